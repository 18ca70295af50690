//! Residual diagnosis of a motion dataset, on top of the motion fitter:
//! fit the simplest model the dataset supports (Neo-Hookean, no viscosity), look at the residual
//! per marker and step ([`signature`](mod@signature)), hold each candidate effect against it by refitting
//! ([`candidates`]: one file per candidate, each a [`MotionEffect`]), keep the one that predicts
//! held-out data, repeat, and report ([`report`]).
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

pub mod candidates;
mod engine;
pub mod fit;
pub mod floors;
pub mod mesh;
pub mod mesh_null;
pub mod region;
mod region_rank;
pub mod report;
pub mod run;
pub mod screen;
pub mod signature;

pub use candidates::{Candidate, MotionEffect, ALL_CANDIDATES};

use crate::select::{select, Policy, Rank, Screen};
use engine::{motion_rounds, MotionModel};
use fit::{fit_model, FittedModel, Scores, Split};
use palpate_motion::dataset::MotionDataset;
use palpate_motion::model::{Material, Param, ParamKind};
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
    /// Predict each round's candidates before fitting them and fit only the best predicted
    /// ([`screen`]); `false`: fit every open candidate (the full search).
    pub screen: bool,
    /// With the screen: fewest candidates fitted per round.
    pub screen_least: usize,
    /// With the screen: a candidate is fitted when its predicted ΔBIC is within this fraction of
    /// the best predicted one's magnitude.
    pub screen_margin: f64,
    /// Measure the dataset mesh's own discretisation error at the simplest fit and state it
    /// in the report ([`mesh`]): two more simulations, one of them on the mesh refined once.
    pub mesh_error: bool,
    /// The error is measured only when the refined mesh has at most this many tetrahedra.
    pub refine_max_tets: usize,
    /// Check a passing candidate against the mesh's own null before adopting it
    /// ([`mesh_null`]): it must gain more on the data than on data the current model makes on
    /// the mesh refined once (with `mesh_error`).
    pub mesh_null: bool,
    /// Fit the capture's rest state (its last 0.5 s) on linear and quadratic elements after the
    /// diagnosis ([`crate::convergence`]): whether the fitted modulus is the material's or the
    /// mesh's. Skipped, saying why, where the markers have not settled.
    pub mesh_convergence: bool,
    /// Refit the final model on quadratic elements of the same mesh over the fitted steps
    /// ([`crate::motion_convergence`]): every parameter beside the linear one. Off by default
    /// (a quadratic model costs several times a linear one).
    pub motion_convergence: bool,
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
            screen: true,
            screen_least: 2,
            screen_margin: 0.5,
            mesh_error: true,
            refine_max_tets: 50_000,
            mesh_null: true,
            mesh_convergence: true,
            motion_convergence: false,
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
    /// ΔBIC the fit screen predicted before any fit (`None`: screen off, or not predicted).
    pub predicted_delta_bic: Option<f64>,
    /// Left unfitted by the fit screen.
    pub screened_out: bool,
    /// Its check against the mesh's own null, when it passed on the data and was next in line
    /// for adoption ([`mesh_null`]).
    pub mesh_null: Option<mesh_null::NullCheck>,
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
    /// Why no candidate was tried in this round, when the current forecast leaves none a chance
    /// to pass the held-out gate (`forecast_at_floor` in `engine.rs`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub settled: Option<String>,
}

