//! The simulation step's own error, measured on the capture it will fit.
//!
//! [`crate::timestep::choose`] asks for enough steps per period of the capture's *dominant*
//! oscillation. A body shaken at its clamp also moves in its higher modes, which that period does
//! not see: on a 20 cm cylinder shaken at 180 Hz whose first mode rings at ≈ 4 Hz (40 frames per
//! period, one substep by that rule) the second bending mode has ≈ 6 frames per period, and BDF2
//! at the capture rate puts ≈ 0.45 mm RMS into the markers — twice the capture's noise — before
//! any material is wrong (the independent generator's cylinders, simulated on the truth's own
//! mesh and material: 0.495 mm RMS at one substep, 0.238 at two, 0.215 at three, 0.210 at eight
//! against a noise floor of 0.201 mm). A fit absorbs that error into whatever is free (the
//! power-law index to its floor, λ to its floor, a stiffening), and a diagnosis names it as an
//! effect.
//!
//! The check measures the error instead of predicting it: the capture's model is simulated at
//! its step and at half that step from the data's own start estimate ([`crate::start`]: μ from
//! the rest sag, the viscosity that damps the first mode by a few per cent), and the markers'
//! RMS difference d at the capture's frames gives the error at the step by Richardson's rule
//! for a second-order scheme (all three here are): e ≈ d · 2²/(2² − 1). The error falls as the
//! step squared once the step resolves what moves, so k substeps become ⌈k √(e / tolerance)⌉,
//! and the error is measured again there (at most [`MAX_ROUNDS`] times): from a step too coarse
//! to resolve the higher modes the square law promises more than a finer step keeps. The tolerance is
//! [`TOLERANCE_OF_FLOOR`] of the declared noise floor σ√3: an error of 0.3 of the floor adds
//! 4.4 % to the RMS in quadrature, less than the 5 % held-out gain a diagnosis asks of an effect,
//! so the step cannot make an effect on its own. Without a declared noise there is no scale of
//! what the data can see: the error is measured and stated, and the step is kept.

use crate::model::{Material, Model, Observations};
use crate::refine::marker_paths;
use crate::timestep::MAX_SUBSTEPS;
use serde::Serialize;
use std::borrow::Cow;

/// The tolerance on the step's error, as a fraction of the declared noise floor σ√3.
pub const TOLERANCE_OF_FLOOR: f64 = 0.3;

/// Most substeps the check multiplies the capture's step into: time and the adjoint's tape grow
/// with the step count.
pub const MAX_CHECKED_SUBSTEPS: usize = 2 * MAX_SUBSTEPS;

/// What the check measured.
#[derive(Debug, Clone, PartialEq)]
pub struct StepError {
    /// Substeps per capture interval the check started from (the period rule's).
    pub from_substeps: usize,
    /// The markers' RMS error at that step (m), by Richardson's rule.
    pub first_error_m: f64,
    /// The tolerance (m): [`TOLERANCE_OF_FLOOR`] of the declared noise floor; `None` without a
    /// declared noise.
    pub tolerance_m: Option<f64>,
    /// Substeps per capture interval chosen.
    pub substeps: usize,
    /// The error measured at the chosen step (m), by the same rule.
    pub error_m: f64,
}

impl StepError {
    /// One clause for reports.
    pub fn describe(&self) -> String {
        let at = format!(
            "the step's own error measured at the data's start estimate: {:.1} µm RMS at {} \
             substep{}",
            1e6 * self.first_error_m,
            self.from_substeps,
            if self.from_substeps == 1 { "" } else { "s" }
        );
        let Some(tol) = self.tolerance_m else {
            return format!(
                "{at}; no marker_noise declared, so no scale of what the data can see to hold \
                 it to: the step is kept (declare `marker_noise`, or `substeps`)"
            );
        };
        let tol_words = format!("tolerance {:.1} µm (0.3 of the noise floor σ√3)", 1e6 * tol);
        if self.substeps == self.from_substeps {
            format!("{at}, within the {tol_words}")
        } else if self.error_m <= tol {
            format!(
                "{at}, above the {tol_words}: {:.1} µm at {} substeps",
                1e6 * self.error_m,
                self.substeps
            )
        } else {
            format!(
                "{at}, above the {tol_words}: still {:.1} µm at {} substeps, the most the check \
                 takes — declare `substeps` to go finer",
                1e6 * self.error_m,
                self.substeps
            )
        }
    }
}

