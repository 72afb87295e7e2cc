//! What the tests, the library's unit tests and the `gpu_raycast` example add to `oxray-testkit`:
//! building a CPU-backend GAS over a mesh, and the ray sets of `oxray bench` in the shapes they
//! use (the testkit generates the rays; they are bit-identical to the command-line tool's, so
//! numbers are comparable).

#![allow(dead_code, unused_imports)]

use oxray_bvh::{Bvh2, GasData};
use oxray_core::{
    BuildError, BuildFlags, BuildOptions, IndexBuffer, Ray, TriangleInput, VertexBuffer,
};
use oxray_cpu::Gas;
pub use oxray_testkit::mesh::{find_mesh, icosphere_f32, load_obj, Mesh};
use oxray_testkit::rays;

/// Builds a GAS over the mesh on the CPU backend.
pub fn build_gas(mesh: &Mesh, flags: BuildFlags) -> Result<Gas, BuildError> {
    let input = TriangleInput::new(VertexBuffer::f32x3(&mesh.positions))
        .indices(IndexBuffer::u32x3(&mesh.triangles));
    Gas::build(&BuildOptions::new(flags), &[input.into()])
}

/// Builds a GAS over the mesh on the CPU backend, with the canonical binary tree of the build
/// (what the CUDA layouts are derived from).
pub fn build_gas_with_tree(mesh: &Mesh, flags: BuildFlags) -> Result<(Gas, Bvh2), BuildError> {
    let input = TriangleInput::new(VertexBuffer::f32x3(&mesh.positions))
        .indices(IndexBuffer::u32x3(&mesh.triangles));
    let (data, tree) = GasData::build_with_tree(&BuildOptions::new(flags), &[input.into()])?;
    Ok((Gas::from(data), tree))
}

/// The coherent and incoherent ray sets of `oxray bench` for a mesh: a `side` x `side` camera
/// and as many hemisphere rays (seed [`rays::INCOHERENT_SEED`]).
pub fn bench_rays(mesh: &Mesh, side: u32) -> (Vec<Ray>, Vec<Ray>) {
    let n = (side * side) as usize;
    (
        rays::camera_rays(&mesh.positions, side, side),
        rays::hemisphere_rays(&mesh.positions, &mesh.triangles, n, rays::INCOHERENT_SEED),
    )
}

/// [`rays::tricky_rays`] with the bounded rays ending at `gas`'s closest hit.
pub fn tricky_rays(mesh: &Mesh, gas: &Gas, n: usize, seed: u64) -> Vec<Ray> {
    rays::tricky_rays(&mesh.positions, &mesh.triangles, n, seed, |r| {
        gas.intersect(r).map(|h| h.t)
    })
}
