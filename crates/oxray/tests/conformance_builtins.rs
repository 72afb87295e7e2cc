//! The pipeline scenarios of the conformance suite (conformance_twins.rs, conformance_twins2.rs)
//! run with built-in spheres (guide §5.3, §9.4) and curves (§5.2, §9.3) in place of triangles,
//! where they apply: round cubic B-splines, and flat quadratic B-splines (ribbons) where facing
//! matters. Programs in conformance/builtins.cu, run on every device present: the CPU always (its
//! programs compiled by the host's C++ compiler) and a CUDA device where there is one
//! (`OXRAY_REQUIRE_GPU=1` makes its absence a failure). Each device must give the values
//! computed here on the host (with the intersection test every backend uses, or the CPU device's
//! batched query, both tested against brute force), and all devices the same records.
//!
//! Covered: closest-hit selection among overlapping primitives along a ray and over random rays
//! (§13.4, §13.7: t, primitive index, hit kind, primitive type, curve parameters), ignore and
//! terminate in any-hit (§13.13), the ray flags (§13.2) with geometry any-hit flags, and the
//! triangle culling flags that leave built-ins alone (§9.6: only a ribbon has a back face), the
//! SBT index formula (§7.3) with several records of a sphere input and one record per curve
//! input, visibility masks, instance flags and instance ids and indices over an IAS of a sphere
//! GAS and a curve GAS with the object-space ray (§5.4, §13.7), and the shrinking interval that
//! any-hit sees (§13.4, §13.5).
//!
//! Every launch index traces one ray described by a [`RayIn`] record, and every program logs what
//! it saw in the launch index's record.

mod common;

use common::{code_after_runs, name, on_every_device, HitSpec, LabelledPipeline, PipelineSpec};
use glam::Vec3;
use oxray::bvh::GasData;
use oxray::{
    BuildInput, BuildOptions, CurveEndcaps, CurveInput, CurveType, Device, GeometryFlags, HitKind,
    Instance, InstanceFlags, LaunchReport, PipelineCompileOptions, PrimitiveType,
    PrimitiveTypeFlags, Ray, RayFlags, SbtIndexOffsets, SbtRegion, ShaderBindingTable, Sphere,
    SphereInput, Transform,
};
use oxray_testkit::rng::Rng;

const BUILTINS: &str = include_str!("conformance/builtins.cu");

/// Words of a launch index's record (`BI_WORDS` in builtins.cu), where its events start, their
/// size and how many fit.
const WORDS: usize = 512;
const EVENTS_AT: usize = 16;
const EVENT_WORDS: usize = 16;
const MAX_EVENTS: usize = 24;

const CH: Option<&str> = Some("__closesthit__log");

const HIT_GROUPS: [HitSpec; 4] = [
    ("log", CH, Some("__anyhit__log"), None),
    ("ch_only", CH, None, None),
    ("ignore", CH, Some("__anyhit__ignore"), None),
    ("terminate", CH, Some("__anyhit__terminate"), None),
];
const RAYGEN: &str = "__raygen__bi";
const MISS: (&str, &str) = ("ms_log", "__miss__log");
const EXCEPTION: &str = "__exception__bi";

/// The primitive types of every pipeline here.
fn types() -> PrimitiveTypeFlags {
    PrimitiveTypeFlags::SPHERE
        | PrimitiveTypeFlags::ROUND_CUBIC_BSPLINE
        | PrimitiveTypeFlags::FLAT_QUADRATIC_BSPLINE
}

/// A ray of one launch index (`RayIn` in builtins.cu).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct RayIn {
    origin: [f32; 3],
    dir: [f32; 3],
    tmin: f32,
    tmax: f32,
    mask: u32,
    flags: u32,
    sbt_offset: u32,
    sbt_stride: u32,
    miss_index: u32,
    payload: [u32; 8],
    pad: [u32; 3],
}

impl RayIn {
    fn new(origin: Vec3, dir: Vec3) -> RayIn {
        RayIn {
            origin: origin.to_array(),
            dir: dir.to_array(),
            tmin: 0.0,
            tmax: 1e30,
            mask: 0xFF,
            flags: 0,
            sbt_offset: 0,
            sbt_stride: 1,
            miss_index: 0,
            payload: [0; 8],
            pad: [0; 3],
        }
    }

    /// Down -z from `(x, y, 10)`.
    fn down(x: f32, y: f32) -> RayIn {
        RayIn::new(Vec3::new(x, y, 10.0), -Vec3::Z)
    }

    fn interval(mut self, tmin: f32, tmax: f32) -> RayIn {
        (self.tmin, self.tmax) = (tmin, tmax);
        self
    }

    fn flags(mut self, flags: RayFlags) -> RayIn {
        self.flags = flags.bits();
        self
    }

    fn mask(mut self, mask: u32) -> RayIn {
        self.mask = mask;
        self
    }

    fn sbt(mut self, offset: u32, stride: u32) -> RayIn {
        (self.sbt_offset, self.sbt_stride) = (offset, stride);
        self
    }

    /// The any-hit program "ignore" ignores the primitives whose bit is set in `mask`.
    fn ignoring(mut self, mask: u32) -> RayIn {
        self.payload[7] = mask;
        self
    }

    fn ray(&self) -> Ray {
        Ray::with_interval(
            Vec3::from(self.origin),
            Vec3::from(self.dir),
            self.tmin,
            self.tmax,
        )
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct BiParams {
    out: u64,
    handle: u64,
    rays: u64,
}

/// Which program logged an event.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Prog {
    Ah,
    Ch,
    Ms,
}

/// What one program saw (a miss: only tmin, tmax and data).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Ev {
    prog: Prog,
    prim: u32,
    tmin: f32,
    tmax: f32,
    kind: u32,
    ptype: u32,
    u: f32,
    v: f32,
    gas_index: u32,
    data: u32,
    instance_id: u32,
    instance_index: u32,
    /// 1 front face, 2 back face, 4 a triangle.
    facing: u32,
    object_origin_xz: [f32; 2],
    object_dir_z: f32,
}

/// What one launch index did: the payload after the trace (if it returned), the events in
/// order, and the exception code the exception program saw (0 for none).
#[derive(Clone, Debug, PartialEq)]
struct Rec {
    payload: Option<[u32; 8]>,
    log: Vec<Ev>,
    exception: u32,
}

