//! Device-context and pipeline options (guide §4, §6.3, §6.7), ray flags (§13.2) and what a
//! launch reports (§10).

use crate::exception::{Exception, ExceptionFlags};
use bitflags::bitflags;
use std::sync::Arc;

/// Log levels of the context's log callback (guide §4.1; numeric values as OptiX's).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum LogLevel {
    /// No messages.
    Disable = 0,
    /// Unrecoverable errors.
    Fatal = 1,
    /// Recoverable errors.
    Error = 2,
    /// Warnings.
    Warning = 3,
    /// Status and progress.
    Print = 4,
}

type LogFn = Arc<dyn Fn(LogLevel, &str, &str) + Send + Sync>;

/// The device context (`OptixDeviceContext`): validation mode and logging.
///
/// ```
/// use oxray_core::{DeviceContext, LogLevel};
/// let ctx = DeviceContext::new()
///     .validation_mode(true)
///     .log_callback(LogLevel::Warning, |level, tag, message| eprintln!("[{level:?}][{tag}] {message}"));
/// assert!(ctx.is_validation_mode());
/// ```
#[derive(Clone, Default)]
#[doc(alias = "OptixDeviceContext")]
pub struct DeviceContext {
    validation_mode: bool,
    log_level: Option<LogLevel>,
    log: Option<LogFn>,
}

impl DeviceContext {
    /// A context without validation or logging.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Validation mode (guide §4.3): launches also check rays (NaN or infinite components,
    /// negative tmin, tmin > tmax raise `INVALID_RAY`), report every exception to the log, and
    /// fail with [`LaunchError::ValidationFailure`](crate::LaunchError::ValidationFailure) when a
    /// launch index raised a built-in (non-user) exception.
    #[must_use]
    pub fn validation_mode(mut self, on: bool) -> Self {
        self.validation_mode = on;
        self
    }

    /// Whether validation mode is on.
    #[must_use]
    pub fn is_validation_mode(&self) -> bool {
        self.validation_mode
    }

    /// Sets the log callback: it receives messages at `level` and below (more severe).
    pub fn log_callback(
        mut self,
        level: LogLevel,
        f: impl Fn(LogLevel, &str, &str) + Send + Sync + 'static,
    ) -> Self {
        self.log_level = Some(level);
        self.log = Some(Arc::new(f));
        self
    }

    /// Whether a log callback is set (at any level).
    #[must_use]
    pub fn has_log_callback(&self) -> bool {
        self.log.is_some()
    }

    /// Sends a message to the log callback, if one is set for its level.
    pub fn log(&self, level: LogLevel, tag: &str, message: &str) {
        if let (Some(max), Some(f)) = (self.log_level, &self.log) {
            if level != LogLevel::Disable && level <= max {
                f(level, tag, message);
            }
        }
    }
}

bitflags! {
    /// Which traversable graphs a pipeline may trace (`OptixTraversableGraphFlags`); empty means
    /// any.
    #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
    #[doc(alias = "OptixTraversableGraphFlags")]
    pub struct TraversableGraphFlags: u32 {
        /// A GAS traced directly.
        const ALLOW_SINGLE_GAS = 1 << 0;
        /// One level of instances over GASes, without transforms.
        const ALLOW_SINGLE_LEVEL_INSTANCING = 1 << 1;
    }
}

