//! The device layout of a triangle GAS: node and triangle arrays in the form the kernels read,
//! made from a [`GasExport`].
//!
//! Two node layouts exist:
//!
//! - [`NodeLayout::Bvh2`], the default: a binary BVH of 64-byte nodes (Aila and Laine's layout)
//!   made by splitting each 4-wide node into a pair of pairs. Same hits as the CPU, bit for bit,
//!   up to ties (which of two hits at exactly the same distance is reported). On an H100 its
//!   closest-hit kernel is 1.2-1.8x faster than the 4-wide one (docs/gpu-backend.md).
//! - [`NodeLayout::Bvh4`]: the CPU backend's 4-wide nodes, byte for byte (128 bytes, one cache
//!   line, rows of four lanes). The kernel walks them in the CPU kernel's order, so hits are
//!   bit-identical to the CPU's, ties included; its any-hit kernel is 5-15 % faster.
//!
//! Triangles are stored per leaf slot as three `float4` (48 bytes; `w` unused), so that a thread
//! reads one triangle with three 16-byte loads.

use oxray_bvh::{Bvh4Node, GasExport};
use oxray_core::Aabb;

/// The node layout a [`CudaGas`](crate::CudaGas) is uploaded in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum NodeLayout {
    /// The CPU backend's 4-wide BVH, unchanged: 128-byte nodes. Hits are bit-identical to the
    /// CPU backend's, ties included.
    Bvh4,
    /// A binary BVH of 64-byte nodes, split from the 4-wide one: the same hits up to ties, and
    /// the faster closest-hit kernel. The default.
    #[default]
    Bvh2,
}

impl NodeLayout {
    /// Bytes of one node.
    pub fn node_bytes(self) -> usize {
        match self {
            NodeLayout::Bvh4 => 128,
            NodeLayout::Bvh2 => 64,
        }
    }

    /// A short name (`bvh4`, `bvh2`).
    pub fn name(self) -> &'static str {
        match self {
            NodeLayout::Bvh4 => "bvh4",
            NodeLayout::Bvh2 => "bvh2",
        }
    }
}

/// What a hit on a leaf slot reports: primitive index, SBT-GAS index, build input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct SlotInfo {
    pub primitive_index: u32,
    pub sbt_gas_index: u32,
    pub build_input: u32,
}

/// The arrays uploaded to the device, as 32-bit words, plus the host-side slot table.
#[derive(Clone, Debug)]
pub(crate) struct DeviceLayout {
    pub layout: NodeLayout,
    /// Nodes: 32 words each (Bvh4) or 16 (Bvh2).
    pub nodes: Vec<u32>,
    /// Three `float4` per leaf slot.
    pub triangles: Vec<f32>,
    /// Per leaf slot; padding slots report nothing (the kernels never reach them).
    pub slots: Vec<SlotInfo>,
}

/// The largest slot index the hit record can carry (bit 31 holds the facing).
pub(crate) const MAX_SLOTS: usize = 0x7FFF_FFFF;

impl DeviceLayout {
    /// Lays out an export. Fails only when it holds more slots or nodes than 31-bit indices
    /// reach.
    pub fn new(export: &GasExport, layout: NodeLayout) -> Result<Self, String> {
        if export.slots.len() > MAX_SLOTS {
            return Err(format!(
                "{} leaf slots; at most {MAX_SLOTS}",
                export.slots.len()
            ));
        }
        let nodes = match layout {
            NodeLayout::Bvh4 => bytemuck::cast_slice::<Bvh4Node, u32>(&export.nodes).to_vec(),
            NodeLayout::Bvh2 => bvh2_words(&export.nodes)?,
        };
        let mut triangles = Vec::with_capacity(export.slots.len() * 12);
        let mut slots = Vec::with_capacity(export.slots.len());
        for s in &export.slots {
            match s {
                Some(t) => {
                    for p in t.vertices {
                        triangles.extend_from_slice(&[p[0], p[1], p[2], 0.0]);
                    }
                    slots.push(SlotInfo {
                        primitive_index: t.primitive_index,
                        sbt_gas_index: t.sbt_gas_index,
                        build_input: t.build_input,
                    });
                }
                None => {
                    triangles.extend_from_slice(&[0.0; 12]);
                    slots.push(SlotInfo {
                        primitive_index: u32::MAX,
                        sbt_gas_index: 0,
                        build_input: 0,
                    });
                }
            }
        }
        Ok(DeviceLayout {
            layout,
            nodes,
            triangles,
            slots,
        })
    }

