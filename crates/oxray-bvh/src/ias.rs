//! The instance acceleration structure as data (guide §5.4): validated instances in leaf-slot
//! order, their world boxes, and the BVH over them, whatever backend traverses it.

use crate::build::{build_bvh2, BuildConfig};
use crate::bvh2::Bvh2;
use crate::bvh4::Bvh4;
use crate::stats::BvhStats;
use oxray_core::{
    Aabb, BuildError, BuildFlags, BuildInput, BuildInputKind, BuildOperation, BuildOptions,
    Instance, InstanceFlags, Transform, TraversableHandle, UpdateRule, MAX_INSTANCES_PER_IAS,
    MAX_INSTANCE_ID, MAX_SBT_OFFSET, MAX_TRAVERSABLE_GRAPH_DEPTH,
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
    /// The type of the build input (instances or instance pointers), which an update must
    /// repeat.
    pub input_kind: BuildInputKind,
    /// The structure's identity across updates and compaction (see
    /// [`Traversable::lineage`](oxray_core::Traversable::lineage)).
    pub lineage: u64,
    /// The build's motion options (guide §5.10.3): they change which instances can be hit
    /// only through the vanish flags, which hide every instance outside the IAS's time range.
    /// The tree's boxes bound the instances at every time (their children's bounds do).
    pub motion: oxray_core::MotionOptions,
}

