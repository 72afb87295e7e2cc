//! Traversable handles (guide §5.9): what traces and instances point at.
//!
//! A handle owns what it refers to, so it can never dangle. It is opaque, as
//! `OptixTraversableHandle` is: behind it is an object of one backend (a CPU GAS, a GAS in GPU
//! memory, an IAS, a static transform), which that backend recognises by downcasting. A
//! structure of one device placed under an instance built on another is refused by the build.

use crate::aabb::Aabb;
use std::any::Any;
use std::sync::Arc;

/// The kind of a traversable (`OptixTraversableType`, extended with the acceleration
/// structures).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[doc(alias = "OptixTraversableType")]
pub enum TraversableKind {
    /// A geometry acceleration structure.
    Gas,
    /// An instance acceleration structure.
    Ias,
    /// A static transform.
    StaticTransform,
    /// A matrix motion transform (guide §5.10.4).
    MatrixMotionTransform,
    /// An SRT motion transform (guide §5.10.5).
    SrtMotionTransform,
}

/// Which backend's memory a traversable lives in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BackendKind {
    /// Host memory, traversed by the CPU backend.
    Cpu,
    /// Memory of a CUDA device, traversed by the CUDA backend.
    Cuda,
    /// Data that every backend can read (a static transform over nothing, say).
    Any,
}

impl std::fmt::Display for BackendKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            BackendKind::Cpu => "CPU",
            BackendKind::Cuda => "CUDA",
            BackendKind::Any => "any",
        })
    }
}

/// An object a [`TraversableHandle`] can refer to. Backends implement it for their
/// acceleration structures; the facade's backend-neutral wrappers implement it by handing over
/// the backend object they wrap ([`into_object`](Self::into_object)), so that a handle always
/// refers to a backend object.
pub trait Traversable: Any + Send + Sync {
    /// What it is.
    fn traversable_kind(&self) -> TraversableKind;
    /// The box around everything reachable from it, in its own space.
    fn bounds(&self) -> Aabb;
    /// Levels of the graph below and including it: every acceleration structure and transform
    /// counts one (guide §12; a GAS is 1, an IAS over GASes 2).
    fn graph_depth(&self) -> u32;
    /// The backend whose memory it lives in.
    fn backend(&self) -> BackendKind;
    /// A one-line description, for `Debug`.
    fn describe(&self) -> String;
    /// The identity of an acceleration structure across its updates: a build gives a new
    /// lineage, an update (guide §5.6) or a compaction (§5.8) keeps it. An IAS update accepts
    /// an instance child of the same lineage as the one it was built over (the CPU backend
    /// updates a shared structure by copy-on-write, so an updated child is a new object).
    /// `None` for objects without one (transforms).
    fn lineage(&self) -> Option<u64> {
        None
    }
    /// The backend object a handle should refer to: `self` for a backend object, the wrapped
    /// object for a wrapper.
    fn into_object(self: Arc<Self>) -> Arc<dyn Traversable>
    where
        Self: Sized,
    {
        self
    }
}

/// A traversable handle (`OptixTraversableHandle`): nothing (the null handle, whose traces run
/// only the miss program), or a GAS, an IAS or a transform of some backend. Cloning is cheap
/// and keeps the structure alive.
///
/// ```
/// use oxray_core::{TraversableHandle, TraversableKind};
/// let null = TraversableHandle::NULL;
/// assert!(null.is_null());
/// assert_eq!(null.kind(), None);
/// assert_eq!(null.graph_depth(), 0);
/// ```
#[derive(Clone, Default)]
pub struct TraversableHandle(Option<Arc<dyn Traversable>>);

impl TraversableHandle {
    /// The null handle.
    pub const NULL: TraversableHandle = TraversableHandle(None);

    /// A handle to a traversable.
    pub fn new<T: Traversable>(object: Arc<T>) -> Self {
        TraversableHandle(Some(object.into_object()))
    }

    /// Whether this is the null handle.
    #[must_use]
    pub fn is_null(&self) -> bool {
        self.0.is_none()
    }

    /// What the handle refers to, if anything.
    #[must_use]
    pub fn kind(&self) -> Option<TraversableKind> {
        self.0.as_ref().map(|t| t.traversable_kind())
    }

