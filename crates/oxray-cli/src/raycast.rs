//! `oxray raycast` and `oxray info`: batch ray casting against a mesh file, and statistics of a
//! mesh's acceleration structure.

use crate::bench::build_gas;
use oxray::{BuildFlags, Hit, Ray};
use oxray_scene::mesh::Mesh;
use std::path::Path;
use std::time::Instant;
use thiserror::Error;

/// Bytes of one ray in a ray file: `ox, oy, oz, tmin, dx, dy, dz, tmax` as little-endian f32.
pub const RAY_BYTES: usize = 32;
/// Bytes of one hit record: `t: f32, primitive: u32, u: f32, v: f32`.
pub const HIT_BYTES: usize = 16;

/// Why a ray cast failed.
#[derive(Debug, Error)]
pub enum RaycastError {
    /// The mesh could not be loaded.
    #[error(transparent)]
    Mesh(#[from] oxray_scene::mesh::MeshError),
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The ray file's size is not a whole number of rays.
    #[error("{path}: {len} bytes is not a whole number of 32-byte rays")]
    RayFileSize {
        /// The file.
        path: String,
        /// Its size.
        len: u64,
    },
    /// The ray file has more rays than the limit allows.
    #[error("{path}: {rays} rays is over the limit of {limit} (raise it with OXRAY_MAX_RAYS)")]
    TooManyRays {
        /// The file.
        path: String,
        /// Rays in the file.
        rays: u64,
        /// The limit.
        limit: u64,
    },
    /// The output would replace an input, or cannot be written.
    #[error("{0}")]
    Output(String),
    /// The acceleration structure could not be built.
    #[error(transparent)]
    Build(#[from] oxray::BuildError),
    /// The results asked for cannot be made (too large, or a query the device refused).
    #[error("{0}")]
    Results(String),
}

fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> RaycastError + '_ {
    move |source| RaycastError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// Checks a ray file's size from its metadata (a regular file holding a whole number of rays,
/// at most [`Limits::rays`](oxray_scene::files::Limits)) before reading it.
pub fn read_ray_file(path: &Path) -> Result<Vec<u8>, RaycastError> {
    let name = path.display().to_string();
    let len = oxray_scene::files::regular_file_size(path).map_err(io_error(path))?;
    check_ray_bytes(len, &name)?;
    let bytes =
        oxray_scene::files::read_limited(path, len, "OXRAY_MAX_RAYS").map_err(io_error(path))?;
    check_ray_bytes(bytes.len() as u64, &name)?;
    Ok(bytes)
}

fn check_ray_bytes(len: u64, path: &str) -> Result<(), RaycastError> {
    if !len.is_multiple_of(RAY_BYTES as u64) {
        return Err(RaycastError::RayFileSize {
            path: path.to_string(),
            len,
        });
    }
    let limit = oxray_scene::files::Limits::get().rays;
    if len / RAY_BYTES as u64 > limit {
        return Err(RaycastError::TooManyRays {
            path: path.to_string(),
            rays: len / RAY_BYTES as u64,
            limit,
        });
    }
    Ok(())
}

/// Decodes a ray file.
pub fn parse_rays(bytes: &[u8], path: &str) -> Result<Vec<Ray>, RaycastError> {
    check_ray_bytes(bytes.len() as u64, path)?;
    Ok(bytes
        .chunks_exact(RAY_BYTES)
        .map(|c| {
            let f: [f32; 8] = std::array::from_fn(|i| {
                f32::from_le_bytes([c[4 * i], c[4 * i + 1], c[4 * i + 2], c[4 * i + 3]])
            });
            Ray::with_interval(
                glam::Vec3::new(f[0], f[1], f[2]),
                glam::Vec3::new(f[4], f[5], f[6]),
                f[3],
                f[7],
            )
        })
        .collect())
}

/// Loads the mesh and the ray file of a ray cast, with every file the mesh was read from (a
/// glTF's buffers too), for the output checks.
pub fn load_inputs(
    mesh_path: &Path,
    rays_path: &Path,
) -> Result<(Mesh, Vec<std::path::PathBuf>, Vec<Ray>), RaycastError> {
    let name = rays_path.display().to_string();
    let len = oxray_scene::files::regular_file_size(rays_path).map_err(io_error(rays_path))?;
    check_ray_bytes(len, &name)?;
    let (mesh, sources) = Mesh::load_with_sources(mesh_path)?;
    let rays = parse_rays(&read_ray_file(rays_path)?, &name)?;
    Ok((mesh, sources, rays))
}

/// Why a ray of a ray file is not traced: the rules of the guide (§13.14, `Ray::validate`),
/// after a negative `tmin` has been clamped to 0.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RayCheck {
    /// Rays traced.
    pub valid: usize,
    /// Rays whose negative `tmin` was clamped to 0 (they are traced, and counted in `valid`).
    pub clamped_tmin: usize,
    /// Rays with a NaN or infinite origin or direction component.
    pub non_finite: usize,
    /// Rays whose direction is zero.
    pub zero_direction: usize,
    /// Rays with a NaN `tmin` or `tmax`.
    pub nan_interval: usize,
    /// Rays whose `tmin` (after clamping) is greater than `tmax`.
    pub empty_interval: usize,
}

impl RayCheck {
    /// Rays not traced.
    pub fn invalid(&self) -> usize {
        self.non_finite + self.zero_direction + self.nan_interval + self.empty_interval
    }