bitflags! {
    /// Which primitive types a pipeline may intersect (`OptixPrimitiveTypeFlags`); empty means
    /// triangles and custom primitives. Spheres (and curves) must be enabled explicitly (guide
    /// §9.1): an empty set does not include them.
    #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
    #[doc(alias = "OptixPrimitiveTypeFlags")]
    pub struct PrimitiveTypeFlags: u32 {
        /// Custom primitives.
        const CUSTOM = 1 << 0;
        /// Round quadratic B-spline curves (`OPTIX_PRIMITIVE_TYPE_FLAGS_ROUND_QUADRATIC_BSPLINE`).
        const ROUND_QUADRATIC_BSPLINE = 1 << 1;
        /// Round cubic B-spline curves (`OPTIX_PRIMITIVE_TYPE_FLAGS_ROUND_CUBIC_BSPLINE`).
        const ROUND_CUBIC_BSPLINE = 1 << 2;
        /// Round linear curves (`OPTIX_PRIMITIVE_TYPE_FLAGS_ROUND_LINEAR`).
        const ROUND_LINEAR = 1 << 3;
        /// Round Catmull-Rom curves (`OPTIX_PRIMITIVE_TYPE_FLAGS_ROUND_CATMULLROM`).
        const ROUND_CATMULLROM = 1 << 4;
        /// Ribbons (`OPTIX_PRIMITIVE_TYPE_FLAGS_FLAT_QUADRATIC_BSPLINE`).
        const FLAT_QUADRATIC_BSPLINE = 1 << 5;
        /// Built-in spheres (`OPTIX_PRIMITIVE_TYPE_FLAGS_SPHERE`).
        const SPHERE = 1 << 6;
        /// Round cubic Bézier curves (`OPTIX_PRIMITIVE_TYPE_FLAGS_ROUND_CUBIC_BEZIER`).
        const ROUND_CUBIC_BEZIER = 1 << 7;
        /// Rocaps quadratic B-splines (`OPTIX_PRIMITIVE_TYPE_FLAGS_ROUND_QUADRATIC_BSPLINE_ROCAPS`).
        const ROUND_QUADRATIC_BSPLINE_ROCAPS = 1 << 8;
        /// Rocaps cubic B-splines (`OPTIX_PRIMITIVE_TYPE_FLAGS_ROUND_CUBIC_BSPLINE_ROCAPS`).
        const ROUND_CUBIC_BSPLINE_ROCAPS = 1 << 9;
        /// Rocaps Catmull-Rom curves (`OPTIX_PRIMITIVE_TYPE_FLAGS_ROUND_CATMULLROM_ROCAPS`).
        const ROUND_CATMULLROM_ROCAPS = 1 << 10;
        /// Rocaps cubic Béziers (`OPTIX_PRIMITIVE_TYPE_FLAGS_ROUND_CUBIC_BEZIER_ROCAPS`).
        const ROUND_CUBIC_BEZIER_ROCAPS = 1 << 11;
        /// Triangles.
        const TRIANGLE = 1 << 31;
    }
}

impl PrimitiveTypeFlags {
    /// Whether a pipeline with these flags intersects primitives of type `ty` (guide §9.1):
    /// the empty set means triangles and custom primitives; spheres need [`Self::SPHERE`], each curve type its own flag.
    ///
    /// ```
    /// use oxray_core::{PrimitiveType, PrimitiveTypeFlags};
    /// assert!(PrimitiveTypeFlags::empty().allows(PrimitiveType::Triangle));
    /// assert!(!PrimitiveTypeFlags::empty().allows(PrimitiveType::Sphere));
    /// assert!(PrimitiveTypeFlags::SPHERE.allows(PrimitiveType::Sphere));
    /// assert!(!PrimitiveTypeFlags::SPHERE.allows(PrimitiveType::Triangle));
    /// ```
    #[must_use]
    pub fn allows(self, ty: crate::PrimitiveType) -> bool {
        let set = if self.is_empty() {
            PrimitiveTypeFlags::TRIANGLE | PrimitiveTypeFlags::CUSTOM
        } else {
            self
        };
        set.contains(match ty {
            crate::PrimitiveType::Custom => PrimitiveTypeFlags::CUSTOM,
            crate::PrimitiveType::Sphere => PrimitiveTypeFlags::SPHERE,
            crate::PrimitiveType::Triangle => PrimitiveTypeFlags::TRIANGLE,
            crate::PrimitiveType::Curve(c) => c.type_flag(),
        })
    }
}

