//! The path tracer's oxray programs: a ray-generation program that walks each path, closest-hit
//! programs that shade (emission with multiple importance sampling, next-event estimation on
//! emissive triangles and the environment through the shadow ray type, BSDF sampling, Russian
//! roulette), an any-hit program for alpha cutouts (both ray types) and the miss programs.

use super::bsdf::{hash, Rng, Surface};
use super::filter::sample_offset;
use super::lights::{Environment, TriangleLights};
use super::sampler::{dim, Draws, Sampler};
use super::texture::sample;
use glam::{Vec2, Vec3, Vec4};
use oxray::{
    AnyHitCtx, ClosestHitCtx, Module, OutputBuffer, ProgramResult, RayFlags, TraceRay,
    TraversableHandle,
};
use oxray_scene::{AlphaMode, LightKind, MaterialDesc, Primitive, SceneDesc, TextureRef};
use oxray_util::HitGroupData;

/// Ray type of camera and bounce rays.
pub const RADIANCE: u32 = 0;
/// Ray type of visibility rays towards lights.
pub const SHADOW: u32 = 1;
/// Ray types per material.
pub const RAY_TYPES: u32 = 2;

/// A pinhole camera as the ray-generation program uses it.
#[derive(Clone, Copy, Debug)]
pub struct CameraFrame {
    /// Eye position.
    pub origin: Vec3,
    /// Unit view direction.
    pub forward: Vec3,
    /// Right, scaled by the half-width of the image plane at distance 1.
    pub right: Vec3,
    /// Up, scaled by the half-height of the image plane at distance 1.
    pub up: Vec3,
}

impl CameraFrame {
    /// The frame at `time` of a camera keyed by `keys`, evenly spaced over `shutter` from its
    /// opening to its closing: linear between the two keys around `time`, the ends outside.
    /// `None` with fewer than two keys or a closed shutter. `device_programs.cu`
    /// (`camera_at`) does the same arithmetic.
    ///
    /// ```
    /// use glam::Vec3;
    /// use oxray_render::motion::Shutter;
    /// use oxray_render::programs::CameraFrame;
    /// let at = |x: f32| CameraFrame { origin: Vec3::new(x, 0.0, 0.0), forward: Vec3::NEG_Z, right: Vec3::X, up: Vec3::Y };
    /// let keys = [at(0.0), at(1.0), at(4.0)];
    /// let s = Shutter::new(0.0, 2.0).unwrap();
    /// assert_eq!(CameraFrame::at(&keys, s, 1.5).unwrap().origin.x, 2.5);
    /// assert_eq!(CameraFrame::at(&keys, s, 9.0).unwrap().origin.x, 4.0);
    /// assert!(CameraFrame::at(&keys[..1], s, 1.0).is_none());
    /// ```
    #[must_use]
    pub fn at(
        keys: &[CameraFrame],
        shutter: crate::motion::Shutter,
        time: f32,
    ) -> Option<CameraFrame> {
        if keys.len() < 2 || !shutter.is_open() {
            return None;
        }
        let last = keys.len() - 1;
        let u =
            ((time - shutter.open) / (shutter.close - shutter.open)).clamp(0.0, 1.0) * last as f32;
        if u >= last as f32 {
            return Some(keys[last]);
        }
        let k = (u as usize).min(last - 1);
        let f = u - k as f32;
        let (a, b) = (&keys[k], &keys[k + 1]);
        let mix = |x: Vec3, y: Vec3| x + (y - x) * f;
        Some(CameraFrame {
            origin: mix(a.origin, b.origin),
            forward: mix(a.forward, b.forward),
            right: mix(a.right, b.right),
            up: mix(a.up, b.up),
        })
    }
}

