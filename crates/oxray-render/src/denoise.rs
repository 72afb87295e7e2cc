//! Denoising, in the manner of OptiX's AI denoiser: a [`Denoiser`] is created once and then
//! turns noisy renders into clean ones, guided by the first hit's albedo and normal where they
//! are given ([`crate::Aovs`]), on high-dynamic-range (linear, unbounded) radiance.
//!
//! The network is Intel Open Image Denoise (OIDN, Apache-2.0), loaded at run time from its
//! shared library: `scripts/setup-oidn.sh` installs it (from the PyPI wheel `pyoidn`, which
//! carries the libraries with the trained weights built in) into `target/oidn/lib`, where the
//! denoiser finds it; `OXRAY_OIDN_LIB` names another library file or directory; otherwise the
//! system's loader path is searched. Nothing is linked at build time, so oxray builds and runs
//! without it, and only denoising reports that it is missing ([`DenoiseError::LibraryNotFound`]).
//!
//! ```no_run
//! use std::ops::ControlFlow;
//! use glam::Vec3;
//! use oxray_render::denoise::Denoiser;
//! use oxray_render::{lights::Environment, render_passes, RenderOptions};
//!
//! let denoiser = Denoiser::new()?; // before rendering: it fails fast without the library
//! let opts = RenderOptions { width: 64, height: 64, spp: 4, aovs: true, ..Default::default() };
//! let dark = Environment::uniform(Vec3::ZERO);
//! let noisy = render_passes(&oxray_scene::cornell_box(), &dark, &opts, |_| {
//!     ControlFlow::Continue(())
//! })?;
//! let clean = denoiser.denoise_rendered(&noisy)?; // the AOVs guide it
//! clean.save(std::path::Path::new("cornell.png"))?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use crate::{Image, Rendered};
use libloading::Library;
use std::ffi::{c_char, c_void, CStr};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use thiserror::Error;

/// The environment variable naming OIDN's library, or the directory that holds it.
pub const LIBRARY_ENV: &str = "OXRAY_OIDN_LIB";

/// OIDN's main library as the loader knows it (major version 2: the C API declared below).
#[cfg(target_os = "windows")]
const LIBRARY_NAME: &str = "OpenImageDenoise.dll";
#[cfg(target_os = "macos")]
const LIBRARY_NAME: &str = "libOpenImageDenoise.2.dylib";
#[cfg(not(any(target_os = "windows", target_os = "macos")))]
const LIBRARY_NAME: &str = "libOpenImageDenoise.so.2";

/// Why denoising failed.
#[derive(Debug, Error)]
pub enum DenoiseError {
    /// OIDN's library could not be loaded (or lacks a function of its C API).
    #[error("cannot load Open Image Denoise ({reason}); run scripts/setup-oidn.sh, or set OXRAY_OIDN_LIB to libOpenImageDenoise.so.2 or its directory")]
    LibraryNotFound {
        /// What was tried and what the loader said.
        reason: String,
    },
    /// OIDN reported an error (its code and message).
    #[error("Open Image Denoise: {message} (error {code})")]
    Device {
        /// OIDN's error code (`OIDNError`: 1 unknown, 2 invalid argument, 3 invalid operation,
        /// 4 out of memory, 5 unsupported hardware, 6 cancelled).
        code: i32,
        /// OIDN's message.
        message: String,
    },
    /// An image does not have `width` x `height` pixels.
    #[error("the {image} image has {got} pixels, not {width}x{height} = {expected}")]
    SizeMismatch {
        /// Which image: beauty, albedo or normal.
        image: &'static str,
        /// Its pixel count.
        got: usize,
        /// `width` x `height`.
        expected: usize,
        /// The width asked for.
        width: u32,
        /// The height asked for.
        height: u32,
    },
    /// The size is zero, or too large to address.
    #[error("cannot denoise a {width}x{height} image")]
    BadSize {
        /// The width asked for.
        width: u32,
        /// The height asked for.
        height: u32,
    },
    /// A normal guide was given without an albedo guide, which OIDN does not accept.
    #[error("a normal guide needs an albedo guide too")]
    NormalWithoutAlbedo,
}

/// Which device OIDN runs the network on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DeviceType {
    /// OIDN's choice: a supported GPU where there is one, else the CPU.
    #[default]
    Default,
    /// The CPU (all its cores, through TBB).
    Cpu,
    /// The first CUDA GPU.
    Cuda,
}

impl DeviceType {
    /// OIDN's `OIDNDeviceType` value.
    fn code(self) -> i32 {
        match self {
            DeviceType::Default => 0,
            DeviceType::Cpu => 1,
            DeviceType::Cuda => 3,
        }
    }
}

