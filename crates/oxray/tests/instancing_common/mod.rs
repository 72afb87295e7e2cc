//! Helpers shared by the instancing tests (`tests/instancing_*.rs`): a deterministic generator
//! with random well-conditioned affine transforms and triangle helpers (from `oxray-testkit`),
//! triangle soups and their flattening into one GAS, an f64 reference for checking reported
//! hits, and a small multi-ray pipeline harness that records what the hit programs saw.
//!
//! Each test binary uses a different subset of these helpers.
#![allow(dead_code, unused_imports)]

pub use glam::{Affine3A, Mat3, Quat, Vec3};
use oxray::cpu::Gas;
use oxray::{
    AnyHitCtx, BuildInput, BuildOptions, ClosestHitCtx, DeviceContext, ExceptionCode,
    ExceptionFlags, GeometryFlags, Hit, IntersectionCtx, LaunchReport, Module, OutputBuffer,
    Pipeline, PipelineCompileOptions, PipelineLinkOptions, ProgramGroup, RayFlags, SbtRegion,
    ShaderBindingTable, TraceRay, Transform, TraversableHandle, TriangleInput, VertexBuffer,
};
pub use oxray_testkit::mesh::{soup, tri_at, Tri};
pub use oxray_testkit::Rng;
use std::sync::{Arc, Mutex};

/// What the tests return, so that `?` works on the library's errors.
pub type TestResult = Result<(), Box<dyn std::error::Error>>;

