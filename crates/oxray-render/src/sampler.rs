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
    #[must_use]
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
    #[must_use]
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
#[must_use]
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
#[inline]
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
#[must_use]
pub fn owen_scramble(x: u32, seed: u32) -> u32 {
    lk_permute(x.reverse_bits(), seed).reverse_bits()
}

/// The seed of a pixel's Sobol scrambles, for the stream salt `salt`
/// ([`crate::programs::stream_salt`]).
#[must_use]
pub fn pixel_seed(pixel: u32, salt: u32) -> u32 {
    hash(pixel ^ hash(salt ^ 0x50b0_1e5d))
}

/// `hash(g)` for every group of four dimensions that the sequence serves: the part of a group's
/// seed that does not depend on the pixel.
const GROUP_SALTS: [u32; (SOBOL_DIMENSIONS / 4) as usize] = {
    let mut t = [0; (SOBOL_DIMENSIONS / 4) as usize];
    let mut g = 0;
    while g < t.len() {
        t[g] = hash(g as u32);
        g += 1;
    }
    t
};

/// `hash(k + 1)` for a dimension's place `k` in its group: the salt of its scramble's seed.
const COORDINATE_SALTS: [u32; 4] = [hash(1), hash(2), hash(3), hash(4)];

/// The Sobol points of the four dimensions, bit-reversed, as sums of one term per byte of the
/// bit-reversed index: entry `[p][v][d]` is the XOR of the reversed direction numbers of
/// dimension `d` whose index bits are the set bits of byte value `v` at byte `p` of
/// `index.reverse_bits()`. A point is then four lookups and XORs instead of a loop over the
/// 32 bits, and it comes out reversed, which is the order the output scramble permutes in.
/// 16 KiB: it stays in the level-1 cache.
static SOBOL_BYTES: [[[u32; 4]; 256]; 4] = {
    let mut t = [[[0u32; 4]; 256]; 4];
    let mut p = 0;
    while p < 4 {
        let mut v = 0;
        while v < 256 {
            let mut d = 0;
            while d < 4 {
                let mut x = 0u32;
                let mut j = 0;
                while j < 8 {
                    if (v >> j) & 1 == 1 {
                        // Bit 8p + j of the reversed index is bit 31 - (8p + j) of the index.
                        x ^= SOBOL_DIRECTIONS[d][31 - (8 * p + j)].reverse_bits();
                    }
                    j += 1;
                }
                t[p][v][d] = x;
                d += 1;
            }
            v += 1;
        }
        p += 1;
    }
    t
};

/// The four dimensions' Sobol points at index `reversed.reverse_bits()`, each bit-reversed.
#[inline]
fn sobol_reversed(reversed: u32) -> [u32; 4] {
    let mut x = [0u32; 4];
    for (p, table) in SOBOL_BYTES.iter().enumerate() {
        let row = &table[((reversed >> (8 * p)) & 0xff) as usize];
        for (x, r) in x.iter_mut().zip(row) {
            *x ^= r;
        }
    }
    x
}

/// What a group of four dimensions shares for one sample of a pixel: the seed of its scrambles
/// and the four Sobol points at the shuffled index, bit-reversed (see [`sobol_sample`]).
#[derive(Clone, Copy, Debug)]
struct Group {
    seed: u32,
    points: [u32; 4],
}

impl Group {
    /// Group `g` (below `SOBOL_DIMENSIONS / 4`) of sample `index` of the pixel with seed
    /// `pixel`.
    #[inline]
    fn new(index: u32, g: u32, pixel: u32) -> Group {
        let seed = hash(pixel ^ GROUP_SALTS[g as usize]);
        // The shuffle is an Owen scramble of the index; its last bit reversal and the one
        // before the output scramble cancel out in the reversed table.
        let shuffled = lk_permute(index.reverse_bits(), seed);
        Group {
            seed,
            points: sobol_reversed(shuffled),
        }
    }

    /// Coordinate `k` (0..4) of the group's point, in [0, 1).
    #[inline]
    fn coordinate(&self, k: u32) -> f32 {
        let k = (k & 3) as usize;
        let x = lk_permute(self.points[k], hash(self.seed ^ COORDINATE_SALTS[k])).reverse_bits();
        (x >> 8) as f32 * (1.0 / 16_777_216.0)
    }
}