    /// The backend the structure lives on; `None` for the null handle.
    #[must_use]
    pub fn backend(&self) -> Option<BackendKind> {
        self.0.as_ref().map(|t| t.backend())
    }

    /// The box around everything reachable from the handle, in the handle's space.
    #[must_use]
    pub fn bounds(&self) -> Aabb {
        self.0.as_ref().map_or(Aabb::EMPTY, |t| t.bounds())
    }

    /// Levels of the graph below and including this handle (0 for the null handle).
    #[must_use]
    pub fn graph_depth(&self) -> u32 {
        self.0.as_ref().map_or(0, |t| t.graph_depth())
    }

    /// Whether two handles refer to the same structure.
    #[must_use]
    pub fn same_as(&self, other: &TraversableHandle) -> bool {
        match (&self.0, &other.0) {
            (None, None) => true,
            (Some(a), Some(b)) => std::ptr::addr_eq(Arc::as_ptr(a), Arc::as_ptr(b)),
            _ => false,
        }
    }

    /// The lineage of the structure behind the handle (see [`Traversable::lineage`]).
    #[must_use]
    pub fn lineage(&self) -> Option<u64> {
        self.0.as_ref().and_then(|t| t.lineage())
    }

    /// Whether `other` refers to the same structure as `self`, or to an update (or compaction)
    /// of it: what an IAS update accepts as an unchanged instance child (guide §5.6).
    #[must_use]
    pub fn same_structure(&self, other: &TraversableHandle) -> bool {
        self.same_as(other) || (self.lineage().is_some() && self.lineage() == other.lineage())
    }

    /// The backend object, if the handle refers to a `T`.
    #[must_use]
    pub fn downcast_ref<T: Traversable>(&self) -> Option<&T> {
        let any: &dyn Any = self.0.as_deref()?;
        any.downcast_ref()
    }

    /// A new owner of the backend object, if the handle refers to a `T`.
    #[must_use]
    pub fn downcast_arc<T: Traversable>(&self) -> Option<Arc<T>> {
        let any: Arc<dyn Any + Send + Sync> = self.0.clone()?;
        any.downcast().ok()
    }
}

impl TraversableHandle {
    /// A weak reference to the structure, which does not keep it alive.
    pub fn downgrade(&self) -> WeakTraversableHandle {
        WeakTraversableHandle(self.0.as_ref().map(Arc::downgrade))
    }

    /// A number that identifies the structure while it is alive (its address; 0 for the null
    /// handle). A structure dropped and another made later may be given the same number.
    #[must_use]
    pub fn address(&self) -> u64 {
        self.0
            .as_ref()
            .map_or(0, |t| Arc::as_ptr(t) as *const () as usize as u64)
    }
}

/// A weak [`TraversableHandle`]: it refers to a structure without keeping it alive.
///
/// ```
/// # use oxray_core::TraversableHandle;
/// let weak = TraversableHandle::NULL.downgrade();
/// assert!(weak.upgrade().is_none(), "the null handle upgrades to nothing");
/// ```
#[derive(Clone, Default, Debug)]
pub struct WeakTraversableHandle(Option<std::sync::Weak<dyn Traversable>>);

impl WeakTraversableHandle {
    /// The handle, if the structure is still alive (`None` for a dropped structure and for the
    /// null handle).
    #[must_use]
    pub fn upgrade(&self) -> Option<TraversableHandle> {
        self.0
            .as_ref()
            .and_then(|w| w.upgrade())
            .map(|a| TraversableHandle(Some(a)))
    }
}

impl<T: Traversable> From<T> for TraversableHandle {
    fn from(t: T) -> Self {
        TraversableHandle::new(Arc::new(t))
    }
}

impl<T: Traversable> From<Arc<T>> for TraversableHandle {
    fn from(t: Arc<T>) -> Self {
        TraversableHandle::new(t)
    }
}

impl std::fmt::Debug for TraversableHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.0 {
            None => f.write_str("TraversableHandle(null)"),
            Some(t) => write!(f, "TraversableHandle({})", t.describe()),
        }
    }
}
