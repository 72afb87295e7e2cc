//! Copies of structures on the device and between devices: a duplicate (the copy an update of
//! a shared structure writes, as the CPU backend's copy-on-write), compaction (guide §5.8),
//! and the way to and from [`GasData`], through which a structure is saved and loaded (beyond
//! §5.7's relocation: the saved bytes load on any backend).
//!
//! Structures on this device are exactly sized when built (a device build counts its nodes
//! before writing them; an upload writes the host's arrays), so a compaction is an exact copy
//! and the compacted size is the structure's size.

use crate::context::CudaContext;
use crate::error::{driver, CudaError};
use crate::gas::{CudaGas, Scratch};
use crate::layout::NodeLayout;
use cudarc::driver::{CudaSlice, CudaView};
use oxray_bvh::{
    Bvh2, Bvh2Node, Bvh4Node, CurveSegment, GasData, GasKind, SlotPrimitives, Sphere, NO_PRIMITIVE,
};
use oxray_core::{Aabb, BuildError, BuildFlags, LoadError};
use std::sync::Mutex;

/// Words of one binary node (`layout.rs`).
const NODE_WORDS: usize = 16;

fn copy(ctx: &CudaContext, w: &CudaSlice<u32>) -> Result<CudaSlice<u32>, CudaError> {
    ctx.stream
        .clone_dtod(w)
        .map_err(driver("copying a structure on the device"))
}

fn download(ctx: &CudaContext, w: &CudaView<'_, u32>, len: usize) -> Result<Vec<u32>, CudaError> {
    let mut out = vec![0u32; len.min(w.len())];
    if !out.is_empty() {
        ctx.stream
            .memcpy_dtoh(&w.slice(..out.len()), &mut out[..])
            .map_err(driver("copying a structure to the host"))?;
    }
    ctx.synchronize()?;
    Ok(out)
}

impl CudaGas {
    /// A copy of the structure in new device memory, with the same hits, lineage and update
    /// state: what an update of a structure that is shared (an IAS, a handle) writes into, so
    /// that the holders of the original keep tracing it unchanged.
    pub fn duplicate(&self) -> Result<CudaGas, CudaError> {
        let refit = match &self.refit {
            Some(p) => Some(p.duplicate(&self.ctx)?),
            None => None,
        };
        let motion = match &self.motion {
            Some(m) => Some(m.duplicate(&self.ctx)?),
            None => None,
        };
        let gas = CudaGas {
            ctx: self.ctx.clone(),
            kind: self.kind,
            layout: self.layout,
            nodes: self.nodes.duplicate(&self.ctx)?,
            triangles: copy(&self.ctx, &self.triangles)?,
            slots: self.slots.clone(),
            info: self.info.clone(),
            num_nodes: self.num_nodes,
            device_bytes: self.device_bytes,
            builder: self.builder,
            scratch: Mutex::new(Scratch::default()),
            record_flags: self.record_flags.clone(),
            program_view: Mutex::new(None),
            curve_types: self.curve_types.clone(),
            meta: self.meta.clone(),
            refit,
            random_slots: self.random_slots.clone(),
            simulation: Default::default(),
            motion,
        };
        self.ctx.synchronize()?;
        Ok(gas)
    }

    /// The emitted property `COMPACTED_SIZE` (guide §5.5, §5.8): the bytes of the compacted
    /// structure on the device, its nodes and primitives; `None` unless built with
    /// `ALLOW_COMPACTION`. Device structures are exactly sized from the start, so this is
    /// [`device_bytes`](Self::device_bytes).
    pub fn compacted_size(&self) -> Option<usize> {
        self.meta
            .build_flags
            .contains(BuildFlags::ALLOW_COMPACTION)
            .then_some(self.device_bytes)
    }

    /// The compacted structure (`optixAccelCompact`, guide §5.8): a copy of
    /// [`compacted_size`](Self::compacted_size) bytes with the same hits, independent of the
    /// source, updatable if the source was. Refused without `ALLOW_COMPACTION`
    /// ([`BuildError::CompactionNotAllowed`]).
    #[doc(alias = "optixAccelCompact")]
    pub fn compact(&self) -> Result<CudaGas, BuildError> {
        if !self.meta.build_flags.contains(BuildFlags::ALLOW_COMPACTION) {
            return Err(BuildError::CompactionNotAllowed);
        }
        self.duplicate()
            .map_err(|e| BuildError::Device(e.to_string()))
    }

