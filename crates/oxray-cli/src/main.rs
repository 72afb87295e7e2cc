//! `oxray`: the command-line tool.

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use glam::Vec3;
use oxray_cli::bench;
use oxray_render::lights::Environment;
use oxray_render::RenderOptions;
use oxray_scene::mesh::Mesh;
use oxray_scene::SceneDesc;
use std::path::{Path, PathBuf};

mod render_device;
mod view;

#[derive(Parser)]
#[command(
    name = "oxray",
    version,
    about = "oxray: a programmable ray-tracing engine",
    after_help = LIMITS_HELP
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene file to an image with the path tracer.
    ///
    /// Scenes: glTF 2.0 (.gltf, .glb), OBJ (+MTL) or PLY. Without SCENE, the built-in Cornell
    /// box. Ctrl-C stops after the pass in flight and writes the samples done.
    Render(Box<RenderArgs>),
    /// Preview a scene in a window, rendered progressively; the mouse moves the camera.
    ///
    /// Scenes as for render (the built-in Cornell box without SCENE). Each pass adds a sample
    /// per pixel until --spp; any camera move starts again. Left-drag orbits the camera around
    /// its target, right-drag or the wheel dollies, middle-drag pans; R resets the camera, S
    /// saves the window's image to a new PNG in the current directory, Esc or Q quits. With
    /// --screenshot, renders --frames passes, writes the window's image and exits. Needs an
    /// X11 or Wayland display.
    View(Box<ViewArgs>),
    /// Cast a file of rays at a mesh and write the hits.
    ///
    /// Rays are little-endian `f32[8]`: ox, oy, oz, tmin, dx, dy, dz, tmax. Hits are f32 t,
    /// u32 primitive, f32 u, f32 v (t = +inf and primitive 0xFFFFFFFF on a miss) or, with
    /// --occlusion, one u32 0/1 per ray. Primitive indices are triangles in file order
    /// (polygons fan-triangulated, strips unrolled, glTF meshes flattened node by node).
    Raycast {
        /// The mesh or scene (.obj, .ply, .gltf, .glb).
        mesh: PathBuf,
        /// The ray file.
        #[arg(long)]
        rays: PathBuf,
        /// Where to write the results (replaced atomically; never the mesh or the ray file).
        #[arg(long, short)]
        out: PathBuf,
        /// Any hit instead of closest hit.
        #[arg(long, conflicts_with_all = ["count", "all_hits"])]
        occlusion: bool,
        /// How many primitives each ray crosses: one u32 per ray.
        #[arg(long, conflicts_with = "all_hits")]
        count: bool,
        /// Every primitive each ray crosses (LiDAR returns), the nearest N of them.
        ///
        /// One record of 8 + 16 N bytes per ray: u32 hits listed, u32 1 if no hit was left out,
        /// then N hit records (t, primitive, u, v, nearest first; misses after the last).
        #[arg(long, value_name = "N")]
        all_hits: Option<usize>,
        /// Worker threads (default: all cores).
        #[arg(short = 't', long)]
        threads: Option<usize>,
        /// The device that builds and traces: cpu, cuda, cuda:N or auto.
        ///
        /// cuda is GPU 0, auto a GPU where there is one (else the CPU). Asking for CUDA without
        /// one is an error.
        #[arg(long, default_value = "cpu", value_parser = oxray_cli::device::parse_backend)]
        backend: String,
    },
    /// The closest point of a mesh's surface to every point of a file, and its distance.
    ///
    /// Points are little-endian `f32[3]`. Each result is 20 bytes: f32 distance (signed with
    /// --signed: negative inside a closed mesh), f32 x, y, z of the closest point, u32
    /// triangle; none (a non-finite point, an empty mesh) is +inf, NaN and 0xFFFFFFFF.
    Closest {
        /// The mesh or scene (.obj, .ply, .gltf, .glb).
        mesh: PathBuf,
        /// The point file.
        #[arg(long)]
        points: PathBuf,
        /// Where to write the results (replaced atomically; never an input).
        #[arg(long, short)]
        out: PathBuf,
        /// Signed distances: negative inside a closed, consistently wound mesh.
        #[arg(long)]
        signed: bool,
        /// Worker threads (default: all cores).
        #[arg(short = 't', long)]
        threads: Option<usize>,
        /// The device that builds and answers: cpu, cuda, cuda:N or auto.
        #[arg(long, default_value = "cpu", value_parser = oxray_cli::device::parse_backend)]
        backend: String,
    },
    /// Triangle and instance counts and BVH statistics of a mesh or scene.
    ///
    /// For glTF, one GAS per mesh and an IAS over the node placements, as the renderer builds
    /// them.
    Info {
        /// The mesh or scene (.obj, .ply, .gltf, .glb).
        mesh: PathBuf,
    },
    /// Build time and Mrays/s on meshes.
    ///
    /// Primary (camera) and diffuse (hemisphere) rays with closest and any hit, and shadow rays
    /// to a point light. Without MESH, the bunny and igea from ../shared/data when present,
    /// else a generated icosphere.
    Bench {
        /// Meshes (.obj, .ply).
        meshes: Vec<PathBuf>,
        /// Worker threads (default: all cores).
        #[arg(short = 't', long)]
        threads: Option<usize>,
        /// Rays per set are SIDE x SIDE.
        #[arg(long, default_value_t = 1024)]
        side: u32,
        /// Repetitions of each measurement (the median is reported).
        #[arg(long, default_value_t = 5)]
        runs: usize,
        /// Also write each mesh, its rays and oxray's answers into this folder.
        ///
        /// For scripts/bench_embree.py and scripts/embree3_bench.c.
        #[arg(long)]
        export: Option<PathBuf>,
        /// The build preset the rays trace: default, fast-build, fast-trace or fast-trace-binned.
        ///
        /// The structure the ray columns trace (and --export answers with): default,
        /// fast-build (PREFER_FAST_BUILD), fast-trace (PREFER_FAST_TRACE, with spatial splits)
        /// or fast-trace-binned (PREFER_FAST_TRACE without spatial splits).
        #[arg(long, default_value = "default")]
        build: String,
        /// Also build an IAS of this many instances of the first mesh and trace through it, on
        /// the device of --backend.
        #[arg(long)]
        instances: Option<usize>,
        /// Split every triangle into 4^K first (a large mesh of a real shape).
        ///
        /// Each triangle of each mesh is split at its edges' midpoints K times: the same
        /// surface with K more levels of triangles.
        #[arg(long, value_name = "K", default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=6))]
        subdivide: u32,
        /// The device measured next to the CPU: cpu, cuda, cuda:N or auto.
        ///
        /// cpu: the CPU table. cuda, cuda:N, auto: the same ray sets on that device next to
        /// the CPU, with hit agreement (asking for CUDA without one is an error).
        #[arg(long, default_value = "cpu", value_parser = oxray_cli::device::parse_backend)]
        backend: String,
        /// With --backend cuda: time GAS builds on the device against the host's builder.
        ///
        /// Instead of the query table: per preset, kernel and end-to-end ms, SAH cost, and
        /// closest-hit Mrays/s through each tree.
        #[arg(long)]
        gas_builds: bool,
        /// Time the simulation queries instead: closest points, signed distances, all hits, counts.
        ///
        /// SIDE x SIDE points and rays per mesh, on the CPU and (with --backend cuda) on the
        /// device beside it, with the share of identical results.
        #[arg(long)]
        simulation: bool,
    },
    /// Print a shell completion script (bash, zsh, fish, elvish or powershell).
    ///
    /// For bash: `oxray completions bash > ~/.local/share/bash-completion/completions/oxray`.
    Completions {
        /// The shell.
        shell: clap_complete::Shell,
    },
}

