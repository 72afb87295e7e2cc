// Programs of the CUDA C++ twins of the Rust-closure pipeline tests (oxray/tests/
// conformance_twins.rs), run on every device: the CPU (compiled by the host's C++ compiler) and
// CUDA. One ray per launch index, described by a `RayIn` record; every program logs what it saw
// into that launch index's record of `TWIN_WORDS` words:
//   words 0-7    the payload after the trace (written by the ray-generation program),
//   word 8       the number of events, word 9 the number of notes, word 10 = 1 if the trace
//                returned to the ray-generation program,
//   words 16-    events of 8 words: program (1 IS, 2 AH, 3 CH, 4 MS), primitive index, tmin,
//                tmax, hit kind, attribute 0, attribute 1, instance id,
//   words 400-   notes: words some programs write for the test to read.
#include <optix.h>

#define TWIN_WORDS 512u
#define TWIN_EVENTS 48u
#define TWIN_NOTES_AT 400u
#define TWIN_NOTES 112u

struct RayIn {
    float ox, oy, oz, dx, dy, dz;
    float tmin, tmax, time;
    unsigned int mask, flags, sbt_offset, sbt_stride, miss_index;
    unsigned int payload[8];
    unsigned int pad[2];
};

struct TwinParams {
    unsigned int* out;
    OptixTraversableHandle handle;
    const RayIn* rays;
    const float* boxes;  // min x, y, z, max x, y, z of each custom primitive, by primitive index
};

extern "C" __constant__ TwinParams twin;

static __forceinline__ __device__ unsigned int twin_index() {
    const uint3 i = optixGetLaunchIndex();
    const uint3 d = optixGetLaunchDimensions();
    return (i.z * d.y + i.y) * d.x + i.x;
}

static __forceinline__ __device__ unsigned int* twin_record() {
    return twin.out + TWIN_WORDS * twin_index();
}

static __forceinline__ __device__ void twin_note(unsigned int w) {
    unsigned int* o = twin_record();
    const unsigned int n = o[9];
    if (n < TWIN_NOTES) o[TWIN_NOTES_AT + n] = w;
    o[9] = n + 1u;
}

static __forceinline__ __device__ void twin_event(unsigned int prog, unsigned int prim,
                                                  unsigned int kind, unsigned int a0,
                                                  unsigned int a1, unsigned int id) {
    unsigned int* o = twin_record();
    const unsigned int n = o[8];
    if (n < TWIN_EVENTS) {
        unsigned int* e = o + 16u + 8u * n;
        e[0] = prog;
        e[1] = prim;
        e[2] = __float_as_uint(optixGetRayTmin());
        e[3] = __float_as_uint(optixGetRayTmax());
        e[4] = kind;
        e[5] = a0;
        e[6] = a1;
        e[7] = id;
    }
    o[8] = n + 1u;
}

// A hit's event: triangles log their barycentrics as the attributes.
static __forceinline__ __device__ void twin_hit_event(unsigned int prog) {
    unsigned int a0, a1;
    if (optixIsTriangleHit()) {
        const float2 b = optixGetTriangleBarycentrics();
        a0 = __float_as_uint(b.x);
        a1 = __float_as_uint(b.y);
    } else {
        a0 = optixGetAttribute_0();
        a1 = optixGetAttribute_1();
    }
    twin_event(prog, optixGetPrimitiveIndex(), optixGetHitKind(), a0, a1, optixGetInstanceId());
}

static __forceinline__ __device__ void twin_is_event() {
    twin_event(1u, optixGetPrimitiveIndex(), 0u, 0u, 0u, 0u);
}

// The ray of this launch index, with its 8 payload words.
extern "C" __global__ void __raygen__twin() {
    unsigned int* o = twin_record();
    for (unsigned int k = 8u; k < TWIN_WORDS; ++k) o[k] = 0u;
    const RayIn r = twin.rays[twin_index()];
    unsigned int p[8];
    for (int k = 0; k < 8; ++k) p[k] = r.payload[k];
    optixTrace(twin.handle, make_float3(r.ox, r.oy, r.oz), make_float3(r.dx, r.dy, r.dz), r.tmin,
               r.tmax, r.time, r.mask, r.flags, r.sbt_offset, r.sbt_stride, r.miss_index, p[0],
               p[1], p[2], p[3], p[4], p[5], p[6], p[7]);
    for (int k = 0; k < 8; ++k) o[k] = p[k];
    o[10] = 1u;
}

// The top face of the box of the current primitive along the ray, for rays down -z.
static __forceinline__ __device__ float twin_top_t() {
    const float* b = twin.boxes + 6u * optixGetPrimitiveIndex();
    return (optixGetObjectRayOrigin().z - b[5]) / -optixGetObjectRayDirection().z;
}

