//! Programs in CUDA C++ (guide §6, §7, §10, §13): modules of OptiX-style programs, program
//! groups, and pipelines compiled by NVRTC into one kernel each.
//!
//! A pipeline's translation unit is the traversal code ([`KERNEL_SOURCE`](crate::KERNEL_SOURCE)),
//! the device header ([`DEVICE_HEADER`]), every module's source, and generated dispatch
//! functions: program groups are numbered in the order the pipeline is given them, the host
//! writes that number into word 0 of each SBT record header as it uploads the SBT, and the
//! device calls a group's programs through a `switch` on it (or, for a kind of group the
//! pipeline has only one of, calls that group's programs without reading the header).

use crate::context::{compile_options, guarded, nvrtc_compile, nvrtc_version, CudaContext};
use crate::error::{driver, CudaError};
use bytemuck::{Pod, Zeroable};
use cudarc::driver::{
    CudaFunction, CudaSlice, DevicePtr, LaunchConfig, PinnedHostSlice, PushKernelArg,
};
use oxray_core::sbt::{SbtRegion, ShaderBindingTable, SBT_RECORD_HEADER_SIZE};
use oxray_core::{
    DeviceContext, Exception, ExceptionCode, LaunchError, LaunchReport, PipelineCompileOptions,
    PipelineError, PipelineLinkOptions, SbtHeader,
};
use std::marker::PhantomData;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// The device-side API: the guide's device functions over the per-thread state of a pipeline's
/// kernel. Modules may include it as `<optix.h>` or `<optix_device.h>`.
pub const DEVICE_HEADER: &str = include_str!("device/oxray_device.h");

/// Threads per block of a pipeline's kernel, unless `OXRAY_PIPELINE_BLOCK` sets another
/// multiple of 32 up to 1024 (a tuning knob).
pub const PIPELINE_BLOCK: u32 = 128;

/// Resident threads per SM that a pipeline's kernel is compiled for (its launch bounds).
const PIPELINE_THREADS_PER_SM: u32 = 1152;

/// The block size pipelines are compiled and launched with.
#[must_use]
pub fn pipeline_block() -> u32 {
    std::env::var("OXRAY_PIPELINE_BLOCK")
        .ok()
        .and_then(|v| v.trim().parse::<u32>().ok())
        .filter(|b| *b >= 32 && *b <= 1024 && b % 32 == 0)
        .unwrap_or(PIPELINE_BLOCK)
}

/// Exception records a launch keeps for its report (the count is exact).
const EXCEPTION_RECORDS: usize = 64;

/// A module of CUDA C++ programs (`OptixModule` made from source): entry points named with the
/// guide's prefixes (`__raygen__`, `__miss__`, `__closesthit__`, `__anyhit__`,
/// `__intersection__`, `__exception__`), declared `extern "C" __global__ void name()`, and
/// callables (`__direct_callable__`, `__continuation_callable__`), declared
/// `extern "C" __device__ ReturnT name(ArgTypes...)`.
///
/// The modules of one pipeline are compiled together in one translation unit, so they must
/// not define the same names twice (helpers of several modules can be `static`).
#[derive(Clone, Debug)]
#[doc(alias = "OptixModule")]
pub struct CudaModule {
    inner: Arc<ModuleInner>,
}

#[derive(Debug)]
struct ModuleInner {
    source: String,
}

impl CudaModule {
    /// A module of the given CUDA C++ source. It is compiled with the pipelines that use it.
    pub fn from_source(source: impl Into<String>) -> CudaModule {
        CudaModule {
            inner: Arc::new(ModuleInner {
                source: source.into(),
            }),
        }
    }

    /// The source as given.
    #[must_use]
    pub fn source(&self) -> &str {
        &self.inner.source
    }

    /// Whether the source defines or declares the entry `name` (a word followed by `(`).
    #[must_use]
    pub fn has_entry(&self, name: &str) -> bool {
        oxray_core::source::has_entry(&self.inner.source, name)
    }

    fn entry(
        &self,
        name: &str,
        prefix: &'static str,
        kind: &'static str,
    ) -> Result<Entry, PipelineError> {
        if !name.starts_with(prefix) || !self.has_entry(name) {
            return Err(PipelineError::UnknownEntry {
                name: name.to_string(),
                kind,
            });
        }
        Ok(Entry {
            module: self.clone(),
            name: name.to_string(),
        })
    }
}

#[derive(Clone, Debug)]
struct Entry {
    module: CudaModule,
    name: String,
}

/// The kind of a CUDA program group; the values are those of the record headers' word 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CudaProgramGroupKind {
    /// A ray-generation program.
    RayGen,
    /// A miss program, or none.
    Miss,
    /// An exception program.
    Exception,
    /// Closest-hit, any-hit and intersection programs, each optional.
    HitGroup,
    /// A direct callable, a continuation callable, or both.
    Callables,
}

impl CudaProgramGroupKind {
    fn region(self) -> &'static str {
        match self {
            CudaProgramGroupKind::RayGen => "raygen",
            CudaProgramGroupKind::Miss => "miss",
            CudaProgramGroupKind::Exception => "exception",
            CudaProgramGroupKind::HitGroup => "hitgroup",
            CudaProgramGroupKind::Callables => "callables",
        }
    }
}

static NEXT_GROUP_ID: AtomicU64 = AtomicU64::new(1);
const CUDA_HEADER_MAGIC: [u8; 8] = *b"oxrayGPU";
const CUDA_HEADER_CHECK: u64 = 0xC2B2_AE3D_27D4_EB4F;

#[derive(Debug)]
struct GroupInner {
    id: u64,
    kind: CudaProgramGroupKind,
    /// Ray generation, miss or exception program; the closest-hit program; the direct callable.
    main: Option<Entry>,
    any_hit: Option<Entry>,
    intersection: Option<Entry>,
    /// The continuation callable.
    continuation: Option<Entry>,
}

impl GroupInner {
    fn entries(&self) -> impl Iterator<Item = &Entry> {
        [
            &self.main,
            &self.any_hit,
            &self.intersection,
            &self.continuation,
        ]
        .into_iter()
        .flatten()
    }
}

/// A program group of CUDA C++ programs (`OptixProgramGroup`).
#[derive(Clone, Debug)]
#[doc(alias = "OptixProgramGroup")]
pub struct CudaProgramGroup {
    inner: Arc<GroupInner>,
}

/// The programs of a CUDA hit group: `(module, entry name)` or absent.
#[derive(Clone, Copy, Debug, Default)]
pub struct CudaHitGroupDesc<'a> {
    /// Closest-hit program.
    pub closest_hit: Option<(&'a CudaModule, &'a str)>,
    /// Any-hit program.
    pub any_hit: Option<(&'a CudaModule, &'a str)>,
    /// Intersection program, run for the custom primitives whose boxes a ray enters.
    pub intersection: Option<(&'a CudaModule, &'a str)>,
}

impl CudaProgramGroup {
    fn new(kind: CudaProgramGroupKind, main: Option<Entry>, any_hit: Option<Entry>) -> Self {
        Self::with(GroupInner {
            id: NEXT_GROUP_ID.fetch_add(1, Ordering::Relaxed),
            kind,
            main,
            any_hit,
            intersection: None,
            continuation: None,
        })
    }

    fn with(inner: GroupInner) -> Self {
        CudaProgramGroup {
            inner: Arc::new(inner),
        }
    }

    /// A ray-generation group.
    pub fn raygen(module: &CudaModule, entry: &str) -> Result<Self, PipelineError> {
        let e = module.entry(entry, "__raygen__", "ray-generation")?;
        Ok(Self::new(CudaProgramGroupKind::RayGen, Some(e), None))
    }

    /// A miss group; `None` makes a miss group that does nothing.
    pub fn miss(entry: Option<(&CudaModule, &str)>) -> Result<Self, PipelineError> {
        let e = entry
            .map(|(m, n)| m.entry(n, "__miss__", "miss"))
            .transpose()?;
        Ok(Self::new(CudaProgramGroupKind::Miss, e, None))
    }

    /// An exception group.
    pub fn exception(module: &CudaModule, entry: &str) -> Result<Self, PipelineError> {
        let e = module.entry(entry, "__exception__", "exception")?;
        Ok(Self::new(CudaProgramGroupKind::Exception, Some(e), None))
    }

    /// A hit group: for triangles, and with an intersection program for custom primitives.
    pub fn hit_group(desc: CudaHitGroupDesc<'_>) -> Result<Self, PipelineError> {
        let is = desc
            .intersection
            .map(|(m, n)| m.entry(n, "__intersection__", "intersection"))
            .transpose()?;
        let ch = desc
            .closest_hit
            .map(|(m, n)| m.entry(n, "__closesthit__", "closest-hit"))
            .transpose()?;
        let ah = desc
            .any_hit
            .map(|(m, n)| m.entry(n, "__anyhit__", "any-hit"))
            .transpose()?;
        let inner = GroupInner {
            id: NEXT_GROUP_ID.fetch_add(1, Ordering::Relaxed),
            kind: CudaProgramGroupKind::HitGroup,
            main: ch,
            any_hit: ah,
            intersection: is,
            continuation: None,
        };
        Ok(Self::with(inner))
    }

