//! Saving built structures to bytes and loading them back: serialization, beyond guide §5.7's
//! relocation (which copies a structure within or between devices of one kind). The format is
//! versioned and checksummed, and the loader trusts nothing: the header's magic number,
//! version and payload length are checked first, every array's size is checked against the
//! bytes left before anything is allocated (so memory stays within a small multiple of the
//! input's size), and every index is range-checked — the tree must be a tree whose children
//! follow their parents, no deeper than traversal's fixed stack allows, with leaves inside the
//! primitive arrays — so that damaged bytes give a typed [`LoadError`], never a panic, a hang
//! or undefined behaviour. A loaded structure traces bit-identical hits.
//!
//! An IAS is saved without its children; as OptiX's relocation takes "one relocated
//! traversable per instance", the caller gives the children back when loading, by instance
//! index.
//!
//! Layout (little-endian): magic `OXRAYAS\0`, version (`u32`), kind (`u32`: 1 GAS, 2 IAS),
//! payload length (`u64`), checksum of the payload (`u64`), then the payload: a fixed header
//! of scalars and array lengths, then the arrays. Version 2 added a GAS's 8-wide layout (an
//! array that may be empty), checked as strictly as the 4-wide one; version 3 added sphere
//! structures (a primitive kind, an array of spheres after the boxes, and a sphere input's
//! `singleRadius` in its shape); version 4 added curve structures (a primitive kind, an array
//! of curve segments after the input shapes, and a curve input's type, end caps and normals in
//! its shape); version 5 added motion (guide §5.10.2: a GAS's motion options and its
//! primitives at keys 1, 2, …, after the other arrays); version 6 added curves with motion (a
//! fourth array of later keys' primitives: curve segments). Versions 1 to 5 are still read.

use crate::bvh4::{Bvh4, Bvh4Node};
use crate::bvh8::{Bvh8, Bvh8Node};
use crate::curve::CurveSegment;
use crate::gas::{GasData, GasKind, InputRecord, InputShape, NO_PRIMITIVE};
use crate::ias::{validate_instance, IasData, InstanceData};
use crate::motion::GasMotion;
use crate::sphere::Sphere;
use crate::triangle4::Triangle4;
use crate::wide::WideNode;
use crate::MAX_BVH2_DEPTH;
use bytemuck::Pod;
use oxray_core::{
    Aabb, BuildError, BuildFlags, BuildInputKind, GeometryFlags, Instance, InstanceFlags,
    LoadError, MotionFlags, MotionOptions, Transform, TraversableHandle, MAX_PRIMITIVES_PER_GAS,
    MAX_SBT_RECORDS_PER_GAS,
};

/// The first bytes of every saved structure.
pub const MAGIC: [u8; 8] = *b"OXRAYAS\0";
/// The version this build writes. It reads it and every earlier version.
pub const FORMAT_VERSION: u32 = 6;
/// The first version with a GAS's optional 8-wide layout (version 1 has none).
const VERSION_BVH8: u32 = 2;
/// The first version with spheres (earlier ones have no sphere array).
const VERSION_SPHERES: u32 = 3;
/// The first version with curves (earlier ones have no curve array).
const VERSION_CURVES: u32 = 4;
/// The first version with motion (earlier ones have no motion section).
const VERSION_MOTION: u32 = 5;
/// The first version with curves with motion (earlier ones have three motion arrays).
const VERSION_MOTION_CURVES: u32 = 6;
const KIND_GAS: u32 = 1;
const KIND_IAS: u32 = 2;
const HEADER: usize = 8 + 4 + 4 + 8 + 8;

/// A 64-bit checksum of the payload (multiply-rotate over 8-byte words, then the length).
#[must_use]
pub fn checksum(bytes: &[u8]) -> u64 {
    const P: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut h: u64 = 0xCBF2_9CE4_8422_2325;
    let mut chunks = bytes.chunks_exact(8);
    for c in &mut chunks {
        let w = u64::from_le_bytes(c.try_into().unwrap_or([0; 8]));
        h = (h ^ w).wrapping_mul(P).rotate_left(29);
    }
    let mut tail = [0u8; 8];
    tail[..chunks.remainder().len()].copy_from_slice(chunks.remainder());
    h = (h ^ u64::from_le_bytes(tail))
        .wrapping_mul(P)
        .rotate_left(29);
    (h ^ bytes.len() as u64).wrapping_mul(P) ^ (h >> 32)
}

