//! The CUDA context: the driver and NVRTC loaded at run time, one device, one stream, and the
//! trace kernels compiled for that device.

use crate::error::{driver, CudaError};
use cudarc::driver::{CudaFunction, CudaStream};
use cudarc::nvrtc::CompileOptions;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::{Arc, OnceLock};

/// The CUDA C++ source of the trace kernels, compiled at run time by NVRTC: the walks, the
/// box, triangle and sphere tests (`trace.cu`), then the curve intersector (`curve.cu`).
pub const KERNEL_SOURCE: &str = concat!(
    include_str!("kernels/trace.cu"),
    "\n",
    include_str!("kernels/curve.cu")
);

// The numeric contract of every backend's box and triangle tests, passed to the kernels as
// defines so that it is written down once.
pub(crate) use oxray_bvh::triangle::F32_TINY;
pub(crate) use oxray_core::ray::{ROBUST_FAR, TMAX_SLACK};

/// What the device is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DeviceInfo {
    /// Device ordinal.
    pub ordinal: usize,
    /// Marketing name, e.g. "NVIDIA H100 80GB HBM3".
    pub name: String,
    /// Compute capability (major, minor), e.g. (9, 0).
    pub compute_capability: (i32, i32),
    /// Streaming multiprocessors.
    pub multiprocessors: i32,
    /// Device memory in bytes.
    pub total_memory: usize,
    /// Driver version, as the driver reports it (e.g. 13000 for CUDA 13.0).
    pub driver_version: i32,
    /// NVRTC version (major, minor).
    pub nvrtc_version: (i32, i32),
}

/// Resources of one compiled trace kernel, as the driver reports them.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct KernelInfo {
    /// Entry name, e.g. `oxray_closest_bvh4`.
    pub name: &'static str,
    /// Registers per thread.
    pub registers: i32,
    /// Local memory per thread in bytes (the traversal stack lives there).
    pub local_bytes: i32,
}

/// The compiled trace kernels.
#[derive(Debug)]
pub(crate) struct Kernels {
    pub closest_bvh4: CudaFunction,
    pub occluded_bvh4: CudaFunction,
    pub closest_bvh2: CudaFunction,
    pub occluded_bvh2: CudaFunction,
    pub closest_ias: CudaFunction,
    pub occluded_ias: CudaFunction,
    pub closest_spheres: CudaFunction,
    pub occluded_spheres: CudaFunction,
    pub closest_curves: CudaFunction,
    pub occluded_curves: CudaFunction,
    /// Copies a pipeline launch's counts into mapped host memory (`CudaPipeline::launch`).
    pub launch_counts: CudaFunction,
}

/// A CUDA device ready to trace: driver and NVRTC loaded, a context and stream on the device,
/// and the trace kernels compiled (by NVRTC, for the device's architecture).
///
/// Cloning is cheap (the clones share the context).
///
/// ```no_run
/// use oxray_cuda::CudaContext;
/// match CudaContext::new() {
///     Ok(ctx) => println!("tracing on {}", ctx.device().name),
///     Err(e) if e.is_unavailable() => println!("no GPU here ({e}); using the CPU backend"),
///     Err(e) => return Err(e.into()),
/// }
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug)]
pub struct CudaContext {
    pub(crate) stream: Arc<CudaStream>,
    pub(crate) kernels: Arc<Kernels>,
    /// The GAS builder's kernels, compiled on the first device build.
    build: Arc<OnceLock<Result<crate::device_build::BuildKernels, CudaError>>>,
    /// The simulation queries' kernels, compiled on first use.
    simulation: Arc<OnceLock<Result<crate::simulation::SimulationKernels, CudaError>>>,
    info: DeviceInfo,
}

/// Runs a call into a library loaded at run time, turning a panic (a missing symbol in an old
/// library) into an error.
pub(crate) fn guarded<T>(
    during: &'static str,
    f: impl FnOnce() -> Result<T, cudarc::driver::DriverError>,
) -> Result<T, CudaError> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(r) => r.map_err(driver(during)),
        Err(p) => Err(CudaError::Driver {
            during,
            message: panic_message(&p),
        }),
    }
}

fn panic_message(p: &Box<dyn std::any::Any + Send>) -> String {
    p.downcast_ref::<String>()
        .cloned()
        .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_else(|| "the CUDA library panicked".to_string())
}

impl CudaContext {
    /// Opens device 0 and compiles the trace kernels.
    pub fn new() -> Result<CudaContext, CudaError> {
        CudaContext::with_device(0)
    }

