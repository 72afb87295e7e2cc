//! Build inputs of geometry acceleration structures (guide §5.1, §5.3): triangle arrays, custom
//! primitive (AABB) arrays, sphere arrays and curve arrays (see [`crate::curve`]), described by borrowed byte buffers and formats so that nothing here
//! assumes where the data lives or how the backend lays it out.

use crate::options::GeometryFlags;
use crate::vertex::{IndexFormat, VertexFormat};
use glam::Vec3;

/// The one-record default for the `flags` of every GAS input.
const ONE_RECORD: &[GeometryFlags] = &[GeometryFlags::empty()];

/// A vertex buffer: `count` vertices of `format`, `stride` bytes apart (0 = tightly packed).
#[derive(Clone, Copy, Debug)]
pub struct VertexBuffer<'a> {
    /// Raw little-endian bytes.
    pub data: &'a [u8],
    /// Format of each vertex.
    pub format: VertexFormat,
    /// Bytes from one vertex to the next; 0 means `format.size()`.
    pub stride: u32,
    /// Number of vertices.
    pub count: u32,
}

impl<'a> VertexBuffer<'a> {
    /// A buffer of `count` vertices of `format` with the given stride.
    #[must_use]
    pub fn new(data: &'a [u8], format: VertexFormat, stride: u32, count: u32) -> Self {
        VertexBuffer {
            data,
            format,
            stride,
            count,
        }
    }

    /// Tightly packed `f32` positions.
    #[must_use]
    pub fn f32x3(vertices: &'a [[f32; 3]]) -> Self {
        Self::new(
            bytemuck::cast_slice(vertices),
            VertexFormat::F32x3,
            0,
            count_u32(vertices.len()),
        )
    }

    /// Tightly packed `glam::Vec3` positions.
    #[must_use]
    pub fn vec3(vertices: &'a [Vec3]) -> Self {
        Self::new(
            bytemuck::cast_slice(vertices),
            VertexFormat::F32x3,
            0,
            count_u32(vertices.len()),
        )
    }

    /// The stride in bytes, resolving 0.
    #[must_use]
    pub fn effective_stride(&self) -> usize {
        if self.stride == 0 {
            self.format.size()
        } else {
            self.stride as usize
        }
    }
}

/// An index buffer: `count` triplets of `format`, `stride` bytes apart (0 = tightly packed).
#[derive(Clone, Copy, Debug)]
pub struct IndexBuffer<'a> {
    /// Raw little-endian bytes.
    pub data: &'a [u8],
    /// Format of each triplet.
    pub format: IndexFormat,
    /// Bytes from one triplet to the next; 0 means `format.size()`.
    pub stride: u32,
    /// Number of triplets (triangles).
    pub count: u32,
}

impl<'a> IndexBuffer<'a> {
    /// A buffer of `count` triplets of `format` with the given stride.
    #[must_use]
    pub fn new(data: &'a [u8], format: IndexFormat, stride: u32, count: u32) -> Self {
        IndexBuffer {
            data,
            format,
            stride,
            count,
        }
    }

    /// Tightly packed `u32` triplets.
    #[must_use]
    pub fn u32x3(triangles: &'a [[u32; 3]]) -> Self {
        Self::new(
            bytemuck::cast_slice(triangles),
            IndexFormat::U32x3,
            0,
            count_u32(triangles.len()),
        )
    }

    /// Tightly packed `u16` triplets.
    #[must_use]
    pub fn u16x3(triangles: &'a [[u16; 3]]) -> Self {
        Self::new(
            bytemuck::cast_slice(triangles),
            IndexFormat::U16x3,
            0,
            count_u32(triangles.len()),
        )
    }

    /// The stride in bytes, resolving 0.
    #[must_use]
    pub fn effective_stride(&self) -> usize {
        if self.stride == 0 {
            self.format.size()
        } else {
            self.stride as usize
        }
    }
}

/// The integer size of one per-primitive SBT index offset.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SbtIndexSize {
    /// `u8` offsets.
    U8,
    /// `u16` offsets.
    U16,
    /// `u32` offsets.
    U32,
}

