//! The closest point of a triangle GAS to a query point, the signed distance, and the inside
//! test of closed meshes.
//!
//! The search walks the GAS's 4-wide BVH nearest box first, with the squared distance from the
//! point to each child box as its key, and skips every box farther than the best triangle so
//! far; a triangle's closest point is Ericson's region test (Real-Time Collision Detection,
//! §5.1.5). Among triangles at the same distance the lowest primitive wins, whatever the
//! traversal order.
//!
//! The sign of the signed distance is that of `(p - q) · n`, with `q` the closest point and
//! `n` the angle-weighted pseudo-normal at `q` (Bærentzen and Aanæs, "Signed distance
//! computation using the angle weighted pseudonormal", 2005): the sum of the normals of every
//! triangle that `q` lies on, each weighted by the triangle's angle at `q` (its angle at a
//! vertex, π on an edge, 2π inside). The triangles at `q` are found by a second, very short walk
//! of the BVH, so no adjacency is needed. For a closed, consistently oriented mesh (triangles
//! counter-clockwise seen from outside: the outward geometric normals of
//! [`SurfaceHit`](super::SurfaceHit)) the sign is exact: negative inside, positive outside,
//! even where `q` is on an edge or a vertex. On an open or non-manifold mesh the sign only says
//! on which side of the nearest part of the surface the point lies (positive on its front),
//! which is no inside test: use [`Gas::count_hits`] parity along several rays there.

use super::{check_point, par_try_batch, SurfaceQueryError};
use crate::Gas;
use glam::Vec3;
use oxray_bvh::{GasKind, TRAVERSAL_STACK_SIZE};

/// The closest point of a triangle GAS to a query point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClosestPoint {
    /// The closest point, on the surface.
    pub point: Vec3,
    /// Its (unsigned) distance to the query point.
    pub distance: f32,
    /// The triangle it lies on: the index within its build input plus the input's primitive
    /// index offset, as [`Hit::primitive_index`](oxray_core::Hit::primitive_index).
    pub primitive_index: u32,
    /// The build input of that triangle.
    pub build_input: u32,
    /// Barycentrics of the point in its triangle, as a hit's:
    /// `point = (1 - u - v) v0 + u v1 + v v2`.
    pub u: f32,
    /// The second barycentric.
    pub v: f32,
}

/// The closest point of triangle `[a, b, c]` to `p`, and its barycentrics `(u, v)` (weights of
/// `b` and `c`). Exact at the vertices (the vertex itself is returned) and on the edges' lines.
#[inline]
fn closest_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> (Vec3, f32, f32) {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, 0.0, 0.0);
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return (b, 1.0, 0.0);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let u = d1 / (d1 - d3);
        return (a + ab * u, u, 0.0);
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return (c, 0.0, 1.0);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let v = d2 / (d2 - d6);
        return (a + ac * v, 0.0, v);
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        let v = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (b + (c - b) * v, 1.0 - v, v);
    }
    let denom = 1.0 / (va + vb + vc);
    let u = vb * denom;
    let v = vc * denom;
    (a + ab * u + ac * v, u, v)
}

/// Squared distances from `p` to the four child boxes of a node (NaN for unused lanes, whose
/// empty boxes no radius reaches).
#[inline(always)]
fn box_dist2(node: &oxray_bvh::Bvh4Node, p: Vec3) -> [f32; 4] {
    let b = &node.bounds;
    std::array::from_fn(|l| {
        let mut d2 = 0.0f32;
        for axis in 0..3 {
            let (lo, hi) = (b[axis][l], b[axis + 3][l]);
            if lo.is_nan() || hi.is_nan() || lo > hi {
                return f32::NAN;
            }
            let d = (lo - p[axis]).max(p[axis] - hi).max(0.0);
            d2 += d * d;
        }
        d2
    })
}

/// Walks the BVH of `gas` nearest box first, handing every active triangle slot in a box at
/// squared distance at most `*radius2` to `visit`, which may shrink `*radius2`.
fn walk(gas: &Gas, p: Vec3, radius2: &mut f32, mut visit: impl FnMut(u32, &mut f32)) {
    let nodes = &gas.bvh.nodes;
    if nodes.is_empty() {
        return;
    }
    // (child, count, squared distance) as the kernel's stack entries.
    let mut stack = [(0u32, 0u32, 0.0f32); TRAVERSAL_STACK_SIZE + 4];
    let mut sp = 1usize;
    while sp > 0 {
        sp -= 1;
        let (child, count, d2) = stack[sp];
        if d2 > *radius2 {
            continue;
        }
        if count > 0 {
            for slot in child..child + count {
                if gas.slot_is_active(slot as usize) {
                    visit(slot, radius2);
                }
            }
            continue;
        }
        let node = &nodes[child as usize];
        let dist = box_dist2(node, p);
        let base = sp;
        for l in 0..4 {
            if dist[l] <= *radius2 {
                stack[sp] = (node.child[l], node.count[l], dist[l]);
                sp += 1;
            }
        }
        // Farthest first, so that the nearest is popped next.
        stack[base..sp].sort_unstable_by(|x, y| y.2.total_cmp(&x.2));
    }
}

