//! Batches of rays through a small triangle structure (at most [`SMALL_SLOTS`] leaf slots),
//! sixteen rays at a time and without the tree.
//!
//! In a structure this small (a room, a box, a few objects) a ray enters most of the tree's
//! leaves anyway, and what it costs is the work around the tests: its set-up, the walk's
//! bookkeeping and its answer, each paid one ray at a time. Here a batch's rays are grouped by
//! the watertight test's axis permutation (six classes: the dominant axis and the sign along
//! it), and each group of sixteen rays of one class is tested in AVX-512, one lane per ray,
//! against the triangles of every leaf whose box one of its rays may enter (the tree's
//! conservative slab test, sixteen lanes at once): the vertices are broadcast, the
//! permutation is the class's (fixed at compile time), and every lane performs exactly the
//! `f32` operations of
//! [`WatertightRay::intersect`] in the same order; a lane whose edge function is exactly zero
//! (or whose values leave the safe range) goes to the scalar test, with its exact fallback. So
//! every candidate hit (t, u, v, facing) is bit-identical to the tree walk's, and the closest
//! one is the same, up to which of two slots at exactly the same distance is kept (here the
//! later slot; in the walk, the later visited).
//!
//! The box tests only discard triangles that cannot be hit (they are conservative), so the
//! group finds every hit the walk finds. Measured on the Cornell box's path tracer: 1.2x the
//! samples per second of the walk (`docs/BENCHMARKS.md`).

use crate::Gas;
use oxray_bvh::triangle::{TriangleHit, WatertightRay};
use oxray_bvh::GasKind;
use oxray_core::ray::{ROBUST_FAR, TMAX_SLACK};
use oxray_core::Ray;

/// Leaf slots (triangles, padding included) up to which a structure is tested whole.
pub(crate) const SMALL_SLOTS: usize = 64;

/// Rays per group: one AVX-512 register of floats.
const GROUP: usize = 16;

/// Rays handled per call of the grouping (the batch's own chunks are this size).
const CHUNK: usize = 256;

/// The candidate a ray keeps: its leaf slot and its hit.
pub(crate) type Found = (u32, TriangleHit);

/// Whether [`small_gas_rays`] takes rays through `gas` on this processor.
#[inline]
pub(crate) fn applies(gas: &Gas) -> bool {
    gas.motion.is_none()
        && gas.kind == GasKind::Triangles
        && !gas.slot_prim.is_empty()
        && gas.slot_prim.len() <= SMALL_SLOTS
        && gas.bvh8.is_some()
        && has_avx512()
}

#[cfg(target_arch = "x86_64")]
fn has_avx512() -> bool {
    std::arch::is_x86_feature_detected!("avx512f")
}

#[cfg(not(target_arch = "x86_64"))]
fn has_avx512() -> bool {
    false
}

/// Closest hits (`first_hit_ends` false) or any hit (true) of `rays` in `gas`, which
/// [`applies`] must accept: `out[i] = answer(i, found)`, with `None` for a ray that hits
/// nothing or is invalid. With `first_hit_ends`, the hit kept is the first found. Returns
/// `false`, having done nothing, for a tree it does not read (then the walk answers).
pub(crate) fn small_gas_rays<T>(
    gas: &Gas,
    rays: &[Ray],
    out: &mut [T],
    first_hit_ends: bool,
    answer: impl Fn(usize, Option<Found>) -> T,
) -> bool {
    debug_assert!(applies(gas));
    let Some(tris) = Triangles::of(gas) else {
        return false;
    };
    for (c, (rays, out)) in rays.chunks(CHUNK).zip(out.chunks_mut(CHUNK)).enumerate() {
        chunk(&tris, rays, out, first_hit_ends, &|i, f| {
            answer(c * CHUNK + i, f)
        });
    }
    true
}

/// The structure's triangles leaf by leaf (in the tree's order), without the padding lanes,
/// and each leaf's box: a group tests a leaf's triangles only where one of its rays may enter
/// the box.
struct Triangles {
    /// `v[i]`: triangle `i`'s vertices (three points, x y z each).
    v: [[f32; 9]; SMALL_SLOTS],
    slot: [u32; SMALL_SLOTS],
    n: usize,
    leaves: [Leaf; SMALL_SLOTS],
    n_leaves: usize,
}