    /// A callables group (guide §15): a direct callable, a continuation callable, or both, in
    /// one SBT record of the callables region. Each is a device function of any signature;
    /// `optixDirectCall<ReturnT>(index, args...)` and `optixContinuationCall` call it with the
    /// caller's `ReturnT(ArgTypes...)`, which must be its own.
    #[doc(alias = "optixDirectCall")]
    #[doc(alias = "optixContinuationCall")]
    pub fn callables(
        direct: Option<(&CudaModule, &str)>,
        continuation: Option<(&CudaModule, &str)>,
    ) -> Result<Self, PipelineError> {
        if direct.is_none() && continuation.is_none() {
            return Err(PipelineError::EmptyCallables);
        }
        let dc = direct
            .map(|(m, n)| m.entry(n, "__direct_callable__", "direct-callable"))
            .transpose()?;
        let cc = continuation
            .map(|(m, n)| m.entry(n, "__continuation_callable__", "continuation-callable"))
            .transpose()?;
        Ok(Self::with(GroupInner {
            id: NEXT_GROUP_ID.fetch_add(1, Ordering::Relaxed),
            kind: CudaProgramGroupKind::Callables,
            main: dc,
            any_hit: None,
            intersection: None,
            continuation: cc,
        }))
    }

    /// The group's kind.
    #[must_use]
    pub fn kind(&self) -> CudaProgramGroupKind {
        self.inner.kind
    }

    /// The record header naming this group (`optixSbtRecordPackHeader`). A pipeline that holds
    /// the group replaces it, as it uploads the SBT, with the group's program index.
    #[doc(alias = "optixSbtRecordPackHeader")]
    #[must_use]
    pub fn pack_header(&self) -> SbtHeader {
        let id = self.inner.id;
        let mut h = [0u8; SBT_RECORD_HEADER_SIZE];
        h[..8].copy_from_slice(&CUDA_HEADER_MAGIC);
        h[8..16].copy_from_slice(&id.to_le_bytes());
        h[16..24].copy_from_slice(&(id ^ CUDA_HEADER_CHECK).to_le_bytes());
        SbtHeader(h)
    }

    /// The group id a header packed by [`pack_header`](Self::pack_header) names.
    #[must_use]
    pub fn header_group_id(bytes: &[u8]) -> Option<u64> {
        let h = bytes.get(..SBT_RECORD_HEADER_SIZE)?;
        if h[..8] != CUDA_HEADER_MAGIC {
            return None;
        }
        let id = u64::from_le_bytes(h[8..16].try_into().ok()?);
        let check = u64::from_le_bytes(h[16..24].try_into().ok()?);
        (check == id ^ CUDA_HEADER_CHECK).then_some(id)
    }
}

/// The CUDA C++ translation unit of a pipeline: traversal, device header, modules, dispatch and
/// the kernel `__oxray_pipeline`. Compiled with [`pipeline_compile_options`].
#[must_use]
pub fn pipeline_source(groups: &[CudaProgramGroup]) -> String {
    let mut s = String::new();
    // Without any-hit programs, a trace into a triangle GAS that culls nothing takes the query
    // kernels' own loop (the device header's fast path).
    let any_hit = groups.iter().any(|g| g.inner.any_hit.is_some());
    s.push_str(&format!(
        "#define OXRAY_PIPELINE_HAS_ANYHIT {}\n",
        any_hit as u32
    ));
    // The triangle test's rare cases (the exact fallback, the division's slow path) in one call
    // outside the walks' hot path: a call keeps every live value of the walk in a register at
    // its site, which sized the pipeline's register budget (`kernels/trace.cu`,
    // `intersect_rare`). The query kernels, which have registers to spare, keep the plain
    // division.
    s.push_str("#ifndef OXRAY_TRIANGLE_RARE_CALL\n#define OXRAY_TRIANGLE_RARE_CALL 1\n#endif\n");
    // What the programs may read of the ray and the hit (an NVRTC option may say otherwise).
    s.push_str(&format!(
        "#ifndef OXRAY_READS\n#define OXRAY_READS {}u\n#endif\n",
        reads(
            groups
                .iter()
                .flat_map(|g| g.inner.entries())
                .map(|e| e.module.source())
        )
    ));
    s.push_str(crate::KERNEL_SOURCE);
    s.push_str("\n#line 1 \"optix_types.h\"\n");
    s.push_str(oxray_core::source::OPTIX_TYPES_HEADER);
    s.push_str("\n#line 1 \"oxray_device.h\"\n");
    s.push_str(DEVICE_HEADER);
    // Modules, each once, in the order the groups name them.
    let mut modules: Vec<&CudaModule> = Vec::new();
    for g in groups {
        for e in g.inner.entries() {
            if !modules
                .iter()
                .any(|m| Arc::ptr_eq(&m.inner, &e.module.inner))
            {
                modules.push(&e.module);
            }
        }
    }
    s.push_str("\n// Entry points of the modules are device functions.\n#undef __global__\n#define __global__ __device__\n");
    for (i, m) in modules.iter().enumerate() {
        s.push_str(&format!("#line 1 \"module{i}.cu\"\n"));
        s.push_str(&oxray_core::source::strip_optix_includes(m.source()));
        s.push('\n');
    }
    s.push_str("#line 1 \"oxray_pipeline.cu\"\n#undef __global__\n#define __global__ __location__(global)\n");
    // A dispatch function receives the group index of a record of one SBT region, and
    // `pack_sbt` admits into a region only headers of this pipeline's groups of the region's
    // kind: where the pipeline has one group of that kind, every record names it, and the
    // function calls its program without reading the index. The record's header word, a load
    // on the way from a trace's hit (or from the launch) to its program, is then never read.
    let switch = |name: &str,
                  ret: &str,
                  kind: CudaProgramGroupKind,
                  pick: &dyn Fn(&GroupInner) -> Option<String>| {
        let default = match ret {
            "bool" => "return false;",
            "void*" | "const void*" => "return nullptr;",
            _ => "return;",
        };
        // Only the kind's groups can be named by a record of its region.
        let of_kind = || {
            groups
                .iter()
                .enumerate()
                .filter(|(_, g)| g.inner.kind == kind)
        };
        let mut it = of_kind();
        if let (Some((_, only)), None) = (it.next(), it.next()) {
            let body = pick(&only.inner).unwrap_or_else(|| default.to_string());
            return format!(
                "__device__ {ret} {name}(u32 group) {{\n    (void)group;\n    {body}\n}}\n"
            );
        }
        let mut f = format!("__device__ {ret} {name}(u32 group) {{\n    switch (group) {{\n");
        for (i, g) in of_kind() {
            if let Some(body) = pick(&g.inner) {
                f.push_str(&format!("    case {i}: {body}\n"));
            }
        }
        f.push_str(&format!("    default: {default}\n    }}\n}}\n"));
        f
    };
    let call = |g: &GroupInner| g.main.as_ref().map(|e| format!("{}(); return;", e.name));
    use CudaProgramGroupKind::{Callables, Exception, HitGroup, Miss, RayGen};
    s.push_str(&switch("__oxray_call_raygen", "void", RayGen, &call));
    s.push_str(&switch("__oxray_call_miss", "void", Miss, &call));
    s.push_str(&switch("__oxray_call_closesthit", "void", HitGroup, &call));
    s.push_str(&switch("__oxray_call_exception", "void", Exception, &call));
    s.push_str(&switch(
        "__oxray_call_anyhit",
        "void",
        HitGroup,
        &|g: &GroupInner| g.any_hit.as_ref().map(|e| format!("{}(); return;", e.name)),
    ));
    s.push_str(&switch(
        "__oxray_has_anyhit",
        "bool",
        HitGroup,
        &|g: &GroupInner| g.any_hit.as_ref().map(|_| "return true;".to_string()),
    ));
    s.push_str(&switch(
        "__oxray_call_intersection",
        "void",
        HitGroup,
        &|g: &GroupInner| {
            g.intersection
                .as_ref()
                .map(|e| format!("{}(); return;", e.name))
        },
    ));
    s.push_str(&switch(
        "__oxray_has_intersection",
        "bool",
        HitGroup,
        &|g: &GroupInner| g.intersection.as_ref().map(|_| "return true;".to_string()),
    ));
    // Callables have signatures of their own: the group gives the function's address, which
    // optixDirectCall / optixContinuationCall call through a pointer of the caller's type.
    let address = |e: &Entry| format!("return reinterpret_cast<void*>(&{});", e.name);
    s.push_str(&switch(
        "__oxray_dc_of",
        "void*",
        Callables,
        &|g: &GroupInner| g.main.as_ref().map(address),
    ));
    s.push_str(&switch(
        "__oxray_cc_of",
        "void*",
        Callables,
        &|g: &GroupInner| g.continuation.as_ref().map(address),
    ));
    // Each callable's signature, as a tag unique to its function type, which a call compares
    // with its own (CALLABLE_PARAMETER_MISMATCH otherwise, as on the CPU).
    let signature = |e: &Entry| format!("return __oxray_signature<decltype(&{})>();", e.name);
    s.push_str(&switch(
        "__oxray_dc_signature",
        "const void*",
        Callables,
        &|g: &GroupInner| g.main.as_ref().map(signature),
    ));
    s.push_str(&switch(
        "__oxray_cc_signature",
        "const void*",
        Callables,
        &|g: &GroupInner| g.continuation.as_ref().map(signature),
    ));
    s.push_str(
        r#"
#ifndef OXRAY_PIPELINE_MIN_BLOCKS
#define OXRAY_PIPELINE_MIN_BLOCKS 1
#endif
extern "C" __global__ void __launch_bounds__(OXRAY_PIPELINE_BLOCK, OXRAY_PIPELINE_MIN_BLOCKS)
__oxray_pipeline() {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= __oxray_launch.total) return;
    __oxray_ThreadState state;
    __oxray_states[threadIdx.x] = &state;
    __oxray_ThreadState& s = __oxray_state();
    s.depth = 0u;
    s.traces = 0u;
    if (__OXRAY_STORES(true, __OXRAY_READS_CALLS)) s.calls = 0u;
    if (__OXRAY_STORES(true, __OXRAY_READS_REPORT)) s.report = nullptr;
    if (__OXRAY_STORES(true, __OXRAY_READS_PATH)) s.ray.path = nullptr;
    s.record = reinterpret_cast<const char*>(__oxray_launch.raygen);
    __oxray_call_raygen(__oxray_group_of(s.record));
    __oxray_count_traces(s.traces);
}
"#,
    );
    s
}

