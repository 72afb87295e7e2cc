//! The path tracer's two versions under one test: the Rust programs ([`render`]) and the CUDA
//! C++ programs ([`render_on`], `device_programs.cu`) render the same scenes, and their images
//! are compared statistically, so that a change to one version that the other does not follow
//! (a missing MIS weight, a wrong BSDF factor, another light choice) fails here, while
//! Monte-Carlo noise does not.
//!
//! The comparison: with `a` and `b` the two images, every pixel's difference `d = a - b` (per
//! channel) is an independent draw of the two renders' Monte-Carlo errors (pixels have their
//! own random streams). Under "same algorithm" every `d` has mean 0, so over a region (the
//! whole image, and each 8x8 block) the mean difference is tested against its standard error
//! `sd(d) / sqrt(n)`, the sample standard deviation of the differences over the region's `n`
//! pixels: a z-test with |z| <= 4.5 for the image and 5 for blocks (about 200 block tests per
//! image: false alarms stay below one in ten thousand even with heavy tails), plus a floor of
//! 0.2 % of the region's mean radiance for floating-point differences between backends.
//!
//! The test of the test: the C++ programs with another seed salt (independent noise, same
//! algorithm) must pass on both scenes; with the MIS weight of emission or of the environment
//! found by BSDF sampling dropped, the Lambert lobe's 1/pi doubled, or Schlick's Fresnel
//! without its angular term, they must fail.
//!
//! On CUDA (device 0, when present; `OXRAY_REQUIRE_GPU=1` makes its absence a failure) the same
//! comparisons run. Without a GPU the programs are still compiled to PTX by NVRTC where
//! libnvrtc loads (`OXRAY_REQUIRE_NVRTC=1` makes its absence a failure).

mod common;

use common::region;
use glam::{Mat4, Quat, Vec3};
use oxray::Device;
use oxray_render::device::{render_on, render_with_source, SOURCE};
use oxray_render::lights::Environment;
use oxray_render::{render, Image, RenderOptions};
use oxray_scene::{
    cornell_box, AlphaMode, Camera, InstanceDesc, LightKind, MaterialDesc, MeshDesc, Primitive,
    PunctualLight, SceneDesc, Texture, TextureRef, Wrap,
};

const Z_IMAGE: f64 = 4.5;
const Z_BLOCK: f64 = 5.0;
const FLOOR: f64 = 2e-3;
const BLOCK: u32 = 8;

fn opts(size: u32, spp: u32, max_depth: u32) -> RenderOptions {
    RenderOptions {
        width: size,
        height: size,
        spp,
        max_depth,
        ..Default::default()
    }
}

/// Compares two renders of one scene; `Err` names the first region and channel that differ
/// beyond noise.
fn compare(a: &Image, b: &Image) -> Result<String, String> {
    assert_eq!((a.width, a.height), (b.width, b.height));
    for img in [a, b] {
        assert!(
            img.pixels
                .iter()
                .flatten()
                .all(|v| v.is_finite() && *v >= 0.0),
            "NaN, infinite or negative radiance"
        );
    }
    let (w, h) = (a.width as usize, a.height as usize);
    let check = |name: &str, pixels: &[usize], z_max: f64| -> Result<f64, String> {
        let mut worst = 0.0f64;
        for c in 0..3 {
            let (mean, se, reference) = region(a, b, pixels, c);
            let allowed = z_max * se + FLOOR * reference.abs() + 1e-6;
            if mean.abs() > allowed {
                return Err(format!(
                    "{name}, channel {c}: mean difference {mean:.5} (reference mean {reference:.5}) \
                     is {:.1} standard errors ({se:.5}); allowed {allowed:.5}",
                    mean.abs() / se.max(1e-30)
                ));
            }
            worst = worst.max(mean.abs() / allowed);
        }
        Ok(worst)
    };
    let all: Vec<usize> = (0..w * h).collect();
    let image = check("the image", &all, Z_IMAGE)?;
    let mut blocks = 0.0f64;
    let s = BLOCK as usize;
    for by in 0..h / s {
        for bx in 0..w / s {
            let pixels: Vec<usize> = (0..s * s)
                .map(|k| (by * s + k / s) * w + bx * s + k % s)
                .collect();
            blocks = blocks.max(check(&format!("block ({bx}, {by})"), &pixels, Z_BLOCK)?);
        }
    }
    let identical = a
        .pixels
        .iter()
        .zip(&b.pixels)
        .filter(|(p, q)| p == q)
        .count();
    Ok(format!(
        "largest share of the allowed difference: image {image:.2}, blocks {blocks:.2}; \
         {identical} of {} pixels bit-identical",
        w * h
    ))
}

