//! `oxray view`: a window that shows a scene rendered progressively, with an orbit camera.
//!
//! Two threads. The UI thread runs the window's event loop (winit) and draws with softbuffer;
//! the render thread owns the scene and the path tracer and renders one pass at a time. Camera
//! changes go to the render thread through a channel, each with a generation number; after
//! every pass the render thread looks at the channel and, when a newer camera is waiting,
//! stops the render (the pass callback's `ControlFlow::Break`) and starts again from it;
//! otherwise it sends the tone-mapped image so far back to the event loop (an
//! `EventLoopProxy` user event, which wakes it). Frames of an older generation are dropped.
//!
//! The window shows exactly the 8-bit sRGB values that `oxray render` writes to a PNG (the
//! same [`Look`]), packed as softbuffer's `0RGB` words: a screenshot is the render's PNG.

use crate::render_device::RenderBackend;
use anyhow::{bail, Context, Result};
use glam::Vec3;
use oxray::Device;
use oxray_render::lights::Environment;
use oxray_render::tonemap::Look;
use oxray_render::{RenderOptions, Renderer};
use oxray_scene::{Camera, SceneDesc};
use std::num::NonZeroU32;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::sync::mpsc;
use winit::application::ApplicationHandler;
use winit::dpi::{PhysicalPosition, PhysicalSize};
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop, EventLoopProxy};
use winit::keyboard::{Key, NamedKey};
use winit::window::{Window, WindowId};

/// Everything `oxray view` shows, checked and loaded by the command line.
pub struct ViewSetup {
    /// The scene's name (file name without extension), for the window title and saved files.
    pub name: String,
    /// The scene.
    pub scene: SceneDesc,
    /// Its environment light.
    pub environment: Environment,
    /// Size, samples per pixel at most, camera and sampling of the render.
    pub opts: RenderOptions,
    /// Exposure and tone curve of the displayed image.
    pub look: Look,
    /// `--look-at`: the point the camera orbits (default: the scene's centre).
    pub look_at: Option<Vec3>,
    /// Which path tracer renders.
    pub renderer: RenderBackend,
    /// The render's worker threads.
    pub pool: rayon::ThreadPool,
    /// `--screenshot`: render `opts.spp` passes, write the window's image there and exit.
    pub screenshot: Option<PathBuf>,
}

/// Fails with one line when there is no display to open a window on.
pub fn check_display() -> Result<()> {
    let set = |name: &str| std::env::var_os(name).is_some_and(|v| !v.is_empty());
    if !set("DISPLAY") && !set("WAYLAND_DISPLAY") {
        bail!("oxray view needs a display, and neither DISPLAY nor WAYLAND_DISPLAY is set (oxray render writes an image file instead)");
    }
    Ok(())
}

/// Opens the window and runs until it is closed (or, with a screenshot, until it is written).
pub fn run(setup: ViewSetup) -> Result<()> {
    let event_loop = EventLoop::<FromRenderer>::with_user_event()
        .build()
        .map_err(|e| {
            // winit's message names its own source line before the reason: keep the reason.
            let message = e.to_string();
            let reason = message
                .strip_prefix("os error at ")
                .and_then(|m| m.split_once(": "))
                .map_or(message.as_str(), |(_, reason)| reason);
            let display = std::env::var("WAYLAND_DISPLAY")
                .ok()
                .filter(|d| !d.is_empty())
                .or_else(|| std::env::var("DISPLAY").ok())
                .unwrap_or_default();
            anyhow::anyhow!("cannot open the display {display}: {reason}")
        })?;
    let ViewSetup {
        name,
        scene,
        environment,
        opts,
        look,
        look_at,
        renderer,
        pool,
        screenshot,
    } = setup;
    let frame = oxray_render::camera_frame(&scene, &opts)?;
    let home = Orbit::new(&frame, look_at.or_else(|| centre(&scene)));
    let (to_renderer, commands) = mpsc::channel();
    let proxy = event_loop.create_proxy();
    let render_opts = opts.clone();
    std::thread::Builder::new()
        .name("oxray-view-render".into())
        .spawn(move || {
            let failed = proxy.clone();
            if let Err(e) = pool.install(|| {
                render_loop(
                    renderer,
                    scene,
                    environment,
                    render_opts,
                    look,
                    commands,
                    proxy,
                )
            }) {
                let _ = failed.send_event(FromRenderer::Failed(format!("{e:#}")));
            }
        })
        .context("cannot start the render thread")?;
    let mut app = App {
        name,
        width: opts.width,
        height: opts.height,
        total: opts.spp,
        screenshot,
        window: None,
        framebuffer: vec![0; opts.width as usize * opts.height as usize],
        shown: None,
        generation: 0,
        orbit: home,
        home,
        buttons: [false; 3],
        cursor: None,
        to_renderer,
        result: Ok(()),
    };
    event_loop
        .run_app(&mut app)
        .map_err(|e| anyhow::anyhow!("the window's event loop failed: {e}"))?;
    let _ = app.to_renderer.send(ToRenderer::Quit);
    app.result
}

