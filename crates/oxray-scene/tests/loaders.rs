//! Scene loaders: glTF (.gltf, .glb) and OBJ + MTL fixtures checked field by field, malformed
//! files giving one-line errors, and the real scenes in `../shared/data` when present.

use glam::{Mat4, Vec3};
use oxray_scene::mesh::Mesh;
use oxray_scene::{AlphaMode, MaterialDesc, SceneDesc, SceneError, Wrap};
use std::path::{Path, PathBuf};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// A file of the shared data set, or `None` (with a message) when the data set is absent.
fn shared(rel: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data")
        .join(rel);
    if p.exists() {
        Some(p)
    } else {
        println!("skipping: {} is absent", p.display());
        None
    }
}

/// A fresh directory for files a test writes.
fn tmp_dir(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("oxray-loaders-{}-{test}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn close(a: Vec3, b: Vec3) -> bool {
    (a - b).abs().max_element() < 1e-5
}

fn world(scene: &SceneDesc, instance: usize, p: [f32; 3]) -> Vec3 {
    scene.instances[instance]
        .transform
        .transform_point3(Vec3::from(p))
}

/// The 2x2 fixture texture: red, green / blue, transparent white.
const TEX2X2: [[u8; 4]; 4] = [
    [255, 0, 0, 255],
    [0, 255, 0, 255],
    [0, 0, 255, 255],
    [255, 255, 255, 0],
];

fn assert_one_line_error(err: &SceneError, file: &Path) {
    let msg = err.to_string();
    assert_eq!(msg.lines().count(), 1, "{msg}");
    assert!(msg.contains(&file.display().to_string()), "{msg}");
}

#[test]
fn gltf_with_data_uri_buffer_and_image() {
    let s = SceneDesc::load(&data("triangle.gltf")).unwrap();
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    assert_eq!(s.meshes.len(), 1);
    let p = &s.meshes[0].primitives[0];
    assert_eq!(
        p.positions,
        vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    );
    assert_eq!(p.triangles, vec![[0, 1, 2]]);
    assert!(p.normals.is_empty() && p.uvs.is_empty());
    assert_eq!(s.instances.len(), 1);
    assert_eq!(s.instances[0].transform, Mat4::IDENTITY);
    assert_eq!(s.materials.len(), 1);
    let m = &s.materials[0];
    assert_eq!(m.name, "red");
    assert_eq!(m.base_color, [1.0, 0.0, 0.0, 1.0]);
    // glTF defaults.
    assert_eq!((m.metallic, m.roughness), (1.0, 1.0));
    assert_eq!(m.alpha_mode, AlphaMode::Opaque);
    assert!(!m.double_sided);
    let t = &s.textures[m.base_color_texture.unwrap().texture as usize];
    assert_eq!((t.width, t.height), (2, 2));
    assert_eq!(t.texels, TEX2X2);
    assert_eq!((t.wrap_u, t.wrap_v), (Wrap::Repeat, Wrap::Repeat));
    assert!(s.cameras.is_empty());
}

#[test]
fn glb_with_embedded_buffer_and_image() {
    let s = SceneDesc::load(&data("triangle.glb")).unwrap();
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    assert_eq!(s.triangle_count(), 1);
    assert!(close(
        world(&s, 0, [1.0, 0.0, 0.0]),
        Vec3::new(1.0, 0.0, -1.0)
    ));
    let m = &s.materials[0];
    assert_eq!(m.metallic, 0.0);
    assert_eq!(m.base_color, [1.0; 4]);
    let t = &s.textures[m.base_color_texture.unwrap().texture as usize];
    assert_eq!(t.texels, TEX2X2);
    // Mesh::load accepts .glb and flattens it into world space.
    let mesh = Mesh::load(&data("triangle.glb")).unwrap();
    assert_eq!(mesh.triangles, vec![[0, 1, 2]]);
    assert_eq!(mesh.positions[1], [1.0, 0.0, -1.0]);
}

#[test]
fn gltf_node_hierarchy_cameras_materials_and_warnings() {
    let s = SceneDesc::load(&data("hierarchy.gltf")).unwrap();
    // Nodes 0 (parent), 1 (child), 2 (strip) and 5 (fan) have meshes; node 6 is outside the scene.
    assert_eq!(s.instances.len(), 4);
    assert_eq!(
        s.instances.iter().map(|i| i.mesh).collect::<Vec<_>>(),
        [0, 0, 1, 2]
    );
    // Parent: scale 2, then 90 degrees about +Y, which takes +X to -Z.
    assert!(close(
        world(&s, 0, [1.0, 0.0, 0.0]),
        Vec3::new(0.0, 0.0, -2.0)
    ));
    assert!(close(
        world(&s, 0, [0.0, 1.0, 0.0]),
        Vec3::new(0.0, 2.0, 0.0)
    ));
    // Child: translated by +X inside the parent.
    assert!(close(
        world(&s, 1, [0.0, 0.0, 0.0]),
        Vec3::new(0.0, 0.0, -2.0)
    ));
    assert!(close(
        world(&s, 1, [1.0, 0.0, 0.0]),
        Vec3::new(0.0, 0.0, -4.0)
    ));
    // Strip node: a column-major matrix translating by +10 X, inside the parent.
    assert!(close(
        world(&s, 2, [0.0, 0.0, 0.0]),
        Vec3::new(0.0, 0.0, -20.0)
    ));
    // Fan node: a root translated by -5 Y.
    assert!(close(
        world(&s, 3, [1.0, 1.0, 0.0]),
        Vec3::new(1.0, -4.0, 0.0)
    ));

    let tri = &s.meshes[0].primitives[0];
    assert_eq!(tri.triangles, vec![[0, 1, 2]]);
    assert_eq!(tri.normals, vec![[0.0, 0.0, 1.0]; 3]);
    assert_eq!(tri.uvs, vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]);
    // The strip keeps its winding; the points primitive is skipped.
    assert_eq!(s.meshes[1].primitives.len(), 1);
    assert_eq!(
        s.meshes[1].primitives[0].triangles,
        vec![[0, 1, 2], [1, 3, 2]]
    );
    assert_eq!(s.meshes[1].primitives[0].material, 1);
    // Non-indexed fan, no material: the default material is appended.
    let fan = &s.meshes[2].primitives[0];
    assert_eq!(fan.triangles, vec![[1, 2, 0], [2, 3, 0]]);
    assert_eq!(s.materials.len(), 3);
    assert_eq!(fan.material, 2);
    assert_eq!(s.materials[2], MaterialDesc::default());

    assert_eq!(s.cameras.len(), 1);
    let c = &s.cameras[0];
    assert_eq!(c.yfov, 0.8);
    assert_eq!(c.aspect, Some(1.5));
    assert_eq!(c.to_world, Mat4::from_translation(Vec3::new(0.0, 1.0, 5.0)));

    let m = &s.materials[0];
    assert_eq!(m.name, "masked");
    assert_eq!(m.base_color, [1.0, 0.5, 0.25, 1.0]);
    assert_eq!((m.metallic, m.roughness), (0.25, 0.75));
    assert_eq!(m.emissive, [4.0, 2.0, 0.0]);
    assert_eq!(m.alpha_mode, AlphaMode::Mask { cutoff: 0.3 });
    assert!(m.double_sided);
    assert_eq!(m.normal_scale, 0.5);
    // The normal map's image is missing: dropped, with a warning.
    assert_eq!(m.normal_texture, None);
    let t = &s.textures[m.base_color_texture.unwrap().texture as usize];
    assert_eq!(t.texels, TEX2X2);
    assert_eq!(
        (t.wrap_u, t.wrap_v),
        (Wrap::ClampToEdge, Wrap::MirroredRepeat)
    );
    let g = &s.materials[1];
    assert_eq!((g.transmission, g.ior), (1.0, 1.33));
    assert_eq!(g.alpha_mode, AlphaMode::Blend);
    assert_eq!(g.base_color, [1.0; 4]);

    assert_eq!(s.warnings.len(), 3, "{:#?}", s.warnings);
    let has = |needle: &str| s.warnings.iter().any(|w| w.contains(needle));
    assert!(
        has("texture textures/missing.png: cannot read"),
        "{:#?}",
        s.warnings
    );
    assert!(has("point and line primitives"), "{:#?}", s.warnings);
    assert!(has("camera 1: only perspective"), "{:#?}", s.warnings);
    let name = data("hierarchy.gltf").display().to_string();
    assert!(s
        .warnings
        .iter()
        .all(|w| w.starts_with(&name) && !w.contains('\n')));
}

