// oxray_device_cpu.h: the device side of oxray's OptiX-compatible programming model on the CPU.
//
// The same device functions as the CUDA backend's oxray_device.h (the guide's §13 and §15, under
// the guide's names and signatures, written from the guide), implemented over the CPU pipeline:
// a module of CUDA C++ programs is compiled by the host's C++ compiler into a shared library,
// and the CPU backend runs its programs in place of Rust closures. User modules may
// `#include <optix.h>` or `<optix_device.h>`: the module compiler replaces those includes.
//
// How it works. Every program the library exports is wrapped in a generated C function that
// takes a frame (`__oxray_Frame`, filled by the Rust runtime with the launch index, the ray, the
// hit, the payload and the SBT record of the running program), makes it the thread's current
// frame, and calls the program. Queries read the frame; calls that need the runtime (a trace, a
// report, a callable, the transform list) go through the table of functions in the frame.
// Calls that never return in OptiX (`optixIgnoreIntersection`, `optixTerminateRay`,
// `optixThrowException`, a trace or call that raised) record what happened in the frame and
// unwind the program with a C++ exception that only the wrapper catches, so no code after them
// runs, as in OptiX. (A program must therefore not be called from a `noexcept` function.)
//
// CUDA on the host. The CUDA C++ that OptiX programs use (qualifiers, vector types and their
// make_ functions, bit casts, atomics, fast-math intrinsics) is given host meanings below;
// intrinsics that exist only on a GPU (block and warp functions, shared memory, textures) fail
// to compile with a message saying so.

#ifndef OXRAY_DEVICE_CPU_H
#define OXRAY_DEVICE_CPU_H

#include <cmath>
#include <math.h>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <tuple>
#include <type_traits>
#include <typeinfo>

// ---------------------------------------------------------------------------------------------
// CUDA C++ on the host
// ---------------------------------------------------------------------------------------------

#define __OXRAY_CPU__ 1
#define __global__
#define __device__
#define __host__
#define __constant__
#define __forceinline__ inline __attribute__((always_inline))
#define __noinline__ __attribute__((noinline))
#define __restrict__ __restrict
#define __launch_bounds__(...)
#define __align__(n) alignas(n)

#define __OXRAY_GPU_ONLY(what) \
    __attribute__((error(what " exists only on a GPU: this program cannot run on the CPU backend")))
__OXRAY_GPU_ONLY("shared memory (__shared__)") int __oxray_gpu_only_shared();
#define __shared__ static_assert(false, "shared memory (__shared__) exists only on a GPU: OptiX programs may not use it (guide §6.2)");
__OXRAY_GPU_ONLY("__syncthreads") void __syncthreads();
__OXRAY_GPU_ONLY("__syncwarp") void __syncwarp(unsigned int mask = 0xffffffffu);
__OXRAY_GPU_ONLY("__threadfence") void __threadfence();
__OXRAY_GPU_ONLY("__ballot_sync") unsigned int __ballot_sync(unsigned int, int);
__OXRAY_GPU_ONLY("__activemask") unsigned int __activemask();
__OXRAY_GPU_ONLY("__any_sync") int __any_sync(unsigned int, int);
__OXRAY_GPU_ONLY("__all_sync") int __all_sync(unsigned int, int);
template <typename T>
__OXRAY_GPU_ONLY("__shfl_sync") T __shfl_sync(unsigned int, T, int, int = 32);
template <typename T>
__OXRAY_GPU_ONLY("__shfl_xor_sync") T __shfl_xor_sync(unsigned int, T, int, int = 32);
__OXRAY_GPU_ONLY("clock64") long long clock64();
__OXRAY_GPU_ONLY("clock") long long clock();
template <typename T, typename... A>
__OXRAY_GPU_ONLY("texture fetches (tex2D)") T tex2D(A...);
template <typename T, typename... A>
__OXRAY_GPU_ONLY("texture fetches (tex2DLod)") T tex2DLod(A...);
struct __oxray_GpuOnlyIndex {};
__OXRAY_GPU_ONLY("threadIdx, blockIdx, blockDim and gridDim (use optixGetLaunchIndex)")
__oxray_GpuOnlyIndex __oxray_gpu_only_index();
#define threadIdx __oxray_gpu_only_index()
#define blockIdx __oxray_gpu_only_index()
#define blockDim __oxray_gpu_only_index()
#define gridDim __oxray_gpu_only_index()

struct __align__(8) float2 { float x, y; };
struct float3 { float x, y, z; };
struct __align__(16) float4 { float x, y, z, w; };
struct __align__(8) int2 { int x, y; };
struct int3 { int x, y, z; };
struct __align__(16) int4 { int x, y, z, w; };
struct __align__(8) uint2 { unsigned int x, y; };
struct uint3 { unsigned int x, y, z; };
struct __align__(16) uint4 { unsigned int x, y, z, w; };
struct uchar4 { unsigned char x, y, z, w; };
struct __align__(16) double2 { double x, y; };
struct double3 { double x, y, z; };
typedef uint3 dim3;

static inline float2 make_float2(float x, float y) { return {x, y}; }
static inline float3 make_float3(float x, float y, float z) { return {x, y, z}; }
static inline float4 make_float4(float x, float y, float z, float w) { return {x, y, z, w}; }
static inline int2 make_int2(int x, int y) { return {x, y}; }
static inline int3 make_int3(int x, int y, int z) { return {x, y, z}; }
static inline int4 make_int4(int x, int y, int z, int w) { return {x, y, z, w}; }
static inline uint2 make_uint2(unsigned int x, unsigned int y) { return {x, y}; }
static inline uint3 make_uint3(unsigned int x, unsigned int y, unsigned int z) { return {x, y, z}; }
static inline uint4 make_uint4(unsigned int x, unsigned int y, unsigned int z, unsigned int w) {
    return {x, y, z, w};
}
static inline uchar4 make_uchar4(unsigned char x, unsigned char y, unsigned char z,
                                 unsigned char w) {
    return {x, y, z, w};
}
static inline double2 make_double2(double x, double y) { return {x, y}; }
static inline double3 make_double3(double x, double y, double z) { return {x, y, z}; }

