// oxray: the GPU builder of triangle GASes (a linear BVH, Karras 2012), compiled at run time
// by NVRTC. The host side is `src/device_build.rs`, which launches these kernels in order:
//
//   1. oxray_build_bounds     per triangle: fetch, the CPU's degeneracy rule, box; centroid
//                             bounds, the count of active triangles and of the tree's
//                             triangles (atomics): the active ones, or with `keep_inactive`
//                             (ALLOW_UPDATE: an update may make them active) all of them.
//   2. oxray_build_morton32/64  Morton code of each active centroid (30, 32 or 60 bits); inactive
//                             triangles get the key 1 << bits, which sorts after every code.
//   3. oxray_sort_hist32/64, oxray_sort_scan, oxray_sort_scatter32/64
//                             a stable LSD radix sort of (key, triangle) pairs, 8 bits a pass.
//   4. oxray_build_karras     the binary radix tree over the sorted keys, ties broken by
//                             position (Karras' trick), so that the tree is valid and its depth
//                             bounded by the key's bits plus log2(n).
//   5. oxray_build_bottom_up  boxes, SAH costs and the collapse into leaves of up to max_leaf
//                             triangles, bottom-up with one atomic counter per node.
//   6. oxray_build_mark, oxray_scan_*  which inner nodes remain, numbered by a prefix sum.
//   7. oxray_build_write_nodes, oxray_build_write_triangles
//                             the exact layout of `layout.rs` that trace.cu and oxray_device.h
//                             walk: 64-byte binary nodes, 3 float4 per leaf slot.
//   8. oxray_build_heights    (updatable builds) the height of each written node, by which the
//                             refit orders its launches.
//
// Leaf slots are positions in the sorted order: a leaf of the collapsed tree is a range of
// consecutive sorted triangles, so the triangle array needs no padding and the slot table is the
// sorted triangle ids themselves.
//
// Compiled with the trace kernels' options (no FMA contraction), so that the degeneracy test's
// double-precision cross product rounds as the CPU's does.

typedef unsigned int u32;
typedef unsigned long long u64;

#define BUILD_BLOCK 256
#define SORT_ITEMS 8
#define SORT_TILE (BUILD_BLOCK * SORT_ITEMS)
#define SORT_WARPS (BUILD_BLOCK / 32)
#define LEAF_BIT 0x80000000u
#define NO_NODE 0xFFFFFFFFu
#define FULL_MASK 0xFFFFFFFFu
#define F32_INF __int_as_float(0x7f800000)

// SAH costs of visiting a binary node and of testing one triangle (Karras 2013's 1.2 and 1).
#define COST_NODE 1.2f
#define COST_TRI 1.0f

// One build input as the device reads it: f32 vertices `vstride` floats apart, and (when
// `istride` is not 0) u32 index triplets `istride` words apart. `first` is the global id of its
// first triangle; inputs are sorted by it.
struct InputDesc {
    u64 vertices;
    u64 indices;
    u32 first;
    u32 vstride;
    u32 istride;
    u32 pad;
};

// Counters the host zeroes (and sets the minima of) before the build.
// [0..3) centroid minima, [3..6) centroid maxima (as order-preserving integers),
// [6] triangles in the tree (the active ones, or all with `keep_inactive`), [7] inner nodes
// kept, [8] active triangles.
#define C_ACTIVE 6
#define C_KEPT 7
#define C_LIVE 8

// One node of the binary radix tree. `left`/`right` are inner nodes or, with LEAF_BIT, sorted
// positions; `first..=last` is the range of sorted positions below it. Written by
// oxray_build_karras; `visits`, the box, costs and `shape` by oxray_build_bottom_up.
struct INode {
    u32 left, right, parent, first, last;
    u32 visits;
    u32 shape;  // LEAF_BIT: becomes a leaf; low bits: height of the collapsed subtree
    float cost;  // SAH cost with COST_NODE / COST_TRI (decides the collapse)
    float stat;  // SAH cost with unit costs (BvhStats::sah_cost, times the box's area)
    float lo[3], hi[3];
    u32 pad;
};

__device__ __forceinline__ u32 ordered(float f) {
    u32 b = __float_as_uint(f);
    return (b & 0x80000000u) ? ~b : (b | 0x80000000u);
}
__device__ __forceinline__ float unordered(u32 u) {
    return __uint_as_float((u & 0x80000000u) ? (u & 0x7FFFFFFFu) : ~u);
}

__device__ __forceinline__ u32 find_input(const InputDesc* in, u32 n_in, u32 g) {
    u32 lo = 0, hi = n_in;
    while (hi - lo > 1) {
        u32 mid = (lo + hi) >> 1;
        if (in[mid].first <= g) lo = mid;
        else hi = mid;
    }
    return lo;
}

__device__ __forceinline__ void fetch(const InputDesc* in, u32 n_in, u32 g, float3 p[3]) {
    const InputDesc d = in[find_input(in, n_in, g)];
    const size_t local = g - d.first;
    size_t ix[3];
    if (d.istride != 0) {
        const u32* I = reinterpret_cast<const u32*>(d.indices) + local * d.istride;
        ix[0] = I[0];
        ix[1] = I[1];
        ix[2] = I[2];
    } else {
        ix[0] = 3 * local;
        ix[1] = 3 * local + 1;
        ix[2] = 3 * local + 2;
    }
    const float* V = reinterpret_cast<const float*>(d.vertices);
    for (int k = 0; k < 3; ++k) {
        const float* v = V + ix[k] * d.vstride;
        p[k] = make_float3(v[0], v[1], v[2]);
    }
}

