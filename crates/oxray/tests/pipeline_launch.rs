//! Conformance of modules, program groups, pipelines and launches (guide §6, §10, §12; inventory
//! S, X, Z7 G40, G41), plus two whole-pipeline properties: launch results do not depend on the
//! thread count, and a trace with a trivial closest-hit program agrees with the query API.

mod pipeline_common;

use oxray::cpu::Gas;
use oxray::{
    Aabb, AabbBuffer, BuildInput, BuildOptions, CustomHit, CustomPrimitive, CustomPrimitiveInput,
    DeviceContext, ErrorCode, LaunchError, Module, OutputBuffer, Pipeline, PipelineError,
    ProgramGroup, ProgramKind, Ray, RayFlags, SbtRegion, ShaderBindingTable, TraceRay,
    TraversableHandle, TriangleInput, VertexBuffer,
};
use pipeline_common::*;
use std::sync::atomic::{AtomicU32, AtomicUsize, Ordering};
use std::sync::Arc;

/// A pipeline of one ray-generation program and nothing else.
fn raygen_only<P: 'static>(
    m: &Module<P>,
    entry: &str,
    depth: u32,
) -> (Pipeline<P>, ShaderBindingTable) {
    let rg = ProgramGroup::raygen(m, entry).unwrap();
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &compile(0, 2),
        &link(depth),
        std::slice::from_ref(&rg),
    )
    .unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        ..Default::default()
    };
    (pipeline, sbt)
}

#[derive(Clone)]
struct CountP {
    runs: Arc<Vec<AtomicU32>>,
    bad: Arc<AtomicU32>,
}

/// §10 / §13.1 / X / Z7 G41: the ray-generation program runs exactly once for every launch index
/// of a 1D, 2D or 3D launch, sees `launch_dimensions() == (w, h, d)` and a launch index inside
/// them.
#[test]
fn raygen_runs_once_per_launch_index_10_g41() {
    let m = Module::<CountP>::new()
        .raygen("__raygen__count", |ctx| {
            let [x, y, z] = ctx.launch_index();
            let [w, h, d] = ctx.launch_dimensions();
            let p = ctx.params();
            if x >= w || y >= h || z >= d {
                p.bad.fetch_add(1, Ordering::Relaxed);
                return Ok(());
            }
            p.runs[(x + w * (y + h * z)) as usize].fetch_add(1, Ordering::Relaxed);
            Ok(())
        })
        .unwrap();
    let (pipeline, sbt) = raygen_only(&m, "__raygen__count", 0);
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
        let p = CountP {
            runs: Arc::new((0..n).map(|_| AtomicU32::new(0)).collect()),
            bad: Arc::new(AtomicU32::new(0)),
        };
        let report = pipeline.launch(&p, &sbt, w, h, d).unwrap();
        assert_eq!(report.exceptions, 0);
        assert_eq!(
            p.bad.load(Ordering::Relaxed),
            0,
            "{w}x{h}x{d}: index outside the launch"
        );
        for (i, r) in p.runs.iter().enumerate() {
            assert_eq!(
                r.load(Ordering::Relaxed),
                1,
                "{w}x{h}x{d}: linear index {i}"
            );
        }
    }
}

/// Launch parameters that count their clones and know whether they are a clone.
struct Counted {
    clones: Arc<AtomicUsize>,
    is_copy: bool,
    originals_seen: Arc<AtomicUsize>,
    copies_seen: Arc<AtomicUsize>,
    address: Arc<AtomicUsize>,
    addresses: Arc<AtomicUsize>,
}

impl Clone for Counted {
    fn clone(&self) -> Self {
        self.clones.fetch_add(1, Ordering::SeqCst);
        Counted {
            clones: self.clones.clone(),
            is_copy: true,
            originals_seen: self.originals_seen.clone(),
            copies_seen: self.copies_seen.clone(),
            address: self.address.clone(),
            addresses: self.addresses.clone(),
        }
    }
}

