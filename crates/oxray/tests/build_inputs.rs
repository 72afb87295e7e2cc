//! Build inputs (guide §5, §5.1, §5.5, §12): every validation error with its fields, location
//! and `OptixResult` code (§3.1); vertex and index formats and strides; pre-transforms;
//! primitive index offsets; SBT record indices over several inputs (§7.3.2); inactive
//! primitives; and the query semantics the guide fixes: hit kinds and barycentrics (§13.7,
//! §13.4), the closed interval `[tmin, tmax]` (§13.2), ray validation (§13.14), custom hit
//! kinds (§12), ignore/terminate (§13.13), and the batch APIs.

mod common;

use common::Rng;
use glam::Vec3;
use oxray::cpu::Gas;
use oxray::error::{BufferKind, InputLocation};
use oxray::{
    Aabb, AabbBuffer, BuildError, BuildFlags, BuildInput, BuildInputKind, BuildOperation,
    BuildOptions, CandidateAction, CustomHit, CustomPrimitive, CustomPrimitiveInput, ErrorCode,
    GeometryFlags, Hit, HitKind, IndexBuffer, IndexFormat, NoCustomPrimitives, QueryError, Ray,
    RayError, SbtIndexOffsets, SbtIndexSize, TriangleInput, VertexBuffer, VertexFormat,
};
use oxray::{MAX_PRIMITIVES_PER_GAS, MAX_SBT_RECORDS_PER_GAS};

// ---------------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------------

/// One valid triangle soup input (a single triangle).
const TRI: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

fn valid_tri() -> BuildInput<'static> {
    TriangleInput::new(VertexBuffer::f32x3(&TRI)).into()
}

const BOX: [Aabb; 1] = [Aabb::new(Vec3::ZERO, Vec3::ONE)];

fn valid_custom() -> BuildInput<'static> {
    CustomPrimitiveInput::new(AabbBuffer::new(&BOX)).into()
}

