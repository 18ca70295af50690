//! Fitting a [`Model`] to a dataset (or to the training part of it): start values from the model
//! being augmented (matched by parameter name), alternatives for the new non-linear parameters,
//! the parameters the prediction is linear in solved by linear least squares at each start, a
//! short Levenberg–Marquardt screen of every start, then the best one polished.

use super::candidates::effects;
use super::lm::{levenberg_marquardt, linear_lsq};
use super::model::{Model, Param};
use super::read::Group;
use nalgebra::DMatrix;

/// A fitted model.
#[derive(Debug, Clone)]
pub struct Fit {
    /// The model.
    pub model: Model,
    /// Parameters θ.
    pub theta: Vec<f64>,
    /// Residual sum of squares over the fitted samples.
    pub rss: f64,
    /// Fitted samples.
    pub n: usize,
    /// Covariance of θ.
    pub cov: Option<DMatrix<f64>>,
}

/// Which samples are fitted: `mask[g][i]`; `None` = all.
pub type Mask = Vec<Vec<bool>>;

/// Residuals (prediction − measurement) of the masked samples, `None` outside the domain.
pub fn residuals(
    model: &Model,
    theta: &[f64],
    groups: &[Group],
    mask: Option<&Mask>,
) -> Option<Vec<f64>> {
    let mut r = Vec::new();
    for (gi, g) in groups.iter().enumerate() {
        if let Some(m) = mask {
            if !m[gi].iter().any(|&b| b) {
                continue;
            }
        }
        let p = model.predict(theta, g)?;
        for i in 0..g.y.len() {
            if mask.is_none_or(|m| m[gi][i]) {
                r.push(p[i] - g.y[i]);
            }
        }
    }
    Some(r)
}

/// Alternative start values of a newly added non-linear parameter: the candidate's that frees
/// it, else its one default start.
fn alternatives(p: &Param, model: &Model) -> Vec<f64> {
    effects()
        .find_map(|e| e.alternatives(p, model))
        .unwrap_or_else(|| vec![p.start])
}

/// Start vectors: warm values by name, the cartesian product of alternatives of the other
/// non-linear parameters (at most 9), linear parameters solved afterwards.
fn starts(model: &Model, warm: Option<(&Model, &[f64])>) -> Vec<Vec<f64>> {
    let params = model.params();
    let warm_params = warm.map(|(m, t)| (m.params(), t));
    let mut base: Vec<f64> = params.iter().map(|p| p.theta(p.start)).collect();
    let mut free: Vec<usize> = Vec::new();
    for (i, p) in params.iter().enumerate() {
        let from_warm = warm_params.as_ref().and_then(|(wp, wt)| {
            wp.iter()
                .position(|q| q.name == p.name && q.log == p.log)
                .map(|j| wt[j])
        });
        match from_warm {
            Some(t) => base[i] = t,
            None if !p.linear => free.push(i),
            None => {}
        }
    }
    let mut out = vec![base];
    for &i in &free {
        let alts = alternatives(&params[i], model);
        let mut next = Vec::new();
        for s in &out {
            for &a in &alts {
                let mut s = s.clone();
                s[i] = params[i].theta(a);
                next.push(s);
            }
        }
        next.truncate(9);
        out = next;
    }
    out
}

/// Solves the linear parameters at fixed non-linear ones (the prediction is affine in them).
fn solve_linear(model: &Model, theta: &mut [f64], groups: &[Group], mask: Option<&Mask>) {
    let params = model.params();
    let lin: Vec<usize> = (0..params.len()).filter(|&i| params[i].linear).collect();
    if lin.is_empty() {
        return;
    }
    let mut th = theta.to_vec();
    for &i in &lin {
        th[i] = 0.0;
    }
    let Some(base) = residuals(model, &th, groups, mask) else {
        return;
    };
    let mut cols = Vec::new();
    for &i in &lin {
        th[i] = 1.0;
        let Some(r) = residuals(model, &th, groups, mask) else {
            return;
        };
        cols.push(r.iter().zip(&base).map(|(a, b)| a - b).collect::<Vec<_>>());
        th[i] = 0.0;
    }
    // base = pred₀ − y, so minimising ‖Σ c_j col_j + base‖ is lsq with target −base.
    let target: Vec<f64> = base.iter().map(|v| -v).collect();
    if let Some(c) = linear_lsq(&cols, &target) {
        for (k, &i) in lin.iter().enumerate() {
            theta[i] = c[k];
        }
    }
}

/// Fits `model` to the masked samples of `groups`, warm-started from `warm` when given.
pub fn fit(
    model: &Model,
    groups: &[Group],
    mask: Option<&Mask>,
    warm: Option<(&Model, &[f64])>,
    max_iterations: usize,
) -> Option<Fit> {
    let f = |th: &[f64]| residuals(model, th, groups, mask);
    let mut best: Option<super::lm::LmFit> = None;
    let cands = starts(model, warm);
    let screen = if cands.len() > 1 { 12 } else { max_iterations };
    for mut s in cands {
        solve_linear(model, &mut s, groups, mask);
        if let Some(r) = levenberg_marquardt(&f, &s, screen) {
            if best.as_ref().is_none_or(|b| r.rss < b.rss) {
                best = Some(r);
            }
        }
    }
    let mut best = best?;
    if screen < max_iterations {
        best = levenberg_marquardt(&f, &best.theta, max_iterations)?;
    }
    let n = f(&best.theta)?.len();
    Some(Fit {
        model: model.clone(),
        theta: best.theta,
        rss: best.rss,
        n,
        cov: best.cov,
    })
}
