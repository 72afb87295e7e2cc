//! The SIMD kernels of the CPU backend, chosen at run time from what the processor has.
//!
//! Every kernel finds the same hits: the box test is the same conservative slab test in every
//! width (so no box that holds a hit is ever skipped), and leaves are the same [`Triangle4`]
//! blocks under the same watertight test, so t, u, v and facing are bit-identical whatever the
//! kernel. Only which of two primitives hit at exactly the same distance is reported may differ
//! between kernels (children are visited in another order); for one kernel it never depends on
//! the number of threads.
//!
//! [`Triangle4`]: oxray_bvh::Triangle4

use oxray_bvh::NodeWidth;
use std::sync::OnceLock;

/// A traversal kernel: a node layout and the instruction set that tests it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Isa {
    /// 8-wide nodes tested lane by lane with portable code: the reference for the SIMD 8-wide
    /// kernels, on every processor.
    Scalar,
    /// 4-wide nodes ([`oxray_bvh::Bvh4`]) tested with SSE on x86-64, with the portable 4-wide
    /// code elsewhere (NEON through the compiler's vectorisation on AArch64).
    Sse,
    /// 8-wide nodes ([`oxray_bvh::Bvh8`]) tested with AVX2 (x86-64).
    Avx2,
    /// 8-wide nodes tested with AVX-512 (F and VL: mask registers for the compares; x86-64).
    Avx512,
    /// Quantised 8-wide nodes ([`oxray_bvh::QBvh8`]: 128 bytes instead of 256) tested with
    /// AVX2 (x86-64). A structure whose boxes cannot be quantised is traversed by
    /// [`Isa::Avx2`].
    Avx2Quantized,
    /// Quantised 8-wide nodes tested with AVX-512 (x86-64); falls back to [`Isa::Avx512`] as
    /// [`Isa::Avx2Quantized`] does to [`Isa::Avx2`].
    Avx512Quantized,
}

/// The environment variable that forces a kernel: `scalar`, `sse` (or `neon`), `avx2`,
/// `avx512`, `avx2q`, `avx512q`; clamped to what the processor has (see [`Isa::clamp`]).
pub const ISA_ENV: &str = "OXRAY_CPU_ISA";

impl Isa {
    /// Every kernel, from the narrowest.
    pub const ALL: [Isa; 6] = [
        Isa::Scalar,
        Isa::Sse,
        Isa::Avx2,
        Isa::Avx512,
        Isa::Avx2Quantized,
        Isa::Avx512Quantized,
    ];

