//! Built-in spheres on the CPU backend (guide §5.3, §9.1, §9.4, §9.6, §13.2, §13.7): hits
//! against an f64 reference on random rays, rays from inside, instancing with a non-uniform
//! transform, inactive spheres, update against rebuild, compaction, and the pipeline (any-hit,
//! closest-hit, miss, flags, primitive-type flags), with Rust programs and with a CUDA C++
//! program compiled by the host compiler.

use glam::Vec3;
use oxray_bvh::{GasData, Sphere};
use oxray_core::{
    BuildError, BuildFlags, BuildOperation, BuildOptions, DeviceContext, ExceptionCode,
    GeometryFlags, HitKind, Instance, PipelineCompileOptions, PipelineLinkOptions, PrimitiveType,
    PrimitiveTypeFlags, Ray, RayFlags, SbtIndexOffsets, SbtRegion, ShaderBindingTable, SphereInput,
    Transform, TraversableHandle, TriangleInput, VertexBuffer,
};
use oxray_cpu::{
    Gas, HitGroupDesc, Ias, Isa, Module, OutputBuffer, Pipeline, ProgramGroup, TraceRay,
};
use oxray_testkit::oracle::hit_bits;
use oxray_testkit::rng::Rng;

/// Centres and radii as the byte buffers of one motion key.
struct Cloud {
    centres: Vec<[f32; 3]>,
    radii: Vec<f32>,
}

impl Cloud {
    fn random(rng: &mut Rng, n: usize, extent: f32, rmin: f32, rmax: f32) -> Cloud {
        Cloud {
            centres: (0..n)
                .map(|_| rng.vec3(-extent, extent).to_array())
                .collect(),
            radii: (0..n).map(|_| rng.range(rmin, rmax)).collect(),
        }
    }

    fn keys(&self) -> ([&[u8]; 1], [&[u8]; 1]) {
        (
            [bytemuck::cast_slice(&self.centres)],
            [bytemuck::cast_slice(&self.radii)],
        )
    }

    fn sphere(&self, i: usize) -> Sphere {
        Sphere::new(Vec3::from(self.centres[i]), self.radii[i])
    }
}

/// The f64 reference: the entry root of the f32 sphere and ray, evaluated in f64 (every input
/// is exact in f64), or `None` when the line misses.
fn entry_f64(s: &Sphere, o: Vec3, d: Vec3) -> Option<f64> {
    let c = Vec3::from(s.center).as_dvec3();
    let (o, d, r) = (o.as_dvec3(), d.as_dvec3(), s.radius as f64);
    let f = o - c;
    let a = d.dot(d);
    let b = -f.dot(d);
    let perp = f + d * (b / a);
    let disc = a * (r * r - perp.dot(perp));
    if disc < 0.0 {
        return None;
    }
    let q = b + disc.sqrt().copysign(b);
    let cc = f.dot(f) - r * r;
    Some((cc / q).min(q / a))
}

/// How close to grazing the ray passes: `1 - |f⊥| / r` (0 at the silhouette), in f64.
fn grazing(s: &Sphere, o: Vec3, d: Vec3) -> f64 {
    let c = Vec3::from(s.center).as_dvec3();
    let (o, d) = (o.as_dvec3(), d.as_dvec3());
    let f = o - c;
    let perp = f - d * (f.dot(d) / d.dot(d));
    (1.0 - perp.length() / s.radius as f64).abs()
}