    /// Opens device `ordinal` and compiles the trace kernels. Fails with
    /// [`CudaError::NoDriver`], [`CudaError::NoDevice`] or [`CudaError::NoNvrtc`] where this
    /// machine has no CUDA, never panicking.
    pub fn with_device(ordinal: usize) -> Result<CudaContext, CudaError> {
        // SAFETY: only tries to open the library by its usual names (dlopen); no symbol of it
        // is called.
        if !unsafe { cudarc::driver::sys::is_culib_present() } {
            return Err(CudaError::NoDriver(
                "libcuda could not be loaded; is the NVIDIA driver installed?".into(),
            ));
        }
        // SAFETY: as above, for NVRTC.
        if !unsafe { cudarc::nvrtc::sys::is_culib_present() } {
            return Err(CudaError::NoNvrtc(
                "libnvrtc could not be loaded; add the CUDA toolkit's lib directory to \
                 LD_LIBRARY_PATH"
                    .into(),
            ));
        }
        guarded("initialising the driver", cudarc::driver::result::init).map_err(|e| match e {
            CudaError::Driver { message, .. } if message.contains("NO_DEVICE") => {
                CudaError::NoDevice(message)
            }
            CudaError::Driver { message, .. } => CudaError::NoDriver(message),
            e => e,
        })?;
        let count = guarded(
            "counting devices",
            cudarc::driver::CudaContext::device_count,
        )?;
        if count <= 0 || ordinal >= count as usize {
            return Err(CudaError::NoDevice(format!(
                "asked for device {ordinal}, the driver reports {count}"
            )));
        }
        let ctx = guarded("creating a context", || {
            cudarc::driver::CudaContext::new(ordinal)
        })?;
        let name = guarded("reading the device name", || ctx.name())?;
        let cc = guarded("reading the compute capability", || {
            ctx.compute_capability()
        })?;
        let total_memory = guarded("reading the memory size", || ctx.total_mem())?;
        let multiprocessors = guarded("reading the multiprocessor count", || {
            ctx.attribute(
                cudarc::driver::sys::CUdevice_attribute::CU_DEVICE_ATTRIBUTE_MULTIPROCESSOR_COUNT,
            )
        })?;
        let driver_version = guarded("reading the driver version", || {
            let mut v = 0;
            // SAFETY: writes one int through a valid pointer; the driver is initialised.
            unsafe { cudarc::driver::sys::cuDriverGetVersion(&mut v) }.result()?;
            Ok(v)
        })?;
        let nvrtc_version = catch_unwind(|| {
            let (mut major, mut minor) = (0, 0);
            // SAFETY: writes two ints through valid pointers; the library is loaded.
            unsafe { cudarc::nvrtc::sys::nvrtcVersion(&mut major, &mut minor) };
            (major, minor)
        })
        .map_err(|p| CudaError::NoNvrtc(panic_message(&p)))?;

        let ptx = compile(cc)?;
        let module = guarded("loading the trace module", || ctx.load_module(ptx))?;
        let load = |name: &'static str| guarded("loading a kernel", || module.load_function(name));
        let kernels = Kernels {
            closest_bvh4: load("oxray_closest_bvh4")?,
            occluded_bvh4: load("oxray_occluded_bvh4")?,
            closest_bvh2: load("oxray_closest_bvh2")?,
            occluded_bvh2: load("oxray_occluded_bvh2")?,
            closest_ias: load("oxray_closest_ias")?,
            occluded_ias: load("oxray_occluded_ias")?,
            closest_spheres: load("oxray_closest_spheres")?,
            occluded_spheres: load("oxray_occluded_spheres")?,
            closest_curves: load("oxray_closest_curves")?,
            occluded_curves: load("oxray_occluded_curves")?,
            launch_counts: load("oxray_launch_counts")?,
        };
        let stream = guarded("creating a stream", || ctx.new_stream())?;
        Ok(CudaContext {
            stream,
            kernels: Arc::new(kernels),
            build: Arc::new(OnceLock::new()),
            simulation: Arc::new(OnceLock::new()),
            info: DeviceInfo {
                ordinal,
                name,
                compute_capability: cc,
                multiprocessors,
                total_memory,
                driver_version,
                nvrtc_version,
            },
        })
    }

    /// Whether two handles share one context (device memory of one is valid in the other).
    #[must_use]
    pub fn same_context(&self, other: &CudaContext) -> bool {
        Arc::ptr_eq(&self.kernels, &other.kernels)
    }

    /// The device.
    #[must_use]
    pub fn device(&self) -> &DeviceInfo {
        &self.info
    }

