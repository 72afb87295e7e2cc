//! A small deterministic random-number generator.

use glam::{Affine3A, Mat3, Quat, Vec3};

/// SplitMix64: a small, fast, deterministic generator, so that tests and benchmark rays do not
/// depend on another crate's stream staying the same across versions.
///
/// Every method's stream is part of the contract: the benchmark ray sets of [`crate::rays`] and
/// the cases of many tests are drawn from it.
///
/// ```
/// use oxray_testkit::Rng;
/// let mut a = Rng::new(7);
/// let mut b = Rng::new(7);
/// assert_eq!(a.next_u64(), b.next_u64());
/// let x = a.f32();
/// assert!((0.0..1.0).contains(&x));
/// ```
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator from a seed.
    #[must_use]
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`: the top 24 bits of [`Rng::next_u64`] over `2^24` (exact).
    pub fn f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.f32()
    }

    /// Uniform in `0..n` (`n` must not be 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }

    /// A point uniform in the cube `[lo, hi]^3`.
    pub fn vec3(&mut self, lo: f32, hi: f32) -> Vec3 {
        Vec3::new(self.range(lo, hi), self.range(lo, hi), self.range(lo, hi))
    }

    /// A direction with components uniform in `[-1, 1)`, not too short (longer than 0.1), not
    /// normalised.
    pub fn dir(&mut self) -> Vec3 {
        loop {
            let d = self.vec3(-1.0, 1.0);
            if d.length() > 0.1 {
                return d;
            }
        }
    }

    /// A unit vector, uniform on the sphere.
    pub fn unit(&mut self) -> Vec3 {
        loop {
            let d = self.vec3(-1.0, 1.0);
            let l = d.length();
            if l > 0.1 && l <= 1.0 {
                return d / l;
            }
        }
    }

    /// A random rotation.
    pub fn rotation(&mut self) -> Quat {
        Quat::from_axis_angle(self.unit(), self.range(0.0, std::f32::consts::TAU))
    }

    /// A well-conditioned random affine transform: rotation, then a non-uniform scale with
    /// factors in `[0.5, 2]` along randomly rotated axes, then a translation in
    /// `[-spread, spread]^3`. The determinant is positive (no mirroring).
    pub fn affine(&mut self, spread: f32) -> Affine3A {
        let scale = Vec3::new(
            self.range(0.5, 2.0),
            self.range(0.5, 2.0),
            self.range(0.5, 2.0),
        );
        let r1 = Mat3::from_quat(self.rotation());
        let r2 = Mat3::from_quat(self.rotation());
        let linear = r2 * Mat3::from_diagonal(scale) * r1;
        Affine3A::from_mat3_translation(linear, self.vec3(-spread, spread))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_stream_is_splitmix64() {
        // The first outputs of SplitMix64 seeded with 0 (the reference implementation's).
        let mut r = Rng::new(0);
        assert_eq!(r.next_u64(), 0xE220_A839_7B1D_CDAF);
        assert_eq!(r.next_u64(), 0x6E78_9E6A_A1B9_65F4);
        assert_eq!(r.next_u64(), 0x06C4_5D18_8009_454F);
    }

    #[test]
    fn same_seed_same_stream_other_seed_other_stream() {
        let (mut a, mut b, mut c) = (Rng::new(42), Rng::new(42), Rng::new(43));
        let xs: Vec<u64> = (0..100).map(|_| a.next_u64()).collect();
        let ys: Vec<u64> = (0..100).map(|_| b.next_u64()).collect();
        let zs: Vec<u64> = (0..100).map(|_| c.next_u64()).collect();
        assert_eq!(xs, ys);
        assert_ne!(xs, zs);
        // A clone continues the same stream.
        let mut d = a.clone();
        assert_eq!(a.next_u64(), d.next_u64());
    }

    #[test]
    fn draws_stay_in_their_ranges() {
        let mut r = Rng::new(3);
        for _ in 0..10_000 {
            let x = r.f32();
            assert!((0.0..1.0).contains(&x), "{x}");
            let y = r.range(-2.0, 5.0);
            assert!((-2.0..5.0).contains(&y), "{y}");
            assert!(r.below(7) < 7);
            let p = r.vec3(1.0, 2.0);
            assert!(p.cmpge(Vec3::ONE).all() && p.cmple(Vec3::splat(2.0)).all());
            assert!(r.dir().length() > 0.1);
            assert!((r.unit().length() - 1.0).abs() < 1e-6);
        }
    }

    #[test]
    fn f32_is_the_top_24_bits() {
        let (mut a, mut b) = (Rng::new(9), Rng::new(9));
        for _ in 0..1000 {
            let bits = b.next_u64() >> 40;
            assert_eq!(a.f32(), bits as f32 * (1.0 / (1u64 << 24) as f32));
        }
    }

    #[test]
    fn affine_transforms_are_well_conditioned_and_keep_orientation() {
        let mut r = Rng::new(5);
        for _ in 0..1000 {
            let a = r.affine(10.0);
            let det = a.matrix3.determinant();
            assert!(det > 0.5f32.powi(3) * 0.99 && det < 8.0 * 1.01, "{det}");
            assert!(a.translation.abs().max_element() <= 10.0);
            let q = r.rotation();
            assert!((q.length() - 1.0).abs() < 1e-5);
        }
    }
}
