//! Watertightness: rays aimed exactly at the vertices and edges of closed meshes must hit them —
//! a ray can never slip between the triangles that share an edge or a vertex (the library
//! promises watertight triangle intersection; guide §2.3 / §5.1 triangles, §13.2 closest hit).
//!
//! Each ray goes from an origin to a target point on the surface with `direction = target -
//! origin`, so the target lies at t = 1: the ray must hit with `t <= 1 + 1e-4`.

mod common;

use common::{grid_cube, icosphere, load_bunny, parse_obj, Mesh, Rng};
use glam::{DVec3, Vec3};
use oxray::cpu::Gas;
use oxray::{BuildFlags, BuildOptions, IndexBuffer, Ray, TriangleInput, VertexBuffer};
use std::collections::{HashMap, HashSet};

const TOLERANCE: f32 = 1e-4;

/// The mesh built for every CPU traversal kernel the processor runs ([`common::kernels`]);
/// rays are checked on each. Dereferences to the first, for the structure's facts.
struct Gases(Vec<Gas>);

impl std::ops::Deref for Gases {
    type Target = Gas;
    fn deref(&self) -> &Gas {
        &self.0[0]
    }
}

fn mesh_gas(mesh: &Mesh) -> Gases {
    let input = TriangleInput::new(VertexBuffer::f32x3(&mesh.positions))
        .indices(IndexBuffer::u32x3(&mesh.triangles));
    let options = BuildOptions::new(BuildFlags::PREFER_FAST_TRACE);
    Gases(
        common::kernels()
            .into_iter()
            .map(|isa| Gas::build_with_isa(isa, &options, &[input.into()]).expect("mesh builds"))
            .collect(),
    )
}

/// Collects leaks instead of stopping at the first, so that a failure says how many rays leak.
#[derive(Default)]
struct Leaks {
    rays: usize,
    failures: Vec<String>,
}

impl Leaks {
    /// Casts `origin -> target` on every kernel; the hit must exist, lie at `t <= 1 +
    /// TOLERANCE`, and (when `faces` is given) be one of those faces.
    fn check(
        &mut self,
        gases: &Gases,
        origin: Vec3,
        target: Vec3,
        faces: Option<&[usize]>,
        what: &str,
    ) {
        for gas in &gases.0 {
            self.check_one(
                gas,
                origin,
                target,
                faces,
                &format!("{} kernel, {what}", gas.isa()),
            );
        }
    }

    fn check_one(
        &mut self,
        gas: &Gas,
        origin: Vec3,
        target: Vec3,
        faces: Option<&[usize]>,
        what: &str,
    ) {
        self.rays += 1;
        let ray = Ray::new(origin, target - origin);
        if ray.validate().is_err() {
            self.failures.push(format!("{what}: invalid ray {ray:?}"));
            return;
        }
        match gas.intersect(&ray) {
            None => self
                .failures
                .push(format!("{what}: leak, no hit; ray {ray:?}")),
            Some(h) => {
                if h.t.is_nan() || h.t > 1.0 + TOLERANCE {
                    self.failures.push(format!(
                        "{what}: hit at t = {} > 1 + {TOLERANCE}; {h:?}, ray {ray:?}",
                        h.t
                    ));
                } else if let Some(f) = faces {
                    if !f.contains(&(h.primitive_index as usize)) {
                        self.failures.push(format!(
                            "{what}: hit face {} is not one of {f:?}; ray {ray:?}",
                            h.primitive_index
                        ));
                    }
                }
            }
        }
        // A shadow ray to just past the target is occluded too.
        let shadow = Ray::with_interval(origin, target - origin, 0.0, 1.0 + TOLERANCE);
        if !gas.occluded(&shadow) {
            self.failures
                .push(format!("{what}: occluded() leaks; ray {shadow:?}"));
        }
    }

