//! glTF node animations (glTF 2.0 §3.11): channels read with their samplers, placements of
//! instances at any time through the node hierarchy, and unusable channels dropped with one
//! warning instead of failing the file.

use glam::Vec3;
use oxray_scene::animation::{Interpolation, Property};
use oxray_scene::SceneDesc;

/// The buffer: a triangle, keyframe times, rotations (float and normalized short),
/// translations, and decreasing times.
fn buffer() -> Vec<u8> {
    let mut b: Vec<u8> = Vec::new();
    let f = |b: &mut Vec<u8>, v: &[f32]| v.iter().for_each(|x| b.extend(x.to_le_bytes()));
    let h = std::f32::consts::FRAC_1_SQRT_2;
    f(&mut b, &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]); // 0: positions
    f(&mut b, &[0.0, 1.0]); // 36: times
    f(&mut b, &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, h, h]); // 44: rotations
    f(&mut b, &[0.0, 0.0, 0.0, 0.0, 0.0, 5.0]); // 76: translations
    f(&mut b, &[1.0, 0.0]); // 100: decreasing times
    for s in [0i16, 0, 0, 32767, 0, 0, 23170, 23170] {
        b.extend(s.to_le_bytes()); // 108: rotations as normalized shorts
    }
    b
}

const GLTF: &str = r#"{
  "asset": {"version": "2.0"},
  "buffers": [{"uri": "anim.bin", "byteLength": 124}],
  "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 124}],
  "accessors": [
    {"bufferView": 0, "byteOffset": 0, "componentType": 5126, "count": 3, "type": "VEC3",
     "min": [0, 0, 0], "max": [1, 1, 0]},
    {"bufferView": 0, "byteOffset": 36, "componentType": 5126, "count": 2, "type": "SCALAR",
     "min": [0], "max": [1]},
    {"bufferView": 0, "byteOffset": 44, "componentType": 5126, "count": 2, "type": "VEC4"},
    {"bufferView": 0, "byteOffset": 76, "componentType": 5126, "count": 2, "type": "VEC3"},
    {"bufferView": 0, "byteOffset": 100, "componentType": 5126, "count": 2, "type": "SCALAR",
     "min": [0], "max": [1]},
    {"bufferView": 0, "byteOffset": 108, "componentType": 5122, "normalized": true,
     "count": 2, "type": "VEC4"}
  ],
  "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
  "nodes": [
    {"name": "pivot", "children": [1]},
    {"name": "arm", "mesh": 0, "translation": [1, 0, 0]},
    {"name": "fixed", "mesh": 0, "matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,3,0,1]}
  ],
  "scenes": [{"nodes": [0, 2]}],
  "animations": [
    {"name": "spin",
     "samplers": [{"input": 1, "output": 2}, {"input": 1, "output": 3, "interpolation": "STEP"}],
     "channels": [{"sampler": 0, "target": {"node": 0, "path": "rotation"}},
                  {"sampler": 1, "target": {"node": 0, "path": "translation"}}]},
    {"name": "broken",
     "samplers": [{"input": 4, "output": 3}, {"input": 1, "output": 0}, {"input": 1, "output": 5},
                  {"input": 1, "output": 3}],
     "channels": [{"sampler": 0, "target": {"node": 1, "path": "translation"}},
                  {"sampler": 1, "target": {"node": 1, "path": "rotation"}},
                  {"sampler": 2, "target": {"node": 0, "path": "rotation"}},
                  {"sampler": 3, "target": {"node": 2, "path": "translation"}}]}
  ]
}"#;

fn load(test: &str) -> SceneDesc {
    let dir = std::env::temp_dir().join(format!("oxray-animation-{}-{test}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("anim.bin"), buffer()).unwrap();
    let p = dir.join("anim.gltf");
    std::fs::write(&p, GLTF).unwrap();
    let scene = SceneDesc::load(&p).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    scene
}

fn origin_at(scene: &SceneDesc, instance: usize, animation: usize, time: f32) -> Vec3 {
    scene
        .instance_transform_at(instance, animation, time)
        .transform_point3(Vec3::ZERO)
}

#[test]
fn channels_keep_their_node_property_interpolation_and_keyframes() {
    let s = load("channels");
    assert_eq!(s.nodes.len(), 3);
    assert_eq!(s.nodes[1].parent, Some(0));
    assert_eq!(s.nodes[0].parent, None);
    assert_eq!(s.instances[0].node, Some(1));
    assert_eq!(s.instances[1].node, Some(2));
    assert_eq!(s.animations.len(), 2);
    let spin = &s.animations[0];
    assert_eq!(spin.name, "spin");
    assert_eq!(spin.channels.len(), 2);
    assert_eq!(spin.channels[0].property, Property::Rotation);
    assert_eq!(spin.channels[0].interpolation, Interpolation::Linear);
    assert_eq!(spin.channels[1].interpolation, Interpolation::Step);
    assert_eq!(spin.channels[1].times, vec![0.0, 1.0]);
    assert_eq!(spin.channels[1].values[1], [0.0, 0.0, 5.0, 0.0]);
}

#[test]
fn instances_move_through_their_parents() {
    let s = load("parents");
    // The arm hangs one unit along x from the pivot, which turns a quarter about z in one
    // second and steps 5 along z at the end.
    assert!(s.is_animated(0, 0));
    assert!(
        !s.is_animated(1, 0),
        "a node given by a matrix is not animated"
    );
    let h = std::f32::consts::FRAC_1_SQRT_2;
    assert!((origin_at(&s, 0, 0, 0.0) - Vec3::X).length() < 1e-6);
    assert!((origin_at(&s, 0, 0, 0.5) - Vec3::new(h, h, 0.0)).length() < 1e-6);
    assert!(
        (origin_at(&s, 0, 0, 0.99).z).abs() < 1e-6,
        "STEP holds the first value"
    );
    assert!((origin_at(&s, 0, 0, 1.0) - Vec3::new(0.0, 1.0, 5.0)).length() < 1e-6);
    assert!((origin_at(&s, 0, 0, 7.0) - Vec3::new(0.0, 1.0, 5.0)).length() < 1e-6);
    // The still instance keeps its matrix.
    assert_eq!(origin_at(&s, 1, 0, 0.5), Vec3::new(0.0, 3.0, 0.0));
    // At rest, the loader's placement is the unanimated hierarchy's.
    assert!((s.instances[0].transform.transform_point3(Vec3::ZERO) - Vec3::X).length() < 1e-6);
}

#[test]
fn unusable_channels_are_dropped_with_one_warning() {
    let s = load("unusable");
    // Of "broken", only the rotation in normalized shorts is kept; the decreasing times,
    // the VEC3 rotation and the matrix node's translation are named in one warning.
    let broken = &s.animations[1];
    assert_eq!(broken.channels.len(), 1);
    assert_eq!(broken.channels[0].node, 0);
    let q = broken.channels[0].sample(1.0);
    assert!(
        (q - glam::Vec4::new(
            0.0,
            0.0,
            std::f32::consts::FRAC_1_SQRT_2,
            std::f32::consts::FRAC_1_SQRT_2
        ))
        .abs()
        .max_element()
            < 1e-4
    );
    assert!((origin_at(&s, 0, 1, 1.0) - Vec3::Y).length() < 1e-4);
    let w: Vec<_> = s
        .warnings
        .iter()
        .filter(|w| w.contains("animation"))
        .collect();
    assert_eq!(w.len(), 1, "{:#?}", s.warnings);
    assert!(
        w[0].contains(
            "ignoring animation 1 channel 0: keyframe times do not increase (and 2 more channels)"
        ),
        "{}",
        w[0]
    );
}
