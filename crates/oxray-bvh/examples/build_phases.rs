//! Where a GAS build spends its time: the whole `GasData::build` of each preset, and the binary
//! build and the wide collapses alone (the rest is decoding, validation and packing).
//!
//! ```sh
//! cargo run --release -p oxray-bvh --example build_phases -- [--threads T] [--runs R] \
//!     [--subdivide K] [--preset default|fast-build|fast-trace] MESH.obj...
//! ```

use oxray_bvh::{build_bvh2, BuildConfig, Bvh4, Bvh8, GasData, NodeWidth};
use oxray_core::{Aabb, BuildFlags, BuildOptions, IndexBuffer, TriangleInput, VertexBuffer};
use oxray_testkit::mesh::{load_obj, Mesh};
use std::time::Instant;

fn median(mut xs: Vec<f64>) -> f64 {
    xs.sort_by(f64::total_cmp);
    xs[xs.len() / 2]
}

/// Splits every triangle into four, `levels` times (unshared midpoints: only the count matters).
fn subdivided(m: &Mesh, levels: u32) -> Mesh {
    let mut tris: Vec<[[f32; 3]; 3]> = m.soup();
    for _ in 0..levels {
        let mid = |a: [f32; 3], b: [f32; 3]| std::array::from_fn(|i| 0.5 * (a[i] + b[i]));
        tris = tris
            .iter()
            .flat_map(|&[a, b, c]| {
                let (ab, bc, ca) = (mid(a, b), mid(b, c), mid(c, a));
                [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]
            })
            .collect();
    }
    Mesh {
        positions: tris.iter().flatten().copied().collect(),
        triangles: (0..tris.len() as u32)
            .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect(),
    }
}

fn main() {
    let mut threads = 0;
    let mut runs = 5;
    let mut levels = 0;
    let mut only: Option<String> = None;
    let mut paths = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut num = || args.next().and_then(|v| v.parse().ok()).expect("a number");
        match a.as_str() {
            "--threads" => threads = num(),
            "--runs" => runs = num(),
            "--subdivide" => levels = num() as u32,
            "--preset" => only = args.next(),
            _ => paths.push(a),
        }
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("a thread pool");
    pool.install(|| {
        for path in &paths {
            let mut m = load_obj(path.as_ref()).expect("a readable OBJ file");
            if levels > 0 {
                m = subdivided(&m, levels);
            }
            let input = TriangleInput::new(VertexBuffer::f32x3(&m.positions))
                .indices(IndexBuffer::u32x3(&m.triangles));
            let bounds: Vec<Aabb> = m
                .soup()
                .iter()
                .map(|t| Aabb::from_points(&t.map(Into::into)))
                .collect();
            println!("{path}: {} triangles, {} threads", m.triangles.len(), rayon::current_num_threads());
            for (name, flags, config) in [
                ("default", BuildFlags::empty(), BuildConfig::BALANCED),
                ("fast-build", BuildFlags::PREFER_FAST_BUILD, BuildConfig::FAST_BUILD),
                ("fast-trace", BuildFlags::PREFER_FAST_TRACE, BuildConfig::FAST_TRACE),
            ] {
                if only.as_deref().is_some_and(|o| o != name) {
                    continue;
                }
                let time = |f: &mut dyn FnMut()| {
                    median(
                        (0..runs)
                            .map(|_| {
                                let t = Instant::now();
                                f();
                                t.elapsed().as_secs_f64() * 1e3
                            })
                            .collect(),
                    )
                };
                let options = BuildOptions::new(flags);
                let build = || {
                    GasData::build_with_width(&options, &[input.into()], NodeWidth::Eight)
                        .expect("a valid input")
                };
                let sah = build().stats().sah_cost;
                let gas_ms = time(&mut || {
                    std::hint::black_box(build());
                });
                let bvh2 = build_bvh2(&bounds, &config);
                let bvh2_ms = time(&mut || {
                    std::hint::black_box(build_bvh2(&bounds, &config));
                });
                let b4_ms = time(&mut || {
                    std::hint::black_box(Bvh4::from(&bvh2));
                });
                let b8_ms = time(&mut || {
                    std::hint::black_box(Bvh8::from(&bvh2));
                });
                println!(
                    "  {name:<11} GasData::build (8-wide) {gas_ms:8.2} ms | build_bvh2 {bvh2_ms:8.2} | Bvh4 {b4_ms:6.2} | Bvh8 {b8_ms:6.2} | rest {:6.2} | SAH {sah:.3}",
                    gas_ms - bvh2_ms - b4_ms - b8_ms
                );
            }
        }
    });
}
