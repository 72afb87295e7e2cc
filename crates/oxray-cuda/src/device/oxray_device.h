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
// index that the host writes into word 0 of each SBT record header; for a kind of group the
// pipeline has one of, a plain call that reads no header) and the kernel itself.
// While the modules are compiled, `__global__` is defined as `__device__`, so that the
// guide's `extern "C" __global__ void __raygen__name()` entry points become device functions
// that the kernel and `optixTrace` call.
//
// Per-thread state. Device functions take no arguments, so they read and write a per-thread
// record of the current launch index, ray, hit, payload and SBT record. It is a local variable
// of the kernel (per-thread local memory); a `__shared__` array of the block holds a pointer to
// it for each thread (`__oxray_states`); keeping the records themselves out of shared memory
// leaves the L1 cache, which shares its storage, to the traversal. Only the functions below
// touch them; every name the runtime defines starts with `__oxray_` (reserved identifiers), so
// no user name can clash with them. Traces nest: `optixTrace` saves the caller's state in its
// own frame and restores it on return.
//
// Fast path. In a pipeline without any-hit programs, a trace of a triangle GAS with no culling
// flags accepts every candidate, so `optixTrace` runs the query kernels' own loop at its call
// site and passes the closest hit to `__oxray_trace`, which runs the closest-hit or miss
// program (see `__oxray_fast_root`); everything else takes the general traversal.
//
// Programs that never return in OptiX (`optixIgnoreIntersection`, `optixTerminateRay`) record
// their effect (the first one called) and return; the traversal honours it when the any-hit
// program returns (the CPU backend does not return from them, as OptiX): write the payload
// before calling them and return right after.
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
// Attribute words a report keeps (the pipeline's numAttributeValues, clamped to 2..8).
#ifndef OXRAY_NUM_ATTRIBUTE_VALUES
#define OXRAY_NUM_ATTRIBUTE_VALUES 2
#endif
// The pipeline's traversable graph flags and primitive type flags (0: anything).
#ifndef OXRAY_GRAPH_FLAGS
#define OXRAY_GRAPH_FLAGS 0u
#endif
#ifndef OXRAY_PRIMITIVE_TYPE_FLAGS
#define OXRAY_PRIMITIVE_TYPE_FLAGS 0u
#endif
// Entries of one binary walk's stack: one per level of the deepest tree the builder makes.
#ifndef OXRAY_BVH2_STACK
#define OXRAY_BVH2_STACK OXRAY_STACK_SIZE
#endif
// Transforms a path from the root to a GAS holds at most (a graph is at most 31 deep).
#define __OXRAY_MAX_LEVELS 31
// Nesting of callables before STACK_OVERFLOW is raised, as on the CPU backend.
#define __OXRAY_MAX_CALL_DEPTH 64u

// ---------------------------------------------------------------------------------------------
// Types and constants of the guide
// ---------------------------------------------------------------------------------------------

// The guide's types and constants: optix_types.h (oxray_core::source::OPTIX_TYPES_HEADER),
// which the pipeline compiler puts before this header.

// ---------------------------------------------------------------------------------------------
// What the host uploads: traversables, SBT, launch information
// ---------------------------------------------------------------------------------------------

// What an OptixTraversableHandle of a GAS, an IAS or a static transform points at (64 bytes,
// made by the host; the handle is its device address). The kind word comes first in every
// record a handle can point at (instances too), so that a handle is decoded by reading it.
struct __oxray_Traversable {
    u32 kind;   // __OXRAY_GAS, __OXRAY_CUSTOM_GAS, __OXRAY_SPHERE_GAS, __OXRAY_CURVE_GAS,
                // __OXRAY_IAS or __OXRAY_STATIC
    u32 count;  // GAS: SBT records (geometry flags); IAS: instance slots; static transform: 1
    unsigned long long nodes;      // GAS, IAS: binary nodes; static transform: its
                                   // OptixStaticTransform, which follows this descriptor
    unsigned long long prims;      // triangle GAS: 3 float4 per leaf slot; custom GAS: 2 float4
                                   // per leaf slot (the box's corners); sphere GAS: 1 float4
                                   // per leaf slot (centre, radius); curve GAS: 6 float4 per
                                   // leaf slot (curve.cu's CurveRecord); IAS: 6 float4 per slot
                                   // (the query kernels' table: the world box is rows 3, 4)
    unsigned long long info;       // GAS: uint2 per slot (primitive index, SBT-GAS index);
                                   // IAS: one __oxray_Instance per slot
    unsigned long long geom_flags; // GAS: one u32 per SBT-GAS index
    u32 depth;                     // traversable graph depth (a GAS is 1)
    u32 types;                     // curve GAS: the OptixPrimitiveTypeFlags of its curve types
    unsigned long long random;     // GAS built with ALLOW_RANDOM_VERTEX_ACCESS: its inputs and
                                   // each primitive's leaf slot (__oxray_random_slot); else 0
    unsigned long long motion;     // GAS or IAS built with motion (guide §5.10): its
                                   // __oxray_Motion; else 0
};
#define __OXRAY_GAS 1u
#define __OXRAY_IAS 2u
#define __OXRAY_STATIC 3u
#define __OXRAY_INSTANCE 4u
#define __OXRAY_CUSTOM_GAS 5u
#define __OXRAY_SPHERE_GAS 6u
#define __OXRAY_CURVE_GAS 7u
// Motion transforms (§5.10.4, §5.10.5): like a static transform, the descriptor is followed by
// the guide's struct (OptixMatrixMotionTransform, OptixSRTMotionTransform), at `nodes`.
#define __OXRAY_MATRIX_MOTION 8u
#define __OXRAY_SRT_MOTION 9u

// The motion of a GAS or an IAS (§5.10.1): its options; for a GAS, its primitives at keys 1,
// 2, ... follow, each key a copy of the `prims` table (`stride` float4 apiece).
struct __oxray_Motion {
    u32 keys, flags;  // numKeys (> 1), OptixMotionFlags
    float begin, end;
    u32 stride;
    u32 pad[3];
};
// Whether a descriptor kind is a GAS.
#define __OXRAY_IS_GAS(k)                                                                    \
    ((k) == __OXRAY_GAS || (k) == __OXRAY_CUSTOM_GAS || (k) == __OXRAY_SPHERE_GAS ||           \
     (k) == __OXRAY_CURVE_GAS)

// One instance of an IAS as pipelines read it (128 bytes). Its address is the instance's
// handle in the transform list (optixGetTransformListHandle).
struct __oxray_Instance {
    u32 kind;  // __OXRAY_INSTANCE
    u32 id, sbt_offset, flags;
    u32 mask, index;
    unsigned long long child;  // the child's handle; 0 for none
    float4 object_to_world[3];
    float4 world_to_object[3];
};

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
    unsigned long long callables;
    u32 callable_stride, callable_count;
    u32 max_graph_depth;  // the pipeline's maximum traversable graph depth
    u32 validation;       // 1 in validation mode (§4.3): traces check their rays
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

// Where the geometry being traversed sits: the transform list from the root (instances and
// static transforms, index 0 nearest the root), what the instances on it add up to, and the
// ray in the GAS's object space. It lives in the trace's frame (local memory); the state
// points at the one the running program sees.
struct __oxray_Path {
    u32 len;             // transforms on the path
    u32 sbt_offset;      // SBT offsets of the instances, summed (§7.3.1)
    u32 instance_id;     // the nearest instance's (~0u without one, §13.7)
    u32 instance_index;  // the nearest instance's (0 without one)
    u32 iflags;          // the nearest instance's flags (§5.4)
    const __oxray_Traversable* gas;  // the GAS entered last
    float3 org, dir;     // the ray in that GAS's object space
    unsigned long long levels[__OXRAY_MAX_LEVELS];
};

struct __oxray_RayState {
    float3 org, dir;
    float tmin, tmax, time;
    u32 flags, mask;
    // The current hit: candidate in any-hit, closest in closest-hit; the primitive in
    // intersection programs.
    u32 prim, sbt_gas_index, hit_kind;
    u32 slot;  // leaf slot of a triangle or sphere hit (vertex data), ~0u for a custom primitive
    u32 attr[8];
    const __oxray_Path* path;
    // The GAS hit on a trace's fast path, whose path is the shared root (`__oxray_root_path`).
    const __oxray_Traversable* gas;
    u32 payload[OXRAY_NUM_PAYLOAD_VALUES > 0 ? OXRAY_NUM_PAYLOAD_VALUES : 1];
};

// Each field is written only where it starts to matter (the kernel sets `depth`, `calls`,
// `record`, `report` and `ray.path`): every word a thread writes here is local memory that the
// device eventually writes back to DRAM, which a launch of a million short rays feels.
struct __oxray_ThreadState {
    u32 depth;       // traces in progress
    u32 ah_action;   // set by any-hit: 0 accept, 1 ignore, 2 terminate
    u32 calls;       // callables in progress
    const char* record;  // the running program's SBT record
    void* report;    // an intersection program's report context (__oxray_Report)
    __oxray_RayState ray;
    int exception_code;
    u32 exception_ndetails;
    u32 exception_details[8];
    u32 traces;  // optixTrace calls of this launch index, for the launch report
};

// The state itself is a local variable of the kernel (per-thread local memory, cached in L1);
// the block's shared memory holds only a pointer to it per thread. Keeping the state out of
// shared memory keeps the L1 cache, which shares its storage with shared memory, for the
// traversal's node fetches and stack.
__shared__ __oxray_ThreadState* __oxray_states[OXRAY_PIPELINE_BLOCK];

// The pointer stays generic. (Telling the compiler that the state is local memory,
// `__builtin_assume(__isLocal(s))`, makes it address the state with `ld.local` and `st.local`
// in every function, but ptxas then takes a callee's local accesses through such an address
// for accesses to the callee's own frame and drops its stores: the programs' writes to the
// state are lost. Measured on a device and in the assembly, docs/BENCHMARKS.md, "The pipeline,
// eleventh round".)
static __forceinline__ __device__ __oxray_ThreadState& __oxray_state() {
    return *__oxray_states[threadIdx.x];
}

// The launch index of this thread (the kernel runs one thread per index, x fastest).
static __forceinline__ __device__ uint3 __oxray_launch_index() {
    const u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    const uint3 d = __oxray_launch.dims;
    // A 1-D launch needs no division (the same branch for every thread of the launch).
    if (d.y == 1u && d.z == 1u) return make_uint3(i, 0u, 0u);
    const u32 row = i / d.x;
    return make_uint3(i - row * d.x, row % d.y, row / d.y);
}

// Generated with the pipeline: calls the program of the given kind of the group whose index the
// host wrote into the record header (nothing for a group without one).
__device__ void __oxray_call_raygen(u32 group);
__device__ void __oxray_call_miss(u32 group);
__device__ void __oxray_call_closesthit(u32 group);
__device__ bool __oxray_has_anyhit(u32 group);
__device__ void __oxray_call_anyhit(u32 group);
__device__ void __oxray_call_exception(u32 group);
__device__ bool __oxray_has_intersection(u32 group);
__device__ void __oxray_call_intersection(u32 group);
// The address of a callables group's direct or continuation callable (null for none).
__device__ void* __oxray_dc_of(u32 group);
__device__ void* __oxray_cc_of(u32 group);
// A tag unique to a function type: the address of a variable of its own. The generated
// __oxray_dc_signature / __oxray_cc_signature give each callable's, which a call compares with
// the tag of its own ReturnT(ArgTypes...) (the guide's CALLABLE_PARAMETER_MISMATCH otherwise).
template <typename F>
__device__ char __oxray_signature_tag = 0;
template <typename F>
static __forceinline__ __device__ const void* __oxray_signature() {
    return &__oxray_signature_tag<F>;
}
__device__ const void* __oxray_dc_signature(u32 group);
__device__ const void* __oxray_cc_signature(u32 group);

static __forceinline__ __device__ u32 __oxray_group_of(const char* record) {
    return *reinterpret_cast<const u32*>(record);
}

