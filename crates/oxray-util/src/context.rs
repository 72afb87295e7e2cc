//! The util context: creates scenes, materials and pipelines over one device context.

use crate::pipeline::ScenePipeline;
use crate::scene::{Material, Scene};
use oxray::{DeviceContext, PipelineCompileOptions, PipelineLinkOptions, ProgramGroup};

/// The entry point of the scene layer (design: "Context creates Materials, Scenes and
/// Pipelines"). Materials are values that scenes take with [`Scene::add_material`].
#[derive(Clone, Default)]
pub struct Context {
    device: DeviceContext,
}

impl Context {
    /// A context over `device`.
    #[must_use]
    pub fn new(device: DeviceContext) -> Self {
        Context { device }
    }

    /// The device context.
    #[must_use]
    pub fn device(&self) -> &DeviceContext {
        &self.device
    }

    /// A new, empty scene.
    #[must_use]
    pub fn create_scene<P>(&self) -> Scene<P> {
        Scene::new()
    }

    /// A material with one hit group per ray type and a user value.
    #[must_use]
    pub fn create_material<P>(
        &self,
        hit_groups: Vec<Option<ProgramGroup<P>>>,
        user_data: u32,
    ) -> Material<P> {
        Material::new(hit_groups, user_data)
    }

    /// A pipeline over scenes: ray generation and one miss program per ray type.
    #[must_use]
    pub fn create_pipeline<P: Clone + Sync>(
        &self,
        compile: PipelineCompileOptions,
        link: PipelineLinkOptions,
        raygen: ProgramGroup<P>,
        miss: Vec<ProgramGroup<P>>,
    ) -> ScenePipeline<P> {
        ScenePipeline::new(&self.device, compile, link, raygen, miss)
    }
}
