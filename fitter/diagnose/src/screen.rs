//! The fit screen's linearisation: a candidate's gain predicted by one Gauss–Newton step at the
//! current fit, before the candidate is fitted ([`crate::select::FitScreen`]).
//!
//! At the current fit q̂, with a candidate's new parameters p at their neutral values (where the
//! augmented model is the current one: no viscosity, no stiffening term), one simulation with
//! direct sensitivities gives the residual r and its Jacobian J = [J_q | J_p]. One Gauss–Newton
//! step over (q, p) lowers χ² = rᵀr by
//!
//! Δχ² ≈ rᵀ J_c (J_cᵀ J_c)⁻¹ J_cᵀ r,
//!
//! J_c the current columns and the candidate's: the score (Lagrange-multiplier) statistic of
//! the candidate, the gain a fit would make if the model were linear over the step. In what a
//! simulation returns — Φ = ½ rᵀWr, g = JᵀWr, H = JᵀWJ — the step δ solves H_c δ = −g_c. It is
//! a first-order prediction: a parameter whose effect is strongly nonlinear between its neutral
//! value and its fit (a damping that turns an undamped ring-down into a damped one) may gain more
//! or less than predicted, hence a margin, and a fall-back when nothing fitted passes.
//!
//! The step is solved on the Jacobi-scaled matrix with a small Levenberg damping, so that a
//! column with no effect (the power-law index at zero viscosity) or two collinear ones give the
//! minimum-norm step rather than a singular system.

/// Φ, its gradient and Gauss–Newton matrix (row-major) over a list of parameters, from one
/// simulation of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct Normal {
    /// Φ.
    pub phi: f64,
    /// dΦ/dq.
    pub grad: Vec<f64>,
    /// H = JᵀWJ, `grad.len()`² row-major.
    pub gn: Vec<f64>,
}

impl Normal {
    /// Parameters.
    pub fn len(&self) -> usize {
        self.grad.len()
    }
    /// Whether there are no parameters.
    pub fn is_empty(&self) -> bool {
        self.grad.is_empty()
    }

    /// The same over new parameters that are linear combinations of the old ones: new parameter
    /// a moves old parameter i by `t[a][i]` (a region's value set in all of its parts at once,
    /// say). The chain rule gives Tᵀ∇Φ and TᵀHT.
    pub fn combine(&self, t: &[Vec<f64>]) -> Normal {
        let n = self.len();
        let m = t.len();
        let grad = t
            .iter()
            .map(|ta| ta.iter().zip(&self.grad).map(|(a, g)| a * g).sum())
            .collect();
        // H T, column by column, then Tᵀ (H T).
        let ht: Vec<Vec<f64>> = t
            .iter()
            .map(|tb| {
                (0..n)
                    .map(|i| (0..n).map(|j| self.gn[i * n + j] * tb[j]).sum())
                    .collect()
            })
            .collect();
        let mut gn = vec![0.0; m * m];
        for a in 0..m {
            for b in 0..m {
                gn[a * m + b] = t[a].iter().zip(&ht[b]).map(|(x, y)| x * y).sum();
            }
        }
        Normal {
            phi: self.phi,
            grad,
            gn,
        }
    }

    /// The same over the parameters with `from` tied to `into` (q_from = ratio · q_into, e.g. λ
    /// to μ at a fixed Poisson's ratio): the chain rule folds `from`'s column into `into`'s, and
    /// `from` is dropped.
    pub fn tie(&self, into: usize, from: usize, ratio: f64) -> Normal {
        let n = self.len();
        // Kept parameter k moves itself, and `from` by `ratio` when it is `into`.
        let t: Vec<Vec<f64>> = (0..n)
            .filter(|&k| k != from)
            .map(|k| {
                let mut col = vec![0.0; n];
                col[k] = 1.0;
                if k == into {
                    col[from] = ratio;
                }
                col
            })
            .collect();
        self.combine(&t)
    }
}

/// Relative Levenberg damping of the scaled step: small enough not to bias a well-posed step
/// (a relative 1e-9 of each diagonal), large enough to keep a singular one finite.
const DAMPING: f64 = 1e-9;

