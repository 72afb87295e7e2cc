//! The path tracer end to end: the built-in Cornell box checked by image statistics, thread-count
//! independence, materials against analytic expectations (a white furnace, a mirror, glass),
//! alpha cutouts on the pine glTF, and the `oxray render` command's outputs and errors.

mod common;

use glam::Vec3;
use oxray_render::lights::Environment;
use oxray_render::{render, Image, RenderOptions};
use oxray_scene::{
    cornell_box, AlphaMode, Camera, InstanceDesc, MaterialDesc, MeshDesc, Primitive, SceneDesc,
    Texture, TextureRef,
};
use std::path::Path;

fn opts(w: u32, h: u32, spp: u32, max_depth: u32) -> RenderOptions {
    RenderOptions {
        width: w,
        height: h,
        spp,
        max_depth,
        ..Default::default()
    }
}

fn black() -> Environment {
    Environment::uniform(Vec3::ZERO)
}

fn cornell(w: u32, h: u32, spp: u32, depth: u32) -> Image {
    render(&cornell_box(), &black(), &opts(w, h, spp, depth), |_| {}).unwrap()
}

#[test]
fn cornell_box_has_a_bright_light_red_wall_left_green_right_and_no_nan() {
    let (w, h) = (64u32, 64u32);
    let img = cornell(w, h, 8, 6);
    let px = &img.pixels;
    assert!(
        px.iter().flatten().all(|c| c.is_finite() && *c >= 0.0),
        "NaN, inf or negative radiance"
    );
    let at = |x: u32, y: u32| px[(y * w + x) as usize];
    // The light is at the top centre: the brightest pixel there sees it directly.
    let light = (5..11)
        .flat_map(|y| (26..38).map(move |x| (x, y)))
        .map(|(x, y)| at(x, y))
        .max_by(|a, b| a[0].total_cmp(&b[0]))
        .unwrap();
    assert!(light[0] > 5.0 && light[1] > 3.0, "light {light:?}");
    // As in the Cornell data, seen from its camera: the red wall on the left, the green one on
    // the right. Each wall fills most of its third of the image and tints the rest of it (the
    // warm light makes every white surface a little red).
    let third = |x0: u32| {
        let mut s = Vec3::ZERO;
        for y in 0..h {
            for x in x0..x0 + w / 3 {
                s += Vec3::from_slice(&at(x, y)[..3]);
            }
        }
        s
    };
    let (left, right) = (third(0), third(w - w / 3));
    assert!(
        left.x > 1.5 * left.y && left.x > 1.5 * left.z,
        "the left third is not reddish: {left}"
    );
    assert!(
        right.y > 1.1 * right.x && right.y > 1.5 * right.z,
        "the right third is not greenish: {right}"
    );
    assert!(
        left.x / left.y > 3.0 * (right.x / right.y),
        "{left} vs {right}"
    );
}

#[test]
fn render_is_deterministic_across_thread_counts() {
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| cornell(32, 32, 4, 4))
    };
    let (a, b) = (run(1), run(4));
    assert!(a
        .pixels
        .iter()
        .zip(&b.pixels)
        .all(|(p, q)| p.iter().zip(q).all(|(x, y)| x.to_bits() == y.to_bits())));
}

/// A closed cube seen from inside, every face of material 0.
fn inside_cube(material: MaterialDesc) -> SceneDesc {
    let mut prim = Primitive::default();
    let c = [-1.0f32, 1.0];
    for z in c {
        for y in c {
            for x in c {
                prim.positions.push([x, y, z]);
            }
        }
    }
    // Faces of the cube (index = x + 2y + 4z).
    for q in [
        [0, 1, 3, 2],
        [4, 6, 7, 5],
        [0, 4, 5, 1],
        [2, 3, 7, 6],
        [0, 2, 6, 4],
        [1, 5, 7, 3],
    ] {
        prim.triangles.push([q[0], q[1], q[2]]);
        prim.triangles.push([q[0], q[2], q[3]]);
    }
    SceneDesc {
        meshes: vec![MeshDesc {
            name: "cube".into(),
            primitives: vec![prim],
        }],
        materials: vec![material],
        instances: vec![InstanceDesc {
            mesh: 0,
            transform: glam::Mat4::IDENTITY,
            node: None,
        }],
        cameras: vec![Camera::look_at(Vec3::ZERO, Vec3::new(0.2, 0.1, 1.0), 1.0)],
        ..Default::default()
    }
}

