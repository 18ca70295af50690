//! Leave-one-measurement-out: each measurement refitted without and predicted, and the error
//! figures of a model on fitted and held-out data.

use rayon::prelude::*;

use super::fit::{fit, Fitted};
use super::model::Context;
use super::signature::{self, signature};
use super::{DiagnoseError, Errors};
use crate::select;

pub(super) fn stats(v: &[f64]) -> (f64, f64) {
    let rms = (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    (rms, v.iter().copied().fold(0.0, f64::max))
}

pub(super) fn marker_norms(ctx: &Context, f: &Fitted) -> Vec<f64> {
    signature::residual_vectors(ctx, f)
        .iter()
        .flatten()
        .map(|(_, e)| (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt())
        .collect()
}

pub(super) fn force_errors(ctx: &Context, f: &Fitted) -> Vec<f64> {
    let sig = signature(ctx, f);
    sig.per_measurement
        .iter()
        .zip(&f.subset)
        .map(|(p, &i)| {
            let fm = f.model.model_force(ctx, &f.theta, i);
            (p.scale - 1.0).abs() * (fm[0] * fm[0] + fm[1] * fm[1] + fm[2] * fm[2]).sqrt()
        })
        .collect()
}

/// Held-out errors of a model.
#[derive(Debug, Clone)]
pub(super) struct Held {
    /// Held-out marker error norms (m), all measurements.
    pub(super) markers: Vec<f64>,
    /// Held-out implied-force errors (N), one per measurement.
    pub(super) forces: Vec<f64>,
    /// Held-out χ² (Σ|r|²/σ²) of each measurement (∞ for one in `unpredicted`).
    pub(super) chi2: Vec<f64>,
    /// Measurements the refit without them could not predict — its law has no equilibrium under
    /// their load, or under another's in the refit itself — with the reason. Their markers are
    /// not in `markers`; a candidate with any fails the gate: a model that cannot reach a
    /// measured state does not explain it.
    pub(super) unpredicted: Vec<String>,
}

/// The paired one-sided t statistic of the held-out χ² reductions d_i = χ²_i(old) − χ²_i(new)
/// over the held-out measurements: mean(d) / (sd(d)/√m). Large when the new model predicts
/// held-out measurements better consistently, not just on one.
pub(super) fn paired_t(old: &Held, new: &Held) -> f64 {
    let d: Vec<f64> = old.chi2.iter().zip(&new.chi2).map(|(a, b)| a - b).collect();
    let m = d.len() as f64;
    if m < 2.0 {
        return 0.0;
    }
    let mean = d.iter().sum::<f64>() / m;
    let var = d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (m - 1.0);
    if var <= 0.0 {
        return if mean > 0.0 { f64::INFINITY } else { 0.0 };
    }
    mean / (var / m).sqrt()
}

/// [`select::heldout_delta_bic`] over the leave-one-out residuals (k extra parameters); infinite
/// when either χ² is zero, since an exact held-out prediction says nothing about the effect.
pub(super) fn heldout_delta_bic(old: &Held, new: &Held, k: usize) -> f64 {
    let (a, b) = (old.chi2.iter().sum::<f64>(), new.chi2.iter().sum::<f64>());
    if !(a > 0.0 && b > 0.0) {
        return f64::INFINITY;
    }
    select::heldout_delta_bic(a, b, 3 * old.markers.len(), k)
}

/// Leave-one-measurement-out: refit without each measurement (warm-started from the full fit),
/// predict it.
pub(super) fn holdout(
    ctx: &Context,
    full: &Fitted,
    iterations: usize,
) -> Result<Held, DiagnoseError> {
    let all: Vec<usize> = (0..ctx.meas.len()).collect();
    // Each held-out refit is independent: one per core.
    let per: Vec<Result<(Vec<f64>, Vec<f64>), String>> = all
        .par_iter()
        .map(|&i| {
            let sub: Vec<usize> = all.iter().copied().filter(|&j| j != i).collect();
            let warm: Vec<Vec<[f64; 3]>> = sub.iter().map(|&j| full.sim.x[j].clone()).collect();
            let f = match fit(
                ctx,
                &full.model,
                full.theta.clone(),
                &sub,
                Some(&warm),
                iterations,
            ) {
                Ok(f) => f,
                Err(DiagnoseError::Diverged(why)) => {
                    return Ok(Err(format!(
                        "{:?} (the refit without it): {why}",
                        ctx.meas[i].id
                    )))
                }
                Err(e) => return Err(e),
            };
            let sim = match full.model.simulate(
                ctx,
                &f.theta,
                &[i],
                Some(std::slice::from_ref(&full.sim.x[i])),
            ) {
                Ok(sim) => sim,
                Err(DiagnoseError::Diverged(why)) => {
                    return Ok(Err(format!("{:?}: {why}", ctx.meas[i].id)))
                }
                Err(e) => return Err(e),
            };
            let held = Fitted {
                subset: vec![i],
                sim,
                theta: f.theta.clone(),
                ..f
            };
            Ok(Ok((marker_norms(ctx, &held), force_errors(ctx, &held))))
        })
        .collect::<Result<_, DiagnoseError>>()?;
    let (mut errs, mut ferrs, mut sse, mut unpredicted) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for p in per {
        match p {
            Ok((norms, forces)) => {
                sse.push(norms.iter().map(|e| e * e).sum::<f64>() / (ctx.sigma * ctx.sigma));
                errs.extend(norms);
                ferrs.extend(forces);
            }
            Err(why) => {
                sse.push(f64::INFINITY);
                unpredicted.push(why);
            }
        }
    }
    Ok(Held {
        markers: errs,
        forces: ferrs,
        chi2: sse,
        unpredicted,
    })
}

pub(super) fn errors(ctx: &Context, f: &Fitted, held: &Held) -> Errors {
    let (fitted_rms, fitted_max) = stats(&marker_norms(ctx, f));
    let (force_rms, force_max) = stats(&force_errors(ctx, f));
    let (heldout_rms, heldout_max) = stats(&held.markers);
    Errors {
        fitted_rms,
        fitted_max,
        heldout_rms,
        heldout_max,
        force_rms,
        force_max,
        heldout_force_rms: stats(&held.forces).0,
    }
}
