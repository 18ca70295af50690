//! In-memory models for runtime tests, made by the fitter's one record builder
//! ([`palpate_fem::export::ModelBuffers::build`]) so the tests replay exactly what an export
//! would write; the helpers only let a test choose parameter sets and blends directly.
//! (The protocol crate's own tests build records by hand on purpose, malformed ones included.)

use nalgebra::Vector3;
pub use palpate_fem::export::{BlendData, ModelBuffers};
use palpate_fem::export::{ModelGeometry, ProvenanceInfo};
use palpate_fem::forward::Material;
use palpate_fem::mesh::Mesh;
pub use palpate_fem::runtime_storage::Storage;
use palpate_runtime::element::tet_geometry;
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::RuntimeConfig;

/// A model of `mesh` with the nodes of `fixed` fixed, parameter sets `sets` (all global or all
/// per element) and blend `blend`. Panics on an invalid combination (a test bug).
pub fn build(mesh: &Mesh, fixed: &[usize], sets: &[Material], blend: &BlendData) -> ModelBuffers {
    let geometry: Vec<_> = mesh
        .tets
        .iter()
        .map(|t| tet_geometry(&t.map(|i| Vector3::from(mesh.nodes[i]))).expect("valid test mesh"))
        .collect();
    let mut is_fixed = vec![false; mesh.nodes.len()];
    for &i in fixed {
        is_fixed[i] = true;
    }
    let surface = mesh.boundary_triangles();
    let geom = ModelGeometry {
        x0: &mesh.nodes,
        tets: &mesh.tets,
        geometry: &geometry,
        fixed: &is_fixed,
        surface: &surface,
    };
    let prov = ProvenanceInfo {
        tool: "palpate-tests".into(),
        source: "test mesh".into(),
        notes: String::new(),
    };
    ModelBuffers::build(&geom, &mesh.node_tags, sets, blend, &prov).expect("valid test model")
}

/// A linear homogeneous model of `mesh` with the nodes of `fixed` fixed.
pub fn homogeneous(mesh: &Mesh, fixed: &[usize], lambda: f64, alpha: f64) -> ModelBuffers {
    build(
        mesh,
        fixed,
        &[Material::homogeneous(LambdaAlpha { lambda, alpha })],
        &BlendData::None,
    )
}

/// The solver settings under which an exported model is compared with the fitter's f64 solve:
/// tolerance 1e-7, up to 5000 PCG iterations, 8 rotation iterations.
pub fn tight_config() -> RuntimeConfig {
    RuntimeConfig {
        tolerance: 1e-7,
        max_iterations: 5000,
        rotation_iterations: 8,
        ..Default::default()
    }
}
