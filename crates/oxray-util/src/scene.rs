//! Scene objects: materials, geometry instances, GASes and IASes, with the dirty rules of
//! optix_util-design.md §2 and the automatic hit-group SBT.

use crate::layout::SbtLayout;
use bytemuck::{Pod, Zeroable};
use oxray::{
    Aabb, AabbBuffer, BuildError, BuildFlags, BuildInput, BuildOptions, CustomPrimitiveInput, Gas,
    GeometryFlags, Ias, IndexBuffer, Instance, InstanceFlags, MotionOptions, ProgramGroup,
    SbtIndexOffsets, SbtRegion, SrtData, SrtMotionTransform, Transform, TraversableHandle,
    TriangleInput, VertexBuffer,
};
use std::collections::BTreeMap;
use std::sync::Arc;
use thiserror::Error;

/// A material, by id.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct MaterialId(pub u32);
/// A geometry instance, by id.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct GeomId(pub u32);
/// A GAS of the scene, by id (its position in the scene's GAS order).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct GasId(pub u32);
/// An IAS of the scene, by id.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct IasId(pub u32);

/// What the scene layer refuses.
#[derive(Debug, Error, Clone, PartialEq)]
#[non_exhaustive]
pub enum UtilError {
    /// Something must be rebuilt before use.
    #[error("{what} is dirty: {action}")]
    Dirty {
        /// What is dirty.
        what: String,
        /// What to do.
        action: &'static str,
    },
    /// An id that the scene does not know.
    #[error("unknown {0}")]
    UnknownId(String),
    /// No material is bound at a (material set, material index) a record needs.
    #[error("geometry instance {geom}: no material for material set {set}, material {index}")]
    MissingMaterial {
        /// The geometry instance.
        geom: u32,
        /// The material set.
        set: u32,
        /// The material index.
        index: u32,
    },
    /// A material has no hit group for a ray type the record needs.
    #[error("material {material}: no hit group for ray type {ray_type}")]
    MissingHitGroup {
        /// The material.
        material: u32,
        /// The ray type.
        ray_type: u32,
    },
    /// A GAS has no such material set.
    #[error("GAS {gas}: no material set {set}")]
    NoMaterialSet {
        /// The GAS.
        gas: u32,
        /// The set.
        set: u32,
    },
    /// A build failed.
    #[error(transparent)]
    Build(#[from] BuildError),
}

/// A material: one hit group per ray type and one user value (design §2 R4, R5).
pub struct Material<P> {
    /// Hit group of each ray type (`None`: nothing runs for that ray type).
    pub hit_groups: Vec<Option<ProgramGroup<P>>>,
    /// User data, given to hit programs in [`HitGroupData::material`].
    pub user_data: u32,
}

impl<P> Material<P> {
    /// A material with these hit groups (by ray type) and user value.
    #[must_use]
    pub fn new(hit_groups: Vec<Option<ProgramGroup<P>>>, user_data: u32) -> Self {
        Material {
            hit_groups,
            user_data,
        }
    }
}

/// The data of every hit-group record the scene writes: the user values of the material, the
/// geometry instance and the GAS.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct HitGroupData {
    /// The material's user value.
    pub material: u32,
    /// The geometry instance's user value.
    pub geometry: u32,
    /// The GAS's user value.
    pub gas: u32,
}

/// The geometry of a geometry instance.
#[derive(Clone, Debug, PartialEq)]
pub enum Geometry {
    /// An indexed triangle mesh.
    Triangles {
        /// Vertex positions.
        vertices: Vec<[f32; 3]>,
        /// Index triplets.
        indices: Vec<[u32; 3]>,
    },
    /// Custom primitives, one per box.
    CustomPrimitives {
        /// Boxes.
        aabbs: Vec<Aabb>,
    },
}

