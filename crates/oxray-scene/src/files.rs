//! Safe file input and output, shared by the loaders, the image writers and the `oxray` tool:
//!
//! - inputs are read only from regular files (a FIFO, a device such as `/dev/zero` or a
//!   directory is refused before it is opened), and only when their size, taken from the file's
//!   metadata, is within [`Limits::file_bytes`];
//! - outputs are written to a temporary file in the target folder and renamed into place
//!   ([`write_atomic`]), so a command killed while writing leaves the previous file intact;
//! - [`check_output`] refuses, before any work, an output that is one of the command's inputs
//!   or that lies in a folder that does not exist or cannot be written;
//! - [`guard_panics`] runs third-party decoders so that a panic becomes an error.
//!
//! The memory limits ([`Limits`]) have defaults that any scene a workstation can render fits
//! in, and can be raised (or lowered) with environment variables.

use std::cell::Cell;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::OnceLock;

const MIB: u64 = 1 << 20;

/// The memory and size limits of the loaders and of `oxray raycast`, checked before
/// allocating. Each can be set with an environment variable (a whole number; sizes in MiB).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Largest input file read whole: a scene, a glTF buffer, an image, an MTL or a ray file
    /// (`OXRAY_MAX_FILE_MB`, default 2048).
    pub file_bytes: u64,
    /// Largest decoded image, as RGBA8 (`OXRAY_MAX_IMAGE_MB`, default 256: 8192 x 8192).
    pub image_bytes: u64,
    /// All the decoded textures of one scene together, as RGBA8 (`OXRAY_MAX_TEXTURES_MB`,
    /// default 1024).
    pub textures_bytes: u64,
    /// A scene flattened into one mesh for `oxray raycast`: 12 bytes per vertex and per
    /// triangle, summed over every instance (`OXRAY_MAX_GEOMETRY_MB`, default 2048).
    pub geometry_bytes: u64,
    /// Rays in one ray file (`OXRAY_MAX_RAYS`, default 33554432 = 2^25, a 1 GiB file).
    pub rays: u64,
}

/// The environment variables of [`Limits`], with the unit their value is in.
pub const LIMIT_VARIABLES: [(&str, &str); 5] = [
    ("OXRAY_MAX_FILE_MB", "MiB"),
    ("OXRAY_MAX_IMAGE_MB", "MiB"),
    ("OXRAY_MAX_TEXTURES_MB", "MiB"),
    ("OXRAY_MAX_GEOMETRY_MB", "MiB"),
    ("OXRAY_MAX_RAYS", "rays"),
];

impl Default for Limits {
    fn default() -> Self {
        Limits {
            file_bytes: 2048 * MIB,
            image_bytes: 256 * MIB,
            textures_bytes: 1024 * MIB,
            geometry_bytes: 2048 * MIB,
            rays: 1 << 25,
        }
    }
}

impl Limits {
    /// The defaults overridden by the environment; an unparsable value is an error naming
    /// the variable.
    pub fn from_env() -> Result<Limits, String> {
        let mut l = Limits::default();
        let fields: [&mut u64; 5] = [
            &mut l.file_bytes,
            &mut l.image_bytes,
            &mut l.textures_bytes,
            &mut l.geometry_bytes,
            &mut l.rays,
        ];
        for ((var, unit), field) in LIMIT_VARIABLES.iter().zip(fields) {
            let Some(v) = std::env::var_os(var) else {
                continue;
            };
            let n = v
                .to_str()
                .and_then(|s| s.trim().parse::<u64>().ok())
                .filter(|&n| n > 0)
                .ok_or_else(|| format!("{var} must be a whole number of {unit} above 0"))?;
            *field = if *unit == "MiB" {
                n.saturating_mul(MIB)
            } else {
                n
            };
        }
        Ok(l)
    }

    /// The limits in force: [`Limits::from_env`] read once, the defaults where it fails (the
    /// `oxray` tool reports that failure at start).
    pub fn get() -> &'static Limits {
        static LIMITS: OnceLock<Limits> = OnceLock::new();
        LIMITS.get_or_init(|| Limits::from_env().unwrap_or_default())
    }
}

/// `n` bytes in MiB for messages.
#[must_use]
pub fn mib(n: u64) -> String {
    if n >= MIB {
        format!("{} MiB", n / MIB)
    } else {
        format!("{n} bytes")
    }
}

/// Checks that `path` names a regular file (following symbolic links) and returns its size.
/// FIFOs, devices, sockets and directories are refused without being opened.
pub fn regular_file_size(path: &Path) -> io::Result<u64> {
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        let kind = if meta.is_dir() {
            "a directory"
        } else {
            "not a regular file (a device, FIFO or socket)"
        };
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("it is {kind}"),
        ));
    }
    Ok(meta.len())
}

