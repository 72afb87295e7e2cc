//! glTF `KHR_texture_transform`: parsed into the material's texture references and applied by
//! the renderer before sampling.

mod common;

use glam::{Mat4, Vec3};
use oxray_render::lights::Environment;
use oxray_render::{render, RenderOptions};
use oxray_scene::{Camera, InstanceDesc, MaterialDesc, MeshDesc, SceneDesc, Texture, TextureRef};
use std::path::{Path, PathBuf};

fn fixture_with_transform(extension: &str) -> PathBuf {
    // A directory of its own per fixture: tests run in parallel, and one test rewriting the
    // texture while another's loader reads it would lose that texture.
    static NEXT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("../oxray-scene/tests/data");
    let dir = std::env::temp_dir().join(format!("oxray-khr-tt-{}-{n}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::copy(src.join("tex2x2.png"), dir.join("tex2x2.png")).unwrap();
    let text = std::fs::read_to_string(src.join("hierarchy.gltf"))
        .unwrap()
        .replacen(
            "\"baseColorTexture\": {",
            &format!(
                "\"baseColorTexture\": {{ \"extensions\": {{ \"KHR_texture_transform\": {extension} }},"
            ),
            1,
        );
    assert!(
        text.contains("KHR_texture_transform"),
        "the fixture changed shape"
    );
    let path = dir.join(format!("tt-{}.gltf", text.len()));
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn khr_texture_transform_is_read_as_the_specified_matrix() {
    // The extension's matrix is translation * rotation * scale, with
    // rotation = [cos sin; -sin cos].
    let path = fixture_with_transform(
        r#"{ "offset": [0.5, -1.0], "rotation": 1.5707964, "scale": [2.0, 3.0] }"#,
    );
    let scene = SceneDesc::load(&path).unwrap();
    let r = scene.materials[0].base_color_texture.unwrap();
    let (u, v) = r.map(1.0, 0.0);
    assert!(
        (u - 0.5).abs() < 1e-6 && (v - (-2.0 - 1.0)).abs() < 1e-6,
        "{u} {v}"
    );
    let (u, v) = r.map(0.0, 1.0);
    assert!(
        (u - (3.0 + 0.5)).abs() < 1e-6 && (v + 1.0).abs() < 1e-6,
        "{u} {v}"
    );
    // Without the extension: the identity.
    let plain = SceneDesc::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../oxray-scene/tests/data/hierarchy.gltf"),
    )
    .unwrap();
    assert_eq!(
        plain.materials[0].base_color_texture.unwrap().uv_transform,
        TextureRef::IDENTITY
    );
}

#[test]
fn non_finite_transforms_are_an_error() {
    let path = fixture_with_transform(r#"{ "offset": [1e39, 0.0] }"#);
    let err = SceneDesc::load(&path).unwrap_err().to_string();
    assert!(err.contains("KHR_texture_transform"), "{err}");
    assert_eq!(err.lines().count(), 1);
}

#[test]
fn the_renderer_samples_through_the_transform() {
    // An emissive quad textured red (left texel) and blue (right texel), seen head on. An
    // offset of half the texture swaps what the two halves show.
    let quad = common::quad(0);
    let tex = Texture {
        name: "red|blue".into(),
        width: 2,
        height: 1,
        texels: vec![[255, 0, 0, 255], [0, 0, 255, 255]],
        wrap_u: Default::default(),
        wrap_v: Default::default(),
    };
    let scene = |r: TextureRef| SceneDesc {
        meshes: vec![MeshDesc {
            name: "quad".into(),
            primitives: vec![quad.clone()],
        }],
        materials: vec![MaterialDesc {
            base_color: [0.0, 0.0, 0.0, 1.0],
            emissive: [1.0, 1.0, 1.0],
            emissive_texture: Some(r),
            ..Default::default()
        }],
        textures: vec![tex.clone()],
        instances: vec![InstanceDesc {
            mesh: 0,
            transform: Mat4::IDENTITY,
            node: None,
        }],
        cameras: vec![Camera::look_at(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, 1.0)],
        ..Default::default()
    };
    let opts = RenderOptions {
        width: 16,
        height: 16,
        spp: 1,
        max_depth: 1,
        ..Default::default()
    };
    let env = Environment::uniform(Vec3::ZERO);
    let left_right = |r: TextureRef| {
        let img = render(&scene(r), &env, &opts, |_| {}).unwrap();
        (img.pixels[8 * 16 + 5], img.pixels[8 * 16 + 10])
    };
    // Bilinear filtering blends the two texels a little away from their centres.
    let (l, r) = left_right(TextureRef::new(0));
    assert!(
        l[0] > 0.7 && l[2] < 0.3 && r[2] > 0.7 && r[0] < 0.3,
        "{l:?} {r:?}"
    );
    let (l, r) = left_right(TextureRef::new(0).with_khr_transform([0.5, 0.0], 0.0, [1.0, 1.0]));
    assert!(
        l[2] > 0.7 && l[0] < 0.3 && r[0] > 0.7 && r[2] < 0.3,
        "{l:?} {r:?}"
    );
}
