//! Instancing: one mesh (the Stanford bunny from `../shared/data` when present, else a
//! generated sphere) placed many times by an instance acceleration structure, each instance with
//! its own colour in its own hit-group record, chosen by the instance's SBT offset.
//!
//! `cargo run --release -p oxray --example instancing [out.png]`

mod common;

use glam::{Affine3A, Quat, Vec3};
use oxray::cpu::{Gas, Ias};
use oxray::{
    BuildOptions, DeviceContext, HitGroupDesc, IndexBuffer, Instance, Module, OutputBuffer,
    Pipeline, PipelineCompileOptions, PipelineLinkOptions, ProgramGroup, SbtRegion,
    ShaderBindingTable, TraceRay, Transform, TraversableHandle, TriangleInput, VertexBuffer,
};
use std::sync::Arc;

/// Launch parameters.
#[derive(Clone)]
pub struct Params<'a> {
    pub image: &'a OutputBuffer<[u8; 4]>,
    pub handle: TraversableHandle,
    pub eye: Vec3,
    pub u: Vec3,
    pub v: Vec3,
    pub w: Vec3,
}

/// Grid of instances per side.
pub const GRID: usize = 4;

/// A mesh: the bunny when the shared data is present, else a sphere; scaled to unit size.
pub fn mesh() -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/meshes/stanford-bunny.obj"
    );
    let (mut v, t) = match std::fs::read_to_string(path) {
        Ok(text) => {
            let mut v = Vec::new();
            let mut t = Vec::new();
            for line in text.lines() {
                let mut w = line.split_whitespace();
                match w.next() {
                    Some("v") => {
                        let c: Vec<f32> = w.take(3).filter_map(|x| x.parse().ok()).collect();
                        if let [x, y, z] = c[..] {
                            v.push([x, y, z]);
                        }
                    }
                    Some("f") => {
                        let ids: Vec<u32> = w
                            .filter_map(|x| x.split('/').next()?.parse::<u32>().ok())
                            .map(|i| i - 1)
                            .collect();
                        for k in 1..ids.len().saturating_sub(1) {
                            t.push([ids[0], ids[k], ids[k + 1]]);
                        }
                    }
                    _ => {}
                }
            }
            (v, t)
        }
        Err(_) => sphere(24, 48),
    };
    // Centre and scale to a unit box.
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for p in &v {
        lo = lo.min(Vec3::from(*p));
        hi = hi.max(Vec3::from(*p));
    }
    let (c, s) = ((lo + hi) * 0.5, 1.0 / (hi - lo).max_element());
    for p in &mut v {
        *p = ((Vec3::from(*p) - c) * s).to_array();
    }
    (v, t)
}

fn sphere(rings: u32, segments: u32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let mut v = Vec::new();
    for r in 0..=rings {
        let th = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..segments {
            let ph = std::f32::consts::TAU * s as f32 / segments as f32;
            v.push([th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin()]);
        }
    }
    let mut t = Vec::new();
    for r in 0..rings {
        for s in 0..segments {
            let a = r * segments + s;
            let b = r * segments + (s + 1) % segments;
            t.push([a, a + segments, b]);
            t.push([b, a + segments, b + segments]);
        }
    }
    (v, t)
}

