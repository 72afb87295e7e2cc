//! Robustness of the scene and mesh loaders against malformed files: a deterministic, seeded
//! mutation fuzzer over the fixtures in `tests/data` (byte flips, truncations, inserted garbage,
//! and JSON value mutations such as huge counts, negative or huge indices, wrong component types
//! and node cycles), plus a regression test for every crash found or guarded against.
//!
//! Every load must return `Ok` or a one-line `Err`; never panic or hang. A counting allocator
//! refuses any single allocation over [`ALLOC_CAP`], so a file that claims billions of elements
//! in a tiny buffer aborts the test instead of being silently satisfied.

use oxray_scene::mesh::Mesh;
use oxray_scene::SceneDesc;
use std::alloc::{GlobalAlloc, Layout, System};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Largest single allocation any load may make. Textures may take up to 256 MiB (an 8K x 8K
/// RGBA8 image); anything beyond that comes from trusting a corrupt count.
const ALLOC_CAP: usize = 512 << 20;

struct Capped;

// SAFETY: forwards to the system allocator; only refuses oversized requests by returning null,
// which the allocation APIs turn into `handle_alloc_error` (an abort naming the size).
unsafe impl GlobalAlloc for Capped {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if layout.size() > ALLOC_CAP {
            return std::ptr::null_mut();
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if layout.size() > ALLOC_CAP {
            return std::ptr::null_mut();
        }
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > ALLOC_CAP {
            return std::ptr::null_mut();
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOC: Capped = Capped;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn read(name: &str) -> Vec<u8> {
    std::fs::read(data(name)).unwrap()
}

/// A fresh directory for one test's files.
fn tmp_dir(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("oxray-fuzz-{}-{test}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// xorshift64*: small, deterministic, good enough to pick mutations.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
    fn pick<'a, T>(&mut self, items: &'a [T]) -> &'a T {
        &items[self.below(items.len())]
    }
}

/// Values that stress counts, offsets, indices, enums and floats.
const INTERESTING: &[&str] = &[
    "0",
    "-1",
    "1",
    "2",
    "3",
    "4",
    "7",
    "12",
    "255",
    "256",
    "65535",
    "65536",
    "2147483647",
    "2147483648",
    "4294967295",
    "4294967296",
    "18446744073709551615",
    "1e30",
    "-1e30",
    "0.5",
    "1e-30",
    "5120",
    "5121",
    "5122",
    "5123",
    "5125",
    "5126",
    "33071",
    "33648",
    "10497",
    "9007199254740993",
    "-2147483648",
    "99999999999999999999",
];

/// Strings that swap one glTF enumeration value for another.
const ENUMS: &[&str] = &[
    "\"SCALAR\"",
    "\"VEC2\"",
    "\"VEC3\"",
    "\"VEC4\"",
    "\"MAT4\"",
    "\"MASK\"",
    "\"BLEND\"",
    "\"OPAQUE\"",
    "\"perspective\"",
    "\"orthographic\"",
    "\"\"",
];

/// Byte ranges of the numbers in a text.
fn numbers(text: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < text.len() {
        let c = text[i];
        let starts =
            c.is_ascii_digit() || (c == b'-' && text.get(i + 1).is_some_and(u8::is_ascii_digit));
        // Digits inside words (TEXCOORD_0, base64) are not numbers.
        let after_word = i > 0 && (text[i - 1].is_ascii_alphanumeric() || text[i - 1] == b'_');
        if starts && !after_word {
            let start = i;
            i += 1;
            while i < text.len() && (text[i].is_ascii_digit() || b".eE+-".contains(&text[i])) {
                i += 1;
            }
            out.push((start, i));
        } else {
            i += 1;
        }
    }
    out
}

/// Byte ranges of the quoted enumeration values in a text.
fn enum_values(text: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    for e in ENUMS.iter().filter(|e| e.len() > 2) {
        let e = e.as_bytes();
        for i in 0..text.len().saturating_sub(e.len() - 1) {
            if &text[i..i + e.len()] == e {
                out.push((i, i + e.len()));
            }
        }
    }
    out
}

fn splice(b: &[u8], (s, e): (usize, usize), with: &[u8]) -> Vec<u8> {
    [&b[..s], with, &b[e..]].concat()
}

/// One random byte-level mutation.
fn mutate_bytes(rng: &mut Rng, b: &[u8]) -> Vec<u8> {
    let mut b = b.to_vec();
    if b.is_empty() {
        return vec![rng.next() as u8];
    }
    let at = rng.below(b.len());
    match rng.below(7) {
        0 => b[at] ^= 1 << rng.below(8),
        1 => b[at] = *rng.pick(&[0u8, 0xff, 0x7f, 0x80, b'"', b'{', b'-', b'9']),
        2 => b.truncate(at),
        3 => {
            let n = 1 + rng.below(16);
            let garbage: Vec<u8> = (0..n).map(|_| rng.next() as u8).collect();
            b.splice(at..at, garbage);
        }
        4 => {
            let end = (at + 1 + rng.below(32)).min(b.len());
            b.drain(at..end);
        }
        5 => {
            let end = (at + 1 + rng.below(64)).min(b.len());
            let copy = b[at..end].to_vec();
            let to = rng.below(b.len());
            b.splice(to..to, copy);
        }
        _ => {
            // A little-endian u32 field (a GLB length, a PLY count or index) set to an extreme.
            let v: u32 = *rng.pick(&[0, 1, 11, 12, 0x7fff_ffff, 0x8000_0000, u32::MAX]);
            for (k, byte) in v.to_le_bytes().iter().enumerate() {
                if let Some(x) = b.get_mut(at + k) {
                    *x = *byte;
                }
            }
        }
    }
    b
}

/// One random mutation that keeps text text: a number or an enumeration value replaced, or a
/// `children` reference (possibly a cycle) injected.
fn mutate_text(rng: &mut Rng, b: &[u8]) -> Vec<u8> {
    match rng.below(6) {
        0..=2 => {
            let nums = numbers(b);
            if nums.is_empty() {
                return mutate_bytes(rng, b);
            }
            let r = *rng.pick(&nums);
            splice(b, r, rng.pick(INTERESTING).as_bytes())
        }
        3 => {
            let vals = enum_values(b);
            if vals.is_empty() {
                return mutate_bytes(rng, b);
            }
            let r = *rng.pick(&vals);
            splice(b, r, rng.pick(ENUMS).as_bytes())
        }
        4 => {
            // Make some object point at a node: on a node this may close a cycle or give a node a
            // second parent; elsewhere it is an unknown field.
            let starts: Vec<usize> = (0..b.len()).filter(|&i| b[i] == b'{').skip(1).collect();
            if starts.is_empty() {
                return mutate_bytes(rng, b);
            }
            let at = *rng.pick(&starts) + 1;
            let child = rng.below(8);
            let inject = format!("\"children\": [{child}], ");
            splice(b, (at, at), inject.as_bytes())
        }
        _ => mutate_bytes(rng, b),
    }
}

/// Applies one to three mutations.
fn mutate(rng: &mut Rng, b: &[u8], text: bool) -> Vec<u8> {
    let mut out = b.to_vec();
    for _ in 0..1 + rng.below(3) {
        out = if text && rng.below(4) != 0 {
            mutate_text(rng, &out)
        } else {
            mutate_bytes(rng, &out)
        };
    }
    out
}

/// Splits a GLB into (JSON, rest after the JSON chunk) if its first chunk is JSON.
fn glb_json(b: &[u8]) -> Option<(&[u8], &[u8])> {
    let len = u32::from_le_bytes(b.get(12..16)?.try_into().ok()?) as usize;
    let json = b.get(20..20 + len)?;
    Some((json, &b[20 + len..]))
}

/// Rebuilds a GLB around a mutated JSON chunk, with consistent lengths, so that the mutation
/// reaches the JSON checks instead of stopping at the container.
fn glb_with_json(json: &[u8], rest: &[u8]) -> Vec<u8> {
    let mut json = json.to_vec();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let total = 12 + 8 + json.len() + rest.len();
    let mut out = Vec::with_capacity(total);
    out.extend(b"glTF");
    out.extend(2u32.to_le_bytes());
    out.extend((total as u32).to_le_bytes());
    out.extend((json.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(&json);
    out.extend(rest);
    out
}

/// The case being run, for the watchdog: its start (ms since `EPOCH`, 0 when idle) and label.
static CASE_START: AtomicU64 = AtomicU64::new(0);
static CASE_LABEL: Mutex<String> = Mutex::new(String::new());

/// Longest a single load may take before the run is declared hung.
const HANG: Duration = Duration::from_secs(20);

fn start_watchdog(epoch: Instant) {
    std::thread::spawn(move || loop {
        std::thread::sleep(Duration::from_millis(200));
        let start = CASE_START.load(Ordering::SeqCst);
        if start != 0 && epoch.elapsed().as_millis() as u64 > start + HANG.as_millis() as u64 {
            let label = CASE_LABEL.lock().map(|l| l.clone()).unwrap_or_default();
            eprintln!("loader hung for over {HANG:?} on {label}");
            std::process::abort();
        }
    });
}

/// Scene loads that succeeded: a fuzzer whose every input is rejected at the first check would
/// prove little, so the run reports how many mutated files still load.
static LOADED: AtomicU64 = AtomicU64::new(0);

/// Loads `path` with the scene loader and, for formats it supports, the mesh loader. Returns a
/// description of the first problem: a panic, or an error message that is not one line.
fn check(path: &Path) -> Option<String> {
    let scene = catch_unwind(AssertUnwindSafe(|| SceneDesc::load(path)));
    if matches!(scene, Ok(Ok(_))) {
        LOADED.fetch_add(1, Ordering::Relaxed);
    }
    match scene {
        Err(_) => return Some("SceneDesc::load panicked".into()),
        Ok(Err(e)) if e.to_string().lines().count() != 1 => {
            return Some(format!("SceneDesc::load error is not one line: {e}"))
        }
        Ok(Ok(s)) => {
            if let Err(e) = s.validate() {
                return Some(format!("SceneDesc::load returned an invalid scene: {e}"));
            }
        }
        Ok(Err(_)) => {}
    }
    let mesh = catch_unwind(AssertUnwindSafe(|| Mesh::load(path)));
    match mesh {
        Err(_) => Some("Mesh::load panicked".into()),
        Ok(Err(e)) if e.to_string().lines().count() != 1 => {
            Some(format!("Mesh::load error is not one line: {e}"))
        }
        Ok(Ok(m)) => {
            let n = m.positions.len();
            m.triangles
                .iter()
                .any(|t| t.iter().any(|&i| i as usize >= n))
                .then(|| "Mesh::load returned an index out of range".into())
        }
        Ok(Err(_)) => None,
    }
}

/// A fuzzing target: the file written each case, and how to mutate it.
struct Target {
    /// File name in the case directory (its extension picks the loader).
    file: &'static str,
    /// The fixture it starts from.
    fixture: &'static str,
    /// Whether text mutations apply.
    text: bool,
    /// Whether this is a GLB whose JSON chunk is mutated and repacked.
    glb: bool,
    /// Cases to run.
    cases: u64,
}

#[test]
fn mutated_fixtures_never_panic_hang_or_over_allocate() {
    let epoch = Instant::now();
    start_watchdog(epoch);
    let dir = tmp_dir("cases");
    std::fs::copy(data("tex2x2.png"), dir.join("tex2x2.png")).unwrap();
    std::fs::copy(data("materials.mtl"), dir.join("materials.mtl")).unwrap();
    let obj = String::from_utf8(read("materials.obj")).unwrap();
    let mtl = String::from_utf8(read("materials.mtl")).unwrap();
    let targets = [
        Target {
            file: "triangle.gltf",
            fixture: "triangle.gltf",
            text: true,
            glb: false,
            cases: 1500,
        },
        Target {
            file: "hierarchy.gltf",
            fixture: "hierarchy.gltf",
            text: true,
            glb: false,
            cases: 2000,
        },
        Target {
            file: "extensions.gltf",
            fixture: "extensions.gltf",
            text: true,
            glb: false,
            cases: 1200,
        },
        Target {
            file: "triangle.glb",
            fixture: "triangle.glb",
            text: false,
            glb: true,
            cases: 1500,
        },
        Target {
            file: "materials.obj",
            fixture: "materials.obj",
            text: true,
            glb: false,
            cases: 800,
        },
        Target {
            file: "materials.mtl",
            fixture: "materials.mtl",
            text: true,
            glb: false,
            cases: 500,
        },
        Target {
            file: "tex2x2.png",
            fixture: "tex2x2.png",
            text: false,
            glb: false,
            cases: 400,
        },
        // Seeds of the hostile and real files of issue 12: a palette PNG (bad PLTE lengths
        // crashed the decoder), a PNG header declaring 16384 x 16384 (a decompression bomb),
        // PLY elements without properties and huge counts (a hang), quantized and
        // meshopt-compressed glTF.
        Target {
            file: "palette.png",
            fixture: "palette.png",
            text: false,
            glb: false,
            cases: 300,
        },
        Target {
            file: "huge.png",
            fixture: "huge.png",
            text: false,
            glb: false,
            cases: 150,
        },
        Target {
            file: "elements.ply",
            fixture: "elements.ply",
            text: true,
            glb: false,
            cases: 400,
        },
        Target {
            file: "quantized.gltf",
            fixture: "quantized.gltf",
            text: true,
            glb: false,
            cases: 600,
        },
        Target {
            file: "meshopt.gltf",
            fixture: "meshopt.gltf",
            text: true,
            glb: false,
            cases: 300,
        },
        // Vertex colours and a second texture coordinate set.
        Target {
            file: "colors.gltf",
            fixture: "colors.gltf",
            text: true,
            glb: false,
            cases: 300,
        },
        Target {
            file: "texcoord1.gltf",
            fixture: "texcoord1.gltf",
            text: true,
            glb: false,
            cases: 300,
        },
        Target {
            file: "quad_ascii.ply",
            fixture: "quad_ascii.ply",
            text: true,
            glb: false,
            cases: 600,
        },
        Target {
            file: "strip_binary.ply",
            fixture: "strip_binary.ply",
            text: false,
            glb: false,
            cases: 600,
        },
    ];
    let mut failures = Vec::new();
    let mut total = 0;
    let mut slowest = (Duration::ZERO, String::new());
    for (ti, t) in targets.iter().enumerate() {
        let original = read(t.fixture);
        for case in 0..t.cases {
            // splitmix64 of (target, case): distinct, well-mixed, never-zero seeds.
            let mut z = ((ti as u64) << 32 | case)
                .wrapping_add(1)
                .wrapping_mul(0x9e37_79b9_7f4a_7c15);
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            let mut rng = Rng((z ^ (z >> 31)) | 1);
            let bytes = if t.glb && rng.below(2) == 0 {
                match glb_json(&original) {
                    Some((json, rest)) => glb_with_json(&mutate(&mut rng, json, true), rest),
                    None => mutate(&mut rng, &original, false),
                }
            } else {
                mutate(&mut rng, &original, t.text)
            };
            // Every case gets new file names: creating a file is much faster than truncating
            // one on some file systems. A mutated MTL or texture is loaded through an OBJ that
            // refers to it.
            let stem = format!("t{ti}c{case}");
            let ext = t.file.rsplit('.').next().unwrap();
            let mutated = format!("{stem}.{ext}");
            let mut files = vec![(mutated.clone(), bytes.clone())];
            match t.file {
                "materials.mtl" => files.push((
                    format!("{stem}.obj"),
                    obj.replace("materials.mtl", &mutated).into_bytes(),
                )),
                f if f.ends_with(".png") => {
                    files.push((
                        format!("{stem}.mtl"),
                        mtl.replace("tex2x2.png", &mutated).into_bytes(),
                    ));
                    files.push((
                        format!("{stem}.obj"),
                        obj.replace("materials.mtl", &format!("{stem}.mtl"))
                            .into_bytes(),
                    ));
                }
                _ => {}
            }
            for (name, b) in &files {
                std::fs::write(dir.join(name), b).unwrap();
            }
            let load_path = dir.join(&files.last().unwrap().0);
            *CASE_LABEL.lock().unwrap() = format!("{} case {case}", t.file);
            CASE_START.store(epoch.elapsed().as_millis() as u64 + 1, Ordering::SeqCst);
            let case_start = Instant::now();
            let problem = check(&load_path);
            CASE_START.store(0, Ordering::SeqCst);
            let took = case_start.elapsed();
            if took > slowest.0 {
                slowest = (took, format!("{} case {case}", t.file));
            }
            total += 1;
            if let Some(p) = problem {
                // The case's files stay in the directory for minimising into a regression test.
                failures.push(format!(
                    "{} case {case}: {p} (input: {})",
                    t.file,
                    dir.join(&mutated).display()
                ));
            }
        }
        println!(
            "{}: {} cases, {} loaded, {:?} so far",
            t.file,
            t.cases,
            LOADED.swap(0, Ordering::Relaxed),
            epoch.elapsed()
        );
    }
    println!(
        "{total} mutated files loaded in {:?}; slowest: {} ({:?})",
        epoch.elapsed(),
        slowest.1,
        slowest.0
    );
    assert!(
        failures.is_empty(),
        "{} failures:\n{}",
        failures.len(),
        failures.join("\n")
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// Writes `files` into a fresh directory and checks the first one loads without a crash.
fn regression(test: &str, files: &[(&str, &[u8])]) -> PathBuf {
    let dir = tmp_dir(test);
    for (name, bytes) in files {
        std::fs::write(dir.join(name), bytes).unwrap();
    }
    let path = dir.join(files[0].0);
    if let Some(problem) = check(&path) {
        panic!("{test}: {problem}");
    }
    path
}

fn expect_error(path: &Path, needle: &str) {
    let err = SceneDesc::load(path)
        .expect_err("the file is malformed")
        .to_string();
    assert!(err.contains(needle), "{err}");
}

const TRIANGLE_BUFFER: &str =
    "\"buffers\":[{\"byteLength\":44,\"uri\":\"data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAAAAABAAIAAAA=\"}]";

/// A minimal glTF with one triangle, with `accessors` and `extra` spliced in.
fn gltf_with(accessors: &str, extra: &str) -> String {
    format!(
        "{{\"asset\":{{\"version\":\"2.0\"}},\"scenes\":[{{\"nodes\":[0]}}],\"nodes\":[{{\"mesh\":0}}],\
         \"meshes\":[{{\"primitives\":[{{\"attributes\":{{\"POSITION\":0}},\"indices\":1}}]}}],\
         \"accessors\":[{accessors}],\
         \"bufferViews\":[{{\"buffer\":0,\"byteLength\":36}},{{\"buffer\":0,\"byteOffset\":36,\"byteLength\":6}}],\
         {TRIANGLE_BUFFER}{extra}}}"
    )
}

const POSITIONS: &str = "{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\"}";
const INDICES: &str = "{\"bufferView\":1,\"componentType\":5123,\"count\":3,\"type\":\"SCALAR\"}";

/// Sparse values: vertex 0 (from the u16 index 0 in view 1) becomes the third vertex, (0, 1, 0).
const SPARSE: &str =
    "\"sparse\":{\"count\":1,\"indices\":{\"bufferView\":1,\"componentType\":5123},\
                      \"values\":{\"bufferView\":0,\"byteOffset\":24}}";

#[test]
fn sparse_accessor_overrides_base_values() {
    let positions = POSITIONS.replace("}", &format!(",{SPARSE}}}"));
    let p = regression(
        "sparse",
        &[(
            "a.gltf",
            gltf_with(&format!("{positions},{INDICES}"), "").as_bytes(),
        )],
    );
    let s = SceneDesc::load(&p).unwrap();
    assert_eq!(
        s.meshes[0].primitives[0].positions,
        vec![[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    );
    // Without a base buffer view, the other vertices are zeros.
    let positions = format!("{{\"componentType\":5126,\"count\":3,\"type\":\"VEC3\",{SPARSE}}}");
    let p = regression(
        "sparse-zeros",
        &[(
            "a.gltf",
            gltf_with(&format!("{positions},{INDICES}"), "").as_bytes(),
        )],
    );
    let s = SceneDesc::load(&p).unwrap();
    assert_eq!(
        s.meshes[0].primitives[0].positions,
        vec![[0.0, 1.0, 0.0], [0.0; 3], [0.0; 3]]
    );
}

#[test]
fn minimal_gltf_fixture_loads() {
    // The base of the regression inputs below must itself be valid, or they prove nothing.
    let p = regression(
        "minimal",
        &[(
            "a.gltf",
            gltf_with(&format!("{POSITIONS},{INDICES}"), "").as_bytes(),
        )],
    );
    let s = SceneDesc::load(&p).unwrap();
    assert_eq!(s.meshes[0].primitives[0].triangles, vec![[0, 1, 2]]);
}

/// The `gltf` crate's validation indexes the accessor list with the POSITION index before
/// checking it.
#[test]
fn regression_position_accessor_index_beyond_accessors() {
    let text = gltf_with(&format!("{POSITIONS},{INDICES}"), "")
        .replace("\"POSITION\":0", "\"POSITION\":7");
    let p = regression("position-index", &[("a.gltf", text.as_bytes())]);
    expect_error(&p, "missing accessor 7");
}

/// The `gltf` crate's GLB reader subtracts the header size from the declared length unchecked.
#[test]
fn regression_glb_length_shorter_than_header() {
    let mut glb = b"glTF".to_vec();
    glb.extend(2u32.to_le_bytes());
    glb.extend(4u32.to_le_bytes());
    glb.extend([0u8; 8]);
    let p = regression("glb-length", &[("a.glb", &glb)]);
    expect_error(&p, "bad GLB length 4");
}

/// The `gltf` crate's accessor reader computes `count - 1` unchecked.
#[test]
fn regression_accessor_with_zero_count() {
    let text = gltf_with(
        &format!(
            "{POSITIONS},{}",
            INDICES.replace("\"count\":3", "\"count\":0")
        ),
        "",
    );
    let p = regression("zero-count", &[("a.gltf", text.as_bytes())]);
    expect_error(&p, "accessor 1 has no elements");
}

/// The `gltf` crate's reader only debug-asserts that the element type matches the accessor.
#[test]
fn regression_positions_with_integer_components() {
    let text = gltf_with(
        &format!("{},{INDICES}", POSITIONS.replace("5126", "5121")),
        "",
    );
    let p = regression("int-positions", &[("a.gltf", text.as_bytes())]);
    expect_error(&p, "accessor 0");
}

/// A count of 2^31 in a 36-byte view must fail before anything is allocated for it.
#[test]
fn regression_huge_count_in_tiny_buffer() {
    let text = gltf_with(
        &format!(
            "{},{INDICES}",
            POSITIONS.replace("\"count\":3", "\"count\":2147483648")
        ),
        "",
    );
    let p = regression("huge-count", &[("a.gltf", text.as_bytes())]);
    expect_error(&p, "do not fit in buffer view 0");
    // A sparse accessor without a buffer view starts as zeros, so its count is capped instead.
    let text = gltf_with(
        &format!(
            "{{\"componentType\":5126,\"count\":2147483648,\"type\":\"VEC3\",{SPARSE}}},{INDICES}"
        ),
        "",
    );
    let p = regression("huge-zero-count", &[("a.gltf", text.as_bytes())]);
    expect_error(&p, "without a buffer view");
}

/// byteOffset plus the element span overflowing `usize` must be caught, not wrap.
#[test]
fn regression_byte_offset_overflow() {
    let text = gltf_with(
        &format!(
            "{},{INDICES}",
            POSITIONS.replace(
                "\"count\":3",
                "\"count\":3,\"byteOffset\":18446744073709551615"
            )
        ),
        "",
    );
    let p = regression("offset-overflow", &[("a.gltf", text.as_bytes())]);
    assert!(SceneDesc::load(&p).is_err());
}

/// The `gltf` crate unwraps an image's MIME type when it has a buffer view.
#[test]
fn regression_image_buffer_view_without_mime_type() {
    let extra = ",\"materials\":[{\"pbrMetallicRoughness\":{\"baseColorTexture\":{\"index\":0}}}],\
                 \"textures\":[{\"source\":0}],\"images\":[{\"bufferView\":0}]";
    let text = gltf_with(&format!("{POSITIONS},{INDICES}"), extra);
    let p = regression("image-no-mime", &[("a.gltf", text.as_bytes())]);
    let s = SceneDesc::load(&p).unwrap();
    assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
}

/// A node that is its own child, and two nodes that are each other's child.
#[test]
fn regression_node_cycles() {
    let text = gltf_with(&format!("{POSITIONS},{INDICES}"), "")
        .replace("{\"mesh\":0}", "{\"mesh\":0,\"children\":[0]}");
    let p = regression("self-cycle", &[("a.gltf", text.as_bytes())]);
    expect_error(&p, "node 0 appears twice");
    // Without scenes, nodes in a pure cycle are no root and are never reached.
    let text = gltf_with(&format!("{POSITIONS},{INDICES}"), "")
        .replace("\"scenes\":[{\"nodes\":[0]}],", "")
        .replace(
            "{\"mesh\":0}",
            "{\"mesh\":0,\"children\":[1]},{\"children\":[0]}",
        );
    let p = regression("cycle-no-scene", &[("a.gltf", text.as_bytes())]);
    assert_eq!(
        SceneDesc::load(&p).unwrap_err().to_string().lines().count(),
        1
    );
}

/// A node hierarchy 100 000 deep is walked without recursion.
#[test]
fn regression_deep_node_chain() {
    let n = 100_000;
    let nodes: Vec<String> = (0..n)
        .map(|i| {
            if i + 1 < n {
                format!("{{\"children\":[{}]}}", i + 1)
            } else {
                "{\"mesh\":0}".into()
            }
        })
        .collect();
    let text = gltf_with(&format!("{POSITIONS},{INDICES}"), "").replace(
        "\"nodes\":[{\"mesh\":0}]",
        &format!("\"nodes\":[{}]", nodes.join(",")),
    );
    let p = regression("deep-chain", &[("a.gltf", text.as_bytes())]);
    assert_eq!(SceneDesc::load(&p).unwrap().instances.len(), 1);
}

/// tobj panics on an MTL colour with fewer than three numbers (`Kd` alone here).
#[test]
fn regression_mtl_colour_without_numbers() {
    let p = regression(
        "mtl-kd",
        &[
            (
                "a.obj",
                b"mtllib a.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m\nf 1 2 3\n",
            ),
            ("a.mtl", b"newmtl m\nKd\n"),
        ],
    );
    let s = SceneDesc::load(&p).unwrap();
    assert_eq!(s.triangle_count(), 1);
    assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
}

/// tobj turns a relative index reaching before the first element into a huge offset and
/// overflows computing with it (found by the fuzzer as `4/-2147483648/1`; `-3` with one texture
/// coordinate is enough), and overflows the same way on huge positive indices.
#[test]
fn regression_obj_face_index_out_of_range() {
    for face in [
        "f 1/1 2/1 3/-3",
        "f 1//-2 2//1 3//1",
        "f 1/9223372036854775807 2 3",
        "f -9223372036854775808 2 3",
    ] {
        let obj = format!("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n{face}\n");
        let p = regression("obj-index", &[("a.obj", obj.as_bytes())]);
        let err = SceneDesc::load(&p).unwrap_err().to_string();
        assert!(err.contains("line 6: index"), "{err}");
        let err = Mesh::load(&p).unwrap_err().to_string();
        assert!(err.contains("line 6: index"), "{err}");
    }
    // Relative indices within range still load.
    let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf -3/-1 -2/-1 -1/-1\n";
    let p = regression("obj-relative", &[("a.obj", obj.as_bytes())]);
    assert_eq!(SceneDesc::load(&p).unwrap().triangle_count(), 1);
}

#[test]
fn new_seed_fixtures_load_or_fail_as_intended() {
    let s = SceneDesc::load(&data("quantized.gltf")).unwrap();
    let p = &s.meshes[0].primitives[0];
    assert_eq!(p.positions[1], [1.0, 0.0, 0.0]);
    assert_eq!(p.normals[0], [0.0, 0.0, 1.0]);
    let m = Mesh::load(&data("elements.ply")).unwrap();
    assert_eq!(m.triangles.len(), 2);
    let s = SceneDesc::load(&data("meshopt.gltf")).unwrap();
    assert_eq!(s.triangle_count(), 80);
    // The palette PNG decodes; the header bomb is refused before decoding.
    let dir = tmp_dir("seeds");
    for png in ["palette.png", "huge.png"] {
        std::fs::copy(data(png), dir.join(png)).unwrap();
        std::fs::write(dir.join("m.mtl"), format!("newmtl m\nmap_Kd {png}\n")).unwrap();
        std::fs::write(
            dir.join("m.obj"),
            "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m\nf 1 2 3\n",
        )
        .unwrap();
        let r = SceneDesc::load(&dir.join("m.obj"));
        if png == "palette.png" {
            assert_eq!(r.unwrap().textures.len(), 1);
        } else {
            assert!(r.unwrap_err().to_string().contains("16384x16384"));
        }
    }
}