// `oxray_bvh::triangle::is_degenerate`: a non-finite coordinate, or a cross product of the edges
// that is exactly zero in double precision (glam's operand order, no FMA).
__device__ __forceinline__ bool degenerate(const float3 p[3]) {
    for (int k = 0; k < 3; ++k)
        if (!(isfinite(p[k].x) && isfinite(p[k].y) && isfinite(p[k].z))) return true;
    double ux = (double)p[1].x - (double)p[0].x, uy = (double)p[1].y - (double)p[0].y,
           uz = (double)p[1].z - (double)p[0].z;
    double vx = (double)p[2].x - (double)p[0].x, vy = (double)p[2].y - (double)p[0].y,
           vz = (double)p[2].z - (double)p[0].z;
    double nx = uy * vz - vy * uz;
    double ny = uz * vx - vz * ux;
    double nz = ux * vy - vx * uy;
    return nx == 0.0 && ny == 0.0 && nz == 0.0;
}

// Half the surface area of a box; 0 for the empty box of an inactive primitive (and of a
// subtree of inactive primitives only), which an updatable build keeps in its tree.
__device__ __forceinline__ float half_area(float3 lo, float3 hi) {
    if (!(lo.x <= hi.x)) return 0.0f;
    float x = hi.x - lo.x, y = hi.y - lo.y, z = hi.z - lo.z;
    return x * y + y * z + z * x;
}

// ---------------------------------------------------------------------------------------------
// 1. Bounds.

// Stores primitive i's box (an empty one when inactive: sorted last by its key, and a leaf's
// only with `keep_inactive`) and adds its centroid, its activity and whether the tree holds it
// to the block's reduction into `counters`. Every thread of the block calls it (i past n:
// inactive, not kept).
__device__ __forceinline__ void store_box(u32 i, u32 n, bool active, u32 keep_inactive, float3 lo,
                                          float3 hi, float4* __restrict__ boxes,
                                          u32* __restrict__ counters) {
    float c_lo[3] = {F32_INF, F32_INF, F32_INF};
    float c_hi[3] = {-F32_INF, -F32_INF, -F32_INF};
    u32 act = 0, tree = 0;
    if (i < n) {
        tree = active || keep_inactive ? 1 : 0;
        if (!active) {
            boxes[2 * (size_t)i] = make_float4(F32_INF, F32_INF, F32_INF, 0.0f);
            boxes[2 * (size_t)i + 1] = make_float4(-F32_INF, -F32_INF, -F32_INF, 0.0f);
        } else {
            boxes[2 * (size_t)i] = make_float4(lo.x, lo.y, lo.z, 0.0f);
            boxes[2 * (size_t)i + 1] = make_float4(hi.x, hi.y, hi.z, 0.0f);
            c_lo[0] = c_hi[0] = 0.5f * (lo.x + hi.x);
            c_lo[1] = c_hi[1] = 0.5f * (lo.y + hi.y);
            c_lo[2] = c_hi[2] = 0.5f * (lo.z + hi.z);
            act = 1;
        }
    }
    for (int off = 16; off > 0; off >>= 1) {
        for (int k = 0; k < 3; ++k) {
            c_lo[k] = fminf(c_lo[k], __shfl_xor_sync(FULL_MASK, c_lo[k], off));
            c_hi[k] = fmaxf(c_hi[k], __shfl_xor_sync(FULL_MASK, c_hi[k], off));
        }
        act += __shfl_xor_sync(FULL_MASK, act, off);
        tree += __shfl_xor_sync(FULL_MASK, tree, off);
    }
    __shared__ float s_lo[3][SORT_WARPS], s_hi[3][SORT_WARPS];
    __shared__ u32 s_active[SORT_WARPS], s_tree[SORT_WARPS];
    const u32 lane = threadIdx.x & 31, warp = threadIdx.x >> 5;
    if (lane == 0) {
        for (int k = 0; k < 3; ++k) {
            s_lo[k][warp] = c_lo[k];
            s_hi[k][warp] = c_hi[k];
        }
        s_active[warp] = act;
        s_tree[warp] = tree;
    }
    __syncthreads();
    if (threadIdx.x < 3) {
        const int k = threadIdx.x;
        float l = F32_INF, h = -F32_INF;
        for (int w = 0; w < SORT_WARPS; ++w) {
            l = fminf(l, s_lo[k][w]);
            h = fmaxf(h, s_hi[k][w]);
        }
        if (l <= h) {
            atomicMin(&counters[k], ordered(l));
            atomicMax(&counters[3 + k], ordered(h));
        }
    } else if (threadIdx.x == 3) {
        u32 a = 0, t = 0;
        for (int w = 0; w < SORT_WARPS; ++w) {
            a += s_active[w];
            t += s_tree[w];
        }
        if (a) atomicAdd(&counters[C_LIVE], a);
        if (t) atomicAdd(&counters[C_ACTIVE], t);
    }
}

extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_build_bounds(const InputDesc* __restrict__ in, u32 n_in, u32 n, u32 keep_inactive,
                       float4* __restrict__ boxes, u32* __restrict__ counters) {
    const u32 i = blockIdx.x * BUILD_BLOCK + threadIdx.x;
    bool active = false;
    float3 lo = make_float3(0.0f, 0.0f, 0.0f), hi = lo;
    if (i < n) {
        float3 p[3];
        fetch(in, n_in, i, p);
        active = !degenerate(p);
        lo = make_float3(fminf(fminf(p[0].x, p[1].x), p[2].x), fminf(fminf(p[0].y, p[1].y), p[2].y),
                         fminf(fminf(p[0].z, p[1].z), p[2].z));
        hi = make_float3(fmaxf(fmaxf(p[0].x, p[1].x), p[2].x), fmaxf(fmaxf(p[0].y, p[1].y), p[2].y),
                         fmaxf(fmaxf(p[0].z, p[1].z), p[2].z));
    }
    store_box(i, n, active, keep_inactive, lo, hi, boxes, counters);
}

