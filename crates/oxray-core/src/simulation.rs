//! The results and errors of the simulation queries (every primitive along a ray, hit counts,
//! the closest point of a surface, signed distances), shared by every backend: the CPU's
//! (`oxray_cpu::simulation`) and the CUDA backend's batched kernels give the same values in
//! these types.

use crate::{BuildInputKind, Hit, Ray, RayError, Transform};
use glam::Vec3;
use std::cmp::Ordering;
use thiserror::Error;

/// The order of an all-hits list: by `t`, then by instance index, instance id, build input and
/// primitive, so that which hits a bounded list keeps among equal distances does not depend on
/// traversal order. Two offers of one primitive (spatial splits reference a triangle from
/// several leaves) compare equal.
///
/// ```
/// use oxray_core::simulation::hit_order;
/// use oxray_core::{Hit, HitKind};
/// let hit = |t, primitive_index| Hit {
///     t, u: 0.0, v: 0.0, primitive_index, sbt_gas_index: 0, build_input: 0,
///     hit_kind: HitKind::TRIANGLE_FRONT_FACE, instance_id: !0, instance_index: 0,
/// };
/// assert!(hit_order(&hit(1.0, 5), &hit(2.0, 0)).is_lt());
/// assert!(hit_order(&hit(1.0, 5), &hit(1.0, 4)).is_gt());
/// assert!(hit_order(&hit(1.0, 5), &hit(1.0, 5)).is_eq());
/// ```
#[must_use]
pub fn hit_order(a: &Hit, b: &Hit) -> Ordering {
    a.t.total_cmp(&b.t)
        .then(a.instance_index.cmp(&b.instance_index))
        .then(a.instance_id.cmp(&b.instance_id))
        .then(a.build_input.cmp(&b.build_input))
        .then(a.primitive_index.cmp(&b.primitive_index))
}

/// The results of an all-hits batch (`all_hits_batch` of a GAS or an IAS, on any device):
/// every ray's hits, one ray after the other. Reuse it across batches to keep its allocations.
///
/// ```
/// use oxray_core::AllHits;
/// let mut out = AllHits::new();
/// out.push_ray(&[], true);
/// out.push_ray(&[], false);
/// assert_eq!((out.len(), out.hits(0).len(), out.all().len()), (2, 0, 0));
/// assert!(out.is_complete(0) && !out.is_complete(1));
/// assert_eq!(out.offsets(), [0, 0, 0]);
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct AllHits {
    hits: Vec<Hit>,
    /// Ray `i`'s hits are `hits[offsets[i] .. offsets[i + 1]]`.
    offsets: Vec<usize>,
    complete: Vec<bool>,
}

impl Default for AllHits {
    fn default() -> Self {
        AllHits {
            hits: Vec::new(),
            offsets: vec![0],
            complete: Vec::new(),
        }
    }
}

impl AllHits {
    /// An empty result.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Rays in the batch.
    #[must_use]
    pub fn len(&self) -> usize {
        self.complete.len()
    }

