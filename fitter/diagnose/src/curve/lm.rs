//! A small dense Levenberg–Marquardt (Marquardt's diagonal scaling) on a residual function
//! r(θ) ∈ ℝⁿ, with a forward-difference Jacobian, and the Gauss–Newton covariance
//! s² (JᵀJ)⁻¹, s² = ‖r‖²/(n − p), at the optimum.

use nalgebra::{DMatrix, DVector};

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

fn ss(r: &[f64]) -> f64 {
    r.iter().map(|v| v * v).sum()
}

/// Minimises ‖f(θ)‖² from `theta0`; `None` if f is undefined at the start.
pub fn levenberg_marquardt(
    f: &dyn Fn(&[f64]) -> Option<Vec<f64>>,
    theta0: &[f64],
    max_iterations: usize,
) -> Option<LmFit> {
    let mut theta = theta0.to_vec();
    let mut r = f(&theta)?;
    let mut cost = ss(&r);
    let p = theta.len();
    let mut mu = 1e-3;
    let mut it = 0;
    while it < max_iterations {
        it += 1;
        let j = fd_jacobian(f, &theta, &r);
        let jtj = j.transpose() * &j;
        let g = j.transpose() * DVector::from_column_slice(&r);
        let mut improved = false;
        for _ in 0..12 {
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
            if let Some(rt) = f(&trial) {
                let ct = ss(&rt);
                if ct.is_finite() && ct < cost {
                    let rel = (cost - ct) / cost.max(f64::MIN_POSITIVE);
                    theta = trial;
                    r = rt;
                    cost = ct;
                    mu = (mu / 3.0).max(1e-12);
                    improved = true;
                    if rel < 1e-10 {
                        it = max_iterations;
                    }
                    break;
                }
            }
            mu *= 10.0;
        }
        if !improved {
            break;
        }
    }
    let n = r.len();
    let j = fd_jacobian(f, &theta, &r);
    let cov = (n > p)
        .then(|| (j.transpose() * &j).try_inverse())
        .flatten()
        .map(|inv| inv * (cost / (n - p) as f64));
    Some(LmFit {
        theta,
        rss: cost,
        iterations: it,
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
