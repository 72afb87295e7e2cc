//! Typed errors. Each carries its context and maps to the guide's `OptixResult` code.

use crate::input::BuildInputKind;
use thiserror::Error;

/// The `OptixResult` codes that oxray's errors map to (guide §3.1; values from the OptiX headers).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u32)]
#[doc(alias = "OptixResult")]
pub enum ErrorCode {
    /// `OPTIX_ERROR_INVALID_VALUE`.
    InvalidValue = 7001,
    /// `OPTIX_ERROR_INVALID_INPUT`.
    InvalidInput = 7200,
    /// `OPTIX_ERROR_VALIDATION_FAILURE`.
    ValidationFailure = 7053,
    /// `OPTIX_ERROR_INVALID_LAUNCH_PARAMETER`.
    InvalidLaunchParameter = 7201,
    /// `OPTIX_ERROR_NOT_SUPPORTED`.
    NotSupported = 7800,
}

/// Where in a build an offending value lies: which build input and, where known, which primitive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InputLocation {
    /// Index of the build input.
    pub input: usize,
}

impl std::fmt::Display for InputLocation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "build input {}", self.input)
    }
}

/// Which buffer of a build input an error is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BufferKind {
    /// The vertex buffer.
    Vertices,
    /// The index buffer.
    Indices,
    /// The AABB buffer.
    Aabbs,
    /// The SBT index offset buffer.
    SbtIndexOffsets,
    /// A sphere input's radius buffer, or a curve input's width (radius) buffer.
    Radii,
    /// A ribbon input's normal buffer.
    Normals,
}

impl std::fmt::Display for BufferKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            BufferKind::Vertices => "vertex buffer",
            BufferKind::Indices => "index buffer",
            BufferKind::Aabbs => "AABB buffer",
            BufferKind::SbtIndexOffsets => "SBT index offset buffer",
            BufferKind::Radii => "radius buffer",
            BufferKind::Normals => "normal buffer",
        })
    }
}

