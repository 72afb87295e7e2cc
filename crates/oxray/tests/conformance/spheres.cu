// Programs of the built-in sphere scenarios (oxray/tests/spheres.rs), run on every device: the
// CPU (compiled by the host's C++ compiler) and CUDA. Each launch index writes 8 words.
#include <optix.h>

struct SphereParams {
    unsigned int* out;  // 8 words per launch index
    OptixTraversableHandle handle;
    unsigned int width, height;
    float z;
    unsigned int ray_flags;
    unsigned int mode;  // 0: a grid down -z; 1: from the centre of the sphere under each ray
    unsigned int pad;
};

extern "C" __constant__ SphereParams sp;

// Rays down -z over [-3, 3] x [-1.5, 1.5]. Payload 0 is 1 for a hit, 0 for a miss, plus 16 per
// any-hit call.
extern "C" __global__ void __raygen__spheres() {
    const uint3 i = optixGetLaunchIndex();
    const float x = 6.0f * ((float)i.x + 0.5f) / (float)sp.width - 3.0f;
    const float y = 3.0f * ((float)i.y + 0.5f) / (float)sp.height - 1.5f;
    unsigned int p[8] = {0u, 0u, 0u, 0u, 0u, 0u, 0u, 0u};
    float3 origin = make_float3(x, y, sp.z);
    if (sp.mode == 1u) {
        // Inside the spheres at x = -2, 0 and 2 (guide §9.6: no hit from inside).
        origin = make_float3(2.0f * rintf(x / 2.0f), 0.0f, 0.0f);
    }
    optixTrace(sp.handle, origin, make_float3(0.0f, 0.0f, -1.0f), 0.0f, 1e16f, 0.0f, 0xFFu,
               sp.ray_flags, 0, 1, 0, p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7]);
    unsigned int* o = sp.out + 8 * ((i.z * sp.height + i.y) * sp.width + i.x);
    for (int k = 0; k < 8; ++k) o[k] = p[k];
}

// What was hit (guide §9.4, §13.5, §13.7): the primitive, its hit kind with the facing and type
// queries, its SBT-GAS index, the instance id, t, and the sphere's object-space data.
extern "C" __global__ void __closesthit__sphere() {
    float4 s[1];
    optixGetSphereData(s);
    const unsigned int kind = optixGetHitKind();
    const unsigned int is_sphere = optixGetPrimitiveType() == OPTIX_PRIMITIVE_TYPE_SPHERE;
    optixSetPayload_0((optixGetPayload_0() & ~0xFu) | 1u);
    optixSetPayload_1(optixGetPrimitiveIndex() | (optixGetSbtGASIndex() << 16) |
                      ((optixGetInstanceId() & 0xFFu) << 24));
    optixSetPayload_2(kind | ((unsigned int)optixIsFrontFaceHit() << 8) |
                      ((unsigned int)optixIsBackFaceHit() << 9) | (is_sphere << 10) |
                      ((unsigned int)optixIsTriangleHit() << 11) |
                      (optixGetAttribute_0() == 0u ? 0u : 1u << 12));
    optixSetPayload_3(__float_as_uint(optixGetRayTmax()));
    optixSetPayload_4(__float_as_uint(s[0].x));
    optixSetPayload_5(__float_as_uint(s[0].y));
    optixSetPayload_6(__float_as_uint(s[0].z));
    optixSetPayload_7(__float_as_uint(s[0].w));
}

extern "C" __global__ void __miss__spheres() {
    optixSetPayload_0(optixGetPayload_0() & ~0xFu);
    optixSetPayload_3(__float_as_uint(optixGetRayTmax()));
}

// Even primitives are ignored; every call is counted.
extern "C" __global__ void __anyhit__skip_even() {
    optixSetPayload_0(optixGetPayload_0() + 16u);
    if ((optixGetPrimitiveIndex() & 1u) == 0u) optixIgnoreIntersection();
}