fn invalid(what: &'static str, index: usize) -> LoadError {
    LoadError::Invalid {
        what,
        index: index as u64,
    }
}

/// Appends little-endian scalars and arrays.
struct Writer(Vec<u8>);

impl Writer {
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn aabb(&mut self, b: &Aabb) {
        self.pod(&[*b]);
    }
    fn pod<T: Pod>(&mut self, v: &[T]) {
        self.0.extend_from_slice(bytemuck::cast_slice(v));
    }
}

/// Reads what [`Writer`] wrote, checking every length before allocating.
struct Reader<'a> {
    bytes: &'a [u8],
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: u64, what: &'static str) -> Result<&'a [u8], LoadError> {
        if n > self.bytes.len() as u64 {
            return Err(LoadError::Truncated {
                what,
                needed: n,
                available: self.bytes.len() as u64,
            });
        }
        let (head, rest) = self.bytes.split_at(n as usize);
        self.bytes = rest;
        Ok(head)
    }
    fn u32(&mut self, what: &'static str) -> Result<u32, LoadError> {
        let b = self.take(4, what)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn u64(&mut self, what: &'static str) -> Result<u64, LoadError> {
        let b = self.take(8, what)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(u64::from_le_bytes(a))
    }
    fn aabb(&mut self, what: &'static str) -> Result<Aabb, LoadError> {
        Ok(self.array::<Aabb>(1, what)?[0])
    }
    /// `count` elements of `T`; the bytes are checked to be there before the allocation.
    fn array<T: Pod>(&mut self, count: u64, what: &'static str) -> Result<Vec<T>, LoadError> {
        let size = std::mem::size_of::<T>() as u64;
        let n = count.checked_mul(size).ok_or(LoadError::Truncated {
            what,
            needed: u64::MAX,
            available: self.bytes.len() as u64,
        })?;
        let b = self.take(n, what)?;
        Ok(bytemuck::pod_collect_to_vec(b))
    }
}

fn frame(kind: u32, payload: Vec<u8>) -> Vec<u8> {
    let mut w = Writer(Vec::with_capacity(HEADER + payload.len()));
    w.0.extend_from_slice(&MAGIC);
    w.u32(FORMAT_VERSION);
    w.u32(kind);
    w.u64(payload.len() as u64);
    w.u64(checksum(&payload));
    w.0.extend_from_slice(&payload);
    w.0
}

fn kind_name(kind: u32) -> &'static str {
    match kind {
        KIND_GAS => "GAS",
        KIND_IAS => "IAS",
        _ => "structure of unknown kind",
    }
}

/// Checks the header; returns the version and the payload.
fn unframe(bytes: &[u8], want: u32) -> Result<(u32, &[u8]), LoadError> {
    if cfg!(target_endian = "big") {
        return Err(LoadError::Unsupported("loading on a big-endian host"));
    }
    let mut r = Reader { bytes };
    if r.take(8, "the magic number").ok() != Some(&MAGIC[..]) {
        return Err(LoadError::BadMagic);
    }
    let version = r.u32("the version")?;
    if version == 0 || version > FORMAT_VERSION {
        return Err(LoadError::UnsupportedVersion {
            found: version,
            supported: FORMAT_VERSION,
        });
    }
    let kind = r.u32("the kind")?;
    if kind != want {
        return Err(LoadError::WrongKind {
            expected: kind_name(want),
            found: kind_name(kind),
        });
    }
    let len = r.u64("the payload length")?;
    let stored = r.u64("the checksum")?;
    let payload = r.take(len, "the payload")?;
    if !r.bytes.is_empty() {
        return Err(LoadError::TrailingBytes(r.bytes.len() as u64));
    }
    let computed = checksum(payload);
    if computed != stored {
        return Err(LoadError::Checksum { stored, computed });
    }
    Ok((version, payload))
}

