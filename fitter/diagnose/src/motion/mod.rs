//! Residual diagnosis of a motion dataset, on top of the motion fitter:
//! fit the simplest model the dataset supports (Neo-Hookean, no viscosity), look at the residual
//! per marker and step ([`signature`](mod@signature)), hold each candidate effect against it by refitting, keep
//! the one that predicts held-out data, repeat, and report ([`report`]).
//!
//! **Held-out data = a forecast.** Parameters are fitted on the first
//! (1 − [`MotionOptions::holdout_fraction`]) of the time steps; the whole trajectory is simulated
//! and only the last steps are scored as held out. An extra parameter must therefore predict
//! motion it was not fitted to.
//!
//! **The simplest model.** Neo-Hookean (λ, μ) with viscosity ν = 0 *held fixed* (not a parameter
//! of the optimiser, so its log transform never sees 0; the viscous stress ν γ̇^(h−1)(∇v + ∇vᵀ)
//! of eq. 17 is then exactly zero, h = 1 is irrelevant), density as declared in dataset.toml
//! (1000 kg/m³ if not).
//!
//! **Adoption rule** (stated in every report): with n scalar marker residuals on the fitted steps,
//! χ² their sum of squares and k the number of free parameters, BIC = n ln(χ²/n) + k ln n
//! (unknown noise variance). A candidate passes if (a) ΔBIC < −[`MotionOptions::bic_threshold`]
//! on the fitted steps, (b) the same criterion on the held-out steps,
//! n_h ln(χ²_h,new/χ²_h,old) + Δk ln n_h, is negative, and (c) the held-out RMS marker error
//! drops by at least [`MotionOptions::min_holdout_gain`]. The first passing candidate in
//! fitted-ΔBIC order is adopted; repeat until none passes.

pub mod fit;
pub mod region;
pub mod report;
pub mod run;
pub mod signature;

use crate::select::{
    self, select, CandidateModel, Current, Gate, GateDetail, HeldoutGate, Outcome, PassWords,
    Policy, Rank, Score, Screen, Verdict,
};
use fit::{fit_model, fit_with_offsets, with_offsets, FittedModel, Scores, Split};
use palpate_motion::dataset::MotionDataset;
use palpate_motion::model::{Material, Param, ParamKind};
use palpate_motion::time_offset;
use rayon::prelude::*;
use serde::Serialize;
use signature::{signature, Signature};
use std::path::Path;

/// The motion diagnosis's errors: the crate's one [`crate::Error`] (the name kept for its
/// callers).
pub type MotionDiagnoseError = crate::Error;

/// True when `dir` holds a motion dataset: a `dataset.toml` with a `dt` key (the static format
/// has none) — [`palpate_motion::dataset::load`] then needs `trajectories.csv` or `forces.csv`.
pub fn is_motion_dataset(dir: &Path) -> bool {
    let Ok(text) = std::fs::read_to_string(dir.join("dataset.toml")) else {
        return false;
    };
    text.parse::<toml::Table>()
        // `clamps` is the static datasets' key for their clamped face too; only a static dataset
        // has a `probe_radius`.
        .is_ok_and(|t| {
            t.contains_key("dt") || (t.contains_key("clamps") && !t.contains_key("probe_radius"))
        })
}

/// Refits that move the two-material candidate's boundary ([`MotionModel::fit_two_material`]).
const REGION_REFITS: usize = 4;

/// Steps the time-offset candidate moves from its scanned offset, each way, while a refit there
/// lowers χ² ([`MotionModel::fit_timed`]).
const OFFSET_NEIGHBOURS: usize = 3;

/// A candidate effect the simplest motion model lacks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Candidate {
    /// Power-law viscosity of eq. 17: ν and h free (2 parameters).
    Viscosity,
    /// Newtonian viscosity: ν free, h = 1 (1 parameter).
    ViscosityNewtonian,
    /// Density free (1 parameter); only identifiable with measured clamp forces.
    Density,
    /// Each marker sits at a constant offset from its declared place (3 parameters per marker):
    /// a marker glued a millimetre from where `markers.csv` says, a marker's centre above the
    /// surface, a capture registered with a small shift. Eliminated in closed form (each
    /// marker's mean residual on the fitted steps, [`fit::fit_with_offsets`]); the held-out
    /// steps use the offsets fitted on the fitted steps.
    MarkerOffsets,
    /// The markers are recorded out of step with the clamps' record (1 parameter: an integer
    /// number of simulation steps, [`palpate_motion::time_offset`]): two capture streams on two
    /// clocks, or a start instant misread. Scanned on the fitted steps within ±3 capture frames (widened to ±12 while the best lies at the edge)
    /// with the current material, the material refitted, scanned again (refitted once more if it
    /// moved), then the neighbouring offsets refitted while χ² falls (a scan at 0 has both ±1
    /// fitted); the held-out steps are forecast at the same offset.
    TimeOffset,
    /// The material stiffens at larger strains beyond Neo-Hookean: a Yeoh-type c (Ī₁ − 3)² term
    /// beside eq. 16 (1 parameter, fitted in ln c from c = μ).
    Stiffening,
    /// A body of two materials (the second material's shear modulus, and its region's shape
    /// charged as [`fit::REGION_SHAPE_PARAMS`] more parameters). Where it sits
    /// is found first, from the misfit's sensitivity to each element's own μ at the current fit
    /// ([`region`]): of the map's level sets, the region whose screened fit is best; its μ is
    /// then fitted, the rest keeps the global μ (λ stays one value: Poisson's ratio differs
    /// between the two).
    TwoMaterial,
}

