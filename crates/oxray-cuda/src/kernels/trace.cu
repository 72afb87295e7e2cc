// oxray CUDA trace kernels: closest hit and occlusion of a batch of rays against a triangle GAS,
// or against one level of instances over triangle GASes.
//
// Every floating-point operation below is the one the CPU backend performs, in the same order,
// and the module is compiled with --fmad=false (no contraction into FMA), --ftz=false and IEEE
// division, so box tests, triangle tests and hit distances are bit-identical to the CPU's.
//
// Constants come from the host as -D definitions (bit patterns of f32):
//   OXRAY_ROBUST_FAR_BITS, OXRAY_TMAX_SLACK_BITS, OXRAY_F32_TINY_BITS, OXRAY_STACK_SIZE.

#define OXRAY_TRACE_CU 1

typedef unsigned int u32;

#define ROBUST_FAR __int_as_float(OXRAY_ROBUST_FAR_BITS)
#define TMAX_SLACK __int_as_float(OXRAY_TMAX_SLACK_BITS)
#define F32_TINY __int_as_float(OXRAY_F32_TINY_BITS)
#define F32_INF __int_as_float(0x7f800000)
#define MISS_SLOT 0xffffffffu
#define BACK_FACE_BIT 0x80000000u

// ---------------------------------------------------------------------------------------------
// Rays
// ---------------------------------------------------------------------------------------------

__device__ __forceinline__ float comp(const float3& v, int k) {
    return k == 0 ? v.x : (k == 1 ? v.y : v.z);
}

struct TraceRay {
    float3 org;
    float tmin;
    float3 dir;
    float tmax;
    // Box test: 1/d (+inf for a zero component) and whether each axis enters at its upper plane.
    float3 inv;
    bool neg_x, neg_y, neg_z;
    // Watertight triangle test: axis permutation (kz dominant) and shear.
    int kx, ky, kz;
    float sx, sy, sz;
};

__device__ __forceinline__ bool finite3(float3 v) {
    return isfinite(v.x) && isfinite(v.y) && isfinite(v.z);
}

// Ray::validate: a finite origin and direction, a non-zero direction, 0 <= tmin <= tmax, no NaN.
__device__ __forceinline__ bool ray_valid(const TraceRay& r) {
    if (!finite3(r.org) || !finite3(r.dir)) return false;
    if (r.dir.x == 0.0f && r.dir.y == 0.0f && r.dir.z == 0.0f) return false;
    if (isnan(r.tmin) || isnan(r.tmax)) return false;
    if (r.tmin < 0.0f) return false;
    if (r.tmin > r.tmax) return false;
    return true;
}

__device__ __forceinline__ float safe_inv(float d) {
    return d == 0.0f ? F32_INF : 1.0f / d;
}

// PreparedRay::new: validates the ray (org, dir, tmin, tmax set) and computes the per-ray
// constants of the box and triangle tests. False for an invalid ray, which hits nothing.
__device__ __forceinline__ bool prepare_ray(TraceRay& r) {
    if (!ray_valid(r)) return false;
    r.inv = make_float3(safe_inv(r.dir.x), safe_inv(r.dir.y), safe_inv(r.dir.z));
    r.neg_x = !(r.inv.x >= 0.0f);
    r.neg_y = !(r.inv.y >= 0.0f);
    r.neg_z = !(r.inv.z >= 0.0f);
    float ax = fabsf(r.dir.x), ay = fabsf(r.dir.y), az = fabsf(r.dir.z);
    int kz = (ax >= ay && ax >= az) ? 0 : (ay >= az ? 1 : 2);
    int kx = (kz + 1) % 3;
    int ky = (kx + 1) % 3;
    // Swapping keeps the winding of the projected triangle independent of the ray's sign.
    if (comp(r.dir, kz) < 0.0f) {
        int t = kx;
        kx = ky;
        ky = t;
    }
    float dz = comp(r.dir, kz);
    r.kx = kx;
    r.ky = ky;
    r.kz = kz;
    r.sx = comp(r.dir, kx) / dz;
    r.sy = comp(r.dir, ky) / dz;
    r.sz = 1.0f / dz;
    return true;
}

__device__ __forceinline__ bool load_ray(const float4* __restrict__ rays, u32 i, TraceRay& r) {
    float4 a = rays[2 * i];
    float4 b = rays[2 * i + 1];
    r.org = make_float3(a.x, a.y, a.z);
    r.tmin = a.w;
    r.dir = make_float3(b.x, b.y, b.z);
    r.tmax = b.w;
    return prepare_ray(r);
}

// ---------------------------------------------------------------------------------------------
// Watertight ray/triangle test (Woop, Benthin, Wald 2013), as the CPU backend computes it
// ---------------------------------------------------------------------------------------------

struct TriHit {
    float t, u, v;
    bool front;
};

__device__ __forceinline__ bool ok_mag(float x) {
    float a = fabsf(x);
    return a >= F32_TINY && a < F32_INF;
}

// What the exact fallback returns: the hit in `h` where `hit` is set. Returned by value (in
// registers), so that callers need no generic pointer to a local variable, which the pipeline's
// walks would keep in two registers for its whole loop.
struct TriHitF64 {
    TriHit h;
    bool hit;
};

