//! Levenberg–Marquardt on the Gauss–Newton matrix (`palpate_motion::optimize`): the matrix
//! H = Σ Δt w Jᵀ J that the direct sensitivities sum against JᵀJ of a finite-difference Jacobian
//! of the residual vector, and the fit it drives against the paper's LBFGS on noisy data.

use crate::support::{assert_gradients_agree, bar, truth};
use palpate_motion::gradient::{evaluate, evaluate_gauss_newton};
use palpate_motion::model::{Material, Model, Observations, Param, ParamKind};
use palpate_motion::objective::clamp_force;
use palpate_motion::optimize::{fit, FitSettings, Optimizer, LAMBDA_FLOOR_RATIO};
use palpate_motion::scenario::record;
use palpate_motion::sim::simulate_states;
use palpate_motion::viscosity::Form;

/// The weighted residual vector whose half squared norm is Φ: √(Δt w_m)(x̄_i − x_i*) for every
/// observed marker and √(Δt w_f)(F_c − F_c*) for every observed clamp force, step by step.
fn residuals(model: &Model, mat: &Material, obs: &Observations) -> Vec<f64> {
    let dt = model.observation_interval();
    let (wm, wf) = (
        (obs.marker_weight * dt).sqrt(),
        (obs.force_weight * dt).sqrt(),
    );
    let mut r = Vec::new();
    simulate_states(model, mat, |s| {
        for (i, t) in obs.markers[s.n - 1].iter().enumerate() {
            if let Some(t) = t {
                let p = model.marker_position(&model.markers[i], s.x);
                r.extend((0..3).map(|k| wm * (p[k] - t[k])));
            }
        }
        for (c, t) in obs.forces[s.n - 1].iter().enumerate() {
            if let Some(t) = t {
                let f = clamp_force(model, mat, c, s.x, s.v)?;
                r.extend((0..3).map(|k| wf * (f[k] - t[k])));
            }
        }
        Ok(())
    })
    .unwrap();
    r
}

/// The Jacobian of `residuals` by central differences, relative step `rel_step` of each
/// parameter.
fn fd_columns(
    params: &[Param],
    at: &Material,
    rel_step: f64,
    residuals: impl Fn(&Material) -> Vec<f64>,
) -> Vec<Vec<f64>> {
    let q0 = at.read(params);
    (0..params.len())
        .map(|p| {
            let step = rel_step * q0[p];
            let shifted = |d: f64| {
                let mut q = q0.clone();
                q[p] += d;
                let mut m = at.clone();
                m.set(params, &q);
                residuals(&m)
            };
            let (a, b) = (shifted(step), shifted(-step));
            a.iter()
                .zip(&b)
                .map(|(x, y)| (x - y) / (2.0 * step))
                .collect()
        })
        .collect()
}

/// Every entry of H (row-major) within 1e-5 of its largest of JᵀJ with J's columns `cols`.
fn assert_gauss_newton_is_jtj(h: &[f64], cols: &[Vec<f64>]) {
    let np = cols.len();
    let scale = h.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for p in 0..np {
        for q in 0..np {
            let fd: f64 = cols[p].iter().zip(&cols[q]).map(|(a, b)| a * b).sum();
            assert!(
                (h[p * np + q] - fd).abs() <= 1e-5 * scale,
                "H[{p}][{q}] = {} against JᵀJ {fd}",
                h[p * np + q]
            );
        }
    }
}

/// H from the direct sensitivities against JᵀJ with J by central differences (relative step
/// 1e-5 of each parameter), on markers *and* clamp forces, at a state away from the data (so the
/// viscous and elastic columns both matter): every entry within 1e-5 of the largest.
#[test]
fn gauss_newton_matrix_matches_finite_difference_jacobian() {
    gauss_newton_matches_finite_differences(
        Form::RestGradient,
        &[ParamKind::Lambda, ParamKind::Mu, ParamKind::Nu],
        &[1.3e4, 1.7e4, 9.0],
        1e-5,
    );
}

/// The same under the objective viscosity (its force depends on the positions too, so its
/// tangent enters the sensitivities' matrix), the power-law index among the parameters.
#[test]
fn gauss_newton_matrix_matches_finite_differences_under_the_objective_viscosity() {
    gauss_newton_matches_finite_differences(
        Form::Objective,
        &[
            ParamKind::Lambda,
            ParamKind::Mu,
            ParamKind::Nu,
            ParamKind::PowerH,
        ],
        &[1.3e4, 1.7e4, 9.0, 0.8],
        1e-5,
    );
}