/// The values of the ray and the hit that a trace on the device header's fast path stores only
/// when a program may read them (its `OXRAY_READS` bits), with the device functions that return
/// each.
const READS: [(u32, &[&str]); 13] = [
    (1, &["optixGetWorldRayOrigin", "optixGetObjectRayOrigin"]),
    (
        2,
        &[
            "optixGetWorldRayDirection",
            "optixGetObjectRayDirection",
            "optixGetRibbonNormal",
        ],
    ),
    (4, &["optixGetRayTmin"]),
    (8, &["optixGetRayTime"]),
    (16, &["optixGetRayVisibilityMask"]),
    (32, &["optixGetPrimitiveIndex"]),
    (64, &["optixGetSbtGASIndex"]),
    (
        128,
        &[
            "optixGetHitKind",
            "optixIsFrontFaceHit",
            "optixIsBackFaceHit",
            "optixIsTriangleFrontFaceHit",
            "optixIsTriangleBackFaceHit",
            "optixIsTriangleHit",
            "optixGetPrimitiveType",
        ],
    ),
    (256, &["optixGetTriangleBarycentrics", "optixGetAttribute_"]),
    (
        512,
        &["optixGetTriangleVertexData", "optixGetGASTraversableHandle"],
    ),
    (1024, &["optixReportIntersection"]),
    (2048, &["optixDirectCall", "optixContinuationCall"]),
    (
        4096,
        &[
            "optixGetInstanceId",
            "optixGetInstanceIndex",
            "optixGetObjectRay",
            "optixGetTransformList",
            "optixGetObjectToWorldTransformMatrix",
            "optixGetWorldToObjectTransformMatrix",
            "optixTransform",
            "optixGetGASTraversableHandle",
            "optixGetTriangleVertexData",
            "optixGetRibbonNormal",
        ],
    ),
];

/// Which of the ray's and the hit's values the programs of `sources` may read: a value whose
/// device functions no source names is never asked for, so a fast-path trace need not write it
/// into the thread's state (local memory, which a launch of a million short rays pays for in
/// DRAM writes). A name anywhere in a source (a comment too) counts, so the set errs on the
/// side of storing.
fn reads<'a>(sources: impl Iterator<Item = &'a str>) -> u32 {
    let sources: Vec<&str> = sources.collect();
    READS
        .iter()
        .filter(|(_, names)| {
            names
                .iter()
                .any(|name| sources.iter().any(|src| src.contains(name)))
        })
        .fold(0, |bits, (bit, _)| bits | bit)
}

/// The NVRTC options of a pipeline for a device of compute capability `cc`: those of the query
/// kernels, plus the pipeline's payload count, trace depth and block size.
pub fn pipeline_compile_options(
    cc: (i32, i32),
    compile: &PipelineCompileOptions,
    link: &PipelineLinkOptions,
) -> Vec<String> {
    let mut o = compile_options(cc);
    o.push("-DOXRAY_NO_QUERY_KERNELS=1".into());
    o.push(format!(
        "-DOXRAY_NUM_PAYLOAD_VALUES={}",
        compile.num_payload_values
    ));
    o.push(format!("-DOXRAY_MAX_TRACE_DEPTH={}", link.max_trace_depth));
    o.push(format!("-DOXRAY_PIPELINE_BLOCK={}", pipeline_block()));
    o.push(format!("-DOXRAY_EXCEPTION_RECORDS={EXCEPTION_RECORDS}"));
    o.push(format!(
        "-DOXRAY_NUM_ATTRIBUTE_VALUES={}",
        compile.num_attribute_values.clamp(2, 8)
    ));
    o.push(format!(
        "-DOXRAY_GRAPH_FLAGS={}u",
        compile.traversable_graph_flags.bits()
    ));
    o.push(format!(
        "-DOXRAY_PRIMITIVE_TYPE_FLAGS={}u",
        compile.uses_primitive_type_flags.bits()
    ));
    o.push(format!(
        "-DOXRAY_USES_MOTION_BLUR={}",
        u32::from(compile.uses_motion_blur)
    ));
    // A binary walk pushes at most one entry per level of its tree.
    o.push(format!("-DOXRAY_BVH2_STACK={}", BVH2_STACK));
    // Tuning: `OXRAY_NVRTC_OPTIONS` adds NVRTC options (e.g. `-DOXRAY_PIPELINE_MIN_BLOCKS=8`).
    let extra = std::env::var("OXRAY_NVRTC_OPTIONS").unwrap_or_default();
    if !extra.contains("OXRAY_PIPELINE_MIN_BLOCKS") {
        // 1152 resident threads per SM: at most 56 registers each on a 64K-register SM, what
        // the fast path's walks need to hold their values without reloading them at each node
        // (the query kernels need 48 and 40, with no program state around them); 48
        // registers (1280 threads) spill in both walks and measured 1-3 points lower against
        // the query kernel (docs/BENCHMARKS.md, "The pipeline, fifth round" and "eighth
        // round").
        o.push(format!(
            "-DOXRAY_PIPELINE_MIN_BLOCKS={}",
            (PIPELINE_THREADS_PER_SM / pipeline_block()).max(1)
        ));
    }
    o.extend(extra.split_whitespace().map(str::to_string));
    o
}

/// Entries of one binary walk's stack in a pipeline's traversal: the deepest binary tree the
/// builder makes, plus slack. Walks of nested structures each have their own.
const BVH2_STACK: usize = oxray_bvh::MAX_BVH2_DEPTH + 2;

/// The traversable graph depth a CUDA pipeline allows until
/// [`CudaPipeline::set_max_traversable_graph_depth`] says otherwise: OptiX's default of 2 (an
/// IAS over GASes, or a static transform over one). Each further level costs every thread
/// stack, which is reserved for every thread the device can hold.
pub const DEFAULT_MAX_TRAVERSABLE_GRAPH_DEPTH: u32 = 2;

/// Bytes of stack the curve intersector of `curve.cu` takes at most.
const CURVE_STACK: usize = 4096;

/// The per-thread stack a pipeline needs (bytes): per trace level, the trace's frame and a
/// walk frame per graph level, plus the programs' own.
fn stack_bytes(max_trace_depth: u32, max_graph_depth: u32, curves: bool) -> usize {
    let walk = 4 * BVH2_STACK * 3 + 512;
    // The curve intersector's frames (its polynomials and their chains of derivatives, in
    // double precision) sit below the deepest walk of each trace of a pipeline with curves.
    let curve = if curves { CURVE_STACK } else { 0 };
    let trace = 4096 + curve + max_graph_depth.max(1) as usize * walk;
    trace * max_trace_depth.max(1) as usize + 2048
}

/// Whether a pipeline with these primitive types may intersect curves.
fn uses_curves(kinds: oxray_core::PrimitiveTypeFlags) -> bool {
    use oxray_core::PrimitiveTypeFlags as F;
    kinds.intersects(!(F::CUSTOM | F::SPHERE | F::TRIANGLE))
}

