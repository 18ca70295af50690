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
//! viscosity (held at 0), density and loads as declared, hanging weights as forces only.
//!
//! **Candidates** ([`Effect`]): Newtonian viscosity (ν free, h = 1), power-law viscosity (ν and h
//! free, eq. 17), the inertia of hanging weights (no new parameter: the declared mass moves
//! with its nodes), and a time offset of each run's markers against the simulation's clock (one
//! integer number of steps per run, [`palpate_motion::time_offset`]: the release instant an import
//! reads off the capture is uncertain by a frame or two). Each is fitted on top of the current
//! model (all its material parameters refitted).
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
//! Newtonian damping with one more parameter. The hanging weights' inertia, a switch with no
//! neutral value to linearise about, is always fitted; the time offset is predicted by its scan
//! at the current material (its fit starts from that scan, which is not repeated), without the
//! material's refit. The best predicted are fitted in full
//! (the screen's `least`, and those within its `margin` of the best); the rest are reported with
//! their predicted ΔBIC, and fitted after all if nothing fitted passes the gate.
//!
//! **The residual's signature** ([`RunResidual`]): per run, the RMS per marker, in the first and
//! last quarter of the run, and — on the marker that moves most — the ring-down's period and its
//! amplitude ratio per cycle, measured and simulated. A period the model gets wrong points at the
//! mass (the hanging weight's inertia); a decay it gets wrong at the damping.

pub mod report;
pub mod run;

use crate::screen::{self, Normal};
use crate::select::{
    self, select, CandidateModel, Current, FitScreen, Gate, HeldoutGate, Outcome, ParamValue,
    PassWords, Policy, Progress, Rank, Score, Screen, Stop,
};
use palpate_motion::dataset::MotionDataset;
use palpate_motion::fitted::{set_hanging_inertia, FittedModel, FittedRun};
use palpate_motion::gradient::evaluate_gauss_newton;
use palpate_motion::model::{Material, Observations, Param, ParamKind};
use palpate_motion::optimize::{fit_runs, FitSettings, Run};
use palpate_motion::predict::{self, Prediction};
use palpate_motion::time_offset;
use palpate_motion::MotionError;
use serde::Serialize;

/// The runs diagnosis's errors: the crate's one [`crate::Error`] (the name kept for its callers).
pub type RunsError = crate::Error;

/// A candidate effect the simplest model of the runs lacks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Effect {
    /// Newtonian viscosity: ν free, h = 1 (1 parameter).
    Damping,
    /// Power-law viscosity of eq. 17: ν and h free (2 parameters).
    DampingPowerLaw,
    /// Hanging weights move with their nodes (0 parameters: the declared mass).
    HangingInertia,
    /// Each run's markers are offset in time against the simulation (1 integer parameter per
    /// run: its offset in steps, scanned).
    TimeOffset,
    /// The material stiffens (or holds its stiffness) at larger strains beyond Neo-Hookean: a
    /// Yeoh-type c (Ī₁ − 3)² term beside eq. 16 (1 parameter, c ≥ 0, fitted in ln c from
    /// c = μ: at 10 % strain that adds about 6 % to the Neo-Hookean energy). What tells it
    /// from a stiffer μ is the load: runs under different weights strain the body differently.
    Stiffening,
}

/// Every effect, in the order tried.
pub const ALL_EFFECTS: [Effect; 5] = [
    Effect::Damping,
    Effect::DampingPowerLaw,
    Effect::HangingInertia,
    Effect::TimeOffset,
    Effect::Stiffening,
];

impl Effect {
    /// Name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::Damping => "damping",
            Self::DampingPowerLaw => "damping-power-law",
            Self::HangingInertia => "hanging-inertia",
            Self::TimeOffset => "time-offset",
            Self::Stiffening => "stiffening",
        }
    }
    /// Material parameters it frees.
    pub fn kinds(self) -> &'static [ParamKind] {
        match self {
            Self::Damping => &[ParamKind::Nu],
            Self::DampingPowerLaw => &[ParamKind::Nu, ParamKind::PowerH],
            Self::Stiffening => &[ParamKind::Stiffening],
            Self::HangingInertia | Self::TimeOffset => &[],
        }
    }
    /// Whether `self` is `other` with some of `other`'s material parameters held at their neutral
    /// values (Newtonian damping is the power law at h = 1). Switches (no parameters) nest nothing.
    pub fn nested_in(self, other: Effect) -> bool {
        let (a, b) = (self.kinds(), other.kinds());
        !a.is_empty() && a.len() < b.len() && a.iter().all(|k| b.contains(k))
    }
    /// Parameters it adds to a model of `runs` runs: its material kinds, or one offset per run.
    fn parameters(self, runs: usize) -> usize {
        match self {
            Self::TimeOffset => runs,
            _ => self.kinds().len(),
        }
    }
    fn conflicts(self, other: Effect) -> bool {
        matches!(
            (self, other),
            (Self::Damping, Self::DampingPowerLaw) | (Self::DampingPowerLaw, Self::Damping)
        )
    }
}

/// Options of [`diagnose_runs`].
#[derive(Debug, Clone, Serialize)]
pub struct RunsOptions {
    /// Candidates to try.
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
    /// With the screen: fewest candidates fitted per round.
    pub screen_least: usize,
    /// With the screen: a candidate is fitted when its predicted ΔBIC is within this fraction of
    /// the best predicted one's magnitude.
    pub screen_margin: f64,
}