/// A geometry instance: one GAS build input (design §2 R2, R6). It fixes how many materials it
/// distinguishes, the per-primitive material index and the per-material geometry flags; actual
/// materials are bound per (material set, material index).
#[derive(Clone, Debug)]
pub struct GeometryInstance {
    /// The geometry.
    pub geometry: Geometry,
    /// Geometry flags of each material; the length is the material count.
    pub material_flags: Vec<GeometryFlags>,
    /// Material index of each primitive (needed with more than one material).
    pub material_indices: Option<Vec<u32>>,
    /// Bound materials by (material set, material index).
    pub materials: BTreeMap<(u32, u32), MaterialId>,
    /// User data, given to hit programs in [`HitGroupData::geometry`].
    pub user_data: u32,
}

impl GeometryInstance {
    /// Geometry distinguishing `num_materials` materials, without flags or bindings.
    #[must_use]
    pub fn new(geometry: Geometry, num_materials: u32) -> Self {
        GeometryInstance {
            geometry,
            material_flags: vec![GeometryFlags::empty(); num_materials.max(1) as usize],
            material_indices: None,
            materials: BTreeMap::new(),
            user_data: 0,
        }
    }

    /// Binds `material` at (material set `set`, material index `index`).
    #[must_use]
    pub fn material(mut self, set: u32, index: u32, material: MaterialId) -> Self {
        self.materials.insert((set, index), material);
        self
    }

    /// Sets the per-primitive material indices.
    #[must_use]
    pub fn material_indices(mut self, indices: Vec<u32>) -> Self {
        self.material_indices = Some(indices);
        self
    }

    /// Sets the geometry flags of material `index`.
    #[must_use]
    pub fn flags(mut self, index: u32, flags: GeometryFlags) -> Self {
        if let Some(f) = self.material_flags.get_mut(index as usize) {
            *f = flags;
        }
        self
    }

    /// Sets the user value.
    #[must_use]
    pub fn user_data(mut self, v: u32) -> Self {
        self.user_data = v;
        self
    }

    fn num_materials(&self) -> u32 {
        self.material_flags.len() as u32
    }
}

/// How a GAS is made: its geometry instances (build inputs, in order), the ray-type count of
/// each of its material sets, build flags and a user value (design §2 R7, R8).
#[derive(Clone, Debug)]
pub struct GasDesc {
    /// Children, in build-input order.
    pub children: Vec<GeomId>,
    /// Ray types of each material set; the length is the number of material sets.
    pub ray_types_per_set: Vec<u32>,
    /// Build flags.
    pub build_flags: BuildFlags,
    /// User data, given to hit programs in [`HitGroupData::gas`].
    pub user_data: u32,
}

impl GasDesc {
    /// A GAS over `children` with these material sets.
    #[must_use]
    pub fn new(children: Vec<GeomId>, ray_types_per_set: Vec<u32>) -> Self {
        GasDesc {
            children,
            ray_types_per_set,
            build_flags: BuildFlags::PREFER_FAST_TRACE,
            user_data: 0,
        }
    }
}

/// An instance in a scene IAS: a GAS with a material set, placed by a transform, and moving
/// with [`UtilInstance::motion`] where it is given.
///
/// ```
/// use oxray::{MotionOptions, SrtData};
/// use oxray_util::{GasId, UtilInstance};
/// // A GAS that slides one unit along x while the shutter is open (times 0 to 1).
/// let mut moving = UtilInstance::new(GasId(0), 0);
/// moving.motion = Some((
///     MotionOptions::new(2, 0.0, 1.0),
///     vec![SrtData::IDENTITY, SrtData { tx: 1.0, ..SrtData::IDENTITY }],
/// ));
/// ```
#[derive(Clone, Debug)]
pub struct UtilInstance {
    /// The GAS.
    pub gas: GasId,
    /// Its material set.
    pub material_set: u32,
    /// Object-to-world transform.
    pub transform: Transform,
    /// User id.
    pub instance_id: u32,
    /// Visibility mask.
    pub visibility_mask: u32,
    /// Flags.
    pub flags: InstanceFlags,
    /// Motion of the GAS under the instance's transform: an SRT motion transform
    /// ([`SrtMotionTransform`], guide §5.10.5) with these options and one key per motion key
    /// is placed between the instance and its GAS, so that the object-to-world transform at a
    /// ray's time is `transform · C(time)`. Tracing it needs a pipeline compiled with
    /// `uses_motion_blur`. `None`: the GAS is placed by `transform` alone.
    pub motion: Option<(MotionOptions, Vec<SrtData>)>,
}