fn build(inputs: &[BuildInput<'_>]) -> Result<Gas, BuildError> {
    Gas::build(&BuildOptions::default(), inputs)
}

fn build_err(inputs: &[BuildInput<'_>]) -> BuildError {
    match build(inputs) {
        Ok(_) => panic!("the build was accepted"),
        Err(e) => e,
    }
}

fn at(input: usize) -> InputLocation {
    InputLocation { input }
}

/// An error about one build input: `InvalidInput`, and the message names the input.
fn assert_located(e: &BuildError, input: usize) {
    assert_eq!(e.code(), ErrorCode::InvalidInput, "{e:?}");
    let msg = e.to_string();
    assert!(
        msg.contains(&format!("build input {input}")),
        "{msg:?} does not name input {input}"
    );
}

/// Little-endian bytes of `elems` laid out `stride` bytes apart, padding filled with `fill`.
fn strided(elems: &[Vec<u8>], stride: usize, fill: u8) -> Vec<u8> {
    let mut out =
        vec![fill; elems.len().saturating_sub(1) * stride + elems.last().map_or(0, Vec::len)];
    for (k, e) in elems.iter().enumerate() {
        assert!(e.len() <= stride);
        out[k * stride..k * stride + e.len()].copy_from_slice(e);
    }
    out
}

fn le_f32(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// `n` unit triangles in the plane z = 0, triangle k with its corner at (x0 + 2k, 0, 0).
fn row_of_triangles(x0: f32, n: usize) -> Vec<[f32; 3]> {
    (0..n)
        .flat_map(|k| {
            let x = x0 + 2.0 * k as f32;
            [[x, 0.0, 0.0], [x + 1.0, 0.0, 0.0], [x, 1.0, 0.0]]
        })
        .collect()
}

/// A ray down onto the triangle of `row_of_triangles(x0, _)` number k.
fn ray_onto(x0: f32, k: usize) -> Ray {
    Ray::new(Vec3::new(x0 + 2.0 * k as f32 + 0.25, 0.25, 1.0), -Vec3::Z)
}

fn bits(h: &Option<Hit>) -> Option<common::HitBits> {
    common::hit_bits(h)
}

// ---------------------------------------------------------------------------------------------
// Validation errors
// ---------------------------------------------------------------------------------------------

/// Guide §5: a GAS needs at least one build input (`numBuildInputs >= 1`).
#[test]
fn no_build_inputs_is_rejected_5() {
    let e = build_err(&[]);
    assert_eq!(e, BuildError::NoBuildInputs);
    assert_eq!(e.code(), ErrorCode::InvalidValue);
    assert_eq!(ErrorCode::InvalidValue as u32, 7001);
}

/// Guide §5: all build inputs of one GAS have the same type.
#[test]
fn mixed_input_types_are_rejected_5() {
    let e = build_err(&[valid_tri(), valid_custom()]);
    assert_eq!(
        e,
        BuildError::MixedInputTypes {
            index: 1,
            expected: BuildInputKind::Triangles,
            found: BuildInputKind::CustomPrimitives
        }
    );
    assert_located(&e, 1);
    let e = build_err(&[valid_custom(), valid_custom(), valid_tri()]);
    assert_eq!(
        e,
        BuildError::MixedInputTypes {
            index: 2,
            expected: BuildInputKind::CustomPrimitives,
            found: BuildInputKind::Triangles
        }
    );
    assert_located(&e, 2);
    assert_eq!(ErrorCode::InvalidInput as u32, 7200);
}

/// Guide §5.5: `PREFER_FAST_TRACE` and `PREFER_FAST_BUILD` are mutually exclusive.
#[test]
fn conflicting_build_flags_are_rejected_5_5() {
    for extra in [
        BuildFlags::empty(),
        BuildFlags::ALLOW_COMPACTION | BuildFlags::ALLOW_UPDATE,
    ] {
        let flags = BuildFlags::PREFER_FAST_TRACE | BuildFlags::PREFER_FAST_BUILD | extra;
        let e = Gas::build(&BuildOptions::new(flags), &[valid_tri()]).unwrap_err();
        assert_eq!(e, BuildError::ConflictingBuildFlags);
        assert_eq!(e.code(), ErrorCode::InvalidValue);
    }
    // Each alone, and the other flags, are fine.
    for flags in [
        BuildFlags::PREFER_FAST_TRACE,
        BuildFlags::PREFER_FAST_BUILD,
        BuildFlags::all() - BuildFlags::PREFER_FAST_BUILD,
    ] {
        let gas = Gas::build(&BuildOptions::new(flags), &[valid_tri()]).unwrap();
        assert_eq!(gas.build_flags(), flags);
    }
}

/// Guide §5.6: an update applies to an existing structure (`Device::update_gas`); a build call
/// with operation Update is refused with a typed error naming the rule, not a crash.
#[test]
fn update_operation_in_a_build_call_is_refused_5_6() {
    for input in [valid_tri(), valid_custom()] {
        let options = BuildOptions {
            flags: BuildFlags::ALLOW_UPDATE,
            operation: BuildOperation::Update,
            ..Default::default()
        };
        let e = Gas::build(&options, &[input]).unwrap_err();
        assert_eq!(e, BuildError::InvalidUpdate(oxray::UpdateRule::NoStructure));
        assert_eq!(e.code(), ErrorCode::InvalidValue);
        assert!(e.to_string().contains("§5.6"), "{e}");
    }
}

/// Guide §12: at most 2^29 primitives per GAS, checked on the declared counts before the
/// buffers' sizes (the buffers here are tiny).
#[test]
fn too_many_primitives_are_rejected_12() {
    assert_eq!(MAX_PRIMITIVES_PER_GAS, 1 << 29);
    let over = (1u32 << 29) + 1;
    let tiny = [0u8; 36];
    let expected = BuildError::TooManyPrimitives {
        count: over as u64,
        limit: 1 << 29,
    };
    // Indexed.
    let ix = TriangleInput::new(VertexBuffer::f32x3(&TRI)).indices(IndexBuffer::new(
        &tiny,
        IndexFormat::U32x3,
        0,
        over,
    ));
    let e = build_err(&[ix.into()]);
    assert_eq!(e, expected);
    assert_eq!(e.code(), ErrorCode::InvalidInput);
    assert!(e.to_string().contains(&over.to_string()), "{e}");
    // A soup: 3 * (2^29 + 1) vertices.
    let soup = TriangleInput::new(VertexBuffer::new(&tiny, VertexFormat::F32x3, 0, 3 * over));
    assert_eq!(build_err(&[soup.into()]), expected);
    // Custom primitives.
    let boxes = CustomPrimitiveInput::new(AabbBuffer {
        data: &tiny,
        stride: 0,
        count: over,
    });
    assert_eq!(build_err(&[boxes.into()]), expected);
    // Summed over inputs.
    let half = TriangleInput::new(VertexBuffer::f32x3(&TRI)).indices(IndexBuffer::new(
        &tiny,
        IndexFormat::U32x3,
        0,
        1 << 28,
    ));
    let half_plus = TriangleInput::new(VertexBuffer::f32x3(&TRI)).indices(IndexBuffer::new(
        &tiny,
        IndexFormat::U32x3,
        0,
        (1 << 28) + 1,
    ));
    assert_eq!(build_err(&[half.into(), half_plus.into()]), expected);
    // Exactly the limit is allowed: the next problem is the buffer's size.
    let limit = TriangleInput::new(VertexBuffer::f32x3(&TRI)).indices(IndexBuffer::new(
        &tiny,
        IndexFormat::U32x3,
        0,
        1 << 29,
    ));
    assert!(matches!(
        build_err(&[limit.into()]),
        BuildError::BufferTooSmall {
            buffer: BufferKind::Indices,
            ..
        }
    ));
}

/// Guide §12: at most 2^24 SBT records per GAS (the sum of every input's `numSbtRecords`).
#[test]
fn too_many_sbt_records_are_rejected_12() {
    assert_eq!(MAX_SBT_RECORDS_PER_GAS, 1 << 24);
    let over = vec![GeometryFlags::empty(); (1 << 24) + 1];
    let expected = BuildError::TooManySbtRecords {
        count: (1 << 24) + 1,
        limit: 1 << 24,
    };
    let e = build_err(&[TriangleInput::new(VertexBuffer::f32x3(&TRI))
        .flags(&over)
        .into()]);
    assert_eq!(e, expected);
    assert_eq!(e.code(), ErrorCode::InvalidInput);
    // Summed over inputs.
    let a = &over[..1 << 23];
    let b = &over[..(1 << 23) + 1];
    let e = build_err(&[
        TriangleInput::new(VertexBuffer::f32x3(&TRI))
            .flags(a)
            .into(),
        TriangleInput::new(VertexBuffer::f32x3(&TRI))
            .flags(b)
            .into(),
    ]);
    assert_eq!(e, expected);
    let e = build_err(&[CustomPrimitiveInput::new(AabbBuffer::new(&BOX))
        .flags(&over)
        .into()]);
    assert_eq!(e, expected);
    // Exactly the limit passes this check (and then lacks SBT index offsets).
    let e = build_err(&[TriangleInput::new(VertexBuffer::f32x3(&TRI))
        .flags(&over[..1 << 24])
        .into()]);
    assert_eq!(
        e,
        BuildError::MissingSbtIndexOffsets {
            at: at(0),
            num_sbt_records: 1 << 24
        }
    );
}

/// Guide §5.1: every build input references at least one SBT record.
#[test]
fn no_sbt_records_is_rejected_5_1() {
    let e = build_err(&[
        valid_tri(),
        TriangleInput::new(VertexBuffer::f32x3(&TRI))
            .flags(&[])
            .into(),
    ]);
    assert_eq!(e, BuildError::NoSbtRecords { at: at(1) });
    assert_located(&e, 1);
    let e = build_err(&[CustomPrimitiveInput::new(AabbBuffer::new(&BOX))
        .flags(&[])
        .into()]);
    assert_eq!(e, BuildError::NoSbtRecords { at: at(0) });
    assert_located(&e, 0);
}

/// Guide §5.1: an input with more than one SBT record needs per-primitive SBT index offsets.
#[test]
fn missing_sbt_index_offsets_are_rejected_5_1() {
    let flags = [GeometryFlags::empty(); 3];
    let e = build_err(&[
        valid_tri(),
        TriangleInput::new(VertexBuffer::f32x3(&TRI))
            .flags(&flags)
            .into(),
    ]);
    assert_eq!(
        e,
        BuildError::MissingSbtIndexOffsets {
            at: at(1),
            num_sbt_records: 3
        }
    );
    assert_located(&e, 1);
    let e = build_err(&[
        valid_custom(),
        valid_custom(),
        CustomPrimitiveInput::new(AabbBuffer::new(&BOX))
            .flags(&flags[..2])
            .into(),
    ]);
    assert_eq!(
        e,
        BuildError::MissingSbtIndexOffsets {
            at: at(2),
            num_sbt_records: 2
        }
    );
    assert_located(&e, 2);
}

/// Guide §5.1: each per-primitive SBT index offset lies in `[0, numSbtRecords - 1]`; with
/// 1-, 2- and 4-byte offsets, tightly packed or strided.
#[test]
fn sbt_index_offset_out_of_range_is_rejected_5_1() {
    let verts = row_of_triangles(0.0, 3);
    let flags = [GeometryFlags::empty(); 2];
    let with = |o: SbtIndexOffsets<'_>| -> BuildError {
        let input = TriangleInput::new(VertexBuffer::f32x3(&verts))
            .flags(&flags)
            .sbt_index_offsets(o);
        let e = build_err(&[valid_tri(), input.into()]);
        assert_located(&e, 1);
        e
    };
    let oob = |primitive: u32, offset: u32| BuildError::SbtIndexOffsetOutOfRange {
        at: at(1),
        primitive,
        offset,
        num_sbt_records: 2,
    };
    assert_eq!(with(SbtIndexOffsets::u8(&[0, 1, 2])), oob(2, 2));
    assert_eq!(with(SbtIndexOffsets::u8(&[255, 1, 0])), oob(0, 255));
    assert_eq!(with(SbtIndexOffsets::u16(&[1, 300, 0])), oob(1, 300));
    assert_eq!(with(SbtIndexOffsets::u32(&[0, 0, 70_000])), oob(2, 70_000));
    assert_eq!(
        with(SbtIndexOffsets::u32(&[0, u32::MAX, 0])),
        oob(1, u32::MAX)
    );
    // Strided: the padding (0xFF) is not read, the element is.
    let data = strided(&[vec![1, 0], vec![2, 0], vec![0, 0]], 4, 0xFF);
    let o = SbtIndexOffsets {
        data: &data,
        size: SbtIndexSize::U16,
        stride: 4,
    };
    assert_eq!(with(o), oob(1, 2));
    // The same offsets in range build.
    let data = strided(&[vec![1, 0], vec![1, 0], vec![0, 0]], 4, 0xFF);
    let o = SbtIndexOffsets {
        data: &data,
        size: SbtIndexSize::U16,
        stride: 4,
    };
    let input = TriangleInput::new(VertexBuffer::f32x3(&verts))
        .flags(&flags)
        .sbt_index_offsets(o);
    assert!(build(&[input.into()]).is_ok());
    // Custom primitives too.
    let boxes = [BOX[0]; 3];
    let e = build_err(&[CustomPrimitiveInput::new(AabbBuffer::new(&boxes))
        .flags(&flags)
        .sbt_index_offsets(SbtIndexOffsets::u8(&[0, 1, 7]))
        .into()]);
    assert_eq!(
        e,
        BuildError::SbtIndexOffsetOutOfRange {
            at: at(0),
            primitive: 2,
            offset: 7,
            num_sbt_records: 2
        }
    );
}

/// Strides: smaller than one element, or not a multiple of the element's alignment (§5.1,
/// natural alignment of each format; AABB strides a multiple of 8).
#[test]
fn invalid_strides_are_rejected_5_1() {
    let bytes = vec![0u8; 4096];
    let mut small_reasons = Vec::new();
    let mut align_reasons = Vec::new();
    let mut check = |e: BuildError, buffer: BufferKind, stride: u32, too_small: bool| {
        assert_located(&e, 1);
        match e {
            BuildError::InvalidStride {
                at: a,
                buffer: b,
                stride: s,
                reason,
            } => {
                assert_eq!((a, b, s), (at(1), buffer, stride));
                if too_small {
                    small_reasons.push(reason);
                } else {
                    align_reasons.push(reason);
                }
            }
            e => panic!("expected InvalidStride for {buffer:?} stride {stride}, got {e:?}"),
        }
    };
    // Vertices: (format, stride, too small?)
    for (format, stride, small) in [
        (VertexFormat::F32x3, 8, true),
        (VertexFormat::F32x3, 11, true),
        (VertexFormat::F32x3, 14, false),
        (VertexFormat::F32x2, 4, true),
        (VertexFormat::F32x2, 10, false),
        (VertexFormat::F16x3, 4, true),
        (VertexFormat::F16x3, 7, false),
        (VertexFormat::F16x2, 2, true),
        (VertexFormat::F16x2, 5, false),
        (VertexFormat::Snorm16x3, 5, true),
        (VertexFormat::Snorm16x3, 9, false),
        (VertexFormat::Snorm16x2, 3, true),
        (VertexFormat::Snorm16x2, 7, false),
    ] {
        let input = TriangleInput::new(VertexBuffer::new(&bytes, format, stride, 3));
        check(
            build_err(&[valid_tri(), input.into()]),
            BufferKind::Vertices,
            stride,
            small,
        );
    }
    // Indices.
    let v = VertexBuffer::f32x3(&TRI);
    for (format, stride, small) in [
        (IndexFormat::U32x3, 8, true),
        (IndexFormat::U32x3, 14, false),
        (IndexFormat::U16x3, 4, true),
        (IndexFormat::U16x3, 7, false),
    ] {
        let input = TriangleInput::new(v).indices(IndexBuffer::new(&bytes, format, stride, 1));
        check(
            build_err(&[valid_tri(), input.into()]),
            BufferKind::Indices,
            stride,
            small,
        );
    }
    // AABBs.
    for (stride, small) in [(16, true), (23, true), (28, false), (36, false)] {
        let input = CustomPrimitiveInput::new(AabbBuffer {
            data: &bytes,
            stride,
            count: 2,
        });
        check(
            build_err(&[valid_custom(), input.into()]),
            BufferKind::Aabbs,
            stride,
            small,
        );
    }
    // SBT index offsets.
    let flags = [GeometryFlags::empty(); 2];
    for (size, stride, small) in [
        (SbtIndexSize::U16, 1, true),
        (SbtIndexSize::U16, 3, false),
        (SbtIndexSize::U32, 2, true),
        (SbtIndexSize::U32, 6, false),
    ] {
        let o = SbtIndexOffsets {
            data: &bytes,
            size,
            stride,
        };
        let input = TriangleInput::new(v).flags(&flags).sbt_index_offsets(o);
        check(
            build_err(&[valid_tri(), input.into()]),
            BufferKind::SbtIndexOffsets,
            stride,
            small,
        );
    }
    // The two rules are told apart.
    assert!(small_reasons.iter().all(|r| *r == small_reasons[0]));
    assert!(align_reasons.iter().all(|r| *r == align_reasons[0]));
    assert_ne!(small_reasons[0], align_reasons[0]);

    // Valid strides: larger than an element and aligned (u8 offsets take any stride).
    let o = SbtIndexOffsets {
        data: &bytes,
        size: SbtIndexSize::U8,
        stride: 3,
    };
    let input = TriangleInput::new(VertexBuffer::new(&bytes, VertexFormat::F16x3, 10, 3))
        .indices(IndexBuffer::new(&bytes, IndexFormat::U16x3, 10, 1))
        .flags(&flags)
        .sbt_index_offsets(o);
    assert!(build(&[input.into()]).is_ok());
    let input = CustomPrimitiveInput::new(AabbBuffer {
        data: &bytes,
        stride: 32,
        count: 2,
    });
    assert!(build(&[input.into()]).is_ok());
}

/// A buffer shorter than its count and stride require; the last element needs only its own
/// size, not a whole stride.
#[test]
fn buffers_too_small_are_rejected_5_1() {
    let too_small = |e: BuildError, buffer: BufferKind, count: u64, needed: u64, len: u64| {
        assert_located(&e, 1);
        assert_eq!(
            e,
            BuildError::BufferTooSmall {
                at: at(1),
                buffer,
                count,
                needed,
                len
            }
        );
    };
    let ix = [[0u32, 1, 2]];
    // Vertices, packed: 4 vertices need 48 bytes.
    let v = le_f32(&[0.0; 9]);
    let input = TriangleInput::new(VertexBuffer::new(&v, VertexFormat::F32x3, 0, 4))
        .indices(IndexBuffer::u32x3(&ix));
    too_small(
        build_err(&[valid_tri(), input.into()]),
        BufferKind::Vertices,
        4,
        48,
        36,
    );
    // Vertices, strided: 3 vertices 16 bytes apart need 2 * 16 + 12 = 44 bytes.
    let v = vec![0u8; 44];
    let input = TriangleInput::new(VertexBuffer::new(&v[..43], VertexFormat::F32x3, 16, 3));
    too_small(
        build_err(&[valid_tri(), input.into()]),
        BufferKind::Vertices,
        3,
        44,
        43,
    );
    let input = TriangleInput::new(VertexBuffer::new(&v, VertexFormat::F32x3, 16, 3));
    assert!(build(&[input.into()]).is_ok());
    // Indices: 2 triplets of u32 need 24 bytes; of u16 with stride 8, 14.
    let ib = vec![0u8; 14];
    let input = TriangleInput::new(VertexBuffer::f32x3(&TRI)).indices(IndexBuffer::new(
        &ib[..12],
        IndexFormat::U32x3,
        0,
        2,
    ));
    too_small(
        build_err(&[valid_tri(), input.into()]),
        BufferKind::Indices,
        2,
        24,
        12,
    );
    let input = TriangleInput::new(VertexBuffer::f32x3(&TRI)).indices(IndexBuffer::new(
        &ib[..13],
        IndexFormat::U16x3,
        8,
        2,
    ));
    too_small(
        build_err(&[valid_tri(), input.into()]),
        BufferKind::Indices,
        2,
        14,
        13,
    );
    let input = TriangleInput::new(VertexBuffer::f32x3(&TRI)).indices(IndexBuffer::new(
        &ib,
        IndexFormat::U16x3,
        8,
        2,
    ));
    assert!(build(&[input.into()]).is_ok());
    // AABBs: 2 boxes need 48 bytes.
    let ab = le_f32(&[0.0, 0.0, 0.0, 1.0, 1.0, 1.0]);
    let input = CustomPrimitiveInput::new(AabbBuffer {
        data: &ab,
        stride: 0,
        count: 2,
    });
    too_small(
        build_err(&[valid_custom(), input.into()]),
        BufferKind::Aabbs,
        2,
        48,
        24,
    );
    // SBT index offsets: 3 primitives of u16 need 6 bytes; with stride 4, 10.
    let verts = row_of_triangles(0.0, 3);
    let flags = [GeometryFlags::empty(); 2];
    for (stride, needed) in [(0u32, 6u64), (4, 10)] {
        let data = vec![0u8; needed as usize];
        let o = SbtIndexOffsets {
            data: &data[..needed as usize - 1],
            size: SbtIndexSize::U16,
            stride,
        };
        let input = TriangleInput::new(VertexBuffer::f32x3(&verts))
            .flags(&flags)
            .sbt_index_offsets(o);
        too_small(
            build_err(&[valid_tri(), input.into()]),
            BufferKind::SbtIndexOffsets,
            3,
            needed,
            needed - 1,
        );
        let o = SbtIndexOffsets {
            data: &data,
            size: SbtIndexSize::U16,
            stride,
        };
        let input = TriangleInput::new(VertexBuffer::f32x3(&verts))
            .flags(&flags)
            .sbt_index_offsets(o);
        assert!(build(&[input.into()]).is_ok());
    }
}

/// Guide §5.1: without an index buffer every three vertices form a triangle.
#[test]
fn vertex_count_not_multiple_of_three_is_rejected_5_1() {
    let v = [[0.0f32; 3]; 4];
    let e = build_err(&[
        valid_tri(),
        TriangleInput::new(VertexBuffer::f32x3(&v)).into(),
    ]);
    assert_eq!(
        e,
        BuildError::VertexCountNotMultipleOfThree {
            at: at(1),
            count: 4
        }
    );
    assert_located(&e, 1);
    // With an index buffer, any vertex count is fine.
    let v = [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [9.0, 9.0, 9.0],
    ];
    let ok = TriangleInput::new(VertexBuffer::f32x3(&v)).indices(IndexBuffer::u32x3(&[[0, 1, 2]]));
    assert!(build(&[ok.into()]).is_ok());
}

/// Guide §5.1: every index refers to a vertex of the buffer.
#[test]
fn index_out_of_range_is_rejected_5_1() {
    let ix32 = [[0u32, 1, 2], [2, 3, 0]];
    let input = TriangleInput::new(VertexBuffer::f32x3(&TRI)).indices(IndexBuffer::u32x3(&ix32));
    let e = build_err(&[valid_tri(), input.into()]);
    assert_eq!(
        e,
        BuildError::IndexOutOfRange {
            at: at(1),
            triangle: 1,
            index: 3,
            num_vertices: 3
        }
    );
    assert_located(&e, 1);
    let ix16 = [[0u16, 1, 2], [0, 1, 2], [1, 65535, 0]];
    let input = TriangleInput::new(VertexBuffer::f32x3(&TRI)).indices(IndexBuffer::u16x3(&ix16));
    assert_eq!(
        build_err(&[input.into()]),
        BuildError::IndexOutOfRange {
            at: at(0),
            triangle: 2,
            index: 65535,
            num_vertices: 3
        }
    );
    // Strided: the padding is not an index.
    let data = strided(
        &[[0u32, 1, 2], [2, 1, 0]]
            .map(|t| t.iter().flat_map(|i| i.to_le_bytes()).collect::<Vec<u8>>()),
        16,
        0xFF,
    );
    let input = TriangleInput::new(VertexBuffer::f32x3(&TRI)).indices(IndexBuffer::new(
        &data,
        IndexFormat::U32x3,
        16,
        2,
    ));
    assert!(build(&[input.into()]).is_ok());
}

/// `primitiveIndexOffset + numPrimitives` must fit in 32 bits (OptiX header rule, §5.1).
#[test]
fn primitive_index_offset_overflow_is_rejected_5_1() {
    let verts = row_of_triangles(0.0, 2);
    let input =
        TriangleInput::new(VertexBuffer::f32x3(&verts)).primitive_index_offset(u32::MAX - 1);
    let e = build_err(&[valid_tri(), input.into()]);
    assert_eq!(
        e,
        BuildError::PrimitiveIndexOffsetOverflow {
            at: at(1),
            offset: u32::MAX - 1,
            count: 2
        }
    );
    assert_located(&e, 1);
    let boxes = [BOX[0]; 2];
    let input = CustomPrimitiveInput::new(AabbBuffer::new(&boxes)).primitive_index_offset(u32::MAX);
    assert!(matches!(
        build_err(&[input.into()]),
        BuildError::PrimitiveIndexOffsetOverflow {
            offset: u32::MAX,
            count: 2,
            ..
        }
    ));
    // The largest offset that fits: the last primitive reports u32::MAX - 1.
    let input =
        TriangleInput::new(VertexBuffer::f32x3(&verts)).primitive_index_offset(u32::MAX - 2);
    let gas = build(&[input.into()]).unwrap();
    assert_eq!(
        gas.intersect(&ray_onto(0.0, 1)).unwrap().primitive_index,
        u32::MAX - 1
    );
}

// ---------------------------------------------------------------------------------------------
// Formats, strides, transforms, offsets
// ---------------------------------------------------------------------------------------------

/// Encodes one vertex in `format`; returns the bytes and the position the format represents
/// (computed by hand: half-float rounding, `snorm = max(k / 32767, -1)`, `z = 0` for
/// two-component formats).
fn encode(format: VertexFormat, p: [f32; 3]) -> (Vec<u8>, [f32; 3]) {
    let half = |x: f32| half::f16::from_f32(x);
    let snorm = |x: f32| -> i16 {
        if x <= -1.0 {
            -32768 // also decodes to -1
        } else {
            (x * 32767.0).round() as i16
        }
    };
    let sn = |k: i16| (k as f32 / 32767.0).max(-1.0);
    match format {
        VertexFormat::F32x3 => (le_f32(&p), p),
        VertexFormat::F32x2 => (le_f32(&p[..2]), [p[0], p[1], 0.0]),
        VertexFormat::F16x3 => (
            p.iter().flat_map(|&x| half(x).to_le_bytes()).collect(),
            p.map(|x| half(x).to_f32()),
        ),
        VertexFormat::F16x2 => (
            p[..2].iter().flat_map(|&x| half(x).to_le_bytes()).collect(),
            [half(p[0]).to_f32(), half(p[1]).to_f32(), 0.0],
        ),
        VertexFormat::Snorm16x3 => (
            p.iter().flat_map(|&x| snorm(x).to_le_bytes()).collect(),
            p.map(|x| sn(snorm(x))),
        ),
        VertexFormat::Snorm16x2 => (
            p[..2]
                .iter()
                .flat_map(|&x| snorm(x).to_le_bytes())
                .collect(),
            [sn(snorm(p[0])), sn(snorm(p[1])), 0.0],
        ),
    }
}

fn random_rays(rng: &mut Rng, n: usize) -> Vec<Ray> {
    (0..n)
        .map(|i| {
            let target = rng.vec3(-0.9, 0.9);
            let origin = if i % 3 == 0 {
                Vec3::new(target.x, target.y, 2.0)
            } else {
                rng.dir().normalize() * 3.0
            };
            Ray::new(origin, target - origin)
        })
        .collect()
}

/// Guide §5.1: every vertex format, interleaved with padding (a non-trivial stride), builds the
/// same structure and gives the same hits as the equivalent `f32` positions.
#[test]
fn every_vertex_format_with_stride_matches_f32_5_1() {
    let mut mesh = common::icosphere(2);
    for v in &mut mesh.positions {
        *v = v.map(|x| x * 0.9);
    }
    // Extremes of the normalised formats.
    mesh.positions[0] = [-1.0, 1.0, -1.0];
    mesh.positions[1] = [1.0, -1.0, 0.5];
    let mut rng = Rng::new(7);
    let rays = random_rays(&mut rng, 3000);
    for (format, stride) in [
        (VertexFormat::F32x3, 20u32),
        (VertexFormat::F32x2, 12),
        (VertexFormat::F16x3, 10),
        (VertexFormat::F16x2, 6),
        (VertexFormat::Snorm16x3, 8),
        (VertexFormat::Snorm16x2, 10),
    ] {
        let (elems, expected): (Vec<Vec<u8>>, Vec<[f32; 3]>) =
            mesh.positions.iter().map(|&p| encode(format, p)).unzip();
        assert!(elems[0].len() == format.size() && (stride as usize) > format.size());
        let data = strided(&elems, stride as usize, 0xFF);
        let gas = build(&[TriangleInput::new(VertexBuffer::new(
            &data,
            format,
            stride,
            elems.len() as u32,
        ))
        .indices(IndexBuffer::u32x3(&mesh.triangles))
        .into()])
        .unwrap();
        let reference = build(&[TriangleInput::new(VertexBuffer::f32x3(&expected))
            .indices(IndexBuffer::u32x3(&mesh.triangles))
            .into()])
        .unwrap();
        assert_eq!(
            gas.num_active_primitives(),
            reference.num_active_primitives(),
            "{format:?}"
        );
        assert!(
            gas.bvh().nodes == reference.bvh().nodes,
            "{format:?}: the structures differ"
        );
        assert_eq!(gas.bounds(), reference.bounds(), "{format:?}");
        let mut hits = 0;
        for r in &rays {
            let (a, b) = (gas.intersect(r), reference.intersect(r));
            assert_eq!(bits(&a), bits(&b), "{format:?}, ray {r:?}");
            hits += a.is_some() as usize;
        }
        assert!(hits > rays.len() / 4, "{format:?}: only {hits} hits");
    }
    // Snorm16 -32768 and -32767 both decode to exactly -1 (hand-computed corner of the box).
    let (bytes, _) = encode(VertexFormat::Snorm16x3, [-1.0, 1.0, 0.0]);
    assert_eq!(&bytes[..2], &(-32768i16).to_le_bytes());
    let tri: Vec<u8> = [
        [-32768i16, -32767, 0],
        [32767, -32767, 0],
        [-32767, 32767, 0],
    ]
    .iter()
    .flatten()
    .flat_map(|k| k.to_le_bytes())
    .collect();
    let gas =
        build(&[TriangleInput::new(VertexBuffer::new(&tri, VertexFormat::Snorm16x3, 0, 3)).into()])
            .unwrap();
    assert_eq!(
        gas.bounds(),
        Aabb::new(Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, 1.0, 0.0))
    );
}

/// Guide §5.1: `u16` and `u32` index triplets, tightly packed or strided (padding filled with
/// 0xFF, which would be out of range if read), give the same structure and hits.
#[test]
fn u16_and_u32_indices_with_stride_match_5_1() {
    let mesh = common::icosphere(3);
    assert!(mesh.positions.len() < 65536);
    let reference = build(&[TriangleInput::new(VertexBuffer::f32x3(&mesh.positions))
        .indices(IndexBuffer::u32x3(&mesh.triangles))
        .into()])
    .unwrap();
    let tris16: Vec<[u16; 3]> = mesh.triangles.iter().map(|t| t.map(|i| i as u16)).collect();
    let e16: Vec<Vec<u8>> = tris16
        .iter()
        .map(|t| t.iter().flat_map(|i| i.to_le_bytes()).collect())
        .collect();
    let e32: Vec<Vec<u8>> = mesh
        .triangles
        .iter()
        .map(|t| t.iter().flat_map(|i| i.to_le_bytes()).collect())
        .collect();
    let d16 = strided(&e16, 8, 0xFF);
    let d32 = strided(&e32, 16, 0xFF);
    let n = mesh.triangles.len() as u32;
    let variants = [
        IndexBuffer::u16x3(&tris16),
        IndexBuffer::new(&d16, IndexFormat::U16x3, 8, n),
        IndexBuffer::new(&d32, IndexFormat::U32x3, 16, n),
    ];
    let mut rng = Rng::new(8);
    let rays = random_rays(&mut rng, 2000);
    for ix in variants {
        let gas = build(&[TriangleInput::new(VertexBuffer::f32x3(&mesh.positions))
            .indices(ix)
            .into()])
        .unwrap();
        assert!(gas.bvh().nodes == reference.bvh().nodes, "{:?}", ix.format);
        for r in &rays {
            assert_eq!(bits(&gas.intersect(r)), bits(&reference.intersect(r)));
        }
    }
}

/// Guide §5.1: the 3x4 row-major pre-transform is applied to every vertex at build time.
#[test]
fn pre_transform_moves_the_hits_5_1() {
    // (x, y, z) -> (y + 1, z + 2, x + 3): the unit triangle moves to the plane y = 2.
    let m = [0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 1.0, 2.0, 1.0, 0.0, 0.0, 3.0];
    let input = TriangleInput::new(VertexBuffer::f32x3(&TRI)).pre_transform(m);
    let gas = build(&[input.into()]).unwrap();
    // Vertices (1, 2, 3), (1, 2, 4), (2, 2, 3).
    assert_eq!(
        gas.bounds(),
        Aabb::new(Vec3::new(1.0, 2.0, 3.0), Vec3::new(2.0, 2.0, 4.0))
    );
    let h = gas
        .intersect(&Ray::new(Vec3::new(1.25, 5.0, 3.5), -Vec3::Y))
        .expect("moved triangle is hit");
    assert_eq!(h.t, 3.0);
    // Hit point = v0 + u (v1 - v0) + v (v2 - v0) = (1 + v, 2, 3 + u).
    assert!(
        (h.u - 0.5).abs() < 1e-6 && (h.v - 0.25).abs() < 1e-6,
        "{h:?}"
    );
    // Where the untransformed triangle is, there is nothing.
    assert_eq!(
        gas.intersect(&Ray::new(Vec3::new(0.25, 0.25, 1.0), -Vec3::Z)),
        None
    );

    // A general matrix gives the structure of the vertices transformed by hand (same formula:
    // m0 x + m1 y + m2 z + m3 per row).
    let mesh = common::icosphere(2);
    let m = [
        0.8, -0.6, 0.1, 5.0, 0.6, 0.8, 0.0, -2.0, 0.0, 0.3, 1.5, 0.25,
    ];
    let moved: Vec<[f32; 3]> = mesh
        .positions
        .iter()
        .map(|p| {
            [0, 1, 2]
                .map(|r| m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3])
        })
        .collect();
    let a = build(&[TriangleInput::new(VertexBuffer::f32x3(&mesh.positions))
        .indices(IndexBuffer::u32x3(&mesh.triangles))
        .pre_transform(m)
        .into()])
    .unwrap();
    let b = build(&[TriangleInput::new(VertexBuffer::f32x3(&moved))
        .indices(IndexBuffer::u32x3(&mesh.triangles))
        .into()])
    .unwrap();
    assert!(a.bvh().nodes == b.bvh().nodes);
    let mut rng = Rng::new(9);
    let mut hits = 0;
    for _ in 0..1000 {
        let target = Vec3::new(5.0, -2.0, 0.25) + rng.vec3(-1.0, 1.0);
        let origin = target + rng.dir() * 4.0;
        let ray = Ray::new(origin, target - origin);
        assert_eq!(bits(&a.intersect(&ray)), bits(&b.intersect(&ray)));
        hits += a.intersect(&ray).is_some() as usize;
    }
    assert!(hits > 100);
}