/// A proptest configuration with a fixed seed (every run checks the same cases, a failure
/// reproduces) and no regression files. `OXRAY_PROPTEST_SEED=<u64>` explores other cases.
pub fn proptest_config(cases: u32) -> proptest::test_runner::Config {
    let seed = std::env::var("OXRAY_PROPTEST_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0x1a57_a9ce_0009);
    proptest::test_runner::Config {
        cases,
        rng_seed: proptest::test_runner::RngSeed::Fixed(seed),
        failure_persistence: None,
        max_shrink_iters: 64,
        ..Default::default()
    }
}

/// `n` random triangles with vertices within `size` of a centre uniform in `[-extent, extent]^3`.
pub fn random_soup(rng: &mut Rng, n: usize, extent: f32, size: f32) -> Vec<Tri> {
    (0..n)
        .map(|_| {
            let c = rng.vec3(-extent, extent);
            std::array::from_fn(|_| (c + rng.vec3(-size, size)).to_array())
        })
        .collect()
}

/// The triangles moved by `t`.
pub fn transform_tris(t: &Transform, tris: &[Tri]) -> Vec<Tri> {
    tris.iter()
        .map(|tri| tri.map(|p| t.transform_point(Vec3::from_array(p)).to_array()))
        .collect()
}

/// A GAS of one triangle-soup input with one SBT record and the given flags.
pub fn tri_gas_flags(tris: &[Tri], flags: GeometryFlags) -> Arc<Gas> {
    let v = soup(tris);
    let f = [flags];
    let input = TriangleInput::new(VertexBuffer::f32x3(&v)).flags(&f);
    Arc::new(Gas::build(&BuildOptions::default(), &[input.into()]).expect("GAS build"))
}

/// A GAS of one triangle-soup input with one SBT record and no flags.
pub fn tri_gas(tris: &[Tri]) -> Arc<Gas> {
    tri_gas_flags(tris, GeometryFlags::empty())
}

/// A GAS with one triangle-soup build input per element of `parts` (build input `k` holds
/// `parts[k]`), each with one SBT record: the flattened counterpart of an instanced scene.
pub fn flattened_gas(parts: &[Vec<Tri>]) -> Gas {
    let verts: Vec<Vec<[f32; 3]>> = parts.iter().map(|p| soup(p)).collect();
    let inputs: Vec<BuildInput> = verts
        .iter()
        .map(|v| TriangleInput::new(VertexBuffer::f32x3(v)).into())
        .collect();
    Gas::build(&BuildOptions::default(), &inputs).expect("flattened GAS build")
}

/// The distance along `(o, d)` to the plane of `tri`, in f64 (`None` if the ray is parallel to
/// it). Used to check that a reported (instance, primitive) really lies at the reported t.
pub fn plane_t(tri: &Tri, o: Vec3, d: Vec3) -> Option<f64> {
    let p = tri.map(|v| glam::DVec3::from_array(v.map(f64::from)));
    let n = (p[1] - p[0]).cross(p[2] - p[0]);
    let denom = n.dot(d.as_dvec3());
    if denom == 0.0 {
        return None;
    }
    Some(n.dot(p[0] - o.as_dvec3()) / denom)
}

/// Barycentrics `(u, v)` (weights of the second and third vertex) of the point where the ray
/// `(o, d)` meets the plane of `tri`, in f64.
pub fn plane_barycentrics(tri: &Tri, o: Vec3, d: Vec3) -> Option<(f64, f64)> {
    let t = plane_t(tri, o, d)?;
    let p = tri.map(|v| glam::DVec3::from_array(v.map(f64::from)));
    let x = o.as_dvec3() + d.as_dvec3() * t;
    let (e1, e2, w) = (p[1] - p[0], p[2] - p[0], x - p[0]);
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (w1, w2) = (w.dot(e1), w.dot(e2));
    let det = d11 * d22 - d12 * d12;
    if det == 0.0 {
        return None;
    }
    Some(((d22 * w1 - d12 * w2) / det, (d11 * w2 - d12 * w1) / det))
}

/// How far inside its triangle the ray meets the plane: the smallest barycentric weight
/// (negative outside). Near zero means the ray grazes an edge or vertex.
pub fn inside_margin(tri: &Tri, o: Vec3, d: Vec3) -> f64 {
    plane_barycentrics(tri, o, d).map_or(-1.0, |(u, v)| u.min(v).min(1.0 - u - v))
}

/// Whether `a` and `b` agree within relative tolerance `rel` (with an absolute floor of
/// `rel * 1e-2` for values near zero).
pub fn close(a: f32, b: f32, rel: f32) -> bool {
    (a - b).abs() <= rel * a.abs().max(b.abs()).max(1e-2)
}

/// Whether two vectors agree componentwise within `tol * max(1, |largest component|)`.
pub fn vclose(a: Vec3, b: Vec3, tol: f32) -> bool {
    let scale = a.abs().max(b.abs()).max_element().max(1.0);
    (a - b).abs().max_element() <= tol * scale
}

/// Whether two transforms agree elementwise within `tol * max(1, |element|)`.
pub fn tclose(a: &Transform, b: &Transform, tol: f32) -> bool {
    a.0.iter()
        .zip(&b.0)
        .all(|(x, y)| (x - y).abs() <= tol * x.abs().max(y.abs()).max(1.0))
}

/// The bits of a hit, for exact comparisons.
pub type HitBits = (u32, u32, u32, u32, u32, u32, u8, u32, u32);

/// The bits of an optional hit.
pub fn hit_bits(h: &Option<Hit>) -> Option<HitBits> {
    h.map(|h| {
        (
            h.t.to_bits(),
            h.u.to_bits(),
            h.v.to_bits(),
            h.primitive_index,
            h.sbt_gas_index,
            h.build_input,
            h.hit_kind.0,
            h.instance_id,
            h.instance_index,
        )
    })
}

// ---------------------------------------------------------------------------------------------
// Pipeline harness
// ---------------------------------------------------------------------------------------------

/// Number of payload words every harness trace passes.
pub const PAYLOAD: usize = 8;

/// The value every payload word starts with.
pub const UNSET: u32 = 0xDEAD_BEEF;

/// One ray of a harness launch: the trace arguments without the handle.
#[derive(Clone, Debug)]
pub struct RaySpec {
    /// Origin.
    pub origin: Vec3,
    /// Direction.
    pub dir: Vec3,
    /// Ray flags.
    pub flags: RayFlags,
    /// Visibility mask as passed to the trace (all 32 bits).
    pub mask: u32,
    /// SBT offset, stride and miss index.
    pub sbt: (u32, u32, u32),
}

impl RaySpec {
    /// A ray with the trace defaults: no flags, mask `0xFF`, offset 0, stride 1, miss 0.
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        RaySpec {
            origin,
            dir,
            flags: RayFlags::empty(),
            mask: 0xFF,
            sbt: (0, 1, 0),
        }
    }

    /// A ray from `(x, y, 10)` straight down `-z`.
    pub fn down(x: f32, y: f32) -> Self {
        Self::new(Vec3::new(x, y, 10.0), -Vec3::Z)
    }

    /// Sets the flags.
    pub fn flags(mut self, flags: RayFlags) -> Self {
        self.flags = flags;
        self
    }

    /// Sets the visibility mask.
    pub fn mask(mut self, mask: u32) -> Self {
        self.mask = mask;
        self
    }

    /// Sets the SBT offset, stride and miss index.
    pub fn sbt(mut self, offset: u32, stride: u32, miss: u32) -> Self {
        self.sbt = (offset, stride, miss);
        self
    }
}

