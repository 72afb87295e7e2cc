//! Static and motion transforms on the device, and the children of instances and transforms as
//! pipelines traverse them: any traversable graph of CUDA GASes, IASes and transforms.

use crate::context::CudaContext;
use crate::error::{driver, CudaError};
use crate::gas::{CudaGas, DESCRIPTOR_MATRIX_MOTION, DESCRIPTOR_SRT_MOTION, DESCRIPTOR_STATIC};
use crate::ias::CudaIas;
use crate::layout::NodeLayout;
use cudarc::driver::{CudaSlice, DevicePtr};
use oxray_bvh::GasKind;
use oxray_core::{
    Aabb, BackendKind, BuildError, MatrixMotionTransform, SrtMotionTransform, StaticTransform,
    Traversable, TraversableHandle, TraversableKind,
};
use std::sync::{Arc, Mutex};

/// A traversable of this backend that an instance or a static transform refers to.
#[derive(Clone, Debug)]
pub(crate) enum CudaChild {
    Gas(Arc<CudaGas>),
    Ias(Arc<CudaIas>),
    Static(Arc<CudaStaticTransform>),
    Motion(Arc<CudaMotionTransform>),
}

impl CudaChild {
    /// Its `OptixTraversableHandle` (made on first use).
    pub(crate) fn optix_handle(&self) -> Result<u64, CudaError> {
        match self {
            CudaChild::Gas(g) => g.optix_handle(),
            CudaChild::Ias(i) => i.optix_handle(),
            CudaChild::Static(s) => s.optix_handle(),
            CudaChild::Motion(m) => m.optix_handle(),
        }
    }

    /// The child as a triangle GAS without motion, which the batched query kernels trace.
    pub(crate) fn triangle_gas(&self) -> Option<&Arc<CudaGas>> {
        match self {
            CudaChild::Gas(g) if g.kind() == GasKind::Triangles && g.motion.is_none() => Some(g),
            _ => None,
        }
    }
}

/// Resolves the child `handle` of instance `instance` (or of a static transform: `None`) into a
/// structure of `ctx`: a CUDA GAS (binary layout) or IAS, a CUDA static transform, or a static
/// transform of the core, which is uploaded here. The null handle is `None`.
pub(crate) fn resolve_child(
    ctx: &CudaContext,
    handle: &TraversableHandle,
    instance: Option<u32>,
) -> Result<Option<CudaChild>, BuildError> {
    let Some(backend) = handle.backend() else {
        return Ok(None);
    };
    let other_context = || {
        BuildError::Device(match instance {
            Some(i) => format!("instance {i}: its child lives in another CUDA context"),
            None => "a static transform's child lives in another CUDA context".into(),
        })
    };
    if let Some(gas) = handle.downcast_arc::<CudaGas>() {
        if !gas.context().same_context(ctx) {
            return Err(other_context());
        }
        if gas.layout() != NodeLayout::Bvh2 {
            return Err(BuildError::Unsupported(
                "instances of GASes in the BVH4 node layout on the CUDA backend",
            ));
        }
        return Ok(Some(CudaChild::Gas(gas)));
    }
    if let Some(ias) = handle.downcast_arc::<CudaIas>() {
        if !ias.context().same_context(ctx) {
            return Err(other_context());
        }
        return Ok(Some(CudaChild::Ias(ias)));
    }
    if let Some(st) = handle.downcast_arc::<CudaStaticTransform>() {
        if !st.context().same_context(ctx) {
            return Err(other_context());
        }
        return Ok(Some(CudaChild::Static(st)));
    }
    if let Some(m) = handle.downcast_arc::<CudaMotionTransform>() {
        if !m.context().same_context(ctx) {
            return Err(other_context());
        }
        return Ok(Some(CudaChild::Motion(m)));
    }
    if backend == BackendKind::Cuda || backend == BackendKind::Any {
        if let Some(st) = handle.downcast_ref::<StaticTransform>() {
            let st = CudaStaticTransform::new(ctx, st.clone())?;
            return Ok(Some(CudaChild::Static(Arc::new(st))));
        }
        if let Some(m) = handle.downcast_ref::<MatrixMotionTransform>() {
            let m = CudaMotionTransform::new(ctx, MotionTransform::Matrix(m.clone()))?;
            return Ok(Some(CudaChild::Motion(Arc::new(m))));
        }
        if let Some(m) = handle.downcast_ref::<SrtMotionTransform>() {
            let m = CudaMotionTransform::new(ctx, MotionTransform::Srt(m.clone()))?;
            return Ok(Some(CudaChild::Motion(Arc::new(m))));
        }
        return Err(BuildError::Unsupported(
            "this kind of traversable on the CUDA backend",
        ));
    }
    Err(BuildError::ForeignTraversable {
        instance: instance.unwrap_or(0),
        device: BackendKind::Cuda,
        found: backend,
    })
}

