//! CUDA C++ twins of scenarios of pipeline_exceptions.rs, pipeline_payload.rs, pipeline_sbt.rs,
//! pipeline_trace.rs, pipeline_launch.rs, pipeline_noreturn.rs, callables.rs and
//! transform_list.rs that neither conformance.rs nor conformance_twins.rs nor
//! conformance_twins2.rs covers, written against the OptiX device API (programs in
//! conformance/twins3.cu) and run on every device present: the CPU always (its programs compiled
//! by the host's C++ compiler) and a CUDA device where there is one (`OXRAY_REQUIRE_GPU=1` makes
//! its absence a failure). Each device must give the values the Rust-closure original asserts,
//! and all devices the same records.
//!
//! Covered: user exceptions with 0 to 8 details, the range of user codes, the end of one launch
//! index only, the count without an exception record, exceptions from every program kind and
//! from a nested trace (§13.14); invalid rays in validation mode (§4.3); invalid miss and hit
//! SBT indices (§7.2, §7.3); the pipeline's traversable-graph and primitive-type flags (§6.3);
//! the payload length against `numPayloadValues` (§13.3); fewer than 2 attribute words, the
//! barycentrics as attributes 0 and 1, triangle hit kinds and facing (§13.4, §13.7); what an
//! intersection program sees and the instance queries of a GAS root (§13.7); records at
//! `base + index * stride` (§7.2), one program group in two pipelines (§6.6), an indexed input
//! with `u32` SBT index offsets (§7.3.2); `REQUIRE_SINGLE_ANYHIT_CALL` (§5.1); closest-hit
//! programs calling direct callables, continuation callables that trace, runaway recursion
//! (§15); the transform list of a GAS root and of nested instances and static transforms
//! (§13.11), the traversable graph depth (§6.8); one ray-generation run per launch index (§10,
//! §13.1) and launches larger than 2^30 (§12); the first of ignore, terminate and throw wins,
//! a report after a terminating any-hit does nothing, and callables that throw (§13.13,
//! §13.14).
//!
//! Every launch index traces one ray described by a [`RayIn`] record; the programs write notes
//! (words) into the launch index's record, and the ray-generation program the payload after
//! the trace.

mod common;

use common::{code_after_runs, name, on_every_device};
use glam::Vec3;
use oxray::programs::{HitGroupDesc, Module, Pipeline, ProgramGroup};
use oxray::{
    Aabb, AabbBuffer, BackendKind, BuildInput, BuildOptions, CustomPrimitiveInput, Device,
    DeviceContext, ExceptionCode, GeometryFlags, IndexBuffer, Instance, LaunchError, LaunchReport,
    ModuleSource, PipelineCompileOptions, PipelineLinkOptions, PrimitiveTypeFlags, RayFlags,
    SbtIndexOffsets, SbtRegion, ShaderBindingTable, StaticTransform, Transform,
    TraversableGraphFlags, TraversableHandle, TriangleInput, VertexBuffer,
};
use oxray_testkit::mesh::{random_soup, soup, tri_at, Tri};
use oxray_testkit::Rng;

const TWINS3: &str = include_str!("conformance/twins3.cu");

/// Words of a launch index's record (`T3_WORDS` in twins3.cu), where its notes start and how
/// many fit.
const WORDS: usize = 256;
const NOTES_AT: usize = 40;
const MAX_NOTES: usize = 216;

