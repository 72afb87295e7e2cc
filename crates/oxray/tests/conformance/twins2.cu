// Programs of the second set of CUDA C++ twins of the Rust-closure pipeline tests (oxray/tests/
// conformance_twins2.rs: payload, reported intersections and the SBT), run on every device: the
// CPU (compiled by the host's C++ compiler) and CUDA. One ray per launch index, described by a
// `RayIn` record; the programs write into that launch index's record of `T2_WORDS` words:
//   words 0-7    the payload after the trace (written by the ray-generation program),
//   word 8       1 if the trace returned to the ray-generation program,
//   word 9       the number of notes,
//   words 16-    notes: words the programs write for the test to read.
#include <optix.h>

#define T2_WORDS 128u
#define T2_NOTES_AT 16u
#define T2_NOTES 112u

struct RayIn {
    float ox, oy, oz, dx, dy, dz;
    float tmin, tmax;
    unsigned int flags, sbt_offset, sbt_stride, miss_index;
    unsigned int payload[8];
};

struct T2Params {
    unsigned int* out;
    OptixTraversableHandle handle;
    const RayIn* rays;
    const float* tops;  // the top (max z) of each custom primitive's box, by primitive index
};

extern "C" __constant__ T2Params t2;

static __forceinline__ __device__ unsigned int t2_index() {
    const uint3 i = optixGetLaunchIndex();
    const uint3 d = optixGetLaunchDimensions();
    return (i.z * d.y + i.y) * d.x + i.x;
}

static __forceinline__ __device__ unsigned int* t2_record() { return t2.out + T2_WORDS * t2_index(); }

static __forceinline__ __device__ void t2_note(unsigned int w) {
    unsigned int* o = t2_record();
    const unsigned int n = o[9];
    if (n < T2_NOTES) o[T2_NOTES_AT + n] = w;
    o[9] = n + 1u;
}

static __forceinline__ __device__ void t2_note_f(float f) { t2_note(__float_as_uint(f)); }

static __forceinline__ __device__ unsigned int t2_data(unsigned int k) {
    return reinterpret_cast<const unsigned int*>(optixGetSbtDataPointer())[k];
}

// The ray of this launch index, with its 8 payload words.
extern "C" __global__ void __raygen__t2() {
    unsigned int* o = t2_record();
    for (unsigned int k = 8u; k < T2_WORDS; ++k) o[k] = 0u;
    const RayIn r = t2.rays[t2_index()];
    unsigned int p[8];
    for (int k = 0; k < 8; ++k) p[k] = r.payload[k];
    optixTrace(t2.handle, make_float3(r.ox, r.oy, r.oz), make_float3(r.dx, r.dy, r.dz), r.tmin,
               r.tmax, 0.0f, 0xFFu, r.flags, r.sbt_offset, r.sbt_stride, r.miss_index, p[0], p[1],
               p[2], p[3], p[4], p[5], p[6], p[7]);
    for (int k = 0; k < 8; ++k) o[k] = p[k];
    o[8] = 1u;
}

// The top face of the current custom primitive's box along a ray down -z.
static __forceinline__ __device__ float t2_top_t() {
    return (optixGetObjectRayOrigin().z - t2.tops[optixGetPrimitiveIndex()]) /
           -optixGetObjectRayDirection().z;
}

// ----------------------------------------------------------------------------------------------
// Payload words never set come back unchanged (guide §14)
// ----------------------------------------------------------------------------------------------

extern "C" __global__ void __intersection__set1() {
    optixSetPayload_1(11u);
    optixReportIntersection(t2_top_t(), 0u);
}
extern "C" __global__ void __anyhit__set2() { optixSetPayload_2(22u); }
extern "C" __global__ void __closesthit__set4() {
    optixSetPayload_4(44u);
    optixSetPayload_4(45u);
}
extern "C" __global__ void __miss__set3() { optixSetPayload_3(33u); }
// Sets nothing (a hit group needs a program on every device).
extern "C" __global__ void __closesthit__nothing() {}

// ----------------------------------------------------------------------------------------------
// A payload set is visible to later gets: IS -> AH -> CH, IS -> MS (§14)
// ----------------------------------------------------------------------------------------------

// Notes 1, the caller's word 5, word 0 after setting it.
extern "C" __global__ void __intersection__p() {
    const unsigned int caller = optixGetPayload_5();
    optixSetPayload_0(1000u + caller);
    t2_note(1u);
    t2_note(caller);
    t2_note(optixGetPayload_0());
    optixReportIntersection(t2_top_t(), 0u);
}

// Notes 2, words 0 and 5; sets word 1; ignores the hit if word 5 is 7.
extern "C" __global__ void __anyhit__p() {
    const unsigned int p0 = optixGetPayload_0();
    const unsigned int p5 = optixGetPayload_5();
    t2_note(2u);
    t2_note(p0);
    t2_note(p5);
    optixSetPayload_1(p0 + 1u);
    if (p5 == 7u) optixIgnoreIntersection();
}

