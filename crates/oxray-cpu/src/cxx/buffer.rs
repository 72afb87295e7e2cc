//! Host memory that programs address: the CPU counterpart of a device buffer.

use bytemuck::Pod;
use std::cell::UnsafeCell;

/// `len` values of `T` in host memory, which CUDA C++ programs on the CPU read and write
/// through its address ([`device_ptr`](Self::device_ptr), put in the launch parameters or SBT
/// data), as they would a device buffer on a GPU.
///
/// ```
/// let mut b = oxray_cpu::cxx::HostBuffer::<u32>::from_slice(&[1, 2, 3]);
/// b.write(&[4, 5, 6]);
/// assert_eq!(b.download(), [4, 5, 6]);
/// assert_ne!(b.device_ptr(), 0);
/// ```
pub struct HostBuffer<T: Pod> {
    data: Box<[UnsafeCell<T>]>,
}

// SAFETY: the values are plain data; programs write them only during a launch, which the
// launching thread waits for, and the host reads them between launches (as with device
// memory, reading a buffer while a launch on another thread writes it is the caller's race).
unsafe impl<T: Pod> Sync for HostBuffer<T> {}
// SAFETY: as above; the buffer owns its values.
unsafe impl<T: Pod> Send for HostBuffer<T> {}

impl<T: Pod> std::fmt::Debug for HostBuffer<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "HostBuffer({} x {})",
            self.data.len(),
            std::any::type_name::<T>()
        )
    }
}

impl<T: Pod> HostBuffer<T> {
    /// `len` zeroed values.
    #[must_use]
    pub fn zeroed(len: usize) -> Self {
        HostBuffer {
            data: (0..len).map(|_| UnsafeCell::new(T::zeroed())).collect(),
        }
    }

    /// A copy of `data`.
    pub fn from_slice(data: &[T]) -> Self {
        HostBuffer {
            data: data.iter().map(|&v| UnsafeCell::new(v)).collect(),
        }
    }

    /// Replaces the first `data.len()` values (at most `len()`); returns how many were written.
    pub fn write(&mut self, data: &[T]) -> usize {
        let n = data.len().min(self.data.len());
        for (c, v) in self.data.iter_mut().zip(data) {
            *c.get_mut() = *v;
        }
        n
    }

    /// The values, copied.
    #[must_use]
    pub fn download(&self) -> Vec<T> {
        // SAFETY: no launch writes the buffer while the host reads it (see the Sync impl).
        self.data.iter().map(|c| unsafe { *c.get() }).collect()
    }

    /// The address of the first value (a `T*` for programs).
    #[must_use]
    pub fn device_ptr(&self) -> u64 {
        self.data.as_ptr() as *const T as usize as u64
    }

    /// Values held.
    #[must_use]
    pub fn len(&self) -> usize {
        self.data.len()
    }

    /// Whether it holds no values.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }
}