    fn assert_none(&self, name: &str) {
        assert!(
            self.failures.is_empty(),
            "{name}: {} of {} rays failed; first ones:\n{}",
            self.failures.len(),
            self.rays,
            self.failures
                .iter()
                .take(10)
                .cloned()
                .collect::<Vec<_>>()
                .join("\n")
        );
        println!("{name}: {} rays, none leaked", self.rays);
    }
}

/// Faces incident to each vertex.
fn vertex_faces(mesh: &Mesh) -> Vec<Vec<usize>> {
    let mut vf = vec![Vec::new(); mesh.positions.len()];
    for (f, t) in mesh.triangles.iter().enumerate() {
        for &k in t {
            vf[k as usize].push(f);
        }
    }
    vf
}

fn sorted_edges(mesh: &Mesh) -> Vec<((u32, u32), Vec<usize>)> {
    let mut e: Vec<_> = mesh.edge_map().into_iter().collect();
    e.sort();
    e
}

// ---------------------------------------------------------------------------------------------
// Icosphere
// ---------------------------------------------------------------------------------------------

fn icosphere_case(subdivisions: u32) {
    let mesh = icosphere(subdivisions);
    let gas = mesh_gas(&mesh);
    let vf = vertex_faces(&mesh);
    let edges = sorted_edges(&mesh);
    let mut rng = Rng::new(0x1c0 + subdivisions as u64);
    let mut leaks = Leaks::default();
    let outside = [0.05f32, 0.5, 3.0];

    // Vertices: from the centre, and from outside along the normal (and slightly tilted).
    for (i, v) in mesh.positions.iter().enumerate() {
        let p = Vec3::from(*v);
        let n = p.normalize();
        leaks.check(
            &gas,
            Vec3::ZERO,
            p,
            Some(&vf[i]),
            &format!("vertex {i} from the centre"),
        );
        for k in outside {
            leaks.check(
                &gas,
                p + n * k,
                p,
                Some(&vf[i]),
                &format!("vertex {i} from outside, k = {k}"),
            );
        }
        let tilt = (n + rng.dir() * 0.2).normalize();
        leaks.check(
            &gas,
            p + tilt,
            p,
            None,
            &format!("vertex {i} from outside, tilted"),
        );
    }

    // Edges: the midpoint and random points along each shared edge.
    for ((a, b), faces) in &edges {
        assert_eq!(faces.len(), 2, "the icosphere is closed");
        let (pa, pb) = (mesh.v(*a), mesh.v(*b));
        // In f32 a point near an end of the edge may round onto a face of that end's fan.
        let near: Vec<usize> = vf[*a as usize]
            .iter()
            .chain(&vf[*b as usize])
            .copied()
            .collect();
        for s in [
            0.5f32,
            rng.f32(),
            rng.range(0.0, 0.01),
            rng.range(0.99, 1.0),
        ] {
            let p = pa + (pb - pa) * s;
            let n = p.normalize();
            let what = format!("edge {a}-{b} at s = {s}");
            let faces = if s == 0.5 {
                faces.as_slice()
            } else {
                near.as_slice()
            };
            leaks.check(
                &gas,
                Vec3::ZERO,
                p,
                Some(faces),
                &format!("{what} from the centre"),
            );
            for k in outside {
                leaks.check(
                    &gas,
                    p + n * k,
                    p,
                    Some(faces),
                    &format!("{what} from outside, k = {k}"),
                );
            }
            // From points inside other than the centre.
            let o = rng.vec3(-0.4, 0.4);
            leaks.check(&gas, o, p, None, &format!("{what} from inside at {o}"));
        }
    }
    assert!(leaks.rays > 5000);
    leaks.assert_none(&format!("icosphere({subdivisions})"));
}

/// Guide §5.1 / §13.2: no ray aimed at a vertex or an edge of a closed icosphere (subdivision 3)
/// slips through.
#[test]
fn icosphere_3_is_watertight_at_vertices_and_edges_5_1() {
    icosphere_case(3);
}

/// Guide §5.1 / §13.2: the same on a finer icosphere (subdivision 4).
#[test]
fn icosphere_4_is_watertight_at_vertices_and_edges_5_1() {
    icosphere_case(4);
}

