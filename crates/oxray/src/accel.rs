//! Acceleration structures on any device: the facade's [`Gas`] and [`Ias`].

use crate::device::Device;
use glam::Vec3;
use oxray_bvh::{BvhStats, GasMemory};
use oxray_core::{
    Aabb, AccelProperty, AllHits, BackendKind, BuildError, BuildFlags, BuildInput, BuildInputKind,
    BuildOptions, ClosestPoint, EmittedProperty, GeometryFlags, Hit, InstanceClosestPoint,
    LoadError, QueryError, RandomAccessError, Ray, ShadingNormals, SurfaceHit, SurfaceQueryError,
    Traversable, TraversableHandle, TraversableKind,
};
use std::sync::Arc;

#[derive(Clone)]
pub(crate) enum GasRepr {
    Cpu(Arc<oxray_cpu::Gas>),
    #[cfg(feature = "cuda")]
    Cuda(Arc<oxray_cuda::CudaGas>),
}

/// A geometry acceleration structure (GAS) on some device, from [`Device::build_gas`].
///
/// Cheap to clone (the structure is shared). It converts into a [`TraversableHandle`] for
/// instances and traces. Batched queries run on the device that holds it; the per-ray queries,
/// any-hit filters and custom-primitive closures of the CPU backend are on its CPU structure
/// ([`as_cpu`](Self::as_cpu), or build an [`oxray::cpu::Gas`](crate::cpu::Gas) directly).
///
/// ```
/// use oxray::{BuildOptions, Device, Gas, IndexBuffer, Ray, TriangleInput, VertexBuffer};
/// use glam::Vec3;
/// let vertices = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
/// let triangles = [[0u32, 1, 2], [0, 2, 3]];
/// let input = TriangleInput::new(VertexBuffer::f32x3(&vertices))
///     .indices(IndexBuffer::u32x3(&triangles));
/// let gas: Gas = Device::cpu().build_gas(&BuildOptions::default(), &[input.into()])?;
/// assert_eq!(gas.num_primitives(), 2);
///
/// let rays = vec![Ray::new(Vec3::new(0.25, 0.75, 1.0), -Vec3::Z); 16];
/// let mut hits = vec![None; rays.len()];
/// gas.intersect_batch(&rays, &mut hits)?;
/// assert_eq!(hits[0].unwrap().primitive_index, 1);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone)]
pub struct Gas(GasRepr);

/// Calls `$body` with `$g` bound to the structure of whichever backend holds it.
macro_rules! on_gas {
    ($gas:expr, $g:ident => $cpu:expr, $cuda:expr) => {
        match &$gas.0 {
            GasRepr::Cpu($g) => $cpu,
            #[cfg(feature = "cuda")]
            GasRepr::Cuda($g) => $cuda,
        }
    };
}

impl Gas {
    pub(crate) fn from_repr(repr: GasRepr) -> Gas {
        Gas(repr)
    }

    pub(crate) fn repr_mut(&mut self) -> &mut GasRepr {
        &mut self.0
    }

    pub(crate) fn repr(&self) -> &GasRepr {
        &self.0
    }

