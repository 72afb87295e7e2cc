//! The memory query before a build (`optixAccelComputeMemoryUsage`, guide §5): its output size
//! bounds the built structure, it rejects what the build rejects for structural reasons, and its
//! temp size bounds the working memory the build allocates (measured with a counting global
//! allocator, in this test binary only).

mod common;

use common::{random_soup, Rng};
use glam::Vec3;
use oxray::cpu::Gas;
use oxray::error::BufferKind;
use oxray::{
    compute_memory_usage, Aabb, AabbBuffer, AccelBufferSizes, BuildError, BuildFlags, BuildInput,
    BuildOptions, CustomPrimitiveInput, GeometryFlags, IndexBuffer, IndexFormat, SbtIndexOffsets,
    TriangleInput, VertexBuffer, VertexFormat,
};
use proptest::prelude::*;
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

// ---------------------------------------------------------------------------------------------
// A counting allocator: live bytes and their peak.
// ---------------------------------------------------------------------------------------------

struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

fn grew(by: usize) {
    let now = LIVE.fetch_add(by, Ordering::SeqCst) + by;
    PEAK.fetch_max(now, Ordering::SeqCst);
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc(layout);
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc_zeroed(layout);
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout);
        LIVE.fetch_sub(layout.size(), Ordering::SeqCst);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = System.realloc(ptr, layout, new_size);
        if !p.is_null() {
            if new_size >= layout.size() {
                grew(new_size - layout.size());
            } else {
                LIVE.fetch_sub(layout.size() - new_size, Ordering::SeqCst);
            }
        }
        p
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Tests of this binary run one at a time, so that no other test allocates during a measurement.
static SERIAL: Mutex<()> = Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

/// Builds and returns the GAS with the peak of live bytes during the build, over those live
/// before it.
/// Also returns the heap bytes the structure keeps once built (capacity included).
fn measured_build(options: &BuildOptions, inputs: &[BuildInput<'_>]) -> (Gas, usize, usize) {
    let before = LIVE.load(Ordering::SeqCst);
    PEAK.store(before, Ordering::SeqCst);
    let gas = Gas::build(options, inputs).expect("builds");
    let peak = PEAK.load(Ordering::SeqCst);
    let retained = LIVE.load(Ordering::SeqCst).saturating_sub(before);
    (gas, peak - before, retained)
}

/// One measured build: the query's sizes, the structure's bytes and the peak of live bytes.
struct Measured {
    what: String,
    sizes: AccelBufferSizes,
    output: usize,
    retained: usize,
    peak: usize,
}

impl Measured {
    fn output_ok(&self) -> bool {
        self.output <= self.sizes.output_size_in_bytes
    }

    fn heap_ok(&self) -> bool {
        self.retained <= self.sizes.output_size_in_bytes
    }

    fn peak_ok(&self) -> bool {
        self.peak <= self.sizes.output_size_in_bytes + self.sizes.temp_size_in_bytes
    }
}

impl std::fmt::Display for Measured {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let bound = self.sizes.output_size_in_bytes + self.sizes.temp_size_in_bytes;
        write!(
            f,
            "{:<16} output {:>10} <= {:>10} [{}] (heap kept {:>10} [{}])   peak {:>10} <= output {:>10} + temp {:>10} = {:>10} [{}, ratio {:.2}]",
            self.what,
            self.output,
            self.sizes.output_size_in_bytes,
            if self.output_ok() { "ok" } else { "FAIL" },
            self.retained,
            if self.heap_ok() { "ok" } else { "FAIL" },
            self.peak,
            self.sizes.output_size_in_bytes,
            self.sizes.temp_size_in_bytes,
            bound,
            if self.peak_ok() { "ok" } else { "FAIL" },
            self.peak as f64 / bound as f64,
        )
    }
}

