//! CUDA C++ twins of the Rust-closure pipeline tests (issue: programs on the GPU). The scenarios
//! of pipeline_trace.rs and pipeline_exceptions.rs that conformance.rs had no CUDA C++
//! counterpart for are written again here against the OptiX device API (programs in
//! conformance/twins.cu) and run on every device present: the CPU always (its programs compiled
//! by the host's C++ compiler) and a CUDA device where there is one (`OXRAY_REQUIRE_GPU=1` makes
//! its absence a failure). Each device must give the values the Rust-closure original asserts,
//! and all devices the same records.
//!
//! Covered: the null handle (§13.2), the closed interval for triangles and custom primitives
//! (§13.2, §13.4), closest-hit selection and the shrinking interval (§13.4, §13.5), tmin and tmax
//! as each program sees them (§13.5), ignore and terminate (§13.13), `TERMINATE_ON_FIRST_HIT`,
//! `DISABLE_CLOSESTHIT`, any-hit enablement on custom primitives, face culling and
//! `DISABLE_TRIANGLE_FACE_CULLING`, `CULL_DISABLED_ANYHIT` / `CULL_ENFORCED_ANYHIT` (§13.2), the
//! ray queries (§13.5), and trace-depth exceptions by recursion (§13.14).
//!
//! Every launch index traces one ray described by a [`RayIn`] record, and every program logs
//! what it saw (program, primitive, tmin, tmax, hit kind, attributes) in the launch index's
//! record, like the event log of the Rust-closure tests (pipeline_common/mod.rs).

mod common;

use common::{code_after_runs, name, on_every_device, HitSpec, LabelledPipeline, PipelineSpec};
use glam::Vec3;
use oxray::{
    Aabb, AabbBuffer, BuildInput, BuildOptions, CustomPrimitiveInput, Device, ExceptionCode,
    GeometryFlags, LaunchReport, PipelineCompileOptions, RayFlags, SbtRegion, ShaderBindingTable,
    TriangleInput, VertexBuffer,
};
use oxray_testkit::mesh::{soup, tri_at, Tri};

const TWINS: &str = include_str!("conformance/twins.cu");

/// Words of a launch index's record (`TWIN_WORDS` in twins.cu), where its events and notes
/// start, and how many of each fit.
const WORDS: usize = 512;
const EVENTS_AT: usize = 16;
const MAX_EVENTS: usize = 48;
const NOTES_AT: usize = 400;
const MAX_NOTES: usize = 112;

const CH: Option<&str> = Some("__closesthit__log");
const AH: Option<&str> = Some("__anyhit__log");
const IS_TOP: Option<&str> = Some("__intersection__top");

const HIT_GROUPS: [HitSpec; 18] = [
    ("log", CH, AH, IS_TOP),
    ("log_tri", CH, AH, None),
    ("ch_only", CH, None, None),
    ("edges", CH, AH, Some("__intersection__edges")),
    ("two", CH, AH, Some("__intersection__two")),
    ("ignore_top", CH, Some("__anyhit__ignore_top"), None),
    ("ignore_all", CH, Some("__anyhit__ignore_all"), None),
    (
        "terminate_bottom",
        CH,
        Some("__anyhit__terminate_bottom"),
        None,
    ),
    (
        "terminate_first",
        CH,
        Some("__anyhit__terminate_first"),
        None,
    ),
    (
        "terminate_custom",
        CH,
        Some("__anyhit__terminate_first"),
        IS_TOP,
    ),
    ("only_3", CH, Some("__anyhit__only_3"), None),
    ("two_reports", CH, AH, Some("__intersection__two_reports")),
    ("centre", CH, None, Some("__intersection__centre")),
    (
        "write",
        CH,
        Some("__anyhit__write"),
        Some("__intersection__write"),
    ),
    ("mark", CH, AH, Some("__intersection__mark")),
    (
        "ray",
        Some("__closesthit__ray"),
        Some("__anyhit__ray"),
        Some("__intersection__ray"),
    ),
    ("recurse", Some("__closesthit__recurse"), AH, None),
    ("once", Some("__closesthit__once"), AH, None),
];

const RAYGEN: &str = "__raygen__twin";
const MISSES: [(&str, &str); 4] = [
    ("ms_log", "__miss__log"),
    ("ms_ray", "__miss__ray"),
    ("ms_recurse", "__miss__recurse"),
    ("ms_ten", "__miss__ten"),
];
const EXCEPTION: &str = "__exception__note";

/// A ray of one launch index (`RayIn` in twins.cu).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct RayIn {
    origin: [f32; 3],
    dir: [f32; 3],
    tmin: f32,
    tmax: f32,
    time: f32,
    mask: u32,
    flags: u32,
    sbt_offset: u32,
    sbt_stride: u32,
    miss_index: u32,
    payload: [u32; 8],
    pad: [u32; 2],
}

impl RayIn {
    fn new(origin: Vec3, dir: Vec3) -> RayIn {
        RayIn {
            origin: origin.to_array(),
            dir: dir.to_array(),
            tmin: 0.0,
            tmax: f32::INFINITY,
            time: 0.0,
            mask: 0xFF,
            flags: 0,
            sbt_offset: 0,
            sbt_stride: 1,
            miss_index: 0,
            payload: [0; 8],
            pad: [0; 2],
        }
    }

    /// Down -z from `(x, y, 10)`, like `RayDesc::down`.
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

    fn payload(mut self, p: &[u32]) -> RayIn {
        self.payload[..p.len()].copy_from_slice(p);
        self
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct TwinParams {
    out: u64,
    handle: u64,
    rays: u64,
    boxes: u64,
}

/// Which program logged an event.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Prog {
    Is,
    Ah,
    Ch,
    Ms,
}

/// What one program saw.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Ev {
    prog: Prog,
    prim: u32,
    tmin: f32,
    tmax: f32,
    kind: u32,
    attrs: [u32; 2],
    instance_id: u32,
}

/// What one launch index did: the payload after the trace (if it returned), the events in
/// order and the notes.
#[derive(Clone, Debug, PartialEq)]
struct Rec {
    payload: Option<[u32; 8]>,
    log: Vec<Ev>,
    notes: Vec<u32>,
}

