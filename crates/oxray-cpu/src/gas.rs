//! The CPU backend's geometry acceleration structure: the backend-neutral [`GasData`] in host
//! memory, traversed in place.

use crate::Isa;
use glam::Vec3;
use oxray_bvh::{GasData, GasKind, NodeWidth, QBvh8};
use oxray_core::{
    Aabb, BackendKind, BuildError, BuildInput, BuildOptions, PrimitiveTypeFlags, RandomAccessError,
    Traversable, TraversableKind,
};
use std::sync::Arc;

/// A geometry acceleration structure (GAS) in host memory, over triangles or custom primitives.
///
/// It copies what it needs from the build inputs, which may be dropped once it is built. The
/// built data ([`GasData`]: BVH, primitives, hit tables) is reachable through `Deref`.
///
/// ```
/// use oxray_cpu::Gas;
/// use oxray_core::{BuildOptions, IndexBuffer, Ray, TriangleInput, VertexBuffer};
/// use glam::Vec3;
/// let vertices = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
/// let triangles = [[0u32, 1, 2]];
/// let input = TriangleInput::new(VertexBuffer::f32x3(&vertices))
///     .indices(IndexBuffer::u32x3(&triangles));
/// let gas = Gas::build(&BuildOptions::default(), &[input.into()])?;
///
/// let hit = gas.intersect(&Ray::new(Vec3::new(0.0, 0.0, 1.0), -Vec3::Z)).unwrap();
/// assert_eq!((hit.t, hit.primitive_index), (1.0, 0));
/// assert!(gas.occluded(&Ray::new(Vec3::new(0.0, 0.0, -1.0), Vec3::Z)));
/// # Ok::<(), oxray_core::BuildError>(())
/// ```
#[derive(Clone, Debug)]
pub struct Gas {
    data: GasData,
    /// The kernel that traverses it: one this processor runs, whose layout `data` holds.
    isa: Isa,
    /// The pipeline flags of the curve types it holds (empty for other kinds), read by every
    /// trace that enters it (guide §9.1). Updates keep the curve types (§5.6).
    curve_types: PrimitiveTypeFlags,
    /// The first leaf slot of every primitive, for random vertex access (guide §13.9): only
    /// with `ALLOW_RANDOM_VERTEX_ACCESS`. Updates keep the slots (§5.6).
    prim_slots: Option<Arc<Vec<u32>>>,
    /// The quantised copy of the 8-wide nodes that a quantised kernel walks (derived from
    /// `data`, never saved; made again after every update).
    qbvh8: Option<QBvh8>,
}

