//! A pipeline over a scene: ray generation, one miss program per ray type, an optional
//! exception program and callables, with the hit groups and the hit-group SBT taken from the
//! scene at launch.

use crate::scene::{Scene, UtilError};
use oxray::{
    DeviceContext, LaunchError, LaunchReport, Pipeline, PipelineCompileOptions, PipelineError,
    PipelineLinkOptions, ProgramGroup, SbtHeader, SbtRegion, ShaderBindingTable,
};
use thiserror::Error;

/// Why a scene launch failed.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum SceneLaunchError {
    /// The scene is not ready (something dirty), or its SBT could not be generated.
    #[error(transparent)]
    Scene(#[from] UtilError),
    /// Linking failed.
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
    /// The launch was refused.
    #[error(transparent)]
    Launch(#[from] LaunchError),
}

/// A pipeline whose hit-group SBT comes from a [`Scene`]. Miss record `r` is the miss program of
/// ray type `r`, so traces use `miss_index = ray type` as the design says.
pub struct ScenePipeline<P> {
    context: DeviceContext,
    compile: PipelineCompileOptions,
    link: PipelineLinkOptions,
    raygen: ProgramGroup<P>,
    miss: Vec<ProgramGroup<P>>,
    exception: Option<ProgramGroup<P>>,
    callables: Vec<ProgramGroup<P>>,
    /// Rebuild dirty structures and the SBT at launch instead of failing.
    pub auto_rebuild: bool,
}

impl<P: Clone + Sync> ScenePipeline<P> {
    /// A pipeline with this ray-generation group and one miss group per ray type.
    #[must_use]
    pub fn new(
        context: &DeviceContext,
        compile: PipelineCompileOptions,
        link: PipelineLinkOptions,
        raygen: ProgramGroup<P>,
        miss: Vec<ProgramGroup<P>>,
    ) -> Self {
        ScenePipeline {
            context: context.clone(),
            compile,
            link,
            raygen,
            miss,
            exception: None,
            callables: Vec::new(),
            auto_rebuild: false,
        }
    }

    /// Sets the exception program.
    #[must_use]
    pub fn exception(mut self, group: ProgramGroup<P>) -> Self {
        self.exception = Some(group);
        self
    }

    /// Sets the callables, by SBT index.
    #[must_use]
    pub fn callables(mut self, groups: Vec<ProgramGroup<P>>) -> Self {
        self.callables = groups;
        self
    }

    /// Launches over `scene`. With anything dirty the launch fails with an error naming what to
    /// rebuild, unless [`auto_rebuild`](Self::auto_rebuild) is set, in which case dirty GASes,
    /// the layout, the IASes and the SBT are rebuilt first. Params holding traversable handles
    /// must be made after the rebuild (handles of rebuilt structures change).
    pub fn launch(
        &self,
        scene: &mut Scene<P>,
        params: &P,
        width: u32,
        height: u32,
        depth: u32,
    ) -> Result<LaunchReport, SceneLaunchError> {
        if self.auto_rebuild {
            scene.rebuild_dirty()?;
        }
        scene.check_ready()?;
        let hitgroup = scene.hit_group_records()?;
        let mut groups = vec![self.raygen.clone()];
        groups.extend(self.miss.iter().cloned());
        groups.extend(self.exception.iter().cloned());
        groups.extend(self.callables.iter().cloned());
        groups.extend(scene.hit_groups());
        let pipeline = Pipeline::new(&self.context, &self.compile, &self.link, &groups)?;
        let headers = |g: &[ProgramGroup<P>]| -> Vec<SbtHeader> {
            g.iter().map(|g| g.pack_header()).collect()
        };
        let sbt = ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[self.raygen.pack_header()]),
            exception: self
                .exception
                .as_ref()
                .map(|e| SbtRegion::from_headers(&[e.pack_header()])),
            miss: SbtRegion::from_headers(&headers(&self.miss)),
            hitgroup,
            callables: SbtRegion::from_headers(&headers(&self.callables)),
        };
        Ok(pipeline.launch(params, &sbt, width, height, depth)?)
    }
}