/// Which program recorded a [`Seen`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Prog {
    /// Intersection.
    Is,
    /// Any-hit.
    Ah,
    /// Closest-hit.
    Ch,
}

/// What a hit program saw: the device functions of guide §13.7 / §13.11.
#[derive(Clone, Debug)]
pub struct Seen {
    /// The program.
    pub prog: Prog,
    /// Launch index x (the ray).
    pub ray: u32,
    /// The first word of the SBT record's data.
    pub data: u32,
    /// `instance_id()`.
    pub instance_id: u32,
    /// `instance_index()`.
    pub instance_index: u32,
    /// `primitive_index()`.
    pub prim: u32,
    /// `sbt_gas_index()`.
    pub sbt_gas_index: u32,
    /// `hit_kind()` (0 in IS).
    pub kind: u8,
    /// `ray_tmax()`.
    pub tmax: f32,
    /// `ray_visibility_mask()`.
    pub mask: u8,
    /// World ray.
    pub world_origin: Vec3,
    /// World ray direction.
    pub world_dir: Vec3,
    /// Object ray (AH and IS only).
    pub object_origin: Option<Vec3>,
    /// Object ray direction (AH and IS only).
    pub object_dir: Option<Vec3>,
    /// `transform_list_size()` (AH and CH only).
    pub levels: Option<u32>,
    /// `object_to_world_transform()` (AH and CH only).
    pub o2w: Option<Transform>,
    /// `world_to_object_transform()` (AH and CH only).
    pub w2o: Option<Transform>,
    /// Probes of the transform helpers (AH and CH only), see [`Probes`].
    pub probes: Option<Probes>,
    /// Triangle barycentrics (AH and CH only).
    pub bary: Option<[f32; 2]>,
}

/// Fixed vectors pushed through the context's transform helpers.
#[derive(Clone, Copy, Debug)]
pub struct Probes {
    /// `transform_point_to_world(PROBE)`.
    pub point_to_world: Vec3,
    /// `transform_vector_to_world(PROBE)`.
    pub vector_to_world: Vec3,
    /// `transform_normal_to_world(PROBE)`.
    pub normal_to_world: Vec3,
    /// `transform_point_to_object(PROBE)`.
    pub point_to_object: Vec3,
    /// `transform_vector_to_object(PROBE)`.
    pub vector_to_object: Vec3,
    /// `transform_normal_to_object(PROBE)`.
    pub normal_to_object: Vec3,
    /// `transform_normal_to_world(+Z)`.
    pub z_normal_to_world: Vec3,
}

/// The vector the transform helpers are probed with.
pub const PROBE: Vec3 = Vec3::new(0.3, -1.7, 2.2);

macro_rules! hit_common {
    ($ctx:expr, $prog:expr) => {{
        let ctx = $ctx;
        Seen {
            prog: $prog,
            ray: ctx.launch_index()[0],
            data: ctx.sbt_data::<u32>().unwrap_or(!0),
            instance_id: ctx.instance_id(),
            instance_index: ctx.instance_index(),
            prim: ctx.primitive_index(),
            sbt_gas_index: ctx.sbt_gas_index(),
            kind: 0,
            tmax: ctx.ray_tmax(),
            mask: ctx.ray_visibility_mask(),
            world_origin: ctx.world_ray_origin(),
            world_dir: ctx.world_ray_direction(),
            object_origin: None,
            object_dir: None,
            levels: None,
            o2w: None,
            w2o: None,
            probes: None,
            bary: None,
        }
    }};
}

