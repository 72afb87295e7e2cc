//! Ray queries on a GAS: closest hit, any hit (occlusion) and filtered queries, one ray at a time
//! or in parallel batches. This is the Embree-like path for simulation users and the kernel the
//! program pipeline is built on.

use crate::traversal::{
    coherent, small_applies, small_gas_rays, traverse_gas_packet, traverse_node, triangle_gas_rays,
    with_stack, Decision, Entry, GasVisitor, NodeRef, Path, SceneVisitor, PACKET,
};
use crate::Gas;
use oxray_bvh::triangle::TriangleHit;
use oxray_bvh::InstanceData as InstanceRecord;
use oxray_core::{CandidateAction, CustomHit, CustomPrimitive, Hit, HitKind, QueryError, Ray};
use rayon::prelude::*;

/// Intersects custom primitives: given the primitive and the ray with its current interval,
/// returns the closest intersection in that interval, if any.
pub trait CustomIntersector {
    /// Intersects one primitive.
    fn intersect(&mut self, primitive: &CustomPrimitive, ray: &Ray) -> Option<CustomHit>;
}

impl<F: FnMut(&CustomPrimitive, &Ray) -> Option<CustomHit>> CustomIntersector for F {
    fn intersect(&mut self, primitive: &CustomPrimitive, ray: &Ray) -> Option<CustomHit> {
        self(primitive, ray)
    }
}

/// The intersector of [`Gas::intersect`]: custom primitives are never hit.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoCustomPrimitives;

impl CustomIntersector for NoCustomPrimitives {
    fn intersect(&mut self, _: &CustomPrimitive, _: &Ray) -> Option<CustomHit> {
        None
    }
}

/// What a query does with each candidate: an any-hit program in closure form, or accept
/// every candidate. A filter that never looks at the candidates lets the query skip finding
/// each one's primitive index and SBT record (a lookup per candidate, a cache miss on large
/// meshes) and do it once, for the hit it returns.
trait CandidateFilter {
    /// Whether [`decide`](Self::decide) reads the candidate.
    const SEES_CANDIDATES: bool;
    fn decide(&mut self, hit: &Hit) -> CandidateAction;
}

/// Accepts every candidate.
struct AcceptAll;

impl CandidateFilter for AcceptAll {
    const SEES_CANDIDATES: bool = false;
    #[inline(always)]
    fn decide(&mut self, _: &Hit) -> CandidateAction {
        CandidateAction::Accept
    }
}

/// A user's filter closure.
struct Closure<F>(F);

impl<F: FnMut(&Hit) -> CandidateAction> CandidateFilter for Closure<F> {
    const SEES_CANDIDATES: bool = true;
    #[inline(always)]
    fn decide(&mut self, hit: &Hit) -> CandidateAction {
        (self.0)(hit)
    }
}

/// A caller's intersector, borrowed for one query.
struct Borrowed<'a, C>(&'a mut C);

impl<C: CustomIntersector> CustomIntersector for Borrowed<'_, C> {
    #[inline(always)]
    fn intersect(&mut self, primitive: &CustomPrimitive, ray: &Ray) -> Option<CustomHit> {
        self.0.intersect(primitive, ray)
    }
}

struct QueryVisitor<'s, C, F> {
    /// The GAS being traversed, and where it sits.
    gas: Option<&'s Gas>,
    /// The instance nearest to the current GAS (a reference, not a copy of the whole path:
    /// entering a GAS happens once per ray and instance).
    instance: Option<&'s InstanceRecord>,
    object_ray: Ray,
    custom: C,
    filter: F,
    first_hit_ends: bool,
    best: Option<Hit>,
    /// The GAS and leaf slot of `best` while its primitive index, SBT-GAS index and build
    /// input are still to be found (filters that do not see candidates).
    unresolved: Option<(&'s Gas, u32)>,
}

