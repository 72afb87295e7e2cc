// Programs of the two-backend conformance suite (oxray/tests/conformance.rs) beyond those of
// oxray-cuda/tests/programs/suite.cu, which the suite compiles with this module: custom
// primitives and intersection programs, callables, transforms and the transform list, vertex
// data and the built-in exceptions. Each writes 8 words per launch index through the payload.
#include <optix.h>

struct ExtParams {
    unsigned int* out;  // 8 words per launch index
    OptixTraversableHandle handle;
    unsigned int width, height;
    const float4* spheres;  // centre and radius of each custom primitive
    float z;
    unsigned int mode;
};

extern "C" __constant__ ExtParams ext;

static __forceinline__ __device__ unsigned int ext_index() {
    const uint3 i = optixGetLaunchIndex();
    const uint3 d = optixGetLaunchDimensions();
    return (i.z * d.y + i.y) * d.x + i.x;
}

// A grid of rays down -z over [-2, 2] x [-1, 1], with the launch's ray flags in `mode`.
extern "C" __global__ void __raygen__ext_grid() {
    const uint3 i = optixGetLaunchIndex();
    const float x = 4.0f * ((float)i.x + 0.5f) / (float)ext.width - 2.0f;
    const float y = 2.0f * ((float)i.y + 0.5f) / (float)ext.height - 1.0f;
    unsigned int p[8] = {0xBBBB0000u, 0u, 0u, 0u, 0u, 0u, 0u, 0u};
    optixTrace(ext.handle, make_float3(x, y, ext.z), make_float3(0.0f, 0.0f, -1.0f), 0.0f, 1e16f,
               0.0f, 0xFFu, ext.mode, 0, 1, 0, p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7]);
    unsigned int* o = ext.out + 8 * ext_index();
    for (int k = 0; k < 8; ++k) o[k] = p[k];
}

// A sphere per primitive (guide §13.4): the nearer root in the interval is reported with hit
// kind 5 and the object-space normal as three attributes; the farther root too, with kind 6,
// if the nearer one was not accepted.
extern "C" __global__ void __intersection__sphere() {
    const float4 s = ext.spheres[optixGetPrimitiveIndex()];
    const float3 o = optixGetObjectRayOrigin();
    const float3 d = optixGetObjectRayDirection();
    const float3 oc = make_float3(o.x - s.x, o.y - s.y, o.z - s.z);
    const float a = d.x * d.x + d.y * d.y + d.z * d.z;
    const float b = oc.x * d.x + oc.y * d.y + oc.z * d.z;
    const float c = oc.x * oc.x + oc.y * oc.y + oc.z * oc.z - s.w * s.w;
    const float disc = b * b - a * c;
    if (disc < 0.0f) return;
    const float q = sqrtf(disc);
    const float roots[2] = {(-b - q) / a, (-b + q) / a};
    for (int k = 0; k < 2; ++k) {
        const float t = roots[k];
        const float3 n = make_float3((o.x + t * d.x - s.x) / s.w, (o.y + t * d.y - s.y) / s.w,
                                     (o.z + t * d.z - s.z) / s.w);
        if (optixReportIntersection(t, 5u + (unsigned int)k, __float_as_uint(n.x),
                                    __float_as_uint(n.y), __float_as_uint(n.z))) {
            return;
        }
    }
}

// What was hit: 1, primitive, hit kind, t, attributes 0-2, SBT-GAS index and instance id.
extern "C" __global__ void __closesthit__custom() {
    optixSetPayload_0(1u);
    optixSetPayload_1(optixGetPrimitiveIndex());
    optixSetPayload_2(optixGetHitKind() | (optixGetSbtGASIndex() << 8) |
                      ((optixGetInstanceId() & 0xFFu) << 16));
    optixSetPayload_3(__float_as_uint(optixGetRayTmax()));
    optixSetPayload_4(optixGetAttribute_0());
    optixSetPayload_5(optixGetAttribute_1());
    optixSetPayload_6(optixGetAttribute_2());
    optixSetPayload_7(optixGetPayload_7() + 1u);
}

extern "C" __global__ void __miss__ext() {
    optixSetPayload_0(0u);
    optixSetPayload_3(__float_as_uint(optixGetRayTmax()));
}

// Any-hit on custom primitives: even primitives are ignored, hits of kind 6 (far side) too;
// payload 7 counts the calls.
extern "C" __global__ void __anyhit__custom_filter() {
    optixSetPayload_7(optixGetPayload_7() + 0x100u);
    if ((optixGetPrimitiveIndex() & 1u) == 0u || optixGetHitKind() == 6u) {
        optixIgnoreIntersection();
    }
}