/// What a group is made of.
#[derive(Clone, Copy)]
enum G {
    Rg(&'static str),
    Ms(&'static str),
    Hit(
        Option<&'static str>,
        Option<&'static str>,
        Option<&'static str>,
    ),
    Call(Option<&'static str>, Option<&'static str>),
    Ex(&'static str),
}

const CH_LOG: Option<&str> = Some("__closesthit__log");
const AH_LOG: Option<&str> = Some("__anyhit__log");

const GROUPS: [(&str, G); 42] = [
    ("rg", G::Rg("__raygen__t3")),
    ("rg_throws", G::Rg("__raygen__throws")),
    ("rg_count", G::Rg("__raygen__count")),
    ("rg_calls", G::Rg("__raygen__calls")),
    ("rg_cc_throw", G::Rg("__raygen__cc_throw")),
    ("rg_count_index", G::Rg("__raygen__count_index")),
    ("ms_log", G::Ms("__miss__log")),
    ("ms_throw", G::Ms("__miss__throw")),
    ("ms_throw77", G::Ms("__miss__throw77")),
    ("ms_record", G::Ms("__miss__record")),
    ("ms_note7", G::Ms("__miss__note7")),
    ("log", G::Hit(CH_LOG, AH_LOG, Some("__intersection__top"))),
    ("log_tri", G::Hit(CH_LOG, AH_LOG, None)),
    ("ch_log", G::Hit(CH_LOG, None, None)),
    (
        "throw",
        G::Hit(
            Some("__closesthit__throw"),
            Some("__anyhit__throw"),
            Some("__intersection__throw"),
        ),
    ),
    (
        "nest_null",
        G::Hit(Some("__closesthit__nest_null"), None, None),
    ),
    (
        "attrs8",
        G::Hit(
            Some("__closesthit__attrs8"),
            Some("__anyhit__attrs8"),
            Some("__intersection__attrs8"),
        ),
    ),
    (
        "attrs8_tri",
        G::Hit(Some("__closesthit__attrs8"), None, None),
    ),
    (
        "bary",
        G::Hit(Some("__closesthit__bary"), Some("__anyhit__bary"), None),
    ),
    (
        "face",
        G::Hit(Some("__closesthit__face"), Some("__anyhit__face"), None),
    ),
    ("who", G::Hit(None, None, Some("__intersection__who"))),
    (
        "inst",
        G::Hit(
            Some("__closesthit__inst"),
            Some("__anyhit__inst"),
            Some("__intersection__quiet"),
        ),
    ),
    ("record", G::Hit(Some("__closesthit__record"), None, None)),
    ("count_tri", G::Hit(None, Some("__anyhit__count"), None)),
    (
        "count_box",
        G::Hit(
            None,
            Some("__anyhit__count"),
            Some("__intersection__box_entry"),
        ),
    ),
    (
        "call_add",
        G::Hit(Some("__closesthit__call_add"), None, None),
    ),
    (
        "call_throw",
        G::Hit(Some("__closesthit__call_throw"), None, None),
    ),
    (
        "ah_call_throw",
        G::Hit(CH_LOG, Some("__anyhit__call_throw"), None),
    ),
    (
        "list",
        G::Hit(Some("__closesthit__list"), Some("__anyhit__list"), None),
    ),
    (
        "ignore_terminate",
        G::Hit(CH_LOG, Some("__anyhit__ignore_terminate"), None),
    ),
    (
        "terminate_ignore",
        G::Hit(CH_LOG, Some("__anyhit__terminate_ignore"), None),
    ),
    (
        "throw_ignore",
        G::Hit(CH_LOG, Some("__anyhit__throw_ignore"), None),
    ),
    (
        "twice",
        G::Hit(
            Some("__closesthit__t_kind_attr"),
            Some("__anyhit__terminate_kind1"),
            Some("__intersection__twice"),
        ),
    ),
    ("pass_on", G::Hit(CH_LOG, Some("__anyhit__pass_on"), None)),
    ("dc_add", G::Call(Some("__direct_callable__add"), None)),
    (
        "cc_probe",
        G::Call(None, Some("__continuation_callable__probe")),
    ),
    (
        "dc_recurse",
        G::Call(Some("__direct_callable__recurse"), None),
    ),
    (
        "dc_throw13",
        G::Call(Some("__direct_callable__throw13"), None),
    ),
    (
        "cc_throw14",
        G::Call(None, Some("__continuation_callable__throw14")),
    ),
    (
        "dc_throw15",
        G::Call(Some("__direct_callable__throw15"), None),
    ),
    ("ex", G::Ex("__exception__note")),
    // A miss group without a program.
    ("ms_none", G::Ms("")),
];

/// A ray of one launch index (`RayIn` in twins3.cu).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct RayIn {
    origin: [f32; 3],
    dir: [f32; 3],
    tmin: f32,
    tmax: f32,
    flags: u32,
    sbt_offset: u32,
    sbt_stride: u32,
    miss_index: u32,
    npayload: u32,
    pad: [u32; 3],
    payload: [u32; 32],
}

impl RayIn {
    fn new(origin: Vec3, dir: Vec3) -> RayIn {
        RayIn {
            origin: origin.to_array(),
            dir: dir.to_array(),
            tmin: 0.0,
            tmax: f32::INFINITY,
            flags: 0,
            sbt_offset: 0,
            sbt_stride: 1,
            miss_index: 0,
            npayload: 8,
            pad: [0; 3],
            payload: [0; 32],
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

    fn sbt(mut self, offset: u32, stride: u32, miss: u32) -> RayIn {
        (self.sbt_offset, self.sbt_stride, self.miss_index) = (offset, stride, miss);
        self
    }

    /// Passes `p.len()` payload words (0, 1, 2, 4, 5, 8 or 32) with these values.
    fn payload(mut self, p: &[u32]) -> RayIn {
        assert!(
            [0, 1, 2, 4, 5, 8, 32].contains(&p.len()),
            "{} words",
            p.len()
        );
        self.npayload = p.len() as u32;
        self.payload[..p.len()].copy_from_slice(p);
        self
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct T3Params {
    out: u64,
    handle: u64,
    rays: u64,
    aux: u64,
    mode: u32,
    pad: u32,
}

/// What one launch index did: the payload after the trace (if it returned; as many words as
/// the ray passed), the notes, and the words a ray-generation program that throws writes.
#[derive(Clone, Debug, PartialEq)]
struct Rec {
    payload: Option<Vec<u32>>,
    notes: Vec<u32>,
    /// Code after a throw in the ray-generation program ran (word 36).
    after: u32,
    /// The ray-generation program finished (word 37).
    done: u32,
}

impl Rec {
    fn parse(w: &[u32; WORDS], npayload: usize) -> Rec {
        let m = w[33] as usize;
        assert!(m <= MAX_NOTES, "{m} notes: the record keeps {MAX_NOTES}");
        Rec {
            payload: (w[32] == 1).then(|| w[..npayload].to_vec()),
            notes: w[NOTES_AT..NOTES_AT + m].to_vec(),
            after: w[36],
            done: w[37],
        }
    }

    fn payload(&self) -> &[u32] {
        self.payload.as_deref().expect("the trace did not return")
    }
}

fn f(x: f32) -> u32 {
    x.to_bits()
}

/// The notes of `__exception__note`: 0xE0, the code, 8 detail words, the launch index's x.
fn ex(code: i32, details: &[u32], x: u32) -> Vec<u32> {
    let mut v = vec![0xE0, code as u32];
    v.extend((0..8).map(|k| details.get(k).copied().unwrap_or(0)));
    v.push(x);
    v
}

/// The one exception of a one-index launch: its code and details, at launch index 0.
fn only_exception(report: &LaunchReport) -> (i32, Vec<u32>) {
    assert_eq!(report.exceptions, 1, "{report:?}");
    assert_eq!(report.first_exceptions.len(), 1, "{report:?}");
    let (index, e) = &report.first_exceptions[0];
    assert_eq!(*index, [0, 0, 0]);
    (e.code.0, e.details().to_vec())
}

/// The records of an SBT region: (group label, data).
type Records<'a> = &'a [(&'a str, u32)];

/// Every group of twins3.cu on one device, by label, and pipelines of them.
struct Twins {
    device: Device,
    groups: Vec<(&'static str, ProgramGroup)>,
}

impl Twins {
    fn new(device: &Device) -> Twins {
        let m: Module = device
            .create_module(ModuleSource::CudaCpp(TWINS3))
            .unwrap_or_else(|e| panic!("{}: {e}", name(device)));
        let e = |n: Option<&'static str>| n.map(|n| (&m, n));
        let groups = GROUPS
            .iter()
            .map(|&(label, g)| {
                let group = match g {
                    G::Rg(n) => ProgramGroup::raygen(&m, n),
                    G::Ms("") => ProgramGroup::miss_none(device),
                    G::Ms(n) => ProgramGroup::miss(&m, n),
                    G::Hit(ch, ah, is) => ProgramGroup::hit_group(HitGroupDesc {
                        closest_hit: e(ch),
                        any_hit: e(ah),
                        intersection: e(is),
                    }),
                    G::Call(dc, cc) => ProgramGroup::callables(e(dc), e(cc)),
                    G::Ex(n) => ProgramGroup::exception(&m, n),
                };
                (label, group.unwrap_or_else(|e| panic!("{label}: {e}")))
            })
            .collect();
        Twins {
            device: device.clone(),
            groups,
        }
    }

    fn group(&self, label: &str) -> &ProgramGroup {
        &self
            .groups
            .iter()
            .find(|(n, _)| *n == label)
            .unwrap_or_else(|| panic!("no group {label}"))
            .1
    }

    fn header(&self, label: &str) -> oxray::SbtHeader {
        self.group(label).pack_header()
    }

    /// A pipeline of every group (8 payload words, 8 attribute words unless `compile` says
    /// otherwise) with trace depth `depth`.
    fn pipeline(&self, compile: &PipelineCompileOptions, depth: u32) -> Pipeline {
        self.pipeline_of(&self.groups, compile, depth)
    }

    fn pipeline_of(
        &self,
        groups: &[(&'static str, ProgramGroup)],
        compile: &PipelineCompileOptions,
        depth: u32,
    ) -> Pipeline {
        let list: Vec<ProgramGroup> = groups.iter().map(|(_, g)| g.clone()).collect();
        self.device
            .create_pipeline(
                compile,
                &PipelineLinkOptions {
                    max_trace_depth: depth,
                },
                Some("t3"),
                &list,
            )
            .unwrap_or_else(|e| panic!("{} pipeline: {e}", name(&self.device)))
    }

    fn region(&self, records: Records<'_>) -> SbtRegion {
        let r: Vec<(oxray::SbtHeader, u32)> =
            records.iter().map(|(g, d)| (self.header(g), *d)).collect();
        SbtRegion::from_records(&r)
    }

    /// The SBT of raygen `rg`, the hit and miss records given, and the exception program if
    /// `exception`.
    fn sbt(
        &self,
        rg: &str,
        hits: Records<'_>,
        misses: Records<'_>,
        exception: bool,
    ) -> ShaderBindingTable {
        ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[self.header(rg)]),
            miss: self.region(misses),
            hitgroup: self.region(hits),
            exception: exception.then(|| SbtRegion::from_headers(&[self.header("ex")])),
            ..Default::default()
        }
    }

    /// A `dims` launch of `pipeline` with one ray per launch index (the first for all if there
    /// are fewer), `aux` and `mode`; a launch that validation mode fails is reported like any
    /// other exception.
    #[allow(clippy::too_many_arguments)]
    fn launch(
        &self,
        pipeline: &Pipeline,
        sbt: &ShaderBindingTable,
        handle: u64,
        rays: &[RayIn],
        aux: &[f32],
        mode: u32,
        dims: [u32; 3],
    ) -> (Vec<Rec>, LaunchReport) {
        let d = &self.device;
        let n = (dims[0] * dims[1] * dims[2]) as usize;
        let mut all: Vec<RayIn> = rays.to_vec();
        all.resize(n.max(1), rays[0]);
        let out = d.create_buffer::<[u32; WORDS]>(n).unwrap();
        let ray_buf = d.buffer_from_slice(&all).unwrap();
        let mut a = aux.to_vec();
        a.push(0.0);
        let aux_buf = d.buffer_from_slice(&a).unwrap();
        let params = T3Params {
            out: out.device_ptr(),
            handle,
            rays: ray_buf.device_ptr(),
            aux: aux_buf.device_ptr(),
            mode,
            pad: 0,
        };
        let report = match pipeline.launch_with(&params, sbt, dims[0], dims[1], dims[2]) {
            Ok(r) => r,
            Err(oxray::programs::ProgramError::Launch(LaunchError::ValidationFailure {
                index,
                exception,
            })) => LaunchReport {
                exceptions: 1,
                first_exceptions: vec![(index, exception)],
                ..Default::default()
            },
            Err(e) => panic!("{} launch: {e}", name(d)),
        };
        let recs = out
            .download()
            .unwrap()
            .iter()
            .zip(&all)
            .map(|(w, r)| Rec::parse(w, r.npayload as usize))
            .collect();
        (recs, report)
    }

    /// One ray through `pipeline` with the SBT `sbt`.
    fn one(
        &self,
        pipeline: &Pipeline,
        sbt: &ShaderBindingTable,
        handle: u64,
        ray: RayIn,
        aux: &[f32],
    ) -> (Rec, LaunchReport) {
        let (mut recs, report) = self.launch(pipeline, sbt, handle, &[ray], aux, 0, [1, 1, 1]);
        (recs.remove(0), report)
    }
}

/// 8 payload words and 8 attribute words.
fn compile() -> PipelineCompileOptions {
    PipelineCompileOptions {
        num_payload_values: 8,
        num_attribute_values: 8,
        ..Default::default()
    }
}

// ----------------------------------------------------------------------------------------------
// Geometry
// ----------------------------------------------------------------------------------------------

fn cube(c: Vec3, h: f32) -> Aabb {
    Aabb::new(c - Vec3::splat(h), c + Vec3::splat(h))
}

fn tri_gas_flags(device: &Device, tris: &[Tri], flags: GeometryFlags) -> oxray::Gas {
    let v = soup(tris);
    let fl = [flags];
    let input = TriangleInput::new(VertexBuffer::f32x3(&v)).flags(&fl);
    device
        .build_gas(&BuildOptions::default(), &[input.into()])
        .unwrap()
}

fn tri_gas(device: &Device, tris: &[Tri]) -> oxray::Gas {
    tri_gas_flags(device, tris, GeometryFlags::empty())
}

/// A GAS of `boxes`, and the tops of the boxes.
fn box_gas_flags(device: &Device, boxes: &[Aabb], flags: GeometryFlags) -> (oxray::Gas, Vec<f32>) {
    let fl = [flags];
    let input = CustomPrimitiveInput::new(AabbBuffer::new(boxes)).flags(&fl);
    let gas = device
        .build_gas(&BuildOptions::default(), &[input.into()])
        .unwrap();
    (gas, boxes.iter().map(|b| b.max.z).collect())
}

/// One box under `(0, 0)` whose top face is at height 0.5 (a ray down from height 10 enters it
/// at t = 9.5).
fn one_box(device: &Device) -> (oxray::Gas, Vec<f32>) {
    box_gas_flags(device, &[cube(Vec3::ZERO, 0.5)], GeometryFlags::empty())
}

fn one_triangle(device: &Device) -> oxray::Gas {
    tri_gas(device, &[tri_at(0.0, 0.0, 0.0, 1.0)])
}

/// `n` triangles stacked under `(0, 0)`, listed far to near: primitive `i` lies at height
/// `-(n - 1 - i)`, so a ray down from height 10 meets it at `t = 10 + (n - 1 - i)`.
fn stack(device: &Device, n: usize) -> oxray::Gas {
    let tris: Vec<Tri> = (0..n)
        .map(|i| tri_at(0.0, 0.0, -((n - 1 - i) as f32), 1.0))
        .collect();
    tri_gas(device, &tris)
}

fn handle(gas: &oxray::Gas) -> u64 {
    gas.optix_handle().unwrap()
}

/// The (program tag, primitive) pairs of logging notes (0x15, 0xA0, 0xC0 with a primitive;
/// 0x40 alone), up to the first exception note.
fn events(notes: &[u32]) -> Vec<(u32, u32)> {
    let mut out = Vec::new();
    let mut k = 0;
    while k < notes.len() {
        match notes[k] {
            0x15 | 0xA0 | 0xC0 => {
                out.push((notes[k], notes[k + 1]));
                k += 2;
            }
            0x40 => {
                out.push((0x40, 0));
                k += 1;
            }
            _ => break,
        }
    }
    out
}

/// The tags of the logging notes.
fn progs(notes: &[u32]) -> Vec<u32> {
    events(notes).iter().map(|e| e.0).collect()
}

// ----------------------------------------------------------------------------------------------
// User exceptions (pipeline_exceptions.rs)
// ----------------------------------------------------------------------------------------------

/// A launch of `rg_throws` in `mode` over `dims`, with or without the exception program.
fn throws(t: &Twins, mode: u32, dims: [u32; 3], exception: bool) -> (Vec<Rec>, LaunchReport) {
    let p = t.pipeline(&compile(), 1);
    let sbt = t.sbt("rg_throws", &[], &[], exception);
    t.launch(&p, &sbt, 0, &[RayIn::down(0.0, 0.0)], &[], mode, dims)
}

fn details_of(i: u32) -> Vec<u32> {
    (0..i).map(|j| 0x100 * i + j).collect()
}

/// Twin of `user_exception_code_and_details_13_14_g39`: a user exception thrown with 0 to 8
/// details reaches the exception program with its code and those details (the rest read 0);
/// the code after the throw does not run, nor does the rest of the launch index; the report
/// keeps the first five with their details.
#[test]
fn user_exception_code_and_details_13_14() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let (out, report) = throws(&t, 0, [9, 1, 1], true);
        assert_eq!(report.exceptions, 9);
        for (i, o) in out.iter().enumerate() {
            let i = i as u32;
            assert_eq!(o.notes, ex(100 + i as i32, &details_of(i), i), "index {i}");
            assert_eq!((o.after, o.done), (0, 0), "index {i}");
        }
        let firsts: Vec<([u32; 3], i32, Vec<u32>)> = report
            .first_exceptions
            .iter()
            .map(|(ix, e)| (*ix, e.code.0, e.details().to_vec()))
            .collect();
        let expected: Vec<_> = (0..5u32)
            .map(|i| ([i, 0, 0], 100 + i as i32, details_of(i)))
            .collect();
        assert_eq!(firsts, expected);
        (out, firsts)
    });
}

/// Twin of `user_exception_code_range_13_14_n15`: user codes span `0..=2^30 - 1`; codes outside
/// become `2^30 - 1` (documented choice), so a program cannot raise a built-in code.
#[test]
fn user_exception_code_range_13_14() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let (out, report) = throws(&t, 1, [5, 1, 1], true);
        assert_eq!(report.exceptions, 5, "{report:?}");
        let max = ExceptionCode::MAX_USER;
        assert_eq!(max, (1 << 30) - 1);
        let codes: Vec<i32> = out.iter().map(|o| o.notes[1] as i32).collect();
        assert_eq!(codes, [0, max, max, max, max]);
        assert!(codes.iter().all(|&c| ExceptionCode(c).is_user()));
        out
    });
}

/// Twin of `exception_ends_only_its_launch_index_13_14`: an exception ends only its own launch
/// index: the others run to completion, and the exception program sees the index that raised
/// it.
#[test]
fn exception_ends_only_its_launch_index_13_14() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let (out, report) = throws(&t, 2, [16, 16, 1], true);
        let mut n = 0;
        for (i, o) in out.iter().enumerate() {
            let (x, y) = (i as u32 % 16, i as u32 / 16);
            if (x * 7 + y) % 5 == 0 {
                n += 1;
                assert_eq!(o.notes, ex(i as i32, &[x, y], x), "index {i}");
                assert_eq!((o.after, o.done), (0, 0), "index {i}");
            } else {
                assert!(o.notes.is_empty(), "index {i}: {:?}", o.notes);
                assert_eq!(o.done, 1, "index {i} finished");
            }
        }
        assert_eq!(report.exceptions, n);
        out
    });
}

