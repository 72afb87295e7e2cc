//! The device every build and query goes through, chosen at run time.

use crate::accel::{Gas, GasRepr, Ias, IasRepr};
use oxray_core::{
    AccelBackend, BackendKind, BatchKind, BuildError, BuildInput, BuildOptions, DeviceContext, Hit,
    LoadError, QueryError, Ray, TraversableHandle,
};
use std::sync::Arc;
use thiserror::Error;

/// Why a device could not be opened.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
#[non_exhaustive]
pub enum DeviceError {
    /// The name is not one of `cpu`, `cuda`, `cuda:N` or `auto`.
    #[error("unknown device {0:?}: expected cpu, cuda, cuda:N or auto")]
    UnknownName(String),
    /// This build of oxray has no CUDA backend (the `cuda` feature is off).
    #[error("this build of oxray has no CUDA backend (the `cuda` feature is off)")]
    CudaNotBuilt,
    /// This machine has no usable CUDA (no driver, no device or no NVRTC).
    #[error("CUDA is not available on this machine: {0}")]
    CudaUnavailable(String),
    /// CUDA is there but opening the device failed.
    #[error("the CUDA device could not be opened: {0}")]
    Cuda(String),
}

impl DeviceError {
    /// Whether the error only says that this machine or build has no CUDA, so that a caller
    /// may fall back to the CPU or skip.
    #[must_use]
    pub fn is_unavailable(&self) -> bool {
        matches!(
            self,
            DeviceError::CudaNotBuilt | DeviceError::CudaUnavailable(_)
        )
    }
}

#[derive(Clone)]
pub(crate) enum DeviceRepr {
    Cpu(oxray_cpu::Cpu),
    #[cfg(feature = "cuda")]
    Cuda(Arc<oxray_cuda::Cuda>),
}

/// A device: the CPU (the default, everywhere) or a CUDA GPU. Every build and query takes one,
/// so the same host code runs on either; the choice is made once, at run time
/// ([`Device::from_name`] for a command-line flag, [`Device::best`] for the fastest present).
///
/// A device also carries the options of the OptiX device context ([`DeviceContext`]:
/// validation mode and the log callback), which pipelines created for it inherit.
///
/// Dispatch to the backend happens once per call (a build, a batch), never per ray.
///
/// ```
/// use oxray::{BuildOptions, Device, Ray, TriangleInput, VertexBuffer};
/// use glam::Vec3;
/// let device = Device::from_name("cpu")?; // or "cuda", "cuda:1", "auto"
/// let v = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
/// let gas = device.build_gas(&BuildOptions::default(), &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
/// let rays = vec![Ray::new(Vec3::Z, -Vec3::Z); 64];
/// let mut hits = vec![None; rays.len()];
/// device.intersect_closest(&gas.handle(), &rays, &mut hits)?;
/// assert!(hits.iter().all(|h| h.map(|h| h.t) == Some(1.0)));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone)]
pub struct Device {
    pub(crate) repr: DeviceRepr,
    context: DeviceContext,
}

impl Default for Device {
    /// The CPU.
    fn default() -> Self {
        Device::cpu()
    }
}

impl std::fmt::Debug for Device {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Device({})", self.describe())
    }
}

/// Calls `$body` with `$b` bound to the device's backend.
macro_rules! with_backend {
    ($dev:expr, $b:ident => $body:expr) => {
        match &$dev.repr {
            DeviceRepr::Cpu($b) => $body,
            #[cfg(feature = "cuda")]
            DeviceRepr::Cuda($b) => {
                let $b = &**$b;
                $body
            }
        }
    };
}

impl Device {
    /// The CPU backend, on the current rayon pool.
    #[must_use]
    pub fn cpu() -> Device {
        Device {
            repr: DeviceRepr::Cpu(oxray_cpu::Cpu::new()),
            context: DeviceContext::default(),
        }
    }