/// A static transform (`OptixStaticTransform`) over a structure of this device, for pipelines:
/// on the device, a descriptor followed by the guide's struct (the child's handle, padding,
/// the object-to-world transform and its inverse, 3x4 row-major), which
/// `optixGetStaticTransformFromHandle` returns. Instances whose child is a core
/// [`StaticTransform`] over CUDA structures get one made by [`CudaIas::upload`]; make one to
/// trace from a static transform at the root.
#[derive(Debug)]
#[doc(alias = "OptixStaticTransform")]
#[doc(alias = "optixGetStaticTransformFromHandle")]
pub struct CudaStaticTransform {
    ctx: CudaContext,
    transform: StaticTransform,
    child: Option<CudaChild>,
    /// The descriptor, made on first use ([`optix_handle`](Self::optix_handle)).
    view: Mutex<Option<(CudaSlice<u32>, u64)>>,
}

/// Words of a static transform on the device: the 16-word descriptor, then the child's handle
/// (2), padding (2) and the two matrices (24).
pub(crate) const STATIC_TRANSFORM_WORDS: usize = 16 + 28;

/// The device words of a static transform whose descriptor is at `address` (the struct follows
/// at `address + 64`) over the child `child`.
pub(crate) fn static_transform_words(
    t: &StaticTransform,
    address: u64,
    child: u64,
    depth: u32,
) -> [u32; STATIC_TRANSFORM_WORDS] {
    let mut w = [0u32; STATIC_TRANSFORM_WORDS];
    let d = crate::gas::descriptor_words(DESCRIPTOR_STATIC, depth, 1, address + 64, 0, 0, 0);
    w[..16].copy_from_slice(&d);
    w[16] = child as u32;
    w[17] = (child >> 32) as u32;
    for (k, f) in t.transform().0.iter().enumerate() {
        w[20 + k] = f.to_bits();
    }
    for (k, f) in t.inverse().0.iter().enumerate() {
        w[32 + k] = f.to_bits();
    }
    w
}

impl CudaStaticTransform {
    /// A static transform over a structure of `ctx` (a CUDA GAS, IAS or static transform, or a
    /// core static transform over those), or over nothing.
    pub fn new(ctx: &CudaContext, transform: StaticTransform) -> Result<Self, BuildError> {
        let child = resolve_child(ctx, transform.child(), None)?;
        Ok(CudaStaticTransform {
            ctx: ctx.clone(),
            transform,
            child,
            view: Mutex::new(None),
        })
    }

    /// The transform.
    pub fn transform(&self) -> &StaticTransform {
        &self.transform
    }

    /// The context it lives in.
    pub fn context(&self) -> &CudaContext {
        &self.ctx
    }

