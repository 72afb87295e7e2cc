//! Flattening: the meshes that a scene places once, at rest, baked into world space as one mesh.
//!
//! A renderer traces a scene as a level of instances over one structure per mesh. Where the
//! meshes are placed once each (most glTF files: a node per part), that level buys nothing and
//! costs every ray a walk over the parts' overlapping boxes before the parts themselves.
//! [`SceneDesc::flattened`] moves those meshes into world space and makes them the primitives
//! of one mesh, placed by an identity instance, so that they are traced as one structure; what
//! the level of instances is for stays: meshes placed more than once, placements that an
//! animation moves, and mirroring placements (a negative determinant turns the triangles'
//! winding, which the renderer's facing follows through the transform).

use super::{InstanceDesc, MeshDesc, Primitive, SceneDesc};
use glam::{Mat3, Mat4, Vec3};

impl SceneDesc {
    /// The scene with every mesh that is placed once, by a transform that no animation moves
    /// and that does not mirror, moved into world space and merged into one mesh (first in
    /// [`meshes`](SceneDesc::meshes), placed by an identity instance, first in
    /// [`instances`](SceneDesc::instances)); the other placements follow with their meshes.
    /// Meshes no instance places are left out. Materials, textures, cameras, lights and
    /// animations are kept as they are; instance indices change, so edits that name instances
    /// belong to the scene as loaded.
    ///
    /// ```
    /// use glam::{Mat4, Vec3};
    /// use oxray_scene::{InstanceDesc, MeshDesc, Primitive, SceneDesc};
    /// let tri = MeshDesc {
    ///     name: "tri".into(),
    ///     primitives: vec![Primitive {
    ///         positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
    ///         triangles: vec![[0, 1, 2]],
    ///         ..Default::default()
    ///     }],
    /// };
    /// let scene = SceneDesc {
    ///     meshes: vec![tri.clone(), tri],
    ///     instances: vec![
    ///         InstanceDesc::new(0, Mat4::from_translation(Vec3::X)),
    ///         InstanceDesc::new(1, Mat4::from_translation(Vec3::Y)),
    ///     ],
    ///     ..Default::default()
    /// };
    /// let flat = scene.flattened();
    /// assert_eq!((flat.meshes.len(), flat.instances.len()), (1, 1));
    /// assert_eq!(flat.meshes[0].primitives[1].positions[1], [1.0, 1.0, 0.0]);
    /// ```
    #[must_use]
    pub fn flattened(&self) -> SceneDesc {
        let mut uses = vec![0u32; self.meshes.len()];
        for inst in &self.instances {
            if let Some(u) = uses.get_mut(inst.mesh as usize) {
                *u += 1;
            }
        }
        let animations = self.animations.len();
        // The ground `add_ground` placed stays an instance of its own, to be told apart.
        let bakes = |i: usize, inst: &InstanceDesc| {
            Some(i) != self.ground
                && uses.get(inst.mesh as usize) == Some(&1)
                && inst.transform.is_finite()
                && inst.transform.determinant() > 0.0
                && !(0..animations).any(|a| self.is_animated(i, a))
        };
        let mut merged = Vec::new();
        let mut kept = Vec::new();
        for (i, inst) in self.instances.iter().enumerate() {
            if bakes(i, inst) {
                let mesh = &self.meshes[inst.mesh as usize];
                merged.extend(mesh.primitives.iter().map(|p| baked(p, inst.transform)));
            } else if (inst.mesh as usize) < self.meshes.len() {
                kept.push((i, inst.clone()));
            }
        }
        let mut meshes = Vec::new();
        let mut instances = Vec::new();
        if !merged.is_empty() {
            meshes.push(MeshDesc {
                name: "flattened".into(),
                primitives: merged,
            });
            instances.push(InstanceDesc::new(0, Mat4::IDENTITY));
        }
        // Each kept mesh once, in the order its first placement comes.
        let mut index = vec![None; self.meshes.len()];
        let mut ground = None;
        for (i, mut inst) in kept {
            let m = inst.mesh as usize;
            inst.mesh = *index[m].get_or_insert_with(|| {
                meshes.push(self.meshes[m].clone());
                meshes.len() as u32 - 1
            });
            if Some(i) == self.ground {
                ground = Some(instances.len());
            }
            instances.push(inst);
        }
        SceneDesc {
            meshes,
            materials: self.materials.clone(),
            textures: self.textures.clone(),
            instances,
            cameras: self.cameras.clone(),
            lights: self.lights.clone(),
            warnings: self.warnings.clone(),
            ground,
            sources: self.sources.clone(),
            nodes: self.nodes.clone(),
            animations: self.animations.clone(),
        }
    }
}

