//! Output buffers that launch indices write in parallel: the CPU stand-in for the device memory a
//! launch's parameters point to.

use bytemuck::Pod;
use std::marker::PhantomData;
use std::sync::atomic::{AtomicU32, Ordering};

/// A buffer of `T` that every launch index may write through a shared reference. Elements are
/// stored as relaxed atomic words, so concurrent writes are never undefined behaviour; a launch
/// whose indices each write their own elements gives the same contents whatever the thread
/// count. `T` must be a whole number of 32-bit words.
///
/// ```
/// use oxray_cpu::OutputBuffer;
/// let out = OutputBuffer::<[f32; 4]>::new(2);
/// assert!(out.write(1, [1.0, 0.5, 0.25, 1.0]));
/// assert!(!out.write(2, [0.0; 4])); // out of range: ignored
/// assert_eq!(out.to_vec()[1], [1.0, 0.5, 0.25, 1.0]);
/// ```
pub struct OutputBuffer<T> {
    words: Vec<AtomicU32>,
    len: usize,
    _t: PhantomData<T>,
}

impl<T: Pod> OutputBuffer<T> {
    const WORDS: usize = {
        assert!(
            std::mem::size_of::<T>().is_multiple_of(4),
            "OutputBuffer elements must be whole 32-bit words"
        );
        std::mem::size_of::<T>() / 4
    };

    /// A zeroed buffer of `len` elements.
    #[must_use]
    pub fn new(len: usize) -> Self {
        OutputBuffer {
            words: (0..len * Self::WORDS).map(|_| AtomicU32::new(0)).collect(),
            len,
            _t: PhantomData,
        }
    }

    /// Number of elements.
    #[must_use]
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the buffer has no elements.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Writes element `i`; returns false (and writes nothing) if `i` is out of range.
    pub fn write(&self, i: usize, value: T) -> bool {
        if i >= self.len {
            return false;
        }
        let src: &[u8] = bytemuck::bytes_of(&value);
        for (k, w) in src.chunks_exact(4).enumerate() {
            let word = u32::from_le_bytes([w[0], w[1], w[2], w[3]]);
            self.words[i * Self::WORDS + k].store(word, Ordering::Relaxed);
        }
        true
    }

    /// Reads element `i`.
    #[must_use]
    pub fn read(&self, i: usize) -> Option<T> {
        if i >= self.len {
            return None;
        }
        // Into the value itself: programs read elements per sample, so no allocation here.
        let mut value = T::zeroed();
        let dst = bytemuck::bytes_of_mut(&mut value);
        let src = &self.words[i * Self::WORDS..(i + 1) * Self::WORDS];
        for (d, w) in dst.chunks_exact_mut(4).zip(src) {
            d.copy_from_slice(&w.load(Ordering::Relaxed).to_le_bytes());
        }
        Some(value)
    }

    /// All elements.
    #[must_use]
    pub fn to_vec(&self) -> Vec<T> {
        (0..self.len).filter_map(|i| self.read(i)).collect()
    }
}
