// Programs of the third set of CUDA C++ twins of the Rust-closure pipeline tests (oxray/tests/
// conformance_twins3.rs: exceptions, payload length, attributes and hit kinds, SBT layouts, the
// single any-hit call, callables, the transform list, launch indices and the functions that do
// not return), run on every device: the CPU (compiled by the host's C++ compiler) and CUDA. One
// ray per launch index, described by a `RayIn` record; the programs write into that launch
// index's record of `T3_WORDS` words:
//   words 0-31   the payload after the trace (written by the ray-generation program),
//   word 32      1 if the trace returned to the ray-generation program,
//   word 33      the number of notes,
//   word 36      1 if code after a throw in the ray-generation program ran,
//   word 37      1 if the ray-generation program finished,
//   words 40-    notes: words the programs write for the test to read.
#include <optix.h>

#define T3_WORDS 256u
#define T3_NOTES_AT 40u
#define T3_NOTES 216u

struct RayIn {
    float ox, oy, oz, dx, dy, dz;
    float tmin, tmax;
    unsigned int flags, sbt_offset, sbt_stride, miss_index;
    unsigned int npayload;  // payload words passed to optixTrace: 0, 1, 2, 4, 5, 8 or 32
    unsigned int pad[3];
    unsigned int payload[32];
};

struct T3Params {
    unsigned int* out;
    OptixTraversableHandle handle;
    const RayIn* rays;
    const float* aux;  // per scenario: the tops of custom primitives' boxes, or whole boxes
    unsigned int mode;
    unsigned int pad;
};

extern "C" __constant__ T3Params t3;

static __forceinline__ __device__ unsigned int t3_index() {
    const uint3 i = optixGetLaunchIndex();
    const uint3 d = optixGetLaunchDimensions();
    return (i.z * d.y + i.y) * d.x + i.x;
}

static __forceinline__ __device__ unsigned int* t3_record() {
    return t3.out + T3_WORDS * t3_index();
}

static __forceinline__ __device__ void t3_clear() {
    unsigned int* o = t3_record();
    for (unsigned int k = 32u; k < T3_WORDS; ++k) o[k] = 0u;
}

static __forceinline__ __device__ void t3_note(unsigned int w) {
    unsigned int* o = t3_record();
    const unsigned int n = o[33];
    if (n < T3_NOTES) o[T3_NOTES_AT + n] = w;
    o[33] = n + 1u;
}

static __forceinline__ __device__ void t3_note_f(float f) { t3_note(__float_as_uint(f)); }

static __forceinline__ __device__ unsigned int t3_data(unsigned int k) {
    return reinterpret_cast<const unsigned int*>(optixGetSbtDataPointer())[k];
}

#define T3_P8(p) p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7]
#define T3_P32(p)                                                                               \
    T3_P8(p), p[8], p[9], p[10], p[11], p[12], p[13], p[14], p[15], p[16], p[17], p[18], p[19], \
        p[20], p[21], p[22], p[23], p[24], p[25], p[26], p[27], p[28], p[29], p[30], p[31]

// The ray of this launch index, with its `npayload` payload words.
extern "C" __global__ void __raygen__t3() {
    t3_clear();
    unsigned int* o = t3_record();
    const RayIn r = t3.rays[t3_index()];
    unsigned int p[32];
    for (int k = 0; k < 32; ++k) p[k] = r.payload[k];
    const float3 org = make_float3(r.ox, r.oy, r.oz);
    const float3 dir = make_float3(r.dx, r.dy, r.dz);
#define T3_RAY                                                                                 \
    t3.handle, org, dir, r.tmin, r.tmax, 0.0f, 0xFFu, r.flags, r.sbt_offset, r.sbt_stride,     \
        r.miss_index
    switch (r.npayload) {
        case 0u: optixTrace(T3_RAY); break;
        case 1u: optixTrace(T3_RAY, p[0]); break;
        case 2u: optixTrace(T3_RAY, p[0], p[1]); break;
        case 4u: optixTrace(T3_RAY, p[0], p[1], p[2], p[3]); break;
        case 5u: optixTrace(T3_RAY, p[0], p[1], p[2], p[3], p[4]); break;
        case 32u: optixTrace(T3_RAY, T3_P32(p)); break;
        default: optixTrace(T3_RAY, T3_P8(p)); break;
    }
#undef T3_RAY
    for (int k = 0; k < 32; ++k) o[k] = p[k];
    o[32] = 1u;
}

