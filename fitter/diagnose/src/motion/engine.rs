//! The motion diagnosis as the selection engine sees it ([`MotionModel`]): the room's fitter —
//! a candidate's refit on top of the current model, at the current model's time offset and with
//! its marker offsets when those are adopted — and the engine's hooks, which reach each
//! candidate through its [`MotionEffect`](super::candidates::MotionEffect).

use palpate_motion::dataset::MotionDataset;
use palpate_motion::model::ParamKind;

use super::candidates::two_material::RegionSearch;
use super::candidates::{Candidate, REPORT_ORDER};
use super::fit::{self, fit_model, fit_with_offsets, with_offsets, FittedModel, Scores, Split};
use super::signature::{signature, Signature};
use super::{values_of, MotionDiagnoseError, MotionOptions, Round, Trial, Value};
use crate::select::{
    self, CandidateModel, Current, FitScreen, Gate, GateDetail, HeldoutGate, Outcome, PassWords,
    Prediction, Verdict,
};

/// The motion diagnosis as the selection engine sees it, and the fitter its candidates call.
pub struct MotionModel<'a> {
    /// The dataset.
    pub(in crate::motion) ds: &'a MotionDataset,
    /// Where its steps are cut into fitted and held out.
    pub(in crate::motion) split: Split,
    /// The options.
    pub(in crate::motion) o: &'a MotionOptions,
    /// Measured clamp forces: the density is identifiable only with them.
    pub(in crate::motion) has_forces: bool,
    /// One line per fit.
    pub(in crate::motion) log: &'a (dyn Fn(&str) + Sync),
    /// Simulations the fit screen ran.
    pub(in crate::motion) screen_simulations: usize,
    /// The round's candidates fitted ahead of their turn, side by side, each with its log lines.
    pub(in crate::motion) ahead: select::Ahead<Candidate, AheadFit>,
    /// The dataset's model on the mesh refined once, from the mesh's note
    /// ([`super::mesh::estimate`]), for the checks against the mesh's own null (`Err`: why there
    /// is none).
    pub(in crate::motion) fine: Result<super::mesh::Refined, String>,
    /// The null of a round ([`super::mesh_null`]), made once per round (`Err`: why there is
    /// none).
    pub(in crate::motion) null: Option<(usize, Result<super::mesh_null::NullRound, String>)>,
    /// The candidates the screen of a round predicted to pass the ΔBIC threshold.
    pub(in crate::motion) promising: (usize, Vec<Candidate>),
    /// Where the current round's screen stepped the candidates' new parameters: a start
    /// ([`super::candidates::MotionEffect::screened_start`]).
    pub(in crate::motion) stepped: Vec<(ParamKind, f64)>,
    /// The second material's region search the current round's screen ran at the current fit
    /// ([`super::candidates::two_material`]): its fit reads it instead of searching again.
    pub(in crate::motion) region_search: Option<std::sync::Arc<RegionSearch>>,
    /// Every check against the null: round, candidate, what it found.
    pub(in crate::motion) null_checks: Vec<(usize, Candidate, super::mesh_null::NullCheck)>,
    /// What the first null made says of the fitted parameters ([`super::mesh_null::MeshBias`]).
    pub(in crate::motion) mesh_bias: Option<super::mesh_null::MeshBias>,
    /// The rounds in which no candidate was tried, and why ([`forecast_at_floor`]).
    pub(in crate::motion) settled: Vec<(usize, String)>,
}

