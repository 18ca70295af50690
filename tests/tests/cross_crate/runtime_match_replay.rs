//! Across the crate boundary: the runtime's model matched to the material
//! (`palpate_diagnose::runtime_match`) reports its error with the f64 forward model; exported
//! through the model format and played by the f32 runtime under a press, it must deform as that
//! forward model says, so that the error reported is the runtime's (measured: 3·10⁻⁹ m of 19 mm).

use palpate_diagnose::runtime_match::{match_runtime, MatchOptions};
use palpate_fem::export::{ModelBuffers, ProvenanceInfo};
use palpate_fem::forward::{Load, Material, SolveOptions, StaticProblem};
use palpate_runtime::material::LambdaAlpha;
use palpate_tests::model::{tight_config, Storage};

#[test]
fn the_matched_beam_plays_in_the_runtime_as_the_match_measured_it() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mesh = palpate_fem::mesh::gmsh::read_msh(root.join("models/silicone-beam/beam-coarse.msh"))
        .unwrap();
    let fixed = mesh.node_groups["clamp"].clone();
    let fit: palpate_motion::fitted::FittedModel = serde_json::from_str(
        &std::fs::read_to_string(root.join("docs/results/beam/diagnosis/fit.json")).unwrap(),
    )
    .unwrap();
    let converged = fit.converged.clone().unwrap();
    let own = Material::homogeneous(LambdaAlpha::from_lame(fit.lambda[0], fit.mu[0]));
    let m = match_runtime(&mesh, &fixed, &own, &converged, &MatchOptions::default()).unwrap();
    assert_eq!(m.material.lambda.len(), mesh.tets.len(), "{}", m.markdown());
    let prov = ProvenanceInfo {
        tool: "test".into(),
        source: "beam".into(),
        notes: m.provenance(),
    };
    let bytes = ModelBuffers::from_mesh(&mesh, &fixed, &m.material, &prov)
        .unwrap()
        .encode()
        .unwrap();
    // 1 N on the free end along the beam's gravity: 19 mm of bending, rotations and all.
    let surface = mesh.boundary_triangles();
    let problem = StaticProblem::new(&mesh, &fixed, &surface).unwrap();
    // The node farthest from the clamp.
    let clamp: Vec<f64> = (0..3)
        .map(|k| fixed.iter().map(|&i| mesh.nodes[i][k]).sum::<f64>() / fixed.len() as f64)
        .collect();
    let from_clamp = |i: usize| {
        (0..3)
            .map(|k| (mesh.nodes[i][k] - clamp[k]).powi(2))
            .sum::<f64>()
    };
    let far = (0..mesh.nodes.len())
        .max_by(|&a, &b| from_clamp(a).total_cmp(&from_clamp(b)))
        .unwrap();
    let (point, force, radius) = (mesh.nodes[far], [-1.0, 0.0, 0.0], 0.01);
    let f = problem
        .force_vector(&Load::contact(point, force, radius))
        .unwrap();
    let solve = SolveOptions {
        increments: 4,
        ..Default::default()
    };
    let x = problem
        .solve_forces(&m.material, &f, None, &solve)
        .unwrap()
        .solution
        .x;
    let record = palpate_protocol::model::decode(&bytes).unwrap();
    let cfg = tight_config();
    let mut storage = Storage::for_model(&record, &cfg);
    let mut rt = storage.runtime(record, cfg).unwrap();
    rt.set_contact_force(
        point.map(|v| v as f32),
        force.map(|v| v as f32),
        radius as f32,
    )
    .unwrap();
    assert!(
        palpate_tests::settle::settle(&mut rt, 400, 1e-6),
        "did not settle"
    );
    let u = rt.displacements();
    let (mut worst, mut largest) = (0.0f64, 0.0f64);
    for (n, (xn, x0)) in x.iter().zip(&mesh.nodes).enumerate() {
        let d = |k: usize| xn[k] - x0[k];
        largest = largest.max((0..3).map(|k| d(k).powi(2)).sum::<f64>().sqrt());
        let e = (0..3)
            .map(|k| (u[3 * n + k] as f64 - d(k)).powi(2))
            .sum::<f64>()
            .sqrt();
        worst = worst.max(e);
    }
    eprintln!("largest displacement {largest:e} m, runtime against the f64 model {worst:e} m");
    assert!(largest > 1e-2, "{largest:e}");
    // f32 and an iterative solve against the f64 direct one: 10⁻⁴ of the largest displacement,
    // as for the static fit's exports (`static_export_runtime`).
    assert!(
        worst < 1e-4 * largest + 1e-7,
        "{worst:e} against {largest:e}"
    );
}
