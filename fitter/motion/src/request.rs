//! A motion fit as a user asks for it (`palpate fit-motion`): one or several runs of one object,
//! the parameters to fit (global or per element), starting values, the optimiser's settings →
//! the fitted material, its `fit.json` record, the summary a person reads, and the result's
//! sanity findings. The command only parses its flags, calls [`fit`] (or [`fit_equilibria`])
//! and prints or writes what comes back.

use crate::dataset::{DatasetError, MotionDataset};
use crate::fitted::{FittedModel, FittedRun};
use crate::model::{Material, Param, ParamKind};
use crate::optimize::{fit_runs, FitResult, FitSettings, Optimizer, Run};
use crate::{predict, MotionError};
use palpate_fem::export::{ExportError, ModelBuffers, ProvenanceInfo};
use palpate_fem::numbers;
use palpate_fem::sanity::Findings;
use palpate_runtime::material::LambdaAlpha;
use std::fmt;
use std::path::Path;

/// Density assumed when a dataset gives none and the fit does not estimate it (kg/m³).
pub const DEFAULT_DENSITY: f64 = 1000.0;

/// Named runs of one object, loaded: the name is what reports and `fit.json` call the run
/// (its folder, as the user typed it).
pub struct NamedRun {
    /// The run's name in reports.
    pub name: String,
    /// The loaded dataset.
    pub dataset: MotionDataset,
}

impl NamedRun {
    /// Loads the motion dataset at `dir`, named as the user typed it.
    pub fn load(dir: &Path) -> Result<Self, DatasetError> {
        Ok(Self {
            name: dir.display().to_string(),
            dataset: crate::dataset::load(dir)?,
        })
    }
}

/// What to fit and how.
#[derive(Debug, Clone, Default)]
pub struct FitRequest {
    /// Global parameters to fit, in the order given.
    pub params: Vec<ParamKind>,
    /// Per-element parameters (λ, μ or density), with neighbour smoothness.
    pub per_element: Vec<ParamKind>,
    /// Starting values overriding the first dataset's `[initial]` table; when empty, the start
    /// is estimated from the data (`crate::start`).
    pub initial: Vec<(ParamKind, f64)>,
    /// Hanging weights also add their inertia.
    pub hanging_inertia: bool,
    /// The optimiser's settings (Poisson's ratio held when `settings.poisson` is set).
    pub settings: FitSettings,
}

/// A fitted motion model and everything the command shows or writes of it.
pub struct FitOutcome {
    /// The fitted material (every parameter, fitted or held).
    pub fitted: Material,
    /// The fitted parameters.
    pub params: Vec<Param>,
    /// The optimiser's result.
    pub result: FitResult,
    /// The `fit.json` record (`palpate validate` reads it).
    pub record: FittedModel,
    /// The result's gates: errors refuse it, warnings say it is written with doubts.
    pub findings: Findings,
    summary: Summary,
}

/// What the summary table needs besides the fitted material.
struct Summary {
    names: Vec<String>,
    tets: usize,
    steps: Vec<usize>,
    dt: f64,
    markers: usize,
    poisson: Option<f64>,
}

/// Checks that the runs share one mesh (one object, one material) and returns the first.
fn first_of_one_object(runs: &[NamedRun]) -> Result<&MotionDataset, MotionError> {
    let first = &runs
        .first()
        .ok_or_else(|| MotionError::Invalid("no runs to fit".into()))?
        .dataset;
    for r in &runs[1..] {
        if r.dataset.mesh.nodes != first.mesh.nodes || r.dataset.mesh.tets != first.mesh.tets {
            return Err(MotionError::Invalid(format!(
                "{}: its mesh differs from {}'s: the runs of one fit share one mesh and material",
                r.name, runs[0].name
            )));
        }
    }
    Ok(first)
}

