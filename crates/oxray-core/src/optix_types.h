// optix_types.h: the types and constants of the NVIDIA OptiX 9 programming guide that programs
// name (handles, ray flags, hit kinds, exception codes, payload types, transform and primitive
// types, the static transform's layout), written from the guide and its header values. Both
// of oxray's device headers include it: the CUDA backend's and the CPU backend's.

#ifndef OXRAY_OPTIX_TYPES_H
#define OXRAY_OPTIX_TYPES_H

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

// The guide's static transform (§13.11): the child's handle, padding, the object-to-world
// transform and its inverse, 3x4 row-major. A static transform's handle points at a
// descriptor of kind __OXRAY_STATIC on a GPU, which this follows.
struct OptixStaticTransform {
    OptixTraversableHandle child;
    unsigned int pad[2];
    float transform[12];
    float invTransform[12];
};

// Motion (guide §5.10.1): keys evenly spaced from timeBegin to timeEnd.
enum OptixMotionFlags {
    OPTIX_MOTION_FLAG_NONE = 0,
    OPTIX_MOTION_FLAG_START_VANISH = 1u << 0,
    OPTIX_MOTION_FLAG_END_VANISH = 1u << 1,
};
struct OptixMotionOptions {
    unsigned short numKeys;
    unsigned short flags;
    float timeBegin;
    float timeEnd;
};
// A matrix motion transform (§5.10.4): variable size, numKeys 3x4 row-major matrices.
struct OptixMatrixMotionTransform {
    OptixTraversableHandle child;
    OptixMotionOptions motionOptions;
    unsigned int pad[3];
    float transform[2][12];
};
// One key of an SRT motion transform (§5.10.5).
struct OptixSRTData {
    float sx, a, b, pvx, sy, c, pvy, sz, pvz, qx, qy, qz, qw, tx, ty, tz;
};
// An SRT motion transform (§5.10.5): variable size, numKeys keys.
struct OptixSRTMotionTransform {
    OptixTraversableHandle child;
    OptixMotionOptions motionOptions;
    unsigned int pad[3];
    OptixSRTData srtData[2];
};

enum OptixTransformType {
    OPTIX_TRANSFORM_TYPE_NONE = 0,
    OPTIX_TRANSFORM_TYPE_STATIC_TRANSFORM = 1,
    OPTIX_TRANSFORM_TYPE_MATRIX_MOTION_TRANSFORM = 2,
    OPTIX_TRANSFORM_TYPE_SRT_MOTION_TRANSFORM = 3,
    OPTIX_TRANSFORM_TYPE_INSTANCE = 4,
};

enum OptixPrimitiveType {
    OPTIX_PRIMITIVE_TYPE_CUSTOM = 0x2500,
    OPTIX_PRIMITIVE_TYPE_ROUND_QUADRATIC_BSPLINE = 0x2501,
    OPTIX_PRIMITIVE_TYPE_ROUND_CUBIC_BSPLINE = 0x2502,
    OPTIX_PRIMITIVE_TYPE_ROUND_LINEAR = 0x2503,
    OPTIX_PRIMITIVE_TYPE_ROUND_CATMULLROM = 0x2504,
    OPTIX_PRIMITIVE_TYPE_FLAT_QUADRATIC_BSPLINE = 0x2505,
    OPTIX_PRIMITIVE_TYPE_SPHERE = 0x2506,
    OPTIX_PRIMITIVE_TYPE_ROUND_CUBIC_BEZIER = 0x2507,
    OPTIX_PRIMITIVE_TYPE_ROUND_QUADRATIC_BSPLINE_ROCAPS = 0x2508,
    OPTIX_PRIMITIVE_TYPE_ROUND_CUBIC_BSPLINE_ROCAPS = 0x2509,
    OPTIX_PRIMITIVE_TYPE_ROUND_CATMULLROM_ROCAPS = 0x250A,
    OPTIX_PRIMITIVE_TYPE_ROUND_CUBIC_BEZIER_ROCAPS = 0x250B,
    OPTIX_PRIMITIVE_TYPE_TRIANGLE = 0x2531,
    OPTIX_PRIMITIVE_TYPE_DISPLACED_MICROMESH_TRIANGLE = 0x2532,
};

#endif  // OXRAY_OPTIX_TYPES_H
