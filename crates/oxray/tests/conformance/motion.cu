// Programs of motion_devices.rs: motion blur (guide §5.10) through a pipeline, the same CUDA C++
// on every device. Each launch index traces one ray of `mo.rays` at its time and the programs
// write what they see into the index's record of MO_WORDS words.
#include <optix.h>

#define MO_WORDS 24

struct MoRay {
    float org[3], dir[3];
    float tmin, tmax, time;
    unsigned int flags, pad[2];
};

struct MoParams {
    unsigned int* out;
    OptixTraversableHandle handle;
    const MoRay* rays;
};

extern "C" __constant__ MoParams mo;

// A float's bits, every NaN as one (devices differ in the NaN that arithmetic makes).
static __forceinline__ __device__ unsigned int bits(float x) {
    return x != x ? 0x7fc00000u : __float_as_uint(x);
}

static __forceinline__ __device__ unsigned int* record() {
    return mo.out + (size_t)MO_WORDS * optixGetLaunchIndex().x;
}

extern "C" __global__ void __raygen__mo() {
    unsigned int* o = record();
    for (int k = 0; k < MO_WORDS; ++k) o[k] = 0u;
    const MoRay r = mo.rays[optixGetLaunchIndex().x];
    optixTrace(mo.handle, make_float3(r.org[0], r.org[1], r.org[2]),
               make_float3(r.dir[0], r.dir[1], r.dir[2]), r.tmin, r.tmax, r.time, 255u, r.flags,
               0u, 1u, 0u);
}

extern "C" __global__ void __miss__mo() {
    unsigned int* o = record();
    o[0] = 2u;
    o[19] = bits(optixGetRayTime());
}

// The transform-list entry `i`'s type, 0xFF past the list.
static __forceinline__ __device__ unsigned int level_type(unsigned int i) {
    if (i >= optixGetTransformListSize()) return 0xFFu;
    return (unsigned int)optixGetTransformTypeFromHandle(optixGetTransformListHandle(i));
}

extern "C" __global__ void __closesthit__mo() {
    unsigned int* o = record();
    o[0] = 1u;
    o[1] = bits(optixGetRayTmax());
    o[2] = optixGetPrimitiveIndex();
    o[3] = optixGetHitKind();
    o[4] = optixGetInstanceId();
    o[5] = optixGetAttribute_0();
    o[6] = optixGetAttribute_1();
    o[7] = optixGetTransformListSize();
    o[8] = level_type(0);
    o[9] = level_type(1);
    float m[12];
    optixGetObjectToWorldTransformMatrix(m);
    o[10] = bits(m[3]);
    o[11] = bits(m[7]);
    o[12] = bits(m[0] + m[5] + m[10]);
    optixGetWorldToObjectTransformMatrix(m);
    o[13] = bits(m[3] + m[7] + m[11]);
    // The hit primitive at the ray's time (§13.9), and through the GAS handle (§13.9, with
    // ALLOW_RANDOM_VERTEX_ACCESS; NaN without).
    const OptixTraversableHandle gas = optixGetGASTraversableHandle();
    const float time = optixGetRayTime();
    const unsigned int prim = optixGetPrimitiveIndex(), sbt = optixGetSbtGASIndex();
    if (optixIsTriangleHit()) {
        float3 v[3];
        optixGetTriangleVertexData(v);
        o[14] = bits(v[0].x + v[1].y + v[2].z);
        optixGetTriangleVertexDataFromHandle(gas, prim, sbt, time, v);
        o[15] = bits(v[0].x + v[1].y + v[2].z);
    } else if (optixGetPrimitiveType() == OPTIX_PRIMITIVE_TYPE_SPHERE) {
        float4 s[1];
        optixGetSphereData(s);
        o[14] = bits(s[0].x + s[0].w);
        optixGetSphereDataFromHandle(gas, prim, sbt, time, s);
        o[15] = bits(s[0].x + s[0].w);
    } else if (optixGetPrimitiveType() == OPTIX_PRIMITIVE_TYPE_ROUND_CUBIC_BSPLINE) {
        float4 c[4];
        optixGetCubicBSplineVertexData(c);
        o[14] = bits(c[1].x + c[2].w);
        optixGetCubicBSplineVertexDataFromHandle(gas, prim, sbt, time, c);
        o[15] = bits(c[1].x + c[2].w);
    }
    o[16] = optixGetGASMotionStepCount(gas);
    o[17] = bits(optixGetGASMotionTimeBegin(gas));
    o[18] = bits(optixGetGASMotionTimeEnd(gas));
    o[19] = bits(time);
    // The guide's structs of the motion transforms on the path (§13.10).
    for (unsigned int i = 0; i < optixGetTransformListSize(); ++i) {
        const OptixTraversableHandle h = optixGetTransformListHandle(i);
        const OptixMatrixMotionTransform* mm = optixGetMatrixMotionTransformFromHandle(h);
        const OptixSRTMotionTransform* sm = optixGetSRTMotionTransformFromHandle(h);
        if (mm) {
            o[20] = mm->motionOptions.numKeys | ((unsigned int)mm->motionOptions.flags << 16);
            o[21] = bits(mm->transform[1][3]);
        }
        if (sm) {
            o[22] = sm->motionOptions.numKeys | ((unsigned int)sm->motionOptions.flags << 16);
            o[23] = bits(sm->srtData[1].tx + sm->srtData[0].qw);
        }
    }
}

// A custom primitive whose box the ray enters: a hit where the ray crosses the plane
// z = -0.01 * primitive index (in object space), with the primitive index as attribute 0.
extern "C" __global__ void __intersection__mo() {
    const float3 org = optixGetObjectRayOrigin();
    const float3 dir = optixGetObjectRayDirection();
    if (dir.z == 0.0f) return;
    const unsigned int prim = optixGetPrimitiveIndex();
    const float t = (-0.01f * (float)prim - org.z) / dir.z;
    optixReportIntersection(t, 7u, prim, __float_as_uint(optixGetRayTime()));
}

// An exception ends the index with its code in word 0's place of a marker (3) and word 1.
extern "C" __global__ void __exception__mo() {
    unsigned int* o = record();
    o[0] = 3u;
    o[1] = (unsigned int)optixGetExceptionCode();
}
