//! The CPU renderer's wavefront: the path tracer's programs run over tiles of paths, one ray
//! kind at a time, straight on the CPU backend's queries instead of through the pipeline.
//!
//! A pass traces one sample of every pixel. The launch's pixels are cut into fixed tiles of
//! [`TILE`] consecutive pixels (the same whatever the thread count), a tile per rayon task.
//! A tile keeps its paths' states side by side and advances them in lock step: the rays of
//! every live path, traced as one batch (a small structure is tested whole sixteen rays at a
//! time; in others camera rays from a pinhole go as packets of eight,
//! [`oxray::cpu::Gas::intersect_batch`]), then every path's vertex shaded (emission, light
//! samples, the BSDF sample), then the light samples' shadow rays as one occlusion batch, then
//! their radiance added to the paths they are not blocked for. A batch of one ray kind keeps
//! the traversal's code and data hot; the pipeline traced each path's rays in turn, a camera,
//! closest-hit and shadow ray interleaved, each through the launch's program dispatch.
//!
//! The shading is the pipeline's own ([`programs::vertex`], [`programs::camera_path`],
//! [`programs::miss_environment`], [`programs::accumulate`]), fed the same hits, random
//! numbers and shadow answers in the same order, so a pass gives the pipeline's image bit for
//! bit (`tests` below). The wavefront covers the scenes without motion: one GAS placed without
//! a transform (the built-in Cornell box, OBJ and PLY files, glTF files whose meshes are each
//! placed once, [`oxray_scene::SceneDesc::flattened`]) or an IAS of static instances over
//! GASes, whose hits it resolves as the pipeline does (the instance's own matrices from the
//! IAS); alpha-tested materials go through the queries' filters. Scenes with motion render
//! through the pipeline.

mod lanes;

use crate::programs::{self, Params, PathHit, PathState, PixelAt, ShadowRay};
use glam::Vec3;
use oxray::bvh::InstanceData;
use oxray::cpu::{Gas, Ias};
use oxray::{CandidateAction, Hit, NoCustomPrimitives, Ray, Transform};
use oxray_util::HitGroupData;
use rayon::prelude::*;

/// Pixels per tile: one rayon task, and the paths one batch holds.
pub const TILE: usize = 256;

/// What the wavefront traces: the scene's root and, per mesh, the hit-group data of its GAS's
/// build inputs (what the pipeline's SBT records hold).
pub(crate) struct Wavefront<'g> {
    root: Root<'g>,
    /// Per mesh the root's hits may be on, its build inputs' hit-group data.
    records: Vec<Vec<HitGroupData>>,
    /// Whether a material is alpha-tested: then every query filters its candidates by the
    /// alpha rule (as the pipeline's any-hit program does), ray by ray.
    alpha: bool,
}

/// The structure the rays are traced through.
pub(crate) enum Root<'g> {
    /// One GAS placed without a transform: its hits are on mesh 0 of the records.
    Gas(&'g Gas),
    /// An IAS over GASes (one level of static instances); instance `i` of its build input
    /// places mesh `mesh_of_instance[i]`.
    Ias {
        ias: &'g Ias,
        mesh_of_instance: Vec<u32>,
    },
}