/// The triangle of leaf slot `slot`.
#[inline(always)]
fn triangle(gas: &Gas, slot: u32) -> [Vec3; 3] {
    let s = slot as usize;
    gas.triangles[s / 4].get(s % 4).map(Vec3::from)
}

/// Checks that the GAS holds static triangles.
fn check_gas(gas: &Gas) -> Result<(), SurfaceQueryError> {
    if gas.kind != GasKind::Triangles {
        return Err(SurfaceQueryError::NotTriangles(gas.data().kind()));
    }
    if gas.motion.is_some() {
        return Err(SurfaceQueryError::Unsupported("a GAS with motion"));
    }
    Ok(())
}

/// The nearest triangle to `p` within `max_distance`: its slot, global id, point, `u`, `v`,
/// squared distance.
fn nearest(gas: &Gas, p: Vec3, max_distance: f32) -> Option<(u32, u32, Vec3, f32, f32, f32)> {
    let mut best: Option<(u32, u32, Vec3, f32, f32, f32)> = None;
    let mut radius2 = max_distance * max_distance;
    walk(gas, p, &mut radius2, |slot, radius2| {
        let [a, b, c] = triangle(gas, slot);
        let (q, u, v) = closest_on_triangle(p, a, b, c);
        let d2 = (p - q).length_squared();
        let id = gas.slot_prim[slot as usize];
        let better = match best {
            None => d2 <= *radius2,
            Some((_, best_id, .., best_d2)) => d2 < best_d2 || (d2 == best_d2 && id < best_id),
        };
        if better {
            best = Some((slot, id, q, u, v, d2));
            *radius2 = d2;
        }
    });
    best
}

/// The angle-weighted pseudo-normal (unnormalised) at `q`, the closest point to `p` at
/// distance `d`: every triangle within a rounding tolerance of `q`, each once.
fn pseudo_normal(gas: &Gas, p: Vec3, q: Vec3, d: f32) -> Vec3 {
    let tol = 64.0 * f32::EPSILON * (q.abs().max_element() + d) + f32::MIN_POSITIVE;
    let mut radius2 = (d + tol) * (d + tol);
    // Spatial splits reference a triangle from several leaves: count each id once. Beyond the
    // table (a vertex of very high valence with splits), repeats are counted again.
    let mut seen = [0u32; 64];
    let mut n_seen = 0usize;
    let mut sum = Vec3::ZERO;
    walk(gas, p, &mut radius2, |slot, _| {
        let [a, b, c] = triangle(gas, slot);
        let (q2, u, v) = closest_on_triangle(p, a, b, c);
        if (q2 - q).length() > tol {
            return;
        }
        let id = gas.slot_prim[slot as usize];
        if seen[..n_seen].contains(&id) {
            return;
        }
        if n_seen < seen.len() {
            seen[n_seen] = id;
            n_seen += 1;
        }
        let n = (b - a).cross(c - a).normalize_or_zero();
        sum += n * angle_at(a, b, c, u, v);
    });
    sum
}

/// The angle of triangle `[a, b, c]` at its point of barycentrics `(u, v)`: its angle at a
/// vertex, π on an edge, 2π inside (barycentrics within 1e-5 of 0 count as 0).
fn angle_at(a: Vec3, b: Vec3, c: Vec3, u: f32, v: f32) -> f32 {
    const EPS: f32 = 1e-5;
    let w = [1.0 - u - v, u, v];
    let zeros = w.iter().filter(|&&x| x <= EPS).count();
    let angle = |o: Vec3, x: Vec3, y: Vec3| {
        (x - o)
            .normalize_or_zero()
            .dot((y - o).normalize_or_zero())
            .clamp(-1.0, 1.0)
            .acos()
    };
    match zeros {
        0 => std::f32::consts::TAU,
        1 => std::f32::consts::PI,
        _ => {
            // The vertex with the largest weight.
            if w[0] >= w[1] && w[0] >= w[2] {
                angle(a, b, c)
            } else if w[1] >= w[2] {
                angle(b, c, a)
            } else {
                angle(c, a, b)
            }
        }
    }
}