impl Rec {
    fn parse(w: &[u32; WORDS]) -> Rec {
        let n = w[8] as usize;
        assert!(n <= MAX_EVENTS, "{n} events: the record keeps {MAX_EVENTS}");
        let log = (0..n)
            .map(|k| {
                let e = &w[EVENTS_AT + 8 * k..EVENTS_AT + 8 * k + 8];
                Ev {
                    prog: match e[0] {
                        1 => Prog::Is,
                        2 => Prog::Ah,
                        3 => Prog::Ch,
                        4 => Prog::Ms,
                        p => panic!("event {k}: no program {p}"),
                    },
                    prim: e[1],
                    tmin: f32::from_bits(e[2]),
                    tmax: f32::from_bits(e[3]),
                    kind: e[4],
                    attrs: [e[5], e[6]],
                    instance_id: e[7],
                }
            })
            .collect();
        let m = w[9] as usize;
        assert!(m <= MAX_NOTES, "{m} notes: the record keeps {MAX_NOTES}");
        let mut payload = [0u32; 8];
        payload.copy_from_slice(&w[..8]);
        Rec {
            payload: (w[10] == 1).then_some(payload),
            log,
            notes: w[NOTES_AT..NOTES_AT + m].to_vec(),
        }
    }

    fn of(&self, p: Prog) -> Vec<Ev> {
        self.log.iter().filter(|e| e.prog == p).copied().collect()
    }

    fn count(&self, p: Prog) -> usize {
        self.log.iter().filter(|e| e.prog == p).count()
    }

    fn progs(&self) -> Vec<Prog> {
        self.log.iter().map(|e| e.prog).collect()
    }

    /// The only closest-hit event.
    fn ch(&self) -> Ev {
        let ch = self.of(Prog::Ch);
        assert_eq!(ch.len(), 1, "one closest-hit call: {:#?}", self.log);
        ch[0]
    }

    fn payload(&self) -> [u32; 8] {
        self.payload.expect("the trace did not return")
    }

    fn notes_f32(&self) -> Vec<f32> {
        self.notes.iter().map(|w| f32::from_bits(*w)).collect()
    }
}

/// The twins' pipeline on one device, with its program groups by label.
struct Twins(LabelledPipeline);

impl std::ops::Deref for Twins {
    type Target = LabelledPipeline;

    fn deref(&self) -> &LabelledPipeline {
        &self.0
    }
}

impl Twins {
    fn new(device: &Device, max_trace_depth: u32) -> Twins {
        let spec = PipelineSpec {
            source: TWINS,
            params: "twin",
            raygens: &[("rg", RAYGEN)],
            misses: &MISSES,
            hit_groups: &HIT_GROUPS,
            exception: ("ex", EXCEPTION),
            compile: PipelineCompileOptions {
                num_payload_values: 8,
                num_attribute_values: 2,
                ..Default::default()
            },
            max_trace_depth,
        };
        Twins(LabelledPipeline::new(device, &spec))
    }

    /// The SBT of the hit records `hits` and miss records `misses` (each record's data is its
    /// index) and, if `exception`, the noting exception program.
    fn sbt(&self, hits: &[&str], misses: &[&str], exception: bool) -> ShaderBindingTable {
        let records = |l: &[&str]| {
            l.iter()
                .zip(0u32..)
                .map(|(g, k)| (self.header(g), k))
                .collect::<Vec<_>>()
        };
        ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[self.header("rg")]),
            miss: SbtRegion::from_records(&records(misses)),
            hitgroup: SbtRegion::from_records(&records(hits)),
            exception: exception.then(|| SbtRegion::from_headers(&[self.header("ex")])),
            ..Default::default()
        }
    }

    /// Traces `rays` (one per launch index) against `handle`; `boxes` are the custom
    /// primitives' boxes by primitive index.
    fn run(
        &self,
        sbt: &ShaderBindingTable,
        handle: u64,
        rays: &[RayIn],
        boxes: &[Aabb],
    ) -> (Vec<Rec>, LaunchReport) {
        let d = &self.device;
        let out = d.create_buffer::<[u32; WORDS]>(rays.len()).unwrap();
        let ray_buf = d.buffer_from_slice(rays).unwrap();
        let mut b: Vec<[f32; 6]> = boxes
            .iter()
            .map(|b| [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z])
            .collect();
        b.push([0.0; 6]);
        let box_buf = d.buffer_from_slice(&b).unwrap();
        let params = TwinParams {
            out: out.device_ptr(),
            handle,
            rays: ray_buf.device_ptr(),
            boxes: box_buf.device_ptr(),
        };
        let report = self
            .pipeline
            .launch_with(&params, sbt, rays.len() as u32, 1, 1)
            .unwrap_or_else(|e| panic!("{} launch: {e}", name(d)));
        let recs = out.download().unwrap().iter().map(Rec::parse).collect();
        (recs, report)
    }

    /// One ray through hit group `hit` (two records, like the Rust-closure tests' setup) and
    /// the logging miss program.
    fn one(&self, hit: &str, handle: u64, ray: RayIn, boxes: &[Aabb]) -> Rec {
        let sbt = self.sbt(&[hit, hit], &["ms_log"], false);
        let (mut recs, report) = self.run(&sbt, handle, &[ray], boxes);
        assert_eq!(report.exceptions, 0, "{report:?}");
        recs.remove(0)
    }
}

// ----------------------------------------------------------------------------------------------
// Geometry, as in pipeline_trace.rs
// ----------------------------------------------------------------------------------------------

fn cube(c: Vec3, h: f32) -> Aabb {
    Aabb::new(c - Vec3::splat(h), c + Vec3::splat(h))
}

/// Triangles stacked under `(0, 0)` (primitive `i` at `zs[i]`), each shifted a little in x.
fn stack_tris(zs: &[f32]) -> Vec<Tri> {
    zs.iter()
        .enumerate()
        .map(|(i, &z)| tri_at(0.01 * i as f32, 0.005 * i as f32, z, 1.0))
        .collect()
}

fn tri_gas_flags(device: &Device, tris: &[Tri], flags: GeometryFlags) -> oxray::Gas {
    let v = soup(tris);
    let f = [flags];
    let input = TriangleInput::new(VertexBuffer::f32x3(&v)).flags(&f);
    device
        .build_gas(&BuildOptions::default(), &[input.into()])
        .unwrap()
}

fn tri_gas(device: &Device, tris: &[Tri]) -> oxray::Gas {
    tri_gas_flags(device, tris, GeometryFlags::empty())
}

fn box_gas(device: &Device, boxes: &[Aabb]) -> oxray::Gas {
    let f = [GeometryFlags::empty()];
    let input = CustomPrimitiveInput::new(AabbBuffer::new(boxes)).flags(&f);
    device
        .build_gas(&BuildOptions::default(), &[input.into()])
        .unwrap()
}