fn mean(img: &Image) -> Vec3 {
    img.pixels
        .iter()
        .map(|p| Vec3::new(p[0], p[1], p[2]))
        .sum::<Vec3>()
        / img.pixels.len() as f32
}

#[test]
fn furnace_emitter_interior_converges_to_the_geometric_series() {
    // Inside a closed box whose walls reflect a fraction a of light and emit E, the radiance is
    // E (1 + a + a^2 + ...) truncated at the path length: with 4 vertices, E (1 + a + a^2 + a^3).
    // This checks emission, the BSDF's energy (its albedo with the Fresnel split), next-event
    // estimation and MIS together: any double counting or lost weight moves the mean.
    let a = 0.5f32;
    let m = MaterialDesc {
        base_color: [a, a, a, 1.0],
        roughness: 1.0,
        emissive: [1.0, 1.0, 1.0],
        ..Default::default()
    };
    let img = render(&inside_cube(m), &black(), &opts(24, 24, 64, 4), |_| {}).unwrap();
    let got = mean(&img).x;
    // The diffuse + GGX split reflects a little less than a at normal incidence and more at
    // grazing; the measured directional albedo of this material lies within 3% of a.
    let lo = 1.0 + 0.97 * a + (0.97 * a).powi(2) + (0.97 * a).powi(3);
    let hi = 1.0 + 1.03 * a + (1.03 * a).powi(2) + (1.03 * a).powi(3);
    assert!(
        got > lo * 0.98 && got < hi * 1.02,
        "{got} not in {lo}..{hi}"
    );
}

#[test]
fn white_furnace_ball_reflects_the_whole_environment() {
    // A white ball under a uniform white sky, no other light: every pixel sees it, and an
    // energy-conserving BRDF returns exactly the sky's radiance, 1, whatever the roughness, for
    // a metal and for a diffuse base under a dielectric coat (next-event estimation on the sky,
    // BSDF sampling and their MIS weights all take part). Single-scattering GGX without
    // compensation returns as little as 0.7 for a rough metal.
    let env = Environment::uniform(Vec3::ONE);
    let mut worst = 0.0f32;
    for (kind, metallic, specular) in [
        ("metal", 1.0, 1.0),
        ("coated diffuse", 0.0, 1.0),
        ("Lambertian", 0.0, 0.0),
    ] {
        let mut row = String::new();
        for roughness in [0.0, 0.25, 0.5, 0.75, 1.0] {
            let mut s = SceneDesc::from_mesh("ball", oxray_scene::mesh::Mesh::icosphere(4));
            s.materials[0] = MaterialDesc {
                base_color: [1.0; 4],
                metallic,
                roughness,
                specular,
                ..Default::default()
            };
            s.cameras = vec![Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, 0.5)];
            let m = mean(&render(&s, &env, &opts(16, 16, 32, 8), |_| {}).unwrap());
            row += &format!(" {:.4}", m.x);
            worst = worst.max((m.x - 1.0).abs());
            assert!(
                (m.x - 1.0).abs() < 0.015,
                "{kind}, roughness {roughness}: the furnace returns {m}"
            );
        }
        println!("furnace ball, {kind}, roughness 0, 0.25, 0.5, 0.75, 1:{row}");
    }
    println!("furnace ball: largest deviation from 1: {worst:.4}");
}

#[test]
fn uniform_environment_is_seen_through_glass_and_mirrors() {
    // A white environment seen directly, reflected by a perfect white mirror and refracted by
    // clear glass keeps radiance 1 (both lose nothing); a grey diffuse ball under it reflects
    // at most its albedo.
    let scene = |m: MaterialDesc| {
        let mut s = SceneDesc::from_mesh("ball", oxray_scene::mesh::Mesh::icosphere(3));
        s.materials[0] = m;
        s.cameras = vec![Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, 0.5)];
        s
    };
    let env = Environment::uniform(Vec3::ONE);
    let render1 = |m| render(&scene(m), &env, &opts(16, 16, 16, 16), |_| {}).unwrap();
    let mirror = render1(MaterialDesc {
        base_color: [1.0; 4],
        metallic: 1.0,
        roughness: 0.0,
        ..Default::default()
    });
    let glass = render1(MaterialDesc {
        base_color: [1.0; 4],
        transmission: 1.0,
        ior: 1.5,
        ..Default::default()
    });
    // Glass is sampled exactly (Fresnel picks reflection or refraction, each of weight 1), so
    // a sample is 1 unless its path was cut at the depth limit while trapped inside by internal
    // reflections; the mirror's GGX lobe has a floor on its roughness, so its tail adds a
    // little noise.
    for p in &glass.pixels {
        assert!(p[0] <= 1.0 + 1e-4, "glass: {p:?}");
    }
    let g = mean(&glass).x;
    assert!(g > 0.97, "glass mean {g}");
    let m = mean(&mirror).x;
    assert!((m - 1.0).abs() < 0.01, "mirror mean {m}");
    for p in &mirror.pixels {
        assert!((p[0] - 1.0).abs() < 0.1, "mirror: {p:?}");
    }
    let grey = render1(MaterialDesc {
        base_color: [0.5, 0.5, 0.5, 1.0],
        roughness: 1.0,
        ..Default::default()
    });
    let centre = grey.pixels[8 * 16 + 8][0];
    assert!(centre > 0.4 && centre < 0.56, "{centre}");
}