/// §10 / X / Z7 G40: launch parameters are copied at launch: the params are cloned exactly once
/// per launch, and every program of every launch index sees that one copy, not the caller's
/// value.
#[test]
fn launch_params_copied_once_per_launch_10_g40() {
    fn seen(p: &Counted) {
        if p.is_copy {
            p.copies_seen.fetch_add(1, Ordering::Relaxed);
        } else {
            p.originals_seen.fetch_add(1, Ordering::Relaxed);
        }
        let a = p as *const Counted as usize;
        if p.address
            .compare_exchange(0, a, Ordering::SeqCst, Ordering::SeqCst)
            .is_err()
            && p.address.load(Ordering::SeqCst) != a
        {
            p.addresses.fetch_add(1, Ordering::Relaxed);
        }
    }
    let m = Module::<Counted>::new()
        .raygen("__raygen__p", |ctx| {
            seen(ctx.params());
            ctx.trace(
                &TraceRay::new(&TraversableHandle::NULL, Vec3::ZERO, Vec3::X),
                &mut [],
            )
        })
        .unwrap()
        .miss("__miss__p", |ctx| {
            seen(ctx.params());
            Ok(())
        })
        .unwrap();
    let rg = ProgramGroup::raygen(&m, "__raygen__p").unwrap();
    let ms = ProgramGroup::miss(Some((&m, "__miss__p"))).unwrap();
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &compile(0, 2),
        &link(1),
        &[rg.clone(), ms.clone()],
    )
    .unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_headers(&[ms.pack_header()]),
        ..Default::default()
    };
    let p = Counted {
        clones: Arc::new(AtomicUsize::new(0)),
        is_copy: false,
        originals_seen: Arc::new(AtomicUsize::new(0)),
        copies_seen: Arc::new(AtomicUsize::new(0)),
        address: Arc::new(AtomicUsize::new(0)),
        addresses: Arc::new(AtomicUsize::new(0)),
    };
    for launch in 1..=3 {
        p.address.store(0, Ordering::SeqCst);
        let report = pipeline.launch(&p, &sbt, 32, 8, 2).unwrap();
        assert_eq!(report.exceptions, 0, "{:?}", report.first_exceptions);
        assert_eq!(
            p.clones.load(Ordering::SeqCst),
            launch,
            "one clone per launch"
        );
        assert_eq!(p.copies_seen.load(Ordering::Relaxed), launch * 2 * 512);
        assert_eq!(
            p.originals_seen.load(Ordering::Relaxed),
            0,
            "a program saw the caller's params"
        );
        assert_eq!(
            p.addresses.load(Ordering::Relaxed),
            0,
            "programs saw different copies"
        );
        assert_ne!(
            p.address.load(Ordering::SeqCst),
            &p as *const Counted as usize
        );
    }
}

/// §12 / X / N14: a launch of more than 2^30 indices is refused with `LaunchError::TooLarge`
/// (carrying the dimensions) and runs nothing.
#[test]
fn launch_larger_than_2_pow_30_is_refused_12_n14() {
    let m = Module::<CountP>::new()
        .raygen("__raygen__count", |ctx| {
            ctx.params().bad.fetch_add(1, Ordering::Relaxed);
            Ok(())
        })
        .unwrap();
    let (pipeline, sbt) = raygen_only(&m, "__raygen__count", 0);
    let p = CountP {
        runs: Arc::new(Vec::new()),
        bad: Arc::new(AtomicU32::new(0)),
    };
    for (w, h, d) in [
        ((1 << 30) + 1, 1, 1),
        (1, 1, u32::MAX),
        (1 << 15, 1 << 15, 2),
        (1 << 16, 1 << 16, 1),
        (1 << 10, 1 << 10, 1 << 11),
        (u32::MAX, u32::MAX, 1),
    ] {
        match pipeline.launch(&p, &sbt, w, h, d) {
            Err(LaunchError::TooLarge {
                width,
                height,
                depth,
            }) => assert_eq!((width, height, depth), (w, h, d)),
            other => panic!("{w}x{h}x{d}: {other:?}"),
        }
    }
    assert_eq!(p.bad.load(Ordering::Relaxed), 0, "a refused launch ran");
    assert_eq!(
        LaunchError::TooLarge {
            width: 0,
            height: 0,
            depth: 0
        }
        .code(),
        ErrorCode::InvalidLaunchParameter
    );
}

