//! Where the path tracer's random numbers come from: independent hash-based numbers
//! ([`Rng`]), or an Owen-scrambled Sobol sequence (Burley 2020, "Practical
//! Hash-based Owen Scrambling").
//!
//! The Sobol sampler gives each use of a random number in a path its own dimension
//! ([`dim`]): the pixel offset and the time, then per path vertex the light sample, the BSDF
//! sample, the punctual light's choice and Russian roulette. Dimensions are grouped in fours;
//! a group is the first four dimensions of the Sobol sequence (Joe and Kuo's direction numbers)
//! at a sample index shuffled by a nested uniform scramble, each coordinate then Owen-scrambled
//! by a hash (Laine and Karras' construction with Vegard Nossum's constants as in
//! `sobol_burley`); the seeds of the shuffle and of the scrambles come from the pixel, the
//! group and the user's seed, so that pixels are decorrelated and groups independent, while
//! the first 2^k samples of a pixel stay stratified in every group. Dimensions past
//! [`SOBOL_DIMENSIONS`] (deep path vertices) fall back to the hash numbers.
//!
//! Either way the hash stream advances once per draw, so the seeds that shadow rays and the
//! any-hit program take from it do not depend on the sampler. The same algorithm, with the
//! same constants, is in `device_programs.cu` (`sobol_sample`, `Draws`), so that both
//! backends sample alike.

use super::bsdf::{hash, Rng};
use std::fmt;
use std::str::FromStr;

/// Which random numbers the path tracer uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Sampler {
    /// Independent hash-based numbers per draw.
    Independent,
    /// Owen-scrambled Sobol points per pixel, one dimension per use (then hash numbers past
    /// [`SOBOL_DIMENSIONS`]): lower error at equal samples (`docs/BENCHMARKS.md`).
    #[default]
    Sobol,
}

impl Sampler {
    /// The name `FromStr` takes.
    pub fn name(self) -> &'static str {
        match self {
            Sampler::Independent => "independent",
            Sampler::Sobol => "sobol",
        }
    }

    /// The value of the C++ programs' `Params::sampler`.
    pub(crate) fn code(self) -> u32 {
        match self {
            Sampler::Independent => 0,
            Sampler::Sobol => 1,
        }
    }
}

impl fmt::Display for Sampler {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Sampler {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "independent" | "random" => Ok(Sampler::Independent),
            "sobol" => Ok(Sampler::Sobol),
            _ => Err(format!("unknown sampler {s:?} (sobol or independent)")),
        }
    }
}

/// The dimensions of a path: the camera's, then [`dim::PER_VERTEX`] per path vertex.
pub mod dim {
    /// The pixel offset's x (its y is the next dimension).
    pub const PIXEL: u32 = 0;
    /// The camera ray's time in the shutter.
    pub const TIME: u32 = 2;
    /// The camera's dimensions (one spare, for a lens).
    pub const CAMERA: u32 = 4;
    /// Dimensions per path vertex.
    pub const PER_VERTEX: u32 = 12;
    /// Within a vertex: the light sample's three numbers (`u[1]`, `u[2]`: the point on a
    /// triangle, the first pair of the group; `u[0]`: the triangle).
    pub const LIGHT: [u32; 3] = [2, 0, 1];
    /// Within a vertex: environment or triangles.
    pub const LIGHT_PICK: u32 = 3;
    /// Within a vertex: the BSDF sample's three numbers (`u[0]` the lobe, `u[1]`, `u[2]` the
    /// direction, the group's first pair).
    pub const BSDF: [u32; 3] = [6, 4, 5];
    /// Within a vertex: Russian roulette.
    pub const ROULETTE: u32 = 7;
    /// Within a vertex: the punctual light.
    pub const PUNCTUAL: u32 = 8;

    /// The first dimension of path vertex `depth` (0: the camera ray's hit).
    pub const fn vertex(depth: u32) -> u32 {
        CAMERA + depth.saturating_mul(PER_VERTEX)
    }
}

/// Dimensions that the Sobol sampler draws from the sequence: the camera's and five path
/// vertices'; later ones are hash numbers.
pub const SOBOL_DIMENSIONS: u32 = dim::vertex(5);

