//! The embeddable renderer (`Renderer`, `render_passes`): progressive passes, cancellation,
//! edits without a full rebuild, seeds and AOVs. Everything runs on the CPU device (the
//! CUDA C++ programs compiled by the host's C++ compiler), where renders are deterministic, so
//! equalities are bit for bit.

mod common;

use glam::{Mat4, Vec3};
use oxray::Device;
use oxray_render::device::render_on;
use oxray_render::lights::Environment;
use oxray_render::{render, render_passes, Image, RenderOptions, Rendered, Renderer};
use oxray_scene::{cornell_box, AlphaMode, Camera, SceneDesc};
use std::ops::ControlFlow;

fn opts(size: u32, spp: u32) -> RenderOptions {
    RenderOptions {
        width: size,
        height: size,
        spp,
        max_depth: 4,
        ..Default::default()
    }
}

fn dark() -> Environment {
    Environment::uniform(Vec3::ZERO)
}

fn all(r: &mut Renderer, o: &RenderOptions) -> Rendered {
    r.render(o, |_| ControlFlow::Continue(())).unwrap()
}

fn fresh(scene: &SceneDesc, env: &Environment, o: &RenderOptions) -> Image {
    render_on(&Device::cpu(), scene, env, o, |_| {}).unwrap()
}

#[test]
fn a_renderer_renders_what_render_on_renders_every_time() {
    let scene = cornell_box();
    let env = dark();
    let o = opts(16, 3);
    let mut r = Renderer::new(&Device::cpu(), &scene, &env).unwrap();
    let first = all(&mut r, &o);
    let second = all(&mut r, &o);
    assert_eq!(first.samples, 3);
    assert!(!first.cancelled);
    assert!(first.aovs.is_none());
    assert_eq!(first.image, fresh(&scene, &env, &o));
    assert_eq!(first.image, second.image);
    // The C++ programs on the CPU and the Rust programs give the same bits.
    assert_eq!(first.image, render(&scene, &env, &o, |_| {}).unwrap());
}

/// A uniform environment (one texel, sampled uniformly over the sphere) lights the box's open
/// side the same way in both program sets: the same bits from the Rust and the C++ programs.
#[test]
fn a_uniform_environment_gives_the_same_bits_from_both_program_sets() {
    let scene = cornell_box();
    let env = Environment::uniform(Vec3::new(0.4, 0.5, 0.6));
    let o = opts(16, 3);
    let rust = render(&scene, &env, &o, |_| {}).unwrap();
    assert_eq!(rust, fresh(&scene, &env, &o));
    // The environment does light it: brighter than the dark box.
    let mean = |i: &Image| i.pixels.iter().map(|p| p[0] + p[1] + p[2]).sum::<f32>();
    assert!(mean(&rust) > mean(&render(&scene, &dark(), &o, |_| {}).unwrap()));
}

/// A render reports the time it spent before its first pass (building what the passes need),
/// which lies within the call: for `render_passes` everything (structures, tables, programs),
/// for a `Renderer` its tables (the first render) and nothing to rebuild after that.
#[test]
fn a_render_reports_its_setup_time_within_the_call() {
    let scene = cornell_box();
    let env = dark();
    let o = opts(16, 2);
    let timed = |f: &mut dyn FnMut() -> Rendered| {
        let start = std::time::Instant::now();
        let r = f();
        (r, start.elapsed())
    };
    let (r, call) =
        timed(&mut || render_passes(&scene, &env, &o, |_| ControlFlow::Continue(())).unwrap());
    assert!(
        r.setup > std::time::Duration::ZERO && r.setup <= call,
        "{:?} of {call:?}",
        r.setup
    );
    let mut renderer = Renderer::new(&Device::cpu(), &scene, &env).unwrap();
    for _ in 0..2 {
        let (r, call) = timed(&mut || all(&mut renderer, &o));
        assert!(r.setup <= call, "{:?} of {call:?}", r.setup);
        assert_eq!(r.samples, 2);
    }
}