/// Checks a pipeline's options and groups (guide §12), as the CPU pipeline does.
fn check_pipeline(
    compile: &PipelineCompileOptions,
    link: &PipelineLinkOptions,
    groups: &[CudaProgramGroup],
) -> Result<(), PipelineError> {
    if compile.num_payload_values > 32 {
        return Err(PipelineError::TooManyPayloadValues(
            compile.num_payload_values,
        ));
    }
    if compile.num_attribute_values > 8 {
        return Err(PipelineError::TooManyAttributeValues(
            compile.num_attribute_values,
        ));
    }
    if link.max_trace_depth > 31 {
        return Err(PipelineError::TraceDepthTooLarge(link.max_trace_depth));
    }
    if groups.is_empty() {
        return Err(PipelineError::NoProgramGroups);
    }
    Ok(())
}

/// Compiles a pipeline's unit to PTX with NVRTC (no device needed): what [`CudaPipeline::new`]
/// does before loading it. Fails with [`CudaError::Compile`] and NVRTC's log.
pub fn compile_pipeline_ptx(
    cc: (i32, i32),
    compile: &PipelineCompileOptions,
    link: &PipelineLinkOptions,
    groups: &[CudaProgramGroup],
) -> Result<String, CudaError> {
    check_pipeline(compile, link, groups)?;
    let source = pipeline_source(groups);
    let options = pipeline_compile_options(cc, compile, link);
    let entry = cache_entry(&options, &source);
    if let Some(ptx) = entry
        .as_ref()
        .and_then(|p| std::fs::read_to_string(p).ok())
        .filter(|ptx| ptx.contains(".entry __oxray_pipeline"))
    {
        return Ok(ptx);
    }
    let ptx = nvrtc_compile(&source, options, "oxray_pipeline.cu")?.to_src();
    if let Some(path) = &entry {
        // A cache that cannot be written costs only the next compile's time.
        let _ = oxray_core::cache::write_entry(path, ptx.as_bytes());
    }
    Ok(ptx)
}

/// Where [`compile_pipeline_ptx`] keeps the PTX of a pipeline (`None` without NVRTC): the disk
/// cache (the counterpart of OptiX's, guide §4.2), keyed by everything that determines the PTX
/// (NVRTC's version, the options, which name the architecture, and the whole unit).
#[must_use]
pub fn pipeline_cache_entry(
    cc: (i32, i32),
    compile: &PipelineCompileOptions,
    link: &PipelineLinkOptions,
    groups: &[CudaProgramGroup],
) -> Option<std::path::PathBuf> {
    cache_entry(
        &pipeline_compile_options(cc, compile, link),
        &pipeline_source(groups),
    )
}

fn cache_entry(options: &[String], source: &str) -> Option<std::path::PathBuf> {
    let version = nvrtc_version()?;
    let key = oxray_core::cache::content_key(&[
        "oxray pipeline ptx",
        &version,
        &options.join(" "),
        source,
    ]);
    Some(oxray_core::cache::entry_path(
        &oxray_core::cache::cache_dir(),
        "ptx",
        key,
        "ptx",
    ))
}

/// The launch information of the device header (`__oxray_LaunchInfo`), byte for byte.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub(crate) struct LaunchInfo {
    pub dims: [u32; 3],
    pub total: u32,
    pub raygen: u64,
    pub exception: u64,
    pub miss: u64,
    pub hitgroup: u64,
    pub miss_stride: u32,
    pub miss_count: u32,
    pub hit_stride: u32,
    pub hit_count: u32,
    pub exceptions: u64,
    pub callables: u64,
    pub callable_stride: u32,
    pub callable_count: u32,
    pub max_graph_depth: u32,
    pub validation: u32,
}

/// Where each region of an SBT lies in its packed bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PackedRegion {
    /// Byte offset of the first record.
    pub offset: usize,
    /// Bytes from one record to the next.
    pub stride: usize,
    /// Records.
    pub count: usize,
}

/// An SBT as a pipeline uploads it: the regions' records one after the other (each region
/// 16-byte aligned, strides kept), every header replaced by the device's: word 0 the group's
/// program index in the pipeline, word 1 its kind, the rest zero. Record data is unchanged.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PackedSbt {
    /// The bytes to upload.
    pub bytes: Vec<u8>,
    /// The ray-generation record.
    pub raygen: PackedRegion,
    /// The exception record, if any.
    pub exception: Option<PackedRegion>,
    /// Miss records.
    pub miss: PackedRegion,
    /// Hit-group records.
    pub hitgroup: PackedRegion,
    /// Callables records.
    pub callables: PackedRegion,
}

/// Packs `sbt` for a pipeline of `groups`: each header must name a group of the pipeline of the
/// region's kind ([`LaunchError::InvalidSbtRecord`] otherwise, as on the CPU backend).
pub fn pack_sbt(
    groups: &[CudaProgramGroup],
    sbt: &ShaderBindingTable,
) -> Result<PackedSbt, LaunchError> {
    if sbt.raygen.count() == 0 {
        return Err(LaunchError::NoRaygenRecord);
    }
    let mut bytes = Vec::new();
    let mut region = |r: &SbtRegion, kind: CudaProgramGroupKind, max: usize| {
        let count = r.count().min(max);
        bytes.resize(bytes.len().next_multiple_of(16), 0);
        let offset = bytes.len();
        for i in 0..count {
            let rec = r.record(i).unwrap_or(&[]);
            let bad = |reason| LaunchError::InvalidSbtRecord {
                region: kind.region(),
                index: i,
                reason,
            };
            let id = CudaProgramGroup::header_group_id(rec)
                .ok_or(bad("the header was not packed from a CUDA program group"))?;
            let g = groups
                .iter()
                .position(|g| g.inner.id == id)
                .ok_or(bad("the header's program group is not in this pipeline"))?;
            if groups[g].kind() != kind {
                return Err(bad("the header's program group is of another kind"));
            }
            let mut header = [0u8; SBT_RECORD_HEADER_SIZE];
            header[..4].copy_from_slice(&(g as u32).to_le_bytes());
            header[4..8].copy_from_slice(&(kind as u32).to_le_bytes());
            bytes.extend_from_slice(&header);
            bytes.extend_from_slice(&rec[SBT_RECORD_HEADER_SIZE..]);
        }
        Ok(PackedRegion {
            offset,
            stride: r.stride(),
            count,
        })
    };
    let raygen = region(&sbt.raygen, CudaProgramGroupKind::RayGen, 1)?;
    let exception = match &sbt.exception {
        Some(r) if r.count() > 0 => Some(region(r, CudaProgramGroupKind::Exception, 1)?),
        _ => None,
    };
    let miss = region(&sbt.miss, CudaProgramGroupKind::Miss, usize::MAX)?;
    let hitgroup = region(&sbt.hitgroup, CudaProgramGroupKind::HitGroup, usize::MAX)?;
    let callables = region(&sbt.callables, CudaProgramGroupKind::Callables, usize::MAX)?;
    if bytes.is_empty() {
        bytes.resize(16, 0);
    }
    Ok(PackedSbt {
        bytes,
        raygen,
        exception,
        miss,
        hitgroup,
        callables,
    })
}

/// Launch indices of a `width x height x depth` launch, checked against guide §12 (at most
/// 2^30).
pub fn launch_size(width: u32, height: u32, depth: u32) -> Result<u32, LaunchError> {
    (width as u64)
        .checked_mul(height as u64)
        .and_then(|x| x.checked_mul(depth as u64))
        .filter(|&t| t <= 1 << 30)
        .map(|t| t as u32)
        .ok_or(LaunchError::TooLarge {
            width,
            height,
            depth,
        })
}

/// Turns the device's exception records into a report: the count, and the first five by launch
/// index (of the first records the device kept).
pub(crate) fn exception_report(words: &[u32]) -> LaunchReport {
    let count = words.first().copied().unwrap_or(0) as u64;
    let kept = (count as usize).min(EXCEPTION_RECORDS);
    let mut first: Vec<([u32; 3], Exception)> = (0..kept)
        .filter_map(|k| words.get(16 + 16 * k..32 + 16 * k))
        .map(|r| {
            let n = (r[12] as usize).min(8);
            (
                [r[0], r[1], r[2]],
                Exception::new(ExceptionCode(r[3] as i32), &r[4..4 + n]),
            )
        })
        .collect();
    first.sort_by_key(|(i, _)| [i[2], i[1], i[0]]);
    first.truncate(5);
    let word = |i: usize| words.get(i).copied().unwrap_or(0) as u64;
    LaunchReport {
        exceptions: count,
        first_exceptions: first,
        traces: word(2) | word(3) << 32,
    }
}

/// Whether the PTX declares the variable `name` in the constant state space (`__constant__`),
/// where the programs cannot write it. Anything else (a `__device__` variable, a name not found)
/// is treated as writable.
fn declared_constant(ptx: &str, name: &str) -> bool {
    ptx.lines().any(|line| {
        let mut words = line
            .split_whitespace()
            .skip_while(|w| matches!(*w, ".visible" | ".extern" | ".weak"));
        words.next() == Some(".const")
            && words.any(|w| {
                w.strip_prefix(name)
                    .is_some_and(|rest| rest.is_empty() || rest.starts_with(['[', ';']))
            })
    })
}