template <typename To, typename From>
static inline To __oxray_bits(From v) {
    static_assert(sizeof(To) == sizeof(From), "bit casts keep the size");
    To r;
    std::memcpy(&r, &v, sizeof r);
    return r;
}
static inline unsigned int __float_as_uint(float f) { return __oxray_bits<unsigned int>(f); }
static inline float __uint_as_float(unsigned int u) { return __oxray_bits<float>(u); }
static inline int __float_as_int(float f) { return __oxray_bits<int>(f); }
static inline float __int_as_float(int i) { return __oxray_bits<float>(i); }
static inline long long __double_as_longlong(double d) { return __oxray_bits<long long>(d); }
static inline double __longlong_as_double(long long l) { return __oxray_bits<double>(l); }

// Single-precision math: <math.h> has the C names CUDA uses; the fast-math forms are exact here.
static inline float rsqrtf(float x) { return 1.0f / std::sqrt(x); }
static inline float __saturatef(float x) { return x < 0.0f ? 0.0f : (x > 1.0f ? 1.0f : x); }
static inline float __fdividef(float a, float b) { return a / b; }
// __expf, __logf, __powf, __sinf, __cosf and sincosf: glibc declares them with these meanings.
static inline int min(int a, int b) { return a < b ? a : b; }
static inline int max(int a, int b) { return a > b ? a : b; }
static inline unsigned int min(unsigned int a, unsigned int b) { return a < b ? a : b; }
static inline unsigned int max(unsigned int a, unsigned int b) { return a > b ? a : b; }
static inline float min(float a, float b) { return ::fminf(a, b); }
static inline float max(float a, float b) { return ::fmaxf(a, b); }

// Atomics: launch indices run on several threads, so these are real atomics.
template <typename T>
static inline T __oxray_atomic_rmw(T* p, T v, int op) {
    switch (op) {
    case 0: return __atomic_fetch_add(p, v, __ATOMIC_RELAXED);
    case 1: return __atomic_fetch_sub(p, v, __ATOMIC_RELAXED);
    case 2: return __atomic_fetch_and(p, v, __ATOMIC_RELAXED);
    case 3: return __atomic_fetch_or(p, v, __ATOMIC_RELAXED);
    case 4: return __atomic_fetch_xor(p, v, __ATOMIC_RELAXED);
    default: return __atomic_exchange_n(p, v, __ATOMIC_RELAXED);
    }
}
#define __OXRAY_ATOMIC_INT(T)                                                              \
    static inline T atomicAdd(T* p, T v) { return __oxray_atomic_rmw(p, v, 0); }          \
    static inline T atomicSub(T* p, T v) { return __oxray_atomic_rmw(p, v, 1); }          \
    static inline T atomicAnd(T* p, T v) { return __oxray_atomic_rmw(p, v, 2); }          \
    static inline T atomicOr(T* p, T v) { return __oxray_atomic_rmw(p, v, 3); }           \
    static inline T atomicXor(T* p, T v) { return __oxray_atomic_rmw(p, v, 4); }          \
    static inline T atomicExch(T* p, T v) { return __oxray_atomic_rmw(p, v, 5); }         \
    static inline T atomicCAS(T* p, T expected, T desired) {                              \
        __atomic_compare_exchange_n(p, &expected, desired, false, __ATOMIC_RELAXED,        \
                                    __ATOMIC_RELAXED);                                    \
        return expected;                                                                  \
    }                                                                                     \
    static inline T atomicMin(T* p, T v) {                                                \
        T old = __atomic_load_n(p, __ATOMIC_RELAXED);                                     \
        while (v < old && !__atomic_compare_exchange_n(p, &old, v, true, __ATOMIC_RELAXED, \
                                                       __ATOMIC_RELAXED)) {               \
        }                                                                                 \
        return old;                                                                       \
    }                                                                                     \
    static inline T atomicMax(T* p, T v) {                                                \
        T old = __atomic_load_n(p, __ATOMIC_RELAXED);                                     \
        while (v > old && !__atomic_compare_exchange_n(p, &old, v, true, __ATOMIC_RELAXED, \
                                                       __ATOMIC_RELAXED)) {               \
        }                                                                                 \
        return old;                                                                       \
    }
__OXRAY_ATOMIC_INT(int)
__OXRAY_ATOMIC_INT(unsigned int)
__OXRAY_ATOMIC_INT(unsigned long long)
#undef __OXRAY_ATOMIC_INT
static inline float atomicAdd(float* p, float v) {
    unsigned int* u = reinterpret_cast<unsigned int*>(p);
    unsigned int old = __atomic_load_n(u, __ATOMIC_RELAXED);
    while (!__atomic_compare_exchange_n(u, &old, __float_as_uint(__uint_as_float(old) + v), true,
                                        __ATOMIC_RELAXED, __ATOMIC_RELAXED)) {
    }
    return __uint_as_float(old);
}

// ---------------------------------------------------------------------------------------------
// Types and constants of the guide
// ---------------------------------------------------------------------------------------------

// The guide's types and constants: optix_types.h (oxray_core::source::OPTIX_TYPES_HEADER),
// which the module compiler puts before this header.

// ---------------------------------------------------------------------------------------------
// The frame of a running program, shared with the Rust runtime (oxray-cpu/src/cxx/bridge.rs)
// ---------------------------------------------------------------------------------------------

struct __oxray_Frame;