/// The centre of the scene's content: where the camera orbits by default.
fn centre(scene: &SceneDesc) -> Option<Vec3> {
    scene.content_bounds().map(|(lo, hi)| (lo + hi) * 0.5)
}

/// What the UI thread tells the render thread.
enum ToRenderer {
    /// Render from this camera (`None`: the scene's, as `oxray render` does); frames of the
    /// render carry `generation`.
    Camera {
        generation: u64,
        camera: Option<Camera>,
    },
    Quit,
}

/// What the render thread tells the UI thread.
enum FromRenderer {
    Frame(Frame),
    Failed(String),
}

/// The image after a pass, ready to display.
struct Frame {
    generation: u64,
    /// `0RGB` words, row-major from the top row, as softbuffer takes them.
    pixels: Vec<u32>,
    samples: u32,
    /// Seconds since this generation's render began.
    seconds: f64,
}

/// The render thread's path tracer. The CUDA C++ programs' `Renderer` is built once and a
/// camera change rebuilds nothing; the Rust programs prepare their pipeline per render, as
/// `oxray render` does.
enum Session {
    Rust {
        scene: Box<SceneDesc>,
        env: Box<Environment>,
        /// Whether the scene's last camera is the viewer's, appended to it.
        added: bool,
    },
    Built(Box<Renderer<'static>>),
}

impl Session {
    fn new(backend: RenderBackend, scene: SceneDesc, env: Environment) -> Result<Session> {
        Ok(match backend {
            RenderBackend::Rust => Session::Rust {
                scene: Box::new(scene),
                env: Box::new(env),
                added: false,
            },
            RenderBackend::CxxOnCpu => {
                Session::Built(Box::new(Renderer::from_owned(&Device::cpu(), scene, env)?))
            }
            RenderBackend::Device(d) => {
                Session::Built(Box::new(Renderer::from_owned(&d, scene, env)?))
            }
        })
    }

    fn render(
        &mut self,
        camera: Option<Camera>,
        opts: &RenderOptions,
        on_pass: impl FnMut(&oxray_render::Progress<'_>) -> ControlFlow<()>,
    ) -> Result<()> {
        match self {
            Session::Rust { scene, env, added } => {
                let mut opts = opts.clone();
                match camera {
                    Some(c) => {
                        if *added {
                            scene.cameras.pop();
                        }
                        scene.cameras.push(c);
                        *added = true;
                        opts.camera = Some(scene.cameras.len() - 1);
                    }
                    None if *added => {
                        scene.cameras.pop();
                        *added = false;
                    }
                    None => {}
                }
                let _ = oxray_render::render_passes(scene, env, &opts, on_pass)?;
            }
            Session::Built(renderer) => {
                renderer.set_camera(camera);
                let _ = renderer.render(opts, on_pass)?;
            }
        }
        Ok(())
    }
}

/// The render thread: renders the latest camera pass by pass until the image has all its
/// samples or a newer camera comes, and sends each pass's image to the event loop.
fn render_loop(
    backend: RenderBackend,
    scene: SceneDesc,
    env: Environment,
    opts: RenderOptions,
    look: Look,
    commands: mpsc::Receiver<ToRenderer>,
    proxy: EventLoopProxy<FromRenderer>,
) -> Result<()> {
    let mut session = Session::new(backend, scene, env)?;
    let mut next = Some((0, None));
    loop {
        let (generation, camera) = match next.take() {
            Some(job) => job,
            // The image is complete: wait for the next camera.
            None => match commands.recv() {
                Ok(ToRenderer::Camera { generation, camera }) => (generation, camera),
                Ok(ToRenderer::Quit) | Err(_) => return Ok(()),
            },
        };
        let mut quit = false;
        let start = std::time::Instant::now();
        let mut failed = None;
        session.render(camera, &opts, |p| {
            // The newest of the waiting cameras replaces this render.
            for command in commands.try_iter() {
                match command {
                    ToRenderer::Camera { generation, camera } => next = Some((generation, camera)),
                    ToRenderer::Quit => quit = true,
                }
            }
            if quit || next.is_some() {
                return ControlFlow::Break(());
            }
            let image = match p.image() {
                Ok(image) => image,
                Err(e) => {
                    failed = Some(e);
                    return ControlFlow::Break(());
                }
            };
            let pixels = image
                .to_srgb8_with(&look)
                .chunks_exact(4)
                .map(|c| u32::from_be_bytes([0, c[0], c[1], c[2]]))
                .collect();
            let frame = Frame {
                generation,
                pixels,
                samples: p.samples(),
                seconds: start.elapsed().as_secs_f64(),
            };
            // The event loop is gone: the window was closed.
            if proxy.send_event(FromRenderer::Frame(frame)).is_err() {
                quit = true;
                return ControlFlow::Break(());
            }
            ControlFlow::Continue(())
        })?;
        if let Some(e) = failed {
            return Err(e.into());
        }
        if quit {
            return Ok(());
        }
    }
}

/// An orbit camera: an eye circling a target, with a fixed up direction.
#[derive(Clone, Copy)]
struct Orbit {
    eye: Vec3,
    target: Vec3,
    up: Vec3,
    yfov: f32,
}

impl Orbit {
    /// The orbit of the camera `frame`, around the point of its view axis nearest `pivot`.
    fn new(frame: &oxray_render::programs::CameraFrame, pivot: Option<Vec3>) -> Orbit {
        let eye = frame.origin;
        let forward = frame.forward.normalize_or(Vec3::NEG_Z);
        // A pivot behind the camera would orbit it away from the view: use one unit ahead.
        let distance = pivot
            .map(|p| (p - eye).dot(forward))
            .filter(|d| d.is_finite() && *d > 1e-4)
            .unwrap_or(1.0);
        let camera_up = frame.up.normalize_or(Vec3::Y);
        let up = if forward.cross(Vec3::Y).length() > 1e-2 {
            Vec3::Y
        } else {
            camera_up
        };
        Orbit {
            eye,
            target: eye + forward * distance,
            up,
            yfov: 2.0 * frame.up.length().atan(),
        }
    }