impl Gas {
    /// Builds a GAS (`optixAccelBuild`). Inputs must all be of one kind; see [`BuildError`] for
    /// every rule checked. Primitives that can never be hit (a NaN or infinite coordinate, a
    /// zero-area triangle, an inverted box) are left out: they are inactive.
    ///
    /// It is traversed by the process's kernel ([`Isa::selected`]).
    #[doc(alias = "optixAccelBuild")]
    pub fn build(options: &BuildOptions, inputs: &[BuildInput<'_>]) -> Result<Gas, BuildError> {
        Self::build_with_isa(Isa::selected(), options, inputs)
    }

    /// [`build`](Self::build) for the kernel `isa` (clamped to what the processor has, see
    /// [`Isa::clamp`]): the structure holds the node layout that kernel traverses. The hits are
    /// those of every other kernel (see [`Isa`]).
    pub fn build_with_isa(
        isa: Isa,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<Gas, BuildError> {
        let isa = isa.clamp();
        let data = GasData::build_with_width(options, inputs, isa.width())?;
        Ok(Gas::from_data_with_isa(data, isa))
    }

    /// Wraps built (or loaded, or compacted) data for the kernel `isa`, clamped to what the
    /// processor has; a kernel of 8-wide nodes falls back to the 4-wide one ([`Isa::Sse`]) if
    /// the data has no 8-wide layout.
    #[must_use]
    pub fn from_data_with_isa(data: GasData, isa: Isa) -> Gas {
        let (isa, qbvh8) = Self::kernel_for(&data, isa);
        let curve_types = data
            .curves
            .iter()
            .fold(PrimitiveTypeFlags::empty(), |f, s| {
                f | s.curve_type().type_flag()
            });
        let prim_slots = data
            .build_flags
            .contains(oxray_core::BuildFlags::ALLOW_RANDOM_VERTEX_ACCESS)
            .then(|| Arc::new(data.primitive_slots()));
        Gas {
            data,
            isa,
            curve_types,
            prim_slots,
            qbvh8,
        }
    }

    /// The pipeline flags (`OptixPrimitiveTypeFlags`) of the curve types it holds; empty for a
    /// structure that is not made of curves.
    #[doc(alias = "OptixPrimitiveTypeFlags")]
    #[must_use]
    pub fn curve_types(&self) -> PrimitiveTypeFlags {
        self.curve_types
    }

    /// The kernel that traverses this structure.
    #[must_use]
    pub fn isa(&self) -> Isa {
        self.isa
    }

    /// A kernel this processor runs, whose layout `data` holds (with the quantised nodes such a
    /// kernel walks). A quantised kernel takes the float 8-wide layout of its instruction set
    /// for a structure with motion (its time parts are float nodes) or boxes that cannot be
    /// quantised.
    fn kernel_for(data: &GasData, isa: Isa) -> (Isa, Option<QBvh8>) {
        let isa = isa.clamp();
        let Some(bvh8) = data
            .bvh8
            .as_ref()
            .filter(|_| isa.width() == NodeWidth::Eight)
        else {
            return (Isa::Sse, None);
        };
        if !isa.is_quantized() || data.motion.is_some() {
            return (isa.unquantized(), None);
        }
        match QBvh8::quantize(bvh8) {
            Some(q) => (isa, Some(q)),
            None => (isa.unquantized(), None),
        }
    }

    /// The quantised nodes its kernel walks, where it is a quantised one.
    #[must_use]
    pub fn quantized_nodes(&self) -> Option<&QBvh8> {
        self.qbvh8.as_ref()
    }

    /// Bytes it holds: [`GasData::memory`] and the quantised nodes of a quantised kernel.
    #[must_use]
    pub fn memory(&self) -> oxray_bvh::GasMemory {
        let mut m = self.data.memory();
        let q = self.qbvh8.as_ref().map_or(0, QBvh8::memory);
        m.node_bytes += q;
        m.output_bytes += q;
        m
    }

    /// [`GasData::compacted_size`] and the quantised nodes, which a compacted copy for this
    /// kernel derives again.
    #[must_use]
    pub fn compacted_size(&self) -> Option<usize> {
        let q = self.qbvh8.as_ref().map_or(0, QBvh8::memory);
        self.data.compacted_size().map(|s| s + q)
    }

    /// The built data.
    #[must_use]
    pub fn data(&self) -> &GasData {
        &self.data
    }

    /// Updates (refits) the structure in place (guide §5.6); see [`GasData::update`]. A
    /// structure shared by handles is updated through [`oxray_core::AccelBackend::update_gas`]
    /// (copy-on-write) or the facade's `Device::update_gas`.
    pub fn update(
        &mut self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(), BuildError> {
        self.data.update(options, inputs)?;
        if self.qbvh8.is_some() {
            // The refit moved the boxes: quantise them again (or fall back to the float nodes
            // should one have become unquantisable).
            (self.isa, self.qbvh8) = Self::kernel_for(&self.data, self.isa);
        }
        Ok(())
    }
}

/// Random vertex access (guide §13.9): the primitives of a GAS built with
/// `ALLOW_RANDOM_VERTEX_ACCESS`, named as programs know them (the primitive index, with its
/// input's offset, and the SBT-GAS index), at a time (interpolated between motion keys as
/// traversal does). A primitive the builder left out (a degenerate triangle, a sphere without a
/// positive radius) reads NaN. Programs written as Rust closures call these on the GAS they
/// capture; CUDA C++ programs call the guide's `optixGet…FromHandle` functions.
impl Gas {
    fn random_slot(
        &self,
        asked: GasKind,
        primitive_index: u32,
        sbt_gas_index: u32,
    ) -> Result<Option<usize>, RandomAccessError> {
        let slots = self.prim_slots.as_deref().map_or(&[][..], |v| &v[..]);
        self.data
            .random_access_slot(slots, asked, primitive_index, sbt_gas_index)
    }

    /// `optixGetTriangleVertexDataFromHandle`: the object-space vertices of a triangle at
    /// `time`.
    ///
    /// ```
    /// use oxray_cpu::Gas;
    /// use oxray_core::{BuildFlags, BuildOptions, TriangleInput, VertexBuffer};
    /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    /// let input = TriangleInput::new(VertexBuffer::f32x3(&v)).primitive_index_offset(5);
    /// let gas = Gas::build(&BuildOptions::new(BuildFlags::ALLOW_RANDOM_VERTEX_ACCESS), &[input.into()])?;
    /// assert_eq!(gas.triangle_vertex_data(5, 0, 0.0).unwrap()[1].x, 1.0);
    /// assert!(gas.triangle_vertex_data(4, 0, 0.0).is_err());
    /// # Ok::<(), oxray_core::BuildError>(())
    /// ```
    #[doc(alias = "optixGetTriangleVertexDataFromHandle")]
    pub fn triangle_vertex_data(
        &self,
        primitive_index: u32,
        sbt_gas_index: u32,
        time: f32,
    ) -> Result<[Vec3; 3], RandomAccessError> {
        let slot = self.random_slot(GasKind::Triangles, primitive_index, sbt_gas_index)?;
        Ok(slot
            .and_then(|s| self.data.triangle_at(s, time))
            .map_or([Vec3::NAN; 3], |t| t.map(Vec3::from)))
    }

    /// `optixGetSphereDataFromHandle`: a sphere's object-space centre and radius
    /// `(x, y, z, r)` at `time`.
    #[doc(alias = "optixGetSphereDataFromHandle")]
    pub fn sphere_data(
        &self,
        primitive_index: u32,
        sbt_gas_index: u32,
        time: f32,
    ) -> Result<[f32; 4], RandomAccessError> {
        let slot = self.random_slot(GasKind::Spheres, primitive_index, sbt_gas_index)?;
        Ok(slot
            .and_then(|s| self.data.sphere_at(s, time))
            .map_or([f32::NAN; 4], |s| s.to_array()))
    }

    /// `optixGetLinearCurveVertexDataFromHandle`, `…QuadraticBSpline…`, `…CubicBSpline…`,
    /// `…CatmullRom…`, `…CubicBezier…`, their Rocaps variants and
    /// `optixGetRibbonVertexDataFromHandle`: a curve segment's control points
    /// `(x, y, z, radius)` at `time`, as many as its type has, then zeros.
    #[doc(alias = "optixGetCubicBSplineVertexDataFromHandle")]
    pub fn curve_vertex_data(
        &self,
        primitive_index: u32,
        sbt_gas_index: u32,
        time: f32,
    ) -> Result<[[f32; 4]; 4], RandomAccessError> {
        let slot = self.random_slot(GasKind::Curves, primitive_index, sbt_gas_index)?;
        Ok(slot
            .and_then(|s| self.data.curve_at(s, time))
            .map_or([[f32::NAN; 4]; 4], |c| c.points))
    }
}

impl From<GasData> for Gas {
    /// Wraps data for the process's kernel ([`Isa::selected`]); see
    /// [`Gas::from_data_with_isa`].
    fn from(data: GasData) -> Self {
        Gas::from_data_with_isa(data, Isa::selected())
    }
}

impl std::ops::Deref for Gas {
    type Target = GasData;

    fn deref(&self) -> &GasData {
        &self.data
    }
}

impl Traversable for Gas {
    fn traversable_kind(&self) -> TraversableKind {
        TraversableKind::Gas
    }

    fn bounds(&self) -> Aabb {
        self.data.bounds
    }

    fn graph_depth(&self) -> u32 {
        1
    }

    fn backend(&self) -> BackendKind {
        BackendKind::Cpu
    }

    fn describe(&self) -> String {
        format!("CPU GAS of {} primitives", self.data.num_primitives)
    }

    fn lineage(&self) -> Option<u64> {
        Some(self.data.lineage)
    }
}

/// A traversable of the CPU backend, resolved from a handle once (at an IAS build, or when a
/// trace starts) so that traversal dispatches on a closed enum, never on a trait object.
#[derive(Clone)]
pub(crate) enum CpuNode {
    Gas(Arc<Gas>),
    Ias(Arc<crate::Ias>),
    Static(Arc<oxray_core::StaticTransform>),
    MatrixMotion(Arc<oxray_core::MatrixMotionTransform>),
    SrtMotion(Arc<oxray_core::SrtMotionTransform>),
}

impl std::fmt::Debug for CpuNode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&match self {
            CpuNode::Gas(g) => g.describe(),
            CpuNode::Ias(i) => i.describe(),
            CpuNode::Static(s) => s.describe(),
            CpuNode::MatrixMotion(m) => m.describe(),
            CpuNode::SrtMotion(m) => m.describe(),
        })
    }
}

