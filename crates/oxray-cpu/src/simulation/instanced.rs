//! The closest point of the triangles under an IAS to a query point ([`Ias::closest_point`]):
//! the scenes simulation users build by placing meshes (rigid bodies, robots, rooms) rather
//! than by baking them into one mesh.
//!
//! The search visits the instances nearest world box first and skips every instance whose box
//! is farther than the best point so far; in an instance it runs the GAS's own search
//! ([`Gas::closest_point_within`]) on the query point carried into object space, with the best
//! distance so far as its radius. That is exact when the transforms on the way are
//! similarities (rotations, reflections, uniform scales and translations: they scale every
//! distance by one factor), which is what placements are; an instance with a non-uniform scale
//! or a shear, a motion transform (a point query has no time) or a GAS of other primitives is a
//! typed error, never a wrong answer.

use super::{check_point, par_try_batch, ClosestPoint, SurfaceQueryError};
use crate::traversal::NodeRef;
#[allow(unused_imports)] // Named by the docs.
use crate::Gas;
use crate::Ias;
use glam::Vec3;
use oxray_bvh::{Bvh4Node, IasData};
pub use oxray_core::InstanceClosestPoint;
use oxray_core::{Aabb, Transform, MAX_TRAVERSABLE_GRAPH_DEPTH};
use std::cell::RefCell;
use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// Where the search is: the world-to-here and here-to-world transforms, the factor from here to
/// world distances, and the instance nearest below.
#[derive(Clone, Copy)]
struct Frame {
    world_to_here: Transform,
    here_to_world: Transform,
    scale: f32,
    instance: Option<(u32, u32)>,
    depth: u32,
}

impl Frame {
    /// One level down through a transform `to_parent` (object to this frame) whose inverse is
    /// `from_parent`.
    fn enter(
        &self,
        to_parent: &Transform,
        from_parent: &Transform,
        instance: Option<(u32, u32)>,
    ) -> Result<Frame, SurfaceQueryError> {
        let s = to_parent.similarity_scale().ok_or(SurfaceQueryError::Unsupported(
            "the closest point through a transform that is not a similarity (a non-uniform scale or a shear)",
        ))?;
        Ok(Frame {
            world_to_here: from_parent.then_after(&self.world_to_here),
            here_to_world: self.here_to_world.then_after(to_parent),
            scale: self.scale * s,
            instance: instance.or(self.instance),
            depth: self.depth + 1,
        })
    }
}

/// Checks, before any search, that the closest point can be answered under `node`: every
/// transform on the way a similarity, no motion transform, every GAS of triangles without
/// motion; so that a refusal does not depend on the query point. An IAS's answer is kept with
/// it (until an update), so a graph is checked once however many instances share a child.
fn check_graph(node: NodeRef<'_>, depth: u32) -> Result<(), SurfaceQueryError> {
    if depth > MAX_TRAVERSABLE_GRAPH_DEPTH {
        return Err(SurfaceQueryError::Unsupported(
            "a graph deeper than the traversable graph depth limit",
        ));
    }
    let similar = |t: &Transform| {
        t.similarity_scale().map(|_| ()).ok_or(SurfaceQueryError::Unsupported(
            "the closest point through a transform that is not a similarity (a non-uniform scale or a shear)",
        ))
    };
    match node {
        NodeRef::Gas(gas) => super::closest_point::check_gas(gas),
        NodeRef::Ias(ias) => ias
            .closest_support
            .get_or_init(|| {
                for (slot, child) in ias.nodes.iter().enumerate() {
                    let Some(child) = child else { continue };
                    similar(&ias.data().instances[slot].object_to_world)?;
                    check_graph(NodeRef::from(child), depth + 1)?;
                }
                Ok(())
            })
            .clone(),
        NodeRef::Static(st) => match NodeRef::of(st.child()) {
            Some(child) => {
                similar(st.transform())?;
                check_graph(child, depth + 1)
            }
            None => Ok(()),
        },
        NodeRef::MatrixMotion(_) | NodeRef::SrtMotion(_) => Err(SurfaceQueryError::Unsupported(
            "the closest point through a motion transform (a point query has no time)",
        )),
    }
}

/// The squared distance from `p` to box `b` (0 inside).
fn box_distance2(b: &Aabb, p: Vec3) -> f32 {
    (b.min - p).max(p - b.max).max(Vec3::ZERO).length_squared()
}

/// What the best-first walk of an IAS's tree orders: the squared distance's bits (the
/// distances are not negative, so their bits order as they do), [`INNER`] before [`INSTANCE`]
/// at one distance (an inner box may hold an instance box at that distance with a lower
/// slot), and the node index or instance slot.
type Key = (u32, u8, u32);
const INNER: u8 = 0;
const INSTANCE: u8 = 1;