    /// Builds a GAS on the CPU: shorthand for `Device::cpu().build_gas(options, inputs)`.
    pub fn build(options: &BuildOptions, inputs: &[BuildInput<'_>]) -> Result<Gas, BuildError> {
        Device::cpu().build_gas(options, inputs)
    }

    /// A handle for instances and traces.
    #[must_use]
    pub fn handle(&self) -> TraversableHandle {
        on_gas!(self, g => g.clone().into(), g.clone().into())
    }

    /// The backend whose memory holds it.
    #[must_use]
    pub fn device_kind(&self) -> BackendKind {
        on_gas!(self, _g => BackendKind::Cpu, BackendKind::Cuda)
    }

    /// The CPU structure, if it lives on the CPU.
    #[must_use]
    pub fn as_cpu(&self) -> Option<&oxray_cpu::Gas> {
        on_gas!(self, g => Some(g), { let _ = g; None })
    }

    /// The CUDA structure, if it lives on a CUDA device.
    #[cfg(feature = "cuda")]
    #[must_use]
    pub fn as_cuda(&self) -> Option<&oxray_cuda::CudaGas> {
        on_gas!(self, _g => None, Some(_g))
    }

    /// The kind of primitives.
    #[must_use]
    pub fn kind(&self) -> BuildInputKind {
        on_gas!(self, g => g.kind(), g.info().kind)
    }

    /// The flags it was built with.
    #[must_use]
    pub fn build_flags(&self) -> BuildFlags {
        on_gas!(self, g => g.build_flags, g.info().build_flags)
    }

    /// Primitives declared over all build inputs, inactive ones included.
    #[must_use]
    pub fn num_primitives(&self) -> u32 {
        on_gas!(self, g => g.num_primitives, g.info().num_primitives)
    }

    /// Primitives that can be hit.
    #[must_use]
    pub fn num_active_primitives(&self) -> u32 {
        on_gas!(self, g => g.num_active_primitives(), g.info().num_active_primitives)
    }

    /// Number of build inputs.
    #[must_use]
    pub fn num_build_inputs(&self) -> usize {
        on_gas!(self, g => g.num_build_inputs(), g.info().num_build_inputs)
    }

    /// SBT records over all build inputs (the span of SBT-GAS indices).
    #[must_use]
    pub fn num_sbt_records(&self) -> u32 {
        on_gas!(self, g => g.num_sbt_records(), g.info().record_flags.len() as u32)
    }

    /// The geometry flags of an SBT record, by SBT-GAS index.
    #[must_use]
    pub fn geometry_flags(&self, sbt_gas_index: u32) -> Option<GeometryFlags> {
        on_gas!(
            self,
            g => g.geometry_flags(sbt_gas_index),
            g.info().record_flags.get(sbt_gas_index as usize).copied()
        )
    }

    /// The box around every active primitive (empty when there is none).
    #[must_use]
    pub fn bounds(&self) -> Aabb {
        on_gas!(self, g => g.bounds, g.info().bounds)
    }

    /// Random vertex access (`optixGetTriangleVertexDataFromHandle`, guide §13.9): the
    /// object-space vertices of the triangle programs know as `primitive_index` (with its
    /// input's offset) under `sbt_gas_index`, at `time`, on any device (a GPU's are read from
    /// its memory). Needs `ALLOW_RANDOM_VERTEX_ACCESS`; a triangle the builder left out
    /// (degenerate) reads NaN; what OptiX leaves undefined is a [`RandomAccessError`].
    ///
    /// ```
    /// use oxray::{BuildFlags, BuildOptions, Device, TriangleInput, VertexBuffer};
    /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    /// let options = BuildOptions::new(BuildFlags::ALLOW_RANDOM_VERTEX_ACCESS);
    /// let gas = Device::cpu().build_gas(&options, &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
    /// assert_eq!(gas.triangle_vertex_data(0, 0, 0.0)?[2].y, 1.0);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    #[doc(alias = "optixGetTriangleVertexDataFromHandle")]
    pub fn triangle_vertex_data(
        &self,
        primitive_index: u32,
        sbt_gas_index: u32,
        time: f32,
    ) -> Result<[glam::Vec3; 3], RandomAccessError> {
        on_gas!(
            self,
            g => g.triangle_vertex_data(primitive_index, sbt_gas_index, time),
            g.triangle_vertex_data(primitive_index, sbt_gas_index, time)
                .map(|t| t.map(glam::Vec3::from))
        )
    }

    /// Random vertex access to a sphere (`optixGetSphereDataFromHandle`, guide §13.9): its
    /// centre and radius `(x, y, z, r)`; see [`triangle_vertex_data`](Self::triangle_vertex_data).
    #[doc(alias = "optixGetSphereDataFromHandle")]
    pub fn sphere_data(
        &self,
        primitive_index: u32,
        sbt_gas_index: u32,
        time: f32,
    ) -> Result<[f32; 4], RandomAccessError> {
        on_gas!(
            self,
            g => g.sphere_data(primitive_index, sbt_gas_index, time),
            g.sphere_data(primitive_index, sbt_gas_index, time)
        )
    }

    /// Random vertex access to a curve segment (the `optixGet…VertexDataFromHandle` functions
    /// of curves, guide §13.9): its control points `(x, y, z, radius)`, as many as its type
    /// has, then zeros; see [`triangle_vertex_data`](Self::triangle_vertex_data).
    #[doc(alias = "optixGetCubicBSplineVertexDataFromHandle")]
    pub fn curve_vertex_data(
        &self,
        primitive_index: u32,
        sbt_gas_index: u32,
        time: f32,
    ) -> Result<[[f32; 4]; 4], RandomAccessError> {
        on_gas!(
            self,
            g => g.curve_vertex_data(primitive_index, sbt_gas_index, time),
            g.curve_vertex_data(primitive_index, sbt_gas_index, time)
        )
    }

    /// Statistics of the BVH it was built with: nodes, depth, SAH cost.
    #[must_use]
    pub fn stats(&self) -> BvhStats {
        on_gas!(self, g => g.stats(), g.info().stats)
    }

    /// Bytes the structure occupies in its device's memory.
    #[must_use]
    pub fn memory(&self) -> GasMemory {
        on_gas!(self, g => g.memory(), GasMemory {
            output_bytes: g.device_bytes(),
            node_bytes: g.num_nodes() * g.layout().node_bytes(),
            primitive_bytes: g.device_bytes() - g.num_nodes() * g.layout().node_bytes(),
        })
    }

    /// A property of the built structure (guide §5.8): its compacted size (needs
    /// `ALLOW_COMPACTION`; [`BuildError::CompactionNotAllowed`] without it) or its box, on
    /// every device.
    pub fn emit_property(&self, property: AccelProperty) -> Result<EmittedProperty, BuildError> {
        match property {
            // One box per motion key (guide §5.10.2).
            AccelProperty::Aabbs => Ok(EmittedProperty::Aabbs(on_gas!(
                self,
                g => g.data().key_bounds(),
                g.key_bounds()
            ))),
            AccelProperty::CompactedSize => on_gas!(
                self,
                g => g
                    .compacted_size()
                    .map(|s| EmittedProperty::CompactedSize(s as u64))
                    .ok_or(BuildError::CompactionNotAllowed),
                g.compacted_size()
                    .map(|s| EmittedProperty::CompactedSize(s as u64))
                    .ok_or(BuildError::CompactionNotAllowed)
            ),
        }
    }

    /// Saves the structure as bytes (versioned and checksummed) that
    /// [`Device::load_gas`] loads back on any device. On the CPU the loaded structure gives
    /// bit-identical hits; a structure saved from a GPU is read back from its memory and
    /// assembled into the CPU's layout, so its hits are the same up to which of two primitives
    /// at exactly the same distance is reported (`docs/gpu-backend.md`).
    pub fn to_bytes(&self) -> Result<Vec<u8>, LoadError> {
        on_gas!(self, g => Ok(g.data().to_bytes()), Ok(g.to_data()?.to_bytes()))
    }

    /// Closest hits of a batch on the structure's device; the same hits on every device and
    /// for every thread count.
    pub fn intersect_batch(
        &self,
        rays: &[Ray],
        hits: &mut [Option<Hit>],
    ) -> Result<(), QueryError> {
        on_gas!(
            self,
            g => g.intersect_batch(rays, hits),
            {
                let handle = TraversableHandle::from(g.clone());
                oxray_core::AccelBackend::intersect_closest(&cuda_of(g.context()), &handle, rays, hits)
            }
        )
    }

    /// Occlusion of a batch on the structure's device.
    pub fn occluded_batch(&self, rays: &[Ray], occluded: &mut [bool]) -> Result<(), QueryError> {
        on_gas!(
            self,
            g => g.occluded_batch(rays, occluded),
            {
                let handle = TraversableHandle::from(g.clone());
                oxray_core::AccelBackend::intersect_any(&cuda_of(g.context()), &handle, rays, occluded)
            }
        )
    }

    /// Every primitive each ray crosses in its `[tmin, tmax]`, on the structure's device, into
    /// `out` (cleared first): sorted by `t` (then instance, build input and primitive), each
    /// primitive once, at most `max_hits_per_ray` (the nearest), with whether each list is
    /// complete. The same lists, bit for bit, on every device (multiple LiDAR returns, paths
    /// through walls). An invalid ray is an error (the lowest index) and `out` is left empty.
    ///
    /// ```
    /// use oxray::{AllHits, Device, Gas, Ray};
    /// use glam::Vec3;
    /// // Two parallel triangles at z = 1 and z = 2.
    /// let v = [[-1.0f32, -1.0, 1.0], [1.0, -1.0, 1.0], [0.0, 1.0, 1.0],
    ///          [-1.0, -1.0, 2.0], [1.0, -1.0, 2.0], [0.0, 1.0, 2.0]];
    /// let gas = Gas::from(oxray::cpu::Gas::from_mesh(&v, &[[0, 1, 2], [3, 4, 5]])?);
    /// let rays = [Ray::new(Vec3::ZERO, Vec3::Z), Ray::new(Vec3::ZERO, -Vec3::Z)];
    /// let mut out = AllHits::new();
    /// gas.all_hits_batch(&rays, 8, &mut out)?;
    /// assert_eq!(out.hits(0).iter().map(|h| h.t).collect::<Vec<_>>(), [1.0, 2.0]);
    /// assert!(out.hits(1).is_empty());
    /// let mut counts = [0u32; 2];
    /// gas.count_hits_batch(&rays, &mut counts)?;
    /// assert_eq!(counts, [2, 0]);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn all_hits_batch(
        &self,
        rays: &[Ray],
        max_hits_per_ray: usize,
        out: &mut AllHits,
    ) -> Result<(), SurfaceQueryError> {
        on_gas!(
            self,
            g => g.all_hits_batch(rays, max_hits_per_ray, out),
            g.all_hits_batch(rays, max_hits_per_ray, out)
        )
    }

