//! Random access to a structure's primitives and instances (guide §13.9, §13.12): a primitive
//! named as programs know it (its primitive index, with its input's offset, and its SBT-GAS
//! index) found in the leaf slots, and an instance found by its index in the build input.
//! Structures keep the tables this needs only when built with `ALLOW_RANDOM_VERTEX_ACCESS` /
//! `ALLOW_RANDOM_INSTANCE_ACCESS` (the guide: "may use a little more memory").

use crate::gas::{GasData, GasKind, NO_PRIMITIVE};
use crate::ias::{IasData, InstanceData};
use oxray_core::{BuildFlags, RandomAccessError};

/// A primitive the builder left out of every leaf slot (a degenerate triangle, a sphere without
/// a positive radius): its random access reads NaN (guide §13.9).
pub const NO_SLOT: u32 = u32::MAX;

/// The name of a GAS kind in errors.
#[must_use]
pub fn kind_name(kind: GasKind) -> &'static str {
    match kind {
        GasKind::Triangles => "triangles",
        GasKind::CustomPrimitives => "custom primitives",
        GasKind::Spheres => "spheres",
        GasKind::Curves => "curves",
    }
}

impl GasData {
    /// The global primitive id of the primitive programs know as `primitive_index` (what
    /// `optixGetPrimitiveIndex` returns: with the input's primitive index offset) under
    /// `sbt_gas_index` (which names its build input), or `None` where no input matches.
    ///
    /// ```
    /// use oxray_bvh::GasData;
    /// use oxray_core::{BuildOptions, TriangleInput, VertexBuffer};
    /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    /// let a = TriangleInput::new(VertexBuffer::f32x3(&v));
    /// let b = TriangleInput::new(VertexBuffer::f32x3(&v)).primitive_index_offset(10);
    /// let gas = GasData::build(&BuildOptions::default(), &[a.into(), b.into()])?;
    /// assert_eq!(gas.global_primitive(10, 1), Some(1));
    /// assert_eq!(gas.global_primitive(0, 1), None);
    /// # Ok::<(), oxray_core::BuildError>(())
    /// ```
    #[doc(alias = "optixGetPrimitiveIndex")]
    #[must_use]
    pub fn global_primitive(&self, primitive_index: u32, sbt_gas_index: u32) -> Option<u32> {
        let n = self.inputs.len();
        let i = self
            .inputs
            .partition_point(|r| r.sbt_base <= sbt_gas_index)
            .checked_sub(1)?;
        let rec = &self.inputs[i];
        let records_end = self
            .inputs
            .get(i + 1)
            .map_or(self.record_flags.len() as u32, |r| r.sbt_base);
        let prims_end = if i + 1 < n {
            self.inputs[i + 1].first
        } else {
            self.num_primitives
        };
        if sbt_gas_index >= records_end {
            return None;
        }
        let local = primitive_index.checked_sub(rec.primitive_index_offset)?;
        let global = rec.first.checked_add(local)?;
        (global < prims_end).then_some(global)
    }

    /// The first leaf slot of every primitive by global id ([`NO_SLOT`] for one the builder
    /// left out): the table random vertex access reads through.
    #[must_use]
    pub fn primitive_slots(&self) -> Vec<u32> {
        let mut slots = vec![NO_SLOT; self.num_primitives as usize];
        for (slot, &g) in self.slot_prim.iter().enumerate() {
            if g != NO_PRIMITIVE {
                if let Some(s) = slots.get_mut(g as usize) {
                    if *s == NO_SLOT {
                        *s = slot as u32;
                    }
                }
            }
        }
        slots
    }

    /// Checks a random vertex access of `asked` primitives: the build flag and the kind.
    pub fn check_random_vertex_access(&self, asked: GasKind) -> Result<(), RandomAccessError> {
        if !self
            .build_flags
            .contains(BuildFlags::ALLOW_RANDOM_VERTEX_ACCESS)
        {
            return Err(RandomAccessError::NotAllowed {
                flag: "ALLOW_RANDOM_VERTEX_ACCESS",
            });
        }
        if self.kind != asked {
            return Err(RandomAccessError::WrongKind {
                holds: kind_name(self.kind),
                asked: kind_name(asked),
            });
        }
        Ok(())
    }

    /// The leaf slot of a primitive for random vertex access (guide §13.9), through `slots`
    /// ([`primitive_slots`](Self::primitive_slots)): `Ok(None)` for a primitive the builder
    /// left out (its data reads NaN).
    pub fn random_access_slot(
        &self,
        slots: &[u32],
        asked: GasKind,
        primitive_index: u32,
        sbt_gas_index: u32,
    ) -> Result<Option<usize>, RandomAccessError> {
        self.check_random_vertex_access(asked)?;
        let g = self
            .global_primitive(primitive_index, sbt_gas_index)
            .ok_or(RandomAccessError::NoSuchPrimitive {
                primitive_index,
                sbt_gas_index,
            })?;
        Ok(slots
            .get(g as usize)
            .copied()
            .filter(|&s| s != NO_SLOT)
            .map(|s| s as usize))
    }
}

impl IasData {
    /// The instance of index `index` in the build input (`optixGetInstanceTraversableFromIAS`,
    /// guide §13.12): its transforms, id, SBT offset, mask, flags and child. Needs
    /// `ALLOW_RANDOM_INSTANCE_ACCESS`.
    #[doc(alias = "optixGetInstanceTraversableFromIAS")]
    pub fn instance_by_index(&self, index: u32) -> Result<&InstanceData, RandomAccessError> {
        if !self
            .build_flags
            .contains(BuildFlags::ALLOW_RANDOM_INSTANCE_ACCESS)
        {
            return Err(RandomAccessError::NotAllowed {
                flag: "ALLOW_RANDOM_INSTANCE_ACCESS",
            });
        }
        self.slot_of
            .get(index as usize)
            .and_then(|&s| self.instances.get(s as usize))
            .ok_or(RandomAccessError::NoSuchInstance {
                index,
                count: self.num_instances,
            })
    }
}