impl Root<'_> {
    fn intersect_batch(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        // Lengths agree by construction; a mismatch would leave every path missing.
        let _ = match self {
            Root::Gas(g) => g.intersect_batch(rays, hits),
            Root::Ias { ias, .. } => ias.intersect_batch(rays, hits),
        };
    }

    fn occluded_batch(&self, rays: &[Ray], occluded: &mut [bool]) {
        let _ = match self {
            Root::Gas(g) => g.occluded_batch(rays, occluded),
            Root::Ias { ias, .. } => ias.occluded_batch(rays, occluded),
        };
    }

    fn intersect_filtered(
        &self,
        ray: &Ray,
        filter: impl FnMut(&Hit) -> CandidateAction,
    ) -> Option<Hit> {
        match self {
            Root::Gas(g) => g.intersect_filtered(ray, &mut NoCustomPrimitives, filter),
            Root::Ias { ias, .. } => ias.intersect_filtered(ray, &mut NoCustomPrimitives, filter),
        }
    }

    /// The instance a hit is on, `None` for a GAS root.
    fn instance(&self, hit: &Hit) -> Option<&InstanceData> {
        match self {
            Root::Gas(_) => None,
            Root::Ias { ias, .. } => {
                let data = ias.data();
                let slot = *data.slot_of.get(hit.instance_index as usize)?;
                data.instances.get(slot as usize)
            }
        }
    }

    /// The mesh a hit is on.
    fn mesh(&self, hit: &Hit) -> Option<usize> {
        match self {
            Root::Gas(_) => Some(0),
            Root::Ias {
                mesh_of_instance, ..
            } => mesh_of_instance
                .get(hit.instance_index as usize)
                .map(|&m| m as usize),
        }
    }
}

/// One path of a tile.
#[derive(Clone, Copy)]
struct Lane {
    state: PathState,
    time: f32,
    /// The launch pixel (the index of `accum`).
    at: PixelAt,
    /// Radiance rays the path may still trace (the pipeline's ray-generation loop bound).
    traces_left: u32,
}

/// A tile's buffers, kept across the tiles a rayon worker takes (no allocation per ray).
#[derive(Default)]
struct Scratch {
    lanes: Vec<Lane>,
    live: Vec<u32>,
    rays: Vec<Ray>,
    hits: Vec<Option<Hit>>,
    shadows: Vec<(u32, ShadowRay)>,
    shadow_rays: Vec<Ray>,
    occluded: Vec<bool>,
}

impl<'g> Wavefront<'g> {
    /// The wavefront over `root`, whose hits on mesh `m`'s build input `i` have the
    /// hit-group data `records[m][i]`; `alpha` when a material is alpha-tested.
    pub(crate) fn new(root: Root<'g>, records: Vec<Vec<HitGroupData>>, alpha: bool) -> Self {
        Wavefront {
            root,
            records,
            alpha,
        }
    }

    /// Traces one pass (sample `p.sample` of every pixel of a `width` x `height` launch),
    /// adding each path's radiance to its pixel's sums; returns the rays traced.
    pub(crate) fn pass(&self, p: &Params, width: u32, height: u32) -> u64 {
        let pixels = width as usize * height as usize;
        let tiles = pixels.div_ceil(TILE);
        let plain = Plain::of(p);
        (0..tiles)
            .into_par_iter()
            .map_init(Scratch::default, |scratch, tile| {
                let start = tile * TILE;
                let end = (start + TILE).min(pixels);
                self.tile(p, &plain, width, start..end, scratch)
            })
            .sum()
    }