    /// The number of distinct primitives each ray crosses in its `[tmin, tmax]`, on the
    /// structure's device. The first invalid ray (the lowest index) is the error; the counts
    /// of the others are written.
    pub fn count_hits_batch(
        &self,
        rays: &[Ray],
        counts: &mut [u32],
    ) -> Result<(), SurfaceQueryError> {
        on_gas!(
            self,
            g => g.count_hits_batch(rays, counts),
            g.count_hits_batch(rays, counts)
        )
    }

    /// The closest point of this triangle GAS to every point, on the structure's device: the
    /// point, its distance, triangle and barycentrics, the same on every device (`None` for an
    /// empty GAS). The first non-finite point (the lowest index) is the error; the others'
    /// results are written.
    ///
    /// ```
    /// use oxray::{Gas, glam::Vec3};
    /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    /// // A tetrahedron, counter-clockwise seen from outside.
    /// let gas = Gas::from(oxray::cpu::Gas::from_mesh(&v, &[[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])?);
    /// let points = [Vec3::new(0.25, 0.25, -1.0), Vec3::splat(0.1)];
    /// let mut closest = [None; 2];
    /// gas.closest_point_batch(&points, &mut closest)?;
    /// assert_eq!(closest[0].unwrap().point, Vec3::new(0.25, 0.25, 0.0));
    /// let mut sdf = [0.0f32; 2];
    /// gas.signed_distance_batch(&points, &mut sdf)?;
    /// assert!(sdf[0] == 1.0 && sdf[1] < 0.0);
    /// let mut inside = [false; 2];
    /// gas.contains_batch(&points, &mut inside)?;
    /// assert_eq!(inside, [false, true]);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn closest_point_batch(
        &self,
        points: &[Vec3],
        out: &mut [Option<ClosestPoint>],
    ) -> Result<(), SurfaceQueryError> {
        on_gas!(
            self,
            g => g.closest_point_batch(points, out),
            g.closest_point_batch(points, out)
        )
    }

    /// The signed distance from every point to the surface, on the structure's device:
    /// negative inside a closed, consistently oriented mesh (counter-clockwise seen from
    /// outside), `+inf` for an empty GAS. Errors as
    /// [`closest_point_batch`](Self::closest_point_batch).
    pub fn signed_distance_batch(
        &self,
        points: &[Vec3],
        out: &mut [f32],
    ) -> Result<(), SurfaceQueryError> {
        on_gas!(
            self,
            g => g.signed_distance_batch(points, out),
            g.signed_distance_batch(points, out)
        )
    }

    /// Whether every point lies strictly inside the closed mesh (a negative signed distance),
    /// on the structure's device.
    pub fn contains_batch(
        &self,
        points: &[Vec3],
        out: &mut [bool],
    ) -> Result<(), SurfaceQueryError> {
        on_gas!(
            self,
            g => g.contains_batch(points, out),
            g.contains_batch(points, out)
        )
    }

    /// The world-space point, unit geometric and shading normals and face of every hit
    /// (`hits[i]` of `rays[i]`, `None` for a miss), on the structure's device: the same values
    /// on every device. A hit that is not on its ray in this structure is
    /// [`SurfaceQueryError::HitNotFound`]; the first failing query (the lowest index) is the
    /// error and every other output is written.
    ///
    /// ```
    /// use oxray::{Gas, Ray, glam::Vec3};
    /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    /// let gas = Gas::from(oxray::cpu::Gas::from_mesh(&v, &[[0, 1, 2]])?);
    /// let rays = [Ray::new(Vec3::new(0.25, 0.25, 1.0), -Vec3::Z)];
    /// let mut hits = [None];
    /// gas.intersect_batch(&rays, &mut hits)?;
    /// let mut surfaces = [None];
    /// gas.hit_surface_batch(&rays, &hits, &mut surfaces)?;
    /// let s = surfaces[0].unwrap();
    /// assert_eq!((s.point, s.geometric_normal), (Vec3::new(0.25, 0.25, 0.0), Vec3::Z));
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn hit_surface_batch(
        &self,
        rays: &[Ray],
        hits: &[Option<Hit>],
        out: &mut [Option<SurfaceHit>],
    ) -> Result<(), SurfaceQueryError> {
        on_gas!(
            self,
            g => g.hit_surface_batch(rays, hits, out),
            g.hit_surface_batch(rays, hits, out)
        )
    }

    /// [`hit_surface_batch`](Self::hit_surface_batch) with the shading normal interpolated from
    /// vertex normals.
    pub fn hit_surface_batch_shaded<N: ShadingNormals + Sync + ?Sized>(
        &self,
        rays: &[Ray],
        hits: &[Option<Hit>],
        normals: &N,
        out: &mut [Option<SurfaceHit>],
    ) -> Result<(), SurfaceQueryError> {
        on_gas!(
            self,
            g => g.hit_surface_batch_shaded(rays, hits, normals, out),
            g.hit_surface_batch_shaded(rays, hits, normals, out)
        )
    }
}

