//! Renderable scenes: meshes, PBR materials, textures, instances, cameras and lights, in one
//! format-neutral description ([`SceneDesc`]) that every loader (glTF, OBJ+MTL, PLY, the built-in
//! Cornell box) produces and the path tracer (`oxray-render`) consumes. [`mesh`] loads plain
//! triangle meshes for ray casting and benchmarks. Loaders fail with typed errors
//! ([`SceneError`], [`mesh::MeshError`]) whose messages are one line naming the file; problems
//! that do not stop loading become [`SceneDesc::warnings`].
//!
//! ```
//! use oxray_scene::{cornell_box, SceneDesc};
//! use std::path::Path;
//!
//! // The built-in Cornell box, with its own camera and an emissive ceiling panel.
//! let cornell = cornell_box();
//! assert_eq!(cornell.cameras.len(), 1);
//! assert!(cornell.materials.iter().any(|m| m.emissive != [0.0; 3]));
//!
//! // A file, its format picked by the extension (.gltf, .glb, .obj, .ply).
//! let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/triangle.gltf");
//! let scene = SceneDesc::load(&path)?;
//! assert_eq!(scene.triangle_count(), 1);
//! assert_eq!(scene.materials[0].name, "red");
//! for warning in &scene.warnings {
//!     eprintln!("warning: {warning}");
//! }
//!
//! // The same file flattened into one world-space triangle mesh, for ray casting.
//! let mesh = oxray_scene::mesh::Mesh::load(&path)?;
//! assert_eq!(mesh.triangles.len(), 1);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![warn(missing_docs)]

pub mod animation;
mod cornell;
pub mod files;
mod flatten;
pub mod gltf;
mod image;
pub mod mesh;
pub mod obj;
mod text;

pub use animation::NodeDesc;
pub use cornell::cornell_box;

use glam::{Mat4, Vec3};
use std::path::Path;
use thiserror::Error;

/// A scene ready to render.
#[derive(Clone, Debug, Default)]
pub struct SceneDesc {
    /// Meshes; instances refer to them by index.
    pub meshes: Vec<MeshDesc>,
    /// Materials; primitives refer to them by index.
    pub materials: Vec<MaterialDesc>,
    /// Textures; materials refer to them by index.
    pub textures: Vec<Texture>,
    /// Placements of meshes in the world (glTF nodes with a mesh; one identity instance per mesh
    /// for OBJ and PLY).
    pub instances: Vec<InstanceDesc>,
    /// The scene's own cameras, first one used by default.
    pub cameras: Vec<Camera>,
    /// Point, spot and directional lights (glTF `KHR_lights_punctual`), in world space.
    pub lights: Vec<PunctualLight>,
    /// Problems that did not stop loading (a missing texture, an unsupported feature), one line
    /// each, for the caller to print.
    pub warnings: Vec<String>,
    /// The instance [`SceneDesc::add_ground`] added, if any.
    pub ground: Option<usize>,
    /// Every file the loader read (the scene file, its buffers, material libraries and
    /// images), so that a caller can refuse to write over one of them.
    pub sources: Vec<std::path::PathBuf>,
    /// The node hierarchy (glTF `nodes`, by index; empty for formats without one), which
    /// [`InstanceDesc::node`] and the animations refer to.
    pub nodes: Vec<NodeDesc>,
    /// Node animations ([`animation`]), played one at a time.
    pub animations: Vec<animation::Animation>,
}

/// A mesh: one or more primitives, each with its own material.
#[derive(Clone, Debug, Default)]
pub struct MeshDesc {
    /// A name for messages.
    pub name: String,
    /// The primitives.
    pub primitives: Vec<Primitive>,
}