impl Default for RunsOptions {
    fn default() -> Self {
        Self {
            candidates: ALL_EFFECTS.to_vec(),
            // Damping (one of its two laws), the weights' inertia, the time offset and the
            // stiffening can all be in one model.
            max_effects: 4,
            max_iters: 40,
            screen_max_iters: 15,
            poisson: 0.49,
            start_mu: 5e4,
            start_viscosity: None,
            bic_threshold: 10.0,
            min_holdout_gain: 0.05,
            screen: true,
            screen_least: 2,
            screen_margin: 0.5,
        }
    }
}

/// One run's residual, as the diagnosis reads it.
#[derive(Debug, Clone, Serialize)]
pub struct RunResidual {
    /// The run (its dataset directory).
    pub run: String,
    /// RMS over every observed (step, marker) (m).
    pub rms_m: f64,
    /// Sum of squared marker distances (m²) and the number of observed marker positions.
    pub chi2: f64,
    /// Observed marker positions.
    pub count: usize,
    /// RMS per marker over the run (m).
    pub per_marker_m: Vec<(String, f64)>,
    /// RMS over the first and the last quarter of the steps (m).
    pub early_m: f64,
    /// See `early_m`.
    pub late_m: f64,
    /// Predicted equilibrium against the markers' rest state at the end (RMS, m).
    pub final_rms_m: f64,
    /// Dead loads along gravity at the end of the run (N).
    pub load_n: f64,
    /// The marker that moves most (the ring-down is read on it).
    pub ring_marker: String,
    /// Ring-down period, measured and simulated (s); `None` when fewer than two half-cycles.
    pub period_s: (Option<f64>, Option<f64>),
    /// Amplitude ratio per cycle, measured and simulated.
    pub decay_per_cycle: (Option<f64>, Option<f64>),
    /// The run's time offset: its markers compared with the simulation this much later (s; 0
    /// without the time-offset effect).
    pub time_offset_s: f64,
    /// Displacement along gravity of `ring_marker` per step, measured (NaN = unseen) and
    /// simulated (m) — for the report's plots.
    #[serde(skip)]
    pub ring: (Vec<f64>, Vec<f64>),
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
    /// Time offset of each fitted run (steps; all 0 without [`Effect::TimeOffset`]).
    pub offsets: Vec<i64>,
    /// Residuals of the fitted runs.
    pub fitted: Vec<RunResidual>,
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
    /// Free parameters: the material kinds and, with the time offset, one per run.
    fn parameters(&self) -> usize {
        self.kinds.len()
            + if self.effects.contains(&Effect::TimeOffset) {
                self.offsets.len()
            } else {
                0
            }
    }
    /// Young's modulus from μ at the fixed Poisson's ratio (Pa).
    pub fn young(&self, poisson: f64) -> f64 {
        2.0 * (1.0 + poisson) * self.material.get(ParamKind::Mu, 0)
    }
}