/// Why no candidate can pass the held-out gate on top of a model whose forecast has RMS
/// `held_rms` over `n_held` scalar residuals, when none can: passing needs the forecast's RMS
/// down by `gain` (the gate's share), and that would put it more than two standard errors below
/// the declared noise floor `floor` (σ√3) — a forecast below the noise itself, which no model of
/// data it was not fitted to makes but by the noise's own scatter (the RMS of n residuals at
/// the floor has a relative standard error of 1/√(2n)). `None`: a candidate may still pass, or
/// no noise is declared.
pub(in crate::motion) fn forecast_at_floor(
    held_rms: f64,
    n_held: usize,
    floor: f64,
    gain: f64,
) -> Option<String> {
    // A NaN floor (no declared noise) or gain is no reason to stop.
    if floor.is_nan() || floor <= 0.0 || n_held == 0 || gain.is_nan() || gain <= 0.0 {
        return None;
    }
    let needed = (1.0 - gain) * held_rms;
    let lowest = floor * (1.0 - 2.0 / (2.0 * n_held as f64).sqrt());
    (needed < lowest).then(|| {
        format!(
            "the forecast ({:.1} µm RMS held out) is {:.3}× the declared noise floor ({:.1} µm): \
             a candidate would pass the held-out gate only by forecasting {:.1} µm, more than two \
             standard errors below the noise itself, so none is fitted",
            1e6 * held_rms,
            held_rms / floor,
            1e6 * floor,
            1e6 * needed
        )
    })
}

/// Why a fitter has no refined model: only the diagnosis' own engine is handed one.
const NOT_MADE: &str = "the mesh refined once was not made for this fitter";

/// A candidate's fit done ahead of its turn, and its log lines in order.
type AheadFit = (
    Result<Outcome<FittedModel>, MotionDiagnoseError>,
    Vec<String>,
);

/// Starting values of a candidate's parameters, given the current fit: the global values, the
/// candidate's new ones ([`MotionEffect::new_starts`](super::candidates::MotionEffect::new_starts)),
/// then each region's μ ([`fit::params_for`]).
fn starts(
    c: Candidate,
    cur: &FittedModel,
    ds: &MotionDataset,
    stepped: &[(ParamKind, f64)],
) -> Vec<Vec<f64>> {
    let globals = cur.kinds.len();
    let (base, regions) = cur.values.split_at(globals);
    let at = |k: ParamKind| stepped.iter().find(|(j, _)| *j == k).map(|(_, v)| *v);
    c.effect()
        .screened_start(&at)
        .map_or_else(|| c.effect().new_starts(cur, ds.model.dt), |s| vec![s])
        .into_iter()
        .map(|new| [base, new.as_slice(), regions].concat())
        .collect()
}

/// `cur` with the parameters of `held` kinds no longer free: their values stay in its material,
/// out of its kinds, values and 1σ ([`MotionEffect::holds`](super::candidates::MotionEffect::holds)).
fn holding<'c>(cur: &'c FittedModel, held: &[ParamKind]) -> std::borrow::Cow<'c, FittedModel> {
    if !cur.kinds.iter().any(|k| held.contains(k)) {
        return std::borrow::Cow::Borrowed(cur);
    }
    let globals = cur.kinds.len();
    let keep = |i: usize| i >= globals || !held.contains(&cur.kinds[i]);
    let pick = |v: &[f64]| -> Vec<f64> {
        v.iter()
            .enumerate()
            .filter(|(i, _)| keep(*i))
            .map(|(_, x)| *x)
            .collect()
    };
    let mut out = cur.clone();
    out.kinds.retain(|k| !held.contains(k));
    out.values = pick(&cur.values);
    out.sigma = cur.sigma.as_deref().map(pick);
    std::borrow::Cow::Owned(out)
}

impl<'a> MotionModel<'a> {
    /// The engine of the diagnosis of `ds` split at `split`.
    pub(in crate::motion) fn new(
        ds: &'a MotionDataset,
        split: Split,
        o: &'a MotionOptions,
        log: &'a (dyn Fn(&str) + Sync),
    ) -> Self {
        Self {
            ds,
            split,
            o,
            has_forces: ds.obs.forces.iter().flatten().flatten().count() > 0,
            log,
            screen_simulations: 0,
            ahead: select::Ahead::default(),
            fine: Err(NOT_MADE.into()),
            null: None,
            mesh_bias: None,
            promising: (0, Vec::new()),
            stepped: Vec::new(),
            region_search: None,
            null_checks: Vec::new(),
            settled: Vec::new(),
        }
    }

