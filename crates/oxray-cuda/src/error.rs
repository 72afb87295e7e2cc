//! Errors of the CUDA backend.

use thiserror::Error;

/// Why a CUDA operation failed. Nothing in this crate panics when CUDA is absent: every way the
/// driver, the device or the runtime compiler can be missing or fail is one of these.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
pub enum CudaError {
    /// The CUDA driver library (`libcuda.so` / `nvcuda.dll`) could not be loaded or initialised.
    #[error("no CUDA driver found ({0})")]
    NoDriver(String),
    /// The driver is there but reports no usable device (or not the one asked for).
    #[error("no CUDA device found ({0})")]
    NoDevice(String),
    /// The NVRTC runtime compiler library (`libnvrtc.so`) could not be loaded.
    #[error("no NVRTC library found ({0})")]
    NoNvrtc(String),
    /// NVRTC rejected the trace kernels or a pipeline; `log` is the compiler's log.
    #[error("NVRTC could not compile the CUDA C++ ({message}):\n{log}")]
    Compile {
        /// The NVRTC error.
        message: String,
        /// The compiler's log.
        log: String,
    },
    /// A driver call failed: loading the module, allocating, copying or launching.
    #[error("CUDA driver call failed while {during}: {message}")]
    Driver {
        /// What was being done.
        during: &'static str,
        /// The driver's error.
        message: String,
    },
    /// The GAS (or a GAS under the IAS) holds custom primitives: the batched query kernels
    /// trace triangles; intersection programs run in pipelines ([`CudaPipeline`](crate::CudaPipeline)).
    #[error("the CUDA backend's batched queries trace triangles; custom primitives need their intersection programs, which run in pipelines (CudaPipeline)")]
    CustomPrimitives,
    /// The GAS or the batch is too large for the device layout's 32-bit indices.
    #[error("too large for the CUDA backend: {0}")]
    TooLarge(String),
    /// A pipeline's options or program groups were refused (guide §6, §12).
    #[error(transparent)]
    Pipeline(#[from] oxray_core::PipelineError),
    /// A launch was refused before it ran: its size, or an SBT record (guide §7, §10, §12).
    #[error(transparent)]
    InvalidLaunch(#[from] oxray_core::LaunchError),
    /// The launch parameters do not fit the pipeline's parameter variable.
    #[error("launch parameters: {0}")]
    Launch(String),
    /// A device-built tree is deeper than the traversal stacks allow ([`Cuda`](crate::Cuda)
    /// then builds on the host).
    #[error("the device-built tree is {depth} levels deep; traversal supports {max}")]
    TreeTooDeep {
        /// Depth of the tree made.
        depth: u32,
        /// The deepest accepted.
        max: u32,
    },
    /// What the device's kernels wrote failed the host's checks (read back from device
    /// memory, as a loader checks bytes).
    #[error("device data failed its check: {0}")]
    DeviceData(String),
    /// A setting (an environment variable) has a value this crate does not know.
    #[error("{0}")]
    Config(String),
    /// Something this slice of the CUDA backend does not do yet.
    #[error("not supported on the CUDA backend yet: {0}")]
    Unsupported(&'static str),
    /// A batch's rays and outputs differ in length.
    #[error("{rays} rays but room for {outputs} results")]
    LengthMismatch {
        /// Rays in the batch.
        rays: usize,
        /// Results the output holds.
        outputs: usize,
    },
}

impl CudaError {
    /// Whether the error only says that this machine has no CUDA (no driver, no device, no
    /// NVRTC): the caller may fall back to the CPU backend or skip.
    #[must_use]
    pub fn is_unavailable(&self) -> bool {
        matches!(
            self,
            CudaError::NoDriver(_) | CudaError::NoDevice(_) | CudaError::NoNvrtc(_)
        )
    }
}

/// Wraps a driver error with what was being done.
pub(crate) fn driver(
    during: &'static str,
) -> impl FnOnce(cudarc::driver::DriverError) -> CudaError {
    move |e| CudaError::Driver {
        during,
        message: e.to_string(),
    }
}