    /// The `OptixTraversableHandle` of this transform for programs of a
    /// [`CudaPipeline`](crate::CudaPipeline), made on first use and kept with it.
    #[doc(alias = "OptixTraversableHandle")]
    pub fn optix_handle(&self) -> Result<u64, CudaError> {
        let mut view = self.view.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, a)) = view.as_ref() {
            return Ok(*a);
        }
        let child = match &self.child {
            Some(c) => c.optix_handle()?,
            None => 0,
        };
        let stream = &self.ctx.stream;
        let mut words = stream
            .alloc_zeros::<u32>(STATIC_TRANSFORM_WORDS)
            .map_err(driver("allocating a static transform"))?;
        let address = {
            let (p, _g) = words.device_ptr(stream);
            p
        };
        let host = static_transform_words(&self.transform, address, child, self.graph_depth());
        stream
            .memcpy_htod(&host[..], &mut words)
            .map_err(driver("copying a static transform to the device"))?;
        self.ctx.synchronize()?;
        *view = Some((words, address));
        Ok(address)
    }
}

impl Traversable for CudaStaticTransform {
    fn traversable_kind(&self) -> TraversableKind {
        TraversableKind::StaticTransform
    }

    fn bounds(&self) -> Aabb {
        self.transform.bounds()
    }

    fn graph_depth(&self) -> u32 {
        self.transform.graph_depth()
    }

    fn backend(&self) -> BackendKind {
        BackendKind::Cuda
    }

    fn describe(&self) -> String {
        format!("CUDA {}", self.transform.describe())
    }
}

/// A motion transform of the core (guide §5.10.4, §5.10.5).
#[derive(Clone, Debug)]
pub enum MotionTransform {
    /// `OptixMatrixMotionTransform`.
    Matrix(MatrixMotionTransform),
    /// `OptixSRTMotionTransform`.
    Srt(SrtMotionTransform),
}

impl MotionTransform {
    fn child(&self) -> &TraversableHandle {
        match self {
            MotionTransform::Matrix(m) => m.child(),
            MotionTransform::Srt(m) => m.child(),
        }
    }

    fn traversable(&self) -> &dyn Traversable {
        match self {
            MotionTransform::Matrix(m) => m,
            MotionTransform::Srt(m) => m,
        }
    }
}

/// A motion transform over a structure of this device, for pipelines: on the device, a
/// descriptor followed by the guide's struct (`OptixMatrixMotionTransform` or
/// `OptixSRTMotionTransform`: the child's handle, the motion options, padding, every key), which
/// `optixGetMatrixMotionTransformFromHandle` and `optixGetSRTMotionTransformFromHandle` return.
/// Traversal interpolates its keys at each ray's time with the CPU backend's arithmetic.
/// Instances whose child is a core motion transform over CUDA structures get one made by
/// [`CudaIas::upload`]; make one to trace from a motion transform at the root.
#[derive(Debug)]
#[doc(alias = "OptixMatrixMotionTransform")]
#[doc(alias = "OptixSRTMotionTransform")]
#[doc(alias = "optixGetMatrixMotionTransformFromHandle")]
#[doc(alias = "optixGetSRTMotionTransformFromHandle")]
pub struct CudaMotionTransform {
    ctx: CudaContext,
    transform: MotionTransform,
    child: Option<CudaChild>,
    /// The descriptor, made on first use ([`optix_handle`](Self::optix_handle)).
    view: Mutex<Option<(CudaSlice<u32>, u64)>>,
}