/// A w x h RGBA texture from a function of the texel.
fn texture(name: &str, w: u32, h: u32, f: impl Fn(u32, u32) -> [u8; 4]) -> Texture {
    Texture {
        name: name.into(),
        width: w,
        height: h,
        texels: (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| f(x, y))
            .collect(),
        wrap_u: Wrap::Repeat,
        wrap_v: Wrap::MirroredRepeat,
    }
}

/// A unit quad in the XZ plane facing +Y, with normals and texture coordinates.
fn quad(material: u32) -> Primitive {
    Primitive {
        positions: vec![
            [-0.5, 0.0, -0.5],
            [0.5, 0.0, -0.5],
            [0.5, 0.0, 0.5],
            [-0.5, 0.0, 0.5],
        ],
        normals: vec![[0.0, 1.0, 0.0]; 4],
        uvs: vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
        triangles: vec![[0, 2, 1], [0, 3, 2]],
        material,
        ..Default::default()
    }
}

/// A cube of side 1 centred at `c`, flat shaded (no normals), outward winding.
fn cube(material: u32, c: Vec3, smooth: bool) -> Primitive {
    let mut p = Primitive {
        material,
        ..Default::default()
    };
    for z in [-0.5f32, 0.5] {
        for y in [-0.5f32, 0.5] {
            for x in [-0.5f32, 0.5] {
                p.positions.push((c + Vec3::new(x, y, z)).to_array());
                if smooth {
                    p.normals.push(Vec3::new(x, y, z).normalize().to_array());
                    p.uvs.push([x + 0.5, z + 0.5]);
                    p.uvs1.push([y + 0.5, x + 0.5]);
                    p.colors.push([0.5 + x, 0.8, 0.5 - z, 1.0]);
                }
            }
        }
    }
    for q in [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ] {
        p.triangles.push([q[0], q[1], q[2]]);
        p.triangles.push([q[0], q[2], q[3]]);
    }
    p
}

