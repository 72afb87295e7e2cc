// The `triangle` example's programs in CUDA C++ (the counterpart of the OptiX SDK's
// optixTriangle): ray generation traces a camera ray per pixel, closest hit shades by
// barycentrics, miss returns the background colour of its SBT record.
#include <optix.h>

struct Params {
    float4* image;
    OptixTraversableHandle handle;
    unsigned int width, height;
    float eye[3], u[3], v[3], w[3];
};

struct MissData {
    float r, g, b;
};

extern "C" __constant__ Params params;

static __forceinline__ __device__ void setPayload(float3 p) {
    optixSetPayload_0(__float_as_uint(p.x));
    optixSetPayload_1(__float_as_uint(p.y));
    optixSetPayload_2(__float_as_uint(p.z));
}

extern "C" __global__ void __raygen__rg() {
    const uint3 idx = optixGetLaunchIndex();
    const uint3 dim = optixGetLaunchDimensions();
    const float dx = 2.0f * ((float)idx.x + 0.5f) / (float)dim.x - 1.0f;
    const float dy = 1.0f - 2.0f * ((float)idx.y + 0.5f) / (float)dim.y;
    float3 dir = make_float3(params.u[0] * dx + params.v[0] * dy + params.w[0],
                             params.u[1] * dx + params.v[1] * dy + params.w[1],
                             params.u[2] * dx + params.v[2] * dy + params.w[2]);
    const float inv = 1.0f / sqrtf(dir.x * dir.x + dir.y * dir.y + dir.z * dir.z);
    dir = make_float3(dir.x * inv, dir.y * inv, dir.z * inv);
    const float3 eye = make_float3(params.eye[0], params.eye[1], params.eye[2]);
    unsigned int p0, p1, p2;
    optixTrace(params.handle, eye, dir, 0.0f, 1e16f, 0.0f, OptixVisibilityMask(255),
               OPTIX_RAY_FLAG_NONE, 0, 1, 0, p0, p1, p2);
    params.image[idx.y * params.width + idx.x] =
        make_float4(__uint_as_float(p0), __uint_as_float(p1), __uint_as_float(p2), 1.0f);
}

extern "C" __global__ void __miss__ms() {
    const MissData* d = reinterpret_cast<const MissData*>(optixGetSbtDataPointer());
    setPayload(make_float3(d->r, d->g, d->b));
}

extern "C" __global__ void __closesthit__ch() {
    const float2 b = optixGetTriangleBarycentrics();
    setPayload(make_float3(1.0f - b.x - b.y, b.x, b.y));
}
