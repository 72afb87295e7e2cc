// oxray_device.h: the device side of oxray's OptiX-compatible programming model on CUDA.
//
// The device functions of the NVIDIA OptiX 9 programming guide (§13, §15), under the guide's
// names and signatures, written from the guide: a program written for OptiX that uses only
// these compiles against this header unchanged. User modules may `#include <optix.h>` or
// `<optix_device.h>`: the pipeline compiler replaces those includes with this header.
//
// How it is compiled. oxray compiles each pipeline into one kernel (`__oxray_pipeline`) with
// NVRTC. The translation unit is, in order: the traversal code (kernels/trace.cu), this header,
// every module of the pipeline, then generated dispatch functions (a `switch` on the program
// index that the host writes into word 0 of each SBT record header) and the kernel itself.
// While the modules are compiled, `__global__` is defined as `__device__`, so that the
// guide's `extern "C" __global__ void __raygen__name()` entry points become device functions
// that the kernel and `optixTrace` call.
//
// Per-thread state. Device functions take no arguments, so they read and write a per-thread
// record of the current launch index, ray, hit, payload and SBT record. It lives in a
// `__shared__` array of the kernel's block, one element per thread (`__oxray_states`), which
// only the functions below touch; every name the runtime defines starts with `__oxray_`
// (reserved identifiers), so no user name can clash with it. Traces nest: `optixTrace` saves
// the caller's state in its own frame and restores it on return.
//
// Programs that never return in OptiX (`optixIgnoreIntersection`, `optixTerminateRay`) record
// their effect and return; the traversal honours it when the any-hit program returns (as the
// CPU backend does): write the payload before calling them and return right after.
// `optixThrowException` does not return: it runs the exception program, records the exception
// for the host and ends the launch index.

#ifndef OXRAY_DEVICE_H
#define OXRAY_DEVICE_H

#ifndef OXRAY_TRACE_CU
#error "oxray_device.h is compiled by oxray's pipeline compiler, after the traversal code"
#endif

#ifndef OXRAY_NUM_PAYLOAD_VALUES
#define OXRAY_NUM_PAYLOAD_VALUES 8
#endif
#ifndef OXRAY_MAX_TRACE_DEPTH
#define OXRAY_MAX_TRACE_DEPTH 1
#endif
#ifndef OXRAY_PIPELINE_BLOCK
#define OXRAY_PIPELINE_BLOCK 64
#endif
#ifndef OXRAY_EXCEPTION_RECORDS
#define OXRAY_EXCEPTION_RECORDS 64
#endif

// ---------------------------------------------------------------------------------------------
// Types and constants of the guide
// ---------------------------------------------------------------------------------------------

typedef unsigned long long CUdeviceptr;
typedef unsigned long long OptixTraversableHandle;
typedef unsigned int OptixVisibilityMask;

enum OptixRayFlags {
    OPTIX_RAY_FLAG_NONE = 0u,
    OPTIX_RAY_FLAG_DISABLE_ANYHIT = 1u << 0,
    OPTIX_RAY_FLAG_ENFORCE_ANYHIT = 1u << 1,
    OPTIX_RAY_FLAG_TERMINATE_ON_FIRST_HIT = 1u << 2,
    OPTIX_RAY_FLAG_DISABLE_CLOSESTHIT = 1u << 3,
    OPTIX_RAY_FLAG_CULL_BACK_FACING_TRIANGLES = 1u << 4,
    OPTIX_RAY_FLAG_CULL_FRONT_FACING_TRIANGLES = 1u << 5,
    OPTIX_RAY_FLAG_CULL_DISABLED_ANYHIT = 1u << 6,
    OPTIX_RAY_FLAG_CULL_ENFORCED_ANYHIT = 1u << 7,
    OPTIX_RAY_FLAG_FORCE_OPACITY_MICROMAP_2_STATE = 1u << 10,
};

enum OptixHitKind {
    OPTIX_HIT_KIND_TRIANGLE_FRONT_FACE = 0xFE,
    OPTIX_HIT_KIND_TRIANGLE_BACK_FACE = 0xFF,
};