// ----------------------------------------------------------------------------------------------
// Callables (guide §15)
// ----------------------------------------------------------------------------------------------

struct CallableData {
    unsigned int salt;
};

extern "C" __device__ unsigned int __direct_callable__mix(unsigned int a, unsigned int b) {
    const CallableData* d = reinterpret_cast<const CallableData*>(optixGetSbtDataPointer());
    return a * 31u + b + d->salt;
}

extern "C" __device__ float __direct_callable__scale(float x, unsigned int k) {
    return x * (float)k;
}

// A continuation callable traces (allowed, unlike in a direct callable) and returns the hit's
// primitive index plus one, or 0 for a miss.
extern "C" __device__ unsigned int __continuation_callable__probe(float x, float y) {
    unsigned int p[8] = {0u, 0u, 0u, 0u, 0u, 0u, 0u, 0u};
    optixTrace(ext.handle, make_float3(x, y, ext.z), make_float3(0.0f, 0.0f, -1.0f), 0.0f,
               1e16f, 0.0f, 0xFFu, 0u, 0, 1, 0, p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7]);
    return p[0] ? p[1] + 1u : 0u;
}

// mode 0: the calls that work; 1: a callables index past the records; 2: a record without a
// direct callable; 3: a record without a continuation callable; 4: a direct call with the
// wrong argument types.
extern "C" __global__ void __raygen__callables() {
    const uint3 i = optixGetLaunchIndex();
    unsigned int* o = ext.out + 8 * ext_index();
    o[0] = 0xCA11u;
    if (ext.mode == 1u) optixDirectCall<unsigned int>(9u, 1u, 2u);
    if (ext.mode == 2u) optixDirectCall<unsigned int>(2u, 1u, 2u);
    if (ext.mode == 3u) optixContinuationCall<unsigned int>(0u, 0.0f, 0.0f);
    if (ext.mode == 4u) optixDirectCall<unsigned int>(0u, 1.0f, 2u);
    o[1] = optixDirectCall<unsigned int>(0u, i.x, 7u);
    o[2] = optixDirectCall<unsigned int>(1u, i.x + 1u, 100u);
    o[3] = __float_as_uint(optixDirectCall<float>(3u, 1.5f, i.x));
    o[4] = optixContinuationCall<unsigned int>(2u, -0.5f, 0.0f);
    o[5] = optixContinuationCall<unsigned int>(2u, 10.0f, 0.0f);
    o[6] = 0x600Du;
}

// ----------------------------------------------------------------------------------------------
// Transforms, the transform list and vertex data (guide §13.9, §13.11)
// ----------------------------------------------------------------------------------------------

// 1 + list size (bits 0-7), the types of the first three entries (bits 8-19), the nearest
// instance id and index, the world-space point and normal of (0, 0, 0) / (0, 0, 1).
extern "C" __global__ void __closesthit__xform() {
    const unsigned int n = optixGetTransformListSize();
    unsigned int types = 0u;
    for (unsigned int k = 0; k < n && k < 3u; ++k) {
        types |= (unsigned int)optixGetTransformTypeFromHandle(optixGetTransformListHandle(k))
                 << (8u + 4u * k);
    }
    optixSetPayload_0(1u + n + types);
    optixSetPayload_1(optixGetInstanceId() | (optixGetInstanceIndex() << 16));
    const float3 p = optixTransformPointFromObjectToWorldSpace(make_float3(0.0f, 0.0f, 0.0f));
    const float3 nw = optixTransformNormalFromObjectToWorldSpace(make_float3(0.0f, 0.0f, 1.0f));
    optixSetPayload_2(__float_as_uint(p.x));
    optixSetPayload_3(__float_as_uint(p.y));
    optixSetPayload_4(__float_as_uint(p.z));
    optixSetPayload_5(__float_as_uint(nw.z));
    float m[12];
    optixGetWorldToObjectTransformMatrix(m);
    optixSetPayload_6(__float_as_uint(m[3]));
    const float3 back = optixTransformPointFromWorldToObjectSpace(p);
    optixSetPayload_7(__float_as_uint(back.x));
}

// The hit triangle's object-space vertices: x and y of each, and the primitive.
extern "C" __global__ void __closesthit__vertices() {
    float3 v[3];
    optixGetTriangleVertexData(v);
    optixSetPayload_0(1u);
    optixSetPayload_1(optixGetPrimitiveIndex());
    optixSetPayload_2(__float_as_uint(v[0].x));
    optixSetPayload_3(__float_as_uint(v[0].y));
    optixSetPayload_4(__float_as_uint(v[1].x));
    optixSetPayload_5(__float_as_uint(v[1].y));
    optixSetPayload_6(__float_as_uint(v[2].x));
    optixSetPayload_7(__float_as_uint(v[2].y));
}

