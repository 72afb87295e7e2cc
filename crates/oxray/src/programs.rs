//! Programs in CUDA C++ through the device-neutral API: the same host code on every device.
//!
//! A module is created from source by the device that will run it; program groups, pipelines,
//! the SBT, launch parameters and launches are the same calls on both backends. The CUDA device
//! compiles each pipeline with NVRTC into one kernel (`oxray::cuda::CudaPipeline`); the CPU
//! device compiles it with the host's C++ compiler against a CPU implementation of the same
//! device header and runs it on all cores (`oxray::cpu::cxx::CxxPipeline`). Programs address
//! memory through [`Buffer::device_ptr`] and trace [`Gas::optix_handle`] /
//! [`Ias::optix_handle`] values.
//!
//! ```no_run
//! use oxray::programs::{HitGroupDesc, ProgramGroup};
//! use oxray::{Device, ModuleSource, PipelineCompileOptions, PipelineLinkOptions, SbtRegion, ShaderBindingTable};
//!
//! let device = Device::best(); // CUDA where there is a GPU, else the CPU
//! let module = device.create_module(ModuleSource::CudaCpp(r#"
//!     #include <optix.h>
//!     struct Params { unsigned int* out; };
//!     extern "C" __constant__ Params params;
//!     extern "C" __global__ void __raygen__main() {
//!         params.out[optixGetLaunchIndex().x] = optixGetLaunchIndex().x * 2u;
//!     }
//! "#))?;
//! let raygen = ProgramGroup::raygen(&module, "__raygen__main")?;
//! let pipeline = device.create_pipeline(
//!     &PipelineCompileOptions::default(),
//!     &PipelineLinkOptions::default(),
//!     Some("params"),
//!     &[raygen.clone()],
//! )?;
//! let out = device.create_buffer::<u32>(8)?;
//! let sbt = ShaderBindingTable {
//!     raygen: SbtRegion::from_headers(&[raygen.pack_header()]),
//!     ..Default::default()
//! };
//! pipeline.launch_with(&out.device_ptr(), &sbt, 8, 1, 1)?;
//! assert_eq!(out.download()?[3], 6);
//! # Ok::<(), oxray::ProgramError>(())
//! ```

use crate::accel::{Gas, GasRepr, Ias, IasRepr};
use crate::device::{Device, DeviceRepr};
use bytemuck::Pod;
use oxray_core::sbt::{SbtHeader, ShaderBindingTable};
use oxray_core::{LaunchReport, PipelineCompileOptions, PipelineError, PipelineLinkOptions};
use oxray_cpu::cxx::{
    CxxError, CxxHitGroupDesc, CxxModule, CxxPipeline, CxxProgramGroup, HostBuffer,
};
use thiserror::Error;

#[cfg(feature = "cuda")]
use oxray_cuda::{CudaBuffer, CudaHitGroupDesc, CudaModule, CudaPipeline, CudaProgramGroup};

/// The source of a module of programs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum ModuleSource<'a> {
    /// OptiX-style CUDA C++ programs (`extern "C" __global__ void __raygen__name()`, …) using
    /// the guide's device functions (the device header of each backend).
    CudaCpp(&'a str),
}