// The exact fallback for edge functions of zero and for under- or overflow.
__device__ __noinline__ TriHitF64 intersect_f64(float ax_, float ay_, float az_, float bx_,
                                                float by_, float bz_, float cx_, float cy_,
                                                float cz_, float tmin, float tmax) {
    TriHitF64 out = {};  // no hit
    double ax = ax_, ay = ay_, az = az_;
    double bx = bx_, by = by_, bz = bz_;
    double cx = cx_, cy = cy_, cz = cz_;
    double u = cx * by - cy * bx;
    double v = ax * cy - ay * cx;
    double w = bx * ay - by * ax;
    if ((u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0)) return out;
    double det = u + v + w;
    if (det == 0.0 || !isfinite(det)) return out;
    double t_scaled = u * az + v * bz + w * cz;
    double inv = 1.0 / det;
    float t = (float)(t_scaled * inv) + 0.0f;
    if (!(t >= tmin && t <= tmax)) return out;
    out.h.t = t;
    out.h.u = (float)(v * inv);
    out.h.v = (float)(w * inv);
    out.h.front = det > 0.0;
    out.hit = true;
    return out;
}

// Whether `1.0f / x` takes the fast sequence of the IEEE division (`rcp_fast`): the exponent
// range in which that sequence is exact, as the compiler's division tests it. Outside it, the
// division calls a slow path.
__device__ __forceinline__ bool rcp_fast_range(float x) {
    return ((__float_as_uint(x) + 0x01800000u) & 0x7f800000u) > 0x01ffffffu;
}

// `1.0f / x` for `x` where `rcp_fast_range(x)`: the fast sequence of the compiler's IEEE
// division, instruction for instruction (an approximate reciprocal, refined once with the
// residual flushed to zero when subnormal), so the same bits. Written out so that the walks
// hold no call to the division's slow path, which at its call site keeps every live value in a
// register (docs/BENCHMARKS.md, "The pipeline, tenth round").
__device__ __forceinline__ float rcp_fast(float x) {
    float r;
    asm("{\n\t"
        ".reg .f32 a, e;\n\t"
        "rcp.approx.ftz.f32 a, %1;\n\t"
        "fma.rn.f32 e, a, %1, 0fBF800000;\n\t"
        "neg.ftz.f32 e, e;\n\t"
        "fma.rn.f32 %0, a, e, a;\n\t"
        "}"
        : "=f"(r)
        : "f"(x));
    return r;
}

// The cases of the triangle test that are rare, in one call out of the walk's way: the exact
// fallback (edge functions of zero, under- or overflow) and a determinant whose reciprocal
// needs the division's slow path. Computes what `intersect_triangle` computes, in the same
// order (fused multiply-adds are off), so its hits are the same bits.
__device__ __noinline__ TriHitF64 intersect_rare(float ax, float ay, float az, float bx,
                                                 float by, float bz, float cx, float cy,
                                                 float cz, float tmin, float tmax) {
    float u = cx * by - cy * bx;
    float v = ax * cy - ay * cx;
    float w = bx * ay - by * ax;
    float det = u + v + w;
    float t_scaled = u * az + v * bz + w * cz;
    TriHitF64 out = {};  // no hit
    if (u == 0.0f || v == 0.0f || w == 0.0f || !ok_mag(det) || !ok_mag(t_scaled)) {
        return intersect_f64(ax, ay, az, bx, by, bz, cx, cy, cz, tmin, tmax);
    }
    if ((u < 0.0f || v < 0.0f || w < 0.0f) && (u > 0.0f || v > 0.0f || w > 0.0f)) return out;
    float inv = 1.0f / det;
    float t = t_scaled * inv + 0.0f;
    if (!(t >= tmin && t <= tmax)) return out;
    out.h.t = t;
    out.h.u = v * inv;
    out.h.v = w * inv;
    out.h.front = det > 0.0f;
    out.hit = true;
    return out;
}

