//! The diagnosed model exported for the runtime plays back what diagnose
//! fitted. A strain-stiffening model (secant E_e = E (1 + β (‖ε_e‖/0.1)²)) is exported as the
//! thesis' per-element strain-space blend (one set per measurement state, eqs. 6.7–6.11); the
//! runtime, driven with each measurement's contact force, must settle on the diagnose model's
//! own solution — and that solution must differ from the linear one by much more than the
//! playback error, or the test would prove nothing.

use palpate_diagnose::export::runtime_material;
use palpate_diagnose::model::{s_of, Candidate, Context, Model};
use palpate_fem::export::{ModelBuffers, ProvenanceInfo};
use palpate_fem::forward::Load;
use palpate_specimen::{generate, SpecimenOptions};
use palpate_tests::model::{tight_config, Storage};

#[test]
fn stiffening_model_exports_as_strain_blend_and_replays() {
    let s = generate(&SpecimenOptions {
        seed: 3,
        ..Default::default()
    })
    .expect("specimen");
    let ds = &s.dataset;
    let ctx = Context::new(ds, [2, 2, 2]).expect("context");
    let all: Vec<usize> = (0..ctx.meas.len()).collect();
    let model = Model::base().with(Candidate::Stiffening);
    let beta = 0.5;
    let theta = vec![2e4f64.ln(), s_of(0.35), beta];
    let sim = model.simulate(&ctx, &theta, &all, None).expect("simulate");
    let linear = Model::base()
        .simulate(&ctx, &theta[..2], &all, None)
        .expect("linear");
    let (sets, blend) = runtime_material(&ctx, &model, &theta, &sim.x).expect("material");
    assert_eq!(sets.len(), all.len(), "one set per measurement state");
    let buffers = ModelBuffers::new(
        &ctx.problem,
        &ds.mesh.node_tags,
        &sets,
        &blend,
        &ProvenanceInfo {
            tool: "test".into(),
            source: "specimen seed 3".into(),
            notes: String::new(),
        },
    )
    .expect("buffers");
    let bytes = buffers.encode().expect("encode");
    let record = palpate_protocol::model::decode(&bytes).expect("decode");
    let cfg = tight_config();
    let mut storage = Storage::for_model(&record, &cfg);
    let mut rt = storage.runtime(record, cfg).expect("runtime");
    let x0 = &ctx.problem.x0;
    let (mut worst, mut nonlinearity, mut largest) = (0.0f64, 0.0f64, 0.0f64);
    for &i in &all {
        let m = &ctx.meas[i];
        let f = model.model_force(&ctx, &theta, i);
        let fitted_load = ctx
            .problem
            .force_vector(&Load::contact(m.point, f, m.radius))
            .expect("force vector");
        rt.reset();
        rt.set_contact_force(
            m.point.map(|v| v as f32),
            f.map(|v| v as f32),
            m.radius as f32,
        )
        .expect("contact");
        // The same nodal force vector both sides (the shared contact rule), node by node: the
        // runtime's commanded load against the fitter's f64 one, to f32 round-off of the force
        // (1e-6 of |f|; a node loaded on one side only would differ by a whole share of |f|).
        let f_norm = f.iter().map(|v| v * v).sum::<f64>().sqrt();
        for n in 0..x0.len() {
            let cmd = rt.commanded_force(n).expect("node in range");
            for k in 0..3 {
                let (a, b) = (cmd[k] as f64, fitted_load[3 * n + k]);
                assert!(
                    (a - b).abs() <= 1e-6 * f_norm,
                    "measurement {i}, node {n}, axis {k}: runtime commands {a:e} N, fitter {b:e} N"
                );
            }
        }
        let settled = palpate_tests::settle::settle(&mut rt, 400, 1e-5);
        assert!(settled, "measurement {i} did not settle");
        let u = rt.displacements();
        for n in 0..x0.len() {
            let d = |a: [f64; 3], b: [f64; 3]| {
                (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
            };
            let xr = [0, 1, 2].map(|k| x0[n][k] + u[3 * n + k] as f64);
            worst = worst.max(d(xr, sim.x[i][n]));
            nonlinearity = nonlinearity.max(d(linear.x[i][n], sim.x[i][n]));
            largest = largest.max(d(x0[n], sim.x[i][n]));
        }
    }
    eprintln!(
        "largest displacement {largest:e} m; stiffening changes it by up to {nonlinearity:e} m; \
         runtime vs diagnose model: {worst:e} m"
    );
    // The stiffening must matter (≥ 5 % of the displacement) for the comparison to mean anything.
    assert!(nonlinearity > 0.05 * largest, "β too small to test");
    // Both sides solve the secant fixed point (diagnose to 1e-5 in log E; the runtime on its own
    // blended material, exact at the strain centres, in f32). Measured 3.0e-9 m on 2.1 mm; the
    // bound is the runtime export test's 1e-4 of the largest displacement (f32 iterative vs f64
    // direct).
    assert!(
        worst < 1e-4 * largest,
        "runtime {worst:e} m off the diagnose model (largest {largest:e} m)"
    );
}