/// Reads a whole regular file of at most `limit` bytes; the size is checked from the metadata
/// before anything is read, and the read stops at the limit should the file grow meanwhile.
pub fn read_limited(path: &Path, limit: u64, variable: &str) -> io::Result<Vec<u8>> {
    use io::Read;
    let len = regular_file_size(path)?;
    let too_big = |len: u64| {
        io::Error::new(
            io::ErrorKind::InvalidInput,
            format!(
                "it is {len} bytes, over the {} limit (raise it with {variable})",
                mib(limit)
            ),
        )
    };
    if len > limit {
        return Err(too_big(len));
    }
    let file = std::fs::File::open(path)?;
    let mut out = Vec::with_capacity(len as usize);
    file.take(limit.saturating_add(1)).read_to_end(&mut out)?;
    if out.len() as u64 > limit {
        return Err(too_big(out.len() as u64));
    }
    Ok(out)
}

/// Reads an input file within [`Limits::file_bytes`].
pub fn read_input(path: &Path) -> io::Result<Vec<u8>> {
    read_limited(path, Limits::get().file_bytes, "OXRAY_MAX_FILE_MB")
}

/// Whether `a` and `b` name the same existing file (same device and inode on Unix, same
/// canonical path elsewhere). Paths that do not exist are never the same file.
#[must_use]
pub fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        match (std::fs::metadata(a), std::fs::metadata(b)) {
            (Ok(x), Ok(y)) => x.dev() == y.dev() && x.ino() == y.ino(),
            _ => false,
        }
    }
    #[cfg(not(unix))]
    {
        match (a.canonicalize(), b.canonicalize()) {
            (Ok(x), Ok(y)) => x == y,
            _ => false,
        }
    }
}

/// The folder a file is written into (`.` for a bare file name).
fn folder_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

static TEMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// A fresh temporary name next to `path`: `.NAME.PID-N.oxray-tmp` in the same folder, so that
/// renaming it onto `path` is atomic.
fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map_or("output".into(), |n| n.to_string_lossy().into_owned());
    let n = TEMP_COUNTER.fetch_add(1, Ordering::Relaxed);
    folder_of(path).join(format!(".{name}.{}-{n}.oxray-tmp", std::process::id()))
}

/// Checks before any work that `out` can be written and is none of `inputs`: an existing
/// `out` must be a regular file and not the same file as an input; its folder must exist and
/// accept a new file (checked by creating and removing a temporary one). The message is one
/// phrase naming the file.
pub fn check_output(out: &Path, inputs: &[&Path]) -> Result<(), String> {
    let name = out.display();
    if let Some(input) = inputs.iter().find(|i| same_file(out, i)) {
        return Err(format!(
            "{name} is also an input ({}); choose another output file",
            input.display()
        ));
    }
    if let Ok(meta) = std::fs::metadata(out) {
        if !meta.is_file() {
            return Err(format!(
                "cannot write {name}: it exists and is not a regular file"
            ));
        }
    }
    let folder = folder_of(out);
    match std::fs::metadata(folder) {
        Ok(m) if m.is_dir() => {}
        Ok(_) => {
            return Err(format!(
                "cannot write {name}: {} is not a folder",
                folder.display()
            ))
        }
        Err(e) => {
            return Err(format!(
                "cannot write {name}: the folder {} does not exist ({e})",
                folder.display()
            ))
        }
    }
    let probe = temp_path(out);
    match std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
    {
        Ok(_) => {
            std::fs::remove_file(&probe).ok();
            Ok(())
        }
        Err(e) => Err(format!(
            "cannot write {name}: cannot create a file in {} ({e})",
            folder.display()
        )),
    }
}

/// Removes the temporary file unless it was renamed into place.
struct TempGuard(Option<PathBuf>);

impl Drop for TempGuard {
    fn drop(&mut self) {
        if let Some(p) = self.0.take() {
            std::fs::remove_file(p).ok();
        }
    }
}

/// Writes `path` atomically: `write` fills a temporary file in the same folder (it gets that
/// file's path), which is flushed to disk and renamed onto `path`. On any failure (a full disk,
/// an encoder error, a panic) the temporary file is removed and `path` is left as it was; a
/// process killed meanwhile leaves at most a hidden `.NAME.*.oxray-tmp` file beside it.
pub fn write_atomic<E: From<io::Error>>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), E>,
) -> Result<(), E> {
    let tmp = temp_path(path);
    let mut guard = TempGuard(Some(tmp.clone()));
    write(&tmp)?;
    std::fs::File::open(&tmp)?.sync_all()?;
    std::fs::rename(&tmp, path)?;
    guard.0 = None;
    Ok(())
}