/// §12 / X / N14: dimensions whose product overflows 64 bits are still more than 2^30 indices and
/// must be refused with `TooLarge` (not wrap around to a small launch, nor panic).
#[test]
fn launch_size_product_overflow_is_refused_12_n14() {
    let m = Module::<CountP>::new()
        .raygen("__raygen__count", |ctx| {
            ctx.params().bad.fetch_add(1, Ordering::Relaxed);
            Ok(())
        })
        .unwrap();
    let (pipeline, sbt) = raygen_only(&m, "__raygen__count", 0);
    let p = CountP {
        runs: Arc::new(Vec::new()),
        bad: Arc::new(AtomicU32::new(0)),
    };
    // 2^66 and 2^64: both wrap to 0 in u64; (2^32 - 1)^3 wraps to 3 * 2^32 - 1.
    for (w, h, d) in [
        (1 << 22, 1 << 22, 1 << 22),
        (1 << 31, 1 << 31, 4),
        (u32::MAX, u32::MAX, u32::MAX),
    ] {
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            pipeline.launch(&p, &sbt, w, h, d)
        }));
        match r {
            Ok(Err(LaunchError::TooLarge { .. })) => {}
            Ok(other) => panic!("{w}x{h}x{d}: expected TooLarge, got {other:?}"),
            Err(_) => panic!("{w}x{h}x{d}: launch panicked instead of returning TooLarge"),
        }
    }
    assert_eq!(p.bad.load(Ordering::Relaxed), 0);
}

/// §6.2 / S.1: every program kind's entry name must start with its prefix (`__raygen__`,
/// `__closesthit__`, `__anyhit__`, `__miss__`, `__intersection__`, `__exception__`, case
/// sensitive); otherwise registration fails with `PipelineError::BadEntryName`.
#[test]
fn module_entry_name_prefixes_6_2() {
    fn bad(r: Result<Module<()>, PipelineError>, name: &str, kind: ProgramKind) {
        match r {
            Err(PipelineError::BadEntryName {
                name: n,
                kind: k,
                prefix,
            }) => {
                assert_eq!((n.as_str(), k, prefix), (name, kind.name(), kind.prefix()));
            }
            Err(e) => panic!("{name}: {e:?}"),
            Ok(_) => panic!("{name} was accepted as a {}", kind.name()),
        }
    }
    let m = || Module::<()>::new();
    for name in [
        "__miss__x",
        "raygen",
        "__RAYGEN__x",
        "_raygen__x",
        "x__raygen__y",
    ] {
        bad(m().raygen(name, |_| Ok(())), name, ProgramKind::RayGen);
    }
    for name in ["__anyhit__x", "__closesthit_x", "closesthit"] {
        bad(
            m().closest_hit(name, |_| Ok(())),
            name,
            ProgramKind::ClosestHit,
        );
    }
    for name in ["__closesthit__x", "__any_hit__x"] {
        bad(m().any_hit(name, |_| Ok(())), name, ProgramKind::AnyHit);
    }
    for name in ["__raygen__x", "miss"] {
        bad(m().miss(name, |_| Ok(())), name, ProgramKind::Miss);
    }
    for name in ["__intersect__x", "__anyhit__x"] {
        bad(
            m().intersection(name, |_| Ok(())),
            name,
            ProgramKind::Intersection,
        );
    }
    for name in ["__exceptions__x", "__raygen__x"] {
        bad(m().exception(name, |_| {}), name, ProgramKind::Exception);
    }
    // The right prefixes are accepted.
    let ok = m()
        .raygen("__raygen__x", |_| Ok(()))
        .and_then(|m| m.closest_hit("__closesthit__x", |_| Ok(())))
        .and_then(|m| m.any_hit("__anyhit__x", |_| Ok(())))
        .and_then(|m| m.miss("__miss__x", |_| Ok(())))
        .and_then(|m| m.intersection("__intersection__x", |_| Ok(())))
        .and_then(|m| m.exception("__exception__x", |_| {}));
    assert!(ok.is_ok());
    let e = m().raygen("nope", |_| Ok(())).err().unwrap();
    assert_eq!(e.code(), ErrorCode::InvalidValue);
    assert_eq!(
        [
            ProgramKind::RayGen,
            ProgramKind::ClosestHit,
            ProgramKind::AnyHit,
            ProgramKind::Miss,
            ProgramKind::Intersection,
            ProgramKind::Exception
        ]
        .map(ProgramKind::prefix),
        [
            "__raygen__",
            "__closesthit__",
            "__anyhit__",
            "__miss__",
            "__intersection__",
            "__exception__"
        ]
    );
}

