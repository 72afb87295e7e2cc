//! The world-space point and normals of a hit: what a closest-hit program computes from
//! `optixGetTriangleVertexData` and `optixGetObjectToWorldTransformMatrix`, as a query.
//!
//! A [`Hit`] names its primitive but not where the primitive's data lies, nor the transforms
//! above it. The query finds both by tracing the hit's ray again in an interval of a few ulps
//! around the hit's `t` and stopping at the candidate with the hit's primitive and instance:
//! the same traversal that found the hit (the same instances, transforms and motion), at the
//! cost of a very short ray. It works for hits of any traversable graph (instances, static and
//! motion transforms, nested IASes) on triangles and spheres.

use super::{check_ray, par_try_batch, SurfaceQueryError};
use crate::traversal::{
    traverse_node, with_stack, Decision, Entry, GasVisitor, NodeRef, Path, SceneVisitor,
};
use crate::{Gas, Ias};
use glam::Vec3;
use oxray_bvh::motion::{lerp_sphere, lerp_triangle4};
use oxray_bvh::triangle::TriangleHit;
use oxray_bvh::GasKind;
use oxray_core::simulation::{sphere_surface_parts, surface_in_world, triangle_surface_parts};
use oxray_core::{Hit, PrimitiveType, Ray};
pub use oxray_core::{NoShadingNormals, ShadingNormals, SurfaceHit};

/// The vertex normals of one indexed mesh, looked up by the hit's primitive index (the
/// triangle's position in `indices`, as [`Gas::from_mesh`] numbers them); a primitive index
/// past the end of `indices` has none.
#[derive(Clone, Copy, Debug)]
pub struct VertexNormals<'a> {
    normals: &'a [[f32; 3]],
    indices: &'a [[u32; 3]],
}

impl<'a> VertexNormals<'a> {
    /// Normals (one per vertex) of the mesh with triangles `indices`; every index must name a
    /// normal.
    pub fn new(normals: &'a [[f32; 3]], indices: &'a [[u32; 3]]) -> Result<Self, super::MeshError> {
        super::mesh::check_indices(normals.len(), indices)?;
        Ok(VertexNormals { normals, indices })
    }
}

impl ShadingNormals for VertexNormals<'_> {
    fn vertex_normals(&self, hit: &Hit) -> Option<[Vec3; 3]> {
        let t = self.indices.get(hit.primitive_index as usize)?;
        Some(t.map(|i| Vec3::from(self.normals[i as usize])))
    }
}

/// The primitive found again, with the transforms above it.
struct Located<'s> {
    gas: &'s Gas,
    slot: u32,
    path: Path<'s>,
    object_ray: Ray,
}

/// Finds the candidate with the target hit's primitive and instance.
struct Locate<'s> {
    target: Hit,
    /// The current GAS, where it is reached with the target's instance.
    current: Option<(&'s Gas, Path<'s>, Ray)>,
    found: Option<Located<'s>>,
}

impl<'s> Locate<'s> {
    fn matches(&mut self, slot: u32) -> Decision {
        let Some((gas, path, ray)) = &self.current else {
            return Decision::Ignore;
        };
        let (primitive_index, _, build_input) = gas.resolve(slot);
        if primitive_index != self.target.primitive_index || build_input != self.target.build_input
        {
            return Decision::Ignore;
        }
        self.found = Some(Located {
            gas,
            slot,
            path: *path,
            object_ray: *ray,
        });
        Decision::AcceptAndTerminate
    }
}

impl<'s> SceneVisitor<'s> for Locate<'s> {
    fn enter_gas(&mut self, gas: &'s Gas, path: &Path<'s>, object_ray: &Ray) {
        let instance = path.instance.map_or((!0, 0), |i| (i.instance_id, i.index));
        // Copy the path only where the instance is the hit's.
        self.current = if instance == (self.target.instance_id, self.target.instance_index) {
            Some((gas, *path, *object_ray))
        } else {
            None
        };
    }

    fn ray_mask(&self) -> u8 {
        0xFF
    }
}