/// Every material feature at once under the sky: a textured ground, glass and rough gold in one
/// mesh (two build inputs), a smooth-shaded normal-mapped box with vertex colours and a
/// metallic-roughness texture on the second texture set, an alpha-masked and a blended leaf, a
/// single-sided emitter, a mirrored instance, a point and a spot light.
fn feature_scene() -> SceneDesc {
    let checker = texture("checker", 8, 8, |x, y| {
        if (x + y) % 2 == 0 {
            [230, 220, 200, 255]
        } else {
            [60, 90, 140, 255]
        }
    });
    let holes = texture("holes", 4, 4, |x, y| {
        [90, 200, 80, if (x / 2 + y) % 2 == 0 { 255 } else { 0 }]
    });
    let bumps = texture("bumps", 8, 8, |x, y| {
        [
            128 + ((x * 37) % 64) as u8,
            128 - ((y * 23) % 64) as u8,
            230,
            255,
        ]
    });
    let mr = texture("mr", 4, 4, |x, y| {
        [0, 60 + 40 * x as u8, 120 + 40 * y as u8, 255]
    });
    let materials = vec![
        MaterialDesc {
            name: "ground".into(),
            base_color_texture: Some(TextureRef::new(0).with_khr_transform(
                [0.1, 0.2],
                0.3,
                [3.0, 3.0],
            )),
            roughness: 0.8,
            ..Default::default()
        },
        MaterialDesc {
            name: "glass".into(),
            base_color: [0.9, 1.0, 0.95, 1.0],
            transmission: 1.0,
            ior: 1.5,
            ..Default::default()
        },
        MaterialDesc {
            name: "gold".into(),
            base_color: [1.0, 0.78, 0.34, 1.0],
            metallic: 1.0,
            roughness: 0.3,
            ..Default::default()
        },
        MaterialDesc {
            name: "panel".into(),
            emissive: [6.0, 5.0, 4.0],
            base_color: [0.2, 0.2, 0.2, 1.0],
            double_sided: false,
            ..Default::default()
        },
        MaterialDesc {
            name: "leaf".into(),
            base_color_texture: Some(TextureRef::new(1)),
            alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
            ..Default::default()
        },
        MaterialDesc {
            name: "bumpy".into(),
            base_color: [0.9, 0.5, 0.4, 1.0],
            normal_texture: Some(TextureRef::new(2)),
            normal_scale: 0.8,
            metallic: 0.5,
            metallic_roughness_texture: Some(TextureRef::new(3).with_tex_coord(1)),
            ..Default::default()
        },
        MaterialDesc {
            name: "veil".into(),
            base_color: [0.3, 0.4, 0.9, 0.4],
            alpha_mode: AlphaMode::Blend,
            ..Default::default()
        },
    ];
    let mesh = |name: &str, primitives| MeshDesc {
        name: name.into(),
        primitives,
    };
    let meshes = vec![
        mesh("ground", vec![quad(0)]),
        mesh(
            "boxes",
            vec![
                // The boxes float a little above the ground: a bottom face in the ground's
                // plane would tie with it at every point (the same distance), and which of two
                // primitives at one distance a trace reports depends on the tree, which the
                // device builds differently from the host. Under a uniform sky that choice
                // (refract out of the glass below the ground, or stop at the ground) shows.
                cube(1, Vec3::new(-0.7, 0.52, 0.0), false),
                cube(2, Vec3::new(0.7, 0.52, -0.3), false),
            ],
        ),
        mesh("panel", vec![quad(3)]),
        mesh("leaf", vec![quad(4)]),
        mesh("bumpy", vec![cube(5, Vec3::ZERO, true)]),
        mesh("veil", vec![quad(6)]),
    ];
    let at = InstanceDesc::new;
    let instances = vec![
        at(0, Mat4::from_scale(Vec3::new(8.0, 1.0, 8.0))),
        at(1, Mat4::IDENTITY),
        // The panel faces down (its front face is +Y before the half turn about X).
        at(
            2,
            Mat4::from_scale_rotation_translation(
                Vec3::splat(1.2),
                Quat::from_rotation_x(std::f32::consts::PI),
                Vec3::new(0.0, 2.2, 0.3),
            ),
        ),
        at(
            3,
            Mat4::from_scale_rotation_translation(
                Vec3::splat(1.0),
                Quat::from_rotation_x(1.3),
                Vec3::new(0.0, 0.6, 1.0),
            ),
        ),
        at(
            4,
            Mat4::from_scale_rotation_translation(
                Vec3::splat(0.6),
                Quat::from_rotation_y(0.6),
                Vec3::new(-1.7, 0.3, 1.0),
            ),
        ),
        // A mirrored copy of the boxes: the winding order turns around.
        at(
            1,
            Mat4::from_translation(Vec3::new(0.0, 0.0, -2.5))
                * Mat4::from_scale(Vec3::new(-1.0, 1.0, 1.0)),
        ),
        at(
            5,
            Mat4::from_scale_rotation_translation(
                Vec3::splat(1.4),
                Quat::from_rotation_z(1.5),
                Vec3::new(0.9, 0.7, 1.4),
            ),
        ),
    ];
    SceneDesc {
        meshes,
        materials,
        textures: vec![checker, holes, bumps, mr],
        instances,
        cameras: vec![Camera::look_at(
            Vec3::new(1.8, 3.2, 5.0),
            Vec3::new(0.0, 0.3, -0.4),
            50f32.to_radians(),
        )],
        lights: vec![
            PunctualLight {
                kind: LightKind::Point,
                position: Vec3::new(-1.5, 1.5, 1.5),
                direction: Vec3::NEG_Y,
                intensity: Vec3::splat(800.0),
                range: Some(6.0),
            },
            PunctualLight {
                kind: LightKind::Spot {
                    inner_cone: 0.2,
                    outer_cone: 0.5,
                },
                position: Vec3::new(1.0, 3.0, 1.0),
                direction: Vec3::new(-0.2, -1.0, -0.3).normalize(),
                intensity: Vec3::new(1500.0, 1200.0, 900.0),
                range: None,
            },
        ],
        ..Default::default()
    }
}