/// Dimension `dim` of sample `index` of the pixel with seed `seed`, in [0, 1): the point of
/// group `dim / 4` at the index shuffled by an Owen scramble seeded by the pixel and the group,
/// then Owen-scrambled with a seed of its own. `dim` must be below [`SOBOL_DIMENSIONS`].
#[must_use]
pub fn sobol_sample(index: u32, dim: u32, seed: u32) -> f32 {
    Group::new(index, dim >> 2, seed).coordinate(dim & 3)
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
    /// The group of the last Sobol draw (`u32::MAX`: none yet) and what its dimensions share:
    /// a path vertex draws up to four numbers from each of its groups, and this computes the
    /// shuffle and the four points once.
    group: u32,
    cached: Group,
}

impl Draws {
    /// The draws of sample `index` of the pixel `pixel` (of the full image) with stream salt
    /// `salt`, resuming the hash stream `rng`, at the camera's dimensions.
    #[must_use]
    pub fn new(sampler: Sampler, rng: Rng, pixel: u32, index: u32, salt: u32) -> Draws {
        Draws {
            rng,
            sobol: (sampler == Sampler::Sobol).then(|| pixel_seed(pixel, salt)),
            index,
            base: 0,
            group: u32::MAX,
            cached: Group {
                seed: 0,
                points: [0; 4],
            },
        }
    }

    /// The number of dimension `base + k` in [0, 1).
    #[inline]
    pub fn get(&mut self, k: u32) -> f32 {
        let u = self.rng.uniform();
        let d = self.base.saturating_add(k);
        match self.sobol {
            Some(seed) if d < SOBOL_DIMENSIONS => {
                if d >> 2 != self.group {
                    self.group = d >> 2;
                    self.cached = Group::new(self.index, self.group, seed);
                }
                self.cached.coordinate(d)
            }
            _ => u,
        }
    }
}

/// The first eight numbers of path vertex `depth` (its first two groups of dimensions) of
/// sample `index` for the pixel with Sobol seed `seed` ([`pixel_seed`]): what
/// [`Draws::get`] returns for those dimensions with the Sobol sampler. `None` past
/// [`SOBOL_DIMENSIONS`], where the draws are hash numbers.
#[inline]
#[must_use]
pub fn vertex_numbers(index: u32, depth: u32, seed: u32) -> Option<[f32; 8]> {
    let first = dim::vertex(depth);
    if first.saturating_add(8) > SOBOL_DIMENSIONS {
        return None;
    }
    let (a, b) = (
        Group::new(index, first / 4, seed),
        Group::new(index, first / 4 + 1, seed),
    );
    Some([
        a.coordinate(0),
        a.coordinate(1),
        a.coordinate(2),
        a.coordinate(3),
        b.coordinate(0),
        b.coordinate(1),
        b.coordinate(2),
        b.coordinate(3),
    ])
}

/// [`vertex_numbers`] for `L` pixels side by side (their Sobol seeds `seeds`), at the same
/// sample `index` and vertex `depth`: entry `[k][l]` is number `k` of pixel `l`. The same
/// operations lane by lane, written as loops over the lanes so that the compiler makes vector
/// instructions of the hashes, the scrambles and the bit reversals (the wavefront's lanes).
#[inline(always)]
#[must_use]
pub fn vertex_numbers_lanes<const L: usize>(
    index: u32,
    depth: u32,
    seeds: &[u32; L],
) -> Option<[[f32; L]; 8]> {
    vertex_numbers_lanes_of(index, depth, seeds, 0xff)
}

/// [`vertex_numbers_lanes`] of the numbers whose bits are set in `needed` (bit `k`: number
/// `k`); the others are NaN. A vertex that does not draw a number (a Lambertian surface's
/// lobe, roulette before its first vertex) skips its scramble.
#[inline(always)]
#[must_use]
pub fn vertex_numbers_lanes_of<const L: usize>(
    index: u32,
    depth: u32,
    seeds: &[u32; L],
    needed: u8,
) -> Option<[[f32; L]; 8]> {
    let first = dim::vertex(depth);
    if first.saturating_add(8) > SOBOL_DIMENSIONS {
        return None;
    }
    let mut out = [[f32::NAN; L]; 8];
    let (a, b) = out.split_at_mut(4);
    group_lanes(index, first / 4, seeds, a, needed & 0xf);
    group_lanes(index, first / 4 + 1, seeds, b, needed >> 4);
    Some(out)
}

