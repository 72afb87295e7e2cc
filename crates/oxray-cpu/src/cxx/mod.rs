//! CUDA C++ programs on the CPU: the same modules that the CUDA backend compiles with NVRTC,
//! compiled by the host's C++ compiler against a CPU implementation of the device header
//! ([`DEVICE_HEADER_CPU`]) and run by this backend's pipeline.
//!
//! The host code is that of the CUDA backend: a [`CxxModule`] is made from source, program
//! groups take entries by name ([`CxxProgramGroup`]), a [`CxxPipeline`] links them with the
//! guide's options and the name of the launch-parameter variable, the SBT holds the groups'
//! headers and the user's data, and [`CxxPipeline::launch`] copies the parameters into the
//! variable and runs the launch on all cores. Programs read and write memory through addresses
//! in the parameters or SBT data; on the CPU those are host addresses, of [`HostBuffer`]s.
//! Programs trace the value of [`optix_handle`] for a CPU structure.
//!
//! A pipeline's modules are compiled together into one shared library (so, as on the GPU, they
//! must not define the same name twice), kept in a cache directory ([`cache_dir`]) under a hash
//! of the unit, the compiler and its flags, and loaded; a later pipeline of the same unit loads
//! the cached library without compiling. `$CXX` names the compiler (default `c++`).
//!
//! ```
//! use oxray_cpu::cxx::{CxxModule, CxxPipeline, CxxProgramGroup, HostBuffer};
//! use oxray_core::{DeviceContext, PipelineCompileOptions, PipelineLinkOptions, ShaderBindingTable, SbtRegion};
//!
//! let module = CxxModule::from_source(r#"
//!     #include <optix.h>
//!     struct Params { unsigned int* out; };
//!     extern "C" __constant__ Params params;
//!     extern "C" __global__ void __raygen__hello() {
//!         params.out[optixGetLaunchIndex().x] = 7u * optixGetLaunchIndex().x;
//!     }
//! "#);
//! let raygen = CxxProgramGroup::raygen(&module, "__raygen__hello")?;
//! let pipeline = CxxPipeline::new(
//!     &DeviceContext::default(),
//!     &PipelineCompileOptions::default(),
//!     &PipelineLinkOptions::default(),
//!     Some("params"),
//!     &[raygen.clone()],
//! )?;
//! let out = HostBuffer::<u32>::zeroed(16);
//! let sbt = ShaderBindingTable {
//!     raygen: SbtRegion::from_headers(&[raygen.pack_header()]),
//!     ..Default::default()
//! };
//! pipeline.launch_with(&out.device_ptr(), &sbt, 16, 1, 1)?;
//! assert_eq!(out.download()[3], 21);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod bridge;
mod buffer;
mod handles;
mod unit;

pub use bridge::{MISUSED_FUNCTIONS, PROGRAM_ERROR_CODE};
pub use buffer::HostBuffer;
pub use handles::optix_handle;
pub use unit::{cache_dir, DEVICE_HEADER_CPU};

use crate::pipeline::Pipeline;
use crate::program::{HitGroupDesc, Module, ProgramGroup, ProgramGroupKind, ProgramKind};
use bytemuck::Pod;
use oxray_core::sbt::{SbtHeader, ShaderBindingTable};
use oxray_core::{
    DeviceContext, LaunchError, LaunchReport, PipelineCompileOptions, PipelineError,
    PipelineLinkOptions, TraversableHandle,
};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use thiserror::Error;

