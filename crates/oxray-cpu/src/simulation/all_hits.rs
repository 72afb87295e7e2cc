//! Every primitive a ray crosses: sorted by distance, each reported once, with a bound on how
//! many are kept; and the number of primitives crossed.
//!
//! Both ignore every candidate of the closest-hit traversal, so that the interval never
//! shrinks and every primitive in `[tmin, tmax]` is offered. A primitive may be offered more
//! than once (spatial splits reference a triangle from several leaves, guide §5.1); every offer
//! of one primitive on one path has the same `t`.
//!
//! - The list of [`Gas::all_hits`] is an any-hit filter (`intersect_filtered`) that keeps the
//!   candidates sorted and finds repeats by binary search. Once a full list is known to miss a
//!   hit, the interval shrinks to its farthest hit (not before, so that whether the list is
//!   complete is exact).
//! - [`Gas::count_hits`] has a visitor of its own (`CountVisitor`) that keeps no hit
//!   record: only the key of each primitive counted (`t`, instance, build input, primitive)
//!   in a fixed array on the stack, scanned for repeats. A ray crossing more than
//!   `COUNT_KEYS` primitives is counted again with the sorted list (a thread's scratch list,
//!   allocated once).

use super::{check_ray, par_try_batch, AllHits, SurfaceQueryError, CHUNK};
use crate::traversal::{
    traverse_node, with_stack, Decision, Entry, GasVisitor, NodeRef, Path, SceneVisitor,
};
use crate::{Gas, Ias, NoCustomPrimitives};
use oxray_bvh::InstanceData;
use oxray_core::{CandidateAction, Hit, Ray};
use rayon::prelude::*;
use std::cell::RefCell;

use oxray_core::simulation::hit_order as order;

/// Offers a candidate to the list `out` (sorted by [`order`], at most `max` long). Clears
/// `*complete` where a hit is left out.
fn offer(out: &mut Vec<Hit>, max: usize, hit: &Hit, complete: &mut bool) -> CandidateAction {
    let Err(pos) = out.binary_search_by(|x| order(x, hit)) else {
        // Already in the list.
        return CandidateAction::Ignore;
    };
    if max == 0 {
        // Only whether there is a hit matters.
        *complete = false;
        return CandidateAction::Terminate;
    }
    if out.len() == max {
        *complete = false;
        if pos == max {
            // Beyond the full list: nothing beyond this hit can enter it either.
            return CandidateAction::Accept;
        }
        out.pop();
    }
    out.insert(pos, *hit);
    if !*complete && pos == max - 1 {
        // The new farthest hit of a list known to be incomplete: nothing beyond it can enter.
        CandidateAction::Accept
    } else {
        CandidateAction::Ignore
    }
}

/// Primitives [`CountVisitor`] tells apart without a list: beyond them, the ray is counted
/// again with the sorted list of [`all_hits`](Gas::all_hits).
pub(crate) const COUNT_KEYS: usize = 64;

/// What tells two offers of one primitive from two primitives, as [`order`] compares hits:
/// the instance index and id, the build input and the primitive index (the `t` is kept apart).
type CountKey = (u32, u32, u32, u32);

/// The visitor of [`Gas::count_hits`]: counts every distinct primitive offered, ignoring each
/// (the interval never shrinks). Allocates nothing: the keys of the primitives counted are a
/// fixed array, scanned on every offer (`t` first); should they overflow, traversal is aborted
/// and [`overflow`](Self::overflow) says to count again otherwise.
struct CountVisitor<'s> {
    gas: Option<&'s Gas>,
    /// The instance nearest to the current GAS.
    instance: Option<&'s InstanceData>,
    /// `t` (its bits) of the primitives counted, in offer order.
    ts: [u32; COUNT_KEYS],
    /// The rest of their keys.
    keys: [CountKey; COUNT_KEYS],
    count: usize,
    overflow: bool,
}

impl<'s> CountVisitor<'s> {
    fn new() -> Self {
        CountVisitor {
            gas: None,
            instance: None,
            ts: [0; COUNT_KEYS],
            keys: [(0, 0, 0, 0); COUNT_KEYS],
            count: 0,
            overflow: false,
        }
    }

    /// Counts the primitive of leaf slot `slot` hit at `t`, unless it was counted already.
    #[inline(always)]
    fn offer(&mut self, slot: u32, t: f32) -> Decision {
        let Some(gas) = self.gas else {
            return Decision::Ignore;
        };
        let (primitive_index, _, build_input) = gas.resolve(slot);
        let (instance_id, instance_index) =
            self.instance.map_or((!0, 0), |i| (i.instance_id, i.index));
        let key = (instance_index, instance_id, build_input, primitive_index);
        let bits = t.to_bits();
        let n = self.count;
        if (0..n).any(|k| self.ts[k] == bits && self.keys[k] == key) {
            return Decision::Ignore;
        }
        if n == COUNT_KEYS {
            self.overflow = true;
            return Decision::Abort;
        }
        self.ts[n] = bits;
        self.keys[n] = key;
        self.count = n + 1;
        Decision::Ignore
    }
}