enum OptixExceptionCodes {
    OPTIX_EXCEPTION_CODE_STACK_OVERFLOW = -1,
    OPTIX_EXCEPTION_CODE_TRACE_DEPTH_EXCEEDED = -2,
    OPTIX_EXCEPTION_CODE_TRAVERSAL_DEPTH_EXCEEDED = -3,
    OPTIX_EXCEPTION_CODE_TRAVERSAL_INVALID_TRAVERSABLE = -5,
    OPTIX_EXCEPTION_CODE_INVALID_MISS_SBT = -6,
    OPTIX_EXCEPTION_CODE_INVALID_HIT_SBT = -7,
    OPTIX_EXCEPTION_CODE_UNSUPPORTED_PRIMITIVE_TYPE = -8,
    OPTIX_EXCEPTION_CODE_INVALID_RAY = -9,
    OPTIX_EXCEPTION_CODE_CALLABLE_PARAMETER_MISMATCH = -10,
    OPTIX_EXCEPTION_CODE_BUILTIN_IS_MISMATCH = -11,
    OPTIX_EXCEPTION_CODE_CALLABLE_INVALID_SBT = -12,
    OPTIX_EXCEPTION_CODE_CALLABLE_NO_DC_SBT_RECORD = -13,
    OPTIX_EXCEPTION_CODE_CALLABLE_NO_CC_SBT_RECORD = -14,
    OPTIX_EXCEPTION_CODE_UNSUPPORTED_SINGLE_LEVEL_GAS = -15,
    OPTIX_EXCEPTION_CODE_PAYLOAD_TYPE_MISMATCH = -33,
};

enum OptixPayloadTypeID {
    OPTIX_PAYLOAD_TYPE_DEFAULT = 0,
    OPTIX_PAYLOAD_TYPE_ID_0 = (1 << 0u),
    OPTIX_PAYLOAD_TYPE_ID_1 = (1 << 1u),
    OPTIX_PAYLOAD_TYPE_ID_2 = (1 << 2u),
    OPTIX_PAYLOAD_TYPE_ID_3 = (1 << 3u),
    OPTIX_PAYLOAD_TYPE_ID_4 = (1 << 4u),
    OPTIX_PAYLOAD_TYPE_ID_5 = (1 << 5u),
    OPTIX_PAYLOAD_TYPE_ID_6 = (1 << 6u),
    OPTIX_PAYLOAD_TYPE_ID_7 = (1 << 7u),
};

#define OPTIX_SBT_RECORD_HEADER_SIZE ((size_t)32)
#define OPTIX_SBT_RECORD_ALIGNMENT 16ull

// ---------------------------------------------------------------------------------------------
// What the host uploads: traversables, SBT, launch information
// ---------------------------------------------------------------------------------------------

// What an OptixTraversableHandle points at (64 bytes, made by the host for a GAS or an IAS).
struct __oxray_Traversable {
    u32 kind;   // 1: triangle GAS (binary node layout); 2: one level of instances
    u32 count;  // GAS: SBT records (geometry flags); IAS: instance slots
    unsigned long long nodes;      // binary nodes
    unsigned long long prims;      // GAS: 3 float4 per leaf slot; IAS: 6 float4 per slot
    unsigned long long info;       // GAS: uint2 per slot (primitive index, SBT-GAS index);
                                   // IAS: 2 uint4 per slot (id, sbt offset, flags, mask),
                                   //      (index, 0, child descriptor lo, hi)
    unsigned long long geom_flags; // GAS: one u32 per SBT-GAS index
    unsigned long long pad[2];
};
#define __OXRAY_GAS 1u
#define __OXRAY_IAS 2u

// The launch, in constant memory, written by the host before each launch.
struct __oxray_LaunchInfo {
    uint3 dims;
    u32 total;
    unsigned long long raygen;  // record address
    unsigned long long exception;  // record address, 0 for none
    unsigned long long miss;
    unsigned long long hitgroup;
    u32 miss_stride, miss_count;
    u32 hit_stride, hit_count;
    unsigned long long exceptions;  // u32 count, then records of 16 words
};
__constant__ __oxray_LaunchInfo __oxray_launch;

// Instance flags and geometry flags (their values in the guide's headers).
#define __OXRAY_INSTANCE_DISABLE_CULLING 1u
#define __OXRAY_INSTANCE_FLIP_FACING 2u
#define __OXRAY_INSTANCE_DISABLE_ANYHIT 4u
#define __OXRAY_INSTANCE_ENFORCE_ANYHIT 8u
#define __OXRAY_GEOMETRY_DISABLE_ANYHIT 1u
#define __OXRAY_GEOMETRY_DISABLE_CULLING 4u