impl SbtIndexSize {
    /// Bytes of one offset.
    #[must_use]
    pub const fn size(self) -> usize {
        match self {
            SbtIndexSize::U8 => 1,
            SbtIndexSize::U16 => 2,
            SbtIndexSize::U32 => 4,
        }
    }
}

/// Per-primitive SBT index offsets (`sbtIndexOffsetBuffer`, guide §5.1): one unsigned integer per
/// primitive, each in `[0, num_sbt_records)`.
#[derive(Clone, Copy, Debug)]
pub struct SbtIndexOffsets<'a> {
    /// Raw little-endian bytes.
    pub data: &'a [u8],
    /// Size of each offset.
    pub size: SbtIndexSize,
    /// Bytes from one offset to the next; 0 means `size.size()`.
    pub stride: u32,
}

impl<'a> SbtIndexOffsets<'a> {
    /// Tightly packed `u8` offsets.
    #[must_use]
    pub fn u8(offsets: &'a [u8]) -> Self {
        SbtIndexOffsets {
            data: offsets,
            size: SbtIndexSize::U8,
            stride: 0,
        }
    }

    /// Tightly packed `u16` offsets.
    #[must_use]
    pub fn u16(offsets: &'a [u16]) -> Self {
        SbtIndexOffsets {
            data: bytemuck::cast_slice(offsets),
            size: SbtIndexSize::U16,
            stride: 0,
        }
    }

    /// Tightly packed `u32` offsets.
    #[must_use]
    pub fn u32(offsets: &'a [u32]) -> Self {
        SbtIndexOffsets {
            data: bytemuck::cast_slice(offsets),
            size: SbtIndexSize::U32,
            stride: 0,
        }
    }

    /// The stride in bytes, resolving 0.
    #[must_use]
    pub fn effective_stride(&self) -> usize {
        if self.stride == 0 {
            self.size.size()
        } else {
            self.stride as usize
        }
    }

    /// The offset of primitive `i`; the buffer must have been validated.
    #[inline]
    #[must_use]
    pub fn get(&self, i: usize) -> u32 {
        let at = i * self.effective_stride();
        let b = &self.data[at..at + self.size.size()];
        match self.size {
            SbtIndexSize::U8 => b[0] as u32,
            SbtIndexSize::U16 => u16::from_le_bytes([b[0], b[1]]) as u32,
            SbtIndexSize::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        }
    }
}

/// A triangle build input (`OptixBuildInputTriangleArray`, guide §5.1).
///
/// ```
/// use oxray_core::{GeometryFlags, IndexBuffer, TriangleInput, VertexBuffer};
/// let vertices = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
/// let triangles = [[0u32, 1, 2]];
/// let input = TriangleInput::new(VertexBuffer::f32x3(&vertices))
///     .indices(IndexBuffer::u32x3(&triangles))
///     .flags(&[GeometryFlags::DISABLE_ANYHIT]);
/// assert_eq!(input.num_primitives(), 1);
/// ```
#[derive(Clone, Copy, Debug)]
#[doc(alias = "OptixBuildInputTriangleArray")]
pub struct TriangleInput<'a> {
    /// Vertex positions.
    pub vertices: VertexBuffer<'a>,
    /// Index triplets; without them every three consecutive vertices form a triangle.
    pub indices: Option<IndexBuffer<'a>>,
    /// A 3x4 row-major object transform applied to every vertex at build time.
    pub pre_transform: Option<[f32; 12]>,
    /// Geometry flags, one per SBT record: its length is `numSbtRecords` (at least 1).
    pub flags: &'a [GeometryFlags],
    /// Which of this input's SBT records each primitive uses; required when there is more than
    /// one record.
    pub sbt_index_offsets: Option<SbtIndexOffsets<'a>>,
    /// Added to the primitive index that hits report.
    pub primitive_index_offset: u32,
    /// The vertices at motion keys 1, 2, … of a build with motion (guide §5.10.2):
    /// [`vertices`](Self::vertices) is key 0, so a build of `n` keys takes `n - 1` buffers
    /// here, each of the same count and format as key 0 (strides may differ). Empty without
    /// motion. The indices are shared by every key.
    pub motion_vertices: &'a [VertexBuffer<'a>],
}

