//! The power statement of a clean verdict (issue 14): the smallest gravity preload the dataset
//! would have detected, checked against what the selection rule's criterion actually does when
//! that preload is put into the data. The statement is linearised (Schur complement of the
//! candidate's Jacobian block against the fitted parameters, a secant Jacobian); here the
//! models are refitted for real.

use palpate_diagnose::fit::{fit, initial_theta, Fitted};
use palpate_diagnose::model::{Candidate, Context, Model};
use palpate_diagnose::power::detectable;
use palpate_specimen::{generate, SpecimenOptions};

/// The shortlist threshold T of ΔBIC < −T (the diagnosis' default).
const T: f64 = 10.0;

fn fitted(ctx: &Context, model: &Model, theta0: Vec<f64>, warm: &[Vec<[f64; 3]>]) -> Fitted {
    let all: Vec<usize> = (0..ctx.meas.len()).collect();
    fit(ctx, model, theta0, &all, Some(warm), 40).unwrap()
}

/// Measured markers replaced by `base` (per measurement, aligned with `observed`) moved by what a
/// gravity preload of ρ (kg/m³) changes in the fitted simulation.
fn with_gravity(ctx: &Context, f: &Fitted, rho: f64, base: &[Vec<[f64; 3]>]) -> Context {
    let all: Vec<usize> = (0..ctx.meas.len()).collect();
    let model = Model::base().with(Candidate::Gravity);
    let mut theta = f.theta.clone();
    theta.push(rho / 1000.0);
    let sim = model.simulate(ctx, &theta, &all, Some(&f.sim.x)).unwrap();
    let mut out = ctx.clone();
    for (i, m) in out.meas.iter_mut().enumerate() {
        for (k, (_, p)) in m.observed.iter_mut().enumerate() {
            *p = [0, 1, 2].map(|d| base[i][k][d] + sim.markers[i][k][d] - f.sim.markers[i][k][d]);
        }
    }
    out
}

/// Δχ² that adding gravity to the simplest model gains on `ctx`, and the fit without it.
fn gravity_gain(ctx: &Context, f: &Fitted) -> (f64, Fitted) {
    let f0 = fitted(ctx, &Model::base(), f.theta.clone(), &f.sim.x);
    let mut t1 = f0.theta.clone();
    t1.push(0.0);
    let f1 = fitted(ctx, &Model::base().with(Candidate::Gravity), t1, &f0.sim.x);
    (f0.chi2 - f1.chi2, f0)
}

#[test]
fn the_smallest_detectable_gravity_is_where_the_selection_rule_starts_to_shortlist_it() {
    let s = generate(&SpecimenOptions {
        seed: 5,
        ..SpecimenOptions::default()
    })
    .unwrap();
    let ctx = Context::new(&s.dataset, [3, 3, 2]).unwrap();
    let all: Vec<usize> = (0..ctx.meas.len()).collect();
    let (theta0, sim0) = initial_theta(&ctx, &all).unwrap();
    let f = fitted(&ctx, &Model::base(), theta0, &sim0.x);
    let statement = detectable(&ctx, &f, T).unwrap();
    for d in &statement {
        eprintln!("{}", d.describe());
    }
    // Every θ-candidate is stated; none of the simplest model's.
    assert_eq!(statement.len(), 9, "{statement:?}");
    let g = statement
        .iter()
        .find(|d| d.candidate == Candidate::Gravity)
        .unwrap();
    let rho_min = g.params[0].min.expect("gravity is separable from E and ν");
    assert!(rho_min > 0.0 && rho_min.is_finite());
    let n = f.n as f64;
    let s2 = f.chi2 / n;
    let threshold_chi2 = s2 * (n.ln() + T);

    // The expected gain (noise-free data: the fitted simulation plus the preload): at the stated
    // magnitude the gain is the threshold's, so the BIC of the criterion, −Δχ²/s² + ln n, is −T.
    for factor in [0.5, 1.0, 2.0] {
        let data = with_gravity(&ctx, &f, factor * rho_min, &f.sim.markers);
        let (dchi2, _) = gravity_gain(&data, &f);
        let ratio = dchi2 / (factor * factor * threshold_chi2);
        let dbic = -dchi2 / s2 + n.ln();
        eprintln!(
            "noise-free, ρ = {factor} × {rho_min:.1} kg/m³: Δχ² {dchi2:.2} = {ratio:.3} × the linearised prediction, expected ΔBIC {dbic:.1}"
        );
        // Above the stated magnitude the gain may outgrow the linearisation (measured 1.273× at
        // 2× since the gravity candidate re-embeds markers with their own offsets: part of the
        // preload's signal is quadratic in ρ), which only makes the statement conservative; at
        // and below it the linearisation must hold.
        if factor > 1.0 {
            assert!(ratio >= 0.75, "Δχ² ratio {ratio}");
        } else {
            assert!((0.75..1.25).contains(&ratio), "Δχ² ratio {ratio}");
        }
        // (At 1× it is −T to the linearisation's precision: the ratio above.)
        if factor != 1.0 {
            assert_eq!(
                dbic < -T,
                factor > 1.0,
                "ΔBIC {dbic} at {factor} × the stated magnitude"
            );
        }
    }

    // With the dataset's own noise, twice the stated magnitude is shortlisted by the rule itself
    // (the noise's projection on the candidate moves the gain by ≈ 2√Δχ² about its expectation).
    let measured: Vec<Vec<[f64; 3]>> = ctx
        .meas
        .iter()
        .map(|m| m.observed.iter().map(|(_, p)| *p).collect())
        .collect();
    let data = with_gravity(&ctx, &f, 2.0 * rho_min, &measured);
    let (dchi2, f0) = gravity_gain(&data, &f);
    let dbic = n * ((f0.chi2 - dchi2) / f0.chi2).ln() + n.ln();
    eprintln!("noisy, ρ = 2 × {rho_min:.1} kg/m³: Δχ² {dchi2:.2}, ΔBIC {dbic:.1}");
    assert!(dbic < -T, "ΔBIC {dbic} at twice the stated magnitude");
}
