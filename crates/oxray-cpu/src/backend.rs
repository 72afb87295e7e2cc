//! The CPU backend behind the facade's `Device`: builds in host memory, batched queries on the
//! current rayon pool.

use crate::query::{any_batch, closest_batch};
use crate::traversal::NodeRef;
use crate::{Gas, Ias, Isa};
use oxray_core::{
    AccelBackend, BackendKind, BatchKind, BuildError, BuildInput, BuildOptions, Hit, QueryError,
    Ray, TraversableHandle,
};
use std::sync::Arc;

/// The CPU backend: all cores of the current rayon pool.
///
/// ```
/// use oxray_cpu::Cpu;
/// use oxray_core::{AccelBackend, BuildOptions, Ray, TraversableHandle, TriangleInput, VertexBuffer};
/// use glam::Vec3;
/// let cpu = Cpu::new();
/// let v = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
/// let gas = cpu.build_gas(&BuildOptions::default(), &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
/// let root = TraversableHandle::from(gas);
/// let rays = [Ray::new(Vec3::Z, -Vec3::Z), Ray::new(Vec3::Z, Vec3::Z)];
/// let mut hits = [None; 2];
/// cpu.intersect_closest(&root, &rays, &mut hits)?;
/// assert_eq!((hits[0].map(|h| h.t), hits[1]), (Some(1.0), None));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Copy, Debug)]
pub struct Cpu {
    /// The kernel of the structures it builds.
    isa: Isa,
}

impl Cpu {
    /// The CPU backend, with the process's traversal kernel: the best the processor has, or the
    /// one `OXRAY_CPU_ISA` forces ([`Isa::selected`]).
    #[must_use]
    pub fn new() -> Self {
        Cpu {
            isa: Isa::selected(),
        }
    }

    /// The CPU backend with the traversal kernel `isa`, clamped to what the processor has
    /// ([`Isa::clamp`]).
    #[must_use]
    pub fn with_isa(isa: Isa) -> Self {
        Cpu { isa: isa.clamp() }
    }

    /// The traversal kernel of the structures it builds.
    #[must_use]
    pub fn isa(&self) -> Isa {
        self.isa
    }
}

impl Default for Cpu {
    fn default() -> Self {
        Cpu::new()
    }
}

/// A batch of rays and their results in host memory.
#[derive(Clone, Debug)]
pub struct CpuBatch {
    rays: Vec<Ray>,
    results: Results,
}

#[derive(Clone, Debug)]
enum Results {
    Closest(Vec<Option<Hit>>),
    Any(Vec<bool>),
}

/// The root of a query on the CPU: `Ok(None)` for the null handle.
fn root(handle: &TraversableHandle) -> Result<Option<NodeRef<'_>>, QueryError> {
    match (handle.backend(), NodeRef::of(handle)) {
        (None, _) => Ok(None),
        (Some(_), Some(node)) => Ok(Some(node)),
        (Some(found), None) => Err(QueryError::ForeignTraversable {
            device: BackendKind::Cpu,
            found,
        }),
    }
}

impl AccelBackend for Cpu {
    type Gas = Gas;
    type Ias = Ias;
    type Batch = CpuBatch;

    fn kind(&self) -> BackendKind {
        BackendKind::Cpu
    }

    fn describe(&self) -> String {
        format!("CPU ({} threads)", rayon::current_num_threads())
    }

    fn update_gas(
        &self,
        gas: &mut Arc<Gas>,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(), BuildError> {
        if Arc::get_mut(gas).is_none() {
            // Checked before the copy, so that a refused update copies nothing.
            gas.check_update(options, inputs)?;
        }
        Arc::make_mut(gas).update(options, inputs)
    }

    fn update_ias(
        &self,
        ias: &mut Arc<Ias>,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(), BuildError> {
        if Arc::get_mut(ias).is_none() {
            ias.check_update(options, inputs)?;
        }
        Arc::make_mut(ias).update(options, inputs)
    }

    fn build_gas(
        &self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<Gas, BuildError> {
        Gas::build_with_isa(self.isa, options, inputs)
    }

    fn build_ias(
        &self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<Ias, BuildError> {
        Ias::build(options, inputs)
    }

    fn intersect_closest(
        &self,
        root_handle: &TraversableHandle,
        rays: &[Ray],
        hits: &mut [Option<Hit>],
    ) -> Result<(), QueryError> {
        closest_batch(root(root_handle)?, rays, hits)
    }

    fn intersect_any(
        &self,
        root_handle: &TraversableHandle,
        rays: &[Ray],
        occluded: &mut [bool],
    ) -> Result<(), QueryError> {
        any_batch(root(root_handle)?, rays, occluded)
    }

    fn upload_batch(&self, rays: &[Ray], kind: BatchKind) -> Result<CpuBatch, QueryError> {
        let results = match kind {
            BatchKind::Closest => Results::Closest(vec![None; rays.len()]),
            BatchKind::Any => Results::Any(vec![false; rays.len()]),
        };
        Ok(CpuBatch {
            rays: rays.to_vec(),
            results,
        })
    }

    fn run_batch(
        &self,
        root_handle: &TraversableHandle,
        batch: &mut CpuBatch,
    ) -> Result<(), QueryError> {
        let root = root(root_handle)?;
        match &mut batch.results {
            Results::Closest(hits) => closest_batch(root, &batch.rays, hits),
            Results::Any(occluded) => any_batch(root, &batch.rays, occluded),
        }
    }

    fn download_hits(&self, batch: &CpuBatch, hits: &mut [Option<Hit>]) -> Result<(), QueryError> {
        let Results::Closest(h) = &batch.results else {
            return Err(QueryError::WrongBatchKind("occlusion"));
        };
        copy_out(h, hits)
    }

    fn download_occlusion(
        &self,
        batch: &CpuBatch,
        occluded: &mut [bool],
    ) -> Result<(), QueryError> {
        let Results::Any(o) = &batch.results else {
            return Err(QueryError::WrongBatchKind("closest-hit"));
        };
        copy_out(o, occluded)
    }
}

fn copy_out<T: Copy>(src: &[T], dst: &mut [T]) -> Result<(), QueryError> {
    if src.len() != dst.len() {
        return Err(QueryError::LengthMismatch {
            rays: src.len(),
            outputs: dst.len(),
        });
    }
    dst.copy_from_slice(src);
    Ok(())
}