impl<'a> TriangleInput<'a> {
    /// A triangle soup over `vertices` with one SBT record and no flags.
    #[must_use]
    pub fn new(vertices: VertexBuffer<'a>) -> Self {
        TriangleInput {
            vertices,
            indices: None,
            pre_transform: None,
            flags: ONE_RECORD,
            sbt_index_offsets: None,
            primitive_index_offset: 0,
            motion_vertices: &[],
        }
    }

    /// Sets the vertices of motion keys 1, 2, … (key 0 is [`vertices`](Self::vertices)).
    ///
    /// ```
    /// use oxray_core::{TriangleInput, VertexBuffer};
    /// let k0 = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    /// let k1 = [[0.0f32, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]];
    /// let later = [VertexBuffer::f32x3(&k1)];
    /// let input = TriangleInput::new(VertexBuffer::f32x3(&k0)).motion_vertices(&later);
    /// assert_eq!(input.num_motion_keys(), 2);
    /// ```
    #[must_use]
    pub fn motion_vertices(mut self, keys: &'a [VertexBuffer<'a>]) -> Self {
        self.motion_vertices = keys;
        self
    }

    /// Motion keys the input gives vertices for (1 without motion).
    #[must_use]
    pub fn num_motion_keys(&self) -> usize {
        1 + self.motion_vertices.len()
    }

    /// The vertex buffer of motion key `key` (0 is [`vertices`](Self::vertices)).
    #[must_use]
    pub fn vertex_key(&self, key: usize) -> Option<&VertexBuffer<'a>> {
        match key {
            0 => Some(&self.vertices),
            k => self.motion_vertices.get(k - 1),
        }
    }

    /// Sets the index buffer.
    #[must_use]
    pub fn indices(mut self, indices: IndexBuffer<'a>) -> Self {
        self.indices = Some(indices);
        self
    }

    /// Sets the 3x4 row-major pre-transform.
    #[must_use]
    pub fn pre_transform(mut self, m: [f32; 12]) -> Self {
        self.pre_transform = Some(m);
        self
    }

    /// Sets the per-record geometry flags (and so the number of SBT records).
    #[must_use]
    pub fn flags(mut self, flags: &'a [GeometryFlags]) -> Self {
        self.flags = flags;
        self
    }

    /// Sets the per-primitive SBT index offsets.
    #[must_use]
    pub fn sbt_index_offsets(mut self, offsets: SbtIndexOffsets<'a>) -> Self {
        self.sbt_index_offsets = Some(offsets);
        self
    }

    /// Sets the primitive index offset.
    #[must_use]
    pub fn primitive_index_offset(mut self, offset: u32) -> Self {
        self.primitive_index_offset = offset;
        self
    }

    /// Number of triangles this input declares.
    #[must_use]
    pub fn num_primitives(&self) -> u32 {
        match &self.indices {
            Some(ix) => ix.count,
            None => self.vertices.count / 3,
        }
    }
}

/// An AABB buffer for custom primitives: `count` boxes of six `f32`
/// (`minX, minY, minZ, maxX, maxY, maxZ`), `stride` bytes apart (0 = 24, else a multiple of 8).
#[derive(Clone, Copy, Debug)]
pub struct AabbBuffer<'a> {
    /// Raw little-endian bytes.
    pub data: &'a [u8],
    /// Bytes from one box to the next; 0 means 24.
    pub stride: u32,
    /// Number of boxes (primitives).
    pub count: u32,
}

impl<'a> AabbBuffer<'a> {
    /// Tightly packed boxes.
    #[must_use]
    pub fn new(aabbs: &'a [crate::Aabb]) -> Self {
        AabbBuffer {
            data: bytemuck::cast_slice(aabbs),
            stride: 0,
            count: count_u32(aabbs.len()),
        }
    }

