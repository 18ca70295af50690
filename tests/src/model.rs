//! In-memory models for runtime tests, made by the fitter's one record builder
//! ([`palpate_fem::export::ModelBuffers::from_mesh_sets`]) so the tests replay exactly what an
//! export would write; the helpers only let a test choose parameter sets and blends directly.
//! (The protocol crate's own tests build records by hand on purpose, malformed ones included.)

use palpate_fem::export::ProvenanceInfo;
pub use palpate_fem::export::{BlendData, ModelBuffers};
use palpate_fem::forward::Material;
use palpate_fem::mesh::Mesh;
pub use palpate_fem::runtime_storage::Storage;
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::RuntimeConfig;

/// A model of `mesh` with the nodes of `fixed` fixed, parameter sets `sets` (all global or all
/// per element) and blend `blend`. Panics on an invalid combination (a test bug).
pub fn build(mesh: &Mesh, fixed: &[usize], sets: &[Material], blend: &BlendData) -> ModelBuffers {
    let prov = ProvenanceInfo {
        tool: "palpate-tests".into(),
        source: "test mesh".into(),
        notes: String::new(),
    };
    ModelBuffers::from_mesh_sets(mesh, fixed, sets, blend, &prov).expect("valid test model")
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

/// Two parameter sets blended in strain space, each element its own only neighbour (weight 1):
/// set 0 centred at zero strain, set 1 at the strain `eps` (Voigt order), every element's RBF
/// weights for λ and for α given by `weights(value of set 0, value of set 1)`.
pub fn strain_blend(
    mesh: &Mesh,
    fixed: &[usize],
    [p0, p1]: [LambdaAlpha; 2],
    eps: [f64; 6],
    weights: impl Fn(f64, f64) -> [f64; 2],
) -> ModelBuffers {
    let t = mesh.tets.len();
    let sets = [p0, p1].map(|p| Material::per_element(&vec![p; t]));
    build(
        mesh,
        fixed,
        &sets,
        &BlendData::Strain {
            decay: 1.0,
            neighbours: 1,
            neighbour_index: (0..t as u32).collect(),
            neighbour_weight: vec![1.0; t],
            centres: (0..2 * t)
                .flat_map(|k| if k < t { [0.0; 6] } else { eps })
                .collect(),
            weights_lambda: (0..t).flat_map(|_| weights(p0.lambda, p1.lambda)).collect(),
            weights_alpha: (0..t).flat_map(|_| weights(p0.alpha, p1.alpha)).collect(),
        },
    )
}

/// Linear (unwarped) solver settings: PCG to `tolerance`, at most `max_iterations` iterations,
/// the rest the defaults — the runtime checked against linear references.
pub fn linear_config(tolerance: f32, max_iterations: u32) -> RuntimeConfig {
    RuntimeConfig {
        warp: false,
        tolerance,
        max_iterations,
        ..Default::default()
    }
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
