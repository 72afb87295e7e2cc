//! Benchmarks: BVH build time and ray throughput for coherent (pinhole camera) and incoherent
//! (random hemisphere from surface points) rays, closest hit and any hit.

use glam::Vec3;
use oxray::cpu::Gas;
use oxray::{BuildFlags, BuildOptions, IndexBuffer, Ray, RayRecord, TriangleInput, VertexBuffer};
use oxray_scene::mesh::Mesh;
use oxray_testkit::rays;
use oxray_testkit::rng::Rng;
use rayon::prelude::*;
use std::time::Instant;

/// The build input of a mesh.
fn mesh_input(mesh: &Mesh) -> oxray::BuildInput<'_> {
    TriangleInput::new(VertexBuffer::f32x3(&mesh.positions))
        .indices(IndexBuffer::u32x3(&mesh.triangles))
        .into()
}

/// Builds a GAS over a mesh on the CPU, for the CPU benchmark's per-ray and instanced queries.
pub fn build_gas(mesh: &Mesh, flags: BuildFlags) -> Result<Gas, oxray::BuildError> {
    Gas::build(&BuildOptions::new(flags), &[mesh_input(mesh)])
}

/// Builds a GAS over a mesh on `device`.
pub fn build_gas_on(
    device: &oxray::Device,
    mesh: &Mesh,
    flags: BuildFlags,
) -> Result<oxray::Gas, oxray::BuildError> {
    device.build_gas(&BuildOptions::new(flags), &[mesh_input(mesh)])
}

fn center_radius(mesh: &Mesh) -> (Vec3, f32) {
    rays::center_radius(&mesh.positions)
}

/// Primary rays of a `width` x `height` pinhole camera that frames the mesh, in scanline order
/// (the benchmark's generators live in `oxray-testkit`, shared with the tests and the GPU
/// checks, and stay bit-identical so that results compare across versions).
pub fn camera_rays(mesh: &Mesh, width: u32, height: u32) -> Vec<Ray> {
    rays::camera_rays(&mesh.positions, width, height)
}

/// `n` diffuse (cosine hemisphere) rays from random surface points; none without area.
pub fn hemisphere_rays(mesh: &Mesh, n: usize, seed: u64) -> Vec<Ray> {
    rays::hemisphere_rays(&mesh.positions, &mesh.triangles, n, seed)
}

/// `n` shadow rays from random surface points to a point light; none without area.
pub fn shadow_rays(mesh: &Mesh, n: usize, seed: u64) -> Vec<Ray> {
    rays::shadow_rays(&mesh.positions, &mesh.triangles, n, seed)
}

/// The median of some timings (0 for none).
pub fn median(mut xs: Vec<f64>) -> f64 {
    xs.sort_by(f64::total_cmp);
    let n = xs.len();
    if n == 0 {
        0.0
    } else if n % 2 == 1 {
        xs[n / 2]
    } else {
        0.5 * (xs[n / 2 - 1] + xs[n / 2])
    }
}

/// Results of one mesh's benchmark.
#[derive(Clone, Debug, Default)]
pub struct BenchResult {
    /// Mesh name.
    pub name: String,
    /// Triangles.
    pub triangles: usize,
    /// Median build time (ms) of each of the [`PRESETS`].
    pub build_ms: [f64; 4],
    /// SAH cost of each preset's build.
    pub sah: [f64; 4],
    /// Leaf references per triangle of each preset's build (above 1 with spatial splits).
    pub refs_per_tri: [f64; 4],
    /// Mrays/s (median) for primary closest, primary any, diffuse closest, diffuse any and
    /// shadow (any hit, bounded by the light's distance).
    pub mrays: [f64; 5],
    /// Mrays/s of incoherent closest hit on each preset's build.
    pub mrays_by_flags: [f64; 4],
    /// Fraction of primary, diffuse and shadow rays that hit (are blocked, for shadow rays).
    pub hit_rate: [f64; 3],
    /// Mrays/s of the coherent rays traced through the programmable pipeline (trivial
    /// closest-hit and miss programs), as single-ray queries (`Gas::intersect` ray by ray in
    /// parallel: the kernel a launch's traces run), and as a batched query (packets).
    pub pipeline_mrays: (f64, f64, f64),
}