/// Queries the sizes, then builds while measuring the peak. The build is measured three times
/// and the smallest peak kept, so that a stray allocation of the test harness on another thread
/// cannot make the measurement fail.
fn measure(options: &BuildOptions, inputs: &[BuildInput<'_>], what: &str) -> Measured {
    let sizes = compute_memory_usage(options, inputs).expect("the memory query accepts the inputs");
    let mut output = 0;
    let mut retained = usize::MAX;
    let mut peak = usize::MAX;
    for _ in 0..3 {
        let (gas, p, r) = measured_build(options, inputs);
        output = gas.memory().output_bytes;
        peak = peak.min(p);
        retained = retained.min(r);
    }
    Measured {
        what: what.to_string(),
        sizes,
        output,
        retained,
        peak,
    }
}

/// Warms up rayon's global pool so that its own allocations are not charged to a build.
fn warm_up() {
    let v = random_soup(&mut Rng::new(0), 50_000, 1.0, 0.1);
    let verts: Vec<[f32; 3]> = v.iter().flatten().copied().collect();
    Gas::build(
        &BuildOptions::default(),
        &[TriangleInput::new(VertexBuffer::f32x3(&verts)).into()],
    )
    .unwrap();
}

// ---------------------------------------------------------------------------------------------
// Output bound
// ---------------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(common::proptest_config(96))]

    /// Guide §5: `outputSizeInBytes` is an upper bound of the built structure, for random
    /// meshes of one or several inputs (some triangles inactive, some inputs with several SBT
    /// records), under every build preset.
    #[test]
    fn output_bound_holds_for_random_meshes_5(
        seed in any::<u64>(),
        counts in prop::collection::vec(0usize..400, 1..4),
        records in 1usize..4,
        degenerate_every in 0usize..5,
        preset in 0usize..3,
    ) {
        let _guard = serial();
        let mut rng = Rng::new(seed);
        let soups: Vec<Vec<[f32; 3]>> = counts.iter().map(|&n| {
            let mut v: Vec<[f32; 3]> = random_soup(&mut rng, n, 10.0, 1.0).into_iter().flatten().collect();
            if degenerate_every > 0 {
                for k in (0..n).step_by(degenerate_every + 1) {
                    v[3 * k + 1] = v[3 * k];
                }
            }
            v
        }).collect();
        let flags = vec![GeometryFlags::empty(); records];
        let offsets: Vec<Vec<u8>> = counts.iter().map(|&n| (0..n).map(|k| (k % records) as u8).collect()).collect();
        let inputs: Vec<BuildInput<'_>> = soups.iter().zip(&offsets).enumerate().map(|(i, (v, o))| {
            let t = TriangleInput::new(VertexBuffer::f32x3(v));
            if i % 2 == 1 {
                t.flags(&flags).sbt_index_offsets(SbtIndexOffsets::u8(o)).into()
            } else {
                t.into()
            }
        }).collect();
        let flags = [BuildFlags::empty(), BuildFlags::PREFER_FAST_BUILD, BuildFlags::PREFER_FAST_TRACE][preset];
        let options = BuildOptions::new(flags);
        let sizes = compute_memory_usage(&options, &inputs).unwrap();
        let gas = Gas::build(&options, &inputs).unwrap();
        prop_assert!(gas.memory().output_bytes <= sizes.output_size_in_bytes,
            "{} > {}", gas.memory().output_bytes, sizes.output_size_in_bytes);
        prop_assert!(gas.memory().node_bytes + gas.memory().primitive_bytes <= gas.memory().output_bytes);
        // No update was asked for.
        prop_assert_eq!(sizes.temp_update_size_in_bytes, 0);
        // The query reads no data: it depends on the declared counts only.
        let zeros: Vec<Vec<[f32; 3]>> = soups.iter().map(|v| vec![[0.0; 3]; v.len()]).collect();
        let zero_inputs: Vec<BuildInput<'_>> = zeros.iter().zip(&inputs).map(|(z, i)| match i {
            BuildInput::Triangles(t) => BuildInput::Triangles(TriangleInput { vertices: VertexBuffer::f32x3(z), ..*t }),
            other => *other,
        }).collect();
        prop_assert_eq!(compute_memory_usage(&options, &zero_inputs).unwrap(), sizes);
    }

    /// Guide §5: the same for custom primitives (inactive boxes included).
    #[test]
    fn output_bound_holds_for_custom_primitives_5(
        seed in any::<u64>(),
        counts in prop::collection::vec(0usize..500, 1..4),
        preset in 0usize..3,
    ) {
        let _guard = serial();
        let mut rng = Rng::new(seed);
        let boxes: Vec<Vec<Aabb>> = counts.iter().map(|&n| (0..n).map(|k| {
            let c = rng.vec3(0.0, 10.0);
            let h = rng.vec3(0.0, 0.5);
            if k % 7 == 3 { Aabb::new(c + h, c - h - 0.1) } else { Aabb::new(c - h, c + h) }
        }).collect()).collect();
        let inputs: Vec<BuildInput<'_>> = boxes.iter().map(|b| CustomPrimitiveInput::new(AabbBuffer::new(b)).into()).collect();
        let flags = [BuildFlags::empty(), BuildFlags::PREFER_FAST_BUILD, BuildFlags::PREFER_FAST_TRACE][preset];
        let options = BuildOptions::new(flags);
        let sizes = compute_memory_usage(&options, &inputs).unwrap();
        let gas = Gas::build(&options, &inputs).unwrap();
        prop_assert!(gas.memory().output_bytes <= sizes.output_size_in_bytes,
            "{} > {}", gas.memory().output_bytes, sizes.output_size_in_bytes);
        prop_assert_eq!(sizes.temp_update_size_in_bytes, 0);
    }
}