impl Rec {
    fn parse(w: &[u32; WORDS]) -> Rec {
        let n = w[8] as usize;
        assert!(n <= MAX_EVENTS, "{n} events: the record keeps {MAX_EVENTS}");
        let f = f32::from_bits;
        let log = (0..n)
            .map(|k| {
                let e = &w[EVENTS_AT + EVENT_WORDS * k..EVENTS_AT + EVENT_WORDS * (k + 1)];
                Ev {
                    prog: match e[0] {
                        2 => Prog::Ah,
                        3 => Prog::Ch,
                        4 => Prog::Ms,
                        p => panic!("event {k}: no program {p}"),
                    },
                    prim: e[1],
                    tmin: f(e[2]),
                    tmax: f(e[3]),
                    kind: e[4],
                    ptype: e[5],
                    u: f(e[6]),
                    v: f(e[7]),
                    gas_index: e[8],
                    data: e[9],
                    instance_id: e[10],
                    instance_index: e[11],
                    facing: e[12],
                    object_origin_xz: [f(e[13]), f(e[14])],
                    object_dir_z: f(e[15]),
                }
            })
            .collect();
        let mut payload = [0u32; 8];
        payload.copy_from_slice(&w[..8]);
        Rec {
            payload: (w[10] == 1).then_some(payload),
            log,
            exception: w[11],
        }
    }

    fn of(&self, p: Prog) -> Vec<Ev> {
        self.log.iter().filter(|e| e.prog == p).copied().collect()
    }

    fn count(&self, p: Prog) -> usize {
        self.log.iter().filter(|e| e.prog == p).count()
    }

    /// The only closest-hit event.
    fn ch(&self) -> Ev {
        let ch = self.of(Prog::Ch);
        assert_eq!(ch.len(), 1, "one closest-hit call: {:#?}", self.log);
        ch[0]
    }

    /// The primitives any-hit saw, sorted, each once.
    fn ah_prims(&self) -> Vec<u32> {
        let mut p: Vec<u32> = self.of(Prog::Ah).iter().map(|e| e.prim).collect();
        p.sort();
        p.dedup();
        p
    }

    fn payload(&self) -> [u32; 8] {
        self.payload.expect("the trace did not return")
    }

    /// The events but the any-hit calls, whose number and order depend on the traversal.
    fn ch_free(&self) -> Vec<Ev> {
        self.log
            .iter()
            .filter(|e| e.prog != Prog::Ah)
            .copied()
            .collect()
    }
}

/// The pipeline on one device, with its program groups by label.
struct Bi(LabelledPipeline);

impl std::ops::Deref for Bi {
    type Target = LabelledPipeline;

    fn deref(&self) -> &LabelledPipeline {
        &self.0
    }
}

impl Bi {
    fn new(device: &Device) -> Bi {
        let spec = PipelineSpec {
            source: BUILTINS,
            params: "bi",
            raygens: &[("rg", RAYGEN)],
            misses: &[MISS],
            hit_groups: &HIT_GROUPS,
            exception: ("ex", EXCEPTION),
            compile: PipelineCompileOptions {
                num_payload_values: 8,
                num_attribute_values: 2,
                uses_primitive_type_flags: types(),
                ..Default::default()
            },
            max_trace_depth: 1,
        };
        Bi(LabelledPipeline::new(device, &spec))
    }

    /// The SBT of `records` hit records of group `hit` (each record's data is its index) and
    /// the logging miss program (data 500).
    fn sbt(&self, hit: &str, records: usize) -> ShaderBindingTable {
        let hits: Vec<(oxray::SbtHeader, u32)> =
            (0..records as u32).map(|k| (self.header(hit), k)).collect();
        ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[self.header("rg")]),
            miss: SbtRegion::from_records(&[(self.header("ms_log"), 500u32)]),
            hitgroup: SbtRegion::from_records(&hits),
            exception: Some(SbtRegion::from_headers(&[self.header("ex")])),
            ..Default::default()
        }
    }

    /// Traces `rays` (one per launch index) against `handle` with hit group `hit` in
    /// `records` records.
    fn run(
        &self,
        hit: &str,
        records: usize,
        handle: u64,
        rays: &[RayIn],
    ) -> (Vec<Rec>, LaunchReport) {
        let d = &self.device;
        let out = d.create_buffer::<[u32; WORDS]>(rays.len()).unwrap();
        let ray_buf = d.buffer_from_slice(rays).unwrap();
        let params = BiParams {
            out: out.device_ptr(),
            handle,
            rays: ray_buf.device_ptr(),
        };
        let report = self
            .pipeline
            .launch_with(&params, &self.sbt(hit, records), rays.len() as u32, 1, 1)
            .unwrap_or_else(|e| panic!("{} launch: {e}", name(d)));
        let recs: Vec<Rec> = out.download().unwrap().iter().map(Rec::parse).collect();
        assert_eq!(report.exceptions, 0, "{}: {report:?}", name(d));
        (recs, report)
    }

    /// One ray through hit group `hit` in `records` records.
    fn one(&self, hit: &str, records: usize, handle: u64, ray: RayIn) -> Rec {
        self.run(hit, records, handle, &[ray]).0.remove(0)
    }
}

// ----------------------------------------------------------------------------------------------
// Geometry
// ----------------------------------------------------------------------------------------------

/// The built-in primitive types the scenarios run with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Sphere,
    Cubic,
    Ribbon,
}

const KINDS: [Kind; 3] = [Kind::Sphere, Kind::Cubic, Kind::Ribbon];

impl Kind {
    fn primitive_type(self) -> PrimitiveType {
        match self {
            Kind::Sphere => PrimitiveType::Sphere,
            Kind::Cubic => PrimitiveType::Curve(CurveType::RoundCubicBSpline),
            Kind::Ribbon => PrimitiveType::Curve(CurveType::FlatQuadraticBSpline),
        }
    }

    /// The hit kind of a front (`back == false`) or back face.
    fn hit_kind(self, back: bool) -> u32 {
        match self {
            Kind::Sphere => HitKind::SPHERE_FRONT_FACE.0 as u32,
            Kind::Cubic => HitKind::curve(CurveType::RoundCubicBSpline, back).0 as u32,
            Kind::Ribbon => HitKind::curve(CurveType::FlatQuadraticBSpline, back).0 as u32,
        }
    }
}

/// A primitive: a sphere of radius `r` centred at `c`, or a straight curve segment along x
/// through `c` from `c.x - 0.5` to `c.x + 0.5` of radius (a ribbon: half-width) `r`; a ribbon
/// faces +z if `up`, -z otherwise.
#[derive(Clone, Copy, Debug)]
struct Prim {
    c: Vec3,
    r: f32,
    up: bool,
}

fn prim(x: f32, z: f32, r: f32) -> Prim {
    Prim {
        c: Vec3::new(x, 0.0, z),
        r,
        up: true,
    }
}