/// Why CUDA C++ programs could not be compiled, loaded or launched on the CPU.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
#[non_exhaustive]
pub enum CxxError {
    /// The C++ compiler could not be run.
    #[error("cannot run the C++ compiler `{compiler}` ({reason}); install one or set $CXX")]
    NoCompiler {
        /// The command tried.
        compiler: String,
        /// What the system said.
        reason: String,
    },
    /// The unit did not compile: the compiler's log, and the GPU-only intrinsics it names.
    #[error("{}the programs do not compile for the CPU:\n{log}", gpu_only_note(.gpu_only))]
    Compile {
        /// The compiler's messages.
        log: String,
        /// GPU-only intrinsics the programs use (empty if none is the cause).
        gpu_only: Vec<String>,
    },
    /// The cache directory could not be written.
    #[error("cannot write the program cache at {path:?}: {reason}")]
    Cache {
        /// The path.
        path: PathBuf,
        /// What the system said.
        reason: String,
    },
    /// The compiled library could not be loaded.
    #[error("cannot load the compiled programs {path:?}: {reason}")]
    Load {
        /// The library.
        path: PathBuf,
        /// What the loader said.
        reason: String,
    },
    /// The pipeline's options or groups break a rule of the guide.
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
    /// The launch was refused.
    #[error(transparent)]
    Launch(#[from] LaunchError),
    /// The launch parameters do not fit the pipeline's parameter variable (guide §10).
    #[error("{given} bytes of launch parameters for `{name}`, which holds {declared}")]
    ParamsSize {
        /// The variable.
        name: String,
        /// Bytes given.
        given: usize,
        /// Bytes of the variable.
        declared: usize,
    },
    /// Launch parameters were given to a pipeline that names no parameter variable.
    #[error("launch parameters given, but the pipeline names no parameter variable")]
    NoParamsVariable,
}

fn gpu_only_note(names: &[String]) -> String {
    if names.is_empty() {
        String::new()
    } else {
        format!(
            "GPU-only intrinsics ({}) cannot run on the CPU backend; ",
            names.join(", ")
        )
    }
}

static NEXT_MODULE: AtomicU64 = AtomicU64::new(1);

/// What each launch of a C++ pipeline gives its programs: the loaded unit's entry points and
/// the traversables their handles name. (The launch parameters themselves are in the unit's
/// parameter variable.)
#[derive(Clone)]
pub struct CxxLaunch {
    loaded: Arc<unit::Loaded>,
    handles: Arc<Vec<(u64, TraversableHandle)>>,
}

impl CxxLaunch {
    pub(crate) fn entry(&self, module: u64, index: usize) -> Option<bridge::EntryFn> {
        self.loaded.entry(module, index)
    }

    pub(crate) fn handle(&self, value: u64) -> Option<&TraversableHandle> {
        self.handles
            .iter()
            .find(|(v, _)| *v == value)
            .map(|(_, h)| h)
    }
}

struct ModuleInner {
    uid: u64,
    source: String,
    entries: Vec<String>,
    module: Module<CxxLaunch>,
}

/// A module of CUDA C++ programs for the CPU (`OptixModule` made from source): entry points
/// named with the guide's prefixes, declared `extern "C" __global__ void __raygen__name()`
/// (callables: `extern "C" __device__ R __direct_callable__name(args…)`). It is compiled with
/// the pipelines that use it.
#[derive(Clone)]
#[doc(alias = "OptixModule")]
pub struct CxxModule {
    inner: Arc<ModuleInner>,
}

impl std::fmt::Debug for CxxModule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CxxModule")
            .field("entries", &self.inner.entries)
            .finish()
    }
}

impl CxxModule {
    /// A module of the given CUDA C++ source.
    pub fn from_source(source: impl Into<String>) -> CxxModule {
        let source = source.into();
        let uid = NEXT_MODULE.fetch_add(1, Ordering::Relaxed);
        let entries = oxray_core::source::entries(&source);
        let mut module = Module::new();
        for (i, name) in entries.iter().enumerate() {
            if let Some(kind) = unit::kind_of(name) {
                module
                    .programs
                    .insert(name.clone(), bridge::program(kind, uid, i));
            }
        }
        CxxModule {
            inner: Arc::new(ModuleInner {
                uid,
                source,
                entries,
                module,
            }),
        }
    }

    /// The source as given.
    #[must_use]
    pub fn source(&self) -> &str {
        &self.inner.source
    }

    /// Whether the source declares or defines the entry `name`.
    #[must_use]
    pub fn has_entry(&self, name: &str) -> bool {
        self.inner.entries.iter().any(|e| e == name)
    }

    pub(crate) fn uid(&self) -> u64 {
        self.inner.uid
    }

    pub(crate) fn entry_names(&self) -> impl Iterator<Item = &str> {
        self.inner.entries.iter().map(String::as_str)
    }
}

/// A program group of CUDA C++ programs for the CPU (`OptixProgramGroup`).
#[derive(Clone)]
#[doc(alias = "OptixProgramGroup")]
pub struct CxxProgramGroup {
    group: ProgramGroup<CxxLaunch>,
    modules: Vec<CxxModule>,
}