#[test]
fn mesh_load_flattens_gltf_in_node_then_primitive_then_triangle_order() {
    let mesh = Mesh::load(&data("hierarchy.gltf")).unwrap();
    assert_eq!(mesh.triangles.len(), 6);
    let corner = |t: usize, k: usize| Vec3::from(mesh.positions[mesh.triangles[t][k] as usize]);
    // Triangle 0: the parent's; 1: the child's; 2 and 3: the strip; 4 and 5: the fan.
    assert!(close(corner(0, 1), Vec3::new(0.0, 0.0, -2.0)));
    assert!(close(corner(1, 1), Vec3::new(0.0, 0.0, -4.0)));
    assert!(close(corner(2, 0), Vec3::new(0.0, 0.0, -20.0)));
    assert!(close(corner(3, 1), Vec3::new(0.0, 2.0, -22.0)));
    assert!(close(corner(4, 2), Vec3::new(0.0, -5.0, 0.0)));
    assert!(close(corner(5, 1), Vec3::new(1.0, -4.0, 0.0)));
}

/// Writes `text` as `name` next to a copy of the PNG fixture and loads it.
fn load_text(test: &str, name: &str, text: &str) -> (PathBuf, Result<SceneDesc, SceneError>) {
    let dir = tmp_dir(test);
    std::fs::copy(data("tex2x2.png"), dir.join("tex2x2.png")).unwrap();
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    let r = SceneDesc::load(&p);
    (p, r)
}

fn hierarchy_text() -> String {
    std::fs::read_to_string(data("hierarchy.gltf")).unwrap()
}

#[test]
fn malformed_gltf_files_are_one_line_errors() {
    let h = hierarchy_text();
    let cases: Vec<(&str, String, &str)> = vec![
        ("json", "{\"asset\": ".into(), "invalid glTF JSON"),
        (
            "missing_buffer",
            h.replacen("data:application/octet-stream;base64,", "nowhere.bin#", 1),
            "cannot read",
        ),
        (
            "cycle",
            h.replace(
                "\"translation\": [\n    1,",
                "\"children\": [0], \"translation\": [\n    1,",
            ),
            "appears twice",
        ),
        (
            "index_out_of_range",
            h.replacen(
                "\"count\": 3,\n   \"type\": \"SCALAR\"",
                "\"count\": 3,\n   \"type\": \"SCALAR\", \"byteOffset\": 1",
                1,
            ),
            "do not fit",
        ),
        (
            "huge_count",
            h.replacen("\"count\": 4,", "\"count\": 2147483648,", 1),
            "accessor 4",
        ),
        (
            "wrong_component_type",
            h.replacen("\"componentType\": 5126", "\"componentType\": 5123", 1),
            "accessor 0",
        ),
        (
            "bad_reference",
            h.replacen("\"mesh\": 0", "\"mesh\": 99", 1),
            "invalid glTF",
        ),
    ];
    for (test, text, expect) in cases {
        assert!(text != h, "{test}: the fixture edit did not apply");
        let (p, r) = load_text(&format!("malformed-{test}"), "scene.gltf", &text);
        let err = r.expect_err(test);
        assert_one_line_error(&err, &p);
        assert!(err.to_string().contains(expect), "{test}: {err}");
    }
}

#[test]
fn gltf_vertex_index_beyond_positions_fails_validation() {
    // Point the strip's u8 indices at the bytes of a float 1.0 (00 00 80 3F): indices 128, 63.
    let h = hierarchy_text();
    let text = h.replacen(
        "\"bufferView\": 5,",
        "\"bufferView\": 0, \"byteOffset\": 12,",
        1,
    );
    assert!(text != h, "the fixture edit did not apply");
    let (p, r) = load_text("index-beyond", "scene.gltf", &text);
    let err = r.unwrap_err();
    assert_one_line_error(&err, &p);
    assert!(
        err.to_string().contains("refers to a vertex beyond"),
        "{err}"
    );
}

