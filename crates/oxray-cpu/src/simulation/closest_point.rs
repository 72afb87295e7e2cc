//! The closest point of a triangle GAS to a query point, the signed distance, and the inside
//! test of closed meshes.
//!
//! The search walks the GAS's 4-wide BVH nearest box first, with the squared distance from the
//! point to each child box as its key, and skips every box farther than the best triangle so
//! far; a triangle's closest point is Ericson's region test (Real-Time Collision Detection,
//! §5.1.5). Among triangles at the same distance the lowest primitive wins, whatever the
//! traversal order. The region test runs only on the triangles of a leaf's 4-wide block whose
//! lower bound (the larger of the squared distances to the triangle's box and to its plane,
//! computed four lanes at a time) is within the best distance plus a rounding margin, so the
//! bounds change the cost, never the result.
//!
//! The sign of the signed distance is that of `(p - q) · n`, with `q` the closest point and
//! `n` the angle-weighted pseudo-normal at `q` (Bærentzen and Aanæs, "Signed distance
//! computation using the angle weighted pseudonormal", 2005): the sum of the normals of every
//! triangle that `q` lies on, each weighted by the triangle's angle at `q` (its angle at a
//! vertex, π on an edge, 2π inside). The triangles at `q` are gathered during the search
//! itself, whose radius is then the best distance grown by the tolerance that decides which
//! triangles `q` lies on (a fixed array of 32; beyond it, a second walk of radius `d` plus
//! that tolerance finds them), so no adjacency is needed. For a closed, consistently oriented mesh (triangles
//! counter-clockwise seen from outside: the outward geometric normals of
//! [`SurfaceHit`](super::SurfaceHit)) the sign is exact: negative inside, positive outside,
//! even where `q` is on an edge or a vertex. On an open or non-manifold mesh the sign only says
//! on which side of the nearest part of the surface the point lies (positive on its front),
//! which is no inside test: use [`Gas::count_hits`] parity along several rays there.

use super::{check_point, par_try_batch, ClosestPoint, SurfaceQueryError};
use crate::Gas;
use glam::Vec3;
use oxray_bvh::{GasKind, Triangle4, NO_PRIMITIVE, TRAVERSAL_STACK_SIZE};

/// The closest point of triangle `[a, b, c]` to `p`, and its barycentrics `(u, v)` (weights of
/// `b` and `c`). Exact at the vertices (the vertex itself is returned) and on the edges' lines.
#[inline(always)]
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
/// empty boxes no radius reaches). Lane-wise arithmetic without branches, so that it compiles
/// to 4-wide instructions.
#[inline(always)]
fn box_dist2(node: &oxray_bvh::Bvh4Node, p: Vec3) -> [f32; 4] {
    let b = &node.bounds;
    let mut d2 = [0.0f32; 4];
    let mut used = [true; 4];
    for axis in 0..3 {
        for l in 0..4 {
            let (lo, hi) = (b[axis][l], b[axis + 3][l]);
            // False for NaN bounds and for the empty box of an unused lane.
            used[l] &= lo <= hi;
            let d = (lo - p[axis]).max(p[axis] - hi).max(0.0);
            d2[l] += d * d;
        }
    }
    std::array::from_fn(|l| if used[l] { d2[l] } else { f32::NAN })
}

/// Walks the BVH of `gas` nearest box first, handing the slot range (first slot, count) of
/// every leaf whose box is at squared distance at most `*radius2` to `visit`, which may shrink
/// `*radius2`.
#[inline(always)]
fn walk(gas: &Gas, p: Vec3, radius2: &mut f32, mut visit: impl FnMut(u32, u32, &mut f32)) {
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
            visit(child, count, radius2);
            continue;
        }
        let node = &nodes[child as usize];
        let dist = box_dist2(node, p);
        let base = sp;
        for l in 0..4 {
            if dist[l] <= *radius2 {
                // Insertion, farthest first, so that the nearest is popped next.
                let e = (node.child[l], node.count[l], dist[l]);
                let mut j = sp;
                while j > base && stack[j - 1].2 < e.2 {
                    stack[j] = stack[j - 1];
                    j -= 1;
                }
                stack[j] = e;
                sp += 1;
            }
        }
    }
}

/// Four lanes of `f32`, for the lane-wise bounds below (plain arrays: the compiler keeps them
/// in 4-wide registers).
type F4 = [f32; 4];

#[inline(always)]
fn lanes(f: impl FnMut(usize) -> f32) -> F4 {
    std::array::from_fn(f)
}