/// The starting material: the first dataset's `[initial]` table, or a start estimated from the
/// data when no value is given, then the given values.
fn starting_material(ds: &MotionDataset, req: &FitRequest) -> Material {
    let mut init = ds.config.initial.clone();
    if req.initial.is_empty() {
        let start = crate::start::initial_values(ds, req.settings.poisson);
        log::info!("{}", start.note);
        (init.lambda, init.mu, init.nu, init.h) =
            (start.lambda, start.mu, start.viscosity, start.h);
    }
    let mut stiffening = None;
    for &(kind, v) in &req.initial {
        match kind {
            ParamKind::Lambda => init.lambda = v,
            ParamKind::Mu => init.mu = v,
            ParamKind::Nu => init.nu = v,
            ParamKind::PowerH => init.h = v,
            ParamKind::Stiffening => stiffening = Some(v),
            _ => {}
        }
    }
    let density = ds.config.density.unwrap_or(DEFAULT_DENSITY);
    let mut base = Material::uniform(
        ds.model.tets.len(),
        init.lambda,
        init.mu,
        init.nu,
        init.h,
        density,
    );
    base.viscous_form = ds.model.viscous_form;
    // The stiffening is 0 (eq. 16) unless given or fitted; fitted in ln c, it needs a start
    // above 0: c = μ unless given (at 10 % strain that adds about 6 % to the Neo-Hookean energy).
    let fits_stiffening = req.params.contains(&ParamKind::Stiffening);
    if let Some(c) = stiffening.or(fits_stiffening.then_some(init.mu)) {
        base.set_uniform(ParamKind::Stiffening, c);
    }
    base
}

/// The parameter list: the global ones, then each per-element kind over every element.
fn parameter_list(req: &FitRequest, elements: usize) -> Result<Vec<Param>, MotionError> {
    let mut params: Vec<Param> = req.params.iter().map(|&k| Param::global(k)).collect();
    for &kind in &req.per_element {
        if !matches!(kind, ParamKind::Lambda | ParamKind::Mu | ParamKind::Density) {
            return Err(MotionError::Invalid(format!(
                "--per-element: {:?} is not one of lambda, mu, density",
                kind.name()
            )));
        }
        if params.iter().any(|p| p.kind == kind) {
            return Err(MotionError::Invalid(format!(
                "{} is both global and per-element",
                kind.name()
            )));
        }
        params.extend((0..elements).map(|e| Param::of_element(kind, e)));
    }
    if params.is_empty() {
        return Err(MotionError::Invalid("no parameters to fit".into()));
    }
    Ok(params)
}

/// Fits one material to the runs (Real2Sim §4; `crate::optimize::fit_runs`) and gathers what the
/// command reports. `progress(simulations, Φ)` is called as the optimiser goes.
pub fn fit(
    runs: &mut [NamedRun],
    req: &FitRequest,
    progress: &(dyn Fn(usize, f64) + Sync),
) -> Result<FitOutcome, MotionError> {
    if req.hanging_inertia {
        for r in runs.iter_mut() {
            crate::fitted::set_hanging_inertia(&mut r.dataset.model, true);
        }
    }
    let ds = first_of_one_object(runs)?;
    let ne = ds.model.tets.len();
    let base = starting_material(ds, req);
    let params = parameter_list(req, ne)?;
    if ds.config.density.is_none() && !params.iter().any(|p| p.kind == ParamKind::Density) {
        log::info!("note: density not given in dataset.toml; using 1000 kg/m³");
    }
    let q0 = base.read(&params);
    let fit_inputs: Vec<Run> = runs
        .iter()
        .map(|r| Run {
            model: &r.dataset.model,
            obs: &r.dataset.obs,
        })
        .collect();
    let r = fit_runs(
        &fit_inputs,
        &base,
        &params,
        &q0,
        &req.settings,
        &ds.mesh.face_neighbours(),
        progress,
    )?;
    let mut fitted = base.clone();
    fitted.set(&params, &r.q);
    if let (Some(nu), Some(mu)) = (
        req.settings.poisson,
        params.iter().position(|p| p.kind == ParamKind::Mu),
    ) {
        fitted.set(
            &[Param::global(ParamKind::Lambda)],
            &[2.0 * nu / (1.0 - 2.0 * nu) * r.q[mu]],
        );
    }
    let findings = result_gates(&fitted, &r, &q0, ds.model.steps, req.settings.max_iters);
    let record = record(runs, req, &fitted, &params, &r);
    let summary = Summary {
        names: runs.iter().map(|r| r.name.clone()).collect(),
        tets: ne,
        steps: runs.iter().map(|r| r.dataset.model.steps).collect(),
        dt: ds.model.dt,
        markers: ds.model.markers.len(),
        poisson: req.settings.poisson,
    };
    Ok(FitOutcome {
        fitted,
        params,
        result: r,
        record,
        findings,
        summary,
    })
}

