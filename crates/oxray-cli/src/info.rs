//! `oxray info` on scene files: what the renderer would build (one GAS per mesh, one IAS over
//! the placements) and its statistics.

use oxray::cpu::{Gas, Ias};
use oxray::{BuildFlags, BuildOptions, IndexBuffer, Instance, TriangleInput, VertexBuffer};
use oxray_scene::{AlphaMode, SceneDesc};
use std::fmt::Write;
use std::path::Path;
use std::time::Instant;

/// A report on the scene in `path`: counts (meshes, primitives, triangles unique and
/// instanced, instances, materials, textures, cameras), world bounds, and BVH statistics of the
/// GASes (summed) and of the IAS.
pub fn scene_info(path: &Path) -> Result<String, Box<dyn std::error::Error>> {
    let scene = SceneDesc::load(path)?;
    let t = Instant::now();
    // Built for compaction, so that the memory as built and compacted (guide §5.8) is shown.
    let opts = BuildOptions::new(BuildFlags::PREFER_FAST_TRACE | BuildFlags::ALLOW_COMPACTION);
    let mut gases: Vec<Option<Gas>> = Vec::with_capacity(scene.meshes.len());
    for mesh in &scene.meshes {
        let inputs: Vec<_> = mesh
            .primitives
            .iter()
            .filter(|p| !p.triangles.is_empty())
            .map(|p| {
                TriangleInput::new(VertexBuffer::f32x3(&p.positions))
                    .indices(IndexBuffer::u32x3(&p.triangles))
                    .into()
            })
            .collect();
        gases.push(if inputs.is_empty() {
            None
        } else {
            Some(Gas::build(&opts, &inputs)?)
        });
    }
    // Bytes as built (with the builder's slack), then compacted.
    let built_bytes: usize = gases
        .iter()
        .flatten()
        .map(|g| g.memory().output_bytes)
        .sum();
    let gases: Vec<Option<Gas>> = gases
        .into_iter()
        .map(|g| g.map(|g| g.data().compact().map(Gas::from)).transpose())
        .collect::<Result<_, _>>()?;
    let instances: Vec<Instance> = scene
        .instances
        .iter()
        .filter_map(|i| {
            let gas = gases.get(i.mesh as usize)?.as_ref()?;
            Some(Instance::new(gas.clone().into()).transform(i.placement()?))
        })
        .collect();
    let ias = if instances.is_empty() {
        None
    } else {
        Some(Ias::build(
            &BuildOptions::default(),
            &[(&instances[..]).into()],
        )?)
    };
    let build_ms = t.elapsed().as_secs_f64() * 1e3;

    let unique: usize = scene
        .meshes
        .iter()
        .flat_map(|m| &m.primitives)
        .map(|p| p.triangles.len())
        .sum();
    let (mut nodes, mut leaves, mut depth, mut bytes) = (0, 0, 0, 0);
    for g in gases.iter().flatten() {
        let s = g.stats();
        nodes += s.nodes;
        leaves += s.leaves;
        depth = depth.max(s.max_depth);
        bytes += g.memory().output_bytes;
    }
    let mut out = String::new();
    writeln!(out, "file: {}", path.display())?;
    writeln!(
        out,
        "meshes: {} ({} primitives)",
        scene.meshes.len(),
        scene
            .meshes
            .iter()
            .map(|m| m.primitives.len())
            .sum::<usize>()
    )?;
    writeln!(
        out,
        "triangles: {unique} unique, {} instanced",
        scene.triangle_count()
    )?;
    writeln!(out, "instances: {}", scene.instances.len())?;
    let alpha = scene
        .materials
        .iter()
        .filter(|m| m.alpha_mode != AlphaMode::Opaque)
        .count();
    let emissive = scene
        .materials
        .iter()
        .filter(|m| m.emissive.iter().any(|&e| e > 0.0))
        .count();
    writeln!(
        out,
        "materials: {} ({alpha} alpha-tested, {emissive} emissive)",
        scene.materials.len()
    )?;
    writeln!(out, "textures: {}", scene.textures.len())?;
    writeln!(out, "cameras: {}", scene.cameras.len())?;
    writeln!(out, "punctual lights: {}", scene.lights.len())?;
    if let Some((lo, hi)) = scene.bounds() {
        writeln!(
            out,
            "bounds: [{:.4}, {:.4}, {:.4}] .. [{:.4}, {:.4}, {:.4}]",
            lo.x, lo.y, lo.z, hi.x, hi.y, hi.z
        )?;
    }
    writeln!(
        out,
        "GAS BVHs: {} GASes, {nodes} nodes (4-wide), {leaves} leaves, max depth {depth}, {bytes} bytes",
        gases.iter().flatten().count()
    )?;
    let per = |b: usize| b as f64 / unique.max(1) as f64;
    writeln!(
        out,
        "GAS memory: {built_bytes} bytes as built ({:.1} B/triangle), {bytes} bytes compacted ({:.1} B/triangle)",
        per(built_bytes),
        per(bytes)
    )?;
    if let Some(ias) = &ias {
        let s = ias.stats();
        writeln!(
            out,
            "IAS BVH: {} nodes, {} leaves, depth {}, SAH cost {:.2}",
            s.nodes, s.leaves, s.max_depth, s.sah_cost
        )?;
    }
    for w in &scene.warnings {
        writeln!(out, "warning: {w}")?;
    }
    write!(out, "build: {build_ms:.1} ms")?;
    Ok(out)
}