    fn tile(
        &self,
        p: &Params,
        plain: &Plain,
        width: u32,
        pixels: std::ops::Range<usize>,
        scratch: &mut Scratch,
    ) -> u64 {
        let Scratch {
            lanes,
            live,
            rays,
            hits,
            shadows,
            shadow_rays,
            occluded,
        } = scratch;
        lanes.clear();
        let (start, end) = (pixels.start as u32, pixels.end as u32);
        for first in (start..end).step_by(lanes::LANES) {
            let n = (end - first).min(lanes::LANES as u32) as usize;
            // The camera rays sixteen at a time where the camera does not move; the launch
            // indices past the tile's end are the last one's, computed and dropped.
            let at = |k: usize| {
                let pixel = first + k.min(n - 1) as u32;
                (pixel % width, pixel / width)
            };
            let lx = std::array::from_fn(|k| at(k).0);
            let ly = std::array::from_fn(|k| at(k).1);
            let group = lanes::camera_paths(p, &lx, &ly);
            for k in 0..n {
                let (state, time) = match &group {
                    Some(states) => (states[k], 0.0),
                    None => programs::camera_path(p, lx[k], ly[k]),
                };
                lanes.push(Lane {
                    state,
                    time,
                    at: PixelAt::new(p, lx[k], ly[k], width),
                    traces_left: p.max_depth + 1,
                });
            }
        }
        live.clear();
        live.extend(0..lanes.len() as u32);
        let mut traced = 0u64;
        // Plain diffuse vertices go eight at a time ([`lanes`]) where the scene allows it.
        let lanes_apply = lanes::applies(p) && matches!(self.root, Root::Gas(_));
        // Every live path is at the same vertex: the tile's paths start together and each
        // step adds one vertex to each path it does not end.
        let mut depth = 0u32;
        while !live.is_empty() {
            rays.clear();
            rays.extend(live.iter().map(|&l| {
                let lane = &lanes[l as usize];
                Ray {
                    origin: lane.state.origin.into(),
                    tmin: 0.0,
                    direction: lane.state.direction.into(),
                    tmax: f32::INFINITY,
                    time: lane.time,
                }
            }));
            hits.clear();
            hits.resize(rays.len(), None);
            self.closest(p, live, lanes, rays, hits);
            traced += rays.len() as u64;

            shadows.clear();
            let mut batch = Batch::default();
            for ((&l, ray), hit) in live.iter().zip(rays.iter()).zip(hits.iter()) {
                let lane = &mut lanes[l as usize];
                lane.traces_left -= 1;
                match hit {
                    Some(hit) => {
                        let data = self.record(hit);
                        if lanes_apply
                            && lane.state.depth == depth
                            && lane_input(p, plain, data, ray, hit, lane, batch.next())
                        {
                            batch.take(l);
                            if batch.n == lanes::LANES {
                                batch.flush(p, lanes, shadows);
                            }
                            continue;
                        }
                        let view = QueryHit::new(p, data, ray, hit, self.root.instance(hit));
                        let made = programs::vertex(p, &view, data, lane.at, &mut lane.state);
                        shadows.extend(made.into_iter().flatten().map(|r| (l, r)));
                    }
                    None => programs::miss_environment(p, &mut lane.state, ray.direction),
                }
            }
            batch.flush(p, lanes, shadows);

            shadow_rays.clear();
            shadow_rays.extend(shadows.iter().map(|&(l, r)| Ray {
                origin: r.from,
                tmin: 0.0,
                direction: r.dir,
                tmax: r.tmax,
                time: lanes[l as usize].time,
            }));
            occluded.clear();
            occluded.resize(shadow_rays.len(), false);
            self.occluded(p, shadows, shadow_rays, occluded);
            traced += shadow_rays.len() as u64;
            // A vertex's shadow rays are in the order the pipeline's closest-hit program
            // traced them: their radiance adds up in the same order.
            for (&(l, r), &blocked) in shadows.iter().zip(occluded.iter()) {
                if !blocked {
                    let s = &mut lanes[l as usize].state;
                    s.radiance = (Vec3::from(s.radiance) + r.radiance).to_array();
                }
            }

            live.retain(|&l| {
                let lane = &lanes[l as usize];
                lane.state.done == 0 && lane.traces_left > 0
            });
            depth += 1;
        }
        for lane in lanes.iter() {
            programs::accumulate(p, lane.at.launch as usize, &lane.state);
        }
        traced
    }

    /// The hit-group data of a hit's build input (the default record's for one the table does
    /// not have, as a missing SBT record reads in the pipeline).
    fn record(&self, hit: &Hit) -> HitGroupData {
        self.root
            .mesh(hit)
            .and_then(|m| self.records.get(m)?.get(hit.build_input as usize))
            .copied()
            .unwrap_or_default()
    }