impl FitOutcome {
    /// The fit as a runtime model (`.palp`) on `run`'s mesh and clamps (the first of the runs
    /// fitted: they share them), its provenance naming `tool` (the command line that made it),
    /// the runs and the fit's errors and effort. `matched`: the runtime's parameters fitted to
    /// the converged material and what their provenance says; `None` exports the fit's own
    /// moduli at rest.
    pub fn runtime_model(
        &self,
        run: &MotionDataset,
        tool: String,
        matched: Option<(&palpate_fem::forward::Material, &str)>,
    ) -> Result<ModelBuffers, ExportError> {
        let r = &self.result;
        let prov = ProvenanceInfo {
            tool,
            source: self.record.datasets.join(" + "),
            notes: format!(
                "fit-motion: RMS marker {:.4e} m, RMS force {:.4e} N, {} simulations",
                r.eval.rms_marker, r.eval.rms_force, r.evaluations
            ),
        };
        match matched {
            None => crate::export::model_buffers(&run.mesh, &run.model, &self.fitted, &prov),
            Some((params, how)) => crate::export::model_buffers_with(
                &run.mesh,
                &run.model,
                &self.fitted,
                params,
                Some(how),
                &prov,
            ),
        }
    }
}

/// The result's gates: elastic parameters at the bounds of what a soft object can be refuse the
/// export; Newton steps that never met their tolerance and an optimiser stopped by its cap are
/// warnings (said loudly by the command, exit status 2).
fn result_gates(
    fitted: &Material,
    r: &FitResult,
    q0: &[f64],
    steps: usize,
    max_iters: u64,
) -> Findings {
    let elastic: Vec<palpate_fem::forward::Material> =
        (0..fitted.values[0].len().max(fitted.values[1].len()))
            .map(|e| {
                let at = |k: usize| fitted.values[k][e.min(fitted.values[k].len() - 1)];
                palpate_fem::forward::Material::homogeneous(LambdaAlpha::from_lame(at(0), at(1)))
            })
            .collect();
    let mut findings = Findings::default();
    for (e, m) in elastic.iter().enumerate() {
        for mut f in palpate_fem::sanity::check_material(std::slice::from_ref(m)).0 {
            if elastic.len() > 1 {
                f.message = format!("element {e}: {}", f.message);
            }
            findings.0.push(f);
        }
    }
    let stats = r.eval.stats;
    if stats.unconverged_steps > 0 {
        findings.warn(
            "newton-not-converged",
            format!(
                "{} of {} time steps of the fitted simulation did not meet the Newton tolerance \
                 (largest residual {:.3e} N): the fitted trajectory is not an accurate solution",
                stats.unconverged_steps, steps, stats.max_residual
            ),
        );
    }
    findings.extend(palpate_fem::sanity::check_iterations(
        optimizer_name(r.optimizer),
        r.iterations as usize,
        max_iters as usize,
        r.iterations < max_iters,
    ));
    // A fit that never left its start (nothing in the data pulled on it) or ended at infinity
    // is no result.
    if r.q == q0 {
        findings.error(
            "fit-did-not-move",
            format!(
                "the fit ended on its starting values after {} simulation(s): the data did not \
                 move it, so writing it would pass the start off as a measurement (check the \
                 weights, units and frame of the dataset)",
                r.evaluations
            ),
        );
    }
    if !(r.q.iter().all(|v| v.is_finite())
        && r.eval.rms_marker.is_finite()
        && r.eval.rms_force.is_finite())
    {
        findings.error(
            "non-finite-fit",
            format!(
                "the fit ended at infinity or NaN (RMS marker error {:.3e} m, force {:.3e} N)",
                r.eval.rms_marker, r.eval.rms_force
            ),
        );
    }
    findings
}