    /// The stride in bytes, resolving 0.
    #[must_use]
    pub fn effective_stride(&self) -> usize {
        if self.stride == 0 {
            24
        } else {
            self.stride as usize
        }
    }
}

/// A custom-primitive build input (`OptixBuildInputCustomPrimitiveArray`, guide §5.1): the shape
/// inside each box is decided by an intersection program (or closure) at trace time.
#[derive(Clone, Copy, Debug)]
#[doc(alias = "OptixBuildInputCustomPrimitiveArray")]
pub struct CustomPrimitiveInput<'a> {
    /// One box per primitive; each must enclose its primitive.
    pub aabbs: AabbBuffer<'a>,
    /// Geometry flags, one per SBT record.
    pub flags: &'a [GeometryFlags],
    /// Which of this input's SBT records each primitive uses.
    pub sbt_index_offsets: Option<SbtIndexOffsets<'a>>,
    /// Added to the primitive index that hits report.
    pub primitive_index_offset: u32,
    /// The boxes at motion keys 1, 2, … of a build with motion (guide §5.10.1, §5.10.2):
    /// [`aabbs`](Self::aabbs) is key 0, so a build of `n` keys takes `n - 1` buffers here, each
    /// of the same count. Boxes are interpolated linearly between keys, so each key's box must
    /// be large enough that the interpolated boxes contain the primitive's whole motion path.
    pub motion_aabbs: &'a [AabbBuffer<'a>],
}

impl<'a> CustomPrimitiveInput<'a> {
    /// Custom primitives bounded by `aabbs`, with one SBT record and no flags.
    #[must_use]
    pub fn new(aabbs: AabbBuffer<'a>) -> Self {
        CustomPrimitiveInput {
            aabbs,
            flags: ONE_RECORD,
            sbt_index_offsets: None,
            primitive_index_offset: 0,
            motion_aabbs: &[],
        }
    }

    /// Sets the boxes of motion keys 1, 2, … (key 0 is [`aabbs`](Self::aabbs)).
    #[must_use]
    pub fn motion_aabbs(mut self, keys: &'a [AabbBuffer<'a>]) -> Self {
        self.motion_aabbs = keys;
        self
    }

    /// The box buffer of motion key `key` (0 is [`aabbs`](Self::aabbs)).
    #[must_use]
    pub fn aabb_key(&self, key: usize) -> Option<&AabbBuffer<'a>> {
        match key {
            0 => Some(&self.aabbs),
            k => self.motion_aabbs.get(k - 1),
        }
    }

    /// Box `i` of a validated key buffer.
    #[inline]
    #[must_use]
    pub fn aabb(buffer: &AabbBuffer<'_>, i: usize) -> crate::Aabb {
        let at = i * buffer.effective_stride();
        let f: [f32; 6] = std::array::from_fn(|k| {
            let b = &buffer.data[at + 4 * k..at + 4 * k + 4];
            f32::from_le_bytes([b[0], b[1], b[2], b[3]])
        });
        crate::Aabb::new(Vec3::new(f[0], f[1], f[2]), Vec3::new(f[3], f[4], f[5]))
    }

    /// Sets the per-record geometry flags.
    #[must_use]
    pub fn flags(mut self, flags: &'a [GeometryFlags]) -> Self {
        self.flags = flags;
        self
    }

    /// Sets the per-primitive SBT index offsets.
    #[must_use]
    pub fn sbt_index_offsets(mut self, offsets: SbtIndexOffsets<'a>) -> Self {
        self.sbt_index_offsets = Some(offsets);
        self
    }

    /// Sets the primitive index offset.
    #[must_use]
    pub fn primitive_index_offset(mut self, offset: u32) -> Self {
        self.primitive_index_offset = offset;
        self
    }
}

