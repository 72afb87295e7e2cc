//! Curve build inputs (`OptixBuildInputCurveArray`, guide §5.2, §9): the curve types, their end
//! caps and the input that describes strands of segments by borrowed byte buffers.

use crate::options::GeometryFlags;
use glam::Vec3;

/// The basis and cross-section of a curve input (`OptixPrimitiveType`'s curve values, guide
/// §5.2, §9.7).
///
/// Round types sweep a circle (or, for the Rocaps variants, a sphere) whose radius follows the
/// same basis as the position; the flat quadratic B-spline is a ribbon, a ruled surface swept by
/// a straight line.
///
/// ```
/// use oxray_core::CurveType;
/// assert_eq!(CurveType::RoundCubicBSpline.control_points(), 4);
/// assert_eq!(CurveType::RoundLinear.code(), 0x2503);
/// assert_eq!(CurveType::from_code(0x250B), Some(CurveType::RoundCubicBezierRocaps));
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[doc(alias = "OptixPrimitiveType")]
pub enum CurveType {
    /// Piecewise linear segments with spherical end caps and elbows
    /// (`OPTIX_PRIMITIVE_TYPE_ROUND_LINEAR`).
    RoundLinear,
    /// Uniform quadratic B-spline (`OPTIX_PRIMITIVE_TYPE_ROUND_QUADRATIC_BSPLINE`).
    RoundQuadraticBSpline,
    /// Uniform cubic B-spline (`OPTIX_PRIMITIVE_TYPE_ROUND_CUBIC_BSPLINE`).
    RoundCubicBSpline,
    /// Catmull-Rom spline (`OPTIX_PRIMITIVE_TYPE_ROUND_CATMULLROM`).
    RoundCatmullRom,
    /// Cubic Bézier (`OPTIX_PRIMITIVE_TYPE_ROUND_CUBIC_BEZIER`).
    RoundCubicBezier,
    /// Ribbons: flat quadratic B-splines (`OPTIX_PRIMITIVE_TYPE_FLAT_QUADRATIC_BSPLINE`).
    FlatQuadraticBSpline,
    /// Swept-sphere quadratic B-spline (`OPTIX_PRIMITIVE_TYPE_ROUND_QUADRATIC_BSPLINE_ROCAPS`).
    RoundQuadraticBSplineRocaps,
    /// Swept-sphere cubic B-spline (`OPTIX_PRIMITIVE_TYPE_ROUND_CUBIC_BSPLINE_ROCAPS`).
    RoundCubicBSplineRocaps,
    /// Swept-sphere Catmull-Rom spline (`OPTIX_PRIMITIVE_TYPE_ROUND_CATMULLROM_ROCAPS`).
    RoundCatmullRomRocaps,
    /// Swept-sphere cubic Bézier (`OPTIX_PRIMITIVE_TYPE_ROUND_CUBIC_BEZIER_ROCAPS`).
    RoundCubicBezierRocaps,
}

impl CurveType {
    /// Every curve type, in `OptixPrimitiveType` order.
    #[doc(alias = "OptixPrimitiveType")]
    pub const ALL: [CurveType; 10] = [
        CurveType::RoundQuadraticBSpline,
        CurveType::RoundCubicBSpline,
        CurveType::RoundLinear,
        CurveType::RoundCatmullRom,
        CurveType::FlatQuadraticBSpline,
        CurveType::RoundCubicBezier,
        CurveType::RoundQuadraticBSplineRocaps,
        CurveType::RoundCubicBSplineRocaps,
        CurveType::RoundCatmullRomRocaps,
        CurveType::RoundCubicBezierRocaps,
    ];

    /// The `OptixPrimitiveType` value.
    #[doc(alias = "OptixPrimitiveType")]
    #[must_use]
    pub const fn code(self) -> u32 {
        match self {
            CurveType::RoundQuadraticBSpline => 0x2501,
            CurveType::RoundCubicBSpline => 0x2502,
            CurveType::RoundLinear => 0x2503,
            CurveType::RoundCatmullRom => 0x2504,
            CurveType::FlatQuadraticBSpline => 0x2505,
            CurveType::RoundCubicBezier => 0x2507,
            CurveType::RoundQuadraticBSplineRocaps => 0x2508,
            CurveType::RoundCubicBSplineRocaps => 0x2509,
            CurveType::RoundCatmullRomRocaps => 0x250A,
            CurveType::RoundCubicBezierRocaps => 0x250B,
        }
    }

