//! Typed payloads: a `Pod` value packed into 32-bit payload words, so programs do not count
//! registers.

use bytemuck::Pod;

/// Reads a `T` from the leading payload words (missing words read as 0).
///
/// ```
/// use oxray_util::{read_payload, write_payload};
/// let mut words = [0u32; 4];
/// write_payload(&[1.0f32, 2.0, 3.0], |i, w| words[i] = w);
/// assert_eq!(read_payload::<[f32; 3]>(&words), [1.0, 2.0, 3.0]);
/// ```
#[must_use]
pub fn read_payload<T: Pod>(words: &[u32]) -> T {
    let mut v = T::zeroed();
    let bytes = bytemuck::bytes_of_mut(&mut v);
    for (i, chunk) in bytes.chunks_mut(4).enumerate() {
        let w = words.get(i).copied().unwrap_or(0).to_le_bytes();
        chunk.copy_from_slice(&w[..chunk.len()]);
    }
    v
}

/// Writes a `T` into payload words through `set(index, word)` (e.g. a context's
/// `set_payload`).
pub fn write_payload<T: Pod>(value: &T, mut set: impl FnMut(usize, u32)) {
    for (i, chunk) in bytemuck::bytes_of(value).chunks(4).enumerate() {
        let mut w = [0u8; 4];
        w[..chunk.len()].copy_from_slice(chunk);
        set(i, u32::from_le_bytes(w));
    }
}

/// Payload words a `T` needs.
#[must_use]
pub const fn payload_words<T>() -> usize {
    std::mem::size_of::<T>().div_ceil(4)
}