/// A sphere build input (`OptixBuildInputSphereArray`, guide §5.3, §9): a centre and a radius
/// per sphere.
///
/// As in OptiX, the centres and radii are given per motion key: `vertex_buffers[k]` holds the
/// centres (`float3`, `vertex_stride` bytes apart) and `radius_buffers[k]` the radii (`f32`,
/// `radius_stride` bytes apart) at key `k`: both slices have one buffer per motion key of the
/// build (one without motion; [`BuildError::MotionKeyCount`](crate::BuildError) otherwise). With [`single_radius`](Self::single_radius), each radius buffer holds one radius
/// for every sphere. There is no index buffer and no pre-transform (§9.1): a non-uniform scale
/// belongs in an instance transform. Spheres take per-primitive SBT index offsets like
/// triangles (§9.1).
///
/// ```
/// use oxray_core::{GeometryFlags, SphereInput};
/// let centres = [[0.0f32, 0.0, 0.0], [3.0, 0.0, 0.0]];
/// let radii = [1.0f32, 0.5];
/// let c = [bytemuck::cast_slice::<_, u8>(&centres)];
/// let r = [bytemuck::cast_slice::<_, u8>(&radii)];
/// let input = SphereInput::new(&c, 2, &r).flags(&[GeometryFlags::DISABLE_ANYHIT]);
/// assert_eq!(input.num_primitives(), 2);
/// // One radius for every sphere.
/// let one = [bytemuck::cast_slice::<_, u8>(&radii[..1])];
/// let input = SphereInput::new(&c, 2, &one).single_radius(true);
/// assert_eq!(input.radius(&one[0], 1), 1.0);
/// ```
#[derive(Clone, Copy, Debug)]
#[doc(alias = "OptixBuildInputSphereArray")]
pub struct SphereInput<'a> {
    /// Centres (`float3`, little-endian), one buffer per motion key (`vertexBuffers`).
    pub vertex_buffers: &'a [&'a [u8]],
    /// Bytes from one centre to the next; 0 means 12 (`vertexStrideInBytes`, a multiple of 4).
    pub vertex_stride: u32,
    /// Spheres (centres) per buffer (`numVertices`).
    pub num_vertices: u32,
    /// Radii (`f32`, little-endian), one buffer per motion key (`radiusBuffers`).
    pub radius_buffers: &'a [&'a [u8]],
    /// Bytes from one radius to the next; 0 means 4 (`radiusStrideInBytes`, a multiple of 4).
    pub radius_stride: u32,
    /// One radius per radius buffer for every sphere (`singleRadius`).
    pub single_radius: bool,
    /// Geometry flags, one per SBT record: its length is `numSbtRecords` (at least 1).
    pub flags: &'a [GeometryFlags],
    /// Which of this input's SBT records each sphere uses; required with more than one record.
    pub sbt_index_offsets: Option<SbtIndexOffsets<'a>>,
    /// Added to the primitive index that hits report.
    pub primitive_index_offset: u32,
}

