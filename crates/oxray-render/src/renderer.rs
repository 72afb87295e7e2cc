//! The embeddable renderer: a scene built once on a [`Device`] and rendered many times,
//! progressively, with edits in between that rebuild only what they touch.
//!
//! [`Renderer::new`] compiles the path tracer's CUDA C++ programs ([`device::SOURCE`]) for the
//! device, builds one GAS per mesh and uploads the vertex attributes and textures. A render then
//! adds one sample per pixel per pass and calls the caller back after each pass with a
//! [`Progress`]: the samples done, the image so far on demand ([`Progress::image`]), and the
//! power to stop ([`ControlFlow::Break`]), which returns the image of the passes done.
//! Between renders:
//! - [`Renderer::set_camera`] changes nothing on the device;
//! - [`Renderer::set_instance_transform`] and [`Renderer::set_environment`] rebuild the instance
//!   level and the light tables (no GAS);
//! - [`Renderer::set_material`] re-uploads the material table, and rebuilds the GASes of the
//!   meshes that use the material only where its alpha mode changes between opaque and not
//!   (opaque geometry is built without any-hit programs);
//! - [`Renderer::set_texture`] uploads the textures again (no GAS);
//! - a render with another [`RenderOptions::shutter`] poses the moving instances anew.
//!
//! An edit then a render gives exactly the image of a new renderer over the edited scene (tested
//! bit for bit on the CPU). With [`RenderOptions::aovs`] the render also returns the first hit's
//! [`Aovs`] (albedo, shading normal, distance, samples), which [`Rendered::save_exr`] writes
//! with the image as the layers of one OpenEXR file.
//!
//! ```
//! use std::ops::ControlFlow;
//! use glam::{Mat4, Vec3};
//! use oxray_render::lights::Environment;
//! use oxray_render::{Renderer, RenderOptions};
//!
//! let device = oxray::Device::cpu(); // or oxray::Device::cuda(0)?
//! let scene = oxray_scene::cornell_box();
//! let dark = Environment::uniform(Vec3::ZERO); // lit by the box's ceiling panel only
//! let mut renderer = Renderer::new(&device, &scene, &dark)?;
//! let opts = RenderOptions { width: 16, height: 16, spp: 8, max_depth: 4, aovs: true,
//!                            ..Default::default() };
//!
//! // Stop after three of the eight passes; the result is the image of those three.
//! let first = renderer.render(&opts, |p| {
//!     if p.samples() == 3 { ControlFlow::Break(()) } else { ControlFlow::Continue(()) }
//! })?;
//! assert!(first.cancelled && first.samples == 3);
//! let aovs = first.aovs.as_ref().unwrap();
//! let centre = 8 * 16 + 8; // the middle of the image sees the back wall
//! assert!(aovs.depth[centre].is_finite() && aovs.samples[centre] == 3.0);
//!
//! // Move the first block and render again: only the instance level is rebuilt.
//! let moved = scene.instances[0].transform * Mat4::from_translation(Vec3::new(0.05, 0.0, 0.0));
//! renderer.set_instance_transform(0, moved)?;
//! let second = renderer.render(&opts, |_| ControlFlow::Continue(()))?;
//! assert_eq!(second.samples, 8);
//! # Ok::<(), oxray_render::RenderError>(())
//! ```

use crate::device::{self, GpuScene, SceneGeometry};
use crate::lights::Environment;
use crate::output::Image;
use crate::{camera_frame_with, crop, image_from_sums, RenderError, RenderOptions};
use glam::Mat4;
use oxray::programs::Buffer;
use oxray::{Device, OutputBuffer};
use oxray_scene::{AlphaMode, Camera, MaterialDesc, SceneDesc};
use std::borrow::Cow;
use std::ops::ControlFlow;
use std::path::Path;

/// A scene built on a device, rendered progressively and edited between renders. See the
/// [module documentation](self).
pub struct Renderer<'s> {
    device: Device,
    scene: Cow<'s, SceneDesc>,
    env: Cow<'s, Environment>,
    camera: Option<Camera>,
    geometry: SceneGeometry,
    /// The instance level, lights and materials: `None` after an edit that changes them.
    tables: Option<GpuScene>,
    /// The shutter and animation the tables pose the instances for.
    posed_for: Option<(crate::motion::Shutter, usize)>,
}