/// §6.3 / S.1: one module may not define an entry name twice.
#[test]
fn module_duplicate_entry_6_3() {
    let r = Module::<()>::new()
        .raygen("__raygen__a", |_| Ok(()))
        .unwrap()
        .miss("__miss__a", |_| Ok(()))
        .unwrap()
        .raygen("__raygen__a", |_| Ok(()));
    assert_eq!(
        r.err(),
        Some(PipelineError::DuplicateEntry("__raygen__a".into()))
    );
    let r = Module::<()>::new()
        .closest_hit("__closesthit__c", |_| Ok(()))
        .unwrap()
        .closest_hit("__closesthit__c", |_| Ok(()));
    assert_eq!(
        r.err(),
        Some(PipelineError::DuplicateEntry("__closesthit__c".into()))
    );
}

/// §6.6 / S.4: a program group naming an entry its module lacks, or an entry of another program
/// kind, fails with `PipelineError::UnknownEntry` (naming the entry and the kind wanted).
#[test]
fn program_group_unknown_entry_6_6() {
    let m = Module::<()>::new()
        .raygen("__raygen__r", |_| Ok(()))
        .unwrap()
        .miss("__miss__m", |_| Ok(()))
        .unwrap()
        .closest_hit("__closesthit__c", |_| Ok(()))
        .unwrap()
        .any_hit("__anyhit__a", |_| Ok(()))
        .unwrap()
        .intersection("__intersection__i", |_| Ok(()))
        .unwrap()
        .exception("__exception__e", |_| {})
        .unwrap();
    let other = Module::<()>::new()
        .raygen("__raygen__elsewhere", |_| Ok(()))
        .unwrap();
    let unknown =
        |r: Result<ProgramGroup<()>, PipelineError>, name: &str, kind: ProgramKind| match r {
            Err(PipelineError::UnknownEntry { name: n, kind: k }) => {
                assert_eq!((n.as_str(), k), (name, kind.name()))
            }
            Err(e) => panic!("{name}: {e:?}"),
            Ok(_) => panic!("{name} was accepted as a {}", kind.name()),
        };
    unknown(
        ProgramGroup::raygen(&m, "__raygen__missing"),
        "__raygen__missing",
        ProgramKind::RayGen,
    );
    unknown(
        ProgramGroup::raygen(&m, "__raygen__elsewhere"),
        "__raygen__elsewhere",
        ProgramKind::RayGen,
    );
    unknown(
        ProgramGroup::raygen(&m, "__miss__m"),
        "__miss__m",
        ProgramKind::RayGen,
    );
    unknown(
        ProgramGroup::miss(Some((&m, "__raygen__r"))),
        "__raygen__r",
        ProgramKind::Miss,
    );
    unknown(
        ProgramGroup::exception(&m, "__miss__m"),
        "__miss__m",
        ProgramKind::Exception,
    );
    let hg = |ch: Option<&str>, ah: Option<&str>, is: Option<&str>| {
        ProgramGroup::hit_group(oxray::HitGroupDesc {
            closest_hit: ch.map(|n| (&m, n)),
            any_hit: ah.map(|n| (&m, n)),
            intersection: is.map(|n| (&m, n)),
        })
    };
    unknown(
        hg(Some("__anyhit__a"), None, None),
        "__anyhit__a",
        ProgramKind::ClosestHit,
    );
    unknown(
        hg(None, Some("__closesthit__c"), None),
        "__closesthit__c",
        ProgramKind::AnyHit,
    );
    unknown(
        hg(None, None, Some("__intersection__x")),
        "__intersection__x",
        ProgramKind::Intersection,
    );
    unknown(
        hg(
            Some("__closesthit__c"),
            Some("__anyhit__a"),
            Some("__closesthit__c"),
        ),
        "__closesthit__c",
        ProgramKind::Intersection,
    );
    // The right names work, and every hit-group member is optional.
    assert!(ProgramGroup::raygen(&other, "__raygen__elsewhere").is_ok());
    assert!(hg(
        Some("__closesthit__c"),
        Some("__anyhit__a"),
        Some("__intersection__i")
    )
    .is_ok());
    assert!(hg(None, None, None).is_ok());
    assert!(ProgramGroup::miss(None::<(&Module<()>, &str)>).is_ok());
    assert_eq!(
        ProgramGroup::exception(&m, "__exception__e")
            .unwrap()
            .kind(),
        oxray::ProgramGroupKind::Exception
    );
}

