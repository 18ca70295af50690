//! The one dense Levenberg–Marquardt of the offline tools (Marquardt's diagonal scaling: the
//! damped normal matrix is JᵀJ + μ·diag(max(JᵀJ_dd, 1e-12))), for small problems with a dense
//! Jacobian: the diagnosis' augmented static model (`palpate-diagnose` `fit`) and its measured-curve
//! laws (`curve::lm`). The callers choose the constants ([`LmOptions`]) and how the Jacobian and
//! residuals are made; a state `S` travels with the accepted θ (a warm start for the next solve).
//!
//! Not used by the displacement-based static inverse (`palpate-static-fit` `displacement`): that
//! one damps with μI on a Hessian that may be matrix-free (adjoint products and CG on large
//! per-element layouts), so it is a different method, kept where it is.

use nalgebra::{DMatrix, DVector};

/// The constants of one use of [`minimise`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmOptions {
    /// Outer iterations (one Jacobian each).
    pub max_iterations: usize,
    /// Damped solves tried per iteration before giving up.
    pub tries: usize,
    /// μ at the start.
    pub initial_damping: f64,
    /// Lower bound of μ after an accepted step (μ ← max(μ/3, this)).
    pub min_damping: f64,
    /// μ ← μ × this after a trial that did not lower the cost (×10 after a singular system).
    pub reject_factor: f64,
    /// Stop when an accepted step lowers the cost by less than this fraction.
    pub rel_tolerance: f64,
    /// Floor of the cost in that fraction's denominator.
    pub cost_floor: f64,
}

/// Where [`minimise`] stopped.
#[derive(Debug, Clone)]
pub struct LmOutcome<S> {
    /// Parameters.
    pub theta: Vec<f64>,
    /// Residuals at θ.
    pub residuals: Vec<f64>,
    /// ‖r‖² at θ.
    pub cost: f64,
    /// The state that came with θ.
    pub state: S,
    /// Outer iterations run.
    pub iterations: usize,
    /// Whether the relative-decrease test stopped it (not the iteration limit or a failed
    /// iteration).
    pub converged: bool,
    /// JᵀJ of the last Jacobian evaluated (zeros if none was).
    pub jtj: DMatrix<f64>,
}

fn sum_of_squares(r: &[f64]) -> f64 {
    r.iter().map(|v| v * v).sum()
}

/// Minimises ‖r(θ)‖² from θ₀ (with residuals `r0` and state `state0` there). `jacobian(θ, state,
/// r)` gives J at an accepted point (its error aborts); `eval(θ)` gives a trial's residuals and
/// state, `None` where the model is undefined (the trial counts as rejected).
pub fn minimise<S, E>(
    theta0: Vec<f64>,
    r0: Vec<f64>,
    state0: S,
    mut jacobian: impl FnMut(&[f64], &S, &[f64]) -> Result<DMatrix<f64>, E>,
    mut eval: impl FnMut(&[f64], &S) -> Option<(Vec<f64>, S)>,
    o: &LmOptions,
) -> Result<LmOutcome<S>, E> {
    let p = theta0.len();
    let mut theta = theta0;
    let mut r = r0;
    let mut state = state0;
    let mut cost = sum_of_squares(&r);
    let mut mu = o.initial_damping;
    let mut jtj = DMatrix::zeros(p, p);
    let mut iterations = 0;
    let mut converged = false;
    while iterations < o.max_iterations {
        iterations += 1;
        let j = jacobian(&theta, &state, &r)?;
        jtj = j.transpose() * &j;
        let g = j.transpose() * DVector::from_column_slice(&r);
        let mut accepted = false;
        for _ in 0..o.tries {
            let mut a = jtj.clone();
            for d in 0..p {
                a[(d, d)] += mu * jtj[(d, d)].max(1e-12);
            }
            let Some(ch) = a.cholesky() else {
                mu *= 10.0;
                continue;
            };
            let step = ch.solve(&(-&g));
            let trial: Vec<f64> = theta.iter().zip(step.iter()).map(|(t, s)| t + s).collect();
            if let Some((rt, st)) = eval(&trial, &state) {
                let ct = sum_of_squares(&rt);
                if ct.is_finite() && ct < cost {
                    let rel = (cost - ct) / cost.max(o.cost_floor);
                    theta = trial;
                    r = rt;
                    state = st;
                    cost = ct;
                    mu = (mu / 3.0).max(o.min_damping);
                    accepted = true;
                    converged = rel < o.rel_tolerance;
                    break;
                }
            }
            mu *= o.reject_factor;
        }
        if !accepted || converged {
            break;
        }
    }
    Ok(LmOutcome {
        theta,
        residuals: r,
        cost,
        state,
        iterations,
        converged,
        jtj,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rosenbrock as least squares: r = (10 (y − x²), 1 − x), minimum at (1, 1).
    #[test]
    fn finds_the_rosenbrock_minimum() {
        let f = |t: &[f64]| vec![10.0 * (t[1] - t[0] * t[0]), 1.0 - t[0]];
        let jac = |t: &[f64], _: &(), _: &[f64]| {
            Ok::<_, ()>(DMatrix::from_row_slice(
                2,
                2,
                &[-20.0 * t[0], 10.0, -1.0, 0.0],
            ))
        };
        let o = LmOptions {
            max_iterations: 200,
            tries: 12,
            initial_damping: 1e-3,
            min_damping: 1e-12,
            reject_factor: 10.0,
            rel_tolerance: 1e-12,
            cost_floor: f64::MIN_POSITIVE,
        };
        let out = minimise(
            vec![-1.2, 1.0],
            f(&[-1.2, 1.0]),
            (),
            jac,
            |t, _| Some((f(t), ())),
            &o,
        )
        .unwrap();
        assert!((out.theta[0] - 1.0).abs() < 1e-6 && (out.theta[1] - 1.0).abs() < 1e-6);
    }
}