/// Every candidate, in the order they are tried.
pub const ALL_CANDIDATES: [Candidate; 7] = [
    Candidate::Viscosity,
    Candidate::ViscosityNewtonian,
    Candidate::Density,
    Candidate::MarkerOffsets,
    Candidate::TimeOffset,
    Candidate::Stiffening,
    Candidate::TwoMaterial,
];

impl Candidate {
    /// Name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::Viscosity => "viscosity",
            Self::ViscosityNewtonian => "viscosity-newtonian",
            Self::Density => "density",
            Self::MarkerOffsets => "marker-offsets",
            Self::TimeOffset => "time-offset",
            Self::Stiffening => "stiffening",
            Self::TwoMaterial => "two-material",
        }
    }
    /// Parameters it adds to a model of `markers` markers.
    pub fn extra_params(self, markers: usize) -> usize {
        match self {
            Self::MarkerOffsets => 3 * markers,
            Self::TimeOffset => 1,
            Self::TwoMaterial => 1 + fit::REGION_SHAPE_PARAMS,
            c => c.kinds().len(),
        }
    }
    /// Parameters it frees.
    pub fn kinds(self) -> &'static [ParamKind] {
        match self {
            Self::Viscosity => &[ParamKind::Nu, ParamKind::PowerH],
            Self::ViscosityNewtonian => &[ParamKind::Nu],
            Self::Density => &[ParamKind::Density],
            Self::Stiffening => &[ParamKind::Stiffening],
            Self::MarkerOffsets | Self::TimeOffset | Self::TwoMaterial => &[],
        }
    }
    /// Effects that exclude each other (the two viscosity laws).
    fn conflicts(self, other: Candidate) -> bool {
        matches!(
            (self, other),
            (Self::Viscosity, Self::ViscosityNewtonian)
                | (Self::ViscosityNewtonian, Self::Viscosity)
        )
    }
}

/// Options of [`diagnose`].
#[derive(Debug, Clone, Serialize)]
pub struct MotionOptions {
    /// Candidates to try.
    pub candidates: Vec<Candidate>,
    /// Fraction of the time steps held out at the end of the trajectory.
    pub holdout_fraction: f64,
    /// Most effects adopted.
    pub max_effects: usize,
    /// Optimiser iteration cap of each fit.
    pub max_iters: u64,
    /// LBFGS iterations of each screened start of a new non-linear parameter.
    pub screen_iters: u64,
    /// Fitted ΔBIC must be below −this.
    pub bic_threshold: f64,
    /// Held-out RMS must drop by at least this fraction.
    pub min_holdout_gain: f64,
}

impl Default for MotionOptions {
    fn default() -> Self {
        Self {
            candidates: ALL_CANDIDATES.to_vec(),
            holdout_fraction: 0.25,
            max_effects: 2,
            max_iters: 150,
            screen_iters: 15,
            bic_threshold: 10.0,
            min_holdout_gain: 0.05,
        }
    }
}

/// A fitted parameter with its 1σ.
#[derive(Debug, Clone, Serialize)]
pub struct Value {
    /// Name (lambda, mu, nu, h, density).
    pub name: String,
    /// Value (SI).
    pub value: f64,
    /// 1σ (Gauss–Newton; `None` when not available).
    pub sigma: Option<f64>,
}

/// One candidate's refit and scores.
#[derive(Debug, Clone, Serialize)]
pub struct Trial {
    /// Candidate name.
    pub candidate: String,
    /// False when the candidate was not fitted (see `reason`).
    pub fitted: bool,
    /// Free parameters of the augmented model.
    pub k: usize,
    /// Fitted values.
    pub values: Vec<Value>,
    /// Error figures.
    pub scores: Scores,
    /// ΔBIC on the fitted steps.
    pub delta_bic: f64,
    /// ΔBIC on the held-out steps.
    pub heldout_delta_bic: f64,
    /// Relative change of the held-out RMS (negative = better).
    pub heldout_gain: f64,
    /// Passes the rule.
    pub passed: bool,
    /// Why it passed or failed.
    pub reason: String,
    /// Simulations.
    pub evaluations: usize,
}

/// One round: the residual of the current model and what was tried against it.
#[derive(Debug, Clone, Serialize)]
pub struct Round {
    /// 1-based.
    pub round: usize,
    /// Effects adopted before this round.
    pub model: Vec<String>,
    /// Signature of the current residual.
    pub signature: Signature,
    /// Candidates tried.
    pub trials: Vec<Trial>,
    /// Adopted candidate, if any.
    pub adopted: Option<String>,
}