/// The device words of a motion transform whose descriptor is at `address` (the guide's
/// struct follows at `address + 64`, its child handle patched in) over `child`.
pub(crate) fn motion_transform_words(
    t: &MotionTransform,
    address: u64,
    child: u64,
    depth: u32,
) -> Vec<u32> {
    let (kind, layout) = match t {
        MotionTransform::Matrix(m) => (DESCRIPTOR_MATRIX_MOTION, m.optix_layout()),
        MotionTransform::Srt(m) => (DESCRIPTOR_SRT_MOTION, m.optix_layout()),
    };
    let mut w = crate::gas::descriptor_words(kind, depth, 1, address + 64, 0, 0, 0).to_vec();
    let start = w.len();
    w.extend(
        layout
            .chunks_exact(4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
    );
    w[start] = child as u32;
    w[start + 1] = (child >> 32) as u32;
    w
}

impl CudaMotionTransform {
    /// A motion transform over a structure of `ctx` (a CUDA GAS, IAS or transform, or a core
    /// transform over those), or over nothing.
    pub fn new(ctx: &CudaContext, transform: MotionTransform) -> Result<Self, BuildError> {
        let child = resolve_child(ctx, transform.child(), None)?;
        Ok(CudaMotionTransform {
            ctx: ctx.clone(),
            transform,
            child,
            view: Mutex::new(None),
        })
    }

    /// The transform.
    pub fn transform(&self) -> &MotionTransform {
        &self.transform
    }

    /// The context it lives in.
    pub fn context(&self) -> &CudaContext {
        &self.ctx
    }

    /// The `OptixTraversableHandle` of this transform for programs of a
    /// [`CudaPipeline`](crate::CudaPipeline), made on first use and kept with it.
    #[doc(alias = "OptixTraversableHandle")]
    pub fn optix_handle(&self) -> Result<u64, CudaError> {
        let mut view = self.view.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, a)) = view.as_ref() {
            return Ok(*a);
        }
        let child = match &self.child {
            Some(c) => c.optix_handle()?,
            None => 0,
        };
        let stream = &self.ctx.stream;
        let len = motion_transform_words(&self.transform, 0, 0, 0).len();
        let mut words = stream
            .alloc_zeros::<u32>(len)
            .map_err(driver("allocating a motion transform"))?;
        let address = {
            let (p, _g) = words.device_ptr(stream);
            p
        };
        let host = motion_transform_words(&self.transform, address, child, self.graph_depth());
        stream
            .memcpy_htod(&host[..], &mut words)
            .map_err(driver("copying a motion transform to the device"))?;
        self.ctx.synchronize()?;
        *view = Some((words, address));
        Ok(address)
    }
}

impl Traversable for CudaMotionTransform {
    fn traversable_kind(&self) -> TraversableKind {
        self.transform.traversable().traversable_kind()
    }

    fn bounds(&self) -> Aabb {
        self.transform.traversable().bounds()
    }

    fn graph_depth(&self) -> u32 {
        self.transform.traversable().graph_depth()
    }

    fn backend(&self) -> BackendKind {
        BackendKind::Cuda
    }