// The SBT index formula (§7.3) with the trace's SBT offset and stride (only their low 4 bits
// count): `mode` packs offset (bits 0-7) and stride (bits 8-15); the closest-hit program
// reports the record it runs from (its SBT data) and the SBT-GAS index.
extern "C" __global__ void __raygen__sbt() {
    const uint3 i = optixGetLaunchIndex();
    const float x = 2.0f * ((float)i.x + 0.5f) / (float)ext.width - 1.0f;
    unsigned int p0 = 0u, p1 = 0u, p2 = 0u;
    optixTrace(ext.handle, make_float3(x, 0.0f, ext.z), make_float3(0.0f, 0.0f, -1.0f), 0.0f,
               1e16f, 0.0f, 0xFFu, 0u, ext.mode & 0xFFu, (ext.mode >> 8) & 0xFFu, 0, p0, p1, p2);
    unsigned int* o = ext.out + 8 * ext_index();
    o[0] = p0;
    o[1] = p1;
    o[2] = p2;
}

extern "C" __global__ void __closesthit__record() {
    optixSetPayload_0(1u);
    optixSetPayload_1(*reinterpret_cast<const unsigned int*>(optixGetSbtDataPointer()));
    optixSetPayload_2(optixGetSbtGASIndex());
}

// Any-hit precedence (§13.2): an any-hit program that counts its calls in payload 3, and a
// closest-hit program that keeps the count and reports the SBT-GAS index.
extern "C" __global__ void __anyhit__mark() { optixSetPayload_3(optixGetPayload_3() + 1u); }

extern "C" __global__ void __closesthit__ah_seen() {
    optixSetPayload_0(1u);
    optixSetPayload_1(optixGetSbtGASIndex());
}

// 32 payload words (§14, the most a trace passes): the closest-hit program reads every word,
// folds them into one value it returns in word 31, and rewrites words 0-30.
extern "C" __global__ void __raygen__payload32() {
    unsigned int p[32];
    for (unsigned int k = 0; k < 32u; ++k) p[k] = 1000u + k;
    const uint3 i = optixGetLaunchIndex();
    const float x = 2.0f * ((float)i.x + 0.5f) / (float)ext.width - 1.0f;
    optixTrace(ext.handle, make_float3(x, 0.0f, ext.z), make_float3(0.0f, 0.0f, -1.0f), 0.0f,
               1e16f, 0.0f, 0xFFu, 0u, 0, 1, 0, p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7],
               p[8], p[9], p[10], p[11], p[12], p[13], p[14], p[15], p[16], p[17], p[18], p[19],
               p[20], p[21], p[22], p[23], p[24], p[25], p[26], p[27], p[28], p[29], p[30], p[31]);
    unsigned int* o = ext.out + 8 * ext_index();
    unsigned int sum = 0u;
    for (unsigned int k = 0; k < 31u; ++k) sum = sum * 31u + p[k];
    o[0] = sum;
    o[1] = p[31];
    o[2] = p[0];
    o[3] = p[30];
}