impl<'s, C: CustomIntersector, F: CandidateFilter> QueryVisitor<'s, C, F> {
    /// Offers the candidate at leaf `slot` of the current GAS (a built-in primitive: its
    /// distance, attributes and hit kind), with the nearest instance's id and index.
    #[inline(always)]
    fn offer(
        &mut self,
        gas: &'s Gas,
        slot: u32,
        t: f32,
        uv: (f32, f32),
        kind: HitKind,
    ) -> Decision {
        let (instance_id, instance_index) = self.instance();
        let mut hit = Hit {
            t,
            u: uv.0,
            v: uv.1,
            primitive_index: 0,
            sbt_gas_index: 0,
            build_input: 0,
            hit_kind: kind,
            instance_id,
            instance_index,
        };
        let unresolved = if F::SEES_CANDIDATES {
            (hit.primitive_index, hit.sbt_gas_index, hit.build_input) = gas.resolve(slot);
            None
        } else {
            Some((gas, slot))
        };
        self.offer_resolved(hit, unresolved)
    }

    #[inline(always)]
    fn offer_resolved(&mut self, hit: Hit, unresolved: Option<(&'s Gas, u32)>) -> Decision {
        match self.filter.decide(&hit) {
            CandidateAction::Ignore => Decision::Ignore,
            action => {
                self.best = Some(hit);
                self.unresolved = unresolved;
                if self.first_hit_ends || action == CandidateAction::Terminate {
                    Decision::AcceptAndTerminate
                } else {
                    Decision::Accept
                }
            }
        }
    }

    /// The hit the query returns, its primitive fields filled in.
    fn finish(&self) -> Option<Hit> {
        let mut hit = self.best?;
        if let Some((gas, slot)) = self.unresolved {
            (hit.primitive_index, hit.sbt_gas_index, hit.build_input) = gas.resolve(slot);
        }
        Some(hit)
    }

    #[inline(always)]
    fn instance(&self) -> (u32, u32) {
        self.instance.map_or((!0, 0), |i| (i.instance_id, i.index))
    }
}

impl<'s, C: CustomIntersector, F: CandidateFilter> SceneVisitor<'s> for QueryVisitor<'s, C, F> {
    fn enter_gas(&mut self, gas: &'s Gas, path: &Path<'s>, object_ray: &Ray) {
        self.gas = Some(gas);
        self.instance = path.instance;
        self.object_ray = *object_ray;
    }

    fn ray_mask(&self) -> u8 {
        0xFF
    }
}

impl<'s, C: CustomIntersector, F: CandidateFilter> GasVisitor for QueryVisitor<'s, C, F> {
    #[inline(always)]
    fn nearest_first(&self) -> bool {
        // An occlusion query stops at its first hit, wherever it is.
        !self.first_hit_ends
    }

    #[inline(always)]
    fn triangle(&mut self, slot: u32, h: &TriangleHit) -> Decision {
        let Some(gas) = self.gas else {
            return Decision::Ignore;
        };
        // FLIP_TRIANGLE_FACING of the nearest instance swaps the faces (guide §5.4).
        let flip = self
            .instance
            .is_some_and(|i| i.flags.contains(crate::InstanceFlags::FLIP_TRIANGLE_FACING));
        let kind = if h.front_face != flip {
            HitKind::TRIANGLE_FRONT_FACE
        } else {
            HitKind::TRIANGLE_BACK_FACE
        };
        self.offer(gas, slot, h.t, (h.u, h.v), kind)
    }

    #[inline(always)]
    fn sphere(&mut self, slot: u32, t: f32) -> Decision {
        let Some(gas) = self.gas else {
            return Decision::Ignore;
        };
        // Spheres have no attributes (guide §9.4, §13.4) and only a front face.
        self.offer(gas, slot, t, (0.0, 0.0), HitKind::SPHERE_FRONT_FACE)
    }

    #[inline(always)]
    fn curve(&mut self, slot: u32, h: &oxray_bvh::CurveHit) -> Decision {
        let Some(gas) = self.gas else {
            return Decision::Ignore;
        };
        // A curve's attributes are its u (and a ribbon's v), guide §9.3.
        let kind = HitKind::curve(gas.curves[slot as usize].curve_type(), h.back_face);
        self.offer(gas, slot, h.t, (h.u, h.v), kind)
    }

