//! The OBJ + MTL loader (through `tobj`).
//!
//! The file becomes one mesh, named after the file and placed once by an identity instance:
//! OBJ has no instancing, so nothing is gained by a level of instances, which costs every ray a
//! walk over the objects' overlapping boxes (a 38-object file renders 1.25x faster as one
//! structure, docs/BENCHMARKS.md). Each object, split wherever its material changes, is one
//! primitive of that mesh (one build input of its GAS). Polygons are triangulated as fans in
//! file order. MTL materials map onto the metallic-roughness model:
//!
//! - `Kd` is the base colour, `map_Kd` its texture (relative to the `.mtl` file);
//! - `Ke` (or a `Ke` tobj did not recognise) is the emitted radiance;
//! - `d` (or `1 - Tr`) is the alpha; below 1 the material is blended;
//! - `Ns` gives the roughness `sqrt(2 / (Ns + 2))` (the Blinn-Phong to GGX correspondence), `Pr`
//!   overrides it;
//! - `illum` 3 or 5, or a specular colour brighter than the diffuse one, makes a metal whose
//!   colour is `Ks`; `Pm` sets the metalness directly;
//! - `illum` 4, 6 or 7 with `Ni > 1`, or `d < 1` with `Ni > 1`, makes a glass (transmission 1,
//!   index of refraction `Ni`), which is then opaque: transmission models its transparency;
//! - `illum` 0 or 1 (no specular term) makes a Lambertian diffuse material (`specular` 0),
//!   unless `Pm` makes it metallic.
//!
//! A missing or unreadable `.mtl` or texture is a warning; the geometry still loads.