#[test]
fn truncated_and_corrupt_glb_files_are_errors() {
    let bytes = std::fs::read(data("triangle.glb")).unwrap();
    let dir = tmp_dir("glb");
    for (name, b) in [
        ("short.glb", bytes[..10].to_vec()),
        ("cut.glb", bytes[..bytes.len() - 100].to_vec()),
        (
            "version.glb",
            [&bytes[..4], &[1, 0, 0, 0], &bytes[8..]].concat(),
        ),
        (
            "length.glb",
            [&bytes[..8], &[4, 0, 0, 0], &bytes[12..]].concat(),
        ),
    ] {
        let p = dir.join(name);
        std::fs::write(&p, &b).unwrap();
        let err = SceneDesc::load(&p).expect_err(name);
        assert_one_line_error(&err, &p);
        let err = Mesh::load(&p).expect_err(name).to_string();
        assert_eq!(err.lines().count(), 1, "{err}");
    }
}

#[test]
fn obj_with_mtl_materials_and_texture() {
    let s = SceneDesc::load(&data("materials.obj")).unwrap();
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    // One mesh placed once, an object per primitive (OBJ has no instancing).
    assert_eq!(s.meshes.len(), 1);
    assert_eq!(s.meshes[0].name, "materials");
    assert_eq!(s.meshes[0].primitives.len(), 5);
    assert_eq!(s.instances.len(), 1);
    assert_eq!(s.instances[0].transform, Mat4::IDENTITY);
    // Quads fan-triangulated in file order.
    let q = &s.meshes[0].primitives[0];
    assert_eq!(q.triangles, vec![[0, 1, 2], [0, 2, 3]]);
    assert_eq!(q.positions[2], [1.0, 1.0, 0.0]);
    assert_eq!(q.normals, vec![[0.0, 0.0, 1.0]; 4]);
    // v is flipped: OBJ counts from the bottom row, textures start at the top.
    assert_eq!(q.uvs, vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]]);
    assert!(s.meshes[0].primitives[1].uvs.is_empty());

    let mat = |prim: usize| &s.materials[s.meshes[0].primitives[prim].material as usize];
    let t = mat(0);
    assert_eq!(t.name, "textured");
    assert_eq!(t.base_color, [0.5, 0.25, 1.0, 1.0]);
    assert!((t.roughness - 0.02f32.sqrt()).abs() < 1e-6);
    assert_eq!(t.metallic, 0.0);
    let tex = &s.textures[t.base_color_texture.unwrap().texture as usize];
    assert_eq!(tex.texels, TEX2X2);
    assert_eq!(mat(1).emissive, [10.0, 9.0, 8.0]);
    assert_eq!(mat(1).alpha_mode, AlphaMode::Opaque);
    let veil = mat(2);
    assert_eq!(veil.base_color, [0.2, 0.4, 0.6, 0.25]);
    assert_eq!(veil.alpha_mode, AlphaMode::Blend);
    assert_eq!(veil.transmission, 0.0);
    let glass = mat(3);
    assert_eq!((glass.transmission, glass.ior), (1.0, 1.5));
    assert_eq!(glass.alpha_mode, AlphaMode::Opaque);
    // An unknown material name gets the default material.
    assert_eq!(*mat(4), MaterialDesc::default());
}

#[test]
fn obj_with_missing_mtl_or_texture_warns_and_keeps_the_geometry() {
    let obj = std::fs::read_to_string(data("materials.obj")).unwrap();
    let text = obj.replace("mtllib materials.mtl", "mtllib absent.mtl");
    let (p, r) = load_text("no-mtl", "scene.obj", &text);
    let s = r.unwrap();
    assert_eq!(s.triangle_count(), 9);
    assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
    assert!(s.warnings[0].starts_with(&p.display().to_string()));
    assert!(s.warnings[0].contains("absent.mtl"), "{:?}", s.warnings);
    assert!(s.materials.iter().all(|m| *m == MaterialDesc::default()));

    let dir = tmp_dir("no-texture");
    let mtl = std::fs::read_to_string(data("materials.mtl")).unwrap();
    std::fs::write(
        dir.join("materials.mtl"),
        mtl.replace("tex2x2.png", "gone.png"),
    )
    .unwrap();
    std::fs::write(dir.join("materials.obj"), &obj).unwrap();
    let s = SceneDesc::load(&dir.join("materials.obj")).unwrap();
    assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
    assert!(
        s.warnings[0].contains("texture gone.png"),
        "{:?}",
        s.warnings
    );
    assert_eq!(s.materials[0].base_color_texture, None);
    assert_eq!(s.materials[0].base_color, [0.5, 0.25, 1.0, 1.0]);
}

/// tobj panics on a colour statement with fewer than three numbers; the loader drops such lines.
#[test]
fn regression_mtl_colour_with_two_numbers() {
    let dir = tmp_dir("mtl-two-numbers");
    std::fs::write(dir.join("a.mtl"), "newmtl a\nKd 1 1\nKe 2 3 4\n").unwrap();
    std::fs::write(
        dir.join("a.obj"),
        "mtllib a.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n",
    )
    .unwrap();
    let s = SceneDesc::load(&dir.join("a.obj")).unwrap();
    assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
    assert!(s.warnings[0].contains("line 2"), "{:?}", s.warnings);
    assert_eq!(s.materials[0].emissive, [2.0, 3.0, 4.0]);
    assert_eq!(s.materials[0].base_color, [0.8, 0.8, 0.8, 1.0]);
}