    fn custom(&mut self, slot: u32, tmin: f32, tmax: f32, _: &mut [Entry]) -> (Option<f32>, bool) {
        let Some(gas) = self.gas else {
            return (None, false);
        };
        let (primitive_index, sbt_gas_index, build_input) = gas.resolve(slot);
        let prim = CustomPrimitive {
            primitive_index,
            sbt_gas_index,
            build_input,
            // With motion, the box at the ray's time (guide §5.10.1).
            aabb: gas
                .aabb_at(slot as usize, self.object_ray.time)
                .unwrap_or(oxray_core::Aabb::EMPTY),
        };
        let ray = Ray {
            tmin,
            tmax,
            ..self.object_ray
        };
        let Some(c) = self.custom.intersect(&prim, &ray) else {
            return (None, false);
        };
        if !(c.t >= tmin && c.t <= tmax) {
            return (None, false);
        }
        let (instance_id, instance_index) = self.instance();
        let hit = Hit {
            t: c.t,
            u: c.u,
            v: c.v,
            primitive_index,
            sbt_gas_index,
            build_input,
            hit_kind: HitKind::custom(c.hit_kind),
            instance_id,
            instance_index,
        };
        match self.offer_resolved(hit, None) {
            Decision::Ignore | Decision::Abort => (None, false),
            Decision::Accept => (Some(c.t), false),
            Decision::AcceptAndTerminate => (Some(c.t), true),
        }
    }
}

impl<C: CustomIntersector, F: CandidateFilter> QueryVisitor<'_, C, F> {
    fn new(ray: &Ray, custom: C, filter: F, first_hit_ends: bool) -> Self {
        QueryVisitor {
            gas: None,
            instance: None,
            object_ray: *ray,
            custom,
            filter,
            first_hit_ends,
            best: None,
            unresolved: None,
        }
    }
}

/// Runs one query from `root` with this thread's stack.
fn query<'s, C: CustomIntersector, F: CandidateFilter>(
    root: NodeRef<'s>,
    ray: &Ray,
    custom: &mut C,
    filter: F,
    first_hit_ends: bool,
) -> Option<Hit> {
    ray.validate().ok()?;
    let mut v = QueryVisitor::new(ray, Borrowed(custom), filter, first_hit_ends);
    with_stack(|stack| traverse_node(root, &Path::ROOT, ray, &mut v, stack));
    v.finish()
}

/// Closest hits (`first_hit_ends` false) or occlusion (true) of a batch under `root`
/// (`None`: the null handle, every ray misses), in parallel, each answer mapped by `answer`
/// into `out`. A small triangle GAS is tested whole, sixteen rays at a time (see
/// [`small_gas_rays`]); otherwise coherent groups of eight rays under a triangle GAS go through
/// the packet kernel (see [`traverse_gas_packet`]). The answers are those of one ray at a time
/// (up to which of two primitives at exactly the same distance is reported), whatever the
/// number of threads.
fn batch_queries<T: Send>(
    root: Option<NodeRef<'_>>,
    rays: &[Ray],
    out: &mut [T],
    first_hit_ends: bool,
    answer: impl Fn(Option<Hit>) -> T + Sync,
) -> Result<(), QueryError> {
    let single = |ray: &Ray| {
        root.and_then(|r| query(r, ray, &mut NoCustomPrimitives, AcceptAll, first_hit_ends))
    };
    let Some(NodeRef::Gas(gas)) = root else {
        return par_batch(rays, out, |ray| answer(single(ray)));
    };
    // Rays that do not go as a packet: one at a time, through the batch path where it applies.
    let one_by_one = |rays: &[Ray], out: &mut [T]| {
        let visitor = |ray: &Ray| {
            let mut v = QueryVisitor::new(ray, NoCustomPrimitives, AcceptAll, first_hit_ends);
            v.gas = Some(gas);
            v
        };
        let done = |v: Option<QueryVisitor<'_, _, _>>| answer(v.and_then(|v| v.finish()));
        if !triangle_gas_rays(gas, rays, out, visitor, done) {
            for (o, ray) in out.iter_mut().zip(rays) {
                *o = answer(single(ray));
            }
        }
    };
    let small = small_applies(gas);
    par_chunks(rays, out, |rays, out| {
        // A small structure: its triangles tested whole, sixteen rays at a time; each ray's
        // candidate then offered to its visitor as the walk would offer it.
        if small
            && small_gas_rays(gas, rays, out, first_hit_ends, |i, found| {
                answer(found.and_then(|(slot, h)| {
                    let mut v =
                        QueryVisitor::new(&rays[i], NoCustomPrimitives, AcceptAll, first_hit_ends);
                    v.gas = Some(gas);
                    v.triangle(slot, &h);
                    v.finish()
                }))
            })
        {
            return;
        }
        // Rays before `pending` are answered.
        let mut pending = 0;
        for at in (0..rays.len()).step_by(PACKET) {
            let end = (at + PACKET).min(rays.len());
            let group = &rays[at..end];
            if !coherent(group) {
                continue;
            }
            let mut visitors: [_; PACKET] = std::array::from_fn(|l| {
                QueryVisitor::new(&group[l], NoCustomPrimitives, AcceptAll, first_hit_ends)
            });
            if traverse_gas_packet(gas, group, &mut visitors) {
                one_by_one(&rays[pending..at], &mut out[pending..at]);
                for (o, v) in out[at..end].iter_mut().zip(&visitors) {
                    *o = answer(v.finish());
                }
                pending = end;
            }
        }
        one_by_one(&rays[pending..], &mut out[pending..]);
    })
}

