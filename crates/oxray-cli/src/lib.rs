//! The library behind the `oxray` command-line tool: mesh loaders and benchmarks.

#![warn(missing_docs)]

pub mod bench;
pub mod gpu;
pub mod info;
pub mod mesh;
pub mod raycast;
pub mod render;
pub mod scene;

/// A file's extension in lower case (`None` without one, or when it is not UTF-8): how every
/// loader and writer of the tool picks a format.
pub fn file_extension(path: &std::path::Path) -> Option<String> {
    path.extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
}