// Custom primitives (guide §5.3): `aabbs` holds 6 floats per primitive (lower, upper corner),
// decoded by the host. A box is active when it is finite and not inverted
// (`Aabb::is_finite_valid`), as on the CPU.
extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_build_bounds_aabbs(const float* __restrict__ aabbs, u32 n, u32 keep_inactive,
                             float4* __restrict__ boxes, u32* __restrict__ counters) {
    const u32 i = blockIdx.x * BUILD_BLOCK + threadIdx.x;
    bool active = false;
    float3 lo = make_float3(0.0f, 0.0f, 0.0f), hi = lo;
    if (i < n) {
        const float* a = aabbs + 6 * (size_t)i;
        lo = make_float3(a[0], a[1], a[2]);
        hi = make_float3(a[3], a[4], a[5]);
        active = isfinite(lo.x) && isfinite(lo.y) && isfinite(lo.z) && isfinite(hi.x) &&
                 isfinite(hi.y) && isfinite(hi.z) && lo.x <= hi.x && lo.y <= hi.y && lo.z <= hi.z;
    }
    store_box(i, n, active, keep_inactive, lo, hi, boxes, counters);
}

// ---------------------------------------------------------------------------------------------
// 2. Morton codes.

__device__ __forceinline__ u32 expand10(u32 x) {
    x &= 0x3FFu;
    x = (x | (x << 16)) & 0x030000FFu;
    x = (x | (x << 8)) & 0x0300F00Fu;
    x = (x | (x << 4)) & 0x030C30C3u;
    x = (x | (x << 2)) & 0x09249249u;
    return x;
}

__device__ __forceinline__ u64 expand20(u64 x) {
    x &= 0xFFFFFull;
    x = (x | (x << 32)) & 0x1F00000000FFFFull;
    x = (x | (x << 16)) & 0x1F0000FF0000FFull;
    x = (x | (x << 8)) & 0x100F00F00F00F00Full;
    x = (x | (x << 4)) & 0x10C30C30C30C30C3ull;
    x = (x | (x << 2)) & 0x1249249249249249ull;
    return x;
}

// The centroid's cell in a grid of 2^bits cells per axis over the centroid bounds; false for
// an inactive triangle.
__device__ __forceinline__ bool cell(const float4* boxes, const u32* counters, u32 i, float scale,
                                     u32 q[3]) {
    float4 lo = boxes[2 * (size_t)i], hi = boxes[2 * (size_t)i + 1];
    if (!(lo.x <= hi.x)) return false;
    float c[3] = {0.5f * (lo.x + hi.x), 0.5f * (lo.y + hi.y), 0.5f * (lo.z + hi.z)};
    for (int k = 0; k < 3; ++k) {
        float b0 = unordered(counters[k]), b1 = unordered(counters[3 + k]);
        float extent = b1 - b0;
        float t = extent > 0.0f ? (c[k] - b0) / extent : 0.0f;
        float f = fminf(fmaxf(t * scale, 0.0f), scale - 1.0f);
        q[k] = (u32)f;
    }
    return true;
}

// 32-bit keys of `bits` bits: 30, the Morton code of a grid of 2^10 cells per axis; 32, the
// first 32 bits of the 60-bit code (those ten levels of cells, then each cell's halves in x and
// y): four sort passes either way, the finer cells for free. Inactive triangles get a key past
// every active one.
extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_build_morton32(const float4* __restrict__ boxes, u32 n, const u32* __restrict__ counters,
                         u32 bits, u32* __restrict__ keys, u32* __restrict__ values) {
    const u32 i = blockIdx.x * BUILD_BLOCK + threadIdx.x;
    if (i >= n) return;
    u32 q[3];
    if (bits == 30) {
        keys[i] = cell(boxes, counters, i, 1024.0f, q)
                      ? (expand10(q[0]) << 2) | (expand10(q[1]) << 1) | expand10(q[2])
                      : (1u << 30);
    } else if (cell(boxes, counters, i, 1048576.0f, q)) {
        u64 code = (expand20(q[0]) << 2) | (expand20(q[1]) << 1) | expand20(q[2]);
        // The last cell shares its key with the one before, so that no active key is the
        // inactive ones'.
        keys[i] = min((u32)(code >> 28), 0xFFFFFFFEu);
    } else {
        keys[i] = 0xFFFFFFFFu;
    }
    values[i] = i;
}

extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_build_morton64(const float4* __restrict__ boxes, u32 n, const u32* __restrict__ counters,
                         u32 bits, u64* __restrict__ keys, u32* __restrict__ values) {
    (void)bits;  // always 60
    const u32 i = blockIdx.x * BUILD_BLOCK + threadIdx.x;
    if (i >= n) return;
    u32 q[3];
    keys[i] = cell(boxes, counters, i, 1048576.0f, q)
                  ? (expand20(q[0]) << 2) | (expand20(q[1]) << 1) | expand20(q[2])
                  : (1ull << 60);
    values[i] = i;
}

// ---------------------------------------------------------------------------------------------
// 3. Stable LSD radix sort, 8 bits a pass, tiles of SORT_TILE keys: per-tile digit counts
// (digit-major, so that one scan per digit orders the tiles), a scan per digit, and a scatter
// that ranks each key within its tile with warp-level matching (warps own consecutive runs of
// the tile, so ranks follow the input order: the sort is stable).