/// Twin of `exceptions_without_exception_record_are_reported_13_14`, without its log callback:
/// without an exception record the launch report counts every exception and keeps five, in
/// launch-index order (x fastest, then y, then z), each with its details. Which five: the first
/// five of the launch on the CPU, whatever the thread count; CUDA keeps the first five of the
/// first 64 it records (docs/gpu-backend.md, "Launches"), so only their order and contents are
/// compared there.
#[test]
fn exceptions_without_exception_record_are_counted_13_14() {
    fn throws_at(i: u32) -> bool {
        let (x, y) = (i % 40, (i / 40) % 30);
        x % 3 == 1 && (y > 0 || i >= 1200)
    }
    on_every_device(|device| {
        let t = Twins::new(device);
        let (out, report) = throws(&t, 3, [40, 30, 2], false);
        let expected = (0..2400).filter(|&i| throws_at(i)).count() as u64;
        assert_eq!(report.exceptions, expected);
        assert!(
            out.iter().all(|o| o.notes.is_empty()),
            "no exception program"
        );
        let linear = |ix: [u32; 3]| ix[0] + 40 * (ix[1] + 30 * ix[2]);
        let firsts: Vec<u32> = report
            .first_exceptions
            .iter()
            .map(|(ix, _)| linear(*ix))
            .collect();
        assert_eq!(firsts.len(), 5);
        assert!(firsts.windows(2).all(|w| w[0] < w[1]), "{firsts:?}");
        for (ix, e) in &report.first_exceptions {
            let i = linear(*ix);
            assert!(throws_at(i), "{ix:?}");
            assert_eq!((e.code.0, e.details()), (i as i32, &[i][..]));
        }
        if device.kind() != BackendKind::Cuda {
            let first: Vec<u32> = (0..2400).filter(|&i| throws_at(i)).take(5).collect();
            assert_eq!(firsts, first);
        }
        let done: Vec<u32> = out.iter().map(|o| o.done).collect();
        for (i, d) in done.iter().enumerate() {
            assert_eq!(*d, !throws_at(i as u32) as u32, "index {i}");
        }
        (report.exceptions, done)
    });
}

/// Twin of `user_exception_from_every_program_kind_13_14`: an exception raised in an
/// intersection, any-hit, closest-hit or miss program ends the launch index: the exception
/// program sees it, the trace does not return, no code after the throw runs and no other
/// program of the trace runs after it.
#[test]
fn user_exception_from_every_program_kind_13_14() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 1);
        let sbt = t.sbt("rg", &[("throw", 0)], &[("ms_throw", 0)], true);
        let (boxes, tops) = one_box(device);
        let tris = one_triangle(device);
        let down = RayIn::down(0.0, 0.0);
        let mut all = Vec::new();
        for (which, h, ray, details, programs) in [
            (1, &boxes, down, vec![0], vec![0x15]),
            (2, &boxes, down, vec![7], vec![0x15, 0xA0]),
            (3, &boxes, down, vec![8, 9], vec![0x15, 0xA0, 0xC0]),
            (4, &boxes, RayIn::down(5.0, 5.0), vec![], vec![0x40]),
            (2, &tris, down, vec![7], vec![0xA0]),
            (3, &tris, down, vec![8, 9], vec![0xA0, 0xC0]),
        ] {
            let (out, report) = t.one(&p, &sbt, handle(h), ray.payload(&[which]), &tops);
            let what = format!("program {which}, {programs:x?}");
            assert_eq!(progs(&out.notes), programs, "{what}");
            let k = out.notes.len() - 11;
            assert_eq!(out.notes[k..], ex(which as i32, &details, 0), "{what}");
            assert!(
                !out.notes.contains(&0xAF7E),
                "{what}: code after a throw ran"
            );
            assert!(out.payload.is_none(), "{what}: the trace returned");
            assert_eq!(only_exception(&report), (which as i32, details), "{what}");
            all.push(out);
        }
        all
    });
}

/// Twin of `invalid_ray_in_validation_mode_4_3`: in validation mode an invalid ray (NaN or
/// infinite origin or direction, zero direction, negative tmin, tmin > tmax, NaN interval)
/// raises `INVALID_RAY` (-9) before any program runs, and the launch fails; without validation
/// mode nothing is raised (the original's miss is not compared: what such a trace finds is
/// undefined, guide §13.2, and CUDA's traversal does not test the ray). A valid ray is fine
/// either way.
#[test]
fn invalid_ray_in_validation_mode_4_3() {
    on_every_device(|device| {
        let nan = f32::NAN;
        let down = RayIn::down(0.0, 0.0);
        let cases: Vec<(&str, RayIn)> = vec![
            (
                "NaN origin",
                RayIn::new(Vec3::new(nan, 0.0, 10.0), -Vec3::Z),
            ),
            (
                "infinite origin",
                RayIn::new(Vec3::new(0.0, f32::INFINITY, 10.0), -Vec3::Z),
            ),
            (
                "NaN direction",
                RayIn::new(Vec3::new(0.0, 0.0, 10.0), Vec3::new(0.0, nan, -1.0)),
            ),
            (
                "zero direction",
                RayIn::new(Vec3::new(0.0, 0.0, 10.0), Vec3::ZERO),
            ),
            ("negative tmin", down.interval(-1.0, 100.0)),
            ("tmin > tmax", down.interval(5.0, 2.0)),
            ("NaN tmin", down.interval(nan, 100.0)),
            ("NaN tmax", down.interval(0.0, nan)),
        ];
        let mut all = Vec::new();
        for validation in [true, false] {
            let d = device
                .clone()
                .with_context(DeviceContext::new().validation_mode(validation));
            let t = Twins::new(&d);
            let gas = one_triangle(&d);
            let p = t.pipeline(&compile(), 1);
            let sbt = t.sbt("rg", &[("log_tri", 0)], &[("ms_log", 0)], true);
            for (what, ray) in &cases {
                let (out, report) = t.one(&p, &sbt, handle(&gas), *ray, &[]);
                if validation {
                    let (code, _) = only_exception(&report);
                    assert_eq!(code, ExceptionCode::INVALID_RAY.0, "{what}");
                    assert_eq!(code, -9);
                    assert_eq!(out.notes.len(), 11, "{what}: {:x?}", out.notes);
                    assert_eq!(out.notes[..2], [0xE0, -9i32 as u32], "{what}");
                    all.push(out);
                } else {
                    assert_eq!(report.exceptions, 0, "{what}");
                    assert!(!out.notes.contains(&0xE0), "{what}");
                }
            }
            let (out, report) = t.one(
                &p,
                &sbt,
                handle(&gas),
                down.interval(0.0, f32::INFINITY),
                &[],
            );
            assert_eq!(report.exceptions, 0);
            assert_eq!(progs(&out.notes), [0xA0, 0xC0]);
            all.push(out);
        }
        all
    });
}