/// Primitives of one kind in groups of one SBT record each: the records of a sphere input, or
/// one curve input per group. Primitive indices count over the groups in order from `base`;
/// the SBT-GAS index of a primitive is its group's.
#[derive(Clone, Debug)]
struct Scene {
    kind: Kind,
    groups: Vec<(GeometryFlags, Vec<Prim>)>,
    base: u32,
}

/// One segment's control points, radii and (ribbon) normals.
type Segment = (Vec<[f32; 3]>, Vec<f32>, Vec<[f32; 3]>);

impl Scene {
    fn new(kind: Kind, prims: &[Prim]) -> Scene {
        Scene {
            kind,
            groups: vec![(GeometryFlags::empty(), prims.to_vec())],
            base: 0,
        }
    }

    fn grouped(kind: Kind, groups: &[(GeometryFlags, &[Prim])]) -> Scene {
        Scene {
            kind,
            groups: groups.iter().map(|(f, p)| (*f, p.to_vec())).collect(),
            base: 0,
        }
    }

    fn prims(&self) -> Vec<Prim> {
        self.groups.iter().flat_map(|g| g.1.clone()).collect()
    }

    fn segment(&self, p: &Prim) -> Segment {
        let k = if self.kind == Kind::Cubic { 4 } else { 3 };
        // Uniform B-spline control points one apart: the segment spans [x - 0.5, x + 0.5].
        let first = if k == 4 { -1.5 } else { -1.0 };
        let points = (0..k)
            .map(|j| (p.c + Vec3::X * (first + j as f32)).to_array())
            .collect();
        let n = if p.up {
            [0.0, 0.0, 1.0]
        } else {
            [0.0, 0.0, -1.0]
        };
        (points, vec![p.r; k], vec![n; k])
    }

    /// Calls `f` with the build inputs of this scene.
    fn with_inputs<R>(&self, f: impl FnOnce(&[BuildInput<'_>]) -> R) -> R {
        if self.kind == Kind::Sphere {
            let prims = self.prims();
            let centres: Vec<[f32; 3]> = prims.iter().map(|p| p.c.to_array()).collect();
            let radii: Vec<f32> = prims.iter().map(|p| p.r).collect();
            let flags: Vec<GeometryFlags> = self.groups.iter().map(|g| g.0).collect();
            let offsets: Vec<u8> = (0u8..)
                .zip(&self.groups)
                .flat_map(|(k, g)| vec![k; g.1.len()])
                .collect();
            let (c, r) = (
                [bytemuck::cast_slice::<_, u8>(&centres)],
                [bytemuck::cast_slice::<_, u8>(&radii)],
            );
            let mut input = SphereInput::new(&c, prims.len() as u32, &r)
                .flags(&flags)
                .primitive_index_offset(self.base);
            if flags.len() > 1 {
                input = input.sbt_index_offsets(SbtIndexOffsets::u8(&offsets));
            }
            return f(&[input.into()]);
        }
        let ty = match self.kind {
            Kind::Cubic => CurveType::RoundCubicBSpline,
            _ => CurveType::FlatQuadraticBSpline,
        };
        // Per group: its strands' points, radii, normals and index.
        let bufs: Vec<Segment> = self
            .groups
            .iter()
            .map(|g| {
                let mut all: Segment = Default::default();
                for p in &g.1 {
                    let s = self.segment(p);
                    all.0.extend(s.0);
                    all.1.extend(s.1);
                    all.2.extend(s.2);
                }
                all
            })
            .collect();
        let k = ty.control_points() as u32;
        let index: Vec<Vec<u32>> = self
            .groups
            .iter()
            .map(|g| (0..g.1.len() as u32).map(|i| i * k).collect())
            .collect();
        type Refs<'a> = ([&'a [u8]; 1], [&'a [u8]; 1], [&'a [u8]; 1]);
        let refs: Vec<Refs<'_>> = bufs
            .iter()
            .map(|b| {
                (
                    [bytemuck::cast_slice::<_, u8>(&b.0)],
                    [bytemuck::cast_slice::<_, u8>(&b.1)],
                    [bytemuck::cast_slice::<_, u8>(&b.2)],
                )
            })
            .collect();
        let mut first = self.base;
        let mut inputs: Vec<BuildInput<'_>> = Vec::new();
        for ((g, r), ix) in self.groups.iter().zip(&refs).zip(&index) {
            // One any-hit call per segment and ray (§9.2), so that any-hit logs can be counted.
            let mut input = CurveInput::new(
                ty,
                &r.0,
                (g.1.len() as u32) * k,
                &r.1,
                bytemuck::cast_slice(ix),
                g.1.len() as u32,
            )
            .flag(g.0 | GeometryFlags::REQUIRE_SINGLE_ANYHIT_CALL)
            .endcaps(CurveEndcaps::Default)
            .primitive_index_offset(first);
            if self.kind == Kind::Ribbon {
                input = input.normals(&r.2, 0);
            }
            inputs.push(input.into());
            first += g.1.len() as u32;
        }
        f(&inputs)
    }

    fn build(&self, device: &Device) -> oxray::Gas {
        self.with_inputs(|inputs| {
            device
                .build_gas(&BuildOptions::default(), inputs)
                .unwrap_or_else(|e| panic!("{} {:?}: {e}", name(device), self.kind))
        })
    }

    /// Every primitive `ray` hits in its interval, nearest first, with the intersection test
    /// every backend uses: the candidates a traversal may offer.
    fn candidates(&self, ray: &Ray) -> Vec<Cand> {
        let mut out: Vec<Cand> = Vec::new();
        if self.kind == Kind::Sphere {
            for (p, i) in self.prims().iter().zip(self.base..) {
                let s = Sphere::new(p.c, p.r);
                if let Some(t) = s.intersect(ray.origin, ray.direction, ray.tmin, ray.tmax) {
                    out.push(Cand {
                        prim: i,
                        t,
                        u: 0.0,
                        v: 0.0,
                        back: false,
                    });
                }
            }
        } else {
            let data = self
                .with_inputs(|inputs| GasData::build(&BuildOptions::default(), inputs).unwrap());
            for (slot, s) in data.curves.iter().enumerate() {
                if let Some(h) = s.intersect(ray.origin, ray.direction, ray.tmin, ray.tmax) {
                    let prim = data.resolve(slot as u32).0;
                    if out.iter().all(|c| c.prim != prim) {
                        out.push(Cand {
                            prim,
                            t: h.t,
                            u: h.u,
                            v: h.v,
                            back: h.back_face,
                        });
                    }
                }
            }
        }
        out.sort_by(|a, b| a.t.total_cmp(&b.t));
        out
    }

    /// The candidate of primitive `prim` along `ray`.
    fn cand(&self, ray: &RayIn, prim: u32) -> Cand {
        self.candidates(&ray.ray())
            .into_iter()
            .find(|c| c.prim == prim)
            .unwrap_or_else(|| panic!("{:?}: the ray misses primitive {prim}", self.kind))
    }
}

