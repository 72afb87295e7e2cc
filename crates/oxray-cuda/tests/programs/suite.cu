// Programs of the pipeline conformance tests (oxray-cuda/tests/programs.rs): each scenario
// picks its ray-generation, miss, closest-hit and any-hit programs from this module.
#include <optix_device.h>

struct Params {
    unsigned int* out;  // 8 words per launch index
    OptixTraversableHandle handle;
    unsigned int width, height;
    unsigned int ray_flags, ray_mask;
    float z;  // rays start at (x, y, z) and go towards -z
    unsigned int pad;
};

extern "C" __constant__ Params params;

static __forceinline__ __device__ unsigned int linear_index() {
    const uint3 i = optixGetLaunchIndex();
    const uint3 d = optixGetLaunchDimensions();
    return (i.z * d.y + i.y) * d.x + i.x;
}

// One ray per launch index down -z through a grid over [-1, 1]^2; records what the hit or
// miss program put in the payload.
extern "C" __global__ void __raygen__grid() {
    const uint3 i = optixGetLaunchIndex();
    const float x = 2.0f * ((float)i.x + 0.5f) / (float)params.width - 1.0f;
    const float y = 2.0f * ((float)i.y + 0.5f) / (float)params.height - 1.0f;
    unsigned int p[8] = {0xAAAA0000u, 1u, 2u, 3u, 4u, 5u, 6u, 7u};
    optixTrace(params.handle, make_float3(x, y, params.z), make_float3(0.0f, 0.0f, -1.0f), 0.0f,
               1e16f, 0.0f, params.ray_mask, params.ray_flags, 0, 1, 0, p[0], p[1], p[2], p[3],
               p[4], p[5], p[6], p[7]);
    unsigned int* o = params.out + 8 * linear_index();
    for (int k = 0; k < 8; ++k) o[k] = p[k];
}

// Writes the launch index and dimensions.
extern "C" __global__ void __raygen__index() {
    const uint3 i = optixGetLaunchIndex();
    const uint3 d = optixGetLaunchDimensions();
    unsigned int* o = params.out + 8 * linear_index();
    o[0] = i.x;
    o[1] = i.y;
    o[2] = i.z;
    o[3] = d.x;
    o[4] = d.y;
    o[5] = d.z;
    o[6] = 0x600D;
    o[7] = 0;
}

// What was hit: payload 0 = 1, then primitive, instance id, instance index, hit kind, t, u, v.
extern "C" __global__ void __closesthit__ids() {
    const float2 b = optixGetTriangleBarycentrics();
    optixSetPayload_0(1u);
    optixSetPayload_1(optixGetPrimitiveIndex());
    optixSetPayload_2(optixGetInstanceId());
    optixSetPayload_3(optixGetInstanceIndex());
    optixSetPayload_4(optixGetHitKind() | (optixIsTriangleHit() ? 0x100u : 0u) |
                      (optixIsFrontFaceHit() ? 0x200u : 0u) | (optixGetSbtGASIndex() << 16));
    optixSetPayload_5(__float_as_uint(optixGetRayTmax()));
    optixSetPayload_6(__float_as_uint(b.x));
    optixSetPayload_7(__float_as_uint(b.y));
}

// Payload copy-in/copy-out: reads every word, writes some back changed, leaves others alone.
extern "C" __global__ void __closesthit__payload() {
    optixSetPayload_0(optixGetPayload_0() + 0x11u);
    optixSetPayload_3(optixGetPayload_3() * 10u + optixGetPayload_1());
    optixSetPayload_7(optixGetPayload_7() ^ optixGetPayload_6());
}

extern "C" __global__ void __miss__payload() {
    optixSetPayload_0(optixGetPayload_0() + 0x22u);
    optixSetPayload_2(optixGetPayload_2() + 100u);
}

// A miss: payload 0 = 0, the ray's tmax, flags and mask.
extern "C" __global__ void __miss__ids() {
    optixSetPayload_0(0u);
    optixSetPayload_5(__float_as_uint(optixGetRayTmax()));
    optixSetPayload_6(optixGetRayFlags());
    optixSetPayload_7(optixGetRayVisibilityMask());
}

// Ignores odd primitives; counts the calls in payload 2's high bits... kept simple: ignore odd.
extern "C" __global__ void __anyhit__skip_odd() {
    if (optixGetPrimitiveIndex() & 1u) {
        optixIgnoreIntersection();
        return;
    }
}

// Accepts the first candidate and ends the traversal.
extern "C" __global__ void __anyhit__terminate() {
    optixTerminateRay();
}

// Throws a user exception with two details at launch indices whose x is 3.
extern "C" __global__ void __raygen__throw() {
    const uint3 i = optixGetLaunchIndex();
    unsigned int* o = params.out + 8 * linear_index();
    o[0] = 1u;
    if (i.x == 3u) {
        optixThrowException(7, i.x, i.y);
    }
    o[1] = 2u;
}

extern "C" __global__ void __exception__record() {
    const uint3 i = optixGetLaunchIndex();
    unsigned int* o = params.out + 8 * linear_index();
    o[2] = (unsigned int)optixGetExceptionCode();
    o[3] = optixGetExceptionDetail_0();
    o[4] = optixGetExceptionDetail_1();
    (void)i;
}
