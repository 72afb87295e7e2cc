//! The instance acceleration structure as data (guide §5.4): validated instances in leaf-slot
//! order, their world boxes, and the BVH over them, whatever backend traverses it.

use crate::build::{build_bvh2, BuildConfig};
use crate::bvh2::Bvh2;
use crate::bvh4::Bvh4;
use crate::stats::BvhStats;
use oxray_core::{
    Aabb, BuildError, BuildFlags, BuildInput, BuildOperation, BuildOptions, Instance,
    InstanceFlags, Transform, TraversableHandle, MAX_INSTANCES_PER_IAS, MAX_INSTANCE_ID,
    MAX_SBT_OFFSET, MAX_TRAVERSABLE_GRAPH_DEPTH,
};
use rayon::prelude::*;

/// What an IAS keeps of an instance.
#[derive(Clone, Debug)]
pub struct InstanceData {
    /// Object-to-world transform.
    pub object_to_world: Transform,
    /// World-to-object transform (computed, not trusted from the caller).
    pub world_to_object: Transform,
    /// User id (`optixGetInstanceId`).
    pub instance_id: u32,
    /// Added to the hit-group index of everything below.
    pub sbt_offset: u32,
    /// Visibility mask.
    pub mask: u8,
    /// Flags.
    pub flags: InstanceFlags,
    /// The child as the user gave it (for `optixGetInstanceTraversableFromIAS`); it keeps the
    /// child alive.
    pub child: TraversableHandle,
    /// Position in the build input (`optixGetInstanceIndex`).
    pub index: u32,
}

/// A built instance acceleration structure as data: backends wrap it with what they need to
/// reach the children (the CPU backend resolves them to its own structures; the CUDA backend
/// uploads a table of device pointers).
///
/// ```
/// use oxray_bvh::IasData;
/// use oxray_core::{BuildOptions, Instance, Transform, TraversableHandle};
/// use glam::Vec3;
/// let instances = [Instance::new(TraversableHandle::NULL).transform(Transform::from_translation(Vec3::X))];
/// let ias = IasData::build(&BuildOptions::default(), &[(&instances[..]).into()])?;
/// assert_eq!((ias.num_instances, ias.depth), (1, 1));
/// assert!(ias.bvh.nodes.len() >= 1);
/// # Ok::<(), oxray_core::BuildError>(())
/// ```
#[derive(Clone, Debug)]
pub struct IasData {
    /// The 4-wide BVH over the instances' world boxes; leaves point at instance slots.
    pub bvh: Bvh4,
    /// Instances in leaf-slot order.
    pub instances: Vec<InstanceData>,
    /// World boxes in leaf-slot order.
    pub boxes: Vec<Aabb>,
    /// Leaf slot of every instance, by input index (for random instance access).
    pub slot_of: Vec<u32>,
    /// The world box of every instance that can be hit.
    pub bounds: Aabb,
    /// The flags it was built with.
    pub build_flags: BuildFlags,
    /// Instances in the build input.
    pub num_instances: u32,
    /// Levels of the traversable graph from this IAS down (an IAS over GASes is 2).
    pub depth: u32,
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

impl IasData {
    /// Builds an IAS from exactly one instance build input (guide §5.4). Instance fields with
    /// bits above their limits, singular transforms and graphs deeper than 31 levels are
    /// refused. Instances of the null handle, or of empty structures, are never hit.
    pub fn build(options: &BuildOptions, inputs: &[BuildInput<'_>]) -> Result<IasData, BuildError> {
        Ok(Self::build_with_tree(options, inputs)?.0)
    }

    /// [`build`](Self::build), also returning the canonical binary tree over the instance slots
    /// (the tree other traversal layouts are derived from).
    pub fn build_with_tree(
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(IasData, Bvh2), BuildError> {
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
        let records: Vec<InstanceData> = list
            .par_iter()
            .enumerate()
            .map(|(i, inst)| {
                let inverse = validate_instance(i as u32, inst)?;
                Ok(InstanceData {
                    object_to_world: inst.transform,
                    world_to_object: inverse,
                    instance_id: inst.instance_id,
                    sbt_offset: inst.sbt_offset,
                    mask: inst.visibility_mask as u8,
                    flags: inst.flags,
                    child: inst.child.clone(),
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
        let mut bvh2 = build_bvh2(&boxes, &config);
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
        let data = IasData {
            bvh,
            instances,
            boxes,
            slot_of,
            bounds,
            build_flags: options.flags,
            num_instances: list.len() as u32,
            depth,
        };
        // The tree's slots are the structure's: instances are not packed.
        bvh2.prim_order = Vec::new();
        Ok((data, bvh2))
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