#[test]
fn shared_smallpine_loads_with_one_warning_for_the_empty_normal_map() {
    let Some(p) = shared("gltf/smallpine/scene.gltf") else {
        return;
    };
    let s = SceneDesc::load(&p).unwrap();
    assert_eq!(s.materials.len(), 2);
    // The empty normal map, named once; the second texture coordinate set is read.
    assert_eq!(s.warnings.len(), 1, "{:#?}", s.warnings);
    assert!(s
        .meshes
        .iter()
        .flat_map(|m| &m.primitives)
        .any(|p| p.uvs1.len() == p.positions.len() && !p.uvs1.is_empty()));
    assert!(
        s.warnings[0].contains("M_TreeAtlas_normal.png"),
        "{}",
        s.warnings[0]
    );
    let leaves = s
        .materials
        .iter()
        .find(|m| m.name == "M_TreeAtlas")
        .unwrap();
    assert_eq!(leaves.alpha_mode, AlphaMode::Blend);
    assert_eq!(leaves.normal_texture, None);
    let tex = &s.textures[leaves.base_color_texture.unwrap().texture as usize];
    assert_eq!((tex.width, tex.height), (2048, 2048));
    assert!(tex.texels.iter().any(|t| t[3] == 0));
    assert!(tex.texels.iter().any(|t| t[3] == 255));
    let trunk = s.materials.iter().find(|m| m.name == "Trunk").unwrap();
    assert!(trunk.normal_texture.is_some());
    assert_eq!(s.instances.len(), 2);
    assert_eq!(s.triangle_count(), 1650);
    let (lo, hi) = s.bounds().unwrap();
    assert!(lo.is_finite() && hi.is_finite() && (hi - lo).min_element() > 0.0);
}

#[test]
fn shared_balloon_loads() {
    let Some(p) = shared("gltf/balloon/scene.gltf") else {
        return;
    };
    let s = SceneDesc::load(&p).unwrap();
    assert!(s.warnings.is_empty(), "{:#?}", s.warnings);
    assert_eq!(s.materials.len(), 37);
    // 17 images; one is used with two samplers, so it becomes two textures.
    assert_eq!(s.textures.len(), 18);
    assert_eq!(s.instances.len(), 37);
    assert!(s.triangle_count() >= 35_000, "{}", s.triangle_count());
    let (lo, hi) = s.bounds().unwrap();
    assert!(lo.is_finite() && hi.is_finite() && (hi - lo).min_element() > 0.0);
}

#[test]
fn shared_drone_loads() {
    let Some(p) = shared("gltf/drone/scene.gltf") else {
        return;
    };
    let s = SceneDesc::load(&p).unwrap();
    // Only the unused texture coordinate sets and the morph target weights are named.
    assert_eq!(s.warnings.len(), 2, "{:#?}", s.warnings);
    assert!(s.warnings[0].contains("attributes TEXCOORD_2, TEXCOORD_3, TEXCOORD_4 "));
    assert!(s.warnings[1].contains("1 animation channel of morph target weights ignored"));
    // Its one 25-second animation: every translation, rotation and scale channel is kept,
    // and it moves some of the instances but not all of them.
    assert_eq!(s.animations.len(), 1);
    assert_eq!(s.animations[0].channels.len(), 99);
    assert_eq!(s.nodes.len(), 93);
    let end = s.animations[0]
        .channels
        .iter()
        .map(|c| *c.times.last().unwrap())
        .fold(0.0f32, f32::max);
    assert!((end - 25.0).abs() < 1e-3, "{end}");
    let moving = (0..s.instances.len())
        .filter(|&i| s.is_animated(i, 0))
        .count();
    assert!(moving > 0 && moving < s.instances.len(), "{moving}");
    // A still instance keeps its rest placement at any time; a moving one is somewhere else
    // a second later.
    let still = (0..s.instances.len())
        .find(|&i| !s.is_animated(i, 0))
        .unwrap();
    assert_eq!(
        s.instance_transform_at(still, 0, 3.0),
        s.instances[still].transform
    );
    assert!((0..s.instances.len()).any(|i| s.is_animated(i, 0)
        && !s
            .instance_transform_at(i, 0, 1.0)
            .abs_diff_eq(s.instance_transform_at(i, 0, 2.0), 1e-4)));
    assert_eq!(s.materials.len(), 3);
    assert_eq!(s.textures.len(), 10);
    assert!(
        (1..=93).contains(&s.instances.len()),
        "{}",
        s.instances.len()
    );
    assert!(s.triangle_count() >= 30_000, "{}", s.triangle_count());
    let body = s.materials.iter().find(|m| m.name == "body").unwrap();
    assert!(body.emissive_texture.is_some());
    let (lo, hi) = s.bounds().unwrap();
    assert!(lo.is_finite() && hi.is_finite() && (hi - lo).min_element() > 0.0);
    let mesh = Mesh::load(&p).unwrap();
    assert_eq!(mesh.triangles.len() as u64, s.triangle_count());
}

#[test]
fn shared_cornell_box_obj_materials() {
    let Some(p) = shared("scenes/cornell_box/cornell_box.obj") else {
        return;
    };
    let s = SceneDesc::load(&p).unwrap();
    assert!(s.warnings.is_empty(), "{:#?}", s.warnings);
    let by_name = |n: &str| s.materials.iter().find(|m| m.name == n).unwrap();
    assert_eq!(by_name("Green").base_color, [0.0, 0.8, 0.0, 1.0]);
    assert_eq!(by_name("Red").base_color, [0.8, 0.0, 0.0, 1.0]);
    assert_eq!(by_name("Material.001").base_color, [0.8, 0.8, 0.8, 1.0]);
    assert!(by_name("Metal").roughness < 0.1);
    assert!(s.materials.iter().all(|m| m.transmission == 0.0));
    // The light's material (if the file gives it one) emits.
    if let Some(light) = s
        .materials
        .iter()
        .find(|m| m.name.to_lowercase().contains("light"))
    {
        assert!(light.emissive.iter().any(|&e| e > 0.0));
    }
    assert_eq!(s.triangle_count(), 3968);
    assert_eq!(
        Mesh::load(&p).unwrap().triangles.len() as u64,
        s.triangle_count()
    );
}

/// A glTF triangle whose buffer is `bin` in `tri.bin` next to it, with `accessors`,
/// `bufferViews` and `extra` top-level members spliced in.
fn gltf_with_bin(test: &str, bin: &[u8], accessors: &str, views: &str, extra: &str) -> PathBuf {
    let dir = tmp_dir(test);
    std::fs::write(dir.join("tri.bin"), bin).unwrap();
    let path = dir.join("tri.gltf");
    std::fs::write(
        &path,
        format!(
            r#"{{"asset":{{"version":"2.0"}},"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
            "accessors":[{accessors}],"bufferViews":[{views}],
            "buffers":[{{"byteLength":{},"uri":"tri.bin"}}]{extra}}}"#,
            bin.len()
        ),
    )
    .unwrap();
    path
}