/// `p` moved by `m` (positions by `m`, normals by its inverse transpose, renormalised).
fn baked(p: &Primitive, m: Mat4) -> Primitive {
    // In place already: the same bits (a product by the identity can turn -0 into +0).
    if m == Mat4::IDENTITY {
        return p.clone();
    }
    let normal = Mat3::from_mat4(m).inverse().transpose();
    let positions = p
        .positions
        .iter()
        .map(|&q| m.transform_point3(Vec3::from(q)).to_array())
        .collect();
    let normals = p
        .normals
        .iter()
        .map(|&n| {
            let t = normal * Vec3::from(n);
            t.try_normalize().unwrap_or(t).to_array()
        })
        .collect();
    Primitive {
        positions,
        normals,
        uvs: p.uvs.clone(),
        uvs1: p.uvs1.clone(),
        colors: p.colors.clone(),
        triangles: p.triangles.clone(),
        material: p.material,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::animation::{Animation, Channel, Interpolation, NodeDesc, Property};
    use glam::Quat;

    fn triangle(name: &str, material: u32) -> MeshDesc {
        MeshDesc {
            name: name.into(),
            primitives: vec![Primitive {
                positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                normals: vec![[0.0, 0.0, 1.0]; 3],
                uvs: vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
                triangles: vec![[0, 1, 2]],
                material,
                ..Default::default()
            }],
        }
    }

    #[test]
    fn meshes_placed_once_move_into_world_space_as_one_mesh() {
        let m = Mat4::from_scale_rotation_translation(
            Vec3::new(2.0, 1.0, 1.0),
            Quat::from_rotation_y(std::f32::consts::FRAC_PI_2),
            Vec3::new(0.0, 3.0, 0.0),
        );
        let scene = SceneDesc {
            meshes: vec![triangle("a", 0), triangle("unplaced", 0), triangle("b", 1)],
            instances: vec![
                InstanceDesc::new(2, Mat4::IDENTITY),
                InstanceDesc::new(0, m),
            ],
            ..Default::default()
        };
        let flat = scene.flattened();
        assert_eq!(flat.meshes.len(), 1);
        assert_eq!(flat.instances.len(), 1);
        assert_eq!(flat.instances[0].transform, Mat4::IDENTITY);
        let prims = &flat.meshes[0].primitives;
        // In the instances' order, materials and attributes kept.
        assert_eq!(prims.len(), 2);
        assert_eq!(prims[0].material, 1);
        assert_eq!(prims[0].positions, scene.meshes[2].primitives[0].positions);
        let p = &prims[1];
        for (q, r) in p
            .positions
            .iter()
            .zip(&scene.meshes[0].primitives[0].positions)
        {
            let want = m.transform_point3(Vec3::from(*r));
            assert!(Vec3::from(*q).abs_diff_eq(want, 1e-6), "{q:?} {want}");
        }
        // The normal turns with the rotation (the scale along x does not reach it).
        assert!(
            Vec3::from(p.normals[0]).abs_diff_eq(Vec3::X, 1e-6),
            "{:?}",
            p.normals[0]
        );
        assert_eq!(p.uvs, scene.meshes[0].primitives[0].uvs);
        assert_eq!(p.triangles, [[0, 1, 2]]);
        assert_eq!(flat.triangle_count(), scene.triangle_count());
    }

    #[test]
    fn shared_mirrored_animated_and_ground_placements_stay_instances() {
        let mirror = Mat4::from_scale(Vec3::new(-1.0, 1.0, 1.0));
        let mut scene = SceneDesc {
            meshes: vec![
                triangle("shared", 0),
                triangle("mirrored", 0),
                triangle("moving", 0),
                triangle("still", 0),
            ],
            instances: vec![
                InstanceDesc::new(0, Mat4::IDENTITY),
                InstanceDesc::new(1, mirror),
                InstanceDesc {
                    mesh: 2,
                    transform: Mat4::IDENTITY,
                    node: Some(0),
                },
                InstanceDesc::new(0, Mat4::from_translation(Vec3::X)),
                InstanceDesc::new(3, Mat4::from_translation(Vec3::Y)),
            ],
            nodes: vec![NodeDesc::default()],
            animations: vec![Animation {
                name: "spin".into(),
                channels: vec![Channel {
                    node: 0,
                    property: Property::Translation,
                    interpolation: Interpolation::Linear,
                    times: vec![0.0, 1.0],
                    values: vec![[0.0; 4], [1.0, 0.0, 0.0, 0.0]],
                }],
            }],
            ..Default::default()
        };
        scene.add_ground();
        let ground_mesh = scene.meshes.len() - 1;
        let flat = scene.flattened();
        // The still mesh is baked; the shared one's two placements, the mirror, the animated
        // placement and the ground stay, each mesh once.
        assert_eq!(flat.meshes[0].name, "flattened");
        assert_eq!(flat.meshes[0].primitives.len(), 1);
        let names: Vec<&str> = flat
            .instances
            .iter()
            .map(|i| flat.meshes[i.mesh as usize].name.as_str())
            .collect();
        assert_eq!(
            names,
            [
                "flattened",
                "shared",
                "mirrored",
                "moving",
                "shared",
                "ground"
            ]
        );
        assert_eq!(flat.instances[3].node, Some(0));
        assert_eq!(flat.instances[2].transform, mirror);
        let g = flat.ground.expect("the ground is still known");
        assert_eq!(
            flat.meshes[flat.instances[g].mesh as usize].name,
            scene.meshes[ground_mesh].name
        );
        assert_eq!(flat.triangle_count(), scene.triangle_count());
        assert_eq!(flat.content_bounds(), scene.content_bounds());
    }
}