extern "C" __global__ void __closesthit__payload32() {
    const unsigned int folded = (optixGetPayload_0() << 0) ^ (optixGetPayload_1() << 1) ^ (optixGetPayload_2() << 2) ^ (optixGetPayload_3() << 3) ^ (optixGetPayload_4() << 4) ^ (optixGetPayload_5() << 5) ^ (optixGetPayload_6() << 6) ^ (optixGetPayload_7() << 7) ^ (optixGetPayload_8() << 0) ^ (optixGetPayload_9() << 1) ^ (optixGetPayload_10() << 2) ^ (optixGetPayload_11() << 3) ^ (optixGetPayload_12() << 4) ^ (optixGetPayload_13() << 5) ^ (optixGetPayload_14() << 6) ^ (optixGetPayload_15() << 7) ^ (optixGetPayload_16() << 0) ^ (optixGetPayload_17() << 1) ^ (optixGetPayload_18() << 2) ^ (optixGetPayload_19() << 3) ^ (optixGetPayload_20() << 4) ^ (optixGetPayload_21() << 5) ^ (optixGetPayload_22() << 6) ^ (optixGetPayload_23() << 7) ^ (optixGetPayload_24() << 0) ^ (optixGetPayload_25() << 1) ^ (optixGetPayload_26() << 2) ^ (optixGetPayload_27() << 3) ^ (optixGetPayload_28() << 4) ^ (optixGetPayload_29() << 5) ^ (optixGetPayload_30() << 6) ^ (optixGetPayload_31() << 7);
    optixSetPayload_0(optixGetPayload_0() * 3u + 0u);
    optixSetPayload_1(optixGetPayload_1() * 3u + 1u);
    optixSetPayload_2(optixGetPayload_2() * 3u + 2u);
    optixSetPayload_3(optixGetPayload_3() * 3u + 3u);
    optixSetPayload_4(optixGetPayload_4() * 3u + 4u);
    optixSetPayload_5(optixGetPayload_5() * 3u + 5u);
    optixSetPayload_6(optixGetPayload_6() * 3u + 6u);
    optixSetPayload_7(optixGetPayload_7() * 3u + 7u);
    optixSetPayload_8(optixGetPayload_8() * 3u + 8u);
    optixSetPayload_9(optixGetPayload_9() * 3u + 9u);
    optixSetPayload_10(optixGetPayload_10() * 3u + 10u);
    optixSetPayload_11(optixGetPayload_11() * 3u + 11u);
    optixSetPayload_12(optixGetPayload_12() * 3u + 12u);
    optixSetPayload_13(optixGetPayload_13() * 3u + 13u);
    optixSetPayload_14(optixGetPayload_14() * 3u + 14u);
    optixSetPayload_15(optixGetPayload_15() * 3u + 15u);
    optixSetPayload_16(optixGetPayload_16() * 3u + 16u);
    optixSetPayload_17(optixGetPayload_17() * 3u + 17u);
    optixSetPayload_18(optixGetPayload_18() * 3u + 18u);
    optixSetPayload_19(optixGetPayload_19() * 3u + 19u);
    optixSetPayload_20(optixGetPayload_20() * 3u + 20u);
    optixSetPayload_21(optixGetPayload_21() * 3u + 21u);
    optixSetPayload_22(optixGetPayload_22() * 3u + 22u);
    optixSetPayload_23(optixGetPayload_23() * 3u + 23u);
    optixSetPayload_24(optixGetPayload_24() * 3u + 24u);
    optixSetPayload_25(optixGetPayload_25() * 3u + 25u);
    optixSetPayload_26(optixGetPayload_26() * 3u + 26u);
    optixSetPayload_27(optixGetPayload_27() * 3u + 27u);
    optixSetPayload_28(optixGetPayload_28() * 3u + 28u);
    optixSetPayload_29(optixGetPayload_29() * 3u + 29u);
    optixSetPayload_30(optixGetPayload_30() * 3u + 30u);
    optixSetPayload_31(optixGetPayload_31() * 3u + 31u);
    optixSetPayload_31(folded);
}

// The hit's GAS handle: 1, and whether it is the handle traced (a GAS traced directly).
extern "C" __global__ void __closesthit__gas() {
    optixSetPayload_0(1u);
    optixSetPayload_1(optixGetGASTraversableHandle() == ext.handle ? 1u : 0u);
    optixSetPayload_2(optixGetGASTraversableHandle() != 0ull ? 1u : 0u);
}

// ----------------------------------------------------------------------------------------------
// Built-in exceptions (guide §13.14): mode 1 traces with a miss index past the records, mode 2
// recurses past the pipeline's trace depth, mode 3 traces a ray with a negative tmin (an
// invalid ray, which only validation mode checks).
// ----------------------------------------------------------------------------------------------

extern "C" __global__ void __raygen__faults() {
    unsigned int* o = ext.out + 8 * ext_index();
    o[0] = 0xFA17u;
    unsigned int p0 = 0u;
    const unsigned int miss = ext.mode == 1u ? 5u : 0u;
    const float tmin = ext.mode == 3u ? -1.0f : 0.0f;
    optixTrace(ext.handle, make_float3(0.5f, 0.0f, ext.z), make_float3(0.0f, 0.0f, -1.0f), tmin,
               1e16f, 0.0f, 0xFFu, 0u, 0, 1, miss, p0);
    o[1] = p0;
}

// Traces again from every hit: with a depth of 2 the third nested trace raises.
extern "C" __global__ void __closesthit__recurse() {
    unsigned int p0 = optixGetPayload_0() + 1u;
    optixTrace(ext.handle, make_float3(0.5f, 0.0f, ext.z), make_float3(0.0f, 0.0f, -1.0f), 0.0f,
               1e16f, 0.0f, 0xFFu, 0u, 0, 1, 0, p0);
    optixSetPayload_0(p0);
}

extern "C" __global__ void __exception__ext() {
    unsigned int* o = ext.out + 8 * ext_index();
    o[2] = (unsigned int)optixGetExceptionCode();
    o[3] = 0xE0E0u;
}
