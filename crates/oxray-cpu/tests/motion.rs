//! Motion blur on the CPU backend (guide §5.10): GASes with vertex, box and sphere motion and
//! motion transforms (matrix and SRT) against brute force at random ray times, the boundary
//! behaviour (clamping, vanish flags), motionless motion structures against static ones, the
//! rules on motion options and key buffers, saving and loading, and determinism.
//!
//! The brute-force references interpolate the geometry here, with the guide's rule (keys evenly
//! spaced over `[timeBegin, timeEnd]`, linear between the two neighbouring keys, time clamped),
//! then intersect the interpolated geometry with the existing references.

use glam::Vec3;
use oxray_bvh::{GasData, Sphere};
use oxray_core::{
    Aabb, AabbBuffer, BufferKind, BuildError, BuildFlags, BuildOptions, CustomHit, CustomPrimitive,
    CustomPrimitiveInput, Instance, InstanceFlags, MatrixMotionTransform, MotionFlags,
    MotionOptions, Ray, SphereInput, SrtData, SrtMotionTransform, Transform, TraversableHandle,
    TriangleInput, VertexBuffer,
};
use oxray_cpu::{Gas, Ias, Isa};
use oxray_testkit::mesh::random_soup;
use oxray_testkit::oracle::{check_closest, hit_bits, reference_hits};
use oxray_testkit::rng::Rng;
use oxray_testkit::Tri;

/// Every kernel this processor runs.
fn kernels() -> Vec<Isa> {
    Isa::available()
}