impl<'s> SceneVisitor<'s> for CountVisitor<'s> {
    fn enter_gas(&mut self, gas: &'s Gas, path: &Path<'s>, _: &Ray) {
        self.gas = Some(gas);
        self.instance = path.instance;
    }

    fn ray_mask(&self) -> u8 {
        0xFF
    }
}

impl GasVisitor for CountVisitor<'_> {
    #[inline(always)]
    fn triangle(&mut self, slot: u32, hit: &oxray_bvh::triangle::TriangleHit) -> Decision {
        self.offer(slot, hit.t)
    }

    #[inline(always)]
    fn sphere(&mut self, slot: u32, t: f32) -> Decision {
        self.offer(slot, t)
    }

    #[inline(always)]
    fn curve(&mut self, slot: u32, hit: &oxray_bvh::CurveHit) -> Decision {
        self.offer(slot, hit.t)
    }

    fn custom(&mut self, _: u32, _: f32, _: f32, _: &mut [Entry]) -> (Option<f32>, bool) {
        // Custom primitives are not hit, as by `all_hits` (`NoCustomPrimitives`).
        (None, false)
    }

    /// Every box the ray crosses is entered whatever the order (the interval never shrinks),
    /// and a set of primitives does not depend on it: the children are not sorted.
    fn nearest_first(&self) -> bool {
        false
    }
}

/// The number of distinct primitives `ray` (valid) crosses under `root`: [`CountVisitor`], or
/// the sorted list of `all_hits` where the ray crosses more than [`COUNT_KEYS`].
fn count_under(root: NodeRef<'_>, ray: &Ray, list_count: impl FnOnce() -> u32) -> u32 {
    let mut v = CountVisitor::new();
    with_stack(|stack| traverse_node(root, &Path::ROOT, ray, &mut v, stack));
    if v.overflow {
        list_count()
    } else {
        v.count as u32
    }
}

thread_local! {
    /// The unbounded list of [`count_hits`](Gas::count_hits), kept per thread so that counting
    /// allocates nothing per ray once it has grown.
    static SCRATCH: RefCell<Vec<Hit>> = const { RefCell::new(Vec::new()) };
}

/// Runs `f` with this thread's scratch list (a fresh one should a count nest in another).
fn with_scratch<R>(f: impl FnOnce(&mut Vec<Hit>) -> R) -> R {
    SCRATCH.with(|cell| match cell.try_borrow_mut() {
        Ok(mut v) => f(&mut v),
        Err(_) => f(&mut Vec::new()),
    })
}