/// The diagnosis of a motion dataset.
#[derive(Debug, Clone, Serialize)]
pub struct MotionDiagnosis {
    /// Dataset label.
    pub dataset: String,
    /// Tets, markers, steps, dt.
    pub size: (usize, usize, usize, f64),
    /// Split into fitted and held-out steps.
    pub split: Split,
    /// Whether dataset.toml declares the density.
    pub density_declared: bool,
    /// Options used.
    pub options: MotionOptions,
    /// The rule, in words.
    pub rule: String,
    /// Rounds.
    pub rounds: Vec<Round>,
    /// Adopted effects in order.
    pub adopted: Vec<String>,
    /// Simplest model: parameters and scores.
    pub before_values: Vec<Value>,
    /// Simplest model's scores.
    pub before: Scores,
    /// Final model's parameters (all five material quantities; fixed ones with `sigma: None`).
    pub after_values: Vec<Value>,
    /// Final model's scores.
    pub after: Scores,
    /// Signature of the final residual.
    pub final_signature: Signature,
    /// Residual vs relative marker speed, simplest model (for the plot).
    pub speed_before: Vec<(f64, f64)>,
    /// Same for the final model.
    pub speed_after: Vec<(f64, f64)>,
    /// The final fitted residual against the declared marker noise floor σ√3
    /// (`marker_noise` in dataset.toml; not judged when it is not declared).
    pub residual_check: crate::ResidualCheck,
    /// The same for the held-out (forecast) steps, no fitted parameters.
    pub heldout_check: crate::ResidualCheck,
    /// Final material (for export; not serialised).
    #[serde(skip)]
    pub material: Option<Material>,
}

impl MotionDiagnosis {
    /// The verdict a user reads: never "clean" while the fitted or the forecast residual stands
    /// significantly above the declared noise floor.
    pub fn verdict(&self) -> String {
        let adopted = self.adopted.join(", ");
        // The worse of the two checks speaks.
        let worse = if self.heldout_check.judged && self.heldout_check.z > self.residual_check.z {
            &self.heldout_check
        } else {
            &self.residual_check
        };
        let which = if std::ptr::eq(worse, &self.heldout_check) {
            " (held-out forecast)"
        } else {
            ""
        };
        format!("{}{which}", worse.verdict(&adopted))
    }
}

/// The material's values, and the time offset (s, from steps of `dt`) when the model has one.
fn values_of(m: &FittedModel, model: &palpate_motion::model::Model) -> Vec<Value> {
    let dt = model.dt;
    let offset = m.time_offset.map(|r| Value {
        name: "time offset of the markers (s)".into(),
        value: r as f64 * dt,
        sigma: None,
    });
    ParamKind::ALL
        .iter()
        .filter_map(|&k| {
            let i = m.kinds.iter().position(|&x| x == k);
            let value = match i {
                Some(i) => m.values[i],
                None => m.material.get(k, 0),
            };
            // The stiffening term is listed where it is in the model, not as a fixed 0.
            if k == ParamKind::Stiffening && i.is_none() && value == 0.0 {
                return None;
            }
            Some(Value {
                name: format!("{}{}", k.name(), if i.is_some() { "" } else { " (fixed)" }),
                value,
                sigma: i.and_then(|i| m.sigma.as_ref().map(|s| s[i])),
            })
        })
        .chain(region_values(m, model))
        .chain(offset)
        .collect()
}

/// The shear modulus of each region of `m`'s material (the second material of a two-material
/// body), named with where the region is.
fn region_values(m: &FittedModel, model: &palpate_motion::model::Model) -> Vec<Value> {
    let first = m.values.len() - m.material.regions.len();
    let mu_rest = m.material.read(&[Param::global(ParamKind::Mu)])[0];
    m.material
        .regions
        .iter()
        .enumerate()
        .map(|(r, elements)| Value {
            name: format!(
                "mu of the second material ({})",
                region::describe(model, elements, m.values[first + r] > mu_rest)
            ),
            value: m.values[first + r],
            sigma: m.sigma.as_ref().map(|s| s[first + r]),
        })
        .collect()
}

/// Starting values of a candidate's parameters, given the current fit: the global values, the
/// candidate's new ones, then each region's μ ([`fit::params_for`]).
fn starts(c: Candidate, cur: &FittedModel, ds: &MotionDataset) -> Vec<Vec<f64>> {
    let globals = cur.kinds.len();
    let regions = &cur.values[globals..];
    starts_of_new(c, cur, ds)
        .into_iter()
        .map(|mut q| {
            q.extend_from_slice(regions);
            q
        })
        .collect()
}

/// [`starts`] without the regions' values.
fn starts_of_new(c: Candidate, cur: &FittedModel, ds: &MotionDataset) -> Vec<Vec<f64>> {
    let base: Vec<f64> = cur.values[..cur.kinds.len()].to_vec();
    let mu = cur.material.read(&[Param::global(ParamKind::Mu)])[0];
    let dt = ds.model.dt;
    match c {
        // Viscous time τ = ν/μ over three decades around the step: 0.03, 0.3 and 3 Δt.
        Candidate::Viscosity | Candidate::ViscosityNewtonian => [0.03, 0.3, 3.0]
            .iter()
            .map(|f| {
                let mut q = base.clone();
                q.push(mu * f * dt);
                if c == Candidate::Viscosity {
                    q.push(1.0);
                }
                q
            })
            .collect(),
        Candidate::Density => {
            let mut q = base;
            q.push(cur.material.get(ParamKind::Density, 0));
            vec![q]
        }
        // From c = μ: at 10 % strain the term adds about 6 % to the Neo-Hookean energy.
        Candidate::Stiffening => {
            let mut q = base;
            q.push(mu);
            vec![q]
        }
        Candidate::MarkerOffsets | Candidate::TimeOffset | Candidate::TwoMaterial => vec![base],
    }
}

