//! End-to-end motion fit: LBFGS in log space recovers known parameters from noise-free
//! synthetic markers, and a failed simulation is reported, not fatal.

use palpate_motion::model::{Material, Param, ParamKind};
use palpate_motion::optimize::{fit, FitSettings};
use palpate_motion::scenario::{bar_model, nine_markers, record, two_sinusoids};

/// μ and ν from a 2× wrong start on a 24-tet bar, 40 steps: noise-free data, so the optimum is
/// the truth. The cost tolerance is tightened to 1e-14 because with the default (relative Φ
/// change 1e-10) LBFGS stopped with ν 1.4 % off: on this short, stiff motion the viscosity
/// moves the markers little, so Φ is flat along ν. 1 % on both parameters.
#[test]
fn lbfgs_recovers_mu_and_viscosity() {
    let size = [0.02, 0.08, 0.02];
    let (_, model) = bar_model(
        size,
        [1, 4, 1],
        1.0 / 180.0,
        40,
        &two_sinusoids,
        &nine_markers(size),
    )
    .unwrap();
    let ne = model.tets.len();
    let truth = Material::uniform(ne, 1.0e4, 2.0e4, 12.0, 1.0, 47.0);
    let obs = record(&model, &truth, 0.0, 1).unwrap();
    let params = [
        Param {
            kind: ParamKind::Mu,
            element: None,
        },
        Param {
            kind: ParamKind::Nu,
            element: None,
        },
    ];
    let r = fit(
        &model,
        &truth,
        &params,
        &[1.0e4, 24.0],
        &obs,
        &FitSettings {
            tol_cost: 1e-14,
            ..FitSettings::default()
        },
        &[],
        &|_, _| {},
    )
    .unwrap();
    assert!((r.q[0] / 2.0e4 - 1.0).abs() < 0.01, "mu {}", r.q[0]);
    assert!((r.q[1] / 12.0 - 1.0).abs() < 0.01, "nu {}", r.q[1]);
    assert!(r.eval.rms_marker < 1e-5, "rms {}", r.eval.rms_marker);
}

/// A start so soft that the bar collapses under gravity cannot be simulated: the fit returns a
/// clear error naming the cause instead of panicking.
#[test]
fn unsimulatable_start_is_reported() {
    let size = [0.02, 0.08, 0.02];
    let (_, model) = bar_model(
        size,
        [1, 4, 1],
        1.0 / 180.0,
        10,
        &two_sinusoids,
        &nine_markers(size),
    )
    .unwrap();
    let ne = model.tets.len();
    let truth = Material::uniform(ne, 1.0e4, 2.0e4, 12.0, 1.0, 47.0);
    let obs = record(&model, &truth, 0.0, 1).unwrap();
    let params = [
        Param {
            kind: ParamKind::Lambda,
            element: None,
        },
        Param {
            kind: ParamKind::Mu,
            element: None,
        },
    ];
    let e = fit(
        &model,
        &truth,
        &params,
        &[1e-3, 1e-3],
        &obs,
        &FitSettings::default(),
        &[],
        &|_, _| {},
    )
    .unwrap_err();
    assert!(e.to_string().contains("do not simulate"), "{e}");
}
