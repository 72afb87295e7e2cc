//! # oxray-testkit
//!
//! Test support shared by the oxray crates' tests, examples and benchmarks, so that there is one
//! copy of each helper:
//! - [`rng`]: [`Rng`], a small deterministic generator (SplitMix64);
//! - [`mesh`]: an indexed [`Mesh`], generators (icosphere, subdivided cube, random triangle
//!   soups), OBJ reading, and the lookup of the shared data meshes (`$OXRAY_MESH_DIR`,
//!   `../shared/data/meshes` beside the checkout, `carry/meshes`);
//! - [`rays`]: the benchmark ray sets of `oxray bench` (coherent camera rays, incoherent diffuse
//!   rays, shadow rays) and "tricky" rays aimed at vertices and edges, bit-identical across
//!   versions;
//! - [`oracle`]: a brute-force reference intersector built on the engine's watertight triangle
//!   test, and exact hit comparisons.
//!
//! The crate depends only on `oxray-core` and `oxray-bvh` (and `glam`, `tobj`), never on a
//! backend, so that every crate of the workspace can take it as a dev-dependency without a
//! cycle. Adapters that need a backend type (building a CPU `Gas` over a [`Mesh`], say) stay in
//! the test crate that uses them.
//!
//! ```
//! use oxray_testkit::{mesh, oracle, rays};
//!
//! // A 320-triangle icosphere and the benchmark's rays for it.
//! let sphere = mesh::icosphere_f32(2);
//! assert_eq!(sphere.triangles.len(), 320);
//! let bench = rays::BenchRays::new(&sphere.positions, &sphere.triangles, 8);
//! assert_eq!(bench.coherent.len(), 64);
//! assert_eq!(bench.incoherent.len(), 64);
//!
//! // The camera stands 2.2 bounding radii from the centre and looks at it: a central ray hits
//! // the unit sphere on a front face, about one unit before the centre.
//! let (_, radius) = rays::center_radius(&sphere.positions);
//! let soup = sphere.soup();
//! let central = &bench.coherent[4 * 8 + 4];
//! let hit = oracle::reference_closest(&soup, central).expect("the central ray hits");
//! assert!(hit.hit.front_face);
//! assert!((hit.hit.t - (2.2 * radius - 1.0)).abs() < 0.1);
//!
//! // Same seed, same rays, bit for bit.
//! let again = rays::hemisphere_rays(&sphere.positions, &sphere.triangles, 64, rays::INCOHERENT_SEED);
//! assert_eq!(rays::ray_hash(&again), rays::ray_hash(&bench.incoherent));
//! ```

#![warn(missing_docs)]

pub mod mesh;
pub mod oracle;
pub mod rays;
pub mod rng;

pub use mesh::{Mesh, Tri};
pub use rng::Rng;
