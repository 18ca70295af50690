//! Log-parameter LBFGS (§4.3) with the Moré–Thuente line search (strong Wolfe conditions,
//! c₁ = 1e-4, c₂ = 0.9), via argmin's `Vec<f64>` backend.
//!
//! The optimiser works on z = ln q, so dΦ/dz = q · dΦ/dq — except for the spline control values
//! of §4.2, which may be negative (J h′(J) is −μ at rest): the paper optimises them directly, so
//! here q = s·z with s the RMS of the starting control values of that spline (a fixed scale that
//! puts them on the same O(1) footing as the log-parameters for LBFGS's initial Hessian). With the
//! spline material the objective also carries the paper's penalty on negative spline slopes,
//! R = w Σ min(0, slope)² ([`SplineMaterial::slope_penalty`]), w from
//! [`SplineMaterial::slope_weight`] or automatic ([`auto_slope_weight`]). A failed simulation (inverted element,
//! indefinite system, NaN) is an infinitely bad point. argmin's Moré–Thuente aborts on a
//! non-finite value, so the line search is handed a finite stand-in that has the same effect as
//! +∞ — a value 10⁶ × (1 + |Φ| of the last good point) with a gradient pointing back towards it —
//! which makes it bracket and back off; the reasons are collected and shown to the user.
//! (argmin's backtracking search was tried first: with the curvature condition it can only
//! shrink the step, and its inner executor has no iteration cap, so it stalls forever when the
//! first LBFGS step is too short.) For per-element parameters an optional neighbour-smoothness
//! regulariser R = w Σ_{(e,f) face neighbours} (z_e − z_f)² (per kind, in log space: the motion
//! analogue of the static fitter's L_s) is added.

use super::gradient::{evaluate, evaluate_gauss_newton, Evaluation, Method};
use super::model::{Material, Model, Observations, Param, ParamKind};
use super::spline::{Response, SplineMaterial};
use super::MotionError;
use argmin::core::{CostFunction, Error as ArgminError, Executor, Gradient, State};
use argmin::solver::linesearch::MoreThuenteLineSearch;
use argmin::solver::quasinewton::LBFGS;
use palpate_fem::lm::{minimise_restarting_confirmed, Normal, TrustOptions};
use std::sync::Mutex;

/// Which optimiser a fit runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Optimizer {
    /// The paper's LBFGS (§4.3) on the gradient of `FitSettings::method`.
    Lbfgs,
    /// Levenberg–Marquardt on the Gauss–Newton matrix of Φ (direct sensitivities): for a few
    /// global parameters fitted to marker trajectories and clamp forces, Φ is a sum of
    /// squares, and steps on its Gauss–Newton model converge in a handful of simulations where
    /// LBFGS, which must learn the curvature from gradients, needs tens.
    LevenbergMarquardt,
    /// Levenberg–Marquardt where it applies (every parameter global and in log space: no
    /// per-element parameters with their regulariser, no spline), else LBFGS.
    #[default]
    Auto,
}

/// Optimiser settings.
#[derive(Debug, Clone)]
pub struct FitSettings {
    /// Which optimiser.
    pub optimizer: Optimizer,
    /// Gradient method (LBFGS; Levenberg–Marquardt always uses direct sensitivities).
    pub method: Method,
    /// LBFGS history length m.
    pub memory: usize,
    /// Iteration cap (the paper uses 150).
    pub max_iters: u64,
    /// Stop when ‖dΦ/dz‖ falls below this.
    pub tol_grad: f64,
    /// Stop when the relative change of Φ falls below this.
    pub tol_cost: f64,
    /// Levenberg–Marquardt stops at the precision the data are worth ([`precision`]: a tenth of
    /// one residual's share of Φ) where that is coarser than `tol_cost`. Off, it stops at
    /// max(`tol_cost`, 10⁻⁶) of Φ: for a comparison of optimisers on one minimum.
    pub data_precision: bool,
    /// Neighbour-smoothness weight; `None` = automatic (see [`auto_smoothness_weight`]).
    pub smoothness: Option<f64>,
    /// Poisson's ratio held fixed: λ = 2μν/(1 − 2ν) follows the fitted global μ (λ must then
    /// not be a parameter itself). For a bending test whose markers see the deflection but not
    /// the volume change, λ is not identifiable; a nearly incompressible material is declared.
    pub poisson: Option<f64>,
    /// Lower bounds (floors) of global parameters, by kind: for a parameter whose values below
    /// some bound describe another effect than the one fitted. A step that would cross a floor
    /// stops on it, and a parameter on its floor stays there while Φ falls below it
    /// ([`palpate_fem::lm::minimise_restarting`]). Levenberg–Marquardt only; the start
    /// must not lie below the floor.
    pub floors: Vec<(ParamKind, f64)>,
}

impl Default for FitSettings {
    fn default() -> Self {
        Self {
            optimizer: Optimizer::Auto,
            method: Method::Adjoint,
            memory: 5,
            max_iters: 150,
            tol_grad: 1e-12,
            tol_cost: 1e-10,
            data_precision: true,
            smoothness: None,
            poisson: None,
            floors: Vec::new(),
        }
    }
}

/// Outcome of a fit.
#[derive(Debug, Clone)]
pub struct FitResult {
    /// Fitted parameter values (linear).
    pub q: Vec<f64>,
    /// Final objective (including the regulariser).
    pub phi: f64,
    /// Evaluation at the fitted parameters (data term, RMS errors).
    pub eval: Evaluation,
    /// Simulations run (each with gradient).
    pub evaluations: usize,
    /// Simulations run without the gradient: Levenberg–Marquardt's last step confirmed by Φ
    /// alone ([`palpate_fem::lm::CONFIRM_BELOW`]).
    pub plain_evaluations: usize,
    /// Optimiser iterations (LBFGS, or accepted and rejected Levenberg–Marquardt steps).
    pub iterations: u64,
    /// The optimiser that ran.
    pub optimizer: Optimizer,
    /// Why simulations failed during the line search (deduplicated).
    pub failures: Vec<String>,
    /// Φ after each evaluation.
    pub history: Vec<f64>,
    /// Evaluation of each run at the fitted parameters (one entry for a one-run fit).
    pub runs: Vec<Evaluation>,
    /// Levenberg–Marquardt's Gauss–Newton matrix at the fitted parameters, in z = ln q
    /// (row-major, `q.len()`²): the marker term's Σ_n Δt w_m Σ_i J_inᵀ J_in summed over the runs
    /// ([`crate::gradient::evaluate_gauss_newton`]), from the simulation the fit ended on, or
    /// where that one was confirmed by Φ alone from the fit's last linearisation, a step within the
    /// precision before it — so a caller's Gauss–Newton 1σ needs no simulation of its own.
    /// `None` from LBFGS.
    pub gauss_newton: Option<Vec<f64>>,
}

/// Automatic neighbour-smoothness weight: 1e-3 · Φ(q₀) / #pairs, i.e. a log-ratio of e ≈ 2.7
/// across every neighbour pair costs 0.1 % of the starting misfit — small enough not to mask a
/// real material jump, large enough to fix the null space of elements the data cannot see.
pub fn auto_smoothness_weight(phi0: f64, pairs: usize) -> f64 {
    1e-3 * phi0 / pairs.max(1) as f64
}