type Handle = *mut c_void;

/// The functions of OIDN's C API the denoiser calls, as its documentation declares them
/// (handles are opaque pointers, enums `int`, sizes `size_t`).
struct Api {
    new_device: unsafe extern "C" fn(i32) -> Handle,
    commit_device: unsafe extern "C" fn(Handle),
    release_device: unsafe extern "C" fn(Handle),
    get_device_int: unsafe extern "C" fn(Handle, *const c_char) -> i32,
    get_device_error: unsafe extern "C" fn(Handle, *mut *const c_char) -> i32,
    new_buffer: unsafe extern "C" fn(Handle, usize) -> Handle,
    write_buffer: unsafe extern "C" fn(Handle, usize, usize, *const c_void),
    read_buffer: unsafe extern "C" fn(Handle, usize, usize, *mut c_void),
    release_buffer: unsafe extern "C" fn(Handle),
    new_filter: unsafe extern "C" fn(Handle, *const c_char) -> Handle,
    set_filter_image:
        unsafe extern "C" fn(Handle, *const c_char, Handle, i32, usize, usize, usize, usize, usize),
    set_filter_bool: unsafe extern "C" fn(Handle, *const c_char, bool),
    commit_filter: unsafe extern "C" fn(Handle),
    execute_filter: unsafe extern "C" fn(Handle),
    release_filter: unsafe extern "C" fn(Handle),
}

/// The function `name` (NUL-terminated) of `lib`, typed as the field it fills.
fn symbol<T: Copy>(lib: &Library, path: &str, name: &str) -> Result<T, DenoiseError> {
    // SAFETY: each `Api` field's type is the documented C signature of the OIDN 2 function of
    // that name; the pointer is used only while `lib` is loaded, as the `Denoiser` keeps the
    // library as long as the `Api`.
    let f = unsafe { lib.get::<T>(name.as_bytes()) };
    f.map(|f| *f).map_err(|e| DenoiseError::LibraryNotFound {
        reason: format!("{path} lacks {}: {e}", name.trim_end_matches('\0')),
    })
}

/// `OIDN_FORMAT_FLOAT3`: three 32-bit floats a pixel.
const FORMAT_FLOAT3: i32 = 3;

impl Api {
    fn load(lib: &Library, path: &str) -> Result<Api, DenoiseError> {
        macro_rules! sym {
            ($name:literal) => {
                symbol(lib, path, concat!($name, "\0"))?
            };
        }
        Ok(Api {
            new_device: sym!("oidnNewDevice"),
            commit_device: sym!("oidnCommitDevice"),
            release_device: sym!("oidnReleaseDevice"),
            get_device_int: sym!("oidnGetDeviceInt"),
            get_device_error: sym!("oidnGetDeviceError"),
            new_buffer: sym!("oidnNewBuffer"),
            write_buffer: sym!("oidnWriteBuffer"),
            read_buffer: sym!("oidnReadBuffer"),
            release_buffer: sym!("oidnReleaseBuffer"),
            new_filter: sym!("oidnNewFilter"),
            set_filter_image: sym!("oidnSetFilterImage"),
            set_filter_bool: sym!("oidnSetFilterBool"),
            commit_filter: sym!("oidnCommitFilter"),
            execute_filter: sym!("oidnExecuteFilter"),
            release_filter: sym!("oidnReleaseFilter"),
        })
    }
}

/// A denoiser: OIDN's library and one committed device, created once and used for any number
/// of images (the OptiX denoiser's life cycle). Calls from several threads are taken one at a
/// time.
///
/// ```no_run
/// use oxray_render::denoise::Denoiser;
///
/// let denoiser = Denoiser::new()?;
/// let (width, height) = (2, 1);
/// let beauty = vec![[0.5, 0.4, 0.3], [8.0, 0.0, 0.1]]; // linear radiance, HDR
/// let albedo = vec![[0.8, 0.8, 0.8]; 2];
/// let normal = vec![[0.0, 0.0, 1.0]; 2];
/// let clean = denoiser.denoise(&beauty, Some(&albedo), Some(&normal), width, height)?;
/// assert_eq!(clean.len(), 2);
/// # Ok::<(), oxray_render::denoise::DenoiseError>(())
/// ```
pub struct Denoiser {
    api: Api,
    device: Handle,
    kind: DeviceType,
    /// OIDN reports the last error per device: one call at a time keeps each call's own.
    lock: Mutex<()>,
    path: String,
    // Dropped last (fields drop in order): the functions above point into it.
    _lib: Library,
}