    /// Whether the batch had no ray.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.complete.is_empty()
    }

    /// The hits of ray `ray`, sorted by `t`, each primitive once.
    ///
    /// # Panics
    ///
    /// If `ray >= self.len()`.
    #[must_use]
    pub fn hits(&self, ray: usize) -> &[Hit] {
        &self.hits[self.offsets[ray]..self.offsets[ray + 1]]
    }

    /// Whether ray `ray` has no hit beyond those kept (false where the bound left some out).
    ///
    /// # Panics
    ///
    /// If `ray >= self.len()`.
    #[must_use]
    pub fn is_complete(&self, ray: usize) -> bool {
        self.complete[ray]
    }

    /// Every hit of every ray, ray after ray.
    #[must_use]
    pub fn all(&self) -> &[Hit] {
        &self.hits
    }

    /// Where each ray's hits start in [`all`](Self::all), and the end (`len() + 1` entries).
    #[must_use]
    pub fn offsets(&self) -> &[usize] {
        &self.offsets
    }

    /// Empties the result, keeping its allocations.
    pub fn clear(&mut self) {
        self.hits.clear();
        self.offsets.clear();
        self.offsets.push(0);
        self.complete.clear();
    }

    /// Appends the next ray's hits (already sorted and without repeats) and whether its list
    /// is complete.
    pub fn push_ray(&mut self, hits: &[Hit], complete: bool) {
        self.hits.extend_from_slice(hits);
        self.offsets.push(self.hits.len());
        self.complete.push(complete);
    }

    /// Appends the rays of `parts`, one part after the other, copying their hits in parallel:
    /// how a batch made chunk by chunk on several threads becomes one result without copying
    /// every ray's list on one thread.
    ///
    /// ```
    /// use oxray_core::{AllHits, Hit, HitKind};
    /// let hit = |t| Hit {
    ///     t,
    ///     u: 0.0,
    ///     v: 0.0,
    ///     primitive_index: 0,
    ///     sbt_gas_index: 0,
    ///     build_input: 0,
    ///     hit_kind: HitKind::TRIANGLE_FRONT_FACE,
    ///     instance_id: !0,
    ///     instance_index: 0,
    /// };
    /// let (mut a, mut b) = (AllHits::new(), AllHits::new());
    /// a.push_ray(&[hit(1.0)], true);
    /// b.push_ray(&[], true);
    /// b.push_ray(&[hit(2.0), hit(3.0)], false);
    /// let mut out = AllHits::new();
    /// out.append_parts(vec![a, b]);
    /// assert_eq!(out.offsets(), [0, 1, 1, 3]);
    /// assert_eq!(out.hits(2)[1].t, 3.0);
    /// assert!(!out.is_complete(2));
    /// ```
    pub fn append_parts(&mut self, parts: Vec<AllHits>) {
        use rayon::prelude::*;
        let start = self.hits.len();
        let rays: usize = parts.iter().map(AllHits::len).sum();
        self.offsets.reserve(rays);
        self.complete.reserve(rays);
        let mut base = start;
        for p in &parts {
            self.offsets
                .extend(p.offsets[1..].iter().map(|&o| base + o));
            self.complete.extend_from_slice(&p.complete);
            base += p.hits.len();
        }
        let added = base - start;
        self.hits.reserve(added);
        let mut dest: Vec<&mut [std::mem::MaybeUninit<Hit>]> = Vec::with_capacity(parts.len());
        let mut rest = &mut self.hits.spare_capacity_mut()[..added];
        for p in &parts {
            let (d, tail) = std::mem::take(&mut rest).split_at_mut(p.hits.len());
            dest.push(d);
            rest = tail;
        }
        dest.into_par_iter()
            .zip(parts.par_iter())
            .for_each(|(d, p)| {
                for (d, &h) in d.iter_mut().zip(&p.hits) {
                    d.write(h);
                }
            });
        // SAFETY: the parts' lengths sum to `added`, so the loop above wrote every one of the
        // `added` values past the old length (reserved above); `Hit` is `Copy` (no drop).
        unsafe { self.hits.set_len(base) };
    }
}

/// Where a hit lies, in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceHit {
    /// The hit point. On a triangle it is interpolated from the vertices with the hit's
    /// barycentrics and carried to world space (so it lies on the triangle to rounding, which
    /// `ray.at(hit.t)` need not); on a sphere it is the point of the ray at the hit's `t`
    /// projected onto the sphere.
    pub point: Vec3,
    /// The unit geometric normal. A triangle's is `(v1 - v0) × (v2 - v0)` in object space, the
    /// side its counter-clockwise winding faces, carried to world space by the inverse
    /// transpose of the object-to-world transform; so the hit is a front face
    /// (`optixIsFrontFaceHit`) exactly when the ray's direction points against it (a negative
    /// dot product), mirrored instances included. An instance's `FLIP_TRIANGLE_FACING` swaps
    /// [`front_face`](Self::front_face) but not this normal. A sphere's points outwards.
    pub geometric_normal: Vec3,
    /// The unit shading normal: the caller's vertex normals (see [`ShadingNormals`])
    /// interpolated with the barycentrics in object space and carried to world space as the
    /// geometric normal is; the geometric normal where there are none (spheres, triangles
    /// without normals, normals that interpolate to zero or NaN).
    pub shading_normal: Vec3,
    /// Whether the hit is on the primitive's front face (the hit kind's).
    pub front_face: bool,
}

/// Per-vertex normals of the triangles hit: the source of [`SurfaceHit::shading_normal`].
///
/// Implemented by `VertexNormals` of the CPU backend (one indexed mesh), by [`NoShadingNormals`], and by any
/// `Fn(&Hit) -> Option<[Vec3; 3]>` (say, one mesh per instance id).
pub trait ShadingNormals {
    /// The object-space normals of the hit triangle's three vertices, in its vertex order;
    /// `None` for none.
    fn vertex_normals(&self, hit: &Hit) -> Option<[Vec3; 3]>;
}