/// Guide §5.1: `primitiveIndexOffset` is added to the reported primitive index.
#[test]
fn primitive_index_offset_is_reported_5_1() {
    let verts = row_of_triangles(0.0, 5);
    let gas = build(&[TriangleInput::new(VertexBuffer::f32x3(&verts))
        .primitive_index_offset(1000)
        .into()])
    .unwrap();
    for k in 0..5 {
        assert_eq!(
            gas.intersect(&ray_onto(0.0, k)).unwrap().primitive_index,
            1000 + k as u32
        );
    }
    let boxes: Vec<Aabb> = (0..5)
        .map(|k| {
            Aabb::new(
                Vec3::new(2.0 * k as f32, 0.0, 0.0),
                Vec3::new(2.0 * k as f32 + 1.0, 1.0, 0.0),
            )
        })
        .collect();
    let gas = build(&[CustomPrimitiveInput::new(AabbBuffer::new(&boxes))
        .primitive_index_offset(77)
        .into()])
    .unwrap();
    for k in 0..5 {
        let mut seen = Vec::new();
        let h = gas
            .intersect_with(&ray_onto(0.0, k), &mut |p: &CustomPrimitive, r: &Ray| {
                seen.push(p.primitive_index);
                Some(CustomHit {
                    t: r.tmin + 1.0,
                    hit_kind: 0,
                    u: 0.0,
                    v: 0.0,
                })
            })
            .unwrap();
        assert_eq!(h.primitive_index, 77 + k as u32);
        assert_eq!(seen, vec![77 + k as u32]);
    }
}

