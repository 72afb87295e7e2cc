//! Four triangles in structure-of-arrays form, intersected together with 4-wide arithmetic.
//!
//! The 4-wide test performs, lane by lane, exactly the `f32` operations of
//! [`WatertightRay::intersect`] in the same order, and hands lanes that need the exact `f64`
//! fallback to the scalar code, so its hits are bit-identical to the scalar test's.

use crate::triangle::{TriangleHit, WatertightRay};
use bytemuck::{Pod, Zeroable};

/// Four triangles: `v[vertex][axis][lane]`. Unused lanes hold zeros and are masked off.
#[repr(C, align(16))]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Triangle4 {
    /// Vertex coordinates.
    pub v: [[[f32; 4]; 3]; 3],
}

impl Triangle4 {
    /// Sets lane `lane` to the triangle `t`.
    pub fn set(&mut self, lane: usize, t: &[[f32; 3]; 3]) {
        for (k, p) in t.iter().enumerate() {
            for (axis, &c) in p.iter().enumerate() {
                self.v[k][axis][lane] = c;
            }
        }
    }

    /// The triangle in lane `lane`.
    #[must_use]
    pub fn get(&self, lane: usize) -> [[f32; 3]; 3] {
        std::array::from_fn(|k| std::array::from_fn(|axis| self.v[k][axis][lane]))
    }
}

/// The hits of up to four triangles: lane `l` hit iff bit `l` of `mask` is set.
#[derive(Clone, Copy, Debug)]
pub struct Hits4 {
    /// Bit `l`: lane `l` hit.
    pub mask: u32,
    /// Distances.
    pub t: [f32; 4],
    /// First barycentrics.
    pub u: [f32; 4],
    /// Second barycentrics.
    pub v: [f32; 4],
    /// Bit `l`: lane `l` was hit on its front face.
    pub front: u32,
}

impl Hits4 {
    /// The hit of lane `l`.
    #[inline(always)]
    #[must_use]
    pub fn get(&self, l: usize) -> TriangleHit {
        TriangleHit {
            t: self.t[l],
            u: self.u[l],
            v: self.v[l],
            front_face: self.front & (1 << l) != 0,
        }
    }
}

impl WatertightRay {
    /// Intersects the first `valid` (1 to 4) lanes of a block; hits lie in `[tmin, tmax]`.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    #[must_use]
    pub fn intersect4(&self, tri: &Triangle4, valid: usize, tmin: f32, tmax: f32) -> Hits4 {
        use crate::triangle::F32_TINY;
        use std::arch::x86_64::*;
        let [kx, ky, kz] = self.k;
        // SAFETY: SSE/SSE2 are part of the x86_64 baseline. `Triangle4` is `align(16)` and made of
        // `[f32; 4]` rows, so its loads are aligned and in bounds; the stores go to local
        // `[f32; 4]` arrays (unaligned stores).
        unsafe {
            let ld = |row: &[f32; 4]| _mm_load_ps(row.as_ptr());
            let (sx, sy, sz) = (
                _mm_set1_ps(self.shear[0]),
                _mm_set1_ps(self.shear[1]),
                _mm_set1_ps(self.shear[2]),
            );
            let o = [
                _mm_set1_ps(self.org[0]),
                _mm_set1_ps(self.org[1]),
                _mm_set1_ps(self.org[2]),
            ];
            // Vertex relative to the origin, sheared: (x, y, z) in the ray's frame.
            let shear = |p: &[[f32; 4]; 3]| {
                let rx = _mm_sub_ps(ld(&p[kx]), o[kx]);
                let ry = _mm_sub_ps(ld(&p[ky]), o[ky]);
                let rz = _mm_sub_ps(ld(&p[kz]), o[kz]);
                (
                    _mm_sub_ps(rx, _mm_mul_ps(sx, rz)),
                    _mm_sub_ps(ry, _mm_mul_ps(sy, rz)),
                    _mm_mul_ps(sz, rz),
                )
            };
            let (ax, ay, az) = shear(&tri.v[0]);
            let (bx, by, bz) = shear(&tri.v[1]);
            let (cx, cy, cz) = shear(&tri.v[2]);
            let u = _mm_sub_ps(_mm_mul_ps(cx, by), _mm_mul_ps(cy, bx));
            let v = _mm_sub_ps(_mm_mul_ps(ax, cy), _mm_mul_ps(ay, cx));
            let w = _mm_sub_ps(_mm_mul_ps(bx, ay), _mm_mul_ps(by, ax));
            let zero = _mm_setzero_ps();
            let det = _mm_add_ps(_mm_add_ps(u, v), w);
            let t_scaled = _mm_add_ps(
                _mm_add_ps(_mm_mul_ps(u, az), _mm_mul_ps(v, bz)),
                _mm_mul_ps(w, cz),
            );
            let lanes = (1u32 << valid) - 1;
            // Lanes the scalar code would send to its exact fallback (see `needs_f64`).
            let zero_edge = _mm_or_ps(
                _mm_or_ps(_mm_cmpeq_ps(u, zero), _mm_cmpeq_ps(v, zero)),
                _mm_cmpeq_ps(w, zero),
            );
            let abs_mask = _mm_castsi128_ps(_mm_set1_epi32(0x7FFF_FFFF));
            let tiny = _mm_set1_ps(F32_TINY);
            let inf = _mm_set1_ps(f32::INFINITY);
            let ok = |x: __m128| {
                let a = _mm_and_ps(x, abs_mask);
                _mm_and_ps(_mm_cmpge_ps(a, tiny), _mm_cmplt_ps(a, inf))
            };
            let fine = _mm_and_ps(ok(det), ok(t_scaled));
            let suspect =
                (_mm_movemask_ps(zero_edge) as u32 | !(_mm_movemask_ps(fine) as u32)) & lanes;
            let any_neg = _mm_or_ps(
                _mm_or_ps(_mm_cmplt_ps(u, zero), _mm_cmplt_ps(v, zero)),
                _mm_cmplt_ps(w, zero),
            );
            let any_pos = _mm_or_ps(
                _mm_or_ps(_mm_cmpgt_ps(u, zero), _mm_cmpgt_ps(v, zero)),
                _mm_cmpgt_ps(w, zero),
            );
            let outside = _mm_movemask_ps(_mm_and_ps(any_neg, any_pos)) as u32;
            let inv = _mm_div_ps(_mm_set1_ps(1.0), det);
            // Adding +0.0 turns a -0.0 distance into +0.0, as the scalar code does.
            let t = _mm_add_ps(_mm_mul_ps(t_scaled, inv), zero);
            let in_range = _mm_and_ps(
                _mm_cmpge_ps(t, _mm_set1_ps(tmin)),
                _mm_cmple_ps(t, _mm_set1_ps(tmax)),
            );
            let mut hits = Hits4 {
                mask: _mm_movemask_ps(in_range) as u32 & !outside & lanes & !suspect,
                t: [0.0; 4],
                u: [0.0; 4],
                v: [0.0; 4],
                front: _mm_movemask_ps(_mm_cmpgt_ps(det, zero)) as u32,
            };
            _mm_storeu_ps(hits.t.as_mut_ptr(), t);
            _mm_storeu_ps(hits.u.as_mut_ptr(), _mm_mul_ps(v, inv));
            _mm_storeu_ps(hits.v.as_mut_ptr(), _mm_mul_ps(w, inv));
            if suspect != 0 {
                self.resolve_suspects(tri, suspect, tmin, tmax, &mut hits);
            }
            hits
        }
    }

