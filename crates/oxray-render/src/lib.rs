//! A physically based path tracer written as oxray programs (the renderer of `oxray render`),
//! over scenes described by `oxray-scene` and built with the oxray-util layer (one GAS per mesh,
//! one IAS instance per placement, the hit-group SBT laid out by the scene).
//!
//! Materials follow glTF's metallic-roughness model (Lambert plus GGX, energy-conserving:
//! [`bsdf`], [`albedo`]), with `KHR_materials_specular`'s factor (0: Lambertian), smooth
//! dielectrics for transmissive materials, emission, normal maps in glTF's tangent frame, and
//! alpha cutouts (MASK) or stochastic transparency (BLEND) in an any-hit program that both ray
//! types run. Light transport: next-event estimation on emissive triangles (chosen by power) and
//! on the environment (bilinear, chosen by importance over the filtered map), combined with BSDF
//! sampling by multiple importance sampling; Russian roulette. Pixels are reconstructed by
//! filter importance sampling ([`filter`]). Each launch adds one sample per pixel, so progress
//! is reported per pass and the result does not depend on the thread count.
//!
//! The result is linear radiance; [`Image::save`] writes it as OpenEXR (linear) or PNG (sRGB
//! through an exposure and a tone curve, [`tonemap`]; [`Image::save_with`] chooses them).
//!
//! To render a scene more than once (progressively, with a callback that sees the image and
//! may stop the render, with edits between renders that rebuild only what they touch, with
//! AOVs), build a [`Renderer`] on a device; [`render_passes`] gives the callback, the
//! cancellation and the AOVs to the Rust programs too.
//!
//! The same path tracer exists as CUDA C++ programs ([`device::render_on`], `device_programs.cu`)
//! that run on any [`oxray::Device`]: the CPU (compiled by the host's C++ compiler) or a CUDA
//! GPU (compiled by NVRTC). Both versions share the scene preparation (camera, emissive
//! triangles, environment tables) and follow the same random sequence; one test
//! (`tests/device_programs.rs`) compares their images statistically. A change to the algorithm
//! is made in both: `programs.rs` (with `bsdf.rs`, `lights.rs`, `texture.rs`) and
//! `device_programs.cu`.
//!
//! ```
//! use glam::Vec3;
//! use oxray_render::lights::Environment;
//! use oxray_render::filter::Filter;
//! use oxray_render::{render, RenderOptions, Sampler};
//!
//! let scene = oxray_scene::cornell_box();
//! let opts = RenderOptions {
//!     width: 8,
//!     height: 8,
//!     spp: 2,
//!     max_depth: 4,
//!     camera: None, // the scene's first camera, else one framing the scene
//!     filter: Filter::Gaussian,
//!     roulette_depth: 3,
//!     seed: 0,
//!     sampler: Sampler::Sobol, // Owen-scrambled Sobol points ([`sampler`])
//!     aovs: false,
//!     crop: None, // the whole image ([`crop`]: a window of it)
//!     shutter: None, // no motion blur ([`motion`]: a shutter over the scene's animation)
//!     animation: 0,
//! };
//! let dark = Environment::uniform(Vec3::ZERO); // the box is lit by its ceiling panel only
//! let mut passes = 0;
//! let image = render(&scene, &dark, &opts, |done| passes = done)?;
//! assert_eq!(passes, 2);
//! assert_eq!(image.pixels.len(), 64);
//! assert!(image.pixels.iter().any(|p| p[0] + p[1] + p[2] > 0.0));
//!
//! let out = std::env::temp_dir().join(format!("oxray-doc-{}.png", std::process::id()));
//! image.save(&out)?;
//! # std::fs::remove_file(&out)?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![warn(missing_docs)]

pub mod albedo;
pub mod bsdf;
pub mod crop;
pub mod denoise;
pub mod device;
pub mod filter;
pub mod lights;
pub mod motion;
pub mod output;
pub mod programs;
pub mod renderer;
pub mod sampler;
pub mod texture;
pub mod tonemap;
mod wavefront;

use glam::Vec3;
use lights::{Environment, TriangleLights};
use oxray::{
    BuildFlags, DeviceContext, GeometryFlags, HitGroupDesc, OutputBuffer, PipelineCompileOptions,
    PipelineLinkOptions, ProgramGroup, Transform, TraversableHandle,
};
use oxray_scene::{AlphaMode, Camera, Primitive, SceneDesc};
use oxray_util::{
    GasDesc, Geometry, GeometryInstance, HitGroupData, Material, Scene, ScenePipeline, UtilInstance,
};
use programs::{CameraFrame, Params, AOV_WORDS, RAY_TYPES};
use std::ops::ControlFlow;
use thiserror::Error;