// SAFETY: the device handle is only used under `lock` (or in `drop`, which has `&mut self`),
// and OIDN's API may be called from any thread.
unsafe impl Send for Denoiser {}
// SAFETY: as above; `&self` methods take `lock` before using the device.
unsafe impl Sync for Denoiser {}

impl std::fmt::Debug for Denoiser {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Denoiser")
            .field("library", &self.path)
            .field("device", &self.kind)
            .finish()
    }
}

impl Denoiser {
    /// Loads OIDN and creates its default device (a GPU it supports, else the CPU).
    pub fn new() -> Result<Denoiser, DenoiseError> {
        Denoiser::with_device(DeviceType::Default)
    }

    /// Loads OIDN and creates a device of that type.
    pub fn with_device(kind: DeviceType) -> Result<Denoiser, DenoiseError> {
        Denoiser::open(load_library(candidates())?, kind)
    }

    /// Loads OIDN from that library file only (no search), and creates a device of that type.
    pub fn from_library(path: &Path, kind: DeviceType) -> Result<Denoiser, DenoiseError> {
        Denoiser::open(load_library(vec![path.to_path_buf()])?, kind)
    }

    fn open((lib, path): (Library, String), kind: DeviceType) -> Result<Denoiser, DenoiseError> {
        let api = Api::load(&lib, &path)?;
        // SAFETY: the documented call; a null result is handled below.
        let device = unsafe { (api.new_device)(kind.code()) };
        if device.is_null() {
            return Err(thread_error(&api).unwrap_or(DenoiseError::Device {
                code: 1,
                message: format!("no {kind:?} device"),
            }));
        }
        let mut d = Denoiser {
            api,
            device,
            kind,
            lock: Mutex::new(()),
            path,
            _lib: lib,
        };
        // SAFETY: a live device, created above.
        unsafe { (d.api.commit_device)(d.device) };
        d.check()?;
        // SAFETY: a committed device; "type" is a documented parameter, the name is a C string.
        let actual = unsafe { (d.api.get_device_int)(d.device, c"type".as_ptr()) };
        d.kind = match actual {
            1 => DeviceType::Cpu,
            3 => DeviceType::Cuda,
            _ => kind,
        };
        Ok(d)
    }

    /// The device that runs the network (the CPU or the GPU [`DeviceType::Default`] chose).
    pub fn device_type(&self) -> DeviceType {
        self.kind
    }

    /// The library file it loaded (as found: a path, or the name the loader resolved).
    pub fn library(&self) -> &str {
        &self.path
    }

    /// Denoises `beauty`, `width` x `height` linear RGB pixels (row-major), with the optional
    /// guides: `albedo` (the first hit's albedo) and `normal` (its shading normal, world or
    /// camera space; it needs the albedo too). Returns the denoised pixels.
    ///
    /// Values that are not finite become 0, and negative radiance 0, as the network expects
    /// non-negative HDR input: one bad sample then darkens its pixel instead of spreading over
    /// the neighbourhood.
    pub fn denoise(
        &self,
        beauty: &[[f32; 3]],
        albedo: Option<&[[f32; 3]]>,
        normal: Option<&[[f32; 3]]>,
        width: u32,
        height: u32,
    ) -> Result<Vec<[f32; 3]>, DenoiseError> {
        let n = (width as usize)
            .checked_mul(height as usize)
            .filter(|&n| n > 0 && n.checked_mul(12).is_some())
            .ok_or(DenoiseError::BadSize { width, height })?;
        let sized = |image: &'static str, got: usize| match got == n {
            true => Ok(()),
            false => Err(DenoiseError::SizeMismatch {
                image,
                got,
                expected: n,
                width,
                height,
            }),
        };
        sized("beauty", beauty.len())?;
        if let Some(a) = albedo {
            sized("albedo", a.len())?;
        }
        if let Some(nm) = normal {
            sized("normal", nm.len())?;
            if albedo.is_none() {
                return Err(DenoiseError::NormalWithoutAlbedo);
            }
        }
        let clean = |v: f32, lo: f32| if v.is_finite() { v.max(lo) } else { 0.0 };
        let color: Vec<[f32; 3]> = beauty.iter().map(|p| p.map(|v| clean(v, 0.0))).collect();
        let albedo: Option<Vec<[f32; 3]>> = albedo.map(|a| {
            a.iter()
                .map(|p| p.map(|v| clean(v, 0.0).min(1.0)))
                .collect()
        });
        let normal: Option<Vec<[f32; 3]>> = normal.map(|a| {
            a.iter()
                .map(|p| p.map(|v| clean(v, -1.0).min(1.0)))
                .collect()
        });