/// The CUDA backend of the context a structure lives in.
#[cfg(feature = "cuda")]
fn cuda_of(ctx: &oxray_cuda::CudaContext) -> oxray_cuda::Cuda {
    oxray_cuda::Cuda::from_context(ctx.clone())
}

impl From<oxray_cpu::Gas> for Gas {
    fn from(g: oxray_cpu::Gas) -> Self {
        Gas(GasRepr::Cpu(Arc::new(g)))
    }
}

impl std::fmt::Debug for Gas {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Gas({})", on_gas!(self, g => g.describe(), g.describe()))
    }
}

impl Traversable for Gas {
    fn traversable_kind(&self) -> TraversableKind {
        TraversableKind::Gas
    }
    fn bounds(&self) -> Aabb {
        Gas::bounds(self)
    }
    fn graph_depth(&self) -> u32 {
        1
    }
    fn backend(&self) -> BackendKind {
        self.device_kind()
    }
    fn describe(&self) -> String {
        format!("{self:?}")
    }
    /// A handle refers to the backend's structure, not to this wrapper.
    fn into_object(self: Arc<Self>) -> Arc<dyn Traversable> {
        match &self.0 {
            GasRepr::Cpu(g) => g.clone(),
            #[cfg(feature = "cuda")]
            GasRepr::Cuda(g) => g.clone(),
        }
    }
}