/// The pixel offset's two Sobol numbers ([`dim::PIXEL`] and the next) of sample `index` for
/// `L` pixels with Sobol seeds `seeds`: what [`Draws::get`] returns for them with the Sobol
/// sampler, `[k][l]` for dimension `k` of pixel `l`.
#[inline(always)]
#[must_use]
pub fn pixel_numbers_lanes<const L: usize>(index: u32, seeds: &[u32; L]) -> [[f32; L]; 2] {
    let mut out = [[0.0f32; L]; 2];
    group_lanes(index, dim::PIXEL / 4, seeds, &mut out, 0x3);
    out
}

/// `[f(0), f(1), ...]`: `std::array::from_fn` as a plain loop, inlined into its caller. The
/// lanes' code is compiled for the vector instruction sets the processor has, and a call to
/// `from_fn`'s own function would run its closure (the hashes) in the baseline instructions
/// (measured: 3.6 % of a Cornell sample).
#[inline(always)]
pub(crate) fn lanes_from<T: Copy + Default, const L: usize>(f: impl Fn(usize) -> T) -> [T; L] {
    let mut out = [T::default(); L];
    for (l, o) in out.iter_mut().enumerate() {
        *o = f(l);
    }
    out
}

/// The first `out.len()` (at most four) coordinates of group `g` of sample `index` for `L`
/// pixels, those whose bits are set in `needed`: [`Group::new`] and [`Group::coordinate`] as
/// loops over the lanes.
#[inline(always)]
fn group_lanes<const L: usize>(
    index: u32,
    g: u32,
    seeds: &[u32; L],
    out: &mut [[f32; L]],
    needed: u8,
) {
    let reversed = index.reverse_bits();
    let salt = GROUP_SALTS[g as usize];
    let seed: [u32; L] = lanes_from(|l| hash(seeds[l] ^ salt));
    let shuffled: [u32; L] = lanes_from(|l| lk_permute(reversed, seed[l]));
    let mut points = [[0u32; L]; 4];
    for (l, &s) in shuffled.iter().enumerate() {
        for (k, x) in sobol_reversed(s).into_iter().enumerate() {
            points[k][l] = x;
        }
    }
    for (k, out) in out.iter_mut().enumerate().take(4) {
        if needed & (1 << k) == 0 {
            continue;
        }
        for l in 0..L {
            let x = lk_permute(points[k][l], hash(seed[l] ^ COORDINATE_SALTS[k])).reverse_bits();
            out[l] = (x >> 8) as f32 * (1.0 / 16_777_216.0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sequence as first written: one dimension at a time, the Sobol point by a loop over
    /// the index's bits, both scrambles through [`owen_scramble`].
    fn reference(index: u32, dim: u32, seed: u32) -> f32 {
        let group = hash(seed ^ hash(dim >> 2));
        let shuffled = owen_scramble(index, group);
        let x = sobol(shuffled, (dim & 3) as usize);
        let x = owen_scramble(x, hash(group ^ hash((dim & 3) + 1)));
        (x >> 8) as f32 * (1.0 / 16_777_216.0)
    }

    #[test]
    fn the_tables_give_the_bits_of_the_plain_computation() {
        let mut h = 0x1234_5678u32;
        let mut indices: Vec<u32> = (0..4096).chain([u32::MAX - 1, u32::MAX]).collect();
        indices.extend((0..4096).map(|_| {
            h = hash(h);
            h
        }));
        for seed in [0u32, 1, 0xdead_beef, u32::MAX, pixel_seed(77, 0x5eed)] {
            for &index in &indices {
                for dim in 0..SOBOL_DIMENSIONS {
                    assert_eq!(
                        sobol_sample(index, dim, seed).to_bits(),
                        reference(index, dim, seed).to_bits(),
                        "index {index}, dim {dim}, seed {seed}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_vertex_computes_the_numbers_it_draws_and_only_those() {
        let seeds: [u32; 8] = std::array::from_fn(|l| hash(l as u32 + 17));
        for needed in [0u8, 0b0011_0111, 0b1011_1111, 0xff, 0x80, 0x01] {
            let all = vertex_numbers_lanes(9, 1, &seeds).unwrap();
            let some = vertex_numbers_lanes_of(9, 1, &seeds, needed).unwrap();
            for k in 0..8 {
                for l in 0..8 {
                    if needed & (1 << k) != 0 {
                        assert_eq!(some[k][l].to_bits(), all[k][l].to_bits(), "{needed:b} {k}");
                    } else {
                        assert!(some[k][l].is_nan(), "{needed:b} {k}");
                    }
                }
            }
        }
        // Past the sequence's dimensions, none.
        assert!(vertex_numbers_lanes_of(0, 5, &seeds, 0xff).is_none());
    }

    #[test]
    fn vertex_numbers_of_eight_pixels_are_each_pixels_own() {
        let mut h = 0x9e37_79b9u32;
        for depth in 0..7 {
            for index in [0u32, 1, 5, 63, 1000, u32::MAX] {
                let seeds: [u32; 8] = std::array::from_fn(|_| {
                    h = hash(h);
                    h
                });
                let lanes = vertex_numbers_lanes(index, depth, &seeds);
                for (l, &seed) in seeds.iter().enumerate() {
                    let one = vertex_numbers(index, depth, seed);
                    assert_eq!(lanes.is_some(), one.is_some(), "depth {depth}");
                    if let (Some(lanes), Some(one)) = (lanes, one) {
                        for k in 0..8 {
                            assert_eq!(
                                lanes[k][l].to_bits(),
                                one[k].to_bits(),
                                "{depth} {index} {l} {k}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn pixel_numbers_of_eight_pixels_are_those_draws_return() {
        let mut h = 0x0bad_5eedu32;
        for index in [0u32, 1, 2, 3, 17, 255, 4096, u32::MAX] {
            let seeds: [u32; 8] = std::array::from_fn(|_| {
                h = hash(h);
                h
            });
            let lanes = pixel_numbers_lanes(index, &seeds);
            for (l, &seed) in seeds.iter().enumerate() {
                for (k, numbers) in lanes.iter().enumerate() {
                    assert_eq!(
                        numbers[l].to_bits(),
                        sobol_sample(index, dim::PIXEL + k as u32, seed).to_bits(),
                        "{index} {l} {k}"
                    );
                }
            }
        }
    }

    #[test]
    fn vertex_numbers_are_those_draws_return() {
        for depth in 0..6 {
            for sample in [0u32, 3, 77] {
                let seed = pixel_seed(4321, 0x5eed);
                let got = vertex_numbers(sample, depth, seed);
                let mut d = Draws::new(Sampler::Sobol, Rng(1), 4321, sample, 0x5eed);
                d.base = dim::vertex(depth);
                let want: Vec<u32> = (0..8).map(|k| d.get(k).to_bits()).collect();
                match got {
                    Some(v) => assert_eq!(v.map(f32::to_bits).to_vec(), want),
                    None => assert!(depth >= 5),
                }
            }
        }
    }

    #[test]
    fn draws_in_any_order_give_the_numbers_of_their_dimensions() {
        // A vertex draws its groups' dimensions out of order and goes back to earlier groups;
        // the cached group must never leak into another's numbers.
        let order = [3u32, 2, 0, 1, 8, 6, 4, 5, 7, 0, 11, 9, 3, 15, 12];
        for sample in [0u32, 1, 5, 1000] {
            for vertex in 0..7 {
                let mut d = Draws::new(Sampler::Sobol, Rng(9), 123, sample, 0x5eed);
                d.base = dim::vertex(vertex);
                let mut rng = Rng(9);
                for &k in &order {
                    let hashed = rng.uniform();
                    let dim = d.base + k;
                    let want = if dim < SOBOL_DIMENSIONS {
                        reference(sample, dim, pixel_seed(123, 0x5eed))
                    } else {
                        hashed
                    };
                    assert_eq!(d.get(k).to_bits(), want.to_bits(), "vertex {vertex}, k {k}");
                }
            }
        }
    }
}