        let _one = self.lock.lock().unwrap_or_else(|e| e.into_inner());
        // Errors left by an earlier failed call are not this call's.
        let _ = self.check();
        let mut run = Run {
            d: self,
            buffers: Vec::new(),
            filter: std::ptr::null_mut(),
        };
        run.execute(&color, albedo.as_deref(), normal.as_deref(), width, height)
    }

    /// Denoises a render's image, guided by its AOVs where it has them
    /// ([`crate::RenderOptions::aovs`]); the alpha channel is kept.
    pub fn denoise_rendered(&self, rendered: &Rendered) -> Result<Image, DenoiseError> {
        self.denoise_image(&rendered.image, rendered.aovs.as_ref())
    }

    /// Denoises `image` with the albedo and normal of `aovs` (when given) as guides; the alpha
    /// channel is kept.
    pub fn denoise_image(
        &self,
        image: &Image,
        aovs: Option<&crate::Aovs>,
    ) -> Result<Image, DenoiseError> {
        let beauty: Vec<[f32; 3]> = image.pixels.iter().map(|p| [p[0], p[1], p[2]]).collect();
        let (albedo, normal) = match aovs {
            Some(a) => {
                if (a.width, a.height) != (image.width, image.height) {
                    return Err(DenoiseError::SizeMismatch {
                        image: "albedo",
                        got: a.width as usize * a.height as usize,
                        expected: image.pixels.len(),
                        width: image.width,
                        height: image.height,
                    });
                }
                (Some(a.albedo.as_slice()), Some(a.normal.as_slice()))
            }
            None => (None, None),
        };
        let out = self.denoise(&beauty, albedo, normal, image.width, image.height)?;
        Ok(Image {
            width: image.width,
            height: image.height,
            pixels: out
                .iter()
                .zip(&image.pixels)
                .map(|(c, p)| [c[0], c[1], c[2], p[3]])
                .collect(),
        })
    }

    /// The device's pending error, cleared.
    fn check(&self) -> Result<(), DenoiseError> {
        let mut message: *const c_char = std::ptr::null();
        // SAFETY: a live device and a valid place for the message pointer.
        let code = unsafe { (self.api.get_device_error)(self.device, &mut message) };
        match code {
            0 => Ok(()),
            _ => Err(DenoiseError::Device {
                code,
                message: message_of(message),
            }),
        }
    }
}

impl Drop for Denoiser {
    fn drop(&mut self) {
        // SAFETY: the device is live and released once; the library is still loaded.
        unsafe { (self.api.release_device)(self.device) };
    }
}

/// One denoising call's OIDN objects, released when it ends however it ends.
struct Run<'d> {
    d: &'d Denoiser,
    buffers: Vec<Handle>,
    filter: Handle,
}

impl Run<'_> {
    fn execute(
        &mut self,
        color: &[[f32; 3]],
        albedo: Option<&[[f32; 3]]>,
        normal: Option<&[[f32; 3]]>,
        width: u32,
        height: u32,
    ) -> Result<Vec<[f32; 3]>, DenoiseError> {
        let api = &self.d.api;
        let bytes = std::mem::size_of_val(color);
        // SAFETY: a live device; "RT" is OIDN's ray-tracing filter, the name a C string.
        self.filter = unsafe { (api.new_filter)(self.d.device, c"RT".as_ptr()) };
        self.d.check()?;
        // The inputs present, then the output (no data to write).
        let images = [
            (c"color", Some(color)),
            (c"albedo", albedo),
            (c"normal", normal),
        ]
        .into_iter()
        .filter(|(_, data)| data.is_some())
        .chain([(c"output", None)]);
        let mut output = std::ptr::null_mut();
        for (name, data) in images {
            // SAFETY: a live device; the size is that of the pixels (checked not to overflow).
            let buffer = unsafe { (api.new_buffer)(self.d.device, bytes) };
            self.d.check()?;
            if buffer.is_null() {
                return Err(DenoiseError::Device {
                    code: 4,
                    message: "no buffer".into(),
                });
            }
            self.buffers.push(buffer);
            if let Some(pixels) = data {
                // SAFETY: `pixels` holds `bytes` bytes (every image has the beauty's size) and
                // the buffer as many; the write is synchronous.
                unsafe { (api.write_buffer)(buffer, 0, bytes, pixels.as_ptr().cast()) };
            } else {
                output = buffer;
            }
            // SAFETY: a live filter and buffer; the image is `width` x `height` packed FLOAT3
            // pixels (strides 0: packed), which is the buffer's size.
            unsafe {
                (api.set_filter_image)(
                    self.filter,
                    name.as_ptr(),
                    buffer,
                    FORMAT_FLOAT3,
                    width as usize,
                    height as usize,
                    0,
                    0,
                    0,
                )
            };
            self.d.check()?;
        }
        // SAFETY: a live filter; "hdr" is a documented parameter of "RT".
        unsafe { (api.set_filter_bool)(self.filter, c"hdr".as_ptr(), true) };
        // SAFETY: a live filter with its images set.
        unsafe { (api.commit_filter)(self.filter) };
        self.d.check()?;
        // SAFETY: a committed filter; the call returns when the output is written.
        unsafe { (api.execute_filter)(self.filter) };
        self.d.check()?;
        let mut out = vec![[0f32; 3]; color.len()];
        // SAFETY: `out` holds `bytes` bytes, as does the output buffer; the read is synchronous.
        unsafe { (api.read_buffer)(output, 0, bytes, out.as_mut_ptr().cast()) };
        self.d.check()?;
        Ok(out)
    }
}