/// A triangle list with optional per-vertex attributes, all in the mesh's object space.
#[derive(Clone, Debug, Default)]
pub struct Primitive {
    /// Vertex positions.
    pub positions: Vec<[f32; 3]>,
    /// Per-vertex normals (same length as `positions`), or empty for flat shading.
    pub normals: Vec<[f32; 3]>,
    /// Per-vertex texture coordinates (set 0), or empty.
    pub uvs: Vec<[f32; 2]>,
    /// Per-vertex texture coordinates of set 1 (glTF `TEXCOORD_1`), or empty.
    pub uvs1: Vec<[f32; 2]>,
    /// Per-vertex linear RGBA colours (glTF `COLOR_0`; alpha 1 for RGB colours), multiplied
    /// with the base colour and its alpha; or empty.
    pub colors: Vec<[f32; 4]>,
    /// Triangles as vertex-index triplets, every index `< positions.len()`.
    pub triangles: Vec<[u32; 3]>,
    /// Index into [`SceneDesc::materials`].
    pub material: u32,
}

/// How a material's alpha is used (glTF `alphaMode`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum AlphaMode {
    /// Alpha is ignored.
    #[default]
    Opaque,
    /// Fully transparent below the cutoff, opaque otherwise.
    Mask {
        /// The cutoff (glTF default 0.5).
        cutoff: f32,
    },
    /// Partial coverage: rendered as stochastic transparency.
    Blend,
}

/// A texture reference: a texture coordinate set (0 or 1) mapped through a 2x3 affine
/// transform (glTF `KHR_texture_transform`) before sampling.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TextureRef {
    /// Index into [`SceneDesc::textures`].
    pub texture: u32,
    /// Rows of the UV transform: `u' = m[0] u + m[1] v + m[2]`, `v' = m[3] u + m[4] v + m[5]`.
    pub uv_transform: [f32; 6],
    /// The texture coordinate set: 0 ([`Primitive::uvs`]) or 1 ([`Primitive::uvs1`]).
    pub tex_coord: u32,
}

impl TextureRef {
    /// The identity UV transform.
    pub const IDENTITY: [f32; 6] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0];

    /// A reference to `texture` with untransformed coordinates.
    #[must_use]
    pub fn new(texture: u32) -> TextureRef {
        TextureRef {
            texture,
            uv_transform: Self::IDENTITY,
            tex_coord: 0,
        }
    }

    /// The same reference, reading texture coordinate set `set` (0 or 1).
    #[must_use]
    pub fn with_tex_coord(mut self, set: u32) -> Self {
        self.tex_coord = set;
        self
    }

    /// The transform of `KHR_texture_transform`: scale, then rotate by `rotation` radians
    /// (counter-clockwise in UV space, which is clockwise in the image), then offset.
    #[must_use]
    pub fn with_khr_transform(mut self, offset: [f32; 2], rotation: f32, scale: [f32; 2]) -> Self {
        let (s, c) = rotation.sin_cos();
        self.uv_transform = [
            c * scale[0],
            s * scale[1],
            offset[0],
            -s * scale[0],
            c * scale[1],
            offset[1],
        ];
        self
    }

    /// Applies the UV transform.
    #[must_use]
    pub fn map(&self, u: f32, v: f32) -> (f32, f32) {
        let m = &self.uv_transform;
        (m[0] * u + m[1] * v + m[2], m[3] * u + m[4] * v + m[5])
    }
}

