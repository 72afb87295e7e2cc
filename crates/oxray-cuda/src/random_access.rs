//! Random vertex access (guide §13.9) on the device: the table a pipeline's
//! `optixGet…VertexDataFromHandle` reads, and the same access from the host.

use crate::error::driver;
use crate::gas::CudaGas;
use oxray_bvh::{GasKind, NO_PRIMITIVE, NO_SLOT};
use oxray_core::{BuildFlags, RandomAccessError};

impl CudaGas {
    /// The first leaf slot of every primitive by global id ([`NO_SLOT`] where the builder left
    /// it out), made on first use.
    pub(crate) fn primitive_slots(&self) -> &[u32] {
        self.random_slots.get_or_init(|| {
            let mut slots = vec![NO_SLOT; self.meta.num_primitives as usize];
            for (slot, g) in self.slot_globals().into_iter().enumerate() {
                if g != NO_PRIMITIVE {
                    if let Some(s) = slots.get_mut(g as usize) {
                        if *s == NO_SLOT {
                            *s = slot as u32;
                        }
                    }
                }
            }
            slots
        })
    }

    /// The words of the random-access table `__oxray_random_slot` reads: the number of inputs
    /// and of primitives, per input its first global primitive, primitive index offset, first
    /// SBT-GAS index and the end of its SBT-GAS indices, then each primitive's leaf slot.
    /// `None` without `ALLOW_RANDOM_VERTEX_ACCESS`.
    pub(crate) fn random_access_words(&self) -> Option<Vec<u32>> {
        let meta = &self.meta;
        if !meta
            .build_flags
            .contains(BuildFlags::ALLOW_RANDOM_VERTEX_ACCESS)
        {
            return None;
        }
        let n = meta.inputs.len();
        let mut w = Vec::with_capacity(2 + 4 * n + meta.num_primitives as usize);
        w.extend_from_slice(&[n as u32, meta.num_primitives]);
        for (i, r) in meta.inputs.iter().enumerate() {
            let end = meta
                .inputs
                .get(i + 1)
                .map_or(meta.record_flags.len() as u32, |next| next.sbt_base);
            w.extend_from_slice(&[r.first, r.primitive_index_offset, r.sbt_base, end]);
        }
        w.extend_from_slice(self.primitive_slots());
        Some(w)
    }

    /// The `words` 32-bit words of the record of a primitive's slot, read from device memory;
    /// NaN where the builder left it out.
    fn random_record(
        &self,
        kind: GasKind,
        primitive_index: u32,
        sbt_gas_index: u32,
        words: usize,
    ) -> Result<Vec<f32>, RandomAccessError> {
        let slot = self.meta.random_access_slot(
            self.primitive_slots(),
            kind,
            primitive_index,
            sbt_gas_index,
        )?;
        let Some(slot) = slot else {
            return Ok(vec![f32::NAN; words]);
        };
        let per_slot = match kind {
            GasKind::Triangles => 12,
            GasKind::Spheres => 4,
            GasKind::Curves => 24,
            GasKind::CustomPrimitives => 8,
        };
        let at = slot * per_slot;
        let mut out = vec![0u32; per_slot];
        let dev = |e: crate::CudaError| RandomAccessError::Device(e.to_string());
        self.ctx
            .stream
            .memcpy_dtoh(&self.triangles.slice(at..at + per_slot), &mut out[..])
            .map_err(driver("reading a primitive"))
            .map_err(dev)?;
        self.ctx.synchronize().map_err(dev)?;
        Ok(out.into_iter().map(f32::from_bits).collect())
    }

    /// `optixGetTriangleVertexDataFromHandle` from the host: a triangle's vertices (guide
    /// §13.9), read from device memory. The GAS must be built with
    /// `ALLOW_RANDOM_VERTEX_ACCESS`; `time` is unused (no GAS has motion keys on this device).
    #[doc(alias = "optixGetTriangleVertexDataFromHandle")]
    pub fn triangle_vertex_data(
        &self,
        primitive_index: u32,
        sbt_gas_index: u32,
        time: f32,
    ) -> Result<[[f32; 3]; 3], RandomAccessError> {
        let _ = time;
        let r = self.random_record(GasKind::Triangles, primitive_index, sbt_gas_index, 12)?;
        Ok(std::array::from_fn(|k| {
            [r[4 * k], r[4 * k + 1], r[4 * k + 2]]
        }))
    }

    /// `optixGetSphereDataFromHandle` from the host: a sphere's centre and radius.
    #[doc(alias = "optixGetSphereDataFromHandle")]
    pub fn sphere_data(
        &self,
        primitive_index: u32,
        sbt_gas_index: u32,
        time: f32,
    ) -> Result<[f32; 4], RandomAccessError> {
        let _ = time;
        let r = self.random_record(GasKind::Spheres, primitive_index, sbt_gas_index, 4)?;
        Ok([r[0], r[1], r[2], r[3]])
    }

    /// The `optixGet…VertexDataFromHandle` functions of curves from the host: a segment's
    /// control points `(x, y, z, radius)`, as many as its type has, then zeros.
    pub fn curve_vertex_data(
        &self,
        primitive_index: u32,
        sbt_gas_index: u32,
        time: f32,
    ) -> Result<[[f32; 4]; 4], RandomAccessError> {
        let _ = time;
        let r = self.random_record(GasKind::Curves, primitive_index, sbt_gas_index, 24)?;
        Ok(std::array::from_fn(|k| {
            std::array::from_fn(|d| r[4 * k + d])
        }))
    }
}
