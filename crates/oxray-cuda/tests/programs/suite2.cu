// Programs of the second set of pipeline tests (oxray-cuda/tests/programs.rs): custom
// primitives (a sphere intersection program), any-hit on them, callables, and the transform
// list with the transform functions.
#include <optix.h>

struct Params {
    unsigned int* out;  // 48 words per launch index
    OptixTraversableHandle handle;
    unsigned int width, height;
    unsigned int ray_flags, ray_mask;
    float z;            // rays start at (x, y, z) and go towards -z
    unsigned int mode;  // 1: any-hit ignores odd primitives; 2: any-hit terminates;
                        // 3: the intersection program first reports outside the interval
    unsigned int dc_index, cc_index;
};

extern "C" __constant__ Params params;

// The data of a custom primitive's hit-group record: its spheres (centre, radius), indexed by
// primitive index minus `prim_offset`, and the hit kind it reports (with bit 7 set, which the
// report must drop).
struct SphereData {
    const float4* spheres;
    unsigned int prim_offset;
    unsigned int kind;
};

static __forceinline__ __device__ unsigned int linear_index() {
    const uint3 i = optixGetLaunchIndex();
    const uint3 d = optixGetLaunchDimensions();
    return (i.z * d.y + i.y) * d.x + i.x;
}

static __forceinline__ __device__ unsigned int* out_of_index() {
    return params.out + 48 * linear_index();
}

// One ray per launch index down -z through a grid over [-1, 1]^2; the 16 payload words go to
// words 0..15 of the output.
extern "C" __global__ void __raygen__grid() {
    const uint3 i = optixGetLaunchIndex();
    const float x = 2.0f * ((float)i.x + 0.5f) / (float)params.width - 1.0f;
    const float y = 2.0f * ((float)i.y + 0.5f) / (float)params.height - 1.0f;
    unsigned int p[16] = {0xAAAA0000u, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0};
    optixTrace(params.handle, make_float3(x, y, params.z), make_float3(0.0f, 0.0f, -1.0f), 0.0f,
               1e16f, 0.0f, params.ray_mask, params.ray_flags, 0, 1, 0, p[0], p[1], p[2], p[3],
               p[4], p[5], p[6], p[7], p[8], p[9], p[10], p[11], p[12], p[13], p[14], p[15]);
    unsigned int* o = out_of_index();
    for (int k = 0; k < 16; ++k) o[k] = p[k];
}

extern "C" __global__ void __miss__none() { optixSetPayload_0(0u); }

// A sphere: the nearer root is reported, and the farther one if the nearer is not accepted.
// Attributes: the object-space normal (3), the root (0 or 1), the primitive index, 0xA5, 6, 7.
extern "C" __global__ void __intersection__sphere() {
    const SphereData* d = reinterpret_cast<const SphereData*>(optixGetSbtDataPointer());
    const unsigned int prim = optixGetPrimitiveIndex();
    const float4 s = d->spheres[prim - d->prim_offset];
    const float3 o = optixGetObjectRayOrigin();
    const float3 dir = optixGetObjectRayDirection();
    const float ox = o.x - s.x, oy = o.y - s.y, oz = o.z - s.z;
    const float a = dir.x * dir.x + dir.y * dir.y + dir.z * dir.z;
    const float b = ox * dir.x + oy * dir.y + oz * dir.z;
    const float c = ox * ox + oy * oy + oz * oz - s.w * s.w;
    const float disc = b * b - a * c;
    if (disc < 0.0f) return;
    const float q = sqrtf(disc);
    if (params.mode == 3u) {
        // Outside [tmin, tmax]: ignored, false.
        const bool above = optixReportIntersection(optixGetRayTmax() * 2.0f + 1.0f, 1u);
        const bool below = optixReportIntersection(-1.0f, 1u);
        optixSetPayload_14((above ? 1u : 0u) | (below ? 2u : 0u) | 0x100u);
    }
    for (unsigned int root = 0; root < 2; ++root) {
        const float t = (root == 0 ? (-b - q) : (-b + q)) / a;
        const float nx = (ox + t * dir.x) / s.w;
        const float ny = (oy + t * dir.y) / s.w;
        const float nz = (oz + t * dir.z) / s.w;
        const bool accepted =
            optixReportIntersection(t, d->kind | 0x80u, __float_as_uint(nx), __float_as_uint(ny),
                                    __float_as_uint(nz), root, prim, 0xA5u, 6u, 7u);
        if (accepted) {
            if (params.mode == 2u) {
                // The any-hit program terminated: later reports do nothing.
                const bool again = optixReportIntersection(t * 0.5f, 3u);
                optixSetPayload_14(optixGetPayload_14() | (again ? 4u : 0u) | 0x200u);
            }
            return;
        }
    }
}

