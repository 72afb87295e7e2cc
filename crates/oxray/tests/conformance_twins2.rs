//! CUDA C++ twins of scenarios of pipeline_payload.rs and pipeline_sbt.rs that neither
//! conformance.rs nor conformance_twins.rs covers, written against the OptiX device API
//! (programs in conformance/twins2.cu) and run on every device present: the CPU always (its
//! programs compiled by the host's C++ compiler) and a CUDA device where there is one
//! (`OXRAY_REQUIRE_GPU=1` makes its absence a failure). Each device must give the values the
//! Rust-closure original asserts, and all devices the same records.
//!
//! Covered: payload words never set come back unchanged and sets are visible to later programs
//! (§14), nested-trace payload isolation (§14) and closest-hit state after a nested trace
//! (§13.5), `optixReportIntersection`'s return values (§13.4), the 7-bit custom hit kind
//! (§13.4) and 8 attribute words (§13.4); the SBT-GAS index prefix sum over build inputs
//! (§7.3.2), the primitive index offset (§13.7), the miss record by miss index (§7.2) and the
//! SBT data pointer of raygen, exception, hit-group and miss records (§7.4).
//!
//! Every launch index traces one ray described by a [`RayIn`] record; the programs write notes
//! (words) into the launch index's record, and the ray-generation program the payload after
//! the trace.

mod common;

use common::{code_after_runs, name, on_every_device, HitSpec, LabelledPipeline, PipelineSpec};
use glam::Vec3;
use oxray::{
    Aabb, AabbBuffer, BuildOptions, CustomPrimitiveInput, Device, GeometryFlags, LaunchReport,
    PipelineCompileOptions, SbtRegion, ShaderBindingTable, TriangleInput, VertexBuffer,
};
use oxray_testkit::mesh::{soup, tri_at, Tri};

const TWINS2: &str = include_str!("conformance/twins2.cu");

/// Words of a launch index's record (`T2_WORDS` in twins2.cu), where its notes start and how
/// many fit.
const WORDS: usize = 128;
const NOTES_AT: usize = 16;
const MAX_NOTES: usize = 112;

const HIT_GROUPS: [HitSpec; 13] = [
    (
        "set",
        Some("__closesthit__set4"),
        Some("__anyhit__set2"),
        Some("__intersection__set1"),
    ),
    ("empty", Some("__closesthit__nothing"), None, None),
    (
        "p",
        Some("__closesthit__p"),
        Some("__anyhit__p"),
        Some("__intersection__p"),
    ),
    ("nest", Some("__closesthit__nest"), None, None),
    ("state", Some("__closesthit__state"), None, None),
    (
        "seq",
        Some("__closesthit__kind_t_attr"),
        Some("__anyhit__by_kind"),
        Some("__intersection__seq"),
    ),
    (
        "seq_no_ah",
        Some("__closesthit__kind_t_attr"),
        None,
        Some("__intersection__seq"),
    ),
    (
        "kind",
        Some("__closesthit__kind"),
        Some("__anyhit__kind"),
        Some("__intersection__kind"),
    ),
    (
        "attrs",
        Some("__closesthit__attrs"),
        Some("__anyhit__attrs"),
        Some("__intersection__attrs"),
    ),
    ("record", Some("__closesthit__record"), None, None),
    (
        "data_tri",
        Some("__closesthit__data"),
        Some("__anyhit__data"),
        None,
    ),
    (
        "data_box",
        Some("__closesthit__data"),
        None,
        Some("__intersection__data"),
    ),
    (
        "data_box_ah",
        Some("__closesthit__data"),
        Some("__anyhit__data"),
        Some("__intersection__data"),
    ),
];

const RAYGENS: [(&str, &str); 2] = [("rg", "__raygen__t2"), ("rg_data", "__raygen__data")];
const MISSES: [(&str, &str); 5] = [
    ("ms_set3", "__miss__set3"),
    ("ms_p", "__miss__p"),
    ("ms_nested", "__miss__nested"),
    ("ms_record", "__miss__record"),
    ("ms_data", "__miss__data"),
];
const EXCEPTION: &str = "__exception__data";

/// A ray of one launch index (`RayIn` in twins2.cu).
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
    payload: [u32; 8],
}