    /// Closest hits of the live paths' radiance rays.
    fn closest(
        &self,
        p: &Params,
        live: &[u32],
        lanes: &[Lane],
        rays: &[Ray],
        hits: &mut [Option<Hit>],
    ) {
        if !self.alpha {
            self.root.intersect_batch(rays, hits);
            return;
        }
        for ((&l, ray), hit) in live.iter().zip(rays).zip(hits.iter_mut()) {
            let seed = lanes[l as usize].state.seed;
            *hit = self
                .root
                .intersect_filtered(ray, |h| match self.keeps(p, seed, h) {
                    true => CandidateAction::Accept,
                    false => CandidateAction::Ignore,
                });
        }
    }

    /// Whether the shadow rays are blocked: the pipeline's shadow rays end at the first hit
    /// the alpha rule keeps.
    fn occluded(
        &self,
        p: &Params,
        shadows: &[(u32, ShadowRay)],
        rays: &[Ray],
        occluded: &mut [bool],
    ) {
        if !self.alpha {
            self.root.occluded_batch(rays, occluded);
            return;
        }
        for ((&(_, r), ray), blocked) in shadows.iter().zip(rays).zip(occluded.iter_mut()) {
            *blocked = self
                .root
                .intersect_filtered(ray, |h| match self.keeps(p, r.seed, h) {
                    true => CandidateAction::Terminate,
                    false => CandidateAction::Ignore,
                })
                .is_some();
        }
    }

    /// The any-hit program's decision on a candidate of a ray whose payload word 0 is `seed`.
    fn keeps(&self, p: &Params, seed: u32, h: &Hit) -> bool {
        programs::alpha_keeps(
            p,
            self.record(h),
            seed,
            h.primitive_index,
            [h.u, h.v],
            h.instance_index,
        )
    }
}

/// Up to [`lanes::LANES`] plain diffuse vertices waiting to be shaded together.
#[derive(Default)]
struct Batch {
    lane: [u32; lanes::LANES],
    inputs: [lanes::Input; lanes::LANES],
    n: usize,
}

impl Batch {
    /// The input the next path taken will have: written in place (an input is 150 bytes,
    /// which a copy into the batch would move once more).
    fn next(&mut self) -> &mut lanes::Input {
        &mut self.inputs[self.n]
    }

    /// Takes path `lane`, whose input [`next`](Self::next) holds.
    fn take(&mut self, lane: u32) {
        self.lane[self.n] = lane;
        self.n += 1;
    }

    /// Shades the batch's vertices, and empties it.
    fn flush(&mut self, p: &Params, lanes: &mut [Lane], shadows: &mut Vec<(u32, ShadowRay)>) {
        if self.n == 0 {
            return;
        }
        let mut out = [lanes::Output::default(); lanes::LANES];
        lanes::vertices(p, &self.inputs, self.n, &mut out);
        for (&l, (state, shadow)) in self.lane.iter().zip(out).take(self.n) {
            lanes[l as usize].state = state;
            shadows.extend(shadow.map(|r| (l, r)));
        }
        self.n = 0;
    }
}

/// Writes a hit's vertex as [`lanes::vertices`] takes it into `input`, if it is a plain diffuse
/// one (a hit without an instance: the root is a GAS); otherwise leaves `input` and returns
/// `false`.
fn lane_input(
    p: &Params,
    plain: &Plain,
    data: HitGroupData,
    ray: &Ray,
    hit: &Hit,
    lane: &Lane,
    input: &mut lanes::Input,
) -> bool {
    let Some(Some(m)) = plain.materials.get(data.material as usize) else {
        return false;
    };
    if plain.prims.get(data.geometry as usize) != Some(&true) {
        return false;
    }
    *input = lanes::Input {
        state: lane.state,
        image_pixel: lane.at.image,
        origin: ray.origin,
        dir: ray.direction,
        t: hit.t,
        vertices: QueryHit::new(p, data, ray, hit, None).vertices,
        base: m.base,
        emissive: m.emissive,
        double_sided: m.double_sided,
        area_pdf: m.area_pdf,
        sampled: !p
            .moving
            .get(hit.instance_id as usize)
            .copied()
            .unwrap_or(false),
    };
    true
}