#[derive(Clone, Copy, Default)]
struct Leaf {
    /// Lower then upper corner.
    lo: [f32; 3],
    hi: [f32; 3],
    /// Its triangles: `start..end` of [`Triangles::v`].
    start: usize,
    end: usize,
}

impl Triangles {
    /// `None` where the tree is not the 8-wide one or holds more than it should.
    fn of(gas: &Gas) -> Option<Triangles> {
        let bvh8 = gas.bvh8.as_ref()?;
        let mut t = Triangles {
            v: [[0.0; 9]; SMALL_SLOTS],
            slot: [0; SMALL_SLOTS],
            n: 0,
            leaves: [Leaf::default(); SMALL_SLOTS],
            n_leaves: 0,
        };
        let mut stack = [0u32; SMALL_SLOTS];
        let mut sp = 1;
        while sp > 0 {
            sp -= 1;
            let node = bvh8.nodes.get(stack[sp] as usize)?;
            for lane in 0..8 {
                if !node.is_used(lane) {
                    continue;
                }
                let (child, count) = (node.child[lane] as usize, node.count[lane] as usize);
                if count == 0 {
                    *stack.get_mut(sp)? = child as u32;
                    sp += 1;
                    continue;
                }
                let b = node.child_bounds(lane);
                let start = t.n;
                for s in child..child + count {
                    let prim = *gas.slot_prim.get(s)?;
                    if prim == oxray_bvh::gas::NO_PRIMITIVE {
                        continue;
                    }
                    let block = gas.triangles.get(s / 4)?;
                    let out = t.v.get_mut(t.n)?;
                    for k in 0..3 {
                        for axis in 0..3 {
                            out[k * 3 + axis] = block.v[k][axis][s % 4];
                        }
                    }
                    t.slot[t.n] = s as u32;
                    t.n += 1;
                }
                *t.leaves.get_mut(t.n_leaves)? = Leaf {
                    lo: b.min.to_array(),
                    hi: b.max.to_array(),
                    start,
                    end: t.n,
                };
                t.n_leaves += 1;
            }
        }
        Some(t)
    }
}

/// Up to [`GROUP`] rays of one class, structure of arrays.
struct Lanes {
    org: [[f32; GROUP]; 3],
    /// The direction (the shear and the box test's inverses are computed per group).
    dir: [[f32; GROUP]; 3],
    tmin: [f32; GROUP],
    tmax: [f32; GROUP],
    /// Rays in the group (the rest is padding, masked off).
    n: usize,
}

/// What a group's lanes found.
struct Best {
    t: [f32; GROUP],
    u: [f32; GROUP],
    v: [f32; GROUP],
    /// Bit `l`: lane `l` found a hit.
    hit: u32,
    /// Bit `l`: lane `l`'s hit is on the front face.
    front: u32,
    /// Index into [`Triangles`] of lane `l`'s hit.
    tri: [u32; GROUP],
}

/// The axis permutations `[kx, ky, kz]` of [`WatertightRay::new`], by class: the dominant
/// axis `kz` times two, plus one where the direction along it is negative.
const CLASSES: [[usize; 3]; 6] = [
    [1, 2, 0],
    [2, 1, 0],
    [2, 0, 1],
    [0, 2, 1],
    [0, 1, 2],
    [1, 0, 2],
];

/// The class of a direction: [`WatertightRay::new`]'s choice of axes.
#[inline]
fn class_of(d: [f32; 3]) -> usize {
    let a = d.map(f32::abs);
    let kz = if a[0] >= a[1] && a[0] >= a[2] {
        0
    } else if a[1] >= a[2] {
        1
    } else {
        2
    };
    kz * 2 + usize::from(d[kz] < 0.0)
}