/// A render reports the rays it traced (every launch's trace count): at least one camera ray
/// per pixel and sample, at most a camera ray and, per vertex, a bounce and its shadow rays; the
/// same count on every render of the same options, and from the Rust programs, which trace the
/// same rays as the C++ ones.
#[test]
fn a_render_counts_the_rays_it_traced() {
    let scene = cornell_box();
    let env = dark();
    let o = opts(16, 3);
    let mut r = Renderer::new(&Device::cpu(), &scene, &env).unwrap();
    let first = all(&mut r, &o);
    let camera_rays = 16 * 16 * 3;
    // Each of the 4 vertices may add a bounce and up to two shadow rays (lights, environment).
    assert!(
        first.rays > camera_rays && first.rays <= camera_rays * (1 + 4 * 3),
        "{} rays",
        first.rays
    );
    assert_eq!(all(&mut r, &o).rays, first.rays);
    let rust = render_passes(&scene, &env, &o, |_| ControlFlow::Continue(())).unwrap();
    assert_eq!(rust.rays, first.rays, "Rust and C++ programs");
    // Fewer vertices, fewer rays.
    let short = all(&mut r, &RenderOptions { max_depth: 1, ..o });
    assert!(short.rays < first.rays, "{} vs {}", short.rays, first.rays);
}

#[test]
fn a_cancelled_render_is_the_render_of_the_passes_done() {
    let scene = cornell_box();
    let env = dark();
    let mut r = Renderer::new(&Device::cpu(), &scene, &env).unwrap();
    let mut seen = Vec::new();
    let mut partial = None;
    let done = r
        .render(&opts(12, 10), |p| {
            seen.push((p.samples(), p.total()));
            if p.samples() == 2 {
                partial = Some(p.image().unwrap());
            }
            match p.samples() < 4 {
                true => ControlFlow::Continue(()),
                false => ControlFlow::Break(()),
            }
        })
        .unwrap();
    assert_eq!(seen, [(1, 10), (2, 10), (3, 10), (4, 10)]);
    assert!(done.cancelled);
    assert_eq!(done.samples, 4);
    assert_eq!(done.image, fresh(&scene, &env, &opts(12, 4)));
    assert_eq!(partial.unwrap(), fresh(&scene, &env, &opts(12, 2)));
    // Stopping after the last pass is no cancellation.
    let whole = r.render(&opts(12, 2), |_| ControlFlow::Break(())).unwrap();
    assert_eq!(whole.samples, 1);
    assert!(whole.cancelled);
    let last = r.render(&opts(12, 1), |_| ControlFlow::Break(())).unwrap();
    assert!(!last.cancelled);

    // The Rust programs stop the same way.
    let rust = render_passes(&scene, &env, &opts(12, 10), |p| match p.samples() {
        4 => ControlFlow::Break(()),
        _ => ControlFlow::Continue(()),
    })
    .unwrap();
    assert!(rust.cancelled);
    assert_eq!((rust.samples, rust.image), (4, done.image));
}