/// Which hits the lanes shade ([`lanes::qualifies_material`], [`lanes::qualifies_prim`]),
/// decided once a pass rather than a hit: per material, what a plain diffuse vertex reads of it
/// (`None`: not plain); per primitive, whether it has neither vertex normals nor colours.
struct Plain {
    materials: Vec<Option<PlainMaterial>>,
    prims: Vec<bool>,
}

/// What [`lanes::Input`] takes of a plain diffuse material.
struct PlainMaterial {
    base: Vec3,
    emissive: Vec3,
    double_sided: bool,
    /// Its area pdf as a light ([`crate::lights::TriangleLights::area_pdf`]).
    area_pdf: f32,
}

impl Plain {
    fn of(p: &Params) -> Plain {
        let materials = p.scene.materials.iter().enumerate();
        Plain {
            materials: materials
                .map(|(i, m)| {
                    lanes::qualifies_material(m).then(|| PlainMaterial {
                        base: Vec3::from_slice(&m.base_color[..3]),
                        emissive: Vec3::from(m.emissive),
                        double_sided: m.double_sided,
                        area_pdf: p.lights.area_pdf(i as u32),
                    })
                })
                .collect(),
            prims: p
                .prims
                .iter()
                .map(|prim| lanes::qualifies_prim(prim))
                .collect(),
        }
    }
}

/// A query's hit as a path vertex sees it: what a closest-hit program's context reads.
struct QueryHit<'a> {
    ray: &'a Ray,
    hit: &'a Hit,
    /// The triangle in object space.
    vertices: [Vec3; 3],
    /// The instance the hit is on (`None`: object space is world space).
    instance: Option<&'a InstanceData>,
}

impl<'a> QueryHit<'a> {
    fn new(
        p: &Params,
        data: HitGroupData,
        ray: &'a Ray,
        hit: &'a Hit,
        instance: Option<&'a InstanceData>,
    ) -> Self {
        // The GAS's triangles are the primitive's, as given to the build.
        let vertices = p
            .prims
            .get(data.geometry as usize)
            .and_then(|prim| {
                let t = prim.triangles.get(hit.primitive_index as usize)?;
                let v = |i: u32| prim.positions.get(i as usize).copied().map(Vec3::from);
                Some([v(t[0])?, v(t[1])?, v(t[2])?])
            })
            .unwrap_or([Vec3::ZERO; 3]);
        QueryHit {
            ray,
            hit,
            vertices,
            instance,
        }
    }
}

impl PathHit for QueryHit<'_> {
    fn world_ray_origin(&self) -> Vec3 {
        self.ray.origin
    }
    fn world_ray_direction(&self) -> Vec3 {
        self.ray.direction
    }
    fn ray_tmax(&self) -> f32 {
        self.hit.t
    }
    fn triangle_vertex_data(&self) -> [Vec3; 3] {
        self.vertices
    }
    fn triangle_barycentrics(&self) -> [f32; 2] {
        [self.hit.u, self.hit.v]
    }
    fn primitive_index(&self) -> u32 {
        self.hit.primitive_index
    }
    fn instance_id(&self) -> u32 {
        self.hit.instance_id
    }
    // The pipeline's arithmetic: one level of instance transforms (the IAS's own matrices), or
    // the identity's without an instance.
    fn transform_normal_to_world(&self, n: Vec3) -> Vec3 {
        let inverse = self
            .instance
            .map_or(&Transform::IDENTITY, |i| &i.world_to_object);
        Transform::transform_normal_with_inverse(inverse, n)
    }
    fn transform_vector_to_world(&self, v: Vec3) -> Vec3 {
        self.instance
            .map_or(&Transform::IDENTITY, |i| &i.object_to_world)
            .transform_vector(v)
    }
}