/// Twin of `invalid_miss_sbt_index_13_14`: a miss with a miss index past the miss records raises
/// `INVALID_MISS_SBT` (-6), also with no miss records at all and with the null handle; no
/// program of the trace runs.
#[test]
fn invalid_miss_sbt_index_13_14() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 1);
        let gas = one_triangle(device);
        let two = t.sbt(
            "rg",
            &[("ch_log", 0)],
            &[("ms_log", 0), ("ms_log", 1)],
            true,
        );
        let none = t.sbt("rg", &[("ch_log", 0)], &[], true);
        let mut all = Vec::new();
        for (sbt, miss, ok) in [
            (&two, 0, true),
            (&two, 1, true),
            (&two, 2, false),
            (&two, 0x10, false),
            (&none, 0, false),
        ] {
            for h in [handle(&gas), 0] {
                let ray = RayIn::down(5.0, 5.0).sbt(0, 1, miss);
                let (out, report) = t.one(&p, sbt, h, ray, &[]);
                if ok {
                    assert_eq!(report.exceptions, 0, "miss index {miss}");
                    assert_eq!(out.notes, [0x40], "miss index {miss}");
                } else {
                    let (code, _) = only_exception(&report);
                    assert_eq!(code, ExceptionCode::INVALID_MISS_SBT.0, "miss index {miss}");
                    assert_eq!(out.notes[..2], [0xE0, -6i32 as u32], "miss index {miss}");
                    assert_eq!(out.notes.len(), 11, "miss index {miss}: a program ran");
                }
                all.push(out);
            }
        }
        assert_eq!(ExceptionCode::INVALID_MISS_SBT.0, -6);
        all
    });
}

/// Twin of `invalid_hit_sbt_index_13_14`: a hit whose hit-group index lies past the hit records
/// raises `INVALID_HIT_SBT` (-7) before any program of that record runs (triangles and custom
/// primitives); only the low 4 bits of the trace's offset and stride count.
#[test]
fn invalid_hit_sbt_index_13_14() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 1);
        let sbt = t.sbt("rg", &[("log", 0), ("log", 1)], &[("ms_log", 0)], true);
        let tris = one_triangle(device);
        let (boxes, tops) = one_box(device);
        let mut all = Vec::new();
        for h in [handle(&tris), handle(&boxes)] {
            for (offset, stride, ok) in [
                (0, 1, true),
                (1, 1, true),
                (2, 1, false),
                (0x12, 1, false),
                (0x11, 0x10, true),
                (5, 0, false),
            ] {
                let ray = RayIn::down(0.0, 0.0).sbt(offset, stride, 0);
                let (out, report) = t.one(&p, &sbt, h, ray, &tops);
                let what = format!("offset {offset:#x} stride {stride:#x}");
                if ok {
                    assert_eq!(report.exceptions, 0, "{what}");
                    assert_eq!(progs(&out.notes).iter().filter(|&&x| x == 0xC0).count(), 1);
                } else {
                    let (code, _) = only_exception(&report);
                    assert_eq!(code, ExceptionCode::INVALID_HIT_SBT.0, "{what}");
                    assert_eq!(out.notes[..2], [0xE0, -7i32 as u32], "{what}");
                    assert_eq!(
                        out.notes.len(),
                        11,
                        "{what}: a program ran: {:x?}",
                        out.notes
                    );
                }
                all.push(out);
            }
        }
        assert_eq!(ExceptionCode::INVALID_HIT_SBT.0, -7);
        all
    });
}

/// Twin of `traversable_graph_flags_single_gas_6_3`: a pipeline whose traversable-graph flags
/// do not allow a single GAS raises `UNSUPPORTED_SINGLE_LEVEL_GAS` when a GAS is traced
/// directly; flags that allow it (or no flags) do not.
#[test]
fn traversable_graph_flags_single_gas_6_3() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let gas = one_triangle(device);
        let sbt = t.sbt("rg", &[("log_tri", 0)], &[("ms_log", 0)], true);
        let allow_gas = TraversableGraphFlags::ALLOW_SINGLE_GAS;
        let instancing = TraversableGraphFlags::ALLOW_SINGLE_LEVEL_INSTANCING;
        let mut all = Vec::new();
        for (flags, ok) in [
            (TraversableGraphFlags::empty(), true),
            (allow_gas, true),
            (allow_gas | instancing, true),
            (instancing, false),
        ] {
            let c = PipelineCompileOptions {
                traversable_graph_flags: flags,
                ..compile()
            };
            let p = t.pipeline(&c, 1);
            let (out, report) = t.one(&p, &sbt, handle(&gas), RayIn::down(0.0, 0.0), &[]);
            if ok {
                assert_eq!(report.exceptions, 0, "{flags:?}");
                assert_eq!(progs(&out.notes), [0xA0, 0xC0], "{flags:?}");
            } else {
                let (code, _) = only_exception(&report);
                assert_eq!(
                    code,
                    ExceptionCode::UNSUPPORTED_SINGLE_LEVEL_GAS.0,
                    "{flags:?}"
                );
                assert_eq!(out.notes.len(), 11, "{flags:?}: a program ran");
            }
            all.push(out);
        }
        all
    });
}

/// Twin of `primitive_type_flags_6_3`: a pipeline whose primitive-type flags exclude the
/// primitives of the traced GAS raises `UNSUPPORTED_PRIMITIVE_TYPE`; empty flags mean
/// triangles and custom primitives.
#[test]
fn primitive_type_flags_6_3() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let tris = one_triangle(device);
        let (boxes, tops) = one_box(device);
        let sbt = t.sbt("rg", &[("log", 0)], &[("ms_log", 0)], true);
        let tri = PrimitiveTypeFlags::TRIANGLE;
        let custom = PrimitiveTypeFlags::CUSTOM;
        let mut all = Vec::new();
        for (flags, gas, ok) in [
            (PrimitiveTypeFlags::empty(), &tris, true),
            (PrimitiveTypeFlags::empty(), &boxes, true),
            (tri, &tris, true),
            (tri, &boxes, false),
            (custom, &boxes, true),
            (custom, &tris, false),
            (tri | custom, &boxes, true),
            (tri | custom, &tris, true),
        ] {
            let c = PipelineCompileOptions {
                uses_primitive_type_flags: flags,
                ..compile()
            };
            let p = t.pipeline(&c, 1);
            let (out, report) = t.one(&p, &sbt, handle(gas), RayIn::down(0.0, 0.0), &tops);
            if ok {
                assert_eq!(report.exceptions, 0, "{flags:?}");
                assert_eq!(progs(&out.notes).last(), Some(&0xC0), "{flags:?}");
            } else {
                let (code, _) = only_exception(&report);
                assert_eq!(
                    code,
                    ExceptionCode::UNSUPPORTED_PRIMITIVE_TYPE.0,
                    "{flags:?}"
                );
            }
            all.push((out, report.exceptions));
        }
        all
    });
}

/// Twin of `exception_in_nested_trace_unwinds_all_levels_13_14`: an exception from a nested
/// trace (a user exception in the nested miss program) unwinds through the closest-hit program
/// that traced: neither it nor the ray-generation program continues.
#[test]
fn exception_in_nested_trace_unwinds_all_levels_13_14() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 2);
        let sbt = t.sbt(
            "rg",
            &[("nest_null", 0)],
            &[("ms_log", 0), ("ms_throw77", 0)],
            true,
        );
        let gas = one_triangle(device);
        let (out, report) = t.one(&p, &sbt, handle(&gas), RayIn::down(0.0, 0.0), &[]);
        let mut expected = vec![0xC0];
        expected.extend(ex(77, &[1, 2, 3], 0));
        assert_eq!(out.notes, expected);
        assert!(out.payload.is_none());
        assert_eq!(only_exception(&report), (77, vec![1, 2, 3]));
        out
    });
}

// ----------------------------------------------------------------------------------------------
// Payload, attributes, hit kinds (pipeline_payload.rs)
// ----------------------------------------------------------------------------------------------

/// Twin of `payload_longer_than_num_payload_values_raises_z3`: a trace may pass at most
/// `numPayloadValues` words; more raises `PAYLOAD_TYPE_MISMATCH` and the trace does not return
/// (no program runs); fewer or exactly as many is fine. (The original's 33 words cannot be
/// written with `optixTrace`, which takes at most 32.)
#[test]
fn payload_longer_than_num_payload_values_raises_13_3() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let gas = one_triangle(device);
        let sbt = t.sbt("rg", &[("ch_log", 0)], &[("ms_log", 0)], false);
        let mut all = Vec::new();
        for (num, len, ok) in [
            (4, 4, true),
            (4, 0, true),
            (4, 2, true),
            (4, 5, false),
            (0, 1, false),
            (32, 32, true),
        ] {
            let c = PipelineCompileOptions {
                num_payload_values: num,
                ..compile()
            };
            let p = t.pipeline(&c, 1);
            let payload = vec![3u32; len];
            let ray = RayIn::down(0.0, 0.0).payload(&payload);
            let (out, report) = t.one(&p, &sbt, handle(&gas), ray, &[]);
            let what = format!("numPayloadValues {num}, payload {len}");
            if ok {
                assert_eq!(report.exceptions, 0, "{what}");
                assert_eq!(out.payload(), payload, "{what}");
                assert_eq!(out.notes, [0xC0, 0], "{what}");
            } else {
                let (code, _) = only_exception(&report);
                assert_eq!(code, ExceptionCode::PAYLOAD_TYPE_MISMATCH.0, "{what}");
                assert!(out.payload.is_none(), "{what}: the trace returned");
                assert!(
                    out.notes.is_empty(),
                    "{what}: programs ran: {:x?}",
                    out.notes
                );
            }
            all.push(out);
        }
        all
    });
}

/// Twin of `num_attribute_values_below_2_become_2_13_4_n8`: `numAttributeValues` below 2 counts
/// as 2 (two reported attribute words and the triangle barycentrics always arrive), and every
/// word up to `numAttributeValues` reaches the AH and CH.
#[test]
fn num_attribute_values_below_2_become_2_13_4() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let (boxes, tops) = one_box(device);
        let tri = one_triangle(device);
        let mut all = Vec::new();
        for (num, kept) in [(0u32, 2usize), (1, 2), (2, 2), (3, 3), (8, 8)] {
            let c = PipelineCompileOptions {
                num_attribute_values: num,
                ..compile()
            };
            let p = t.pipeline(&c, 1);
            let sbt = t.sbt("rg", &[("attrs8", 0)], &[("ms_log", 0)], false);
            let (out, _) = t.one(&p, &sbt, handle(&boxes), RayIn::down(0.0, 0.0), &tops);
            assert_eq!(out.notes.len(), 18, "{num}: {:?}", out.notes);
            let expected: Vec<u32> = (11..11 + kept as u32).collect();
            let (ah, ch) = (&out.notes[1..1 + kept], &out.notes[10..10 + kept]);
            assert_eq!([out.notes[0], out.notes[9]], [0xA0, 0xC0]);
            assert_eq!(ah, expected, "numAttributeValues {num}");
            assert_eq!(ch, expected, "numAttributeValues {num}");
            let sbt = t.sbt("rg", &[("attrs8_tri", 0)], &[("ms_log", 0)], false);
            let (bary, _) = t.one(&p, &sbt, handle(&tri), RayIn::down(0.25, 0.0), &[]);
            let [u, v] = [bary.notes[1], bary.notes[2]].map(f32::from_bits);
            assert!(
                u > 0.0 && v > 0.0 && u + v < 1.0,
                "numAttributeValues {num}: ({u}, {v})"
            );
            // Words past numAttributeValues are the device's business.
            all.push((ah.to_vec(), ch.to_vec(), bary.notes[..3].to_vec()));
        }
        all
    });
}