    /// CUDA device `ordinal`; its kernels are compiled when it is opened.
    pub fn cuda(ordinal: usize) -> Result<Device, DeviceError> {
        #[cfg(feature = "cuda")]
        {
            match oxray_cuda::Cuda::new(ordinal) {
                Ok(c) => Ok(Device {
                    repr: DeviceRepr::Cuda(Arc::new(c)),
                    context: DeviceContext::default(),
                }),
                Err(e) if e.is_unavailable() => Err(DeviceError::CudaUnavailable(e.to_string())),
                Err(e) => Err(DeviceError::Cuda(e.to_string())),
            }
        }
        #[cfg(not(feature = "cuda"))]
        {
            let _ = ordinal;
            Err(DeviceError::CudaNotBuilt)
        }
    }

    /// CUDA device 0 where this machine has one, else the CPU.
    #[must_use]
    pub fn best() -> Device {
        Device::cuda(0).unwrap_or_else(|_| Device::cpu())
    }

    /// A device by name: `cpu`, `cuda` (device 0), `cuda:N`, or `auto` ([`Device::best`]).
    /// Asking for CUDA where there is none is an error, never a silent fall-back.
    pub fn from_name(name: &str) -> Result<Device, DeviceError> {
        match name.trim().to_ascii_lowercase().as_str() {
            "cpu" => Ok(Device::cpu()),
            "auto" => Ok(Device::best()),
            "cuda" | "gpu" => Device::cuda(0),
            other => match other.strip_prefix("cuda:").map(str::parse::<usize>) {
                Some(Ok(n)) => Device::cuda(n),
                _ => Err(DeviceError::UnknownName(name.to_string())),
            },
        }
    }

    /// The same device with these context options (validation mode, log callback).
    #[must_use]
    pub fn with_context(mut self, context: DeviceContext) -> Device {
        self.context = context;
        self
    }

    /// The context options.
    #[must_use]
    pub fn context(&self) -> &DeviceContext {
        &self.context
    }

    /// Which backend this is.
    #[must_use]
    pub fn kind(&self) -> BackendKind {
        with_backend!(self, b => b.kind())
    }

    /// One line naming the device, e.g. `CPU (16 threads)` or
    /// `NVIDIA H200 (sm_90, 132 SMs)`.
    #[must_use]
    pub fn describe(&self) -> String {
        with_backend!(self, b => b.describe())
    }

    /// The same device with its GASes built by the host's builder (the binned SAH builder every
    /// backend shares, then uploaded) instead of the device's kernels; the CPU is returned as
    /// it is. Every device then traces the same tree of the same inputs, so that even rays
    /// through shared edges and vertices report the same primitive everywhere (which of two
    /// primitives at exactly the same distance a query reports depends on the tree).
    ///
    /// ```
    /// use oxray::Device;
    /// let device = Device::cpu().with_host_builds();
    /// assert_eq!(device.kind(), oxray::BackendKind::Cpu);
    /// ```
    #[must_use]
    pub fn with_host_builds(self) -> Device {
        match self.repr {
            DeviceRepr::Cpu(_) => self,
            #[cfg(feature = "cuda")]
            DeviceRepr::Cuda(c) => Device {
                repr: DeviceRepr::Cuda(Arc::new(
                    (*c).clone().with_builder(oxray_cuda::GasBuilder::Host),
                )),
                context: self.context,
            },
        }
    }

    /// The CUDA backend, if this is a CUDA device (for its node-layout and timing extras).
    #[cfg(feature = "cuda")]
    #[must_use]
    pub fn as_cuda(&self) -> Option<&oxray_cuda::Cuda> {
        match &self.repr {
            DeviceRepr::Cuda(c) => Some(c),
            DeviceRepr::Cpu(_) => None,
        }
    }