/// Why an acceleration-structure build (or its memory query) was refused.
#[derive(Debug, Error, Clone, PartialEq)]
#[non_exhaustive]
pub enum BuildError {
    /// A GAS build needs at least one build input (guide §5).
    #[error("a geometry acceleration structure needs at least one build input")]
    NoBuildInputs,
    /// All build inputs of one GAS must have the same type (guide §5).
    #[error("build input {index} is {found} but build input 0 is {expected}: all inputs of one GAS must have the same type")]
    MixedInputTypes {
        /// Index of the first input of another kind.
        index: usize,
        /// Kind of input 0.
        expected: BuildInputKind,
        /// Kind of the offending input.
        found: BuildInputKind,
    },
    /// `PREFER_FAST_TRACE` and `PREFER_FAST_BUILD` exclude each other (guide §5.5).
    #[error("build flags PREFER_FAST_TRACE and PREFER_FAST_BUILD are mutually exclusive")]
    ConflictingBuildFlags,
    /// A child of an instance or transform lives on another backend than the build's device.
    #[error("instance {instance}: its child lives on the {found} backend, not on the {device} device building the IAS")]
    ForeignTraversable {
        /// The instance.
        instance: u32,
        /// The backend of the building device.
        device: crate::handle::BackendKind,
        /// The backend the child lives on.
        found: crate::handle::BackendKind,
    },
    /// The device failed (out of memory, a driver error).
    #[error("device error: {0}")]
    Device(String),
    /// The operation is not available (yet) for this structure.
    #[error("{0} is not supported by this build")]
    Unsupported(&'static str),
    /// A GAS may hold at most 2^29 primitives (guide §12).
    #[error("{count} primitives exceed the limit of {limit} per geometry acceleration structure")]
    TooManyPrimitives {
        /// Primitives over all inputs.
        count: u64,
        /// The limit, 2^29.
        limit: u64,
    },
    /// A GAS may reference at most 2^24 SBT records (guide §12).
    #[error("{count} SBT records exceed the limit of {limit} per geometry acceleration structure")]
    TooManySbtRecords {
        /// SBT records over all inputs.
        count: u64,
        /// The limit, 2^24.
        limit: u64,
    },
    /// Every build input uses at least one SBT record (guide §5.1).
    #[error("{at}: numSbtRecords is 0 (the flags slice is empty); every input needs at least one SBT record")]
    NoSbtRecords {
        /// The input.
        at: InputLocation,
    },
    /// An input with more than one SBT record needs per-primitive SBT index offsets (guide §5.1).
    #[error("{at}: {num_sbt_records} SBT records but no SBT index offset buffer")]
    MissingSbtIndexOffsets {
        /// The input.
        at: InputLocation,
        /// Its number of SBT records.
        num_sbt_records: u32,
    },
    /// A per-primitive SBT index offset must lie in `[0, numSbtRecords)` (guide §5.1).
    #[error("{at}, primitive {primitive}: SBT index offset {offset} is out of range (numSbtRecords = {num_sbt_records})")]
    SbtIndexOffsetOutOfRange {
        /// The input.
        at: InputLocation,
        /// Primitive within the input.
        primitive: u32,
        /// The offending offset.
        offset: u32,
        /// The input's number of SBT records.
        num_sbt_records: u32,
    },
    /// A stride is smaller than one element or breaks the element's alignment.
    #[error("{at}: {buffer} stride {stride} is invalid ({reason})")]
    InvalidStride {
        /// The input.
        at: InputLocation,
        /// Which buffer.
        buffer: BufferKind,
        /// The stride given.
        stride: u32,
        /// What rule it breaks.
        reason: &'static str,
    },
    /// A buffer is shorter than its declared count and stride require.
    #[error("{at}: {buffer} holds {len} bytes but {count} elements need {needed}")]
    BufferTooSmall {
        /// The input.
        at: InputLocation,
        /// Which buffer.
        buffer: BufferKind,
        /// Elements declared.
        count: u64,
        /// Bytes needed.
        needed: u64,
        /// Bytes given.
        len: u64,
    },
    /// A triangle soup (no index buffer) needs a multiple of three vertices.
    #[error("{at}: {count} vertices without an index buffer is not a multiple of 3")]
    VertexCountNotMultipleOfThree {
        /// The input.
        at: InputLocation,
        /// The vertex count.
        count: u32,
    },
    /// An index refers past the end of the vertex buffer.
    #[error(
        "{at}, triangle {triangle}: vertex index {index} is out of range ({num_vertices} vertices)"
    )]
    IndexOutOfRange {
        /// The input.
        at: InputLocation,
        /// Triangle within the input.
        triangle: u32,
        /// The offending index.
        index: u32,
        /// Vertices in the input.
        num_vertices: u32,
    },
    /// Instance build inputs belong in an IAS, not a GAS (guide §5).
    #[error("build input {index} holds instances: instances are built into an IAS, not a GAS")]
    InstancesInGas {
        /// The input.
        index: usize,
    },
    /// An IAS takes exactly one build input (guide §5.4).
    #[error("an instance acceleration structure takes exactly one build input, not {count}")]
    IasInputCount {
        /// Inputs given.
        count: usize,
    },
    /// An IAS's input must hold instances.
    #[error("an instance acceleration structure needs an instance input, not {found}")]
    NotInstances {
        /// Kind given.
        found: BuildInputKind,
    },
    /// An IAS holds at most 2^28 instances (guide §12).
    #[error("{count} instances exceed the limit of {limit} per instance acceleration structure")]
    TooManyInstances {
        /// Instances given.
        count: u64,
        /// The limit.
        limit: u64,
    },
    /// An instance field has bits set above its limit (guide §5.4, §12: they must be zero).
    #[error("instance {instance}: {field} {value:#x} has bits above its {bits}-bit limit")]
    InstanceFieldOutOfRange {
        /// The instance.
        instance: u32,
        /// The field.
        field: &'static str,
        /// Its value.
        value: u32,
        /// Bits allowed.
        bits: u32,
    },
    /// `DISABLE_ANYHIT` and `ENFORCE_ANYHIT` exclude each other.
    #[error("instance {instance}: flags DISABLE_ANYHIT and ENFORCE_ANYHIT are mutually exclusive")]
    ConflictingInstanceFlags {
        /// The instance.
        instance: u32,
    },
    /// A transform is singular or not finite.
    #[error("{}transform is singular or not finite", match instance { Some(i) => format!("instance {i}: "), None => String::new() })]
    InvalidTransform {
        /// The instance, or `None` for a static transform.
        instance: Option<u32>,
    },
    /// The traversable graph may be at most 31 levels deep (guide §12).
    #[error("traversable graph depth {depth} exceeds {limit}")]
    GraphTooDeep {
        /// The depth.
        depth: u32,
        /// The limit.
        limit: u32,
    },
    /// An update (`BuildOperation::Update`, guide §5.6) that breaks one of the guide's rules
    /// on updates: the structure must have been built with `ALLOW_UPDATE`, with the same
    /// options and the same inputs up to buffer contents.
    #[error("update refused: {0}")]
    InvalidUpdate(UpdateRule),
    /// Compaction (guide §5.8) of a structure built without `ALLOW_COMPACTION`.
    #[error("compaction needs a structure built with ALLOW_COMPACTION (guide §5.8)")]
    CompactionNotAllowed,
    /// A build input gives one vertex (or box, or radius) buffer per motion key of the build
    /// (guide §5.3, §5.10.2).
    #[error(
        "{at}: {given} {buffer}s, but the build has {expected} motion key(s) and takes one per key"
    )]
    MotionKeyCount {
        /// The input.
        at: InputLocation,
        /// Which buffers.
        buffer: BufferKind,
        /// Buffers given.
        given: usize,
        /// Motion keys of the build.
        expected: usize,
    },
    /// A curve segment whose control points run past the vertex buffer (guide §5.2: segment
    /// `i` uses `v[index[i]] ..= v[index[i] + degree]`).
    #[error("{at}, segment {segment}: first control point {index} + {control_points} control points exceed {num_vertices} vertices")]
    CurveIndexOutOfRange {
        /// The input.
        at: InputLocation,
        /// The segment.
        segment: u32,
        /// Its first control point.
        index: u32,
        /// Control points per segment of the curve type.
        control_points: u32,
        /// Vertices of the input.
        num_vertices: u32,
    },
    /// `OPTIX_CURVE_ENDCAP_ON` on a linear curve input, which always has round caps (guide
    /// §5.2), or normals on a curve input that is not a ribbon (only ribbons are oriented,
    /// §5.2).
    #[error("{at}: {reason}")]
    InvalidCurveInput {
        /// The input.
        at: InputLocation,
        /// What is wrong.
        reason: &'static str,
    },
    /// Motion options that break a rule of guide §5.10.1.
    #[error("invalid motion options: {0}")]
    InvalidMotionOptions(crate::motion::MotionRule),
    /// A key of a motion transform that breaks a rule of guide §5.10.4–§5.10.6.
    #[error("motion transform key {key}: {rule}")]
    InvalidMotionKey {
        /// The key (the count of keys given, for a wrong count).
        key: usize,
        /// The rule it breaks.
        rule: crate::motion_transform::MotionKeyRule,
    },
    /// A motion key buffer of a build input differs from key 0 in its count or format
    /// (guide §5.10.2: every key describes the same primitives).
    #[error("{at}: motion key {key}'s {buffer} differs from key 0's in count or format")]
    MotionKeyMismatch {
        /// The input.
        at: InputLocation,
        /// The key.
        key: usize,
        /// Which buffers.
        buffer: BufferKind,
    },
    /// `primitiveIndexOffset + numPrimitives` must fit in 32 bits.
    #[error("{at}: primitive index offset {offset} + {count} primitives overflows 32 bits")]
    PrimitiveIndexOffsetOverflow {
        /// The input.
        at: InputLocation,
        /// The offset.
        offset: u32,
        /// Primitives in the input.
        count: u32,
    },
}