#[test]
fn edits_then_a_render_equal_a_new_renderer_over_the_edited_scene() {
    let scene = cornell_box();
    let env = dark();
    let o = opts(16, 2);
    let mut r = Renderer::new(&Device::cpu(), &scene, &env).unwrap();
    let before = all(&mut r, &o).image;

    // An instance moved: only the instance level and the lights are rebuilt.
    let mut moved = scene.clone();
    let i = moved.instances.len() - 1;
    moved.instances[i].transform =
        Mat4::from_translation(Vec3::new(0.1, 0.0, 0.05)) * moved.instances[i].transform;
    r.set_instance_transform(i, moved.instances[i].transform)
        .unwrap();
    let after = all(&mut r, &o).image;
    assert_ne!(after, before, "the move must show");
    assert_eq!(after, fresh(&moved, &env, &o));

    // A material recoloured, then made alpha-tested (its meshes' GASes are rebuilt with any-hit).
    let mut recoloured = moved.clone();
    let m =
        recoloured.meshes[recoloured.instances[0].mesh as usize].primitives[0].material as usize;
    recoloured.materials[m].base_color = [0.2, 0.3, 0.9, 1.0];
    r.set_material(m, recoloured.materials[m].clone()).unwrap();
    assert_eq!(all(&mut r, &o).image, fresh(&recoloured, &env, &o));
    recoloured.materials[m].base_color = [0.2, 0.3, 0.9, 0.4];
    recoloured.materials[m].alpha_mode = AlphaMode::Blend;
    r.set_material(m, recoloured.materials[m].clone()).unwrap();
    let blended = all(&mut r, &o).image;
    assert_eq!(blended, fresh(&recoloured, &env, &o));
    assert_eq!(r.scene().materials[m], recoloured.materials[m]);

    // Another camera, and back; another environment.
    let eye = Camera::look_at(Vec3::new(0.3, 0.3, 1.2), Vec3::new(0.0, 0.25, 0.0), 0.8);
    r.set_camera(Some(eye));
    let mut seen_from = recoloured.clone();
    seen_from.cameras.insert(0, eye);
    assert_eq!(all(&mut r, &o).image, fresh(&seen_from, &env, &o));
    r.set_camera(None);
    assert_eq!(all(&mut r, &o).image, blended);
    let grey = Environment::uniform(Vec3::splat(0.5));
    r.set_environment(grey.clone());
    assert_eq!(all(&mut r, &o).image, fresh(&recoloured, &grey, &o));

    // Bad edits are errors that change nothing.
    let count = r.scene().instances.len();
    assert!(r.set_instance_transform(count, Mat4::IDENTITY).is_err());
    let mut bad = r.scene().materials[0].clone();
    bad.base_color_texture = Some(oxray_scene::TextureRef::new(999));
    let materials = r.scene().materials.len();
    assert!(r.set_material(materials, bad.clone()).is_err());
    let kept = r.scene().materials[0].clone();
    assert!(
        r.set_material(0, bad).is_err(),
        "a texture that does not exist"
    );
    assert_eq!(
        r.scene().materials[0],
        kept,
        "a refused edit changes nothing"
    );
    assert_eq!(all(&mut r, &o).image, fresh(&recoloured, &grey, &o));
}

/// A quad facing the camera, its material's base colour from a 2 x 2 texture, under a white sky.
fn textured_quad(texels: [[u8; 4]; 4]) -> SceneDesc {
    use oxray_scene::{InstanceDesc, MaterialDesc, Texture, TextureRef, Wrap};
    let mut s = SceneDesc::default();
    s.textures.push(Texture {
        name: "checker".into(),
        width: 2,
        height: 2,
        texels: texels.to_vec(),
        wrap_u: Wrap::Repeat,
        wrap_v: Wrap::Repeat,
    });
    s.materials.push(MaterialDesc {
        name: "textured".into(),
        base_color_texture: Some(TextureRef::new(0)),
        specular: 0.0,
        roughness: 1.0,
        ..Default::default()
    });
    s.meshes.push(quad_mesh("quad", 0));
    s.instances.push(InstanceDesc::new(0, Mat4::IDENTITY));
    s.cameras
        .push(Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, 0.9));
    s
}

#[test]
fn a_texture_edit_then_a_render_equals_a_new_renderer_over_the_edited_scene() {
    let red = [[255, 0, 0, 255]; 4];
    let mut blue = [[0, 0, 255, 255]; 4];
    blue[1] = [255, 255, 255, 255];
    let env = Environment::uniform(Vec3::ONE);
    let o = opts(16, 2);
    let scene = textured_quad(red);
    let mut r = Renderer::new(&Device::cpu(), &scene, &env).unwrap();
    let before = all(&mut r, &o).image;
    let centre = before.pixels[(8 * 16 + 8) as usize];
    assert!(centre[0] > 4.0 * centre[2], "a red quad: {centre:?}");

    let edited = textured_quad(blue);
    r.set_texture(0, edited.textures[0].clone()).unwrap();
    let after = all(&mut r, &o).image;
    assert_ne!(after, before, "the new texture must show");
    assert_eq!(after, fresh(&edited, &env, &o));
    assert_eq!(r.scene().textures[0], edited.textures[0]);

    // Bad edits are errors that change nothing.
    let mut bad = edited.textures[0].clone();
    bad.texels.pop();
    assert!(
        r.set_texture(0, bad.clone()).is_err(),
        "texels that do not fill the size"
    );
    assert!(r.set_texture(1, edited.textures[0].clone()).is_err());
    assert_eq!(r.scene().textures[0], edited.textures[0]);
    assert_eq!(all(&mut r, &o).image, after);
}

