//! # oxray-util
//!
//! The scene layer over oxray that hides the shader binding table, after the optix_util design:
//! materials carry one hit group per ray type, geometry instances (one per GAS build input) say
//! how many materials they distinguish and bind actual materials per material set, GASes group
//! geometry instances and declare their material sets and ray types, and the hit-group SBT is
//! laid out and filled automatically: one chunk per (GAS, material set), ordered by build input,
//! material and ray type. An instance of a GAS with a material set gets that chunk's offset as
//! its SBT offset, and traces use `stride = ray-type count`, `offset = ray type`.
//!
//! Dirty state is tracked as the design's rules say; using a scene with anything dirty is an
//! error naming what to rebuild.
//!
//! ```
//! use oxray::{Module, ProgramGroup, HitGroupDesc};
//! use oxray_util::{GasDesc, Geometry, GeometryInstance, Material, Scene};
//! let module = Module::<()>::new().closest_hit("__closesthit__ch", |_| Ok(()))?;
//! let hg = ProgramGroup::hit_group(HitGroupDesc { closest_hit: Some((&module, "__closesthit__ch")), ..Default::default() })?;
//! let mut scene = Scene::new();
//! let mat = scene.add_material(Material::new(vec![Some(hg)], 7));
//! let tri = Geometry::Triangles { vertices: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], indices: vec![[0, 1, 2]] };
//! let geom = scene.add_geometry(GeometryInstance::new(tri, 1).material(0, 0, mat));
//! let gas = scene.add_gas(GasDesc::new(vec![geom], vec![1]));
//! scene.build_gas(gas)?;
//! let layout = scene.sbt_layout()?;
//! assert_eq!(layout.hit_group_count(), 1);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![warn(missing_docs)]

mod context;
mod layout;
mod payload;
mod pipeline;
mod scene;

pub use context::Context;
pub use layout::{ChunkInfo, SbtLayout};
pub use payload::{payload_words, read_payload, write_payload};
pub use pipeline::{SceneLaunchError, ScenePipeline};
pub use scene::{
    GasDesc, GasId, GeomId, Geometry, GeometryInstance, HitGroupData, IasId, Material, MaterialId,
    Scene, UtilError, UtilInstance,
};