#[test]
fn quantized_positions_load_with_khr_mesh_quantization() {
    // Three SHORT positions, normalized, each padded to 8 bytes (accessor alignment).
    let mut bin = Vec::new();
    for p in [[0i16, 0, 0], [32767, 0, 0], [0, -32767, 0]] {
        for c in p {
            bin.extend(c.to_le_bytes());
        }
        bin.extend([0, 0]);
    }
    let path = gltf_with_bin(
        "quantized",
        &bin,
        r#"{"bufferView":0,"componentType":5122,"normalized":true,"count":3,"type":"VEC3"}"#,
        r#"{"buffer":0,"byteLength":24,"byteStride":8}"#,
        r#","extensionsUsed":["KHR_mesh_quantization"],"extensionsRequired":["KHR_mesh_quantization"]"#,
    );
    let s = SceneDesc::load(&path).unwrap();
    assert_eq!(
        s.meshes[0].primitives[0].positions,
        vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
    );
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    // Not normalized: the integers as they are.
    let path = gltf_with_bin(
        "quantized-int",
        &bin,
        r#"{"bufferView":0,"componentType":5122,"count":3,"type":"VEC3"}"#,
        r#"{"buffer":0,"byteLength":24,"byteStride":8}"#,
        r#","extensionsRequired":["KHR_mesh_quantization"]"#,
    );
    let s = SceneDesc::load(&path).unwrap();
    assert_eq!(s.meshes[0].primitives[0].positions[1], [32767.0, 0.0, 0.0]);
}

#[test]
fn unsupported_required_extensions_gltf_1_0_and_ignored_features_are_named() {
    let bin: Vec<u8> = [0f32, 0., 0., 1., 0., 0., 0., 1., 0.]
        .iter()
        .flat_map(|f| f.to_le_bytes())
        .collect();
    let acc = r#"{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3"}"#;
    let view = r#"{"buffer":0,"byteLength":36}"#;
    for (ext, what) in [
        ("KHR_draco_mesh_compression", "Draco"),
        ("KHR_texture_basisu", "KTX2"),
    ] {
        let extra = format!(r#","extensionsUsed":["{ext}"],"extensionsRequired":["{ext}"]"#);
        let path = gltf_with_bin("required", &bin, acc, view, &extra);
        let e = SceneDesc::load(&path).unwrap_err();
        assert_one_line_error(&e, &path);
        let msg = e.to_string();
        assert!(
            msg.contains(&format!("requires extension {ext}"))
                && msg.contains(what)
                && msg.contains("which oxray does not support"),
            "{msg}"
        );
        assert!(!msg.contains("invalid glTF"), "{msg}");
    }
    // Used but not required: loads, with one warning naming them.
    let path = gltf_with_bin(
        "used",
        &bin,
        acc,
        view,
        r#","extensionsUsed":["KHR_materials_clearcoat","KHR_materials_sheen"]"#,
    );
    let s = SceneDesc::load(&path).unwrap();
    let w: Vec<_> = s
        .warnings
        .iter()
        .filter(|w| w.contains("ignoring extension"))
        .collect();
    assert_eq!(w.len(), 1, "{:?}", s.warnings);
    assert!(
        w[0].contains("KHR_materials_clearcoat, KHR_materials_sheen"),
        "{w:?}"
    );
    // glTF 1.0.
    let (path, r) = load_text(
        "gltf1",
        "old.gltf",
        r#"{"asset":{"version":"1.0"},"meshes":{"m":{"primitives":[]}}}"#,
    );
    let e = r.unwrap_err();
    assert_one_line_error(&e, &path);
    assert!(e.to_string().contains("glTF 1.0"), "{e}");
}

#[test]
fn scenes_without_nodes_colours_and_accessors_without_buffer_views_load() {
    let bin: Vec<u8> = [0f32, 0., 0., 1., 0., 0., 0., 1., 0.]
        .iter()
        .flat_map(|f| f.to_le_bytes())
        .collect();
    // A scene without "nodes", a file whose only placement is missing, COLOR_1 and
    // TEXCOORD_2 (ignored, named once), COLOR_0 and a NORMAL accessor without a buffer view
    // (zeros).
    let dir = tmp_dir("no-nodes");
    std::fs::write(dir.join("tri.bin"), &bin).unwrap();
    let path = dir.join("tri.gltf");
    std::fs::write(
        &path,
        r#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{}],
        "meshes":[{"primitives":[{"attributes":{"POSITION":0,"NORMAL":1,"COLOR_0":1,"COLOR_1":1,"TEXCOORD_2":2}}]}],
        "accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3"},
                     {"componentType":5126,"count":3,"type":"VEC3"},
                     {"componentType":5126,"count":3,"type":"VEC2"}],
        "bufferViews":[{"buffer":0,"byteLength":36}],
        "buffers":[{"byteLength":36,"uri":"tri.bin"}]}"#,
    )
    .unwrap();
    let s = SceneDesc::load(&path).unwrap();
    assert_eq!(s.instances.len(), 1);
    assert_eq!(s.meshes[0].primitives[0].normals, vec![[0.0; 3]; 3]);
    assert_eq!(
        s.meshes[0].primitives[0].colors,
        vec![[0.0, 0.0, 0.0, 1.0]; 3]
    );
    let has = |n: &str| s.warnings.iter().filter(|w| w.contains(n)).count();
    assert_eq!(
        has("ignoring vertex attributes COLOR_1, TEXCOORD_2"),
        1,
        "{:?}",
        s.warnings
    );
    assert_eq!(has("placing each mesh once"), 1, "{:?}", s.warnings);
}

#[test]
fn obj_with_latin1_names_and_a_bare_usemtl_loads() {
    let dir = tmp_dir("latin1");
    // "rosé" in Latin-1, in both files.
    std::fs::write(dir.join("m.mtl"), b"newmtl ros\xe9\nKd 0.9 0.1 0.2\n").unwrap();
    let obj = dir.join("m.obj");
    std::fs::write(
        &obj,
        b"mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nusemtl ros\xe9\nf 1 2 3\nusemtl\nf 1 2 4\n",
    )
    .unwrap();
    let s = SceneDesc::load(&obj).unwrap();
    let rose = s.materials.iter().position(|m| m.name == "rosé").unwrap();
    assert_eq!(s.materials[rose].base_color[0], 0.9);
    let prims: Vec<_> = s.meshes.iter().flat_map(|m| &m.primitives).collect();
    assert_eq!(prims.len(), 2);
    assert_eq!(prims[0].material as usize, rose);
    assert_ne!(prims[1].material as usize, rose);
    assert_eq!(Mesh::load(&obj).unwrap().triangles.len(), 2);
}