#[test]
fn seeds_choose_the_random_sequence() {
    let scene = cornell_box();
    let env = dark();
    let mut r = Renderer::new(&Device::cpu(), &scene, &env).unwrap();
    let with = |seed| RenderOptions {
        seed,
        ..opts(16, 2)
    };
    let zero = all(&mut r, &with(0)).image;
    assert_eq!(
        zero,
        fresh(&scene, &env, &opts(16, 2)),
        "seed 0 is the default"
    );
    let one = all(&mut r, &with(1)).image;
    let two = all(&mut r, &with(2)).image;
    assert_ne!(one, zero);
    assert_ne!(one, two);
    assert_eq!(one, all(&mut r, &with(1)).image);
    assert_eq!(one, render(&scene, &env, &with(1), |_| {}).unwrap());
    // Different seeds are the same estimate: their means agree within noise.
    let mean = |i: &Image| {
        i.pixels
            .iter()
            .map(|p| (p[0] + p[1] + p[2]) as f64)
            .sum::<f64>()
    };
    let more = |seed| RenderOptions {
        seed,
        ..opts(32, 16)
    };
    let (a, b) = (
        mean(&all(&mut r, &more(7)).image),
        mean(&all(&mut r, &more(0)).image),
    );
    assert!((a - b).abs() < 0.05 * b, "{a} against {b}");
}

#[test]
fn aovs_hold_the_first_hit_on_both_versions() {
    let scene = cornell_box();
    // A grey sky, seen through the open front only where a pixel looks past the box.
    let env = dark();
    let o = RenderOptions {
        aovs: true,
        filter: oxray_render::filter::Filter::Box,
        ..opts(24, 3)
    };
    let mut r = Renderer::new(&Device::cpu(), &scene, &env).unwrap();
    let done = all(&mut r, &o);
    let aovs = done.aovs.clone().expect("AOVs were asked for");
    assert_eq!((aovs.width, aovs.height), (24, 24));
    assert!(aovs.samples.iter().all(|&s| s == 3.0));
    // The image is the one rendered without AOVs.
    assert_eq!(
        done.image,
        fresh(
            &scene,
            &env,
            &RenderOptions {
                aovs: false,
                ..o.clone()
            }
        )
    );
    // The Rust programs write the same sums.
    let rust = render_passes(&scene, &env, &o, |_| ControlFlow::Continue(())).unwrap();
    assert_eq!(rust.aovs.as_ref(), Some(&aovs));

    // Camera rays hit the box's walls, blocks or light, or miss past its edges.
    let camera = oxray_render::camera_frame(&scene, &o).unwrap();
    let (lo, hi) = scene.content_bounds().unwrap();
    let far = (hi - lo).length() + (camera.origin - (lo + hi) * 0.5).length();
    let mut hits = 0;
    for (i, &d) in aovs.depth.iter().enumerate() {
        if d.is_infinite() {
            assert_eq!((aovs.albedo[i], aovs.normal[i]), ([0.0; 3], [0.0; 3]));
            continue;
        }
        hits += 1;
        assert!(d > 0.0 && d < far, "pixel {i}: depth {d}");
        let n = Vec3::from(aovs.normal[i]);
        assert!(n.length() <= 1.0 + 1e-4, "pixel {i}: normal {n}");
        assert!(aovs.albedo[i].iter().all(|a| (0.0..=1.0).contains(a)));
    }
    assert!(hits > aovs.depth.len() * 3 / 4, "{hits} pixels see the box");
    // The middle of the left edge is the red wall (the Cornell data's orientation), seen
    // from the camera: its normal points to the camera's right, its albedo is red.
    let left = 12 * 24 + 3;
    let (a, n) = (aovs.albedo[left], aovs.normal[left]);
    assert!(
        a[0] > 2.0 * a[1] && a[0] > 2.0 * a[2],
        "red wall albedo {a:?}"
    );
    let right = camera.right.normalize();
    assert!(
        Vec3::from(n).dot(right) > 0.9,
        "red wall normal {n:?}, camera right {right}"
    );

    // Misses: no depth, no albedo.
    let open = RenderOptions {
        camera: None,
        ..o.clone()
    };
    let mut outside = scene.clone();
    outside.cameras[0] = Camera::look_at(Vec3::new(0.0, 0.0, 40.0), Vec3::ZERO, 0.3);
    let mut r = Renderer::new(&Device::cpu(), &outside, &env).unwrap();
    let far_view = all(&mut r, &open).aovs.unwrap();
    let corner = 0;
    assert_eq!(far_view.depth[corner], f32::INFINITY);
    assert_eq!(far_view.albedo[corner], [0.0; 3]);
    assert!(far_view.depth.iter().any(|d| d.is_finite()));
}

