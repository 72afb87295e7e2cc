//! Prefetch hints: traversal is bound by the latency of loading nodes and primitives it has
//! not touched before (a profile of incoherent rays on a 124k-triangle mesh spends a third of
//! its time waiting on the first load of a node or a triangle block). Asking for every cache
//! line of a child as soon as it is known to be entered overlaps those misses with each other
//! and with the work on the current node.

/// Bytes of one cache line.
const LINE: usize = 64;

/// Asks for the `lines` cache lines from `p` to be loaded. A hint: it never faults, whatever
/// the address, and does nothing on targets without a stable prefetch instruction.
#[inline(always)]
pub(crate) fn prefetch<T>(p: *const T, lines: usize) {
    #[cfg(target_arch = "x86_64")]
    for k in 0..lines {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        // SAFETY: a prefetch is only a hint to the cache: it reads nothing the program sees and
        // does not fault on any address (the pointer is not dereferenced), and SSE is part of
        // the x86-64 baseline.
        unsafe { _mm_prefetch::<_MM_HINT_T0>(p.cast::<i8>().wrapping_add(k * LINE)) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (p, lines);
}

/// The cache lines `T` spans from a line boundary.
pub(crate) const fn lines_of<T>() -> usize {
    std::mem::size_of::<T>().div_ceil(LINE)
}
