//! Helpers shared by the integration tests: the brute-force reference for ray queries, the
//! deterministic random-number generator, the mesh generators (icosphere, subdivided cube), the
//! tiny OBJ reader and the Stanford bunny come from `oxray-testkit`; the proptest configuration
//! stays here.
//!
//! Each test binary uses a different subset of these helpers.
#![allow(dead_code, unused_imports)]

pub use oxray_testkit::mesh::{
    bunny_path, grid_cube, icosphere, load_bunny, parse_obj, random_soup, Mesh, Tri,
};
pub use oxray_testkit::oracle::{
    check_closest, closest_of, hit_bits, reference_closest, reference_hits, HitBits, RefHit,
};
pub use oxray_testkit::Rng;

/// A proptest configuration with a fixed seed, so that every run checks the same cases and a
/// failure reproduces, and no regression files are written. `OXRAY_PROPTEST_SEED=<u64>` explores
/// other cases.
pub fn proptest_config(cases: u32) -> proptest::test_runner::Config {
    let seed = std::env::var("OXRAY_PROPTEST_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0x6f78_7261_7939);
    proptest::test_runner::Config {
        cases,
        rng_seed: proptest::test_runner::RngSeed::Fixed(seed),
        failure_persistence: None,
        max_shrink_iters: 2048,
        ..Default::default()
    }
}

/// The CPU traversal kernels this processor runs: the oracle tests run on each. The kernels it
/// lacks are named once, as skipped.
pub fn kernels() -> Vec<oxray::cpu::Isa> {
    static SKIPPED: std::sync::Once = std::sync::Once::new();
    SKIPPED.call_once(|| {
        for isa in oxray::cpu::Isa::ALL {
            if !isa.is_available() {
                eprintln!("skipping the {isa} traversal kernel: this processor lacks it");
            }
        }
    });
    oxray::cpu::Isa::available()
}
