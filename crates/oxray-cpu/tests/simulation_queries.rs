//! The simulation queries (issue 19) on the CPU backend against brute-force references:
//! the one-call mesh constructor, hit points and normals (through instances, mirrored and
//! nested), all hits along a ray and hit counts (shared edges and vertices, spatial splits),
//! closest points (on vertices and edges too), signed distance and inside tests of closed
//! meshes, determinism of the batches, and bad input.

use glam::{Affine3A, DVec3, Vec3};
use oxray_core::{
    BuildFlags, BuildInputKind, BuildOptions, CustomPrimitiveInput, Hit, HitKind, Instance,
    InstanceFlags, Ray, RayError, SphereInput, Transform,
};
use oxray_cpu::{
    AllHits, ClosestPoint, Gas, Ias, MeshError, SurfaceHit, SurfaceQueryError, VertexNormals,
};
use oxray_testkit::mesh::{grid_cube, icosphere, random_soup, Mesh};
use oxray_testkit::oracle::reference_hits;
use oxray_testkit::rng::Rng;
use oxray_testkit::Tri;
use std::sync::Arc;

/// A triangle soup as an indexed mesh (no shared vertices).
fn soup_mesh(tris: &[Tri]) -> Mesh {
    Mesh {
        positions: tris.iter().flatten().copied().collect(),
        triangles: (0..tris.len() as u32)
            .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect(),
    }
}

/// The build presets a query must not care about: the default, spatial splits (a triangle in
/// several leaves) and an updatable structure.
fn presets() -> [BuildOptions; 3] {
    [
        BuildOptions::default(),
        BuildOptions::new(BuildFlags::PREFER_FAST_TRACE),
        BuildOptions::new(BuildFlags::ALLOW_UPDATE),
    ]
}

fn gas_of(m: &Mesh, options: &BuildOptions) -> Gas {
    Gas::from_mesh_with_options(options, &m.positions, &m.triangles).unwrap()
}

/// A random ray through the box `[0, extent]^3`, starting outside it.
fn random_ray(rng: &mut Rng, extent: f32) -> Ray {
    let target = rng.vec3(0.0, extent);
    let d = rng.unit();
    Ray::new(target - d * extent * 2.0, d)
}

/// `(t, primitive)` of the reference hits, sorted as the query sorts them.
fn reference_sorted(tris: &[Tri], ray: &Ray) -> Vec<(f32, u32)> {
    let mut r: Vec<(f32, u32)> = reference_hits(tris, ray)
        .iter()
        .map(|h| (h.hit.t, h.prim))
        .collect();
    r.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    r
}

// ---------------------------------------------------------------------------------------------
// The mesh constructor.