/// Automatic slope-penalty weight: 1e-2 · Φ(q₀) / (samples · scale²), i.e. a negative slope as
/// large as the typical control value at every sample point would cost 1 % of the starting misfit
/// ("slightly penalizes", §4.2): enough to push the line search away from softening branches,
/// too small to compete with a real misfit reduction.
pub fn auto_slope_weight(phi0: f64, samples: usize, scale: f64) -> f64 {
    1e-2 * phi0 / (samples.max(1) as f64 * scale * scale)
}

/// How one parameter maps to the optimiser's variable.
#[derive(Debug, Clone, Copy)]
enum Transform {
    /// q = exp z.
    Log,
    /// q = s z.
    Linear(f64),
}

impl Transform {
    fn q(self, z: f64) -> f64 {
        match self {
            Self::Log => z.exp(),
            Self::Linear(s) => s * z,
        }
    }
    fn z(self, q: f64) -> f64 {
        match self {
            Self::Log => q.ln(),
            Self::Linear(s) => q / s,
        }
    }
    fn dq_dz(self, q: f64) -> f64 {
        match self {
            Self::Log => q,
            Self::Linear(s) => s,
        }
    }
}

/// `base` with `q` applied and, with a fixed Poisson's ratio, λ = ratio · μ.
fn problem_material(
    base: &Material,
    params: &[Param],
    q: &[f64],
    tie: Option<(usize, f64)>,
) -> Material {
    let mut mat = base.clone();
    mat.set(params, q);
    if let Some((mu, ratio)) = tie {
        mat.set(&[Param::global(ParamKind::Lambda)], &[ratio * q[mu]]);
    }
    mat
}

/// One run of a fit: a model (mesh, clamps, loads, time grid) and what was observed. Several runs
/// of one object (other loads, repeats) share one material and are fitted together.
#[derive(Debug, Clone, Copy)]
pub struct Run<'a> {
    /// The run's model.
    pub model: &'a Model,
    /// The run's observations.
    pub obs: &'a Observations,
}

/// Φ and dΦ/dq summed over `runs` (each simulated on its own thread when there are several).
pub fn evaluate_runs(
    runs: &[Run<'_>],
    mat: &Material,
    params: &[Param],
    method: Option<Method>,
) -> Result<(Evaluation, Vec<Evaluation>), MotionError> {
    let parts: Vec<Evaluation> = if runs.len() == 1 {
        vec![evaluate(runs[0].model, mat, params, runs[0].obs, method)?]
    } else {
        use rayon::prelude::*;
        runs.par_iter()
            .map(|r| evaluate(r.model, mat, params, r.obs, method))
            .collect::<Result<_, _>>()?
    };
    Ok((Evaluation::combine(&parts), parts))
}

struct Problem<'a> {
    runs: &'a [Run<'a>],
    base: &'a Material,
    params: &'a [Param],
    method: Method,
    pairs: Vec<(usize, usize)>,
    weight: f64,
    transforms: Vec<Transform>,
    slope_weight: f64,
    /// (index of the global μ parameter, λ/μ) when Poisson's ratio is held fixed.
    tie: Option<(usize, f64)>,
    cache: &'a Mutex<Cache>,
    progress: &'a (dyn Fn(usize, f64) + Sync),
}

#[derive(Default)]
struct Cache {
    z: Vec<f64>,
    value: f64,
    grad: Vec<f64>,
    evaluations: usize,
    failures: Vec<String>,
    history: Vec<f64>,
    best: Option<(f64, Vec<f64>)>,
}

impl Problem<'_> {
    /// The base material with the parameters `q` applied (and λ tied to μ if asked).
    fn material(&self, q: &[f64]) -> Material {
        problem_material(self.base, self.params, q, self.tie)
    }

    fn regulariser(&self, z: &[f64], grad: &mut [f64]) -> f64 {
        let mut r = 0.0;
        for &(a, b) in &self.pairs {
            let d = z[a] - z[b];
            r += self.weight * d * d;
            grad[a] += 2.0 * self.weight * d;
            grad[b] -= 2.0 * self.weight * d;
        }
        r
    }

    /// w·R of the spline slopes; adds dR/dz of the spline parameters into `gz`.
    fn slope_penalty(&self, sp: &SplineMaterial, gz: &mut [f64]) -> f64 {
        if self.slope_weight == 0.0 {
            return 0.0;
        }
        let nf = sp.len(Response::F);
        let mut gc = vec![0.0; nf + sp.len(Response::H)];
        let r = sp.slope_penalty(&mut gc);
        for (p, par) in self.params.iter().enumerate() {
            let (Some(resp), Some(i)) = (par.kind.response(), par.element) else {
                continue;
            };
            let c = if resp == Response::F { i } else { nf + i };
            gz[p] += self.slope_weight * gc[c] * self.transforms[p].dq_dz(0.0);
        }
        self.slope_weight * r
    }

    fn compute(&self, z: &[f64]) -> (f64, Vec<f64>) {
        {
            let c = self.cache.lock().expect("cache lock");
            if c.z == z && !c.grad.is_empty() {
                return (c.value, c.grad.clone());
            }
        }
        let q: Vec<f64> = z
            .iter()
            .zip(&self.transforms)
            .map(|(v, t)| t.q(*v))
            .collect();
        let mat = self.material(&q);
        let out = match self.tie {
            None => evaluate_runs(self.runs, &mat, self.params, Some(self.method)).map(|(a, _)| a),
            // λ is evaluated as one more global parameter and folded into μ by the chain rule:
            // dΦ/dμ|tied = ∂Φ/∂μ + (λ/μ) ∂Φ/∂λ.
            Some((mu, ratio)) => {
                let mut with_lambda = self.params.to_vec();
                with_lambda.push(Param::global(ParamKind::Lambda));
                evaluate_runs(self.runs, &mat, &with_lambda, Some(self.method)).map(|(mut a, _)| {
                    if let Some(g) = a.grad.as_mut() {
                        let dl = g.pop().unwrap_or(0.0);
                        g[mu] += ratio * dl;
                    }
                    a
                })
            }
        };
        let mut c = self.cache.lock().expect("cache lock");
        c.evaluations += 1;
        let out_ok = out.is_ok();
        let (value, grad) = match out {
            Ok(ev) => {
                let g = ev.grad.expect("gradient requested");
                let mut gz: Vec<f64> = g
                    .iter()
                    .zip(&q)
                    .zip(&self.transforms)
                    .map(|((g, q), t)| g * t.dq_dz(*q))
                    .collect();
                let mut v = ev.phi + self.regulariser(z, &mut gz);
                if let Some(sp) = &mat.spline {
                    v += self.slope_penalty(sp, &mut gz);
                }
                (v, gz)
            }
            Err(e) => {
                let msg = e.to_string();
                if !c.failures.contains(&msg) {
                    c.failures.push(msg);
                }
                match &c.best {
                    Some((phi, zb)) => {
                        let big = 1e6 * (1.0 + phi.abs());
                        let g: Vec<f64> = z.iter().zip(zb).map(|(a, b)| big * (a - b)).collect();
                        (big, g)
                    }
                    None => (f64::INFINITY, vec![0.0; z.len()]),
                }
            }
        };
        c.z = z.to_vec();
        c.value = value;
        c.grad = grad.clone();
        c.history.push(value);
        if out_ok && c.best.as_ref().is_none_or(|b| value < b.0) {
            c.best = Some((value, z.to_vec()));
        }
        (self.progress)(c.evaluations, value);
        (value, grad)
    }
}

