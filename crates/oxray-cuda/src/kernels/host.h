// host.h: the CUDA C++ the trace and simulation kernels use, given host meanings, so that the
// tests compile the kernels' own source with the host's C++ compiler and run them one thread at
// a time on the CPU (`src/host_kernels.rs`). Without FMA contraction, the host's IEEE single
// precision computes what the device computes with the kernels' options (--fmad=false, IEEE
// division and square root), so the kernels' results can be compared bit for bit with the CPU
// backend's on a machine without a GPU.

#include <cmath>
#include <cstdint>
#include <cstring>
#include <math.h>

#define __global__
#define __device__
#define __host__
#define __forceinline__ inline
#define __noinline__ __attribute__((noinline))
#define __restrict__ __restrict
#define __launch_bounds__(...)
#define __align__(n) alignas(n)

struct float3 {
    float x, y, z;
};
struct alignas(16) float4 {
    float x, y, z, w;
};
struct alignas(16) uint4 {
    unsigned int x, y, z, w;
};

static inline float3 make_float3(float x, float y, float z) { return {x, y, z}; }
static inline float4 make_float4(float x, float y, float z, float w) { return {x, y, z, w}; }
static inline uint4 make_uint4(unsigned int x, unsigned int y, unsigned int z, unsigned int w) {
    return {x, y, z, w};
}

template <typename To, typename From>
static inline To host_bits(From v) {
    static_assert(sizeof(To) == sizeof(From), "bit casts keep the size");
    To r;
    std::memcpy(&r, &v, sizeof r);
    return r;
}
static inline unsigned int __float_as_uint(float f) { return host_bits<unsigned int>(f); }
static inline float __uint_as_float(unsigned int u) { return host_bits<float>(u); }
static inline int __float_as_int(float f) { return host_bits<int>(f); }
static inline float __int_as_float(int i) { return host_bits<float>(i); }
static inline double __longlong_as_double(long long l) { return host_bits<double>(l); }
static inline int __ffs(unsigned int x) { return __builtin_ffs((int)x); }
static inline int __clz(unsigned int x) { return x == 0 ? 32 : __builtin_clz(x); }

template <typename T>
static inline T __ldg(const T* p) {
    return *p;
}

using std::isfinite;
using std::isnan;

// One kernel thread at a time: the drivers set the block index to the kernel thread's index
// (per host thread, so that tests may run kernels side by side).
struct host_dim {
    unsigned int x, y, z;
};
static thread_local host_dim blockIdx = {0, 0, 0}, threadIdx = {0, 0, 0}, blockDim = {1, 1, 1};

// Runs a kernel's body for threads 0 .. n, one after the other.
#define HOST_LAUNCH(n, call)                  \
    do {                                      \
        for (unsigned int t = 0; t < (n); ++t) { \
            blockIdx.x = t;                   \
            call;                             \
        }                                     \
    } while (0)