/// Launch parameters (one launch per sample pass).
#[derive(Clone)]
pub struct Params<'a> {
    /// Radiance sums per pixel; the alpha channel counts samples.
    pub accum: &'a OutputBuffer<[f32; 4]>,
    /// The scene's root.
    pub handle: TraversableHandle,
    /// The scene (materials, textures, vertex attributes).
    pub scene: &'a SceneDesc,
    /// Primitive per geometry instance (its user value indexes this).
    pub prims: &'a [&'a Primitive],
    /// Emissive triangles.
    pub lights: &'a TriangleLights,
    /// The environment.
    pub env: &'a Environment,
    /// Probability that next-event estimation samples the environment rather than triangles.
    pub p_env: f32,
    /// The camera.
    pub camera: CameraFrame,
    /// The camera's frames over the shutter when the scene's animation moves it while the
    /// shutter is open (evenly spaced, [`CameraFrame::at`]); empty otherwise.
    pub camera_keys: &'a [CameraFrame],
    /// Index of this pass's sample.
    pub sample: u32,
    /// Path length limit.
    pub max_depth: u32,
    /// Distance by which new rays leave a surface, along its normal.
    pub eps: f32,
    /// The pixel filter's inverse-CDF table ([`crate::filter::Filter::table`]).
    pub filter: &'a [f32],
    /// The first vertex after which Russian roulette may end a path.
    pub roulette_depth: u32,
    /// Chooses the image's random sequence (0: the default one).
    pub seed: u32,
    /// Where the random numbers come from ([`crate::sampler`]).
    pub sampler: Sampler,
    /// Sums per pixel of the first hit's albedo, shading normal and distance, and the number
    /// of samples that hit ([`AOV_WORDS`] floats), or `None`.
    pub aov: Option<&'a OutputBuffer<[f32; AOV_WORDS]>>,
    /// The full image's pixel of launch index (0, 0): the crop window's first column and row
    /// ([`crate::crop`]); the launch covers the window, `accum` and `aov` hold its pixels.
    pub window: [u32; 2],
    /// The full image's width and height: the camera's image plane and the pixels' random
    /// streams are those of the full image, so a window's pixels are the full render's.
    pub image: [u32; 2],
    /// The open shutter camera rays take their times in, when something moves while it is
    /// open (`None`: every ray at time 0, and no random number spent on it).
    pub shutter: Option<crate::motion::Shutter>,
    /// Per instance id, whether the instance moves (empty when none does): its emission is
    /// not sampled by next-event estimation, so a hit on it weighs in full.
    pub moving: &'a [bool],
}

/// Floats per pixel of the auxiliary sums: albedo (3), shading normal (3), distance, hits.
pub const AOV_WORDS: usize = 8;

/// The salt of a pixel's random stream for `seed` (the same in `device_programs.cu`).
#[must_use]
pub fn stream_salt(seed: u32) -> u32 {
    0x5eed ^ seed.wrapping_mul(0x9E37_79B9)
}

/// The radiance payload. The random state is word 0 in both ray types so that the any-hit
/// program can draw from it.
#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct PathState {
    pub(crate) seed: u32,
    pub(crate) done: u32,
    pub(crate) depth: u32,
    /// Solid-angle pdf of the BSDF sample that made this ray; 0 for camera rays and specular
    /// bounces (emission they find is counted in full).
    pub(crate) pdf: f32,
    pub(crate) radiance: [f32; 3],
    pub(crate) throughput: [f32; 3],
    pub(crate) origin: [f32; 3],
    pub(crate) direction: [f32; 3],
}

/// Payload words of a radiance ray.
pub const WORDS: usize = std::mem::size_of::<PathState>() / 4;

fn load(words: &[u32]) -> PathState {
    bytemuck::pod_read_unaligned(bytemuck::cast_slice(&words[..WORDS]))
}

fn store(s: &PathState, mut set: impl FnMut(usize, u32)) {
    for (i, &w) in bytemuck::cast_slice::<PathState, u32>(std::slice::from_ref(s))
        .iter()
        .enumerate()
    {
        set(i, w);
    }
}

pub(crate) fn power_heuristic(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 {
        a2 / (a2 + b2)
    } else {
        0.0
    }
}

/// Samples texture reference `r` at the texture coordinates of sets 0 and 1 (`uvs`), in the
/// set it names; white without a texture.
fn tex(p: &Params, r: Option<TextureRef>, uvs: &[Vec2; 2], srgb: bool) -> Vec4 {
    let Some(r) = r else {
        return Vec4::ONE;
    };
    let uv = uvs[(r.tex_coord as usize).min(1)];
    match p.scene.textures.get(r.texture as usize) {
        Some(t) => {
            let (u, v) = r.map(uv.x, uv.y);
            sample(t, Vec2::new(u, v), srgb)
        }
        None => Vec4::ONE,
    }
}

/// Emitted radiance of `m` at texture coordinates `uvs` (sets 0 and 1).
fn emission(p: &Params, m: &MaterialDesc, uvs: &[Vec2; 2]) -> Vec3 {
    Vec3::from(m.emissive) * tex(p, m.emissive_texture, uvs, true).truncate()
}

fn interpolate<T: Copy + Into<V>, V>(attr: &[T], t: [u32; 3], b: [f32; 3]) -> Option<V>
where
    V: std::ops::Mul<f32, Output = V> + std::ops::Add<Output = V>,
{
    if attr.is_empty() {
        return None;
    }
    let a = |i: usize| -> V { attr[t[i] as usize].into() };
    Some(a(0) * b[0] + a(1) * b[1] + a(2) * b[2])
}

/// Both texture coordinate sets at barycentrics `b` of triangle `t` (zero for a set the
/// primitive does not have).
fn uvs_at(prim: &Primitive, t: [u32; 3], b: [f32; 3]) -> [Vec2; 2] {
    [&prim.uvs, &prim.uvs1].map(|set| interpolate(set, t, b).unwrap_or(Vec2::ZERO))
}