impl RayIn {
    /// Down -z from `(x, y, 10)`.
    fn down(x: f32, y: f32) -> RayIn {
        RayIn {
            origin: [x, y, 10.0],
            dir: [0.0, 0.0, -1.0],
            tmin: 0.0,
            tmax: f32::INFINITY,
            flags: 0,
            sbt_offset: 0,
            sbt_stride: 1,
            miss_index: 0,
            payload: [0; 8],
        }
    }

    fn interval(mut self, tmin: f32, tmax: f32) -> RayIn {
        (self.tmin, self.tmax) = (tmin, tmax);
        self
    }

    fn sbt(mut self, offset: u32, stride: u32, miss: u32) -> RayIn {
        (self.sbt_offset, self.sbt_stride, self.miss_index) = (offset, stride, miss);
        self
    }

    fn payload(mut self, p: &[u32]) -> RayIn {
        self.payload[..p.len()].copy_from_slice(p);
        self
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct T2Params {
    out: u64,
    handle: u64,
    rays: u64,
    tops: u64,
}

/// What one launch index did: the payload after the trace (if it returned) and the notes.
#[derive(Clone, Debug, PartialEq)]
struct Rec {
    payload: Option<[u32; 8]>,
    notes: Vec<u32>,
}

impl Rec {
    fn parse(w: &[u32; WORDS]) -> Rec {
        let m = w[9] as usize;
        assert!(m <= MAX_NOTES, "{m} notes: the record keeps {MAX_NOTES}");
        let mut payload = [0u32; 8];
        payload.copy_from_slice(&w[..8]);
        Rec {
            payload: (w[8] == 1).then_some(payload),
            notes: w[NOTES_AT..NOTES_AT + m].to_vec(),
        }
    }

    fn payload(&self) -> [u32; 8] {
        self.payload.expect("the trace did not return")
    }
}

fn f(x: f32) -> u32 {
    x.to_bits()
}

/// The records of an SBT region: (group label, data).
type Records<'a, T> = &'a [(&'a str, T)];

/// The twins' pipeline on one device (8 payload words, 8 attribute words, trace depth 2), with
/// its program groups by label.
struct Twins(LabelledPipeline);

impl std::ops::Deref for Twins {
    type Target = LabelledPipeline;

    fn deref(&self) -> &LabelledPipeline {
        &self.0
    }
}

impl Twins {
    fn new(device: &Device) -> Twins {
        let spec = PipelineSpec {
            source: TWINS2,
            params: "t2",
            raygens: &RAYGENS,
            misses: &MISSES,
            hit_groups: &HIT_GROUPS,
            exception: ("ex", EXCEPTION),
            compile: PipelineCompileOptions {
                num_payload_values: 8,
                num_attribute_values: 8,
                ..Default::default()
            },
            max_trace_depth: 2,
        };
        Twins(LabelledPipeline::new(device, &spec))
    }

    fn region<T: bytemuck::Pod>(&self, records: Records<'_, T>) -> SbtRegion {
        let r: Vec<(oxray::SbtHeader, T)> =
            records.iter().map(|(g, d)| (self.header(g), *d)).collect();
        SbtRegion::from_records(&r)
    }

    /// The SBT of the plain raygen and the hit and miss records given.
    fn sbt(&self, hits: Records<'_, u32>, misses: Records<'_, u32>) -> ShaderBindingTable {
        ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[self.header("rg")]),
            miss: self.region(misses),
            hitgroup: self.region(hits),
            ..Default::default()
        }
    }

    /// Traces `rays` (one per launch index) against `handle`; `tops` are the tops of the custom
    /// primitives' boxes by primitive index.
    fn run(
        &self,
        sbt: &ShaderBindingTable,
        handle: u64,
        rays: &[RayIn],
        tops: &[f32],
    ) -> (Vec<Rec>, LaunchReport) {
        let d = &self.device;
        let out = d.create_buffer::<[u32; WORDS]>(rays.len()).unwrap();
        let ray_buf = d.buffer_from_slice(rays).unwrap();
        let mut t = tops.to_vec();
        t.push(0.0);
        let tops_buf = d.buffer_from_slice(&t).unwrap();
        let params = T2Params {
            out: out.device_ptr(),
            handle,
            rays: ray_buf.device_ptr(),
            tops: tops_buf.device_ptr(),
        };
        let report = self
            .pipeline
            .launch_with(&params, sbt, rays.len() as u32, 1, 1)
            .unwrap_or_else(|e| panic!("{} launch: {e}", name(d)));
        let recs = out.download().unwrap().iter().map(Rec::parse).collect();
        (recs, report)
    }

    /// One ray through hit group `hit` (one record, data 0) and miss program `miss`, with no
    /// exception.
    fn one(&self, hit: &str, miss: &str, handle: u64, ray: RayIn, tops: &[f32]) -> Rec {
        let sbt = self.sbt(&[(hit, 0)], &[(miss, 0)]);
        let (mut recs, report) = self.run(&sbt, handle, &[ray], tops);
        assert_eq!(report.exceptions, 0, "{report:?}");
        recs.remove(0)
    }
}

// ----------------------------------------------------------------------------------------------
// Geometry
// ----------------------------------------------------------------------------------------------

fn cube(c: Vec3, h: f32) -> Aabb {
    Aabb::new(c - Vec3::splat(h), c + Vec3::splat(h))
}

fn tri_gas(device: &Device, tris: &[Tri]) -> oxray::Gas {
    let v = soup(tris);
    let fl = [GeometryFlags::empty()];
    let input = TriangleInput::new(VertexBuffer::f32x3(&v)).flags(&fl);
    device
        .build_gas(&BuildOptions::default(), &[input.into()])
        .unwrap()
}

/// A GAS of `boxes`, and the tops of the boxes.
fn box_gas(device: &Device, boxes: &[Aabb]) -> (oxray::Gas, Vec<f32>) {
    let fl = [GeometryFlags::empty()];
    let input = CustomPrimitiveInput::new(AabbBuffer::new(boxes)).flags(&fl);
    let gas = device
        .build_gas(&BuildOptions::default(), &[input.into()])
        .unwrap();
    (gas, boxes.iter().map(|b| b.max.z).collect())
}

/// One box under `(0, 0)` whose top face is at height 0.5 (a ray down from height 10 enters it
/// at t = 9.5).
fn one_box(device: &Device) -> (oxray::Gas, Vec<f32>) {
    box_gas(device, &[cube(Vec3::ZERO, 0.5)])
}

fn one_triangle(device: &Device) -> oxray::Gas {
    tri_gas(device, &[tri_at(0.0, 0.0, 0.0, 1.0)])
}

fn handle(gas: &oxray::Gas) -> u64 {
    gas.optix_handle().unwrap()
}

const INIT: [u32; 8] = [0xA0, 0xA1, 0xA2, 0xA3, 0xA4, 0xA5, 0xA6, 0xA7];

// ----------------------------------------------------------------------------------------------
// Payload (pipeline_payload.rs)
// ----------------------------------------------------------------------------------------------

/// Twin of `payload_words_never_set_come_back_unchanged_z3_g24`: payload words that no program
/// sets come back unchanged; words set by the programs of the trace come back with the last
/// value set. Miss path, hit path, and a trace whose programs set nothing.
#[test]
fn payload_words_never_set_come_back_unchanged_14() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let (gas, tops) = one_box(device);
        let h = handle(&gas);
        let hit = t.one(
            "set",
            "ms_set3",
            h,
            RayIn::down(0.0, 0.0).payload(&INIT),
            &tops,
        );
        assert_eq!(hit.payload(), [0xA0, 11, 22, 0xA3, 45, 0xA5, 0xA6, 0xA7]);
        let miss = t.one(
            "set",
            "ms_set3",
            h,
            RayIn::down(5.0, 0.0).payload(&INIT),
            &tops,
        );
        assert_eq!(
            miss.payload(),
            [0xA0, 0xA1, 0xA2, 33, 0xA4, 0xA5, 0xA6, 0xA7]
        );
        // No programs that set anything: a closest hit that does nothing (a hit group without
        // programs is refused by `ProgramGroup::hit_group`) and a no-op miss group.
        let tri = one_triangle(device);
        let mut none = Vec::new();
        for ray in [RayIn::down(0.0, 0.0), RayIn::down(5.0, 0.0)] {
            let out = t.one("empty", "ms_none", handle(&tri), ray.payload(&INIT), &[]);
            assert_eq!(out.payload(), INIT);
            none.push(out);
        }
        (hit, miss, none)
    });
}