/// Checks a wide node array: every used lane's child is a later node referenced once, no
/// deeper than the traversal stack allows, every unused lane has the empty box that no ray
/// enters, and every leaf lies in `[0, slots)` (starting a triangle block where `block` is 4).
/// `leaf_ok(slots)` checks a leaf's slots further.
fn check_nodes<N: WideNode>(
    nodes: &[N],
    slots: u64,
    block: u64,
    mut leaf_ok: impl FnMut(std::ops::Range<usize>) -> bool,
) -> Result<(), LoadError> {
    if nodes.is_empty() {
        return Err(invalid("node count (a structure has a root node)", 0));
    }
    let mut depth = vec![0u32; nodes.len()];
    let mut referenced = vec![false; nodes.len()];
    for (i, n) in nodes.iter().enumerate() {
        for lane in 0..N::WIDTH {
            let (child, count) = (n.child(lane), n.count(lane));
            if count == 0 && child == u32::MAX {
                let empty = (0..3).all(|a| {
                    n.bound(a, lane) == f32::INFINITY && n.bound(3 + a, lane) == f32::NEG_INFINITY
                });
                if !empty {
                    return Err(invalid("unused node lane with a box", i));
                }
            } else if count == 0 {
                let c = child as usize;
                if c <= i || c >= nodes.len() || referenced[c] {
                    return Err(invalid("inner node child", i));
                }
                referenced[c] = true;
                depth[c] = depth[i] + 1;
                if depth[c] as usize >= MAX_BVH2_DEPTH {
                    return Err(invalid("tree depth", c));
                }
            } else {
                let end = child as u64 + count as u64;
                if end > slots
                    || !(child as u64).is_multiple_of(block)
                    || !leaf_ok(child as usize..end as usize)
                {
                    return Err(invalid("leaf slot range", i));
                }
            }
        }
    }
    Ok(())
}

/// The code of a primitive kind in the format.
fn kind_code(kind: GasKind) -> u32 {
    match kind {
        GasKind::Triangles => 0,
        GasKind::CustomPrimitives => 1,
        GasKind::Spheres => 2,
        GasKind::Curves => 3,
    }
}

/// The primitive kind of a code, in a format of `version`.
fn kind_of(code: u32, version: u32) -> Option<GasKind> {
    match code {
        0 => Some(GasKind::Triangles),
        1 => Some(GasKind::CustomPrimitives),
        2 if version >= VERSION_SPHERES => Some(GasKind::Spheres),
        3 if version >= VERSION_CURVES => Some(GasKind::Curves),
        _ => None,
    }
}

/// Reads a GAS's motion section (version 5; version 6 adds curves): options valid for a
/// structure, and exactly `keys - 1` copies of the primitive array of its kind (`lens`:
/// triangle blocks, boxes, spheres, curve segments of key 0), none of the others. An updatable
/// structure has no motion.
fn read_motion(
    r: &mut Reader<'_>,
    version: u32,
    kind: GasKind,
    build_flags: BuildFlags,
    lens: [u64; 4],
) -> Result<Option<GasMotion>, LoadError> {
    let num_keys = r.u32("the motion keys")?;
    let flags = r.u32("the motion flags")?;
    let time_begin = f32::from_bits(r.u32("the motion begin")?);
    let time_end = f32::from_bits(r.u32("the motion end")?);
    let mut counts = [0u64; 4];
    for (i, c) in counts.iter_mut().enumerate() {
        // Version 5 has no curve segments with motion.
        if i != 3 || version >= VERSION_MOTION_CURVES {
            *c = r.u64("the motion array lengths")?;
        }
    }
    let triangles: Vec<Triangle4> = r.array(counts[0], "the motion triangles")?;
    let aabbs: Vec<Aabb> = r.array(counts[1], "the motion boxes")?;
    let spheres: Vec<Sphere> = r.array(counts[2], "the motion spheres")?;
    let curves: Vec<CurveSegment> = r.array(counts[3], "the motion curve segments")?;
    let options = MotionOptions {
        num_keys: u16::try_from(num_keys).map_err(|_| invalid("motion keys", 0))?,
        flags: u16::try_from(flags)
            .ok()
            .and_then(MotionFlags::from_bits)
            .ok_or(invalid("motion flags", 0))?,
        time_begin,
        time_end,
    };
    if !options.has_motion() {
        // No motion: nothing else may be set.
        if num_keys != 0 || flags != 0 || counts != [0; 4] || time_begin != 0.0 || time_end != 0.0 {
            return Err(invalid("motion options", 0));
        }
        return Ok(None);
    }
    if options.validate_for_structure().is_err() || build_flags.contains(BuildFlags::ALLOW_UPDATE) {
        return Err(invalid("motion options", 0));
    }
    let later = options.key_count() as u64 - 1;
    let own = match kind {
        GasKind::Triangles => 0,
        GasKind::CustomPrimitives => 1,
        GasKind::Spheres => 2,
        GasKind::Curves => 3,
    };
    for (i, (&n, &base)) in counts.iter().zip(&lens).enumerate() {
        let expected = if i == own { later * base } else { 0 };
        if n != expected {
            return Err(invalid("motion array length", i));
        }
    }
    Ok(Some(GasMotion {
        options,
        triangles,
        aabbs,
        spheres,
        curves,
        segments: None,
    }))
}