    /// Registers and local memory of each trace kernel.
    pub fn kernel_info(&self) -> Result<Vec<KernelInfo>, CudaError> {
        let k = &self.kernels;
        [
            ("oxray_closest_bvh4", &k.closest_bvh4),
            ("oxray_occluded_bvh4", &k.occluded_bvh4),
            ("oxray_closest_bvh2", &k.closest_bvh2),
            ("oxray_occluded_bvh2", &k.occluded_bvh2),
            ("oxray_closest_ias", &k.closest_ias),
            ("oxray_occluded_ias", &k.occluded_ias),
            ("oxray_closest_spheres", &k.closest_spheres),
            ("oxray_occluded_spheres", &k.occluded_spheres),
            ("oxray_closest_curves", &k.closest_curves),
            ("oxray_occluded_curves", &k.occluded_curves),
        ]
        .into_iter()
        .map(|(name, f)| {
            Ok(KernelInfo {
                name,
                registers: f.num_regs().map_err(driver("reading kernel attributes"))?,
                local_bytes: f
                    .local_size_bytes()
                    .map_err(driver("reading kernel attributes"))?,
            })
        })
        .collect()
    }

    /// The GAS builder's kernels, compiled by NVRTC on first use (a failure is kept and
    /// returned again).
    pub(crate) fn build_kernels(&self) -> Result<&crate::device_build::BuildKernels, CudaError> {
        self.build
            .get_or_init(|| crate::device_build::BuildKernels::load(self))
            .as_ref()
            .map_err(Clone::clone)
    }

    /// The simulation queries' kernels, compiled by NVRTC on first use (a failure is kept and
    /// returned again).
    pub(crate) fn simulation_kernels(
        &self,
    ) -> Result<&crate::simulation::SimulationKernels, CudaError> {
        self.simulation
            .get_or_init(|| crate::simulation::SimulationKernels::load(self))
            .as_ref()
            .map_err(Clone::clone)
    }

    /// Waits until all work queued on the context's stream is done.
    pub fn synchronize(&self) -> Result<(), CudaError> {
        self.stream.synchronize().map_err(driver("synchronizing"))
    }
}

/// The NVRTC options of the trace kernels for a device of compute capability `cc`: the
/// device's virtual architecture (the driver JIT-compiles the PTX for it), and IEEE arithmetic
/// without FMA contraction so that results are bit-identical to the CPU backend's.
pub(crate) fn compile_options(cc: (i32, i32)) -> Vec<String> {
    vec![
        format!("--gpu-architecture=compute_{}{}", cc.0, cc.1),
        "--fmad=false".into(),
        "--ftz=false".into(),
        "--prec-div=true".into(),
        "--prec-sqrt=true".into(),
        "--std=c++17".into(),
        format!("-DOXRAY_ROBUST_FAR_BITS={:#010x}", ROBUST_FAR.to_bits()),
        format!("-DOXRAY_TMAX_SLACK_BITS={:#010x}", TMAX_SLACK.to_bits()),
        format!("-DOXRAY_F32_TINY_BITS={:#010x}", F32_TINY.to_bits()),
        format!("-DOXRAY_STACK_SIZE={}", oxray_bvh::TRAVERSAL_STACK_SIZE),
    ]
}

/// Compiles the trace kernels to PTX with NVRTC.
fn compile(cc: (i32, i32)) -> Result<cudarc::nvrtc::Ptx, CudaError> {
    nvrtc_compile(KERNEL_SOURCE, compile_options(cc), "oxray_trace.cu")
}

/// The PTX of the trace kernels ([`KERNEL_SOURCE`]) for a device of compute capability `cc`,
/// compiled with NVRTC exactly as a [`CudaContext`] compiles them (no GPU needed): for reading
/// the machine code with `ptxas` (`scripts/pipeline-sass.sh`).
///
/// ```no_run
/// let ptx = oxray_cuda::trace_kernels_ptx((9, 0))?;
/// assert!(ptx.contains(".entry oxray_closest_bvh2"));
/// # Ok::<(), oxray_cuda::CudaError>(())
/// ```
pub fn trace_kernels_ptx(cc: (i32, i32)) -> Result<String, CudaError> {
    compile(cc).map(|p| p.to_src())
}

/// NVRTC's version, `major.minor`, if the library can be loaded.
pub(crate) fn nvrtc_version() -> Option<String> {
    // SAFETY: only tries to open the library by its usual names (dlopen).
    if !unsafe { cudarc::nvrtc::sys::is_culib_present() } {
        return None;
    }
    let (r, major, minor) = catch_unwind(|| {
        let (mut major, mut minor) = (0, 0);
        // SAFETY: the library is present; the function writes two integers.
        let r = unsafe { cudarc::nvrtc::sys::nvrtcVersion(&mut major, &mut minor) };
        (r, major, minor)
    })
    .ok()?;
    (r == cudarc::nvrtc::sys::nvrtcResult::NVRTC_SUCCESS).then(|| format!("{major}.{minor}"))
}

