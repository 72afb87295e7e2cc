// Each example declares `mod common;`, so the helper module is included once per example.
#![allow(clippy::duplicate_mod)]

//! Runs every example, writes its PNG, and checks the image: analytic statistics, a golden image
//! (with a tolerance), and bit-identical output with one and four threads.

#[path = "../examples/custom_sphere.rs"]
mod custom_sphere;
#[path = "../examples/cutouts.rs"]
mod cutouts;
#[path = "../examples/hair.rs"]
mod hair;
#[path = "../examples/hello.rs"]
mod hello;
#[path = "../examples/instancing.rs"]
mod instancing;
#[path = "../examples/motion_geometry.rs"]
mod motion_geometry;
#[path = "../examples/simple_motion_blur.rs"]
mod simple_motion_blur;
#[path = "../examples/triangle.rs"]
mod triangle;
#[path = "../examples/triangle_cpp.rs"]
mod triangle_cpp;

use std::path::PathBuf;

type Render = fn(u32, u32) -> Result<Vec<[u8; 4]>, Box<dyn std::error::Error>>;

const W: u32 = 128;
const H: u32 = 96;

fn golden_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/golden")
        .join(format!("{name}.png"))
}

fn read_png(path: &std::path::Path) -> (u32, u32, Vec<[u8; 4]>) {
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgba);
    let px = buf[..info.buffer_size()]
        .chunks_exact(4)
        .map(|c| [c[0], c[1], c[2], c[3]])
        .collect();
    (info.width, info.height, px)
}

/// Renders with 1 and 4 threads (must agree bit for bit), writes the PNG next to the build
/// output, compares with the golden image (at most 0.5% of pixels may differ, by at most 8 per
/// channel; set OXRAY_UPDATE_GOLDEN=1 to rewrite it) and returns the pixels.
fn run(name: &str, render: Render) -> Vec<[u8; 4]> {
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let four = rayon::ThreadPoolBuilder::new()
        .num_threads(4)
        .build()
        .unwrap();
    // Errors are turned into strings inside the pools: `Box<dyn Error>` is not `Send`.
    let a = one
        .install(|| render(W, H).map_err(|e| e.to_string()))
        .unwrap();
    let b = four
        .install(|| render(W, H).map_err(|e| e.to_string()))
        .unwrap();
    assert_eq!(a, b, "{name}: output differs between 1 and 4 threads");
    assert_eq!(a.len(), (W * H) as usize);

    let out = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../target/test-examples")
        .join(format!("{name}.png"));
    std::fs::create_dir_all(out.parent().unwrap()).unwrap();
    let file = std::io::BufWriter::new(std::fs::File::create(&out).unwrap());
    let mut enc = png::Encoder::new(file, W, H);
    enc.set_color(png::ColorType::Rgba);
    enc.set_depth(png::BitDepth::Eight);
    enc.write_header()
        .unwrap()
        .write_image_data(bytemuck::cast_slice(&a))
        .unwrap();
    let (w, h, written) = read_png(&out);
    assert_eq!((w, h), (W, H));
    assert_eq!(
        written, a,
        "{name}: the PNG does not hold the rendered pixels"
    );

    let golden = golden_path(name);
    if std::env::var_os("OXRAY_UPDATE_GOLDEN").is_some() {
        std::fs::copy(&out, &golden).unwrap();
    }
    let (gw, gh, g) = read_png(&golden);
    assert_eq!((gw, gh), (W, H), "{name}: golden image size");
    let differing = a
        .iter()
        .zip(&g)
        .filter(|(p, q)| p.iter().zip(q.iter()).any(|(x, y)| x.abs_diff(*y) > 8))
        .count();
    assert!(
        differing * 200 <= a.len(),
        "{name}: {differing} of {} pixels differ from {}",
        a.len(),
        golden.display()
    );
    a
}

fn at(px: &[[u8; 4]], x: u32, y: u32) -> [u8; 4] {
    px[(y * W + x) as usize]
}

#[test]
fn hello_fills_every_pixel_with_the_raygen_record_colour() {
    let px = run("hello", |w, h| hello::render(w, h, [0.462, 0.725, 0.0]));
    assert!(px.iter().all(|&p| p == [118, 185, 0, 255]));
}