#[test]
fn alpha_mask_cuts_holes_in_both_ray_types() {
    // A quad textured half transparent (left) and half opaque (right) in front of a white
    // environment: camera rays pass through the transparent half, and an emissive floor below
    // is not shadowed through it.
    let tex = Texture {
        name: "half".into(),
        width: 2,
        height: 1,
        texels: vec![[255, 0, 0, 0], [0, 0, 255, 255]],
        wrap_u: Default::default(),
        wrap_v: Default::default(),
    };
    let quad = common::quad(0);
    let mut scene = SceneDesc {
        meshes: vec![MeshDesc {
            name: "quad".into(),
            primitives: vec![quad],
        }],
        materials: vec![MaterialDesc {
            base_color: [1.0; 4],
            base_color_texture: Some(TextureRef::new(0)),
            alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
            emissive: [1.0, 1.0, 1.0],
            roughness: 1.0,
            ..Default::default()
        }],
        textures: vec![tex],
        instances: vec![InstanceDesc {
            mesh: 0,
            transform: glam::Mat4::IDENTITY,
            node: None,
        }],
        cameras: vec![Camera::look_at(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, 1.2)],
        ..Default::default()
    };
    let env = Environment::uniform(Vec3::new(0.0, 1.0, 0.0));
    let img = render(&scene, &env, &opts(32, 32, 4, 4), |_| {}).unwrap();
    let at = |x: usize, y: usize| img.pixels[y * 32 + x];
    // Left: the green environment through the hole. Right: the quad's blue texel (emission
    // times texture is not used: emission is white, plus blue reflection of green: no red).
    let left = at(10, 16);
    let right = at(22, 16);
    assert_eq!(left[0], 0.0, "{left:?}");
    assert!((left[1] - 1.0).abs() < 1e-6, "{left:?}");
    assert!(right[0] >= 1.0 && right[2] >= 1.0, "{right:?}");
    // Without the mask, the left half is opaque too.
    scene.materials[0].alpha_mode = AlphaMode::Opaque;
    let img = render(&scene, &env, &opts(32, 32, 4, 4), |_| {}).unwrap();
    assert!(img.pixels[16 * 32 + 10][0] >= 1.0);
}

fn data(rel: &str) -> Option<std::path::PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data")
        .join(rel);
    if p.exists() {
        Some(p)
    } else {
        eprintln!("skipping: {} is absent", p.display());
        None
    }
}

#[test]
fn pine_leaves_show_holes_where_the_texture_is_transparent() {
    let Some(path) = data("gltf/smallpine/scene.gltf") else {
        return;
    };
    let scene = SceneDesc::load(&path).unwrap();
    let env = Environment::uniform(Vec3::new(0.0, 0.0, 1.0));
    let o = opts(96, 96, 1, 1);
    // With a blue environment, a pixel is pure blue exactly when its camera ray got through.
    let through = |s: &SceneDesc| {
        let img = render(s, &env, &o, |_| {}).unwrap();
        img.pixels
            .iter()
            .filter(|p| p[0] == 0.0 && p[1] == 0.0 && p[2] == 1.0)
            .count()
    };
    let with_alpha = through(&scene);
    let mut opaque = scene.clone();
    let mut leaves = 0;
    for m in &mut opaque.materials {
        if m.alpha_mode != AlphaMode::Opaque {
            m.alpha_mode = AlphaMode::Opaque;
            leaves += 1;
        }
    }
    assert!(leaves > 0, "the pine has no alpha-tested material");
    let without = through(&opaque);
    // The leaf cards cover most of the tree's silhouette; their transparent texels let the
    // environment through in a good part of it.
    let covered = 96 * 96 - without;
    assert!(
        covered > 500 && with_alpha - without > covered / 5,
        "{with_alpha} pixels see through with alpha, {without} without"
    );
}