fn gauss_newton_matches_finite_differences(
    form: Form,
    kinds: &[ParamKind],
    at_values: &[f64],
    rel_step: f64,
) {
    let (_, mut model) = bar([1, 4, 1], 30);
    // Newton solved far below its default 1e-6 N, so that the finite differences see the
    // discrete scheme's derivative and not the solver's stopping noise.
    model.newton.tol = 1e-11;
    let mut t = truth(&model);
    t.viscous_form = form;
    let obs = record(&model, &t, 1e-4, 3).unwrap();
    assert!(obs.forces.iter().flatten().any(Option::is_some));
    let params = Param::globals(kinds);
    let mut at = t.clone();
    at.set(&params, at_values);
    let (ev, h) = evaluate_gauss_newton(&model, &at, &params, &obs).unwrap();
    let np = params.len();
    let cols = fd_columns(&params, &at, rel_step, |m| residuals(&model, m, &obs));
    let r0 = residuals(&model, &at, &obs);
    let phi: f64 = 0.5 * r0.iter().map(|v| v * v).sum::<f64>();
    assert!((phi - ev.phi).abs() <= 1e-8 * phi, "Φ {phi} vs {}", ev.phi);
    assert_gauss_newton_is_jtj(&h, &cols);
    for p in 0..np {
        // And the gradient is Jᵀ r.
        let jr: f64 = cols[p].iter().zip(&r0).map(|(a, b)| a * b).sum();
        let g = ev.grad.as_ref().unwrap()[p];
        assert!(
            (g - jr).abs() <= 1e-5 * g.abs().max(jr.abs()),
            "g {g} vs Jᵀr {jr}"
        );
    }
}

/// On noisy data (a residual that does not vanish, where plain Gauss–Newton is only linear)
/// Levenberg–Marquardt and LBFGS reach the same minimum — Φ within 1e-7, parameters within
/// 1e-3 — and Levenberg–Marquardt takes fewer simulations.
#[test]
fn levenberg_marquardt_reaches_the_lbfgs_minimum_in_fewer_simulations() {
    let (_, model) = bar([1, 4, 1], 40);
    let t = truth(&model);
    let obs = record(&model, &t, 2e-4, 5).unwrap();
    let params = Param::globals(&[ParamKind::Mu, ParamKind::Nu]);
    let run = |optimizer| {
        let settings = FitSettings {
            optimizer,
            tol_cost: 1e-14,
            data_precision: false,
            ..FitSettings::default()
        };
        fit(
            &model,
            &t,
            &params,
            &[1.0e4, 24.0],
            &obs,
            &settings,
            &[],
            &|_, _| {},
        )
        .unwrap()
    };
    let lm = run(Optimizer::LevenbergMarquardt);
    let lbfgs = run(Optimizer::Lbfgs);
    assert_eq!(lm.optimizer, Optimizer::LevenbergMarquardt);
    assert!(
        lm.phi <= lbfgs.phi * (1.0 + 1e-7),
        "Φ: LM {} LBFGS {}",
        lm.phi,
        lbfgs.phi
    );
    for p in 0..2 {
        assert!(
            (lm.q[p] / lbfgs.q[p] - 1.0).abs() < 1e-3,
            "{:?}: LM {} LBFGS {}",
            params[p].kind,
            lm.q[p],
            lbfgs.q[p]
        );
    }
    assert!(
        lm.evaluations < lbfgs.evaluations,
        "simulations: LM {} LBFGS {}",
        lm.evaluations,
        lbfgs.evaluations
    );
}

/// `Auto` picks Levenberg–Marquardt for global parameters and LBFGS for per-element ones
/// (whose neighbour regulariser is not a sum of squared residuals of the simulation).
#[test]
fn auto_picks_the_optimiser_by_the_parameters() {
    let (_, model) = bar([1, 4, 1], 10);
    let t = truth(&model);
    let obs = record(&model, &t, 0.0, 1).unwrap();
    let settings = FitSettings {
        max_iters: 2,
        ..FitSettings::default()
    };
    let global = Param::globals(&[ParamKind::Mu]);
    let r = fit(
        &model,
        &t,
        &global,
        &[1.5e4],
        &obs,
        &settings,
        &[],
        &|_, _| {},
    )
    .unwrap();
    assert_eq!(r.optimizer, Optimizer::LevenbergMarquardt);
    let per: Vec<Param> = (0..model.tets.len())
        .map(|e| Param::of_element(ParamKind::Mu, e))
        .collect();
    let q0 = vec![1.5e4; per.len()];
    let pairs = [(0, 1)];
    let r = fit(&model, &t, &per, &q0, &obs, &settings, &pairs, &|_, _| {}).unwrap();
    assert_eq!(r.optimizer, Optimizer::Lbfgs);
    let lm = FitSettings {
        optimizer: Optimizer::LevenbergMarquardt,
        ..settings
    };
    let e = fit(&model, &t, &per, &q0, &obs, &lm, &pairs, &|_, _| {}).unwrap_err();
    assert!(e.to_string().contains("use LBFGS"), "{e}");
}

