//! glTF vertex colours (`COLOR_0`) and the second texture coordinate set (`TEXCOORD_1`), from
//! the file to the image: colours multiply the base colour and its alpha, interpolated across
//! each triangle; a texture may read either set.

use glam::{Mat4, Vec3};
use oxray_render::lights::Environment;
use oxray_render::{render, Image, RenderOptions};
use oxray_scene::{AlphaMode, Camera, InstanceDesc, MaterialDesc, MeshDesc, Primitive, SceneDesc};
use std::path::{Path, PathBuf};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../oxray-scene/tests/data")
        .join(name)
}

/// A white environment lights the scene, in a pool of `threads` threads.
fn shoot(scene: &SceneDesc, size: u32, spp: u32, env: Vec3, threads: usize) -> Image {
    let opts = RenderOptions {
        width: size,
        height: size,
        spp,
        max_depth: 3,
        ..Default::default()
    };
    let env = Environment::uniform(env);
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(|| render(scene, &env, &opts, |_| {}).unwrap())
}

/// The sum of each channel over the pixels whose column is in `cols` and row in `rows`.
fn sum(img: &Image, cols: std::ops::Range<u32>, rows: std::ops::Range<u32>) -> Vec3 {
    let mut s = Vec3::ZERO;
    for y in rows {
        for x in cols.clone() {
            let p = img.pixels[(y * img.width + x) as usize];
            s += Vec3::new(p[0], p[1], p[2]);
        }
    }
    s
}

/// A 2 x 2 quad in the z = 0 plane, facing a camera on +Z.
fn quad_scene(colors: Vec<[f32; 4]>, material: MaterialDesc) -> SceneDesc {
    SceneDesc {
        meshes: vec![MeshDesc {
            name: "quad".into(),
            primitives: vec![Primitive {
                positions: vec![
                    [-1.0, -1.0, 0.0],
                    [1.0, -1.0, 0.0],
                    [1.0, 1.0, 0.0],
                    [-1.0, 1.0, 0.0],
                ],
                normals: vec![[0.0, 0.0, 1.0]; 4],
                colors,
                triangles: vec![[0, 1, 2], [0, 2, 3]],
                ..Default::default()
            }],
        }],
        materials: vec![material],
        instances: vec![InstanceDesc {
            mesh: 0,
            transform: Mat4::IDENTITY,
            node: None,
        }],
        cameras: vec![Camera::look_at(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, 1.0)],
        ..Default::default()
    }
}

#[test]
fn a_quad_with_vertex_colours_renders_with_the_expected_colour_ratio() {
    // colors.gltf: a white material on a quad whose left vertices are red and right vertices
    // blue, seen head on by the file's camera. The colour at s (0 on the left edge, 1 on the
    // right) is (1 - s, 0, s); the specular lobe is grey, so green measures it and R - G and
    // B - G are the diffuse red and blue.
    let scene = SceneDesc::load(&fixture("colors.gltf")).unwrap();
    assert!(scene.warnings.is_empty(), "{:?}", scene.warnings);
    let size = 32;
    let img = shoot(&scene, size, 16, Vec3::ONE, 2);
    // Pixel column c looks at x = (2 (c + 0.5) / size - 1) tan(yfov / 2) * 2 on the quad.
    let half = 2.0 * 0.5f32.tan();
    let s_of = |c: u32| ((2.0 * (c as f32 + 0.5) / size as f32 - 1.0) * half + 1.0) * 0.5;
    let region = |cols: std::ops::Range<u32>| {
        let m = sum(&img, cols.clone(), 4..28);
        let expected =
            cols.clone().map(|c| 1.0 - s_of(c)).sum::<f32>() / cols.map(s_of).sum::<f32>();
        ((m.x - m.y) / (m.z - m.y), expected, m)
    };
    for cols in [4..10, 13..19, 22..28] {
        let (ratio, expected, m) = region(cols.clone());
        assert!(
            (ratio / expected - 1.0).abs() < 0.05,
            "columns {cols:?}: red/blue {ratio}, expected {expected} ({m})"
        );
        assert!(m.y > 0.0 && m.y < 0.2 * m.x.max(m.z), "{m}");
    }
    // Bit-identical whatever the thread count.
    let other = shoot(&scene, size, 16, Vec3::ONE, 3);
    assert!(img
        .pixels
        .iter()
        .zip(&other.pixels)
        .all(|(a, b)| a.map(f32::to_bits) == b.map(f32::to_bits)));
}

