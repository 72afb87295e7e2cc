//! The path tracer as CUDA C++ programs ([`SOURCE`], `device_programs.cu`), on any
//! [`Device`]: the same algorithm as the Rust programs of [`render`](crate::render), written once
//! against the guide's device functions, compiled by the host's C++ compiler on the CPU and by
//! NVRTC on a GPU.
//!
//! [`render_on`] prepares the scene as [`render`](crate::render) does (camera, emissive
//! triangles, the environment's sampling tables), builds it on the device (one GAS per mesh
//! with one build input per primitive, one IAS instance per placement, or the GAS alone for a
//! single untransformed placement), uploads what the programs read (vertex attributes,
//! materials, textures, lights, the environment, per-instance matrices) and launches one pass
//! per sample. The hit-group SBT holds, per primitive and ray type (radiance, shadow), the
//! device addresses of its vertex attributes and its material.
//!
//! The two versions are kept under one test (`tests/device_programs.rs`) that compares their
//! images statistically.

use crate::crop::CropWindow;
use crate::lights::Environment;
use crate::motion::Shutter;
use crate::programs::CameraFrame;
use crate::{prepare_lighting, traced, Image, RenderError, RenderOptions};
use bytemuck::{Pod, Zeroable};
use oxray::programs::{Buffer, HitGroupDesc, Pipeline, ProgramGroup};
use oxray::{
    BackendKind, BuildFlags, BuildInput, BuildOptions, Device, Gas, GeometryFlags, Ias,
    IndexBuffer, Instance, ModuleSource, PipelineCompileOptions, PipelineLinkOptions, SbtRegion,
    ShaderBindingTable, SrtMotionTransform, Transform, TriangleInput, VertexBuffer,
};
use oxray_scene::{AlphaMode, LightKind, MaterialDesc, MeshDesc, SceneDesc, TextureRef, Wrap};
use std::borrow::Cow;
use std::ops::ControlFlow;

/// The CUDA C++ source of the path tracer's programs.
pub const SOURCE: &str = include_str!("device_programs.cu");

/// The ray-generation program.
pub const RAYGEN: &str = "__raygen__camera";
/// The miss programs, by miss index: radiance rays, shadow rays.
pub const MISS: [&str; 2] = ["__miss__environment", "__miss__shadow"];
/// The closest-hit program of radiance rays.
pub const CLOSEST_HIT: &str = "__closesthit__radiance";
/// The closest-hit program of shadow rays (never called: shadow rays disable it).
pub const CLOSEST_HIT_SHADOW: &str = "__closesthit__shadow";
/// The any-hit program of alpha-tested materials (both ray types).
pub const ANY_HIT: &str = "__anyhit__alpha";

/// Payload words of a radiance ray.
const WORDS: u32 = 16;

/// The pipeline compile options the programs need (16 payload words).
#[must_use]
pub fn compile_options() -> PipelineCompileOptions {
    PipelineCompileOptions {
        num_payload_values: WORDS,
        num_attribute_values: 2,
        // Rays take the shutter's times when something moves (time 0 otherwise).
        uses_motion_blur: true,
        ..Default::default()
    }
}

/// How deep the programs' traversable graphs go: an IAS, an instance's SRT motion transform
/// (an instance that moves while the shutter is open) and a GAS.
pub const MAX_GRAPH_DEPTH: u32 = 3;

/// The pipeline link options the programs need (closest-hit programs trace shadow rays).
#[must_use]
pub fn link_options() -> PipelineLinkOptions {
    PipelineLinkOptions { max_trace_depth: 2 }
}