/// Compile options shared by every program of a pipeline (`OptixPipelineCompileOptions`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[doc(alias = "OptixPipelineCompileOptions")]
pub struct PipelineCompileOptions {
    /// Whether rays carry a time (otherwise `ray_time()` is 0).
    pub uses_motion_blur: bool,
    /// Allowed traversable graphs (empty: any). A trace whose root the flags exclude raises
    /// `UNSUPPORTED_SINGLE_LEVEL_GAS` or `TRAVERSAL_INVALID_TRAVERSABLE` (guide §5.9.1). On the
    /// CUDA backend a pipeline that allows only a single GAS is compiled without the instance
    /// and transform traversal, as OptiX specialises its pipelines: name the graphs the
    /// pipeline traces.
    pub traversable_graph_flags: TraversableGraphFlags,
    /// Payload words a trace may pass (at most 32).
    pub num_payload_values: u32,
    /// Attribute words an intersection may report (at most 8).
    pub num_attribute_values: u32,
    /// Exceptions checked for.
    pub exception_flags: ExceptionFlags,
    /// Allowed primitive types (empty: triangles and custom primitives). A hit GAS of another
    /// type raises `UNSUPPORTED_PRIMITIVE_TYPE` (guide §6.3); on the CUDA backend only these
    /// types' walks (by default the triangles' and the custom primitives') are compiled into
    /// the pipeline's kernel.
    pub uses_primitive_type_flags: PrimitiveTypeFlags,
}

impl Default for PipelineCompileOptions {
    fn default() -> Self {
        PipelineCompileOptions {
            uses_motion_blur: false,
            traversable_graph_flags: TraversableGraphFlags::empty(),
            num_payload_values: 8,
            num_attribute_values: 2,
            exception_flags: ExceptionFlags::empty(),
            uses_primitive_type_flags: PrimitiveTypeFlags::empty(),
        }
    }
}

/// Link options (`OptixPipelineLinkOptions`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PipelineLinkOptions {
    /// Deepest trace nesting (ray generation traces at depth 1); at most 31.
    pub max_trace_depth: u32,
}

impl Default for PipelineLinkOptions {
    fn default() -> Self {
        PipelineLinkOptions { max_trace_depth: 1 }
    }
}

bitflags! {
    /// Ray flags of a trace (`OptixRayFlags`, guide §13.2). Values match OptiX's.
    #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
    pub struct RayFlags: u32 {
        /// No any-hit program runs; overrides instance and geometry flags.
        const DISABLE_ANYHIT = 1 << 0;
        /// The any-hit program runs even where geometry or instance flags disable it.
        const ENFORCE_ANYHIT = 1 << 1;
        /// The first accepted hit ends traversal and becomes the closest hit.
        const TERMINATE_ON_FIRST_HIT = 1 << 2;
        /// No closest-hit program runs (the miss program still does on a miss).
        const DISABLE_CLOSESTHIT = 1 << 3;
        /// Back faces of triangles are not hit.
        const CULL_BACK_FACING_TRIANGLES = 1 << 4;
        /// Front faces of triangles are not hit.
        const CULL_FRONT_FACING_TRIANGLES = 1 << 5;
        /// Primitives whose any-hit is disabled are not hit.
        const CULL_DISABLED_ANYHIT = 1 << 6;
        /// Primitives whose any-hit is enabled are not hit.
        const CULL_ENFORCED_ANYHIT = 1 << 7;
        /// Accepted for compatibility; oxray has no opacity micromaps yet.
        const FORCE_OPACITY_MICROMAP_2_STATE = 1 << 10;
    }
}

/// What a launch reports.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
#[must_use = "a launch reports the exceptions its launch indices raised"]
pub struct LaunchReport {
    /// Launch indices that ended in an exception.
    pub exceptions: u64,
    /// The first (up to five, by launch index) exceptions, with their launch indices.
    pub first_exceptions: Vec<([u32; 3], Exception)>,
    /// Rays traced: the `optixTrace` calls of every launch index at every depth (radiance,
    /// shadow and any other ray type alike), so that a caller can report rays per second.
    pub traces: u64,
}