// ---------------------------------------------------------------------------------------------
// Per-thread state
// ---------------------------------------------------------------------------------------------

struct __oxray_RayState {
    float3 org, dir;
    float tmin, tmax, time;
    u32 flags, mask;
    // The current hit: candidate in any-hit, closest in closest-hit.
    float u, v;
    u32 prim, sbt_gas_index, hit_kind, instance_id, instance_index;
    u32 payload[OXRAY_NUM_PAYLOAD_VALUES > 0 ? OXRAY_NUM_PAYLOAD_VALUES : 1];
};

struct __oxray_ThreadState {
    uint3 launch_index;
    u32 depth;       // traces in progress
    u32 ah_action;   // set by any-hit: 0 accept, 1 ignore, 2 terminate
    const char* record;  // the running program's SBT record
    __oxray_RayState ray;
    int exception_code;
    u32 exception_ndetails;
    u32 exception_details[8];
};

__shared__ __oxray_ThreadState __oxray_states[OXRAY_PIPELINE_BLOCK];

static __forceinline__ __device__ __oxray_ThreadState& __oxray_state() {
    return __oxray_states[threadIdx.x];
}

// Generated with the pipeline: calls the program of the given kind of the group whose index the
// host wrote into the record header (nothing for a group without one).
__device__ void __oxray_call_raygen(u32 group);
__device__ void __oxray_call_miss(u32 group);
__device__ void __oxray_call_closesthit(u32 group);
__device__ bool __oxray_has_anyhit(u32 group);
__device__ void __oxray_call_anyhit(u32 group);
__device__ void __oxray_call_exception(u32 group);

static __forceinline__ __device__ u32 __oxray_group_of(const char* record) {
    return *reinterpret_cast<const u32*>(record);
}

// Ends the launch index with the exception in the state: the exception program runs (if the
// SBT has one), the exception is recorded for the host, and the thread exits.
static __noinline__ __device__ void __oxray_raise() {
    __oxray_ThreadState& s = __oxray_state();
    if (__oxray_launch.exception != 0) {
        s.record = reinterpret_cast<const char*>(__oxray_launch.exception);
        __oxray_call_exception(__oxray_group_of(s.record));
    }
    u32* out = reinterpret_cast<u32*>(__oxray_launch.exceptions);
    u32 slot = atomicAdd(out, 1u);
    if (slot < OXRAY_EXCEPTION_RECORDS) {
        u32* r = out + 16 + 16 * slot;
        r[0] = s.launch_index.x;
        r[1] = s.launch_index.y;
        r[2] = s.launch_index.z;
        r[3] = (u32)s.exception_code;
        for (int i = 0; i < 8; ++i) r[4 + i] = s.exception_details[i];
        r[12] = s.exception_ndetails;
    }
    asm volatile("exit;");
}

static __forceinline__ __device__ void __oxray_throw(int code, u32 n, const u32* details) {
    __oxray_ThreadState& s = __oxray_state();
    s.exception_code = code;
    s.exception_ndetails = n;
    for (u32 i = 0; i < 8; ++i) s.exception_details[i] = i < n ? details[i] : 0u;
    __oxray_raise();
}

// ---------------------------------------------------------------------------------------------
// Device functions: launch, SBT, ray and hit queries
// ---------------------------------------------------------------------------------------------

static __forceinline__ __device__ uint3 optixGetLaunchIndex() {
    return __oxray_state().launch_index;
}
static __forceinline__ __device__ uint3 optixGetLaunchDimensions() { return __oxray_launch.dims; }

static __forceinline__ __device__ CUdeviceptr optixGetSbtDataPointer() {
    return reinterpret_cast<CUdeviceptr>(__oxray_state().record + OPTIX_SBT_RECORD_HEADER_SIZE);
}