impl GasData {
    /// Saves the structure as bytes that [`GasData::from_bytes`] loads back, on this machine
    /// or another, into a structure with bit-identical hits.
    ///
    /// ```
    /// use oxray_bvh::GasData;
    /// use oxray_core::{BuildOptions, TriangleInput, VertexBuffer};
    /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    /// let gas = GasData::build(&BuildOptions::default(), &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
    /// let bytes = gas.to_bytes();
    /// let back = GasData::from_bytes(&bytes).unwrap();
    /// assert_eq!(back.bvh.nodes, gas.bvh.nodes);
    /// assert!(GasData::from_bytes(&bytes[..bytes.len() - 1]).is_err());
    /// # Ok::<(), oxray_core::BuildError>(())
    /// ```
    #[must_use]
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut w = Writer(Vec::new());
        w.u32(kind_code(self.kind));
        w.u32(self.build_flags.bits());
        w.u32(self.num_primitives);
        w.aabb(&self.bounds);
        let bvh8: &[Bvh8Node] = self.bvh8.as_ref().map_or(&[], |b| &b.nodes);
        for n in [
            self.bvh.nodes.len(),
            bvh8.len(),
            self.triangles.len(),
            self.aabbs.len(),
            self.spheres.len(),
            self.slot_prim.len(),
            self.sbt_offsets.len(),
            self.inputs.len(),
            self.record_flags.len(),
            self.shapes.len(),
            self.curves.len(),
        ] {
            w.u64(n as u64);
        }
        w.pod(&self.bvh.nodes);
        w.pod(bvh8);
        w.pod(&self.triangles);
        w.pod(&self.aabbs);
        w.pod(&self.spheres);
        w.pod(&self.slot_prim);
        w.pod(&self.sbt_offsets);
        for r in &self.inputs {
            w.u32(r.first);
            w.u32(r.primitive_index_offset);
            w.u32(r.sbt_base);
        }
        for f in &self.record_flags {
            w.u32(f.bits());
        }
        for s in &self.shapes {
            w.0.extend_from_slice(&[
                kind_code(s.kind) as u8,
                s.vertex_format,
                s.index_format,
                s.pre_transform as u8,
                s.sbt_offset_size,
                s.single_radius as u8,
                0,
                0,
            ]);
            w.u32(s.num_vertices);
            w.u32(s.num_indices);
            w.u32(s.num_sbt_records);
        }
        w.pod(&self.curves);
        // Motion: the options (no keys without motion), then the later keys' primitives.
        let m = self.motion.as_ref();
        let options = m.map_or(MotionOptions::NONE, |m| m.options);
        w.u32(options.num_keys as u32);
        w.u32(options.flags.bits() as u32);
        w.u32(options.time_begin.to_bits());
        w.u32(options.time_end.to_bits());
        let (mt, ma, ms, mc): (&[Triangle4], &[Aabb], &[Sphere], &[CurveSegment]) = m
            .map_or((&[], &[], &[], &[]), |m| {
                (&m.triangles, &m.aabbs, &m.spheres, &m.curves)
            });
        for n in [mt.len(), ma.len(), ms.len(), mc.len()] {
            w.u64(n as u64);
        }
        w.pod(mt);
        w.pod(ma);
        w.pod(ms);
        w.pod(mc);
        frame(KIND_GAS, w.0)
    }

    /// Loads a structure saved by [`to_bytes`](Self::to_bytes), checking everything (see the
    /// [module](self) documentation). It gets a new lineage: it is a new structure.
    pub fn from_bytes(bytes: &[u8]) -> Result<GasData, LoadError> {
        let (version, payload) = unframe(bytes, KIND_GAS)?;
        let mut r = Reader { bytes: payload };
        let kind =
            kind_of(r.u32("the primitive kind")?, version).ok_or(invalid("primitive kind", 0))?;
        let build_flags =
            BuildFlags::from_bits(r.u32("the build flags")?).ok_or(invalid("build flags", 0))?;
        let num_primitives = r.u32("the primitive count")?;
        if num_primitives as u64 > MAX_PRIMITIVES_PER_GAS {
            return Err(invalid("primitive count", 0));
        }
        let bounds = r.aabb("the bounds")?;
        let mut counts = [0u64; 11];
        for (i, c) in counts.iter_mut().enumerate() {
            // Version 1 has no 8-wide layout, versions before 3 no spheres, before 4 no curves.
            if (i != 1 || version >= VERSION_BVH8)
                && (i != 4 || version >= VERSION_SPHERES)
                && (i != 10 || version >= VERSION_CURVES)
            {
                *c = r.u64("the array lengths")?;
            }
        }
        let [nn, n8, nt, na, nsp, ns, no, ni, nr, nsh, ncv] = counts;
        let nodes: Vec<Bvh4Node> = r.array(nn, "the nodes")?;
        let nodes8: Vec<Bvh8Node> = r.array(n8, "the 8-wide nodes")?;
        let triangles: Vec<Triangle4> = r.array(nt, "the triangles")?;
        let aabbs: Vec<Aabb> = r.array(na, "the boxes")?;
        let spheres: Vec<Sphere> = r.array(nsp, "the spheres")?;
        let slot_prim: Vec<u32> = r.array(ns, "the slot table")?;
        let sbt_offsets: Vec<u32> = r.array(no, "the SBT index offsets")?;
        let raw_inputs: Vec<[u32; 3]> = r.array(ni, "the build inputs")?;
        let raw_flags: Vec<u32> = r.array(nr, "the geometry flags")?;
        let raw_shapes: Vec<[u32; 5]> = r.array(nsh, "the input shapes")?;
        let curves: Vec<CurveSegment> = r.array(ncv, "the curve segments")?;
        let motion = if version >= VERSION_MOTION {
            read_motion(&mut r, version, kind, build_flags, [nt, na, nsp, ncv])?
        } else {
            None
        };
        if !r.bytes.is_empty() {
            return Err(LoadError::TrailingBytes(r.bytes.len() as u64));
        }
        // A segment's type, caps and normals flag are those of every key: traversal reads
        // them from the key it interpolates from, hits from key 0.
        if let Some(m) = &motion {
            let n = curves.len().max(1);
            for (i, later) in m.curves.iter().enumerate() {
                let base = &curves[i % n];
                if (later.curve_type, later.flags) != (base.curve_type, base.flags) {
                    return Err(invalid("motion curve segment", i));
                }
            }
        }

        // Primitive arrays and the slot table.
        let slots_ok = match kind {
            GasKind::Triangles => {
                aabbs.is_empty() && spheres.is_empty() && curves.is_empty() && ns == 4 * nt
            }
            GasKind::CustomPrimitives => {
                triangles.is_empty() && spheres.is_empty() && curves.is_empty() && ns == na
            }
            GasKind::Spheres => {
                triangles.is_empty() && aabbs.is_empty() && curves.is_empty() && ns == nsp
            }
            GasKind::Curves => {
                triangles.is_empty() && aabbs.is_empty() && spheres.is_empty() && ns == ncv
            }
        };
        if !slots_ok {
            return Err(invalid("slot table length", 0));
        }
        if let Some(s) = slot_prim
            .iter()
            .position(|&g| g != NO_PRIMITIVE && g >= num_primitives)
        {
            return Err(invalid("slot primitive", s));
        }
        let block = if kind == GasKind::Triangles { 4 } else { 1 };
        check_nodes(&nodes, ns, block, |slots| {
            slot_prim[slots].iter().all(|&g| g != NO_PRIMITIVE)
        })?;
        // The 8-wide layout is checked as strictly; it may be absent.
        let bvh8 = if nodes8.is_empty() {
            None
        } else {
            check_nodes(&nodes8, ns, block, |slots| {
                slot_prim[slots].iter().all(|&g| g != NO_PRIMITIVE)
            })?;
            Some(Bvh8 { nodes: nodes8 })
        };

        // Build inputs, SBT records and offsets.
        if raw_inputs.is_empty() {
            return Err(invalid("build input count", 0));
        }
        if nr == 0 || nr > MAX_SBT_RECORDS_PER_GAS {
            return Err(invalid("SBT record count", 0));
        }
        let record_flags: Vec<GeometryFlags> = raw_flags
            .iter()
            .enumerate()
            .map(|(i, &f)| GeometryFlags::from_bits(f).ok_or(invalid("geometry flags", i)))
            .collect::<Result<_, _>>()?;
        let inputs: Vec<InputRecord> = raw_inputs
            .iter()
            .map(|&[first, primitive_index_offset, sbt_base]| InputRecord {
                first,
                primitive_index_offset,
                sbt_base,
            })
            .collect();
        // (primitives, SBT records) of every input.
        let mut spans = Vec::with_capacity(inputs.len());
        for (i, rec) in inputs.iter().enumerate() {
            let (next_first, next_base) = inputs
                .get(i + 1)
                .map_or((num_primitives, nr as u32), |n| (n.first, n.sbt_base));
            let first_ok = if i == 0 { rec.first == 0 } else { true };
            let base_ok = if i == 0 { rec.sbt_base == 0 } else { true };
            if !first_ok || !base_ok || next_first < rec.first || next_base <= rec.sbt_base {
                return Err(invalid("build input record", i));
            }
            let count = next_first - rec.first;
            if rec.primitive_index_offset.checked_add(count).is_none() {
                return Err(invalid("primitive index offset", i));
            }
            spans.push((count, next_base - rec.sbt_base));
        }
        if !sbt_offsets.is_empty() {
            if no != num_primitives as u64 {
                return Err(invalid("SBT index offset count", 0));
            }
            let mut g = 0usize;
            for &(count, records) in &spans {
                for _ in 0..count {
                    if sbt_offsets[g] >= records {
                        return Err(invalid("SBT index offset", g));
                    }
                    g += 1;
                }
            }
        }

        // Input shapes: exactly those of an updatable build.
        let updatable = build_flags.contains(BuildFlags::ALLOW_UPDATE);
        let expected = if updatable { inputs.len() } else { 0 };
        if raw_shapes.len() != expected {
            return Err(invalid("input shape count", 0));
        }
        let mut shapes = Vec::with_capacity(raw_shapes.len());
        for (i, (raw, &(count, records))) in raw_shapes.iter().zip(&spans).enumerate() {
            let b = raw[0].to_le_bytes();
            let shape = InputShape {
                kind: kind_of(b[0] as u32, version).ok_or(invalid("input shape", i))?,
                vertex_format: b[1],
                index_format: b[2],
                pre_transform: b[3] != 0,
                sbt_offset_size: raw[1].to_le_bytes()[0],
                num_vertices: raw[2],
                num_indices: raw[3],
                num_sbt_records: raw[4],
                single_radius: raw[1].to_le_bytes()[1] != 0,
            };
            let primitives = match (shape.kind, shape.index_format) {
                (GasKind::CustomPrimitives | GasKind::Spheres, _) => shape.num_vertices,
                (GasKind::Curves, _) => shape.num_indices,
                (GasKind::Triangles, 0) => shape.num_vertices / 3,
                (GasKind::Triangles, _) => shape.num_indices,
            };
            // Only a sphere input has singleRadius and only a curve input normals (byte 5,
            // padding before version 3, which the loader already required to be 0); bytes 6
            // and 7 are padding. A curve input keeps its type's code and its end caps in the
            // format bytes.
            let single = raw[1].to_le_bytes()[1];
            let single_ok =
                single == 0 || (single == 1 && matches!(kind, GasKind::Spheres | GasKind::Curves));
            let formats_ok = if kind == GasKind::Curves {
                oxray_core::CurveType::from_code(0x2500 | shape.vertex_format as u32).is_some()
                    && matches!(shape.index_format, 1 | 2)
            } else {
                shape.vertex_format <= 5 && shape.index_format <= 2
            };
            let ok = shape.kind == kind
                && single_ok
                && b[3] <= 1
                && formats_ok
                && matches!(shape.sbt_offset_size, 0 | 1 | 2 | 4)
                && raw[1] >> 16 == 0
                && shape.num_sbt_records == records
                && primitives == count;
            if !ok {
                return Err(invalid("input shape", i));
            }
            shapes.push(shape);
        }

        let mut gas = GasData {
            kind,
            build_flags,
            bvh: Bvh4 { nodes },
            bvh8,
            triangles,
            aabbs,
            spheres,
            curves,
            slot_prim,
            sbt_offsets,
            inputs,
            record_flags,
            bounds,
            num_primitives,
            shapes,
            lineage: crate::next_lineage(),
            motion,
        };
        if let Some(slot) = gas.repeated_reference() {
            return Err(invalid("primitive referenced from two leaf slots", slot));
        }
        // The time parts of a motion structure are not saved: they follow from its tree and
        // primitives, as the build made them.
        if !build_flags.contains(BuildFlags::PREFER_FAST_BUILD) {
            gas.build_motion_segments();
        }
        Ok(gas)
    }

    /// A leaf slot that names a primitive an earlier slot names too, where the structure must
    /// reference it once: every primitive of an updatable structure (a refit fills one slot
    /// per primitive) or of custom primitives (never split), and the primitives of SBT records
    /// with `REQUIRE_SINGLE_ANYHIT_CALL` (guide §5.1, §9.2: one any-hit call per primitive);
    /// spheres are never split either. Spatial splits and curve splitting (§9.2) make the
    /// others repeat.
    fn repeated_reference(&self) -> Option<usize> {
        let all = self.build_flags.contains(BuildFlags::ALLOW_UPDATE)
            || matches!(self.kind, GasKind::CustomPrimitives | GasKind::Spheres);
        let single = self
            .record_flags
            .iter()
            .any(|f| f.contains(GeometryFlags::REQUIRE_SINGLE_ANYHIT_CALL));
        if !all && !single {
            return None;
        }
        let mut seen = vec![false; self.num_primitives as usize];
        for (slot, &g) in self.slot_prim.iter().enumerate() {
            // Indices were checked against the primitive count.
            let Some(mark) = seen.get_mut(g as usize) else {
                continue;
            };
            if !all {
                let (input, _) = self.locate(g);
                let record = self.inputs[input].sbt_base
                    + self.sbt_offsets.get(g as usize).copied().unwrap_or(0);
                let flags = self.record_flags.get(record as usize).copied();
                if !flags.is_some_and(|f| f.contains(GeometryFlags::REQUIRE_SINGLE_ANYHIT_CALL)) {
                    continue;
                }
            }
            if *mark {
                return Some(slot);
            }
            *mark = true;
        }
        None
    }
}

