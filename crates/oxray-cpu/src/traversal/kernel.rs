//! The traversal kernel: a BVH walked nearest-first with a fixed-size stack, composed from three
//! orthogonal parts, as Embree's kernels are:
//!
//! - a node layout ([`NodeLayout`]: how one node's children are tested),
//! - a leaf intersector ([`LeafIntersector`]: how the primitives of one leaf are tested —
//!   triangle blocks, custom-primitive boxes, instances),
//! - a visitor ([`GasVisitor`]: what is done with a candidate — queries, any-hit filters, the
//!   program pipeline).
//!
//! Each combination is monomorphised: there is no dynamic dispatch per node or per leaf. The
//! choice of leaf intersector is made once per acceleration structure entered (see
//! [`super::scene::traverse_node`]).

use super::leaf::{LeafEnd, LeafIntersector};
use super::node::NodeLayout;
use super::ray::PreparedRay;
use oxray_bvh::WIDE_TRAVERSAL_STACK_SIZE;
use oxray_core::ray::TMAX_SLACK;

/// What a visitor decides about a candidate hit (guide §13.4, §13.13).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Decision {
    /// Not a hit (an any-hit program ignored it, or it was culled): tmax stays.
    Ignore,
    /// Accepted: tmax shrinks to its t.
    Accept,
    /// Accepted, and traversal ends (terminate-ray, or terminate-on-first-hit).
    AcceptAndTerminate,
    /// Not accepted, and traversal ends (an exception was raised).
    Abort,
}

/// Receives the candidate hits of a traversal.
pub(crate) trait GasVisitor {
    /// A triangle hit within the current interval, at leaf slot `slot`.
    fn triangle(&mut self, slot: u32, hit: &oxray_bvh::triangle::TriangleHit) -> Decision;
    /// A sphere's front-face hit at distance `t` within the current interval, at leaf slot
    /// `slot` (guide §9.4: spheres report only their front face).
    fn sphere(&mut self, slot: u32, t: f32) -> Decision;
    /// A curve segment's hit within the current interval, at leaf slot `slot` (guide §9.3:
    /// round curves report front faces only, ribbons either face).
    fn curve(&mut self, slot: u32, hit: &oxray_bvh::CurveHit) -> Decision;
    /// A custom primitive whose box the ray enters within `[tmin, tmax]`. Returns the t of the
    /// closest hit it accepted (the new tmax), and whether traversal must end. `spare` is the
    /// unused part of the traversal stack, for a nested traversal (an instance's child).
    fn custom(
        &mut self,
        slot: u32,
        tmin: f32,
        tmax: f32,
        spare: &mut [Entry],
    ) -> (Option<f32>, bool);
    /// Whether children are visited nearest first. A visitor whose first accepted hit ends
    /// traversal (an occlusion query) may say no: any order finds whether there is a hit, and
    /// not sorting saves work on every node.
    #[inline(always)]
    fn nearest_first(&self) -> bool {
        true
    }
}

/// One entry of the traversal stack.
#[derive(Clone, Copy, Default)]
pub(crate) struct Entry {
    /// Node index (inner) or first primitive slot (leaf).
    pub child: u32,
    /// Primitive count of a leaf; 0 for an inner node.
    pub count: u32,
    /// Entry distance of the node's box.
    pub dist: f32,
}

/// Entries of the per-thread stack: enough for the deepest graph (31 levels) of the deepest BVHs
/// oxray builds, in the widest layout.
pub(crate) const STACK_ENTRIES: usize = 32 * WIDE_TRAVERSAL_STACK_SIZE;