/// [`write_atomic`] of a byte buffer.
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    write_atomic(path, |tmp| std::fs::write(tmp, bytes))
}

thread_local! {
    static GUARDED: Cell<u32> = const { Cell::new(0) };
}

/// Whether the current thread is inside [`guard_panics`]: a panic hook can stay silent then,
/// since the panic is reported as an ordinary error.
#[must_use]
pub fn in_guarded_code() -> bool {
    GUARDED.with(|g| g.get() > 0)
}

/// Runs `f` (a third-party decoder) so that a panic in it becomes `Err` with the panic's
/// message instead of ending the program.
pub fn guard_panics<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    GUARDED.with(|g| g.set(g.get() + 1));
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    GUARDED.with(|g| g.set(g.get() - 1));
    r.map_err(|p| {
        let msg = p
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| p.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown cause".into());
        format!("the decoder failed ({})", msg.lines().next().unwrap_or(""))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(test: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("oxray-files-{}-{test}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn leftovers(d: &Path) -> Vec<String> {
        std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".oxray-tmp"))
            .collect()
    }

    #[test]
    fn a_failed_write_keeps_the_previous_file_and_leaves_no_temporary() {
        let d = dir("failed");
        let out = d.join("img.png");
        std::fs::write(&out, b"previous").unwrap();
        // A full disk, as the writer sees it.
        let r = write_atomic(&out, |tmp| {
            std::fs::write(tmp, b"half")?;
            Err::<(), io::Error>(io::Error::from_raw_os_error(28))
        });
        assert!(r.unwrap_err().to_string().contains("No space left"));
        assert_eq!(std::fs::read(&out).unwrap(), b"previous");
        assert!(leftovers(&d).is_empty(), "{:?}", leftovers(&d));
        // A panicking encoder.
        let p = std::panic::catch_unwind(|| {
            write_atomic(&out, |tmp| -> io::Result<()> {
                std::fs::write(tmp, b"half").unwrap();
                panic!("encoder bug")
            })
        });
        assert!(p.is_err());
        assert_eq!(std::fs::read(&out).unwrap(), b"previous");
        assert!(leftovers(&d).is_empty());
        write_bytes_atomic(&out, b"new").unwrap();
        assert_eq!(std::fs::read(&out).unwrap(), b"new");
        assert!(leftovers(&d).is_empty());
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn outputs_that_are_inputs_or_in_missing_folders_are_refused() {
        let d = dir("check");
        let input = d.join("in.obj");
        std::fs::write(&input, b"v 0 0 0\n").unwrap();
        // The same file under another name: a hard link and a path with "..".
        let link = d.join("link.obj");
        std::fs::hard_link(&input, &link).unwrap();
        let dotted = d.join("sub/../in.obj");
        std::fs::create_dir_all(d.join("sub")).unwrap();
        for out in [&input, &link, &dotted] {
            let e = check_output(out, &[&input]).unwrap_err();
            assert!(e.contains("is also an input"), "{e}");
        }
        assert!(check_output(&d.join("out.bin"), &[&input]).is_ok());
        let e = check_output(&d.join("missing/out.png"), &[]).unwrap_err();
        assert!(e.contains("does not exist"), "{e}");
        let e = check_output(&d, &[]).unwrap_err();
        assert!(e.contains("not a regular file"), "{e}");
        assert!(leftovers(&d).is_empty());
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn non_regular_and_oversized_inputs_are_refused_before_reading() {
        let e = read_limited(Path::new("/dev/zero"), 1 << 20, "X").unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
        let e = read_limited(&std::env::temp_dir(), 1 << 20, "X").unwrap_err();
        assert!(e.to_string().contains("directory"), "{e}");
        let d = dir("limited");
        let f = d.join("big.bin");
        std::fs::write(&f, vec![0u8; 4096]).unwrap();
        let e = read_limited(&f, 100, "OXRAY_MAX_FILE_MB").unwrap_err();
        assert!(e.to_string().contains("OXRAY_MAX_FILE_MB"), "{e}");
        assert_eq!(read_limited(&f, 4096, "X").unwrap().len(), 4096);
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn panics_in_guarded_code_become_errors() {
        let e = guard_panics(|| -> u32 { panic!("bad palette") }).unwrap_err();
        assert!(e.contains("bad palette"), "{e}");
        assert!(!in_guarded_code());
        assert_eq!(guard_panics(|| 3).unwrap(), 3);
    }
}