impl<'a> SphereInput<'a> {
    /// `num_vertices` spheres, tightly packed, one radius each, one SBT record and no flags.
    #[must_use]
    pub fn new(
        vertex_buffers: &'a [&'a [u8]],
        num_vertices: u32,
        radius_buffers: &'a [&'a [u8]],
    ) -> Self {
        SphereInput {
            vertex_buffers,
            vertex_stride: 0,
            num_vertices,
            radius_buffers,
            radius_stride: 0,
            single_radius: false,
            flags: ONE_RECORD,
            sbt_index_offsets: None,
            primitive_index_offset: 0,
        }
    }

    /// Sets the centre stride in bytes.
    #[must_use]
    pub fn vertex_stride(mut self, stride: u32) -> Self {
        self.vertex_stride = stride;
        self
    }

    /// Sets the radius stride in bytes.
    #[must_use]
    pub fn radius_stride(mut self, stride: u32) -> Self {
        self.radius_stride = stride;
        self
    }

    /// Sets `singleRadius`: one radius per buffer for every sphere.
    #[must_use]
    pub fn single_radius(mut self, single: bool) -> Self {
        self.single_radius = single;
        self
    }

    /// Sets the per-record geometry flags (and so the number of SBT records).
    #[must_use]
    pub fn flags(mut self, flags: &'a [GeometryFlags]) -> Self {
        self.flags = flags;
        self
    }

    /// Sets the per-primitive SBT index offsets.
    #[must_use]
    pub fn sbt_index_offsets(mut self, offsets: SbtIndexOffsets<'a>) -> Self {
        self.sbt_index_offsets = Some(offsets);
        self
    }

    /// Sets the primitive index offset.
    #[must_use]
    pub fn primitive_index_offset(mut self, offset: u32) -> Self {
        self.primitive_index_offset = offset;
        self
    }

    /// Number of spheres this input declares.
    #[must_use]
    pub fn num_primitives(&self) -> u32 {
        self.num_vertices
    }

    /// The centre stride in bytes, resolving 0.
    #[must_use]
    pub fn effective_vertex_stride(&self) -> usize {
        if self.vertex_stride == 0 {
            12
        } else {
            self.vertex_stride as usize
        }
    }

    /// The radius stride in bytes, resolving 0.
    #[must_use]
    pub fn effective_radius_stride(&self) -> usize {
        if self.radius_stride == 0 {
            4
        } else {
            self.radius_stride as usize
        }
    }

    /// Centre `i` of a validated key buffer.
    #[inline]
    #[must_use]
    pub fn centre(&self, buffer: &[u8], i: usize) -> Vec3 {
        let at = i * self.effective_vertex_stride();
        let f = |k: usize| {
            let b = &buffer[at + 4 * k..at + 4 * k + 4];
            f32::from_le_bytes([b[0], b[1], b[2], b[3]])
        };
        Vec3::new(f(0), f(1), f(2))
    }

    /// Radius of sphere `i` in a validated key buffer (the single radius with
    /// [`single_radius`](Self::single_radius)).
    #[inline]
    #[must_use]
    pub fn radius(&self, buffer: &[u8], i: usize) -> f32 {
        let at = if self.single_radius {
            0
        } else {
            i * self.effective_radius_stride()
        };
        let b = &buffer[at..at + 4];
        f32::from_le_bytes([b[0], b[1], b[2], b[3]])
    }
}

/// One build input of an acceleration structure (`OptixBuildInput`). All inputs of one GAS
/// build must be of the same kind.
#[derive(Clone, Copy, Debug)]
#[doc(alias = "OptixBuildInput")]
pub enum BuildInput<'a> {
    /// Triangles.
    Triangles(TriangleInput<'a>),
    /// Custom primitives bounded by AABBs.
    CustomPrimitives(CustomPrimitiveInput<'a>),
    /// Built-in spheres (guide §5.3).
    Spheres(SphereInput<'a>),
    /// Built-in curves (guide §5.2).
    Curves(crate::CurveInput<'a>),
    /// Instances, for an IAS (`OPTIX_BUILD_INPUT_TYPE_INSTANCES`).
    Instances(&'a [crate::Instance]),
    /// Instances by reference, for an IAS (`OPTIX_BUILD_INPUT_TYPE_INSTANCE_POINTERS`).
    InstancePointers(&'a [&'a crate::Instance]),
}

impl<'a> From<TriangleInput<'a>> for BuildInput<'a> {
    fn from(t: TriangleInput<'a>) -> Self {
        BuildInput::Triangles(t)
    }
}

impl<'a> From<SphereInput<'a>> for BuildInput<'a> {
    fn from(s: SphereInput<'a>) -> Self {
        BuildInput::Spheres(s)
    }
}

impl<'a> From<crate::CurveInput<'a>> for BuildInput<'a> {
    fn from(c: crate::CurveInput<'a>) -> Self {
        BuildInput::Curves(c)
    }
}

impl<'a> From<CustomPrimitiveInput<'a>> for BuildInput<'a> {
    fn from(c: CustomPrimitiveInput<'a>) -> Self {
        BuildInput::CustomPrimitives(c)
    }
}

/// The kind of a build input (`OptixBuildInputType`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BuildInputKind {
    /// Triangles.
    Triangles,
    /// Custom primitives.
    CustomPrimitives,
    /// Built-in spheres.
    Spheres,
    /// Built-in curves.
    Curves,
    /// Instances.
    Instances,
    /// Instance pointers.
    InstancePointers,
}

