//! Export of a built triangle GAS for other backends (a GPU, say): the 4-wide BVH as it is, the
//! triangles in leaf-slot order, and what each slot reports when hit.
//!
//! A backend that walks [`GasExport::nodes`] exactly as the CPU kernel does, and intersects the
//! slots' triangles with the watertight test of [`crate::triangle`], finds the same hits as the
//! CPU backend's closest-hit and any-hit queries.

use crate::bvh4::Bvh4Node;
use crate::gas::{GasData, GasKind};
use oxray_core::Aabb;
use rayon::prelude::*;

/// The triangle in one leaf slot of an exported GAS, and what a hit on it reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExportedTriangle {
    /// The vertices, pre-transformed, in the order of the build input (they fix the facing and
    /// the barycentrics `u`, `v`).
    pub vertices: [[f32; 3]; 3],
    /// [`Hit::primitive_index`](oxray_core::Hit::primitive_index): the index within its build input
    /// plus the input's primitive index offset.
    pub primitive_index: u32,
    /// [`Hit::sbt_gas_index`](oxray_core::Hit::sbt_gas_index).
    pub sbt_gas_index: u32,
    /// [`Hit::build_input`](oxray_core::Hit::build_input).
    pub build_input: u32,
}

/// The traversal data of a triangle GAS, from [`GasData::export_triangles`].
///
/// `nodes[0]` is the root. A lane of a node with `count[lane] == 0` and a valid box is an inner
/// child at `child[lane]`; with `count[lane] > 0` it is a leaf whose triangles are the slots
/// `child[lane] .. child[lane] + count[lane]` of [`slots`](Self::slots). Within a leaf the CPU
/// kernel tests slots in increasing order, and a later slot at the same distance replaces an
/// earlier one as the closest hit.
#[derive(Clone, Debug)]
pub struct GasExport {
    /// The 4-wide BVH, root first (see [`Bvh4Node`]).
    pub nodes: Vec<Bvh4Node>,
    /// The triangle of each leaf slot; `None` for padding slots that no leaf covers and for
    /// the slots an `ALLOW_UPDATE` build keeps for inactive primitives (never hit).
    pub slots: Vec<Option<ExportedTriangle>>,
    /// The box around every active triangle (empty when there is none).
    pub bounds: Aabb,
}

impl GasExport {
    /// Triangles that can be hit (slots that are not padding).
    #[must_use]
    pub fn num_triangles(&self) -> usize {
        self.slots.iter().filter(|s| s.is_some()).count()
    }
}

impl GasData {
    /// Exports the BVH and triangles of a triangle GAS for another backend; `None` for a GAS of
    /// custom primitives, whose intersection is a host closure.
    ///
    /// ```
    /// use oxray_bvh::GasData;
    /// use oxray_core::{BuildOptions, TriangleInput, VertexBuffer};
    /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    /// let gas = GasData::build(&BuildOptions::default(), &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
    /// let export = gas.export_triangles().expect("a triangle GAS");
    /// assert_eq!(export.num_triangles(), 1);
    /// let root = &export.nodes[0];
    /// let slot = root.child[0] as usize;
    /// assert_eq!(root.count[0], 1);
    /// assert_eq!(export.slots[slot].unwrap().vertices, v);
    /// # Ok::<(), oxray_core::BuildError>(())
    /// ```
    #[must_use]
    pub fn export_triangles(&self) -> Option<GasExport> {
        if self.kind != GasKind::Triangles {
            return None;
        }
        let slots = (0..self.slot_prim.len())
            .into_par_iter()
            .map(|slot| {
                // Padding, and the slots an updatable build keeps for inactive primitives.
                if !self.slot_is_active(slot) {
                    return None;
                }
                let (primitive_index, sbt_gas_index, build_input) = self.resolve(slot as u32);
                Some(ExportedTriangle {
                    vertices: self.triangles[slot / 4].get(slot % 4),
                    primitive_index,
                    sbt_gas_index,
                    build_input,
                })
            })
            .collect();
        Some(GasExport {
            nodes: self.bvh.nodes.clone(),
            slots,
            bounds: self.bounds,
        })
    }
}

