//! The shear modulus from rest states: a motion dataset's settled end (the markers' mean over its
//! last stretch, where the ring-down has died out) is a quasi-static equilibrium under gravity,
//! the dead loads and the clamps' final poses, so μ at a fixed Poisson's ratio can be fitted by
//! Gauss–Newton in ln μ through the quasi-static solver on linear ([`super::statics`]) or
//! quadratic ([`super::quadratic_statics`]) tetrahedra — the same data seen through two
//! discretisations, which is what a mesh-convergence study of the fitted modulus needs.
//!
//! The markers are taken as the dataset embeds them (element and barycentric coordinates on the
//! linear mesh, extrapolated a little outside it for stand-offs) with no registration or offset
//! fitted at rest: what is left is reported as the RMS.

use super::dataset::MotionDataset;
use super::hyperelastic::HyperParams;
use super::model::Model;
use super::quadratic_statics::{quadratic_sensitivity, solve_static_quadratic, value_at};
use super::statics::{solve_static, static_sensitivity, StaticProblem};
use super::MotionError;
use palpate_fem::mesh::Mesh;
use std::collections::HashMap;

/// The element design a rest state is solved with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Design {
    /// Linear 4-node tetrahedra (P1).
    Linear,
    /// Quadratic 10-node tetrahedra on the same corners (P2).
    Quadratic,
}

impl Design {
    /// "P1" or "P2".
    pub fn name(self) -> &'static str {
        match self {
            Self::Linear => "P1",
            Self::Quadratic => "P2",
        }
    }
}

/// One run's rest state: the static problem's data and the markers' settled positions.
#[derive(Debug, Clone)]
pub struct RestState {
    /// The linear mesh.
    pub mesh: Mesh,
    /// Density (kg/m³) and gravity (m/s²).
    pub density: f64,
    /// Gravity (m/s²).
    pub gravity: [f64; 3],
    /// Clamped nodes and their displacement at the end of the capture.
    pub fixed: Vec<usize>,
    /// Displacement of each clamped node (same order as `fixed`).
    pub fixed_displacement: Vec<[f64; 3]>,
    /// Dead loads acting at the end of the capture, per node (N).
    pub forces: Vec<(usize, [f64; 3])>,
    /// Each marker's element of the linear mesh and barycentric coordinates in it.
    pub markers: Vec<(usize, [f64; 4])>,
    /// Each marker's mean observed position over the window (m).
    pub observed: Vec<[f64; 3]>,
    /// Observed frames averaged per marker (fewest over the markers).
    pub frames: usize,
}

impl RestState {
    /// The rest state of `ds`: the markers' mean positions over the last `window` seconds of
    /// the capture, with the loads and clamp poses of its last step. A marker with no frame in
    /// the window, or whose weights name no element, is an error naming it.
    pub fn of_dataset(ds: &MotionDataset, window: f64) -> Result<Self, MotionError> {
        let model = &ds.model;
        let density = ds.config.density.ok_or_else(|| {
            MotionError::Invalid(
                "dataset.toml: field density is missing (a rest state needs the weight)".into(),
            )
        })?;
        let end = model.steps;
        let first = end.saturating_sub((window / model.dt).round() as usize);
        let element: HashMap<[usize; 4], usize> = ds
            .mesh
            .tets
            .iter()
            .enumerate()
            .map(|(e, t)| {
                let mut k = *t;
                k.sort_unstable();
                (k, e)
            })
            .collect();
        let mut markers = Vec::with_capacity(model.markers.len());
        let mut observed = Vec::with_capacity(model.markers.len());
        let mut frames = usize::MAX;
        for (i, m) in model.markers.iter().enumerate() {
            let mut key: [usize; 4] = [0; 4];
            if m.weights.len() != 4 {
                return Err(MotionError::Invalid(format!(
                    "marker {:?}: {} weights, expected 4 (one tetrahedron)",
                    m.name,
                    m.weights.len()
                )));
            }
            for (k, (n, _)) in key.iter_mut().zip(&m.weights) {
                *k = *n;
            }
            key.sort_unstable();
            let e = *element.get(&key).ok_or_else(|| {
                MotionError::Invalid(format!(
                    "marker {:?}: its nodes {key:?} are no element of the mesh",
                    m.name
                ))
            })?;
            let t = ds.mesh.tets[e];
            let bary = t.map(|n| {
                m.weights
                    .iter()
                    .find(|(w, _)| *w == n)
                    .map_or(0.0, |(_, w)| *w)
            });
            // Steps first+1..=end are observation rows first..end.
            let seen: Vec<[f64; 3]> = model_rows(&ds.obs.markers, first, end, i);
            if seen.is_empty() {
                return Err(MotionError::Invalid(format!(
                    "marker {:?}: no observed frame in the last {window} s",
                    m.name
                )));
            }
            frames = frames.min(seen.len());
            let k = seen.len() as f64;
            observed.push([0, 1, 2].map(|d| seen.iter().map(|p| p[d]).sum::<f64>() / k));
            markers.push((e, bary));
        }
        let ndof = 3 * ds.mesh.nodes.len();
        let forces = dead_load_forces(model);
        let mut x = vec![0.0; ndof];
        model.apply_clamps(end, &mut x);
        let fixed: Vec<usize> = model
            .clamps
            .iter()
            .flat_map(|c| c.nodes.iter().copied())
            .collect();
        let fixed_displacement = fixed
            .iter()
            .map(|&n| [0, 1, 2].map(|d| x[3 * n + d] - ds.mesh.nodes[n][d]))
            .collect();
        Ok(Self {
            mesh: ds.mesh.clone(),
            density,
            gravity: model.gravity,
            fixed,
            fixed_displacement,
            forces,
            markers,
            observed,
            frames: if frames == usize::MAX { 0 } else { frames },
        })
    }