impl IasData {
    /// Saves the IAS without its children (see [`IasData::from_bytes`]).
    #[must_use]
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut w = Writer(Vec::new());
        w.u32(self.build_flags.bits());
        w.u32(match self.input_kind {
            BuildInputKind::InstancePointers => 1,
            _ => 0,
        });
        w.u32(self.num_instances);
        w.aabb(&self.bounds);
        for n in [
            self.bvh.nodes.len(),
            self.instances.len(),
            self.boxes.len(),
            self.slot_of.len(),
        ] {
            w.u64(n as u64);
        }
        w.pod(&self.bvh.nodes);
        w.pod(&self.boxes);
        w.pod(&self.slot_of);
        for inst in &self.instances {
            w.pod(&inst.object_to_world.0);
            for v in [
                inst.instance_id,
                inst.sbt_offset,
                inst.mask as u32,
                inst.flags.bits(),
                inst.index,
            ] {
                w.u32(v);
            }
        }
        w.u32(self.motion.num_keys as u32);
        w.u32(self.motion.flags.bits() as u32);
        w.u32(self.motion.time_begin.to_bits());
        w.u32(self.motion.time_end.to_bits());
        frame(KIND_IAS, w.0)
    }

    /// Loads an IAS saved by [`to_bytes`](Self::to_bytes) over `children`, one per instance by
    /// instance index (as `OptixRelocateInputInstanceArray::traversableHandles`): they should
    /// be the structures it was built over, or copies of them (loaded, compacted) — the world
    /// boxes are the saved ones, not recomputed, as in OptiX's relocation. Every field is
    /// checked as a build checks it, and the tree as [`GasData::from_bytes`] does.
    #[doc(alias = "OptixRelocateInputInstanceArray")]
    pub fn from_bytes(bytes: &[u8], children: &[TraversableHandle]) -> Result<IasData, LoadError> {
        let (version, payload) = unframe(bytes, KIND_IAS)?;
        let mut r = Reader { bytes: payload };
        let build_flags =
            BuildFlags::from_bits(r.u32("the build flags")?).ok_or(invalid("build flags", 0))?;
        let input_kind = match r.u32("the input kind")? {
            0 => BuildInputKind::Instances,
            1 => BuildInputKind::InstancePointers,
            _ => return Err(invalid("input kind", 0)),
        };
        let num_instances = r.u32("the instance count")?;
        if children.len() != num_instances as usize {
            return Err(LoadError::ChildCount {
                expected: num_instances as u64,
                given: children.len() as u64,
            });
        }
        let bounds = r.aabb("the bounds")?;
        let mut counts = [0u64; 4];
        for c in &mut counts {
            *c = r.u64("the array lengths")?;
        }
        let [nn, ni, nb, ns] = counts;
        let nodes: Vec<Bvh4Node> = r.array(nn, "the nodes")?;
        let boxes: Vec<Aabb> = r.array(nb, "the boxes")?;
        let slot_of: Vec<u32> = r.array(ns, "the slot table")?;
        let raw: Vec<[u32; 17]> = r.array(ni, "the instances")?;
        let motion = if version >= VERSION_MOTION {
            let num_keys = r.u32("the motion keys")?;
            let flags = r.u32("the motion flags")?;
            let options = MotionOptions {
                num_keys: u16::try_from(num_keys).map_err(|_| invalid("motion keys", 0))?,
                flags: u16::try_from(flags)
                    .ok()
                    .and_then(MotionFlags::from_bits)
                    .ok_or(invalid("motion flags", 0))?,
                time_begin: f32::from_bits(r.u32("the motion begin")?),
                time_end: f32::from_bits(r.u32("the motion end")?),
            };
            options
                .validate_for_structure()
                .map_err(|_| invalid("motion options", 0))?;
            options
        } else {
            MotionOptions::NONE
        };
        if !r.bytes.is_empty() {
            return Err(LoadError::TrailingBytes(r.bytes.len() as u64));
        }
        if nb != ni || ns != num_instances as u64 || ni > ns {
            return Err(invalid("instance table length", 0));
        }
        check_nodes(&nodes, ni, 1, |_| true)?;
        // An updatable IAS has a slot for every instance.
        if build_flags.contains(BuildFlags::ALLOW_UPDATE) && slot_of.contains(&u32::MAX) {
            return Err(invalid(
                "slot of instance (an updatable IAS has one for each)",
                0,
            ));
        }
        // Every input index has at most one slot and every slot one input index.
        for (i, &s) in slot_of.iter().enumerate() {
            if s != u32::MAX && raw.get(s as usize).is_none_or(|x| x[16] != i as u32) {
                return Err(invalid("slot of instance", i));
            }
        }
        let mut instances = Vec::with_capacity(raw.len());
        for (slot, x) in raw.iter().enumerate() {
            let index = x[16];
            if slot_of.get(index as usize) != Some(&(slot as u32)) {
                return Err(invalid("instance index", slot));
            }
            let transform = Transform(std::array::from_fn(|k| f32::from_bits(x[k])));
            let flags = InstanceFlags::from_bits(x[15]).ok_or(invalid("instance flags", slot))?;
            let child = children[index as usize].clone();
            let inst = Instance {
                transform,
                instance_id: x[12],
                sbt_offset: x[13],
                visibility_mask: x[14],
                flags,
                child: child.clone(),
            };
            let inverse = validate_instance(index, &inst).map_err(|e| match e {
                BuildError::GraphTooDeep { .. } => LoadError::Child {
                    instance: index,
                    reason: e.to_string(),
                },
                _ => invalid("instance", slot),
            })?;
            instances.push(InstanceData {
                object_to_world: transform,
                world_to_object: inverse,
                instance_id: inst.instance_id,
                sbt_offset: inst.sbt_offset,
                mask: inst.visibility_mask as u8,
                flags,
                child,
                index,
            });
        }
        let depth = 1 + children.iter().map(|c| c.graph_depth()).max().unwrap_or(0);
        Ok(IasData {
            bvh: Bvh4 { nodes },
            instances,
            boxes,
            slot_of,
            bounds,
            build_flags,
            num_instances,
            depth,
            input_kind,
            lineage: crate::next_lineage(),
            motion,
        })
    }
}