/// The declared noise floor of a marker error: σ√3, the RMS of a 3-D error whose axes carry
/// the declared σ (`marker_noise` in dataset.toml); `None` when none is declared.
pub(in crate::motion) fn noise_floor(ds: &MotionDataset) -> Option<f64> {
    ds.config.marker_noise.map(|s| s * 3f64.sqrt())
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
    /// Figures these data determine only relative to another, in words: with neither a measured
    /// force nor a known load, the moduli and the viscosity relative to the density held.
    pub relative: Vec<String>,
    /// The final model's fitted parameters that ended on their floors, and what that means
    /// ([`floors`]).
    pub on_floor: Vec<floors::OnFloor>,
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
    /// Simulations of the optimiser's fits: the simplest model's and every trial's.
    pub evaluations: usize,
    /// Simulations of the fit screen (one with sensitivities per round, and each time-offset
    /// scan).
    pub screen_simulations: usize,
    /// The dataset mesh's own discretisation error at the simplest fit, stated.
    pub mesh: mesh::MeshNote,
    /// The simulation step and why, with its own error measured on the capture
    /// ([`palpate_motion::timestep::TimeStep::describe`]).
    pub time_step: String,
    /// The step's error at the final model against its fitted residual
    /// ([`palpate_motion::step_error::at_fitted`]).
    pub fitted_step_error: crate::runs::RunStepError,
    /// Whether the fitted modulus is the material's or the mesh's ([`crate::convergence`]);
    /// `None` when not asked for.
    pub mesh_convergence: Option<crate::convergence::MeshConvergence>,
    /// The final model refitted on quadratic elements ([`crate::motion_convergence`]); `None`
    /// when not asked for.
    pub motion_convergence: Option<crate::motion_convergence::MotionConvergence>,
    /// What the mesh's own null says of the fitted parameters under one refinement
    /// ([`mesh_null::MeshBias`]); `None` when no null was made.
    pub mesh_bias: Option<mesh_null::MeshBias>,
    /// What the dataset mesh's own error leaves in the final residual, by which both checks'
    /// floor is widened ([`mesh_null::MeshFloor`]); `None` when the residual is the noise's
    /// alone, the check is off, or no null could be made.
    pub mesh_floor: Option<mesh_null::MeshFloor>,
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
        let mut v = format!("{}{which}", worse.verdict(&adopted));
        // A candidate that passed beside the one adopted, whose parameters the adopted one holds
        // (it leaves them unidentified): it cannot be tested after that adoption, so the verdict
        // says it is not ruled out.
        for r in &self.rounds {
            let Some(a) = r.adopted.as_deref().and_then(candidates::Candidate::named) else {
                continue;
            };
            let held = a.effect().holds();
            for t in r.trials.iter().filter(|t| t.passed) {
                let unidentified = candidates::Candidate::named(&t.candidate)
                    .is_some_and(|b| b.kinds().iter().any(|k| held.contains(k)));
                if unidentified {
                    v.push_str(&format!(
                        "; {} passed too in round {}, and with {} in the model it cannot be told \
                         from them: it is not ruled out",
                        t.candidate,
                        r.round,
                        a.name()
                    ));
                }
            }
        }
        // Candidates refused against the mesh's own null: what the mesh leaves by itself there
        // is the scale of what is left here.
        let refused: Vec<(&str, &mesh_null::NullCheck)> = self
            .rounds
            .iter()
            .flat_map(|r| &r.trials)
            .filter_map(|t| t.mesh_null.as_ref().map(|c| (t.candidate.as_str(), c)))
            .filter(|(_, c)| c.refused)
            .collect();
        if let Some((_, last)) = refused.last().filter(|_| worse.judged && worse.ratio > 1.0) {
            let mut names: Vec<&str> = Vec::new();
            for (n, _) in &refused {
                if !names.contains(n) {
                    names.push(n);
                }
            }
            if let Some(floor) = last.noise_floor {
                // The null holds no noise: its residual is the mesh's alone, set against what
                // stands above the floor here (the excess over the noise, in quadrature).
                let above = floor * (worse.ratio * worse.ratio - 1.0).max(0.0).sqrt();
                v.push_str(&format!(
                    "; the mesh's own error left on its null ({} refused against it; the current \
                     model refitted there, noise-free, to {:.1} µm) is {:.0} % of what stands \
                     above the floor here ({:.1} µm in quadrature)",
                    names.join(", "),
                    1e6 * last.base_rms_fit,
                    100.0 * (last.base_rms_fit / above).powi(2),
                    1e6 * above
                ));
            }
        }
        v
    }
}

