//! Device context, pipelines (guide §4, §6.7) and launches (§10).

use crate::program::{run_raygen, LaunchShared, ProgramGroup, ProgramGroupKind, Scratch};
use crate::traversal::HeldStack;
use oxray_core::sbt::{SbtHeader, SbtRegion, ShaderBindingTable};
use oxray_core::{
    DeviceContext, Exception, LaunchError, LaunchReport, PipelineCompileOptions, PipelineError,
    PipelineLinkOptions, MAX_TRAVERSABLE_GRAPH_DEPTH,
};
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::Arc;

/// Launch indices per parallel task: enough to make the task's set-up negligible, few enough
/// that a launch of a few thousand indices still spreads over every core.
const LAUNCH_CHUNK: usize = 64;

pub(crate) struct PipelineShared<P> {
    pub compile: PipelineCompileOptions,
    pub link: PipelineLinkOptions,
    /// Deepest traversable graph a trace may enter (`optixPipelineSetStackSize`'s last
    /// argument); 31 unless set.
    pub max_traversable_graph_depth: u32,
    pub validation_mode: bool,
    pub groups: Vec<ProgramGroup<P>>,
    by_id: HashMap<u64, usize>,
    context: DeviceContext,
}

/// A pipeline (`OptixPipeline`): program groups linked with their options, ready to launch.
/// `P` is the type of the launch parameters.
#[doc(alias = "OptixPipeline")]
pub struct Pipeline<P> {
    shared: Arc<PipelineShared<P>>,
}

impl<P> Pipeline<P> {
    /// Links a pipeline (`optixPipelineCreate`), checking the options against the guide's
    /// limits (§12).
    #[doc(alias = "optixPipelineCreate")]
    pub fn new(
        context: &DeviceContext,
        compile: &PipelineCompileOptions,
        link: &PipelineLinkOptions,
        groups: &[ProgramGroup<P>],
    ) -> Result<Self, PipelineError> {
        if compile.num_payload_values > 32 {
            return Err(PipelineError::TooManyPayloadValues(
                compile.num_payload_values,
            ));
        }
        if compile.num_attribute_values > 8 {
            return Err(PipelineError::TooManyAttributeValues(
                compile.num_attribute_values,
            ));
        }
        if link.max_trace_depth > 31 {
            return Err(PipelineError::TraceDepthTooLarge(link.max_trace_depth));
        }
        if groups.is_empty() {
            return Err(PipelineError::NoProgramGroups);
        }
        let by_id = groups
            .iter()
            .enumerate()
            .map(|(i, g)| (g.inner.id, i))
            .collect();
        Ok(Pipeline {
            shared: Arc::new(PipelineShared {
                compile: *compile,
                link: *link,
                max_traversable_graph_depth: MAX_TRAVERSABLE_GRAPH_DEPTH,
                validation_mode: context.is_validation_mode(),
                groups: groups.to_vec(),
                by_id,
                context: context.clone(),
            }),
        })
    }

    fn resolve(
        &self,
        region: &SbtRegion,
        name: &'static str,
        kind: ProgramGroupKind,
    ) -> Result<Vec<usize>, LaunchError> {
        (0..region.count())
            .map(|i| {
                let bytes = region.record(i).unwrap_or(&[]);
                let bad = |reason| LaunchError::InvalidSbtRecord {
                    region: name,
                    index: i,
                    reason,
                };
                let id = SbtHeader::group_id(bytes)
                    .ok_or(bad("the header was not packed from a program group"))?;
                let g = *self
                    .shared
                    .by_id
                    .get(&id)
                    .ok_or(bad("the header's program group is not in this pipeline"))?;
                if self.shared.groups[g].kind() != kind {
                    return Err(bad("the header's program group is of another kind"));
                }
                Ok(g)
            })
            .collect()
    }