/// The vertex colour at barycentrics `b` of triangle `t` (white without colours).
fn color_at(prim: &Primitive, t: [u32; 3], b: [f32; 3]) -> Vec4 {
    interpolate::<[f32; 4], Vec4>(&prim.colors, t, b).unwrap_or(Vec4::ONE)
}

/// Coverage in [0, 1] of an alpha-tested material at a hit: the base colour's alpha times the
/// texture's and the vertex colour's.
fn alpha_at(
    p: &Params,
    m: &MaterialDesc,
    prim: &Primitive,
    prim_index: u32,
    bary: [f32; 2],
) -> f32 {
    let Some(&t) = prim.triangles.get(prim_index as usize) else {
        return 1.0;
    };
    let b = [1.0 - bary[0] - bary[1], bary[0], bary[1]];
    let uvs = uvs_at(prim, t, b);
    m.base_color[3] * tex(p, m.base_color_texture, &uvs, true).w * color_at(prim, t, b).w
}

/// The material and primitive a hit-group record names (both `None`-safe: a record the scene
/// did not make yields nothing).
fn record<'p>(p: &'p Params, data: HitGroupData) -> Option<(&'p MaterialDesc, &'p Primitive)> {
    Some((
        p.scene.materials.get(data.material as usize)?,
        *p.prims.get(data.geometry as usize)?,
    ))
}

/// Whether the alpha rule keeps a candidate: cutouts for MASK materials, stochastic
/// transparency for BLEND ones (`seed`: payload word 0 of the ray, the path's random state).
/// The any-hit program of the pipeline and the wavefront's query filters both decide here.
pub(crate) fn alpha_keeps(
    p: &Params,
    data: HitGroupData,
    seed: u32,
    prim_index: u32,
    bary: [f32; 2],
    instance_index: u32,
) -> bool {
    let Some((m, prim)) = record(p, data) else {
        return true;
    };
    let alpha = alpha_at(p, m, prim, prim_index, bary);
    match m.alpha_mode {
        AlphaMode::Opaque => true,
        AlphaMode::Mask { cutoff } => alpha >= cutoff,
        AlphaMode::Blend => {
            // One decision per (path state, primitive, instance): the same surface point is
            // either in or out for this ray, whatever the traversal order.
            let h = hash(seed ^ hash(prim_index ^ hash(instance_index)));
            alpha > h as f32 * (1.0 / 4294967296.0)
        }
    }
}

/// `__anyhit__alpha`: cutouts for MASK materials, stochastic transparency for BLEND ones.
fn any_hit_alpha(ctx: &mut AnyHitCtx<Params>) -> ProgramResult {
    let data = ctx.sbt_data::<HitGroupData>().unwrap_or_default();
    let keep = alpha_keeps(
        ctx.params(),
        data,
        ctx.payload(0),
        ctx.primitive_index(),
        ctx.triangle_barycentrics(),
        ctx.instance_index(),
    );
    if keep {
        Ok(())
    } else {
        ctx.ignore_intersection()
    }
}

/// What a path vertex reads of its hit: a closest-hit program's context in the pipeline, a
/// query's hit in the wavefront ([`crate::wavefront`]). Both give the same values for the same
/// hit (the methods are the device functions of the same names), so a vertex is shaded alike,
/// bit for bit, whichever integrator found it.
pub(crate) trait PathHit {
    fn world_ray_origin(&self) -> Vec3;
    fn world_ray_direction(&self) -> Vec3;
    fn ray_tmax(&self) -> f32;
    fn triangle_vertex_data(&self) -> [Vec3; 3];
    fn triangle_barycentrics(&self) -> [f32; 2];
    fn primitive_index(&self) -> u32;
    fn instance_id(&self) -> u32;
    fn transform_normal_to_world(&self, n: Vec3) -> Vec3;
    fn transform_vector_to_world(&self, v: Vec3) -> Vec3;
}

impl PathHit for ClosestHitCtx<'_, Params<'_>> {
    fn world_ray_origin(&self) -> Vec3 {
        ClosestHitCtx::world_ray_origin(self)
    }
    fn world_ray_direction(&self) -> Vec3 {
        ClosestHitCtx::world_ray_direction(self)
    }
    fn ray_tmax(&self) -> f32 {
        ClosestHitCtx::ray_tmax(self)
    }
    fn triangle_vertex_data(&self) -> [Vec3; 3] {
        ClosestHitCtx::triangle_vertex_data(self)
    }
    fn triangle_barycentrics(&self) -> [f32; 2] {
        ClosestHitCtx::triangle_barycentrics(self)
    }
    fn primitive_index(&self) -> u32 {
        ClosestHitCtx::primitive_index(self)
    }
    fn instance_id(&self) -> u32 {
        ClosestHitCtx::instance_id(self)
    }
    fn transform_normal_to_world(&self, n: Vec3) -> Vec3 {
        ClosestHitCtx::transform_normal_to_world(self, n)
    }
    fn transform_vector_to_world(&self, v: Vec3) -> Vec3 {
        ClosestHitCtx::transform_vector_to_world(self, v)
    }
}

