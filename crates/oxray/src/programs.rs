//! Programs in CUDA C++ through the device-neutral API: a module is created from source by the
//! device that will run it. The CUDA device compiles pipelines of such modules with NVRTC
//! (`oxray::cuda::CudaPipeline`); the CPU device runs programs written as Rust closures
//! (`oxray::cpu::Module`), and refuses CUDA C++ with a typed error until it compiles it too.

use crate::accel::{Gas, GasRepr, Ias, IasRepr};
use crate::device::{Device, DeviceRepr};
use oxray_core::{PipelineCompileOptions, PipelineLinkOptions};
use thiserror::Error;

/// The source of a module of programs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum ModuleSource<'a> {
    /// OptiX-style CUDA C++ programs (`extern "C" __global__ void __raygen__name()`, …) using
    /// the device functions of `oxray::cuda::DEVICE_HEADER`.
    CudaCpp(&'a str),
}

/// Why a module, pipeline or buffer of programs could not be made.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
#[non_exhaustive]
pub enum ProgramError {
    /// The CPU device runs programs written as Rust closures (`oxray::cpu::Module`); CUDA C++
    /// on the CPU is not there yet.
    #[error("the CPU device does not compile CUDA C++ programs yet; use oxray::cpu::Module")]
    CudaCppOnCpu,
    /// The CUDA backend refused or failed.
    #[error(transparent)]
    Cuda(#[from] oxray_cuda::CudaError),
}

impl Device {
    /// A module of programs for this device (`optixModuleCreate`).
    pub fn create_module(
        &self,
        source: ModuleSource<'_>,
    ) -> Result<oxray_cuda::CudaModule, ProgramError> {
        match (&self.repr, source) {
            (DeviceRepr::Cpu(_), ModuleSource::CudaCpp(_)) => Err(ProgramError::CudaCppOnCpu),
            (DeviceRepr::Cuda(_), ModuleSource::CudaCpp(src)) => {
                Ok(oxray_cuda::CudaModule::from_source(src))
            }
        }
    }

    /// A pipeline of CUDA C++ program groups, compiled into one kernel (`optixPipelineCreate`);
    /// `params_variable` is the guide's `pipelineLaunchParamsVariableName`.
    pub fn create_pipeline(
        &self,
        compile: &PipelineCompileOptions,
        link: &PipelineLinkOptions,
        params_variable: Option<&str>,
        groups: &[oxray_cuda::CudaProgramGroup],
    ) -> Result<oxray_cuda::CudaPipeline, ProgramError> {
        match &self.repr {
            DeviceRepr::Cpu(_) => Err(ProgramError::CudaCppOnCpu),
            DeviceRepr::Cuda(c) => Ok(oxray_cuda::CudaPipeline::new(
                c.context(),
                compile,
                link,
                params_variable,
                groups,
            )?),
        }
    }

    /// Device memory of `len` zeroed values that programs read and write through its address.
    pub fn create_buffer<T: bytemuck::Pod>(
        &self,
        len: usize,
    ) -> Result<oxray_cuda::CudaBuffer<T>, ProgramError> {
        match &self.repr {
            DeviceRepr::Cpu(_) => Err(ProgramError::CudaCppOnCpu),
            DeviceRepr::Cuda(c) => Ok(oxray_cuda::CudaBuffer::zeroed(c.context(), len)?),
        }
    }
}

impl Gas {
    /// The `OptixTraversableHandle` value that CUDA C++ programs trace (CUDA GASes only; CPU
    /// programs take [`handle`](Gas::handle)).
    pub fn optix_handle(&self) -> Result<u64, ProgramError> {
        match self.repr() {
            GasRepr::Cpu(_) => Err(ProgramError::CudaCppOnCpu),
            GasRepr::Cuda(g) => Ok(g.optix_handle()?),
        }
    }
}

impl Ias {
    /// The `OptixTraversableHandle` value that CUDA C++ programs trace (CUDA IASes only).
    pub fn optix_handle(&self) -> Result<u64, ProgramError> {
        match self.repr() {
            IasRepr::Cpu(_) => Err(ProgramError::CudaCppOnCpu),
            IasRepr::Cuda(i) => Ok(i.optix_handle()?),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cpu_device_refuses_cuda_cpp_with_a_typed_error() {
        let cpu = Device::cpu();
        let e = cpu
            .create_module(ModuleSource::CudaCpp(
                "extern \"C\" __global__ void __raygen__a() {}",
            ))
            .unwrap_err();
        assert_eq!(e, ProgramError::CudaCppOnCpu);
        assert!(e.to_string().contains("oxray::cpu::Module"));
        assert!(cpu.create_buffer::<f32>(4).is_err());
        let compile = PipelineCompileOptions::default();
        let link = PipelineLinkOptions::default();
        assert_eq!(
            cpu.create_pipeline(&compile, &link, None, &[]).unwrap_err(),
            ProgramError::CudaCppOnCpu
        );
        let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let input = oxray_core::TriangleInput::new(oxray_core::VertexBuffer::f32x3(&v));
        let gas = cpu
            .build_gas(&oxray_core::BuildOptions::default(), &[input.into()])
            .unwrap();
        assert_eq!(gas.optix_handle(), Err(ProgramError::CudaCppOnCpu));
    }

    #[test]
    fn a_cuda_device_creates_modules_from_source() {
        let Ok(cuda) = Device::cuda(0) else {
            println!("skipping: no CUDA device");
            return;
        };
        let m = cuda
            .create_module(ModuleSource::CudaCpp(
                "extern \"C\" __global__ void __raygen__a() {}",
            ))
            .unwrap();
        assert!(m.has_entry("__raygen__a"));
    }
}