/// The `fit.json` record of a fit.
fn record(
    runs: &[NamedRun],
    req: &FitRequest,
    fitted: &Material,
    params: &[Param],
    r: &FitResult,
) -> FittedModel {
    let ds = &runs[0].dataset;
    FittedModel {
        format: crate::fitted::FORMAT.into(),
        datasets: runs.iter().map(|r| r.name.clone()).collect(),
        nodes: ds.mesh.nodes.len(),
        tets: ds.model.tets.len(),
        lambda: fitted.values[0].clone(),
        mu: fitted.values[1].clone(),
        viscosity: fitted.values[2].clone(),
        h: fitted.values[3].clone(),
        density: fitted.values[4].clone(),
        stiffening: FittedModel::stiffening_of(fitted),
        creep: crate::fitted::CreepRecord::of(fitted),
        viscosity_form: fitted.viscous_form,
        poisson_fixed: req.settings.poisson,
        hanging_inertia: req.hanging_inertia
            || runs
                .iter()
                .any(|r| r.dataset.model.loads.iter().any(|l| l.inertia)),
        time_offset: false,
        load_lever_m: runs
            .iter()
            .map(|r| r.dataset.model.load_lever())
            .find(|d| *d != 0.0),
        gravity_turn: FittedModel::gravity_turn_of(fitted),
        fitted: params
            .iter()
            .map(|p| p.kind.name().to_string())
            .collect::<std::collections::BTreeSet<_>>()
            .into_iter()
            .collect(),
        runtime_lambda_alpha: fitted.values[0]
            .iter()
            .zip(&fitted.values[1])
            .map(|(l, m)| {
                let a = LambdaAlpha::from_lame(*l, *m);
                [a.lambda, a.alpha]
            })
            .collect(),
        rms_marker_m: r.eval.rms_marker,
        rms_force_n: r.eval.rms_force,
        evaluations: r.evaluations,
        runs: runs
            .iter()
            .zip(&r.runs)
            .map(|(run, e)| {
                let d = &run.dataset;
                let rest = predict::rest_markers(&d.model);
                FittedRun {
                    dataset: run.name.clone(),
                    load_n: predict::load_along_gravity(&d.model),
                    rms_marker_m: e.rms_marker,
                    time_offset_s: 0.0,
                    markers: d.model.markers.iter().map(|m| m.name.clone()).collect(),
                    final_displacement_m: predict::final_observed(&d.model, &d.obs)
                        .iter()
                        .zip(&rest)
                        .map(|(f, r0)| f.map(|p| [0, 1, 2].map(|k| p[k] - r0[k])))
                        .collect(),
                }
            })
            .collect(),
        converged: None,
    }
}

/// The optimiser's name in reports.
pub fn optimizer_name(o: Optimizer) -> &'static str {
    match o {
        Optimizer::Lbfgs => "LBFGS",
        _ => "Levenberg–Marquardt",
    }
}

/// The summary table a person reads (Markdown): errors, effort, every parameter, E and ν, and
/// the thesis pair the runtime stores.
impl fmt::Display for FitOutcome {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (s, r, fitted) = (&self.summary, &self.result, &self.fitted);
        let steps: Vec<String> = s.steps.iter().map(usize::to_string).collect();
        writeln!(
            f,
            "fit-motion {}: {} tets, {} steps of {} s, {} markers",
            s.names.join(" + "),
            s.tets,
            steps.join(" + "),
            s.dt,
            s.markers
        )?;
        writeln!(f, "| quantity | value |\n|---|---|")?;
        writeln!(
            f,
            "| RMS marker error √(2Φ/(NT)) | {:.4} mm |",
            r.eval.rms_marker * 1e3
        )?;
        writeln!(
            f,
            "| RMS force error | {} N |",
            numbers::plain(r.eval.rms_force)
        )?;
        if s.names.len() > 1 {
            for (name, e) in s.names.iter().zip(&r.runs) {
                writeln!(
                    f,
                    "| RMS marker error, {name} | {:.4} mm |",
                    e.rms_marker * 1e3
                )?;
            }
        }
        writeln!(
            f,
            "| simulations / {} iterations | {} / {} |",
            optimizer_name(r.optimizer),
            r.evaluations,
            r.iterations
        )?;
        for k in ParamKind::ALL {
            let v = &fitted.values[k as usize];
            let mean = v.iter().sum::<f64>() / v.len() as f64;
            let (lo, hi) = v
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                    (a.min(*x), b.max(*x))
                });
            let tag = if self.params.iter().any(|p| p.kind == k) {
                "fitted"
            } else if k == ParamKind::Lambda && s.poisson.is_some() {
                "from μ at the fixed Poisson's ratio"
            } else {
                "fixed"
            };
            // The label's unit ("shear modulus μ (Pa)") picks one unit for the three figures.
            let (name, unit) = match k.label().rsplit_once(" (") {
                Some((n, u)) if u.ends_with(')') => (n, u.trim_end_matches(')')),
                _ => (k.label(), ""),
            };
            let (unit, size) = numbers::unit_for(mean, unit);
            let q = |v: f64| {
                let v = numbers::plain(v / size);
                if unit.is_empty() {
                    v
                } else {
                    format!("{v} {unit}")
                }
            };
            writeln!(
                f,
                "| {name} ({tag}) | mean {} (min {}, max {}) |",
                q(mean),
                q(lo),
                q(hi)
            )?;
        }
        let la = LambdaAlpha::from_lame(
            fitted.get(ParamKind::Lambda, 0),
            fitted.get(ParamKind::Mu, 0),
        );
        writeln!(
            f,
            "| Young's modulus E, Poisson's ratio ν (element 0) | {}, {:.4} |",
            numbers::pressure(la.young()),
            la.poisson()
        )?;
        writeln!(
            f,
            "| {} of element 0, as exported | {}, {} |",
            palpate_fem::names::THESIS_PAIR,
            numbers::pressure(la.lambda),
            numbers::pressure(la.alpha)
        )?;
        write!(f, "\n{}", palpate_fem::names::THESIS_PAIR_NOTE)
    }
}