/// Why a module, group, pipeline, buffer or launch of programs failed.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
#[non_exhaustive]
pub enum ProgramError {
    /// A rule of the guide about modules, groups or pipelines.
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
    /// A launch was refused or failed (bad SBT records, sizes, validation mode), on any device.
    #[error(transparent)]
    Launch(#[from] oxray_core::LaunchError),
    /// The CPU backend refused or failed (compiler, cache, loading, launch).
    #[error(transparent)]
    Cpu(#[from] CxxError),
    /// The CUDA backend refused or failed.
    #[cfg(feature = "cuda")]
    #[error(transparent)]
    Cuda(#[from] oxray_cuda::CudaError),
    /// Objects of different devices were combined (a group of a CPU module in a CUDA pipeline,
    /// say).
    #[error("program objects of different devices: {0}")]
    MixedDevices(&'static str),
    /// The backend does not have this yet.
    #[error("{0}")]
    Unsupported(String),
}

/// A module of programs (`OptixModule`), for the device that created it.
#[derive(Clone, Debug)]
#[doc(alias = "OptixModule")]
pub struct Module(ModuleRepr);

#[derive(Clone, Debug)]
enum ModuleRepr {
    Cpu(CxxModule),
    #[cfg(feature = "cuda")]
    Cuda(CudaModule),
}

impl Module {
    /// Whether the source declares or defines the entry `name`.
    #[must_use]
    pub fn has_entry(&self, name: &str) -> bool {
        match &self.0 {
            ModuleRepr::Cpu(m) => m.has_entry(name),
            #[cfg(feature = "cuda")]
            ModuleRepr::Cuda(m) => m.has_entry(name),
        }
    }

    /// The CPU module, on a CPU device.
    #[must_use]
    pub fn as_cpu(&self) -> Option<&CxxModule> {
        match &self.0 {
            ModuleRepr::Cpu(m) => Some(m),
            #[cfg(feature = "cuda")]
            _ => None,
        }
    }

    /// The CUDA module, on a CUDA device.
    #[cfg(feature = "cuda")]
    #[must_use]
    pub fn as_cuda(&self) -> Option<&CudaModule> {
        match &self.0 {
            ModuleRepr::Cuda(m) => Some(m),
            _ => None,
        }
    }
}

/// A program group (`OptixProgramGroup`).
#[derive(Clone, Debug)]
#[doc(alias = "OptixProgramGroup")]
pub struct ProgramGroup(GroupRepr);

#[derive(Clone, Debug)]
enum GroupRepr {
    Cpu(CxxProgramGroup),
    #[cfg(feature = "cuda")]
    Cuda(CudaProgramGroup),
}

/// The programs of a hit group: `(module, entry name)` or absent.
#[derive(Clone, Copy, Debug, Default)]
pub struct HitGroupDesc<'a> {
    /// Closest-hit program.
    pub closest_hit: Option<(&'a Module, &'a str)>,
    /// Any-hit program.
    pub any_hit: Option<(&'a Module, &'a str)>,
    /// Intersection program (custom primitives).
    pub intersection: Option<(&'a Module, &'a str)>,
}

/// The device of a set of entries: all on the CPU, all on CUDA (`Err` if mixed), or none.
enum Side<'a> {
    None,
    Cpu(Vec<Option<(&'a CxxModule, &'a str)>>),
    #[cfg(feature = "cuda")]
    Cuda(Vec<Option<(&'a CudaModule, &'a str)>>),
}

fn side<'a>(entries: &[Option<(&'a Module, &'a str)>]) -> Result<Side<'a>, ProgramError> {
    let mut cpu = 0;
    let mut cuda = 0;
    for (m, _) in entries.iter().flatten() {
        match &m.0 {
            ModuleRepr::Cpu(_) => cpu += 1,
            #[cfg(feature = "cuda")]
            ModuleRepr::Cuda(_) => cuda += 1,
        }
    }
    if cpu > 0 && cuda > 0 {
        return Err(ProgramError::MixedDevices(
            "modules of a CPU and a CUDA device in one group",
        ));
    }
    if cpu == 0 && cuda == 0 {
        return Ok(Side::None);
    }
    if cpu > 0 {
        return Ok(Side::Cpu(
            entries
                .iter()
                .map(|e| e.and_then(|(m, n)| m.as_cpu().map(|m| (m, n))))
                .collect(),
        ));
    }
    #[cfg(feature = "cuda")]
    {
        Ok(Side::Cuda(
            entries
                .iter()
                .map(|e| e.and_then(|(m, n)| m.as_cuda().map(|m| (m, n))))
                .collect(),
        ))
    }
    #[cfg(not(feature = "cuda"))]
    unreachable!("without the cuda feature every module is a CPU module")
}

impl ProgramGroup {
    /// A ray-generation group.
    pub fn raygen(module: &Module, entry: &str) -> Result<Self, ProgramError> {
        Ok(ProgramGroup(match &module.0 {
            ModuleRepr::Cpu(m) => GroupRepr::Cpu(CxxProgramGroup::raygen(m, entry)?),
            #[cfg(feature = "cuda")]
            ModuleRepr::Cuda(m) => GroupRepr::Cuda(CudaProgramGroup::raygen(m, entry)?),
        }))
    }

    /// A miss group of `entry`. (A miss group without a program is device-specific:
    /// [`miss_none`](Self::miss_none).)
    pub fn miss(module: &Module, entry: &str) -> Result<Self, ProgramError> {
        Ok(ProgramGroup(match &module.0 {
            ModuleRepr::Cpu(m) => GroupRepr::Cpu(CxxProgramGroup::miss(Some((m, entry)))?),
            #[cfg(feature = "cuda")]
            ModuleRepr::Cuda(m) => GroupRepr::Cuda(CudaProgramGroup::miss(Some((m, entry)))?),
        }))
    }

    /// A miss group that does nothing, for the device of `device`.
    pub fn miss_none(device: &Device) -> Result<Self, ProgramError> {
        Ok(ProgramGroup(match &device.repr {
            DeviceRepr::Cpu(_) => GroupRepr::Cpu(CxxProgramGroup::miss(None)?),
            #[cfg(feature = "cuda")]
            DeviceRepr::Cuda(_) => GroupRepr::Cuda(CudaProgramGroup::miss(None)?),
        }))
    }

    /// An exception group.
    pub fn exception(module: &Module, entry: &str) -> Result<Self, ProgramError> {
        Ok(ProgramGroup(match &module.0 {
            ModuleRepr::Cpu(m) => GroupRepr::Cpu(CxxProgramGroup::exception(m, entry)?),
            #[cfg(feature = "cuda")]
            ModuleRepr::Cuda(m) => GroupRepr::Cuda(CudaProgramGroup::exception(m, entry)?),
        }))
    }

    /// A hit group. At least one program must be given (its module says the device).
    pub fn hit_group(desc: HitGroupDesc<'_>) -> Result<Self, ProgramError> {
        let entries = [desc.closest_hit, desc.any_hit, desc.intersection];
        Ok(ProgramGroup(match side(&entries)? {
            Side::None => {
                return Err(ProgramError::Unsupported(
                    "a hit group without programs does not say its device: give one program".into(),
                ))
            }
            Side::Cpu(e) => GroupRepr::Cpu(CxxProgramGroup::hit_group(CxxHitGroupDesc {
                closest_hit: e[0],
                any_hit: e[1],
                intersection: e[2],
            })?),
            #[cfg(feature = "cuda")]
            Side::Cuda(e) => GroupRepr::Cuda(CudaProgramGroup::hit_group(CudaHitGroupDesc {
                closest_hit: e[0],
                any_hit: e[1],
                intersection: e[2],
            })?),
        }))
    }

    /// A callables group: a direct and/or a continuation callable sharing one SBT record.
    pub fn callables(
        direct: Option<(&Module, &str)>,
        continuation: Option<(&Module, &str)>,
    ) -> Result<Self, ProgramError> {
        Ok(ProgramGroup(match side(&[direct, continuation])? {
            Side::None => {
                return Err(ProgramError::Unsupported(
                    "a callables group needs a direct or a continuation callable".into(),
                ))
            }
            Side::Cpu(e) => GroupRepr::Cpu(CxxProgramGroup::callables(e[0], e[1])?),
            #[cfg(feature = "cuda")]
            Side::Cuda(e) => GroupRepr::Cuda(CudaProgramGroup::callables(e[0], e[1])?),
        }))
    }

    /// The record header naming this group (`optixSbtRecordPackHeader`).
    #[doc(alias = "optixSbtRecordPackHeader")]
    #[must_use]
    pub fn pack_header(&self) -> SbtHeader {
        match &self.0 {
            GroupRepr::Cpu(g) => g.pack_header(),
            #[cfg(feature = "cuda")]
            GroupRepr::Cuda(g) => g.pack_header(),
        }
    }
}

/// A pipeline of program groups (`OptixPipeline`).
#[derive(Debug)]
#[doc(alias = "OptixPipeline")]
pub struct Pipeline(PipelineRepr);

#[derive(Debug)]
enum PipelineRepr {
    Cpu(CxxPipeline),
    #[cfg(feature = "cuda")]
    Cuda(Box<CudaPipeline>),
}

impl Pipeline {
    /// Launches `width * height * depth` ray-generation programs (`optixLaunch`); `params` are
    /// copied into the pipeline's launch-parameter variable first (guide §10).
    #[doc(alias = "optixLaunch")]
    pub fn launch(
        &self,
        params: &[u8],
        sbt: &ShaderBindingTable,
        width: u32,
        height: u32,
        depth: u32,
    ) -> Result<LaunchReport, ProgramError> {
        // The guide's launch errors are the same on every device.
        match &self.0 {
            PipelineRepr::Cpu(p) => {
                p.launch(params, sbt, width, height, depth)
                    .map_err(|e| match e {
                        CxxError::Launch(l) => ProgramError::Launch(l),
                        CxxError::Pipeline(p) => ProgramError::Pipeline(p),
                        other => ProgramError::Cpu(other),
                    })
            }
            #[cfg(feature = "cuda")]
            PipelineRepr::Cuda(p) => {
                p.launch(params, sbt, width, height, depth)
                    .map_err(|e| match e {
                        oxray_cuda::CudaError::InvalidLaunch(l) => ProgramError::Launch(l),
                        oxray_cuda::CudaError::Pipeline(p) => ProgramError::Pipeline(p),
                        other => ProgramError::Cuda(other),
                    })
            }
        }
    }

    /// Sets the deepest traversable graph a trace may enter (the last argument of
    /// `optixPipelineSetStackSize`; 1 to 31). A trace into a deeper graph raises
    /// `TRAVERSAL_DEPTH_EXCEEDED`. The defaults differ: 31 on the CPU, where depth costs
    /// nothing, and 2 on CUDA (one level of instances over geometry, OptiX's default), where the
    /// stack reserved for every resident thread grows with it.
    #[doc(alias = "optixPipelineSetStackSize")]
    pub fn set_max_traversable_graph_depth(&mut self, depth: u32) -> Result<(), ProgramError> {
        match &mut self.0 {
            PipelineRepr::Cpu(p) => p.set_max_traversable_graph_depth(depth)?,
            #[cfg(feature = "cuda")]
            PipelineRepr::Cuda(p) => p.set_max_traversable_graph_depth(depth)?,
        }
        Ok(())
    }

    /// [`launch`](Self::launch) with typed launch parameters.
    pub fn launch_with<P: Pod>(
        &self,
        params: &P,
        sbt: &ShaderBindingTable,
        width: u32,
        height: u32,
        depth: u32,
    ) -> Result<LaunchReport, ProgramError> {
        self.launch(bytemuck::bytes_of(params), sbt, width, height, depth)
    }

    /// The CPU pipeline, on a CPU device.
    #[must_use]
    pub fn as_cpu(&self) -> Option<&CxxPipeline> {
        match &self.0 {
            PipelineRepr::Cpu(p) => Some(p),
            #[cfg(feature = "cuda")]
            _ => None,
        }
    }

    /// The CUDA pipeline, on a CUDA device.
    #[cfg(feature = "cuda")]
    #[must_use]
    pub fn as_cuda(&self) -> Option<&CudaPipeline> {
        match &self.0 {
            PipelineRepr::Cuda(p) => Some(p),
            _ => None,
        }
    }
}

/// Memory that programs read and write through its address: host memory on the CPU device,
/// device memory on a CUDA device.
pub struct Buffer<T: Pod>(BufferRepr<T>);

enum BufferRepr<T: Pod> {
    Cpu(HostBuffer<T>),
    #[cfg(feature = "cuda")]
    Cuda(CudaBuffer<T>),
}

impl<T: Pod> std::fmt::Debug for Buffer<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.0 {
            BufferRepr::Cpu(b) => b.fmt(f),
            #[cfg(feature = "cuda")]
            BufferRepr::Cuda(b) => b.fmt(f),
        }
    }
}

