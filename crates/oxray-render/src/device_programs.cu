// The path tracer of `oxray render` as CUDA C++ programs: the same algorithm as the Rust
// programs (programs.rs, bsdf.rs, lights.rs, texture.rs), written once against the guide's
// device functions, so that it runs on every device: compiled by the host's C++ compiler on the
// CPU and by NVRTC on a GPU. `device.rs` builds the scene and the buffers these programs read.
//
// What it does, as in the Rust programs: a pinhole camera with one jittered sample per pixel
// and launch; glTF metallic-roughness surfaces (Lambert plus GGX sampled by visible normals)
// and smooth dielectrics; emission; textures (bilinear, glTF wrap modes, sRGB through the same
// table), vertex colours and normal maps; alpha MASK and BLEND in an any-hit program that both
// ray types run; next-event estimation on emissive triangles (chosen by power) and on the
// environment (chosen by importance over its texels), combined with BSDF sampling by the power
// heuristic; punctual lights; Russian roulette. Random numbers follow the Rust sequence draw by
// draw (same PCG hash, same seeds, same order; the same Owen-scrambled Sobol dimensions).
//
// Device functions used: launch index and dimensions, optixTrace with payload words, payload
// get/set, barycentrics, primitive and instance index, SBT data pointer, ray origin, direction
// and tmax, optixIgnoreIntersection. Transforms and vertex positions come from this file's own
// buffers (per-instance matrices, per-geometry vertex arrays), not from optixTransform* or
// optixGetTriangleVertexData, so that the GPU pipeline needs nothing more.
//
// Every layout below is mirrored by a `#[repr(C)]` struct in device.rs: only 4- and 8-byte
// fields, each at an offset that is a multiple of its size.

#include <optix.h>

namespace pt {

typedef unsigned int u32;
typedef unsigned long long u64;

#define PTI static __forceinline__ __device__
#define PTF static __device__

// ---------------------------------------------------------------------------------------------
// Data the host uploads
// ---------------------------------------------------------------------------------------------

// A texture reference: texture < 0 for none; uv' = (m0 u + m1 v + m2, m3 u + m4 v + m5).
struct TexRef {
    int texture;
    u32 tex_coord;
    float m[6];
};

struct Material {
    float base_color[4];
    float emissive[3];
    float metallic;
    float roughness;
    float normal_scale;
    float transmission;
    float ior;
    u32 alpha_mode;  // 0 opaque, 1 mask, 2 blend
    float alpha_cutoff;
    u32 double_sided;
    float specular;  // KHR_materials_specular's factor: 0 is Lambertian
    TexRef base_color_tex, metallic_roughness_tex, emissive_tex, normal_tex;
};

// A texture: `width * height` texels (RGBA8, top row first) at `offset` in the texel buffer.
struct TextureDesc {
    u32 offset, width, height;
    u32 wrap_u, wrap_v;  // 0 repeat, 1 mirrored repeat, 2 clamp to edge
    u32 pad[3];
};

// An emissive triangle in world space (lights.rs LightTriangle).
struct LightTri {
    float p0[3], e1[3], e2[3], normal[3];
    float uv[6];
    u32 material, two_sided;
};

// A punctual light; intensities in the scene's photometric units.
struct Punctual {
    u32 kind;  // 0 directional, 1 point, 2 spot
    float position[3], direction[3], intensity[3];
    float range;  // +inf: unlimited
    float cos_inner, cos_outer;
    u32 pad;
};

// An instance's object-to-world and world-to-object matrices (3x4, rows).
struct InstanceXform {
    float o2w[12];
    float w2o[12];
};

// The hit-group record data: one geometry (a scene primitive) and its material.
struct HitData {
    u64 positions;  // float[3] per vertex
    u64 normals;    // float[3] per vertex, or 0
    u64 uvs0;       // float[2] per vertex, or 0
    u64 uvs1;       // float[2] per vertex, or 0
    u64 colors;     // float[4] per vertex, or 0
    u64 triangles;  // u32[3] per triangle
    u32 material, num_triangles;
};

struct Params {
    u64 accum;  // float[4] per pixel: radiance sums and the sample count
    u64 handle;
    u64 materials, textures, texels, srgb, instances;
    u64 lights, light_cdf, light_area_pdf;  // light_area_pdf: per material
    u64 punctual;
    u64 env_texels, env_conditional, env_marginal;  // float[3] per texel; cdfs
    u64 ggx_albedo;  // float[2] (A, B) per cell, PT_GGX_N x PT_GGX_N (albedo.rs)
    u64 filter;      // float[filter_len]: the pixel filter's inverse CDF (filter.rs)
    u64 aov;         // float[8] per pixel, or 0: the first hit's albedo, normal, distance sums
    u32 num_materials, num_textures, num_lights, num_punctual, num_instances;
    u32 env_width, env_height;
    float env_total;
    float p_env;
    float cam_origin[3], cam_forward[3], cam_right[3], cam_up[3];
    u32 sample, max_depth;
    float eps;
    u32 filter_len;
    u32 roulette_depth;  // the first vertex after which Russian roulette may end a path
    u32 seed;            // chooses the image's random sequence (0: the default one)
    // The crop window (RenderOptions::crop): the full image's pixel of launch index (0, 0),
    // and the full image's size, which the camera and the pixels' random streams use; the
    // launch covers the window, and accum and aov hold its pixels.
    u32 crop_x0, crop_y0;
    u32 image_width, image_height;
    u32 sampler;  // 0: independent hash numbers, 1: Owen-scrambled Sobol (sampler.rs)
    // Motion blur (motion.rs Shutter): camera rays take times in [shutter_open, shutter_close]
    // when shutter_on, and instances marked moving in `instances` move through SRT motion
    // transforms; without it every ray's time is 0.
    u32 shutter_on;
    float shutter_open, shutter_close;
    // A camera the animation moves while the shutter is open: num_cam_keys frames evenly
    // spaced over it, 12 floats each (origin, forward, right, up; programs.rs CameraFrame::at);
    // 0: the still camera above.
    u32 num_cam_keys;
    u64 cam_keys;
};

}  // namespace pt

extern "C" __constant__ pt::Params params;