/// The device address of a pipeline's private buffer. Only the pipeline's stream uses these
/// buffers, so the access record cudarc keeps for other streams is not needed past this call.
fn device_address<T>(buffer: &CudaSlice<T>, stream: &Arc<cudarc::driver::CudaStream>) -> u64 {
    let (address, _record) = buffer.device_ptr(stream);
    address
}

/// A pipeline of CUDA C++ programs (`OptixPipeline`), compiled into one kernel.
#[doc(alias = "OptixPipeline")]
pub struct CudaPipeline {
    ctx: CudaContext,
    module: Arc<cudarc::driver::CudaModule>,
    function: CudaFunction,
    groups: Vec<CudaProgramGroup>,
    params_name: Option<String>,
    /// Whether the parameter variable is `__constant__`: the programs cannot write it, so the
    /// bytes of the last launch are still there.
    params_constant: bool,
    max_trace_depth: u32,
    max_graph_depth: u32,
    /// Whether the pipeline may intersect curves (whose intersector's frames its stack holds).
    curves: bool,
    block: u32,
    context: DeviceContext,
    scratch: Mutex<LaunchState>,
}

/// What a pipeline keeps between launches.
#[derive(Default)]
struct LaunchState {
    /// The launch buffers, made by the first launch.
    buffers: Option<LaunchScratch>,
    /// The launch parameters last copied into a `__constant__` parameter variable, which the
    /// programs cannot change: an unchanged launch skips the copy.
    params: Option<Vec<u8>>,
}

/// A pipeline's buffers between launches: the SBT's device copy, the exception records, and
/// what the device already holds, so that a launch issues only the copies it needs (a launch of
/// a million rays takes a fraction of a millisecond; each copy from pageable memory costs
/// microseconds and waits for the stream).
struct LaunchScratch {
    sbt: CudaSlice<u8>,
    exceptions: CudaSlice<u32>,
    /// Page-locked host memory mapped into the device's address space, which the
    /// `oxray_launch_counts` kernel queued after each launch writes the exception and trace
    /// counts into: the launch then waits for the stream once, with no copy queued.
    counts: PinnedHostSlice<u32>,
    /// The address of `counts` on the device.
    counts_device: u64,
    /// The SBT bytes last copied into `sbt`.
    sbt_bytes: Vec<u8>,
    /// The launch information last written to the module's `__oxray_launch`.
    info: Option<LaunchInfo>,
}

impl std::fmt::Debug for CudaPipeline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CudaPipeline")
            .field("groups", &self.groups.len())
            .field("params", &self.params_name)
            .finish()
    }
}

impl CudaPipeline {
    /// Compiles and loads a pipeline (`optixPipelineCreate`). `params_variable` is the guide's
    /// `pipelineLaunchParamsVariableName`: a `__constant__` (or `__device__`) variable of a
    /// module that each launch fills with the launch parameters.
    #[doc(alias = "optixPipelineCreate")]
    pub fn new(
        ctx: &CudaContext,
        compile: &PipelineCompileOptions,
        link: &PipelineLinkOptions,
        params_variable: Option<&str>,
        groups: &[CudaProgramGroup],
    ) -> Result<CudaPipeline, CudaError> {
        let cc = ctx.device().compute_capability;
        let ptx = compile_pipeline_ptx(cc, compile, link, groups)?;
        let cu = ctx.stream.context();
        let module = guarded("loading a pipeline", || {
            cu.load_module(cudarc::nvrtc::Ptx::from_src(ptx.clone()))
        })?;
        let function = guarded("loading a pipeline kernel", || {
            module.load_function("__oxray_pipeline")
        })?;
        if let Some(name) = params_variable {
            guarded("finding the launch parameters", || {
                module.get_global(name, &ctx.stream).map(|_| ())
            })
            .map_err(|_| {
                CudaError::Launch(format!("no variable {name} in the pipeline's modules"))
            })?;
        }
        let pipeline = CudaPipeline {
            ctx: ctx.clone(),
            module,
            function,
            groups: groups.to_vec(),
            params_name: params_variable.map(str::to_string),
            params_constant: params_variable.is_some_and(|name| declared_constant(&ptx, name)),
            max_trace_depth: link.max_trace_depth,
            max_graph_depth: DEFAULT_MAX_TRAVERSABLE_GRAPH_DEPTH,
            curves: uses_curves(compile.uses_primitive_type_flags),
            block: pipeline_block(),
            context: DeviceContext::new(),
            scratch: Mutex::new(LaunchState::default()),
        };
        pipeline.reserve_stack()?;
        Ok(pipeline)
    }

    /// Sets the device context whose options launches follow (guide §4): in validation mode
    /// every trace checks its ray (`INVALID_RAY`) and the first built-in exception fails the
    /// launch (§4.3); without an exception record, the first five exceptions go to its log
    /// callback, or to stderr (§13.14), as on the CPU backend.
    pub fn set_device_context(&mut self, context: &DeviceContext) {
        self.context = context.clone();
    }

    /// The compiled kernel's registers and local memory per thread, and its block size.
    pub fn kernel_info(&self) -> Result<(crate::KernelInfo, u32), CudaError> {
        let f = &self.function;
        Ok((
            crate::KernelInfo {
                name: "__oxray_pipeline",
                registers: f.num_regs().map_err(driver("reading kernel attributes"))?,
                local_bytes: f
                    .local_size_bytes()
                    .map_err(driver("reading kernel attributes"))?,
            },
            self.block,
        ))
    }

    /// Traces that nest (a closest-hit, miss or continuation callable that traces) and walks of
    /// nested structures recurse on the stack: raises the context's stack limit to what this
    /// pipeline needs (never lowers it). The driver reserves that much for every thread the
    /// device can hold at once: a stack it cannot hold is [`CudaError::TooLarge`].
    fn reserve_stack(&self) -> Result<(), CudaError> {
        let stack = stack_bytes(self.max_trace_depth, self.max_graph_depth, self.curves);
        let current = guarded("reading the stack size", || {
            cudarc::driver::result::ctx::get_limit(
                cudarc::driver::sys::CUlimit::CU_LIMIT_STACK_SIZE,
            )
        })?;
        if current < stack {
            let cu = self.ctx.stream.context();
            let set = guarded("setting the stack size", || {
                cu.set_limit(cudarc::driver::sys::CUlimit::CU_LIMIT_STACK_SIZE, stack)
            });
            if let Err(CudaError::Driver { message, .. }) = &set {
                if message.contains("CUDA_ERROR_OUT_OF_MEMORY") {
                    let d = self.ctx.device();
                    return Err(CudaError::TooLarge(format!(
                        "the pipeline's stack, {} KiB a thread for max_trace_depth {} and a \
                         traversable graph depth of {}{}, over every thread {} can hold at once \
                         does not fit its {} GiB; lower max_trace_depth or the graph depth",
                        stack / 1024,
                        self.max_trace_depth,
                        self.max_graph_depth,
                        if self.curves { " with curves" } else { "" },
                        d.name,
                        d.total_memory >> 30,
                    )));
                }
            }
            set?;
        }
        Ok(())
    }

    /// Sets the deepest traversable graph a trace may enter (the last argument of
    /// `optixPipelineSetStackSize`, guide §6.8): 1 to 31, by default
    /// [`DEFAULT_MAX_TRAVERSABLE_GRAPH_DEPTH`]. A trace of a deeper graph raises
    /// `TRAVERSAL_DEPTH_EXCEEDED`. The context's stack grows to match.
    #[doc(alias = "optixPipelineSetStackSize")]
    pub fn set_max_traversable_graph_depth(&mut self, depth: u32) -> Result<(), CudaError> {
        if depth == 0 || depth > oxray_core::MAX_TRAVERSABLE_GRAPH_DEPTH {
            return Err(PipelineError::InvalidGraphDepth(depth).into());
        }
        self.max_graph_depth = depth;
        self.reserve_stack()
    }

    /// The deepest traversable graph a trace may enter.
    pub fn max_traversable_graph_depth(&self) -> u32 {
        self.max_graph_depth
    }

    /// The program groups, in program-index order.
    pub fn groups(&self) -> &[CudaProgramGroup] {
        &self.groups
    }