impl<T: Pod> Buffer<T> {
    /// Replaces the contents with `data`, which must have the buffer's length.
    pub fn write(&mut self, data: &[T]) -> Result<(), ProgramError> {
        if data.len() != self.len() {
            return Err(ProgramError::Unsupported(format!(
                "{} values written to a buffer of {}",
                data.len(),
                self.len()
            )));
        }
        match &mut self.0 {
            BufferRepr::Cpu(b) => {
                b.write(data);
            }
            #[cfg(feature = "cuda")]
            BufferRepr::Cuda(b) => b.write(data)?,
        }
        Ok(())
    }

    /// The values, copied to the host.
    pub fn download(&self) -> Result<Vec<T>, ProgramError> {
        Ok(match &self.0 {
            BufferRepr::Cpu(b) => b.download(),
            #[cfg(feature = "cuda")]
            BufferRepr::Cuda(b) => b.download()?,
        })
    }

    /// The address of the first value (a `T*` for programs).
    #[must_use]
    pub fn device_ptr(&self) -> u64 {
        match &self.0 {
            BufferRepr::Cpu(b) => b.device_ptr(),
            #[cfg(feature = "cuda")]
            BufferRepr::Cuda(b) => b.device_ptr(),
        }
    }

    /// Values held.
    #[must_use]
    pub fn len(&self) -> usize {
        match &self.0 {
            BufferRepr::Cpu(b) => b.len(),
            #[cfg(feature = "cuda")]
            BufferRepr::Cuda(b) => b.len(),
        }
    }

