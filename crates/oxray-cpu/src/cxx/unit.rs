//! A pipeline's translation unit on the CPU: the device header, the modules, generated wrappers
//! for every entry point; compiled by the host's C++ compiler into a shared library, cached on
//! disk by content, and loaded.

use super::bridge::{frame_layout, CallableEntry, EntryFn, ProgramEntry};
use super::{CxxError, CxxModule};
use crate::program::ProgramKind;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Arc, Mutex, OnceLock, Weak};

/// The CPU implementation of the device header.
pub const DEVICE_HEADER_CPU: &str = include_str!("oxray_device_cpu.h");

/// What the compiler is given besides the unit: C++17, optimised, with no contraction of
/// multiplies and adds (so that programs compute what they compute on the GPU, where oxray
/// compiles with `--fmad=false`).
const FLAGS: [&str; 7] = [
    "-std=c++17",
    "-O2",
    "-fPIC",
    "-shared",
    "-ffp-contract=off",
    "-fno-strict-aliasing",
    "-Wl,-z,defs",
];

pub(crate) fn kind_of(name: &str) -> Option<ProgramKind> {
    use ProgramKind::*;
    [
        RayGen,
        Intersection,
        AnyHit,
        ClosestHit,
        Miss,
        Exception,
        DirectCallable,
        ContinuationCallable,
    ]
    .into_iter()
    .find(|k| name.starts_with(k.prefix()) && name.len() > k.prefix().len())
}

/// The unit's source: header, modules (each once), definitions of variables the modules
/// declare `extern "C"`, the launch-parameter accessors, and a wrapper per entry point.
pub(crate) fn unit_source(modules: &[CxxModule], params: Option<&str>) -> String {
    let mut s = String::from("#line 1 \"optix_types.h\"\n");
    s.push_str(oxray_core::source::OPTIX_TYPES_HEADER);
    s.push_str("#line 1 \"oxray_device_cpu.h\"\n");
    s.push_str(DEVICE_HEADER_CPU);
    let mut externs: Vec<String> = Vec::new();
    for (i, m) in modules.iter().enumerate() {
        s.push_str(&format!("#line 1 \"module{i}.cu\"\n"));
        s.push_str(&oxray_core::source::strip_optix_includes(m.source()));
        s.push('\n');
        for v in oxray_core::source::extern_c_variables(m.source()) {
            if !externs.contains(&v) {
                externs.push(v);
            }
        }
    }
    s.push_str("#line 1 \"oxray_cpu_unit.cpp\"\n");
    for v in &externs {
        // CUDA takes `extern "C" __constant__ T v;` for the definition; here it is defined once.
        s.push_str(&format!("extern \"C\" {{ decltype({v}) {v}; }}\n"));
    }
    if let Some(p) = params {
        s.push_str(&format!(
            "extern \"C\" unsigned long long __oxray_params_size() {{ return sizeof({p}); }}\n\
             extern \"C\" void* __oxray_params_address() {{ return (void*)&{p}; }}\n"
        ));
    }
    for m in modules {
        for name in m.entry_names() {
            let Some(kind) = kind_of(name) else { continue };
            let callable = matches!(
                kind,
                ProgramKind::DirectCallable | ProgramKind::ContinuationCallable
            );
            let (params, call) = if callable {
                (
                    ", void* args, void* ret, const char* sig",
                    format!("r = __oxray_Invoke<decltype(&{name})>::run(&{name}, args, ret, sig);"),
                )
            } else {
                ("", format!("{name}();"))
            };
            s.push_str(&format!(
                "extern \"C\" unsigned int __oxray_entry_{name}(__oxray_Frame* f{params}) {{\n\
                 \x20   __oxray_Frame* saved = __oxray_frame;\n\
                 \x20   __oxray_frame = f;\n\
                 \x20   unsigned int r = 0u;\n\
                 \x20   try {{ {call} }} catch (const __oxray_Unwind&) {{ r = 1u; }} \
                 catch (...) {{ f->pending = __OXRAY_PENDING_ESCAPED; r = 1u; }}\n\
                 \x20   __oxray_frame = saved;\n\
                 \x20   return r;\n}}\n"
            ));
        }
    }
    s
}

/// The compiler: `$CXX`, or `c++`.
fn compiler() -> String {
    std::env::var("CXX")
        .ok()
        .filter(|c| !c.trim().is_empty())
        .unwrap_or_else(|| "c++".to_string())
}

