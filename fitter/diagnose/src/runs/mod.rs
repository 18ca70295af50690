//! Residual diagnosis of several runs of one object — a capture rig's loads and repeats (the
//! clamped silicone beam released under its own weight and with a hanging weight): fit the
//! simplest model to some runs, read the residual of every run per marker and per step, hold each
//! candidate effect against it by refitting, and keep what predicts the *other* runs better.
//!
//! **Held-out data = other runs.** The fitted runs and the held-out runs are named by the user
//! (the repeats of the same loads, or another load). A candidate must predict runs it was not
//! fitted to, the way the model will be used (`palpate validate`).
//!
//! **The simplest model.** Neo-Hookean with Poisson's ratio held at
//! [`RunsOptions::poisson`] (the markers of a bending test see the deflection, not the volume
//! change: λ is not identifiable, and silicone is nearly incompressible), μ fitted, no
//! viscosity (held at 0), density and loads as declared, a weight hung from the release moving
//! with its nodes (its declared mass lumped on them; [`RunsOptions::weights_move`]). Its one
//! coordinate is searched on the misfit of plain simulations (`fit.rs`'s `search_modulus`).
//!
//! **Candidates** ([`Effect`], one file each in `candidates/`): Newtonian viscosity (ν free, h = 1), power-law viscosity (ν and h
//! free, eq. 17), a time offset of each run's markers against the simulation's clock (one
//! integer number of steps per run, [`palpate_motion::time_offset`]: the release instant an import
//! reads off the capture is uncertain by a frame or two), a strain stiffening, a creep branch,
//! where the hanging weights act, and a clamp that gives (the elements at the clamps softened as
//! a whole, their μ fitted beside the global kinds: `fit.rs`'s `region_params`). Each is fitted on top
//! of the current model (all its material parameters refitted). On request the weights' inertia
//! too (`hanging-inertia`, no new parameter): the simplest model then holds the weights as
//! forces only.
//!
//! **The time offset** is found by a scan, not a descent (the misfit of a ring-down has a minimum
//! every period): each fitted run's offset is scanned with the current material, the material
//! refitted with the offsets held, the offsets scanned again with the refitted material and, if
//! one moved, the material refitted once more. A held-out run is a new capture with its own
//! release: it gets its own offset, scanned with the candidate's material (the material is never
//! fitted to it), and the held-out gate counts those offsets as parameters. Once adopted, the
//! offsets start every later candidate's fit and are scanned again after it.
//!
//! **Adoption rule** (the motion diagnosis' rule, [`crate::motion`]): with n scalar marker
//! residuals of the fitted runs, χ² their sum of squares and k the free parameters,
//! BIC = n ln(χ²/n) + k ln n. A candidate passes if (a) ΔBIC < −[`RunsOptions::bic_threshold`],
//! (b) on the held-out runs n_h ln(χ²_h,new/χ²_h,old) + Δk ln n_h < 0, and (c) the held-out RMS
//! marker error drops by at least [`RunsOptions::min_holdout_gain`]. The first passing candidate
//! in fitted-ΔBIC order is adopted; repeat until none passes ([`crate::select`]).
//!
//! **The fit screen** ([`RunsOptions::screen`], [`crate::screen`]): before a round's fits, one
//! Gauss–Newton evaluation of the fitted runs at the current fit, with the damping's and the
//! stiffening's parameters at their neutral values (ν = 0, h = 1, c = 0: the current model),
//! predicts each of them by the χ² drop of one Gauss–Newton step over the current parameters
//! and its own. The power-law index has no effect at ν = 0, so the power law is predicted as
//! Newtonian damping with one more parameter; on an undamped model a damping law is predicted
//! by the better of that step and one from its fit's start, the runs linearised there too
//! (`screen.rs`). The hanging weights' inertia (on request), a
//! switch with no neutral value to linearise about, is always fitted; the time offset is predicted by its scan
//! at the current material (its fit starts from that scan, which is not repeated), without the
//! material's refit; the clamp's give by the column of the layer's own μ in the same evaluation
//! (the layer held there at the body's moduli). A step that takes a parameter bounded at its neutral value (ν, c, g ≥ 0)
//! below its bound is taken again with that parameter held there; a candidate whose every new
//! parameter is so held is the current model and predicts no gain. The best predicted are fitted
//! in full (the screen's `least`, and those within its `margin` of the best), among them only
//! those predicted to pay (ΔBIC below the gate's −threshold); the rest are reported with their
//! predicted ΔBIC, and fitted after all if nothing fitted passes the gate.
//!
//! **The residual's signature** ([`RunResidual`], `signature.rs`): per run, the RMS per marker, in the first and
//! last quarter of the run, and — on the marker that moves most — the ring-down's period and its
//! amplitude ratio per cycle, measured and simulated. A period the model gets wrong points at the
//! stiffness or the mass; a decay it gets wrong at the damping.

mod candidates;
mod fit;
pub mod report;
pub mod run;
mod screen;
mod select;
mod signature;

