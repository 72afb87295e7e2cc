// oxray CUDA simulation kernels: every primitive along a ray (the offers of a walk whose
// interval never shrinks), and the closest point of a triangle GAS to a point with the sign of
// its angle-weighted pseudo-normal. Compiled after trace.cu and curve.cu (their walks, box,
// triangle and sphere tests), with the same options: no FMA contraction, IEEE division and
// square root, so that every distance is the CPU backend's bit for bit.
//
// The offers are what the CPU's all-hits traversal is offered: every primitive hit in the ray's
// whole [tmin, tmax], a primitive referenced from several leaves once per leaf. Sorting them,
// telling repeats apart and bounding the lists are the host's (it knows the primitives).

// A kind of primitive for the offer kernels: `hit(r, prims, s, tmax, best)` as the query
// kernels' leaves (SphereLeaf in trace.cu); TriangleLeaf here for triangles.
struct TriangleLeaf {
    static __device__ __forceinline__ bool hit(const TraceRay& r, const float4* __restrict__ tris,
                                               u32 s, float tmax, Best& best) {
        float4 q0 = load_ro(tris + 3 * s);
        float4 q1 = load_ro(tris + 3 * s + 1);
        float4 q2 = load_ro(tris + 3 * s + 2);
        TriHit h;
        if (!intersect_triangle(r, make_float3(q0.x, q0.y, q0.z), make_float3(q1.x, q1.y, q1.z),
                                make_float3(q2.x, q2.y, q2.z), r.tmin, tmax, h)) {
            return false;
        }
        best.t = h.t;
        best.u = h.u;
        best.v = h.v;
        best.slot = s | (h.front ? 0u : BACK_FACE_BIT);
        return true;
    }
};

// Records offer `k` of a ray into its own part of the output, or only counts it (`out` null).
__device__ __forceinline__ void record_offer(uint4* __restrict__ out, u32* __restrict__ out_inst,
                                             u32 k, const Best& b, u32 inst) {
    if (out == nullptr) return;
    out[k] = make_uint4(__float_as_uint(b.t), b.slot, __float_as_uint(b.u), __float_as_uint(b.v));
    if (out_inst != nullptr) out_inst[k] = inst;
}

// The offers of ray `r` in a GAS of `Leaf`s: counted from `k` on, recorded at out[k..] where
// `out` is set (room for every one: the count pass ran first with the same rays). Returns the
// new count.
template <typename Leaf>
__device__ __forceinline__ u32 offers_gas(const TraceRay& r, const float4* __restrict__ nodes,
                                          const float4* __restrict__ prims, u32 k,
                                          uint4* __restrict__ out, u32* __restrict__ out_inst,
                                          u32 inst) {
    walk_bvh2(r, nodes, r.tmin, r.tmax, [&](u32 start, u32 count, float& tmax) {
        for (u32 s = start; s < start + count; ++s) {
            Best b;
            b.u = 0.0f;
            b.v = 0.0f;
            if (!Leaf::hit(r, prims, s, tmax, b)) continue;
            record_offer(out, out_inst, k, b, inst);
            ++k;
        }
        return false;
    });
    return k;
}

// Offers of ray `i` in a GAS: with `offsets` null, their number into `counts[i]`; else the
// offers into `out[offsets[i] ..]` (64-bit offsets: a batch may hold more than 2^32 offers in
// all) and nothing into `counts`. An invalid ray has none.
template <typename Leaf>
__device__ __forceinline__ void offers_write(const float4* __restrict__ nodes,
                                             const float4* __restrict__ prims,
                                             const float4* __restrict__ rays,
                                             u32* __restrict__ counts,
                                             const unsigned long long* __restrict__ offsets,
                                             uint4* __restrict__ out, u32 n) {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    TraceRay r;
    u32 k = 0;
    if (load_ray(rays, i, r)) {
        if (offsets == nullptr) {
            k = offers_gas<Leaf>(r, nodes, prims, 0, nullptr, nullptr, 0);
        } else {
            k = offers_gas<Leaf>(r, nodes, prims, 0, out + offsets[i], nullptr, 0);
        }
    }
    if (offsets == nullptr) counts[i] = k;
}