/// Held-out evidence: the held-out runs predicted.
#[derive(Debug, Clone)]
pub struct Held {
    /// Residuals of the held-out runs.
    pub runs: Vec<RunResidual>,
    /// Each held-out run's own time offset (steps; all 0 without [`Effect::TimeOffset`]).
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
    /// Seconds the diagnosis took.
    pub seconds: f64,
    /// Simulations of one run the diagnosis made.
    pub simulations: Simulations,
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

/// The residual of one run under `mat`: simulated, compared, its ring-down read.
pub fn residual(
    name: &str,
    ds: &MotionDataset,
    mat: &Material,
) -> Result<RunResidual, MotionError> {
    let p = predict::predict(&ds.model, mat, &ds.obs)?;
    Ok(read_residual(name, ds, &p, 0))
}

fn read_residual(name: &str, ds: &MotionDataset, p: &Prediction, offset: i64) -> RunResidual {
    let nm = ds.model.markers.len();
    let steps = p.simulated.len();
    let mut per = vec![(0.0, 0usize); nm];
    let (mut early, mut late) = ((0.0, 0usize), (0.0, 0usize));
    let q = steps / 4;
    for (n, (sim, obs)) in p.simulated.iter().zip(&ds.obs.markers).enumerate() {
        for i in 0..nm {
            if let Some(o) = obs.get(i).copied().flatten() {
                let e2 = (0..3).map(|k| (sim[i][k] - o[k]).powi(2)).sum::<f64>();
                per[i].0 += e2;
                per[i].1 += 1;
                if n < q {
                    early.0 += e2;
                    early.1 += 1;
                }
                if n >= steps - q {
                    late.0 += e2;
                    late.1 += 1;
                }
            }
        }
    }
    let r = |(s, c): (f64, usize)| if c == 0 { 0.0 } else { (s / c as f64).sqrt() };
    let chi2: f64 = per.iter().map(|p| p.0).sum();
    let count: usize = per.iter().map(|p| p.1).sum();
    // The ring-down is read along gravity on the marker whose equilibrium moves most.
    let g = ds.model.gravity;
    let gn = g.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
    let rest = predict::rest_markers(&ds.model);
    let along =
        |x: &[f64; 3], i: usize| (0..3).map(|k| (x[k] - rest[i][k]) * g[k] / gn).sum::<f64>();
    let tip = (0..nm)
        .max_by(|&a, &b| {
            along(&p.equilibrium[a], a)
                .abs()
                .total_cmp(&along(&p.equilibrium[b], b).abs())
        })
        .unwrap_or(0);
    let measured: Vec<f64> = ds
        .obs
        .markers
        .iter()
        .take(steps)
        .map(|row| {
            row.get(tip)
                .copied()
                .flatten()
                .map_or(f64::NAN, |o| along(&o, tip))
        })
        .collect();
    let simulated: Vec<f64> = p
        .simulated
        .iter()
        .map(|row| along(&row[tip], tip))
        .collect();
    let dt = ds.model.dt;
    let ring_m = ring_down(&measured, dt);
    let ring_s = ring_down(&simulated, dt);
    RunResidual {
        run: name.to_string(),
        rms_m: r((chi2, count)),
        chi2,
        count,
        per_marker_m: ds
            .model
            .markers
            .iter()
            .zip(&per)
            .map(|(m, &p)| (m.name.clone(), r(p)))
            .collect(),
        early_m: r(early),
        late_m: r(late),
        final_rms_m: p.final_rms_m,
        load_n: predict::load_along_gravity(&ds.model),
        ring_marker: ds
            .model
            .markers
            .get(tip)
            .map(|m| m.name.clone())
            .unwrap_or_default(),
        period_s: (ring_m.0, ring_s.0),
        decay_per_cycle: (ring_m.1, ring_s.1),
        time_offset_s: offset as f64 * ds.model.dt,
        ring: (measured, simulated),
    }
}

/// A Newtonian viscosity on the scale the measured ring-downs show: for each run with a measured
/// period T and amplitude ratio a per cycle, the damping ratio ζ = −ln a / 2π of its first mode
/// and the Kelvin–Voigt viscosity that damps a mode of ω = 2π/T at ζ in a material of shear
/// modulus μ, ν = 2ζμ/ω (the viscous stress 2ν ε̇ beside the elastic 2μ ε; the motion fitter's
/// own start from a rest sag uses the same relation, `palpate_motion::start`); the geometric
/// mean over the runs. `None` when no run rings.
pub fn viscosity_from_ring_down(runs: &[RunResidual], mu: f64) -> Option<f64> {
    let logs: Vec<f64> = runs
        .iter()
        .filter_map(|r| {
            let (t, a) = (r.period_s.0?, r.decay_per_cycle.0?);
            (t > 0.0 && a > 0.0 && a < 1.0).then(|| {
                let zeta = -a.ln() / (2.0 * std::f64::consts::PI);
                (2.0 * zeta * mu * t / (2.0 * std::f64::consts::PI)).ln()
            })
        })
        .filter(|v| v.is_finite())
        .collect();
    (!logs.is_empty() && mu > 0.0).then(|| (logs.iter().sum::<f64>() / logs.len() as f64).exp())
}

/// The ring-down's period and decay per cycle: the motion crate's estimate, the one that also
/// chooses the simulation's time step from the capture ([`palpate_motion::timestep`]).
pub use palpate_motion::timestep::ring_down;

struct RunsModel<'a> {
    fit: &'a [(String, MotionDataset)],
    held: &'a [(String, MotionDataset)],
    o: &'a RunsOptions,
    log: &'a dyn Fn(&str),
    trials: Vec<Trial>,
    /// Each fitted candidate's material, by round: the start of a later candidate of the same
    /// round that nests it.
    fitted: Vec<(usize, Effect, Material)>,
    /// The fit screen's predictions, by round.
    predicted: Vec<(usize, Effect, f64)>,
    /// The time offsets the screen scanned at the current material, by round: the start of the
    /// time offset's fit in that round.
    scanned: Option<(usize, Vec<i64>)>,
    /// Receives the selection's progress.
    progress: &'a dyn Fn(&Progress),
    /// Simulations so far.
    simulations: std::cell::Cell<Simulations>,
}