/// The options of `oxray render`.
#[derive(clap::Args)]
struct RenderArgs {
    /// The scene file; omit for the built-in Cornell box.
    scene: Option<PathBuf>,
    /// Output image: .png (tone-mapped sRGB) or .exr (linear).
    ///
    /// An existing file is replaced (atomically), but never one the render reads. Default:
    /// NAME.oxray.png in the current directory, NAME being the scene file's name without
    /// extension (cornell without a scene); an existing file of that name is replaced only
    /// if oxray wrote it.
    #[arg(short, long)]
    output: Option<PathBuf>,
    /// Image size, WxH.
    #[arg(long, default_value = "512x512")]
    size: String,
    /// Samples per pixel.
    #[arg(long, default_value_t = 64)]
    spp: u32,
    /// Path vertices at most.
    #[arg(long, default_value_t = 8)]
    max_depth: u32,
    /// Worker threads (default: all cores).
    #[arg(short = 't', long)]
    threads: Option<usize>,
    /// Which of the scene's cameras to use (default: the first, else one framing the scene).
    #[arg(long)]
    camera: Option<usize>,
    #[command(flatten)]
    aim: CameraOverride,
    /// Environment light: sky, none, a grey level, or an .hdr/.exr map.
    ///
    /// "sky" is a procedural daylight (the default for scene files), "none" is black (the
    /// default for the Cornell box), a number such as "0.5" a constant grey, and a .hdr or
    /// .exr file an equirectangular map.
    #[arg(long)]
    env: Option<String>,
    /// Multiplies the environment's radiance.
    #[arg(long, default_value_t = 1.0)]
    env_intensity: f32,
    /// Exposure in stops applied before tone mapping (PNG only; EXR stays linear).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    exposure: f32,
    /// Tone curve of a PNG: aces, neutral or linear.
    ///
    /// "aces": Hill's ACES fit, radiance divided by 0.6 first (mid-grey 0.18 becomes
    /// 127/255). "neutral": Khronos PBR Neutral (colours below 0.76 kept, mid-grey
    /// 105/255). "linear": clamped (mid-grey 118/255).
    #[arg(long, default_value = "aces")]
    tonemap: String,
    /// Pixel filter: gaussian, blackman-harris or box.
    ///
    /// Applied by filter importance sampling: "gaussian" (sigma 0.5 pixel, radius 1.5),
    /// "blackman-harris" (radius 1.5) or "box" (the pixel's square).
    #[arg(long, default_value = "gaussian")]
    filter: String,
    /// Put the scene on a large grey ground plane.
    #[arg(long)]
    ground: bool,
    /// Seed of the random sequence.
    ///
    /// The same seed gives the same image, another seed an independent one.
    #[arg(long, default_value_t = 0)]
    seed: u32,
    /// Random numbers: sobol or independent.
    ///
    /// "sobol": Owen-scrambled Sobol points per pixel, one dimension per use (pixel offset,
    /// time, each bounce's light and BSDF samples and Russian roulette), lower noise at equal
    /// samples. "independent": independent hash-based random numbers.
    #[arg(long, default_value = "sobol")]
    sampler: String,
    /// Stop after this many seconds (at the end of a pass) and write the samples done.
    #[arg(long, value_name = "SECONDS")]
    time: Option<f64>,
    /// Write the image so far every SECONDS while rendering (replaced atomically).
    #[arg(long, value_name = "SECONDS")]
    checkpoint: Option<f64>,
    /// Render only the pixels X0..X1, Y0..Y1 of the image (X1 and Y1 excluded).
    ///
    /// The output has the window's size and each of its pixels is the same pixel of the
    /// full --size render, bit for bit (same camera, same random numbers); row 0 is the top.
    #[arg(long, value_name = "X0,Y0,X1,Y1")]
    crop: Option<String>,
    /// Motion blur: the shutter is open from OPEN to CLOSE seconds of the scene's animation.
    ///
    /// Each camera ray takes a time in the interval, and the glTF animation (translation,
    /// rotation and scale of nodes) moves the instances during it. OPEN = CLOSE renders the
    /// pose at that time without blur. Every backend renders it.
    #[arg(long, value_name = "OPEN,CLOSE")]
    shutter: Option<String>,
    /// Which of the scene's animations --shutter plays (0: the first).
    #[arg(long, value_name = "N", default_value_t = 0, requires = "shutter")]
    animation: usize,
    /// Also write AOVs (albedo, normal, depth, samples) as layers of the .exr output.
    ///
    /// The first hit's albedo, shading normal, distance and sample count, as the layers
    /// albedo.RGB, normal.XYZ, depth.Z and samples.Y of the output (an .exr file).
    #[arg(long)]
    aov: bool,
    /// Denoise the image (Open Image Denoise, guided by the first hit's albedo and normal).
    ///
    /// The render also computes the albedo and normal AOVs, and the output (PNG or EXR) is the
    /// denoised image; with --aov the .exr also keeps the noisy image as the layer noisy.RGB.
    /// Checkpoint images (--checkpoint) are not denoised. Needs OIDN's library: install it
    /// with scripts/setup-oidn.sh, or name it (or its folder) with OXRAY_OIDN_LIB.
    #[arg(long)]
    denoise: bool,
    /// No progress bar.
    #[arg(short, long)]
    quiet: bool,
    /// Which path tracer on which device: cpu, cpu-cxx, cuda, cuda:N or auto.
    ///
    /// cpu: the path tracer's Rust programs on the CPU (a wavefront of paths over the batched
    /// queries; through the CPU pipeline for scenes with motion). cpu-cxx: its CUDA C++ programs on
    /// the CPU (compiled by the host's C++ compiler). cuda, cuda:N: the CUDA C++ programs on
    /// that GPU (asking for one this machine lacks is an error). auto: a GPU where there is
    /// one, else cpu.
    #[arg(long, default_value = "cpu", value_parser = render_device::parse)]
    backend: String,
}