/// A primitive's hit along a ray, as the host computes it.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Cand {
    prim: u32,
    t: f32,
    u: f32,
    v: f32,
    back: bool,
}

fn handle(gas: &oxray::Gas) -> u64 {
    gas.optix_handle().unwrap()
}

/// Checks that hit event `e` is candidate `c` of a primitive of `kind` (t, hit kind, type,
/// facing, curve parameters).
fn check_hit(kind: Kind, e: &Ev, c: &Cand, what: &str) {
    assert_eq!(e.prim, c.prim, "{kind:?} {what}: primitive");
    assert_eq!(e.tmax, c.t, "{kind:?} {what}: t of primitive {}", c.prim);
    assert_eq!(
        e.kind,
        kind.hit_kind(c.back),
        "{kind:?} {what}: hit kind of {}",
        c.prim
    );
    assert_eq!(e.ptype, kind.primitive_type().code(), "{kind:?} {what}");
    let facing = if c.back { 2 } else { 1 };
    assert_eq!(e.facing, facing, "{kind:?} {what}: facing, not a triangle");
    assert_eq!((e.u, e.v), (c.u, c.v), "{kind:?} {what}: curve parameters");
}

/// Primitives 0..4 stacked under the ray `RayIn::down(0.1, 0.05)`, at heights such that the
/// ray meets them in the order 1, 0, 3, 2 and each overlaps the next along it; ribbons 1 and 3
/// face away from the ray.
fn stack(kind: Kind) -> Scene {
    let r = if kind == Kind::Sphere { 0.6 } else { 0.4 };
    let mut p: Vec<Prim> = [-1.0, 0.0, -3.0, -2.0]
        .iter()
        .map(|&z| prim(0.0, z, r))
        .collect();
    p[1].up = false;
    p[3].up = false;
    Scene::new(kind, &p)
}

const STACK_RAY: (f32, f32) = (0.1, 0.05);

fn stack_ray() -> RayIn {
    RayIn::down(STACK_RAY.0, STACK_RAY.1)
}

// ----------------------------------------------------------------------------------------------
// Closest-hit selection (§13.4, §13.7)
// ----------------------------------------------------------------------------------------------

/// §13.4, §13.7, §9.3, §9.4: among primitives overlapping along a ray the closest-hit program
/// runs once, for the nearest: its t, primitive index, hit kind (a sphere's front face; a
/// ribbon's back face where it faces away), primitive type and curve parameters are the host's;
/// every any-hit call sees one of the candidates.
#[test]
fn s13_4_closest_hit_is_the_nearest_built_in_along_the_ray() {
    on_every_device(|device| {
        let t = Bi::new(device);
        let mut all = Vec::new();
        for kind in KINDS {
            let scene = stack(kind);
            let gas = scene.build(device);
            let ray = stack_ray();
            let cands = scene.candidates(&ray.ray());
            assert_eq!(
                cands.iter().map(|c| c.prim).collect::<Vec<_>>(),
                [1, 0, 3, 2],
                "{kind:?}: the scene"
            );
            let out = t.one("log", 1, handle(&gas), ray);
            let ch = out.ch();
            check_hit(kind, &ch, &cands[0], "closest hit");
            assert_eq!((ch.tmin, ch.gas_index, ch.data), (0.0, 0, 0));
            assert_eq!(out.count(Prog::Ms), 0);
            assert!(out.count(Prog::Ah) >= 1, "{kind:?}");
            for ah in out.of(Prog::Ah) {
                let c = cands.iter().find(|c| c.prim == ah.prim).unwrap();
                check_hit(kind, &ah, c, "any hit");
            }
            if kind == Kind::Ribbon {
                assert_eq!(ch.facing, 2, "ribbon 1 faces away from the ray");
                // v is y over the half-width, its sign the width direction's.
                assert!((ch.v.abs() - 0.125).abs() < 1e-4, "v = {}", ch.v);
            }
            if kind != Kind::Sphere {
                // Straight uniform segments: u is the position along the segment.
                assert!((ch.u - 0.6).abs() < 1e-3, "{kind:?}: u = {}", ch.u);
            }
            all.push(out.ch_free());
        }
        all
    });
}

/// A random scene: `n` primitives of `kind` in `[-3, 3]³` (curve segments along x, ribbons
/// facing either way).
fn random_scene(rng: &mut Rng, kind: Kind, n: usize) -> Scene {
    let prims: Vec<Prim> = (0..n)
        .map(|_| Prim {
            c: rng.vec3(-3.0, 3.0),
            r: rng.range(0.1, 0.6),
            up: rng.below(2) == 0,
        })
        .collect();
    Scene::new(kind, &prims)
}

/// §13.4, §13.7: over a few hundred random rays through random spheres, cubic B-splines and
/// ribbons, the closest-hit program sees what the CPU device's batched query finds (t,
/// primitive, hit kind, curve parameters), and misses run the miss program.
#[test]
fn s13_4_closest_hit_matches_the_query_over_random_rays() {
    let mut rng = Rng::new(0x13_4b);
    let cases: Vec<(Scene, Vec<RayIn>)> = KINDS
        .iter()
        .map(|&kind| {
            let scene = random_scene(&mut rng, kind, 40);
            let prims = scene.prims();
            let rays = (0..300)
                .map(|_| {
                    let o = rng.vec3(-6.0, 6.0);
                    let target = prims[rng.below(prims.len())].c + rng.vec3(-0.5, 0.5);
                    RayIn::new(o, target - o).interval(0.0, rng.range(2.0, 20.0))
                })
                .collect();
            (scene, rays)
        })
        .collect();
    on_every_device(|device| {
        let t = Bi::new(device);
        let cpu = Device::cpu();
        let mut all = Vec::new();
        for (scene, rays) in &cases {
            let kind = scene.kind;
            let gas = scene.build(device);
            let (out, _) = t.run("ch_only", 1, handle(&gas), rays);
            let reference = scene.build(&cpu);
            let queried: Vec<Ray> = rays.iter().map(RayIn::ray).collect();
            let mut hits = vec![None; rays.len()];
            cpu.intersect_closest(&reference.handle(), &queried, &mut hits)
                .unwrap();
            let mut found = 0;
            for (i, (o, h)) in out.iter().zip(&hits).enumerate() {
                let what = format!("{} ray {i}", name(device));
                match h {
                    Some(h) => {
                        found += 1;
                        let c = Cand {
                            prim: h.primitive_index,
                            t: h.t,
                            u: h.u,
                            v: h.v,
                            back: h.hit_kind.is_back_face(),
                        };
                        check_hit(kind, &o.ch(), &c, &what);
                        assert_eq!(o.count(Prog::Ms), 0, "{kind:?} {what}");
                    }
                    None => {
                        assert_eq!(o.count(Prog::Ch), 0, "{kind:?} {what}");
                        let ms = o.of(Prog::Ms);
                        assert_eq!(ms.len(), 1, "{kind:?} {what}");
                        assert_eq!((ms[0].tmax, ms[0].data), (rays[i].tmax, 500));
                    }
                }
            }
            assert!(found > 100, "{kind:?}: {found} hits");
            all.push(out);
        }
        all
    });
}

