//! Packet traversal: eight rays from one origin (pinhole camera rays, rays from one point)
//! walk the 8-wide BVH together as one "fat" ray. At each node, the children's boxes are tested
//! once for the whole packet (SIMD over the children, as for one ray) with interval arithmetic
//! over the packet's directions: a box is entered if any ray of the packet may enter it.
//! Only at a leaf is each ray tested on its own: first against the leaf's box, with exactly the
//! single-ray test, then against the leaf's triangles with the single-ray leaf intersector. So
//! every hit (t, u, v, facing) is bit-identical to the single-ray kernel's, and only which of
//! two primitives at exactly the same distance is reported may differ (fixed by the ray's place
//! in the batch, not by the thread count).
//!
//! Why the packet's box test is conservative: for one origin `o` and a plane at `p`, ray `l`'s
//! slab distance is `(p - o) * inv_l`, rounded. Over the packet, the smallest is
//! `(p - o) * min(inv)` when `p - o >= 0` and `(p - o) * max(inv)` otherwise, and rounding is
//! monotone, so the packet's near distance is at most every ray's and its far distance at least
//! every ray's (before and after the same `ROBUST_FAR` scaling). A box any ray enters is
//! entered by the packet.

use super::kernel::Decision;
use super::kernel::{GasVisitor, STACK_ENTRIES};
use super::leaf::{LeafIntersector, TriangleLeaves};
use super::node::{Bvh8Scalar, NodeLayout};
use super::ray::PreparedRay;
use super::scene::{Path, SceneVisitor};
use crate::{Gas, Isa};
use oxray_bvh::{Bvh8Node, GasKind, Triangle4};
use oxray_core::ray::{ROBUST_FAR, TMAX_SLACK};
use oxray_core::Ray;

/// Rays per packet.
pub(crate) const PACKET: usize = 8;

/// Whether eight rays can share a traversal: one origin, bit for bit. Cheap enough to ask of
/// every group of eight rays in a batch.
#[inline]
pub(crate) fn coherent(rays: &[Ray]) -> bool {
    let Some(first) = rays.first() else {
        return false;
    };
    rays.len() == PACKET && rays.iter().all(|r| r.origin == first.origin)
}

/// One entry of the packet stack.
#[derive(Clone, Copy, Default)]
pub(crate) struct PacketEntry {
    /// Node index (inner) or first primitive slot (leaf).
    child: u32,
    /// Primitive count of a leaf; 0 for an inner node.
    count: u32,
    /// The packet's entry distance: no ray enters the box before it.
    dist: f32,
    /// For a leaf, bit `l`: ray `l` enters its box (by the single-ray test); all bits for an
    /// inner node.
    rays: u32,
}

thread_local! {
    static PACKET_STACK: std::cell::RefCell<Vec<PacketEntry>> =
        const { std::cell::RefCell::new(Vec::new()) };
}

/// Traces eight rays through a GAS as one packet, offering each ray's candidates to its own
/// visitor. Returns `false`, having done nothing, where the packet kernel does not apply (then
/// the caller traces the rays one by one): a GAS other than triangles without motion, a
/// processor without AVX2, rays of different octants, or an invalid ray among them.
pub(crate) fn traverse_gas_packet<'s, V: SceneVisitor<'s>>(
    gas: &'s Gas,
    rays: &[Ray],
    visitors: &mut [V],
) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        if rays.len() != PACKET
            || visitors.len() != PACKET
            || gas.kind != GasKind::Triangles
            || gas.motion.is_some()
            || !matches!(gas.isa().unquantized(), Isa::Avx2 | Isa::Avx512)
        {
            return false;
        }
        let Some(bvh8) = gas.bvh8.as_ref() else {
            return false;
        };
        if !rays.iter().all(|r| r.validate().is_ok()) {
            return false;
        }
        let prepared: [PreparedRay; PACKET] =
            std::array::from_fn(|l| PreparedRay::of_valid(&rays[l]));
        // One octant (the near and far planes of every axis are the same for all rays), finite
        // inverse directions (the packet's box test takes no NaN rule), and one dominant axis
        // (the triangle test's axis permutation is shared).
        if prepared.iter().any(|p| {
            p.near != prepared[0].near
                || p.tri.k != prepared[0].tri.k
                || !p.inv.iter().all(|x| x.is_finite())
        }) {
            return false;
        }
        for (v, r) in visitors.iter_mut().zip(rays) {
            v.enter_gas(gas, &Path::ROOT, r);
        }
        PACKET_STACK.with(|cell| {
            let mut owned;
            let mut borrowed = cell.try_borrow_mut();
            let stack: &mut Vec<PacketEntry> = match borrowed.as_deref_mut() {
                Ok(s) => s,
                Err(_) => {
                    owned = Vec::new();
                    &mut owned
                }
            };
            if stack.len() < STACK_ENTRIES {
                stack.resize(STACK_ENTRIES, PacketEntry::default());
            }
            // SAFETY: the GAS was given `Isa::Avx2`, `Isa::Avx512` or their quantised kernels only where
            // `Isa::is_available` found AVX2 (and the other features the kernel is compiled
            // with) on this processor (`Gas::kernel_for`).
            unsafe {
                traverse_packet_avx2(
                    &bvh8.nodes,
                    &gas.triangles,
                    &prepared,
                    rays,
                    visitors,
                    stack,
                )
            };
        });
        true
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (gas, rays, visitors);
        false
    }
}