use super::image::ImageError;
use super::{
    image, AlphaMode, InstanceDesc, MaterialDesc, MeshDesc, Primitive, SceneDesc, SceneError,
    Texture, TextureRef,
};
use glam::Mat4;
use rayon::prelude::*;
use std::cell::RefCell;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Loads an `.obj` file with the material libraries it names.
pub fn load(path: &Path) -> Result<SceneDesc, SceneError> {
    let name = path.display().to_string();
    let bytes = crate::files::read_input(path).map_err(|e| SceneError::Io {
        path: name.clone(),
        message: e.to_string(),
    })?;
    let bytes = crate::text::fix_obj(crate::text::to_utf8(bytes));
    let sources = RefCell::new(vec![path.to_path_buf()]);
    crate::mesh::check_obj_indices(&bytes).map_err(|e| SceneError::Malformed {
        path: name.clone(),
        message: format!("malformed OBJ: {e}"),
    })?;
    let base = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let warnings = RefCell::new(Vec::new());
    // The directory of each loaded material's library, in tobj's material order, so that
    // texture paths resolve relative to their `.mtl` file.
    let material_dirs = RefCell::new(Vec::new());
    let opts = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let (models, materials) = tobj::load_obj_buf(&mut &bytes[..], &opts, |mtl| {
        let file = base.join(mtl);
        let label = mtl.display().to_string();
        let text = match crate::files::read_input(&file) {
            Ok(b) => {
                sources.borrow_mut().push(file.clone());
                String::from_utf8(crate::text::to_utf8(b)).unwrap_or_default()
            }
            Err(e) => {
                warnings.borrow_mut().push(format!(
                    "{name}: material library {label}: cannot read ({e}); using default materials"
                ));
                return Ok(Default::default());
            }
        };
        let text = sanitize_mtl(
            &text,
            &format!("{name}: material library {label}"),
            &mut warnings.borrow_mut(),
        );
        match tobj::load_mtl_buf(&mut text.as_bytes()) {
            Ok((mats, map)) => {
                let dir = file.parent().unwrap_or(Path::new(".")).to_path_buf();
                material_dirs
                    .borrow_mut()
                    .extend(std::iter::repeat_n(dir, mats.len()));
                Ok((mats, map))
            }
            Err(e) => {
                warnings.borrow_mut().push(format!(
                    "{name}: material library {label}: {e}; using default materials"
                ));
                Ok(Default::default())
            }
        }
    })
    .map_err(|e| SceneError::Malformed {
        path: name.clone(),
        message: format!("malformed OBJ: {e}"),
    })?;
    // The loader above never fails, so an error here cannot happen; keep the geometry anyway.
    let materials = materials.unwrap_or_default();
    let material_dirs = material_dirs.into_inner();
    let mut scene = SceneDesc {
        warnings: warnings.into_inner(),
        sources: sources.into_inner(),
        ..Default::default()
    };

    // Textures: each distinct file decoded once, in parallel.
    let texture_path = |mi: usize, map: &str| -> PathBuf {
        let dir = material_dirs
            .get(mi)
            .cloned()
            .unwrap_or_else(|| base.clone());
        dir.join(texture_file(map))
    };
    let mut files: Vec<(PathBuf, String)> = materials
        .iter()
        .enumerate()
        .filter_map(|(mi, m)| {
            let map = m.diffuse_texture.as_deref()?;
            Some((texture_path(mi, map), map.to_string()))
        })
        .collect();
    files.sort();
    files.dedup_by(|a, b| a.0 == b.0);
    // Read, then check every image's decoded size against the limits before decoding any.
    let fatal = |message: String| SceneError::Malformed {
        path: name.clone(),
        message,
    };
    let read: Vec<(PathBuf, String, Result<Vec<u8>, ImageError>)> = files
        .into_par_iter()
        .map(|(file, label)| {
            let bytes = image::read_file(&file);
            (file, label, bytes)
        })
        .collect();
    let mut sizes = Vec::new();
    for (_, label, bytes) in &read {
        let size = match bytes {
            Ok(b) => image::decoded_size(b),
            Err(ImageError::Fatal(e)) => Err(ImageError::Fatal(e.clone())),
            Err(ImageError::Skip(_)) => continue,
        };
        match size {
            Ok(size) => sizes.push(size),
            Err(ImageError::Fatal(e)) => return Err(fatal(format!("texture {label}: {e}"))),
            Err(ImageError::Skip(_)) => {}
        }
    }
    image::check_total(sizes).map_err(fatal)?;
    let decoded: Vec<(PathBuf, String, Result<Texture, ImageError>)> = read
        .into_par_iter()
        .map(|(file, label, bytes)| {
            let t = bytes.and_then(|b| image::decode(texture_file(&label), &b));
            (file, label, t)
        })
        .collect();
    let mut by_file: HashMap<PathBuf, Option<u32>> = HashMap::new();
    for (file, label, t) in decoded {
        scene.sources.push(file.clone());
        match t {
            Ok(t) => {
                scene.textures.push(t);
                by_file.insert(file, Some(scene.textures.len() as u32 - 1));
            }
            Err(ImageError::Fatal(e)) => return Err(fatal(format!("texture {label}: {e}"))),
            Err(ImageError::Skip(e)) => {
                scene.warnings.push(format!(
                    "{name}: texture {label}: {e}; rendering without it"
                ));
                by_file.insert(file, None);
            }
        }
    }
    for (mi, m) in materials.iter().enumerate() {
        let texture = m
            .diffuse_texture
            .as_deref()
            .and_then(|map| by_file.get(&texture_path(mi, map)).copied().flatten())
            .map(TextureRef::new);
        scene.materials.push(convert(m, texture));
    }

    let mut default_material = None;
    let mut primitives = Vec::new();
    for model in models {
        let mesh = model.mesh;
        if mesh.indices.len() < 3 {
            continue;
        }
        let n = mesh.positions.len() / 3;
        let positions: Vec<[f32; 3]> = mesh
            .positions
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        // tobj leaves out the normal or texture coordinate of a vertex that has none, so the
        // attributes are only usable when every vertex has one.
        let normals = if mesh.normals.len() == 3 * n {
            mesh.normals
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect()
        } else {
            Vec::new()
        };
        // OBJ's v axis points up from the bottom row; textures here start at the top row.
        let uvs = if mesh.texcoords.len() == 2 * n {
            mesh.texcoords
                .chunks_exact(2)
                .map(|c| [c[0], 1.0 - c[1]])
                .collect()
        } else {
            Vec::new()
        };
        let triangles = mesh
            .indices
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        let material = match mesh.material_id.filter(|&m| m < materials.len()) {
            Some(m) => m as u32,
            None => *default_material.get_or_insert_with(|| {
                scene.materials.push(MaterialDesc::default());
                scene.materials.len() as u32 - 1
            }),
        };
        primitives.push(Primitive {
            positions,
            normals,
            uvs,
            triangles,
            material,
            ..Default::default()
        });
    }
    if !primitives.is_empty() {
        scene.instances.push(InstanceDesc {
            mesh: 0,
            transform: Mat4::IDENTITY,
            node: None,
        });
        let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned());
        scene.meshes.push(MeshDesc {
            name: stem.unwrap_or_else(|| name.clone()),
            primitives,
        });
    }
    scene.validate().map_err(|message| SceneError::Malformed {
        path: name.clone(),
        message,
    })?;
    Ok(scene)
}

/// The file name of a texture statement's argument: options such as `-bm 1` come first, so
/// when there are options the file is the last word.
fn texture_file(map: &str) -> &str {
    if map.starts_with('-') {
        map.split_whitespace().last().unwrap_or(map)
    } else {
        map
    }
}

