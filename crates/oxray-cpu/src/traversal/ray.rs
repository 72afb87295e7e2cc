//! The per-ray constants traversal precomputes.

use oxray_bvh::triangle::WatertightRay;
use oxray_core::ray::{max_ignore_nan, min_ignore_nan, Ray, ROBUST_FAR, TMAX_SLACK};

/// The per-ray constants of box and triangle tests.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PreparedRay {
    pub org: [f32; 3],
    /// The direction as given (not normalised: t is in its units), for the sphere test.
    pub dir: glam::Vec3,
    /// `1 / d`, with `+inf` for a zero component (of either sign).
    pub inv: [f32; 3],
    /// Index into `Bvh4Node::bounds` of each axis' near plane (the far plane is the other one).
    pub near: [usize; 3],
    pub far: [usize; 3],
    pub tri: WatertightRay,
}

impl PreparedRay {
    /// `None` for an invalid ray, which can hit nothing. Inlined into every caller: the
    /// structure is large, and a call would build it on the stack and copy it out.
    #[inline(always)]
    pub fn new(ray: &Ray) -> Option<Self> {
        ray.validate().ok()?;
        Some(Self::of_valid(ray))
    }

    /// The constants of a ray that [`Ray::validate`] accepted.
    #[inline(always)]
    pub fn of_valid(ray: &Ray) -> Self {
        let d = ray.direction.to_array();
        let mut inv = [0.0; 3];
        let mut near = [0; 3];
        let mut far = [0; 3];
        for a in 0..3 {
            // A zero component gets +inf whatever its sign: the slab test then yields NaN exactly
            // when the origin lies on a slab plane, and the NaN-ignoring min/max of the box test
            // treat that as "inside", which is right for a closed box.
            inv[a] = if d[a] == 0.0 {
                f32::INFINITY
            } else {
                1.0 / d[a]
            };
            if inv[a] >= 0.0 {
                near[a] = a;
                far[a] = a + 3;
            } else {
                near[a] = a + 3;
                far[a] = a;
            }
        }
        PreparedRay {
            org: ray.origin.to_array(),
            dir: ray.direction,
            inv,
            near,
            far,
            tri: WatertightRay::new(ray.origin, ray.direction),
        }
    }

    /// The scalar slab test against one box, conservative like the 4-wide one.
    #[inline]
    pub fn hits_box(&self, b: &oxray_core::Aabb, tmin: f32, tmax: f32) -> bool {
        let lo = b.min.to_array();
        let hi = b.max.to_array();
        let mut t0 = tmin;
        let mut t1 = f32::INFINITY;
        for a in 0..3 {
            let (n, f) = if self.near[a] == a {
                (lo[a], hi[a])
            } else {
                (hi[a], lo[a])
            };
            let tn = (n - self.org[a]) * self.inv[a];
            let tf = (f - self.org[a]) * self.inv[a];
            t0 = max_ignore_nan(t0, tn);
            t1 = min_ignore_nan(t1, tf);
        }
        t0 <= min_ignore_nan(tmax * TMAX_SLACK, t1 * ROBUST_FAR)
    }
}