struct Shading {
    point: Vec3,
    /// Geometric normal facing the incoming ray.
    ng: Vec3,
    /// Shading normal, in the hemisphere of `ng`.
    ns: Vec3,
    /// Texture coordinates of sets 0 and 1.
    uvs: [Vec2; 2],
    /// Vertex colour (white without one).
    color: Vec4,
    /// Whether the ray hit the front face (the side the winding order makes outward).
    front: bool,
}

fn shading(p: &Params, ctx: &impl PathHit, m: &MaterialDesc, prim: &Primitive) -> Shading {
    let dir = ctx.world_ray_direction();
    let point = ctx.world_ray_origin() + dir * ctx.ray_tmax();
    let [a, b, c] = ctx.triangle_vertex_data();
    let ng = ctx
        .transform_normal_to_world((b - a).cross(c - a))
        .normalize_or(Vec3::Y);
    let front = ng.dot(dir) < 0.0;
    let ng = if front { ng } else { -ng };
    let t = prim.triangles.get(ctx.primitive_index() as usize).copied();
    let [b1, b2] = ctx.triangle_barycentrics();
    let bary = [1.0 - b1 - b2, b1, b2];
    let uvs = t.map_or([Vec2::ZERO; 2], |t| uvs_at(prim, t, bary));
    let color = t.map_or(Vec4::ONE, |t| color_at(prim, t, bary));
    let mut ns = t
        .and_then(|t| interpolate::<[f32; 3], Vec3>(&prim.normals, t, bary))
        .map(|n| ctx.transform_normal_to_world(n).normalize_or(ng))
        .unwrap_or(ng);
    if ns.dot(ng) < 0.0 {
        ns = -ns;
    }
    if let (Some(nt), Some(t)) = (m.normal_texture, t) {
        let set = if nt.tex_coord == 1 {
            &prim.uvs1
        } else {
            &prim.uvs
        };
        if !set.is_empty() {
            // Tangent frame from the triangle's positions and the normal map's texture
            // coordinates.
            let tuv = t.map(|i| Vec2::from(set[i as usize]));
            let (d1, d2) = (tuv[1] - tuv[0], tuv[2] - tuv[0]);
            let det = d1.x * d2.y - d2.x * d1.y;
            if det.abs() > 1e-12 {
                let (e1, e2) = (b - a, c - a);
                let tangent = ctx.transform_vector_to_world((e1 * d2.y - e2 * d1.y) / det);
                let tangent = (tangent - ns * ns.dot(tangent)).normalize_or_zero();
                if tangent != Vec3::ZERO {
                    // glTF's tangent space: +X along increasing u, +Y up in the image, that
                    // is along decreasing v (v runs down the image), and the bitangent is
                    // cross(N, T) * w. An unmirrored mapping has det < 0 (v against the
                    // surface's counter-clockwise orientation): w = 1; a mirrored one w = -1.
                    let mut bitangent = ns.cross(tangent);
                    if det > 0.0 {
                        bitangent = -bitangent;
                    }
                    let n = tex(p, Some(nt), &uvs, false).truncate() * 2.0 - Vec3::ONE;
                    let n = Vec3::new(n.x * m.normal_scale, n.y * m.normal_scale, n.z);
                    let mapped = (tangent * n.x + bitangent * n.y + ns * n.z).normalize_or(ns);
                    if mapped.dot(ng) > 0.0 {
                        ns = mapped;
                    }
                }
            }
        }
    }
    if ns.dot(-dir) <= 0.0 {
        ns = ng;
    }
    Shading {
        point,
        ng,
        ns,
        uvs,
        color,
        front,
    }
}

fn offset(p: &Params, s: &Shading, dir: Vec3) -> Vec3 {
    let scale = p.eps + s.point.abs().max_element() * 1e-6;
    if dir.dot(s.ng) >= 0.0 {
        s.point + s.ng * scale
    } else {
        s.point - s.ng * scale
    }
}

/// A shadow ray that a path vertex asks for, and the radiance it adds to the path when nothing
/// blocks it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ShadowRay {
    pub from: Vec3,
    pub dir: Vec3,
    pub tmax: f32,
    /// The path's random state when the ray was made: payload word 0 of the shadow ray, which
    /// the alpha rule draws from.
    pub seed: u32,
    /// The light sample's contribution, throughput included.
    pub radiance: Vec3,
}

/// The shadow rays of one vertex: the light sample's, then the punctual light's (the order in
/// which their radiance is added).
pub(crate) type VertexShadows = [Option<ShadowRay>; 2];