impl RunsModel<'_> {
    /// Counts `n` simulations of one run, with sensitivities or without.
    fn count(&self, n: usize, sensitivities: bool) {
        let mut s = self.simulations.get();
        if sensitivities {
            s.with_sensitivities += n;
        } else {
            s.plain += n;
        }
        self.simulations.set(s);
    }

    /// Records a candidate that could not be fitted, and tells the engine why.
    fn not_fitted(&mut self, round: usize, effect: Effect, why: String) -> Outcome<RunsFit> {
        self.trials.push(Trial {
            round,
            effect,
            delta_bic: f64::NAN,
            rms_fit_m: None,
            rms_held_m: None,
            gate: None,
            not_fitted: Some(why.clone()),
            adopted: false,
            predicted_delta_bic: self.prediction(round, effect),
            screened_out: false,
        });
        Outcome::NotFitted(why)
    }
    /// The screen's prediction of `effect` in `round`.
    fn prediction(&self, round: usize, effect: Effect) -> Option<f64> {
        self.predicted
            .iter()
            .rev()
            .find(|(r, e, _)| *r == round && *e == effect)
            .map(|p| p.2)
    }

    /// The fitted runs with `effects`' structural changes, run i's markers `offsets[i]` steps
    /// late.
    fn retimed(
        &self,
        effects: &[Effect],
        offsets: &[i64],
    ) -> Result<Vec<(palpate_motion::model::Model, Observations)>, MotionError> {
        Self::models(self.fit, effects)
            .into_iter()
            .zip(self.fit)
            .enumerate()
            .map(
                |(i, (model, (_, d)))| match offsets.get(i).copied().unwrap_or(0) {
                    0 => Ok((model, d.obs.clone())),
                    r => time_offset::shifted(&model, &d.obs, r),
                },
            )
            .collect()
    }

    /// Each fitted run's Φ, gradient and Gauss–Newton matrix over the global `kinds` (μ first;
    /// λ tied to μ at the held Poisson's ratio) under `mat`, and its marker χ² (m²).
    fn normals(
        &self,
        effects: &[Effect],
        mat: &Material,
        kinds: &[ParamKind],
        offsets: &[i64],
    ) -> Result<Vec<(Normal, f64)>, MotionError> {
        let runs = self.retimed(effects, offsets)?;
        self.count(runs.len(), true);
        let mut params: Vec<Param> = kinds.iter().map(|k| Param::global(*k)).collect();
        params.push(Param::global(ParamKind::Lambda));
        let nu = self.o.poisson;
        let ratio = 2.0 * nu / (1.0 - 2.0 * nu);
        use rayon::prelude::*;
        runs.par_iter()
            .map(|(m, obs)| {
                let (ev, gn) = evaluate_gauss_newton(m, mat, &params, obs)?;
                let chi2 = ev.rms_marker * ev.rms_marker * ev.marker_count as f64;
                let all = Normal {
                    phi: ev.phi,
                    grad: ev.grad.unwrap_or_default(),
                    gn,
                };
                Ok((all.tie(0, kinds.len(), ratio), chi2))
            })
            .collect()
    }

    /// χ² (m²) after one Gauss–Newton step over the columns `cols` of `parts` (run χ² and its Φ
    /// in proportion: the marker term's weight is the run's).
    fn stepped_chi2(parts: &[(Normal, f64)], cols: &[usize]) -> f64 {
        let normals: Vec<Normal> = parts.iter().map(|p| p.0.clone()).collect();
        let delta = screen::step(&normals, cols);
        let change = screen::change(&normals, cols, &delta);
        parts
            .iter()
            .zip(change)
            .map(|((n, chi2), d)| {
                let scale = if n.phi > 0.0 { chi2 / n.phi } else { 0.0 };
                (chi2 + scale * d).max(0.0)
            })
            .sum()
    }

    /// The runs with the effects' structural changes (hanging inertia) applied.
    fn models(
        sets: &[(String, MotionDataset)],
        effects: &[Effect],
    ) -> Vec<palpate_motion::model::Model> {
        sets.iter()
            .map(|(_, d)| {
                let mut m = d.model.clone();
                set_hanging_inertia(&mut m, effects.contains(&Effect::HangingInertia));
                m
            })
            .collect()
    }

    /// The residual of every run of `sets` under `mat`, run i's markers `offsets[i]` steps late
    /// (none when `offsets` is empty).
    fn residuals(
        sets: &[(String, MotionDataset)],
        effects: &[Effect],
        mat: &Material,
        offsets: &[i64],
    ) -> Result<Vec<RunResidual>, MotionError> {
        let models = Self::models(sets, effects);
        use rayon::prelude::*;
        sets.par_iter()
            .zip(models.par_iter())
            .enumerate()
            .map(|(i, ((name, d), m))| {
                let r = offsets.get(i).copied().unwrap_or(0);
                let p = predict::predict_offset(m, mat, &d.obs, r)?;
                let mut ds = d.clone();
                ds.model = m.clone();
                Ok(read_residual(name, &ds, &p, r))
            })
            .collect()
    }

    /// Each run's time offset under `mat`, scanned ([`time_offset::scan`]).
    fn scan_offsets(
        sets: &[(String, MotionDataset)],
        effects: &[Effect],
        mat: &Material,
    ) -> Result<Vec<i64>, MotionError> {
        let models = Self::models(sets, effects);
        use rayon::prelude::*;
        sets.par_iter()
            .zip(models.par_iter())
            .map(|((_, d), m)| Ok(time_offset::scan(m, mat, &d.obs)?.0))
            .collect()
    }

    fn describe_offsets(sets: &[(String, MotionDataset)], offsets: &[i64]) -> String {
        sets.iter()
            .zip(offsets)
            .map(|((name, d), r)| {
                let edge = r.abs() >= time_offset::MAX_SCAN_FRAMES * d.model.substeps.max(1) as i64;
                format!(
                    "{name} {:+.1} ms{}",
                    1e3 * *r as f64 * d.model.dt,
                    if edge { " (the edge of the scan)" } else { "" }
                )
            })
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// The viscosity a damping candidate starts from: the option, else the ring-down estimate of
    /// the current model's runs.
    fn start_viscosity(&self, cur: &RunsFit) -> (f64, &'static str) {
        match self.o.start_viscosity {
            Some(v) => (v, "given"),
            None => match viscosity_from_ring_down(&cur.fitted, cur.material.get(ParamKind::Mu, 0))
            {
                Some(v) => (v, "from the measured ring-downs"),
                None => (10.0, "no run rings down: the default"),
            },
        }
    }

    /// Fits the material of `effects` to the fitted runs, run i's markers `offsets[i]` steps late.
    fn fit(
        &self,
        effects: &[Effect],
        start: &Material,
        offsets: &[i64],
        max_iters: u64,
    ) -> Result<RunsFit, MotionError> {
        let mut kinds = vec![ParamKind::Mu];
        for e in effects {
            for k in e.kinds() {
                if !kinds.contains(k) {
                    kinds.push(*k);
                }
            }
        }
        let base = start.clone();
        let params: Vec<Param> = kinds.iter().map(|k| Param::global(*k)).collect();
        let q0 = base.read(&params);
        let retimed = self.retimed(effects, offsets)?;
        let runs: Vec<Run> = retimed
            .iter()
            .map(|(model, obs)| Run { model, obs })
            .collect();
        let settings = FitSettings {
            max_iters,
            poisson: Some(self.o.poisson),
            ..Default::default()
        };
        let r = fit_runs(&runs, &base, &params, &q0, &settings, &[], &|_, _| {})?;
        self.count(r.evaluations * runs.len(), true);
        self.count(runs.len(), false);
        let mut material = base.clone();
        material.set(&params, &r.q);
        let nu = self.o.poisson;
        material.set(
            &[Param::global(ParamKind::Lambda)],
            &[2.0 * nu / (1.0 - 2.0 * nu) * material.get(ParamKind::Mu, 0)],
        );
        let fitted = Self::residuals(self.fit, effects, &material, offsets)?;
        Ok(RunsFit {
            effects: effects.to_vec(),
            material,
            kinds,
            offsets: offsets.to_vec(),
            fitted,
            evaluations: r.evaluations,
            capped: r.iterations >= max_iters,
        })
    }

    /// A fit with the time offset among `effects`, starting from `offsets` (scanned with the
    /// current material for the candidate itself, adopted for a later one): the material refitted
    /// with them held; scanned again with the refitted material, refitted once more if one moved
    /// (module note).
    fn fit_time_offset(
        &self,
        round: usize,
        effects: &[Effect],
        start: &Material,
        mut offsets: Vec<i64>,
        max_iters: u64,
    ) -> Result<RunsFit, MotionError> {
        let mut f = self.fit(effects, start, &offsets, max_iters)?;
        let again = Self::scan_offsets(self.fit, effects, &f.material)?;
        self.count(self.fit.len(), false);
        if again != offsets {
            offsets = again;
            (self.log)(&format!(
                "round {round}: time offsets after the refit: {}",
                Self::describe_offsets(self.fit, &offsets)
            ));
            let evaluations = f.evaluations;
            f = self.fit(effects, &f.material, &offsets, max_iters)?;
            f.evaluations += evaluations;
        }
        Ok(f)
    }

    fn name(e: &[Effect]) -> String {
        if e.is_empty() {
            "the simplest model".into()
        } else {
            e.iter().map(|e| e.name()).collect::<Vec<_>>().join(" + ")
        }
    }
}

