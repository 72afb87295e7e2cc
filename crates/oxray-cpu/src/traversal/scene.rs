//! Traversal of a traversable graph (guide §2.5, §5.4, §5.9): instance ASes and static
//! transforms above GASes, any number of levels deep. The ray is carried into each object space;
//! its direction is transformed without normalising, so distances t agree across levels and the
//! interval shrinks across instances.

use super::kernel::{traverse, Entry, GasVisitor};
use super::leaf::{
    AabbLeaves, CurveLeaves, LeafEnd, LeafIntersector, SphereLeaves, TriangleLeaves,
};
use super::motion::{
    MotionAabbLeaves, MotionCurveLeaves, MotionSphereLeaves, MotionTriangleLeaves,
};
use super::node::{Bvh4, Bvh8Scalar};
use super::ray::PreparedRay;
use crate::gas::CpuNode;
use crate::{Gas, Ias, Isa};
use oxray_bvh::GasKind;
use oxray_bvh::InstanceData as InstanceRecord;
use oxray_core::ray::min_ignore_nan;
use oxray_core::{
    KeySample, MatrixMotionTransform, Ray, SrtMotionTransform, StaticTransform, Transform,
    MAX_TRAVERSABLE_GRAPH_DEPTH,
};

/// One transform on the way from the root to a GAS. A motion transform keeps the ray's time
/// and its interpolated transform (guide §5.10.4, §5.10.5: the transform at that time).
#[derive(Clone, Copy)]
pub(crate) enum Level<'s> {
    Instance(&'s InstanceRecord),
    Static(&'s StaticTransform),
    MatrixMotion(&'s MatrixMotionTransform, f32),
    SrtMotion(&'s SrtMotionTransform, f32),
}

impl Level<'_> {
    /// Object-to-world transform of this level (a motion transform's at the ray's time).
    pub fn object_to_world(&self) -> Transform {
        match self {
            Level::Instance(i) => i.object_to_world,
            Level::Static(s) => *s.transform(),
            Level::MatrixMotion(m, time) => m.object_to_world_at(*time).unwrap_or_default(),
            Level::SrtMotion(m, time) => m.object_to_world_at(*time).unwrap_or_default(),
        }
    }
    /// World-to-object transform of this level (a motion transform's at the ray's time).
    pub fn world_to_object(&self) -> Transform {
        match self {
            Level::Instance(i) => i.world_to_object,
            Level::Static(s) => *s.inverse(),
            Level::MatrixMotion(..) | Level::SrtMotion(..) => self
                .object_to_world()
                .inverse_cofactors()
                .unwrap_or_default(),
        }
    }
}

/// The path from the root to the current GAS: the transform list of guide §13.11 and what the
/// instances along it add up to.
#[derive(Clone, Copy)]
pub(crate) struct Path<'s> {
    pub levels: [Option<Level<'s>>; MAX_TRAVERSABLE_GRAPH_DEPTH as usize],
    pub len: usize,
    /// Sum of the SBT offsets of the instances on the path (§7.3.1).
    pub sbt_offset: u32,
    /// The instance nearest to the GAS, whose flags override its ancestors' (§5.4).
    pub instance: Option<&'s InstanceRecord>,
}

impl<'s> Path<'s> {
    pub const ROOT: Path<'static> = Path {
        levels: [None; MAX_TRAVERSABLE_GRAPH_DEPTH as usize],
        len: 0,
        sbt_offset: 0,
        instance: None,
    };

    fn push(&self, level: Level<'s>) -> Option<Path<'s>> {
        if self.len >= self.levels.len() {
            return None;
        }
        let mut p = *self;
        p.levels[p.len] = Some(level);
        p.len += 1;
        if let Level::Instance(i) = level {
            p.sbt_offset = p.sbt_offset.wrapping_add(i.sbt_offset);
            p.instance = Some(i);
        }
        Some(p)
    }

    /// The transforms from the root (index 0) to the GAS.
    pub fn levels(&self) -> impl DoubleEndedIterator<Item = &Level<'s>> {
        self.levels[..self.len].iter().flatten()
    }
}

/// A visitor of a whole graph: a [`GasVisitor`] told which GAS it is in and where.
pub(crate) trait SceneVisitor<'s>: GasVisitor {
    /// Called before the candidates of `gas`, reached along `path` with `object_ray`.
    fn enter_gas(&mut self, gas: &'s Gas, path: &Path<'s>, object_ray: &Ray);
    /// The ray's visibility mask: instances whose mask shares no bit with it are skipped.
    fn ray_mask(&self) -> u8;
    /// A path deeper than 31 levels was met; traversal of that branch stops.
    fn graph_too_deep(&mut self) {}
}