/// Guide §7.3.2: the SBT-GAS index is the prefix sum of the earlier inputs' record counts plus
/// the primitive's own SBT index offset (`u8`, `u16`, `u32` offsets, strided); each hit reports
/// its build input, and `geometry_flags` gives the flags of its record.
#[test]
fn sbt_gas_index_is_prefix_sum_plus_offset_7_3_2() {
    let record_flags = |n: usize, seed: u32| -> Vec<GeometryFlags> {
        (0..n)
            .map(|r| GeometryFlags::from_bits_truncate(seed + r as u32))
            .collect()
    };
    let f0 = record_flags(4, 1);
    let f1 = vec![GeometryFlags::DISABLE_TRIANGLE_FACE_CULLING];
    let f2 = record_flags(2, 5);
    let f3 = record_flags(3, 2);
    let (x0, x1, x2, x3) = (0.0, 100.0, 200.0, 300.0);
    let v0 = row_of_triangles(x0, 4);
    let v1 = row_of_triangles(x1, 3);
    let v2 = row_of_triangles(x2, 3);
    let v3 = row_of_triangles(x3, 2);
    let o0 = [3u8, 0, 2, 1];
    let o2 = [1u16, 0, 1];
    let o3 = [2u32, 0];
    let d0 = strided(&o0.map(|o| vec![o]), 2, 0xFF);
    let d2 = strided(&o2.map(|o| o.to_le_bytes().to_vec()), 4, 0xFF);
    let d3 = strided(&o3.map(|o| o.to_le_bytes().to_vec()), 8, 0xFF);
    let ix3: Vec<[u16; 3]> = vec![[0, 1, 2], [3, 4, 5]];
    let inputs: Vec<BuildInput<'_>> = vec![
        TriangleInput::new(VertexBuffer::f32x3(&v0))
            .flags(&f0)
            .sbt_index_offsets(SbtIndexOffsets {
                data: &d0,
                size: SbtIndexSize::U8,
                stride: 2,
            })
            .into(),
        TriangleInput::new(VertexBuffer::f32x3(&v1))
            .flags(&f1)
            .into(),
        TriangleInput::new(VertexBuffer::f32x3(&v2))
            .flags(&f2)
            .sbt_index_offsets(SbtIndexOffsets {
                data: &d2,
                size: SbtIndexSize::U16,
                stride: 4,
            })
            .primitive_index_offset(100)
            .into(),
        TriangleInput::new(VertexBuffer::f32x3(&v3))
            .indices(IndexBuffer::u16x3(&ix3))
            .flags(&f3)
            .sbt_index_offsets(SbtIndexOffsets {
                data: &d3,
                size: SbtIndexSize::U32,
                stride: 8,
            })
            .into(),
    ];
    let gas = build(&inputs).unwrap();
    assert_eq!(gas.num_build_inputs(), 4);
    assert_eq!(gas.num_sbt_records(), 4 + 1 + 2 + 3);
    assert_eq!(gas.num_primitives(), 4 + 3 + 3 + 2);
    assert_eq!(gas.kind(), BuildInputKind::Triangles);
    let all_flags: Vec<GeometryFlags> = [&f0, &f1, &f2, &f3]
        .iter()
        .flat_map(|f| f.iter().copied())
        .collect();
    for (i, f) in all_flags.iter().enumerate() {
        assert_eq!(gas.geometry_flags(i as u32), Some(*f));
    }
    assert_eq!(gas.geometry_flags(10), None);

    // (x0, input, first SBT-GAS index, per-triangle offsets, primitive index offset)
    let cases: [(f32, u32, u32, Vec<u32>, u32); 4] = [
        (x0, 0, 0, o0.iter().map(|&o| o as u32).collect(), 0),
        (x1, 1, 4, vec![0; 3], 0),
        (x2, 2, 5, o2.iter().map(|&o| o as u32).collect(), 100),
        (x3, 3, 7, o3.to_vec(), 0),
    ];
    for (x, input, base, offsets, pio) in cases {
        for (k, offset) in offsets.iter().enumerate() {
            let h = gas.intersect(&ray_onto(x, k)).expect("hit");
            assert_eq!(h.build_input, input);
            assert_eq!(h.primitive_index, pio + k as u32);
            assert_eq!(
                h.sbt_gas_index,
                base + offset,
                "input {input}, primitive {k}"
            );
            assert_eq!(
                gas.geometry_flags(h.sbt_gas_index),
                Some(all_flags[h.sbt_gas_index as usize])
            );
        }
    }
    // The guide's example: inputs with 4, 1 and 2 records map input 1 to index 4 and input 2 to
    // indices 5 and 6.
    let ex = |n: usize| vec![GeometryFlags::empty(); n];
    let (e0, e1, e2) = (ex(4), ex(1), ex(2));
    let g = build(&[
        TriangleInput::new(VertexBuffer::f32x3(&v0))
            .flags(&e0)
            .sbt_index_offsets(SbtIndexOffsets::u8(&[0, 1, 2, 3]))
            .into(),
        TriangleInput::new(VertexBuffer::f32x3(&v1))
            .flags(&e1)
            .into(),
        TriangleInput::new(VertexBuffer::f32x3(&v2))
            .flags(&e2)
            .sbt_index_offsets(SbtIndexOffsets::u8(&[0, 1, 1]))
            .into(),
    ])
    .unwrap();
    let sbt = |x: f32, k: usize| g.intersect(&ray_onto(x, k)).unwrap().sbt_gas_index;
    assert_eq!(
        [sbt(x0, 0), sbt(x0, 1), sbt(x0, 2), sbt(x0, 3)],
        [0, 1, 2, 3]
    );
    assert_eq!([sbt(x1, 0), sbt(x1, 2)], [4, 4]);
    assert_eq!([sbt(x2, 0), sbt(x2, 1), sbt(x2, 2)], [5, 6, 6]);
}