/// Twin of `triangle_barycentrics_are_attributes_0_1_13_4_g25`: for triangles, attributes 0
/// and 1 are the barycentrics (`optixGetTriangleBarycentrics`), with OptiX's convention: the
/// hit point is `(1 - u - v) v0 + u v1 + v v2`; AH and CH agree. The same 60 random cases.
#[test]
fn triangle_barycentrics_are_attributes_0_1_13_4() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 1);
        let sbt = t.sbt("rg", &[("bary", 0)], &[("ms_none", 0)], false);
        let mut rng = Rng::new(25);
        let mut checked = 0;
        let mut all = Vec::new();
        for case in 0..60 {
            let tri: Tri = std::array::from_fn(|_| rng.vec3(-2.0, 2.0).to_array());
            let [a, b, c] = tri.map(Vec3::from);
            let n = (b - a).cross(c - a);
            if n.length() < 0.5 {
                continue;
            }
            let (u, v) = (rng.range(0.05, 0.9), rng.range(0.05, 0.9));
            if u + v > 0.95 {
                continue;
            }
            let pt = (1.0 - u - v) * a + u * b + v * c;
            let origin = pt + rng.dir() * 5.0;
            let gas = tri_gas(device, &[tri]);
            let ray = RayIn::new(origin, pt - origin).payload(&[0, 0, 0, 0]);
            let (out, report) = t.one(&p, &sbt, handle(&gas), ray, &[]);
            assert_eq!(report.exceptions, 0);
            if out.notes.is_empty() {
                // The random origin may lie in the triangle's plane; skip such grazing rays.
                all.push(out);
                continue;
            }
            let w = out.payload();
            let (hu, hv, tt) = (
                f32::from_bits(w[0]),
                f32::from_bits(w[1]),
                f32::from_bits(w[2]),
            );
            assert_eq!(out.notes.len(), 8, "case {case}");
            assert_eq!([out.notes[0], out.notes[4]], [0xA0, 0xC0], "case {case}");
            assert_eq!([out.notes[3], out.notes[7]], [1, 1], "case {case}");
            assert_eq!(
                out.notes[1..3],
                out.notes[5..7],
                "case {case}: AH and CH agree"
            );
            assert!(
                (hu - u).abs() < 1e-3 && (hv - v).abs() < 1e-3,
                "case {case}: ({hu}, {hv}) vs ({u}, {v})"
            );
            let hit = (1.0 - hu - hv) * a + hu * b + hv * c;
            let along = origin + (pt - origin) * tt;
            assert!(
                (hit - along).length() < 1e-3,
                "case {case}: {hit} vs {along}"
            );
            checked += 1;
            all.push(out);
        }
        assert!(checked >= 20, "only {checked} cases hit");
        all
    });
}

/// Twin of `triangle_hit_kinds_and_facing_13_7_u5`: triangle hits report hit kind 0xFE (front,
/// counter-clockwise as seen by the ray) or 0xFF (back), and `optixIsTriangleHit`,
/// `optixIsFrontFaceHit`, `optixIsBackFaceHit` agree, in AH and CH.
#[test]
fn triangle_hit_kinds_and_facing_13_7() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 1);
        let sbt = t.sbt("rg", &[("face", 0)], &[("ms_none", 0)], false);
        let ccw = tri_at(0.0, 0.0, 0.0, 1.0);
        let cw = [ccw[0], ccw[2], ccw[1]];
        let down = RayIn::down(0.0, 0.0);
        let up = RayIn::new(Vec3::new(0.0, 0.0, -10.0), Vec3::Z);
        let mut all = Vec::new();
        for (tri, ray, front) in [
            (ccw, down, true),
            (ccw, up, false),
            (cw, down, false),
            (cw, up, true),
        ] {
            let gas = tri_gas(device, &[tri]);
            let (out, _) = t.one(&p, &sbt, handle(&gas), ray, &[]);
            let fc = if front {
                [0xFE, 1, 1, 0]
            } else {
                [0xFF, 1, 0, 1]
            };
            let mut expected = vec![0xA0];
            expected.extend(fc);
            expected.push(0xC0);
            expected.extend(fc);
            assert_eq!(out.notes, expected, "front {front}");
            all.push(out);
        }
        all
    });
}

/// Twin of `intersection_program_sees_its_primitive_13_7`: an intersection program sees its
/// primitive: the primitive index (with the input's offset) and the SBT-GAS index. (The
/// original's primitive box has no device function in OptiX.)
#[test]
fn intersection_program_sees_its_primitive_13_7() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 1);
        let sbt = t.sbt(
            "rg",
            &[("who", 0), ("who", 1), ("who", 2)],
            &[("ms_none", 0)],
            false,
        );
        let a = [
            cube(Vec3::new(0.0, 0.0, 0.0), 0.5),
            cube(Vec3::new(3.0, 0.0, 0.0), 0.25),
        ];
        let b = [Aabb::new(
            Vec3::new(5.5, -0.5, -1.0),
            Vec3::new(6.5, 0.75, 0.0),
        )];
        let flags2 = [GeometryFlags::empty(); 2];
        let offsets = [1u8, 0];
        let inputs: [BuildInput; 2] = [
            CustomPrimitiveInput::new(AabbBuffer::new(&a))
                .flags(&flags2)
                .sbt_index_offsets(SbtIndexOffsets::u8(&offsets))
                .primitive_index_offset(40)
                .into(),
            CustomPrimitiveInput::new(AabbBuffer::new(&b))
                .primitive_index_offset(7)
                .into(),
        ];
        let gas = device.build_gas(&BuildOptions::default(), &inputs).unwrap();
        let mut all = Vec::new();
        for (x, expected) in [(0.0, [40, 1]), (3.0, [41, 0]), (6.0, [7, 2])] {
            let (out, report) = t.one(&p, &sbt, handle(&gas), RayIn::down(x, 0.0), &[]);
            assert_eq!(report.exceptions, 0);
            assert_eq!(out.notes, expected, "x = {x}");
            all.push(out);
        }
        all
    });
}

/// Twin of `instance_queries_with_gas_root_13_7_g21`: with a GAS as the traced handle,
/// `optixGetInstanceId` is `~0` and `optixGetInstanceIndex` 0 in AH and CH, for triangles and
/// custom primitives.
#[test]
fn instance_queries_with_gas_root_13_7() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 1);
        let sbt = t.sbt("rg", &[("inst", 0)], &[("ms_none", 0)], false);
        let tri = one_triangle(device);
        let (boxes, tops) = one_box(device);
        let mut all = Vec::new();
        for gas in [&tri, &boxes] {
            let ray = RayIn::down(0.0, 0.0).flags(RayFlags::ENFORCE_ANYHIT);
            let (out, _) = t.one(&p, &sbt, handle(gas), ray, &tops);
            assert_eq!(out.notes, [0xA0, !0, 0, 0xC0, !0, 0]);
            all.push(out);
        }
        all
    });
}

// ----------------------------------------------------------------------------------------------
// The SBT (pipeline_sbt.rs)
// ----------------------------------------------------------------------------------------------

/// The scene of pipeline_sbt.rs: three triangle inputs with 2, 1 and 3 SBT records,
/// per-primitive SBT index offsets and primitive index offsets 100, 7 and 0; triangle `k` (over
/// all inputs) lies around `(3k, 0, 0)`. The GAS, a ray down at each triangle and one at the
/// empty spot `(27, 0)` (4 payload words, all `!0`), and the expected `(sbtGASIndex, primitive
/// index)` of each triangle.
fn three_input_scene(device: &Device) -> (oxray::Gas, Vec<RayIn>, Vec<(u32, u32)>) {
    let (gas, expected) = common::three_input_gas(device);
    let rays = (0..10)
        .map(|k| RayIn::down(3.0 * k as f32, 0.0).payload(&[!0; 4]))
        .collect();
    (gas, rays, expected)
}

/// Twin of `record_address_base_plus_index_times_stride_7_2_g22`: record `i` of a region lies
/// at `base + i * stride`, and `optixGetSbtDataPointer` points 32 bytes into it, for regions
/// laid out by hand with a stride larger than the records need (80 and 128 bytes).
#[test]
fn record_address_base_plus_index_times_stride_7_2() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 1);
        let region = |header: oxray::SbtHeader, stride: usize, count: usize, base: u32| {
            let mut bytes = vec![0xEEu8; stride * count];
            for i in 0..count {
                let r = &mut bytes[i * stride..(i + 1) * stride];
                r[..32].copy_from_slice(&header.0);
                r[32..36].copy_from_slice(&(base + i as u32).to_le_bytes());
            }
            SbtRegion::from_bytes(bytes, stride, count).unwrap()
        };
        let sbt = ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[t.header("rg")]),
            miss: region(t.header("ms_record"), 80, 3, 700),
            hitgroup: region(t.header("record"), 128, 8, 2000),
            ..Default::default()
        };
        let (gas, rays, expected) = three_input_scene(device);
        let rays: Vec<RayIn> = rays.iter().map(|r| r.sbt(1, 1, 2)).collect();
        let (out, report) = t.launch(&p, &sbt, handle(&gas), &rays, &[], 0, [10, 1, 1]);
        assert_eq!(report.exceptions, 0, "{report:?}");
        for (k, &(gas_index, _)) in expected.iter().enumerate() {
            assert_eq!(out[k].payload()[0], 2000 + gas_index + 1, "triangle {k}");
        }
        assert_eq!(out[9].payload()[0], 702, "miss record 2");
        out
    });
}