/// Traces a shadow ray; true when nothing blocks it.
fn visible(ctx: &ClosestHitCtx<Params>, r: &ShadowRay) -> Result<bool, oxray::Interrupt> {
    let p = ctx.params();
    let mut words = [r.seed, 0u32];
    let ray = TraceRay::new(&p.handle, r.from, r.dir)
        .interval(0.0, r.tmax)
        .time(ctx.ray_time())
        .flags(RayFlags::TERMINATE_ON_FIRST_HIT | RayFlags::DISABLE_CLOSESTHIT)
        .sbt(SHADOW, RAY_TYPES, SHADOW);
    ctx.trace(&ray, &mut words)?;
    Ok(words[1] != 0)
}

/// The first hit's auxiliary values, added to its pixel's sums ([`Params::aov`]): the base
/// colour with its texture and vertex colour, the shading normal, the distance from the camera.
fn write_aov(
    p: &Params,
    aov: &OutputBuffer<[f32; AOV_WORDS]>,
    pixel: usize,
    t: f32,
    m: &MaterialDesc,
    sh: &Shading,
) {
    let base_tex = tex(p, m.base_color_texture, &sh.uvs, true);
    let albedo = Vec3::from_slice(&m.base_color[..3]) * base_tex.truncate() * sh.color.truncate();
    let a = aov.read(pixel).unwrap_or([0.0; AOV_WORDS]);
    aov.write(
        pixel,
        [
            a[0] + albedo.x,
            a[1] + albedo.y,
            a[2] + albedo.z,
            a[3] + sh.ns.x,
            a[4] + sh.ns.y,
            a[5] + sh.ns.z,
            a[6] + t,
            a[7] + 1.0,
        ],
    );
}

/// Where a path's sample lands: its pixel in the launch (the sums of `accum` and `aov`) and
/// in the full image (its random stream).
#[derive(Clone, Copy, Debug)]
pub(crate) struct PixelAt {
    pub launch: u32,
    pub image: u32,
}

impl PixelAt {
    /// The pixel of launch index (`lx`, `ly`) in a launch `launch_width` wide.
    pub(crate) fn new(p: &Params, lx: u32, ly: u32, launch_width: u32) -> PixelAt {
        let (x, y) = (p.window[0] + lx, p.window[1] + ly);
        PixelAt {
            launch: ly * launch_width + lx,
            image: y * p.image[0] + x,
        }
    }
}

/// `__closesthit__radiance`: one path vertex.
fn closest_hit(ctx: &mut ClosestHitCtx<Params>) -> ProgramResult {
    let mut s = load(ctx.payload_words());
    let data = ctx.sbt_data::<HitGroupData>().unwrap_or_default();
    let [lx, ly, _] = ctx.launch_index();
    let [w, _, _] = ctx.launch_dimensions();
    let at = PixelAt::new(ctx.params(), lx, ly, w);
    let shadows = vertex(ctx.params(), &*ctx, data, at, &mut s);
    let mut rad = Vec3::from(s.radiance);
    for r in shadows.iter().flatten() {
        if visible(ctx, r)? {
            rad += r.radiance;
        }
    }
    s.radiance = rad.to_array();
    store(&s, |i, w| ctx.set_payload(i, w));
    Ok(())
}

/// One path vertex at `hit`, whose hit group's data is `data`: its emission, weighted against
/// the light sample that could have found it, added to the path's radiance; the light samples
/// as shadow rays (for the caller to trace: each adds its radiance when nothing blocks it);
/// the BSDF sample that makes the next ray, and Russian roulette. The closest-hit program of
/// the pipeline and the wavefront ([`crate::wavefront`]) both shade here.
pub(crate) fn vertex(
    p: &Params,
    hit: &impl PathHit,
    data: HitGroupData,
    at: PixelAt,
    s: &mut PathState,
) -> VertexShadows {
    let mut shadows = [None, None];
    let Some((m, prim)) = record(p, data) else {
        s.done = 1;
        return shadows;
    };
    let sh = shading(p, hit, m, prim);
    if let (Some(aov), 0) = (p.aov, s.depth) {
        write_aov(p, aov, at.launch as usize, hit.ray_tmax(), m, &sh);
    }
    let dir = hit.world_ray_direction();
    let wo = -dir;
    let mut rng = {
        let mut d = Draws::new(
            p.sampler,
            Rng(s.seed),
            at.image,
            p.sample,
            stream_salt(p.seed),
        );
        d.base = dim::vertex(s.depth);
        d
    };
    let mut thr = Vec3::from(s.throughput);
    let mut rad = Vec3::from(s.radiance);

    // Emission, weighted against the light sample that could have found it.
    // Single-sided materials emit from their front face only (the side glTF's winding order and
    // the instance transform's handedness make outward).
    let le = if sh.front || m.double_sided {
        emission(p, m, &sh.uvs)
    } else {
        Vec3::ZERO
    };
    if le != Vec3::ZERO {
        let w = if s.pdf > 0.0 {
            let t = hit.ray_tmax();
            let cos_l = sh.ng.dot(wo).abs().max(1e-6);
            let sampled = !p
                .moving
                .get(hit.instance_id() as usize)
                .copied()
                .unwrap_or(false);
            let light_pdf = match sampled {
                true => (1.0 - p.p_env) * p.lights.area_pdf(data.material) * t * t / cos_l,
                false => 0.0,
            };
            power_heuristic(s.pdf, light_pdf)
        } else {
            1.0
        };
        rad += thr * le * w;
    }
    s.depth += 1;
    if s.depth >= p.max_depth {
        s.done = 1;
    } else {
        let base_tex = tex(p, m.base_color_texture, &sh.uvs, true);
        let mr = tex(p, m.metallic_roughness_texture, &sh.uvs, false);
        // glTF: the vertex colour multiplies the base colour factor and texture.
        let base = Vec3::from_slice(&m.base_color[..3]) * base_tex.truncate() * sh.color.truncate();
        let surf = Surface::new(
            base,
            m.metallic * mr.z,
            m.roughness * mr.y,
            m.transmission,
            m.ior,
            m.specular,
        );

        if !surf.dielectric {
            let with_throughput = |mut r: ShadowRay| {
                r.radiance = thr * r.radiance;
                r
            };
            shadows[0] = next_event(p, &mut rng, &surf, &sh, wo).map(with_throughput);
            shadows[1] = punctual_light(p, &mut rng, &surf, &sh, wo).map(with_throughput);
        }
        let u = dim::BSDF.map(|k| rng.get(k));
        match surf.sample(sh.ns, wo, sh.front, u) {
            Some(b) if surf.dielectric || b.wi.dot(sh.ng) > 0.0 => {
                let origin = offset(p, &sh, b.wi);
                continue_path(p, s, &mut thr, b.weight, b.pdf, origin, b.wi, || {
                    rng.get(dim::ROULETTE)
                });
            }
            _ => s.done = 1,
        }
    }
    s.seed = rng.rng.0;
    s.radiance = rad.to_array();
    s.throughput = thr.to_array();
    shadows
}

