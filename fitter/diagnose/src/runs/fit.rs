//! The runs room's fits: the runs' models with the candidates' changes, the material fitted to
//! the fitted runs (retimed when an effect offsets them in time), their residuals, and the time
//! offsets scanned.

use palpate_motion::dataset::MotionDataset;
use palpate_motion::fitted::set_hanging_inertia;
use palpate_motion::gradient::Evaluation;
use palpate_motion::line_minimum::line_minimum;
use palpate_motion::model::{Material, Observations, Param, ParamKind};
use palpate_motion::optimize::{evaluate_runs, fit_runs, precision, FitSettings, Run};
use palpate_motion::predict::{self, Simulated};
use palpate_motion::step_error::{self, FittedStepError};
use palpate_motion::time_offset;
use palpate_motion::MotionError;

use super::candidates::Effect;
use super::signature::read_residual;
use super::{RunResidual, RunsFit, RunsOptions, Simulations, Trial};
use crate::select::{Outcome, Progress};

/// The runs room's driver: the runs, the options, and what the selection has recorded so far.
pub(in crate::runs) struct RunsModel<'a> {
    /// The fitted runs.
    pub(in crate::runs) fit: &'a [(String, MotionDataset)],
    /// The held-out runs.
    pub(in crate::runs) held: &'a [(String, MotionDataset)],
    /// The options.
    pub(in crate::runs) o: &'a RunsOptions,
    /// Receives progress lines.
    pub(in crate::runs) log: &'a dyn Fn(&str),
    /// Every candidate tried, as reported.
    pub(in crate::runs) trials: Vec<Trial>,
    /// Each fitted candidate's material, by round: the start of a later candidate of the same
    /// round that nests it.
    pub(in crate::runs) fitted: Vec<(usize, Effect, Material)>,
    /// The fit screen's predictions, by round.
    pub(in crate::runs) predicted: Vec<(usize, Effect, f64)>,
    /// Where the fit screen's step took a candidate's new parameter, by round
    /// ([`ScreenPoint::stepped_to`](super::screen::ScreenPoint::stepped_to)): the start of its fit
    /// where that is above the candidate's own start.
    pub(in crate::runs) landed: Vec<(usize, ParamKind, f64)>,
    /// The time offsets the screen scanned at the current material, by round: the start of the
    /// time offset's fit in that round.
    pub(in crate::runs) scanned: Option<(usize, Vec<i64>)>,
    /// Receives the selection's progress.
    pub(in crate::runs) progress: &'a dyn Fn(&Progress),
    /// Simulations so far.
    pub(in crate::runs) simulations: std::cell::Cell<Simulations>,
    /// The round's candidates fitted ahead of their turn, side by side.
    pub(in crate::runs) ahead: crate::select::Ahead<Effect, super::select::AheadFit>,
    /// The hanging weights' lever read from the fitted runs' rest states (the `load-point`
    /// candidate's), when they hang a weight and give one.
    pub(in crate::runs) lever: Option<palpate_motion::load_point::LeverFit>,
    /// The floor of the creep branch's relaxation time: the longest ring-down period measured
    /// in the fitted runs (`None` when none rings). A branch that relaxes within a period of the
    /// ring-down acts on it as a dashpot, which the damping candidates are; held above it, the
    /// branch is what the creep candidate says it is, relaxation slower than the ring-down.
    pub(in crate::runs) creep_floor: Option<f64>,
}

/// The last value recorded for `key` in `round` in a screen's per-round list.
fn of_round<K: PartialEq>(list: &[(usize, K, f64)], round: usize, key: K) -> Option<f64> {
    list.iter()
        .rev()
        .find(|(r, k, _)| *r == round && *k == key)
        .map(|l| l.2)
}