type Heap = BinaryHeap<Reverse<Key>>;

/// Pushes the children of `node`: inner nodes by their box, the instances of leaves by their
/// own world boxes (the CPU's order key: [`box_distance2`] of `data.boxes[slot]`).
fn push_children(heap: &mut Heap, data: &IasData, node: &Bvh4Node, p: Vec3) {
    for lane in 0..4 {
        let b = node.child_bounds(lane);
        if b.min.x.partial_cmp(&b.max.x).is_none_or(|o| o.is_gt()) {
            // An unused lane (an empty box).
            continue;
        }
        let (child, count) = (node.child[lane], node.count[lane]);
        if count == 0 {
            heap.push(Reverse((box_distance2(&b, p).to_bits(), INNER, child)));
        } else {
            for slot in child..child + count {
                let d2 = box_distance2(&data.boxes[slot as usize], p);
                heap.push(Reverse((d2.to_bits(), INSTANCE, slot)));
            }
        }
    }
}

thread_local! {
    /// The heaps of the best-first walks, one per level of the graph (a walk of an IAS under
    /// another's instance runs inside its parent's), kept so that queries allocate nothing
    /// once warm.
    static HEAPS: RefCell<Vec<Heap>> = const { RefCell::new(Vec::new()) };
}

/// Runs `f` with this thread's heap for graph level `depth`.
fn with_heap<R>(depth: u32, f: impl FnOnce(&mut Heap) -> R) -> R {
    let d = depth as usize;
    let mut heap = HEAPS.with(|h| {
        let mut h = h.borrow_mut();
        if h.len() <= d {
            h.resize_with(d + 1, Heap::new);
        }
        std::mem::take(&mut h[d])
    });
    let r = f(&mut heap);
    HEAPS.with(|h| h.borrow_mut()[d] = heap);
    r
}

/// Searches the graph under `node` for a point closer to `world` than `best` (a world
/// distance; `found` holds the point that gave it).
fn search(
    node: NodeRef<'_>,
    frame: &Frame,
    world: Vec3,
    best: &mut f32,
    found: &mut Option<InstanceClosestPoint>,
) -> Result<(), SurfaceQueryError> {
    if frame.depth > MAX_TRAVERSABLE_GRAPH_DEPTH {
        return Err(SurfaceQueryError::Unsupported(
            "a graph deeper than the traversable graph depth limit",
        ));
    }
    let here = frame.world_to_here.transform_point(world);
    match node {
        NodeRef::Gas(gas) => {
            let radius = *best / frame.scale;
            if let Some(c) = gas.closest_point_within(here, radius)? {
                let distance = c.distance * frame.scale;
                if distance < *best {
                    *best = distance;
                    let (instance_id, instance_index) = frame.instance.unwrap_or((u32::MAX, 0));
                    *found = Some(InstanceClosestPoint {
                        closest: ClosestPoint {
                            point: frame.here_to_world.transform_point(c.point),
                            distance,
                            ..c
                        },
                        instance_id,
                        instance_index,
                    });
                }
            }
            Ok(())
        }
        NodeRef::Ias(ias) => with_heap(frame.depth, |heap| {
            // Nearest world box first (the slot breaks ties, so the order is fixed), stopping
            // at the first box farther than the best point: a best-first walk of the top-level
            // tree, whose inner boxes bound the instance boxes below them, gives the instances
            // in that order without measuring them all.
            let data = ias.data();
            let Some(root) = data.bvh.nodes.first() else {
                return Ok(());
            };
            heap.clear();
            push_children(heap, data, root, here);
            while let Some(Reverse((bits, kind, index))) = heap.pop() {
                if f32::from_bits(bits).sqrt() * frame.scale > *best {
                    break;
                }
                if kind == INNER {
                    push_children(heap, data, &data.bvh.nodes[index as usize], here);
                    continue;
                }
                let slot = index as usize;
                let Some(child) = ias.nodes.get(slot).and_then(Option::as_ref) else {
                    continue;
                };
                let inst = &data.instances[slot];
                let next = frame.enter(
                    &inst.object_to_world,
                    &inst.world_to_object,
                    Some((inst.instance_id, inst.index)),
                )?;
                search(NodeRef::from(child), &next, world, best, found)?;
            }
            Ok(())
        }),
        NodeRef::Static(st) => {
            let Some(child) = NodeRef::of(st.child()) else {
                return Ok(());
            };
            let next = frame.enter(st.transform(), st.inverse(), None)?;
            search(child, &next, world, best, found)
        }
        NodeRef::MatrixMotion(_) | NodeRef::SrtMotion(_) => Err(SurfaceQueryError::Unsupported(
            "the closest point through a motion transform (a point query has no time)",
        )),
    }
}

