//! `oxray render --backend`: which version of the path tracer renders, on which device.
//!
//! - `cpu` (the default): the Rust programs on the CPU ([`oxray_render::render`]: as a
//!   wavefront of paths over the batched queries for a scene without motion, else through the
//!   CPU pipeline; the same image either way).
//! - `cpu-cxx`: the path tracer's CUDA C++ programs on the CPU, compiled by the host's C++
//!   compiler ([`oxray_render::device::render_on`] with the CPU device).
//! - `cuda`, `cuda:N`: the CUDA C++ programs on that GPU; asking for one this machine lacks is
//!   an error, never a silent fall-back.
//! - `auto`: the CUDA C++ programs on GPU 0 where there is one, else the Rust programs on the
//!   CPU.

use oxray::{BackendKind, Device};
use oxray_cli::device::DeviceCommandError;
use oxray_render::lights::Environment;
use oxray_render::{Progress, RenderError, RenderOptions, Rendered, Renderer};
use oxray_scene::SceneDesc;
use std::ops::ControlFlow;

/// A renderer chosen by `--backend`.
pub enum RenderBackend {
    /// The Rust programs on the CPU (a wavefront, or the CPU pipeline for scenes with motion).
    Rust,
    /// The CUDA C++ programs on the CPU device (made on the render's thread pool).
    CxxOnCpu,
    /// The CUDA C++ programs on a CUDA device.
    Device(Device),
}

/// Checks a `--backend` value of `render` without opening anything (for the argument parser).
pub fn parse(name: &str) -> Result<String, String> {
    let n = name.trim().to_ascii_lowercase();
    if n == "cpu-cxx" {
        return Ok(n);
    }
    oxray_cli::device::parse_backend(&n)
        .map_err(|_| "expected cpu, cpu-cxx, cuda, cuda:N or auto".to_string())
}

/// Opens what `--backend` names (a CUDA device is opened here, before any loading).
pub fn open(name: &str) -> Result<RenderBackend, DeviceCommandError> {
    Ok(match name {
        "cpu" => RenderBackend::Rust,
        "cpu-cxx" => RenderBackend::CxxOnCpu,
        "auto" => match Device::cuda(0) {
            Ok(d) => RenderBackend::Device(d),
            Err(_) => RenderBackend::Rust,
        },
        other => {
            let d = oxray_cli::device::open(other)?;
            if d.kind() == BackendKind::Cuda {
                RenderBackend::Device(d)
            } else {
                RenderBackend::CxxOnCpu
            }
        }
    })
}

impl RenderBackend {
    /// Renders with this backend (call it on the render's thread pool); `on_pass` sees each
    /// pass and may stop the render.
    pub fn render(
        &self,
        scene: &SceneDesc,
        env: &Environment,
        opts: &RenderOptions,
        on_pass: impl FnMut(&Progress<'_>) -> ControlFlow<()>,
    ) -> Result<Rendered, RenderError> {
        // A renderer's geometry is built before its render: part of this render's setup.
        let device = match self {
            RenderBackend::Rust => return oxray_render::render_passes(scene, env, opts, on_pass),
            RenderBackend::CxxOnCpu => &Device::cpu(),
            RenderBackend::Device(d) => d,
        };
        let start = std::time::Instant::now();
        let mut renderer = Renderer::new(device, scene, env)?;
        let geometry = start.elapsed();
        let mut rendered = renderer.render(opts, on_pass)?;
        rendered.setup += geometry;
        Ok(rendered)
    }

    /// What renders, for the summary line (`None` for the default).
    pub fn describe(&self) -> Option<String> {
        match self {
            RenderBackend::Rust => None,
            RenderBackend::CxxOnCpu => Some("the CUDA C++ programs on the CPU".into()),
            RenderBackend::Device(d) => Some(format!("the CUDA C++ programs on {}", d.describe())),
        }
    }
}