#[derive(Clone)]
pub(crate) enum IasRepr {
    Cpu(Arc<oxray_cpu::Ias>),
    #[cfg(feature = "cuda")]
    Cuda(Arc<oxray_cuda::CudaIas>),
}

/// Calls `$body` with `$i` bound to the IAS data of whichever backend holds it.
macro_rules! on_ias {
    ($ias:expr, $i:ident => $cpu:expr, $cuda:expr) => {
        match &$ias.0 {
            IasRepr::Cpu($i) => $cpu,
            #[cfg(feature = "cuda")]
            IasRepr::Cuda($i) => $cuda,
        }
    };
}

/// An instance acceleration structure (IAS) on some device, from [`Device::build_ias`]. It
/// keeps every child it references alive. The CPU backend builds any graph (IASes of IASes,
/// transforms); the CUDA backend one level of instances over GASes, refusing deeper graphs
/// with `Unsupported`.
///
/// ```
/// use oxray::{BuildOptions, Device, Instance, Ray, Transform, TriangleInput, VertexBuffer};
/// use glam::Vec3;
/// let device = Device::cpu();
/// let v = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
/// let gas = device.build_gas(&BuildOptions::default(), &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
/// let instances: Vec<Instance> = (0..3)
///     .map(|i| Instance::new(gas.handle())
///         .transform(Transform::from_translation(Vec3::new(0.0, 0.0, i as f32)))
///         .instance_id(10 + i))
///     .collect();
/// let ias = device.build_ias(&BuildOptions::default(), &[(&instances[..]).into()])?;
/// let mut hits = [None];
/// device.intersect_closest(&ias.handle(), &[Ray::new(Vec3::new(0.0, 0.0, 5.0), -Vec3::Z)], &mut hits)?;
/// let hit = hits[0].unwrap();
/// assert_eq!((hit.t, hit.instance_id, hit.instance_index), (3.0, 12, 2));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone)]
pub struct Ias(IasRepr);