// Counts its calls in payload 15 and keeps the candidate's t in payload 13.
extern "C" __global__ void __anyhit__custom() {
    optixSetPayload_15(optixGetPayload_15() + 1u);
    optixSetPayload_13(__float_as_uint(optixGetRayTmax()));
    if (params.mode == 1u && (optixGetPrimitiveIndex() & 1u)) {
        optixIgnoreIntersection();
        return;
    }
    if (params.mode == 2u) {
        optixTerminateRay();
        return;
    }
}

// What was hit: 1, primitive, SBT-GAS index, hit kind, t, attributes 0..7, instance id and
// index, and flags: custom type, front, back, triangle.
extern "C" __global__ void __closesthit__custom() {
    optixSetPayload_0(1u);
    optixSetPayload_1(optixGetPrimitiveIndex());
    optixSetPayload_2(optixGetSbtGASIndex());
    optixSetPayload_3(optixGetHitKind());
    optixSetPayload_4(__float_as_uint(optixGetRayTmax()));
    optixSetPayload_5(optixGetAttribute_0());
    optixSetPayload_6(optixGetAttribute_1());
    optixSetPayload_7(optixGetAttribute_2());
    optixSetPayload_8(optixGetAttribute_3());
    optixSetPayload_9(optixGetAttribute_4());
    optixSetPayload_10(optixGetAttribute_5() | (optixGetAttribute_6() << 8) |
                       (optixGetAttribute_7() << 16));
    optixSetPayload_11(optixGetInstanceId());
    optixSetPayload_12(optixGetInstanceIndex() |
                       (optixGetPrimitiveType() == OPTIX_PRIMITIVE_TYPE_CUSTOM ? 0x100u : 0u) |
                       (optixIsFrontFaceHit() ? 0x200u : 0u) | (optixIsBackFaceHit() ? 0x400u : 0u) |
                       (optixIsTriangleHit() ? 0x800u : 0u) |
                       (optixGetPrimitiveType() == OPTIX_PRIMITIVE_TYPE_TRIANGLE ? 0x1000u : 0u));
}