// The runtime's functions. Those returning unsigned int give 0 when the call returned and 1 when
// it raised (the runtime has recorded the interrupt: the program must unwind).
struct __oxray_Api {
    unsigned int (*trace)(__oxray_Frame* f, unsigned long long handle, const float* org,
                          const float* dir, float tmin, float tmax, float time, unsigned int mask,
                          unsigned int flags, unsigned int sbt_offset, unsigned int sbt_stride,
                          unsigned int miss, unsigned int* payload, unsigned int n);
    unsigned int (*report)(__oxray_Frame* f, float t, unsigned int kind, const unsigned int* attr,
                           unsigned int nattr, unsigned int* accepted);
    unsigned int (*call)(__oxray_Frame* f, unsigned int continuation, unsigned int sbt_index,
                         void* args, void* ret, const char* signature);
    // Matrices of the current hit's transform list (12 floats, rows): which 0 object-to-world,
    // 1 world-to-object. Identity outside a hit.
    void (*transform)(__oxray_Frame* f, unsigned int which, float* m);
    // Entry i of the transform list: its type (0 past the list), instance id and index, and
    // its two matrices. i = ~0u gives the list's size as the type.
    unsigned int (*transform_list)(__oxray_Frame* f, unsigned int i, unsigned int* id,
                                   unsigned int* index, float* o2w, float* w2o);
    // The object-space vertices of the hit triangle (9 floats; zeros for a custom primitive).
    void (*vertex_data)(__oxray_Frame* f, float* v);
    // The handle of the hit's GAS (its address, as `optix_handle` gives it; 0 if unknown).
    unsigned long long (*gas_handle)(__oxray_Frame* f);
    // The object-space centre and radius of the hit sphere (4 floats; zeros for another
    // primitive type).
    void (*sphere_data)(__oxray_Frame* f, float* v);
    // The object-space control points and radii of the hit curve segment (16 floats, as many
    // float4s as the type has, then zeros; zeros for another primitive type).
    void (*curve_data)(__oxray_Frame* f, float* v);
    // Entry i of the transform list as an OptixMatrixMotionTransform (kind 2) or
    // OptixSRTMotionTransform (kind 3), read-only, alive for the launch; null if the entry is
    // not of that kind.
    const void* (*motion_transform)(__oxray_Frame* f, unsigned int i, unsigned int kind);
    // The motion options of a GAS (its handle, or the hit's GAS): writes timeBegin and timeEnd,
    // returns the number of keys (1 without motion, 0 for a handle that names no GAS).
    unsigned int (*gas_motion)(__oxray_Frame* f, unsigned long long gas, float* times);
    // The unit object-space normal of the hit ribbon at (u, v), out of its front face (3
    // floats; zeros for another primitive type).
    void (*ribbon_normal)(__oxray_Frame* f, float u, float v, float* n);
    // Random vertex access (guide §13.9) through a GAS handle at `time`: kind 0 a triangle's
    // vertices (9 floats), 1 a sphere (4), 2 a curve segment's control points (16). Returns 0
    // and writes NaN where refused (no such GAS, no ALLOW_RANDOM_VERTEX_ACCESS, another kind,
    // no such primitive).
    unsigned int (*vertex_data_from_handle)(__oxray_Frame* f, unsigned long long gas,
                                            unsigned int kind, unsigned int prim,
                                            unsigned int sbt, float time, float* out);
    // Random instance access (guide §13.12): instance `index` of an IAS built with
    // ALLOW_RANDOM_INSTANCE_ACCESS: its id, index, matrices (12 floats each) and child's handle.
    // Returns 0 where refused (no such IAS, no flag, an index out of range).
    unsigned int (*instance_from_ias)(__oxray_Frame* f, unsigned long long ias,
                                      unsigned int index, unsigned int* id,
                                      unsigned int* inst_index, float* o2w, float* w2o,
                                      unsigned long long* child);
};

// Program kinds, as the runtime numbers them.
#define __OXRAY_RG 0u
#define __OXRAY_IS 1u
#define __OXRAY_AH 2u
#define __OXRAY_CH 3u
#define __OXRAY_MS 4u
#define __OXRAY_EX 5u
#define __OXRAY_DC 6u
#define __OXRAY_CC 7u

// What ended a program early (`pending`).
#define __OXRAY_PENDING_NONE 0u
#define __OXRAY_PENDING_THROW 1u
#define __OXRAY_PENDING_IGNORE 2u
#define __OXRAY_PENDING_TERMINATE 3u
#define __OXRAY_PENDING_RAISED 4u  // a runtime call raised; the runtime holds the interrupt
#define __OXRAY_PENDING_ESCAPED 5u  // a C++ exception of the program's own escaped it
#define __OXRAY_PENDING_MISUSE 6u  // a device function the program's kind may not call

struct __oxray_Frame {
    const __oxray_Api* api;
    void* ctx;
    unsigned int kind;
    unsigned int pending;
    unsigned int launch_index[3];
    unsigned int launch_dims[3];
    const char* record;
    float org[3];
    float dir[3];
    float tmin, tmax, time;
    unsigned int flags, mask;
    float obj_org[3];
    float obj_dir[3];
    unsigned int prim, sbt_gas_index, hit_kind, instance_id, instance_index, nattr;
    unsigned int attr[8];
    unsigned int* payload;
    unsigned int npayload;
    int exception_code;
    unsigned int ndetails;
    unsigned int details[8];
    unsigned int misuse;  // with PENDING_MISUSE: which function (an index into __oxray_names)
};

// Offsets the runtime checks when it loads a module, so that both sides agree on the frame.
extern "C" void __oxray_frame_layout(unsigned long long* out) {
    out[0] = sizeof(__oxray_Frame);
    out[1] = offsetof(__oxray_Frame, record);
    out[2] = offsetof(__oxray_Frame, obj_org);
    out[3] = offsetof(__oxray_Frame, attr);
    out[4] = offsetof(__oxray_Frame, payload);
    out[5] = offsetof(__oxray_Frame, details);
    out[6] = offsetof(__oxray_Frame, misuse);
}

static thread_local __oxray_Frame* __oxray_frame = nullptr;

// The unwinding of a program by a call that does not return; caught only by the wrappers.
struct __oxray_Unwind {};