/// A metallic-roughness PBR material (the glTF 2.0 model) with transmission for dielectrics.
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialDesc {
    /// A name for messages.
    pub name: String,
    /// Linear base colour and alpha.
    pub base_color: [f32; 4],
    /// Base colour texture (sRGB colour, linear alpha), multiplied with `base_color`.
    pub base_color_texture: Option<TextureRef>,
    /// Metalness in [0, 1].
    pub metallic: f32,
    /// Perceptual roughness in [0, 1].
    pub roughness: f32,
    /// Metallic (blue) and roughness (green) texture, multiplied with the factors.
    pub metallic_roughness_texture: Option<TextureRef>,
    /// Linear emitted radiance (glTF emissive factor times emissive strength).
    pub emissive: [f32; 3],
    /// Emissive texture (sRGB), multiplied with `emissive`.
    pub emissive_texture: Option<TextureRef>,
    /// Tangent-space normal map.
    pub normal_texture: Option<TextureRef>,
    /// Scale of the normal map's x and y.
    pub normal_scale: f32,
    /// Alpha handling.
    pub alpha_mode: AlphaMode,
    /// Whether back faces are shaded like front faces (glTF `doubleSided`).
    pub double_sided: bool,
    /// Specular transmission in [0, 1]: 1 makes a smooth dielectric (glass, water).
    pub transmission: f32,
    /// Index of refraction of a dielectric.
    pub ior: f32,
    /// Strength of the specular reflection of the non-metallic part, in [0, 1] (glTF
    /// `KHR_materials_specular`'s `specularFactor`): 1 is glTF's default dielectric coat
    /// (4 % reflectance at normal incidence), 0 a purely Lambertian diffuse material.
    pub specular: f32,
}

impl Default for MaterialDesc {
    fn default() -> Self {
        MaterialDesc {
            name: "default".into(),
            base_color: [0.8, 0.8, 0.8, 1.0],
            base_color_texture: None,
            metallic: 0.0,
            roughness: 0.5,
            metallic_roughness_texture: None,
            emissive: [0.0; 3],
            emissive_texture: None,
            normal_texture: None,
            normal_scale: 1.0,
            alpha_mode: AlphaMode::Opaque,
            double_sided: true,
            transmission: 0.0,
            ior: 1.5,
            specular: 1.0,
        }
    }
}

/// How texture coordinates outside [0, 1] are treated.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Wrap {
    /// Tile.
    #[default]
    Repeat,
    /// Tile, mirroring every other copy.
    MirroredRepeat,
    /// Clamp to the edge texel.
    ClampToEdge,
}

/// An RGBA8 texture. Colour channels are stored as in the file; whether they are sRGB-encoded is
/// decided by the material slot that uses the texture (base colour and emissive are sRGB, the
/// others linear).
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    /// A name for messages (usually the file name).
    pub name: String,
    /// Width in texels (at least 1).
    pub width: u32,
    /// Height in texels (at least 1).
    pub height: u32,
    /// Texels, row-major from the top row, `width * height` of them.
    pub texels: Vec<[u8; 4]>,
    /// Wrapping along u.
    pub wrap_u: Wrap,
    /// Wrapping along v.
    pub wrap_v: Wrap,
}

impl Texture {
    /// A 1x1 texture of one colour (the stand-in for a texture that could not be loaded).
    #[must_use]
    pub fn solid(name: &str, rgba: [u8; 4]) -> Texture {
        Texture {
            name: name.into(),
            width: 1,
            height: 1,
            texels: vec![rgba],
            wrap_u: Wrap::Repeat,
            wrap_v: Wrap::Repeat,
        }
    }
}

/// A placement of a mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct InstanceDesc {
    /// Index into [`SceneDesc::meshes`].
    pub mesh: u32,
    /// Object to world (glTF: the node's global transform at rest).
    pub transform: Mat4,
    /// The node that places the mesh (index into [`SceneDesc::nodes`]), through which
    /// animations move it; `None` for a placement no animation can move.
    pub node: Option<u32>,
}

/// The kind of a punctual light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LightKind {
    /// Light from one direction, like the sun: `intensity` is irradiance on a surface facing it.
    Directional,
    /// Light from a point in all directions: `intensity` is radiant intensity (per steradian).
    Point,
    /// A point light limited to a cone, with a smooth falloff between the inner and outer
    /// angles (radians).
    Spot {
        /// Full intensity inside this angle from the axis.
        inner_cone: f32,
        /// No light beyond this angle.
        outer_cone: f32,
    },
}