#[cfg(test)]
mod tests {
    use crate::GasData as Gas;
    use oxray_core::{BuildOptions, IndexBuffer, TriangleInput, VertexBuffer};

    /// A grid of `n` x `n` quads (two triangles each) in the z = 0 plane.
    fn grid(n: u32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let mut v = Vec::new();
        for y in 0..=n {
            for x in 0..=n {
                v.push([x as f32, y as f32, (x * y % 3) as f32 * 0.1]);
            }
        }
        let mut t = Vec::new();
        for y in 0..n {
            for x in 0..n {
                let i = y * (n + 1) + x;
                t.push([i, i + 1, i + n + 2]);
                t.push([i, i + n + 2, i + n + 1]);
            }
        }
        (v, t)
    }

    #[test]
    fn every_triangle_is_in_exactly_one_leaf_slot() {
        let (v, t) = grid(20);
        // Two inputs, the second with a primitive index offset, so that resolution is tested.
        let half = t.len() / 2;
        let a = TriangleInput::new(VertexBuffer::f32x3(&v)).indices(IndexBuffer::u32x3(&t[..half]));
        let b = TriangleInput::new(VertexBuffer::f32x3(&v))
            .indices(IndexBuffer::u32x3(&t[half..]))
            .primitive_index_offset(1000);
        let gas = Gas::build(&BuildOptions::default(), &[a.into(), b.into()]).unwrap();
        let e = gas.export_triangles().unwrap();
        assert_eq!(e.num_triangles(), t.len());
        assert_eq!(e.bounds, gas.bounds());

        let mut seen = vec![0u32; t.len()];
        let mut stack = vec![0usize];
        while let Some(n) = stack.pop() {
            let node = &e.nodes[n];
            for lane in 0..4 {
                if !node.is_used(lane) {
                    continue;
                }
                let (child, count) = (node.child[lane] as usize, node.count[lane] as usize);
                if count == 0 {
                    stack.push(child);
                    continue;
                }
                let b = node.child_bounds(lane);
                for slot in child..child + count {
                    let tri = e.slots[slot].expect("a leaf slot holds a triangle");
                    let (input, local) = (tri.build_input as usize, tri.primitive_index);
                    let global = if input == 0 {
                        local as usize
                    } else {
                        assert!(local >= 1000);
                        half + (local - 1000) as usize
                    };
                    seen[global] += 1;
                    let want = t[global].map(|i| v[i as usize]);
                    assert_eq!(tri.vertices, want);
                    assert_eq!(tri.sbt_gas_index, input as u32);
                    for p in tri.vertices {
                        assert!(b.contains(p.into()), "leaf box holds its triangles");
                    }
                }
            }
        }
        assert!(seen.iter().all(|&s| s == 1));
    }

    #[test]
    fn inactive_slots_of_an_updatable_gas_are_not_exported() {
        let (mut v, t) = grid(6);
        v[0] = v[1]; // triangle 0 degenerate
        let options = BuildOptions::new(oxray_core::BuildFlags::ALLOW_UPDATE);
        let input = TriangleInput::new(VertexBuffer::f32x3(&v)).indices(IndexBuffer::u32x3(&t));
        let gas = Gas::build(&options, &[input.into()]).unwrap();
        assert_eq!(gas.num_active_primitives() as usize, t.len() - 1);
        let e = gas.export_triangles().unwrap();
        assert_eq!(e.num_triangles(), t.len() - 1);
        assert!(e.slots.iter().flatten().all(|s| s
            .vertices
            .iter()
            .flatten()
            .all(|c| c.is_finite())));
    }

    #[test]
    fn custom_primitive_gas_has_no_triangle_export() {
        let boxes = [oxray_core::Aabb::new(glam::Vec3::ZERO, glam::Vec3::ONE)];
        let input = oxray_core::CustomPrimitiveInput::new(oxray_core::AabbBuffer::new(&boxes));
        let gas = Gas::build(&BuildOptions::default(), &[input.into()]).unwrap();
        assert!(gas.export_triangles().is_none());
    }
}