#[cfg(test)]
mod tests {
    use crate::crop::CropWindow;
    use crate::lights::Environment;
    use crate::sampler::Sampler;
    use crate::{render_passes, RenderOptions, Rendered, FORCE_PIPELINE, WAVEFRONT_PASSES};
    use glam::Vec3;
    use glam::{Mat4, Quat};
    use oxray_scene::{AlphaMode, InstanceDesc, LightKind, PunctualLight, SceneDesc};
    use std::ops::ControlFlow;

    /// A render, and the passes the wavefront traced of it.
    fn render(
        scene: &SceneDesc,
        env: &Environment,
        opts: &RenderOptions,
        pipeline: bool,
    ) -> (Rendered, u32) {
        FORCE_PIPELINE.with(|f| f.set(pipeline));
        let before = WAVEFRONT_PASSES.with(std::cell::Cell::get);
        let done = render_passes(scene, env, opts, |_| ControlFlow::Continue(()));
        FORCE_PIPELINE.with(|f| f.set(false));
        (
            done.unwrap(),
            WAVEFRONT_PASSES.with(std::cell::Cell::get) - before,
        )
    }

    fn bits(r: &Rendered) -> Vec<u32> {
        let mut v: Vec<u32> = r
            .image
            .pixels
            .iter()
            .flatten()
            .map(|x| x.to_bits())
            .collect();
        if let Some(a) = &r.aovs {
            v.extend(a.albedo.iter().flatten().map(|x| x.to_bits()));
            v.extend(a.normal.iter().flatten().map(|x| x.to_bits()));
            v.extend(a.depth.iter().map(|x| x.to_bits()));
            v.extend(a.samples.iter().map(|x| x.to_bits()));
        }
        v
    }

    /// The wavefront renders the pipeline's image, bit for bit, with the same rays.
    fn same_as_pipeline(scene: &SceneDesc, env: &Environment, opts: &RenderOptions) {
        let (wavefront, passes) = render(scene, env, opts, false);
        assert_eq!(passes, opts.spp, "the wavefront should trace every pass");
        let (pipeline, passes) = render(scene, env, opts, true);
        assert_eq!(passes, 0);
        assert_eq!(wavefront.rays, pipeline.rays, "rays traced");
        assert!(wavefront.rays > u64::from(opts.width * opts.height * opts.spp));
        let (a, b) = (bits(&wavefront), bits(&pipeline));
        let differ = a.iter().zip(&b).filter(|(x, y)| x != y).count();
        assert_eq!(differ, 0, "{differ} of {} values differ", a.len());
        let mean: f32 = wavefront
            .image
            .pixels
            .iter()
            .map(|p| p[0] + p[1] + p[2])
            .sum();
        assert!(mean > 0.0, "a black image proves nothing");
    }

    fn opts(sampler: Sampler) -> RenderOptions {
        RenderOptions {
            width: 40,
            height: 30,
            spp: 4,
            max_depth: 6,
            sampler,
            ..Default::default()
        }
    }

    #[test]
    fn the_cornell_box_renders_as_through_the_pipeline() {
        let scene = oxray_scene::cornell_box();
        let env = Environment::uniform(Vec3::ZERO);
        same_as_pipeline(&scene, &env, &opts(Sampler::Sobol));
        let mut o = opts(Sampler::Independent);
        o.aovs = true;
        o.crop = Some(CropWindow::new(5, 3, 31, 22).unwrap());
        o.seed = 7;
        same_as_pipeline(&scene, &env, &o);
        // The camera rays eight at a time: a window whose tiles end in part of a batch, both
        // pixel filters' offset tables.
        let mut o = opts(Sampler::Sobol);
        o.crop = Some(CropWindow::new(2, 1, 39, 30).unwrap());
        o.filter = crate::filter::Filter::Box;
        same_as_pipeline(&scene, &env, &o);
    }