// The top face of the current custom primitive's box along a ray down -z (`aux`: the tops).
static __forceinline__ __device__ float t3_top_t() {
    return (optixGetObjectRayOrigin().z - t3.aux[optixGetPrimitiveIndex()]) /
           -optixGetObjectRayDirection().z;
}

// ----------------------------------------------------------------------------------------------
// Logging programs: each notes its tag and (hit programs) the primitive index
// ----------------------------------------------------------------------------------------------

extern "C" __global__ void __closesthit__log() {
    t3_note(0xC0u);
    t3_note(optixGetPrimitiveIndex());
}
extern "C" __global__ void __anyhit__log() {
    t3_note(0xA0u);
    t3_note(optixGetPrimitiveIndex());
}
extern "C" __global__ void __miss__log() { t3_note(0x40u); }
// Reports the top face of the box (kind 0).
extern "C" __global__ void __intersection__top() {
    t3_note(0x15u);
    t3_note(optixGetPrimitiveIndex());
    optixReportIntersection(t3_top_t(), 0u);
}

// Notes 0xE0, the code, the 8 detail words and the launch index's x.
extern "C" __global__ void __exception__note() {
    t3_note(0xE0u);
    t3_note(static_cast<unsigned int>(optixGetExceptionCode()));
    t3_note(optixGetExceptionDetail_0());
    t3_note(optixGetExceptionDetail_1());
    t3_note(optixGetExceptionDetail_2());
    t3_note(optixGetExceptionDetail_3());
    t3_note(optixGetExceptionDetail_4());
    t3_note(optixGetExceptionDetail_5());
    t3_note(optixGetExceptionDetail_6());
    t3_note(optixGetExceptionDetail_7());
    t3_note(optixGetLaunchIndex().x);
}

// ----------------------------------------------------------------------------------------------
// User exceptions from the ray-generation program (guide §13.14)
// ----------------------------------------------------------------------------------------------

// `t3.mode` 0: index i throws code 100 + i with i details 0x100 i + j; 1: index i throws the
// i-th code of {0, 2^30 - 1, -2, 2^30, INT_MIN}; 2: a 16 x 16 launch where (7x + y) % 5 == 0
// throws code i with details x, y; 3: a 40 x 30 x 2 launch where x % 3 == 1 (not in the first
// row of the first slice) throws code i with detail i. Word 36: code after a throw ran; word
// 37: the program finished.
extern "C" __global__ void __raygen__throws() {
    t3_clear();
    unsigned int* o = t3_record();
    const unsigned int i = t3_index();
    const uint3 l = optixGetLaunchIndex();
    const unsigned int b = 0x100u * i;
    bool threw = false;
    switch (t3.mode) {
        case 0u:
            switch (i) {
                case 0u: optixThrowException(100); threw = true; break;
                case 1u: optixThrowException(101, b); threw = true; break;
                case 2u: optixThrowException(102, b, b + 1u); threw = true; break;
                case 3u: optixThrowException(103, b, b + 1u, b + 2u); threw = true; break;
                case 4u: optixThrowException(104, b, b + 1u, b + 2u, b + 3u); threw = true; break;
                case 5u:
                    optixThrowException(105, b, b + 1u, b + 2u, b + 3u, b + 4u);
                    threw = true;
                    break;
                case 6u:
                    optixThrowException(106, b, b + 1u, b + 2u, b + 3u, b + 4u, b + 5u);
                    threw = true;
                    break;
                case 7u:
                    optixThrowException(107, b, b + 1u, b + 2u, b + 3u, b + 4u, b + 5u, b + 6u);
                    threw = true;
                    break;
                case 8u:
                    optixThrowException(108, b, b + 1u, b + 2u, b + 3u, b + 4u, b + 5u, b + 6u,
                                        b + 7u);
                    threw = true;
                    break;
                default: break;
            }
            break;
        case 1u: {
            const int codes[5] = {0, (1 << 30) - 1, -2, 1 << 30, (int)0x80000000u};
            if (i < 5u) {
                optixThrowException(codes[i]);
                threw = true;
            }
            break;
        }
        case 2u:
            if ((l.x * 7u + l.y) % 5u == 0u) {
                optixThrowException((int)i, l.x, l.y);
                threw = true;
            }
            break;
        default:
            if (l.x % 3u == 1u && (l.y > 0u || l.z > 0u)) {
                optixThrowException((int)i, i);
                threw = true;
            }
            break;
    }
    if (threw) o[36] = 1u;
    o[37] = 1u;
}