[[noreturn]] static inline void __oxray_unwind(unsigned int why) {
    __oxray_frame->pending = why;
    throw __oxray_Unwind{};
}

// Device functions a program of the current kind may not call end its launch index with a
// user exception naming the function (on a GPU they do not compile).
static inline void __oxray_allow(unsigned int kinds, unsigned int name) {
    if ((kinds & (1u << __oxray_frame->kind)) == 0u) {
        __oxray_frame->misuse = name;
        __oxray_unwind(__OXRAY_PENDING_MISUSE);
    }
}
#define __OXRAY_K(k) (1u << __OXRAY_##k)
#define __OXRAY_HIT_KINDS (__OXRAY_K(IS) | __OXRAY_K(AH) | __OXRAY_K(CH))
#define __OXRAY_RAY_KINDS (__OXRAY_K(IS) | __OXRAY_K(AH) | __OXRAY_K(CH) | __OXRAY_K(MS))

// ---------------------------------------------------------------------------------------------
// Device functions: launch, SBT, ray and hit queries
// ---------------------------------------------------------------------------------------------

static inline uint3 optixGetLaunchIndex() {
    const unsigned int* i = __oxray_frame->launch_index;
    return make_uint3(i[0], i[1], i[2]);
}
static inline uint3 optixGetLaunchDimensions() {
    const unsigned int* d = __oxray_frame->launch_dims;
    return make_uint3(d[0], d[1], d[2]);
}
static inline CUdeviceptr optixGetSbtDataPointer() {
    return reinterpret_cast<CUdeviceptr>(__oxray_frame->record + OPTIX_SBT_RECORD_HEADER_SIZE);
}

static inline float3 optixGetWorldRayOrigin() {
    __oxray_allow(__OXRAY_RAY_KINDS, 0);
    const float* o = __oxray_frame->org;
    return make_float3(o[0], o[1], o[2]);
}
static inline float3 optixGetWorldRayDirection() {
    __oxray_allow(__OXRAY_RAY_KINDS, 1);
    const float* d = __oxray_frame->dir;
    return make_float3(d[0], d[1], d[2]);
}
static inline float3 optixGetObjectRayOrigin() {
    __oxray_allow(__OXRAY_K(IS) | __OXRAY_K(AH), 2);
    const float* o = __oxray_frame->obj_org;
    return make_float3(o[0], o[1], o[2]);
}
static inline float3 optixGetObjectRayDirection() {
    __oxray_allow(__OXRAY_K(IS) | __OXRAY_K(AH), 3);
    const float* d = __oxray_frame->obj_dir;
    return make_float3(d[0], d[1], d[2]);
}
static inline float optixGetRayTmin() { return __oxray_frame->tmin; }
static inline float optixGetRayTmax() { return __oxray_frame->tmax; }
static inline float optixGetRayTime() { return __oxray_frame->time; }
static inline unsigned int optixGetRayFlags() { return __oxray_frame->flags; }
static inline unsigned int optixGetRayVisibilityMask() { return __oxray_frame->mask; }

static inline unsigned int optixGetPrimitiveIndex() { return __oxray_frame->prim; }
static inline unsigned int optixGetSbtGASIndex() { return __oxray_frame->sbt_gas_index; }
static inline unsigned int optixGetInstanceId() { return __oxray_frame->instance_id; }
static inline unsigned int optixGetInstanceIndex() { return __oxray_frame->instance_index; }
static inline unsigned int optixGetHitKind() { return __oxray_frame->hit_kind; }
// Built-in hit kinds (128..255): a triangle's 0xFE/0xFF, otherwise 0x80 | (the low byte of the
// OptixPrimitiveType) << 1 | back face: a sphere's 0x8C/0x8D, a curve's 0x82..0x97 (oxray's
// choice; see oxray_core::HitKind). Everything else is a custom primitive's kind.
static inline OptixPrimitiveType optixGetPrimitiveType(unsigned int hitKind) {
    if (hitKind >= 0xFEu) return OPTIX_PRIMITIVE_TYPE_TRIANGLE;
    unsigned int low = (hitKind & 0x7Fu) >> 1;
    if (hitKind >= 0x80u && low >= 1u && low <= 0x0Bu)
        return (OptixPrimitiveType)(0x2500u | low);
    return OPTIX_PRIMITIVE_TYPE_CUSTOM;
}
static inline OptixPrimitiveType optixGetPrimitiveType() {
    return optixGetPrimitiveType(optixGetHitKind());
}
// Facing is defined for built-in primitives only (hit kinds 128..255), as on the GPU.
static inline bool optixIsFrontFaceHit(unsigned int hitKind) {
    return hitKind >= 0x80u && (hitKind & 1u) == 0u;
}
static inline bool optixIsFrontFaceHit() { return optixIsFrontFaceHit(optixGetHitKind()); }
static inline bool optixIsBackFaceHit(unsigned int hitKind) {
    return hitKind >= 0x80u && (hitKind & 1u) == 1u;
}
static inline bool optixIsBackFaceHit() { return optixIsBackFaceHit(optixGetHitKind()); }
static inline bool optixIsTriangleFrontFaceHit() {
    return optixGetHitKind() == OPTIX_HIT_KIND_TRIANGLE_FRONT_FACE;
}
static inline bool optixIsTriangleBackFaceHit() {
    return optixGetHitKind() == OPTIX_HIT_KIND_TRIANGLE_BACK_FACE;
}
static inline bool optixIsTriangleHit() {
    return optixIsTriangleFrontFaceHit() || optixIsTriangleBackFaceHit();
}
static inline float2 optixGetTriangleBarycentrics() {
    return make_float2(__uint_as_float(__oxray_frame->attr[0]),
                       __uint_as_float(__oxray_frame->attr[1]));
}
#define __OXRAY_ATTRIBUTE(N)                                                                \
    static inline unsigned int optixGetAttribute_##N() { return __oxray_frame->attr[N]; }
