//! Exceptions (guide §13.14): codes, flags, and what a launch index raised.

use bitflags::bitflags;

bitflags! {
    /// Which exceptions a pipeline checks for (`OptixExceptionFlags`). On the CPU oxray checks
    /// trace depth, SBT indices and callable nesting whatever the flags, and user exceptions are
    /// always raised: the checks cost next to nothing there and turn what OptiX leaves
    /// undefined into exceptions. The flags are kept for backends where they cost.
    #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
    #[doc(alias = "OptixExceptionFlags")]
    pub struct ExceptionFlags: u32 {
        /// Continuation-stack overflow (`OPTIX_EXCEPTION_FLAG_STACK_OVERFLOW`).
        const STACK_OVERFLOW = 1 << 0;
        /// A trace nested deeper than `max_trace_depth` (`OPTIX_EXCEPTION_FLAG_TRACE_DEPTH`).
        const TRACE_DEPTH = 1 << 1;
        /// User exceptions thrown by programs (`OPTIX_EXCEPTION_FLAG_USER`).
        const USER = 1 << 2;
    }
}

/// An exception code (`optixGetExceptionCode`): user codes are `0..2^30`, built-in codes are
/// negative (values from the OptiX headers).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[doc(alias = "optixGetExceptionCode")]
pub struct ExceptionCode(pub i32);

impl ExceptionCode {
    /// `OPTIX_EXCEPTION_CODE_STACK_OVERFLOW`.
    #[doc(alias = "OPTIX_EXCEPTION_CODE_STACK_OVERFLOW")]
    pub const STACK_OVERFLOW: ExceptionCode = ExceptionCode(-1);
    /// `OPTIX_EXCEPTION_CODE_TRACE_DEPTH_EXCEEDED`.
    #[doc(alias = "OPTIX_EXCEPTION_CODE_TRACE_DEPTH_EXCEEDED")]
    pub const TRACE_DEPTH_EXCEEDED: ExceptionCode = ExceptionCode(-2);
    /// `OPTIX_EXCEPTION_CODE_TRAVERSAL_DEPTH_EXCEEDED`: the traversable graph is deeper than
    /// the pipeline's `max_traversable_graph_depth`.
    #[doc(alias = "OPTIX_EXCEPTION_CODE_TRAVERSAL_DEPTH_EXCEEDED")]
    pub const TRAVERSAL_DEPTH_EXCEEDED: ExceptionCode = ExceptionCode(-3);
    /// `OPTIX_EXCEPTION_CODE_TRAVERSAL_INVALID_TRAVERSABLE`: the traced graph is not allowed by
    /// the pipeline's traversable-graph flags.
    #[doc(alias = "OPTIX_EXCEPTION_CODE_TRAVERSAL_INVALID_TRAVERSABLE")]
    pub const TRAVERSAL_INVALID_TRAVERSABLE: ExceptionCode = ExceptionCode(-5);
    /// `OPTIX_EXCEPTION_CODE_TRAVERSAL_INVALID_MISS_SBT`: the miss index is past the miss records.
    #[doc(alias = "OPTIX_EXCEPTION_CODE_TRAVERSAL_INVALID_MISS_SBT")]
    pub const INVALID_MISS_SBT: ExceptionCode = ExceptionCode(-6);
    /// `OPTIX_EXCEPTION_CODE_TRAVERSAL_INVALID_HIT_SBT`: the hit-group index is past the records.
    #[doc(alias = "OPTIX_EXCEPTION_CODE_TRAVERSAL_INVALID_HIT_SBT")]
    pub const INVALID_HIT_SBT: ExceptionCode = ExceptionCode(-7);
    /// `OPTIX_EXCEPTION_CODE_UNSUPPORTED_PRIMITIVE_TYPE`: the pipeline's primitive-type flags
    /// exclude the primitives of the traced structure.
    #[doc(alias = "OPTIX_EXCEPTION_CODE_UNSUPPORTED_PRIMITIVE_TYPE")]
    pub const UNSUPPORTED_PRIMITIVE_TYPE: ExceptionCode = ExceptionCode(-8);
    /// `OPTIX_EXCEPTION_CODE_UNSUPPORTED_SINGLE_LEVEL_GAS`: a GAS was traced directly but the
    /// pipeline's traversable-graph flags do not allow a single GAS.
    #[doc(alias = "OPTIX_EXCEPTION_CODE_UNSUPPORTED_SINGLE_LEVEL_GAS")]
    pub const UNSUPPORTED_SINGLE_LEVEL_GAS: ExceptionCode = ExceptionCode(-15);
    /// `OPTIX_EXCEPTION_CODE_INVALID_RAY` (validation mode): NaN or infinite origin or
    /// direction, negative tmin, or tmin > tmax.
    #[doc(alias = "OPTIX_EXCEPTION_CODE_INVALID_RAY")]
    pub const INVALID_RAY: ExceptionCode = ExceptionCode(-9);
    /// `OPTIX_EXCEPTION_CODE_CALLABLE_PARAMETER_MISMATCH`: a callable was called with other
    /// argument or return types than it was registered with.
    #[doc(alias = "OPTIX_EXCEPTION_CODE_CALLABLE_PARAMETER_MISMATCH")]
    pub const CALLABLE_PARAMETER_MISMATCH: ExceptionCode = ExceptionCode(-10);
    /// `OPTIX_EXCEPTION_CODE_CALLABLE_INVALID_SBT`: the callable index is past the records.
    #[doc(alias = "OPTIX_EXCEPTION_CODE_CALLABLE_INVALID_SBT")]
    pub const CALLABLE_INVALID_SBT: ExceptionCode = ExceptionCode(-12);
    /// `OPTIX_EXCEPTION_CODE_CALLABLE_NO_DC_SBT_RECORD`: the record has no direct callable.
    #[doc(alias = "OPTIX_EXCEPTION_CODE_CALLABLE_NO_DC_SBT_RECORD")]
    pub const CALLABLE_NO_DC_SBT_RECORD: ExceptionCode = ExceptionCode(-13);
    /// `OPTIX_EXCEPTION_CODE_CALLABLE_NO_CC_SBT_RECORD`: the record has no continuation callable.
    #[doc(alias = "OPTIX_EXCEPTION_CODE_CALLABLE_NO_CC_SBT_RECORD")]
    pub const CALLABLE_NO_CC_SBT_RECORD: ExceptionCode = ExceptionCode(-14);
    /// `OPTIX_EXCEPTION_CODE_PAYLOAD_TYPE_MISMATCH`: more payload words than the pipeline has.
    #[doc(alias = "OPTIX_EXCEPTION_CODE_PAYLOAD_TYPE_MISMATCH")]
    pub const PAYLOAD_TYPE_MISMATCH: ExceptionCode = ExceptionCode(-33);