/// The build presets the benchmark compares, in its columns' order, by the names `--build`
/// takes: the build flags, and whether the build may use spatial splits where the flags choose
/// them (`fast-trace-binned` is `PREFER_FAST_TRACE` without them, the binned SAH build that
/// preset was before, for comparison).
pub const PRESETS: [(&str, BuildFlags, bool); 4] = [
    ("default", BuildFlags::empty(), true),
    ("fast-build", BuildFlags::PREFER_FAST_BUILD, true),
    ("fast-trace", BuildFlags::PREFER_FAST_TRACE, true),
    ("fast-trace-binned", BuildFlags::PREFER_FAST_TRACE, false),
];

/// Builds a GAS over a mesh on the CPU with preset `k` of [`PRESETS`].
pub fn build_preset(mesh: &Mesh, k: usize) -> Result<Gas, oxray::BuildError> {
    let (_, flags, splits) = PRESETS[k];
    if splits {
        return build_gas(mesh, flags);
    }
    let isa = oxray::cpu::Isa::selected();
    let data = oxray::bvh::GasData::build_with_spatial_splits(
        &BuildOptions::new(flags),
        &[mesh_input(mesh)],
        isa.width(),
        None,
    )?;
    Ok(Gas::from_data_with_isa(data, isa))
}

/// The index in [`PRESETS`] of a preset's name.
pub fn preset_index(name: &str) -> Result<usize, String> {
    PRESETS
        .iter()
        .position(|(n, ..)| *n == name)
        .ok_or_else(|| {
            let names: Vec<&str> = PRESETS.iter().map(|(n, ..)| *n).collect();
            format!("unknown build preset {name:?}; one of {}", names.join(", "))
        })
}

/// Runs the benchmark on a mesh with `runs` repetitions of each measurement; the ray columns
/// trace the build of preset `traced` (an index in [`PRESETS`]).
pub fn run(
    name: &str,
    mesh: &Mesh,
    runs: usize,
    rays: &BenchRays,
    traced: usize,
) -> Result<BenchResult, Box<dyn std::error::Error>> {
    let mut res = BenchResult {
        name: name.to_string(),
        triangles: mesh.triangles.len(),
        ..Default::default()
    };
    let mut gases = Vec::new();
    for k in 0..PRESETS.len() {
        let mut times = Vec::new();
        let mut gas = None;
        for _ in 0..runs {
            let t = Instant::now();
            let g = build_preset(mesh, k)?;
            times.push(t.elapsed().as_secs_f64() * 1e3);
            gas = Some(g);
        }
        let gas = gas.expect("runs >= 1");
        res.build_ms[k] = median(times);
        res.sah[k] = gas.stats().sah_cost;
        res.refs_per_tri[k] =
            gas.data().num_references() as f64 / gas.data().num_active_primitives().max(1) as f64;
        gases.push(gas);
    }
    let gas = gases.get(traced).ok_or("no such build preset")?;
    let longest = rays
        .coherent
        .len()
        .max(rays.incoherent.len())
        .max(rays.shadow.len());
    let mut hits = vec![None; longest];
    let mut occ = vec![false; hits.len()];
    let time = |f: &mut dyn FnMut()| {
        f(); // warm-up
        median(
            (0..runs)
                .map(|_| {
                    let t = Instant::now();
                    f();
                    t.elapsed().as_secs_f64()
                })
                .collect(),
        )
    };
    for (k, set) in [&rays.coherent, &rays.incoherent].into_iter().enumerate() {
        let n = set.len();
        let h = &mut hits[..n];
        let s = time(&mut || gas.intersect_batch(set, h).expect("lengths match"));
        res.mrays[2 * k] = n as f64 / s / 1e6;
        res.hit_rate[k] = h.iter().filter(|x| x.is_some()).count() as f64 / n.max(1) as f64;
        let o = &mut occ[..n];
        let s = time(&mut || gas.occluded_batch(set, o).expect("lengths match"));
        res.mrays[2 * k + 1] = n as f64 / s / 1e6;
    }
    let n = rays.shadow.len();
    let o = &mut occ[..n];
    let s = time(&mut || gas.occluded_batch(&rays.shadow, o).expect("lengths match"));
    res.mrays[4] = n as f64 / s / 1e6;
    res.hit_rate[2] = o.iter().filter(|&&x| x).count() as f64 / n.max(1) as f64;
    let shared = std::sync::Arc::new(gas.clone());
    res.pipeline_mrays = pipeline_mrays(&shared, &rays.coherent, runs)?;
    for (k, g) in gases.iter().enumerate() {
        let n = rays.incoherent.len();
        let h = &mut hits[..n];
        let s = time(&mut || {
            g.intersect_batch(&rays.incoherent, h)
                .expect("lengths match")
        });
        res.mrays_by_flags[k] = n as f64 / s / 1e6;
    }
    Ok(res)
}