impl Ias {
    /// The closest point of the triangles under this IAS (instances of triangle GASes, of
    /// IASes and of static transforms, placed by similarities) to `point`, with its distance,
    /// triangle, barycentrics and instance; `None` when nothing is under it. As exact as
    /// [`Gas::closest_point`]; where two instances are equally close, the instance whose box is
    /// searched first (nearer, then the lower slot) wins.
    ///
    /// Errors: a non-finite point; an instance under a transform that is not a similarity, a
    /// motion transform, or a GAS of other primitives or with motion anywhere under the IAS
    /// ([`SurfaceQueryError::Unsupported`], [`SurfaceQueryError::NotTriangles`]), whatever the
    /// point (the graph is checked once, before any search).
    ///
    /// ```
    /// use oxray_cpu::{Gas, Ias};
    /// use oxray_core::{BuildOptions, Instance, Transform};
    /// use glam::Vec3;
    /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    /// let gas = std::sync::Arc::new(Gas::from_mesh(&v, &[[0, 1, 2]])?);
    /// let far = Transform::from_translation(Vec3::new(0.0, 0.0, 10.0));
    /// let instances = [
    ///     Instance::new(gas.clone().into()).instance_id(1),
    ///     Instance::new(gas.clone().into()).instance_id(2).transform(far),
    /// ];
    /// let ias = Ias::build(&BuildOptions::default(), &[(&instances[..]).into()])?;
    /// let c = ias.closest_point(Vec3::new(0.25, 0.25, 8.0))?.unwrap();
    /// assert_eq!((c.instance_id, c.closest.distance), (2, 2.0));
    /// assert_eq!(c.closest.point, Vec3::new(0.25, 0.25, 10.0));
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn closest_point(
        &self,
        point: Vec3,
    ) -> Result<Option<InstanceClosestPoint>, SurfaceQueryError> {
        check_point(point)?;
        check_graph(NodeRef::Ias(self), 1)?;
        let frame = Frame {
            world_to_here: Transform::IDENTITY,
            here_to_world: Transform::IDENTITY,
            scale: 1.0,
            instance: None,
            depth: 1,
        };
        let mut best = f32::INFINITY;
        let mut found = None;
        search(NodeRef::Ias(self), &frame, point, &mut best, &mut found)?;
        Ok(found)
    }