/// The step's own error at a fitted model: what the step puts into the fit's residual, measured
/// where the fit ended rather than at the data's start estimate — a fitted viscosity damps the
/// higher modes that make most of the error at the start estimate, and a capture that declares
/// no noise has only its residual to hold the error to.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FittedStepError {
    /// Substeps per capture interval of the fit.
    pub substeps: usize,
    /// The markers' RMS error at that step (m), by Richardson's rule.
    pub error_m: f64,
    /// The fitted model's marker RMS on the run (m).
    pub residual_m: f64,
    /// Whether the error is within [`TOLERANCE_OF_FLOOR`] of the residual: then it adds at most
    /// 4.4 % to the residual in quadrature.
    pub converged: bool,
}

impl FittedStepError {
    /// The measured `error_m` at `substeps` against the run's `residual_m`.
    pub fn new(substeps: usize, error_m: f64, residual_m: f64) -> Self {
        Self {
            substeps,
            error_m,
            residual_m,
            converged: error_m <= TOLERANCE_OF_FLOOR * residual_m,
        }
    }

    /// The substeps that bring the error within the tolerance by the square law of a
    /// second-order scheme.
    pub fn substeps_for_tolerance(&self) -> usize {
        let ratio = self.error_m / (TOLERANCE_OF_FLOOR * self.residual_m);
        ((self.substeps as f64 * ratio.sqrt()).ceil() as usize).max(self.substeps + 1)
    }

    /// One clause for reports.
    pub fn describe(&self) -> String {
        let at = format!(
            "{:.1} µm RMS at the fitted model, {:.0} % of its residual {:.3} mm",
            1e6 * self.error_m,
            100.0 * self.error_m / self.residual_m,
            1e3 * self.residual_m
        );
        if self.converged {
            format!("{at}: converged in time (within 0.3 of the residual)")
        } else {
            format!(
                "{at}: not converged in time (above 0.3 of the residual, so the step is part \
                 of what the fit absorbed; about {} substeps would bring it within — declare \
                 `substeps`)",
                self.substeps_for_tolerance()
            )
        }
    }
}

/// The step's own error at a fitted material `mat` on a run's `model` (at its fitted step) and
/// `obs`, whose residual there is `residual_m`.
pub fn at_fitted(
    model: &Model,
    obs: &Observations,
    mat: &Material,
    residual_m: f64,
) -> Result<FittedStepError, String> {
    at_fitted_from(model, obs, mat, residual_m, None)
}

/// [`at_fitted`] with the run's markers at its own step already simulated (`at`: every step of
/// `model` under `mat`, as [`crate::refine::marker_paths`] gives them): the halved step alone is
/// simulated.
pub fn at_fitted_from(
    model: &Model,
    obs: &Observations,
    mat: &Material,
    residual_m: f64,
    at: Option<&[Vec<[f64; 3]>]>,
) -> Result<FittedStepError, String> {
    Ok(FittedStepError::new(
        model.substeps.max(1),
        compare_halved(model, obs, 1, mat, at)?,
        residual_m,
    ))
}

/// Rounds of refinement the check makes at most: the error falls as the step squared only once
/// the step resolves what moves, so each predicted step is measured again.
pub const MAX_ROUNDS: usize = 3;

/// Measures the step error of the capture's `model` and `obs` (at the capture rate) stepped
/// with `from` substeps, `mat` simulated, and the substeps that bring it within the tolerance
/// that `noise` (the declared σ, m) sets. `Err` says why it could not be measured.
pub fn measure(
    model: &Model,
    obs: &Observations,
    from: usize,
    noise: Option<f64>,
    mat: &Material,
) -> Result<StepError, String> {
    let from = from.max(1);
    let first_error_m = error_at(model, obs, from, mat)?;
    let tolerance_m = noise.map(|s| TOLERANCE_OF_FLOOR * s * 3f64.sqrt());
    let (mut substeps, mut error_m) = (from, first_error_m);
    if let Some(tol) = tolerance_m {
        let most = MAX_CHECKED_SUBSTEPS.max(from);
        for _ in 0..MAX_ROUNDS {
            if error_m <= tol || substeps >= most {
                break;
            }
            let next = ((substeps as f64 * (error_m / tol).sqrt()).ceil() as usize)
                .clamp(substeps + 1, most);
            error_m = error_at(model, obs, next, mat)?;
            substeps = next;
        }
    }
    Ok(StepError {
        from_substeps: from,
        first_error_m,
        tolerance_m,
        substeps,
        error_m,
    })
}