/// What the life of a structure costs on a device (guide §5.6–§5.8): an updatable build, its
/// refit against a rebuild, its memory before and after compaction, saving and loading.
#[derive(Clone, Debug, Default)]
pub struct LifeResult {
    /// Median ms of a build with `ALLOW_UPDATE | ALLOW_COMPACTION`.
    pub updatable_build_ms: f64,
    /// Median ms of an update (refit) of that structure with moved vertices.
    pub refit_ms: f64,
    /// Median ms of a build with no flags (on a GPU: the device's builder).
    pub rebuild_ms: f64,
    /// Bytes of the updatable structure as built.
    pub built_bytes: usize,
    /// Its emitted compacted size.
    pub compacted_bytes: u64,
    /// Median ms of saving it to bytes, and of loading them back with every check.
    pub save_ms: f64,
    /// See `save_ms`.
    pub load_ms: f64,
}

/// Measures [`LifeResult`] for a mesh on `device`, `runs` times each.
pub fn life(
    device: &oxray::Device,
    mesh: &Mesh,
    runs: usize,
) -> Result<LifeResult, Box<dyn std::error::Error>> {
    let flags = BuildFlags::ALLOW_UPDATE | BuildFlags::ALLOW_COMPACTION;
    let timed = |f: &mut dyn FnMut() -> Result<(), Box<dyn std::error::Error>>| {
        let mut ts = Vec::with_capacity(runs);
        for _ in 0..runs {
            let t = Instant::now();
            f()?;
            ts.push(t.elapsed().as_secs_f64() * 1e3);
        }
        Ok::<f64, Box<dyn std::error::Error>>(median(ts))
    };
    let updatable_build_ms = timed(&mut || {
        build_gas_on(device, mesh, flags)?;
        Ok(())
    })?;
    let rebuild_ms = timed(&mut || {
        build_gas_on(device, mesh, BuildFlags::empty())?;
        Ok(())
    })?;
    let mut gas = build_gas_on(device, mesh, flags)?;
    let built_bytes = gas.memory().output_bytes;
    let compacted_bytes = match gas.emit_property(oxray::AccelProperty::CompactedSize)? {
        oxray::EmittedProperty::CompactedSize(s) => s,
        _ => 0,
    };
    // Two poses, a small wave apart, alternated so that every update moves the vertices.
    let (c, r) = center_radius(mesh);
    let wave: Vec<[f32; 3]> = mesh
        .positions
        .iter()
        .map(|&p| {
            let p = Vec3::from(p);
            (p + Vec3::new(((p - c).y * 9.0 / r).sin(), 0.0, 0.0) * (0.01 * r)).to_array()
        })
        .collect();
    let poses = [&wave, &mesh.positions];
    let update = BuildOptions {
        operation: oxray::BuildOperation::Update,
        ..BuildOptions::new(flags)
    };
    let mut k = 0;
    let refit_ms = timed(&mut || {
        k += 1;
        let input = oxray::TriangleInput::new(oxray::VertexBuffer::f32x3(poses[k % 2]))
            .indices(oxray::IndexBuffer::u32x3(&mesh.triangles));
        device.update_gas(&mut gas, &update, &[input.into()])?;
        Ok(())
    })?;
    let mut bytes = Vec::new();
    let save_ms = timed(&mut || {
        bytes = gas.to_bytes()?;
        Ok(())
    })?;
    let load_ms = timed(&mut || {
        device.load_gas(&bytes)?;
        Ok(())
    })?;
    Ok(LifeResult {
        updatable_build_ms,
        refit_ms,
        rebuild_ms,
        built_bytes,
        compacted_bytes,
        save_ms,
        load_ms,
    })
}