#ifndef OXRAY_TRIANGLE_RARE_CALL
#define OXRAY_TRIANGLE_RARE_CALL 0
#endif
__device__ __forceinline__ bool intersect_triangle(const TraceRay& r, float3 p0, float3 p1,
                                                   float3 p2, float tmin, float tmax, TriHit& h) {
    float3 a = make_float3(p0.x - r.org.x, p0.y - r.org.y, p0.z - r.org.z);
    float3 b = make_float3(p1.x - r.org.x, p1.y - r.org.y, p1.z - r.org.z);
    float3 c = make_float3(p2.x - r.org.x, p2.y - r.org.y, p2.z - r.org.z);
    float akz = comp(a, r.kz), bkz = comp(b, r.kz), ckz = comp(c, r.kz);
    float ax = comp(a, r.kx) - r.sx * akz;
    float ay = comp(a, r.ky) - r.sy * akz;
    float bx = comp(b, r.kx) - r.sx * bkz;
    float by = comp(b, r.ky) - r.sy * bkz;
    float cx = comp(c, r.kx) - r.sx * ckz;
    float cy = comp(c, r.ky) - r.sy * ckz;

    float u = cx * by - cy * bx;
    float v = ax * cy - ay * cx;
    float w = bx * ay - by * ax;

    float az = r.sz * akz;
    float bz = r.sz * bkz;
    float cz = r.sz * ckz;

    float det = u + v + w;
    float t_scaled = u * az + v * bz + w * cz;
#if OXRAY_TRIANGLE_RARE_CALL
    if (u == 0.0f || v == 0.0f || w == 0.0f || !ok_mag(det) || !ok_mag(t_scaled) ||
        !rcp_fast_range(det)) {
        const TriHitF64 rare = intersect_rare(ax, ay, az, bx, by, bz, cx, cy, cz, tmin, tmax);
        if (rare.hit) h = rare.h;
        return rare.hit;
    }
    if ((u < 0.0f || v < 0.0f || w < 0.0f) && (u > 0.0f || v > 0.0f || w > 0.0f)) return false;
    float inv = rcp_fast(det);
#else
    if (u == 0.0f || v == 0.0f || w == 0.0f || !ok_mag(det) || !ok_mag(t_scaled)) {
        const TriHitF64 exact = intersect_f64(ax, ay, az, bx, by, bz, cx, cy, cz, tmin, tmax);
        if (exact.hit) h = exact.h;
        return exact.hit;
    }
    if ((u < 0.0f || v < 0.0f || w < 0.0f) && (u > 0.0f || v > 0.0f || w > 0.0f)) return false;
    float inv = 1.0f / det;
#endif
    // `+ 0.0f` turns a -0.0 distance into +0.0.
    float t = t_scaled * inv + 0.0f;
    if (!(t >= tmin && t <= tmax)) return false;
    h.t = t;
    h.u = v * inv;
    h.v = w * inv;
    h.front = det > 0.0f;
    return true;
}

// ---------------------------------------------------------------------------------------------
// Box test: the CPU's conservative slab test with NaN-ignoring min/max
// ---------------------------------------------------------------------------------------------

// max(acc, x) keeping acc when x is NaN; min likewise.
__device__ __forceinline__ float max_keep(float x, float acc) { return x > acc ? x : acc; }
__device__ __forceinline__ float min_keep(float x, float acc) { return x < acc ? x : acc; }

// One box given by its near and far planes per axis (already chosen by the ray's signs).
__device__ __forceinline__ bool slab(const TraceRay& r, float nx, float ny, float nz, float fx,
                                     float fy, float fz, float tmin, float box_tmax, float& dist) {
    float tn = tmin;
    float tf = box_tmax;
    tn = max_keep((nx - r.org.x) * r.inv.x, tn);
    tf = min_keep(((fx - r.org.x) * r.inv.x) * ROBUST_FAR, tf);
    tn = max_keep((ny - r.org.y) * r.inv.y, tn);
    tf = min_keep(((fy - r.org.y) * r.inv.y) * ROBUST_FAR, tf);
    tn = max_keep((nz - r.org.z) * r.inv.z, tn);
    tf = min_keep(((fz - r.org.z) * r.inv.z) * ROBUST_FAR, tf);
    dist = tn;
    return tn <= tf;
}

__device__ __forceinline__ float lane(const float4& v, int l) {
    return l == 0 ? v.x : (l == 1 ? v.y : (l == 2 ? v.z : v.w));
}
__device__ __forceinline__ u32 lane(const uint4& v, int l) {
    return l == 0 ? v.x : (l == 1 ? v.y : (l == 2 ? v.z : v.w));
}

// ---------------------------------------------------------------------------------------------
// Traversal
// ---------------------------------------------------------------------------------------------

struct Entry {
    u32 child;
    u32 count;
    float dist;
};

// An entry being sorted, with the lane it came from (ties in distance go in lane order).
struct SortEntry {
    Entry e;
    int lane;
};

// Whether x goes before (deeper in the stack than) y: farther first, ties in lane order.
__device__ __forceinline__ bool goes_before(const SortEntry& x, const SortEntry& y) {
    return x.e.dist > y.e.dist || (x.e.dist == y.e.dist && x.lane < y.lane);
}

__device__ __forceinline__ void sort2(SortEntry& x, SortEntry& y) {
    if (goes_before(y, x)) {
        SortEntry t = x;
        x = y;
        y = t;
    }
}

struct Best {
    float t, u, v;
    u32 slot;  // MISS_SLOT for none; BACK_FACE_BIT set for a back-face hit
};

// Intersects the triangles of leaf slots [start, start + count). Returns true when an any-hit
// query may stop.
// Nodes and triangles are read-only while rays are traced: loaded through the read-only data
// cache, which the compiler picks by itself only for a kernel's own `const __restrict__`
// parameters (the query kernels), not for addresses a pipeline reads from its traversables.
// `-DOXRAY_READONLY_LOADS=0` turns it off, for comparison.
#ifndef OXRAY_READONLY_LOADS
#define OXRAY_READONLY_LOADS 1
#endif
template <typename T>
__device__ __forceinline__ T load_ro(const T* p) {
#if OXRAY_READONLY_LOADS
    return __ldg(p);
#else
    return *p;
#endif
}