impl BuildError {
    /// Shorthand for an instance field with bits above its limit.
    #[must_use]
    pub fn field(instance: u32, field: &'static str, value: u32, bits: u32) -> Self {
        BuildError::InstanceFieldOutOfRange {
            instance,
            field,
            value,
            bits,
        }
    }

    /// The `OptixResult` code the guide gives for this error.
    #[doc(alias = "OptixResult")]
    #[must_use]
    pub fn code(&self) -> ErrorCode {
        match self {
            BuildError::Unsupported(_) => ErrorCode::NotSupported,
            BuildError::NoBuildInputs
            | BuildError::ConflictingBuildFlags
            | BuildError::CompactionNotAllowed
            | BuildError::MotionKeyCount { .. }
            | BuildError::InvalidCurveInput { .. }
            | BuildError::InvalidMotionOptions(_)
            | BuildError::InvalidMotionKey { .. }
            | BuildError::InvalidUpdate(
                UpdateRule::NoStructure | UpdateRule::NotAnUpdate | UpdateRule::NotAllowed,
            ) => ErrorCode::InvalidValue,
            _ => ErrorCode::InvalidInput,
        }
    }
}

/// The rule of guide §5.6 (and §5.8 for compacted structures) an update breaks: what differs
/// from the build that made the structure. "Only the device pointers and/or their buffer
/// content may be changed. You cannot change the number of build inputs, the build input
/// types, build flags, traversable handles for instances (for an instance-AS), or the number
/// of vertices, indices, AABBs, instances, SBT records or motion keys."
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum UpdateRule {
    /// A build call with `operation = Update`: an update applies to an existing structure
    /// (§5.6, Listing 5.9: "call `optixAccelBuild` on the same output data").
    NoStructure,
    /// An update call whose options say `operation = Build` (§5.6, Listing 5.9).
    NotAnUpdate,
    /// The structure was built without `ALLOW_UPDATE` (§5.6: "To allow for future updates ...
    /// set `OPTIX_BUILD_FLAG_ALLOW_UPDATE`"; §5.8 for a compacted structure).
    NotAllowed,
    /// The build flags differ from the build's (§5.6: "All other options are required to be
    /// identical to the original build").
    Flags {
        /// Flags of the build.
        built: crate::options::BuildFlags,
        /// Flags of the update.
        given: crate::options::BuildFlags,
    },
    /// The number of build inputs differs (§5.6).
    InputCount {
        /// Inputs of the build.
        built: usize,
        /// Inputs of the update.
        given: usize,
    },
    /// A build input's type differs (§5.6).
    InputKind {
        /// The input.
        input: usize,
        /// Its type at the build.
        built: BuildInputKind,
        /// Its type now.
        given: BuildInputKind,
    },
    /// A count differs: vertices, indices, AABBs, instances or SBT records (§5.6).
    Count {
        /// The input.
        input: usize,
        /// What is counted.
        what: &'static str,
        /// The count at the build.
        built: u64,
        /// The count now.
        given: u64,
    },
    /// A part of the input's description other than a buffer's contents differs: a vertex or
    /// index format, an index buffer, pre-transform or SBT index offset buffer present at one
    /// call and not the other, the SBT index offset size, the primitive index offset, or the
    /// geometry flags of an SBT record (§5.6: only device pointers and buffer contents may
    /// change).
    Description {
        /// The input.
        input: usize,
        /// What differs.
        what: &'static str,
    },
    /// An instance's child is not the structure it was built with, nor an update of it (§5.6:
    /// "traversable handles for instances" may not change).
    InstanceChild {
        /// The instance (index in the build input).
        instance: u32,
    },
    /// The motion options differ from the build's (§5.6: the number of motion keys may not
    /// change, and the other options must be identical).
    Motion {
        /// Options of the build.
        built: crate::motion::MotionOptions,
        /// Options of the update.
        given: crate::motion::MotionOptions,
    },
}