impl<'s> Renderer<'s> {
    /// Builds `scene` lit by `env` on `device` with the path tracer's programs. The scene and
    /// the environment are borrowed until the first edit that changes them (then copied).
    pub fn new(
        device: &Device,
        scene: &'s SceneDesc,
        env: &'s Environment,
    ) -> Result<Self, RenderError> {
        Self::with_source(
            device,
            device::SOURCE,
            Cow::Borrowed(scene),
            Cow::Borrowed(env),
        )
    }

    /// [`Renderer::new`] over a scene and an environment that the renderer keeps.
    pub fn from_owned(
        device: &Device,
        scene: SceneDesc,
        env: Environment,
    ) -> Result<Renderer<'static>, RenderError> {
        Renderer::with_source(device, device::SOURCE, Cow::Owned(scene), Cow::Owned(env))
    }

    /// [`Renderer::new`] with other programs in place of [`device::SOURCE`] (same entry points
    /// and layouts), for the tests of the comparison between the two path tracers.
    #[doc(hidden)]
    pub fn with_source(
        device: &Device,
        source: &str,
        scene: Cow<'s, SceneDesc>,
        env: Cow<'s, Environment>,
    ) -> Result<Self, RenderError> {
        scene.validate().map_err(RenderError::Scene)?;
        let geometry = SceneGeometry::build(device, source, &scene)?;
        Ok(Renderer {
            device: device.clone(),
            scene,
            env,
            camera: None,
            geometry,
            tables: None,
            posed_for: None,
        })
    }

    /// The scene as it is now (with the edits made).
    #[must_use]
    pub fn scene(&self) -> &SceneDesc {
        &self.scene
    }

    /// The device that renders.
    #[must_use]
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// Renders from `camera` instead of the scene's camera ([`RenderOptions::camera`]); `None`
    /// goes back to it. Nothing is rebuilt.
    pub fn set_camera(&mut self, camera: Option<Camera>) {
        self.camera = camera;
    }

    /// Replaces material `index`. The material table is uploaded again; the meshes that use the
    /// material are rebuilt only when its alpha mode changes between opaque and not. A material
    /// the scene cannot use (a texture that does not exist, say) is an error that changes
    /// nothing.
    pub fn set_material(
        &mut self,
        index: usize,
        material: MaterialDesc,
    ) -> Result<(), RenderError> {
        let old = self
            .scene
            .materials
            .get(index)
            .ok_or_else(|| missing("material", index, self.scene.materials.len()))?;
        let rebuild =
            (old.alpha_mode == AlphaMode::Opaque) != (material.alpha_mode == AlphaMode::Opaque);
        let old = std::mem::replace(&mut self.scene.to_mut().materials[index], material);
        if let Err(e) = self.scene.validate() {
            self.scene.to_mut().materials[index] = old;
            return Err(RenderError::Scene(e));
        }
        if rebuild {
            self.geometry
                .rebuild_meshes_of_material(&self.device, &self.scene, index as u32)?;
        }
        self.tables = None;
        Ok(())
    }

    /// Replaces texture `index` (its texels, size or wrap modes): the textures are uploaded
    /// again and the materials that use it show the new one from the next render on; no GAS
    /// is rebuilt (alpha-tested materials read the texture as they trace). A texture whose
    /// texels do not match its size, or past the scene's textures, is an error that changes
    /// nothing.
    pub fn set_texture(
        &mut self,
        index: usize,
        texture: oxray_scene::Texture,
    ) -> Result<(), RenderError> {
        let count = self.scene.textures.len();
        if index >= count {
            return Err(missing("texture", index, count));
        }
        let old = std::mem::replace(&mut self.scene.to_mut().textures[index], texture);
        let checked = self
            .scene
            .validate()
            .map_err(RenderError::Scene)
            .and_then(|()| device::check_supported(&self.device, &self.scene));
        if let Err(e) = checked {
            self.scene.to_mut().textures[index] = old;
            return Err(e);
        }
        self.geometry.reupload_textures(&self.device, &self.scene)?;
        self.tables = None;
        Ok(())
    }

    /// Moves instance `index` (object to world). The instance level and the light tables are
    /// rebuilt; no GAS is.
    pub fn set_instance_transform(
        &mut self,
        index: usize,
        to_world: Mat4,
    ) -> Result<(), RenderError> {
        let count = self.scene.instances.len();
        if index >= count {
            return Err(missing("instance", index, count));
        }
        let inst = &mut self.scene.to_mut().instances[index];
        inst.transform = to_world;
        self.tables = None;
        Ok(())
    }

    /// Lights the scene with `env` from the next render on (its sampling tables are uploaded
    /// again; no GAS is rebuilt).
    pub fn set_environment(&mut self, env: Environment) {
        self.env = Cow::Owned(env);
        self.tables = None;
    }

    /// Renders `opts.spp` samples per pixel, one pass each; `on_pass` is called after every
    /// pass and may stop the render, which then returns the image of the passes done
    /// ([`Rendered::cancelled`]). The image does not depend on the device's thread count.
    pub fn render(
        &mut self,
        opts: &RenderOptions,
        mut on_pass: impl FnMut(&Progress<'_>) -> ControlFlow<()>,
    ) -> Result<Rendered, RenderError> {
        let start = std::time::Instant::now();
        let window = crop::window_of(opts.width, opts.height, opts.crop)?;
        let (width, height) = (window.width(), window.height());
        // The instances are posed for one shutter: another one poses them anew.
        let posed_for = opts.shutter.map(|s| (s, opts.animation));
        if posed_for != self.posed_for {
            self.tables = None;
        }
        let camera = camera_frame_with(&self.scene, opts, self.camera)?;
        let keys = crate::camera_keys(&self.scene, opts, self.camera)?;
        let tables = match &mut self.tables {
            Some(t) => t,
            slot @ None => {
                let built = GpuScene::build(
                    &self.device,
                    &self.scene,
                    &self.env,
                    &self.geometry,
                    posed_for,
                )?;
                self.posed_for = posed_for;
                slot.insert(built)
            }
        };
        let pixels = width as usize * height as usize;
        let accum = self.device.create_buffer::<[f32; 4]>(pixels)?;
        let aov = match opts.aovs {
            true => Some(self.device.create_buffer::<[f32; 8]>(pixels)?),
            false => None,
        };
        let filter = self.device.buffer_from_slice(&opts.filter.table())?;
        let keys = match keys.is_empty() {
            true => None,
            false => {
                let words: Vec<[f32; 12]> = keys
                    .iter()
                    .map(|c| {
                        let v = [c.origin, c.forward, c.right, c.up];
                        std::array::from_fn(|i| v[i / 3][i % 3])
                    })
                    .collect();
                Some(self.device.buffer_from_slice(&words)?)
            }
        };
        let mut pass = tables.pass(
            &self.geometry,
            opts,
            window,
            camera,
            keys.as_ref(),
            &accum,
            aov.as_ref(),
            &filter,
        );
        let setup = start.elapsed();
        let mut samples = 0;
        let mut rays = 0;
        let mut cancelled = false;
        for sample in 0..opts.spp {
            rays += pass.launch(sample)?;
            samples = sample + 1;
            let progress = Progress {
                samples,
                total: opts.spp,
                width,
                height,
                accum: Sums::Device(&accum),
            };
            if on_pass(&progress).is_break() {
                cancelled = samples < opts.spp;
                break;
            }
        }
        let sums = accum.download()?;
        let aovs = match aov {
            Some(b) => Some(Aovs::from_sums(width, height, &sums, &b.download()?)),
            None => None,
        };
        Ok(Rendered {
            image: image_from_sums(width, height, &sums),
            samples,
            rays,
            cancelled,
            aovs,
            setup,
        })
    }
}