/// Lower bounds of the squared distances from `p` to the four triangles of `block`: the larger
/// of the squared distance to the triangle's box and, where the triangle is not a sliver (the
/// sine of its angle at its first vertex is at least 1/16), to its plane. Within rounding
/// (see [`bound_margin`]) a triangle is never nearer than its bound. Lanes with a NaN
/// coordinate get a bound from the other coordinates or NaN; the caller checks activity.
#[inline(always)]
fn lower_bounds(block: &Triangle4, p: Vec3) -> F4 {
    let v = &block.v;
    let mut box_d2 = [0.0f32; 4];
    for axis in 0..3 {
        let pa = p[axis];
        let lo = lanes(|l| v[0][axis][l].min(v[1][axis][l]).min(v[2][axis][l]));
        let hi = lanes(|l| v[0][axis][l].max(v[1][axis][l]).max(v[2][axis][l]));
        for l in 0..4 {
            let d = (lo[l] - pa).max(pa - hi[l]).max(0.0);
            box_d2[l] += d * d;
        }
    }
    let e1: [F4; 3] = std::array::from_fn(|k| lanes(|l| v[1][k][l] - v[0][k][l]));
    let e2: [F4; 3] = std::array::from_fn(|k| lanes(|l| v[2][k][l] - v[0][k][l]));
    let ap: [F4; 3] = std::array::from_fn(|k| lanes(|l| p[k] - v[0][k][l]));
    let n: [F4; 3] = std::array::from_fn(|k| {
        let (i, j) = ((k + 1) % 3, (k + 2) % 3);
        lanes(|l| e1[i][l] * e2[j][l] - e1[j][l] * e2[i][l])
    });
    let dot = |a: &[F4; 3], b: &[F4; 3]| {
        lanes(|l| a[0][l] * b[0][l] + a[1][l] * b[1][l] + a[2][l] * b[2][l])
    };
    let (nn, s, l1, l2) = (dot(&n, &n), dot(&n, &ap), dot(&e1, &e1), dot(&e2, &e2));
    lanes(|l| {
        let plane = if 256.0 * nn[l] >= l1[l] * l2[l] {
            s[l] * s[l] / nn[l]
        } else {
            0.0
        };
        // `max` keeps the box bound where the plane bound is NaN.
        box_d2[l].max(plane)
    })
}

/// The absolute rounding margin of [`lower_bounds`] for a query at `p` in `gas`: 256 ulps of
/// the largest coordinate involved (the query's and the structure's), far above the few ulps
/// either the bounds or [`closest_on_triangle`] can be off by.
#[inline]
fn bound_margin(gas: &Gas, p: Vec3) -> f32 {
    let b = &gas.bounds;
    let scale = p.abs().max_element() + b.min.abs().max(b.max.abs()).max_element();
    256.0 * f32::EPSILON * scale.max(f32::MIN_POSITIVE)
}

/// The bound below which a triangle may be within squared distance `radius2`: `radius2`
/// grown by `margin` on the distance.
#[inline]
fn bound_limit(radius2: f32, margin: f32) -> f32 {
    let r = radius2.sqrt() + margin;
    r * r
}

/// Hands every active triangle of the slot range `first .. first + count` whose lower bound
/// is at most `*limit` to `visit(slot, [a, b, c])`, which may lower `*limit`.
#[inline(always)]
fn near_triangles(
    gas: &Gas,
    p: Vec3,
    first: u32,
    count: u32,
    limit: &mut f32,
    mut visit: impl FnMut(u32, [Vec3; 3], &mut f32),
) {
    let (start, end) = (first as usize, (first + count) as usize);
    // Every leaf starts a block.
    let mut slot = start;
    while slot < end {
        let block = &gas.triangles[slot / 4];
        let bounds = lower_bounds(block, p);
        for (l, &bound) in bounds.iter().enumerate().take(end - slot) {
            let s = slot + l;
            // As `slot_is_active` for triangles: a primitive, with no NaN first coordinate.
            if bound <= *limit && gas.slot_prim[s] != NO_PRIMITIVE && !block.v[0][0][l].is_nan() {
                let v = &block.v;
                let t = std::array::from_fn(|k| Vec3::new(v[k][0][l], v[k][1][l], v[k][2][l]));
                visit(s as u32, t, limit);
            }
        }
        slot += 4;
    }
}

/// The triangle of leaf slot `slot`.
#[inline(always)]
fn triangle(gas: &Gas, slot: u32) -> [Vec3; 3] {
    let s = slot as usize;
    gas.triangles[s / 4].get(s % 4).map(Vec3::from)
}

