//! The geometry acceleration structure: primitives of one kind from one or more build inputs,
//! under a 4-wide BVH (and an 8-wide one where the CPU backend asks for it).

use crate::build::{build_bvh2, BuildConfig};
use crate::bvh2::Bvh2;
use crate::bvh4::Bvh4;
use crate::bvh8::Bvh8;
use crate::curve::{CurveSegment, CurveSplits, CAP_END, CAP_START};
use crate::sbvh::{build_sbvh2, SpatialSplits};
use crate::sphere::Sphere;
use crate::stats::BvhStats;
use crate::triangle::is_degenerate;
use crate::triangle4::Triangle4;
use crate::wide::{leaf_starts, WideNode};
use bytemuck::Zeroable;
use glam::Vec3;
use oxray_core::validate::{validate_sbt_offsets, validate_structure};
use oxray_core::{
    Aabb, BuildError, BuildFlags, BuildInput, BuildInputKind, BuildOperation, BuildOptions,
    CurveEndcaps, CurveInput, GeometryFlags, IndexFormat, InputLocation, SphereInput,
    TriangleInput, UpdateRule, VertexFormat,
};
use rayon::prelude::*;

/// The primitives of a GAS.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GasKind {
    /// Triangles, in blocks of four.
    Triangles,
    /// Custom primitives (boxes; their shape is decided by an intersection program).
    CustomPrimitives,
    /// Built-in spheres (guide §5.3), one [`Sphere`] per leaf slot.
    Spheres,
    /// Built-in curves (guide §5.2), one [`CurveSegment`] per leaf slot.
    Curves,
}

/// What the structure keeps of each build input.
#[derive(Clone, Debug)]
pub struct InputRecord {
    /// Global id of the input's first primitive (ids count over all inputs, in order).
    pub first: u32,
    /// Added to reported primitive indices.
    pub primitive_index_offset: u32,
    /// SBT-GAS index of the input's first record: the records of the inputs before it.
    pub sbt_base: u32,
}

/// The facts of a built GAS that every backend reports, whatever memory holds its data.
#[derive(Clone, Debug, PartialEq)]
pub struct GasInfo {
    /// The kind of primitives.
    pub kind: BuildInputKind,
    /// The flags it was built with.
    pub build_flags: BuildFlags,
    /// Primitives declared over all build inputs, inactive ones included.
    pub num_primitives: u32,
    /// Primitives that can be hit.
    pub num_active_primitives: u32,
    /// Number of build inputs.
    pub num_build_inputs: usize,
    /// Geometry flags of every SBT record, by SBT-GAS index.
    pub record_flags: Vec<GeometryFlags>,
    /// The box around every active primitive.
    pub bounds: Aabb,
    /// Statistics of the BVH it was built with.
    pub stats: BvhStats,
}

/// The node layouts a GAS is built with, besides the canonical tree's 4-wide layout that every
/// structure has ([`GasData::bvh`]: updates, statistics, the CUDA backend's layouts start from
/// it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum NodeWidth {
    /// The 4-wide layout only.
    #[default]
    Four,
    /// Also the 8-wide layout ([`GasData::bvh8`]), for 8-wide SIMD traversal (AVX2, AVX-512).
    Eight,
}

/// Bytes a built GAS occupies.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct GasMemory {
    /// Bytes of the structure: nodes, primitives and the tables that hits are resolved with.
    /// At most the `output_size_in_bytes` of the memory query.
    pub output_bytes: usize,
    /// Of which BVH nodes.
    pub node_bytes: usize,
    /// Of which primitive data (vertices or boxes).
    pub primitive_bytes: usize,
}

/// The data of a built geometry acceleration structure (GAS), whatever backend traverses it:
/// the 4-wide BVH derived from the builder's binary BVH, the primitives in leaf-slot order and
/// the tables a hit is resolved with (primitive index, SBT-GAS index, build input).
///
/// It copies what it needs from the build inputs, which may be dropped once it is built.
/// Backends wrap it (the CPU backend traverses it in place; the CUDA backend uploads a layout
/// derived from it).
///
/// ```
/// use oxray_bvh::GasData;
/// use oxray_core::{BuildOptions, IndexBuffer, TriangleInput, VertexBuffer};
/// let vertices = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
/// let triangles = [[0u32, 1, 2]];
/// let input = TriangleInput::new(VertexBuffer::f32x3(&vertices))
///     .indices(IndexBuffer::u32x3(&triangles));
/// let gas = GasData::build(&BuildOptions::default(), &[input.into()])?;
/// assert_eq!((gas.num_primitives(), gas.num_active_primitives()), (1, 1));
/// let root = &gas.bvh.nodes[0];
/// assert_eq!(root.count[0], 1);
/// // Leaf slot of that lane: primitive 0 of build input 0, SBT-GAS index 0.
/// assert_eq!(gas.resolve(root.child[0]), (0, 0, 0));
/// # Ok::<(), oxray_core::BuildError>(())
/// ```
#[derive(Clone, Debug)]
pub struct GasData {
    /// The kind of primitives.
    pub kind: GasKind,
    /// The flags it was built with.
    pub build_flags: BuildFlags,
    /// The 4-wide BVH; leaves point at slots (triangle GAS: at the first slot of a block).
    pub bvh: Bvh4,
    /// The 8-wide BVH of a structure built with [`NodeWidth::Eight`]: collapsed from the same
    /// binary tree, with the same leaves (the same slot ranges) as [`bvh`](Self::bvh).
    pub bvh8: Option<Bvh8>,
    /// Triangles in blocks of four, in leaf-slot order (triangle GAS): slot `s` is lane `s % 4`
    /// of block `s / 4`. Each leaf starts a new block; unused lanes have no primitive.
    pub triangles: Vec<Triangle4>,
    /// Boxes in leaf-slot order (custom-primitive GAS).
    pub aabbs: Vec<Aabb>,
    /// Spheres in leaf-slot order (sphere GAS); an updatable structure's inactive spheres are
    /// [`Sphere::INACTIVE`].
    pub spheres: Vec<Sphere>,
    /// Curve segments in leaf-slot order (curve GAS); an updatable structure's inactive
    /// segments are [`CurveSegment::deactivated`].
    pub curves: Vec<CurveSegment>,
    /// Leaf slot to global primitive id ([`NO_PRIMITIVE`] for an unused lane).
    pub slot_prim: Vec<u32>,
    /// Per global primitive id, its SBT record within its input; empty when every input has one.
    pub sbt_offsets: Vec<u32>,
    /// What is kept of each build input.
    pub inputs: Vec<InputRecord>,
    /// Flags of every SBT record, indexed by SBT-GAS index.
    pub record_flags: Vec<GeometryFlags>,
    /// The box around every active primitive.
    pub bounds: Aabb,
    /// Primitives declared over all inputs, inactive ones included.
    pub num_primitives: u32,
    /// The description of every build input (counts, formats), which an update must repeat
    /// (guide §5.6).
    pub shapes: Vec<InputShape>,
    /// The structure's identity across updates and compaction (see
    /// [`Traversable::lineage`](oxray_core::Traversable::lineage)).
    pub lineage: u64,
    /// A structure built with motion (guide §5.10.2): its options and the primitives of keys
    /// 1, 2, … (`triangles`, `aabbs` and `spheres` hold key 0). `None` without motion.
    pub motion: Option<crate::motion::GasMotion>,
}

/// What an update must repeat of a build input (guide §5.6): its type, counts and formats.
/// Buffer contents (vertices, indices, boxes, SBT index offsets, the pre-transform matrix) may
/// change.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InputShape {
    /// Triangles, custom primitives or spheres.
    pub kind: GasKind,
    /// Vertices (triangles), boxes (custom primitives) or spheres.
    pub num_vertices: u32,
    /// The vertex format (triangles), as [`VertexFormat`]'s declaration order.
    pub vertex_format: u8,
    /// The index format plus one (0: no index buffer).
    pub index_format: u8,
    /// Index triplets.
    pub num_indices: u32,
    /// Whether a pre-transform is applied.
    pub pre_transform: bool,
    /// Bytes of one SBT index offset (0: no SBT index offset buffer).
    pub sbt_offset_size: u8,
    /// SBT records of the input.
    pub num_sbt_records: u32,
    /// A sphere input's `singleRadius`; whether a curve input has normals (false for the
    /// other kinds). A curve input keeps its curve type's code's low byte in `vertex_format`
    /// and its end caps in `index_format` (1: default, 2: on).
    pub single_radius: bool,
}