static __forceinline__ __device__ float3 optixGetWorldRayOrigin() { return __oxray_state().ray.org; }
static __forceinline__ __device__ float3 optixGetWorldRayDirection() {
    return __oxray_state().ray.dir;
}
static __forceinline__ __device__ float optixGetRayTmin() { return __oxray_state().ray.tmin; }
static __forceinline__ __device__ float optixGetRayTmax() { return __oxray_state().ray.tmax; }
static __forceinline__ __device__ float optixGetRayTime() { return __oxray_state().ray.time; }
static __forceinline__ __device__ unsigned int optixGetRayFlags() {
    return __oxray_state().ray.flags;
}
static __forceinline__ __device__ unsigned int optixGetRayVisibilityMask() {
    return __oxray_state().ray.mask;
}
static __forceinline__ __device__ unsigned int optixGetPrimitiveIndex() {
    return __oxray_state().ray.prim;
}
static __forceinline__ __device__ unsigned int optixGetSbtGASIndex() {
    return __oxray_state().ray.sbt_gas_index;
}
static __forceinline__ __device__ unsigned int optixGetInstanceId() {
    return __oxray_state().ray.instance_id;
}
static __forceinline__ __device__ unsigned int optixGetInstanceIndex() {
    return __oxray_state().ray.instance_index;
}
static __forceinline__ __device__ unsigned int optixGetHitKind() {
    return __oxray_state().ray.hit_kind;
}
static __forceinline__ __device__ bool optixIsFrontFaceHit(unsigned int hitKind) {
    return (hitKind & 1u) == 0u;
}
static __forceinline__ __device__ bool optixIsFrontFaceHit() {
    return optixIsFrontFaceHit(optixGetHitKind());
}
static __forceinline__ __device__ bool optixIsBackFaceHit(unsigned int hitKind) {
    return (hitKind & 1u) == 1u;
}
static __forceinline__ __device__ bool optixIsBackFaceHit() {
    return optixIsBackFaceHit(optixGetHitKind());
}
static __forceinline__ __device__ bool optixIsTriangleFrontFaceHit() {
    return optixGetHitKind() == OPTIX_HIT_KIND_TRIANGLE_FRONT_FACE;
}
static __forceinline__ __device__ bool optixIsTriangleBackFaceHit() {
    return optixGetHitKind() == OPTIX_HIT_KIND_TRIANGLE_BACK_FACE;
}
static __forceinline__ __device__ bool optixIsTriangleHit() {
    return optixIsTriangleFrontFaceHit() || optixIsTriangleBackFaceHit();
}
static __forceinline__ __device__ float2 optixGetTriangleBarycentrics() {
    __oxray_ThreadState& s = __oxray_state();
    return make_float2(s.ray.u, s.ray.v);
}
static __forceinline__ __device__ unsigned int optixGetAttribute_0() {
    return __float_as_uint(__oxray_state().ray.u);
}
static __forceinline__ __device__ unsigned int optixGetAttribute_1() {
    return __float_as_uint(__oxray_state().ray.v);
}

// ---------------------------------------------------------------------------------------------
// Payload (guide §14): up to 32 words, copied in at the trace and out when it returns
// ---------------------------------------------------------------------------------------------

template <unsigned int N>
static __forceinline__ __device__ unsigned int __oxray_get_payload() {
    if constexpr (N < OXRAY_NUM_PAYLOAD_VALUES) {
        return __oxray_state().ray.payload[N];
    } else {
        return 0u;
    }
}
template <unsigned int N>
static __forceinline__ __device__ void __oxray_set_payload(unsigned int v) {
    if constexpr (N < OXRAY_NUM_PAYLOAD_VALUES) __oxray_state().ray.payload[N] = v;
}

#define __OXRAY_PAYLOAD(N)                                                                  \
    static __forceinline__ __device__ unsigned int optixGetPayload_##N() {                  \
        return __oxray_get_payload<N>();                                                    \
    }                                                                                       \
    static __forceinline__ __device__ void optixSetPayload_##N(unsigned int p) {            \
        __oxray_set_payload<N>(p);                                                          \
    }