/// The closest front-face hit over every sphere, by brute force in f64: (t, sphere).
fn reference(cloud: &Cloud, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<(f64, usize)> {
    let mut best: Option<(f64, usize)> = None;
    for i in 0..cloud.centres.len() {
        let s = cloud.sphere(i);
        if !s.is_active() {
            continue;
        }
        if let Some(t) = entry_f64(&s, o, d) {
            if t >= tmin as f64 && t <= tmax as f64 && best.is_none_or(|b| t < b.0) {
                best = Some((t, i));
            }
        }
    }
    best
}

fn build(cloud: &Cloud, flags: BuildFlags) -> Gas {
    let (c, r) = cloud.keys();
    let input = SphereInput::new(&c, cloud.centres.len() as u32, &r);
    Gas::build(&BuildOptions::new(flags), &[input.into()]).unwrap()
}

/// §9.4: the hit is the front-face (entry) point of the nearest sphere; compared with an f64
/// brute force on random rays through a random cloud, for every kernel this processor has.
/// Differences may only come from rays that graze a silhouette (within 1e-4 of the radius)
/// or whose entry lies at the interval's ends.
#[test]
fn s9_4_hits_match_an_f64_reference_on_random_rays() {
    let mut rng = Rng::new(0x594);
    let cloud = Cloud::random(&mut rng, 2000, 10.0, 0.05, 0.8);
    let mut rays = Vec::new();
    for k in 0..6000 {
        let o = rng.vec3(-14.0, 14.0);
        let d = if k % 2 == 0 {
            rng.dir()
        } else {
            // Aimed near a sphere's silhouette, to test grazing rays.
            let s = cloud.sphere(rng.below(cloud.centres.len()));
            let near = if k % 4 == 1 { 1e-5 } else { 2e-2 };
            let target =
                Vec3::from(s.center) + rng.unit() * s.radius * rng.range(1.0 - near, 1.0 + near);
            (target - o) * rng.range(0.5, 2.0)
        };
        rays.push(Ray::with_interval(o, d, 0.0, rng.range(5.0, 40.0)));
    }
    for isa in Isa::available() {
        let (cref, rref) = cloud.keys();
        let input = SphereInput::new(&cref, cloud.centres.len() as u32, &rref);
        let gas = Gas::build_with_isa(isa, &BuildOptions::default(), &[input.into()]).unwrap();
        let (mut max_rel, mut max_grazing, mut hits, mut misses, mut false_hits, mut others) =
            (0f64, 0f64, 0, 0, 0, 0);
        for ray in &rays {
            let got = gas.intersect(ray);
            let want = reference(&cloud, ray.origin, ray.direction, ray.tmin, ray.tmax);
            match (got, want) {
                (Some(h), Some((t, i))) => {
                    hits += 1;
                    assert_eq!(h.hit_kind, HitKind::SPHERE_FRONT_FACE);
                    assert_eq!((h.u, h.v), (0.0, 0.0), "spheres have no attributes (§13.4)");
                    let s = cloud.sphere(i);
                    // Relative to t, or to the origin's distance from the centre (in units of
                    // the direction) where that is larger: with the origin near the surface,
                    // t is tiny and f·f - r² cancels, and no f32 formulation resolves t
                    // better than the origin's own rounding, ε |f| / |d|.
                    let f = (ray.origin - Vec3::from(s.center)).length() as f64;
                    let scale = t.max(f / ray.direction.length() as f64);
                    let rel = (h.t as f64 - t).abs() / scale;
                    if h.primitive_index as usize != i {
                        // Another sphere at (nearly) the same distance: checked below.
                    } else if grazing(&s, ray.origin, ray.direction) >= 1e-2 {
                        max_rel = max_rel.max(rel);
                    } else {
                        // Near the silhouette t is ill-conditioned: an error ε|f| in the
                        // centre's distance to the line moves t by about √(2 r ε |f|) / |d|.
                        let bound = (2.0 * s.radius as f64 * f32::EPSILON as f64 * f).sqrt()
                            / ray.direction.length() as f64;
                        let err = (h.t as f64 - t).abs();
                        assert!(err <= 2.0 * bound + 1e-6 * t, "{ray:?}: {err} > {bound}");
                        max_grazing = max_grazing.max(err / bound);
                    }
                    if h.primitive_index as usize != i {
                        // Another sphere at (nearly) the same distance.
                        assert!(rel < 1e-4, "{ray:?}: {h:?} vs sphere {i} at {t}");
                        others += 1;
                    }
                }
                (None, None) => {}
                (Some(h), None) => {
                    let s = cloud.sphere(h.primitive_index as usize);
                    assert!(
                        grazing(&s, ray.origin, ray.direction) < 1e-4,
                        "a false hit away from the silhouette: {ray:?} {h:?}"
                    );
                    false_hits += 1;
                }
                (None, Some((t, i))) => {
                    let s = cloud.sphere(i);
                    let end = (t - ray.tmax as f64).abs().min((t - ray.tmin as f64).abs());
                    assert!(
                        grazing(&s, ray.origin, ray.direction) < 1e-4 || end < 1e-5 * t,
                        "a miss away from the silhouette: {ray:?}, sphere {i} at {t}"
                    );
                    misses += 1;
                }
            }
        }
        println!(
            "{isa:?}: {} rays, {hits} hits, max relative t error {max_rel:.3e} (within 1 % of \
             the silhouette: {max_grazing:.2} of the conditioning bound), {misses} misses and \
             {false_hits} false hits at silhouettes, {others} ties",
            rays.len()
        );
        assert!(hits > 1000);
        assert!(max_rel < 1e-5, "max relative t error {max_rel}");
        assert!(misses + false_hits <= rays.len() / 200);
    }
}

/// The textbook test in f32 (`b² - a c` and `(-b - √disc) / a`), to show what the robust one
/// buys.
fn naive_f32(s: &Sphere, o: Vec3, d: Vec3) -> Option<f32> {
    let f = o - Vec3::from(s.center);
    let (a, b, c) = (d.dot(d), f.dot(d), f.dot(f) - s.radius * s.radius);
    let disc = b * b - a * c;
    (disc >= 0.0).then(|| (-b - disc.sqrt()) / a)
}

/// The robust formulation (RTG ch. 7) keeps t accurate for small spheres far away, where the
/// textbook discriminant `b² - a c` cancels: one sphere at a time against f64, rays aimed
/// well inside the silhouette (within 0.9 of the radius).
#[test]
fn s9_4_small_distant_spheres_keep_their_precision() {
    let mut rng = Rng::new(0x7);
    let dists = [1.0f32, 1e2, 1e3, 1e4];
    let (mut worst, mut naive_worst, mut naive_misses) = ([0f64; 4], [0f64; 4], [0; 4]);
    for (k, dist) in dists.into_iter().enumerate() {
        for _ in 0..4000 {
            // Radii of 1e-4 to 1e-3 of the distance: small, yet many ulps of the centre.
            let r = rng.range(1e-4, 1e-3) * dist;
            let c = rng.unit() * dist;
            let s = Sphere::new(c, r);
            let o = rng.vec3(-1.0, 1.0);
            let target = c + rng.unit() * r * rng.range(0.0, 0.9);
            let d = (target - o) * rng.range(0.1, 10.0);
            let want = entry_f64(&s, o, d).expect("aimed inside");
            let got = s.intersect(o, d, 0.0, f32::INFINITY).expect("a hit");
            worst[k] = worst[k].max((got as f64 - want).abs() / want);
            match naive_f32(&s, o, d) {
                Some(t) => naive_worst[k] = naive_worst[k].max((t as f64 - want).abs() / want),
                None => naive_misses[k] += 1,
            }
        }
    }
    println!(
        "distances {dists:?}: max relative t error {worst:?}; the textbook f32 test: \
         {naive_worst:?}, and {naive_misses:?} misses of 4000"
    );
    for w in worst {
        assert!(w < 1e-5, "{worst:?}");
    }
}

/// §9.6: spheres are hollow and their back faces culled: a ray starting inside a sphere does
/// not hit it, and goes on to the next sphere; an interval that starts inside does the same.
#[test]
fn s9_6_rays_from_inside_do_not_hit_that_sphere() {
    let cloud = Cloud {
        centres: vec![[0.0, 0.0, 0.0], [0.0, 0.0, 5.0]],
        radii: vec![1.0, 1.0],
    };
    let gas = build(&cloud, BuildFlags::empty());
    let h = gas
        .intersect(&Ray::new(Vec3::new(0.0, 0.0, 0.3), Vec3::Z))
        .unwrap();
    assert_eq!(h.primitive_index, 1);
    assert!((h.t - 3.7).abs() < 1e-6, "{}", h.t);
    // The interval starts inside sphere 0 (the origin is outside it): no hit on it either.
    let ray = Ray::with_interval(Vec3::new(0.0, 0.0, -3.0), Vec3::Z, 2.5, 100.0);
    assert_eq!(gas.intersect(&ray).unwrap().primitive_index, 1);
    // Out of sphere 1 backwards: sphere 0 at t = 4; forwards: nothing.
    let h = gas
        .intersect(&Ray::new(Vec3::new(0.0, 0.0, 5.0), -Vec3::Z))
        .unwrap();
    assert_eq!((h.primitive_index, h.t), (0, 4.0));
    assert!(gas
        .intersect(&Ray::new(Vec3::new(0.0, 0.0, 5.0), Vec3::Z))
        .is_none());
}

/// §5.3 with §5.1's rule on inactive primitives: spheres with a NaN centre, a radius that is
/// NaN, zero or negative are not hit; an updatable build keeps their slots, and an update that
/// gives them a radius makes them hit.
#[test]
fn s5_3_inactive_spheres_are_dropped_and_an_update_activates_them() {
    let mut cloud = Cloud {
        centres: vec![
            [0.0, 0.0, 0.0],
            [3.0, 0.0, 0.0],
            [6.0, 0.0, 0.0],
            [f32::NAN, 0.0, 0.0],
            [12.0, 0.0, 0.0],
        ],
        radii: vec![1.0, 0.0, -1.0, 1.0, f32::NAN],
    };
    let gas = build(&cloud, BuildFlags::empty());
    assert_eq!((gas.num_primitives(), gas.num_active_primitives()), (5, 1));
    let mut gas = build(&cloud, BuildFlags::ALLOW_UPDATE);
    assert_eq!(gas.num_active_primitives(), 1);
    for x in [3.0, 6.0, 12.0] {
        let ray = Ray::new(Vec3::new(x, 0.0, -5.0), Vec3::Z);
        assert!(gas.intersect(&ray).is_none(), "x = {x}");
    }
    cloud.radii = vec![1.0, 1.0, 1.0, 1.0, 1.0];
    cloud.centres[3] = [9.0, 0.0, 0.0];
    let (c, r) = cloud.keys();
    let up = BuildOptions {
        operation: BuildOperation::Update,
        ..BuildOptions::new(BuildFlags::ALLOW_UPDATE)
    };
    gas.update(&up, &[SphereInput::new(&c, 5, &r).into()])
        .unwrap();
    assert_eq!(gas.num_active_primitives(), 5);
    for (i, x) in [0.0, 3.0, 6.0, 9.0, 12.0].into_iter().enumerate() {
        let h = gas
            .intersect(&Ray::new(Vec3::new(x, 0.0, -5.0), Vec3::Z))
            .unwrap();
        assert_eq!((h.primitive_index, h.t), (i as u32, 4.0));
    }
    // §5.6: singleRadius is part of the input's description.
    let one = [bytemuck::cast_slice::<f32, u8>(&cloud.radii[..1])];
    let err = gas
        .update(
            &up,
            &[SphereInput::new(&c, 5, &one).single_radius(true).into()],
        )
        .unwrap_err();
    assert!(matches!(err, BuildError::InvalidUpdate(_)), "{err}");
}

/// §5.6: an updated structure traces the hits of a rebuild over the new data, and §5.8: a
/// compacted one the hits of its source; §5.3 with per-primitive SBT offsets and a primitive
/// index offset.
#[test]
fn s5_6_update_then_trace_equals_rebuild_then_trace() {
    let mut rng = Rng::new(0x56);
    let a = Cloud::random(&mut rng, 800, 5.0, 0.1, 0.5);
    let mut b = Cloud {
        centres: a.centres.clone(),
        radii: a.radii.clone(),
    };
    for (c, r) in b.centres.iter_mut().zip(&mut b.radii) {
        *c = (Vec3::from(*c) + rng.vec3(-0.5, 0.5)).to_array();
        *r *= rng.range(0.5, 1.5);
    }
    let offsets: Vec<u16> = (0..800).map(|i| (i % 3) as u16).collect();
    let flags = [GeometryFlags::empty(); 3];
    let input = |cloud: &Cloud| -> (Vec<u8>, Vec<u8>) {
        (
            bytemuck::cast_slice(&cloud.centres).to_vec(),
            bytemuck::cast_slice(&cloud.radii).to_vec(),
        )
    };
    let options = BuildOptions::new(BuildFlags::ALLOW_UPDATE | BuildFlags::ALLOW_COMPACTION);
    let (ca, ra) = input(&a);
    let (cb, rb) = input(&b);
    let (ka, kra, kb, krb) = ([&ca[..]], [&ra[..]], [&cb[..]], [&rb[..]]);
    let offsets = SbtIndexOffsets::u16(&offsets);
    let input_a = SphereInput::new(&ka, 800, &kra)
        .flags(&flags)
        .sbt_index_offsets(offsets)
        .primitive_index_offset(100);
    let input_b = SphereInput::new(&kb, 800, &krb)
        .flags(&flags)
        .sbt_index_offsets(offsets)
        .primitive_index_offset(100);
    let mut updated = Gas::build(&options, &[input_a.into()]).unwrap();
    let up = BuildOptions {
        operation: BuildOperation::Update,
        ..options
    };
    updated.update(&up, &[input_b.into()]).unwrap();
    let rebuilt = Gas::build(&options, &[input_b.into()]).unwrap();
    let compact = Gas::from(rebuilt.data().compact().unwrap());
    let mut hits = 0;
    for _ in 0..4000 {
        let o = rng.vec3(-8.0, 8.0);
        let ray = Ray::new(o, rng.vec3(-3.0, 3.0) - o);
        let (u, r) = (updated.intersect(&ray), rebuilt.intersect(&ray));
        assert_eq!(hit_bits(&u), hit_bits(&r), "{ray:?}");
        assert_eq!(hit_bits(&compact.intersect(&ray)), hit_bits(&r));
        if let Some(h) = u {
            hits += 1;
            let local = h.primitive_index - 100;
            assert_eq!(
                h.sbt_gas_index,
                local % 3,
                "§7.3: the per-primitive SBT offset"
            );
        }
    }
    assert!(hits > 500);
}

/// §9.1, §5.4: spheres under instances with non-uniform scale (ellipsoids: a sphere takes the
/// instance transform, not a pre-transform) and rotation, in an IAS, against the reference in
/// each instance's object space.
#[test]
fn s9_1_spheres_in_an_ias_with_transforms() {
    let mut rng = Rng::new(0x91);
    let cloud = Cloud::random(&mut rng, 300, 2.0, 0.1, 0.4);
    let gas: TraversableHandle = build(&cloud, BuildFlags::empty()).into();
    let transforms: Vec<Transform> = (0..6)
        .map(|i| {
            let a = glam::Affine3A::from_scale_rotation_translation(
                Vec3::new(1.0 + i as f32 * 0.3, 0.5 + 0.2 * i as f32, 1.0),
                rng.rotation(),
                Vec3::new(i as f32 * 7.0 - 17.5, 0.0, 0.0),
            );
            Transform::from_affine(&a)
        })
        .collect();
    let instances: Vec<Instance> = transforms
        .iter()
        .enumerate()
        .map(|(i, t)| {
            Instance::new(gas.clone())
                .transform(*t)
                .instance_id(10 + i as u32)
        })
        .collect();
    let ias = Ias::build(&BuildOptions::default(), &[(&instances[..]).into()]).unwrap();
    let mut hits = 0;
    for _ in 0..3000 {
        let o = Vec3::new(rng.range(-22.0, 22.0), rng.range(-6.0, 6.0), -10.0);
        let d = Vec3::new(rng.range(-0.3, 0.3), rng.range(-0.3, 0.3), 1.0);
        let ray = Ray::new(o, d);
        let got = ias.intersect(&ray);
        // The reference: each instance's object-space ray (not normalised: t agrees).
        let mut want: Option<(f64, u32, usize)> = None;
        for (k, t) in transforms.iter().enumerate() {
            let w2o = t.inverse().unwrap();
            let (oo, od) = (w2o.transform_point(o), w2o.transform_vector(d));
            if let Some((tt, i)) = reference(&cloud, oo, od, 0.0, f32::INFINITY) {
                if want.is_none_or(|w| tt < w.0) {
                    want = Some((tt, 10 + k as u32, i));
                }
            }
        }
        match (got, want) {
            (Some(h), Some((t, id, i))) => {
                hits += 1;
                assert!((h.t as f64 - t).abs() <= 1e-4 * t, "{h:?} vs {t}");
                if (h.t as f64 - t).abs() <= 1e-6 * t {
                    assert_eq!((h.instance_id, h.primitive_index), (id, i as u32));
                }
            }
            (None, None) => {}
            (g, w) => {
                // Only at a silhouette (checked loosely: the two must be near-tangent).
                let (id, i) = match (g, w) {
                    (Some(h), _) => (h.instance_id, h.primitive_index as usize),
                    (_, Some((_, id, i))) => (id, i),
                    _ => unreachable!(),
                };
                let w2o = transforms[(id - 10) as usize].inverse().unwrap();
                let s = cloud.sphere(i);
                let g = grazing(&s, w2o.transform_point(o), w2o.transform_vector(d));
                assert!(g < 1e-3, "{ray:?}: {g}");
            }
        }
    }
    assert!(hits > 200, "{hits}");
}

/// Facts of the structure: memory, kind and the serialization round trip with identical hits
/// (the corruption fuzzer for spheres is in `accel_serialize.rs`).
#[test]
fn a_sphere_gas_saves_and_loads_with_identical_hits() {
    let mut rng = Rng::new(0x5a);
    let cloud = Cloud::random(&mut rng, 500, 3.0, 0.05, 0.3);
    for flags in [BuildFlags::empty(), BuildFlags::ALLOW_UPDATE] {
        let gas = build(&cloud, flags);
        assert_eq!(gas.kind(), oxray_core::BuildInputKind::Spheres);
        assert_eq!(gas.data().spheres.len(), 500);
        let bytes = gas.data().to_bytes();
        let back = Gas::from(GasData::from_bytes(&bytes).unwrap());
        assert_eq!(back.to_bytes(), bytes);
        for _ in 0..1000 {
            let o = rng.vec3(-5.0, 5.0);
            let ray = Ray::new(o, rng.vec3(-2.0, 2.0) - o);
            assert_eq!(
                hit_bits(&gas.intersect(&ray)),
                hit_bits(&back.intersect(&ray))
            );
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The pipeline, with Rust programs
// ---------------------------------------------------------------------------------------------

/// Per ray: origin, direction, flags and what the any-hit program does (0: accept; 1: ignore
/// sphere 0; 2: terminate the ray).
type TestRay = (Vec3, Vec3, RayFlags, u32);

#[derive(Clone)]
struct Params {
    handle: TraversableHandle,
    rays: Vec<TestRay>,
    out: std::sync::Arc<OutputBuffer<[u32; 8]>>,
}

const MISS: u32 = 0xDEAD;

fn sphere_pipeline(compile: PipelineCompileOptions) -> (Pipeline<Params>, ShaderBindingTable) {
    let module = Module::<Params>::new()
        .raygen("__raygen__rg", |ctx| {
            let [x, _, _] = ctx.launch_index();
            let p = ctx.params();
            let (o, d, flags, mode) = p.rays[x as usize];
            let mut payload = [0, 0, 0, 0, 0, 0, mode, 0];
            ctx.trace(&TraceRay::new(&p.handle, o, d).flags(flags), &mut payload)?;
            p.out.write(x as usize, payload);
            Ok(())
        })
        .unwrap()
        .any_hit("__anyhit__ah", |ctx| {
            let mode = ctx.payload(6);
            let n = ctx.payload(7) + 1;
            ctx.set_payload(7, n);
            if mode == 1 && ctx.primitive_index() == 0 {
                return ctx.ignore_intersection();
            }
            if mode == 2 {
                return ctx.terminate_ray();
            }
            Ok(())
        })
        .unwrap()
        .closest_hit("__closesthit__ch", |ctx| {
            let s = ctx.sphere_data();
            ctx.set_payload(0, ctx.primitive_index());
            ctx.set_payload_f32(1, ctx.ray_tmax());
            ctx.set_payload(2, ctx.hit_kind().0 as u32);
            ctx.set_payload(3, ctx.primitive_type().code());
            ctx.set_payload(
                4,
                ctx.is_front_face_hit() as u32 | (ctx.is_back_face_hit() as u32) << 1,
            );
            ctx.set_payload_f32(5, s[2]);
            ctx.set_payload_f32(6, s[3]);
            Ok(())
        })
        .unwrap()
        .miss("__miss__ms", |ctx| {
            ctx.set_payload(0, MISS);
            Ok(())
        })
        .unwrap();
    let rg = ProgramGroup::raygen(&module, "__raygen__rg").unwrap();
    let ms = ProgramGroup::miss(Some((&module, "__miss__ms"))).unwrap();
    let hg = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__ch")),
        any_hit: Some((&module, "__anyhit__ah")),
        ..Default::default()
    })
    .unwrap();
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &compile,
        &PipelineLinkOptions { max_trace_depth: 1 },
        &[rg.clone(), ms.clone(), hg.clone()],
    )
    .unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_headers(&[ms.pack_header()]),
        hitgroup: SbtRegion::from_headers(&[hg.pack_header(), hg.pack_header()]),
        ..Default::default()
    };
    (pipeline, sbt)
}