/// Twin of `payload_sets_visible_to_later_programs_is_ah_ch_z3_g24`: a payload set is visible
/// to every later get of the same trace, within a program and across programs: IS → AH → CH,
/// and IS → MS when the AH ignores the hit. Every program sees the caller's values of the words
/// nobody set.
#[test]
fn payload_sets_visible_to_later_programs_14() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let (gas, tops) = one_box(device);
        let h = handle(&gas);
        let ray = RayIn::down(0.0, 0.0).payload(&[0, 0, 0, 0, 0, 5]);
        let hit = t.one("p", "ms_p", h, ray, &tops);
        assert_eq!(hit.notes, [1, 5, 1005, 2, 1005, 5, 3, 1005, 1006, 5]);
        assert_eq!(hit.payload(), [1005, 1006, 1007, 0, 0, 5, 0, 0]);
        let ray = RayIn::down(0.0, 0.0).payload(&[0, 0, 0, 0, 0, 7]);
        let ignored = t.one("p", "ms_p", h, ray, &tops);
        assert_eq!(
            ignored.notes,
            [1, 7, 1007, 2, 1007, 7, 4, 1007, 1008, 0, 0, 0, 7, 0, 0]
        );
        assert_eq!(ignored.payload(), [1007, 1008, 0, 0, 0, 7, 0, 0]);
        (hit, ignored)
    });
}

