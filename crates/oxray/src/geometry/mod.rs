//! Per-primitive geometry: bounds and ray intersection for each primitive kind.

mod aabb;
pub mod triangle;
pub mod triangle4;
pub mod vertex;

pub use aabb::Aabb;