template <bool ANY>
__device__ __forceinline__ bool leaf(const TraceRay& r, const float4* __restrict__ tris, u32 start,
                                     u32 count, float tmin, float& tmax, float& box_tmax,
                                     Best& best) {
    for (u32 s = start; s < start + count; ++s) {
        float4 q0 = load_ro(tris + 3 * s);
        float4 q1 = load_ro(tris + 3 * s + 1);
        float4 q2 = load_ro(tris + 3 * s + 2);
        TriHit h;
        if (intersect_triangle(r, make_float3(q0.x, q0.y, q0.z), make_float3(q1.x, q1.y, q1.z),
                               make_float3(q2.x, q2.y, q2.z), tmin, tmax, h)) {
            best.t = h.t;
            best.u = h.u;
            best.v = h.v;
            best.slot = s | (h.front ? 0u : BACK_FACE_BIT);
            if (ANY) return true;
            tmax = h.t;
            box_tmax = tmax * TMAX_SLACK;
        }
    }
    return false;
}

// The 4-wide BVH of the CPU backend, node for node (Bvh4Node: 128 bytes, rows of four lanes:
// lower x, y, z, upper x, y, z, then child indices, then leaf counts), walked exactly as the CPU
// kernel walks it: nearest child first, farther children on the stack sorted farthest first.
template <bool ANY>
__device__ __forceinline__ Best trace_bvh4(const TraceRay& r, const float4* __restrict__ nodes,
                                           const float4* __restrict__ tris) {
    Best best;
    best.t = F32_INF;
    best.u = 0.0f;
    best.v = 0.0f;
    best.slot = MISS_SLOT;
    float tmin = r.tmin;
    float tmax = r.tmax;
    float box_tmax = tmax * TMAX_SLACK;
    Entry stack[OXRAY_STACK_SIZE];
    int sp = 0;
    Entry cur;
    cur.child = 0;
    cur.count = 0;
    cur.dist = tmin;
    const int nx = r.neg_x ? 3 : 0, fx = r.neg_x ? 0 : 3;
    const int ny = r.neg_y ? 4 : 1, fy = r.neg_y ? 1 : 4;
    const int nz = r.neg_z ? 5 : 2, fz = r.neg_z ? 2 : 5;
    for (;;) {
        if (cur.count == 0) {
            const float4* n = nodes + 8 * (size_t)cur.child;
            float4 bnx = n[nx], bny = n[ny], bnz = n[nz];
            float4 bfx = n[fx], bfy = n[fy], bfz = n[fz];
            uint4 child = reinterpret_cast<const uint4*>(n)[6];
            uint4 count = reinterpret_cast<const uint4*>(n)[7];
            float dist[4];
            u32 mask = 0;
#pragma unroll
            for (int l = 0; l < 4; ++l) {
                float d;
                bool hit = slab(r, lane(bnx, l), lane(bny, l), lane(bnz, l), lane(bfx, l),
                                lane(bfy, l), lane(bfz, l), tmin, box_tmax, d);
                dist[l] = d;
                mask |= (hit ? 1u : 0u) << l;
            }
            if (mask != 0) {
                int la = __ffs(mask) - 1;
                mask &= mask - 1;
                Entry a;
                a.child = lane(child, la);
                a.count = lane(count, la);
                a.dist = la == 0 ? dist[0] : (la == 1 ? dist[1] : (la == 2 ? dist[2] : dist[3]));
                if (mask == 0) {
                    cur = a;
                    continue;
                }
                int lb = __ffs(mask) - 1;
                mask &= mask - 1;
                Entry b;
                b.child = lane(child, lb);
                b.count = lane(count, lb);
                b.dist = lb == 0 ? dist[0] : (lb == 1 ? dist[1] : (lb == 2 ? dist[2] : dist[3]));
                if (mask == 0) {
                    if (b.dist < a.dist) {
                        stack[sp++] = a;
                        cur = b;
                    } else {
                        stack[sp++] = b;
                        cur = a;
                    }
                    continue;
                }
                // Three or four children: sort them in registers, farthest first, with ties in
                // lane order (the order of the CPU kernel's stable insertion sort), push all but
                // the nearest and continue with it. A missing fourth entry is a sentinel that
                // sorts first and is not pushed.
                int lc = __ffs(mask) - 1;
                mask &= mask - 1;
                SortEntry s0, s1, s2, s3;
                s0.e = a;
                s0.lane = la;
                s1.e = b;
                s1.lane = lb;
                s2.e.child = lane(child, lc);
                s2.e.count = lane(count, lc);
                s2.e.dist = lc == 0 ? dist[0] : (lc == 1 ? dist[1] : (lc == 2 ? dist[2] : dist[3]));
                s2.lane = lc;
                bool four = mask != 0;
                if (four) {
                    int ld = __ffs(mask) - 1;
                    s3.e.child = lane(child, ld);
                    s3.e.count = lane(count, ld);
                    s3.e.dist = dist[3];
                    s3.lane = ld;
                } else {
                    s3.e.child = 0;
                    s3.e.count = 0;
                    s3.e.dist = F32_INF;
                    s3.lane = -1;
                }
                // A sorting network for four; keys (dist, lane) are distinct, so the result is
                // the one order the insertion sort gives.
                sort2(s0, s1);
                sort2(s2, s3);
                sort2(s0, s2);
                sort2(s1, s3);
                sort2(s1, s2);
                if (four) stack[sp++] = s0.e;
                stack[sp++] = s1.e;
                stack[sp++] = s2.e;
                cur = s3.e;
                continue;
            }
        } else {
            if (leaf<ANY>(r, tris, cur.child, cur.count, tmin, tmax, box_tmax, best)) return best;
        }
        // Pop the next entry that may still hold a hit.
        for (;;) {
            if (sp == 0) return best;
            cur = stack[--sp];
            if (cur.dist <= box_tmax) break;
        }
    }
}

