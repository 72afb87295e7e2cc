//! The instance acceleration structure (guide §5.4): instances of traversables under a BVH of
//! their world-space boxes.

use crate::gas::CpuNode;
use oxray_bvh::{build_bvh2, BuildConfig, Bvh4, BvhStats};
use oxray_core::{
    Aabb, BackendKind, BuildError, BuildFlags, BuildInput, BuildOperation, BuildOptions, Instance,
    InstanceFlags, Transform, Traversable, TraversableHandle, TraversableKind,
    MAX_INSTANCES_PER_IAS, MAX_INSTANCE_ID, MAX_SBT_OFFSET, MAX_TRAVERSABLE_GRAPH_DEPTH,
};
use rayon::prelude::*;

/// What the structure keeps of an instance.
#[derive(Clone, Debug)]
pub(crate) struct InstanceRecord {
    pub object_to_world: Transform,
    pub world_to_object: Transform,
    pub instance_id: u32,
    pub sbt_offset: u32,
    pub mask: u8,
    pub flags: InstanceFlags,
    /// The child as the user gave it (for `optixGetInstanceTraversableFromIAS`).
    pub child: TraversableHandle,
    /// The child resolved to a CPU object; `None` for the null handle.
    pub node: Option<CpuNode>,
    /// Position in the build input (`optixGetInstanceIndex`).
    pub index: u32,
}

/// An instance acceleration structure (IAS). It keeps every child it references alive.
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
    pub(crate) bvh: Bvh4,
    /// Instances in leaf-slot order.
    pub(crate) instances: Vec<InstanceRecord>,
    /// World boxes in leaf-slot order.
    pub(crate) boxes: Vec<Aabb>,
    /// Leaf slot of every instance, by input index (for random instance access).
    pub(crate) slot_of: Vec<u32>,
    pub(crate) bounds: Aabb,
    pub(crate) build_flags: BuildFlags,
    pub(crate) num_instances: u32,
    pub(crate) depth: u32,
}

fn validate_instance(i: u32, inst: &Instance) -> Result<Transform, BuildError> {
    if inst.instance_id > MAX_INSTANCE_ID {
        return Err(BuildError::field(i, "instance_id", inst.instance_id, 28));
    }
    if inst.sbt_offset > MAX_SBT_OFFSET {
        return Err(BuildError::field(i, "sbt_offset", inst.sbt_offset, 28));
    }
    if inst.visibility_mask > 0xFF {
        return Err(BuildError::field(
            i,
            "visibility_mask",
            inst.visibility_mask,
            8,
        ));
    }
    if inst
        .flags
        .contains(InstanceFlags::DISABLE_ANYHIT | InstanceFlags::ENFORCE_ANYHIT)
    {
        return Err(BuildError::ConflictingInstanceFlags { instance: i });
    }
    let depth = 1 + inst.child.graph_depth();
    if depth > MAX_TRAVERSABLE_GRAPH_DEPTH {
        return Err(BuildError::GraphTooDeep {
            depth,
            limit: MAX_TRAVERSABLE_GRAPH_DEPTH,
        });
    }
    inst.transform
        .inverse()
        .ok_or(BuildError::InvalidTransform { instance: Some(i) })
}

