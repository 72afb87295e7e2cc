//! Validation of build inputs: every rule of guide §5, §5.1, §5.3, §5.5 and §12 that can be
//! checked before reading the data, and the data checks (index and SBT offset ranges) the build makes.

use crate::curve::{CurveEndcaps, CurveInput, CurveType};
use crate::error::{BufferKind, BuildError, InputLocation};
use crate::input::{BuildInput, BuildInputKind, SbtIndexOffsets, SphereInput};
use crate::options::{BuildFlags, BuildOptions};

/// Maximum primitives per GAS, motion keys included (guide §12).
pub const MAX_PRIMITIVES_PER_GAS: u64 = 1 << 29;
/// Maximum SBT records referenced by one GAS (guide §12).
pub const MAX_SBT_RECORDS_PER_GAS: u64 = 1 << 24;

/// What validation learnt about a set of build inputs.
#[derive(Clone, Copy, Debug)]
pub struct InputSummary {
    /// The kind of every input.
    pub kind: BuildInputKind,
    /// Primitives declared over all inputs.
    pub num_primitives: u32,
    /// SBT records over all inputs.
    pub num_sbt_records: u32,
}

/// Checks everything that does not need the buffers' contents.
pub fn validate_structure(
    options: &BuildOptions,
    inputs: &[BuildInput<'_>],
) -> Result<InputSummary, BuildError> {
    let Some(first) = inputs.first() else {
        return Err(BuildError::NoBuildInputs);
    };
    options.motion.validate_for_structure()?;
    let keys = options.motion.key_count();
    if options
        .flags
        .contains(BuildFlags::PREFER_FAST_TRACE | BuildFlags::PREFER_FAST_BUILD)
    {
        return Err(BuildError::ConflictingBuildFlags);
    }
    if let Some(index) = inputs.iter().position(|i| {
        matches!(
            i.kind(),
            BuildInputKind::Instances | BuildInputKind::InstancePointers
        )
    }) {
        return Err(BuildError::InstancesInGas { index });
    }
    let kind = first.kind();
    if let Some((index, other)) = inputs.iter().enumerate().find(|(_, i)| i.kind() != kind) {
        return Err(BuildError::MixedInputTypes {
            index,
            expected: kind,
            found: other.kind(),
        });
    }

    // Limits first, on declared counts, so that they are reported before any buffer problem.
    let mut prims = 0u64;
    let mut records = 0u64;
    for (i, input) in inputs.iter().enumerate() {
        if input.flags().is_empty() {
            return Err(BuildError::NoSbtRecords {
                at: InputLocation { input: i },
            });
        }
        prims += input.num_primitives() as u64;
        records += input.flags().len() as u64;
    }
    // The limit counts every key's primitives (guide §12).
    if prims * keys as u64 > MAX_PRIMITIVES_PER_GAS {
        return Err(BuildError::TooManyPrimitives {
            count: prims * keys as u64,
            limit: MAX_PRIMITIVES_PER_GAS,
        });
    }
    if records > MAX_SBT_RECORDS_PER_GAS {
        return Err(BuildError::TooManySbtRecords {
            count: records,
            limit: MAX_SBT_RECORDS_PER_GAS,
        });
    }

    for (i, input) in inputs.iter().enumerate() {
        let at = InputLocation { input: i };
        match input {
            BuildInput::Triangles(t) => {
                let v = &t.vertices;
                check_key_count(at, BufferKind::Vertices, t.num_motion_keys(), keys)?;
                for (key, k) in (0..keys).filter_map(|key| Some((key, t.vertex_key(key)?))) {
                    if k.count != v.count || k.format != v.format {
                        return Err(BuildError::MotionKeyMismatch {
                            at,
                            key,
                            buffer: BufferKind::Vertices,
                        });
                    }
                    check_stride(
                        at,
                        BufferKind::Vertices,
                        k.stride,
                        k.format.size(),
                        k.format.alignment(),
                    )?;
                    check_len(
                        at,
                        BufferKind::Vertices,
                        k.data.len(),
                        k.count,
                        k.effective_stride(),
                        k.format.size(),
                    )?;
                }
                match &t.indices {
                    Some(ix) => {
                        check_stride(
                            at,
                            BufferKind::Indices,
                            ix.stride,
                            ix.format.size(),
                            ix.format.alignment(),
                        )?;
                        check_len(
                            at,
                            BufferKind::Indices,
                            ix.data.len(),
                            ix.count,
                            ix.effective_stride(),
                            ix.format.size(),
                        )?;
                    }
                    None => {
                        if v.count % 3 != 0 {
                            return Err(BuildError::VertexCountNotMultipleOfThree {
                                at,
                                count: v.count,
                            });
                        }
                    }
                }
            }
            BuildInput::Instances(_) | BuildInput::InstancePointers(_) => {
                unreachable!("instance inputs were refused above")
            }
            BuildInput::Spheres(s) => validate_spheres(at, s, keys)?,
            BuildInput::Curves(c) => validate_curves(at, c, keys)?,
            BuildInput::CustomPrimitives(c) => {
                check_key_count(at, BufferKind::Aabbs, 1 + c.motion_aabbs.len(), keys)?;
                for (key, a) in (0..keys).filter_map(|key| Some((key, c.aabb_key(key)?))) {
                    if a.count != c.aabbs.count {
                        return Err(BuildError::MotionKeyMismatch {
                            at,
                            key,
                            buffer: BufferKind::Aabbs,
                        });
                    }
                    check_stride(at, BufferKind::Aabbs, a.stride, 24, 8)?;
                    check_len(
                        at,
                        BufferKind::Aabbs,
                        a.data.len(),
                        a.count,
                        a.effective_stride(),
                        24,
                    )?;
                }
            }
        }
        let n = input.num_primitives();
        let offset = input.primitive_index_offset();
        if offset.checked_add(n).is_none() {
            return Err(BuildError::PrimitiveIndexOffsetOverflow {
                at,
                offset,
                count: n,
            });
        }
        let num_sbt_records = input.flags().len() as u32;
        match input.sbt_index_offsets() {
            None if num_sbt_records > 1 => {
                return Err(BuildError::MissingSbtIndexOffsets {
                    at,
                    num_sbt_records,
                });
            }
            None => {}
            Some(o) => {
                let size = o.size.size();
                check_stride(at, BufferKind::SbtIndexOffsets, o.stride, size, size)?;
                check_len(
                    at,
                    BufferKind::SbtIndexOffsets,
                    o.data.len(),
                    n,
                    o.effective_stride(),
                    size,
                )?;
            }
        }
    }
    Ok(InputSummary {
        kind,
        num_primitives: prims as u32,
        num_sbt_records: records as u32,
    })
}

/// One buffer per motion key of the build (guide §5.10.2).
fn check_key_count(
    at: InputLocation,
    buffer: BufferKind,
    given: usize,
    expected: usize,
) -> Result<(), BuildError> {
    if given != expected {
        return Err(BuildError::MotionKeyCount {
            at,
            buffer,
            given,
            expected,
        });
    }
    Ok(())
}

/// The rules of guide §5.3 (and `OptixBuildInputSphereArray`'s fields): one centre buffer and
/// one radius buffer per motion key, `float3` centres and `f32` radii with strides that are 0
/// or a multiple of 4 and at least one element, buffers long enough for `numVertices`
/// elements (one radius per buffer with `singleRadius`).
fn validate_spheres(at: InputLocation, s: &SphereInput<'_>, keys: usize) -> Result<(), BuildError> {
    check_key_count(at, BufferKind::Vertices, s.vertex_buffers.len(), keys)?;
    check_key_count(at, BufferKind::Radii, s.radius_buffers.len(), keys)?;
    check_stride(at, BufferKind::Vertices, s.vertex_stride, 12, 4)?;
    check_stride(at, BufferKind::Radii, s.radius_stride, 4, 4)?;
    let n = s.num_vertices;
    for centres in s.vertex_buffers {
        check_len(
            at,
            BufferKind::Vertices,
            centres.len(),
            n,
            s.effective_vertex_stride(),
            12,
        )?;
    }
    // With singleRadius one radius serves every sphere (and none is needed for no sphere).
    let radii = if s.single_radius { n.min(1) } else { n };
    for r in s.radius_buffers {
        check_len(
            at,
            BufferKind::Radii,
            r.len(),
            radii,
            s.effective_radius_stride(),
            4,
        )?;
    }
    Ok(())
}

/// The rules of guide §5.2 and §9.1 (and `OptixBuildInputCurveArray`'s fields): one vertex
/// and one width buffer per motion key, normals (per key) only for ribbons, `float3` points,
/// `f32` radii, `u32` indices with strides that are 0 or a multiple of 4, buffers long enough,
/// no flat end caps on linear curves, and every segment's control points inside the vertex
/// buffer.
fn validate_curves(at: InputLocation, c: &CurveInput<'_>, keys: usize) -> Result<(), BuildError> {
    check_key_count(at, BufferKind::Vertices, c.vertex_buffers.len(), keys)?;
    check_key_count(at, BufferKind::Radii, c.width_buffers.len(), keys)?;
    if !c.normal_buffers.is_empty() {
        if !c.curve_type.is_ribbon() {
            return Err(BuildError::InvalidCurveInput {
                at,
                reason: "normals are given but only ribbons (flat quadratic B-splines) take them",
            });
        }
        check_key_count(at, BufferKind::Normals, c.normal_buffers.len(), keys)?;
    }
    if c.curve_type == CurveType::RoundLinear && c.endcaps == CurveEndcaps::On {
        return Err(BuildError::InvalidCurveInput {
            at,
            reason:
                "OPTIX_CURVE_ENDCAP_ON is not valid for linear curves, which always have round caps",
        });
    }
    check_stride(at, BufferKind::Vertices, c.vertex_stride, 12, 4)?;
    check_stride(at, BufferKind::Radii, c.width_stride, 4, 4)?;
    check_stride(at, BufferKind::Normals, c.normal_stride, 12, 4)?;
    check_stride(at, BufferKind::Indices, c.index_stride, 4, 4)?;
    let n = c.num_vertices;
    for v in c.vertex_buffers {
        check_len(
            at,
            BufferKind::Vertices,
            v.len(),
            n,
            c.effective_vertex_stride(),
            12,
        )?;
    }
    for w in c.width_buffers {
        check_len(
            at,
            BufferKind::Radii,
            w.len(),
            n,
            c.effective_width_stride(),
            4,
        )?;
    }
    for nb in c.normal_buffers {
        check_len(
            at,
            BufferKind::Normals,
            nb.len(),
            n,
            c.effective_normal_stride(),
            12,
        )?;
    }
    check_len(
        at,
        BufferKind::Indices,
        c.index_buffer.len(),
        c.num_primitives,
        c.effective_index_stride(),
        4,
    )?;
    let control_points = c.curve_type.control_points() as u32;
    for segment in 0..c.num_primitives {
        let index = c.segment_start(c.index_buffer, segment as usize);
        if index as u64 + control_points as u64 > n as u64 {
            return Err(BuildError::CurveIndexOutOfRange {
                at,
                segment,
                index,
                control_points,
                num_vertices: n,
            });
        }
    }
    Ok(())
}

/// Checks that every per-primitive SBT index offset of an input is in range.
pub fn validate_sbt_offsets(
    at: InputLocation,
    offsets: &SbtIndexOffsets<'_>,
    count: u32,
    num_sbt_records: u32,
) -> Result<(), BuildError> {
    for primitive in 0..count {
        let offset = offsets.get(primitive as usize);
        if offset >= num_sbt_records {
            return Err(BuildError::SbtIndexOffsetOutOfRange {
                at,
                primitive,
                offset,
                num_sbt_records,
            });
        }
    }
    Ok(())
}

fn check_stride(
    at: InputLocation,
    buffer: BufferKind,
    stride: u32,
    elem: usize,
    align: usize,
) -> Result<(), BuildError> {
    if stride == 0 {
        return Ok(());
    }
    let reason = if (stride as usize) < elem {
        "smaller than one element"
    } else if !(stride as usize).is_multiple_of(align) {
        "not a multiple of the element's alignment"
    } else {
        return Ok(());
    };
    Err(BuildError::InvalidStride {
        at,
        buffer,
        stride,
        reason,
    })
}

fn check_len(
    at: InputLocation,
    buffer: BufferKind,
    len: usize,
    count: u32,
    stride: usize,
    elem: usize,
) -> Result<(), BuildError> {
    // The last element needs only its own size, not a whole stride.
    let needed = if count == 0 {
        0
    } else {
        (count as u64 - 1) * stride as u64 + elem as u64
    };
    if (len as u64) < needed {
        return Err(BuildError::BufferTooSmall {
            at,
            buffer,
            count: count as u64,
            needed,
            len: len as u64,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ErrorCode, GeometryFlags, SphereInput};

    const CENTRES: [[f32; 3]; 3] = [[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]];
    const RADII: [f32; 3] = [0.5; 3];

    fn check(input: SphereInput<'_>) -> Result<InputSummary, BuildError> {
        validate_structure(&BuildOptions::default(), &[input.into()])
    }

    #[test]
    fn s5_3_a_sphere_input_is_counted_like_the_others() {
        let c = [bytemuck::cast_slice::<_, u8>(&CENTRES)];
        let r = [bytemuck::cast_slice::<_, u8>(&RADII)];
        let flags = [GeometryFlags::empty(); 2];
        let s = check(
            SphereInput::new(&c, 3, &r)
                .flags(&flags)
                .sbt_index_offsets(SbtIndexOffsets::u8(&[0, 1, 1])),
        )
        .unwrap();
        assert_eq!(
            (s.kind, s.num_primitives, s.num_sbt_records),
            (BuildInputKind::Spheres, 3, 2)
        );
        // §5.1's rules hold for spheres: more than one record needs offsets.
        let err = check(SphereInput::new(&c, 3, &r).flags(&flags)).unwrap_err();
        assert!(matches!(err, BuildError::MissingSbtIndexOffsets { .. }));
        // And all inputs of a GAS have one type (§5).
        let v = [[0.0f32; 3]; 3];
        let tri = crate::TriangleInput::new(crate::VertexBuffer::f32x3(&v));
        let err = validate_structure(
            &BuildOptions::default(),
            &[SphereInput::new(&c, 3, &r).into(), tri.into()],
        )
        .unwrap_err();
        assert!(matches!(err, BuildError::MixedInputTypes { .. }));
    }

    #[test]
    fn s5_3_one_centre_and_one_radius_buffer_per_motion_key() {
        let c = bytemuck::cast_slice::<_, u8>(&CENTRES);
        let r = bytemuck::cast_slice::<_, u8>(&RADII);
        for (cs, rs, buffer, given) in [
            (&[c, c][..], &[r][..], BufferKind::Vertices, 2),
            (&[][..], &[r][..], BufferKind::Vertices, 0),
            (&[c][..], &[r, r][..], BufferKind::Radii, 2),
        ] {
            let err = check(SphereInput::new(cs, 3, rs)).unwrap_err();
            assert_eq!(
                err,
                BuildError::MotionKeyCount {
                    at: InputLocation { input: 0 },
                    buffer,
                    given,
                    expected: 1
                }
            );
            assert_eq!(err.code(), ErrorCode::InvalidValue);
        }
    }

    #[test]
    fn s5_3_strides_and_buffer_sizes() {
        let c = [bytemuck::cast_slice::<_, u8>(&CENTRES)];
        let r = [bytemuck::cast_slice::<_, u8>(&RADII)];
        // Strides: a multiple of 4, at least one element.
        for (input, buffer) in [
            (
                SphereInput::new(&c, 3, &r).vertex_stride(8),
                BufferKind::Vertices,
            ),
            (
                SphereInput::new(&c, 3, &r).vertex_stride(14),
                BufferKind::Vertices,
            ),
            (
                SphereInput::new(&c, 3, &r).radius_stride(6),
                BufferKind::Radii,
            ),
        ] {
            match check(input).unwrap_err() {
                BuildError::InvalidStride { buffer: b, .. } => assert_eq!(b, buffer),
                e => panic!("{e}"),
            }
        }
        // Too short: 4 centres, or 3 radii 8 bytes apart.
        for (input, buffer) in [
            (
                SphereInput::new(&c, 4, &r).single_radius(true),
                BufferKind::Vertices,
            ),
            (
                SphereInput::new(&c, 3, &r).radius_stride(8),
                BufferKind::Radii,
            ),
        ] {
            let err = check(input).unwrap_err();
            assert!(
                matches!(err, BuildError::BufferTooSmall { buffer: b, .. } if b == buffer),
                "{err}"
            );
            assert_eq!(err.code(), ErrorCode::InvalidInput);
        }
        // singleRadius needs one radius; interleaved centres and radii share one buffer.
        let one = [bytemuck::cast_slice::<_, u8>(&RADII[..1])];
        check(SphereInput::new(&c, 3, &one).single_radius(true)).unwrap();
        let packed: Vec<[f32; 4]> = CENTRES.iter().map(|p| [p[0], p[1], p[2], 0.5]).collect();
        let bytes = bytemuck::cast_slice::<_, u8>(&packed);
        let (pc, pr) = ([bytes], [&bytes[12..]]);
        let input = SphereInput::new(&pc, 3, &pr)
            .vertex_stride(16)
            .radius_stride(16);
        check(input).unwrap();
        assert_eq!(input.radius(pr[0], 2), 0.5);
        assert_eq!(input.centre(pc[0], 2).x, 2.0);
    }

    fn check_curve(input: CurveInput<'_>) -> Result<InputSummary, BuildError> {
        validate_structure(&BuildOptions::default(), &[input.into()])
    }

    /// §5.2, §9.1: one SBT record per curve input (one flag), one primitive per segment; the
    /// buffers' strides and sizes, the motion keys, the end caps of linear curves, normals on
    /// non-ribbons and segments past the vertices are refused with typed errors.
    #[test]
    fn s5_2_curve_inputs_are_checked() {
        // Two cubic strands of one segment each, interleaved point + radius (stride 16).
        let packed: Vec<[f32; 4]> = (0..8).map(|i| [i as f32, 0.0, 0.0, 0.1]).collect();
        let bytes = bytemuck::cast_slice::<_, u8>(&packed);
        let (v, w) = ([bytes], [&bytes[12..]]);
        let index = [0u32, 4];
        let ix = bytemuck::cast_slice::<_, u8>(&index);
        let input = CurveInput::new(CurveType::RoundCubicBSpline, &v, 8, &w, ix, 2)
            .vertex_stride(16)
            .width_stride(16)
            .flag(GeometryFlags::DISABLE_ANYHIT);
        let s = check_curve(input).unwrap();
        assert_eq!(
            (s.kind, s.num_primitives, s.num_sbt_records),
            (BuildInputKind::Curves, 2, 1)
        );
        assert_eq!(input.radius(w[0], 7), 0.1);
        assert_eq!(input.point(v[0], 5).x, 5.0);
        assert!(input.starts_strand(1) && input.ends_strand(0));
        // Strides: not a multiple of 4, or smaller than an element.
        for (bad, buffer) in [
            (input.vertex_stride(14), BufferKind::Vertices),
            (input.width_stride(2), BufferKind::Radii),
            (input.index_stride(6), BufferKind::Indices),
            (input.normals(&v, 8), BufferKind::Normals),
        ] {
            let err = check_curve(bad).unwrap_err();
            let ok = matches!(err, BuildError::InvalidStride { buffer: b, .. } if b == buffer)
                || matches!(err, BuildError::InvalidCurveInput { .. });
            assert!(ok, "{err}");
        }
        // Sizes: more vertices or segments than the buffers hold.
        for (bad, buffer) in [
            (
                CurveInput {
                    num_vertices: 9,
                    ..input
                },
                BufferKind::Vertices,
            ),
            (
                CurveInput {
                    num_primitives: 3,
                    ..input
                },
                BufferKind::Indices,
            ),
        ] {
            let err = check_curve(bad).unwrap_err();
            assert!(
                matches!(err, BuildError::BufferTooSmall { buffer: b, .. } if b == buffer),
                "{err}"
            );
            assert_eq!(err.code(), ErrorCode::InvalidInput);
        }
        // Motion keys (§5.10.2): one buffer of each per key, and builds have one key.
        let two = [bytes, bytes];
        let err = check_curve(CurveInput {
            width_buffers: &two,
            ..input
        })
        .unwrap_err();
        assert!(matches!(
            err,
            BuildError::MotionKeyCount {
                buffer: BufferKind::Radii,
                given: 2,
                expected: 1,
                ..
            }
        ));
        assert_eq!(err.code(), ErrorCode::InvalidValue);
        // A segment whose control points run past the vertices.
        let past = [0u32, 5];
        let err = check_curve(CurveInput {
            index_buffer: bytemuck::cast_slice(&past),
            ..input
        })
        .unwrap_err();
        assert!(matches!(
            err,
            BuildError::CurveIndexOutOfRange {
                segment: 1,
                index: 5,
                control_points: 4,
                ..
            }
        ));
        // Flat caps are for the splines; linear curves always have round ones.
        let linear = CurveInput {
            curve_type: CurveType::RoundLinear,
            ..input
        };
        check_curve(linear).unwrap();
        let err = check_curve(linear.endcaps(CurveEndcaps::On)).unwrap_err();
        assert!(matches!(err, BuildError::InvalidCurveInput { .. }), "{err}");
        check_curve(input.endcaps(CurveEndcaps::On)).unwrap();
        // Normals only for ribbons (one buffer per key).
        let ribbon = CurveInput {
            curve_type: CurveType::FlatQuadraticBSpline,
            ..input
        };
        check_curve(ribbon.normals(&v, 16)).unwrap();
        let err = check_curve(input.normals(&v, 16)).unwrap_err();
        assert!(matches!(err, BuildError::InvalidCurveInput { .. }), "{err}");
        let err = check_curve(ribbon.normals(&two, 16)).unwrap_err();
        assert!(matches!(
            err,
            BuildError::MotionKeyCount {
                buffer: BufferKind::Normals,
                ..
            }
        ));
    }
}
