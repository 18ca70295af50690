//! The example bar of the cross-crate motion tests (seed 001 scenario).

use palpate_fem::mesh::Mesh;
use palpate_motion::model::{Material, Model};
use palpate_motion::scenario::{example_bar, example_truth};

/// The example bar ([`example_bar`]) in `cells` hexahedra for `steps` steps.
pub fn bar(cells: [usize; 3], steps: usize) -> (Mesh, Model) {
    example_bar(cells, steps).unwrap()
}

/// The example bar's material ([`example_truth`]).
pub fn truth(model: &Model) -> Material {
    example_truth(model)
}