/// The ray sets of a benchmark: primary (camera), diffuse and shadow rays.
pub use oxray_testkit::rays::BenchRays;

/// The benchmark's rays for a mesh: a `side` x `side` camera and as many diffuse and shadow
/// rays.
pub fn bench_rays(mesh: &Mesh, side: u32) -> BenchRays {
    BenchRays::new(&mesh.positions, &mesh.triangles, side)
}

/// Writes a mesh and its rays for the side-by-side scripts (`scripts/bench_embree.py`,
/// `scripts/embree3_bench.c`): `NAME.mesh` (u32 vertex count, u32 triangle count, f32x3
/// vertices, u32x3 triangles), `NAME.coherent.rays`, `NAME.incoherent.rays` and
/// `NAME.shadow.rays` (`f32[8]` per ray), all little endian. Each file is written atomically.
pub fn export(
    dir: &std::path::Path,
    name: &str,
    mesh: &Mesh,
    rays: &BenchRays,
) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let mut m = Vec::new();
    m.extend((mesh.positions.len() as u32).to_le_bytes());
    m.extend((mesh.triangles.len() as u32).to_le_bytes());
    m.extend_from_slice(bytemuck::cast_slice(&mesh.positions));
    m.extend_from_slice(bytemuck::cast_slice(&mesh.triangles));
    write_bytes_atomic(&dir.join(format!("{name}.mesh")), &m)?;
    for (set, rays) in export_sets(rays) {
        write_bytes_atomic(
            &dir.join(format!("{name}.{set}.rays")),
            &ray_file_bytes(rays),
        )?;
    }
    Ok(())
}

/// The exported ray sets by file name.
fn export_sets(rays: &BenchRays) -> [(&'static str, &[Ray]); 3] {
    [
        ("coherent", &rays.coherent),
        ("incoherent", &rays.incoherent),
        ("shadow", &rays.shadow),
    ]
}

/// Rays in the ray-file format: one 32-byte [`RayRecord`] per ray (the time is not stored).
pub fn ray_file_bytes(rays: &[Ray]) -> Vec<u8> {
    let records: Vec<RayRecord> = rays.iter().map(|&r| RayRecord::from(r)).collect();
    bytemuck::cast_slice(&records).to_vec()
}

/// Writes oxray's answers for the exported rays, so that the side-by-side scripts can check
/// that the engines agree: for the coherent and incoherent sets, the closest hit's distance
/// (`NAME.SET.oxray-hits`: one f32 per ray, +inf for a miss) and primitive index
/// (`NAME.SET.oxray-prims`: one u32 per ray, `u32::MAX` for a miss); for every set, whether
/// the ray is blocked (`NAME.SET.oxray-occluded`: one byte per ray, 0 or 1).
pub fn export_hits(
    dir: &std::path::Path,
    name: &str,
    gas: &Gas,
    rays: &BenchRays,
) -> std::io::Result<()> {
    for (set, rays) in export_sets(rays) {
        if set != "shadow" {
            let mut hits = vec![None; rays.len()];
            gas.intersect_batch(rays, &mut hits).expect("lengths match");
            let t: Vec<f32> = hits
                .iter()
                .map(|h| h.map_or(f32::INFINITY, |h| h.t))
                .collect();
            let prims: Vec<u32> = hits
                .iter()
                .map(|h| h.map_or(u32::MAX, |h| h.primitive_index))
                .collect();
            write_bytes_atomic(
                &dir.join(format!("{name}.{set}.oxray-hits")),
                bytemuck::cast_slice(&t),
            )?;
            write_bytes_atomic(
                &dir.join(format!("{name}.{set}.oxray-prims")),
                bytemuck::cast_slice(&prims),
            )?;
        }
        let mut blocked = vec![false; rays.len()];
        gas.occluded_batch(rays, &mut blocked)
            .expect("lengths match");
        let bytes: Vec<u8> = blocked.iter().map(|&b| b as u8).collect();
        write_bytes_atomic(&dir.join(format!("{name}.{set}.oxray-occluded")), &bytes)?;
    }
    Ok(())
}

use oxray_scene::files::write_bytes_atomic;

/// Launch parameters of the pipeline benchmark.
#[derive(Clone)]
struct PipelineParams<'a> {
    rays: &'a [Ray],
    handle: oxray::TraversableHandle,
    out: &'a oxray::OutputBuffer<f32>,
}