impl std::fmt::Debug for CxxProgramGroup {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CxxProgramGroup")
            .field("kind", &self.group.kind())
            .finish()
    }
}

/// The programs of a hit group: `(module, entry name)` or absent.
#[derive(Clone, Copy, Debug, Default)]
pub struct CxxHitGroupDesc<'a> {
    /// Closest-hit program.
    pub closest_hit: Option<(&'a CxxModule, &'a str)>,
    /// Any-hit program.
    pub any_hit: Option<(&'a CxxModule, &'a str)>,
    /// Intersection program (custom primitives).
    pub intersection: Option<(&'a CxxModule, &'a str)>,
}

fn check_kind(name: &str, kind: ProgramKind) -> Result<(), PipelineError> {
    if unit::kind_of(name) == Some(kind) {
        Ok(())
    } else {
        Err(PipelineError::UnknownEntry {
            name: name.to_string(),
            kind: kind.name(),
        })
    }
}

fn modules_of<'a>(
    entries: impl IntoIterator<Item = Option<(&'a CxxModule, &'a str)>>,
) -> Vec<CxxModule> {
    let mut out: Vec<CxxModule> = Vec::new();
    for (m, _) in entries.into_iter().flatten() {
        if !out.iter().any(|o| Arc::ptr_eq(&o.inner, &m.inner)) {
            out.push(m.clone());
        }
    }
    out
}

impl CxxProgramGroup {
    /// A ray-generation group.
    pub fn raygen(module: &CxxModule, entry: &str) -> Result<Self, PipelineError> {
        check_kind(entry, ProgramKind::RayGen)?;
        Ok(CxxProgramGroup {
            group: ProgramGroup::raygen(&module.inner.module, entry)?,
            modules: vec![module.clone()],
        })
    }

    /// A miss group; `None` makes a miss group that does nothing.
    pub fn miss(entry: Option<(&CxxModule, &str)>) -> Result<Self, PipelineError> {
        if let Some((_, n)) = entry {
            check_kind(n, ProgramKind::Miss)?;
        }
        Ok(CxxProgramGroup {
            group: ProgramGroup::miss(cpu_entry(entry))?,
            modules: modules_of([entry]),
        })
    }

    /// An exception group.
    pub fn exception(module: &CxxModule, entry: &str) -> Result<Self, PipelineError> {
        check_kind(entry, ProgramKind::Exception)?;
        Ok(CxxProgramGroup {
            group: ProgramGroup::exception(&module.inner.module, entry)?,
            modules: vec![module.clone()],
        })
    }

    /// A hit group.
    pub fn hit_group(desc: CxxHitGroupDesc<'_>) -> Result<Self, PipelineError> {
        for (e, k) in [
            (desc.closest_hit, ProgramKind::ClosestHit),
            (desc.any_hit, ProgramKind::AnyHit),
            (desc.intersection, ProgramKind::Intersection),
        ] {
            if let Some((_, n)) = e {
                check_kind(n, k)?;
            }
        }
        let group = ProgramGroup::hit_group(HitGroupDesc {
            closest_hit: cpu_entry(desc.closest_hit),
            any_hit: cpu_entry(desc.any_hit),
            intersection: cpu_entry(desc.intersection),
        })?;
        Ok(CxxProgramGroup {
            group,
            modules: modules_of([desc.closest_hit, desc.any_hit, desc.intersection]),
        })
    }

    /// A callables group: a direct and/or a continuation callable sharing one SBT record.
    pub fn callables(
        direct: Option<(&CxxModule, &str)>,
        continuation: Option<(&CxxModule, &str)>,
    ) -> Result<Self, PipelineError> {
        if let Some((_, n)) = direct {
            check_kind(n, ProgramKind::DirectCallable)?;
        }
        if let Some((_, n)) = continuation {
            check_kind(n, ProgramKind::ContinuationCallable)?;
        }
        Ok(CxxProgramGroup {
            group: ProgramGroup::callables(cpu_entry(direct), cpu_entry(continuation))?,
            modules: modules_of([direct, continuation]),
        })
    }

    /// The group's kind.
    #[must_use]
    pub fn kind(&self) -> ProgramGroupKind {
        self.group.kind()
    }