impl CandidateModel for RunsModel<'_> {
    type Candidate = Effect;
    type Fitted = RunsFit;
    type Held = Held;
    type Observed = ();
    type Summary = ();
    type Detail = GateDetail;
    type Adoption = ();
    type Error = RunsError;

    fn observe(&mut self, round: usize, f: &RunsFit, h: &Held) {
        for r in f.fitted.iter().chain(&h.runs) {
            (self.log)(&format!(
                "round {round}: {}: RMS {:.2} mm (first quarter {:.2}, last {:.2}); period {} s measured, {} simulated; decay per cycle {} measured, {} simulated",
                r.run,
                1e3 * r.rms_m,
                1e3 * r.early_m,
                1e3 * r.late_m,
                fmt(r.period_s.0, 3),
                fmt(r.period_s.1, 3),
                fmt(r.decay_per_cycle.0, 2),
                fmt(r.decay_per_cycle.1, 2),
            ));
        }
    }

    fn candidates(&mut self, _: &RunsFit, adopted: &[Effect]) -> Vec<Effect> {
        let has_mass = self.fit.iter().chain(self.held).any(|(_, d)| {
            d.model
                .loads
                .iter()
                .any(|l| l.mass.is_some() && l.from_step == 0)
        });
        self.o
            .candidates
            .iter()
            .copied()
            .filter(|c| !adopted.contains(c) && !adopted.iter().any(|a| a.conflicts(*c)))
            .filter(|c| *c != Effect::HangingInertia || has_mass)
            .collect()
    }

    fn fit_with(
        &mut self,
        round: usize,
        cur: &RunsFit,
        c: Effect,
    ) -> Result<Outcome<RunsFit>, RunsError> {
        let mut effects = cur.effects.clone();
        effects.push(c);
        (self.log)(&format!("round {round}: fitting {}", Self::name(&effects)));
        // A candidate that nests one already fitted this round (the power law holds Newtonian
        // damping at h = 1) starts from that fit, its own extra parameters at their neutral
        // values: it starts where the nested model ended, so its fit can only end as low, and
        // it spends no simulations finding the shared parameters again.
        let nested = self
            .fitted
            .iter()
            .rev()
            .find(|(r, d, _)| *r == round && d.nested_in(c))
            .map(|(_, d, m)| (*d, m.clone()));
        let mut start = cur.material.clone();
        if let Some((d, m)) = nested {
            (self.log)(&format!(
                "round {round}: {} starts from the fit of {} (nested in it)",
                c.name(),
                d.name()
            ));
            start = m;
        }
        if c.kinds().contains(&ParamKind::Nu) && start.get(ParamKind::Nu, 0) <= 0.0 {
            let (nu, source) = self.start_viscosity(cur);
            (self.log)(&format!(
                "round {round}: {} starts at viscosity {nu:.3e} Pa·s ({source})",
                c.name()
            ));
            start.set(&[Param::global(ParamKind::Nu)], &[nu]);
        }
        if c == Effect::Stiffening && start.get(ParamKind::Stiffening, 0) <= 0.0 {
            let mu = start.get(ParamKind::Mu, 0);
            (self.log)(&format!(
                "round {round}: stiffening starts at c = μ = {mu:.3e} Pa"
            ));
            start.set_uniform(ParamKind::Stiffening, mu);
        }
        let budget = self.o.screen_max_iters.min(self.o.max_iters);
        let fitted = if c == Effect::TimeOffset {
            let scanned = match self.scanned.take() {
                Some((r, o)) if r == round => o,
                _ => {
                    self.count(self.fit.len(), false);
                    Self::scan_offsets(self.fit, &effects, &start)?
                }
            };
            (self.log)(&format!(
                "round {round}: time offsets scanned (±{} frames, widened to ±{} at an edge): {}",
                time_offset::SCAN_FRAMES,
                time_offset::MAX_SCAN_FRAMES,
                Self::describe_offsets(self.fit, &scanned)
            ));
            if scanned.iter().all(|&r| r == 0) {
                let why = "the scan puts every run in step with the simulation (offsets 0)";
                return Ok(self.not_fitted(round, c, why.into()));
            }
            self.fit_time_offset(round, &effects, &start, scanned, budget)
        } else if effects.contains(&Effect::TimeOffset) {
            self.fit_time_offset(round, &effects, &start, cur.offsets.clone(), budget)
        } else {
            self.fit(&effects, &start, &cur.offsets, budget)
        };
        match fitted {
            Ok(f) => {
                self.fitted.push((round, c, f.material.clone()));
                Ok(Outcome::Fitted(f))
            }
            Err(e) => Ok(self.not_fitted(round, c, e.to_string())),
        }
    }

    fn score(&self, f: &RunsFit) -> Score {
        let (chi2, n) = f.chi2();
        Score {
            chi2,
            n,
            k: f.parameters(),
        }
    }

    fn summarise(&self, _: &RunsFit) {}

    fn heldout(&mut self, round: usize, _: Effect, f: &RunsFit) -> Result<Held, RunsError> {
        let offsets = if f.effects.contains(&Effect::TimeOffset) {
            let o = Self::scan_offsets(self.held, &f.effects, &f.material)?;
            self.count(self.held.len(), false);
            (self.log)(&format!(
                "round {round}: held-out time offsets (each run its own): {}",
                Self::describe_offsets(self.held, &o)
            ));
            o
        } else {
            Vec::new()
        };
        self.count(self.held.len(), false);
        Ok(Held {
            runs: Self::residuals(self.held, &f.effects, &f.material, &offsets)?,
            offsets,
        })
    }

    fn gate(
        &mut self,
        cur: &Current<'_, Self>,
        cand: &select::Candidate<'_, Self>,
    ) -> Gate<GateDetail> {
        let o = self.o;
        let ((c0, _), (c1, n1)) = (cur.held.chi2(), cand.held.chi2());
        let dk = cand.candidate.parameters(self.held.len());
        let heldout_delta_bic = select::heldout_delta_bic(c0, c1, n1, dk);
        let heldout_gain = cand.held.rms() / cur.held.rms() - 1.0;
        let gate = HeldoutGate {
            bic_threshold: o.bic_threshold,
            min_holdout_gain: o.min_holdout_gain,
        };
        let (passes, detail) = gate.judge(
            cand.delta_bic,
            heldout_delta_bic,
            heldout_gain,
            PassWords::Figures,
        );
        let reason = &detail.reason;
        let (fc, fnn) = cand.fitted.chi2();
        (self.log)(&format!(
            "round {}: {}: fitted RMS {:.3} mm, held-out RMS {:.3} mm ({} simulations): {reason}",
            cur.round,
            cand.candidate.name(),
            1e3 * (3.0 * fc / fnn.max(1) as f64).sqrt(),
            1e3 * cand.held.rms(),
            cand.fitted.evaluations
        ));
        self.trials.push(Trial {
            round: cur.round,
            effect: cand.candidate,
            delta_bic: cand.delta_bic,
            rms_fit_m: Some((3.0 * fc / fnn.max(1) as f64).sqrt()),
            rms_held_m: Some(cand.held.rms()),
            gate: Some(detail.clone()),
            not_fitted: None,
            adopted: false,
            predicted_delta_bic: self.prediction(cur.round, cand.candidate),
            screened_out: false,
        });
        Gate {
            passes,
            heldout_delta_bic,
            heldout_rank: cand.held.rms(),
            detail,
        }
    }

    fn adopt(
        &mut self,
        cur: &Current<'_, Self>,
        c: Effect,
        f: RunsFit,
        h: Held,
    ) -> Result<(RunsFit, Held, ()), RunsError> {
        if let Some(t) = self
            .trials
            .iter_mut()
            .rev()
            .find(|t| t.round == cur.round && t.effect == c)
        {
            t.adopted = true;
        }
        if !f.capped {
            return Ok((f, h, ()));
        }
        // Screened with a capped fit: refitted to the full budget before the next round builds
        // on it (its offsets held, its material as the start).
        (self.log)(&format!(
            "round {}: {} stopped at the screening cap ({} iterations): refitting it in full",
            cur.round,
            c.name(),
            self.o.screen_max_iters
        ));
        let evaluations = f.evaluations;
        let mut full = self.fit(&f.effects, &f.material, &f.offsets, self.o.max_iters)?;
        full.evaluations += evaluations;
        let held = self.heldout(cur.round, c, &full)?;
        Ok((full, held, ()))
    }

    fn fit_screen(&self) -> FitScreen {
        if !self.o.screen {
            return FitScreen::Off;
        }
        FitScreen::Predicted {
            least: self.o.screen_least,
            margin: self.o.screen_margin,
            fallback_below: -self.o.bic_threshold,
        }
    }

    fn predict(
        &mut self,
        round: usize,
        cur: &RunsFit,
        open: &[Effect],
    ) -> Result<Vec<select::Prediction>, RunsError> {
        let (chi0, n) = cur.chi2();
        let runs = self.fit.len();
        let delta =
            |chi2: f64, c: Effect| select::heldout_delta_bic(chi0, chi2, n, c.parameters(runs));
        // The continuous candidates: one evaluation with every new parameter at its neutral
        // value, the current model's.
        let mut kinds = cur.kinds.clone();
        for c in open {
            for k in c.kinds() {
                if !kinds.contains(k) {
                    kinds.push(*k);
                }
            }
        }
        let mut mat = cur.material.clone();
        for k in &kinds[cur.kinds.len()..] {
            let neutral = match k {
                ParamKind::PowerH => 1.0,
                _ => 0.0,
            };
            mat.set(&[Param::global(*k)], &[neutral]);
        }
        let continuous = open.iter().any(|c| !c.kinds().is_empty());
        let parts = if continuous {
            self.normals(&cur.effects, &mat, &kinds, &cur.offsets)?
        } else {
            Vec::new()
        };
        let own: Vec<usize> = (0..cur.kinds.len()).collect();
        let mut out = Vec::new();
        for &c in open {
            let p = match c {
                // A switch has no neutral value to linearise about: switched on, a weight that
                // moves with its nodes changes the period, and one Gauss–Newton step from the
                // current material cannot follow (a run whose timing was adopted was predicted
                // +7,233 where its fit was adopted). It is always fitted.
                Effect::HangingInertia => select::Prediction {
                    delta_bic: None,
                    how: "a switch: always fitted".into(),
                },
                Effect::TimeOffset => {
                    let mut effects = cur.effects.clone();
                    effects.push(c);
                    let models = Self::models(self.fit, &effects);
                    use rayon::prelude::*;
                    let scans: Vec<(i64, Vec<(i64, f64)>)> = self
                        .fit
                        .par_iter()
                        .zip(models.par_iter())
                        .map(|((_, d), m)| time_offset::scan(m, &cur.material, &d.obs))
                        .collect::<Result<_, _>>()?;
                    // Each run's χ² in proportion to the scan's own at offset 0 (the scan's
                    // window of steps may differ from the fit's).
                    let chi2: f64 = scans
                        .iter()
                        .zip(&cur.fitted)
                        .map(|((best, tried), r)| {
                            let at = |o: i64| tried.iter().find(|t| t.0 == o).map(|t| t.1);
                            match (at(*best), at(0)) {
                                (Some(b), Some(z)) if z > 0.0 => r.chi2 * b / z,
                                _ => r.chi2,
                            }
                        })
                        .sum();
                    self.count(self.fit.len(), false);
                    self.scanned = Some((round, scans.iter().map(|s| s.0).collect()));
                    select::Prediction {
                        delta_bic: Some(delta(chi2, c)),
                        how: "the offsets scanned, the material not refitted".into(),
                    }
                }
                _ => {
                    let mut cols = own.clone();
                    cols.extend(
                        c.kinds()
                            .iter()
                            .filter_map(|k| kinds.iter().position(|j| j == k))
                            .filter(|i| !own.contains(i)),
                    );
                    // χ² in proportion to the current fit's, so that an evaluation's own
                    // rounding does not count as a gain.
                    let sim: f64 = parts.iter().map(|p| p.1).sum();
                    let chi2 =
                        chi0 * Self::stepped_chi2(&parts, &cols) / sim.max(f64::MIN_POSITIVE);
                    select::Prediction {
                        delta_bic: Some(delta(chi2, c)),
                        how: "one Gauss–Newton step from the neutral value".into(),
                    }
                }
            };
            (self.log)(&format!(
                "round {round}: screen: {} predicted ΔBIC {:.1} ({})",
                c.name(),
                p.delta_bic.unwrap_or(f64::NAN),
                p.how
            ));
            self.predicted
                .push((round, c, p.delta_bic.unwrap_or(f64::NAN)));
            out.push(p);
        }
        Ok(out)
    }

    fn screened_out(&mut self, round: usize, c: Effect, p: &select::Prediction) {
        let d = p.delta_bic.unwrap_or(f64::NAN);
        (self.log)(&format!(
            "round {round}: {} screened out (predicted ΔBIC {d:.1})",
            c.name()
        ));
        self.trials.push(Trial {
            round,
            effect: c,
            delta_bic: f64::NAN,
            rms_fit_m: None,
            rms_held_m: None,
            gate: None,
            not_fitted: Some(format!("screened out: predicted ΔBIC {d:.1} ({})", p.how)),
            adopted: false,
            predicted_delta_bic: Some(d),
            screened_out: true,
        });
    }

    fn progress(&mut self, event: &Progress) {
        (self.progress)(event)
    }
}

