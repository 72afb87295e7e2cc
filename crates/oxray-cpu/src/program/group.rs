//! Program groups (guide §6.6): the unit an SBT record names.

use crate::program::module::{
    AnyHitFn, ClosestHitFn, ContinuationCallableFn, DirectCallableFn, ExceptionFn, IntersectionFn,
    MissFn, Module, Program, ProgramKind, RayGenFn,
};
use oxray_core::PipelineError;
use oxray_core::SbtHeader;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

static NEXT_GROUP_ID: AtomicU64 = AtomicU64::new(1);

/// The kind of a program group (`OptixProgramGroupKind`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[doc(alias = "OptixProgramGroupKind")]
pub enum ProgramGroupKind {
    /// One ray-generation program.
    RayGen,
    /// One miss program, or none (a no-op miss).
    Miss,
    /// One exception program.
    Exception,
    /// Closest-hit, any-hit and intersection programs, each optional.
    HitGroup,
    /// A direct and/or a continuation callable sharing one SBT record.
    Callables,
}

pub(crate) enum GroupPrograms<P> {
    RayGen(RayGenFn<P>),
    Miss(Option<MissFn<P>>),
    Exception(ExceptionFn<P>),
    HitGroup {
        closest_hit: Option<ClosestHitFn<P>>,
        any_hit: Option<AnyHitFn<P>>,
        intersection: Option<IntersectionFn<P>>,
    },
    Callables {
        direct: Option<DirectCallableFn<P>>,
        continuation: Option<ContinuationCallableFn<P>>,
    },
}

pub(crate) struct GroupInner<P> {
    pub id: u64,
    pub programs: GroupPrograms<P>,
}

/// A program group. Cheap to clone; one group may serve any number of SBT records and
/// pipelines.
pub struct ProgramGroup<P> {
    pub(crate) inner: Arc<GroupInner<P>>,
}

impl<P> Clone for ProgramGroup<P> {
    fn clone(&self) -> Self {
        ProgramGroup {
            inner: self.inner.clone(),
        }
    }
}

/// The programs of a hit group: each is `(module, entry name)` or absent. Triangles need no
/// intersection program; custom primitives do.
pub struct HitGroupDesc<'a, P> {
    /// Closest-hit program.
    pub closest_hit: Option<(&'a Module<P>, &'a str)>,
    /// Any-hit program.
    pub any_hit: Option<(&'a Module<P>, &'a str)>,
    /// Intersection program.
    pub intersection: Option<(&'a Module<P>, &'a str)>,
}

impl<P> Default for HitGroupDesc<'_, P> {
    fn default() -> Self {
        HitGroupDesc {
            closest_hit: None,
            any_hit: None,
            intersection: None,
        }
    }
}

fn unknown(name: &str, kind: ProgramKind) -> PipelineError {
    PipelineError::UnknownEntry {
        name: name.to_string(),
        kind: kind.name(),
    }
}

impl<P> ProgramGroup<P> {
    fn new(programs: GroupPrograms<P>) -> Self {
        ProgramGroup {
            inner: Arc::new(GroupInner {
                id: NEXT_GROUP_ID.fetch_add(1, Ordering::Relaxed),
                programs,
            }),
        }
    }

    /// A ray-generation group.
    pub fn raygen(module: &Module<P>, entry: &str) -> Result<Self, PipelineError> {
        match module.get(entry) {
            Some(Program::RayGen(f)) => Ok(Self::new(GroupPrograms::RayGen(f.clone()))),
            _ => Err(unknown(entry, ProgramKind::RayGen)),
        }
    }

    /// A miss group; `None` makes a miss group that does nothing.
    pub fn miss(entry: Option<(&Module<P>, &str)>) -> Result<Self, PipelineError> {
        let f = match entry {
            None => None,
            Some((m, name)) => match m.get(name) {
                Some(Program::Miss(f)) => Some(f.clone()),
                _ => return Err(unknown(name, ProgramKind::Miss)),
            },
        };
        Ok(Self::new(GroupPrograms::Miss(f)))
    }

    /// An exception group.
    pub fn exception(module: &Module<P>, entry: &str) -> Result<Self, PipelineError> {
        match module.get(entry) {
            Some(Program::Exception(f)) => Ok(Self::new(GroupPrograms::Exception(f.clone()))),
            _ => Err(unknown(entry, ProgramKind::Exception)),
        }
    }

    /// A hit group.
    pub fn hit_group(desc: HitGroupDesc<'_, P>) -> Result<Self, PipelineError> {
        let closest_hit = match desc.closest_hit {
            None => None,
            Some((m, name)) => match m.get(name) {
                Some(Program::ClosestHit(f)) => Some(f.clone()),
                _ => return Err(unknown(name, ProgramKind::ClosestHit)),
            },
        };
        let any_hit = match desc.any_hit {
            None => None,
            Some((m, name)) => match m.get(name) {
                Some(Program::AnyHit(f)) => Some(f.clone()),
                _ => return Err(unknown(name, ProgramKind::AnyHit)),
            },
        };
        let intersection = match desc.intersection {
            None => None,
            Some((m, name)) => match m.get(name) {
                Some(Program::Intersection(f)) => Some(f.clone()),
                _ => return Err(unknown(name, ProgramKind::Intersection)),
            },
        };
        Ok(Self::new(GroupPrograms::HitGroup {
            closest_hit,
            any_hit,
            intersection,
        }))
    }

    /// A callables group: a direct callable, a continuation callable, or both (one SBT record).
    pub fn callables(
        direct: Option<(&Module<P>, &str)>,
        continuation: Option<(&Module<P>, &str)>,
    ) -> Result<Self, PipelineError> {
        if direct.is_none() && continuation.is_none() {
            return Err(PipelineError::EmptyCallables);
        }
        let direct = match direct {
            None => None,
            Some((m, name)) => match m.get(name) {
                Some(Program::DirectCallable(f)) => Some(f.clone()),
                _ => return Err(unknown(name, ProgramKind::DirectCallable)),
            },
        };
        let continuation = match continuation {
            None => None,
            Some((m, name)) => match m.get(name) {
                Some(Program::ContinuationCallable(f)) => Some(f.clone()),
                _ => return Err(unknown(name, ProgramKind::ContinuationCallable)),
            },
        };
        Ok(Self::new(GroupPrograms::Callables {
            direct,
            continuation,
        }))
    }

    /// The group's kind.
    #[must_use]
    pub fn kind(&self) -> ProgramGroupKind {
        match &self.inner.programs {
            GroupPrograms::RayGen(_) => ProgramGroupKind::RayGen,
            GroupPrograms::Miss(_) => ProgramGroupKind::Miss,
            GroupPrograms::Exception(_) => ProgramGroupKind::Exception,
            GroupPrograms::HitGroup { .. } => ProgramGroupKind::HitGroup,
            GroupPrograms::Callables { .. } => ProgramGroupKind::Callables,
        }
    }

    /// The record header naming this group (`optixSbtRecordPackHeader`).
    #[doc(alias = "optixSbtRecordPackHeader")]
    #[must_use]
    pub fn pack_header(&self) -> SbtHeader {
        SbtHeader::for_group(self.inner.id)
    }
}