impl GasVisitor for Locate<'_> {
    fn triangle(&mut self, slot: u32, _: &TriangleHit) -> Decision {
        self.matches(slot)
    }

    fn sphere(&mut self, slot: u32, _: f32) -> Decision {
        self.matches(slot)
    }

    fn curve(&mut self, _: u32, _: &oxray_bvh::CurveHit) -> Decision {
        Decision::Ignore
    }

    fn custom(&mut self, _: u32, _: f32, _: f32, _: &mut [Entry]) -> (Option<f32>, bool) {
        (None, false)
    }
}

/// The surface of `hit`, a hit of `ray` under `root`.
fn hit_surface<N: ShadingNormals + ?Sized>(
    root: NodeRef<'_>,
    ray: &Ray,
    hit: &Hit,
    normals: &N,
) -> Result<SurfaceHit, SurfaceQueryError> {
    check_ray(ray)?;
    match hit.hit_kind.primitive_type() {
        PrimitiveType::Triangle | PrimitiveType::Sphere => {}
        PrimitiveType::Custom => return Err(SurfaceQueryError::Unsupported("a custom primitive")),
        PrimitiveType::Curve(_) => return Err(SurfaceQueryError::Unsupported("a curve")),
    }
    let not_found = SurfaceQueryError::HitNotFound {
        index: 0,
        primitive_index: hit.primitive_index,
        build_input: hit.build_input,
        instance_index: hit.instance_index,
    };
    if !(hit.t >= 0.0 && hit.t.is_finite()) {
        return Err(not_found);
    }
    // The interval around the hit: the traversal computes the same t again, the slack only
    // keeps the box tests' rounding out of the way.
    let slack = hit.t * 1e-6 + f32::MIN_POSITIVE;
    let short = Ray {
        tmin: (hit.t - slack).max(0.0),
        tmax: hit.t + slack,
        ..*ray
    };
    let mut v = Locate {
        target: *hit,
        current: None,
        found: None,
    };
    with_stack(|stack| traverse_node(root, &Path::ROOT, &short, &mut v, stack));
    let Some(found) = v.found else {
        return Err(not_found);
    };
    let gas = found.gas;
    let Some(sample) = gas.key_sample(found.object_ray.time) else {
        return Err(not_found);
    };
    let slot = found.slot as usize;
    let (point, normal, shading) = match gas.kind {
        GasKind::Triangles => {
            let (a, b) = gas.triangle_keys(sample);
            let block = lerp_triangle4(&a[slot / 4], &b[slot / 4], sample.fraction);
            let v = block.get(slot % 4).map(Vec3::from);
            triangle_surface_parts(v, hit, normals.vertex_normals(hit))
        }
        GasKind::Spheres => {
            let (a, b) = gas.sphere_keys(sample);
            let s = lerp_sphere(&a[slot], &b[slot], sample.fraction);
            let (point, normal) =
                sphere_surface_parts(Vec3::from(s.center), s.radius, &found.object_ray, hit.t);
            (point, normal, None)
        }
        GasKind::CustomPrimitives | GasKind::Curves => {
            return Err(SurfaceQueryError::Unsupported(
                "a custom primitive or curve",
            ));
        }
    };
    Ok(surface_in_world(
        point,
        normal,
        shading,
        found
            .path
            .levels()
            .rev()
            .map(|l| (l.object_to_world(), l.world_to_object())),
        hit.hit_kind.is_front_face(),
    ))
}