/// Twin of `nested_trace_payload_does_not_leak_z3_g24`: a trace from a closest-hit program has
/// its own payload: the nested programs see only the nested payload, the outer trace's payload
/// is untouched by the nested trace, and the nested result reaches the outer caller only
/// through the CH's explicit copy.
#[test]
fn nested_trace_payload_does_not_leak_14() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let gas = one_triangle(device);
        let sbt = t.sbt(&[("nest", 0)], &[("ms_data", 0), ("ms_nested", 1)]);
        let ray = RayIn::down(0.0, 0.0).payload(&[1, 2, 3, 4]);
        let (out, report) = t.run(&sbt, handle(&gas), &[ray], &[]);
        assert_eq!(report.exceptions, 0, "{report:?}");
        assert_eq!(
            out[0].notes,
            [0x40, 9, 9, 9, 9, 0xC0, 1, 2, 3, 4, 42, 43, 9, 9],
            "nested MS [9, 9, 9, 9]; CH outer [1, 2, 3, 4] nested [42, 43, 9, 9]"
        );
        assert_eq!(out[0].payload(), [1, 2, 3, 42, 0, 0, 0, 0]);
        out
    });
}

/// Twin of `closest_hit_state_unchanged_by_nested_trace_13_5`: a closest-hit program's own hit
/// state (primitive, tmin, tmax, hit kind, barycentrics, world ray, record data, launch index)
/// is the same before and after it traces a nested ray that hits something else.
#[test]
fn closest_hit_state_unchanged_by_nested_trace_13_5() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let gas = tri_gas(
            device,
            &[tri_at(0.0, 0.0, 0.0, 1.0), tri_at(3.0, 0.0, 0.0, 1.0)],
        );
        let sbt = t.sbt(&[("state", 5)], &[("ms_none", 0)]);
        let (out, report) = t.run(&sbt, handle(&gas), &[RayIn::down(0.0, 0.0)], &[]);
        assert_eq!(report.exceptions, 0, "{report:?}");
        let n = &out[0].notes;
        assert_eq!(n.len(), 48, "{n:x?}");
        let (before, nested, after) = (&n[1..16], &n[17..32], &n[33..48]);
        assert_eq!([n[0], n[16], n[32]], [0x22, 0x11, 0x33], "{n:x?}");
        assert_eq!(before, after, "the state changed over the nested trace");
        // prim, tmin, tmax, kind; (barycentrics); origin, direction, data, launch index.
        assert_eq!(before[..4], [0, f(0.0), f(10.0), 0xFE]);
        assert_eq!(
            before[6..],
            [f(0.0), f(0.0), f(10.0), f(0.0), f(0.0), f(-1.0), 5, 0, 0]
        );
        assert_eq!(nested[..4], [1, f(0.5), f(10.0), 0xFF]);
        assert_eq!(
            nested[6..],
            [f(3.0), f(0.1), f(-10.0), f(0.0), f(0.0), f(1.0), 5, 0, 0]
        );
        for bary in [&before[4..6], &nested[4..6]] {
            let [u, v] = [bary[0], bary[1]].map(f32::from_bits);
            assert!(u >= 0.0 && v >= 0.0 && u + v <= 1.0, "({u}, {v})");
        }
        out
    });
}

