//! Helpers shared by the integration tests: the brute-force reference for ray queries, the
//! deterministic random-number generator, the mesh generators (icosphere, subdivided cube), the
//! tiny OBJ reader and the Stanford bunny come from `oxray-testkit`; the proptest configuration
//! stays here.
//!
//! The devices of this machine and a runner that checks that every device gives the same
//! result are here too.
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

use oxray::{BackendKind, Device};

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

/// The devices to run on: the CPU, and CUDA device 0 if there is one (`OXRAY_REQUIRE_GPU=1`
/// makes a missing GPU a failure).
pub fn devices() -> Vec<Device> {
    let mut d = vec![Device::cpu()];
    match Device::cuda(0) {
        Ok(c) => d.push(c),
        Err(e) => {
            assert!(
                std::env::var_os("OXRAY_REQUIRE_GPU").is_none(),
                "OXRAY_REQUIRE_GPU is set but there is no CUDA device: {e}"
            );
            assert!(e.is_unavailable(), "CUDA is there but failed: {e}");
            println!("the CUDA half skips: {e}");
        }
    }
    d
}

/// The device's name in failure messages.
pub fn name(d: &Device) -> &'static str {
    match d.kind() {
        BackendKind::Cuda => "cuda",
        _ => "cpu",
    }
}

/// Runs `scenario` on every device and checks that all give the same result.
pub fn on_every_device<R: PartialEq + std::fmt::Debug>(scenario: impl Fn(&Device) -> R) {
    let results: Vec<(&str, R)> = devices().iter().map(|d| (name(d), scenario(d))).collect();
    for (n, r) in &results[1..] {
        if r != &results[0].1 {
            // Name the first difference rather than print two long results whole.
            let (a, b) = (format!("{r:?}"), format!("{:?}", results[0].1));
            let at = a.bytes().zip(b.bytes()).take_while(|(x, y)| x == y).count();
            let from = at.saturating_sub(200);
            let part = |s: &str| {
                s.get(from..(at + 200).min(s.len()))
                    .unwrap_or("")
                    .to_string()
            };
            panic!(
                "{n} and {} differ on the same scenario, at character {at}:\n  {n}: …{}…\n  {}: …{}…",
                results[0].0,
                part(&a),
                results[0].0,
                part(&b)
            );
        }
    }
}