/// Boxes stacked under `(0, 0)` at the given heights, half-size 0.5.
fn box_stack(zs: &[f32]) -> Vec<Aabb> {
    zs.iter()
        .map(|&z| cube(Vec3::new(0.0, 0.0, z), 0.5))
        .collect()
}

fn handle(gas: &oxray::Gas) -> u64 {
    gas.optix_handle().unwrap()
}

fn next_up(x: f32) -> f32 {
    f32::from_bits(x.to_bits() + 1)
}

fn next_down(x: f32) -> f32 {
    f32::from_bits(x.to_bits() - 1)
}

/// A GAS of two single-record inputs: primitive 0 around `(0, 0, 0)` with `f0`, primitive 1
/// around `(x1, 0, z1)` with `f1` (SBT-GAS indices 0 and 1), triangles or boxes; and the boxes.
fn two_inputs(
    device: &Device,
    custom: bool,
    f0: GeometryFlags,
    f1: GeometryFlags,
    x1: f32,
    z1: f32,
) -> (oxray::Gas, Vec<Aabb>) {
    let (fa, fb) = ([f0], [f1]);
    let b0 = [cube(Vec3::ZERO, 0.5)];
    let b1 = [cube(Vec3::new(x1, 0.0, z1), 0.5)];
    let v0 = soup(&[tri_at(0.0, 0.0, 0.0, 1.0)]);
    let v1 = soup(&[tri_at(x1, 0.0, z1, 1.0)]);
    let inputs: [BuildInput; 2] = if custom {
        [
            CustomPrimitiveInput::new(AabbBuffer::new(&b0))
                .flags(&fa)
                .into(),
            CustomPrimitiveInput::new(AabbBuffer::new(&b1))
                .flags(&fb)
                .primitive_index_offset(1)
                .into(),
        ]
    } else {
        [
            TriangleInput::new(VertexBuffer::f32x3(&v0))
                .flags(&fa)
                .into(),
            TriangleInput::new(VertexBuffer::f32x3(&v1))
                .flags(&fb)
                .primitive_index_offset(1)
                .into(),
        ]
    };
    let gas = device.build_gas(&BuildOptions::default(), &inputs).unwrap();
    (gas, vec![b0[0], b1[0]])
}

// ----------------------------------------------------------------------------------------------
// optixTrace (pipeline_trace.rs)
// ----------------------------------------------------------------------------------------------

/// Twin of `null_handle_runs_only_miss_13_2_g1`: tracing the null handle runs only the miss
/// program, whatever lies along the ray; the same setup does hit a real structure.
#[test]
fn null_handle_runs_only_miss_13_2() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let boxes = box_stack(&[0.0]);
        let mut all = Vec::new();
        for ray in [
            RayIn::down(0.0, 0.0),
            RayIn::down(0.0, 0.0).interval(0.0, 1e30),
        ] {
            let out = t.one("log", 0, ray.payload(&[5, 6]), &boxes);
            assert_eq!(out.progs(), vec![Prog::Ms]);
            assert_eq!(out.payload()[..2], [5, 6]);
            all.push(out);
        }
        let gas = box_gas(device, &boxes);
        let out = t.one("log", handle(&gas), RayIn::down(0.0, 0.0), &boxes);
        assert_eq!(out.count(Prog::Ch), 1);
        assert_eq!(out.count(Prog::Ms), 0);
        all.push(out);
        all
    });
}

/// Twin of `closed_interval_triangles_13_2_g2`: a triangle hit at exactly tmin or tmax is
/// reported (to any-hit and closest-hit); one a float outside is not (only the miss runs).
#[test]
fn closed_interval_triangles_13_2() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let tris = stack_tris(&[0.0]);
        let gas = tri_gas(device, &tris);
        let h = handle(&gas);
        let first = t.one("log_tri", h, RayIn::down(0.0, 0.0), &[]);
        let hit_t = first.ch().tmax;
        let reference = oxray::cpu::Gas::build(
            &BuildOptions::default(),
            &[TriangleInput::new(VertexBuffer::f32x3(&soup(&tris))).into()],
        )
        .unwrap()
        .intersect(&oxray::Ray::new(Vec3::new(0.0, 0.0, 10.0), -Vec3::Z))
        .unwrap();
        assert_eq!(
            hit_t, reference.t,
            "the closest hit's tmax is the hit distance"
        );
        let mut all = vec![first];
        for (tmin, tmax, hit) in [
            (hit_t, hit_t, true),
            (0.0, hit_t, true),
            (hit_t, f32::INFINITY, true),
            (0.0, next_down(hit_t), false),
            (next_up(hit_t), f32::INFINITY, false),
            (next_up(hit_t), 2.0 * hit_t, false),
        ] {
            let out = t.one(
                "log_tri",
                h,
                RayIn::down(0.0, 0.0).interval(tmin, tmax),
                &[],
            );
            if hit {
                assert_eq!(out.ch().tmax, hit_t, "[{tmin}, {tmax}]");
                assert_eq!(out.count(Prog::Ah), 1, "[{tmin}, {tmax}]");
                assert_eq!(out.count(Prog::Ms), 0);
            } else {
                assert_eq!(out.progs(), vec![Prog::Ms], "[{tmin}, {tmax}]");
            }
            all.push(out);
        }
        all
    });
}

/// Twin of `closed_interval_custom_primitives_13_2_g2`: an intersection reported at exactly
/// tmin or tmax is accepted (`optixReportIntersection` returns true); one a float outside, or
/// NaN, is not (false, no any-hit call).
#[test]
fn closed_interval_custom_primitives_13_2_and_13_4() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let boxes = box_stack(&[0.0]);
        let gas = box_gas(device, &boxes);
        let out = t.one(
            "edges",
            handle(&gas),
            RayIn::down(0.0, 0.0).interval(2.0, 30.0),
            &boxes,
        );
        // Below tmin, above tmax, NaN, at tmax, at tmin.
        assert_eq!(out.notes, vec![0, 0, 0, 1, 1]);
        assert_eq!(
            out.of(Prog::Ah).iter().map(|e| e.tmax).collect::<Vec<_>>(),
            vec![30.0, 2.0]
        );
        assert_eq!(out.ch().tmax, 2.0);
        out
    });
}

