//! The `contact-radius` candidate (a probe's contact patch wider or narrower than declared):
//! its load is the model without it at ln s = 0, keeps the probe's resultant at every s, moves
//! continuously with s (its Jacobian column is a finite difference), and the diagnosis names it
//! on palpate's own specimens whose truth was loaded over a patch 1.6× the declared probe.

use crate::support::drawn;
use palpate_diagnose::model::{Candidate, Context, Model};
use palpate_fem::forward::Load;
use palpate_specimen::{Effect, SpecimenOptions};

use palpate_diagnose::{run_diagnosis, DiagnoseOptions};

#[test]
fn contact_radius_load_nests_the_lumped_one_and_keeps_the_resultant() {
    let s = drawn(&SpecimenOptions::with_effect(None, 1)).expect("specimen");
    let ctx = Context::new(&s.dataset, [3, 3, 2]).expect("context");
    let model = Model::base().with(Candidate::ContactRadius);
    let at = model.offset(Candidate::ContactRadius, ctx.grid).unwrap();
    let mut theta = vec![0.0; model.param_count(ctx.grid)];
    let force: [f64; 3] = [0.3, -0.2, -1.5];
    let norm = (force[0] * force[0] + force[1] * force[1] + force[2] * force[2]).sqrt();
    let n = ctx.problem.x0.len();
    let sum = |f: &[f64]| [0, 1, 2].map(|d| (0..n).map(|k| f[3 * k + d]).sum::<f64>());
    for i in 0..ctx.meas.len() {
        let m = &ctx.meas[i];
        let lumped = ctx
            .problem
            .force_vector(&Load::contact(m.point, force, m.radius))
            .unwrap();
        theta[at] = 0.0;
        assert_eq!(model.load_vector(&ctx, &theta, i, force).unwrap(), lumped);
        // The patch changes where the force goes, never how much: the resultant at every s.
        for ln_s in [-0.4, 0.3, 0.7] {
            theta[at] = ln_s;
            let f = model.load_vector(&ctx, &theta, i, force).unwrap();
            let r = sum(&f);
            for d in 0..3 {
                assert!((r[d] - force[d]).abs() < 1e-12 * norm, "ln s {ln_s}: {r:?}");
            }
            assert!(f != lumped, "ln s {ln_s}: no change");
        }
        // Continuous in s: a step of 1e-6 in ln s moves the nodal forces by O(1e-6) |f|.
        theta[at] = 1e-6;
        let f = model.load_vector(&ctx, &theta, i, force).unwrap();
        let moved = f
            .iter()
            .zip(&lumped)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(moved < 1e-4 * norm, "measurement {i}: moved {moved:e} N");
    }
}

/// On the mesh the diagnosis chooses (the dataset mesh with the approximation-error correction):
/// on the dataset's own 648 tets without it, the discretisation error near the probe is as large
/// as the patch's effect and `layer` ranks first (measured: seed 1, contact-radius fourth at
/// 199.2 µm against layer's 192.2). With it (final refit): seed 1 206.3 → 173.9 µm, seed 2
/// 213.6 → 181.6 µm (floor 173.2 µm; held out 207.1 → 174.2 and 214.1 → 182.1), the fitted patch
/// e^0.507 = 1.66× and e^0.475 = 1.61× the declared one for the truth's 1.6×.
#[test]
fn diagnose_names_a_wider_contact_patch() {
    for seed in [1, 2] {
        let s = drawn(&SpecimenOptions::with_effect(
            Some(Effect::ContactRadius),
            seed,
        ))
        .expect("specimen");
        let o = DiagnoseOptions {
            max_effects: 1,
            ..Default::default()
        };
        let r = run_diagnosis(&s.dataset, &o).expect("diagnosis");
        assert_eq!(
            r.adopted.first(),
            Some(&Candidate::ContactRadius),
            "seed {seed}: adopted {:?}",
            r.adopted
        );
        assert!(
            r.after.heldout_rms < 0.92 * r.before.heldout_rms,
            "seed {seed}: held-out {:e} → {:e}",
            r.before.heldout_rms,
            r.after.heldout_rms
        );
        assert!(
            r.after.fitted_rms <= 1.1 * r.noise_floor,
            "seed {seed}: residual after {:e} vs floor {:e}",
            r.after.fitted_rms,
            r.noise_floor
        );
    }
}