/// A borrowed traversable.
#[derive(Clone, Copy)]
pub(crate) enum NodeRef<'s> {
    Gas(&'s Gas),
    Ias(&'s Ias),
    Static(&'s StaticTransform),
    MatrixMotion(&'s MatrixMotionTransform),
    SrtMotion(&'s SrtMotionTransform),
}

impl<'s> From<&'s CpuNode> for NodeRef<'s> {
    fn from(t: &'s CpuNode) -> Self {
        match t {
            CpuNode::Gas(g) => NodeRef::Gas(g),
            CpuNode::Ias(i) => NodeRef::Ias(i),
            CpuNode::Static(s) => NodeRef::Static(s),
            CpuNode::MatrixMotion(m) => NodeRef::MatrixMotion(m),
            CpuNode::SrtMotion(m) => NodeRef::SrtMotion(m),
        }
    }
}

impl<'s> NodeRef<'s> {
    /// The CPU structure behind a handle, borrowed; `None` for the null handle or a structure
    /// of another backend (which a CPU traversal cannot enter).
    #[inline]
    pub fn of(handle: &'s oxray_core::TraversableHandle) -> Option<NodeRef<'s>> {
        // The CPU's own structures first (the common root, found without asking the backend).
        if let Some(g) = handle.downcast_ref::<Gas>() {
            return Some(NodeRef::Gas(g));
        }
        // A static transform reports its child's backend: over another device's structure, it
        // cannot be entered either.
        if !matches!(
            handle.backend(),
            Some(oxray_core::BackendKind::Cpu | oxray_core::BackendKind::Any)
        ) {
            return None;
        }
        if let Some(i) = handle.downcast_ref::<Ias>() {
            return Some(NodeRef::Ias(i));
        }
        if let Some(m) = handle.downcast_ref::<MatrixMotionTransform>() {
            return Some(NodeRef::MatrixMotion(m));
        }
        if let Some(m) = handle.downcast_ref::<SrtMotionTransform>() {
            return Some(NodeRef::SrtMotion(m));
        }
        handle
            .downcast_ref::<StaticTransform>()
            .map(NodeRef::Static)
    }
}

/// Traverses the graph under `node` with `ray` in `node`'s space. Returns the final tmax and
/// whether the visitor ended traversal. The leaf intersector is chosen here, once per
/// structure entered.
pub(crate) fn traverse_node<'s, V: SceneVisitor<'s>>(
    node: NodeRef<'s>,
    path: &Path<'s>,
    ray: &Ray,
    visitor: &mut V,
    stack: &mut [Entry],
) -> (f32, bool) {
    match node {
        NodeRef::Gas(gas) => {
            // Guide §5.10.1: a structure with motion is hit at the ray's time, and not at all
            // outside its range where a vanish flag says so.
            let sample = match &gas.motion {
                None => None,
                Some(m) => match m.options.sample(ray.time) {
                    Some(s) => Some(s),
                    None => return (ray.tmax, false),
                },
            };
            visitor.enter_gas(gas, path, ray);
            let Some(prepared) = PreparedRay::new(ray) else {
                return (ray.tmax, false);
            };
            let (tmin, tmax) = (ray.tmin, ray.tmax);
            if let Some(s) = sample {
                return traverse_motion_gas(gas, s, &prepared, tmin, tmax, visitor, stack);
            }
            match gas.kind {
                GasKind::Triangles => {
                    let leaves = TriangleLeaves(&gas.triangles);
                    traverse_nodes(
                        Nodes::of(gas),
                        &leaves,
                        &prepared,
                        tmin,
                        tmax,
                        visitor,
                        stack,
                    )
                }
                GasKind::CustomPrimitives => {
                    let leaves = AabbLeaves(&gas.aabbs);
                    traverse_nodes(
                        Nodes::of(gas),
                        &leaves,
                        &prepared,
                        tmin,
                        tmax,
                        visitor,
                        stack,
                    )
                }
                GasKind::Spheres => {
                    let leaves = SphereLeaves(&gas.spheres);
                    traverse_nodes(
                        Nodes::of(gas),
                        &leaves,
                        &prepared,
                        tmin,
                        tmax,
                        visitor,
                        stack,
                    )
                }
                GasKind::Curves => {
                    let leaves = CurveLeaves(&gas.curves);
                    traverse_nodes(
                        Nodes::of(gas),
                        &leaves,
                        &prepared,
                        tmin,
                        tmax,
                        visitor,
                        stack,
                    )
                }
            }
        }
        NodeRef::Ias(ias) => {
            // Guide §5.10.3: an IAS's vanish flags hide every instance outside its range.
            if ias.motion.vanishes_at(ray.time) {
                return (ray.tmax, false);
            }
            let Some(prepared) = PreparedRay::new(ray) else {
                return (ray.tmax, false);
            };
            let leaves = InstanceLeaves { ias, path, ray };
            let (nodes, tmin, tmax) = (&ias.bvh.nodes, ray.tmin, ray.tmax);
            traverse::<Bvh4, _, _>(nodes, &leaves, &prepared, tmin, tmax, visitor, stack)
        }
        NodeRef::Static(st) => {
            let Some(child) = NodeRef::of(st.child()) else {
                return (ray.tmax, false);
            };
            let Some(p) = path.push(Level::Static(st)) else {
                visitor.graph_too_deep();
                return (ray.tmax, true);
            };
            let r = transform_ray(st.inverse(), ray);
            traverse_node(child, &p, &r, visitor, stack)
        }
        NodeRef::MatrixMotion(m) => {
            let o2w = m.object_to_world_at(ray.time);
            let level = Level::MatrixMotion(m, ray.time);
            traverse_motion_transform(m.child(), o2w, level, path, ray, visitor, stack)
        }
        NodeRef::SrtMotion(m) => {
            let o2w = m.object_to_world_at(ray.time);
            let level = Level::SrtMotion(m, ray.time);
            traverse_motion_transform(m.child(), o2w, level, path, ray, visitor, stack)
        }
    }
}

/// Enters a motion transform's child with the ray carried by the transform at the ray's time
/// (`o2w`; `None` where the transform vanishes). An interpolated matrix may be singular where
/// its keys are not (a scale passing through zero): the child is then not hit at that time.
fn traverse_motion_transform<'s, V: SceneVisitor<'s>>(
    child: &'s oxray_core::TraversableHandle,
    o2w: Option<Transform>,
    level: Level<'s>,
    path: &Path<'s>,
    ray: &Ray,
    visitor: &mut V,
    stack: &mut [Entry],
) -> (f32, bool) {
    let Some(w2o) = o2w.and_then(|m| m.inverse_cofactors()) else {
        return (ray.tmax, false);
    };
    let Some(child) = NodeRef::of(child) else {
        return (ray.tmax, false);
    };
    let Some(p) = path.push(level) else {
        visitor.graph_too_deep();
        return (ray.tmax, true);
    };
    let r = transform_ray(&w2o, ray);
    traverse_node(child, &p, &r, visitor, stack)
}

/// Traverses a GAS with motion at the keys `s` of the ray's time: its tree bounds every key,
/// and the leaves interpolate their primitives between the two keys.
#[inline(never)]
fn traverse_motion_gas<V: GasVisitor>(
    gas: &Gas,
    s: KeySample,
    prepared: &PreparedRay,
    tmin: f32,
    tmax: f32,
    visitor: &mut V,
    stack: &mut [Entry],
) -> (f32, bool) {
    let f = s.fraction;
    // The nodes of the time part holding the ray's time, where the structure has parts.
    // Parts are kept for one layout: the 8-wide one where the structure has it (a 4-wide
    // kernel then walks the one tree), else the 4-wide one.
    let one_tree = Nodes::of(gas);
    let nodes = match gas.motion.as_ref().and_then(|m| m.segments.as_ref()) {
        Some(parts) => {
            let p = parts.part(s);
            match (parts.bvh.get(p), parts.bvh8.get(p)) {
                (_, Some(b8)) => Nodes {
                    bvh8: Some(&b8[..]),
                    qbvh8: None,
                    ..one_tree
                },
                (Some(b4), None) => Nodes {
                    bvh: &b4[..],
                    qbvh8: None,
                    ..one_tree
                },
                (None, None) => one_tree,
            }
        }
        None => one_tree,
    };
    match gas.kind {
        GasKind::Triangles => {
            let (a, b) = gas.triangle_keys(s);
            let leaves = MotionTriangleLeaves { a, b, f };
            traverse_nodes(nodes, &leaves, prepared, tmin, tmax, visitor, stack)
        }
        GasKind::CustomPrimitives => {
            let (a, b) = gas.aabb_keys(s);
            let leaves = MotionAabbLeaves { a, b, f };
            traverse_nodes(nodes, &leaves, prepared, tmin, tmax, visitor, stack)
        }
        GasKind::Spheres => {
            let (a, b) = gas.sphere_keys(s);
            let leaves = MotionSphereLeaves { a, b, f };
            traverse_nodes(nodes, &leaves, prepared, tmin, tmax, visitor, stack)
        }
        GasKind::Curves => {
            let (a, b) = gas.curve_keys(s);
            let leaves = MotionCurveLeaves { a, b, f };
            traverse_nodes(nodes, &leaves, prepared, tmin, tmax, visitor, stack)
        }
    }
}

/// A GAS's nodes (its own, or a motion structure's time part's) and the kernel that walks them
/// (the structure's: see [`Gas::isa`]).
#[derive(Clone, Copy)]
struct Nodes<'a> {
    isa: Isa,
    bvh: &'a [oxray_bvh::Bvh4Node],
    bvh8: Option<&'a [oxray_bvh::Bvh8Node]>,
    /// The quantised nodes, where the kernel is a quantised one.
    qbvh8: Option<&'a [oxray_bvh::QBvh8Node]>,
}

impl<'a> Nodes<'a> {
    /// The GAS's own nodes and the kernel it was given (once, when it was built or loaded).
    #[inline(always)]
    fn of(gas: &'a Gas) -> Nodes<'a> {
        Nodes {
            isa: gas.isa(),
            bvh: &gas.bvh.nodes,
            bvh8: gas.bvh8.as_ref().map(|b| &b.nodes[..]),
            qbvh8: gas.quantized_nodes().map(|q| &q.nodes[..]),
        }
    }
}

/// Traverses `nodes`: the 8-wide ones where there are some and the kernel is not the 4-wide
/// one.
#[inline(always)]
fn traverse_nodes<L: LeafIntersector<V>, V: GasVisitor>(
    Nodes {
        isa,
        bvh,
        bvh8,
        qbvh8,
    }: Nodes<'_>,
    leaves: &L,
    prepared: &PreparedRay,
    tmin: f32,
    tmax: f32,
    visitor: &mut V,
    stack: &mut [Entry],
) -> (f32, bool) {
    #[cfg(target_arch = "x86_64")]
    if let Some(q) = qbvh8 {
        return match isa {
            // SAFETY: a `Gas` holds quantised nodes only for a quantised kernel, given only
            // where `Isa::is_available` found that kernel's features (`Gas::kernel_for`).
            Isa::Avx512Quantized => unsafe {
                super::kernel::traverse_q_avx512(q, leaves, prepared, tmin, tmax, visitor, stack)
            },
            // SAFETY: likewise (`Isa::Avx2Quantized`).
            _ => unsafe {
                super::kernel::traverse_q_avx2(q, leaves, prepared, tmin, tmax, visitor, stack)
            },
        };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = qbvh8;
    let Some(nodes) = bvh8.filter(|_| isa != Isa::Sse) else {
        return traverse::<Bvh4, _, _>(bvh, leaves, prepared, tmin, tmax, visitor, stack);
    };
    match isa {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: a `Gas` is given `Isa::Avx2` only where `Isa::is_available` found AVX2 and
        // the other features of the kernel on this processor (`Gas::kernel_for`).
        Isa::Avx2 => unsafe {
            super::kernel::traverse_avx2(nodes, leaves, prepared, tmin, tmax, visitor, stack)
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: likewise for `Isa::Avx512` and its features.
        Isa::Avx512 => unsafe {
            super::kernel::traverse_avx512(nodes, leaves, prepared, tmin, tmax, visitor, stack)
        },
        _ => traverse::<Bvh8Scalar, _, _>(nodes, leaves, prepared, tmin, tmax, visitor, stack),
    }
}

fn transform_ray(world_to_object: &Transform, ray: &Ray) -> Ray {
    Ray {
        origin: world_to_object.transform_point(ray.origin),
        direction: world_to_object.transform_vector(ray.direction),
        ..*ray
    }
}

/// The leaves of an IAS: instances, in leaf-slot order with their world boxes. Entering one
/// carries the ray into the instance's object space and traverses its child, with the same
/// visitor and the shrinking interval (guide §5.4).
pub(crate) struct InstanceLeaves<'s, 'v> {
    ias: &'s Ias,
    path: &'v Path<'s>,
    /// The ray in the IAS's space.
    ray: &'v Ray,
}

impl<'s, V: SceneVisitor<'s>> LeafIntersector<V> for InstanceLeaves<'s, '_> {
    #[inline(always)]
    fn leaf(
        &self,
        start: u32,
        count: u32,
        prepared: &PreparedRay,
        tmin: f32,
        tmax: &mut f32,
        visitor: &mut V,
        spare: &mut [Entry],
    ) -> LeafEnd {
        let start = start as usize;
        for slot in start..start + count as usize {
            if !prepared.hits_box(&self.ias.boxes[slot], tmin, *tmax) {
                continue;
            }
            let inst = &self.ias.instances[slot];
            // §5.4 / §13.2: an instance is traversed only if its mask shares a bit with the ray's.
            if inst.mask & visitor.ray_mask() == 0 {
                continue;
            }
            let Some(child) = self.ias.nodes[slot].as_ref() else {
                continue;
            };
            let Some(path) = self.path.push(Level::Instance(inst)) else {
                visitor.graph_too_deep();
                return LeafEnd::Stop;
            };
            let r = Ray {
                tmin,
                tmax: *tmax,
                ..transform_ray(&inst.world_to_object, self.ray)
            };
            let before = *tmax;
            let (t, stop) = traverse_node(child.into(), &path, &r, visitor, spare);
            if t < before {
                *tmax = min_ignore_nan(*tmax, t);
            }
            if stop {
                return LeafEnd::Stop;
            }
        }
        LeafEnd::Continue
    }
}