impl Ias {
    pub(crate) fn from_repr(repr: IasRepr) -> Ias {
        Ias(repr)
    }

    pub(crate) fn repr_mut(&mut self) -> &mut IasRepr {
        &mut self.0
    }

    pub(crate) fn repr(&self) -> &IasRepr {
        &self.0
    }

    /// Builds an IAS on the CPU: shorthand for `Device::cpu().build_ias(options, inputs)`.
    pub fn build(options: &BuildOptions, inputs: &[BuildInput<'_>]) -> Result<Ias, BuildError> {
        Device::cpu().build_ias(options, inputs)
    }

    /// A handle for instances and traces.
    #[must_use]
    pub fn handle(&self) -> TraversableHandle {
        on_ias!(self, i => i.clone().into(), i.clone().into())
    }

    /// The CPU structure, if it lives on the CPU.
    #[must_use]
    pub fn as_cpu(&self) -> Option<&oxray_cpu::Ias> {
        on_ias!(self, i => Some(i), { let _ = i; None })
    }

    /// The CUDA structure, if it lives on a CUDA device.
    #[cfg(feature = "cuda")]
    #[must_use]
    pub fn as_cuda(&self) -> Option<&oxray_cuda::CudaIas> {
        on_ias!(self, _i => None, Some(_i))
    }

    /// The backend whose memory holds it.
    #[must_use]
    pub fn device_kind(&self) -> BackendKind {
        on_ias!(self, _i => BackendKind::Cpu, BackendKind::Cuda)
    }

    /// The built data: instances in slot order, world boxes, flags.
    fn data(&self) -> &oxray_bvh::IasData {
        on_ias!(self, i => i.data(), i.data())
    }

    /// Instances in the build input.
    #[must_use]
    pub fn num_instances(&self) -> u32 {
        self.data().num_instances
    }

    /// The world box of every instance that can be hit.
    #[must_use]
    pub fn bounds(&self) -> Aabb {
        self.data().bounds
    }

    /// Random instance access (`optixGetInstanceTraversableFromIAS`, guide §13.12): the
    /// instance of index `index` in the build input, with its transforms, id, SBT offset,
    /// mask, flags and child. Needs `ALLOW_RANDOM_INSTANCE_ACCESS`.
    ///
    /// ```
    /// use oxray::{BuildFlags, BuildOptions, Device, Instance, TraversableHandle};
    /// let list = [Instance::new(TraversableHandle::NULL).instance_id(7)];
    /// let options = BuildOptions::new(BuildFlags::ALLOW_RANDOM_INSTANCE_ACCESS);
    /// let ias = Device::cpu().build_ias(&options, &[(&list[..]).into()])?;
    /// assert_eq!(ias.instance(0)?.instance_id, 7);
    /// assert!(ias.instance(1).is_err());
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    #[doc(alias = "optixGetInstanceTraversableFromIAS")]
    pub fn instance(&self, index: u32) -> Result<&oxray_bvh::InstanceData, RandomAccessError> {
        self.data().instance_by_index(index)
    }

    /// Levels of the traversable graph from this IAS down (an IAS over GASes is 2).
    #[must_use]
    pub fn graph_depth(&self) -> u32 {
        self.data().depth
    }

    /// Statistics of the BVH over the instances.
    #[must_use]
    pub fn stats(&self) -> BvhStats {
        self.data().stats()
    }

    /// The flags it was built with.
    #[must_use]
    pub fn build_flags(&self) -> BuildFlags {
        self.data().build_flags
    }

    /// Saves the IAS without its children; [`Device::load_ias`] loads it back, on any
    /// device, over children given by instance index.
    pub fn to_bytes(&self) -> Result<Vec<u8>, LoadError> {
        Ok(self.data().to_bytes())
    }

    /// Bytes of the IAS's own tables (its children are not counted).
    #[must_use]
    pub fn memory_bytes(&self) -> usize {
        self.data().memory_bytes()
    }

    /// A property of the built IAS (guide §5.8): its compacted size (needs
    /// `ALLOW_COMPACTION`; on a GPU, its device tables' bytes) or its box.
    pub fn emit_property(&self, property: AccelProperty) -> Result<EmittedProperty, BuildError> {
        match property {
            AccelProperty::Aabbs => Ok(EmittedProperty::Aabbs(vec![self.bounds()])),
            AccelProperty::CompactedSize => on_ias!(
                self,
                i => i.data().compacted_size(),
                i.compacted_size()
            )
            .map(|s| EmittedProperty::CompactedSize(s as u64))
            .ok_or(BuildError::CompactionNotAllowed),
        }
    }

    /// Closest hits of a batch on the structure's device.
    pub fn intersect_batch(
        &self,
        rays: &[Ray],
        hits: &mut [Option<Hit>],
    ) -> Result<(), QueryError> {
        on_ias!(
            self,
            i => i.intersect_batch(rays, hits),
            {
                let handle = TraversableHandle::from(i.clone());
                oxray_core::AccelBackend::intersect_closest(&cuda_of(i.context()), &handle, rays, hits)
            }
        )
    }

    /// Occlusion of a batch on the structure's device.
    pub fn occluded_batch(&self, rays: &[Ray], occluded: &mut [bool]) -> Result<(), QueryError> {
        on_ias!(
            self,
            i => i.occluded_batch(rays, occluded),
            {
                let handle = TraversableHandle::from(i.clone());
                oxray_core::AccelBackend::intersect_any(&cuda_of(i.context()), &handle, rays, occluded)
            }
        )
    }

    /// Every primitive of every instance each ray crosses, on the structure's device (see
    /// [`Gas::all_hits_batch`]): each primitive of each instance once. On CUDA, over one level
    /// of instances of triangle GASes.
    pub fn all_hits_batch(
        &self,
        rays: &[Ray],
        max_hits_per_ray: usize,
        out: &mut AllHits,
    ) -> Result<(), SurfaceQueryError> {
        on_ias!(
            self,
            i => i.all_hits_batch(rays, max_hits_per_ray, out),
            i.all_hits_batch(rays, max_hits_per_ray, out)
        )
    }

    /// The number of distinct primitives of every instance each ray crosses, on the
    /// structure's device (see [`Gas::count_hits_batch`]).
    pub fn count_hits_batch(
        &self,
        rays: &[Ray],
        counts: &mut [u32],
    ) -> Result<(), SurfaceQueryError> {
        on_ias!(
            self,
            i => i.count_hits_batch(rays, counts),
            i.count_hits_batch(rays, counts)
        )
    }

    /// The closest point of the triangles under the instances to every point, with the
    /// instance it lies under, on the structure's device: the same point, distance, triangle
    /// and instance on every device (among equally close instances, the nearer box, then the
    /// lower slot). Instances must be placed by similarities; on CUDA, over one level of
    /// instances of triangle GASes. What cannot be answered is refused before any search.
    pub fn closest_point_batch(
        &self,
        points: &[Vec3],
        out: &mut [Option<InstanceClosestPoint>],
    ) -> Result<(), SurfaceQueryError> {
        on_ias!(
            self,
            i => i.closest_point_batch(points, out),
            i.closest_point_batch(points, out)
        )
    }

    /// The surfaces of hits through the instances, on the structure's device (see
    /// [`Gas::hit_surface_batch`]). On CUDA, over one level of instances of triangle GASes.
    pub fn hit_surface_batch(
        &self,
        rays: &[Ray],
        hits: &[Option<Hit>],
        out: &mut [Option<SurfaceHit>],
    ) -> Result<(), SurfaceQueryError> {
        on_ias!(
            self,
            i => i.hit_surface_batch(rays, hits, out),
            i.hit_surface_batch(rays, hits, out)
        )
    }

    /// [`hit_surface_batch`](Self::hit_surface_batch) with vertex normals.
    pub fn hit_surface_batch_shaded<N: ShadingNormals + Sync + ?Sized>(
        &self,
        rays: &[Ray],
        hits: &[Option<Hit>],
        normals: &N,
        out: &mut [Option<SurfaceHit>],
    ) -> Result<(), SurfaceQueryError> {
        on_ias!(
            self,
            i => i.hit_surface_batch_shaded(rays, hits, normals, out),
            i.hit_surface_batch_shaded(rays, hits, normals, out)
        )
    }
}

impl From<oxray_cpu::Ias> for Ias {
    fn from(i: oxray_cpu::Ias) -> Self {
        Ias(IasRepr::Cpu(Arc::new(i)))
    }
}

impl std::fmt::Debug for Ias {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Ias({})", on_ias!(self, i => i.describe(), i.describe()))
    }
}

impl Traversable for Ias {
    fn traversable_kind(&self) -> TraversableKind {
        TraversableKind::Ias
    }
    fn bounds(&self) -> Aabb {
        Ias::bounds(self)
    }
    fn graph_depth(&self) -> u32 {
        Ias::graph_depth(self)
    }
    fn backend(&self) -> BackendKind {
        self.device_kind()
    }
    fn describe(&self) -> String {
        format!("{self:?}")
    }
    /// A handle refers to the backend's structure, not to this wrapper.
    fn into_object(self: Arc<Self>) -> Arc<dyn Traversable> {
        match &self.0 {
            IasRepr::Cpu(i) => i.clone(),
            #[cfg(feature = "cuda")]
            IasRepr::Cuda(i) => i.clone(),
        }
    }
}