// Adds the launch index's trace count to the launch's (words 2 and 3 of the exception buffer,
// a u64), one atomic per group of converged threads.
static __forceinline__ __device__ void __oxray_count_traces(u32 traces) {
    unsigned long long* total =
        reinterpret_cast<unsigned long long*>(__oxray_launch.exceptions) + 1;
#if __CUDA_ARCH__ >= 800
    const unsigned int mask = __activemask();
    const u32 sum = __reduce_add_sync(mask, traces);
    if ((threadIdx.x & 31u) == (u32)(__ffs(mask) - 1) && sum != 0u) {
        atomicAdd(total, (unsigned long long)sum);
    }
#else
    if (traces != 0u) atomicAdd(total, (unsigned long long)traces);
#endif
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
        const uint3 index = __oxray_launch_index();
        r[0] = index.x;
        r[1] = index.y;
        r[2] = index.z;
        r[3] = (u32)s.exception_code;
        for (int i = 0; i < 8; ++i) r[4 + i] = s.exception_details[i];
        r[12] = s.exception_ndetails;
    }
    if (s.traces != 0u) {
        atomicAdd(reinterpret_cast<unsigned long long*>(__oxray_launch.exceptions) + 1,
                  (unsigned long long)s.traces);
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

static __forceinline__ __device__ uint3 optixGetLaunchIndex() { return __oxray_launch_index(); }
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
#ifndef OXRAY_USES_MOTION_BLUR
#define OXRAY_USES_MOTION_BLUR 0
#endif
// Guide §13.5: the ray's time, 0 in a pipeline compiled without usesMotionBlur (as on the CPU).
static __forceinline__ __device__ float optixGetRayTime() {
    return OXRAY_USES_MOTION_BLUR ? __oxray_state().ray.time : 0.0f;
}
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
    return __oxray_state().ray.path->instance_id;
}
static __forceinline__ __device__ unsigned int optixGetInstanceIndex() {
    return __oxray_state().ray.path->instance_index;
}
static __forceinline__ __device__ unsigned int optixGetHitKind() {
    return __oxray_state().ray.hit_kind;
}
// Facing is defined for built-in primitives only (hit kinds 128..255); a custom primitive's
// hit kind (0..127) is neither front nor back.
static __forceinline__ __device__ bool optixIsFrontFaceHit(unsigned int hitKind) {
    return hitKind >= 0x80u && (hitKind & 1u) == 0u;
}
static __forceinline__ __device__ bool optixIsFrontFaceHit() {
    return optixIsFrontFaceHit(optixGetHitKind());
}
static __forceinline__ __device__ bool optixIsBackFaceHit(unsigned int hitKind) {
    return hitKind >= 0x80u && (hitKind & 1u) == 1u;
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
// Built-in hit kinds: a triangle's 0xFE/0xFF, otherwise 0x80 | (the low byte of the
// OptixPrimitiveType) << 1 | back face: a sphere's 0x8C/0x8D, a curve's 0x82..0x97 (oxray's
// choice, the same on both devices: see oxray_core::HitKind). Every other hit kind is a custom
// one.
static __forceinline__ __device__ OptixPrimitiveType optixGetPrimitiveType(unsigned int hitKind) {
    if (hitKind == OPTIX_HIT_KIND_TRIANGLE_FRONT_FACE ||
        hitKind == OPTIX_HIT_KIND_TRIANGLE_BACK_FACE)
        return OPTIX_PRIMITIVE_TYPE_TRIANGLE;
    unsigned int low = (hitKind & 0x7Fu) >> 1;
    if (hitKind >= 0x80u && low >= 1u && low <= 0x0Bu)
        return (OptixPrimitiveType)(0x2500u | low);
    return OPTIX_PRIMITIVE_TYPE_CUSTOM;
}
static __forceinline__ __device__ OptixPrimitiveType optixGetPrimitiveType() {
    return optixGetPrimitiveType(optixGetHitKind());
}
static __forceinline__ __device__ float2 optixGetTriangleBarycentrics() {
    __oxray_ThreadState& s = __oxray_state();
    return make_float2(__uint_as_float(s.ray.attr[0]), __uint_as_float(s.ray.attr[1]));
}
// Attributes: a triangle's are its barycentrics (0, 1); a custom primitive's are the words its
// intersection program reported (0 past those).
#define __OXRAY_ATTRIBUTE(N)                                                                \
    static __forceinline__ __device__ unsigned int optixGetAttribute_##N() {                \
        const __oxray_ThreadState& s = __oxray_state();                                     \
        /* A triangle has two attributes (§13.4): the others read as zero. */               \
        if (N >= 2 && s.ray.slot != 0xffffffffu) return 0u;                                 \
        return s.ray.attr[N];                                                               \
    }
__OXRAY_ATTRIBUTE(0) __OXRAY_ATTRIBUTE(1) __OXRAY_ATTRIBUTE(2) __OXRAY_ATTRIBUTE(3)
__OXRAY_ATTRIBUTE(4) __OXRAY_ATTRIBUTE(5) __OXRAY_ATTRIBUTE(6) __OXRAY_ATTRIBUTE(7)
#undef __OXRAY_ATTRIBUTE

// Any value will do (§13.6): the payload word it is written to is left to the compiler.
static __forceinline__ __device__ unsigned int optixUndefinedValue() { return 0u; }

// One payload type for now: every program supports it, so there is nothing to declare.
static __forceinline__ __device__ void optixSetPayloadTypes(unsigned int typeMask) {
    (void)typeMask;
}

// ---------------------------------------------------------------------------------------------
// Object space, transforms and the transform list (guide §13.5, §13.9, §13.11)
// ---------------------------------------------------------------------------------------------

// Without transforms on the path, the object-space ray is the world ray (the fast path's
// shared root path keeps no ray of its own).
static __forceinline__ __device__ float3 optixGetObjectRayOrigin() {
    const __oxray_ThreadState& s = __oxray_state();
    return s.ray.path->len == 0u ? s.ray.org : s.ray.path->org;
}
static __forceinline__ __device__ float3 optixGetObjectRayDirection() {
    const __oxray_ThreadState& s = __oxray_state();
    return s.ray.path->len == 0u ? s.ray.dir : s.ray.path->dir;
}
// The GAS of the current hit: the path's, or the fast path's root GAS.
static __forceinline__ __device__ const __oxray_Traversable* __oxray_hit_gas() {
    const __oxray_ThreadState& s = __oxray_state();
    return s.ray.path->gas != nullptr ? s.ray.path->gas : s.ray.gas;
}
static __forceinline__ __device__ OptixTraversableHandle optixGetGASTraversableHandle() {
    return reinterpret_cast<OptixTraversableHandle>(__oxray_hit_gas());
}
static __forceinline__ __device__ unsigned int optixGetTransformListSize() {
    return __oxray_state().ray.path->len;
}
static __forceinline__ __device__ OptixTraversableHandle optixGetTransformListHandle(unsigned int index) {
    const __oxray_Path* p = __oxray_state().ray.path;
    return index < p->len ? p->levels[index] : 0ull;
}

static __forceinline__ __device__ u32 __oxray_kind_of(OptixTraversableHandle handle) {
    return handle == 0ull ? 0u : *reinterpret_cast<const u32*>(handle);
}
static __forceinline__ __device__ OptixTransformType
optixGetTransformTypeFromHandle(OptixTraversableHandle handle) {
    u32 k = __oxray_kind_of(handle);
    return k == __OXRAY_INSTANCE        ? OPTIX_TRANSFORM_TYPE_INSTANCE
           : k == __OXRAY_STATIC        ? OPTIX_TRANSFORM_TYPE_STATIC_TRANSFORM
           : k == __OXRAY_MATRIX_MOTION ? OPTIX_TRANSFORM_TYPE_MATRIX_MOTION_TRANSFORM
           : k == __OXRAY_SRT_MOTION    ? OPTIX_TRANSFORM_TYPE_SRT_MOTION_TRANSFORM
                                        : OPTIX_TRANSFORM_TYPE_NONE;
}
static __forceinline__ __device__ const __oxray_Instance* __oxray_instance_of(
    OptixTraversableHandle handle) {
    return __oxray_kind_of(handle) == __OXRAY_INSTANCE
               ? reinterpret_cast<const __oxray_Instance*>(handle)
               : nullptr;
}
static __forceinline__ __device__ unsigned int optixGetInstanceIdFromHandle(OptixTraversableHandle handle) {
    const __oxray_Instance* i = __oxray_instance_of(handle);
    return i ? i->id : 0u;
}
static __forceinline__ __device__ OptixTraversableHandle
optixGetInstanceChildFromHandle(OptixTraversableHandle handle) {
    const __oxray_Instance* i = __oxray_instance_of(handle);
    return i ? i->child : 0ull;
}
static __forceinline__ __device__ const float4* optixGetInstanceTransformFromHandle(
    OptixTraversableHandle handle) {
    const __oxray_Instance* i = __oxray_instance_of(handle);
    return i ? i->object_to_world : nullptr;
}
static __forceinline__ __device__ const float4* optixGetInstanceInverseTransformFromHandle(
    OptixTraversableHandle handle) {
    const __oxray_Instance* i = __oxray_instance_of(handle);
    return i ? i->world_to_object : nullptr;
}
// Guide §13.12: the handle of instance `instIdx` of an IAS built with
// OPTIX_BUILD_FLAG_ALLOW_RANDOM_INSTANCE_ACCESS: its record in the IAS's instance table. The IAS
// keeps the slot of every instance index (`random`: the count, then the slots); 0 where OptiX
// leaves the access undefined (no flag, an index out of range), as on the CPU.
static __forceinline__ __device__ OptixTraversableHandle
optixGetInstanceTraversableFromIAS(OptixTraversableHandle ias, unsigned int instIdx) {
    if (__oxray_kind_of(ias) != __OXRAY_IAS) return 0ull;
    const __oxray_Traversable* t = reinterpret_cast<const __oxray_Traversable*>(ias);
    if (t->random == 0ull) return 0ull;
    const u32* w = reinterpret_cast<const u32*>(t->random);
    if (instIdx >= w[0]) return 0ull;
    const u32 slot = w[1 + instIdx];
    return slot == 0xffffffffu ? 0ull : t->info + sizeof(__oxray_Instance) * (size_t)slot;
}
static __forceinline__ __device__ const OptixStaticTransform* optixGetStaticTransformFromHandle(
    OptixTraversableHandle handle) {
    if (__oxray_kind_of(handle) != __OXRAY_STATIC) return nullptr;
    return reinterpret_cast<const OptixStaticTransform*>(
        reinterpret_cast<const __oxray_Traversable*>(handle)->nodes);
}

// ---------------------------------------------------------------------------------------------
// Motion (guide §5.10): the CPU backend's arithmetic, operation for operation (the pipeline is
// compiled without fused multiply-add), so that both devices see the same scene at each time
// ---------------------------------------------------------------------------------------------

// The traversal's time: the ray's, or 0 in a pipeline compiled without usesMotionBlur (§13.5).
#define __OXRAY_TIME(t) (OXRAY_USES_MOTION_BLUR ? (t) : 0.0f)

// a + (b - a) * f, as every motion key is interpolated (oxray_core::motion::lerp).
static __forceinline__ __device__ float __oxray_lerp(float a, float b, float f) {
    return a + (b - a) * f;
}
static __forceinline__ __device__ float4 __oxray_lerp4(float4 a, float4 b, float f) {
    return make_float4(__oxray_lerp(a.x, b.x, f), __oxray_lerp(a.y, b.y, f),
                       __oxray_lerp(a.z, b.z, f), __oxray_lerp(a.w, b.w, f));
}

// Whether a traversable with these motion options vanishes at `time` (§5.10.1).
static __forceinline__ __device__ bool __oxray_vanishes(u32 keys, u32 flags, float begin,
                                                        float end, float time) {
    return keys > 1u && (((flags & OPTIX_MOTION_FLAG_START_VANISH) && time < begin) ||
                         ((flags & OPTIX_MOTION_FLAG_END_VANISH) && time > end));
}

// The keys `time` falls between and the fraction past the first (MotionOptions::sample): false
// where the traversable vanishes. Keys are evenly spaced from `begin` to `end`; a time outside
// is clamped, a NaN time is `begin`.
static __forceinline__ __device__ bool __oxray_sample(u32 keys, u32 flags, float begin, float end,
                                                      float time, u32& key, u32& next,
                                                      float& f) {
    key = 0u;
    next = 0u;
    f = 0.0f;
    if (keys <= 1u) return true;
    if (__oxray_vanishes(keys, flags, begin, end, time)) return false;
    const u32 last = keys - 1u;
    const float span = end - begin;
    if (span <= 0.0f) {
        key = time > end ? last : 0u;
        next = key;
        return true;
    }
    const float t = isnan(time) ? begin : fminf(fmaxf(time, begin), end);
    const float pos = (t - begin) / span * (float)last;
    const float fl = floorf(pos);
    u32 k = fl > 0.0f ? (u32)fl : 0u;
    if (k >= last) {
        key = last;
        next = last;
        return true;
    }
    key = k;
    next = k + 1u;
    f = fminf(fmaxf(pos - (float)k, 0.0f), 1.0f);
    return true;
}

// The motion of a GAS or an IAS; null without.
static __forceinline__ __device__ const __oxray_Motion* __oxray_motion_of(
    const __oxray_Traversable* t) {
    return reinterpret_cast<const __oxray_Motion*>(t->motion);
}

// Key `key`'s table of a GAS's primitives (the descriptor's `prims` for key 0).
static __forceinline__ __device__ const float4* __oxray_key_table(const __oxray_Traversable* g,
                                                                 const __oxray_Motion* m,
                                                                 u32 key) {
    if (key == 0u) return reinterpret_cast<const float4*>(g->prims);
    return reinterpret_cast<const float4*>(m + 1) + (size_t)(key - 1u) * m->stride;
}

// The two key tables of a GAS at `time` and the fraction between them: for a GAS without
// motion, its table twice and 0. False where the GAS vanishes.
static __forceinline__ __device__ bool __oxray_gas_keys(const __oxray_Traversable* g, float time,
                                                        const float4*& ka, const float4*& kb,
                                                        float& f) {
    const __oxray_Motion* m = __oxray_motion_of(g);
    ka = reinterpret_cast<const float4*>(g->prims);
    kb = ka;
    f = 0.0f;
    if (m == nullptr) return true;
    u32 key, next;
    if (!__oxray_sample(m->keys, m->flags, m->begin, m->end, time, key, next, f)) return false;
    ka = __oxray_key_table(g, m, key);
    kb = __oxray_key_table(g, m, next);
    return true;
}

// The same keys where a vanished GAS reads as its first key (random vertex access and vertex
// data, GasData::triangle_at).
static __forceinline__ __device__ void __oxray_gas_keys_at(const __oxray_Traversable* g,
                                                          float time, const float4*& ka,
                                                          const float4*& kb, float& f) {
    if (!__oxray_gas_keys(g, time, ka, kb, f)) {
        ka = reinterpret_cast<const float4*>(g->prims);
        kb = ka;
        f = 0.0f;
    }
}