/// The marker residuals with each marker's mean over its observed steps removed, weighted
/// √(Δt w_m): the residual vector of a model whose markers carry free constant offsets.
fn centred_residuals(model: &Model, mat: &Material, obs: &Observations) -> Vec<f64> {
    let wm = (obs.marker_weight * model.observation_interval()).sqrt();
    let nm = model.markers.len();
    let mut rows: Vec<Vec<(usize, [f64; 3])>> = Vec::new();
    simulate_states(model, mat, |s| {
        let mut row = Vec::new();
        for (i, t) in obs.markers[s.n - 1].iter().enumerate() {
            if let Some(t) = t {
                let p = model.marker_position(&model.markers[i], s.x);
                row.push((i, [0, 1, 2].map(|k| p[k] - t[k])));
            }
        }
        rows.push(row);
        Ok(())
    })
    .unwrap();
    let (mut sum, mut count) = (vec![[0.0; 3]; nm], vec![0usize; nm]);
    for &(i, e) in rows.iter().flatten() {
        count[i] += 1;
        for k in 0..3 {
            sum[i][k] += e[k];
        }
    }
    rows.iter()
        .flatten()
        .flat_map(|&(i, e)| (0..3).map(move |k| (i, k, e[k])))
        .map(|(i, k, e)| wm * (e - sum[i][k] / count[i] as f64))
        .collect()
}

/// Free marker offsets eliminated in closed form (`Observations::free_marker_offsets`): at the
/// truth, data whose markers sit 0.2–0.7 mm off their declared places leave Φ at round-off; away
/// from it Φ, the Gauss–Newton matrix and the gradient are those of the centred residuals
/// (H against JᵀJ of their finite-difference Jacobian, 1e-5 of the largest entry; the direct and
/// adjoint gradients against finite differences of Φ); and Levenberg–Marquardt from 30 % off
/// recovers the truth in one fit — what the diagnosis' eight offsets-then-material rounds
/// approached.
#[test]
fn free_marker_offsets_are_eliminated_exactly() {
    let (_, mut model) = bar([1, 4, 1], 30);
    model.newton.tol = 1e-11;
    model.newton.max_iter = 50;
    let t = truth(&model);
    let mut obs = record(&model, &t, 0.0, 1).unwrap();
    obs.forces.clear();
    let offsets: Vec<[f64; 3]> = (0..model.markers.len())
        .map(|i| {
            let a = 2e-4 + 5e-4 * ((i * 7 % 11) as f64 / 10.0);
            [a, -0.5 * a, 0.3 * a * (i % 2) as f64]
        })
        .collect();
    for row in &mut obs.markers {
        for (p, o) in row.iter_mut().zip(&offsets) {
            if let Some(p) = p {
                for k in 0..3 {
                    p[k] += o[k];
                }
            }
        }
    }
    let params = Param::globals(&[ParamKind::Mu, ParamKind::Nu]);
    let raw = evaluate(&model, &t, &params, &obs, None).unwrap().phi;
    obs.free_marker_offsets = true;
    let at_truth = evaluate(&model, &t, &params, &obs, None).unwrap().phi;
    assert!(
        raw > 0.0 && at_truth <= 1e-12 * raw,
        "Φ at the truth {at_truth:e} (raw {raw:e})"
    );

    let mut at = t.clone();
    at.set(&params, &[1.3e4, 9.0]);
    let (ev, h) = evaluate_gauss_newton(&model, &at, &params, &obs).unwrap();
    let r0 = centred_residuals(&model, &at, &obs);
    let phi: f64 = 0.5 * r0.iter().map(|v| v * v).sum::<f64>();
    assert!((phi - ev.phi).abs() <= 1e-8 * phi, "Φ {phi} vs {}", ev.phi);
    let cols = fd_columns(&params, &at, 1e-5, |m| centred_residuals(&model, m, &obs));
    assert_gauss_newton_is_jtj(&h, &cols);
    assert_gradients_agree(&model, &at, &params, &obs, |_, q0| 1e-5 * q0);

    let settings = FitSettings {
        optimizer: Optimizer::LevenbergMarquardt,
        ..FitSettings::default()
    };
    let r = fit(
        &model,
        &t,
        &params,
        &[1.3e4, 9.0],
        &obs,
        &settings,
        &[],
        &|_, _| {},
    )
    .unwrap();
    let truth_q = t.read(&params);
    for p in 0..params.len() {
        assert!(
            (r.q[p] / truth_q[p] - 1.0).abs() < 1e-3,
            "{:?}: fitted {} truth {}",
            params[p].kind,
            r.q[p],
            truth_q[p]
        );
    }
}