/// The markers' RMS error of `model` stepped `k` times finer (m): their RMS difference at the
/// capture's frames from `2k` times finer, times 2²/(2² − 1). `model` may already be finer than
/// the capture ([`Model::substeps`]); the frames compared are the capture's either way.
fn error_at(model: &Model, obs: &Observations, k: usize, mat: &Material) -> Result<f64, String> {
    compare_halved(model, obs, k, mat, None)
}

/// [`error_at`], the markers at `k` already simulated when `known` holds them (`k` = 1).
fn compare_halved(
    model: &Model,
    obs: &Observations,
    k: usize,
    mat: &Material,
    known: Option<&[Vec<[f64; 3]>]>,
) -> Result<f64, String> {
    let q = model.substeps.max(1);
    let (half, _) = model.resampled(obs, 2 * k);
    let known = known.filter(|rows| k == 1 && rows.len() == model.steps);
    let (at, half) = match known {
        // The run at its own step is at hand: the halved step alone is simulated.
        Some(rows) => (Ok(Cow::Borrowed(rows)), marker_paths(&half, mat)),
        None => {
            // The two simulations are independent: side by side, the check costs the finer
            // one's time.
            let (at, half) = rayon::join(
                || marker_paths(&model.resampled(obs, k).0, mat),
                || marker_paths(&half, mat),
            );
            (at.map(Cow::Owned), half)
        }
    };
    let at = at.map_err(|e| format!("at {} substeps: {e}", q * k))?;
    let half = half.map_err(|e| format!("at {} substeps: {e}", 2 * q * k))?;
    let (mut d2, mut count) = (0.0, 0usize);
    for s in 1..=model.steps / q {
        let (Some(a), Some(b)) = (at.get(s * q * k - 1), half.get(2 * s * q * k - 1)) else {
            break;
        };
        for (p, q) in a.iter().zip(b) {
            d2 += (0..3).map(|j| (p[j] - q[j]).powi(2)).sum::<f64>();
            count += 1;
        }
    }
    if count == 0 {
        return Err("no marker to compare".into());
    }
    let e = (d2 / count as f64).sqrt() * 4.0 / 3.0;
    if e.is_finite() {
        Ok(e)
    } else {
        Err(format!("the markers' difference is not a number ({e})"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Clamp, MassKind, Pose};
    use palpate_fem::mesh::boxmesh::box_mesh;

    const DT: f64 = 1.0 / 120.0;

    /// A bar clamped at one end, sagged under gravity, its clamp moved sideways fast enough
    /// that its higher modes ring; markers along its top.
    fn shaken_bar() -> (Model, Observations, Material) {
        let mesh = box_mesh([0.12, 0.02, 0.02], [6, 2, 2]);
        let clamped: Vec<usize> = (0..mesh.nodes.len())
            .filter(|&i| mesh.nodes[i][0] < 1e-9)
            .collect();
        let steps = 48;
        let clamp = Clamp {
            name: "clamp".into(),
            nodes: clamped,
            poses: (0..=steps)
                .map(|n| {
                    // A smooth (C², quintic) ramp of 4 mm over 6 frames: the bar's higher
                    // modes ring, and the path between frames is the same at any step.
                    let s = ((n as f64 - 4.0) / 6.0).clamp(0.0, 1.0);
                    let ramp = s * s * s * (10.0 - 15.0 * s + 6.0 * s * s);
                    Pose::translation([0.0, 0.004 * ramp, 0.0])
                })
                .collect(),
        };
        let mut model = Model::new(
            &mesh,
            vec![clamp],
            Vec::new(),
            DT,
            steps,
            [0.0, 0.0, -9.81],
            MassKind::Lumped,
        )
        .unwrap();
        model.static_start = true;
        model.markers = [0.04, 0.08, 0.12]
            .iter()
            .map(|&x| model.marker_at("m", [x, 0.01, 0.02]))
            .collect();
        let obs = Observations {
            markers: vec![vec![None; 3]; steps],
            forces: vec![vec![None; 1]; steps],
            marker_weight: 1.0,
            force_weight: 1.0,
            free_marker_offsets: false,
            phi_precision: 0.0,
        };
        let mat = Material::uniform(mesh.tets.len(), 4e5, 1e5, 5.0, 1.0, 1000.0);
        (model, obs, mat)
    }

    /// The RMS over markers and capture frames between the bar stepped with `k` substeps and
    /// with 32 (the reference): the step's true error.
    fn true_error(model: &Model, obs: &Observations, mat: &Material, k: usize) -> f64 {
        let (at, _) = model.resampled(obs, k);
        let (reference, _) = model.resampled(obs, 32);
        let a = marker_paths(&at, mat).unwrap();
        let r = marker_paths(&reference, mat).unwrap();
        let (mut d2, mut n) = (0.0, 0);
        for s in 1..=model.steps {
            for (p, q) in a[s * k - 1].iter().zip(&r[s * 32 - 1]) {
                d2 += (0..3).map(|j| (p[j] - q[j]).powi(2)).sum::<f64>();
                n += 1;
            }
        }
        (d2 / n as f64).sqrt()
    }

    /// Richardson's estimate from the step and its half is the error against a step 32 times
    /// finer, within a third.
    #[test]
    fn the_estimate_is_the_error_against_a_fine_step() {
        let (model, obs, mat) = shaken_bar();
        let e = measure(&model, &obs, 1, None, &mat).unwrap();
        let truth = true_error(&model, &obs, &mat, 1);
        assert!(
            (0.75..1.33).contains(&(e.first_error_m / truth)),
            "estimate {:.3e} m, error against the fine step {truth:.3e} m",
            e.first_error_m
        );
        assert!(
            truth > 1e-5,
            "the bar's step error is measurable: {truth:e} m"
        );
        // No declared noise: measured, stated, the step kept.
        assert_eq!((e.substeps, e.tolerance_m), (1, None));
        assert!(e.describe().contains("no marker_noise declared"));
    }

    /// With a declared noise the chosen step's true error is within the tolerance, one substep
    /// is not, and a noise that swamps the error keeps the step.
    #[test]
    fn the_chosen_step_is_within_tolerance() {
        let (model, obs, mat) = shaken_bar();
        let e1 = measure(&model, &obs, 1, None, &mat).unwrap().first_error_m;
        // A floor σ√3 of 0.5 e1: the tolerance is 0.15 e1.
        let e = measure(&model, &obs, 1, Some(0.5 * e1 / 3f64.sqrt()), &mat).unwrap();
        let tol = e.tolerance_m.unwrap();
        assert!(e.substeps > 1 && e.error_m <= tol, "{}", e.describe());
        let truth = true_error(&model, &obs, &mat, e.substeps);
        eprintln!("{}; against 32 substeps {truth:.3e} m", e.describe());
        assert!(
            truth <= tol,
            "{truth:e} m at {} substeps > {tol:e} m",
            e.substeps
        );
        assert!(true_error(&model, &obs, &mat, 1) > tol);
        let kept = measure(&model, &obs, 1, Some(10.0 * e1), &mat).unwrap();
        assert_eq!(kept.substeps, 1);
        assert!(kept.describe().contains("within the tolerance"));
    }

    /// At a fitted model already stepped finer than the capture, the check compares the
    /// capture's frames: the model at 2 substeps gives the error the capture-rate model gives
    /// at 2, and that error against a residual of 10× it is converged, against 2× it is not,
    /// with the square law's substeps to bring it within.
    #[test]
    fn a_fitted_model_is_measured_at_its_own_step() {
        let (model, obs, mat) = shaken_bar();
        let at_two = error_at(&model, &obs, 2, &mat).unwrap();
        let (fine, fine_obs) = model.resampled(&obs, 2);
        let fitted = at_fitted(&fine, &fine_obs, &mat, 10.0 * at_two).unwrap();
        assert_eq!(fitted.substeps, 2);
        assert!(
            (fitted.error_m / at_two - 1.0).abs() < 1e-12,
            "{} against {at_two}",
            fitted.error_m
        );
        assert!(fitted.converged && fitted.describe().contains("converged in time"));
        let coarse = at_fitted(&fine, &fine_obs, &mat, 2.0 * at_two).unwrap();
        assert!(!coarse.converged && coarse.describe().contains("not converged in time"));
        // e / (0.3 r) = 1/0.6: 2 · √1.67 = 2.58 → 3 substeps.
        assert_eq!(coarse.substeps_for_tolerance(), 3);
        // The run at its own step already simulated: the same error from the halved step
        // alone; markers of another run length are not taken for it.
        let own = crate::refine::marker_paths(&fine, &mat).unwrap();
        let known = at_fitted_from(&fine, &fine_obs, &mat, 10.0 * at_two, Some(&own)).unwrap();
        assert_eq!(known.error_m, fitted.error_m);
        let wrong = at_fitted_from(&fine, &fine_obs, &mat, 10.0 * at_two, Some(&own[1..]));
        assert_eq!(wrong.unwrap().error_m, fitted.error_m);
    }
}