fn fmt(v: Option<f64>, digits: usize) -> String {
    v.map_or("–".into(), |v| format!("{v:.digits$}"))
}

/// 1σ of log μ from the curvature of Φ (central second difference) with independent residuals:
/// σ² = 2Φ / ((n − k) Φ''). A lower bound: a ring-down's residuals are correlated in time.
fn mu_sd(
    runs: &[Run<'_>],
    mat: &Material,
    poisson: f64,
    n: usize,
    k: usize,
) -> Result<f64, MotionError> {
    let ratio = 2.0 * poisson / (1.0 - 2.0 * poisson);
    let mu = mat.get(ParamKind::Mu, 0);
    let params = [
        Param::global(ParamKind::Mu),
        Param::global(ParamKind::Lambda),
    ];
    let phi = |z: f64| -> Result<f64, MotionError> {
        let mut m = mat.clone();
        let v = mu * z.exp();
        m.set(&params, &[v, ratio * v]);
        Ok(
            palpate_motion::optimize::evaluate_runs(runs, &m, &params, None)?
                .0
                .phi,
        )
    };
    let h = 1e-2;
    let (p0, pp, pm) = (phi(0.0)?, phi(h)?, phi(-h)?);
    let curv = (pp - 2.0 * p0 + pm) / (h * h);
    if curv <= 0.0 || n <= k {
        return Ok(f64::NAN);
    }
    Ok(mu * (2.0 * p0 / ((n - k) as f64 * curv)).sqrt())
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
    let mut m = RunsModel {
        fit,
        held,
        o,
        log,
        trials: Vec::new(),
        fitted: Vec::new(),
        predicted: Vec::new(),
        scanned: None,
        progress,
        simulations: Default::default(),
    };
    log("fitting the simplest model (Neo-Hookean, fixed Poisson's ratio, no damping)");
    let start = m.fit(&[], &base, &[], o.max_iters)?;
    let start_held = Held {
        runs: {
            m.count(held.len(), false);
            RunsModel::residuals(held, &[], &start.material, &[])?
        },
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
    // Uncertainty of μ (hence E) on the final model (the runs at their offsets).
    let models = RunsModel::models(fit, &last.effects);
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
    let sd_mu = mu_sd(&runs, &last.material, nu, n, last.parameters())?;
    m.count(3 * runs.len(), false);
    let mu = last.material.get(ParamKind::Mu, 0);
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
    if last.kinds.contains(&ParamKind::Nu) {
        values.push(ParamValue {
            name: "viscosity (power law)".into(),
            value: last.material.get(ParamKind::Nu, 0),
            sd: f64::NAN,
            unit: "Pa·s^h".into(),
        });
        values.push(ParamValue {
            name: "power-law index h".into(),
            value: last.material.get(ParamKind::PowerH, 0),
            sd: f64::NAN,
            unit: "".into(),
        });
    }
    if last.kinds.contains(&ParamKind::Stiffening) {
        values.push(ParamValue {
            name: "strain-stiffening c of c (Ī₁ − 3)²".into(),
            value: last.material.get(ParamKind::Stiffening, 0),
            sd: f64::NAN,
            unit: "Pa".into(),
        });
    }
    let rms_of = |v: &[RunResidual]| {
        let (c, n) = v
            .iter()
            .fold((0.0, 0), |(c, n), r| (c + r.chi2, n + r.count));
        if n == 0 {
            0.0
        } else {
            (c / n as f64).sqrt()
        }
    };
    let mat = &last.material;
    let model = FittedModel {
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
        poisson_fixed: Some(nu),
        hanging_inertia: last.effects.contains(&Effect::HangingInertia),
        time_offset: last.effects.contains(&Effect::TimeOffset),
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
            .zip(&models)
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
    };
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
        seconds: t0.elapsed().as_secs_f64(),
        simulations: m.simulations.get(),
    })
}

