//! Animated geometry refit every frame (the counterpart of the OptiX SDK's
//! `optixDynamicGeometry`), and the life of an acceleration structure around it: build for
//! update and compaction (guide §5.5), update the GAS and the IAS over it every frame (§5.6),
//! compact (§5.8), save and load back. It prints what each step costs, against a rebuild: the
//! numbers of docs/BENCHMARKS.md.
//!
//! `cargo run --release -p oxray --example dynamic_geometry [mesh.obj] [frames] [--device NAME]`
//! (default: the Stanford bunny from `../shared/data/meshes`, else an icosphere; 8 frames; the
//! CPU, or `cuda`, `cuda:N`, `auto`: the same code refits on the GPU)

use glam::Vec3;
use oxray::{
    AccelProperty, BuildFlags, BuildOperation, BuildOptions, Device, EmittedProperty, IndexBuffer,
    Instance, Ray, Transform, TriangleInput, VertexBuffer,
};
use oxray_testkit::mesh::{icosphere, load_bunny, load_obj, Mesh};
use oxray_testkit::rays::camera_rays;
use std::time::Instant;

fn input(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> oxray::BuildInput<'static> {
    // The example keeps its buffers alive for the whole run; leaking them keeps it short.
    let p: &'static [[f32; 3]] = Box::leak(positions.to_vec().into_boxed_slice());
    let t: &'static [[u32; 3]] = Box::leak(triangles.to_vec().into_boxed_slice());
    TriangleInput::new(VertexBuffer::f32x3(p))
        .indices(IndexBuffer::u32x3(t))
        .into()
}

/// The median of `runs` timings of `f`, in milliseconds.
fn time_ms(runs: usize, mut f: impl FnMut()) -> f64 {
    let mut ts: Vec<f64> = (0..runs)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    ts.sort_by(f64::total_cmp);
    ts[ts.len() / 2]
}