impl Drop for Run<'_> {
    fn drop(&mut self) {
        let api = &self.d.api;
        if !self.filter.is_null() {
            // SAFETY: the filter this run created, released once.
            unsafe { (api.release_filter)(self.filter) };
        }
        for &b in &self.buffers {
            // SAFETY: a buffer this run created, released once (after the filter using it).
            unsafe { (api.release_buffer)(b) };
        }
    }
}

/// The error OIDN recorded for this thread (the failure to create a device).
fn thread_error(api: &Api) -> Option<DenoiseError> {
    let mut message: *const c_char = std::ptr::null();
    // SAFETY: a null device asks for the thread's error, as documented.
    let code = unsafe { (api.get_device_error)(std::ptr::null_mut(), &mut message) };
    (code != 0).then(|| DenoiseError::Device {
        code,
        message: message_of(message),
    })
}

fn message_of(message: *const c_char) -> String {
    if message.is_null() {
        return "no message".into();
    }
    // SAFETY: OIDN returns a NUL-terminated string valid until the next call on the device,
    // copied here at once (under the denoiser's lock).
    unsafe { CStr::from_ptr(message) }
        .to_string_lossy()
        .into_owned()
}

/// Where OIDN's library may be: `OXRAY_OIDN_LIB` (a file, or a directory holding it), the
/// directory `scripts/setup-oidn.sh` installs into, then the loader's own search by name.
fn candidates() -> Vec<PathBuf> {
    let mut out = Vec::new();
    if let Some(v) = std::env::var_os(LIBRARY_ENV).filter(|v| !v.is_empty()) {
        let p = PathBuf::from(v);
        out.push(match p.is_dir() {
            true => p.join(LIBRARY_NAME),
            false => p,
        });
        // A set variable is the only place looked at: a wrong one is reported, not bypassed.
        return out;
    }
    let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    out.push(workspace.join("target/oidn/lib").join(LIBRARY_NAME));
    if let Ok(exe) = std::env::current_exe() {
        // An installed binary next to its `target` folder (target/release/oxray).
        if let Some(target) = exe.parent().and_then(Path::parent) {
            out.push(target.join("oidn/lib").join(LIBRARY_NAME));
        }
    }
    out.push(PathBuf::from(LIBRARY_NAME));
    out
}

fn load_library(candidates: Vec<PathBuf>) -> Result<(Library, String), DenoiseError> {
    let mut tried = Vec::new();
    for path in candidates {
        let bare = path.components().count() == 1;
        if !bare && !path.exists() {
            tried.push(format!("{}: no such file", path.display()));
            continue;
        }
        // SAFETY: loading OIDN runs its libraries' initialisers, which only set up OIDN's own
        // state (no symbol is used before its signature is matched in `Api::load`).
        match unsafe { Library::new(&path) } {
            Ok(lib) => return Ok((lib, path.display().to_string())),
            Err(e) => tried.push(e.to_string()),
        }
    }
    Err(DenoiseError::LibraryNotFound {
        reason: tried.join("; "),
    })
}

impl Rendered {
    /// Writes `denoised` (this render's image denoised, [`Denoiser::denoise_rendered`]) as one
    /// OpenEXR file, atomically, as [`Rendered::save_exr`] writes the image: channels `R`, `G`,
    /// `B`, `A` of the denoised image, the AOV layers where they were rendered, and the noisy
    /// image as the layer `noisy.{R,G,B}`, for comparison or for another denoiser.
    pub fn save_denoised_exr(&self, path: &Path, denoised: &Image) -> Result<(), String> {
        crate::output::write_layers_exr(path, denoised, self.aovs.as_ref(), Some(&self.image))
    }
}
