//! Geometry acceleration structures with motion (guide §5.10.2): the primitives at every motion
//! key, under one tree whose boxes bound every key.
//!
//! A primitive interpolated linearly between two keys lies in the convex hull of its two key
//! primitives, so in the union of their boxes: the tree is built over the union of each
//! primitive's key boxes (padded by a few ulps for the rounding of the interpolation), and its
//! nodes are those of a static structure. Key 0 of the primitives lives where a static
//! structure keeps its primitives (`GasData::triangles`, `aabbs`, `spheres`, `curves`), in the same
//! leaf-slot order; keys 1, 2, … live in [`GasMotion`], each a copy of that layout.

use crate::build::{build_bvh2, BuildConfig};
use crate::bvh4::Bvh4;
use crate::curve::{CurveSegment, CurveSplits};
use crate::gas::{
    decode_curve_key, decode_sphere_key, decode_triangles, GasData, GasKind, NodeWidth,
};
use crate::sphere::Sphere;
use crate::triangle::is_degenerate;
use crate::triangle4::Triangle4;
use glam::Vec3;
use oxray_core::motion::lerp;
use oxray_core::motion_transform::pad_motion_box;
use oxray_core::{Aabb, BuildInput, CustomPrimitiveInput, KeySample, MotionOptions, TriangleInput};
use rayon::prelude::*;

/// The motion of a GAS: its options and its primitives at keys 1, 2, … in the leaf-slot
/// layout of key 0. Key `k`'s copy of a table of `n` entries is entries `(k - 1) * n ..`.
#[derive(Clone, Debug, PartialEq)]
pub struct GasMotion {
    /// The build's motion options (more than one key).
    pub options: MotionOptions,
    /// Triangle blocks of keys 1, 2, … (triangle GAS).
    pub triangles: Vec<Triangle4>,
    /// Boxes of keys 1, 2, … (custom-primitive GAS).
    pub aabbs: Vec<Aabb>,
    /// Spheres of keys 1, 2, … (sphere GAS).
    pub spheres: Vec<Sphere>,
    /// Curve segments of keys 1, 2, … (curve GAS), one per leaf slot like key 0's.
    pub curves: Vec<CurveSegment>,
    /// The node boxes of parts of the time range ([`MotionSegments`]); `None` for a
    /// `PREFER_FAST_BUILD` structure, whose rays at every time walk the one tree over each
    /// primitive's union of key boxes.
    pub segments: Option<MotionSegments>,
}

/// The same tree as a motion GAS's, once per part of its time range, each with boxes that bound
/// the primitives only over that part: the key intervals split in `per_interval` equal parts
/// (8, 4, 2 or 1 of them, at most 8 parts for the whole range, one per interval beyond 8
/// intervals). A ray walks the nodes of the part holding its time. The tree over the union of
/// every key's boxes makes a moving primitive's box as large as its whole path; a part's box is
/// that of the path within the part, so rays enter far fewer nodes (measured in
/// `docs/BENCHMARKS.md`, "Motion blur: what it costs, and whether splitting the time range
/// pays"). The leaves, their slots and the primitives are the structure's: only boxes differ,
/// so every hit is the one-tree traversal's.
///
/// Each box is the intersection of the tree's own box with the union of the part's end
/// boxes, grown by a few ulps of the keys' coordinates: a primitive interpolated linearly lies
/// between its positions at the part's ends, and its interpolation in `f32` rounds by at most
/// a few ulps of the larger key.
#[derive(Clone, Debug, PartialEq)]
pub struct MotionSegments {
    /// Parts per key interval: a power of two, so that a ray's part is exact.
    pub per_interval: u32,
    /// The 4-wide nodes of each part, in time order, for a structure without the 8-wide
    /// layout (empty otherwise).
    pub bvh: Vec<Vec<crate::bvh4::Bvh4Node>>,
    /// The 8-wide nodes of each part, in time order, for a structure with the 8-wide layout
    /// (empty otherwise: parts are kept for the layout the 8-wide kernels walk; a 4-wide
    /// kernel forced on such a structure walks the one tree).
    pub bvh8: Vec<Vec<crate::bvh8::Bvh8Node>>,
}