impl CpuNode {
    /// The CPU object behind a handle: `Ok(None)` for the null handle, `Err(backend)` for an
    /// object of another backend.
    pub(crate) fn resolve(
        handle: &oxray_core::TraversableHandle,
    ) -> Result<Option<CpuNode>, BackendKind> {
        let Some(backend) = handle.backend() else {
            return Ok(None);
        };
        if let Some(g) = handle.downcast_arc::<Gas>() {
            return Ok(Some(CpuNode::Gas(g)));
        }
        if let Some(i) = handle.downcast_arc::<crate::Ias>() {
            return Ok(Some(CpuNode::Ias(i)));
        }
        if let Some(s) = handle.downcast_arc::<oxray_core::StaticTransform>() {
            if matches!(s.backend(), BackendKind::Cpu | BackendKind::Any) {
                return Ok(Some(CpuNode::Static(s)));
            }
        }
        // Motion transforms over structures of this backend (or over nothing).
        if matches!(backend, BackendKind::Cpu | BackendKind::Any) {
            if let Some(m) = handle.downcast_arc::<oxray_core::MatrixMotionTransform>() {
                return Ok(Some(CpuNode::MatrixMotion(m)));
            }
            if let Some(m) = handle.downcast_arc::<oxray_core::SrtMotionTransform>() {
                return Ok(Some(CpuNode::SrtMotion(m)));
            }
        }
        Err(backend)
    }
}