    /// The curve type of an `OptixPrimitiveType` value.
    #[doc(alias = "OptixPrimitiveType")]
    #[must_use]
    pub const fn from_code(code: u32) -> Option<CurveType> {
        Some(match code {
            0x2501 => CurveType::RoundQuadraticBSpline,
            0x2502 => CurveType::RoundCubicBSpline,
            0x2503 => CurveType::RoundLinear,
            0x2504 => CurveType::RoundCatmullRom,
            0x2505 => CurveType::FlatQuadraticBSpline,
            0x2507 => CurveType::RoundCubicBezier,
            0x2508 => CurveType::RoundQuadraticBSplineRocaps,
            0x2509 => CurveType::RoundCubicBSplineRocaps,
            0x250A => CurveType::RoundCatmullRomRocaps,
            0x250B => CurveType::RoundCubicBezierRocaps,
            _ => return None,
        })
    }

    /// Control points of one segment (guide §5.2): 2 linear, 3 quadratic, 4 cubic.
    #[must_use]
    pub const fn control_points(self) -> usize {
        match self {
            CurveType::RoundLinear => 2,
            CurveType::RoundQuadraticBSpline
            | CurveType::FlatQuadraticBSpline
            | CurveType::RoundQuadraticBSplineRocaps => 3,
            _ => 4,
        }
    }

    /// Whether this is a ribbon (flat cross-section).
    #[must_use]
    pub const fn is_ribbon(self) -> bool {
        matches!(self, CurveType::FlatQuadraticBSpline)
    }

    /// Whether this is a Rocaps (swept-sphere) variant (guide §9.7).
    #[must_use]
    pub const fn is_rocaps(self) -> bool {
        matches!(
            self,
            CurveType::RoundQuadraticBSplineRocaps
                | CurveType::RoundCubicBSplineRocaps
                | CurveType::RoundCatmullRomRocaps
                | CurveType::RoundCubicBezierRocaps
        )
    }

    /// The pipeline flag that enables this type (`OptixPrimitiveTypeFlags`, guide §9.1).
    #[doc(alias = "OptixPrimitiveTypeFlags")]
    #[must_use]
    pub const fn type_flag(self) -> crate::PrimitiveTypeFlags {
        use crate::PrimitiveTypeFlags as F;
        match self {
            CurveType::RoundLinear => F::ROUND_LINEAR,
            CurveType::RoundQuadraticBSpline => F::ROUND_QUADRATIC_BSPLINE,
            CurveType::RoundCubicBSpline => F::ROUND_CUBIC_BSPLINE,
            CurveType::RoundCatmullRom => F::ROUND_CATMULLROM,
            CurveType::RoundCubicBezier => F::ROUND_CUBIC_BEZIER,
            CurveType::FlatQuadraticBSpline => F::FLAT_QUADRATIC_BSPLINE,
            CurveType::RoundQuadraticBSplineRocaps => F::ROUND_QUADRATIC_BSPLINE_ROCAPS,
            CurveType::RoundCubicBSplineRocaps => F::ROUND_CUBIC_BSPLINE_ROCAPS,
            CurveType::RoundCatmullRomRocaps => F::ROUND_CATMULLROM_ROCAPS,
            CurveType::RoundCubicBezierRocaps => F::ROUND_CUBIC_BEZIER_ROCAPS,
        }
    }
}

impl std::fmt::Display for CurveType {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            CurveType::RoundLinear => "round linear",
            CurveType::RoundQuadraticBSpline => "round quadratic B-spline",
            CurveType::RoundCubicBSpline => "round cubic B-spline",
            CurveType::RoundCatmullRom => "round Catmull-Rom",
            CurveType::RoundCubicBezier => "round cubic Bézier",
            CurveType::FlatQuadraticBSpline => "flat quadratic B-spline (ribbon)",
            CurveType::RoundQuadraticBSplineRocaps => "round quadratic B-spline (Rocaps)",
            CurveType::RoundCubicBSplineRocaps => "round cubic B-spline (Rocaps)",
            CurveType::RoundCatmullRomRocaps => "round Catmull-Rom (Rocaps)",
            CurveType::RoundCubicBezierRocaps => "round cubic Bézier (Rocaps)",
        })
    }
}