/// Three spheres along +z (z = 5, 10, 15, radius 1); sphere 1 uses record 1, whose geometry
/// flags disable any-hit.
fn three_spheres() -> Gas {
    let centres = [[0.0f32, 0.0, 5.0], [0.0, 0.0, 10.0], [0.0, 0.0, 15.0]];
    let radius = [1.0f32];
    let c = [bytemuck::cast_slice::<_, u8>(&centres)];
    let r = [bytemuck::cast_slice::<_, u8>(&radius)];
    let flags = [GeometryFlags::empty(), GeometryFlags::DISABLE_ANYHIT];
    let offsets = [0u8, 1, 0];
    let input = SphereInput::new(&c, 3, &r)
        .single_radius(true)
        .flags(&flags)
        .sbt_index_offsets(SbtIndexOffsets::u8(&offsets));
    Gas::build(&BuildOptions::default(), &[input.into()]).unwrap()
}

fn sphere_compile() -> PipelineCompileOptions {
    PipelineCompileOptions {
        uses_primitive_type_flags: PrimitiveTypeFlags::SPHERE,
        ..Default::default()
    }
}

/// §9.4, §13.2, §13.7: closest-hit, any-hit (ignore, terminate) and miss programs on spheres;
/// the hit kind, primitive type, facing and sphere data a closest-hit program reads; the ray
/// flags that apply to spheres (any-hit culling) and those that do not (triangle face
/// culling).
#[test]
fn s13_7_sphere_hits_through_the_pipeline() {
    let (pipeline, sbt) = sphere_pipeline(sphere_compile());
    let gas: TraversableHandle = three_spheres().into();
    let z = Vec3::Z;
    let none = RayFlags::empty();
    let rays = vec![
        // 0: any-hit ignores sphere 0; sphere 1 (any-hit disabled) is the closest hit.
        (Vec3::ZERO, z, none, 1),
        // 1: from inside sphere 1: sphere 2 at t = 4 (§9.6).
        (Vec3::new(0.0, 0.0, 10.0), z, none, 0),
        // 2: a miss.
        (Vec3::new(5.0, 0.0, 0.0), z, none, 0),
        // 3: the triangle culling flags do not apply to spheres.
        (
            Vec3::new(0.0, 0.0, 10.0),
            z,
            RayFlags::CULL_FRONT_FACING_TRIANGLES,
            0,
        ),
        // 4: CULL_ENFORCED_ANYHIT removes sphere 0 (any-hit on) ahead of a ray leaving
        // sphere 1 backwards.
        (
            Vec3::new(0.0, 0.0, 10.0),
            -z,
            RayFlags::CULL_ENFORCED_ANYHIT,
            0,
        ),
        // 5: CULL_DISABLED_ANYHIT removes sphere 1 (any-hit off): sphere 0 at t = 6.
        (
            Vec3::new(0.0, 0.0, 12.0),
            -z,
            RayFlags::CULL_DISABLED_ANYHIT,
            0,
        ),
        // 6: any-hit terminates the ray at the first sphere it sees with any-hit on (0 or 2,
        // whichever the leaf offers first), whose hit the closest-hit program gets.
        (Vec3::ZERO, z, none, 2),
    ];
    let n = rays.len() as u32;
    let out = std::sync::Arc::new(OutputBuffer::new(rays.len()));
    let params = Params {
        handle: gas,
        rays,
        out: out.clone(),
    };
    let report = pipeline.launch(&params, &sbt, n, 1, 1).unwrap();
    assert_eq!(report.exceptions, 0, "{report:?}");
    let o = out.to_vec();
    let sphere = PrimitiveType::Sphere.code();
    // Ray 0: any-hit ran on sphere 0 and ignored it; sphere 1 has no any-hit.
    assert_eq!(o[0][..5], [1, 9f32.to_bits(), 0x8C, sphere, 1]);
    assert_eq!(
        (f32::from_bits(o[0][5]), f32::from_bits(o[0][6])),
        (10.0, 1.0)
    );
    assert!(o[0][7] >= 1, "any-hit ran");
    assert_eq!(o[1][..2], [2, 4f32.to_bits()]);
    assert_eq!(o[2][0], MISS);
    assert_eq!(o[3][..2], [2, 4f32.to_bits()]);
    assert_eq!(o[4][0], MISS);
    assert_eq!(o[5][..2], [0, 6f32.to_bits()]);
    match o[6][0] {
        0 => assert_eq!(o[6][1], 4f32.to_bits()),
        2 => assert_eq!(o[6][1], 14f32.to_bits()),
        other => panic!("terminated on sphere {other}"),
    }
    assert_eq!(o[6][7], 1, "one any-hit call: it terminated the ray");
}