extern "C" __global__ void __launch_bounds__(128)
    oxray_offers_triangles(const float4* __restrict__ nodes, const float4* __restrict__ tris,
                           const float4* __restrict__ rays, u32* __restrict__ counts,
                           const unsigned long long* __restrict__ offsets,
                           uint4* __restrict__ out, u32 n) {
    offers_write<TriangleLeaf>(nodes, tris, rays, counts, offsets, out, n);
}

extern "C" __global__ void __launch_bounds__(128)
    oxray_offers_spheres(const float4* __restrict__ nodes, const float4* __restrict__ spheres,
                         const float4* __restrict__ rays, u32* __restrict__ counts,
                         const unsigned long long* __restrict__ offsets,
                         uint4* __restrict__ out, u32 n) {
    offers_write<SphereLeaf>(nodes, spheres, rays, counts, offsets, out, n);
}

// The offers of ray `i` under one level of instances over triangle GASes (the layout of
// trace_ias): each instance whose world box the ray crosses carries the ray into its space and
// offers every triangle hit there, with its instance slot into `out_inst`.
extern "C" __global__ void __launch_bounds__(128)
    oxray_offers_ias(const float4* __restrict__ top, const float4* __restrict__ insts,
                     const float4* __restrict__ rays, u32* __restrict__ counts,
                     const unsigned long long* __restrict__ offsets, uint4* __restrict__ out,
                     u32* __restrict__ out_inst, u32 n) {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    TraceRay r;
    u32 k = 0;
    const bool write = offsets != nullptr;
    uint4* o = write ? out + offsets[i] : nullptr;
    u32* oi = write ? out_inst + offsets[i] : nullptr;
    if (load_ray(rays, i, r)) {
        const float tmin = r.tmin;
        walk_bvh2(r, top, tmin, r.tmax, [&](u32 start, u32 count, float& tmax) {
            for (u32 s = start; s < start + count; ++s) {
                TraceRay ob;
                const float4 *nodes, *tris;
                if (!__oxray_enter_instance(r, insts + 6 * (size_t)s, tmin, tmax, ob, nodes,
                                            tris)) {
                    continue;
                }
                k = offers_gas<TriangleLeaf>(ob, nodes, tris, k, o, oi, s);
            }
            return false;
        });
    }
    if (!write) counts[i] = k;
}

// ---------------------------------------------------------------------------------------------
// Closest points (oxray_cpu::simulation::closest_point, operation for operation where the
// result depends on it: the region test, the squared distance, the lowest global id among equal
// distances). The walk prunes with box distances grown by a rounding margin, so it may test more
// triangles than the CPU's but finds the same nearest one.
// ---------------------------------------------------------------------------------------------

__device__ __forceinline__ float3 sub3(float3 a, float3 b) {
    return make_float3(a.x - b.x, a.y - b.y, a.z - b.z);
}
__device__ __forceinline__ float3 add3(float3 a, float3 b) {
    return make_float3(a.x + b.x, a.y + b.y, a.z + b.z);
}
__device__ __forceinline__ float3 mul3(float3 a, float s) {
    return make_float3(a.x * s, a.y * s, a.z * s);
}
// glam's Vec3::dot: (x * x') + (y * y') + (z * z'), left to right.
__device__ __forceinline__ float dot3(float3 a, float3 b) {
    return a.x * b.x + a.y * b.y + a.z * b.z;
}
__device__ __forceinline__ float3 cross3(float3 a, float3 b) {
    return make_float3(a.y * b.z - b.y * a.z, a.z * b.x - b.z * a.x, a.x * b.y - b.x * a.y);
}
// glam's Vec3::normalize_or_zero.
__device__ __forceinline__ float3 normalize_or_zero(float3 a) {
    float rcp = 1.0f / sqrtf(dot3(a, a));
    if (isfinite(rcp) && rcp > 0.0f) return mul3(a, rcp);
    return make_float3(0.0f, 0.0f, 0.0f);
}

