//! `oxray render`: a path tracer written as oxray programs. This first version renders the
//! built-in Cornell box with diffuse and emissive materials, next-event estimation on the area
//! light through a shadow ray type, and Russian roulette.

use glam::Vec3;
use oxray::{
    BuildOptions, DeviceContext, Gas, GeometryFlags, HitGroupDesc, IndexBuffer, Module,
    OutputBuffer, Pipeline, PipelineCompileOptions, PipelineLinkOptions, ProgramGroup, RayFlags,
    SbtIndexOffsets, SbtRegion, ShaderBindingTable, TraceRay, TraversableHandle, TriangleInput,
    VertexBuffer,
};

/// A diffuse material with emission.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Surface {
    /// Reflectance.
    pub albedo: [f32; 3],
    /// Emitted radiance.
    pub emission: [f32; 3],
}

/// A triangle scene: vertices, triangles, the material of each triangle, and the materials.
pub type Scene = (Vec<[f32; 3]>, Vec<[u32; 3]>, Vec<u8>, Vec<Surface>);

/// The Cornell box (the classic dimensions, scaled to [0, 1]).
pub fn cornell_box() -> Scene {
    let white = Surface {
        albedo: [0.73, 0.73, 0.73],
        emission: [0.0; 3],
    };
    let red = Surface {
        albedo: [0.65, 0.05, 0.05],
        emission: [0.0; 3],
    };
    let green = Surface {
        albedo: [0.12, 0.45, 0.15],
        emission: [0.0; 3],
    };
    let light = Surface {
        albedo: [0.78; 3],
        emission: [17.0, 12.0, 4.0],
    };
    let mut v: Vec<[f32; 3]> = Vec::new();
    let mut t = Vec::new();
    let mut m = Vec::new();
    let mut quad = |p: [[f32; 3]; 4], mat: u8| {
        let b = v.len() as u32;
        v.extend(p.iter().map(|q| [q[0] / 555.0, q[1] / 555.0, q[2] / 555.0]));
        t.extend([[b, b + 1, b + 2], [b, b + 2, b + 3]]);
        m.extend([mat, mat]);
    };
    quad(
        [
            [0.0, 0.0, 0.0],
            [555.0, 0.0, 0.0],
            [555.0, 0.0, 555.0],
            [0.0, 0.0, 555.0],
        ],
        0,
    ); // floor
    quad(
        [
            [0.0, 555.0, 0.0],
            [0.0, 555.0, 555.0],
            [555.0, 555.0, 555.0],
            [555.0, 555.0, 0.0],
        ],
        0,
    ); // ceiling
    quad(
        [
            [0.0, 0.0, 555.0],
            [555.0, 0.0, 555.0],
            [555.0, 555.0, 555.0],
            [0.0, 555.0, 555.0],
        ],
        0,
    ); // back
    quad(
        [
            [555.0, 0.0, 0.0],
            [555.0, 555.0, 0.0],
            [555.0, 555.0, 555.0],
            [555.0, 0.0, 555.0],
        ],
        2,
    ); // left (green)
    quad(
        [
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 555.0],
            [0.0, 555.0, 555.0],
            [0.0, 555.0, 0.0],
        ],
        1,
    ); // right (red)
    quad(
        [
            [213.0, 554.0, 227.0],
            [213.0, 554.0, 332.0],
            [343.0, 554.0, 332.0],
            [343.0, 554.0, 227.0],
        ],
        3,
    ); // light
       // Two boxes, as five quads each (no bottom).
    let mut boxq = |c: [f32; 2], half: f32, h: f32, angle: f32| {
        let (s, co) = angle.to_radians().sin_cos();
        let corner =
            |dx: f32, dz: f32, y: f32| [c[0] + dx * co - dz * s, y, c[1] + dx * s + dz * co];
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
    (v, t, m, vec![white, red, green, light])
}

#[derive(Clone)]
struct Params<'a> {
    image: &'a OutputBuffer<[f32; 4]>,
    handle: TraversableHandle,
    spp: u32,
    max_depth: u32,
    /// The light quad: corner and edges (area light).
    light: [Vec3; 3],
    light_emission: Vec3,
}

/// Radiance payload: throughput-weighted radiance, throughput, next origin and direction, and
/// state (seed, done flag).
#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct PathState {
    radiance: [f32; 3],
    throughput: [f32; 3],
    origin: [f32; 3],
    direction: [f32; 3],
    seed: u32,
    done: u32,
    /// Whether emission seen by this bounce counts (it does not after next-event estimation).
    count_emission: u32,
}

const WORDS: usize = std::mem::size_of::<PathState>() / 4;

fn rnd(seed: &mut u32) -> f32 {
    // PCG-like hash; deterministic per pixel and sample.
    *seed = seed.wrapping_mul(747796405).wrapping_add(2891336453);
    let w = ((*seed >> ((*seed >> 28) + 4)) ^ *seed).wrapping_mul(277803737);
    ((w >> 22) ^ w) as f32 / u32::MAX as f32
}