/// Mrays/s of a launch that traces `rays` (one per launch index) through the programmable
/// pipeline, with a closest-hit program that returns t and a miss program that returns +inf,
/// of the same rays as single-ray queries (the pipeline's overhead over its own kernel) and of
/// [`Gas::intersect_batch`] (which traces camera rays as packets), timed alternately.
pub fn pipeline_mrays(
    gas: &std::sync::Arc<Gas>,
    rays: &[Ray],
    runs: usize,
) -> Result<(f64, f64, f64), Box<dyn std::error::Error>> {
    use oxray::{
        DeviceContext, HitGroupDesc, Module, OutputBuffer, Pipeline, PipelineCompileOptions,
        PipelineLinkOptions, ProgramGroup, SbtRegion, ShaderBindingTable, TraceRay,
    };
    let out = OutputBuffer::<f32>::new(rays.len());
    let module = Module::<PipelineParams>::new()
        .raygen("__raygen__bench", |ctx| {
            let [x, _, _] = ctx.launch_index();
            let p = ctx.params();
            let r = &p.rays[x as usize];
            let mut payload = [0u32; 1];
            ctx.trace(
                &TraceRay::new(&p.handle, r.origin, r.direction).interval(r.tmin, r.tmax),
                &mut payload,
            )?;
            p.out.write(x as usize, f32::from_bits(payload[0]));
            Ok(())
        })?
        .closest_hit("__closesthit__t", |ctx| {
            let t = ctx.ray_tmax();
            ctx.set_payload_f32(0, t);
            Ok(())
        })?
        .miss("__miss__inf", |ctx| {
            ctx.set_payload_f32(0, f32::INFINITY);
            Ok(())
        })?;
    let rg = ProgramGroup::raygen(&module, "__raygen__bench")?;
    let ms = ProgramGroup::miss(Some((&module, "__miss__inf")))?;
    let hg = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__t")),
        ..Default::default()
    })?;
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &PipelineCompileOptions {
            num_payload_values: 1,
            ..Default::default()
        },
        &PipelineLinkOptions { max_trace_depth: 1 },
        &[rg.clone(), ms.clone(), hg.clone()],
    )?;
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_headers(&[ms.pack_header()]),
        hitgroup: SbtRegion::from_headers(&[hg.pack_header()]),
        ..Default::default()
    };
    let params = PipelineParams {
        rays,
        handle: gas.clone().into(),
        out: &out,
    };
    let launch = || {
        pipeline
            .launch(&params, &sbt, rays.len() as u32, 1, 1)
            .map(|_| ())
    };
    launch()?;
    // Launches and raw batched queries of the same rays alternate, so that both see the same
    // machine conditions.
    let mut hits = vec![None; rays.len()];
    let (mut piped, mut single, mut batched) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..runs {
        let t = Instant::now();
        launch()?;
        piped.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        rays.par_iter()
            .zip(hits.par_iter_mut())
            .with_min_len(256)
            .for_each(|(r, h)| *h = gas.intersect(r));
        single.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        gas.intersect_batch(rays, &mut hits)?;
        batched.push(t.elapsed().as_secs_f64());
    }
    let n = rays.len() as f64;
    let rate = |times| n / median(times) / 1e6;
    Ok((rate(piped), rate(single), rate(batched)))
}