/// The all-hits queries every traversable offers.
macro_rules! all_hits_api {
    ($t:ty, $root:expr) => {
        impl $t {
            /// Every primitive `ray` crosses in `[tmin, tmax]`, into `out` (cleared first): sorted
            /// by `t` (then by instance index, instance id, build input and primitive index), each
            /// primitive of each instance once, at most `max_hits` of them: the nearest. Returns
            /// whether the list is complete (`false` where the bound left hits out). Custom
            /// primitives are not hit. `out`'s allocation is reused: keep it across rays.
            ///
            /// A ray through an edge or a vertex shared by several triangles crosses each of
            /// them: each is reported (all at the same `t`). An invalid ray is an error.
            ///
            /// ```
            /// use oxray_cpu::Gas;
            /// use oxray_core::Ray;
            /// use glam::Vec3;
            /// // Three parallel triangles at z = 1, 2, 3.
            /// let v: Vec<[f32; 3]> = (1..=3)
            ///     .flat_map(|z| [[-1.0, -1.0, z as f32], [1.0, -1.0, z as f32], [0.0, 1.0, z as f32]])
            ///     .collect();
            /// let gas = Gas::from_mesh(&v, &[[0, 1, 2], [3, 4, 5], [6, 7, 8]])?;
            /// let ray = Ray::new(Vec3::ZERO, Vec3::Z);
            /// let mut hits = Vec::new();
            /// assert!(gas.all_hits(&ray, 8, &mut hits)?);
            /// assert_eq!(hits.iter().map(|h| h.primitive_index).collect::<Vec<_>>(), [0, 1, 2]);
            /// // Bounded: the two nearest, and the list says it is not complete.
            /// assert!(!gas.all_hits(&ray, 2, &mut hits)?);
            /// assert_eq!(hits.iter().map(|h| h.t).collect::<Vec<_>>(), [1.0, 2.0]);
            /// assert_eq!(gas.count_hits(&ray)?, 3);
            /// # Ok::<(), Box<dyn std::error::Error>>(())
            /// ```
            pub fn all_hits(
                &self,
                ray: &Ray,
                max_hits: usize,
                out: &mut Vec<Hit>,
            ) -> Result<bool, SurfaceQueryError> {
                check_ray(ray)?;
                out.clear();
                let mut complete = true;
                self.intersect_filtered(ray, &mut NoCustomPrimitives, |h| {
                    offer(out, max_hits, h, &mut complete)
                });
                Ok(complete)
            }

            /// The number of distinct primitives `ray` crosses in `[tmin, tmax]` (each primitive of
            /// each instance once), as [`all_hits`](Self::all_hits) would list them without a
            /// bound. Its parity tells inside from outside for a closed mesh only where the ray
            /// crosses no edge or vertex (a shared edge counts once per triangle); see
            /// [`Gas::signed_distance`] for a robust inside test.
            ///
            /// It keeps no hit record and allocates nothing: the primitives counted are told
            /// apart in a fixed array on the stack (a ray crossing more than 64 is counted
            /// again through the sorted list of `all_hits`, allocated once per thread).
            ///
            /// ```
            /// use oxray_cpu::Gas;
            /// use oxray_core::Ray;
            /// use glam::Vec3;
            /// // A tetrahedron: a ray through it crosses two faces, one that starts inside one.
            /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
            /// let gas = Gas::from_mesh(&v, &[[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])?;
            /// assert_eq!(gas.count_hits(&Ray::new(Vec3::new(0.2, 0.2, -1.0), Vec3::Z))?, 2);
            /// assert_eq!(gas.count_hits(&Ray::new(Vec3::splat(0.1), Vec3::Z))?, 1);
            /// # Ok::<(), Box<dyn std::error::Error>>(())
            /// ```
            pub fn count_hits(&self, ray: &Ray) -> Result<u32, SurfaceQueryError> {
                check_ray(ray)?;
                Ok(count_under($root(self), ray, || {
                    with_scratch(|list| {
                        list.clear();
                        let mut complete = true;
                        self.intersect_filtered(ray, &mut NoCustomPrimitives, |h| {
                            offer(list, usize::MAX, h, &mut complete)
                        });
                        list.len() as u32
                    })
                }))
            }

            /// [`all_hits`](Self::all_hits) of a batch of rays in parallel, at most
            /// `max_hits_per_ray` per ray, into `out` (cleared first): the same lists as ray by
            /// ray, whatever the number of threads. Every ray is checked before any is traced: an
            /// invalid one is an error (the lowest index) and `out` is left empty.
            ///
            /// ```
            /// use oxray_cpu::{AllHits, Gas};
            /// use oxray_core::Ray;
            /// use glam::Vec3;
            /// let v = [[-1.0f32, -1.0, 1.0], [1.0, -1.0, 1.0], [0.0, 1.0, 1.0]];
            /// let gas = Gas::from_mesh(&v, &[[0, 1, 2]])?;
            /// let rays = [Ray::new(Vec3::ZERO, Vec3::Z), Ray::new(Vec3::ZERO, -Vec3::Z)];
            /// let mut out = AllHits::new();
            /// gas.all_hits_batch(&rays, 4, &mut out)?;
            /// assert_eq!((out.hits(0).len(), out.hits(1).len()), (1, 0));
            /// # Ok::<(), Box<dyn std::error::Error>>(())
            /// ```
            pub fn all_hits_batch(
                &self,
                rays: &[Ray],
                max_hits_per_ray: usize,
                out: &mut AllHits,
            ) -> Result<(), SurfaceQueryError> {
                out.clear();
                if let Some((index, error)) = rays
                    .iter()
                    .enumerate()
                    .find_map(|(i, r)| r.validate().err().map(|e| (i, e)))
                {
                    return Err(SurfaceQueryError::InvalidRay { index, error });
                }
                let parts: Vec<AllHits> = rays
                    .par_chunks(CHUNK)
                    .map(|rays| {
                        let mut part = AllHits::new();
                        let mut list = Vec::new();
                        for r in rays {
                            // Checked above: only `Ok` comes back.
                            let complete = self.all_hits(r, max_hits_per_ray, &mut list)?;
                            part.push_ray(&list, complete);
                        }
                        Ok(part)
                    })
                    .collect::<Result<_, SurfaceQueryError>>()?;
                out.append_parts(parts);
                Ok(())
            }

            /// [`count_hits`](Self::count_hits) of a batch of rays in parallel. The first invalid
            /// ray (the lowest index) is the error; the counts of the others are written.
            ///
            /// ```
            /// use oxray_cpu::Gas;
            /// use oxray_core::Ray;
            /// use glam::Vec3;
            /// let v = [[-1.0f32, -1.0, 1.0], [1.0, -1.0, 1.0], [0.0, 1.0, 1.0]];
            /// let gas = Gas::from_mesh(&v, &[[0, 1, 2]])?;
            /// let rays = [Ray::new(Vec3::ZERO, Vec3::Z), Ray::new(Vec3::ZERO, -Vec3::Z)];
            /// let mut counts = [0; 2];
            /// gas.count_hits_batch(&rays, &mut counts)?;
            /// assert_eq!(counts, [1, 0]);
            /// # Ok::<(), Box<dyn std::error::Error>>(())
            /// ```
            pub fn count_hits_batch(
                &self,
                rays: &[Ray],
                counts: &mut [u32],
            ) -> Result<(), SurfaceQueryError> {
                par_try_batch(rays.len(), counts, |i| self.count_hits(&rays[i]))
            }
        }
    };
}

all_hits_api!(Gas, NodeRef::Gas);
all_hits_api!(Ias, NodeRef::Ias);