/// The Gauss–Newton step over the parameters `cols` of the summed runs `parts` (the other
/// parameters held): H_c δ = −g_c, Jacobi-scaled, damped. Returns δ over `cols`.
pub fn step(parts: &[Normal], cols: &[usize]) -> Vec<f64> {
    let m = cols.len();
    let Some(n) = parts.first().map(Normal::len) else {
        return vec![0.0; m];
    };
    let mut g = vec![0.0; m];
    let mut h = vec![0.0; m * m];
    for p in parts {
        for (a, &i) in cols.iter().enumerate() {
            g[a] += p.grad[i];
            for (b, &j) in cols.iter().enumerate() {
                h[a * m + b] += p.gn[i * n + j];
            }
        }
    }
    // A column with no effect on the residual (zero diagonal) takes no step.
    let s: Vec<f64> = (0..m)
        .map(|a| {
            let d = h[a * m + a];
            if d > 0.0 && d.is_finite() {
                1.0 / d.sqrt()
            } else {
                0.0
            }
        })
        .collect();
    let mut a_mat = vec![0.0; m * m];
    let mut rhs = vec![0.0; m];
    for a in 0..m {
        rhs[a] = -g[a] * s[a];
        for b in 0..m {
            a_mat[a * m + b] = h[a * m + b] * s[a] * s[b];
        }
        a_mat[a * m + a] = if s[a] > 0.0 { 1.0 + DAMPING } else { 1.0 };
    }
    let y = solve_spd(&mut a_mat, &mut rhs, m);
    y.iter().zip(&s).map(|(y, s)| y * s).collect()
}

/// Whether a candidate's parameter kind has its neutral value at its lower bound (0): a
/// viscosity, a stiffening coefficient, a relaxed fraction. A screen's step that takes one below
/// it predicts a gain the candidate cannot give.
pub fn bounded_at_neutral(kind: palpate_motion::model::ParamKind) -> bool {
    use palpate_motion::model::ParamKind;
    matches!(
        kind,
        ParamKind::Nu | ParamKind::Stiffening | ParamKind::CreepFraction
    )
}

/// The prediction's `how` for a candidate whose step held every new parameter at its neutral
/// value ([`step_within_bounds`]): that candidate is the current model, and what the step of the
/// current parameters alone would gain (a refit of the current model, which its fit would make
/// and the gate refuse) is not its gain, so it is charged its parameters alone.
pub fn held_at_neutral(how: &str) -> String {
    format!("{how}: the current model, no gain predicted")
}

