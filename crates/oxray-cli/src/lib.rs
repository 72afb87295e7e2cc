//! The library behind the `oxray` command-line tool: mesh loaders and benchmarks.

#![warn(missing_docs)]

pub mod bench;
pub mod gpu;
pub mod info;
pub mod mesh;
pub mod raycast;
pub mod render;
pub mod scene;