impl UtilInstance {
    /// An instance of `gas` with material set `material_set`, identity transform, id 0, mask
    /// 0xFF.
    #[must_use]
    pub fn new(gas: GasId, material_set: u32) -> Self {
        UtilInstance {
            gas,
            material_set,
            transform: Transform::IDENTITY,
            instance_id: 0,
            visibility_mask: 0xFF,
            flags: InstanceFlags::empty(),
            motion: None,
        }
    }
}

struct GasEntry {
    desc: GasDesc,
    built: Option<Arc<Gas>>,
    dirty: bool,
}

struct IasEntry {
    instances: Vec<UtilInstance>,
    build_flags: BuildFlags,
    built: Option<TraversableHandle>,
    dirty: bool,
}

/// A scene: materials, geometry instances, GASes and IASes, and their hit-group SBT.
pub struct Scene<P> {
    materials: Vec<Material<P>>,
    geoms: Vec<GeometryInstance>,
    gases: Vec<GasEntry>,
    iases: Vec<IasEntry>,
    layout: Option<SbtLayout>,
    sbt_dirty: bool,
}

impl<P> Default for Scene<P> {
    fn default() -> Self {
        Scene {
            materials: Vec::new(),
            geoms: Vec::new(),
            gases: Vec::new(),
            iases: Vec::new(),
            layout: None,
            sbt_dirty: true,
        }
    }
}

impl<P> Scene<P> {
    /// An empty scene.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a material.
    pub fn add_material(&mut self, m: Material<P>) -> MaterialId {
        self.materials.push(m);
        MaterialId(self.materials.len() as u32 - 1)
    }

    /// Changes a material's hit group for a ray type: the hit-group SBT becomes dirty.
    pub fn set_material_hit_group(
        &mut self,
        id: MaterialId,
        ray_type: u32,
        pg: Option<ProgramGroup<P>>,
    ) -> Result<(), UtilError> {
        let m = self
            .materials
            .get_mut(id.0 as usize)
            .ok_or_else(|| UtilError::UnknownId(format!("material {}", id.0)))?;
        if m.hit_groups.len() <= ray_type as usize {
            m.hit_groups.resize_with(ray_type as usize + 1, || None);
        }
        m.hit_groups[ray_type as usize] = pg;
        self.sbt_dirty = true;
        Ok(())
    }

    /// Changes a material's user value: the hit-group SBT becomes dirty.
    pub fn set_material_user_data(&mut self, id: MaterialId, v: u32) -> Result<(), UtilError> {
        let m = self
            .materials
            .get_mut(id.0 as usize)
            .ok_or_else(|| UtilError::UnknownId(format!("material {}", id.0)))?;
        m.user_data = v;
        self.sbt_dirty = true;
        Ok(())
    }

    /// Adds a geometry instance.
    pub fn add_geometry(&mut self, g: GeometryInstance) -> GeomId {
        self.geoms.push(g);
        GeomId(self.geoms.len() as u32 - 1)
    }

    /// Changes a geometry instance. Its geometry, flags or material count may change, so every
    /// GAS holding it becomes dirty (the design leaves this to the user; oxray does it), and with
    /// them the layout, the IASes and the SBT.
    pub fn update_geometry(
        &mut self,
        id: GeomId,
        f: impl FnOnce(&mut GeometryInstance),
    ) -> Result<(), UtilError> {
        let g = self
            .geoms
            .get_mut(id.0 as usize)
            .ok_or_else(|| UtilError::UnknownId(format!("geometry instance {}", id.0)))?;
        f(g);
        let holders: Vec<usize> = (0..self.gases.len())
            .filter(|&i| self.gases[i].desc.children.contains(&id))
            .collect();
        for i in holders {
            self.mark_gas_dirty(i);
        }
        self.sbt_dirty = true;
        Ok(())
    }

    /// Adds a GAS (dirty until built).
    pub fn add_gas(&mut self, desc: GasDesc) -> GasId {
        self.gases.push(GasEntry {
            desc,
            built: None,
            dirty: true,
        });
        self.layout_dirty();
        GasId(self.gases.len() as u32 - 1)
    }