// The address of a binary walk's nodes: `nodes` itself, or for another type (a pipeline's
// traversable, whose walk reloads the address rather than hold it in registers) its own
// `node_base`, found where the walk is instantiated.
__device__ __forceinline__ const float4* node_base(const float4* nodes) { return nodes; }

// A binary BVH of 64-byte nodes (Aila and Laine's layout): rows (c0.lo.x, c0.hi.x, c0.lo.y,
// c0.hi.y), (c1.lo.x, c1.hi.x, c1.lo.y, c1.hi.y), (c0.lo.z, c0.hi.z, c1.lo.z, c1.hi.z) and
// (child0, child1, count0, count1), with the CPU's box and triangle tests.
//
// Walked nearest child first; the slot range of every leaf the ray enters goes to
// `leaf(start, count, tmax)`, which may shrink `tmax` and returns true to end the walk. Both the
// triangles of a GAS and the instances of an IAS are leaves of this one walk. The stack holds at
// most one entry per level of the tree; pipelines, whose walks nest, size it to the deepest
// binary tree the builder makes (`STACK`), the query kernels keep the BVH4 bound. `nodes` goes
// through `node_base` at each step.
template <int STACK = OXRAY_STACK_SIZE, typename Nodes, typename Leaf>
__device__ __forceinline__ void walk_bvh2(const TraceRay& r, Nodes nodes, float tmin, float tmax,
                                          Leaf&& leaf) {
    // The boxes' bound is `tmax * TMAX_SLACK`, computed where it is used rather than kept: one
    // multiplication a node costs less than the register it would hold, which in the
    // pipeline's 56-register walk pushed `tmax` out to local memory, reloaded at every leaf
    // and pop (docs/BENCHMARKS.md, "The pipeline, eighth round"); the bound is the same bits.
    Entry stack[STACK];
    int sp = 0;
    Entry cur;
    cur.child = 0;
    cur.count = 0;
    cur.dist = tmin;
    for (;;) {
        if (cur.count == 0) {
            const float4* n = node_base(nodes) + 4 * (size_t)cur.child;
            float4 n0 = load_ro(n), n1 = load_ro(n + 1), n2 = load_ro(n + 2);
            uint4 links = load_ro(reinterpret_cast<const uint4*>(n) + 3);
            float d0, d1;
            bool h0 = slab(r, r.neg_x ? n0.y : n0.x, r.neg_y ? n0.w : n0.z, r.neg_z ? n2.y : n2.x,
                           r.neg_x ? n0.x : n0.y, r.neg_y ? n0.z : n0.w, r.neg_z ? n2.x : n2.y,
                           tmin, tmax * TMAX_SLACK, d0);
            bool h1 = slab(r, r.neg_x ? n1.y : n1.x, r.neg_y ? n1.w : n1.z, r.neg_z ? n2.w : n2.z,
                           r.neg_x ? n1.x : n1.y, r.neg_y ? n1.z : n1.w, r.neg_z ? n2.z : n2.w,
                           tmin, tmax * TMAX_SLACK, d1);
            Entry a, b;
            a.child = links.x;
            a.count = links.z;
            a.dist = d0;
            b.child = links.y;
            b.count = links.w;
            b.dist = d1;
            if (h0 && h1) {
                if (b.dist < a.dist) {
                    stack[sp++] = a;
                    cur = b;
                } else {
                    stack[sp++] = b;
                    cur = a;
                }
                continue;
            }
            if (h0) {
                cur = a;
                continue;
            }
            if (h1) {
                cur = b;
                continue;
            }
        } else {
            if (leaf(cur.child, cur.count, tmax)) return;
        }
        for (;;) {
            if (sp == 0) return;
            cur = stack[--sp];
            if (cur.dist <= tmax * TMAX_SLACK) break;
        }
    }
}

template <bool ANY>
__device__ __forceinline__ Best trace_bvh2(const TraceRay& r, const float4* __restrict__ nodes,
                                           const float4* __restrict__ tris) {
    Best best;
    best.t = F32_INF;
    best.u = 0.0f;
    best.v = 0.0f;
    best.slot = MISS_SLOT;
    walk_bvh2(r, nodes, r.tmin, r.tmax, [&](u32 start, u32 count, float& tmax) {
        float box_tmax;  // the walk keeps its own
        return leaf<ANY>(r, tris, start, count, r.tmin, tmax, box_tmax, best);
    });
    return best;
}

