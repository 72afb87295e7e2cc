//! The on-disk cache of compiled programs (guide §4.2 describes OptiX's; this is oxray's): one
//! directory, entries named by a hash of everything that determines their content, written
//! under a temporary name and renamed into place so that a reader never sees half an entry.

use std::path::{Path, PathBuf};

/// Where compiled programs are kept: `$OXRAY_CACHE_DIR`, else `$XDG_CACHE_HOME/oxray`, else
/// `~/.cache/oxray`, else `oxray-cache` in the temporary directory.
///
/// ```
/// let dir = oxray_core::cache::cache_dir();
/// assert!(dir.is_absolute() || dir.is_relative()); // any path the environment gives
/// ```
#[must_use]
pub fn cache_dir() -> PathBuf {
    let env = |k: &str| {
        std::env::var_os(k)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
    };
    env("OXRAY_CACHE_DIR")
        .or_else(|| env("XDG_CACHE_HOME").map(|d| d.join("oxray")))
        .or_else(|| env("HOME").map(|d| d.join(".cache").join("oxray")))
        .unwrap_or_else(|| std::env::temp_dir().join("oxray-cache"))
}

/// A 64-bit FNV-1a hash of the parts, each followed by a separator: stable across builds and
/// platforms, which is what a cache key needs (it is not a defence against crafted input).
///
/// ```
/// use oxray_core::cache::content_key;
/// assert_ne!(content_key(&["a", "bc"]), content_key(&["ab", "c"]));
/// ```
#[must_use]
pub fn content_key(parts: &[&str]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for p in parts {
        for b in p.bytes().chain([0xff]) {
            h ^= b as u64;
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    }
    h
}

/// The path of entry `key` with extension `ext` in `dir`.
#[must_use]
pub fn entry_path(dir: &Path, prefix: &str, key: u64, ext: &str) -> PathBuf {
    dir.join(format!("{prefix}-{key:016x}.{ext}"))
}

/// A temporary path next to `final_path`, unique to this process and call, for writing an
/// entry before renaming it into place.
pub fn temporary_path(final_path: &Path) -> PathBuf {
    use std::sync::atomic::{AtomicU64, Ordering};
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    let name = final_path
        .file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .unwrap_or_default();
    final_path.with_file_name(format!(".tmp-{}-{n}-{name}", std::process::id()))
}

/// Writes `bytes` as the entry at `path` (directory created, temporary file renamed into
/// place).
pub fn write_entry(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    let tmp = temporary_path(path);
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path).inspect_err(|_| {
        let _ = std::fs::remove_file(&tmp);
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entries_are_written_whole_and_keys_depend_on_every_part() {
        assert_eq!(content_key(&["x"]), content_key(&["x"]));
        assert_ne!(content_key(&["x"]), content_key(&["y"]));
        let dir = std::env::temp_dir().join(format!("oxray-cache-test-{}", std::process::id()));
        let p = entry_path(&dir, "t", 0xabc, "bin");
        assert!(p.ends_with("t-0000000000000abc.bin"));
        write_entry(&p, b"hello").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"hello");
        let leftovers = std::fs::read_dir(&dir)
            .unwrap()
            .filter(|e| {
                e.as_ref()
                    .unwrap()
                    .file_name()
                    .to_string_lossy()
                    .starts_with(".tmp")
            })
            .count();
        assert_eq!(leftovers, 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