/// The compiler's `--version` line, part of the cache key (asked once per process).
fn compiler_identity(cxx: &str) -> Result<String, CxxError> {
    static IDS: OnceLock<Mutex<HashMap<String, String>>> = OnceLock::new();
    let ids = IDS.get_or_init(Default::default);
    if let Some(id) = ids.lock().unwrap_or_else(|e| e.into_inner()).get(cxx) {
        return Ok(id.clone());
    }
    let out = Command::new(cxx)
        .arg("--version")
        .output()
        .map_err(|e| CxxError::NoCompiler {
            compiler: cxx.to_string(),
            reason: e.to_string(),
        })?;
    let id = String::from_utf8_lossy(&out.stdout)
        .lines()
        .next()
        .unwrap_or("")
        .to_string();
    ids.lock()
        .unwrap_or_else(|e| e.into_inner())
        .insert(cxx.to_string(), id.clone());
    Ok(id)
}

pub use oxray_core::cache::cache_dir;

/// Compiles `source` into a shared library in the cache (or finds it there) and returns its
/// path. A library is written under a temporary name and renamed into place, so a reader never
/// sees half of one.
pub(crate) fn compile(source: &str) -> Result<PathBuf, CxxError> {
    let cxx = compiler();
    let id = compiler_identity(&cxx)?;
    let k = oxray_core::cache::content_key(&[&cxx, &id, &FLAGS.join(" "), source]);
    let dir = cache_dir();
    let lib = oxray_core::cache::entry_path(&dir, "cpu", k, "so");
    if lib.is_file() {
        return Ok(lib);
    }
    std::fs::create_dir_all(&dir).map_err(|e| CxxError::Cache {
        path: dir.clone(),
        reason: e.to_string(),
    })?;
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let tmp = format!("tmp-{}-{n}-{k:016x}", std::process::id());
    let src_path = dir.join(format!("{tmp}.cpp"));
    let tmp_lib = dir.join(format!("{tmp}.so"));
    let cache_err = |path: &Path, e: std::io::Error| CxxError::Cache {
        path: path.to_path_buf(),
        reason: e.to_string(),
    };
    std::fs::write(&src_path, source).map_err(|e| cache_err(&src_path, e))?;
    let out = Command::new(&cxx)
        .args(FLAGS)
        .arg("-x")
        .arg("c++")
        .arg(&src_path)
        .arg("-o")
        .arg(&tmp_lib)
        .output();
    let _ = std::fs::remove_file(&src_path);
    let out = out.map_err(|e| CxxError::NoCompiler {
        compiler: cxx.clone(),
        reason: e.to_string(),
    })?;
    if !out.status.success() {
        let _ = std::fs::remove_file(&tmp_lib);
        let log = String::from_utf8_lossy(&out.stderr).into_owned();
        return Err(CxxError::Compile {
            gpu_only: gpu_only_intrinsics(&log),
            log,
        });
    }
    std::fs::rename(&tmp_lib, &lib).map_err(|e| cache_err(&lib, e))?;
    Ok(lib)
}

/// The GPU-only intrinsics a compiler log complains about (the header's messages name them).
fn gpu_only_intrinsics(log: &str) -> Vec<String> {
    let mut found = Vec::new();
    for line in log.lines() {
        if let Some(i) = line.find(" exists only on a GPU") {
            let what = line[..i]
                .rsplit(['\'', '"', ':'])
                .next()
                .unwrap_or("")
                .trim()
                .to_string();
            if !what.is_empty() && !found.contains(&what) {
                found.push(what);
            }
        }
    }
    found
}

/// A loaded unit: its library, the entry points of its modules, the launch parameters, and the
/// lock that makes its launches one at a time (they share the library's globals).
pub(crate) struct Loaded {
    _lib: libloading::Library,
    /// Per module (by uid): its entries, in the module's order.
    pub entries: Vec<(u64, Vec<Option<EntryFn>>)>,
    pub params: Option<(*mut u8, usize)>,
    /// Shared by every unit loaded from the same library.
    pub launch_lock: Arc<Mutex<()>>,
}

// SAFETY: the raw pointer is the address of the library's parameter variable, written only
// under `launch_lock`; function pointers and the library handle may be used from any thread.
unsafe impl Send for Loaded {}
// SAFETY: as above.
unsafe impl Sync for Loaded {}

impl Loaded {
    pub fn entry(&self, module: u64, index: usize) -> Option<EntryFn> {
        self.entries
            .iter()
            .find(|(m, _)| *m == module)
            .and_then(|(_, e)| e.get(index).copied().flatten())
    }
}