__OXRAY_ATTRIBUTE(0) __OXRAY_ATTRIBUTE(1) __OXRAY_ATTRIBUTE(2) __OXRAY_ATTRIBUTE(3)
__OXRAY_ATTRIBUTE(4) __OXRAY_ATTRIBUTE(5) __OXRAY_ATTRIBUTE(6) __OXRAY_ATTRIBUTE(7)
#undef __OXRAY_ATTRIBUTE

static inline void optixGetTriangleVertexData(float3 data[3]) {
    __oxray_allow(__OXRAY_K(AH) | __OXRAY_K(CH), 4);
    float v[9];
    __oxray_frame->api->vertex_data(__oxray_frame, v);
    for (int k = 0; k < 3; ++k) data[k] = make_float3(v[3 * k], v[3 * k + 1], v[3 * k + 2]);
}

// Guide §9.4: the centre (xyz) and radius (w) of the hit sphere, in object space; no build flag
// is needed. Zeros when the hit is not a sphere.
static inline void optixGetSphereData(float4 data[1]) {
    __oxray_allow(__OXRAY_K(AH) | __OXRAY_K(CH), 16);
    float v[4];
    __oxray_frame->api->sphere_data(__oxray_frame, v);
    data[0] = make_float4(v[0], v[1], v[2], v[3]);
}

// Guide §9.3: a curve hit's u in its segment (exactly 0 or 1 on a flat end cap), and a ribbon
// hit's (u, v). They are the hit's attributes.
static inline float optixGetCurveParameter() { return __uint_as_float(__oxray_frame->attr[0]); }
static inline float2 optixGetRibbonParameters() {
    return make_float2(__uint_as_float(__oxray_frame->attr[0]),
                       __uint_as_float(__oxray_frame->attr[1]));
}
// Guide §9.3: the control points (xyz) and radii (w) of the hit curve segment, object space; no
// build flag is needed. Zeros when the hit is not a curve.
static inline void __oxray_curve_data(float4* data, int n) {
    __oxray_allow(__OXRAY_K(AH) | __OXRAY_K(CH), 17);
    float v[16];
    __oxray_frame->api->curve_data(__oxray_frame, v);
    for (int k = 0; k < n; ++k)
        data[k] = make_float4(v[4 * k], v[4 * k + 1], v[4 * k + 2], v[4 * k + 3]);
}
// Guide §9.3: the geometric normal of the hit ribbon at its ribbon parameters (u, v): unit
// length, object space, out of the front face. Zeros when the hit is not a ribbon.
static inline float3 optixGetRibbonNormal(float2 ribbonParameters) {
    __oxray_allow(__OXRAY_K(AH) | __OXRAY_K(CH), 18);
    float n[3];
    __oxray_frame->api->ribbon_normal(__oxray_frame, ribbonParameters.x, ribbonParameters.y, n);
    return make_float3(n[0], n[1], n[2]);
}
static inline void optixGetLinearCurveVertexData(float4 data[2]) { __oxray_curve_data(data, 2); }
static inline void optixGetQuadraticBSplineVertexData(float4 data[3]) {
    __oxray_curve_data(data, 3);
}
static inline void optixGetQuadraticBSplineRocapsVertexData(float4 data[3]) {
    __oxray_curve_data(data, 3);
}
static inline void optixGetCubicBSplineVertexData(float4 data[4]) { __oxray_curve_data(data, 4); }
static inline void optixGetCubicBSplineRocapsVertexData(float4 data[4]) {
    __oxray_curve_data(data, 4);
}
static inline void optixGetCatmullRomVertexData(float4 data[4]) { __oxray_curve_data(data, 4); }
static inline void optixGetCatmullRomRocapsVertexData(float4 data[4]) {
    __oxray_curve_data(data, 4);
}
static inline void optixGetCubicBezierVertexData(float4 data[4]) { __oxray_curve_data(data, 4); }
static inline void optixGetCubicBezierRocapsVertexData(float4 data[4]) {
    __oxray_curve_data(data, 4);
}
static inline void optixGetRibbonVertexData(float4 data[3]) { __oxray_curve_data(data, 3); }

// Guide §13.9: random vertex access, from any program, to a GAS built with
// OPTIX_BUILD_FLAG_ALLOW_RANDOM_VERTEX_ACCESS. A primitive the builder left out reads NaN; so
// does an access OptiX leaves undefined (no flag, another kind, an index out of range).
static inline void optixGetTriangleVertexDataFromHandle(OptixTraversableHandle gas,
                                                        unsigned int primIdx,
                                                        unsigned int sbtGASIdx, float time,
                                                        float3 data[3]) {
    float v[9];
    __oxray_frame->api->vertex_data_from_handle(__oxray_frame, gas, 0u, primIdx, sbtGASIdx,
                                                time, v);
    for (int k = 0; k < 3; ++k) data[k] = make_float3(v[3 * k], v[3 * k + 1], v[3 * k + 2]);
}
static inline void optixGetSphereDataFromHandle(OptixTraversableHandle gas, unsigned int primIdx,
                                                unsigned int sbtGASIdx, float time,
                                                float4 data[1]) {
    float v[4];
    __oxray_frame->api->vertex_data_from_handle(__oxray_frame, gas, 1u, primIdx, sbtGASIdx,
                                                time, v);
    data[0] = make_float4(v[0], v[1], v[2], v[3]);
}
static inline void __oxray_curve_data_from_handle(OptixTraversableHandle gas,
                                                  unsigned int primIdx, unsigned int sbtGASIdx,
                                                  float time, float4* data, int n) {
    float v[16];
    __oxray_frame->api->vertex_data_from_handle(__oxray_frame, gas, 2u, primIdx, sbtGASIdx,
                                                time, v);
    for (int k = 0; k < n; ++k)
        data[k] = make_float4(v[4 * k], v[4 * k + 1], v[4 * k + 2], v[4 * k + 3]);
}
#define __OXRAY_CURVE_FROM_HANDLE(name, n)                                                      \
    static inline void name(OptixTraversableHandle gas, unsigned int primIdx,                  \
                            unsigned int sbtGASIdx, float time, float4 data[n]) {              \
        __oxray_curve_data_from_handle(gas, primIdx, sbtGASIdx, time, data, n);                \
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

static inline OptixTraversableHandle optixGetGASTraversableHandle() {
    __oxray_allow(__OXRAY_HIT_KINDS, 15);
    return __oxray_frame->api->gas_handle(__oxray_frame);
}

static inline unsigned int optixUndefinedValue() { return 0u; }
static inline void optixSetPayloadTypes(unsigned int) {}

// ---------------------------------------------------------------------------------------------
// Payload (guide §14): up to 32 words, copied in at the trace and out when it returns
// ---------------------------------------------------------------------------------------------

#define __OXRAY_PAYLOAD(N)                                                                  \
    static inline unsigned int optixGetPayload_##N() {                                      \
        __oxray_allow(__OXRAY_RAY_KINDS, 5);                                                \
        return N < __oxray_frame->npayload ? __oxray_frame->payload[N] : 0u;                \
    }                                                                                       \
    static inline void optixSetPayload_##N(unsigned int p) {                                \
        __oxray_allow(__OXRAY_RAY_KINDS, 6);                                                \
        if (N < __oxray_frame->npayload) __oxray_frame->payload[N] = p;                     \
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
// Any-hit control, reports and exceptions
// ---------------------------------------------------------------------------------------------