// ----------------------------------------------------------------------------------------------
// Reported intersections (pipeline_payload.rs)
// ----------------------------------------------------------------------------------------------

/// Twin of `report_intersection_return_values_13_4_g6`: `optixReportIntersection` returns false
/// outside `[tmin, tmax]` (no AH runs), false when the AH ignores the hit, true when the hit is
/// accepted (the interval then ends there, so a farther report returns false), and does not
/// return when the AH terminates the ray (on CUDA it returns: the documented deviation); the
/// CH then runs for the terminating hit. Without an AH program every report in the interval is
/// accepted.
#[test]
fn report_intersection_return_values_13_4() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let (gas, tops) = one_box(device);
        let h = handle(&gas);
        let ray = RayIn::down(0.0, 0.0).interval(1.0, 50.0);
        let mut with_ah = t.one("seq", "ms_none", h, ray, &tops);
        let ah = |kind: u32, tmax: f32, attr: u32| [0xA0, kind, f(tmax), attr];
        let mut expected = vec![0];
        expected.extend(ah(1, 12.0, 2));
        expected.extend([0, f(50.0)]);
        expected.extend(ah(2, 11.0, 3));
        expected.extend([1, f(11.0), 0]);
        expected.extend(ah(4, 10.5, 5));
        let ch_at = expected.len();
        expected.extend([0xC0, 4, f(10.5), 5]);
        if code_after_runs(device) {
            let n = &mut with_ah.notes;
            assert_eq!(n.len(), expected.len() + 2, "{n:x?}");
            assert_eq!(n[ch_at], 0xAF7E, "{n:x?}");
            n.drain(ch_at..ch_at + 2);
        }
        assert_eq!(with_ah.notes, expected);
        let without_ah = t.one("seq_no_ah", "ms_none", h, ray, &tops);
        assert_eq!(
            without_ah.notes,
            [0, 1, f(12.0), 1, f(11.0), 0, 0xAF7E, 1, 0xC0, 4, f(10.5), 5]
        );
        (with_ah, without_ah)
    });
}

/// Twin of `custom_hit_kind_masked_to_7_bits_13_4_n9`: only the low 7 bits of a reported hit
/// kind count; a custom hit kind can never look like a triangle's (`optixIsTriangleHit`,
/// `optixIsFrontFaceHit`, `optixIsBackFaceHit` false), in AH and CH.
#[test]
fn custom_hit_kind_masked_to_7_bits_13_4() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let (gas, tops) = one_box(device);
        let mut all = Vec::new();
        for (kind, seen) in [
            (0x00u32, 0x00u32),
            (0x05, 0x05),
            (0x7F, 0x7F),
            (0x85, 0x05),
            (0xFE, 0x7E),
            (0xFF, 0x7F),
        ] {
            let ray = RayIn::down(0.0, 0.0).payload(&[kind]);
            let out = t.one("kind", "ms_none", handle(&gas), ray, &tops);
            assert_eq!(
                out.notes,
                [0xA0, seen, 0, 0, 0, 0xC0, seen, 0, 0, 0],
                "reported {kind:#x}"
            );
            all.push(out);
        }
        all
    });
}