/// Checks that the GAS holds static triangles.
pub(super) fn check_gas(gas: &Gas) -> Result<(), SurfaceQueryError> {
    if gas.kind != GasKind::Triangles {
        return Err(SurfaceQueryError::NotTriangles(gas.data().kind()));
    }
    if gas.motion.is_some() {
        return Err(SurfaceQueryError::Unsupported("a GAS with motion"));
    }
    Ok(())
}

/// The nearest triangle so far: its slot, global id, point, barycentrics, squared distance.
#[derive(Clone, Copy)]
struct Nearest {
    slot: u32,
    id: u32,
    q: Vec3,
    u: f32,
    v: f32,
    d2: f32,
}

/// Takes triangle `slot` (`[a, b, c]`) as the nearest if it is nearer than `best` (the lowest
/// global id among equal distances) and within `max2` when there is no best yet. Returns
/// its closest point and squared distance either way.
#[inline(always)]
fn consider(
    gas: &Gas,
    p: Vec3,
    slot: u32,
    [a, b, c]: [Vec3; 3],
    max2: f32,
    best: &mut Option<Nearest>,
) -> (Vec3, f32) {
    let (q, u, v) = closest_on_triangle(p, a, b, c);
    let d2 = (p - q).length_squared();
    let id = gas.slot_prim[slot as usize];
    let better = match best {
        None => d2 <= max2,
        Some(n) => d2 < n.d2 || (d2 == n.d2 && id < n.id),
    };
    if better {
        *best = Some(Nearest {
            slot,
            id,
            q,
            u,
            v,
            d2,
        });
    }
    (q, d2)
}

/// The nearest triangle to `p` within `max_distance`.
fn nearest(gas: &Gas, p: Vec3, max_distance: f32) -> Option<Nearest> {
    let mut best: Option<Nearest> = None;
    let max2 = max_distance * max_distance;
    let margin = bound_margin(gas, p);
    let mut radius2 = max2;
    let mut limit = bound_limit(radius2, margin);
    walk(gas, p, &mut radius2, |first, count, radius2| {
        near_triangles(gas, p, first, count, &mut limit, |slot, t, limit| {
            consider(gas, p, slot, t, max2, &mut best);
            if let Some(n) = best {
                if n.d2 < *radius2 {
                    *radius2 = n.d2;
                    *limit = bound_limit(n.d2, margin);
                }
            }
        });
    });
    best
}

/// Triangles met near the nearest one during the search of [`nearest_with_neighbours`]: those
/// whose closest point was within the pseudo-normal's reach of the nearest so far.
struct Near {
    /// (global id, slot, closest point, squared distance).
    items: [(u32, u32, Vec3, f32); NEAR],
    len: usize,
    /// More than [`NEAR`] were within reach at once: the caller walks again.
    overflow: bool,
}

/// Triangles kept by [`Near`].
const NEAR: usize = 32;

/// The pseudo-normal's tolerance at the closest point `q` at distance `d`: the triangles whose
/// closest point is within it of `q` are those `q` lies on (as [`pseudo_normal`]).
#[inline]
fn normal_tolerance(q: Vec3, d: f32) -> f32 {
    64.0 * f32::EPSILON * (q.abs().max_element() + d) + f32::MIN_POSITIVE
}

/// [`nearest`] (without a bound), also keeping every triangle that the pseudo-normal at the
/// nearest point may take: the walk's radius is the best distance grown by a tolerance that
/// bounds [`normal_tolerance`] over every point of the structure, so that it reaches every
/// triangle [`pseudo_normal`]'s second walk would.
fn nearest_with_neighbours(gas: &Gas, p: Vec3, near: &mut Near) -> Option<Nearest> {
    let mut best: Option<Nearest> = None;
    let b = &gas.bounds;
    let extent = b.min.abs().max(b.max.abs()).max_element();
    let reach = |d2: f32| {
        let d = d2.sqrt();
        let r = d + 64.0 * f32::EPSILON * (extent + d) * 1.01 + 2.0 * f32::MIN_POSITIVE;
        r * r
    };
    let margin = bound_margin(gas, p);
    let mut radius2 = f32::INFINITY;
    let mut limit = f32::INFINITY;
    walk(gas, p, &mut radius2, |first, count, radius2| {
        near_triangles(gas, p, first, count, &mut limit, |slot, t, limit| {
            let (q, d2) = consider(gas, p, slot, t, f32::INFINITY, &mut best);
            let Some(n) = best else { return };
            let r2 = reach(n.d2);
            if r2 < *radius2 {
                *radius2 = r2;
                *limit = bound_limit(r2, margin);
            }
            if d2 > r2 {
                return;
            }
            if near.len == NEAR {
                // Drop those out of reach of the new nearest.
                let mut k = 0;
                for i in 0..near.len {
                    if near.items[i].3 <= r2 {
                        near.items[k] = near.items[i];
                        k += 1;
                    }
                }
                near.len = k;
                if k == NEAR {
                    near.overflow = true;
                    return;
                }
            }
            near.items[near.len] = (gas.slot_prim[slot as usize], slot, q, d2);
            near.len += 1;
        });
    });
    best
}