/// The surface queries every traversable offers.
macro_rules! surface_api {
    ($t:ty, $root:expr) => {
        impl $t {
            /// The world-space point, geometric normal and face of `hit`, a hit of `ray` on
            /// this structure (as [`intersect`](Self::intersect) or [`all_hits`](Self::all_hits)
            /// found it), on a triangle or a sphere. The shading normal is the geometric one; see
            /// [`hit_surface_shaded`](Self::hit_surface_shaded) for vertex normals.
            ///
            /// Errors: an invalid ray, a custom primitive or curve
            /// ([`SurfaceQueryError::Unsupported`]), a hit that is not on this ray in this
            /// structure ([`SurfaceQueryError::HitNotFound`]).
            ///
            /// ```
            /// use oxray_cpu::Gas;
            /// use oxray_core::Ray;
            /// use glam::Vec3;
            /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
            /// let gas = Gas::from_mesh(&v, &[[0, 1, 2]])?;
            /// let ray = Ray::new(Vec3::new(0.25, 0.25, 1.0), -Vec3::Z);
            /// let hit = gas.intersect(&ray).unwrap();
            /// let s = gas.hit_surface(&ray, &hit)?;
            /// assert_eq!(s.point, Vec3::new(0.25, 0.25, 0.0));
            /// assert_eq!(s.geometric_normal, Vec3::Z); // counter-clockwise seen from +z
            /// assert!(s.front_face && s.geometric_normal.dot(ray.direction) < 0.0);
            /// # Ok::<(), Box<dyn std::error::Error>>(())
            /// ```
            pub fn hit_surface(
                &self,
                ray: &Ray,
                hit: &Hit,
            ) -> Result<SurfaceHit, SurfaceQueryError> {
                hit_surface($root(self), ray, hit, &NoShadingNormals)
            }

            /// [`hit_surface`](Self::hit_surface) with the shading normal interpolated from
            /// vertex normals.
            ///
            /// ```
            /// use oxray_cpu::{Gas, VertexNormals};
            /// use oxray_core::Ray;
            /// use glam::Vec3;
            /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
            /// let n = [[0.0f32, 0.0, 1.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
            /// let tris = [[0u32, 1, 2]];
            /// let gas = Gas::from_mesh(&v, &tris)?;
            /// let ray = Ray::new(Vec3::new(0.5, 0.0, 1.0), -Vec3::Z);
            /// let hit = gas.intersect(&ray).unwrap();
            /// let s = gas.hit_surface_shaded(&ray, &hit, &VertexNormals::new(&n, &tris)?)?;
            /// assert!((s.shading_normal - Vec3::new(1.0, 0.0, 1.0).normalize()).length() < 1e-6);
            /// # Ok::<(), Box<dyn std::error::Error>>(())
            /// ```
            pub fn hit_surface_shaded<N: ShadingNormals + ?Sized>(
                &self,
                ray: &Ray,
                hit: &Hit,
                normals: &N,
            ) -> Result<SurfaceHit, SurfaceQueryError> {
                hit_surface($root(self), ray, hit, normals)
            }

            /// The surfaces of a batch of hits (`hits[i]` of `rays[i]`, `None` for a miss), in
            /// parallel: `out[i]` is `None` for a miss. The first failing query (the lowest
            /// index) is the error; every other output is written.
            pub fn hit_surface_batch(
                &self,
                rays: &[Ray],
                hits: &[Option<Hit>],
                out: &mut [Option<SurfaceHit>],
            ) -> Result<(), SurfaceQueryError> {
                self.hit_surface_batch_shaded(rays, hits, &NoShadingNormals, out)
            }

            /// [`hit_surface_batch`](Self::hit_surface_batch) with vertex normals.
            pub fn hit_surface_batch_shaded<N: ShadingNormals + Sync + ?Sized>(
                &self,
                rays: &[Ray],
                hits: &[Option<Hit>],
                normals: &N,
                out: &mut [Option<SurfaceHit>],
            ) -> Result<(), SurfaceQueryError> {
                if rays.len() != hits.len() {
                    return Err(SurfaceQueryError::LengthMismatch {
                        queries: rays.len(),
                        outputs: hits.len(),
                    });
                }
                par_try_batch(rays.len(), out, |i| match &hits[i] {
                    None => Ok(None),
                    Some(h) => hit_surface($root(self), &rays[i], h, normals).map(Some),
                })
            }
        }
    };
}

surface_api!(Gas, NodeRef::Gas);
surface_api!(Ias, NodeRef::Ias);