/// Guide §7.3.2 for custom primitives: the intersection closure and the hit see the same
/// resolved SBT-GAS index, build input and primitive index.
#[test]
fn custom_primitive_sbt_gas_index_7_3_2() {
    let boxes_at = |x0: f32, n: usize| -> Vec<Aabb> {
        (0..n)
            .map(|k| {
                let x = x0 + 2.0 * k as f32;
                Aabb::new(Vec3::new(x, 0.0, -0.5), Vec3::new(x + 1.0, 1.0, 0.0))
            })
            .collect()
    };
    let (b0, b1, b2) = (boxes_at(0.0, 3), boxes_at(100.0, 2), boxes_at(200.0, 3));
    let (f0, f1, f2) = (
        vec![GeometryFlags::empty(); 2],
        vec![GeometryFlags::DISABLE_ANYHIT],
        vec![GeometryFlags::REQUIRE_SINGLE_ANYHIT_CALL; 3],
    );
    let o0 = [1u8, 0, 1];
    let o2 = [2u32, 2, 0];
    let gas = build(&[
        CustomPrimitiveInput::new(AabbBuffer::new(&b0))
            .flags(&f0)
            .sbt_index_offsets(SbtIndexOffsets::u8(&o0))
            .into(),
        CustomPrimitiveInput::new(AabbBuffer::new(&b1))
            .flags(&f1)
            .primitive_index_offset(50)
            .into(),
        CustomPrimitiveInput::new(AabbBuffer::new(&b2))
            .flags(&f2)
            .sbt_index_offsets(SbtIndexOffsets::u32(&o2))
            .into(),
    ])
    .unwrap();
    assert_eq!(gas.num_sbt_records(), 6);
    assert_eq!(gas.kind(), BuildInputKind::CustomPrimitives);
    assert_eq!(gas.geometry_flags(2), Some(GeometryFlags::DISABLE_ANYHIT));
    assert_eq!(
        gas.geometry_flags(5),
        Some(GeometryFlags::REQUIRE_SINGLE_ANYHIT_CALL)
    );
    // (x0, boxes, input, first SBT-GAS index, per-box offsets, primitive index offset)
    type Case<'a> = (f32, &'a [Aabb], u32, u32, Vec<u32>, u32);
    let cases: [Case<'_>; 3] = [
        (0.0, &b0, 0, 0, o0.iter().map(|&o| o as u32).collect(), 0),
        (100.0, &b1, 1, 2, vec![0, 0], 50),
        (200.0, &b2, 2, 3, o2.to_vec(), 0),
    ];
    for (x, boxes, input, base, offsets, pio) in cases {
        for (k, b) in boxes.iter().enumerate() {
            let mut seen = None;
            let h = gas
                .intersect_with(&ray_onto(x, k), &mut |p: &CustomPrimitive, _: &Ray| {
                    seen = Some(*p);
                    Some(CustomHit {
                        t: 1.0,
                        hit_kind: 5,
                        u: 0.5,
                        v: 0.25,
                    })
                })
                .expect("hit");
            let expected = CustomPrimitive {
                primitive_index: pio + k as u32,
                sbt_gas_index: base + offsets[k],
                build_input: input,
                aabb: *b,
            };
            assert_eq!(seen, Some(expected));
            assert_eq!(
                (
                    h.primitive_index,
                    h.sbt_gas_index,
                    h.build_input,
                    h.hit_kind,
                    h.t,
                    h.u,
                    h.v
                ),
                (
                    expected.primitive_index,
                    expected.sbt_gas_index,
                    input,
                    HitKind(5),
                    1.0,
                    0.5,
                    0.25
                )
            );
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Inactive primitives, empty inputs
// ---------------------------------------------------------------------------------------------

/// Triangles with a NaN or infinite vertex, or zero area, are inactive (§5.1 / the library's
/// build contract): never hit, not counted as active, and harmless to the rest.
#[test]
fn nan_inf_and_degenerate_triangles_are_inactive_5_1() {
    let nan = f32::NAN;
    let inf = f32::INFINITY;
    let verts: Vec<[f32; 3]> = vec![
        // 0: valid
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        // 1: NaN vertex
        [2.0, 0.0, 0.0],
        [3.0, nan, 0.0],
        [2.0, 1.0, 0.0],
        // 2: infinite vertex
        [4.0, 0.0, 0.0],
        [inf, 0.0, 0.0],
        [4.0, 1.0, 0.0],
        // 3: collinear
        [6.0, 0.0, 0.0],
        [7.0, 1.0, 0.0],
        [8.0, 2.0, 0.0],
        // 4: a point
        [8.25, 0.25, 0.0],
        [8.25, 0.25, 0.0],
        [8.25, 0.25, 0.0],
        // 5: -inf everywhere
        [-inf, -inf, -inf],
        [-inf, -inf, -inf],
        [-inf, -inf, -inf],
        // 6: valid, next to the others
        [10.0, 0.0, 0.0],
        [11.0, 0.0, 0.0],
        [10.0, 1.0, 0.0],
    ];
    let gas = build(&[TriangleInput::new(VertexBuffer::f32x3(&verts)).into()]).unwrap();
    assert_eq!(gas.num_primitives(), 7);
    assert_eq!(gas.num_active_primitives(), 2);
    // The bounds hold only the active triangles.
    assert_eq!(
        gas.bounds(),
        Aabb::new(Vec3::ZERO, Vec3::new(11.0, 1.0, 0.0))
    );
    assert_eq!(gas.intersect(&ray_onto(0.0, 0)).unwrap().primitive_index, 0);
    assert_eq!(
        gas.intersect(&ray_onto(10.0, 0)).unwrap().primitive_index,
        6
    );
    // Rays through where the inactive ones are, from both sides and obliquely.
    let mut rng = Rng::new(10);
    for _ in 0..2000 {
        let target = Vec3::new(rng.range(1.5, 9.5), rng.range(-0.5, 2.5), 0.0);
        let origin = target
            + Vec3::new(
                rng.range(-0.2, 0.2),
                rng.range(-0.2, 0.2),
                if rng.f32() < 0.5 { 1.0 } else { -1.0 },
            );
        let ray = Ray::new(origin, target - origin);
        assert_eq!(gas.intersect(&ray), None, "{ray:?}");
        assert!(!gas.occluded(&ray));
    }
    // Along the collinear one's line.
    assert_eq!(
        gas.intersect(&Ray::new(
            Vec3::new(5.0, -1.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0)
        )),
        None
    );

    // Only inactive triangles: builds, hits nothing.
    let gas = build(&[TriangleInput::new(VertexBuffer::f32x3(&verts[3..18])).into()]).unwrap();
    assert_eq!((gas.num_primitives(), gas.num_active_primitives()), (5, 0));
    assert_eq!(
        gas.intersect(&Ray::new(Vec3::new(2.2, 0.2, 1.0), -Vec3::Z)),
        None
    );
}

/// Boxes that are inverted or have a NaN or infinite coordinate are inactive: never handed to
/// the intersection closure, never hit. Flat and point boxes are valid (§5.1).
#[test]
fn inverted_and_nan_aabbs_are_inactive_5_1() {
    let b = |min: [f32; 3], max: [f32; 3]| Aabb::new(Vec3::from(min), Vec3::from(max));
    let nan = f32::NAN;
    let inf = f32::INFINITY;
    let boxes = vec![
        b([0.0, 0.0, -1.0], [1.0, 1.0, 0.0]),      // 0 valid
        b([3.0, 0.0, -1.0], [2.0, 1.0, 0.0]),      // 1 inverted in x
        b([4.0, 0.0, -1.0], [5.0, nan, 0.0]),      // 2 NaN
        b([6.0, 0.0, -1.0], [inf, 1.0, 0.0]),      // 3 infinite
        b([8.0, 0.0, 0.0], [9.0, 1.0, 0.0]),       // 4 flat (zero thickness): valid
        b([10.0, 1.0, 0.0], [11.0, 0.0, 0.0]),     // 5 inverted in y
        b([12.25, 0.25, 0.0], [12.25, 0.25, 0.0]), // 6 a point: valid
        Aabb::EMPTY,                               // 7 the empty box
    ];
    let gas = build(&[CustomPrimitiveInput::new(AabbBuffer::new(&boxes)).into()]).unwrap();
    assert_eq!(gas.num_primitives(), 8);
    assert_eq!(gas.num_active_primitives(), 3);
    let mut called = Vec::new();
    let mut hits = Vec::new();
    for k in 0..7 {
        let h = gas.intersect_with(&ray_onto(0.0, k), &mut |p: &CustomPrimitive, r: &Ray| {
            called.push(p.primitive_index);
            Some(CustomHit {
                t: r.tmin,
                hit_kind: 0,
                u: 0.0,
                v: 0.0,
            })
        });
        hits.push(h.map(|h| h.primitive_index));
    }
    assert_eq!(
        hits,
        vec![Some(0), None, None, None, Some(4), None, Some(6)]
    );
    called.sort_unstable();
    called.dedup();
    assert_eq!(called, vec![0, 4, 6]);
}

/// An input with no primitives builds and is never hit (§5: counts may be zero).
#[test]
fn empty_inputs_build_and_never_hit_5_1() {
    let none: [[f32; 3]; 0] = [];
    let no_ix: [[u32; 3]; 0] = [];
    let no_boxes: [Aabb; 0] = [];
    let ray = Ray::new(Vec3::new(0.25, 0.25, 1.0), -Vec3::Z);
    let inputs: [BuildInput<'_>; 3] = [
        TriangleInput::new(VertexBuffer::f32x3(&none)).into(),
        TriangleInput::new(VertexBuffer::f32x3(&TRI))
            .indices(IndexBuffer::u32x3(&no_ix))
            .into(),
        CustomPrimitiveInput::new(AabbBuffer::new(&no_boxes)).into(),
    ];
    for input in inputs {
        let gas = build(&[input]).unwrap();
        assert_eq!((gas.num_primitives(), gas.num_active_primitives()), (0, 0));
        assert!(!gas.bounds().is_valid());
        assert_eq!(gas.intersect(&ray), None);
        assert!(!gas.occluded(&ray));
        let mut called = false;
        let h = gas.intersect_with(&ray, &mut |_: &CustomPrimitive, _: &Ray| {
            called = true;
            None
        });
        assert!(h.is_none() && !called);
        let mut out = vec![None; 3];
        gas.intersect_batch(&[ray; 3], &mut out).unwrap();
        assert!(out.iter().all(Option::is_none));
    }
    // An empty input before a real one still counts for indices: input 1, SBT-GAS index 1.
    let gas = build(&[
        TriangleInput::new(VertexBuffer::f32x3(&none)).into(),
        valid_tri(),
    ])
    .unwrap();
    let h = gas.intersect(&ray).unwrap();
    assert_eq!(
        (h.build_input, h.sbt_gas_index, h.primitive_index),
        (1, 1, 0)
    );
}

// ---------------------------------------------------------------------------------------------
// Hit semantics
// ---------------------------------------------------------------------------------------------

/// Guide §13.7: triangle hit kinds are 0xFE for the front face (the vertices counter-clockwise
/// as seen from the ray, i.e. the ray travels against `(v1 - v0) x (v2 - v0)`) and 0xFF for the
/// back face.
#[test]
fn triangle_hit_kind_front_and_back_13_7() {
    assert_eq!(HitKind::TRIANGLE_FRONT_FACE, HitKind(0xFE));
    assert_eq!(HitKind::TRIANGLE_BACK_FACE, HitKind(0xFF));
    // TRI's normal is +Z.
    let gas = build(&[valid_tri()]).unwrap();
    let reversed = [TRI[0], TRI[2], TRI[1]];
    let gas_rev = build(&[TriangleInput::new(VertexBuffer::f32x3(&reversed)).into()]).unwrap();
    let target = Vec3::new(0.25, 0.25, 0.0);
    let mut rng = Rng::new(11);
    for i in 0..200 {
        // Any direction with a negative z component travels against +Z.
        let mut d = if i == 0 { -Vec3::Z } else { rng.dir() };
        d.z = -d.z.abs().max(0.05);
        let down = Ray::new(target - d * 2.0, d);
        let up = Ray::new(target + d * 2.0, -d);
        let h = gas.intersect(&down).unwrap();
        assert_eq!(h.hit_kind, HitKind::TRIANGLE_FRONT_FACE);
        assert!(h.hit_kind.is_triangle_front_face() && !h.hit_kind.is_triangle_back_face());
        let h = gas.intersect(&up).unwrap();
        assert_eq!(h.hit_kind, HitKind::TRIANGLE_BACK_FACE);
        assert!(h.hit_kind.is_triangle_back_face() && !h.hit_kind.is_triangle_front_face());
        assert_eq!(
            gas_rev.intersect(&down).unwrap().hit_kind,
            HitKind::TRIANGLE_BACK_FACE
        );
        assert_eq!(
            gas_rev.intersect(&up).unwrap().hit_kind,
            HitKind::TRIANGLE_FRONT_FACE
        );
    }
}

/// Guide §13.4 / §13.7: triangle barycentrics: hit point = (1-u-v) v0 + u v1 + v v2.
#[test]
fn barycentrics_follow_optix_13_7() {
    let v = [[0.0f32, 0.0, 0.0], [4.0, 0.0, 0.0], [0.0, 4.0, 0.0]];
    let gas = build(&[TriangleInput::new(VertexBuffer::f32x3(&v)).into()]).unwrap();
    let h = gas
        .intersect(&Ray::new(Vec3::new(1.0, 2.0, 5.0), -Vec3::Z))
        .unwrap();
    assert_eq!(h.t, 5.0);
    assert!(
        (h.u - 0.25).abs() < 1e-6 && (h.v - 0.5).abs() < 1e-6,
        "{h:?}"
    );
    // Random triangles and rays: the barycentric point is the hit point.
    let mut rng = Rng::new(12);
    let mut checked = 0;
    while checked < 2000 {
        let t: [Vec3; 3] = std::array::from_fn(|_| rng.vec3(-1.0, 1.0));
        let (a, b) = (rng.range(0.05, 0.45), rng.range(0.05, 0.45));
        let p = t[0] * (1.0 - a - b) + t[1] * a + t[2] * b;
        let dir = rng.dir().normalize();
        let n = (t[1] - t[0]).cross(t[2] - t[0]);
        // Well-shaped triangles and non-grazing rays: the barycentrics are well conditioned.
        if n.length() < 0.1 || n.normalize().dot(dir).abs() < 0.2 {
            continue;
        }
        checked += 1;
        let o = p + dir * 2.0;
        let verts = t.map(|x| x.to_array());
        let gas = build(&[TriangleInput::new(VertexBuffer::f32x3(&verts)).into()]).unwrap();
        let ray = Ray::new(o, p - o);
        let Some(h) = gas.intersect(&ray) else {
            panic!("missed an interior point; {ray:?}, {verts:?}");
        };
        let q = t[0] * (1.0 - h.u - h.v) + t[1] * h.u + t[2] * h.v;
        assert!((q - ray.at(h.t)).length() < 1e-4, "{q} vs {}", ray.at(h.t));
        assert!(
            (h.u - a).abs() < 1e-3 && (h.v - b).abs() < 1e-3,
            "({}, {}) vs ({a}, {b})",
            h.u,
            h.v
        );
    }
}

/// Guide §13.2: the ray interval is closed: a hit exactly at `tmin` or at `tmax` is reported,
/// one just outside is not.
#[test]
fn hits_at_tmin_and_tmax_are_reported_13_2() {
    let gas = build(&[valid_tri()]).unwrap();
    let (o, d) = (Vec3::new(0.25, 0.25, 2.0), -Vec3::Z);
    // Hand-computed: the plane z = 0 is 2 units away.
    assert_eq!(gas.intersect(&Ray::new(o, d)).unwrap().t, 2.0);
    let below = 2.0f32.next_down();
    let above = 2.0f32.next_up();
    for (tmin, tmax, hit) in [
        (2.0, f32::INFINITY, true),
        (0.0, 2.0, true),
        (2.0, 2.0, true),
        (0.0, below, false),
        (above, f32::INFINITY, false),
        (above, 3.0, false),
    ] {
        let ray = Ray::with_interval(o, d, tmin, tmax);
        assert_eq!(gas.intersect(&ray).is_some(), hit, "[{tmin}, {tmax}]");
        assert_eq!(gas.occluded(&ray), hit, "[{tmin}, {tmax}]");
    }
    // Custom primitives: a reported t exactly at either end is kept.
    let gas = build(&[valid_custom()]).unwrap();
    for t in [0.5f32, 1.5] {
        let ray = Ray::with_interval(Vec3::new(0.5, 0.5, 2.0), -Vec3::Z, 0.5, 1.5);
        let h = gas.intersect_with(&ray, &mut |_: &CustomPrimitive, _: &Ray| {
            Some(CustomHit {
                t,
                hit_kind: 1,
                u: 0.0,
                v: 0.0,
            })
        });
        assert_eq!(h.map(|h| h.t), Some(t));
    }
}

/// Guide §13.2: the same for an oblique ray, with the interval closed on the distance the query
/// itself reported: re-casting with `tmax = t` (or `tmin = tmax = t`) must find the hit again.
#[test]
fn hit_exactly_at_tmax_is_reported_for_oblique_rays_13_2() {
    let v = [[0.0f32, 0.0, 1.5], [0.5, 0.0, 1.5], [0.5, 0.5, 1.5]];
    let gas = build(&[TriangleInput::new(VertexBuffer::f32x3(&v)).into()]).unwrap();
    let ray = Ray::new(Vec3::new(0.25, 0.25, 5.0), Vec3::new(0.01, -0.02, -1.0));
    let t = gas.intersect(&ray).expect("hit").t;
    let closed = Ray { tmax: t, ..ray };
    assert_eq!(
        gas.intersect(&closed).map(|h| h.t),
        Some(t),
        "[0, {t}] loses the hit at {t}"
    );
    assert!(gas.occluded(&closed));
    let point = Ray {
        tmin: t,
        tmax: t,
        ..ray
    };
    assert_eq!(
        gas.intersect(&point).map(|h| h.t),
        Some(t),
        "[{t}, {t}] loses the hit at {t}"
    );
}

/// Guide §13.14 / §13.2: invalid rays are rejected by `Ray::validate` with the right reason and
/// hit nothing (single and batch queries).
#[test]
fn invalid_rays_never_hit_13_14() {
    let gas = build(&[valid_tri()]).unwrap();
    let o = Vec3::new(0.25, 0.25, 1.0);
    let d = -Vec3::Z;
    let nan = f32::NAN;
    let cases = [
        (
            Ray::new(Vec3::new(nan, 0.25, 1.0), d),
            RayError::NonFiniteOrigin,
        ),
        (
            Ray::new(Vec3::new(0.25, f32::INFINITY, 1.0), d),
            RayError::NonFiniteOrigin,
        ),
        (
            Ray::new(o, Vec3::new(0.0, 0.0, nan)),
            RayError::NonFiniteDirection,
        ),
        (
            Ray::new(o, Vec3::new(0.0, f32::NEG_INFINITY, -1.0)),
            RayError::NonFiniteDirection,
        ),
        (Ray::new(o, Vec3::ZERO), RayError::ZeroDirection),
        (
            Ray::new(o, Vec3::new(-0.0, 0.0, -0.0)),
            RayError::ZeroDirection,
        ),
        (Ray::with_interval(o, d, nan, 2.0), RayError::NanInterval),
        (Ray::with_interval(o, d, 0.0, nan), RayError::NanInterval),
        (Ray::with_interval(o, d, -0.5, 2.0), RayError::NegativeTmin),
        (
            Ray::with_interval(o, d, f32::NEG_INFINITY, 2.0),
            RayError::NegativeTmin,
        ),
        (Ray::with_interval(o, d, 1.5, 0.5), RayError::EmptyInterval),
        (
            Ray::with_interval(o, d, f32::INFINITY, 2.0),
            RayError::EmptyInterval,
        ),
    ];
    for (ray, err) in cases {
        assert_eq!(ray.validate(), Err(err), "{ray:?}");
        assert_eq!(gas.intersect(&ray), None, "{ray:?}");
        assert!(!gas.occluded(&ray), "{ray:?}");
        let mut called = false;
        let h = gas.intersect_filtered(&ray, &mut NoCustomPrimitives, |_| {
            called = true;
            CandidateAction::Accept
        });
        assert!(h.is_none() && !called);
    }
    let rays: Vec<Ray> = cases.iter().map(|c| c.0).collect();
    let mut hits = vec![Some(gas.intersect(&Ray::new(o, d)).unwrap()); rays.len()];
    gas.intersect_batch(&rays, &mut hits).unwrap();
    assert!(hits.iter().all(Option::is_none));
    let mut occ = vec![true; rays.len()];
    gas.occluded_batch(&rays, &mut occ).unwrap();
    assert!(occ.iter().all(|o| !o));
    // Valid edge cases: -0 tmin, tmin = tmax, infinite tmax, an unnormalised direction.
    for ray in [
        Ray::with_interval(o, d, -0.0, 2.0),
        Ray::with_interval(o, d, 1.0, 1.0),
        Ray::with_interval(o, d * 1e-3, 0.0, f32::INFINITY),
    ] {
        assert_eq!(ray.validate(), Ok(()));
        assert!(gas.intersect(&ray).is_some(), "{ray:?}");
    }
    // Custom primitives: the closure is never called for an invalid ray.
    let gas = build(&[valid_custom()]).unwrap();
    for (ray, _) in cases {
        let mut called = false;
        assert!(gas
            .intersect_with(&ray, &mut |_: &CustomPrimitive, _: &Ray| {
                called = true;
                Some(CustomHit {
                    t: 1.0,
                    hit_kind: 0,
                    u: 0.0,
                    v: 0.0,
                })
            })
            .is_none());
        assert!(!called);
    }
}

/// Guide §12 / §13.4: only the low 7 bits of a custom hit kind are kept.
#[test]
fn custom_hit_kind_is_masked_to_7_bits_12() {
    assert_eq!(HitKind::custom(0xAB), HitKind(0x2B));
    assert_eq!(HitKind::custom(0x7F), HitKind(0x7F));
    let gas = build(&[valid_custom()]).unwrap();
    let ray = Ray::new(Vec3::new(0.5, 0.5, 2.0), -Vec3::Z);
    for (kind, expected) in [
        (0u8, 0u8),
        (5, 5),
        (127, 127),
        (128, 0),
        (0xFE, 0x7E),
        (0xFF, 0x7F),
    ] {
        let h = gas
            .intersect_with(&ray, &mut |_: &CustomPrimitive, _: &Ray| {
                Some(CustomHit {
                    t: 1.0,
                    hit_kind: kind,
                    u: 0.0,
                    v: 0.0,
                })
            })
            .unwrap();
        assert_eq!(h.hit_kind, HitKind(expected), "kind {kind:#x}");
        // A custom hit never reads as a triangle face.
        assert!(!h.hit_kind.is_triangle_front_face() && !h.hit_kind.is_triangle_back_face());
    }
}

/// Guide §13.2 / §13.4: a custom hit reported outside the current `[tmin, tmax]` (or NaN) is
/// ignored; the hits of other primitives are unaffected.
#[test]
fn custom_hit_outside_the_interval_is_ignored_13_4() {
    let boxes = [
        Aabb::new(Vec3::new(0.0, 0.0, -1.0), Vec3::ONE),
        Aabb::new(Vec3::new(0.0, 0.0, -3.0), Vec3::new(1.0, 1.0, -2.0)),
    ];
    let gas = build(&[CustomPrimitiveInput::new(AabbBuffer::new(&boxes)).into()]).unwrap();
    let ray = Ray::with_interval(Vec3::new(0.5, 0.5, 2.0), -Vec3::Z, 1.0, 10.0);
    for bad in [
        0.5f32,
        0.0,
        -1.0,
        10.5,
        f32::INFINITY,
        f32::NAN,
        1.0f32.next_down(),
        10.0f32.next_up(),
    ] {
        // Primitive 0 reports the bad t; primitive 1 nothing.
        let mut only_bad = |p: &CustomPrimitive, _: &Ray| {
            (p.primitive_index == 0).then_some(CustomHit {
                t: bad,
                hit_kind: 0,
                u: 0.0,
                v: 0.0,
            })
        };
        assert_eq!(gas.intersect_with(&ray, &mut only_bad), None, "t = {bad}");
        assert!(!gas.occluded_with(&ray, &mut only_bad), "t = {bad}");
        // Primitive 1 reports a good t farther away: it is the hit.
        let mut mixed = |p: &CustomPrimitive, _: &Ray| {
            Some(CustomHit {
                t: if p.primitive_index == 0 { bad } else { 4.5 },
                hit_kind: 0,
                u: 0.0,
                v: 0.0,
            })
        };
        let h = gas.intersect_with(&ray, &mut mixed).unwrap();
        assert_eq!((h.primitive_index, h.t), (1, 4.5), "t = {bad}");
    }
}

// ---------------------------------------------------------------------------------------------
// Any-hit filters: ignore and terminate (§13.13)
// ---------------------------------------------------------------------------------------------

/// Ten parallel triangles crossing the ray at z = 1, 2, ..., 10 (primitive i at z = i + 1), in
/// an order that scatters them over the tree.
fn stack_of_triangles() -> Gas {
    let mut verts = Vec::new();
    for i in [3, 7, 0, 9, 5, 1, 8, 2, 6, 4] {
        let z = (i + 1) as f32;
        verts.extend_from_slice(&[[-10.0, -10.0, z], [10.0, -10.0, z], [0.0, 10.0, z]]);
    }
    build(&[TriangleInput::new(VertexBuffer::f32x3(&verts)).into()]).unwrap()
}

/// The primitive index of the triangle at z = i + 1 in `stack_of_triangles`.
fn at_depth(i: u32) -> u32 {
    [3, 7, 0, 9, 5, 1, 8, 2, 6, 4]
        .iter()
        .position(|&k| k == i)
        .unwrap() as u32
}

const UP: Ray = Ray {
    origin: Vec3::ZERO,
    tmin: 0.0,
    direction: Vec3::Z,
    tmax: f32::INFINITY,
    time: 0.0,
};

/// Every candidate the filter sees lies within the interval as shrunk by the accepted ones.
fn assert_candidates_within_interval(log: &[(Hit, CandidateAction)], ray: &Ray) {
    let mut tmax = ray.tmax;
    for (h, a) in log {
        assert!(
            h.t >= ray.tmin && h.t <= tmax,
            "candidate {h:?} outside [{}, {tmax}]",
            ray.tmin
        );
        if *a != CandidateAction::Ignore {
            tmax = h.t;
        }
    }
}

/// Guide §13.13: `optixIgnoreIntersection` — ignored candidates never become the closest hit
/// and do not shrink the interval; the next nearest accepted one is returned.
#[test]
fn ignored_candidates_never_become_closest_13_13() {
    let gas = stack_of_triangles();
    assert_eq!(gas.intersect(&UP).unwrap().t, 1.0);
    for k in 0..=10u32 {
        // Ignore the k nearest.
        let mut log = Vec::new();
        let h = gas.intersect_filtered(&UP, &mut NoCustomPrimitives, |h| {
            let a = if h.t < (k + 1) as f32 {
                CandidateAction::Ignore
            } else {
                CandidateAction::Accept
            };
            log.push((*h, a));
            a
        });
        assert_candidates_within_interval(&log, &UP);
        if k == 10 {
            assert_eq!(h, None);
            // Every triangle was offered, as nothing shrank the interval.
            let mut seen: Vec<u32> = log.iter().map(|(h, _)| h.primitive_index).collect();
            seen.sort_unstable();
            seen.dedup();
            assert_eq!(seen, (0..10).collect::<Vec<_>>());
        } else {
            let h = h.unwrap();
            assert_eq!((h.t, h.primitive_index), ((k + 1) as f32, at_depth(k)));
        }
    }
    // Ignoring one in the middle (z = 1 accepted anyway) changes nothing; ignoring only the
    // nearest gives the second.
    let h = gas.intersect_filtered(&UP, &mut NoCustomPrimitives, |h| {
        if h.primitive_index == at_depth(0) {
            CandidateAction::Ignore
        } else {
            CandidateAction::Accept
        }
    });
    assert_eq!(h.unwrap().t, 2.0);
    // Accept-all is the plain closest hit.
    let h = gas.intersect_filtered(&UP, &mut NoCustomPrimitives, |_| CandidateAction::Accept);
    assert_eq!(bits(&h), bits(&gas.intersect(&UP)));
}

/// Guide §13.13: `optixTerminateRay` — the candidate is accepted and traversal stops: that hit
/// is returned and no further candidate is offered.
#[test]
fn terminate_stops_traversal_and_returns_that_hit_13_13() {
    let gas = stack_of_triangles();
    // Terminate on the first candidate seen, whichever it is.
    let mut log = Vec::new();
    let h = gas
        .intersect_filtered(&UP, &mut NoCustomPrimitives, |h| {
            log.push(*h);
            CandidateAction::Terminate
        })
        .unwrap();
    assert_eq!(log.len(), 1);
    assert_eq!(bits(&Some(h)), bits(&Some(log[0])));
    // Ignore everything nearer than z = 6, terminate on z = 6, accept the rest: z = 6 is
    // always offered (accepting farther ones never shrinks the interval below 6) and ends it.
    let target = at_depth(5);
    let mut log = Vec::new();
    let h = gas
        .intersect_filtered(&UP, &mut NoCustomPrimitives, |h| {
            let a = if h.t < 6.0 {
                CandidateAction::Ignore
            } else if h.primitive_index == target {
                CandidateAction::Terminate
            } else {
                CandidateAction::Accept
            };
            log.push((*h, a));
            a
        })
        .unwrap();
    assert_eq!((h.primitive_index, h.t), (target, 6.0));
    let (last, action) = log.last().unwrap();
    assert_eq!(
        (last.primitive_index, *action),
        (target, CandidateAction::Terminate)
    );
    assert_eq!(
        log.iter()
            .filter(|(_, a)| *a == CandidateAction::Terminate)
            .count(),
        1
    );
    assert_candidates_within_interval(&log, &UP);
    // Terminating on a far candidate returns it even though nearer ones exist, if it comes
    // first; in any case the result is the terminating candidate or a nearer accepted one.
    let far = at_depth(9);
    let mut log = Vec::new();
    let h = gas
        .intersect_filtered(&UP, &mut NoCustomPrimitives, |h| {
            let a = if h.primitive_index == far {
                CandidateAction::Terminate
            } else {
                CandidateAction::Accept
            };
            log.push((*h, a));
            a
        })
        .unwrap();
    match log
        .iter()
        .position(|(_, a)| *a == CandidateAction::Terminate)
    {
        Some(i) => {
            assert_eq!(i, log.len() - 1, "candidates offered after terminate");
            assert_eq!(h.primitive_index, far);
        }
        None => assert_eq!(h.t, 1.0),
    }
    assert_candidates_within_interval(&log, &UP);
}

/// Guide §13.13 with custom primitives: the filter sees custom hits too.
#[test]
fn filters_apply_to_custom_hits_13_13() {
    let boxes: Vec<Aabb> = (0..6)
        .map(|i| {
            Aabb::new(
                Vec3::new(-1.0, -1.0, i as f32 + 1.0),
                Vec3::new(1.0, 1.0, i as f32 + 1.5),
            )
        })
        .collect();
    let gas = build(&[CustomPrimitiveInput::new(AabbBuffer::new(&boxes)).into()]).unwrap();
    let mut entry = |p: &CustomPrimitive, r: &Ray| {
        let t = p.aabb.min.z - r.origin.z;
        (t >= r.tmin && t <= r.tmax).then_some(CustomHit {
            t,
            hit_kind: 3,
            u: 0.0,
            v: 0.0,
        })
    };
    let h = gas.intersect_with(&UP, &mut entry).unwrap();
    assert_eq!((h.primitive_index, h.t), (0, 1.0));
    let h = gas
        .intersect_filtered(&UP, &mut entry, |h| {
            if h.primitive_index < 3 {
                CandidateAction::Ignore
            } else {
                CandidateAction::Accept
            }
        })
        .unwrap();
    assert_eq!((h.primitive_index, h.t), (3, 4.0));
    let mut calls = 0;
    let h = gas
        .intersect_filtered(&UP, &mut entry, |_| {
            calls += 1;
            CandidateAction::Terminate
        })
        .unwrap();
    assert_eq!(calls, 1);
    assert_eq!(h.hit_kind, HitKind(3));
}

// ---------------------------------------------------------------------------------------------
// Batch APIs
// ---------------------------------------------------------------------------------------------

/// Batch queries need one output per ray.
#[test]
fn batch_length_mismatch_is_rejected() {
    let gas = build(&[valid_tri()]).unwrap();
    let rays = [Ray::new(Vec3::new(0.25, 0.25, 1.0), -Vec3::Z); 3];
    let mut hits = vec![None; 2];
    let e = gas.intersect_batch(&rays, &mut hits).unwrap_err();
    assert_eq!(
        e,
        QueryError::LengthMismatch {
            rays: 3,
            outputs: 2
        }
    );
    assert!(e.to_string().contains('3') && e.to_string().contains('2'));
    let mut occ = vec![false; 4];
    assert_eq!(
        gas.occluded_batch(&rays, &mut occ),
        Err(QueryError::LengthMismatch {
            rays: 3,
            outputs: 4
        })
    );
    let mut hits = vec![None; 0];
    let never = |_: &CustomPrimitive, _: &Ray| -> Option<CustomHit> { None };
    assert_eq!(
        gas.intersect_batch_with(&rays, &mut hits, &never),
        Err(QueryError::LengthMismatch {
            rays: 3,
            outputs: 0
        })
    );
    // Matching lengths (including empty) work, and agree with single queries.
    let mut hits = vec![None; 3];
    gas.intersect_batch(&rays, &mut hits).unwrap();
    assert!(hits
        .iter()
        .all(|h| bits(h) == bits(&gas.intersect(&rays[0]))));
    gas.intersect_batch(&[], &mut []).unwrap();
    let mut occ = vec![false; 3];
    gas.occluded_batch(&rays, &mut occ).unwrap();
    assert_eq!(occ, vec![true; 3]);
}