// ----------------------------------------------------------------------------------------------
// Ignore and terminate (§13.13)
// ----------------------------------------------------------------------------------------------

/// §13.13: an any-hit program that ignores the even primitives makes the nearest odd one the
/// closest; the ignored ones nearer than it are offered once each (one call per primitive: no
/// splitting) and do not shrink the interval. Code after `optixIgnoreIntersection` does not run
/// (on CUDA it does: the documented deviation).
#[test]
fn s13_13_ignore_intersection_on_built_ins() {
    on_every_device(|device| {
        let t = Bi::new(device);
        let mut all = Vec::new();
        for kind in KINDS {
            // Along the ray: 0, 2, 1, 3.
            let mut p: Vec<Prim> = [0.0, -2.0, -1.0, -3.0]
                .iter()
                .map(|&z| prim(0.0, z, 0.45))
                .collect();
            p[0].up = false;
            let scene = Scene::new(kind, &p);
            let gas = scene.build(device);
            let ray = stack_ray().ignoring(0b0101);
            let out = t.one("ignore", 1, handle(&gas), ray);
            check_hit(kind, &out.ch(), &scene.cand(&ray, 1), "closest hit");
            let ahs = out.of(Prog::Ah);
            for k in [0, 2] {
                let calls: Vec<&Ev> = ahs.iter().filter(|e| e.prim == k).collect();
                assert_eq!(
                    calls.len(),
                    1,
                    "{kind:?}: one call for ignored {k}: {ahs:#?}"
                );
                check_hit(kind, calls[0], &scene.cand(&ray, k), "ignored");
                assert_eq!(calls[0].tmin, 0.0);
            }
            let ignored = ahs.iter().filter(|e| e.prim % 2 == 0).count() as u32;
            let after = out.payload()[3];
            if code_after_runs(device) {
                assert_eq!(after, ignored, "{kind:?}");
            } else {
                assert_eq!(after, 0, "{kind:?}: code after optixIgnoreIntersection ran");
            }
            // Everything ignored: the miss program sees the whole interval.
            let none = t.one(
                "ignore",
                1,
                handle(&gas),
                ray.ignoring(0b1111).interval(1.0, 50.0),
            );
            assert_eq!(none.count(Prog::Ch), 0, "{kind:?}");
            let ms = none.of(Prog::Ms);
            assert_eq!(ms.len(), 1, "{kind:?}");
            assert_eq!(
                (ms[0].tmin, ms[0].tmax),
                (1.0, 50.0),
                "ignored hits keep tmax"
            );
            assert_eq!(
                none.ah_prims(),
                [0, 1, 2, 3],
                "{kind:?}: every candidate offered"
            );
            assert_eq!(none.count(Prog::Ah), 4, "{kind:?}: once each");
            all.push((out.ch(), none.ch_free(), none.ah_prims()));
        }
        all
    });
}

/// §13.13: `optixTerminateRay` accepts the candidate and ends the traversal: one any-hit call,
/// and the closest-hit program runs for that candidate (whichever the traversal offered first);
/// code after the call does not run (on CUDA it does: the documented deviation).
#[test]
fn s13_13_terminate_ray_on_built_ins() {
    on_every_device(|device| {
        let t = Bi::new(device);
        let mut all = Vec::new();
        for kind in KINDS {
            let scene = stack(kind);
            let gas = scene.build(device);
            let ray = stack_ray();
            let out = t.one("terminate", 1, handle(&gas), ray);
            let ahs = out.of(Prog::Ah);
            assert_eq!(
                ahs.len(),
                1,
                "{kind:?}: traversal ends at the first terminate"
            );
            let ch = out.ch();
            check_hit(kind, &ch, &scene.cand(&ray, ahs[0].prim), "terminating hit");
            assert_eq!(
                ch,
                Ev {
                    prog: Prog::Ch,
                    ..ahs[0]
                }
            );
            let after = out.payload()[4];
            let expected = if code_after_runs(device) { 0xAF7E } else { 0 };
            assert_eq!(after, expected, "{kind:?}: code after optixTerminateRay");
            // Where only one candidate lies in the interval the result is the same everywhere.
            let c3 = scene.cand(&ray, 3);
            let only = t.one(
                "terminate",
                1,
                handle(&gas),
                ray.interval(c3.t - 0.1, c3.t + 0.1),
            );
            check_hit(kind, &only.ch(), &c3, "the only candidate");
            assert_eq!(only.count(Prog::Ah), 1);
            all.push(only.log);
        }
        all
    });
}

// ----------------------------------------------------------------------------------------------
// Ray flags (§13.2)
// ----------------------------------------------------------------------------------------------

/// The scene of the ray-flag scenarios: primitives 0 and 1 in a record with any-hit, 2 and 3
/// in a record whose geometry flags disable it; along `stack_ray()` they come in the order 0,
/// 2, 1, 3. Ribbons 0 and 1 face away from the ray, ribbon 3 faces a ray up +z.
fn flag_scene(kind: Kind) -> Scene {
    let r = if kind == Kind::Sphere { 0.6 } else { 0.45 };
    let mut a = [prim(0.0, 0.0, r), prim(0.0, -2.0, r)];
    let mut b = [prim(0.0, -1.0, r), prim(0.0, -3.0, r)];
    a[0].up = false;
    a[1].up = false;
    b[1].up = false;
    Scene::grouped(
        kind,
        &[
            (GeometryFlags::empty(), &a),
            (GeometryFlags::DISABLE_ANYHIT, &b),
        ],
    )
}