impl LaunchReport {
    /// What every backend does with a finished launch's exceptions. Without an exception
    /// record, the built-in exception program (guide §13.14) stands in: the first five
    /// exceptions go to the context's log callback at [`LogLevel::Error`] if one is set, and
    /// are otherwise printed to stderr ([`builtin_exception_lines`]; the guide says stdout, where
    /// a CUDA `printf` goes, but a library keeps its caller's stdout clean). In validation mode
    /// they are logged even with an exception record, and the first built-in exception fails the
    /// launch (§4.3).
    pub fn settle(
        self,
        context: &DeviceContext,
        has_exception_record: bool,
    ) -> Result<LaunchReport, crate::LaunchError> {
        let validation = context.is_validation_mode();
        if context.has_log_callback() {
            if !has_exception_record || validation {
                for (index, e) in &self.first_exceptions {
                    context.log(LogLevel::Error, "EXCEPTION", &exception_message(*index, e));
                }
            }
        } else if !has_exception_record && !self.first_exceptions.is_empty() {
            eprint!("{}", builtin_exception_lines(&self.first_exceptions));
        }
        if validation {
            if let Some((index, e)) = self
                .first_exceptions
                .iter()
                .find(|(_, e)| !e.code.is_user())
            {
                return Err(crate::LaunchError::ValidationFailure {
                    index: *index,
                    exception: *e,
                });
            }
        }
        Ok(self)
    }
}

/// The message for one exception: `launch index [x, y, z]: <exception>`.
fn exception_message(index: [u32; 3], e: &Exception) -> String {
    format!("launch index {index:?}: {e}")
}

/// What the built-in exception program (guide §13.14) prints when a launch has no exception
/// record and its context no log callback: one line for each of the first five exceptions (by
/// launch index) of `first`.
///
/// ```
/// use oxray_core::{Exception, ExceptionCode};
/// let first = [([3, 0, 0], Exception::new(ExceptionCode(7), &[1, 2]))];
/// assert_eq!(
///     oxray_core::pipeline::builtin_exception_lines(&first),
///     "[oxray][EXCEPTION] launch index [3, 0, 0]: user exception (code 7, details [1, 2])\n"
/// );
/// ```
#[must_use]
pub fn builtin_exception_lines(first: &[([u32; 3], Exception)]) -> String {
    first
        .iter()
        .take(5)
        .map(|(index, e)| format!("[oxray][EXCEPTION] {}\n", exception_message(*index, e)))
        .collect()
}

#[cfg(test)]
mod launch_report_tests {
    use super::*;
    use crate::ExceptionCode;

    /// §13.14: the built-in exception program prints the first five exceptions, one line each.
    #[test]
    fn builtin_exception_lines_print_the_first_five_13_14() {
        let first: Vec<_> = (0..7u32)
            .map(|i| ([i, 1, 0], Exception::new(ExceptionCode(i as i32), &[i, 2])))
            .collect();
        let text = builtin_exception_lines(&first);
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 5, "{text}");
        assert_eq!(
            lines[3],
            "[oxray][EXCEPTION] launch index [3, 1, 0]: user exception (code 3, details [3, 2])"
        );
        let trace = [(
            [0, 0, 2],
            Exception::new(ExceptionCode::TRACE_DEPTH_EXCEEDED, &[]),
        )];
        assert_eq!(
            builtin_exception_lines(&trace),
            "[oxray][EXCEPTION] launch index [0, 0, 2]: trace depth exceeded (code -2)\n"
        );
        assert_eq!(builtin_exception_lines(&[]), "");
    }

    /// §4.3: in validation mode the first built-in exception fails the launch; user exceptions
    /// do not; without validation nothing fails.
    #[test]
    fn validation_mode_fails_launches_on_built_in_exceptions_4_3() {
        let user = ([1, 0, 0], Exception::new(ExceptionCode(5), &[]));
        let depth = (
            [2, 0, 0],
            Exception::new(ExceptionCode::TRACE_DEPTH_EXCEEDED, &[]),
        );
        let report = LaunchReport {
            exceptions: 2,
            first_exceptions: vec![user, depth],
            traces: 0,
        };
        let quiet = DeviceContext::new().log_callback(LogLevel::Error, |_, _, _| {});
        assert_eq!(report.clone().settle(&quiet, true), Ok(report.clone()));
        let strict = quiet.clone().validation_mode(true);
        assert_eq!(
            report.clone().settle(&strict, true),
            Err(crate::LaunchError::ValidationFailure {
                index: [2, 0, 0],
                exception: depth.1
            })
        );
        let only_user = LaunchReport {
            exceptions: 1,
            first_exceptions: vec![user],
            traces: 0,
        };
        assert_eq!(only_user.clone().settle(&strict, true), Ok(only_user));
    }
}