/// The options of `oxray view`.
#[derive(clap::Args)]
struct ViewArgs {
    /// The scene file; omit for the built-in Cornell box.
    scene: Option<PathBuf>,
    /// Window (and image) size, WxH.
    #[arg(long, default_value = "512x512")]
    size: String,
    /// Samples per pixel at most: the preview stops refining there.
    #[arg(long, default_value_t = 4096)]
    spp: u32,
    /// Path vertices at most.
    #[arg(long, default_value_t = 8)]
    max_depth: u32,
    /// Worker threads (default: all cores).
    #[arg(short = 't', long)]
    threads: Option<usize>,
    /// Which of the scene's cameras to start from (default: the first, else one framing the
    /// scene).
    #[arg(long)]
    camera: Option<usize>,
    #[command(flatten)]
    aim: CameraOverride,
    /// Environment light: sky, none, a grey level, or an .hdr/.exr map (as for render).
    #[arg(long)]
    env: Option<String>,
    /// Multiplies the environment's radiance.
    #[arg(long, default_value_t = 1.0)]
    env_intensity: f32,
    /// Exposure in stops applied before tone mapping.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    exposure: f32,
    /// Tone curve: aces, neutral or linear (as for render).
    #[arg(long, default_value = "aces")]
    tonemap: String,
    /// Pixel filter: gaussian, blackman-harris or box.
    #[arg(long, default_value = "gaussian")]
    filter: String,
    /// Put the scene on a large grey ground plane.
    #[arg(long)]
    ground: bool,
    /// Seed of the random sequence (the same seed gives render's image).
    #[arg(long, default_value_t = 0)]
    seed: u32,
    /// Random numbers: sobol or independent.
    #[arg(long, default_value = "sobol")]
    sampler: String,
    /// Which path tracer on which device: cpu, cpu-cxx, cuda, cuda:N or auto (as for render).
    #[arg(long, default_value = "cpu", value_parser = render_device::parse)]
    backend: String,
    /// Render --frames passes, write the window's image to this PNG and exit.
    ///
    /// The file holds the pixels the window shows (replaced atomically; never a file the
    /// scene reads). Mouse and keys are ignored meanwhile. For scripts and tests.
    #[arg(long, value_name = "OUT.png")]
    screenshot: Option<PathBuf>,
    /// With --screenshot: the passes (samples per pixel) before the image is written
    /// (default: --spp).
    #[arg(long, value_name = "N", requires = "screenshot")]
    frames: Option<u32>,
}

const LIMITS_HELP: &str = "Limits (checked before allocating; raise them with these environment variables): input files up to OXRAY_MAX_FILE_MB (default 2048), one decoded image up to OXRAY_MAX_IMAGE_MB (256), a scene's textures up to OXRAY_MAX_TEXTURES_MB (1024), geometry flattened for raycast up to OXRAY_MAX_GEOMETRY_MB (2048), ray files up to OXRAY_MAX_RAYS rays (33554432).";

fn main() {
    // A panic inside a guarded decoder is reported as an ordinary error; any other is a bug,
    // reported in one line.
    std::panic::set_hook(Box::new(|info| {
        if oxray_scene::files::in_guarded_code() {
            return;
        }
        let msg = info
            .payload()
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| info.payload().downcast_ref::<String>().cloned())
            .unwrap_or_default();
        let at = info
            .location()
            .map(|l| format!(" at {}:{}", l.file(), l.line()))
            .unwrap_or_default();
        eprintln!(
            "error: internal error (a bug in oxray): {}{at}",
            msg.lines().next().unwrap_or("")
        );
    }));
    let cli = Cli::parse();
    let result = oxray_scene::files::Limits::from_env()
        .map_err(anyhow::Error::msg)
        .and_then(|_| run(cli));
    if let Err(e) = result {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

/// Prints a line on standard output. A closed pipe (`oxray info f | head -0`) ends the program
/// quietly with status 0, as Unix tools do; another write error (a full disk) is an error.
/// Parses `X,Y,Z` into a finite vector.
fn parse_vec3(text: &str) -> Result<Vec3, String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let values: Option<Vec<f32>> = parts.iter().map(|p| p.parse::<f32>().ok()).collect();
    match values.as_deref() {
        Some(&[x, y, z]) if x.is_finite() && y.is_finite() && z.is_finite() => {
            Ok(Vec3::new(x, y, z))
        }
        _ => Err(format!("expected three finite numbers X,Y,Z, got {text:?}")),
    }
}

/// `--look-from`, `--look-at`, `--up` and `--fov`: a camera made from the chosen one (the
/// options of `render` and `view`).
#[derive(clap::Args, Clone, Copy)]
struct CameraOverride {
    /// Put the camera at X,Y,Z (world space; default: where the chosen camera is).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    look_from: Option<Vec3>,
    /// Aim the camera at X,Y,Z.
    ///
    /// Default: the scene's centre with --look-from, else where the chosen camera looks.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    look_at: Option<Vec3>,
    /// The camera's up direction (default: +Y).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    up: Option<Vec3>,
    /// Vertical field of view in degrees (default: the chosen camera's).
    #[arg(long, value_name = "DEGREES")]
    fov: Option<f32>,
}

