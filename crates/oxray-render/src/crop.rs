//! Crop windows: render a rectangle of the image only ([`RenderOptions::crop`]), as Blender's
//! border render and Mitsuba's `crop_offset`/`crop_size` do.
//!
//! A window is a half-open pixel rectangle `[x0, x1) x [y0, y1)` in the coordinates of the full
//! image (`RenderOptions::width` x `RenderOptions::height`, row 0 at the top). The camera still
//! sees the full image and each pixel draws the random numbers of its place in the full image,
//! so every pixel of a cropped render is bit for bit the same pixel of the full render with the
//! same options; the result (image, AOVs, the progress images) has the window's size.
//!
//! ```
//! use glam::Vec3;
//! use oxray_render::crop::CropWindow;
//! use oxray_render::lights::Environment;
//! use oxray_render::{render, RenderOptions};
//!
//! let scene = oxray_scene::cornell_box();
//! let dark = Environment::uniform(Vec3::ZERO);
//! let full = RenderOptions { width: 8, height: 6, spp: 2, max_depth: 3, ..Default::default() };
//! let window: CropWindow = "2,1,5,4".parse()?; // x0,y0,x1,y1: 3x3 pixels
//! let cropped = RenderOptions { crop: Some(window), ..full.clone() };
//!
//! let all = render(&scene, &dark, &full, |_| {})?;
//! let part = render(&scene, &dark, &cropped, |_| {})?;
//! assert_eq!((part.width, part.height), (3, 3));
//! assert_eq!(part.pixels[0], all.pixels[8 + 2]); // the window's first pixel is (2, 1)
//!
//! // A window must have pixels and lie inside the image.
//! assert!(CropWindow::new(3, 0, 3, 4).is_err());
//! assert!(window.check(4, 4).is_err());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! [`RenderOptions::crop`]: crate::RenderOptions::crop

use std::fmt;
use std::str::FromStr;
use thiserror::Error;

/// A half-open pixel rectangle `[x0, x1) x [y0, y1)` of the full image, with at least one
/// pixel (`x0 < x1`, `y0 < y1`); whether it lies inside an image is checked against the image's
/// size ([`CropWindow::check`], which every render does).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CropWindow {
    x0: u32,
    y0: u32,
    x1: u32,
    y1: u32,
}

/// Why a crop window was refused.
#[derive(Clone, Debug, PartialEq, Eq, Error)]
pub enum CropError {
    /// The text is not four whole numbers `X0,Y0,X1,Y1`.
    #[error("expected four whole numbers X0,Y0,X1,Y1 (pixels, X1 and Y1 excluded), got {0:?}")]
    Malformed(String),
    /// The window has no pixels (`x1 <= x0` or `y1 <= y0`).
    #[error("the crop window {0} has no pixels (X1 must exceed X0 and Y1 must exceed Y0)")]
    Empty(String),
    /// The window reaches past the image (`x1 > width` or `y1 > height`).
    #[error("the crop window {window} reaches past the {width}x{height} image")]
    OutOfImage {
        /// The window, as `X0,Y0,X1,Y1`.
        window: String,
        /// The image's width.
        width: u32,
        /// The image's height.
        height: u32,
    },
}

impl CropWindow {
    /// The window `[x0, x1) x [y0, y1)`; an error unless it has pixels.
    pub fn new(x0: u32, y0: u32, x1: u32, y1: u32) -> Result<Self, CropError> {
        let w = CropWindow { x0, y0, x1, y1 };
        if x1 <= x0 || y1 <= y0 {
            return Err(CropError::Empty(w.to_string()));
        }
        Ok(w)
    }

    /// The whole of a `width` x `height` image (an error if it has no pixels).
    pub fn full(width: u32, height: u32) -> Result<Self, CropError> {
        CropWindow::new(0, 0, width, height)
    }

    /// Checks that the window lies inside a `width` x `height` image.
    pub fn check(&self, width: u32, height: u32) -> Result<(), CropError> {
        if self.x1 > width || self.y1 > height {
            return Err(CropError::OutOfImage {
                window: self.to_string(),
                width,
                height,
            });
        }
        Ok(())
    }

    /// The first column.
    #[must_use]
    pub fn x0(&self) -> u32 {
        self.x0
    }

    /// The first row.
    #[must_use]
    pub fn y0(&self) -> u32 {
        self.y0
    }

    /// The column after the last.
    #[must_use]
    pub fn x1(&self) -> u32 {
        self.x1
    }

    /// The row after the last.
    #[must_use]
    pub fn y1(&self) -> u32 {
        self.y1
    }

    /// Columns.
    #[must_use]
    pub fn width(&self) -> u32 {
        self.x1 - self.x0
    }

    /// Rows.
    #[must_use]
    pub fn height(&self) -> u32 {
        self.y1 - self.y0
    }

    /// Pixels.
    #[must_use]
    pub fn pixels(&self) -> u64 {
        self.width() as u64 * self.height() as u64
    }

    /// The full image's pixel of a launch index over the window (for error messages).
    pub(crate) fn image_pixel(&self, index: &[u32; 3]) -> [u32; 2] {
        [self.x0 + index[0], self.y0 + index[1]]
    }
}

impl fmt::Display for CropWindow {
    /// `X0,Y0,X1,Y1`, the form [`CropWindow::from_str`] reads.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{},{},{},{}", self.x0, self.y0, self.x1, self.y1)
    }
}

impl FromStr for CropWindow {
    type Err = CropError;

    /// Reads `X0,Y0,X1,Y1` (whole numbers, spaces around them allowed).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let values: Option<Vec<u32>> = s.split(',').map(|p| p.trim().parse().ok()).collect();
        match values.as_deref() {
            Some(&[x0, y0, x1, y1]) => CropWindow::new(x0, y0, x1, y1),
            _ => Err(CropError::Malformed(s.into())),
        }
    }
}

/// The pixels a render of `width` x `height` with `crop` computes: the window, checked against
/// the image, or the whole image.
pub(crate) fn window_of(
    width: u32,
    height: u32,
    crop: Option<CropWindow>,
) -> Result<CropWindow, crate::RenderError> {
    let full = CropWindow::full(width, height).map_err(|_| {
        crate::RenderError::Scene(format!("the image has no pixels ({width}x{height})"))
    })?;
    match crop {
        Some(c) => {
            c.check(width, height)?;
            Ok(c)
        }
        None => Ok(full),
    }
}