    /// The memory query of a GAS build on this device (`optixAccelComputeMemoryUsage`): the
    /// CPU's builder's sizes ([`compute_memory_usage`](crate::compute_memory_usage)), or on a
    /// CUDA device those of the builder that will run (the device's kernels for the inputs and
    /// presets it builds, see `oxray::cuda::Cuda`). Validates as the build does, short of
    /// reading the buffers.
    #[doc(alias = "optixAccelComputeMemoryUsage")]
    pub fn compute_memory_usage(
        &self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<crate::AccelBufferSizes, BuildError> {
        match &self.repr {
            DeviceRepr::Cpu(_) => oxray_bvh::compute_memory_usage(options, inputs),
            #[cfg(feature = "cuda")]
            DeviceRepr::Cuda(b) => b.compute_memory_usage(options, inputs),
        }
    }

    /// Builds a GAS on this device (`optixAccelBuild`); inputs are validated as the guide says,
    /// with the same typed errors on every device.
    #[doc(alias = "optixAccelBuild")]
    pub fn build_gas(
        &self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<Gas, BuildError> {
        Ok(Gas::from_repr(match &self.repr {
            DeviceRepr::Cpu(b) => GasRepr::Cpu(Arc::new(b.build_gas(options, inputs)?)),
            #[cfg(feature = "cuda")]
            DeviceRepr::Cuda(b) => GasRepr::Cuda(Arc::new(b.build_gas(options, inputs)?)),
        }))
    }

    /// Builds an IAS on this device from one instance build input (guide §5.4). Every child
    /// must live on this device; the CUDA backend builds one level of instances over GASes.
    pub fn build_ias(
        &self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<Ias, BuildError> {
        Ok(Ias::from_repr(match &self.repr {
            DeviceRepr::Cpu(b) => IasRepr::Cpu(Arc::new(b.build_ias(options, inputs)?)),
            #[cfg(feature = "cuda")]
            DeviceRepr::Cuda(b) => IasRepr::Cuda(Arc::new(b.build_ias(options, inputs)?)),
        }))
    }

    /// Updates (refits) a GAS built with `ALLOW_UPDATE` on this device (guide §5.6): the
    /// options must be the build's with `operation = BuildOperation::Update`, and the inputs
    /// the build's up to the contents of their buffers (new vertices, boxes, indices, SBT index
    /// offsets, pre-transform matrix); every rule is checked, with a typed
    /// [`BuildError::InvalidUpdate`] naming it, before anything changes.
    ///
    /// The update is in place when `gas` is the structure's only owner. When something else
    /// shares it (a clone, a handle, an IAS built over it) it is copy-on-write: `gas` then
    /// refers to the updated copy and the sharers keep the old structure — as in OptiX, an IAS
    /// over the GAS must itself be updated ([`update_ias`](Self::update_ias), with instances of
    /// `gas.handle()`) or rebuilt to see the change. On a GPU the refit runs on the device
    /// (a structure in the BVH4 node layout is refused with `Unsupported`), with the hits of
    /// the CPU's update of the same build.
    ///
    /// ```
    /// use oxray::{BuildFlags, BuildOperation, BuildOptions, Device, Ray, TriangleInput, VertexBuffer};
    /// use glam::Vec3;
    /// let device = Device::cpu();
    /// let mut v = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
    /// let mut options = BuildOptions::new(BuildFlags::ALLOW_UPDATE);
    /// let mut gas = device.build_gas(&options, &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
    /// for p in &mut v {
    ///     p[2] = -2.0; // the triangle moves away
    /// }
    /// options.operation = BuildOperation::Update;
    /// device.update_gas(&mut gas, &options, &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
    /// let mut hits = [None];
    /// device.intersect_closest(&gas.handle(), &[Ray::new(Vec3::Z, -Vec3::Z)], &mut hits)?;
    /// assert_eq!(hits[0].unwrap().t, 3.0);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn update_gas(
        &self,
        gas: &mut Gas,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(), BuildError> {
        match (&self.repr, gas.repr_mut()) {
            (DeviceRepr::Cpu(b), GasRepr::Cpu(g)) => b.update_gas(g, options, inputs),
            #[cfg(feature = "cuda")]
            (DeviceRepr::Cuda(b), GasRepr::Cuda(g)) => b.update_gas(g, options, inputs),
            #[cfg(feature = "cuda")]
            _ => Err(BuildError::Unsupported(
                "updating a structure on another device than the one holding it",
            )),
        }
    }

    /// Updates (refits) an IAS built with `ALLOW_UPDATE` on this device (guide §5.6): new
    /// instance transforms, ids, SBT offsets, masks and flags for the same number of
    /// instances over the same children — where a child is an update of the structure the IAS
    /// was built over (see [`update_gas`](Self::update_gas)), its new bounds are taken. In
    /// place or copy-on-write as `update_gas`, on every device.
    pub fn update_ias(
        &self,
        ias: &mut Ias,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(), BuildError> {
        match (&self.repr, ias.repr_mut()) {
            (DeviceRepr::Cpu(b), IasRepr::Cpu(i)) => b.update_ias(i, options, inputs),
            #[cfg(feature = "cuda")]
            (DeviceRepr::Cuda(b), IasRepr::Cuda(i)) => b.update_ias(i, options, inputs),
            #[cfg(feature = "cuda")]
            _ => Err(BuildError::Unsupported(
                "updating a structure on another device than the one holding it",
            )),
        }
    }

    /// Compacts a GAS built with `ALLOW_COMPACTION` (`optixAccelCompact`, guide §5.8): a new
    /// structure of [`AccelProperty::CompactedSize`](oxray_core::AccelProperty::CompactedSize) bytes with the same hits, independent of
    /// the source. It can be traced, updated (if built with `ALLOW_UPDATE`) and saved. A GPU's
    /// structures are exactly sized when built, so there it is an exact copy.
    ///
    /// ```
    /// use oxray::{AccelProperty, BuildFlags, BuildOptions, Device, EmittedProperty, TriangleInput, VertexBuffer};
    /// let device = Device::cpu();
    /// let v = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
    /// let options = BuildOptions::new(BuildFlags::ALLOW_COMPACTION);
    /// let gas = device.build_gas(&options, &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
    /// let EmittedProperty::CompactedSize(size) = gas.emit_property(AccelProperty::CompactedSize)? else { unreachable!() };
    /// if (size as usize) < gas.memory().output_bytes {
    ///     let compact = device.compact_gas(&gas)?;
    ///     assert_eq!(compact.memory().output_bytes as u64, size);
    /// }
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    #[doc(alias = "optixAccelCompact")]
    pub fn compact_gas(&self, gas: &Gas) -> Result<Gas, BuildError> {
        match (&self.repr, gas.repr()) {
            (DeviceRepr::Cpu(_), GasRepr::Cpu(g)) => Ok(Gas::from_repr(GasRepr::Cpu(Arc::new(
                oxray_cpu::Gas::from(g.data().compact()?),
            )))),
            #[cfg(feature = "cuda")]
            (DeviceRepr::Cuda(_), GasRepr::Cuda(g)) => {
                Ok(Gas::from_repr(GasRepr::Cuda(Arc::new(g.compact()?))))
            }
            #[cfg(feature = "cuda")]
            _ => Err(BuildError::Unsupported(
                "compacting a structure on another device than the one holding it",
            )),
        }
    }

    /// Compacts an IAS built with `ALLOW_COMPACTION` (guide §5.8), over the same children.
    pub fn compact_ias(&self, ias: &Ias) -> Result<Ias, BuildError> {
        match (&self.repr, ias.repr()) {
            (DeviceRepr::Cpu(_), IasRepr::Cpu(i)) => Ok(Ias::from_repr(IasRepr::Cpu(Arc::new(
                oxray_cpu::Ias::from_data(i.data().compact()?)?,
            )))),
            #[cfg(feature = "cuda")]
            (DeviceRepr::Cuda(_), IasRepr::Cuda(i)) => {
                Ok(Ias::from_repr(IasRepr::Cuda(Arc::new(i.compact()?))))
            }
            #[cfg(feature = "cuda")]
            _ => Err(BuildError::Unsupported(
                "compacting a structure on another device than the one holding it",
            )),
        }
    }

    /// Loads a GAS saved by [`Gas::to_bytes`] into this device's memory. The bytes are checked
    /// before use (format, version, checksum, every size and index), so that damaged or
    /// hostile bytes give a typed [`LoadError`]. Bytes saved on any device load on any device
    /// (beyond guide §5.7: OptiX relocates only between buffers of one device). Loaded on the
    /// device it was saved from the structure traces bit-identical hits on the CPU; on another
    /// device, the same hits up to which of two primitives at exactly the same distance is
    /// reported (a GPU derives its binary tree from the saved 4-wide one). A structure with
    /// motion keys has no GPU layout yet: [`LoadError::Unsupported`] there.
    ///
    /// ```
    /// use oxray::{BuildOptions, Device, Ray, TriangleInput, VertexBuffer};
    /// use glam::Vec3;
    /// let device = Device::cpu();
    /// let v = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
    /// let gas = device.build_gas(&BuildOptions::default(), &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
    /// let bytes = gas.to_bytes()?;
    /// let loaded = device.load_gas(&bytes)?;
    /// let mut hits = [None];
    /// device.intersect_closest(&loaded.handle(), &[Ray::new(Vec3::Z, -Vec3::Z)], &mut hits)?;
    /// assert_eq!(hits[0].unwrap().t, 1.0);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn load_gas(&self, bytes: &[u8]) -> Result<Gas, LoadError> {
        match &self.repr {
            DeviceRepr::Cpu(_) => Ok(Gas::from_repr(GasRepr::Cpu(Arc::new(
                oxray_cpu::Gas::from(oxray_bvh::GasData::from_bytes(bytes)?),
            )))),
            #[cfg(feature = "cuda")]
            DeviceRepr::Cuda(b) => {
                let data = oxray_bvh::GasData::from_bytes(bytes)?;
                let gas = oxray_cuda::CudaGas::from_data(b.context(), &data, b.layout()).map_err(
                    |e| match e {
                        oxray_cuda::CudaError::Unsupported(what) => LoadError::Unsupported(what),
                        other => LoadError::Device(other.to_string()),
                    },
                )?;
                Ok(Gas::from_repr(GasRepr::Cuda(Arc::new(gas))))
            }
        }
    }

    /// Loads an IAS saved by [`Ias::to_bytes`] over `children`, one per instance by instance
    /// index — the structures it was built over or copies of them (loaded, compacted), as
    /// OptiX's relocation takes one relocated traversable per instance (guide §5.7); the
    /// saved world boxes are kept. Children must live on this device (an IAS saved on one
    /// device loads on another over children loaded there).
    pub fn load_ias(&self, bytes: &[u8], children: &[TraversableHandle]) -> Result<Ias, LoadError> {
        let data = oxray_bvh::IasData::from_bytes(bytes, children)?;
        let child_error = |e: BuildError| match e {
            BuildError::ForeignTraversable { instance, .. } => LoadError::Child {
                instance,
                reason: e.to_string(),
            },
            other => LoadError::Child {
                instance: 0,
                reason: other.to_string(),
            },
        };
        match &self.repr {
            DeviceRepr::Cpu(_) => {
                let ias = oxray_cpu::Ias::from_data(data).map_err(child_error)?;
                Ok(Ias::from_repr(IasRepr::Cpu(Arc::new(ias))))
            }
            #[cfg(feature = "cuda")]
            DeviceRepr::Cuda(b) => {
                let ias = oxray_cuda::CudaIas::from_data(b.context(), data).map_err(child_error)?;
                Ok(Ias::from_repr(IasRepr::Cuda(Arc::new(ias))))
            }
        }
    }

    /// The closest hit of every ray under `root` (`None` for a miss), in parallel. The hits are
    /// the same on every device and for every thread count.
    pub fn intersect_closest(
        &self,
        root: &TraversableHandle,
        rays: &[Ray],
        hits: &mut [Option<Hit>],
    ) -> Result<(), QueryError> {
        with_backend!(self, b => b.intersect_closest(root, rays, hits))
    }

    /// Whether anything lies in every ray's interval under `root` (shadow and visibility rays).
    pub fn intersect_any(
        &self,
        root: &TraversableHandle,
        rays: &[Ray],
        occluded: &mut [bool],
    ) -> Result<(), QueryError> {
        with_backend!(self, b => b.intersect_any(root, rays, occluded))
    }

    /// Copies rays into the device's memory with room for the results of a `kind` query, so
    /// that they can be traced again and again without transfers (timing, iterative work).
    pub fn upload_rays(&self, rays: &[Ray], kind: BatchKind) -> Result<RayBatch, QueryError> {
        Ok(RayBatch {
            len: rays.len(),
            kind,
            repr: match &self.repr {
                DeviceRepr::Cpu(b) => BatchRepr::Cpu(b.upload_batch(rays, kind)?),
                #[cfg(feature = "cuda")]
                DeviceRepr::Cuda(b) => BatchRepr::Cuda(b.upload_batch(rays, kind)?),
            },
        })
    }

    /// Traces a resident batch under `root`; the results stay on the device.
    pub fn trace_batch(
        &self,
        root: &TraversableHandle,
        batch: &mut RayBatch,
    ) -> Result<(), QueryError> {
        match (&self.repr, &mut batch.repr) {
            (DeviceRepr::Cpu(b), BatchRepr::Cpu(x)) => b.run_batch(root, x),
            #[cfg(feature = "cuda")]
            (DeviceRepr::Cuda(b), BatchRepr::Cuda(x)) => b.run_batch(root, x),
            #[cfg(feature = "cuda")]
            _ => Err(QueryError::ForeignTraversable {
                device: self.kind(),
                found: batch.device_kind(),
            }),
        }
    }

    /// Copies the closest hits of a traced [`BatchKind::Closest`] batch out.
    pub fn download_hits(
        &self,
        batch: &RayBatch,
        hits: &mut [Option<Hit>],
    ) -> Result<(), QueryError> {
        match (&self.repr, &batch.repr) {
            (DeviceRepr::Cpu(b), BatchRepr::Cpu(x)) => b.download_hits(x, hits),
            #[cfg(feature = "cuda")]
            (DeviceRepr::Cuda(b), BatchRepr::Cuda(x)) => b.download_hits(x, hits),
            #[cfg(feature = "cuda")]
            _ => Err(QueryError::ForeignTraversable {
                device: self.kind(),
                found: batch.device_kind(),
            }),
        }
    }

    /// Copies the results of a traced [`BatchKind::Any`] batch out.
    pub fn download_occlusion(
        &self,
        batch: &RayBatch,
        occluded: &mut [bool],
    ) -> Result<(), QueryError> {
        match (&self.repr, &batch.repr) {
            (DeviceRepr::Cpu(b), BatchRepr::Cpu(x)) => b.download_occlusion(x, occluded),
            #[cfg(feature = "cuda")]
            (DeviceRepr::Cuda(b), BatchRepr::Cuda(x)) => b.download_occlusion(x, occluded),
            #[cfg(feature = "cuda")]
            _ => Err(QueryError::ForeignTraversable {
                device: self.kind(),
                found: batch.device_kind(),
            }),
        }
    }
}

/// Rays and room for their results, resident in one device's memory ([`Device::upload_rays`]).
pub struct RayBatch {
    len: usize,
    kind: BatchKind,
    repr: BatchRepr,
}

enum BatchRepr {
    Cpu(oxray_cpu::CpuBatch),
    #[cfg(feature = "cuda")]
    Cuda(oxray_cuda::CudaBatch),
}

impl RayBatch {
    /// Rays in the batch.
    #[must_use]
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the batch holds no rays.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The query it runs.
    #[must_use]
    pub fn kind(&self) -> BatchKind {
        self.kind
    }

    /// The device whose memory holds it.
    #[must_use]
    pub fn device_kind(&self) -> BackendKind {
        match self.repr {
            BatchRepr::Cpu(_) => BackendKind::Cpu,
            #[cfg(feature = "cuda")]
            BatchRepr::Cuda(_) => BackendKind::Cuda,
        }
    }
}