/// A light with no extent (glTF `KHR_lights_punctual`): it cannot be hit by rays, only sampled.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PunctualLight {
    /// Kind and cone.
    pub kind: LightKind,
    /// World position (unused for directional lights).
    pub position: Vec3,
    /// Unit world direction the light shines in (unused for point lights).
    pub direction: Vec3,
    /// Linear colour times intensity.
    pub intensity: Vec3,
    /// Distance beyond which a point or spot light has no effect (`None`: unlimited).
    pub range: Option<f32>,
}

impl InstanceDesc {
    /// The placement as an engine transform, or `None` when it cannot be traced (a non-finite
    /// or singular matrix: such an instance has no visible surface).
    #[must_use]
    pub fn placement(&self) -> Option<oxray::Transform> {
        let m = self.transform;
        (m.is_finite() && m.determinant().abs() > 1e-30)
            .then(|| oxray::Transform::from_affine(&glam::Affine3A::from_mat4(m)))
    }
}

/// A pinhole camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Camera to world: the camera looks down its local -Z with +Y up (the glTF convention).
    pub to_world: Mat4,
    /// Vertical field of view in radians.
    pub yfov: f32,
    /// The aspect ratio (width / height) the scene asks for, if any.
    pub aspect: Option<f32>,
    /// The node the camera hangs on (glTF: the node that names it), through which the scene's
    /// animations move it; `None` for a camera placed by `to_world` alone.
    pub node: Option<u32>,
}

impl Camera {
    /// A camera at `eye` looking at `target`, with +Y up.
    #[must_use]
    pub fn look_at(eye: Vec3, target: Vec3, yfov: f32) -> Camera {
        let up = if (target - eye).normalize().cross(Vec3::Y).length() < 1e-3 {
            Vec3::Z
        } else {
            Vec3::Y
        };
        Camera {
            to_world: Self::to_world_looking_at(eye, target, up),
            yfov,
            aspect: None,
            node: None,
        }
    }

    /// The same camera hung on node `node` (see [`Camera::node`]).
    #[must_use]
    pub fn at_node(mut self, node: u32) -> Camera {
        self.node = Some(node);
        self
    }

    /// The camera-to-world transform of a camera at `eye` looking at `target` with `up` up,
    /// in glTF's convention (it looks down its -Z axis, +Y up, +X right): the columns are its
    /// right, up and back directions and its position. `up` must not be parallel to the view.
    ///
    /// ```
    /// use glam::Vec3;
    /// use oxray_scene::Camera;
    /// let m = Camera::to_world_looking_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y);
    /// assert_eq!(m.transform_vector3(-Vec3::Z), -Vec3::Z);
    /// assert_eq!(m.transform_point3(Vec3::ZERO), Vec3::new(0.0, 0.0, 5.0));
    /// ```
    #[must_use]
    pub fn to_world_looking_at(eye: Vec3, target: Vec3, up: Vec3) -> Mat4 {
        let forward = (target - eye).normalize();
        let right = forward.cross(up).normalize();
        let up = right.cross(forward);
        Mat4::from_cols(
            right.extend(0.0),
            up.extend(0.0),
            (-forward).extend(0.0),
            eye.extend(1.0),
        )
    }
}

/// Why a scene could not be loaded. Each message is one line naming the file.
#[derive(Debug, Error)]
pub enum SceneError {
    /// The file could not be read.
    #[error("{path}: {message}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        message: String,
    },
    /// The extension names no supported format.
    #[error("{path}: unknown scene format (expected .gltf, .glb, .obj or .ply)")]
    UnknownFormat {
        /// The file.
        path: String,
    },
    /// The file is malformed.
    #[error("{path}: {message}")]
    Malformed {
        /// The file.
        path: String,
        /// What is wrong.
        message: String,
    },
    /// The scene has nothing to render.
    #[error("{path}: the scene has no triangles")]
    Empty {
        /// The file.
        path: String,
    },
}