#[test]
fn aovs_are_layers_of_one_exr() {
    let scene = cornell_box();
    let env = dark();
    let o = RenderOptions {
        aovs: true,
        ..opts(8, 2)
    };
    let done = render_passes(&scene, &env, &o, |_| ControlFlow::Continue(())).unwrap();
    let dir = std::env::temp_dir().join(format!("oxray-aov-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("layers.exr");
    done.save_exr(&path).unwrap();
    let read = exr::prelude::read_all_flat_layers_from_file(&path).unwrap();
    let layer = &read.layer_data[0];
    let names: Vec<String> = layer
        .channel_data
        .list
        .iter()
        .map(|c| c.name.to_string())
        .collect();
    let mut expected = [
        "A",
        "B",
        "G",
        "R",
        "albedo.B",
        "albedo.G",
        "albedo.R",
        "depth.Z",
        "normal.X",
        "normal.Y",
        "normal.Z",
        "samples.Y",
    ];
    expected.sort();
    assert_eq!(names, expected);
    let channel = |name: &str| -> Vec<f32> {
        let c = layer
            .channel_data
            .list
            .iter()
            .find(|c| c.name.to_string() == name)
            .unwrap();
        c.sample_data.values_as_f32().collect()
    };
    let aovs = done.aovs.as_ref().unwrap();
    assert_eq!(
        channel("R"),
        done.image.pixels.iter().map(|p| p[0]).collect::<Vec<_>>()
    );
    assert_eq!(channel("depth.Z"), aovs.depth);
    assert_eq!(channel("samples.Y"), aovs.samples);
    assert_eq!(
        channel("normal.Y"),
        aovs.normal.iter().map(|n| n[1]).collect::<Vec<_>>()
    );
    // Without AOVs: the beauty alone; a PNG name is refused (AOVs need EXR).
    let plain = render_passes(&scene, &env, &opts(8, 1), |_| ControlFlow::Continue(())).unwrap();
    plain.save_exr(&path).unwrap();
    let read = exr::prelude::read_all_flat_layers_from_file(&path).unwrap();
    assert_eq!(read.layer_data[0].channel_data.list.len(), 4);
    let png = dir.join("layers.png");
    assert!(done.save_exr(&png).unwrap_err().contains(".exr"));
    assert!(!png.exists());
    std::fs::remove_dir_all(&dir).ok();
}

/// The same renderer on CUDA device 0 where there is one (`OXRAY_REQUIRE_GPU=1` makes its
/// absence a failure): passes, cancellation and edits behave as on the CPU, and the first hits
/// (AOVs) agree with the CPU's up to floating-point rounding.
#[test]
fn the_renderer_on_cuda_agrees_with_the_cpu() {
    let cuda = match Device::cuda(0) {
        Ok(d) => d,
        Err(e) => {
            assert!(
                std::env::var_os("OXRAY_REQUIRE_GPU").is_none(),
                "OXRAY_REQUIRE_GPU is set but there is no CUDA device: {e}"
            );
            println!("skipped: {e}");
            return;
        }
    };
    let scene = cornell_box();
    let env = dark();
    let o = RenderOptions {
        aovs: true,
        ..opts(32, 4)
    };
    let mut gpu = Renderer::new(&cuda, &scene, &env).unwrap();
    let mut cpu = Renderer::new(&Device::cpu(), &scene, &env).unwrap();
    let stop_at_two = |p: &oxray_render::Progress| match p.samples() {
        2 => ControlFlow::Break(()),
        _ => ControlFlow::Continue(()),
    };
    let g = gpu.render(&o, stop_at_two).unwrap();
    let c = cpu.render(&o, stop_at_two).unwrap();
    assert!(g.cancelled && g.samples == 2);
    // The same paths up to rounding: the same number of rays, give or take a few percent.
    let (gr, cr) = (g.rays as f64, c.rays as f64);
    assert!(cr >= (32 * 32 * 2) as f64, "{cr}");
    assert!(
        (gr - cr).abs() <= 0.05 * cr,
        "{gr} rays on CUDA, {cr} on the CPU"
    );
    let (ga, ca) = (g.aovs.unwrap(), c.aovs.unwrap());
    assert_eq!(ga.samples, ca.samples);
    let mut close = 0;
    for (dg, dc) in ga.depth.iter().zip(&ca.depth) {
        if dg == dc || (dg - dc).abs() <= 1e-4 * dc.abs() {
            close += 1;
        }
    }
    assert!(
        close * 100 >= ga.depth.len() * 99,
        "{close} of {} depths agree",
        ga.depth.len()
    );

    // An edit on both, then the same images up to noise: the mean radiance agrees.
    let i = scene.instances.len() - 1;
    let moved = Mat4::from_translation(Vec3::new(0.1, 0.0, 0.0)) * scene.instances[i].transform;
    gpu.set_instance_transform(i, moved).unwrap();
    cpu.set_instance_transform(i, moved).unwrap();
    let more = opts(32, 16);
    let mean = |i: &Image| {
        i.pixels
            .iter()
            .map(|p| (p[0] + p[1] + p[2]) as f64)
            .sum::<f64>()
    };
    let (a, b) = (
        mean(&all(&mut gpu, &more).image),
        mean(&all(&mut cpu, &more).image),
    );
    assert!((a - b).abs() < 0.05 * b, "{a} against {b}");
}

/// A mesh of one quad ([`common::quad`]) with material `material`.
fn quad_mesh(name: &str, material: u32) -> oxray_scene::MeshDesc {
    oxray_scene::MeshDesc {
        name: name.into(),
        primitives: vec![common::quad(material)],
    }
}

/// The SBT index of a hit adds the instance's offset (§7.3): a scene whose only placement is
/// untransformed is traced through its GAS alone only where that mesh's hit records start the
/// table. With an unplaced mesh before it (a glTF file's unused mesh), its records start later,
/// and a root GAS would shade the placed mesh with the unplaced mesh's materials.
#[test]
fn an_unplaced_mesh_before_the_only_placement_keeps_its_materials_out() {
    use oxray_scene::{InstanceDesc, MaterialDesc};
    let emission = [2.0f32, 3.0, 4.0];
    let scene = SceneDesc {
        materials: vec![
            MaterialDesc {
                name: "unused".into(),
                base_color: [0.0, 0.0, 0.0, 1.0],
                ..Default::default()
            },
            MaterialDesc {
                name: "lamp".into(),
                emissive: emission,
                ..Default::default()
            },
        ],
        meshes: vec![quad_mesh("unused", 0), quad_mesh("lamp", 1)],
        instances: vec![InstanceDesc::new(1, Mat4::IDENTITY)],
        cameras: vec![Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, 0.5)],
        ..Default::default()
    };
    // The same placement with the unused mesh gone.
    let mut alone = scene.clone();
    alone.meshes.remove(0);
    alone.instances[0].mesh = 0;
    let o = opts(8, 2);
    let rust = render(&scene, &dark(), &o, |_| {}).unwrap();
    let cpp = fresh(&scene, &dark(), &o);
    for img in [&rust, &cpp] {
        // Every pixel sees the lamp (half-angle 0.25 rad at distance 3 spans 0.77 < 1).
        for p in &img.pixels {
            assert_eq!(&p[..3], &emission[..], "a pixel shows {p:?}");
        }
    }
    assert_eq!(rust, render(&alone, &dark(), &o, |_| {}).unwrap());
    assert_eq!(cpp, fresh(&alone, &dark(), &o));
}