    /// A one-line summary of the rays not traced and clamped, or `None` when every ray is valid
    /// as given.
    pub fn summary(&self) -> Option<String> {
        if self.invalid() == 0 && self.clamped_tmin == 0 {
            return None;
        }
        let mut parts = Vec::new();
        for (n, what) in [
            (self.non_finite, "non-finite origin or direction"),
            (self.zero_direction, "zero direction"),
            (self.nan_interval, "NaN tmin or tmax"),
            (self.empty_interval, "tmin > tmax"),
        ] {
            if n > 0 {
                parts.push(format!("{n} {what}"));
            }
        }
        let mut s = format!("{} invalid rays written as misses", self.invalid());
        if !parts.is_empty() {
            s += &format!(" ({})", parts.join(", "));
        }
        if self.clamped_tmin > 0 {
            s += &format!(
                "; {} rays with tmin < 0 traced from tmin = 0",
                self.clamped_tmin
            );
        }
        Some(s)
    }
}

/// Applies the ray rules of `oxray raycast`: a negative `tmin` is clamped to 0 (the ray is
/// traced from its origin: a surface behind the origin is never reported); a ray that is then
/// invalid by the guide's rules (`Ray::validate`: NaN or infinite origin or direction, zero
/// direction, NaN `tmin`/`tmax`, `tmin > tmax`) is not traced and is written as a miss.
/// Returns the indices of the rays to trace, the rays themselves (clamped), and the counts.
pub fn check_rays(rays: &[Ray]) -> (Vec<usize>, Vec<Ray>, RayCheck) {
    use oxray::RayError;
    let mut check = RayCheck::default();
    let mut index = Vec::with_capacity(rays.len());
    let mut valid = Vec::with_capacity(rays.len());
    for (i, r) in rays.iter().enumerate() {
        let mut r = *r;
        let clamped = r.tmin < 0.0;
        if clamped {
            r.tmin = 0.0;
        }
        match r.validate() {
            Ok(()) => {
                check.valid += 1;
                check.clamped_tmin += clamped as usize;
                index.push(i);
                valid.push(r);
            }
            Err(RayError::NonFiniteOrigin | RayError::NonFiniteDirection) => check.non_finite += 1,
            Err(RayError::ZeroDirection) => check.zero_direction += 1,
            Err(RayError::NanInterval) => check.nan_interval += 1,
            Err(_) => check.empty_interval += 1,
        }
    }
    (index, valid, check)
}

/// Encodes closest hits in the hit file format: `t, primitive, u, v` per ray, with `t = +inf`
/// and primitive `0xFFFF_FFFF` for a miss.
pub fn encode_hits(hits: &[Option<Hit>]) -> Vec<u8> {
    let mut out = Vec::with_capacity(hits.len() * HIT_BYTES);
    for h in hits {
        let (t, p, u, v) = h.map_or((f32::INFINITY, u32::MAX, 0.0, 0.0), |h| {
            (h.t, h.primitive_index, h.u, h.v)
        });
        out.extend_from_slice(&t.to_le_bytes());
        out.extend_from_slice(&p.to_le_bytes());
        out.extend_from_slice(&u.to_le_bytes());
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// What `oxray raycast` asks of every ray.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RaycastQuery {
    /// The closest hit ([`encode_hits`]).
    Closest,
    /// Whether anything is hit ([`encode_occlusion`]).
    Occlusion,
    /// How many primitives the ray crosses ([`encode_counts`]).
    Count,
    /// Every primitive the ray crosses, the nearest `max` of them ([`encode_all_hits`]).
    AllHits {
        /// Hits kept per ray.
        max: usize,
    },
}

/// Most hits `--all-hits` keeps per ray: the records are fixed-size, so that a file is an
/// array (numpy's `fromfile` reads it with one dtype).
pub const MAX_ALL_HITS: usize = 4096;

/// Largest result file `oxray raycast` writes (checked before anything is allocated).
pub const MAX_RESULT_BYTES: u64 = 1 << 36;

/// Bytes of one ray's result of `query`, and of `rays` rays: an error where the file would
/// pass [`MAX_RESULT_BYTES`] or `max` passes [`MAX_ALL_HITS`].
pub fn result_bytes(query: RaycastQuery, rays: usize) -> Result<(usize, u64), RaycastError> {
    let per_ray = match query {
        RaycastQuery::Closest => HIT_BYTES,
        RaycastQuery::Occlusion | RaycastQuery::Count => 4,
        RaycastQuery::AllHits { max } => {
            if max == 0 || max > MAX_ALL_HITS {
                return Err(RaycastError::Results(format!(
                    "--all-hits takes 1 to {MAX_ALL_HITS} hits per ray, not {max}"
                )));
            }
            8 + HIT_BYTES * max
        }
    };
    let total = (per_ray as u64).saturating_mul(rays as u64);
    if total > MAX_RESULT_BYTES {
        return Err(RaycastError::Results(format!(
            "{rays} rays of {per_ray} result bytes each would write {total} bytes; at most {MAX_RESULT_BYTES}"
        )));
    }
    Ok((per_ray, total))
}

/// Encodes hit counts: one little-endian u32 per ray.
pub fn encode_counts(counts: &[u32]) -> Vec<u8> {
    counts.iter().flat_map(|c| c.to_le_bytes()).collect()
}

/// Encodes all-hits lists as fixed-size records of `8 + 16 * max` bytes per ray: `u32` hits
/// listed, `u32` 1 if the list is complete (no hit beyond the `max` kept), then `max` hit
/// records as [`encode_hits`] writes them, nearest first, misses after the last hit. `lists`
/// has `None` for the rays that were not traced (invalid: no hit, complete).
pub fn encode_all_hits(lists: &[Option<(&[Hit], bool)>], max: usize) -> Vec<u8> {
    let mut out = Vec::with_capacity(lists.len() * (8 + HIT_BYTES * max));
    for l in lists {
        let (hits, complete) = l.unwrap_or((&[], true));
        let hits = &hits[..hits.len().min(max)];
        out.extend_from_slice(&(hits.len() as u32).to_le_bytes());
        out.extend_from_slice(&(complete as u32).to_le_bytes());
        let padded: Vec<Option<Hit>> = (0..max).map(|k| hits.get(k).copied()).collect();
        out.extend_from_slice(&encode_hits(&padded));
    }
    out
}

/// Encodes occlusion results: one little-endian u32 per ray, 1 for occluded.
pub fn encode_occlusion(occluded: &[bool]) -> Vec<u8> {
    occluded
        .iter()
        .flat_map(|&o| (o as u32).to_le_bytes())
        .collect()
}

/// Writes a result file atomically (a temporary file renamed into place).
pub fn write_results(path: &Path, bytes: &[u8]) -> Result<(), RaycastError> {
    oxray_scene::files::write_bytes_atomic(path, bytes).map_err(io_error(path))
}

/// Statistics of a mesh file's acceleration structure.
pub fn info(mesh_path: &Path) -> Result<String, RaycastError> {
    let mesh = Mesh::load(mesh_path)?;
    let t = Instant::now();
    // Built for compaction (guide §5.8), so that the memory as built and compacted is shown.
    let built = build_gas(
        &mesh,
        BuildFlags::PREFER_FAST_TRACE | BuildFlags::ALLOW_COMPACTION,
    )?;
    let build_ms = t.elapsed().as_secs_f64() * 1e3;
    let built_bytes = built.memory().output_bytes;
    let gas = oxray::cpu::Gas::from(built.data().compact()?);
    let s = gas.stats();
    let m = gas.memory();
    let b = gas.bounds();
    let per = |bytes: usize| bytes as f64 / (gas.num_primitives().max(1)) as f64;
    Ok(format!(
        "file: {}\nvertices: {}\ntriangles: {} ({} active)\ninstances: 1\nbounds: [{:.4}, {:.4}, {:.4}] .. [{:.4}, {:.4}, {:.4}]\nBVH: {} nodes (4-wide), {} leaves, depth {}, mean leaf {:.2} triangles, SAH cost {:.2}, {} leaf references ({:.3} per active triangle: spatial splits repeat some)\nbytes: {} total ({} nodes, {} triangles)\nmemory: {:.1} B/triangle as built with ALLOW_COMPACTION ({} bytes), {:.1} B/triangle compacted\nbuild: {:.1} ms (PREFER_FAST_TRACE)",
        mesh_path.display(),
        mesh.positions.len(),
        gas.num_primitives(),
        gas.num_active_primitives(),
        b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z,
        s.nodes,
        s.leaves,
        s.max_depth,
        s.mean_leaf_size,
        s.sah_cost,
        s.references,
        s.references as f64 / gas.num_active_primitives().max(1) as f64,
        m.output_bytes,
        m.node_bytes,
        m.primitive_bytes,
        per(built_bytes),
        built_bytes,
        per(m.output_bytes),
        build_ms,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use oxray::HitKind;

    fn hit(t: f32, primitive_index: u32) -> Hit {
        Hit {
            t,
            u: 0.25,
            v: 0.5,
            primitive_index,
            sbt_gas_index: 0,
            build_input: 0,
            hit_kind: HitKind::TRIANGLE_FRONT_FACE,
            instance_id: !0,
            instance_index: 0,
        }
    }

    #[test]
    fn all_hits_records_are_fixed_size_and_padded_with_misses() {
        let hits = [hit(1.0, 3), hit(2.0, 7)];
        let lists = [Some((&hits[..], false)), None, Some((&hits[..1], true))];
        let bytes = encode_all_hits(&lists, 2);
        assert_eq!(bytes.len(), 3 * (8 + 32));
        let w: Vec<u32> = bytes
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        assert_eq!(&w[..2], &[2, 0]);
        assert_eq!((f32::from_bits(w[2]), w[3]), (1.0, 3));
        assert_eq!((f32::from_bits(w[6]), w[7]), (2.0, 7));
        // A ray not traced: nothing listed, complete, misses.
        assert_eq!(&w[10..12], &[0, 1]);
        assert_eq!((f32::from_bits(w[12]), w[13]), (f32::INFINITY, u32::MAX));
        assert_eq!(&w[20..22], &[1, 1]);
        assert_eq!((f32::from_bits(w[26]), w[27]), (f32::INFINITY, u32::MAX));
        assert_eq!(encode_counts(&[3, 0]), [3, 0, 0, 0, 0, 0, 0, 0]);
    }

    #[test]
    fn result_sizes_are_checked_before_anything_is_traced() {
        assert_eq!(result_bytes(RaycastQuery::Closest, 10).unwrap(), (16, 160));
        assert_eq!(result_bytes(RaycastQuery::Count, 10).unwrap(), (4, 40));
        assert_eq!(
            result_bytes(RaycastQuery::AllHits { max: 3 }, 10).unwrap(),
            (56, 560)
        );
        for max in [0, MAX_ALL_HITS + 1] {
            assert!(result_bytes(RaycastQuery::AllHits { max }, 1).is_err());
        }
        assert!(matches!(
            result_bytes(RaycastQuery::AllHits { max: MAX_ALL_HITS }, 1 << 30),
            Err(RaycastError::Results(_))
        ));
    }
}
