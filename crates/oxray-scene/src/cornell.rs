//! The built-in Cornell box: the classic dimensions scaled to the unit cube, diffuse walls, two
//! boxes and a warm area light under the ceiling.

use super::{Camera, InstanceDesc, MaterialDesc, MeshDesc, Primitive, SceneDesc};
use glam::{Mat4, Vec3};

fn diffuse(name: &str, rgb: [f32; 3]) -> MaterialDesc {
    MaterialDesc {
        name: name.into(),
        base_color: [rgb[0], rgb[1], rgb[2], 1.0],
        roughness: 1.0,
        ..Default::default()
    }
}

/// The Cornell box scene with its camera. Materials: 0 white, 1 red, 2 green, 3 light (emitting
/// downwards only).
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
            .extend(p.iter().map(|q| [q[0] / 555.0, q[1] / 555.0, q[2] / 555.0]));
        prim.triangles
            .extend([[b, b + 1, b + 2], [b, b + 2, b + 3]]);
    };
    let s = 555.0;
    quad(
        [[0.0, 0.0, 0.0], [s, 0.0, 0.0], [s, 0.0, s], [0.0, 0.0, s]],
        0,
    ); // floor
    quad([[0.0, s, 0.0], [0.0, s, s], [s, s, s], [s, s, 0.0]], 0); // ceiling
    quad([[0.0, 0.0, s], [s, 0.0, s], [s, s, s], [0.0, s, s]], 0); // back
    quad([[s, 0.0, 0.0], [s, s, 0.0], [s, s, s], [s, 0.0, s]], 2); // left (green)
    quad(
        [[0.0, 0.0, 0.0], [0.0, 0.0, s], [0.0, s, s], [0.0, s, 0.0]],
        1,
    ); // right (red)
    quad(
        [
            [213.0, 554.0, 227.0],
            [343.0, 554.0, 227.0],
            [343.0, 554.0, 332.0],
            [213.0, 554.0, 332.0],
        ],
        3,
    );
    // Two boxes, five quads each (no bottom).
    let mut boxq = |c: [f32; 2], half: f32, h: f32, angle: f32| {
        let (sn, co) = angle.to_radians().sin_cos();
        let corner =
            |dx: f32, dz: f32, y: f32| [c[0] + dx * co - dz * sn, y, c[1] + dx * sn + dz * co];
        let [a, b, cc, d] =
            [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)].map(|(x, z)| (x * half, z * half));
        quad(
            [
                corner(a.0, a.1, h),
                corner(d.0, d.1, h),
                corner(cc.0, cc.1, h),
                corner(b.0, b.1, h),
            ],
            0,
        );
        for (p, q) in [(a, b), (b, cc), (cc, d), (d, a)] {
            quad(
                [
                    corner(p.0, p.1, 0.0),
                    corner(q.0, q.1, 0.0),
                    corner(q.0, q.1, h),
                    corner(p.0, p.1, h),
                ],
                0,
            );
        }
    };
    boxq([185.0, 169.0], 82.5, 165.0, -18.0);
    boxq([368.0, 351.0], 82.5, 330.0, 15.0);
    let eye = Vec3::new(0.5, 0.5, -1.4);
    SceneDesc {
        meshes: vec![MeshDesc {
            name: "cornell box".into(),
            primitives: prims,
        }],
        materials,
        instances: vec![InstanceDesc {
            mesh: 0,
            transform: Mat4::IDENTITY,
        }],
        cameras: vec![Camera::look_at(
            eye,
            Vec3::new(0.5, 0.5, 0.0),
            2.0 * 0.35f32.atan(),
        )],
        ..Default::default()
    }
}