    /// Whether it holds no values.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl Device {
    /// A module of programs for this device (`optixModuleCreate`). It is compiled with the
    /// pipelines that use it.
    #[doc(alias = "optixModuleCreate")]
    pub fn create_module(&self, source: ModuleSource<'_>) -> Result<Module, ProgramError> {
        let ModuleSource::CudaCpp(src) = source;
        Ok(Module(match &self.repr {
            DeviceRepr::Cpu(_) => ModuleRepr::Cpu(CxxModule::from_source(src)),
            #[cfg(feature = "cuda")]
            DeviceRepr::Cuda(_) => ModuleRepr::Cuda(CudaModule::from_source(src)),
        }))
    }

    /// A pipeline of program groups made from this device's modules (`optixPipelineCreate`);
    /// `params_variable` is the guide's `pipelineLaunchParamsVariableName`. The CUDA device
    /// compiles it with NVRTC, the CPU device with the host's C++ compiler (cached on disk).
    #[doc(alias = "optixPipelineCreate")]
    pub fn create_pipeline(
        &self,
        compile: &PipelineCompileOptions,
        link: &PipelineLinkOptions,
        params_variable: Option<&str>,
        groups: &[ProgramGroup],
    ) -> Result<Pipeline, ProgramError> {
        let mixed = || ProgramError::MixedDevices("a program group of another device");
        Ok(Pipeline(match &self.repr {
            DeviceRepr::Cpu(_) => {
                let g = groups
                    .iter()
                    .map(|g| match &g.0 {
                        GroupRepr::Cpu(g) => Ok(g.clone()),
                        #[cfg(feature = "cuda")]
                        _ => Err(mixed()),
                    })
                    .collect::<Result<Vec<_>, _>>()?;
                PipelineRepr::Cpu(CxxPipeline::new(
                    self.context(),
                    compile,
                    link,
                    params_variable,
                    &g,
                )?)
            }
            #[cfg(feature = "cuda")]
            DeviceRepr::Cuda(c) => {
                let g = groups
                    .iter()
                    .map(|g| match &g.0 {
                        GroupRepr::Cuda(g) => Ok(g.clone()),
                        _ => Err(mixed()),
                    })
                    .collect::<Result<Vec<_>, _>>()?;
                let mut p = CudaPipeline::new(c.context(), compile, link, params_variable, &g)?;
                p.set_device_context(self.context());
                PipelineRepr::Cuda(Box::new(p))
            }
        }))
    }

