//! Normal maps follow glTF's tangent-space convention: +X along increasing u, +Y up in the
//! image (along decreasing v, as glTF's v runs down the image), +Z out of the surface, and the
//! bitangent is cross(N, T) * w with w = -1 for a mirrored mapping. A quad whose normal map
//! tilts every normal by 30 degrees in one direction, lit by a directional light from that side
//! and then from the opposite side, must be much brighter in the first case, in both of the
//! renderer's versions.

use glam::{Mat4, Vec3};
use oxray::Device;
use oxray_render::lights::Environment;
use oxray_render::{device::render_on, render, Image, RenderOptions};
use oxray_scene::{
    Camera, InstanceDesc, LightKind, MaterialDesc, MeshDesc, Primitive, PunctualLight, SceneDesc,
    Texture, TextureRef,
};

/// A 2 x 2 quad in the XY plane facing +Z, seen head on from +Z (image right is +X, image up
/// +Y), with a constant normal map whose tangent-space normal is `n`, lit by one directional
/// light arriving from direction `from`. `mirror_u` mirrors the mapping left to right.
fn scene(n: Vec3, from: Vec3, mirror_u: bool) -> SceneDesc {
    let n = n.normalize();
    let texel = n
        .to_array()
        .map(|c| ((c * 0.5 + 0.5) * 255.0).round() as u8);
    // glTF texture coordinates: v = 0 is the top of the image.
    let mut uvs = vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]];
    if mirror_u {
        for uv in &mut uvs {
            uv[0] = 1.0 - uv[0];
        }
    }
    let quad = Primitive {
        positions: vec![
            [-1.0, -1.0, 0.0],
            [1.0, -1.0, 0.0],
            [1.0, 1.0, 0.0],
            [-1.0, 1.0, 0.0],
        ],
        normals: vec![[0.0, 0.0, 1.0]; 4],
        uvs,
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        ..Default::default()
    };
    SceneDesc {
        meshes: vec![MeshDesc {
            name: "quad".into(),
            primitives: vec![quad],
        }],
        materials: vec![MaterialDesc {
            base_color: [0.8, 0.8, 0.8, 1.0],
            roughness: 1.0,
            normal_texture: Some(TextureRef::new(0)),
            ..Default::default()
        }],
        textures: vec![Texture {
            name: "slope".into(),
            width: 2,
            height: 2,
            texels: vec![[texel[0], texel[1], texel[2], 255]; 4],
            wrap_u: Default::default(),
            wrap_v: Default::default(),
        }],
        instances: vec![InstanceDesc {
            mesh: 0,
            transform: Mat4::IDENTITY,
            node: None,
        }],
        cameras: vec![Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, 0.5)],
        lights: vec![PunctualLight {
            kind: LightKind::Directional,
            position: Vec3::ZERO,
            direction: -from.normalize(),
            intensity: Vec3::splat(683.0),
            range: None,
        }],
        ..Default::default()
    }
}

fn mean(img: &Image) -> f32 {
    img.pixels.iter().map(|p| p[0] + p[1] + p[2]).sum::<f32>() / (3 * img.pixels.len()) as f32
}

fn opts() -> RenderOptions {
    RenderOptions {
        width: 8,
        height: 8,
        spp: 2,
        max_depth: 2,
        ..Default::default()
    }
}

/// Mean brightness lit from `toward` and from the mirror image of `toward` about the quad's
/// normal axis, for a normal map tilted toward `tilt` (tangent space).
fn lit_and_opposite(
    tilt: Vec3,
    toward: Vec3,
    mirror_u: bool,
    run: &dyn Fn(&SceneDesc) -> Image,
) -> (f32, f32) {
    let n = Vec3::new(tilt.x * 0.5, tilt.y * 0.5, 0.75f32.sqrt());
    let lit = toward * 0.8 + Vec3::Z * 0.6;
    let opposite = -toward * 0.8 + Vec3::Z * 0.6;
    (
        mean(&run(&scene(n, lit, mirror_u))),
        mean(&run(&scene(n, opposite, mirror_u))),
    )
}

fn check(run: &dyn Fn(&SceneDesc) -> Image, who: &str) {
    // Tangent +Y is image up (+Y in the world here), tangent +X is +u: image right, or image
    // left when the mapping is mirrored (then w = -1 keeps +Y up).
    let cases = [
        ("+Y up", Vec3::Y, Vec3::Y, false),
        ("+X right", Vec3::X, Vec3::X, false),
        ("+Y up, mirrored u", Vec3::Y, Vec3::Y, true),
        ("+X along u, mirrored u", Vec3::X, -Vec3::X, true),
    ];
    for (name, tilt, toward, mirror) in cases {
        let (lit, opposite) = lit_and_opposite(tilt, toward, mirror, run);
        // Lambert with a normal tilted 30 degrees: cos 0.92 toward the light, 0.12 away.
        println!("{who}: {name}: lit side {lit:.4}, opposite {opposite:.4}");
        assert!(
            lit > 4.0 * opposite && lit > 0.0,
            "{who}: {name}: the normal map tilts the wrong way ({lit} vs {opposite})"
        );
    }
}

#[test]
fn normal_maps_tilt_toward_the_gltf_tangent_frame() {
    check(
        &|s| render(s, &Environment::uniform(Vec3::ZERO), &opts(), |_| {}).unwrap(),
        "rust",
    );
}

#[test]
fn device_programs_tilt_normal_maps_the_same_way() {
    if std::process::Command::new("c++")
        .arg("--version")
        .output()
        .is_err()
    {
        eprintln!("skipped: no host C++ compiler");
        return;
    }
    let device = Device::cpu();
    check(
        &|s| {
            render_on(
                &device,
                s,
                &Environment::uniform(Vec3::ZERO),
                &opts(),
                |_| {},
            )
            .unwrap()
        },
        "c++",
    );
}
