// Programs of the built-in primitive conformance scenarios (oxray/tests/conformance_builtins.rs):
// the pipeline scenarios of the conformance suite run with spheres and curves in place of
// triangles, on every device: the CPU (compiled by the host's C++ compiler) and CUDA. One ray per
// launch index, described by a `RayIn` record; every program logs what it saw into that launch
// index's record of `BI_WORDS` words:
//   words 0-7    the payload after the trace (written by the ray-generation program),
//   word 8       the number of events, word 10 = 1 if the trace returned to the ray-generation
//                program,
//   words 16-    events of 16 words: program (2 AH, 3 CH, 4 MS), primitive index, tmin, tmax,
//                hit kind, primitive type, curve parameter u, ribbon v, SBT-GAS index, record
//                data, instance id, instance index, facing (1 front, 2 back, 4 triangle),
//                object-space ray origin x and z, object-space ray direction z. A miss logs the
//                program, tmin, tmax and its record's data only.
#include <optix.h>

#define BI_WORDS 512u
#define BI_EVENTS 24u
#define BI_EVENT_WORDS 16u

struct RayIn {
    float ox, oy, oz, dx, dy, dz;
    float tmin, tmax;
    unsigned int mask, flags, sbt_offset, sbt_stride, miss_index;
    unsigned int payload[8];
    unsigned int pad[3];
};

struct BiParams {
    unsigned int* out;
    OptixTraversableHandle handle;
    const RayIn* rays;
};

extern "C" __constant__ BiParams bi;

static __forceinline__ __device__ unsigned int bi_index() {
    const uint3 i = optixGetLaunchIndex();
    const uint3 d = optixGetLaunchDimensions();
    return (i.z * d.y + i.y) * d.x + i.x;
}

static __forceinline__ __device__ unsigned int* bi_record() { return bi.out + BI_WORDS * bi_index(); }

static __forceinline__ __device__ unsigned int bi_data() {
    return *reinterpret_cast<const unsigned int*>(optixGetSbtDataPointer());
}

// The next event's words, or null once the record is full (the count still grows, so that the
// test sees the overflow).
static __forceinline__ __device__ unsigned int* bi_event(unsigned int prog) {
    unsigned int* o = bi_record();
    const unsigned int n = o[8];
    o[8] = n + 1u;
    if (n >= BI_EVENTS) return 0;
    unsigned int* e = o + 16u + BI_EVENT_WORDS * n;
    for (unsigned int k = 0u; k < BI_EVENT_WORDS; ++k) e[k] = 0u;
    e[0] = prog;
    e[2] = __float_as_uint(optixGetRayTmin());
    e[3] = __float_as_uint(optixGetRayTmax());
    return e;
}

// A hit's event: the curve parameter through the function of its type (guide §9.3); spheres
// have no attributes (§9.4).
static __forceinline__ __device__ void bi_hit_event(unsigned int prog) {
    unsigned int* e = bi_event(prog);
    if (!e) return;
    const unsigned int kind = optixGetHitKind();
    const OptixPrimitiveType type = optixGetPrimitiveType();
    e[1] = optixGetPrimitiveIndex();
    e[4] = kind;
    e[5] = (unsigned int)type;
    if (type == OPTIX_PRIMITIVE_TYPE_FLAT_QUADRATIC_BSPLINE) {
        const float2 uv = optixGetRibbonParameters();
        e[6] = __float_as_uint(uv.x);
        e[7] = __float_as_uint(uv.y);
    } else if (type != OPTIX_PRIMITIVE_TYPE_SPHERE) {
        e[6] = __float_as_uint(optixGetCurveParameter());
    }
    e[8] = optixGetSbtGASIndex();
    e[9] = bi_data();
    e[10] = optixGetInstanceId();
    e[11] = optixGetInstanceIndex();
    e[12] = (optixIsFrontFaceHit() ? 1u : 0u) | (optixIsBackFaceHit() ? 2u : 0u) |
            (optixIsTriangleHit() ? 4u : 0u);
    // The object-space ray (optixGetObjectRayOrigin is not available to closest-hit programs).
    const float3 o = optixTransformPointFromWorldToObjectSpace(optixGetWorldRayOrigin());
    const float3 d = optixTransformVectorFromWorldToObjectSpace(optixGetWorldRayDirection());
    e[13] = __float_as_uint(o.x);
    e[14] = __float_as_uint(o.z);
    e[15] = __float_as_uint(d.z);
}

// The ray of this launch index, with its 8 payload words.
extern "C" __global__ void __raygen__bi() {
    unsigned int* o = bi_record();
    for (unsigned int k = 8u; k < BI_WORDS; ++k) o[k] = 0u;
    const RayIn r = bi.rays[bi_index()];
    unsigned int p[8];
    for (int k = 0; k < 8; ++k) p[k] = r.payload[k];
    optixTrace(bi.handle, make_float3(r.ox, r.oy, r.oz), make_float3(r.dx, r.dy, r.dz), r.tmin,
               r.tmax, 0.0f, r.mask, r.flags, r.sbt_offset, r.sbt_stride, r.miss_index, p[0],
               p[1], p[2], p[3], p[4], p[5], p[6], p[7]);
    for (int k = 0; k < 8; ++k) o[k] = p[k];
    o[10] = 1u;
}

extern "C" __global__ void __closesthit__log() { bi_hit_event(3u); }
extern "C" __global__ void __anyhit__log() { bi_hit_event(2u); }

extern "C" __global__ void __miss__log() {
    unsigned int* e = bi_event(4u);
    if (e) e[9] = bi_data();
}

// Ends the traversal at the first candidate it sees (§13.13); payload word 4 is set by code after
// the call.
extern "C" __global__ void __anyhit__terminate() {
    bi_hit_event(2u);
    optixTerminateRay();
    optixSetPayload_4(0xAF7Eu);
}

// Ignores the primitives whose bit is set in payload word 7 (guide §13.13); payload word 3
// counts the times code after the call ran (never, where the call does not return).
extern "C" __global__ void __anyhit__ignore() {
    bi_hit_event(2u);
    const unsigned int prim = optixGetPrimitiveIndex();
    if (prim < 32u && ((optixGetPayload_7() >> prim) & 1u) != 0u) {
        optixIgnoreIntersection();
        optixSetPayload_3(optixGetPayload_3() + 1u);
    }
}

// Word 11 of the record: the exception code (no scenario expects one).
extern "C" __global__ void __exception__bi() {
    bi_record()[11] = static_cast<unsigned int>(optixGetExceptionCode());
}
