//! The CUDA backend behind the facade's `Device`: triangle GASes built on the device
//! (`device_build`) or on the host by the shared builders of `oxray-bvh` and uploaded in the
//! kernels' node layout (see [`GasBuilder`]), traced by the batch kernels.

use crate::context::CudaContext;
use crate::device_build::{self, DeviceBuildConfig, DeviceBuildError, GasBuilder};
use crate::error::CudaError;
use crate::gas::{CudaGas, DeviceHits, DeviceOcclusion, DeviceRays};
use crate::ias::CudaIas;
use crate::layout::NodeLayout;
use cudarc::driver::CudaSlice;
use oxray_bvh::{GasData, IasData};
use oxray_core::{
    AccelBackend, BackendKind, BatchKind, BuildError, BuildInput, BuildOptions, Hit, QueryError,
    Ray, TraversableHandle,
};
use std::sync::Arc;

/// The CUDA backend: one device, its compiled kernels, a node layout for the GASes it builds
/// and where it builds them.
///
/// Triangle and custom-primitive GASes, and the top-level trees of IASes, are built on the
/// device ([`GasBuilder::Device`], as OptiX builds them) unless `OXRAY_CUDA_GAS_BUILDER=host`
/// is set when the backend is opened or [`with_builder`](Self::with_builder) says otherwise:
/// every preset and flag, GASes in the
/// binary layout ([`NodeLayout::Bvh2`]), as [`DeviceBuildConfig::for_options`] configures it.
/// The rest (spheres, curves, motion keys, the BVH4 layout, and the rare tree too deep for the
/// traversal stacks) is built on the host and uploaded.
#[derive(Clone, Debug)]
pub struct Cuda {
    ctx: CudaContext,
    layout: NodeLayout,
    builder: GasBuilder,
}

impl Cuda {
    /// Opens device `ordinal` and compiles the kernels; an error for which
    /// [`CudaError::is_unavailable`] holds where this machine has no CUDA, and
    /// [`CudaError::Config`] where `OXRAY_CUDA_GAS_BUILDER` has an unknown value.
    pub fn new(ordinal: usize) -> Result<Cuda, CudaError> {
        let builder = GasBuilder::from_env()?;
        Ok(Cuda {
            ctx: CudaContext::with_device(ordinal)?,
            layout: NodeLayout::default(),
            builder,
        })
    }

    /// The backend of an open context (the GASes it builds use the default layout and are
    /// built on the device).
    #[must_use]
    pub fn from_context(ctx: CudaContext) -> Cuda {
        Cuda {
            ctx,
            layout: NodeLayout::default(),
            builder: GasBuilder::Device,
        }
    }

    /// The same device, building GASes in `layout` from now on.
    #[must_use]
    pub fn with_layout(mut self, layout: NodeLayout) -> Self {
        self.layout = layout;
        self
    }

    /// The same device, building triangle GASes with `builder` from now on.
    #[must_use]
    pub fn with_builder(mut self, builder: GasBuilder) -> Self {
        self.builder = builder;
        self
    }

    /// The node layout triangle GASes are uploaded in.
    #[must_use]
    pub fn layout(&self) -> NodeLayout {
        self.layout
    }

    /// Where triangle GASes are built.
    #[must_use]
    pub fn builder(&self) -> GasBuilder {
        self.builder
    }