/// Guide §5: the bound also holds for meshes with shared vertices and for a single triangle.
#[test]
fn output_bound_holds_for_indexed_meshes_5() {
    let _guard = serial();
    for s in 0..5 {
        let mesh = common::icosphere(s);
        let inputs = [TriangleInput::new(VertexBuffer::f32x3(&mesh.positions))
            .indices(IndexBuffer::u32x3(&mesh.triangles))
            .into()];
        let sizes = compute_memory_usage(&BuildOptions::default(), &inputs).unwrap();
        let gas = Gas::build(&BuildOptions::default(), &inputs).unwrap();
        assert!(gas.memory().output_bytes <= sizes.output_size_in_bytes);
    }
}

// ---------------------------------------------------------------------------------------------
// The same validation as the build
// ---------------------------------------------------------------------------------------------

/// Guide §5: the memory query validates the inputs' structure as the build does: for every
/// structural problem both return the same error.
#[test]
fn memory_query_rejects_what_the_build_rejects_5() {
    let _guard = serial();
    let tri = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let four = [[0.0f32; 3]; 4];
    let bytes = vec![0u8; 256];
    let boxes = [Aabb::new(Vec3::ZERO, Vec3::ONE)];
    let flags3 = [GeometryFlags::empty(); 3];
    let over = vec![GeometryFlags::empty(); (1 << 24) + 1];
    let valid: BuildInput<'_> = TriangleInput::new(VertexBuffer::f32x3(&tri)).into();
    let d = BuildOptions::default();
    let cases: Vec<(&str, BuildOptions, Vec<BuildInput<'_>>)> = vec![
        ("no inputs", d, vec![]),
        (
            "mixed",
            d,
            vec![
                valid,
                CustomPrimitiveInput::new(AabbBuffer::new(&boxes)).into(),
            ],
        ),
        (
            "conflicting flags",
            BuildOptions::new(BuildFlags::PREFER_FAST_BUILD | BuildFlags::PREFER_FAST_TRACE),
            vec![valid],
        ),
        (
            "too many primitives",
            d,
            vec![TriangleInput::new(VertexBuffer::f32x3(&tri))
                .indices(IndexBuffer::new(
                    &bytes,
                    IndexFormat::U32x3,
                    0,
                    (1 << 29) + 1,
                ))
                .into()],
        ),
        (
            "too many records",
            d,
            vec![TriangleInput::new(VertexBuffer::f32x3(&tri))
                .flags(&over)
                .into()],
        ),
        (
            "no records",
            d,
            vec![
                valid,
                TriangleInput::new(VertexBuffer::f32x3(&tri))
                    .flags(&[])
                    .into(),
            ],
        ),
        (
            "missing offsets",
            d,
            vec![
                valid,
                TriangleInput::new(VertexBuffer::f32x3(&tri))
                    .flags(&flags3)
                    .into(),
            ],
        ),
        (
            "vertex stride",
            d,
            vec![
                valid,
                TriangleInput::new(VertexBuffer::new(&bytes, VertexFormat::F32x3, 14, 3)).into(),
            ],
        ),
        (
            "index stride",
            d,
            vec![
                valid,
                TriangleInput::new(VertexBuffer::f32x3(&tri))
                    .indices(IndexBuffer::new(&bytes, IndexFormat::U16x3, 4, 1))
                    .into(),
            ],
        ),
        (
            "aabb stride",
            d,
            vec![CustomPrimitiveInput::new(AabbBuffer {
                data: &bytes,
                stride: 28,
                count: 2,
            })
            .into()],
        ),
        (
            "offset stride",
            d,
            vec![
                valid,
                TriangleInput::new(VertexBuffer::f32x3(&tri))
                    .flags(&flags3)
                    .sbt_index_offsets(SbtIndexOffsets {
                        data: &bytes,
                        size: oxray::SbtIndexSize::U32,
                        stride: 6,
                    })
                    .into(),
            ],
        ),
        (
            "vertex buffer",
            d,
            vec![
                valid,
                TriangleInput::new(VertexBuffer::new(&bytes[..35], VertexFormat::F32x3, 0, 3))
                    .into(),
            ],
        ),
        (
            "index buffer",
            d,
            vec![
                valid,
                TriangleInput::new(VertexBuffer::f32x3(&tri))
                    .indices(IndexBuffer::new(&bytes[..11], IndexFormat::U32x3, 0, 1))
                    .into(),
            ],
        ),
        (
            "aabb buffer",
            d,
            vec![CustomPrimitiveInput::new(AabbBuffer {
                data: &bytes[..47],
                stride: 0,
                count: 2,
            })
            .into()],
        ),
        (
            "offset buffer",
            d,
            vec![
                valid,
                TriangleInput::new(VertexBuffer::f32x3(&tri))
                    .flags(&flags3)
                    .sbt_index_offsets(SbtIndexOffsets::u8(&[]))
                    .into(),
            ],
        ),
        (
            "soup count",
            d,
            vec![valid, TriangleInput::new(VertexBuffer::f32x3(&four)).into()],
        ),
        (
            "offset overflow",
            d,
            vec![
                valid,
                TriangleInput::new(VertexBuffer::f32x3(&tri))
                    .primitive_index_offset(u32::MAX)
                    .into(),
            ],
        ),
    ];
    // The memory query takes an update's options too (its sizes include the update's working
    // memory); only the build refuses operation Update, which needs a structure (§5.6).
    let update = BuildOptions {
        flags: BuildFlags::ALLOW_UPDATE,
        operation: oxray::BuildOperation::Update,
        ..Default::default()
    };
    let sizes = compute_memory_usage(&update, &[valid]).unwrap();
    assert!(sizes.temp_update_size_in_bytes > 0);
    for (what, options, inputs) in &cases {
        let q = compute_memory_usage(options, inputs).expect_err(what);
        let b = Gas::build(options, inputs).expect_err(what);
        assert_eq!(q, b, "{what}");
        assert_eq!(q.code(), b.code());
    }
    assert!(matches!(
        compute_memory_usage(&d, &cases.iter().find(|c| c.0 == "aabb buffer").unwrap().2),
        Err(BuildError::BufferTooSmall {
            buffer: BufferKind::Aabbs,
            ..
        })
    ));
    // The checks that need the data (index and SBT offset ranges) are the build's alone: the
    // query needs only counts (device pointers need not be valid yet, §5).
    let bad_ix = [[0u32, 1, 7]];
    let inputs = [TriangleInput::new(VertexBuffer::f32x3(&tri))
        .indices(IndexBuffer::u32x3(&bad_ix))
        .into()];
    assert!(compute_memory_usage(&d, &inputs).is_ok());
    assert!(matches!(
        Gas::build(&d, &inputs),
        Err(BuildError::IndexOutOfRange { .. })
    ));
    let inputs = [TriangleInput::new(VertexBuffer::f32x3(&tri))
        .flags(&flags3)
        .sbt_index_offsets(SbtIndexOffsets::u8(&[9]))
        .into()];
    assert!(compute_memory_usage(&d, &inputs).is_ok());
    assert!(matches!(
        Gas::build(&d, &inputs),
        Err(BuildError::SbtIndexOffsetOutOfRange { .. })
    ));
}