// ----------------------------------------------------------------------------------------------
// User exceptions from every program kind (§13.14): payload word 0 says which program throws
// (1 intersection, 2 any-hit, 3 closest-hit; the miss program always throws). 0xAF7E: code
// after a throw ran.
// ----------------------------------------------------------------------------------------------

extern "C" __global__ void __intersection__throw() {
    t3_note(0x15u);
    t3_note(optixGetPrimitiveIndex());
    if (optixGetPayload_0() == 1u) {
        optixThrowException(1, optixGetPrimitiveIndex());
        t3_note(0xAF7Eu);
    }
    optixReportIntersection(t3_top_t(), 0u);
}
extern "C" __global__ void __anyhit__throw() {
    t3_note(0xA0u);
    t3_note(optixGetPrimitiveIndex());
    if (optixGetPayload_0() == 2u) {
        optixThrowException(2, 7u);
        t3_note(0xAF7Eu);
    }
}
extern "C" __global__ void __closesthit__throw() {
    t3_note(0xC0u);
    t3_note(optixGetPrimitiveIndex());
    if (optixGetPayload_0() == 3u) {
        optixThrowException(3, 8u, 9u);
        t3_note(0xAF7Eu);
    }
}
extern "C" __global__ void __miss__throw() {
    t3_note(0x40u);
    optixThrowException(4);
    t3_note(0xAF7Eu);
}

// A nested trace of the null handle whose miss program throws 77 [1, 2, 3]: notes 0xC0, then
// 0xAF7E if the nested trace returned.
extern "C" __global__ void __closesthit__nest_null() {
    t3_note(0xC0u);
    unsigned int n0 = 0u;
    optixTrace(0ull, make_float3(0.0f, 0.0f, 0.0f), make_float3(1.0f, 0.0f, 0.0f), 0.0f, 1e30f,
               0.0f, 0xFFu, 0u, 0u, 1u, 1u, n0);
    t3_note(0xAF7Eu);
}
extern "C" __global__ void __miss__throw77() { optixThrowException(77, 1u, 2u, 3u); }

// ----------------------------------------------------------------------------------------------
// Attributes, barycentrics, hit kinds and instance queries (§13.4, §13.7)
// ----------------------------------------------------------------------------------------------

// Reports the top face with attributes 11..18.
extern "C" __global__ void __intersection__attrs8() {
    optixReportIntersection(t3_top_t(), 0u, 11u, 12u, 13u, 14u, 15u, 16u, 17u, 18u);
}

