//! One ray set of `oxray bench --export DIR` traced again and again: the tool for profiling
//! the CPU kernel (`perf record` on this binary sees only traversal) and for comparing two
//! kernels on exactly the rays `scripts/bench-vs-embree.sh` gives Embree.
//!
//! ```sh
//! target/release/oxray bench ogre.obj --export bench-out/rays --runs 1
//! cargo bench -p oxray-cpu --bench ray_sets -- bench-out/rays ogre shadow any 9 1
//! ```
//!
//! Arguments: DIR NAME SET (coherent, incoherent, shadow) QUERY (closest, any, single: closest
//! hits ray by ray with `Gas::intersect`, no packets, or pipeline: closest hits through the
//! programmable pipeline, a ray-generation program tracing one ray per launch index with a
//! closest-hit program that returns t, or pipeline-ratio: single and pipeline passes in turn,
//! the median of their rate ratios) RUNS THREADS.
//! Prints the median and the best Mrays/s (on a shared machine the best is the steadier
//! figure), the hit count (which must not change between kernels) and the
//! kernel used. `OXRAY_CPU_ISA` picks the kernel as everywhere else.

use oxray_core::{
    BuildOptions, DeviceContext, IndexBuffer, PipelineCompileOptions, PipelineLinkOptions, Ray,
    SbtRegion, ShaderBindingTable, TraversableHandle, TriangleInput, VertexBuffer,
};
use oxray_cpu::{Gas, HitGroupDesc, Module, OutputBuffer, Pipeline, ProgramGroup, TraceRay};
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

fn read(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn words(bytes: &[u8]) -> impl Iterator<Item = [u8; 4]> + '_ {
    bytes.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]])
}

fn load_mesh(path: &Path) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let b = read(path);
    let mut w = words(&b);
    let nv = u32::from_le_bytes(w.next().expect("vertex count")) as usize;
    let nt = u32::from_le_bytes(w.next().expect("triangle count")) as usize;
    let f: Vec<f32> = w.by_ref().take(nv * 3).map(f32::from_le_bytes).collect();
    let i: Vec<u32> = w.take(nt * 3).map(u32::from_le_bytes).collect();
    assert_eq!((f.len(), i.len()), (nv * 3, nt * 3), "truncated mesh");
    let v = f.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let t = i.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    (v, t)
}

fn load_rays(path: &Path) -> Vec<Ray> {
    let f: Vec<f32> = words(&read(path)).map(f32::from_le_bytes).collect();
    f.chunks_exact(8)
        .map(|r| {
            Ray::with_interval(
                [r[0], r[1], r[2]].into(),
                [r[4], r[5], r[6]].into(),
                r[3],
                r[7],
            )
        })
        .collect()
}

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| a != "--bench")
        .collect();
    if args.len() < 4 {
        eprintln!("usage: ray_sets DIR NAME SET QUERY [RUNS] [THREADS]");
        return;
    }
    let dir = Path::new(&args[0]);
    let (name, set, query) = (&args[1], &args[2], &args[3]);
    let runs: usize = args.get(4).map_or(9, |s| s.parse().expect("RUNS"));
    let threads: usize = args.get(5).map_or(1, |s| s.parse().expect("THREADS"));
    let (v, t) = load_mesh(&dir.join(format!("{name}.mesh")));
    let rays = load_rays(&dir.join(format!("{name}.{set}.rays")));
    let input = TriangleInput::new(VertexBuffer::f32x3(&v)).indices(IndexBuffer::u32x3(&t));
    let gas = Gas::build(&BuildOptions::default(), &[input.into()]).expect("build");
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool");
    let any = query == "any";
    let single = query == "single";
    let mut hits = vec![None; rays.len()];
    let mut blocked = vec![false; rays.len()];
    let gas = Arc::new(gas);
    let ratio = query == "pipeline-ratio";
    let piped = (query == "pipeline" || ratio).then(|| PipelineBench::new(&gas, &rays));
    if let (true, Some(p)) = (ratio, &piped) {
        pipeline_ratio(name, set, &pool, &gas, &rays, p, runs, threads);
        return;
    }
    let mut trace = || {
        let start = Instant::now();
        pool.install(|| {
            if let Some(p) = &piped {
                p.launch();
            } else if single {
                single_rays(&gas, &rays, &mut hits);
            } else if any {
                gas.occluded_batch(&rays, &mut blocked).expect("batch");
            } else {
                gas.intersect_batch(&rays, &mut hits).expect("batch");
            }
        });
        start.elapsed().as_secs_f64()
    };
    trace();
    let mut times: Vec<f64> = (0..runs).map(|_| trace()).collect();
    times.sort_by(f64::total_cmp);
    let count = if let Some(p) = &piped {
        p.hit_count()
    } else if any {
        blocked.iter().filter(|&&b| b).count()
    } else {
        hits.iter().flatten().count()
    };
    println!(
        "{name} {set} {query}: {:.3} Mrays/s (median of {runs}; best {:.3}; {threads} thread(s), kernel {:?}), {count} of {} rays hit",
        rays.len() as f64 / times[runs / 2] / 1e6,
        rays.len() as f64 / times[0] / 1e6,
        gas.isa(),
        rays.len()
    );
}