/// The keys and fraction of `time` under `m`, computed here from the guide's rule (not with
/// the engine's `MotionOptions::sample`): `None` where a vanish flag hides the structure.
fn keys_at(m: &MotionOptions, time: f32) -> Option<(usize, usize, f32)> {
    let n = m.num_keys as usize;
    if n <= 1 {
        return Some((0, 0, 0.0));
    }
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

fn mix(a: f32, b: f32, f: f32) -> f32 {
    a + (b - a) * f
}

fn mix_tri(a: &Tri, b: &Tri, f: f32) -> Tri {
    if f == 0.0 {
        return *a;
    }
    std::array::from_fn(|v| std::array::from_fn(|c| mix(a[v][c], b[v][c], f)))
}

/// A soup at key 0 and `keys - 1` moved copies (each vertex displaced by up to `amount`).
fn moving_soup(rng: &mut Rng, n: usize, keys: usize, amount: f32) -> Vec<Vec<Tri>> {
    let base = random_soup(rng, n, 10.0, 1.5);
    let mut out = vec![base.clone()];
    for _ in 1..keys {
        let prev = out.last().unwrap().clone();
        let moved = prev
            .iter()
            .map(|t| {
                let d = rng.vec3(-amount, amount);
                t.map(|p| (Vec3::from(p) + d + rng.vec3(-0.2, 0.2)).to_array())
            })
            .collect();
        out.push(moved);
    }
    out
}

fn flat(tris: &[Tri]) -> Vec<[f32; 3]> {
    tris.iter().flatten().copied().collect()
}

fn motion_triangle_gas(isa: Isa, keys: &[Vec<Tri>], m: MotionOptions, flags: BuildFlags) -> Gas {
    let verts: Vec<Vec<[f32; 3]>> = keys.iter().map(|k| flat(k)).collect();
    let later: Vec<VertexBuffer<'_>> = verts[1..].iter().map(|v| VertexBuffer::f32x3(v)).collect();
    let input = TriangleInput::new(VertexBuffer::f32x3(&verts[0])).motion_vertices(&later);
    let options = BuildOptions::new(flags).with_motion(m);
    Gas::build_with_isa(isa, &options, &[input.into()]).unwrap()
}

fn random_ray(rng: &mut Rng, t0: f32, t1: f32) -> Ray {
    let o = rng.vec3(-16.0, 16.0);
    let target = rng.vec3(-9.0, 9.0);
    Ray::new(o, target - o).with_time(rng.range(t0, t1))
}

#[test]
fn s5_10_2_motion_triangles_match_brute_force_at_random_times() {
    let mut rng = Rng::new(510);
    let m = MotionOptions::new(3, -1.0, 1.5);
    let keys = moving_soup(&mut rng, 300, 3, 2.0);
    for isa in kernels() {
        for flags in [BuildFlags::empty(), BuildFlags::PREFER_FAST_TRACE] {
            let gas = motion_triangle_gas(isa, &keys, m, flags);
            let mut hits = 0;
            for _ in 0..1500 {
                // Times beyond the range too: they are clamped.
                let ray = random_ray(&mut rng, -2.0, 2.5);
                let (k, n, f) = keys_at(&m, ray.time).unwrap();
                let tris: Vec<Tri> = (0..keys[0].len())
                    .map(|i| mix_tri(&keys[k][i], &keys[n][i], f))
                    .collect();
                let got = gas.intersect(&ray);
                hits += got.is_some() as usize;
                check_closest(got, &tris, &ray).unwrap_or_else(|e| panic!("{isa}: {e}"));
                assert_eq!(
                    gas.occluded(&ray),
                    !reference_hits(&tris, &ray).is_empty(),
                    "{isa}"
                );
            }
            assert!(hits > 300, "{hits} hits: the scene should be hit often");
        }
    }
}

/// Boxes at two keys, per primitive, and the entry distance into a box (the custom primitive's
/// shape is its box).
fn slab_entry(b: &Aabb, ray: &Ray) -> Option<f32> {
    let (mut t0, mut t1) = (ray.tmin, ray.tmax);
    for a in 0..3 {
        let inv = 1.0 / ray.direction[a];
        let (n, f) = (
            (b.min[a] - ray.origin[a]) * inv,
            (b.max[a] - ray.origin[a]) * inv,
        );
        t0 = t0.max(n.min(f));
        t1 = t1.min(n.max(f));
    }
    (t0 <= t1).then_some(t0)
}

fn box_hit(p: &CustomPrimitive, ray: &Ray) -> Option<CustomHit> {
    slab_entry(&p.aabb, ray).map(|t| CustomHit {
        t,
        hit_kind: 0,
        u: 0.0,
        v: 0.0,
    })
}

fn mix_box(a: &Aabb, b: &Aabb, f: f32) -> Aabb {
    if f == 0.0 {
        return *a;
    }
    Aabb::new(
        Vec3::from_array(std::array::from_fn(|i| mix(a.min[i], b.min[i], f))),
        Vec3::from_array(std::array::from_fn(|i| mix(a.max[i], b.max[i], f))),
    )
}

#[test]
fn s5_10_1_motion_aabbs_are_interpolated_and_match_brute_force() {
    let mut rng = Rng::new(5101);
    let m = MotionOptions::new(2, 0.0, 1.0);
    let n = 200;
    let k0: Vec<Aabb> = (0..n)
        .map(|_| {
            let c = rng.vec3(-10.0, 10.0);
            let h = rng.vec3(0.2, 1.0);
            Aabb::new(c - h, c + h)
        })
        .collect();
    let k1: Vec<Aabb> = k0
        .iter()
        .map(|b| {
            let d = rng.vec3(-3.0, 3.0);
            Aabb::new(b.min + d, b.max + d)
        })
        .collect();
    let later = [AabbBuffer::new(&k1)];
    let input = CustomPrimitiveInput::new(AabbBuffer::new(&k0)).motion_aabbs(&later);
    for isa in kernels() {
        let gas = Gas::build_with_isa(
            isa,
            &BuildOptions::default().with_motion(m),
            &[input.into()],
        )
        .unwrap();
        let mut hits = 0;
        for _ in 0..1500 {
            let ray = random_ray(&mut rng, -0.5, 1.5);
            let (a, b, f) = keys_at(&m, ray.time).unwrap();
            let keys = [&k0, &k1];
            let want = (0..n)
                .filter_map(|i| {
                    let bx = mix_box(&keys[a][i], &keys[b][i], f);
                    slab_entry(&bx, &ray).map(|t| (t, i))
                })
                .min_by(|x, y| x.0.total_cmp(&y.0));
            let got = gas.intersect_with(&ray, &mut box_hit);
            match (got, want) {
                (None, None) => {}
                (Some(g), Some((t, _))) => {
                    hits += 1;
                    assert_eq!(g.t.to_bits(), t.to_bits(), "{isa}");
                    // Ties aside, the primitive is the one the reference found at that t.
                    let bx = mix_box(
                        &keys[a][g.primitive_index as usize],
                        &keys[b][g.primitive_index as usize],
                        f,
                    );
                    assert_eq!(slab_entry(&bx, &ray), Some(t), "{isa}");
                }
                (g, w) => panic!("{isa}: got {g:?}, want {w:?}"),
            }
        }
        assert!(hits > 200, "{hits}");
    }
}

#[test]
fn s5_10_2_motion_spheres_match_brute_force() {
    let mut rng = Rng::new(5102);
    let m = MotionOptions::new(3, 2.0, 4.0);
    let n = 150;
    let centres: Vec<Vec<[f32; 3]>> = {
        let c0: Vec<[f32; 3]> = (0..n).map(|_| rng.vec3(-10.0, 10.0).to_array()).collect();
        let mut all = vec![c0];
        for _ in 1..3 {
            let prev = all.last().unwrap();
            let next = prev
                .iter()
                .map(|c| (Vec3::from(*c) + rng.vec3(-2.0, 2.0)).to_array())
                .collect();
            all.push(next);
        }
        all
    };
    let radii: Vec<Vec<f32>> = (0..3)
        .map(|_| (0..n).map(|_| rng.range(0.2, 1.2)).collect())
        .collect();
    let cb: Vec<&[u8]> = centres.iter().map(|c| bytemuck::cast_slice(c)).collect();
    let rb: Vec<&[u8]> = radii.iter().map(|r| bytemuck::cast_slice(r)).collect();
    let input = SphereInput::new(&cb, n as u32, &rb);
    let gas = Gas::build(&BuildOptions::default().with_motion(m), &[input.into()]).unwrap();
    let mut hits = 0;
    for _ in 0..1500 {
        let ray = random_ray(&mut rng, 1.5, 4.5);
        let (a, b, f) = keys_at(&m, ray.time).unwrap();
        let want = (0..n)
            .filter_map(|i| {
                let s = if f == 0.0 {
                    Sphere::new(Vec3::from(centres[a][i]), radii[a][i])
                } else {
                    Sphere::new(
                        Vec3::from_array(std::array::from_fn(|c| {
                            mix(centres[a][i][c], centres[b][i][c], f)
                        })),
                        mix(radii[a][i], radii[b][i], f),
                    )
                };
                s.intersect(ray.origin, ray.direction, ray.tmin, ray.tmax)
                    .map(|t| (t, i))
            })
            .min_by(|x, y| x.0.total_cmp(&y.0));
        let got = gas.intersect(&ray);
        assert_eq!(got.map(|h| h.t.to_bits()), want.map(|w| w.0.to_bits()));
        if let (Some(g), Some(w)) = (got, want) {
            hits += 1;
            assert_eq!(g.primitive_index as usize, w.1);
        }
    }
    assert!(hits > 100, "{hits}");
}

/// A GAS over one soup, static.
fn static_gas(isa: Isa, tris: &[Tri]) -> Gas {
    let v = flat(tris);
    let input = TriangleInput::new(VertexBuffer::f32x3(&v));
    Gas::build_with_isa(isa, &BuildOptions::default(), &[input.into()]).unwrap()
}

#[test]
fn s5_10_2_a_motionless_motion_gas_hits_bit_for_bit_like_the_static_one() {
    let mut rng = Rng::new(5103);
    let tris = random_soup(&mut rng, 400, 10.0, 1.5);
    let keys = vec![tris.clone(); 4];
    let m = MotionOptions::new(4, 0.0, 1.0);
    for isa in kernels() {
        let moving = motion_triangle_gas(isa, &keys, m, BuildFlags::empty());
        let fixed = static_gas(isa, &tris);
        for _ in 0..2000 {
            let ray = random_ray(&mut rng, -0.5, 1.5);
            assert_eq!(
                hit_bits(&moving.intersect(&ray)),
                hit_bits(&fixed.intersect(&ray)),
                "{isa}"
            );
        }
    }
    // Spheres and boxes too.
    let c: Vec<[f32; 3]> = (0..50).map(|_| rng.vec3(-8.0, 8.0).to_array()).collect();
    let r: Vec<f32> = (0..50).map(|_| rng.range(0.3, 1.0)).collect();
    let (cb, rb) = (
        [bytemuck::cast_slice::<_, u8>(&c)],
        [bytemuck::cast_slice::<_, u8>(&r)],
    );
    let (cb2, rb2) = ([cb[0], cb[0]], [rb[0], rb[0]]);
    let fixed = Gas::build(
        &BuildOptions::default(),
        &[SphereInput::new(&cb, 50, &rb).into()],
    )
    .unwrap();
    let m2 = MotionOptions::new(2, 0.0, 1.0);
    let moving = Gas::build(
        &BuildOptions::default().with_motion(m2),
        &[SphereInput::new(&cb2, 50, &rb2).into()],
    )
    .unwrap();
    let boxes: Vec<Aabb> = c
        .iter()
        .zip(&r)
        .map(|(c, r)| Aabb::new(Vec3::from(*c) - *r, Vec3::from(*c) + *r))
        .collect();
    let later = [AabbBuffer::new(&boxes)];
    let fixed_boxes = Gas::build(
        &BuildOptions::default(),
        &[CustomPrimitiveInput::new(AabbBuffer::new(&boxes)).into()],
    )
    .unwrap();
    let moving_boxes = Gas::build(
        &BuildOptions::default().with_motion(m2),
        &[CustomPrimitiveInput::new(AabbBuffer::new(&boxes))
            .motion_aabbs(&later)
            .into()],
    )
    .unwrap();
    for _ in 0..2000 {
        let ray = random_ray(&mut rng, -0.5, 1.5);
        assert_eq!(
            hit_bits(&moving.intersect(&ray)),
            hit_bits(&fixed.intersect(&ray))
        );
        assert_eq!(
            hit_bits(&moving_boxes.intersect_with(&ray, &mut box_hit)),
            hit_bits(&fixed_boxes.intersect_with(&ray, &mut box_hit))
        );
    }
}

/// One triangle facing -z at z = 0 that moves from x = 0 (key 0) to x = 10 (key 1).
fn sliding_triangle(m: MotionOptions) -> Gas {
    let k0 = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
    let k1 = k0.map(|p| [p[0] + 10.0, p[1], p[2]]);
    let later = [VertexBuffer::f32x3(&k1)];
    let input = TriangleInput::new(VertexBuffer::f32x3(&k0)).motion_vertices(&later);
    Gas::build(&BuildOptions::default().with_motion(m), &[input.into()]).unwrap()
}

fn down_at(x: f32, time: f32) -> Ray {
    Ray::new(Vec3::new(x, 0.0, -5.0), Vec3::Z).with_time(time)
}

#[test]
fn s5_10_1_time_outside_the_range_is_clamped() {
    let gas = sliding_triangle(MotionOptions::new(2, 1.0, 2.0));
    // Half-way the triangle is at x = 5.
    assert!(gas.intersect(&down_at(5.0, 1.5)).is_some());
    assert!(gas.intersect(&down_at(0.0, 1.5)).is_none());
    // Before the range it stays at key 0, after it at key 1, bit for bit.
    for (x, early, edge) in [(0.0, -7.0, 1.0), (10.0, 9.0, 2.0)] {
        let a = gas.intersect(&down_at(x, early));
        let b = gas.intersect(&down_at(x, edge));
        assert!(a.is_some());
        assert_eq!(hit_bits(&a), hit_bits(&b));
    }
}

#[test]
fn s5_10_1_vanish_flags_remove_the_structure_outside_its_range() {
    let start =
        sliding_triangle(MotionOptions::new(2, 1.0, 2.0).with_flags(MotionFlags::START_VANISH));
    assert!(start.intersect(&down_at(0.0, 0.999)).is_none());
    assert!(start.intersect(&down_at(0.0, 1.0)).is_some());
    assert!(start.intersect(&down_at(10.0, 3.0)).is_some(), "end clamps");
    let end = sliding_triangle(MotionOptions::new(2, 1.0, 2.0).with_flags(MotionFlags::END_VANISH));
    assert!(end.intersect(&down_at(10.0, 2.001)).is_none());
    assert!(end.intersect(&down_at(10.0, 2.0)).is_some());
    assert!(end.intersect(&down_at(0.0, -3.0)).is_some(), "start clamps");
}

#[test]
fn s5_10_3_a_motion_ias_with_vanish_flags_hides_even_static_children() {
    let tri = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
    let gas: TraversableHandle = Gas::build(
        &BuildOptions::default(),
        &[TriangleInput::new(VertexBuffer::f32x3(&tri)).into()],
    )
    .unwrap()
    .into();
    let inst = [Instance::new(gas)];
    let m = MotionOptions::new(2, 0.0, 1.0).with_flags(MotionFlags::all());
    let ias = Ias::build(
        &BuildOptions::default().with_motion(m),
        &[(&inst[..]).into()],
    )
    .unwrap();
    assert!(ias.intersect(&down_at(0.0, 0.5)).is_some());
    assert!(ias.intersect(&down_at(0.0, -0.1)).is_none());
    assert!(ias.intersect(&down_at(0.0, 1.1)).is_none());
    // Without flags the IAS's motion changes nothing (§5.10.3).
    let plain = Ias::build(
        &BuildOptions::default().with_motion(MotionOptions::new(3, 0.0, 1.0)),
        &[(&inst[..]).into()],
    )
    .unwrap();
    for t in [-5.0, 0.3, 7.0] {
        assert!(plain.intersect(&down_at(0.0, t)).is_some());
    }
}

/// A transform chain of the test: matrix or SRT keys with their options.
#[derive(Clone)]
enum Chain {
    Matrix(MotionOptions, Vec<Transform>),
    Srt(MotionOptions, Vec<SrtData>),
}

impl Chain {
    fn handle(&self, child: TraversableHandle) -> TraversableHandle {
        match self {
            Chain::Matrix(m, k) => MatrixMotionTransform::new(child, *m, k).unwrap().into(),
            Chain::Srt(m, k) => SrtMotionTransform::new(child, *m, k).unwrap().into(),
        }
    }

    /// The object-to-world transform at `time`, from the guide's definitions: element-wise
    /// lerp of matrices; for SRT, lerp of the 16 components, quaternion normalised, T·R·S
    /// (composed here with glam).
    fn at(&self, time: f32) -> Option<glam::Affine3A> {
        match self {
            Chain::Matrix(m, k) => {
                let (a, b, f) = keys_at(m, time)?;
                let t = Transform(std::array::from_fn(|i| mix(k[a].0[i], k[b].0[i], f)));
                Some(t.to_affine())
            }
            Chain::Srt(m, k) => {
                let (a, b, f) = keys_at(m, time)?;
                let (x, y): (&[f32; 16], &[f32; 16]) =
                    (bytemuck::cast_ref(&k[a]), bytemuck::cast_ref(&k[b]));
                let s: [f32; 16] = std::array::from_fn(|i| mix(x[i], y[i], f));
                let scale = glam::Affine3A::from_cols_array(&[
                    s[0], 0.0, 0.0, s[1], s[4], 0.0, s[2], s[5], s[7], s[3], s[6], s[8],
                ]);
                let q = glam::Quat::from_xyzw(s[9], s[10], s[11], s[12]).normalize();
                let tr = glam::Affine3A::from_translation(Vec3::new(s[13], s[14], s[15]));
                Some(tr * glam::Affine3A::from_quat(q) * scale)
            }
        }
    }
}

fn random_chain(rng: &mut Rng) -> Chain {
    let n = 2 + rng.below(3);
    let m = MotionOptions::new(n as u16, rng.range(-1.0, 0.0), rng.range(0.5, 2.0));
    if rng.below(2) == 0 {
        Chain::Matrix(
            m,
            (0..n)
                .map(|_| Transform::from_affine(&rng.affine(4.0)))
                .collect(),
        )
    } else {
        // Neighbouring quaternions on the same hemisphere (§5.10.6), with shear and pivots.
        let mut q = rng.rotation();
        let keys = (0..n)
            .map(|_| {
                let step = rng.rotation();
                let next = (q * glam::Quat::from_axis_angle(step * Vec3::X, rng.range(0.1, 1.5)))
                    .normalize();
                q = if next.dot(q) < 0.0 { -next } else { next };
                SrtData {
                    sx: rng.range(0.5, 2.0),
                    a: rng.range(-0.3, 0.3),
                    b: rng.range(-0.3, 0.3),
                    pvx: rng.range(-1.0, 1.0),
                    sy: rng.range(0.5, 2.0),
                    c: rng.range(-0.3, 0.3),
                    pvy: rng.range(-1.0, 1.0),
                    sz: rng.range(0.5, 2.0),
                    pvz: rng.range(-1.0, 1.0),
                    qx: q.x * 1.7,
                    qy: q.y * 1.7,
                    qz: q.z * 1.7,
                    qw: q.w * 1.7,
                    tx: rng.range(-4.0, 4.0),
                    ty: rng.range(-4.0, 4.0),
                    tz: rng.range(-4.0, 4.0),
                }
            })
            .collect();
        Chain::Srt(m, keys)
    }
}

/// Closest hit by brute force on `tris` placed by `chains` (outermost first) under an
/// instance transform `inst`, at the ray's time: the ray goes into object space through the
/// inverse of the composed transform (computed in f64), and the distance found is compared
/// with a tolerance (the engine carries the ray level by level in f32).
fn reference_placed(
    tris: &[Tri],
    inst: &glam::Affine3A,
    chains: &[Chain],
    ray: &Ray,
) -> Option<(f32, u32)> {
    let mut o2w = glam::DAffine3::from_mat4(glam::Mat4::from(*inst).as_dmat4());
    for c in chains {
        let m = c.at(ray.time)?;
        o2w *= glam::DAffine3::from_mat4(glam::Mat4::from(m).as_dmat4());
    }
    let w2o = o2w.inverse();
    let o = w2o.transform_point3(ray.origin.as_dvec3()).as_vec3();
    let d = w2o.transform_vector3(ray.direction.as_dvec3()).as_vec3();
    let object_ray = Ray {
        origin: o,
        direction: d,
        ..*ray
    };
    oxray_testkit::oracle::reference_closest(tris, &object_ray).map(|h| (h.hit.t, h.prim))
}

#[test]
fn s5_10_4_s5_10_5_motion_transforms_in_an_ias_match_brute_force() {
    let mut rng = Rng::new(5104);
    let tris = random_soup(&mut rng, 60, 2.0, 0.8);
    let v = flat(&tris);
    let gas: TraversableHandle = Gas::build(
        &BuildOptions::default(),
        &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()],
    )
    .unwrap()
    .into();
    // Instances over one chain, two nested chains, and a chain over a static transform.
    let mut cases: Vec<(glam::Affine3A, Vec<Chain>)> = Vec::new();
    for depth in [1, 1, 2, 2, 3] {
        let chains: Vec<Chain> = (0..depth).map(|_| random_chain(&mut rng)).collect();
        cases.push((rng.affine(8.0), chains));
    }
    let instances: Vec<Instance> = cases
        .iter()
        .map(|(inst, chains)| {
            let mut h = gas.clone();
            for c in chains.iter().rev() {
                h = c.handle(h);
            }
            let mut i = Instance::new(h);
            i.transform = Transform::from_affine(inst);
            i.flags = InstanceFlags::DISABLE_TRIANGLE_FACE_CULLING;
            i
        })
        .collect();
    let ias = Ias::build(&BuildOptions::default(), &[(&instances[..]).into()]).unwrap();
    let (mut hits, mut compared) = (0, 0);
    for _ in 0..3000 {
        let o = rng.vec3(-25.0, 25.0);
        let ray = Ray::new(o, rng.vec3(-8.0, 8.0) - o).with_time(rng.range(-1.5, 2.5));
        let want = cases
            .iter()
            .filter_map(|(inst, chains)| reference_placed(&tris, inst, chains, &ray))
            .min_by(|a, b| a.0.total_cmp(&b.0));
        let got = ias.intersect(&ray);
        match (got, want) {
            (Some(g), Some((t, _))) => {
                hits += 1;
                assert!((g.t - t).abs() <= 1e-3 * t.abs().max(1.0), "{} vs {t}", g.t);
                compared += 1;
            }
            (None, None) => {}
            // A ray that grazes an edge may be decided differently by the f64 reference.
            (g, w) => {
                let near_edge = {
                    let probe = |dx: f32| {
                        let r = Ray {
                            direction: ray.direction + Vec3::splat(dx),
                            ..ray
                        };
                        ias.intersect(&r).is_some()
                    };
                    probe(1e-4) != probe(-1e-4) || probe(1e-4) != g.is_some()
                };
                assert!(near_edge, "got {g:?}, want {w:?} at time {}", ray.time);
            }
        }
    }
    assert!(hits > 100 && compared > 100, "{hits} hits");
}