fn load(words: &[u32]) -> PathState {
    let mut s = PathState::default();
    bytemuck::cast_slice_mut::<PathState, u32>(std::slice::from_mut(&mut s))
        .copy_from_slice(&words[..WORDS]);
    s
}

fn store(s: &PathState, set: &mut impl FnMut(usize, u32)) {
    for (i, &w) in bytemuck::cast_slice::<PathState, u32>(std::slice::from_ref(s))
        .iter()
        .enumerate()
    {
        set(i, w);
    }
}

/// Renders the Cornell box at `width` x `height` with `spp` samples per pixel; returns linear
/// RGB.
pub fn render_cornell(
    width: u32,
    height: u32,
    spp: u32,
    max_depth: u32,
) -> Result<Vec<[f32; 4]>, Box<dyn std::error::Error>> {
    let (v, t, m, surfaces) = cornell_box();
    let offsets: Vec<u8> = m;
    let flags = vec![GeometryFlags::DISABLE_ANYHIT; surfaces.len()];
    let input = TriangleInput::new(VertexBuffer::f32x3(&v))
        .indices(IndexBuffer::u32x3(&t))
        .flags(&flags)
        .sbt_index_offsets(SbtIndexOffsets::u8(&offsets));
    let gas = Gas::build(&BuildOptions::default(), &[input.into()])?;
    let image = OutputBuffer::new((width * height) as usize);
    let l = &v[20..24]; // the light quad's vertices (quad 5)
    let light = [
        Vec3::from(l[0]),
        Vec3::from(l[1]) - Vec3::from(l[0]),
        Vec3::from(l[3]) - Vec3::from(l[0]),
    ];

    let module = Module::<Params>::new()
        .raygen("__raygen__pathtrace", |ctx| {
            let [x, y, _] = ctx.launch_index();
            let [w, h, _] = ctx.launch_dimensions();
            let p = ctx.params();
            let mut sum = Vec3::ZERO;
            for s in 0..p.spp {
                let mut seed = (y * w + x)
                    .wrapping_mul(9781)
                    .wrapping_add(s.wrapping_mul(6271))
                    | 1;
                let jx = rnd(&mut seed);
                let jy = rnd(&mut seed);
                let sx = (2.0 * (x as f32 + jx) / w as f32 - 1.0) * 0.35;
                let sy = (1.0 - 2.0 * (y as f32 + jy) / h as f32) * 0.35 * h as f32 / w as f32;
                let mut state = PathState {
                    throughput: [1.0; 3],
                    origin: [0.5, 0.5, -1.4],
                    direction: Vec3::new(-sx, sy, 1.0).normalize().to_array(),
                    seed,
                    count_emission: 1,
                    ..Default::default()
                };
                for _ in 0..p.max_depth {
                    let mut words = [0u32; WORDS];
                    store(&state, &mut |i, w| words[i] = w);
                    ctx.trace(
                        &TraceRay::new(&p.handle, state.origin.into(), state.direction.into())
                            .interval(1e-4, f32::INFINITY)
                            .sbt(0, 2, 0),
                        &mut words,
                    )?;
                    state = load(&words);
                    if state.done != 0 {
                        break;
                    }
                }
                sum += Vec3::from(state.radiance);
            }
            let c = sum / p.spp as f32;
            p.image.write((y * w + x) as usize, [c.x, c.y, c.z, 1.0]);
            Ok(())
        })?
        .closest_hit("__closesthit__diffuse", |ctx| {
            let mut s = load(ctx.payload_words());
            let surf = ctx.sbt_data::<Surface>().unwrap_or(Surface {
                albedo: [0.0; 3],
                emission: [0.0; 3],
            });
            let [a, b, c] = ctx.triangle_vertex_data();
            let mut n = (b - a).cross(c - a).normalize();
            let dir = ctx.world_ray_direction();
            if n.dot(dir) > 0.0 {
                n = -n;
            }
            let thr = Vec3::from(s.throughput);
            let mut rad = Vec3::from(s.radiance);
            if s.count_emission != 0 {
                rad += thr * Vec3::from(surf.emission);
            }
            let p = ctx.world_ray_origin() + dir * ctx.ray_tmax();
            let albedo = Vec3::from(surf.albedo);
            // Next-event estimation: one sample on the light, through the shadow ray type.
            let params = ctx.params();
            let [lo, le1, le2] = params.light;
            let (u, v) = (rnd(&mut s.seed), rnd(&mut s.seed));
            let lp = lo + le1 * u + le2 * v;
            let to = lp - p;
            let dist2 = to.length_squared();
            let wi = to / dist2.sqrt();
            let ln = le1.cross(le2);
            let area = ln.length();
            let cos_l = (-wi).dot(ln / area).abs();
            let cos_s = n.dot(wi);
            if cos_s > 0.0 && surf.emission == [0.0; 3] {
                let mut visible = [0u32];
                let shadow = TraceRay::new(&params.handle, p, wi)
                    .interval(1e-4, dist2.sqrt() * (1.0 - 1e-3))
                    .flags(RayFlags::TERMINATE_ON_FIRST_HIT | RayFlags::DISABLE_CLOSESTHIT)
                    .sbt(1, 2, 1);
                ctx.trace(&shadow, &mut visible)?;
                if visible[0] != 0 {
                    let pdf_light = dist2 / (cos_l * area).max(1e-8);
                    rad += thr * albedo / std::f32::consts::PI * params.light_emission * cos_s
                        / pdf_light;
                }
            }
            // Cosine-weighted bounce; emission seen by it was already counted by the light sample.
            let (r1, r2) = (rnd(&mut s.seed), rnd(&mut s.seed));
            let (t1, t2) = n.any_orthonormal_pair();
            let phi = std::f32::consts::TAU * r1;
            let new_dir =
                (t1 * phi.cos() * r2.sqrt() + t2 * phi.sin() * r2.sqrt() + n * (1.0 - r2).sqrt())
                    .normalize();
            let mut thr = thr * albedo;
            // Russian roulette.
            let q = thr.max_element().clamp(0.05, 0.95);
            if rnd(&mut s.seed) > q {
                s.done = 1;
            } else {
                thr /= q;
            }
            s.radiance = rad.to_array();
            s.throughput = thr.to_array();
            s.origin = p.to_array();
            s.direction = new_dir.to_array();
            s.count_emission = 0;
            if surf.emission != [0.0; 3] {
                s.done = 1;
            }
            store(&s, &mut |i, w| ctx.set_payload(i, w));
            Ok(())
        })?
        .miss("__miss__black", |ctx| {
            let mut s = load(ctx.payload_words());
            s.done = 1;
            store(&s, &mut |i, w| ctx.set_payload(i, w));
            Ok(())
        })?
        .miss("__miss__shadow", |ctx| {
            ctx.set_payload(0, 1);
            Ok(())
        })?;
    let rg = ProgramGroup::raygen(&module, "__raygen__pathtrace")?;
    let ms = ProgramGroup::miss(Some((&module, "__miss__black")))?;
    let ms_shadow = ProgramGroup::miss(Some((&module, "__miss__shadow")))?;
    let hg = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__diffuse")),
        ..Default::default()
    })?;
    let hg_shadow = ProgramGroup::hit_group(HitGroupDesc::default())?;
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &PipelineCompileOptions {
            num_payload_values: WORDS as u32,
            ..Default::default()
        },
        &PipelineLinkOptions { max_trace_depth: 2 },
        &[
            rg.clone(),
            ms.clone(),
            ms_shadow.clone(),
            hg.clone(),
            hg_shadow.clone(),
        ],
    )?;
    // Two ray types per material: radiance (record 2m) and shadow (record 2m + 1).
    let records: Vec<_> = surfaces
        .iter()
        .flat_map(|s| [(hg.pack_header(), *s), (hg_shadow.pack_header(), *s)])
        .collect();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_headers(&[ms.pack_header(), ms_shadow.pack_header()]),
        hitgroup: SbtRegion::from_records(&records),
        ..Default::default()
    };
    let params = Params {
        image: &image,
        handle: gas.into(),
        spp: spp.max(1),
        max_depth: max_depth.max(1),
        light,
        light_emission: Vec3::from(surfaces[3].emission),
    };
    pipeline.launch(&params, &sbt, width, height, 1)?;
    Ok(image.to_vec())
}

/// Writes linear RGB as a tone-mapped sRGB PNG.
pub fn write_png(
    path: &std::path::Path,
    width: u32,
    height: u32,
    pixels: &[[f32; 4]],
) -> Result<(), Box<dyn std::error::Error>> {
    let srgb = |x: f32| {
        let x = (x / (1.0 + x)).clamp(0.0, 1.0); // Reinhard
        let s = if x <= 0.0031308 {
            12.92 * x
        } else {
            1.055 * x.powf(1.0 / 2.4) - 0.055
        };
        (s * 255.0 + 0.5) as u8
    };
    let bytes: Vec<u8> = pixels
        .iter()
        .flat_map(|p| [srgb(p[0]), srgb(p[1]), srgb(p[2]), 255])
        .collect();
    let file = std::io::BufWriter::new(std::fs::File::create(path)?);
    let mut enc = png::Encoder::new(file, width, height);
    enc.set_color(png::ColorType::Rgba);
    enc.set_depth(png::BitDepth::Eight);
    enc.write_header()?.write_image_data(&bytes)?;
    Ok(())
}