/// §6.7 / §12 / §13.3 / §13.4 / S.5: pipeline creation checks `num_payload_values <= 32`,
/// `num_attribute_values <= 8`, `max_trace_depth <= 31`, and needs at least one program group.
#[test]
fn pipeline_create_limits_6_7() {
    let m = Module::<()>::new()
        .raygen("__raygen__r", |_| Ok(()))
        .unwrap();
    let groups = [ProgramGroup::raygen(&m, "__raygen__r").unwrap()];
    let ctx = DeviceContext::new();
    let make = |payload, attrs, depth, groups: &[ProgramGroup<()>]| {
        Pipeline::new(&ctx, &compile(payload, attrs), &link(depth), groups).err()
    };
    assert_eq!(
        make(33, 2, 1, &groups),
        Some(PipelineError::TooManyPayloadValues(33))
    );
    assert_eq!(
        make(u32::MAX, 2, 1, &groups),
        Some(PipelineError::TooManyPayloadValues(u32::MAX))
    );
    assert_eq!(make(32, 2, 1, &groups), None);
    assert_eq!(make(0, 2, 1, &groups), None);
    assert_eq!(
        make(8, 9, 1, &groups),
        Some(PipelineError::TooManyAttributeValues(9))
    );
    assert_eq!(make(8, 8, 1, &groups), None);
    assert_eq!(
        make(8, 2, 32, &groups),
        Some(PipelineError::TraceDepthTooLarge(32))
    );
    assert_eq!(make(8, 2, 31, &groups), None);
    assert_eq!(make(8, 2, 0, &groups), None);
    assert_eq!(make(8, 2, 1, &[]), Some(PipelineError::NoProgramGroups));
    for e in [
        PipelineError::TooManyPayloadValues(33),
        PipelineError::NoProgramGroups,
    ] {
        assert_eq!(e.code(), ErrorCode::InvalidValue);
    }
}

/// §6.6 / S.4: triangles need no intersection program and one given in their hit group is
/// ignored: it never runs, and the hit is the triangle's.
#[test]
fn intersection_program_ignored_for_triangles_6_6() -> TestResult {
    let m = with_single_raygen(Module::new())
        .intersection("__intersection__never", |ctx| {
            ctx.params().push(ev_is(ctx));
            ctx.report_intersection(1.0, 5, &[])?;
            Ok(())
        })?
        .closest_hit("__closesthit__log", log_ch)?;
    let hg = hit_group(
        &m,
        Some("__closesthit__log"),
        None,
        Some("__intersection__never"),
    );
    let s = Setup::new(&m).hit(&hg, 0).miss(&miss_group(&m, None), 0);
    let handle = TraversableHandle::from(tri_gas(&[tri_at(0.0, 0.0, 0.0, 1.0)]));
    let out = s.run(&handle, RayDesc::down(0.0, 0.0), &[]);
    assert_eq!(out.count(Prog::Is), 0);
    assert_eq!((out.ch().kind, out.ch().tmax), (0xFE, 10.0));
    Ok(())
}

/// A random triangle soup split over two inputs (the second with primitive index offset 5000).
fn soup_gas(seed: u64, n: usize) -> Arc<Gas> {
    let mut rng = Rng::new(seed);
    let tris = random_soup(&mut rng, n, 10.0, 1.0);
    let (a, b) = tris.split_at(n / 2);
    let (va, vb) = (soup(a), soup(b));
    let inputs: [BuildInput; 2] = [
        TriangleInput::new(VertexBuffer::f32x3(&va)).into(),
        TriangleInput::new(VertexBuffer::f32x3(&vb))
            .primitive_index_offset(5000)
            .into(),
    ];
    Arc::new(Gas::build(&BuildOptions::default(), &inputs).unwrap())
}