#[test]
fn s5_10_1_a_matrix_motion_transform_vanishes_by_its_flags() {
    let tri = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
    let gas: TraversableHandle = Gas::build(
        &BuildOptions::default(),
        &[TriangleInput::new(VertexBuffer::f32x3(&tri)).into()],
    )
    .unwrap()
    .into();
    let keys = [
        Transform::IDENTITY,
        Transform::from_translation(Vec3::new(10.0, 0.0, 0.0)),
    ];
    let m = MotionOptions::new(2, 0.0, 1.0).with_flags(MotionFlags::START_VANISH);
    let t: TraversableHandle = MatrixMotionTransform::new(gas, m, &keys).unwrap().into();
    let ias = Ias::build(
        &BuildOptions::default(),
        &[(&[Instance::new(t)][..]).into()],
    )
    .unwrap();
    assert!(ias.intersect(&down_at(5.0, 0.5)).is_some());
    assert!(ias.intersect(&down_at(0.0, -0.5)).is_none(), "vanished");
    assert!(ias.intersect(&down_at(10.0, 3.0)).is_some(), "clamped");
    assert!(ias.intersect(&down_at(0.0, 0.5)).is_none());
}

#[test]
fn s5_10_2_one_buffer_per_motion_key_of_the_same_shape() {
    let k0 = [[0.0f32; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let k1 = [[0.0f32; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0; 3]];
    let m3 = BuildOptions::default().with_motion(MotionOptions::new(3, 0.0, 1.0));
    let later = [VertexBuffer::f32x3(&k0)];
    let input = TriangleInput::new(VertexBuffer::f32x3(&k0)).motion_vertices(&later);
    let err = Gas::build(&m3, &[input.into()]).unwrap_err();
    assert!(
        matches!(
            err,
            BuildError::MotionKeyCount {
                buffer: BufferKind::Vertices,
                given: 2,
                expected: 3,
                ..
            }
        ),
        "{err}"
    );
    // A static build takes no later keys.
    let err = Gas::build(&BuildOptions::default(), &[input.into()]).unwrap_err();
    assert!(matches!(
        err,
        BuildError::MotionKeyCount {
            given: 2,
            expected: 1,
            ..
        }
    ));
    // Every key describes the same vertices.
    let later = [VertexBuffer::f32x3(&k1)];
    let input = TriangleInput::new(VertexBuffer::f32x3(&k0)).motion_vertices(&later);
    let m2 = BuildOptions::default().with_motion(MotionOptions::new(2, 0.0, 1.0));
    let err = Gas::build(&m2, &[input.into()]).unwrap_err();
    assert_eq!(
        err,
        BuildError::MotionKeyMismatch {
            at: oxray_core::InputLocation { input: 0 },
            key: 1,
            buffer: BufferKind::Vertices
        }
    );
    // Boxes and spheres likewise.
    let b = [Aabb::new(Vec3::ZERO, Vec3::ONE)];
    let err = Gas::build(
        &m2,
        &[CustomPrimitiveInput::new(AabbBuffer::new(&b)).into()],
    )
    .unwrap_err();
    assert!(matches!(
        err,
        BuildError::MotionKeyCount {
            buffer: BufferKind::Aabbs,
            ..
        }
    ));
    let c = [bytemuck::cast_slice::<_, u8>(&k0[..1])];
    let r = [bytemuck::cast_slice::<_, u8>(&[1.0f32][..])];
    let err = Gas::build(&m2, &[SphereInput::new(&c, 1, &r).into()]).unwrap_err();
    assert!(matches!(
        err,
        BuildError::MotionKeyCount {
            given: 1,
            expected: 2,
            ..
        }
    ));
    // Invalid options are refused before anything else (§5.10.1).
    let bad = BuildOptions::default().with_motion(MotionOptions::new(2, 1.0, 0.0));
    let err = Gas::build(&bad, &[input.into()]).unwrap_err();
    assert!(matches!(err, BuildError::InvalidMotionOptions(_)), "{err}");
    let err = Ias::build(&bad, &[(&[][..] as &[Instance]).into()]).unwrap_err();
    assert!(matches!(err, BuildError::InvalidMotionOptions(_)), "{err}");
    // A motion GAS is not updatable here: a typed refusal.
    let later = [VertexBuffer::f32x3(&k0)];
    let input = TriangleInput::new(VertexBuffer::f32x3(&k0)).motion_vertices(&later);
    let up =
        BuildOptions::new(BuildFlags::ALLOW_UPDATE).with_motion(MotionOptions::new(2, 0.0, 1.0));
    assert!(matches!(
        Gas::build(&up, &[input.into()]),
        Err(BuildError::Unsupported(_))
    ));
}

#[test]
fn s5_10_2_motion_structures_save_and_load_with_identical_hits() {
    let mut rng = Rng::new(5105);
    let keys = moving_soup(&mut rng, 200, 3, 1.5);
    let m = MotionOptions::new(3, 0.0, 2.0).with_flags(MotionFlags::END_VANISH);
    for isa in kernels() {
        let gas = motion_triangle_gas(isa, &keys, m, BuildFlags::ALLOW_COMPACTION);
        let bytes = gas.data().to_bytes();
        let back = Gas::from_data_with_isa(GasData::from_bytes(&bytes).unwrap(), isa);
        let compact = Gas::from_data_with_isa(gas.data().compact().unwrap(), isa);
        assert_eq!(back.data().motion, gas.data().motion);
        for _ in 0..500 {
            let ray = random_ray(&mut rng, -0.5, 2.5);
            let want = hit_bits(&gas.intersect(&ray));
            assert_eq!(hit_bits(&back.intersect(&ray)), want);
            assert_eq!(hit_bits(&compact.intersect(&ray)), want);
        }
        // Damaged motion sections are refused: a later key's array one block short.
        let mut data = gas.data().clone();
        if let Some(motion) = data.motion.as_mut() {
            motion.triangles.pop();
        }
        assert!(GasData::from_bytes(&data.to_bytes()).is_err());
    }
    // An IAS keeps its motion options.
    let tri = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
    let g: TraversableHandle = Gas::build(
        &BuildOptions::default(),
        &[TriangleInput::new(VertexBuffer::f32x3(&tri)).into()],
    )
    .unwrap()
    .into();
    let inst = [Instance::new(g.clone())];
    let ias = Ias::build(
        &BuildOptions::default().with_motion(m),
        &[(&inst[..]).into()],
    )
    .unwrap();
    let back = oxray_bvh::IasData::from_bytes(&ias.data().to_bytes(), &[g]).unwrap();
    assert_eq!(back.motion, m);
}

#[test]
fn motion_traversal_is_deterministic_whatever_the_thread_count() {
    let mut rng = Rng::new(5106);
    let keys = moving_soup(&mut rng, 2000, 2, 3.0);
    let gas = motion_triangle_gas(
        Isa::selected(),
        &keys,
        MotionOptions::new(2, 0.0, 1.0),
        BuildFlags::empty(),
    );
    let rays: Vec<Ray> = (0..5000).map(|_| random_ray(&mut rng, 0.0, 1.0)).collect();
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let mut hits = vec![None; rays.len()];
                gas.intersect_batch(&rays, &mut hits).unwrap();
                hits.iter().map(hit_bits).collect::<Vec<_>>()
            })
    };
    let one = run(1);
    assert_eq!(one, run(4));
    assert!(one.iter().filter(|h| h.is_some()).count() > 500);
}

