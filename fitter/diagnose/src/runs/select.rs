//! The runs room's side of the selection ([`crate::select`]): the candidates open on these runs,
//! each fitted on top of the current model through its
//! [`RunsEffect`](super::candidates::RunsEffect) hooks, predicted by the fit
//! screen, gated on the held-out runs, and the adopted one refitted in full when its screening
//! fit stopped at the cap.

use super::candidates::Effect;
use super::fit::RunsModel;
use super::screen::ScreenPoint;
use super::{GateDetail, Held, RunsError, RunsFit, Simulations, Trial};
use crate::select::{
    self, CandidateModel, Current, FitScreen, Gate, HeldoutGate, Outcome, PassWords, Progress,
    Score,
};

/// A candidate fitted ahead of its turn ([`CandidateModel::prefit`]), with what the room records
/// of its fit when the turn comes.
pub(in crate::runs) struct AheadFit {
    outcome: Result<Outcome<RunsFit>, RunsError>,
    /// Its log lines, in order.
    lines: Vec<String>,
    /// The trial it records when it is not fitted.
    trials: Vec<Trial>,
    /// The simulations it ran.
    simulations: Simulations,
    /// Whether it started from the fit screen's scan of the time offsets (which only one fit
    /// of a round may take).
    took_scan: bool,
}

impl RunsModel<'_> {
    /// Fits `c` on top of `cur`: from the fit of a candidate of this round nested in it, if
    /// there is one, else from the current material.
    fn fit_candidate(
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
        c.effect().start(self, round, cur, &mut start);
        let budget = self.o.screen_max_iters.min(self.o.max_iters);
        match c.effect().fit(self, round, cur, &effects, &start, budget)? {
            Outcome::NotFitted(why) => Ok(self.not_fitted(round, c, why)),
            other => Ok(other),
        }
    }

    /// Records a fit done ahead as if it were done now: its log lines, its simulations, its
    /// trial, the scan it took.
    fn record_ahead(&mut self, a: AheadFit) -> Result<Outcome<RunsFit>, RunsError> {
        for line in &a.lines {
            (self.log)(line);
        }
        self.count(a.simulations.with_sensitivities, true);
        self.count(a.simulations.plain, false);
        self.trials.extend(a.trials);
        if a.took_scan {
            self.scanned = None;
        }
        a.outcome
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
        self.o
            .candidates
            .iter()
            .copied()
            .filter(|c| !adopted.contains(c) && !adopted.iter().any(|a| a.conflicts(*c)))
            .filter(|c| c.effect().available(self))
            .collect()
    }

    fn fit_with(
        &mut self,
        round: usize,
        cur: &RunsFit,
        c: Effect,
    ) -> Result<Outcome<RunsFit>, RunsError> {
        let out = match self.ahead.take(round, c) {
            Some(fit) => self.record_ahead(fit),
            None => self.fit_candidate(round, cur, c),
        }?;
        if let Outcome::Fitted(f) = &out {
            self.fitted.push((round, c, f.material.clone()));
        }
        Ok(out)
    }

    fn prefit(&mut self, round: usize, cur: &RunsFit, batch: &[Effect]) {
        (self.log)(&select::side_by_side_line(round, batch));
        let (fit, held, o) = (self.fit, self.held, self.o);
        let (fitted, predicted, scanned) = (&self.fitted, &self.predicted, &self.scanned);
        let landed = &self.landed;
        let (lever, creep_floor) = (&self.lever, self.creep_floor);
        // A candidate that nests one of the batch starts from its fit (`fit_candidate`).
        let results = select::fit_ahead(
            batch,
            |c, earlier| earlier.nested_in(c),
            |c, earlier: &[(Effect, &AheadFit)]| {
                let lines = std::cell::RefCell::new(Vec::new());
                let log = |line: &str| lines.borrow_mut().push(line.to_string());
                let mut room = RunsModel {
                    fit,
                    held,
                    o,
                    log: &log,
                    trials: Vec::new(),
                    fitted: fitted.clone(),
                    predicted: predicted.clone(),
                    landed: landed.clone(),
                    scanned: scanned.clone(),
                    progress: &|_| {},
                    simulations: Default::default(),
                    ahead: Default::default(),
                    lever: lever.clone(),
                    creep_floor,
                };
                for (d, a) in earlier {
                    if let Ok(Outcome::Fitted(f)) = &a.outcome {
                        room.fitted.push((round, *d, f.material.clone()));
                    }
                }
                let outcome = room.fit_candidate(round, cur, c);
                AheadFit {
                    outcome,
                    lines: lines.take(),
                    trials: room.trials,
                    simulations: room.simulations.get(),
                    took_scan: scanned.is_some() && room.scanned.is_none(),
                }
            },
        );
        self.ahead = select::Ahead::new(round, batch, results);
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
        let offsets = if Effect::retimed(&f.effects) {
            let o = self.scan_offsets(self.held, &f.effects, &f.material)?;
            self.count(self.held.len(), false);
            (self.log)(&format!(
                "round {round}: held-out time offsets (each run its own): {}",
                Self::describe_offsets(self.held, &o)
            ));
            o
        } else {
            Vec::new()
        };
        Ok(Held {
            runs: self.residuals(self.held, &f.effects, &f.material, &offsets)?,
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
        // The room's predictions of its continuous candidates are one Gauss–Newton step held at
        // their parameters' bounds (`screen.rs`), the time offset's its scan: a candidate they
        // predict not to pay is not fitted only to make up the `least`.
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
        cur: &RunsFit,
        open: &[Effect],
    ) -> Result<Vec<select::Prediction>, RunsError> {
        let at = ScreenPoint::new(self, round, cur, open)?;
        let mut out = Vec::new();
        for &c in open {
            let p = c.effect().predict(self, &at)?;
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
