// Programs of the built-in curve scenarios (oxray/tests/curves.rs), run on every device: the CPU
// (compiled by the host's C++ compiler) and CUDA. Each launch index writes 8 words.
#include <optix.h>

struct CurveParams {
    unsigned int* out;  // 8 words per launch index
    OptixTraversableHandle handle;
    unsigned int width, height;
    float z;
    unsigned int ray_flags;
};

extern "C" __constant__ CurveParams cp;

// Rays down -z over [-2, 2] x [-2, 2]. Payload 0 is 1 for a hit, 0 for a miss, plus 16 per
// any-hit call.
extern "C" __global__ void __raygen__curves() {
    const uint3 i = optixGetLaunchIndex();
    const float x = 4.0f * ((float)i.x + 0.5f) / (float)cp.width - 2.0f;
    const float y = 4.0f * ((float)i.y + 0.5f) / (float)cp.height - 2.0f;
    unsigned int p[8] = {0u, 0u, 0u, 0u, 0u, 0u, 0u, 0u};
    optixTrace(cp.handle, make_float3(x, y, cp.z), make_float3(0.0f, 0.0f, -1.0f), 0.0f, 1e16f,
               0.0f, 0xFFu, cp.ray_flags, 0, 1, 0, p[0], p[1], p[2], p[3], p[4], p[5], p[6],
               p[7]);
    unsigned int* o = cp.out + 8 * (i.y * cp.width + i.x);
    for (int k = 0; k < 8; ++k) o[k] = p[k];
}

// The hit segment's control points through the vertex-data function of its type (guide §9.3).
static __forceinline__ __device__ int vertex_data(float4 v[4]) {
    switch (optixGetPrimitiveType()) {
    case OPTIX_PRIMITIVE_TYPE_ROUND_LINEAR:
        optixGetLinearCurveVertexData(v);
        return 2;
    case OPTIX_PRIMITIVE_TYPE_ROUND_QUADRATIC_BSPLINE:
        optixGetQuadraticBSplineVertexData(v);
        return 3;
    case OPTIX_PRIMITIVE_TYPE_ROUND_QUADRATIC_BSPLINE_ROCAPS:
        optixGetQuadraticBSplineRocapsVertexData(v);
        return 3;
    case OPTIX_PRIMITIVE_TYPE_FLAT_QUADRATIC_BSPLINE:
        optixGetRibbonVertexData(v);
        return 3;
    case OPTIX_PRIMITIVE_TYPE_ROUND_CUBIC_BSPLINE:
        optixGetCubicBSplineVertexData(v);
        return 4;
    case OPTIX_PRIMITIVE_TYPE_ROUND_CUBIC_BSPLINE_ROCAPS:
        optixGetCubicBSplineRocapsVertexData(v);
        return 4;
    case OPTIX_PRIMITIVE_TYPE_ROUND_CATMULLROM:
        optixGetCatmullRomVertexData(v);
        return 4;
    case OPTIX_PRIMITIVE_TYPE_ROUND_CATMULLROM_ROCAPS:
        optixGetCatmullRomRocapsVertexData(v);
        return 4;
    case OPTIX_PRIMITIVE_TYPE_ROUND_CUBIC_BEZIER:
        optixGetCubicBezierVertexData(v);
        return 4;
    case OPTIX_PRIMITIVE_TYPE_ROUND_CUBIC_BEZIER_ROCAPS:
        optixGetCubicBezierRocapsVertexData(v);
        return 4;
    default:
        return 0;
    }
}

// What was hit (guide §9.3, §13.5): the primitive and SBT-GAS index, the hit kind with the facing
// and type queries, t, the curve parameter, a ribbon's v, and the segment's first and last
// control points.
extern "C" __global__ void __closesthit__curve() {
    float4 v[4];
    const int n = vertex_data(v);
    const unsigned int kind = optixGetHitKind();
    optixSetPayload_0((optixGetPayload_0() & ~0xFu) | 1u);
    optixSetPayload_1(optixGetPrimitiveIndex() | (optixGetSbtGASIndex() << 16));
    optixSetPayload_2(kind | ((unsigned int)optixIsFrontFaceHit() << 8) |
                      ((unsigned int)optixIsBackFaceHit() << 9) |
                      (((unsigned int)optixGetPrimitiveType() & 0xFFu) << 10) |
                      ((unsigned int)optixIsTriangleHit() << 18));
    optixSetPayload_3(__float_as_uint(optixGetRayTmax()));
    optixSetPayload_4(__float_as_uint(optixGetCurveParameter()));
    optixSetPayload_5(__float_as_uint(optixGetRibbonParameters().y));
    optixSetPayload_6(n > 0 ? __float_as_uint(v[0].x) : 0u);
    optixSetPayload_7(n > 0 ? __float_as_uint(v[n - 1].w) : 0u);
}

extern "C" __global__ void __miss__curves() {
    optixSetPayload_0(optixGetPayload_0() & ~0xFu);
    optixSetPayload_3(__float_as_uint(optixGetRayTmax()));
}

// Even primitives are ignored; every call is counted.
extern "C" __global__ void __anyhit__skip_even() {
    optixSetPayload_0(optixGetPayload_0() + 16u);
    if ((optixGetPrimitiveIndex() & 1u) == 0u) optixIgnoreIntersection();
}

// A ribbon's normal at its hit (guide §9.3): primitive, hit kind, t, the normal and u.
extern "C" __global__ void __closesthit__ribbon_normal() {
    const float2 uv = optixGetRibbonParameters();
    const float3 n = optixGetRibbonNormal(uv);
    optixSetPayload_0((optixGetPayload_0() & ~0xFu) | 1u);
    optixSetPayload_1(optixGetPrimitiveIndex());
    optixSetPayload_2(optixGetHitKind());
    optixSetPayload_3(__float_as_uint(optixGetRayTmax()));
    optixSetPayload_4(__float_as_uint(n.x));
    optixSetPayload_5(__float_as_uint(n.y));
    optixSetPayload_6(__float_as_uint(n.z));
    optixSetPayload_7(__float_as_uint(uv.y));
}
