//! Rays of a batch walked one after another through one triangle GAS, with each ray's set-up
//! (validation, the prepared constants), its walk and its answer compiled together for the
//! structure's instruction set.
//!
//! A query ray by ray goes through [`super::traverse_node`]: it matches the structure's kind,
//! motion and kernel, and prepares the ray in code compiled for the baseline processor before
//! calling the SIMD kernel, every ray. A batch of rays under one structure decides all of that
//! once, and the per-ray work left (about a third of a ray's instructions on small scenes, such
//! as a path tracer's bounce and shadow rays in a room) runs inside the kernel's own function.
//! The hits are those of [`super::traverse_node`], bit for bit: the same walk with the same
//! visitor.

use super::kernel::GasVisitor;
#[cfg(target_arch = "x86_64")]
use super::kernel::{traverse, with_stack, Entry};
#[cfg(target_arch = "x86_64")]
use super::leaf::TriangleLeaves;
#[cfg(target_arch = "x86_64")]
use super::node::NodeLayout;
#[cfg(target_arch = "x86_64")]
use super::ray::PreparedRay;
use crate::Gas;
#[cfg(target_arch = "x86_64")]
use crate::Isa;
use oxray_bvh::GasKind;
use oxray_core::Ray;

/// Walks `rays` through `gas` one at a time, writing `answer` of each ray's visitor into `out`
/// (`None` for an invalid ray, which walks nothing). `visitor` makes a ray's visitor, as
/// [`super::SceneVisitor::enter_gas`] would leave it for a GAS at the root. Returns `false`,
/// having done nothing, where this path does not apply: a structure with motion, not made of
/// triangles, or walked by a kernel other than the 8-wide float AVX2 and AVX-512 ones.
#[inline]
pub(crate) fn triangle_gas_rays<V: GasVisitor, T>(
    gas: &Gas,
    rays: &[Ray],
    out: &mut [T],
    visitor: impl Fn(&Ray) -> V,
    answer: impl Fn(Option<V>) -> T,
) -> bool {
    if gas.motion.is_some() || gas.kind != GasKind::Triangles || gas.quantized_nodes().is_some() {
        return false;
    }
    let Some(bvh8) = gas.bvh8.as_ref() else {
        return false;
    };
    #[cfg(target_arch = "x86_64")]
    {
        let (nodes, leaves) = (&bvh8.nodes[..], TriangleLeaves(&gas.triangles));
        match gas.isa() {
            // SAFETY: a `Gas` is given `Isa::Avx2` only where `Isa::is_available` found AVX2
            // and the other features of the kernel on this processor (`Gas::kernel_for`).
            Isa::Avx2 => with_stack(|stack| unsafe {
                rays_avx2(nodes, &leaves, rays, out, &visitor, &answer, stack);
            }),
            // SAFETY: likewise for `Isa::Avx512` and its features.
            Isa::Avx512 => with_stack(|stack| unsafe {
                rays_avx512(nodes, &leaves, rays, out, &visitor, &answer, stack);
            }),
            _ => return false,
        }
        true
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (bvh8, rays, out, visitor, answer);
        false
    }
}

/// The loop of [`triangle_gas_rays`] over one node layout.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn rays_with<N: NodeLayout, V: GasVisitor, T>(
    nodes: &[N::Node],
    leaves: &TriangleLeaves<'_>,
    rays: &[Ray],
    out: &mut [T],
    visitor: &impl Fn(&Ray) -> V,
    answer: &impl Fn(Option<V>) -> T,
    stack: &mut [Entry],
) {
    for (ray, o) in rays.iter().zip(out) {
        let walked = ray.validate().is_ok().then(|| {
            let mut v = visitor(ray);
            let prepared = PreparedRay::of_valid(ray);
            traverse::<N, _, _>(nodes, leaves, &prepared, ray.tmin, ray.tmax, &mut v, stack);
            v
        });
        *o = answer(walked);
    }
}

/// Defines [`rays_with`] over one SIMD node layout, compiled with the layout's instruction set.
macro_rules! simd_rays {
    ($(#[$doc:meta])* $name:ident, $layout:ty, $features:literal) => {
        $(#[$doc])*
        ///
        /// # Safety
        ///
        /// The processor must have the features this function is compiled with.
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        unsafe fn $name<V: GasVisitor, T>(
            nodes: &[oxray_bvh::Bvh8Node],
            leaves: &TriangleLeaves<'_>,
            rays: &[Ray],
            out: &mut [T],
            visitor: &impl Fn(&Ray) -> V,
            answer: &impl Fn(Option<V>) -> T,
            stack: &mut [Entry],
        ) {
            rays_with::<$layout, V, T>(nodes, leaves, rays, out, visitor, answer, stack)
        }
    };
}

simd_rays!(
    /// [`rays_with`] over 8-wide nodes with AVX2.
    rays_avx2,
    super::node::Bvh8Avx2,
    "avx2,bmi1,bmi2,lzcnt,popcnt"
);
simd_rays!(
    /// [`rays_with`] over 8-wide nodes with AVX-512 (VL) compares.
    rays_avx512,
    super::node::Bvh8Avx512,
    "avx2,bmi1,bmi2,lzcnt,popcnt,avx512f,avx512vl"
);
