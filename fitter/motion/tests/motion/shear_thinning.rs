//! A strongly shear-thinning material (h = 0.15) on a body that starts at rest: the elements'
//! rates are of round-off size until the clamp moves, where the pure power law's viscosity
//! ν γ̇^(h−1) has no bound (`palpate_motion::viscosity::RATE_FLOOR`).

use palpate_motion::gradient::evaluate_gauss_newton;
use palpate_motion::model::{Material, Param, ParamKind};
use palpate_motion::scenario::{bar_model, example_truth, nine_markers, record, two_sinusoids};
use palpate_motion::viscosity::Form;

/// Under both readings of the viscosity, a simulation with sensitivities of a bar held still
/// at its static sag for its first ten steps, then shaken, factorises every step's system
/// matrix and gives a finite Φ and gradient.
#[test]
fn a_shear_thinning_body_at_rest_simulates_with_sensitivities() {
    let size = [0.02, 0.1, 0.02];
    let dt = 1.0 / 180.0;
    let still = 10;
    let shaken = move |t: f64| two_sinusoids((t - still as f64 * dt).max(0.0));
    let (_, model) = bar_model(size, [1, 4, 1], dt, 30, &shaken, &nine_markers(size)).unwrap();
    assert!(model.static_start);
    for form in [Form::RestGradient, Form::Objective] {
        let mut truth: Material = example_truth(&model);
        truth.viscous_form = form;
        let obs = record(&model, &truth, 1e-4, 3).unwrap();
        let params = Param::globals(&[ParamKind::Mu, ParamKind::Nu, ParamKind::PowerH]);
        let mut at = truth.clone();
        at.set(&params, &[2.0e4, 30.0, 0.15]);
        let (ev, h) = evaluate_gauss_newton(&model, &at, &params, &obs)
            .unwrap_or_else(|e| panic!("{form:?}: {e}"));
        assert!(ev.phi.is_finite(), "{form:?}: Φ {}", ev.phi);
        let grad = ev.grad.expect("a gradient");
        assert!(
            grad.iter().chain(&h).all(|g| g.is_finite()),
            "{form:?}: {grad:?}"
        );
    }
}

/// Levenberg–Marquardt fitting ν and h to data of a nearly rate-independent loss (h = 0.03)
/// from h = 1 stops on the power-law index's floor
/// (`palpate_motion::optimize::POWER_INDEX_FLOOR`) with a lower Φ than at its start, and a fit
/// started below the floor keeps its start as its floor.
#[test]
fn the_power_law_index_stops_on_its_floor() {
    use palpate_motion::optimize::{fit, FitSettings, Optimizer, POWER_INDEX_FLOOR};
    let size = [0.02, 0.1, 0.02];
    let (_, model) = bar_model(
        size,
        [1, 4, 1],
        1.0 / 180.0,
        30,
        &two_sinusoids,
        &nine_markers(size),
    )
    .unwrap();
    let mut truth = example_truth(&model);
    let params = Param::globals(&[ParamKind::Nu, ParamKind::PowerH]);
    truth.set(&params, &[12.0, 0.03]);
    let obs = record(&model, &truth, 0.0, 1).unwrap();
    let settings = FitSettings {
        optimizer: Optimizer::LevenbergMarquardt,
        ..FitSettings::default()
    };
    let run = |start: &[f64]| {
        fit(
            &model,
            &truth,
            &params,
            start,
            &obs,
            &settings,
            &[],
            &|_, _| {},
        )
        .unwrap()
    };
    let from_one = run(&[12.0, 1.0]);
    // q = exp(ln h): the floor to round-off.
    assert!(
        (from_one.q[1] / POWER_INDEX_FLOOR - 1.0).abs() < 1e-12,
        "h {}",
        from_one.q[1]
    );
    assert!(from_one.history[0] > from_one.phi, "{:?}", from_one.history);
    let below = run(&[12.0, 0.05]);
    assert!(
        below.q[1] >= 0.05 && below.q[1] < POWER_INDEX_FLOOR,
        "h {}",
        below.q[1]
    );
}