/// Renders the grid of instances; returns the pixels.
pub fn render(width: u32, height: u32) -> Result<Vec<[u8; 4]>, Box<dyn std::error::Error>> {
    let image = OutputBuffer::new((width * height) as usize);
    let (vertices, triangles) = mesh();
    let input =
        TriangleInput::new(VertexBuffer::f32x3(&vertices)).indices(IndexBuffer::u32x3(&triangles));
    let gas = Arc::new(Gas::build(&BuildOptions::default(), &[input.into()])?);
    let mut instances = Vec::new();
    let mut colours = Vec::new();
    for i in 0..GRID * GRID {
        let (gx, gy) = ((i % GRID) as f32, (i / GRID) as f32);
        let offset = (GRID as f32 - 1.0) * 0.5;
        let t = Affine3A::from_scale_rotation_translation(
            Vec3::splat(0.9),
            Quat::from_rotation_y(i as f32 * 0.7),
            Vec3::new((gx - offset) * 1.2, (gy - offset) * 1.2, 0.0),
        );
        instances.push(
            Instance::new(gas.clone().into())
                .transform(Transform::from_affine(&t))
                .instance_id(100 + i as u32)
                .sbt_offset(i as u32),
        );
        let hue = i as f32 / (GRID * GRID) as f32 * std::f32::consts::TAU;
        colours.push([
            0.55 + 0.45 * hue.cos(),
            0.55 + 0.45 * (hue + 2.1).cos(),
            0.55 + 0.45 * (hue + 4.2).cos(),
        ]);
    }
    let ias = Ias::build(&BuildOptions::default(), &[(&instances[..]).into()])?;

    let module = Module::<Params>::new()
        .raygen("__raygen__camera", |ctx| {
            let [x, y, _] = ctx.launch_index();
            let [w, h, _] = ctx.launch_dimensions();
            let p = ctx.params();
            let d = Vec3::new(
                2.0 * (x as f32 + 0.5) / w as f32 - 1.0,
                1.0 - 2.0 * (y as f32 + 0.5) / h as f32,
                1.0,
            );
            let dir = (p.u * d.x + p.v * d.y + p.w * d.z).normalize();
            let mut payload = [0u32; 3];
            ctx.trace(&TraceRay::new(&p.handle, p.eye, dir), &mut payload)?;
            p.image.write(
                (y * w + x) as usize,
                common::rgba8(payload.map(f32::from_bits)),
            );
            Ok(())
        })?
        .closest_hit("__closesthit__shade", |ctx| {
            // Geometric normal from the object-space vertices, to world space.
            let [a, b, c] = ctx.triangle_vertex_data();
            let n = ctx
                .transform_normal_to_world((b - a).cross(c - a))
                .normalize();
            let n = if n.dot(ctx.world_ray_direction()) > 0.0 {
                -n
            } else {
                n
            };
            let light = Vec3::new(-0.4, 0.7, -0.6).normalize();
            let shade = 0.25 + 0.75 * n.dot(light).max(0.0);
            let colour = Vec3::from(ctx.sbt_data::<[f32; 3]>().unwrap_or([1.0; 3])) * shade;
            ctx.set_payload_vec3(0, colour);
            Ok(())
        })?
        .miss("__miss__sky", |ctx| {
            let y = ctx.world_ray_direction().normalize().y;
            ctx.set_payload_vec3(0, Vec3::new(0.15, 0.2, 0.3) * (0.6 + 0.4 * y));
            Ok(())
        })?;
    let raygen = ProgramGroup::raygen(&module, "__raygen__camera")?;
    let miss = ProgramGroup::miss(Some((&module, "__miss__sky")))?;
    let hit = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__shade")),
        ..Default::default()
    })?;
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &PipelineCompileOptions {
            num_payload_values: 3,
            ..Default::default()
        },
        &PipelineLinkOptions { max_trace_depth: 1 },
        &[raygen.clone(), miss.clone(), hit.clone()],
    )?;
    // One hit-group record per instance: record i = instance i's SBT offset (one ray type, one
    // SBT record in the GAS).
    let records: Vec<_> = colours.iter().map(|c| (hit.pack_header(), *c)).collect();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[raygen.pack_header()]),
        miss: SbtRegion::from_headers(&[miss.pack_header()]),
        hitgroup: SbtRegion::from_records(&records),
        ..Default::default()
    };
    let aspect = width as f32 / height as f32;
    let params = Params {
        image: &image,
        handle: ias.into(),
        eye: Vec3::new(0.0, 0.0, -6.0),
        u: Vec3::X * aspect * 0.5,
        v: Vec3::Y * 0.5,
        w: Vec3::Z,
    };
    let report = pipeline.launch(&params, &sbt, width, height, 1)?;
    if report.exceptions > 0 {
        return Err(format!("the launch raised {:?}", report.first_exceptions).into());
    }
    Ok(image.to_vec())
}

#[allow(dead_code)]
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (w, h) = (640, 480);
    let pixels = render(w, h)?;
    let path = common::output_path("instancing");
    common::write_png(&path, w, h, &pixels)?;
    println!("wrote {}", path.display());
    Ok(())
}
