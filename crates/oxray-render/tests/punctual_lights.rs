//! glTF `KHR_lights_punctual`: point, spot and directional lights are read with their node
//! placement and lit by next-event estimation with the inverse-square law, the spot cone and
//! the range window.

use glam::{Mat4, Vec3};
use oxray_render::lights::Environment;
use oxray_render::{render, RenderOptions};
use oxray_scene::{
    Camera, InstanceDesc, LightKind, MaterialDesc, MeshDesc, Primitive, PunctualLight, SceneDesc,
};

const GLTF: &str = r#"{
  "asset": { "version": "2.0" },
  "extensionsUsed": ["KHR_lights_punctual"],
  "extensions": { "KHR_lights_punctual": { "lights": [
    { "type": "point", "color": [1.0, 0.5, 0.25], "intensity": 683.0, "range": 10.0 },
    { "type": "spot", "intensity": 2.0, "spot": { "innerConeAngle": 0.2, "outerConeAngle": 0.4 } },
    { "type": "directional", "intensity": 3.0 },
    { "type": "spot", "intensity": 1.0, "spot": { "innerConeAngle": 0.9, "outerConeAngle": 0.4 } }
  ] } },
  "scene": 0,
  "scenes": [ { "nodes": [0, 1, 2, 3] } ],
  "nodes": [
    { "translation": [1.0, 2.0, 3.0], "extensions": { "KHR_lights_punctual": { "light": 0 } } },
    { "rotation": [-0.7071068, 0.0, 0.0, 0.7071068], "translation": [0.0, 5.0, 0.0],
      "extensions": { "KHR_lights_punctual": { "light": 1 } } },
    { "rotation": [0.0, 0.7071068, 0.0, 0.7071068], "extensions": { "KHR_lights_punctual": { "light": 2 } } },
    { "extensions": { "KHR_lights_punctual": { "light": 3 } } }
  ]
}"#;

