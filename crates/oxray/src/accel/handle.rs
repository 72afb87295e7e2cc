//! Traversable handles (guide §5.9): what traces and instances point at. A handle owns what it
//! refers to, so it can never dangle.

use super::gas::Gas;
use super::ias::Ias;
use super::instance::StaticTransform;
use std::sync::Arc;

/// A traversable handle (`OptixTraversableHandle`): nothing (the null handle, whose traces run
/// only the miss program), a GAS, an IAS or a static transform. Cloning is cheap and keeps the
/// structure alive.
#[derive(Clone, Default)]
pub struct TraversableHandle(pub(crate) Option<Traversable>);

#[derive(Clone)]
pub(crate) enum Traversable {
    Gas(Arc<Gas>),
    Ias(Arc<Ias>),
    Static(Arc<StaticTransform>),
}

/// The kind of a traversable (`OptixTraversableType`, extended with the acceleration
/// structures).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TraversableKind {
    /// A geometry acceleration structure.
    Gas,
    /// An instance acceleration structure.
    Ias,
    /// A static transform.
    StaticTransform,
}

impl TraversableHandle {
    /// The null handle.
    pub const NULL: TraversableHandle = TraversableHandle(None);

    /// Whether this is the null handle.
    pub fn is_null(&self) -> bool {
        self.0.is_none()
    }

    /// What the handle refers to, if anything.
    pub fn kind(&self) -> Option<TraversableKind> {
        self.0.as_ref().map(|t| match t {
            Traversable::Gas(_) => TraversableKind::Gas,
            Traversable::Ias(_) => TraversableKind::Ias,
            Traversable::Static(_) => TraversableKind::StaticTransform,
        })
    }

    /// The GAS, if the handle is one.
    pub fn as_gas(&self) -> Option<&Gas> {
        match &self.0 {
            Some(Traversable::Gas(g)) => Some(g),
            _ => None,
        }
    }

    /// The IAS, if the handle is one.
    pub fn as_ias(&self) -> Option<&Ias> {
        match &self.0 {
            Some(Traversable::Ias(g)) => Some(g),
            _ => None,
        }
    }

    /// The box around everything reachable from the handle, in the handle's space.
    pub fn bounds(&self) -> crate::Aabb {
        match &self.0 {
            None => crate::Aabb::EMPTY,
            Some(Traversable::Gas(g)) => g.bounds(),
            Some(Traversable::Ias(i)) => i.bounds(),
            Some(Traversable::Static(s)) => s.transform.transform_aabb(&s.child.bounds()),
        }
    }

    /// Levels of the graph below and including this handle: every acceleration structure and
    /// transform counts one (guide §12; a GAS is 1, an IAS over GASes 2).
    pub fn graph_depth(&self) -> u32 {
        match &self.0 {
            None => 0,
            Some(Traversable::Gas(_)) => 1,
            Some(Traversable::Ias(i)) => i.depth,
            Some(Traversable::Static(s)) => 1 + s.child.graph_depth(),
        }
    }

    /// Whether two handles refer to the same structure.
    pub fn same_as(&self, other: &TraversableHandle) -> bool {
        match (&self.0, &other.0) {
            (None, None) => true,
            (Some(Traversable::Gas(a)), Some(Traversable::Gas(b))) => Arc::ptr_eq(a, b),
            (Some(Traversable::Ias(a)), Some(Traversable::Ias(b))) => Arc::ptr_eq(a, b),
            (Some(Traversable::Static(a)), Some(Traversable::Static(b))) => Arc::ptr_eq(a, b),
            _ => false,
        }
    }
}

impl From<Arc<Gas>> for TraversableHandle {
    fn from(g: Arc<Gas>) -> Self {
        TraversableHandle(Some(Traversable::Gas(g)))
    }
}

impl From<Gas> for TraversableHandle {
    fn from(g: Gas) -> Self {
        Arc::new(g).into()
    }
}

impl From<Arc<Ias>> for TraversableHandle {
    fn from(i: Arc<Ias>) -> Self {
        TraversableHandle(Some(Traversable::Ias(i)))
    }
}

impl From<Ias> for TraversableHandle {
    fn from(i: Ias) -> Self {
        Arc::new(i).into()
    }
}

impl From<Arc<StaticTransform>> for TraversableHandle {
    fn from(s: Arc<StaticTransform>) -> Self {
        TraversableHandle(Some(Traversable::Static(s)))
    }
}

impl From<StaticTransform> for TraversableHandle {
    fn from(s: StaticTransform) -> Self {
        Arc::new(s).into()
    }
}

impl std::fmt::Debug for TraversableHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.0 {
            None => f.write_str("TraversableHandle(null)"),
            Some(Traversable::Gas(g)) => write!(
                f,
                "TraversableHandle(GAS of {} primitives)",
                g.num_primitives()
            ),
            Some(Traversable::Ias(i)) => write!(
                f,
                "TraversableHandle(IAS of {} instances)",
                i.num_instances()
            ),
            Some(Traversable::Static(_)) => f.write_str("TraversableHandle(static transform)"),
        }
    }
}
