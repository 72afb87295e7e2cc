//! The CPU backend's instance acceleration structure: the backend-neutral [`IasData`] with
//! every child resolved to a CPU structure.

use crate::gas::CpuNode;
use oxray_bvh::IasData;
use oxray_core::{
    Aabb, BackendKind, BuildError, BuildInput, BuildOptions, Traversable, TraversableKind,
};

/// An instance acceleration structure (IAS) in host memory. It keeps every child it references
/// alive; the built data ([`IasData`]: instances, world boxes, BVH) is reachable through
/// `Deref`.
///
/// ```
/// use oxray_cpu::{Gas, Ias};
/// use oxray_core::{BuildOptions, Instance, Ray, Transform, TriangleInput, VertexBuffer};
/// use glam::Vec3;
/// use std::sync::Arc;
/// let v = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
/// let gas = Arc::new(Gas::build(&BuildOptions::default(), &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?);
/// let instances: Vec<Instance> = (0..3)
///     .map(|i| Instance::new(gas.clone().into())
///         .transform(Transform::from_translation(Vec3::new(0.0, 0.0, i as f32)))
///         .instance_id(10 + i))
///     .collect();
/// let ias = Ias::build(&BuildOptions::default(), &[(&instances[..]).into()])?;
/// let hit = ias.intersect(&Ray::new(Vec3::new(0.0, 0.0, 5.0), -Vec3::Z)).unwrap();
/// assert_eq!((hit.t, hit.instance_id, hit.instance_index), (3.0, 12, 2));
/// # Ok::<(), oxray_core::BuildError>(())
/// ```
#[derive(Clone, Debug)]
pub struct Ias {
    data: IasData,
    /// The child of every instance slot resolved to a CPU object; `None` for the null handle.
    pub(crate) nodes: Vec<Option<CpuNode>>,
    /// Whether every child is a GAS (or the null handle): the graph that
    /// `ALLOW_SINGLE_LEVEL_INSTANCING` allows, which every trace from such a pipeline checks.
    pub(crate) single_level: bool,
    /// Whether closest points can be answered under it (checked on first use, again after an
    /// update): `simulation::instanced`.
    pub(crate) closest_support: std::sync::OnceLock<Result<(), crate::SurfaceQueryError>>,
}

impl Ias {
    /// Builds an IAS from exactly one instance build input (guide §5.4). Instance fields with
    /// bits above their limits, singular transforms and graphs deeper than 31 levels are
    /// refused, and so are children on another device. Instances of the null handle, or of
    /// empty structures, are never hit.
    pub fn build(options: &BuildOptions, inputs: &[BuildInput<'_>]) -> Result<Ias, BuildError> {
        Self::from_data(IasData::build(options, inputs)?)
    }

    /// Wraps built (or loaded) IAS data, resolving every child to a CPU structure; a child on
    /// another device is refused.
    pub fn from_data(data: IasData) -> Result<Ias, BuildError> {
        let nodes = resolve_children(&data)?;
        Ok(Ias {
            data,
            single_level: single_level(&nodes),
            nodes,
            closest_support: Default::default(),
        })
    }

    /// Updates (refits) the IAS in place (guide §5.6); see [`IasData::update`]. The children
    /// may be updates of the structures it was built over (new objects of the same lineage).
    pub fn update(
        &mut self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(), BuildError> {
        self.data.update(options, inputs)?;
        // The children are the same structures or updates of them: of this backend.
        self.nodes = resolve_children(&self.data)?;
        self.single_level = single_level(&self.nodes);
        self.closest_support = Default::default();
        Ok(())
    }

    /// The built data.
    #[must_use]
    pub fn data(&self) -> &IasData {
        &self.data
    }
}

fn resolve_children(data: &IasData) -> Result<Vec<Option<CpuNode>>, BuildError> {
    data.instances
        .iter()
        .map(|inst| {
            CpuNode::resolve(&inst.child).map_err(|found| BuildError::ForeignTraversable {
                instance: inst.index,
                device: BackendKind::Cpu,
                found,
            })
        })
        .collect()
}

impl std::ops::Deref for Ias {
    type Target = IasData;

    fn deref(&self) -> &IasData {
        &self.data
    }
}

impl Traversable for Ias {
    fn traversable_kind(&self) -> TraversableKind {
        TraversableKind::Ias
    }

    fn bounds(&self) -> Aabb {
        self.data.bounds
    }

    fn graph_depth(&self) -> u32 {
        self.data.depth
    }

    fn backend(&self) -> BackendKind {
        BackendKind::Cpu
    }

    fn describe(&self) -> String {
        format!("CPU IAS of {} instances", self.data.num_instances)
    }

    fn lineage(&self) -> Option<u64> {
        Some(self.data.lineage)
    }
}

/// Whether every child is a GAS or the null handle (one level of instancing).
fn single_level(nodes: &[Option<CpuNode>]) -> bool {
    nodes
        .iter()
        .all(|n| matches!(n, None | Some(CpuNode::Gas(_))))
}