// The inverse of a 3x4 matrix by cofactors (Transform::inverse_cofactors): false where it is
// singular or not finite.
static __forceinline__ __device__ bool __oxray_inverse(const float* m, float* out) {
    const float a = m[0], b = m[1], c = m[2], tx = m[3];
    const float d = m[4], e = m[5], f = m[6], ty = m[7];
    const float g = m[8], h = m[9], i = m[10], tz = m[11];
    const float c00 = e * i - f * h;
    const float c01 = f * g - d * i;
    const float c02 = d * h - e * g;
    const float det = a * c00 + b * c01 + c * c02;
    bool finite = isfinite(det) && det != 0.0f;
    for (int k = 0; k < 12; ++k) finite = finite && isfinite(m[k]);
    if (!finite) return false;
    const float r = 1.0f / det;
    const float l[9] = {c00 * r,           (c * h - b * i) * r, (b * f - c * e) * r,
                        c01 * r,           (a * i - c * g) * r, (c * d - a * f) * r,
                        c02 * r,           (b * g - a * h) * r, (a * e - b * d) * r};
    out[0] = l[0];
    out[1] = l[1];
    out[2] = l[2];
    out[3] = -(l[0] * tx + l[1] * ty + l[2] * tz);
    out[4] = l[3];
    out[5] = l[4];
    out[6] = l[5];
    out[7] = -(l[3] * tx + l[4] * ty + l[5] * tz);
    out[8] = l[6];
    out[9] = l[7];
    out[10] = l[8];
    out[11] = -(l[6] * tx + l[7] * ty + l[8] * tz);
    for (int k = 0; k < 12; ++k) {
        if (!isfinite(out[k])) return false;
    }
    return true;
}

// The object-to-world matrix of an SRT key (SrtData::to_transform): C = T * R * S with the
// quaternion normalised first (§5.10.5).
static __forceinline__ __device__ void __oxray_srt_matrix(const float* k, float* m) {
    const float sx = k[0], sa = k[1], sb = k[2], pvx = k[3], sy = k[4], sc = k[5], pvy = k[6];
    const float sz = k[7], pvz = k[8], qx = k[9], qy = k[10], qz = k[11], qw = k[12];
    const float n = sqrtf(qx * qx + qy * qy + qz * qz + qw * qw);
    const float x = qx / n, y = qy / n, z = qz / n, w = qw / n;
    const float r[3][3] = {
        {1.0f - 2.0f * (y * y + z * z), 2.0f * (x * y - z * w), 2.0f * (x * z + y * w)},
        {2.0f * (x * y + z * w), 1.0f - 2.0f * (x * x + z * z), 2.0f * (y * z - x * w)},
        {2.0f * (x * z - y * w), 2.0f * (y * z + x * w), 1.0f - 2.0f * (x * x + y * y)}};
    const float s[3][4] = {{sx, sa, sb, pvx}, {0.0f, sy, sc, pvy}, {0.0f, 0.0f, sz, pvz}};
    const float t[3] = {k[13], k[14], k[15]};
    for (int row = 0; row < 3; ++row) {
        for (int col = 0; col < 4; ++col) {
            float v = 0.0f;
            for (int q = 0; q < 3; ++q) v += r[row][q] * s[q][col];
            if (col == 3) v += t[row];
            m[row * 4 + col] = v;
        }
    }
}

// The object-to-world matrix of the motion transform `t` (descriptor kind __OXRAY_MATRIX_MOTION
// or __OXRAY_SRT_MOTION) at `time`: false where it vanishes.
static __forceinline__ __device__ bool __oxray_motion_matrix(const __oxray_Traversable* t,
                                                             float time, float* m) {
    const OptixMatrixMotionTransform* mt =
        reinterpret_cast<const OptixMatrixMotionTransform*>(t->nodes);
    const OptixMotionOptions o = mt->motionOptions;
    u32 key, next;
    float f;
    if (!__oxray_sample(o.numKeys, o.flags, o.timeBegin, o.timeEnd, time, key, next, f)) {
        return false;
    }
    if (t->kind == __OXRAY_MATRIX_MOTION) {
        const float* a = mt->transform[0] + 12 * (size_t)key;
        const float* b = mt->transform[0] + 12 * (size_t)next;
        for (int k = 0; k < 12; ++k) m[k] = __oxray_lerp(a[k], b[k], f);
    } else {
        const OptixSRTMotionTransform* st =
            reinterpret_cast<const OptixSRTMotionTransform*>(t->nodes);
        const float* a = &st->srtData[0].sx + 16 * (size_t)key;
        const float* b = &st->srtData[0].sx + 16 * (size_t)next;
        float k16[16];
        for (int k = 0; k < 16; ++k) k16[k] = __oxray_lerp(a[k], b[k], f);
        __oxray_srt_matrix(k16, m);
    }
    return true;
}

static __forceinline__ __device__ const OptixMatrixMotionTransform*
optixGetMatrixMotionTransformFromHandle(OptixTraversableHandle handle) {
    if (__oxray_kind_of(handle) != __OXRAY_MATRIX_MOTION) return nullptr;
    return reinterpret_cast<const OptixMatrixMotionTransform*>(
        reinterpret_cast<const __oxray_Traversable*>(handle)->nodes);
}
static __forceinline__ __device__ const OptixSRTMotionTransform*
optixGetSRTMotionTransformFromHandle(OptixTraversableHandle handle) {
    if (__oxray_kind_of(handle) != __OXRAY_SRT_MOTION) return nullptr;
    return reinterpret_cast<const OptixSRTMotionTransform*>(
        reinterpret_cast<const __oxray_Traversable*>(handle)->nodes);
}
// Guide §13.10: a GAS's motion options; without motion one step and times 0, as on the CPU.
static __forceinline__ __device__ const __oxray_Motion* __oxray_gas_motion(
    OptixTraversableHandle gas) {
    if (gas == 0ull || !__OXRAY_IS_GAS(__oxray_kind_of(gas))) return nullptr;
    return __oxray_motion_of(reinterpret_cast<const __oxray_Traversable*>(gas));
}
static __forceinline__ __device__ float optixGetGASMotionTimeBegin(OptixTraversableHandle gas) {
    const __oxray_Motion* m = __oxray_gas_motion(gas);
    return m ? m->begin : 0.f;
}
static __forceinline__ __device__ float optixGetGASMotionTimeEnd(OptixTraversableHandle gas) {
    const __oxray_Motion* m = __oxray_gas_motion(gas);
    return m ? m->end : 0.f;
}
static __forceinline__ __device__ unsigned int optixGetGASMotionStepCount(OptixTraversableHandle gas) {
    const __oxray_Motion* m = __oxray_gas_motion(gas);
    return m ? m->keys : 1u;
}

// The object-to-world (`inverse` false) or world-to-object matrix of a transform-list entry,
// 12 floats row-major: the instance's or static transform's own, or a motion transform's at the
// ray's time, made in `scratch`.
static __forceinline__ __device__ const float* __oxray_level_matrix(unsigned long long handle,
                                                                   bool inverse, float* scratch) {
    const u32 kind = __oxray_kind_of(handle);
    if (kind == __OXRAY_INSTANCE) {
        const __oxray_Instance* i = reinterpret_cast<const __oxray_Instance*>(handle);
        return reinterpret_cast<const float*>(inverse ? i->world_to_object : i->object_to_world);
    }
    if (kind == __OXRAY_MATRIX_MOTION || kind == __OXRAY_SRT_MOTION) {
        // The path holds a motion transform only at a time where it is present and invertible.
        const __oxray_Traversable* t = reinterpret_cast<const __oxray_Traversable*>(handle);
        float o2w[12];
        __oxray_motion_matrix(t, __OXRAY_TIME(__oxray_state().ray.time), o2w);
        if (inverse) {
            __oxray_inverse(o2w, scratch);
        } else {
            for (int k = 0; k < 12; ++k) scratch[k] = o2w[k];
        }
        return scratch;
    }
    const OptixStaticTransform* t = optixGetStaticTransformFromHandle(handle);
    return inverse ? t->invTransform : t->transform;
}

// c = a * b for 3x4 affine matrices (b applied first), the row-by-column sums left to right.
static __forceinline__ __device__ void __oxray_mul(const float* a, const float* b, float* c) {
    float r[12];
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 4; ++j) {
            float x = a[4 * i] * b[j] + a[4 * i + 1] * b[4 + j] + a[4 * i + 2] * b[8 + j];
            r[4 * i + j] = j == 3 ? x + a[4 * i + 3] : x;
        }
    }
    for (int k = 0; k < 12; ++k) c[k] = r[k];
}

// The transform list composed: object-to-world = T0 * T1 * ... (index 0 nearest the root),
// world-to-object = ... * inv(T1) * inv(T0), as the CPU backend composes them; one level is
// its matrices unchanged, none the identity.
static __forceinline__ __device__ void __oxray_composed(bool inverse, float m[12]) {
    const __oxray_Path* p = __oxray_state().ray.path;
    for (int k = 0; k < 12; ++k) m[k] = (k % 5 == 0) ? 1.0f : 0.0f;
    for (u32 l = 0; l < p->len; ++l) {
        float scratch[12];
        const float* t = __oxray_level_matrix(p->levels[l], inverse, scratch);
        if (l == 0) {
            for (int k = 0; k < 12; ++k) m[k] = t[k];
        } else if (inverse) {
            __oxray_mul(t, m, m);
        } else {
            __oxray_mul(m, t, m);
        }
    }
}
static __forceinline__ __device__ void optixGetObjectToWorldTransformMatrix(float m[12]) {
    __oxray_composed(false, m);
}
static __forceinline__ __device__ void optixGetWorldToObjectTransformMatrix(float m[12]) {
    __oxray_composed(true, m);
}
static __forceinline__ __device__ float3 __oxray_point(const float* m, float3 p) {
    return make_float3(m[0] * p.x + m[1] * p.y + m[2] * p.z + m[3],
                       m[4] * p.x + m[5] * p.y + m[6] * p.z + m[7],
                       m[8] * p.x + m[9] * p.y + m[10] * p.z + m[11]);
}
static __forceinline__ __device__ float3 __oxray_vector(const float* m, float3 v) {
    return make_float3(m[0] * v.x + m[1] * v.y + m[2] * v.z,
                       m[4] * v.x + m[5] * v.y + m[6] * v.z,
                       m[8] * v.x + m[9] * v.y + m[10] * v.z);
}
// A normal goes by the inverse transpose: `inv` is the inverse of the transform applied.
static __forceinline__ __device__ float3 __oxray_normal(const float* inv, float3 n) {
    return make_float3(inv[0] * n.x + inv[4] * n.y + inv[8] * n.z,
                       inv[1] * n.x + inv[5] * n.y + inv[9] * n.z,
                       inv[2] * n.x + inv[6] * n.y + inv[10] * n.z);
}
static __forceinline__ __device__ float3 optixTransformPointFromWorldToObjectSpace(float3 point) {
    float m[12];
    __oxray_composed(true, m);
    return __oxray_point(m, point);
}
static __forceinline__ __device__ float3 optixTransformVectorFromWorldToObjectSpace(float3 vec) {
    float m[12];
    __oxray_composed(true, m);
    return __oxray_vector(m, vec);
}
static __forceinline__ __device__ float3 optixTransformNormalFromWorldToObjectSpace(float3 normal) {
    float m[12];
    __oxray_composed(false, m);
    return __oxray_normal(m, normal);
}
static __forceinline__ __device__ float3 optixTransformPointFromObjectToWorldSpace(float3 point) {
    float m[12];
    __oxray_composed(false, m);
    return __oxray_point(m, point);
}
static __forceinline__ __device__ float3 optixTransformVectorFromObjectToWorldSpace(float3 vec) {
    float m[12];
    __oxray_composed(false, m);
    return __oxray_vector(m, vec);
}
static __forceinline__ __device__ float3 optixTransformNormalFromObjectToWorldSpace(float3 normal) {
    float m[12];
    __oxray_composed(true, m);
    return __oxray_normal(m, normal);
}

// The primitives of leaf slot `slot` of a GAS at `time` (GasData::triangle_at, sphere_at,
// curve_at): a GAS with motion interpolates its two keys around the time (a vanished one reads
// its first key), as traversal does.
static __forceinline__ __device__ void __oxray_triangle_at(const __oxray_Traversable* g, u32 slot,
                                                           float time, float4 q[3]) {
    const float4 *ka, *kb;
    float f;
    __oxray_gas_keys_at(g, time, ka, kb, f);
    for (int k = 0; k < 3; ++k) {
        q[k] = ka[3 * (size_t)slot + k];
        // A triangle at a key is that key's, zeros' signs included (lerp_triangle4).
        if (f != 0.0f) q[k] = __oxray_lerp4(q[k], kb[3 * (size_t)slot + k], f);
    }
}
static __forceinline__ __device__ float4 __oxray_sphere_at(const __oxray_Traversable* g, u32 slot,
                                                           float time) {
    const float4 *ka, *kb;
    float f;
    __oxray_gas_keys_at(g, time, ka, kb, f);
    return g->motion == 0ull ? ka[slot] : __oxray_lerp4(ka[slot], kb[slot], f);
}
static __forceinline__ __device__ void __oxray_curve_record_at(const __oxray_Traversable* g,
                                                               u32 slot, float time,
                                                               float4 rec[6]) {
    const float4 *ka, *kb;
    float f;
    __oxray_gas_keys_at(g, time, ka, kb, f);
    for (int k = 0; k < 6; ++k) rec[k] = ka[6 * (size_t)slot + k];
    if (f == 0.0f) return;
    // Control points and ribbon normals (22 floats) are interpolated; type and flags are key 0's.
    const float* a = reinterpret_cast<const float*>(ka + 6 * (size_t)slot);
    const float* b = reinterpret_cast<const float*>(kb + 6 * (size_t)slot);
    float* out = reinterpret_cast<float*>(rec);
    for (int k = 0; k < 22; ++k) out[k] = __oxray_lerp(a[k], b[k], f);
}