fn chunk<T>(
    tris: &Triangles,
    rays: &[Ray],
    out: &mut [T],
    first_hit_ends: bool,
    answer: &impl Fn(usize, Option<Found>) -> T,
) {
    // Rays by class, in batch order.
    let mut members = [[0u16; CHUNK]; 6];
    let mut count = [0usize; 6];
    for (i, (ray, o)) in rays.iter().zip(out.iter_mut()).enumerate() {
        if ray.validate().is_err() {
            *o = answer(i, None);
            continue;
        }
        let c = class_of(ray.direction.to_array());
        debug_assert_eq!(CLASSES[c], WatertightRay::new(ray.origin, ray.direction).k);
        members[c][count[c]] = i as u16;
        count[c] += 1;
    }
    for c in 0..6 {
        for group in members[c][..count[c]].chunks(GROUP) {
            let mut lanes = Lanes {
                org: [[0.0; GROUP]; 3],
                dir: [[0.0; GROUP]; 3],
                tmin: [0.0; GROUP],
                tmax: [-1.0; GROUP],
                n: group.len(),
            };
            for (l, &i) in group.iter().enumerate() {
                let r = &rays[i as usize];
                let (o, d) = (r.origin.to_array(), r.direction.to_array());
                for a in 0..3 {
                    lanes.org[a][l] = o[a];
                    lanes.dir[a][l] = d[a];
                }
                lanes.tmin[l] = r.tmin;
                lanes.tmax[l] = r.tmax;
            }
            let best = test_group(c, tris, &lanes, first_hit_ends);
            for (l, &i) in group.iter().enumerate() {
                let found = (best.hit & (1 << l) != 0).then(|| {
                    let hit = TriangleHit {
                        t: best.t[l],
                        u: best.u[l],
                        v: best.v[l],
                        front_face: best.front & (1 << l) != 0,
                    };
                    (tris.slot[best.tri[l] as usize], hit)
                });
                out[i as usize] = answer(i as usize, found);
            }
        }
    }
}