/// Frame `f` of the animation: a travelling wave whose amplitude grows with the frame, as a
/// fraction of the mesh's size.
fn animate(base: &[[f32; 3]], size: f32, frame: u32) -> Vec<[f32; 3]> {
    let amp = 0.02 * size * frame as f32;
    let k = 12.0 / size;
    base.iter()
        .map(|&p| {
            let p = Vec3::from(p);
            let phase = frame as f32 * 0.7;
            let d = Vec3::new(
                (k * p.y + phase).sin(),
                (k * p.z + 1.3 * phase).sin(),
                (k * p.x + 0.4 * phase).cos(),
            );
            (p + d * amp).to_array()
        })
        .collect()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args: Vec<String> = std::env::args().collect();
    let device = match args.iter().position(|a| a == "--device") {
        Some(i) if i + 1 < args.len() => {
            let name = args.remove(i + 1);
            args.remove(i);
            Device::from_name(&name)?
        }
        _ => Device::cpu(),
    };
    let (name, mesh): (String, Mesh) = match args.get(1) {
        Some(path) => (path.clone(), load_obj(path.as_ref())?),
        None => match load_bunny("dynamic_geometry") {
            Some(m) => ("stanford-bunny".into(), m),
            None => ("icosphere(6)".into(), icosphere(6)),
        },
    };
    let frames: u32 = args.get(2).and_then(|f| f.parse().ok()).unwrap_or(8);
    let n = mesh.triangles.len();
    let (lo, hi) = mesh.bounds();
    let size = (Vec3::from(hi) - Vec3::from(lo)).max_element();
    println!("{name}: {n} triangles on {}", device.describe());

    let flags =
        BuildFlags::ALLOW_UPDATE | BuildFlags::ALLOW_COMPACTION | BuildFlags::PREFER_FAST_TRACE;
    let build = BuildOptions::new(flags);
    let update = BuildOptions {
        operation: BuildOperation::Update,
        ..build
    };
    let base = input(&mesh.positions, &mesh.triangles);
    let mut gas = device.build_gas(&build, &[base])?;
    // As built, an ALLOW_COMPACTION structure occupies the memory query's output bound (a copy
    // made by a copy-on-write update is exactly sized, as a compacted one).
    let built = gas.memory().output_bytes;
    let build_ms = time_ms(5, || {
        device.build_gas(&build, &[base]).unwrap();
    });
    let plain = BuildOptions::new(BuildFlags::PREFER_FAST_TRACE);
    let plain_ms = time_ms(5, || {
        device.build_gas(&plain, &[base]).unwrap();
    });
    let fast = BuildOptions::new(BuildFlags::PREFER_FAST_BUILD);
    let fast_ms = time_ms(5, || {
        device.build_gas(&fast, &[base]).unwrap();
    });
    println!("build (ALLOW_UPDATE | ALLOW_COMPACTION | PREFER_FAST_TRACE): {build_ms:.2} ms; without the two flags: {plain_ms:.2} ms; PREFER_FAST_BUILD: {fast_ms:.2} ms");
    // The SAH cost is computed from the tree a structure holds on the host: the CPU's. A GPU
    // structure reports its build's, so the refit columns are the CPU's alone.
    let sah = device.kind() == oxray::BackendKind::Cpu;

    // An IAS of a few placements, updated after the GAS every frame.
    let placements: Vec<Transform> = (0..4)
        .map(|i| Transform::from_translation(Vec3::new(i as f32 * 1.5 * size, 0.0, 0.0)))
        .collect();
    let instances = |gas: &oxray::Gas| -> Vec<Instance> {
        placements
            .iter()
            .map(|t| Instance::new(gas.handle()).transform(*t))
            .collect()
    };
    let list = instances(&gas);
    let mut ias = device.build_ias(
        &BuildOptions::new(BuildFlags::ALLOW_UPDATE),
        &[(&list[..]).into()],
    )?;
    let ias_update = BuildOptions {
        operation: BuildOperation::Update,
        ..BuildOptions::new(BuildFlags::ALLOW_UPDATE)
    };

    let rays: Vec<Ray> = camera_rays(&mesh.positions, 256, 256);
    println!("frame | refit ms | rebuild ms | rebuild/refit | SAH refit | SAH rebuild | growth | IAS update ms | hits equal");
    for frame in 1..=frames {
        let moved = animate(&mesh.positions, size, frame);
        let inp = input(&moved, &mesh.triangles);
        // The refit, timed on unshared copies of the structure as it was before this frame
        // (a clone shares it: its first update copies it, outside the timing).
        let before = gas.clone();
        let mut times: Vec<f64> = (0..5)
            .map(|_| {
                let mut g = before.clone();
                device.update_gas(&mut g, &update, &[base]).unwrap();
                let t = Instant::now();
                device.update_gas(&mut g, &update, &[inp]).unwrap();
                t.elapsed().as_secs_f64() * 1e3
            })
            .collect();
        times.sort_by(f64::total_cmp);
        let refit_ms = times[2];
        // In place: `gas` is shared by the IAS, so this update copies once, then the IAS update
        // moves to the new structure and drops its hold on the old one.
        device.update_gas(&mut gas, &update, &[inp])?;
        let list = instances(&gas);
        let t = Instant::now();
        device.update_ias(&mut ias, &ias_update, &[(&list[..]).into()])?;
        let ias_ms = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let rebuilt = device.build_gas(&build, &[inp])?;
        let rebuild_ms = t.elapsed().as_secs_f64() * 1e3;
        let (a, b) = if sah {
            (gas.stats().sah_cost, rebuilt.stats().sah_cost)
        } else {
            (f64::NAN, f64::NAN)
        };
        let mut h1 = vec![None; rays.len()];
        let mut h2 = vec![None; rays.len()];
        device.intersect_closest(&gas.handle(), &rays, &mut h1)?;
        device.intersect_closest(&rebuilt.handle(), &rays, &mut h2)?;
        let same_t = h1
            .iter()
            .zip(&h2)
            .all(|(x, y)| x.map(|h| h.t.to_bits()) == y.map(|h| h.t.to_bits()));
        println!(
            "{frame} | {refit_ms:.2} | {rebuild_ms:.2} | {:.1}x | {a:.2} | {b:.2} | {:+.1}% | {ias_ms:.3} | {same_t}",
            rebuild_ms / refit_ms,
            100.0 * (a / b - 1.0)
        );
    }

    // Compaction (§5.8).
    let EmittedProperty::CompactedSize(compacted) =
        gas.emit_property(AccelProperty::CompactedSize)?
    else {
        unreachable!("asked for the compacted size")
    };
    let t = Instant::now();
    let compact = device.compact_gas(&gas)?;
    let compact_ms = t.elapsed().as_secs_f64() * 1e3;
    println!(
        "memory: {built} bytes as built ({:.1} B/triangle), {compacted} compacted ({:.1} B/triangle), compaction {compact_ms:.2} ms",
        built as f64 / n as f64,
        compacted as f64 / n as f64
    );

    // Save and load (§5.7 and beyond).
    let t = Instant::now();
    let bytes = compact.to_bytes()?;
    let save_ms = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let loaded = device.load_gas(&bytes)?;
    let load_ms = t.elapsed().as_secs_f64() * 1e3;
    let mut h1 = vec![None; rays.len()];
    let mut h2 = vec![None; rays.len()];
    device.intersect_closest(&compact.handle(), &rays, &mut h1)?;
    device.intersect_closest(&loaded.handle(), &rays, &mut h2)?;
    println!(
        "saved: {} bytes ({:.1} B/triangle) in {save_ms:.2} ms, loaded and checked in {load_ms:.2} ms, hits identical: {}",
        bytes.len(),
        bytes.len() as f64 / n as f64,
        h1 == h2
    );
    Ok(())
}