// ---------------------------------------------------------------------------------------------
// Temp bound (peak live bytes during the build)
// ---------------------------------------------------------------------------------------------

fn assert_all_within(report: &[Measured]) {
    let table = report
        .iter()
        .map(|m| m.to_string())
        .collect::<Vec<_>>()
        .join("\n");
    println!("{table}");
    assert!(
        report.iter().all(Measured::output_ok),
        "GasMemory::output_bytes exceeds the output bound:\n{table}"
    );
    assert!(
        report.iter().all(Measured::heap_ok),
        "the heap a built structure keeps exceeds the output bound:\n{table}"
    );
    assert!(
        report.iter().all(Measured::peak_ok),
        "peak live bytes during Gas::build exceed output + temp bounds:\n{table}"
    );
}

fn soup_case(rng: &mut Rng, n: usize, flags: BuildFlags) -> Measured {
    let soup: Vec<[f32; 3]> = random_soup(rng, n, 100.0, 0.5)
        .into_iter()
        .flatten()
        .collect();
    let inputs = [TriangleInput::new(VertexBuffer::f32x3(&soup)).into()];
    measure(&BuildOptions::new(flags), &inputs, &format!("soup {n}"))
}

fn boxes_case(rng: &mut Rng, n: usize) -> Measured {
    let boxes: Vec<Aabb> = (0..n)
        .map(|_| {
            let c = rng.vec3(0.0, 100.0);
            Aabb::new(c - 0.3, c + 0.3)
        })
        .collect();
    let inputs = [CustomPrimitiveInput::new(AabbBuffer::new(&boxes)).into()];
    measure(
        &BuildOptions::new(BuildFlags::PREFER_FAST_TRACE),
        &inputs,
        &format!("boxes {n}"),
    )
}