impl InputShape {
    /// The shape of a GAS build input; `None` for an instance input.
    #[must_use]
    pub fn of(input: &BuildInput<'_>) -> Option<InputShape> {
        let sbt_offset_size = input.sbt_index_offsets().map_or(0, |o| o.size.size() as u8);
        let num_sbt_records = input.flags().len() as u32;
        match input {
            BuildInput::Triangles(t) => Some(InputShape {
                kind: GasKind::Triangles,
                num_vertices: t.vertices.count,
                vertex_format: vertex_format_code(t.vertices.format),
                index_format: t.indices.as_ref().map_or(0, |i| match i.format {
                    IndexFormat::U16x3 => 1,
                    IndexFormat::U32x3 => 2,
                }),
                num_indices: t.indices.as_ref().map_or(0, |i| i.count),
                pre_transform: t.pre_transform.is_some(),
                sbt_offset_size,
                num_sbt_records,
                single_radius: false,
            }),
            BuildInput::CustomPrimitives(c) => Some(InputShape {
                kind: GasKind::CustomPrimitives,
                num_vertices: c.aabbs.count,
                vertex_format: 0,
                index_format: 0,
                num_indices: 0,
                pre_transform: false,
                sbt_offset_size,
                num_sbt_records,
                single_radius: false,
            }),
            BuildInput::Spheres(s) => Some(InputShape {
                kind: GasKind::Spheres,
                num_vertices: s.num_vertices,
                vertex_format: 0,
                index_format: 0,
                num_indices: 0,
                pre_transform: false,
                sbt_offset_size,
                num_sbt_records,
                single_radius: s.single_radius,
            }),
            BuildInput::Curves(c) => Some(InputShape {
                kind: GasKind::Curves,
                num_vertices: c.num_vertices,
                vertex_format: (c.curve_type.code() & 0xFF) as u8,
                index_format: match c.endcaps {
                    CurveEndcaps::Default => 1,
                    CurveEndcaps::On => 2,
                },
                num_indices: c.num_primitives,
                pre_transform: false,
                sbt_offset_size,
                num_sbt_records,
                single_radius: !c.normal_buffers.is_empty(),
            }),
            _ => None,
        }
    }
}

fn vertex_format_code(f: VertexFormat) -> u8 {
    match f {
        VertexFormat::F32x3 => 0,
        VertexFormat::F32x2 => 1,
        VertexFormat::F16x3 => 2,
        VertexFormat::F16x2 => 3,
        VertexFormat::Snorm16x3 => 4,
        VertexFormat::Snorm16x2 => 5,
    }
}