/// End caps of a curve input (`OptixCurveEndcapFlags`, guide §5.2).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum CurveEndcaps {
    /// `OPTIX_CURVE_ENDCAP_DEFAULT`: linear curves have round caps, the others open ends.
    #[default]
    Default,
    /// `OPTIX_CURVE_ENDCAP_ON`: flat caps at the ends of strands of quadratic, cubic,
    /// Catmull-Rom and Bézier curves (not valid for linear curves).
    On,
}

/// A curve build input (`OptixBuildInputCurveArray`, guide §5.2, §9.1): strands of polynomial
/// segments, each segment one primitive.
///
/// The control points (`float3`) and their radii (`f32`) are given per motion key, like a
/// sphere input's: one buffer per key of the build's motion options
/// ([`BuildError::MotionKeyCount`](crate::BuildError) otherwise); a ray at a time between two
/// keys meets the segment whose control points, radii and normals are interpolated linearly
/// between them (guide §5.10.2). The index buffer (required)
/// holds one `u32` per segment: the index of its first control point. Segment `N` ends a strand
/// unless `index[N + 1] == index[N] + 1` (§5.2), which is where end caps go. Ribbons may give
/// one normal buffer per key (segment `i` interpolates `n[i]` and `n[i + 1]` linearly). A curve
/// input has one SBT record, so one geometry flag and no per-primitive SBT index (§9.1).
///
/// ```
/// use oxray_core::{CurveEndcaps, CurveInput, CurveType};
/// // One cubic B-spline strand of two segments: five control points.
/// let points = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 1.0, 0.0], [3.0, 1.0, 0.0], [4.0, 0.0, 0.0]];
/// let radii = [0.1f32; 5];
/// let index = [0u32, 1];
/// let v = [bytemuck::cast_slice::<_, u8>(&points)];
/// let r = [bytemuck::cast_slice::<_, u8>(&radii)];
/// let input = CurveInput::new(CurveType::RoundCubicBSpline, &v, 5, &r, bytemuck::cast_slice(&index), 2)
///     .endcaps(CurveEndcaps::On);
/// assert_eq!(input.num_primitives(), 2);
/// assert_eq!(input.segment_start(&input.index_buffer, 1), 1);
/// ```
#[derive(Clone, Copy, Debug)]
pub struct CurveInput<'a> {
    /// The curve type (`curveType`).
    pub curve_type: CurveType,
    /// Control points (`float3`, little-endian), one buffer per motion key (`vertexBuffers`).
    pub vertex_buffers: &'a [&'a [u8]],
    /// Control points per buffer (`numVertices`).
    pub num_vertices: u32,
    /// Bytes from one control point to the next; 0 means 12 (a multiple of 4).
    pub vertex_stride: u32,
    /// Radii (`f32`), one per control point, one buffer per motion key (`widthBuffers`).
    pub width_buffers: &'a [&'a [u8]],
    /// Bytes from one radius to the next; 0 means 4 (a multiple of 4).
    pub width_stride: u32,
    /// Ribbon normals (`float3`), one buffer per motion key or none (`normalBuffers`).
    pub normal_buffers: &'a [&'a [u8]],
    /// Bytes from one normal to the next; 0 means 12 (a multiple of 4).
    pub normal_stride: u32,
    /// One `u32` per segment: its first control point (`indexBuffer`).
    pub index_buffer: &'a [u8],
    /// Bytes from one index to the next; 0 means 4 (a multiple of 4).
    pub index_stride: u32,
    /// Segments (`numPrimitives`).
    pub num_primitives: u32,
    /// The geometry flags of the input's one SBT record (`flag`).
    pub flag: GeometryFlags,
    /// End caps (`endcapFlags`).
    pub endcaps: CurveEndcaps,
    /// Added to the primitive index that hits report.
    pub primitive_index_offset: u32,
}