impl CostFunction for Problem<'_> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, z: &Self::Param) -> Result<f64, ArgminError> {
        Ok(self.compute(z).0)
    }
}

impl Gradient for Problem<'_> {
    type Param = Vec<f64>;
    type Gradient = Vec<f64>;
    fn gradient(&self, z: &Self::Param) -> Result<Vec<f64>, ArgminError> {
        Ok(self.compute(z).1)
    }
}

/// Fits `params` starting from `q0` (linear values; must be > 0 except spline control values). `progress(evals, Φ)` is called
/// after every simulation. Neighbour pairs for the regulariser are taken from `pairs`
/// (element pairs); only per-element parameters of the same kind on both elements are coupled.
#[allow(clippy::too_many_arguments)]
pub fn fit(
    model: &Model,
    base: &Material,
    params: &[Param],
    q0: &[f64],
    obs: &Observations,
    settings: &FitSettings,
    element_pairs: &[(usize, usize)],
    progress: &(dyn Fn(usize, f64) + Sync),
) -> Result<FitResult, MotionError> {
    fit_runs(
        &[Run { model, obs }],
        base,
        params,
        q0,
        settings,
        element_pairs,
        progress,
    )
}

/// [`fit`] over several runs of one object sharing the material (Φ summed over the runs; every
/// run's model must be on the same mesh as `base`).
pub fn fit_runs(
    runs: &[Run<'_>],
    base: &Material,
    params: &[Param],
    q0: &[f64],
    settings: &FitSettings,
    element_pairs: &[(usize, usize)],
    progress: &(dyn Fn(usize, f64) + Sync),
) -> Result<FitResult, MotionError> {
    base.check_params(params)?;
    if runs.is_empty() {
        return Err(MotionError::Invalid("no runs to fit".into()));
    }
    if let Some(r) = runs
        .iter()
        .find(|r| r.model.tets.len() != runs[0].model.tets.len())
    {
        return Err(MotionError::Invalid(format!(
            "runs on different meshes ({} and {} tets): the runs of one fit share one material",
            runs[0].model.tets.len(),
            r.model.tets.len()
        )));
    }
    if q0.len() != params.len() {
        return Err(MotionError::Invalid(format!(
            "{} starting values for {} parameters",
            q0.len(),
            params.len()
        )));
    }
    if let Some((i, v)) = q0
        .iter()
        .enumerate()
        .find(|(i, v)| !v.is_finite() || (!params[*i].kind.is_spline() && **v <= 0.0))
    {
        return Err(MotionError::Invalid(format!(
            "parameter {} ({}{}) must start positive for the log transform, found {v}",
            i,
            params[i].kind.name(),
            match (params[i].element, params[i].region) {
                (Some(e), _) => format!(" of element {e}"),
                (None, Some(r)) => format!(" of region {r}"),
                (None, None) => String::new(),
            }
        )));
    }
    let spline_scale = |r: Response| {
        let v: Vec<f64> = params
            .iter()
            .zip(q0)
            .filter(|(p, _)| p.kind.response() == Some(r))
            .map(|(_, q)| q * q)
            .collect();
        let rms = (v.iter().sum::<f64>() / v.len().max(1) as f64).sqrt();
        if rms > 0.0 {
            rms
        } else {
            1.0
        }
    };
    let transforms: Vec<Transform> = params
        .iter()
        .map(|p| match p.kind.response() {
            Some(r) => Transform::Linear(spline_scale(r)),
            None => Transform::Log,
        })
        .collect();
    let z0: Vec<f64> = q0.iter().zip(&transforms).map(|(v, t)| t.z(*v)).collect();
    let mut index = std::collections::HashMap::new();
    for (p, par) in params.iter().enumerate() {
        if let Some(e) = par.element {
            index.insert((par.kind, e), p);
        }
    }
    let pairs: Vec<(usize, usize)> = element_pairs
        .iter()
        .flat_map(|&(a, b)| {
            super::model::ParamKind::ALL
                .into_iter()
                .filter_map(|k| Some((*index.get(&(k, a))?, *index.get(&(k, b))?)))
                .collect::<Vec<_>>()
        })
        .collect();
    let tie = match settings.poisson {
        None => None,
        Some(nu) => {
            if !(nu.is_finite() && nu > -1.0 && nu < 0.5) {
                return Err(MotionError::Invalid(format!(
                    "Poisson's ratio must lie in (−1, 0.5), found {nu}"
                )));
            }
            if params.iter().any(|p| p.kind == ParamKind::Lambda) {
                return Err(MotionError::Invalid(
                    "λ is a parameter and Poisson's ratio is fixed: give one or the other".into(),
                ));
            }
            let mu = params
                .iter()
                .position(|p| p.kind == ParamKind::Mu && p.is_global())
                .ok_or_else(|| {
                    MotionError::Invalid(
                        "a fixed Poisson's ratio needs the global μ among the parameters".into(),
                    )
                })?;
            Some((mu, 2.0 * nu / (1.0 - 2.0 * nu)))
        }
    };
    let lm_applies = params
        .iter()
        .all(|p| p.element.is_none() && !p.kind.is_spline())
        && base.spline.is_none()
        && pairs.is_empty();
    for &(kind, floor) in &settings.floors {
        if !(floor.is_finite() && floor > 0.0) {
            return Err(MotionError::Invalid(format!(
                "the floor of {} must be positive and finite, found {floor}",
                kind.name()
            )));
        }
        if matches!(kind, ParamKind::Nu | ParamKind::PowerH) {
            // Their coordinates are read at the data's strain rate ([`RateReference`]), not ln q.
            return Err(MotionError::Invalid(format!(
                "a floor on {} is not supported",
                kind.name()
            )));
        }
        if !lm_applies || settings.optimizer == Optimizer::Lbfgs {
            return Err(MotionError::Invalid(format!(
                "a floor on {} needs Levenberg–Marquardt on global parameters",
                kind.name()
            )));
        }
        if let Some((p, q)) = params
            .iter()
            .zip(q0)
            .find(|(p, q)| p.kind == kind && **q < floor)
        {
            return Err(MotionError::Invalid(format!(
                "{} starts at {q}, below its floor {floor}",
                p.kind.name()
            )));
        }
    }
    match settings.optimizer {
        Optimizer::LevenbergMarquardt if !lm_applies => {
            return Err(MotionError::Invalid(
                "Levenberg–Marquardt fits global log-parameters only (no per-element or spline parameters): use LBFGS".into(),
            ))
        }
        Optimizer::LevenbergMarquardt | Optimizer::Auto if lm_applies => {
            return levenberg_marquardt(runs, base, params, &z0, settings, tie, progress);
        }
        _ => {}
    }
    let cache_cell = Mutex::new(Cache::default());
    let mut problem = Problem {
        runs,
        base,
        params,
        method: settings.method,
        pairs,
        weight: 0.0,
        transforms: transforms.clone(),
        slope_weight: 0.0,
        tie,
        cache: &cache_cell,
        progress,
    };
    if !problem.pairs.is_empty() {
        problem.weight = match settings.smoothness {
            Some(w) => w,
            None => {
                let (phi0, _) = problem.compute(&z0);
                if !phi0.is_finite() {
                    return Err(MotionError::Invalid(format!(
                        "the starting parameters do not simulate: {}",
                        problem.cache.lock().expect("cache").failures.join("; ")
                    )));
                }
                problem.cache.lock().expect("cache").grad.clear(); // weight changes Φ: recompute
                auto_smoothness_weight(phi0, problem.pairs.len())
            }
        };
    }
    let (phi0, _) = problem.compute(&z0);
    if !phi0.is_finite() {
        return Err(MotionError::Invalid(format!(
            "the starting parameters do not simulate: {}",
            problem.cache.lock().expect("cache").failures.join("; ")
        )));
    }
    if let Some(sp) = &base.spline {
        if params.iter().any(|p| p.kind.is_spline()) {
            let samples = sp.f.samples().len() + sp.h.samples().len();
            problem.slope_weight = sp
                .slope_weight
                .unwrap_or_else(|| auto_slope_weight(phi0, samples, spline_scale(Response::F)));
            problem.cache.lock().expect("cache").grad.clear(); // Φ changes with the weight
        }
    }
    let ls = MoreThuenteLineSearch::new()
        .with_c(1e-4, 0.9)
        .map_err(|e| MotionError::Invalid(e.to_string()))?;
    let solver = LBFGS::new(ls, settings.memory)
        .with_tolerance_grad(settings.tol_grad)
        .and_then(|s| s.with_tolerance_cost(settings.tol_cost))
        .map_err(|e| MotionError::Invalid(e.to_string()))?;
    let run = Executor::new(problem, solver)
        .configure(|s| s.param(z0.clone()).max_iters(settings.max_iters))
        .run();
    let iterations = match &run {
        Ok(r) => r.state().get_iter(),
        Err(_) => 0,
    };
    let run = run.map(|_| ()).map_err(|e| e.to_string());
    let cache = std::mem::take(&mut *cache_cell.lock().expect("cache"));
    let (phi, zbest) = cache.best.clone().unwrap_or((phi0, z0));
    let q: Vec<f64> = zbest
        .iter()
        .zip(&transforms)
        .map(|(v, t)| t.q(*v))
        .collect();
    let mat = problem_material(base, params, &q, tie);
    let (eval, per_run) = evaluate_runs(runs, &mat, params, None)?;
    let mut failures = cache.failures;
    if let Err(e) = run {
        failures.push(format!("optimiser stopped: {e}"));
    }
    Ok(FitResult {
        q,
        phi,
        eval,
        evaluations: cache.evaluations,
        plain_evaluations: 0,
        iterations,
        optimizer: Optimizer::Lbfgs,
        failures,
        history: cache.history,
        runs: per_run,
        gauss_newton: None,
    })
}

/// Φ, dΦ/dz and the Gauss–Newton matrix in z = ln q, summed over the runs; with a tied
/// Poisson's ratio λ is evaluated as one more global parameter and folded into μ by the chain
/// rule (J_μ|tied = J_μ + (λ/μ) J_λ, so H folds as Tᵀ H T).
fn gauss_newton_runs(
    runs: &[Run<'_>],
    base: &Material,
    params: &[Param],
    z: &[f64],
    tie: Option<(usize, f64)>,
) -> Result<(f64, Vec<f64>, Vec<f64>, Vec<Evaluation>), MotionError> {
    let np = params.len();
    let q: Vec<f64> = z.iter().map(|v| v.exp()).collect();
    let mat = problem_material(base, params, &q, tie);
    let mut all = params.to_vec();
    if tie.is_some() {
        all.push(Param::global(ParamKind::Lambda));
    }
    let na = all.len();
    let one = |r: &Run<'_>| evaluate_gauss_newton(r.model, &mat, &all, r.obs);
    let parts: Vec<(Evaluation, Vec<f64>)> = if runs.len() == 1 {
        vec![one(&runs[0])?]
    } else {
        use rayon::prelude::*;
        runs.par_iter().map(one).collect::<Result<_, _>>()?
    };
    let mut phi = 0.0;
    let mut g = vec![0.0; na];
    let mut h = vec![0.0; na * na];
    for (ev, hp) in &parts {
        phi += ev.phi;
        for (a, b) in g.iter_mut().zip(ev.grad.as_deref().unwrap_or(&[])) {
            *a += b;
        }
        for (a, b) in h.iter_mut().zip(hp) {
            *a += b;
        }
    }
    // T maps the np fitted parameters onto the na evaluated ones; then dq/dz = q (log space).
    let t = |i: usize, a: usize| -> f64 {
        match tie {
            Some((mu, ratio)) if i == np && a == mu => ratio,
            _ if i == a => 1.0,
            _ => 0.0,
        }
    };
    let mut gz = vec![0.0; np];
    let mut hz = vec![0.0; np * np];
    for a in 0..np {
        gz[a] = (0..na).map(|i| t(i, a) * g[i]).sum::<f64>() * q[a];
        for b in 0..np {
            let mut s = 0.0;
            for i in 0..na {
                for j in 0..na {
                    s += t(i, a) * h[i * na + j] * t(j, b);
                }
            }
            hz[a * np + b] = s * q[a] * q[b];
        }
    }
    // Each run's evaluation without its gradient: what the fit reports at the accepted point.
    let per_run = parts
        .into_iter()
        .map(|(ev, _)| Evaluation { grad: None, ..ev })
        .collect();
    Ok((phi, gz, hz, per_run))
}

/// The lowest power-law index a Levenberg–Marquardt fit of a viscosity with its index takes
/// (from a start above it; a start below is its own floor). As h → 0 the power law becomes a
/// rate-independent, friction-like loss (σ ≈ ν E/γ̇: a stress of fixed size whatever the rate),
/// another effect than a dashpot, and its near-step in the rate makes every Newton solve crawl.
/// Most shear-thinning materials measured in rheology have h between about 0.2 and 0.9. A fit
/// that ends on the floor reports h = 0.1 with the Gauss–Newton σ of that point.
pub const POWER_INDEX_FLOOR: f64 = 0.1;

/// The least ratio λ/μ a Levenberg–Marquardt fit with a free global Lamé λ takes (from a start
/// above it; a start below is its own floor): Poisson's ratio 0.0005. Against μ where the fit is
/// when μ is free too (the fit's coordinate ln(λ/μ), `ElasticPair`), else against μ at the
/// start.
/// Below it the model barely changes — the bulk modulus λ + 2μ/3 is within 0.15 % of its value
/// at λ = 0 — while each step of ln λ toward −∞ costs a simulation for a gain of Φ the data
/// cannot tell from noise. Data that push λ there are those of a mesh that locks in bending
/// (its cylinders read a lower ν than the material's): in the diagnosis of one of the
/// independent generator's cylinders (1,300 tets), 128 of the 231 simulations with
/// sensitivities were steps of ln λ alone toward zero, and the floor takes that diagnosis from
/// 312 s to 264 s with the same verdict (BENCHMARKS.md, "A free λ held at its floor"). A fit
/// that ends on the floor reports λ there with the Gauss–Newton σ of that point.
pub const LAMBDA_FLOOR_RATIO: f64 = 1e-3;

/// Where the power law's prefactor is read: the fit's coordinates for a viscosity ν with its
/// index h are ln ν_ref = ln ν + (h − 1) ln γ̇_ref, the viscosity at a strain rate γ̇_ref of the
/// data instead of at 1/s, and h itself. The data pin the stress at the rates they contain,
/// ν γ̇^(h−1) ≈ const there, so ln ν and h trade off along ln ν ≈ const − (h − 1) ln γ̇_ref: a
/// straight line in (ln ν, h) — and in (ln ν_ref, h), which only turns it to an axis — but a
/// curved one in (ln ν, ln h), which Gauss–Newton steps follow a short chord at a time. h must
/// stay positive: a step to h ≤ 0 is a rejected one. Every other coordinate is z = ln q, so the
/// minimum and the reported (ν, h) are those of the log-parameters.
#[derive(Debug, Clone, Default, PartialEq)]
struct RateReference {
    /// (index of ν, index of its h, ln γ̇_ref) for each viscosity fitted with its index.
    pairs: Vec<(usize, usize, f64)>,
}

impl RateReference {
    /// γ̇_ref for every global or per-region ν fitted with the h of the same elements, from the
    /// Gauss–Newton matrix `hz` in z = ln q at `z`: the ln γ̇_ref whose h column
    /// J_h − ln γ̇_ref J_{ln ν} is orthogonal to J_{ln ν} (the regression of one column on the
    /// other, so that the trust region's Euclidean norm sees two independent directions), i.e.
    /// ln γ̇_ref = H_{ln ν, ln h} / (h H_{ln ν, ln ν}). Fixed for the rest of the fit, so that the
    /// coordinates do not move under the trust region and its secant model.
    fn from_gauss_newton(params: &[Param], z: &[f64], hz: &[f64]) -> Self {
        let np = params.len();
        let pairs = params
            .iter()
            .enumerate()
            .filter(|(_, p)| p.kind == ParamKind::Nu && p.element.is_none())
            .filter_map(|(n, p)| {
                let h = params.iter().position(|o| {
                    o.kind == ParamKind::PowerH && o.element.is_none() && o.region == p.region
                })?;
                let ln_rate = hz[n * np + h] / (z[h].exp() * hz[n * np + n]);
                (ln_rate.is_finite() && hz[n * np + n] > 0.0).then_some((n, h, ln_rate))
            })
            .collect();
        Self { pairs }
    }

    /// z = ln q from the fit's coordinates w; `None` where an h is not positive.
    fn log_params(&self, w: &[f64]) -> Option<Vec<f64>> {
        let mut z = w.to_vec();
        for &(n, h, l) in &self.pairs {
            if w[h].is_nan() || w[h] <= 0.0 {
                return None;
            }
            z[n] = w[n] - (w[h] - 1.0) * l;
            z[h] = w[h].ln();
        }
        Some(z)
    }

    /// The fit's coordinates w from z = ln q.
    fn coordinates(&self, z: &[f64]) -> Vec<f64> {
        let mut w = z.to_vec();
        for &(n, h, l) in &self.pairs {
            w[n] = z[n] + (z[h].exp() - 1.0) * l;
            w[h] = z[h].exp();
        }
        w
    }

    /// ∇Φ and the Gauss–Newton matrix in z carried to w at `w` by the chain rule: with
    /// T = ∂z/∂w (the identity but for T_{ln h, h} = 1/h and T_{ln ν, h} = −ln γ̇_ref),
    /// J_w = J_z T, so ∇_w Φ = Tᵀ ∇_z Φ and H_w = Tᵀ H_z T.
    fn normal_in_coordinates(&self, w: &[f64], mut normal: Normal) -> Normal {
        let np = w.len();
        let gn = &mut normal.gn;
        for &(n, h, l) in &self.pairs {
            let (th, tn) = (1.0 / w[h], -l);
            normal.grad[h] = th * normal.grad[h] + tn * normal.grad[n];
            // H T: column h = th · column h + tn · column n; then Tᵀ (H T) likewise on rows.
            for i in 0..np {
                gn[i * np + h] = th * gn[i * np + h] + tn * gn[i * np + n];
            }
            for j in 0..np {
                gn[h * np + j] = th * gn[h * np + j] + tn * gn[n * np + j];
            }
        }
        normal
    }
}

/// The fit's coordinates for a free global μ and Lamé λ: a = ln E (Young's modulus) in μ's place
/// and b = ln(λ/μ) in λ's. A bending or ringing body's markers pin E (E = μ(3λ + 2μ)/(λ + μ))
/// far better than λ/μ, so μ and λ trade off along E ≈ const: a curved valley in (ln μ, ln λ),
/// which Gauss–Newton steps follow a short chord at a time (each longer step leaves the valley
/// and is rejected), and an axis in (a, b) (BENCHMARKS.md, "The elastic pair in ln E and
/// ln(λ/μ)"). The floor of λ ([`LAMBDA_FLOOR_RATIO`]) is b ≥ ln 10⁻³ there: λ against μ where
/// the fit is.
#[derive(Debug, Clone, Copy, PartialEq)]
struct ElasticPair {
    /// Index of μ.
    mu: usize,
    /// Index of λ.
    lambda: usize,
}

impl ElasticPair {
    /// The pair when both μ and λ are free global parameters (not tied, no floor of their own).
    fn find(
        params: &[Param],
        tie: Option<(usize, f64)>,
        floors: &[(ParamKind, f64)],
    ) -> Option<Self> {
        let global = |k: ParamKind| params.iter().position(|p| p.kind == k && p.is_global());
        let floored = |k: ParamKind| floors.iter().any(|(f, _)| *f == k);
        if tie.is_some() || floored(ParamKind::Mu) || floored(ParamKind::Lambda) {
            return None;
        }
        Some(Self {
            mu: global(ParamKind::Mu)?,
            lambda: global(ParamKind::Lambda)?,
        })
    }

    /// ln(E/μ) at λ/μ = e^b, ln((3 e^b + 2)/(e^b + 1)), written in e^(−|b|) so it neither
    /// overflows nor loses its digits at either end.
    fn ln_e_over_mu(b: f64) -> f64 {
        if b > 0.0 {
            let t = (-b).exp();
            (3.0 + 2.0 * t).ln() - (1.0 + t).ln()
        } else {
            let t = b.exp();
            (3.0 * t + 2.0).ln() - (t + 1.0).ln()
        }
    }

    /// d ln(E/μ) / db = 3e^b/(3e^b + 2) − e^b/(e^b + 1), in e^(−|b|) likewise.
    fn slope(b: f64) -> f64 {
        if b > 0.0 {
            let t = (-b).exp();
            3.0 / (3.0 + 2.0 * t) - 1.0 / (1.0 + t)
        } else {
            let t = b.exp();
            3.0 * t / (3.0 * t + 2.0) - t / (t + 1.0)
        }
    }

    /// (ln μ, ln λ) in `w` to (a, b) in place.
    fn write_fit_coordinates(&self, w: &mut [f64]) {
        let b = w[self.lambda] - w[self.mu];
        w[self.mu] += Self::ln_e_over_mu(b);
        w[self.lambda] = b;
    }

    /// (a, b) in `v` to (ln μ, ln λ) in place.
    fn write_log_params(&self, v: &mut [f64]) {
        let (a, b) = (v[self.mu], v[self.lambda]);
        let ln_mu = a - Self::ln_e_over_mu(b);
        v[self.mu] = ln_mu;
        v[self.lambda] = ln_mu + b;
    }

    /// ∇Φ and the Gauss–Newton matrix in (ln μ, ln λ) carried to (a, b) at `v` by the chain
    /// rule: T = ∂(ln μ, ln λ)/∂(a, b) = [[1, −s], [1, 1 − s]] with s the [`Self::slope`] at b,
    /// so ∇_v Φ = Tᵀ ∇_w Φ and H_v = Tᵀ H_w T (the other coordinates unchanged).
    fn normal_in_fit(&self, v: &[f64], mut normal: Normal) -> Normal {
        let (m, l) = (self.mu, self.lambda);
        let s = Self::slope(v[l]);
        let np = v.len();
        let (gm, gl) = (normal.grad[m], normal.grad[l]);
        normal.grad[m] = gm + gl;
        normal.grad[l] = -s * gm + (1.0 - s) * gl;
        let gn = &mut normal.gn;
        for i in 0..np {
            let (cm, cl) = (gn[i * np + m], gn[i * np + l]);
            gn[i * np + m] = cm + cl;
            gn[i * np + l] = -s * cm + (1.0 - s) * cl;
        }
        for j in 0..np {
            let (rm, rl) = (gn[m * np + j], gn[l * np + j]);
            gn[m * np + j] = rm + rl;
            gn[l * np + j] = -s * rm + (1.0 - s) * rl;
        }
        normal
    }
}

/// The fraction of Φ below which a fit's remaining decrease is not worth a simulation, for
/// `residuals` scalar residuals: a tenth of one residual's share, 0.1/n (and never below 10⁻⁶,
/// the precision of Φ itself: the Newton solves of every step leave a relative 10⁻⁷–10⁻⁶ on a
/// long run).
///
/// Why a tenth of a share: with s² = 2Φ/n the residuals' own variance, the Gauss–Newton 1σ of
/// the parameters is where Φ has grown by Φ/n, so a minimum whose model promises less than
/// 0.1 Φ/n lies within √0.1 ≈ 0.3 of the parameters' 1σ, and a BIC (2Φ/s² = n at the minimum)
/// moves by less than 0.2. A fit along a flat valley — a parameter the data hardly determine,
/// such as a shear-thinning index on a Newtonian body — otherwise took 20 more simulations, each
/// gaining a hundredth of that share (measured on the independent 1,267-tetrahedron cylinder:
/// BENCHMARKS.md, "A fit's precision in its own noise, and a screen that fits only what
/// pays"). A noise-free fit (Φ → 0 at
/// the truth) is unaffected: the relative rule still runs it to the truth.
pub fn precision(residuals: usize) -> f64 {
    if residuals == 0 {
        return 1e-6;
    }
    (0.1 / residuals as f64).max(1e-6)
}

/// Levenberg–Marquardt in z = ln q, a fitted viscosity with its index read at the data's strain
/// rate ([`RateReference`]): palpate's trust-region form of it
/// ([`palpate_fem::lm::minimise_restarting`], held above [`FitSettings::floors`]) on Φ,
/// ∇Φ and the Gauss–Newton matrix of every simulation ([`gauss_newton_runs`]), radius in log space (a factor e to start), stopping at a
/// relative precision max(`tol_cost`, [`precision`]) of Φ (10⁻⁶ for [`precision`] without
/// [`FitSettings::data_precision`]) or after `max_iters` iterations.
fn levenberg_marquardt(
    runs: &[Run<'_>],
    base: &Material,
    params: &[Param],
    z0: &[f64],
    settings: &FitSettings,
    tie: Option<(usize, f64)>,
    progress: &(dyn Fn(usize, f64) + Sync),
) -> Result<FitResult, MotionError> {
    use std::cell::{Cell, RefCell};
    let evaluations = Cell::new(0usize);
    let plain_evaluations = Cell::new(0usize);
    let history = RefCell::new(Vec::new());
    let failures: RefCell<Vec<String>> = RefCell::new(Vec::new());
    let fail = |msg: String| {
        let mut f = failures.borrow_mut();
        if !f.contains(&msg) {
            f.push(msg);
        }
    };
    // Every simulated point with its runs' evaluations and, where the sensitivities were
    // simulated, its Gauss–Newton matrix: the fit's result is one of them, so it needs no
    // simulation of its own.
    let evaluated: RefCell<Vec<(Vec<f64>, Vec<Evaluation>, Option<Vec<f64>>)>> =
        RefCell::new(Vec::new());
    let first_counts = Cell::new(0usize);
    let eval = |z: &[f64]| {
        evaluations.set(evaluations.get() + 1);
        match gauss_newton_runs(runs, base, params, z, tie) {
            Ok((phi, grad, gn, per_run)) if phi.is_finite() => {
                if history.borrow().is_empty() {
                    first_counts.set(
                        per_run
                            .iter()
                            .map(|p| 3 * (p.marker_count + p.force_count))
                            .sum(),
                    );
                }
                history.borrow_mut().push(phi);
                progress(evaluations.get(), phi);
                evaluated
                    .borrow_mut()
                    .push((z.to_vec(), per_run, Some(gn.clone())));
                Some(Normal { phi, grad, gn })
            }
            Ok(_) => {
                failures.borrow_mut().push("Φ is not finite".into());
                None
            }
            Err(e) => {
                fail(e.to_string());
                None
            }
        }
    };
    // Φ alone, by simulations without the sensitivities: a last step's confirmation
    // ([`palpate_fem::lm::CONFIRM_BELOW`]).
    let value = |z: &[f64]| {
        plain_evaluations.set(plain_evaluations.get() + 1);
        let q: Vec<f64> = z.iter().map(|v| v.exp()).collect();
        let mat = problem_material(base, params, &q, tie);
        match evaluate_runs(runs, &mat, params, None) {
            Ok((ev, per_run)) if ev.phi.is_finite() => {
                history.borrow_mut().push(ev.phi);
                evaluated.borrow_mut().push((z.to_vec(), per_run, None));
                Some(ev.phi)
            }
            Ok(_) => None,
            Err(e) => {
                fail(e.to_string());
                None
            }
        }
    };
    let Some(first) = eval(z0) else {
        return Err(MotionError::Invalid(format!(
            "the starting parameters do not simulate: {}",
            failures.borrow().join("; ")
        )));
    };
    let reference = RateReference::from_gauss_newton(params, z0, &first.gn);
    for &(n, h, l) in &reference.pairs {
        log::debug!(
            "{} read at the strain rate {:.4e}/s with {} (from the first Jacobian)",
            params[n].kind.name(),
            l.exp(),
            params[h].kind.name()
        );
    }
    let w0 = reference.coordinates(z0);
    let first = reference.normal_in_coordinates(&w0, first);
    let paired = |i: usize| reference.pairs.iter().any(|&(n, h, _)| i == n || i == h);
    let elastic = ElasticPair::find(params, tie, &settings.floors);
    // The rate pairs are (viscosity, index): they never hold μ or λ, so the two coordinate
    // changes act on disjoint parameters.
    debug_assert!(elastic.is_none_or(|e| !paired(e.mu) && !paired(e.lambda)));
    let mut v0 = w0.clone();
    let first = match elastic {
        Some(e) => {
            e.write_fit_coordinates(&mut v0);
            e.normal_in_fit(&v0, first)
        }
        None => first,
    };
    // The floors in the fit's coordinates: ln f on a global log-parameter outside the rate pairs
    // (a coordinate w = z = ln q there).
    let mut lower: Vec<f64> = params
        .iter()
        .enumerate()
        .map(|(i, p)| {
            settings
                .floors
                .iter()
                .find(|(k, _)| *k == p.kind && p.is_global() && !paired(i))
                .map_or(f64::NEG_INFINITY, |(_, f)| f.ln())
        })
        .collect();
    // A paired h's coordinate is h itself.
    for &(_, h, _) in &reference.pairs {
        lower[h] = POWER_INDEX_FLOOR.min(w0[h]);
    }
    // A free global λ stays at or above LAMBDA_FLOOR_RATIO μ: μ where the fit is when the two
    // are fitted as (ln E, ln(λ/μ)) (b ≥ ln 10⁻³), else μ at the start.
    let global = |k: ParamKind| params.iter().position(|p| p.kind == k && p.is_global());
    if let Some(e) = elastic {
        lower[e.lambda] = lower[e.lambda].max(LAMBDA_FLOOR_RATIO.ln().min(v0[e.lambda]));
    } else if let Some(l) = global(ParamKind::Lambda) {
        let mu0 = global(ParamKind::Mu).map_or_else(|| base.get(ParamKind::Mu, 0), |m| z0[m].exp());
        if mu0.is_finite() && mu0 > 0.0 {
            lower[l] = lower[l].max((LAMBDA_FLOOR_RATIO * mu0).ln().min(w0[l]));
        }
    }
    if log::log_enabled!(log::Level::Debug) {
        // What each component of the logged steps is.
        let names: Vec<String> = (0..params.len())
            .map(|i| {
                let p = &params[i];
                let name = match (p.element, p.region) {
                    (Some(e), _) => format!("{} of element {e}", p.kind.name()),
                    (None, Some(r)) => format!("{} of region {r}", p.kind.name()),
                    (None, None) => p.kind.name().to_string(),
                };
                match elastic {
                    Some(e) if i == e.mu => "ln E".to_string(),
                    Some(e) if i == e.lambda => "ln(λ/μ)".to_string(),
                    _ if reference.pairs.iter().any(|&(_, h, _)| i == h) => name,
                    _ if reference.pairs.iter().any(|&(n, _, _)| i == n) => {
                        format!("ln {name} at the data's strain rate")
                    }
                    _ => format!("ln {name}"),
                }
            })
            .collect();
        log::debug!("fitting in the coordinates [{}]", names.join(", "));
    }
    // The log-coordinates with a floor are tried on it when they run to it: their effect fades
    // as they fall (a Lamé λ that a locking mesh asks to vanish walked ln(λ/μ) to its floor one
    // radius a step: 146 of the 273 iterations of a diagnosis of draw 001 of the motion
    // confusion plan). A paired index h is not: toward its floor the law changes character.
    let probe_bounds = (0..params.len().min(64))
        .filter(|&i| lower[i].is_finite() && !reference.pairs.iter().any(|&(_, h, _)| i == h))
        .fold(0u64, |bits, i| bits | 1 << i);
    // Scalar residuals: three per observed marker position and clamp force.
    let residuals = first_counts.get();
    let options = TrustOptions {
        max_iterations: settings.max_iters as usize,
        rel_tolerance: settings.tol_cost.max(if settings.data_precision {
            precision(residuals)
        } else {
            1e-6
        }),
        noise_tolerance: 1e-5,
        // Φ sums the runs' terms, and so their absolute precisions.
        abs_tolerance: runs.iter().map(|r| r.obs.phi_precision).sum(),
        // A factor e per log-parameter to start, e³ at most.
        initial_radius: 1.0,
        max_radius: 3.0,
        probe_bounds,
    };
    let to_w = |v: &[f64]| {
        let mut w = v.to_vec();
        if let Some(e) = elastic {
            e.write_log_params(&mut w);
        }
        w
    };
    let z_of = |v: &[f64]| {
        let z = reference.log_params(&to_w(v));
        if z.is_none() {
            log::debug!("a step to a power-law index h ≤ 0: rejected unsimulated");
        }
        z
    };
    let mut in_v = |v: &[f64]| {
        let w = to_w(v);
        eval(&z_of(v)?)
            .map(|normal| reference.normal_in_coordinates(&w, normal))
            .map(|normal| match elastic {
                Some(e) => e.normal_in_fit(v, normal),
                None => normal,
            })
    };
    let mut value_in_v = |v: &[f64]| value(&z_of(v)?);
    let out =
        minimise_restarting_confirmed(v0, first, &mut in_v, &mut value_in_v, &options, &lower);
    let iterations = out.iterations;
    let z = z_of(&out.theta).expect("an accepted point has h > 0");
    let (phi, iterations) = (out.normal.phi, iterations as u64);
    let q: Vec<f64> = z.iter().map(|v| v.exp()).collect();
    let mut evaluated = evaluated.into_inner();
    let last_at = |evaluated: &[(Vec<f64>, _, _)], z: &[f64]| {
        evaluated.iter().rposition(|(at, ..)| at.as_slice() == z)
    };
    // A result confirmed by Φ alone takes the Gauss–Newton matrix of the fit's last
    // linearisation, a step within the precision before it.
    let linearised = out
        .linearised_at
        .as_deref()
        .and_then(z_of)
        .and_then(|zl| last_at(&evaluated, &zl))
        .and_then(|i| evaluated[i].2.clone());
    let (ev, per_run, gauss_newton) = match last_at(&evaluated, &z) {
        Some(i) => {
            let (_, parts, gn) = evaluated.swap_remove(i);
            (Evaluation::combine(&parts), parts, gn.or(linearised))
        }
        None => {
            let mat = problem_material(base, params, &q, tie);
            let (ev, parts) = evaluate_runs(runs, &mat, params, None)?;
            (ev, parts, None)
        }
    };
    let mut failures = failures.into_inner();
    if !out.converged {
        failures.push(format!(
            "optimiser stopped: the iteration cap ({}) was reached",
            settings.max_iters
        ));
    }
    Ok(FitResult {
        q,
        phi,
        eval: ev,
        evaluations: evaluations.get(),
        plain_evaluations: plain_evaluations.get(),
        iterations,
        optimizer: Optimizer::LevenbergMarquardt,
        failures,
        history: history.into_inner(),
        runs: per_run,
        gauss_newton,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::{example_bar, example_truth, record};

    /// The fit's coordinates with the viscosity read at the data's strain rate: on the example
    /// bar with a shear-thinning truth (h = 0.8) and a start away from it (h = 0.7, so h ln γ̇_ref
    /// and ln γ̇_ref differ), the gradient carried to w matches central differences of Φ(z(w))
    /// (step 1e-5 in w, to 1e-4 of the largest component), the Gauss–Newton matrix is Tᵀ H T
    /// with T = ∂z/∂w built entry by entry, the ν and h columns are decorrelated, and w ↔ z
    /// round-trips.
    #[test]
    fn rate_reference_gradient_matches_finite_differences() {
        let (_, mut model) = example_bar([1, 4, 1], 30).unwrap();
        // Newton solved far below its default, so the differences see the scheme, not its noise.
        model.newton.tol = 1e-11;
        let params = Param::globals(&[ParamKind::Mu, ParamKind::Nu, ParamKind::PowerH]);
        let mut truth = example_truth(&model);
        truth.set(&params, &[2.0e4, 12.0, 0.8]);
        let mut obs = record(&model, &truth, 1e-4, 3).unwrap();
        obs.forces.clear();
        let runs = [Run {
            model: &model,
            obs: &obs,
        }];
        let z: Vec<f64> = [1.4e4f64, 30.0, 0.7].iter().map(|q| q.ln()).collect();
        let (phi, grad, gn, _) = gauss_newton_runs(&runs, &truth, &params, &z, None).unwrap();
        let reference = RateReference::from_gauss_newton(&params, &z, &gn);
        assert_eq!(reference.pairs.len(), 1);
        let (n, h, ln_rate) = reference.pairs[0];
        assert!(
            ln_rate.abs() > 0.1,
            "ln γ̇_ref {ln_rate}: too near 1/s to test"
        );
        let w = reference.coordinates(&z);
        let back = reference.log_params(&w).unwrap();
        assert!(back.iter().zip(&z).all(|(a, b)| (a - b).abs() < 1e-12));
        let at_w = reference.normal_in_coordinates(
            &w,
            Normal {
                phi,
                grad: grad.clone(),
                gn: gn.clone(),
            },
        );

        let phi_at = |w: &[f64]| {
            let q: Vec<f64> = reference
                .log_params(w)
                .unwrap()
                .iter()
                .map(|v| v.exp())
                .collect();
            let mat = problem_material(&truth, &params, &q, None);
            evaluate_runs(&runs, &mat, &params, None).unwrap().0.phi
        };
        let scale = at_w.grad.iter().fold(0.0f64, |m, g| m.max(g.abs()));
        let eps = 1e-5;
        for k in 0..params.len() {
            let shifted = |d: f64| {
                let mut v = w.clone();
                v[k] += d;
                phi_at(&v)
            };
            let fd = (shifted(eps) - shifted(-eps)) / (2.0 * eps);
            assert!(
                (at_w.grad[k] - fd).abs() <= 1e-4 * scale,
                "dΦ/dw[{k}] = {} against finite differences {fd}",
                at_w.grad[k]
            );
        }

        let np = params.len();
        let mut t = vec![0.0; np * np];
        for i in 0..np {
            t[i * np + i] = 1.0;
        }
        t[h * np + h] = 1.0 / z[h].exp();
        t[n * np + h] = -ln_rate;
        let hmax = gn.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for a in 0..np {
            for b in 0..np {
                let mut s = 0.0;
                for i in 0..np {
                    for j in 0..np {
                        s += t[i * np + a] * gn[i * np + j] * t[j * np + b];
                    }
                }
                assert!(
                    (at_w.gn[a * np + b] - s).abs() <= 1e-12 * hmax,
                    "H_w[{a}][{b}] = {} against TᵀHT {s}",
                    at_w.gn[a * np + b]
                );
            }
        }
        let corr = at_w.gn[n * np + h] / (at_w.gn[n * np + n] * at_w.gn[h * np + h]).sqrt();
        assert!(corr.abs() < 1e-9, "ν and h columns correlate: {corr}");
    }

    /// The (ln E, ln(λ/μ)) coordinates: a = ln E with E = μ(3λ + 2μ)/(λ + μ), (a, b) ↔ (ln μ,
    /// ln λ) round-trips from λ/μ = 10⁻⁶ to 10⁶, and the gradient and Gauss–Newton matrix carried
    /// to (a, b) are those of central differences of residuals r(ln μ, ln λ, x) made of them
    /// (a nonlinear r with a third coordinate the pair leaves alone).
    #[test]
    fn elastic_pair_coordinates_match_finite_differences() {
        let pair = ElasticPair { mu: 2, lambda: 0 };
        for ratio in [1e-6f64, 1e-3, 0.5, 9.0, 1e3, 1e6] {
            let (mu, lambda) = (7.0e5f64, 7.0e5 * ratio);
            let w = [lambda.ln(), 0.3, mu.ln()];
            let mut v = w;
            pair.write_fit_coordinates(&mut v);
            let e = mu * (3.0 * lambda + 2.0 * mu) / (lambda + mu);
            assert!(
                (v[2] - e.ln()).abs() < 1e-12,
                "a = {} against ln E {}",
                v[2],
                e.ln()
            );
            assert!((v[0] - ratio.ln()).abs() < 1e-12);
            assert_eq!(v[1], 0.3);
            let mut back = v;
            pair.write_log_params(&mut back);
            for k in 0..3 {
                assert!((back[k] - w[k]).abs() < 1e-12, "{back:?} against {w:?}");
            }
        }
        // r(w): five residuals, nonlinear in each coordinate.
        let r = |w: &[f64]| -> Vec<f64> {
            let (l, x, m) = (w[0], w[1], w[2]);
            vec![
                (m + 0.3 * l).sin() - 0.2,
                m * m - 0.1 * l,
                (0.5 * l).exp() - x,
                x * m + l,
                (l - m).cos() * x,
            ]
        };
        let jac = |f: &dyn Fn(&[f64]) -> Vec<f64>, at: &[f64]| -> Vec<Vec<f64>> {
            (0..3)
                .map(|k| {
                    let (mut p, mut q) = (at.to_vec(), at.to_vec());
                    p[k] += 1e-6;
                    q[k] -= 1e-6;
                    let (fp, fq) = (f(&p), f(&q));
                    fp.iter().zip(&fq).map(|(a, b)| (a - b) / 2e-6).collect()
                })
                .collect()
        };
        let normal_of = |res: &[f64], j: &[Vec<f64>]| Normal {
            phi: 0.5 * res.iter().map(|v| v * v).sum::<f64>(),
            grad: (0..3)
                .map(|a| j[a].iter().zip(res).map(|(x, y)| x * y).sum())
                .collect(),
            gn: (0..9)
                .map(|ab| j[ab / 3].iter().zip(&j[ab % 3]).map(|(x, y)| x * y).sum())
                .collect(),
        };
        let w = [1.1f64, 0.4, 0.7];
        let mut v = w;
        pair.write_fit_coordinates(&mut v);
        let carried = pair.normal_in_fit(&v, normal_of(&r(&w), &jac(&r, &w)));
        let r_v = |v: &[f64]| {
            let mut w = v.to_vec();
            pair.write_log_params(&mut w);
            r(&w)
        };
        let direct = normal_of(&r_v(&v), &jac(&r_v, &v));
        for (what, a, b) in [
            ("∇", &carried.grad, &direct.grad),
            ("H", &carried.gn, &direct.gn),
        ] {
            for (k, (x, y)) in a.iter().zip(b.iter()).enumerate() {
                assert!((x - y).abs() < 1e-7, "{what} {k}: {x} against {y}");
            }
        }
    }
}