// The meshopt fixtures were made by gltfpack 1.3 (the npm package `gltfpack`) from one UV sphere
// (8 segments, 6 rings, 63 vertices with normals and texture coordinates):
// - `meshopt_plain.glb`: `-kv`, quantized and not compressed, the reference;
// - `meshopt_sphere.glb`: `-cc -kv`, EXT_meshopt_compression required, OCTAHEDRAL normals;
// - `meshopt.gltf` (a fuzzer seed): the same, its buffer embedded as a data URI;
// - `meshopt_khr.glb`: `-cc -ce khr -kv -vpf -vtf`, KHR_meshopt_compression with EXPONENTIAL
//   float positions and texture coordinates;
// - `meshopt_fallback.gltf` (+ `.bin`, `.fallback.bin`): `-c -cf -kv`, the extension used but not
//   required, with an uncompressed fallback buffer.

/// A primitive's triangles as (position, texture coordinate) triplets, each triangle rotated to
/// start at its smallest vertex, sorted, with the normal of each such vertex: what does not
/// depend on the order of vertices and of triangles (which compression changes).
#[allow(clippy::type_complexity)]
fn canonical(
    p: &oxray_scene::Primitive,
) -> (
    Vec<[[u32; 5]; 3]>,
    std::collections::BTreeMap<[u32; 5], [f32; 3]>,
) {
    let key = |i: u32| {
        let (v, t) = (p.positions[i as usize], p.uvs[i as usize]);
        [v[0], v[1], v[2], t[0], t[1]].map(f32::to_bits)
    };
    let mut tris: Vec<[[u32; 5]; 3]> = p
        .triangles
        .iter()
        .map(|t| {
            let k = t.map(key);
            let m = (0..3).min_by_key(|&i| k[i]).unwrap();
            [k[m], k[(m + 1) % 3], k[(m + 2) % 3]]
        })
        .collect();
    tris.sort_unstable();
    let normals = (0..p.positions.len() as u32)
        .map(|i| (key(i), p.normals[i as usize]))
        .collect();
    (tris, normals)
}

#[test]
fn meshopt_compressed_files_decode_to_the_uncompressed_geometry() {
    let plain = SceneDesc::load(&data("meshopt_plain.glb")).unwrap();
    let (tris, normals) = canonical(&plain.meshes[0].primitives[0]);
    assert_eq!(tris.len(), 80);
    for file in [
        "meshopt_sphere.glb",
        "meshopt.gltf",
        "meshopt_fallback.gltf",
    ] {
        let s = SceneDesc::load(&data(file)).unwrap();
        assert!(s.warnings.is_empty(), "{file}: {:?}", s.warnings);
        let (t, n) = canonical(&s.meshes[0].primitives[0]);
        assert_eq!(t, tris, "{file}");
        assert_eq!(s.instances, plain.instances, "{file}");
        // The octahedral filter stores the normals differently, as precisely.
        assert_eq!(n.len(), normals.len());
        for (k, n) in &n {
            let r = normals[k];
            assert!(
                close_within(Vec3::from(*n), Vec3::from(r), 0.02),
                "{file}: {n:?} {r:?}"
            );
        }
    }
    // Float positions through the EXPONENTIAL filter: a unit sphere whose normals point out.
    let s = SceneDesc::load(&data("meshopt_khr.glb")).unwrap();
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    let p = &s.meshes[0].primitives[0];
    assert_eq!(p.triangles.len(), 80);
    for (pos, n) in p.positions.iter().zip(&p.normals) {
        let w = world(&s, 0, *pos);
        assert!((w.length() - 1.0).abs() < 1e-3, "{w}");
        assert!(
            close_within(Vec3::from(*n).normalize(), w.normalize(), 0.02),
            "{n:?} {w}"
        );
    }
    let uv_max = p.uvs.iter().flatten().fold(0f32, |a, &b| a.max(b));
    assert!((uv_max - 1.0).abs() < 1e-3, "{uv_max}");
}

fn close_within(a: Vec3, b: Vec3, tol: f32) -> bool {
    (a - b).abs().max_element() <= tol
}

#[test]
fn meshopt_fallback_buffers_are_read_only_when_decoding_is_not_possible() {
    let reference = SceneDesc::load(&data("meshopt_fallback.gltf")).unwrap();
    let reference = canonical(&reference.meshes[0].primitives[0]);
    let dir = tmp_dir("meshopt-fallback");
    let names = [
        "meshopt_fallback.gltf",
        "meshopt_fallback.bin",
        "meshopt_fallback.fallback.bin",
    ];
    for n in names {
        std::fs::copy(data(n), dir.join(n)).unwrap();
    }
    let gltf = dir.join(names[0]);
    let fallback = dir.join(names[2]);
    // Decoded without the fallback buffer, whose file is still listed as the scene's.
    std::fs::remove_file(&fallback).unwrap();
    let s = SceneDesc::load(&gltf).unwrap();
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    assert_eq!(canonical(&s.meshes[0].primitives[0]), reference);
    assert!(s.sources.contains(&fallback), "{:?}", s.sources);
    // Compressed data that does not decode: the fallback is used, with a warning per view.
    std::fs::copy(data(names[2]), &fallback).unwrap();
    let compressed = std::fs::read(data(names[1])).unwrap();
    std::fs::write(dir.join(names[1]), vec![0u8; compressed.len()]).unwrap();
    let s = SceneDesc::load(&gltf).unwrap();
    assert_eq!(canonical(&s.meshes[0].primitives[0]), reference);
    let used = |s: &SceneDesc| {
        s.warnings
            .iter()
            .filter(|w| w.contains("using the uncompressed fallback"))
            .count()
    };
    assert_eq!(used(&s), 4, "{:?}", s.warnings);
    assert!(s.warnings[0].contains("cannot decode its EXT_meshopt_compression data"));
    // ... and without the fallback either, an error naming both.
    std::fs::remove_file(&fallback).unwrap();
    let e = SceneDesc::load(&gltf).unwrap_err();
    assert_one_line_error(&e, &gltf);
    let msg = e.to_string();
    assert!(
        msg.contains("cannot decode")
            && msg.contains("fallback buffer 1 ")
            && msg.contains("cannot read"),
        "{msg}"
    );
    // An unknown filter is a reason to fall back too (the extension is not required).
    std::fs::copy(data(names[1]), dir.join(names[1])).unwrap();
    std::fs::copy(data(names[2]), &fallback).unwrap();
    let text = std::fs::read_to_string(&gltf).unwrap();
    let text = text.replacen(
        r#""mode":"TRIANGLES""#,
        r#""mode":"TRIANGLES","filter":"FUTURE""#,
        1,
    );
    std::fs::write(&gltf, text).unwrap();
    let s = SceneDesc::load(&gltf).unwrap();
    assert_eq!(used(&s), 1, "{:?}", s.warnings);
    assert!(
        s.warnings[0].contains("unknown filter \"FUTURE\""),
        "{:?}",
        s.warnings
    );
    assert_eq!(canonical(&s.meshes[0].primitives[0]), reference);
}