impl SceneDesc {
    /// Loads a `.gltf`, `.glb`, `.obj` (with its `.mtl`) or `.ply` file.
    pub fn load(path: &Path) -> Result<SceneDesc, SceneError> {
        let name = path.display().to_string();
        let ext = crate::file_extension(path);
        let scene = match ext.as_deref() {
            Some("gltf") | Some("glb") => gltf::load(path)?,
            Some("obj") => obj::load(path)?,
            Some("ply") => {
                let mesh = crate::mesh::Mesh::load(path).map_err(|e| SceneError::Malformed {
                    path: name.clone(),
                    message: strip_path(&e.to_string(), &name),
                })?;
                let mut scene = SceneDesc::from_mesh(&name, mesh);
                scene.sources.push(path.to_path_buf());
                scene
            }
            _ => return Err(SceneError::UnknownFormat { path: name }),
        };
        if scene.triangle_count() == 0 {
            return Err(SceneError::Empty { path: name });
        }
        Ok(scene)
    }

    /// A scene of one untextured mesh with the default material.
    #[must_use]
    pub fn from_mesh(name: &str, mesh: crate::mesh::Mesh) -> SceneDesc {
        SceneDesc {
            meshes: vec![MeshDesc {
                name: name.into(),
                primitives: vec![Primitive {
                    positions: mesh.positions,
                    triangles: mesh.triangles,
                    ..Default::default()
                }],
            }],
            materials: vec![MaterialDesc::default()],
            instances: vec![InstanceDesc {
                mesh: 0,
                transform: Mat4::IDENTITY,
                node: None,
            }],
            ..Default::default()
        }
    }

    /// Adds a large grey ground square under the scene (at its lowest point, ten times its
    /// size), so that objects stand on something and cast visible shadows. Nothing happens for
    /// an empty scene. The framing camera still frames the original bounds.
    pub fn add_ground(&mut self) {
        let Some((lo, hi)) = self.bounds() else {
            return;
        };
        let c = (lo + hi) * 0.5;
        let r = ((hi - lo).length() * 5.0).max(1e-3);
        let y = lo.y;
        let material = self.materials.len() as u32;
        self.materials.push(MaterialDesc {
            name: "ground".into(),
            base_color: [0.45, 0.45, 0.45, 1.0],
            roughness: 1.0,
            ..Default::default()
        });
        self.meshes.push(MeshDesc {
            name: "ground".into(),
            primitives: vec![Primitive {
                positions: vec![
                    [c.x - r, y, c.z - r],
                    [c.x - r, y, c.z + r],
                    [c.x + r, y, c.z + r],
                    [c.x + r, y, c.z - r],
                ],
                normals: vec![[0.0, 1.0, 0.0]; 4],
                triangles: vec![[0, 1, 2], [0, 2, 3]],
                material,
                ..Default::default()
            }],
        });
        self.ground = Some(self.instances.len());
        self.instances.push(InstanceDesc {
            mesh: self.meshes.len() as u32 - 1,
            transform: Mat4::IDENTITY,
            node: None,
        });
    }

    /// World-space bounds of the scene's own content: every instance but the added ground.
    #[must_use]
    pub fn content_bounds(&self) -> Option<(Vec3, Vec3)> {
        match self.ground {
            None => self.bounds(),
            Some(g) => {
                let mut own = self.clone();
                own.instances.remove(g);
                own.ground = None;
                own.bounds()
            }
        }
    }

    /// Triangles over all instances.
    #[must_use]
    pub fn triangle_count(&self) -> u64 {
        self.instances
            .iter()
            .filter_map(|i| self.meshes.get(i.mesh as usize))
            .flat_map(|m| &m.primitives)
            .map(|p| p.triangles.len() as u64)
            .sum()
    }