#[test]
fn from_mesh_builds_what_the_four_types_build_and_refuses_bad_indices() {
    let mut rng = Rng::new(1);
    let tris = random_soup(&mut rng, 200, 10.0, 1.0);
    let m = soup_mesh(&tris);
    let gas = Gas::from_mesh(&m.positions, &m.triangles).unwrap();
    assert_eq!(gas.num_primitives(), 200);
    assert_eq!(gas.data().kind(), BuildInputKind::Triangles);
    for _ in 0..200 {
        let ray = random_ray(&mut rng, 10.0);
        let want = reference_sorted(&tris, &ray).first().copied();
        let got = gas.intersect(&ray).map(|h| (h.t, h.primitive_index));
        assert_eq!(got.map(|g| g.0), want.map(|w| w.0));
    }

    let v = [[0.0f32; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    assert_eq!(
        Gas::from_mesh(&v, &[[0, 1, 2], [2, 7, 0]]).unwrap_err(),
        MeshError::IndexOutOfRange {
            triangle: 1,
            index: 7,
            vertices: 3
        }
    );
    let e = Gas::from_mesh(&[], &[[0, 0, 0]]).unwrap_err();
    assert!(e.to_string().contains("out of range"), "{e}");

    // A NaN vertex makes its triangles inactive, as the build does.
    let v = [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [f32::NAN, 0.0, 0.0],
    ];
    let gas = Gas::from_mesh(&v, &[[0, 1, 2], [3, 1, 2]]).unwrap();
    assert_eq!((gas.num_primitives(), gas.num_active_primitives()), (2, 1));
    let c = gas
        .closest_point(Vec3::new(5.0, 5.0, 5.0))
        .unwrap()
        .unwrap();
    assert_eq!(c.primitive_index, 0);

    // An empty mesh is an empty structure.
    let empty = Gas::from_mesh(&[], &[]).unwrap();
    assert_eq!(empty.num_active_primitives(), 0);
    assert!(empty.intersect(&Ray::new(Vec3::ZERO, Vec3::Z)).is_none());
}

// ---------------------------------------------------------------------------------------------
// All hits and counts.

#[test]
fn all_hits_are_the_brute_force_hits_sorted_and_each_once() {
    let mut rng = Rng::new(2);
    // Large triangles and long slivers across a small box: rays cross many, and spatial
    // splits reference the slivers from several leaves, so that a primitive is offered more
    // than once.
    let mut tris = random_soup(&mut rng, 1500, 4.0, 0.3);
    for _ in 0..300 {
        let a = rng.vec3(0.0, 4.0);
        let b = rng.vec3(0.0, 4.0);
        tris.push([
            a.to_array(),
            b.to_array(),
            (a + rng.vec3(-0.3, 0.3)).to_array(),
        ]);
    }
    let m = soup_mesh(&tris);
    let mut list = Vec::new();
    for options in presets() {
        let gas = gas_of(&m, &options);
        if options.flags.contains(BuildFlags::PREFER_FAST_TRACE) {
            let (refs, prims) = (gas.num_references(), gas.num_active_primitives());
            assert!(refs > prims + 20, "{refs} references of {prims} triangles");
        }
        let mut crossings = 0;
        for _ in 0..300 {
            let ray = random_ray(&mut rng, 4.0);
            let want = reference_sorted(&tris, &ray);
            crossings += want.len();
            assert!(gas.all_hits(&ray, usize::MAX, &mut list).unwrap());
            let got: Vec<(f32, u32)> = list.iter().map(|h| (h.t, h.primitive_index)).collect();
            assert_eq!(got, want);
            assert_eq!(gas.count_hits(&ray).unwrap() as usize, want.len());
            // Bounded: the nearest ones, and whether some were left out.
            for max in [0, 1, 3] {
                let complete = gas.all_hits(&ray, max, &mut list).unwrap();
                let got: Vec<(f32, u32)> = list.iter().map(|h| (h.t, h.primitive_index)).collect();
                assert_eq!(got[..], want[..want.len().min(max)]);
                assert_eq!(complete, want.len() <= max);
            }
            // A shorter interval.
            if want.len() >= 2 {
                let short = Ray::with_interval(ray.origin, ray.direction, want[0].0, want[1].0);
                gas.all_hits(&short, 64, &mut list).unwrap();
                assert_eq!(list.len(), want.iter().filter(|w| w.0 <= want[1].0).count());
            }
        }
        assert!(crossings > 1000, "too few hits to test: {crossings}");
    }
}

#[test]
fn rays_through_shared_edges_and_vertices_report_each_triangle_once() {
    // A cube of 4 x 4 quads per face: every grid line is an edge shared by two triangles, every
    // grid point a vertex shared by several.
    let m = grid_cube(4);
    let tris = m.soup();
    let edges = m.edge_map();
    for options in presets() {
        let gas = gas_of(&m, &options);
        let mut list = Vec::new();
        let mut checked = 0;
        // Rays along -z through grid points (vertices of the top and bottom faces), through
        // the middle of grid edges, and through the diagonal of each quad.
        for i in 0..=8 {
            for j in 0..=8 {
                let (x, y) = (-1.0 + 0.25 * i as f32, -1.0 + 0.25 * j as f32);
                let ray = Ray::new(Vec3::new(x, y, 3.0), -Vec3::Z);
                let want = reference_sorted(&tris, &ray);
                gas.all_hits(&ray, 64, &mut list).unwrap();
                let got: Vec<(f32, u32)> = list.iter().map(|h| (h.t, h.primitive_index)).collect();
                assert_eq!(got, want, "ray through ({x}, {y})");
                let mut prims: Vec<u32> = got.iter().map(|g| g.1).collect();
                prims.sort();
                prims.dedup();
                assert_eq!(
                    prims.len(),
                    got.len(),
                    "a primitive twice through ({x}, {y})"
                );
                assert_eq!(gas.count_hits(&ray).unwrap() as usize, want.len());
                checked += 1;
            }
        }
        assert_eq!(checked, 81);

        // Through the midpoint of a diagonal edge of the top face: exactly its two triangles
        // on entry (and two on exit, through a diagonal of the bottom face).
        let top = m
            .triangles
            .iter()
            .find(|t| t.iter().all(|&i| m.v(i).z == 1.0))
            .unwrap();
        let (a, b) = (top[0], top[2]);
        let mid = (m.v(a) + m.v(b)) * 0.5;
        let ray = Ray::new(mid + Vec3::Z, -Vec3::Z);
        gas.all_hits(&ray, 64, &mut list).unwrap();
        let mut sharing: Vec<u32> = edges[&(a.min(b), a.max(b))]
            .iter()
            .map(|&f| f as u32)
            .collect();
        sharing.sort();
        let at_entry: Vec<u32> = list
            .iter()
            .filter(|h| h.t == list[0].t)
            .map(|h| h.primitive_index)
            .collect();
        assert_eq!(list[0].t, 1.0);
        assert_eq!(at_entry, sharing);
        assert_eq!(list.len(), 4);
    }
}

#[test]
fn count_hits_is_the_length_of_all_hits_and_the_brute_force_count() {
    // A stack of 150 large overlapping slabs (rays along z cross up to 150 primitives, past
    // the fixed key array of the counting visitor: those rays are counted through the sorted
    // list) plus slivers that spatial splits reference from several leaves.
    let mut rng = Rng::new(21);
    let mut tris: Vec<Tri> = (0..150)
        .map(|k| {
            let z = 0.5 + 3.0 * k as f32 / 150.0 + rng.f32() * 0.01;
            let c = rng.vec3(1.5, 2.5);
            [
                [c.x - 3.0, c.y - 3.0, z],
                [c.x + 3.0, c.y - 2.0, z + 0.05],
                [c.x - 1.0, c.y + 3.0, z - 0.05],
            ]
        })
        .collect();
    for _ in 0..400 {
        let a = rng.vec3(0.0, 4.0);
        let b = rng.vec3(0.0, 4.0);
        tris.push([
            a.to_array(),
            b.to_array(),
            (a + rng.vec3(-0.2, 0.2)).to_array(),
        ]);
    }
    let m = soup_mesh(&tris);
    let mut list = Vec::new();
    for options in presets() {
        let gas = gas_of(&m, &options);
        let mut rays: Vec<Ray> = (0..300).map(|_| random_ray(&mut rng, 4.0)).collect();
        // Nearly along z through the stack: well over 64 hits each.
        rays.extend((0..100).map(|_| {
            let o = rng.vec3(1.8, 2.2);
            let d = (Vec3::Z + rng.vec3(-0.05, 0.05)).normalize();
            Ray::new(Vec3::new(o.x, o.y, -1.0), d)
        }));
        // Intervals that start and end inside the stack.
        rays.extend((0..100).map(|_| {
            let o = rng.vec3(1.8, 2.2);
            let (t0, t1) = (rng.f32() * 2.0, 2.0 + rng.f32() * 3.0);
            Ray::with_interval(Vec3::new(o.x, o.y, -1.0), Vec3::Z, t0, t1)
        }));
        let (mut long, mut total) = (0, 0);
        for ray in &rays {
            let want = reference_sorted(&tris, ray)
                .into_iter()
                .filter(|w| w.0 >= ray.tmin && w.0 <= ray.tmax)
                .count();
            let count = gas.count_hits(ray).unwrap() as usize;
            assert!(gas.all_hits(ray, usize::MAX, &mut list).unwrap());
            assert_eq!(count, list.len(), "{ray:?}");
            assert_eq!(count, want, "{ray:?}");
            long += usize::from(count > 64);
            total += count;
        }
        assert!(long >= 100, "too few rays past the key array: {long}");
        assert!(total > 15_000, "too few hits to test: {total}");
        let mut counts = vec![0; rays.len()];
        gas.count_hits_batch(&rays, &mut counts).unwrap();
        for (ray, &c) in rays.iter().zip(&counts) {
            assert_eq!(c, gas.count_hits(ray).unwrap());
        }
    }
}

/// The instance scene of several tests: a soup instanced with random transforms (one
/// mirrored, one with flipped facing).
struct Scene {
    tris: Vec<Tri>,
    gas: Arc<Gas>,
    transforms: Vec<Affine3A>,
    ias: Ias,
}

fn instance_scene(rng: &mut Rng, options: &BuildOptions) -> Scene {
    let tris = random_soup(rng, 150, 4.0, 1.5);
    let m = soup_mesh(&tris);
    let gas = Arc::new(gas_of(&m, options));
    let mut transforms: Vec<Affine3A> = (0..5).map(|_| rng.affine(3.0)).collect();
    transforms[1] = Affine3A::from_scale(Vec3::new(-1.0, 1.0, 1.0)) * transforms[1];
    let instances: Vec<Instance> = transforms
        .iter()
        .enumerate()
        .map(|(i, a)| {
            let inst = Instance::new(gas.clone().into())
                .transform(Transform::from_affine(a))
                .instance_id(100 + i as u32);
            if i == 2 {
                inst.flags(InstanceFlags::FLIP_TRIANGLE_FACING)
            } else {
                inst
            }
        })
        .collect();
    let ias = Ias::build(&BuildOptions::default(), &[(&instances[..]).into()]).unwrap();
    Scene {
        tris,
        gas,
        transforms,
        ias,
    }
}

#[test]
fn all_hits_through_instances_are_every_instance_crossing() {
    let mut rng = Rng::new(3);
    for options in presets() {
        let scene = instance_scene(&mut rng, &options);
        let mut list = Vec::new();
        let mut total = 0;
        for _ in 0..300 {
            let o = rng.vec3(-12.0, 12.0);
            let ray = Ray::new(o, (rng.vec3(-3.0, 5.0) - o).normalize());
            // The reference: each instance's triangles tested with the ray carried into its
            // space (as traversal carries it), tagged with the instance.
            let mut want: Vec<(f32, u32, u32)> = Vec::new();
            for (i, a) in scene.transforms.iter().enumerate() {
                let w2o = Transform::from_affine(a).inverse().unwrap();
                let obj = Ray::new(
                    w2o.transform_point(ray.origin),
                    w2o.transform_vector(ray.direction),
                );
                for h in reference_hits(&scene.tris, &obj) {
                    want.push((h.hit.t, i as u32, h.prim));
                }
            }
            want.sort_by(|a, b| a.0.total_cmp(&b.0).then((a.1, a.2).cmp(&(b.1, b.2))));
            total += want.len();
            assert!(scene.ias.all_hits(&ray, 1000, &mut list).unwrap());
            let got: Vec<(u32, u32)> = list
                .iter()
                .map(|h| (h.instance_index, h.primitive_index))
                .collect();
            let mut got_sorted = got.clone();
            got_sorted.sort();
            got_sorted.dedup();
            assert_eq!(
                got_sorted.len(),
                got.len(),
                "a primitive of an instance twice"
            );
            let mut want_ids: Vec<(u32, u32)> = want.iter().map(|w| (w.1, w.2)).collect();
            want_ids.sort();
            assert_eq!(got_sorted, want_ids);
            for (h, w) in list.iter().zip(want.iter()) {
                assert!(
                    (h.t - w.0).abs() <= 1e-4 * w.0.max(1.0),
                    "{} vs {}",
                    h.t,
                    w.0
                );
            }
            assert!(list.windows(2).all(|w| w[0].t <= w[1].t));
            for h in &list {
                assert_eq!(h.instance_id, 100 + h.instance_index);
            }
            assert_eq!(scene.ias.count_hits(&ray).unwrap() as usize, want.len());
        }
        assert!(total > 300, "too few hits to test: {total}");
    }
}

#[test]
fn batches_equal_single_queries_whatever_the_thread_count() {
    let mut rng = Rng::new(4);
    let scene = instance_scene(&mut rng, &BuildOptions::new(BuildFlags::PREFER_FAST_TRACE));
    let rays: Vec<Ray> = (0..1500)
        .map(|_| {
            let o = rng.vec3(-12.0, 12.0);
            Ray::new(o, (rng.vec3(-3.0, 5.0) - o).normalize())
        })
        .collect();
    let points: Vec<Vec3> = (0..1500).map(|_| rng.vec3(-6.0, 10.0)).collect();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut all = AllHits::new();
            scene.ias.all_hits_batch(&rays, 5, &mut all).unwrap();
            let mut counts = vec![0u32; rays.len()];
            scene.ias.count_hits_batch(&rays, &mut counts).unwrap();
            let mut hits = vec![None; rays.len()];
            scene.ias.intersect_batch(&rays, &mut hits).unwrap();
            let mut surfaces = vec![None; rays.len()];
            scene
                .ias
                .hit_surface_batch(&rays, &hits, &mut surfaces)
                .unwrap();
            let mut closest = vec![None; points.len()];
            scene
                .gas
                .closest_point_batch(&points, &mut closest)
                .unwrap();
            let mut sd = vec![0.0f32; points.len()];
            scene.gas.signed_distance_batch(&points, &mut sd).unwrap();
            (all, counts, surfaces, closest, sd)
        })
    };
    let one = run(1);
    let many = run(4);
    assert_eq!(one, many);
    let (all, counts, surfaces, closest, sd) = one;
    let mut list = Vec::new();
    assert_eq!(all.len(), rays.len());
    assert!(all.all().len() > 500);
    for (i, ray) in rays.iter().enumerate() {
        let complete = scene.ias.all_hits(ray, 5, &mut list).unwrap();
        assert_eq!(all.hits(i), &list[..]);
        assert_eq!(all.is_complete(i), complete);
        assert_eq!(counts[i], scene.ias.count_hits(ray).unwrap());
        assert_eq!(complete, counts[i] <= 5);
        let hit = scene.ias.intersect(ray);
        assert_eq!(
            surfaces[i],
            hit.map(|h| scene.ias.hit_surface(ray, &h).unwrap())
        );
    }
    for (i, &p) in points.iter().enumerate() {
        assert_eq!(closest[i], scene.gas.closest_point(p).unwrap());
        assert_eq!(
            sd[i].to_bits(),
            scene.gas.signed_distance(p).unwrap().to_bits()
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Hit points and normals.

fn close(a: Vec3, b: Vec3, tol: f32) -> bool {
    (a - b).length() <= tol
}

#[test]
fn hit_surface_of_triangles_is_the_triangle_point_and_winding_normal() {
    let mut rng = Rng::new(5);
    let tris = random_soup(&mut rng, 300, 10.0, 1.0);
    let m = soup_mesh(&tris);
    // Random unit vertex normals.
    let normals: Vec<[f32; 3]> = (0..m.positions.len())
        .map(|_| rng.unit().to_array())
        .collect();
    let vn = VertexNormals::new(&normals, &m.triangles).unwrap();
    for options in presets() {
        let gas = gas_of(&m, &options);
        let mut hits = 0;
        for _ in 0..500 {
            let ray = random_ray(&mut rng, 10.0);
            let Some(hit) = gas.intersect(&ray) else {
                continue;
            };
            hits += 1;
            let s = gas.hit_surface_shaded(&ray, &hit, &vn).unwrap();
            let [a, b, c] = tris[hit.primitive_index as usize].map(Vec3::from);
            let w = 1.0 - hit.u - hit.v;
            assert!(close(s.point, ray.at(hit.t), 1e-4 * hit.t.max(1.0)));
            assert!(close(s.point, a * w + b * hit.u + c * hit.v, 1e-5));
            let n = (b - a).cross(c - a).normalize();
            assert!(
                close(s.geometric_normal, n, 1e-5),
                "{:?} vs {n:?}",
                s.geometric_normal
            );
            assert_eq!(s.front_face, hit.hit_kind == HitKind::TRIANGLE_FRONT_FACE);
            assert_eq!(s.front_face, s.geometric_normal.dot(ray.direction) < 0.0);
            let [n0, n1, n2] =
                m.triangles[hit.primitive_index as usize].map(|i| Vec3::from(normals[i as usize]));
            let want = (n0 * w + n1 * hit.u + n2 * hit.v).normalize();
            assert!(close(s.shading_normal, want, 1e-5));
            // Without normals, the shading normal is the geometric one.
            let plain = gas.hit_surface(&ray, &hit).unwrap();
            assert_eq!(plain.shading_normal, plain.geometric_normal);
            assert_eq!(plain.point, s.point);
        }
        assert!(hits > 100, "too few hits to test: {hits}");
    }
}

#[test]
fn hit_surface_through_instances_is_in_world_space() {
    let mut rng = Rng::new(6);
    let scene = instance_scene(&mut rng, &BuildOptions::default());
    // A second level: the IAS instanced twice.
    let top_t = [rng.affine(2.0), rng.affine(2.0)];
    let ias = Arc::new(scene.ias.clone());
    let top_instances: Vec<Instance> = top_t
        .iter()
        .enumerate()
        .map(|(i, a)| {
            Instance::new(ias.clone().into())
                .transform(Transform::from_affine(a))
                .instance_id(7 + i as u32)
        })
        .collect();
    let top = Ias::build(&BuildOptions::default(), &[(&top_instances[..]).into()]).unwrap();

    let mut per_level = [0; 2];
    for (level, count) in per_level.iter_mut().enumerate() {
        for _ in 0..600 {
            let o = rng.vec3(-15.0, 15.0);
            let ray = Ray::new(o, (rng.vec3(-3.0, 5.0) - o).normalize());
            let (hit, s, to_world) = if level == 0 {
                let Some(hit) = scene.ias.intersect(&ray) else {
                    continue;
                };
                let s = scene.ias.hit_surface(&ray, &hit).unwrap();
                (hit, s, scene.transforms[hit.instance_index as usize])
            } else {
                let Some(hit) = top.intersect(&ray) else {
                    continue;
                };
                // Which top instance it came through is not in the hit: try both.
                let s = top.hit_surface(&ray, &hit).unwrap();
                let inner = scene.transforms[hit.instance_index as usize];
                let candidates = top_t.map(|t| t * inner);
                let tri = scene.tris[hit.primitive_index as usize].map(Vec3::from);
                let w = 1.0 - hit.u - hit.v;
                let p = tri[0] * w + tri[1] * hit.u + tri[2] * hit.v;
                let best = *candidates
                    .iter()
                    .min_by(|a, b| {
                        let da = (a.transform_point3(p) - s.point).length();
                        let db = (b.transform_point3(p) - s.point).length();
                        da.total_cmp(&db)
                    })
                    .unwrap();
                (hit, s, best)
            };
            *count += 1;
            let [a, b, c] = scene.tris[hit.primitive_index as usize].map(Vec3::from);
            let w = 1.0 - hit.u - hit.v;
            let scale = 1e-4 * hit.t.max(1.0);
            assert!(close(
                s.point,
                to_world.transform_point3(a * w + b * hit.u + c * hit.v),
                scale
            ));
            assert!(close(s.point, ray.at(hit.t), 10.0 * scale));
            // The world triangle's winding normal, times the sign of the determinant.
            let (wa, wb, wc) = (
                to_world.transform_point3(a),
                to_world.transform_point3(b),
                to_world.transform_point3(c),
            );
            let det = to_world.matrix3.determinant();
            let n = ((wb - wa).cross(wc - wa) * det.signum()).normalize();
            assert!(
                close(s.geometric_normal, n, 1e-4),
                "{:?} vs {n:?}",
                s.geometric_normal
            );
            assert!((s.geometric_normal.length() - 1.0).abs() < 1e-5);
            // Front face exactly when the ray meets the normal, except under flipped facing.
            let flipped = hit.instance_index == 2;
            assert_eq!(s.front_face, hit.hit_kind.is_front_face());
            assert_eq!(
                s.front_face != flipped,
                s.geometric_normal.dot(ray.direction) < 0.0
            );
        }
    }
    assert!(
        per_level.iter().all(|&n| n > 50),
        "too few hits: {per_level:?}"
    );
}

#[test]
fn hit_surface_of_spheres_is_on_the_sphere() {
    let mut rng = Rng::new(7);
    let centres: Vec<[f32; 3]> = (0..100).map(|_| rng.vec3(0.0, 10.0).to_array()).collect();
    let radii: Vec<f32> = (0..100).map(|_| rng.range(0.2, 1.0)).collect();
    let cb = [bytemuck::cast_slice::<_, u8>(&centres)];
    let rb = [bytemuck::cast_slice::<_, u8>(&radii)];
    let input = SphereInput::new(&cb, 100, &rb);
    let gas = Arc::new(Gas::build(&BuildOptions::default(), &[input.into()]).unwrap());
    let a = rng.affine(1.0);
    let ias = Ias::build(
        &BuildOptions::default(),
        &[(&[Instance::new(gas.clone().into()).transform(Transform::from_affine(&a))][..]).into()],
    )
    .unwrap();
    let mut hits = 0;
    for _ in 0..400 {
        let ray = random_ray(&mut rng, 10.0);
        if let Some(hit) = gas.intersect(&ray) {
            hits += 1;
            let s = gas.hit_surface(&ray, &hit).unwrap();
            let (c, r) = (
                Vec3::from(centres[hit.primitive_index as usize]),
                radii[hit.primitive_index as usize],
            );
            assert!(((s.point - c).length() - r).abs() < 1e-5);
            assert!(close(s.point, ray.at(hit.t), 1e-4 * hit.t.max(1.0)));
            assert!(close(s.geometric_normal, (s.point - c) / r, 1e-4));
            assert!(s.front_face && s.geometric_normal.dot(ray.direction) < 0.0);
        }
        // Through the instance: the world normal is the inverse transpose of the object one.
        if let Some(hit) = ias.intersect(&ray) {
            let s = ias.hit_surface(&ray, &hit).unwrap();
            let c = Vec3::from(centres[hit.primitive_index as usize]);
            let obj = a.inverse().transform_point3(s.point);
            let n = a.matrix3.inverse().transpose() * (obj - c);
            assert!(close(s.geometric_normal, n.normalize(), 1e-4));
            assert!(close(s.point, ray.at(hit.t), 1e-4 * hit.t.max(1.0)));
        }
    }
    assert!(hits > 50, "too few hits: {hits}");
}

// ---------------------------------------------------------------------------------------------
// Closest points and signed distance.

/// The closest point of a triangle to `p`, in f64, by another method than the engine's: the
/// projection onto the plane where it falls inside, else the nearest point of the three edges.
fn ref_closest(p: DVec3, t: &Tri) -> DVec3 {
    let [a, b, c] = t.map(|v| Vec3::from(v).as_dvec3());
    let n = (b - a).cross(c - a);
    let q = p - n * (n.dot(p - a) / n.dot(n));
    let inside = [(a, b), (b, c), (c, a)]
        .iter()
        .all(|&(x, y)| (y - x).cross(q - x).dot(n) >= 0.0);
    if inside {
        return q;
    }
    [(a, b), (b, c), (c, a)]
        .iter()
        .map(|&(x, y)| {
            let s = ((p - x).dot(y - x) / (y - x).dot(y - x)).clamp(0.0, 1.0);
            x + (y - x) * s
        })
        .min_by(|u, v| (*u - p).length().total_cmp(&(*v - p).length()))
        .unwrap()
}

/// The two smallest distances over the soup and the nearest triangle.
fn ref_nearest(p: Vec3, tris: &[Tri]) -> (f64, f64, usize) {
    let p = p.as_dvec3();
    let mut best = (f64::INFINITY, f64::INFINITY, usize::MAX);
    for (i, t) in tris.iter().enumerate() {
        let d = (ref_closest(p, t) - p).length();
        if d < best.0 {
            best = (d, best.0, i);
        } else if d < best.1 {
            best.1 = d;
        }
    }
    best
}

fn check_closest(c: &ClosestPoint, p: Vec3, tris: &[Tri], scale: f32) {
    let (d, second, prim) = ref_nearest(p, tris);
    let tol = 2e-6 * (scale as f64 + d);
    assert!(
        (c.distance as f64 - d).abs() <= tol,
        "{p}: {} vs {d}",
        c.distance
    );
    assert!(((c.point - p).length() as f64 - d).abs() <= tol);
    if second - d > 10.0 * tol {
        assert_eq!(c.primitive_index as usize, prim, "{p}");
    }
    let t = tris[c.primitive_index as usize].map(Vec3::from);
    let from_bary = t[0] * (1.0 - c.u - c.v) + t[1] * c.u + t[2] * c.v;
    assert!(close(from_bary, c.point, 1e-5 * scale));
    assert!(c.u >= 0.0 && c.v >= 0.0 && c.u + c.v <= 1.0 + 1e-6);
}

#[test]
fn closest_points_are_the_brute_force_ones() {
    let mut rng = Rng::new(8);
    let tris = random_soup(&mut rng, 500, 10.0, 1.0);
    let m = soup_mesh(&tris);
    for options in presets() {
        let gas = gas_of(&m, &options);
        // Near the triangles, far away, and inside the cloud.
        for k in 0..600 {
            let p = match k % 3 {
                0 => rng.vec3(-1.0, 11.0),
                1 => rng.vec3(-60.0, 60.0),
                _ => {
                    let t = tris[rng.below(tris.len())].map(Vec3::from);
                    (t[0] + t[1] + t[2]) / 3.0 + rng.vec3(-0.05, 0.05)
                }
            };
            let c = gas.closest_point(p).unwrap().unwrap();
            check_closest(&c, p, &tris, 60.0);
            // Within a radius: found when the radius reaches it, nothing otherwise.
            let within = gas.closest_point_within(p, c.distance * 1.01).unwrap();
            assert_eq!(within.map(|w| w.distance), Some(c.distance));
            assert_eq!(
                gas.closest_point_within(p, c.distance * 0.99).unwrap(),
                None
            );
        }
    }
}

#[test]
fn closest_points_through_instances_are_the_brute_force_ones() {
    let mut rng = Rng::new(81);
    let a = random_soup(&mut rng, 200, 3.0, 0.8);
    let b = random_soup(&mut rng, 120, 2.0, 0.6);
    let (ga, gb) = (
        Arc::new(gas_of(&soup_mesh(&a), &BuildOptions::default())),
        Arc::new(gas_of(&soup_mesh(&b), &BuildOptions::default())),
    );
    // Placements: rotations, uniform scales (one mirrored), translations; and a nested IAS
    // under a static transform.
    let place = |rng: &mut Rng, s: f32| {
        Affine3A::from_scale_rotation_translation(
            Vec3::splat(s),
            rng.rotation(),
            rng.vec3(-6.0, 6.0),
        )
    };
    let mut placed: Vec<(Affine3A, &[Tri], u32)> = Vec::new();
    let mut instances = Vec::new();
    for i in 0..6u32 {
        let (gas, tris) = if i % 2 == 0 { (&ga, &a) } else { (&gb, &b) };
        let mut t = place(&mut rng, 0.5 + 0.3 * i as f32);
        if i == 3 {
            t = Affine3A::from_scale(Vec3::new(-1.0, 1.0, 1.0)) * t;
        }
        placed.push((t, tris, 10 + i));
        instances.push(
            Instance::new(gas.clone().into())
                .transform(Transform::from_affine(&t))
                .instance_id(10 + i),
        );
    }
    let inner_t = place(&mut rng, 1.5);
    let inner = Arc::new(
        Ias::build(
            &BuildOptions::default(),
            &[(&[Instance::new(ga.clone().into())
                .transform(Transform::from_affine(&inner_t))
                .instance_id(20)][..])
                .into()],
        )
        .unwrap(),
    );
    let outer_t = place(&mut rng, 0.8);
    let st =
        oxray_core::StaticTransform::new(inner.into(), Transform::from_affine(&outer_t)).unwrap();
    placed.push((outer_t * inner_t, &a, 20));
    instances.push(Instance::new(st.into()).instance_id(30));
    let ias = Ias::build(&BuildOptions::default(), &[(&instances[..]).into()]).unwrap();

    // The world triangles of every placement, for the brute force.
    let world: Vec<(Tri, u32, u32)> = placed
        .iter()
        .flat_map(|(t, tris, id)| {
            tris.iter().enumerate().map(move |(k, tri)| {
                (
                    tri.map(|v| t.transform_point3(Vec3::from(v)).to_array()),
                    *id,
                    k as u32,
                )
            })
        })
        .collect();
    let world_tris: Vec<Tri> = world.iter().map(|w| w.0).collect();
    let mut points: Vec<Vec3> = (0..400).map(|_| rng.vec3(-12.0, 12.0)).collect();
    points.push(Vec3::splat(100.0));
    let mut batch = vec![None; points.len()];
    ias.closest_point_batch(&points, &mut batch).unwrap();
    for (p, got) in points.iter().zip(&batch) {
        let c = ias.closest_point(*p).unwrap().unwrap();
        assert_eq!(
            got.as_ref(),
            Some(&c),
            "the batch gives the single query's answer"
        );
        let (d, second, k) = ref_nearest(*p, &world_tris);
        let tol = 1e-5 * (20.0 + d);
        assert!(
            (c.closest.distance as f64 - d).abs() <= tol,
            "{p}: {} vs {d}",
            c.closest.distance
        );
        assert!(((c.closest.point - *p).length() as f64 - d).abs() <= tol);
        if second - d > 10.0 * tol {
            // The nearest instance's (nearest to the GAS: 20 under the static transform)
            // triangle, with its barycentrics in the object-space triangle.
            assert_eq!(
                (c.instance_id, c.closest.primitive_index),
                (world[k].1, world[k].2)
            );
            let t = world[k].0.map(Vec3::from);
            let from_bary =
                t[0] * (1.0 - c.closest.u - c.closest.v) + t[1] * c.closest.u + t[2] * c.closest.v;
            assert!(close(from_bary, c.closest.point, 1e-4 * (20.0 + d as f32)));
        }
    }
}

#[test]
fn closest_points_through_instances_refuse_what_they_cannot_answer() {
    let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let gas = Arc::new(Gas::from_mesh(&v, &[[0, 1, 2]]).unwrap());
    let ias_of = |t: Transform| {
        Ias::build(
            &BuildOptions::default(),
            &[(&[Instance::new(gas.clone().into()).transform(t)][..]).into()],
        )
        .unwrap()
    };
    // A non-uniform scale changes distances by direction: refused, never a wrong answer.
    let stretched = ias_of(Transform::from_affine(&Affine3A::from_scale(Vec3::new(
        1.0, 3.0, 1.0,
    ))));
    assert!(matches!(
        stretched.closest_point(Vec3::ZERO),
        Err(SurfaceQueryError::Unsupported(_))
    ));
    let plain = ias_of(Transform::IDENTITY);
    assert!(matches!(
        plain.closest_point(Vec3::new(f32::NAN, 0.0, 0.0)),
        Err(SurfaceQueryError::NonFinitePoint { .. })
    ));
    assert_eq!(
        plain
            .closest_point(Vec3::new(0.25, 0.25, 3.0))
            .unwrap()
            .unwrap()
            .closest
            .distance,
        3.0
    );
    // Spheres are no triangles.
    let c = [[0.0f32, 0.0, 0.0]];
    let r = [1.0f32];
    let cb = [bytemuck::cast_slice::<_, u8>(&c)];
    let rb = [bytemuck::cast_slice::<_, u8>(&r)];
    let spheres = Arc::new(
        Gas::build(
            &BuildOptions::default(),
            &[SphereInput::new(&cb, 1, &rb).into()],
        )
        .unwrap(),
    );
    let with_spheres = Ias::build(
        &BuildOptions::default(),
        &[(&[Instance::new(spheres.into())][..]).into()],
    )
    .unwrap();
    assert!(matches!(
        with_spheres.closest_point(Vec3::splat(3.0)),
        Err(SurfaceQueryError::NotTriangles(_))
    ));
    // An empty IAS has no closest point.
    let none: [Instance; 0] = [];
    let empty = Ias::build(&BuildOptions::default(), &[(&none[..]).into()]).unwrap();
    assert_eq!(empty.closest_point(Vec3::ZERO).unwrap(), None);
}

#[test]
fn closest_points_on_vertices_and_edges_are_at_distance_zero() {
    let m = icosphere(2);
    let tris = m.soup();
    for options in presets() {
        let gas = gas_of(&m, &options);
        for (i, p) in m.positions.iter().enumerate() {
            let c = gas.closest_point(Vec3::from(*p)).unwrap().unwrap();
            assert_eq!(c.distance, 0.0, "vertex {i}");
            assert_eq!(c.point, Vec3::from(*p));
            assert_eq!(gas.signed_distance(Vec3::from(*p)).unwrap(), 0.0);
            assert!(!gas.contains(Vec3::from(*p)).unwrap());
        }
        for (&(a, b), faces) in m.edge_map().iter() {
            assert_eq!(faces.len(), 2, "the icosphere is closed");
            let mid = (m.v(a) + m.v(b)) * 0.5;
            let c = gas.closest_point(mid).unwrap().unwrap();
            assert!(c.distance < 1e-6, "{}", c.distance);
            assert!(faces.contains(&(c.primitive_index as usize)));
            // Just off the edge, out and in.
            let out = mid.normalize() * 0.01;
            assert!(gas.signed_distance(mid + out).unwrap() > 0.0);
            assert!(gas.signed_distance(mid - out).unwrap() < 0.0);
            check_closest(
                &gas.closest_point(mid + out).unwrap().unwrap(),
                mid + out,
                &tris,
                1.0,
            );
        }
    }
}

#[test]
fn signed_distance_of_closed_meshes_is_negative_inside() {
    let mut rng = Rng::new(9);
    let cube = grid_cube(3);
    let sphere = icosphere(3);
    for options in presets() {
        let cube_gas = gas_of(&cube, &options);
        let sphere_gas = gas_of(&sphere, &options);
        let cube_tris = cube.soup();
        let sphere_tris = sphere.soup();
        let mut inside = 0;
        for _ in 0..400 {
            let p = rng.vec3(-2.0, 2.0);
            // The cube [-1, 1]^3.
            let sd = cube_gas.signed_distance(p).unwrap();
            let (d, ..) = ref_nearest(p, &cube_tris);
            assert!((sd.abs() as f64 - d).abs() < 1e-5, "{p}: {sd} vs {d}");
            let want_inside = p.abs().max_element() < 1.0;
            assert_eq!(sd < 0.0, want_inside, "{p}: {sd}");
            assert_eq!(cube_gas.contains(p).unwrap(), want_inside);
            inside += want_inside as u32;
            // The icosphere: inside a radius 0.99 ball, outside the unit ball.
            let sd = sphere_gas.signed_distance(p).unwrap();
            let (d, ..) = ref_nearest(p, &sphere_tris);
            assert!((sd.abs() as f64 - d).abs() < 1e-5);
            if p.length() < 0.99 {
                assert!(sd < 0.0, "{p}: {sd}");
            } else if p.length() > 1.0 {
                assert!(sd > 0.0, "{p}: {sd}");
            }
        }
        assert!(inside > 20);

        // Points whose closest point is a vertex or an edge of the cube, where the normal of
        // one nearest triangle alone can give the wrong sign.
        let cases = [
            (Vec3::new(1.5, 1.5, 1.5), 0.75f32.sqrt()),
            (Vec3::new(1.2, 1.2, 0.1), 0.08f32.sqrt()),
            (Vec3::new(-1.1, 0.5, -1.1), 0.02f32.sqrt()),
            (
                Vec3::new(1.0 + 1e-3, 1.0 + 1e-3, 1.0 + 1e-3),
                3e-6f32.sqrt(),
            ),
            (Vec3::new(0.9, 0.9, 0.9), -0.1),
            (Vec3::new(0.99, -0.99, 0.3), -0.01),
            (Vec3::new(0.999, 0.999, 0.999), -0.001),
            // On a grid vertex of a face, and on grid edges, just outside and inside.
            (Vec3::new(1.0 / 3.0, 1.0 / 3.0, 1.01), 0.01),
            (Vec3::new(1.0 / 3.0, 1.0 / 3.0, 0.99), -0.01),
            (Vec3::new(0.0, 1.0 / 3.0, -1.02), 0.02),
        ];
        for (p, want) in cases {
            let sd = cube_gas.signed_distance(p).unwrap();
            assert!((sd - want).abs() < 1e-5, "{p}: {sd} vs {want}");
        }
    }

    // Turned inside out (every triangle wound the other way), the signs swap.
    let inverted: Vec<[u32; 3]> = cube.triangles.iter().map(|t| [t[0], t[2], t[1]]).collect();
    let gas = Gas::from_mesh(&cube.positions, &inverted).unwrap();
    assert!(gas.signed_distance(Vec3::ZERO).unwrap() > 0.0);
    assert!(gas.signed_distance(Vec3::splat(1.5)).unwrap() < 0.0);
}

/// A convex solid as a closed mesh: the triangles given, each wound to face away from the
/// centroid of the vertices.
fn outward(positions: Vec<[f32; 3]>, triangles: &[[u32; 3]]) -> Mesh {
    let centre = positions.iter().map(|&p| Vec3::from(p)).sum::<Vec3>() / positions.len() as f32;
    let triangles = triangles
        .iter()
        .map(|&[a, b, c]| {
            let [pa, pb, pc] = [a, b, c].map(|i| Vec3::from(positions[i as usize]));
            if (pb - pa).cross(pc - pa).dot(pa - centre) < 0.0 {
                [a, c, b]
            } else {
                [a, b, c]
            }
        })
        .collect();
    Mesh {
        positions,
        triangles,
    }
}

#[test]
fn signed_distance_is_right_beyond_sharp_edges_and_vertices() {
    // A prism whose edge along z through the origin is a 20 degree wedge: beyond it, the
    // normal of either face alone gives the wrong sign for half of the directions.
    let w = 0.18f32;
    let positions = vec![
        [0.0, 0.0, 0.0],
        [1.0, w, 0.0],
        [1.0, -w, 0.0],
        [0.0, 0.0, 1.0],
        [1.0, w, 1.0],
        [1.0, -w, 1.0],
    ];
    let quads = [[0, 1, 4, 3], [0, 3, 5, 2], [1, 2, 5, 4]];
    let mut tris = vec![[0, 1, 2], [3, 4, 5]];
    for [a, b, c, d] in quads {
        tris.push([a, b, c]);
        tris.push([a, c, d]);
    }
    let m = outward(positions, &tris);
    let n1 = Vec3::new(-w, 1.0, 0.0).normalize();
    let n2 = Vec3::new(-w, -1.0, 0.0).normalize();
    for options in presets() {
        let gas = gas_of(&m, &options);
        for k in 0..=10 {
            let s = k as f32 / 10.0;
            let dir = (n1 * (1.0 - s) + n2 * s).normalize();
            // Beyond the edge, in its normal cone.
            let p = Vec3::new(0.0, 0.0, 0.5) + dir * 0.05;
            let sd = gas.signed_distance(p).unwrap();
            assert!((sd - 0.05).abs() < 1e-6, "{p}: {sd}");
            // Beyond the vertex at the origin, in its normal cone.
            let p = (dir - Vec3::Z).normalize() * 0.05;
            let sd = gas.signed_distance(p).unwrap();
            assert!((sd - 0.05).abs() < 1e-6, "{p}: {sd}");
        }
        // Inside, near the edge: the distance to the nearer face, negative.
        let p = Vec3::new(0.05, 0.0, 0.5);
        let want = -0.05 * (w.atan()).sin();
        let sd = gas.signed_distance(p).unwrap();
        assert!((sd - want).abs() < 1e-6, "{sd} vs {want}");
    }
}

#[test]
fn signed_distance_at_vertices_of_high_valence_is_right() {
    // A tall closed cone of 48 sides: its apex and the centre of its base are each a vertex of
    // 48 triangles, more than the search keeps beside the nearest one (the pseudo-normal is
    // then found by a second walk).
    let n = 48;
    let mut positions = vec![[0.0f32, 0.0, 4.0], [0.0, 0.0, 0.0]];
    positions.extend((0..n).map(|i| {
        let a = std::f32::consts::TAU * i as f32 / n as f32;
        [a.cos(), a.sin(), 0.0]
    }));
    let ring = |i: u32| 2 + i % n as u32;
    let mut tris = Vec::new();
    for i in 0..n as u32 {
        tris.push([ring(i), ring(i + 1), 0]);
        tris.push([1, ring(i + 1), ring(i)]);
    }
    let m = outward(positions, &tris);
    for options in presets() {
        let gas = gas_of(&m, &options);
        for k in 0..12 {
            let phi = std::f32::consts::TAU * k as f32 / 12.0;
            for tilt in [0.0f32, 0.3, 0.6] {
                // Beyond the apex, in its normal cone: the apex is the closest point.
                let dir = Vec3::new(phi.cos() * tilt.sin(), phi.sin() * tilt.sin(), tilt.cos());
                let p = Vec3::new(0.0, 0.0, 4.0) + dir * 0.05;
                let sd = gas.signed_distance(p).unwrap();
                assert!((sd - 0.05).abs() < 1e-5, "{p}: {sd}");
                // Below the base's centre: that vertex is the closest point.
                let p = Vec3::new(0.0, 0.0, -0.05) + dir * Vec3::new(1e-3, 1e-3, 0.0);
                let sd = gas.signed_distance(p).unwrap();
                assert!((sd - 0.05).abs() < 1e-5, "{p}: {sd}");
            }
            // Inside, near the apex and near the base's centre.
            for p in [
                Vec3::new(0.0, 0.0, 3.8),
                Vec3::new(0.01 * phi.cos(), 0.0, 0.02),
            ] {
                assert!(gas.signed_distance(p).unwrap() < 0.0, "{p}");
                assert!(gas.contains(p).unwrap(), "{p}");
            }
        }
    }
}

#[test]
fn signed_distance_of_an_open_mesh_is_the_side_of_the_nearest_surface() {
    // One triangle, counter-clockwise seen from +z: positive above, negative below, and
    // beyond its edges the sign of the side its plane leaves the point on.
    let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let gas = Gas::from_mesh(&v, &[[0, 1, 2]]).unwrap();
    assert_eq!(gas.signed_distance(Vec3::new(0.2, 0.2, 0.5)).unwrap(), 0.5);
    assert_eq!(
        gas.signed_distance(Vec3::new(0.2, 0.2, -0.5)).unwrap(),
        -0.5
    );
    assert!(gas.signed_distance(Vec3::new(2.0, 2.0, 0.1)).unwrap() > 0.0);
    assert!(gas.signed_distance(Vec3::new(-1.0, -1.0, -0.1)).unwrap() < 0.0);
}

// ---------------------------------------------------------------------------------------------
// Bad input and empty structures.

#[test]
fn bad_input_is_an_error_and_empty_structures_give_empty_results() {
    let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let gas = Gas::from_mesh(&v, &[[0, 1, 2]]).unwrap();
    let nan = Vec3::new(f32::NAN, 0.0, 0.0);
    assert!(matches!(
        gas.closest_point(nan),
        Err(SurfaceQueryError::NonFinitePoint { index: 0, .. })
    ));
    assert!(matches!(
        gas.signed_distance(Vec3::new(0.0, f32::INFINITY, 0.0)),
        Err(SurfaceQueryError::NonFinitePoint { .. })
    ));
    let bad_ray = Ray::new(Vec3::new(f32::NAN, 0.0, 0.0), Vec3::Z);
    let mut list = Vec::new();
    assert_eq!(
        gas.all_hits(&bad_ray, 4, &mut list),
        Err(SurfaceQueryError::InvalidRay {
            index: 0,
            error: RayError::NonFiniteOrigin
        })
    );
    assert_eq!(
        gas.count_hits(&Ray::new(Vec3::ZERO, Vec3::ZERO)),
        Err(SurfaceQueryError::InvalidRay {
            index: 0,
            error: RayError::ZeroDirection
        })
    );

    // Batches: length mismatches, and the first bad query named by its index.
    let mut points = vec![Vec3::new(0.2, 0.2, 1.0); 700];
    points[300] = nan;
    points[600] = nan;
    let mut out = vec![None; 700];
    assert_eq!(
        gas.closest_point_batch(&points, &mut out[..5]),
        Err(SurfaceQueryError::LengthMismatch {
            queries: 700,
            outputs: 5
        })
    );
    assert!(matches!(
        gas.closest_point_batch(&points, &mut out),
        Err(SurfaceQueryError::NonFinitePoint { index: 300, .. })
    ));
    assert_eq!(out[299].unwrap().distance, 1.0);
    assert_eq!(out[699].unwrap().distance, 1.0);
    assert!(out[300].is_none());
    let mut sd = vec![0.0; 700];
    assert!(matches!(
        gas.signed_distance_batch(&points, &mut sd),
        Err(SurfaceQueryError::NonFinitePoint { index: 300, .. })
    ));
    let mut rays = vec![Ray::new(Vec3::new(0.2, 0.2, 1.0), -Vec3::Z); 10];
    rays[7] = bad_ray;
    let mut all = AllHits::new();
    assert!(matches!(
        gas.all_hits_batch(&rays, 4, &mut all),
        Err(SurfaceQueryError::InvalidRay { index: 7, .. })
    ));
    assert!(all.is_empty());
    let mut counts = vec![9; 10];
    assert!(matches!(
        gas.count_hits_batch(&rays, &mut counts),
        Err(SurfaceQueryError::InvalidRay { index: 7, .. })
    ));
    assert_eq!((counts[0], counts[7]), (1, 9));
    let mut surfaces = vec![None; 10];
    assert!(matches!(
        gas.hit_surface_batch(&rays, &[None; 3], &mut surfaces),
        Err(SurfaceQueryError::LengthMismatch { .. })
    ));

    // A hit of another ray, or with changed fields, is not found; a custom hit is refused.
    let ray = Ray::new(Vec3::new(0.2, 0.2, 1.0), -Vec3::Z);
    let hit = gas.intersect(&ray).unwrap();
    let other = Ray::new(Vec3::new(0.2, 0.2, 3.0), -Vec3::Z);
    assert!(matches!(
        gas.hit_surface(&other, &hit),
        Err(SurfaceQueryError::HitNotFound { .. })
    ));
    let moved = Hit {
        primitive_index: 5,
        ..hit
    };
    assert!(matches!(
        gas.hit_surface(&ray, &moved),
        Err(SurfaceQueryError::HitNotFound {
            primitive_index: 5,
            ..
        })
    ));
    let nan_t = Hit { t: f32::NAN, ..hit };
    assert!(gas.hit_surface(&ray, &nan_t).is_err());
    let custom = Hit {
        hit_kind: HitKind::custom(1),
        ..hit
    };
    assert!(matches!(
        gas.hit_surface(&ray, &custom),
        Err(SurfaceQueryError::Unsupported(_))
    ));
    assert!(matches!(
        gas.hit_surface(&bad_ray, &hit),
        Err(SurfaceQueryError::InvalidRay { .. })
    ));
    let mut batch_hits = vec![Some(hit); 10];
    batch_hits[2] = None;
    rays[7] = ray;
    batch_hits[9] = Some(moved);
    assert!(matches!(
        gas.hit_surface_batch(&rays, &batch_hits, &mut surfaces),
        Err(SurfaceQueryError::HitNotFound { index: 9, .. })
    ));
    let s: SurfaceHit = surfaces[0].unwrap();
    assert!(close(s.point, Vec3::new(0.2, 0.2, 0.0), 1e-6));
    assert!(surfaces[2].is_none());
    assert!(VertexNormals::new(&v, &[[0, 1, 3]]).is_err());

    // Closest points need static triangles.
    let boxes = [oxray_core::Aabb::new(Vec3::ZERO, Vec3::ONE)];
    let custom_gas = Gas::build(
        &BuildOptions::default(),
        &[CustomPrimitiveInput::new(oxray_core::AabbBuffer::new(&boxes)).into()],
    )
    .unwrap();
    assert_eq!(
        custom_gas.closest_point(Vec3::ZERO),
        Err(SurfaceQueryError::NotTriangles(
            BuildInputKind::CustomPrimitives
        ))
    );
    assert!(matches!(
        custom_gas.signed_distance_batch(&[Vec3::ZERO], &mut [0.0]),
        Err(SurfaceQueryError::NotTriangles(_))
    ));

    // Empty structures: nothing hit, nothing close, nothing inside.
    let empty = Gas::from_mesh(&[], &[]).unwrap();
    assert!(empty.all_hits(&ray, 4, &mut list).unwrap());
    assert!(list.is_empty());
    assert_eq!(empty.count_hits(&ray).unwrap(), 0);
    assert_eq!(empty.closest_point(Vec3::ZERO).unwrap(), None);
    assert_eq!(empty.signed_distance(Vec3::ZERO).unwrap(), f32::INFINITY);
    assert!(!empty.contains(Vec3::ZERO).unwrap());
    let mut inside = [true; 3];
    empty.contains_batch(&[Vec3::ZERO; 3], &mut inside).unwrap();
    assert_eq!(inside, [false; 3]);
    let no_instances: [Instance; 0] = [];
    let empty_ias = Ias::build(&BuildOptions::default(), &[(&no_instances[..]).into()]).unwrap();
    assert_eq!(empty_ias.count_hits(&ray).unwrap(), 0);
    empty_ias.all_hits_batch(&rays, 4, &mut all).unwrap();
    assert_eq!(all.len(), 10);
    assert!(all.all().is_empty() && (0..10).all(|i| all.is_complete(i)));
}