#[test]
fn required_meshopt_data_that_does_not_decode_is_a_one_line_error() {
    let text = std::fs::read_to_string(data("meshopt.gltf")).unwrap();
    for (from, to, needle) in [
        (
            r#""mode":"TRIANGLES""#,
            r#""mode":"STRIPS""#,
            "unknown mode",
        ),
        (r#""count":240"#, r#""count":241"#, "not a multiple of 3"),
        (r#""count":240"#, r#""count":999999999999"#, "do not fit"),
        (
            r#""filter":"OCTAHEDRAL""#,
            r#""filter":"QUATERNION""#,
            "QUATERNION",
        ),
        (
            r#""byteOffset":0,"byteLength":395"#,
            r#""byteOffset":0,"byteLength":99999"#,
            "outside",
        ),
        (
            r#""byteOffset":0,"byteLength":395"#,
            r#""byteOffset":0,"byteLength":20"#,
            "malformed",
        ),
    ] {
        assert!(text.contains(from), "{from}");
        let (path, r) = load_text("meshopt-required", "m.gltf", &text.replacen(from, to, 1));
        let e = r.unwrap_err();
        assert_one_line_error(&e, &path);
        let msg = e.to_string();
        assert!(
            msg.contains("cannot decode its EXT_meshopt_compression data") && msg.contains(needle),
            "{needle}: {msg}"
        );
    }
}

/// A glTF triangle with a COLOR_0 accessor (`accessor`, reading buffer view 1) over `colour`
/// bytes, after the 36 bytes of positions.
fn gltf_with_colour(test: &str, colour: &[u8], accessor: &str, view: &str) -> PathBuf {
    let mut bin: Vec<u8> = [0f32, 0., 0., 1., 0., 0., 0., 1., 0.]
        .iter()
        .flat_map(|f| f.to_le_bytes())
        .collect();
    bin.extend(colour);
    let dir = tmp_dir(test);
    std::fs::write(dir.join("tri.bin"), &bin).unwrap();
    let path = dir.join("tri.gltf");
    std::fs::write(
        &path,
        format!(
            r#"{{"asset":{{"version":"2.0"}},"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"COLOR_0":1}}}}]}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3"}},{accessor}],
            "bufferViews":[{{"buffer":0,"byteLength":36}},{view}],
            "buffers":[{{"byteLength":{},"uri":"tri.bin"}}]}}"#,
            bin.len()
        ),
    )
    .unwrap();
    path
}