    /// World-space bounds over all instances, or `None` for an empty scene.
    #[must_use]
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for inst in &self.instances {
            let Some(mesh) = self.meshes.get(inst.mesh as usize) else {
                continue;
            };
            for p in mesh.primitives.iter().flat_map(|p| &p.positions) {
                let w = inst.transform.transform_point3(Vec3::from(*p));
                if w.is_finite() {
                    lo = lo.min(w);
                    hi = hi.max(w);
                }
            }
        }
        (lo.x <= hi.x).then_some((lo, hi))
    }

    /// Checks the invariants the renderer relies on: indices in range, attribute lengths,
    /// material, texture and mesh references. Loaders call this last, so a malformed file is
    /// reported instead of crashing the renderer.
    pub fn validate(&self) -> Result<(), String> {
        for (ti, t) in self.textures.iter().enumerate() {
            if t.width == 0
                || t.height == 0
                || t.texels.len() as u64 != t.width as u64 * t.height as u64
            {
                return Err(format!("texture {ti} ({}) has inconsistent size", t.name));
            }
        }
        let tex_ok = |r: &Option<TextureRef>| {
            r.is_none_or(|r| (r.texture as usize) < self.textures.len() && r.tex_coord <= 1)
        };
        for (mi, m) in self.materials.iter().enumerate() {
            if !(tex_ok(&m.base_color_texture)
                && tex_ok(&m.metallic_roughness_texture)
                && tex_ok(&m.emissive_texture)
                && tex_ok(&m.normal_texture))
            {
                return Err(format!(
                    "material {mi} ({}) refers to a missing texture or texture coordinate set",
                    m.name
                ));
            }
        }
        for (mi, mesh) in self.meshes.iter().enumerate() {
            for (pi, p) in mesh.primitives.iter().enumerate() {
                let n = p.positions.len();
                let bad = |len: usize| len != 0 && len != n;
                if bad(p.normals.len())
                    || bad(p.uvs.len())
                    || bad(p.uvs1.len())
                    || bad(p.colors.len())
                {
                    return Err(format!(
                        "mesh {mi} ({}) primitive {pi}: attribute count differs from the {n} positions",
                        mesh.name
                    ));
                }
                if let Some(t) = p
                    .triangles
                    .iter()
                    .position(|t| t.iter().any(|&i| i as usize >= n))
                {
                    return Err(format!(
                        "mesh {mi} ({}) primitive {pi}: triangle {t} refers to a vertex beyond the {n} positions",
                        mesh.name
                    ));
                }
                if p.material as usize >= self.materials.len() {
                    return Err(format!(
                        "mesh {mi} ({}) primitive {pi}: material {} does not exist",
                        mesh.name, p.material
                    ));
                }
            }
        }
        for (ii, inst) in self.instances.iter().enumerate() {
            if inst.mesh as usize >= self.meshes.len() {
                return Err(format!(
                    "instance {ii} refers to missing mesh {}",
                    inst.mesh
                ));
            }
        }
        Ok(())
    }
}

/// A file's extension in lower case (`None` without one, or when it is not UTF-8): how every
/// loader and writer picks a format.
#[must_use]
pub fn file_extension(path: &Path) -> Option<String> {
    path.extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
}

/// Drops a leading "path: " from a message that will be prefixed with the path again.
fn strip_path(message: &str, path: &str) -> String {
    message
        .strip_prefix(path)
        .and_then(|m| m.strip_prefix(": "))
        .unwrap_or(message)
        .to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn placements_convert_exactly_and_refuse_singular_matrices() {
        let at = |transform| InstanceDesc::new(0, transform);
        // The renderer traces an untransformed single instance as its GAS: that needs the
        // identity to convert to exactly the engine's identity.
        assert_eq!(
            at(Mat4::IDENTITY).placement(),
            Some(oxray::Transform::IDENTITY)
        );
        let t = at(Mat4::from_translation(Vec3::new(1.0, 2.0, 3.0)))
            .placement()
            .unwrap();
        assert_eq!(t.transform_point(Vec3::ZERO), Vec3::new(1.0, 2.0, 3.0));
        assert_eq!(
            at(Mat4::from_scale(Vec3::new(1.0, 0.0, 1.0))).placement(),
            None
        );
        assert_eq!(
            at(Mat4::from_scale(Vec3::splat(f32::NAN))).placement(),
            None
        );
    }
}