/// Compiles the programs for a GPU of compute capability `cc` to PTX with NVRTC (no GPU
/// needed: only libnvrtc), so that a program that does not compile for the GPU is caught
/// anywhere. Returns the PTX.
///
/// ```no_run
/// let ptx = oxray_render::device::compile_for_gpu((9, 0))?;
/// assert!(ptx.contains(".entry"));
/// # Ok::<(), oxray::ProgramError>(())
/// ```
pub fn compile_for_gpu(cc: (i32, i32)) -> Result<String, oxray::ProgramError> {
    use oxray::cuda::{CudaHitGroupDesc, CudaModule, CudaProgramGroup};
    let m = CudaModule::from_source(SOURCE);
    let hit = |ch: &'static str, ah: bool| {
        CudaProgramGroup::hit_group(CudaHitGroupDesc {
            closest_hit: Some((&m, ch)),
            any_hit: ah.then_some((&m, ANY_HIT)),
            intersection: None,
        })
    };
    let groups = vec![
        CudaProgramGroup::raygen(&m, RAYGEN)?,
        CudaProgramGroup::miss(Some((&m, MISS[0])))?,
        CudaProgramGroup::miss(Some((&m, MISS[1])))?,
        hit(CLOSEST_HIT, false)?,
        hit(CLOSEST_HIT, true)?,
        hit(CLOSEST_HIT_SHADOW, false)?,
        hit(CLOSEST_HIT_SHADOW, true)?,
    ];
    Ok(oxray::cuda::compile_pipeline_ptx(
        cc,
        &compile_options(),
        &link_options(),
        &groups,
    )?)
}