    /// Launches `width * height * depth` ray-generation programs (`optixLaunch`) with the launch
    /// parameters `params` (the bytes of the parameter variable, copied before the launch, guide
    /// §10), and waits for them. Exceptions are counted in the report, with the first five by
    /// launch index (among the first 64 the device recorded).
    #[doc(alias = "optixLaunch")]
    pub fn launch(
        &self,
        params: &[u8],
        sbt: &ShaderBindingTable,
        width: u32,
        height: u32,
        depth: u32,
    ) -> Result<LaunchReport, CudaError> {
        let total = launch_size(width, height, depth)?;
        let packed = pack_sbt(&self.groups, sbt)?;
        let stream = &self.ctx.stream;
        let mut state = self.scratch.lock().unwrap_or_else(|e| e.into_inner());
        let LaunchState {
            buffers: scratch,
            params: held,
        } = &mut *state;
        match &self.params_name {
            Some(name) => {
                let unchanged =
                    self.params_constant && held.as_deref().is_some_and(|last| last == params);
                if !unchanged {
                    *held = None;
                    let mut var = guarded("finding the launch parameters", || {
                        self.module.get_global(name, stream)
                    })?;
                    if params.len() != var.len() {
                        return Err(CudaError::Launch(format!(
                            "{} bytes of launch parameters for {name}, which holds {}",
                            params.len(),
                            var.len()
                        )));
                    }
                    if !params.is_empty() {
                        stream
                            .memcpy_htod(params, &mut var)
                            .map_err(driver("copying the launch parameters"))?;
                    }
                    if self.params_constant {
                        *held = Some(params.to_vec());
                    }
                }
            }
            None if !params.is_empty() => {
                return Err(CudaError::Launch(
                    "launch parameters given, but the pipeline names no parameter variable".into(),
                ))
            }
            None => {}
        }
        if total == 0 {
            return Ok(LaunchReport::default());
        }
        let grow = scratch
            .as_ref()
            .is_none_or(|s| s.sbt.len() < packed.bytes.len());
        if grow {
            *scratch = None;
            let sbt = stream
                .alloc_zeros::<u8>(packed.bytes.len().next_power_of_two())
                .map_err(driver("allocating the SBT"))?;
            let exceptions = stream
                .alloc_zeros::<u32>(16 + 16 * EXCEPTION_RECORDS)
                .map_err(driver("allocating exception records"))?;
            // SAFETY: four words of page-locked host memory (cached: the host reads them),
            // mapped for the device; the counts kernel of each launch writes them before the
            // host reads them, after the stream is synchronized.
            let mut counts = unsafe {
                stream.context().alloc_pinned_with_flags::<u32>(
                    4,
                    cudarc::driver::sys::CU_MEMHOSTALLOC_DEVICEMAP,
                )
            }
            .map_err(driver("allocating the launch counts"))?;
            let counts_host = counts
                .as_mut_ptr()
                .map_err(driver("allocating the launch counts"))?;
            let mut counts_device: cudarc::driver::sys::CUdeviceptr = 0;
            // SAFETY: `counts_host` is the start of a live page-locked allocation made with
            // DEVICEMAP, in the context bound by the allocation above; flags must be 0.
            unsafe {
                cudarc::driver::sys::cuMemHostGetDevicePointer_v2(
                    &mut counts_device,
                    counts_host.cast(),
                    0,
                )
            }
            .result()
            .map_err(driver("mapping the launch counts"))?;
            *scratch = Some(LaunchScratch {
                sbt,
                exceptions,
                counts,
                counts_device,
                sbt_bytes: Vec::new(),
                info: None,
            });
        }
        let Some(scratch) = scratch.as_mut() else {
            return Err(CudaError::Launch("scratch buffers missing".into()));
        };
        // Every launch sees the SBT it is given, as OptiX reads the user's SBT at each launch;
        // the device copy is the pipeline's own and read-only to the programs, so bytes equal
        // to the last launch's are already there.
        if scratch.sbt_bytes != packed.bytes {
            stream
                .memcpy_htod(
                    &packed.bytes[..],
                    &mut scratch.sbt.slice_mut(..packed.bytes.len()),
                )
                .map_err(driver("copying the SBT"))?;
            scratch.sbt_bytes.clone_from(&packed.bytes);
        }
        let base = device_address(&scratch.sbt, stream);
        let exc = device_address(&scratch.exceptions, stream);
        let at = |r: &PackedRegion| base + r.offset as u64;
        let info = LaunchInfo {
            dims: [width, height, depth],
            total,
            raygen: at(&packed.raygen),
            exception: packed.exception.as_ref().map_or(0, at),
            miss: at(&packed.miss),
            hitgroup: at(&packed.hitgroup),
            miss_stride: packed.miss.stride as u32,
            miss_count: packed.miss.count as u32,
            hit_stride: packed.hitgroup.stride as u32,
            hit_count: packed.hitgroup.count as u32,
            exceptions: exc,
            callables: at(&packed.callables),
            callable_stride: packed.callables.stride as u32,
            callable_count: packed.callables.count as u32,
            max_graph_depth: self.max_graph_depth,
            validation: self.context.is_validation_mode() as u32,
        };
        if scratch.info != Some(info) {
            let mut var = guarded("finding the launch information", || {
                self.module.get_global("__oxray_launch", stream)
            })?;
            stream
                .memcpy_htod(bytemuck::bytes_of(&info), &mut var)
                .map_err(driver("copying the launch information"))?;
            scratch.info = Some(info);
        }
        let cfg = LaunchConfig {
            grid_dim: (total.div_ceil(self.block), 1, 1),
            block_dim: (self.block, 1, 1),
            shared_mem_bytes: 0,
        };
        let mut launch = stream.launch_builder(&self.function);
        // SAFETY: the kernel takes no parameters; everything it reads is in the launch
        // information written above (the SBT and exception buffers, alive until the launch is
        // synchronized below while `scratch` is locked) and in the launch parameters and
        // traversables the user's programs read, which the user provides as for OptiX.
        unsafe { launch.launch(cfg) }.map_err(driver("launching a pipeline"))?;
        // The exception count and the trace count (four words) come back without a wait of
        // their own; the records only when there are some.
        let mut counts = stream.launch_builder(&self.ctx.kernels.launch_counts);
        counts.arg(&exc).arg(&scratch.counts_device);
        let one = LaunchConfig {
            grid_dim: (1, 1, 1),
            block_dim: (1, 1, 1),
            shared_mem_bytes: 0,
        };
        // SAFETY: the kernel reads and clears words of the exception buffer (`exc`, at least
        // four words) and writes four words at the device address of `scratch.counts`; both
        // are alive and locked with `scratch`.
        unsafe { counts.launch(one) }.map_err(driver("launching the launch counts"))?;
        self.ctx.synchronize()?;
        let count: [u32; 4] = scratch
            .counts
            .as_slice()
            .map_err(driver("reading the launch counts"))?
            .try_into()
            .map_err(|_| CudaError::Launch("launch counts of the wrong length".into()))?;
        let traces = u64::from(count[2]) | u64::from(count[3]) << 32;
        let mut words = if count[0] > 0 {
            let words = stream
                .clone_dtoh(&scratch.exceptions.slice(..))
                .map_err(driver("copying exception records"))?;
            // The records past the count are never read: clearing the count is enough, and
            // only a launch that raised exceptions needs it (the slot of a record is its count).
            stream
                .memset_zeros(&mut scratch.exceptions.slice_mut(..1))
                .map_err(driver("clearing exception records"))?;
            words
        } else {
            count.to_vec()
        };
        // The report's trace count is this launch's.
        words[2] = traces as u32;
        words[3] = (traces >> 32) as u32;
        Ok(exception_report(&words).settle(&self.context, packed.exception.is_some())?)
    }

    /// [`launch`](Self::launch) with typed launch parameters.
    pub fn launch_with<P: Pod>(
        &self,
        params: &P,
        sbt: &ShaderBindingTable,
        width: u32,
        height: u32,
        depth: u32,
    ) -> Result<LaunchReport, CudaError> {
        self.launch(bytemuck::bytes_of(params), sbt, width, height, depth)
    }
}

/// Device memory holding `len` values of `T`, which programs read and write through its
/// address ([`device_ptr`](Self::device_ptr), put in the launch parameters or SBT data).
pub struct CudaBuffer<T: Pod> {
    ctx: CudaContext,
    bytes: CudaSlice<u8>,
    len: usize,
    _t: PhantomData<T>,
}

impl<T: Pod> std::fmt::Debug for CudaBuffer<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "CudaBuffer({} x {})",
            self.len,
            std::any::type_name::<T>()
        )
    }
}

impl<T: Pod> CudaBuffer<T> {
    /// `len` zeroed values.
    pub fn zeroed(ctx: &CudaContext, len: usize) -> Result<Self, CudaError> {
        let n = (len * std::mem::size_of::<T>()).max(16);
        let bytes = ctx
            .stream
            .alloc_zeros::<u8>(n)
            .map_err(driver("allocating a buffer"))?;
        Ok(CudaBuffer {
            ctx: ctx.clone(),
            bytes,
            len,
            _t: PhantomData,
        })
    }

    /// A copy of `data`.
    pub fn from_slice(ctx: &CudaContext, data: &[T]) -> Result<Self, CudaError> {
        let mut b = Self::zeroed(ctx, data.len())?;
        b.write(data)?;
        Ok(b)
    }

    /// Replaces the contents with `data` (of the same length).
    pub fn write(&mut self, data: &[T]) -> Result<(), CudaError> {
        if data.len() != self.len {
            return Err(CudaError::LengthMismatch {
                rays: data.len(),
                outputs: self.len,
            });
        }
        let src: &[u8] = bytemuck::cast_slice(data);
        if src.is_empty() {
            return Ok(());
        }
        self.ctx
            .stream
            .memcpy_htod(src, &mut self.bytes.slice_mut(..src.len()))
            .map_err(driver("copying a buffer to the device"))
    }