    fn camera(&self) -> Camera {
        Camera {
            to_world: Camera::to_world_looking_at(self.eye, self.target, self.up),
            yfov: self.yfov,
            aspect: None,
            node: None,
        }
    }

    /// Turns the eye around the target by `yaw` about the up direction and `pitch` about the
    /// camera's right, never over the poles (where the view would flip).
    fn orbit(&mut self, yaw: f32, pitch: f32) {
        let offset = self.eye - self.target;
        let turned = glam::Quat::from_axis_angle(self.up, yaw) * offset;
        let right = (-turned).cross(self.up).normalize_or_zero();
        let tilted = glam::Quat::from_axis_angle(right, pitch) * turned;
        let offset = if right != Vec3::ZERO && tilted.normalize().dot(self.up).abs() < 0.995 {
            tilted
        } else {
            turned
        };
        self.eye = self.target + offset;
    }

    /// Moves the eye towards the target (positive `steps`) or away, by a factor per step.
    fn dolly(&mut self, steps: f32) {
        let offset = (self.eye - self.target) * (-0.1 * steps).exp();
        if offset.length() > 1e-5 {
            self.eye = self.target + offset;
        }
    }

    /// Moves eye and target across the view by `dx`, `dy` pixels of an image `height` high,
    /// so that the point at the target's depth follows the cursor.
    fn pan(&mut self, dx: f32, dy: f32, height: u32) {
        let forward = (self.target - self.eye).normalize_or_zero();
        let right = forward.cross(self.up).normalize_or_zero();
        let up = right.cross(forward);
        let per_pixel =
            2.0 * (self.target - self.eye).length() * (0.5 * self.yfov).tan() / height as f32;
        let shift = (-dx * right + dy * up) * per_pixel;
        self.eye += shift;
        self.target += shift;
    }
}

struct WindowState {
    window: Rc<Window>,
    surface: softbuffer::Surface<Rc<Window>, Rc<Window>>,
}

struct App {
    name: String,
    width: u32,
    height: u32,
    total: u32,
    screenshot: Option<PathBuf>,
    window: Option<WindowState>,
    /// The image the window shows (`0RGB`, `width` x `height`), what screenshots write.
    framebuffer: Vec<u32>,
    /// Samples and seconds of the frame shown.
    shown: Option<(u32, f64)>,
    generation: u64,
    orbit: Orbit,
    home: Orbit,
    /// Left, right and middle mouse buttons held.
    buttons: [bool; 3],
    cursor: Option<PhysicalPosition<f64>>,
    to_renderer: mpsc::Sender<ToRenderer>,
    result: Result<()>,
}

impl App {
    fn fail(&mut self, event_loop: &ActiveEventLoop, error: anyhow::Error) {
        if self.result.is_ok() {
            self.result = Err(error);
        }
        event_loop.exit();
    }