    /// The same fitter with the options `o` (a screen's shorter fits).
    pub(in crate::motion) fn with_options<'b>(&self, o: &'b MotionOptions) -> MotionModel<'b>
    where
        'a: 'b,
    {
        MotionModel::new(self.ds, self.split, o, self.log)
    }

    /// The fit of `c` on top of `cur` on the data `ds` split at `split`: with the marker offsets
    /// free when `c` frees them or they are adopted (later candidates refit the material and
    /// the offsets together).
    fn fit_on(
        &self,
        ds: &MotionDataset,
        split: Split,
        cur: &FittedModel,
        c: Candidate,
        kinds: &[ParamKind],
    ) -> Result<FittedModel, MotionDiagnoseError> {
        let starts = starts(c, cur, ds, &self.stepped);
        if c.effect().frees_marker_offsets() || cur.offsets.is_some() {
            fit_with_offsets(
                ds,
                split,
                &cur.material,
                kinds,
                &starts[0],
                self.o.max_iters,
            )
        } else {
            fit_model(
                ds,
                split,
                &cur.material,
                kinds,
                &starts,
                self.o.max_iters,
                self.o.screen_iters,
            )
        }
    }

    /// One fit of `c` at the time offset `r`, its simulations added to `evaluations`: the fit
    /// on the re-timed data, its trajectory and scores read back on the data's rows.
    pub(in crate::motion) fn fit_at(
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

    /// The fit of `c` from `cur`, at `cur`'s time offset if it has one (no new scan).
    pub(in crate::motion) fn fit_from(
        &self,
        cur: &FittedModel,
        c: Candidate,
    ) -> Result<FittedModel, MotionDiagnoseError> {
        let held = holding(cur, c.effect().holds());
        let cur = held.as_ref();
        let mut kinds = cur.kinds.clone();
        kinds.extend_from_slice(c.kinds());
        match cur.time_offset {
            Some(r) => self.fit_at(cur, c, &kinds, r, &mut 0),
            None => self.fit_on(self.ds, self.split, cur, c, &kinds),
        }
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

    fn candidates(&mut self, current: &FittedModel, adopted: &[Candidate]) -> Vec<Candidate> {
        // Each round before the last adopts one effect: this is round `adopted.len() + 1`.
        let round = adopted.len() + 1;
        let floor = super::noise_floor(self.ds).unwrap_or(f64::NAN);
        let s = current.scores;
        if let Some(why) = forecast_at_floor(s.rms_held, s.n_held, floor, self.o.min_holdout_gain) {
            (self.log)(&format!("round {round}: {why}"));
            self.settled.push((round, why));
            return Vec::new();
        }
        let open = |c: &Candidate| !adopted.iter().any(|&a| a == *c || a.conflicts(*c));
        self.o.candidates.iter().copied().filter(open).collect()
    }

    fn fit_with(
        &mut self,
        round: usize,
        cur: &FittedModel,
        c: Candidate,
    ) -> Result<Outcome<FittedModel>, MotionDiagnoseError> {
        match self.ahead.take(round, c) {
            Some((outcome, lines)) => {
                for line in &lines {
                    (self.log)(line);
                }
                outcome
            }
            None => c.effect().fit(self, c, cur),
        }
    }

    fn prefit(&mut self, round: usize, cur: &FittedModel, batch: &[Candidate]) {
        (self.log)(&select::side_by_side_line(round, batch));
        // The round's null, should a passing candidate need it, is made beside the fits: it
        // reads only the current model, and the fits seldom keep both cores busy to the end.
        let null = self.wants_null(round, batch).then_some(&self.fine);
        let prior_scale = self.null_scale();
        let this = &*self;
        let fits = || {
            select::fit_ahead(
                batch,
                |_, _| false,
                |c, _| {
                    let lines = std::sync::Mutex::new(Vec::new());
                    let log = |line: &str| {
                        lines
                            .lock()
                            .expect("a fit's log lines")
                            .push(line.to_string())
                    };
                    let mut fitter = this.with_options(this.o);
                    fitter.log = &log;
                    fitter.stepped.clone_from(&this.stepped);
                    fitter.region_search.clone_from(&this.region_search);
                    let outcome = c.effect().fit(&fitter, c, cur);
                    (outcome, lines.into_inner().expect("a fit's log lines"))
                },
            )
        };
        let (results, made) = rayon::join(fits, || match null {
            Some(Ok(fine)) => Some(super::mesh_null::make_null(
                this.ds,
                this.split,
                this.o,
                fine,
                cur,
                prior_scale,
                None,
            )),
            _ => None,
        });
        self.ahead = select::Ahead::new(round, batch, results);
        if let Some(made) = made {
            self.keep_null(round, cur, made);
        }
    }

    fn score(&self, m: &FittedModel) -> select::Score {
        select::Score {
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
        for c in REPORT_ORDER {
            values.extend(c.effect().summary_values(m));
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
        _held: Scores,
    ) -> Result<(FittedModel, Scores, ()), MotionDiagnoseError> {
        // The held-out figures are the (possibly refined) fit's own.
        let m = c.effect().adopt(self, m);
        let held = m.scores;
        Ok((m, held, ()))
    }

    fn fit_screen(&self) -> FitScreen {
        // As the runs room's: the predictions are one Gauss–Newton step held at the parameters'
        // bounds (`screen.rs`), so a candidate predicted not to pay is not fitted only to make up
        // the `least`. On the 24 independent cylinders of the confusion table, seed 7's and the
        // committed ones, no candidate predicted ≥ −threshold that was fitted for the `least`
        // passed the gate (the third round's stiffening, +9.2 to +9.7, in five draws; −3.9 on
        // seed 7, where its fit at a shear-thinning index near its floor took 24–33 of the
        // diagnosis' ≈ 190 simulations).
        FitScreen::paying(
            self.o.screen,
            self.o.screen_least,
            self.o.screen_margin,
            self.o.bic_threshold,
        )
    }

    fn predict(
        &mut self,
        round: usize,
        cur: &FittedModel,
        open: &[Candidate],
    ) -> Result<Vec<Prediction>, MotionDiagnoseError> {
        // A linearisation that does not simulate (a current model on the edge of stability)
        // predicts nothing: every open candidate is fitted, as without the screen.
        let (p, simulations, found) = match super::screen::predict(self, round, cur, open) {
            Ok(r) => r,
            Err(e) => {
                (self.log)(&format!(
                    "round {round}: screen failed ({e}): every open candidate is fitted"
                ));
                let why = format!("the screen failed: {e}");
                (
                    open.iter().map(|_| Prediction::none(&why)).collect(),
                    0,
                    super::screen::Found::default(),
                )
            }
        };
        self.screen_simulations += simulations;
        self.stepped = found.stepped;
        self.region_search = found.region_search;
        let promising = open
            .iter()
            .zip(&p)
            .filter(|(_, p)| p.delta_bic.is_some_and(|d| d < -self.o.bic_threshold))
            .map(|(&c, _)| c)
            .collect();
        self.promising = (round, promising);
        Ok(p)
    }

    fn confirm(
        &mut self,
        cur: &Current<'_, Self>,
        cand: &select::Candidate<'_, Self>,
        gate: &mut Gate<GateDetail>,
    ) -> Result<(), MotionDiagnoseError> {
        let c = cand.candidate;
        let Some(check) = self.null_check(cur.round, cur.fitted, c, cand.fitted, cand.delta_bic)
        else {
            return Ok(());
        };
        let but = if check.refused {
            gate.passes = false;
            "but "
        } else {
            ""
        };
        gate.detail.reason = format!("{}; {but}{}", gate.detail.reason, check.statement);
        self.null_checks.push((cur.round, c, check));
        Ok(())
    }

    fn screened_out(&mut self, round: usize, c: Candidate, p: &Prediction) {
        (self.log)(&format!(
            "round {round}: {} screened out (predicted ΔBIC {:.1})",
            c.name(),
            p.delta_bic.unwrap_or(f64::NAN)
        ));
    }
}

/// The motion report's rounds from the engine's verdict (trials in the order tried).
pub(in crate::motion) fn motion_rounds(
    v: &Verdict<MotionModel<'_>>,
    markers: usize,
    checks: &[(usize, Candidate, super::mesh_null::NullCheck)],
    settled: &[(usize, String)],
) -> Vec<Round> {
    let predicted =
        |a: &select::Attempt<MotionModel<'_>>| a.prediction.as_ref().and_then(|p| p.delta_bic);
    v.rounds
        .iter()
        .map(|r| {
            // Round r starts from path[r − 1]; a candidate adds its kinds to that model's.
            let k0 = v.path[r.round - 1].0.parameter_count();
            let null = |c: Candidate| {
                checks
                    .iter()
                    .find(|(round, cand, _)| *round == r.round && *cand == c)
                    .map(|(_, _, check)| check.clone())
            };
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
                        predicted_delta_bic: predicted(a),
                        screened_out: false,
                        mesh_null: null(a.candidate),
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
                        predicted_delta_bic: predicted(a),
                        screened_out: a.screened_out,
                        mesh_null: None,
                    },
                })
                .collect();
            Round {
                round: r.round,
                model: r.model.iter().map(|c| c.name().to_string()).collect(),
                signature: r.observed.clone(),
                trials,
                adopted: r.adopted_attempt().map(|a| a.candidate.name().to_string()),
                settled: settled
                    .iter()
                    .find(|(round, _)| *round == r.round)
                    .map(|(_, why)| why.clone()),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_motion::model::Material;

    /// The seed-7 cylinder's third round (339.1 µm held out over 4,884 residuals, floor
    /// 337.0 µm, the gate's 5 %): passing would need 322.1 µm, 4.4 % below the floor where two
    /// standard errors are 2.0 %, so nothing is fitted. The viscous bar of the tests (205.2 µm,
    /// 1.18× its floor) and a forecast 3 % above the floor over so few residuals that 2σ is 5 %
    /// are searched; without a declared noise nothing is said.
    #[test]
    fn a_forecast_at_the_noise_floor_leaves_no_candidate_a_chance() {
        let why = forecast_at_floor(339.1e-6, 4884, 336.96e-6, 0.05).expect("settled");
        assert!(why.contains("1.006×") && why.contains("322.1 µm"), "{why}");
        assert!(forecast_at_floor(205.2e-6, 297, 174.0e-6, 0.05).is_none());
        assert!(forecast_at_floor(1.03e-3, 800, 1.0e-3, 0.05).is_none());
        assert!(forecast_at_floor(1.03e-3, 4884, 1.0e-3, 0.05).is_some());
        assert!(forecast_at_floor(339.1e-6, 4884, f64::NAN, 0.05).is_none());
        assert!(forecast_at_floor(339.1e-6, 4884, 336.96e-6, 0.0).is_none());
    }

    /// A Newtonian viscosity starts once, where the screen's step put ν, when that is positive;
    /// the power law, and a Newtonian viscosity the step put at ν ≤ 0 or did not place, start
    /// from the three viscous times.
    #[test]
    fn a_newtonian_viscosity_starts_where_the_screen_stepped_it() {
        let base =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/motion-example");
        let ds = palpate_motion::dataset::load(&base).unwrap();
        let ne = ds.model.tets.len();
        let material = Material::uniform(ne, 4.0e4, 2.0e4, 0.0, 1.0, 47.0);
        let cur = FittedModel::elastic(material, [4.0e4, 2.0e4]);
        let stepped = [(ParamKind::Nu, 12.5)];
        let one = starts(Candidate::ViscosityNewtonian, &cur, &ds, &stepped);
        assert_eq!(one, vec![vec![4.0e4, 2.0e4, 12.5]]);
        for stepped in [&[(ParamKind::Nu, -3.0)][..], &[]] {
            let three = starts(Candidate::ViscosityNewtonian, &cur, &ds, stepped);
            assert_eq!(three.len(), 3, "{stepped:?}: {three:?}");
        }
        let power_law = starts(Candidate::Viscosity, &cur, &ds, &stepped);
        assert_eq!(power_law.len(), 3);
        assert!(power_law.iter().all(|s| s.len() == 4 && s[3] == 1.0));
    }
}