__OXRAY_PAYLOAD(0) __OXRAY_PAYLOAD(1) __OXRAY_PAYLOAD(2) __OXRAY_PAYLOAD(3)
__OXRAY_PAYLOAD(4) __OXRAY_PAYLOAD(5) __OXRAY_PAYLOAD(6) __OXRAY_PAYLOAD(7)
__OXRAY_PAYLOAD(8) __OXRAY_PAYLOAD(9) __OXRAY_PAYLOAD(10) __OXRAY_PAYLOAD(11)
__OXRAY_PAYLOAD(12) __OXRAY_PAYLOAD(13) __OXRAY_PAYLOAD(14) __OXRAY_PAYLOAD(15)
__OXRAY_PAYLOAD(16) __OXRAY_PAYLOAD(17) __OXRAY_PAYLOAD(18) __OXRAY_PAYLOAD(19)
__OXRAY_PAYLOAD(20) __OXRAY_PAYLOAD(21) __OXRAY_PAYLOAD(22) __OXRAY_PAYLOAD(23)
__OXRAY_PAYLOAD(24) __OXRAY_PAYLOAD(25) __OXRAY_PAYLOAD(26) __OXRAY_PAYLOAD(27)
__OXRAY_PAYLOAD(28) __OXRAY_PAYLOAD(29) __OXRAY_PAYLOAD(30) __OXRAY_PAYLOAD(31)
#undef __OXRAY_PAYLOAD

// ---------------------------------------------------------------------------------------------
// Any-hit control and exceptions
// ---------------------------------------------------------------------------------------------

static __forceinline__ __device__ void optixIgnoreIntersection() { __oxray_state().ah_action = 1u; }
static __forceinline__ __device__ void optixTerminateRay() { __oxray_state().ah_action = 2u; }

// User codes are 0 to 2^30 - 1; others are clamped to the largest, as on the CPU backend.
static __forceinline__ __device__ int __oxray_user_code(int code) {
    return (code >= 0 && code <= (1 << 30) - 1) ? code : (1 << 30) - 1;
}
template <typename... D>
static __forceinline__ __device__ void optixThrowException(int exceptionCode, D... details) {
    static_assert(sizeof...(D) <= 8, "optixThrowException takes at most 8 details");
    u32 d[8] = {static_cast<u32>(details)...};
    __oxray_throw(__oxray_user_code(exceptionCode), sizeof...(D), d);
}
static __forceinline__ __device__ int optixGetExceptionCode() {
    return __oxray_state().exception_code;
}
#define __OXRAY_DETAIL(N)                                                                   \
    static __forceinline__ __device__ unsigned int optixGetExceptionDetail_##N() {          \
        return __oxray_state().exception_details[N];                                        \
    }
__OXRAY_DETAIL(0) __OXRAY_DETAIL(1) __OXRAY_DETAIL(2) __OXRAY_DETAIL(3)
__OXRAY_DETAIL(4) __OXRAY_DETAIL(5) __OXRAY_DETAIL(6) __OXRAY_DETAIL(7)
#undef __OXRAY_DETAIL

// ---------------------------------------------------------------------------------------------
// optixTrace: traversal with the rules of guide §13.2 and the §7.3 hit-group index
// ---------------------------------------------------------------------------------------------

// Where the GAS being traversed sits.
struct __oxray_Placement {
    u32 sbt_offset, flags, instance_id, instance_index;
};

// The closest accepted hit.
struct __oxray_Best {
    bool found;
    float t, u, v;
    u32 prim, sbt_gas_index, hit_kind, instance_id, instance_index;
    const char* record;
};

struct __oxray_TraceArgs {
    u32 flags, sbt_offset, sbt_stride;
};

// Whether any-hit is on for geometry with flags `gflags` under instance flags `iflags`: the
// geometry's flag, overridden by the instance's, overridden by the ray's (§13.2).
static __forceinline__ __device__ bool __oxray_anyhit_on(u32 rflags, u32 iflags, u32 gflags) {
    bool on = (gflags & __OXRAY_GEOMETRY_DISABLE_ANYHIT) == 0u;
    if (iflags & __OXRAY_INSTANCE_DISABLE_ANYHIT) {
        on = false;
    } else if (iflags & __OXRAY_INSTANCE_ENFORCE_ANYHIT) {
        on = true;
    }
    if (rflags & OPTIX_RAY_FLAG_DISABLE_ANYHIT) {
        on = false;
    } else if (rflags & OPTIX_RAY_FLAG_ENFORCE_ANYHIT) {
        on = true;
    }
    return on;
}

