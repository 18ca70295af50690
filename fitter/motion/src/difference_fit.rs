//! Levenberg–Marquardt on a few global material parameters of any forward model, its Jacobian
//! by forward differences: the fit that a model without sensitivities of its own can make — the
//! motion on quadratic tetrahedra ([`crate::quadratic_motion`]) — and, through the same code,
//! the linear model, so that the two discretisations are fitted to the same objective by the
//! same method and their parameters can be set side by side.
//!
//! The objective is the marker term of eq. 15 without its weights (they do not move the
//! minimum): r = x_sim − x_obs over every observed marker and step of every run, each marker's
//! mean removed when the observations free its offset. A parameter is fitted in ln q (moduli,
//! viscosity) or in q (the power-law index); with a fixed Poisson's ratio λ follows μ. A
//! difference quotient costs one simulation per parameter; the runs and the columns are
//! simulated side by side.

use super::model::{Material, Observations, ParamKind};
use super::MotionError;
use nalgebra::DMatrix;
use palpate_fem::lm::{minimise, LmOptions};
use rayon::prelude::*;
use std::sync::atomic::{AtomicUsize, Ordering};

/// The simulated markers of one run at steps 1..=steps, for a material.
pub type Forward<'a> = dyn Fn(&Material) -> Result<Vec<Vec<[f64; 3]>>, MotionError> + Sync + 'a;

/// A run to fit: its observations and its forward model.
pub struct DifferenceRun<'a> {
    /// The observed markers.
    pub obs: &'a Observations,
    /// The forward model.
    pub forward: &'a Forward<'a>,
}

/// One global parameter: fitted in ln q when `log`, else in q.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GlobalParam {
    /// The material kind set in every element.
    pub kind: ParamKind,
    /// Fitted in ln q (positive quantities).
    pub log: bool,
}

/// The step of the forward differences in the fitted coordinates: 10⁻³ of ln q is a 0.1 %
/// change, which moves the markers ~10³ times more than a Newton tolerance of 10⁻⁶ N does.
const DIFFERENCE_STEP: f64 = 1e-3;

/// Where the fit ended.
#[derive(Debug, Clone)]
pub struct DifferenceFit {
    /// The fitted values, in the order of the parameters.
    pub values: Vec<f64>,
    /// One standard deviation of each value from the Gauss–Newton matrix and the residual's
    /// variance (independent errors assumed).
    pub std: Vec<f64>,
    /// RMS over every observed marker and step of the marker's distance from its observation
    /// (m): √(2Φ/(NT)), the motion fit's own figure.
    pub rms: f64,
    /// Per run: the same over its own markers and steps (m).
    pub run_rms: Vec<f64>,
    /// Simulations of one run spent.
    pub simulations: usize,
    /// Levenberg–Marquardt iterations.
    pub iterations: usize,
    /// Whether the relative-decrease test stopped it.
    pub converged: bool,
}

/// The residual of one run's simulated markers against its observations (3 per observed
/// marker and step), each marker's mean removed when its offset is free.
pub fn marker_residual(obs: &Observations, sim: &[Vec<[f64; 3]>]) -> Vec<f64> {
    let markers = obs.markers.first().map_or(0, Vec::len);
    let mut per_marker: Vec<Vec<[f64; 3]>> = vec![Vec::new(); markers];
    for (n, row) in obs.markers.iter().enumerate() {
        let Some(simulated) = sim.get(n) else {
            break;
        };
        for (i, o) in row.iter().enumerate() {
            if let (Some(o), Some(s)) = (o, simulated.get(i)) {
                per_marker[i].push(std::array::from_fn(|d| s[d] - o[d]));
            }
        }
    }
    let mut r = Vec::new();
    for rows in &per_marker {
        let mean: [f64; 3] = if obs.free_marker_offsets && !rows.is_empty() {
            std::array::from_fn(|d| rows.iter().map(|x| x[d]).sum::<f64>() / rows.len() as f64)
        } else {
            [0.0; 3]
        };
        for x in rows {
            r.extend((0..3).map(|d| x[d] - mean[d]));
        }
    }
    r
}

/// √(Σ r² / (len/3)): the RMS distance of the markers from their observations, from a
/// residual of three components per marker and step.
pub fn marker_rms(r: &[f64]) -> f64 {
    (3.0 * r.iter().map(|x| x * x).sum::<f64>() / r.len().max(1) as f64).sqrt()
}