/// Guide §5: `tempSizeInBytes` bounds the working memory: the peak of live heap bytes during
/// `Gas::build`, over those live before, is at most the output bound plus the temp bound —
/// for builds of 100 to 200k primitives (above the parallel thresholds).
#[test]
fn build_peak_memory_within_output_plus_temp_5() {
    let _guard = serial();
    warm_up();
    let mut rng = Rng::new(42);
    let mut report = vec![
        soup_case(&mut rng, 100, BuildFlags::empty()),
        soup_case(&mut rng, 10_000, BuildFlags::PREFER_FAST_TRACE),
        soup_case(&mut rng, 50_000, BuildFlags::PREFER_FAST_BUILD),
        soup_case(&mut rng, 200_000, BuildFlags::empty()),
    ];
    // Indexed, two inputs, one pre-transformed with SBT offsets.
    let mesh = common::icosphere(5);
    let offsets: Vec<u16> = (0..mesh.triangles.len()).map(|k| (k % 3) as u16).collect();
    let flags = [GeometryFlags::empty(); 3];
    let inputs = [
        TriangleInput::new(VertexBuffer::f32x3(&mesh.positions))
            .indices(IndexBuffer::u32x3(&mesh.triangles))
            .into(),
        TriangleInput::new(VertexBuffer::f32x3(&mesh.positions))
            .indices(IndexBuffer::u32x3(&mesh.triangles))
            .pre_transform([1.0, 0.0, 0.0, 3.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0])
            .flags(&flags)
            .sbt_index_offsets(SbtIndexOffsets::u16(&offsets))
            .into(),
    ];
    report.push(measure(&BuildOptions::default(), &inputs, "2 icospheres"));
    report.push(boxes_case(&mut rng, 100));
    report.push(boxes_case(&mut rng, 100_000));
    assert_all_within(&report);
}