/// §9.1: spheres must be enabled in `usesPrimitiveTypeFlags`; the default (0: triangles and
/// custom primitives) does not include them, and a pipeline with only SPHERE cannot trace
/// triangles. Either raises OPTIX_EXCEPTION_CODE_UNSUPPORTED_PRIMITIVE_TYPE.
#[test]
fn s9_1_spheres_need_their_primitive_type_flag() {
    let v = [[-1.0f32, -1.0, 3.0], [1.0, -1.0, 3.0], [0.0, 1.0, 3.0]];
    let tri: TraversableHandle = Gas::build(
        &BuildOptions::default(),
        &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()],
    )
    .unwrap()
    .into();
    let spheres: TraversableHandle = three_spheres().into();
    for (flags, handle, raises) in [
        (PrimitiveTypeFlags::empty(), &spheres, true),
        (PrimitiveTypeFlags::SPHERE, &spheres, false),
        (PrimitiveTypeFlags::SPHERE, &tri, true),
        (
            PrimitiveTypeFlags::SPHERE | PrimitiveTypeFlags::TRIANGLE,
            &tri,
            false,
        ),
    ] {
        let (pipeline, sbt) = sphere_pipeline(PipelineCompileOptions {
            uses_primitive_type_flags: flags,
            ..Default::default()
        });
        let params = Params {
            handle: handle.clone(),
            rays: vec![(Vec3::ZERO, Vec3::Z, RayFlags::empty(), 0)],
            out: std::sync::Arc::new(OutputBuffer::new(1)),
        };
        let report = pipeline.launch(&params, &sbt, 1, 1, 1).unwrap();
        assert_eq!(report.exceptions > 0, raises, "{flags:?}");
        if raises {
            assert_eq!(
                report.first_exceptions[0].1.code,
                ExceptionCode::UNSUPPORTED_PRIMITIVE_TYPE
            );
        }
    }
}