/// Twin of `closest_hit_runs_once_for_closest_accepted_hit_13_4_g3_g4`: with every candidate
/// accepted, each any-hit call sees a candidate no farther than those accepted before it, and
/// the closest-hit program runs once, last, for the closest hit, with its primitive, hit kind
/// and barycentrics (those its any-hit call saw).
#[test]
fn closest_hit_runs_once_for_the_closest_accepted_hit_13_4() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let mut rng = common::Rng::new(3);
        let mut all = Vec::new();
        for case in 0..20 {
            let zs: Vec<f32> = (0..24).map(|_| rng.range(-5.0, 5.0)).collect();
            let tris = stack_tris(&zs);
            let gas = tri_gas(device, &tris);
            let out = t.one("log_tri", handle(&gas), RayIn::down(0.0, 0.0), &[]);
            let q = oxray::cpu::Gas::build(
                &BuildOptions::default(),
                &[TriangleInput::new(VertexBuffer::f32x3(&soup(&tris))).into()],
            )
            .unwrap()
            .intersect(&oxray::Ray::new(Vec3::new(0.0, 0.0, 10.0), -Vec3::Z))
            .unwrap();
            let ch = out.ch();
            let top = zs
                .iter()
                .enumerate()
                .fold(0, |b, (i, &z)| if z > zs[b] { i } else { b });
            assert_eq!(ch.prim, top as u32, "case {case}: the highest is closest");
            assert_eq!(
                (ch.prim, ch.tmax, ch.kind),
                (q.primitive_index, q.t, 0xFE),
                "case {case}"
            );
            assert_eq!(ch.attrs, [q.u.to_bits(), q.v.to_bits()], "case {case}");
            let ahs = out.of(Prog::Ah);
            let mut closest = f32::INFINITY;
            for e in &ahs {
                assert!(e.tmax <= closest, "case {case}: {} after {closest}", e.tmax);
                closest = e.tmax;
            }
            let ah_of_ch = ahs.iter().rev().find(|e| e.prim == ch.prim).unwrap();
            assert_eq!(ah_of_ch.attrs, ch.attrs, "case {case}");
            assert_eq!(*out.log.last().unwrap(), ch, "case {case}: CH runs last");
            // Which candidates any-hit sees depends on the traversal order, which the guide
            // leaves open: only the closest hit is compared across devices.
            all.push(ch);
        }
        all
    });
}

/// Twin of `ray_tmin_tmax_per_program_triangles_13_5_g5`: tmin is the trace's in every
/// program; tmax is the candidate's t in any-hit, the hit's t in closest-hit and the trace's
/// tmax in miss, even when the ray passes hits beyond it.
#[test]
fn ray_tmin_tmax_per_program_triangles_13_5() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let gas = tri_gas(device, &stack_tris(&[0.0, -2.0]));
        let h = handle(&gas);
        let hit = t.one(
            "log_tri",
            h,
            RayIn::down(0.0, 0.0).interval(0.5, 100.0),
            &[],
        );
        assert_eq!((hit.ch().tmin, hit.ch().tmax), (0.5, 10.0));
        for e in hit.of(Prog::Ah) {
            assert_eq!(e.tmin, 0.5);
            assert_eq!(e.tmax, if e.prim == 0 { 10.0 } else { 12.0 });
        }
        let miss = t.one(
            "log_tri",
            h,
            RayIn::down(7.0, 7.0).interval(0.5, 100.0),
            &[],
        );
        let ms = miss.of(Prog::Ms);
        assert_eq!(ms.len(), 1);
        assert_eq!((ms[0].tmin, ms[0].tmax), (0.5, 100.0));
        let short = t.one("log_tri", h, RayIn::down(0.0, 0.0).interval(0.25, 9.5), &[]);
        assert_eq!(short.progs(), vec![Prog::Ms]);
        assert_eq!((short.log[0].tmin, short.log[0].tmax), (0.25, 9.5));
        (hit.ch(), miss, short)
    });
}

/// Twin of `ray_tmin_tmax_per_program_custom_13_5_g5`: in an intersection program tmax is the
/// trace's until a hit is accepted, then the closest accepted t; the farther box is not
/// intersected once the interval ends before it; any-hit sees the reported t.
#[test]
fn ray_tmin_tmax_per_program_custom_13_5() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let boxes = box_stack(&[0.0, -4.0]);
        let gas = box_gas(device, &boxes);
        let out = t.one(
            "two",
            handle(&gas),
            RayIn::down(0.0, 0.0).interval(0.5, 100.0),
            &boxes,
        );
        // prim, tmin, before, far accepted, mid, near accepted, after.
        let f = |x: f32| x.to_bits();
        assert_eq!(
            out.notes,
            vec![0, f(0.5), f(100.0), 1, f(10.0), 1, f(9.5)],
            "{:?}",
            out.notes_f32()
        );
        assert_eq!(out.count(Prog::Is), 1);
        assert_eq!(
            out.of(Prog::Ah)
                .iter()
                .map(|e| (e.tmin, e.tmax))
                .collect::<Vec<_>>(),
            vec![(0.5, 10.0), (0.5, 9.5)]
        );
        let ch = out.ch();
        assert_eq!((ch.prim, ch.tmin, ch.tmax, ch.kind), (0, 0.5, 9.5, 2));
        out
    });
}

/// Twin of `ignore_intersection_13_13_g6_g8`: an ignored hit never becomes the closest hit and
/// does not shrink the interval; payload written before the ignore is kept; code after
/// `optixIgnoreIntersection` does not run; with every hit ignored the ray misses and the miss
/// program sees the full tmax.
#[test]
fn ignore_intersection_13_13() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let gas = tri_gas(device, &stack_tris(&[0.0, -1.0, -2.0]));
        let h = handle(&gas);
        let top = t.one("ignore_top", h, RayIn::down(0.0, 0.0), &[]);
        assert_eq!((top.ch().prim, top.ch().tmax), (1, 11.0));
        let p = top.payload();
        assert_eq!(
            p[1], 0xAB,
            "payload written before the ignore reaches the caller"
        );
        assert_eq!(p[0] as usize, top.count(Prog::Ah));
        assert!(top.of(Prog::Ah).iter().any(|e| e.prim == 0));
        let all = t.one(
            "ignore_all",
            h,
            RayIn::down(0.0, 0.0).interval(1.0, 50.0),
            &[],
        );
        assert_eq!(all.count(Prog::Ch), 0);
        let ms = all.of(Prog::Ms);
        assert_eq!(ms.len(), 1);
        assert_eq!(ms[0].tmax, 50.0, "ignored hits do not shrink tmax");
        let mut seen: Vec<u32> = all.of(Prog::Ah).iter().map(|e| e.prim).collect();
        seen.sort();
        seen.dedup();
        assert_eq!(
            seen,
            vec![0, 1, 2],
            "with nothing accepted every hit is a candidate"
        );
        let p = all.payload();
        assert_eq!(p[2] as usize, all.count(Prog::Ah));
        if !code_after_runs(device) {
            assert_eq!(p[3], 0, "code after optixIgnoreIntersection does not run");
        }
        (top.ch(), p[1], all.ch_free())
    });
}

