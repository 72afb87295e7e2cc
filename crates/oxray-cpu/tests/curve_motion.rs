//! Curves with motion on the CPU backend (guide §5.10.2 with §5.2, §9): a curve input gives its
//! control points, radii and ribbon normals per motion key, and a ray at time `t` meets the
//! segments interpolated linearly between the two keys around `t`.
//!
//! The reference for a ray at time `t` is a static build over the curve data interpolated here
//! with the guide's rule (keys evenly spaced over `[timeBegin, timeEnd]`, linear between the
//! two neighbouring keys, time clamped): the motion structure must give bit-identical hits,
//! with and without segment splitting (§9.2), on every kernel. Then the boundary behaviour
//! (vanish flags), the device functions that read the segment at the ray's time, the emitted
//! per-key boxes, the memory bound, compaction, saving and loading, and damaged files.

use glam::Vec3;
use oxray_bvh::serialize::{checksum, FORMAT_VERSION};
use oxray_bvh::{GasData, Triangle4};
use oxray_core::{
    BuildFlags, BuildOptions, CurveEndcaps, CurveInput, CurveType, DeviceContext, LoadError,
    MotionFlags, MotionOptions, PipelineCompileOptions, PipelineLinkOptions, PrimitiveTypeFlags,
    Ray, SbtRegion, ShaderBindingTable, TraversableHandle, TriangleInput, VertexBuffer,
};
use oxray_cpu::{Gas, HitGroupDesc, Isa, Module, OutputBuffer, Pipeline, ProgramGroup, TraceRay};
use oxray_testkit::oracle::hit_bits;
use oxray_testkit::rng::Rng;

/// Strands of one curve type with their control points, radii and (ribbons) normals at every
/// motion key.
#[derive(Clone)]
struct MovingStrands {
    ty: CurveType,
    points: Vec<Vec<[f32; 3]>>,
    radii: Vec<Vec<f32>>,
    normals: Vec<Vec<[f32; 3]>>,
    index: Vec<u32>,
}

impl MovingStrands {
    /// `n` strands of `segments` segments each, about one unit per segment, at `keys` keys:
    /// each key moves every strand by up to `amount`, jitters its control points, scales its
    /// radii and turns its ribbon normals.
    fn random(
        rng: &mut Rng,
        ty: CurveType,
        n: usize,
        segments: usize,
        keys: usize,
        amount: f32,
    ) -> Self {
        let k = ty.control_points();
        let mut s = MovingStrands {
            ty,
            points: vec![Vec::new()],
            radii: vec![Vec::new()],
            normals: vec![Vec::new()],
            index: Vec::new(),
        };
        for _ in 0..n {
            let start = s.points[0].len() as u32;
            s.index.extend((0..segments as u32).map(|j| start + j));
            let base = rng.vec3(-4.0, 4.0);
            let dir = rng.dir() * 0.5;
            for j in 0..segments + k - 1 {
                let p = base + dir * j as f32 + rng.vec3(-0.15, 0.15);
                s.points[0].push(p.to_array());
                s.radii[0].push(rng.range(0.03, 0.15));
                s.normals[0].push(rng.dir().to_array());
            }
        }
        for key in 1..keys {
            let prev = (&s.points[key - 1], &s.radii[key - 1], &s.normals[key - 1]);
            let mut points = Vec::with_capacity(prev.0.len());
            let mut d = Vec3::ZERO;
            for (i, p) in prev.0.iter().enumerate() {
                if s.index.contains(&(i as u32)) && (i == 0 || !s.index.contains(&(i as u32 - 1))) {
                    // A new strand: a new displacement.
                    d = rng.vec3(-amount, amount);
                }
                points.push((Vec3::from(*p) + d + rng.vec3(-0.1, 0.1)).to_array());
            }
            let radii = prev.1.iter().map(|r| r * rng.range(0.6, 1.5)).collect();
            let normals = prev
                .2
                .iter()
                .map(|nv| (Vec3::from(*nv) + rng.vec3(-0.7, 0.7)).to_array())
                .collect();
            s.points.push(points);
            s.radii.push(radii);
            s.normals.push(normals);
        }
        s
    }