impl<F: Fn(&Hit) -> Option<[Vec3; 3]>> ShadingNormals for F {
    fn vertex_normals(&self, hit: &Hit) -> Option<[Vec3; 3]> {
        self(hit)
    }
}

/// No vertex normals: the shading normal is the geometric normal.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoShadingNormals;

impl ShadingNormals for NoShadingNormals {
    fn vertex_normals(&self, _: &Hit) -> Option<[Vec3; 3]> {
        None
    }
}

/// The object-space parts of a triangle hit's surface: the point interpolated from the vertices
/// `v` with the hit's barycentrics, the (unnormalised) geometric normal of the winding,
/// `(v1 - v0) × (v2 - v0)`, and the vertex normals `normals` interpolated the same way.
#[must_use]
pub fn triangle_surface_parts(
    v: [Vec3; 3],
    hit: &Hit,
    normals: Option<[Vec3; 3]>,
) -> (Vec3, Vec3, Option<Vec3>) {
    let [p0, p1, p2] = v;
    let w = 1.0 - hit.u - hit.v;
    let point = p0 * w + p1 * hit.u + p2 * hit.v;
    let normal = (p1 - p0).cross(p2 - p0);
    let shading = normals.map(|[n0, n1, n2]| n0 * w + n1 * hit.u + n2 * hit.v);
    (point, normal, shading)
}

/// The object-space point and unit outward normal of a sphere hit at `t` of `object_ray` (the
/// ray carried into the sphere's space): the ray's point projected onto the sphere.
#[must_use]
pub fn sphere_surface_parts(center: Vec3, radius: f32, object_ray: &Ray, t: f32) -> (Vec3, Vec3) {
    let normal = (object_ray.at(t) - center).normalize_or_zero();
    (center + normal * radius, normal)
}

/// A hit's [`SurfaceHit`] from its object-space point, normal and shading normal, carried to
/// world space through `levels`, the transforms above the primitive innermost first, each as
/// (object-to-world, world-to-object): points by the first, normals by the inverse transpose
/// (the second's transpose); then normalised. Every backend finishes its surfaces here.
///
/// ```
/// use oxray_core::simulation::surface_in_world;
/// use oxray_core::Transform;
/// use glam::Vec3;
/// let t = Transform::from_translation(Vec3::X);
/// let inverse = Transform::from_translation(-Vec3::X);
/// let s = surface_in_world(Vec3::ZERO, Vec3::new(0.0, 0.0, 2.0), None, [(t, inverse)], true);
/// assert_eq!((s.point, s.geometric_normal, s.shading_normal), (Vec3::X, Vec3::Z, Vec3::Z));
/// ```
#[must_use]
pub fn surface_in_world(
    point: Vec3,
    normal: Vec3,
    shading: Option<Vec3>,
    levels: impl IntoIterator<Item = (Transform, Transform)>,
    front_face: bool,
) -> SurfaceHit {
    let (mut point, mut normal, mut shading) = (point, normal, shading);
    for (object_to_world, world_to_object) in levels {
        point = object_to_world.transform_point(point);
        normal = Transform::transform_normal_with_inverse(&world_to_object, normal);
        shading = shading.map(|n| Transform::transform_normal_with_inverse(&world_to_object, n));
    }
    let geometric_normal = normal.normalize_or_zero();
    let shading_normal = shading
        .map(Vec3::normalize_or_zero)
        .filter(|n| *n != Vec3::ZERO)
        .unwrap_or(geometric_normal);
    SurfaceHit {
        point,
        geometric_normal,
        shading_normal,
        front_face,
    }
}

/// The closest point of a triangle GAS to a query point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClosestPoint {
    /// The closest point, on the surface.
    pub point: Vec3,
    /// Its (unsigned) distance to the query point.
    pub distance: f32,
    /// The triangle it lies on: the index within its build input plus the input's primitive
    /// index offset, as [`Hit::primitive_index`].
    pub primitive_index: u32,
    /// The build input of that triangle.
    pub build_input: u32,
    /// Barycentrics of the point in its triangle, as a hit's:
    /// `point = (1 - u - v) v0 + u v1 + v v2`.
    pub u: f32,
    /// The second barycentric.
    pub v: f32,
}