// Exclusive scan across a block of BUILD_BLOCK threads; `total` gets the sum.
__device__ __forceinline__ u32 block_exclusive_scan(u32 v, u32& total) {
    __shared__ u32 warp_sums[SORT_WARPS];
    const u32 lane = threadIdx.x & 31, warp = threadIdx.x >> 5;
    u32 x = v;
    for (int off = 1; off < 32; off <<= 1) {
        u32 y = __shfl_up_sync(FULL_MASK, x, off);
        if (lane >= off) x += y;
    }
    if (lane == 31) warp_sums[warp] = x;
    __syncthreads();
    u32 before = 0, all = 0;
    for (int w = 0; w < SORT_WARPS; ++w) {
        u32 s = warp_sums[w];
        if (w < (int)warp) before += s;
        all += s;
    }
    __syncthreads();
    total = all;
    return before + x - v;
}

template <typename K>
__device__ __forceinline__ void sort_hist(const K* __restrict__ keys, u32 n, u32 shift,
                                          u32* __restrict__ counts, u32 tiles) {
    __shared__ u32 h[256];
    h[threadIdx.x] = 0;
    __syncthreads();
    const size_t base = (size_t)blockIdx.x * SORT_TILE;
    for (int k = 0; k < SORT_ITEMS; ++k) {
        size_t i = base + k * BUILD_BLOCK + threadIdx.x;
        if (i < n) atomicAdd(&h[(u32)(keys[i] >> shift) & 255u], 1u);
    }
    __syncthreads();
    counts[(size_t)threadIdx.x * tiles + blockIdx.x] = h[threadIdx.x];
}

extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_sort_hist32(const u32* keys, u32 n, u32 shift, u32* counts, u32 tiles) {
    sort_hist<u32>(keys, n, shift, counts, tiles);
}
extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_sort_hist64(const u64* keys, u32 n, u32 shift, u32* counts, u32 tiles) {
    sort_hist<u64>(keys, n, shift, counts, tiles);
}

// One block per digit: the exclusive scan of that digit's counts over the tiles, in place, and
// the digit's total.
extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_sort_scan(u32* __restrict__ counts, u32 tiles, u32* __restrict__ totals) {
    u32* c = counts + (size_t)blockIdx.x * tiles;
    u32 carry = 0;
    for (u32 base = 0; base < tiles; base += BUILD_BLOCK) {
        u32 i = base + threadIdx.x;
        u32 v = i < tiles ? c[i] : 0;
        u32 sum;
        u32 ex = block_exclusive_scan(v, sum);
        if (i < tiles) c[i] = carry + ex;
        carry += sum;
    }
    if (threadIdx.x == 0) totals[blockIdx.x] = carry;
}

template <typename K>
__device__ __forceinline__ void sort_scatter(const K* __restrict__ keys_in,
                                             const u32* __restrict__ vals_in,
                                             K* __restrict__ keys_out, u32* __restrict__ vals_out,
                                             u32 n, u32 shift, const u32* __restrict__ counts,
                                             u32 tiles, const u32* __restrict__ totals) {
    __shared__ u32 base[256];
    __shared__ u32 wh[SORT_WARPS][256];
    const u32 t = threadIdx.x, lane = t & 31, warp = t >> 5;
    u32 sum;
    u32 digit_start = block_exclusive_scan(totals[t], sum);
    base[t] = digit_start + counts[(size_t)t * tiles + blockIdx.x];
    for (int w = 0; w < SORT_WARPS; ++w) wh[w][t] = 0;
    __syncthreads();

    K key[SORT_ITEMS];
    u32 val[SORT_ITEMS], rank[SORT_ITEMS], dig[SORT_ITEMS];
    const size_t run = (size_t)blockIdx.x * SORT_TILE + (size_t)warp * (32 * SORT_ITEMS);
    const u32 lt = (1u << lane) - 1u;
    for (int k = 0; k < SORT_ITEMS; ++k) {
        const size_t i = run + k * 32 + lane;
        const bool valid = i < n;
        const u32 vmask = __ballot_sync(FULL_MASK, valid);
        dig[k] = 256;
        rank[k] = 0;
        u32 before = 0, peers = 0;
        if (valid) {
            key[k] = keys_in[i];
            val[k] = vals_in[i];
            dig[k] = (u32)(key[k] >> shift) & 255u;
            peers = __match_any_sync(vmask, dig[k]);
            before = wh[warp][dig[k]];
        }
        __syncwarp();
        if (valid && (__ffs(peers) - 1) == (int)lane) wh[warp][dig[k]] = before + __popc(peers);
        __syncwarp();
        rank[k] = before + __popc(peers & lt);
    }
    __syncthreads();
    u32 acc = 0;
    for (int w = 0; w < SORT_WARPS; ++w) {
        u32 c = wh[w][t];
        wh[w][t] = acc;
        acc += c;
    }
    __syncthreads();
    for (int k = 0; k < SORT_ITEMS; ++k) {
        if (dig[k] < 256) {
            u32 dst = base[dig[k]] + wh[warp][dig[k]] + rank[k];
            keys_out[dst] = key[k];
            vals_out[dst] = val[k];
        }
    }
}

extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_sort_scatter32(const u32* keys_in, const u32* vals_in, u32* keys_out, u32* vals_out,
                         u32 n, u32 shift, const u32* counts, u32 tiles, const u32* totals) {
    sort_scatter<u32>(keys_in, vals_in, keys_out, vals_out, n, shift, counts, tiles, totals);
}
extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_sort_scatter64(const u64* keys_in, const u32* vals_in, u64* keys_out, u32* vals_out,
                         u32 n, u32 shift, const u32* counts, u32 tiles, const u32* totals) {
    sort_scatter<u64>(keys_in, vals_in, keys_out, vals_out, n, shift, counts, tiles, totals);
}

// ---------------------------------------------------------------------------------------------
// 4. The binary radix tree (Karras 2012) over the `n_act` active keys, which the sort put first.

__device__ __forceinline__ int clz_key(u32 x) { return __clz(x); }
__device__ __forceinline__ int clz_key(u64 x) { return __clzll(x); }

// Common prefix of keys i and j in bits, equal keys extended by their positions' prefix; -1
// outside the range.
template <typename K>
__device__ __forceinline__ int delta(const K* keys, long long n, long long i, long long j) {
    if (j < 0 || j >= n) return -1;
    K a = keys[i], b = keys[j];
    if (a == b) return (int)(8 * sizeof(K)) + __clz((u32)i ^ (u32)j);
    return clz_key(a ^ b);
}

template <typename K>
__device__ __forceinline__ void karras(const K* __restrict__ keys, const u32* __restrict__ counters,
                                       INode* __restrict__ nodes, u32* __restrict__ leaf_parent) {
    const long long n = counters[C_ACTIVE];
    const long long i = (long long)blockIdx.x * BUILD_BLOCK + threadIdx.x;
    if (i >= n - 1) return;
    const int d = delta(keys, n, i, i + 1) - delta(keys, n, i, i - 1) >= 0 ? 1 : -1;
    const int dmin = delta(keys, n, i, i - d);
    long long lmax = 2;
    while (delta(keys, n, i, i + lmax * d) > dmin) lmax *= 2;
    long long l = 0;
    for (long long t = lmax / 2; t >= 1; t /= 2)
        if (delta(keys, n, i, i + (l + t) * d) > dmin) l += t;
    const long long j = i + l * d;
    const int dnode = delta(keys, n, i, j);
    long long s = 0, step = l;
    do {
        step = (step + 1) >> 1;
        if (s + step < l && delta(keys, n, i, i + (s + step) * d) > dnode) s += step;
    } while (step > 1);
    const long long gamma = i + s * d + (d < 0 ? -1 : 0);
    const long long lo = i < j ? i : j, hi = i < j ? j : i;
    INode& node = nodes[i];
    node.left = lo == gamma ? (u32)gamma | LEAF_BIT : (u32)gamma;
    node.right = hi == gamma + 1 ? (u32)(gamma + 1) | LEAF_BIT : (u32)(gamma + 1);
    node.first = (u32)lo;
    node.last = (u32)hi;
    node.visits = 0;
    if (lo == gamma) leaf_parent[gamma] = (u32)i;
    else nodes[gamma].parent = (u32)i;
    if (hi == gamma + 1) leaf_parent[gamma + 1] = (u32)i;
    else nodes[gamma + 1].parent = (u32)i;
    if (i == 0) node.parent = NO_NODE;
}

extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_build_karras32(const u32* keys, const u32* counters, INode* nodes, u32* leaf_parent) {
    karras<u32>(keys, counters, nodes, leaf_parent);
}
extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_build_karras64(const u64* keys, const u32* counters, INode* nodes, u32* leaf_parent) {
    karras<u64>(keys, counters, nodes, leaf_parent);
}

// ---------------------------------------------------------------------------------------------
// 5. Bottom-up: the second thread to reach a node computes its box, its costs, whether it
// becomes a leaf (never the root) and the height of its collapsed subtree. Data another thread
// wrote is read through L2 (__ldcg), after that thread's fence and counter increment.

struct ChildInfo {
    float3 lo, hi;
    float cost, stat;
    u32 height;
};

__device__ __forceinline__ ChildInfo child_info(u32 c, const INode* nodes, const float4* boxes,
                                                const u32* values) {
    ChildInfo r;
    if (c & LEAF_BIT) {
        const u32 g = values[c & ~LEAF_BIT];
        float4 lo = boxes[2 * (size_t)g], hi = boxes[2 * (size_t)g + 1];
        r.lo = make_float3(lo.x, lo.y, lo.z);
        r.hi = make_float3(hi.x, hi.y, hi.z);
        float a = half_area(r.lo, r.hi);
        r.cost = COST_TRI * a;
        r.stat = a;
        r.height = 0;
    } else {
        const INode* m = nodes + c;
        r.lo = make_float3(__ldcg(&m->lo[0]), __ldcg(&m->lo[1]), __ldcg(&m->lo[2]));
        r.hi = make_float3(__ldcg(&m->hi[0]), __ldcg(&m->hi[1]), __ldcg(&m->hi[2]));
        r.cost = __ldcg(&m->cost);
        r.stat = __ldcg(&m->stat);
        r.height = __ldcg(&m->shape) & ~LEAF_BIT;
    }
    return r;
}

extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_build_bottom_up(INode* nodes, const u32* __restrict__ leaf_parent,
                          const float4* __restrict__ boxes, const u32* __restrict__ values,
                          const u32* __restrict__ counters, u32 max_leaf) {
    const u32 n = counters[C_ACTIVE];
    const u32 j = blockIdx.x * BUILD_BLOCK + threadIdx.x;
    if (n < 2 || j >= n) return;
    u32 p = leaf_parent[j];
    while (p != NO_NODE) {
        __threadfence();
        if (atomicAdd(&nodes[p].visits, 1u) == 0) return;
        __threadfence();
        INode* m = nodes + p;
        const u32 left = __ldcg(&m->left), right = __ldcg(&m->right);
        ChildInfo a = child_info(left, nodes, boxes, values);
        ChildInfo b = child_info(right, nodes, boxes, values);
        float3 lo = make_float3(fminf(a.lo.x, b.lo.x), fminf(a.lo.y, b.lo.y), fminf(a.lo.z, b.lo.z));
        float3 hi = make_float3(fmaxf(a.hi.x, b.hi.x), fmaxf(a.hi.y, b.hi.y), fmaxf(a.hi.z, b.hi.z));
        const float area = half_area(lo, hi);
        const u32 count = __ldcg(&m->last) - __ldcg(&m->first) + 1;
        const float split = COST_NODE * area + a.cost + b.cost;
        const float as_leaf = COST_TRI * area * (float)count;
        const bool leaf = p != 0 && count <= max_leaf && as_leaf <= split;
        m->lo[0] = lo.x;
        m->lo[1] = lo.y;
        m->lo[2] = lo.z;
        m->hi[0] = hi.x;
        m->hi[1] = hi.y;
        m->hi[2] = hi.z;
        m->cost = leaf ? as_leaf : split;
        m->stat = leaf ? area * (float)count : area + a.stat + b.stat;
        m->shape = leaf ? LEAF_BIT : 1 + max(a.height, b.height);
        p = __ldcg(&m->parent);
    }
}

// ---------------------------------------------------------------------------------------------
// 6. Inner nodes that remain: not leaves, and not below a leaf. Only nodes of at most max_leaf
// triangles can be leaves, and counts grow towards the root, so the walk up stops early.

extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_build_mark(const INode* __restrict__ nodes, const u32* __restrict__ counters, u32 cap,
                     u32 max_leaf, u32* __restrict__ kept) {
    const u32 i = blockIdx.x * BUILD_BLOCK + threadIdx.x;
    if (i >= cap) return;
    const u32 n = counters[C_ACTIVE];
    u32 keep = 0;
    if (n >= 2 && i < n - 1 && !(nodes[i].shape & LEAF_BIT)) {
        keep = 1;
        u32 p = nodes[i].parent;
        while (p != NO_NODE && nodes[p].last - nodes[p].first + 1 <= max_leaf) {
            if (nodes[p].shape & LEAF_BIT) {
                keep = 0;
                break;
            }
            p = nodes[p].parent;
        }
    }
    kept[i] = keep;
}

// An exclusive prefix sum of `len` words in place, in tiles of SORT_TILE: tile sums, their scan
// (one block), then each tile's scan. `total` gets the sum.
extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_scan_reduce(const u32* __restrict__ v, u32 len, u32* __restrict__ sums) {
    const size_t base = (size_t)blockIdx.x * SORT_TILE;
    u32 s = 0;
    for (int k = 0; k < SORT_ITEMS; ++k) {
        size_t i = base + k * BUILD_BLOCK + threadIdx.x;
        if (i < len) s += v[i];
    }
    u32 total;
    block_exclusive_scan(s, total);
    if (threadIdx.x == 0) sums[blockIdx.x] = total;
}

extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_scan_sums(u32* __restrict__ sums, u32 tiles, u32* __restrict__ total) {
    u32 carry = 0;
    for (u32 base = 0; base < tiles; base += BUILD_BLOCK) {
        u32 i = base + threadIdx.x;
        u32 v = i < tiles ? sums[i] : 0;
        u32 s;
        u32 ex = block_exclusive_scan(v, s);
        if (i < tiles) sums[i] = carry + ex;
        carry += s;
    }
    if (threadIdx.x == 0) *total = carry;
}

extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_scan_down(u32* __restrict__ v, u32 len, const u32* __restrict__ sums) {
    // Each thread owns SORT_ITEMS consecutive words, so that the tile is scanned in order.
    const size_t base = (size_t)blockIdx.x * SORT_TILE + (size_t)threadIdx.x * SORT_ITEMS;
    u32 x[SORT_ITEMS];
    u32 s = 0;
    for (int k = 0; k < SORT_ITEMS; ++k) {
        x[k] = base + k < len ? v[base + k] : 0;
        s += x[k];
    }
    u32 total;
    u32 run = sums[blockIdx.x] + block_exclusive_scan(s, total);
    for (int k = 0; k < SORT_ITEMS; ++k) {
        if (base + k < len) v[base + k] = run;
        run += x[k];
    }
}

// ---------------------------------------------------------------------------------------------
// 7. The output layout (`layout.rs`): node k holds its two children's boxes as rows
// (c0.lo.x, c0.hi.x, c0.lo.y, c0.hi.y), (c1.lo.x, c1.hi.x, c1.lo.y, c1.hi.y),
// (c0.lo.z, c0.hi.z, c1.lo.z, c1.hi.z) and the links (child0, child1, count0, count1): an inner
// child's node index with count 0, or a leaf's first slot and count.

struct OutChild {
    float3 lo, hi;
    u32 link, count;
};

__device__ __forceinline__ OutChild out_child(u32 c, const INode* nodes, const float4* boxes,
                                              const u32* values, const u32* index) {
    OutChild r;
    if (c & LEAF_BIT) {
        const u32 s = c & ~LEAF_BIT;
        const u32 g = values[s];
        float4 lo = boxes[2 * (size_t)g], hi = boxes[2 * (size_t)g + 1];
        r.lo = make_float3(lo.x, lo.y, lo.z);
        r.hi = make_float3(hi.x, hi.y, hi.z);
        r.link = s;
        r.count = 1;
    } else {
        const INode& m = nodes[c];
        r.lo = make_float3(m.lo[0], m.lo[1], m.lo[2]);
        r.hi = make_float3(m.hi[0], m.hi[1], m.hi[2]);
        if (m.shape & LEAF_BIT) {
            r.link = m.first;
            r.count = m.last - m.first + 1;
        } else {
            r.link = index[c];
            r.count = 0;
        }
    }
    return r;
}

