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
        len: usize,
    },
    /// The acceleration structure could not be built.
    #[error(transparent)]
    Build(#[from] oxray::BuildError),
}

fn read(path: &Path) -> Result<Vec<u8>, RaycastError> {
    std::fs::read(path).map_err(|source| RaycastError::Io {
        path: path.display().to_string(),
        source,
    })
}

/// Decodes a ray file.
pub fn parse_rays(bytes: &[u8], path: &str) -> Result<Vec<Ray>, RaycastError> {
    if !bytes.len().is_multiple_of(RAY_BYTES) {
        return Err(RaycastError::RayFileSize {
            path: path.to_string(),
            len: bytes.len(),
        });
    }
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

/// Loads the mesh and the ray file of a ray cast.
pub fn load_mesh_and_rays(
    mesh_path: &Path,
    rays_path: &Path,
) -> Result<(Mesh, Vec<Ray>), RaycastError> {
    let mesh = Mesh::load(mesh_path)?;
    let rays = parse_rays(&read(rays_path)?, &rays_path.display().to_string())?;
    Ok((mesh, rays))
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

/// Encodes occlusion results: one little-endian u32 per ray, 1 for occluded.
pub fn encode_occlusion(occluded: &[bool]) -> Vec<u8> {
    occluded
        .iter()
        .flat_map(|&o| (o as u32).to_le_bytes())
        .collect()
}

/// Writes a result file.
pub fn write_results(path: &Path, bytes: &[u8]) -> Result<(), RaycastError> {
    std::fs::write(path, bytes).map_err(|source| RaycastError::Io {
        path: path.display().to_string(),
        source,
    })
}

/// Statistics of a mesh file's acceleration structure.
pub fn info(mesh_path: &Path) -> Result<String, RaycastError> {
    let mesh = Mesh::load(mesh_path)?;
    let t = Instant::now();
    let gas = build_gas(&mesh, BuildFlags::PREFER_FAST_TRACE)?;
    let build_ms = t.elapsed().as_secs_f64() * 1e3;
    let s = gas.stats();
    let m = gas.memory();
    let b = gas.bounds();
    Ok(format!(
        "file: {}\nvertices: {}\ntriangles: {} ({} active)\ninstances: 1\nbounds: [{:.4}, {:.4}, {:.4}] .. [{:.4}, {:.4}, {:.4}]\nBVH: {} nodes (4-wide), {} leaves, depth {}, mean leaf {:.2} triangles, SAH cost {:.2}\nbytes: {} total ({} nodes, {} triangles)\nbuild: {:.1} ms (PREFER_FAST_TRACE)",
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
        m.output_bytes,
        m.node_bytes,
        m.primitive_bytes,
        build_ms,
    ))
}