    /// Builds over every key with `options` (whose motion options the caller sets), end caps
    /// on for the types that take them.
    fn build(&self, isa: Isa, options: &BuildOptions) -> Gas {
        let v: Vec<&[u8]> = self
            .points
            .iter()
            .map(|p| bytemuck::cast_slice(p))
            .collect();
        let r: Vec<&[u8]> = self.radii.iter().map(|p| bytemuck::cast_slice(p)).collect();
        let nb: Vec<&[u8]> = self
            .normals
            .iter()
            .map(|p| bytemuck::cast_slice(p))
            .collect();
        let mut input = CurveInput::new(
            self.ty,
            &v,
            self.points[0].len() as u32,
            &r,
            bytemuck::cast_slice(&self.index),
            self.index.len() as u32,
        );
        if self.ty != CurveType::RoundLinear {
            input = input.endcaps(CurveEndcaps::On);
        }
        if self.ty.is_ribbon() {
            input = input.normals(&nb, 0);
        }
        Gas::build_with_isa(isa, options, &[input.into()]).unwrap()
    }

    /// The strands at one instant: key `a` mixed with key `b` by `f`, with the guide's linear
    /// interpolation written out here.
    fn at(&self, a: usize, b: usize, f: f32) -> MovingStrands {
        let mix = |x: f32, y: f32| if f == 0.0 { x } else { x + (y - x) * f };
        let mix3 = |p: &[f32; 3], q: &[f32; 3]| std::array::from_fn(|i| mix(p[i], q[i]));
        MovingStrands {
            ty: self.ty,
            points: vec![self.points[a]
                .iter()
                .zip(&self.points[b])
                .map(|(p, q)| mix3(p, q))
                .collect()],
            radii: vec![self.radii[a]
                .iter()
                .zip(&self.radii[b])
                .map(|(&p, &q)| mix(p, q))
                .collect()],
            normals: vec![self.normals[a]
                .iter()
                .zip(&self.normals[b])
                .map(|(p, q)| mix3(p, q))
                .collect()],
            index: self.index.clone(),
        }
    }
}

/// The keys and fraction of `time` under `m`, from the guide's rule (not the engine's
/// `MotionOptions::sample`); `None` where a vanish flag hides the structure.
fn keys_at(m: &MotionOptions, time: f32) -> Option<(usize, usize, f32)> {
    let n = m.num_keys as usize;
    if (m.flags.contains(MotionFlags::START_VANISH) && time < m.time_begin)
        || (m.flags.contains(MotionFlags::END_VANISH) && time > m.time_end)
    {
        return None;
    }
    let t = time.clamp(m.time_begin, m.time_end);
    let pos = (t - m.time_begin) / (m.time_end - m.time_begin) * (n - 1) as f32;
    let k = (pos.floor() as usize).min(n - 1);
    if k == n - 1 {
        return Some((k, k, 0.0));
    }
    Some((k, k + 1, pos - k as f32))
}

/// Rays at `time` into `still` (the strands at that time): half aimed at points near the
/// surface of random segments (silhouettes included), half at random.
fn rays_at(rng: &mut Rng, still: &Gas, time: f32, n: usize) -> Vec<Ray> {
    let curves = &still.data().curves;
    (0..n)
        .map(|i| {
            let o = rng.vec3(-9.0, 9.0);
            let target = if i % 2 == 0 && !curves.is_empty() {
                let s = &curves[rng.below(curves.len())];
                let (c, r) = s.eval(rng.range(0.0, 1.0) as f64);
                c.as_vec3() + rng.dir() * (r as f32 * rng.range(0.0, 1.3))
            } else {
                rng.vec3(-5.0, 5.0)
            };
            Ray::new(o, target - o).with_time(time)
        })
        .collect()
}