impl std::fmt::Display for UpdateRule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            UpdateRule::Motion { built, given } => write!(
                f,
                "motion options {given:?} differ from the build's {built:?} (guide §5.6: the \
                 number of motion keys may not change)"
            ),
            UpdateRule::NoStructure => write!(
                f,
                "operation Update needs the structure to update; build with operation Build, or \
                 call the update function with the structure (guide §5.6)"
            ),
            UpdateRule::NotAnUpdate => write!(
                f,
                "the options of an update must say operation Update (guide §5.6, Listing 5.9)"
            ),
            UpdateRule::NotAllowed => write!(
                f,
                "the structure was built without ALLOW_UPDATE (guide §5.6, §5.8)"
            ),
            UpdateRule::Flags { built, given } => write!(
                f,
                "build flags {given:?} differ from the build's {built:?} (guide §5.6: all other \
                 options must be identical)"
            ),
            UpdateRule::InputCount { built, given } => write!(
                f,
                "{given} build inputs but the structure was built from {built} (guide §5.6)"
            ),
            UpdateRule::InputKind {
                input,
                built,
                given,
            } => write!(
                f,
                "build input {input} is {given} but was {built} (guide §5.6: input types may \
                 not change)"
            ),
            UpdateRule::Count {
                input,
                what,
                built,
                given,
            } => write!(
                f,
                "build input {input}: {given} {what} but the build had {built} (guide §5.6: \
                 counts may not change)"
            ),
            UpdateRule::Description { input, what } => write!(
                f,
                "build input {input}: {what} differs from the build (guide §5.6: only buffer \
                 pointers and contents may change)"
            ),
            UpdateRule::InstanceChild { instance } => write!(
                f,
                "instance {instance}: its child is not the structure the IAS was built over, \
                 nor an update of it (guide §5.6: instance traversable handles may not change)"
            ),
        }
    }
}

