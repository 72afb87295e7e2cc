//! Leaf intersectors: how the primitives of one leaf are tested against a ray and offered to
//! the visitor. One per primitive kind (triangle blocks, custom-primitive boxes, spheres,
//! curve segments) and
//! one for
//! the instances of an IAS ([`super::scene::InstanceLeaves`]); a new built-in primitive kind is
//! a new implementation of [`LeafIntersector`].

use super::kernel::{Decision, Entry, GasVisitor};
use super::ray::PreparedRay;
use glam::Vec3;
use oxray_bvh::{CurveSegment, Sphere, Triangle4};
use oxray_core::ray::min_ignore_nan;
use oxray_core::Aabb;

/// Whether traversal goes on after a leaf.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum LeafEnd {
    /// Go on with the (possibly shrunk) interval.
    Continue,
    /// End traversal: a terminating accept, or an abort.
    Stop,
}

/// Tests the primitives of one leaf, slots `start .. start + count`, within `[tmin, *tmax]`,
/// offering candidates to the visitor and shrinking `*tmax` to every accepted hit. `spare` is
/// the unused part of the traversal stack, for a nested traversal (an instance's child).
pub(crate) trait LeafIntersector<V> {
    /// Tests one leaf.
    #[allow(clippy::too_many_arguments)]
    fn leaf(
        &self,
        start: u32,
        count: u32,
        ray: &PreparedRay,
        tmin: f32,
        tmax: &mut f32,
        visitor: &mut V,
        spare: &mut [Entry],
    ) -> LeafEnd;

    /// Asks for the first primitives of the leaf at slot `start` to be loaded (a hint, given
    /// as soon as the leaf is known to be entered; any slot is allowed).
    #[inline(always)]
    fn prefetch(&self, _start: u32) {}
}

/// Triangles in blocks of four (leaf slot `s` is lane `s % 4` of block `s / 4`), tested with
/// the watertight test four at a time.
pub(crate) struct TriangleLeaves<'a>(pub &'a [Triangle4]);

impl<V: GasVisitor> LeafIntersector<V> for TriangleLeaves<'_> {
    #[inline(always)]
    fn prefetch(&self, start: u32) {
        let block = self.0.as_ptr().wrapping_add(start as usize / 4);
        super::prefetch::prefetch(block, super::prefetch::lines_of::<Triangle4>());
    }

    #[inline(always)]
    fn leaf(
        &self,
        start: u32,
        count: u32,
        ray: &PreparedRay,
        tmin: f32,
        tmax: &mut f32,
        visitor: &mut V,
        _spare: &mut [Entry],
    ) -> LeafEnd {
        let blocks = self.0;
        let mut slot = start as usize;
        let end = slot + count as usize;
        while slot < end {
            let valid = (end - slot).min(4);
            let hits = ray.tri.intersect4(&blocks[slot / 4], valid, tmin, *tmax);
            let mut m = hits.mask;
            while m != 0 {
                let l = m.trailing_zeros() as usize;
                m &= m - 1;
                // An earlier lane may have shrunk the interval.
                if hits.t[l] > *tmax {
                    continue;
                }
                let h = hits.get(l);
                match visitor.triangle((slot + l) as u32, &h) {
                    Decision::Ignore => {}
                    Decision::Accept => *tmax = h.t,
                    Decision::AcceptAndTerminate => {
                        *tmax = h.t;
                        return LeafEnd::Stop;
                    }
                    Decision::Abort => return LeafEnd::Stop,
                }
            }
            slot += 4;
        }
        LeafEnd::Continue
    }
}

/// Custom primitives: boxes in leaf-slot order; the visitor runs the intersection for every box
/// the ray enters.
pub(crate) struct AabbLeaves<'a>(pub &'a [Aabb]);

impl<V: GasVisitor> LeafIntersector<V> for AabbLeaves<'_> {
    #[inline(always)]
    fn leaf(
        &self,
        start: u32,
        count: u32,
        ray: &PreparedRay,
        tmin: f32,
        tmax: &mut f32,
        visitor: &mut V,
        spare: &mut [Entry],
    ) -> LeafEnd {
        let start = start as usize;
        for (k, b) in self.0[start..start + count as usize].iter().enumerate() {
            if ray.hits_box(b, tmin, *tmax) {
                let (t, stop) = visitor.custom((start + k) as u32, tmin, *tmax, spare);
                if let Some(t) = t {
                    *tmax = min_ignore_nan(*tmax, t);
                }
                if stop {
                    return LeafEnd::Stop;
                }
            }
        }
        LeafEnd::Continue
    }
}

/// Built-in spheres in leaf-slot order (guide §5.3), each tested with the robust ray/sphere
/// test of [`Sphere::intersect`]: only the front face is a hit (§9.4, §9.6), so a ray whose
/// interval starts inside a sphere does not hit it.
pub(crate) struct SphereLeaves<'a>(pub &'a [Sphere]);

impl<V: GasVisitor> LeafIntersector<V> for SphereLeaves<'_> {
    #[inline(always)]
    fn leaf(
        &self,
        start: u32,
        count: u32,
        ray: &PreparedRay,
        tmin: f32,
        tmax: &mut f32,
        visitor: &mut V,
        _spare: &mut [Entry],
    ) -> LeafEnd {
        let start = start as usize;
        let org = Vec3::from(ray.org);
        for (k, s) in self.0[start..start + count as usize].iter().enumerate() {
            // The interval shrinks with every accepted hit of the leaf.
            let Some(t) = s.intersect(org, ray.dir, tmin, *tmax) else {
                continue;
            };
            match visitor.sphere((start + k) as u32, t) {
                Decision::Ignore => {}
                Decision::Accept => *tmax = t,
                Decision::AcceptAndTerminate => {
                    *tmax = t;
                    return LeafEnd::Stop;
                }
                Decision::Abort => return LeafEnd::Stop,
            }
        }
        LeafEnd::Continue
    }
}

/// Built-in curve segments in leaf-slot order (guide §5.2), each tested with
/// [`CurveSegment::intersect`]: the nearest entry into a round curve's tube (§9.6: a ray whose
/// interval starts inside the tube does not hit it) or a ribbon's nearest hit, with its `u`.
pub(crate) struct CurveLeaves<'a>(pub &'a [CurveSegment]);

impl<V: GasVisitor> LeafIntersector<V> for CurveLeaves<'_> {
    #[inline(always)]
    fn leaf(
        &self,
        start: u32,
        count: u32,
        ray: &PreparedRay,
        tmin: f32,
        tmax: &mut f32,
        visitor: &mut V,
        _spare: &mut [Entry],
    ) -> LeafEnd {
        let start = start as usize;
        let org = Vec3::from(ray.org);
        for (k, s) in self.0[start..start + count as usize].iter().enumerate() {
            let Some(hit) = s.intersect(org, ray.dir, tmin, *tmax) else {
                continue;
            };
            match visitor.curve((start + k) as u32, &hit) {
                Decision::Ignore => {}
                Decision::Accept => *tmax = hit.t,
                Decision::AcceptAndTerminate => {
                    *tmax = hit.t;
                    return LeafEnd::Stop;
                }
                Decision::Abort => return LeafEnd::Stop,
            }
        }
        LeafEnd::Continue
    }
}