    fn open(&self, event_loop: &ActiveEventLoop) -> Result<WindowState> {
        let attributes = Window::default_attributes()
            .with_title(format!("oxray view: {}", self.name))
            .with_inner_size(PhysicalSize::new(self.width, self.height))
            .with_resizable(false);
        let window = Rc::new(
            event_loop
                .create_window(attributes)
                .map_err(|e| anyhow::anyhow!("cannot open a window: {e}"))?,
        );
        let context = softbuffer::Context::new(window.clone())
            .map_err(|e| anyhow::anyhow!("cannot draw on the display: {e}"))?;
        let surface = softbuffer::Surface::new(&context, window.clone())
            .map_err(|e| anyhow::anyhow!("cannot draw in the window: {e}"))?;
        Ok(WindowState { window, surface })
    }

    /// Copies the framebuffer into the window (its top-left corner, should the window manager
    /// have given it another size) and shows it.
    fn draw(&mut self) -> Result<()> {
        let Some(state) = &mut self.window else {
            return Ok(());
        };
        let size = state.window.inner_size();
        let (Some(sw), Some(sh)) = (NonZeroU32::new(size.width), NonZeroU32::new(size.height))
        else {
            return Ok(());
        };
        state
            .surface
            .resize(sw, sh)
            .map_err(|e| anyhow::anyhow!("cannot draw in the window: {e}"))?;
        let mut buffer = state
            .surface
            .buffer_mut()
            .map_err(|e| anyhow::anyhow!("cannot draw in the window: {e}"))?;
        let (sw, sh) = (size.width as usize, size.height as usize);
        let (w, h) = (self.width as usize, self.height as usize);
        for y in 0..sh {
            let row = &mut buffer[y * sw..(y + 1) * sw];
            if y < h {
                let n = w.min(sw);
                row[..n].copy_from_slice(&self.framebuffer[y * w..y * w + n]);
                row[n..].fill(0);
            } else {
                row.fill(0);
            }
        }
        buffer
            .present()
            .map_err(|e| anyhow::anyhow!("cannot draw in the window: {e}"))
    }

    fn title(&self) -> String {
        match self.shown {
            Some((samples, seconds)) => {
                let rate =
                    self.width as f64 * self.height as f64 * samples as f64 / seconds.max(1e-9);
                format!(
                    "oxray view: {}: {samples}/{} spp, {:.2} M samples/s",
                    self.name,
                    self.total,
                    rate / 1e6
                )
            }
            None => format!("oxray view: {}: rendering", self.name),
        }
    }

    /// Starts the render again from the orbit camera (`home` from the scene's own camera).
    fn restart(&mut self, home: bool) {
        self.generation += 1;
        let camera = (!home).then(|| self.orbit.camera());
        let _ = self.to_renderer.send(ToRenderer::Camera {
            generation: self.generation,
            camera,
        });
    }

    /// `S`: the framebuffer to a new PNG in the current directory.
    fn save(&self) {
        let png = match encode_png(self.width, self.height, &self.framebuffer) {
            Ok(png) => png,
            Err(e) => return eprintln!("warning: cannot save a screenshot: {e:#}"),
        };
        match write_new(&self.name, &png) {
            Ok(path) => println!("wrote {}", path.display()),
            Err(e) => eprintln!("warning: cannot save a screenshot: {e:#}"),
        }
    }