    /// Memory of `len` zeroed values that programs read and write through its address.
    pub fn create_buffer<T: Pod>(&self, len: usize) -> Result<Buffer<T>, ProgramError> {
        Ok(Buffer(match &self.repr {
            DeviceRepr::Cpu(_) => BufferRepr::Cpu(HostBuffer::zeroed(len)),
            #[cfg(feature = "cuda")]
            DeviceRepr::Cuda(c) => BufferRepr::Cuda(CudaBuffer::zeroed(c.context(), len)?),
        }))
    }

    /// A buffer holding a copy of `data`.
    pub fn buffer_from_slice<T: Pod>(&self, data: &[T]) -> Result<Buffer<T>, ProgramError> {
        let mut b = self.create_buffer(data.len())?;
        b.write(data)?;
        Ok(b)
    }
}

impl Gas {
    /// The `OptixTraversableHandle` value that CUDA C++ programs of this structure's device
    /// trace. It stays valid while the structure lives.
    #[doc(alias = "OptixTraversableHandle")]
    pub fn optix_handle(&self) -> Result<u64, ProgramError> {
        match self.repr() {
            GasRepr::Cpu(_) => Ok(oxray_cpu::cxx::optix_handle(&self.handle())),
            #[cfg(feature = "cuda")]
            GasRepr::Cuda(g) => Ok(g.optix_handle()?),
        }
    }
}

