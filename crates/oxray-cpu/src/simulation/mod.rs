//! The queries simulation users expect of a ray-tracing library (Embree, Open3D's
//! `RaycastingScene`, trimesh), on the CPU backend's structures, one at a time or in parallel
//! batches:
//!
//! - [`mesh`]: a triangle GAS from vertex and index slices in one call ([`Gas::from_mesh`]).
//! - [`surface`]: the world-space point and normals of a hit ([`Gas::hit_surface`],
//!   [`Ias::hit_surface`]: [`SurfaceHit`]), through any graph of instances and transforms.
//! - [`all_hits`]: every primitive a ray crosses, sorted and each once ([`Gas::all_hits`]), and
//!   how many ([`Gas::count_hits`]).
//! - [`closest_point`]: the closest point of a triangle GAS to a point, the signed distance and
//!   the inside test of closed meshes ([`Gas::closest_point`], [`Gas::signed_distance`]).
//! - [`instanced`]: the closest point of the triangles under an IAS ([`Ias::closest_point`]),
//!   through instances placed by similarities.
//!
//! Bad input (a NaN point, an invalid ray, slices of different lengths) is a
//! [`SurfaceQueryError`]; an empty structure gives the documented empty result of each query.
//! The batches give the same results as the single queries, whatever the number of threads, and
//! allocate nothing per query beyond the output.
//!
//! ```
//! use oxray_cpu::Gas;
//! use oxray_core::Ray;
//! use glam::Vec3;
//! // Two unit squares at z = 1 and z = 2.
//! let v = [[0.0f32, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 1.0, 1.0], [0.0, 1.0, 1.0],
//!          [0.0, 0.0, 2.0], [1.0, 0.0, 2.0], [1.0, 1.0, 2.0], [0.0, 1.0, 2.0]];
//! let tris = [[0u32, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]];
//! let gas = Gas::from_mesh(&v, &tris)?;
//!
//! let ray = Ray::new(Vec3::new(0.25, 0.75, 0.0), Vec3::Z);
//! let mut hits = Vec::new();
//! gas.all_hits(&ray, 16, &mut hits)?;
//! assert_eq!(hits.iter().map(|h| h.t).collect::<Vec<_>>(), [1.0, 2.0]);
//! let surface = gas.hit_surface(&ray, &hits[0])?;
//! assert_eq!(surface.geometric_normal, Vec3::Z);
//!
//! let closest = gas.closest_point(Vec3::new(0.5, 0.5, 0.0))?.unwrap();
//! assert_eq!(closest.distance, 1.0);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod all_hits;
pub mod closest_point;
pub mod instanced;
pub mod mesh;
pub mod surface;

#[allow(unused_imports)] // Named by the docs above.
use crate::{Gas, Ias};
use glam::Vec3;
use oxray_core::Ray;
use rayon::prelude::*;

pub use instanced::InstanceClosestPoint;
pub use mesh::MeshError;
pub use oxray_core::{AllHits, ClosestPoint, SurfaceQueryError};
pub use oxray_core::{NoShadingNormals, ShadingNormals, SurfaceHit};
pub use surface::VertexNormals;

/// Checks a ray of a single query.
fn check_ray(ray: &Ray) -> Result<(), SurfaceQueryError> {
    ray.validate()
        .map_err(|error| SurfaceQueryError::InvalidRay { index: 0, error })
}

/// Checks a query point of a single query.
fn check_point(point: Vec3) -> Result<(), SurfaceQueryError> {
    if point.is_finite() {
        Ok(())
    } else {
        Err(SurfaceQueryError::NonFinitePoint { index: 0, point })
    }
}

/// Queries per parallel task: as the ray batches of [`crate::query`].
const CHUNK: usize = 256;

/// Runs `f` on every query index `0..queries` in parallel chunks, writing `out` in query order.
/// The first error (the lowest index) is returned, after every query ran; the outputs of failed
/// queries are left as they were.
fn par_try_batch<T: Send>(
    queries: usize,
    out: &mut [T],
    f: impl Fn(usize) -> Result<T, SurfaceQueryError> + Sync,
) -> Result<(), SurfaceQueryError> {
    if queries != out.len() {
        return Err(SurfaceQueryError::LengthMismatch {
            queries,
            outputs: out.len(),
        });
    }
    let first_error = out
        .par_chunks_mut(CHUNK)
        .enumerate()
        .filter_map(|(c, out)| {
            let mut first = None;
            for (k, o) in out.iter_mut().enumerate() {
                let i = c * CHUNK + k;
                match f(i) {
                    Ok(v) => *o = v,
                    Err(e) => {
                        first.get_or_insert((i, e.at(i)));
                    }
                }
            }
            first
        })
        .min_by_key(|(i, _)| *i);
    match first_error {
        Some((_, e)) => Err(e),
        None => Ok(()),
    }
}