// Notes 3, words 0, 1 and 5; sets word 2.
extern "C" __global__ void __closesthit__p() {
    const unsigned int p1 = optixGetPayload_1();
    t2_note(3u);
    t2_note(optixGetPayload_0());
    t2_note(p1);
    t2_note(optixGetPayload_5());
    optixSetPayload_2(p1 + 1u);
}

// Notes 4 and the 8 payload words.
extern "C" __global__ void __miss__p() {
    t2_note(4u);
    t2_note(optixGetPayload_0());
    t2_note(optixGetPayload_1());
    t2_note(optixGetPayload_2());
    t2_note(optixGetPayload_3());
    t2_note(optixGetPayload_4());
    t2_note(optixGetPayload_5());
    t2_note(optixGetPayload_6());
    t2_note(optixGetPayload_7());
}

// ----------------------------------------------------------------------------------------------
// Nested traces (§14, §13.5)
// ----------------------------------------------------------------------------------------------

// Traces a 4-word payload {9, 9, 9, 9} from (50, 50, 10) down with miss index 1; notes 0xC0,
// the outer words 0-3 and the nested words; sets outer word 3 to nested word 0.
extern "C" __global__ void __closesthit__nest() {
    unsigned int n0 = 9u, n1 = 9u, n2 = 9u, n3 = 9u;
    optixTrace(t2.handle, make_float3(50.0f, 50.0f, 10.0f), make_float3(0.0f, 0.0f, -1.0f), 0.0f,
               1e30f, 0.0f, 0xFFu, 0u, 0u, 1u, 1u, n0, n1, n2, n3);
    t2_note(0xC0u);
    t2_note(optixGetPayload_0());
    t2_note(optixGetPayload_1());
    t2_note(optixGetPayload_2());
    t2_note(optixGetPayload_3());
    t2_note(n0);
    t2_note(n1);
    t2_note(n2);
    t2_note(n3);
    optixSetPayload_3(n0);
}

// Notes 0x40 and its 4 payload words, then sets words 0 and 1 to 42 and 43.
extern "C" __global__ void __miss__nested() {
    t2_note(0x40u);
    t2_note(optixGetPayload_0());
    t2_note(optixGetPayload_1());
    t2_note(optixGetPayload_2());
    t2_note(optixGetPayload_3());
    optixSetPayload_0(42u);
    optixSetPayload_1(43u);
}

// A closest-hit program's hit state: 15 words.
static __forceinline__ __device__ void t2_state() {
    t2_note(optixGetPrimitiveIndex());
    t2_note_f(optixGetRayTmin());
    t2_note_f(optixGetRayTmax());
    t2_note(optixGetHitKind());
    const float2 b = optixGetTriangleBarycentrics();
    t2_note_f(b.x);
    t2_note_f(b.y);
    const float3 o = optixGetWorldRayOrigin();
    t2_note_f(o.x);
    t2_note_f(o.y);
    t2_note_f(o.z);
    const float3 d = optixGetWorldRayDirection();
    t2_note_f(d.x);
    t2_note_f(d.y);
    t2_note_f(d.z);
    t2_note(t2_data(0u));
    const uint3 i = optixGetLaunchIndex();
    t2_note(i.x);
    t2_note(i.y + i.z);
}

// Payload word 0 = 1: the nested hit, notes 0x11 and its state. Otherwise notes 0x22, its state,
// traces from (3, 0.1, -10) up over [0.5, 100] with payload {1}, then notes 0x33 and its state.
extern "C" __global__ void __closesthit__state() {
    if (optixGetPayload_0() == 1u) {
        t2_note(0x11u);
        t2_state();
        return;
    }
    t2_note(0x22u);
    t2_state();
    unsigned int n0 = 1u;
    optixTrace(t2.handle, make_float3(3.0f, 0.1f, -10.0f), make_float3(0.0f, 0.0f, 1.0f), 0.5f,
               100.0f, 0.0f, 0xFFu, 0u, 0u, 1u, 0u, n0);
    t2_note(0x33u);
    t2_state();
}

// ----------------------------------------------------------------------------------------------
// optixReportIntersection's return values (§13.4)
// ----------------------------------------------------------------------------------------------

// Reports at 100 (kind 1), 12 (kind 1), 11 (kind 2), 11.5 (kind 2) and 10.5 (kind 4), with
// attribute 1 to 5; notes each result and tmax after the second and third. After the last
// report notes 0xAF7E and its result.
extern "C" __global__ void __intersection__seq() {
    t2_note(optixReportIntersection(100.0f, 1u, 1u) ? 1u : 0u);
    t2_note(optixReportIntersection(12.0f, 1u, 2u) ? 1u : 0u);
    t2_note_f(optixGetRayTmax());
    t2_note(optixReportIntersection(11.0f, 2u, 3u) ? 1u : 0u);
    t2_note_f(optixGetRayTmax());
    t2_note(optixReportIntersection(11.5f, 2u, 4u) ? 1u : 0u);
    const bool last = optixReportIntersection(10.5f, 4u, 5u);
    t2_note(0xAF7Eu);
    t2_note(last ? 1u : 0u);
}