static __forceinline__ __device__ void t3_attrs(unsigned int tag) {
    t3_note(tag);
    t3_note(optixGetAttribute_0());
    t3_note(optixGetAttribute_1());
    t3_note(optixGetAttribute_2());
    t3_note(optixGetAttribute_3());
    t3_note(optixGetAttribute_4());
    t3_note(optixGetAttribute_5());
    t3_note(optixGetAttribute_6());
    t3_note(optixGetAttribute_7());
}
extern "C" __global__ void __anyhit__attrs8() { t3_attrs(0xA0u); }
extern "C" __global__ void __closesthit__attrs8() { t3_attrs(0xC0u); }

// Notes tag, u, v and whether they are attributes 0 and 1 bit for bit.
static __forceinline__ __device__ void t3_bary(unsigned int tag) {
    const float2 b = optixGetTriangleBarycentrics();
    t3_note(tag);
    t3_note_f(b.x);
    t3_note_f(b.y);
    t3_note(__float_as_uint(b.x) == optixGetAttribute_0() &&
                    __float_as_uint(b.y) == optixGetAttribute_1()
                ? 1u
                : 0u);
}
extern "C" __global__ void __anyhit__bary() { t3_bary(0xA0u); }
// Also sets payload words 0-2 to u, v and tmax.
extern "C" __global__ void __closesthit__bary() {
    t3_bary(0xC0u);
    const float2 b = optixGetTriangleBarycentrics();
    optixSetPayload_0(__float_as_uint(b.x));
    optixSetPayload_1(__float_as_uint(b.y));
    optixSetPayload_2(__float_as_uint(optixGetRayTmax()));
}

static __forceinline__ __device__ void t3_face(unsigned int tag) {
    t3_note(tag);
    t3_note(optixGetHitKind());
    t3_note(optixIsTriangleHit() ? 1u : 0u);
    t3_note(optixIsFrontFaceHit() ? 1u : 0u);
    t3_note(optixIsBackFaceHit() ? 1u : 0u);
}
extern "C" __global__ void __anyhit__face() { t3_face(0xA0u); }
extern "C" __global__ void __closesthit__face() { t3_face(0xC0u); }

// Notes the primitive index and the SBT-GAS index; reports nothing.
extern "C" __global__ void __intersection__who() {
    t3_note(optixGetPrimitiveIndex());
    t3_note(optixGetSbtGASIndex());
}

// Reports the top face of the box (kind 0), noting nothing.
extern "C" __global__ void __intersection__quiet() { optixReportIntersection(t3_top_t(), 0u); }

extern "C" __global__ void __anyhit__inst() {
    t3_note(0xA0u);
    t3_note(optixGetInstanceId());
    t3_note(optixGetInstanceIndex());
}
extern "C" __global__ void __closesthit__inst() {
    t3_note(0xC0u);
    t3_note(optixGetInstanceId());
    t3_note(optixGetInstanceIndex());
}

// ----------------------------------------------------------------------------------------------
// The SBT (§7)
// ----------------------------------------------------------------------------------------------

// Payload: record data, SBT-GAS index, primitive index, 1 (hit).
extern "C" __global__ void __closesthit__record() {
    optixSetPayload_0(t3_data(0u));
    optixSetPayload_1(optixGetSbtGASIndex());
    optixSetPayload_2(optixGetPrimitiveIndex());
    optixSetPayload_3(1u);
}

// Payload: record data, 2 (miss) in word 3.
extern "C" __global__ void __miss__record() {
    optixSetPayload_0(t3_data(0u));
    optixSetPayload_3(2u);
}

// ----------------------------------------------------------------------------------------------
// REQUIRE_SINGLE_ANYHIT_CALL (§5.1): counts per (launch index, primitive) in `out` (t3.mode
// primitives per launch index: any-hit calls first, then intersection calls after all of them)
// ----------------------------------------------------------------------------------------------

extern "C" __global__ void __raygen__count() {
    const RayIn r = t3.rays[t3_index()];
    optixTrace(t3.handle, make_float3(r.ox, r.oy, r.oz), make_float3(r.dx, r.dy, r.dz), r.tmin,
               r.tmax, 0.0f, 0xFFu, 0u, 0u, 1u, 0u);
}