    /// Bytes of nodes and triangles on the device.
    pub fn device_bytes(&self) -> usize {
        4 * (self.nodes.len() + self.triangles.len())
    }
}

/// One child of a binary node: its box and link (`count == 0`: inner node `child`; otherwise
/// the leaf slots `child .. child + count`). An empty box marks an unused child.
#[derive(Clone, Copy, Debug)]
struct Bvh2Child {
    bounds: Aabb,
    child: u32,
    count: u32,
}

const UNUSED: Bvh2Child = Bvh2Child {
    bounds: Aabb::EMPTY,
    child: u32::MAX,
    count: 0,
};

/// Splits every 4-wide node into binary nodes: two children stay one node, three become a node
/// over one child and a pair, four a node over two pairs; the pairing taken is the one whose
/// pair boxes have the least total surface area. Node 0 is the root.
fn bvh2_words(nodes4: &[Bvh4Node]) -> Result<Vec<u32>, String> {
    // Binary nodes as child pairs; index 0 is reserved for the root.
    let mut out: Vec<[Bvh2Child; 2]> = vec![[UNUSED; 2]];
    // (4-wide node, binary node index that receives its split)
    let mut work = vec![(0usize, 0usize)];
    while let Some((n4, at)) = work.pop() {
        let node = &nodes4[n4];
        let mut kids: Vec<Bvh2Child> = Vec::with_capacity(4);
        for lane in 0..4 {
            if !node.is_used(lane) {
                continue;
            }
            let count = node.count[lane];
            let mut child = node.child[lane];
            if count == 0 {
                // Inner: give its split a binary node now, fill it later.
                let idx = out.len();
                out.push([UNUSED; 2]);
                work.push((child as usize, idx));
                child = idx as u32;
            }
            kids.push(Bvh2Child {
                bounds: node.child_bounds(lane),
                child,
                count,
            });
        }
        let pair = |a: Bvh2Child, b: Bvh2Child, out: &mut Vec<[Bvh2Child; 2]>| {
            let idx = out.len();
            out.push([a, b]);
            Bvh2Child {
                bounds: a.bounds.union(&b.bounds),
                child: idx as u32,
                count: 0,
            }
        };
        let area = |a: &Bvh2Child, b: &Bvh2Child| a.bounds.union(&b.bounds).half_area();
        out[at] = match kids.len() {
            0 => [UNUSED; 2],
            1 => [kids[0], UNUSED],
            2 => [kids[0], kids[1]],
            3 => {
                // Pair the two whose box is smallest; the third stays a direct child.
                let options = [(0, 1, 2), (0, 2, 1), (1, 2, 0)];
                let (i, j, k) = options
                    .into_iter()
                    .min_by(|x, y| {
                        area(&kids[x.0], &kids[x.1]).total_cmp(&area(&kids[y.0], &kids[y.1]))
                    })
                    .unwrap_or((0, 1, 2));
                let p = pair(kids[i], kids[j], &mut out);
                [kids[k], p]
            }
            _ => {
                let options = [(0, 1, 2, 3), (0, 2, 1, 3), (0, 3, 1, 2)];
                let cost = |o: &(usize, usize, usize, usize)| {
                    area(&kids[o.0], &kids[o.1]) + area(&kids[o.2], &kids[o.3])
                };
                let (a, b, c, d) = options
                    .into_iter()
                    .min_by(|x, y| cost(x).total_cmp(&cost(y)))
                    .unwrap_or((0, 1, 2, 3));
                let p = pair(kids[a], kids[b], &mut out);
                let q = pair(kids[c], kids[d], &mut out);
                [p, q]
            }
        };
    }
    if out.len() > MAX_SLOTS {
        return Err(format!("{} binary nodes; at most {MAX_SLOTS}", out.len()));
    }
    let mut words = Vec::with_capacity(out.len() * 16);
    for [c0, c1] in &out {
        let (l0, h0, l1, h1) = (c0.bounds.min, c0.bounds.max, c1.bounds.min, c1.bounds.max);
        for f in [
            l0.x, h0.x, l0.y, h0.y, l1.x, h1.x, l1.y, h1.y, l0.z, h0.z, l1.z, h1.z,
        ] {
            words.push(f.to_bits());
        }
        words.extend_from_slice(&[c0.child, c1.child, c0.count, c1.count]);
    }
    Ok(words)
}
