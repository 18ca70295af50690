//! A motion fit exported to the runtime model: Lamé → thesis (λ, α) exactly,
//! the exported file loads in `palpate_runtime`, and a small static load on it matches the
//! fitter's own f64 warped static solve with the same (λ, α).

use palpate_fem::export::ProvenanceInfo;
use palpate_fem::forward::{Load, SolveOptions, StaticProblem};
use palpate_motion::export::{clamp_nodes, model_buffers, runtime_parameters};
use palpate_motion::model::{Material, Param, ParamKind};
use palpate_motion::optimize::{fit, FitSettings};
use palpate_motion::scenario::record;
use palpate_runtime::material::LambdaAlpha;
use palpate_tests::model::{tight_config, Storage};
use palpate_tests::motion::{bar, truth};

/// (λ_L, μ) → (λ, α) → (λ_L, μ): α = λ_L and μ = λ/2 − α. Two additions and a halving, so
/// the round trip is exact to a few ulps: 1e-12 relative over seven orders of magnitude and
/// Poisson ratios from −0.5 to 0.499.
#[test]
fn lame_to_thesis_round_trip_is_exact() {
    for &mu in &[1.0e2, 3.3e3, 2.0e4, 7.5e5, 1.0e9] {
        for &nu in &[-0.5, 0.0, 0.25, 0.45, 0.499] {
            let lame = 2.0 * mu * nu / (1.0 - 2.0 * nu);
            let la = LambdaAlpha::from_lame(lame, mu);
            let back_mu = la.shear_modulus();
            let back_lame = la.alpha;
            assert!(
                (back_mu - mu).abs() <= 1e-12 * mu,
                "mu {mu} nu {nu}: {back_mu}"
            );
            assert!(
                (back_lame - lame).abs() <= 1e-12 * lame.abs().max(mu),
                "lambda {lame}: {back_lame}"
            );
            assert!((la.poisson() - nu).abs() <= 1e-12, "poisson {nu}");
        }
    }
}

#[test]
fn motion_fit_export_loads_and_matches_the_static_solve() {
    // A short motion fit (μ from a 2× wrong start, 24-tet bar, 30 steps) — the export path is
    // what is tested, the fit only has to be a real one.
    let (mesh, model) = bar([2, 6, 2], 30);
    let truth = truth(&model);
    let obs = record(&model, &truth, 0.0, 1).unwrap();
    let params = [Param::global(ParamKind::Mu)];
    let r = fit(
        &model,
        &truth,
        &params,
        &[1.0e4],
        &obs,
        &FitSettings::default(),
        &[],
        &|_, _| {},
    )
    .unwrap();
    let mut fitted = truth.clone();
    fitted.set(&params, &r.q);
    assert!((r.q[0] / 2.0e4 - 1.0).abs() < 0.01, "fitted mu {}", r.q[0]);

    let prov = ProvenanceInfo {
        tool: "motion_export test".into(),
        source: "synthetic bar".into(),
        notes: String::new(),
    };
    let buffers = model_buffers(&mesh, &model, &fitted, &prov).unwrap();
    let bytes = buffers.encode().unwrap();
    let record = palpate_protocol::model::decode(&bytes).unwrap();
    // What is lost is stated in the model itself.
    let notes = record.provenance.notes;
    assert!(
        notes.contains("viscosity") && notes.contains("density") && notes.contains("Neo-Hookean")
    );
    // Global fit → one global (λ, α) pair equal to the conversion of the fitted Lamé values.
    let la = LambdaAlpha::from_lame(fitted.get(ParamKind::Lambda, 0), r.q[0]);
    assert_eq!(record.parameters.count, 1);
    assert_eq!(record.parameters.lambda.get(0), Some(la.lambda as f32));
    assert_eq!(record.parameters.alpha.get(0), Some(la.alpha as f32));
    let fixed = clamp_nodes(&model);
    assert_eq!(record.fixed_nodes.len(), fixed.len());

    // The runtime, loaded from the exported bytes.
    let cfg = tight_config();
    let mut storage = Storage::for_model(&record, &cfg);
    let mut rt = storage.runtime(record, cfg).unwrap();
    // A small sideways push on the free end: 5 mN over a 1 cm radius (≈ 1 mm tip deflection).
    let point = [0.01, 0.08, 0.01];
    let force = [5e-3, 0.0, 0.0];
    let radius = 0.01;
    rt.set_contact_force(
        point.map(|v| v as f32),
        force.map(|v| v as f32),
        radius as f32,
    )
    .unwrap();
    let settled = palpate_tests::settle::settle(&mut rt, 400, 1e-6);
    assert!(settled, "the runtime did not settle");
    let u = rt.displacements().to_vec();

    // The fitter's f64 static solve (warped, incremental) with the same (λ, α), clamps, surface.
    let problem = StaticProblem::new(&mesh, &fixed, &mesh.boundary_triangles()).unwrap();
    let sol = problem
        .solve(
            &runtime_parameters(&fitted),
            &Load::contact(point, force, radius),
            &SolveOptions::default(),
        )
        .unwrap();
    let mut largest = 0.0f64;
    let mut worst = 0.0f64;
    for (n, x) in sol.x.iter().enumerate() {
        let mut d2 = 0.0;
        let mut e2 = 0.0;
        for k in 0..3 {
            let uf = x[k] - mesh.nodes[n][k];
            d2 += uf * uf;
            e2 += (uf - u[3 * n + k] as f64).powi(2);
        }
        largest = largest.max(d2.sqrt());
        worst = worst.max(e2.sqrt());
    }
    eprintln!("largest displacement {largest:e} m, worst runtime vs fitter {worst:e} m");
    assert!(
        largest > 2e-4,
        "the load should move the tip visibly: {largest:e} m"
    );
    // f32 runtime with an iterative solver vs the f64 direct solve: 1e-4 of the largest
    // displacement (f32 resolves ~1e-7 of the 8 cm positions; the runtime stops at a 1e-6
    // relative step), the same bound as the static export test.
    assert!(
        worst < 1e-4 * largest + 1e-7,
        "worst {worst:e} m vs largest {largest:e} m"
    );
}

/// With the spline material of §4.2 the export keeps its rest tangent: for the Neo-Hookean
/// initialisation (eq. 19) that is exactly the Neo-Hookean (λ, μ) (1e-12 relative: the splines
/// reproduce the quadratics exactly), and the provenance names what is dropped.
#[test]
fn spline_material_exports_its_rest_tangent() {
    use palpate_motion::export::lost_in_export;
    use palpate_motion::spline::{Spline, SplineMaterial};
    let (l, m) = (3.0e4, 1.2e4);
    let mut mat = Material::uniform(4, 0.0, 0.0, 3.0, 1.0, 1000.0);
    mat.spline = Some(
        SplineMaterial::neo_hookean(
            l,
            m,
            Spline::uniform_knots(0.5, 1.7, 5),
            Spline::uniform_knots(0.7, 1.3, 5),
        )
        .unwrap(),
    );
    let p = runtime_parameters(&mat);
    let want = LambdaAlpha::from_lame(l, m);
    assert_eq!(p.lambda.len(), 1);
    assert!((p.lambda[0] - want.lambda).abs() <= 1e-12 * want.lambda);
    assert!((p.alpha[0] - want.alpha).abs() <= 1e-12 * want.alpha);
    let note = lost_in_export(&mat);
    assert!(note.contains("rest tangent") && note.contains("stress at rest"));
}