    /// The values, copied to the host.
    pub fn download(&self) -> Result<Vec<T>, CudaError> {
        let mut out = vec![T::zeroed(); self.len];
        let dst: &mut [u8] = bytemuck::cast_slice_mut(&mut out);
        if !dst.is_empty() {
            let n = dst.len();
            self.ctx
                .stream
                .memcpy_dtoh(&self.bytes.slice(..n), dst)
                .map_err(driver("copying a buffer to the host"))?;
            self.ctx.synchronize()?;
        }
        Ok(out)
    }

    /// The device address of the first value (a `T*` for programs).
    #[must_use]
    pub fn device_ptr(&self) -> u64 {
        let (p, _g) = self.bytes.device_ptr(&self.ctx.stream);
        p
    }

    /// Values held.
    #[must_use]
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether it holds no values.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SRC: &str = "#include <optix.h>\n  #  include \"optix_device.h\"\n#include <cuda_fp16.h>\n\
        extern \"C\" __global__ void __raygen__a() {}\nextern \"C\" __global__ void __miss__m() {}\n\
        extern \"C\" __global__ void __closesthit__c () {}\nvoid x__raygen__b() {}\n";

    #[test]
    fn reads_name_each_value_the_programs_may_read() {
        let reads = |srcs: &[&str]| reads(srcs.iter().copied());
        assert_eq!(reads(&["optixSetPayload_0(optixGetRayTmax());"]), 0);
        assert_eq!(reads(&["float3 o = optixGetWorldRayOrigin();"]), 1);
        assert_eq!(reads(&["optixGetObjectRayOrigin()"]), 1 | 4096);
        assert_eq!(
            reads(&["optixGetObjectRayDirection()", "// optixGetRayTime\n"]),
            2 | 8 | 4096
        );
        assert_eq!(
            reads(&["optixIsTriangleHit() ? optixGetAttribute_3() : 0"]),
            128 | 256
        );
        let every: Vec<&str> = READS.iter().flat_map(|(_, n)| n.iter().copied()).collect();
        assert_eq!(reads(&[&every.join(" ")]), 8191);
        // The pipeline's unit says what its programs read: SRC reads none of the values.
        let (_m, g) = groups();
        assert!(pipeline_source(&g).contains("#ifndef OXRAY_READS\n#define OXRAY_READS 0u\n"));
    }

    fn groups() -> (CudaModule, Vec<CudaProgramGroup>) {
        let m = CudaModule::from_source(SRC);
        let g = vec![
            CudaProgramGroup::raygen(&m, "__raygen__a").unwrap(),
            CudaProgramGroup::miss(Some((&m, "__miss__m"))).unwrap(),
            CudaProgramGroup::hit_group(CudaHitGroupDesc {
                closest_hit: Some((&m, "__closesthit__c")),
                ..Default::default()
            })
            .unwrap(),
            CudaProgramGroup::miss(None).unwrap(),
        ];
        (m, g)
    }

    #[test]
    fn entries_are_found_by_name_and_prefix() {
        let (m, _) = groups();
        assert!(m.has_entry("__closesthit__c"));
        assert!(!m.has_entry("__raygen__b"), "only a suffix of another name");
        assert!(matches!(
            CudaProgramGroup::raygen(&m, "__raygen__b"),
            Err(PipelineError::UnknownEntry { .. })
        ));
        assert!(
            CudaProgramGroup::raygen(&m, "__miss__m").is_err(),
            "wrong prefix"
        );
        assert!(CudaProgramGroup::hit_group(CudaHitGroupDesc {
            intersection: Some((&m, "__intersection__i")),
            ..Default::default()
        })
        .is_err());
    }

    #[test]
    fn optix_includes_are_replaced_by_the_header() {
        let s = oxray_core::source::strip_optix_includes(SRC);
        assert!(s.contains("// (oxray device header) #include <optix.h>"));
        assert!(s.contains("// (oxray device header)   #  include \"optix_device.h\""));
        assert!(s.contains("\n#include <cuda_fp16.h>"));
    }

    #[test]
    fn the_unit_dispatches_by_group_index_and_includes_each_module_once() {
        let (_, g) = groups();
        let src = pipeline_source(&g);
        assert_eq!(src.matches("#line 1 \"module").count(), 1);
        let body = |name: &str| {
            let at = src.find(&format!(" {name}(u32 group) {{")).unwrap();
            src[at..at + src[at..].find("\n}\n").unwrap()].to_string()
        };
        // Two miss groups: the record's group index picks the program.
        let miss = body("__oxray_call_miss");
        assert!(miss.contains("case 1: __miss__m(); return;"));
        assert!(
            !miss.contains("case 3:"),
            "a miss group without a program calls nothing"
        );
        // One group of the kind: every record of the region names it (`pack_sbt`), so its
        // program is called without reading the index.
        for (name, call) in [
            ("__oxray_call_raygen", "__raygen__a(); return;"),
            ("__oxray_call_closesthit", "__closesthit__c(); return;"),
        ] {
            let f = body(name);
            assert!(f.contains(call) && !f.contains("switch"), "{f}");
        }
        // No exception group: the exception dispatch calls nothing.
        assert!(!body("__oxray_call_exception").contains("();"));
        let o = pipeline_compile_options(
            (9, 0),
            &PipelineCompileOptions::default(),
            &PipelineLinkOptions { max_trace_depth: 3 },
        );
        assert!(o.contains(&"-DOXRAY_MAX_TRACE_DEPTH=3".to_string()));
        assert!(o.contains(&"-DOXRAY_NUM_PAYLOAD_VALUES=8".to_string()));
        assert!(o.contains(&"--fmad=false".to_string()));
    }

    #[test]
    fn the_sbt_is_packed_with_program_indices_and_the_records_data() {
        let (_, g) = groups();
        let sbt = ShaderBindingTable {
            raygen: SbtRegion::from_records(&[(g[0].pack_header(), [7u32; 3])]),
            miss: SbtRegion::from_records(&[
                (g[1].pack_header(), 1.5f32),
                (g[3].pack_header(), 2.5),
            ]),
            hitgroup: SbtRegion::from_records(&[(g[2].pack_header(), [9u64; 3]); 3]),
            ..Default::default()
        };
        let p = pack_sbt(&g, &sbt).unwrap();
        assert_eq!(
            p.raygen,
            PackedRegion {
                offset: 0,
                stride: 48,
                count: 1
            }
        );
        assert_eq!(
            p.miss,
            PackedRegion {
                offset: 48,
                stride: 48,
                count: 2
            }
        );
        assert_eq!(
            p.hitgroup,
            PackedRegion {
                offset: 144,
                stride: 64,
                count: 3
            }
        );
        assert_eq!(p.exception, None);
        assert_eq!(p.bytes.len(), 144 + 3 * 64);
        let word = |o: usize| u32::from_le_bytes(p.bytes[o..o + 4].try_into().unwrap());
        assert_eq!((word(0), word(4), word(8)), (0, 0, 0));
        assert_eq!(word(32), 7);
        assert_eq!((word(48), word(52)), (1, 1));
        assert_eq!((word(96), word(100)), (3, 1));
        assert_eq!(f32::from_bits(word(96 + 32)), 2.5);
        for r in 0..3 {
            assert_eq!((word(144 + 64 * r), word(148 + 64 * r)), (2, 3));
            assert_eq!(word(144 + 64 * r + 32), 9);
        }
    }