#[test]
fn scene_renders_with_instances_and_stochastic_alpha_are_thread_count_independent() {
    // Instanced glTF geometry through an IAS with BLEND leaves: the any-hit program's
    // stochastic decisions come from the path's own random state, so 1 and 3 threads give the
    // same bits.
    let Some(path) = data("gltf/smallpine/scene.gltf") else {
        return;
    };
    let scene = SceneDesc::load(&path).unwrap();
    let env = Environment::sky(1.0);
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| render(&scene, &env, &opts(40, 40, 3, 6), |_| {}).unwrap())
    };
    let (a, b) = (run(1), run(3));
    assert!(a
        .pixels
        .iter()
        .zip(&b.pixels)
        .all(|(p, q)| p.iter().zip(q).all(|(x, y)| x.to_bits() == y.to_bits())));
}

#[test]
fn mirrored_instances_keep_their_front_faces_and_emission_side() {
    // glTF: a placement with a negative determinant reverses the winding order, so a
    // single-sided emitter still emits towards the side its normal pointed before mirroring.
    // A downward-facing emissive quad is mirrored in x (which keeps it facing down): the camera
    // below sees it lit; a camera above sees nothing.
    let quad = Primitive {
        positions: vec![
            [-1.0, 0.0, -1.0],
            [1.0, 0.0, -1.0],
            [1.0, 0.0, 1.0],
            [-1.0, 0.0, 1.0],
        ],
        // Wound so that the face normal points down (-Y).
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        ..Default::default()
    };
    let mut scene = SceneDesc {
        meshes: vec![MeshDesc {
            name: "lamp".into(),
            primitives: vec![quad],
        }],
        materials: vec![MaterialDesc {
            base_color: [0.0, 0.0, 0.0, 1.0],
            emissive: [2.0, 2.0, 2.0],
            double_sided: false,
            ..Default::default()
        }],
        instances: vec![InstanceDesc {
            mesh: 0,
            transform: glam::Mat4::from_scale(Vec3::new(-1.0, 1.0, 1.0)),
            node: None,
        }],
        ..Default::default()
    };
    let seen_from = |y: f32, scene: &mut SceneDesc| {
        scene.cameras = vec![Camera::look_at(Vec3::new(0.0, y, 0.01), Vec3::ZERO, 0.3)];
        let img = render(scene, &black(), &opts(4, 4, 1, 2), |_| {}).unwrap();
        img.pixels[5][0]
    };
    // From above: nothing but a numerical residue (the Sobol sampler's numbers find one of
    // about 4e-10 in one pixel, independent ones none).
    assert_eq!(seen_from(-3.0, &mut scene), 2.0);
    assert!(seen_from(3.0, &mut scene) < 1e-6);
    // Unmirrored: the same.
    scene.instances[0].transform = glam::Mat4::IDENTITY;
    assert_eq!(seen_from(-3.0, &mut scene), 2.0);
    assert!(seen_from(3.0, &mut scene) < 1e-6);
}

#[test]
fn ground_plane_is_under_the_scene_and_outside_the_framing() {
    // A white environment: without ground, the bottom row sees the sky (exactly 1); with the
    // ground, it sees a grey diffuse plane (at most its albedo, 0.45, under a white sky).
    let mut scene = SceneDesc::from_mesh("ball", oxray_scene::mesh::Mesh::icosphere(2));
    let env = Environment::uniform(Vec3::ONE);
    let o = opts(16, 16, 4, 3);
    let bottom = |s: &SceneDesc| {
        let img = render(s, &env, &o, |_| {}).unwrap();
        img.pixels[15 * 16 + 1][0]
    };
    let camera_before = oxray_render::camera_frame(&scene, &o).unwrap();
    assert_eq!(bottom(&scene), 1.0);
    scene.add_ground();
    assert_eq!(scene.triangle_count(), 320 + 2);
    let (lo, _) = scene.bounds().unwrap();
    assert!(
        lo.y >= -1.0 - 1e-6,
        "the ground is at the ball's lowest point"
    );
    let camera_after = oxray_render::camera_frame(&scene, &o).unwrap();
    assert_eq!(camera_before.origin, camera_after.origin);
    let g = bottom(&scene);
    assert!(g > 0.0 && g <= 0.46, "{g}");
}