#[test]
fn triangle_covers_its_projected_area_with_barycentric_colours() {
    let px = run("triangle", triangle::render);
    let bg = [77, 26, 51, 255];
    assert_eq!(at(&px, 0, 0), bg);
    assert_eq!(at(&px, W - 1, H - 1), bg);
    // The triangle (base 1, height 1 at distance 2, field of view 1 x 1 at distance 1)
    // covers 1/2 * (1/2)^2 / (aspect * 1) of the image... computed exactly:
    let covered = px.iter().filter(|&&p| p != bg).count() as f64;
    let expected = 0.5 * 0.5 * 0.5 / ((W as f64 / H as f64) * 1.0) * (W * H) as f64 / 1.0;
    assert!(
        (covered / expected - 1.0).abs() < 0.05,
        "covered {covered}, expected {expected}"
    );
    // Near each corner the colour is dominated by that vertex's channel.
    let centre = at(&px, W / 2, H / 2);
    assert!(
        centre[0] > 40 && centre[1] > 40 && centre[2] > 40,
        "{centre:?}"
    );
}

#[test]
fn custom_sphere_is_a_disc_shaded_by_its_normals() {
    let px = run("custom_sphere", custom_sphere::render);
    let bg = [26, 26, 26, 255];
    assert_eq!(at(&px, 0, 0), bg);
    // Seen from distance 5, a sphere of radius 1.5 subtends asin(1.5 / 5); the image plane is at
    // distance 2.5 with half-height 1.
    let r_img = 2.5 * (1.5f64 / 5.0).asin().tan() * (H as f64 / 2.0);
    let expected = std::f64::consts::PI * r_img * r_img;
    let covered = px.iter().filter(|&&p| p != bg).count() as f64;
    assert!(
        (covered / expected - 1.0).abs() < 0.05,
        "covered {covered}, expected {expected}"
    );
    // At the centre the normal faces the camera (-z): blue channel 0, red and green 0.5.
    let c = at(&px, W / 2, H / 2);
    assert!(
        c[2] < 10 && (c[0] as i32 - 128).abs() < 12 && (c[1] as i32 - 128).abs() < 12,
        "{c:?}"
    );
}

/// Guide §9.3: the strands cover part of the image around the scalp in their brown, shaded
/// from their normals and tangents (not one flat colour), and the background shows around.
#[test]
fn hair_shows_shaded_strands_around_the_scalp() {
    let px = run("hair", hair::render);
    // Hair is brown (red over green over blue); the background is grey-blue, the scalp pink.
    let hair: Vec<&[u8; 4]> = px
        .iter()
        .filter(|p| p[0] > p[1] + 4 && p[1] > p[2] + 4 && p[0] < 200)
        .collect();
    let share = hair.len() as f64 / px.len() as f64;
    assert!((0.1..0.7).contains(&share), "hair covers {share}");
    let mut shades: Vec<u8> = hair.iter().map(|p| p[0]).collect();
    shades.sort_unstable();
    shades.dedup();
    assert!(shades.len() > 20, "{} shades of hair", shades.len());
    assert!(
        at(&px, 0, 0)[2] > at(&px, 0, 0)[0],
        "background in the corner"
    );
}

#[test]
fn cutouts_show_the_back_quad_through_the_any_hit_holes() {
    let px = run("cutouts", cutouts::render);
    let front = [230, 128, 26, 255];
    let back = [26, 77, 230, 255];
    // Pixel of the centre of checker cell (i, j) of the front quad: the quad spans [-1, 1] at
    // distance 4, the image plane is at distance 2 with half-height 1.
    let pixel = |c: f32| c / 4.0 * 2.0;
    for i in 0..cutouts::CELLS as i32 {
        for j in 0..cutouts::CELLS as i32 {
            let cx = -1.0 + (i as f32 + 0.5) * 2.0 / cutouts::CELLS;
            let cy = -1.0 + (j as f32 + 0.5) * 2.0 / cutouts::CELLS;
            let sx = pixel(cx) / (W as f32 / H as f32);
            let x = ((sx + 1.0) * 0.5 * W as f32) as u32;
            let y = ((1.0 - pixel(cy)) * 0.5 * H as f32) as u32;
            let want = if (i + j) % 2 == 0 { front } else { back };
            assert_eq!(at(&px, x, y), want, "cell ({i}, {j}) at pixel ({x}, {y})");
        }
    }
}