impl Rec {
    /// The events but the any-hit calls, whose number and order depend on the traversal.
    fn ch_free(&self) -> Vec<Ev> {
        self.log
            .iter()
            .filter(|e| e.prog != Prog::Ah)
            .copied()
            .collect()
    }
}

/// Twin of `terminate_ray_triangles_13_13_g7`: `optixTerminateRay` accepts the candidate and
/// ends the traversal: no further any-hit call, and the closest-hit program runs for that
/// candidate even if closer primitives exist; code after it does not run.
#[test]
fn terminate_ray_triangles_13_13() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let gas = tri_gas(device, &stack_tris(&[0.0, -1.0, -2.0, -3.0]));
        let h = handle(&gas);
        let bottom = t.one("terminate_bottom", h, RayIn::down(0.0, 0.0), &[]);
        assert_eq!((bottom.ch().prim, bottom.ch().tmax), (2, 12.0));
        let ahs = bottom.of(Prog::Ah);
        assert_eq!(
            ahs.last().unwrap().prim,
            2,
            "no any-hit after terminate: {ahs:#?}"
        );
        assert_eq!(ahs.iter().filter(|e| e.prim == 2).count(), 1);
        assert_eq!(bottom.payload()[..2], [0x77, 0]);
        let first = t.one("terminate_first", h, RayIn::down(0.0, 0.0), &[]);
        let ahs = first.of(Prog::Ah);
        assert_eq!(ahs.len(), 1, "traversal ends at the first terminate");
        let ch = first.ch();
        assert_eq!(
            (ch.prim, ch.tmax, ch.attrs),
            (ahs[0].prim, ahs[0].tmax, ahs[0].attrs)
        );
        assert_eq!(first.payload()[0], 0);
        if !code_after_runs(device) {
            assert_eq!(first.payload()[1], 0, "code after terminate does not run");
        }
        // Which primitive comes first depends on the traversal order: not compared.
        (bottom.ch(), bottom.payload(), first.payload()[0])
    });
}

/// Twin of `terminate_ray_custom_13_13_g7`: when any-hit terminates, `optixReportIntersection`
/// does not return (the code after it does not run), no other intersection or any-hit program
/// runs, and closest-hit runs for the terminating hit.
#[test]
fn terminate_ray_custom_13_13() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let boxes = box_stack(&[0.0, -2.0, -4.0, -6.0]);
        let gas = box_gas(device, &boxes);
        let out = t.one(
            "terminate_custom",
            handle(&gas),
            RayIn::down(0.0, 0.0),
            &boxes,
        );
        if !code_after_runs(device) {
            assert!(
                out.notes.is_empty(),
                "code after a terminated report ran: {:?}",
                out.notes
            );
        }
        assert_eq!(out.count(Prog::Is), 1, "{:#?}", out.log);
        assert_eq!(out.count(Prog::Ah), 1);
        let ah = out.of(Prog::Ah)[0];
        let ch = out.ch();
        assert_eq!((ch.prim, ch.tmax, ch.attrs[0]), (ah.prim, ah.tmax, ah.prim));
        assert_eq!(ch.tmax, 9.5 + 2.0 * ch.prim as f32);
        (out.count(Prog::Is), out.count(Prog::Ah))
    });
}

/// Twin of `terminate_on_first_hit_13_2_g9`: with `TERMINATE_ON_FIRST_HIT` the first hit that
/// any-hit does not ignore ends the traversal and is the closest hit.
#[test]
fn terminate_on_first_hit_13_2() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let zs = [0.0, -1.0, -2.0, -3.0, -4.0];
        let gas = tri_gas(device, &stack_tris(&zs));
        let h = handle(&gas);
        let first = RayIn::down(0.0, 0.0).flags(RayFlags::TERMINATE_ON_FIRST_HIT);
        let out = t.one("log_tri", h, first, &[]);
        let ahs = out.of(Prog::Ah);
        assert_eq!(ahs.len(), 1, "the first accepted hit ends traversal");
        assert_eq!((out.ch().prim, out.ch().tmax), (ahs[0].prim, ahs[0].tmax));
        let only3 = t.one("only_3", h, first, &[]);
        assert_eq!((only3.ch().prim, only3.ch().tmax), (3, 13.0));
        assert_eq!(only3.of(Prog::Ah).last().unwrap().prim, 3);
        let plain = t.one("only_3", h, RayIn::down(0.0, 0.0), &[]);
        assert_eq!(
            plain.ch().prim,
            3,
            "without the flag the only accepted hit too"
        );
        let no_ah = t.one("ch_only", h, first, &[]);
        assert!(no_ah.ch().prim < zs.len() as u32);
        assert_eq!(no_ah.count(Prog::Ms), 0);
        (only3.ch(), plain.ch())
    });
}

/// Twin of `terminate_on_first_hit_custom_13_2_g9`: with `TERMINATE_ON_FIRST_HIT` the first
/// accepted report ends the traversal: the intersection program does not go on, no other runs,
/// and closest-hit runs for that report; without the flag the nearest report wins.
#[test]
fn terminate_on_first_hit_custom_13_2() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let boxes = box_stack(&[0.0, -2.0, -4.0]);
        let gas = box_gas(device, &boxes);
        let h = handle(&gas);
        let first = RayIn::down(0.0, 0.0).flags(RayFlags::TERMINATE_ON_FIRST_HIT);
        let out = t.one("two_reports", h, first, &boxes);
        if !code_after_runs(device) {
            assert!(
                out.notes.is_empty(),
                "the IS went on after a terminating report"
            );
        }
        assert_eq!(out.count(Prog::Is), 1);
        let ah = out.of(Prog::Ah);
        assert_eq!(ah.len(), 1);
        let ch = out.ch();
        assert_eq!((ch.prim, ch.kind, ch.tmax), (ah[0].prim, 1, ah[0].tmax));
        let plain = t.one("two_reports", h, RayIn::down(0.0, 0.0), &boxes);
        assert_eq!(
            (plain.ch().prim, plain.ch().kind, plain.ch().tmax),
            (0, 2, 9.5)
        );
        (ch.kind, plain.ch())
    });
}