use crate::select::{select, ParamValue, Policy, Progress, Rank, Screen, Stop};
use fit::RunsModel;
use palpate_motion::dataset::MotionDataset;
use palpate_motion::fitted::{FittedModel, FittedRun};
use palpate_motion::model::{Material, Observations, Param, ParamKind};
use palpate_motion::optimize::Run;
use palpate_motion::predict;
use palpate_motion::time_offset;
use palpate_motion::MotionError;
use serde::Serialize;

pub use candidates::clamp_compliance::ClampLayer;
pub use candidates::{default_effects, Effect, ALL_EFFECTS};
pub use signature::{residual, ring_down, viscosity_from_ring_down, RunResidual};

/// The runs diagnosis's errors: the crate's one [`crate::Error`] (the name kept for its callers).
pub type RunsError = crate::Error;

/// Options of [`diagnose_runs`].
#[derive(Debug, Clone, Serialize)]
pub struct RunsOptions {
    /// Candidates to try ([`default_effects`]; naming [`Effect::HangingInertia`] among them
    /// takes the weights' inertia out of the simplest model, [`Self::weights_move`]).
    pub candidates: Vec<Effect>,
    /// Most effects adopted.
    pub max_effects: usize,
    /// Optimiser iteration cap of the simplest model's fit and of an adopted candidate's.
    pub max_iters: u64,
    /// Optimiser iteration cap of a candidate's screening fit: a fit that crawls (a new elastic
    /// parameter on an undamped ring-down took 40 iterations on the measured beam) is scored
    /// where it stands, which can only under-state its gain; the candidate a round adopts is
    /// refitted to `max_iters` first.
    pub screen_max_iters: u64,
    /// Poisson's ratio held fixed.
    pub poisson: f64,
    /// Starting shear modulus of the simplest model (Pa).
    pub start_mu: f64,
    /// Starting viscosity when a damping effect frees it (Pa·s^h); `None`: from the fitted runs'
    /// measured ring-downs ([`viscosity_from_ring_down`]), 10 Pa·s where none rings.
    pub start_viscosity: Option<f64>,
    /// Fitted ΔBIC must be below −this.
    pub bic_threshold: f64,
    /// Held-out RMS must drop by at least this fraction.
    pub min_holdout_gain: f64,
    /// Predict each round's candidates before fitting them and fit only the best predicted
    /// (module note); `false`: fit every open candidate (the full search).
    pub screen: bool,
    /// With the screen: fewest candidates fitted per round. One: a runner-up predicted to gain
    /// less than `screen_margin` of the best predicted one's ΔBIC is not fitted beside it, but is
    /// predicted again next round from the model the best one made (or fitted as the fall-back
    /// when the best fails the gate). On the measured beam the runner-up of the second round,
    /// the stiffening at a quarter of the creep's predicted gain, cost about a fifth of the
    /// diagnosis' time and is predicted to gain nothing once the creep is in.
    pub screen_least: usize,
    /// With the screen: a candidate is fitted when its predicted ΔBIC is within this fraction of
    /// the best predicted one's magnitude.
    pub screen_margin: f64,
    /// Fit the fitted runs' rest states on linear and quadratic elements after the diagnosis
    /// ([`crate::convergence`]): whether the fitted modulus is the material's or the mesh's.
    pub mesh_convergence: bool,
    /// Refit the final model on quadratic elements ([`crate::motion_convergence`]): whether the
    /// fitted modulus and viscosity are the material's or the mesh's. About a minute on the
    /// beam's coarse mesh (two cores), more than the rest of a diagnosis: off by default.
    pub motion_convergence: bool,
}

impl RunsOptions {
    /// Whether the simplest model moves each hung weight with its nodes (its declared mass), as
    /// it does unless the candidates name the weights' inertia: then the simplest model holds
    /// the weights as forces only and the diagnosis is asked to find their mass in the
    /// ring-down's period. A weight hung from the release is declared with its mass; that it
    /// moves with the body is no effect to find. Held as a candidate it cost the measured beam's
    /// diagnosis a quarter of its simulations (an undamped model with the mass fitted in the
    /// first round only to fail, adopted in the second) for the same final model.
    pub fn weights_move(&self) -> bool {
        !self.candidates.contains(&Effect::HangingInertia)
    }
}

impl Default for RunsOptions {
    fn default() -> Self {
        Self {
            candidates: default_effects(),
            // Damping (one of its two laws), the time offset, the stiffening and the creep can
            // all be in one model.
            max_effects: 4,
            max_iters: 40,
            screen_max_iters: 15,
            poisson: 0.49,
            start_mu: 5e4,
            start_viscosity: None,
            bic_threshold: 10.0,
            min_holdout_gain: 0.05,
            screen: true,
            screen_least: 1,
            screen_margin: 0.5,
            mesh_convergence: true,
            motion_convergence: false,
        }
    }
}