impl Gas {
    /// The closest point of this triangle GAS to `point` (every active triangle of every build
    /// input), with its distance, triangle and barycentrics; `None` for an empty GAS.
    ///
    /// Errors: a non-finite point, a GAS of other primitives
    /// ([`SurfaceQueryError::NotTriangles`]) or with motion
    /// ([`SurfaceQueryError::Unsupported`]).
    ///
    /// ```
    /// use oxray_cpu::Gas;
    /// use glam::Vec3;
    /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    /// let gas = Gas::from_mesh(&v, &[[0, 1, 2]])?;
    /// let c = gas.closest_point(Vec3::new(0.25, 0.25, 2.0))?.unwrap();
    /// assert_eq!((c.point, c.distance, c.primitive_index), (Vec3::new(0.25, 0.25, 0.0), 2.0, 0));
    /// assert_eq!((c.u, c.v), (0.25, 0.25));
    /// // Beyond the edge x + y = 1: the closest point is on that edge.
    /// let c = gas.closest_point(Vec3::new(1.0, 1.0, 0.0))?.unwrap();
    /// assert!((c.point - Vec3::new(0.5, 0.5, 0.0)).length() < 1e-6);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn closest_point(&self, point: Vec3) -> Result<Option<ClosestPoint>, SurfaceQueryError> {
        self.closest_point_within(point, f32::INFINITY)
    }

    /// [`closest_point`](Self::closest_point) among the triangles within `max_distance` of
    /// `point` (`None` if there is none): the search skips everything farther, as Embree's
    /// point query with a radius. A NaN or negative `max_distance` finds nothing.
    pub fn closest_point_within(
        &self,
        point: Vec3,
        max_distance: f32,
    ) -> Result<Option<ClosestPoint>, SurfaceQueryError> {
        check_point(point)?;
        check_gas(self)?;
        if max_distance.is_nan() || max_distance < 0.0 {
            return Ok(None);
        }
        Ok(
            nearest(self, point, max_distance).map(|(_, id, q, u, v, d2)| {
                let (primitive_index, _, build_input) = self.resolve_global(id);
                ClosestPoint {
                    point: q,
                    distance: d2.sqrt(),
                    primitive_index,
                    build_input,
                    u,
                    v,
                }
            }),
        )
    }

    /// The closest points of a batch of points, in parallel (`out[i]` for `points[i]`): the
    /// same as point by point, whatever the number of threads. The first failing query (the
    /// lowest index) is the error; every other output is written.
    pub fn closest_point_batch(
        &self,
        points: &[Vec3],
        out: &mut [Option<ClosestPoint>],
    ) -> Result<(), SurfaceQueryError> {
        check_gas(self)?;
        par_try_batch(points.len(), out, |i| self.closest_point(points[i]))
    }

    /// The signed distance from `point` to the surface: negative inside a closed mesh,
    /// positive outside, zero on the surface; `+inf` for an empty GAS. The sign comes from the
    /// angle-weighted pseudo-normal at the closest point (see the [module](self) docs), which
    /// is exact for closed, consistently oriented meshes (counter-clockwise seen from outside);
    /// on open meshes it tells the side of the nearest surface, front positive. Errors as
    /// [`closest_point`](Self::closest_point).
    ///
    /// ```
    /// use oxray_cpu::Gas;
    /// use glam::Vec3;
    /// // A tetrahedron, counter-clockwise seen from outside.
    /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    /// let gas = Gas::from_mesh(&v, &[[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])?;
    /// assert!(gas.signed_distance(Vec3::splat(0.1))? < 0.0);
    /// assert_eq!(gas.signed_distance(Vec3::new(0.2, 0.2, -1.0))?, 1.0);
    /// // Nearest to a vertex or an edge: still the right sign.
    /// assert!(gas.signed_distance(Vec3::splat(-1.0))? > 0.0);
    /// assert!(gas.contains(Vec3::new(0.2, 0.2, 0.2))?);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn signed_distance(&self, point: Vec3) -> Result<f32, SurfaceQueryError> {
        check_point(point)?;
        check_gas(self)?;
        let Some((slot, _, q, u, v, d2)) = nearest(self, point, f32::INFINITY) else {
            return Ok(f32::INFINITY);
        };
        let d = d2.sqrt();
        if d == 0.0 {
            return Ok(0.0);
        }
        let [a, b, c] = triangle(self, slot);
        let n = if angle_at(a, b, c, u, v) == std::f32::consts::TAU {
            // Inside the triangle: its normal is the pseudo-normal.
            (b - a).cross(c - a)
        } else {
            pseudo_normal(self, point, q, d)
        };
        Ok(if (point - q).dot(n) < 0.0 { -d } else { d })
    }

    /// [`signed_distance`](Self::signed_distance) of a batch of points, in parallel. The first
    /// failing query (the lowest index) is the error; every other output is written.
    pub fn signed_distance_batch(
        &self,
        points: &[Vec3],
        out: &mut [f32],
    ) -> Result<(), SurfaceQueryError> {
        check_gas(self)?;
        par_try_batch(points.len(), out, |i| self.signed_distance(points[i]))
    }

    /// Whether `point` lies strictly inside the closed mesh: a negative
    /// [`signed_distance`](Self::signed_distance) (points on the surface are not inside;
    /// nothing is inside an empty GAS).
    pub fn contains(&self, point: Vec3) -> Result<bool, SurfaceQueryError> {
        Ok(self.signed_distance(point)? < 0.0)
    }

    /// [`contains`](Self::contains) of a batch of points, in parallel.
    pub fn contains_batch(
        &self,
        points: &[Vec3],
        out: &mut [bool],
    ) -> Result<(), SurfaceQueryError> {
        check_gas(self)?;
        par_try_batch(points.len(), out, |i| self.contains(points[i]))
    }
}
