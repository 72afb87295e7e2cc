//! The library behind the `oxray` command-line tool: the logic of its `bench`, `raycast`, `info`
//! commands on any device. Scene and mesh loading live in `oxray-scene`, the path tracer in
//! `oxray-render`.

#![warn(missing_docs)]

pub mod bench;
pub mod closest;
pub mod device;
pub mod info;
pub mod raycast;
pub mod simulation;