    /// The structure read back from the device as host data (for [`GasData::to_bytes`], or to
    /// trace it on another backend): its binary tree and leaf slots assembled into the CPU's
    /// layout ([`GasData::assemble`]), with the same tables. The hits are the same, up to
    /// which of two primitives at exactly the same distance is reported. What comes back from
    /// the device is checked as a loader checks bytes.
    pub fn to_data(&self) -> Result<GasData, LoadError> {
        if self.motion.is_some() {
            return Err(LoadError::Unsupported(
                "reading a GAS with motion keys back from the CUDA backend",
            ));
        }
        let dev = |e: CudaError| LoadError::Device(e.to_string());
        let nodes = download(
            &self.ctx,
            &self.nodes.nodes(),
            self.num_nodes * self.layout.node_bytes() / 4,
        )
        .map_err(dev)?;
        let per_slot = match self.kind {
            GasKind::Triangles => 12,
            GasKind::CustomPrimitives => 8,
            GasKind::Spheres => 4,
            GasKind::Curves => 24,
        };
        let n_slots = self.slots.len();
        let words =
            download(&self.ctx, &self.triangles.slice(..), per_slot * n_slots).map_err(dev)?;
        if words.len() < per_slot * n_slots {
            return Err(LoadError::Invalid {
                what: "device primitive array",
                index: words.len() as u64,
            });
        }
        let tree = match self.layout {
            NodeLayout::Bvh2 => tree_of_words(&nodes)?,
            NodeLayout::Bvh4 => {
                let wide: Vec<Bvh4Node> = nodes
                    .chunks_exact(32)
                    .map(|c| bytemuck::pod_read_unaligned::<Bvh4Node>(bytemuck::cast_slice(c)))
                    .collect();
                Bvh2::from_wide(&wide)
            }
        };
        let slot_prim = self.slot_globals();
        let f = |w: u32| f32::from_bits(w);
        let prims = match self.kind {
            GasKind::Triangles => SlotPrimitives::Triangles(
                words
                    .chunks_exact(12)
                    .map(|w| {
                        std::array::from_fn(|v| [f(w[4 * v]), f(w[4 * v + 1]), f(w[4 * v + 2])])
                    })
                    .collect(),
            ),
            GasKind::CustomPrimitives => SlotPrimitives::Aabbs(
                words
                    .chunks_exact(8)
                    .map(|w| {
                        Aabb::new(
                            [f(w[0]), f(w[1]), f(w[2])].into(),
                            [f(w[4]), f(w[5]), f(w[6])].into(),
                        )
                    })
                    .collect(),
            ),
            GasKind::Spheres => SlotPrimitives::Spheres(
                words
                    .chunks_exact(4)
                    .map(|w| Sphere {
                        center: [f(w[0]), f(w[1]), f(w[2])],
                        radius: f(w[3]),
                    })
                    .collect(),
            ),
            GasKind::Curves => SlotPrimitives::Curves(
                words
                    .chunks_exact(24)
                    .map(|w| bytemuck::pod_read_unaligned::<CurveSegment>(bytemuck::cast_slice(w)))
                    .collect(),
            ),
        };
        GasData::assemble(&self.meta, &tree, &slot_prim, prims)
    }

    /// The global primitive of every leaf slot ([`NO_PRIMITIVE`] for padding).
    pub(crate) fn slot_globals(&self) -> Vec<u32> {
        if let Some(plan) = &self.refit {
            return plan.slot_prim.clone();
        }
        self.slots
            .iter()
            .map(|s| {
                let Some(rec) = self.meta.inputs.get(s.build_input as usize) else {
                    return NO_PRIMITIVE;
                };
                if s.primitive_index == u32::MAX {
                    return NO_PRIMITIVE;
                }
                s.primitive_index
                    .checked_sub(rec.primitive_index_offset)
                    .and_then(|k| k.checked_add(rec.first))
                    .unwrap_or(NO_PRIMITIVE)
            })
            .collect()
    }

    /// A structure given as host data (loaded from bytes, or read back from another device)
    /// uploaded to this device in `layout` (custom primitives, spheres and curves always in the
    /// binary layout): the binary tree is made from the data's 4-wide one
    /// ([`Bvh2::from_wide`]). It traces the data's hits and can be updated and compacted as the
    /// structure it was saved from, motion keys included.
    pub fn from_data(
        ctx: &CudaContext,
        data: &GasData,
        layout: NodeLayout,
    ) -> Result<CudaGas, CudaError> {
        let tree = Bvh2::from_wide(&data.bvh.nodes);
        CudaGas::upload_with_layout(ctx, data, &tree, layout)
    }
}

