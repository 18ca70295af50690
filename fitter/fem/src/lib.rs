//! palpate's shared finite-element layer for the offline tools: tetrahedral meshes (Gmsh in, VTK
//! out, refinement, generated boxes), the f64 forward model that both fitters and the diagnosis
//! solve (warped linear FEM of seed 000 with the runtime's element maths), static measurement
//! datasets, and the owned model record the fitters export for the runtime.
//!
//! What it must not depend on: any fitter, the diagnosis, the link or the command line — they all
//! build on it.

pub mod block_model;
pub mod dataset;
pub mod export;
pub mod forward;
pub mod geometry;
pub mod io;
pub mod lm;
pub mod mesh;
pub mod names;
pub mod numbers;
pub mod one_coordinate;
pub mod rng;
pub mod runtime_storage;
pub mod sanity;
pub mod simulate;