/// The closest point of the triangles under an IAS, and the instance it lies under.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InstanceClosestPoint {
    /// The closest point in world space, its distance from the query point, its triangle
    /// (primitive index and build input of its GAS) and barycentrics in that triangle.
    pub closest: ClosestPoint,
    /// The id of the instance nearest the GAS on the way (as a hit's `instance_id`).
    pub instance_id: u32,
    /// The index of that instance in its IAS's build input (as a hit's `instance_index`).
    pub instance_index: u32,
}

/// Why a simulation query could not run.
#[derive(Clone, Debug, Error, PartialEq)]
#[non_exhaustive]
pub enum SurfaceQueryError {
    /// A query point has a NaN or infinite coordinate.
    #[error("query point {index} is not finite: {point}")]
    NonFinitePoint {
        /// Position of the point in its batch (0 for a single query).
        index: usize,
        /// The point.
        point: Vec3,
    },
    /// A ray is invalid (see [`Ray::validate`](crate::Ray::validate)).
    #[error("ray {index} is invalid: {error}")]
    InvalidRay {
        /// Position of the ray in its batch (0 for a single query).
        index: usize,
        /// What is wrong with it.
        error: RayError,
    },
    /// An output (or a second input) does not have one element per query.
    #[error("{queries} queries but {outputs} results or inputs beside them")]
    LengthMismatch {
        /// Queries given.
        queries: usize,
        /// Elements of the other slice.
        outputs: usize,
    },
    /// The query needs a structure of triangles.
    #[error("this query needs a GAS of triangles, not of {0:?}")]
    NotTriangles(BuildInputKind),
    /// The primitive type of the hit, or the structure, is not supported by this query.
    #[error("{0} is not supported by this query")]
    Unsupported(&'static str),
    /// The device failed (out of memory, a driver error).
    #[error("device error: {0}")]
    Device(String),
    /// The hit is not a hit of this ray on this structure (a hit of another ray or structure,
    /// or one whose fields were changed).
    #[error("hit {index} (primitive {primitive_index} of build input {build_input}, instance {instance_index}) is not on its ray in this structure")]
    HitNotFound {
        /// Position of the hit in its batch (0 for a single query).
        index: usize,
        /// The hit's primitive index.
        primitive_index: u32,
        /// The hit's build input.
        build_input: u32,
        /// The hit's instance index.
        instance_index: u32,
    },
}

impl SurfaceQueryError {
    /// The same error, for query `index` of a batch.
    #[must_use]
    pub fn at(self, index: usize) -> Self {
        match self {
            SurfaceQueryError::NonFinitePoint { point, .. } => {
                SurfaceQueryError::NonFinitePoint { index, point }
            }
            SurfaceQueryError::InvalidRay { error, .. } => {
                SurfaceQueryError::InvalidRay { index, error }
            }
            SurfaceQueryError::HitNotFound {
                primitive_index,
                build_input,
                instance_index,
                ..
            } => SurfaceQueryError::HitNotFound {
                index,
                primitive_index,
                build_input,
                instance_index,
            },
            e => e,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::HitKind;

    fn hit(t: f32, primitive_index: u32) -> Hit {
        Hit {
            t,
            u: 0.25,
            v: 0.5,
            primitive_index,
            sbt_gas_index: 0,
            build_input: 0,
            hit_kind: HitKind::TRIANGLE_BACK_FACE,
            instance_id: !0,
            instance_index: 0,
        }
    }

    #[test]
    fn appended_parts_equal_the_same_rays_pushed_one_by_one() {
        // Parts of varied sizes (empty ones and rays without hits included), appended after
        // rays already held.
        let mut parts = Vec::new();
        let mut pushed = AllHits::new();
        let mut appended = AllHits::new();
        pushed.push_ray(&[hit(0.5, 99)], true);
        appended.push_ray(&[hit(0.5, 99)], true);
        let mut next = 0u32;
        for size in [3usize, 0, 1, 7, 0, 2] {
            let mut part = AllHits::new();
            for r in 0..size {
                let list: Vec<Hit> = (0..(next % 4))
                    .map(|k| hit(k as f32 + r as f32, next * 10 + k))
                    .collect();
                let complete = !next.is_multiple_of(3);
                part.push_ray(&list, complete);
                pushed.push_ray(&list, complete);
                next += 1;
            }
            parts.push(part);
        }
        appended.append_parts(parts);
        assert_eq!(appended, pushed);
        // Nothing to append leaves the result as it was.
        appended.append_parts(vec![AllHits::new(), AllHits::new()]);
        assert_eq!(appended, pushed);
    }
}
