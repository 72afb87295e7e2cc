//! The CUDA backend behind the facade's `Device`: GASes built on the host by the shared
//! builders of `oxray-bvh`, uploaded in the kernels' node layout, and traced by the batch
//! kernels.

use crate::context::CudaContext;
use crate::error::CudaError;
use crate::gas::{CudaGas, DeviceHits, DeviceOcclusion, DeviceRays};
use crate::layout::NodeLayout;
use oxray_bvh::{GasData, GasKind};
use oxray_core::{
    Aabb, AccelBackend, BackendKind, BatchKind, BuildError, BuildInput, BuildOptions, Hit,
    QueryError, Ray, Traversable, TraversableHandle, TraversableKind,
};

/// The CUDA backend: one device, its compiled kernels and a node layout for the GASes it
/// builds.
#[derive(Clone, Debug)]
pub struct Cuda {
    ctx: CudaContext,
    layout: NodeLayout,
}

impl Cuda {
    /// Opens device `ordinal` and compiles the kernels; an error for which
    /// [`CudaError::is_unavailable`] holds where this machine has no CUDA.
    pub fn new(ordinal: usize) -> Result<Cuda, CudaError> {
        Ok(Cuda {
            ctx: CudaContext::with_device(ordinal)?,
            layout: NodeLayout::default(),
        })
    }

    /// The backend of an open context (the GASes it builds use the default layout).
    pub fn from_context(ctx: CudaContext) -> Cuda {
        Cuda {
            ctx,
            layout: NodeLayout::default(),
        }
    }

    /// The same device, building GASes in `layout` from now on.
    pub fn with_layout(mut self, layout: NodeLayout) -> Self {
        self.layout = layout;
        self
    }

    /// The device context.
    pub fn context(&self) -> &CudaContext {
        &self.ctx
    }
}

/// An instance acceleration structure on the CUDA backend. The batch kernels trace single GASes
/// for now, so none can be built ([`Cuda::build_ias`] refuses with `Unsupported`); the type
/// exists so that the backend boundary is whole.
#[derive(Debug)]
pub enum CudaIas {}

impl Traversable for CudaIas {
    fn traversable_kind(&self) -> TraversableKind {
        match *self {}
    }
    fn bounds(&self) -> Aabb {
        match *self {}
    }
    fn graph_depth(&self) -> u32 {
        match *self {}
    }
    fn backend(&self) -> BackendKind {
        match *self {}
    }
    fn describe(&self) -> String {
        match *self {}
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
    Closest(DeviceHits),
    Any(DeviceOcclusion),
}

fn query_error(e: CudaError) -> QueryError {
    match e {
        CudaError::LengthMismatch { rays, outputs } => QueryError::LengthMismatch { rays, outputs },
        other => QueryError::Device(other.to_string()),
    }
}

fn build_error(e: CudaError) -> BuildError {
    BuildError::Device(e.to_string())
}

impl Cuda {
    /// The GAS a query starts at: `Ok(None)` for the null handle.
    fn root<'h>(&self, handle: &'h TraversableHandle) -> Result<Option<&'h CudaGas>, QueryError> {
        match (handle.backend(), handle.downcast_ref::<CudaGas>()) {
            (None, _) => Ok(None),
            (_, Some(gas)) => Ok(Some(gas)),
            (Some(BackendKind::Cuda), None) => Err(QueryError::Unsupported(
                "tracing an instance or transform on the CUDA backend",
            )),
            (Some(found), None) => Err(QueryError::ForeignTraversable {
                device: BackendKind::Cuda,
                found,
            }),
        }
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
        let (data, tree) = GasData::build_with_tree(options, inputs)?;
        if data.kind == GasKind::CustomPrimitives {
            return Err(BuildError::Unsupported(
                "custom primitives on the CUDA backend (their intersection programs run on the CPU backend)",
            ));
        }
        CudaGas::upload_with_layout(&self.ctx, &data, &tree, self.layout).map_err(build_error)
    }

    fn build_ias(
        &self,
        _options: &BuildOptions,
        _inputs: &[BuildInput<'_>],
    ) -> Result<CudaIas, BuildError> {
        Err(BuildError::Unsupported(
            "instance acceleration structures on the CUDA backend",
        ))
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
            None => hits.fill(None),
            Some(gas) => gas.intersect_batch_into(rays, hits).map_err(query_error)?,
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
            None => occluded.fill(false),
            Some(gas) => gas
                .occluded_batch_into(rays, occluded)
                .map_err(query_error)?,
        }
        Ok(())
    }

    fn upload_batch(&self, rays: &[Ray], kind: BatchKind) -> Result<CudaBatch, QueryError> {
        let d_rays = DeviceRays::upload(&self.ctx, rays).map_err(query_error)?;
        let results = match kind {
            BatchKind::Closest => {
                DeviceResults::Closest(DeviceHits::new(&self.ctx, rays.len()).map_err(query_error)?)
            }
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
        let Some(gas) = self.root(root)? else {
            return Err(QueryError::Unsupported(
                "a resident batch on the null handle (every ray misses; use intersect_closest)",
            ));
        };
        match &mut batch.results {
            DeviceResults::Closest(h) => gas.intersect_device(&batch.rays, h),
            DeviceResults::Any(o) => gas.occluded_device(&batch.rays, o),
        }
        .map_err(query_error)?;
        batch.traced = Some(root.clone());
        Ok(())
    }

    fn download_hits(&self, batch: &CudaBatch, hits: &mut [Option<Hit>]) -> Result<(), QueryError> {
        let DeviceResults::Closest(h) = &batch.results else {
            return Err(QueryError::WrongBatchKind("occlusion"));
        };
        if hits.len() != h.len() {
            return Err(QueryError::LengthMismatch {
                rays: h.len(),
                outputs: hits.len(),
            });
        }
        let Some(gas) = batch
            .traced
            .as_ref()
            .and_then(|t| t.downcast_ref::<CudaGas>())
        else {
            return Err(QueryError::Unsupported(
                "downloading the hits of a batch that was never traced",
            ));
        };
        let records = h.download(&self.ctx).map_err(query_error)?;
        gas.resolve_into(&records, hits);
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
