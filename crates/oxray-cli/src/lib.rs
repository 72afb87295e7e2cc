//! The library behind the `oxray` command-line tool: the logic of its `bench`, `raycast`, `info`
//! and GPU commands. Scene and mesh loading live in `oxray-scene`, the path tracer in
//! `oxray-render`.

#![warn(missing_docs)]

pub mod bench;
pub mod gpu;
pub mod info;
pub mod raycast;