/// [`step`] over `cols` with a candidate's parameters bounded at their neutral values
/// ([`bounded_at_neutral`]) held there: a column that `candidate` names as such a parameter (its
/// kind) and whose step goes below 0 is dropped from `cols` and the step taken again. Returns the
/// step and the names of the parameters held.
pub fn step_within_bounds(
    parts: &[Normal],
    cols: &mut Vec<usize>,
    candidate: impl Fn(usize) -> Option<palpate_motion::model::ParamKind>,
) -> (Vec<f64>, Vec<&'static str>) {
    let delta = step(parts, cols);
    let below: Vec<(usize, &'static str)> = (0..cols.len())
        .filter_map(|a| {
            let kind = candidate(cols[a]).filter(|k| bounded_at_neutral(*k))?;
            (delta[a] < 0.0).then(|| (a, kind.name()))
        })
        .collect();
    if below.is_empty() {
        return (delta, Vec::new());
    }
    for &(a, _) in below.iter().rev() {
        cols.remove(a);
    }
    (
        step(parts, cols),
        below.into_iter().map(|(_, n)| n).collect(),
    )
}

/// The change of each run's Φ along the step `delta` over `cols` on its Gauss–Newton model:
/// g_r·δ + ½ δᵀ H_r δ (negative: the run fits better).
pub fn change(parts: &[Normal], cols: &[usize], delta: &[f64]) -> Vec<f64> {
    parts
        .iter()
        .map(|p| {
            let n = p.len();
            let mut lin = 0.0;
            let mut quad = 0.0;
            for (a, &i) in cols.iter().enumerate() {
                lin += p.grad[i] * delta[a];
                for (b, &j) in cols.iter().enumerate() {
                    quad += delta[a] * p.gn[i * n + j] * delta[b];
                }
            }
            lin + 0.5 * quad
        })
        .collect()
}

/// Solves the symmetric positive (semi-)definite `a` x = `b` (m × m, row-major) by Cholesky; a
/// pivot that vanishes (a column dependent on earlier ones) leaves its unknown at 0.
fn solve_spd(a: &mut [f64], b: &mut [f64], m: usize) -> Vec<f64> {
    let mut l = vec![0.0; m * m];
    let mut alive = vec![true; m];
    for j in 0..m {
        let d = a[j * m + j] - (0..j).map(|k| l[j * m + k] * l[j * m + k]).sum::<f64>();
        if d <= 1e-14 * a[j * m + j].abs().max(1.0) || !d.is_finite() {
            alive[j] = false;
            continue;
        }
        let ljj = d.sqrt();
        l[j * m + j] = ljj;
        for i in j + 1..m {
            let v = a[i * m + j] - (0..j).map(|k| l[i * m + k] * l[j * m + k]).sum::<f64>();
            l[i * m + j] = v / ljj;
        }
    }
    let mut y = vec![0.0; m];
    for i in 0..m {
        if alive[i] {
            y[i] = (b[i] - (0..i).map(|k| l[i * m + k] * y[k]).sum::<f64>()) / l[i * m + i];
        }
    }
    let mut x = vec![0.0; m];
    for i in (0..m).rev() {
        if alive[i] {
            x[i] = (y[i] - (i + 1..m).map(|k| l[k * m + i] * x[k]).sum::<f64>()) / l[i * m + i];
        }
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A linear least-squares problem r(q) = J q − y with unit weights at q = 0: Φ = ½‖y‖²,
    /// g = −Jᵀy, H = JᵀJ.
    fn linear(j: &[[f64; 3]], y: &[f64]) -> Normal {
        let n = 3;
        let mut grad = vec![0.0; n];
        let mut gn = vec![0.0; n * n];
        for (row, yi) in j.iter().zip(y) {
            for a in 0..n {
                grad[a] -= row[a] * yi;
                for b in 0..n {
                    gn[a * n + b] += row[a] * row[b];
                }
            }
        }
        Normal {
            phi: 0.5 * y.iter().map(|v| v * v).sum::<f64>(),
            grad,
            gn,
        }
    }

    /// A candidate column bounded at 0 whose step goes below 0 is held there: the step over the
    /// rest is the fit of the rest alone (its Φ the projection onto them), the held name is
    /// reported, and a column whose step is positive is kept.
    #[test]
    fn a_step_below_a_bound_is_taken_again_without_that_column() {
        use palpate_motion::model::ParamKind;
        // y wants column 2 negative: y = j·(1, 0.5, −2) exactly.
        let j = [
            [1.0, 0.0, 0.3],
            [0.0, 1.0, 0.2],
            [0.5, 0.5, 1.0],
            [0.2, 0.1, 0.7],
        ];
        let y: Vec<f64> = j.iter().map(|r| r[0] + 0.5 * r[1] - 2.0 * r[2]).collect();
        let n = linear(&j, &y);
        let parts = std::slice::from_ref(&n);
        let stiff = |c: usize| (c == 2).then_some(ParamKind::Stiffening);
        let mut cols = vec![0, 1, 2];
        let (delta, held) = step_within_bounds(parts, &mut cols, stiff);
        assert_eq!(held, ["stiffening"]);
        assert_eq!(cols, [0, 1]);
        let after = n.phi + change(parts, &cols, &delta)[0];
        let fit = projected_phi(&j, &y, &[0, 1]);
        assert!((after - fit).abs() < 1e-3 * n.phi, "{after} vs {fit}");
        // The same data wanting column 2 positive keep it.
        let y: Vec<f64> = j.iter().map(|r| r[0] + 0.5 * r[1] + 2.0 * r[2]).collect();
        let n = linear(&j, &y);
        let mut cols = vec![0, 1, 2];
        let (delta, held) = step_within_bounds(std::slice::from_ref(&n), &mut cols, stiff);
        assert!(
            held.is_empty() && cols == [0, 1, 2] && delta[2] > 0.0,
            "{delta:?}"
        );
    }

    /// ½‖y − P y‖² by Gram–Schmidt over the columns `cols` of `j`: the least-squares residual
    /// reached by a fit, computed without normal equations.
    fn projected_phi(j: &[[f64; 3]], y: &[f64], cols: &[usize]) -> f64 {
        let mut basis: Vec<Vec<f64>> = Vec::new();
        for &c in cols {
            let mut v: Vec<f64> = j.iter().map(|r| r[c]).collect();
            for e in &basis {
                let d: f64 = v.iter().zip(e).map(|(a, b)| a * b).sum();
                v.iter_mut().zip(e).for_each(|(a, b)| *a -= d * b);
            }
            let norm = v.iter().map(|a| a * a).sum::<f64>().sqrt();
            if norm > 1e-9 {
                basis.push(v.iter().map(|a| a / norm).collect());
            }
        }
        let mut r = y.to_vec();
        for e in &basis {
            let d: f64 = r.iter().zip(e).map(|(a, b)| a * b).sum();
            r.iter_mut().zip(e).for_each(|(a, b)| *a -= d * b);
        }
        0.5 * r.iter().map(|a| a * a).sum::<f64>()
    }

    const J: [[f64; 3]; 6] = [
        [1.0, 0.2, 0.0],
        [0.5, -1.0, 3.0],
        [0.1, 0.4, -2.0],
        [2.0, 0.0, 1.0],
        [-1.0, 1.5, 0.5],
        [0.3, 0.3, 0.3],
    ];
    const Y: [f64; 6] = [1.0, -2.0, 0.5, 3.0, 0.0, 1.5];

    /// On a linear model the predicted change is the fit's: for every subset of columns, Φ
    /// after the step equals the least-squares residual, and the runs' changes add up.
    #[test]
    fn a_linear_model_gains_what_its_fit_gains() {
        let whole = linear(&J, &Y);
        let (first, second) = (linear(&J[..3], &Y[..3]), linear(&J[3..], &Y[3..]));
        for cols in [vec![0], vec![1, 2], vec![0, 1, 2], vec![2, 0]] {
            let d = step(&[first.clone(), second.clone()], &cols);
            let per_run = change(&[first.clone(), second.clone()], &cols, &d);
            let fitted = projected_phi(&J, &Y, &cols);
            let predicted = whole.phi + per_run.iter().sum::<f64>();
            assert!(
                (predicted - fitted).abs() < 1e-9 * whole.phi,
                "{cols:?}: {predicted} vs {fitted}"
            );
            assert!(per_run.iter().all(|c| c.is_finite()));
        }
    }

    /// A column with no effect and a column repeated change nothing: the step is the one of the
    /// columns that matter.
    #[test]
    fn dead_and_repeated_columns_add_no_gain() {
        let j: Vec<[f64; 3]> = J.iter().map(|r| [r[0], r[0], 0.0]).collect();
        let p = linear(&j, &Y);
        let one = std::slice::from_ref(&p);
        let alone = change(one, &[0], &step(one, &[0]))[0];
        let all = change(one, &[0, 1, 2], &step(one, &[0, 1, 2]))[0];
        assert!(alone < 0.0);
        assert!((all - alone).abs() < 1e-6 * alone.abs(), "{all} vs {alone}");
    }

    /// Tying λ = 2 μ folds λ's column into μ's: the tied step equals the fit of the summed
    /// column.
    #[test]
    fn a_tie_folds_the_column() {
        let p = linear(&J, &Y);
        let tied = p.tie(0, 2, 2.0);
        let j: Vec<[f64; 3]> = J.iter().map(|r| [r[0] + 2.0 * r[2], r[1], 0.0]).collect();
        let direct = linear(&j, &Y);
        assert_eq!(tied.len(), 2);
        for a in 0..2 {
            assert!((tied.grad[a] - direct.grad[a]).abs() < 1e-12);
            for b in 0..2 {
                assert!((tied.gn[a * 2 + b] - direct.gn[a * 3 + b]).abs() < 1e-12);
            }
        }
    }

    /// Folding columns into combinations (two bands' parameters moved together, one of them
    /// with a third column) gives the normal equations of the combined Jacobian's columns.
    #[test]
    fn combined_columns_are_the_combined_jacobians() {
        let p = linear(&J, &Y);
        let t = vec![vec![1.0, 1.0, 0.0], vec![0.0, 0.5, -2.0]];
        let combined = p.combine(&t);
        let j: Vec<[f64; 3]> = J
            .iter()
            .map(|r| [r[0] + r[1], 0.5 * r[1] - 2.0 * r[2], 0.0])
            .collect();
        let direct = linear(&j, &Y);
        assert_eq!(combined.len(), 2);
        assert_eq!(combined.phi, p.phi);
        for a in 0..2 {
            assert!((combined.grad[a] - direct.grad[a]).abs() < 1e-12);
            for b in 0..2 {
                assert!((combined.gn[a * 2 + b] - direct.gn[a * 3 + b]).abs() < 1e-12);
            }
        }
    }
}