/// Direction numbers of the Sobol sequence's first four dimensions, the most significant bit
/// first (dimension 0 is van der Corput's; Joe and Kuo's `new-joe-kuo-6.21201` for the others).
/// The same table is `PT_SOBOL` in `device_programs.cu`.
pub const SOBOL_DIRECTIONS: [[u32; 32]; 4] = [
    [
        0x80000000, 0x40000000, 0x20000000, 0x10000000, 0x08000000, 0x04000000, 0x02000000,
        0x01000000, 0x00800000, 0x00400000, 0x00200000, 0x00100000, 0x00080000, 0x00040000,
        0x00020000, 0x00010000, 0x00008000, 0x00004000, 0x00002000, 0x00001000, 0x00000800,
        0x00000400, 0x00000200, 0x00000100, 0x00000080, 0x00000040, 0x00000020, 0x00000010,
        0x00000008, 0x00000004, 0x00000002, 0x00000001,
    ],
    [
        0x80000000, 0xc0000000, 0xa0000000, 0xf0000000, 0x88000000, 0xcc000000, 0xaa000000,
        0xff000000, 0x80800000, 0xc0c00000, 0xa0a00000, 0xf0f00000, 0x88880000, 0xcccc0000,
        0xaaaa0000, 0xffff0000, 0x80008000, 0xc000c000, 0xa000a000, 0xf000f000, 0x88008800,
        0xcc00cc00, 0xaa00aa00, 0xff00ff00, 0x80808080, 0xc0c0c0c0, 0xa0a0a0a0, 0xf0f0f0f0,
        0x88888888, 0xcccccccc, 0xaaaaaaaa, 0xffffffff,
    ],
    [
        0x80000000, 0xc0000000, 0x60000000, 0x90000000, 0xe8000000, 0x5c000000, 0x8e000000,
        0xc5000000, 0x68800000, 0x9cc00000, 0xee600000, 0x55900000, 0x80680000, 0xc09c0000,
        0x60ee0000, 0x90550000, 0xe8808000, 0x5cc0c000, 0x8e606000, 0xc5909000, 0x6868e800,
        0x9c9c5c00, 0xeeee8e00, 0x5555c500, 0x8000e880, 0xc0005cc0, 0x60008e60, 0x9000c590,
        0xe8006868, 0x5c009c9c, 0x8e00eeee, 0xc5005555,
    ],
    [
        0x80000000, 0xc0000000, 0x20000000, 0x50000000, 0xf8000000, 0x74000000, 0xa2000000,
        0x93000000, 0xd8800000, 0x25400000, 0x59e00000, 0xe6d00000, 0x78080000, 0xb40c0000,
        0x82020000, 0xc3050000, 0x208f8000, 0x51474000, 0xfbea2000, 0x75d93000, 0xa0858800,
        0x914e5400, 0xdbe79e00, 0x25db6d00, 0x58800080, 0xe54000c0, 0x79e00020, 0xb6d00050,
        0x800800f8, 0xc00c0074, 0x200200a2, 0x50050093,
    ],
];

/// Coordinate `d` (0..4) of Sobol point `index`, unscrambled, as a 32-bit binary fraction.
pub fn sobol(index: u32, d: usize) -> u32 {
    let v = &SOBOL_DIRECTIONS[d & 3];
    let mut x = 0u32;
    for (bit, &v) in v.iter().enumerate() {
        // Branch-free, as in the C++ programs.
        x ^= v & 0u32.wrapping_sub((index >> bit) & 1);
    }
    x
}

/// Laine and Karras' permutation of the bits of `x`, each bit flipped by a function of the
/// lower ones (here with Nossum's improved constants).
fn lk_permute(mut x: u32, seed: u32) -> u32 {
    x ^= x.wrapping_mul(0x3d20adea);
    x = x.wrapping_add(seed);
    x = x.wrapping_mul((seed >> 16) | 1);
    x ^= x.wrapping_mul(0x05526c56);
    x ^= x.wrapping_mul(0x53a22864);
    x
}

/// A nested uniform (Owen) scramble of the binary fraction `x` by `seed`: each digit flipped by
/// a hash of the digits before it.
pub fn owen_scramble(x: u32, seed: u32) -> u32 {
    lk_permute(x.reverse_bits(), seed).reverse_bits()
}

/// The seed of a pixel's Sobol scrambles, for the stream salt `salt`
/// ([`crate::programs::stream_salt`]).
pub fn pixel_seed(pixel: u32, salt: u32) -> u32 {
    hash(pixel ^ hash(salt ^ 0x50b0_1e5d))
}

/// Dimension `dim` of sample `index` of the pixel with seed `seed`, in [0, 1).
pub fn sobol_sample(index: u32, dim: u32, seed: u32) -> f32 {
    let group = hash(seed ^ hash(dim >> 2));
    let shuffled = owen_scramble(index, group);
    let x = sobol(shuffled, (dim & 3) as usize);
    let x = owen_scramble(x, hash(group ^ hash((dim & 3) + 1)));
    (x >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// The draws of one path: the hash stream, and the Sobol point when the sampler is Sobol.
#[derive(Clone, Copy, Debug)]
pub struct Draws {
    /// The hash stream (advanced once per draw whatever the sampler).
    pub rng: Rng,
    /// The pixel's Sobol seed, for the Sobol sampler.
    sobol: Option<u32>,
    /// The sample index.
    index: u32,
    /// The first dimension of the current path vertex.
    pub base: u32,
}

impl Draws {
    /// The draws of sample `index` of the pixel `pixel` (of the full image) with stream salt
    /// `salt`, resuming the hash stream `rng`, at the camera's dimensions.
    pub fn new(sampler: Sampler, rng: Rng, pixel: u32, index: u32, salt: u32) -> Draws {
        Draws {
            rng,
            sobol: (sampler == Sampler::Sobol).then(|| pixel_seed(pixel, salt)),
            index,
            base: 0,
        }
    }

    /// The number of dimension `base + k` in [0, 1).
    pub fn get(&mut self, k: u32) -> f32 {
        let u = self.rng.uniform();
        let d = self.base.saturating_add(k);
        match self.sobol {
            Some(seed) if d < SOBOL_DIMENSIONS => sobol_sample(self.index, d, seed),
            _ => u,
        }
    }
}
