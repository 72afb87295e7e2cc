//! A triangle GAS from a vertex slice and an index slice in one call.

use crate::Gas;
use oxray_core::{BuildError, BuildOptions, IndexBuffer, TriangleInput, VertexBuffer};
use thiserror::Error;

/// Why a mesh could not be built.
#[derive(Clone, Debug, Error, PartialEq)]
#[non_exhaustive]
pub enum MeshError {
    /// A triangle names a vertex past the end of the vertex slice.
    #[error("triangle {triangle}: vertex index {index} is out of range ({vertices} vertices)")]
    IndexOutOfRange {
        /// The triangle.
        triangle: usize,
        /// The offending index.
        index: u32,
        /// Vertices given.
        vertices: usize,
    },
    /// More vertices or triangles than a build input can hold (`u32` counts).
    #[error("{0} vertices or triangles exceed the u32 counts of a build input")]
    TooLarge(usize),
    /// The build refused the mesh (see [`BuildError`]).
    #[error(transparent)]
    Build(#[from] BuildError),
}

impl Gas {
    /// Builds a triangle GAS from vertex positions and counter-clockwise vertex-index triplets
    /// in one call, with the default [`BuildOptions`]. The primitive index of a hit is the
    /// position of its triangle in `indices` (build input 0).
    ///
    /// Triangles with a NaN or infinite vertex, and zero-area ones, are left out (inactive,
    /// never hit), as by [`Gas::build`]. An empty `indices` gives an empty GAS, which nothing
    /// hits.
    ///
    /// ```
    /// use oxray_cpu::{Gas, MeshError};
    /// use oxray_core::Ray;
    /// use glam::Vec3;
    /// let vertices = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
    /// let gas = Gas::from_mesh(&vertices, &[[0, 1, 2]])?;
    /// assert_eq!(gas.intersect(&Ray::new(Vec3::Z, -Vec3::Z)).unwrap().t, 1.0);
    ///
    /// let bad = Gas::from_mesh(&vertices, &[[0, 1, 3]]);
    /// assert!(matches!(bad, Err(MeshError::IndexOutOfRange { triangle: 0, index: 3, .. })));
    /// # Ok::<(), MeshError>(())
    /// ```
    pub fn from_mesh(vertices: &[[f32; 3]], indices: &[[u32; 3]]) -> Result<Gas, MeshError> {
        Self::from_mesh_with_options(&BuildOptions::default(), vertices, indices)
    }

    /// [`from_mesh`](Self::from_mesh) with build options (`PREFER_FAST_TRACE`,
    /// `ALLOW_UPDATE`, …). Every query of this module works on the result whatever the options.
    pub fn from_mesh_with_options(
        options: &BuildOptions,
        vertices: &[[f32; 3]],
        indices: &[[u32; 3]],
    ) -> Result<Gas, MeshError> {
        check_indices(vertices.len(), indices)?;
        let input =
            TriangleInput::new(VertexBuffer::f32x3(vertices)).indices(IndexBuffer::u32x3(indices));
        Ok(Gas::build(options, &[input.into()])?)
    }
}

/// Checks that every index names one of `vertices` vertices, and that the counts fit a build
/// input.
pub(crate) fn check_indices(vertices: usize, indices: &[[u32; 3]]) -> Result<(), MeshError> {
    for n in [vertices, indices.len()] {
        if u32::try_from(n).is_err() {
            return Err(MeshError::TooLarge(n));
        }
    }
    for (triangle, t) in indices.iter().enumerate() {
        if let Some(&index) = t.iter().find(|&&i| i as usize >= vertices) {
            return Err(MeshError::IndexOutOfRange {
                triangle,
                index,
                vertices,
            });
        }
    }
    Ok(())
}