/// The packet kernel over 8-wide nodes, compiled for AVX2.
///
/// # Safety
///
/// The processor must have the features this function is compiled with.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,lzcnt,popcnt")]
unsafe fn traverse_packet_avx2<V: GasVisitor>(
    nodes: &[Bvh8Node],
    triangles: &[Triangle4],
    prepared: &[PreparedRay; PACKET],
    rays: &[Ray],
    visitors: &mut [V],
    stack: &mut [PacketEntry],
) {
    use std::arch::x86_64::*;
    let leaves = TriangleLeaves(triangles);
    let load = |a: &[f32; PACKET]| {
        // SAFETY: `a` is 8 readable floats (unaligned load).
        unsafe { _mm256_loadu_ps(a.as_ptr()) }
    };
    let per_ray = |f: &dyn Fn(usize) -> f32| -> [f32; PACKET] { std::array::from_fn(f) };
    let (near, far) = (prepared[0].near, prepared[0].far);
    // Per ray, over the rays (for a leaf's box).
    let org = [0, 1, 2].map(|a| _mm256_set1_ps(prepared[0].org[a]));
    let inv = [0, 1, 2].map(|a| load(&per_ray(&|l| prepared[l].inv[a])));
    // The packet's interval of inverse directions, per axis (for the nodes' boxes).
    let inv_lo = [0, 1, 2].map(|a| {
        let m = (0..PACKET)
            .map(|l| prepared[l].inv[a])
            .fold(f32::INFINITY, f32::min);
        _mm256_set1_ps(m)
    });
    let inv_hi = [0, 1, 2].map(|a| {
        let m = (0..PACKET)
            .map(|l| prepared[l].inv[a])
            .fold(f32::NEG_INFINITY, f32::max);
        _mm256_set1_ps(m)
    });
    let tmin = per_ray(&|l| rays[l].tmin);
    let tmin_v = load(&tmin);
    // The packet's interval starts at its smallest tmin.
    let packet_tmin_scalar = tmin.iter().copied().fold(f32::INFINITY, f32::min);
    let packet_tmin = _mm256_set1_ps(packet_tmin_scalar);
    let mut tmax = per_ray(&|l| rays[l].tmax);
    let robust = _mm256_set1_ps(ROBUST_FAR);
    let zero = _mm256_setzero_ps();
    // Rays still looking: a ray leaves when its visitor ends its traversal.
    let mut live: u32 = (1 << PACKET) - 1;
    // Per ray, and the packet's (the largest among live rays).
    let bounds_of = |tmax: &[f32; PACKET], live: u32| {
        let per_ray = per_ray(&|l| tmax[l] * TMAX_SLACK);
        let mut packet = f32::NEG_INFINITY;
        let mut m = live;
        while m != 0 {
            let l = m.trailing_zeros() as usize;
            m &= m - 1;
            packet = packet.max(per_ray[l]);
        }
        (load(&per_ray), packet)
    };
    let (mut box_tmax, mut packet_tmax) = bounds_of(&tmax, live);
    let mut sp = 0usize;
    let mut cur = PacketEntry {
        child: 0,
        count: 0,
        dist: packet_tmin_scalar,
        rays: live,
    };
    loop {
        if cur.count == 0 {
            let node = &nodes[cur.child as usize];
            let b = &node.bounds;
            let row = |r: usize| {
                // SAFETY: `Bvh8Node` is `repr(C, align(64))` with `bounds` (rows of `[f32; 8]`)
                // first, so each row is a 32-byte aligned load of 8 floats.
                unsafe { _mm256_load_ps(b[r].as_ptr()) }
            };
            // The fat ray against the eight children.
            let mut tn = packet_tmin;
            let mut tf = _mm256_set1_ps(packet_tmax);
            for a in 0..3 {
                let dn = _mm256_sub_ps(row(near[a]), org[a]);
                let df = _mm256_sub_ps(row(far[a]), org[a]);
                let pos_n = _mm256_cmp_ps::<_CMP_GE_OQ>(dn, zero);
                let pos_f = _mm256_cmp_ps::<_CMP_GE_OQ>(df, zero);
                // Smallest near distance and largest far distance over the packet's rays.
                let n = _mm256_mul_ps(dn, _mm256_blendv_ps(inv_hi[a], inv_lo[a], pos_n));
                let f = _mm256_mul_ps(
                    _mm256_mul_ps(df, _mm256_blendv_ps(inv_lo[a], inv_hi[a], pos_f)),
                    robust,
                );
                tn = _mm256_max_ps(n, tn);
                tf = _mm256_min_ps(f, tf);
            }
            let mut mask = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(tn, tf)) as u32;
            let mut dist = [0.0f32; PACKET];
            // SAFETY: `dist` is 8 writable floats (unaligned store).
            unsafe { _mm256_storeu_ps(dist.as_mut_ptr(), tn) };
            let mut kids = [PacketEntry::default(); PACKET];
            let mut n = 0usize;
            while mask != 0 {
                let c = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                let (child, count) = (node.child[c], node.count[c]);
                let rays = if count == 0 {
                    <Bvh8Scalar as NodeLayout>::prefetch(nodes, child);
                    live
                } else {
                    // A leaf: which rays enter its box, each by the single-ray test.
                    let mut rn = tmin_v;
                    let mut rf = box_tmax;
                    for a in 0..3 {
                        let lo = _mm256_set1_ps(b[near[a]][c]);
                        let hi = _mm256_set1_ps(b[far[a]][c]);
                        let nd = _mm256_mul_ps(_mm256_sub_ps(lo, org[a]), inv[a]);
                        let fd =
                            _mm256_mul_ps(_mm256_mul_ps(_mm256_sub_ps(hi, org[a]), inv[a]), robust);
                        rn = _mm256_max_ps(nd, rn);
                        rf = _mm256_min_ps(fd, rf);
                    }
                    let r = live & _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(rn, rf)) as u32;
                    if r == 0 {
                        continue;
                    }
                    LeafIntersector::<V>::prefetch(&leaves, child);
                    r
                };
                kids[n] = PacketEntry {
                    child,
                    count,
                    dist: dist[c],
                    rays,
                };
                n += 1;
            }
            if n > 0 {
                // Nearest first: sort, push the others farthest first, go on with the nearest.
                let kids = &mut kids[..n];
                for i in 1..n {
                    let e = kids[i];
                    let mut j = i;
                    while j > 0 && kids[j - 1].dist > e.dist {
                        kids[j] = kids[j - 1];
                        j -= 1;
                    }
                    kids[j] = e;
                }
                for e in kids[1..].iter().rev() {
                    stack[sp] = *e;
                    sp += 1;
                }
                cur = kids[0];
                continue;
            }
        } else {
            let shrunk = {
                let leaf = PacketLeaf {
                    triangles,
                    prepared,
                    tmin: &tmin,
                    tmin_v,
                };
                // SAFETY: this function has the features `PacketLeaf::test` is compiled with.
                unsafe {
                    leaf.test(
                        cur.child, cur.count, cur.rays, &mut live, &mut tmax, visitors,
                    )
                }
            };
            if live == 0 {
                return;
            }
            if shrunk {
                (box_tmax, packet_tmax) = bounds_of(&tmax, live);
            }
        }
        // Pop the next entry some live ray may still hit in.
        loop {
            if sp == 0 {
                return;
            }
            sp -= 1;
            cur = stack[sp];
            if cur.dist <= packet_tmax && cur.rays & live != 0 {
                break;
            }
        }
    }
}