/// Twin of `intersection_sees_shrinking_tmax_13_5_g3`: each intersection program sees as tmax
/// the closest hit accepted so far (or the trace's tmax), in whatever order the primitives are
/// visited; a report is accepted iff it is no farther; closest-hit gets the closest report.
#[test]
fn intersection_sees_shrinking_tmax_13_5() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let mut rng = common::Rng::new(35);
        let mut all = Vec::new();
        for case in 0..30 {
            let boxes: Vec<Aabb> = (0..6)
                .map(|_| {
                    let z = rng.range(-2.0, 2.0);
                    let h = rng.range(0.1, 2.0);
                    Aabb::new(Vec3::new(-1.0, -1.0, z - h), Vec3::new(1.0, 1.0, z + h))
                })
                .collect();
            let gas = box_gas(device, &boxes);
            let ray = RayIn::down(0.0, 0.0).interval(0.0, 40.0);
            let out = t.one("centre", handle(&gas), ray, &boxes);
            assert!(!out.notes.is_empty() && out.notes.len().is_multiple_of(3));
            let mut closest = 40.0f32;
            for n in out.notes.chunks(3) {
                let (before, t, r) = (f32::from_bits(n[0]), f32::from_bits(n[1]), n[2] == 1);
                assert_eq!(before, closest, "case {case}: {:?}", out.notes);
                assert_eq!(r, t <= closest, "case {case}: {:?}", out.notes);
                closest = closest.min(t);
            }
            let best = boxes
                .iter()
                .map(|b| 10.0 - 0.5 * (b.min.z + b.max.z))
                .fold(f32::INFINITY, f32::min);
            assert_eq!(out.ch().tmax, best, "case {case}");
            all.push(out.ch());
        }
        all
    });
}

/// Twin of `disable_closesthit_13_2_g10`: with `DISABLE_CLOSESTHIT` closest-hit never runs,
/// a hit is not a miss, the miss program still runs on a miss, and payload written by
/// intersection and any-hit programs reaches the caller.
#[test]
fn disable_closesthit_13_2() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let no_ch = RayIn::down(0.0, 0.0)
            .flags(RayFlags::DISABLE_CLOSESTHIT)
            .payload(&[1, 2, 3]);
        let tris = tri_gas(device, &stack_tris(&[0.0]));
        let out = t.one("write", handle(&tris), no_ch, &[]);
        assert_eq!(out.progs(), vec![Prog::Ah]);
        assert_eq!(out.payload()[..3], [1, 77, 3]);
        let boxes = box_stack(&[0.0]);
        let gas = box_gas(device, &boxes);
        let custom = t.one("write", handle(&gas), no_ch, &boxes);
        assert_eq!(custom.progs(), vec![Prog::Is, Prog::Ah]);
        assert_eq!(custom.payload()[..3], [1, 77, 55]);
        let mut miss = no_ch;
        miss.origin = [9.0, 9.0, 10.0];
        let missed = t.one("write", handle(&tris), miss, &[]);
        assert_eq!(missed.progs(), vec![Prog::Ms]);
        (out, custom, missed)
    });
}

/// Twin of `anyhit_enablement_precedence_u3_g11`, for triangles and custom primitives (the
/// triangle half with instance flags is in conformance.rs): the geometry flag `DISABLE_ANYHIT`
/// turns any-hit off, the ray flag `ENFORCE_ANYHIT` back on, the ray flag `DISABLE_ANYHIT` off
/// whatever the geometry says; the hit is accepted either way.
#[test]
fn any_hit_enablement_precedence_on_custom_primitives_5_1_and_13_2() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let mut all = Vec::new();
        for custom in [false, true] {
            let (gas, boxes) = two_inputs(
                device,
                custom,
                GeometryFlags::DISABLE_ANYHIT,
                GeometryFlags::empty(),
                5.0,
                0.0,
            );
            for (x, flags, ah) in [
                (0.0, RayFlags::empty(), false),
                (0.0, RayFlags::ENFORCE_ANYHIT, true),
                (0.0, RayFlags::DISABLE_ANYHIT, false),
                (5.0, RayFlags::empty(), true),
                (5.0, RayFlags::ENFORCE_ANYHIT, true),
                (5.0, RayFlags::DISABLE_ANYHIT, false),
            ] {
                let ray = RayIn::down(x, 0.0).flags(flags);
                let out = t.one("log", handle(&gas), ray, &boxes);
                let what = format!("custom {custom}, x {x}, flags {flags:?}");
                assert_eq!(out.count(Prog::Ah), ah as usize, "{what}");
                assert_eq!(out.ch().prim, (x > 0.0) as u32, "{what}");
                if custom {
                    assert_eq!(out.ch().kind, 3, "{what}");
                }
                all.push(out);
            }
        }
        all
    });
}

