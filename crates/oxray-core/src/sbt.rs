//! The shader binding table (guide §7): records of a 32-byte header naming a program group plus
//! user data, grouped in regions with a base, a stride and a count.

use crate::error::PipelineError;
use bytemuck::Pod;

/// Bytes of a record header (`OPTIX_SBT_RECORD_HEADER_SIZE`).
#[doc(alias = "OPTIX_SBT_RECORD_HEADER_SIZE")]
pub const SBT_RECORD_HEADER_SIZE: usize = 32;
/// Alignment of records and strides (`OPTIX_SBT_RECORD_ALIGNMENT`).
#[doc(alias = "OPTIX_SBT_RECORD_ALIGNMENT")]
pub const SBT_RECORD_ALIGNMENT: usize = 16;

const HEADER_MAGIC: [u8; 8] = *b"oxraySBT";

/// An opaque record header naming a program group, made by
/// a program group's `pack_header` (`optixSbtRecordPackHeader`).
/// Headers may be copied byte-wise and reused by every pipeline that holds the group.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[doc(alias = "optixSbtRecordPackHeader")]
pub struct SbtHeader(pub [u8; SBT_RECORD_HEADER_SIZE]);

impl SbtHeader {
    /// The header of a CPU program group with id `id` (what `pack_header` writes).
    #[must_use]
    pub fn for_group(id: u64) -> SbtHeader {
        let mut h = [0u8; SBT_RECORD_HEADER_SIZE];
        h[..8].copy_from_slice(&HEADER_MAGIC);
        h[8..16].copy_from_slice(&id.to_le_bytes());
        // A check word so that random bytes are not mistaken for a header.
        h[16..24].copy_from_slice(&(id ^ 0x9E37_79B9_7F4A_7C15).to_le_bytes());
        SbtHeader(h)
    }

    /// The program-group id, if the bytes are a header at all.
    #[must_use]
    pub fn group_id(bytes: &[u8]) -> Option<u64> {
        let h: &[u8; SBT_RECORD_HEADER_SIZE] =
            bytes.get(..SBT_RECORD_HEADER_SIZE)?.try_into().ok()?;
        if h[..8] != HEADER_MAGIC {
            return None;
        }
        let id = u64::from_le_bytes(h[8..16].try_into().ok()?);
        let check = u64::from_le_bytes(h[16..24].try_into().ok()?);
        (check == id ^ 0x9E37_79B9_7F4A_7C15).then_some(id)
    }
}

/// A region of the SBT: `count` records `stride` bytes apart, each a header followed by data.
///
/// ```
/// use oxray_core::sbt::SbtRegion;
/// # use oxray_core::sbt::SbtHeader;
/// # let header = SbtHeader([0; 32]);
/// // Two records whose data is an RGB colour; the stride is rounded up to 16 bytes.
/// let region = SbtRegion::from_records(&[(header, [1.0f32, 0.0, 0.0]), (header, [0.0, 1.0, 0.0])]);
/// assert_eq!((region.stride(), region.count()), (48, 2));
/// ```
#[derive(Clone, Debug, Default)]
pub struct SbtRegion {
    bytes: Vec<u8>,
    stride: usize,
    count: usize,
}

impl SbtRegion {
    /// Records of typed data, tightly laid out with a stride of `32 + size_of::<T>()` rounded up
    /// to 16.
    pub fn from_records<T: Pod>(records: &[(SbtHeader, T)]) -> Self {
        let stride = (SBT_RECORD_HEADER_SIZE + std::mem::size_of::<T>())
            .next_multiple_of(SBT_RECORD_ALIGNMENT);
        let mut bytes = vec![0u8; stride * records.len()];
        for (i, (h, d)) in records.iter().enumerate() {
            let r = &mut bytes[i * stride..(i + 1) * stride];
            r[..SBT_RECORD_HEADER_SIZE].copy_from_slice(&h.0);
            r[SBT_RECORD_HEADER_SIZE..SBT_RECORD_HEADER_SIZE + std::mem::size_of::<T>()]
                .copy_from_slice(bytemuck::bytes_of(d));
        }
        SbtRegion {
            bytes,
            stride,
            count: records.len(),
        }
    }

    /// Records whose only content is the header.
    #[must_use]
    pub fn from_headers(headers: &[SbtHeader]) -> Self {
        let records: Vec<(SbtHeader, [u8; 0])> = headers.iter().map(|h| (*h, [])).collect();
        Self::from_records(&records)
    }

    /// A region over raw bytes, as OptiX takes it (`*RecordBase`, `*RecordStrideInBytes`,
    /// `*RecordCount`). The stride must be a multiple of 16 holding at least the header, and
    /// the bytes must hold `count` records.
    pub fn from_bytes(bytes: Vec<u8>, stride: usize, count: usize) -> Result<Self, PipelineError> {
        if !stride.is_multiple_of(SBT_RECORD_ALIGNMENT) || stride < SBT_RECORD_HEADER_SIZE {
            return Err(PipelineError::InvalidSbtStride { stride });
        }
        let needed = stride
            .checked_mul(count)
            .ok_or(PipelineError::InvalidSbtStride { stride })?;
        if bytes.len() < needed {
            return Err(PipelineError::SbtRegionTooSmall {
                needed,
                len: bytes.len(),
            });
        }
        Ok(SbtRegion {
            bytes,
            stride,
            count,
        })
    }

    /// Bytes from one record to the next.
    #[must_use]
    pub fn stride(&self) -> usize {
        self.stride
    }

    /// Number of records.
    #[must_use]
    pub fn count(&self) -> usize {
        self.count
    }

    /// Record `i` (header and data), if it exists.
    #[must_use]
    #[inline]
    pub fn record(&self, i: usize) -> Option<&[u8]> {
        (i < self.count).then(|| &self.bytes[i * self.stride..(i + 1) * self.stride])
    }
}

/// The shader binding table of a launch (`OptixShaderBindingTable`).
#[derive(Clone, Debug, Default)]
#[doc(alias = "OptixShaderBindingTable")]
pub struct ShaderBindingTable {
    /// The ray-generation record (the first record of the region is used).
    pub raygen: SbtRegion,
    /// The exception record, if any (the first record of the region is used).
    pub exception: Option<SbtRegion>,
    /// Miss records, selected by the trace's miss index.
    pub miss: SbtRegion,
    /// Hit-group records, selected by [`hit_group_index`].
    pub hitgroup: SbtRegion,
    /// Callable records, selected by the index of a direct or continuation call.
    pub callables: SbtRegion,
}

/// The hit-group record index of guide §7.3: the instance offsets summed over the ancestors,
/// plus the SBT-GAS index times the trace's stride, plus the trace's offset; only the low four
/// bits of the trace's stride and offset count (§12).
///
/// ```
/// use oxray_core::sbt::hit_group_index;
/// // §7.3.5: instance offset 6, SBT-GAS index 2, stride 2, ray type 1.
/// assert_eq!(hit_group_index(6, 2, 2, 1), 11);
/// // Bits above the fourth are ignored.
/// assert_eq!(hit_group_index(0, 1, 0x12, 0x31), 3);
/// ```
#[must_use]
pub fn hit_group_index(
    instance_offset: u32,
    sbt_gas_index: u32,
    sbt_stride: u32,
    sbt_offset: u32,
) -> u64 {
    instance_offset as u64
        + sbt_gas_index as u64 * (sbt_stride & 0xF) as u64
        + (sbt_offset & 0xF) as u64
}
