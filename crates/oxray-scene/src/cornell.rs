//! The built-in Cornell box: the geometry of the Cornell University Program of Computer
//! Graphics' measured data (<https://www.graphics.cornell.edu/online/box/data.html>) scaled by
//! 1/555, with its camera, Lambertian walls (red on the left seen from the camera, green on the
//! right), the two blocks as measured and the area light under the ceiling.

use super::{Camera, InstanceDesc, MaterialDesc, MeshDesc, Primitive, SceneDesc};
use glam::{Mat4, Vec3};

/// A Lambertian material (no specular coat).
fn diffuse(name: &str, rgb: [f32; 3]) -> MaterialDesc {
    MaterialDesc {
        name: name.into(),
        base_color: [rgb[0], rgb[1], rgb[2], 1.0],
        roughness: 1.0,
        specular: 0.0,
        ..Default::default()
    }
}

/// The data's units (millimetres) per scene unit.
const SCALE: f32 = 555.0;

/// The light's height: the data puts it in the ceiling's plane (548.8); it sits half a
/// millimetre lower so that rays meet it, not the coincident ceiling.
const LIGHT_Y: f32 = 548.3;

/// The Cornell box scene with its camera (the data's pinhole: at (278, 273, -800) mm looking
/// down +Z, a 25 mm film at 35 mm focal length). Materials: 0 white, 1 red, 2 green, 3 light
/// (emitting downwards only). Every quad is listed as in the data, whose windings face the
/// room's inside and the blocks' outside.
#[must_use]
pub fn cornell_box() -> SceneDesc {
    let mut light = diffuse("light", [0.78; 3]);
    light.emissive = [17.0, 12.0, 4.0];
    light.double_sided = false;
    let materials = vec![
        diffuse("white", [0.73; 3]),
        diffuse("red", [0.65, 0.05, 0.05]),
        diffuse("green", [0.12, 0.45, 0.15]),
        light,
    ];
    let mut prims: Vec<Primitive> = (0..materials.len() as u32)
        .map(|material| Primitive {
            material,
            ..Default::default()
        })
        .collect();
    let mut quad = |p: [[f32; 3]; 4], mat: usize| {
        let prim = &mut prims[mat];
        let b = prim.positions.len() as u32;
        prim.positions
            .extend(p.iter().map(|q| [q[0] / SCALE, q[1] / SCALE, q[2] / SCALE]));
        prim.triangles
            .extend([[b, b + 1, b + 2], [b, b + 2, b + 3]]);
    };
    let (white, red, green, emitter) = (0, 1, 2, 3);
    // Floor, ceiling, back wall.
    quad(
        [
            [552.8, 0.0, 0.0],
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 559.2],
            [549.6, 0.0, 559.2],
        ],
        white,
    );
    quad(
        [
            [556.0, 548.8, 0.0],
            [556.0, 548.8, 559.2],
            [0.0, 548.8, 559.2],
            [0.0, 548.8, 0.0],
        ],
        white,
    );
    quad(
        [
            [549.6, 0.0, 559.2],
            [0.0, 0.0, 559.2],
            [0.0, 548.8, 559.2],
            [556.0, 548.8, 559.2],
        ],
        white,
    );
    // The red wall at x = 550 is on the camera's left (it looks down +Z with +Y up, so +X is
    // to its left); the green wall at x = 0 on its right.
    quad(
        [
            [552.8, 0.0, 0.0],
            [549.6, 0.0, 559.2],
            [556.0, 548.8, 559.2],
            [556.0, 548.8, 0.0],
        ],
        red,
    );
    quad(
        [
            [0.0, 0.0, 559.2],
            [0.0, 0.0, 0.0],
            [0.0, 548.8, 0.0],
            [0.0, 548.8, 559.2],
        ],
        green,
    );
    quad(
        [
            [343.0, LIGHT_Y, 227.0],
            [343.0, LIGHT_Y, 332.0],
            [213.0, LIGHT_Y, 332.0],
            [213.0, LIGHT_Y, 227.0],
        ],
        emitter,
    );
    // A block from its top face's corners (as the data lists them) and its height: the top and
    // four sides (no bottom).
    let mut block = |top: [[f32; 2]; 4], h: f32| {
        let [a, b, c, d] = top;
        quad(
            [
                [a[0], h, a[1]],
                [b[0], h, b[1]],
                [c[0], h, c[1]],
                [d[0], h, d[1]],
            ],
            white,
        );
        for (p, q) in [(d, c), (a, d), (b, a), (c, b)] {
            quad(
                [
                    [p[0], 0.0, p[1]],
                    [p[0], h, p[1]],
                    [q[0], h, q[1]],
                    [q[0], 0.0, q[1]],
                ],
                white,
            );
        }
    };
    // The short block, turned to face the right wall, and the tall one.
    block(
        [[130.0, 65.0], [82.0, 225.0], [240.0, 272.0], [290.0, 114.0]],
        165.0,
    );
    block(
        [
            [423.0, 247.0],
            [265.0, 296.0],
            [314.0, 456.0],
            [472.0, 406.0],
        ],
        330.0,
    );
    let eye = Vec3::new(278.0, 273.0, -800.0) / SCALE;
    SceneDesc {
        meshes: vec![MeshDesc {
            name: "cornell box".into(),
            primitives: prims,
        }],
        materials,
        instances: vec![InstanceDesc {
            mesh: 0,
            transform: Mat4::IDENTITY,
            node: None,
        }],
        cameras: vec![Camera::look_at(
            eye,
            eye + Vec3::Z,
            2.0 * (12.5f32 / 35.0).atan(),
        )],
        ..Default::default()
    }
}
