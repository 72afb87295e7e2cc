//! A multi-material scene with radiance and shadow ray types, written with the util layer: the
//! hit-group SBT, the instance SBT offsets and the material sets come from the scene, not from
//! hand-written indices. Two instances of one sphere GAS use two material sets (two colour
//! schemes); the sphere has two materials (upper and lower half) picked per primitive.
//!
//! `cargo run -p oxray-util --example util_scene [out.png]`

use glam::Vec3;
use oxray::{
    DeviceContext, HitGroupDesc, Module, OutputBuffer, PipelineCompileOptions, PipelineLinkOptions,
    ProgramGroup, RayFlags, TraceRay, Transform, TraversableHandle,
};
use oxray_util::{
    GasDesc, Geometry, GeometryInstance, HitGroupData, Material, Scene, ScenePipeline, UtilInstance,
};

/// Launch parameters.
#[derive(Clone)]
pub struct Params<'a> {
    pub image: &'a OutputBuffer<[u8; 4]>,
    pub handle: TraversableHandle,
    /// Colours, indexed by a material's user value.
    pub colours: [[f32; 3]; 5],
}

const RADIANCE: u32 = 0;
const SHADOW: u32 = 1;
const RAY_TYPES: u32 = 2;

fn sphere(rings: u32, segments: u32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>, Vec<u32>) {
    let mut v = Vec::new();
    for r in 0..=rings {
        let th = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..segments {
            let ph = std::f32::consts::TAU * s as f32 / segments as f32;
            v.push([th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin()]);
        }
    }
    let (mut t, mut m) = (Vec::new(), Vec::new());
    for r in 0..rings {
        for s in 0..segments {
            let a = r * segments + s;
            let b = r * segments + (s + 1) % segments;
            t.push([a, b, a + segments]);
            t.push([b, b + segments, a + segments]);
            // Material 0 on the upper half, 1 on the lower half.
            let lower = (r >= rings / 2) as u32;
            m.extend([lower, lower]);
        }
    }
    (v, t, m)
}