impl GasData {
    /// Builds a GAS (`optixAccelBuild`). Inputs must all be of one kind; see [`BuildError`] for
    /// every rule checked. Primitives that can never be hit (a NaN or infinite coordinate, a
    /// zero-area triangle, an inverted box, a sphere whose radius is not positive) are left
    /// out: they are inactive.
    ///
    /// A triangle build with `PREFER_FAST_TRACE` and without `ALLOW_UPDATE` uses spatial
    /// splits ([`spatial_splits`]): a leaf may then hold a triangle that another leaf holds
    /// too (never one whose SBT record has `REQUIRE_SINGLE_ANYHIT_CALL`).
    #[doc(alias = "optixAccelBuild")]
    pub fn build(options: &BuildOptions, inputs: &[BuildInput<'_>]) -> Result<GasData, BuildError> {
        Ok(Self::build_impl(
            options,
            inputs,
            false,
            NodeWidth::Four,
            spatial_splits(options),
            curve_splits(options),
        )?
        .0)
    }

    /// [`build`](Self::build) with the curve-splitting setting `splits` (guide §9.2) instead of
    /// the one the build flags choose ([`curve_splits`]; `None`: one reference per segment), to
    /// compare builders. Where the rules exclude splitting it stays off whatever `splits`
    /// says: `ALLOW_UPDATE` builds (a refit needs one reference per primitive) and the segments
    /// of SBT records with `REQUIRE_SINGLE_ANYHIT_CALL` (§9.2).
    pub fn build_with_curve_splits(
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
        splits: Option<CurveSplits>,
    ) -> Result<GasData, BuildError> {
        let splits = splits.filter(|_| !options.flags.contains(BuildFlags::ALLOW_UPDATE));
        Ok(Self::build_impl(
            options,
            inputs,
            false,
            NodeWidth::Four,
            spatial_splits(options),
            splits,
        )?
        .0)
    }

    /// [`build_with_width`](Self::build_with_width) with the spatial-split setting `splits`
    /// instead of the one the build flags choose (`None`: no spatial splits), to compare
    /// builders. Where the rules exclude spatial splits they stay off whatever `splits` says:
    /// custom primitives, `ALLOW_UPDATE` builds (a refit needs one reference per primitive),
    /// and the primitives of SBT records with `REQUIRE_SINGLE_ANYHIT_CALL` (guide §5.1).
    pub fn build_with_spatial_splits(
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
        width: NodeWidth,
        splits: Option<SpatialSplits>,
    ) -> Result<GasData, BuildError> {
        let splits = splits.filter(|_| !options.flags.contains(BuildFlags::ALLOW_UPDATE));
        Ok(Self::build_impl(options, inputs, false, width, splits, curve_splits(options))?.0)
    }

    /// [`build`](Self::build) with the node layouts of `width`: with [`NodeWidth::Eight`], the
    /// structure also holds the 8-wide layout ([`bvh8`](Self::bvh8)). The 4-wide layout, the
    /// primitives and every table are those of [`build`](Self::build), byte for byte.
    ///
    /// ```
    /// use oxray_bvh::{GasData, NodeWidth};
    /// use oxray_core::{BuildOptions, TriangleInput, VertexBuffer};
    /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    /// let inputs = [TriangleInput::new(VertexBuffer::f32x3(&v)).into()];
    /// let gas = GasData::build_with_width(&BuildOptions::default(), &inputs, NodeWidth::Eight)?;
    /// let b8 = gas.bvh8.as_ref().unwrap();
    /// assert_eq!((b8.nodes[0].child[0], b8.nodes[0].count[0]), (0, 1));
    /// # Ok::<(), oxray_core::BuildError>(())
    /// ```
    pub fn build_with_width(
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
        width: NodeWidth,
    ) -> Result<GasData, BuildError> {
        Ok(Self::build_impl(
            options,
            inputs,
            false,
            width,
            spatial_splits(options),
            curve_splits(options),
        )?
        .0)
    }

    /// The node layouts the structure holds.
    #[must_use]
    pub fn width(&self) -> NodeWidth {
        if self.bvh8.is_some() {
            NodeWidth::Eight
        } else {
            NodeWidth::Four
        }
    }

    /// [`build`](Self::build), also returning the canonical binary BVH the builder made, with
    /// its leaves pointing at this structure's leaf slots (`left_first` is the leaf's first
    /// slot, as in the 4-wide layout): the tree other traversal layouts (a GPU's binary nodes,
    /// say) are derived from. The CPU backend does not keep it.
    pub fn build_with_tree(
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(GasData, Bvh2), BuildError> {
        let (gas, tree) = Self::build_impl(
            options,
            inputs,
            true,
            NodeWidth::Four,
            spatial_splits(options),
            curve_splits(options),
        )?;
        Ok((gas, tree.unwrap_or_default()))
    }

    /// Validates a build (every rule of guide §5, §5.1, §5.5, §12, the SBT index offsets and the
    /// triangles' indices) and makes the structure's tables without building anything: the
    /// inputs' records, the SBT records' flags, the per-primitive SBT offsets, the counts. Its
    /// tree, primitives and slot table are empty and its bounds [`Aabb::EMPTY`]; a builder that
    /// keeps the structure elsewhere (a GPU's) fills its own and resolves hits with
    /// [`resolve_global`](Self::resolve_global).
    ///
    /// ```
    /// use oxray_bvh::GasData;
    /// use oxray_core::{BuildOptions, IndexBuffer, TriangleInput, VertexBuffer};
    /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    /// let bad = [[0u32, 1, 3]];
    /// let input = TriangleInput::new(VertexBuffer::f32x3(&v)).indices(IndexBuffer::u32x3(&bad));
    /// assert!(GasData::prepare(&BuildOptions::default(), &[input.into()]).is_err());
    /// let good = TriangleInput::new(VertexBuffer::f32x3(&v));
    /// let gas = GasData::prepare(&BuildOptions::default(), &[good.into()])?;
    /// assert_eq!((gas.num_primitives, gas.slot_prim.len()), (1, 0));
    /// # Ok::<(), oxray_core::BuildError>(())
    /// ```
    pub fn prepare(
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<GasData, BuildError> {
        if options.operation == BuildOperation::Update {
            return Err(BuildError::InvalidUpdate(UpdateRule::NoStructure));
        }
        let summary = validate_structure(options, inputs)?;
        let mut records = Vec::with_capacity(inputs.len());
        let mut record_flags = Vec::with_capacity(summary.num_sbt_records as usize);
        let mut first = 0u32;
        for (i, input) in inputs.iter().enumerate() {
            let count = input.num_primitives();
            let num_records = input.flags().len() as u32;
            if let Some(o) = input.sbt_index_offsets() {
                validate_sbt_offsets(InputLocation { input: i }, o, count, num_records)?;
            }
            if let BuildInput::Triangles(t) = input {
                check_indices(InputLocation { input: i }, t)?;
            }
            records.push(InputRecord {
                first,
                primitive_index_offset: input.primitive_index_offset(),
                sbt_base: record_flags.len() as u32,
            });
            record_flags.extend_from_slice(input.flags());
            first += count;
        }

        let sbt_offsets: Vec<u32> = if inputs.iter().any(|i| i.flags().len() > 1) {
            inputs
                .iter()
                .flat_map(|input| {
                    let n = input.num_primitives() as usize;
                    let offsets = input.sbt_index_offsets();
                    (0..n).map(move |p| offsets.map_or(0, |o| o.get(p)))
                })
                .collect()
        } else {
            Vec::new()
        };

        Ok(GasData {
            kind: match summary.kind {
                BuildInputKind::Triangles => GasKind::Triangles,
                BuildInputKind::Spheres => GasKind::Spheres,
                BuildInputKind::Curves => GasKind::Curves,
                _ => GasKind::CustomPrimitives,
            },
            build_flags: options.flags,
            bvh: Bvh4 { nodes: Vec::new() },
            bvh8: None,
            triangles: Vec::new(),
            aabbs: Vec::new(),
            spheres: Vec::new(),
            curves: Vec::new(),
            slot_prim: Vec::new(),
            sbt_offsets,
            inputs: records,
            record_flags,
            bounds: Aabb::EMPTY,
            num_primitives: summary.num_primitives,
            shapes: inputs.iter().filter_map(InputShape::of).collect(),
            lineage: crate::next_lineage(),
            motion: None,
        })
    }

    /// The tree over the boxes of the active primitives (`Some`), for a structure that keeps
    /// one primitive per leaf slot in the tree's order (custom primitives, spheres): the slot
    /// table, the bounds and the node layouts. The caller stores the primitives by slot.
    pub(crate) fn build_slots(
        &mut self,
        boxes: &[Option<Aabb>],
        config: &BuildConfig,
        width: NodeWidth,
    ) -> Bvh2 {
        let (ids, bounds): (Vec<u32>, Vec<Aabb>) = boxes
            .iter()
            .enumerate()
            .filter_map(|(i, b)| b.map(|b| (i as u32, b)))
            .unzip();
        self.build_slot_refs(&ids, &bounds, false, config, width)
    }

    /// [`build_slots`](Self::build_slots) over references: reference `k` is primitive `ids[k]`
    /// bounded by `bounds[k]`, and a primitive may have several (split curve segments, guide
    /// §9.2). Each leaf slot names one primitive; with `repeats`, a leaf keeps one slot of a
    /// primitive that several of its references name (the leaf's box holds all of theirs).
    pub(crate) fn build_slot_refs(
        &mut self,
        ids: &[u32],
        bounds: &[Aabb],
        repeats: bool,
        config: &BuildConfig,
        width: NodeWidth,
    ) -> Bvh2 {
        let mut bvh2 = build_bvh2(bounds, config);
        if repeats {
            merge_leaf_repeats(&mut bvh2, ids);
        }
        self.slot_prim = bvh2.prim_order.iter().map(|&k| ids[k as usize]).collect();
        self.bounds = bvh2.nodes.first().map_or(Aabb::EMPTY, |n| n.bounds());
        self.bvh = Bvh4::from(&bvh2);
        if width == NodeWidth::Eight {
            self.bvh8 = Some(Bvh8::from(&bvh2));
        }
        bvh2
    }

    fn build_impl(
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
        keep_tree: bool,
        width: NodeWidth,
        splits: Option<SpatialSplits>,
        curve_splits: Option<CurveSplits>,
    ) -> Result<(GasData, Option<Bvh2>), BuildError> {
        let mut gas = Self::prepare(options, inputs)?;
        // An updatable structure keeps a slot for every primitive, inactive ones included, so
        // that an update can make them active (and inactive ones never hit).
        let keep_inactive = options.flags.contains(BuildFlags::ALLOW_UPDATE);
        let config = if options.flags.contains(BuildFlags::PREFER_FAST_TRACE) {
            BuildConfig::FAST_TRACE
        } else if options.flags.contains(BuildFlags::PREFER_FAST_BUILD) {
            BuildConfig::FAST_BUILD
        } else {
            BuildConfig::BALANCED
        };

        let mut tree = None;
        if options.motion.has_motion() {
            // A refit would re-read every key.
            if options.flags.contains(BuildFlags::ALLOW_UPDATE) {
                return Err(BuildError::Unsupported("ALLOW_UPDATE with motion keys"));
            }
            let bvh2 = crate::motion::build_motion(
                &mut gas,
                options.motion,
                inputs,
                &config,
                width,
                curve_splits,
            );
            gas.shapes = Vec::new();
            if !options.flags.contains(BuildFlags::ALLOW_COMPACTION) {
                gas.shrink_to_fit();
            }
            return Ok((gas, keep_tree.then_some(bvh2)));
        }
        match gas.kind {
            GasKind::Triangles => {
                let mut per_input: Vec<Vec<[Vec3; 3]>> = inputs
                    .iter()
                    .map(|input| match input {
                        BuildInput::Triangles(t) => decode_triangles(t),
                        _ => unreachable!("inputs are homogeneous"),
                    })
                    .collect();
                let tris: Vec<[Vec3; 3]> = if per_input.len() == 1 {
                    per_input.pop().unwrap_or_default()
                } else {
                    per_input.concat()
                };
                // An indexed parallel map, then a sequential filter: rayon's filtered collect
                // would allocate per item.
                let mut boxes: Vec<Option<Aabb>> = tris
                    .par_iter()
                    .map(|t| (!is_degenerate(t[0], t[1], t[2])).then(|| Aabb::from_points(t)))
                    .collect();
                let active: Option<Vec<bool>> =
                    keep_inactive.then(|| boxes.iter().map(Option::is_some).collect());
                if keep_inactive {
                    place_inactive(&mut boxes, |i| Aabb::from_points(&tris[i]));
                }
                let (ids, bounds): (Vec<u32>, Vec<Aabb>) = boxes
                    .iter()
                    .enumerate()
                    .filter_map(|(i, b)| b.map(|b| (i as u32, b)))
                    .unzip();
                let splittable = splits.and_then(|_| gas.splittable(&ids));
                let bvh2 = match (splits, splittable) {
                    (Some(splits), Some(splittable)) => {
                        let active: Vec<[Vec3; 3]> =
                            ids.par_iter().map(|&g| tris[g as usize]).collect();
                        let all = splittable.iter().all(|&s| s);
                        let only = (!all).then_some(&splittable[..]);
                        build_sbvh2(&active, &bounds, only, &config, &splits)
                    }
                    _ => build_bvh2(&bounds, &config),
                };
                gas.bounds = bvh2.nodes.first().map_or(Aabb::EMPTY, |n| n.bounds());
                gas.bvh = Bvh4::from(&bvh2);
                let global: Vec<u32> = bvh2
                    .prim_order
                    .par_iter()
                    .map(|&k| ids[k as usize])
                    .collect();
                let remap = keep_tree || width == NodeWidth::Eight;
                let before = remap.then(|| leaf_starts(&gas.bvh.nodes));
                (gas.triangles, gas.slot_prim) = pack_triangles(&mut gas.bvh, &global, &tris);
                if let Some(before) = before {
                    let map = leaf_map(&before, &leaf_starts(&gas.bvh.nodes));
                    if width == NodeWidth::Eight {
                        let mut b8 = Bvh8::from(&bvh2);
                        remap_wide_leaves(&mut b8.nodes, &map);
                        gas.bvh8 = Some(b8);
                    }
                    if keep_tree {
                        tree = Some(remap_leaves(bvh2, &map));
                    }
                }
                if let Some(active) = active {
                    crate::refit::deactivate_lanes(&mut gas.triangles, &gas.slot_prim, &active);
                    gas.bounds = crate::refit::refit_triangle_boxes(&mut gas);
                }
            }
            GasKind::CustomPrimitives => {
                let boxes: Vec<Aabb> = inputs
                    .iter()
                    .flat_map(|input| match input {
                        BuildInput::CustomPrimitives(c) => {
                            let a = c.aabbs;
                            let stride = a.effective_stride();
                            (0..a.count as usize).map(move |i| {
                                let f: [f32; 6] = std::array::from_fn(|k| {
                                    let at = i * stride + 4 * k;
                                    f32::from_le_bytes(
                                        a.data[at..at + 4].try_into().unwrap_or([0; 4]),
                                    )
                                });
                                Aabb::new(Vec3::new(f[0], f[1], f[2]), Vec3::new(f[3], f[4], f[5]))
                            })
                        }
                        _ => unreachable!("inputs are homogeneous"),
                    })
                    .collect();
                let mut valid: Vec<Option<Aabb>> = boxes
                    .iter()
                    .map(|b| b.is_finite_valid().then_some(*b))
                    .collect();
                if keep_inactive {
                    place_inactive(&mut valid, |i| {
                        let b = boxes[i];
                        Aabb::from_points(&[b.min, b.max])
                    });
                }
                let bvh2 = gas.build_slots(&valid, &config, width);
                gas.aabbs = gas
                    .slot_prim
                    .iter()
                    .map(|&g| {
                        let b = boxes[g as usize];
                        if b.is_finite_valid() {
                            b
                        } else {
                            Aabb::EMPTY
                        }
                    })
                    .collect();
                if keep_inactive {
                    gas.bounds = crate::refit::refit_aabb_boxes(&mut gas);
                }
                // Custom primitives are not packed: the tree's slots are the structure's.
                tree = keep_tree.then_some(bvh2);
            }
            GasKind::Spheres => {
                let spheres: Vec<Sphere> = inputs
                    .iter()
                    .flat_map(|input| match input {
                        BuildInput::Spheres(s) => decode_spheres(s),
                        _ => unreachable!("inputs are homogeneous"),
                    })
                    .collect();
                // Inactive spheres (NaN, zero or negative radius) are left out like degenerate
                // triangles; an updatable build places them by their centre (or the middle of
                // the others) so that an update can make them active.
                let mut boxes: Vec<Option<Aabb>> = spheres
                    .par_iter()
                    .map(|s| s.is_active().then(|| s.bounds()))
                    .collect();
                if keep_inactive {
                    place_inactive(&mut boxes, |i| {
                        let c = Vec3::from(spheres[i].center);
                        Aabb::new(c, c)
                    });
                }
                let bvh2 = gas.build_slots(&boxes, &config, width);
                gas.spheres = gas
                    .slot_prim
                    .par_iter()
                    .map(|&g| {
                        let s = spheres[g as usize];
                        if s.is_active() {
                            s
                        } else {
                            Sphere::INACTIVE
                        }
                    })
                    .collect();
                if keep_inactive {
                    gas.bounds = crate::refit::refit_sphere_boxes(&mut gas);
                }
                // Spheres are not packed either: one slot per sphere, in the tree's order.
                tree = keep_tree.then_some(bvh2);
            }
            GasKind::Curves => {
                let segments: Vec<CurveSegment> = inputs
                    .iter()
                    .flat_map(|input| match input {
                        BuildInput::Curves(c) => decode_curves(c),
                        _ => unreachable!("inputs are homogeneous"),
                    })
                    .collect();
                // Segments without a positive radius or with non-finite data are inactive
                // (the guide skips negative radii, §9.8); an updatable build places them at
                // their first control point.
                let mut boxes: Vec<Option<Aabb>> = segments
                    .par_iter()
                    .map(|s| s.is_active().then(|| s.bounds()))
                    .collect();
                if keep_inactive {
                    place_inactive(&mut boxes, |i| {
                        let p = segments[i].points[0];
                        let c = Vec3::new(p[0], p[1], p[2]);
                        Aabb::new(c, c)
                    });
                }
                let (ids, bounds): (Vec<u32>, Vec<Aabb>) = boxes
                    .iter()
                    .enumerate()
                    .filter_map(|(i, b)| b.map(|b| (i as u32, b)))
                    .unzip();
                // §9.2: long segments are referenced by pieces of their parameter interval, each
                // reference intersecting the whole segment. Never in an updatable build (a refit
                // fills one slot per segment) nor for REQUIRE_SINGLE_ANYHIT_CALL records.
                let curve_splits = curve_splits.filter(|_| !keep_inactive);
                let splittable = curve_splits.and_then(|_| gas.splittable(&ids));
                let bvh2 = match (curve_splits, splittable) {
                    (Some(cs), Some(splittable)) => {
                        let (ref_ids, ref_bounds): (Vec<u32>, Vec<Aabb>) = ids
                            .par_iter()
                            .zip(&bounds)
                            .zip(&splittable)
                            .flat_map_iter(|((&g, &b), &split)| {
                                let s = &segments[g as usize];
                                let n = if split { s.pieces(&cs) } else { 1 };
                                (0..n).map(move |j| {
                                    if n == 1 {
                                        (g, b)
                                    } else {
                                        let u = |j: u32| j as f64 / n as f64;
                                        (g, s.bounds_over(u(j), u(j + 1)))
                                    }
                                })
                            })
                            .unzip();
                        let repeats = ref_ids.len() > ids.len();
                        gas.build_slot_refs(&ref_ids, &ref_bounds, repeats, &config, width)
                    }
                    _ => gas.build_slot_refs(&ids, &bounds, false, &config, width),
                };
                gas.curves = gas
                    .slot_prim
                    .par_iter()
                    .map(|&g| {
                        let s = segments[g as usize];
                        if s.is_active() {
                            s
                        } else {
                            s.deactivated()
                        }
                    })
                    .collect();
                if keep_inactive {
                    gas.bounds = crate::refit::refit_curve_boxes(&mut gas);
                }
                // Slots in the tree's order: one per segment, or one per leaf that references
                // it where it is split.
                tree = keep_tree.then_some(bvh2);
            }
        }
        if !keep_inactive {
            // Only an update checks the inputs' shapes.
            gas.shapes = Vec::new();
        }
        if !options.flags.contains(BuildFlags::ALLOW_COMPACTION) {
            // What the structure keeps is exactly what it reports: compact from the start. A
            // build that allows compaction skips this copy and keeps the builder's slack until
            // it is compacted (guide §5.8); it never takes more than the memory query's bound.
            gas.shrink_to_fit();
        }
        Ok((gas, tree))
    }

    /// The kind of primitives.
    #[must_use]
    pub fn kind(&self) -> BuildInputKind {
        match self.kind {
            GasKind::Triangles => BuildInputKind::Triangles,
            GasKind::CustomPrimitives => BuildInputKind::CustomPrimitives,
            GasKind::Spheres => BuildInputKind::Spheres,
            GasKind::Curves => BuildInputKind::Curves,
        }
    }

    /// The flags it was built with.
    #[must_use]
    pub fn build_flags(&self) -> BuildFlags {
        self.build_flags
    }

    /// Primitives declared over all build inputs, inactive ones included.
    #[must_use]
    pub fn num_primitives(&self) -> u32 {
        self.num_primitives
    }

    /// Primitives that can be hit (each once, however many leaf slots hold it).
    #[must_use]
    pub fn num_active_primitives(&self) -> u32 {
        let mut seen = vec![false; self.num_primitives as usize];
        let mut count = 0;
        for s in 0..self.slot_prim.len() {
            if self.slot_is_active(s) {
                let g = self.slot_prim[s] as usize;
                // Loaded bytes are checked to name primitives below the count; stay safe anyway.
                if let Some(seen) = seen.get_mut(g) {
                    count += u32::from(!*seen);
                    *seen = true;
                }
            }
        }
        count
    }

    /// Leaf slots that hold a primitive that can be hit: more than
    /// [`num_active_primitives`](Self::num_active_primitives) where spatial splits referenced
    /// a primitive from several leaves.
    #[must_use]
    pub fn num_references(&self) -> u32 {
        (0..self.slot_prim.len())
            .filter(|&s| self.slot_is_active(s))
            .count() as u32
    }

    /// Per active primitive (`ids[k]` the global id of the builder's primitive `k`), whether
    /// spatial splits may split it: not when its SBT record has `REQUIRE_SINGLE_ANYHIT_CALL`
    /// (guide §5.1: the any-hit program is then called once per primitive, and a primitive
    /// referenced from two leaves would be reported twice; §9.2 says the same of OptiX's
    /// curve splitting). `None` when no primitive may be split.
    pub(crate) fn splittable(&self, ids: &[u32]) -> Option<Vec<bool>> {
        let single = |record: usize| {
            self.record_flags
                .get(record)
                .is_some_and(|f| f.contains(GeometryFlags::REQUIRE_SINGLE_ANYHIT_CALL))
        };
        if !(0..self.record_flags.len()).any(single) {
            return Some(vec![true; ids.len()]);
        }
        let out: Vec<bool> = ids
            .iter()
            .map(|&g| {
                let (input, _) = self.locate(g);
                let record = self.inputs[input].sbt_base
                    + self.sbt_offsets.get(g as usize).copied().unwrap_or(0);
                !single(record as usize)
            })
            .collect();
        out.iter().any(|&s| s).then_some(out)
    }

    /// Whether leaf slot `slot` holds a primitive that can be hit (an updatable structure keeps
    /// slots of inactive primitives: their triangle lanes hold NaN, their boxes are empty).
    #[inline]
    #[must_use]
    pub fn slot_is_active(&self, slot: usize) -> bool {
        if self.slot_prim.get(slot).is_none_or(|&g| g == NO_PRIMITIVE) {
            return false;
        }
        match self.kind {
            GasKind::Triangles => !self.triangles[slot / 4].v[0][0][slot % 4].is_nan(),
            GasKind::CustomPrimitives => self.aabbs[slot].is_finite_valid(),
            GasKind::Spheres => self.spheres[slot].is_active(),
            GasKind::Curves => self.curves[slot].is_active(),
        }
    }

    /// Number of build inputs.
    #[must_use]
    pub fn num_build_inputs(&self) -> usize {
        self.inputs.len()
    }

    /// SBT records over all build inputs (the span of SBT-GAS indices).
    #[must_use]
    pub fn num_sbt_records(&self) -> u32 {
        self.record_flags.len() as u32
    }

    /// The geometry flags of an SBT record, by SBT-GAS index.
    #[must_use]
    pub fn geometry_flags(&self, sbt_gas_index: u32) -> Option<GeometryFlags> {
        self.record_flags.get(sbt_gas_index as usize).copied()
    }

    /// The box around every active primitive (empty when there is none).
    #[must_use]
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// The BVH.
    #[must_use]
    pub fn bvh(&self) -> &Bvh4 {
        &self.bvh
    }

    /// BVH statistics: nodes, depth, SAH cost, bytes.
    #[must_use]
    pub fn stats(&self) -> BvhStats {
        self.bvh.stats()
    }

    /// Bytes the structure occupies.
    #[must_use]
    pub fn memory(&self) -> GasMemory {
        fn bytes<T>(v: &Vec<T>) -> usize {
            v.capacity() * std::mem::size_of::<T>()
        }
        // A motion structure's time parts are copies of its nodes.
        let parts = self
            .motion
            .as_ref()
            .and_then(|m| m.segments.as_ref())
            .map_or(0, |p| {
                p.bvh.iter().map(bytes).sum::<usize>() + p.bvh8.iter().map(bytes).sum::<usize>()
            });
        let node_bytes =
            bytes(&self.bvh.nodes) + self.bvh8.as_ref().map_or(0, |b| bytes(&b.nodes)) + parts;
        let primitive_bytes = bytes(&self.triangles)
            + bytes(&self.aabbs)
            + bytes(&self.spheres)
            + bytes(&self.curves)
            + self.motion.as_ref().map_or(0, |m| {
                bytes(&m.triangles) + bytes(&m.aabbs) + bytes(&m.spheres) + bytes(&m.curves)
            });
        GasMemory {
            output_bytes: node_bytes
                + primitive_bytes
                + bytes(&self.slot_prim)
                + bytes(&self.sbt_offsets)
                + bytes(&self.inputs)
                + bytes(&self.record_flags)
                + bytes(&self.shapes),
            node_bytes,
            primitive_bytes,
        }
    }

    fn shrink_to_fit(&mut self) {
        self.bvh.nodes.shrink_to_fit();
        if let Some(b8) = &mut self.bvh8 {
            b8.nodes.shrink_to_fit();
        }
        self.triangles.shrink_to_fit();
        self.aabbs.shrink_to_fit();
        self.spheres.shrink_to_fit();
        self.curves.shrink_to_fit();
        self.slot_prim.shrink_to_fit();
        self.sbt_offsets.shrink_to_fit();
        self.inputs.shrink_to_fit();
        self.record_flags.shrink_to_fit();
        self.shapes.shrink_to_fit();
        if let Some(m) = &mut self.motion {
            m.shrink_to_fit();
        }
    }

    /// Grows every table to the size the memory query allows it (the output buffer).
    /// The bytes the structure takes once compacted: the emitted property `COMPACTED_SIZE`
    /// (guide §5.8), known before compacting. `None` unless it was built with
    /// `ALLOW_COMPACTION`.
    #[must_use]
    pub fn compacted_size(&self) -> Option<usize> {
        if !self.build_flags.contains(BuildFlags::ALLOW_COMPACTION) {
            return None;
        }
        fn bytes<T>(v: &[T]) -> usize {
            std::mem::size_of_val(v)
        }
        Some(
            bytes(&self.bvh.nodes)
                + self.bvh8.as_ref().map_or(0, |b| bytes(&b.nodes))
                + bytes(&self.triangles)
                + bytes(&self.aabbs)
                + bytes(&self.spheres)
                + bytes(&self.curves)
                + bytes(&self.slot_prim)
                + bytes(&self.sbt_offsets)
                + bytes(&self.inputs)
                + bytes(&self.record_flags)
                + bytes(&self.shapes)
                + self.motion.as_ref().map_or(0, |m| m.bytes()),
        )
    }

    /// The compacted structure (`optixAccelCompact`, guide §5.8): a copy in exactly sized
    /// tables, [`compacted_size`](Self::compacted_size) bytes, with the same tree, primitives
    /// and hits; it references nothing of the source, which may be dropped. It can be
    /// traversed, updated (if built with `ALLOW_UPDATE`) and saved like its source, and keeps
    /// its lineage. Refused with [`BuildError::CompactionNotAllowed`] without
    /// `ALLOW_COMPACTION`.
    ///
    /// ```
    /// use oxray_bvh::GasData;
    /// use oxray_core::{BuildFlags, BuildOptions, TriangleInput, VertexBuffer};
    /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    /// let options = BuildOptions::new(BuildFlags::ALLOW_COMPACTION);
    /// let gas = GasData::build(&options, &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
    /// let size = gas.compacted_size().unwrap();
    /// let compact = gas.compact()?;
    /// assert_eq!(compact.memory().output_bytes, size);
    /// assert!(size <= gas.memory().output_bytes);
    /// # Ok::<(), oxray_core::BuildError>(())
    /// ```
    #[doc(alias = "optixAccelCompact")]
    pub fn compact(&self) -> Result<GasData, BuildError> {
        if !self.build_flags.contains(BuildFlags::ALLOW_COMPACTION) {
            return Err(BuildError::CompactionNotAllowed);
        }
        // `Vec::clone` allocates exactly the length.
        let mut out = self.clone();
        out.shrink_to_fit();
        Ok(out)
    }

    /// What a backend that keeps the structure elsewhere (in GPU memory, say) reports of it.
    #[must_use]
    pub fn info(&self) -> GasInfo {
        GasInfo {
            kind: self.kind(),
            build_flags: self.build_flags,
            num_primitives: self.num_primitives,
            num_active_primitives: self.num_active_primitives(),
            num_build_inputs: self.inputs.len(),
            record_flags: self.record_flags.clone(),
            bounds: self.bounds,
            stats: self.stats(),
        }
    }

    /// The build input and the index within it of a global primitive id.
    #[inline]
    #[must_use]
    pub fn locate(&self, global: u32) -> (usize, u32) {
        let i = if self.inputs.len() == 1 {
            0
        } else {
            self.inputs.partition_point(|r| r.first <= global) - 1
        };
        (i, global - self.inputs[i].first)
    }

    /// Primitive index (with the input's offset), SBT-GAS index and build input of a leaf slot.
    #[inline]
    #[must_use]
    pub fn resolve(&self, slot: u32) -> (u32, u32, u32) {
        self.resolve_global(self.slot_prim[slot as usize])
    }

    /// Primitive index (with the input's offset), SBT-GAS index and build input of a global
    /// primitive id (ids count over all inputs, in order; `global < num_primitives`).
    #[inline]
    #[must_use]
    pub fn resolve_global(&self, global: u32) -> (u32, u32, u32) {
        let (input, local) = self.locate(global);
        let rec = &self.inputs[input];
        let sbt = rec.sbt_base + self.sbt_offsets.get(global as usize).copied().unwrap_or(0);
        (local + rec.primitive_index_offset, sbt, input as u32)
    }
}

/// The spatial splits a build uses (see [`crate::sbvh`]): those of
/// [`SpatialSplits::FAST_TRACE`] for `PREFER_FAST_TRACE` without `ALLOW_UPDATE` (an update
/// refits one leaf slot per primitive, and rebuilding the clipped boxes would need the
/// splits again), none otherwise. Only triangles are split, and never those whose SBT record
/// has `REQUIRE_SINGLE_ANYHIT_CALL` (guide §5.1).
#[must_use]
pub fn spatial_splits(options: &BuildOptions) -> Option<SpatialSplits> {
    (options.flags.contains(BuildFlags::PREFER_FAST_TRACE)
        && !options.flags.contains(BuildFlags::ALLOW_UPDATE))
    .then_some(SpatialSplits::FAST_TRACE)
}

/// The curve-splitting setting of a build (guide §9.2): [`CurveSplits::BALANCED`] by default,
/// [`CurveSplits::FAST_TRACE`] with `PREFER_FAST_TRACE` (a higher splitting factor),
/// [`CurveSplits::FAST_BUILD`] with `PREFER_FAST_BUILD` (a lower one), none with
/// `ALLOW_UPDATE` (a refit fills one slot per segment). Segments of SBT records with
/// `REQUIRE_SINGLE_ANYHIT_CALL` are never split, whatever this says.
#[must_use]
pub fn curve_splits(options: &BuildOptions) -> Option<CurveSplits> {
    let flags = options.flags;
    if flags.contains(BuildFlags::ALLOW_UPDATE) {
        None
    } else if flags.contains(BuildFlags::PREFER_FAST_TRACE) {
        Some(CurveSplits::FAST_TRACE)
    } else if flags.contains(BuildFlags::PREFER_FAST_BUILD) {
        Some(CurveSplits::FAST_BUILD)
    } else {
        Some(CurveSplits::BALANCED)
    }
}

/// Within each leaf of `tree`, keeps the first of the references that name one primitive
/// (`ids[k]` the primitive of reference `k`): a leaf tests each primitive once. Leaf slots are
/// renumbered in node order, every slot referenced by one leaf.
fn merge_leaf_repeats(tree: &mut Bvh2, ids: &[u32]) {
    let Bvh2 { nodes, prim_order } = tree;
    let mut order = Vec::with_capacity(prim_order.len());
    for node in nodes.iter_mut().filter(|n| n.is_leaf()) {
        let first = order.len();
        let (start, count) = (node.left_first as usize, node.count as usize);
        for &k in &prim_order[start..start + count] {
            let seen = order[first..]
                .iter()
                .any(|&j: &u32| ids[j as usize] == ids[k as usize]);
            if !seen {
                order.push(k);
            }
        }
        node.left_first = first as u32;
        node.count = (order.len() - first) as u32;
    }
    *prim_order = order;
}

/// Gives every inactive primitive of an updatable build a box to be placed by (`fallback`'s
/// box where it is finite and valid, else a point at the centre of the active boxes), so that
/// it has a leaf slot that an update can fill.
fn place_inactive(boxes: &mut [Option<Aabb>], fallback: impl Fn(usize) -> Aabb) {
    let all = boxes.iter().flatten().fold(Aabb::EMPTY, |a, b| a.union(b));
    let centre = if all.is_finite_valid() {
        (all.min + all.max) * 0.5
    } else {
        Vec3::ZERO
    };
    for (i, b) in boxes.iter_mut().enumerate() {
        if b.is_none() {
            let f = fallback(i);
            *b = Some(if f.is_finite_valid() {
                f
            } else {
                Aabb::new(centre, centre)
            });
        }
    }
}

/// Marks an unused lane of a [`Triangle4`] block in [`GasData::slot_prim`].
pub const NO_PRIMITIVE: u32 = u32::MAX;

/// The map from a binary leaf's first slot before packing (`before`, the 4-wide layout's leaf
/// starts in node and lane order) to its first slot after (`after`, in the same order), sorted
/// for lookups: the wide layouts' leaves are the binary tree's.
pub(crate) fn leaf_map(before: &[u32], after: &[u32]) -> Vec<(u32, u32)> {
    let mut map: Vec<(u32, u32)> = before.iter().copied().zip(after.iter().copied()).collect();
    map.sort_unstable();
    map
}

/// The packed first slot of the binary leaf starting at `start`.
fn packed_start(map: &[(u32, u32)], start: u32) -> Option<u32> {
    map.binary_search_by_key(&start, |&(b, _)| b)
        .ok()
        .map(|i| map[i].1)
}

/// Points the leaves of the binary tree at the slots the packing gave them.
pub(crate) fn remap_leaves(mut tree: Bvh2, map: &[(u32, u32)]) -> Bvh2 {
    for node in tree.nodes.iter_mut().filter(|n| n.is_leaf()) {
        if let Some(s) = packed_start(map, node.left_first) {
            node.left_first = s;
        }
    }
    tree
}

/// Points the leaves of another wide layout (collapsed from the same binary tree) at the slots
/// the packing gave them.
pub(crate) fn remap_wide_leaves<N: WideNode>(nodes: &mut [N], map: &[(u32, u32)]) {
    nodes.par_iter_mut().for_each(|n| {
        for l in 0..N::WIDTH {
            if n.count(l) > 0 {
                let s = packed_start(map, n.child(l));
                debug_assert!(s.is_some(), "every leaf of the tree is packed");
                n.set_child(l, s.unwrap_or(u32::MAX));
            }
        }
    });
}

/// Lays the triangles of every leaf out in blocks of four, leaves in node order, and points the
/// leaves at their blocks. `global[slot]` is the primitive at binary-BVH slot `slot`.
pub(crate) fn pack_triangles(
    bvh: &mut Bvh4,
    global: &[u32],
    tris: &[[Vec3; 3]],
) -> (Vec<Triangle4>, Vec<u32>) {
    // Serially: give every leaf its blocks, and note each block's primitives.
    let mut sources: Vec<(u32, u32)> = Vec::new();
    for node in &mut bvh.nodes {
        for lane in 0..4 {
            let n = node.count[lane];
            if n == 0 {
                continue;
            }
            let start = node.child[lane];
            node.child[lane] = (sources.len() * 4) as u32;
            for k in (0..n).step_by(4) {
                sources.push((start + k, (n - k).min(4)));
            }
        }
    }
    // In parallel: fill the blocks and the slot map.
    let blocks: Vec<Triangle4> = sources
        .par_iter()
        .map(|&(start, n)| {
            let mut block = Triangle4::zeroed();
            for l in 0..n as usize {
                let g = global[start as usize + l];
                block.set(l, &tris[g as usize].map(|v| v.to_array()));
            }
            block
        })
        .collect();
    let slot_prim: Vec<u32> = (0..sources.len() * 4)
        .into_par_iter()
        .map(|slot| {
            let (start, n) = sources[slot / 4];
            let l = (slot % 4) as u32;
            if l < n {
                global[(start + l) as usize]
            } else {
                NO_PRIMITIVE
            }
        })
        .collect();
    (blocks, slot_prim)
}

/// Checks that every index of an indexed triangle input is in range.
pub(crate) fn check_indices(at: InputLocation, t: &TriangleInput<'_>) -> Result<(), BuildError> {
    let Some(ix) = &t.indices else { return Ok(()) };
    let stride = ix.effective_stride();
    let nv = t.vertices.count;
    // A plain scan: one compare per index is cheaper than splitting the work.
    for i in 0..ix.count as usize {
        let tri = ix.format.decode(&ix.data[i * stride..]);
        if let Some(&index) = tri.iter().find(|&&v| v >= nv) {
            return Err(BuildError::IndexOutOfRange {
                at,
                triangle: i as u32,
                index,
                num_vertices: nv,
            });
        }
    }
    Ok(())
}

/// Decodes every segment of a validated curve input (without motion: its one key).
fn decode_curves<'a>(c: &'a CurveInput<'_>) -> impl Iterator<Item = CurveSegment> + 'a {
    (0..c.num_primitives as usize).map(move |i| decode_curve(c, i))
}

/// Segment `i` of a validated curve input: its control points and radii, its flat caps where
/// it starts or ends a strand (guide §5.2), and a ribbon's normals `n[start]`, `n[start + 1]`.
pub(crate) fn decode_curve(c: &CurveInput<'_>, i: usize) -> CurveSegment {
    decode_curve_key(c, i, 0)
}

/// Segment `i` of a validated curve input at motion key `key` (see [`decode_curve`]).
pub(crate) fn decode_curve_key(c: &CurveInput<'_>, i: usize, key: usize) -> CurveSegment {
    let start = c.segment_start(c.index_buffer, i) as usize;
    let mut points = [[0.0f32; 4]; 4];
    for (k, p) in points
        .iter_mut()
        .enumerate()
        .take(c.curve_type.control_points())
    {
        let v = c.point(c.vertex_buffers[key], start + k);
        *p = [v.x, v.y, v.z, c.radius(c.width_buffers[key], start + k)];
    }
    let mut flags = 0;
    if c.endcaps == CurveEndcaps::On {
        if c.starts_strand(i) {
            flags |= CAP_START;
        }
        if c.ends_strand(i) {
            flags |= CAP_END;
        }
    }
    let normals = c
        .normal_buffers
        .get(key)
        .map(|n| [c.normal(n, start), c.normal(n, start + 1)]);
    CurveSegment::new(
        c.curve_type,
        &points[..c.curve_type.control_points()],
        flags,
        normals,
    )
}

/// Decodes every sphere of a validated input (its one motion key).
fn decode_spheres<'a>(s: &'a SphereInput<'_>) -> impl Iterator<Item = Sphere> + 'a {
    (0..s.num_vertices as usize).map(move |i| decode_sphere(s, i))
}

/// Sphere `i` of a validated input.
pub(crate) fn decode_sphere(s: &SphereInput<'_>, i: usize) -> Sphere {
    decode_sphere_key(s, i, 0)
}

/// Sphere `i` of a validated input at motion key `key`.
pub(crate) fn decode_sphere_key(s: &SphereInput<'_>, i: usize, key: usize) -> Sphere {
    Sphere::new(
        s.centre(s.vertex_buffers[key], i),
        s.radius(s.radius_buffers[key], i),
    )
}

/// Decodes (and pre-transforms) every triangle of a validated input (one whose indices are in
/// range: [`GasData::prepare`] checks them), in parallel.
#[must_use]
pub fn decode_triangles(t: &TriangleInput<'_>) -> Vec<[Vec3; 3]> {
    let n = t.num_primitives() as usize;
    (0..n)
        .into_par_iter()
        .map(|k| decode_triangle(t, k))
        .collect()
}

/// Decodes (and pre-transforms) triangle `k` of a validated input whose indices are in range.
pub(crate) fn decode_triangle(t: &TriangleInput<'_>, k: usize) -> [Vec3; 3] {
    let v = &t.vertices;
    let vstride = v.effective_stride();
    let vertex = |i: u32| {
        let p = v.format.decode(&v.data[i as usize * vstride..]);
        match &t.pre_transform {
            None => p,
            Some(m) => Vec3::new(
                m[0] * p.x + m[1] * p.y + m[2] * p.z + m[3],
                m[4] * p.x + m[5] * p.y + m[6] * p.z + m[7],
                m[8] * p.x + m[9] * p.y + m[10] * p.z + m[11],
            ),
        }
    };
    let idx = match &t.indices {
        Some(ix) => ix.format.decode(&ix.data[k * ix.effective_stride()..]),
        None => [3 * k as u32, 3 * k as u32 + 1, 3 * k as u32 + 2],
    };
    idx.map(vertex)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use oxray_core::{AabbBuffer, CustomPrimitiveInput, IndexBuffer, VertexBuffer};

    /// The leaf slot ranges reachable in a binary tree, sorted.
    pub(crate) fn tree_leaves(tree: &Bvh2) -> Vec<(u32, u32)> {
        let mut out = Vec::new();
        let mut stack = if tree.nodes.is_empty() {
            vec![]
        } else {
            vec![0usize]
        };
        while let Some(n) = stack.pop() {
            let node = &tree.nodes[n];
            if node.is_leaf() {
                out.push((node.left_first, node.count));
            } else {
                stack.extend([node.left_first as usize, node.left_first as usize + 1]);
            }
        }
        out.sort_unstable();
        out
    }

    /// The leaf slot ranges of the 4-wide layout, sorted.
    pub(crate) fn layout_leaves(gas: &GasData) -> Vec<(u32, u32)> {
        let mut out: Vec<(u32, u32)> = gas
            .bvh
            .nodes
            .iter()
            .flat_map(|n| {
                (0..4)
                    .filter(|&l| n.count[l] > 0)
                    .map(|l| (n.child[l], n.count[l]))
            })
            .collect();
        out.sort_unstable();
        out
    }

    /// An `n` x `n` grid of quads with heights `((x * a + y * 3) % m) * h`, whose diagonal quads
    /// have a degenerate triangle, so that leaf slots and primitive indices differ.
    fn bumpy_grid(n: u32, a: u32, m: u32, h: f32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let mut v = Vec::new();
        for y in 0..=n {
            for x in 0..=n {
                v.push([x as f32, y as f32, ((x * a + y * 3) % m) as f32 * h]);
            }
        }
        let mut t = Vec::new();
        for y in 0..n {
            for x in 0..n {
                let i = y * (n + 1) + x;
                t.push([i, i + 1, i + n + 2]);
                t.push(if x == y {
                    [i, i, i + 1]
                } else {
                    [i, i + n + 2, i + n + 1]
                });
            }
        }
        (v, t)
    }

    #[test]
    fn the_canonical_tree_points_at_the_same_leaf_slots_as_the_4_wide_layout() {
        // A grid with some degenerate triangles, so that slots and primitives differ.
        let (v, t) = bumpy_grid(30, 7, 5, 0.2);
        for flags in [BuildFlags::empty(), BuildFlags::PREFER_FAST_TRACE] {
            let input = TriangleInput::new(VertexBuffer::f32x3(&v)).indices(IndexBuffer::u32x3(&t));
            let options = BuildOptions::new(flags);
            let (gas, tree) = GasData::build_with_tree(&options, &[input.into()]).unwrap();
            // The same structure as a plain build.
            let plain = GasData::build(&options, &[input.into()]).unwrap();
            assert_eq!(gas.bvh.nodes, plain.bvh.nodes);
            assert_eq!(gas.slot_prim, plain.slot_prim);
            let leaves = tree_leaves(&tree);
            assert_eq!(leaves, layout_leaves(&gas));
            // Every active slot is in exactly one leaf, and leaf boxes hold their triangles.
            let covered: u32 = leaves.iter().map(|&(_, c)| c).sum();
            assert_eq!(covered, gas.num_active_primitives());
            assert_eq!(tree.nodes[0].bounds(), gas.bounds);
            for node in tree.nodes.iter().filter(|n| n.is_leaf()) {
                if !leaves.contains(&(node.left_first, node.count)) {
                    continue; // a slot of the node array that no node references
                }
                for slot in node.left_first..node.left_first + node.count {
                    assert_ne!(gas.slot_prim[slot as usize], NO_PRIMITIVE);
                    let tri = gas.triangles[slot as usize / 4].get(slot as usize % 4);
                    for p in tri {
                        assert!(node.bounds().contains(p.into()));
                    }
                }
            }
        }
    }

    /// A room as modelled ones are, its walls leaning by up to 1 % (the Cornell data's), a
    /// light just under the ceiling and a block on the floor: quads of two triangles each.
    fn room() -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let quads: [[[f32; 3]; 4]; 8] = [
            // floor, ceiling, back, left, right (leaning), light, block top, block side
            [
                [0.0, 0.0, 0.0],
                [5.5, 0.0, 0.0],
                [5.5, 0.0, 5.6],
                [0.0, 0.0, 5.6],
            ],
            [
                [0.0, 5.5, 0.0],
                [5.6, 5.5, 0.0],
                [5.6, 5.5, 5.6],
                [0.0, 5.5, 5.6],
            ],
            [
                [0.0, 0.0, 5.6],
                [5.5, 0.0, 5.6],
                [5.6, 5.5, 5.6],
                [0.0, 5.5, 5.6],
            ],
            [
                [0.0, 0.0, 0.0],
                [0.0, 0.0, 5.6],
                [0.0, 5.5, 5.6],
                [0.0, 5.5, 0.0],
            ],
            [
                [5.5, 0.0, 0.0],
                [5.5, 0.0, 5.6],
                [5.6, 5.5, 5.6],
                [5.6, 5.5, 0.0],
            ],
            [
                [2.1, 5.49, 2.2],
                [3.4, 5.49, 2.2],
                [3.4, 5.49, 3.3],
                [2.1, 5.49, 3.3],
            ],
            [
                [1.3, 1.6, 0.6],
                [2.9, 1.6, 1.1],
                [2.4, 1.6, 2.7],
                [0.8, 1.6, 2.2],
            ],
            [
                [1.3, 0.0, 0.6],
                [2.9, 0.0, 1.1],
                [2.9, 1.6, 1.1],
                [1.3, 1.6, 0.6],
            ],
        ];
        let mut v = Vec::new();
        let mut t = Vec::new();
        for q in quads {
            let b = v.len() as u32;
            v.extend(q);
            t.extend([[b, b + 1, b + 2], [b, b + 2, b + 3]]);
        }
        (v, t)
    }

    /// Rays that start inside a room enter the box of any leaf that holds two of its walls
    /// (the box spans the room), which the surface-area heuristic does not count: every build
    /// gives each wall a leaf of its own (`build::face_split`).
    #[test]
    fn the_walls_of_a_room_get_leaves_of_their_own() {
        let (v, t) = room();
        for flags in [
            BuildFlags::empty(),
            BuildFlags::PREFER_FAST_BUILD,
            BuildFlags::PREFER_FAST_TRACE,
        ] {
            let input = TriangleInput::new(VertexBuffer::f32x3(&v)).indices(IndexBuffer::u32x3(&t));
            let options = BuildOptions::new(flags);
            let (gas, tree) = GasData::build_with_tree(&options, &[input.into()]).unwrap();
            for (first, count) in tree_leaves(&tree) {
                let quads: Vec<u32> = (first..first + count)
                    .map(|slot| gas.slot_prim[slot as usize] / 2)
                    .collect();
                assert!(
                    quads.iter().all(|&q| q == quads[0] && q < 5) || quads.iter().all(|&q| q >= 5),
                    "{flags:?}: a leaf holds the quads {quads:?}"
                );
            }
        }
    }

    fn wide_leaves<N: WideNode>(nodes: &[N]) -> Vec<(u32, u32)> {
        let mut out: Vec<(u32, u32)> = nodes
            .iter()
            .flat_map(|n| {
                (0..N::WIDTH)
                    .filter(|&l| n.count(l) > 0)
                    .map(|l| (n.child(l), n.count(l)))
            })
            .collect();
        out.sort_unstable();
        out
    }

    #[test]
    fn the_8_wide_layout_adds_to_the_4_wide_structure_and_shares_its_leaves() {
        let (v, t) = bumpy_grid(40, 5, 7, 0.3);
        let boxes: Vec<Aabb> = (0..300)
            .map(|i| Aabb::new(Vec3::splat(i as f32), Vec3::splat(i as f32 + 0.5)))
            .collect();
        for flags in [
            BuildFlags::empty(),
            BuildFlags::PREFER_FAST_TRACE,
            BuildFlags::ALLOW_UPDATE | BuildFlags::ALLOW_COMPACTION,
        ] {
            let options = BuildOptions::new(flags);
            let tri = TriangleInput::new(VertexBuffer::f32x3(&v)).indices(IndexBuffer::u32x3(&t));
            let custom = CustomPrimitiveInput::new(AabbBuffer::new(&boxes));
            for input in [tri.into(), custom.into()] {
                let four = GasData::build(&options, &[input]).unwrap();
                let eight =
                    GasData::build_with_width(&options, &[input], NodeWidth::Eight).unwrap();
                assert_eq!(four.width(), NodeWidth::Four);
                assert_eq!(eight.width(), NodeWidth::Eight);
                assert_eq!(four.bvh.nodes, eight.bvh.nodes);
                let bytes = |t: &[Triangle4]| bytemuck::cast_slice::<_, u8>(t).to_vec();
                assert!(bytes(&four.triangles) == bytes(&eight.triangles));
                assert_eq!(four.slot_prim, eight.slot_prim);
                let b8 = eight.bvh8.as_ref().unwrap();
                assert_eq!(wide_leaves(&b8.nodes), wide_leaves(&eight.bvh.nodes));
                assert!(eight.memory().node_bytes > four.memory().node_bytes);
                // Saved and loaded with both layouts.
                let back = GasData::from_bytes(&eight.to_bytes()).unwrap();
                assert_eq!(back.bvh8.as_ref().unwrap().nodes, b8.nodes);
                let back = GasData::from_bytes(&four.to_bytes()).unwrap();
                assert!(back.bvh8.is_none());
                if flags.contains(BuildFlags::ALLOW_COMPACTION) {
                    let c = eight.compact().unwrap();
                    assert_eq!(c.compacted_size(), Some(c.memory().output_bytes));
                    assert_eq!(c.memory().output_bytes, eight.compacted_size().unwrap());
                }
            }
        }
    }

    #[test]
    fn custom_primitive_trees_index_the_structure_slots_directly() {
        let boxes: Vec<Aabb> = (0..40)
            .map(|i| Aabb::new(Vec3::splat(i as f32), Vec3::splat(i as f32 + 0.5)))
            .collect();
        let input = CustomPrimitiveInput::new(AabbBuffer::new(&boxes));
        let (gas, tree) =
            GasData::build_with_tree(&BuildOptions::default(), &[input.into()]).unwrap();
        assert_eq!(tree_leaves(&tree), layout_leaves(&gas));
        // No primitives, no tree.
        let none: [Aabb; 0] = [];
        let input = CustomPrimitiveInput::new(AabbBuffer::new(&none));
        let (_, tree) =
            GasData::build_with_tree(&BuildOptions::default(), &[input.into()]).unwrap();
        assert!(tree.nodes.is_empty());
    }
}