    /// The closest points of a batch of points, in parallel (`out[i]` for `points[i]`): the
    /// same as point by point, whatever the number of threads. The first failing query (the
    /// lowest index) is the error; every other output is written.
    pub fn closest_point_batch(
        &self,
        points: &[Vec3],
        out: &mut [Option<InstanceClosestPoint>],
    ) -> Result<(), SurfaceQueryError> {
        par_try_batch(points.len(), out, |i| self.closest_point(points[i]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Affine3A, Quat};

    #[test]
    fn equally_close_instances_go_to_the_nearer_box_then_the_lower_slot() {
        let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let gas = std::sync::Arc::new(Gas::from_mesh(&v, &[[0, 1, 2]]).unwrap());
        // Five copies on one spot: equal boxes, every one at distance 1 from the point.
        let mut instances: Vec<oxray_core::Instance> = (0..5)
            .map(|i| oxray_core::Instance::new(gas.clone().into()).instance_id(10 + i))
            .collect();
        let p = Vec3::new(0.25, 0.25, 1.0);
        let ias = Ias::build(
            &oxray_core::BuildOptions::default(),
            &[(&instances[..]).into()],
        )
        .unwrap();
        let c = ias.closest_point(p).unwrap().unwrap();
        let first = ias.data().instances[0].instance_id;
        assert_eq!((c.instance_id, c.closest.distance), (first, 1.0));
        // A mirrored copy: the same triangle and box, in whichever slot the builder gives it:
        // the lowest slot still wins.
        instances.push(
            oxray_core::Instance::new(gas.clone().into())
                .instance_id(99)
                .transform(Transform::from_affine(&Affine3A::from_scale(Vec3::new(
                    1.0, 1.0, -1.0,
                )))),
        );
        let ias = Ias::build(
            &oxray_core::BuildOptions::default(),
            &[(&instances[..]).into()],
        )
        .unwrap();
        let c = ias.closest_point(p).unwrap().unwrap();
        assert_eq!(c.instance_id, ias.data().instances[0].instance_id);
        // Many instances: the same answers as searching them one by one.
        let many: Vec<oxray_core::Instance> = (0..300)
            .map(|i| {
                let t = Vec3::new((i % 10) as f32, ((i / 10) % 10) as f32, (i / 100) as f32);
                oxray_core::Instance::new(gas.clone().into())
                    .instance_id(i)
                    .transform(Transform::from_translation(t * 1.5))
            })
            .collect();
        let ias = Ias::build(&oxray_core::BuildOptions::default(), &[(&many[..]).into()]).unwrap();
        for k in 0..50 {
            let q = Vec3::new(k as f32 * 0.31, (k * 7 % 13) as f32, (k % 5) as f32 - 1.0);
            let got = ias.closest_point(q).unwrap().unwrap();
            let best = ias
                .data()
                .instances
                .iter()
                .map(|inst| {
                    let local = inst.world_to_object.transform_point(q);
                    gas.closest_point(local).unwrap().unwrap().distance
                })
                .fold(f32::INFINITY, f32::min);
            assert_eq!(got.closest.distance, best, "point {q}");
        }
    }

    #[test]
    fn what_cannot_be_answered_is_refused_whatever_the_point() {
        let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let gas = std::sync::Arc::new(Gas::from_mesh(&v, &[[0, 1, 2]]).unwrap());
        // A stretched instance far away: a point next to the plain one never reaches it, yet
        // the answer would depend on the point if it were checked only when reached.
        let stretched = Transform::from_affine(&Affine3A::from_scale_rotation_translation(
            Vec3::new(1.0, 3.0, 1.0),
            Quat::IDENTITY,
            Vec3::new(100.0, 0.0, 0.0),
        ));
        let instances = [
            oxray_core::Instance::new(gas.clone().into()),
            oxray_core::Instance::new(gas.clone().into()).transform(stretched),
        ];
        let mut ias = Ias::build(
            &oxray_core::BuildOptions::default(),
            &[(&instances[..]).into()],
        )
        .unwrap();
        for p in [Vec3::new(0.25, 0.25, 0.5), Vec3::new(100.0, 0.0, 1.0)] {
            assert!(matches!(
                ias.closest_point(p),
                Err(SurfaceQueryError::Unsupported(_))
            ));
        }
        // An update to similar placements is answered (the check is made again).
        let moved = [
            oxray_core::Instance::new(gas.clone().into()),
            oxray_core::Instance::new(gas.clone().into())
                .transform(Transform::from_translation(Vec3::new(100.0, 0.0, 0.0))),
        ];
        let mut rebuilt = Ias::build(
            &oxray_core::BuildOptions::new(oxray_core::BuildFlags::ALLOW_UPDATE),
            &[(&instances[..]).into()],
        )
        .unwrap();
        assert!(rebuilt.closest_point(Vec3::ZERO).is_err());
        rebuilt
            .update(
                &oxray_core::BuildOptions {
                    flags: oxray_core::BuildFlags::ALLOW_UPDATE,
                    operation: oxray_core::BuildOperation::Update,
                    ..Default::default()
                },
                &[(&moved[..]).into()],
            )
            .unwrap();
        let c = rebuilt
            .closest_point(Vec3::new(0.25, 0.25, 0.5))
            .unwrap()
            .unwrap();
        assert_eq!(c.closest.distance, 0.5);
        ias = rebuilt;
        assert!(ias.closest_point(Vec3::new(100.25, 0.25, 2.0)).is_ok());
    }

    #[test]
    fn similarities_are_told_from_other_transforms() {
        let r = Affine3A::from_scale_rotation_translation(
            Vec3::splat(2.5),
            Quat::from_rotation_y(0.7) * Quat::from_rotation_x(0.3),
            Vec3::new(1.0, -2.0, 3.0),
        );
        let s = Transform::from_affine(&r).similarity_scale().unwrap();
        assert!((s - 2.5).abs() < 1e-5, "{s}");
        let mirror = Transform::from_affine(&Affine3A::from_scale(Vec3::new(-1.0, 1.0, 1.0)));
        assert_eq!(mirror.similarity_scale(), Some(1.0));
        let stretched = Transform::from_affine(&Affine3A::from_scale(Vec3::new(1.0, 2.0, 1.0)));
        assert_eq!(stretched.similarity_scale(), None);
        let mut sheared = Transform::IDENTITY;
        sheared.0[1] = 0.5;
        assert_eq!(sheared.similarity_scale(), None);
        assert_eq!(Transform([0.0; 12]).similarity_scale(), None);
    }
}