static __forceinline__ __device__ unsigned int t3_count_slot() {
    return t3_index() * t3.mode + optixGetPrimitiveIndex();
}

extern "C" __global__ void __anyhit__count() {
    atomicAdd(t3.out + t3_count_slot(), 1u);
    optixIgnoreIntersection();
}

// Reports the entry into the primitive's box (`aux`: min and max corners, 6 floats a box).
extern "C" __global__ void __intersection__box_entry() {
    const uint3 d = optixGetLaunchDimensions();
    atomicAdd(t3.out + d.x * t3.mode + t3_count_slot(), 1u);
    const float* b = t3.aux + 6u * optixGetPrimitiveIndex();
    const float3 o = optixGetObjectRayOrigin();
    const float3 dir = optixGetObjectRayDirection();
    const float ox[3] = {o.x, o.y, o.z};
    const float dx[3] = {dir.x, dir.y, dir.z};
    float t = optixGetRayTmin();
    for (int k = 0; k < 3; ++k) {
        const float t0 = (b[k] - ox[k]) / dx[k];
        const float t1 = (b[3 + k] - ox[k]) / dx[k];
        t = fmaxf(t, fminf(t0, t1));
    }
    optixReportIntersection(t, 0u);
}

// ----------------------------------------------------------------------------------------------
// Callables (§15): the scenario of callables.rs. `t3.mode` packs the record (bits 0-7) and how
// the ray-generation program calls it (bits 8-15: 0 direct (20, 22), 1 continuation (3.0), 2
// direct with the wrong types, 3 direct (0)); it writes the result and 1 to words 0 and 1, and
// 1 to word 32.
// ----------------------------------------------------------------------------------------------

extern "C" __global__ void __raygen__calls() {
    t3_clear();
    unsigned int* o = t3_record();
    const unsigned int record = t3.mode & 0xFFu;
    unsigned int r = 0u;
    switch (t3.mode >> 8) {
        case 0u: r = optixDirectCall<unsigned int>(record, 20u, 22u); break;
        case 1u: r = optixContinuationCall<unsigned int>(record, 3.0f); break;
        case 2u: r = __float_as_uint(optixDirectCall<float>(record, 1.0f)); break;
        default: r = optixDirectCall<unsigned int>(record, 0u); break;
    }
    o[0] = r;
    o[1] = 1u;
    o[32] = 1u;
}

// Record 0: adds its arguments and multiplies by its record's data.
extern "C" __device__ unsigned int __direct_callable__add(unsigned int a, unsigned int b) {
    return (a + b) * t3_data(0u);
}

// Record 1: traces from (0, 0, -z) up and returns the payload plus 100.
extern "C" __device__ unsigned int __continuation_callable__probe(float z) {
    unsigned int p0 = 0u;
    optixTrace(t3.handle, make_float3(0.0f, 0.0f, -z), make_float3(0.0f, 0.0f, 1.0f), 0.0f, 1e30f,
               0.0f, 0xFFu, 0u, 0u, 1u, 0u, p0);
    return p0 + 100u;
}

// Record 2: calls itself forever.
extern "C" __device__ unsigned int __direct_callable__recurse(unsigned int n) {
    return optixDirectCall<unsigned int>(2u, n + 1u);
}

// Sets payload 0 to the primitive + 1, then to what record 0 makes of (primitive + 1, 0).
extern "C" __global__ void __closesthit__call_add() {
    const unsigned int prim = optixGetPrimitiveIndex();
    optixSetPayload_0(prim + 1u);
    const unsigned int doubled = optixDirectCall<unsigned int>(0u, prim + 1u, 0u);
    optixSetPayload_0(doubled);
}

// ----------------------------------------------------------------------------------------------
// Callables that throw (§13.14, §15)
// ----------------------------------------------------------------------------------------------

