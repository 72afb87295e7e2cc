//! The device layout of a triangle GAS: node and triangle arrays in the form the kernels read,
//! made from a [`GasExport`] and the canonical binary tree the builder made.
//!
//! Two node layouts exist, both derived from that one tree:
//!
//! - [`NodeLayout::Bvh2`], the default: the builder's binary tree itself, as 64-byte nodes that
//!   hold both children's boxes (Aila and Laine's layout). Same hits as the CPU, bit for bit, up
//!   to ties (which of two hits at exactly the same distance is reported).
//! - [`NodeLayout::Bvh4`]: the CPU backend's 4-wide nodes, byte for byte (128 bytes, one cache
//!   line, rows of four lanes). The kernel walks them in the CPU kernel's order, so hits are
//!   bit-identical to the CPU's, ties included; its any-hit kernel is 5-15 % faster.
//!
//! Triangles are stored per leaf slot as three `float4` (48 bytes; `w` unused), so that a thread
//! reads one triangle with three 16-byte loads.

use oxray_bvh::{Bvh2, Bvh4Node, GasExport};
use oxray_core::Aabb;

/// The node layout a [`CudaGas`](crate::CudaGas) is uploaded in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum NodeLayout {
    /// The CPU backend's 4-wide BVH, unchanged: 128-byte nodes. Hits are bit-identical to the
    /// CPU backend's, ties included.
    Bvh4,
    /// The builder's binary BVH as 64-byte nodes: the same hits up to ties, and the faster
    /// closest-hit kernel. The default.
    #[default]
    Bvh2,
}

impl NodeLayout {
    /// Bytes of one node.
    #[must_use]
    pub fn node_bytes(self) -> usize {
        match self {
            NodeLayout::Bvh4 => 128,
            NodeLayout::Bvh2 => 64,
        }
    }

    /// A short name (`bvh4`, `bvh2`).
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            NodeLayout::Bvh4 => "bvh4",
            NodeLayout::Bvh2 => "bvh2",
        }
    }
}

/// What a hit on a leaf slot reports: primitive index, SBT-GAS index, build input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SlotInfo {
    /// Primitive index with the input's offset.
    pub primitive_index: u32,
    /// SBT-GAS index.
    pub sbt_gas_index: u32,
    /// Build input.
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
    /// Lays out an export; `tree` is the canonical binary tree of the same build, its leaves
    /// pointing at the export's slots ([`GasData::build_with_tree`](oxray_bvh::GasData::build_with_tree)).
    /// Fails only when it holds more slots or nodes than 31-bit indices reach.
    pub fn new(export: &GasExport, tree: &Bvh2, layout: NodeLayout) -> Result<Self, String> {
        if export.slots.len() > MAX_SLOTS {
            return Err(format!(
                "{} leaf slots; at most {MAX_SLOTS}",
                export.slots.len()
            ));
        }
        let nodes = match layout {
            NodeLayout::Bvh4 => bytemuck::cast_slice::<Bvh4Node, u32>(&export.nodes).to_vec(),
            NodeLayout::Bvh2 => bvh2_words(tree)?,
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
                    // NaN, as the CPU's inactive lanes: no ray hits it, and a random vertex
                    // access reads NaN (guide §13.9).
                    triangles.extend_from_slice(&[f32::NAN; 12]);
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

/// The canonical binary tree as device nodes: one node per inner node of the tree, holding its
/// two children (a leaf child is its slot range); node 0 is the root. A tree whose root is a
/// leaf becomes one node with one child; an empty tree one node with none.
pub(crate) fn bvh2_words(tree: &Bvh2) -> Result<Vec<u32>, String> {
    let mut out: Vec<[Bvh2Child; 2]> = vec![[UNUSED; 2]];
    if let Some(root) = tree.nodes.first() {
        if root.is_leaf() {
            out[0][0] = Bvh2Child {
                bounds: root.bounds(),
                child: root.left_first,
                count: root.count,
            };
        } else {
            // (inner node of the tree, device node that receives its children)
            let mut work = vec![(0usize, 0usize)];
            while let Some((n, at)) = work.pop() {
                let first = tree.nodes[n].left_first as usize;
                for (k, c) in [first, first + 1].into_iter().enumerate() {
                    let node = &tree.nodes[c];
                    let (child, count) = if node.is_leaf() {
                        (node.left_first, node.count)
                    } else {
                        let idx = out.len();
                        out.push([UNUSED; 2]);
                        work.push((c, idx));
                        (idx as u32, 0)
                    };
                    out[at][k] = Bvh2Child {
                        bounds: node.bounds(),
                        child,
                        count,
                    };
                }
            }
        }
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

/// The device's view of an instance's child: its index among the IAS's children (for the host)
/// and its binary nodes and triangles in device memory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct ChildRef {
    pub index: u32,
    pub nodes_addr: u64,
    pub triangles_addr: u64,
}

/// Words per instance slot: the world-to-object rows (12), the world box's corners (2 x 4, the
/// lower one's `w` holding the child index), and the child's two device addresses (4).
pub(crate) const INSTANCE_WORDS: usize = 24;

/// One level of instances over GASes as the IAS kernels read it: the top-level binary tree
/// (its leaves are instance slots) and the instance table in slot order.
#[derive(Clone, Debug)]
pub(crate) struct IasLayout {
    pub nodes: Vec<u32>,
    pub instances: Vec<u32>,
}

impl IasLayout {
    /// Lays out an IAS; `children[slot]` is the device view of the child of the instance in
    /// that slot (`None`: never hit).
    pub fn new(
        ias: &oxray_bvh::IasData,
        tree: &Bvh2,
        children: &[Option<ChildRef>],
    ) -> Result<Self, String> {
        if ias.instances.len() > MAX_SLOTS {
            return Err(format!(
                "{} instances; at most {MAX_SLOTS}",
                ias.instances.len()
            ));
        }
        let nodes = bvh2_words(tree)?;
        let mut instances = Vec::with_capacity(ias.instances.len() * INSTANCE_WORDS);
        for (slot, inst) in ias.instances.iter().enumerate() {
            for f in inst.world_to_object.0 {
                instances.push(f.to_bits());
            }
            let b = ias.boxes[slot];
            let child = children.get(slot).copied().flatten();
            let index = child.map_or(u32::MAX, |c| c.index);
            instances.extend_from_slice(&[
                b.min.x.to_bits(),
                b.min.y.to_bits(),
                b.min.z.to_bits(),
                index,
            ]);
            instances.extend_from_slice(&[
                b.max.x.to_bits(),
                b.max.y.to_bits(),
                b.max.z.to_bits(),
                0,
            ]);
            let (n, t) = child.map_or((0, 0), |c| (c.nodes_addr, c.triangles_addr));
            instances.extend_from_slice(&[n as u32, (n >> 32) as u32, t as u32, (t >> 32) as u32]);
        }
        Ok(IasLayout { nodes, instances })
    }

    /// Bytes on the device.
    pub fn device_bytes(&self) -> usize {
        4 * (self.nodes.len() + self.instances.len())
    }
}