// ---------------------------------------------------------------------------------------------
// Axis-aligned cube
// ---------------------------------------------------------------------------------------------

/// Guide §5.1 / §13.2: axis-parallel rays through every grid vertex and edge midpoint of an
/// axis-aligned closed cube (each face an 8 x 8 grid of split quads), from outside along each of
/// the six directions and from inside; the boundary rows run along the cube's edges, in the
/// plane of the neighbouring face.
#[test]
fn cube_is_watertight_for_axis_parallel_rays_5_1() {
    let n = 8u32;
    let mesh = grid_cube(n);
    let gas = mesh_gas(&mesh);
    let mut leaks = Leaks::default();
    // Grid coordinates at vertices and at edge midpoints (half steps).
    let coords: Vec<f32> = (0..=2 * n).map(|i| -1.0 + i as f32 / n as f32).collect();
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            for &x in &coords {
                for &y in &coords {
                    let mut p = Vec3::ZERO;
                    p[axis] = sign;
                    p[(axis + 1) % 3] = x;
                    p[(axis + 2) % 3] = y;
                    let mut out = Vec3::ZERO;
                    out[axis] = sign;
                    let what = format!("face {axis}{sign:+} at ({x}, {y})");
                    leaks.check(
                        &gas,
                        p + out * 4.0,
                        p,
                        None,
                        &format!("{what} from outside"),
                    );
                    leaks.check(
                        &gas,
                        p + out * 0.125,
                        p,
                        None,
                        &format!("{what} from just outside"),
                    );
                    // From inside: from the opposite face's plane (on the surface itself when
                    // x or y is +-1) and from the middle.
                    leaks.check(&gas, p - out, p, None, &format!("{what} from the middle"));
                    leaks.check(
                        &gas,
                        p - out * 2.0,
                        p,
                        None,
                        &format!("{what} from the opposite face"),
                    );
                }
            }
        }
    }
    // With a direction of length 4 from 4 units away, the face is at t = 1 exactly.
    let ray = Ray::new(Vec3::new(0.25, -0.5, -5.0), Vec3::new(0.0, 0.0, 4.0));
    assert_eq!(gas.intersect(&ray).map(|h| h.t), Some(1.0));
    assert!(leaks.rays >= 6 * 17 * 17 * 4);
    leaks.assert_none("cube, axis-parallel");
}

/// Guide §5.1 / §13.2: rays grazing along the cube's edges and along grid lines in a face's
/// plane reach the perpendicular face exactly on its boundary edge or corner, and must hit it.
#[test]
fn cube_rays_grazing_along_edges_hit_5_1() {
    let n = 4u32;
    let mesh = grid_cube(n);
    let gas = mesh_gas(&mesh);
    let mut leaks = Leaks::default();
    let grid: Vec<f32> = (0..=2 * n).map(|i| -1.0 + i as f32 / n as f32).collect();
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            // Travel along -sign * e_axis towards the face `axis = sign`.
            let mut out = Vec3::ZERO;
            out[axis] = sign;
            let (a1, a2) = ((axis + 1) % 3, (axis + 2) % 3);
            for &s in &[-1.0f32, 1.0] {
                for &x in &grid {
                    // In the plane `a1 = s` (a neighbouring face), along a grid line or edge.
                    let mut p = out;
                    p[a1] = s;
                    p[a2] = x;
                    leaks.check(
                        &gas,
                        p + out * 3.0,
                        p,
                        None,
                        &format!("graze a{a1}={s} to {p}"),
                    );
                    let mut q = out;
                    q[a2] = s;
                    q[a1] = x;
                    leaks.check(
                        &gas,
                        q + out * 3.0,
                        q,
                        None,
                        &format!("graze a{a2}={s} to {q}"),
                    );
                }
            }
        }
    }
    // Along the twelve edges of the cube, and diagonally within a face plane to a corner.
    for c in 0..8 {
        let corner = Vec3::new(
            if c & 1 == 0 { -1.0 } else { 1.0 },
            if c & 2 == 0 { -1.0 } else { 1.0 },
            if c & 4 == 0 { -1.0 } else { 1.0 },
        );
        for axis in 0..3 {
            let mut out = Vec3::ZERO;
            out[axis] = corner[axis];
            leaks.check(
                &gas,
                corner + out * 2.0,
                corner,
                None,
                &format!("along an edge to {corner}"),
            );
            let mut diag = corner;
            diag[axis] = 0.0;
            leaks.check(
                &gas,
                corner + diag * 2.0,
                corner,
                None,
                &format!("diagonal to {corner}"),
            );
        }
    }
    leaks.assert_none("cube, grazing");
}