#[test]
fn s5_6_an_update_keeps_the_motion_options() {
    let tri = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
    let g: TraversableHandle = Gas::build(
        &BuildOptions::default(),
        &[TriangleInput::new(VertexBuffer::f32x3(&tri)).into()],
    )
    .unwrap()
    .into();
    let inst = [Instance::new(g)];
    let m = MotionOptions::new(2, 0.0, 1.0);
    let options = BuildOptions::new(BuildFlags::ALLOW_UPDATE).with_motion(m);
    let mut ias = Ias::build(&options, &[(&inst[..]).into()]).unwrap();
    let update = BuildOptions {
        operation: oxray_core::BuildOperation::Update,
        ..options
    };
    ias.update(&update, &[(&inst[..]).into()]).unwrap();
    let other = update.with_motion(MotionOptions::new(3, 0.0, 1.0));
    let err = ias.update(&other, &[(&inst[..]).into()]).unwrap_err();
    assert!(
        matches!(
            err,
            BuildError::InvalidUpdate(oxray_core::UpdateRule::Motion { .. })
        ),
        "{err}"
    );
    // A static updatable GAS cannot be updated into one with motion.
    let mut gas = Gas::build(
        &BuildOptions::new(BuildFlags::ALLOW_UPDATE),
        &[TriangleInput::new(VertexBuffer::f32x3(&tri)).into()],
    )
    .unwrap();
    let later = [VertexBuffer::f32x3(&tri)];
    let input = TriangleInput::new(VertexBuffer::f32x3(&tri)).motion_vertices(&later);
    let up = BuildOptions {
        operation: oxray_core::BuildOperation::Update,
        ..BuildOptions::new(BuildFlags::ALLOW_UPDATE).with_motion(m)
    };
    assert!(gas.update(&up, &[input.into()]).is_err());
}