macro_rules! hit_transforms {
    ($ctx:expr, $seen:expr) => {{
        let ctx = $ctx;
        let mut s = $seen;
        s.kind = ctx.hit_kind().0;
        s.levels = Some(ctx.transform_list_size());
        s.o2w = Some(ctx.object_to_world_transform());
        s.w2o = Some(ctx.world_to_object_transform());
        s.probes = Some(Probes {
            point_to_world: ctx.transform_point_to_world(PROBE),
            vector_to_world: ctx.transform_vector_to_world(PROBE),
            normal_to_world: ctx.transform_normal_to_world(PROBE),
            point_to_object: ctx.transform_point_to_object(PROBE),
            vector_to_object: ctx.transform_vector_to_object(PROBE),
            normal_to_object: ctx.transform_normal_to_object(PROBE),
            z_normal_to_world: ctx.transform_normal_to_world(Vec3::Z),
        });
        if ctx.is_triangle_hit() {
            s.bary = Some(ctx.triangle_barycentrics());
        }
        s
    }};
}

/// What an any-hit program sees.
pub fn seen_ah(ctx: &AnyHitCtx<'_, Lp>) -> Seen {
    let mut s = hit_transforms!(ctx, hit_common!(ctx, Prog::Ah));
    s.object_origin = Some(ctx.object_ray_origin());
    s.object_dir = Some(ctx.object_ray_direction());
    s
}

/// What a closest-hit program sees.
pub fn seen_ch(ctx: &ClosestHitCtx<'_, Lp>) -> Seen {
    hit_transforms!(ctx, hit_common!(ctx, Prog::Ch))
}

/// What an intersection program sees.
pub fn seen_is(ctx: &IntersectionCtx<'_, '_, Lp>) -> Seen {
    let mut s = hit_common!(ctx, Prog::Is);
    s.object_origin = Some(ctx.object_ray_origin());
    s.object_dir = Some(ctx.object_ray_direction());
    s
}

/// Launch parameters of the harness: ray `i` is traced by launch index `(i, 0, 0)`.
#[derive(Clone)]
pub struct Lp {
    /// What every ray is traced against.
    pub handle: TraversableHandle,
    /// The rays.
    pub rays: Arc<Vec<RaySpec>>,
    /// The payload of every ray after its trace returned (all `UNSET` if it did not).
    pub out: Arc<OutputBuffer<[u32; PAYLOAD]>>,
    /// What the hit programs saw.
    pub seen: Arc<Mutex<Vec<Seen>>>,
}

impl Lp {
    /// Records what a program saw.
    pub fn push(&self, s: Seen) {
        self.seen.lock().unwrap().push(s);
    }
}

/// Entry name of the harness's ray-generation program.
pub const RG: &str = "__raygen__rays";

/// A module with the harness's ray generation: launch index `i` traces `rays[i]` with a payload
/// of [`PAYLOAD`] words set to [`UNSET`] and stores the payload once the trace has returned.
pub fn module() -> Module<Lp> {
    Module::<Lp>::new()
        .raygen(RG, |ctx| {
            let i = ctx.launch_index()[0] as usize;
            let p = ctx.params();
            let r = &p.rays[i];
            let mut payload = [UNSET; PAYLOAD];
            let (offset, stride, miss) = r.sbt;
            ctx.trace(
                &TraceRay::new(&p.handle, r.origin, r.dir)
                    .flags(r.flags)
                    .visibility_mask(r.mask)
                    .sbt(offset, stride, miss),
                &mut payload,
            )?;
            p.out.write(i, payload);
            Ok(())
        })
        .expect("raygen registers")
}

/// The programs of one hit-group record.
#[derive(Clone, Copy, Default)]
pub struct HitProgs<'a> {
    /// Closest hit.
    pub ch: Option<&'a str>,
    /// Any hit.
    pub ah: Option<&'a str>,
    /// Intersection.
    pub is: Option<&'a str>,
}