    #[test]
    fn environment_and_punctual_lights_render_as_through_the_pipeline() {
        let mut scene = oxray_scene::cornell_box();
        scene.lights.push(PunctualLight {
            kind: LightKind::Point,
            position: Vec3::new(0.5, 0.6, 0.5),
            direction: Vec3::NEG_Y,
            intensity: Vec3::splat(300.0),
            range: None,
        });
        scene.lights.push(PunctualLight {
            kind: LightKind::Directional,
            position: Vec3::ZERO,
            direction: Vec3::new(0.3, -1.0, 0.2).normalize(),
            intensity: Vec3::splat(500.0),
            range: None,
        });
        same_as_pipeline(&scene, &Environment::sky(1.0), &opts(Sampler::Sobol));
    }

    #[test]
    fn alpha_tested_materials_render_as_through_the_pipeline() {
        // Cut-out red wall (its alpha under the cutoff) and half-transparent white surfaces
        // (stochastic transparency), lit by the box's light and a sky seen through them.
        let mut scene = oxray_scene::cornell_box();
        let mut blended = false;
        for m in &mut scene.materials {
            if m.base_color[0] > 0.5 && m.base_color[1] < 0.2 {
                m.alpha_mode = AlphaMode::Mask { cutoff: 0.5 };
                m.base_color[3] = 0.3;
            } else if m.emissive == [0.0; 3] && !blended {
                m.alpha_mode = AlphaMode::Blend;
                m.base_color[3] = 0.6;
                blended = true;
            }
        }
        assert!(blended);
        same_as_pipeline(&scene, &Environment::sky(1.0), &opts(Sampler::Sobol));
    }

    #[test]
    fn instanced_scenes_render_as_through_the_pipeline() {
        // The box placed twice more inside itself: scaled, turned and once mirrored (the
        // instance level's transforms, normals through the inverse transpose, a mirror's
        // facing), alpha-tested and not.
        let mut scene = oxray_scene::cornell_box();
        let mesh = scene.instances[0].mesh;
        let base = scene.instances[0].transform;
        for (k, mirror) in [(0.0f32, false), (1.0, true)] {
            let t = Mat4::from_scale_rotation_translation(
                Vec3::new(if mirror { -0.15 } else { 0.15 }, 0.2, 0.15),
                Quat::from_rotation_y(0.4 + k),
                Vec3::new(0.3 + 0.35 * k, 0.1, 0.4),
            );
            scene.instances.push(InstanceDesc {
                mesh,
                transform: t * base,
                node: None,
            });
        }
        same_as_pipeline(
            &scene,
            &Environment::uniform(Vec3::ZERO),
            &opts(Sampler::Sobol),
        );
        for m in &mut scene.materials {
            if m.emissive == [0.0; 3] {
                m.alpha_mode = AlphaMode::Blend;
                m.base_color[3] = 0.8;
            }
        }
        let mut o = opts(Sampler::Independent);
        o.aovs = true;
        same_as_pipeline(&scene, &Environment::sky(0.5), &o);
    }

    #[test]
    fn diffuse_vertices_in_lanes_render_as_through_the_pipeline() {
        // Scenes whose vertices go eight at a time: the box lit by its light and a sky (light
        // samples on both), by the sky alone (its light turned off), deep paths past the Sobol
        // sequence's dimensions, both samplers, a crop window.
        let mut scene = oxray_scene::cornell_box();
        let sky = Environment::sky(0.7);
        for sampler in [Sampler::Sobol, Sampler::Independent] {
            let mut o = opts(sampler);
            o.max_depth = 9;
            o.roulette_depth = 2;
            same_as_pipeline(&scene, &sky, &o);
            o.crop = Some(CropWindow::new(3, 4, 29, 25).unwrap());
            same_as_pipeline(&scene, &Environment::uniform(Vec3::ZERO), &o);
        }
        for m in &mut scene.materials {
            m.emissive = [0.0; 3];
        }
        same_as_pipeline(
            &scene,
            &Environment::uniform(Vec3::splat(0.8)),
            &opts(Sampler::Sobol),
        );
    }
}