impl crate::select::CandidateEffect for Effect {
    const LIBRARY: &'static str = "runs candidate";
    fn library() -> Vec<Self> {
        ALL_EFFECTS.to_vec()
    }
    fn label(self) -> String {
        self.name().into()
    }
}

#[cfg(test)]
mod tests {
    use super::{ring_down, viscosity_from_ring_down, Effect, RunResidual, ALL_EFFECTS};

    /// Only Newtonian damping nests in another candidate (the power law at h = 1); switches and
    /// the time offset nest nothing, and nothing nests in itself.
    #[test]
    fn only_newtonian_damping_nests_in_the_power_law() {
        for a in ALL_EFFECTS {
            for b in ALL_EFFECTS {
                let expected = a == Effect::Damping && b == Effect::DampingPowerLaw;
                assert_eq!(a.nested_in(b), expected, "{a:?} in {b:?}");
            }
        }
    }

    #[test]
    fn ring_down_reads_period_and_decay_of_a_damped_sine() {
        let dt = 0.01;
        let (period, ratio) = (0.25, 0.7f64);
        let s: Vec<f64> = (0..500)
            .map(|n| {
                let t = n as f64 * dt;
                5.0 + 3.0 * ratio.powf(t / period) * (2.0 * std::f64::consts::PI * t / period).cos()
            })
            .collect();
        let (p, d) = ring_down(&s, dt);
        assert!((p.unwrap() / period - 1.0).abs() < 0.01, "{p:?}");
        assert!((d.unwrap() / ratio - 1.0).abs() < 0.03, "{d:?}");
        assert_eq!(ring_down(&[1.0; 100], dt), (None, None));
    }