impl Ias {
    /// Builds an IAS from exactly one instance build input (guide §5.4). Instance fields with
    /// bits above their limits, singular transforms and graphs deeper than 31 levels are
    /// refused. Instances of the null handle, or of empty structures, are never hit.
    pub fn build(options: &BuildOptions, inputs: &[BuildInput<'_>]) -> Result<Ias, BuildError> {
        if options
            .flags
            .contains(BuildFlags::PREFER_FAST_TRACE | BuildFlags::PREFER_FAST_BUILD)
        {
            return Err(BuildError::ConflictingBuildFlags);
        }
        if options.operation == BuildOperation::Update {
            return Err(BuildError::Unsupported("BuildOperation::Update"));
        }
        let [input] = inputs else {
            return Err(BuildError::IasInputCount {
                count: inputs.len(),
            });
        };
        let list: Vec<&Instance> = match input {
            BuildInput::Instances(i) => i.iter().collect(),
            BuildInput::InstancePointers(i) => i.to_vec(),
            other => {
                return Err(BuildError::NotInstances {
                    found: other.kind(),
                })
            }
        };
        if list.len() as u64 > MAX_INSTANCES_PER_IAS {
            return Err(BuildError::TooManyInstances {
                count: list.len() as u64,
                limit: MAX_INSTANCES_PER_IAS,
            });
        }
        let records: Vec<InstanceRecord> = list
            .par_iter()
            .enumerate()
            .map(|(i, inst)| {
                let inverse = validate_instance(i as u32, inst)?;
                let node = CpuNode::resolve(&inst.child).map_err(|found| {
                    BuildError::ForeignTraversable {
                        instance: i as u32,
                        device: BackendKind::Cpu,
                        found,
                    }
                })?;
                Ok(InstanceRecord {
                    object_to_world: inst.transform,
                    world_to_object: inverse,
                    instance_id: inst.instance_id,
                    sbt_offset: inst.sbt_offset,
                    mask: inst.visibility_mask as u8,
                    flags: inst.flags,
                    child: inst.child.clone(),
                    node,
                    index: i as u32,
                })
            })
            .collect::<Vec<Result<_, BuildError>>>()
            .into_iter()
            .collect::<Result<_, _>>()?;
        let depth = 1 + records
            .iter()
            .map(|r| r.child.graph_depth())
            .max()
            .unwrap_or(0);

        let world: Vec<Option<Aabb>> = records
            .par_iter()
            .map(|r| {
                let b = r.object_to_world.transform_aabb(&r.child.bounds());
                b.is_finite_valid().then_some(b)
            })
            .collect();
        let (ids, boxes): (Vec<u32>, Vec<Aabb>) = world
            .iter()
            .enumerate()
            .filter_map(|(i, b)| b.map(|b| (i as u32, b)))
            .unzip();
        let config = BuildConfig {
            block_size: 1,
            max_leaf_size: 2,
            ..if options.flags.contains(BuildFlags::PREFER_FAST_TRACE) {
                BuildConfig::FAST_TRACE
            } else if options.flags.contains(BuildFlags::PREFER_FAST_BUILD) {
                BuildConfig::FAST_BUILD
            } else {
                BuildConfig::BALANCED
            }
        };
        let bvh2 = build_bvh2(&boxes, &config);
        let bounds = bvh2.nodes.first().map_or(Aabb::EMPTY, |n| n.bounds());
        let bvh = Bvh4::from(&bvh2);
        let order: Vec<u32> = bvh2.prim_order.iter().map(|&k| ids[k as usize]).collect();
        let mut slot_of = vec![u32::MAX; records.len()];
        for (slot, &i) in order.iter().enumerate() {
            slot_of[i as usize] = slot as u32;
        }
        let instances = order.iter().map(|&i| records[i as usize].clone()).collect();
        let boxes = order
            .iter()
            .map(|&i| world[i as usize].unwrap_or(Aabb::EMPTY))
            .collect();
        Ok(Ias {
            bvh,
            instances,
            boxes,
            slot_of,
            bounds,
            build_flags: options.flags,
            num_instances: list.len() as u32,
            depth,
        })
    }

    /// Instances in the build input.
    pub fn num_instances(&self) -> u32 {
        self.num_instances
    }

    /// The world box of every instance that can be hit.
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// The flags it was built with.
    pub fn build_flags(&self) -> BuildFlags {
        self.build_flags
    }

    /// The BVH over the instances.
    pub fn bvh(&self) -> &Bvh4 {
        &self.bvh
    }

    /// BVH statistics.
    pub fn stats(&self) -> BvhStats {
        self.bvh.stats()
    }

    /// Levels of the traversable graph from this IAS down (an IAS over GASes is 2).
    pub fn graph_depth(&self) -> u32 {
        self.depth
    }

    /// The child of instance `index` (`optixGetInstanceTraversableFromIAS`); needs
    /// `ALLOW_RANDOM_INSTANCE_ACCESS`. `None` for an index out of range, an instance that is
    /// never hit (null or empty child), or without the flag.
    pub fn instance_child(&self, index: u32) -> Option<&TraversableHandle> {
        if !self
            .build_flags
            .contains(BuildFlags::ALLOW_RANDOM_INSTANCE_ACCESS)
        {
            return None;
        }
        let slot = *self.slot_of.get(index as usize)?;
        self.instances.get(slot as usize).map(|r| &r.child)
    }
}

impl Traversable for Ias {
    fn traversable_kind(&self) -> TraversableKind {
        TraversableKind::Ias
    }

    fn bounds(&self) -> Aabb {
        self.bounds
    }

    fn graph_depth(&self) -> u32 {
        self.depth
    }

    fn backend(&self) -> BackendKind {
        BackendKind::Cpu
    }

    fn describe(&self) -> String {
        format!("CPU IAS of {} instances", self.num_instances)
    }
}