/// Parameters of the determinism and agreement launches: launch index `i` traces `rays[i]` and
/// writes `[hit, t, primitive, u, v, hit kind, sbt-GAS index, extra]` to `out[i]`.
#[derive(Clone)]
struct Qp {
    handle: TraversableHandle,
    rays: Arc<Vec<Ray>>,
    out: Arc<OutputBuffer<[u32; 8]>>,
    shadow: bool,
}

fn query_module() -> Module<Qp> {
    Module::<Qp>::new()
        .raygen("__raygen__rays", |ctx| {
            let p = ctx.params();
            let [x, y, _] = ctx.launch_index();
            let i = (x + ctx.launch_dimensions()[0] * y) as usize;
            let r = p.rays[i];
            let mut payload = [0u32; 8];
            ctx.trace(
                &TraceRay::new(&p.handle, r.origin, r.direction).interval(r.tmin, r.tmax),
                &mut payload,
            )?;
            p.out.write(i, payload);
            Ok(())
        })
        .unwrap()
        .closest_hit("__closesthit__record", |ctx| {
            let [u, v] = ctx.triangle_barycentrics();
            let words = [
                1,
                ctx.ray_tmax().to_bits(),
                ctx.primitive_index(),
                if ctx.is_triangle_hit() {
                    u.to_bits()
                } else {
                    ctx.attribute(0)
                },
                if ctx.is_triangle_hit() {
                    v.to_bits()
                } else {
                    ctx.attribute(1)
                },
                ctx.hit_kind().0 as u32,
                ctx.sbt_gas_index(),
            ];
            for (k, w) in words.into_iter().enumerate() {
                ctx.set_payload(k, w);
            }
            if ctx.params().shadow {
                // A second-level occlusion ray towards a fixed light.
                let o = ctx.world_ray_origin() + ctx.world_ray_direction() * ctx.ray_tmax();
                let to_light = Vec3::new(20.0, 30.0, -10.0) - o;
                let mut occluded = [1u32];
                let flags = RayFlags::TERMINATE_ON_FIRST_HIT
                    | RayFlags::DISABLE_CLOSESTHIT
                    | RayFlags::DISABLE_ANYHIT;
                let p = ctx.params();
                ctx.trace(
                    &TraceRay::new(&p.handle, o, to_light)
                        .interval(1e-3, 1.0)
                        .flags(flags)
                        .sbt(0, 1, 1),
                    &mut occluded,
                )?;
                ctx.set_payload(7, occluded[0]);
            }
            Ok(())
        })
        .unwrap()
        .any_hit("__anyhit__cutout", |ctx| {
            if ctx.primitive_index() % 5 == 0 {
                return ctx.ignore_intersection();
            }
            Ok(())
        })
        .unwrap()
        .miss("__miss__none", |_| Ok(()))
        .unwrap()
        .miss("__miss__unoccluded", |ctx| {
            ctx.set_payload(0, 0);
            Ok(())
        })
        .unwrap()
        .intersection("__intersection__slab", |ctx| {
            let b = ctx.primitive_aabb();
            if let Some((t, u, v)) = slab(
                &b,
                ctx.object_ray_origin(),
                ctx.object_ray_direction(),
                ctx.ray_tmin(),
            ) {
                ctx.report_intersection(
                    t,
                    (ctx.primitive_index() % 100) as u8,
                    &[u.to_bits(), v.to_bits()],
                )?;
            }
            Ok(())
        })
        .unwrap()
}

/// The custom primitive of the agreement test: the box itself; the hit is where the ray enters it
/// (or leaves it, from inside), with `(u, v)` = the hit point's x and y.
fn slab(b: &Aabb, o: Vec3, d: Vec3, tmin: f32) -> Option<(f32, f32, f32)> {
    let t0 = (b.min - o) / d;
    let t1 = (b.max - o) / d;
    let near = t0.min(t1).max_element();
    let far = t0.max(t1).min_element();
    if near.is_nan() || far.is_nan() || near > far {
        return None;
    }
    let t = if near >= tmin { near } else { far };
    let p = o + d * t;
    Some((t, p.x, p.y))
}