/// A fitted model of the runs.
#[derive(Debug, Clone)]
pub struct RunsFit {
    /// Effects in the model, in the order adopted.
    pub effects: Vec<Effect>,
    /// The fitted material.
    pub material: Material,
    /// Fitted parameter kinds (μ first).
    pub kinds: Vec<ParamKind>,
    /// Time offset of each fitted run (steps; all 0 without the time offset).
    pub offsets: Vec<i64>,
    /// Residuals of the fitted runs.
    pub fitted: Vec<RunResidual>,
    /// Φ of the fitted runs at the fitted material, as the fit simulated it.
    pub phi: f64,
    /// Φ's Gauss–Newton matrix at the fitted material in z = ln q over the fitted parameters
    /// (μ first; row-major), from the simulation the fit ended on
    /// ([`palpate_motion::optimize::FitResult::gauss_newton`]); `None` for the simplest model's
    /// search.
    pub gauss_newton: Option<Vec<f64>>,
    /// Simulations of the fit.
    pub evaluations: usize,
    /// The optimiser stopped at the screening cap ([`RunsOptions::screen_max_iters`]), not at
    /// its tolerance.
    pub capped: bool,
}

impl RunsFit {
    fn chi2(&self) -> (f64, usize) {
        self.fitted
            .iter()
            .fold((0.0, 0), |(c, n), r| (c + r.chi2, n + 3 * r.count))
    }
    /// Free parameters: the material kinds, the regions' μ (a clamp layer's) and, with the time
    /// offset, one per run.
    fn parameters(&self) -> usize {
        self.kinds.len()
            + self.material.scaled_regions.len()
            + if Effect::retimed(&self.effects) {
                self.offsets.len()
            } else {
                0
            }
    }
    /// Young's modulus from μ at the fixed Poisson's ratio (Pa).
    pub fn young(&self, poisson: f64) -> f64 {
        2.0 * (1.0 + poisson) * self.material.body_moduli().1
    }
}

/// Held-out evidence: the held-out runs predicted.
#[derive(Debug, Clone)]
pub struct Held {
    /// Residuals of the held-out runs.
    pub runs: Vec<RunResidual>,
    /// Each held-out run's own time offset (steps; all 0 without the time offset).
    pub offsets: Vec<i64>,
}

impl Held {
    fn chi2(&self) -> (f64, usize) {
        self.runs
            .iter()
            .fold((0.0, 0), |(c, n), r| (c + r.chi2, n + 3 * r.count))
    }
    /// RMS over every held-out marker observation (m).
    pub fn rms(&self) -> f64 {
        let (c, n) = self.chi2();
        if n == 0 {
            0.0
        } else {
            (3.0 * c / n as f64).sqrt()
        }
    }
    /// RMS of the predicted equilibria against the held-out runs' rest states (m).
    pub fn final_rms(&self) -> f64 {
        let v: Vec<f64> = self.runs.iter().map(|r| r.final_rms_m).collect();
        (v.iter().map(|e| e * e).sum::<f64>() / v.len().max(1) as f64).sqrt()
    }
}

pub use crate::select::GateDetail;

/// One candidate tried, as reported.
#[derive(Debug, Clone, Serialize)]
pub struct Trial {
    /// Round.
    pub round: usize,
    /// The effect.
    pub effect: Effect,
    /// Fitted ΔBIC (NaN when not fitted).
    pub delta_bic: f64,
    /// Fitted RMS (m).
    pub rms_fit_m: Option<f64>,
    /// Held-out RMS (m).
    pub rms_held_m: Option<f64>,
    /// The gate, when run.
    pub gate: Option<GateDetail>,
    /// Why it was not fitted.
    pub not_fitted: Option<String>,
    /// Adopted.
    pub adopted: bool,
    /// ΔBIC the fit screen predicted before any fit (`None`: screen off).
    pub predicted_delta_bic: Option<f64>,
    /// Left unfitted by the fit screen.
    pub screened_out: bool,
}