/// Why bytes could not be loaded as an acceleration structure (serialization, beyond guide
/// §5.7's relocation). Every check happens before the structure is used, and sizes are checked
/// against the bytes given before anything is allocated.
#[derive(Debug, Error, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum LoadError {
    /// The bytes do not start with the format's magic number.
    #[error("not an oxray acceleration structure (bad magic number)")]
    BadMagic,
    /// Written by a version of the format this build cannot read.
    #[error("format version {found} is not supported (this build reads version {supported})")]
    UnsupportedVersion {
        /// Version in the bytes.
        found: u32,
        /// Version this build reads.
        supported: u32,
    },
    /// A GAS where an IAS was expected, or the other way round.
    #[error("the bytes hold a {found}, not a {expected}")]
    WrongKind {
        /// What the caller asked for.
        expected: &'static str,
        /// What the bytes hold.
        found: &'static str,
    },
    /// The bytes end before the data they declare.
    #[error("truncated: {needed} bytes needed for {what}, {available} available")]
    Truncated {
        /// What was being read.
        what: &'static str,
        /// Bytes needed.
        needed: u64,
        /// Bytes left.
        available: u64,
    },
    /// Bytes after the end of the structure.
    #[error("{0} unexpected bytes after the structure")]
    TrailingBytes(u64),
    /// The checksum over the payload does not match: the bytes were damaged.
    #[error("checksum mismatch: stored {stored:#018x}, computed {computed:#018x}")]
    Checksum {
        /// The stored checksum.
        stored: u64,
        /// The checksum of the bytes given.
        computed: u64,
    },
    /// A value is out of range or inconsistent with the rest of the structure.
    #[error("invalid {what} at {index}")]
    Invalid {
        /// What is wrong.
        what: &'static str,
        /// Where (an element index, or 0).
        index: u64,
    },
    /// An IAS must be given one child per instance (guide §5.7: one relocated traversable per
    /// instance).
    #[error("the IAS has {expected} instances but {given} children were given")]
    ChildCount {
        /// Instances in the IAS.
        expected: u64,
        /// Children given.
        given: u64,
    },
    /// A child given for an instance cannot be used (another backend, too deep a graph).
    #[error("instance {instance}: {reason}")]
    Child {
        /// The instance.
        instance: u32,
        /// Why.
        reason: String,
    },
    /// The device cannot hold this structure (yet).
    #[error("{0} is not supported by this backend")]
    Unsupported(&'static str),
    /// The device failed while the structure was copied to or from its memory.
    #[error("device error: {0}")]
    Device(String),
}