fn dark() -> Environment {
    Environment::uniform(Vec3::ZERO)
}

/// The devices that run the C++ programs: the CPU, and CUDA device 0 where there is one.
fn devices() -> Vec<(&'static str, Device)> {
    let mut d = vec![("cpu", Device::cpu())];
    match Device::cuda(0) {
        Ok(c) => d.push(("cuda", c)),
        Err(e) => {
            assert!(
                std::env::var_os("OXRAY_REQUIRE_GPU").is_none(),
                "OXRAY_REQUIRE_GPU is set but there is no CUDA device: {e}"
            );
            println!("the CUDA half skips: {e}");
        }
    }
    d
}

fn compare_on_devices(label: &str, scene: &SceneDesc, env: &Environment, o: &RenderOptions) {
    let t = std::time::Instant::now();
    let reference = render(scene, env, o, |_| {}).unwrap();
    let rust = t.elapsed();
    for (name, device) in devices() {
        let t = std::time::Instant::now();
        let img = render_on(&device, scene, env, o, |_| {})
            .unwrap_or_else(|e| panic!("{label} on {name}: {e}"));
        match compare(&reference, &img) {
            Ok(summary) => println!(
                "{label}: the C++ programs on {name} agree with the Rust programs ({summary}); \
                 Rust {rust:.2?}, C++ {:.2?}",
                t.elapsed()
            ),
            Err(e) => {
                panic!("{label}: the C++ programs on {name} differ from the Rust programs: {e}")
            }
        }
    }
}

#[test]
fn cornell_box_agrees_with_the_rust_programs() {
    compare_on_devices("Cornell box", &cornell_box(), &dark(), &opts(64, 32, 6));
}

#[test]
fn materials_textures_alpha_and_the_sky_agree_with_the_rust_programs() {
    compare_on_devices(
        "feature scene",
        &feature_scene(),
        &Environment::sky(1.0),
        &opts(64, 32, 6),
    );
}

/// A uniform environment (one texel: looked up without map coordinates, sampled uniformly over
/// the sphere) is lit alike by both program sets, on every device.
#[test]
fn a_uniform_sky_agrees_with_the_rust_programs() {
    compare_on_devices(
        "feature scene under a uniform sky",
        &feature_scene(),
        &Environment::uniform(Vec3::new(0.8, 0.9, 1.0)),
        &opts(64, 32, 6),
    );
}