/// The result of [`diagnose_runs`].
#[derive(Debug, Clone, Serialize)]
pub struct RunsDiagnosis {
    /// The fitted runs.
    pub fitted_runs: Vec<String>,
    /// The held-out runs.
    pub held_out_runs: Vec<String>,
    /// Options.
    pub options: RunsOptions,
    /// Effects adopted, in order.
    pub adopted: Vec<Effect>,
    /// Every candidate tried.
    pub trials: Vec<Trial>,
    /// Why the loop stopped.
    pub stop: Stop,
    /// The simplest model's residuals: fitted runs, then held-out runs.
    pub before: (Vec<RunResidual>, Vec<RunResidual>),
    /// The final model's residuals.
    pub after: (Vec<RunResidual>, Vec<RunResidual>),
    /// Held-out RMS before and after (m).
    pub heldout_rms_m: (f64, f64),
    /// Held-out equilibrium RMS before and after (m).
    pub heldout_final_rms_m: (f64, f64),
    /// Fitted RMS before and after (m).
    pub fitted_rms_m: (f64, f64),
    /// The final model's parameters (1σ `NaN` where not computed; E's from the curvature of the
    /// objective with independent residuals — a lower bound, a ring-down's residuals are
    /// correlated in time).
    pub values: Vec<ParamValue>,
    /// The final model as the record `palpate validate` reads.
    #[serde(skip)]
    pub model: FittedModel,
    /// Whether the fitted modulus is the material's or the mesh's ([`crate::convergence`]); `None`
    /// when not asked for.
    pub mesh_convergence: Option<crate::convergence::MeshConvergence>,
    /// The final model refitted on quadratic elements ([`crate::motion_convergence`]); `None`
    /// when not asked for.
    pub motion_convergence: Option<crate::motion_convergence::MotionConvergence>,
    /// The hanging weights' lever, when `load-point` was adopted.
    pub load_lever: Option<palpate_motion::load_point::LeverFit>,
    /// The softened layer at the clamps, when `clamp-compliance` was adopted.
    pub clamp_layer: Option<candidates::clamp_compliance::ClampLayer>,
    /// The floor the creep branch's relaxation time was held above (s): the longest ring-down
    /// period measured in the fitted runs; `None` when none rings.
    pub creep_floor_s: Option<f64>,
    /// Each run's simulation step and why, with its own error measured on the capture
    /// ([`palpate_motion::timestep::TimeStep::describe`]): fitted runs, then held-out runs.
    pub time_steps: Vec<(String, String)>,
    /// Each run's step error at the final model, against its residual there
    /// ([`palpate_motion::step_error::at_fitted`]): fitted runs, then held-out runs; `Err` says
    /// why it was not measured.
    pub fitted_step_errors: Vec<RunStepError>,
    /// Seconds the diagnosis took.
    pub seconds: f64,
    /// Simulations of one run the diagnosis made.
    pub simulations: Simulations,
}

/// A run's step error at the final model ([`palpate_motion::step_error::at_fitted`]).
#[derive(Debug, Clone, Serialize)]
pub struct RunStepError {
    /// The run (its dataset directory).
    pub run: String,
    /// The error against the run's final residual; `None` when not measured.
    pub measured: Option<palpate_motion::step_error::FittedStepError>,
    /// Why it was not measured.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub not_measured: Option<String>,
}

/// Simulations of one run (a fit's evaluation of two runs is two), by kind: what the
/// diagnosis' time is made of, whatever the machine's load.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Simulations {
    /// With the sensitivities of every fitted parameter (a Levenberg–Marquardt evaluation, the
    /// fit screen's).
    pub with_sensitivities: usize,
    /// Without (a prediction, a residual, a time-offset scan).
    pub plain: usize,
}

impl RunsDiagnosis {
    /// The held-out runs' loads (N along gravity) that no fitted run carries (within 2 % of the
    /// largest fitted load, or 1 mN): empty when every held-out run repeats a fitted load, and
    /// then the held-out gate tests repeatability, not extrapolation to other loads — a law that
    /// depends on the strain (the stiffening) is checked only at the loads it was fitted on.
    pub fn held_out_loads_beyond_fitted(&self) -> Vec<f64> {
        let fitted: Vec<f64> = self.after.0.iter().map(|r| r.load_n).collect();
        let tol = (0.02 * fitted.iter().fold(0.0f64, |m, l| m.max(l.abs()))).max(1e-3);
        self.after
            .1
            .iter()
            .map(|r| r.load_n)
            .filter(|l| fitted.iter().all(|f| (f - l).abs() > tol))
            .collect()
    }
}