/// The motion diagnosis as the selection engine sees it.
struct MotionModel<'a> {
    ds: &'a MotionDataset,
    split: Split,
    o: &'a MotionOptions,
    /// Measured clamp forces: the density is identifiable only with them.
    has_forces: bool,
    log: &'a (dyn Fn(&str) + Sync),
}

impl MotionModel<'_> {
    /// The fit of `c` on top of `cur` on the data `ds` split at `split`.
    fn fit_on(
        &self,
        ds: &MotionDataset,
        split: Split,
        cur: &FittedModel,
        c: Candidate,
        kinds: &[ParamKind],
    ) -> Result<FittedModel, MotionDiagnoseError> {
        match (c, &cur.offsets) {
            (Candidate::MarkerOffsets, _) => fit_with_offsets(
                ds,
                split,
                &cur.material,
                kinds,
                &cur.values,
                self.o.max_iters,
            ),
            // Offsets adopted: later candidates refit the material and the offsets together.
            (_, Some(_)) => fit_with_offsets(
                ds,
                split,
                &cur.material,
                kinds,
                &starts(c, cur, ds)[0],
                self.o.max_iters,
            ),
            (_, None) => fit_model(
                ds,
                split,
                &cur.material,
                kinds,
                &starts(c, cur, ds),
                self.o.max_iters,
                self.o.screen_iters,
            ),
        }
    }

    /// The time offset of the fitted steps under `mat` with the marker offsets `offsets`, scanned
    /// ([`time_offset::scan`]; the held-out steps are a forecast and take no part).
    fn scan_offset(
        &self,
        mat: &Material,
        offsets: Option<&[[f64; 3]]>,
    ) -> Result<i64, MotionDiagnoseError> {
        let ds = offsets.map_or_else(|| self.ds.clone(), |o| with_offsets(self.ds, o));
        let (model, obs) = fit::fitted_part(&ds, self.split);
        Ok(time_offset::scan(&model, mat, &obs)?.0)
    }

    /// A fit at the time offset `r` (the candidate's own, scanned with the current material, or
    /// the adopted one): the fit on the re-timed data, its trajectory and scores read back on the
    /// data's rows; for the time-offset candidate the offset is scanned again with the refitted
    /// material and, if it moved, the material refitted once more; then the neighbouring offsets
    /// are refitted while that lowers χ² on the fitted steps (at most [`OFFSET_NEIGHBOURS`] steps
    /// each way): the scan runs at a material fitted without the offset, and on a strongly loaded
    /// run it can settle a step off (−2 for −3 on drawn specimens, the fit then far above the
    /// floor).
    fn fit_timed(
        &self,
        cur: &FittedModel,
        c: Candidate,
        kinds: &[ParamKind],
        mut r: i64,
    ) -> Result<FittedModel, MotionDiagnoseError> {
        let mut evaluations = 0;
        let mut rescanned = false;
        let mut m = loop {
            let m = self.fit_at(cur, c, kinds, r, &mut evaluations)?;
            if c != Candidate::TimeOffset || rescanned {
                break m;
            }
            let again = self.scan_offset(&m.material, m.offsets.as_deref())?;
            if again == r {
                break m;
            }
            (r, rescanned) = (again, true);
        };
        if c == Candidate::TimeOffset {
            for dir in [-1, 1] {
                for _ in 0..OFFSET_NEIGHBOURS {
                    let next = m.time_offset.unwrap_or(r) + dir;
                    match self.fit_at(cur, c, kinds, next, &mut evaluations) {
                        Ok(n) if n.scores.chi2_fit < m.scores.chi2_fit => m = n,
                        _ => break,
                    }
                }
            }
            m.evaluations = evaluations;
        }
        Ok(m)
    }

    /// One fit of `c` at the time offset `r`, its simulations added to `evaluations`.
    fn fit_at(
        &self,
        cur: &FittedModel,
        c: Candidate,
        kinds: &[ParamKind],
        r: i64,
        evaluations: &mut usize,
    ) -> Result<FittedModel, MotionDiagnoseError> {
        let (d, split) = fit::retimed(self.ds, self.split, r)?;
        let mut m = self.fit_on(&d, split, cur, c, kinds)?;
        *evaluations += m.evaluations;
        let data = m
            .offsets
            .as_deref()
            .map_or_else(|| self.ds.clone(), |o| with_offsets(self.ds, o));
        m.traj = fit::run_trajectory_at(&data.model, &m.material, &data.obs, r)?;
        m.scores = fit::scores(&m.traj, self.split);
        m.time_offset = Some(r);
        m.evaluations = *evaluations;
        (self.log)(&format!(
            "  {} fitted at a time offset of {:+.1} ms",
            c.name(),
            1e3 * r as f64 * self.ds.model.dt
        ));
        Ok(m)
    }

    /// The time offset when the scan says 0. The scan runs at a material fitted without an
    /// offset, which has absorbed part of one: a step off is what it can miss (random bars: 2 of
    /// 8 draws with ±1 step were scanned to 0 and another effect adopted, 25–34× the floor).
    /// Both neighbours are fitted for [`MotionOptions::screen_iters`] iterations; the better,
    /// if it lowers χ² on the fitted steps below the current model's, is fitted in full and its
    /// own neighbours that way while χ² falls ([`Self::fit_timed`]), and gated as any other fit.
    fn fit_step_off(&self, cur: &FittedModel) -> Result<Outcome<FittedModel>, MotionDiagnoseError> {
        let c = Candidate::TimeOffset;
        let screen = MotionOptions {
            max_iters: self.o.screen_iters,
            ..self.o.clone()
        };
        let screener = MotionModel {
            o: &screen,
            ..*self
        };
        // The two neighbours are independent fits: one per core.
        let fits: Vec<(i64, usize, Option<FittedModel>)> = [-1i64, 1]
            .par_iter()
            .map(|&r| {
                let mut evaluations = 0;
                let m = screener.fit_at(cur, c, &cur.kinds, r, &mut evaluations);
                (r, evaluations, m.ok())
            })
            .collect();
        let evaluations: usize = fits.iter().map(|f| f.1).sum();
        let mut best: Option<(FittedModel, i64)> = None;
        for (r, _, m) in fits {
            if let Some(m) = m {
                if best
                    .as_ref()
                    .is_none_or(|(b, _)| m.scores.chi2_fit < b.scores.chi2_fit)
                {
                    best = Some((m, r));
                }
            }
        }
        let r = match best {
            Some((m, r)) if m.scores.chi2_fit < cur.scores.chi2_fit => r,
            _ => {
                return Ok(Outcome::NotFitted(
                    "the scan puts the markers in step with the simulation (offset 0), and a \
                     step either way fits no better"
                        .into(),
                ))
            }
        };
        Ok(match self.fit_timed(cur, c, &cur.kinds, r) {
            Ok(mut m) => {
                m.evaluations += evaluations;
                Outcome::Fitted(m)
            }
            Err(e) => Outcome::NotFitted(format!("fit failed: {e}")),
        })
    }
}