/// The hit `got` as [`hit_bits`] gives it, or `want`'s where the two are a tie on a linear
/// strand's joint: the end of one segment and the start of the next are the same sphere (a
/// round cap, §9.3), met at the same distance, and which of the two a traversal meets first
/// depends on its tree.
fn joint_tie(
    got: &Option<oxray_core::Hit>,
    want: &Option<oxray_core::Hit>,
    ty: CurveType,
) -> Option<oxray_testkit::oracle::HitBits> {
    if let (Some(g), Some(w)) = (got, want) {
        let adjacent = g.primitive_index.abs_diff(w.primitive_index) == 1;
        let ends = [g.u, w.u] == [0.0, 1.0] || [g.u, w.u] == [1.0, 0.0];
        if ty == CurveType::RoundLinear && g.t == w.t && adjacent && ends {
            return hit_bits(want);
        }
    }
    hit_bits(got)
}

/// §5.10.2: every curve type with three motion keys hits exactly what a static build of the
/// segments interpolated at the ray's time hits (times outside the range are clamped), with
/// the default, the highest and the lowest splitting factors (§9.2), on every kernel.
#[test]
fn s5_10_2_moving_curves_match_static_builds_of_the_interpolated_curves() {
    let mut rng = Rng::new(0x5102c);
    let m = MotionOptions::new(3, -1.0, 1.5);
    for ty in CurveType::ALL {
        let strands = MovingStrands::random(&mut rng, ty, 40, 3, 3, 1.5);
        for flags in [
            BuildFlags::empty(),
            BuildFlags::PREFER_FAST_TRACE,
            BuildFlags::PREFER_FAST_BUILD,
        ] {
            let options = BuildOptions::new(flags).with_motion(m);
            for isa in Isa::available() {
                let gas = strands.build(isa, &options);
                let (mut hits, mut rays_cast) = (0, 0);
                for step in 0..9 {
                    // -1.6 .. 2.2: clamped at both ends, keys themselves, between keys.
                    let time = -1.6 + step as f32 * 0.475;
                    let (a, b, f) = keys_at(&m, time).unwrap();
                    let still = strands.at(a, b, f).build(isa, &BuildOptions::new(flags));
                    for ray in rays_at(&mut rng, &still, time, 60) {
                        let got = gas.intersect(&ray);
                        let want = still.intersect(&ray);
                        let (g, w) = (joint_tie(&got, &want, ty), hit_bits(&want));
                        assert_eq!(g, w, "{ty:?} {flags:?} {isa} at time {time}: {ray:?}");
                        assert_eq!(gas.occluded(&ray), want.is_some(), "{ty:?} {isa} {time}");
                        hits += got.is_some() as usize;
                        rays_cast += 1;
                    }
                }
                assert!(
                    hits * 5 > rays_cast,
                    "{ty:?}: too few hits to test anything ({hits} of {rays_cast})"
                );
            }
        }
    }
}

/// A straight linear segment along z from (x, 0, 5) to (x, 0, 7), radius `r`, at each key
/// `(x, r)`: one input with `keys.len()` motion keys.
fn sliding_tube(keys: &[(f32, f32)], m: MotionOptions) -> Gas {
    let points: Vec<[[f32; 3]; 2]> = keys
        .iter()
        .map(|&(x, _)| [[x, 0.0, 5.0], [x, 0.0, 7.0]])
        .collect();
    let radii: Vec<[f32; 2]> = keys.iter().map(|&(_, r)| [r, r]).collect();
    let v: Vec<&[u8]> = points.iter().map(|p| bytemuck::cast_slice(p)).collect();
    let r: Vec<&[u8]> = radii.iter().map(|p| bytemuck::cast_slice(p)).collect();
    let index = [0u32];
    let input = CurveInput::new(
        CurveType::RoundLinear,
        &v,
        2,
        &r,
        bytemuck::cast_slice(&index),
        1,
    );
    Gas::build(&BuildOptions::default().with_motion(m), &[input.into()]).unwrap()
}

