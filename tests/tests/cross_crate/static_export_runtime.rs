//! Across the crate boundary: a static fit exported through the model format, loaded by the
//! runtime and driven with each measured contact, reproduces the fitter's own predicted marker
//! positions (what is fitted is what is simulated).

use palpate_fem::export::{ModelBuffers, ProvenanceInfo};
use palpate_static_fit::blend::BlendData;
use palpate_static_fit::synthetic::{synthesise, SyntheticSpec};
use palpate_static_fit::{fit_static, FitOptions, Layout, Method, Sets};
use palpate_tests::model::{tight_config, Storage};

#[test]
fn exported_fit_reproduces_fitted_markers_in_the_runtime() {
    let mut spec = SyntheticSpec::block([5, 5, 3]);
    spec.noise = 1e-4;
    let syn = synthesise(&spec).unwrap();
    let input = &syn.input;
    let o = FitOptions::new(Method::Displacement, Layout::Homogeneous, Sets::Single);
    let fit = fit_static(input, &o, |_, _| {}).unwrap();
    let buffers = ModelBuffers::new(
        &input.problem,
        &syn.mesh.node_tags,
        &fit.params,
        &BlendData::None,
        &ProvenanceInfo {
            tool: "test".into(),
            source: "synthetic".into(),
            notes: String::new(),
        },
    )
    .unwrap();
    let bytes = buffers.encode().unwrap();
    let record = palpate_protocol::model::decode(&bytes).unwrap();
    let cfg = tight_config();
    let mut storage = Storage::for_model(&record, &cfg);
    let mut rt = storage.runtime(record, cfg).unwrap();
    let mut worst = 0.0f64;
    let mut largest = 0.0f64;
    for (i, m) in input.measurements.iter().enumerate() {
        rt.reset();
        let c = m.contact;
        rt.set_contact_force(
            c.point.map(|v| v as f32),
            c.force.map(|v| v as f32),
            c.radius as f32,
        )
        .unwrap();
        let settled = palpate_tests::settle::settle(&mut rt, 200, 1e-5);
        assert!(settled, "measurement {i} did not settle");
        let u = rt.displacements();
        let x0 = &syn.mesh.nodes;
        for &(k, _) in &m.observed {
            let runtime_pos =
                input.markers[k].interpolate(|n| [0, 1, 2].map(|d| x0[n][d] + u[3 * n + d] as f64));
            let fitted_pos = input.markers[k].interpolate(|n| fit.deformed[i][n]);
            let rest = input.markers[k].rest;
            let disp = (0..3)
                .map(|d| (fitted_pos[d] - rest[d]).powi(2))
                .sum::<f64>()
                .sqrt();
            largest = largest.max(disp);
            let err = (0..3)
                .map(|d| (runtime_pos[d] - fitted_pos[d]).powi(2))
                .sum::<f64>()
                .sqrt();
            worst = worst.max(err);
        }
    }
    eprintln!(
        "largest marker displacement {largest:e} m, worst runtime-vs-fitter difference {worst:e} m"
    );
    // f32 runtime with an iterative solver vs the f64 direct forward model: agreement to 1e-4 of
    // the largest marker displacement (a few µm on these ~cm displacements would be 1e-4).
    assert!(largest > 1e-3);
    assert!(
        worst < 1e-4 * largest + 1e-7,
        "worst {worst:e} m vs largest displacement {largest:e} m"
    );
}

mod exported_model_decodes {
    use palpate_fem::export::{ModelBuffers, ProvenanceInfo};
    use palpate_fem::forward::{Material, StaticProblem};
    use palpate_fem::mesh::boxmesh::box_mesh;
    use palpate_protocol::model::decode;
    use palpate_runtime::element::element_cd;
    use palpate_static_fit::blend::deformation_blend;

    /// Exported models decode, and the decoded C_e/λ/α equal the f64 values rounded to f32.
    #[test]
    fn exported_model_decodes_with_the_fitted_values() {
        let mesh = box_mesh([0.1, 0.1, 0.05], [2, 2, 1]);
        let fixed = mesh.node_groups["bottom"].clone();
        let p = StaticProblem::new(&mesh, &fixed, &mesh.boundary_triangles()).unwrap();
        let sets = vec![
            Material::from_young_poisson(2e4, 0.3),
            Material::from_young_poisson(3e4, 0.25),
        ];
        let deformed = vec![
            p.x0.clone(),
            p.x0.iter().map(|x| [x[0], x[1], x[2] * 0.99]).collect(),
        ];
        let blend = deformation_blend(&sets, &deformed).unwrap();
        let prov = ProvenanceInfo {
            tool: "test".into(),
            source: "synthetic".into(),
            notes: String::new(),
        };
        let b = ModelBuffers::new(&p, &mesh.node_tags, &sets, &blend, &prov).unwrap();
        let bytes = b.encode().unwrap();
        let rec = decode(&bytes).unwrap();
        assert_eq!(rec.element_count as usize, mesh.tets.len());
        assert_eq!(rec.parameters.count, 2);
        assert_eq!(rec.parameters.lambda.get(1), Some(sets[1].lambda[0] as f32));
        let (c0, _) = element_cd(&p.geometry[0]);
        assert_eq!(rec.c_packed.get(0), Some(c0[(0, 0)] as f32));
        assert!(rec.provenance.created.ends_with('Z') && rec.provenance.created.len() == 20);
    }
}