/// Twin of `attributes_reach_anyhit_and_closesthit_13_4`: the 8 attribute words reported with
/// a hit reach its AH and, for the closest accepted hit, the CH, whichever primitive or report
/// came first.
#[test]
fn attributes_reach_any_hit_and_closest_hit_13_4() {
    on_every_device(|device| {
        let t = Twins::new(device);
        // Primitive 1 (top at 1.5) is in front of primitive 0 (top at 0.5).
        let (gas, tops) = box_gas(
            device,
            &[cube(Vec3::ZERO, 0.5), cube(Vec3::new(0.0, 0.0, 0.9), 0.6)],
        );
        let out = t.one(
            "attrs",
            "ms_none",
            handle(&gas),
            RayIn::down(0.0, 0.0),
            &tops,
        );
        assert_eq!(out.notes.len() % 12, 0, "{:?}", out.notes);
        let events: Vec<&[u32]> = out.notes.chunks(12).collect();
        let (ch, ahs) = events.split_last().unwrap();
        assert!(!ahs.is_empty(), "no AH ran");
        for e in ahs {
            assert_eq!(e[0], 0xA0, "{e:?}");
            let base = e[1] * 100 + if e[2] == 2 { 50 } else { 0 };
            assert_eq!(
                e[4..],
                std::array::from_fn::<u32, 8, _>(|i| base + i as u32)
            );
        }
        assert!(
            ahs.iter().any(|e| e[1] == 1 && e[2] == 2),
            "the closest report's AH"
        );
        assert_eq!(ch[..4], [0xC0, 1, 2, f(8.5)]);
        assert_eq!(
            ch[4..],
            std::array::from_fn::<u32, 8, _>(|i| 150 + i as u32)
        );
        // The AHs seen depend on the traversal order: only the CH is the same everywhere.
        ch.to_vec()
    });
}

// ----------------------------------------------------------------------------------------------
// The SBT (pipeline_sbt.rs)
// ----------------------------------------------------------------------------------------------

/// The scene of pipeline_sbt.rs: three triangle inputs with 2, 1 and 3 SBT records,
/// per-primitive SBT index offsets and primitive index offsets 100, 7 and 0; triangle `k` (over
/// all inputs) lies around `(3k, 0, 0)`. Traces one ray down at each triangle and one at the
/// empty spot `(27, 0)` with 6 hit records (data 1000 + i) and a miss record (data 500), and
/// returns the payloads and the expected `(sbtGASIndex, primitive index)` of each triangle.
fn three_input_scene(device: &Device) -> (Vec<[u32; 8]>, Vec<(u32, u32)>) {
    let (gas, expected) = common::three_input_gas(device);
    let t = Twins::new(device);
    let hits: Vec<(&str, u32)> = (0..6).map(|i| ("record", 1000 + i)).collect();
    let sbt = t.sbt(&hits, &[("ms_record", 500)]);
    let rays: Vec<RayIn> = (0..10)
        .map(|k| RayIn::down(3.0 * k as f32, 0.0).payload(&[!0; 4]))
        .collect();
    let (out, report) = t.run(&sbt, handle(&gas), &rays, &[]);
    assert_eq!(report.exceptions, 0, "{report:?}");
    let payloads: Vec<[u32; 8]> = out.iter().map(Rec::payload).collect();
    assert_eq!(
        payloads[9],
        [500, !0, !0, 2, 0, 0, 0, 0],
        "the empty spot misses"
    );
    (payloads, expected)
}

/// Twin of `sbt_gas_index_prefix_sum_7_3_2_g19`: `optixGetSbtGASIndex` is the sum of the
/// records of earlier build inputs plus the primitive's SBT index offset, and with stride 1 and
/// offset 0 it selects the hit record.
#[test]
fn sbt_gas_index_prefix_sum_over_build_inputs_7_3_2() {
    on_every_device(|device| {
        let (out, expected) = three_input_scene(device);
        for (k, &(gas_index, _)) in expected.iter().enumerate() {
            assert_eq!(out[k][1], gas_index, "triangle {k}");
            assert_eq!(out[k][0], 1000 + gas_index, "triangle {k}: record");
            assert_eq!(out[k][3], 1, "triangle {k} was hit");
        }
        out
    });
}

/// Twin of `primitive_index_with_offset_13_7_g20`: `optixGetPrimitiveIndex` is the index within
/// the build input plus the input's `primitiveIndexOffset`.
#[test]
fn primitive_index_with_offset_13_7() {
    on_every_device(|device| {
        let (out, expected) = three_input_scene(device);
        for (k, &(_, prim)) in expected.iter().enumerate() {
            assert_eq!(out[k][2], prim, "triangle {k}");
        }
        out
    });
}