impl MotionModel<'_> {
    /// The fit of `c` from `cur`, at `cur`'s time offset if it has one (no new scan).
    fn fit_from(
        &self,
        cur: &FittedModel,
        c: Candidate,
    ) -> Result<FittedModel, MotionDiagnoseError> {
        let mut kinds = cur.kinds.clone();
        kinds.extend_from_slice(c.kinds());
        match cur.time_offset {
            Some(r) => self.fit_timed(cur, c, &kinds, r),
            None => self.fit_on(self.ds, self.split, cur, c, &kinds),
        }
    }

    /// The two-material candidate: where first ([`region::locate`]: the sensitivity map's
    /// nested level sets), each coarse cut's region μ fitted beside the global one from the
    /// current model for [`region::SCREEN_ITERS`] iterations, then every cut between the
    /// best one's neighbours ([`region::FINE_LEVELS`] at most); the region whose screened fit
    /// has the lowest χ² on the fitted steps is fitted in full, and its boundary refined on
    /// adoption ([`Self::refine_boundary`]). The held-out steps choose nothing.
    fn fit_two_material(
        &self,
        cur: &FittedModel,
    ) -> Result<Outcome<FittedModel>, MotionDiagnoseError> {
        let c = Candidate::TwoMaterial;
        let family = match region::locate(self.ds, self.split, cur) {
            Ok(Some(f)) => f,
            Ok(None) => {
                return Ok(Outcome::NotFitted(
                    "the misfit's sensitivity to each element's μ has one sign everywhere: no \
                     second material to place"
                        .into(),
                ))
            }
            Err(e) => return Ok(Outcome::NotFitted(format!("locating it failed: {e}"))),
        };
        // Each region starts at the current μ: the fit starts from the current model (its χ²),
        // where the map says which way the region's μ goes, and can only improve on it. (A start
        // 1.5× off that way, and a 5 × 5 grid of starting contrasts with the rest's λ moving with
        // its μ, were tried: the first ended worse than the current model on the independent
        // cylinder with marker offsets adopted, the second never beat the one-material point on
        // the two-material test bar — neither kept. Starts 2× and 4× off on the random bars
        // ended where the current μ's start did: the region, not the start, was what was wrong.)
        let mu = cur.material.read(&[Param::global(ParamKind::Mu)])[0];
        let screen = MotionOptions {
            max_iters: self.o.screen_iters.min(region::SCREEN_ITERS),
            ..self.o.clone()
        };
        let screener = MotionModel {
            o: &screen,
            ..*self
        };
        let mut best: Option<(FittedModel, usize)> = None;
        let (mut screened, mut evaluations) = (0, 0);
        let mut failures = Vec::new();
        // The screens are independent fits: one per core.
        let mut scan = |cuts: &[usize], best: &mut Option<(FittedModel, usize)>| {
            let fits: Vec<(usize, Result<FittedModel, MotionDiagnoseError>)> = cuts
                .par_iter()
                .map(|&k| {
                    let mut start = cur.clone();
                    start.material.regions.push(family.region(k).elements);
                    start.values.push(mu);
                    (k, screener.fit_from(&start, c))
                })
                .collect();
            for (k, fit) in fits {
                screened += 1;
                match fit {
                    Ok(m) => {
                        evaluations += m.evaluations;
                        if best
                            .as_ref()
                            .is_none_or(|(b, _)| m.scores.chi2_fit < b.scores.chi2_fit)
                        {
                            *best = Some((m, k));
                        }
                    }
                    Err(e) => failures.push(format!("cut {k}: {e}")),
                }
            }
        };
        let coarse = family.coarse();
        scan(&coarse, &mut best);
        if let Some(k) = best.as_ref().map(|b| b.1) {
            scan(&family.between(&coarse, k, region::FINE_LEVELS), &mut best);
        }
        let Some((start, k)) = best else {
            return Ok(Outcome::NotFitted(format!(
                "fit failed on all {screened} candidate regions: {}",
                failures.join("; ")
            )));
        };
        let region = family.region(k);
        (self.log)(&format!(
            "  two-material: region of {} (the best of {screened} level sets of the sensitivity \
             map)",
            region::describe(&self.ds.model, &region.elements, region.stiffer),
        ));
        let mut best = match self.fit_from(&start, c) {
            Ok(m) => m,
            Err(e) => return Ok(Outcome::NotFitted(format!("fit failed: {e}"))),
        };
        best.evaluations += evaluations;
        Ok(Outcome::Fitted(best))
    }

    /// The adopted two-material model with its region's boundary moved while that lowers the
    /// fitted misfit: the elements whose switch of material lowers Φ to first order
    /// ([`region::switches`]) — all of them, else the better half, quarter, … (a first-order
    /// estimate overshoots when many move at once) —, refitted and kept only if χ² on the fitted
    /// steps fell; at most [`REGION_REFITS`] refits. Done on adoption only: each refit is a
    /// whole fit, and a candidate that does not pass the gate with its located region is not
    /// refined into passing.
    fn refine_boundary(&self, gated: FittedModel) -> FittedModel {
        let c = Candidate::TwoMaterial;
        let mut best = gated.clone();
        let ne = self.ds.model.tets.len();
        let mut refits = 0;
        'passes: while refits < REGION_REFITS {
            let grad = match region::sensitivity(self.ds, self.split, &best) {
                Ok(g) => g,
                Err(e) => {
                    (self.log)(&format!("  two-material: boundary: {e}; region kept"));
                    break;
                }
            };
            let mu_in = best.values[best.values.len() - 1];
            let mu_out = best.material.read(&[Param::global(ParamKind::Mu)])[0];
            let region = best.material.regions[0].clone();
            let moves = region::switches(&region, &grad, mu_in, mu_out);
            let mut k = moves.len();
            while k > 0 && refits < REGION_REFITS {
                let Some(next) = region::switched(&region, &moves[..k], ne) else {
                    k /= 2;
                    continue;
                };
                refits += 1;
                let mut start = best.clone();
                start.material.regions[0] = next;
                if let Ok(mut m) = self.fit_from(&start, c) {
                    if m.scores.chi2_fit < best.scores.chi2_fit {
                        (self.log)(&format!(
                            "  two-material: boundary: {k} element(s) switched, region of {} \
                             elements, fitted RMS {:.1} → {:.1} µm",
                            m.material.regions[0].len(),
                            1e6 * best.scores.rms_fit,
                            1e6 * m.scores.rms_fit
                        ));
                        m.evaluations += best.evaluations;
                        best = m;
                        continue 'passes;
                    }
                }
                k /= 2;
            }
            break;
        }
        if best.material.regions != gated.material.regions {
            (self.log)(&format!(
                "  two-material: boundary refined on adoption: region of {} elements, RMS \
                 {:.1}/{:.1} → {:.1}/{:.1} µm fitted/held out",
                best.material.regions[0].len(),
                1e6 * gated.scores.rms_fit,
                1e6 * gated.scores.rms_held,
                1e6 * best.scores.rms_fit,
                1e6 * best.scores.rms_held
            ));
        }
        best
    }
}