impl LoadError {
    /// The `OptixResult` code closest to this error (`OPTIX_ERROR_INVALID_VALUE` for damaged
    /// bytes, `OPTIX_ERROR_NOT_SUPPORTED` for a version or a device that cannot take them).
    #[doc(alias = "OptixResult")]
    #[doc(alias = "OPTIX_ERROR_INVALID_VALUE")]
    #[doc(alias = "OPTIX_ERROR_NOT_SUPPORTED")]
    #[must_use]
    pub fn code(&self) -> ErrorCode {
        match self {
            LoadError::UnsupportedVersion { .. } | LoadError::Unsupported(_) => {
                ErrorCode::NotSupported
            }
            _ => ErrorCode::InvalidValue,
        }
    }
}

/// Why a random access to a structure's primitives or instances (guide §13.9, §13.12) was
/// refused. On OptiX these cases are undefined behaviour; here they are errors.
#[derive(Debug, Error, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum RandomAccessError {
    /// The structure was not built with the flag the access needs
    /// (`ALLOW_RANDOM_VERTEX_ACCESS`, `ALLOW_RANDOM_INSTANCE_ACCESS`).
    #[error("the structure was not built with {flag} (guide §13.9, §13.12)")]
    NotAllowed {
        /// The build flag.
        flag: &'static str,
    },
    /// No build input holds that SBT-GAS index, or its primitives do not reach that index.
    #[error("no primitive {primitive_index} under SBT-GAS index {sbt_gas_index} in this GAS")]
    NoSuchPrimitive {
        /// The primitive index asked (with the input's primitive index offset).
        primitive_index: u32,
        /// The SBT-GAS index asked.
        sbt_gas_index: u32,
    },
    /// The GAS holds primitives of another kind than the access reads.
    #[error("the GAS holds {holds}, not {asked}")]
    WrongKind {
        /// What the GAS holds.
        holds: &'static str,
        /// What the access reads.
        asked: &'static str,
    },
    /// The IAS has no instance of that index.
    #[error("no instance {index}: the IAS has {count}")]
    NoSuchInstance {
        /// The index asked.
        index: u32,
        /// Instances in the IAS.
        count: u32,
    },
    /// The device failed while the data was read.
    #[error("device error: {0}")]
    Device(String),
}