/// A free λ is held at `LAMBDA_FLOOR_RATIO` μ: noise-free runs of a bar whose λ is 10⁻⁴ μ
/// (Poisson's ratio 0.00005), fitted in (λ, μ) from λ = μ, end with λ on the floor — 10⁻³ of the
/// fitted μ, to the rounding of ln(λ/μ) — not below it, and μ within 10⁻³ of the truth's: below
/// the floor the bulk modulus changes by less than 0.15 %, which moves this bar's markers by
/// less than the fit's own precision (the tolerance is the other fits' here).
#[test]
fn a_free_lambda_stops_on_its_floor() {
    let (_, model) = bar([1, 4, 1], 10);
    let mut t = truth(&model);
    let mu = t.get(ParamKind::Mu, 0);
    t.set(&Param::globals(&[ParamKind::Lambda]), &[1e-4 * mu]);
    let obs = record(&model, &t, 0.0, 1).unwrap();
    let params = Param::globals(&[ParamKind::Lambda, ParamKind::Mu]);
    let settings = FitSettings {
        optimizer: Optimizer::LevenbergMarquardt,
        max_iters: 60,
        ..FitSettings::default()
    };
    let q0 = [mu, mu];
    let r = fit(&model, &t, &params, &q0, &obs, &settings, &[], &|_, _| {}).unwrap();
    let floor = LAMBDA_FLOOR_RATIO * r.q[1];
    assert!(
        (r.q[0] / floor - 1.0).abs() < 1e-12,
        "λ {} floor {floor}",
        r.q[0]
    );
    assert!((r.q[1] / mu - 1.0).abs() < 1e-3, "μ {} truth {mu}", r.q[1]);
    assert!(r.failures.is_empty(), "{:?}", r.failures);
}

/// A floor above the truth's μ holds the fit on it (`FitSettings::floors`): started at twice the
/// truth with the floor at 1.3 times it, Levenberg–Marquardt ends with μ on the floor (to the
/// rounding of ln μ) and the viscosity refitted beside it. A floor the optimiser cannot keep (LBFGS), a floor on
/// the viscosity (whose coordinate is read at the data's strain rate) and a start below the floor
/// are refused, each naming the parameter.
#[test]
fn a_floor_above_the_minimum_holds_the_fit_on_it() {
    let (_, model) = bar([1, 4, 1], 10);
    let t = truth(&model);
    let obs = record(&model, &t, 0.0, 1).unwrap();
    let (mu, visc) = (t.get(ParamKind::Mu, 0), t.get(ParamKind::Nu, 0));
    let params = Param::globals(&[ParamKind::Mu, ParamKind::Nu]);
    let floor = 1.3 * mu;
    let settings = FitSettings {
        optimizer: Optimizer::LevenbergMarquardt,
        max_iters: 30,
        floors: vec![(ParamKind::Mu, floor)],
        ..FitSettings::default()
    };
    let q0 = [2.0 * mu, visc];
    let r = fit(&model, &t, &params, &q0, &obs, &settings, &[], &|_, _| {}).unwrap();
    assert!((r.q[0] / floor - 1.0).abs() < 1e-12, "{:?}", r.q);
    assert!(r.q[1] > 0.0 && r.failures.is_empty(), "{:?}", r.failures);
    // Unbounded, the same fit finds the truth: the floor is what held μ.
    let free = FitSettings {
        floors: Vec::new(),
        ..settings.clone()
    };
    let u = fit(&model, &t, &params, &q0, &obs, &free, &[], &|_, _| {}).unwrap();
    assert!((u.q[0] / mu - 1.0).abs() < 1e-3, "{:?}", u.q);
    let refused = |s: &FitSettings, q0: &[f64]| {
        fit(&model, &t, &params, q0, &obs, s, &[], &|_, _| {})
            .unwrap_err()
            .to_string()
    };
    let lbfgs = FitSettings {
        optimizer: Optimizer::Lbfgs,
        ..settings.clone()
    };
    assert!(refused(&lbfgs, &q0).contains("needs Levenberg–Marquardt"));
    let on_viscosity = FitSettings {
        floors: vec![(ParamKind::Nu, 1.0)],
        ..settings.clone()
    };
    assert!(refused(&on_viscosity, &q0).contains("not supported"));
    let e = refused(&settings, &[mu, visc]);
    assert!(
        e.contains("below its floor") && e.contains(ParamKind::Mu.name()),
        "{e}"
    );
}