impl RunsModel<'_> {
    /// Counts `n` simulations of one run, with sensitivities or without.
    pub(in crate::runs) fn count(&self, n: usize, sensitivities: bool) {
        let mut s = self.simulations.get();
        if sensitivities {
            s.with_sensitivities += n;
        } else {
            s.plain += n;
        }
        self.simulations.set(s);
    }

    /// Records a candidate that could not be fitted, and tells the engine why.
    pub(in crate::runs) fn not_fitted(
        &mut self,
        round: usize,
        effect: Effect,
        why: String,
    ) -> Outcome<RunsFit> {
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
    pub(in crate::runs) fn prediction(&self, round: usize, effect: Effect) -> Option<f64> {
        of_round(&self.predicted, round, effect)
    }

    /// Where the fit screen's step took `kind` in `round`, if it was predicted there.
    pub(in crate::runs) fn landing(&self, round: usize, kind: ParamKind) -> Option<f64> {
        of_round(&self.landed, round, kind)
    }

    /// The fitted runs with `effects`' structural changes, run i's markers `offsets[i]` steps
    /// late.
    pub(in crate::runs) fn retimed(
        &self,
        effects: &[Effect],
        offsets: &[i64],
    ) -> Result<Vec<(palpate_motion::model::Model, Observations)>, MotionError> {
        self.models(self.fit, effects)
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

    /// The runs' models with the effects' changes ([`RunsEffect::change_model`](super::candidates::RunsEffect::change_model)) applied.
    pub(in crate::runs) fn models(
        &self,
        sets: &[(String, MotionDataset)],
        effects: &[Effect],
    ) -> Vec<palpate_motion::model::Model> {
        sets.iter()
            .map(|(_, d)| {
                let mut m = d.model.clone();
                // The simplest model: hung weights move with their nodes unless their inertia is
                // a candidate (`RunsOptions::weights_move`).
                set_hanging_inertia(&mut m, self.o.weights_move());
                for e in effects {
                    e.effect().change_model(self, &mut m);
                }
                m
            })
            .collect()
    }

    /// The residual of every run of `sets` under `mat`, run i's markers `offsets[i]` steps late
    /// (none when `offsets` is empty); counts the simulations.
    pub(in crate::runs) fn residuals(
        &self,
        sets: &[(String, MotionDataset)],
        effects: &[Effect],
        mat: &Material,
        offsets: &[i64],
    ) -> Result<Vec<RunResidual>, MotionError> {
        self.readings(sets, effects, mat, offsets, Vec::new())
    }

    /// [`Self::residuals`] with run i read from `simulated[i]`, a simulation of it under `mat`
    /// already made, where there is one and the run is not offset in time (an offset run's
    /// simulation is of the model run longer, [`time_offset::shifted`]); the others simulated,
    /// and counted.
    pub(in crate::runs) fn readings(
        &self,
        sets: &[(String, MotionDataset)],
        effects: &[Effect],
        mat: &Material,
        offsets: &[i64],
        mut simulated: Vec<Option<Simulated>>,
    ) -> Result<Vec<RunResidual>, MotionError> {
        let models = self.models(sets, effects);
        simulated.resize(sets.len(), None);
        let offset = |i: usize| offsets.get(i).copied().unwrap_or(0);
        let fresh = (0..sets.len())
            .filter(|&i| offset(i) != 0 || simulated[i].is_none())
            .count();
        self.count(fresh, false);
        use rayon::prelude::*;
        sets.par_iter()
            .zip(models.par_iter())
            .zip(simulated.into_par_iter())
            .enumerate()
            .map(|(i, (((name, d), m), sim))| {
                let r = offset(i);
                let p = match sim.filter(|_| r == 0) {
                    Some(sim) => predict::assess(m, mat, &d.obs, sim)?,
                    None => predict::predict_offset(m, mat, &d.obs, r)?,
                };
                let mut ds = d.clone();
                ds.model = m.clone();
                Ok(read_residual(name, &ds, p, r))
            })
            .collect()
    }

    /// The runs `sets` with `effects`' changes, each at its offset `offsets[i]` (0 past the end)
    /// and held to its residual `residuals[i]`: what [`step_errors`] measures.
    pub(in crate::runs) fn step_error_runs<'s>(
        &self,
        sets: &'s [(String, MotionDataset)],
        effects: &[Effect],
        offsets: &[i64],
        residuals: &[RunResidual],
    ) -> Vec<StepErrorRun<'s>> {
        self.models(sets, effects)
            .into_iter()
            .zip(sets)
            .zip(residuals)
            .enumerate()
            .map(|(i, ((model, (_, d)), r))| StepErrorRun {
                model,
                obs: &d.obs,
                offset: offsets.get(i).copied().unwrap_or(0),
                rms_m: r.rms_m,
                simulated: r.simulated.clone(),
            })
            .collect()
    }

    /// Each run's time offset under `mat`, scanned ([`time_offset::scan`]).
    pub(in crate::runs) fn scan_offsets(
        &self,
        sets: &[(String, MotionDataset)],
        effects: &[Effect],
        mat: &Material,
    ) -> Result<Vec<i64>, MotionError> {
        let models = self.models(sets, effects);
        use rayon::prelude::*;
        sets.par_iter()
            .zip(models.par_iter())
            .map(|((_, d), m)| Ok(time_offset::scan(m, mat, &d.obs)?.0))
            .collect()
    }

    /// Each run's offset in words (ms), marked at the edge of the scan.
    pub(in crate::runs) fn describe_offsets(
        sets: &[(String, MotionDataset)],
        offsets: &[i64],
    ) -> String {
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

    /// Fits the material of `effects` to the fitted runs, run i's markers `offsets[i]` steps late.
    pub(in crate::runs) fn fit(
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
        let mut params: Vec<Param> = kinds.iter().map(|k| Param::global(*k)).collect();
        params.extend(region_params(start));
        let q0 = base.read(&params);
        let retimed = self.retimed(effects, offsets)?;
        let runs: Vec<Run> = retimed
            .iter()
            .map(|(model, obs)| Run { model, obs })
            .collect();
        let floors: Vec<(ParamKind, f64)> = self
            .creep_floor
            .filter(|_| kinds.contains(&ParamKind::CreepTime))
            .map(|f| (ParamKind::CreepTime, f))
            .into_iter()
            .collect();
        let mut q0 = q0;
        for &(kind, f) in &floors {
            // A start below the floor (a material fitted without it) begins above it.
            if let Some(i) = params.iter().position(|p| p.kind == kind) {
                if q0[i] < f {
                    q0[i] = 2.0 * f;
                }
            }
        }
        let nu = self.o.poisson;
        let (q, evaluations, capped, phi, gauss_newton, at_result) =
            if params == [Param::global(ParamKind::Mu)] {
                let (q, evaluations, capped, phi, at_result) =
                    self.search_modulus(&runs, &base, q0[0], max_iters)?;
                (q, evaluations, capped, phi, None, at_result)
            } else {
                let settings = FitSettings {
                    max_iters,
                    poisson: Some(nu),
                    floors,
                    ..Default::default()
                };
                let r = fit_runs(&runs, &base, &params, &q0, &settings, &[], &|_, _| {})?;
                self.count(r.evaluations * runs.len(), true);
                self.count(r.plain_evaluations * runs.len(), false);
                let all = r.evaluations + r.plain_evaluations;
                (
                    r.q,
                    all,
                    r.iterations >= max_iters,
                    r.eval.phi,
                    r.gauss_newton,
                    r.runs,
                )
            };
        let mut material = base.clone();
        material.set(&params, &q);
        material.set(
            &[Param::global(ParamKind::Lambda)],
            &[2.0 * nu / (1.0 - 2.0 * nu) * material.body_moduli().1],
        );
        // The fit simulated every run at its result: read them from those simulations.
        let simulated: Vec<Option<Simulated>> =
            at_result.into_iter().map(|e| e.simulated).collect();
        let fitted = self.readings(self.fit, effects, &material, offsets, simulated)?;
        Ok(RunsFit {
            effects: effects.to_vec(),
            material,
            kinds,
            offsets: offsets.to_vec(),
            fitted,
            phi,
            gauss_newton,
            evaluations,
            capped,
        })
    }

    /// The modulus alone (the simplest model: μ, λ following at the held Poisson's ratio) fitted
    /// to `runs` from `mu0` by a search on Φ of plain simulations in ln μ ([`line_minimum`]): in
    /// one coordinate the sensitivities buy only the slope, and on the beam's undamped runs a
    /// plain simulation takes about half the time of one with them. Steps of 10 % bracket the
    /// minimum; the search stops where a trusted parabola predicts less gain than the data's
    /// precision, the gradient fits' rule ([`precision`]); at most `max_iters` values. Returns μ,
    /// the values simulated, whether the cap stopped the search, Φ at μ and the runs' evaluations
    /// there.
    fn search_modulus(
        &self,
        runs: &[Run],
        base: &Material,
        mu0: f64,
        max_iters: u64,
    ) -> Result<(Vec<f64>, usize, bool, f64, Vec<Evaluation>), MotionError> {
        let ratio = 2.0 * self.o.poisson / (1.0 - 2.0 * self.o.poisson);
        let elastic = Param::globals(&[ParamKind::Mu, ParamKind::Lambda]);
        // Each value's runs, kept: the search ends on one of them.
        let values: std::cell::RefCell<Vec<(f64, Vec<Evaluation>)>> = Default::default();
        let at = |z: f64| -> Result<Evaluation, MotionError> {
            let mut m = base.clone();
            let mu = z.exp();
            m.set(&elastic, &[mu, ratio * mu]);
            let (ev, parts) = evaluate_runs(runs, &m, &[], None)?;
            log::debug!("modulus search: μ {mu:.6e} Pa, Φ {:.6e}", ev.phi);
            values.borrow_mut().push((z, parts));
            Ok(ev)
        };
        let z0 = mu0.ln();
        let first = at(z0)?;
        // Scalar residuals: three per observed marker position and clamp force.
        let residuals = 3 * (first.marker_count + first.force_count);
        // A modulus the runs do not simulate at (a static start that does not converge, an
        // inverted element) bounds the search there, as a failed step bounds a gradient fit's.
        let found = line_minimum(
            |z| -> Result<f64, MotionError> {
                if z == z0 {
                    return Ok(first.phi);
                }
                Ok(at(z).map_or_else(
                    |e| {
                        log::debug!(
                            "modulus search: μ {:.6e} Pa does not simulate: {e}",
                            z.exp()
                        );
                        f64::INFINITY
                    },
                    |ev| ev.phi,
                ))
            },
            z0,
            0.1,
            precision(residuals),
            max_iters as usize,
        )?;
        self.count(found.evaluations * runs.len(), false);
        let mut values = values.into_inner();
        let at_found = values
            .iter()
            .rposition(|(z, _)| *z == found.t)
            .map(|i| values.swap_remove(i).1)
            .unwrap_or_default();
        Ok((
            vec![found.t.exp()],
            found.evaluations,
            !found.converged,
            found.value,
            at_found,
        ))
    }

    /// A fit of `effects` with the runs offset in time ([`RunsEffect::retimes`](super::candidates::RunsEffect::retimes)), from `offsets`
    /// (scanned with the current material for the candidate itself, adopted for a later one):
    /// the material refitted with them held; scanned again with the refitted material, refitted
    /// once more if one moved (module note).
    pub(in crate::runs) fn fit_retimed(
        &self,
        round: usize,
        effects: &[Effect],
        start: &Material,
        mut offsets: Vec<i64>,
        max_iters: u64,
    ) -> Result<RunsFit, MotionError> {
        let mut f = self.fit(effects, start, &offsets, max_iters)?;
        let again = self.scan_offsets(self.fit, effects, &f.material)?;
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

    /// Fits the material of `effects` from `start`, run i's markers `offsets[i]` steps late: the
    /// offsets held, or scanned again after the fit when an effect offsets the runs in time.
    pub(in crate::runs) fn fit_effects(
        &self,
        round: usize,
        effects: &[Effect],
        start: &Material,
        offsets: &[i64],
        max_iters: u64,
    ) -> Result<RunsFit, MotionError> {
        if Effect::retimed(effects) {
            self.fit_retimed(round, effects, start, offsets.to_vec(), max_iters)
        } else {
            self.fit(effects, start, offsets, max_iters)
        }
    }

    /// The model of `e`, in words.
    pub(in crate::runs) fn name(e: &[Effect]) -> String {
        if e.is_empty() {
            "the simplest model".into()
        } else {
            e.iter().map(|e| e.name()).collect::<Vec<_>>().join(" + ")
        }
    }
}
/// The parameters of `material`'s regions: each scaled region's μ (a clamp layer's, whose λ
/// follows at the body's Poisson's ratio), fitted beside the global kinds.
pub(in crate::runs) fn region_params(material: &Material) -> Vec<Param> {
    material
        .scaled_regions
        .iter()
        .map(|&r| Param::in_region(ParamKind::Mu, r))
        .collect()
}

/// A fit's result as the selection takes it: a fit that fails is a candidate not fitted, and
/// the report says why.
pub(in crate::runs) fn fitted(f: Result<RunsFit, MotionError>) -> Outcome<RunsFit> {
    match f {
        Ok(f) => Outcome::Fitted(f),
        Err(e) => Outcome::NotFitted(e.to_string()),
    }
}

/// A run whose step error [`step_errors`] measures: its model with the effects' changes, its
/// observations, its offset (steps) and its residual's RMS (m).
pub(in crate::runs) struct StepErrorRun<'a> {
    model: palpate_motion::model::Model,
    obs: &'a Observations,
    offset: i64,
    rms_m: f64,
    /// The markers the residual was read from: the run at its own step, simulated already.
    simulated: std::sync::Arc<Vec<Vec<[f64; 3]>>>,
}

impl StepErrorRun<'_> {
    /// The run's markers at its own step, when its residual was read from a simulation of this
    /// model: an offset run's was read from the model run longer.
    fn known(&self) -> Option<&[Vec<[f64; 3]>]> {
        (self.offset == 0 && self.simulated.len() == self.model.steps)
            .then_some(self.simulated.as_slice())
    }

    /// Simulations its step error takes: the halved step, and the run's own unless known.
    pub(in crate::runs) fn simulations(&self) -> usize {
        if self.known().is_some() {
            1
        } else {
            2
        }
    }
}

/// Each run's step error at the fitted `mat` ([`palpate_motion::step_error::at_fitted`]), the
/// run at its offset, held to its residual, all the runs side by side: `Err` says why one was
/// not measured.
pub(in crate::runs) fn step_errors(
    runs: &[StepErrorRun<'_>],
    mat: &Material,
) -> Vec<Result<FittedStepError, String>> {
    use rayon::prelude::*;
    runs.par_iter()
        .map(|r| {
            let (m, obs) =
                time_offset::shifted(&r.model, r.obs, r.offset).map_err(|e| e.to_string())?;
            step_error::at_fitted_from(&m, &obs, mat, r.rms_m, r.known())
        })
        .collect()
}
