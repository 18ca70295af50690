//! Across the crate boundary: a static fit exported through the model format, loaded by the
//! runtime and driven with each measured contact, reproduces the fitter's own predicted marker
//! positions (what is fitted is what is simulated).

use palpate_fem::export::{ModelBuffers, ProvenanceInfo};
use palpate_fem::forward::{Material, StaticProblem};
use palpate_runtime::Runtime;
use palpate_static_fit::blend::BlendData;
use palpate_static_fit::synthetic::{synthesise, SyntheticSpec};
use palpate_static_fit::{fit_static, FitInput, FitOptions, Layout, Method, Sets};
use palpate_tests::model::{tight_config, Storage};

/// The model file's bytes of `params` and `blend` on `problem`, through the fitter's export.
fn export(
    problem: &StaticProblem,
    node_tags: &[u64],
    params: &[Material],
    blend: &BlendData,
    source: &str,
) -> Vec<u8> {
    let prov = ProvenanceInfo {
        tool: "test".into(),
        source: source.into(),
        notes: String::new(),
    };
    let buffers = ModelBuffers::new(problem, node_tags, params, blend, &prov).unwrap();
    buffers.encode().unwrap()
}

/// Plays each measurement's contact from rest in `rt` (rest positions `x0`) and compares the
/// runtime's marker positions with the fitter's `deformed` states: returns the worst difference
/// and the largest fitted marker displacement (m). A contact that does not settle within
/// `settle` = (ticks, relative step) fails the test, named "`what` i".
fn replay(
    rt: &mut Runtime<'_>,
    input: &FitInput,
    x0: &[[f64; 3]],
    deformed: &[Vec<[f64; 3]>],
    settle: (usize, f32),
    what: &str,
) -> (f64, f64) {
    let dist = |a: [f64; 3], b: [f64; 3]| (0..3).map(|d| (a[d] - b[d]).powi(2)).sum::<f64>().sqrt();
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
        assert!(
            palpate_tests::settle::settle(rt, settle.0, settle.1),
            "{what} {i} did not settle"
        );
        let u = rt.displacements();
        for &(k, _) in &m.observed {
            let mk = &input.markers[k];
            let rt_pos = mk.interpolate(|n| [0, 1, 2].map(|d| x0[n][d] + u[3 * n + d] as f64));
            let fitted = mk.interpolate(|n| deformed[i][n]);
            largest = largest.max(dist(fitted, mk.rest));
            worst = worst.max(dist(rt_pos, fitted));
        }
    }
    (worst, largest)
}

