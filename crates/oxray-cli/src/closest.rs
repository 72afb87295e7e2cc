//! `oxray closest`: the closest point of a mesh's surface to every point of a file, with the
//! distance (signed with `--signed`: negative inside a closed mesh) and the triangle, on any
//! device.

use crate::bench::build_gas_on;
use crate::device::DeviceCommandError;
use crate::raycast::{write_results, RaycastError};
use glam::Vec3;
use oxray::{BuildFlags, ClosestPoint, Device};
use oxray_scene::mesh::Mesh;
use std::path::Path;
use std::time::Instant;

/// Bytes of one point in a point file: `x, y, z` as little-endian f32.
pub const POINT_BYTES: usize = 12;
/// Bytes of one result: `f32 distance, f32 x, y, z` (the closest point), `u32 primitive`.
pub const CLOSEST_BYTES: usize = 20;

/// What `oxray closest` did.
#[derive(Clone, Copy, Debug)]
pub struct ClosestReport {
    /// Points in the file.
    pub points: usize,
    /// Points with a non-finite coordinate (written as "none").
    pub non_finite: usize,
    /// Millions of points answered per second (the query, on its device).
    pub mpoints_per_s: f64,
}

/// Checks a point file's size and reads it (at most the ray limit, `OXRAY_MAX_RAYS`, of
/// points).
fn read_points(path: &Path) -> Result<Vec<Vec3>, RaycastError> {
    let name = path.display().to_string();
    let io = |source| RaycastError::Io {
        path: name.clone(),
        source,
    };
    let len = oxray_scene::files::regular_file_size(path).map_err(io)?;
    let check = |len: u64| {
        if !len.is_multiple_of(POINT_BYTES as u64) {
            return Err(RaycastError::Results(format!(
                "{name}: {len} bytes is not a whole number of 12-byte points"
            )));
        }
        let limit = oxray_scene::files::Limits::get().rays;
        if len / POINT_BYTES as u64 > limit {
            return Err(RaycastError::Results(format!(
                "{name}: {} points is over the limit of {limit} (raise it with OXRAY_MAX_RAYS)",
                len / POINT_BYTES as u64
            )));
        }
        Ok(())
    };
    check(len)?;
    let io = |source| RaycastError::Io {
        path: name.clone(),
        source,
    };
    let bytes = oxray_scene::files::read_limited(path, len, "OXRAY_MAX_RAYS").map_err(io)?;
    check(bytes.len() as u64)?;
    Ok(bytes
        .chunks_exact(POINT_BYTES)
        .map(|c| {
            let f =
                |k: usize| f32::from_le_bytes([c[4 * k], c[4 * k + 1], c[4 * k + 2], c[4 * k + 3]]);
            Vec3::new(f(0), f(1), f(2))
        })
        .collect())
}

/// Encodes the results, one record per point: the distance (`+inf` for none), the closest
/// point (NaN for none) and its triangle (`u32::MAX` for none).
pub fn encode_closest(results: &[Option<(f32, ClosestPoint)>]) -> Vec<u8> {
    let mut out = Vec::with_capacity(results.len() * CLOSEST_BYTES);
    for r in results {
        let (d, p, prim) = r.map_or((f32::INFINITY, Vec3::NAN, u32::MAX), |(d, c)| {
            (d, c.point, c.primitive_index)
        });
        for x in [d, p.x, p.y, p.z] {
            out.extend_from_slice(&x.to_le_bytes());
        }
        out.extend_from_slice(&prim.to_le_bytes());
    }
    out
}

/// `oxray closest`: builds the mesh's GAS on `device`, answers every point of `points_path`
/// and writes the records to `out_path` (atomically; never over an input).
pub fn closest(
    device: &Device,
    mesh_path: &Path,
    points_path: &Path,
    out_path: &Path,
    signed: bool,
) -> Result<ClosestReport, DeviceCommandError> {
    oxray_scene::files::check_output(out_path, &[mesh_path, points_path])
        .map_err(RaycastError::Output)?;
    let points = read_points(points_path)?;
    let (mesh, sources) = Mesh::load_with_sources(mesh_path).map_err(RaycastError::Mesh)?;
    let sources: Vec<&Path> = sources.iter().map(|p| p.as_path()).collect();
    oxray_scene::files::check_output(out_path, &sources).map_err(RaycastError::Output)?;
    let (index, finite): (Vec<usize>, Vec<Vec3>) = points
        .iter()
        .enumerate()
        .filter(|(_, p)| p.is_finite())
        .map(|(i, p)| (i, *p))
        .unzip();
    let gas = build_gas_on(device, &mesh, BuildFlags::empty())?;
    let refused = |e: oxray::SurfaceQueryError| RaycastError::Results(e.to_string());
    let t = Instant::now();
    let mut found = vec![None; finite.len()];
    gas.closest_point_batch(&finite, &mut found)
        .map_err(refused)?;
    let mut signed_d = vec![0.0f32; if signed { finite.len() } else { 0 }];
    if signed {
        gas.signed_distance_batch(&finite, &mut signed_d)
            .map_err(refused)?;
    }
    let secs = t.elapsed().as_secs_f64();
    let mut all = vec![None; points.len()];
    for (k, (&i, c)) in index.iter().zip(found).enumerate() {
        all[i] = c.map(|c| (if signed { signed_d[k] } else { c.distance }, c));
    }
    write_results(out_path, &encode_closest(&all))?;
    Ok(ClosestReport {
        points: points.len(),
        non_finite: points.len() - finite.len(),
        mpoints_per_s: finite.len() as f64 / secs.max(1e-12) / 1e6,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_say_none_with_inf_nan_and_max() {
        let c = ClosestPoint {
            point: Vec3::new(1.0, 2.0, 3.0),
            distance: 0.5,
            primitive_index: 9,
            build_input: 0,
            u: 0.0,
            v: 0.0,
        };
        let bytes = encode_closest(&[Some((-0.5, c)), None]);
        assert_eq!(bytes.len(), 2 * CLOSEST_BYTES);
        let f = |k: usize| f32::from_le_bytes(bytes[4 * k..4 * k + 4].try_into().unwrap());
        assert_eq!((f(0), f(1), f(2), f(3)), (-0.5, 1.0, 2.0, 3.0));
        assert_eq!(u32::from_le_bytes(bytes[16..20].try_into().unwrap()), 9);
        assert_eq!(f(5), f32::INFINITY);
        assert!(f(6).is_nan());
        assert_eq!(
            u32::from_le_bytes(bytes[36..40].try_into().unwrap()),
            u32::MAX
        );
    }
}