// ---------------------------------------------------------------------------------------------
// One level of instances over GASes: an IAS whose top-level tree is a binary BVH (the layout
// above) whose leaves are instance slots. Each slot is six float4: the world-to-object rows
// (3), the world box's lower and upper corners (.w: the child's index, for the host), and the
// child GAS's binary nodes and triangles as two 64-bit device addresses (0: no child). Walked
// as the CPU walks an IAS: the instance box test, the ray carried into object space with the
// interval as it has shrunk, the child traversed, the interval shrunk to an accepted hit.
// ---------------------------------------------------------------------------------------------

// PreparedRay::hits_box: the scalar test of one instance's world box.
__device__ __forceinline__ bool hits_box(const TraceRay& r, float4 lo, float4 hi, float tmin,
                                         float tmax) {
    float t0 = tmin;
    float t1 = F32_INF;
    float nx = r.neg_x ? hi.x : lo.x, fx = r.neg_x ? lo.x : hi.x;
    float ny = r.neg_y ? hi.y : lo.y, fy = r.neg_y ? lo.y : hi.y;
    float nz = r.neg_z ? hi.z : lo.z, fz = r.neg_z ? lo.z : hi.z;
    t0 = max_keep((nx - r.org.x) * r.inv.x, t0);
    t1 = min_keep((fx - r.org.x) * r.inv.x, t1);
    t0 = max_keep((ny - r.org.y) * r.inv.y, t0);
    t1 = min_keep((fy - r.org.y) * r.inv.y, t1);
    t0 = max_keep((nz - r.org.z) * r.inv.z, t0);
    t1 = min_keep((fz - r.org.z) * r.inv.z, t1);
    return t0 <= min_keep(t1 * ROBUST_FAR, tmax * TMAX_SLACK);
}

// Transform::transform_point of the rows m0, m1, m2 (3x4), in the CPU's order.
__device__ __forceinline__ float3 __oxray_point(float4 m0, float4 m1, float4 m2, float3 p) {
    return make_float3(m0.x * p.x + m0.y * p.y + m0.z * p.z + m0.w,
                       m1.x * p.x + m1.y * p.y + m1.z * p.z + m1.w,
                       m2.x * p.x + m2.y * p.y + m2.z * p.z + m2.w);
}

// Carries `r` into the instance whose slot is `inst` (the layout above) with the interval
// [tmin, tmax]: false where the ray misses the instance's world box, the instance has no child
// or the carried ray is invalid; else the object-space ray `o` and the child's nodes and
// triangles.
__device__ __forceinline__ bool __oxray_enter_instance(const TraceRay& r,
                                                       const float4* __restrict__ inst,
                                                       float tmin, float tmax, TraceRay& o,
                                                       const float4*& nodes,
                                                       const float4*& tris) {
    if (!hits_box(r, inst[3], inst[4], tmin, tmax)) return false;
    uint4 ptrs = reinterpret_cast<const uint4*>(inst)[5];
    nodes = reinterpret_cast<const float4*>(((unsigned long long)ptrs.y << 32) |
                                            (unsigned long long)ptrs.x);
    tris = reinterpret_cast<const float4*>(((unsigned long long)ptrs.w << 32) |
                                           (unsigned long long)ptrs.z);
    if (nodes == nullptr) return false;
    float4 m0 = inst[0], m1 = inst[1], m2 = inst[2];
    // Transform::transform_point and transform_vector, in the CPU's order.
    o.org = __oxray_point(m0, m1, m2, r.org);
    o.dir = make_float3(m0.x * r.dir.x + m0.y * r.dir.y + m0.z * r.dir.z,
                        m1.x * r.dir.x + m1.y * r.dir.y + m1.z * r.dir.z,
                        m2.x * r.dir.x + m2.y * r.dir.y + m2.z * r.dir.z);
    o.tmin = tmin;
    o.tmax = tmax;
    return prepare_ray(o);
}

struct IasBest {
    Best hit;
    u32 inst;  // instance slot of the hit; MISS_SLOT for none
};

template <bool ANY>
__device__ __forceinline__ IasBest trace_ias(const TraceRay& r, const float4* __restrict__ top,
                                             const float4* __restrict__ insts) {
    IasBest best;
    best.hit.t = F32_INF;
    best.hit.u = 0.0f;
    best.hit.v = 0.0f;
    best.hit.slot = MISS_SLOT;
    best.inst = MISS_SLOT;
    const float tmin = r.tmin;
    walk_bvh2(r, top, tmin, r.tmax, [&](u32 start, u32 count, float& tmax) {
        for (u32 s = start; s < start + count; ++s) {
            TraceRay o;
            const float4 *nodes, *tris;
            if (!__oxray_enter_instance(r, insts + 6 * (size_t)s, tmin, tmax, o, nodes, tris)) {
                continue;
            }
            Best h = trace_bvh2<ANY>(o, nodes, tris);
            if (h.slot != MISS_SLOT) {
                // A hit at the current tmax replaces the one found before, as on the CPU.
                best.hit = h;
                best.inst = s;
                if (ANY) return true;
                tmax = h.t;
            }
        }
        return false;
    });
    return best;
}