/// How much larger than a path's throughput (its largest channel) the probability that Russian
/// roulette lets it go on is: paths whose throughput is at least its inverse, 1/3, always go on,
/// and a survivor's throughput is raised to at least 1/3. Plain roulette (the probability the
/// throughput itself) cuts paths whose every vertex still adds much of a closed room's light,
/// and the weights of its survivors add more variance than the rays it saves are worth: on the
/// Cornell box and the balloon (`docs/BENCHMARKS.md`, "Russian roulette with a floor") this
/// factor gives 1.2x the samples per unit of error and time.
pub const ROULETTE_SCALE: f32 = 3.0;

/// The probability that Russian roulette lets a path of throughput `thr` go on:
/// [`ROULETTE_SCALE`] times its largest channel, at most 1 and at least 0.05 (so that a
/// survivor's weight stays bounded). The CUDA programs' `roulette_survival` is the same.
#[inline]
#[must_use]
pub fn roulette_survival(thr: Vec3) -> f32 {
    (thr.max_element() * ROULETTE_SCALE).clamp(0.05, 1.0)
}

/// The path's next ray after an accepted BSDF sample (`weight`, `pdf`, the ray from `origin`
/// towards `wi`), and Russian roulette from vertex `p.roulette_depth` on, whose number `draw`
/// gives (drawn only then). [`vertex`] and the wavefront's lanes both end a vertex here.
#[allow(clippy::too_many_arguments)]
pub(crate) fn continue_path(
    p: &Params,
    s: &mut PathState,
    thr: &mut Vec3,
    weight: Vec3,
    pdf: f32,
    origin: Vec3,
    wi: Vec3,
    draw: impl FnOnce() -> f32,
) {
    *thr *= weight;
    s.pdf = pdf;
    s.origin = origin.to_array();
    s.direction = wi.to_array();
    if s.depth >= p.roulette_depth {
        let q = roulette_survival(*thr);
        if draw() >= q {
            s.done = 1;
        } else {
            *thr /= q;
        }
    }
    if !thr.is_finite() {
        s.done = 1;
    }
}