// The object-space vertices of the hit triangle, as uploaded (pre-transform applied) and, with
// motion, at the ray's time; zeros for a custom primitive.
static __forceinline__ __device__ void optixGetTriangleVertexData(float3 data[3]) {
    __oxray_ThreadState& s = __oxray_state();
    const __oxray_Traversable* g = __oxray_hit_gas();
    if (g == nullptr || g->kind != __OXRAY_GAS || s.ray.slot == 0xffffffffu) {
        for (int k = 0; k < 3; ++k) data[k] = make_float3(0.0f, 0.0f, 0.0f);
        return;
    }
    float4 q[3];
    __oxray_triangle_at(g, s.ray.slot, __OXRAY_TIME(s.ray.time), q);
    for (int k = 0; k < 3; ++k) data[k] = make_float3(q[k].x, q[k].y, q[k].z);
}

// Guide §9.4: the centre and radius of the hit sphere, in object space, as the build input gave
// them; zeros for a hit that is not a sphere, as on the CPU.
static __forceinline__ __device__ void optixGetSphereData(float4 data[1]) {
    __oxray_ThreadState& s = __oxray_state();
    const __oxray_Traversable* g = __oxray_hit_gas();
    if (g == nullptr || g->kind != __OXRAY_SPHERE_GAS || s.ray.slot == 0xffffffffu) {
        data[0] = make_float4(0.0f, 0.0f, 0.0f, 0.0f);
        return;
    }
    data[0] = __oxray_sphere_at(g, s.ray.slot, __OXRAY_TIME(s.ray.time));
}

// Guide §9.3: a curve hit's u in its segment (exactly 0 or 1 on a flat end cap), and a ribbon
// hit's (u, v): the hit's attributes, read as the CPU device's header reads them.
static __forceinline__ __device__ float optixGetCurveParameter() {
    return __uint_as_float(__oxray_state().ray.attr[0]);
}
static __forceinline__ __device__ float2 optixGetRibbonParameters() {
    const __oxray_ThreadState& s = __oxray_state();
    return make_float2(__uint_as_float(s.ray.attr[0]), __uint_as_float(s.ray.attr[1]));
}
// The control points (x, y, z, radius) of the hit segment in object space, as the build input
// gave them: the first n of its record (zeros when the hit is not a curve).
static __forceinline__ __device__ void __oxray_curve_vertex_data(float4* data, int n) {
    __oxray_ThreadState& s = __oxray_state();
    const __oxray_Traversable* g = __oxray_hit_gas();
    const bool curve = g != nullptr && g->kind == __OXRAY_CURVE_GAS && s.ray.slot != 0xffffffffu;
    float4 rec[6];
    if (curve) __oxray_curve_record_at(g, s.ray.slot, __OXRAY_TIME(s.ray.time), rec);
    for (int k = 0; k < n; ++k) data[k] = curve ? rec[k] : make_float4(0.0f, 0.0f, 0.0f, 0.0f);
}
// Guide §9.3: the geometric normal of the hit ribbon at `ribbonParameters` (u, v): unit length,
// object space, out of the front face; zeros when the hit is not a ribbon.
// oxray_bvh::CurveSegment::ribbon_normal, operation for operation in double precision.
static __forceinline__ __device__ float3 optixGetRibbonNormal(float2 ribbonParameters) {
    __oxray_ThreadState& st = __oxray_state();
    const __oxray_Traversable* g = __oxray_hit_gas();
    const float3 zero = make_float3(0.0f, 0.0f, 0.0f);
    if (g == nullptr || g->kind != __OXRAY_CURVE_GAS || st.ray.slot == 0xffffffffu) return zero;
    CurveRecord c;
    __oxray_curve_record_at(g, st.ray.slot, __OXRAY_TIME(st.ray.time),
                            reinterpret_cast<float4*>(&c));
    if (c.type != 0x2505u) return zero;
    const double u = (double)ribbonParameters.x, v = (double)ribbonParameters.y;
    double a[3][4];
    for (int d = 0; d < 4; ++d) {
        const double p0 = (double)c.p[0][d], p1 = (double)c.p[1][d], p2 = (double)c.p[2][d];
        a[0][d] = 0.5 * (p0 + p1);
        a[1][d] = p1 - p0;
        a[2][d] = 0.5 * (p0 - 2.0 * p1 + p2);
    }
    auto add = [](D3 x, D3 y) { return d3(x.x + y.x, x.y + y.y, x.z + y.z); };
    auto scale = [](D3 x, double k) { return d3(x.x * k, x.y * k, x.z * k); };
    const D3 a1 = d3(a[1][0], a[1][1], a[1][2]), a2 = d3(a[2][0], a[2][1], a[2][2]);
    const D3 tangent = add(a1, scale(a2, 2.0 * u));
    const D3 second = scale(a2, 2.0);
    const double r = (a[2][3] * u + a[1][3]) * u + a[0][3];
    const double dr = 2.0 * a[2][3] * u + a[1][3];
    D3 m, dm;
    if ((c.flags & CURVE_HAS_NORMALS) != 0u) {
        const D3 n0 = d3((double)c.normals[0][0], (double)c.normals[0][1], (double)c.normals[0][2]);
        const D3 n1 = d3((double)c.normals[1][0], (double)c.normals[1][1], (double)c.normals[1][2]);
        const D3 dn = d3_sub(n1, n0);
        const D3 n = add(n0, scale(dn, u));
        m = d3_cross(n, tangent);
        dm = add(d3_cross(dn, tangent), d3_cross(n, second));
    } else {
        const float3 df = optixGetObjectRayDirection();
        const D3 dir = d3((double)df.x, (double)df.y, (double)df.z);
        m = d3_cross(tangent, dir);
        dm = d3_cross(second, dir);
    }
    const double len = sqrt(d3_dot(m, m));
    if (isnan(len) || len <= 0.0) return zero;
    const D3 w = d3(m.x / len, m.y / len, m.z / len);
    const D3 t = d3_sub(dm, scale(w, d3_dot(w, dm)));
    const D3 dw = d3(t.x / len, t.y / len, t.z / len);
    const D3 du = add(tangent, scale(add(scale(w, dr), scale(dw, r)), v));
    const D3 normal = d3_cross(du, w);
    const double nl = sqrt(d3_dot(normal, normal));
    if (isnan(nl) || nl <= 0.0) return zero;
    return make_float3((float)(normal.x / nl), (float)(normal.y / nl), (float)(normal.z / nl));
}
static __forceinline__ __device__ void optixGetLinearCurveVertexData(float4 data[2]) {
    __oxray_curve_vertex_data(data, 2);
}
static __forceinline__ __device__ void optixGetQuadraticBSplineVertexData(float4 data[3]) {
    __oxray_curve_vertex_data(data, 3);
}
static __forceinline__ __device__ void optixGetQuadraticBSplineRocapsVertexData(float4 data[3]) {
    __oxray_curve_vertex_data(data, 3);
}
static __forceinline__ __device__ void optixGetCubicBSplineVertexData(float4 data[4]) {
    __oxray_curve_vertex_data(data, 4);
}
static __forceinline__ __device__ void optixGetCubicBSplineRocapsVertexData(float4 data[4]) {
    __oxray_curve_vertex_data(data, 4);
}
static __forceinline__ __device__ void optixGetCatmullRomVertexData(float4 data[4]) {
    __oxray_curve_vertex_data(data, 4);
}
static __forceinline__ __device__ void optixGetCatmullRomRocapsVertexData(float4 data[4]) {
    __oxray_curve_vertex_data(data, 4);
}
static __forceinline__ __device__ void optixGetCubicBezierVertexData(float4 data[4]) {
    __oxray_curve_vertex_data(data, 4);
}
static __forceinline__ __device__ void optixGetCubicBezierRocapsVertexData(float4 data[4]) {
    __oxray_curve_vertex_data(data, 4);
}
static __forceinline__ __device__ void optixGetRibbonVertexData(float4 data[3]) {
    __oxray_curve_vertex_data(data, 3);
}

// Guide §13.9: random vertex access, from any program, to a GAS built with
// OPTIX_BUILD_FLAG_ALLOW_RANDOM_VERTEX_ACCESS. The GAS keeps a table (words): the number of
// inputs and of primitives, then per input its first global primitive, primitive index offset,
// first SBT-GAS index and the end of its SBT-GAS indices, then each primitive's leaf slot
// (~0u: left out by the builder). A primitive left out reads NaN; so does an access OptiX leaves
// undefined (no flag, another kind, an index out of range), as on the CPU.
static __forceinline__ __device__ u32 __oxray_random_slot(OptixTraversableHandle gas, u32 kind,
                                                          u32 prim, u32 sbt) {
    if (__oxray_kind_of(gas) != kind) return 0xffffffffu;
    const __oxray_Traversable* t = reinterpret_cast<const __oxray_Traversable*>(gas);
    if (t->random == 0ull) return 0xffffffffu;
    const u32* w = reinterpret_cast<const u32*>(t->random);
    const u32 n = w[0], np = w[1];
    const u32* in = w + 2;
    u32 lo = 0, hi = n;  // the last input whose first SBT-GAS index is at most sbt
    while (lo < hi) {
        const u32 mid = (lo + hi) >> 1;
        if (in[4 * mid + 2] <= sbt) lo = mid + 1;
        else hi = mid;
    }
    if (lo == 0) return 0xffffffffu;
    const u32 i = lo - 1;
    if (sbt >= in[4 * i + 3] || prim < in[4 * i + 1]) return 0xffffffffu;
    const unsigned long long g = (unsigned long long)in[4 * i] + (prim - in[4 * i + 1]);
    const u32 end = i + 1 < n ? in[4 * (i + 1)] : np;
    if (g >= end) return 0xffffffffu;
    return w[2 + 4 * (size_t)n + g];
}
static __forceinline__ __device__ void optixGetTriangleVertexDataFromHandle(
    OptixTraversableHandle gas, unsigned int primIdx, unsigned int sbtGASIdx, float time,
    float3 data[3]) {
    const u32 slot = __oxray_random_slot(gas, __OXRAY_GAS, primIdx, sbtGASIdx);
    const float nan = __int_as_float(0x7fc00000);
    if (slot == 0xffffffffu) {
        for (int k = 0; k < 3; ++k) data[k] = make_float3(nan, nan, nan);
        return;
    }
    float4 q[3];
    __oxray_triangle_at(reinterpret_cast<const __oxray_Traversable*>(gas), slot, time, q);
    for (int k = 0; k < 3; ++k) data[k] = make_float3(q[k].x, q[k].y, q[k].z);
}
static __forceinline__ __device__ void optixGetSphereDataFromHandle(OptixTraversableHandle gas,
                                                                    unsigned int primIdx,
                                                                    unsigned int sbtGASIdx,
                                                                    float time, float4 data[1]) {
    const u32 slot = __oxray_random_slot(gas, __OXRAY_SPHERE_GAS, primIdx, sbtGASIdx);
    const float nan = __int_as_float(0x7fc00000);
    data[0] = slot == 0xffffffffu
                  ? make_float4(nan, nan, nan, nan)
                  : __oxray_sphere_at(reinterpret_cast<const __oxray_Traversable*>(gas), slot,
                                      time);
}
static __forceinline__ __device__ void __oxray_curve_data_from_handle(OptixTraversableHandle gas,
                                                                      unsigned int primIdx,
                                                                      unsigned int sbtGASIdx,
                                                                      float time, float4* data,
                                                                      int n) {
    const u32 slot = __oxray_random_slot(gas, __OXRAY_CURVE_GAS, primIdx, sbtGASIdx);
    const float nan = __int_as_float(0x7fc00000);
    if (slot == 0xffffffffu) {
        for (int k = 0; k < n; ++k) data[k] = make_float4(nan, nan, nan, nan);
        return;
    }
    float4 rec[6];
    __oxray_curve_record_at(reinterpret_cast<const __oxray_Traversable*>(gas), slot, time, rec);
    for (int k = 0; k < n; ++k) data[k] = rec[k];
}
#define __OXRAY_CURVE_FROM_HANDLE(name, n)                                                      \
    static __forceinline__ __device__ void name(OptixTraversableHandle gas, unsigned int primIdx, \
                                                unsigned int sbtGASIdx, float time,             \
                                                float4 data[n]) {                               \
        __oxray_curve_data_from_handle(gas, primIdx, sbtGASIdx, time, data, n);                 \
    }
__OXRAY_CURVE_FROM_HANDLE(optixGetLinearCurveVertexDataFromHandle, 2)
__OXRAY_CURVE_FROM_HANDLE(optixGetQuadraticBSplineVertexDataFromHandle, 3)
__OXRAY_CURVE_FROM_HANDLE(optixGetQuadraticBSplineRocapsVertexDataFromHandle, 3)
__OXRAY_CURVE_FROM_HANDLE(optixGetCubicBSplineVertexDataFromHandle, 4)
__OXRAY_CURVE_FROM_HANDLE(optixGetCubicBSplineRocapsVertexDataFromHandle, 4)
__OXRAY_CURVE_FROM_HANDLE(optixGetCatmullRomVertexDataFromHandle, 4)
__OXRAY_CURVE_FROM_HANDLE(optixGetCatmullRomRocapsVertexDataFromHandle, 4)
__OXRAY_CURVE_FROM_HANDLE(optixGetCubicBezierVertexDataFromHandle, 4)
__OXRAY_CURVE_FROM_HANDLE(optixGetCubicBezierRocapsVertexDataFromHandle, 4)
__OXRAY_CURVE_FROM_HANDLE(optixGetRibbonVertexDataFromHandle, 3)
#undef __OXRAY_CURVE_FROM_HANDLE

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