/// The constants of a packet's leaf tests.
#[cfg(target_arch = "x86_64")]
struct PacketLeaf<'a> {
    triangles: &'a [Triangle4],
    prepared: &'a [PreparedRay; PACKET],
    tmin: &'a [f32; PACKET],
    tmin_v: std::arch::x86_64::__m256,
}

#[cfg(target_arch = "x86_64")]
impl PacketLeaf<'_> {
    /// Tests the rays of `rays` still `live` against the triangles of the leaf at slots
    /// `start .. start + count`, one triangle against eight rays at a time, and offers each
    /// ray's hits to its visitor in slot order. Each ray's arithmetic is the single-ray
    /// test's ([`oxray_bvh::triangle::WatertightRay::intersect`]), operation for operation;
    /// lanes that test needs in `f64` take it, ray by ray. Returns whether some `tmax` shrank
    /// or a ray stopped.
    ///
    /// # Safety
    ///
    /// The processor must have AVX2.
    #[target_feature(enable = "avx2")]
    unsafe fn test<V: GasVisitor>(
        &self,
        start: u32,
        count: u32,
        rays: u32,
        live: &mut u32,
        tmax: &mut [f32; PACKET],
        visitors: &mut [V],
    ) -> bool {
        use oxray_bvh::triangle::F32_TINY;
        use std::arch::x86_64::*;
        let load = |a: &[f32; PACKET]| {
            // SAFETY: `a` is 8 readable floats (unaligned load).
            unsafe { _mm256_loadu_ps(a.as_ptr()) }
        };
        let p0 = &self.prepared[0].tri;
        let [kx, ky, kz] = p0.k;
        let o = p0.org;
        let shear = |i: usize| load(&std::array::from_fn(|l| self.prepared[l].tri.shear[i]));
        let (sx, sy, sz) = (shear(0), shear(1), shear(2));
        let zero = _mm256_setzero_ps();
        let one = _mm256_set1_ps(1.0);
        let abs_mask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7FFF_FFFF));
        let tiny = _mm256_set1_ps(F32_TINY);
        let inf = _mm256_set1_ps(f32::INFINITY);
        let ok = |x: __m256| {
            let a = _mm256_and_ps(x, abs_mask);
            _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_GE_OQ>(a, tiny),
                _mm256_cmp_ps::<_CMP_LT_OQ>(a, inf),
            )
        };
        let mut tmax_v = load(tmax);
        let mut changed = false;
        let mut rays = rays & *live;
        let end = start as usize + count as usize;
        let mut slot = start as usize;
        while slot < end && rays != 0 {
            let block = &self.triangles[slot / 4];
            for j in 0..(end - slot).min(4) {
                let p = block.get(j);
                // Vertex relative to the (shared) origin: the same for every ray.
                let rel = |k: usize| [p[k][0] - o[0], p[k][1] - o[1], p[k][2] - o[2]];
                let (a, b, c) = (rel(0), rel(1), rel(2));
                let sheared = |v: [f32; 3]| {
                    let vz = _mm256_set1_ps(v[kz]);
                    (
                        _mm256_sub_ps(_mm256_set1_ps(v[kx]), _mm256_mul_ps(sx, vz)),
                        _mm256_sub_ps(_mm256_set1_ps(v[ky]), _mm256_mul_ps(sy, vz)),
                        _mm256_mul_ps(sz, vz),
                    )
                };
                let (ax, ay, az) = sheared(a);
                let (bx, by, bz) = sheared(b);
                let (cx, cy, cz) = sheared(c);
                let u = _mm256_sub_ps(_mm256_mul_ps(cx, by), _mm256_mul_ps(cy, bx));
                let v = _mm256_sub_ps(_mm256_mul_ps(ax, cy), _mm256_mul_ps(ay, cx));
                let w = _mm256_sub_ps(_mm256_mul_ps(bx, ay), _mm256_mul_ps(by, ax));
                let det = _mm256_add_ps(_mm256_add_ps(u, v), w);
                let t_scaled = _mm256_add_ps(
                    _mm256_add_ps(_mm256_mul_ps(u, az), _mm256_mul_ps(v, bz)),
                    _mm256_mul_ps(w, cz),
                );
                let eq0 = |x: __m256| _mm256_cmp_ps::<_CMP_EQ_OQ>(x, zero);
                let zero_edge = _mm256_or_ps(_mm256_or_ps(eq0(u), eq0(v)), eq0(w));
                let fine = _mm256_and_ps(ok(det), ok(t_scaled));
                let suspect = (_mm256_movemask_ps(zero_edge) as u32
                    | !(_mm256_movemask_ps(fine) as u32))
                    & rays;
                let lt0 = |x: __m256| _mm256_cmp_ps::<_CMP_LT_OQ>(x, zero);
                let gt0 = |x: __m256| _mm256_cmp_ps::<_CMP_GT_OQ>(x, zero);
                let any_neg = _mm256_or_ps(_mm256_or_ps(lt0(u), lt0(v)), lt0(w));
                let any_pos = _mm256_or_ps(_mm256_or_ps(gt0(u), gt0(v)), gt0(w));
                let outside = _mm256_movemask_ps(_mm256_and_ps(any_neg, any_pos)) as u32;
                let inv = _mm256_div_ps(one, det);
                // `+ 0.0` turns a -0.0 distance into +0.0, as the single-ray test does.
                let t = _mm256_add_ps(_mm256_mul_ps(t_scaled, inv), zero);
                let in_range = _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_GE_OQ>(t, self.tmin_v),
                    _mm256_cmp_ps::<_CMP_LE_OQ>(t, tmax_v),
                );
                let mut hits = _mm256_movemask_ps(in_range) as u32 & !outside & rays & !suspect;
                if hits == 0 && suspect == 0 {
                    continue;
                }
                let mut ts = [0.0f32; PACKET];
                let mut us = [0.0f32; PACKET];
                let mut vs = [0.0f32; PACKET];
                // SAFETY: 8 writable floats each (unaligned stores).
                unsafe {
                    _mm256_storeu_ps(ts.as_mut_ptr(), t);
                    _mm256_storeu_ps(us.as_mut_ptr(), _mm256_mul_ps(v, inv));
                    _mm256_storeu_ps(vs.as_mut_ptr(), _mm256_mul_ps(w, inv));
                }
                let front = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(det, zero)) as u32;
                let mut resolved = [None; PACKET];
                let mut sm = suspect;
                while sm != 0 {
                    let l = sm.trailing_zeros() as usize;
                    sm &= sm - 1;
                    let h =
                        self.prepared[l]
                            .tri
                            .intersect(&p[0], &p[1], &p[2], self.tmin[l], tmax[l]);
                    if h.is_some() {
                        hits |= 1 << l;
                        resolved[l] = h;
                    }
                }
                while hits != 0 {
                    let l = hits.trailing_zeros() as usize;
                    hits &= hits - 1;
                    let h = resolved[l].unwrap_or(oxray_bvh::triangle::TriangleHit {
                        t: ts[l],
                        u: us[l],
                        v: vs[l],
                        front_face: front & (1 << l) != 0,
                    });
                    match visitors[l].triangle((slot + j) as u32, &h) {
                        Decision::Ignore => {}
                        Decision::Accept => {
                            tmax[l] = h.t;
                            changed = true;
                        }
                        Decision::AcceptAndTerminate => {
                            tmax[l] = h.t;
                            rays &= !(1 << l);
                            *live &= !(1 << l);
                            changed = true;
                        }
                        Decision::Abort => {
                            rays &= !(1 << l);
                            *live &= !(1 << l);
                            changed = true;
                        }
                    }
                }
                tmax_v = load(tmax);
                if rays == 0 {
                    break;
                }
            }
            slot += 4;
        }
        changed
    }
}