/// §13.2, §5.1: DISABLE_ANYHIT and ENFORCE_ANYHIT against the geometry's any-hit flags,
/// CULL_DISABLED_ANYHIT and CULL_ENFORCED_ANYHIT, with spheres and curves as with triangles.
#[test]
fn s13_2_any_hit_ray_flags_on_built_ins() {
    on_every_device(|device| {
        let t = Bi::new(device);
        let mut all = Vec::new();
        for kind in KINDS {
            let scene = flag_scene(kind);
            let gas = scene.build(device);
            let h = handle(&gas);
            let ray = stack_ray();
            let run = |hit: &str, r: RayIn| t.one(hit, 2, h, r);
            let ch_of = |r: &Rec, prim: u32, what: &str| {
                let ch = r.ch();
                check_hit(kind, &ch, &scene.cand(&ray, prim), what);
                assert_eq!(
                    (ch.gas_index, ch.data),
                    (prim / 2, prim / 2),
                    "{kind:?} {what}"
                );
            };
            // No flags: any-hit runs for the first record only.
            let plain = run("log", ray);
            ch_of(&plain, 0, "no flags");
            assert!(plain.ah_prims().contains(&0), "{kind:?}");
            assert!(
                plain.ah_prims().iter().all(|&p| p < 2),
                "{kind:?}: {plain:#?}"
            );
            let disabled = run("log", ray.flags(RayFlags::DISABLE_ANYHIT));
            ch_of(&disabled, 0, "DISABLE_ANYHIT");
            assert_eq!(disabled.count(Prog::Ah), 0, "{kind:?}");
            // Ignoring 0 and 2: 2 is opaque without ENFORCE_ANYHIT, ignored with it.
            let ign = ray.ignoring(0b0101);
            let opaque = run("ignore", ign);
            ch_of(&opaque, 2, "2 is opaque");
            seen(kind, &opaque, &[0], &[1]);
            let enforced = run("ignore", ign.flags(RayFlags::ENFORCE_ANYHIT));
            ch_of(&enforced, 1, "ENFORCE_ANYHIT");
            seen(kind, &enforced, &[0, 1, 2], &[3]);
            // The culling flags remove a record's primitives altogether.
            let cull_disabled = run(
                "ignore",
                ray.ignoring(0b0001).flags(RayFlags::CULL_DISABLED_ANYHIT),
            );
            ch_of(&cull_disabled, 1, "CULL_DISABLED_ANYHIT");
            assert_eq!(cull_disabled.ah_prims(), [0, 1], "{kind:?}");
            let cull_enforced = run("log", ray.flags(RayFlags::CULL_ENFORCED_ANYHIT));
            ch_of(&cull_enforced, 2, "CULL_ENFORCED_ANYHIT");
            assert_eq!(cull_enforced.count(Prog::Ah), 0, "{kind:?}");
            let both = run(
                "log",
                ray.flags(RayFlags::CULL_ENFORCED_ANYHIT | RayFlags::CULL_DISABLED_ANYHIT),
            );
            assert_eq!(both.count(Prog::Ch), 0, "{kind:?}: every primitive culled");
            assert_eq!(both.count(Prog::Ms), 1, "{kind:?}");
            all.push(
                [
                    plain,
                    disabled,
                    opaque,
                    enforced,
                    cull_disabled,
                    cull_enforced,
                    both,
                ]
                .map(|r| r.ch_free()),
            );
        }
        all
    });
}

/// §13.2: TERMINATE_ON_FIRST_HIT ends the traversal at the first accepted candidate, which is
/// the closest hit; DISABLE_CLOSESTHIT runs neither closest-hit nor miss on a hit (any-hit still
/// runs) and the miss program on a miss; CULL_BACK_FACING_TRIANGLES and
/// CULL_FRONT_FACING_TRIANGLES cull no sphere or curve, not even a ribbon's back face (§9.6).
#[test]
fn s13_2_trace_ray_flags_on_built_ins() {
    on_every_device(|device| {
        let t = Bi::new(device);
        let mut all = Vec::new();
        for kind in KINDS {
            let scene = flag_scene(kind);
            let gas = scene.build(device);
            let h = handle(&gas);
            let ray = stack_ray();
            let run = |hit: &str, r: RayIn| t.one(hit, 2, h, r);
            // The first accepted candidate is of the second record (any-hit ignores the first).
            let first = run(
                "ignore",
                ray.ignoring(0b0011).flags(RayFlags::TERMINATE_ON_FIRST_HIT),
            );
            let ch = first.ch();
            assert!(ch.prim == 2 || ch.prim == 3, "{kind:?}: {ch:?}");
            check_hit(
                kind,
                &ch,
                &scene.cand(&ray, ch.prim),
                "TERMINATE_ON_FIRST_HIT",
            );
            assert!(first.ah_prims().iter().all(|&p| p < 2), "{kind:?}");
            let logged = run("log", ray.flags(RayFlags::TERMINATE_ON_FIRST_HIT));
            let ahs = logged.of(Prog::Ah);
            assert!(
                ahs.len() <= 1,
                "{kind:?}: traversal ends at the first accepted hit"
            );
            if let Some(ah) = ahs.first() {
                assert_eq!(
                    logged.ch(),
                    Ev {
                        prog: Prog::Ch,
                        ..*ah
                    }
                );
            }
            // Within an interval that holds only primitive 1, it is the first and the closest.
            let c1 = scene.cand(&ray, 1);
            let only = run(
                "log",
                ray.interval(c1.t - 0.05, c1.t + 0.05)
                    .flags(RayFlags::TERMINATE_ON_FIRST_HIT),
            );
            check_hit(
                kind,
                &only.ch(),
                &c1,
                "TERMINATE_ON_FIRST_HIT, one candidate",
            );
            // DISABLE_CLOSESTHIT.
            let no_ch = run("log", ray.flags(RayFlags::DISABLE_CLOSESTHIT));
            assert_eq!(no_ch.count(Prog::Ch), 0, "{kind:?}");
            assert_eq!(
                no_ch.count(Prog::Ms),
                0,
                "{kind:?}: a hit runs no miss program"
            );
            assert!(
                no_ch.ah_prims().contains(&0),
                "{kind:?}: any-hit still runs"
            );
            assert!(no_ch.payload.is_some());
            let far = RayIn::down(20.0, 0.0).flags(RayFlags::DISABLE_CLOSESTHIT);
            let missed = run("log", far);
            assert_eq!(
                missed.count(Prog::Ms),
                1,
                "{kind:?}: a miss runs the miss program"
            );
            // The triangle culling flags, from above and from below.
            let plain = run("ch_only", ray);
            let up = RayIn::new(Vec3::new(STACK_RAY.0, STACK_RAY.1, -10.0), Vec3::Z);
            let plain_up = run("ch_only", up);
            for faces in [
                RayFlags::CULL_BACK_FACING_TRIANGLES,
                RayFlags::CULL_FRONT_FACING_TRIANGLES,
                RayFlags::CULL_BACK_FACING_TRIANGLES | RayFlags::CULL_FRONT_FACING_TRIANGLES,
            ] {
                assert_eq!(
                    run("ch_only", ray.flags(faces)),
                    plain,
                    "{kind:?} {faces:?}"
                );
                assert_eq!(
                    run("ch_only", up.flags(faces)),
                    plain_up,
                    "{kind:?} {faces:?}"
                );
            }
            ch_of_stack(kind, &scene, &plain, &ray, 0);
            ch_of_stack(kind, &scene, &plain_up, &up, 3);
            if kind == Kind::Ribbon {
                // Ribbon 0 faces away from the downward ray, ribbon 3 faces the upward one.
                assert_eq!((plain.ch().facing, plain_up.ch().facing), (2, 1));
            }
            // Which candidate comes first depends on the traversal: not compared.
            all.push((only.ch_free(), no_ch.ch_free(), missed.log, plain, plain_up));
        }
        all
    });
}