    /// Changes a GAS's description: children or build flags make the GAS dirty; material sets
    /// and ray types make the layout dirty (design §1, Auto rules).
    pub fn update_gas(&mut self, id: GasId, f: impl FnOnce(&mut GasDesc)) -> Result<(), UtilError> {
        let i = id.0 as usize;
        let e = self
            .gases
            .get_mut(i)
            .ok_or_else(|| UtilError::UnknownId(format!("GAS {}", id.0)))?;
        let before = (
            e.desc.children.clone(),
            e.desc.build_flags,
            e.desc.ray_types_per_set.clone(),
            e.desc.user_data,
        );
        f(&mut e.desc);
        if e.desc.children != before.0 || e.desc.build_flags != before.1 {
            self.mark_gas_dirty(i);
        } else if e.desc.ray_types_per_set != before.2 {
            self.layout_dirty();
        } else if e.desc.user_data != before.3 {
            self.sbt_dirty = true;
        }
        Ok(())
    }

    fn mark_gas_dirty(&mut self, i: usize) {
        self.gases[i].dirty = true;
        self.layout_dirty();
    }

    fn layout_dirty(&mut self) {
        self.layout = None;
        self.sbt_dirty = true;
        for ias in &mut self.iases {
            ias.dirty = true;
        }
    }

    fn geom(&self, id: GeomId) -> Result<&GeometryInstance, UtilError> {
        self.geoms
            .get(id.0 as usize)
            .ok_or_else(|| UtilError::UnknownId(format!("geometry instance {}", id.0)))
    }

    /// Builds (or rebuilds) a GAS from its children; returns its handle.
    pub fn build_gas(&mut self, id: GasId) -> Result<TraversableHandle, UtilError> {
        let i = id.0 as usize;
        let desc = &self
            .gases
            .get(i)
            .ok_or_else(|| UtilError::UnknownId(format!("GAS {}", id.0)))?
            .desc;
        let geoms: Vec<&GeometryInstance> = desc
            .children
            .iter()
            .map(|&c| self.geom(c))
            .collect::<Result<_, _>>()?;
        let inputs: Vec<BuildInput<'_>> = geoms
            .iter()
            .map(|g| {
                let offsets = g.material_indices.as_deref().map(SbtIndexOffsets::u32);
                match &g.geometry {
                    Geometry::Triangles { vertices, indices } => {
                        let mut t = TriangleInput::new(VertexBuffer::f32x3(vertices))
                            .indices(IndexBuffer::u32x3(indices))
                            .flags(&g.material_flags);
                        if let Some(o) = offsets {
                            t = t.sbt_index_offsets(o);
                        }
                        t.into()
                    }
                    Geometry::CustomPrimitives { aabbs } => {
                        let mut c = CustomPrimitiveInput::new(AabbBuffer::new(aabbs))
                            .flags(&g.material_flags);
                        if let Some(o) = offsets {
                            c = c.sbt_index_offsets(o);
                        }
                        c.into()
                    }
                }
            })
            .collect();
        let gas = Arc::new(Gas::build(&BuildOptions::new(desc.build_flags), &inputs)?);
        let e = &mut self.gases[i];
        e.built = Some(gas.clone());
        e.dirty = false;
        // A rebuilt GAS has a new handle: IASes over it must be rebuilt (design: manual; oxray
        // does it).
        for ias in &mut self.iases {
            if ias.instances.iter().any(|inst| inst.gas == id) {
                ias.dirty = true;
            }
        }
        Ok(gas.into())
    }

    /// The hit-group SBT layout, computed from the GASes' build inputs, material sets and ray
    /// types (it does not need the GASes built).
    pub fn sbt_layout(&mut self) -> Result<&SbtLayout, UtilError> {
        if self.layout.is_none() {
            let mut per_gas = Vec::with_capacity(self.gases.len());
            for e in &self.gases {
                let mut materials = 0;
                for &c in &e.desc.children {
                    materials += self.geom(c)?.num_materials();
                }
                per_gas.push((materials, e.desc.ray_types_per_set.clone()));
            }
            self.layout = Some(SbtLayout::compute(&per_gas));
        }
        Ok(self.layout.as_ref().expect("computed above"))
    }