/// Twin of `program_group_reused_across_pipelines_6_6`: a program group may serve several
/// records and several pipelines; the same SBT (same headers) works with every pipeline that
/// holds the groups, whatever their order there.
#[test]
fn program_group_reused_across_pipelines_6_6() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let pick = |labels: &[&'static str]| -> Vec<(&'static str, ProgramGroup)> {
            labels.iter().map(|&l| (l, t.group(l).clone())).collect()
        };
        let p1 = t.pipeline_of(&pick(&["rg", "record", "ms_record"]), &compile(), 1);
        let p2 = t.pipeline_of(&pick(&["ms_record", "record", "rg"]), &compile(), 2);
        let sbt = t.sbt(
            "rg",
            &[("record", 1000), ("record", 1001)],
            &[("ms_record", 500)],
            false,
        );
        let gas = one_triangle(device);
        let rays = [
            RayIn::down(0.0, 0.0).sbt(1, 1, 0).payload(&[!0; 4]),
            RayIn::down(9.0, 0.0).sbt(1, 1, 0).payload(&[!0; 4]),
        ];
        let mut all = Vec::new();
        for p in [&p1, &p2] {
            let (out, report) = t.launch(p, &sbt, handle(&gas), &rays, &[], 0, [2, 1, 1]);
            assert_eq!(report.exceptions, 0, "{report:?}");
            assert_eq!(out[0].payload(), [1001, 0, 0, 1]);
            assert_eq!(out[1].payload(), [500, !0, !0, 2]);
            all.push(out);
        }
        all
    });
}

/// Twin of `indexed_input_with_u32_offsets_selects_records_7_3_2`: a triangle input with an
/// index buffer and a `u32` SBT index offset buffer selects records the same way as a soup.
#[test]
fn indexed_input_with_u32_offsets_selects_records_7_3_2() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 1);
        let v = [
            [0.0f32, -1.0, 0.0],
            [2.0, -1.0, 0.0],
            [1.0, 1.0, 0.0],
            [4.0, 1.0, 0.0],
            [3.0, -1.0, 0.0],
        ];
        let idx = [[0u32, 1, 2], [2, 4, 3]];
        let offs = [3u32, 1];
        let flags = [GeometryFlags::empty(); 4];
        let input = TriangleInput::new(VertexBuffer::f32x3(&v))
            .indices(IndexBuffer::u32x3(&idx))
            .flags(&flags)
            .sbt_index_offsets(SbtIndexOffsets::u32(&offs))
            .primitive_index_offset(5);
        let gas = device
            .build_gas(&BuildOptions::default(), &[input.into()])
            .unwrap();
        let hits: Vec<(&str, u32)> = (0..8).map(|i| ("record", 1000 + i)).collect();
        let sbt = t.sbt("rg", &hits, &[("ms_record", 500)], false);
        let rays = [
            RayIn::down(1.0, -0.5).sbt(0, 2, 0).payload(&[!0; 4]),
            RayIn::down(3.0, 0.5).sbt(0, 2, 0).payload(&[!0; 4]),
        ];
        let (out, report) = t.launch(&p, &sbt, handle(&gas), &rays, &[], 0, [2, 1, 1]);
        assert_eq!(report.exceptions, 0, "{report:?}");
        assert_eq!(out[0].payload(), [1006, 3, 5, 1]);
        assert_eq!(out[1].payload(), [1002, 1, 6, 1]);
        out
    });
}

// ----------------------------------------------------------------------------------------------
// REQUIRE_SINGLE_ANYHIT_CALL (pipeline_trace.rs)
// ----------------------------------------------------------------------------------------------

/// Twin of `require_single_anyhit_call_5_1_g12`: with `REQUIRE_SINGLE_ANYHIT_CALL`, AH runs at
/// most once per primitive and ray (and an intersection program at most once per custom
/// primitive and ray); with every candidate ignored, every triangle along the ray (as the CPU's
/// query finds them) gets its AH call. The same random scene and rays.
#[test]
fn require_single_anyhit_call_5_1() {
    let mut rng = Rng::new(12);
    let n = 400;
    let tris = random_soup(&mut rng, n, 4.0, 3.0);
    let boxes: Vec<Aabb> = (0..n)
        .map(|_| cube(rng.vec3(0.0, 4.0), rng.range(0.2, 1.5)))
        .collect();
    let rays: Vec<(Vec3, Vec3)> = (0..64)
        .map(|_| {
            let o = rng.vec3(-2.0, 6.0) + Vec3::new(0.0, 0.0, 12.0);
            let target = rng.vec3(1.0, 3.0);
            (o, target - o)
        })
        .collect();
    let flags = GeometryFlags::REQUIRE_SINGLE_ANYHIT_CALL;
    // The triangles along each ray, by the CPU's query.
    let reference = {
        let v = soup(&tris);
        let fl = [flags];
        let input = TriangleInput::new(VertexBuffer::f32x3(&v)).flags(&fl);
        let gas = oxray::cpu::Gas::build(&BuildOptions::default(), &[input.into()]).unwrap();
        rays.iter()
            .map(|&(o, d)| {
                let mut along = std::collections::BTreeSet::new();
                gas.intersect_filtered(
                    &oxray::Ray::new(o, d),
                    &mut oxray::NoCustomPrimitives,
                    |h| {
                        along.insert(h.primitive_index as usize);
                        oxray::CandidateAction::Ignore
                    },
                );
                along
            })
            .collect::<Vec<_>>()
    };
    let ray_in: Vec<RayIn> = rays.iter().map(|&(o, d)| RayIn::new(o, d)).collect();
    let aux: Vec<f32> = boxes
        .iter()
        .flat_map(|b| [b.min.to_array(), b.max.to_array()].concat())
        .collect();
    on_every_device(|device| {
        let t = Twins::new(device);
        let c = PipelineCompileOptions {
            num_payload_values: 0,
            ..compile()
        };
        let p = t.pipeline(&c, 1);
        let tri = tri_gas_flags(device, &tris, flags);
        let (bx, _) = box_gas_flags(device, &boxes, flags);
        let mut compared = Vec::new();
        for (what, gas, group) in [
            ("triangles", &tri, "count_tri"),
            ("boxes", &bx, "count_box"),
        ] {
            let sbt = t.sbt("rg_count", &[(group, 0)], &[("ms_none", 0)], false);
            let m = rays.len() * n;
            let out = device.create_buffer::<u32>(2 * m).unwrap();
            let ray_buf = device.buffer_from_slice(&ray_in).unwrap();
            let aux_buf = device.buffer_from_slice(&aux).unwrap();
            let params = T3Params {
                out: out.device_ptr(),
                handle: handle(gas),
                rays: ray_buf.device_ptr(),
                aux: aux_buf.device_ptr(),
                mode: n as u32,
                pad: 0,
            };
            let report = p
                .launch_with(&params, &sbt, rays.len() as u32, 1, 1)
                .unwrap_or_else(|e| panic!("{} launch: {e}", name(device)));
            assert_eq!(report.exceptions, 0, "{report:?}");
            let counts = out.download().unwrap();
            let (ah, is) = counts.split_at(m);
            assert!(ah.iter().all(|&c| c <= 1), "{what}: an AH ran twice");
            assert!(is.iter().all(|&c| c <= 1), "{what}: an IS ran twice");
            let total: u32 = ah.iter().sum();
            assert!(
                total > rays.len() as u32 * 3,
                "{what}: the rays should meet many primitives ({total})"
            );
            if what == "triangles" {
                for (r, along) in reference.iter().enumerate() {
                    for &p in along {
                        assert_eq!(ah[r * n + p], 1, "ray {r} primitive {p}");
                    }
                }
                compared.push(ah.to_vec());
            }
        }
        compared
    });
}

// ----------------------------------------------------------------------------------------------
// Callables (callables.rs, pipeline_noreturn.rs)
// ----------------------------------------------------------------------------------------------

/// The launch of callables.rs: one launch index calling callables record `record` in `how` (0
/// direct (20, 22), 1 continuation (3.0), 2 direct with the wrong types, 3 direct (0)) over a
/// triangle at z = 1, with records add (data 2), probe and recurse; what it wrote (or the
/// exception code and 2) and the exception code.
fn callables_launch(t: &Twins, record: u32, how: u32) -> ([u32; 2], Option<i32>) {
    let p = t.pipeline(&compile(), 2);
    let v = [[-1.0f32, -1.0, 1.0], [1.0, -1.0, 1.0], [0.0, 1.0, 1.0]];
    let gas = t
        .device
        .build_gas(
            &BuildOptions::default(),
            &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()],
        )
        .unwrap();
    let mut sbt = t.sbt("rg_calls", &[("call_add", 0)], &[("ms_none", 0)], true);
    sbt.callables = t.region(&[("dc_add", 2), ("cc_probe", 0), ("dc_recurse", 0)]);
    let (out, report) = t.launch(
        &p,
        &sbt,
        handle(&gas),
        &[RayIn::down(0.0, 0.0).payload(&[0, 0])],
        &[],
        record | how << 8,
        [1, 1, 1],
    );
    let code = report.first_exceptions.first().map(|(_, e)| e.code.0);
    let o = &out[0];
    if o.notes.first() == Some(&0xE0) {
        assert_eq!(Some(o.notes[1] as i32), code);
        return ([o.notes[1], 2], code);
    }
    // The ray-generation program writes its result and 1 over payload words 0 and 1.
    let w = o.payload();
    ([w[0], w[1]], code)
}

/// Twin of `direct_call_runs_the_records_callable_with_its_sbt_data_15_2` and
/// `continuation_call_may_trace_and_closest_hit_may_call_direct_callables_15_1`: a direct call
/// runs its record's callable with its record's data; a continuation callable traces, and the
/// closest-hit program of that trace calls a direct callable: (1 + 0) * 2 = 2, plus 100.
#[test]
fn closest_hit_and_continuation_callables_15() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let direct = callables_launch(&t, 0, 0);
        assert_eq!(direct, ([84, 1], None));
        let continuation = callables_launch(&t, 1, 1);
        assert_eq!(continuation, ([102, 1], None));
        (direct, continuation)
    });
}

