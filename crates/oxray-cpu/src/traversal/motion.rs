//! Leaf intersectors of structures with motion (guide §5.10.2): the primitives of the two keys
//! around the ray's time, interpolated as each leaf is tested, then the static tests (the
//! watertight triangle test on the interpolated triangles, the box test on the interpolated
//! boxes, the sphere test on the interpolated sphere, the curve test on the interpolated
//! segment). Nothing is allocated: a block of four
//! triangles is interpolated on the stack.

use super::kernel::{Decision, Entry, GasVisitor};
use super::leaf::{LeafEnd, LeafIntersector};
use super::ray::PreparedRay;
use glam::Vec3;
use oxray_bvh::motion::{lerp_aabb, lerp_curve, lerp_sphere, lerp_triangle4};
use oxray_bvh::{CurveSegment, Sphere, Triangle4};
use oxray_core::ray::min_ignore_nan;
use oxray_core::Aabb;

/// Triangle blocks of two keys and the fraction between them.
pub(crate) struct MotionTriangleLeaves<'a> {
    pub a: &'a [Triangle4],
    pub b: &'a [Triangle4],
    pub f: f32,
}

impl<V: GasVisitor> LeafIntersector<V> for MotionTriangleLeaves<'_> {
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
        let mut slot = start as usize;
        let end = slot + count as usize;
        while slot < end {
            let valid = (end - slot).min(4);
            let block = lerp_triangle4(&self.a[slot / 4], &self.b[slot / 4], self.f);
            let hits = ray.tri.intersect4(&block, valid, tmin, *tmax);
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

/// Custom-primitive boxes of two keys: the intersection runs where the ray enters the
/// interpolated box (guide §5.10.1: "the AABBs are also linearly interpolated").
pub(crate) struct MotionAabbLeaves<'a> {
    pub a: &'a [Aabb],
    pub b: &'a [Aabb],
    pub f: f32,
}

impl<V: GasVisitor> LeafIntersector<V> for MotionAabbLeaves<'_> {
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
        for slot in start as usize..(start + count) as usize {
            let b = lerp_aabb(&self.a[slot], &self.b[slot], self.f);
            if ray.hits_box(&b, tmin, *tmax) {
                let (t, stop) = visitor.custom(slot as u32, tmin, *tmax, spare);
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

/// Spheres of two keys: centre and radius interpolated, then the front-face test.
pub(crate) struct MotionSphereLeaves<'a> {
    pub a: &'a [Sphere],
    pub b: &'a [Sphere],
    pub f: f32,
}

impl<V: GasVisitor> LeafIntersector<V> for MotionSphereLeaves<'_> {
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
        let org = Vec3::from(ray.org);
        for slot in start as usize..(start + count) as usize {
            let s = if self.f == 0.0 {
                self.a[slot]
            } else {
                lerp_sphere(&self.a[slot], &self.b[slot], self.f)
            };
            let Some(t) = s.intersect(org, ray.dir, tmin, *tmax) else {
                continue;
            };
            match visitor.sphere(slot as u32, t) {
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

/// Curve segments of two keys: control points, radii and normals interpolated (guide
/// §5.10.2), then [`CurveSegment::intersect`].
pub(crate) struct MotionCurveLeaves<'a> {
    pub a: &'a [CurveSegment],
    pub b: &'a [CurveSegment],
    pub f: f32,
}

impl<V: GasVisitor> LeafIntersector<V> for MotionCurveLeaves<'_> {
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
        let org = Vec3::from(ray.org);
        for slot in start as usize..(start + count) as usize {
            let s = lerp_curve(&self.a[slot], &self.b[slot], self.f);
            let Some(hit) = s.intersect(org, ray.dir, tmin, *tmax) else {
                continue;
            };
            match visitor.curve(slot as u32, &hit) {
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