    /// Adds an IAS over instances of scene GASes (dirty until built).
    pub fn add_ias(&mut self, instances: Vec<UtilInstance>, build_flags: BuildFlags) -> IasId {
        self.iases.push(IasEntry {
            instances,
            build_flags,
            built: None,
            dirty: true,
        });
        IasId(self.iases.len() as u32 - 1)
    }

    /// Changes an IAS's instances: it becomes dirty.
    pub fn update_ias(
        &mut self,
        id: IasId,
        f: impl FnOnce(&mut Vec<UtilInstance>),
    ) -> Result<(), UtilError> {
        let e = self
            .iases
            .get_mut(id.0 as usize)
            .ok_or_else(|| UtilError::UnknownId(format!("IAS {}", id.0)))?;
        f(&mut e.instances);
        e.dirty = true;
        Ok(())
    }

    /// Builds an IAS: each instance's SBT offset is the layout offset of its (GAS, material
    /// set). Needs the layout and every instanced GAS built and clean.
    pub fn build_ias(&mut self, id: IasId) -> Result<TraversableHandle, UtilError> {
        self.sbt_layout()?;
        let layout = self.layout.as_ref().expect("computed above");
        let e = self
            .iases
            .get(id.0 as usize)
            .ok_or_else(|| UtilError::UnknownId(format!("IAS {}", id.0)))?;
        let mut instances = Vec::with_capacity(e.instances.len());
        for u in &e.instances {
            let g = self
                .gases
                .get(u.gas.0 as usize)
                .ok_or_else(|| UtilError::UnknownId(format!("GAS {}", u.gas.0)))?;
            let built = match (&g.built, g.dirty) {
                (Some(b), false) => b.clone(),
                _ => {
                    return Err(UtilError::Dirty {
                        what: format!("GAS {}", u.gas.0),
                        action: "build it with Scene::build_gas before building the IAS",
                    })
                }
            };
            let chunk = layout
                .chunk(u.gas.0 as usize, u.material_set as usize)
                .ok_or(UtilError::NoMaterialSet {
                    gas: u.gas.0,
                    set: u.material_set,
                })?;
            // The GAS, or the motion transform that moves it (the keys are checked there).
            let child: TraversableHandle = match &u.motion {
                None => built.into(),
                Some((options, keys)) => {
                    SrtMotionTransform::new(built.into(), *options, keys)?.into()
                }
            };
            instances.push(
                Instance::new(child)
                    .transform(u.transform)
                    .instance_id(u.instance_id)
                    .visibility_mask(u.visibility_mask)
                    .flags(u.flags)
                    .sbt_offset(chunk.offset),
            );
        }
        let ias: TraversableHandle = Ias::build(
            &BuildOptions::new(e.build_flags),
            &[(&instances[..]).into()],
        )?
        .into();
        let e = &mut self.iases[id.0 as usize];
        e.built = Some(ias.clone());
        e.dirty = false;
        Ok(ias)
    }

    /// Fails, naming what to rebuild, unless every GAS and IAS is built and clean.
    pub fn check_ready(&self) -> Result<(), UtilError> {
        if let Some(i) = self.gases.iter().position(|g| g.dirty || g.built.is_none()) {
            return Err(UtilError::Dirty {
                what: format!("GAS {i}"),
                action: "rebuild it with Scene::build_gas",
            });
        }
        if let Some(i) = self.iases.iter().position(|g| g.dirty || g.built.is_none()) {
            return Err(UtilError::Dirty {
                what: format!("IAS {i}"),
                action: "rebuild it with Scene::build_ias",
            });
        }
        Ok(())
    }

    /// Rebuilds whatever is dirty: GASes, then the layout, then IASes (beyond the design, which
    /// leaves rebuilding to the user).
    pub fn rebuild_dirty(&mut self) -> Result<(), UtilError> {
        for i in 0..self.gases.len() {
            if self.gases[i].dirty || self.gases[i].built.is_none() {
                self.build_gas(GasId(i as u32))?;
            }
        }
        self.sbt_layout()?;
        for i in 0..self.iases.len() {
            if self.iases[i].dirty || self.iases[i].built.is_none() {
                self.build_ias(IasId(i as u32))?;
            }
        }
        Ok(())
    }