    /// The kernel's name, as [`ISA_ENV`] takes it.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Isa::Scalar => "scalar",
            Isa::Sse if cfg!(target_arch = "aarch64") => "neon",
            Isa::Sse => "sse",
            Isa::Avx2 => "avx2",
            Isa::Avx512 => "avx512",
            Isa::Avx2Quantized => "avx2q",
            Isa::Avx512Quantized => "avx512q",
        }
    }

    /// The kernel of a name (`scalar`, `sse`, `neon`, `avx2`, `avx512`, `avx2q`, `avx512q`, any
    /// case).
    #[must_use]
    pub fn from_name(name: &str) -> Option<Isa> {
        match name.trim().to_ascii_lowercase().as_str() {
            "scalar" => Some(Isa::Scalar),
            "sse" | "sse2" | "neon" | "4" => Some(Isa::Sse),
            "avx2" => Some(Isa::Avx2),
            "avx512" | "avx-512" => Some(Isa::Avx512),
            "avx2q" => Some(Isa::Avx2Quantized),
            "avx512q" | "avx-512q" => Some(Isa::Avx512Quantized),
            _ => None,
        }
    }

    /// Whether this processor runs the kernel.
    #[must_use]
    pub fn is_available(self) -> bool {
        match self {
            Isa::Scalar | Isa::Sse => true,
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 | Isa::Avx2Quantized => avx2_detected(),
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 | Isa::Avx512Quantized => avx2_detected() && avx512_detected(),
            #[cfg(not(target_arch = "x86_64"))]
            Isa::Avx2 | Isa::Avx512 | Isa::Avx2Quantized | Isa::Avx512Quantized => false,
        }
    }

    /// The kernels this processor runs, from the narrowest.
    #[must_use]
    pub fn available() -> Vec<Isa> {
        Isa::ALL.into_iter().filter(|i| i.is_available()).collect()
    }

    /// The fastest kernel this processor runs: AVX-512, else AVX2 (both 8-wide; AVX-512's mask
    /// compares and 32 registers measured 4-12 % faster on the bunny), else the 4-wide SSE/NEON
    /// kernel.
    #[must_use]
    pub fn detect() -> Isa {
        [Isa::Avx512, Isa::Avx2]
            .into_iter()
            .find(|i| i.is_available())
            .unwrap_or(Isa::Sse)
    }

    /// The kernel itself if the processor runs it, else the best one below it that it runs
    /// (AVX-512 → AVX2 → SSE, and the quantised kernels likewise: AVX-512 → AVX2 → SSE; the
    /// scalar kernel runs everywhere).
    #[must_use]
    pub fn clamp(self) -> Isa {
        match self {
            i if i.is_available() => i,
            Isa::Avx512 => Isa::Avx2.clamp(),
            Isa::Avx512Quantized => Isa::Avx2Quantized.clamp(),
            _ => Isa::Sse,
        }
    }

    /// Whether the kernel walks the quantised layout.
    #[must_use]
    pub fn is_quantized(self) -> bool {
        matches!(self, Isa::Avx2Quantized | Isa::Avx512Quantized)
    }

    /// The kernel of the same instruction set over the float 8-wide layout (itself for the
    /// others): what a structure whose boxes cannot be quantised is traversed by.
    #[must_use]
    pub fn unquantized(self) -> Isa {
        match self {
            Isa::Avx2Quantized => Isa::Avx2,
            Isa::Avx512Quantized => Isa::Avx512,
            other => other,
        }
    }

    /// The kernel of this process, chosen once: [`ISA_ENV`] if set to a known name (clamped to
    /// what the processor has), else [`Isa::detect`].
    pub fn selected() -> Isa {
        static SELECTED: OnceLock<Isa> = OnceLock::new();
        *SELECTED.get_or_init(
            || match std::env::var(ISA_ENV).ok().as_deref().map(Isa::from_name) {
                Some(Some(isa)) => isa.clamp(),
                _ => Isa::detect(),
            },
        )
    }

    /// The node layouts a structure needs for this kernel.
    #[must_use]
    pub fn width(self) -> NodeWidth {
        match self {
            Isa::Sse => NodeWidth::Four,
            Isa::Scalar | Isa::Avx2 | Isa::Avx512 | Isa::Avx2Quantized | Isa::Avx512Quantized => {
                NodeWidth::Eight
            }
        }
    }
}

impl std::fmt::Display for Isa {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The features the AVX2 kernel is compiled with (see `traversal::node::avx2`).
#[cfg(target_arch = "x86_64")]
pub(crate) fn avx2_detected() -> bool {
    std::arch::is_x86_feature_detected!("avx2")
        && std::arch::is_x86_feature_detected!("bmi1")
        && std::arch::is_x86_feature_detected!("bmi2")
        && std::arch::is_x86_feature_detected!("lzcnt")
        && std::arch::is_x86_feature_detected!("popcnt")
}

/// The further features of the AVX-512 kernel.
#[cfg(target_arch = "x86_64")]
pub(crate) fn avx512_detected() -> bool {
    std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512vl")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_clamping_stays_available() {
        for isa in Isa::ALL {
            assert_eq!(Isa::from_name(isa.name()), Some(isa));
            assert!(isa.clamp().is_available());
            if isa.is_available() {
                assert_eq!(isa.clamp(), isa);
            }
        }
        assert_eq!(Isa::from_name("AVX2"), Some(Isa::Avx2));
        assert_eq!(Isa::from_name("mmx"), None);
        assert!(Isa::available().contains(&Isa::Scalar));
        assert!(Isa::available().contains(&Isa::Sse));
        assert!(Isa::selected().is_available());
        assert!(Isa::detect().is_available());
    }
}