// ---------------------------------------------------------------------------------------------
// Built-in spheres (guide §5.3, §9.4, §9.6): oxray_bvh::Sphere::entry, operation for operation
// (the kernels are compiled without FMA contraction, so both devices find the same t). A slot is
// one float4: the centre and the radius (NaN for an inactive slot, which no ray hits).
// ---------------------------------------------------------------------------------------------

// The smaller root of |o + t d - c|^2 = r^2 (Haines et al., Ray Tracing Gems ch. 7: the
// discriminant from the centre's distance to the ray's line, the stable roots), NaN for a miss.
__device__ __forceinline__ float sphere_entry(float3 o, float3 d, float4 s) {
    const float fx = o.x - s.x, fy = o.y - s.y, fz = o.z - s.z;
    const float r = s.w;
    const float a = d.x * d.x + d.y * d.y + d.z * d.z;
    const float b = -(fx * d.x + fy * d.y + fz * d.z);
    const float k = b / a;
    const float px = fx + d.x * k, py = fy + d.y * k, pz = fz + d.z * k;
    const float p = sqrtf(px * px + py * py + pz * pz);
    const float disc = a * ((r - p) * (r + p));
    if (isnan(disc) || disc < 0.0f) return __int_as_float(0x7fc00000);
    const float cc = (fx * fx + fy * fy + fz * fz) - r * r;
    const float q = b + copysignf(sqrtf(disc), b);
    return fminf(cc / q, q / a);
}

// The front-face hit of a sphere in [tmin, tmax] (spheres are hollow, back faces culled: a ray
// whose interval starts inside one does not hit it).
__device__ __forceinline__ bool intersect_sphere(const TraceRay& r, float4 s, float tmin,
                                                 float tmax, float& t) {
    t = sphere_entry(r.org, r.dir, s);
    return t >= tmin && t <= tmax;
}

// A kind of built-in primitive for the query kernels: `Leaf::hit(r, prims, s, tmax, best)`
// tests leaf slot `s` of `prims` in [r.tmin, tmax] and writes a hit to `best`. SphereLeaf here;
// CurveLeaf in curve.cu, after the curve intersector.
struct SphereLeaf {
    static __device__ __forceinline__ bool hit(const TraceRay& r,
                                               const float4* __restrict__ spheres, u32 s,
                                               float tmax, Best& best) {
        float t;
        if (!intersect_sphere(r, load_ro(spheres + s), r.tmin, tmax, t)) return false;
        best.t = t;
        best.slot = s;
        return true;
    }
};

// The closest hit (or, with ANY, any hit) of `r` in a GAS of built-in primitives of kind `Leaf`:
// the binary BVH `nodes` over the leaf slots `prims`.
template <bool ANY, typename Leaf>
__device__ __forceinline__ Best trace_builtin(const TraceRay& r, const float4* __restrict__ nodes,
                                              const float4* __restrict__ prims) {
    Best best;
    best.t = F32_INF;
    best.u = 0.0f;
    best.v = 0.0f;
    best.slot = MISS_SLOT;
    walk_bvh2(r, nodes, r.tmin, r.tmax, [&](u32 start, u32 count, float& tmax) {
        for (u32 s = start; s < start + count; ++s) {
            if (!Leaf::hit(r, prims, s, tmax, best)) continue;
            if (ANY) return true;
            tmax = best.t;
        }
        return false;
    });
    return best;
}

// A pipeline (oxray_device.h) compiles this file for its traversal, without the query kernels.
#ifndef OXRAY_NO_QUERY_KERNELS

// ---------------------------------------------------------------------------------------------
// Entry points. Rays are eight f32 (ox, oy, oz, tmin, dx, dy, dz, tmax); a closest-hit record is
// (t, slot | back-face bit, u, v) with t = +inf and slot = 0xffffffff for a miss; an occlusion
// result is one byte, 1 for occluded. An invalid ray hits nothing.
// ---------------------------------------------------------------------------------------------

__device__ __forceinline__ void store_hit(uint4* __restrict__ hits, u32 i, const Best& b) {
    hits[i] = make_uint4(__float_as_uint(b.t), b.slot, __float_as_uint(b.u),
                         __float_as_uint(b.v));
}

extern "C" __global__ void __launch_bounds__(128)
    oxray_closest_bvh4(const float4* __restrict__ nodes, const float4* __restrict__ tris,
                       const float4* __restrict__ rays, uint4* __restrict__ hits, u32 n) {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    TraceRay r;
    Best b;
    if (load_ray(rays, i, r)) {
        b = trace_bvh4<false>(r, nodes, tris);
    } else {
        b.t = F32_INF;
        b.u = b.v = 0.0f;
        b.slot = MISS_SLOT;
    }
    store_hit(hits, i, b);
}