    /// Largest user code, `2^30 - 1`.
    pub const MAX_USER: i32 = (1 << 30) - 1;

    /// Whether this is a user code.
    #[must_use]
    pub fn is_user(self) -> bool {
        (0..=Self::MAX_USER).contains(&self.0)
    }
}

/// An exception raised in a launch index: its code and up to eight detail words.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Exception {
    /// The code.
    pub code: ExceptionCode,
    details: [u32; 8],
    num_details: u8,
}

impl Exception {
    /// An exception with `code` and up to eight detail words (more are dropped).
    #[must_use]
    pub fn new(code: ExceptionCode, details: &[u32]) -> Self {
        let n = details.len().min(8);
        let mut d = [0; 8];
        d[..n].copy_from_slice(&details[..n]);
        Exception {
            code,
            details: d,
            num_details: n as u8,
        }
    }

    /// The detail words (`optixGetExceptionDetail_0..7`).
    #[doc(alias = "optixGetExceptionDetail_0")]
    #[must_use]
    pub fn details(&self) -> &[u32] {
        &self.details[..self.num_details as usize]
    }
}

impl std::fmt::Display for Exception {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let name = match self.code {
            ExceptionCode::STACK_OVERFLOW => "stack overflow",
            ExceptionCode::TRACE_DEPTH_EXCEEDED => "trace depth exceeded",
            ExceptionCode::INVALID_MISS_SBT => "invalid miss SBT index",
            ExceptionCode::TRAVERSAL_DEPTH_EXCEEDED => "traversable graph too deep",
            ExceptionCode::TRAVERSAL_INVALID_TRAVERSABLE => {
                "traversable not allowed by the graph flags"
            }
            ExceptionCode::INVALID_HIT_SBT => "invalid hit-group SBT index",
            ExceptionCode::INVALID_RAY => "invalid ray",
            ExceptionCode::UNSUPPORTED_PRIMITIVE_TYPE => "unsupported primitive type",
            ExceptionCode::UNSUPPORTED_SINGLE_LEVEL_GAS => {
                "single GAS not allowed by the graph flags"
            }
            ExceptionCode::CALLABLE_INVALID_SBT => "invalid callable SBT index",
            ExceptionCode::CALLABLE_PARAMETER_MISMATCH => "callable parameter mismatch",
            ExceptionCode::CALLABLE_NO_DC_SBT_RECORD => "no direct callable in the record",
            ExceptionCode::CALLABLE_NO_CC_SBT_RECORD => "no continuation callable in the record",
            ExceptionCode::PAYLOAD_TYPE_MISMATCH => "payload size mismatch",
            c if c.is_user() => "user exception",
            _ => "exception",
        };
        write!(f, "{name} (code {}", self.code.0)?;
        if self.num_details > 0 {
            write!(f, ", details {:?}", self.details())?;
        }
        write!(f, ")")
    }
}