    fn input(&mut self, event_loop: &ActiveEventLoop, event: &WindowEvent) {
        match event {
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => {
                match &event.logical_key {
                    Key::Named(NamedKey::Escape) => event_loop.exit(),
                    Key::Character(c) if c.eq_ignore_ascii_case("q") => event_loop.exit(),
                    Key::Character(c) if c.eq_ignore_ascii_case("r") && !event.repeat => {
                        self.orbit = self.home;
                        self.restart(true);
                    }
                    Key::Character(c) if c.eq_ignore_ascii_case("s") && !event.repeat => {
                        self.save()
                    }
                    _ => {}
                }
            }
            WindowEvent::MouseInput { state, button, .. } => {
                let slot = match button {
                    MouseButton::Left => 0,
                    MouseButton::Right => 1,
                    MouseButton::Middle => 2,
                    _ => return,
                };
                self.buttons[slot] = *state == ElementState::Pressed;
            }
            WindowEvent::CursorMoved { position, .. } => {
                let last = self.cursor.replace(*position);
                let Some(last) = last else { return };
                let (dx, dy) = ((position.x - last.x) as f32, (position.y - last.y) as f32);
                if dx == 0.0 && dy == 0.0 {
                    return;
                }
                // Dragging across the window's height turns the camera half a turn.
                let per_pixel = std::f32::consts::PI / self.height as f32;
                match self.buttons {
                    [true, _, _] => self.orbit.orbit(-dx * per_pixel, -dy * per_pixel),
                    [false, true, _] => self.orbit.dolly(-dy / 20.0),
                    [false, false, true] => self.orbit.pan(dx, dy, self.height),
                    _ => return,
                }
                self.restart(false);
            }
            WindowEvent::CursorLeft { .. } => self.cursor = None,
            WindowEvent::MouseWheel { delta, .. } => {
                let steps = match delta {
                    MouseScrollDelta::LineDelta(_, y) => *y,
                    MouseScrollDelta::PixelDelta(p) => p.y as f32 / 40.0,
                };
                if steps != 0.0 {
                    self.orbit.dolly(steps);
                    self.restart(false);
                }
            }
            _ => {}
        }
    }
}

impl ApplicationHandler<FromRenderer> for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.window.is_some() {
            return;
        }
        match self.open(event_loop) {
            Ok(state) => {
                state.window.set_title(&self.title());
                self.window = Some(state);
            }
            Err(e) => self.fail(event_loop, e),
        }
    }

    fn user_event(&mut self, event_loop: &ActiveEventLoop, event: FromRenderer) {
        let frame = match event {
            FromRenderer::Frame(frame) => frame,
            FromRenderer::Failed(e) => return self.fail(event_loop, anyhow::anyhow!(e)),
        };
        if frame.generation != self.generation || self.window.is_none() {
            return;
        }
        self.framebuffer = frame.pixels;
        self.shown = Some((frame.samples, frame.seconds));
        if let Err(e) = self.draw() {
            return self.fail(event_loop, e);
        }
        if let Some(state) = &self.window {
            state.window.set_title(&self.title());
        }
        if frame.samples < self.total {
            return;
        }
        if let Some(out) = self.screenshot.clone() {
            let written = encode_png(self.width, self.height, &self.framebuffer).and_then(|png| {
                oxray_scene::files::write_atomic(&out, |tmp| std::fs::write(tmp, &png))
                    .with_context(|| format!("cannot write {}", out.display()))
            });
            match written {
                Ok(()) => {
                    println!("wrote {} ({} spp)", out.display(), frame.samples);
                    event_loop.exit();
                }
                Err(e) => self.fail(event_loop, e),
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.draw() {
                    self.fail(event_loop, e);
                }
            }
            // The screenshot is of the scene's own camera: input waits until it is written.
            _ if self.screenshot.is_some() => {}
            other => self.input(event_loop, &other),
        }
    }
}

/// The `0RGB` framebuffer as an 8-bit RGBA PNG marked as oxray's, the bytes `oxray render`
/// writes for the same image.
fn encode_png(width: u32, height: u32, pixels: &[u32]) -> Result<Vec<u8>> {
    let rgba: Vec<u8> = pixels
        .iter()
        .flat_map(|p| {
            let [_, r, g, b] = p.to_be_bytes();
            [r, g, b, 255]
        })
        .collect();
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, width, height);
    enc.set_color(png::ColorType::Rgba);
    enc.set_depth(png::BitDepth::Eight);
    let (key, text) = oxray_render::output::PNG_SOFTWARE;
    enc.add_text_chunk(key.into(), text.into())?;
    let mut writer = enc.write_header()?;
    writer.write_image_data(&rgba)?;
    writer.finish()?;
    Ok(out)
}

/// Writes `bytes` to the first free `NAME.view-N.png` of the current directory. The file is
/// written whole under a temporary name and then linked to its name, which fails rather than
/// replace a file that appeared meanwhile.
fn write_new(name: &str, bytes: &[u8]) -> Result<PathBuf> {
    for n in 1..100_000u32 {
        let path = PathBuf::from(format!("{name}.view-{n}.png"));
        if path.symlink_metadata().is_ok() {
            continue;
        }
        let tmp = PathBuf::from(format!(".{name}.view-{n}.png.{}.tmp", std::process::id()));
        let linked = write_synced(&tmp, bytes).and_then(|_| std::fs::hard_link(&tmp, &path));
        let _ = std::fs::remove_file(&tmp);
        match linked {
            Ok(()) => return Ok(path),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e).with_context(|| format!("cannot write {}", path.display())),
        }
    }
    bail!("no free file name {name}.view-N.png in the current directory")
}

fn write_synced(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    let mut file = std::fs::File::create(path)?;
    file.write_all(bytes)?;
    file.sync_all()
}