/// Renders the scene; returns the pixels.
pub fn render(width: u32, height: u32) -> Result<Vec<[u8; 4]>, Box<dyn std::error::Error>> {
    let image = OutputBuffer::new((width * height) as usize);
    let module = Module::<Params>::new()
        .raygen("__raygen__camera", |ctx| {
            let [x, y, _] = ctx.launch_index();
            let [w, h, _] = ctx.launch_dimensions();
            let p = ctx.params();
            let d = Vec3::new(
                (2.0 * (x as f32 + 0.5) / w as f32 - 1.0) * w as f32 / h as f32,
                1.0 - 2.0 * (y as f32 + 0.5) / h as f32,
                2.0,
            )
            .normalize();
            let mut colour = [0u32; 3];
            let ray = TraceRay::new(&p.handle, Vec3::new(0.0, 1.0, -6.0), d)
                .sbt(RADIANCE, RAY_TYPES, RADIANCE);
            ctx.trace(&ray, &mut colour)?;
            let c = colour.map(|w| (f32::from_bits(w).clamp(0.0, 1.0) * 255.0 + 0.5) as u8);
            p.image.write((y * w + x) as usize, [c[0], c[1], c[2], 255]);
            Ok(())
        })?
        .closest_hit("__closesthit__radiance", |ctx| {
            let data = ctx.sbt_data::<HitGroupData>().unwrap_or_default();
            let base = Vec3::from(ctx.params().colours[data.material as usize % 5]);
            let [a, b, c] = ctx.triangle_vertex_data();
            let mut n = ctx
                .transform_normal_to_world((b - a).cross(c - a))
                .normalize();
            if n.dot(ctx.world_ray_direction()) > 0.0 {
                n = -n;
            }
            let hit = ctx.world_ray_origin() + ctx.world_ray_direction() * ctx.ray_tmax();
            let light = Vec3::new(-0.5, 1.0, -0.4).normalize();
            // Shadow ray: the shadow miss program sets the word to 1 when nothing is in the way.
            let mut visible = [0u32];
            let shadow = TraceRay::new(&ctx.params().handle, hit + n * 1e-3, light)
                .flags(RayFlags::TERMINATE_ON_FIRST_HIT | RayFlags::DISABLE_CLOSESTHIT)
                .sbt(SHADOW, RAY_TYPES, SHADOW);
            ctx.trace(&shadow, &mut visible)?;
            let lit = 0.2 + 0.8 * n.dot(light).max(0.0) * visible[0] as f32;
            ctx.set_payload_vec3(0, base * lit);
            Ok(())
        })?
        .miss("__miss__sky", |ctx| {
            let y = ctx.world_ray_direction().normalize().y;
            ctx.set_payload_vec3(0, Vec3::new(0.5, 0.65, 0.9) * (0.7 + 0.3 * y));
            Ok(())
        })?
        .miss("__miss__shadow", |ctx| {
            ctx.set_payload(0, 1);
            Ok(())
        })?;
    let radiance = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__radiance")),
        ..Default::default()
    })?;
    // Shadow rays need no programs: the hit itself (terminate on first hit) is the answer.
    let shadow = ProgramGroup::hit_group(HitGroupDesc::default())?;

    let mut scene = Scene::new();
    // Materials: the user value picks a colour (ground, red, blue, yellow, green).
    let mats: Vec<_> = (0..5)
        .map(|colour| {
            scene.add_material(Material::new(
                vec![Some(radiance.clone()), Some(shadow.clone())],
                colour,
            ))
        })
        .collect();
    let (ground_mat, red, blue, yellow, green) = (mats[0], mats[1], mats[2], mats[3], mats[4]);
    let ground = Geometry::Triangles {
        vertices: vec![
            [-20.0, -1.0, -20.0],
            [20.0, -1.0, -20.0],
            [20.0, -1.0, 20.0],
            [-20.0, -1.0, 20.0],
        ],
        indices: vec![[0, 2, 1], [0, 3, 2]],
    };
    let ground = scene.add_geometry(GeometryInstance::new(ground, 1).material(0, 0, ground_mat));
    let (v, t, m) = sphere(24, 48);
    let ball = GeometryInstance::new(
        Geometry::Triangles {
            vertices: v,
            indices: t,
        },
        2,
    )
    .material_indices(m)
    // Set 0: red over blue; set 1: yellow over green.
    .material(0, 0, red)
    .material(0, 1, blue)
    .material(1, 0, yellow)
    .material(1, 1, green);
    let ball = scene.add_geometry(ball);
    let ground_gas = scene.add_gas(GasDesc::new(vec![ground], vec![RAY_TYPES]));
    let ball_gas = scene.add_gas(GasDesc::new(vec![ball], vec![RAY_TYPES, RAY_TYPES]));
    let mut left = UtilInstance::new(ball_gas, 0);
    left.transform = Transform::from_translation(Vec3::new(-1.3, 0.0, 0.0));
    let mut right = UtilInstance::new(ball_gas, 1);
    right.transform = Transform::from_translation(Vec3::new(1.3, 0.0, 0.0));
    let ias = scene.add_ias(
        vec![UtilInstance::new(ground_gas, 0), left, right],
        Default::default(),
    );
    scene.rebuild_dirty()?;
    let handle = scene.ias_handle(ias).ok_or("IAS not built")?;

    let raygen = ProgramGroup::raygen(&module, "__raygen__camera")?;
    let misses = vec![
        ProgramGroup::miss(Some((&module, "__miss__sky")))?,
        ProgramGroup::miss(Some((&module, "__miss__shadow")))?,
    ];
    let pipeline = ScenePipeline::new(
        &DeviceContext::new(),
        PipelineCompileOptions {
            num_payload_values: 3,
            ..Default::default()
        },
        PipelineLinkOptions { max_trace_depth: 2 },
        raygen,
        misses,
    );
    let params = Params {
        image: &image,
        handle,
        colours: [
            [0.8, 0.8, 0.75],
            [0.9, 0.2, 0.15],
            [0.15, 0.3, 0.9],
            [0.95, 0.85, 0.2],
            [0.2, 0.8, 0.3],
        ],
    };
    let report = pipeline.launch(&mut scene, &params, width, height, 1)?;
    if report.exceptions > 0 {
        return Err(format!("the launch raised {:?}", report.first_exceptions).into());
    }
    Ok(image.to_vec())
}

#[allow(dead_code)]
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (w, h) = (640, 400);
    let pixels = render(w, h)?;
    let path = std::env::args()
        .nth(1)
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| {
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../target/examples/util_scene.ppm")
        });
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    // A binary PPM keeps this crate free of image dependencies.
    let mut out = format!("P6\n{w} {h}\n255\n").into_bytes();
    for p in &pixels {
        out.extend_from_slice(&p[..3]);
    }
    std::fs::write(&path, out)?;
    println!("wrote {}", path.display());
    Ok(())
}
