//! The value that unwinds a Rust program: an exception, or an any-hit's ignore or terminate.

use oxray_core::{Exception, ExceptionCode};

/// Why a program stopped early. Device functions that, in OptiX, never return
/// (`optixTrace` raising an exception, `optixThrowException`, `optixIgnoreIntersection`,
/// `optixTerminateRay`, a report whose any-hit terminated the ray, a callable that raised) give
/// an `Interrupt` instead. The call takes effect when it is made: the program's context records
/// it, and once the program returns the runtime honours it whatever the program returns (the
/// candidate is ignored, traversal ends, or the launch index ends with the exception and the
/// exception program runs); later device calls of the same program do nothing and give the
/// first interrupt back, since in OptiX they are never reached (guide §13.13, §13.14). Passing
/// it on with `?` or `return` is the idiomatic way to leave the program at once, so that no
/// code after the call runs. It can only be made by those functions, so a program cannot invent
/// one it is not allowed to raise.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[doc(alias = "optixTrace")]
#[doc(alias = "optixThrowException")]
#[doc(alias = "optixIgnoreIntersection")]
#[doc(alias = "optixTerminateRay")]
pub struct Interrupt(pub(crate) InterruptKind);

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum InterruptKind {
    /// An exception: the launch index ends and the exception program runs.
    Exception(Exception),
    /// `optixIgnoreIntersection` from an any-hit program.
    IgnoreIntersection,
    /// `optixTerminateRay` from an any-hit program (or an intersection program whose report
    /// was terminated).
    TerminateRay,
}

impl Interrupt {
    pub(crate) fn exception(code: ExceptionCode, details: &[u32]) -> Self {
        Interrupt(InterruptKind::Exception(Exception::new(code, details)))
    }

    /// The exception, if this interrupt is one.
    #[must_use]
    pub fn as_exception(&self) -> Option<&Exception> {
        match &self.0 {
            InterruptKind::Exception(e) => Some(e),
            _ => None,
        }
    }
}

/// What every program returns: `Ok(())`, or an [`Interrupt`] passed on from a device function
/// (the interrupt a program's device call recorded wins over what it returns).
pub type ProgramResult = Result<(), Interrupt>;