    /// This rest state under `model`'s dead loads at its last step (the same run's model with
    /// its hanging weights moved, say: [`crate::load_point`]).
    pub fn with_loads_of(&self, model: &Model) -> Self {
        Self {
            forces: dead_load_forces(model),
            ..self.clone()
        }
    }

    /// The static problem of this rest state for `material`.
    fn problem(&self, material: HyperParams, solve: &RestSolve) -> StaticProblem<'_> {
        let mut p = StaticProblem::new(&self.mesh, material, self.fixed.clone());
        p.density = self.density;
        p.gravity = self.gravity;
        p.fixed_displacement = self.fixed_displacement.clone();
        p.forces = self.forces.clone();
        p.load_steps = solve.load_steps;
        p.tol = solve.tol;
        p
    }
}

/// The nodal forces of `model`'s dead loads at its last step, on the nodes they load.
fn dead_load_forces(model: &Model) -> Vec<(usize, [f64; 3])> {
    let mut f = vec![0.0; 3 * model.nodes.len()];
    model.add_dead_loads(model.steps, &mut f);
    (0..model.nodes.len())
        .filter(|&n| f[3 * n..3 * n + 3].iter().any(|v| *v != 0.0))
        .map(|n| (n, [f[3 * n], f[3 * n + 1], f[3 * n + 2]]))
        .collect()
}

/// How each rest state is solved: load increments and Newton tolerance on the residual (N).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RestSolve {
    /// Load increments (≥ 1).
    pub load_steps: usize,
    /// Newton tolerance (N). Near incompressibility the residual's round-off floor rises with λ
    /// (≈ 2e-8 N for the beam at ν = 0.499 on linear tetrahedra), so it must sit above it.
    pub tol: f64,
}

/// Observed positions of marker `i` at observation rows `first..end`.
fn model_rows(rows: &[Vec<Option<[f64; 3]>>], first: usize, end: usize, i: usize) -> Vec<[f64; 3]> {
    rows[first.min(rows.len())..end.min(rows.len())]
        .iter()
        .filter_map(|r| r.get(i).copied().flatten())
        .collect()
}

/// A solved rest state: the markers' predicted positions and, if asked, their derivative with
/// respect to ln μ at fixed Poisson's ratio.
#[derive(Debug, Clone)]
pub struct RestPrediction {
    /// Predicted marker positions (m).
    pub markers: Vec<[f64; 3]>,
    /// ∂marker/∂ln μ at fixed ν (m), when asked for.
    pub dmarkers: Option<Vec<[f64; 3]>>,
    /// Newton iterations of the solve.
    pub newton_iterations: usize,
}

impl RestPrediction {
    /// RMS of the 3-D marker error against `state`'s observed rest positions (m).
    pub fn rms(&self, state: &RestState) -> f64 {
        let s: f64 = self
            .markers
            .iter()
            .zip(&state.observed)
            .map(|(p, o)| (0..3).map(|d| (p[d] - o[d]).powi(2)).sum::<f64>())
            .sum();
        (s / self.markers.len().max(1) as f64).sqrt()
    }
}

/// Lamé parameters of shear modulus `mu` at Poisson's ratio `poisson`.
pub fn lame(mu: f64, poisson: f64) -> HyperParams {
    HyperParams {
        lambda: 2.0 * mu * poisson / (1.0 - 2.0 * poisson),
        mu,
        stiffening: 0.0,
    }
}