#[test]
fn pixel_filters_spread_an_edge_by_their_width_and_keep_its_energy() {
    // An emitter of radiance 1 fills the right half of the view exactly up to the boundary
    // between columns 7 and 8. The box filter keeps every sample in its pixel's square: column 7
    // is black and column 8 white, exactly. The Gaussian and Blackman-Harris filters (radius
    // 1.5 pixels) blur the edge over their width, and a row's total stays the same.
    use oxray_render::filter::Filter;
    let half = Primitive {
        positions: vec![
            [0.0, -10.0, 0.0],
            [10.0, -10.0, 0.0],
            [10.0, 10.0, 0.0],
            [0.0, 10.0, 0.0],
        ],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        ..Default::default()
    };
    let scene = SceneDesc {
        meshes: vec![MeshDesc {
            name: "half".into(),
            primitives: vec![half],
        }],
        materials: vec![MaterialDesc {
            base_color: [0.0, 0.0, 0.0, 1.0],
            emissive: [1.0; 3],
            ..Default::default()
        }],
        instances: vec![InstanceDesc {
            mesh: 0,
            transform: glam::Mat4::IDENTITY,
            node: None,
        }],
        cameras: vec![Camera::look_at(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, 1.0)],
        ..Default::default()
    };
    let row_of = |filter| {
        let o = RenderOptions {
            filter,
            ..opts(16, 16, 64, 1)
        };
        let img = render(&scene, &black(), &o, |_| {}).unwrap();
        // The mean of the middle rows per column.
        (0..16)
            .map(|x| (4..12).map(|y| img.pixels[y * 16 + x][0]).sum::<f32>() / 8.0)
            .collect::<Vec<f32>>()
    };
    let b = row_of(Filter::Box);
    assert_eq!((b[7], b[8]), (0.0, 1.0), "{b:?}");
    let box_total: f32 = b.iter().sum();
    for f in [Filter::Gaussian, Filter::BlackmanHarris] {
        let r = row_of(f);
        println!("{f:?}: columns 5..11 {:?}", &r[5..11]);
        assert!(
            r[7] > 0.02 && r[7] < 0.5 && r[8] > 0.5 && r[8] < 0.98,
            "{f:?}: {r:?}"
        );
        assert!(r[5] < 0.01 && r[10] > 0.99, "{f:?}: {r:?}");
        let total: f32 = r.iter().sum();
        assert!(
            (total - box_total).abs() < 0.1,
            "{f:?}: {total} vs {box_total}"
        );
    }
}

/// A scene flattened for rendering ([`SceneDesc::flattened`]: its meshes placed once baked
/// into world space as one mesh) renders the scene it came from: the Cornell box's primitives
/// as separate meshes, each placed by a rotation, a scale and a translation (their vertices the
/// inverse of it), against the flattened scene, up to Monte-Carlo noise where the paths part.
#[test]
fn a_flattened_scene_renders_as_its_instances_do() {
    use glam::{Mat4, Quat};
    let box_ = cornell_box();
    let mut placed = SceneDesc {
        meshes: Vec::new(),
        instances: Vec::new(),
        ..box_.clone()
    };
    for (k, p) in box_.meshes[0].primitives.iter().enumerate() {
        let m = Mat4::from_scale_rotation_translation(
            Vec3::new(1.0 + k as f32 * 0.5, 0.7, 1.3),
            Quat::from_rotation_y(0.4 * k as f32 + 0.3),
            Vec3::new(0.1 * k as f32, -0.2, 0.3),
        );
        let inv = m.inverse();
        let mut q = p.clone();
        for v in &mut q.positions {
            *v = inv.transform_point3(Vec3::from(*v)).to_array();
        }
        placed.meshes.push(MeshDesc {
            name: format!("part {k}"),
            primitives: vec![q],
        });
        placed.instances.push(InstanceDesc::new(k as u32, m));
    }
    let flat = placed.flattened();
    assert_eq!((flat.meshes.len(), flat.instances.len()), (1, 1));
    let o = opts(24, 24, 8, 4);
    let a = render(&placed, &black(), &o, |_| {}).unwrap();
    let b = render(&flat, &black(), &o, |_| {}).unwrap();
    let all: Vec<usize> = (0..a.pixels.len()).collect();
    for c in 0..3 {
        let (mean, se, level) = common::region(&a, &b, &all, c);
        assert!(
            mean.abs() <= 4.5 * se + 1e-4 * level,
            "channel {c}: mean difference {mean} ({se} standard error, mean {level})"
        );
    }
    let same = a
        .pixels
        .iter()
        .zip(&b.pixels)
        .filter(|(p, q)| p == q)
        .count();
    println!("{same} of {} pixels bit-identical", a.pixels.len());
}