struct Closest {
    float3 q;
    float u, v;
};

// Ericson's region test (Real-Time Collision Detection §5.1.5), as closest_on_triangle.
__device__ __forceinline__ Closest closest_on_triangle(float3 p, float3 a, float3 b, float3 c) {
    Closest r;
    float3 ab = sub3(b, a);
    float3 ac = sub3(c, a);
    float3 ap = sub3(p, a);
    float d1 = dot3(ab, ap);
    float d2 = dot3(ac, ap);
    if (d1 <= 0.0f && d2 <= 0.0f) {
        r.q = a;
        r.u = 0.0f;
        r.v = 0.0f;
        return r;
    }
    float3 bp = sub3(p, b);
    float d3 = dot3(ab, bp);
    float d4 = dot3(ac, bp);
    if (d3 >= 0.0f && d4 <= d3) {
        r.q = b;
        r.u = 1.0f;
        r.v = 0.0f;
        return r;
    }
    float vc = d1 * d4 - d3 * d2;
    if (vc <= 0.0f && d1 >= 0.0f && d3 <= 0.0f) {
        float u = d1 / (d1 - d3);
        r.q = add3(a, mul3(ab, u));
        r.u = u;
        r.v = 0.0f;
        return r;
    }
    float3 cp = sub3(p, c);
    float d5 = dot3(ab, cp);
    float d6 = dot3(ac, cp);
    if (d6 >= 0.0f && d5 <= d6) {
        r.q = c;
        r.u = 0.0f;
        r.v = 1.0f;
        return r;
    }
    float vb = d5 * d2 - d1 * d6;
    if (vb <= 0.0f && d2 >= 0.0f && d6 <= 0.0f) {
        float v = d2 / (d2 - d6);
        r.q = add3(a, mul3(ac, v));
        r.u = 0.0f;
        r.v = v;
        return r;
    }
    float va = d3 * d6 - d5 * d4;
    if (va <= 0.0f && d4 - d3 >= 0.0f && d5 - d6 >= 0.0f) {
        float v = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        r.q = add3(b, mul3(sub3(c, b), v));
        r.u = 1.0f - v;
        r.v = v;
        return r;
    }
    float denom = 1.0f / (va + vb + vc);
    float u = vb * denom;
    float v = vc * denom;
    r.q = add3(add3(a, mul3(ab, u)), mul3(ac, v));
    r.u = u;
    r.v = v;
    return r;
}

// The squared distance from `p` to the box [lo, hi], NaN for an empty box (which no radius
// reaches): box_dist2 of the CPU, one lane.
__device__ __forceinline__ float box_dist2(float3 p, float3 lo, float3 hi) {
    if (!(lo.x <= hi.x && lo.y <= hi.y && lo.z <= hi.z)) return __int_as_float(0x7fc00000);
    float dx = fmaxf(fmaxf(lo.x - p.x, p.x - hi.x), 0.0f);
    float dy = fmaxf(fmaxf(lo.y - p.y, p.y - hi.y), 0.0f);
    float dz = fmaxf(fmaxf(lo.z - p.z, p.z - hi.z), 0.0f);
    return dx * dx + dy * dy + dz * dz;
}

// `r2` grown by `margin` on the distance: the radius within which boxes are entered.
__device__ __forceinline__ float grown(float r2, float margin) {
    float r = sqrtf(r2) + margin;
    return r * r;
}

struct PointEntry {
    u32 child;
    u32 count;
    float d2;
};