/// The comparison itself: independent noise passes, a changed algorithm fails.
#[test]
fn the_comparison_tells_noise_from_a_changed_algorithm() {
    let device = Device::cpu();
    let o = opts(64, 32, 6);
    let cornell = (cornell_box(), dark());
    let sky = (feature_scene(), Environment::sky(1.0));
    let reference =
        |(scene, env): &(SceneDesc, Environment)| render(scene, env, &o, |_| {}).unwrap();
    let references = [reference(&cornell), reference(&sky)];
    let variant = |what: &str, from: &str, to: &str, which: usize| {
        assert!(
            SOURCE.contains(from),
            "the programs no longer contain {from:?}"
        );
        let source = SOURCE.replace(from, to);
        let (scene, env) = [&cornell, &sky][which];
        let img = render_with_source(&device, &source, scene, env, &o, |_| {})
            .unwrap_or_else(|e| panic!("{what}: {e}"));
        compare(&references[which], &img)
    };
    // The salt of both the hash streams and the Sobol scrambles.
    let seed = (
        "return 0x5eedu ^ (params.seed",
        "return 0x5eeeu ^ (params.seed",
    );
    for which in [0, 1] {
        let reseeded = variant("another seed", seed.0, seed.1, which);
        assert!(
            reseeded.is_ok(),
            "independent noise must pass: {}",
            reseeded.unwrap_err()
        );
        println!("another seed passes: {}", reseeded.unwrap());
    }
    for (what, from, to, which) in [
        (
            "no MIS weight on emission found by BSDF sampling",
            "w = power_heuristic(s.pdf, light_pdf);",
            "w = 1.0f;",
            0,
        ),
        (
            "twice the Lambert lobe",
            "(PT_FRAC_1_PI * cos_i)",
            "(2.0f * PT_FRAC_1_PI * cos_i)",
            0,
        ),
        (
            "no MIS weight on the environment found by BSDF sampling",
            "power_heuristic(s.pdf, params.p_env * env_pdf(d))",
            "1.0f",
            1,
        ),
        (
            "Schlick's Fresnel without its (1 - cos)^5",
            "pow5(1.0f - clampf(c, 0.0f, 1.0f))",
            "0.0f",
            1,
        ),
    ] {
        match variant(what, from, to, which) {
            Ok(s) => panic!("{what}: the comparison did not notice ({s})"),
            Err(e) => println!("{what}: caught ({e})"),
        }
    }
}

#[test]
fn render_on_is_deterministic_across_thread_counts() {
    let scene = feature_scene();
    let env = Environment::sky(1.0);
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| render_on(&Device::cpu(), &scene, &env, &opts(32, 4, 5), |_| {}).unwrap())
    };
    let (a, b) = (run(1), run(4));
    assert!(a
        .pixels
        .iter()
        .zip(&b.pixels)
        .all(|(p, q)| p.iter().zip(q).all(|(x, y)| x.to_bits() == y.to_bits())));
}

#[test]
fn render_on_reports_progress_and_scene_errors() {
    let mut done = Vec::new();
    render_on(
        &Device::cpu(),
        &cornell_box(),
        &dark(),
        &opts(8, 3, 3),
        |n| done.push(n),
    )
    .unwrap();
    assert_eq!(done, [1, 2, 3]);
    let empty = SceneDesc::default();
    assert!(render_on(&Device::cpu(), &empty, &dark(), &opts(8, 1, 3), |_| {}).is_err());
}

#[test]
fn the_programs_compile_for_the_gpu_with_nvrtc() {
    use oxray::cuda::{CudaModule, CudaProgramGroup};
    use oxray::{PipelineCompileOptions, PipelineLinkOptions};
    // NVRTC present? A trivial program says.
    if let Err(e) = oxray::cuda::compile_pipeline_ptx(
        (9, 0),
        &PipelineCompileOptions::default(),
        &PipelineLinkOptions::default(),
        &[CudaProgramGroup::raygen(
            &CudaModule::from_source("extern \"C\" __global__ void __raygen__x() {}"),
            "__raygen__x",
        )
        .unwrap()],
    ) {
        assert!(
            std::env::var_os("OXRAY_REQUIRE_NVRTC").is_none(),
            "OXRAY_REQUIRE_NVRTC is set but NVRTC fails: {e}"
        );
        println!("skipping: NVRTC is not available ({e})");
        return;
    }
    let ptx = oxray_render::device::compile_for_gpu((9, 0))
        .unwrap_or_else(|e| panic!("the path tracer does not compile for the GPU: {e}"));
    assert!(ptx.contains(".entry"));
}
