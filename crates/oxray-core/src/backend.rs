//! The boundary between the facade and a backend: building acceleration structures and running
//! batched queries, one call per batch (never per ray).
//!
//! Inputs arrive validated by [`validate`](crate::validate), so backends may trust them. A
//! backend grows one capability at a time: what it cannot do it refuses with a typed
//! `Unsupported` error, never by silently falling back to another device.

use crate::error::{BuildError, QueryError};
use crate::handle::{BackendKind, Traversable, TraversableHandle};
use crate::hit::Hit;
use crate::input::BuildInput;
use crate::options::BuildOptions;
use crate::ray::Ray;

/// Which query a resident batch runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BatchKind {
    /// The closest hit of every ray.
    Closest,
    /// Whether anything lies in every ray's interval (traversal stops at the first hit).
    Any,
}

/// Acceleration structures and batched ray queries on one device.
pub trait AccelBackend: Send + Sync + 'static {
    /// A geometry acceleration structure in this backend's memory.
    type Gas: Traversable;
    /// An instance acceleration structure in this backend's memory.
    type Ias: Traversable;
    /// Rays and room for their results, resident in this backend's memory between queries.
    type Batch: Send;

    /// Which backend this is.
    fn kind(&self) -> BackendKind;

    /// One line naming the device (for example `CPU (16 threads)`).
    fn describe(&self) -> String;

    /// Builds a GAS from validated inputs (`optixAccelBuild`).
    fn build_gas(
        &self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<Self::Gas, BuildError>;

    /// Builds an IAS from one instance build input.
    fn build_ias(
        &self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<Self::Ias, BuildError>;

    /// Updates (refits) a GAS built with `ALLOW_UPDATE` (guide §5.6) with new buffer
    /// contents: in place where `gas` is the structure's only owner, else on a copy that `gas`
    /// then refers to (copy-on-write), so that what shares the old structure (an IAS over it,
    /// a trace in flight) keeps it until it is updated in turn. Backends that cannot update
    /// refuse with `Unsupported`.
    fn update_gas(
        &self,
        gas: &mut std::sync::Arc<Self::Gas>,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(), BuildError> {
        let _ = (gas, options, inputs);
        Err(BuildError::Unsupported("updating a GAS on this backend"))
    }

    /// Updates (refits) an IAS built with `ALLOW_UPDATE` (guide §5.6), as
    /// [`update_gas`](Self::update_gas) does a GAS.
    fn update_ias(
        &self,
        ias: &mut std::sync::Arc<Self::Ias>,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(), BuildError> {
        let _ = (ias, options, inputs);
        Err(BuildError::Unsupported("updating an IAS on this backend"))
    }

    /// The closest hit of every ray under `root`, or `None`.
    fn intersect_closest(
        &self,
        root: &TraversableHandle,
        rays: &[Ray],
        hits: &mut [Option<Hit>],
    ) -> Result<(), QueryError>;

    /// Whether anything lies in every ray's interval under `root`.
    fn intersect_any(
        &self,
        root: &TraversableHandle,
        rays: &[Ray],
        occluded: &mut [bool],
    ) -> Result<(), QueryError>;

    /// Copies rays into this backend's memory, with room for the results of a `kind` query.
    fn upload_batch(&self, rays: &[Ray], kind: BatchKind) -> Result<Self::Batch, QueryError>;

    /// Runs the batch's query under `root`, leaving the results in the batch.
    fn run_batch(
        &self,
        root: &TraversableHandle,
        batch: &mut Self::Batch,
    ) -> Result<(), QueryError>;

    /// Copies the results of a [`BatchKind::Closest`] batch out.
    fn download_hits(
        &self,
        batch: &Self::Batch,
        hits: &mut [Option<Hit>],
    ) -> Result<(), QueryError>;

    /// Copies the results of a [`BatchKind::Any`] batch out.
    fn download_occlusion(
        &self,
        batch: &Self::Batch,
        occluded: &mut [bool],
    ) -> Result<(), QueryError>;
}
