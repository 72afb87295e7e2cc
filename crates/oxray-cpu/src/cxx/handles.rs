//! The `OptixTraversableHandle` values of CPU structures: C++ programs trace a 64-bit value,
//! which the runtime must turn back into a structure without trusting it as a pointer.
//!
//! [`optix_handle`] registers a structure (weakly: the registry keeps nothing alive) under its
//! address and gives that address as the value. Each launch takes a snapshot of the live
//! structures, so a trace finds its structure without a lock, and a value that names no live
//! structure raises `TRAVERSAL_INVALID_TRAVERSABLE` instead of being followed.

use oxray_core::{TraversableHandle, WeakTraversableHandle};
use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

fn registry() -> &'static Mutex<HashMap<u64, WeakTraversableHandle>> {
    static R: OnceLock<Mutex<HashMap<u64, WeakTraversableHandle>>> = OnceLock::new();
    R.get_or_init(Default::default)
}

/// The `OptixTraversableHandle` value that CUDA C++ programs on the CPU trace for `handle` (0
/// for the null handle). The value stays valid while the structure lives.
///
/// ```
/// use oxray_core::TraversableHandle;
/// assert_eq!(oxray_cpu::cxx::optix_handle(&TraversableHandle::NULL), 0);
/// ```
#[doc(alias = "OptixTraversableHandle")]
#[must_use]
pub fn optix_handle(handle: &TraversableHandle) -> u64 {
    let value = handle.address();
    if value != 0 {
        let mut r = registry().lock().unwrap_or_else(|e| e.into_inner());
        r.retain(|_, w| w.upgrade().is_some());
        r.insert(value, handle.downgrade());
    }
    value
}

/// The live registered structures, for one launch.
pub(crate) fn snapshot() -> Arc<Vec<(u64, TraversableHandle)>> {
    let r = registry().lock().unwrap_or_else(|e| e.into_inner());
    Arc::new(
        r.iter()
            .filter_map(|(v, w)| w.upgrade().map(|h| (*v, h)))
            .collect(),
    )
}