#[test]
fn instancing_shows_every_instance_in_its_own_record_colour() {
    // No golden image: the mesh is the bunny when ../shared/data is present, else a sphere.
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let four = rayon::ThreadPoolBuilder::new()
        .num_threads(4)
        .build()
        .unwrap();
    let a = one
        .install(|| instancing::render(W * 2, H * 2).map_err(|e| e.to_string()))
        .unwrap();
    let b = four
        .install(|| instancing::render(W * 2, H * 2).map_err(|e| e.to_string()))
        .unwrap();
    assert_eq!(a, b, "output differs between 1 and 4 threads");
    // Each instance's colour (record i) is hue i; classify lit pixels by their hue.
    let n = instancing::GRID * instancing::GRID;
    let mut counts = vec![0usize; n];
    for p in &a {
        let c = [p[0] as f32, p[1] as f32, p[2] as f32];
        let max = c.iter().cloned().fold(0.0, f32::max);
        if max < 60.0 {
            continue; // background or deep shadow
        }
        let best = (0..n)
            .min_by(|&i, &j| {
                let d = |k: usize| {
                    let hue = k as f32 / n as f32 * std::f32::consts::TAU;
                    let want = [
                        0.55 + 0.45 * hue.cos(),
                        0.55 + 0.45 * (hue + 2.1).cos(),
                        0.55 + 0.45 * (hue + 4.2).cos(),
                    ];
                    let wm = want.iter().cloned().fold(0.0, f32::max);
                    (0..3)
                        .map(|ch| (c[ch] / max - want[ch] / wm).powi(2))
                        .sum::<f32>()
                };
                d(i).total_cmp(&d(j))
            })
            .unwrap();
        counts[best] += 1;
    }
    for (i, &c) in counts.iter().enumerate() {
        assert!(c > 50, "instance {i} shows in only {c} pixels: {counts:?}");
    }
}

#[test]
fn triangle_in_cuda_cpp_renders_the_rust_triangle_pixel_for_pixel() {
    // The CUDA C++ programs on the CPU device (compiled by the host's C++ compiler).
    let cpp = run("triangle_cpp", triangle_cpp::render);
    let rust = triangle::render(W, H).unwrap();
    assert_eq!(
        cpp, rust,
        "the CUDA C++ and Rust programs give different images"
    );
    // And on a GPU, where there is one: the same pixels.
    match oxray::Device::cuda(0) {
        Ok(gpu) => assert_eq!(triangle_cpp::render_on(&gpu, W, H).unwrap(), rust),
        Err(e) => {
            assert!(
                std::env::var_os("OXRAY_REQUIRE_GPU").is_none(),
                "OXRAY_REQUIRE_GPU is set: {e}"
            );
            println!("the GPU half skips: {e}");
        }
    }
}

/// Pixels whose colour lies strictly between the background and the fully covered colour:
/// only some of a pixel's ray times hit, which is what motion blur looks like.
fn partially_covered(px: &[[u8; 4]], bg: [u8; 4], channel: usize, full: u8) -> usize {
    px.iter()
        .filter(|p| p[channel] > bg[channel] + 12 && p[channel] + 12 < full)
        .count()
}

#[test]
fn simple_motion_blur_smears_the_moving_cubes_5_10() {
    let px = run("simple_motion_blur", simple_motion_blur::render);
    let bg = common_bg([0.1, 0.1, 0.15]);
    assert_eq!(at(&px, 0, 0), bg);
    // The translating cube (orange: red channel) covers its path from x = -2.6 to -0.2 only
    // part of the time away from the middle: many partially covered pixels, not a hard edge.
    let orange = px
        .iter()
        .filter(|p| p[0] > p[2] + 20)
        .copied()
        .collect::<Vec<_>>();
    assert!(orange.len() > 500, "{} orange pixels", orange.len());
    assert!(
        partially_covered(&orange, bg, 0, 200) * 3 > orange.len(),
        "most of the translating cube's pixels are blurred"
    );
    // The turning cube (blue) has a sharp core and blurred corners.
    let blue = px.iter().filter(|p| p[2] > p[0] + 20).count();
    assert!(blue > 500, "{blue} blue pixels");
}

#[test]
fn motion_geometry_blurs_the_deforming_sphere_5_10_2() {
    let px = run("motion_geometry", motion_geometry::render);
    let bg = common_bg([0.12, 0.1, 0.1]);
    assert_eq!(at(&px, 0, 0), bg);
    let green: Vec<[u8; 4]> = px.iter().filter(|p| p[1] > p[0] + 10).copied().collect();
    assert!(green.len() > 1000, "{} green pixels", green.len());
    // The silhouette changes with time: its rim is partially covered.
    assert!(partially_covered(&green, bg, 1, 120) > 100);
}

fn common_bg(c: [f32; 3]) -> [u8; 4] {
    let q = |x: f32| (x.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
    [q(c[0]), q(c[1]), q(c[2]), 255]
}
