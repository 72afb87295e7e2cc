//! Helpers of the kernel and layout tests (each test file declares `mod common;`).

use oxray_core::{BuildFlags, BuildOptions, Hit, IndexBuffer, Ray, TriangleInput, VertexBuffer};
use oxray_cpu::{Gas, Isa};
use oxray_testkit::mesh::Mesh;
use oxray_testkit::Tri;

/// The kernels this processor runs; says which are skipped.
pub fn kernels() -> Vec<Isa> {
    for isa in Isa::ALL {
        if !isa.is_available() {
            eprintln!("skipping the {isa} kernel: this processor lacks it");
        }
    }
    Isa::available()
}

/// A GAS over the indexed mesh `m`, traced by kernel `isa`.
pub fn mesh_gas(isa: Isa, m: &Mesh, flags: BuildFlags) -> Gas {
    let input = TriangleInput::new(VertexBuffer::f32x3(&m.positions))
        .indices(IndexBuffer::u32x3(&m.triangles));
    let gas = Gas::build_with_isa(isa, &BuildOptions::new(flags), &[input.into()]).unwrap();
    assert_eq!(gas.isa(), isa);
    gas
}

/// A triangle soup as an indexed mesh (no shared vertices).
pub fn soup_mesh(tris: &[Tri]) -> Mesh {
    Mesh {
        positions: tris.iter().flatten().copied().collect(),
        triangles: (0..tris.len() as u32)
            .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect(),
    }
}

/// Closest hits and occlusion of `rays` through the batched queries on a pool of `threads`
/// (occlusion starts `true` in every slot, so a slot the batch leaves unwritten shows).
#[allow(dead_code)] // the batch tests' helper; the layout tests trace ray by ray
pub fn batched(gas: &Gas, rays: &[Ray], threads: usize) -> (Vec<Option<Hit>>, Vec<bool>) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let mut hits = vec![None; rays.len()];
    let mut occluded = vec![true; rays.len()];
    pool.install(|| {
        gas.intersect_batch(rays, &mut hits).unwrap();
        gas.occluded_batch(rays, &mut occluded).unwrap();
    });
    (hits, occluded)
}

/// One ray of each kind [`Ray::validate`] refuses (a NaN or zero direction, an infinite
/// origin, an interval that is reversed, negative or NaN): a query answers each with a miss.
#[allow(dead_code)] // the batch tests' helper
pub fn invalid_rays() -> [Ray; 6] {
    let o = glam::Vec3::new(0.1, 0.2, 0.3);
    let x = glam::Vec3::X;
    [
        Ray::new(o, glam::Vec3::new(f32::NAN, 1.0, 0.0)),
        Ray::new(o, glam::Vec3::ZERO),
        Ray::new(glam::Vec3::new(f32::INFINITY, 0.0, 0.0), x),
        Ray::with_interval(o, x, 2.0, 1.0),
        Ray::with_interval(o, x, -1.0, 1.0),
        Ray::with_interval(o, x, 0.0, f32::NAN),
    ]
}