#[test]
fn vertex_colours_load_in_every_layout_the_specification_allows() {
    // Float RGB (the fixture the renderer's test uses): alpha 1.
    let s = SceneDesc::load(&data("colors.gltf")).unwrap();
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    let (red, blue) = ([1.0, 0.0, 0.0, 1.0], [0.0, 0.0, 1.0, 1.0]);
    assert_eq!(s.meshes[0].primitives[0].colors, vec![red, blue, blue, red]);
    // Normalized UNSIGNED_BYTE RGBA.
    let path = gltf_with_colour(
        "colour-u8",
        &[255, 0, 0, 255, 0, 51, 0, 0, 0, 0, 255, 102],
        r#"{"bufferView":1,"componentType":5121,"normalized":true,"count":3,"type":"VEC4"}"#,
        r#"{"buffer":0,"byteOffset":36,"byteLength":12}"#,
    );
    let s = SceneDesc::load(&path).unwrap();
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    assert_eq!(
        s.meshes[0].primitives[0].colors,
        vec![
            [1.0, 0.0, 0.0, 1.0],
            [0.0, 0.2, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.4]
        ]
    );
    // Normalized UNSIGNED_SHORT RGB, each element padded to 8 bytes.
    let mut u16s = Vec::new();
    for c in [[65535u16, 0, 0, 0], [0, 13107, 0, 0], [0, 0, 65535, 0]] {
        u16s.extend(c.iter().flat_map(|x| x.to_le_bytes()));
    }
    let path = gltf_with_colour(
        "colour-u16",
        &u16s,
        r#"{"bufferView":1,"componentType":5123,"normalized":true,"count":3,"type":"VEC3"}"#,
        r#"{"buffer":0,"byteOffset":36,"byteLength":24,"byteStride":8}"#,
    );
    let s = SceneDesc::load(&path).unwrap();
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    assert_eq!(
        s.meshes[0].primitives[0].colors,
        vec![
            [1.0, 0.0, 0.0, 1.0],
            [0.0, 0.2, 0.0, 1.0],
            [0.0, 0.0, 1.0, 1.0]
        ]
    );
    // What the specification does not allow, or a count that does not match, is dropped with
    // a warning; the geometry still loads.
    for (accessor, needle) in [
        (
            r#"{"bufferView":1,"componentType":5121,"count":3,"type":"VEC4"}"#,
            "not normalized",
        ),
        (
            r#"{"bufferView":1,"componentType":5121,"normalized":true,"count":6,"type":"VEC2"}"#,
            "VEC3 or VEC4",
        ),
        (
            r#"{"bufferView":1,"componentType":5121,"normalized":true,"count":2,"type":"VEC4"}"#,
            "2 values for 3 positions",
        ),
    ] {
        let path = gltf_with_colour(
            "colour-bad",
            &[255; 12],
            accessor,
            r#"{"buffer":0,"byteOffset":36,"byteLength":12}"#,
        );
        let s = SceneDesc::load(&path).unwrap();
        assert!(s.meshes[0].primitives[0].colors.is_empty());
        assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
        assert!(
            s.warnings[0].contains("ignoring COLOR_0: mesh 0 primitive 0: accessor 1")
                || s.warnings[0].contains("ignoring COLOR_0: mesh 0 primitive 0: 2 values"),
            "{:?}",
            s.warnings
        );
        assert!(s.warnings[0].contains(needle), "{needle}: {:?}", s.warnings);
    }
    // Named once however many primitives have it.
    let text = std::fs::read_to_string(data("colors.gltf")).unwrap();
    let prim = r#"{"attributes":{"POSITION":0,"NORMAL":1,"COLOR_0":3},"indices":3,"material":0}"#;
    let text = text.replace(
        r#""primitives":[{"attributes":{"POSITION":0,"NORMAL":1,"COLOR_0":2},"indices":3,"material":0}]"#,
        &format!(r#""primitives":[{prim},{prim},{prim}]"#),
    );
    let (_, r) = load_text("colour-once", "c.gltf", &text);
    let s = r.unwrap();
    assert_eq!(s.meshes[0].primitives.len(), 3);
    assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
    assert!(
        s.warnings[0].contains("ignoring COLOR_0: mesh 0 primitive 0: accessor 3")
            && s.warnings[0].ends_with("(and in 2 more primitives)"),
        "{:?}",
        s.warnings
    );
}

#[test]
fn the_second_texture_coordinate_set_is_read_and_textures_may_use_it() {
    let s = SceneDesc::load(&data("texcoord1.gltf")).unwrap();
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    let p = &s.meshes[0].primitives[0];
    assert_eq!(p.uvs, vec![[0.25, 0.25]; 4]);
    assert_eq!(p.uvs1, vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]]);
    let r = s.materials[0].base_color_texture.unwrap();
    assert_eq!(r.tex_coord, 1);
    assert_eq!(s.textures[r.texture as usize].texels, TEX2X2);
    let text = std::fs::read_to_string(data("texcoord1.gltf")).unwrap();
    let slot = r#""baseColorTexture":{"index":0,"texCoord":1}"#;
    assert!(text.contains(slot));
    // KHR_texture_transform's texCoord overrides the slot's.
    let (_, r) = load_text(
        "texcoord-khr",
        "t.gltf",
        &text.replace(
            slot,
            r#""baseColorTexture":{"index":0,"extensions":{"KHR_texture_transform":{"texCoord":1,"scale":[2,2]}}}"#,
        ),
    );
    let s = r.unwrap();
    let r = s.materials[0].base_color_texture.unwrap();
    assert_eq!((r.tex_coord, r.map(1.0, 1.0)), (1, (2.0, 2.0)));
    // Set 0 stays the default.
    let (_, r) = load_text(
        "texcoord-0",
        "t.gltf",
        &text.replace(slot, r#""baseColorTexture":{"index":0}"#),
    );
    assert_eq!(
        r.unwrap().materials[0]
            .base_color_texture
            .unwrap()
            .tex_coord,
        0
    );
    // A set beyond 1: the texture is dropped with a warning.
    let (_, r) = load_text(
        "texcoord-2",
        "t.gltf",
        &text.replace(slot, r#""baseColorTexture":{"index":0,"texCoord":2}"#),
    );
    let s = r.unwrap();
    assert!(s.materials[0].base_color_texture.is_none());
    assert!(
        s.warnings.len() == 1 && s.warnings[0].contains("only sets 0 and 1"),
        "{:?}",
        s.warnings
    );
}

#[test]
fn lambertian_materials_from_obj_illum_and_khr_materials_specular() {
    // MTL illumination models 0 and 1 have no specular term: a Lambertian material. Model 2
    // (and no model) keeps glTF's default dielectric coat; a metal stays specular.
    let dir = tmp_dir("lambert");
    std::fs::write(
        dir.join("m.mtl"),
        "newmtl flat\nKd 0.5 0.5 0.5\nillum 0\n\
         newmtl matte\nKd 0.5 0.5 0.5\nillum 1\n\
         newmtl shiny\nKd 0.5 0.5 0.5\nillum 2\n\
         newmtl metal\nKd 0.5 0.5 0.5\nKs 0.9 0.9 0.9\nillum 3\n",
    )
    .unwrap();
    let mut obj = String::from("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\n");
    for m in ["flat", "matte", "shiny", "metal"] {
        obj += &format!("usemtl {m}\nf 1 2 3\n");
    }
    std::fs::write(dir.join("m.obj"), obj).unwrap();
    let s = SceneDesc::load(&dir.join("m.obj")).unwrap();
    let by_name = |n: &str| s.materials.iter().find(|m| m.name == n).unwrap();
    assert_eq!(by_name("flat").specular, 0.0);
    assert_eq!(by_name("matte").specular, 0.0);
    assert_eq!(by_name("shiny").specular, 1.0);
    assert_eq!(by_name("metal").specular, 1.0);
    assert_eq!(by_name("metal").metallic, 1.0);

    // glTF: KHR_materials_specular's factor, read without a warning; 1 without the extension.
    let bin: Vec<u8> = [0f32, 0., 0., 1., 0., 0., 0., 1., 0.]
        .iter()
        .flat_map(|f| f.to_le_bytes())
        .collect();
    let path = gltf_with_bin(
        "specular",
        &bin,
        r#"{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3"}"#,
        r#"{"buffer":0,"byteLength":36}"#,
        r#","extensionsUsed":["KHR_materials_specular"],
        "materials":[{"extensions":{"KHR_materials_specular":{"specularFactor":0.0}}},
                     {"extensions":{"KHR_materials_specular":{"specularFactor":0.25}}},{}]"#,
    );
    let s = SceneDesc::load(&path).unwrap();
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    let spec: Vec<f32> = s.materials.iter().take(3).map(|m| m.specular).collect();
    assert_eq!(spec, [0.0, 0.25, 1.0]);
}