impl CandidateModel for MotionModel<'_> {
    type Candidate = Candidate;
    type Fitted = FittedModel;
    /// The held-out (forecast) figures are part of every fit's scores.
    type Held = Scores;
    type Observed = Signature;
    /// Free values (fixed ones left out), scores, simulations run.
    type Summary = (Vec<Value>, Scores, usize);
    type Detail = GateDetail;
    type Adoption = ();
    type Error = MotionDiagnoseError;

    fn observe(&mut self, _round: usize, f: &FittedModel, _held: &Scores) -> Signature {
        signature(self.ds, self.split, f)
    }

    fn candidates(&mut self, _current: &FittedModel, adopted: &[Candidate]) -> Vec<Candidate> {
        let open = |c: &Candidate| !adopted.iter().any(|&a| a == *c || a.conflicts(*c));
        self.o.candidates.iter().copied().filter(open).collect()
    }

    fn fit_with(
        &mut self,
        _round: usize,
        cur: &FittedModel,
        c: Candidate,
    ) -> Result<Outcome<FittedModel>, MotionDiagnoseError> {
        if c == Candidate::Density && !self.has_forces {
            return Ok(Outcome::NotFitted(
                "not identifiable from markers alone: with prescribed clamps the motion \
                 depends on λ/ρ, μ/ρ, ν/ρ only (M a = f_int + M g), so ρ needs measured \
                 clamp forces (forces.csv)"
                    .into(),
            ));
        }
        if c == Candidate::TwoMaterial {
            return self.fit_two_material(cur);
        }
        // With a time offset (this candidate, or adopted before) every fit runs on the data
        // re-timed to the simulation's clock and is read back on the data's own rows
        // (`fit_from` for an adopted one).
        let r = if c == Candidate::TimeOffset {
            let r = match self.scan_offset(&cur.material, cur.offsets.as_deref()) {
                Ok(r) => r,
                Err(e) => return Ok(Outcome::NotFitted(format!("scan failed: {e}"))),
            };
            if r == 0 {
                return self.fit_step_off(cur);
            }
            self.fit_timed(cur, c, &cur.kinds, r)
        } else {
            self.fit_from(cur, c)
        };
        // A failed fit is a finding about this candidate, not the end of the diagnosis.
        Ok(match r {
            Ok(m) => Outcome::Fitted(m),
            Err(e) => Outcome::NotFitted(format!("fit failed: {e}")),
        })
    }

    fn score(&self, m: &FittedModel) -> Score {
        Score {
            chi2: m.scores.chi2_fit,
            n: m.scores.n_fit,
            k: m.parameter_count(),
        }
    }

    fn summarise(&self, m: &FittedModel) -> (Vec<Value>, Scores, usize) {
        let mut values: Vec<Value> = values_of(m, &self.ds.model)
            .into_iter()
            .filter(|v| !v.name.ends_with("(fixed)"))
            .collect();
        if let Some(off) = &m.offsets {
            let largest = off
                .iter()
                .map(|c| (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt())
                .fold(0.0, f64::max);
            values.push(Value {
                name: format!("marker offsets ({} markers): largest |c| (m)", off.len()),
                value: largest,
                sigma: None,
            });
        }
        (values, m.scores, m.evaluations)
    }

    fn heldout(
        &mut self,
        _round: usize,
        _c: Candidate,
        m: &FittedModel,
    ) -> Result<Scores, MotionDiagnoseError> {
        Ok(m.scores)
    }

    fn gate(
        &mut self,
        cur: &Current<'_, Self>,
        cand: &select::Candidate<'_, Self>,
    ) -> Gate<GateDetail> {
        let o = self.o;
        let (s0, s1) = (cur.held, cand.held);
        let delta_bic = cand.delta_bic;
        let dk = cand.candidate.extra_params(self.ds.model.markers.len());
        let heldout_delta_bic =
            select::heldout_delta_bic(s0.chi2_held, s1.chi2_held, s1.n_held, dk);
        let heldout_gain = s1.rms_held / s0.rms_held - 1.0;
        let gate = HeldoutGate {
            bic_threshold: o.bic_threshold,
            min_holdout_gain: o.min_holdout_gain,
        };
        let (passes, detail) = gate.judge(
            delta_bic,
            heldout_delta_bic,
            heldout_gain,
            PassWords::WithThresholds,
        );
        let reason = &detail.reason;
        (self.log)(&format!(
            "round {}: {}: RMS {:.1}/{:.1} µm, ΔBIC {delta_bic:.1}, held-out ΔBIC \
             {heldout_delta_bic:.1}, {reason}",
            cur.round,
            cand.candidate.name(),
            1e6 * s1.rms_fit,
            1e6 * s1.rms_held
        ));
        Gate {
            passes,
            heldout_delta_bic,
            heldout_rank: s1.rms_held,
            detail,
        }
    }

    fn adopt(
        &mut self,
        _cur: &Current<'_, Self>,
        c: Candidate,
        m: FittedModel,
        held: Scores,
    ) -> Result<(FittedModel, Scores, ()), MotionDiagnoseError> {
        if c == Candidate::TwoMaterial {
            let m = self.refine_boundary(m);
            let held = m.scores;
            return Ok((m, held, ()));
        }
        Ok((m, held, ()))
    }
}