/// 1σ of log μ from the curvature of Φ with independent residuals: σ² = 2Φ / ((n − k) Φ''),
/// the other parameters held. Φ'' in ln μ is the fit's own Gauss–Newton matrix's where the fit
/// has one (`gauss_newton`, μ's diagonal entry: JᵀJ with J exact), else the central second
/// difference. A lower bound: a ring-down's residuals are correlated in time.
fn mu_sd(
    runs: &[Run<'_>],
    mat: &Material,
    phi: f64,
    gauss_newton: Option<&[f64]>,
    poisson: f64,
    n: usize,
    k: usize,
) -> Result<f64, MotionError> {
    let mu = mat.body_moduli().1;
    let sd = |curv: f64| {
        if curv <= 0.0 || n <= k {
            f64::NAN
        } else {
            mu * (2.0 * phi / ((n - k) as f64 * curv)).sqrt()
        }
    };
    if let Some(&curv) = gauss_newton.and_then(<[f64]>::first) {
        return Ok(sd(curv));
    }
    let ratio = 2.0 * poisson / (1.0 - 2.0 * poisson);
    // The body's μ varied, a clamp layer's held where it is.
    let mut params = vec![
        Param::global(ParamKind::Mu),
        Param::global(ParamKind::Lambda),
    ];
    let regions = fit::region_params(mat);
    let held = mat.read(&regions);
    params.extend(regions);
    let at = |z: f64| -> Result<f64, MotionError> {
        let mut m = mat.clone();
        let v = mu * z.exp();
        let mut q = vec![v, ratio * v];
        q.extend(&held);
        m.set(&params, &q);
        Ok(
            palpate_motion::optimize::evaluate_runs(runs, &m, &params, None)?
                .0
                .phi,
        )
    };
    let h = 1e-2;
    // Φ at the fitted μ is the fit's own: the two sides alone are simulated.
    let (pp, pm) = rayon::join(|| at(h), || at(-h));
    Ok(sd((pp? - 2.0 * phi + pm?) / (h * h)))
}

/// Diagnoses the runs `fit` (fitted) against `held` (held out); `log` receives progress lines.
pub fn diagnose_runs(
    fit: &[(String, MotionDataset)],
    held: &[(String, MotionDataset)],
    o: &RunsOptions,
    log: &dyn Fn(&str),
) -> Result<RunsDiagnosis, RunsError> {
    diagnose_runs_with(fit, held, o, log, &|_| {})
}

/// [`diagnose_runs`], with the selection's [`Progress`] handed to `progress` as it goes (the
/// round, the candidate fitted and how many are planned: what a progress bar draws).
pub fn diagnose_runs_with(
    fit: &[(String, MotionDataset)],
    held: &[(String, MotionDataset)],
    o: &RunsOptions,
    log: &dyn Fn(&str),
    progress: &dyn Fn(&Progress),
) -> Result<RunsDiagnosis, RunsError> {
    let t0 = std::time::Instant::now();
    check_runs(fit, held, o)?;
    let first = &fit[0].1;
    let density = first.config.density.unwrap_or(1000.0);
    let nu = o.poisson;
    let mut base = Material::uniform(
        first.model.tets.len(),
        2.0 * nu / (1.0 - 2.0 * nu) * o.start_mu,
        o.start_mu,
        0.0,
        1.0,
        density,
    );
    base.set(&[Param::global(ParamKind::Nu)], &[0.0]);
    let lever = read_lever(fit, o, log);
    let mut m = RunsModel {
        fit,
        held,
        o,
        log,
        trials: Vec::new(),
        fitted: Vec::new(),
        predicted: Vec::new(),
        landed: Vec::new(),
        scanned: None,
        progress,
        simulations: Default::default(),
        ahead: Default::default(),
        lever,
        creep_floor: None,
    };
    for c in &o.candidates {
        let e = c.effect();
        if !e.available(&m) {
            log(&format!(
                "{} not offered: {}",
                e.name(),
                e.unavailable_because()
            ));
        }
    }
    let weights_moved = weights_moving(o, fit, held);
    log(&format!(
        "fitting the simplest model (Neo-Hookean, fixed Poisson's ratio, no damping{})",
        if weights_moved {
            ", the hung weights moving with their nodes"
        } else {
            ""
        }
    ));
    let start = m.fit(&[], &base, &[], o.max_iters)?;
    m.creep_floor = start
        .fitted
        .iter()
        .filter_map(|r| r.period_s.0)
        .filter(|t| t.is_finite() && *t > 0.0)
        .reduce(f64::max);
    let start_held = Held {
        runs: m.residuals(held, &[], &start.material, &[])?,
        offsets: Vec::new(),
    };
    let policy = Policy {
        rounds: o.max_effects + 1,
        max_adopted: o.max_effects,
        rank: Rank::FittedBic,
        screen: Screen::All,
    };
    let verdict = select(&mut m, &policy, start.clone(), start_held.clone())?;
    let (last, last_held) = verdict
        .path
        .last()
        .cloned()
        .expect("the start is on the path");
    let adopted = verdict.adopted();
    let lever_adopted = if adopted.contains(&Effect::LoadPoint) {
        m.lever.clone()
    } else {
        None
    };
    // Uncertainty of μ (hence E) on the final model (the runs at their offsets).
    let models = m.models(fit, &last.effects);
    let retimed: Vec<(palpate_motion::model::Model, Observations)> = models
        .iter()
        .zip(fit)
        .enumerate()
        .map(|(i, (model, (_, d)))| {
            time_offset::shifted(model, &d.obs, last.offsets.get(i).copied().unwrap_or(0))
        })
        .collect::<Result<_, _>>()?;
    let runs: Vec<Run> = retimed
        .iter()
        .map(|(model, obs)| Run { model, obs })
        .collect();
    let (_, n) = last.chi2();
    // What the step puts into the final residual of each run, measured at the final material,
    // beside μ's curvature: independent simulations, side by side.
    let mut measured = m.step_error_runs(fit, &last.effects, &last.offsets, &last.fitted);
    measured.extend(m.step_error_runs(held, &last.effects, &last_held.offsets, &last_held.runs));
    let mesh_lines = std::sync::Mutex::new(Vec::<String>::new());
    let ((sd_mu, step_errors), mesh_convergence) = rayon::join(
        || {
            rayon::join(
                || {
                    mu_sd(
                        &runs,
                        &last.material,
                        last.phi,
                        last.gauss_newton.as_deref(),
                        nu,
                        n,
                        last.parameters(),
                    )
                },
                || fit::step_errors(&measured, &last.material),
            )
        },
        || {
            // Whether the fitted modulus is the mesh's: the rest states on quadratic elements,
            // beside them too, its lines held and logged after the step errors'; the runs with
            // the final model's loads (a lever moves the weights).
            o.mesh_convergence.then(|| {
                let changed: Vec<MotionDataset> = fit
                    .iter()
                    .zip(&models)
                    .map(|((_, d), model)| MotionDataset {
                        model: model.clone(),
                        ..d.clone()
                    })
                    .collect();
                let named: Vec<(&str, &MotionDataset)> = fit
                    .iter()
                    .zip(&changed)
                    .map(|((n, _), d)| (n.as_str(), d))
                    .collect();
                let hold = |line: &str| {
                    mesh_lines
                        .lock()
                        .unwrap_or_else(|e| e.into_inner())
                        .push(line.to_string())
                };
                let mu = last.material.body_moduli().1;
                crate::convergence::check(&named, nu, mu, rms_of(&last.fitted), &hold)
            })
        },
    );
    let sd_mu = sd_mu?;
    if last.gauss_newton.is_none() {
        m.count(2 * runs.len(), false);
    }
    let values = final_values(&last, nu, sd_mu);
    let fitted_step_errors: Vec<RunStepError> = fit
        .iter()
        .chain(held)
        .zip(step_errors)
        .map(|((run, _), e)| RunStepError {
            run: run.clone(),
            not_measured: e.as_ref().err().cloned(),
            measured: e.ok(),
        })
        .collect();
    m.count(measured.iter().map(|r| r.simulations()).sum(), false);
    for e in &fitted_step_errors {
        match (&e.measured, &e.not_measured) {
            (Some(m), _) => log(&format!("{}: the step's own error {}", e.run, m.describe())),
            (None, why) => log(&format!(
                "{}: the step's own error not measured: {}",
                e.run,
                why.as_deref().unwrap_or("")
            )),
        }
    }
    for line in mesh_lines.into_inner().unwrap_or_else(|e| e.into_inner()) {
        log(&line);
    }
    let mut model = fitted_model(fit, &models, &last, nu, weights_moved);
    let motion_convergence = o.motion_convergence.then(|| {
        // From the rest states' quadratic-to-linear modulus ratio when known; the runs at
        // their offsets and with the final model's loads.
        let scale = mesh_convergence
            .as_ref()
            .and_then(|c| c.converged_modulus())
            .map_or(1.0, |c| c.shear_modulus_pa / c.mesh_shear_modulus_pa);
        let named: Vec<crate::motion_convergence::FittedRun<'_>> = fit
            .iter()
            .zip(&retimed)
            .map(|((n, _), (model, obs))| (n.as_str(), model, obs))
            .collect();
        crate::motion_convergence::check(
            &named,
            &last.material,
            &last.kinds,
            Some(nu),
            scale,
            rms_of(&last.fitted),
            log,
        )
    });
    // fit.json carries the converged modulus, so `palpate validate` can take the material to
    // another mesh.
    model.converged = mesh_convergence
        .as_ref()
        .and_then(|c| c.converged_modulus());
    Ok(RunsDiagnosis {
        fitted_runs: fit.iter().map(|(n, _)| n.clone()).collect(),
        held_out_runs: held.iter().map(|(n, _)| n.clone()).collect(),
        options: o.clone(),
        adopted,
        trials: m.trials,
        stop: verdict.stop,
        heldout_rms_m: (start_held.rms(), last_held.rms()),
        heldout_final_rms_m: (start_held.final_rms(), last_held.final_rms()),
        fitted_rms_m: (rms_of(&start.fitted), rms_of(&last.fitted)),
        before: (start.fitted, start_held.runs),
        after: (last.fitted, last_held.runs),
        values,
        model,
        mesh_convergence,
        motion_convergence,
        load_lever: lever_adopted,
        clamp_layer: candidates::clamp_compliance::clamp_layer(&fit[0].1.model, &last.material),
        creep_floor_s: m.creep_floor,
        time_steps: fit
            .iter()
            .chain(held)
            .map(|(n, d)| (n.clone(), d.timestep.describe()))
            .collect(),
        fitted_step_errors,
        seconds: t0.elapsed().as_secs_f64(),
        simulations: m.simulations.get(),
    })
}

/// The `load-point` candidate's lever: read from the fitted runs' rest states when it is asked
/// for and some fitted run hangs a weight ([`palpate_motion::load_point::fit_lever`] on the
/// dataset's linear elements at the held Poisson's ratio), logged either way.
fn read_lever(
    fit: &[(String, MotionDataset)],
    o: &RunsOptions,
    log: &dyn Fn(&str),
) -> Option<palpate_motion::load_point::LeverFit> {
    let hangs = fit
        .iter()
        .any(|(_, d)| d.model.loads.iter().any(|l| l.mass.is_some()));
    if !o.candidates.contains(&Effect::LoadPoint) || !hangs {
        return None;
    }
    let sets: Vec<&MotionDataset> = fit.iter().map(|(_, d)| d).collect();
    match palpate_motion::load_point::fit_lever(
        &sets,
        palpate_motion::rest_fit::Design::Linear,
        o.poisson,
        o.start_mu,
        0.5,
    ) {
        Ok(l) => {
            // As the mesh-convergence check: a run whose markers scatter in the window by more
            // than the rest states' misfit has not come to rest, and its mean is no equilibrium.
            let moving = fit.iter().find_map(|(name, d)| {
                let scatter = crate::convergence::scatter_in_window(d, 0.5);
                (scatter.is_nan() || scatter > l.rms_on_nodes_m).then_some((name, scatter))
            });
            if let Some((name, scatter)) = moving {
                log(&format!(
                    "load-point: {name}'s markers still move in its last 0.5 s (scatter {:.3} mm, above the rest states' misfit {:.3} mm): no lever read",
                    1e3 * scatter,
                    1e3 * l.rms_on_nodes_m
                ));
                return None;
            }
            log(&format!(
                "the hanging weights' point from the rest states: {:.1} mm ± {:.1} mm beyond their nodes (rest RMS {:.3} → {:.3} mm)",
                1e3 * l.offset_m,
                1e3 * l.sigma_m,
                1e3 * l.rms_on_nodes_m,
                1e3 * l.rms_m
            ));
            Some(l)
        }
        Err(e) => {
            log(&format!("load-point: no lever from the rest states: {e}"));
            None
        }
    }
}

/// Whether the runs and the options can be diagnosed: runs on both sides, one mesh, a Poisson's
/// ratio in range.
fn check_runs(
    fit: &[(String, MotionDataset)],
    held: &[(String, MotionDataset)],
    o: &RunsOptions,
) -> Result<(), RunsError> {
    if fit.is_empty() || held.is_empty() {
        return Err(RunsError::Input(
            "the runs diagnosis needs runs to fit and other runs to hold out".into(),
        ));
    }
    let first = &fit[0].1;
    for (name, d) in fit.iter().chain(held) {
        if d.mesh.nodes != first.mesh.nodes || d.mesh.tets != first.mesh.tets {
            return Err(RunsError::Input(format!(
                "{name}: its mesh differs from {}'s: the runs of one object share one mesh",
                fit[0].0
            )));
        }
    }
    if !(o.poisson > -1.0 && o.poisson < 0.5) {
        return Err(RunsError::Input(format!(
            "Poisson's ratio must lie in (−1, 0.5), found {}",
            o.poisson
        )));
    }
    Ok(())
}

/// The final model's parameters as reported: E and μ (1σ `sd_mu`), the held Poisson's ratio,
/// then each adopted effect's in library order.
fn final_values(last: &RunsFit, nu: f64, sd_mu: f64) -> Vec<ParamValue> {
    let mu = last.material.body_moduli().1;
    let mut values = vec![
        ParamValue {
            name: "E (Young's modulus)".into(),
            value: 2.0 * (1.0 + nu) * mu,
            sd: 2.0 * (1.0 + nu) * sd_mu,
            unit: "Pa".into(),
        },
        ParamValue {
            name: "μ (shear modulus)".into(),
            value: mu,
            sd: sd_mu,
            unit: "Pa".into(),
        },
        ParamValue {
            name: "Poisson's ratio (held)".into(),
            value: nu,
            sd: f64::NAN,
            unit: "".into(),
        },
    ];
    for e in ALL_EFFECTS.iter().filter(|e| last.effects.contains(e)) {
        values.extend(e.effect().values(&last.material));
    }
    values
}

/// RMS over every observed marker position of `v` (m).
fn rms_of(v: &[RunResidual]) -> f64 {
    let (c, n) = v
        .iter()
        .fold((0.0, 0), |(c, n), r| (c + r.chi2, n + r.count));
    if n == 0 {
        0.0
    } else {
        (c / n as f64).sqrt()
    }
}

/// Whether the simplest model of these runs moves hung weights with their nodes: the options ask
/// it ([`RunsOptions::weights_move`]) and some run, fitted or held out, hangs a weight with a
/// declared mass from its start.
pub(in crate::runs) fn weights_moving(
    o: &RunsOptions,
    fit: &[(String, MotionDataset)],
    held: &[(String, MotionDataset)],
) -> bool {
    o.weights_move() && hangs_a_weight(fit.iter().chain(held))
}

/// Whether some run of `runs` hangs a weight with a declared mass from its start.
pub(in crate::runs) fn hangs_a_weight<'a>(
    runs: impl IntoIterator<Item = &'a (String, MotionDataset)>,
) -> bool {
    runs.into_iter().any(|(_, d)| {
        d.model
            .loads
            .iter()
            .any(|l| l.mass.is_some() && l.from_step == 0)
    })
}