impl MotionSegments {
    /// The most parts a structure is split in; a structure of more key intervals gets one
    /// part per interval up to [`MAX_INTERVALS`](Self::MAX_INTERVALS), and none beyond.
    pub const PARTS: u32 = 8;
    /// The most key intervals a structure has parts for (each part a copy of the nodes).
    pub const MAX_INTERVALS: u32 = 16;

    /// Parts per key interval for `intervals` key intervals, `None` where none are made.
    #[must_use]
    pub fn per_interval(intervals: u32) -> Option<u32> {
        match intervals {
            0 => None,
            n if n > Self::MAX_INTERVALS => None,
            // 8, 4, 2 (for 3 intervals), then 1: every value a power of two.
            n => Some((Self::PARTS / n).max(1)),
        }
    }

    /// The part a ray at key sample `s` walks (the last one at the last key, where a time at
    /// or past the end is clamped).
    #[inline(always)]
    #[must_use]
    pub fn part(&self, s: KeySample) -> usize {
        let m = self.per_interval as usize;
        // `fraction * m` is exact (m is a power of two) and below m for a fraction below 1.
        let j = ((s.fraction * m as f32) as usize).min(m - 1);
        (s.key * m + j).min(self.len().saturating_sub(1))
    }

    /// The number of parts.
    #[must_use]
    pub fn len(&self) -> usize {
        self.bvh.len().max(self.bvh8.len())
    }

    /// Whether there are no parts.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bytes of the parts' nodes.
    #[must_use]
    pub fn bytes(&self) -> usize {
        self.bvh
            .iter()
            .map(|n| std::mem::size_of_val(&n[..]))
            .sum::<usize>()
            + self
                .bvh8
                .iter()
                .map(|n| std::mem::size_of_val(&n[..]))
                .sum::<usize>()
    }
}

impl GasMotion {
    /// Key `key`'s copy of a table whose key 0 is `base` (`later` holding keys 1, 2, …).
    #[inline]
    pub fn key<'a, T>(base: &'a [T], later: &'a [T], key: usize) -> &'a [T] {
        if key == 0 {
            base
        } else {
            let n = base.len();
            &later[(key - 1) * n..key * n]
        }
    }

    pub(crate) fn shrink_to_fit(&mut self) {
        self.triangles.shrink_to_fit();
        self.aabbs.shrink_to_fit();
        self.spheres.shrink_to_fit();
        self.curves.shrink_to_fit();
    }

    /// Bytes of the later keys' primitives and of the time parts' nodes.
    #[must_use]
    pub fn bytes(&self) -> usize {
        std::mem::size_of_val(&self.triangles[..])
            + std::mem::size_of_val(&self.aabbs[..])
            + std::mem::size_of_val(&self.spheres[..])
            + std::mem::size_of_val(&self.curves[..])
            + self.segments.as_ref().map_or(0, MotionSegments::bytes)
    }
}

/// The union of boxes, padded for interpolation; `None` if any key is `None`.
fn union_boxes(keys: impl Iterator<Item = Option<Aabb>>) -> Option<Aabb> {
    let mut out = Aabb::EMPTY;
    for b in keys {
        out = out.union(&b?);
    }
    Some(pad_motion_box(&out))
}