/// Guide §5: the same bound for the smallest builds (0 to 8 primitives), where fixed costs of
/// the build dominate.
#[test]
fn tiny_build_peak_memory_within_output_plus_temp_5() {
    let _guard = serial();
    warm_up();
    let mut rng = Rng::new(43);
    let mut report = Vec::new();
    for n in [0usize, 1, 2, 8] {
        report.push(soup_case(&mut rng, n, BuildFlags::empty()));
        report.push(boxes_case(&mut rng, n));
    }
    assert_all_within(&report);
}

/// The counting allocator itself counts (a sanity check of the measurement).
#[test]
fn counting_allocator_sees_allocations() {
    let _guard = serial();
    // Other threads of the harness may free a little memory meanwhile (a finished test's
    // output), hence the slack.
    let slack = 1 << 16;
    let before = LIVE.load(Ordering::SeqCst);
    PEAK.store(before, Ordering::SeqCst);
    let v: Vec<u8> = vec![1; 1 << 20];
    assert!(LIVE.load(Ordering::SeqCst) + slack >= before + (1 << 20));
    drop(v);
    assert!(PEAK.load(Ordering::SeqCst) + slack >= before + (1 << 20));
    assert!(LIVE.load(Ordering::SeqCst) < before + slack);
}

#[test]
fn each_device_answers_the_memory_query_of_its_own_builder_5() {
    let _s = serial();
    let mut rng = Rng::new(5);
    let tris = random_soup(&mut rng, 500, 10.0, 0.5);
    let v: Vec<[f32; 3]> = tris.iter().flatten().copied().collect();
    let inputs = [BuildInput::from(TriangleInput::new(VertexBuffer::f32x3(
        &v,
    )))];
    for flags in [BuildFlags::empty(), BuildFlags::PREFER_FAST_TRACE] {
        let options = BuildOptions::new(flags);
        // The CPU builds with the shared builder: the device-neutral query is its own.
        assert_eq!(
            oxray::Device::cpu().compute_memory_usage(&options, &inputs),
            compute_memory_usage(&options, &inputs)
        );
        // A CUDA device answers for the builder it will run, and its output bounds what the
        // structure keeps on the device.
        if let Ok(device) = oxray::Device::cuda(0) {
            let sizes = device.compute_memory_usage(&options, &inputs).unwrap();
            let gas = device.build_gas(&options, &inputs).unwrap();
            let cuda = gas.as_cuda().expect("a CUDA device builds CUDA GASes");
            assert!(
                cuda.device_bytes() <= sizes.output_size_in_bytes,
                "{sizes:?}"
            );
        }
    }
    let bad = BuildOptions::new(BuildFlags::PREFER_FAST_BUILD | BuildFlags::PREFER_FAST_TRACE);
    assert_eq!(
        oxray::Device::cpu().compute_memory_usage(&bad, &inputs),
        Err(BuildError::ConflictingBuildFlags)
    );
}