[[noreturn]] static inline void optixIgnoreIntersection() {
    __oxray_allow(__OXRAY_K(AH), 7);
    __oxray_unwind(__OXRAY_PENDING_IGNORE);
}
[[noreturn]] static inline void optixTerminateRay() {
    __oxray_allow(__OXRAY_K(AH), 8);
    __oxray_unwind(__OXRAY_PENDING_TERMINATE);
}

template <typename... A>
static inline bool optixReportIntersection(float hitT, unsigned int hitKind, A... attributes) {
    static_assert(sizeof...(A) <= 8, "optixReportIntersection takes at most 8 attributes");
    __oxray_allow(__OXRAY_K(IS), 9);
    unsigned int a[8] = {static_cast<unsigned int>(attributes)...};
    unsigned int accepted = 0u;
    if (__oxray_frame->api->report(__oxray_frame, hitT, hitKind, a, sizeof...(A), &accepted)) {
        __oxray_unwind(__OXRAY_PENDING_RAISED);
    }
    return accepted != 0u;
}

template <typename... D>
[[noreturn]] static inline void optixThrowException(int exceptionCode, D... details) {
    static_assert(sizeof...(D) <= 8, "optixThrowException takes at most 8 details");
    unsigned int d[8] = {static_cast<unsigned int>(details)...};
    __oxray_frame->exception_code = exceptionCode;
    __oxray_frame->ndetails = sizeof...(D);
    for (unsigned int i = 0; i < 8; ++i) __oxray_frame->details[i] = d[i];
    __oxray_unwind(__OXRAY_PENDING_THROW);
}
static inline int optixGetExceptionCode() { return __oxray_frame->exception_code; }
#define __OXRAY_DETAIL(N)                                                                   \
    static inline unsigned int optixGetExceptionDetail_##N() {                              \
        return __oxray_frame->details[N];                                                   \
    }
__OXRAY_DETAIL(0) __OXRAY_DETAIL(1) __OXRAY_DETAIL(2) __OXRAY_DETAIL(3)
__OXRAY_DETAIL(4) __OXRAY_DETAIL(5) __OXRAY_DETAIL(6) __OXRAY_DETAIL(7)
#undef __OXRAY_DETAIL
static inline char* optixGetExceptionLineInfo() { return nullptr; }

// ---------------------------------------------------------------------------------------------
// optixTrace
// ---------------------------------------------------------------------------------------------

template <typename... Payload>
static inline void optixTrace(OptixTraversableHandle handle, float3 rayOrigin,
                              float3 rayDirection, float tmin, float tmax, float rayTime,
                              OptixVisibilityMask visibilityMask, unsigned int rayFlags,
                              unsigned int SBToffset, unsigned int SBTstride,
                              unsigned int missSBTIndex, Payload&... payload) {
    static_assert(sizeof...(Payload) <= 32, "optixTrace takes at most 32 payload values");
    __oxray_allow(__OXRAY_K(RG) | __OXRAY_K(CH) | __OXRAY_K(MS) | __OXRAY_K(CC), 10);
    constexpr unsigned int n = sizeof...(Payload);
    unsigned int p[n > 0 ? n : 1] = {static_cast<unsigned int>(payload)...};
    const float o[3] = {rayOrigin.x, rayOrigin.y, rayOrigin.z};
    const float d[3] = {rayDirection.x, rayDirection.y, rayDirection.z};
    if (__oxray_frame->api->trace(__oxray_frame, handle, o, d, tmin, tmax, rayTime,
                                  visibilityMask, rayFlags, SBToffset, SBTstride, missSBTIndex,
                                  p, n)) {
        __oxray_unwind(__OXRAY_PENDING_RAISED);
    }
    unsigned int i = 0;
    ((payload = p[i++]), ...);
    (void)i;
}

// The overload with a payload type (one payload type: the type is not checked).
template <typename... Payload>
static inline void optixTrace(OptixPayloadTypeID type, OptixTraversableHandle handle,
                              float3 rayOrigin, float3 rayDirection, float tmin, float tmax,
                              float rayTime, OptixVisibilityMask visibilityMask,
                              unsigned int rayFlags, unsigned int SBToffset,
                              unsigned int SBTstride, unsigned int missSBTIndex,
                              Payload&... payload) {
    (void)type;
    optixTrace(handle, rayOrigin, rayDirection, tmin, tmax, rayTime, visibilityMask, rayFlags,
               SBToffset, SBTstride, missSBTIndex, payload...);
}