namespace pt {

// Ray types and miss programs.
#define PT_RADIANCE 0u
#define PT_SHADOW 1u
#define PT_RAY_TYPES 2u
#define PT_WORDS 16

#define PT_PI 3.14159265358979323846f
#define PT_TAU 6.28318530717958647692f
#define PT_FRAC_1_PI 0.318309886183790671538f

template <typename T>
PTI const T* ptr(u64 address) {
    return reinterpret_cast<const T*>(address);
}

// ---------------------------------------------------------------------------------------------
// Vectors (glam's operations in glam's order of evaluation)
// ---------------------------------------------------------------------------------------------

struct V2 {
    float x, y;
};
struct V3 {
    float x, y, z;
};
struct V4 {
    float x, y, z, w;
};

PTI V2 v2(float x, float y) { return V2{x, y}; }
PTI V3 v3(float x, float y, float z) { return V3{x, y, z}; }
PTI V3 v3s(float s) { return V3{s, s, s}; }
PTI V3 v3a(const float* a) { return V3{a[0], a[1], a[2]}; }
PTI V4 v4(float x, float y, float z, float w) { return V4{x, y, z, w}; }
PTI V3 operator+(V3 a, V3 b) { return v3(a.x + b.x, a.y + b.y, a.z + b.z); }
PTI V3 operator-(V3 a, V3 b) { return v3(a.x - b.x, a.y - b.y, a.z - b.z); }
PTI V3 operator*(V3 a, V3 b) { return v3(a.x * b.x, a.y * b.y, a.z * b.z); }
PTI V3 operator*(V3 a, float s) { return v3(a.x * s, a.y * s, a.z * s); }
PTI V3 operator*(float s, V3 a) { return v3(s * a.x, s * a.y, s * a.z); }
PTI V3 operator/(V3 a, float s) { return v3(a.x / s, a.y / s, a.z / s); }
PTI V3 operator-(V3 a) { return v3(-a.x, -a.y, -a.z); }
PTI V2 operator+(V2 a, V2 b) { return v2(a.x + b.x, a.y + b.y); }
PTI V2 operator-(V2 a, V2 b) { return v2(a.x - b.x, a.y - b.y); }
PTI V2 operator*(V2 a, float s) { return v2(a.x * s, a.y * s); }
PTI V4 operator+(V4 a, V4 b) { return v4(a.x + b.x, a.y + b.y, a.z + b.z, a.w + b.w); }
PTI V4 operator*(V4 a, float s) { return v4(a.x * s, a.y * s, a.z * s, a.w * s); }
PTI V3 xyz(V4 a) { return v3(a.x, a.y, a.z); }
PTI float dot(V3 a, V3 b) { return (a.x * b.x) + (a.y * b.y) + (a.z * b.z); }
PTI V3 cross(V3 a, V3 b) {
    return v3(a.y * b.z - b.y * a.z, a.z * b.x - b.z * a.x, a.x * b.y - b.x * a.y);
}
PTI float length(V3 a) { return sqrtf(dot(a, a)); }
PTI bool finite(float x) { return (__float_as_uint(x) & 0x7f800000u) != 0x7f800000u; }
PTI bool finite3(V3 a) { return finite(a.x) && finite(a.y) && finite(a.z); }
PTI bool is_zero(V3 a) { return a.x == 0.0f && a.y == 0.0f && a.z == 0.0f; }
PTI V3 normalize(V3 a) { return a * (1.0f / length(a)); }
PTI V3 normalize_or(V3 a, V3 fallback) {
    float r = 1.0f / length(a);
    return (finite(r) && r > 0.0f) ? a * r : fallback;
}
PTI V3 normalize_or_zero(V3 a) { return normalize_or(a, v3s(0.0f)); }
PTI float maxf(float a, float b) { return fmaxf(a, b); }
PTI float minf(float a, float b) { return fminf(a, b); }
PTI float clampf(float x, float lo, float hi) { return x < lo ? lo : (x > hi ? hi : x); }
PTI float max_element(V3 a) { return maxf(a.x, maxf(a.y, a.z)); }
// Russian roulette's probability of going on: the Rust `programs::roulette_survival`, with
// its ROULETTE_SCALE of 3.
PTI float roulette_survival(V3 thr) { return clampf(max_element(thr) * 3.0f, 0.05f, 1.0f); }
PTI V3 abs3(V3 a) { return v3(fabsf(a.x), fabsf(a.y), fabsf(a.z)); }
PTI V3 lerp3(V3 a, V3 b, float s) { return a * (1.0f - s) + b * s; }
PTI V4 lerp4(V4 a, V4 b, float s) { return a * (1.0f - s) + b * s; }
PTI float3 f3(V3 a) { return make_float3(a.x, a.y, a.z); }
PTI V3 from_f3(float3 a) { return v3(a.x, a.y, a.z); }

// Rows of a 3x4 matrix applied to a point, a vector, and (through the inverse) a normal.
PTI V3 xf_point(const float* m, V3 p) {
    return v3(m[0] * p.x + m[1] * p.y + m[2] * p.z + m[3],
              m[4] * p.x + m[5] * p.y + m[6] * p.z + m[7],
              m[8] * p.x + m[9] * p.y + m[10] * p.z + m[11]);
}
PTI V3 xf_vector(const float* m, V3 v) {
    return v3(m[0] * v.x + m[1] * v.y + m[2] * v.z, m[4] * v.x + m[5] * v.y + m[6] * v.z,
              m[8] * v.x + m[9] * v.y + m[10] * v.z);
}
PTI V3 xf_normal(const float* inv, V3 n) {
    return v3(inv[0] * n.x + inv[4] * n.y + inv[8] * n.z,
              inv[1] * n.x + inv[5] * n.y + inv[9] * n.z,
              inv[2] * n.x + inv[6] * n.y + inv[10] * n.z);
}

// ---------------------------------------------------------------------------------------------
// Random numbers (bsdf.rs Rng, hash)
// ---------------------------------------------------------------------------------------------

PTI u32 hash(u32 x) {
    u32 s = x * 747796405u + 2891336453u;
    u32 w = ((s >> ((s >> 28) + 4u)) ^ s) * 277803737u;
    return (w >> 22) ^ w;
}

struct Rng {
    u32 s;
    __device__ float uniform() {
        s = s * 747796405u + 2891336453u;
        u32 w = ((s >> ((s >> 28) + 4u)) ^ s) * 277803737u;
        return (float)((w >> 22) ^ w) * (1.0f / 4294967296.0f);
    }
};

PTI Rng rng_new(u32 pixel, u32 sample, u32 salt) {
    return Rng{hash(pixel ^ hash(sample + hash(salt)))};
}

// The salt of a pixel's random streams for the user's seed (programs.rs stream_salt).
PTI u32 stream_salt() { return 0x5eedu ^ (params.seed * 0x9E3779B9u); }

// ---------------------------------------------------------------------------------------------
// Owen-scrambled Sobol points (sampler.rs): one dimension per use, in groups of four; a group
// is the first four Sobol dimensions at a sample index shuffled by a nested uniform scramble,
// each coordinate Owen-scrambled by a Laine-Karras hash; past PT_SOBOL_DIMS, hash numbers.
// ---------------------------------------------------------------------------------------------

// Direction numbers, most significant bit first (sampler.rs SOBOL_DIRECTIONS).
static __constant__ const u32 PT_SOBOL[4][32] = {
    {0x80000000u, 0x40000000u, 0x20000000u, 0x10000000u, 0x08000000u, 0x04000000u,
     0x02000000u, 0x01000000u, 0x00800000u, 0x00400000u, 0x00200000u, 0x00100000u,
     0x00080000u, 0x00040000u, 0x00020000u, 0x00010000u, 0x00008000u, 0x00004000u,
     0x00002000u, 0x00001000u, 0x00000800u, 0x00000400u, 0x00000200u, 0x00000100u,
     0x00000080u, 0x00000040u, 0x00000020u, 0x00000010u, 0x00000008u, 0x00000004u,
     0x00000002u, 0x00000001u},
    {0x80000000u, 0xc0000000u, 0xa0000000u, 0xf0000000u, 0x88000000u, 0xcc000000u,
     0xaa000000u, 0xff000000u, 0x80800000u, 0xc0c00000u, 0xa0a00000u, 0xf0f00000u,
     0x88880000u, 0xcccc0000u, 0xaaaa0000u, 0xffff0000u, 0x80008000u, 0xc000c000u,
     0xa000a000u, 0xf000f000u, 0x88008800u, 0xcc00cc00u, 0xaa00aa00u, 0xff00ff00u,
     0x80808080u, 0xc0c0c0c0u, 0xa0a0a0a0u, 0xf0f0f0f0u, 0x88888888u, 0xccccccccu,
     0xaaaaaaaau, 0xffffffffu},
    {0x80000000u, 0xc0000000u, 0x60000000u, 0x90000000u, 0xe8000000u, 0x5c000000u,
     0x8e000000u, 0xc5000000u, 0x68800000u, 0x9cc00000u, 0xee600000u, 0x55900000u,
     0x80680000u, 0xc09c0000u, 0x60ee0000u, 0x90550000u, 0xe8808000u, 0x5cc0c000u,
     0x8e606000u, 0xc5909000u, 0x6868e800u, 0x9c9c5c00u, 0xeeee8e00u, 0x5555c500u,
     0x8000e880u, 0xc0005cc0u, 0x60008e60u, 0x9000c590u, 0xe8006868u, 0x5c009c9cu,
     0x8e00eeeeu, 0xc5005555u},
    {0x80000000u, 0xc0000000u, 0x20000000u, 0x50000000u, 0xf8000000u, 0x74000000u,
     0xa2000000u, 0x93000000u, 0xd8800000u, 0x25400000u, 0x59e00000u, 0xe6d00000u,
     0x78080000u, 0xb40c0000u, 0x82020000u, 0xc3050000u, 0x208f8000u, 0x51474000u,
     0xfbea2000u, 0x75d93000u, 0xa0858800u, 0x914e5400u, 0xdbe79e00u, 0x25db6d00u,
     0x58800080u, 0xe54000c0u, 0x79e00020u, 0xb6d00050u, 0x800800f8u, 0xc00c0074u,
     0x200200a2u, 0x50050093u},
};

// Dimensions (sampler.rs dim): the camera's, then PT_DIM_PER_VERTEX per path vertex.
#define PT_DIM_PIXEL 0u
#define PT_DIM_TIME 2u
#define PT_DIM_CAMERA 4u
#define PT_DIM_PER_VERTEX 12u
#define PT_DIM_LIGHT_0 2u
#define PT_DIM_LIGHT_1 0u
#define PT_DIM_LIGHT_2 1u
#define PT_DIM_LIGHT_PICK 3u
#define PT_DIM_BSDF_0 6u
#define PT_DIM_BSDF_1 4u
#define PT_DIM_BSDF_2 5u
#define PT_DIM_ROULETTE 7u
#define PT_DIM_PUNCTUAL 8u
#define PT_SOBOL_DIMS (PT_DIM_CAMERA + 5u * PT_DIM_PER_VERTEX)

PTI u32 reverse_bits(u32 x) {
    x = ((x >> 1) & 0x55555555u) | ((x & 0x55555555u) << 1);
    x = ((x >> 2) & 0x33333333u) | ((x & 0x33333333u) << 2);
    x = ((x >> 4) & 0x0f0f0f0fu) | ((x & 0x0f0f0f0fu) << 4);
    x = ((x >> 8) & 0x00ff00ffu) | ((x & 0x00ff00ffu) << 8);
    return (x >> 16) | (x << 16);
}

PTI u32 sobol(u32 index, u32 d) {
    u32 x = 0u;
    for (u32 bit = 0u; bit < 32u; ++bit) {
        x ^= PT_SOBOL[d & 3u][bit] & (0u - ((index >> bit) & 1u));
    }
    return x;
}

PTI u32 lk_permute(u32 x, u32 seed) {
    x ^= x * 0x3d20adeau;
    x += seed;
    x *= (seed >> 16) | 1u;
    x ^= x * 0x05526c56u;
    x ^= x * 0x53a22864u;
    return x;
}

PTI u32 owen_scramble(u32 x, u32 seed) { return reverse_bits(lk_permute(reverse_bits(x), seed)); }

PTI u32 pixel_seed(u32 pixel, u32 salt) { return hash(pixel ^ hash(salt ^ 0x50b01e5du)); }

PTI float sobol_sample(u32 index, u32 dim, u32 seed) {
    u32 group = hash(seed ^ hash(dim >> 2));
    u32 x = sobol(owen_scramble(index, group), dim & 3u);
    x = owen_scramble(x, hash(group ^ hash((dim & 3u) + 1u)));
    return (float)(x >> 8) * (1.0f / 16777216.0f);
}

// The draws of one path (sampler.rs Draws): the hash stream advances once per draw whatever the
// sampler, so the seeds shadow rays take from it do not depend on it.
struct Draws {
    Rng rng;
    u32 sobol_seed, sobol_on, index, base;
    __device__ float get(u32 k) {
        float u = rng.uniform();
        u32 d = base + k;
        return (sobol_on != 0u && d < PT_SOBOL_DIMS) ? sobol_sample(index, d, sobol_seed) : u;
    }
};

PTI Draws draws_new(Rng rng, u32 pixel, u32 index, u32 salt) {
    Draws d;
    d.rng = rng;
    d.sobol_on = params.sampler == 1u ? 1u : 0u;
    d.sobol_seed = d.sobol_on != 0u ? pixel_seed(pixel, salt) : 0u;
    d.index = index;
    d.base = 0u;
    return d;
}

PTI float luminance(V3 c) { return dot(c, v3(0.2126f, 0.7152f, 0.0722f)); }

// ---------------------------------------------------------------------------------------------
// The surface model (bsdf.rs)
// ---------------------------------------------------------------------------------------------

struct Surface {
    V3 base;
    float metallic, alpha;
    bool dielectric;
    float ior, specular;
};

PTI Surface surface_new(V3 base, float metallic, float roughness, float transmission, float ior,
                        float specular) {
    float r = clampf(roughness, 0.0f, 1.0f);
    Surface s;
    s.base = base;
    s.metallic = clampf(metallic, 0.0f, 1.0f);
    s.alpha = maxf(r * r, 2e-3f);
    s.dielectric = transmission >= 0.5f;
    s.ior = (finite(ior) && ior >= 1.0f) ? ior : 1.5f;
    // NaN: glTF's default coat.
    s.specular = specular >= 0.0f ? minf(specular, 1.0f) : (specular < 0.0f ? 0.0f : 1.0f);
    return s;
}

// The GGX albedo terms (A, B) at cos_o and alpha, bilinear in (cos_o, sqrt(alpha)) (albedo.rs).
#define PT_GGX_N 32u
PTI void ggx_albedo(float cos_o, float alpha, float& a, float& b) {
    const float* t = ptr<float>(params.ggx_albedo);
    float last = (float)(PT_GGX_N - 1u);
    float x = (cos_o > 0.0f ? minf(cos_o, 1.0f) : 0.0f) * last;
    float y = (alpha > 0.0f ? minf(sqrtf(alpha), 1.0f) : 0.0f) * last;
    u32 x0 = (u32)x, y0 = (u32)y;
    if (x0 > PT_GGX_N - 2u) x0 = PT_GGX_N - 2u;
    if (y0 > PT_GGX_N - 2u) y0 = PT_GGX_N - 2u;
    float fx = x - (float)x0, fy = y - (float)y0;
    const float* c00 = t + 2u * (y0 * PT_GGX_N + x0);
    const float* c01 = c00 + 2;
    const float* c10 = c00 + 2u * PT_GGX_N;
    const float* c11 = c10 + 2;
    float top_a = c00[0] * (1.0f - fx) + c01[0] * fx, top_b = c00[1] * (1.0f - fx) + c01[1] * fx;
    float bot_a = c10[0] * (1.0f - fx) + c11[0] * fx, bot_b = c10[1] * (1.0f - fx) + c11[1] * fx;
    a = top_a * (1.0f - fy) + bot_a * fy;
    b = top_b * (1.0f - fy) + bot_b * fy;
}

struct BsdfSample {
    V3 wi, weight;
    float pdf;
};

// glam's any_orthonormal_pair.
// sin_cos_turns (bsdf.rs): the sine and cosine of 2 pi u by the same operations, so that the
// programs on the CPU give the Rust programs' bits (compiled without FMA contraction).
PTI void sin_cos_turns(float u, float& sin_out, float& cos_out) {
    float four = u * 4.0f;
    float q = roundf(four);
    float x = (four - q) * 1.57079632679489661923f;
    float x2 = x * x;
    float s = x * (1.0f + x2 * (-1.0f / 6.0f + x2 * (1.0f / 120.0f + x2 * (-1.0f / 5040.0f + x2 * (1.0f / 362880.0f)))));
    float c = 1.0f + x2 * (-0.5f + x2 * (1.0f / 24.0f + x2 * (-1.0f / 720.0f + x2 * (1.0f / 40320.0f + x2 * (-1.0f / 3628800.0f)))));
    // Clamped before the conversion (NaN to the low end), as the Rust side's saturating cast.
    int qi = (int)fminf(fmaxf(q, -1048576.0f), 1048576.0f);
    if (qi & 1) { float k = s; s = c; c = k; }
    if (qi & 2) s = -s;
    if ((qi + 1) & 2) c = -c;
    sin_out = s;
    cos_out = c;
}

PTI void basis(V3 n, V3& t, V3& b) {
    float sign = copysignf(1.0f, n.z);
    float a = -1.0f / (sign + n.z);
    float bb = n.x * n.y * a;
    t = v3(1.0f + sign * n.x * n.x * a, sign * bb, -sign * n.x);
    b = v3(bb, sign + n.y * n.y * a, -n.y);
}

PTI V3 to_local(V3 v, V3 n, V3 t, V3 b) { return v3(dot(v, t), dot(v, b), dot(v, n)); }

PTI float pow5(float x) {
    float x2 = x * x;
    return x2 * x2 * x;
}
PTI V3 schlick(V3 f0, float f90, float c) {
    return f0 + (v3s(f90) - f0) * pow5(1.0f - clampf(c, 0.0f, 1.0f));
}
PTI float ggx_d(float nh, float a2) {
    float d = nh * nh * (a2 - 1.0f) + 1.0f;
    return a2 / (PT_PI * d * d);
}
PTI float smith_g1(float nv, float a2) {
    return 2.0f * nv / (nv + sqrtf(a2 + (1.0f - a2) * nv * nv));
}
PTI V3 f0_of(const Surface& s) { return lerp3(v3s(0.04f * s.specular), s.base, s.metallic); }
PTI float f90_of(const Surface& s) { return s.specular + (1.0f - s.specular) * s.metallic; }
PTI V3 diffuse_colour(const Surface& s) { return s.base * (1.0f - s.metallic); }
PTI V3 min3(V3 a, V3 b) { return v3(minf(a.x, b.x), minf(a.y, b.y), minf(a.z, b.z)); }

// What depends on the outgoing direction only (bsdf.rs Lobes): Turquin's multiple-scattering
// factor on the GGX lobe, the diffuse layer's reflectance under the coat, and the probability
// of sampling the specular lobe.
struct Lobes {
    V3 compensation, diffuse;
    float p_spec;
};
PTI Lobes lobes_of(const Surface& s, float cos_o) {
    float a, b;
    ggx_albedo(cos_o, s.alpha, a, b);
    V3 f0 = f0_of(s);
    float e = maxf(a + b, 1e-4f);
    Lobes l;
    l.compensation = v3s(1.0f) + f0 * ((1.0f - e) / e);
    V3 e_spec = min3((f0 * a + v3s(f90_of(s) * b)) * l.compensation, v3s(1.0f));
    l.diffuse = diffuse_colour(s) * (v3s(1.0f) - e_spec);
    float sp = luminance(e_spec);
    float d = luminance(l.diffuse);
    l.p_spec = sp <= 0.0f ? 0.0f : (d <= 0.0f ? 1.0f : clampf(sp / (sp + d), 0.05f, 0.95f));
    return l;
}

// Whether the surface is Lambertian (no coat, no metal): its GGX lobe is exactly zero and never
// sampled (bsdf.rs Surface::lambertian).
PTI bool lambertian(const Surface& s) {
    return !s.dielectric && s.specular == 0.0f && s.metallic == 0.0f;
}

// BSDF times |cos| at wi, and the pdf of sampling wi.
PTI V3 bsdf_eval(const Surface& s, V3 n, V3 wo, V3 wi, float& pdf) {
    float cos_o = dot(n, wo), cos_i = dot(n, wi);
    pdf = 0.0f;
    if (s.dielectric || cos_o <= 0.0f || cos_i <= 0.0f) return v3s(0.0f);
    if (lambertian(s)) {
        pdf = cos_i * PT_FRAC_1_PI;
        return s.base * (PT_FRAC_1_PI * cos_i);
    }
    V3 h = normalize(wo + wi);
    float nh = maxf(dot(n, h), 0.0f), oh = maxf(dot(wo, h), 1e-6f);
    float a2 = s.alpha * s.alpha;
    float d = ggx_d(nh, a2);
    float g1o = smith_g1(cos_o, a2);
    Lobes l = lobes_of(s, cos_o);
    V3 f = schlick(f0_of(s), f90_of(s), oh);
    V3 spec = f * l.compensation * (d * g1o * smith_g1(cos_i, a2) / (4.0f * cos_o));
    V3 diff = l.diffuse * (PT_FRAC_1_PI * cos_i);
    float ps = l.p_spec;
    pdf = ps * d * g1o / (4.0f * cos_o) + (1.0f - ps) * cos_i * PT_FRAC_1_PI;
    return spec + diff;
}

PTI V3 sample_vndf(V3 wo, float alpha, float u1, float u2) {
    V3 vh = normalize(v3(alpha * wo.x, alpha * wo.y, wo.z));
    float len2 = vh.x * vh.x + vh.y * vh.y;
    V3 t1 = len2 > 0.0f ? v3(-vh.y, vh.x, 0.0f) / sqrtf(len2) : v3(1.0f, 0.0f, 0.0f);
    V3 t2 = cross(vh, t1);
    float r = sqrtf(u1);
    float phi = PT_TAU * u2;
    float p1 = r * cosf(phi);
    float s = 0.5f * (1.0f + vh.z);
    float p2 = (1.0f - s) * sqrtf(maxf(1.0f - p1 * p1, 0.0f)) + s * r * sinf(phi);
    V3 nh = t1 * p1 + t2 * p2 + vh * sqrtf(maxf(1.0f - p1 * p1 - p2 * p2, 0.0f));
    return normalize(v3(alpha * nh.x, alpha * nh.y, maxf(nh.z, 1e-6f)));
}

PTI BsdfSample sample_dielectric(const Surface& s, V3 n, V3 wo, bool entering, float u) {
    float eta = entering ? 1.0f / s.ior : s.ior;
    float cos_o = clampf(dot(n, wo), 0.0f, 1.0f);
    float sin2_t = eta * eta * (1.0f - cos_o * cos_o);
    V3 reflect = 2.0f * cos_o * n - wo;
    if (sin2_t >= 1.0f) return BsdfSample{reflect, v3s(1.0f), 0.0f};
    float cos_t = sqrtf(1.0f - sin2_t);
    float rs = (eta * cos_o - cos_t) / (eta * cos_o + cos_t);
    float rp = (cos_o - eta * cos_t) / (cos_o + eta * cos_t);
    float fr = 0.5f * (rs * rs + rp * rp);
    if (u < fr) return BsdfSample{reflect, v3s(1.0f), 0.0f};
    return BsdfSample{normalize(-wo * eta + n * (eta * cos_o - cos_t)), s.base, 0.0f};
}

// False when the path ends (the sample fell below the surface).
PTI bool bsdf_sample(const Surface& s, V3 n, V3 wo, bool entering, float u0, float u1, float u2,
                     BsdfSample& out) {
    if (s.dielectric) {
        out = sample_dielectric(s, n, wo, entering, u0);
        return true;
    }
    float cos_o = dot(n, wo);
    if (cos_o <= 0.0f) return false;
    V3 t, b;
    basis(n, t, b);
    V3 wi;
    if (!lambertian(s) && u0 < lobes_of(s, cos_o).p_spec) {
        V3 wo_l = to_local(wo, n, t, b);
        V3 h = sample_vndf(wo_l, s.alpha, u1, u2);
        h = t * h.x + b * h.y + n * h.z;
        wi = 2.0f * dot(wo, h) * h - wo;
    } else {
        float r = sqrtf(u1);
        float sin_phi, cos_phi;
        sin_cos_turns(u2, sin_phi, cos_phi);
        wi = normalize(t * (r * cos_phi) + b * (r * sin_phi) + n * sqrtf(maxf(1.0f - u1, 0.0f)));
    }
    float pdf;
    V3 f = bsdf_eval(s, n, wo, wi, pdf);
    if (pdf <= 0.0f || !finite(pdf)) return false;
    out = BsdfSample{wi, f / pdf, pdf};
    return true;
}

// ---------------------------------------------------------------------------------------------
// Textures (texture.rs)
// ---------------------------------------------------------------------------------------------

PTI u32 wrap(long long i, u32 n32, u32 mode) {
    long long n = (long long)n32;
    long long r;
    if (mode == 2u) {
        r = i < 0 ? 0 : (i > n - 1 ? n - 1 : i);
    } else if (mode == 1u) {
        long long m = i % (2 * n);
        if (m < 0) m += 2 * n;
        r = m < n ? m : 2 * n - 1 - m;
    } else {
        r = i % n;
        if (r < 0) r += n;
    }
    return (u32)r;
}

PTI V4 texel(const TextureDesc& t, u32 x, u32 y, bool srgb) {
    const unsigned char* c = ptr<unsigned char>(params.texels) + 4ull * ((u64)t.offset + (u64)y * t.width + x);
    if (srgb) {
        const float* lut = ptr<float>(params.srgb);
        return v4(lut[c[0]], lut[c[1]], lut[c[2]], (float)c[3] / 255.0f);
    }
    return v4((float)c[0] / 255.0f, (float)c[1] / 255.0f, (float)c[2] / 255.0f,
              (float)c[3] / 255.0f);
}

PTF V4 sample_texture(const TextureDesc& t, V2 uv, bool srgb) {
    if (!finite(uv.x) || !finite(uv.y)) return texel(t, 0, 0, srgb);
    float xf = clampf(uv.x, -1e6f, 1e6f) * (float)t.width - 0.5f;
    float yf = clampf(uv.y, -1e6f, 1e6f) * (float)t.height - 0.5f;
    float x0 = floorf(xf), y0 = floorf(yf);
    float fx = xf - x0, fy = yf - y0;
    long long xi = (long long)x0, yi = (long long)y0;
    u32 xs[2] = {wrap(xi, t.width, t.wrap_u), wrap(xi + 1, t.width, t.wrap_u)};
    u32 ys[2] = {wrap(yi, t.height, t.wrap_v), wrap(yi + 1, t.height, t.wrap_v)};
    V4 top = lerp4(texel(t, xs[0], ys[0], srgb), texel(t, xs[1], ys[0], srgb), fx);
    V4 bottom = lerp4(texel(t, xs[0], ys[1], srgb), texel(t, xs[1], ys[1], srgb), fx);
    return lerp4(top, bottom, fy);
}

// Texture reference `r` at the coordinates of sets 0 and 1; white without a texture.
PTF V4 tex(const TexRef& r, const V2* uvs, bool srgb) {
    if (r.texture < 0 || (u32)r.texture >= params.num_textures) return v4(1.0f, 1.0f, 1.0f, 1.0f);
    V2 uv = uvs[r.tex_coord < 1u ? r.tex_coord : 1u];
    const float* m = r.m;
    V2 mapped = v2(m[0] * uv.x + m[1] * uv.y + m[2], m[3] * uv.x + m[4] * uv.y + m[5]);
    return sample_texture(ptr<TextureDesc>(params.textures)[r.texture], mapped, srgb);
}

PTI V3 emission(const Material& m, const V2* uvs) {
    return v3a(m.emissive) * xyz(tex(m.emissive_tex, uvs, true));
}

// ---------------------------------------------------------------------------------------------
// Geometry of a hit
// ---------------------------------------------------------------------------------------------

PTI V3 attr3(u64 a, u32 i) { return v3a(ptr<float>(a) + 3ull * i); }
PTI V2 attr2(u64 a, u32 i) {
    const float* p = ptr<float>(a) + 2ull * i;
    return v2(p[0], p[1]);
}
PTI V4 attr4(u64 a, u32 i) {
    const float* p = ptr<float>(a) + 4ull * i;
    return v4(p[0], p[1], p[2], p[3]);
}

struct Tri {
    u32 i[3];
};
PTI Tri triangle_of(const HitData& g, u32 prim) {
    const u32* t = ptr<u32>(g.triangles) + 3ull * prim;
    return Tri{{t[0], t[1], t[2]}};
}
PTI V2 interp2(u64 a, Tri t, const float* b) {
    if (a == 0ull) return v2(0.0f, 0.0f);
    return attr2(a, t.i[0]) * b[0] + attr2(a, t.i[1]) * b[1] + attr2(a, t.i[2]) * b[2];
}
PTI void uvs_at(const HitData& g, Tri t, const float* b, V2* uvs) {
    uvs[0] = interp2(g.uvs0, t, b);
    uvs[1] = interp2(g.uvs1, t, b);
}
PTI V4 color_at(const HitData& g, Tri t, const float* b) {
    if (g.colors == 0ull) return v4(1.0f, 1.0f, 1.0f, 1.0f);
    return attr4(g.colors, t.i[0]) * b[0] + attr4(g.colors, t.i[1]) * b[1] +
           attr4(g.colors, t.i[2]) * b[2];
}

PTI const HitData& hit_data() { return *reinterpret_cast<const HitData*>(optixGetSbtDataPointer()); }

PTI const InstanceXform& instance_xform() {
    u32 i = optixGetInstanceIndex();
    if (i >= params.num_instances) i = 0u;
    return ptr<InstanceXform>(params.instances)[i];
}

// Whether the hit instance moves while the shutter is open: its table entry is NaN, its place
// is the transform list's at the ray's time.
PTI bool moving(const InstanceXform& x) { return x.o2w[0] != x.o2w[0]; }

// The hit instance's matrices at the ray's time.
PTI InstanceXform xform_at_hit() {
    InstanceXform x = instance_xform();
    if (moving(x)) {
        optixGetObjectToWorldTransformMatrix(x.o2w);
        optixGetWorldToObjectTransformMatrix(x.w2o);
    }
    return x;
}

// ---------------------------------------------------------------------------------------------
// The radiance payload (programs.rs PathState): 16 words, the random state first so that the
// any-hit program can draw from it in both ray types
// ---------------------------------------------------------------------------------------------

struct PathState {
    u32 seed, done, depth;
    float pdf;
    V3 radiance, throughput, origin, direction;
};

PTI void to_words(const PathState& s, u32* w) {
    w[0] = s.seed;
    w[1] = s.done;
    w[2] = s.depth;
    w[3] = __float_as_uint(s.pdf);
    const V3* v[4] = {&s.radiance, &s.throughput, &s.origin, &s.direction};
    for (int k = 0; k < 4; ++k) {
        w[4 + 3 * k] = __float_as_uint(v[k]->x);
        w[5 + 3 * k] = __float_as_uint(v[k]->y);
        w[6 + 3 * k] = __float_as_uint(v[k]->z);
    }
}
PTI PathState from_words(const u32* w) {
    PathState s;
    s.seed = w[0];
    s.done = w[1];
    s.depth = w[2];
    s.pdf = __uint_as_float(w[3]);
    V3* v[4] = {&s.radiance, &s.throughput, &s.origin, &s.direction};
    for (int k = 0; k < 4; ++k) {
        *v[k] = v3(__uint_as_float(w[4 + 3 * k]), __uint_as_float(w[5 + 3 * k]),
                   __uint_as_float(w[6 + 3 * k]));
    }
    return s;
}

#define PT_GET(N) w[N] = optixGetPayload_##N();
#define PT_SET(N) optixSetPayload_##N(w[N]);
PTI PathState load_payload() {
    u32 w[PT_WORDS];
    PT_GET(0) PT_GET(1) PT_GET(2) PT_GET(3) PT_GET(4) PT_GET(5) PT_GET(6) PT_GET(7)
    PT_GET(8) PT_GET(9) PT_GET(10) PT_GET(11) PT_GET(12) PT_GET(13) PT_GET(14) PT_GET(15)
    return from_words(w);
}
PTI void store_payload(const PathState& s) {
    u32 w[PT_WORDS];
    to_words(s, w);
    PT_SET(0) PT_SET(1) PT_SET(2) PT_SET(3) PT_SET(4) PT_SET(5) PT_SET(6) PT_SET(7)
    PT_SET(8) PT_SET(9) PT_SET(10) PT_SET(11) PT_SET(12) PT_SET(13) PT_SET(14) PT_SET(15)
}
#undef PT_GET
#undef PT_SET

PTI float power_heuristic(float a, float b) {
    float a2 = a * a, b2 = b * b;
    return a2 + b2 > 0.0f ? a2 / (a2 + b2) : 0.0f;
}

// ---------------------------------------------------------------------------------------------
// The environment (lights.rs Environment)
// ---------------------------------------------------------------------------------------------

PTI u32 env_texel_of(V3 d) {
    float u = 0.5f + atan2f(d.x, -d.z) / PT_TAU;
    float v = acosf(clampf(d.y, -1.0f, 1.0f)) / PT_PI;
    float fx = u * (float)params.env_width, fy = v * (float)params.env_height;
    // `as usize` saturates: negative (or NaN) to 0.
    u32 x = fx > 0.0f ? (u32)minf(fx, 4294967040.0f) : 0u;
    u32 y = fy > 0.0f ? (u32)minf(fy, 4294967040.0f) : 0u;
    if (x > params.env_width - 1u) x = params.env_width - 1u;
    if (y > params.env_height - 1u) y = params.env_height - 1u;
    return y * params.env_width + x;
}

PTI V3 env_texel(u32 i) { return v3a(ptr<float>(params.env_texels) + 3ull * i); }

// A one-texel map: a uniform environment, looked up without map coordinates and sampled
// uniformly over the sphere (lights.rs uniform_map).
PTI bool env_uniform() { return params.env_width * params.env_height == 1u; }
#define PT_UNIFORM_PDF (1.0f / (4.0f * PT_PI))

// Bilinear between texel centres, wrapping in u, clamped at the poles (lights.rs radiance).
PTF V3 env_radiance(V3 d) {
    if (!finite3(d)) return v3s(0.0f);
    if (env_uniform()) return env_texel(0u);
    long long w = (long long)params.env_width, h = (long long)params.env_height;
    float u = 0.5f + atan2f(d.x, -d.z) / PT_TAU;
    float v = acosf(clampf(d.y, -1.0f, 1.0f)) / PT_PI;
    float xf = u * (float)w - 0.5f;
    float yf = v * (float)h - 0.5f;
    float xfl = floorf(xf), yfl = floorf(yf);
    float fx = xf - xfl, fy = yf - yfl;
    long long x0 = ((long long)xfl % w + w) % w;
    long long x1 = (x0 + 1) % w;
    long long y0 = (long long)yfl, y1 = y0 + 1;
    y0 = y0 < 0 ? 0 : (y0 > h - 1 ? h - 1 : y0);
    y1 = y1 < 0 ? 0 : (y1 > h - 1 ? h - 1 : y1);
    V3 top = env_texel((u32)(y0 * w + x0)) * (1.0f - fx) + env_texel((u32)(y0 * w + x1)) * fx;
    V3 bottom = env_texel((u32)(y1 * w + x0)) * (1.0f - fx) + env_texel((u32)(y1 * w + x1)) * fx;
    return top * (1.0f - fy) + bottom * fy;
}

// The probability that env_sample picks cell (x, y): its intervals' widths in the tables.
PTI float env_cell_probability(u32 x, u32 y) {
    const float* marginal = ptr<float>(params.env_marginal);
    const float* row = ptr<float>(params.env_conditional) + (u64)y * params.env_width;
    float py = marginal[y] - (y == 0u ? 0.0f : marginal[y - 1u]);
    float px = row[x] - (x == 0u ? 0.0f : row[x - 1u]);
    return py * px;
}

// A uniform point in a cell of probability p, per solid angle at polar sine sin_theta.
PTI float env_density(float p, float sin_theta) {
    return p * (float)(params.env_width * params.env_height) /
           (2.0f * PT_PI * PT_PI * maxf(sin_theta, 1e-6f));
}

PTF float env_pdf(V3 d) {
    if (params.env_total <= 0.0f || !finite3(d)) return 0.0f;
    if (env_uniform()) return PT_UNIFORM_PDF;
    u32 i = env_texel_of(d);
    float p = env_cell_probability(i % params.env_width, i / params.env_width);
    return env_density(p, sqrtf(maxf(1.0f - d.y * d.y, 0.0f)));
}

// The first index whose cumulative value exceeds u (Rust's partition_point(|&c| c <= u)).
PTI u32 upper_bound(const float* cdf, u32 n, float u) {
    u32 lo = 0u, hi = n;
    while (lo < hi) {
        u32 mid = lo + (hi - lo) / 2u;
        if (cdf[mid] <= u) {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo;
}

PTI float within(const float* cdf, u32 i, float u) {
    float lo = i == 0u ? 0.0f : cdf[i - 1u];
    float hi = cdf[i];
    return hi > lo ? clampf((u - lo) / (hi - lo), 0.0f, 0.999999f) : 0.5f;
}

PTI V3 direction_at(float u, float v) {
    float phi = (u - 0.5f) * PT_TAU;
    float theta = v * PT_PI;
    float s = sinf(theta);
    return v3(s * sinf(phi), cosf(theta), -s * cosf(phi));
}

// Draws a direction in proportion to radiance: false if the environment is black.
PTF bool env_sample(float u0, float u1, V3& d, V3& l, float& pdf) {
    if (params.env_total <= 0.0f) return false;
    if (env_uniform()) {
        float y = 1.0f - 2.0f * u0;
        float r = sqrtf(maxf(1.0f - y * y, 0.0f));
        float phi = u1 * PT_TAU;
        d = v3(r * cosf(phi), y, r * sinf(phi));
        pdf = PT_UNIFORM_PDF;
        l = env_texel(0u);
        return true;
    }
    u32 w = params.env_width, h = params.env_height;
    const float* marginal = ptr<float>(params.env_marginal);
    u32 y = upper_bound(marginal, h, u0);
    if (y > h - 1u) y = h - 1u;
    const float* row = ptr<float>(params.env_conditional) + (u64)y * w;
    u32 x = upper_bound(row, w, u1);
    if (x > w - 1u) x = w - 1u;
    float fy = within(marginal, y, u0);
    float fx = within(row, x, u1);
    d = direction_at(((float)x + fx) / (float)w, ((float)y + fy) / (float)h);
    pdf = env_density(env_cell_probability(x, y), sqrtf(maxf(1.0f - d.y * d.y, 0.0f)));
    if (!(pdf > 0.0f) || !finite(pdf)) return false;
    l = env_radiance(d);
    return true;
}

// An offset from the pixel's centre drawn from the filter's table (filter.rs sample_offset).
PTI float filter_offset(float u) {
    u32 n = params.filter_len;
    if (n < 2u) return u - 0.5f;
    const float* t = ptr<float>(params.filter);
    float x = clampf(u, 0.0f, 1.0f) * (float)(n - 1u);
    u32 i = (u32)x;
    if (i > n - 2u) i = n - 2u;
    float f = x - (float)i;
    return t[i] * (1.0f - f) + t[i + 1u] * f;
}

// ---------------------------------------------------------------------------------------------
// Shading
// ---------------------------------------------------------------------------------------------

struct Shading {
    V3 point, ng, ns;
    V2 uvs[2];
    V4 color;
    bool front;
};

PTF Shading shading(const Material& m, const HitData& g) {
    const InstanceXform x = xform_at_hit();
    V3 dir = from_f3(optixGetWorldRayDirection());
    Shading sh;
    sh.point = from_f3(optixGetWorldRayOrigin()) + dir * optixGetRayTmax();
    u32 prim = optixGetPrimitiveIndex();
    bool has_t = prim < g.num_triangles;
    Tri t = has_t ? triangle_of(g, prim) : Tri{{0u, 0u, 0u}};
    V3 a = attr3(g.positions, t.i[0]), b = attr3(g.positions, t.i[1]),
       c = attr3(g.positions, t.i[2]);
    V3 ng = normalize_or(xf_normal(x.w2o, cross(b - a, c - a)), v3(0.0f, 1.0f, 0.0f));
    sh.front = dot(ng, dir) < 0.0f;
    ng = sh.front ? ng : -ng;
    float2 bc = optixGetTriangleBarycentrics();
    float bary[3] = {1.0f - bc.x - bc.y, bc.x, bc.y};
    V3 ns = ng;
    if (has_t) {
        uvs_at(g, t, bary, sh.uvs);
        sh.color = color_at(g, t, bary);
        if (g.normals != 0ull) {
            V3 n = attr3(g.normals, t.i[0]) * bary[0] + attr3(g.normals, t.i[1]) * bary[1] +
                   attr3(g.normals, t.i[2]) * bary[2];
            ns = normalize_or(xf_normal(x.w2o, n), ng);
        }
    } else {
        sh.uvs[0] = v2(0.0f, 0.0f);
        sh.uvs[1] = v2(0.0f, 0.0f);
        sh.color = v4(1.0f, 1.0f, 1.0f, 1.0f);
    }
    if (dot(ns, ng) < 0.0f) ns = -ns;
    if (m.normal_tex.texture >= 0 && has_t) {
        u64 set = m.normal_tex.tex_coord == 1u ? g.uvs1 : g.uvs0;
        if (set != 0ull) {
            // Tangent frame from the triangle's positions and the normal map's coordinates.
            V2 t0 = attr2(set, t.i[0]), t1 = attr2(set, t.i[1]), t2 = attr2(set, t.i[2]);
            V2 d1 = t1 - t0, d2 = t2 - t0;
            float det = d1.x * d2.y - d2.x * d1.y;
            if (fabsf(det) > 1e-12f) {
                V3 e1 = b - a, e2 = c - a;
                V3 tangent = xf_vector(x.o2w, (e1 * d2.y - e2 * d1.y) / det);
                tangent = normalize_or_zero(tangent - ns * dot(ns, tangent));
                if (!is_zero(tangent)) {
                    // glTF: +Y is up in the image (decreasing v), bitangent = cross(N, T) * w,
                    // w = -1 for a mirrored mapping (det > 0).
                    V3 bitangent = cross(ns, tangent);
                    if (det > 0.0f) bitangent = -bitangent;
                    V3 n = xyz(tex(m.normal_tex, sh.uvs, false)) * 2.0f - v3s(1.0f);
                    n = v3(n.x * m.normal_scale, n.y * m.normal_scale, n.z);
                    V3 mapped = normalize_or(tangent * n.x + bitangent * n.y + ns * n.z, ns);
                    if (dot(mapped, ng) > 0.0f) ns = mapped;
                }
            }
        }
    }
    if (dot(ns, -dir) <= 0.0f) ns = ng;
    sh.ng = ng;
    sh.ns = ns;
    return sh;
}

PTI V3 offset(const Shading& s, V3 dir) {
    float scale = params.eps + max_element(abs3(s.point)) * 1e-6f;
    return dot(dir, s.ng) >= 0.0f ? s.point + s.ng * scale : s.point - s.ng * scale;
}

// Traces a shadow ray; true when nothing blocks it.
// It takes the time of the ray being shaded.
PTI bool visible(u32 seed, V3 from, V3 dir, float tmax) {
    u32 w0 = seed, w1 = 0u;
    optixTrace(params.handle, f3(from), f3(dir), 0.0f, tmax, optixGetRayTime(),
               (OptixVisibilityMask)0xFF,
               OPTIX_RAY_FLAG_TERMINATE_ON_FIRST_HIT | OPTIX_RAY_FLAG_DISABLE_CLOSESTHIT,
               PT_SHADOW, PT_RAY_TYPES, PT_SHADOW, w0, w1);
    return w1 != 0u;
}

PTI float inf() { return __uint_as_float(0x7f800000u); }

// One light sample (a triangle or the environment), weighted against BSDF sampling.
PTF V3 next_event(Draws& rng, const Surface& surf, const Shading& sh, V3 wo) {
    float pick = rng.get(PT_DIM_LIGHT_PICK);
    float u[3];
    u[0] = rng.get(PT_DIM_LIGHT_0);
    u[1] = rng.get(PT_DIM_LIGHT_1);
    u[2] = rng.get(PT_DIM_LIGHT_2);
    if (pick < params.p_env) {
        V3 wi, l;
        float pdf;
        if (!env_sample(u[0], u[1], wi, l, pdf)) return v3s(0.0f);
        pdf = pdf * params.p_env;
        float bsdf_pdf;
        V3 f = bsdf_eval(surf, sh.ns, wo, wi, bsdf_pdf);
        if (is_zero(f) || dot(wi, sh.ng) <= 0.0f) return v3s(0.0f);
        if (!visible(rng.rng.s, offset(sh, wi), wi, inf())) return v3s(0.0f);
        return f * l * (power_heuristic(pdf, bsdf_pdf) / pdf);
    }
    if (params.num_lights == 0u) return v3s(0.0f);
    u32 i = upper_bound(ptr<float>(params.light_cdf), params.num_lights, u[0]);
    if (i > params.num_lights - 1u) i = params.num_lights - 1u;
    const LightTri& tri = ptr<LightTri>(params.lights)[i];
    float b1 = u[1], b2 = u[2];
    if (b1 + b2 > 1.0f) {
        b1 = 1.0f - b1;
        b2 = 1.0f - b2;
    }
    V3 lp = v3a(tri.p0) + v3a(tri.e1) * b1 + v3a(tri.e2) * b2;
    if (tri.material >= params.num_materials) return v3s(0.0f);
    float area_pdf = ptr<float>(params.light_area_pdf)[tri.material];
    const Material& lm = ptr<Material>(params.materials)[tri.material];
    V3 from = offset(sh, lp - sh.point);
    V3 to = lp - from;
    float dist = length(to);
    if (!(dist > 0.0f)) return v3s(0.0f);
    V3 wi = to / dist;
    V3 ln = v3a(tri.normal);
    float cos_l = tri.two_sided ? fabsf(dot(ln, wi)) : -dot(ln, wi);
    float bsdf_pdf;
    V3 f = bsdf_eval(surf, sh.ns, wo, wi, bsdf_pdf);
    if (is_zero(f) || dot(wi, sh.ng) <= 0.0f || cos_l <= 1e-6f) return v3s(0.0f);
    V2 uv = v2(tri.uv[0], tri.uv[1]) * (1.0f - b1 - b2) + v2(tri.uv[2], tri.uv[3]) * b1 +
            v2(tri.uv[4], tri.uv[5]) * b2;
    // The light's texture coordinates are those of its emissive texture's set.
    V2 uvs[2] = {uv, uv};
    V3 le = emission(lm, uvs);
    float pdf = (1.0f - params.p_env) * area_pdf * dist * dist / cos_l;
    if (is_zero(le) || !(pdf > 0.0f)) return v3s(0.0f);
    // Stop short of the light itself.
    if (!visible(rng.rng.s, from, wi, dist * (1.0f - 1e-4f) - params.eps)) return v3s(0.0f);
    return f * le * (power_heuristic(pdf, bsdf_pdf) / pdf);
}

// glTF's punctual lights are photometric; the renderer works at 683 lm/W.
#define PT_LUMENS_PER_WATT 683.0f

// One punctual light, chosen uniformly, sampled exactly.
PTF V3 punctual_light(Draws& rng, const Surface& surf, const Shading& sh, V3 wo) {
    u32 n = params.num_punctual;
    if (n == 0u) return v3s(0.0f);
    float fi = rng.get(PT_DIM_PUNCTUAL) * (float)n;
    u32 i = fi > 0.0f ? (u32)fi : 0u;
    if (i > n - 1u) i = n - 1u;
    const Punctual& l = ptr<Punctual>(params.punctual)[i];
    V3 wi, e;
    bool finite_dist;
    if (l.kind == 0u) {
        wi = -v3a(l.direction);
        e = v3a(l.intensity);
        finite_dist = false;
    } else {
        V3 to = v3a(l.position) - sh.point;
        float d2 = dot(to, to);
        if (!(d2 > 0.0f)) return v3s(0.0f);
        float d = sqrtf(d2);
        wi = to / d;
        e = v3a(l.intensity) / d2;
        // The extension's recommended window: smooth to zero at the range (infinite for
        // none, where the window is 1).
        float q = d / l.range;
        float q2 = q * q;
        float w = clampf(1.0f - q2 * q2, 0.0f, 1.0f);
        e = e * (w * w);
        if (l.kind == 2u) {
            float scale = 1.0f / maxf(l.cos_inner - l.cos_outer, 1e-3f);
            float t = clampf((dot(v3a(l.direction), -wi) - l.cos_outer) * scale, 0.0f, 1.0f);
            e = e * (t * t);
        }
        finite_dist = true;
    }
    e = e / PT_LUMENS_PER_WATT;
    if (is_zero(e) || dot(wi, sh.ng) <= 0.0f) return v3s(0.0f);
    float unused;
    V3 f = bsdf_eval(surf, sh.ns, wo, wi, unused);
    if (is_zero(f)) return v3s(0.0f);
    V3 from = offset(sh, wi);
    float tmax = finite_dist ? length(v3a(l.position) - from) * (1.0f - 1e-4f) : inf();
    if (!visible(rng.rng.s, from, wi, tmax)) return v3s(0.0f);
    return f * e * (float)n;
}

// Coverage of an alpha-tested material at the current candidate hit.
PTI float alpha_at(const Material& m, const HitData& g) {
    u32 prim = optixGetPrimitiveIndex();
    if (prim >= g.num_triangles) return 1.0f;
    Tri t = triangle_of(g, prim);
    float2 bc = optixGetTriangleBarycentrics();
    float b[3] = {1.0f - bc.x - bc.y, bc.x, bc.y};
    V2 uvs[2];
    uvs_at(g, t, b, uvs);
    return m.base_color[3] * tex(m.base_color_tex, uvs, true).w * color_at(g, t, b).w;
}

}  // namespace pt

using namespace pt;

// ---------------------------------------------------------------------------------------------
// The programs
// ---------------------------------------------------------------------------------------------

// The first hit's auxiliary values (RenderOptions::aovs): sums per pixel of the surface's
// albedo (base colour with its texture and vertex colour), shading normal (world space) and
// distance from the camera, and the number of samples that hit. Each launch index owns its
// pixel, so the sums need no atomics. The same sums in the same order as programs.rs.
PTF void write_aov(const Material& m, const Shading& sh) {
    const uint3 idx = optixGetLaunchIndex();
    const uint3 dim = optixGetLaunchDimensions();
    u32 pixel = idx.y * dim.x + idx.x;
    V3 albedo = v3a(m.base_color) * xyz(tex(m.base_color_tex, sh.uvs, true)) * xyz(sh.color);
    float* a = reinterpret_cast<float*>(params.aov) + 8ull * pixel;
    a[0] = a[0] + albedo.x;
    a[1] = a[1] + albedo.y;
    a[2] = a[2] + albedo.z;
    a[3] = a[3] + sh.ns.x;
    a[4] = a[4] + sh.ns.y;
    a[5] = a[5] + sh.ns.z;
    a[6] = a[6] + optixGetRayTmax();
    a[7] = a[7] + 1.0f;
}

extern "C" __global__ void __raygen__camera() {
    const uint3 idx = optixGetLaunchIndex();
    const uint3 dim = optixGetLaunchDimensions();
    // The sample is the full image's: its place there keys the random stream and the camera
    // ray; the sums go to the window's pixel.
    const u32 x = params.crop_x0 + idx.x, y = params.crop_y0 + idx.y;
    const u32 w = params.image_width, h = params.image_height;
    u32 pixel = idx.y * dim.x + idx.x;
    const u32 salt = stream_salt();
    Draws rng = draws_new(rng_new(y * w + x, params.sample, salt), y * w + x, params.sample, salt);
    float jx = rng.get(PT_DIM_PIXEL);
    float jy = rng.get(PT_DIM_PIXEL + 1u);
    // Filter importance sampling: the offset from the pixel's centre follows the filter.
    float ox = 0.5f + filter_offset(jx);
    float oy = 0.5f + filter_offset(jy);
    float sx = 2.0f * ((float)x + ox) / (float)w - 1.0f;
    float sy = 1.0f - 2.0f * ((float)y + oy) / (float)h;
    // The path's time (motion.rs Shutter::time), drawn after the pixel's offsets so that a
    // render without motion keeps its random sequence; every ray of the path takes it.
    float time = 0.0f;
    if (params.shutter_on != 0u) {
        const float u = rng.get(PT_DIM_TIME);
        time = fminf(params.shutter_open + (params.shutter_close - params.shutter_open) * u,
                     params.shutter_close);
    }
    // The camera at that time (programs.rs CameraFrame::at: linear between its keys).
    V3 origin = v3a(params.cam_origin), forward = v3a(params.cam_forward);
    V3 right = v3a(params.cam_right), up = v3a(params.cam_up);
    if (params.shutter_on != 0u && params.num_cam_keys >= 2u &&
        params.shutter_close > params.shutter_open) {
        const float* keys = reinterpret_cast<const float*>(params.cam_keys);
        const u32 last = params.num_cam_keys - 1u;
        const float u =
            fminf(fmaxf((time - params.shutter_open) / (params.shutter_close - params.shutter_open),
                        0.0f),
                  1.0f) *
            (float)last;
        if (u >= (float)last) {
            const float* b = keys + 12ull * last;
            origin = v3a(b);
            forward = v3a(b + 3);
            right = v3a(b + 6);
            up = v3a(b + 9);
        } else {
            const u32 k = (u32)u < last - 1u ? (u32)u : last - 1u;
            const float f = u - (float)k;
            const float* a = keys + 12ull * k;
            const float* b = a + 12;
            origin = v3a(a) + (v3a(b) - v3a(a)) * f;
            forward = v3a(a + 3) + (v3a(b + 3) - v3a(a + 3)) * f;
            right = v3a(a + 6) + (v3a(b + 6) - v3a(a + 6)) * f;
            up = v3a(a + 9) + (v3a(b + 9) - v3a(a + 9)) * f;
        }
    }
    V3 dir = normalize(forward + right * sx + up * sy);
    PathState s;
    s.seed = rng.rng.s;
    s.done = 0u;
    s.depth = 0u;
    s.pdf = 0.0f;
    s.radiance = v3s(0.0f);
    s.throughput = v3s(1.0f);
    s.origin = origin;
    s.direction = dir;
    // Each trace either ends the path or adds a vertex, and vertices are capped.
    for (u32 k = 0; k <= params.max_depth; ++k) {
        u32 w[PT_WORDS];
        to_words(s, w);
        optixTrace(params.handle, f3(s.origin), f3(s.direction), 0.0f, inf(), time,
                   (OptixVisibilityMask)0xFF, OPTIX_RAY_FLAG_NONE, PT_RADIANCE, PT_RAY_TYPES,
                   PT_RADIANCE, w[0], w[1], w[2], w[3], w[4], w[5], w[6], w[7], w[8], w[9], w[10],
                   w[11], w[12], w[13], w[14], w[15]);
        s = from_words(w);
        if (s.done != 0u) break;
    }
    V3 r = s.radiance;
    // A non-finite sample is dropped; the count still advances, so it reads as black.
    if (!finite3(r)) r = v3s(0.0f);
    // Four floats a pixel (not float4: the host buffer is only 4-byte aligned).
    float* a = reinterpret_cast<float*>(params.accum) + 4ull * pixel;
    a[0] = a[0] + r.x;
    a[1] = a[1] + r.y;
    a[2] = a[2] + r.z;
    a[3] = a[3] + 1.0f;
}

extern "C" __global__ void __closesthit__radiance() {
    PathState s = load_payload();
    const HitData& g = hit_data();
    if (g.material >= params.num_materials) {
        s.done = 1u;
        store_payload(s);
        return;
    }
    const Material& m = ptr<Material>(params.materials)[g.material];
    Shading sh = shading(m, g);
    if (params.aov != 0ull && s.depth == 0u) write_aov(m, sh);
    V3 dir = from_f3(optixGetWorldRayDirection());
    V3 wo = -dir;
    const uint3 idx = optixGetLaunchIndex();
    const u32 px = params.crop_x0 + idx.x, py = params.crop_y0 + idx.y;
    Draws rng = draws_new(Rng{s.seed}, py * params.image_width + px, params.sample, stream_salt());
    rng.base = PT_DIM_CAMERA + s.depth * PT_DIM_PER_VERTEX;
    V3 thr = s.throughput;
    V3 rad = s.radiance;

    // Emission, weighted against the light sample that could have found it. Single-sided
    // materials emit from their front face only.
    V3 le = (sh.front || m.double_sided) ? emission(m, sh.uvs) : v3s(0.0f);
    if (!is_zero(le)) {
        float w = 1.0f;
        // A moving emitter is not sampled by next-event estimation: found only here, in full.
        if (s.pdf > 0.0f && !moving(instance_xform())) {
            float t = optixGetRayTmax();
            float cos_l = maxf(fabsf(dot(sh.ng, wo)), 1e-6f);
            float light_pdf = (1.0f - params.p_env) *
                              ptr<float>(params.light_area_pdf)[g.material] * t * t / cos_l;
            w = power_heuristic(s.pdf, light_pdf);
        }
        rad = rad + thr * le * w;
    }
    s.depth += 1u;
    if (s.depth >= params.max_depth) {
        s.done = 1u;
    } else {
        V4 base_tex = tex(m.base_color_tex, sh.uvs, true);
        V4 mr = tex(m.metallic_roughness_tex, sh.uvs, false);
        // glTF: the vertex colour multiplies the base colour factor and texture.
        V3 base = v3a(m.base_color) * xyz(base_tex) * xyz(sh.color);
        Surface surf =
            surface_new(base, m.metallic * mr.z, m.roughness * mr.y, m.transmission, m.ior,
                        m.specular);
        if (!surf.dielectric) {
            rad = rad + thr * next_event(rng, surf, sh, wo);
            rad = rad + thr * punctual_light(rng, surf, sh, wo);
        }
        float u0 = rng.get(PT_DIM_BSDF_0);
        float u1 = rng.get(PT_DIM_BSDF_1);
        float u2 = rng.get(PT_DIM_BSDF_2);
        BsdfSample b;
        if (bsdf_sample(surf, sh.ns, wo, sh.front, u0, u1, u2, b) &&
            (surf.dielectric || dot(b.wi, sh.ng) > 0.0f)) {
            thr = thr * b.weight;
            s.pdf = b.pdf;
            s.origin = offset(sh, b.wi);
            s.direction = b.wi;
            if (s.depth >= params.roulette_depth) {
                float q = roulette_survival(thr);
                if (rng.get(PT_DIM_ROULETTE) >= q) {
                    s.done = 1u;
                } else {
                    thr = thr / q;
                }
            }
            if (!finite3(thr)) s.done = 1u;
        } else {
            s.done = 1u;
        }
    }
    s.seed = rng.rng.s;
    s.radiance = rad;
    s.throughput = thr;
    store_payload(s);
}

// Shadow rays end at the first opaque hit (DISABLE_CLOSESTHIT): this never runs. It is the
// closest-hit program of the shadow ray type's groups, which the device-neutral API requires.
extern "C" __global__ void __closesthit__shadow() {}

// Cutouts for MASK materials, stochastic transparency for BLEND ones (both ray types).
extern "C" __global__ void __anyhit__alpha() {
    const HitData& g = hit_data();
    if (g.material >= params.num_materials) return;
    const Material& m = ptr<Material>(params.materials)[g.material];
    if (m.alpha_mode == 0u) return;
    float alpha = alpha_at(m, g);
    bool keep;
    if (m.alpha_mode == 1u) {
        keep = alpha >= m.alpha_cutoff;
    } else {
        // One decision per (path state, primitive, instance): the same surface point is either
        // in or out for this ray, whatever the traversal order.
        u32 h = hash(optixGetPayload_0() ^
                     hash(optixGetPrimitiveIndex() ^ hash(optixGetInstanceIndex())));
        keep = alpha > (float)h * (1.0f / 4294967296.0f);
    }
    if (!keep) {
        optixIgnoreIntersection();
        return;
    }
}

extern "C" __global__ void __miss__environment() {
    PathState s = load_payload();
    V3 d = from_f3(optixGetWorldRayDirection());
    V3 l = env_radiance(d);
    if (!is_zero(l)) {
        float w = s.pdf > 0.0f ? power_heuristic(s.pdf, params.p_env * env_pdf(d)) : 1.0f;
        s.radiance = s.radiance + s.throughput * l * w;
    }
    s.done = 1u;
    store_payload(s);
}

extern "C" __global__ void __miss__shadow() { optixSetPayload_1(1u); }
