//! Modules: programs registered under OptiX-style entry names.

use crate::interrupt::{Interrupt, ProgramResult};
use crate::program::context::{
    AnyHitCtx, ClosestHitCtx, ContinuationCallableCtx, DirectCallableCtx, ExceptionCtx,
    IntersectionCtx, MissCtx, RayGenCtx,
};
use oxray_core::PipelineError;
use std::any::Any;
use std::collections::HashMap;
use std::sync::Arc;

/// The eight program kinds and their entry-name prefixes (guide §6.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ProgramKind {
    /// `__raygen__`.
    RayGen,
    /// `__intersection__`.
    Intersection,
    /// `__anyhit__`.
    AnyHit,
    /// `__closesthit__`.
    ClosestHit,
    /// `__miss__`.
    Miss,
    /// `__exception__`.
    Exception,
    /// `__direct_callable__`.
    DirectCallable,
    /// `__continuation_callable__`.
    ContinuationCallable,
}

impl ProgramKind {
    /// The entry-name prefix of this kind.
    #[must_use]
    pub const fn prefix(self) -> &'static str {
        match self {
            ProgramKind::RayGen => "__raygen__",
            ProgramKind::Intersection => "__intersection__",
            ProgramKind::AnyHit => "__anyhit__",
            ProgramKind::ClosestHit => "__closesthit__",
            ProgramKind::Miss => "__miss__",
            ProgramKind::Exception => "__exception__",
            ProgramKind::DirectCallable => "__direct_callable__",
            ProgramKind::ContinuationCallable => "__continuation_callable__",
        }
    }

    /// A short name for messages.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            ProgramKind::RayGen => "ray-generation",
            ProgramKind::Intersection => "intersection",
            ProgramKind::AnyHit => "any-hit",
            ProgramKind::ClosestHit => "closest-hit",
            ProgramKind::Miss => "miss",
            ProgramKind::Exception => "exception",
            ProgramKind::DirectCallable => "direct-callable",
            ProgramKind::ContinuationCallable => "continuation-callable",
        }
    }
}