#[test]
fn vertex_colours_multiply_the_base_colour_factor() {
    // The same quad coloured c through its vertices under a factor f, and through the factor
    // f * c alone, renders the same image.
    let (f, c) = ([0.5, 1.0, 0.8, 1.0], [0.9, 0.5, 0.2, 1.0]);
    let material = |base_color| MaterialDesc {
        base_color,
        metallic: 0.0,
        roughness: 0.7,
        ..Default::default()
    };
    let product = [f[0] * c[0], f[1] * c[1], f[2] * c[2], 1.0];
    let coloured = shoot(&quad_scene(vec![c; 4], material(f)), 16, 8, Vec3::ONE, 2);
    let factor = shoot(
        &quad_scene(Vec::new(), material(product)),
        16,
        8,
        Vec3::ONE,
        2,
    );
    let (a, b) = (sum(&coloured, 0..16, 0..16), sum(&factor, 0..16, 0..16));
    assert!(
        (a - b).abs().max_element() < 1e-3 * b.max_element(),
        "{a} {b}"
    );
    assert!(a.x > a.z && a.z > a.y * 0.5, "{a}");
}

#[test]
fn vertex_alpha_cuts_out_like_the_base_colour_alpha() {
    // An emissive quad in a black environment, opaque on the right and transparent on the
    // left through its vertex alpha: with MASK (cutoff 0.5) the left half disappears.
    let colors = vec![
        [1.0, 1.0, 1.0, 0.0],
        [1.0, 1.0, 1.0, 1.0],
        [1.0, 1.0, 1.0, 1.0],
        [1.0, 1.0, 1.0, 0.0],
    ];
    let material = MaterialDesc {
        emissive: [1.0; 3],
        alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
        ..Default::default()
    };
    let img = shoot(
        &quad_scene(colors.clone(), material.clone()),
        16,
        1,
        Vec3::ZERO,
        2,
    );
    let (left, right) = (sum(&img, 2..6, 4..12), sum(&img, 10..14, 4..12));
    assert_eq!(left, Vec3::ZERO);
    assert!(right.min_element() > 0.9 * 32.0, "{right}");
    // Opaque materials ignore alpha, as glTF says.
    let opaque = MaterialDesc {
        alpha_mode: AlphaMode::Opaque,
        ..material
    };
    let img = shoot(&quad_scene(colors, opaque), 16, 1, Vec3::ZERO, 2);
    assert!(sum(&img, 2..6, 4..12).min_element() > 0.9 * 32.0);
}

#[test]
fn a_base_colour_texture_reads_the_set_its_material_names() {
    // texcoord1.gltf: set 0 puts every vertex on the red texel, set 1 spans the 2 x 2 texture
    // (red, green / blue, white), and the base colour texture uses set 1.
    let scene = SceneDesc::load(&fixture("texcoord1.gltf")).unwrap();
    assert!(scene.warnings.is_empty(), "{:?}", scene.warnings);
    let img = shoot(&scene, 16, 4, Vec3::ONE, 2);
    let quadrant = |x: u32, y: u32| {
        let m = sum(&img, x..x + 4, y..y + 4);
        m / m.max_element()
    };
    let (tl, tr, bl, br) = (
        quadrant(2, 2),
        quadrant(10, 2),
        quadrant(2, 10),
        quadrant(10, 10),
    );
    assert!(tl.x == 1.0 && tl.y < 0.3 && tl.z < 0.3, "{tl}");
    assert!(tr.y == 1.0 && tr.x < 0.3 && tr.z < 0.3, "{tr}");
    assert!(bl.z == 1.0 && bl.x < 0.3 && bl.y < 0.3, "{bl}");
    assert!(br.min_element() > 0.8, "{br}");
    // Through set 0 the whole quad is red.
    let mut set0 = scene.clone();
    let r = set0.materials[0].base_color_texture.as_mut().unwrap();
    r.tex_coord = 0;
    let img = shoot(&set0, 16, 4, Vec3::ONE, 2);
    for (x, y) in [(2, 2), (10, 2), (2, 10), (10, 10)] {
        let m = sum(&img, x..x + 4, y..y + 4);
        assert!(m.y < 0.3 * m.x && m.z < 0.3 * m.x, "{m}");
    }
}