/// Checks that any-hit saw every primitive of `must`, perhaps those of `may` (farther than the
/// closest hit: whether they are offered depends on the traversal order), and no other.
fn seen(kind: Kind, rec: &Rec, must: &[u32], may: &[u32]) {
    let ah = rec.ah_prims();
    assert!(must.iter().all(|p| ah.contains(p)), "{kind:?}: {ah:?}");
    assert!(
        ah.iter().all(|p| must.contains(p) || may.contains(p)),
        "{kind:?}: {ah:?}"
    );
}

fn ch_of_stack(kind: Kind, scene: &Scene, rec: &Rec, ray: &RayIn, prim: u32) {
    check_hit(kind, &rec.ch(), &scene.cand(ray, prim), "unculled");
}

// ----------------------------------------------------------------------------------------------
// The SBT index (§7.3)
// ----------------------------------------------------------------------------------------------

/// Three SBT records, primitive indices from 100: spheres 100 and 101 use record 0, 102 record
/// 1 and 103 record 2 (SBT index offsets of one input); curves are three inputs of 2, 1 and 1
/// segments. Primitive `100 + k` lies under `(3k, 0)`.
fn sbt_scene(kind: Kind) -> Scene {
    let p: Vec<Prim> = (0..4).map(|k| prim(3.0 * k as f32, 0.0, 0.45)).collect();
    let none = GeometryFlags::empty();
    let mut s = Scene::grouped(kind, &[(none, &p[..2]), (none, &p[2..3]), (none, &p[3..])]);
    s.base = 100;
    s
}

/// §7.3: the hit record is the instance's SBT offset plus the trace's SBT offset plus its
/// stride times the SBT-GAS index, which is a sphere's SBT index offset or a curve's build
/// input; any-hit and closest-hit see the same record; primitive indices carry the inputs'
/// offsets (§13.7).
#[test]
fn s7_3_sbt_index_of_built_ins() {
    on_every_device(|device| {
        let t = Bi::new(device);
        let mut all = Vec::new();
        for kind in KINDS {
            let scene = sbt_scene(kind);
            let gas = scene.build(device);
            let ias = device
                .build_ias(
                    &BuildOptions::default(),
                    &[(&[Instance::new(gas.handle()).sbt_offset(5)][..]).into()],
                )
                .unwrap();
            let rays: Vec<RayIn> = (0..4)
                .map(|k| RayIn::down(3.0 * k as f32 + 0.1, 0.05).sbt(1, 3))
                .collect();
            let gas_index = [0, 0, 1, 2];
            for (h, instance_offset) in [(handle(&gas), 0), (ias.optix_handle().unwrap(), 5)] {
                let (out, _) = t.run("log", 13, h, &rays);
                for (k, o) in out.iter().enumerate() {
                    let ch = o.ch();
                    let g = gas_index[k];
                    check_hit(kind, &ch, &scene.cand(&rays[k], 100 + k as u32), "SBT");
                    assert_eq!(ch.gas_index, g, "{kind:?} primitive {k}");
                    let record = instance_offset + 1 + 3 * g;
                    assert_eq!(ch.data, record, "{kind:?} primitive {k}: the record");
                    // One candidate per ray, so any-hit runs once: the logs compare across devices.
                    assert_eq!(o.count(Prog::Ah), 1, "{kind:?} primitive {k}");
                    for ah in o.of(Prog::Ah) {
                        assert_eq!((ah.prim, ah.data), (ch.prim, record), "{kind:?}");
                    }
                }
                all.push(out);
            }
        }
        all
    });
}

// ----------------------------------------------------------------------------------------------
// Instances (§5.4, §13.7)
// ----------------------------------------------------------------------------------------------

/// An IAS over a sphere GAS (one sphere of radius 0.5 whose geometry flags disable any-hit;
/// instance 1: id 7, mask 1, moved to z = -3, hit record 0) and a cubic B-spline GAS (one
/// segment of radius 0.4; instance 0: id 9, mask 2, SBT offset 1, moved to z = -1, nearer to a
/// ray down).
struct Pair {
    sphere: Scene,
    curve: Scene,
}

impl Pair {
    fn new() -> Pair {
        Pair {
            sphere: Scene::grouped(
                Kind::Sphere,
                &[(GeometryFlags::DISABLE_ANYHIT, &[prim(0.0, 0.0, 0.5)])],
            ),
            curve: Scene::new(Kind::Cubic, &[prim(0.0, 0.0, 0.4)]),
        }
    }

    /// The IAS with the instance flags `curve` and `sphere`, and the GASes it holds.
    fn build(
        &self,
        device: &Device,
        curve: InstanceFlags,
        sphere: InstanceFlags,
    ) -> (oxray::Ias, [oxray::Gas; 2]) {
        let (c, s) = (self.curve.build(device), self.sphere.build(device));
        let at = |z: f32| Transform::from_translation(Vec3::new(0.0, 0.0, z));
        let instances = [
            Instance::new(c.handle())
                .instance_id(9)
                .visibility_mask(2)
                .sbt_offset(1)
                .transform(at(-1.0))
                .flags(curve),
            Instance::new(s.handle())
                .instance_id(7)
                .visibility_mask(1)
                .transform(at(-3.0))
                .flags(sphere),
        ];
        let ias = device
            .build_ias(&BuildOptions::default(), &[(&instances[..]).into()])
            .unwrap();
        (ias, [c, s])
    }
}