    fn describe(&self) -> String {
        format!("CUDA {}", self.transform.traversable().describe())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gas::{custom_words, descriptor_words, DESCRIPTOR_GAS, DESCRIPTOR_INSTANCE};
    use crate::ias::{instance_record, INSTANCE_RECORD_WORDS};
    use crate::program::DEVICE_HEADER;
    use glam::Vec3;
    use oxray_core::Transform;

    /// The offset of `field` in the device struct `name` as the header declares it is what the
    /// host writes: checked by the field order in the header's text.
    fn header_declares(text: &str) {
        assert!(
            DEVICE_HEADER.contains(text) || oxray_core::source::OPTIX_TYPES_HEADER.contains(text),
            "the headers declare {text}"
        );
    }

    #[test]
    fn descriptors_are_sixteen_words_with_the_depth_in_word_ten() {
        let w = descriptor_words(
            DESCRIPTOR_GAS,
            3,
            7,
            0x1_0000_0010,
            0x20,
            0x30,
            0x2_0000_0040,
        );
        assert_eq!(w.len() * 4, 64);
        assert_eq!((w[0], w[1]), (1, 7));
        assert_eq!((w[2], w[3]), (0x10, 1), "nodes at byte 8");
        assert_eq!((w[4], w[6], w[8], w[9]), (0x20, 0x30, 0x40, 2));
        assert_eq!(w[10], 3, "depth at byte 40");
        header_declares(
            "    unsigned long long geom_flags; // GAS: one u32 per SBT-GAS index\n    u32 depth;",
        );
    }

    #[test]
    fn static_transforms_follow_the_guides_layout() {
        let t = Transform([2.0, 0.0, 0.0, 1.0, 0.0, 4.0, 0.0, 2.0, 0.0, 0.0, 1.0, 3.0]);
        let st = StaticTransform::new(TraversableHandle::NULL, t).unwrap();
        let w = static_transform_words(&st, 0x7000, 0x1_2345_6780, 2);
        assert_eq!(w.len() * 4, 64 + 112);
        assert_eq!((w[0], w[10]), (DESCRIPTOR_STATIC, 2));
        assert_eq!(
            (w[2], w[3]),
            (0x7040, 0),
            "the struct follows the descriptor"
        );
        // OptixStaticTransform: child (8 bytes), pad[2], transform[12], invTransform[12].
        assert_eq!((w[16], w[17], w[18], w[19]), (0x2345_6780, 1, 0, 0));
        assert_eq!(f32::from_bits(w[20 + 3]), 1.0);
        assert_eq!(f32::from_bits(w[32]), 0.5, "the inverse");
        assert_eq!(f32::from_bits(w[32 + 7]), -0.5);
        header_declares(
            "struct OptixStaticTransform {\n    OptixTraversableHandle child;\n    unsigned int pad[2];\n    float transform[12];\n    float invTransform[12];\n};",
        );
    }

    #[test]
    fn instance_records_are_128_bytes() {
        let t = Transform::from_translation(Vec3::new(1.0, 2.0, 3.0));
        let inst = oxray_bvh::InstanceData {
            object_to_world: t,
            world_to_object: t.inverse().unwrap(),
            instance_id: 5,
            sbt_offset: 6,
            mask: 0x0F,
            flags: oxray_core::InstanceFlags::empty(),
            child: TraversableHandle::NULL,
            index: 0,
        };
        let r = instance_record(&inst, 0xAB_0000_0001);
        assert_eq!(INSTANCE_RECORD_WORDS * 4, 128);
        assert_eq!(&r[..8], &[DESCRIPTOR_INSTANCE, 5, 6, 0, 0x0F, 0, 1, 0xAB]);
        // Rows of the object-to-world transform from byte 32, the inverse from byte 80.
        assert_eq!(f32::from_bits(r[8 + 3]), 1.0);
        assert_eq!(f32::from_bits(r[20 + 11]), -3.0);
        header_declares("    unsigned long long child;  // the child's handle; 0 for none\n    float4 object_to_world[3];\n    float4 world_to_object[3];");
    }

    #[test]
    fn custom_primitive_boxes_and_slots_are_uploaded_in_leaf_order() {
        let boxes = [
            oxray_core::Aabb::new(Vec3::ZERO, Vec3::ONE),
            oxray_core::Aabb::new(Vec3::splat(5.0), Vec3::splat(6.0)),
            // Inverted: inactive, never hit.
            oxray_core::Aabb::new(Vec3::ONE, Vec3::ZERO),
        ];
        let a = oxray_core::CustomPrimitiveInput::new(oxray_core::AabbBuffer::new(&boxes[..1]));
        let b = oxray_core::CustomPrimitiveInput::new(oxray_core::AabbBuffer::new(&boxes[1..]))
            .primitive_index_offset(20);
        let (gas, tree) = oxray_bvh::GasData::build_with_tree(
            &oxray_core::BuildOptions::default(),
            &[a.into(), b.into()],
        )
        .unwrap();
        let (words, slots) = custom_words(&gas);
        assert_eq!(words.len(), 8 * gas.aabbs.len());
        assert_eq!(slots.len(), gas.aabbs.len());
        let mut seen = Vec::new();
        for (s, info) in slots.iter().enumerate() {
            let lo = f32::from_bits(words[8 * s]);
            let hi = f32::from_bits(words[8 * s + 4]);
            match info.primitive_index {
                0 => assert_eq!((lo, hi, info.sbt_gas_index), (0.0, 1.0, 0)),
                20 => assert_eq!((lo, hi, info.sbt_gas_index), (5.0, 6.0, 1)),
                u32::MAX => {}
                p => panic!("primitive {p}"),
            }
            seen.push(info.primitive_index);
        }
        seen.sort();
        assert_eq!(&seen[..2], &[0, 20]);
        // The tree's leaves are these slots.
        let nodes = crate::layout::bvh2_words(&tree).unwrap();
        assert_eq!(nodes.len() % 16, 0);
    }

    #[test]
    fn motion_tables_hold_every_later_key_in_the_key_0_layout() {
        // Guide §5.10.2: a triangle GAS of three keys, each moving the triangles along x.
        let v0: Vec<[f32; 3]> = (0..30)
            .map(|i| {
                [
                    (i % 3) as f32 + (i / 3) as f32,
                    (i % 2) as f32,
                    (i / 3) as f32 * 0.1,
                ]
            })
            .collect();
        let keys: Vec<Vec<[f32; 3]>> = (1..3)
            .map(|k| v0.iter().map(|p| [p[0] + k as f32, p[1], p[2]]).collect())
            .collect();
        let later: Vec<oxray_core::VertexBuffer<'_>> = keys
            .iter()
            .map(|k| oxray_core::VertexBuffer::f32x3(k))
            .collect();
        let input = oxray_core::TriangleInput::new(oxray_core::VertexBuffer::f32x3(&v0))
            .motion_vertices(&later);
        let m = oxray_core::MotionOptions::new(3, 0.0, 2.0);
        let options = oxray_core::BuildOptions::default().with_motion(m);
        let (gas, tree) = oxray_bvh::GasData::build_with_tree(&options, &[input.into()]).unwrap();
        // The binary tree names the structure's slots, as for a static GAS.
        let export = gas.export_triangles().unwrap();
        let dl = crate::layout::DeviceLayout::new(&export, &tree, NodeLayout::Bvh2).unwrap();
        let slots = dl.slots.len();
        let words = crate::gas::motion_words(&gas).unwrap();
        assert_eq!(&words[..5], &[3, 0, 0, 2.0f32.to_bits(), 3 * slots as u32]);
        assert_eq!(words.len(), 8 + 2 * 12 * slots);
        for (s, info) in dl.slots.iter().enumerate() {
            if info.primitive_index == u32::MAX {
                continue;
            }
            assert_eq!(
                &dl.triangles[12 * s..12 * s + 12],
                &gas.triangle_at(s, 0.0)
                    .unwrap()
                    .map(|p| [p[0], p[1], p[2], 0.0])
                    .concat()[..]
            );
            for k in 1..3 {
                let at = 8 + (k - 1) * 12 * slots + 12 * s;
                let got: Vec<f32> = words[at..at + 12]
                    .iter()
                    .map(|&w| f32::from_bits(w))
                    .collect();
                let want = gas.triangle_at(s, k as f32).unwrap();
                let t = 3 * info.primitive_index as usize;
                assert_eq!(want[0][0], keys[k - 1][t][0], "key {k} of the input");
                assert_eq!(
                    got,
                    want.map(|p| [p[0], p[1], p[2], 0.0]).concat(),
                    "key {k}"
                );
            }
        }
    }

    #[test]
    fn uploaded_triangles_keep_the_inputs_vertex_order() {
        // optixGetTriangleVertexData returns the uploaded vertices: they must be the input's
        // v0, v1, v2 (the barycentrics weigh them in that order).
        let v = [
            [-1.0f32, -1.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 1.0, 0.0],
            [-1.0, 1.0, 0.0],
        ];
        let idx = [[0u32, 1, 2], [0, 2, 3]];
        let input = oxray_core::TriangleInput::new(oxray_core::VertexBuffer::f32x3(&v))
            .indices(oxray_core::IndexBuffer::u32x3(&idx));
        let (gas, tree) = oxray_bvh::GasData::build_with_tree(
            &oxray_core::BuildOptions::default(),
            &[input.into()],
        )
        .unwrap();
        let export = gas.export_triangles().unwrap();
        let dl = crate::layout::DeviceLayout::new(&export, &tree, NodeLayout::Bvh2).unwrap();
        for (s, info) in dl.slots.iter().enumerate() {
            if info.primitive_index == u32::MAX {
                continue;
            }
            let t = idx[info.primitive_index as usize];
            for k in 0..3 {
                let got = &dl.triangles[12 * s + 4 * k..12 * s + 4 * k + 3];
                assert_eq!(got, &v[t[k] as usize][..], "slot {s}, vertex {k}");
            }
        }
    }
}
