//! The memory query that precedes a build (`optixAccelComputeMemoryUsage`, guide §5).

use crate::bvh4::Bvh4Node;
use crate::gas::InputRecord;
use crate::triangle4::Triangle4;
use oxray_core::validate::{validate_structure, InputSummary};
use oxray_core::{Aabb, BuildError, BuildInput, BuildOptions};

/// Buffer sizes for a build (`OptixAccelBufferSizes`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[doc(alias = "OptixAccelBufferSizes")]
pub struct AccelBufferSizes {
    /// Upper bound of the bytes the built structure occupies ([`GasData::memory`](crate::GasData::memory)).
    pub output_size_in_bytes: usize,
    /// Upper bound of the working memory the build allocates and frees.
    pub temp_size_in_bytes: usize,
    /// Working memory of an update; 0 unless `ALLOW_UPDATE` is set.
    pub temp_update_size_in_bytes: usize,
}

/// Computes the buffer sizes of a build without building, from the inputs' declared counts
/// (the buffers' contents are not read). Validates the inputs as the build would, short of
/// the checks that need the data (index and SBT offset ranges).
///
/// ```
/// use oxray_bvh::{compute_memory_usage, GasData};
/// use oxray_core::{BuildInput, BuildOptions, TriangleInput, VertexBuffer};
/// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
/// let inputs = [BuildInput::from(TriangleInput::new(VertexBuffer::f32x3(&v)))];
/// let sizes = compute_memory_usage(&BuildOptions::default(), &inputs)?;
/// let gas = GasData::build(&BuildOptions::default(), &inputs)?;
/// assert!(gas.memory().output_bytes <= sizes.output_size_in_bytes);
/// # Ok::<(), oxray_core::BuildError>(())
/// ```
pub fn compute_memory_usage(
    options: &BuildOptions,
    inputs: &[BuildInput<'_>],
) -> Result<AccelBufferSizes, BuildError> {
    let summary = validate_structure(options, inputs)?;
    let mut sizes = sizes_for(&summary, inputs.len());
    if summary.kind == oxray_core::BuildInputKind::Triangles {
        if let Some(splits) = crate::gas::spatial_splits(options) {
            // Spatial splits reference a triangle from several leaves: more leaf slots and
            // nodes, bounded by the split budget; and the builder's copy of the triangles and
            // its per-node reference lists.
            let n = summary.num_primitives as usize;
            let refs = splits.max_references(n);
            sizes.output_size_in_bytes = output_bound(&summary, inputs.len(), refs);
            sizes.temp_size_in_bytes += n * std::mem::size_of::<[[f32; 3]; 3]>()
                + 3 * refs * std::mem::size_of::<Aabb>()
                + crate::build::temp_bytes(refs);
        }
    }
    if summary.kind == oxray_core::BuildInputKind::Curves {
        if let Some(splits) = crate::gas::curve_splits(options) {
            // Curve splitting (guide §9.2) references a segment from up to `max_pieces`
            // leaves: more leaf slots and nodes, and the builder's references (ids and boxes).
            let n = summary.num_primitives as usize;
            let refs = n * splits.max_pieces.max(1) as usize;
            sizes.output_size_in_bytes = output_bound(&summary, inputs.len(), refs);
            sizes.temp_size_in_bytes +=
                2 * refs * std::mem::size_of::<(u32, Aabb)>() + crate::build::temp_bytes(refs);
        }
    }
    if options.motion.has_motion() {
        // Every later key keeps its own copy of the primitives (no more than one block or box
        // per primitive each), and the builder decodes every key (guide §5.10.2).
        let n = summary.num_primitives as usize;
        let later = options.motion.key_count() - 1;
        let (per_prim, decoded) = match summary.kind {
            oxray_core::BuildInputKind::Triangles => (
                std::mem::size_of::<Triangle4>(),
                std::mem::size_of::<[[f32; 3]; 3]>(),
            ),
            // One segment record per leaf slot, up to `max_pieces` slots per segment where
            // segments are split (§9.2); every key is decoded before the build.
            oxray_core::BuildInputKind::Curves => {
                let pieces = crate::gas::curve_splits(options).map_or(1, |s| s.max_pieces.max(1));
                let record = std::mem::size_of::<crate::CurveSegment>();
                (record * pieces as usize, record)
            }
            _ => (
                std::mem::size_of::<Aabb>(),
                std::mem::size_of::<[[f32; 3]; 3]>(),
            ),
        };
        sizes.output_size_in_bytes += later * n * per_prim;
        sizes.temp_size_in_bytes += (later + 1) * n * decoded;
        // The time parts (`MotionSegments`): a copy of the nodes each.
        let parts = crate::motion::MotionSegments::per_interval(later as u32)
            .filter(|_| {
                !options
                    .flags
                    .contains(oxray_core::BuildFlags::PREFER_FAST_BUILD)
            })
            .map_or(0, |m| m as usize * later);
        let refs = match summary.kind {
            oxray_core::BuildInputKind::Curves => {
                n * crate::gas::curve_splits(options).map_or(1, |s| s.max_pieces.max(1) as usize)
            }
            _ => n,
        };
        sizes.output_size_in_bytes += parts
            * refs.saturating_sub(1).max(1)
            * (std::mem::size_of::<Bvh4Node>() + std::mem::size_of::<crate::Bvh8Node>());
    }
    if options.flags.contains(oxray_core::BuildFlags::ALLOW_UPDATE) {
        // A refit works in place: the table of input starts and the thread pool's jobs.
        sizes.temp_update_size_in_bytes = inputs.len() * 4 + FIXED_TEMP;
    }
    Ok(sizes)
}

/// The sizes for validated inputs of `num_inputs` build inputs.
#[must_use]
pub fn sizes_for(s: &InputSummary, num_inputs: usize) -> AccelBufferSizes {
    let n = s.num_primitives as usize;
    let output = output_bound(s, num_inputs, n);
    // Decoded primitives (bounds and vertices) + the binary tree and its working set + the map
    // from active primitives to global ids.
    let temp = n * (std::mem::size_of::<Aabb>() + std::mem::size_of::<[[f32; 3]; 3]>() + 4)
        + n * std::mem::size_of::<Option<Aabb>>()
        + crate::build::temp_bytes(n)
        + FIXED_TEMP;
    AccelBufferSizes {
        output_size_in_bytes: output,
        temp_size_in_bytes: temp,
        temp_update_size_in_bytes: 0,
    }
}

/// The output bound for `refs` leaf references (one per primitive; more with spatial splits).
fn output_bound(s: &InputSummary, num_inputs: usize, refs: usize) -> usize {
    let n = refs;
    let per_input_prims = s.num_primitives as usize;
    // A 4-wide (or 8-wide) node absorbs at least one binary inner node, and a binary tree over n
    // leaves has n - 1 inner nodes, so n - 1 nodes (and the root) always suffice; the CPU
    // backend may keep both layouts.
    let nodes = n.saturating_sub(1).max(1)
        * (std::mem::size_of::<Bvh4Node>() + std::mem::size_of::<crate::Bvh8Node>());
    // Triangles go in blocks of four, a leaf starting a new block: a leaf of c triangles takes
    // ceil(c / 4) <= c blocks, so at most one block (and four slots) per triangle.
    let (per_prim, slots) = match s.kind {
        oxray_core::BuildInputKind::Triangles => (std::mem::size_of::<Triangle4>(), 4),
        // One segment record per leaf slot.
        oxray_core::BuildInputKind::Curves => (std::mem::size_of::<crate::CurveSegment>(), 1),
        _ => (std::mem::size_of::<Aabb>(), 1),
    };
    // Slot-to-primitive map, and per-primitive SBT offsets (kept only when some input has more
    // than one record, but bounded here by counts alone).
    let ids = n * 4 * slots + per_input_prims * 4;
    let inputs = num_inputs
        * (std::mem::size_of::<InputRecord>() + std::mem::size_of::<crate::InputShape>())
        + s.num_sbt_records as usize * 4;
    nodes + n * per_prim + ids + inputs + FIXED_OUTPUT
}

/// Bytes every structure may take beyond its per-primitive data (the root node, small tables).
const FIXED_OUTPUT: usize = 1024;
/// Working memory every build may take beyond its per-primitive data (thread-pool jobs, small
/// scratch arrays).
const FIXED_TEMP: usize = 16 * 1024;