// The first of the two an any-hit program calls takes effect (a later call does nothing), as on
// the CPU, where the first does not return.
static __forceinline__ __device__ void optixIgnoreIntersection() {
    __oxray_ThreadState& s = __oxray_state();
    if (s.ah_action == 0u) s.ah_action = 1u;
}
static __forceinline__ __device__ void optixTerminateRay() {
    __oxray_ThreadState& s = __oxray_state();
    if (s.ah_action == 0u) s.ah_action = 2u;
}

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
// oxray keeps no line information: null, as OptiX gives without it (§13.14).
static __forceinline__ __device__ char* optixGetExceptionLineInfo() { return nullptr; }
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

// The closest accepted hit, with where its geometry sits.
struct __oxray_Best {
    bool found;
    float t;
    u32 prim, sbt_gas_index, hit_kind, slot;
    u32 attr[8];
    const char* record;
    __oxray_Path path;
};

struct __oxray_TraceArgs {
    u32 flags, sbt_offset, sbt_stride;
    float time;  // the traversal's time (__OXRAY_TIME of the ray's)
};

// What optixReportIntersection works with while an intersection program runs: the primitive,
// its record, and the traversal's closest hit and interval.
struct __oxray_Report {
    const __oxray_TraceArgs* a;
    const __oxray_Path* path;
    __oxray_Best* best;
    const char* record;
    u32 prim, sbt_gas_index, gflags;
    float tmax;  // the interval's end: the closest accepted hit, or the trace's tmax
    bool stop;   // an any-hit program terminated (or TERMINATE_ON_FIRST_HIT): traversal ends
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

// CULL_DISABLED_ANYHIT / CULL_ENFORCED_ANYHIT: the primitive is no candidate at all.
static __forceinline__ __device__ bool __oxray_culled_by_anyhit(u32 rflags, bool ah_on) {
    return ((rflags & OPTIX_RAY_FLAG_CULL_DISABLED_ANYHIT) && !ah_on) ||
           ((rflags & OPTIX_RAY_FLAG_CULL_ENFORCED_ANYHIT) && ah_on);
}

// The hit-group record of SBT-GAS index `sbt_gas_index` under `path` (§7.3); raises
// INVALID_HIT_SBT beyond the region.
static __forceinline__ __device__ const char* __oxray_hit_record(const __oxray_TraceArgs& a,
                                                                const __oxray_Path& path,
                                                                u32 sbt_gas_index) {
    unsigned long long rec = (unsigned long long)path.sbt_offset +
                             (unsigned long long)sbt_gas_index * (a.sbt_stride & 0xFu) +
                             (a.sbt_offset & 0xFu);
    if (rec >= __oxray_launch.hit_count) {
        u32 d[2] = {rec > 0xffffffffull ? 0xffffffffu : (u32)rec, sbt_gas_index};
        __oxray_throw(OPTIX_EXCEPTION_CODE_INVALID_HIT_SBT, 2, d);
    }
    return reinterpret_cast<const char*>(__oxray_launch.hitgroup) + rec * __oxray_launch.hit_stride;
}

static __forceinline__ __device__ void __oxray_copy_path(__oxray_Path& to, const __oxray_Path& from) {
    to.len = from.len;
    to.sbt_offset = from.sbt_offset;
    to.instance_id = from.instance_id;
    to.instance_index = from.instance_index;
    to.iflags = from.iflags;
    to.gas = from.gas;
    to.org = from.org;
    to.dir = from.dir;
    for (u32 l = 0; l < from.len; ++l) to.levels[l] = from.levels[l];
}

// A candidate in the interval (culling done): the any-hit program runs if it is on (§13.2),
// and an accepted candidate becomes the closest hit. 0: ignored; 1: accepted; 2: accepted,
// and traversal ends (terminate, or TERMINATE_ON_FIRST_HIT).
static __forceinline__ __device__ u32 __oxray_candidate(const __oxray_TraceArgs& a,
                                                        const __oxray_Path& path, u32 gflags,
                                                        const char* record, float t, u32 prim,
                                                        u32 sbt_gas_index, u32 kind, u32 slot,
                                                        const u32* attr, __oxray_Best& best) {
    bool terminate = (a.flags & OPTIX_RAY_FLAG_TERMINATE_ON_FIRST_HIT) != 0u;
    u32 group = __oxray_group_of(record);
    if (__oxray_anyhit_on(a.flags, path.iflags, gflags) && __oxray_has_anyhit(group)) {
        __oxray_ThreadState& st = __oxray_state();
        const char* saved = st.record;
        float saved_tmax = st.ray.tmax;
        st.record = record;
        st.ray.tmax = t;
        st.ray.prim = prim;
        st.ray.sbt_gas_index = sbt_gas_index;
        st.ray.hit_kind = kind;
        st.ray.slot = slot;
        for (int k = 0; k < 8; ++k) st.ray.attr[k] = attr[k];
        st.ray.path = &path;
        st.ah_action = 0u;
        __oxray_call_anyhit(group);
        st.record = saved;
        st.ray.tmax = saved_tmax;
        u32 action = st.ah_action;
        st.ah_action = 0u;
        if (action == 1u) return 0u;
        if (action == 2u) terminate = true;
    }
    best.found = true;
    best.t = t;
    best.prim = prim;
    best.sbt_gas_index = sbt_gas_index;
    best.hit_kind = kind;
    best.slot = slot;
    for (int k = 0; k < 8; ++k) best.attr[k] = attr[k];
    best.record = record;
    __oxray_copy_path(best.path, path);
    return terminate ? 2u : 1u;
}

// Whether the pipeline's primitive types (§6.3) include `bits`: an empty set means triangles
// and custom primitives.
#define __OXRAY_TYPE_TRIANGLE (1u << 31)
#define __OXRAY_TYPE_CUSTOM 1u
#define __OXRAY_TYPE_SPHERE (1u << 6)
#define __OXRAY_TYPE_CURVES (0xFBEu)
#define __OXRAY_TYPES                                                                         \
    (OXRAY_PRIMITIVE_TYPE_FLAGS == 0u ? (__OXRAY_TYPE_TRIANGLE | __OXRAY_TYPE_CUSTOM)          \
                                      : OXRAY_PRIMITIVE_TYPE_FLAGS)
#define __OXRAY_USES_TYPE(bits) ((__OXRAY_TYPES & (bits)) != 0u)
// A pipeline whose graph flags allow a single GAS and nothing else (§5.9.1): its root check
// rejects every other traversable, so no trace reaches an instance or a transform.
#define __OXRAY_SINGLE_GAS_ONLY (OXRAY_GRAPH_FLAGS == 1u)

// The pipeline's primitive types (§6.3), wherever in the graph a GAS sits. An empty set means
// triangles and custom primitives: spheres and curves must be named (§9.1), a curve GAS's every
// type (its descriptor's `types`).
static __forceinline__ __device__ void __oxray_check_primitive_type(const __oxray_Traversable* g) {
    const u32 kind = g->kind;
    u32 needed = kind == __OXRAY_GAS          ? __OXRAY_TYPE_TRIANGLE
                 : kind == __OXRAY_SPHERE_GAS ? __OXRAY_TYPE_SPHERE
                 : kind == __OXRAY_CURVE_GAS  ? g->types
                                              : __OXRAY_TYPE_CUSTOM;
    if ((__OXRAY_TYPES & needed) != needed) {
        __oxray_throw(OPTIX_EXCEPTION_CODE_UNSUPPORTED_PRIMITIVE_TYPE, 0, nullptr);
    }
}

// Traverses a triangle GAS with the object-space ray `r`, offering every triangle in the
// interval to the any-hit rules; `tmax` shrinks to accepted hits. True when traversal ends.
static __noinline__ __device__ bool __oxray_walk_triangles(const TraceRay& r,
                                                           const __oxray_Traversable* g,
                                                           const __oxray_TraceArgs& a,
                                                           const __oxray_Path& path, float tmin,
                                                           float& tmax, __oxray_Best& best) {
    const float4* nodes = reinterpret_cast<const float4*>(g->nodes);
    // With motion (§5.10.2), the two keys around the ray's time, interpolated per triangle (a
    // triangle at a key is that key's exactly, as on the CPU); the tree bounds every key.
    const float4 *tris, *tris_b;
    float f;
    if (!__oxray_gas_keys(g, a.time, tris, tris_b, f)) return false;
    const uint2* slots = reinterpret_cast<const uint2*>(g->info);
    const u32* gflags_of = reinterpret_cast<const u32*>(g->geom_flags);
    bool ended = false;
    walk_bvh2<OXRAY_BVH2_STACK>(r, nodes, tmin, tmax, [&](u32 start, u32 count, float& tmax_) {
        for (u32 s = start; s < start + count; ++s) {
            float4 q0 = tris[3 * s];
            float4 q1 = tris[3 * s + 1];
            float4 q2 = tris[3 * s + 2];
            if (f != 0.0f) {
                q0 = __oxray_lerp4(q0, tris_b[3 * s], f);
                q1 = __oxray_lerp4(q1, tris_b[3 * s + 1], f);
                q2 = __oxray_lerp4(q2, tris_b[3 * s + 2], f);
            }
            TriHit h;
            if (!intersect_triangle(r, make_float3(q0.x, q0.y, q0.z),
                                    make_float3(q1.x, q1.y, q1.z),
                                    make_float3(q2.x, q2.y, q2.z), tmin, tmax_, h)) {
                continue;
            }
            uint2 info = slots[s];
            u32 gflags = gflags_of[info.y];
            bool front = h.front != ((path.iflags & __OXRAY_INSTANCE_FLIP_FACING) != 0u);
            bool no_culling = (gflags & __OXRAY_GEOMETRY_DISABLE_CULLING) ||
                              (path.iflags & __OXRAY_INSTANCE_DISABLE_CULLING);
            if (!no_culling) {
                if (((a.flags & OPTIX_RAY_FLAG_CULL_BACK_FACING_TRIANGLES) && !front) ||
                    ((a.flags & OPTIX_RAY_FLAG_CULL_FRONT_FACING_TRIANGLES) && front)) {
                    continue;
                }
            }
            const char* record = __oxray_hit_record(a, path, info.y);
            if (__oxray_culled_by_anyhit(a.flags, __oxray_anyhit_on(a.flags, path.iflags, gflags))) {
                continue;
            }
            u32 kind = front ? OPTIX_HIT_KIND_TRIANGLE_FRONT_FACE : OPTIX_HIT_KIND_TRIANGLE_BACK_FACE;
            u32 attr[8] = {__float_as_uint(h.u), __float_as_uint(h.v), 0u, 0u, 0u, 0u, 0u, 0u};
            u32 d = __oxray_candidate(a, path, gflags, record, h.t, info.x, info.y, kind, s, attr,
                                      best);
            if (d == 0u) continue;
            tmax_ = h.t;
            tmax = h.t;
            if (d == 2u) {
                ended = true;
                return true;
            }
        }
        return false;
    });
    return ended;
}

// A hit of a built-in primitive in the interval (a sphere's or a curve's, at leaf slot `s` of a
// GAS whose slot and geometry-flag tables are `slots` and `gflags_of`, with attributes u and v):
// no face culling; culled by its any-hit state (CULL_*_ANYHIT), or else offered as a candidate
// (__oxray_candidate), and once accepted `tmax_` (the walk's) and `tmax` shrink to it. True when
// traversal ends.
static __forceinline__ __device__ bool __oxray_offer_builtin(const uint2* slots,
                                                             const u32* gflags_of,
                                                             const __oxray_TraceArgs& a,
                                                             const __oxray_Path& path, u32 s,
                                                             float t, float u, float v, u32 kind,
                                                             float& tmax_, float& tmax,
                                                             __oxray_Best& best) {
    uint2 info = slots[s];
    u32 gflags = gflags_of[info.y];
    const char* record = __oxray_hit_record(a, path, info.y);
    if (__oxray_culled_by_anyhit(a.flags, __oxray_anyhit_on(a.flags, path.iflags, gflags))) {
        return false;
    }
    u32 attr[8] = {__float_as_uint(u), __float_as_uint(v), 0u, 0u, 0u, 0u, 0u, 0u};
    u32 d = __oxray_candidate(a, path, gflags, record, t, info.x, info.y, kind, s, attr, best);
    if (d == 0u) return false;
    tmax_ = t;
    tmax = t;
    return d == 2u;
}

// The hit kind of a sphere's front face: 0x80 | (OPTIX_PRIMITIVE_TYPE_SPHERE & 0xFF) << 1.
#define __OXRAY_HIT_KIND_SPHERE_FRONT_FACE 0x8Cu

// Traverses a GAS of built-in spheres (§9.4) with the object-space ray `r`: each sphere's entry
// point in the interval is a candidate (spheres are hollow, their back faces culled, §9.6); the
// triangle face-culling flags do not apply, the any-hit rules and CULL_*_ANYHIT do.
static __noinline__ __device__ bool __oxray_walk_spheres(const TraceRay& r,
                                                         const __oxray_Traversable* g,
                                                         const __oxray_TraceArgs& a,
                                                         const __oxray_Path& path, float tmin,
                                                         float& tmax, __oxray_Best& best) {
    const float4* nodes = reinterpret_cast<const float4*>(g->nodes);
    const float4 *spheres, *spheres_b;
    float f;
    if (!__oxray_gas_keys(g, a.time, spheres, spheres_b, f)) return false;
    const bool motion = g->motion != 0ull;
    const uint2* slots = reinterpret_cast<const uint2*>(g->info);
    const u32* gflags_of = reinterpret_cast<const u32*>(g->geom_flags);
    bool ended = false;
    walk_bvh2<OXRAY_BVH2_STACK>(r, nodes, tmin, tmax, [&](u32 start, u32 count, float& tmax_) {
        for (u32 s = start; s < start + count; ++s) {
            float t;
            // With motion every sphere is interpolated, at a key too (lerp_sphere).
            const float4 sp = motion ? __oxray_lerp4(spheres[s], spheres_b[s], f) : spheres[s];
            if (!intersect_sphere(r, sp, tmin, tmax_, t)) continue;
            if (__oxray_offer_builtin(slots, gflags_of, a, path, s, t, 0.0f, 0.0f,
                                      __OXRAY_HIT_KIND_SPHERE_FRONT_FACE, tmax_, tmax, best)) {
                ended = true;
                return true;
            }
        }
        return false;
    });
    return ended;
}

// Traverses a GAS of built-in curves (§9.3) with the object-space ray `r`: each segment's
// nearest entry (a round tube's front face, §9.6, or a ribbon's either face) in the interval is a
// candidate with its u (and a ribbon's v) as attributes. As for spheres, the triangle
// face-culling flags do not apply, the any-hit rules and CULL_*_ANYHIT do.
static __noinline__ __device__ bool __oxray_walk_curves(const TraceRay& r,
                                                        const __oxray_Traversable* g,
                                                        const __oxray_TraceArgs& a,
                                                        const __oxray_Path& path, float tmin,
                                                        float& tmax, __oxray_Best& best) {
    const float4* nodes = reinterpret_cast<const float4*>(g->nodes);
    const float4 *curves, *curves_b;
    float f;
    if (!__oxray_gas_keys(g, a.time, curves, curves_b, f)) return false;
    const uint2* slots = reinterpret_cast<const uint2*>(g->info);
    const u32* gflags_of = reinterpret_cast<const u32*>(g->geom_flags);
    bool ended = false;
    walk_bvh2<OXRAY_BVH2_STACK>(r, nodes, tmin, tmax, [&](u32 start, u32 count, float& tmax_) {
        for (u32 s = start; s < start + count; ++s) {
            CurveRecord c = load_curve(curves, s);
            if (f != 0.0f) {
                // Control points and ribbon normals between the keys (lerp_curve).
                const CurveRecord b = load_curve(curves_b, s);
                float* cw = &c.p[0][0];
                const float* bw = &b.p[0][0];
                for (int k = 0; k < 22; ++k) cw[k] = __oxray_lerp(cw[k], bw[k], f);
            }
            CurveHit h;
            if (!curve_intersect(c, r.org, r.dir, tmin, tmax_, h)) continue;
            if (__oxray_offer_builtin(slots, gflags_of, a, path, s, h.t, h.u, h.v,
                                      curve_hit_kind(c.type, h.back_face), tmax_, tmax, best)) {
                ended = true;
                return true;
            }
        }
        return false;
    });
    return ended;
}

// Traverses a GAS of custom primitives: the intersection program of every primitive whose box
// the ray enters in the interval runs, and reports through optixReportIntersection.
static __noinline__ __device__ bool __oxray_walk_custom(const TraceRay& r,
                                                        const __oxray_Traversable* g,
                                                        const __oxray_TraceArgs& a,
                                                        const __oxray_Path& path, float tmin,
                                                        float& tmax, __oxray_Best& best) {
    const float4* nodes = reinterpret_cast<const float4*>(g->nodes);
    const float4 *boxes, *boxes_b;
    float f;
    if (!__oxray_gas_keys(g, a.time, boxes, boxes_b, f)) return false;
    const bool motion = g->motion != 0ull;
    const uint2* slots = reinterpret_cast<const uint2*>(g->info);
    const u32* gflags_of = reinterpret_cast<const u32*>(g->geom_flags);
    bool ended = false;
    walk_bvh2<OXRAY_BVH2_STACK>(r, nodes, tmin, tmax, [&](u32 start, u32 count, float& tmax_) {
        for (u32 s = start; s < start + count; ++s) {
            // With motion the box between the keys, corner by corner (lerp_aabb, §5.10.1).
            float4 lo = boxes[2 * s], hi = boxes[2 * s + 1];
            if (motion) {
                lo = __oxray_lerp4(lo, boxes_b[2 * s], f);
                hi = __oxray_lerp4(hi, boxes_b[2 * s + 1], f);
            }
            if (!hits_box(r, lo, hi, tmin, tmax_)) continue;
            uint2 info = slots[s];
            u32 gflags = gflags_of[info.y];
            const char* record = __oxray_hit_record(a, path, info.y);
            u32 group = __oxray_group_of(record);
            if (!__oxray_has_intersection(group)) continue;
            // A primitive culled by its any-hit state never reaches its intersection program.
            if (__oxray_culled_by_anyhit(a.flags, __oxray_anyhit_on(a.flags, path.iflags, gflags))) {
                continue;
            }
            __oxray_Report rep;
            rep.a = &a;
            rep.path = &path;
            rep.best = &best;
            rep.record = record;
            rep.prim = info.x;
            rep.sbt_gas_index = info.y;
            rep.gflags = gflags;
            rep.tmax = tmax_;
            rep.stop = false;
            __oxray_ThreadState& st = __oxray_state();
            const char* saved = st.record;
            st.record = record;
            st.report = &rep;
            st.ray.tmax = tmax_;
            st.ray.prim = info.x;
            st.ray.sbt_gas_index = info.y;
            st.ray.hit_kind = 0u;
            st.ray.slot = 0xffffffffu;
            st.ray.path = &path;
            __oxray_call_intersection(group);
            st.report = nullptr;
            st.record = saved;
            if (rep.tmax < tmax_) {
                tmax_ = rep.tmax;
                tmax = rep.tmax;
            }
            if (rep.stop) {
                ended = true;
                return true;
            }
        }
        return false;
    });
    return ended;
}

// The guide's optixReportIntersection: a hit at hitT of the primitive whose intersection
// program runs, with hit kind `hitKind` (its low 7 bits) and up to eight attribute words (those
// past the pipeline's numAttributeValues are dropped). Outside [tmin, current tmax] it is
// ignored (false); otherwise the any-hit rules run: false if the any-hit program ignored it,
// true if it was accepted (the interval then ends at hitT). When the any-hit program
// terminates the ray, OptiX does not return: here the report returns true, traversal ends when
// the intersection program returns, and later reports do nothing (return right after it).
template <typename... A>
static __forceinline__ __device__ bool optixReportIntersection(float hitT, unsigned int hitKind,
                                                               A... attributes) {
    static_assert(sizeof...(A) <= 8, "optixReportIntersection takes at most 8 attributes");
    __oxray_ThreadState& st = __oxray_state();
    __oxray_Report* rep = static_cast<__oxray_Report*>(st.report);
    if (rep == nullptr || rep->stop) return false;
    if (!(hitT >= st.ray.tmin && hitT <= rep->tmax)) return false;
    u32 given[8] = {static_cast<u32>(attributes)...};
    u32 attr[8];
    for (u32 k = 0; k < 8; ++k) {
        attr[k] = (k < sizeof...(A) && k < OXRAY_NUM_ATTRIBUTE_VALUES) ? given[k] : 0u;
    }
    u32 d = __oxray_candidate(*rep->a, *rep->path, rep->gflags, rep->record, hitT, rep->prim,
                              rep->sbt_gas_index, hitKind & 0x7Fu, 0xffffffffu, attr, *rep->best);
    // The intersection program sees its own primitive again.
    st.ray.prim = rep->prim;
    st.ray.sbt_gas_index = rep->sbt_gas_index;
    st.ray.path = rep->path;
    if (d == 0u) return false;
    rep->tmax = hitT;
    st.ray.tmax = hitT;
    if (d == 2u) rep->stop = true;
    return true;
}

static __noinline__ __device__ bool __oxray_walk(const __oxray_Traversable* t,
                                                 const TraceRay& r, const __oxray_TraceArgs& a,
                                                 __oxray_Path& path, float tmin, float& tmax,
                                                 __oxray_Best& best);

// The ray in a child's space: `m` is the world-to-object matrix (12 floats, row-major),
// applied as Transform::transform_point and transform_vector on the CPU, in the same order.
static __forceinline__ __device__ bool __oxray_child_ray(const float* m, const TraceRay& r,
                                                        float tmin, float tmax, TraceRay& o) {
    o.org = __oxray_point(m, r.org);
    o.dir = __oxray_vector(m, r.dir);
    o.tmin = tmin;
    o.tmax = tmax;
    return prepare_ray(o);
}

// Enters `child` one level down the path (an instance or a static transform `level`); the path
// is as it was when this returns.
static __forceinline__ __device__ bool __oxray_descend(const __oxray_Traversable* child,
                                                      unsigned long long level,
                                                      const __oxray_Instance* inst,
                                                      const TraceRay& o,
                                                      const __oxray_TraceArgs& a,
                                                      __oxray_Path& path, float tmin, float& tmax,
                                                      __oxray_Best& best) {
    if (path.len >= __OXRAY_MAX_LEVELS) {
        __oxray_throw(OPTIX_EXCEPTION_CODE_TRAVERSAL_DEPTH_EXCEEDED, 0, nullptr);
    }
    u32 len = path.len, sbt = path.sbt_offset, id = path.instance_id;
    u32 index = path.instance_index, iflags = path.iflags;
    path.levels[path.len++] = level;
    if (inst != nullptr) {
        // Nested instances add their SBT offsets; the nearest one's id, index and flags count.
        path.sbt_offset += inst->sbt_offset;
        path.instance_id = inst->id;
        path.instance_index = inst->index;
        path.iflags = inst->flags;
    }
    bool stop = __oxray_walk(child, o, a, path, tmin, tmax, best);
    path.len = len;
    path.sbt_offset = sbt;
    path.instance_id = id;
    path.instance_index = index;
    path.iflags = iflags;
    return stop;
}

// An IAS: the top-level binary tree; each instance's mask and world box tested (§5.4, §13.2),
// the ray carried into its space with the interval as it has shrunk, its child traversed.
static __noinline__ __device__ bool __oxray_walk_ias(const TraceRay& r,
                                                     const __oxray_Traversable* t,
                                                     const __oxray_TraceArgs& a,
                                                     __oxray_Path& path, float tmin, float& tmax,
                                                     __oxray_Best& best) {
    const float4* top = reinterpret_cast<const float4*>(t->nodes);
    const float4* table = reinterpret_cast<const float4*>(t->prims);
    const __oxray_Instance* insts = reinterpret_cast<const __oxray_Instance*>(t->info);
    const u32 ray_mask = __oxray_state().ray.mask;
    bool ended = false;
    walk_bvh2<OXRAY_BVH2_STACK>(r, top, tmin, tmax, [&](u32 start, u32 count, float& tmax_) {
        for (u32 s = start; s < start + count; ++s) {
            const __oxray_Instance* in = insts + s;
            if ((in->mask & ray_mask & 0xFFu) == 0u) continue;
            const float4* q = table + 6 * (size_t)s;
            if (!hits_box(r, q[3], q[4], tmin, tmax_)) continue;
            if (in->child == 0ull) continue;
            TraceRay o;
            if (!__oxray_child_ray(reinterpret_cast<const float*>(in->world_to_object), r, tmin,
                                   tmax_, o)) {
                continue;
            }
            float tm = tmax_;
            bool stop = __oxray_descend(reinterpret_cast<const __oxray_Traversable*>(in->child),
                                        reinterpret_cast<unsigned long long>(in), in, o, a, path,
                                        tmin, tm, best);
            if (tm < tmax_) {
                tmax_ = tm;
                tmax = tm;
            }
            if (stop) {
                ended = true;
                return true;
            }
        }
        return false;
    });
    return ended;
}

// Traverses the graph under `t` with the ray `r` (prepared, in `t`'s space). True when
// traversal ends.
static __noinline__ __device__ bool __oxray_walk(const __oxray_Traversable* t, const TraceRay& r,
                                                 const __oxray_TraceArgs& a, __oxray_Path& path,
                                                 float tmin, float& tmax, __oxray_Best& best) {
    switch (t->kind) {
    case __OXRAY_GAS:
    case __OXRAY_CUSTOM_GAS:
    case __OXRAY_SPHERE_GAS:
    case __OXRAY_CURVE_GAS:
        __oxray_check_primitive_type(t);
        path.gas = t;
        path.org = r.org;
        path.dir = r.dir;
        // The walks of types the pipeline does not use are left out of its kernel (the
        // check above has thrown for them), so that their registers do not size it.
        if (__OXRAY_USES_TYPE(__OXRAY_TYPE_TRIANGLE) && t->kind == __OXRAY_GAS) {
            return __oxray_walk_triangles(r, t, a, path, tmin, tmax, best);
        }
        if (__OXRAY_USES_TYPE(__OXRAY_TYPE_SPHERE) && t->kind == __OXRAY_SPHERE_GAS) {
            return __oxray_walk_spheres(r, t, a, path, tmin, tmax, best);
        }
        if (__OXRAY_USES_TYPE(__OXRAY_TYPE_CURVES) && t->kind == __OXRAY_CURVE_GAS) {
            return __oxray_walk_curves(r, t, a, path, tmin, tmax, best);
        }
        if (__OXRAY_USES_TYPE(__OXRAY_TYPE_CUSTOM) && t->kind == __OXRAY_CUSTOM_GAS) {
            return __oxray_walk_custom(r, t, a, path, tmin, tmax, best);
        }
        __oxray_throw(OPTIX_EXCEPTION_CODE_UNSUPPORTED_PRIMITIVE_TYPE, 0, nullptr);
        return true;
    case __OXRAY_IAS: {
        if (__OXRAY_SINGLE_GAS_ONLY) break;
        // Guide §5.10.3: an IAS's vanish flags hide every instance outside its range.
        const __oxray_Motion* m = __oxray_motion_of(t);
        if (m != nullptr && __oxray_vanishes(m->keys, m->flags, m->begin, m->end, a.time)) {
            return false;
        }
        return __oxray_walk_ias(r, t, a, path, tmin, tmax, best);
    }
    case __OXRAY_MATRIX_MOTION:
    case __OXRAY_SRT_MOTION: {
        if (__OXRAY_SINGLE_GAS_ONLY) break;
        // §5.10.4, §5.10.5: the transform at the ray's time; none where it vanishes, and an
        // interpolated matrix that is singular (a scale through zero) hides its child then.
        float o2w[12], w2o[12];
        if (!__oxray_motion_matrix(t, a.time, o2w) || !__oxray_inverse(o2w, w2o)) return false;
        const unsigned long long child =
            reinterpret_cast<const OptixMatrixMotionTransform*>(t->nodes)->child;
        if (child == 0ull) return false;
        TraceRay o;
        if (!__oxray_child_ray(w2o, r, tmin, tmax, o)) return false;
        return __oxray_descend(reinterpret_cast<const __oxray_Traversable*>(child),
                               reinterpret_cast<unsigned long long>(t), nullptr, o, a, path,
                               tmin, tmax, best);
    }
    case __OXRAY_STATIC: {
        if (__OXRAY_SINGLE_GAS_ONLY) break;
        const OptixStaticTransform* st = reinterpret_cast<const OptixStaticTransform*>(t->nodes);
        if (st->child == 0ull) return false;
        TraceRay o;
        if (!__oxray_child_ray(st->invTransform, r, tmin, tmax, o)) return false;
        return __oxray_descend(reinterpret_cast<const __oxray_Traversable*>(st->child),
                               reinterpret_cast<unsigned long long>(t), nullptr, o, a, path,
                               tmin, tmax, best);
    }
    default:
        break;
    }
    __oxray_throw(OPTIX_EXCEPTION_CODE_TRAVERSAL_INVALID_TRAVERSABLE, 0, nullptr);
    return true;
}

// The root of a trace against the pipeline's graph flags (§5.9.1) and traversable graph depth,
// as the CPU backend checks them.
static __forceinline__ __device__ void __oxray_check_root(const __oxray_Traversable* t) {
    u32 k = t->kind;
    if (!__OXRAY_IS_GAS(k) && k != __OXRAY_IAS && k != __OXRAY_STATIC &&
        k != __OXRAY_MATRIX_MOTION && k != __OXRAY_SRT_MOTION) {
        __oxray_throw(OPTIX_EXCEPTION_CODE_TRAVERSAL_INVALID_TRAVERSABLE, 0, nullptr);
    }
    if (OXRAY_GRAPH_FLAGS != 0u) {
        bool gas = __OXRAY_IS_GAS(k);
        // One level of instances over GASes: an IAS of depth 2 at most.
        bool allowed = gas ? (OXRAY_GRAPH_FLAGS & 1u) != 0u
                           : (k == __OXRAY_IAS && (OXRAY_GRAPH_FLAGS & 2u) != 0u && t->depth <= 2u);
        if (!allowed) {
            __oxray_throw(gas ? OPTIX_EXCEPTION_CODE_UNSUPPORTED_SINGLE_LEVEL_GAS
                              : OPTIX_EXCEPTION_CODE_TRAVERSAL_INVALID_TRAVERSABLE,
                          0, nullptr);
        }
    }
    if (t->depth > __oxray_launch.max_graph_depth) {
        __oxray_throw(OPTIX_EXCEPTION_CODE_TRAVERSAL_DEPTH_EXCEEDED, 0, nullptr);
    }
}

#ifndef OXRAY_PIPELINE_HAS_ANYHIT
#define OXRAY_PIPELINE_HAS_ANYHIT 1
#endif
#ifndef OXRAY_NO_FAST_PATH
#define OXRAY_NO_FAST_PATH 0
#endif

// The ray flags that make candidates depend on more than their distance.
#define __OXRAY_CULL_FLAGS                                                                  \
    (OPTIX_RAY_FLAG_CULL_BACK_FACING_TRIANGLES | OPTIX_RAY_FLAG_CULL_FRONT_FACING_TRIANGLES |  \
     OPTIX_RAY_FLAG_CULL_DISABLED_ANYHIT | OPTIX_RAY_FLAG_CULL_ENFORCED_ANYHIT)

// A triangle GAS at the root, in a pipeline without any-hit programs, traced with no culling:
// every candidate in the interval is accepted, so the closest one is what the query kernels
// find, with their own loop (no per-candidate records, flags or paths). The hit's record is
// looked up once, for the closest hit. With TERMINATE_ON_FIRST_HIT the first candidate ends it.
// Whether a trace can take the fast path: a triangle GAS at the root, in a pipeline without
// any-hit programs, traced with no culling flags. Every candidate in the interval is then
// accepted, so the closest one is what the query kernels find, with their own loop (no
// per-candidate records, flags or paths). `optixTrace` runs that loop at its call site, where
// few other values are live, and hands the result to `__oxray_trace`, which looks the hit's
// record up once and runs the closest-hit or miss program.
static __forceinline__ __device__ bool __oxray_fast_root(OptixTraversableHandle handle,
                                                        unsigned int flags) {
    if (OXRAY_NO_FAST_PATH || OXRAY_PIPELINE_HAS_ANYHIT || handle == 0ull ||
        (flags & __OXRAY_CULL_FLAGS) != 0u) {
        return false;
    }
    if (OXRAY_GRAPH_FLAGS != 0u && (OXRAY_GRAPH_FLAGS & 1u) == 0u) return false;
    if (!__OXRAY_USES_TYPE(__OXRAY_TYPE_TRIANGLE)) return false;
    const __oxray_Traversable* t = reinterpret_cast<const __oxray_Traversable*>(handle);
    return t->kind == __OXRAY_GAS && t->motion == 0ull;
}

// A GAS's triangles address, loaded where it is used. The query kernels have theirs in
// parameters (constant memory, no registers); a pipeline's walk has the traversable, and the
// registers of an address held through the walk make the compiler spill the walk's own values,
// reloaded from local memory at every node. The load is volatile so that it is not hoisted out
// of the walk again.
static __forceinline__ __device__ const float4* __oxray_load_address(
    const unsigned long long* at) {
    unsigned long long v;
    asm volatile("ld.global.nc.u64 %0, [%1];" : "=l"(v) : "l"(at));
    return reinterpret_cast<const float4*>(v);
}
// A GAS's descriptor is the 64-byte header of its node buffer (`node_buffer.rs`): its nodes
// start right after it, so a walk computes their address from the handle, with no load at
// each node (docs/BENCHMARKS.md, "The pipeline, ninth round"). The addition is volatile for
// the same reason as the load above: hoisted, the sum would hold two more registers.
static_assert(sizeof(__oxray_Traversable) == 64, "a GAS's nodes follow its 64-byte descriptor");
struct __oxray_GasNodes {
    const __oxray_Traversable* g;
};
static __forceinline__ __device__ const float4* node_base(__oxray_GasNodes n) {
    unsigned long long v;
    asm volatile("add.u64 %0, %1, 64;" : "=l"(v) : "l"(n.g));
    return reinterpret_cast<const float4*>(v);
}

// The query kernels' closest-hit loop over a triangle GAS (first hit with FIRST).
template <bool FIRST>
static __forceinline__ __device__ Best __oxray_fast_walk(const TraceRay& r,
                                                        const __oxray_Traversable* g) {
    Best best;
    best.t = F32_INF;
    best.u = 0.0f;
    best.v = 0.0f;
    best.slot = MISS_SLOT;
    auto leaf_slots = [&](u32 start, u32 count, float& tmax) {
        float box_tmax;  // the walk keeps its own
        return leaf<FIRST>(r, __oxray_load_address(&g->prims), start, count, r.tmin, tmax,
                           box_tmax, best);
    };
    walk_bvh2<OXRAY_BVH2_STACK>(r, __oxray_GasNodes{g}, r.tmin, r.tmax, leaf_slots);
    return best;
}

// The caller's state while a trace runs: its record, and (for a trace from a hit or miss
// program) its ray and payload. It lives in the caller's frame.
struct __oxray_Frame {
    const char* record;
    __oxray_RayState ray;
};

// Which of the ray's and the hit's values the pipeline's programs may read: those whose device
// functions appear in their sources (`pipeline_source` writes the set; all by default). A trace
// on the fast path stores only these in the thread's state: every word stored there is local
// memory that the device writes back to DRAM, which a launch of a million short rays feels.
#define __OXRAY_READS_ORIGIN 1u      // optixGetWorldRayOrigin, optixGetObjectRayOrigin
#define __OXRAY_READS_DIRECTION 2u   // optixGetWorldRayDirection, optixGetObjectRayDirection
#define __OXRAY_READS_TMIN 4u        // optixGetRayTmin
#define __OXRAY_READS_TIME 8u        // optixGetRayTime
#define __OXRAY_READS_MASK 16u       // optixGetRayVisibilityMask
#define __OXRAY_READS_PRIMITIVE 32u  // optixGetPrimitiveIndex
#define __OXRAY_READS_SBT_GAS 64u    // optixGetSbtGASIndex
#define __OXRAY_READS_HIT_KIND 128u  // optixGetHitKind and the facing and type functions
#define __OXRAY_READS_ATTRIBUTES 256u  // optixGetTriangleBarycentrics, the attribute functions
#define __OXRAY_READS_VERTICES 512u  // optixGetTriangleVertexData, optixGetGASTraversableHandle
#define __OXRAY_READS_REPORT 1024u   // optixReportIntersection (the kernel clears the report)
#define __OXRAY_READS_CALLS 2048u    // optixDirectCall, optixContinuationCall (the call depth)
#define __OXRAY_READS_PATH 4096u     // the instance, object-space, transform and GAS functions
#ifndef OXRAY_READS
#define OXRAY_READS 0xffffffffu
#endif
#define __OXRAY_STORES(fast, bit) (!(fast) || (OXRAY_READS & (bit)) != 0u)

// Whether a trace (not yet entered, or left) returns to the ray-generation program: one at
// depth 0 when no callable can be running (no program calls one). Its record is then the
// launch's, which the trace need not save.
#ifndef OXRAY_SAVE_RECORD_ALWAYS
#define OXRAY_SAVE_RECORD_ALWAYS 0
#endif
static __forceinline__ __device__ bool __oxray_from_raygen(const __oxray_ThreadState& st) {
    return !OXRAY_SAVE_RECORD_ALWAYS && (OXRAY_READS & __OXRAY_READS_CALLS) == 0u &&
           st.depth == 0u;
}

// What every trace does first: the checks of the guide's limits (payload count, trace depth)
// and, in validation mode, of the ray; then the caller's state goes into `frame`, and the ray
// and payload into the state. `fast`: the trace takes the fast path (a constant at each call).
static __forceinline__ __device__ void __oxray_enter(bool fast, __oxray_ThreadState& st,
                                                     float3 org, float3 dir, float tmin,
                                                     float tmax, float time,
                                                     OptixVisibilityMask mask, unsigned int flags,
                                                     unsigned int n, const unsigned int* payload,
                                                     __oxray_Frame& frame) {
    st.traces += 1u;
    if (n > OXRAY_NUM_PAYLOAD_VALUES) {
        u32 d[2] = {n, (u32)OXRAY_NUM_PAYLOAD_VALUES};
        __oxray_throw(OPTIX_EXCEPTION_CODE_PAYLOAD_TYPE_MISMATCH, 2, d);
    }
    if (st.depth + 1u > OXRAY_MAX_TRACE_DEPTH) {
        __oxray_throw(OPTIX_EXCEPTION_CODE_TRACE_DEPTH_EXCEEDED, 0, nullptr);
    }
    // Validation mode: the ray's checks of the CPU backend (`Ray::validate`), with the ray's
    // bits as details.
    if (__oxray_launch.validation != 0u) {
        bool finite = isfinite(org.x) && isfinite(org.y) && isfinite(org.z) && isfinite(dir.x) &&
                      isfinite(dir.y) && isfinite(dir.z);
        bool zero = dir.x == 0.0f && dir.y == 0.0f && dir.z == 0.0f;
        bool interval = !isnan(tmin) && !isnan(tmax) && tmin >= 0.0f && tmin <= tmax;
        if (!finite || zero || !interval) {
            u32 d[8] = {__float_as_uint(org.x), __float_as_uint(org.y), __float_as_uint(org.z),
                        __float_as_uint(dir.x), __float_as_uint(dir.y), __float_as_uint(dir.z),
                        __float_as_uint(tmin),  __float_as_uint(tmax)};
            __oxray_throw(OPTIX_EXCEPTION_CODE_INVALID_RAY, 8, d);
        }
    }
    if (!__oxray_from_raygen(st)) frame.record = st.record;
    if (st.depth > 0u) frame.ray = st.ray;
    st.depth += 1u;
    for (u32 i = 0; i < n; ++i) st.ray.payload[i] = payload[i];
    // On the fast path only the programs read the ray's origin, direction, tmin, time and
    // mask (the general traversal reads tmin and mask too).
    if (__OXRAY_STORES(fast, __OXRAY_READS_ORIGIN)) st.ray.org = org;
    if (__OXRAY_STORES(fast, __OXRAY_READS_DIRECTION)) st.ray.dir = dir;
    if (__OXRAY_STORES(fast, __OXRAY_READS_TMIN)) st.ray.tmin = tmin;
    st.ray.tmax = tmax;
    if (__OXRAY_STORES(fast, __OXRAY_READS_TIME)) st.ray.time = time;
    st.ray.flags = flags;
    if (__OXRAY_STORES(fast, __OXRAY_READS_MASK)) st.ray.mask = mask & 0xFFu;
}

// The miss program `miss_index` (raises INVALID_MISS_SBT beyond the region), with the world
// ray (its tmax as traced) and the root's path.
static __forceinline__ __device__ void __oxray_miss(__oxray_ThreadState& st,
                                                    unsigned int miss_index,
                                                    const __oxray_Path* root) {
    if (miss_index >= __oxray_launch.miss_count) {
        u32 d[1] = {miss_index};
        __oxray_throw(OPTIX_EXCEPTION_CODE_INVALID_MISS_SBT, 1, d);
    }
    if (__OXRAY_STORES(true, __OXRAY_READS_PATH)) st.ray.path = root;
    if (__OXRAY_STORES(true, __OXRAY_READS_VERTICES)) st.ray.gas = nullptr;
    st.record = reinterpret_cast<const char*>(__oxray_launch.miss) +
                (unsigned long long)miss_index * __oxray_launch.miss_stride;
    __oxray_call_miss(__oxray_group_of(st.record));
}

// What every trace does last: the payload copied out, the caller's state back.
static __forceinline__ __device__ void __oxray_leave(__oxray_ThreadState& st, unsigned int n,
                                                     unsigned int* payload,
                                                     const __oxray_Frame& frame) {
    for (u32 i = 0; i < n; ++i) payload[i] = st.ray.payload[i];
    st.depth -= 1u;
    st.record = __oxray_from_raygen(st) ? reinterpret_cast<const char*>(__oxray_launch.raygen)
                                        : frame.record;
    if (st.depth > 0u) st.ray = frame.ray;
}

// The path of a trace with no transforms above its GAS, shared by the fast path's traces: the
// object-space ray is then the world ray, and the GAS is the state's (`__oxray_hit_gas`).
__device__ const __oxray_Path __oxray_root_path = {0u, 0u, 0xffffffffu, 0u, 0u, nullptr,
                                                   {0.0f, 0.0f, 0.0f}, {0.0f, 0.0f, 0.0f}, {}};

static __noinline__ __device__ void __oxray_trace(OptixTraversableHandle handle, float3 org,
                                                  float3 dir, float tmin, float tmax, float time,
                                                  OptixVisibilityMask mask, unsigned int flags,
                                                  unsigned int sbt_offset, unsigned int sbt_stride,
                                                  unsigned int miss_index, unsigned int n,
                                                  unsigned int* payload) {
    __oxray_ThreadState& st = __oxray_state();
    __oxray_Frame frame;
    __oxray_enter(false, st, org, dir, tmin, tmax, time, mask, flags, n, payload, frame);

    // The path of the root: no transforms, the world ray.
    __oxray_Path root;
    root.len = 0u;
    root.sbt_offset = 0u;
    root.instance_id = 0xffffffffu;
    root.instance_index = 0u;
    root.iflags = 0u;
    root.gas = nullptr;
    root.org = org;
    root.dir = dir;
    __oxray_Best best;
    best.found = false;
    __oxray_TraceArgs a;
    a.flags = flags;
    a.sbt_offset = sbt_offset;
    a.sbt_stride = sbt_stride;
    a.time = __OXRAY_TIME(time);
    TraceRay r;
    r.org = org;
    r.dir = dir;
    r.tmin = tmin;
    r.tmax = tmax;
    if (handle != 0ull && prepare_ray(r)) {
        const __oxray_Traversable* t = reinterpret_cast<const __oxray_Traversable*>(handle);
        __oxray_check_root(t);
        __oxray_Path path;
        __oxray_copy_path(path, root);
        float tm = tmax;
        __oxray_walk(t, r, a, path, tmin, tm, best);
    }
    if (best.found) {
        if ((flags & OPTIX_RAY_FLAG_DISABLE_CLOSESTHIT) == 0u) {
            st.ray.tmax = best.t;
            st.ray.prim = best.prim;
            st.ray.sbt_gas_index = best.sbt_gas_index;
            st.ray.hit_kind = best.hit_kind;
            st.ray.slot = best.slot;
            for (int k = 0; k < 8; ++k) st.ray.attr[k] = best.attr[k];
            st.ray.path = &best.path;
            st.record = best.record;
            __oxray_call_closesthit(__oxray_group_of(best.record));
        }
    } else {
        __oxray_miss(st, miss_index, &root);
    }
    __oxray_leave(st, n, payload, frame);
}

// The payload a trace on the fast path hands back to its call site: returned by value, in
// registers for a few words, rather than stored into an array of the caller's that the caller
// then reloads (two local-memory round trips on the way from the program to the caller).
template <unsigned int N>
struct __oxray_Payload {
    u32 v[N > 0 ? N : 1];
};

// The end of a trace whose traversal the call site did (`optixTrace`, after `__oxray_enter`
// and `__oxray_fast_walk`): the closest hit `fast` of the triangle GAS `g`, written straight
// into the state (no intermediate hit record, no path of its own: the shared root path), then
// the closest-hit or miss program; returns the payload. The ray's flags are read back from the
// state, so that the call site keeps as few values alive across its walk as the query kernels
// do. (Copying the payload out at the call site instead, to keep it in registers there,
// measured slower: the call then has more live values to save.)
template <unsigned int N>
static __noinline__ __device__ __oxray_Payload<N> __oxray_trace_fast(
    const __oxray_Traversable* g, Best fast, unsigned int sbt_offset, unsigned int sbt_stride,
    unsigned int miss_index, const __oxray_Frame& frame) {
    __oxray_ThreadState& st = __oxray_state();
    if (fast.slot != MISS_SLOT) {
        const u32 s = fast.slot & ~BACK_FACE_BIT;
        // The ray's flags and the GAS's record count are both loaded before either is tested,
        // so that the two loads overlap rather than follow each other: the descriptor's line
        // has usually left the L1 during the walk, and so may the state's. (The descriptor is
        // read-only while a launch runs.) With one SBT record the SBT-GAS index is 0: the
        // slot's entry is needed only when a program reads the primitive or that index.
        const u32 flags = st.ray.flags;
        const u32 count = __ldg(&g->count);
        uint2 info = make_uint2(0u, 0u);
        if (__OXRAY_STORES(true, __OXRAY_READS_PRIMITIVE | __OXRAY_READS_SBT_GAS) ||
            count != 1u) {
            info = reinterpret_cast<const uint2*>(g->info)[s];
        }
        if ((flags & OPTIX_RAY_FLAG_DISABLE_CLOSESTHIT) == 0u) {
            __oxray_TraceArgs a;
            a.flags = flags;
            a.sbt_offset = sbt_offset;
            a.sbt_stride = sbt_stride;
            a.time = 0.0f;  // a GAS without motion
            const char* record = __oxray_hit_record(a, __oxray_root_path, info.y);
            st.ray.tmax = fast.t;
            if (__OXRAY_STORES(true, __OXRAY_READS_PRIMITIVE)) st.ray.prim = info.x;
            if (__OXRAY_STORES(true, __OXRAY_READS_SBT_GAS)) st.ray.sbt_gas_index = info.y;
            if (__OXRAY_STORES(true, __OXRAY_READS_HIT_KIND)) {
                st.ray.hit_kind = (fast.slot & BACK_FACE_BIT) ? OPTIX_HIT_KIND_TRIANGLE_BACK_FACE
                                                              : OPTIX_HIT_KIND_TRIANGLE_FRONT_FACE;
            }
            if (__OXRAY_STORES(true, __OXRAY_READS_ATTRIBUTES | __OXRAY_READS_VERTICES)) {
                st.ray.slot = s;
            }
            if (__OXRAY_STORES(true, __OXRAY_READS_ATTRIBUTES)) {
                st.ray.attr[0] = __float_as_uint(fast.u);
                st.ray.attr[1] = __float_as_uint(fast.v);
            }
            if (__OXRAY_STORES(true, __OXRAY_READS_PATH)) st.ray.path = &__oxray_root_path;
            if (__OXRAY_STORES(true, __OXRAY_READS_VERTICES)) st.ray.gas = g;
            st.record = record;
            __oxray_call_closesthit(__oxray_group_of(record));
        }
    } else {
        __oxray_miss(st, miss_index, &__oxray_root_path);
    }
    __oxray_Payload<N> out;
    __oxray_leave(st, N, out.v, frame);
    return out;
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
    bool traced = false;
    if (__oxray_fast_root(handle, rayFlags)) {
        TraceRay r;
        r.org = rayOrigin;
        r.dir = rayDirection;
        r.tmin = tmin;
        r.tmax = tmax;
        if (prepare_ray(r)) {
            // The ray and payload go into the state before the walk, so that only the walk's
            // own values are alive during it.
            __oxray_Frame frame;
            __oxray_enter(true, __oxray_state(), rayOrigin, rayDirection, tmin, tmax, rayTime,
                          visibilityMask, rayFlags, n, p, frame);
            const __oxray_Traversable* g = reinterpret_cast<const __oxray_Traversable*>(handle);
            const bool first = (rayFlags & OPTIX_RAY_FLAG_TERMINATE_ON_FIRST_HIT) != 0u;
            Best fast = first ? __oxray_fast_walk<true>(r, g) : __oxray_fast_walk<false>(r, g);
            const __oxray_Payload<n> out =
                __oxray_trace_fast<n>(g, fast, SBToffset, SBTstride, missSBTIndex, frame);
            // The payload comes back in registers, not through the array the general
            // traversal fills.
            unsigned int i = 0;
            ((payload = out.v[i++]), ...);
            (void)i;
            traced = true;
        }
    }
    if (!traced) {
        __oxray_trace(handle, rayOrigin, rayDirection, tmin, tmax, rayTime, visibilityMask,
                      rayFlags, SBToffset, SBTstride, missSBTIndex, n, p);
        unsigned int i = 0;
        ((payload = p[i++]), ...);
        (void)i;
    }
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

// ---------------------------------------------------------------------------------------------
// Callables (guide §15): the record's group gives the program's address, called through a
// pointer of the caller's signature
// ---------------------------------------------------------------------------------------------

template <typename T>
struct __oxray_is_void {
    static constexpr bool value = false;
};
template <>
struct __oxray_is_void<void> {
    static constexpr bool value = true;
};

// The callables record `sbtIndex` (raises CALLABLE_INVALID_SBT beyond the region), after the
// nesting check (STACK_OVERFLOW), in the CPU backend's order.
static __forceinline__ __device__ const char* __oxray_callable_record(unsigned int sbtIndex) {
    if (__oxray_state().calls >= __OXRAY_MAX_CALL_DEPTH) {
        __oxray_throw(OPTIX_EXCEPTION_CODE_STACK_OVERFLOW, 0, nullptr);
    }
    if (sbtIndex >= __oxray_launch.callable_count) {
        u32 d[1] = {sbtIndex};
        __oxray_throw(OPTIX_EXCEPTION_CODE_CALLABLE_INVALID_SBT, 1, d);
    }
    return reinterpret_cast<const char*>(__oxray_launch.callables) +
           (unsigned long long)sbtIndex * __oxray_launch.callable_stride;
}

// Calls `f` (a callable of the record `record`) as ReturnT(ArgTypes...): the callable's
// optixGetSbtDataPointer is its record's data; the caller's record comes back after.
template <typename ReturnT, typename... ArgTypes>
static __forceinline__ __device__ ReturnT __oxray_call_callable(void* f, const char* record,
                                                               ArgTypes... args) {
    typedef ReturnT (*Fn)(ArgTypes...);
    Fn fn = reinterpret_cast<Fn>(f);
    __oxray_ThreadState& st = __oxray_state();
    const char* saved = st.record;
    st.record = record;
    st.calls += 1u;
    if constexpr (__oxray_is_void<ReturnT>::value) {
        fn(args...);
        __oxray_ThreadState& s2 = __oxray_state();
        s2.calls -= 1u;
        s2.record = saved;
    } else {
        ReturnT r = fn(args...);
        __oxray_ThreadState& s2 = __oxray_state();
        s2.calls -= 1u;
        s2.record = saved;
        return r;
    }
}

// The guide's optixDirectCall: the direct callable of callables record `sbtIndex`; a record
// whose group has none raises CALLABLE_NO_DC_SBT_RECORD.
template <typename ReturnT, typename... ArgTypes>
static __forceinline__ __device__ ReturnT optixDirectCall(unsigned int sbtIndex, ArgTypes... args) {
    const char* record = __oxray_callable_record(sbtIndex);
    const u32 group = __oxray_group_of(record);
    void* f = __oxray_dc_of(group);
    u32 d[1] = {sbtIndex};
    if (f == nullptr) {
        __oxray_throw(OPTIX_EXCEPTION_CODE_CALLABLE_NO_DC_SBT_RECORD, 1, d);
    }
    if (__oxray_dc_signature(group) != __oxray_signature<ReturnT (*)(ArgTypes...)>()) {
        __oxray_throw(OPTIX_EXCEPTION_CODE_CALLABLE_PARAMETER_MISMATCH, 1, d);
    }
    return __oxray_call_callable<ReturnT, ArgTypes...>(f, record, args...);
}

// The guide's optixContinuationCall. On this backend a continuation callable is called like a
// direct one (no scheduler); it may trace. A record whose group has none raises
// CALLABLE_NO_CC_SBT_RECORD.
template <typename ReturnT, typename... ArgTypes>
static __forceinline__ __device__ ReturnT optixContinuationCall(unsigned int sbtIndex,
                                                                ArgTypes... args) {
    const char* record = __oxray_callable_record(sbtIndex);
    const u32 group = __oxray_group_of(record);
    void* f = __oxray_cc_of(group);
    u32 d[1] = {sbtIndex};
    if (f == nullptr) {
        __oxray_throw(OPTIX_EXCEPTION_CODE_CALLABLE_NO_CC_SBT_RECORD, 1, d);
    }
    if (__oxray_cc_signature(group) != __oxray_signature<ReturnT (*)(ArgTypes...)>()) {
        __oxray_throw(OPTIX_EXCEPTION_CODE_CALLABLE_PARAMETER_MISMATCH, 1, d);
    }
    return __oxray_call_callable<ReturnT, ArgTypes...>(f, record, args...);
}

#endif  // OXRAY_DEVICE_H
