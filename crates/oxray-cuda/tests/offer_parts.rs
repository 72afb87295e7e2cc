//! The all-hits passes in parts (`OXRAY_CUDA_OFFER_BUDGET`): a budget of a few offers traces a
//! batch in many parts, one ray alone where it has more offers than the budget, and must list
//! what one part lists. Its own test binary, as it sets the variable for the whole process.
//! Runs where a CUDA device exists; elsewhere it prints why it skips (`OXRAY_REQUIRE_GPU=1`
//! makes a missing GPU a failure).

mod common;

use common::{build_gas_with_tree, icosphere_f32};
use oxray_core::{AllHits, BuildFlags, Ray};
use oxray_cuda::{CudaContext, CudaGas};
use oxray_testkit::rays::rays_around;
use oxray_testkit::rng::Rng;

#[test]
fn lists_traced_in_parts_are_the_lists_of_one_part() {
    let ctx = match CudaContext::new() {
        Ok(ctx) => ctx,
        Err(e) if e.is_unavailable() && std::env::var_os("OXRAY_REQUIRE_GPU").is_none() => {
            println!("skipping: {e}");
            return;
        }
        Err(e) => panic!("CUDA is present but unusable: {e}"),
    };
    let mesh = icosphere_f32(4);
    // Spatial splits: repeated offers, so that counting goes through the lists too.
    let (cpu, tree) = build_gas_with_tree(&mesh, BuildFlags::PREFER_FAST_TRACE).unwrap();
    let gpu = CudaGas::upload(&ctx, cpu.data(), &tree).unwrap();
    let mut rng = Rng::new(21);
    let rays: Vec<Ray> = rays_around(&mut rng, &mesh, 3000);
    let run = |budget: Option<&str>| {
        match budget {
            Some(b) => std::env::set_var("OXRAY_CUDA_OFFER_BUDGET", b),
            None => std::env::remove_var("OXRAY_CUDA_OFFER_BUDGET"),
        }
        let mut lists = AllHits::new();
        gpu.all_hits_batch(&rays, usize::MAX, &mut lists).unwrap();
        let mut counts = vec![0u32; rays.len()];
        gpu.count_hits_batch(&rays, &mut counts).unwrap();
        (lists, counts)
    };
    let whole = run(None);
    let mut cpu_lists = AllHits::new();
    cpu.all_hits_batch(&rays, usize::MAX, &mut cpu_lists)
        .unwrap();
    assert_eq!(whole.0, cpu_lists, "the CPU's lists");
    assert!(whole.0.all().len() > 1000, "enough offers for many parts");
    for budget in ["1", "3", "64"] {
        assert_eq!(run(Some(budget)), whole, "budget {budget}");
    }
}