    /// How the device would build a GAS of these inputs, or `None` where the host builds it.
    #[must_use]
    pub fn device_build_config(
        &self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Option<DeviceBuildConfig> {
        let device_kind = matches!(
            inputs.first(),
            Some(BuildInput::Triangles(_) | BuildInput::CustomPrimitives(_))
        );
        // Structures with motion keys are built on the host (their tree bounds every key).
        if self.builder != GasBuilder::Device
            || self.layout != NodeLayout::Bvh2
            || !device_kind
            || options.motion.has_motion()
        {
            return None;
        }
        // Saturating: a count past u32 fails validation whichever builder runs.
        let n = inputs
            .iter()
            .fold(0u32, |n, i| n.saturating_add(i.num_primitives()));
        Some(DeviceBuildConfig::for_options(options, n))
    }

    /// The memory query (`optixAccelComputeMemoryUsage`) for a GAS build on this backend: the
    /// device builder's sizes where it would build the inputs, else the host builder's
    /// ([`oxray_bvh::compute_memory_usage`]).
    #[doc(alias = "optixAccelComputeMemoryUsage")]
    pub fn compute_memory_usage(
        &self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<oxray_bvh::AccelBufferSizes, BuildError> {
        match self.device_build_config(options, inputs) {
            Some(config) => device_build::memory_usage(options, inputs, &config),
            None => oxray_bvh::compute_memory_usage(options, inputs),
        }
    }

    /// The device context.
    #[must_use]
    pub fn context(&self) -> &CudaContext {
        &self.ctx
    }
}

/// Rays and room for their results in device memory.
#[derive(Debug)]
pub struct CudaBatch {
    rays: DeviceRays,
    results: DeviceResults,
    /// The GAS the batch was last traced against: its slots resolve the hit records.
    traced: Option<TraversableHandle>,
}

#[derive(Debug)]
enum DeviceResults {
    /// Hit records, and the instance slot of each (filled by IAS queries).
    Closest(DeviceHits, CudaSlice<u32>),
    Any(DeviceOcclusion),
}

/// What a query on the CUDA backend starts at.
enum Root<'h> {
    Null,
    Gas(&'h CudaGas),
    Ias(&'h CudaIas),
}

fn query_error(e: CudaError) -> QueryError {
    match e {
        CudaError::LengthMismatch { rays, outputs } => QueryError::LengthMismatch { rays, outputs },
        CudaError::CustomPrimitives => QueryError::Unsupported(
            "batched queries over custom primitives on the CUDA backend (their intersection programs run in pipelines)",
        ),
        CudaError::Unsupported(what) => QueryError::Unsupported(what),
        other => QueryError::Device(other.to_string()),
    }
}

fn build_error(e: CudaError) -> BuildError {
    BuildError::Device(e.to_string())
}

impl Cuda {
    /// The structure a query starts at.
    fn root<'h>(&self, handle: &'h TraversableHandle) -> Result<Root<'h>, QueryError> {
        let Some(backend) = handle.backend() else {
            return Ok(Root::Null);
        };
        if let Some(gas) = handle.downcast_ref::<CudaGas>() {
            return Ok(Root::Gas(gas));
        }
        if let Some(ias) = handle.downcast_ref::<CudaIas>() {
            return Ok(Root::Ias(ias));
        }
        Err(match backend {
            BackendKind::Cuda | BackendKind::Any => {
                QueryError::Unsupported("tracing a transform on the CUDA backend")
            }
            found => QueryError::ForeignTraversable {
                device: BackendKind::Cuda,
                found,
            },
        })
    }
}

impl AccelBackend for Cuda {
    type Gas = CudaGas;
    type Ias = CudaIas;
    type Batch = CudaBatch;

    fn kind(&self) -> BackendKind {
        BackendKind::Cuda
    }

    fn describe(&self) -> String {
        let d = self.ctx.device();
        format!(
            "{} (sm_{}{}, {} SMs)",
            d.name, d.compute_capability.0, d.compute_capability.1, d.multiprocessors
        )
    }