// The transform list, the composed matrices and the transform functions; words 16..47 of the
// output, the rest in the payload.
extern "C" __global__ void __closesthit__xform() {
    unsigned int* o = out_of_index() + 16;
    const unsigned int n = optixGetTransformListSize();
    o[0] = optixGetInstanceId();
    o[1] = optixGetInstanceIndex();
    o[2] = n;
    unsigned int types = 0u;
    for (unsigned int i = 0; i < n; ++i) {
        types |= (unsigned int)optixGetTransformTypeFromHandle(optixGetTransformListHandle(i))
                 << (4 * i);
    }
    o[3] = types;
    const OptixTraversableHandle h0 = optixGetTransformListHandle(0);
    const OptixTraversableHandle h1 = optixGetTransformListHandle(1);
    o[4] = optixGetInstanceIdFromHandle(h0);
    o[5] = (optixGetInstanceChildFromHandle(h0) == h1 ? 1u : 0u) |
           (optixGetInstanceTransformFromHandle(h0)[0].w == -0.5f ? 2u : 0u) |
           (optixGetInstanceInverseTransformFromHandle(h0) != nullptr ? 4u : 0u) |
           (optixGetStaticTransformFromHandle(h0) == nullptr ? 8u : 0u) |
           (optixGetGASTraversableHandle() != 0ull ? 16u : 0u);
    const OptixStaticTransform* st = optixGetStaticTransformFromHandle(h1);
    o[6] = st ? __float_as_uint(st->transform[0]) : 0xFFFFFFFFu;
    o[7] = *reinterpret_cast<const unsigned int*>(optixGetSbtDataPointer());
    float m[12];
    optixGetObjectToWorldTransformMatrix(m);
    for (int k = 0; k < 12; ++k) o[8 + k] = __float_as_uint(m[k]);
    optixGetWorldToObjectTransformMatrix(m);
    for (int k = 0; k < 12; ++k) o[20 + k] = __float_as_uint(m[k]);

    optixSetPayload_1(optixGetSbtGASIndex());
    optixSetPayload_2(optixGetPrimitiveIndex());
    const float3 nw = optixTransformNormalFromObjectToWorldSpace(make_float3(1.0f, 0.0f, 0.0f));
    optixSetPayload_3(__float_as_uint(nw.x));
    optixSetPayload_4(__float_as_uint(nw.y));
    optixSetPayload_5(__float_as_uint(nw.z));
    float3 v[3];
    optixGetTriangleVertexData(v);
    unsigned int all = 1u;
    for (int k = 0; k < 3; ++k) {
        // The vertices, taken to world space and back: exact for the test's transforms.
        const float3 w = optixTransformPointFromObjectToWorldSpace(v[k]);
        const float3 b = optixTransformPointFromWorldToObjectSpace(w);
        unsigned int same = (b.x == v[k].x && b.y == v[k].y && b.z == v[k].z) ? 1u : 0u;
        const float3 vw = optixTransformVectorFromObjectToWorldSpace(v[k]);
        const float3 vb = optixTransformVectorFromWorldToObjectSpace(vw);
        same &= (vb.x == v[k].x && vb.y == v[k].y && vb.z == v[k].z) ? 1u : 0u;
        const float3 nb = optixTransformNormalFromWorldToObjectSpace(nw);
        same &= (nb.x == 1.0f && nb.y == 0.0f && nb.z == 0.0f) ? 1u : 0u;
        all &= same;
    }
    // 1, and bit 1 when every round trip gave the vertex (and the normal) back.
    optixSetPayload_0(1u | (all << 1));
    optixSetPayload_6(__float_as_uint(v[0].x));
    optixSetPayload_7(__float_as_uint(v[0].y));
    optixSetPayload_8(__float_as_uint(v[0].z));
    optixSetPayload_9(__float_as_uint(v[1].x));
    optixSetPayload_10(__float_as_uint(v[1].y));
    optixSetPayload_11(__float_as_uint(v[1].z));
    optixSetPayload_12(__float_as_uint(v[2].x));
    optixSetPayload_13(__float_as_uint(v[2].y));
    optixSetPayload_14(__float_as_uint(v[2].z));
    optixSetPayload_15(__float_as_uint(optixGetRayTmax()));
}

// Callables: a direct callable of the callables record `dc_index` and a continuation callable
// of `cc_index`; then the ray-generation record's data, which must be its own again.
extern "C" __global__ void __raygen__callables() {
    const uint3 i = optixGetLaunchIndex();
    unsigned int* o = out_of_index();
    o[0] = __float_as_uint(optixDirectCall<float, float, unsigned int>(params.dc_index, 1.5f, i.x));
    o[1] = optixContinuationCall<unsigned int, unsigned int>(params.cc_index, i.x);
    o[2] = *reinterpret_cast<const unsigned int*>(optixGetSbtDataPointer());
    o[3] = 0x600Du;
}

// x * k plus the record's float.
extern "C" __device__ float __direct_callable__scale(float x, unsigned int k) {
    return x * (float)k + *reinterpret_cast<const float*>(optixGetSbtDataPointer());
}

// A direct callable that calls another (record 0), then adds its own record's float.
extern "C" __device__ float __direct_callable__nested(float x, unsigned int k) {
    const float inner = optixDirectCall<float, float, unsigned int>(0u, x, k);
    return inner + *reinterpret_cast<const float*>(optixGetSbtDataPointer());
}

// Traces a ray at x = 0 and returns what the hit or miss program put in payload 0, plus
// 100 * k plus the record's float.
extern "C" __device__ unsigned int __continuation_callable__shoot(unsigned int k) {
    unsigned int p0 = 0xAAAA0000u;
    optixTrace(params.handle, make_float3(0.25f, 0.25f, params.z), make_float3(0.0f, 0.0f, -1.0f),
               0.0f, 1e16f, 0.0f, 0xFFu, OPTIX_RAY_FLAG_NONE, 0, 1, 0, p0);
    return p0 + 100u * k + (unsigned int)*reinterpret_cast<const float*>(optixGetSbtDataPointer());
}