// Traverses a triangle GAS with the object-space ray `r`, offering every triangle in the
// interval to the any-hit rules; `tmax` shrinks to accepted hits. True when traversal ends
// (terminated).
static __forceinline__ __device__ bool __oxray_walk_gas(const TraceRay& r,
                                                        const __oxray_Traversable* g,
                                                        const __oxray_TraceArgs& a,
                                                        const __oxray_Placement& place,
                                                        float tmin, float& tmax,
                                                        __oxray_Best& best) {
    const float4* nodes = reinterpret_cast<const float4*>(g->nodes);
    const float4* tris = reinterpret_cast<const float4*>(g->prims);
    const uint2* slots = reinterpret_cast<const uint2*>(g->info);
    const u32* gflags_of = reinterpret_cast<const u32*>(g->geom_flags);
    bool ended = false;
    walk_bvh2(r, nodes, tmin, tmax, [&](u32 start, u32 count, float& tmax_) {
        for (u32 s = start; s < start + count; ++s) {
            float4 q0 = tris[3 * s];
            float4 q1 = tris[3 * s + 1];
            float4 q2 = tris[3 * s + 2];
            TriHit h;
            if (!intersect_triangle(r, make_float3(q0.x, q0.y, q0.z),
                                    make_float3(q1.x, q1.y, q1.z),
                                    make_float3(q2.x, q2.y, q2.z), tmin, tmax_, h)) {
                continue;
            }
            uint2 info = slots[s];
            u32 gflags = gflags_of[info.y];
            bool front = h.front != ((place.flags & __OXRAY_INSTANCE_FLIP_FACING) != 0u);
            bool no_culling = (gflags & __OXRAY_GEOMETRY_DISABLE_CULLING) ||
                              (place.flags & __OXRAY_INSTANCE_DISABLE_CULLING);
            if (!no_culling) {
                if (((a.flags & OPTIX_RAY_FLAG_CULL_BACK_FACING_TRIANGLES) && !front) ||
                    ((a.flags & OPTIX_RAY_FLAG_CULL_FRONT_FACING_TRIANGLES) && front)) {
                    continue;
                }
            }
            unsigned long long rec = (unsigned long long)place.sbt_offset +
                                     (unsigned long long)info.y * (a.sbt_stride & 0xFu) +
                                     (a.sbt_offset & 0xFu);
            if (rec >= __oxray_launch.hit_count) {
                u32 d[2] = {rec > 0xffffffffull ? 0xffffffffu : (u32)rec, info.y};
                __oxray_throw(OPTIX_EXCEPTION_CODE_INVALID_HIT_SBT, 2, d);
            }
            const char* record = reinterpret_cast<const char*>(__oxray_launch.hitgroup) +
                                 rec * __oxray_launch.hit_stride;
            bool ah_on = __oxray_anyhit_on(a.flags, place.flags, gflags);
            if (((a.flags & OPTIX_RAY_FLAG_CULL_DISABLED_ANYHIT) && !ah_on) ||
                ((a.flags & OPTIX_RAY_FLAG_CULL_ENFORCED_ANYHIT) && ah_on)) {
                continue;
            }
            bool terminate = (a.flags & OPTIX_RAY_FLAG_TERMINATE_ON_FIRST_HIT) != 0u;
            u32 kind = front ? OPTIX_HIT_KIND_TRIANGLE_FRONT_FACE : OPTIX_HIT_KIND_TRIANGLE_BACK_FACE;
            u32 group = __oxray_group_of(record);
            if (ah_on && __oxray_has_anyhit(group)) {
                __oxray_ThreadState& st = __oxray_state();
                const char* saved = st.record;
                st.record = record;
                st.ray.tmax = h.t;
                st.ray.u = h.u;
                st.ray.v = h.v;
                st.ray.prim = info.x;
                st.ray.sbt_gas_index = info.y;
                st.ray.hit_kind = kind;
                st.ray.instance_id = place.instance_id;
                st.ray.instance_index = place.instance_index;
                st.ah_action = 0u;
                __oxray_call_anyhit(group);
                st.record = saved;
                u32 action = st.ah_action;
                if (action == 1u) continue;
                if (action == 2u) terminate = true;
            }
            best.found = true;
            best.t = h.t;
            best.u = h.u;
            best.v = h.v;
            best.prim = info.x;
            best.sbt_gas_index = info.y;
            best.hit_kind = kind;
            best.instance_id = place.instance_id;
            best.instance_index = place.instance_index;
            best.record = record;
            tmax_ = h.t;
            if (terminate) {
                ended = true;
                return true;
            }
        }
        return false;
    });
    tmax = best.found ? best.t : tmax;
    return ended;
}