/// Twin of `runaway_recursion_raises_stack_overflow_instead_of_crashing` (and of the exceptions
/// of callables.rs, which conformance.rs covers with its own scenario): a direct callable that
/// calls itself forever raises `STACK_OVERFLOW`; an index past the records, a record without
/// the callable kind and the wrong argument types raise their exceptions.
#[test]
fn callables_raise_their_exceptions_15() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let mut all = Vec::new();
        for (record, how, code) in [
            (2, 3, ExceptionCode::STACK_OVERFLOW),
            (7, 0, ExceptionCode::CALLABLE_INVALID_SBT),
            (1, 0, ExceptionCode::CALLABLE_NO_DC_SBT_RECORD),
            (0, 1, ExceptionCode::CALLABLE_NO_CC_SBT_RECORD),
            (0, 2, ExceptionCode::CALLABLE_PARAMETER_MISMATCH),
        ] {
            let out = callables_launch(&t, record, how);
            assert_eq!(out, ([code.0 as u32, 2], Some(code.0)), "{code:?}");
            all.push(out);
        }
        all
    });
}

/// Twin of `s13_14_throw_dropped_still_raises_from_direct_callable`,
/// `…_from_continuation_callable` and `…_from_callable_in_any_hit`: a direct callable called
/// from a closest-hit program, a continuation callable called from the ray-generation program
/// and a direct callable called from an any-hit program that throw end the launch index: the
/// call does not return, the candidate is not accepted, the trace does not return.
#[test]
fn callables_that_throw_end_the_launch_index_13_14() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 1);
        let gas = stack(device, 1);
        let h = handle(&gas);
        let down = RayIn::down(0.0, 0.0);
        let mut all = Vec::new();
        // From a closest-hit program.
        let mut sbt = t.sbt("rg", &[("call_throw", 0)], &[("ms_log", 0)], true);
        sbt.callables = t.region(&[("dc_throw13", 0)]);
        let (out, report) = t.one(&p, &sbt, h, down, &[]);
        assert_eq!(only_exception(&report), (13, vec![5]));
        let mut expected = vec![0xC0];
        expected.extend(ex(13, &[5], 0));
        assert_eq!(out.notes, expected);
        assert!(out.payload.is_none(), "the trace returned");
        all.push(out);
        // From the ray-generation program.
        let mut sbt = t.sbt("rg_cc_throw", &[("log_tri", 0)], &[("ms_log", 0)], true);
        sbt.callables = t.region(&[("cc_throw14", 0)]);
        let (out, report) = t.one(&p, &sbt, h, down, &[]);
        assert_eq!(only_exception(&report), (14, vec![3]));
        let mut expected = vec![0x96];
        expected.extend(ex(14, &[3], 0));
        assert_eq!(out.notes, expected);
        all.push(out);
        // From an any-hit program, with the record's data.
        let mut sbt = t.sbt("rg", &[("ah_call_throw", 0)], &[("ms_log", 0)], true);
        sbt.callables = t.region(&[("dc_throw15", 0)]);
        let (out, report) = t.one(&p, &sbt, h, down, &[]);
        assert_eq!(only_exception(&report), (15, vec![0, 0]));
        let mut expected = vec![0xA0, 0];
        expected.extend(ex(15, &[0, 0], 0));
        assert_eq!(out.notes, expected, "no CH, no MS");
        assert!(out.payload.is_none(), "the trace returned");
        all.push(out);
        all
    });
}

// ----------------------------------------------------------------------------------------------
// The transform list and the graph depth (transform_list.rs)
// ----------------------------------------------------------------------------------------------

/// The triangle of transform_list.rs, at z = 0.
fn list_triangle(device: &Device) -> oxray::Gas {
    let v = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
    device
        .build_gas(
            &BuildOptions::default(),
            &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()],
        )
        .unwrap()
}

/// The ray of transform_list.rs: up from `(0.1, 0.1, -10)`.
fn list_ray() -> RayIn {
    RayIn::new(Vec3::new(0.1, 0.1, -10.0), Vec3::Z).payload(&[0])
}

/// One entry of `__anyhit__list` / `__closesthit__list`'s notes: (type, instance id, the 12
/// object-to-world words, whether the inverse takes a point back).
type Entry = (u32, u32, Vec<u32>, u32);

/// The lists in the notes: (tag, entries), AH's then CH's, and the CH's nearest instance id
/// and index.
fn lists(notes: &[u32]) -> (Vec<(u32, Vec<Entry>)>, [u32; 2]) {
    let mut out = Vec::new();
    let mut k = 0;
    while k < notes.len() && (notes[k] == 0xA0 || notes[k] == 0xC0) {
        let (tag, n) = (notes[k], notes[k + 1] as usize);
        k += 2;
        let mut entries = Vec::new();
        for _ in 0..n {
            entries.push((
                notes[k],
                notes[k + 1],
                notes[k + 2..k + 14].to_vec(),
                notes[k + 14],
            ));
            k += 15;
        }
        out.push((tag, entries));
        if tag == 0xC0 {
            break;
        }
    }
    assert_eq!(notes.len(), k + 2, "{notes:x?}");
    (out, [notes[k], notes[k + 1]])
}

/// Twin of `gas_root_has_an_empty_transform_list_13_11`: with a GAS as the traced handle the
/// transform list is empty in AH and CH.
#[test]
fn gas_root_has_an_empty_transform_list_13_11() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 1);
        let sbt = t.sbt("rg", &[("list", 0)], &[("ms_none", 0)], false);
        let gas = list_triangle(device);
        let (out, report) = t.one(&p, &sbt, handle(&gas), list_ray(), &[]);
        assert_eq!(report.exceptions, 0, "{report:?}");
        assert_eq!(out.payload(), [1], "the ray must hit");
        assert_eq!(out.notes, [0xA0, 0, 0xC0, 0, !0, 0]);
        out
    });
}

/// Twin of `nested_instances_and_static_transforms_are_listed_root_first_13_11`: over IAS
/// (instance 1, id 5) → static transform → IAS (instance 0, id 7) → GAS, the list runs from the
/// root: instance 5, the static transform, instance 7, with their object-to-world matrices,
/// whose inverses take points back, in AH and CH. (OptiX has no device function for the index
/// of a listed instance: the nearest instance's id and index stand in for it.)
#[test]
fn nested_instances_and_static_transforms_are_listed_root_first_13_11() {
    on_every_device(|device| {
        let t_inner = Transform::from_translation(Vec3::new(0.0, 0.0, 1.0));
        let t_static = Transform::from_translation(Vec3::new(0.0, 0.0, 2.0));
        let t_outer = Transform::from_translation(Vec3::new(0.0, 0.0, 3.0));
        let gas = list_triangle(device);
        let inner = device
            .build_ias(
                &BuildOptions::default(),
                &[(&[Instance::new(gas.handle())
                    .transform(t_inner)
                    .instance_id(7)][..])
                    .into()],
            )
            .unwrap();
        let st = StaticTransform::new(inner.handle(), t_static).unwrap();
        let outer = device
            .build_ias(
                &BuildOptions::default(),
                &[(&[
                    Instance::new(TraversableHandle::NULL),
                    Instance::new(TraversableHandle::from(st))
                        .transform(t_outer)
                        .instance_id(5),
                ][..])
                    .into()],
            )
            .unwrap();
        let t = Twins::new(device);
        let mut p = t.pipeline(&compile(), 1);
        // IAS, static transform, IAS, GAS: four levels (CUDA's default is two).
        p.set_max_traversable_graph_depth(4).unwrap();
        let sbt = t.sbt("rg", &[("list", 0)], &[("ms_none", 0)], false);
        let (out, report) = t.one(&p, &sbt, outer.optix_handle().unwrap(), list_ray(), &[]);
        assert_eq!(report.exceptions, 0, "{report:?}");
        assert_eq!(out.payload(), [1], "the ray must hit");
        let (seen, nearest) = lists(&out.notes);
        assert_eq!(seen.iter().map(|s| s.0).collect::<Vec<_>>(), [0xA0, 0xC0]);
        let words = |m: Transform| m.0.map(f).to_vec();
        for (_, list) in &seen {
            assert_eq!(
                list,
                &[
                    (4, 5, words(t_outer), 1),
                    (1, 0, words(t_static), 1),
                    (4, 7, words(t_inner), 1),
                ]
            );
        }
        assert_eq!(nearest, [7, 0]);
        out
    });
}

/// Twin of `max_traversable_graph_depth_is_enforced_6_8`: a trace of a graph deeper than the
/// pipeline's maximum traversable graph depth raises `TRAVERSAL_DEPTH_EXCEEDED`; the depth
/// must be in 1..=31. (No hit records: a hit raises `INVALID_HIT_SBT`.)
#[test]
fn max_traversable_graph_depth_is_enforced_6_8() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let mut p = t.pipeline(&compile(), 1);
        let sbt = t.sbt("rg", &[], &[("ms_none", 0)], false);
        let gas = list_triangle(device);
        let ias = device
            .build_ias(
                &BuildOptions::default(),
                &[(&[Instance::new(gas.handle())][..]).into()],
            )
            .unwrap();
        let ias_h = ias.optix_handle().unwrap();
        let code = |r: &LaunchReport| r.first_exceptions.first().map(|e| e.1.code);
        let (_, report) = t.one(&p, &sbt, ias_h, list_ray(), &[]);
        assert_eq!(report.exceptions, 1, "no hit group: an exception");
        let at_default = code(&report);
        assert_eq!(at_default, Some(ExceptionCode::INVALID_HIT_SBT));
        p.set_max_traversable_graph_depth(1).unwrap();
        let (_, report) = t.one(&p, &sbt, ias_h, list_ray(), &[]);
        let too_deep = code(&report);
        assert_eq!(too_deep, Some(ExceptionCode::TRAVERSAL_DEPTH_EXCEEDED));
        // A GAS (one level) is within the limit: traversal runs and finds no hit record.
        let (_, report) = t.one(&p, &sbt, handle(&gas), list_ray(), &[]);
        let gas_code = code(&report);
        assert_eq!(gas_code, Some(ExceptionCode::INVALID_HIT_SBT));
        assert!(p.set_max_traversable_graph_depth(0).is_err());
        assert!(p.set_max_traversable_graph_depth(32).is_err());
        (at_default, too_deep, gas_code)
    });
}

// ----------------------------------------------------------------------------------------------
// Launches (pipeline_launch.rs)
// ----------------------------------------------------------------------------------------------