/// §5.10.2: a tube sliding from x = 0 to x = 4 over [0, 1] crosses a ray at x = 2 only around
/// t = 0.5; its radius grows with it. Clamped outside the range, or gone with the vanish flags
/// (§5.10.1).
#[test]
fn s5_10_2_a_sliding_tube_is_hit_only_where_it_is() {
    let m = MotionOptions::new(2, 0.0, 1.0);
    let gas = sliding_tube(&[(0.0, 0.25), (4.0, 0.75)], m);
    let ray = |time: f32| Ray::new(Vec3::new(2.0, -10.0, 6.0), Vec3::Y).with_time(time);
    for (time, hit) in [
        (0.0, false),
        (0.3, false),
        (0.5, true),
        (0.6, true),
        (1.0, false),
    ] {
        assert_eq!(gas.intersect(&ray(time)).is_some(), hit, "time {time}");
    }
    // At t = 0.5 the tube is at x = 2 with radius 0.5: entered at y = -0.5.
    let h = gas.intersect(&ray(0.5)).unwrap();
    assert!((h.t - 9.5).abs() < 1e-4, "{h:?}");
    // Clamped: at x = 0 before the range, at x = 4 after it.
    let at_zero = |time: f32| Ray::new(Vec3::new(0.0, -10.0, 6.0), Vec3::Y).with_time(time);
    assert!(gas.intersect(&at_zero(-3.0)).is_some());
    assert!(gas.intersect(&at_zero(3.0)).is_none());
    let vanish = m.with_flags(MotionFlags::START_VANISH | MotionFlags::END_VANISH);
    let gas = sliding_tube(&[(0.0, 0.25), (4.0, 0.75)], vanish);
    assert!(gas.intersect(&at_zero(-3.0)).is_none(), "vanished before");
    assert!(gas.intersect(&at_zero(0.0)).is_some(), "there at the start");
}

#[derive(Clone)]
struct Params {
    handle: TraversableHandle,
    rays: Vec<(Vec3, Vec3, f32)>,
    out: std::sync::Arc<OutputBuffer<[f32; 8]>>,
}