    fn build_gas(
        &self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<CudaGas, BuildError> {
        // Validated first, so that bad inputs get the same errors on every device.
        oxray_core::validate::validate_structure(options, inputs)?;
        if let Some(config) = self.device_build_config(options, inputs) {
            match device_build::build_gas(&self.ctx, options, inputs, &config) {
                Ok((gas, _)) => return Ok(gas),
                Err(DeviceBuildError::Invalid(e)) => return Err(e),
                // Too deep for the traversal stacks: the host's builder bounds the depth.
                Err(DeviceBuildError::Device(CudaError::TreeTooDeep { .. })) => {}
                Err(DeviceBuildError::Device(e)) => return Err(build_error(e)),
            }
        }
        // The host builds the rest: the presets and layouts the device builder does not make,
        // spheres and curves (built-in, traced by pipelines and the query kernels alike) and custom
        // primitives (uploaded for pipelines, which run their intersection programs; the
        // batched queries refuse them).
        let (data, tree) = GasData::build_with_tree(options, inputs)?;
        CudaGas::upload_with_layout(&self.ctx, &data, &tree, self.layout).map_err(build_error)
    }

    fn build_ias(
        &self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<CudaIas, BuildError> {
        if self.builder == GasBuilder::Device {
            let prepared = IasData::prepare(options, inputs)?;
            let config = device_build::ias_config(options, prepared.boxes.len() as u32);
            match device_build::build_box_tree(&self.ctx, &prepared.boxes, &config) {
                Ok((tree, _)) => {
                    let (data, tree) = prepared.finish(tree);
                    return Ok(
                        CudaIas::upload(&self.ctx, data, &tree)?.built_by(GasBuilder::Device)
                    );
                }
                // Too deep for the traversal stacks: the host's builder bounds the depth.
                Err(CudaError::TreeTooDeep { .. }) => {}
                Err(e) => return Err(build_error(e)),
            }
        }
        let (data, tree) = IasData::build_with_tree(options, inputs)?;
        CudaIas::upload(&self.ctx, data, &tree)
    }

    fn update_gas(
        &self,
        gas: &mut Arc<CudaGas>,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(), BuildError> {
        if let Some(g) = Arc::get_mut(gas) {
            return g.update(options, inputs);
        }
        // Shared: checked before the copy, so that a refused update copies nothing.
        gas.meta.check_update(options, inputs)?;
        let mut copy = gas.duplicate().map_err(build_error)?;
        copy.update(options, inputs)?;
        *gas = Arc::new(copy);
        Ok(())
    }

    fn update_ias(
        &self,
        ias: &mut Arc<CudaIas>,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(), BuildError> {
        if let Some(i) = Arc::get_mut(ias) {
            return i.update(options, inputs);
        }
        ias.data().check_update(options, inputs)?;
        let mut copy = ias.duplicate()?;
        copy.update(options, inputs)?;
        *ias = Arc::new(copy);
        Ok(())
    }

    fn intersect_closest(
        &self,
        root: &TraversableHandle,
        rays: &[Ray],
        hits: &mut [Option<Hit>],
    ) -> Result<(), QueryError> {
        if rays.len() != hits.len() {
            return Err(QueryError::LengthMismatch {
                rays: rays.len(),
                outputs: hits.len(),
            });
        }
        match self.root(root)? {
            Root::Null => hits.fill(None),
            Root::Gas(gas) => gas.intersect_batch_into(rays, hits).map_err(query_error)?,
            Root::Ias(ias) => ias.intersect_batch_into(rays, hits).map_err(query_error)?,
        }
        Ok(())
    }

    fn intersect_any(
        &self,
        root: &TraversableHandle,
        rays: &[Ray],
        occluded: &mut [bool],
    ) -> Result<(), QueryError> {
        if rays.len() != occluded.len() {
            return Err(QueryError::LengthMismatch {
                rays: rays.len(),
                outputs: occluded.len(),
            });
        }
        match self.root(root)? {
            Root::Null => occluded.fill(false),
            Root::Gas(gas) => gas
                .occluded_batch_into(rays, occluded)
                .map_err(query_error)?,
            Root::Ias(ias) => ias
                .occluded_batch_into(rays, occluded)
                .map_err(query_error)?,
        }
        Ok(())
    }

    fn upload_batch(&self, rays: &[Ray], kind: BatchKind) -> Result<CudaBatch, QueryError> {
        let d_rays = DeviceRays::upload(&self.ctx, rays).map_err(query_error)?;
        let results = match kind {
            BatchKind::Closest => DeviceResults::Closest(
                DeviceHits::new(&self.ctx, rays.len()).map_err(query_error)?,
                self.ctx
                    .stream
                    .alloc_zeros::<u32>(rays.len().max(1))
                    .map_err(|e| QueryError::Device(e.to_string()))?,
            ),
            BatchKind::Any => DeviceResults::Any(
                DeviceOcclusion::new(&self.ctx, rays.len()).map_err(query_error)?,
            ),
        };
        Ok(CudaBatch {
            rays: d_rays,
            results,
            traced: None,
        })
    }

    fn run_batch(&self, root: &TraversableHandle, batch: &mut CudaBatch) -> Result<(), QueryError> {
        let n = batch.rays.len();
        match (self.root(root)?, &mut batch.results) {
            (Root::Null, _) => {
                return Err(QueryError::Unsupported(
                    "a resident batch on the null handle (every ray misses; use intersect_closest)",
                ))
            }
            (Root::Gas(gas), DeviceResults::Closest(h, _)) => gas.intersect_device(&batch.rays, h),
            (Root::Gas(gas), DeviceResults::Any(o)) => gas.occluded_device(&batch.rays, o),
            (Root::Ias(ias), DeviceResults::Closest(h, i)) => {
                ias.intersect_device(&batch.rays.words, &mut h.words, i, n)
            }
            (Root::Ias(ias), DeviceResults::Any(o)) => {
                ias.occluded_device(&batch.rays.words, &mut o.bytes, n)
            }
        }
        .map_err(query_error)?;
        batch.traced = Some(root.clone());
        Ok(())
    }

    fn download_hits(&self, batch: &CudaBatch, hits: &mut [Option<Hit>]) -> Result<(), QueryError> {
        let DeviceResults::Closest(h, insts) = &batch.results else {
            return Err(QueryError::WrongBatchKind("occlusion"));
        };
        if hits.len() != h.len() {
            return Err(QueryError::LengthMismatch {
                rays: h.len(),
                outputs: hits.len(),
            });
        }
        let traced = match &batch.traced {
            Some(t) => self.root(t)?,
            None => Root::Null,
        };
        let records = h.download(&self.ctx).map_err(query_error)?;
        match traced {
            Root::Gas(gas) => gas.resolve_into(&records, hits),
            Root::Ias(ias) => {
                let mut slots = vec![0u32; h.len()];
                if !slots.is_empty() {
                    self.ctx
                        .stream
                        .memcpy_dtoh(&insts.slice(..h.len()), &mut slots[..])
                        .map_err(|e| QueryError::Device(e.to_string()))?;
                    self.ctx.synchronize().map_err(query_error)?;
                }
                ias.resolve_into(&records, &slots, hits);
            }
            Root::Null => {
                return Err(QueryError::Unsupported(
                    "downloading the hits of a batch that was never traced",
                ))
            }
        }
        Ok(())
    }

    fn download_occlusion(
        &self,
        batch: &CudaBatch,
        occluded: &mut [bool],
    ) -> Result<(), QueryError> {
        let DeviceResults::Any(o) = &batch.results else {
            return Err(QueryError::WrongBatchKind("closest-hit"));
        };
        let flags = o.download(&self.ctx).map_err(query_error)?;
        if flags.len() != occluded.len() {
            return Err(QueryError::LengthMismatch {
                rays: flags.len(),
                outputs: occluded.len(),
            });
        }
        occluded.copy_from_slice(&flags);
        Ok(())
    }
}