/// The motion report's rounds from the engine's verdict (trials in the order tried).
fn motion_rounds(v: &Verdict<MotionModel<'_>>, markers: usize) -> Vec<Round> {
    v.rounds
        .iter()
        .map(|r| {
            // Round r starts from path[r − 1]; a candidate adds its kinds to that model's.
            let k0 = v.path[r.round - 1].0.parameter_count();
            let trials = r
                .attempts
                .iter()
                .map(|a| match (&a.summary, &a.gate, &a.score) {
                    (Some((values, scores, evaluations)), Some(g), Some(s)) => Trial {
                        candidate: a.candidate.name().into(),
                        fitted: true,
                        k: s.k,
                        values: values.clone(),
                        scores: *scores,
                        delta_bic: a.delta_bic,
                        heldout_delta_bic: g.detail.heldout_delta_bic,
                        heldout_gain: g.detail.heldout_gain,
                        passed: g.passes,
                        reason: g.detail.reason.clone(),
                        evaluations: *evaluations,
                    },
                    _ => Trial {
                        candidate: a.candidate.name().into(),
                        fitted: false,
                        k: k0 + a.candidate.extra_params(markers),
                        values: Vec::new(),
                        scores: Scores::default(),
                        delta_bic: f64::NAN,
                        heldout_delta_bic: f64::NAN,
                        heldout_gain: f64::NAN,
                        passed: false,
                        reason: a.not_fitted.clone().unwrap_or_default(),
                        evaluations: 0,
                    },
                })
                .collect();
            Round {
                round: r.round,
                model: r.model.iter().map(|c| c.name().to_string()).collect(),
                signature: r.observed.clone(),
                trials,
                adopted: r.adopted_attempt().map(|a| a.candidate.name().to_string()),
            }
        })
        .collect()
}