/// §5.10.2, §9.3: the control points a closest-hit program reads
/// (`optixGetLinearCurveVertexData` and the others) and a ribbon's normal
/// (`optixGetRibbonNormal`) are the segment's at the ray's time; the GAS motion options are its
/// own (§13.10).
#[test]
fn s9_3_programs_read_the_moving_segment_at_the_ray_time() {
    let module = Module::<Params>::new()
        .raygen("__raygen__rg", |ctx| {
            let [x, _, _] = ctx.launch_index();
            let p = ctx.params();
            let (o, d, time) = p.rays[x as usize];
            let mut payload = [0u32; 8];
            ctx.trace(&TraceRay::new(&p.handle, o, d).time(time), &mut payload)?;
            p.out.write(x as usize, payload.map(f32::from_bits));
            Ok(())
        })
        .unwrap()
        .closest_hit("__closesthit__ch", |ctx| {
            let cp = ctx.curve_vertex_data();
            let n = ctx.ribbon_normal(ctx.ribbon_parameters());
            let options = ctx.gas_motion_options();
            for (i, v) in [cp[0][0], cp[0][3], cp[1][0], n.x, n.y, n.z]
                .into_iter()
                .enumerate()
            {
                ctx.set_payload_f32(i, v);
            }
            ctx.set_payload_f32(6, options.num_keys as f32);
            ctx.set_payload_f32(7, options.time_end);
            Ok(())
        })
        .unwrap()
        .miss("__miss__ms", |ctx| {
            ctx.set_payload_f32(0, -1.0);
            Ok(())
        })
        .unwrap();
    let rg = ProgramGroup::raygen(&module, "__raygen__rg").unwrap();
    let ms = ProgramGroup::miss(Some((&module, "__miss__ms"))).unwrap();
    let hg = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__ch")),
        ..Default::default()
    })
    .unwrap();
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &PipelineCompileOptions {
            uses_primitive_type_flags: PrimitiveTypeFlags::ROUND_LINEAR
                | PrimitiveTypeFlags::FLAT_QUADRATIC_BSPLINE,
            uses_motion_blur: true,
            ..Default::default()
        },
        &PipelineLinkOptions { max_trace_depth: 1 },
        &[rg.clone(), ms.clone(), hg.clone()],
    )
    .unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_headers(&[ms.pack_header()]),
        hitgroup: SbtRegion::from_headers(&[hg.pack_header()]),
        ..Default::default()
    };
    let launch = |handle: TraversableHandle, rays: Vec<(Vec3, Vec3, f32)>| {
        let out = std::sync::Arc::new(OutputBuffer::new(rays.len()));
        let n = rays.len() as u32;
        let params = Params {
            handle,
            rays,
            out: out.clone(),
        };
        let report = pipeline.launch(&params, &sbt, n, 1, 1).unwrap();
        assert_eq!(report.exceptions, 0, "{report:?}");
        out.to_vec()
    };

    // The sliding tube: at t = 0.5 its control points are at x = 2 with radius 0.5.
    let m = MotionOptions::new(2, 0.0, 1.0);
    let tube = sliding_tube(&[(0.0, 0.25), (4.0, 0.75)], m);
    let o = launch(
        tube.into(),
        vec![(Vec3::new(2.0, -10.0, 6.0), Vec3::Y, 0.5)],
    );
    assert_eq!(o[0][..3], [2.0, 0.5, 2.0], "{:?}", o[0]);
    assert_eq!(o[0][6..], [2.0, 1.0]);

    // A flat ribbon in the z = 0 plane whose normals turn from +z (key 0) to +y (key 1)
    // about its axis x: half-way, the ribbon faces (0, 1, 1) / √2.
    let points = [[-1.0f32, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
    let radii = [0.5f32; 3];
    let (nz, ny) = ([[0.0f32, 0.0, 1.0]; 3], [[0.0f32, 1.0, 0.0]; 3]);
    let v: [&[u8]; 2] = [bytemuck::cast_slice(&points), bytemuck::cast_slice(&points)];
    let r: [&[u8]; 2] = [bytemuck::cast_slice(&radii), bytemuck::cast_slice(&radii)];
    let nb: [&[u8]; 2] = [bytemuck::cast_slice(&nz), bytemuck::cast_slice(&ny)];
    let index = [0u32];
    let input = CurveInput::new(
        CurveType::FlatQuadraticBSpline,
        &v,
        3,
        &r,
        bytemuck::cast_slice(&index),
        1,
    )
    .normals(&nb, 0);
    let ribbon = Gas::build(&BuildOptions::default().with_motion(m), &[input.into()]).unwrap();
    let down = Vec3::new(0.0, -1.0, -1.0).normalize();
    let o = launch(
        ribbon.into(),
        vec![
            (Vec3::new(0.0, 0.0, 5.0), -Vec3::Z, 0.0),
            (-down * 5.0, down, 0.5),
            (Vec3::new(0.0, 5.0, 0.0), -Vec3::Y, 1.0),
        ],
    );
    let normal = |p: &[f32; 8]| Vec3::new(p[3], p[4], p[5]);
    let expected = [Vec3::Z, -down, Vec3::Y];
    for (p, want) in o.iter().zip(expected) {
        assert_eq!(p[6], 2.0, "the ribbon is hit: {p:?}");
        let got = normal(p);
        // The normal faces the ray's origin; its sign is the face's.
        assert!(
            (got.dot(want).abs() - 1.0).abs() < 1e-4,
            "{got} against {want}"
        );
    }
}

/// §5.8: the emitted boxes of a structure with motion are one per key, each around that key's
/// segments; every segment interpolated at any time lies in the union of its keys' boxes, so
/// in the structure's box.
#[test]
fn s5_10_2_key_boxes_bound_every_key_and_every_instant() {
    let mut rng = Rng::new(0xb0c5);
    let strands = MovingStrands::random(&mut rng, CurveType::RoundCubicBSpline, 30, 4, 4, 2.0);
    let m = MotionOptions::new(4, 0.0, 3.0);
    let gas = strands.build(Isa::Sse, &BuildOptions::default().with_motion(m));
    let boxes = gas.data().key_bounds();
    assert_eq!(boxes.len(), 4);
    for (key, b) in boxes.iter().enumerate() {
        let still = strands
            .at(key, key, 0.0)
            .build(Isa::Sse, &BuildOptions::default());
        assert_eq!(*b, still.data().bounds, "key {key}");
    }
    let all = boxes
        .iter()
        .fold(oxray_core::Aabb::EMPTY, |a, b| a.union(b));
    for i in 0..=30 {
        let time = i as f32 * 0.1;
        let (a, b, f) = keys_at(&m, time).unwrap();
        let still = strands
            .at(a, b, f)
            .build(Isa::Sse, &BuildOptions::default());
        let sb = still.data().bounds;
        assert!(
            gas.data().bounds.contains_box(&sb) && all.contains_box(&sb),
            "time {time}: {sb:?} outside {:?}",
            gas.data().bounds
        );
    }
}

/// §5.7, §5.8: the memory query bounds a motion curve build, compaction keeps every key, and a
/// saved structure loads with the same keys and hits.
#[test]
fn s5_10_2_moving_curves_compact_save_and_load_with_identical_hits() {
    let mut rng = Rng::new(0x5a7e);
    let strands = MovingStrands::random(&mut rng, CurveType::FlatQuadraticBSpline, 60, 3, 3, 1.0);
    let m = MotionOptions::new(3, 0.0, 2.0).with_flags(MotionFlags::END_VANISH);
    for flags in [
        BuildFlags::ALLOW_COMPACTION,
        BuildFlags::ALLOW_COMPACTION | BuildFlags::PREFER_FAST_TRACE,
    ] {
        let options = BuildOptions::new(flags).with_motion(m);
        let gas = strands.build(Isa::Sse, &options);
        {
            let v: Vec<&[u8]> = strands
                .points
                .iter()
                .map(|p| bytemuck::cast_slice(p))
                .collect();
            let r: Vec<&[u8]> = strands
                .radii
                .iter()
                .map(|p| bytemuck::cast_slice(p))
                .collect();
            let nb: Vec<&[u8]> = strands
                .normals
                .iter()
                .map(|p| bytemuck::cast_slice(p))
                .collect();
            let input = CurveInput::new(
                strands.ty,
                &v,
                strands.points[0].len() as u32,
                &r,
                bytemuck::cast_slice(&strands.index),
                strands.index.len() as u32,
            )
            .normals(&nb, 0);
            let sizes = oxray_bvh::compute_memory_usage(&options, &[input.into()]).unwrap();
            assert!(
                gas.data().memory().output_bytes <= sizes.output_size_in_bytes,
                "{flags:?}: {} > {}",
                gas.data().memory().output_bytes,
                sizes.output_size_in_bytes
            );
        }
        let motion = gas.data().motion.as_ref().unwrap();
        assert_eq!(motion.curves.len(), 2 * gas.data().curves.len());
        let bytes = gas.data().to_bytes();
        let back = Gas::from_data_with_isa(GasData::from_bytes(&bytes).unwrap(), Isa::Sse);
        let compact = Gas::from_data_with_isa(gas.data().compact().unwrap(), Isa::Sse);
        assert_eq!(back.data().motion, gas.data().motion);
        assert_eq!(compact.data().motion, gas.data().motion);
        let mut hits = 0;
        for i in 0..400 {
            // Past the end too, where the structure vanishes.
            let time = i as f32 * 0.006;
            let (a, b, f) = keys_at(&m, time).unwrap_or((0, 0, 0.0));
            let still = strands
                .at(a, b, f)
                .build(Isa::Sse, &BuildOptions::default());
            let ray = rays_at(&mut rng, &still, time, 1)[0];
            let want = hit_bits(&gas.intersect(&ray));
            assert_eq!(hit_bits(&back.intersect(&ray)), want);
            assert_eq!(hit_bits(&compact.intersect(&ray)), want);
            if time > 2.0 {
                assert_eq!(want, None, "vanished after the end");
            }
            hits += want.is_some() as usize;
        }
        assert!(hits > 40, "{hits}");

        // A later key's segment of another type than key 0's is refused on loading.
        let mut data = gas.data().clone();
        data.motion.as_mut().unwrap().curves[3].curve_type = CurveType::RoundCubicBezier.code();
        let err = GasData::from_bytes(&data.to_bytes()).unwrap_err();
        assert!(
            matches!(err, LoadError::Invalid { what, index: 3 } if what.contains("motion")),
            "{err}"
        );
    }
}

/// The format before curves with motion (version 5: three motion arrays) still loads: a
/// version-5 file of a triangle structure with motion, written here from a current file by
/// dropping the curve array's length.
#[test]
fn version_5_motion_structures_still_load() {
    assert_eq!(FORMAT_VERSION, 6);
    let k0 = [[0.0f32, 0.0, 5.0], [1.0, 0.0, 5.0], [0.0, 1.0, 5.0]];
    let k1 = [[0.0f32, 0.0, 6.0], [1.0, 0.0, 6.0], [0.0, 1.0, 6.0]];
    let later = [VertexBuffer::f32x3(&k1)];
    let input = TriangleInput::new(VertexBuffer::f32x3(&k0)).motion_vertices(&later);
    let m = MotionOptions::new(2, 0.0, 1.0);
    let gas = Gas::build(&BuildOptions::default().with_motion(m), &[input.into()]).unwrap();
    let bytes = gas.data().to_bytes();
    // Header: magic, version, kind, payload length, checksum; the motion section ends with
    // four lengths and the later keys' triangle blocks (no boxes, spheres or segments).
    let later_bytes =
        gas.data().motion.as_ref().unwrap().triangles.len() * std::mem::size_of::<Triangle4>();
    let cut = bytes.len() - later_bytes - 8;
    assert_eq!(bytes[cut..cut + 8], [0; 8], "the curve array's length");
    let mut payload = bytes[32..cut].to_vec();
    payload.extend_from_slice(&bytes[cut + 8..]);
    let mut v5 = bytes[..8].to_vec();
    v5.extend_from_slice(&5u32.to_le_bytes());
    v5.extend_from_slice(&bytes[12..16]);
    v5.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    v5.extend_from_slice(&checksum(&payload).to_le_bytes());
    v5.extend_from_slice(&payload);
    let back = GasData::from_bytes(&v5).unwrap();
    assert_eq!(back.motion, gas.data().motion);
    let back = Gas::from_data_with_isa(back, Isa::Sse);
    for time in [0.0, 0.5, 1.0] {
        let ray = Ray::new(Vec3::new(0.25, 0.25, 0.0), Vec3::Z).with_time(time);
        assert_eq!(
            hit_bits(&back.intersect(&ray)),
            hit_bits(&gas.intersect(&ray))
        );
        assert!(back.intersect(&ray).is_some());
    }
    // The same bytes read as version 6 are short by the missing length.
    assert!(GasData::from_bytes(&bytes[..bytes.len() - 1]).is_err());
}
