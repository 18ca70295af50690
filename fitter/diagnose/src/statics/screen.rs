//! The static diagnosis' fit screen: every open candidate's gain predicted by one Gauss–Newton
//! step at the current fit ([`crate::screen`]), so that a round fits in full only the candidates
//! the prediction ranks first ([`crate::select::FitScreen`]).
//!
//! A candidate's fit starts from the current θ̂ with its own block at its start
//! ([`super::candidates::StaticEffect::fit_start`]: the effect absent, or where the sensitivity
//! scan puts it); the prediction is that fit's first step without its iterations. One simulation
//! of the augmented model there and its forward-difference Jacobian over every parameter (the
//! fit's own columns, [`super::fit::jacobian_columns`]) give r and J, and with Φ = ½ rᵀr,
//! g = Jᵀr, H = JᵀJ the step H δ = −g (Jacobi-scaled, [`crate::screen::step`]) predicts
//!
//!   χ²₁ ≈ rᵀr + 2 (gᵀδ + ½ δᵀHδ),
//!
//! the score statistic's χ² — the gain a fit would make if the model were linear over the step —
//! charged the candidate's parameters (θ's and the profiled) in the same BIC as its fit would be.
//! Its cost is the Jacobian of one iteration; a fit takes up to
//! [`super::DiagnoseOptions::max_iterations`] of them, and a state-dependent law (the stiffening
//! fixed point) makes each of its simulations several solves: the candidates that cost most to
//! fit are those a screen saves most on. A candidate that acts on the solved markers only makes
//! no solve of its own; it is not predicted, and always fitted.

use nalgebra::DMatrix;

use super::fit::{jacobian_columns, Fitted, FD_STEP};
use super::model::{Candidate, Context};
use super::DiagnoseError;
use crate::screen::{change, step, Normal};
use crate::select::{bic, Prediction};

/// The predicted ΔBIC of adding `c` to the current fit `cur` on the measurements `all` (every
/// one, in order), with the χ² of its start and the one step predicts; an error when the
/// augmented model cannot be simulated at its start (the candidate is then always fitted).
pub(super) fn predict(
    ctx: &Context,
    cur: &Fitted,
    c: Candidate,
    all: &[usize],
    grid: [usize; 3],
) -> Result<Prediction, DiagnoseError> {
    // A candidate that moves the solved markers only (a registration, a marker-side gain) makes
    // no solve of its own: its fit costs little more than its prediction would, and a
    // linearisation at its start can miss most of its gain (a global registration beside the
    // per-measurement one on an independent cylinder: predicted ΔBIC −144, fitted −1,231).
    if !c.affects_solve() {
        return Ok(Prediction::none(
            "acts on the solved markers only: always fitted (its fit costs about what its \
             prediction would)",
        ));
    }
    let m = cur.model.with(c);
    let mut theta = cur.theta.clone();
    theta.extend(c.effect().fit_start(ctx, grid));
    let sim = m.simulate_near(ctx, &theta, all, &cur.sim)?;
    let r = m.residuals(ctx, all, &sim.markers);
    let cols: Vec<usize> = (0..theta.len()).collect();
    let j = jacobian_columns(ctx, &m, &theta, all, &sim, &r, &cols, FD_STEP)?;
    let normal = gauss_newton(&j, &r);
    let delta = step(std::slice::from_ref(&normal), &cols);
    let start = 2.0 * normal.phi;
    let predicted =
        (start + 2.0 * change(std::slice::from_ref(&normal), &cols, &delta)[0]).clamp(0.0, start);
    let profiled =
        |effects: &[Candidate]| -> usize { effects.iter().map(|e| e.profiled(all.len())).sum() };
    let k_cur = cur.theta.len() + profiled(&cur.model.effects);
    let k_new = theta.len() + profiled(&m.effects);
    let n = ctx.residual_len(all);
    Ok(Prediction {
        delta_bic: Some(bic(predicted, n, k_new) - bic(cur.chi2, n, k_cur)),
        how: format!(
            "one Gauss–Newton step from its start (χ² {start:.1} → {predicted:.1}; the current \
             fit's {:.1})",
            cur.chi2
        ),
    })
}

/// Φ = ½ rᵀr, g = Jᵀr and H = JᵀJ of a residual and its Jacobian.
fn gauss_newton(j: &DMatrix<f64>, r: &[f64]) -> Normal {
    let rv = nalgebra::DVector::from_column_slice(r);
    let g = j.transpose() * &rv;
    let h = j.transpose() * j;
    let p = j.ncols();
    Normal {
        phi: 0.5 * rv.norm_squared(),
        grad: g.iter().copied().collect(),
        // Row-major; H is symmetric.
        gn: (0..p * p).map(|ab| h[(ab / p, ab % p)]).collect(),
    }
}