// Notes 0xC0 and calls record 0 with 5; notes 0xAF7E and the result if the call returned.
extern "C" __global__ void __closesthit__call_throw() {
    t3_note(0xC0u);
    const unsigned int r = optixDirectCall<unsigned int>(0u, 5u);
    t3_note(0xAF7Eu);
    t3_note(r);
    optixSetPayload_0(r);
}
extern "C" __device__ unsigned int __direct_callable__throw13(unsigned int x) {
    optixThrowException(13, x);
    return x + 1u;
}

// Notes 0x96 and calls continuation callable record 0 with 3; notes 0xAF7E and the result if
// the call returned.
extern "C" __global__ void __raygen__cc_throw() {
    t3_clear();
    t3_note(0x96u);
    const unsigned int r = optixContinuationCall<unsigned int>(0u, 3u);
    t3_note(0xAF7Eu);
    t3_note(r);
}
extern "C" __device__ unsigned int __continuation_callable__throw14(unsigned int x) {
    optixThrowException(14, x);
    return x;
}

// Notes 0xA0 and the primitive and calls record 0 with the primitive index.
extern "C" __global__ void __anyhit__call_throw() {
    t3_note(0xA0u);
    t3_note(optixGetPrimitiveIndex());
    optixDirectCall<unsigned int>(0u, optixGetPrimitiveIndex());
    t3_note(0xAF7Eu);
}
extern "C" __device__ unsigned int __direct_callable__throw15(unsigned int x) {
    optixThrowException(15, x, t3_data(0u));
    return x;
}

// ----------------------------------------------------------------------------------------------
// The transform list (§13.11)
// ----------------------------------------------------------------------------------------------

// Notes tag, the list size, then per entry its type, instance id (0 for other types), the 12
// object-to-world words and whether the world-to-object matrix takes the point back (1) or not.
static __forceinline__ __device__ void t3_list(unsigned int tag) {
    t3_note(tag);
    const unsigned int n = optixGetTransformListSize();
    t3_note(n);
    for (unsigned int k = 0u; k < n; ++k) {
        const OptixTraversableHandle h = optixGetTransformListHandle(k);
        const OptixTransformType type = optixGetTransformTypeFromHandle(h);
        t3_note((unsigned int)type);
        float m[12], w[12];
        if (type == OPTIX_TRANSFORM_TYPE_INSTANCE) {
            t3_note(optixGetInstanceIdFromHandle(h));
            const float4* o2w = optixGetInstanceTransformFromHandle(h);
            const float4* w2o = optixGetInstanceInverseTransformFromHandle(h);
            for (int r = 0; r < 3; ++r) {
                m[4 * r] = o2w[r].x;
                m[4 * r + 1] = o2w[r].y;
                m[4 * r + 2] = o2w[r].z;
                m[4 * r + 3] = o2w[r].w;
                w[4 * r] = w2o[r].x;
                w[4 * r + 1] = w2o[r].y;
                w[4 * r + 2] = w2o[r].z;
                w[4 * r + 3] = w2o[r].w;
            }
        } else {
            t3_note(0u);
            const OptixStaticTransform* s = optixGetStaticTransformFromHandle(h);
            for (int j = 0; j < 12; ++j) {
                m[j] = s->transform[j];
                w[j] = s->invTransform[j];
            }
        }
        for (int j = 0; j < 12; ++j) t3_note_f(m[j]);
        const float p[3] = {0.3f, -0.2f, 0.7f};
        float q[3], back[3];
        for (int r = 0; r < 3; ++r) {
            q[r] = m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3];
        }
        for (int r = 0; r < 3; ++r) {
            back[r] = w[4 * r] * q[0] + w[4 * r + 1] * q[1] + w[4 * r + 2] * q[2] + w[4 * r + 3];
        }
        float e = 0.0f;
        for (int r = 0; r < 3; ++r) e += (back[r] - p[r]) * (back[r] - p[r]);
        t3_note(e < 1e-12f ? 1u : 0u);
    }
}
extern "C" __global__ void __anyhit__list() { t3_list(0xA0u); }
// Also sets payload word 0 to 1 and notes the nearest instance's id and index.
extern "C" __global__ void __closesthit__list() {
    t3_list(0xC0u);
    t3_note(optixGetInstanceId());
    t3_note(optixGetInstanceIndex());
    optixSetPayload_0(1u);
}