    /// Portable form: the scalar test lane by lane.
    #[cfg(not(target_arch = "x86_64"))]
    #[inline(always)]
    pub fn intersect4(&self, tri: &Triangle4, valid: usize, tmin: f32, tmax: f32) -> Hits4 {
        let mut hits = Hits4 {
            mask: 0,
            t: [0.0; 4],
            u: [0.0; 4],
            v: [0.0; 4],
            front: 0,
        };
        self.resolve_suspects(tri, (1u32 << valid) - 1, tmin, tmax, &mut hits);
        hits
    }

    /// Runs the scalar test on the lanes in `lanes`, writing their results into `hits`.
    #[cold]
    #[inline(never)]
    fn resolve_suspects(
        &self,
        tri: &Triangle4,
        lanes: u32,
        tmin: f32,
        tmax: f32,
        hits: &mut Hits4,
    ) {
        for l in 0..4 {
            if lanes & (1 << l) == 0 {
                continue;
            }
            let [p0, p1, p2] = tri.get(l);
            hits.mask &= !(1 << l);
            hits.front &= !(1 << l);
            if let Some(h) = self.intersect(&p0, &p1, &p2, tmin, tmax) {
                hits.mask |= 1 << l;
                hits.t[l] = h.t;
                hits.u[l] = h.u;
                hits.v[l] = h.v;
                if h.front_face {
                    hits.front |= 1 << l;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// The 4-wide test agrees bit for bit with the scalar one, fallback lanes included.
    #[test]
    fn matches_scalar_test() {
        let mut seed = 1u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        };
        for case in 0..20_000 {
            let mut block = Triangle4::zeroed();
            let mut tris = [[[0.0f32; 3]; 3]; 4];
            for (l, t) in tris.iter_mut().enumerate() {
                for p in t.iter_mut() {
                    *p = [rnd(), rnd(), rnd()];
                }
                // Some lanes share a vertex with the ray's target, or are degenerate.
                if case % 7 == 0 && l == 1 {
                    t[2] = t[0];
                }
                block.set(l, t);
            }
            let o = Vec3::new(rnd(), rnd(), rnd()) * 2.0;
            let target = if case % 3 == 0 {
                Vec3::from(tris[0][1])
            } else {
                Vec3::new(rnd(), rnd(), rnd()) * 0.5
            };
            let mut d = target - o;
            if case % 5 == 0 {
                d.x = 0.0;
            }
            if d == Vec3::ZERO {
                continue;
            }
            let r = WatertightRay::new(o, d);
            let valid = 1 + case % 4;
            let (tmin, tmax) = (0.0, if case % 2 == 0 { f32::INFINITY } else { 1.0 });
            let h = r.intersect4(&block, valid, tmin, tmax);
            for (l, t) in tris.iter().enumerate() {
                let s = if l < valid {
                    r.intersect(&t[0], &t[1], &t[2], tmin, tmax)
                } else {
                    None
                };
                assert_eq!(h.mask & (1 << l) != 0, s.is_some(), "case {case} lane {l}");
                if let Some(s) = s {
                    let v = h.get(l);
                    assert_eq!(
                        (v.t.to_bits(), v.u.to_bits(), v.v.to_bits(), v.front_face),
                        (s.t.to_bits(), s.u.to_bits(), s.v.to_bits(), s.front_face),
                        "case {case} lane {l}"
                    );
                }
            }
        }
    }
}