/// §5.10.2 with the time range split in parts (`oxray_bvh::MotionSegments`): the parts'
/// boxes bound the moving triangles at every time of their part, so every ray at every time
/// finds exactly the hit of the one tree over the union of the key boxes; the number of parts
/// follows the key count, `PREFER_FAST_BUILD` makes none, and a saved structure loads with the
/// same parts.
#[test]
fn s5_10_2_time_parts_trace_the_hits_of_the_one_tree() {
    let mut rng = Rng::new(5102);
    for (keys, parts) in [(2usize, 8usize), (3, 8), (4, 6), (6, 5), (17, 16), (18, 0)] {
        let m = MotionOptions::new(keys as u16, 0.0, 1.0);
        let soup = moving_soup(&mut rng, 400, keys, 3.0);
        for isa in kernels() {
            let gas = motion_triangle_gas(isa, &soup, m, BuildFlags::empty());
            let data = gas.data();
            let made = data
                .motion
                .as_ref()
                .and_then(|m| m.segments.as_ref())
                .map_or(0, |s| s.len());
            assert_eq!(made, parts, "{keys} keys");
            // The memory query bounds the structure with its parts.
            let verts: Vec<Vec<[f32; 3]>> = soup.iter().map(|k| flat(k)).collect();
            let later: Vec<VertexBuffer<'_>> =
                verts[1..].iter().map(|v| VertexBuffer::f32x3(v)).collect();
            let input = TriangleInput::new(VertexBuffer::f32x3(&verts[0])).motion_vertices(&later);
            let sizes = oxray_bvh::compute_memory_usage(
                &BuildOptions::default().with_motion(m),
                &[input.into()],
            )
            .unwrap();
            assert!(
                data.memory().output_bytes <= sizes.output_size_in_bytes,
                "{keys} keys: {} > {}",
                data.memory().output_bytes,
                sizes.output_size_in_bytes
            );
            let mut one_tree = data.clone();
            if let Some(m) = &mut one_tree.motion {
                m.segments = None;
            }
            let one_tree = Gas::from_data_with_isa(one_tree, isa);
            let loaded =
                Gas::from_data_with_isa(GasData::from_bytes(&data.to_bytes()).unwrap(), isa);
            assert_eq!(
                loaded.data().motion,
                data.motion,
                "{keys} keys: the parts are made again on load"
            );
            let mut hits = 0;
            for k in 0..3000 {
                let mut ray = random_ray(&mut rng, -0.1, 1.1);
                // Times at the parts' ends and at the keys, where rounding could put a ray
                // across a boundary.
                if k % 3 == 0 {
                    let ends = (keys - 1) * 8;
                    ray.time = rng.below(ends + 1) as f32 / ends as f32;
                }
                let want = one_tree.intersect(&ray);
                hits += want.is_some() as usize;
                assert_eq!(
                    hit_bits(&gas.intersect(&ray)),
                    hit_bits(&want),
                    "{isa} {keys} keys: {ray:?}"
                );
                assert_eq!(gas.occluded(&ray), want.is_some(), "{isa} {keys} keys");
            }
            assert!(hits > 500, "{hits} hits");
        }
    }
    let fast = motion_triangle_gas(
        Isa::selected(),
        &moving_soup(&mut rng, 50, 2, 1.0),
        MotionOptions::new(2, 0.0, 1.0),
        BuildFlags::PREFER_FAST_BUILD,
    );
    assert!(fast.data().motion.as_ref().unwrap().segments.is_none());
}