/// §5.4, §13.7, §13.2: the ray's visibility mask selects the instances of an IAS over a sphere
/// GAS and a curve GAS; programs see the instance's id and index and the object-space ray; the
/// instance flags DISABLE_ANYHIT and ENFORCE_ANYHIT override the geometry flags and yield to
/// the ray's.
#[test]
fn s5_4_masks_and_instance_flags_over_spheres_and_curves() {
    let pair = Pair::new();
    on_every_device(|device| {
        let t = Bi::new(device);
        let none = InstanceFlags::empty();
        let ray = stack_ray();
        // The hits in object space: the instances only move the ray's origin.
        let object = |z: f32| {
            let mut r = ray;
            r.origin[2] -= z;
            r
        };
        let curve_hit = |e: &Ev| {
            check_hit(Kind::Cubic, e, &pair.curve.cand(&object(-1.0), 0), "curve");
            assert_eq!((e.instance_id, e.instance_index, e.data), (9, 0, 1));
            assert_eq!(e.object_origin_xz, [0.1, 11.0], "object-space origin");
            assert_eq!(e.object_dir_z, -1.0);
        };
        let sphere_hit = |e: &Ev| {
            check_hit(
                Kind::Sphere,
                e,
                &pair.sphere.cand(&object(-3.0), 0),
                "sphere",
            );
            assert_eq!((e.instance_id, e.instance_index, e.data), (7, 1, 0));
            assert_eq!(e.object_origin_xz, [0.1, 13.0], "object-space origin");
        };
        let (ias, _gas) = pair.build(device, none, none);
        let h = ias.optix_handle().unwrap();
        let mut all = Vec::new();
        for (mask, want) in [(0xFF, Some(9)), (1, Some(7)), (2, Some(9)), (4, None)] {
            let out = t.one("log", 2, h, ray.mask(mask));
            match want {
                Some(9) => curve_hit(&out.ch()),
                Some(_) => sphere_hit(&out.ch()),
                None => assert_eq!(out.count(Prog::Ms), 1, "mask {mask}"),
            }
            all.push(out.ch_free());
        }
        let ignore_all = ray.ignoring(!0);
        // The curve is ignored; the sphere's geometry flags make it opaque.
        let out = t.one("ignore", 2, h, ignore_all);
        sphere_hit(&out.ch());
        let ahs = out.of(Prog::Ah);
        assert_eq!(ahs.len(), 1, "{ahs:#?}");
        curve_hit(&ahs[0]);
        all.push(out.log);
        // The instance disables the curve's any-hit: it is opaque.
        let (ias, _gas) = pair.build(device, InstanceFlags::DISABLE_ANYHIT, none);
        let out = t.one("ignore", 2, ias.optix_handle().unwrap(), ignore_all);
        curve_hit(&out.ch());
        assert_eq!(out.count(Prog::Ah), 0);
        all.push(out.log);
        // The instance enforces the sphere's any-hit over its geometry flags: both ignored.
        let (ias, _gas) = pair.build(device, none, InstanceFlags::ENFORCE_ANYHIT);
        let h = ias.optix_handle().unwrap();
        let out = t.one("ignore", 2, h, ignore_all);
        assert_eq!(out.count(Prog::Ch), 0);
        assert_eq!(out.count(Prog::Ms), 1);
        let mut ahs = out.of(Prog::Ah);
        ahs.sort_by_key(|e| e.instance_index);
        assert_eq!(ahs.len(), 2, "{ahs:#?}");
        curve_hit(&ahs[0]);
        sphere_hit(&ahs[1]);
        all.push(ahs);
        // The ray's DISABLE_ANYHIT wins over the instance's ENFORCE_ANYHIT.
        let out = t.one("ignore", 2, h, ignore_all.flags(RayFlags::DISABLE_ANYHIT));
        curve_hit(&out.ch());
        assert_eq!(out.count(Prog::Ah), 0);
        all.push(out.log);
        all
    });
}

// ----------------------------------------------------------------------------------------------
// The shrinking interval (§13.4, §13.5)
// ----------------------------------------------------------------------------------------------

/// §13.4, §13.5: any-hit sees `optixGetRayTmax()` as the candidate's t; once a candidate is
/// accepted, no farther one is offered, so the candidates any-hit sees come nearer and nearer
/// and the last is the closest hit; candidates outside the ray's interval are never offered.
#[test]
fn s13_5_any_hit_sees_the_shrinking_interval_on_built_ins() {
    on_every_device(|device| {
        let t = Bi::new(device);
        let mut all = Vec::new();
        for kind in KINDS {
            let scene = stack(kind);
            let gas = scene.build(device);
            let h = handle(&gas);
            let ray = stack_ray();
            let cands = scene.candidates(&ray.ray());
            let out = t.one("log", 1, h, ray);
            let ahs = out.of(Prog::Ah);
            for ah in &ahs {
                let c = cands.iter().find(|c| c.prim == ah.prim).unwrap();
                check_hit(kind, ah, c, "any hit");
                assert_eq!(ah.tmin, 0.0);
            }
            for w in ahs.windows(2) {
                assert!(w[1].tmax < w[0].tmax, "{kind:?}: {ahs:#?}");
            }
            assert_eq!(ahs.last().unwrap().prim, cands[0].prim, "{kind:?}");
            check_hit(kind, &out.ch(), &cands[0], "closest hit");
            // An interval from past the nearest candidate's entry to past primitive 3's: 0 is
            // the closest hit, 2 is never offered, 1 (entered before tmin) neither.
            let (c1, c3) = (scene.cand(&ray, 1), scene.cand(&ray, 3));
            let cut = ray.interval(c1.t + 0.05, c3.t + 0.05);
            let out = t.one("log", 1, h, cut);
            check_hit(
                kind,
                &out.ch(),
                &scene.cand(&cut, 0),
                "closest in the interval",
            );
            seen(kind, &out, &[0], &[3]);
            for ah in out.of(Prog::Ah) {
                assert_eq!(ah.tmin, cut.tmin, "{kind:?}");
                assert!(ah.tmax <= cut.tmax, "{kind:?}");
            }
            all.push(out.ch_free());
        }
        all
    });
}

/// Every program of builtins.cu compiles for the GPU with NVRTC, GPU or not.
#[test]
fn the_builtin_conformance_programs_compile_with_nvrtc() {
    use oxray::cuda::{CudaHitGroupDesc, CudaModule, CudaProgramGroup};
    let m = CudaModule::from_source(BUILTINS);
    let e = |n: Option<&'static str>| n.map(|n| (&m, n));
    let mut groups = vec![
        CudaProgramGroup::raygen(&m, RAYGEN).unwrap(),
        CudaProgramGroup::miss(Some((&m, MISS.1))).unwrap(),
    ];
    for (label, ch, ah, is) in HIT_GROUPS {
        let g = CudaProgramGroup::hit_group(CudaHitGroupDesc {
            closest_hit: e(ch),
            any_hit: e(ah),
            intersection: e(is),
        });
        groups.push(g.unwrap_or_else(|e| panic!("{label}: {e}")));
    }
    groups.push(CudaProgramGroup::exception(&m, EXCEPTION).unwrap());
    common::assert_compiles_with_nvrtc("the built-in conformance programs", &groups, types());
}