/// Twin of `miss_record_by_miss_index_7_2_g22`: a miss runs the miss record selected by the
/// trace's miss index, and its SBT data pointer is that record's data; the null handle and a
/// real GAS alike.
#[test]
fn miss_record_by_miss_index_7_2() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let gas = one_triangle(device);
        let misses: Vec<(&str, u32)> = (0..4).map(|i| ("ms_record", 500 + i)).collect();
        let sbt = t.sbt(&[("record", 1000)], &misses);
        let mut all = Vec::new();
        for miss in 0..4 {
            for h in [0, handle(&gas)] {
                let rays = [RayIn::down(50.0, 50.0).payload(&[!0; 4]).sbt(0, 1, miss); 3];
                let (out, report) = t.run(&sbt, h, &rays, &[]);
                assert_eq!(report.exceptions, 0, "{report:?}");
                for o in &out {
                    assert_eq!(
                        o.payload(),
                        [500 + miss, !0, !0, 2, 0, 0, 0, 0],
                        "miss index {miss}"
                    );
                }
                all.push(out);
            }
        }
        all
    });
}

/// Twin of `sbt_data_of_hit_and_miss_records_7_4`: `optixGetSbtDataPointer` in any-hit,
/// closest-hit, intersection and miss programs is the data of the record that selected them
/// (the programs of one hit see the same record).
#[test]
fn sbt_data_of_hit_and_miss_records_7_4() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let tri = one_triangle(device);
        let hits = [("data_tri", 40), ("data_tri", 41), ("data_tri", 42)];
        let sbt = t.sbt(&hits, &[("ms_data", 90), ("ms_data", 91)]);
        let rays = [
            RayIn::down(0.0, 0.0).sbt(2, 1, 1),
            RayIn::down(5.0, 5.0).sbt(2, 1, 1),
        ];
        let (out, report) = t.run(&sbt, handle(&tri), &rays, &[]);
        assert_eq!(report.exceptions, 0, "{report:?}");
        assert_eq!(out[0].notes, [0xA0, 42, 0xC0, 42]);
        assert_eq!(out[1].notes, [0x40, 91]);
        let (boxes, tops) = one_box(device);
        let sbt = t.sbt(&[("data_box", 60), ("data_box_ah", 61)], &[("ms_none", 0)]);
        let (boxed, report) = t.run(
            &sbt,
            handle(&boxes),
            &[RayIn::down(0.0, 0.0).sbt(1, 1, 0)],
            &tops,
        );
        assert_eq!(report.exceptions, 0, "{report:?}");
        assert_eq!(boxed[0].notes, [0x15, 61, 0xA0, 61, 0xC0, 61]);
        (out, boxed)
    });
}

/// Twin of `sbt_data_of_raygen_and_exception_records_7_4`: `optixGetSbtDataPointer` in
/// ray-generation and exception programs is the data of the raygen and exception records.
#[test]
fn sbt_data_of_raygen_and_exception_records_7_4() {
    on_every_device(|device| {
        let t = Twins::new(device);
        let sbt = ShaderBindingTable {
            raygen: t.region(&[("rg_data", [11u32, 12, 13, 14])]),
            exception: Some(t.region(&[("ex", [21u32, 22])])),
            ..Default::default()
        };
        let (out, report) = t.run(&sbt, 0, &[RayIn::down(0.0, 0.0)], &[]);
        assert_eq!(report.exceptions, 1, "{report:?}");
        assert_eq!(report.first_exceptions[0].1.code.0, 1);
        assert_eq!(out[0].notes, [0x96, 11, 12, 13, 14, 0xE7, 1, 21, 22]);
        out
    });
}

/// Every program of twins2.cu compiles for the GPU with NVRTC, GPU or not.
#[test]
fn the_twins2_compile_with_nvrtc() {
    use oxray::cuda::{CudaHitGroupDesc, CudaModule, CudaProgramGroup};
    let m = CudaModule::from_source(TWINS2);
    let e = |n: Option<&'static str>| n.map(|n| (&m, n));
    let mut groups = Vec::new();
    for (_, entry) in RAYGENS {
        groups.push(CudaProgramGroup::raygen(&m, entry).unwrap());
    }
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
    common::assert_compiles_with_nvrtc("the twins2 programs", &groups, types);
}