/// The final model `last` of the runs `fit` (their `models` with its effects' changes) as the
/// record `palpate validate` reads.
/// `weights_moved`: the simplest model moved the hung weights ([`weights_moving`]); else their
/// inertia is recorded only when its candidate was adopted.
fn fitted_model(
    fit: &[(String, MotionDataset)],
    models: &[palpate_motion::model::Model],
    last: &RunsFit,
    nu: f64,
    weights_moved: bool,
) -> FittedModel {
    let first = &fit[0].1;
    let mat = &last.material;
    let mut model = FittedModel {
        format: palpate_motion::fitted::FORMAT.into(),
        datasets: fit.iter().map(|(n, _)| n.clone()).collect(),
        nodes: first.mesh.nodes.len(),
        tets: first.mesh.tets.len(),
        lambda: mat.values[0].clone(),
        mu: mat.values[1].clone(),
        viscosity: mat.values[2].clone(),
        h: mat.values[3].clone(),
        density: mat.values[4].clone(),
        stiffening: palpate_motion::fitted::FittedModel::stiffening_of(mat),
        creep: palpate_motion::fitted::CreepRecord::of(mat),
        viscosity_form: mat.viscous_form,
        poisson_fixed: Some(nu),
        hanging_inertia: weights_moved,
        time_offset: false,
        load_lever_m: models.iter().map(|m| m.load_lever()).find(|d| *d != 0.0),
        gravity_turn: palpate_motion::fitted::FittedModel::gravity_turn_of(mat),
        fitted: last.kinds.iter().map(|k| k.name().to_string()).collect(),
        runtime_lambda_alpha: mat.values[0]
            .iter()
            .zip(&mat.values[1])
            .map(|(l, m)| {
                let a = palpate_runtime::material::LambdaAlpha::from_lame(*l, *m);
                [a.lambda, a.alpha]
            })
            .collect(),
        rms_marker_m: rms_of(&last.fitted),
        rms_force_n: 0.0,
        evaluations: last.evaluations,
        runs: fit
            .iter()
            .zip(models)
            .zip(&last.fitted)
            .map(|(((name, d), model), r)| {
                let rest = predict::rest_markers(model);
                FittedRun {
                    dataset: name.clone(),
                    load_n: predict::load_along_gravity(model),
                    rms_marker_m: r.rms_m,
                    time_offset_s: r.time_offset_s,
                    markers: model.markers.iter().map(|m| m.name.clone()).collect(),
                    final_displacement_m: predict::final_observed(model, &d.obs)
                        .iter()
                        .zip(&rest)
                        .map(|(f, r0)| f.map(|p| [0, 1, 2].map(|k| p[k] - r0[k])))
                        .collect(),
                }
            })
            .collect(),
        converged: None,
    };
    for e in &last.effects {
        e.effect().record(&mut model);
    }
    model
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_motion::optimize::{fit_runs, FitSettings};
    use palpate_motion::scenario::{example_bar, example_truth, record};

    /// μ's 1σ read off the fit's own Gauss–Newton matrix against the central second difference
    /// of Φ (the independent reference): the example bar's μ and viscosity fitted to two noisy
    /// runs at a held Poisson's ratio, both within 2 % of each other.
    #[test]
    fn mus_sigma_from_the_fits_matrix_is_the_differenced_one() {
        // The truth's own Poisson's ratio (λ = μ/2).
        let nu = 1.0 / 6.0;
        let (_, mut model) = example_bar([1, 4, 1], 30).unwrap();
        model.newton.tol = 1e-11;
        let truth = example_truth(&model);
        let data: Vec<Observations> = [5, 6]
            .iter()
            .map(|&seed| {
                let mut obs = record(&model, &truth, 2e-4, seed).unwrap();
                obs.forces.clear();
                obs
            })
            .collect();
        let runs: Vec<Run> = data.iter().map(|obs| Run { model: &model, obs }).collect();
        let params = Param::globals(&[ParamKind::Mu, ParamKind::Nu]);
        let settings = FitSettings {
            poisson: Some(nu),
            ..Default::default()
        };
        let r = fit_runs(
            &runs,
            &truth,
            &params,
            &[1.5e4, 20.0],
            &settings,
            &[],
            &|_, _| {},
        )
        .unwrap();
        let mut mat = truth.clone();
        mat.set(&params, &r.q);
        let ratio = 2.0 * nu / (1.0 - 2.0 * nu);
        mat.set(&[Param::global(ParamKind::Lambda)], &[ratio * r.q[0]]);
        let n = 3 * r.eval.marker_count;
        let gn = r
            .gauss_newton
            .as_deref()
            .expect("Levenberg–Marquardt's matrix");
        let exact = mu_sd(&runs, &mat, r.eval.phi, Some(gn), nu, n, 2).unwrap();
        let differenced = mu_sd(&runs, &mat, r.eval.phi, None, nu, n, 2).unwrap();
        assert!(exact.is_finite() && exact > 0.0);
        assert!(
            (exact / differenced - 1.0).abs() < 0.02,
            "σ_μ {exact:e} from the fit's matrix, {differenced:e} differenced"
        );
    }
}