// ---------------------------------------------------------------------------------------------
// Stanford bunny (when ../shared/data is present)
// ---------------------------------------------------------------------------------------------

fn unit_normal(mesh: &Mesh, f: usize) -> Option<DVec3> {
    let n = mesh.face_normal(f);
    (n.length() > 0.0).then(|| n.normalize())
}

/// Guide §5.1 / §13.2: on the bunny, rays aimed from outside, along the averaged normal, at
/// the midpoints of interior edges (two faces whose normals agree) must hit.
#[test]
fn bunny_is_watertight_at_interior_edges_5_1() {
    let Some(mesh) = load_bunny("bunny_is_watertight_at_interior_edges_5_1") else {
        return;
    };
    let gas = mesh_gas(&mesh);
    let diag = (gas.bounds().max - gas.bounds().min).length();
    let mut candidates = Vec::new();
    for ((a, b), faces) in sorted_edges(&mesh) {
        if faces.len() != 2 {
            continue;
        }
        let (Some(n1), Some(n2)) = (unit_normal(&mesh, faces[0]), unit_normal(&mesh, faces[1]))
        else {
            continue;
        };
        if n1.dot(n2) > 0.0 {
            candidates.push((a, b, faces, (n1 + n2).normalize().as_vec3()));
        }
    }
    assert!(
        candidates.len() > 10_000,
        "only {} interior edges",
        candidates.len()
    );
    let mut rng = Rng::new(0xb0b);
    let mut leaks = Leaks::default();
    for _ in 0..3000 {
        let (a, b, faces, n) = &candidates[rng.below(candidates.len())];
        let m = (mesh.v(*a) + mesh.v(*b)) * 0.5;
        for k in [0.01f32, 0.3] {
            leaks.check(
                &gas,
                m + *n * (k * diag),
                m,
                None,
                &format!("edge {a}-{b} ({faces:?}), k = {k}"),
            );
        }
    }
    leaks.assert_none("bunny edges");
}

/// Guide §5.1 / §13.2: on the bunny, rays aimed from outside at interior vertices (closed fan,
/// every face normal agreeing with the averaged normal) must hit.
#[test]
fn bunny_is_watertight_at_interior_vertices_5_1() {
    let Some(mesh) = load_bunny("bunny_is_watertight_at_interior_vertices_5_1") else {
        return;
    };
    let gas = mesh_gas(&mesh);
    let diag = (gas.bounds().max - gas.bounds().min).length();
    let edges: HashMap<(u32, u32), Vec<usize>> = mesh.edge_map();
    let vf = vertex_faces(&mesh);
    let mut candidates = Vec::new();
    for (v, faces) in vf.iter().enumerate() {
        if faces.len() < 3 {
            continue;
        }
        let Some(normals) = faces
            .iter()
            .map(|&f| unit_normal(&mesh, f))
            .collect::<Option<Vec<_>>>()
        else {
            continue;
        };
        let avg = normals.iter().sum::<DVec3>();
        if avg.length() == 0.0 {
            continue;
        }
        let avg = avg.normalize();
        if normals.iter().any(|n| n.dot(avg) <= 0.0) {
            continue;
        }
        if closed_fan(&mesh, &edges, v as u32, faces) {
            candidates.push((v, avg.as_vec3()));
        }
    }
    assert!(
        candidates.len() > 10_000,
        "only {} interior vertices",
        candidates.len()
    );
    let mut rng = Rng::new(0xbe11);
    let mut leaks = Leaks::default();
    for _ in 0..3000 {
        let (v, n) = candidates[rng.below(candidates.len())];
        let p = mesh.v(v as u32);
        for k in [0.01f32, 0.3] {
            leaks.check(
                &gas,
                p + n * (k * diag),
                p,
                None,
                &format!("vertex {v}, k = {k}"),
            );
        }
    }
    leaks.assert_none("bunny vertices");
}