// The layouts of device_programs.cu, field for field.

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct TexRefGpu {
    texture: i32,
    tex_coord: u32,
    m: [f32; 6],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct MaterialGpu {
    base_color: [f32; 4],
    emissive: [f32; 3],
    metallic: f32,
    roughness: f32,
    normal_scale: f32,
    transmission: f32,
    ior: f32,
    alpha_mode: u32,
    alpha_cutoff: f32,
    double_sided: u32,
    specular: f32,
    base_color_tex: TexRefGpu,
    metallic_roughness_tex: TexRefGpu,
    emissive_tex: TexRefGpu,
    normal_tex: TexRefGpu,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct TextureGpu {
    offset: u32,
    width: u32,
    height: u32,
    wrap_u: u32,
    wrap_v: u32,
    pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct LightTriGpu {
    p0: [f32; 3],
    e1: [f32; 3],
    e2: [f32; 3],
    normal: [f32; 3],
    uv: [f32; 6],
    material: u32,
    two_sided: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PunctualGpu {
    kind: u32,
    position: [f32; 3],
    direction: [f32; 3],
    intensity: [f32; 3],
    range: f32,
    cos_inner: f32,
    cos_outer: f32,
    pad: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct InstanceXformGpu {
    o2w: [f32; 12],
    w2o: [f32; 12],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct HitDataGpu {
    positions: u64,
    normals: u64,
    uvs0: u64,
    uvs1: u64,
    colors: u64,
    triangles: u64,
    material: u32,
    num_triangles: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ParamsGpu {
    accum: u64,
    handle: u64,
    materials: u64,
    textures: u64,
    texels: u64,
    srgb: u64,
    instances: u64,
    lights: u64,
    light_cdf: u64,
    light_area_pdf: u64,
    punctual: u64,
    env_texels: u64,
    env_conditional: u64,
    env_marginal: u64,
    ggx_albedo: u64,
    filter: u64,
    aov: u64,
    num_materials: u32,
    num_textures: u32,
    num_lights: u32,
    num_punctual: u32,
    num_instances: u32,
    env_width: u32,
    env_height: u32,
    env_total: f32,
    p_env: f32,
    cam_origin: [f32; 3],
    cam_forward: [f32; 3],
    cam_right: [f32; 3],
    cam_up: [f32; 3],
    sample: u32,
    max_depth: u32,
    eps: f32,
    filter_len: u32,
    roulette_depth: u32,
    seed: u32,
    /// The full image's pixel of launch index (0, 0): the crop window's first column and row.
    crop_x0: u32,
    crop_y0: u32,
    /// The full image's size (the camera's and the random streams'; the launch is the window).
    image_width: u32,
    image_height: u32,
    /// Where the random numbers come from ([`crate::Sampler::code`]).
    sampler: u32,
    /// Motion blur: whether camera rays take times in the shutter, and its interval.
    shutter_on: u32,
    shutter_open: f32,
    shutter_close: f32,
    /// A camera the animation moves: its frames over the shutter (12 floats each: origin,
    /// forward, right, up; [`CameraFrame::at`]), and how many (0: the still camera above).
    num_cam_keys: u32,
    cam_keys: u64,
}

const _: () = assert!(std::mem::size_of::<MaterialGpu>() == 192);
const _: () = assert!(std::mem::size_of::<HitDataGpu>() == 56);
const _: () = assert!(std::mem::size_of::<ParamsGpu>() == 288);
const _: () = assert!(std::mem::offset_of!(ParamsGpu, crop_x0) == 244);

fn tex_ref(r: Option<TextureRef>) -> TexRefGpu {
    match r {
        Some(r) => TexRefGpu {
            texture: i32::try_from(r.texture).unwrap_or(-1),
            tex_coord: r.tex_coord,
            m: r.uv_transform,
        },
        None => TexRefGpu {
            texture: -1,
            tex_coord: 0,
            m: TextureRef::IDENTITY,
        },
    }
}

fn material(m: &MaterialDesc) -> MaterialGpu {
    let (alpha_mode, alpha_cutoff) = match m.alpha_mode {
        AlphaMode::Opaque => (0, 0.0),
        AlphaMode::Mask { cutoff } => (1, cutoff),
        AlphaMode::Blend => (2, 0.0),
    };
    MaterialGpu {
        base_color: m.base_color,
        emissive: m.emissive,
        metallic: m.metallic,
        roughness: m.roughness,
        normal_scale: m.normal_scale,
        transmission: m.transmission,
        ior: m.ior,
        alpha_mode,
        alpha_cutoff,
        double_sided: m.double_sided as u32,
        specular: m.specular,
        base_color_tex: tex_ref(m.base_color_texture),
        metallic_roughness_tex: tex_ref(m.metallic_roughness_texture),
        emissive_tex: tex_ref(m.emissive_texture),
        normal_tex: tex_ref(m.normal_texture),
    }
}

fn wrap(w: Wrap) -> u32 {
    match w {
        Wrap::Repeat => 0,
        Wrap::MirroredRepeat => 1,
        Wrap::ClampToEdge => 2,
    }
}

/// Device memory for `data` (nothing for an empty slice: its address is 0).
pub(crate) struct Uploads {
    device: Device,
    // Kept alive for the programs that read them through their addresses.
    f32s: Vec<Buffer<f32>>,
    bytes: Vec<Buffer<u8>>,
}

impl Uploads {
    fn new(device: &Device) -> Self {
        Uploads {
            device: device.clone(),
            f32s: Vec::new(),
            bytes: Vec::new(),
        }
    }

    fn put<T: Pod>(&mut self, data: &[T]) -> Result<u64, RenderError> {
        if data.is_empty() {
            return Ok(0);
        }
        // Values of 4-byte aligned types (whole words) are stored as f32 words; the rest
        // (texels) as bytes.
        if std::mem::align_of::<T>() >= 4 {
            let words: &[f32] = bytemuck::cast_slice(data);
            let b = self.device.buffer_from_slice(words)?;
            let p = b.device_ptr();
            self.f32s.push(b);
            Ok(p)
        } else {
            let b = self
                .device
                .buffer_from_slice(bytemuck::cast_slice::<T, u8>(data))?;
            let p = b.device_ptr();
            self.bytes.push(b);
            Ok(p)
        }
    }
}

/// The name of the renderer on `device`, for errors.
fn renderer(device: &Device) -> String {
    match device.kind() {
        BackendKind::Cuda => "the CUDA C++ path tracer on CUDA".into(),
        _ => "the CUDA C++ path tracer on the CPU".into(),
    }
}

/// Refuses what the device programs cannot render yet, naming it (today: texture data beyond
/// 32-bit texel offsets).
pub(crate) fn check_supported(device: &Device, scene: &SceneDesc) -> Result<(), RenderError> {
    let texels: u64 = scene.textures.iter().map(|t| t.texels.len() as u64).sum();
    if texels > u32::MAX as u64 {
        return Err(RenderError::Unsupported {
            renderer: renderer(device),
            feature: format!("textures of {texels} texels in all (at most 2^32)"),
        });
    }
    Ok(())
}

/// Renders `scene` with the environment `env` on `device` with the path tracer's CUDA C++
/// programs ([`SOURCE`]): the same algorithm, options and result as
/// [`render`](crate::render), one launch per sample (`progress` is called after each with the
/// number of samples done). On the CPU device the programs are compiled by the host's C++
/// compiler (cached on disk), on a CUDA device by NVRTC. To render a scene more than once,
/// progressively, with edits or AOVs, use a [`Renderer`](crate::Renderer).
///
/// ```
/// use glam::Vec3;
/// use oxray_render::device::render_on;
/// use oxray_render::lights::Environment;
/// use oxray_render::RenderOptions;
///
/// let device = oxray::Device::cpu(); // or Device::cuda(0)?
/// let scene = oxray_scene::cornell_box();
/// let opts = RenderOptions { width: 8, height: 8, spp: 2, max_depth: 4, ..Default::default() };
/// let image = render_on(&device, &scene, &Environment::uniform(Vec3::ZERO), &opts, |_| {})?;
/// assert_eq!(image.pixels.len(), 64);
/// assert!(image.pixels.iter().any(|p| p[0] + p[1] + p[2] > 0.0));
/// # Ok::<(), oxray_render::RenderError>(())
/// ```
pub fn render_on(
    device: &Device,
    scene: &SceneDesc,
    env: &Environment,
    opts: &RenderOptions,
    progress: impl FnMut(u32),
) -> Result<Image, RenderError> {
    render_with_source(device, SOURCE, scene, env, opts, progress)
}

/// [`render_on`] with other programs in place of [`SOURCE`] (same entry points and layouts):
/// for the tests that check that the comparison of the two renderers catches a changed
/// algorithm.
#[doc(hidden)]
pub fn render_with_source(
    device: &Device,
    source: &str,
    scene: &SceneDesc,
    env: &Environment,
    opts: &RenderOptions,
    mut progress: impl FnMut(u32),
) -> Result<Image, RenderError> {
    let mut renderer =
        crate::Renderer::with_source(device, source, Cow::Borrowed(scene), Cow::Borrowed(env))?;
    let done = renderer.render(opts, |p| {
        progress(p.samples());
        ControlFlow::Continue(())
    })?;
    Ok(done.image)
}

/// The program groups of the pipeline.
struct Groups {
    raygen: ProgramGroup,
    miss_env: ProgramGroup,
    miss_shadow: ProgramGroup,
    radiance_opaque: ProgramGroup,
    radiance_alpha: ProgramGroup,
    shadow_opaque: ProgramGroup,
    shadow_alpha: ProgramGroup,
}

/// One mesh's GAS (one build input per traced primitive) and its primitives' hit data.
struct MeshGas {
    gas: Gas,
    /// Per traced primitive: whether its material was opaque when the GAS was built (opaque
    /// inputs are built with `DISABLE_ANYHIT`).
    opaque: Vec<bool>,
    hit: Vec<HitDataGpu>,
}

/// What a render's edits do not change: the compiled pipeline, the GASes, the vertex
/// attributes, the textures and the constant tables on the device.
pub(crate) struct SceneGeometry {
    pipeline: Pipeline,
    groups: Groups,
    /// Per scene mesh; `None` for a mesh without triangles.
    meshes: Vec<Option<MeshGas>>,
    textures: u64,
    num_textures: u32,
    texels: u64,
    /// The texture table and texels, uploaded again when a texture changes.
    texture_up: Uploads,
    srgb: u64,
    ggx_albedo: u64,
    _up: Uploads,
}

/// The texture table and the texels of `scene` on `device`: the uploads that hold them, the
/// table's address, the number of textures and the texels' address.
fn upload_textures(
    device: &Device,
    scene: &SceneDesc,
) -> Result<(Uploads, u64, u32, u64), RenderError> {
    let mut up = Uploads::new(device);
    let mut texels: Vec<[u8; 4]> = Vec::new();
    let mut textures = Vec::with_capacity(scene.textures.len());
    for t in &scene.textures {
        textures.push(TextureGpu {
            offset: texels.len() as u32,
            width: t.width,
            height: t.height,
            wrap_u: wrap(t.wrap_u),
            wrap_v: wrap(t.wrap_v),
            pad: [0; 3],
        });
        texels.extend_from_slice(&t.texels);
    }
    let table = up.put(&textures)?;
    let texels = up.put(&texels)?;
    Ok((up, table, textures.len() as u32, texels))
}

/// Whether material `m` of `scene` is opaque (no any-hit program).
fn is_opaque(scene: &SceneDesc, m: u32) -> bool {
    scene
        .materials
        .get(m as usize)
        .is_none_or(|m| m.alpha_mode == AlphaMode::Opaque)
}

/// Builds the GAS of `mesh`: one build input per traced primitive, opaque ones without any-hit.
fn build_mesh_gas(
    device: &Device,
    scene: &SceneDesc,
    mesh: &MeshDesc,
) -> Result<(Gas, Vec<bool>), RenderError> {
    let prims: Vec<_> = mesh.primitives.iter().filter(|p| traced(p)).collect();
    let opaque: Vec<bool> = prims.iter().map(|p| is_opaque(scene, p.material)).collect();
    let flags: Vec<[GeometryFlags; 1]> = opaque
        .iter()
        .map(|&o| {
            [if o {
                GeometryFlags::DISABLE_ANYHIT
            } else {
                GeometryFlags::REQUIRE_SINGLE_ANYHIT_CALL
            }]
        })
        .collect();
    let inputs: Vec<BuildInput> = prims
        .iter()
        .zip(&flags)
        .map(|(p, f)| {
            TriangleInput::new(VertexBuffer::f32x3(&p.positions))
                .indices(IndexBuffer::u32x3(&p.triangles))
                .flags(f)
                .into()
        })
        .collect();
    let gas = device.build_gas(&BuildOptions::new(BuildFlags::PREFER_FAST_TRACE), &inputs)?;
    Ok((gas, opaque))
}

impl SceneGeometry {
    /// Compiles the programs of `source`, builds one GAS per mesh and uploads the vertex
    /// attributes, the textures and the constant tables.
    pub(crate) fn build(
        device: &Device,
        source: &str,
        scene: &SceneDesc,
    ) -> Result<Self, RenderError> {
        check_supported(device, scene)?;
        let module = device.create_module(ModuleSource::CudaCpp(source))?;
        let hit = |ch: &'static str, ah: bool| {
            ProgramGroup::hit_group(HitGroupDesc {
                closest_hit: Some((&module, ch)),
                any_hit: ah.then_some((&module, ANY_HIT)),
                intersection: None,
            })
        };
        let groups = Groups {
            raygen: ProgramGroup::raygen(&module, RAYGEN)?,
            miss_env: ProgramGroup::miss(&module, MISS[0])?,
            miss_shadow: ProgramGroup::miss(&module, MISS[1])?,
            radiance_opaque: hit(CLOSEST_HIT, false)?,
            radiance_alpha: hit(CLOSEST_HIT, true)?,
            shadow_opaque: hit(CLOSEST_HIT_SHADOW, false)?,
            shadow_alpha: hit(CLOSEST_HIT_SHADOW, true)?,
        };
        let mut pipeline = device.create_pipeline(
            &compile_options(),
            &link_options(),
            Some("params"),
            &[
                groups.raygen.clone(),
                groups.miss_env.clone(),
                groups.miss_shadow.clone(),
                groups.radiance_opaque.clone(),
                groups.radiance_alpha.clone(),
                groups.shadow_opaque.clone(),
                groups.shadow_alpha.clone(),
            ],
        )?;
        pipeline.set_max_traversable_graph_depth(MAX_GRAPH_DEPTH)?;

        let mut up = Uploads::new(device);
        let mut meshes = Vec::with_capacity(scene.meshes.len());
        for mesh in &scene.meshes {
            if !mesh.primitives.iter().any(traced) {
                meshes.push(None);
                continue;
            }
            let (gas, opaque) = build_mesh_gas(device, scene, mesh)?;
            let mut hit = Vec::new();
            for p in mesh.primitives.iter().filter(|p| traced(p)) {
                hit.push(HitDataGpu {
                    positions: up.put(&p.positions)?,
                    normals: up.put(&p.normals)?,
                    uvs0: up.put(&p.uvs)?,
                    uvs1: up.put(&p.uvs1)?,
                    colors: up.put(&p.colors)?,
                    triangles: up.put(&p.triangles)?,
                    material: p.material,
                    num_triangles: p.triangles.len() as u32,
                });
            }
            meshes.push(Some(MeshGas { gas, opaque, hit }));
        }

        let (texture_up, textures, num_textures, texels) = upload_textures(device, scene)?;
        Ok(SceneGeometry {
            pipeline,
            groups,
            meshes,
            textures,
            num_textures,
            texels,
            texture_up,
            srgb: up.put(&crate::texture::srgb_table()[..])?,
            ggx_albedo: up.put(&crate::albedo::GgxAlbedo::get().cells)?,
            _up: up,
        })
    }

    /// Uploads the scene's textures again (one of them changed); the tables that point at them
    /// must be made again.
    pub(crate) fn reupload_textures(
        &mut self,
        device: &Device,
        scene: &SceneDesc,
    ) -> Result<(), RenderError> {
        let (up, textures, num_textures, texels) = upload_textures(device, scene)?;
        (self.texture_up, self.textures) = (up, textures);
        (self.num_textures, self.texels) = (num_textures, texels);
        Ok(())
    }

    /// Rebuilds the GAS of every mesh with a primitive of `material` (its alpha mode changed
    /// between opaque and not); the hit data stays.
    pub(crate) fn rebuild_meshes_of_material(
        &mut self,
        device: &Device,
        scene: &SceneDesc,
        material: u32,
    ) -> Result<(), RenderError> {
        for (mesh, built) in scene.meshes.iter().zip(&mut self.meshes) {
            let Some(built) = built else { continue };
            if built.hit.iter().any(|h| h.material == material) {
                let (gas, opaque) = build_mesh_gas(device, scene, mesh)?;
                built.gas = gas;
                built.opaque = opaque;
            }
        }
        Ok(())
    }
}

/// What edits change: the root (the IAS, or a single GAS), the SBT, the materials, the lights
/// and the environment, with the launch parameters that point at them.
pub(crate) struct GpuScene {
    /// The root's IAS, kept alive for the launches (the handle in `params` refers to it).
    _ias: Option<Ias>,
    sbt: ShaderBindingTable,
    params: ParamsGpu,
    _up: Uploads,
}

impl GpuScene {
    /// The tables of `scene` lit by `env`, over the structures of `geometry`, with its
    /// instances posed over `shutter` by the scene's animation of that index (`None`: at rest).
    pub(crate) fn build(
        device: &Device,
        scene: &SceneDesc,
        env: &Environment,
        geometry: &SceneGeometry,
        shutter: Option<(Shutter, usize)>,
    ) -> Result<Self, RenderError> {
        let lit = prepare_lighting(scene, env, shutter)?;
        let mut up = Uploads::new(device);
        let g = &geometry.groups;

        // The hit-group SBT: two records (radiance, shadow) per traced primitive, mesh by mesh.
        let mut records = Vec::new();
        let mut sbt_offset = Vec::with_capacity(geometry.meshes.len());
        for built in &geometry.meshes {
            sbt_offset.push(records.len() as u32);
            let Some(built) = built else { continue };
            for (data, &opaque) in built.hit.iter().zip(&built.opaque) {
                let (radiance, shadow) = if opaque {
                    (&g.radiance_opaque, &g.shadow_opaque)
                } else {
                    (&g.radiance_alpha, &g.shadow_alpha)
                };
                records.push((radiance.pack_header(), *data));
                records.push((shadow.pack_header(), *data));
            }
        }

        // The root: the GAS of a single untransformed placement, else one level of instances.
        let mut xforms = Vec::new();
        let mut ias = None;
        let handle = if lit.single {
            xforms.push(InstanceXformGpu {
                o2w: Transform::IDENTITY.0,
                w2o: Transform::IDENTITY.0,
            });
            let built = geometry.meshes[lit.placements[0].mesh]
                .as_ref()
                .ok_or_else(|| RenderError::Scene("the scene could not be built".into()))?;
            built.gas.optix_handle()?
        } else {
            let mut instances = Vec::with_capacity(lit.placements.len());
            for p in &lit.placements {
                let Some(built) = &geometry.meshes[p.mesh] else {
                    continue;
                };
                if let Some((options, keys)) = &p.motion {
                    // A moving instance: its SRT keys over the shutter place the mesh, and its
                    // table entry is marked NaN so that the programs take the transform list's
                    // matrices at each ray's time.
                    let srt = SrtMotionTransform::new(built.gas.handle(), *options, keys)?;
                    xforms.push(InstanceXformGpu {
                        o2w: [f32::NAN; 12],
                        w2o: [f32::NAN; 12],
                    });
                    instances.push(
                        Instance::new(srt.into())
                            .instance_id(p.id)
                            .sbt_offset(sbt_offset[p.mesh]),
                    );
                    continue;
                }
                let inverse = p.transform.inverse().ok_or_else(|| {
                    RenderError::Scene(format!(
                        "instance {} has a transform that cannot be inverted",
                        p.id
                    ))
                })?;
                xforms.push(InstanceXformGpu {
                    o2w: p.transform.0,
                    w2o: inverse.0,
                });
                instances.push(
                    Instance::new(built.gas.handle())
                        .transform(p.transform)
                        .instance_id(p.id)
                        .sbt_offset(sbt_offset[p.mesh]),
                );
            }
            let built = device.build_ias(
                &BuildOptions::new(BuildFlags::PREFER_FAST_TRACE),
                &[(&instances[..]).into()],
            )?;
            let h = built.optix_handle()?;
            ias = Some(built);
            h
        };

        let materials: Vec<MaterialGpu> = scene.materials.iter().map(material).collect();
        // Lights: emissive triangles (with their selection table), punctual lights, environment.
        let lights = &lit.lights;
        let light_tris: Vec<LightTriGpu> = lights
            .triangles
            .iter()
            .map(|t| LightTriGpu {
                p0: t.p0.to_array(),
                e1: t.e1.to_array(),
                e2: t.e2.to_array(),
                normal: t.normal.to_array(),
                uv: [
                    t.uv[0].x, t.uv[0].y, t.uv[1].x, t.uv[1].y, t.uv[2].x, t.uv[2].y,
                ],
                material: t.material,
                two_sided: t.two_sided as u32,
            })
            .collect();
        let area_pdf: Vec<f32> = (0..scene.materials.len() as u32)
            .map(|m| lights.area_pdf(m))
            .collect();
        let punctual: Vec<PunctualGpu> = scene
            .lights
            .iter()
            .map(|l| {
                let (kind, cos_inner, cos_outer) = match l.kind {
                    LightKind::Directional => (0, 1.0, 1.0),
                    LightKind::Point => (1, 1.0, 1.0),
                    LightKind::Spot {
                        inner_cone,
                        outer_cone,
                    } => (2, inner_cone.cos(), outer_cone.cos()),
                };
                PunctualGpu {
                    kind,
                    position: l.position.to_array(),
                    direction: l.direction.to_array(),
                    intensity: l.intensity.to_array(),
                    range: l.range.unwrap_or(f32::INFINITY),
                    cos_inner,
                    cos_outer,
                    pad: 0,
                }
            })
            .collect();
        let env_tables = env.tables();
        let env_texels: Vec<[f32; 3]> = env_tables.texels.iter().map(|t| t.to_array()).collect();

        let mut params = ParamsGpu {
            accum: 0,
            handle,
            materials: up.put(&materials)?,
            textures: geometry.textures,
            texels: geometry.texels,
            srgb: geometry.srgb,
            instances: up.put(&xforms)?,
            lights: up.put(&light_tris)?,
            light_cdf: up.put(lights.cdf())?,
            light_area_pdf: up.put(&area_pdf)?,
            punctual: up.put(&punctual)?,
            env_texels: up.put(&env_texels)?,
            env_conditional: up.put(env_tables.conditional)?,
            env_marginal: up.put(env_tables.marginal)?,
            ggx_albedo: geometry.ggx_albedo,
            filter: 0,
            aov: 0,
            num_materials: materials.len() as u32,
            num_textures: geometry.num_textures,
            num_lights: light_tris.len() as u32,
            num_punctual: punctual.len() as u32,
            num_instances: xforms.len() as u32,
            env_width: env_tables.width as u32,
            env_height: env_tables.height as u32,
            env_total: env_tables.total,
            p_env: lit.p_env,
            cam_origin: [0.0; 3],
            cam_forward: [0.0; 3],
            cam_right: [0.0; 3],
            cam_up: [0.0; 3],
            sample: 0,
            max_depth: 1,
            eps: lit.eps,
            filter_len: 0,
            roulette_depth: 1,
            seed: 0,
            crop_x0: 0,
            crop_y0: 0,
            image_width: 0,
            image_height: 0,
            sampler: 0,
            shutter_on: 0,
            shutter_open: 0.0,
            shutter_close: 0.0,
            num_cam_keys: 0,
            cam_keys: 0,
        };
        if let (Some((s, _)), true) = (shutter, lit.has_motion()) {
            (params.shutter_on, params.shutter_open, params.shutter_close) = (1, s.open, s.close);
        }
        let sbt = ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[g.raygen.pack_header()]),
            miss: SbtRegion::from_headers(&[g.miss_env.pack_header(), g.miss_shadow.pack_header()]),
            hitgroup: SbtRegion::from_records(&records),
            ..Default::default()
        };
        Ok(GpuScene {
            _ias: ias,
            sbt,
            params,
            _up: up,
        })
    }

    /// The launches of one render: these tables seen from `camera` with `opts` (a camera the
    /// animation moves over the shutter: its frames in `camera_keys`), over the pixels of
    /// `window` (of the `opts.width` x `opts.height` image), adding to `accum` (and `aov`),
    /// the window's pixels, with the pixel filter's table in `filter`.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn pass<'a>(
        &'a self,
        geometry: &'a SceneGeometry,
        opts: &RenderOptions,
        window: CropWindow,
        camera: CameraFrame,
        camera_keys: Option<&Buffer<[f32; 12]>>,
        accum: &Buffer<[f32; 4]>,
        aov: Option<&Buffer<[f32; 8]>>,
        filter: &Buffer<f32>,
    ) -> Pass<'a> {
        let mut params = self.params;
        params.accum = accum.device_ptr();
        params.aov = aov.map_or(0, |b| b.device_ptr());
        params.filter = filter.device_ptr();
        params.filter_len = filter.len() as u32;
        params.cam_origin = camera.origin.to_array();
        params.cam_forward = camera.forward.to_array();
        params.cam_right = camera.right.to_array();
        params.cam_up = camera.up.to_array();
        if let (Some(keys), Some(s)) = (camera_keys, opts.shutter.filter(|s| s.is_open())) {
            // Rays take the shutter's times for the camera's sake too.
            (params.shutter_on, params.shutter_open, params.shutter_close) = (1, s.open, s.close);
            (params.num_cam_keys, params.cam_keys) = (keys.len() as u32, keys.device_ptr());
        }
        params.max_depth = opts.max_depth.max(1);
        params.roulette_depth = opts.roulette_depth.max(1);
        params.seed = opts.seed;
        params.sampler = opts.sampler.code();
        params.crop_x0 = window.x0();
        params.crop_y0 = window.y0();
        params.image_width = opts.width;
        params.image_height = opts.height;
        Pass {
            pipeline: &geometry.pipeline,
            sbt: &self.sbt,
            params,
            window,
        }
    }
}

/// The launches of one render ([`GpuScene::pass`]).
pub(crate) struct Pass<'a> {
    pipeline: &'a Pipeline,
    sbt: &'a ShaderBindingTable,
    params: ParamsGpu,
    /// The pixels launched.
    window: CropWindow,
}

impl Pass<'_> {
    /// Adds sample `sample` to every pixel; returns the rays it traced.
    pub(crate) fn launch(&mut self, sample: u32) -> Result<u64, RenderError> {
        self.params.sample = sample;
        let report = self.pipeline.launch_with(
            &self.params,
            self.sbt,
            self.window.width(),
            self.window.height(),
            1,
        )?;
        if let Some((index, e)) = report.first_exceptions.first() {
            return Err(RenderError::Exceptions {
                pass: sample,
                count: report.exceptions,
                first: format!("at pixel {:?}: {e}", self.window.image_pixel(index)),
            });
        }
        Ok(report.traces)
    }
}