// ----------------------------------------------------------------------------------------------
// Launch indices (§10, §13.1): counts the runs of each linear index in `out`; the word after
// them counts indices outside the launch.
// ----------------------------------------------------------------------------------------------

extern "C" __global__ void __raygen__count_index() {
    const uint3 i = optixGetLaunchIndex();
    const uint3 d = optixGetLaunchDimensions();
    if (i.x >= d.x || i.y >= d.y || i.z >= d.z) {
        atomicAdd(t3.out + (unsigned long long)d.x * d.y * d.z, 1u);
        return;
    }
    atomicAdd(t3.out + (i.z * d.y + i.y) * d.x + i.x, 1u);
}

// ----------------------------------------------------------------------------------------------
// Functions that do not return (§13.13, §13.14)
// ----------------------------------------------------------------------------------------------

// Ignores, then terminates: the first call wins (on CUDA, where the calls return, the first one
// takes effect).
extern "C" __global__ void __anyhit__ignore_terminate() {
    t3_note(0xA0u);
    t3_note(optixGetPrimitiveIndex());
    optixIgnoreIntersection();
    optixTerminateRay();
}
// Notes 0x40 and sets payload word 1 to 7.
extern "C" __global__ void __miss__note7() {
    t3_note(0x40u);
    optixSetPayload_1(7u);
}
// Terminates, then ignores.
extern "C" __global__ void __anyhit__terminate_ignore() {
    t3_note(0xA0u);
    t3_note(optixGetPrimitiveIndex());
    optixTerminateRay();
    optixIgnoreIntersection();
}
// Throws 6 [2], then ignores.
extern "C" __global__ void __anyhit__throw_ignore() {
    t3_note(0xA0u);
    t3_note(optixGetPrimitiveIndex());
    optixThrowException(6, 2u);
    optixIgnoreIntersection();
}

// Reports at 10.5 (kind 1, attribute 11) and 9.5 (kind 2, attribute 22); after the reports
// notes 0xAF7E and their results.
extern "C" __global__ void __intersection__twice() {
    t3_note(0x15u);
    t3_note(optixGetPrimitiveIndex());
    const bool first = optixReportIntersection(10.5f, 1u, 11u);
    const bool second = optixReportIntersection(9.5f, 2u, 22u);
    t3_note(0xAF7Eu);
    t3_note(first ? 1u : 0u);
    t3_note(second ? 1u : 0u);
}
// Notes 0xA0, tmax, kind, attribute 0; adds 1 to payload word 0; terminates on kind 1.
extern "C" __global__ void __anyhit__terminate_kind1() {
    t3_note(0xA0u);
    t3_note_f(optixGetRayTmax());
    t3_note(optixGetHitKind());
    t3_note(optixGetAttribute_0());
    optixSetPayload_0(optixGetPayload_0() + 1u);
    if (optixGetHitKind() == 1u) optixTerminateRay();
}
// Notes 0xC0, tmax, kind, attribute 0.
extern "C" __global__ void __closesthit__t_kind_attr() {
    t3_note(0xC0u);
    t3_note_f(optixGetRayTmax());
    t3_note(optixGetHitKind());
    t3_note(optixGetAttribute_0());
}

// Ignores primitives 3 and up, terminates on the others; 0xAF7E after terminate.
extern "C" __global__ void __anyhit__pass_on() {
    t3_note(0xA0u);
    t3_note(optixGetPrimitiveIndex());
    if (optixGetPrimitiveIndex() >= 3u) {
        optixIgnoreIntersection();
        return;
    }
    optixTerminateRay();
    t3_note(0xAF7Eu);
}