/// §9.4, §13.7 with a CUDA C++ program run on the CPU backend: `optixGetSphereData`,
/// `optixGetPrimitiveType`, `optixGetHitKind`, `optixIsFrontFaceHit`, through an instance.
#[cfg(unix)]
#[test]
fn s9_4_a_cuda_cpp_program_reads_the_sphere() {
    use oxray_cpu::cxx::{CxxHitGroupDesc, CxxModule, CxxPipeline, CxxProgramGroup, HostBuffer};
    const SRC: &str = r#"
#include <optix.h>
struct Params { float* out; OptixTraversableHandle handle; };
extern "C" __constant__ Params params;
extern "C" __global__ void __raygen__main() {
    const uint3 i = optixGetLaunchIndex();
    unsigned int p[8] = {0, 0, 0, 0, 0, 0, 0, 0};
    optixTrace(params.handle, make_float3(0.0f, 0.0f, 0.0f), make_float3(0.0f, 0.0f, 1.0f),
               0.0f, 100.0f, 0.0f, 255u, 0u, 0u, 1u, 0u,
               p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7]);
    for (int k = 0; k < 8; ++k) params.out[8 * i.x + k] = __uint_as_float(p[k]);
}
extern "C" __global__ void __closesthit__ch() {
    float4 s[1];
    optixGetSphereData(s);
    optixSetPayload_0(__float_as_uint(s[0].x));
    optixSetPayload_1(__float_as_uint(s[0].y));
    optixSetPayload_2(__float_as_uint(s[0].z));
    optixSetPayload_3(__float_as_uint(s[0].w));
    optixSetPayload_4(__float_as_uint(optixGetRayTmax()));
    optixSetPayload_5(__float_as_uint(
        optixGetPrimitiveType() == OPTIX_PRIMITIVE_TYPE_SPHERE ? 1.0f : 0.0f));
    optixSetPayload_6(__float_as_uint((float)optixGetHitKind()));
    optixSetPayload_7(__float_as_uint(
        (optixIsFrontFaceHit() ? 1.0f : 0.0f) + (optixIsBackFaceHit() ? 2.0f : 0.0f)
        + (optixIsTriangleHit() ? 4.0f : 0.0f)));
}
extern "C" __global__ void __miss__ms() { optixSetPayload_0(__float_as_uint(-1.0f)); }
"#;
    let module = CxxModule::from_source(SRC);
    let rg = CxxProgramGroup::raygen(&module, "__raygen__main").unwrap();
    let ms = CxxProgramGroup::miss(Some((&module, "__miss__ms"))).unwrap();
    let hg = CxxProgramGroup::hit_group(CxxHitGroupDesc {
        closest_hit: Some((&module, "__closesthit__ch")),
        ..Default::default()
    })
    .unwrap();
    let compile = PipelineCompileOptions {
        uses_primitive_type_flags: PrimitiveTypeFlags::SPHERE,
        ..sphere_compile()
    };
    let pipeline = CxxPipeline::new(
        &DeviceContext::default(),
        &compile,
        &PipelineLinkOptions::default(),
        Some("params"),
        &[rg.clone(), ms.clone(), hg.clone()],
    )
    .unwrap();
    // The spheres under an instance that moves them by 1 along z: object-space data, world t.
    let gas: TraversableHandle = three_spheres().into();
    let inst = [Instance::new(gas).transform(Transform::from_translation(Vec3::Z))];
    let ias: TraversableHandle = Ias::build(&BuildOptions::default(), &[(&inst[..]).into()])
        .unwrap()
        .into();
    let out = HostBuffer::<f32>::zeroed(8);
    #[repr(C)]
    #[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
    struct CParams {
        out: u64,
        handle: u64,
    }
    let params = CParams {
        out: out.device_ptr(),
        handle: oxray_cpu::cxx::optix_handle(&ias),
    };
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_headers(&[ms.pack_header()]),
        hitgroup: SbtRegion::from_headers(&[hg.pack_header(), hg.pack_header()]),
        ..Default::default()
    };
    let report = pipeline.launch_with(&params, &sbt, 1, 1, 1).unwrap();
    assert_eq!(report.exceptions, 0, "{report:?}");
    let o = out.download();
    assert_eq!(o, [0.0, 0.0, 5.0, 1.0, 5.0, 1.0, 140.0, 1.0]);
}