/// Closest hits of a batch under `root` (`None`: the null handle, every ray misses), in
/// parallel; the same results as one ray at a time, whatever the number of threads.
pub(crate) fn closest_batch(
    root: Option<NodeRef<'_>>,
    rays: &[Ray],
    hits: &mut [Option<Hit>],
) -> Result<(), QueryError> {
    batch_queries(root, rays, hits, false, |h| h)
}

/// Occlusion of a batch under `root`, in parallel.
pub(crate) fn any_batch(
    root: Option<NodeRef<'_>>,
    rays: &[Ray],
    occluded: &mut [bool],
) -> Result<(), QueryError> {
    batch_queries(root, rays, occluded, true, |h| h.is_some())
}

/// Runs `f` on every ray in parallel chunks, writing `out` in ray order.
fn par_batch<T: Send>(
    rays: &[Ray],
    out: &mut [T],
    f: impl Fn(&Ray) -> T + Sync,
) -> Result<(), QueryError> {
    par_chunks(rays, out, |rays, out| {
        for (r, o) in rays.iter().zip(out) {
            *o = f(r);
        }
    })
}

/// Runs `f` on fixed chunks of the rays and their outputs in parallel. The chunks are the same
/// whatever the number of threads (what a packet is made of depends only on the batch).
fn par_chunks<T: Send>(
    rays: &[Ray],
    out: &mut [T],
    f: impl Fn(&[Ray], &mut [T]) + Sync,
) -> Result<(), QueryError> {
    if rays.len() != out.len() {
        return Err(QueryError::LengthMismatch {
            rays: rays.len(),
            outputs: out.len(),
        });
    }
    const CHUNK: usize = 256;
    if rays.len() <= CHUNK {
        // One chunk: on this thread, without the thread pool's bookkeeping (a renderer's
        // tile traces its batches from inside a pool task, a few hundred rays each).
        f(rays, out);
        return Ok(());
    }
    rays.par_chunks(CHUNK)
        .zip(out.par_chunks_mut(CHUNK))
        .for_each(|(rays, out)| f(rays, out));
    Ok(())
}

