//! The example bar of the cross-crate motion tests (seed 001 scenario).

use std::path::{Path, PathBuf};

use palpate_fem::mesh::Mesh;
use palpate_motion::model::{Material, Model};
use palpate_motion::scenario::{example_bar, example_truth, EXAMPLE_BAR_SIZE, EXAMPLE_DT};

/// The bundled motion dataset (`models/motion-example`: a 24-tet bar, front face clamped and
/// shaken, gravity along −y).
pub fn example() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/motion-example")
}

/// The bar: 2 × 8 × 2 cm.
pub const SIZE: [f64; 3] = EXAMPLE_BAR_SIZE;
/// The time step: 180 Hz.
pub const DT: f64 = EXAMPLE_DT;

/// The example bar ([`example_bar`]) in `cells` hexahedra for `steps` steps.
pub fn bar(cells: [usize; 3], steps: usize) -> (Mesh, Model) {
    example_bar(cells, steps).unwrap()
}

/// The example bar's material ([`example_truth`]).
pub fn truth(model: &Model) -> Material {
    example_truth(model)
}

/// The recording of a run observed out of step with its base, shared with the motion specimens.
pub use palpate_specimen::motion::record_late;