#[test]
fn lights_are_read_with_their_node_placement() {
    let dir = std::env::temp_dir().join(format!("oxray-lights-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("lights.gltf");
    std::fs::write(&path, GLTF).unwrap();
    // No triangles: `SceneDesc::load` would refuse the scene as empty; the loader itself
    // returns what it read.
    let scene = oxray_scene::gltf::load(&path).unwrap();
    assert_eq!(scene.lights.len(), 3, "{:?}", scene.warnings);
    let point = scene.lights[0];
    assert_eq!(point.kind, LightKind::Point);
    assert!(point.position.distance(Vec3::new(1.0, 2.0, 3.0)) < 1e-6);
    assert_eq!(point.intensity, Vec3::new(683.0, 341.5, 170.75));
    assert_eq!(point.range, Some(10.0));
    // The spot's node turns -Z to -Y: it shines straight down from y = 5.
    let spot = scene.lights[1];
    assert!(
        matches!(spot.kind, LightKind::Spot { inner_cone, outer_cone } if inner_cone == 0.2 && outer_cone == 0.4)
    );
    assert!(
        spot.direction.distance(Vec3::new(0.0, -1.0, 0.0)) < 1e-5,
        "{}",
        spot.direction
    );
    // The directional light's node turns -Z to -X.
    let sun = scene.lights[2];
    assert_eq!(sun.kind, LightKind::Directional);
    assert!(
        sun.direction.distance(Vec3::new(-1.0, 0.0, 0.0)) < 1e-5,
        "{}",
        sun.direction
    );
    // An inner cone wider than the outer one is skipped with a warning.
    assert_eq!(
        scene
            .warnings
            .iter()
            .filter(|w| w.contains("light 3"))
            .count(),
        1,
        "{:?}",
        scene.warnings
    );
    // A node naming a light that does not exist makes the file malformed: one error line.
    let bad = dir.join("bad-light.gltf");
    std::fs::write(
        &bad,
        GLTF.replace(
            r#"{ "KHR_lights_punctual": { "light": 3 } }"#,
            r#"{ "KHR_lights_punctual": { "light": 9 } }"#,
        ),
    )
    .unwrap();
    let err = oxray_scene::gltf::load(&bad).unwrap_err().to_string();
    assert!(err.contains("light") && err.lines().count() == 1, "{err}");
}

/// A large white diffuse floor at y = 0 seen straight down from above, lit by `light` only.
fn floor_lit_by(light: PunctualLight) -> f32 {
    let r = 50.0;
    let floor = Primitive {
        positions: vec![[-r, 0.0, -r], [-r, 0.0, r], [r, 0.0, r], [r, 0.0, -r]],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        ..Default::default()
    };
    let scene = SceneDesc {
        meshes: vec![MeshDesc {
            name: "floor".into(),
            primitives: vec![floor],
        }],
        materials: vec![MaterialDesc {
            base_color: [1.0; 4],
            roughness: 1.0,
            ..Default::default()
        }],
        instances: vec![InstanceDesc {
            mesh: 0,
            transform: Mat4::IDENTITY,
            node: None,
        }],
        cameras: vec![Camera::look_at(
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(0.0, 0.0, 0.0001),
            0.01,
        )],
        lights: vec![light],
        ..Default::default()
    };
    let opts = RenderOptions {
        width: 3,
        height: 3,
        spp: 1,
        max_depth: 2,
        ..Default::default()
    };
    let img = render(&scene, &Environment::uniform(Vec3::ZERO), &opts, |_| {}).unwrap();
    img.pixels[4][0]
}

fn point_at(height: f32) -> PunctualLight {
    PunctualLight {
        kind: LightKind::Point,
        position: Vec3::new(0.0, height, 0.0),
        direction: Vec3::ZERO,
        intensity: Vec3::splat(683.0),
        range: None,
    }
}

#[test]
fn point_lights_fall_off_with_the_square_of_distance() {
    let (near, far) = (floor_lit_by(point_at(2.0)), floor_lit_by(point_at(4.0)));
    assert!((near / far - 4.0).abs() < 0.01, "{near} {far}");
    // 683 cd is 1 W/sr: irradiance 1/4 at 2 m, reflected by a white Lambertian-like surface
    // as about 1/(4 pi) (Fresnel moves a few percent from the diffuse to the specular lobe).
    let expected = 0.25 / std::f32::consts::PI;
    assert!((near / expected - 1.0).abs() < 0.08, "{near} vs {expected}");
}

#[test]
fn spot_cones_and_ranges_cut_the_light() {
    let spot = |direction: Vec3| PunctualLight {
        kind: LightKind::Spot {
            inner_cone: 0.2,
            outer_cone: 0.4,
        },
        direction,
        ..point_at(2.0)
    };
    let inside = floor_lit_by(spot(Vec3::NEG_Y));
    assert!((inside - floor_lit_by(point_at(2.0))).abs() < 1e-6);
    // Tilted by 0.3 rad: halfway through the falloff, so dimmer but lit.
    let tilted = floor_lit_by(spot(Vec3::new(0.3f32.sin(), -(0.3f32.cos()), 0.0)));
    assert!(tilted > 0.0 && tilted < 0.8 * inside, "{tilted} {inside}");
    // Tilted beyond the outer cone: dark.
    assert_eq!(
        floor_lit_by(spot(Vec3::new(0.5f32.sin(), -(0.5f32.cos()), 0.0))),
        0.0
    );
    // Out of range: dark; well within range: nearly unchanged.
    let ranged = |range| {
        floor_lit_by(PunctualLight {
            range: Some(range),
            ..point_at(2.0)
        })
    };
    assert_eq!(ranged(1.5), 0.0);
    assert!(ranged(100.0) > 0.999 * inside);
}

#[test]
fn directional_lights_give_constant_irradiance_on_the_side_they_face() {
    let sun = |direction: Vec3| PunctualLight {
        kind: LightKind::Directional,
        position: Vec3::ZERO,
        direction,
        intensity: Vec3::splat(683.0),
        range: None,
    };
    let straight = floor_lit_by(sun(Vec3::NEG_Y));
    let expected = 1.0 / std::f32::consts::PI;
    assert!((straight / expected - 1.0).abs() < 0.08, "{straight}");
    // From below the floor: no light reaches the top face.
    assert_eq!(floor_lit_by(sun(Vec3::Y)), 0.0);
}

#[test]
fn the_extensions_fixture_renders_with_its_lights_and_transforms() {
    // The fuzzer's seed for the extension paths must itself load and render.
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../oxray-scene/tests/data/extensions.gltf");
    let scene = SceneDesc::load(&path).unwrap();
    assert_eq!(scene.lights.len(), 3);
    let m = &scene.materials[0];
    assert_ne!(
        m.base_color_texture.unwrap().uv_transform,
        oxray_scene::TextureRef::IDENTITY
    );
    assert_ne!(
        m.emissive_texture.unwrap().uv_transform,
        oxray_scene::TextureRef::IDENTITY
    );
    let opts = RenderOptions {
        width: 8,
        height: 8,
        spp: 2,
        max_depth: 3,
        ..Default::default()
    };
    let img = render(&scene, &Environment::uniform(Vec3::ZERO), &opts, |_| {}).unwrap();
    assert!(img.pixels.iter().flatten().all(|c| c.is_finite()));
    assert!(img.pixels.iter().any(|p| p[0] > 0.0));
}