fn query_pipeline(
    m: &Module<Qp>,
    anyhit: bool,
    custom: bool,
) -> (Pipeline<Qp>, ShaderBindingTable) {
    let rg = ProgramGroup::raygen(m, "__raygen__rays").unwrap();
    let hg = ProgramGroup::hit_group(oxray::HitGroupDesc {
        closest_hit: Some((m, "__closesthit__record")),
        any_hit: anyhit.then_some((m, "__anyhit__cutout")),
        intersection: custom.then_some((m, "__intersection__slab")),
    })
    .unwrap();
    let ms0 = ProgramGroup::miss(Some((m, "__miss__none"))).unwrap();
    let ms1 = ProgramGroup::miss(Some((m, "__miss__unoccluded"))).unwrap();
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &compile(8, 2),
        &link(2),
        &[rg.clone(), hg.clone(), ms0.clone(), ms1.clone()],
    )
    .unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_headers(&[ms0.pack_header(), ms1.pack_header()]),
        hitgroup: SbtRegion::from_headers(&[hg.pack_header(), hg.pack_header()]),
        ..Default::default()
    };
    (pipeline, sbt)
}

/// Camera rays into `[0, 10]^3` for a `w x h` image.
fn camera_rays(w: u32, h: u32) -> Vec<Ray> {
    let eye = Vec3::new(5.0, 5.0, -12.0);
    (0..h)
        .flat_map(|y| {
            (0..w).map(move |x| {
                let px = (x as f32 + 0.5) / w as f32 * 12.0 - 1.0;
                let py = (y as f32 + 0.5) / h as f32 * 12.0 - 1.0;
                Ray::new(eye, Vec3::new(px, py, 10.0) - eye)
            })
        })
        .collect()
}

/// §3.2 / determinism: a launch that traces camera rays at a random triangle soup (with an
/// any-hit cut-out and a second-level occlusion ray from the closest hit) writes bit-identical
/// output in rayon pools of 1 and 4 threads, and again on a second run.
#[test]
fn launch_output_independent_of_thread_count_determinism() {
    let m = query_module();
    let (pipeline, sbt) = query_pipeline(&m, true, false);
    let (w, h) = (96u32, 64u32);
    let gas = soup_gas(7, 3000);
    let rays = Arc::new(camera_rays(w, h));
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let p = Qp {
            handle: TraversableHandle::from(gas.clone()),
            rays: rays.clone(),
            out: Arc::new(OutputBuffer::new((w * h) as usize)),
            shadow: true,
        };
        let report = pool.install(|| pipeline.launch(&p, &sbt, w, h, 1)).unwrap();
        (report, p.out.to_vec())
    };
    let (r1, one) = run(1);
    let (r4, four) = run(4);
    let (r4b, four_again) = run(4);
    assert_eq!(r1.exceptions, 0);
    assert_eq!((&r1, &r1), (&r4, &r4b));
    let hits = one.iter().filter(|o| o[0] == 1).count();
    let shadowed = one.iter().filter(|o| o[0] == 1 && o[7] == 1).count();
    assert!(
        hits > 1000 && shadowed > 0 && shadowed < hits,
        "a meaningful scene: {hits} hits, {shadowed} shadowed"
    );
    for i in 0..one.len() {
        assert_eq!(one[i], four[i], "pixel {i}: 1 vs 4 threads");
        assert_eq!(four[i], four_again[i], "pixel {i}: run to run");
    }
}

fn random_rays(seed: u64, n: usize) -> Vec<Ray> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|i| {
            let o = rng.vec3(-3.0, 13.0);
            let target = rng.vec3(0.0, 10.0);
            let d = if i % 5 == 0 { rng.dir() } else { target - o };
            match i % 4 {
                0 => Ray::with_interval(o, d, 0.0, f32::INFINITY),
                1 => Ray::with_interval(o, d, rng.range(0.0, 0.3), rng.range(0.3, 1.5)),
                2 => {
                    Ray::with_interval(o, d.normalize(), rng.range(0.0, 2.0), rng.range(2.0, 30.0))
                }
                _ => Ray::new(o, d),
            }
        })
        .collect()
}