#[test]
fn exported_fit_reproduces_fitted_markers_in_the_runtime() {
    let mut spec = SyntheticSpec::block([5, 5, 3]);
    spec.noise = 1e-4;
    let syn = synthesise(&spec).unwrap();
    let input = &syn.input;
    let o = FitOptions::new(Method::Displacement, Layout::Homogeneous, Sets::Single);
    let fit = fit_static(input, &o, |_, _| {}).unwrap();
    let bytes = export(
        &input.problem,
        &syn.mesh.node_tags,
        &fit.params,
        &BlendData::None,
        "synthetic",
    );
    let record = palpate_protocol::model::decode(&bytes).unwrap();
    let cfg = tight_config();
    let mut storage = Storage::for_model(&record, &cfg);
    let mut rt = storage.runtime(record, cfg).unwrap();
    let (worst, largest) = replay(
        &mut rt,
        input,
        &syn.mesh.nodes,
        &fit.deformed,
        (200, 1e-5),
        "measurement",
    );
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

/// Across the crate boundary, the non-linear homogeneous class on non-linear data: palpate's
/// specimen with isochoric stiffening (magnitude 60, six contacts 0.75–3 N), one set per contact
/// fitted by the displacement-based inverse, exported with the fitter's own deformation-space RBF
/// weights (`blend::for_fit`, not weights made here) and decoded:
/// 1. at each fitted deformation the runtime's blend gives that contact's set (1e-3: f32 centres);
/// 2. played from rest with each fitted contact, the runtime settles on the fitted deformation
///    (the blend's fixed point), to 1e-3 of the largest marker displacement;
/// 3. a contact at three times the largest fitted force lies outside the fitted range: the RBF
///    evaluated with the exported weights at the runtime's state leaves the fitted [min, max] of λ,
///    and the runtime's λ is that value clamped to the range (`runtime/src/blend.rs`).
#[test]
fn exported_blend_weights_reproduce_fitted_deformations_and_clamp_outside() {
    use palpate_specimen::{generate, Effect, EffectSpec, SpecimenOptions};
    use palpate_static_fit::blend::for_fit;
    use palpate_static_fit::Gammas;

    let mut so = SpecimenOptions::with_effect(None, 5);
    so.measurements = 6;
    so.max_force = 3.0;
    so.effects = vec![EffectSpec {
        effect: Effect::Stiffening,
        magnitude: 60.0,
    }];
    let spec = generate(&so).unwrap();
    let input = FitInput::from_dataset(&spec.dataset).unwrap();
    let mut o = FitOptions::new(
        Method::Displacement,
        Layout::Homogeneous,
        Sets::PerMeasurement,
    );
    o.gammas = Some(Gammas::new(0.0, 0.01));
    let fit = fit_static(&input, &o, |_, _| {}).unwrap();
    let blend = for_fit(
        &input.problem,
        Layout::Homogeneous,
        &fit.params,
        &fit.deformed,
    )
    .unwrap();
    let BlendData::Deformation {
        centres,
        weights_lambda,
        ..
    } = &blend
    else {
        panic!("a homogeneous per-measurement fit exports a deformation blend")
    };
    let bytes = export(
        &input.problem,
        &spec.dataset.mesh.node_tags,
        &fit.params,
        &blend,
        "specimen",
    );
    let record = palpate_protocol::model::decode(&bytes).unwrap();
    let cfg = tight_config();
    let mut storage = Storage::for_model(&record, &cfg);
    let mut rt = storage.runtime(record, cfg).unwrap();
    let x0 = &input.problem.x0;
    let lambdas: Vec<f64> = fit.params.iter().map(|m| m.lambda[0]).collect();
    let (lo, hi) = lambdas
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |a, &v| {
            (a.0.min(v), a.1.max(v))
        });
    eprintln!("fitted λ per contact {lambdas:?}");
    assert!(
        hi > 1.2 * lo,
        "the stiffening should show in the sets: {lambdas:?}"
    );
    // 1. The blend at each fitted deformation.
    for (i, x) in fit.deformed.iter().enumerate() {
        let u: Vec<f32> = x
            .iter()
            .zip(x0)
            .flat_map(|(p, q)| [0, 1, 2].map(|d| (p[d] - q[d]) as f32))
            .collect();
        rt.set_displacements(&u).unwrap();
        let (l, _) = rt.element_parameters(0).unwrap();
        assert!(
            (l as f64 - lambdas[i]).abs() < 1e-3 * lambdas[i],
            "contact {i}: blended λ {l} vs set {}",
            lambdas[i]
        );
    }
    // 2. Each fitted contact played from rest.
    let (worst, largest) = replay(&mut rt, &input, x0, &fit.deformed, (400, 1e-6), "contact");
    eprintln!("blended replay: worst marker difference {worst:e} m, largest marker displacement {largest:e} m");
    assert!(
        worst < 1e-3 * largest,
        "worst {worst:e} vs largest {largest:e}"
    );
    // 3. Beyond the fitted range.
    let strongest = input
        .measurements
        .iter()
        .max_by(|a, b| {
            a.contact.force[2]
                .abs()
                .total_cmp(&b.contact.force[2].abs())
        })
        .unwrap();
    let c = strongest.contact;
    rt.reset();
    rt.set_contact_force(
        c.point.map(|v| v as f32),
        c.force.map(|v| 3.0 * v as f32),
        c.radius as f32,
    )
    .unwrap();
    assert!(
        palpate_tests::settle::settle(&mut rt, 600, 1e-6),
        "3x contact did not settle"
    );
    let u = rt.displacements();
    let n3 = 3 * x0.len();
    let raw: f64 = weights_lambda
        .iter()
        .enumerate()
        .map(|(s, w)| {
            let r = (0..n3)
                .map(|k| (x0[k / 3][k % 3] + u[k] as f64 - centres[s * n3 + k]).powi(2))
                .sum::<f64>()
                .sqrt();
            w * r
        })
        .sum();
    let (l, a) = rt.element_parameters(0).unwrap();
    eprintln!("3x contact: RBF λ {raw:.1} with the exported weights, fitted range [{lo:.1}, {hi:.1}], runtime λ {l}, α {a}");
    assert!(
        raw < lo || raw > hi,
        "the 3x contact should leave the fitted range: {raw}"
    );
    let clamped = raw.clamp(lo, hi);
    assert!(
        (l as f64 - clamped).abs() < 1e-4 * clamped,
        "runtime λ {l} vs clamped {clamped}"
    );
    assert!(rt.displacements().iter().all(|v| v.is_finite()));
}