extern "C" __global__ void __launch_bounds__(128)
    oxray_occluded_bvh4(const float4* __restrict__ nodes, const float4* __restrict__ tris,
                        const float4* __restrict__ rays, unsigned char* __restrict__ occluded,
                        u32 n) {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    TraceRay r;
    bool hit = false;
    if (load_ray(rays, i, r)) hit = trace_bvh4<true>(r, nodes, tris).slot != MISS_SLOT;
    occluded[i] = hit ? 1 : 0;
}

extern "C" __global__ void __launch_bounds__(128)
    oxray_closest_bvh2(const float4* __restrict__ nodes, const float4* __restrict__ tris,
                       const float4* __restrict__ rays, uint4* __restrict__ hits, u32 n) {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    TraceRay r;
    Best b;
    if (load_ray(rays, i, r)) {
        b = trace_bvh2<false>(r, nodes, tris);
    } else {
        b.t = F32_INF;
        b.u = b.v = 0.0f;
        b.slot = MISS_SLOT;
    }
    store_hit(hits, i, b);
}

extern "C" __global__ void __launch_bounds__(128)
    oxray_occluded_bvh2(const float4* __restrict__ nodes, const float4* __restrict__ tris,
                        const float4* __restrict__ rays, unsigned char* __restrict__ occluded,
                        u32 n) {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    TraceRay r;
    bool hit = false;
    if (load_ray(rays, i, r)) hit = trace_bvh2<true>(r, nodes, tris).slot != MISS_SLOT;
    occluded[i] = hit ? 1 : 0;
}

extern "C" __global__ void __launch_bounds__(128)
    oxray_closest_ias(const float4* __restrict__ top, const float4* __restrict__ insts,
                      const float4* __restrict__ rays, uint4* __restrict__ hits,
                      u32* __restrict__ inst_out, u32 n) {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    TraceRay r;
    IasBest b;
    if (load_ray(rays, i, r)) {
        b = trace_ias<false>(r, top, insts);
    } else {
        b.hit.t = F32_INF;
        b.hit.u = b.hit.v = 0.0f;
        b.hit.slot = MISS_SLOT;
        b.inst = MISS_SLOT;
    }
    store_hit(hits, i, b.hit);
    inst_out[i] = b.inst;
}

extern "C" __global__ void __launch_bounds__(128)
    oxray_occluded_ias(const float4* __restrict__ top, const float4* __restrict__ insts,
                       const float4* __restrict__ rays, unsigned char* __restrict__ occluded,
                       u32 n) {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    TraceRay r;
    bool hit = false;
    if (load_ray(rays, i, r)) hit = trace_ias<true>(r, top, insts).inst != MISS_SLOT;
    occluded[i] = hit ? 1 : 0;
}

// The query kernels of a GAS of built-in primitives of kind `Leaf`: ray `i` traced for its
// closest hit into `hits` or, with ANY, for occlusion into `occluded` (the other is unused).
template <bool ANY, typename Leaf>
__device__ __forceinline__ void builtin_entry(const float4* __restrict__ nodes,
                                              const float4* __restrict__ prims,
                                              const float4* __restrict__ rays,
                                              uint4* __restrict__ hits,
                                              unsigned char* __restrict__ occluded, u32 n) {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    TraceRay r;
    Best b;
    if (load_ray(rays, i, r)) {
        b = trace_builtin<ANY, Leaf>(r, nodes, prims);
    } else {
        b.t = F32_INF;
        b.u = b.v = 0.0f;
        b.slot = MISS_SLOT;
    }
    if (ANY) {
        occluded[i] = b.slot != MISS_SLOT ? 1 : 0;
    } else {
        store_hit(hits, i, b);
    }
}

extern "C" __global__ void __launch_bounds__(128)
    oxray_closest_spheres(const float4* __restrict__ nodes, const float4* __restrict__ spheres,
                          const float4* __restrict__ rays, uint4* __restrict__ hits, u32 n) {
    builtin_entry<false, SphereLeaf>(nodes, spheres, rays, hits, nullptr, n);
}

extern "C" __global__ void __launch_bounds__(128)
    oxray_occluded_spheres(const float4* __restrict__ nodes, const float4* __restrict__ spheres,
                           const float4* __restrict__ rays, unsigned char* __restrict__ occluded,
                           u32 n) {
    builtin_entry<true, SphereLeaf>(nodes, spheres, rays, nullptr, occluded, n);
}

// Queued on one thread after each launch of a programmable pipeline: copies the exception
// count and the trace count of the pipeline's exception buffer (words 0, 2 and 3) into mapped
// host memory, which the host reads once the stream is done (no copy to wait for), and starts
// the next launch's trace count at zero. Here, loaded once per context, rather than in each
// pipeline's generated module: there, pipelines with callables and custom primitives crashed
// the process while they were compiled or loaded (docs/BENCHMARKS.md, "The pipeline, seventh
// round").
extern "C" __global__ void oxray_launch_counts(u32* __restrict__ words, u32* __restrict__ host) {
    host[0] = words[0];
    host[1] = 0u;
    host[2] = words[2];
    host[3] = words[3];
    words[2] = 0u;
    words[3] = 0u;
}

#endif  // OXRAY_NO_QUERY_KERNELS
