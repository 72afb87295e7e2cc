//! Vertex and index formats of triangle build inputs (guide §5.1) and their decoding.

use glam::Vec3;

/// The format of one vertex in a vertex buffer (`OptixVertexFormat`).
///
/// Two-component formats have `z = 0`. `Snorm16` components map `i16` to `[-1, 1]` as
/// `max(x / 32767, -1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[doc(alias = "OptixVertexFormat")]
pub enum VertexFormat {
    /// Three `f32` (`OPTIX_VERTEX_FORMAT_FLOAT3`).
    #[default]
    F32x3,
    /// Two `f32` (`OPTIX_VERTEX_FORMAT_FLOAT2`).
    F32x2,
    /// Three IEEE half floats (`OPTIX_VERTEX_FORMAT_HALF3`).
    F16x3,
    /// Two IEEE half floats (`OPTIX_VERTEX_FORMAT_HALF2`).
    F16x2,
    /// Three signed normalised 16-bit integers (`OPTIX_VERTEX_FORMAT_SNORM16_3`).
    Snorm16x3,
    /// Two signed normalised 16-bit integers (`OPTIX_VERTEX_FORMAT_SNORM16_2`).
    Snorm16x2,
}

impl VertexFormat {
    /// Bytes of one vertex, the stride of a tightly packed buffer.
    #[must_use]
    pub const fn size(self) -> usize {
        match self {
            VertexFormat::F32x3 => 12,
            VertexFormat::F32x2 => 8,
            VertexFormat::F16x3 | VertexFormat::Snorm16x3 => 6,
            VertexFormat::F16x2 | VertexFormat::Snorm16x2 => 4,
        }
    }

    /// The natural alignment of a component; strides must be a multiple of it.
    #[must_use]
    pub const fn alignment(self) -> usize {
        match self {
            VertexFormat::F32x3 | VertexFormat::F32x2 => 4,
            _ => 2,
        }
    }

    /// Decodes one vertex from the first [`size`](Self::size) bytes of `bytes` (little endian).
    ///
    /// # Panics
    /// If `bytes` is shorter than one vertex (build inputs are validated before decoding).
    #[inline]
    #[must_use]
    pub fn decode(self, bytes: &[u8]) -> Vec3 {
        // One bounds check per vertex: the fixed-size array below needs no more.
        fn take<const N: usize>(b: &[u8]) -> [u8; N] {
            b[..N].try_into().expect("slice of length N")
        }
        fn f32s<const N: usize>(b: [u8; N], i: usize) -> f32 {
            f32::from_le_bytes([b[4 * i], b[4 * i + 1], b[4 * i + 2], b[4 * i + 3]])
        }
        fn f16s<const N: usize>(b: [u8; N], i: usize) -> f32 {
            half::f16::from_le_bytes([b[2 * i], b[2 * i + 1]]).to_f32()
        }
        fn sn<const N: usize>(b: [u8; N], i: usize) -> f32 {
            let x = i16::from_le_bytes([b[2 * i], b[2 * i + 1]]) as f32;
            (x / 32767.0).max(-1.0)
        }
        match self {
            VertexFormat::F32x3 => {
                let b = take::<12>(bytes);
                Vec3::new(f32s(b, 0), f32s(b, 1), f32s(b, 2))
            }
            VertexFormat::F32x2 => {
                let b = take::<8>(bytes);
                Vec3::new(f32s(b, 0), f32s(b, 1), 0.0)
            }
            VertexFormat::F16x3 => {
                let b = take::<6>(bytes);
                Vec3::new(f16s(b, 0), f16s(b, 1), f16s(b, 2))
            }
            VertexFormat::F16x2 => {
                let b = take::<4>(bytes);
                Vec3::new(f16s(b, 0), f16s(b, 1), 0.0)
            }
            VertexFormat::Snorm16x3 => {
                let b = take::<6>(bytes);
                Vec3::new(sn(b, 0), sn(b, 1), sn(b, 2))
            }
            VertexFormat::Snorm16x2 => {
                let b = take::<4>(bytes);
                Vec3::new(sn(b, 0), sn(b, 1), 0.0)
            }
        }
    }
}

/// The format of one index triplet in an index buffer (`OptixIndicesFormat`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[doc(alias = "OptixIndicesFormat")]
pub enum IndexFormat {
    /// Three `u16` (`OPTIX_INDICES_FORMAT_UNSIGNED_SHORT3`).
    U16x3,
    /// Three `u32` (`OPTIX_INDICES_FORMAT_UNSIGNED_INT3`).
    #[default]
    U32x3,
}

impl IndexFormat {
    /// Bytes of one triplet.
    #[must_use]
    pub const fn size(self) -> usize {
        match self {
            IndexFormat::U16x3 => 6,
            IndexFormat::U32x3 => 12,
        }
    }

    /// The natural alignment of one index; strides must be a multiple of it.
    #[must_use]
    pub const fn alignment(self) -> usize {
        match self {
            IndexFormat::U16x3 => 2,
            IndexFormat::U32x3 => 4,
        }
    }

    /// Decodes one triplet from `bytes` (little endian).
    ///
    /// # Panics
    /// If `bytes` is shorter than one triplet (build inputs are validated before decoding).
    #[inline]
    #[must_use]
    pub fn decode(self, bytes: &[u8]) -> [u32; 3] {
        match self {
            IndexFormat::U16x3 => {
                let b: [u8; 6] = bytes[..6].try_into().expect("6 bytes");
                std::array::from_fn(|i| u16::from_le_bytes([b[2 * i], b[2 * i + 1]]) as u32)
            }
            IndexFormat::U32x3 => {
                let b: [u8; 12] = bytes[..12].try_into().expect("12 bytes");
                std::array::from_fn(|i| {
                    u32::from_le_bytes([b[4 * i], b[4 * i + 1], b[4 * i + 2], b[4 * i + 3]])
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decodes_every_format() {
        let f: Vec<u8> = [1.5f32, -2.0, 3.25]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        assert_eq!(VertexFormat::F32x3.decode(&f), Vec3::new(1.5, -2.0, 3.25));
        assert_eq!(VertexFormat::F32x2.decode(&f), Vec3::new(1.5, -2.0, 0.0));
        let h: Vec<u8> = [1.5f32, -2.0, 3.25]
            .iter()
            .flat_map(|&x| half::f16::from_f32(x).to_le_bytes())
            .collect();
        assert_eq!(VertexFormat::F16x3.decode(&h), Vec3::new(1.5, -2.0, 3.25));
        assert_eq!(VertexFormat::F16x2.decode(&h), Vec3::new(1.5, -2.0, 0.0));
        let s: Vec<u8> = [32767i16, -32768, 0]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        assert_eq!(
            VertexFormat::Snorm16x3.decode(&s),
            Vec3::new(1.0, -1.0, 0.0)
        );
        assert_eq!(
            VertexFormat::Snorm16x2.decode(&s),
            Vec3::new(1.0, -1.0, 0.0)
        );
    }

    #[test]
    fn decodes_indices() {
        let a: Vec<u8> = [7u16, 8, 65535]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        assert_eq!(IndexFormat::U16x3.decode(&a), [7, 8, 65535]);
        let b: Vec<u8> = [7u32, 8, 1 << 30]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        assert_eq!(IndexFormat::U32x3.decode(&b), [7, 8, 1 << 30]);
    }
}