/// Builds a GAS with motion into `gas` (made by `GasData::prepare`): the primitives of every
/// key, the tree over their union boxes, the later keys in [`GasMotion`]. Returns the binary
/// tree the 4-wide one was made from, its leaves naming the structure's leaf slots (what the
/// CUDA backend uploads).
pub(crate) fn build_motion(
    gas: &mut GasData,
    motion: MotionOptions,
    inputs: &[BuildInput<'_>],
    config: &BuildConfig,
    width: NodeWidth,
    curve_splits: Option<CurveSplits>,
) -> crate::Bvh2 {
    let keys = motion.key_count();
    let mut out = GasMotion {
        options: motion,
        triangles: Vec::new(),
        aabbs: Vec::new(),
        spheres: Vec::new(),
        curves: Vec::new(),
        segments: None,
    };
    let tree = match gas.kind {
        GasKind::Triangles => {
            let per_key: Vec<Vec<[Vec3; 3]>> = (0..keys)
                .map(|key| {
                    inputs
                        .iter()
                        .flat_map(|input| match input {
                            BuildInput::Triangles(t) => {
                                let vertices = *t.vertex_key(key).unwrap_or(&t.vertices);
                                decode_triangles(&TriangleInput { vertices, ..*t })
                            }
                            _ => unreachable!("inputs are homogeneous"),
                        })
                        .collect()
                })
                .collect();
            // Active: finite at every key and not degenerate at some key (a triangle that
            // degenerates at one instant is still hit at the others).
            let boxes: Vec<Option<Aabb>> = (0..per_key[0].len())
                .into_par_iter()
                .map(|i| {
                    let finite = per_key.iter().all(|k| k[i].iter().all(|p| p.is_finite()));
                    let area = per_key
                        .iter()
                        .any(|k| !is_degenerate(k[i][0], k[i][1], k[i][2]));
                    if !(finite && area) {
                        return None;
                    }
                    union_boxes(per_key.iter().map(|k| Some(Aabb::from_points(&k[i]))))
                })
                .collect();
            let (ids, bounds): (Vec<u32>, Vec<Aabb>) = boxes
                .iter()
                .enumerate()
                .filter_map(|(i, b)| b.map(|b| (i as u32, b)))
                .unzip();
            let bvh2 = build_bvh2(&bounds, config);
            gas.bounds = bvh2.nodes.first().map_or(Aabb::EMPTY, |n| n.bounds());
            let unpacked = Bvh4::from(&bvh2);
            let global: Vec<u32> = bvh2
                .prim_order
                .par_iter()
                .map(|&k| ids[k as usize])
                .collect();
            // Packing is deterministic: every key packs into the same layout.
            for (key, tris) in per_key.iter().enumerate() {
                let mut bvh = unpacked.clone();
                let (blocks, slots) = crate::gas::pack_triangles(&mut bvh, &global, tris);
                if key == 0 {
                    (gas.bvh, gas.triangles, gas.slot_prim) = (bvh, blocks, slots);
                } else {
                    out.triangles.extend_from_slice(&blocks);
                }
            }
            // Packing moved the leaves' first slots: the other layouts follow.
            let map = crate::gas::leaf_map(
                &crate::wide::leaf_starts(&unpacked.nodes),
                &crate::wide::leaf_starts(&gas.bvh.nodes),
            );
            if width == NodeWidth::Eight {
                let mut b8 = crate::bvh8::Bvh8::from(&bvh2);
                crate::gas::remap_wide_leaves(&mut b8.nodes, &map);
                gas.bvh8 = Some(b8);
            }
            crate::gas::remap_leaves(bvh2, &map)
        }
        GasKind::CustomPrimitives => {
            let per_key: Vec<Vec<Aabb>> = (0..keys)
                .map(|key| {
                    inputs
                        .iter()
                        .flat_map(|input| match input {
                            BuildInput::CustomPrimitives(c) => {
                                let buf = *c.aabb_key(key).unwrap_or(&c.aabbs);
                                (0..buf.count as usize)
                                    .map(move |i| CustomPrimitiveInput::aabb(&buf, i))
                            }
                            _ => unreachable!("inputs are homogeneous"),
                        })
                        .collect()
                })
                .collect();
            // A primitive is active where every key's box is valid.
            let boxes: Vec<Option<Aabb>> = (0..per_key[0].len())
                .map(|i| {
                    union_boxes(
                        per_key
                            .iter()
                            .map(|k| k[i].is_finite_valid().then_some(k[i])),
                    )
                })
                .collect();
            let tree = gas.build_slots(&boxes, config, width);
            for (key, b) in per_key.iter().enumerate() {
                let slotted = gas.slot_prim.iter().map(|&g| b[g as usize]);
                if key == 0 {
                    gas.aabbs = slotted.collect();
                } else {
                    out.aabbs.extend(slotted);
                }
            }
            tree
        }
        GasKind::Spheres => {
            let per_key: Vec<Vec<Sphere>> = (0..keys)
                .map(|key| {
                    inputs
                        .iter()
                        .flat_map(|input| match input {
                            BuildInput::Spheres(s) => (0..s.num_vertices as usize)
                                .map(move |i| decode_sphere_key(s, i, key)),
                            _ => unreachable!("inputs are homogeneous"),
                        })
                        .collect()
                })
                .collect();
            // A sphere interpolated between two keys lies in the union of their boxes: its
            // centre is on the segment and its radius at most the larger one.
            let boxes: Vec<Option<Aabb>> = (0..per_key[0].len())
                .map(|i| {
                    union_boxes(
                        per_key
                            .iter()
                            .map(|k| k[i].is_active().then(|| k[i].bounds())),
                    )
                })
                .collect();
            let tree = gas.build_slots(&boxes, config, width);
            for (key, s) in per_key.iter().enumerate() {
                let slotted = gas.slot_prim.iter().map(|&g| s[g as usize]);
                if key == 0 {
                    gas.spheres = slotted.collect();
                } else {
                    out.spheres.extend(slotted);
                }
            }
            tree
        }
        GasKind::Curves => {
            let per_key: Vec<Vec<CurveSegment>> = (0..keys)
                .map(|key| {
                    inputs
                        .iter()
                        .flat_map(|input| match input {
                            BuildInput::Curves(c) => (0..c.num_primitives as usize)
                                .map(move |i| decode_curve_key(c, i, key)),
                            _ => unreachable!("inputs are homogeneous"),
                        })
                        .collect()
                })
                .collect();
            // A segment interpolated between two keys has the interpolated control points, and
            // every bound here is a hull of (linear combinations of) control points grown by a
            // largest radius: the union of the keys' boxes bounds it. A segment is active
            // where it is at every key.
            let active: Vec<bool> = (0..per_key[0].len())
                .into_par_iter()
                .map(|i| per_key.iter().all(|k| k[i].is_active()))
                .collect();
            let ids: Vec<u32> = (0..active.len() as u32)
                .filter(|&i| active[i as usize])
                .collect();
            // §9.2 splitting with motion: each piece bounded by the union of its keys' boxes
            // of the same parameter interval, as many pieces as the longest key needs.
            let splittable = curve_splits.and_then(|_| gas.splittable(&ids));
            let (ref_ids, ref_bounds): (Vec<u32>, Vec<Aabb>) = ids
                .par_iter()
                .enumerate()
                .flat_map_iter(|(j, &g)| {
                    let segment = move |k: &Vec<CurveSegment>| k[g as usize];
                    let n = match (curve_splits, &splittable) {
                        (Some(cs), Some(split)) if split[j] => per_key
                            .iter()
                            .map(|k| segment(k).pieces(&cs))
                            .max()
                            .unwrap_or(1),
                        _ => 1,
                    };
                    let per_key = &per_key;
                    (0..n).map(move |p| {
                        let u = |p: u32| p as f64 / n as f64;
                        let b = union_boxes(per_key.iter().map(|k| {
                            Some(if n == 1 {
                                segment(k).bounds()
                            } else {
                                segment(k).bounds_over(u(p), u(p + 1))
                            })
                        }));
                        (g, b.expect("every key's box is given"))
                    })
                })
                .unzip();
            let repeats = ref_ids.len() > ids.len();
            let tree = gas.build_slot_refs(&ref_ids, &ref_bounds, repeats, config, width);
            for (key, segments) in per_key.iter().enumerate() {
                let slotted = gas.slot_prim.iter().map(|&g| segments[g as usize]);
                if key == 0 {
                    gas.curves = slotted.collect();
                } else {
                    out.curves.extend(slotted);
                }
            }
            tree
        }
    };
    gas.motion = Some(out);
    if !gas
        .build_flags
        .contains(oxray_core::BuildFlags::PREFER_FAST_BUILD)
    {
        gas.build_motion_segments();
    }
    tree
}

/// A box grown by `pad` on every side (an empty box stays empty).
fn grow(b: Aabb, pad: f32) -> Aabb {
    if b.is_valid() {
        Aabb::new(b.min - Vec3::splat(pad), b.max + Vec3::splat(pad))
    } else {
        b
    }
}

/// The common part of two boxes (empty where they do not meet).
fn meet(a: &Aabb, b: &Aabb) -> Aabb {
    let out = Aabb::new(a.min.max(b.min), a.max.min(b.max));
    if out.is_valid() {
        out
    } else {
        Aabb::EMPTY
    }
}

/// A copy of `nodes` whose boxes are `leaf`'s for leaf lanes and the union of the child's
/// lanes for inner ones, each met with the original lane's box (children follow their parents
/// in the array).
fn part_nodes<N: crate::wide::WideNode>(
    nodes: &[N],
    leaf: impl Fn(u32, u32) -> Aabb + Sync + Send,
) -> Vec<N> {
    let mut out = nodes.to_vec();
    out.par_iter_mut().for_each(|n| {
        for lane in 0..N::WIDTH {
            if n.count(lane) > 0 {
                let b = meet(&leaf(n.child(lane), n.count(lane)), &n.child_bounds(lane));
                n.set_bounds(lane, &b);
            }
        }
    });
    for i in (0..out.len()).rev() {
        for lane in 0..N::WIDTH {
            let (child, count) = (out[i].child(lane), out[i].count(lane));
            if count == 0 && child != u32::MAX {
                let b = meet(&out[child as usize].bounds(), &nodes[i].child_bounds(lane));
                out[i].set_bounds(lane, &b);
            }
        }
    }
    out
}

impl GasData {
    /// The box of leaf slot `slot` over key interval `key` .. `key + 1` from fraction `f0` to
    /// `f1`, grown for the rounding of the interpolation; empty for an inactive slot.
    fn slot_box_over(&self, slot: usize, key: usize, f0: f32, f1: f32) -> Aabb {
        if !self.slot_is_active(slot) {
            return Aabb::EMPTY;
        }
        let s = KeySample {
            key,
            next: key + 1,
            fraction: 0.0,
        };
        let at = |f: f32| -> Aabb {
            match self.kind {
                GasKind::Triangles => {
                    let (a, b) = self.triangle_keys(s);
                    let t = lerp_triangle4(&a[slot / 4], &b[slot / 4], f).get(slot % 4);
                    Aabb::from_points(&t.map(Vec3::from))
                }
                GasKind::CustomPrimitives => {
                    let (a, b) = self.aabb_keys(s);
                    lerp_aabb(&a[slot], &b[slot], f)
                }
                GasKind::Spheres => {
                    let (a, b) = self.sphere_keys(s);
                    lerp_sphere(&a[slot], &b[slot], f).bounds()
                }
                GasKind::Curves => {
                    let (a, b) = self.curve_keys(s);
                    lerp_curve(&a[slot], &b[slot], f).bounds()
                }
            }
        };
        let (k0, k1) = (at(0.0), at(1.0));
        if !(k0.is_finite_valid() && k1.is_finite_valid()) {
            // A key where the primitive is not hit: the tree's own box stands.
            return Aabb::new(Vec3::splat(f32::NEG_INFINITY), Vec3::splat(f32::INFINITY));
        }
        // `lerp` rounds by under 3 ulps of the larger operand, at the part's ends as at the
        // ray's fraction: 8 ulps of the keys' largest coordinate cover both.
        let scale = [k0.min, k0.max, k1.min, k1.max]
            .iter()
            .map(|v| v.abs().max_element())
            .fold(0.0f32, f32::max);
        let pad = scale * 8.0 * f32::EPSILON + f32::MIN_POSITIVE;
        grow(at(f0).union(&at(f1)), pad)
    }

    /// Makes (again) the time parts of a motion GAS ([`MotionSegments`]) from its tree and
    /// primitives; nothing for a static structure or one of more than
    /// [`MotionSegments::MAX_INTERVALS`] key intervals.
    pub fn build_motion_segments(&mut self) {
        let Some(motion) = &self.motion else { return };
        let intervals = motion.options.key_count().saturating_sub(1) as u32;
        let Some(m) = MotionSegments::per_interval(intervals) else {
            return;
        };
        let parts = (intervals * m) as usize;
        let this: &GasData = self;
        let leaf = |part: usize| {
            let key = part / m as usize;
            let j = (part % m as usize) as f32;
            let (f0, f1) = (j / m as f32, (j + 1.0) / m as f32);
            move |first: u32, count: u32| {
                (first..first + count).fold(Aabb::EMPTY, |b, slot| {
                    b.union(&this.slot_box_over(slot as usize, key, f0, f1))
                })
            }
        };
        // Parts of the layout the structure's widest kernel walks.
        let (bvh, bvh8) = match &this.bvh8 {
            Some(b8) => (
                Vec::new(),
                (0..parts).map(|p| part_nodes(&b8.nodes, leaf(p))).collect(),
            ),
            None => (
                (0..parts)
                    .map(|p| part_nodes(&this.bvh.nodes, leaf(p)))
                    .collect(),
                Vec::new(),
            ),
        };
        let segments = MotionSegments {
            per_interval: m,
            bvh,
            bvh8,
        };
        if let Some(motion) = &mut self.motion {
            motion.segments = Some(segments);
        }
    }
}

/// Four triangles interpolated lane by lane between two keys' blocks (key `a` exactly where
/// `f` is 0).
#[inline(always)]
#[must_use]
pub fn lerp_triangle4(a: &Triangle4, b: &Triangle4, f: f32) -> Triangle4 {
    let mut out = *a;
    if f == 0.0 {
        // Key `a` itself, signs of zeros included.
        return out;
    }
    for (o, bv) in out.v.iter_mut().zip(&b.v) {
        for (oa, ba) in o.iter_mut().zip(bv) {
            for (x, &y) in oa.iter_mut().zip(ba) {
                *x = lerp(*x, y, f);
            }
        }
    }
    out
}

/// A box interpolated corner by corner between two keys (guide §5.10.1).
#[inline(always)]
#[must_use]
pub fn lerp_aabb(a: &Aabb, b: &Aabb, f: f32) -> Aabb {
    Aabb::new(
        Vec3::from_array(std::array::from_fn(|i| lerp(a.min[i], b.min[i], f))),
        Vec3::from_array(std::array::from_fn(|i| lerp(a.max[i], b.max[i], f))),
    )
}

/// A sphere interpolated between two keys: centre and radius linearly (guide §5.10.2).
#[inline(always)]
#[must_use]
pub fn lerp_sphere(a: &Sphere, b: &Sphere, f: f32) -> Sphere {
    Sphere {
        center: std::array::from_fn(|i| lerp(a.center[i], b.center[i], f)),
        radius: lerp(a.radius, b.radius, f),
    }
}

/// A curve segment interpolated between two keys: control points, radii and ribbon normals
/// linearly (guide §5.10.2); its type, caps and flags are key `a`'s (every key has the same).
#[inline(always)]
#[must_use]
pub fn lerp_curve(a: &CurveSegment, b: &CurveSegment, f: f32) -> CurveSegment {
    if f == 0.0 {
        return *a;
    }
    CurveSegment {
        points: std::array::from_fn(|i| {
            std::array::from_fn(|d| lerp(a.points[i][d], b.points[i][d], f))
        }),
        normals: std::array::from_fn(|i| {
            std::array::from_fn(|d| lerp(a.normals[i][d], b.normals[i][d], f))
        }),
        ..*a
    }
}

impl GasData {
    /// The motion keys a ray at `time` sees (guide §5.10.1): [`KeySample::STATIC`] without
    /// motion, `None` where the structure vanishes.
    #[inline]
    #[must_use]
    pub fn key_sample(&self, time: f32) -> Option<KeySample> {
        match &self.motion {
            None => Some(KeySample::STATIC),
            Some(m) => m.options.sample(time),
        }
    }

    /// The box around the active primitives at each motion key (one box without motion): the
    /// emitted property `AABBS` (guide §5.8, one per key).
    #[must_use]
    pub fn key_bounds(&self) -> Vec<Aabb> {
        let keys = self.motion_options().key_count();
        (0..keys)
            .map(|key| {
                let s = KeySample {
                    key,
                    next: key,
                    fraction: 0.0,
                };
                let mut out = Aabb::EMPTY;
                for slot in (0..self.slot_prim.len()).filter(|&i| self.slot_is_active(i)) {
                    let b = match self.kind {
                        GasKind::Triangles => {
                            let t = self.triangle_keys(s).0[slot / 4].get(slot % 4);
                            Aabb::from_points(&t.map(Vec3::from))
                        }
                        GasKind::CustomPrimitives => self.aabb_keys(s).0[slot],
                        GasKind::Spheres => self.sphere_keys(s).0[slot].bounds(),
                        GasKind::Curves => self.curve_keys(s).0[slot].bounds(),
                    };
                    out = out.union(&b);
                }
                out
            })
            .collect()
    }

    /// The motion options (the default, no motion, for a static structure).
    #[must_use]
    pub fn motion_options(&self) -> MotionOptions {
        self.motion
            .as_ref()
            .map_or(MotionOptions::NONE, |m| m.options)
    }

    /// The triangle blocks of two keys (both key 0 without motion).
    #[inline]
    #[must_use]
    pub fn triangle_keys(&self, s: KeySample) -> (&[Triangle4], &[Triangle4]) {
        match &self.motion {
            None => (&self.triangles, &self.triangles),
            Some(m) => (
                GasMotion::key(&self.triangles, &m.triangles, s.key),
                GasMotion::key(&self.triangles, &m.triangles, s.next),
            ),
        }
    }

    /// The boxes of two keys (both key 0 without motion).
    #[inline]
    #[must_use]
    pub fn aabb_keys(&self, s: KeySample) -> (&[Aabb], &[Aabb]) {
        match &self.motion {
            None => (&self.aabbs, &self.aabbs),
            Some(m) => (
                GasMotion::key(&self.aabbs, &m.aabbs, s.key),
                GasMotion::key(&self.aabbs, &m.aabbs, s.next),
            ),
        }
    }

    /// The spheres of two keys (both key 0 without motion).
    #[inline]
    #[must_use]
    pub fn sphere_keys(&self, s: KeySample) -> (&[Sphere], &[Sphere]) {
        match &self.motion {
            None => (&self.spheres, &self.spheres),
            Some(m) => (
                GasMotion::key(&self.spheres, &m.spheres, s.key),
                GasMotion::key(&self.spheres, &m.spheres, s.next),
            ),
        }
    }

    /// The curve segments of two keys (both key 0 without motion).
    #[inline]
    #[must_use]
    pub fn curve_keys(&self, s: KeySample) -> (&[CurveSegment], &[CurveSegment]) {
        match &self.motion {
            None => (&self.curves, &self.curves),
            Some(m) => (
                GasMotion::key(&self.curves, &m.curves, s.key),
                GasMotion::key(&self.curves, &m.curves, s.next),
            ),
        }
    }

    /// The triangle of leaf slot `slot` at `time` (interpolated between its keys; clamped
    /// outside the range, and key 0's where the structure vanishes); `None` for a slot out of
    /// range or a structure of another kind.
    #[must_use]
    pub fn triangle_at(&self, slot: usize, time: f32) -> Option<[[f32; 3]; 3]> {
        let s = self.key_sample(time).unwrap_or(KeySample::STATIC);
        let (a, b) = self.triangle_keys(s);
        let (a, b) = (a.get(slot / 4)?, b.get(slot / 4)?);
        Some(lerp_triangle4(a, b, s.fraction).get(slot % 4))
    }

    /// The box of leaf slot `slot` at `time` (see [`triangle_at`](Self::triangle_at)).
    #[must_use]
    pub fn aabb_at(&self, slot: usize, time: f32) -> Option<Aabb> {
        let s = self.key_sample(time).unwrap_or(KeySample::STATIC);
        let (a, b) = self.aabb_keys(s);
        Some(lerp_aabb(a.get(slot)?, b.get(slot)?, s.fraction))
    }

    /// The sphere of leaf slot `slot` at `time` (see [`triangle_at`](Self::triangle_at)).
    #[must_use]
    pub fn sphere_at(&self, slot: usize, time: f32) -> Option<Sphere> {
        let s = self.key_sample(time).unwrap_or(KeySample::STATIC);
        let (a, b) = self.sphere_keys(s);
        Some(lerp_sphere(a.get(slot)?, b.get(slot)?, s.fraction))
    }

    /// The curve segment of leaf slot `slot` at `time` (see [`triangle_at`](Self::triangle_at)).
    #[must_use]
    pub fn curve_at(&self, slot: usize, time: f32) -> Option<CurveSegment> {
        let s = self.key_sample(time).unwrap_or(KeySample::STATIC);
        let (a, b) = self.curve_keys(s);
        Some(lerp_curve(a.get(slot)?, b.get(slot)?, s.fraction))
    }
}