/// μ fitted to where the runs came to rest (their equilibria under their loads, no dynamics),
/// Poisson's ratio held.
pub struct Equilibria {
    /// Runs used.
    pub runs: usize,
    /// Shear modulus μ (Pa) and its 1σ (independent residuals).
    pub mu: (f64, f64),
    /// Poisson's ratio, held.
    pub poisson: f64,
    /// RMS of the rest-state residual (m).
    pub rms_m: f64,
}

/// Poisson's ratio held by [`fit_equilibria`] when the request holds none: a nearly
/// incompressible soft solid.
pub const EQUILIBRIA_POISSON: f64 = 0.49;

/// Fits μ alone to the runs' rest states (`crate::predict::fit_equilibria`), Poisson's ratio
/// held at the request's (or [`EQUILIBRIA_POISSON`]), from the request's starting μ or else the
/// first run's `[initial]` μ.
pub fn fit_equilibria(runs: &[NamedRun], req: &FitRequest) -> Result<Equilibria, MotionError> {
    let poisson = req.settings.poisson.unwrap_or(EQUILIBRIA_POISSON);
    let ds = first_of_one_object(runs)?;
    let init = &ds.config.initial;
    let mu0 = req
        .initial
        .iter()
        .find(|(k, _)| *k == ParamKind::Mu)
        .map_or(init.mu, |(_, v)| *v);
    let mut base = Material::uniform(
        ds.model.tets.len(),
        init.lambda,
        mu0,
        0.0,
        1.0,
        ds.config.density.unwrap_or(DEFAULT_DENSITY),
    );
    base.viscous_form = ds.model.viscous_form;
    let pairs: Vec<_> = runs
        .iter()
        .map(|r| (&r.dataset.model, &r.dataset.obs))
        .collect();
    let (mu, rms, sd) = predict::fit_equilibria(&pairs, &base, poisson, mu0)?;
    Ok(Equilibria {
        runs: runs.len(),
        mu: (mu, sd),
        poisson,
        rms_m: rms,
    })
}

impl fmt::Display for Equilibria {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let ((mu, sd), nu) = (self.mu, self.poisson);
        let (mu_v, mu_sd) = numbers::value_and_sd(mu, sd, "Pa");
        let (e_v, e_sd) = numbers::value_and_sd(2.0 * (1.0 + nu) * mu, 2.0 * (1.0 + nu) * sd, "Pa");
        write!(
            f,
            "equilibria of {} runs: μ = {} ± {} (1σ, independent residuals), E = {} ± {} at Poisson's ratio {nu} (held); rest-state RMS {:.3} mm",
            self.runs,
            mu_v,
            mu_sd,
            e_v,
            e_sd,
            1e3 * self.rms_m
        )
    }
}