// ----------------------------------------------------------------------------------------------
// Logging programs
// ----------------------------------------------------------------------------------------------

extern "C" __global__ void __closesthit__log() { twin_hit_event(3u); }
extern "C" __global__ void __anyhit__log() { twin_hit_event(2u); }
extern "C" __global__ void __miss__log() { twin_event(4u, ~0u, 0u, 0u, 0u, 0u); }

// Reports the top face of its box with hit kind 3 and attributes (primitive, 7); notes 0xAF7E
// after the report returns.
extern "C" __global__ void __intersection__top() {
    twin_is_event();
    optixReportIntersection(twin_top_t(), 3u, optixGetPrimitiveIndex(), 7u);
    twin_note(0xAF7Eu);
}

// Reports just below tmin, just above tmax, NaN, at tmax and at tmin (tmin, tmax > 0), noting
// what each report returns.
extern "C" __global__ void __intersection__edges() {
    const float tmin = optixGetRayTmin();
    const float tmax = optixGetRayTmax();
    const float ts[5] = {__uint_as_float(__float_as_uint(tmin) - 1u),
                         __uint_as_float(__float_as_uint(tmax) + 1u), __uint_as_float(0x7FC00000u),
                         tmax, tmin};
    for (int k = 0; k < 5; ++k) {
        twin_note(optixReportIntersection(ts[k], 1u, 0u, 0u) ? 1u : 0u);
    }
}

// Notes: primitive, tmin, tmax before, the far report's result, tmax between, the near report's
// result, tmax after.
extern "C" __global__ void __intersection__two() {
    twin_is_event();
    const float entry = twin_top_t();
    const float before = optixGetRayTmax();
    const bool far = optixReportIntersection(entry + 0.5f, 1u, 0u, 0u);
    const float mid = optixGetRayTmax();
    const bool near = optixReportIntersection(entry, 2u, 0u, 0u);
    const float after = optixGetRayTmax();
    twin_note(optixGetPrimitiveIndex());
    twin_note(__float_as_uint(optixGetRayTmin()));
    twin_note(__float_as_uint(before));
    twin_note(far ? 1u : 0u);
    twin_note(__float_as_uint(mid));
    twin_note(near ? 1u : 0u);
    twin_note(__float_as_uint(after));
}

// Two reports per box: 0.25 past the top (kind 1), then the top (kind 2); notes 0xAF7E between.
extern "C" __global__ void __intersection__two_reports() {
    twin_is_event();
    const float t = twin_top_t();
    optixReportIntersection(t + 0.25f, 1u, optixGetPrimitiveIndex(), 0u);
    twin_note(0xAF7Eu);
    optixReportIntersection(t, 2u, optixGetPrimitiveIndex(), 0u);
}

// Reports the centre of its box; notes tmax before, t and the report's result.
extern "C" __global__ void __intersection__centre() {
    const float* b = twin.boxes + 6u * optixGetPrimitiveIndex();
    const float before = optixGetRayTmax();
    const float t = optixGetObjectRayOrigin().z - 0.5f * (b[2] + b[5]);
    const bool r = optixReportIntersection(t, 0u, 0u, 0u);
    twin_note(__float_as_uint(before));
    twin_note(__float_as_uint(t));
    twin_note(r ? 1u : 0u);
}

// Writes payload 2 = 55, then reports the top face.
extern "C" __global__ void __intersection__write() {
    twin_is_event();
    optixSetPayload_2(55u);
    optixReportIntersection(twin_top_t(), 0u, 0u, 0u);
}

// Sets bit `primitive` of payload 0, then reports the top face.
extern "C" __global__ void __intersection__mark() {
    twin_is_event();
    optixSetPayload_0(optixGetPayload_0() | (1u << optixGetPrimitiveIndex()));
    optixReportIntersection(twin_top_t(), 0u, 0u, 0u);
}

// ----------------------------------------------------------------------------------------------
// Any-hit programs: ignore and terminate (guide §13.13)
// ----------------------------------------------------------------------------------------------

// Counts its calls in payload 0; ignores primitive 0 after writing payload 1 = 0xAB.
extern "C" __global__ void __anyhit__ignore_top() {
    twin_hit_event(2u);
    optixSetPayload_0(optixGetPayload_0() + 1u);
    if (optixGetPrimitiveIndex() == 0u) {
        optixSetPayload_1(0xABu);
        optixIgnoreIntersection();
    }
}

// Counts its calls in payload 2 and ignores every hit; the code after the ignore never runs.
extern "C" __global__ void __anyhit__ignore_all() {
    twin_hit_event(2u);
    optixSetPayload_2(optixGetPayload_2() + 1u);
    optixIgnoreIntersection();
    optixSetPayload_3(0xDEADu);
}