/// Why a batched query was refused.
#[derive(Debug, Error, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum QueryError {
    /// The traversable lives on another backend than the device asked to trace it.
    #[error("the traversable lives on the {found} backend, not on the {device} device that was asked to trace it")]
    ForeignTraversable {
        /// The backend of the device asked.
        device: crate::handle::BackendKind,
        /// The backend the structure lives on.
        found: crate::handle::BackendKind,
    },
    /// The backend cannot run this query (yet).
    #[error("{0} is not supported by this backend")]
    Unsupported(&'static str),
    /// The result buffer holds results of the other query kind.
    #[error("the batch holds {0} results")]
    WrongBatchKind(&'static str),
    /// A batch larger than the backend can take at once.
    #[error("a batch of {rays} rays exceeds the limit of {limit}")]
    BatchTooLarge {
        /// Rays given.
        rays: usize,
        /// Most rays in one batch.
        limit: usize,
    },
    /// The device failed (out of memory, a driver error).
    #[error("device error: {0}")]
    Device(String),
    /// The output slice must have one element per ray.
    #[error("{rays} rays but the output holds {outputs} results")]
    LengthMismatch {
        /// Rays given.
        rays: usize,
        /// Output elements given.
        outputs: usize,
    },
}

/// Why a module, program group or pipeline could not be created (guide §6), or an SBT region
/// was refused (§7).
#[derive(Debug, Error, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum PipelineError {
    /// An entry name lacks the prefix of its program kind (guide §6.2).
    #[error("entry {name:?} registered as a {kind} program must start with {prefix:?}")]
    BadEntryName {
        /// The name.
        name: String,
        /// The program kind.
        kind: &'static str,
        /// The prefix it needs.
        prefix: &'static str,
    },
    /// Two programs of one module share an entry name.
    #[error("entry {0:?} is defined twice in one module")]
    DuplicateEntry(String),
    /// A program group names an entry its module lacks, or one of another kind.
    #[error("module has no {kind} program named {name:?}")]
    UnknownEntry {
        /// The name.
        name: String,
        /// The kind wanted.
        kind: &'static str,
    },
    /// `num_payload_values` must be at most 32 (guide §13.3).
    #[error("num_payload_values {0} exceeds 32")]
    TooManyPayloadValues(u32),
    /// `num_attribute_values` must be at most 8 (guide §13.4).
    #[error("num_attribute_values {0} exceeds 8")]
    TooManyAttributeValues(u32),
    /// `max_trace_depth` must be at most 31 (guide §12).
    #[error("max_trace_depth {0} exceeds 31")]
    TraceDepthTooLarge(u32),
    /// A callables group needs a direct or a continuation callable (or both).
    #[error("a callables program group needs a direct or a continuation callable")]
    EmptyCallables,
    /// `max_traversable_graph_depth` must be in `1..=31` (guide §12).
    #[error("max_traversable_graph_depth {0} is not in 1..=31")]
    InvalidGraphDepth(u32),
    /// A pipeline needs at least one program group.
    #[error("a pipeline needs at least one program group")]
    NoProgramGroups,
    /// SBT strides are multiples of 16 that hold at least the 32-byte header (guide §7.2).
    #[error("SBT stride {stride} is not a multiple of 16 of at least 32 bytes")]
    InvalidSbtStride {
        /// The stride.
        stride: usize,
    },
    /// An SBT region's bytes are fewer than its records need.
    #[error("SBT region holds {len} bytes but its records need {needed}")]
    SbtRegionTooSmall {
        /// Bytes needed.
        needed: usize,
        /// Bytes given.
        len: usize,
    },
}

impl PipelineError {
    /// The `OptixResult` code the guide gives for this error.
    #[doc(alias = "OptixResult")]
    #[must_use]
    pub fn code(&self) -> ErrorCode {
        ErrorCode::InvalidValue
    }
}

/// Why a launch was refused (guide §7, §10, §12). Nothing ran.
#[derive(Debug, Error, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum LaunchError {
    /// `width * height * depth` must be at most 2^30 (guide §12).
    #[error("launch of {width} x {height} x {depth} exceeds 2^30 launch indices")]
    TooLarge {
        /// Width.
        width: u32,
        /// Height.
        height: u32,
        /// Depth.
        depth: u32,
    },
    /// The SBT has no ray-generation record.
    #[error("the SBT has no ray-generation record")]
    NoRaygenRecord,
    /// Validation mode (guide §4.3): a launch index raised a built-in exception. The launch ran
    /// to the end; this is the first such exception by launch index.
    #[error("validation failure at launch index {index:?}: {exception}")]
    ValidationFailure {
        /// The launch index.
        index: [u32; 3],
        /// The exception.
        exception: crate::exception::Exception,
    },
    /// A record's header does not name a program group of this pipeline, or names one of the
    /// wrong kind for its region.
    #[error("SBT {region} record {index}: {reason}")]
    InvalidSbtRecord {
        /// The region (raygen, exception, miss, hitgroup, callables).
        region: &'static str,
        /// The record.
        index: usize,
        /// What is wrong.
        reason: &'static str,
    },
}

impl LaunchError {
    /// The `OptixResult` code the guide gives for this error.
    #[doc(alias = "OptixResult")]
    #[must_use]
    pub fn code(&self) -> ErrorCode {
        match self {
            LaunchError::ValidationFailure { .. } => ErrorCode::ValidationFailure,
            _ => ErrorCode::InvalidLaunchParameter,
        }
    }
}