/// Closest hits ray by ray (`Gas::intersect`, no packets), in parallel.
fn single_rays(gas: &Gas, rays: &[Ray], hits: &mut [Option<oxray_core::Hit>]) {
    use rayon::prelude::*;
    rays.par_iter()
        .zip(hits.par_iter_mut())
        .with_min_len(256)
        .for_each(|(r, h)| *h = gas.intersect(r));
}

/// The pipeline's rate over the single-ray queries' on the same rays (issue 14's rule: at least
/// 0.75), from passes of each taken in turn (the order swapped every run), so that both see
/// the same machine load: the median of the runs' ratios, and the best pass of each.
#[allow(clippy::too_many_arguments)]
fn pipeline_ratio(
    name: &str,
    set: &str,
    pool: &rayon::ThreadPool,
    gas: &Gas,
    rays: &[Ray],
    piped: &PipelineBench<'_>,
    runs: usize,
    threads: usize,
) {
    let mut hits = vec![None; rays.len()];
    let mut single = || {
        let start = Instant::now();
        pool.install(|| single_rays(gas, rays, &mut hits));
        start.elapsed().as_secs_f64()
    };
    let pipeline = || {
        let start = Instant::now();
        pool.install(|| piped.launch());
        start.elapsed().as_secs_f64()
    };
    single();
    pipeline();
    let (mut ratios, mut best) = (Vec::new(), [f64::INFINITY; 2]);
    for run in 0..runs.max(1) {
        let (s, p) = if run % 2 == 0 {
            let s = single();
            (s, pipeline())
        } else {
            let p = pipeline();
            (single(), p)
        };
        ratios.push(s / p);
        best = [best[0].min(s), best[1].min(p)];
    }
    ratios.sort_by(f64::total_cmp);
    let n = ratios.len();
    println!(
        "{name} {set} pipeline / single: {:.3} (median of {n}; quartiles {:.3}-{:.3}); best passes {:.3} / {:.3} Mrays/s; {threads} thread(s), kernel {:?}",
        ratios[n / 2],
        ratios[n / 4],
        ratios[(3 * n) / 4],
        rays.len() as f64 / best[1] / 1e6,
        rays.len() as f64 / best[0] / 1e6,
        gas.isa(),
    );
    let count = hits.iter().flatten().count();
    assert_eq!(
        count,
        piped.hit_count(),
        "the pipeline and the queries hit alike"
    );
}

/// Launch parameters of the pipeline mode.
#[derive(Clone)]
struct Params<'a> {
    rays: &'a [Ray],
    handle: TraversableHandle,
    out: &'a OutputBuffer<f32>,
}

/// The pipeline of `oxray bench`'s pipeline column: one trace per launch index, a closest-hit
/// program that returns t, a miss program that returns +inf.
struct PipelineBench<'a> {
    pipeline: Pipeline<Params<'a>>,
    sbt: ShaderBindingTable,
    params: Params<'a>,
}

impl<'a> PipelineBench<'a> {
    fn new(gas: &Arc<Gas>, rays: &'a [Ray]) -> Self {
        let out: &'a OutputBuffer<f32> = Box::leak(Box::new(OutputBuffer::new(rays.len())));
        let module = Module::<Params>::new()
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
            })
            .and_then(|m| {
                m.closest_hit("__closesthit__t", |ctx| {
                    let t = ctx.ray_tmax();
                    ctx.set_payload_f32(0, t);
                    Ok(())
                })
            })
            .and_then(|m| {
                m.miss("__miss__inf", |ctx| {
                    ctx.set_payload_f32(0, f32::INFINITY);
                    Ok(())
                })
            })
            .expect("module");
        let rg = ProgramGroup::raygen(&module, "__raygen__bench").expect("raygen");
        let ms = ProgramGroup::miss(Some((&module, "__miss__inf"))).expect("miss");
        let hg = ProgramGroup::hit_group(HitGroupDesc {
            closest_hit: Some((&module, "__closesthit__t")),
            ..Default::default()
        })
        .expect("hit group");
        let pipeline = Pipeline::new(
            &DeviceContext::new(),
            &PipelineCompileOptions {
                num_payload_values: 1,
                ..Default::default()
            },
            &PipelineLinkOptions { max_trace_depth: 1 },
            &[rg.clone(), ms.clone(), hg.clone()],
        )
        .expect("pipeline");
        let sbt = ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[rg.pack_header()]),
            miss: SbtRegion::from_headers(&[ms.pack_header()]),
            hitgroup: SbtRegion::from_headers(&[hg.pack_header()]),
            ..Default::default()
        };
        let params = Params {
            rays,
            handle: gas.clone().into(),
            out,
        };
        PipelineBench {
            pipeline,
            sbt,
            params,
        }
    }

    fn launch(&self) {
        let n = self.params.rays.len() as u32;
        let report = self
            .pipeline
            .launch(&self.params, &self.sbt, n, 1, 1)
            .expect("launch");
        assert_eq!(report.exceptions, 0, "the bench's programs raise nothing");
    }

    /// Rays whose closest-hit program ran (a finite t).
    fn hit_count(&self) -> usize {
        (0..self.params.rays.len())
            .filter(|&i| self.params.out.read(i).is_some_and(f32::is_finite))
            .count()
    }
}