/// Twin of `triangle_face_culling_13_2_g13`: a triangle counter-clockwise as seen by the ray is
/// front-facing (hit kind 0xFE); `CULL_BACK_FACING_TRIANGLES` and `CULL_FRONT_FACING_TRIANGLES`
/// skip back and front faces (no any-hit, no closest-hit; hits behind are still found), the
/// geometry flag `DISABLE_TRIANGLE_FACE_CULLING` overrides both, and custom primitives are
/// never culled by facing.
#[test]
fn triangle_face_culling_13_2() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let down = RayIn::down(0.0, 0.0);
        let up = RayIn::new(Vec3::new(0.0, 0.0, -10.0), Vec3::Z);
        let cull_back = RayFlags::CULL_BACK_FACING_TRIANGLES;
        let cull_front = RayFlags::CULL_FRONT_FACING_TRIANGLES;
        let mut all = Vec::new();
        for no_culling in [false, true] {
            let gflags = if no_culling {
                GeometryFlags::DISABLE_TRIANGLE_FACE_CULLING
            } else {
                GeometryFlags::empty()
            };
            let gas = tri_gas_flags(device, &[tri_at(0.0, 0.0, 0.0, 1.0)], gflags);
            for (ray, front) in [(down, true), (up, false)] {
                for flags in [RayFlags::empty(), cull_back, cull_front] {
                    let out = t.one("log_tri", handle(&gas), ray.flags(flags), &[]);
                    let culled = !no_culling
                        && ((flags == cull_back && !front) || (flags == cull_front && front));
                    let what = format!("front {front}, {flags:?}, no culling {no_culling}");
                    if culled {
                        assert_eq!(out.progs(), vec![Prog::Ms], "{what}");
                    } else {
                        assert_eq!(out.ch().kind, if front { 0xFE } else { 0xFF }, "{what}");
                        assert_eq!(out.count(Prog::Ah), 1, "{what}");
                    }
                    all.push(out);
                }
            }
        }
        // A culled back face does not hide the front face behind it.
        let flipped = {
            let [a, b, c] = tri_at(0.0, 0.0, 0.0, 1.0);
            [b, a, c]
        };
        let gas = tri_gas(device, &[flipped, tri_at(0.0, 0.0, -1.0, 1.0)]);
        let out = t.one("log_tri", handle(&gas), down.flags(cull_back), &[]);
        assert_eq!((out.ch().prim, out.ch().kind), (1, 0xFE));
        assert!(
            out.of(Prog::Ah).iter().all(|e| e.prim == 1),
            "no AH for the culled face"
        );
        all.push(out);
        let out = t.one("log_tri", handle(&gas), down, &[]);
        assert_eq!((out.ch().prim, out.ch().kind), (0, 0xFF));
        all.push(out.ch_free_rec());
        // Facing flags do not apply to custom primitives.
        let boxes = box_stack(&[0.0]);
        let gas = box_gas(device, &boxes);
        for flags in [cull_back, cull_front] {
            let out = t.one("log", handle(&gas), down.flags(flags), &boxes);
            assert_eq!(out.ch().kind, 3, "{flags:?}");
            all.push(out);
        }
        all
    });
}

impl Rec {
    fn ch_free_rec(&self) -> Rec {
        Rec {
            payload: self.payload,
            log: self.ch_free(),
            notes: self.notes.clone(),
        }
    }
}

/// Twin of `cull_disabled_and_enforced_anyhit_13_2_g14`: `CULL_DISABLED_ANYHIT` skips
/// primitives whose any-hit is disabled, `CULL_ENFORCED_ANYHIT` those whose any-hit is enabled,
/// so the hit behind becomes the closest; with only culled geometry along the ray, a miss.
#[test]
fn cull_disabled_and_enforced_any_hit_13_2() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let mut all = Vec::new();
        for custom in [false, true] {
            // Primitive 0 (any-hit disabled) in front of primitive 1 (enabled).
            let (gas, boxes) = two_inputs(
                device,
                custom,
                GeometryFlags::DISABLE_ANYHIT,
                GeometryFlags::empty(),
                0.0,
                -3.0,
            );
            for (flags, closest, ah_prims) in [
                (RayFlags::empty(), 0, vec![]),
                (RayFlags::CULL_DISABLED_ANYHIT, 1, vec![1]),
                (RayFlags::CULL_ENFORCED_ANYHIT, 0, vec![]),
            ] {
                let out = t.one(
                    "log",
                    handle(&gas),
                    RayIn::down(0.0, 0.0).flags(flags),
                    &boxes,
                );
                let what = format!("custom {custom}, flags {flags:?}");
                assert_eq!(out.ch().prim, closest, "{what}");
                let ahs: Vec<u32> = out.of(Prog::Ah).iter().map(|e| e.prim).collect();
                if flags != RayFlags::empty() {
                    assert_eq!(ahs, ah_prims, "{what}");
                }
                all.push((out.ch(), ahs));
            }
            let (gas, boxes) = two_inputs(
                device,
                custom,
                GeometryFlags::empty(),
                GeometryFlags::empty(),
                0.0,
                -3.0,
            );
            let ray = RayIn::down(0.0, 0.0).flags(RayFlags::CULL_ENFORCED_ANYHIT);
            let out = t.one("log", handle(&gas), ray, &boxes);
            let not_is: Vec<Prog> = out.progs().into_iter().filter(|p| *p != Prog::Is).collect();
            assert_eq!(not_is, vec![Prog::Ms], "custom {custom}");
        }
        all
    });
}

/// Twin of `culled_custom_primitives_run_no_intersection_program_13_2_g14`: the intersection
/// program of a custom primitive culled by `CULL_DISABLED_ANYHIT` or `CULL_ENFORCED_ANYHIT`
/// does not run (it cannot write the payload).
#[test]
fn culled_custom_primitives_run_no_intersection_program_13_2() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let (gas, boxes) = two_inputs(
            device,
            true,
            GeometryFlags::DISABLE_ANYHIT,
            GeometryFlags::empty(),
            0.0,
            -3.0,
        );
        let h = handle(&gas);
        let ray = RayIn::down(0.0, 0.0).flags(RayFlags::CULL_DISABLED_ANYHIT);
        let out = t.one("mark", h, ray, &boxes);
        assert_eq!(out.ch().prim, 1);
        assert!(
            out.of(Prog::Is).iter().all(|e| e.prim == 1),
            "{:#?}",
            out.log
        );
        assert_eq!(
            out.payload()[0],
            0b10,
            "a culled primitive's IS wrote the payload"
        );
        let ray = RayIn::down(0.0, 0.0).flags(RayFlags::CULL_ENFORCED_ANYHIT);
        let enforced = t.one("mark", h, ray, &boxes);
        assert!(enforced.of(Prog::Is).iter().all(|e| e.prim == 0));
        assert_eq!(enforced.payload()[0], 0b01);
        assert_eq!(enforced.ch().prim, 0);
        (out, enforced)
    });
}