/// The binary tree of the device layout's words: node 0 holds the root's children (one child:
/// the root is that child; none: an empty tree), each inner child the index of a later node.
/// Leaves keep their slot ranges. A node reached twice is an error.
pub(crate) fn tree_of_words(words: &[u32]) -> Result<Bvh2, LoadError> {
    let n = words.len() / NODE_WORDS;
    let bad = |i: usize| LoadError::Invalid {
        what: "device node",
        index: i as u64,
    };
    let node = |i: usize| &words[i * NODE_WORDS..(i + 1) * NODE_WORDS];
    // One child of device node `i`: box, link, count (`None`: unused).
    let child = |i: usize, k: usize| -> Option<(Aabb, u32, u32)> {
        let w = node(i);
        let f = |j: usize| f32::from_bits(w[j]);
        let (c, count) = (w[12 + k], w[14 + k]);
        if count == 0 && c == u32::MAX {
            return None;
        }
        Some((
            Aabb::new(
                [f(4 * k), f(4 * k + 2), f(8 + 2 * k)].into(),
                [f(4 * k + 1), f(4 * k + 3), f(9 + 2 * k)].into(),
            ),
            c,
            count,
        ))
    };
    let mut slots = 0u32;
    let mut out: Vec<Bvh2Node> = Vec::new();
    if n == 0 {
        return Ok(Bvh2::default());
    }
    // Device builds number nodes in no particular order: a node reached twice is an error,
    // so that no walk over damaged memory loops.
    let mut seen = vec![false; n];
    seen[0] = true;
    let mut enter =
        |c: u32| -> bool { (c as usize) < n && !std::mem::replace(&mut seen[c as usize], true) };
    let set = |out: &mut Vec<Bvh2Node>, at: usize, b: Aabb, first: u32, count: u32| {
        out[at] = Bvh2Node {
            min: b.min.to_array(),
            left_first: first,
            max: b.max.to_array(),
            count,
        };
    };
    // (Bvh2 node to fill as an inner node over device node `d`'s two children, d)
    let mut work: Vec<(usize, usize)> = Vec::new();
    match (child(0, 0), child(0, 1)) {
        (None, None) => return Ok(Bvh2::default()),
        (Some((b, c, count)), None) | (None, Some((b, c, count))) => {
            out.push(Bvh2Node {
                min: [0.0; 3],
                left_first: 0,
                max: [0.0; 3],
                count: 0,
            });
            if count > 0 {
                set(&mut out, 0, b, c, count);
                slots = c.saturating_add(count);
            } else {
                if !enter(c) {
                    return Err(bad(0));
                }
                work.push((0, c as usize));
                out[0].min = b.min.to_array();
                out[0].max = b.max.to_array();
            }
        }
        (Some((b0, _, _)), Some((b1, _, _))) => {
            let u = b0.union(&b1);
            out.push(Bvh2Node {
                min: u.min.to_array(),
                left_first: 0,
                max: u.max.to_array(),
                count: 0,
            });
            work.push((0, 0));
        }
    }
    while let Some((at, d)) = work.pop() {
        let first = out.len();
        out[at].left_first = first as u32;
        out[at].count = 0;
        out.push(out[at]);
        out.push(out[at]);
        for k in 0..2 {
            // Below the root every binary node has two children.
            let Some((b, c, count)) = child(d, k) else {
                return Err(bad(d));
            };
            if count > 0 {
                set(&mut out, first + k, b, c, count);
                slots = slots.max(c.saturating_add(count));
            } else {
                if !enter(c) {
                    return Err(bad(d));
                }
                set(&mut out, first + k, b, 0, 0);
                work.push((first + k, c as usize));
            }
        }
    }
    Ok(Bvh2 {
        nodes: out,
        prim_order: (0..slots).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use oxray_core::{BuildOptions, TriangleInput, VertexBuffer};

    #[test]
    fn the_device_words_of_a_tree_give_back_its_leaves_and_boxes() {
        let v: Vec<[f32; 3]> = (0..900)
            .map(|i| [(i % 31) as f32, (i % 7) as f32 * 0.3, (i / 90) as f32])
            .collect();
        let (_, tree) = GasData::build_with_tree(
            &BuildOptions::default(),
            &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()],
        )
        .unwrap();
        let words = crate::layout::bvh2_words(&tree).unwrap();
        let back = tree_of_words(&words).unwrap();
        let leaves = |t: &Bvh2| {
            let mut l: Vec<(u32, u32, [u32; 6])> = Vec::new();
            let mut stack = vec![0usize];
            while let Some(i) = stack.pop() {
                let n = t.nodes[i];
                if n.is_leaf() {
                    let b = [n.min, n.max].concat();
                    l.push((
                        n.left_first,
                        n.count,
                        std::array::from_fn(|k| b[k].to_bits()),
                    ));
                } else {
                    stack.push(n.left_first as usize);
                    stack.push(n.left_first as usize + 1);
                }
            }
            l.sort_unstable();
            l
        };
        assert_eq!(leaves(&back), leaves(&tree));
        assert_eq!(back.nodes[0].bounds(), tree.nodes[0].bounds());
        // Words that point back at a parent are refused.
        let mut looped = words.clone();
        looped[12] = 0;
        looped[14] = 0;
        assert!(tree_of_words(&looped).is_err());
    }

    #[test]
    fn a_tree_of_one_leaf_comes_back_as_one_leaf() {
        let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let (_, tree) = GasData::build_with_tree(
            &BuildOptions::default(),
            &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()],
        )
        .unwrap();
        let back = tree_of_words(&crate::layout::bvh2_words(&tree).unwrap()).unwrap();
        assert_eq!(back.nodes.len(), 1);
        assert!(back.nodes[0].is_leaf());
        assert_eq!(back.nodes[0].bounds(), tree.nodes[0].bounds());
    }
}