/// The queries every traversable offers: closest hit, occlusion, filtered, and batches.
macro_rules! query_api {
    ($t:ty, $root:expr) => {
        impl $t {
            /// The closest hit in `[ray.tmin, ray.tmax]`, or `None`. Custom primitives are not hit (use
            /// [`intersect_with`](Self::intersect_with)); an invalid ray (see [`Ray::validate`]) hits
            /// nothing. Where two hits are at the same distance, which one is returned is fixed by the
            /// structure, identical from run to run.
            pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
                query($root(self), ray, &mut NoCustomPrimitives, AcceptAll, false)
            }

            /// The closest hit, with custom primitives intersected by `custom`.
            pub fn intersect_with<C: CustomIntersector>(
                &self,
                ray: &Ray,
                custom: &mut C,
            ) -> Option<Hit> {
                query($root(self), ray, custom, AcceptAll, false)
            }

            /// The closest hit that `filter` accepts: an any-hit program in closure form. The filter sees
            /// each candidate within the current interval (in no particular order, possibly more than
            /// once per primitive) and may accept, ignore, or accept and terminate.
            ///
            /// ```
            /// # use oxray_cpu::{Gas, NoCustomPrimitives};
            /// # use oxray_core::{BuildOptions, CandidateAction, Ray, TriangleInput, VertexBuffer};
            /// # use glam::Vec3;
            /// // Two parallel triangles; ignore the first primitive to see the one behind it.
            /// let v = [[-1.0f32, -1.0, 1.0], [1.0, -1.0, 1.0], [0.0, 1.0, 1.0],
            ///          [-1.0, -1.0, 2.0], [1.0, -1.0, 2.0], [0.0, 1.0, 2.0]];
            /// let gas = Gas::build(&BuildOptions::default(), &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
            /// let ray = Ray::new(Vec3::ZERO, Vec3::Z);
            /// let hit = gas.intersect_filtered(&ray, &mut NoCustomPrimitives, |h| {
            ///     if h.primitive_index == 0 { CandidateAction::Ignore } else { CandidateAction::Accept }
            /// });
            /// assert_eq!(hit.unwrap().t, 2.0);
            /// # Ok::<(), oxray_core::BuildError>(())
            /// ```
            pub fn intersect_filtered<C: CustomIntersector>(
                &self,
                ray: &Ray,
                custom: &mut C,
                filter: impl FnMut(&Hit) -> CandidateAction,
            ) -> Option<Hit> {
                query($root(self), ray, custom, Closure(filter), false)
            }

            /// Whether anything lies in `[ray.tmin, ray.tmax]` (a shadow or visibility ray): traversal
            /// stops at the first hit found, which need not be the closest.
            pub fn occluded(&self, ray: &Ray) -> bool {
                query($root(self), ray, &mut NoCustomPrimitives, AcceptAll, true).is_some()
            }

            /// Whether anything lies in the ray's interval, with custom primitives intersected by
            /// `custom`.
            pub fn occluded_with<C: CustomIntersector>(&self, ray: &Ray, custom: &mut C) -> bool {
                query($root(self), ray, custom, AcceptAll, true).is_some()
            }

            /// Closest hits of a batch of rays, in parallel on the current rayon pool. Under a small
            /// triangle GAS (at most 64 leaf slots) sixteen rays are tested at a time where the
            /// processor has AVX-512; otherwise groups of eight consecutive rays from one origin
            /// (camera rays) are traced together as a packet where it has AVX2. The results are
            /// those of [`intersect`](Self::intersect) ray by ray (t, u, v and facing bit for bit;
            /// where two primitives are hit at exactly the same distance either may be reported),
            /// the same whatever the number of threads.
            pub fn intersect_batch(
                &self,
                rays: &[Ray],
                hits: &mut [Option<Hit>],
            ) -> Result<(), QueryError> {
                batch_queries(Some($root(self)), rays, hits, false, |h| h)
            }

            /// Occlusion of a batch of rays, in parallel (packets as for
            /// [`intersect_batch`](Self::intersect_batch)); the same answers as
            /// [`occluded`](Self::occluded) ray by ray.
            pub fn occluded_batch(
                &self,
                rays: &[Ray],
                occluded: &mut [bool],
            ) -> Result<(), QueryError> {
                batch_queries(Some($root(self)), rays, occluded, true, |h| h.is_some())
            }

            /// Closest hits of a batch, with custom primitives intersected by `custom` (called from
            /// several threads at once).
            pub fn intersect_batch_with<C>(
                &self,
                rays: &[Ray],
                hits: &mut [Option<Hit>],
                custom: &C,
            ) -> Result<(), QueryError>
            where
                C: Fn(&CustomPrimitive, &Ray) -> Option<CustomHit> + Sync,
            {
                self.batch(rays, hits, |root, ray| {
                    query(
                        root,
                        ray,
                        &mut |p: &CustomPrimitive, r: &Ray| custom(p, r),
                        AcceptAll,
                        false,
                    )
                })
            }

            fn batch<T: Send>(
                &self,
                rays: &[Ray],
                out: &mut [T],
                f: impl Fn(NodeRef<'_>, &Ray) -> T + Sync,
            ) -> Result<(), QueryError> {
                par_batch(rays, out, |r| f($root(self), r))
            }
        }
    };
}

query_api!(Gas, NodeRef::Gas);
query_api!(crate::Ias, NodeRef::Ias);