/// Solves `state` with `design` at (μ, ν); with `sensitivity`, also ∂markers/∂ln μ at fixed ν,
/// μ ∂x/∂μ + λ ∂x/∂λ (λ is proportional to μ at fixed ν).
pub fn predict_rest(
    state: &RestState,
    design: Design,
    mu: f64,
    poisson: f64,
    solve: &RestSolve,
    sensitivity: bool,
) -> Result<RestPrediction, MotionError> {
    let material = lame(mu, poisson);
    let p = state.problem(material, solve);
    let linear_at = |v: &[[f64; 3]], e: usize, l: &[f64; 4]| -> [f64; 3] {
        let t = state.mesh.tets[e];
        [0, 1, 2].map(|d| (0..4).map(|a| l[a] * v[t[a]][d]).sum())
    };
    let (solution, sens, quadratic) = match design {
        Design::Linear => {
            let s = solve_static(&p)?;
            let d = sensitivity
                .then(|| static_sensitivity(&p, &s))
                .transpose()?;
            (s, d, None)
        }
        Design::Quadratic => {
            let s = solve_static_quadratic(&p)?;
            let d = sensitivity
                .then(|| quadratic_sensitivity(&p, &s))
                .transpose()?;
            (s.solution, d, Some(s.mesh))
        }
    };
    let at = |v: &[[f64; 3]], (e, l): &(usize, [f64; 4])| match &quadratic {
        Some(q) => value_at(q, v, *e, l),
        None => linear_at(v, *e, l),
    };
    Ok(RestPrediction {
        markers: state
            .markers
            .iter()
            .map(|m| at(&solution.positions, m))
            .collect(),
        dmarkers: sens.map(|ds| {
            state
                .markers
                .iter()
                .map(|m| {
                    let (dl, dm) = (at(&ds.dlambda, m), at(&ds.dmu, m));
                    [0, 1, 2].map(|d| material.lambda * dl[d] + material.mu * dm[d])
                })
                .collect()
        }),
        newton_iterations: solution.iterations,
    })
}

/// A fitted shear modulus.
#[derive(Debug, Clone)]
pub struct ShearFit {
    /// μ (Pa).
    pub mu: f64,
    /// Gauss–Newton iterations (each one solve and one sensitivity per run).
    pub iterations: usize,
    /// Newton iterations over every solve of the fit.
    pub newton_iterations: usize,
    /// The fitted runs' predictions at μ.
    pub predictions: Vec<RestPrediction>,
}

/// Fits μ at fixed `poisson` to the rest states `states` by Gauss–Newton in ln μ from `mu0`,
/// until the step is below `1e-4` in ln μ (0.01 %) or after `max_iter` iterations; a step that
/// does not lower the summed squared marker error is halved (up to ten times).
pub fn fit_shear_modulus(
    states: &[RestState],
    design: Design,
    poisson: f64,
    mu0: f64,
    settings: &RestSolve,
    max_iter: usize,
) -> Result<ShearFit, MotionError> {
    let mut newton = 0usize;
    let mut solve = |mu: f64, sens: bool| -> Result<Vec<RestPrediction>, MotionError> {
        let out: Vec<RestPrediction> = states
            .iter()
            .map(|s| predict_rest(s, design, mu, poisson, settings, sens))
            .collect::<Result<_, _>>()?;
        newton += out.iter().map(|p| p.newton_iterations).sum::<usize>();
        Ok(out)
    };
    let cost = |preds: &[RestPrediction]| -> f64 {
        preds
            .iter()
            .zip(states)
            .map(|(p, s)| p.rms(s).powi(2) * p.markers.len() as f64)
            .sum()
    };
    let mut theta = mu0.ln();
    let mut preds = solve(mu0, true)?;
    let mut iterations = 0;
    for _ in 0..max_iter {
        iterations += 1;
        let (mut jtr, mut jtj) = (0.0, 0.0);
        for (p, s) in preds.iter().zip(states) {
            let dm = p.dmarkers.as_ref().expect("sensitivities were asked for");
            for ((x, o), j) in p.markers.iter().zip(&s.observed).zip(dm) {
                for d in 0..3 {
                    jtr += j[d] * (x[d] - o[d]);
                    jtj += j[d] * j[d];
                }
            }
        }
        if jtj <= 0.0 || !jtj.is_finite() {
            return Err(MotionError::NonFinite(format!(
                "Gauss–Newton normal equation JᵀJ = {jtj:e} at μ = {:.1} Pa",
                theta.exp()
            )));
        }
        let mut step = -jtr / jtj;
        let before = cost(&preds);
        let mut accepted = None;
        for _ in 0..10 {
            let trial = solve((theta + step).exp(), true)?;
            if cost(&trial) <= before {
                accepted = Some(trial);
                break;
            }
            step *= 0.5;
        }
        let Some(trial) = accepted else {
            break;
        };
        theta += step;
        preds = trial;
        log::info!(
            "{} ν {poisson}: GN {iterations}: μ = {:.1} Pa (step {step:+.2e} in ln μ)",
            design.name(),
            theta.exp()
        );
        if step.abs() < 1e-4 {
            break;
        }
    }
    Ok(ShearFit {
        mu: theta.exp(),
        iterations,
        newton_iterations: newton,
        predictions: preds,
    })
}