/// A pipeline over the harness's module: the harness ray generation, one miss record (the
/// module's program `miss`, or a no-op), one hit-group record per element of `hits` (whose
/// data is the `u32` given), and an exception record if `exception` names a program.
pub struct Harness {
    /// The pipeline.
    pub pipeline: Pipeline<Lp>,
    /// Its SBT.
    pub sbt: ShaderBindingTable,
}

/// The outcome of a harness launch.
#[derive(Debug)]
pub struct Outcome {
    /// The launch report.
    pub report: LaunchReport,
    /// The payload of every ray.
    pub payloads: Vec<[u32; PAYLOAD]>,
    /// What the hit programs saw, sorted by ray (and in call order within a ray).
    pub seen: Vec<Seen>,
}

impl Outcome {
    /// What ray `i`'s programs of kind `p` saw.
    pub fn of(&self, i: u32, p: Prog) -> Vec<&Seen> {
        self.seen
            .iter()
            .filter(|s| s.ray == i && s.prog == p)
            .collect()
    }

    /// The codes of the exceptions the launch reported.
    pub fn exception_codes(&self) -> Vec<ExceptionCode> {
        self.report
            .first_exceptions
            .iter()
            .map(|(_, e)| e.code)
            .collect()
    }
}

impl Harness {
    /// Links the pipeline. Compile options: [`PAYLOAD`] payload words, 8 attribute words, every
    /// exception check, and `graph` as the traversable graph flags.
    pub fn new(
        m: &Module<Lp>,
        miss: Option<&str>,
        hits: &[(HitProgs<'_>, u32)],
        graph: oxray::TraversableGraphFlags,
    ) -> Self {
        let compile = PipelineCompileOptions {
            traversable_graph_flags: graph,
            ..Self::compile_options()
        };
        Self::with_compile(m, miss, hits, &compile)
    }

    /// The compile options of [`Harness::new`] with any traversable graph.
    pub fn compile_options() -> PipelineCompileOptions {
        PipelineCompileOptions {
            num_payload_values: PAYLOAD as u32,
            num_attribute_values: 8,
            exception_flags: ExceptionFlags::all(),
            ..Default::default()
        }
    }

    /// Links the pipeline with the given compile options.
    pub fn with_compile(
        m: &Module<Lp>,
        miss: Option<&str>,
        hits: &[(HitProgs<'_>, u32)],
        compile: &PipelineCompileOptions,
    ) -> Self {
        let raygen = ProgramGroup::raygen(m, RG).expect("raygen group");
        let miss_g = ProgramGroup::miss(miss.map(|n| (m, n))).expect("miss group");
        let hit_g: Vec<ProgramGroup<Lp>> = hits
            .iter()
            .map(|(h, _)| {
                ProgramGroup::hit_group(oxray::HitGroupDesc {
                    closest_hit: h.ch.map(|n| (m, n)),
                    any_hit: h.ah.map(|n| (m, n)),
                    intersection: h.is.map(|n| (m, n)),
                })
                .expect("hit group")
            })
            .collect();
        let mut groups = vec![raygen.clone(), miss_g.clone()];
        groups.extend(hit_g.iter().cloned());
        let pipeline = Pipeline::new(
            &DeviceContext::new(),
            compile,
            &PipelineLinkOptions { max_trace_depth: 1 },
            &groups,
        )
        .expect("pipeline links");
        let hit_records: Vec<_> = hit_g
            .iter()
            .zip(hits)
            .map(|(g, (_, d))| (g.pack_header(), *d))
            .collect();
        let sbt = ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[raygen.pack_header()]),
            miss: SbtRegion::from_records(&[(miss_g.pack_header(), 0u32)]),
            hitgroup: SbtRegion::from_records(&hit_records),
            ..Default::default()
        };
        Harness { pipeline, sbt }
    }

    /// Traces `rays` against `handle`, one launch index per ray.
    pub fn run(&self, handle: &TraversableHandle, rays: &[RaySpec]) -> Outcome {
        let params = Lp {
            handle: handle.clone(),
            rays: Arc::new(rays.to_vec()),
            out: Arc::new(OutputBuffer::new(rays.len())),
            seen: Arc::new(Mutex::new(Vec::new())),
        };
        for i in 0..rays.len() {
            params.out.write(i, [UNSET; PAYLOAD]);
        }
        let report = self
            .pipeline
            .launch(&params, &self.sbt, rays.len() as u32, 1, 1)
            .expect("launch");
        let mut seen = std::mem::take(&mut *params.seen.lock().unwrap());
        // Stable: programs of one ray run on one thread, in order.
        seen.sort_by_key(|s| s.ray);
        Outcome {
            report,
            payloads: params.out.to_vec(),
            seen,
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Instanced scene against its flattened counterpart
// ---------------------------------------------------------------------------------------------

/// Relative tolerance on t between an instanced and a flattened scene, for rays meeting the
/// triangle's plane at an incidence steeper than 1/100.
pub const REL_T: f32 = 1e-4;
/// A ray meeting the plane within this barycentric margin of an edge grazes it.
pub const GRAZE: f64 = 1e-4;
/// Largest fraction of rays on which the two scenes may disagree (all grazing).
pub const MAX_MISMATCH: f64 = 0.005;

/// One build input of a flattened scene: the world triangles of one path from the root to a
/// GAS, and the nearest instance on that path.
#[derive(Clone, Debug)]
pub struct Leaf {
    /// World-space triangles (primitive `k` of the GAS at the end of the path).
    pub world: Vec<Tri>,
    /// `instance_id` of the nearest instance.
    pub instance_id: u32,
    /// `instance_index` of the nearest instance.
    pub instance_index: u32,
}

/// The relative tolerance on t for a ray meeting a triangle's plane at incidence `cos`: either
/// scene's rounding (transformed ray, or transformed vertices, both in f32) moves the plane by a
/// few ulps of the scene's coordinates, which moves t by that over `cos`. Rays steeper than
/// 1/100 get the plain [`REL_T`]; rays almost parallel to the plane proportionally more.
pub fn t_tolerance(cos: f32) -> f32 {
    REL_T * (0.01 / cos).max(1.0)
}

/// Whether distances `a` and `b` along `ray` agree within relative tolerance `rel`. The floor
/// for small t is scaled by the scene's coordinates where the ray starts (rounding errors are
/// ulps of the coordinates, not of t).
pub fn t_close(ray: &oxray::Ray, a: f32, b: f32, rel: f32) -> bool {
    let floor = 0.1 * ray.origin.abs().max_element().max(1.0) / ray.direction.length();
    (a - b).abs() <= rel * a.abs().max(b.abs()).max(floor)
}

/// The point with barycentrics `(u, v)` on `tri`.
pub fn bary_point(tri: &Tri, u: f32, v: f32) -> Vec3 {
    let p = tri.map(Vec3::from_array);
    p[0] * (1.0 - u - v) + p[1] * u + p[2] * v
}

/// `|cos|` of the angle between the ray and the triangle's normal (at least 1e-6).
pub fn incidence_cos(tri: &Tri, ray: &oxray::Ray) -> f32 {
    let p = tri.map(Vec3::from_array);
    let n = (p[1] - p[0]).cross(p[2] - p[0]).normalize();
    n.dot(ray.direction.normalize()).abs().max(1e-6)
}

/// Counters of a comparison.
#[derive(Default, Debug, Clone, Copy)]
pub struct Stats {
    /// Rays compared.
    pub rays: usize,
    /// Rays both scenes hit.
    pub hits: usize,
    /// Rays where one scene hit and the other did not, or where one found a nearer hit: all
    /// on triangles the ray grazes (or at an end of the interval).
    pub mismatches: usize,
    /// Rays both hit at the same t (within tolerance) on different triangles.
    pub near_ties: usize,
    /// Rays whose occlusion differs between the scenes.
    pub occlusion_mismatches: usize,
}

impl Stats {
    /// Adds another's counters.
    pub fn add(&mut self, o: &Stats) {
        self.rays += o.rays;
        self.hits += o.hits;
        self.mismatches += o.mismatches;
        self.near_ties += o.near_ties;
        self.occlusion_mismatches += o.occlusion_mismatches;
    }

    /// Checks and prints the mismatch fractions.
    pub fn check(&self, what: &str) {
        let frac = self.mismatches as f64 / self.rays.max(1) as f64;
        let occ = self.occlusion_mismatches as f64 / self.rays.max(1) as f64;
        eprintln!(
            "{what}: {self:?}; grazing hit/miss or nearest-t mismatches {:.3}%, occlusion \
             mismatches {:.3}%",
            100.0 * frac,
            100.0 * occ
        );
        assert!(
            self.hits * 3 > self.rays,
            "too few hits to mean much: {self:?}"
        );
        assert!(frac <= MAX_MISMATCH, "{what}: mismatch fraction {frac}");
        assert!(
            occ <= MAX_MISMATCH,
            "{what}: occlusion mismatch fraction {occ}"
        );
    }
}

/// The leaf an IAS hit comes from: one whose nearest instance matches the hit's and whose
/// primitive lies at the hit's t (several paths may share the nearest instance).
fn ias_leaf<'a>(leaves: &'a [Leaf], ray: &oxray::Ray, h: &Hit) -> Result<&'a Leaf, String> {
    let mut candidates = leaves
        .iter()
        .filter(|l| (l.instance_id, l.instance_index) == (h.instance_id, h.instance_index))
        .peekable();
    if candidates.peek().is_none() {
        return Err(format!("no instance has id and index of {h:?}"));
    }
    let mut nearest = f64::INFINITY;
    for l in candidates {
        let Some(tri) = l.world.get(h.primitive_index as usize) else {
            continue;
        };
        let tp = plane_t(tri, ray.origin, ray.direction).unwrap_or(f64::NAN);
        let cos = incidence_cos(tri, ray);
        if t_close(ray, tp as f32, h.t, 2.0 * t_tolerance(cos)) {
            return Ok(l);
        }
        nearest = nearest.min((tp - h.t as f64).abs());
    }
    Err(format!(
        "no primitive {} under instance (id {}, index {}) lies at t = {} (nearest off by \
         {nearest})",
        h.primitive_index, h.instance_id, h.instance_index, h.t
    ))
}

/// Whether the ray grazes an edge of `tri` (or `t` lies at an end of the interval).
fn grazing(tri: &Tri, ray: &oxray::Ray, t: f32) -> bool {
    let margin = inside_margin(tri, ray.origin, ray.direction);
    let cos = incidence_cos(tri, ray);
    let tol = t_tolerance(cos);
    margin.abs() < GRAZE + 1e-5 / cos as f64
        || t_close(ray, t, ray.tmin, tol)
        || t_close(ray, t, ray.tmax, tol)
}

/// Compares one ray on an instanced scene (`ias`) and its flattened counterpart (`flat`, whose
/// build input `k` holds `leaves[k]`): the closest hits agree in t (within [`t_tolerance`]),
/// primitive, hit kind and hit point, and name the right instance; hits on different triangles
/// must be near-ties; where only one scene hits, or one finds a nearer hit, the ray must graze
/// that triangle. `occluded()` agrees with `intersect()` on each scene exactly.
pub fn compare_ray(
    ias: &oxray::cpu::Ias,
    flat: &Gas,
    leaves: &[Leaf],
    ray: &oxray::Ray,
    st: &mut Stats,
) -> Result<(), String> {
    let a = ias.intersect(ray);
    let b = flat.intersect(ray);
    st.rays += 1;
    let leaf_a = match &a {
        Some(h) => Some(ias_leaf(leaves, ray, h)?),
        None => None,
    };
    let leaf_b = match &b {
        Some(h) => {
            if (h.instance_id, h.instance_index) != (!0, 0) {
                return Err(format!("GAS root hit reports an instance: {h:?}"));
            }
            Some(
                leaves
                    .get(h.build_input as usize)
                    .ok_or_else(|| format!("bad build input {h:?}"))?,
            )
        }
        None => None,
    };
    let (oa, ob) = (ias.occluded(ray), flat.occluded(ray));
    if oa != a.is_some() || ob != b.is_some() {
        return Err(format!(
            "occluded() disagrees with intersect(): IAS {oa} vs {a:?}, GAS {ob} vs {b:?}"
        ));
    }
    if oa != ob {
        st.occlusion_mismatches += 1;
    }
    let tri_of = |l: &Leaf, h: &Hit| l.world[h.primitive_index as usize];
    match (a, b, leaf_a, leaf_b) {
        (Some(a), Some(b), Some(la), Some(lb)) => {
            st.hits += 1;
            let tri_a = tri_of(la, &a);
            let tri_b = tri_of(lb, &b);
            let same = std::ptr::eq(la, lb) && a.primitive_index == b.primitive_index;
            let cos = incidence_cos(&tri_a, ray).min(incidence_cos(&tri_b, ray));
            if same {
                if !t_close(ray, a.t, b.t, t_tolerance(cos)) {
                    return Err(format!(
                        "t differs (cos {cos}): IAS {a:?} vs flattened {b:?}"
                    ));
                }
                if a.hit_kind != b.hit_kind {
                    return Err(format!("hit kind differs: IAS {a:?} vs flattened {b:?}"));
                }
                // Barycentrics are affine invariants: both must name the same world point, the
                // one at t along the ray. (Compared as points, not as weights, which are
                // ill-conditioned on slivers; the in-plane error grows as 1 / cos.)
                let pa = bary_point(&tri_a, a.u, a.v);
                let pb = bary_point(&tri_a, b.u, b.v);
                let at = ray.at(a.t);
                let tol = 1e-4 / cos;
                if !vclose(pa, pb, tol) || !vclose(pa, at, tol) {
                    return Err(format!(
                        "barycentrics name different points {pa} / {pb} / ray at t {at} (cos \
                         {cos}): IAS {a:?} vs flattened {b:?}"
                    ));
                }
                Ok(())
            } else if t_close(ray, a.t, b.t, t_tolerance(cos)) {
                st.near_ties += 1;
                Ok(())
            } else {
                // One scene found a nearer triangle: the other may miss it only if grazing.
                let (tri, t, which) = if a.t < b.t {
                    (tri_a, a.t, "IAS")
                } else {
                    (tri_b, b.t, "flattened")
                };
                if grazing(&tri, ray, t) {
                    st.mismatches += 1;
                    Ok(())
                } else {
                    Err(format!(
                        "different closest hits, the {which} one nearer and not grazing: IAS \
                         {a:?} vs flattened {b:?} (ray {ray:?})"
                    ))
                }
            }
        }
        (None, None, _, _) => Ok(()),
        (a, b, la, lb) => {
            let (h, l, which) = match (a, la) {
                (Some(h), Some(l)) => (h, l, "IAS"),
                _ => (b.unwrap(), lb.unwrap(), "flattened"),
            };
            if grazing(&tri_of(l, &h), ray, h.t) {
                st.mismatches += 1;
                Ok(())
            } else {
                Err(format!(
                    "only the {which} scene hits, and not at an edge: {h:?} (ray {ray:?})"
                ))
            }
        }
    }
}

/// Rays into a scene of world triangles: most aimed at a random point inside a random triangle
/// (from a random origin in `[-spread, spread]^3`, half with unnormalised directions), the rest
/// random; every seventh with a finite interval.
pub fn aimed_rays(rng: &mut Rng, leaves: &[Leaf], spread: f32, n: usize) -> Vec<oxray::Ray> {
    (0..n)
        .map(|i| {
            let o = rng.vec3(-spread, spread);
            let d = if i % 5 < 3 {
                let leaf = &leaves[rng.below(leaves.len())];
                let tri = leaf.world[rng.below(leaf.world.len())];
                let (mut a, mut b) = (rng.f32(), rng.f32());
                if a + b > 1.0 {
                    (a, b) = (1.0 - a, 1.0 - b);
                }
                let p = tri.map(Vec3::from_array);
                let d = p[0] + (p[1] - p[0]) * a + (p[2] - p[0]) * b - o;
                if i % 2 == 0 {
                    d.normalize()
                } else {
                    d
                }
            } else {
                rng.unit() * rng.range(0.2, 3.0)
            };
            if i % 7 == 0 {
                let tmin = rng.range(0.0, 0.3);
                let tmax = tmin + rng.range(0.0, 3.0) * spread / d.length();
                oxray::Ray::with_interval(o, d, tmin, tmax)
            } else {
                oxray::Ray::new(o, d)
            }
        })
        .collect()
}