/// One light sample (a triangle or the environment) with its MIS weight against BSDF sampling:
/// the shadow ray towards it, carrying its contribution without the path's throughput.
fn next_event(
    p: &Params,
    rng: &mut Draws,
    surf: &Surface,
    sh: &Shading,
    wo: Vec3,
) -> Option<ShadowRay> {
    let pick = rng.get(dim::LIGHT_PICK);
    let u = dim::LIGHT.map(|k| rng.get(k));
    if pick < p.p_env {
        let (wi, l, pdf) = p.env.sample([u[0], u[1]])?;
        let pdf = pdf * p.p_env;
        let (f, bsdf_pdf) = surf.eval(sh.ns, wo, wi);
        if f == Vec3::ZERO || wi.dot(sh.ng) <= 0.0 {
            return None;
        }
        return Some(ShadowRay {
            from: offset(p, sh, wi),
            dir: wi,
            tmax: f32::INFINITY,
            seed: rng.rng.0,
            radiance: f * l * (power_heuristic(pdf, bsdf_pdf) / pdf),
        });
    }
    let (tri, lp, [b1, b2], area_pdf) = p.lights.sample(u)?;
    let lm = p.scene.materials.get(tri.material as usize)?;
    let from = offset(p, sh, lp - sh.point);
    let to = lp - from;
    let dist = to.length();
    if dist.is_nan() || dist <= 0.0 {
        return None;
    }
    let wi = to / dist;
    let ln = tri.normal;
    let cos_l = if tri.two_sided {
        ln.dot(wi).abs()
    } else {
        -ln.dot(wi)
    };
    let (f, bsdf_pdf) = surf.eval(sh.ns, wo, wi);
    if f == Vec3::ZERO || wi.dot(sh.ng) <= 0.0 || cos_l <= 1e-6 {
        return None;
    }
    let uv = tri.uv[0] * (1.0 - b1 - b2) + tri.uv[1] * b1 + tri.uv[2] * b2;
    // The light's texture coordinates are those of its emissive texture's set.
    let le = emission(p, lm, &[uv, uv]);
    let pdf = (1.0 - p.p_env) * area_pdf * dist * dist / cos_l;
    if le == Vec3::ZERO || pdf.is_nan() || pdf <= 0.0 {
        return None;
    }
    Some(ShadowRay {
        from,
        dir: wi,
        // Stop short of the light itself.
        tmax: dist * (1.0 - 1e-4) - p.eps,
        seed: rng.rng.0,
        radiance: f * le * (power_heuristic(pdf, bsdf_pdf) / pdf),
    })
}

/// glTF gives punctual lights in photometric units (candela, lux); the renderer works in
/// radiometric ones, at 683 lm/W.
const LUMENS_PER_WATT: f32 = 683.0;

/// One punctual light, chosen uniformly, sampled exactly (it is a delta light: BSDF sampling can
/// never find it, so there is nothing to weigh it against): the shadow ray towards it.
fn punctual_light(
    p: &Params,
    rng: &mut Draws,
    surf: &Surface,
    sh: &Shading,
    wo: Vec3,
) -> Option<ShadowRay> {
    let lights = &p.scene.lights;
    if lights.is_empty() {
        return None;
    }
    let i = ((rng.get(dim::PUNCTUAL) * lights.len() as f32) as usize).min(lights.len() - 1);
    let l = &lights[i];
    let (wi, dist, mut e) = match l.kind {
        LightKind::Directional => (-l.direction, f32::INFINITY, l.intensity),
        LightKind::Point | LightKind::Spot { .. } => {
            let to = l.position - sh.point;
            let d2 = to.length_squared();
            if d2.is_nan() || d2 <= 0.0 {
                return None;
            }
            let d = d2.sqrt();
            let wi = to / d;
            let mut e = l.intensity / d2;
            if let Some(range) = l.range {
                // The extension's recommended window: smooth to zero at the range.
                let w = (1.0 - (d / range).powi(4)).clamp(0.0, 1.0);
                e *= w * w;
            }
            if let LightKind::Spot {
                inner_cone,
                outer_cone,
            } = l.kind
            {
                let (cos_in, cos_out) = (inner_cone.cos(), outer_cone.cos());
                let scale = 1.0 / (cos_in - cos_out).max(1e-3);
                let t = ((l.direction.dot(-wi) - cos_out) * scale).clamp(0.0, 1.0);
                e *= t * t;
            }
            (wi, d, e)
        }
    };
    e /= LUMENS_PER_WATT;
    if e == Vec3::ZERO || wi.dot(sh.ng) <= 0.0 {
        return None;
    }
    let (f, _) = surf.eval(sh.ns, wo, wi);
    if f == Vec3::ZERO {
        return None;
    }
    let from = offset(p, sh, wi);
    let tmax = if dist.is_finite() {
        (l.position - from).length() * (1.0 - 1e-4)
    } else {
        f32::INFINITY
    };
    Some(ShadowRay {
        from,
        dir: wi,
        tmax,
        seed: rng.rng.0,
        radiance: f * e * lights.len() as f32,
    })
}