// Accepts primitive 2 and ends the traversal (payload 0 = 0x77); ignores the others.
extern "C" __global__ void __anyhit__terminate_bottom() {
    twin_hit_event(2u);
    if (optixGetPrimitiveIndex() == 2u) {
        optixSetPayload_0(0x77u);
        optixTerminateRay();
    }
    optixIgnoreIntersection();
}

// Accepts the first candidate and ends the traversal; the code after never runs.
extern "C" __global__ void __anyhit__terminate_first() {
    twin_hit_event(2u);
    optixTerminateRay();
    optixSetPayload_1(0xDEADu);
}

// Ignores every primitive but 3.
extern "C" __global__ void __anyhit__only_3() {
    twin_hit_event(2u);
    if (optixGetPrimitiveIndex() != 3u) optixIgnoreIntersection();
}

// Writes payload 1 = 77 and accepts.
extern "C" __global__ void __anyhit__write() {
    twin_hit_event(2u);
    optixSetPayload_1(77u);
}

// ----------------------------------------------------------------------------------------------
// Ray information (guide §13.5): 10 notes per program: the program, world origin and
// direction, flags, visibility mask and time.
// ----------------------------------------------------------------------------------------------

static __forceinline__ __device__ void twin_note_ray(unsigned int prog) {
    const float3 o = optixGetWorldRayOrigin();
    const float3 d = optixGetWorldRayDirection();
    twin_note(prog);
    twin_note(__float_as_uint(o.x));
    twin_note(__float_as_uint(o.y));
    twin_note(__float_as_uint(o.z));
    twin_note(__float_as_uint(d.x));
    twin_note(__float_as_uint(d.y));
    twin_note(__float_as_uint(d.z));
    twin_note(optixGetRayFlags());
    twin_note(optixGetRayVisibilityMask());
    twin_note(__float_as_uint(optixGetRayTime()));
}

extern "C" __global__ void __intersection__ray() {
    twin_note_ray(1u);
    optixReportIntersection(9.5f, 0u, 0u, 0u);
}
extern "C" __global__ void __anyhit__ray() { twin_note_ray(2u); }
extern "C" __global__ void __closesthit__ray() { twin_note_ray(3u); }
extern "C" __global__ void __miss__ray() { twin_note_ray(4u); }

// ----------------------------------------------------------------------------------------------
// Trace depth and exceptions (guide §13.14)
// ----------------------------------------------------------------------------------------------

// Recursion: payload 0 + 1 is the depth; notes 0xC000 + depth, traces the launch index's ray
// again with one payload word, then notes 0xC100 + depth (0xD000 / 0xD100 from the miss).
static __forceinline__ __device__ void twin_recurse(unsigned int tag) {
    const unsigned int depth = optixGetPayload_0() + 1u;
    optixSetPayload_0(depth);
    twin_note(tag + depth);
    const RayIn r = twin.rays[twin_index()];
    unsigned int p0 = depth;
    optixTrace(twin.handle, make_float3(r.ox, r.oy, r.oz), make_float3(r.dx, r.dy, r.dz), r.tmin,
               r.tmax, 0.0f, r.mask, r.flags, 0, 1, 0, p0);
    twin_note(tag + 0x100u + depth);
}

extern "C" __global__ void __closesthit__recurse() { twin_recurse(0xC000u); }
extern "C" __global__ void __miss__recurse() { twin_recurse(0xD000u); }

// Traces the null handle once: payload 0 = 1 + what the miss program returned.
extern "C" __global__ void __closesthit__once() {
    const RayIn r = twin.rays[twin_index()];
    unsigned int p0 = 0u;
    optixTrace(0ull, make_float3(r.ox, r.oy, r.oz), make_float3(r.dx, r.dy, r.dz), r.tmin, r.tmax,
               0.0f, r.mask, r.flags, 0, 1, 0, p0);
    optixSetPayload_0(1u + p0);
}

extern "C" __global__ void __miss__ten() { optixSetPayload_0(10u); }

// Notes 0xE7, the code, details 0 and 1 of a user exception (0 for a built-in one) and the
// launch index.
extern "C" __global__ void __exception__note() {
    const uint3 i = optixGetLaunchIndex();
    const int code = optixGetExceptionCode();
    twin_note(0xE7u);
    twin_note((unsigned int)code);
    twin_note(code >= 0 ? optixGetExceptionDetail_0() : 0u);
    twin_note(code >= 0 ? optixGetExceptionDetail_1() : 0u);
    twin_note(i.x);
    twin_note(i.y);
    twin_note(i.z);
}