// ---------------------------------------------------------------------------------------------
// Callables (guide §15): the arguments travel as a tuple, checked against the callee's
// signature by its wrapper (CALLABLE_PARAMETER_MISMATCH otherwise)
// ---------------------------------------------------------------------------------------------

template <typename ReturnT, typename... ArgTypes>
static inline ReturnT __oxray_call(unsigned int continuation, unsigned int sbtIndex,
                                   ArgTypes... args) {
    std::tuple<ArgTypes...> t(args...);
    typename std::conditional<std::is_void<ReturnT>::value, char, ReturnT>::type r{};
    if (__oxray_frame->api->call(__oxray_frame, continuation, sbtIndex, &t, &r,
                                 typeid(ReturnT(ArgTypes...)).name())) {
        __oxray_unwind(__OXRAY_PENDING_RAISED);
    }
    if constexpr (!std::is_void<ReturnT>::value) return r;
}
template <typename ReturnT, typename... ArgTypes>
static inline ReturnT optixDirectCall(unsigned int sbtIndex, ArgTypes... args) {
    return __oxray_call<ReturnT, ArgTypes...>(0u, sbtIndex, args...);
}
template <typename ReturnT, typename... ArgTypes>
static inline ReturnT optixContinuationCall(unsigned int sbtIndex, ArgTypes... args) {
    __oxray_allow(__OXRAY_K(RG) | __OXRAY_K(CH) | __OXRAY_K(MS) | __OXRAY_K(CC), 11);
    return __oxray_call<ReturnT, ArgTypes...>(1u, sbtIndex, args...);
}

// Runs callable `f` on the caller's tuple, if the signatures agree: 0 done, 2 mismatch.
template <typename F>
struct __oxray_Invoke;
template <typename R, typename... A>
struct __oxray_Invoke<R (*)(A...)> {
    static unsigned int run(R (*f)(A...), void* args, void* ret, const char* signature) {
        if (std::strcmp(signature, typeid(R(A...)).name()) != 0) return 2u;
        std::tuple<A...>& t = *static_cast<std::tuple<A...>*>(args);
        if constexpr (std::is_void<R>::value) {
            std::apply(f, t);
        } else {
            *static_cast<R*>(ret) = std::apply(f, t);
        }
        return 0u;
    }
};

// ---------------------------------------------------------------------------------------------
// Transforms of the current hit and the transform list (guide §13.11)
// ---------------------------------------------------------------------------------------------

static inline void __oxray_matrix(unsigned int which, float m[12]) {
    __oxray_allow(__OXRAY_HIT_KINDS, 12);
    __oxray_frame->api->transform(__oxray_frame, which, m);
}
static inline void optixGetObjectToWorldTransformMatrix(float m[12]) { __oxray_matrix(0u, m); }
static inline void optixGetWorldToObjectTransformMatrix(float m[12]) { __oxray_matrix(1u, m); }
static inline void optixGetObjectToWorldTransformMatrix(float4& m0, float4& m1, float4& m2) {
    float m[12];
    __oxray_matrix(0u, m);
    m0 = make_float4(m[0], m[1], m[2], m[3]);
    m1 = make_float4(m[4], m[5], m[6], m[7]);
    m2 = make_float4(m[8], m[9], m[10], m[11]);
}
static inline void optixGetWorldToObjectTransformMatrix(float4& m0, float4& m1, float4& m2) {
    float m[12];
    __oxray_matrix(1u, m);
    m0 = make_float4(m[0], m[1], m[2], m[3]);
    m1 = make_float4(m[4], m[5], m[6], m[7]);
    m2 = make_float4(m[8], m[9], m[10], m[11]);
}
static inline float3 __oxray_point(const float m[12], float3 p) {
    return make_float3(m[0] * p.x + m[1] * p.y + m[2] * p.z + m[3],
                       m[4] * p.x + m[5] * p.y + m[6] * p.z + m[7],
                       m[8] * p.x + m[9] * p.y + m[10] * p.z + m[11]);
}
static inline float3 __oxray_vector(const float m[12], float3 v) {
    return make_float3(m[0] * v.x + m[1] * v.y + m[2] * v.z, m[4] * v.x + m[5] * v.y + m[6] * v.z,
                       m[8] * v.x + m[9] * v.y + m[10] * v.z);
}
// A normal goes through the inverse transpose: the other matrix, transposed.
static inline float3 __oxray_normal(const float inv[12], float3 n) {
    return make_float3(inv[0] * n.x + inv[4] * n.y + inv[8] * n.z,
                       inv[1] * n.x + inv[5] * n.y + inv[9] * n.z,
                       inv[2] * n.x + inv[6] * n.y + inv[10] * n.z);
}
#define __OXRAY_XFORM(NAME, WHICH, APPLY)                                                   \
    static inline float3 NAME(float3 v) {                                                   \
        float m[12];                                                                        \
        __oxray_matrix(WHICH, m);                                                           \
        return APPLY(m, v);                                                                 \
    }
__OXRAY_XFORM(optixTransformPointFromWorldToObjectSpace, 1u, __oxray_point)
__OXRAY_XFORM(optixTransformVectorFromWorldToObjectSpace, 1u, __oxray_vector)
__OXRAY_XFORM(optixTransformNormalFromWorldToObjectSpace, 0u, __oxray_normal)
__OXRAY_XFORM(optixTransformPointFromObjectToWorldSpace, 0u, __oxray_point)
__OXRAY_XFORM(optixTransformVectorFromObjectToWorldSpace, 0u, __oxray_vector)
__OXRAY_XFORM(optixTransformNormalFromObjectToWorldSpace, 1u, __oxray_normal)
#undef __OXRAY_XFORM