impl CameraOverride {
    /// Puts the camera these options make from the one `opts` chooses first among the scene's
    /// cameras and makes `opts` use it; nothing without them.
    fn apply(&self, desc: &mut SceneDesc, opts: &mut RenderOptions) -> Result<()> {
        if self.look_from.is_none()
            && self.look_at.is_none()
            && self.up.is_none()
            && self.fov.is_none()
        {
            return Ok(());
        }
        let chosen = oxray_render::camera_frame(desc, opts)?;
        desc.cameras
            .insert(0, self.camera(&chosen, desc.content_bounds())?);
        opts.camera = Some(0);
        Ok(())
    }

    fn camera(
        &self,
        chosen: &oxray_render::programs::CameraFrame,
        bounds: Option<(Vec3, Vec3)>,
    ) -> Result<oxray_scene::Camera> {
        let eye = self.look_from.unwrap_or(chosen.origin);
        let target = match (self.look_at, self.look_from, bounds) {
            (Some(t), _, _) => t,
            (None, Some(_), Some((lo, hi))) => (lo + hi) * 0.5,
            _ => chosen.origin + chosen.forward,
        };
        let forward = target - eye;
        if forward.length() <= 1e-6 * eye.length().max(1.0) {
            bail!("--look-from and --look-at must be different points");
        }
        let up = match self.up {
            Some(u) => u,
            None if self.look_from.is_none() && self.look_at.is_none() => chosen.up,
            None => Vec3::Y,
        };
        if forward.normalize().cross(up.normalize_or_zero()).length() < 1e-3 {
            bail!("--up must not be parallel to the viewing direction (or zero), got {up}");
        }
        let yfov = match self.fov {
            Some(f) if f.is_finite() && f > 0.0 && f < 170.0 => f.to_radians(),
            Some(f) => bail!("--fov must be in (0, 170) degrees, got {f}"),
            None => 2.0 * chosen.up.length().atan(),
        };
        Ok(oxray_scene::Camera {
            to_world: oxray_scene::Camera::to_world_looking_at(eye, target, up),
            yfov,
            aspect: None,
            node: None,
        })
    }
}

fn say(line: impl std::fmt::Display) -> Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match writeln!(out, "{line}").and_then(|_| out.flush()) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => std::process::exit(0),
        Err(e) => Err(anyhow::anyhow!("cannot write to standard output: {e}")),
    }
}

/// The default image of `oxray render`: `NAME.oxray.png` in the current directory, NAME being
/// the scene file's name without its extension (`cornell` for the built-in scene). The
/// `.oxray` part keeps it from ever being one of the scene's own textures.
fn default_output(scene: Option<&Path>) -> PathBuf {
    let stem = scene
        .and_then(|p| p.file_stem())
        .map_or("cornell".into(), |s| s.to_string_lossy().into_owned());
    PathBuf::from(format!("{stem}.oxray.png"))
}

/// `--size WxH` of `render` and `view`.
fn parse_size(size: &str) -> Result<(u32, u32)> {
    let (w, h) = size
        .split_once('x')
        .and_then(|(w, h)| Some((w.parse::<u32>().ok()?, h.parse::<u32>().ok()?)))
        .filter(|&(w, h)| w > 0 && h > 0 && w <= 16384 && h <= 16384)
        .with_context(|| format!("--size must be WxH within 1..=16384, got {size:?}"))?;
    // The accumulation buffer takes 16 bytes a pixel: keep it within 1 GiB.
    if w as u64 * h as u64 > 1 << 26 {
        bail!("--size {w}x{h} has more than 2^26 pixels (about 8192x8192); render tiles of it instead");
    }
    Ok((w, h))
}

/// `--tonemap` and `--exposure` of `render` and `view`.
fn parse_look(tonemap: &str, exposure: f32) -> Result<oxray_render::tonemap::Look> {
    if !(exposure.is_finite() && exposure.abs() <= 32.0) {
        bail!("--exposure must be within -32..=32 stops, got {exposure}");
    }
    let tone_map: oxray_render::tonemap::ToneMap = tonemap
        .parse()
        .map_err(|e| anyhow::anyhow!("--tonemap: {e}"))?;
    Ok(oxray_render::tonemap::Look { tone_map, exposure })
}

fn check_env_intensity(env_intensity: f32) -> Result<()> {
    if !(env_intensity.is_finite() && env_intensity >= 0.0) {
        bail!("--env-intensity must be a finite number >= 0, got {env_intensity}");
    }
    Ok(())
}

/// The file `--env` reads, if it names one (rather than sky, none or a grey level).
fn environment_file(env: Option<&str>) -> Option<PathBuf> {
    env.filter(|e| !matches!(*e, "sky" | "none") && e.parse::<f32>().is_err())
        .map(PathBuf::from)
}

/// The environment light `--env` names, scaled by `--env-intensity`.
fn environment(env: &str, env_intensity: f32) -> Result<Environment> {
    Ok(match env {
        "sky" => Environment::sky(env_intensity),
        "none" => Environment::uniform(Vec3::ZERO),
        other => match other.parse::<f32>() {
            Ok(v) if v.is_finite() && v >= 0.0 => {
                Environment::uniform(Vec3::splat(v * env_intensity))
            }
            _ => Environment::load(Path::new(other), env_intensity).map_err(anyhow::Error::msg)?,
        },
    })
}