/// The path of sample `p.sample` at launch index (`lx`, `ly`) of a launch `launch_width` wide:
/// its camera ray, in a path state ready to trace, and the path's time.
pub(crate) fn camera_path(p: &Params, lx: u32, ly: u32) -> (PathState, f32) {
    // The sample is the full image's: its place there keys the random stream and the camera
    // ray; the sums go to the window's pixel.
    let (x, y) = (p.window[0] + lx, p.window[1] + ly);
    let [w, h] = p.image;
    let (index, salt) = (y * w + x, stream_salt(p.seed));
    let mut rng = Draws::new(
        p.sampler,
        Rng::new(index, p.sample, salt),
        index,
        p.sample,
        salt,
    );
    // Filter importance sampling: the offset from the pixel's centre follows the filter.
    let (jx, jy) = (rng.get(dim::PIXEL), rng.get(dim::PIXEL + 1));
    let ox = 0.5 + sample_offset(p.filter, jx);
    let oy = 0.5 + sample_offset(p.filter, jy);
    let sx = 2.0 * (x as f32 + ox) / w as f32 - 1.0;
    let sy = 1.0 - 2.0 * (y as f32 + oy) / h as f32;
    // The path's time, drawn after the pixel's offsets so that a render without motion keeps
    // its random sequence; a moving camera is where it is at that time.
    let time = p.shutter.map_or(0.0, |s| s.time(rng.get(dim::TIME)));
    let c = p
        .shutter
        .and_then(|s| CameraFrame::at(p.camera_keys, s, time))
        .unwrap_or(p.camera);
    let dir = (c.forward + c.right * sx + c.up * sy).normalize();
    let s = PathState {
        seed: rng.rng.0,
        throughput: [1.0; 3],
        origin: c.origin.to_array(),
        direction: dir.to_array(),
        ..Default::default()
    };
    (s, time)
}

/// `__miss__environment` on path state `s`: the environment's radiance in the ray's direction
/// `d`, weighted against its light sample, and the end of the path.
pub(crate) fn miss_environment(p: &Params, s: &mut PathState, d: Vec3) {
    let (l, env_pdf) = p.env.radiance_and_pdf(d);
    if l != Vec3::ZERO {
        let w = if s.pdf > 0.0 {
            power_heuristic(s.pdf, p.p_env * env_pdf)
        } else {
            1.0
        };
        let r = Vec3::from(s.radiance) + Vec3::from(s.throughput) * l * w;
        s.radiance = r.to_array();
    }
    s.done = 1;
}

/// Adds a finished path's radiance to the sums of its launch pixel `pixel`.
pub(crate) fn accumulate(p: &Params, pixel: usize, s: &PathState) {
    let r = Vec3::from(s.radiance);
    // A non-finite sample (a degenerate input the guards missed) is dropped rather than
    // poisoning the pixel; the count still advances, so it reads as black.
    let r = if r.is_finite() { r } else { Vec3::ZERO };
    let old = p.accum.read(pixel).unwrap_or([0.0; 4]);
    p.accum.write(
        pixel,
        [old[0] + r.x, old[1] + r.y, old[2] + r.z, old[3] + 1.0],
    );
}

/// The module with every program of the path tracer.
pub fn module<'a>() -> Result<Module<Params<'a>>, oxray::PipelineError> {
    Module::<Params>::new()
        .raygen("__raygen__camera", |ctx| {
            let [lx, ly, _] = ctx.launch_index();
            let [lw, _, _] = ctx.launch_dimensions();
            let p = ctx.params();
            let (mut s, time) = camera_path(p, lx, ly);
            // Each trace either ends the path or adds a vertex, and vertices are capped.
            for _ in 0..=p.max_depth {
                let mut words = [0u32; WORDS];
                store(&s, |i, w| words[i] = w);
                let ray = TraceRay::new(&p.handle, s.origin.into(), s.direction.into())
                    .time(time)
                    .sbt(RADIANCE, RAY_TYPES, RADIANCE);
                ctx.trace(&ray, &mut words)?;
                s = load(&words);
                if s.done != 0 {
                    break;
                }
            }
            accumulate(p, (ly * lw + lx) as usize, &s);
            Ok(())
        })?
        .closest_hit("__closesthit__radiance", closest_hit)?
        .any_hit("__anyhit__alpha", any_hit_alpha)?
        .miss("__miss__environment", |ctx| {
            let mut s = load(ctx.payload_words());
            miss_environment(ctx.params(), &mut s, ctx.world_ray_direction());
            store(&s, |i, w| ctx.set_payload(i, w));
            Ok(())
        })?
        .miss("__miss__shadow", |ctx| {
            ctx.set_payload(1, 1);
            Ok(())
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roulette_spares_paths_above_a_third_and_bounds_a_survivors_weight() {
        // At or above 1/3 in any channel a path always goes on, its throughput unchanged.
        for thr in [Vec3::ONE, Vec3::splat(1.0 / 3.0), Vec3::new(0.01, 0.4, 0.0)] {
            assert_eq!(roulette_survival(thr), 1.0, "{thr}");
        }
        // Below, it goes on with three times its largest channel, and a survivor's throughput
        // (divided by that) is back at 1/3.
        let thr = Vec3::new(0.1, 0.2, 0.05);
        let q = roulette_survival(thr);
        assert!((q - 0.6).abs() < 1e-6, "{q}");
        assert!(((thr / q).max_element() - 1.0 / 3.0).abs() < 1e-6);
        // A nearly black path: the probability is at least 0.05, so no survivor's weight grows
        // past 20 times.
        assert_eq!(roulette_survival(Vec3::splat(1e-4)), 0.05);
        assert_eq!(roulette_survival(Vec3::ZERO), 0.05);
    }
}