/// Compiles CUDA C++ to PTX with NVRTC, turning a missing library or a compile error into a
/// [`CudaError`] (with NVRTC's log).
pub(crate) fn nvrtc_compile(
    source: &str,
    options: Vec<String>,
    name: &str,
) -> Result<cudarc::nvrtc::Ptx, CudaError> {
    // SAFETY: only tries to open the library by its usual names (dlopen).
    if !unsafe { cudarc::nvrtc::sys::is_culib_present() } {
        return Err(CudaError::NoNvrtc(
            "libnvrtc could not be loaded; add the CUDA toolkit's lib directory to \
             LD_LIBRARY_PATH"
                .into(),
        ));
    }
    let opts = CompileOptions {
        options,
        name: Some(name.into()),
        ..Default::default()
    };
    let result = catch_unwind(|| cudarc::nvrtc::compile_ptx_with_opts(source, opts))
        .map_err(|p| CudaError::NoNvrtc(panic_message(&p)))?;
    result.map_err(|e| match e {
        cudarc::nvrtc::CompileError::CompileError { nvrtc, log, .. } => CudaError::Compile {
            message: format!("{nvrtc:?}"),
            log: log.to_string_lossy().into_owned(),
        },
        other => CudaError::Compile {
            message: format!("{other:?}"),
            log: String::new(),
        },
    })
}

/// For the NVRTC compile tests: the PTX `compile` makes, or `None` (with a message) where
/// libnvrtc cannot be loaded, which `OXRAY_REQUIRE_NVRTC` turns into a failure (CI sets it).
#[cfg(test)]
pub(crate) fn ptx_or_skip(
    compile: impl FnOnce() -> Result<cudarc::nvrtc::Ptx, CudaError>,
) -> Option<String> {
    // SAFETY: only tries to open the library by its usual names (dlopen).
    if !unsafe { cudarc::nvrtc::sys::is_culib_present() } {
        assert!(
            std::env::var_os("OXRAY_REQUIRE_NVRTC").is_none(),
            "OXRAY_REQUIRE_NVRTC is set but libnvrtc cannot be loaded"
        );
        println!("skipping: libnvrtc not found (set LD_LIBRARY_PATH to compile the kernels)");
        return None;
    }
    match compile() {
        Ok(p) => Some(p.to_src()),
        Err(e) => panic!("{e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constants_match_the_cpu_backend() {
        // The constants the kernels are compiled with are the numeric contract every backend keeps.
        assert_eq!(TMAX_SLACK.to_bits(), 0x3f80_0200);
        assert_eq!(F32_TINY, 2f32.powi(-96));
        const { assert!(ROBUST_FAR > 1.0 && ROBUST_FAR < 1.0 + 4.0 * f32::EPSILON) };
    }

    #[test]
    fn options_name_the_device_architecture_and_disable_fma() {
        let o = compile_options((9, 0));
        assert!(o.contains(&"--gpu-architecture=compute_90".to_string()));
        assert!(o.contains(&"--fmad=false".to_string()));
        assert!(o.iter().any(|s| s.starts_with("-DOXRAY_STACK_SIZE=")));
    }

    #[test]
    fn the_kernels_compile_with_nvrtc_where_it_is_present() {
        let Some(ptx) = ptx_or_skip(|| compile((9, 0))) else {
            return;
        };
        for entry in [
            "oxray_closest_bvh4",
            "oxray_occluded_bvh4",
            "oxray_closest_bvh2",
            "oxray_occluded_bvh2",
            "oxray_closest_ias",
            "oxray_occluded_ias",
            "oxray_closest_spheres",
            "oxray_occluded_spheres",
            "oxray_closest_curves",
            "oxray_occluded_curves",
            "oxray_launch_counts",
        ] {
            assert!(ptx.contains(&format!(".entry {entry}")), "{entry} missing");
        }
    }

    #[test]
    fn no_cuda_is_an_error_not_a_panic() {
        // On a machine with CUDA this opens the device; without, it must fail cleanly.
        match CudaContext::new() {
            Ok(ctx) => assert!(!ctx.device().name.is_empty()),
            Err(e) => assert!(
                e.is_unavailable() || matches!(e, CudaError::Driver { .. }),
                "{e}"
            ),
        }
    }
}