/// Twin of `raygen_runs_once_per_launch_index_10_g41`: the ray-generation program runs exactly
/// once for every launch index of a 1D, 2D or 3D launch, and sees a launch index inside
/// `optixGetLaunchDimensions`.
#[test]
fn raygen_runs_once_per_launch_index_10() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 0);
        let sbt = t.sbt("rg_count_index", &[], &[], false);
        let mut all = Vec::new();
        for (w, h, d) in [
            (1, 1, 1),
            (1000, 1, 1),
            (37, 23, 1),
            (7, 5, 3),
            (1, 1, 300),
            (64, 1, 65),
            (513, 129, 1),
        ] {
            let n = (w * h * d) as usize;
            let out = device.buffer_from_slice(&vec![0u32; n + 1]).unwrap();
            let params = T3Params {
                out: out.device_ptr(),
                handle: 0,
                rays: 0,
                aux: 0,
                mode: 0,
                pad: 0,
            };
            let report = p
                .launch_with(&params, &sbt, w, h, d)
                .unwrap_or_else(|e| panic!("{} launch: {e}", name(device)));
            assert_eq!(report.exceptions, 0);
            let runs = out.download().unwrap();
            assert_eq!(runs[n], 0, "{w}x{h}x{d}: index outside the launch");
            let once = runs[..n].iter().all(|&r| r == 1);
            assert!(once, "{w}x{h}x{d}: {:?}", runs.iter().position(|&r| r != 1));
            all.push((w, h, d, once));
        }
        all
    });
}

/// Twin of `launch_larger_than_2_pow_30_is_refused_12_n14` and
/// `launch_size_product_overflow_is_refused_12_n14`: a launch of more than 2^30 indices,
/// including dimensions whose product overflows 64 bits, is refused with `TooLarge` (carrying
/// the dimensions) and runs nothing.
#[test]
fn launch_larger_than_2_pow_30_is_refused_12() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 0);
        let sbt = t.sbt("rg_count_index", &[], &[], false);
        let out = device.buffer_from_slice(&[0u32; 4]).unwrap();
        let params = T3Params {
            out: out.device_ptr(),
            handle: 0,
            rays: 0,
            aux: 0,
            mode: 0,
            pad: 0,
        };
        let mut all = Vec::new();
        for (w, h, d) in [
            ((1 << 30) + 1, 1, 1),
            (1, 1, u32::MAX),
            (1 << 15, 1 << 15, 2),
            (1 << 16, 1 << 16, 1),
            (1 << 10, 1 << 10, 1 << 11),
            (u32::MAX, u32::MAX, 1),
            (1 << 22, 1 << 22, 1 << 22),
            (1 << 31, 1 << 31, 4),
            (u32::MAX, u32::MAX, u32::MAX),
        ] {
            match p.launch_with(&params, &sbt, w, h, d) {
                Err(oxray::programs::ProgramError::Launch(LaunchError::TooLarge {
                    width,
                    height,
                    depth,
                })) => assert_eq!((width, height, depth), (w, h, d)),
                other => panic!("{w}x{h}x{d}: {other:?}"),
            }
            all.push((w, h, d));
        }
        assert_eq!(out.download().unwrap(), [0; 4], "a refused launch ran");
        all
    });
}

// ----------------------------------------------------------------------------------------------
// Functions that do not return (pipeline_noreturn.rs)
// ----------------------------------------------------------------------------------------------

/// Twin of `s13_13_ignore_then_terminate_first_wins`: after `optixIgnoreIntersection`, an
/// `optixTerminateRay` in the same any-hit program has no effect (on the CPU it is never
/// reached; on CUDA, where the calls return, the first one takes effect): every candidate is
/// ignored and the miss program runs.
#[test]
fn ignore_then_terminate_first_wins_13_13() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 1);
        let sbt = t.sbt("rg", &[("ignore_terminate", 0)], &[("ms_note7", 0)], true);
        let gas = stack(device, 3);
        let (out, report) = t.one(
            &p,
            &sbt,
            handle(&gas),
            RayIn::down(0.0, 0.0).payload(&[0, 0]),
            &[],
        );
        assert_eq!(report.exceptions, 0);
        let ev = events(&out.notes);
        let mut ah: Vec<u32> = ev.iter().filter(|e| e.0 == 0xA0).map(|e| e.1).collect();
        ah.sort();
        assert_eq!(ah, [0, 1, 2], "{:x?}", out.notes);
        assert_eq!(ev.last(), Some(&(0x40, 0)), "the miss program runs last");
        assert_eq!(out.notes.len(), 7, "no CH: {:x?}", out.notes);
        assert_eq!(out.payload(), [0, 7]);
        // The any-hit order is the traversal's, which the guide leaves open.
        (ah, out.payload)
    });
}

/// Twin of `s13_13_terminate_then_ignore_first_wins`: after `optixTerminateRay`, an
/// `optixIgnoreIntersection` in the same any-hit program has no effect: the first candidate is
/// accepted and ends traversal (one AH of eight stacked triangles, the CH sees it, no miss).
#[test]
fn terminate_then_ignore_first_wins_13_13() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 1);
        let sbt = t.sbt("rg", &[("terminate_ignore", 0)], &[("ms_log", 0)], true);
        let gas = stack(device, 8);
        let (out, report) = t.one(&p, &sbt, handle(&gas), RayIn::down(0.0, 0.0), &[]);
        assert_eq!(report.exceptions, 0);
        let ev = events(&out.notes);
        assert_eq!(ev.len(), 2, "{:x?}", out.notes);
        assert_eq!((ev[0].0, ev[1].0), (0xA0, 0xC0));
        assert_eq!(ev[0].1, ev[1].1, "the terminating candidate is the hit");
        // Which candidate comes first is the traversal's choice.
        out.payload
    });
}

/// Twin of the second half of `s13_13_ignore_and_throw_first_wins`: after a throw, an ignore is
/// never reached: the launch index ends with the exception, no CH or miss runs and the trace
/// does not return. (The first half, an ignore and then a throw, is the CPU's alone: on CUDA the
/// ignore returns and the throw is reached, docs/gpu-backend.md, "Deviations".)
#[test]
fn throw_then_ignore_throw_wins_13_14() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 1);
        let sbt = t.sbt("rg", &[("throw_ignore", 0)], &[("ms_log", 0)], true);
        let gas = stack(device, 1);
        let (out, report) = t.one(&p, &sbt, handle(&gas), RayIn::down(0.0, 0.0), &[]);
        assert_eq!(only_exception(&report), (6, vec![2]));
        let mut expected = vec![0xA0, 0];
        expected.extend(ex(6, &[2], 0));
        assert_eq!(out.notes, expected);
        assert!(out.payload.is_none(), "the trace did not return");
        out
    });
}

/// Twin of `s13_13_report_after_terminate_does_nothing`: when the any-hit program terminates the
/// ray during a report, a later report of the same intersection program runs no any-hit and is
/// not a hit; the closest hit is the terminating one. (On the CPU the first report does not
/// return; on CUDA it returns true and the second false, the documented deviation.)
#[test]
fn report_after_terminate_does_nothing_13_13() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 1);
        let sbt = t.sbt("rg", &[("twice", 0)], &[("ms_log", 0)], true);
        let (gas, tops) = box_gas_flags(device, &[cube(Vec3::ZERO, 1.0)], GeometryFlags::empty());
        let ray = RayIn::down(0.0, 0.0).payload(&[0, 0]);
        let (mut out, report) = t.one(&p, &sbt, handle(&gas), ray, &tops);
        assert_eq!(report.exceptions, 0);
        if code_after_runs(device) {
            let n = &mut out.notes;
            assert_eq!(n[6..9], [0xAF7E, 1, 0], "{n:x?}");
            n.drain(6..9);
        }
        assert_eq!(
            out.notes,
            [0x15, 0, 0xA0, f(10.5), 1, 11, 0xC0, f(10.5), 1, 11]
        );
        assert_eq!(out.payload(), [1, 0]);
        out
    });
}

/// Twin of `s13_13_ignore_and_terminate_passed_on_unchanged`: of five stacked triangles, the
/// any-hit program ignores primitives 3 and 4 (the nearest) and terminates on any other; nothing
/// after the terminate runs (on the CPU); the terminating candidate is the last any-hit and the
/// closest hit.
#[test]
fn ignore_and_terminate_from_any_hit_13_13() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let p = t.pipeline(&compile(), 1);
        let sbt = t.sbt("rg", &[("pass_on", 0)], &[("ms_log", 0)], true);
        let gas = stack(device, 5);
        let (mut out, report) = t.one(&p, &sbt, handle(&gas), RayIn::down(0.0, 0.0), &[]);
        assert_eq!(report.exceptions, 0);
        if code_after_runs(device) {
            let k = out.notes.len() - 3;
            assert_eq!(out.notes[k], 0xAF7E, "{:x?}", out.notes);
            out.notes.remove(k);
        }
        assert!(!out.notes.contains(&0xAF7E), "{:x?}", out.notes);
        let ev = events(&out.notes);
        let (ch, ah) = ev.split_last().unwrap();
        let last = *ah.last().unwrap();
        assert!(last.1 < 3, "{ah:?}");
        assert!(ah[..ah.len() - 1].iter().all(|e| e.1 >= 3), "{ah:?}");
        assert_eq!(*ch, (0xC0, last.1));
        // The any-hit order is the traversal's.
        last.1 < 3
    });
}

/// Every program of twins3.cu compiles for the GPU with NVRTC, GPU or not.
#[test]
fn the_twins3_compile_with_nvrtc() {
    use oxray::cuda::{CudaHitGroupDesc, CudaModule, CudaProgramGroup};
    let m = CudaModule::from_source(TWINS3);
    let e = |n: Option<&'static str>| n.map(|n| (&m, n));
    let mut groups = Vec::new();
    for (label, g) in GROUPS {
        let r = match g {
            G::Rg(n) => CudaProgramGroup::raygen(&m, n),
            G::Ms("") => CudaProgramGroup::miss(None),
            G::Ms(n) => CudaProgramGroup::miss(Some((&m, n))),
            G::Hit(ch, ah, is) => CudaProgramGroup::hit_group(CudaHitGroupDesc {
                closest_hit: e(ch),
                any_hit: e(ah),
                intersection: e(is),
            }),
            G::Call(dc, cc) => CudaProgramGroup::callables(e(dc), e(cc)),
            G::Ex(n) => CudaProgramGroup::exception(&m, n),
        };
        groups.push(r.unwrap_or_else(|e| panic!("{label}: {e}")));
    }
    let types = PipelineCompileOptions::default().uses_primitive_type_flags;
    common::assert_compiles_with_nvrtc("the twins3 programs", &groups, types);
}