impl Ias {
    /// The `OptixTraversableHandle` value that CUDA C++ programs of this structure's device
    /// trace. It stays valid while the structure lives.
    #[doc(alias = "OptixTraversableHandle")]
    pub fn optix_handle(&self) -> Result<u64, ProgramError> {
        match self.repr() {
            IasRepr::Cpu(_) => Ok(oxray_cpu::cxx::optix_handle(&self.handle())),
            #[cfg(feature = "cuda")]
            IasRepr::Cuda(i) => Ok(i.optix_handle()?),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn program_objects_of_two_devices_do_not_mix() {
        let cpu = Device::cpu();
        let m = cpu
            .create_module(ModuleSource::CudaCpp(
                "extern \"C\" __global__ void __raygen__a() {}\n\
                 extern \"C\" __global__ void __closesthit__c() {}",
            ))
            .unwrap();
        assert!(m.has_entry("__raygen__a"));
        assert!(matches!(
            ProgramGroup::raygen(&m, "__raygen__b"),
            Err(ProgramError::Pipeline(PipelineError::UnknownEntry { .. }))
        ));
        assert!(matches!(
            ProgramGroup::hit_group(HitGroupDesc::default()),
            Err(ProgramError::Unsupported(_))
        ));
        let Ok(cuda) = Device::cuda(0) else {
            println!("skipping the two-device half: no CUDA device");
            return;
        };
        let g = ProgramGroup::raygen(&m, "__raygen__a").unwrap();
        let e = cuda
            .create_pipeline(
                &PipelineCompileOptions::default(),
                &PipelineLinkOptions::default(),
                None,
                &[g],
            )
            .unwrap_err();
        assert!(matches!(e, ProgramError::MixedDevices(_)));
    }
}