/// Twin of `ray_information_13_5_g30`: the ray queries return the trace's world origin and
/// direction, flags and visibility mask in intersection, any-hit, closest-hit and miss
/// programs; the time is 0 in a pipeline without motion blur; a GAS root ignores the
/// visibility mask (a mask of 0 still hits).
#[test]
fn ray_information_13_5() {
    on_every_device(|device| {
        let t = Twins::new(device, 1);
        let boxes = box_stack(&[0.0]);
        let gas = box_gas(device, &boxes);
        let flags = RayFlags::ENFORCE_ANYHIT | RayFlags::CULL_BACK_FACING_TRIANGLES;
        let mut ray =
            RayIn::new(Vec3::new(0.25, -0.5, 10.0), Vec3::new(0.0, 0.0, -2.0)).flags(flags);
        ray.time = 0.7;
        ray.mask = 0xA5;
        let expect = |prog: u32, o: [f32; 3]| {
            let mut v = vec![prog];
            v.extend(o.map(f32::to_bits));
            v.extend([0.0f32, 0.0, -2.0].map(f32::to_bits));
            v.extend([flags.bits(), 0xA5, 0]);
            v
        };
        let sbt = t.sbt(&["ray"], &["ms_ray"], false);
        let mut miss = ray;
        miss.origin = [5.0, 5.0, 10.0];
        let (out, report) = t.run(&sbt, handle(&gas), &[ray, miss], &boxes);
        assert_eq!(report.exceptions, 0);
        let mut hit_notes = expect(1, ray.origin);
        hit_notes.extend(expect(2, ray.origin));
        hit_notes.extend(expect(3, ray.origin));
        assert_eq!(out[0].notes, hit_notes);
        assert_eq!(out[1].notes, expect(4, miss.origin));
        // Visibility mask 0 on a GAS root: still a hit.
        let tris = tri_gas(device, &stack_tris(&[0.0]));
        let mut masked = RayIn::down(0.0, 0.0);
        masked.mask = 0;
        let m = t.one("ch_only", handle(&tris), masked, &[]);
        assert_eq!(m.count(Prog::Ch), 1);
        (out, m)
    });
}

// ----------------------------------------------------------------------------------------------
// Trace depth (pipeline_exceptions.rs)
// ----------------------------------------------------------------------------------------------

/// The notes of the exception program for `code` at launch index 0 (no details).
fn ex_notes(code: ExceptionCode) -> Vec<u32> {
    vec![0xE7, code.0 as u32, 0, 0, 0, 0, 0]
}

/// Twin of `trace_depth_exceeded_with_max_depth_0_13_14_g38`: with `maxTraceDepth` 0 the
/// ray-generation program may not trace: its trace raises `TRACE_DEPTH_EXCEEDED` (-2), no other
/// program runs, the exception program does, and the code after the trace does not.
#[test]
fn trace_depth_exceeded_with_max_depth_0_13_14() {
    on_every_device(|device| {
        let t = Twins::new(device, 0);
        let gas = tri_gas(device, &stack_tris(&[0.0]));
        let sbt = t.sbt(&["log_tri"], &["ms_log"], true);
        let mut all = Vec::new();
        for h in [handle(&gas), 0] {
            let (out, report) = t.run(&sbt, h, &[RayIn::down(0.0, 0.0)], &[]);
            assert_eq!(report.exceptions, 1, "{report:?}");
            assert_eq!(report.first_exceptions[0].0, [0, 0, 0]);
            assert_eq!(
                report.first_exceptions[0].1.code,
                ExceptionCode::TRACE_DEPTH_EXCEEDED
            );
            assert_eq!(ExceptionCode::TRACE_DEPTH_EXCEEDED.0, -2);
            assert_eq!(out[0].notes, ex_notes(ExceptionCode::TRACE_DEPTH_EXCEEDED));
            assert!(out[0].log.is_empty(), "{:?}", out[0].log);
            assert!(out[0].payload.is_none(), "the trace returned");
            all.push(out);
        }
        all
    });
}

/// Twin of `trace_depth_exceeded_by_recursion_13_14_g38`: recursion from closest-hit and from
/// miss programs: traces up to depth `maxTraceDepth` run, the one past it raises
/// `TRACE_DEPTH_EXCEEDED`; no program returns past it and the launch index ends. A trace at
/// exactly the maximum depth is fine.
#[test]
fn trace_depth_exceeded_by_recursion_13_14() {
    on_every_device(|device| {
        let gas = tri_gas(device, &stack_tris(&[0.0]));
        let h = handle(&gas);
        let mut all = Vec::new();
        for max in [1u32, 2, 5, 31] {
            let t = Twins::new(device, max);
            let sbt = t.sbt(&["recurse"], &["ms_recurse"], true);
            for (tag, ray) in [
                (0xC000, RayIn::down(0.0, 0.0)),
                (0xD000, RayIn::down(5.0, 5.0)),
            ] {
                let (out, report) = t.run(&sbt, h, &[ray], &[]);
                let mut expected: Vec<u32> = (1..=max).map(|d| tag + d).collect();
                expected.extend(ex_notes(ExceptionCode::TRACE_DEPTH_EXCEEDED));
                assert_eq!(
                    out[0].notes, expected,
                    "max_trace_depth {max}, tag {tag:#x}"
                );
                assert_eq!(report.exceptions, 1, "{report:?}");
                assert_eq!(
                    report.first_exceptions[0].1.code,
                    ExceptionCode::TRACE_DEPTH_EXCEEDED
                );
                assert!(out[0].payload.is_none());
                all.push(out);
            }
        }
        let t = Twins::new(device, 2);
        let sbt = t.sbt(&["once"], &["ms_ten"], true);
        let (out, report) = t.run(&sbt, h, &[RayIn::down(0.0, 0.0)], &[]);
        assert_eq!(report.exceptions, 0, "{report:?}");
        assert_eq!(out[0].payload()[0], 11);
        all.push(out);
        all
    });
}

/// Every program of twins.cu compiles for the GPU with NVRTC, GPU or not.
#[test]
fn the_twins_compile_with_nvrtc() {
    use oxray::cuda::{CudaHitGroupDesc, CudaModule, CudaProgramGroup};
    let m = CudaModule::from_source(TWINS);
    let e = |n: Option<&'static str>| n.map(|n| (&m, n));
    let mut groups = vec![CudaProgramGroup::raygen(&m, RAYGEN).unwrap()];
    for (label, entry) in MISSES {
        let g = CudaProgramGroup::miss(Some((&m, entry)));
        groups.push(g.unwrap_or_else(|e| panic!("{label}: {e}")));
    }
    for (label, ch, ah, is) in HIT_GROUPS {
        let g = CudaProgramGroup::hit_group(CudaHitGroupDesc {
            closest_hit: e(ch),
            any_hit: e(ah),
            intersection: e(is),
        });
        groups.push(g.unwrap_or_else(|e| panic!("{label}: {e}")));
    }
    groups.push(CudaProgramGroup::exception(&m, EXCEPTION).unwrap());
    let types = PipelineCompileOptions::default().uses_primitive_type_flags;
    common::assert_compiles_with_nvrtc("the twins' programs", &groups, types);
}