// One level of instances: the top-level binary tree, each instance's mask and box tested, the
// ray carried into its space, its GAS traversed with its flags and SBT offset.
static __forceinline__ __device__ void __oxray_walk_ias(const TraceRay& r,
                                                       const __oxray_Traversable* t,
                                                       const __oxray_TraceArgs& a, u32 ray_mask,
                                                       __oxray_Best& best) {
    const float4* top = reinterpret_cast<const float4*>(t->nodes);
    const float4* insts = reinterpret_cast<const float4*>(t->prims);
    const uint4* info = reinterpret_cast<const uint4*>(t->info);
    const float tmin = r.tmin;
    walk_bvh2(r, top, tmin, r.tmax, [&](u32 start, u32 count, float& tmax) {
        for (u32 s = start; s < start + count; ++s) {
            uint4 i0 = info[2 * s];
            uint4 i1 = info[2 * s + 1];
            if ((i0.w & ray_mask & 0xFFu) == 0u) continue;
            const float4* inst = insts + 6 * (size_t)s;
            if (!hits_box(r, inst[3], inst[4], tmin, tmax)) continue;
            const __oxray_Traversable* child = reinterpret_cast<const __oxray_Traversable*>(
                ((unsigned long long)i1.w << 32) | (unsigned long long)i1.z);
            if (child == nullptr) continue;
            float4 m0 = inst[0], m1 = inst[1], m2 = inst[2];
            TraceRay o;
            o.org = make_float3(m0.x * r.org.x + m0.y * r.org.y + m0.z * r.org.z + m0.w,
                                m1.x * r.org.x + m1.y * r.org.y + m1.z * r.org.z + m1.w,
                                m2.x * r.org.x + m2.y * r.org.y + m2.z * r.org.z + m2.w);
            o.dir = make_float3(m0.x * r.dir.x + m0.y * r.dir.y + m0.z * r.dir.z,
                                m1.x * r.dir.x + m1.y * r.dir.y + m1.z * r.dir.z,
                                m2.x * r.dir.x + m2.y * r.dir.y + m2.z * r.dir.z);
            o.tmin = tmin;
            o.tmax = tmax;
            if (!prepare_ray(o)) continue;
            __oxray_Placement place;
            place.instance_id = i0.x;
            place.sbt_offset = i0.y;
            place.flags = i0.z;
            place.instance_index = i1.x;
            if (__oxray_walk_gas(o, child, a, place, tmin, tmax, best)) return true;
        }
        return false;
    });
}