/// Whether the faces around `v` form one closed cycle: every edge from `v` is shared by exactly
/// two of them, and walking from face to face across those edges visits all of them.
fn closed_fan(
    mesh: &Mesh,
    edges: &HashMap<(u32, u32), Vec<usize>>,
    v: u32,
    faces: &[usize],
) -> bool {
    let spokes: HashSet<u32> = faces
        .iter()
        .flat_map(|&f| mesh.triangles[f])
        .filter(|&w| w != v)
        .collect();
    if spokes.len() != faces.len() {
        return false;
    }
    for &w in &spokes {
        match edges.get(&(v.min(w), v.max(w))) {
            Some(f) if f.len() == 2 => {}
            _ => return false,
        }
    }
    // Walk the cycle.
    let mut seen = HashSet::new();
    let mut face = faces[0];
    let mut came_from = u32::MAX;
    while seen.insert(face) {
        let t = mesh.triangles[face];
        let Some(w) = t.iter().copied().find(|&w| w != v && w != came_from) else {
            return false;
        };
        let f = &edges[&(v.min(w), v.max(w))];
        face = if f[0] == face { f[1] } else { f[0] };
        came_from = w;
    }
    seen.len() == faces.len() && face == faces[0]
}

// ---------------------------------------------------------------------------------------------
// The mesh helpers themselves
// ---------------------------------------------------------------------------------------------

#[test]
fn obj_reader_handles_slashes_and_polygons() {
    let m = parse_obj(
        "# comment\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nf 1/1/1 2/2/1 3/3/1 4/4/1\nf 1//1 3//1 4//1\n",
    )
    .unwrap();
    assert_eq!(m.positions.len(), 4);
    assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 2, 3]]);
    assert!(parse_obj("v 0 0 0\nf 1 2 3\n").is_err());
}

fn assert_closed_and_outward(m: &Mesh) {
    let edges = m.edge_map();
    assert!(edges.values().all(|f| f.len() == 2), "not closed");
    assert_eq!(
        m.positions.len() as i64 - edges.len() as i64 + m.triangles.len() as i64,
        2,
        "Euler characteristic"
    );
    for f in 0..m.triangles.len() {
        let c = m.triangles[f]
            .iter()
            .map(|&k| m.v(k).as_dvec3())
            .sum::<DVec3>();
        assert!(m.face_normal(f).dot(c) > 0.0, "face {f} faces inwards");
    }
}

#[test]
fn test_meshes_are_closed_and_outward() {
    for s in 0..4 {
        let m = icosphere(s);
        assert_eq!(m.triangles.len(), 20 * 4usize.pow(s));
        assert_closed_and_outward(&m);
    }
    let m = grid_cube(3);
    assert_eq!(m.triangles.len(), 6 * 9 * 2);
    assert_eq!(m.positions.len(), 6 * 16 - 12 * 4 + 8);
    assert_closed_and_outward(&m);
}

/// The bunny, when present, is read completely.
#[test]
fn bunny_loads() {
    let Some(mesh) = load_bunny("bunny_loads") else {
        return;
    };
    assert_eq!((mesh.positions.len(), mesh.triangles.len()), (35947, 69451));
    let gas = mesh_gas(&mesh);
    assert_eq!(gas.num_primitives(), 69451);
}
