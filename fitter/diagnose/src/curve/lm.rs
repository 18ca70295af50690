//! A small dense Levenberg–Marquardt (Marquardt's diagonal scaling) on a residual function
//! r(θ) ∈ ℝⁿ, with a forward-difference Jacobian, and the Gauss–Newton covariance
//! s² (JᵀJ)⁻¹, s² = ‖r‖²/(n − p), at the optimum.

use nalgebra::{DMatrix, DVector};
use palpate_fem::lm::{minimise, LmOptions};
use std::convert::Infallible;

/// Result of a fit.
#[derive(Debug, Clone)]
pub struct LmFit {
    /// Parameters.
    pub theta: Vec<f64>,
    /// Residual sum of squares.
    pub rss: f64,
    /// Iterations taken.
    pub iterations: usize,
    /// Covariance of θ (`None` if JᵀJ is singular or n ≤ p).
    pub cov: Option<DMatrix<f64>>,
}

/// Forward-difference Jacobian of `f` at `theta` (`r0 = f(theta)`), step 1e-6 (1 + |θ_j|): the
/// square root of machine precision relative to the parameter, which balances truncation and
/// round-off for a forward difference. Columns whose perturbed residual is undefined are zero.
pub fn fd_jacobian(
    f: &dyn Fn(&[f64]) -> Option<Vec<f64>>,
    theta: &[f64],
    r0: &[f64],
) -> DMatrix<f64> {
    let (n, p) = (r0.len(), theta.len());
    let mut j = DMatrix::zeros(n, p);
    let mut th = theta.to_vec();
    for c in 0..p {
        let h = 1e-6 * (1.0 + theta[c].abs());
        th[c] = theta[c] + h;
        if let Some(r) = f(&th) {
            for i in 0..n {
                j[(i, c)] = (r[i] - r0[i]) / h;
            }
        }
        th[c] = theta[c];
    }
    j
}

/// Minimises ‖f(θ)‖² from `theta0`; `None` if f is undefined at the start. The shared
/// [`palpate_fem::lm::minimise`] with this module's constants (12 tries, μ ×10 on a rejected
/// step, floor 1e-12, stop below a 1e-10 relative decrease); the covariance uses J at the optimum.
pub fn levenberg_marquardt(
    f: &dyn Fn(&[f64]) -> Option<Vec<f64>>,
    theta0: &[f64],
    max_iterations: usize,
) -> Option<LmFit> {
    let r0 = f(theta0)?;
    let o = LmOptions {
        max_iterations,
        tries: 12,
        initial_damping: 1e-3,
        min_damping: 1e-12,
        reject_factor: 10.0,
        rel_tolerance: 1e-10,
        cost_floor: f64::MIN_POSITIVE,
    };
    let out = match minimise(
        theta0.to_vec(),
        r0,
        (),
        |t, _, r| Ok::<_, Infallible>(fd_jacobian(f, t, r)),
        |t, _| f(t).map(|r| (r, ())),
        &o,
    ) {
        Ok(out) => out,
        Err(never) => match never {},
    };
    let (theta, r, cost) = (out.theta, out.residuals, out.cost);
    let (n, p) = (r.len(), theta.len());
    let j = fd_jacobian(f, &theta, &r);
    let cov = (n > p)
        .then(|| (j.transpose() * &j).try_inverse())
        .flatten()
        .map(|inv| inv * (cost / (n - p) as f64));
    Some(LmFit {
        theta,
        rss: cost,
        // A converged fit reports the iteration limit (as this solver always has).
        iterations: if out.converged {
            max_iterations
        } else {
            out.iterations
        },
        cov,
    })
}

/// Least-squares solution of min ‖A c − y‖ (columns of A given), `None` if rank-deficient.
pub fn linear_lsq(cols: &[Vec<f64>], y: &[f64]) -> Option<Vec<f64>> {
    let (n, p) = (y.len(), cols.len());
    let a = DMatrix::from_fn(n, p, |i, j| cols[j][i]);
    let ata = a.transpose() * &a;
    // Tiny ridge relative to the diagonal: keeps nearly collinear bases solvable.
    let mut reg = ata.clone();
    for d in 0..p {
        reg[(d, d)] += 1e-12 * ata[(d, d)].max(f64::MIN_POSITIVE);
    }
    let sol = reg
        .cholesky()?
        .solve(&(a.transpose() * DVector::from_column_slice(y)));
    sol.iter()
        .all(|v| v.is_finite())
        .then(|| sol.iter().copied().collect())
}