/// Results of the instancing benchmark.
#[derive(Clone, Debug, Default)]
pub struct InstanceBenchResult {
    /// Instances.
    pub instances: usize,
    /// Triangles of the instanced mesh.
    pub mesh_triangles: usize,
    /// Median IAS build time (ms).
    pub build_ms: f64,
    /// Mrays/s of camera rays (closest hit).
    pub coherent_mrays: f64,
    /// Mrays/s of random rays through the scene (closest hit).
    pub incoherent_mrays: f64,
    /// Fraction of camera rays that hit.
    pub hit_rate: f64,
}

/// Builds an IAS of `n` randomly rotated and scaled copies of `mesh` on a cubic grid and traces
/// `side * side` camera rays and as many random rays through it.
pub fn instances(
    device: &oxray::Device,
    mesh: &Mesh,
    n: usize,
    side: u32,
    runs: usize,
) -> Result<InstanceBenchResult, Box<dyn std::error::Error>> {
    use glam::{Affine3A, Quat};
    use oxray::{Instance, Transform};
    let gas = build_gas_on(device, mesh, BuildFlags::empty())?;
    let (c, r) = center_radius(mesh);
    let per_side = (n as f64).cbrt().ceil() as usize;
    let spacing = 2.5 * r;
    let mut rng = Rng::new(11);
    let instances: Vec<Instance> = (0..n)
        .map(|i| {
            let g = Vec3::new(
                (i % per_side) as f32,
                ((i / per_side) % per_side) as f32,
                (i / (per_side * per_side)) as f32,
            );
            let q = Quat::from_euler(
                glam::EulerRot::XYZ,
                rng.f32() * 6.3,
                rng.f32() * 6.3,
                rng.f32() * 6.3,
            );
            let s = 0.6 + 0.6 * rng.f32();
            let t = Affine3A::from_scale_rotation_translation(Vec3::splat(s), q, g * spacing)
                * Affine3A::from_translation(-c);
            Instance::new(gas.handle())
                .transform(Transform::from_affine(&t))
                .instance_id(i as u32)
        })
        .collect();
    let mut times = Vec::new();
    let mut ias = None;
    for _ in 0..runs {
        let t = Instant::now();
        ias = Some(device.build_ias(&oxray::BuildOptions::default(), &[(&instances[..]).into()])?);
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let ias = ias.expect("runs >= 1");
    let bounds = ias.bounds();
    let (bc, br) = (bounds.center(), bounds.extent().length() * 0.5);
    // Camera rays from outside the grid's corner towards its centre.
    let eye = bc + Vec3::new(0.6, 0.45, -1.0).normalize() * (1.8 * br);
    let fwd = (bc - eye).normalize();
    let right = fwd.cross(Vec3::Y).normalize();
    let up = right.cross(fwd);
    let tan = (40f32.to_radians() * 0.5).tan();
    let camera: Vec<Ray> = (0..side * side)
        .map(|k| {
            let (x, y) = (k % side, k / side);
            let sx = ((x as f32 + 0.5) / side as f32 * 2.0 - 1.0) * tan;
            let sy = (1.0 - (y as f32 + 0.5) / side as f32 * 2.0) * tan;
            Ray::new(eye, (fwd + right * sx + up * sy).normalize())
        })
        .collect();
    let random: Vec<Ray> = (0..side * side)
        .map(|_| {
            let o = bounds.min + bounds.extent() * Vec3::new(rng.f32(), rng.f32(), rng.f32());
            let d = Vec3::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5);
            Ray::new(
                o,
                if d == Vec3::ZERO {
                    Vec3::X
                } else {
                    d.normalize()
                },
            )
        })
        .collect();
    let mut hits = vec![None; camera.len()];
    let root = ias.handle();
    let time = |rays: &[Ray], hits: &mut [Option<oxray::Hit>]| -> Result<f64, oxray::QueryError> {
        device.intersect_closest(&root, rays, hits)?;
        let mut times = Vec::with_capacity(runs);
        for _ in 0..runs {
            let t = Instant::now();
            device.intersect_closest(&root, rays, hits)?;
            times.push(t.elapsed().as_secs_f64());
        }
        Ok(median(times))
    };
    let coherent = camera.len() as f64 / time(&camera, &mut hits)? / 1e6;
    let hit_rate = hits.iter().filter(|h| h.is_some()).count() as f64 / hits.len() as f64;
    let incoherent = random.len() as f64 / time(&random, &mut hits)? / 1e6;
    Ok(InstanceBenchResult {
        instances: n,
        mesh_triangles: mesh.triangles.len(),
        build_ms: median(times),
        coherent_mrays: coherent,
        incoherent_mrays: incoherent,
        hit_rate,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shadow_rays_on_a_convex_mesh_are_blocked_exactly_when_facing_away() {
        // On a convex closed mesh, a point sees the light iff its face points towards it; the
        // ray's own start triangle is skipped by the tmin offset.
        let mesh = Mesh::icosphere(3);
        let gas = build_gas(&mesh, BuildFlags::empty()).unwrap();
        let rays = shadow_rays(&mesh, 2000, 3);
        let mut blocked = vec![false; rays.len()];
        gas.occluded_batch(&rays, &mut blocked).unwrap();
        let (c, r) = center_radius(&mesh);
        let light = c + Vec3::new(0.4, 1.2, 0.8) * (2.0 * r);
        let mut mismatches = 0;
        for (ray, &b) in rays.iter().zip(&blocked) {
            let o = ray.origin;
            // The icosphere is centred at the origin: the outward normal is the position.
            let facing = o.normalize().dot((light - o).normalize());
            assert!((o + ray.direction * ray.tmax - light).length() < 1e-4 * r);
            // The facet normal differs from the sphere normal by a few degrees at level 3.
            if facing.abs() > 0.15 && (facing < 0.0) != b {
                mismatches += 1;
            }
        }
        assert_eq!(mismatches, 0);
        let frac = blocked.iter().filter(|&&b| b).count() as f32 / rays.len() as f32;
        assert!(frac > 0.3 && frac < 0.7, "{frac}");
    }

    #[test]
    fn exported_rays_are_32_byte_records_that_read_back_as_the_same_rays() {
        let rays = hemisphere_rays(&Mesh::icosphere(2), 50, 7);
        let bytes = ray_file_bytes(&rays);
        assert_eq!(bytes.len(), 32 * rays.len());
        let back = crate::raycast::parse_rays(&bytes, "test").unwrap();
        assert_eq!(back, rays);
    }

    #[test]
    fn meshes_without_area_give_no_rays_instead_of_looping() {
        let flat = Mesh {
            positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]],
            triangles: vec![[0, 1, 2]],
        };
        assert!(hemisphere_rays(&flat, 10, 1).is_empty());
        assert!(shadow_rays(&flat, 10, 1).is_empty());
    }

    #[test]
    fn hemisphere_rays_are_deterministic_per_seed() {
        // The exported benchmark rays (and the Embree and GPU comparisons) rely on one seed
        // giving one sequence.
        let r = hemisphere_rays(&Mesh::icosphere(2), 3, 7);
        let again = hemisphere_rays(&Mesh::icosphere(2), 3, 7);
        assert_eq!(r.len(), 3);
        for (a, b) in r.iter().zip(&again) {
            assert_eq!(a.origin, b.origin);
            assert_eq!(a.direction, b.direction);
        }
        assert!((r[0].origin.length() - 1.0).abs() < 0.1);
        assert!((r[0].direction.length() - 1.0).abs() < 1e-5);
    }
}