/// Compiles (or finds) and loads the unit of `modules`. Units loaded from one library share
/// one `Loaded` (the dynamic loader shares the library's globals).
pub(crate) fn load(modules: &[CxxModule], params: Option<&str>) -> Result<Arc<Loaded>, CxxError> {
    let source = unit_source(modules, params);
    let path = compile(&source)?;
    type Units = HashMap<(PathBuf, Vec<u64>), Weak<Loaded>>;
    static LOADED: OnceLock<Mutex<Units>> = OnceLock::new();
    let uids: Vec<u64> = modules.iter().map(|m| m.uid()).collect();
    let map = LOADED.get_or_init(Default::default);
    let mut map = map.lock().unwrap_or_else(|e| e.into_inner());
    map.retain(|_, w| w.strong_count() > 0);
    if let Some(l) = map
        .get(&(path.clone(), uids.clone()))
        .and_then(Weak::upgrade)
    {
        return Ok(l);
    }
    // SAFETY: the library is the one just compiled from this unit; loading it runs the static
    // initialisers of the user's modules, as creating a module does on any device.
    let lib = unsafe { libloading::Library::new(&path) }.map_err(|e| CxxError::Load {
        path: path.clone(),
        reason: e.to_string(),
    })?;
    let load_err = |what: &str| CxxError::Load {
        path: path.clone(),
        reason: what.to_string(),
    };
    // SAFETY: `__oxray_frame_layout` is defined by the header with this type.
    let layout_fn = unsafe { lib.get::<unsafe extern "C" fn(*mut u64)>(b"__oxray_frame_layout\0") }
        .map_err(|e| load_err(&e.to_string()))?;
    let mut layout = [0u64; 7];
    // SAFETY: the function writes 7 words.
    unsafe { layout_fn(layout.as_mut_ptr()) };
    if layout != frame_layout() {
        return Err(load_err(
            "the compiled frame does not match the runtime's (another header version?)",
        ));
    }
    let mut entries = Vec::new();
    for m in modules {
        let mut es = Vec::new();
        for name in m.entry_names() {
            let sym = format!("__oxray_entry_{name}\0");
            let callable = matches!(
                kind_of(name),
                Some(ProgramKind::DirectCallable | ProgramKind::ContinuationCallable)
            );
            // SAFETY: the unit defines each wrapper with exactly the type it is read as here
            // (callables take the call's arguments, every other kind only the frame).
            let e = unsafe {
                if callable {
                    lib.get::<CallableEntry>(sym.as_bytes())
                        .ok()
                        .map(|f| EntryFn::Callable(*f))
                } else {
                    lib.get::<ProgramEntry>(sym.as_bytes())
                        .ok()
                        .map(|f| EntryFn::Program(*f))
                }
            };
            es.push(e);
        }
        entries.push((m.uid(), es));
    }
    let params = match params {
        None => None,
        Some(_) => {
            // SAFETY: both accessors are generated with these types when `params` is named.
            unsafe {
                let size = lib
                    .get::<unsafe extern "C" fn() -> u64>(b"__oxray_params_size\0")
                    .map_err(|e| load_err(&e.to_string()))?;
                let addr = lib
                    .get::<unsafe extern "C" fn() -> *mut u8>(b"__oxray_params_address\0")
                    .map_err(|e| load_err(&e.to_string()))?;
                Some((addr(), size() as usize))
            }
        }
    };
    static LOCKS: OnceLock<Mutex<HashMap<PathBuf, Weak<Mutex<()>>>>> = OnceLock::new();
    let launch_lock = {
        let mut locks = LOCKS
            .get_or_init(Default::default)
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        locks.retain(|_, w| w.strong_count() > 0);
        match locks.get(&path).and_then(Weak::upgrade) {
            Some(l) => l,
            None => {
                let l = Arc::new(Mutex::new(()));
                locks.insert(path.clone(), Arc::downgrade(&l));
                l
            }
        }
    };
    let loaded = Arc::new(Loaded {
        _lib: lib,
        entries,
        params,
        launch_lock,
    });
    map.insert((path, uids), Arc::downgrade(&loaded));
    Ok(loaded)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gpu_only_intrinsics_are_named_from_the_log() {
        let log = "m.cu:3:5: error: call to '__syncthreads' declared with attribute error: \
                   __syncthreads exists only on a GPU: this program cannot run";
        assert_eq!(gpu_only_intrinsics(log), ["__syncthreads"]);
    }
}