thread_local! {
    static STACK: std::cell::RefCell<Vec<Entry>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Runs `f` with this thread's traversal stack (allocated once per thread, so traversal
/// allocates nothing per ray). Should work nest on the same thread while the stack is in use
/// (a program running its own thread pool inside a traversal), a fresh stack is used.
pub(crate) fn with_stack<R>(f: impl FnOnce(&mut [Entry]) -> R) -> R {
    STACK.with(|cell| match cell.try_borrow_mut() {
        Ok(mut stack) => f(full(&mut stack)),
        Err(_) => f(&mut vec![Entry::default(); STACK_ENTRIES]),
    })
}

/// `stack`, grown to [`STACK_ENTRIES`] the first time a thread uses it.
#[inline]
fn full(stack: &mut Vec<Entry>) -> &mut [Entry] {
    if stack.len() < STACK_ENTRIES {
        stack.resize(STACK_ENTRIES, Entry::default());
    }
    stack
}

/// This thread's traversal stack, held for a run of traversals (a launch's chunk of indices):
/// taken from the thread's slot when made and given back when dropped, so that the traversals
/// in between reach it without a thread-local lookup each.
pub(crate) struct HeldStack(std::cell::RefCell<Vec<Entry>>);

impl HeldStack {
    /// Takes this thread's stack (an empty one if the thread's is in use, which `with` then
    /// fills).
    pub(crate) fn take() -> HeldStack {
        let v = STACK
            .try_with(|cell| cell.try_borrow_mut().map(|mut s| std::mem::take(&mut *s)))
            .ok()
            .and_then(Result::ok)
            .unwrap_or_default();
        HeldStack(std::cell::RefCell::new(v))
    }

    /// Runs `f` with the held stack; should it be in use (a traversal started inside another
    /// on this thread), with [`with_stack`]'s.
    #[inline]
    pub(crate) fn with<R>(&self, f: impl FnOnce(&mut [Entry]) -> R) -> R {
        match self.0.try_borrow_mut() {
            Ok(mut stack) => f(full(&mut stack)),
            Err(_) => with_stack(f),
        }
    }
}

impl Drop for HeldStack {
    fn drop(&mut self) {
        let held = std::mem::take(self.0.get_mut());
        // Given back unless the thread's slot meanwhile holds one as large (or is gone, at the
        // thread's end).
        let _ = STACK.try_with(|cell| {
            if let Ok(mut s) = cell.try_borrow_mut() {
                if s.len() < held.len() {
                    *s = held;
                }
            }
        });
    }
}

/// Walks the BVH `nodes` (root first) nearest child first, handing the slot range of every leaf
/// the ray enters to `leaves`, which offers candidates to `visitor`. The interval shrinks as
/// candidates are accepted. Returns the final tmax and whether traversal was ended early.
#[inline(always)]
pub(crate) fn traverse<N: NodeLayout, L: LeafIntersector<V>, V: GasVisitor>(
    nodes: &[N::Node],
    leaves: &L,
    ray: &PreparedRay,
    tmin: f32,
    mut tmax: f32,
    visitor: &mut V,
    stack: &mut [Entry],
) -> (f32, bool) {
    let mut sp = 0usize;
    let mut box_tmax = tmax * TMAX_SLACK;
    let mut cur = Entry {
        child: 0,
        count: 0,
        dist: tmin,
    };
    loop {
        if cur.count == 0 {
            let node = &nodes[cur.child as usize];
            let (dist, mut mask) = N::intersect(node, ray, tmin, box_tmax);
            if mask != 0 {
                let entry = |l: usize| {
                    let e = N::entry(node, l, dist[l]);
                    if e.count == 0 {
                        N::prefetch(nodes, e.child);
                    } else {
                        leaves.prefetch(e.child);
                    }
                    e
                };
                let a = entry(mask.trailing_zeros() as usize);
                mask &= mask - 1;
                if mask == 0 {
                    // One child hit: descend without touching the stack.
                    cur = a;
                    continue;
                }
                let b = entry(mask.trailing_zeros() as usize);
                mask &= mask - 1;
                if mask == 0 {
                    // Two: push the farther one (or the second, in any order).
                    let (near, far) = if b.dist < a.dist && visitor.nearest_first() {
                        (b, a)
                    } else {
                        (a, b)
                    };
                    stack[sp] = far;
                    sp += 1;
                    cur = near;
                    continue;
                }
                if !visitor.nearest_first() {
                    // Any order will do: push all but the first, continue with it.
                    stack[sp] = b;
                    sp += 1;
                    while mask != 0 {
                        stack[sp] = entry(mask.trailing_zeros() as usize);
                        mask &= mask - 1;
                        sp += 1;
                    }
                    cur = a;
                    continue;
                }
                // Three or more: push all, sort them farthest first, continue with the nearest.
                let base = sp;
                stack[sp] = a;
                stack[sp + 1] = b;
                sp += 2;
                while mask != 0 {
                    stack[sp] = entry(mask.trailing_zeros() as usize);
                    mask &= mask - 1;
                    sp += 1;
                }
                for i in base + 1..sp {
                    let e = stack[i];
                    let mut j = i;
                    while j > base && stack[j - 1].dist < e.dist {
                        stack[j] = stack[j - 1];
                        j -= 1;
                    }
                    stack[j] = e;
                }
                sp -= 1;
                cur = stack[sp];
                continue;
            }
        } else {
            let (spare_at, leaf_tmax) = (sp, tmax);
            let end = leaves.leaf(
                cur.child,
                cur.count,
                ray,
                tmin,
                &mut tmax,
                visitor,
                &mut stack[spare_at..],
            );
            if end == LeafEnd::Stop {
                return (tmax, true);
            }
            if tmax != leaf_tmax {
                box_tmax = tmax * TMAX_SLACK;
            }
        }
        // Pop the next entry that may still hold a hit.
        loop {
            if sp == 0 {
                return (tmax, false);
            }
            sp -= 1;
            cur = stack[sp];
            if cur.dist <= box_tmax {
                break;
            }
        }
    }
}

/// Defines a [`traverse`] over one SIMD node layout, the whole kernel (leaf tests and visitor
/// included) compiled with the layout's instruction set.
macro_rules! simd_kernel {
    ($(#[$doc:meta])* $name:ident, $node:ty, $layout:ty, $features:literal) => {
        $(#[$doc])*
        ///
        /// # Safety
        ///
        /// The processor must have the features this function is compiled with (checked by
        /// [`crate::Isa::is_available`] for the kernel that walks this layout).
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        pub(crate) unsafe fn $name<L: LeafIntersector<V>, V: GasVisitor>(
            nodes: &[$node],
            leaves: &L,
            ray: &PreparedRay,
            tmin: f32,
            tmax: f32,
            visitor: &mut V,
            stack: &mut [Entry],
        ) -> (f32, bool) {
            traverse::<$layout, L, V>(nodes, leaves, ray, tmin, tmax, visitor, stack)
        }
    };
}

simd_kernel!(
    /// [`traverse`] over 8-wide nodes with AVX2 ([`crate::Isa::Avx2`]).
    traverse_avx2,
    oxray_bvh::Bvh8Node,
    super::node::Bvh8Avx2,
    "avx2,bmi1,bmi2,lzcnt,popcnt"
);
simd_kernel!(
    /// [`traverse`] over 8-wide nodes with AVX-512 (VL) compares ([`crate::Isa::Avx512`]).
    traverse_avx512,
    oxray_bvh::Bvh8Node,
    super::node::Bvh8Avx512,
    "avx2,bmi1,bmi2,lzcnt,popcnt,avx512f,avx512vl"
);
simd_kernel!(
    /// [`traverse`] over quantised 8-wide nodes with AVX2 ([`crate::Isa::Avx2Quantized`]).
    traverse_q_avx2,
    oxray_bvh::QBvh8Node,
    super::node::QBvh8Avx2,
    "avx2,bmi1,bmi2,lzcnt,popcnt"
);
simd_kernel!(
    /// [`traverse`] over quantised 8-wide nodes with AVX-512 (VL) compares
    /// ([`crate::Isa::Avx512Quantized`]).
    traverse_q_avx512,
    oxray_bvh::QBvh8Node,
    super::node::QBvh8Avx512,
    "avx2,bmi1,bmi2,lzcnt,popcnt,avx512f,avx512vl"
);