pub use output::Image;
pub use renderer::{Aovs, Progress, Rendered, Renderer};
pub use sampler::Sampler;

/// Render settings.
#[derive(Clone, Debug)]
pub struct RenderOptions {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Samples per pixel.
    pub spp: u32,
    /// Path vertices at most.
    pub max_depth: u32,
    /// Which of the scene's cameras to use; `None`: the first, or a camera framing the scene.
    pub camera: Option<usize>,
    /// The pixel reconstruction filter.
    pub filter: filter::Filter,
    /// The first path vertex after which Russian roulette may end a path: the first bounces,
    /// which carry most of the image, are never cut short. From there a path goes on with the
    /// probability [`programs::roulette_survival`] of its throughput.
    pub roulette_depth: u32,
    /// Chooses the random sequence: renders with the same seed are identical, renders with
    /// different seeds independent (0 is the default sequence).
    pub seed: u32,
    /// Where the random numbers come from: Owen-scrambled Sobol points (the default, lower
    /// error at equal samples) or independent ones ([`sampler`]).
    pub sampler: sampler::Sampler,
    /// Also render the first hit's auxiliary images ([`Aovs`]: albedo, shading normal,
    /// distance, samples), returned by [`Renderer::render`] and [`render_passes`].
    pub aovs: bool,
    /// Render only this window of the image ([`crop::CropWindow`], in the pixels of the
    /// `width` x `height` image); the result has the window's size and each of its pixels is
    /// the same pixel of the full render, bit for bit. `None`: the whole image.
    pub crop: Option<crop::CropWindow>,
    /// Motion blur: the shutter interval over which camera rays take their times, with the
    /// scene's animation [`RenderOptions::animation`] moving its instances ([`motion`]).
    /// `None`: no motion, the instances at rest.
    pub shutter: Option<motion::Shutter>,
    /// Which of the scene's animations the shutter sees (ignored without a shutter).
    pub animation: usize,
}

impl Default for RenderOptions {
    /// 640 x 480 pixels, 16 samples per pixel, paths of up to 8 vertices, the scene's camera,
    /// the Gaussian pixel filter, Russian roulette after 3 vertices, seed 0, the Sobol
    /// sampler, no AOVs, the whole image, no motion blur.
    fn default() -> Self {
        RenderOptions {
            width: 640,
            height: 480,
            spp: 16,
            max_depth: 8,
            camera: None,
            filter: filter::Filter::default(),
            roulette_depth: 3,
            seed: 0,
            sampler: sampler::Sampler::default(),
            aovs: false,
            crop: None,
            shutter: None,
            animation: 0,
        }
    }
}