impl<'a> CurveInput<'a> {
    /// `num_primitives` segments of `curve_type` over `num_vertices` control points, tightly
    /// packed, with no normals, default end caps and no flags.
    #[must_use]
    pub fn new(
        curve_type: CurveType,
        vertex_buffers: &'a [&'a [u8]],
        num_vertices: u32,
        width_buffers: &'a [&'a [u8]],
        index_buffer: &'a [u8],
        num_primitives: u32,
    ) -> Self {
        CurveInput {
            curve_type,
            vertex_buffers,
            num_vertices,
            vertex_stride: 0,
            width_buffers,
            width_stride: 0,
            normal_buffers: &[],
            normal_stride: 0,
            index_buffer,
            index_stride: 0,
            num_primitives,
            flag: GeometryFlags::empty(),
            endcaps: CurveEndcaps::Default,
            primitive_index_offset: 0,
        }
    }

    /// Sets the control point stride in bytes.
    #[must_use]
    pub fn vertex_stride(mut self, stride: u32) -> Self {
        self.vertex_stride = stride;
        self
    }

    /// Sets the radius stride in bytes.
    #[must_use]
    pub fn width_stride(mut self, stride: u32) -> Self {
        self.width_stride = stride;
        self
    }

    /// Sets the ribbon normal buffers (one per motion key) and their stride.
    #[must_use]
    pub fn normals(mut self, buffers: &'a [&'a [u8]], stride: u32) -> Self {
        self.normal_buffers = buffers;
        self.normal_stride = stride;
        self
    }

    /// Sets the index stride in bytes.
    #[must_use]
    pub fn index_stride(mut self, stride: u32) -> Self {
        self.index_stride = stride;
        self
    }

    /// Sets the geometry flags of the input's SBT record.
    #[must_use]
    pub fn flag(mut self, flag: GeometryFlags) -> Self {
        self.flag = flag;
        self
    }

    /// Sets the end caps.
    #[must_use]
    pub fn endcaps(mut self, endcaps: CurveEndcaps) -> Self {
        self.endcaps = endcaps;
        self
    }

    /// Sets the primitive index offset.
    #[must_use]
    pub fn primitive_index_offset(mut self, offset: u32) -> Self {
        self.primitive_index_offset = offset;
        self
    }

    /// Segments this input declares.
    #[must_use]
    pub fn num_primitives(&self) -> u32 {
        self.num_primitives
    }

    /// `stride`, resolving 0 to `elem`.
    fn effective(stride: u32, elem: usize) -> usize {
        if stride == 0 {
            elem
        } else {
            stride as usize
        }
    }

    /// The control point stride in bytes, resolving 0.
    #[must_use]
    pub fn effective_vertex_stride(&self) -> usize {
        Self::effective(self.vertex_stride, 12)
    }

    /// The radius stride in bytes, resolving 0.
    #[must_use]
    pub fn effective_width_stride(&self) -> usize {
        Self::effective(self.width_stride, 4)
    }

    /// The normal stride in bytes, resolving 0.
    #[must_use]
    pub fn effective_normal_stride(&self) -> usize {
        Self::effective(self.normal_stride, 12)
    }

    /// The index stride in bytes, resolving 0.
    #[must_use]
    pub fn effective_index_stride(&self) -> usize {
        Self::effective(self.index_stride, 4)
    }

    /// The first control point of segment `i` in a validated index buffer.
    #[inline]
    #[must_use]
    pub fn segment_start(&self, index_buffer: &[u8], i: usize) -> u32 {
        read_u32(index_buffer, i * self.effective_index_stride())
    }

    /// Control point `i` of a validated key buffer.
    #[inline]
    #[must_use]
    pub fn point(&self, buffer: &[u8], i: usize) -> Vec3 {
        read_vec3(buffer, i * self.effective_vertex_stride())
    }

    /// Normal `i` of a validated key buffer.
    #[inline]
    #[must_use]
    pub fn normal(&self, buffer: &[u8], i: usize) -> Vec3 {
        read_vec3(buffer, i * self.effective_normal_stride())
    }

    /// Radius of control point `i` in a validated key buffer.
    #[inline]
    #[must_use]
    pub fn radius(&self, buffer: &[u8], i: usize) -> f32 {
        f32::from_bits(read_u32(buffer, i * self.effective_width_stride()))
    }

    /// Whether segment `i` starts a strand (§5.2: the one before it does not continue into it).
    #[must_use]
    pub fn starts_strand(&self, i: usize) -> bool {
        i == 0
            || self.segment_start(self.index_buffer, i - 1).wrapping_add(1)
                != self.segment_start(self.index_buffer, i)
    }

    /// Whether segment `i` ends a strand (§5.2).
    #[must_use]
    pub fn ends_strand(&self, i: usize) -> bool {
        i + 1 >= self.num_primitives as usize || self.starts_strand(i + 1)
    }
}

fn read_u32(buffer: &[u8], at: usize) -> u32 {
    let b = &buffer[at..at + 4];
    u32::from_le_bytes([b[0], b[1], b[2], b[3]])
}

fn read_vec3(buffer: &[u8], at: usize) -> Vec3 {
    let f = |k: usize| f32::from_bits(read_u32(buffer, at + 4 * k));
    Vec3::new(f(0), f(1), f(2))
}
