//! The hit-group SBT layout of optix_util-design.md §1-§2: one chunk per (GAS, material set),
//! GASes in scene order, each chunk ordered by build input, material, ray type.

/// Where one (GAS, material set) chunk lies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChunkInfo {
    /// First record of the chunk: the SBT offset of instances of this GAS with this material
    /// set.
    pub offset: u32,
    /// Records in the chunk: materials of the GAS times ray types of the set.
    pub len: u32,
    /// Ray types of the material set (the trace's SBT stride).
    pub ray_types: u32,
}

/// The hit-group SBT layout of a scene.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SbtLayout {
    /// `chunks[gas][material_set]`.
    pub(crate) chunks: Vec<Vec<ChunkInfo>>,
    pub(crate) total: u32,
}

impl SbtLayout {
    /// Computes the layout from, per GAS, its total material count (Σ of its inputs' material
    /// counts) and the ray-type count of each material set.
    #[must_use]
    pub fn compute(gases: &[(u32, Vec<u32>)]) -> SbtLayout {
        let mut offset = 0u32;
        let chunks = gases
            .iter()
            .map(|(materials, sets)| {
                sets.iter()
                    .map(|&ray_types| {
                        let len = materials * ray_types;
                        let c = ChunkInfo {
                            offset,
                            len,
                            ray_types,
                        };
                        offset += len;
                        c
                    })
                    .collect()
            })
            .collect();
        SbtLayout {
            chunks,
            total: offset,
        }
    }

    /// The chunk of a GAS (by its position in the scene) and material set.
    #[must_use]
    pub fn chunk(&self, gas: usize, material_set: usize) -> Option<ChunkInfo> {
        self.chunks.get(gas)?.get(material_set).copied()
    }

    /// Hit-group records in all.
    #[must_use]
    pub fn hit_group_count(&self) -> u32 {
        self.total
    }
}