/// Drops MTL lines that tobj would reject or crash on (a colour with fewer than three numbers
/// makes it panic), with one warning per file, so one bad line does not cost every material.
fn sanitize_mtl(text: &str, label: &str, warnings: &mut Vec<String>) -> String {
    let mut out = String::with_capacity(text.len());
    let mut bad = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        let key = words.next().unwrap_or("");
        let floats = |n: usize, words: std::str::SplitWhitespace| {
            words.take(n).filter(|w| w.parse::<f32>().is_ok()).count() == n
        };
        let ok = match key {
            "Ka" | "Kd" | "Ks" | "Ke" => floats(3, words),
            "Ns" | "Ni" | "d" => floats(1, words),
            "illum" => words.next().is_some_and(|w| w.parse::<u8>().is_ok()),
            "newmtl" | "map_Ka" | "map_Kd" | "map_Ks" | "map_Bump" | "map_bump" | "map_Ns"
            | "map_ns" | "map_NS" | "bump" | "map_d" => words.next().is_some(),
            _ => true,
        };
        if ok {
            out.push_str(line);
            out.push('\n');
        } else {
            bad.push(ln + 1);
        }
    }
    if let Some(first) = bad.first() {
        warnings.push(format!(
            "{label}: skipped {} malformed line(s), the first at line {first}",
            bad.len()
        ));
    }
    out
}

/// A colour with every channel finite, or `None`.
fn finite3(c: Option<[f32; 3]>) -> Option<[f32; 3]> {
    c.filter(|c| c.iter().all(|v| v.is_finite()))
}

/// A number from tobj's unrecognised statements (`Tr`, `Pr`, `Pm`, ...), if finite.
fn param(m: &tobj::Material, key: &str) -> Option<f32> {
    m.unknown_param
        .get(key)?
        .split_whitespace()
        .next()?
        .parse::<f32>()
        .ok()
        .filter(|v| v.is_finite())
}

/// Maps an MTL material onto the metallic-roughness model (see the module documentation).
fn convert(m: &tobj::Material, texture: Option<TextureRef>) -> MaterialDesc {
    let default = MaterialDesc::default();
    let kd = finite3(m.diffuse).unwrap_or([0.8; 3]);
    let ks = finite3(m.specular).unwrap_or([0.0; 3]);
    let ke = finite3(m.emissive)
        .or_else(|| {
            let v: Vec<f32> = m
                .unknown_param
                .get("Ke")?
                .split_whitespace()
                .filter_map(|w| w.parse().ok())
                .collect();
            finite3(v.get(..3).map(|v| [v[0], v[1], v[2]]))
        })
        .unwrap_or([0.0; 3])
        .map(|c| c.max(0.0));
    let dissolve = m
        .dissolve
        .filter(|d| d.is_finite())
        .or_else(|| param(m, "Tr").map(|tr| 1.0 - tr))
        .unwrap_or(1.0)
        .clamp(0.0, 1.0);
    let ni = m.optical_density.filter(|n| n.is_finite()).unwrap_or(1.0);
    let illum = m.illumination_model.unwrap_or(2);
    let glass = ni > 1.0 && (matches!(illum, 4 | 6 | 7) || dissolve < 1.0);
    let max = |c: [f32; 3]| c[0].max(c[1]).max(c[2]);
    let metal = !glass && (matches!(illum, 3 | 5) || max(ks) > max(kd) && max(ks) > 0.0);
    let metallic = param(m, "Pm").unwrap_or(if metal { 1.0 } else { 0.0 });
    let roughness = param(m, "Pr")
        .or_else(|| {
            let ns = m.shininess.filter(|s| s.is_finite())?;
            Some((2.0 / (ns.max(0.0) + 2.0)).sqrt())
        })
        .unwrap_or(default.roughness);
    // A metal's colour is its specular colour, unless it is textured or Ks is black.
    let rgb = if metal && max(ks) > 0.0 && texture.is_none() {
        ks
    } else {
        kd
    };
    let alpha = if glass { 1.0 } else { dissolve };
    // The MTL illumination models 0 (colour) and 1 (ambient and diffuse) have no specular term.
    let specular = if matches!(illum, 0 | 1) && !glass && !metal {
        0.0
    } else {
        default.specular
    };
    MaterialDesc {
        name: m.name.clone(),
        base_color: [rgb[0], rgb[1], rgb[2], alpha],
        base_color_texture: texture,
        metallic: metallic.clamp(0.0, 1.0),
        roughness: roughness.clamp(0.0, 1.0),
        emissive: ke,
        transmission: if glass { 1.0 } else { 0.0 },
        ior: if glass { ni } else { default.ior },
        specular,
        alpha_mode: if alpha < 1.0 {
            AlphaMode::Blend
        } else {
            AlphaMode::Opaque
        },
        ..default
    }
}