fn default_meshes() -> Vec<PathBuf> {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/meshes");
    ["stanford-bunny.obj", "igea.ply"]
        .iter()
        .map(|f| data.join(f))
        .filter(|p| p.exists())
        .collect()
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Completions { shell } => {
            use clap::CommandFactory;
            let mut out = Vec::new();
            clap_complete::generate(shell, &mut Cli::command(), "oxray", &mut out);
            say(String::from_utf8_lossy(&out).trim_end())
        }
        Command::Render(args) => {
            let RenderArgs {
                scene,
                output,
                size,
                spp,
                max_depth,
                threads,
                camera,
                aim,
                env,
                env_intensity,
                exposure,
                tonemap,
                filter,
                ground,
                seed,
                sampler,
                time,
                checkpoint,
                crop,
                shutter,
                animation,
                aov,
                denoise,
                quiet,
                backend,
            } = *args;
            let (w, h) = parse_size(&size)?;
            let crop = match crop {
                Some(text) => {
                    let window: oxray_render::crop::CropWindow =
                        text.parse().map_err(|e| anyhow::anyhow!("--crop: {e}"))?;
                    window
                        .check(w, h)
                        .map_err(|e| anyhow::anyhow!("--crop: {e} (--size {w}x{h})"))?;
                    Some(window)
                }
                None => None,
            };
            let shutter = match shutter {
                Some(text) => Some(
                    text.parse::<oxray_render::motion::Shutter>()
                        .map_err(|e| anyhow::anyhow!("--shutter: {e}"))?,
                ),
                None => None,
            };
            if spp == 0 || spp > 1 << 16 {
                bail!("--spp must be in 1..=65536, got {spp}");
            }
            let look = parse_look(&tonemap, exposure)?;
            let filter: oxray_render::filter::Filter = filter
                .parse()
                .map_err(|e| anyhow::anyhow!("--filter: {e}"))?;
            let sampler: oxray_render::Sampler = sampler
                .parse()
                .map_err(|e| anyhow::anyhow!("--sampler: {e}"))?;
            let checkpoint = match checkpoint {
                Some(t) if t.is_finite() && t > 0.0 && t <= 1e7 => {
                    Some(std::time::Duration::from_secs_f64(t))
                }
                Some(t) => bail!("--checkpoint must be a number of seconds in (0, 1e7], got {t}"),
                None => None,
            };
            let budget = match time {
                Some(t) if t.is_finite() && t > 0.0 && t <= 1e7 => {
                    Some(std::time::Duration::from_secs_f64(t))
                }
                Some(t) => bail!("--time must be a number of seconds in (0, 1e7], got {t}"),
                None => None,
            };
            check_env_intensity(env_intensity)?;
            let named = output.is_some();
            let output = output.unwrap_or_else(|| default_output(scene.as_deref()));
            let ext = oxray_scene::file_extension(&output);
            if aov && ext.as_deref() != Some("exr") {
                bail!(
                    "--aov writes layers of an OpenEXR file: name an .exr output, not {}",
                    output.display()
                );
            }
            if !matches!(ext.as_deref(), Some("png") | Some("exr")) {
                bail!(
                    "cannot write {}: unknown image format (expected .png or .exr)",
                    output.display()
                );
            }
            // Checked before any work: the output is none of the inputs and its folder takes
            // a new file; a default name never replaces a file oxray did not write.
            let env_file = environment_file(env.as_deref());
            let inputs: Vec<&Path> = scene.iter().chain(&env_file).map(|p| p.as_path()).collect();
            oxray_scene::files::check_output(&output, &inputs).map_err(anyhow::Error::msg)?;
            if !named && output.exists() && !oxray_render::output::written_by_oxray(&output) {
                bail!(
                    "{} exists and was not written by oxray; name it with -o to replace it, or choose another name",
                    output.display()
                );
            }
            // Loaded before any work, so that a missing library costs no render.
            let denoiser = denoise
                .then(oxray_render::denoise::Denoiser::new)
                .transpose()
                .map_err(|e| anyhow::anyhow!("--denoise: {e}"))?;
            let renderer = render_device::open(&backend)?;
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads.unwrap_or(0))
                .build()
                .context("cannot start the worker threads")?;
            let start = std::time::Instant::now();
            let (mut desc, default_env) = match &scene {
                Some(path) => (pool.install(|| SceneDesc::load(path))?, "sky"),
                None => (oxray_scene::cornell_box(), "none"),
            };
            if let Some(read) = desc
                .sources
                .iter()
                .find(|r| oxray_scene::files::same_file(&output, r))
            {
                bail!(
                    "{} is read by the scene ({}); choose another output file",
                    output.display(),
                    read.display()
                );
            }
            if ground {
                desc.add_ground();
            }
            // One render and no edits: the meshes placed once are traced as one structure.
            let mut desc = desc.flattened();
            for w in &desc.warnings {
                eprintln!("warning: {w}");
            }
            let environment = environment(env.as_deref().unwrap_or(default_env), env_intensity)?;
            let loaded = start.elapsed().as_secs_f64();
            let mut opts = RenderOptions {
                width: w,
                height: h,
                spp,
                max_depth: max_depth.clamp(1, 64),
                camera,
                filter,
                seed,
                sampler,
                // The denoiser's guides are the AOVs' albedo and normal.
                aovs: aov || denoise,
                crop,
                shutter,
                animation,
                ..Default::default()
            };
            if shutter.is_some() {
                if desc.animations.is_empty() {
                    eprintln!("warning: the scene has no animation: --shutter blurs nothing");
                } else if animation >= desc.animations.len() {
                    bail!(
                        "--animation {animation}: the scene has {} animation{}",
                        desc.animations.len(),
                        if desc.animations.len() == 1 { "" } else { "s" }
                    );
                }
            }
            aim.apply(&mut desc, &mut opts)?;
            let bar = if quiet {
                indicatif::ProgressBar::hidden()
            } else {
                indicatif::ProgressBar::new(spp as u64)
            };
            bar.set_style(
                indicatif::ProgressStyle::with_template(
                    "{elapsed_precise} [{bar:40}] {pos}/{len} spp, ETA {eta}",
                )
                .expect("a valid template")
                .progress_chars("=> "),
            );
            // Ctrl-C (or SIGTERM, SIGHUP) ends the render after the pass in flight and writes
            // the samples done; a second one quits at once.
            let interrupted = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
            {
                let flag = interrupted.clone();
                ctrlc::set_handler(move || {
                    if flag.swap(true, std::sync::atomic::Ordering::SeqCst) {
                        std::process::exit(130);
                    }
                })
                .context("cannot install the interrupt handler")?;
            }
            let render_start = std::time::Instant::now();
            let mut last_checkpoint = render_start;
            let mut checkpoints = 0u32;
            let mut checkpoint_error = None;
            let rendered = pool.install(|| {
                renderer.render(&desc, &environment, &opts, |p| {
                    bar.set_position(p.samples() as u64);
                    let more = p.samples() < p.total();
                    if more && checkpoint.is_some_and(|e| last_checkpoint.elapsed() >= e) {
                        // The image so far replaces the output atomically: the file is a
                        // whole image at every moment.
                        let written = p
                            .image()
                            .map_err(|e| e.to_string())
                            .and_then(|image| image.save_with(&output, &look));
                        if let Err(e) = written {
                            checkpoint_error = Some(e);
                            return std::ops::ControlFlow::Break(());
                        }
                        checkpoints += 1;
                        last_checkpoint = std::time::Instant::now();
                    }
                    let out_of_time = budget.is_some_and(|b| render_start.elapsed() >= b);
                    if out_of_time || interrupted.load(std::sync::atomic::Ordering::SeqCst) {
                        std::ops::ControlFlow::Break(())
                    } else {
                        std::ops::ControlFlow::Continue(())
                    }
                })
            })?;
            if let Some(e) = checkpoint_error {
                bail!("{e}");
            }
            let render_secs = render_start.elapsed().as_secs_f64();
            bar.finish_and_clear();
            let denoise_start = std::time::Instant::now();
            let denoised = match &denoiser {
                Some(d) => Some(
                    d.denoise_rendered(&rendered)
                        .map_err(|e| anyhow::anyhow!("--denoise: {e}"))?,
                ),
                None => None,
            };
            let denoise_secs = denoise_start.elapsed().as_secs_f64();
            match (&denoised, aov) {
                (Some(clean), true) => rendered.save_denoised_exr(&output, clean),
                (Some(clean), false) => clean.save_with(&output, &look),
                (None, true) => rendered.save_exr(&output),
                (None, false) => rendered.image.save_with(&output, &look),
            }
            .map_err(anyhow::Error::msg)?;
            let on = renderer
                .describe()
                .map_or(String::new(), |d| format!(" with {d}"));
            let done = rendered.samples;
            let written = match checkpoints {
                0 => String::new(),
                n => format!(", {n} checkpoint images before"),
            };
            let stopped = written
                + &match (
                    rendered.cancelled,
                    interrupted.load(std::sync::atomic::Ordering::SeqCst),
                ) {
                    (false, _) => String::new(),
                    (true, true) => format!(", interrupted after {done} of {spp} spp"),
                    (true, false) => format!(", out of time after {done} of {spp} spp"),
                };
            let denoised = match &denoiser {
                Some(d) => format!(
                    ", denoised on the {} in {denoise_secs:.2} s",
                    match d.device_type() {
                        oxray_render::denoise::DeviceType::Cuda => "GPU",
                        _ => "CPU",
                    }
                ),
                None => String::new(),
            };
            let (out_w, out_h) = (rendered.image.width, rendered.image.height);
            // Rates of the passes: the setup (structures, tables) is a cost per render, not per
            // sample.
            let setup_secs = rendered.setup.as_secs_f64().min(render_secs);
            let pass_secs = (render_secs - setup_secs).max(1e-9);
            let samples_per_s = out_w as f64 * out_h as f64 * done as f64 / pass_secs;
            let rays_per_s = rendered.rays as f64 / pass_secs;
            let size = match crop {
                Some(c) => format!("{out_w}x{out_h}, pixels {c} of {w}x{h}"),
                None => format!("{w}x{h}"),
            };
            say(format_args!(
                "wrote {} ({size}, {done} spp, {} triangles, {} instances{on}{stopped}{denoised}): loaded in {loaded:.1} s, rendered in {render_secs:.1} s ({:.2} M samples/s, {:.2} Mrays/s after {setup_secs:.3} s of setup), total {:.1} s",
                output.display(),
                desc.triangle_count(),
                desc.instances.len(),
                samples_per_s / 1e6,
                rays_per_s / 1e6,
                start.elapsed().as_secs_f64()
            ))?;
            if rendered.cancelled && interrupted.load(std::sync::atomic::Ordering::SeqCst) {
                std::process::exit(130);
            }
            Ok(())
        }
        Command::View(args) => {
            let ViewArgs {
                scene,
                size,
                spp,
                max_depth,
                threads,
                camera,
                aim,
                env,
                env_intensity,
                exposure,
                tonemap,
                filter,
                ground,
                seed,
                sampler,
                backend,
                screenshot,
                frames,
            } = *args;
            let (w, h) = parse_size(&size)?;
            if spp == 0 || spp > 1 << 16 {
                bail!("--spp must be in 1..=65536, got {spp}");
            }
            let passes = match frames {
                Some(0) => bail!("--frames must be at least 1"),
                Some(n) => n.min(spp),
                None => spp,
            };
            let look = parse_look(&tonemap, exposure)?;
            let filter: oxray_render::filter::Filter = filter
                .parse()
                .map_err(|e| anyhow::anyhow!("--filter: {e}"))?;
            let sampler: oxray_render::Sampler = sampler
                .parse()
                .map_err(|e| anyhow::anyhow!("--sampler: {e}"))?;
            check_env_intensity(env_intensity)?;
            let env_file = environment_file(env.as_deref());
            if let Some(out) = &screenshot {
                if oxray_scene::file_extension(out).as_deref() != Some("png") {
                    bail!(
                        "cannot write {}: --screenshot writes a PNG (.png)",
                        out.display()
                    );
                }
                let inputs: Vec<&Path> =
                    scene.iter().chain(&env_file).map(|p| p.as_path()).collect();
                oxray_scene::files::check_output(out, &inputs).map_err(anyhow::Error::msg)?;
            }
            // Before any loading: without a display there is nothing to show it in.
            view::check_display()?;
            let renderer = render_device::open(&backend)?;
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads.unwrap_or(0))
                .build()
                .context("cannot start the worker threads")?;
            let (mut desc, default_env) = match &scene {
                Some(path) => (pool.install(|| SceneDesc::load(path))?, "sky"),
                None => (oxray_scene::cornell_box(), "none"),
            };
            if let Some(out) = &screenshot {
                if let Some(read) = desc
                    .sources
                    .iter()
                    .find(|r| oxray_scene::files::same_file(out, r))
                {
                    bail!(
                        "{} is read by the scene ({}); choose another screenshot file",
                        out.display(),
                        read.display()
                    );
                }
            }
            if ground {
                desc.add_ground();
            }
            // The view moves the camera, never an instance: the meshes placed once are traced
            // as one structure.
            let mut desc = desc.flattened();
            for w in &desc.warnings {
                eprintln!("warning: {w}");
            }
            let environment = environment(env.as_deref().unwrap_or(default_env), env_intensity)?;
            let mut opts = RenderOptions {
                width: w,
                height: h,
                spp: if screenshot.is_some() { passes } else { spp },
                max_depth: max_depth.clamp(1, 64),
                camera,
                filter,
                seed,
                sampler,
                ..Default::default()
            };
            aim.apply(&mut desc, &mut opts)?;
            let name = scene
                .as_deref()
                .and_then(|p| p.file_stem())
                .map_or("cornell".into(), |s| s.to_string_lossy().into_owned());
            view::run(view::ViewSetup {
                name,
                scene: desc,
                environment,
                opts,
                look,
                look_at: aim.look_at,
                renderer,
                pool,
                screenshot,
            })
        }
        Command::Raycast {
            mesh,
            rays,
            out,
            occlusion,
            count,
            all_hits,
            threads,
            backend,
        } => {
            use oxray_cli::raycast::RaycastQuery;
            let query = match (occlusion, count, all_hits) {
                (true, _, _) => RaycastQuery::Occlusion,
                (_, true, _) => RaycastQuery::Count,
                (_, _, Some(max)) => RaycastQuery::AllHits { max },
                _ => RaycastQuery::Closest,
            };
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads.unwrap_or(0))
                .build()
                .context("cannot start the worker threads")?;
            let device = oxray_cli::device::open(&backend)?;
            let r =
                pool.install(|| oxray_cli::device::raycast(&device, &mesh, &rays, &out, query))?;
            say(format_args!(
                "{} rays, {} {}, {} invalid ({:.2} Mrays/s traced, {:.2} Mrays/s with transfers on {})",
                r.rays,
                r.hits,
                match query {
                    RaycastQuery::Occlusion => "occluded",
                    RaycastQuery::Closest => "hits",
                    _ => "rays with hits",
                },
                r.check.invalid(),
                r.traced_mrays_per_s,
                r.transfer_mrays_per_s,
                pool.install(|| device.describe())
            ))?;
            if let Some(summary) = r.check.summary() {
                eprintln!("warning: {}: {summary}", rays.display());
            }
            Ok(())
        }
        Command::Closest {
            mesh,
            points,
            out,
            signed,
            threads,
            backend,
        } => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads.unwrap_or(0))
                .build()
                .context("cannot start the worker threads")?;
            let device = oxray_cli::device::open(&backend)?;
            let r = pool
                .install(|| oxray_cli::closest::closest(&device, &mesh, &points, &out, signed))?;
            say(format_args!(
                "{} points, {} not finite ({:.2} Mpoints/s on {})",
                r.points,
                r.non_finite,
                r.mpoints_per_s,
                pool.install(|| device.describe())
            ))?;
            Ok(())
        }
        Command::Info { mesh } => {
            let ext = oxray_scene::file_extension(&mesh);
            if matches!(ext.as_deref(), Some("gltf") | Some("glb")) {
                let report =
                    oxray_cli::info::scene_info(&mesh).map_err(|e| anyhow::anyhow!("{e}"))?;
                say(format_args!("{report}"))?;
            } else {
                say(format_args!("{}", oxray_cli::raycast::info(&mesh)?))?;
            }
            Ok(())
        }
        Command::Bench {
            meshes,
            threads,
            side,
            runs,
            export,
            build,
            instances,
            subdivide,
            backend,
            gas_builds,
            simulation,
        } => {
            let traced = bench::preset_index(&build).map_err(anyhow::Error::msg)?;
            if side == 0 || side > 16384 {
                bail!("--side must be in 1..=16384, got {side}");
            }
            if runs == 0 {
                bail!("--runs must be at least 1");
            }
            // The CPU table (the default) has every column; another device gets the comparison
            // table of its batched queries against the CPU's.
            let device = match backend.as_str() {
                "cpu" => None,
                name => Some(oxray_cli::device::open(name)?),
            };
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads.unwrap_or(0))
                .build()
                .context("cannot start the worker threads")?;
            let mut sets: Vec<(String, Mesh)> = Vec::new();
            let paths = if meshes.is_empty() {
                default_meshes()
            } else {
                meshes
            };
            if paths.is_empty() {
                say(format_args!(
                    "(no meshes given and ../shared/data absent: using a generated icosphere)"
                ))?;
                sets.push(("icosphere-7".into(), Mesh::icosphere(7)));
            }
            for p in paths {
                let mesh = Mesh::load(&p)?;
                let name = p
                    .file_stem()
                    .and_then(|s| s.to_str())
                    .unwrap_or("mesh")
                    .to_string();
                sets.push((name, mesh));
            }
            if subdivide > 0 {
                for (name, mesh) in &mut sets {
                    *mesh = mesh.subdivided(subdivide).with_context(|| {
                        format!("{name} split {subdivide} times would exceed 2^29 triangles")
                    })?;
                    name.push_str(&format!("/{}", 1u64 << (2 * subdivide)));
                }
            }
            say(format_args!(
                "threads: {}, rays per set: {}, median of {runs} runs, rays traced on the {build} build",
                pool.current_num_threads(),
                side * side
            ))?;
            if gas_builds && device.is_none() {
                bail!("--gas-builds needs --backend cuda");
            }
            if simulation {
                if let Some(device) = &device {
                    say(format_args!("device: {}", device.describe()))?;
                }
                say(oxray_cli::simulation::HEADER)?;
                for (name, mesh) in &sets {
                    let rows = pool.install(|| {
                        oxray_cli::simulation::bench(
                            device.as_ref(),
                            name,
                            mesh,
                            (side * side) as usize,
                            runs,
                        )
                    })?;
                    for row in rows {
                        say(row)?;
                    }
                }
                return Ok(());
            }
            if let Some(device) = &device {
                say(format_args!("device: {}", device.describe()))?;
                say(format_args!(
                    "{}",
                    if gas_builds {
                        oxray_cli::device::BUILD_BENCH_HEADER
                    } else {
                        oxray_cli::device::BENCH_HEADER
                    }
                ))?;
            } else {
                say(format_args!(
                    "| mesh | tris | build ms (default / fast-build / fast-trace / fast-trace-binned) | SAH (default / fast-build / fast-trace / fast-trace-binned) | primary closest | primary any | diffuse closest | diffuse any | shadow | diffuse closest by build (default / fast-build / fast-trace / fast-trace-binned) | pipeline primary closest vs the same rays as single-ray queries, alternated (batched, packets) |"
                ))?;
                say(format_args!(
                    "|---|---:|---|---|---:|---:|---:|---:|---:|---|---:|"
                ))?;
            }
            for (name, mesh) in &sets {
                let rays = bench::bench_rays(mesh, side);
                if let Some(dir) = &export {
                    let gas = bench::build_preset(mesh, traced)?;
                    bench::export(dir, name, mesh, &rays)
                        .and_then(|_| bench::export_hits(dir, name, &gas, &rays))
                        .with_context(|| format!("cannot write to {}", dir.display()))?;
                }
                if let (Some(device), true) = (&device, gas_builds) {
                    let rows = pool.install(|| {
                        oxray_cli::device::bench_builds(device, name, mesh, &rays, runs)
                    })?;
                    for row in rows {
                        say(format_args!("{row}"))?;
                    }
                    continue;
                }
                if let Some(device) = &device {
                    let rows = pool.install(|| {
                        oxray_cli::device::bench_mesh(device, name, mesh, &rays, runs)
                    })?;
                    for row in rows {
                        say(format_args!("{row}"))?;
                    }
                    continue;
                }
                let r = pool
                    .install(|| {
                        bench::run(name, mesh, runs, &rays, traced).map_err(|e| e.to_string())
                    })
                    .map_err(anyhow::Error::msg)?;
                say(format_args!(
                    "| {} | {} | {:.1} / {:.1} / {:.1} / {:.1} | {:.2} / {:.2} / {:.2} / {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} / {:.2} / {:.2} / {:.2} | {:.2} vs {:.2} ({:.0}%) ({:.2}) |",
                    r.name, r.triangles, r.build_ms[0], r.build_ms[1], r.build_ms[2], r.build_ms[3],
                    r.sah[0], r.sah[1], r.sah[2], r.sah[3],
                    r.mrays[0], r.mrays[1], r.mrays[2], r.mrays[3], r.mrays[4],
                    r.mrays_by_flags[0], r.mrays_by_flags[1], r.mrays_by_flags[2], r.mrays_by_flags[3],
                    r.pipeline_mrays.0,
                    r.pipeline_mrays.1,
                    100.0 * r.pipeline_mrays.0 / r.pipeline_mrays.1,
                    r.pipeline_mrays.2,
                ))?;
                eprintln!(
                    "  {}: {:.1} Mtris/s build, fast-trace leaf references {:.3} per triangle, hit rate primary {:.1}%, diffuse {:.1}%, shadow rays blocked {:.1}%",
                    r.name,
                    r.triangles as f64 / r.build_ms[0] / 1e3,
                    r.refs_per_tri[2],
                    100.0 * r.hit_rate[0],
                    100.0 * r.hit_rate[1],
                    100.0 * r.hit_rate[2]
                );
            }
            // The life of a structure (guide §5.6-5.8) on the benchmark's device.
            let on = device.clone().unwrap_or_default();
            say("")?;
            say(format_args!(
                "structure life on {} (ALLOW_UPDATE | ALLOW_COMPACTION)",
                pool.install(|| on.describe())
            ))?;
            say(format_args!("| mesh | tris | updatable build ms | refit ms | rebuild ms (no flags) | rebuild/refit | B/triangle as built | B/triangle compacted | save ms | load ms |"))?;
            say(format_args!(
                "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
            ))?;
            for (name, mesh) in &sets {
                let r = pool
                    .install(|| bench::life(&on, mesh, runs).map_err(|e| e.to_string()))
                    .map_err(anyhow::Error::msg)?;
                let n = mesh.triangles.len().max(1) as f64;
                say(format_args!(
                    "| {name} | {} | {:.2} | {:.3} | {:.2} | {:.1}x | {:.1} | {:.1} | {:.2} | {:.2} |",
                    mesh.triangles.len(),
                    r.updatable_build_ms,
                    r.refit_ms,
                    r.rebuild_ms,
                    r.rebuild_ms / r.refit_ms.max(1e-9),
                    r.built_bytes as f64 / n,
                    r.compacted_bytes as f64 / n,
                    r.save_ms,
                    r.load_ms
                ))?;
            }
            if let (Some(n), Some((name, mesh))) = (instances, sets.first()) {
                if n == 0 || n > 1 << 28 {
                    bail!("--instances must be in 1..=2^28, got {n}");
                }
                let on = device.clone().unwrap_or_default();
                let r = pool
                    .install(|| {
                        bench::instances(&on, mesh, n, side, runs).map_err(|e| e.to_string())
                    })
                    .map_err(anyhow::Error::msg)?;
                say("")?;
                say(format_args!(
                    "instances traced on {}",
                    pool.install(|| on.describe())
                ))?;
                say(format_args!("| instanced mesh | instances | triangles (instanced) | IAS build ms | camera closest Mrays/s | random closest Mrays/s | camera hit rate |"))?;
                say(format_args!("|---|---:|---:|---:|---:|---:|---:|"))?;
                say(format_args!(
                    "| {name} | {} | {} | {:.1} | {:.2} | {:.2} | {:.1}% |",
                    r.instances,
                    r.mesh_triangles as u64 * r.instances as u64,
                    r.build_ms,
                    r.coherent_mrays,
                    r.incoherent_mrays,
                    100.0 * r.hit_rate
                ))?;
            }
            Ok(())
        }
    }
}