// Transform-list handles on the CPU name an entry of the current hit's list: a tag and the
// entry's position. They can be decoded while the hit's programs run.
#define __OXRAY_LIST_TAG 0x4F58000000000000ull
static inline unsigned int optixGetTransformListSize() {
    __oxray_allow(__OXRAY_HIT_KINDS, 13);
    return __oxray_frame->api->transform_list(__oxray_frame, ~0u, nullptr, nullptr, nullptr,
                                              nullptr);
}
static inline OptixTraversableHandle optixGetTransformListHandle(unsigned int i) {
    __oxray_allow(__OXRAY_HIT_KINDS, 14);
    return __OXRAY_LIST_TAG | (unsigned long long)i;
}
struct __oxray_ListEntry {
    unsigned int type, id, index;
    float o2w[12], w2o[12];
    unsigned long long child;
};
// Instance handles from optixGetInstanceTraversableFromIAS (guide §13.12) name one of the last
// 64 instances the thread asked for: a tag and the entry's position in a ring.
#define __OXRAY_RANDOM_TAG 0x4F59000000000000ull
#define __OXRAY_RANDOM_RING 64u
static thread_local __oxray_ListEntry __oxray_random_ring[__OXRAY_RANDOM_RING];
static thread_local unsigned int __oxray_random_next;
static inline __oxray_ListEntry __oxray_entry_of(OptixTraversableHandle h) {
    __oxray_ListEntry e{};
    if ((h & 0xFFFF000000000000ull) == __OXRAY_LIST_TAG) {
        e.type = __oxray_frame->api->transform_list(__oxray_frame, (unsigned int)h, &e.id,
                                                    &e.index, e.o2w, e.w2o);
    } else if ((h & 0xFFFF000000000000ull) == __OXRAY_RANDOM_TAG) {
        e = __oxray_random_ring[(unsigned int)h % __OXRAY_RANDOM_RING];
    }
    return e;
}
static inline OptixTraversableHandle optixGetInstanceTraversableFromIAS(OptixTraversableHandle ias,
                                                                        unsigned int instIdx) {
    __oxray_ListEntry e{};
    if (!__oxray_frame->api->instance_from_ias(__oxray_frame, ias, instIdx, &e.id, &e.index,
                                               e.o2w, e.w2o, &e.child))
        return 0ull;
    e.type = (unsigned int)OPTIX_TRANSFORM_TYPE_INSTANCE;
    const unsigned int k = __oxray_random_next++ % __OXRAY_RANDOM_RING;
    __oxray_random_ring[k] = e;
    return __OXRAY_RANDOM_TAG | (unsigned long long)k;
}
static inline OptixTransformType optixGetTransformTypeFromHandle(OptixTraversableHandle h) {
    return (OptixTransformType)__oxray_entry_of(h).type;
}
static inline unsigned int optixGetInstanceIdFromHandle(OptixTraversableHandle h) {
    return __oxray_entry_of(h).id;
}
static inline OptixTraversableHandle optixGetInstanceChildFromHandle(OptixTraversableHandle h) {
    // The child of an instance from optixGetInstanceTraversableFromIAS: its handle value (it
    // traces where the structure was given a handle before the launch). Transform-list
    // children are not addressable from CPU programs.
    return __oxray_entry_of(h).child;
}
static thread_local float4 __oxray_rows[2][3];
static thread_local OptixStaticTransform __oxray_static;
static inline const float4* optixGetInstanceTransformFromHandle(OptixTraversableHandle h) {
    __oxray_ListEntry e = __oxray_entry_of(h);
    std::memcpy(__oxray_rows[0], e.o2w, sizeof e.o2w);
    return __oxray_rows[0];
}
static inline const float4* optixGetInstanceInverseTransformFromHandle(OptixTraversableHandle h) {
    __oxray_ListEntry e = __oxray_entry_of(h);
    std::memcpy(__oxray_rows[1], e.w2o, sizeof e.w2o);
    return __oxray_rows[1];
}
static inline const OptixStaticTransform* optixGetStaticTransformFromHandle(
    OptixTraversableHandle h) {
    __oxray_ListEntry e = __oxray_entry_of(h);
    __oxray_static = OptixStaticTransform{};
    std::memcpy(__oxray_static.transform, e.o2w, sizeof e.o2w);
    std::memcpy(__oxray_static.invTransform, e.w2o, sizeof e.w2o);
    return &__oxray_static;
}

static inline const OptixMatrixMotionTransform* optixGetMatrixMotionTransformFromHandle(
    OptixTraversableHandle h) {
    if ((h & 0xFFFF000000000000ull) != __OXRAY_LIST_TAG) return nullptr;
    return static_cast<const OptixMatrixMotionTransform*>(
        __oxray_frame->api->motion_transform(__oxray_frame, (unsigned int)h, 2u));
}
static inline const OptixSRTMotionTransform* optixGetSRTMotionTransformFromHandle(
    OptixTraversableHandle h) {
    if ((h & 0xFFFF000000000000ull) != __OXRAY_LIST_TAG) return nullptr;
    return static_cast<const OptixSRTMotionTransform*>(
        __oxray_frame->api->motion_transform(__oxray_frame, (unsigned int)h, 3u));
}

// ---------------------------------------------------------------------------------------------
// Motion options of a GAS (guide §13.10)
// ---------------------------------------------------------------------------------------------

static inline float optixGetGASMotionTimeBegin(OptixTraversableHandle gas) {
    float t[2] = {0.f, 0.f};
    __oxray_frame->api->gas_motion(__oxray_frame, gas, t);
    return t[0];
}
static inline float optixGetGASMotionTimeEnd(OptixTraversableHandle gas) {
    float t[2] = {0.f, 0.f};
    __oxray_frame->api->gas_motion(__oxray_frame, gas, t);
    return t[1];
}
static inline unsigned int optixGetGASMotionStepCount(OptixTraversableHandle gas) {
    float t[2];
    return __oxray_frame->api->gas_motion(__oxray_frame, gas, t);
}

#endif  // OXRAY_DEVICE_CPU_H