static __noinline__ __device__ void __oxray_trace(OptixTraversableHandle handle, float3 org,
                                                  float3 dir, float tmin, float tmax, float time,
                                                  OptixVisibilityMask mask, unsigned int flags,
                                                  unsigned int sbt_offset, unsigned int sbt_stride,
                                                  unsigned int miss_index, unsigned int n,
                                                  unsigned int* payload) {
    __oxray_ThreadState& st = __oxray_state();
    if (n > OXRAY_NUM_PAYLOAD_VALUES) {
        u32 d[2] = {n, (u32)OXRAY_NUM_PAYLOAD_VALUES};
        __oxray_throw(OPTIX_EXCEPTION_CODE_PAYLOAD_TYPE_MISMATCH, 2, d);
    }
    if (st.depth + 1u > OXRAY_MAX_TRACE_DEPTH) {
        __oxray_throw(OPTIX_EXCEPTION_CODE_TRACE_DEPTH_EXCEEDED, 0, nullptr);
    }
    // The caller's state (a hit or miss program's ray and payload, its record).
    const char* saved_record = st.record;
    __oxray_RayState saved;
    if (st.depth > 0u) saved = st.ray;
    st.depth += 1u;
    for (u32 i = 0; i < n; ++i) st.ray.payload[i] = payload[i];
    st.ray.org = org;
    st.ray.dir = dir;
    st.ray.tmin = tmin;
    st.ray.time = time;
    st.ray.flags = flags;
    st.ray.mask = mask & 0xFFu;

    __oxray_Best best;
    best.found = false;
    __oxray_TraceArgs a;
    a.flags = flags;
    a.sbt_offset = sbt_offset;
    a.sbt_stride = sbt_stride;
    TraceRay r;
    r.org = org;
    r.dir = dir;
    r.tmin = tmin;
    r.tmax = tmax;
    if (handle != 0ull && prepare_ray(r)) {
        const __oxray_Traversable* t = reinterpret_cast<const __oxray_Traversable*>(handle);
        if (t->kind == __OXRAY_GAS) {
            __oxray_Placement place;
            place.sbt_offset = 0u;
            place.flags = 0u;
            place.instance_id = 0xffffffffu;
            place.instance_index = 0u;
            float tm = tmax;
            __oxray_walk_gas(r, t, a, place, tmin, tm, best);
        } else if (t->kind == __OXRAY_IAS) {
            __oxray_walk_ias(r, t, a, st.ray.mask, best);
        } else {
            __oxray_throw(OPTIX_EXCEPTION_CODE_TRAVERSAL_INVALID_TRAVERSABLE, 0, nullptr);
        }
    }
    if (best.found) {
        if ((flags & OPTIX_RAY_FLAG_DISABLE_CLOSESTHIT) == 0u) {
            st.ray.tmax = best.t;
            st.ray.u = best.u;
            st.ray.v = best.v;
            st.ray.prim = best.prim;
            st.ray.sbt_gas_index = best.sbt_gas_index;
            st.ray.hit_kind = best.hit_kind;
            st.ray.instance_id = best.instance_id;
            st.ray.instance_index = best.instance_index;
            st.record = best.record;
            __oxray_call_closesthit(__oxray_group_of(best.record));
        }
    } else {
        if (miss_index >= __oxray_launch.miss_count) {
            u32 d[1] = {miss_index};
            __oxray_throw(OPTIX_EXCEPTION_CODE_INVALID_MISS_SBT, 1, d);
        }
        st.ray.tmax = tmax;
        st.record = reinterpret_cast<const char*>(__oxray_launch.miss) +
                    (unsigned long long)miss_index * __oxray_launch.miss_stride;
        __oxray_call_miss(__oxray_group_of(st.record));
    }
    for (u32 i = 0; i < n; ++i) payload[i] = st.ray.payload[i];
    st.depth -= 1u;
    st.record = saved_record;
    if (st.depth > 0u) st.ray = saved;
}

// The guide's optixTrace: 0 to 32 payload words, passed by reference, copied in and out.
template <typename... Payload>
static __forceinline__ __device__ void optixTrace(OptixTraversableHandle handle, float3 rayOrigin,
                                                  float3 rayDirection, float tmin, float tmax,
                                                  float rayTime,
                                                  OptixVisibilityMask visibilityMask,
                                                  unsigned int rayFlags, unsigned int SBToffset,
                                                  unsigned int SBTstride,
                                                  unsigned int missSBTIndex,
                                                  Payload&... payload) {
    static_assert(sizeof...(Payload) <= 32, "optixTrace takes at most 32 payload values");
    constexpr unsigned int n = sizeof...(Payload);
    unsigned int p[n > 0 ? n : 1] = {static_cast<unsigned int>(payload)...};
    __oxray_trace(handle, rayOrigin, rayDirection, tmin, tmax, rayTime, visibilityMask, rayFlags,
                  SBToffset, SBTstride, missSBTIndex, n, p);
    unsigned int i = 0;
    ((payload = p[i++]), ...);
    (void)i;
}

// The overload with a payload type (one payload type for now: the type is not checked).
template <typename... Payload>
static __forceinline__ __device__ void optixTrace(OptixPayloadTypeID type,
                                                  OptixTraversableHandle handle, float3 rayOrigin,
                                                  float3 rayDirection, float tmin, float tmax,
                                                  float rayTime,
                                                  OptixVisibilityMask visibilityMask,
                                                  unsigned int rayFlags, unsigned int SBToffset,
                                                  unsigned int SBTstride,
                                                  unsigned int missSBTIndex,
                                                  Payload&... payload) {
    (void)type;
    optixTrace(handle, rayOrigin, rayDirection, tmin, tmax, rayTime, visibilityMask, rayFlags,
               SBToffset, SBTstride, missSBTIndex, payload...);
}

#endif  // OXRAY_DEVICE_H