    /// The viscosity start: ν = 2ζμ/ω with ζ = −ln a/2π, the geometric mean over the runs that
    /// ring, `None` when none does. A single-degree-of-freedom check: a mode of ω = 2π/T whose
    /// amplitude falls by a per cycle has ζ/√(1−ζ²) = −ln a/2π; at a = 0.72 (the beam) ζ differs
    /// from −ln a/2π by 0.14 %, well inside what a start needs.
    #[test]
    fn viscosity_start_follows_the_ring_down() {
        let run = |t: Option<f64>, a: Option<f64>| RunResidual {
            run: String::new(),
            rms_m: 0.0,
            chi2: 0.0,
            count: 0,
            per_marker_m: Vec::new(),
            early_m: 0.0,
            late_m: 0.0,
            final_rms_m: 0.0,
            load_n: 0.0,
            ring_marker: String::new(),
            period_s: (t, None),
            decay_per_cycle: (a, None),
            time_offset_s: 0.0,
            ring: (Vec::new(), Vec::new()),
        };
        let mu = 4.6e4;
        let one = viscosity_from_ring_down(&[run(Some(0.13), Some(0.72))], mu).unwrap();
        let zeta = -(0.72f64).ln() / (2.0 * std::f64::consts::PI);
        let omega = 2.0 * std::f64::consts::PI / 0.13;
        assert!((one - 2.0 * zeta * mu / omega).abs() < 1e-9 * one, "{one}");
        // A run twice as damped at the same period: twice the viscosity; the mean is geometric.
        let two = viscosity_from_ring_down(&[run(Some(0.13), Some(0.72 * 0.72))], mu).unwrap();
        assert!((two / one - 2.0).abs() < 1e-12);
        let both = viscosity_from_ring_down(
            &[
                run(Some(0.13), Some(0.72)),
                run(Some(0.13), Some(0.72 * 0.72)),
            ],
            mu,
        )
        .unwrap();
        assert!((both / (one * two).sqrt() - 1.0).abs() < 1e-12);
        // No ring-down, a growing one, or none measured: no estimate.
        assert_eq!(viscosity_from_ring_down(&[run(None, None)], mu), None);
        assert_eq!(
            viscosity_from_ring_down(&[run(Some(0.13), Some(1.1))], mu),
            None
        );
        assert_eq!(viscosity_from_ring_down(&[], mu), None);
    }
}
