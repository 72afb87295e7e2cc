//! `oxray view` through the built binary: on a virtual X server (Xvfb) its screenshot is the
//! image `oxray render` writes, and without a display it fails with one error line.

use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("oxray-view-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `oxray` with `args`, on `display` (an X11 display name), or on none at all.
fn oxray(args: &[&str], display: Option<&str>) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_oxray"));
    command
        .args(args)
        .env_remove("WAYLAND_DISPLAY")
        .env_remove("WAYLAND_SOCKET");
    match display {
        Some(d) => command.env("DISPLAY", d),
        None => command.env_remove("DISPLAY"),
    };
    command.output().unwrap()
}

/// Fails unless the command failed with exactly one line on stderr, starting `error:` and
/// containing `needle`.
fn assert_one_error(out: &Output, needle: &str) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "succeeded: {err}");
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "not one line: {err}");
    assert!(lines[0].starts_with("error: "), "{err}");
    assert!(lines[0].contains(needle), "{err} lacks {needle:?}");
    assert!(!err.contains("panicked"));
}

/// An Xvfb server on a display number it picks itself (`-displayfd`), stopped when dropped.
struct Xvfb {
    child: Child,
    display: String,
}

impl Xvfb {
    fn start() -> Result<Xvfb, String> {
        let mut child = Command::new("Xvfb")
            // 24-bit colour: the window's pixels are the 8-bit sRGB channels unchanged.
            .args([
                "-displayfd",
                "1",
                "-screen",
                "0",
                "320x240x24",
                "-nolisten",
                "tcp",
            ])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .map_err(|e| format!("cannot run Xvfb: {e}"))?;
        let mut line = String::new();
        let read = child
            .stdout
            .take()
            .map(|out| std::io::BufReader::new(out).read_line(&mut line));
        match (read, line.trim().parse::<u32>()) {
            (Some(Ok(_)), Ok(n)) => Ok(Xvfb {
                child,
                display: format!(":{n}"),
            }),
            _ => {
                let _ = child.kill();
                let _ = child.wait();
                Err(format!("Xvfb did not start (it said {line:?})"))
            }
        }
    }
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The X server of the test, or `None` (the test skips) where none can be started, unless
/// OXRAY_REQUIRE_DISPLAY=1 (CI installs Xvfb).
fn x_server() -> Option<Xvfb> {
    match Xvfb::start() {
        Ok(x) => Some(x),
        Err(e) if std::env::var("OXRAY_REQUIRE_DISPLAY").as_deref() == Ok("1") => {
            panic!("OXRAY_REQUIRE_DISPLAY=1 but {e}")
        }
        Err(e) => {
            eprintln!("skipped: {e} (install the xvfb package to run this test)");
            None
        }
    }
}

fn decode(path: &Path) -> (u32, u32, Vec<u8>) {
    let decoder = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())),
    ));
    let mut reader = decoder.read_info().unwrap();
    let mut pixels = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut pixels).unwrap();
    assert_eq!(
        (info.color_type, info.bit_depth),
        (png::ColorType::Rgba, png::BitDepth::Eight)
    );
    pixels.truncate(info.buffer_size());
    (info.width, info.height, pixels)
}

#[test]
fn screenshot_of_the_window_is_the_render() {
    let Some(x) = x_server() else { return };
    let shot = tmp("view.png");
    let rendered = tmp("render.png");
    // The window's pixels are the render's 8-bit sRGB values packed into 0RGB words, a
    // lossless change of layout on a 24-bit display: the images are equal pixel for pixel.
    let common = ["--size", "48x32", "--seed", "7", "--max-depth", "4"];
    let mut view = vec!["view", "--screenshot", s(&shot), "--frames", "4"];
    view.extend(common);
    let out = oxray(&view, Some(&x.display));
    assert!(
        out.status.success(),
        "view failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut render = vec!["render", "-q", "-o", s(&rendered), "--spp", "4"];
    render.extend(common);
    let out = oxray(&render, None);
    assert!(
        out.status.success(),
        "render failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (w, h, view_pixels) = decode(&shot);
    let (rw, rh, render_pixels) = decode(&rendered);
    assert_eq!((w, h), (48, 32));
    assert_eq!((rw, rh), (48, 32));
    let differing = view_pixels
        .chunks_exact(4)
        .zip(render_pixels.chunks_exact(4))
        .filter(|(a, b)| a != b)
        .count();
    assert_eq!(differing, 0, "{differing} of {} pixels differ", w * h);
    // A lit Cornell box, not an empty window.
    let lit = view_pixels
        .chunks_exact(4)
        .filter(|p| p[..3].iter().any(|&c| c > 40))
        .count();
    assert!(lit > (w * h / 4) as usize, "only {lit} lit pixels");
}

#[test]
fn without_a_display_it_fails_with_one_line() {
    assert_one_error(
        &oxray(&["view", "--size", "16x16"], None),
        "needs a display",
    );
    // A display that cannot be reached: the connection fails, reported in one line.
    let unreachable = oxray(&["view", "--size", "16x16"], Some(":4093"));
    assert_one_error(&unreachable, "cannot open the display :4093");
    // Arguments are checked before the display.
    assert_one_error(
        &oxray(&["view", "--screenshot", s(&tmp("shot.jpg"))], None),
        "--screenshot writes a PNG",
    );
    assert_one_error(&oxray(&["view", "--size", "0x4"], None), "--size");
}