/// The angle-weighted pseudo-normal (unnormalised) at `q`, the closest point to `p` at
/// distance `d`: every triangle within a rounding tolerance of `q`, each once.
fn pseudo_normal(gas: &Gas, p: Vec3, q: Vec3, d: f32) -> Vec3 {
    let tol = normal_tolerance(q, d);
    let mut radius2 = (d + tol) * (d + tol);
    // Spatial splits reference a triangle from several leaves: count each id once. Beyond the
    // table (a vertex of very high valence with splits), repeats are counted again.
    let mut seen = [0u32; 64];
    let mut n_seen = 0usize;
    let mut sum = Vec3::ZERO;
    walk(gas, p, &mut radius2, |first, count, _| {
        for slot in first..first + count {
            if !gas.slot_is_active(slot as usize) {
                continue;
            }
            let [a, b, c] = triangle(gas, slot);
            let (q2, u, v) = closest_on_triangle(p, a, b, c);
            if (q2 - q).length() > tol {
                continue;
            }
            let id = gas.slot_prim[slot as usize];
            if seen[..n_seen].contains(&id) {
                continue;
            }
            if n_seen < seen.len() {
                seen[n_seen] = id;
                n_seen += 1;
            }
            let n = (b - a).cross(c - a).normalize_or_zero();
            sum += n * angle_at(a, b, c, u, v);
        }
    });
    sum
}

/// [`pseudo_normal`] from the triangles [`nearest_with_neighbours`] kept: those within the
/// tolerance of `q`, each once, summed in the order of their global ids (whatever the
/// traversal order).
fn pseudo_normal_of(gas: &Gas, p: Vec3, q: Vec3, d: f32, near: &mut Near) -> Vec3 {
    let tol = normal_tolerance(q, d);
    let items = &mut near.items[..near.len];
    items.sort_unstable_by_key(|x| x.0);
    let mut sum = Vec3::ZERO;
    let mut last = None;
    for &(id, slot, q2, _) in items.iter() {
        if last == Some(id) || (q2 - q).length() > tol {
            continue;
        }
        last = Some(id);
        let [a, b, c] = triangle(gas, slot);
        let (_, u, v) = closest_on_triangle(p, a, b, c);
        let n = (b - a).cross(c - a).normalize_or_zero();
        sum += n * angle_at(a, b, c, u, v);
    }
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
    ///
    /// ```
    /// use oxray_cpu::Gas;
    /// use glam::Vec3;
    /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    /// let gas = Gas::from_mesh(&v, &[[0, 1, 2]])?;
    /// let p = Vec3::new(0.25, 0.25, 2.0);
    /// assert!(gas.closest_point_within(p, 1.0)?.is_none());
    /// assert_eq!(gas.closest_point_within(p, 2.0)?.unwrap().distance, 2.0);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
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
        Ok(nearest(self, point, max_distance).map(|n| {
            let (primitive_index, _, build_input) = self.resolve_global(n.id);
            ClosestPoint {
                point: n.q,
                distance: n.d2.sqrt(),
                primitive_index,
                build_input,
                u: n.u,
                v: n.v,
            }
        }))
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
        let mut near = Near {
            items: [(0, 0, Vec3::ZERO, 0.0); NEAR],
            len: 0,
            overflow: false,
        };
        let Some(Nearest {
            slot, q, u, v, d2, ..
        }) = nearest_with_neighbours(self, point, &mut near)
        else {
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
        } else if near.overflow {
            pseudo_normal(self, point, q, d)
        } else {
            pseudo_normal_of(self, point, q, d, &mut near)
        };
        Ok(if (point - q).dot(n) < 0.0 { -d } else { d })
    }

    /// [`signed_distance`](Self::signed_distance) of a batch of points, in parallel. The first
    /// failing query (the lowest index) is the error; every other output is written.
    ///
    /// ```
    /// use oxray_cpu::Gas;
    /// use glam::Vec3;
    /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    /// let gas = Gas::from_mesh(&v, &[[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])?;
    /// let mut out = [0.0; 2];
    /// gas.signed_distance_batch(&[Vec3::splat(0.1), Vec3::new(0.2, 0.2, -1.0)], &mut out)?;
    /// assert!(out[0] < 0.0 && out[1] == 1.0);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
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