    /// The handle of a built, clean IAS.
    #[must_use]
    pub fn ias_handle(&self, id: IasId) -> Option<TraversableHandle> {
        let e = self.iases.get(id.0 as usize)?;
        (!e.dirty).then(|| e.built.clone()).flatten()
    }

    /// Whether the hit-group SBT must be regenerated (after layout, material or user-data
    /// changes since the last [`hit_group_records`](Self::hit_group_records)).
    #[must_use]
    pub fn is_sbt_dirty(&self) -> bool {
        self.sbt_dirty
    }

    /// The hit-group SBT region, laid out as [`sbt_layout`](Self::sbt_layout) says: chunk by
    /// chunk, then build input, material and ray type. Each record's header is the bound
    /// material's hit group for the ray type and its data a [`HitGroupData`].
    pub fn hit_group_records(&mut self) -> Result<SbtRegion, UtilError> {
        self.sbt_layout()?;
        let layout = self.layout.clone().expect("computed above");
        let mut records = Vec::with_capacity(layout.hit_group_count() as usize);
        for (gi, g) in self.gases.iter().enumerate() {
            for (set, &ray_types) in g.desc.ray_types_per_set.iter().enumerate() {
                debug_assert_eq!(
                    layout.chunk(gi, set).map(|c| c.offset as usize),
                    Some(records.len())
                );
                for &c in &g.desc.children {
                    let geom = self.geom(c)?;
                    for m in 0..geom.num_materials() {
                        let mat_id = *geom.materials.get(&(set as u32, m)).ok_or(
                            UtilError::MissingMaterial {
                                geom: c.0,
                                set: set as u32,
                                index: m,
                            },
                        )?;
                        let mat = self.materials.get(mat_id.0 as usize).ok_or_else(|| {
                            UtilError::UnknownId(format!("material {}", mat_id.0))
                        })?;
                        for r in 0..ray_types {
                            let pg = mat
                                .hit_groups
                                .get(r as usize)
                                .and_then(|p| p.as_ref())
                                .ok_or(UtilError::MissingHitGroup {
                                    material: mat_id.0,
                                    ray_type: r,
                                })?;
                            records.push((
                                pg.pack_header(),
                                HitGroupData {
                                    material: mat.user_data,
                                    geometry: geom.user_data,
                                    gas: g.desc.user_data,
                                },
                            ));
                        }
                    }
                }
            }
        }
        self.sbt_dirty = false;
        Ok(SbtRegion::from_records(&records))
    }

    /// Every distinct hit group the scene's materials use (to link into a pipeline).
    #[must_use]
    pub fn hit_groups(&self) -> Vec<ProgramGroup<P>> {
        let mut out: Vec<ProgramGroup<P>> = Vec::new();
        for m in &self.materials {
            for pg in m.hit_groups.iter().flatten() {
                if !out.iter().any(|o| o.pack_header() == pg.pack_header()) {
                    out.push(pg.clone());
                }
            }
        }
        out
    }

    /// The built GAS, if clean.
    #[must_use]
    pub fn gas_handle(&self, id: GasId) -> Option<TraversableHandle> {
        let e = self.gases.get(id.0 as usize)?;
        (!e.dirty)
            .then(|| e.built.clone().map(Into::into))
            .flatten()
    }

    /// Whether a GAS is dirty.
    #[must_use]
    pub fn is_gas_dirty(&self, id: GasId) -> bool {
        self.gases.get(id.0 as usize).is_none_or(|e| e.dirty)
    }

    /// Whether an IAS is dirty.
    #[must_use]
    pub fn is_ias_dirty(&self, id: IasId) -> bool {
        self.iases.get(id.0 as usize).is_none_or(|e| e.dirty)
    }

    /// Whether the layout must be recomputed.
    #[must_use]
    pub fn is_layout_dirty(&self) -> bool {
        self.layout.is_none()
    }
}