/// Runs the diagnosis. `log` receives one line per fit.
pub fn diagnose(
    ds: &MotionDataset,
    label: &str,
    o: &MotionOptions,
    log: &(dyn Fn(&str) + Sync),
) -> Result<MotionDiagnosis, MotionDiagnoseError> {
    let observed = ds.obs.markers.iter().flatten().flatten().count();
    if observed == 0 {
        return Err(MotionDiagnoseError::Input(format!(
            "{label}: no marker observations (trajectories.csv): the motion diagnosis reads the \
             residual of tracked markers; a forces-only dataset can be fitted with \
             `palpate fit-motion` but not diagnosed"
        )));
    }
    let steps = ds.model.steps;
    if steps < 8 {
        return Err(MotionDiagnoseError::Input(format!(
            "{label}: {steps} time steps; the diagnosis needs at least 8 (the last {:.0} % are \
             held out as a forecast)",
            100.0 * o.holdout_fraction
        )));
    }
    let fit_steps =
        ((steps as f64 * (1.0 - o.holdout_fraction)).round() as usize).clamp(2, steps - 1);
    let split = Split { fit_steps, steps };
    let ne = ds.model.tets.len();
    let start = palpate_motion::start::initial_values(ds, None);
    log(&format!("{label}: {}", start.note));
    let (lambda0, mu0) = (start.lambda, start.mu);
    let density = ds.config.density.unwrap_or(1000.0);
    let has_forces = ds.obs.forces.iter().flatten().flatten().count() > 0;
    let base = Material::uniform(ne, lambda0, mu0, 0.0, 1.0, density);
    log(&format!(
        "{label}: {ne} tets, {} markers, {steps} steps of {:.4} s; fitting steps 1..={fit_steps}, \
         forecasting {}..={steps}",
        ds.model.markers.len(),
        ds.model.dt,
        fit_steps + 1
    ));
    let elastic = [ParamKind::Lambda, ParamKind::Mu];
    let simplest = fit_model(
        ds,
        split,
        &base,
        &elastic,
        &[vec![lambda0, mu0]],
        o.max_iters,
        o.screen_iters,
    )?;
    log(&format!(
        "simplest (elastic): RMS {:.1} µm fitted, {:.1} µm held out",
        1e6 * simplest.scores.rms_fit,
        1e6 * simplest.scores.rms_held
    ));
    let mut engine = MotionModel {
        ds,
        split,
        o,
        has_forces,
        log,
    };
    let rounds_max = o.max_effects.max(1);
    let policy = Policy {
        rounds: rounds_max,
        max_adopted: rounds_max,
        rank: Rank::FittedBic,
        // The held-out steps are simulated with every fit (a forecast): gating is free.
        screen: Screen::All,
    };
    let verdict = select(&mut engine, &policy, simplest.clone(), simplest.scores)?;
    let rounds = motion_rounds(&verdict, ds.model.markers.len());
    let adopted = verdict.adopted();
    let cur = verdict
        .path
        .last()
        .map(|p| p.0.clone())
        .expect("the start is on the path");
    let mut sp_b = Vec::new();
    let final_signature = signature(ds, split, &cur);
    // The declared marker noise σ per axis: the RMS of a 3-D marker error is σ√3 at the floor.
    let (floor, judged) = match ds.config.marker_noise {
        Some(s) => (s * 3f64.sqrt(), true),
        None => (f64::NAN, false),
    };
    sp_b.extend(signature(ds, split, &simplest).speed_bins);
    Ok(MotionDiagnosis {
        dataset: label.to_string(),
        size: (ne, ds.model.markers.len(), steps, ds.model.dt),
        split,
        density_declared: ds.config.density.is_some(),
        options: o.clone(),
        rule: format!(
            "BIC = n ln(χ²/n) + k ln n over the n scalar marker residuals (unknown noise \
             variance). Parameters are fitted on steps 1..={fit_steps}; the whole trajectory is \
             simulated and steps {}..={steps} are scored as held out (a forecast). A candidate \
             passes if ΔBIC < −{} on the fitted steps AND the held-out ΔBIC (same formula on the \
             held-out residuals) < 0 AND the held-out RMS drops by ≥ {:.0} %; the first passing \
             candidate in fitted-ΔBIC order is adopted; repeat until none passes.",
            fit_steps + 1,
            o.bic_threshold,
            100.0 * o.min_holdout_gain
        ),
        rounds,
        adopted: adopted.iter().map(|c| c.name().to_string()).collect(),
        before_values: values_of(&simplest, &ds.model),
        before: simplest.scores,
        after_values: values_of(&cur, &ds.model),
        after: cur.scores,
        speed_before: sp_b,
        speed_after: final_signature.speed_bins.clone(),
        final_signature,
        residual_check: crate::ResidualCheck::new(
            cur.scores.rms_fit,
            floor,
            cur.scores.n_fit,
            cur.values.len(),
            judged,
        ),
        heldout_check: crate::ResidualCheck::new(
            cur.scores.rms_held,
            floor,
            cur.scores.n_held,
            0,
            judged,
        ),
        material: Some(cur.material.clone()),
    })
}

impl crate::select::CandidateEffect for Candidate {
    const LIBRARY: &'static str = "motion candidate";
    fn library() -> Vec<Self> {
        ALL_CANDIDATES.to_vec()
    }
    fn label(self) -> String {
        self.name().into()
    }
}