/// Why a render failed.
#[derive(Debug, Error)]
pub enum RenderError {
    /// The scene cannot be rendered as given.
    #[error("{0}")]
    Scene(String),
    /// The crop window is not inside the image ([`RenderOptions::crop`]).
    #[error(transparent)]
    Crop(#[from] crop::CropError),
    /// Building acceleration structures or the SBT failed.
    #[error(transparent)]
    Build(#[from] oxray_util::UtilError),
    /// Creating or launching the pipeline failed.
    #[error(transparent)]
    Launch(#[from] oxray_util::SceneLaunchError),
    /// A program could not be registered.
    #[error(transparent)]
    Pipeline(#[from] oxray::PipelineError),
    /// Building acceleration structures on the device failed.
    #[error(transparent)]
    Accel(#[from] oxray::BuildError),
    /// The CUDA C++ programs could not be compiled, or a device buffer or launch failed.
    #[error(transparent)]
    Program(#[from] oxray::ProgramError),
    /// The scene uses something this renderer cannot render yet (it renders nothing rather
    /// than something different).
    #[error("{renderer} cannot render {feature} yet")]
    Unsupported {
        /// The renderer (`the CUDA C++ path tracer on the CPU`, say).
        renderer: String,
        /// The feature.
        feature: String,
    },
    /// A sample pass raised exceptions in the renderer's programs (a defect of the renderer or
    /// a scene it cannot handle); the image would be wrong, so none is returned.
    #[error("sample pass {pass}: {count} pixels raised exceptions, the first {first}")]
    Exceptions {
        /// The sample pass.
        pass: u32,
        /// Pixels that raised one.
        count: u64,
        /// The first, with its pixel.
        first: String,
    },
}

/// Where the camera looks from, for `opts`: the scene's camera, else one that frames the
/// scene's bounds from the front, slightly above and to the right.
pub fn camera_frame(scene: &SceneDesc, opts: &RenderOptions) -> Result<CameraFrame, RenderError> {
    camera_frame_with(scene, opts, None)
}

/// [`camera_frame`] from `camera` where it is given (a [`Renderer`]'s own camera).
pub(crate) fn camera_frame_with(
    scene: &SceneDesc,
    opts: &RenderOptions,
    camera: Option<Camera>,
) -> Result<CameraFrame, RenderError> {
    let camera = match camera {
        Some(c) => c,
        None => {
            let c = select_camera(scene, opts)?;
            // With a shutter, the animation places the camera: a closed one renders the pose
            // at its time (an open one keys the camera over it: `camera_keys`).
            match opts.shutter {
                Some(s) => Camera {
                    to_world: scene.camera_transform_at(&c, opts.animation, s.open),
                    ..c
                },
                None => c,
            }
        }
    };
    frame_of(&camera, opts)
}

/// How many frames key a camera that the animation moves while the shutter is open (evenly
/// spaced, linear between them: [`CameraFrame::at`]).
pub const CAMERA_KEYS: usize = 33;

/// The camera's frames over the shutter when the scene's animation (`opts.animation`) moves it
/// while `opts.shutter` is open; empty otherwise, and for a camera given by the caller
/// (`camera`: a [`Renderer`]'s own, which does not hang on a node).
pub(crate) fn camera_keys(
    scene: &SceneDesc,
    opts: &RenderOptions,
    camera: Option<Camera>,
) -> Result<Vec<CameraFrame>, RenderError> {
    let Some(shutter) = opts.shutter.filter(|s| s.is_open()) else {
        return Ok(Vec::new());
    };
    let camera = match camera {
        Some(c) => c,
        None => select_camera(scene, opts)?,
    };
    if !scene.is_camera_animated(&camera, opts.animation) {
        return Ok(Vec::new());
    }
    (0..CAMERA_KEYS)
        .map(|k| {
            let u = k as f32 / (CAMERA_KEYS - 1) as f32;
            let to_world = scene.camera_transform_at(&camera, opts.animation, shutter.time(u));
            frame_of(&Camera { to_world, ..camera }, opts)
        })
        .collect()
}

fn select_camera(scene: &SceneDesc, opts: &RenderOptions) -> Result<Camera, RenderError> {
    Ok(match opts.camera {
        Some(i) => *scene.cameras.get(i).ok_or_else(|| {
            RenderError::Scene(format!(
                "camera {i} does not exist (the scene has {})",
                scene.cameras.len()
            ))
        })?,
        None => match scene.cameras.first() {
            Some(c) => *c,
            None => framing_camera(scene)?,
        },
    })
}

fn frame_of(camera: &Camera, opts: &RenderOptions) -> Result<CameraFrame, RenderError> {
    let m = camera.to_world;
    let origin = m.transform_point3(Vec3::ZERO);
    let forward = m.transform_vector3(-Vec3::Z).normalize_or_zero();
    let up0 = m.transform_vector3(Vec3::Y);
    let right = forward.cross(up0).normalize_or_zero();
    let up = right.cross(forward);
    if !origin.is_finite() || right == Vec3::ZERO || !(camera.yfov > 0.0 && camera.yfov < 3.1) {
        return Err(RenderError::Scene(
            "the scene's camera is degenerate".into(),
        ));
    }
    let half_h = (camera.yfov * 0.5).tan();
    let half_w = half_h * opts.width as f32 / opts.height as f32;
    Ok(CameraFrame {
        origin,
        forward,
        right: right * half_w,
        up: up * half_h,
    })
}

fn framing_camera(scene: &SceneDesc) -> Result<Camera, RenderError> {
    let (lo, hi) = scene
        .content_bounds()
        .ok_or_else(|| RenderError::Scene("the scene has no finite geometry".into()))?;
    let centre = (lo + hi) * 0.5;
    let radius = ((hi - lo) * 0.5).length().max(1e-6);
    let yfov = 40f32.to_radians();
    let dir = Vec3::new(0.35, 0.3, 1.0).normalize();
    Ok(Camera::look_at(
        centre + dir * (radius / (yfov * 0.5).sin() * 1.05),
        centre,
        yfov,
    ))
}

/// What both renderers ([`render`] and [`device::render_on`]) derive from a scene before
/// tracing: the camera and the lighting, with the options that shape the paths.
pub(crate) struct Prepared {
    pub camera: CameraFrame,
    /// The camera's frames over the shutter where the animation moves it ([`camera_keys`]).
    pub camera_keys: Vec<CameraFrame>,
    pub lit: Lighting,
    pub max_depth: u32,
    /// The pixel filter's inverse-CDF table ([`filter::Filter::table`]).
    pub filter: Vec<f32>,
    /// The first vertex after which Russian roulette may end a path.
    pub roulette_depth: u32,
}

/// What the renderers derive from a scene and its environment, whatever the view: the emissive
/// triangles, the light-selection probability, the ray offset and the placements to trace.
pub(crate) struct Lighting {
    pub lights: TriangleLights,
    /// Probability that next-event estimation samples the environment.
    pub p_env: f32,
    /// Distance by which new rays leave a surface.
    pub eps: f32,
    /// The instances to trace: placeable, of meshes with triangles.
    pub placements: Vec<Placement>,
    /// Whether the scene is one untransformed placement, traced as its GAS: the instance level
    /// would only add a transform per ray.
    pub single: bool,
    /// Per scene instance, whether it moves while the shutter is open (empty when none does).
    pub moving: Vec<bool>,
}

impl Lighting {
    /// Whether any placement moves (the pipeline must then trace with motion blur).
    pub fn has_motion(&self) -> bool {
        self.placements.iter().any(|p| p.motion.is_some())
    }
}

/// One instance to trace.
pub(crate) struct Placement {
    pub mesh: usize,
    /// The instance id (the scene's instance index, in 28 bits).
    pub id: u32,
    pub transform: Transform,
    /// Motion keys over the shutter, for an instance that moves while it is open (then
    /// `transform` is the identity and the keys place the mesh).
    pub motion: Option<(oxray::MotionOptions, Vec<oxray::SrtData>)>,
}

/// Whether a primitive is traced (it has triangles).
pub(crate) fn traced(p: &Primitive) -> bool {
    !p.triangles.is_empty()
}

pub(crate) fn prepare(
    scene: &SceneDesc,
    env: &Environment,
    opts: &RenderOptions,
) -> Result<Prepared, RenderError> {
    scene.validate().map_err(RenderError::Scene)?;
    let camera = camera_frame(scene, opts)?;
    Ok(Prepared {
        camera,
        camera_keys: camera_keys(scene, opts, None)?,
        lit: prepare_lighting(scene, env, opts.shutter.map(|s| (s, opts.animation)))?,
        max_depth: opts.max_depth.max(1),
        filter: opts.filter.table(),
        roulette_depth: opts.roulette_depth.max(1),
    })
}

/// The lighting of a validated scene, with its instances posed over `shutter` by the scene's
/// animation of that index (`None`: at rest).
pub(crate) fn prepare_lighting(
    scene: &SceneDesc,
    env: &Environment,
    shutter: Option<(motion::Shutter, usize)>,
) -> Result<Lighting, RenderError> {
    if let Some((_, a)) = shutter {
        if a > 0 && a >= scene.animations.len() {
            return Err(RenderError::Scene(format!(
                "animation {a} does not exist (the scene has {})",
                scene.animations.len()
            )));
        }
    }
    let poses: Vec<Option<motion::Pose>> = (0..scene.instances.len())
        .map(|i| match shutter {
            None => Some(motion::Pose::Still(scene.instances[i].transform)),
            Some((s, a)) => motion::pose(scene, i, a, s),
        })
        .collect();
    let lights = TriangleLights::placed(scene, |i| match &poses[i] {
        Some(motion::Pose::Still(m)) => Some(*m),
        _ => None,
    });
    let p_env = match (lights.is_empty(), env.is_black()) {
        (_, true) => 0.0,
        (true, false) => 1.0,
        (false, false) => 0.5,
    };
    let eps = scene
        .content_bounds()
        .map_or(1e-4, |(lo, hi)| (hi - lo).max_element() * 1e-5)
        .max(1e-7);
    let mut placements = Vec::new();
    for (i, (inst, pose)) in scene.instances.iter().zip(poses).enumerate() {
        let Some(mesh) = scene.meshes.get(inst.mesh as usize) else {
            continue;
        };
        if !mesh.primitives.iter().any(traced) {
            continue;
        }
        let (transform, motion) = match pose {
            Some(motion::Pose::Still(m)) => {
                let at = oxray_scene::InstanceDesc::new(inst.mesh, m);
                let Some(t) = at.placement() else {
                    continue;
                };
                (t, None)
            }
            Some(motion::Pose::Moving(options, keys)) => {
                (Transform::IDENTITY, Some((options, keys)))
            }
            None => continue,
        };
        placements.push(Placement {
            mesh: inst.mesh as usize,
            id: i as u32 & 0x0FFF_FFFF,
            transform,
            motion,
        });
    }
    if placements.is_empty() {
        return Err(RenderError::Scene(
            "the scene has no visible instance".into(),
        ));
    }
    // The GAS itself is the root only where its hit records start the SBT: no mesh before it
    // has traced primitives (every such mesh has records, placed or not), since a root GAS
    // adds no instance's SBT offset.
    let single = placements.len() == 1
        && placements[0].transform == Transform::IDENTITY
        && placements[0].motion.is_none()
        && scene.meshes[..placements[0].mesh]
            .iter()
            .all(|m| !m.primitives.iter().any(traced));
    let mut moving = Vec::new();
    if placements.iter().any(|p| p.motion.is_some()) {
        moving = vec![false; scene.instances.len()];
        for p in placements.iter().filter(|p| p.motion.is_some()) {
            moving[p.id as usize] = true;
        }
    }
    Ok(Lighting {
        lights,
        p_env,
        eps,
        placements,
        single,
        moving,
    })
}

/// The image from per-pixel sums whose fourth value counts the samples.
pub(crate) fn image_from_sums(width: u32, height: u32, sums: &[[f32; 4]]) -> Image {
    let pixels = sums
        .iter()
        .map(|&[r, g, b, n]| {
            let k = 1.0 / n.max(1.0);
            [r * k, g * k, b * k, 1.0]
        })
        .collect();
    Image {
        width,
        height,
        pixels,
    }
}

/// Renders `scene` with the environment `env`; `progress` is called after each pass with the
/// number of samples done. Returns the mean radiance per pixel, linear RGB.
pub fn render(
    scene: &SceneDesc,
    env: &Environment,
    opts: &RenderOptions,
    mut progress: impl FnMut(u32),
) -> Result<Image, RenderError> {
    let done = render_passes(scene, env, opts, |p| {
        progress(p.samples());
        ControlFlow::Continue(())
    })?;
    Ok(done.image)
}

/// [`render`] with the callback of [`Renderer::render`]: after each pass it sees the samples
/// done and the image so far ([`Progress::image`]) and may stop the render, which then returns
/// the image of the passes done; with [`RenderOptions::aovs`] the result has the [`Aovs`].
///
/// ```
/// use std::ops::ControlFlow;
/// use glam::Vec3;
/// use oxray_render::{lights::Environment, render_passes, RenderOptions};
///
/// let scene = oxray_scene::cornell_box();
/// let opts = RenderOptions { width: 8, height: 8, spp: 16, max_depth: 3, ..Default::default() };
/// let done = render_passes(&scene, &Environment::uniform(Vec3::ZERO), &opts, |p| {
///     match p.samples() < 2 {
///         true => ControlFlow::Continue(()),
///         false => ControlFlow::Break(()),
///     }
/// })?;
/// assert!(done.cancelled);
/// assert_eq!(done.samples, 2);
/// # Ok::<(), oxray_render::RenderError>(())
/// ```
pub fn render_passes(
    scene: &SceneDesc,
    env: &Environment,
    opts: &RenderOptions,
    mut on_pass: impl FnMut(&Progress<'_>) -> ControlFlow<()>,
) -> Result<Rendered, RenderError> {
    let start = std::time::Instant::now();
    let window = crop::window_of(opts.width, opts.height, opts.crop)?;
    let prep = prepare(scene, env, opts)?;
    // Everything the launch parameters borrow outlives the scene that holds the programs.
    let prims: Vec<&Primitive> = scene
        .meshes
        .iter()
        .flat_map(|m| m.primitives.iter().filter(|p| traced(p)))
        .collect();
    let lights = &prep.lit.lights;
    let (w, h) = (window.width(), window.height());
    let pixels = w as usize * h as usize;
    let accum = OutputBuffer::new(pixels);
    let aov = opts
        .aovs
        .then(|| OutputBuffer::<[f32; AOV_WORDS]>::new(pixels));
    let module = programs::module()?;
    let radiance_opaque = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__radiance")),
        ..Default::default()
    })?;
    let radiance_alpha = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__radiance")),
        any_hit: Some((&module, "__anyhit__alpha")),
        ..Default::default()
    })?;
    // Shadow rays end at the first opaque hit and need no program there.
    let shadow_opaque = ProgramGroup::hit_group(HitGroupDesc::default())?;
    let shadow_alpha = ProgramGroup::hit_group(HitGroupDesc {
        any_hit: Some((&module, "__anyhit__alpha")),
        ..Default::default()
    })?;

    let mut util: Scene<Params> = Scene::new();
    let mats: Vec<_> = scene
        .materials
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let groups = if m.alpha_mode == AlphaMode::Opaque {
                vec![Some(radiance_opaque.clone()), Some(shadow_opaque.clone())]
            } else {
                vec![Some(radiance_alpha.clone()), Some(shadow_alpha.clone())]
            };
            util.add_material(Material::new(groups, i as u32))
        })
        .collect();
    let mut next_prim = 0u32;
    let mut gas_of_mesh = Vec::with_capacity(scene.meshes.len());
    // Per mesh, the hit-group data of its GAS's build inputs (what its SBT records hold).
    let mut records_of_mesh = Vec::with_capacity(scene.meshes.len());
    for mesh in &scene.meshes {
        let mut children = Vec::new();
        let mut records = Vec::new();
        for prim in mesh.primitives.iter().filter(|p| traced(p)) {
            let m = prim.material as usize;
            let flags = if scene.materials[m].alpha_mode == AlphaMode::Opaque {
                GeometryFlags::DISABLE_ANYHIT
            } else {
                GeometryFlags::REQUIRE_SINGLE_ANYHIT_CALL
            };
            let geom = GeometryInstance::new(
                Geometry::Triangles {
                    vertices: prim.positions.clone(),
                    indices: prim.triangles.clone(),
                },
                1,
            )
            .material(0, 0, mats[m])
            .flags(0, flags)
            .user_data(next_prim);
            records.push(HitGroupData {
                material: m as u32,
                geometry: next_prim,
                gas: 0,
            });
            next_prim += 1;
            children.push(util.add_geometry(geom));
        }
        records_of_mesh.push(records);
        gas_of_mesh.push(
            (!children.is_empty()).then(|| util.add_gas(GasDesc::new(children, vec![RAY_TYPES]))),
        );
    }
    let mut instances = Vec::new();
    // Per instance of the IAS, the mesh it places.
    let mut mesh_of_instance = Vec::new();
    for p in &prep.lit.placements {
        let Some(gas) = gas_of_mesh[p.mesh] else {
            continue;
        };
        mesh_of_instance.push(p.mesh as u32);
        let mut u = UtilInstance::new(gas, 0);
        u.transform = p.transform;
        u.instance_id = p.id;
        u.motion = p.motion.clone();
        instances.push(u);
    }
    // A single untransformed instance's SBT offset is 0 either way: its chunk starts the
    // hit-group table (`Lighting::single`).
    let single = prep.lit.single.then(|| instances[0].gas);
    let ias = util.add_ias(instances, BuildFlags::PREFER_FAST_TRACE);
    util.rebuild_dirty()?;
    let handle = match single {
        Some(gas) => util.gas_handle(gas),
        None => util.ias_handle(ias),
    }
    .ok_or_else(|| RenderError::Scene("the scene could not be built".into()))?;
    let wavefront = match prep.lit.has_motion() {
        true => None,
        false => wavefront_for(scene, &handle, records_of_mesh, mesh_of_instance),
    };

    let pipeline = ScenePipeline::new(
        &DeviceContext::new(),
        PipelineCompileOptions {
            num_payload_values: programs::WORDS as u32,
            uses_motion_blur: prep.lit.has_motion(),
            ..Default::default()
        },
        PipelineLinkOptions { max_trace_depth: 2 },
        ProgramGroup::raygen(&module, "__raygen__camera")?,
        vec![
            ProgramGroup::miss(Some((&module, "__miss__environment")))?,
            ProgramGroup::miss(Some((&module, "__miss__shadow")))?,
        ],
    );
    let setup = start.elapsed();
    let mut samples = 0;
    let mut rays = 0;
    let mut cancelled = false;
    for sample in 0..opts.spp {
        let params = Params {
            accum: &accum,
            handle: handle.clone(),
            scene,
            prims: &prims,
            lights,
            env,
            p_env: prep.lit.p_env,
            camera: prep.camera,
            camera_keys: &prep.camera_keys,
            sample,
            max_depth: prep.max_depth,
            eps: prep.lit.eps,
            filter: &prep.filter,
            roulette_depth: prep.roulette_depth,
            seed: opts.seed,
            sampler: opts.sampler,
            aov: aov.as_ref(),
            window: [window.x0(), window.y0()],
            image: [opts.width, opts.height],
            shutter: opts
                .shutter
                .filter(|s| s.is_open() && (prep.lit.has_motion() || !prep.camera_keys.is_empty())),
            moving: &prep.lit.moving,
        };
        if let Some(wf) = &wavefront {
            rays += wf.pass(&params, w, h);
            #[cfg(test)]
            WAVEFRONT_PASSES.with(|n| n.set(n.get() + 1));
        } else {
            // One launch index per pixel of the window.
            let report = pipeline.launch(&mut util, &params, w, h, 1)?;
            rays += report.traces;
            if let Some((index, e)) = report.first_exceptions.first() {
                return Err(RenderError::Exceptions {
                    pass: sample,
                    count: report.exceptions,
                    first: format!("at pixel {:?}: {e}", window.image_pixel(index)),
                });
            }
        }
        samples = sample + 1;
        let progress = Progress::host(samples, opts.spp, (w, h), &accum);
        if on_pass(&progress).is_break() {
            cancelled = samples < opts.spp;
            break;
        }
    }
    let sums = accum.to_vec();
    Ok(Rendered {
        image: image_from_sums(w, h, &sums),
        samples,
        rays,
        cancelled,
        aovs: aov
            .as_ref()
            .map(|a| Aovs::from_sums(w, h, &sums, &a.to_vec())),
        setup,
    })
}

/// The wavefront for a scene without motion traced through `handle` (a GAS placed without a
/// transform, the first instance's mesh, or an IAS whose instance `i` places mesh
/// `mesh_of_instance[i]`), whose mesh `m` has the hit-group data `records[m]`. `None`: the
/// pipeline renders it.
fn wavefront_for<'g>(
    scene: &SceneDesc,
    handle: &'g TraversableHandle,
    mut records: Vec<Vec<HitGroupData>>,
    mesh_of_instance: Vec<u32>,
) -> Option<wavefront::Wavefront<'g>> {
    if forced_pipeline() {
        return None;
    }
    let alpha = scene
        .materials
        .iter()
        .any(|m| m.alpha_mode != AlphaMode::Opaque);
    let root = if let Some(gas) = handle.downcast_ref::<oxray::cpu::Gas>() {
        let first = *mesh_of_instance.first()? as usize;
        records = vec![std::mem::take(records.get_mut(first)?)];
        wavefront::Root::Gas(gas)
    } else {
        let ias = handle.downcast_ref::<oxray::cpu::Ias>()?;
        // One level of instances over GASes: the only graph the scene layer makes here.
        if ias.data().depth != 2 {
            return None;
        }
        wavefront::Root::Ias {
            ias,
            mesh_of_instance,
        }
    };
    Some(wavefront::Wavefront::new(root, records, alpha))
}

/// Whether renders go through the pipeline even where the wavefront applies: for the tests
/// that compare the two.
fn forced_pipeline() -> bool {
    #[cfg(test)]
    {
        FORCE_PIPELINE.with(std::cell::Cell::get)
    }
    #[cfg(not(test))]
    {
        false
    }
}

#[cfg(test)]
thread_local! {
    static FORCE_PIPELINE: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
    /// Passes the wavefront traced on this thread's renders.
    static WAVEFRONT_PASSES: std::cell::Cell<u32> = const { std::cell::Cell::new(0) };
}

/// The README's examples (the library's, the renderer's), compiled and run as doctests.
#[cfg(doctest)]
#[doc = include_str!("../../../README.md")]
struct ReadmeDoctests;