    /// The record header naming this group (`optixSbtRecordPackHeader`).
    #[doc(alias = "optixSbtRecordPackHeader")]
    #[must_use]
    pub fn pack_header(&self) -> SbtHeader {
        self.group.pack_header()
    }
}

fn cpu_entry<'a>(e: Option<(&'a CxxModule, &'a str)>) -> Option<(&'a Module<CxxLaunch>, &'a str)> {
    e.map(|(m, n)| (&m.inner.module, n))
}

/// A pipeline of CUDA C++ programs on the CPU (`OptixPipeline`): its modules compiled into one
/// shared library, its groups linked by the CPU pipeline.
#[doc(alias = "OptixPipeline")]
pub struct CxxPipeline {
    pipeline: Pipeline<CxxLaunch>,
    loaded: Arc<unit::Loaded>,
    params_name: Option<String>,
}

impl std::fmt::Debug for CxxPipeline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CxxPipeline")
            .field("params", &self.params_name)
            .finish()
    }
}

impl CxxPipeline {
    /// Compiles (or finds in the cache), loads and links a pipeline (`optixPipelineCreate`).
    /// `params_variable` is the guide's `pipelineLaunchParamsVariableName`: a variable of a
    /// module that each launch fills with the launch parameters.
    #[doc(alias = "optixPipelineCreate")]
    pub fn new(
        context: &DeviceContext,
        compile: &PipelineCompileOptions,
        link: &PipelineLinkOptions,
        params_variable: Option<&str>,
        groups: &[CxxProgramGroup],
    ) -> Result<CxxPipeline, CxxError> {
        let cpu_groups: Vec<ProgramGroup<CxxLaunch>> =
            groups.iter().map(|g| g.group.clone()).collect();
        // The options first: they are checked without compiling anything.
        let pipeline = Pipeline::new(context, compile, link, &cpu_groups)?;
        let mut modules: Vec<CxxModule> = Vec::new();
        for m in groups.iter().flat_map(|g| &g.modules) {
            if !modules.iter().any(|o| Arc::ptr_eq(&o.inner, &m.inner)) {
                modules.push(m.clone());
            }
        }
        let loaded = unit::load(&modules, params_variable)?;
        Ok(CxxPipeline {
            pipeline,
            loaded,
            params_name: params_variable.map(str::to_string),
        })
    }

    /// Sets the deepest traversable graph a trace may enter (`optixPipelineSetStackSize`).
    #[doc(alias = "optixPipelineSetStackSize")]
    pub fn set_max_traversable_graph_depth(&mut self, depth: u32) -> Result<(), CxxError> {
        Ok(self.pipeline.set_max_traversable_graph_depth(depth)?)
    }

    /// Launches `width * height * depth` ray-generation programs on all cores (`optixLaunch`):
    /// `params` are copied into the parameter variable first (guide §10); launches of pipelines
    /// of one compiled unit run one at a time.
    #[doc(alias = "optixLaunch")]
    pub fn launch(
        &self,
        params: &[u8],
        sbt: &ShaderBindingTable,
        width: u32,
        height: u32,
        depth: u32,
    ) -> Result<LaunchReport, CxxError> {
        let _guard = self
            .loaded
            .launch_lock
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        match (&self.params_name, self.loaded.params) {
            (Some(name), Some((addr, size))) => {
                if params.len() != size {
                    return Err(CxxError::ParamsSize {
                        name: name.clone(),
                        given: params.len(),
                        declared: size,
                    });
                }
                // SAFETY: `addr` is the variable's address in the loaded library, `size` its
                // size; no program of this library runs (the launch lock is held).
                unsafe { std::ptr::copy_nonoverlapping(params.as_ptr(), addr, size) };
            }
            (None, _) if !params.is_empty() => return Err(CxxError::NoParamsVariable),
            _ => {}
        }
        let launch = CxxLaunch {
            loaded: self.loaded.clone(),
            handles: handles::snapshot(),
        };
        Ok(self.pipeline.launch(&launch, sbt, width, height, depth)?)
    }

    /// [`launch`](Self::launch) with typed launch parameters.
    pub fn launch_with<P: Pod>(
        &self,
        params: &P,
        sbt: &ShaderBindingTable,
        width: u32,
        height: u32,
        depth: u32,
    ) -> Result<LaunchReport, CxxError> {
        self.launch(bytemuck::bytes_of(params), sbt, width, height, depth)
    }
}