// Walks the binary BVH nearest box first, handing the slot range of every leaf whose box is
// within `grown(*radius2, margin)` of `p` to `visit(start, count)`, which may lower `*radius2`.
template <typename Visit>
__device__ __forceinline__ void walk_point(const float4* __restrict__ nodes, float3 p,
                                           float* radius2, float margin, Visit&& visit) {
    PointEntry stack[OXRAY_STACK_SIZE];
    int sp = 0;
    PointEntry cur;
    cur.child = 0;
    cur.count = 0;
    cur.d2 = 0.0f;
    for (;;) {
        if (!(cur.d2 <= grown(*radius2, margin))) {
            // Pruned since it was pushed.
        } else if (cur.count > 0) {
            visit(cur.child, cur.count);
        } else {
            const float4* n = nodes + 4 * (size_t)cur.child;
            float4 n0 = load_ro(n), n1 = load_ro(n + 1), n2 = load_ro(n + 2);
            uint4 links = load_ro(reinterpret_cast<const uint4*>(n) + 3);
            float d0 = box_dist2(p, make_float3(n0.x, n0.z, n2.x), make_float3(n0.y, n0.w, n2.y));
            float d1 = box_dist2(p, make_float3(n1.x, n1.z, n2.z), make_float3(n1.y, n1.w, n2.w));
            float limit = grown(*radius2, margin);
            bool h0 = d0 <= limit, h1 = d1 <= limit;
            PointEntry a, b;
            a.child = links.x;
            a.count = links.z;
            a.d2 = d0;
            b.child = links.y;
            b.count = links.w;
            b.d2 = d1;
            if (h0 && h1) {
                if (d1 < d0) {
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
        }
        if (sp == 0) return;
        cur = stack[--sp];
    }
}

struct Nearest {
    u32 slot, id;
    float3 q;
    float u, v, d2;
};

__device__ __forceinline__ void load_triangle(const float4* __restrict__ tris, u32 s, float3& a,
                                              float3& b, float3& c) {
    float4 q0 = load_ro(tris + 3 * s);
    float4 q1 = load_ro(tris + 3 * s + 1);
    float4 q2 = load_ro(tris + 3 * s + 2);
    a = make_float3(q0.x, q0.y, q0.z);
    b = make_float3(q1.x, q1.y, q1.z);
    c = make_float3(q2.x, q2.y, q2.z);
}

// The nearest active triangle to `p` within squared distance `max2` (slot MISS_SLOT for none):
// the lowest global id among equal distances, as the CPU's `nearest`.
__device__ __forceinline__ Nearest nearest(const float4* __restrict__ nodes,
                                           const float4* __restrict__ tris,
                                           const u32* __restrict__ ids, float3 p, float max2,
                                           float margin) {
    Nearest best;
    best.slot = MISS_SLOT;
    best.id = MISS_SLOT;
    best.d2 = max2;
    float radius2 = max2;
    walk_point(nodes, p, &radius2, margin, [&](u32 start, u32 count) {
        for (u32 s = start; s < start + count; ++s) {
            u32 id = load_ro(ids + s);
            if (id == MISS_SLOT) continue;
            float3 a, b, c;
            load_triangle(tris, s, a, b, c);
            if (isnan(a.x)) continue;
            Closest cp = closest_on_triangle(p, a, b, c);
            float3 d = sub3(p, cp.q);
            float d2 = dot3(d, d);
            bool better = best.slot == MISS_SLOT ? d2 <= max2
                                                 : (d2 < best.d2 || (d2 == best.d2 && id < best.id));
            if (better) {
                best.slot = s;
                best.id = id;
                best.q = cp.q;
                best.u = cp.u;
                best.v = cp.v;
                best.d2 = d2;
                if (d2 < radius2) radius2 = d2;
            }
        }
    });
    return best;
}

// Points are four f32: x, y, z and the largest distance searched (+inf for no bound, which the
// host gives for a NaN or negative bound only after answering "none" itself). A result is two
// uint4: (q.x, q.y, q.z, d2) and (u, v, slot, id), slot MISS_SLOT for none.
extern "C" __global__ void __launch_bounds__(128)
    oxray_closest_points(const float4* __restrict__ nodes, const float4* __restrict__ tris,
                         const u32* __restrict__ ids, const float4* __restrict__ points,
                         uint4* __restrict__ out, float extent, u32 n) {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    float4 pt = points[i];
    float3 p = make_float3(pt.x, pt.y, pt.z);
    // bound_margin: 256 ulps of the largest coordinate involved.
    float scale = fmaxf(fmaxf(fabsf(p.x), fabsf(p.y)), fabsf(p.z)) + extent;
    float margin = 256.0f * __int_as_float(0x34000000) * fmaxf(scale, __int_as_float(0x00800000));
    float max2 = pt.w * pt.w;
    Nearest b = nearest(nodes, tris, ids, p, max2, margin);
    out[2 * i] = make_uint4(__float_as_uint(b.q.x), __float_as_uint(b.q.y), __float_as_uint(b.q.z),
                            __float_as_uint(b.d2));
    out[2 * i + 1] = make_uint4(__float_as_uint(b.u), __float_as_uint(b.v), b.slot, b.id);
}

// The angle of triangle [a, b, c] at its point of barycentrics (u, v): its angle at a vertex,
// pi on an edge, 2 pi inside (angle_at of the CPU).
__device__ __forceinline__ float angle_at(float3 a, float3 b, float3 c, float u, float v) {
    const float EPS = 1e-5f;
    float w0 = 1.0f - u - v, w1 = u, w2 = v;
    int zeros = (w0 <= EPS) + (w1 <= EPS) + (w2 <= EPS);
    if (zeros == 0) return 6.28318548f;
    if (zeros == 1) return 3.14159274f;
    float3 o, x, y;
    if (w0 >= w1 && w0 >= w2) {
        o = a, x = b, y = c;
    } else if (w1 >= w2) {
        o = b, x = c, y = a;
    } else {
        o = c, x = a, y = b;
    }
    float cosine = dot3(normalize_or_zero(sub3(x, o)), normalize_or_zero(sub3(y, o)));
    return acosf(fminf(fmaxf(cosine, -1.0f), 1.0f));
}

// Triangles a pseudo-normal sums in global-id order; beyond, in walk order.
#define NEAR_IDS 32

// The signed distance of every point (x, y, z, unused) to the surface: the nearest point's
// distance, negative where the angle-weighted pseudo-normal there faces away from the point
// (signed_distance of the CPU); +inf for a GAS with no active triangle.
extern "C" __global__ void __launch_bounds__(128)
    oxray_signed_distances(const float4* __restrict__ nodes, const float4* __restrict__ tris,
                           const u32* __restrict__ ids, const float4* __restrict__ points,
                           float* __restrict__ out, float extent, u32 n) {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    float4 pt = points[i];
    float3 p = make_float3(pt.x, pt.y, pt.z);
    float scale = fmaxf(fmaxf(fabsf(p.x), fabsf(p.y)), fabsf(p.z)) + extent;
    float margin = 256.0f * __int_as_float(0x34000000) * fmaxf(scale, __int_as_float(0x00800000));
    Nearest b = nearest(nodes, tris, ids, p, F32_INF, margin);
    if (b.slot == MISS_SLOT) {
        out[i] = F32_INF;
        return;
    }
    float d = sqrtf(b.d2);
    if (d == 0.0f) {
        out[i] = 0.0f;
        return;
    }
    float3 a0, b0, c0;
    load_triangle(tris, b.slot, a0, b0, c0);
    float3 nrm;
    if (angle_at(a0, b0, c0, b.u, b.v) == 6.28318548f) {
        nrm = cross3(sub3(b0, a0), sub3(c0, a0));
    } else {
        // normal_tolerance: the triangles whose closest point lies within it of q are those q
        // lies on.
        float qmax = fmaxf(fmaxf(fabsf(b.q.x), fabsf(b.q.y)), fabsf(b.q.z));
        float tol = 64.0f * __int_as_float(0x34000000) * (qmax + d) + __int_as_float(0x00800000);
        float radius2 = (d + tol) * (d + tol);
        u32 near_id[NEAR_IDS], near_slot[NEAR_IDS];
        int len = 0;
        bool overflow = false;
        walk_point(nodes, p, &radius2, margin, [&](u32 start, u32 count) {
            for (u32 s = start; s < start + count; ++s) {
                u32 id = load_ro(ids + s);
                if (id == MISS_SLOT) continue;
                float3 a, bb, c;
                load_triangle(tris, s, a, bb, c);
                if (isnan(a.x)) continue;
                Closest cp = closest_on_triangle(p, a, bb, c);
                float3 dq = sub3(cp.q, b.q);
                if (sqrtf(dot3(dq, dq)) > tol) continue;
                // Kept sorted by id, each id once.
                int j = 0;
                while (j < len && near_id[j] < id) ++j;
                if (j < len && near_id[j] == id) continue;
                if (len == NEAR_IDS) {
                    overflow = true;
                    continue;
                }
                for (int m = len; m > j; --m) {
                    near_id[m] = near_id[m - 1];
                    near_slot[m] = near_slot[m - 1];
                }
                near_id[j] = id;
                near_slot[j] = s;
                ++len;
            }
        });
        nrm = make_float3(0.0f, 0.0f, 0.0f);
        if (!overflow) {
            for (int j = 0; j < len; ++j) {
                float3 a, bb, c;
                load_triangle(tris, near_slot[j], a, bb, c);
                Closest cp = closest_on_triangle(p, a, bb, c);
                float3 tn = normalize_or_zero(cross3(sub3(bb, a), sub3(c, a)));
                nrm = add3(nrm, mul3(tn, angle_at(a, bb, c, cp.u, cp.v)));
            }
        } else {
            // More triangles at q than the table holds (a vertex of very high valence): every
            // one in walk order, a triangle referenced from several leaves once per leaf.
            radius2 = (d + tol) * (d + tol);
            walk_point(nodes, p, &radius2, margin, [&](u32 start, u32 count) {
                for (u32 s = start; s < start + count; ++s) {
                    if (load_ro(ids + s) == MISS_SLOT) continue;
                    float3 a, bb, c;
                    load_triangle(tris, s, a, bb, c);
                    if (isnan(a.x)) continue;
                    Closest cp = closest_on_triangle(p, a, bb, c);
                    float3 dq = sub3(cp.q, b.q);
                    if (sqrtf(dot3(dq, dq)) > tol) continue;
                    float3 tn = normalize_or_zero(cross3(sub3(bb, a), sub3(c, a)));
                    nrm = add3(nrm, mul3(tn, angle_at(a, bb, c, cp.u, cp.v)));
                }
            });
        }
    }
    out[i] = dot3(sub3(p, b.q), nrm) < 0.0f ? -d : d;
}

// Copies words[i] 32-bit words (at most RECORD_WORDS) from each address addrs[i] (a
// primitive's record in the slot table of a GAS in this context) into out[i * RECORD_WORDS ..]:
// the primitives of the host's surface queries.
#define RECORD_WORDS 12
extern "C" __global__ void __launch_bounds__(128)
    oxray_gather_records(const unsigned long long* __restrict__ addrs,
                         const u32* __restrict__ words, u32* __restrict__ out, u32 n) {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    const u32* p = reinterpret_cast<const u32*>(addrs[i]);
    u32 w = words[i] < RECORD_WORDS ? words[i] : RECORD_WORDS;
    for (u32 k = 0; k < w; ++k) out[(size_t)i * RECORD_WORDS + k] = p[k];
}

// The closest point of the triangles under one level of instances (the layout of trace_ias)
// to every point (x, y, z, unused): the instance slots' world boxes walked through the top-level
// tree nearest first; an instance is searched where its box is within the best distance so far
// (the CPU's rule), with the point carried into its space and the best distance over its
// similarity scale as the radius. Among equal distances the instance whose box is nearer, then
// the lower slot, wins: the instance the CPU's best-first search finds first, whatever the walk
// order. `extras` holds four float4 per instance slot: the object-to-world rows, then (the
// child's slot-id table address as two words, the scale, the child's extent). A result is two
// uint4: (world q.x, q.y, q.z, distance) and (u, v, child slot, instance slot), instance slot
// MISS_SLOT for none.
extern "C" __global__ void __launch_bounds__(128)
    oxray_instance_closest_points(const float4* __restrict__ top, const float4* __restrict__ insts,
                                  const float4* __restrict__ extras,
                                  const float4* __restrict__ points, uint4* __restrict__ out,
                                  float top_extent, u32 n) {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    float4 pt = points[i];
    float3 p = make_float3(pt.x, pt.y, pt.z);
    float scale_top = fmaxf(fmaxf(fabsf(p.x), fabsf(p.y)), fabsf(p.z)) + top_extent;
    float top_margin =
        256.0f * __int_as_float(0x34000000) * fmaxf(scale_top, __int_as_float(0x00800000));
    float best = F32_INF;
    u32 best_bits = 0xffffffffu, best_slot = MISS_SLOT;
    Nearest found;
    found.slot = MISS_SLOT;
    found.u = 0.0f;
    found.v = 0.0f;
    float3 world_q = make_float3(0.0f, 0.0f, 0.0f);
    float radius2 = F32_INF;
    walk_point(top, p, &radius2, top_margin, [&](u32 start, u32 count) {
        for (u32 s = start; s < start + count; ++s) {
            const float4* inst = insts + 6 * (size_t)s;
            float4 lo = inst[3], hi = inst[4];
            float d2box = box_dist2(p, make_float3(lo.x, lo.y, lo.z), make_float3(hi.x, hi.y, hi.z));
            if (!(sqrtf(d2box) <= best)) continue;
            uint4 ptrs = reinterpret_cast<const uint4*>(inst)[5];
            const float4* nodes = reinterpret_cast<const float4*>(
                ((unsigned long long)ptrs.y << 32) | (unsigned long long)ptrs.x);
            const float4* tris = reinterpret_cast<const float4*>(
                ((unsigned long long)ptrs.w << 32) | (unsigned long long)ptrs.z);
            if (nodes == nullptr) continue;
            const float4* e = extras + 4 * (size_t)s;
            float4 e3 = e[3];
            const u32* ids = reinterpret_cast<const u32*>(
                ((unsigned long long)__float_as_uint(e3.y) << 32) |
                (unsigned long long)__float_as_uint(e3.x));
            float scale = e3.z;
            float4 m0 = inst[0], m1 = inst[1], m2 = inst[2];
            float3 here = __oxray_point(m0, m1, m2, p);
            // The radius grown by a few ulps: an instance as close as the best (a tie that the
            // nearer box or lower slot may win) is still found.
            float radius = best / scale;
            radius = radius + radius * 1e-6f;
            float s_here = fmaxf(fmaxf(fabsf(here.x), fabsf(here.y)), fabsf(here.z)) + e3.w;
            float margin =
                256.0f * __int_as_float(0x34000000) * fmaxf(s_here, __int_as_float(0x00800000));
            Nearest nb = nearest(nodes, tris, ids, here, radius * radius, margin);
            if (nb.slot == MISS_SLOT) continue;
            float dist = sqrtf(nb.d2) * scale;
            u32 bits = __float_as_uint(d2box);
            bool better = dist < best ||
                          (dist == best && (bits < best_bits || (bits == best_bits && s < best_slot)));
            if (!better) continue;
            best = dist;
            best_bits = bits;
            best_slot = s;
            found = nb;
            float4 w0 = e[0], w1 = e[1], w2 = e[2];
            world_q = __oxray_point(w0, w1, w2, nb.q);
            radius2 = best * best;
        }
    });
    out[2 * i] = make_uint4(__float_as_uint(world_q.x), __float_as_uint(world_q.y),
                            __float_as_uint(world_q.z), __float_as_uint(best));
    out[2 * i + 1] = make_uint4(__float_as_uint(found.u), __float_as_uint(found.v), found.slot,
                                best_slot);
}