pub(crate) type RayGenFn<P> = Arc<dyn Fn(&mut RayGenCtx<'_, P>) -> ProgramResult + Send + Sync>;
pub(crate) type ClosestHitFn<P> =
    Arc<dyn Fn(&mut ClosestHitCtx<'_, P>) -> ProgramResult + Send + Sync>;
pub(crate) type AnyHitFn<P> = Arc<dyn Fn(&mut AnyHitCtx<'_, P>) -> ProgramResult + Send + Sync>;
pub(crate) type MissFn<P> = Arc<dyn Fn(&mut MissCtx<'_, P>) -> ProgramResult + Send + Sync>;
pub(crate) type IntersectionFn<P> =
    Arc<dyn Fn(&mut IntersectionCtx<'_, '_, P>) -> ProgramResult + Send + Sync>;
pub(crate) type ExceptionFn<P> = Arc<dyn Fn(&mut ExceptionCtx<'_, P>) + Send + Sync>;
/// A callable behind type erasure: `slot` is the caller's `(Option<A>, Option<R>)`; a slot of
/// other types is a parameter mismatch (`Ok(false)`).
pub(crate) type DirectCallableFn<P> = Arc<
    dyn Fn(&mut DirectCallableCtx<'_, P>, &mut dyn Any) -> Result<bool, Interrupt> + Send + Sync,
>;
pub(crate) type ContinuationCallableFn<P> = Arc<
    dyn Fn(&mut ContinuationCallableCtx<'_, P>, &mut dyn Any) -> Result<bool, Interrupt>
        + Send
        + Sync,
>;

/// A registered program.
pub(crate) enum Program<P> {
    RayGen(RayGenFn<P>),
    ClosestHit(ClosestHitFn<P>),
    AnyHit(AnyHitFn<P>),
    Miss(MissFn<P>),
    Intersection(IntersectionFn<P>),
    Exception(ExceptionFn<P>),
    DirectCallable(DirectCallableFn<P>),
    ContinuationCallable(ContinuationCallableFn<P>),
}

impl<P> Clone for Program<P> {
    fn clone(&self) -> Self {
        match self {
            Program::RayGen(f) => Program::RayGen(f.clone()),
            Program::ClosestHit(f) => Program::ClosestHit(f.clone()),
            Program::AnyHit(f) => Program::AnyHit(f.clone()),
            Program::Miss(f) => Program::Miss(f.clone()),
            Program::Intersection(f) => Program::Intersection(f.clone()),
            Program::Exception(f) => Program::Exception(f.clone()),
            Program::DirectCallable(f) => Program::DirectCallable(f.clone()),
            Program::ContinuationCallable(f) => Program::ContinuationCallable(f.clone()),
        }
    }
}

/// A module: Rust programs registered under OptiX entry names (the counterpart of a compiled
/// PTX or OptiX-IR module). `P` is the type of the launch parameters every program sees.
///
/// ```
/// use oxray_cpu::{Module, ProgramGroup};
/// let module = Module::<()>::new()
///     .raygen("__raygen__main", |ctx| {
///         let _ = ctx.launch_index();
///         Ok(())
///     })?
///     .miss("__miss__background", |_ctx| Ok(()))?;
/// let raygen = ProgramGroup::raygen(&module, "__raygen__main")?;
/// # let _ = raygen;
/// # Ok::<(), oxray_core::PipelineError>(())
/// ```
pub struct Module<P> {
    pub(crate) programs: HashMap<String, Program<P>>,
}

impl<P> Default for Module<P> {
    fn default() -> Self {
        Module {
            programs: HashMap::new(),
        }
    }
}

impl<P> Module<P> {
    /// An empty module.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    fn add(mut self, name: &str, kind: ProgramKind, p: Program<P>) -> Result<Self, PipelineError> {
        if !name.starts_with(kind.prefix()) || name.len() == kind.prefix().len() {
            return Err(PipelineError::BadEntryName {
                name: name.to_string(),
                kind: kind.name(),
                prefix: kind.prefix(),
            });
        }
        if self.programs.insert(name.to_string(), p).is_some() {
            return Err(PipelineError::DuplicateEntry(name.to_string()));
        }
        Ok(self)
    }

    /// Registers a ray-generation program (`__raygen__*`).
    pub fn raygen(
        self,
        name: &str,
        f: impl Fn(&mut RayGenCtx<'_, P>) -> ProgramResult + Send + Sync + 'static,
    ) -> Result<Self, PipelineError> {
        self.add(name, ProgramKind::RayGen, Program::RayGen(Arc::new(f)))
    }

    /// Registers a closest-hit program (`__closesthit__*`).
    pub fn closest_hit(
        self,
        name: &str,
        f: impl Fn(&mut ClosestHitCtx<'_, P>) -> ProgramResult + Send + Sync + 'static,
    ) -> Result<Self, PipelineError> {
        self.add(
            name,
            ProgramKind::ClosestHit,
            Program::ClosestHit(Arc::new(f)),
        )
    }

    /// Registers an any-hit program (`__anyhit__*`).
    pub fn any_hit(
        self,
        name: &str,
        f: impl Fn(&mut AnyHitCtx<'_, P>) -> ProgramResult + Send + Sync + 'static,
    ) -> Result<Self, PipelineError> {
        self.add(name, ProgramKind::AnyHit, Program::AnyHit(Arc::new(f)))
    }

    /// Registers a miss program (`__miss__*`).
    pub fn miss(
        self,
        name: &str,
        f: impl Fn(&mut MissCtx<'_, P>) -> ProgramResult + Send + Sync + 'static,
    ) -> Result<Self, PipelineError> {
        self.add(name, ProgramKind::Miss, Program::Miss(Arc::new(f)))
    }

    /// Registers an intersection program (`__intersection__*`) for custom primitives.
    pub fn intersection(
        self,
        name: &str,
        f: impl Fn(&mut IntersectionCtx<'_, '_, P>) -> ProgramResult + Send + Sync + 'static,
    ) -> Result<Self, PipelineError> {
        self.add(
            name,
            ProgramKind::Intersection,
            Program::Intersection(Arc::new(f)),
        )
    }

    /// Registers an exception program (`__exception__*`).
    pub fn exception(
        self,
        name: &str,
        f: impl Fn(&mut ExceptionCtx<'_, P>) + Send + Sync + 'static,
    ) -> Result<Self, PipelineError> {
        self.add(
            name,
            ProgramKind::Exception,
            Program::Exception(Arc::new(f)),
        )
    }

    /// Registers a direct callable (`__direct_callable__*`) taking `A` and returning `R`
    /// (guide §15). Callers must use the same types; a mismatch raises
    /// `CALLABLE_PARAMETER_MISMATCH`.
    pub fn direct_callable<A: 'static, R: 'static>(
        self,
        name: &str,
        f: impl Fn(&mut DirectCallableCtx<'_, P>, A) -> Result<R, Interrupt> + Send + Sync + 'static,
    ) -> Result<Self, PipelineError> {
        let erased = move |ctx: &mut DirectCallableCtx<'_, P>, slot: &mut dyn Any| {
            fill_slot(slot, |args| f(ctx, args))
        };
        self.add(
            name,
            ProgramKind::DirectCallable,
            Program::DirectCallable(Arc::new(erased)),
        )
    }

    /// Registers a continuation callable (`__continuation_callable__*`) taking `A` and
    /// returning `R`; unlike a direct callable it may trace.
    pub fn continuation_callable<A: 'static, R: 'static>(
        self,
        name: &str,
        f: impl Fn(&mut ContinuationCallableCtx<'_, P>, A) -> Result<R, Interrupt>
            + Send
            + Sync
            + 'static,
    ) -> Result<Self, PipelineError> {
        let erased = move |ctx: &mut ContinuationCallableCtx<'_, P>, slot: &mut dyn Any| {
            fill_slot(slot, |args| f(ctx, args))
        };
        self.add(
            name,
            ProgramKind::ContinuationCallable,
            Program::ContinuationCallable(Arc::new(erased)),
        )
    }

    pub(crate) fn get(&self, name: &str) -> Option<&Program<P>> {
        self.programs.get(name)
    }
}

/// Runs a typed callable on the caller's `(Option<A>, Option<R>)` slot behind type erasure:
/// `Ok(false)` if the slot holds other types (a parameter mismatch).
fn fill_slot<A: 'static, R: 'static>(
    slot: &mut dyn Any,
    call: impl FnOnce(A) -> Result<R, Interrupt>,
) -> Result<bool, Interrupt> {
    let Some(slot) = slot.downcast_mut::<(Option<A>, Option<R>)>() else {
        return Ok(false);
    };
    let Some(args) = slot.0.take() else {
        return Ok(false);
    };
    slot.1 = Some(call(args)?);
    Ok(true)
}