__device__ __forceinline__ void write_node(float4* out, const OutChild& a, const OutChild& b) {
    out[0] = make_float4(a.lo.x, a.hi.x, a.lo.y, a.hi.y);
    out[1] = make_float4(b.lo.x, b.hi.x, b.lo.y, b.hi.y);
    out[2] = make_float4(a.lo.z, a.hi.z, b.lo.z, b.hi.z);
    out[3] = make_float4(__uint_as_float(a.link), __uint_as_float(b.link),
                         __uint_as_float(a.count), __uint_as_float(b.count));
}

// Threads 0 .. n_act - 1 (at least one): each kept inner node's device node. With fewer than two
// active triangles, node 0 is a root with at most one (leaf) child.
extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_build_write_nodes(const INode* __restrict__ nodes, const u32* __restrict__ kept,
                            const u32* __restrict__ index, const float4* __restrict__ boxes,
                            const u32* __restrict__ values, const u32* __restrict__ counters,
                            float4* __restrict__ out) {
    const u32 n = counters[C_ACTIVE];
    const u32 i = blockIdx.x * BUILD_BLOCK + threadIdx.x;
    OutChild unused;
    unused.lo = make_float3(F32_INF, F32_INF, F32_INF);
    unused.hi = make_float3(-F32_INF, -F32_INF, -F32_INF);
    unused.link = NO_NODE;
    unused.count = 0;
    if (n < 2) {
        if (i != 0) return;
        write_node(out, n == 1 ? out_child(0 | LEAF_BIT, nodes, boxes, values, index) : unused,
                   unused);
        return;
    }
    if (i >= n - 1 || !kept[i]) return;
    const INode& m = nodes[i];
    write_node(out + 4 * (size_t)index[i], out_child(m.left, nodes, boxes, values, index),
               out_child(m.right, nodes, boxes, values, index));
}

// One thread per leaf slot: the triangle's vertices as three float4 (w = 0); NaN for an
// inactive triangle an updatable build keeps (its box is empty), as oxray_refit_triangles
// writes it, so that no ray hits it until an update makes it active.
extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_build_write_triangles(const InputDesc* __restrict__ in, u32 n_in,
                                const u32* __restrict__ values, const float4* __restrict__ boxes,
                                u32 n_act, float4* __restrict__ out) {
    const u32 s = blockIdx.x * BUILD_BLOCK + threadIdx.x;
    if (s >= n_act) return;
    const u32 g = values[s];
    if (!(boxes[2 * (size_t)g].x <= boxes[2 * (size_t)g + 1].x)) {
        const float nan = __int_as_float(0x7fc00000);
        for (int k = 0; k < 3; ++k) out[3 * (size_t)s + k] = make_float4(nan, nan, nan, 0.0f);
        return;
    }
    float3 p[3];
    fetch(in, n_in, g, p);
    for (int k = 0; k < 3; ++k) out[3 * (size_t)s + k] = make_float4(p[k].x, p[k].y, p[k].z, 0.0f);
}

// The boxes of a custom-primitive GAS in leaf-slot order: 2 float4 per slot (lower corner, 0,
// upper corner, 0), the layout the pipelines' traversal reads: the bounds kernel's boxes, in
// which an inactive primitive's is empty.
extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_build_write_aabbs(const float4* __restrict__ boxes, const u32* __restrict__ values,
                            u32 n_act, float4* __restrict__ out) {
    const u32 s = blockIdx.x * BUILD_BLOCK + threadIdx.x;
    if (s >= n_act) return;
    const size_t g = values[s];
    out[2 * (size_t)s] = boxes[2 * g];
    out[2 * (size_t)s + 1] = boxes[2 * g + 1];
}

// 8. The height of every written node (1 for a node whose children are leaves), for the refit
// of an updatable build: a node's inner children are lower, so refitting by increasing height
// finishes every child before its parent.
extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_build_heights(const INode* __restrict__ nodes, const u32* __restrict__ kept,
                        const u32* __restrict__ index, const u32* __restrict__ counters,
                        u32* __restrict__ out) {
    const u32 n = counters[C_ACTIVE];
    const u32 i = blockIdx.x * BUILD_BLOCK + threadIdx.x;
    if (n < 2) {
        if (i == 0) out[0] = 1;
        return;
    }
    if (i >= n - 1 || !kept[i]) return;
    out[index[i]] = nodes[i].shape & ~LEAF_BIT;
}

// ---------------------------------------------------------------------------------------------
// Updates (refits, guide §5.6) of a GAS in the binary layout: the same tree and slots, new
// primitives. `src/refit.rs` launches them.
//
//   oxray_refit_triangles  per leaf slot: its triangle fetched again from the inputs, written as
//                          the layout's three float4, NaN where the CPU's degeneracy rule makes
//                          it inactive (no ray hits NaN), as `GasData::update` writes it.
//   oxray_refit_nodes      one launch per level of the tree, children's levels first, one thread
//                          per node: a leaf child's box from its slots, an inner child's as the
//                          union of that node's two boxes (written by an earlier launch).
//                          fminf / fmaxf skip NaN, so inactive triangles add nothing, as on the
//                          CPU.
//   oxray_refit_nodes4     the same over the BVH4 layout's 4-wide nodes.

extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_refit_triangles(const InputDesc* __restrict__ in, u32 n_in,
                          const u32* __restrict__ slot_prim, u32 n_slots,
                          float4* __restrict__ out) {
    const u32 s = blockIdx.x * BUILD_BLOCK + threadIdx.x;
    if (s >= n_slots) return;
    const u32 g = slot_prim[s];
    if (g == NO_NODE) return;
    float3 p[3];
    fetch(in, n_in, g, p);
    if (degenerate(p)) {
        const float nan = __int_as_float(0x7fc00000);
        for (int k = 0; k < 3; ++k) out[3 * (size_t)s + k] = make_float4(nan, nan, nan, 0.0f);
    } else {
        for (int k = 0; k < 3; ++k)
            out[3 * (size_t)s + k] = make_float4(p[k].x, p[k].y, p[k].z, 0.0f);
    }
}

// The box of leaf slots first .. first + n: triangles (3 float4 each) or boxes (2 float4).
__device__ __forceinline__ void slot_bounds(const float4* __restrict__ prims, u32 first, u32 n,
                                            u32 triangles, float lo[3], float hi[3]) {
    for (u32 s = first; s < first + n; ++s) {
        if (triangles) {
            for (int v = 0; v < 3; ++v) {
                const float4 p = prims[3 * (size_t)s + v];
                lo[0] = fminf(lo[0], p.x);
                lo[1] = fminf(lo[1], p.y);
                lo[2] = fminf(lo[2], p.z);
                hi[0] = fmaxf(hi[0], p.x);
                hi[1] = fmaxf(hi[1], p.y);
                hi[2] = fmaxf(hi[2], p.z);
            }
        } else {
            const float4 a = prims[2 * (size_t)s], b = prims[2 * (size_t)s + 1];
            lo[0] = fminf(lo[0], a.x);
            lo[1] = fminf(lo[1], a.y);
            lo[2] = fminf(lo[2], a.z);
            hi[0] = fmaxf(hi[0], b.x);
            hi[1] = fmaxf(hi[1], b.y);
            hi[2] = fmaxf(hi[2], b.z);
        }
    }
}

extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_refit_nodes(u32* __restrict__ nodes, const u32* __restrict__ order, u32 begin, u32 count,
                      const float4* __restrict__ prims, u32 triangles) {
    const u32 i = blockIdx.x * BUILD_BLOCK + threadIdx.x;
    if (i >= count) return;
    u32* w = nodes + 16 * (size_t)order[begin + i];
    float* f = reinterpret_cast<float*>(w);
    for (int k = 0; k < 2; ++k) {
        const u32 child = w[12 + k], n = w[14 + k];
        float lo[3] = {F32_INF, F32_INF, F32_INF};
        float hi[3] = {-F32_INF, -F32_INF, -F32_INF};
        if (n > 0) {
            slot_bounds(prims, child, n, triangles, lo, hi);
        } else if (child != NO_NODE) {
            const float* c = reinterpret_cast<const float*>(nodes + 16 * (size_t)child);
            lo[0] = fminf(c[0], c[4]);
            hi[0] = fmaxf(c[1], c[5]);
            lo[1] = fminf(c[2], c[6]);
            hi[1] = fmaxf(c[3], c[7]);
            lo[2] = fminf(c[8], c[10]);
            hi[2] = fmaxf(c[9], c[11]);
        } else {
            continue;
        }
        // Rows: l0.x h0.x l0.y h0.y | l1.x h1.x l1.y h1.y | l0.z h0.z l1.z h1.z (layout.rs).
        f[4 * k] = lo[0];
        f[4 * k + 1] = hi[0];
        f[4 * k + 2] = lo[1];
        f[4 * k + 3] = hi[1];
        f[8 + 2 * k] = lo[2];
        f[9 + 2 * k] = hi[2];
    }
}

// The same for the BVH4 layout (`layout.rs`: the CPU's 4-wide nodes, `oxray_bvh::Bvh4Node`,
// 32 words: rows of four lanes for lower x, y, z and upper x, y, z, then the four children and
// the four counts; an unused lane has child NO_NODE and count 0), whose leaves are triangles.
extern "C" __global__ void __launch_bounds__(BUILD_BLOCK)
    oxray_refit_nodes4(u32* __restrict__ nodes, const u32* __restrict__ order, u32 begin, u32 count,
                       const float4* __restrict__ prims) {
    const u32 i = blockIdx.x * BUILD_BLOCK + threadIdx.x;
    if (i >= count) return;
    u32* w = nodes + 32 * (size_t)order[begin + i];
    float* f = reinterpret_cast<float*>(w);
    for (int k = 0; k < 4; ++k) {
        const u32 child = w[24 + k], n = w[28 + k];
        float lo[3] = {F32_INF, F32_INF, F32_INF};
        float hi[3] = {-F32_INF, -F32_INF, -F32_INF};
        if (n > 0) {
            slot_bounds(prims, child, n, 1, lo, hi);
        } else if (child != NO_NODE) {
            const float* c = reinterpret_cast<const float*>(nodes + 32 * (size_t)child);
            for (int a = 0; a < 3; ++a) {
                for (int l = 0; l < 4; ++l) {
                    lo[a] = fminf(lo[a], c[4 * a + l]);
                    hi[a] = fmaxf(hi[a], c[4 * (3 + a) + l]);
                }
            }
        } else {
            continue;
        }
        for (int a = 0; a < 3; ++a) {
            f[4 * a + k] = lo[a];
            f[4 * (3 + a) + k] = hi[a];
        }
    }
}