    #[test]
    fn callables_and_intersection_programs_are_dispatched_by_group() {
        let m = CudaModule::from_source(
            "extern \"C\" __global__ void __raygen__a() {}\n\
             extern \"C\" __global__ void __intersection__i() {}\n\
             extern \"C\" __device__ float __direct_callable__d(float x) { return x; }\n\
             extern \"C\" __device__ void __continuation_callable__c() {}\n",
        );
        let g = vec![
            CudaProgramGroup::raygen(&m, "__raygen__a").unwrap(),
            CudaProgramGroup::hit_group(CudaHitGroupDesc {
                intersection: Some((&m, "__intersection__i")),
                ..Default::default()
            })
            .unwrap(),
            CudaProgramGroup::callables(Some((&m, "__direct_callable__d")), None).unwrap(),
            CudaProgramGroup::callables(None, Some((&m, "__continuation_callable__c"))).unwrap(),
            CudaProgramGroup::callables(
                Some((&m, "__direct_callable__d")),
                Some((&m, "__continuation_callable__c")),
            )
            .unwrap(),
        ];
        assert_eq!(g[2].kind(), CudaProgramGroupKind::Callables);
        let src = pipeline_source(&g);
        assert_eq!(src.matches("#line 1 \"module").count(), 1);
        let body = |name: &str| {
            let at = src.find(&format!(" {name}(u32 group) {{")).unwrap();
            src[at..at + src[at..].find("\n}\n").unwrap()].to_string()
        };
        // The one hit group's programs, called without reading the record's group index.
        let is = body("__oxray_call_intersection");
        assert!(is.contains("__intersection__i(); return;") && !is.contains("switch"));
        let has = body("__oxray_has_intersection");
        assert!(has.contains("return true;") && !has.contains("switch"));
        assert!(body("__oxray_has_anyhit").contains("return false;"));
        let dc = body("__oxray_dc_of");
        assert!(dc.contains("case 2: return reinterpret_cast<void*>(&__direct_callable__d);"));
        assert!(dc.contains("case 4:") && !dc.contains("case 3:"));
        assert!(dc.contains("default: return nullptr;"));
        let cc = body("__oxray_cc_of");
        assert!(cc.contains("case 3: return reinterpret_cast<void*>(&__continuation_callable__c);"));
        assert!(cc.contains("case 4:") && !cc.contains("case 2:"));
        // A direct callable is no closest-hit program.
        assert!(!body("__oxray_call_closesthit").contains("__direct_callable__d"));
        let o = pipeline_compile_options(
            (9, 0),
            &PipelineCompileOptions {
                num_attribute_values: 0,
                traversable_graph_flags: oxray_core::TraversableGraphFlags::ALLOW_SINGLE_GAS,
                ..Default::default()
            },
            &PipelineLinkOptions::default(),
        );
        assert!(o.contains(&"-DOXRAY_NUM_ATTRIBUTE_VALUES=2".to_string()));
        assert!(o.contains(&"-DOXRAY_GRAPH_FLAGS=1u".to_string()));
        assert!(o.contains(&format!(
            "-DOXRAY_BVH2_STACK={}",
            oxray_bvh::MAX_BVH2_DEPTH + 2
        )));
    }

    #[test]
    fn the_callables_region_is_packed_like_the_others() {
        let m = CudaModule::from_source(
            "extern \"C\" __global__ void __raygen__a() {}\n\
             extern \"C\" __device__ float __direct_callable__d(float x) { return x; }\n",
        );
        let rg = CudaProgramGroup::raygen(&m, "__raygen__a").unwrap();
        let cl = CudaProgramGroup::callables(Some((&m, "__direct_callable__d")), None).unwrap();
        let g = vec![rg.clone(), cl.clone()];
        let sbt = ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[rg.pack_header()]),
            callables: SbtRegion::from_records(&[
                (cl.pack_header(), [1.0f32, 2.0]),
                (cl.pack_header(), [3.0, 4.0]),
            ]),
            ..Default::default()
        };
        let p = pack_sbt(&g, &sbt).unwrap();
        assert_eq!(
            p.callables,
            PackedRegion {
                offset: 32,
                stride: 48,
                count: 2
            }
        );
        let word = |o: usize| u32::from_le_bytes(p.bytes[o..o + 4].try_into().unwrap());
        assert_eq!(
            (word(32), word(36)),
            (1, CudaProgramGroupKind::Callables as u32)
        );
        assert_eq!(f32::from_bits(word(32 + 32)), 1.0);
        assert_eq!(f32::from_bits(word(32 + 48 + 36)), 4.0);
        // A group of another kind in the region is refused.
        let bad = ShaderBindingTable {
            callables: SbtRegion::from_headers(&[rg.pack_header()]),
            ..sbt
        };
        assert!(matches!(
            pack_sbt(&g, &bad),
            Err(LaunchError::InvalidSbtRecord {
                region: "callables",
                ..
            })
        ));
        // An empty region packs to no records.
        let none = ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[rg.pack_header()]),
            ..Default::default()
        };
        assert_eq!(pack_sbt(&g, &none).unwrap().callables.count, 0);
        assert!(stack_bytes(2, 31, false) > stack_bytes(2, 2, false));
        assert!(stack_bytes(1, 2, false) >= 4096 + 2 * (BVH2_STACK * 12));
        assert_eq!(
            stack_bytes(3, 2, true) - stack_bytes(3, 2, false),
            3 * CURVE_STACK
        );
        use oxray_core::PrimitiveTypeFlags as F;
        assert!(!uses_curves(F::empty()));
        assert!(!uses_curves(F::TRIANGLE | F::CUSTOM | F::SPHERE));
        assert!(uses_curves(F::ROUND_LINEAR));
        assert!(uses_curves(F::TRIANGLE | F::ROUND_CUBIC_BEZIER_ROCAPS));
    }

    #[test]
    fn bad_sbt_records_are_refused_as_on_the_cpu() {
        let (_, g) = groups();
        let rg = SbtRegion::from_headers(&[g[0].pack_header()]);
        let bad = |sbt: ShaderBindingTable| match pack_sbt(&g, &sbt) {
            Err(LaunchError::InvalidSbtRecord { region, reason, .. }) => (region, reason),
            other => panic!("{other:?}"),
        };
        // A CPU header, a group of another pipeline, a group of the wrong kind.
        let cpu = SbtHeader::for_group(1);
        let other = CudaProgramGroup::miss(None).unwrap();
        let (region, reason) = bad(ShaderBindingTable {
            raygen: rg.clone(),
            miss: SbtRegion::from_headers(&[cpu]),
            ..Default::default()
        });
        assert_eq!(region, "miss");
        assert!(reason.contains("CUDA"));
        let (_, reason) = bad(ShaderBindingTable {
            raygen: rg.clone(),
            hitgroup: SbtRegion::from_headers(&[other.pack_header()]),
            ..Default::default()
        });
        assert!(reason.contains("not in this pipeline"));
        let (_, reason) = bad(ShaderBindingTable {
            raygen: rg,
            hitgroup: SbtRegion::from_headers(&[g[1].pack_header()]),
            ..Default::default()
        });
        assert!(reason.contains("another kind"));
        assert_eq!(
            pack_sbt(&g, &ShaderBindingTable::default()),
            Err(LaunchError::NoRaygenRecord)
        );
    }

    #[test]
    fn only_constant_parameter_variables_count_as_unchanged_between_launches() {
        let ptx = ".const .align 8 .b8 params[32];\n.global .align 4 .b8 state[16];\n\
                   .visible .const .align 4 .u32 count;\n.const .align 8 .b8 params_two[8];";
        assert!(declared_constant(ptx, "params"));
        assert!(declared_constant(ptx, "count"));
        assert!(!declared_constant(ptx, "state"), "a __device__ variable");
        assert!(!declared_constant(ptx, "param"), "a prefix of another name");
        assert!(!declared_constant(ptx, "missing"));
    }

    #[test]
    fn launch_sizes_follow_the_guide() {
        assert_eq!(launch_size(4, 3, 2), Ok(24));
        assert_eq!(launch_size(1 << 15, 1 << 15, 1), Ok(1 << 30));
        assert!(launch_size(1 << 15, 1 << 15, 2).is_err());
        assert!(launch_size(u32::MAX, u32::MAX, u32::MAX).is_err());
        assert_eq!(launch_size(0, 5, 5), Ok(0));
    }

    #[test]
    fn launch_information_matches_the_device_struct() {
        // uint3 + u32, four addresses, four u32, two addresses, four u32: 96 bytes, 8-aligned.
        assert_eq!(std::mem::size_of::<LaunchInfo>(), 96);
        assert_eq!(std::mem::offset_of!(LaunchInfo, raygen), 16);
        assert_eq!(std::mem::offset_of!(LaunchInfo, miss_stride), 48);
        assert_eq!(std::mem::offset_of!(LaunchInfo, exceptions), 64);
        assert_eq!(std::mem::offset_of!(LaunchInfo, callables), 72);
        assert_eq!(std::mem::offset_of!(LaunchInfo, callable_stride), 80);
        assert_eq!(std::mem::offset_of!(LaunchInfo, max_graph_depth), 88);
        assert!(DEVICE_HEADER.contains("struct __oxray_LaunchInfo"));
    }

    #[test]
    fn exception_records_become_a_report_sorted_by_launch_index() {
        let mut w = vec![0u32; 16 + 16 * EXCEPTION_RECORDS];
        w[0] = 7;
        for (k, idx) in [
            [5, 0, 0],
            [1, 1, 0],
            [3, 0, 0],
            [0, 0, 1],
            [2, 0, 0],
            [4, 0, 0],
            [0, 1, 0],
        ]
        .into_iter()
        .enumerate()
        {
            let r = &mut w[16 + 16 * k..32 + 16 * k];
            r[..3].copy_from_slice(&idx);
            r[3] = (-2i32) as u32;
            r[4] = k as u32;
            r[12] = 1;
        }
        let report = exception_report(&w);
        assert_eq!(report.exceptions, 7);
        let idx: Vec<_> = report.first_exceptions.iter().map(|(i, _)| *i).collect();
        assert_eq!(idx, [[2, 0, 0], [3, 0, 0], [4, 0, 0], [5, 0, 0], [0, 1, 0]]);
        let e = &report.first_exceptions[0].1;
        assert_eq!(e.code, ExceptionCode::TRACE_DEPTH_EXCEEDED);
        assert_eq!(e.details(), &[4]);
    }
}