impl std::fmt::Display for BuildInputKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            BuildInputKind::Triangles => "triangles",
            BuildInputKind::CustomPrimitives => "custom primitives",
            BuildInputKind::Spheres => "spheres",
            BuildInputKind::Curves => "curves",
            BuildInputKind::Instances => "instances",
            BuildInputKind::InstancePointers => "instance pointers",
        })
    }
}

impl BuildInput<'_> {
    /// The kind of this input.
    #[must_use]
    pub fn kind(&self) -> BuildInputKind {
        match self {
            BuildInput::Triangles(_) => BuildInputKind::Triangles,
            BuildInput::CustomPrimitives(_) => BuildInputKind::CustomPrimitives,
            BuildInput::Spheres(_) => BuildInputKind::Spheres,
            BuildInput::Curves(_) => BuildInputKind::Curves,
            BuildInput::Instances(_) => BuildInputKind::Instances,
            BuildInput::InstancePointers(_) => BuildInputKind::InstancePointers,
        }
    }

    /// Number of primitives this input declares.
    #[must_use]
    pub fn num_primitives(&self) -> u32 {
        match self {
            BuildInput::Triangles(t) => t.num_primitives(),
            BuildInput::CustomPrimitives(c) => c.aabbs.count,
            BuildInput::Spheres(s) => s.num_primitives(),
            BuildInput::Curves(c) => c.num_primitives(),
            BuildInput::Instances(i) => i.len().min(u32::MAX as usize) as u32,
            BuildInput::InstancePointers(i) => i.len().min(u32::MAX as usize) as u32,
        }
    }

    /// The per-record geometry flags (none for instances).
    #[must_use]
    pub fn flags(&self) -> &[GeometryFlags] {
        match self {
            BuildInput::Triangles(t) => t.flags,
            BuildInput::CustomPrimitives(c) => c.flags,
            BuildInput::Spheres(s) => s.flags,
            // One SBT record per curve input (§9.1).
            BuildInput::Curves(c) => std::slice::from_ref(&c.flag),
            BuildInput::Instances(_) | BuildInput::InstancePointers(_) => &[],
        }
    }

    /// The per-primitive SBT index offsets.
    #[must_use]
    pub fn sbt_index_offsets(&self) -> Option<&SbtIndexOffsets<'_>> {
        match self {
            BuildInput::Triangles(t) => t.sbt_index_offsets.as_ref(),
            BuildInput::CustomPrimitives(c) => c.sbt_index_offsets.as_ref(),
            BuildInput::Spheres(s) => s.sbt_index_offsets.as_ref(),
            BuildInput::Curves(_) => None,
            BuildInput::Instances(_) | BuildInput::InstancePointers(_) => None,
        }
    }

    /// The primitive index offset.
    #[must_use]
    pub fn primitive_index_offset(&self) -> u32 {
        match self {
            BuildInput::Triangles(t) => t.primitive_index_offset,
            BuildInput::CustomPrimitives(c) => c.primitive_index_offset,
            BuildInput::Spheres(s) => s.primitive_index_offset,
            BuildInput::Curves(c) => c.primitive_index_offset,
            BuildInput::Instances(_) | BuildInput::InstancePointers(_) => 0,
        }
    }
}

/// Slice lengths beyond `u32` saturate, so that validation reports them as over the limits.
fn count_u32(n: usize) -> u32 {
    u32::try_from(n).unwrap_or(u32::MAX)
}

impl<'a> From<&'a [crate::Instance]> for BuildInput<'a> {
    fn from(i: &'a [crate::Instance]) -> Self {
        BuildInput::Instances(i)
    }
}

impl<'a> From<&'a [&'a crate::Instance]> for BuildInput<'a> {
    fn from(i: &'a [&'a crate::Instance]) -> Self {
        BuildInput::InstancePointers(i)
    }
}

impl BuildInputKind {
    /// Whether inputs of this kind build an IAS.
    #[must_use]
    pub fn is_instances(self) -> bool {
        matches!(
            self,
            BuildInputKind::Instances | BuildInputKind::InstancePointers
        )
    }
}