    /// Launches `width * height * depth` ray-generation programs in parallel (`optixLaunch`).
    /// The parameters are copied first (guide §10). Each launch index runs independently; one
    /// that raises an exception ends there, runs the exception program if the SBT has one, and
    /// is counted in the report. Without an exception record the built-in exception program of
    /// guide §13.14 stands in: the first five exceptions (by launch index) are sent to the
    /// context's log callback at [`LogLevel::Error`](oxray_core::LogLevel::Error) if one is set, and otherwise printed to
    /// stderr, one line each: `[oxray][EXCEPTION] launch index [x, y, z]: <exception>`. In
    /// validation mode they are also logged with an exception record.
    #[doc(alias = "optixLaunch")]
    pub fn launch(
        &self,
        params: &P,
        sbt: &ShaderBindingTable,
        width: u32,
        height: u32,
        depth: u32,
    ) -> Result<LaunchReport, LaunchError>
    where
        P: Clone + Sync,
    {
        let total = (width as u64)
            .checked_mul(height as u64)
            .and_then(|x| x.checked_mul(depth as u64))
            .filter(|&t| t <= 1 << 30)
            .ok_or(LaunchError::TooLarge {
                width,
                height,
                depth,
            })?;
        if sbt.raygen.count() == 0 {
            return Err(LaunchError::NoRaygenRecord);
        }
        let raygen = self.resolve(&sbt.raygen, "raygen", ProgramGroupKind::RayGen)?[0];
        let miss_groups = self.resolve(&sbt.miss, "miss", ProgramGroupKind::Miss)?;
        let hit_groups = self.resolve(&sbt.hitgroup, "hitgroup", ProgramGroupKind::HitGroup)?;
        let callable_groups =
            self.resolve(&sbt.callables, "callables", ProgramGroupKind::Callables)?;
        let exception_group = match &sbt.exception {
            Some(r) if r.count() > 0 => {
                Some(self.resolve(r, "exception", ProgramGroupKind::Exception)?[0])
            }
            _ => None,
        };
        // The copy of guide §10: programs see this, not the caller's value.
        let params = params.clone();
        let shared = LaunchShared {
            pipeline: &self.shared,
            params: &params,
            sbt,
            miss_groups: &miss_groups,
            hit_groups: &hit_groups,
            exception_group,
            callable_groups: &callable_groups,
            dims: [width, height, depth],
        };
        // `total` is at most 2^30, so indices fit 32 bits. Each task walks a run of consecutive
        // indices, stepping the 3-D index instead of dividing for every one.
        let (w, h) = (width.max(1), height.max(1));
        let index_of = |i: u32| [i % w, (i / w) % h, i / (w * h)];
        let chunks = (total as usize).div_ceil(LAUNCH_CHUNK);
        // Each chunk keeps its first five exceptions and counts its traces; chunks are
        // combined in index order.
        type Chunk = (u64, Vec<([u32; 3], Exception)>, u64);
        let (count, first, traces): Chunk = (0..chunks)
            .into_par_iter()
            .fold(
                || (0u64, Vec::new(), 0u64),
                |(mut n, mut first, t0), c| {
                    let start = (c * LAUNCH_CHUNK) as u32;
                    let end = (start as u64 + LAUNCH_CHUNK as u64).min(total) as u32;
                    let scratch = Scratch {
                        traces: std::cell::Cell::new(t0),
                        stack: HeldStack::take(),
                    };
                    let mut index = index_of(start);
                    for _ in start..end {
                        if let Some(e) = run_raygen(&shared, index, raygen, &scratch) {
                            n += 1;
                            if first.len() < 5 {
                                first.push((index, e));
                            }
                        }
                        index[0] += 1;
                        if index[0] == w {
                            index[0] = 0;
                            index[1] += 1;
                            if index[1] == h {
                                index[1] = 0;
                                index[2] += 1;
                            }
                        }
                    }
                    (n, first, scratch.traces.get())
                },
            )
            .reduce(
                || (0u64, Vec::new(), 0u64),
                |(n1, mut f1, t1), (n2, f2, t2)| {
                    f1.extend(f2);
                    f1.truncate(5);
                    (n1 + n2, f1, t1 + t2)
                },
            );
        LaunchReport {
            exceptions: count,
            first_exceptions: first,
            traces,
        }
        .settle(&self.shared.context, exception_group.is_some())
    }
}

impl<P> Clone for PipelineShared<P> {
    fn clone(&self) -> Self {
        PipelineShared {
            compile: self.compile,
            link: self.link,
            max_traversable_graph_depth: self.max_traversable_graph_depth,
            validation_mode: self.validation_mode,
            groups: self.groups.clone(),
            by_id: self.by_id.clone(),
            context: self.context.clone(),
        }
    }
}

impl<P> Pipeline<P> {
    /// Sets the deepest traversable graph a trace may enter (the last argument of
    /// `optixPipelineSetStackSize`, guide §6.8; at most 31, the default). A trace of a deeper
    /// graph raises `TRAVERSAL_DEPTH_EXCEEDED`. Clones of this pipeline keep their setting.
    #[doc(alias = "optixPipelineSetStackSize")]
    pub fn set_max_traversable_graph_depth(&mut self, depth: u32) -> Result<(), PipelineError> {
        if depth == 0 || depth > MAX_TRAVERSABLE_GRAPH_DEPTH {
            return Err(PipelineError::InvalidGraphDepth(depth));
        }
        std::sync::Arc::make_mut(&mut self.shared).max_traversable_graph_depth = depth;
        Ok(())
    }
}

impl<P> Clone for Pipeline<P> {
    fn clone(&self) -> Self {
        Pipeline {
            shared: self.shared.clone(),
        }
    }
}