/// The error of an edit of item `index` of a scene that has `count` of them.
fn missing(what: &str, index: usize, count: usize) -> RenderError {
    RenderError::Scene(format!(
        "{what} {index} does not exist (the scene has {count})"
    ))
}

/// A render's state after a pass, for the callbacks of [`Renderer::render`] and
/// [`render_passes`](crate::render_passes).
pub struct Progress<'r> {
    samples: u32,
    total: u32,
    width: u32,
    height: u32,
    accum: Sums<'r>,
}

/// Where a render's per-pixel sums are.
enum Sums<'r> {
    Device(&'r Buffer<[f32; 4]>),
    Host(&'r OutputBuffer<[f32; 4]>),
}

impl<'r> Progress<'r> {
    /// Samples per pixel done.
    #[must_use]
    pub fn samples(&self) -> u32 {
        self.samples
    }

    /// Samples per pixel asked for.
    #[must_use]
    pub fn total(&self) -> u32 {
        self.total
    }

    /// The mean of the samples done, of the crop window's size with [`RenderOptions::crop`]
    /// (copied from the device: call it when it is shown or saved, not after every pass).
    pub fn image(&self) -> Result<Image, RenderError> {
        let sums = match self.accum {
            Sums::Device(b) => b.download()?,
            Sums::Host(b) => b.to_vec(),
        };
        Ok(image_from_sums(self.width, self.height, &sums))
    }

    /// The progress of the Rust programs: `samples` of `total` done, sums of a
    /// `width` x `height` image (the crop window) in `accum`.
    pub(crate) fn host(
        samples: u32,
        total: u32,
        (width, height): (u32, u32),
        accum: &'r OutputBuffer<[f32; 4]>,
    ) -> Self {
        Progress {
            samples,
            total,
            width,
            height,
            accum: Sums::Host(accum),
        }
    }
}

/// What [`Renderer::render`] returns.
#[derive(Clone, Debug)]
#[must_use]
pub struct Rendered {
    /// The mean radiance per pixel of the samples done, linear RGB.
    pub image: Image,
    /// Samples per pixel done.
    pub samples: u32,
    /// Rays traced (camera, bounce and shadow rays alike; the launches'
    /// [`LaunchReport::traces`](oxray::LaunchReport::traces)): over the render's time, its rays
    /// per second.
    pub rays: u64,
    /// Whether the callback stopped the render before all samples were done.
    pub cancelled: bool,
    /// The auxiliary images, with [`RenderOptions::aovs`].
    pub aovs: Option<Aovs>,
    /// Time the call spent before its first pass, building what the passes need: the
    /// acceleration structures, light and environment tables and programs for
    /// [`render_passes`](crate::render_passes); for a [`Renderer`], whose geometry
    /// [`Renderer::new`] built, only the tables an edit made it rebuild.
    pub setup: std::time::Duration,
}

/// Auxiliary images of the first surface each camera ray meets (a denoiser's guides and a
/// compositor's layers), one value per pixel, row-major from the top row.
#[derive(Clone, Debug, PartialEq)]
pub struct Aovs {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// The surface's albedo: base colour times its texture and vertex colour, averaged over the
    /// pixel's samples (0 for samples that miss every surface).
    pub albedo: Vec<[f32; 3]>,
    /// The shading normal in world space (on the side of the surface the ray came from),
    /// averaged over the pixel's samples without renormalising (0 for misses).
    pub normal: Vec<[f32; 3]>,
    /// The mean distance from the camera of the samples that hit; infinite where none did.
    pub depth: Vec<f32>,
    /// Samples taken in the pixel.
    pub samples: Vec<f32>,
}

impl Aovs {
    /// The AOVs from per-pixel sums (radiance sums with their sample count, and the programs'
    /// [`crate::programs::AOV_WORDS`] sums).
    pub(crate) fn from_sums(width: u32, height: u32, accum: &[[f32; 4]], aov: &[[f32; 8]]) -> Aovs {
        let n = accum.len().min(aov.len());
        let mut out = Aovs {
            width,
            height,
            albedo: Vec::with_capacity(n),
            normal: Vec::with_capacity(n),
            depth: Vec::with_capacity(n),
            samples: Vec::with_capacity(n),
        };
        for (c, a) in accum.iter().zip(aov) {
            let k = 1.0 / c[3].max(1.0);
            out.albedo.push([a[0] * k, a[1] * k, a[2] * k]);
            out.normal.push([a[3] * k, a[4] * k, a[5] * k]);
            out.depth.push(match a[7] > 0.0 {
                true => a[6] / a[7],
                false => f32::INFINITY,
            });
            out.samples.push(c[3]);
        }
        out
    }
}

impl Rendered {
    /// Writes the image and its AOVs as one OpenEXR file (linear 32-bit floats), atomically:
    /// channels `R`, `G`, `B`, `A`, and where AOVs were rendered the layers `albedo.{R,G,B}`,
    /// `normal.{X,Y,Z}`, `depth.Z` and `samples.Y` (the `layer.channel` naming that
    /// compositors and denoisers read as layers).
    pub fn save_exr(&self, path: &Path) -> Result<(), String> {
        crate::output::write_layers_exr(path, &self.image, self.aovs.as_ref(), None)
    }
}