/// Agreement with the query API: for random rays, a trace whose closest-hit program records the
/// hit gives exactly `Gas::intersect`'s t, primitive index, barycentrics, hit kind and SBT-GAS
/// index, and misses exactly where it returns `None`.
#[test]
fn trace_agrees_with_gas_intersect_triangles() {
    let m = query_module();
    let (pipeline, sbt) = query_pipeline(&m, false, false);
    let gas = soup_gas(11, 2000);
    let n = 4096;
    let rays = Arc::new(random_rays(5, n));
    let p = Qp {
        handle: TraversableHandle::from(gas.clone()),
        rays: rays.clone(),
        out: Arc::new(OutputBuffer::new(n)),
        shadow: false,
    };
    assert_eq!(pipeline.launch(&p, &sbt, 64, 64, 1).unwrap().exceptions, 0);
    let out = p.out.to_vec();
    let mut hits = 0;
    for (i, r) in rays.iter().enumerate() {
        let expected = match gas.intersect(r) {
            Some(h) => {
                hits += 1;
                [
                    1,
                    h.t.to_bits(),
                    h.primitive_index,
                    h.u.to_bits(),
                    h.v.to_bits(),
                    h.hit_kind.0 as u32,
                    h.sbt_gas_index,
                    0,
                ]
            }
            None => [0; 8],
        };
        assert_eq!(out[i], expected, "ray {i}: {r:?}");
    }
    assert!(hits > n / 4 && hits < n, "{hits} hits");
}

/// Agreement with the query API for custom primitives: an intersection program and
/// `Gas::intersect_with` running the same intersection give the same closest hits.
#[test]
fn trace_agrees_with_gas_intersect_custom_primitives() {
    let m = query_module();
    let (pipeline, sbt) = query_pipeline(&m, false, true);
    let mut rng = Rng::new(13);
    let boxes: Vec<Aabb> = (0..600)
        .map(|_| {
            let c = rng.vec3(0.0, 10.0);
            Aabb::new(c - rng.vec3(0.05, 0.6), c + rng.vec3(0.05, 0.6))
        })
        .collect();
    let (a, b) = boxes.split_at(300);
    let inputs: [BuildInput; 2] = [
        CustomPrimitiveInput::new(AabbBuffer::new(a)).into(),
        CustomPrimitiveInput::new(AabbBuffer::new(b))
            .primitive_index_offset(1000)
            .into(),
    ];
    let gas = Arc::new(Gas::build(&BuildOptions::default(), &inputs).unwrap());
    let n = 4096;
    let rays = Arc::new(random_rays(17, n));
    let p = Qp {
        handle: TraversableHandle::from(gas.clone()),
        rays: rays.clone(),
        out: Arc::new(OutputBuffer::new(n)),
        shadow: false,
    };
    assert_eq!(pipeline.launch(&p, &sbt, 64, 64, 1).unwrap().exceptions, 0);
    let out = p.out.to_vec();
    let mut hits = 0;
    for (i, r) in rays.iter().enumerate() {
        let mut isect = |prim: &CustomPrimitive, ray: &Ray| {
            slab(&prim.aabb, ray.origin, ray.direction, ray.tmin).map(|(t, u, v)| CustomHit {
                t,
                hit_kind: (prim.primitive_index % 100) as u8,
                u,
                v,
            })
        };
        let expected = match gas.intersect_with(r, &mut isect) {
            Some(h) => {
                hits += 1;
                [
                    1,
                    h.t.to_bits(),
                    h.primitive_index,
                    h.u.to_bits(),
                    h.v.to_bits(),
                    h.hit_kind.0 as u32,
                    h.sbt_gas_index,
                    0,
                ]
            }
            None => [0; 8],
        };
        assert_eq!(out[i], expected, "ray {i}: {r:?}");
    }
    assert!(hits > n / 4 && hits < n, "{hits} hits");
}
