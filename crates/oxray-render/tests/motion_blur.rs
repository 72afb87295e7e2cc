//! Motion blur in the renderer (guide §5.10 through the scene layer): camera rays take times
//! over the shutter, animated instances move through SRT motion transforms, and a closed
//! shutter renders the pose at its time.
//!
//! The scene: a black, purely diffuse strip in front of a white uniform environment, sliding
//! from x = -1 to x = +1 while the shutter is open. A camera ray's radiance is 1 when it misses
//! the strip at its time and 0 when it hits it, so a pixel's mean is the fraction of the
//! shutter during which the strip does not cover it: a known function of where the pixel
//! looks.

use glam::{Mat4, Vec3};
use oxray_render::filter::Filter;
use oxray_render::lights::Environment;
use oxray_render::motion::Shutter;
use oxray_render::{render, Image, RenderOptions, Renderer};
use oxray_scene::animation::{Animation, Channel, Interpolation, Property};
use oxray_scene::{Camera, InstanceDesc, MaterialDesc, MeshDesc, NodeDesc, Primitive, SceneDesc};
use std::ops::ControlFlow;

const WIDTH: u32 = 40;

/// The strip (x in [-0.5, 0.5], tall) at the origin of its node; the camera at z = 5 sees
/// x in [-2, 2] on the plane z = 0 across the image's 40 columns.
fn scene(animated: bool, rest: Vec3) -> SceneDesc {
    let mut s = SceneDesc::default();
    s.materials.push(MaterialDesc {
        name: "black".into(),
        base_color: [0.0, 0.0, 0.0, 1.0],
        specular: 0.0,
        roughness: 1.0,
        ..Default::default()
    });
    s.meshes.push(MeshDesc {
        name: "strip".into(),
        primitives: vec![Primitive {
            positions: vec![
                [-0.5, -10.0, 0.0],
                [0.5, -10.0, 0.0],
                [0.5, 10.0, 0.0],
                [-0.5, 10.0, 0.0],
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            material: 0,
            ..Default::default()
        }],
    });
    s.nodes.push(NodeDesc {
        translation: rest,
        ..Default::default()
    });
    s.instances
        .push(InstanceDesc::new(0, Mat4::from_translation(rest)).at_node(0));
    if animated {
        s.animations.push(Animation {
            name: "slide".into(),
            channels: vec![Channel {
                node: 0,
                property: Property::Translation,
                interpolation: Interpolation::Linear,
                times: vec![0.0, 1.0],
                values: vec![[-1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]],
            }],
        });
    }
    // tan(yfov / 2) = 0.02: half the image's height is 0.1 and half its width 2 at z = 0.
    s.cameras.push(Camera::look_at(
        Vec3::new(0.0, 0.0, 5.0),
        Vec3::ZERO,
        2.0 * 0.02f32.atan(),
    ));
    s
}

fn options(spp: u32, shutter: Option<Shutter>) -> RenderOptions {
    RenderOptions {
        width: WIDTH,
        height: 2,
        spp,
        max_depth: 2,
        filter: Filter::Box,
        shutter,
        ..Default::default()
    }
}

fn white() -> Environment {
    Environment::uniform(Vec3::ONE)
}

/// Where column `x`'s centre looks on the plane z = 0.
fn looks_at(x: u32) -> f32 {
    (2.0 * (x as f32 + 0.5) / WIDTH as f32 - 1.0) * 2.0
}

fn column_mean(img: &Image, x: u32) -> f32 {
    (0..img.height)
        .map(|y| img.pixels[(y * img.width + x) as usize][0])
        .sum::<f32>()
        / img.height as f32
}

#[test]
fn s5_10_an_open_shutter_blurs_a_sliding_strip_by_its_coverage_time() {
    let img = render(
        &scene(true, Vec3::ZERO),
        &white(),
        &options(1024, Some(Shutter::new(0.0, 1.0).unwrap())),
        |_| {},
    )
    .unwrap();
    assert_strip_blur(&img, "Rust programs");
    // Blur, not a still: some columns are neither black nor white.
    assert!((0..WIDTH).any(|x| (0.3..0.7).contains(&column_mean(&img, x))));
}

#[test]
fn s5_10_a_closed_shutter_renders_the_pose_at_its_time() {
    // At t = 0.75 the strip is at x = 0.5: exactly the still strip placed there.
    let posed = render(
        &scene(true, Vec3::ZERO),
        &white(),
        &options(16, Some(Shutter::new(0.75, 0.75).unwrap())),
        |_| {},
    )
    .unwrap();
    let still = render(
        &scene(false, Vec3::new(0.5, 0.0, 0.0)),
        &white(),
        &options(16, None),
        |_| {},
    )
    .unwrap();
    assert_eq!(posed.pixels, still.pixels);
    assert_eq!(column_mean(&posed, 0), 1.0);
    assert_eq!(column_mean(&posed, 25), 0.0, "x = 0.5 is covered");
}

#[test]
fn a_shutter_over_a_still_scene_changes_nothing() {
    let s = scene(false, Vec3::ZERO);
    let plain = render(&s, &white(), &options(8, None), |_| {}).unwrap();
    let shut = render(
        &s,
        &white(),
        &options(8, Some(Shutter::new(0.0, 1.0).unwrap())),
        |_| {},
    )
    .unwrap();
    assert_eq!(plain.pixels, shut.pixels);
}

#[test]
fn a_missing_animation_is_an_error() {
    let mut o = options(1, Some(Shutter::new(0.0, 1.0).unwrap()));
    o.animation = 3;
    let e = render(&scene(true, Vec3::ZERO), &white(), &o, |_| {}).unwrap_err();
    assert!(e.to_string().contains("animation 3 does not exist"), "{e}");
}

/// The devices of this machine: the CPU (the programs' CUDA C++ compiled for it) and CUDA
/// device 0 where there is one (`OXRAY_REQUIRE_GPU=1` makes its absence a failure).
fn devices() -> Vec<oxray::Device> {
    let mut d = vec![oxray::Device::cpu()];
    match oxray::Device::cuda(0) {
        Ok(c) => d.push(c),
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

/// Renders with the path tracer's CUDA C++ programs on `device`.
fn render_on(device: &oxray::Device, s: &SceneDesc, env: &Environment, o: &RenderOptions) -> Image {
    let mut r = Renderer::new(device, s, env).unwrap();
    r.render(o, |_| ControlFlow::Continue(())).unwrap().image
}

#[test]
fn s5_10_the_cuda_cpp_programs_blur_the_sliding_strip_on_every_device() {
    let s = scene(true, Vec3::ZERO);
    let env = white();
    for device in devices() {
        let mut r = Renderer::new(&device, &s, &env).unwrap();
        let o = options(1024, Some(Shutter::new(0.0, 1.0).unwrap()));
        let img = r.render(&o, |_| ControlFlow::Continue(())).unwrap().image;
        assert_strip_blur(&img, &device.describe());
        // The same renderer without the shutter renders the still pose again (the tables are
        // posed anew), and a closed shutter the pose at its time.
        let still = r
            .render(&options(16, None), |_| ControlFlow::Continue(()))
            .unwrap()
            .image;
        assert_eq!(column_mean(&still, 20), 0.0, "x = 0.1 is covered at rest");
        assert_eq!(column_mean(&still, 0), 1.0);
        let posed = r
            .render(
                &options(16, Some(Shutter::new(0.75, 0.75).unwrap())),
                |_| ControlFlow::Continue(()),
            )
            .unwrap()
            .image;
        let moved = render_on(
            &device,
            &scene(false, Vec3::new(0.5, 0.0, 0.0)),
            &white(),
            &options(16, None),
        );
        assert_eq!(posed.pixels, moved.pixels, "{}", device.describe());
    }
}

/// A white floor lit by an emissive panel above it, the panel drifting by 1/1000 of its size
/// over one second when `drift` is set.
fn lit_floor(drift: bool) -> SceneDesc {
    let mut s = SceneDesc::default();
    s.materials.push(MaterialDesc {
        name: "floor".into(),
        base_color: [0.8, 0.8, 0.8, 1.0],
        specular: 0.0,
        roughness: 1.0,
        ..Default::default()
    });
    s.materials.push(MaterialDesc {
        name: "panel".into(),
        base_color: [0.0, 0.0, 0.0, 1.0],
        emissive: [4.0, 4.0, 4.0],
        specular: 0.0,
        ..Default::default()
    });
    let quad = |y: f32, r: f32, material: u32| Primitive {
        positions: vec![[-r, y, -r], [r, y, -r], [r, y, r], [-r, y, r]],
        triangles: vec![[0, 2, 1], [0, 3, 2]],
        material,
        ..Default::default()
    };
    s.meshes.push(MeshDesc {
        name: "floor".into(),
        primitives: vec![quad(0.0, 3.0, 0)],
    });
    s.meshes.push(MeshDesc {
        name: "panel".into(),
        primitives: vec![quad(0.0, 1.0, 1)],
    });
    s.nodes.push(NodeDesc::default());
    s.nodes.push(NodeDesc {
        translation: Vec3::Y,
        ..Default::default()
    });
    s.instances
        .push(InstanceDesc::new(0, Mat4::IDENTITY).at_node(0));
    s.instances
        .push(InstanceDesc::new(1, Mat4::from_translation(Vec3::Y)).at_node(1));
    // A still panel of the same material, which next-event estimation samples in both
    // renders: hits on the moving one must not be weighted as if it were sampled too.
    s.instances.push(InstanceDesc::new(
        1,
        Mat4::from_translation(Vec3::new(2.5, 1.5, -1.0)) * Mat4::from_scale(Vec3::splat(0.5)),
    ));
    if drift {
        s.animations.push(Animation {
            name: "drift".into(),
            channels: vec![Channel {
                node: 1,
                property: Property::Translation,
                interpolation: Interpolation::Linear,
                times: vec![0.0, 1.0],
                values: vec![[0.0, 1.0, 0.0, 0.0], [0.001, 1.0, 0.0, 0.0]],
            }],
        });
    }
    s.cameras.push(Camera::look_at(
        Vec3::new(0.0, 0.6, 4.0),
        Vec3::new(0.0, 0.2, 0.0),
        0.9,
    ));
    s
}

#[test]
fn s5_10_a_moving_emitter_lights_the_scene_as_much_as_a_still_one() {
    // The moving panel is not sampled by next-event estimation: its light reaches the floor
    // only through paths that hit it, weighted in full. The mean brightness must be the still
    // panel's (found by both strategies, weighted by MIS), within noise.
    let mean =
        |img: &Image| img.pixels.iter().map(|p| p[0] as f64).sum::<f64>() / img.pixels.len() as f64;
    let o = |shutter| RenderOptions {
        width: 16,
        height: 16,
        spp: 256,
        max_depth: 3,
        shutter,
        ..Default::default()
    };
    let dark = Environment::uniform(Vec3::ZERO);
    let still = render(&lit_floor(false), &dark, &o(None), |_| {}).unwrap();
    let moving = render(
        &lit_floor(true),
        &dark,
        &o(Some(Shutter::new(0.0, 1.0).unwrap())),
        |_| {},
    )
    .unwrap();
    let (a, b) = (mean(&still), mean(&moving));
    assert!(a > 0.05, "{a}");
    assert!((a - b).abs() < 0.03 * a, "still {a}, moving {b}");
}

#[test]
fn s5_10_a_moving_emitter_lights_alike_with_the_cuda_cpp_programs_on_every_device() {
    let mean =
        |img: &Image| img.pixels.iter().map(|p| p[0] as f64).sum::<f64>() / img.pixels.len() as f64;
    let o = |shutter| RenderOptions {
        width: 16,
        height: 16,
        spp: 256,
        max_depth: 3,
        shutter,
        ..Default::default()
    };
    let dark = Environment::uniform(Vec3::ZERO);
    for device in devices() {
        let still = render_on(&device, &lit_floor(false), &dark, &o(None));
        let moving = render_on(
            &device,
            &lit_floor(true),
            &dark,
            &o(Some(Shutter::new(0.0, 1.0).unwrap())),
        );
        let (a, b) = (mean(&still), mean(&moving));
        assert!(a > 0.05, "{a}");
        assert!(
            (a - b).abs() < 0.03 * a,
            "{}: still {a}, moving {b}",
            device.describe()
        );
    }
}

/// The still strip, seen by a camera on node 1 that slides from x = +1 to x = -1 while the
/// shutter is open: relative to the camera the strip slides as in the scenes above, so every
/// column is uncovered for the same fraction of the shutter.
fn panning_camera() -> SceneDesc {
    let mut s = scene(false, Vec3::ZERO);
    s.nodes.push(NodeDesc {
        translation: Vec3::new(0.0, 0.0, 5.0),
        ..Default::default()
    });
    s.cameras[0] = s.cameras[0].at_node(1);
    s.animations.push(Animation {
        name: "pan".into(),
        channels: vec![Channel {
            node: 1,
            property: Property::Translation,
            interpolation: Interpolation::Linear,
            times: vec![0.0, 1.0],
            values: vec![[1.0, 0.0, 5.0, 0.0], [-1.0, 0.0, 5.0, 0.0]],
        }],
    });
    s
}

/// Checks the blur of the sliding strip (or of the still strip seen by the panning camera).
fn assert_strip_blur(img: &Image, what: &str) {
    for x in 0..WIDTH {
        let xp = looks_at(x);
        // The strip covers xp for t in [(xp + 0.5) / 2, (xp + 1.5) / 2].
        let lo = ((xp + 0.5) / 2.0).clamp(0.0, 1.0);
        let hi = ((xp + 1.5) / 2.0).clamp(0.0, 1.0);
        let want = 1.0 - (hi - lo);
        let got = column_mean(img, x);
        assert!(
            (got - want).abs() < 0.05,
            "{what}: column {x} (x = {xp}): {got}, uncovered {want} of the time"
        );
    }
}

#[test]
fn s5_10_a_camera_the_animation_moves_blurs_the_still_scene() {
    let s = panning_camera();
    let open = Some(Shutter::new(0.0, 1.0).unwrap());
    let img = render(&s, &white(), &options(1024, open), |_| {}).unwrap();
    assert_strip_blur(&img, "Rust programs");
    // A closed shutter sees the scene from where the camera is at its time: at t = 0.25 the
    // camera is at x = 0.5, so the strip sits at x = -0.5 in the image, as the still strip
    // placed there.
    let posed = render(
        &s,
        &white(),
        &options(16, Some(Shutter::new(0.25, 0.25).unwrap())),
        |_| {},
    )
    .unwrap();
    let still = render(
        &scene(false, Vec3::new(-0.5, 0.0, 0.0)),
        &white(),
        &options(16, None),
        |_| {},
    )
    .unwrap();
    assert_eq!(column_mean(&posed, 15), 0.0, "x = -0.5 is covered");
    assert_eq!(column_mean(&posed, 25), 1.0);
    for x in 0..WIDTH {
        assert_eq!(column_mean(&posed, x), column_mean(&still, x), "column {x}");
    }
    // Without a shutter, the camera stays where the scene placed it.
    let rest = render(&s, &white(), &options(16, None), |_| {}).unwrap();
    assert_eq!(column_mean(&rest, 20), 0.0);
    assert_eq!(column_mean(&rest, 0), 1.0);
    // The CUDA C++ programs on every device (the CPU compiles them for the host).
    for device in devices() {
        let img = render_on(&device, &s, &white(), &options(1024, open));
        assert_strip_blur(&img, &device.describe());
        let posed = render_on(
            &device,
            &s,
            &white(),
            &options(16, Some(Shutter::new(0.25, 0.25).unwrap())),
        );
        assert_eq!(column_mean(&posed, 15), 0.0, "{}", device.describe());
        assert_eq!(column_mean(&posed, 25), 1.0, "{}", device.describe());
    }
}