/// Fits `params` (starting at `start`, values not coordinates) on `runs` from the material
/// `base`; with `poisson`, λ = 2μν/(1 − 2ν) follows μ. `progress(iteration, rms)` is called
/// after every accepted step.
pub fn fit_by_differences(
    runs: &[DifferenceRun<'_>],
    base: &Material,
    params: &[GlobalParam],
    start: &[f64],
    poisson: Option<f64>,
    max_iterations: usize,
    progress: &dyn Fn(usize, f64),
) -> Result<DifferenceFit, MotionError> {
    if params.len() != start.len() || params.is_empty() {
        return Err(MotionError::Invalid(format!(
            "{} starting values for {} parameters",
            start.len(),
            params.len()
        )));
    }
    for (p, &v) in params.iter().zip(start) {
        if !v.is_finite() || (p.log && v <= 0.0) {
            return Err(MotionError::Invalid(format!(
                "the start of {} must be finite{}, found {v}",
                p.kind.name(),
                if p.log { " and positive" } else { "" }
            )));
        }
    }
    if let Some(nu) = poisson {
        if !(nu.is_finite() && nu > -1.0 && nu < 0.5) {
            return Err(MotionError::Invalid(format!(
                "Poisson's ratio must lie in (−1, 0.5), found {nu}"
            )));
        }
        if !params.iter().any(|p| p.kind == ParamKind::Mu) {
            return Err(MotionError::Invalid(
                "a fixed Poisson's ratio needs μ among the parameters".into(),
            ));
        }
    }
    let value = |p: &GlobalParam, t: f64| if p.log { t.exp() } else { t };
    let material = |theta: &[f64]| {
        let mut m = base.clone();
        for (p, &t) in params.iter().zip(theta) {
            m.set_uniform(p.kind, value(p, t));
        }
        if let Some(nu) = poisson {
            let mu = m.get(ParamKind::Mu, 0);
            m.set_uniform(ParamKind::Lambda, mu * 2.0 * nu / (1.0 - 2.0 * nu));
        }
        m
    };
    let simulations = AtomicUsize::new(0);
    // Every run's residual at θ, the runs side by side.
    let residual = |theta: &[f64]| -> Result<(Vec<f64>, Vec<usize>), MotionError> {
        let m = material(theta);
        let parts: Vec<Result<Vec<f64>, MotionError>> = runs
            .par_iter()
            .map(|run| {
                simulations.fetch_add(1, Ordering::Relaxed);
                Ok(marker_residual(run.obs, &(run.forward)(&m)?))
            })
            .collect();
        let mut r = Vec::new();
        let mut lengths = Vec::new();
        for p in parts {
            let p = p?;
            lengths.push(p.len());
            r.extend(p);
        }
        Ok((r, lengths))
    };
    let theta0: Vec<f64> = params
        .iter()
        .zip(start)
        .map(|(p, &v)| if p.log { v.ln() } else { v })
        .collect();
    let (r0, lengths) = residual(&theta0)?;
    if r0.is_empty() {
        return Err(MotionError::Invalid(
            "no observed marker to fit in the runs".into(),
        ));
    }
    let iteration = AtomicUsize::new(0);
    let jacobian = |theta: &[f64], _: &(), r: &[f64]| -> Result<DMatrix<f64>, MotionError> {
        progress(iteration.fetch_add(1, Ordering::Relaxed), marker_rms(r));
        let columns: Vec<Result<Vec<f64>, MotionError>> = (0..theta.len())
            .into_par_iter()
            .map(|k| {
                let mut t = theta.to_vec();
                t[k] += DIFFERENCE_STEP;
                let (rk, _) = residual(&t)?;
                if rk.len() != r.len() {
                    return Err(MotionError::Invalid(
                        "a perturbed run observed a different number of markers".into(),
                    ));
                }
                Ok(rk
                    .iter()
                    .zip(r)
                    .map(|(a, b)| (a - b) / DIFFERENCE_STEP)
                    .collect())
            })
            .collect();
        let mut j = DMatrix::zeros(r.len(), theta.len());
        for (k, c) in columns.into_iter().enumerate() {
            for (i, v) in c?.into_iter().enumerate() {
                j[(i, k)] = v;
            }
        }
        Ok(j)
    };
    let eval = |theta: &[f64], _: &()| residual(theta).ok().map(|(r, _)| (r, ()));
    let options = LmOptions {
        max_iterations,
        tries: 8,
        initial_damping: 1e-3,
        min_damping: 1e-9,
        reject_factor: 10.0,
        rel_tolerance: 1e-4,
        cost_floor: 0.0,
    };
    let out = minimise(theta0, r0, (), jacobian, eval, &options)?;
    let n = out.residuals.len();
    let dof = n.saturating_sub(params.len()).max(1) as f64;
    let variance = out.cost / dof;
    let cov = out.jtj.clone().try_inverse();
    let std = params
        .iter()
        .zip(&out.theta)
        .enumerate()
        .map(|(k, (p, &t))| {
            let s = cov
                .as_ref()
                .map_or(f64::NAN, |c| (variance * c[(k, k)]).max(0.0).sqrt());
            if p.log {
                t.exp() * s
            } else {
                s
            }
        })
        .collect();
    let mut run_rms = Vec::new();
    let mut at = 0;
    for len in lengths {
        let part = &out.residuals[at..at + len];
        run_rms.push(marker_rms(part));
        at += len;
    }
    Ok(DifferenceFit {
        values: params
            .iter()
            .zip(&out.theta)
            .map(|(p, &t)| value(p, t))
            .collect(),
        std,
        rms: marker_rms(&out.residuals),
        run_rms,
        simulations: simulations.load(Ordering::Relaxed),
        iterations: out.iterations,
        converged: out.converged,
    })
}