/// The material's values, then each effect's in the fitted model ([`MotionEffect::values`], in
/// [`candidates::REPORT_ORDER`]).
fn values_of(m: &FittedModel, model: &palpate_motion::model::Model) -> Vec<Value> {
    let material = ParamKind::ALL.iter().filter_map(|&k| {
        let i = m.kinds.iter().position(|&x| x == k);
        // A fixed value is read outside every region (element 0 may be in one).
        let value = match i {
            Some(i) => m.values[i],
            None => m.material.read(&[Param::global(k)])[0],
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
    });
    material
        .chain(
            candidates::REPORT_ORDER
                .iter()
                .flat_map(|c| c.effect().values(m, model)),
        )
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
    let mut base = Material::uniform(ne, lambda0, mu0, 0.0, 1.0, density);
    base.viscous_form = ds.model.viscous_form;
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
    let (floor, judged) = match noise_floor(ds) {
        Some(f) => (f, true),
        None => (f64::NAN, false),
    };
    let (mesh_note, refined) = mesh::estimate(ds, &simplest, floor, o, log);
    let mut engine = MotionModel::new(ds, split, o, log);
    engine.fine = refined.ok_or_else(|| mesh_note.statement.clone());
    let rounds_max = o.max_effects.max(1);
    let policy = Policy {
        rounds: rounds_max,
        max_adopted: rounds_max,
        rank: Rank::FittedBicOrSimplerForecast {
            margin: o.bic_threshold,
        },
        // The held-out steps are simulated with every fit (a forecast): gating is free.
        screen: Screen::All,
    };
    let verdict = select(&mut engine, &policy, simplest.clone(), simplest.scores)?;
    let screen_simulations = engine.screen_simulations;
    let rounds = motion_rounds(
        &verdict,
        ds.model.markers.len(),
        &engine.null_checks,
        &engine.settled,
    );
    let evaluations = simplest.evaluations
        + rounds
            .iter()
            .flat_map(|r| &r.trials)
            .map(|t| t.evaluations)
            .sum::<usize>();
    let adopted = verdict.adopted();
    let cur = verdict
        .path
        .last()
        .map(|p| p.0.clone())
        .expect("the start is on the path");
    // The final residual against the noise floor, and where either check finds more than the
    // noise, against the floor widened by what the dataset mesh's own error leaves
    // ([`mesh_null::MeshFloor`]): a residual the mesh alone would leave is not an effect.
    let check = |rms: f64, n: usize, k: usize, remaining: f64| {
        if remaining > 0.0 {
            crate::ResidualCheck::with_discretisation(rms, floor, remaining, n, k, judged)
        } else {
            crate::ResidualCheck::new(rms, floor, n, k, judged)
        }
    };
    let (s, k) = (cur.scores, cur.values.len());
    let unexplained = !check(s.rms_fit, s.n_fit, k, 0.0).explained
        || !check(s.rms_held, s.n_held, 0, 0.0).explained;
    let mesh_floor = if unexplained && o.mesh_error && o.mesh_null {
        log("the final residual stands above the noise floor: what the mesh's own error leaves of it");
        let last = adopted.last().map(|&c| (adopted.len(), c));
        let f = engine.mesh_floor(adopted.len() + 1, &cur, last);
        if let Some(f) = &f {
            log(&format!(
                "the final model refitted on its null ({} tetrahedra) leaves {:.1} µm fitted, \
                 {:.1} µm held out: the floor is widened by them",
                f.refined_tets,
                1e6 * f.null_rms_fit,
                1e6 * f.null_rms_held
            ));
        }
        f
    } else {
        None
    };
    let (remaining_fit, remaining_held) = mesh_floor
        .as_ref()
        .map_or((0.0, 0.0), |f| (f.null_rms_fit, f.null_rms_held));
    let evaluations = evaluations + mesh_floor.as_ref().map_or(0, |f| f.evaluations);
    let mesh_convergence = o.mesh_convergence.then(|| {
        let mean = |k| (0..ne).map(|e| cur.material.get(k, e)).sum::<f64>() / ne.max(1) as f64;
        let (lambda, mu) = (mean(ParamKind::Lambda), mean(ParamKind::Mu));
        let poisson = lambda / (2.0 * (lambda + mu));
        crate::convergence::check(&[(label, ds)], poisson, mu, cur.scores.rms_fit, log)
    });
    let motion_convergence = o.motion_convergence.then(|| {
        let scale = mesh_convergence
            .as_ref()
            .and_then(|c| c.converged_modulus())
            .map_or(1.0, |c| c.shear_modulus_pa / c.mesh_shear_modulus_pa);
        // The fitted rows only, on the final model's clock, its markers' offsets eliminated.
        let timed = match cur.time_offset {
            Some(r) if r != 0 => fit::retimed(ds, split, r),
            _ => Ok((ds.clone(), split)),
        };
        match timed {
            Err(e) => crate::motion_convergence::MotionConvergence::Skipped {
                reason: format!("the final model's time offset could not be applied: {e}"),
            },
            Ok((mut d, s)) => {
                d.model.steps = s.fit_steps;
                d.obs.markers.truncate(s.fit_steps);
                d.obs.free_marker_offsets |= cur.offsets.is_some();
                crate::motion_convergence::check(
                    &[(label, &d.model, &d.obs)],
                    &cur.material,
                    &cur.kinds,
                    None,
                    scale,
                    cur.scores.rms_fit,
                    log,
                )
            }
        }
    });
    // Where the capture has no rest state to check the modulus on and no check made a null,
    // the first round's null is made now, for what it says of the parameters under one
    // refinement ([`mesh_null::MeshBias`]): one refined simulation and one refit.
    let rest_checked = matches!(
        mesh_convergence,
        Some(crate::convergence::MeshConvergence::Checked { .. })
    );
    if o.mesh_convergence && o.mesh_null && !rest_checked {
        engine.first_null_bias(&simplest);
    }
    // What the step puts into the final residual, measured at the final material on the final
    // model's clock (marker offsets cancel in the difference of two simulations).
    let measured = (|| {
        let retimed;
        let d = match cur.time_offset {
            Some(r) if r != 0 => {
                retimed = fit::retimed(ds, split, r).map_err(|e| e.to_string())?.0;
                &retimed
            }
            _ => ds,
        };
        palpate_motion::step_error::at_fitted(&d.model, &d.obs, &cur.material, cur.scores.rms_fit)
    })();
    match &measured {
        Ok(e) => log(&format!("the step's own error {}", e.describe())),
        Err(why) => log(&format!("the step's own error not measured: {why}")),
    }
    let fitted_step_error = crate::runs::RunStepError {
        run: label.to_string(),
        not_measured: measured.as_ref().err().cloned(),
        measured: measured.ok(),
    };
    let mut sp_b = Vec::new();
    let final_signature = signature(ds, split, &cur);
    sp_b.extend(signature(ds, split, &simplest).speed_bins);
    let after_values = values_of(&cur, &ds.model);
    Ok(MotionDiagnosis {
        dataset: label.to_string(),
        size: (ne, ds.model.markers.len(), steps, ds.model.dt),
        split,
        density_declared: ds.config.density.is_some(),
        time_step: ds.timestep.describe(),
        fitted_step_error,
        relative: relative_figures(ds, &adopted, &cur),
        on_floor: floors::of_values(&after_values),
        options: o.clone(),
        rule: format!(
            "BIC = n ln(χ²/n) + k ln n over the n scalar marker residuals (unknown noise \
             variance). Parameters are fitted on steps 1..={fit_steps}; the whole trajectory is \
             simulated and steps {}..={steps} are scored as held out (a forecast). A candidate \
             passes if ΔBIC < −{} on the fitted steps AND the held-out ΔBIC (same formula on the \
             held-out residuals) < 0 AND the held-out RMS drops by ≥ {:.0} %; the first passing \
             candidate in fitted-ΔBIC order is adopted; repeat until none passes.{}",
            fit_steps + 1,
            o.bic_threshold,
            100.0 * o.min_holdout_gain,
            if o.mesh_error && o.mesh_null {
                " Before it is adopted, a passing candidate that the mesh's own error could \
                 imitate is fitted again on the mesh's null (the current model simulated on the \
                 mesh refined once, with the declared noise) and must gain more on the data than \
                 there by the same thresholds (ΔBIC and held-out RMS beyond the null's)."
            } else {
                ""
            }
        ),
        rounds,
        adopted: adopted.iter().map(|c| c.name().to_string()).collect(),
        before_values: values_of(&simplest, &ds.model),
        before: simplest.scores,
        after_values,
        after: cur.scores,
        speed_before: sp_b,
        speed_after: final_signature.speed_bins.clone(),
        final_signature,
        residual_check: check(s.rms_fit, s.n_fit, k, remaining_fit),
        heldout_check: check(s.rms_held, s.n_held, 0, remaining_held),
        mesh_floor,
        evaluations,
        screen_simulations,
        mesh: mesh_note,
        mesh_convergence,
        motion_convergence,
        mesh_bias: engine.mesh_bias.clone(),
        material: Some(cur.material.clone()),
    })
}

/// What the final fit `cur` knows only relative to another figure. With prescribed clamps, no
/// measured clamp force and no known load, M a = f_int + f_visc + M g divides through by ρ: the
/// motion depends on λ/ρ, μ/ρ and the viscosity over ρ only, so the moduli and the viscosity are
/// those of the density held (declared or assumed), and a density off by a factor moves them
/// all by it — which the value tables do not show.
fn relative_figures(ds: &MotionDataset, adopted: &[Candidate], cur: &FittedModel) -> Vec<String> {
    let forces = ds.obs.forces.iter().flatten().flatten().count() > 0;
    if forces || !ds.model.loads.is_empty() || adopted.contains(&Candidate::Density) {
        return Vec::new();
    }
    vec![format!(
        "the moduli λ and μ and the viscosity are relative to the density ρ = {} kg/m³ ({}): \
         with prescribed clamps and neither a measured force nor a known load, the motion \
         depends on λ/ρ, μ/ρ and the viscosity over ρ only — μ/ρ is determined, not μ",
        palpate_fem::numbers::plain(cur.material.get(ParamKind::Density, 0)),
        if ds.config.density.is_some() {
            "declared"
        } else {
            "assumed: not declared"
        }
    )]
}
