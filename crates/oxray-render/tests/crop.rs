//! Crop windows (`RenderOptions::crop`): a window's pixels are the full render's pixels, bit for
//! bit, on the Rust programs, on the CUDA C++ programs on the CPU, and on CUDA device 0 where
//! there is one (`OXRAY_REQUIRE_GPU=1` makes its absence a failure); bad windows are refused
//! with a typed error before any work.

use glam::Vec3;
use oxray::Device;
use oxray_render::crop::{CropError, CropWindow};
use oxray_render::lights::Environment;
use oxray_render::{render_passes, Aovs, Image, RenderError, RenderOptions, Renderer};
use oxray_scene::cornell_box;
use std::ops::ControlFlow;

const W: u32 = 23;
const H: u32 = 17;

fn full() -> RenderOptions {
    RenderOptions {
        width: W,
        height: H,
        spp: 3,
        max_depth: 4,
        seed: 7,
        aovs: true,
        ..Default::default()
    }
}

fn dark() -> Environment {
    Environment::uniform(Vec3::ZERO)
}

/// The windows tried: corners, edges, one pixel, one row, one column, the whole image.
fn windows() -> Vec<CropWindow> {
    [
        (0, 0, 5, 4),
        (18, 13, W, H),
        (7, 3, 8, 4),
        (0, 9, W, 10),
        (11, 0, 12, H),
        (3, 2, 20, 15),
        (0, 0, W, H),
    ]
    .into_iter()
    .map(|(x0, y0, x1, y1)| CropWindow::new(x0, y0, x1, y1).unwrap())
    .collect()
}

fn rust_programs(o: &RenderOptions) -> (Image, Aovs) {
    let r = render_passes(&cornell_box(), &dark(), o, |_| ControlFlow::Continue(())).unwrap();
    (r.image, r.aovs.unwrap())
}

/// Checks that `part` (a render of `window`) holds the pixels of `whole` in that window.
fn assert_window(label: &str, whole: &(Image, Aovs), part: &(Image, Aovs), window: CropWindow) {
    let (image, aovs) = part;
    assert_eq!(
        (image.width, image.height, aovs.width, aovs.height),
        (
            window.width(),
            window.height(),
            window.width(),
            window.height()
        ),
        "{label}: the result has the window's size"
    );
    for y in 0..window.height() {
        for x in 0..window.width() {
            let p = (y * window.width() + x) as usize;
            let q = ((window.y0() + y) * W + window.x0() + x) as usize;
            let at = format!("{label}: window {window}, pixel ({x}, {y})");
            assert_eq!(image.pixels[p], whole.0.pixels[q], "{at}: radiance");
            assert_eq!(aovs.albedo[p], whole.1.albedo[q], "{at}: albedo");
            assert_eq!(aovs.normal[p], whole.1.normal[q], "{at}: normal");
            assert_eq!(
                aovs.depth[p].to_bits(),
                whole.1.depth[q].to_bits(),
                "{at}: depth"
            );
            assert_eq!(aovs.samples[p], whole.1.samples[q], "{at}: samples");
        }
    }
}

#[test]
fn a_cropped_render_of_the_rust_programs_is_the_window_of_the_full_render() {
    let whole = rust_programs(&full());
    // Not a flat image: the check would pass for any crop of a constant one.
    assert!(whole.0.pixels.iter().any(|p| *p != whole.0.pixels[0]));
    for window in windows() {
        let part = rust_programs(&RenderOptions {
            crop: Some(window),
            ..full()
        });
        assert_window("Rust programs", &whole, &part, window);
    }
}

/// The devices that run the C++ programs: the CPU, and CUDA device 0 where there is one.
fn devices() -> Vec<(&'static str, Device)> {
    let mut d = vec![("cpu-cxx", Device::cpu())];
    match Device::cuda(0) {
        Ok(c) => d.push(("cuda", c)),
        Err(e) => {
            assert!(
                std::env::var_os("OXRAY_REQUIRE_GPU").is_none(),
                "OXRAY_REQUIRE_GPU is set but there is no CUDA device: {e}"
            );
            println!("the CUDA half skips: {e}");
        }
    }
    d
}

#[test]
fn a_cropped_render_of_the_cxx_programs_is_the_window_of_the_full_render() {
    let scene = cornell_box();
    let env = dark();
    for (label, device) in devices() {
        let mut r = Renderer::new(&device, &scene, &env).unwrap();
        let mut go = |o: &RenderOptions| {
            let done = r.render(o, |_| ControlFlow::Continue(())).unwrap();
            (done.image, done.aovs.unwrap())
        };
        let whole = go(&full());
        for window in windows() {
            let part = go(&RenderOptions {
                crop: Some(window),
                ..full()
            });
            assert_window(label, &whole, &part, window);
        }
    }
}

#[test]
fn progress_images_of_a_cropped_render_have_the_windows_size() {
    let window = CropWindow::new(2, 3, 9, 5).unwrap();
    let o = RenderOptions {
        crop: Some(window),
        aovs: false,
        ..full()
    };
    let mut sizes = Vec::new();
    let done = render_passes(&cornell_box(), &dark(), &o, |p| {
        let image = p.image().unwrap();
        sizes.push((image.width, image.height));
        ControlFlow::Continue(())
    })
    .unwrap();
    assert_eq!(sizes, vec![(7, 2); 3]);
    assert_eq!(
        (done.image.width, done.image.height, done.samples),
        (7, 2, 3)
    );
}

#[test]
fn a_window_must_have_pixels_and_lie_inside_the_image() {
    assert!(matches!(
        CropWindow::new(4, 0, 4, 2),
        Err(CropError::Empty(_))
    ));
    assert!(matches!(
        CropWindow::new(0, 5, 3, 1),
        Err(CropError::Empty(_))
    ));
    for bad in ["", "1,2,3", "1,2,3,4,5", "a,b,c,d", "-1,0,2,2", "1.5,0,2,2"] {
        assert!(
            matches!(bad.parse::<CropWindow>(), Err(CropError::Malformed(_))),
            "{bad:?} is not a window"
        );
    }
    let read: CropWindow = " 1, 2 ,3,4".parse().unwrap();
    assert_eq!(read, CropWindow::new(1, 2, 3, 4).unwrap());
    assert_eq!(read.to_string(), "1,2,3,4");
    assert_eq!(read.to_string().parse::<CropWindow>().unwrap(), read);

    // Past the right or the bottom edge: refused by both path tracers, before any pass.
    for outside in [(0, 0, W + 1, 2), (0, H - 1, 2, H + 1)] {
        let window = CropWindow::new(outside.0, outside.1, outside.2, outside.3).unwrap();
        let o = RenderOptions {
            crop: Some(window),
            ..full()
        };
        let mut passes = 0;
        let err = render_passes(&cornell_box(), &dark(), &o, |_| {
            passes += 1;
            ControlFlow::Continue(())
        })
        .unwrap_err();
        assert!(
            matches!(
                err,
                RenderError::Crop(CropError::OutOfImage {
                    width: W,
                    height: H,
                    ..
                })
            ),
            "{err}"
        );
        assert_eq!(passes, 0);
        let scene = cornell_box();
        let env = dark();
        let mut r = Renderer::new(&Device::cpu(), &scene, &env).unwrap();
        let err = r.render(&o, |_| ControlFlow::Continue(())).unwrap_err();
        assert!(matches!(err, RenderError::Crop(_)), "{err}");
        assert!(
            err.to_string().contains("reaches past the 23x17 image"),
            "{err}"
        );
    }
}