pub(crate) fn validate_instance(i: u32, inst: &Instance) -> Result<Transform, BuildError> {
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

/// The instances of the single instance input of an IAS build or update.
fn instance_list<'a>(inputs: &'a [BuildInput<'a>]) -> Result<Vec<&'a Instance>, BuildError> {
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
    Ok(list)
}

/// Leaf size of the top-level trees: an instance costs a ray transform, so leaves stay small.
pub const IAS_MAX_LEAF: u32 = 2;

/// An IAS build between validation and its tree ([`IasData::prepare`]).
#[derive(Debug)]
pub struct PreparedIas {
    records: Vec<InstanceData>,
    world: Vec<Option<Aabb>>,
    ids: Vec<u32>,
    /// The boxes the tree is built over, each finite and valid: the world box of every
    /// instance that can be hit (with `ALLOW_UPDATE` or `ALLOW_RANDOM_INSTANCE_ACCESS`, every
    /// instance: a point at the centre of the others for those that cannot be hit yet).
    pub boxes: Vec<Aabb>,
    keep_inactive: bool,
    depth: u32,
    options: BuildOptions,
    num_instances: u32,
    input_kind: BuildInputKind,
}

impl PreparedIas {
    /// The structure over `tree`, a binary tree over [`boxes`](Self::boxes) whose
    /// `prim_order` maps each leaf slot to the index of its box (every box once). Returns the
    /// tree too, its leaves now pointing at the structure's instance slots.
    #[must_use]
    pub fn finish(self, mut tree: Bvh2) -> (IasData, Bvh2) {
        let PreparedIas {
            records,
            world,
            ids,
            boxes: _,
            keep_inactive,
            depth,
            options,
            num_instances,
            input_kind,
        } = self;
        let bounds = tree.nodes.first().map_or(Aabb::EMPTY, |n| n.bounds());
        let bvh = Bvh4::from(&tree);
        let order: Vec<u32> = tree.prim_order.iter().map(|&k| ids[k as usize]).collect();
        let mut slot_of = vec![u32::MAX; records.len()];
        for (slot, &i) in order.iter().enumerate() {
            slot_of[i as usize] = slot as u32;
        }
        let instances = order.iter().map(|&i| records[i as usize].clone()).collect();
        let boxes = order
            .iter()
            .map(|&i| world[i as usize].unwrap_or(Aabb::EMPTY))
            .collect();
        let mut data = IasData {
            bvh,
            instances,
            boxes,
            slot_of,
            bounds,
            build_flags: options.flags,
            num_instances,
            depth,
            input_kind,
            lineage: crate::next_lineage(),
            motion: options.motion,
        };
        if keep_inactive {
            data.refit();
        }
        // The tree's slots are the structure's: instances are not packed.
        tree.prim_order = Vec::new();
        (data, tree)
    }
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
        let prepared = Self::prepare(options, inputs)?;
        let config = BuildConfig {
            block_size: 1,
            max_leaf_size: IAS_MAX_LEAF as usize,
            ..if options.flags.contains(BuildFlags::PREFER_FAST_TRACE) {
                BuildConfig::FAST_TRACE
            } else if options.flags.contains(BuildFlags::PREFER_FAST_BUILD) {
                BuildConfig::FAST_BUILD
            } else {
                BuildConfig::BALANCED
            }
        };
        let tree = build_bvh2(&prepared.boxes, &config);
        Ok(prepared.finish(tree))
    }

    /// The first half of a build: the rules checked, every instance validated and inverted,
    /// and the world boxes the tree is built over ([`PreparedIas::boxes`]). A builder (the
    /// host's in [`build_with_tree`](Self::build_with_tree), or a device's) makes a binary
    /// tree over those boxes and [`PreparedIas::finish`] makes the structure.
    pub fn prepare(
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<PreparedIas, BuildError> {
        if options
            .flags
            .contains(BuildFlags::PREFER_FAST_TRACE | BuildFlags::PREFER_FAST_BUILD)
        {
            return Err(BuildError::ConflictingBuildFlags);
        }
        if options.operation == BuildOperation::Update {
            return Err(BuildError::InvalidUpdate(UpdateRule::NoStructure));
        }
        options.motion.validate_for_structure()?;
        let list = instance_list(inputs)?;
        // An update may give an instance that cannot be hit now a box, and random instance
        // access (guide §13.12) reaches every instance: both keep a slot for each.
        let keep_inactive = options
            .flags
            .intersects(BuildFlags::ALLOW_UPDATE | BuildFlags::ALLOW_RANDOM_INSTANCE_ACCESS);
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
        // An updatable IAS keeps a slot for every instance; one that cannot be hit now is
        // placed at the centre of the others until an update gives it a box.
        let all = world.iter().flatten().fold(Aabb::EMPTY, |a, b| a.union(b));
        let centre = if all.is_finite_valid() {
            (all.min + all.max) * 0.5
        } else {
            glam::Vec3::ZERO
        };
        let (ids, boxes): (Vec<u32>, Vec<Aabb>) = world
            .iter()
            .enumerate()
            .filter_map(|(i, b)| match b {
                Some(b) => Some((i as u32, *b)),
                None if keep_inactive => Some((i as u32, Aabb::new(centre, centre))),
                None => None,
            })
            .unzip();
        Ok(PreparedIas {
            records,
            world,
            ids,
            boxes,
            keep_inactive,
            depth,
            options: *options,
            num_instances: list.len() as u32,
            input_kind: inputs[0].kind(),
        })
    }

    /// Refits the node boxes from the instance boxes.
    fn refit(&mut self) {
        let boxes = &self.boxes;
        self.bounds = crate::refit::refit_nodes(&mut self.bvh.nodes, |first, count| {
            boxes[first as usize..(first + count) as usize]
                .iter()
                .fold(Aabb::EMPTY, |a, b| a.union(b))
        });
    }

    /// Checks an update against the rules of guide §5.6 without changing anything:
    /// `operation` is `Update`, the IAS was built with `ALLOW_UPDATE` and the same flags, from
    /// one input of the same type and number of instances, and every instance's child is the
    /// structure it was built over or an update of it
    /// ([`TraversableHandle::same_structure`]). Transforms, ids, SBT offsets, masks and flags
    /// may change, and are validated as a build validates them.
    pub fn check_update(
        &self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(), BuildError> {
        self.prepare_update(options, inputs).map(|_| ())
    }

    /// The validated new instance records, by input index.
    fn prepare_update(
        &self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<Vec<InstanceData>, BuildError> {
        let rule = |r| Err(BuildError::InvalidUpdate(r));
        if options.operation != BuildOperation::Update {
            return rule(UpdateRule::NotAnUpdate);
        }
        if !self.build_flags.contains(BuildFlags::ALLOW_UPDATE) {
            return rule(UpdateRule::NotAllowed);
        }
        if options.flags != self.build_flags {
            return rule(UpdateRule::Flags {
                built: self.build_flags,
                given: options.flags,
            });
        }
        if options.motion != self.motion {
            return rule(UpdateRule::Motion {
                built: self.motion,
                given: options.motion,
            });
        }
        if inputs.len() != 1 {
            return rule(UpdateRule::InputCount {
                built: 1,
                given: inputs.len(),
            });
        }
        if inputs[0].kind() != self.input_kind {
            return rule(UpdateRule::InputKind {
                input: 0,
                built: self.input_kind,
                given: inputs[0].kind(),
            });
        }
        let list = instance_list(inputs)?;
        if list.len() != self.num_instances as usize {
            return rule(UpdateRule::Count {
                input: 0,
                what: "instances",
                built: self.num_instances as u64,
                given: list.len() as u64,
            });
        }
        list.par_iter()
            .enumerate()
            .map(|(i, inst)| {
                let Some(old) = self
                    .slot_of
                    .get(i)
                    .and_then(|&s| self.instances.get(s as usize))
                else {
                    return Err(BuildError::InvalidUpdate(UpdateRule::InstanceChild {
                        instance: i as u32,
                    }));
                };
                if !old.child.same_structure(&inst.child) {
                    return Err(BuildError::InvalidUpdate(UpdateRule::InstanceChild {
                        instance: i as u32,
                    }));
                }
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
            .collect()
    }

    /// Updates (refits) the IAS in place (guide §5.6): new transforms (and ids, SBT offsets,
    /// masks, flags) for the same instances of the same children — a child may be an update of
    /// the structure the IAS was built over, whose new bounds are taken. Every rule is checked
    /// first ([`check_update`](Self::check_update)); on an error nothing has changed. The
    /// instance boxes are recomputed and the node boxes refit bottom-up.
    pub fn update(
        &mut self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(), BuildError> {
        let records = self.prepare_update(options, inputs)?;
        for (i, r) in records.into_iter().enumerate() {
            let slot = self.slot_of[i] as usize;
            let b = r.object_to_world.transform_aabb(&r.child.bounds());
            self.boxes[slot] = if b.is_finite_valid() { b } else { Aabb::EMPTY };
            self.instances[slot] = r;
        }
        self.depth = 1 + self
            .instances
            .iter()
            .map(|r| r.child.graph_depth())
            .max()
            .unwrap_or(0);
        self.refit();
        Ok(())
    }

    /// Bytes the IAS occupies (its own tables; the children are not counted).
    #[must_use]
    pub fn memory_bytes(&self) -> usize {
        fn bytes<T>(v: &Vec<T>) -> usize {
            v.capacity() * std::mem::size_of::<T>()
        }
        bytes(&self.bvh.nodes) + bytes(&self.instances) + bytes(&self.boxes) + bytes(&self.slot_of)
    }

    /// The bytes of the compacted IAS (emitted property `COMPACTED_SIZE`, guide §5.8); `None`
    /// unless built with `ALLOW_COMPACTION`.
    #[must_use]
    pub fn compacted_size(&self) -> Option<usize> {
        self.build_flags
            .contains(BuildFlags::ALLOW_COMPACTION)
            .then(|| {
                std::mem::size_of_val(self.bvh.nodes.as_slice())
                    + std::mem::size_of_val(self.instances.as_slice())
                    + std::mem::size_of_val(self.boxes.as_slice())
                    + std::mem::size_of_val(self.slot_of.as_slice())
            })
    }

    /// The compacted IAS (guide §5.8): exactly sized tables over the same children, the same
    /// hits. Refused without `ALLOW_COMPACTION`.
    pub fn compact(&self) -> Result<IasData, BuildError> {
        if !self.build_flags.contains(BuildFlags::ALLOW_COMPACTION) {
            return Err(BuildError::CompactionNotAllowed);
        }
        let mut out = self.clone();
        out.bvh.nodes.shrink_to_fit();
        out.instances.shrink_to_fit();
        out.boxes.shrink_to_fit();
        out.slot_of.shrink_to_fit();
        Ok(out)
    }

    /// Instances in the build input.
    #[must_use]
    pub fn num_instances(&self) -> u32 {
        self.num_instances
    }

    /// The world box of every instance that can be hit.
    #[must_use]
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// The flags it was built with.
    #[must_use]
    pub fn build_flags(&self) -> BuildFlags {
        self.build_flags
    }

    /// The BVH over the instances.
    #[must_use]
    pub fn bvh(&self) -> &Bvh4 {
        &self.bvh
    }

    /// BVH statistics.
    #[must_use]
    pub fn stats(&self) -> BvhStats {
        self.bvh.stats()
    }

    /// Levels of the traversable graph from this IAS down (an IAS over GASes is 2).
    #[must_use]
    pub fn graph_depth(&self) -> u32 {
        self.depth
    }

    /// The child of instance `index` (`optixGetInstanceChildFromHandle` of
    /// `optixGetInstanceTraversableFromIAS`); needs `ALLOW_RANDOM_INSTANCE_ACCESS`. `None` for
    /// an index out of range, a null child, or without the flag; the whole instance is
    /// [`instance_by_index`](Self::instance_by_index).
    #[doc(alias = "optixGetInstanceChildFromHandle")]
    #[doc(alias = "optixGetInstanceTraversableFromIAS")]
    #[must_use]
    pub fn instance_child(&self, index: u32) -> Option<&TraversableHandle> {
        self.instance_by_index(index)
            .ok()
            .map(|r| &r.child)
            .filter(|c| !c.is_null())
    }
}