// Notes 0xA0, kind, tmax, attribute 0; ignores kind 1, terminates on kind 4.
extern "C" __global__ void __anyhit__by_kind() {
    const unsigned int k = optixGetHitKind();
    t2_note(0xA0u);
    t2_note(k);
    t2_note_f(optixGetRayTmax());
    t2_note(optixGetAttribute_0());
    if (k == 1u) optixIgnoreIntersection();
    if (k == 4u) optixTerminateRay();
}

// Notes 0xC0, kind, tmax, attribute 0.
extern "C" __global__ void __closesthit__kind_t_attr() {
    t2_note(0xC0u);
    t2_note(optixGetHitKind());
    t2_note_f(optixGetRayTmax());
    t2_note(optixGetAttribute_0());
}

// ----------------------------------------------------------------------------------------------
// Hit kinds and attributes (§13.4, §13.7)
// ----------------------------------------------------------------------------------------------

// Reports the top face with payload word 0 as the hit kind.
extern "C" __global__ void __intersection__kind() {
    optixReportIntersection(t2_top_t(), optixGetPayload_0());
}

static __forceinline__ __device__ void t2_kind(unsigned int tag) {
    t2_note(tag);
    t2_note(optixGetHitKind());
    t2_note(optixIsTriangleHit() ? 1u : 0u);
    t2_note(optixIsFrontFaceHit() ? 1u : 0u);
    t2_note(optixIsBackFaceHit() ? 1u : 0u);
}

extern "C" __global__ void __anyhit__kind() { t2_kind(0xA0u); }
extern "C" __global__ void __closesthit__kind() { t2_kind(0xC0u); }

// Two reports: 0.25 past the top with kind 1 and attributes 100p + 0..7, then the top with kind
// 2 and attributes 100p + 50 + 0..7 (p the primitive index).
extern "C" __global__ void __intersection__attrs() {
    const unsigned int a = 100u * optixGetPrimitiveIndex();
    const float t = t2_top_t();
    optixReportIntersection(t + 0.25f, 1u, a, a + 1u, a + 2u, a + 3u, a + 4u, a + 5u, a + 6u,
                            a + 7u);
    const unsigned int b = a + 50u;
    optixReportIntersection(t, 2u, b, b + 1u, b + 2u, b + 3u, b + 4u, b + 5u, b + 6u, b + 7u);
}

// Notes tag, primitive, kind, tmax and the 8 attributes.
static __forceinline__ __device__ void t2_attrs(unsigned int tag) {
    t2_note(tag);
    t2_note(optixGetPrimitiveIndex());
    t2_note(optixGetHitKind());
    t2_note_f(optixGetRayTmax());
    t2_note(optixGetAttribute_0());
    t2_note(optixGetAttribute_1());
    t2_note(optixGetAttribute_2());
    t2_note(optixGetAttribute_3());
    t2_note(optixGetAttribute_4());
    t2_note(optixGetAttribute_5());
    t2_note(optixGetAttribute_6());
    t2_note(optixGetAttribute_7());
}

extern "C" __global__ void __anyhit__attrs() { t2_attrs(0xA0u); }
extern "C" __global__ void __closesthit__attrs() { t2_attrs(0xC0u); }

// ----------------------------------------------------------------------------------------------
// The SBT (§7)
// ----------------------------------------------------------------------------------------------

// Payload: record data, SBT-GAS index, primitive index, 1 (hit).
extern "C" __global__ void __closesthit__record() {
    optixSetPayload_0(t2_data(0u));
    optixSetPayload_1(optixGetSbtGASIndex());
    optixSetPayload_2(optixGetPrimitiveIndex());
    optixSetPayload_3(1u);
}

// Payload: record data, 2 (miss) in word 3.
extern "C" __global__ void __miss__record() {
    optixSetPayload_0(t2_data(0u));
    optixSetPayload_3(2u);
}

// Notes 0xA0 and its record's data; 0xC0 and the record's data; 0x40 and the record's data.
extern "C" __global__ void __anyhit__data() {
    t2_note(0xA0u);
    t2_note(t2_data(0u));
}
extern "C" __global__ void __closesthit__data() {
    t2_note(0xC0u);
    t2_note(t2_data(0u));
}
extern "C" __global__ void __miss__data() {
    t2_note(0x40u);
    t2_note(t2_data(0u));
}
// Notes 0x15 and its record's data, then reports the top face.
extern "C" __global__ void __intersection__data() {
    t2_note(0x15u);
    t2_note(t2_data(0u));
    optixReportIntersection(t2_top_t(), 0u);
}

// Notes its record's 4 data words, then throws user exception 1.
extern "C" __global__ void __raygen__data() {
    unsigned int* o = t2_record();
    for (unsigned int k = 8u; k < T2_WORDS; ++k) o[k] = 0u;
    t2_note(0x96u);
    for (unsigned int k = 0u; k < 4u; ++k) t2_note(t2_data(k));
    optixThrowException(1);
}

// Notes 0xE7, the exception code and its record's 2 data words.
extern "C" __global__ void __exception__data() {
    t2_note(0xE7u);
    t2_note(static_cast<unsigned int>(optixGetExceptionCode()));
    t2_note(t2_data(0u));
    t2_note(t2_data(1u));
}