/// The group's tests, for its class's permutation.
fn test_group(class: usize, tris: &Triangles, lanes: &Lanes, first_hit_ends: bool) -> Best {
    #[cfg(target_arch = "x86_64")]
    {
        // SAFETY: `applies` found AVX-512F on this processor before any ray came here.
        unsafe {
            match class {
                0 => group_avx512::<1, 2, 0>(tris, lanes, first_hit_ends),
                1 => group_avx512::<2, 1, 0>(tris, lanes, first_hit_ends),
                2 => group_avx512::<2, 0, 1>(tris, lanes, first_hit_ends),
                3 => group_avx512::<0, 2, 1>(tris, lanes, first_hit_ends),
                4 => group_avx512::<0, 1, 2>(tris, lanes, first_hit_ends),
                _ => group_avx512::<1, 0, 2>(tris, lanes, first_hit_ends),
            }
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (class, tris, lanes, first_hit_ends);
        unreachable!("small structures are tested whole only with AVX-512")
    }
}

/// Every triangle against the group's lanes (permutation `KX`, `KY`, `KZ`).
///
/// # Safety
///
/// The processor must have AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f")]
unsafe fn group_avx512<const KX: usize, const KY: usize, const KZ: usize>(
    tris: &Triangles,
    lanes: &Lanes,
    first_hit_ends: bool,
) -> Best {
    use oxray_bvh::triangle::F32_TINY;
    use std::arch::x86_64::*;
    let ld = |a: &[f32; GROUP]| _mm512_loadu_ps(a.as_ptr());
    let org = [ld(&lanes.org[0]), ld(&lanes.org[1]), ld(&lanes.org[2])];
    let d = [ld(&lanes.dir[0]), ld(&lanes.dir[1]), ld(&lanes.dir[2])];
    let one = _mm512_set1_ps(1.0);
    // `WatertightRay::new`'s shear, sixteen lanes at once (the same correctly rounded
    // divisions); the padding lanes' values are never used.
    let (sx, sy, sz) = (
        _mm512_div_ps(d[KX], d[KZ]),
        _mm512_div_ps(d[KY], d[KZ]),
        _mm512_div_ps(one, d[KZ]),
    );
    let mut shear = [[0.0f32; GROUP]; 3];
    _mm512_storeu_ps(shear[0].as_mut_ptr(), sx);
    _mm512_storeu_ps(shear[1].as_mut_ptr(), sy);
    _mm512_storeu_ps(shear[2].as_mut_ptr(), sz);
    let tmin = ld(&lanes.tmin);
    let mut best_t = ld(&lanes.tmax);
    let mut best_u = _mm512_setzero_ps();
    let mut best_v = _mm512_setzero_ps();
    let mut best_tri = _mm512_setzero_si512();
    let all: u16 = if lanes.n >= GROUP {
        u16::MAX
    } else {
        ((1u32 << lanes.n) - 1) as u16
    };
    let mut hit: u16 = 0;
    let mut front: u16 = 0;
    let zero = _mm512_setzero_ps();
    let tiny = _mm512_set1_ps(F32_TINY);
    let inf = _mm512_set1_ps(f32::INFINITY);
    // Macros rather than closures: every intrinsic stays inline in this AVX-512 function.
    macro_rules! sheared {
        ($v:expr, $p:expr) => {{
            let r = [
                _mm512_sub_ps(_mm512_set1_ps($v[$p * 3]), org[0]),
                _mm512_sub_ps(_mm512_set1_ps($v[$p * 3 + 1]), org[1]),
                _mm512_sub_ps(_mm512_set1_ps($v[$p * 3 + 2]), org[2]),
            ];
            (
                _mm512_sub_ps(r[KX], _mm512_mul_ps(sx, r[KZ])),
                _mm512_sub_ps(r[KY], _mm512_mul_ps(sy, r[KZ])),
                _mm512_mul_ps(sz, r[KZ]),
            )
        }};
    }
    macro_rules! cmp {
        ($op:ident, $x:expr, $y:expr) => {
            _mm512_cmp_ps_mask::<$op>($x, $y)
        };
    }
    macro_rules! ok {
        ($x:expr) => {{
            let a = _mm512_abs_ps($x);
            cmp!(_CMP_GE_OQ, a, tiny) & cmp!(_CMP_LT_OQ, a, inf)
        }};
    }
    // One triangle against the lanes in `$enter` (the rest keep what they have).
    macro_rules! triangle {
        ($i:expr, $enter:expr) => {{
            let i: usize = $i;
            let v = &tris.v[i];
            let (ax, ay, az) = sheared!(v, 0);
            let (bx, by, bz) = sheared!(v, 1);
            let (cx, cy, cz) = sheared!(v, 2);
            let u = _mm512_sub_ps(_mm512_mul_ps(cx, by), _mm512_mul_ps(cy, bx));
            let vv = _mm512_sub_ps(_mm512_mul_ps(ax, cy), _mm512_mul_ps(ay, cx));
            let w = _mm512_sub_ps(_mm512_mul_ps(bx, ay), _mm512_mul_ps(by, ax));
            let det = _mm512_add_ps(_mm512_add_ps(u, vv), w);
            let t_scaled = _mm512_add_ps(
                _mm512_add_ps(_mm512_mul_ps(u, az), _mm512_mul_ps(vv, bz)),
                _mm512_mul_ps(w, cz),
            );
            let zero_edge =
                cmp!(_CMP_EQ_OQ, u, zero) | cmp!(_CMP_EQ_OQ, vv, zero) | cmp!(_CMP_EQ_OQ, w, zero);
            let fine = ok!(det) & ok!(t_scaled);
            let live = $enter & !(if first_hit_ends { hit } else { 0 });
            let suspect = (zero_edge | !fine) & live;
            let outside = (cmp!(_CMP_LT_OQ, u, zero)
                | cmp!(_CMP_LT_OQ, vv, zero)
                | cmp!(_CMP_LT_OQ, w, zero))
                & (cmp!(_CMP_GT_OQ, u, zero)
                    | cmp!(_CMP_GT_OQ, vv, zero)
                    | cmp!(_CMP_GT_OQ, w, zero));
            // Lanes inside the triangle's edges: only they need the division.
            let inside = live & !outside & !suspect;
            let inv = if inside != 0 {
                _mm512_div_ps(one, det)
            } else {
                zero
            };
            // Adding +0.0 turns a -0.0 distance into +0.0, as the scalar test does.
            let t = _mm512_add_ps(_mm512_mul_ps(t_scaled, inv), zero);
            let in_range = cmp!(_CMP_GE_OQ, t, tmin) & cmp!(_CMP_LE_OQ, t, best_t);
            let take = in_range & inside;
            if take != 0 {
                best_t = _mm512_mask_blend_ps(take, best_t, t);
                best_u = _mm512_mask_blend_ps(take, best_u, _mm512_mul_ps(vv, inv));
                best_v = _mm512_mask_blend_ps(take, best_v, _mm512_mul_ps(w, inv));
                best_tri = _mm512_mask_blend_epi32(take, best_tri, _mm512_set1_epi32(i as i32));
                front = (front & !take) | (take & cmp!(_CMP_GT_OQ, det, zero));
                hit |= take;
            }
            if suspect != 0 {
                // The scalar test, with its exact fallback, lane by lane.
                let mut t_lanes = [0.0f32; GROUP];
                _mm512_storeu_ps(t_lanes.as_mut_ptr(), best_t);
                let mut u_lanes = [0.0f32; GROUP];
                _mm512_storeu_ps(u_lanes.as_mut_ptr(), best_u);
                let mut v_lanes = [0.0f32; GROUP];
                _mm512_storeu_ps(v_lanes.as_mut_ptr(), best_v);
                let mut tri_lanes = [0i32; GROUP];
                _mm512_storeu_si512(tri_lanes.as_mut_ptr().cast(), best_tri);
                let mut m = suspect;
                while m != 0 {
                    let l = m.trailing_zeros() as usize;
                    m &= m - 1;
                    let ray = WatertightRay {
                        org: [lanes.org[0][l], lanes.org[1][l], lanes.org[2][l]],
                        k: [KX, KY, KZ],
                        shear: [shear[0][l], shear[1][l], shear[2][l]],
                    };
                    let p = |k: usize| [v[k * 3], v[k * 3 + 1], v[k * 3 + 2]];
                    if let Some(h) = ray.intersect(&p(0), &p(1), &p(2), lanes.tmin[l], t_lanes[l]) {
                        t_lanes[l] = h.t;
                        u_lanes[l] = h.u;
                        v_lanes[l] = h.v;
                        tri_lanes[l] = i as i32;
                        let bit = 1u16 << l;
                        front = (front & !bit) | if h.front_face { bit } else { 0 };
                        hit |= bit;
                    }
                }
                best_t = _mm512_loadu_ps(t_lanes.as_ptr());
                best_u = _mm512_loadu_ps(u_lanes.as_ptr());
                best_v = _mm512_loadu_ps(v_lanes.as_ptr());
                best_tri = _mm512_loadu_si512(tri_lanes.as_ptr().cast());
            }
            if first_hit_ends && hit & all == all {
                break;
            }
        }};
    }
    // `1 / d` per axis, for the leaves' boxes.
    let inv = [
        _mm512_div_ps(one, d[0]),
        _mm512_div_ps(one, d[1]),
        _mm512_div_ps(one, d[2]),
    ];
    // Lanes with a zero direction component (an infinite inverse, whose slab distances may be
    // NaN) take every leaf: the box test only spares work.
    let mut nocull: u16 = 0;
    for x in inv {
        nocull |= cmp!(_CMP_EQ_OQ, _mm512_abs_ps(x), inf);
    }
    let (slack, robust) = (_mm512_set1_ps(TMAX_SLACK), _mm512_set1_ps(ROBUST_FAR));
    for leaf in &tris.leaves[..tris.n_leaves] {
        let open = all & !(if first_hit_ends { hit } else { 0 });
        if open == 0 {
            break;
        }
        // The tree's slab test, as conservative (the far distance widened, the interval's end
        // slackened); a NaN distance is ignored.
        let (mut t0, mut t1) = (tmin, inf);
        for a in 0..3 {
            let tl = _mm512_mul_ps(_mm512_sub_ps(_mm512_set1_ps(leaf.lo[a]), org[a]), inv[a]);
            let th = _mm512_mul_ps(_mm512_sub_ps(_mm512_set1_ps(leaf.hi[a]), org[a]), inv[a]);
            t0 = _mm512_max_ps(_mm512_min_ps(tl, th), t0);
            t1 = _mm512_min_ps(_mm512_max_ps(tl, th), t1);
        }
        let end = _mm512_min_ps(_mm512_mul_ps(best_t, slack), _mm512_mul_ps(t1, robust));
        let enter = (cmp!(_CMP_LE_OQ, t0, end) | nocull) & open;
        if enter == 0 {
            continue;
        }
        for i in leaf.start..leaf.end {
            triangle!(i, enter);
        }
    }
    let mut best = Best {
        t: [0.0; GROUP],
        u: [0.0; GROUP],
        v: [0.0; GROUP],
        hit: u32::from(hit & all),
        front: u32::from(front),
        tri: [0; GROUP],
    };
    _mm512_storeu_ps(best.t.as_mut_ptr(), best_t);
    _mm512_storeu_ps(best.u.as_mut_ptr(), best_u);
    _mm512_storeu_ps(best.v.as_mut_ptr(), best_v);
    _mm512_storeu_si512(best.tri.as_mut_ptr().cast(), best_tri);
    best
}
