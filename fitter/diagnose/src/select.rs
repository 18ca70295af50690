//! The selection engine shared by the three diagnoses (static datasets, motion datasets, measured
//! curves): greedy forward selection of candidate effects, gated by the fitted BIC and by held-out
//! data.
//!
//! Each diagnosis knows how to fit its own model with one more effect, how to predict data it was
//! not fitted to and what its gate's numbers are ([`CandidateModel`]); the loop, the bookkeeping
//! of what was tried and the verdict ([`Verdict`]) are written once, here ([`select`]). The
//! diagnoses turn the verdict into their own report records, whose JSON field names predate the
//! engine and are kept so that downstream readers do not break.
//!
//! One round: every open candidate is fitted on top of the current model and scored by
//! ΔBIC = BIC(augmented) − BIC(current); the fitted ones are ranked ([`Rank`]); the held-out gate is
//! run on all of them or on a BIC shortlist ([`Screen`]); the first in rank order that passes is
//! adopted (unless the effect limit is reached), and the round repeats from the augmented model.
//! The loop stops when nothing passes, nothing is left to try, the limit is reached or the rounds
//! run out ([`Stop`]).
//!
//! **The fit screen** ([`FitScreen`]): a diagnosis that can predict every open candidate's gain
//! before fitting it ([`CandidateModel::predict`], e.g. by one linearisation at the current fit:
//! [`crate::screen`]) fits in full only those the prediction ranks first; the others are
//! reported as screened out with their predicted ΔBIC. If none of the fitted ones passes the
//! gate, or every one that passes is refused by the diagnosis' last check
//! ([`CandidateModel::confirm`]), the next predicted to pay for its parameters is fitted, one at
//! a time, so that a poor prediction costs fits, not the verdict.
//!
//! **Fits side by side** ([`CandidateModel::prefit`]): the fits of a round are independent given
//! the current model (but for a candidate that starts from another's fit, which waits for it:
//! [`fit_ahead`]), so a room whose fits only read it fits a round's batch in parallel before the
//! loop takes them one by one; what each fit records (log lines, counts, trials) is recorded when
//! the loop reaches it, so the records and the verdict are those of fits one after the other. On
//! one thread (`RAYON_NUM_THREADS=1`) nothing is fitted ahead.
//!
//! **Progress** ([`Progress`]): the loop tells the diagnosis what it is doing (the screen, the
//! i-th fit of n, the held-out predictions, the adoption), for a progress bar.

use serde::Serialize;

use crate::Error;

/// A fitted parameter with its 1σ uncertainty from the Gauss–Newton covariance, in physical units
/// (static and curve diagnoses; the motion diagnosis' `Value` has another JSON shape and stays).
#[derive(Debug, Clone, Serialize)]
pub struct ParamValue {
    /// Name.
    pub name: String,
    /// Value.
    pub value: f64,
    /// Standard deviation (`NaN` if the covariance is singular).
    pub sd: f64,
    /// Unit.
    pub unit: String,
}

/// BIC with unknown noise variance: n ln(χ²/n) + k ln n (n residual entries, k free parameters).
///
/// χ²/n is floored at the smallest positive `f64` (an exact fit must not give −∞, which would
/// make every ΔBIC against it NaN), and n at 1.
pub fn bic(chi2: f64, n: usize, k: usize) -> f64 {
    let n = n.max(1) as f64;
    n * (chi2 / n).max(f64::MIN_POSITIVE).ln() + k as f64 * n.ln()
}

/// What the BIC of a fit is computed from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Score {
    /// Sum of squared residuals on the fitted data (in whatever scaling the diagnosis uses; only
    /// ratios enter ΔBIC).
    pub chi2: f64,
    /// Scalar residual entries on the fitted data.
    pub n: usize,
    /// Free parameters.
    pub k: usize,
}

impl Score {
    /// [`bic`] of this score.
    pub fn bic(&self) -> f64 {
        bic(self.chi2, self.n, self.k)
    }
}

/// ΔBIC on held-out predictions: n ln(χ²_new/χ²_old) + k ln n over n held-out residual entries
/// (floored at 1) and k extra parameters — [`bic`]'s difference at equal n, so that the held-out
/// gain must pay for the extra parameters at the price BIC charges on the fitted data.
pub fn heldout_delta_bic(chi2_old: f64, chi2_new: f64, n: usize, extra: usize) -> f64 {
    let n = n.max(1) as f64;
    n * (chi2_new / chi2_old).ln() + extra as f64 * n.ln()
}

/// The held-out adoption gate of the runs and motion diagnoses (the curve diagnosis runs it
/// without the held-out ΔBIC): an effect is adopted only if it pays for its parameters on the
/// fitted data (ΔBIC < −`bic_threshold`), pays for them on the held-out data too (held-out
/// ΔBIC < 0), and lowers the held-out RMS by at least `min_holdout_gain` — a fit that improves
/// only where it was fitted has learned the noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeldoutGate {
    /// Fitted ΔBIC must be below −this.
    pub bic_threshold: f64,
    /// The held-out RMS must fall by at least this fraction.
    pub min_holdout_gain: f64,
}

/// The figures and words of a [`HeldoutGate`] verdict, as the runs and motion reports keep them.
#[derive(Debug, Clone, Serialize)]
pub struct GateDetail {
    /// Held-out ΔBIC.
    pub heldout_delta_bic: f64,
    /// Relative change of the held-out RMS.
    pub heldout_gain: f64,
    /// The verdict in words.
    pub reason: String,
}

/// How a pass is put into words: the runs report gives the figures, the motion report the
/// thresholds beside them (both wordings predate the shared gate, and committed results quote
/// them). A failure is worded the same in both.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PassWords {
    /// `passes: ΔBIC …, held-out ΔBIC …, held-out RMS … %`.
    Figures,
    /// `passes: ΔBIC … < −…, held-out ΔBIC … < 0, held-out RMS … % (≤ −… %)`.
    WithThresholds,
}

impl HeldoutGate {
    /// The tests that fail, in words (none: the candidate passes). `heldout_delta_bic` is not
    /// tested when `None`; `heldout_gain` is the relative change of the held-out RMS (negative
    /// is better).
    pub fn failures(
        &self,
        delta_bic: f64,
        heldout_delta_bic: Option<f64>,
        heldout_gain: f64,
    ) -> Vec<String> {
        let fitted = delta_bic < -self.bic_threshold;
        let gain = heldout_gain <= -self.min_holdout_gain;
        let mut why = Vec::new();
        if !fitted {
            why.push(format!("ΔBIC {delta_bic:.1} not < −{}", self.bic_threshold));
        }
        if let Some(d) = heldout_delta_bic {
            let held = d < 0.0;
            if !held {
                why.push(format!("held-out ΔBIC {d:.1} not < 0"));
            }
        }
        if !gain {
            why.push(format!(
                "held-out RMS {:+.1} % (needs ≤ −{:.0} %)",
                100.0 * heldout_gain,
                100.0 * self.min_holdout_gain
            ));
        }
        why
    }

    /// Whether the candidate passes every test.
    pub fn passes(
        &self,
        delta_bic: f64,
        heldout_delta_bic: Option<f64>,
        heldout_gain: f64,
    ) -> bool {
        self.failures(delta_bic, heldout_delta_bic, heldout_gain)
            .is_empty()
    }

    /// The full gate: whether the candidate passes, and the figures and reason to report.
    pub fn judge(
        &self,
        delta_bic: f64,
        heldout_delta_bic: f64,
        heldout_gain: f64,
        words: PassWords,
    ) -> (bool, GateDetail) {
        let why = self.failures(delta_bic, Some(heldout_delta_bic), heldout_gain);
        let passes = why.is_empty();
        let reason = match words {
            _ if !passes => format!("fails: {}", why.join("; ")),
            PassWords::Figures => format!(
                "passes: ΔBIC {delta_bic:.1}, held-out ΔBIC {heldout_delta_bic:.1}, held-out RMS \
                 {:+.1} %",
                100.0 * heldout_gain
            ),
            PassWords::WithThresholds => format!(
                "passes: ΔBIC {delta_bic:.1} < −{}, held-out ΔBIC {heldout_delta_bic:.1} < 0, \
                 held-out RMS {:+.1} % (≤ −{:.0} %)",
                self.bic_threshold,
                100.0 * heldout_gain,
                100.0 * self.min_holdout_gain
            ),
        };
        (
            passes,
            GateDetail {
                heldout_delta_bic,
                heldout_gain,
                reason,
            },
        )
    }
}

/// What became of fitting one candidate.
#[derive(Debug)]
pub enum Outcome<F> {
    /// Fitted: scored, possibly gated.
    Fitted(F),
    /// Not fitted, and the verdict says why (e.g. not identifiable from these data).
    NotFitted(String),
    /// Not fitted, and not worth a line in the verdict (e.g. the fit left the physical range).
    Dropped,
}

/// The gate's verdict on one candidate.
#[derive(Debug, Clone)]
pub struct Gate<D> {
    /// Passes every test of the diagnosis' gate.
    pub passes: bool,
    /// ΔBIC on held-out data: of two candidates that pass, the later one in rank order with the
    /// lower value is reported as an ambiguity ([`Judgement::Ambiguous`]). `NaN` when the
    /// diagnosis does not report ambiguities.
    pub heldout_delta_bic: f64,
    /// Key of [`Rank::Heldout`] (lower = better, e.g. the held-out RMS).
    pub heldout_rank: f64,
    /// The diagnosis' own figures and words.
    pub detail: D,
}

/// The order candidates are considered in for adoption.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Rank {
    /// By fitted ΔBIC, lowest first (static and runs diagnoses).
    FittedBic,
    /// By fitted ΔBIC, lowest first, but a candidate that passes too with fewer free parameters
    /// and predicts the held-out data better ([`Judgement::Ambiguous`]) by more than `margin`
    /// in held-out ΔBIC (which charges the parameters) is adopted instead of the best, the one
    /// among such with the lowest held-out ΔBIC (the motion diagnosis, with its gate's ΔBIC
    /// threshold as the margin: a forecast better by less is no evidence either way). Two criteria of the gate then
    /// agree against the fitted ΔBIC alone: a constant offset of each marker (three parameters
    /// a marker) fits the static part of a turned gravity or of a clamp that gives as well as
    /// the effect itself and fits the rest scan's own noise too, so it leads on the fitted steps
    /// while the effect forecasts better; adopted first, it leaves the effect only its dynamic
    /// part, too small to pass.
    FittedBicOrSimplerForecast {
        /// How much lower the simpler candidate's held-out ΔBIC must be.
        margin: f64,
    },
    /// By [`Gate::heldout_rank`], lowest first (curve diagnosis).
    Heldout,
}

/// Which fitted candidates the held-out gate is run on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Screen {
    /// Every fitted candidate, right after its fit (cheap held-out data: a forecast or a few
    /// small refits).
    All,
    /// Only the first `size` in rank order with ΔBIC < −`bic_threshold` (held-out data cost a
    /// refit per measurement, so only the likely winners pay for it).
    Shortlist {
        /// ΔBIC must be below −this to be shortlisted.
        bic_threshold: f64,
        /// Most candidates shortlisted per round.
        size: usize,
    },
}

/// The loop's limits and orders.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Policy {
    /// Most rounds (a round that adopts nothing ends the loop earlier).
    pub rounds: usize,
    /// Most effects adopted: a round after that only reports what would have passed.
    pub max_adopted: usize,
    /// Adoption order.
    pub rank: Rank,
    /// Which candidates are gated.
    pub screen: Screen,
}

/// Where a gated candidate stands, in rank order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Judgement {
    /// The first that passes: adopted, unless the effect limit is reached.
    Best,
    /// Passes too, and predicts the held-out data better than the best ([`Gate::heldout_delta_bic`]).
    Ambiguous,
    /// Passes too, second in order.
    AlsoPasses,
    /// Fails the gate.
    Rejected,
}

/// Why the loop ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Stop {
    /// No candidate was fitted in the last round.
    NothingToTry,
    /// Candidates were fitted, none passes the gate.
    NothingPasses,
    /// A candidate passes, but [`Policy::max_adopted`] effects are in the model.
    Limit,
    /// Every round of [`Policy::rounds`] adopted an effect.
    Rounds,
}

/// Why the loop ended, in the words a report prints.
impl std::fmt::Display for Stop {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Stop::NothingToTry => "no candidate left to try",
            Stop::NothingPasses => "no candidate passes the gate",
            Stop::Limit => "the most effects a model may adopt are adopted",
            Stop::Rounds => "every round adopted an effect",
        })
    }
}

/// A candidate's gain as predicted before its fit ([`CandidateModel::predict`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Prediction {
    /// Predicted ΔBIC against the current model; `None`: not predicted (no neutral value to
    /// linearise at), and then always fitted.
    pub delta_bic: Option<f64>,
    /// How it was predicted, in words.
    pub how: String,
}

impl Prediction {
    /// Not predicted: fitted whatever the screen says of the others.
    pub fn none(why: &str) -> Self {
        Self {
            delta_bic: None,
            how: why.to_string(),
        }
    }
}

/// Which open candidates a round fits in full ([`CandidateModel::fit_screen`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "kebab-case", tag = "kind")]
pub enum FitScreen {
    /// Every open candidate (the full search).
    Off,
    /// By [`CandidateModel::predict`]: the `least` best predicted, every one whose predicted
    /// ΔBIC is within `margin` × |best| of the best, and every one not predicted. If none of
    /// those passes the gate (or its last check, [`CandidateModel::confirm`]), the next in
    /// predicted order with a predicted ΔBIC below `fallback_below` is fitted, one at a time,
    /// until one passes or none is left.
    Predicted {
        /// Fewest fitted (when that many are open).
        least: usize,
        /// Relative margin to the best predicted ΔBIC.
        margin: f64,
        /// A screened-out candidate is fitted after all when nothing fitted passes and its
        /// predicted ΔBIC is below this (the gate's −threshold: it is predicted to pay).
        fallback_below: f64,
        /// The `least` best and those near the best are fitted only when their predicted ΔBIC
        /// is below this (∞: always; the gate's −threshold: only those predicted to pay).
        least_below: f64,
    },
}

impl FitScreen {
    /// The screen a room's options ask for: off, or the `least` best predicted and those within
    /// `margin`, with the gate's ΔBIC `threshold` as the fallback's bound.
    pub fn from_options(on: bool, least: usize, margin: f64, threshold: f64) -> Self {
        if !on {
            return Self::Off;
        }
        Self::Predicted {
            least,
            margin,
            fallback_below: -threshold,
            least_below: f64::INFINITY,
        }
    }

    /// [`Self::from_options`] with its `least` best fitted only when they are predicted to pay
    /// ([`Self::least_only_paying`]): the rooms' screen, whose predictions are good enough that a
    /// candidate predicted not to pay is not fitted only to make up the `least`.
    pub fn paying(on: bool, least: usize, margin: f64, threshold: f64) -> Self {
        Self::from_options(on, least, margin, threshold).least_only_paying()
    }

    /// This screen with its `least` best fitted only when they are predicted to pay (ΔBIC below
    /// the fallback's bound, the gate's −threshold).
    pub fn least_only_paying(self) -> Self {
        match self {
            Self::Predicted {
                least,
                margin,
                fallback_below,
                ..
            } => Self::Predicted {
                least,
                margin,
                fallback_below,
                least_below: fallback_below,
            },
            off => off,
        }
    }
}

/// What the loop is doing, for a progress display ([`CandidateModel::progress`]). Rounds and
/// fits count from 1; `rounds` is the most rounds the loop may take (it often stops earlier).
#[derive(Debug, Clone, PartialEq)]
pub enum Progress {
    /// A round starts from the current model.
    Round {
        /// Round.
        round: usize,
        /// Most rounds.
        rounds: usize,
        /// Candidates open in the round.
        open: usize,
    },
    /// The fit screen predicts every open candidate's gain.
    Screening {
        /// Round.
        round: usize,
        /// Candidates predicted.
        open: usize,
    },
    /// The `index`-th of the `of` fits planned this round (`of` grows when a fall-back fit is
    /// added).
    Fitting {
        /// Round.
        round: usize,
        /// This fit (1-based).
        index: usize,
        /// Fits planned this round.
        of: usize,
        /// The candidate's label.
        candidate: String,
    },
    /// The held-out evidence of a fitted candidate is computed.
    HeldOut {
        /// Round.
        round: usize,
        /// The candidate's label.
        candidate: String,
    },
    /// The round's best candidate is adopted (the diagnosis may refit it).
    Adopting {
        /// Round.
        round: usize,
        /// The candidate's label.
        candidate: String,
    },
    /// The loop ended.
    Done {
        /// Why.
        stop: Stop,
    },
}

/// The current model and its held-out evidence, as the gate sees them.
pub struct Current<'a, M: CandidateModel + ?Sized> {
    /// Round (1-based).
    pub round: usize,
    /// The current fit.
    pub fitted: &'a M::Fitted,
    /// Its held-out evidence.
    pub held: &'a M::Held,
    /// What the diagnosis read of it at the start of the round.
    pub observed: &'a M::Observed,
}

/// One fitted candidate, as the gate sees it.
pub struct Candidate<'a, M: CandidateModel + ?Sized> {
    /// The candidate.
    pub candidate: M::Candidate,
    /// The augmented fit.
    pub fitted: &'a M::Fitted,
    /// Its held-out evidence.
    pub held: &'a M::Held,
    /// Its fitted ΔBIC against the current model.
    pub delta_bic: f64,
}

/// A model with candidate effects that can be fitted and predicted on held-out data: what a
/// diagnosis supplies to [`select`].
pub trait CandidateModel {
    /// A candidate effect of the room's library.
    type Candidate: CandidateEffect;
    /// A fitted model.
    type Fitted: Clone;
    /// Held-out evidence of a fitted model (its predictions of data it was not fitted to).
    type Held: Clone;
    /// What the diagnosis reads of the current model at the start of a round (its residual
    /// signature, its error figures).
    type Observed;
    /// What the diagnosis records of a fitted candidate, whether adopted or not.
    type Summary;
    /// The diagnosis' figures and words of a gate verdict.
    type Detail;
    /// What the diagnosis records of an adoption.
    type Adoption;
    /// Errors that end the diagnosis.
    type Error;

    /// Reads the current model at the start of a round.
    fn observe(&mut self, round: usize, fitted: &Self::Fitted, held: &Self::Held)
        -> Self::Observed;
    /// The candidates open against the current model, in the order they are tried.
    fn candidates(
        &mut self,
        current: &Self::Fitted,
        adopted: &[Self::Candidate],
    ) -> Vec<Self::Candidate>;
    /// Fits the current model augmented by `candidate`.
    fn fit_with(
        &mut self,
        round: usize,
        current: &Self::Fitted,
        candidate: Self::Candidate,
    ) -> Result<Outcome<Self::Fitted>, Self::Error>;
    /// The fitted figures BIC is computed from.
    fn score(&self, fitted: &Self::Fitted) -> Score;
    /// What the verdict keeps of a fitted candidate (the fit itself is dropped unless adopted).
    fn summarise(&self, fitted: &Self::Fitted) -> Self::Summary;
    /// Held-out evidence of a fitted candidate.
    fn heldout(
        &mut self,
        round: usize,
        candidate: Self::Candidate,
        fitted: &Self::Fitted,
    ) -> Result<Self::Held, Self::Error>;
    /// The diagnosis' gate (its thresholds, its words).
    fn gate(
        &mut self,
        current: &Current<'_, Self>,
        candidate: &Candidate<'_, Self>,
    ) -> Gate<Self::Detail>;
    /// Adopts `candidate`: returns the model the next round starts from (the diagnosis may refit
    /// it, e.g. after refreshing a correction) and what the verdict records of the adoption.
    #[allow(clippy::type_complexity)]
    fn adopt(
        &mut self,
        current: &Current<'_, Self>,
        candidate: Self::Candidate,
        fitted: Self::Fitted,
        held: Self::Held,
    ) -> Result<(Self::Fitted, Self::Held, Self::Adoption), Self::Error>;

    /// Which open candidates a round fits ([`FitScreen`]); the default fits every one.
    fn fit_screen(&self) -> FitScreen {
        FitScreen::Off
    }
    /// The predicted gain of every candidate of `open` (one [`Prediction`] each, in order) on top
    /// of `current`, called once a round when [`Self::fit_screen`] is not [`FitScreen::Off`].
    /// The default predicts nothing (every candidate is fitted).
    fn predict(
        &mut self,
        _round: usize,
        _current: &Self::Fitted,
        open: &[Self::Candidate],
    ) -> Result<Vec<Prediction>, Self::Error> {
        Ok(open
            .iter()
            .map(|_| Prediction::none("no prediction"))
            .collect())
    }
    /// Fits the candidates of `batch` (two or more, in the order tried) ahead of their turn, on
    /// top of `current`; the engine then calls [`Self::fit_with`] for each in that order. A room
    /// whose fits only read it fits them here in parallel ([`fit_ahead`]) and keeps each outcome
    /// with what it would have recorded of the fit (log lines, counts) in an [`Ahead`], for
    /// `fit_with` to hand back and record when the candidate's turn comes: the records, the
    /// gates and the verdict are then those of fits one after the other. The default fits
    /// nothing ahead.
    fn prefit(&mut self, _round: usize, _current: &Self::Fitted, _batch: &[Self::Candidate]) {}
    /// A last check of the round's best passing candidate before it is adopted: the diagnosis
    /// may refuse it by setting `gate.passes` to false (and saying why in its detail); the next
    /// best that passes is then checked in turn, and when every one is refused the screen's
    /// reserve is fitted as when none passes the gate. The default confirms every candidate.
    fn confirm(
        &mut self,
        _current: &Current<'_, Self>,
        _candidate: &Candidate<'_, Self>,
        _gate: &mut Gate<Self::Detail>,
    ) -> Result<(), Self::Error> {
        Ok(())
    }
    /// Records a candidate the screen left unfitted, once the round's fits are done (the
    /// default records nothing).
    fn screened_out(&mut self, _round: usize, _candidate: Self::Candidate, _p: &Prediction) {}
    /// Receives what the loop is doing (the default ignores it).
    fn progress(&mut self, _event: &Progress) {}
}

/// One candidate tried in a round.
pub struct Attempt<M: CandidateModel + ?Sized> {
    /// The candidate.
    pub candidate: M::Candidate,
    /// Why it was not fitted (`None` when it was).
    pub not_fitted: Option<String>,
    /// Its gain as predicted before any fit (`None` when the screen is off).
    pub prediction: Option<Prediction>,
    /// Left unfitted by the fit screen ([`FitScreen`]).
    pub screened_out: bool,
    /// Its fitted figures (`None` when not fitted).
    pub score: Option<Score>,
    /// What the diagnosis keeps of its fit (`None` when not fitted).
    pub summary: Option<M::Summary>,
    /// Fitted ΔBIC against the current model (`NaN` when not fitted).
    pub delta_bic: f64,
    /// Held-out evidence (`None` when not gated).
    pub held: Option<M::Held>,
    /// The gate's verdict (`None` when not gated).
    pub gate: Option<Gate<M::Detail>>,
    /// Where it stands among the gated candidates (`None` when not gated).
    pub judgement: Option<Judgement>,
}

impl<M: CandidateModel + ?Sized> Attempt<M> {
    /// Candidate `c` with its prediction and nothing else yet: not fitted, scored or gated.
    fn untried(candidate: M::Candidate, prediction: Option<Prediction>) -> Self {
        Self {
            candidate,
            not_fitted: None,
            prediction,
            screened_out: false,
            score: None,
            summary: None,
            delta_bic: f64::NAN,
            held: None,
            gate: None,
            judgement: None,
        }
    }
}

/// One round of the loop.
pub struct Round<M: CandidateModel + ?Sized> {
    /// Round (1-based).
    pub round: usize,
    /// Effects in the model at the start of the round, in the order adopted.
    pub model: Vec<M::Candidate>,
    /// What the diagnosis read of that model.
    pub observed: M::Observed,
    /// Candidates, in the order tried.
    pub attempts: Vec<Attempt<M>>,
    /// Indices into `attempts` in rank order ([`Policy::rank`]).
    pub ranked: Vec<usize>,
    /// Index into `attempts` of the adopted candidate.
    pub adopted: Option<usize>,
    /// What the diagnosis recorded of the adoption.
    pub adoption: Option<M::Adoption>,
    /// Why the loop ended, on its last round.
    pub stop: Option<Stop>,
}

impl<M: CandidateModel + ?Sized> Round<M> {
    /// Attempts in rank order.
    pub fn ranked(&self) -> impl Iterator<Item = &Attempt<M>> {
        self.ranked.iter().map(|&i| &self.attempts[i])
    }
    /// The adopted attempt.
    pub fn adopted_attempt(&self) -> Option<&Attempt<M>> {
        self.adopted.map(|i| &self.attempts[i])
    }
}

/// The result of [`select`].
pub struct Verdict<M: CandidateModel + ?Sized> {
    /// The rounds.
    pub rounds: Vec<Round<M>>,
    /// The starting model, then the model after each adoption (as returned by
    /// [`CandidateModel::adopt`]), each with its held-out evidence. Round r starts from
    /// `path[r − 1]`.
    pub path: Vec<(M::Fitted, M::Held)>,
    /// Why the loop ended.
    pub stop: Stop,
}

impl<M: CandidateModel + ?Sized> Verdict<M> {
    /// Effects adopted, in order.
    pub fn adopted(&self) -> Vec<M::Candidate> {
        self.rounds
            .iter()
            .filter_map(|r| r.adopted_attempt().map(|a| a.candidate))
            .collect()
    }
}

/// Greedy forward selection from `start` (with its held-out evidence `held`): round after round,
/// try every open candidate, adopt the best one that passes the gate, stop when none passes, none
/// is left or the policy's limits are reached.
///
/// A round is three steps: the fit screen predicts the open candidates (`screen_round`); the
/// planned ones are fitted and gated, the gated ones ranked and judged and the best checked, the
/// screen's reserve fitted while none passes (`fit_round`); and the best is adopted
/// (`adopt_best`) or the loop stops.
pub fn select<M: CandidateModel>(
    model: &mut M,
    policy: &Policy,
    start: M::Fitted,
    held: M::Held,
) -> Result<Verdict<M>, M::Error> {
    let mut path = vec![(start, held)];
    let mut adopted: Vec<M::Candidate> = Vec::new();
    let mut rounds = Vec::new();
    let mut stop = Stop::Rounds;
    let fit_screen = model.fit_screen();
    for round in 1..=policy.rounds {
        let (cur, cur_held) = path.last().expect("the start is on the path");
        let observed = model.observe(round, cur, cur_held);
        let bic0 = model.score(cur).bic();
        let open = model.candidates(cur, &adopted);
        model.progress(&Progress::Round {
            round,
            rounds: policy.rounds,
            open: open.len(),
        });
        let predictions = screen_round(model, &fit_screen, round, cur, &open)?;
        let now = Current {
            round,
            fitted: cur,
            held: cur_held,
            observed: &observed,
        };
        let (attempts, mut fits, ranked, best) =
            fit_round(model, policy, &fit_screen, &now, bic0, &open, &predictions)?;
        // Told once the round's fits and checks are done: a reserve fitted then is not.
        for a in attempts.iter().filter(|a| a.screened_out) {
            if let Some(p) = &a.prediction {
                model.screened_out(round, a.candidate, p);
            }
        }
        let mut this = Round {
            round,
            model: adopted.clone(),
            observed,
            attempts,
            ranked,
            adopted: None,
            adoption: None,
            stop: None,
        };
        match best {
            Some(i) if round <= policy.max_adopted => {
                let next = adopt_best(model, &mut this, i, &mut fits, cur, cur_held)?;
                adopted.push(this.attempts[i].candidate);
                rounds.push(this);
                path.push(next);
            }
            other => {
                stop = if other.is_some() {
                    Stop::Limit
                } else if this.attempts.is_empty() {
                    Stop::NothingToTry
                } else {
                    Stop::NothingPasses
                };
                this.stop = Some(stop);
                rounds.push(this);
                break;
            }
        }
    }
    if stop == Stop::Rounds {
        if let Some(last) = rounds.last_mut() {
            last.stop = Some(Stop::Rounds);
        }
    }
    model.progress(&Progress::Done { stop });
    Ok(Verdict { rounds, path, stop })
}

/// A round's screen: every open candidate's predicted gain when the fit screen is on, else none.
fn screen_round<M: CandidateModel>(
    model: &mut M,
    fit_screen: &FitScreen,
    round: usize,
    cur: &M::Fitted,
    open: &[M::Candidate],
) -> Result<Vec<Option<Prediction>>, M::Error> {
    Ok(match fit_screen {
        FitScreen::Predicted { .. } if !open.is_empty() => {
            model.progress(&Progress::Screening {
                round,
                open: open.len(),
            });
            let p = model.predict(round, cur, open)?;
            assert_eq!(p.len(), open.len(), "one prediction per open candidate");
            p.into_iter().map(Some).collect()
        }
        _ => vec![None; open.len()],
    })
}

/// A fitted candidate's attempt and its fit (`None`: not fitted).
type Slot<M> = (Attempt<M>, Option<<M as CandidateModel>::Fitted>);

/// A round's attempts in the order tried (by index into the open candidates), each beside its fit
/// (`None`: not fitted).
struct RoundFits<M: CandidateModel> {
    open: Vec<usize>,
    attempts: Vec<Attempt<M>>,
    fits: Vec<Option<M::Fitted>>,
}

impl<M: CandidateModel> RoundFits<M> {
    /// Puts open candidate `i`'s attempt in its place: the report's order and the ranking's
    /// tie-break do not depend on which fits the screen chose, nor when.
    fn place(&mut self, i: usize, a: Attempt<M>, f: Option<M::Fitted>) {
        let p = self.open.partition_point(|&j| j < i);
        self.open.insert(p, i);
        self.attempts.insert(p, a);
        self.fits.insert(p, f);
    }
}

/// A round's fits and verdict: the planned fits ([`plan_fits`]), each gated as it is fitted or
/// the shortlist after them ([`Screen`]), the gated ones judged ([`judge_round`]) and the best
/// that passes checked ([`CandidateModel::confirm`]). When none passes the gate, or the check
/// refuses every one that does, the screen's reserve is fitted one at a time, each gated as the
/// full search would have gated it, until one passes both or the reserve is spent. Returns every
/// attempt in the order tried (the screened out among them) beside its fit, the rank order and
/// the best that passes (indices into the attempts).
#[allow(clippy::type_complexity)]
fn fit_round<M: CandidateModel>(
    model: &mut M,
    policy: &Policy,
    fit_screen: &FitScreen,
    now: &Current<'_, M>,
    bic0: f64,
    open: &[M::Candidate],
    predictions: &[Option<Prediction>],
) -> Result<
    (
        Vec<Attempt<M>>,
        Vec<Option<M::Fitted>>,
        Vec<usize>,
        Option<usize>,
    ),
    M::Error,
> {
    let (batch, mut reserve) = plan_fits(fit_screen, predictions);
    let mut round = RoundFits {
        open: Vec::new(),
        attempts: Vec::new(),
        fits: Vec::new(),
    };
    let mut tried = vec![false; open.len()];
    // On one thread, fits ahead would only delay their log lines.
    if batch.len() > 1 && rayon::current_num_threads() > 1 {
        let cands: Vec<M::Candidate> = batch.iter().map(|&i| open[i]).collect();
        model.prefit(now.round, now.fitted, &cands);
    }
    for (n, &i) in batch.iter().enumerate() {
        tried[i] = true;
        model.progress(&Progress::Fitting {
            round: now.round,
            index: n + 1,
            of: batch.len(),
            candidate: open[i].label(),
        });
        if let Some((a, f)) = fit_one(model, policy, now, bic0, open[i], &predictions[i])? {
            round.place(i, a, f);
        }
    }
    gate_shortlist(model, policy, now, &mut round)?;
    let mut fitted = batch.len();
    loop {
        let best = best_confirmed(model, policy.rank, now, &mut round)?;
        if best.is_some() || reserve.is_empty() {
            break;
        }
        // Nothing fitted passes both the gate and the last check: the screen may have ranked a
        // winner too low, below candidates the gate failed or the check refused. The next
        // predicted to pay for itself is fitted before the round gives up.
        let i = reserve.remove(0);
        tried[i] = true;
        fitted += 1;
        model.progress(&Progress::Fitting {
            round: now.round,
            index: fitted,
            of: fitted,
            candidate: open[i].label(),
        });
        if let Some((a, f)) = fit_one(model, policy, now, bic0, open[i], &predictions[i])? {
            round.place(i, a, f);
            gate_shortlist(model, policy, now, &mut round)?;
        }
    }
    for (i, p) in predictions.iter().enumerate() {
        // Left out by the screen (a candidate the diagnosis dropped has no record).
        let (false, Some(p)) = (tried[i], p) else {
            continue;
        };
        let mut a = Attempt::untried(open[i], Some(p.clone()));
        a.not_fitted = Some(format!(
            "screened out: predicted ΔBIC {:.1} ({})",
            p.delta_bic.unwrap_or(f64::NAN),
            p.how
        ));
        a.screened_out = true;
        round.place(i, a, None);
    }
    let (ranked, best) = judge_round(policy.rank, &mut round.attempts);
    Ok((round.attempts, round.fits, ranked, best))
}

/// The best gated attempt that passes and that the diagnosis' last check does not refuse: the
/// gated attempts judged in rank order, the best checked, and when refused the next best judged
/// and checked in its turn.
fn best_confirmed<M: CandidateModel>(
    model: &mut M,
    rank: Rank,
    now: &Current<'_, M>,
    round: &mut RoundFits<M>,
) -> Result<Option<usize>, M::Error> {
    let (_, mut best) = judge_round(rank, &mut round.attempts);
    while let Some(i) = best {
        if !confirm_one(model, now, &mut round.attempts[i], round.fits[i].as_ref())? {
            break;
        }
        (_, best) = judge_round(rank, &mut round.attempts);
    }
    Ok(best)
}

/// Fits candidate `c` on top of the current model and scores it (gated at once when every
/// fitted candidate is: [`Screen::All`]); `None` when the diagnosis dropped it.
fn fit_one<M: CandidateModel>(
    model: &mut M,
    policy: &Policy,
    now: &Current<'_, M>,
    bic0: f64,
    c: M::Candidate,
    prediction: &Option<Prediction>,
) -> Result<Option<Slot<M>>, M::Error> {
    let mut a = Attempt::untried(c, prediction.clone());
    let f = match model.fit_with(now.round, now.fitted, c)? {
        Outcome::Dropped => return Ok(None),
        Outcome::NotFitted(why) => {
            a.not_fitted = Some(why);
            return Ok(Some((a, None)));
        }
        Outcome::Fitted(f) => f,
    };
    let score = model.score(&f);
    a.score = Some(score);
    a.summary = Some(model.summarise(&f));
    a.delta_bic = score.bic() - bic0;
    if policy.screen == Screen::All {
        gate_one(model, now, &mut a, &f)?;
    }
    Ok(Some((a, Some(f))))
}

/// Under [`Screen::Shortlist`], gates the first `size` fitted candidates in ΔBIC order with
/// ΔBIC < −`bic_threshold` that are not gated yet: the round's shortlist, whichever fits the
/// screen chose, as the full search would gate them (under [`Screen::All`] each fit was gated as
/// it was made).
fn gate_shortlist<M: CandidateModel>(
    model: &mut M,
    policy: &Policy,
    now: &Current<'_, M>,
    round: &mut RoundFits<M>,
) -> Result<(), M::Error> {
    let Screen::Shortlist {
        bic_threshold,
        size,
    } = policy.screen
    else {
        return Ok(());
    };
    let d = |i: usize| round.attempts[i].delta_bic;
    let mut fitted: Vec<usize> = (0..round.attempts.len())
        .filter(|&i| round.fits[i].is_some())
        .collect();
    fitted.sort_by(|&a, &b| d(a).total_cmp(&d(b)));
    fitted.retain(|&i| d(i) < -bic_threshold);
    fitted.truncate(size);
    for i in fitted {
        let (Some(f), None) = (&round.fits[i], &round.attempts[i].gate) else {
            continue;
        };
        gate_one(model, now, &mut round.attempts[i], f)?;
    }
    Ok(())
}

/// The held-out gate of one fitted candidate: its held-out evidence, then the diagnosis' verdict
/// on it against the current model.
fn gate_one<M: CandidateModel>(
    model: &mut M,
    now: &Current<'_, M>,
    a: &mut Attempt<M>,
    f: &M::Fitted,
) -> Result<(), M::Error> {
    let c = a.candidate;
    model.progress(&Progress::HeldOut {
        round: now.round,
        candidate: c.label(),
    });
    let h = model.heldout(now.round, c, f)?;
    a.gate = Some(model.gate(
        now,
        &Candidate {
            candidate: c,
            fitted: f,
            held: &h,
            delta_bic: a.delta_bic,
        },
    ));
    a.held = Some(h);
    Ok(())
}

/// The diagnosis' last check of a passing attempt ([`CandidateModel::confirm`]); `true` when it
/// refused the attempt.
fn confirm_one<M: CandidateModel>(
    model: &mut M,
    now: &Current<'_, M>,
    a: &mut Attempt<M>,
    f: Option<&M::Fitted>,
) -> Result<bool, M::Error> {
    let (Some(f), Some(h), Some(mut g)) = (f, a.held.as_ref(), a.gate.take()) else {
        return Ok(false);
    };
    model.confirm(
        now,
        &Candidate {
            candidate: a.candidate,
            fitted: f,
            held: h,
            delta_bic: a.delta_bic,
        },
        &mut g,
    )?;
    let refused = !g.passes;
    a.gate = Some(g);
    Ok(refused)
}

/// Ranks a round's attempts ([`Rank`]) and judges the gated ones in that order ([`Judgement`]):
/// the rank order (indices into `attempts`) and the best that passes.
fn judge_round<M: CandidateModel>(
    rank: Rank,
    attempts: &mut [Attempt<M>],
) -> (Vec<usize>, Option<usize>) {
    // Stable sorts: ties keep the order tried, as every diagnosis did before the engine.
    let mut ranked: Vec<usize> = (0..attempts.len()).collect();
    match rank {
        Rank::FittedBic | Rank::FittedBicOrSimplerForecast { .. } => {
            ranked.sort_by(|&a, &b| attempts[a].delta_bic.total_cmp(&attempts[b].delta_bic))
        }
        Rank::Heldout => {
            let key = |a: &Attempt<M>| a.gate.as_ref().map_or(f64::INFINITY, |g| g.heldout_rank);
            ranked.sort_by(|&a, &b| key(&attempts[a]).total_cmp(&key(&attempts[b])))
        }
    }
    let mut best: Option<usize> = None;
    for &i in &ranked {
        let Some(g) = &attempts[i].gate else { continue };
        let j = match best {
            None if g.passes => {
                best = Some(i);
                Judgement::Best
            }
            Some(b) if g.passes => {
                let lead = attempts[b]
                    .gate
                    .as_ref()
                    .map_or(f64::NAN, |g| g.heldout_delta_bic);
                if g.heldout_delta_bic < lead {
                    Judgement::Ambiguous
                } else {
                    Judgement::AlsoPasses
                }
            }
            _ => Judgement::Rejected,
        };
        attempts[i].judgement = Some(j);
    }
    if let (Rank::FittedBicOrSimplerForecast { margin }, Some(b)) = (rank, best) {
        let k = |i: usize| attempts[i].score.map_or(usize::MAX, |s| s.k);
        let held = |i: usize| {
            attempts[i]
                .gate
                .as_ref()
                .map_or(f64::NAN, |g| g.heldout_delta_bic)
        };
        let simpler = ranked
            .iter()
            .copied()
            .filter(|&i| {
                attempts[i].judgement == Some(Judgement::Ambiguous)
                    && k(i) < k(b)
                    && held(i) < held(b) - margin
            })
            .min_by(|&x, &y| held(x).total_cmp(&held(y)));
        if let Some(s) = simpler {
            attempts[s].judgement = Some(Judgement::Best);
            attempts[b].judgement = Some(Judgement::AlsoPasses);
            best = Some(s);
        }
    }
    (ranked, best)
}

/// Adopts attempt `i` of round `this` (its fit taken from `fits`): the diagnosis' adoption on
/// top of the current model, recorded in the round; returns the model the next round starts from.
fn adopt_best<M: CandidateModel>(
    model: &mut M,
    this: &mut Round<M>,
    i: usize,
    fits: &mut [Option<M::Fitted>],
    cur: &M::Fitted,
    cur_held: &M::Held,
) -> Result<(M::Fitted, M::Held), M::Error> {
    let f = fits[i].take().expect("a gated candidate was fitted");
    let h = this.attempts[i]
        .held
        .clone()
        .expect("a gated candidate has held-out evidence");
    let c = this.attempts[i].candidate;
    model.progress(&Progress::Adopting {
        round: this.round,
        candidate: c.label(),
    });
    let now = Current {
        round: this.round,
        fitted: cur,
        held: cur_held,
        observed: &this.observed,
    };
    let (f, h, adoption) = model.adopt(&now, c, f, h)?;
    this.adopted = Some(i);
    this.adoption = Some(adoption);
    Ok((f, h))
}

/// The fits of a round: the first batch (indices into the open candidates, in the order tried)
/// and the fall-back reserve (in predicted order). See [`FitScreen::Predicted`].
fn plan_fits(screen: &FitScreen, predictions: &[Option<Prediction>]) -> (Vec<usize>, Vec<usize>) {
    let all: Vec<usize> = (0..predictions.len()).collect();
    let FitScreen::Predicted {
        least,
        margin,
        fallback_below,
        least_below,
    } = *screen
    else {
        return (all, Vec::new());
    };
    let predicted = |i: usize| predictions[i].as_ref().and_then(|p| p.delta_bic);
    // Stable: equal predictions keep the order tried.
    let mut order: Vec<usize> = all
        .iter()
        .copied()
        .filter(|&i| predicted(i).is_some())
        .collect();
    order.sort_by(|&a, &b| {
        predicted(a)
            .unwrap_or(f64::NAN)
            .total_cmp(&predicted(b).unwrap_or(f64::NAN))
    });
    let best = order.first().and_then(|&i| predicted(i));
    let mut batch: Vec<usize> = all
        .iter()
        .copied()
        .filter(|&i| predicted(i).is_none())
        .collect();
    let mut reserve = Vec::new();
    // The prediction cannot rank two candidates it predicts within the gate's threshold of
    // each other (a nested pair above all: the power-law index adds nothing to one Gauss–Newton
    // step from zero viscosity, so the power law is predicted at the plain damping's gain less
    // one parameter's penalty): one next to a fitted one is fitted too.
    let tie = -fallback_below;
    let mut last_fitted: Option<f64> = None;
    for (rank, &i) in order.iter().enumerate() {
        let d = predicted(i).unwrap_or(f64::NAN);
        let near = best.is_some_and(|b| d <= b + margin * b.abs());
        let tied = last_fitted.is_some_and(|l| d - l <= tie);
        if ((rank < least || near || tied) && d < least_below) || !d.is_finite() {
            batch.push(i);
            last_fitted = Some(d);
        } else if d < fallback_below {
            reserve.push(i);
        }
    }
    batch.sort_unstable();
    (batch, reserve)
}

/// Candidates fitted ahead of their turn ([`CandidateModel::prefit`]), each with what its room
/// records of it; each is taken once, when the engine reaches it ([`CandidateModel::fit_with`]).
pub struct Ahead<C, T> {
    round: usize,
    fits: Vec<(C, T)>,
}

impl<C, T> Default for Ahead<C, T> {
    fn default() -> Self {
        Self {
            round: 0,
            fits: Vec::new(),
        }
    }
}

impl<C: Copy + PartialEq, T> Ahead<C, T> {
    /// The results of `batch`'s fits in `round`, one per candidate in order.
    pub fn new(round: usize, batch: &[C], results: Vec<T>) -> Self {
        assert_eq!(batch.len(), results.len(), "one result per candidate");
        Self {
            round,
            fits: batch.iter().copied().zip(results).collect(),
        }
    }

    /// The result of `candidate`'s fit in `round`, if it was fitted ahead and not taken yet.
    pub fn take(&mut self, round: usize, candidate: C) -> Option<T> {
        if round != self.round {
            return None;
        }
        let i = self.fits.iter().position(|(c, _)| *c == candidate)?;
        Some(self.fits.remove(i).1)
    }
}

/// Fits every candidate of `batch` with `fit`, in parallel on rayon's pool, and returns the
/// results in `batch`'s order. A candidate waits for every one before it in `batch` it depends
/// on (`waits_for(c, earlier)`: its fit starts from theirs), and `fit` is handed those results;
/// it starts as soon as the last of them is done, beside whatever else is still fitting, not at
/// the end of a wave of the others: in waves the measured beam's power law, nested in the
/// Newtonian damping, would wait 12 s for the creep branch's longer fit while a core idles at
/// the runs' unequal lengths. A fit's own parallel loops share the pool: rayon's joins steal
/// work rather than block a thread, so nesting neither deadlocks nor starts more threads than
/// the pool has.
/// Each fit depends only on its own dependencies' results, so the results do not depend on the
/// order the pool runs them in.
pub fn fit_ahead<C, T>(
    batch: &[C],
    waits_for: impl Fn(C, C) -> bool + Sync,
    fit: impl Fn(C, &[(C, &T)]) -> T + Sync,
) -> Vec<T>
where
    C: Copy + Send + Sync,
    T: Send + Sync,
{
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::OnceLock;

    /// What every launched fit reads: the batch, its dependencies, the results so far and which
    /// fits have been claimed by a launch.
    struct Flow<'a, C, T, W, F> {
        batch: &'a [C],
        waits_for: &'a W,
        fit: &'a F,
        done: Vec<OnceLock<T>>,
        claimed: Vec<AtomicBool>,
    }

    impl<'a, C, T, W, F> Flow<'a, C, T, W, F>
    where
        C: Copy + Send + Sync,
        T: Send + Sync,
        W: Fn(C, C) -> bool + Sync,
        F: Fn(C, &[(C, &T)]) -> T + Sync,
    {
        fn deps(&self, i: usize) -> impl Iterator<Item = usize> + '_ {
            (0..i).filter(move |&j| (self.waits_for)(self.batch[i], self.batch[j]))
        }

        /// Spawns every fit not yet claimed whose dependencies are all done; the claim makes
        /// each fit start once, whichever finishing dependency sees it ready first.
        fn launch_ready<'s>(&'s self, scope: &rayon::Scope<'s>) {
            for i in 0..self.batch.len() {
                if self.claimed[i].load(Ordering::Acquire)
                    || !self.deps(i).all(|j| self.done[j].get().is_some())
                {
                    continue;
                }
                if !self.claimed[i].swap(true, Ordering::AcqRel) {
                    scope.spawn(move |scope| self.run(i, scope));
                }
            }
        }

        fn run<'s>(&'s self, i: usize, scope: &rayon::Scope<'s>) {
            let earlier: Vec<(C, &T)> = self
                .deps(i)
                .map(|j| {
                    (
                        self.batch[j],
                        self.done[j].get().expect("a dependency is done"),
                    )
                })
                .collect();
            let result = (self.fit)(self.batch[i], &earlier);
            if self.done[i].set(result).is_err() {
                unreachable!("each fit is claimed once");
            }
            self.launch_ready(scope);
        }
    }

    let flow = Flow {
        batch,
        waits_for: &waits_for,
        fit: &fit,
        done: batch.iter().map(|_| OnceLock::new()).collect(),
        claimed: batch.iter().map(|_| AtomicBool::new(false)).collect(),
    };
    // Dependencies point only to earlier candidates, so the first one is always ready and every
    // fit is launched once all before it that it waits for are done.
    rayon::scope(|scope| flow.launch_ready(scope));
    flow.done
        .into_iter()
        .map(|slot| slot.into_inner().expect("every fit ran"))
        .collect()
}

/// The line a room logs before [`fit_ahead`] fits `batch` in `round`: what is fitted side by
/// side, and that each fit's own lines are replayed after it, in the batch's order.
pub fn side_by_side_line<C: CandidateEffect>(round: usize, batch: &[C]) -> String {
    format!(
        "round {round}: fitting {} side by side (the lines of each follow in turn)",
        batch
            .iter()
            .map(|&c| c.label())
            .collect::<Vec<_>>()
            .join(", ")
    )
}

/// A candidate effect of a room's library, as the shared layer sees it: the selection engine
/// ([`CandidateModel::Candidate`]) and the request ([`pick_candidates`]) need nothing else of it.
/// Each room's candidate type implements it where it is defined, so a room's library is stated
/// once (`statics::model`, `motion`, `runs`, `curve::model`).
pub trait CandidateEffect: Copy + PartialEq {
    /// What the library is called in messages ("candidate", "motion candidate").
    const LIBRARY: &'static str;
    /// Every candidate of the library, in the order tried.
    fn library() -> Vec<Self>;
    /// The name on the command line and in reports.
    fn label(self) -> String;
}

/// The candidates named in `--candidates`, each looked up by name in `C`'s library (the error
/// names the library and lists what it knows).
pub fn pick_candidates<C: CandidateEffect>(names: &[String]) -> Result<Vec<C>, Error> {
    let all = C::library();
    names
        .iter()
        .map(|n| {
            all.iter()
                .copied()
                .find(|&c| c.label() == n.trim())
                .ok_or_else(|| Error::UnknownCandidate {
                    what: C::LIBRARY.to_string(),
                    name: n.clone(),
                    input: None,
                    known: all.iter().map(|&c| c.label()).collect(),
                })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The gate's words are those the reports printed before it was shared (committed results
    /// quote them), and the curve diagnosis' form without the held-out ΔBIC tests the rest.
    #[test]
    fn heldout_gate_words_and_tests() {
        let gate = HeldoutGate {
            bic_threshold: 10.0,
            min_holdout_gain: 0.05,
        };
        let (passes, d) = gate.judge(-4128.2, -2929.7, -0.588, PassWords::WithThresholds);
        assert!(passes);
        assert_eq!(
            d.reason,
            "passes: ΔBIC -4128.2 < −10, held-out ΔBIC -2929.7 < 0, held-out RMS -58.8 % (≤ −5 %)"
        );
        let (passes, d) = gate.judge(-44534.8, -42199.5, -0.7, PassWords::Figures);
        assert!(passes);
        assert_eq!(
            d.reason,
            "passes: ΔBIC -44534.8, held-out ΔBIC -42199.5, held-out RMS -70.0 %"
        );
        for words in [PassWords::Figures, PassWords::WithThresholds] {
            let (passes, d) = gate.judge(8583.7, 8421.2, 0.271, words);
            assert!(!passes);
            assert_eq!(
                d.reason,
                "fails: ΔBIC 8583.7 not < −10; held-out ΔBIC 8421.2 not < 0; held-out RMS +27.1 % \
                 (needs ≤ −5 %)"
            );
        }
        assert!(gate.passes(-10.5, None, -0.05));
        assert!(!gate.passes(-10.0, None, -0.5));
        assert!(!gate.passes(-20.0, None, -0.04));
        assert!(!gate.passes(-20.0, None, f64::NAN));
    }
    /// A toy diagnosis: candidate c lowers BIC by `gain[c]` whenever fitted (n = 1, so BIC is
    /// ln χ²), the screen predicts `predicted[c]`, and the gate passes a ΔBIC below −10 unless
    /// c is in `fails`. It counts its fits.
    struct Toy {
        gain: Vec<f64>,
        predicted: Vec<f64>,
        fails: Vec<usize>,
        screen: FitScreen,
        fits: usize,
        screened: Vec<(usize, usize)>,
        /// Candidates whose fit does not converge ([`Outcome::NotFitted`]).
        diverges: Vec<usize>,
        /// Fits done ahead ([`CandidateModel::prefit`]); `None`: the toy fits nothing ahead.
        ahead: Option<Ahead<C, Outcome<f64>>>,
        /// What the toy records, in order: "fit c1 = …", "gate c1".
        events: Vec<String>,
        /// c1 starts from c0's fit of the same round (as the power law from the Newtonian
        /// damping it nests): each fit recorded, by round.
        fitted: Vec<(usize, C, f64)>,
        /// Candidates that pass the gate but are refused by the last check
        /// ([`CandidateModel::confirm`]).
        refused: Vec<usize>,
    }

    impl Toy {
        fn new(fails: &[usize], screen: FitScreen, diverges: &[usize]) -> Self {
            Toy {
                gain: vec![-50.0, -5.0, -200.0, -30.0],
                predicted: vec![-40.0, -1.0, -150.0, -60.0],
                fails: fails.to_vec(),
                screen,
                fits: 0,
                screened: Vec::new(),
                diverges: diverges.to_vec(),
                ahead: None,
                events: Vec::new(),
                fitted: Vec::new(),
                refused: Vec::new(),
            }
        }
        /// The fit proper: read-only, as a fit done ahead must be; `nested` is c0's fit this
        /// round when `c` is c1.
        fn fit_alone(&self, cur: f64, c: C, nested: Option<f64>) -> Outcome<f64> {
            if self.diverges.contains(&c.0) {
                return Outcome::NotFitted(format!("c{} diverged", c.0));
            }
            let start = nested.map_or(cur, |f| 0.5 * (f + cur));
            Outcome::Fitted(start + self.gain[c.0])
        }
        fn nests(c: C, earlier: C) -> bool {
            (c.0, earlier.0) == (1, 0)
        }
    }

    #[derive(Debug, Clone, Copy, PartialEq)]
    struct C(usize);

    impl CandidateEffect for C {
        const LIBRARY: &'static str = "toy candidate";
        fn library() -> Vec<Self> {
            (0..4).map(C).collect()
        }
        fn label(self) -> String {
            format!("c{}", self.0)
        }
    }

    impl CandidateModel for Toy {
        type Candidate = C;
        type Fitted = f64;
        type Held = ();
        type Observed = ();
        type Summary = ();
        type Detail = ();
        type Adoption = ();
        type Error = ();

        fn observe(&mut self, _: usize, _: &f64, _: &()) {}
        fn candidates(&mut self, _: &f64, adopted: &[C]) -> Vec<C> {
            (0..self.gain.len())
                .map(C)
                .filter(|c| !adopted.contains(c))
                .collect()
        }
        fn fit_with(&mut self, round: usize, cur: &f64, c: C) -> Result<Outcome<f64>, ()> {
            self.fits += 1;
            let out = match self.ahead.as_mut().and_then(|a| a.take(round, c)) {
                Some(out) => out,
                None => {
                    let nested = self
                        .fitted
                        .iter()
                        .rev()
                        .find(|(r, e, _)| *r == round && Self::nests(c, *e));
                    self.fit_alone(*cur, c, nested.map(|n| n.2))
                }
            };
            let f = match &out {
                Outcome::Fitted(f) => {
                    self.fitted.push((round, c, *f));
                    format!("{f}")
                }
                _ => "-".into(),
            };
            self.events.push(format!("fit c{} = {f}", c.0));
            Ok(out)
        }
        fn prefit(&mut self, round: usize, cur: &f64, batch: &[C]) {
            if self.ahead.is_none() {
                return;
            }
            let this = &*self;
            let results = fit_ahead(batch, Self::nests, |c, earlier: &[(C, &Outcome<f64>)]| {
                let nested = earlier.iter().find_map(|(_, o)| match o {
                    Outcome::Fitted(f) => Some(*f),
                    _ => None,
                });
                this.fit_alone(*cur, c, nested)
            });
            self.ahead = Some(Ahead::new(round, batch, results));
        }
        fn score(&self, f: &f64) -> Score {
            Score {
                chi2: f.exp(),
                n: 1,
                k: 0,
            }
        }
        fn summarise(&self, _: &f64) {}
        fn heldout(&mut self, _: usize, _: C, _: &f64) -> Result<(), ()> {
            Ok(())
        }
        fn gate(&mut self, _: &Current<'_, Self>, c: &Candidate<'_, Self>) -> Gate<()> {
            self.events.push(format!("gate c{}", c.candidate.0));
            Gate {
                passes: c.delta_bic < -10.0 && !self.fails.contains(&c.candidate.0),
                heldout_delta_bic: f64::NAN,
                heldout_rank: 0.0,
                detail: (),
            }
        }
        fn adopt(
            &mut self,
            _: &Current<'_, Self>,
            _: C,
            f: f64,
            h: (),
        ) -> Result<(f64, (), ()), ()> {
            Ok((f, h, ()))
        }
        fn fit_screen(&self) -> FitScreen {
            self.screen
        }
        fn predict(&mut self, _: usize, _: &f64, open: &[C]) -> Result<Vec<Prediction>, ()> {
            Ok(open
                .iter()
                .map(|c| Prediction {
                    delta_bic: Some(self.predicted[c.0]),
                    how: "toy".into(),
                })
                .collect())
        }
        fn screened_out(&mut self, round: usize, c: C, _: &Prediction) {
            self.screened.push((round, c.0));
        }
        fn confirm(
            &mut self,
            _: &Current<'_, Self>,
            c: &Candidate<'_, Self>,
            g: &mut Gate<()>,
        ) -> Result<(), ()> {
            if self.refused.contains(&c.candidate.0) {
                g.passes = false;
            }
            Ok(())
        }
    }

    fn run_toy(fails: &[usize], screen: FitScreen) -> (Vec<C>, Toy) {
        let mut toy = Toy::new(fails, screen, &[]);
        let policy = Policy {
            rounds: 5,
            max_adopted: 4,
            rank: Rank::FittedBic,
            screen: Screen::All,
        };
        let v = select(&mut toy, &policy, 0.0, ()).unwrap();
        (v.adopted(), toy)
    }

    const PREDICTED: FitScreen = FitScreen::Predicted {
        least: 2,
        margin: 0.5,
        fallback_below: -10.0,
        least_below: f64::INFINITY,
    };

    /// The screen fits the two best predicted (and those near the best), reports the others
    /// as screened out, and adopts what the full search adopts with fewer fits.
    #[test]
    fn the_screen_fits_the_best_predicted_and_keeps_the_verdict() {
        let (full, full_toy) = run_toy(&[], FitScreen::Off);
        let (screened, toy) = run_toy(&[], PREDICTED);
        assert_eq!(full, [C(2), C(0), C(3)]);
        assert_eq!(screened, full);
        assert_eq!(full_toy.fits, 4 + 3 + 2 + 1);
        assert_eq!(toy.fits, 2 + 2 + 2 + 1);
        assert!(full_toy.screened.is_empty());
        // Round 1 fits c2 and c3 (predicted −150, −60); round 2 c3 and c0.
        assert_eq!(toy.screened, [(1, 0), (1, 1), (2, 1)]);
    }

    /// A screen whose `least` fits only candidates predicted to pay leaves a round of
    /// candidates predicted not to pay unfitted (the beam's last round: +9.8 and +16.8), where
    /// the plain screen fits its two best whatever they are predicted; both fit a candidate
    /// predicted to pay, and one that is not predicted at all.
    #[test]
    fn least_only_paying_fits_no_candidate_predicted_not_to_pay() {
        let p = |d: Option<f64>| {
            Some(Prediction {
                delta_bic: d,
                how: String::new(),
            })
        };
        let lose = [p(Some(16.8)), p(Some(9.8))];
        let plain = FitScreen::from_options(true, 2, 0.5, 10.0);
        assert_eq!(plan_fits(&plain, &lose).0, [0, 1]);
        let paying = plain.least_only_paying();
        assert_eq!(plan_fits(&paying, &lose), (vec![], vec![]));
        let mixed = [p(Some(9.8)), p(Some(-300.0)), p(None)];
        assert_eq!(plan_fits(&paying, &mixed).0, [1, 2]);
        assert_eq!(plan_fits(&plain, &mixed).0, [0, 1, 2]);
    }

    /// Two candidates the prediction cannot tell apart (within the gate's threshold) are both
    /// fitted, though the second lies beyond the `least` and the margin: the measured beam's
    /// plain damping (predicted −10,795.3) and its power law (−10,785.5, the same step less one
    /// parameter's penalty) behind the creep (−23,358.7), stepped finely.
    #[test]
    fn candidates_predicted_alike_are_fitted_alike() {
        let p = |d: Option<f64>| {
            Some(Prediction {
                delta_bic: d,
                how: String::new(),
            })
        };
        let round = [
            p(Some(-10_785.5)),
            p(Some(-23_358.7)),
            p(Some(-10_795.3)),
            p(Some(-156.3)),
            p(None),
        ];
        let screen = FitScreen::paying(true, 2, 0.5, 10.0);
        assert_eq!(plan_fits(&screen, &round), (vec![0, 1, 2, 4], vec![3]));
        // Apart by more than the threshold, the third waits in the reserve.
        let apart = [p(Some(-10_700.0)), round[1].clone(), round[2].clone()];
        assert_eq!(plan_fits(&screen, &apart), (vec![1, 2], vec![0]));
    }

    /// When nothing fitted passes, the next predicted to pay is fitted before the round gives
    /// up: the screen's misranking costs a fit, not the verdict.
    #[test]
    fn nothing_fitted_passes_so_the_reserve_is_fitted() {
        let (full, _) = run_toy(&[2, 3], FitScreen::Off);
        let (screened, toy) = run_toy(&[2, 3], PREDICTED);
        assert_eq!(full[0], C(0));
        assert_eq!(screened, full);
        // Round 1: c2, c3 (both fail the gate), then c0 from the reserve; c1 (predicted −1)
        // is never fitted in round 1.
        assert!(toy.screened.contains(&(1, 1)));
        assert!(!toy.screened.contains(&(1, 0)));
    }

    /// When every candidate that passed the gate is refused by the last check (the motion
    /// diagnosis' check against the mesh's own null), the reserve is fitted as when nothing
    /// passes the gate: the round adopts what the full search adopts, and the reserve's attempt
    /// replaces its "screened out" record.
    #[test]
    fn every_passing_candidate_refused_so_the_reserve_is_fitted() {
        let policy = Policy {
            rounds: 1,
            max_adopted: 1,
            rank: Rank::FittedBic,
            screen: Screen::All,
        };
        let run = |screen: FitScreen| {
            let mut toy = Toy::new(&[], screen, &[]);
            toy.refused = vec![2, 3];
            let v = select(&mut toy, &policy, 0.0, ()).unwrap();
            let screened_out: Vec<usize> = v.rounds[0]
                .attempts
                .iter()
                .filter(|a| a.screened_out)
                .map(|a| a.candidate.0)
                .collect();
            (v.adopted(), screened_out, toy)
        };
        let (full, _, _) = run(FitScreen::Off);
        assert_eq!(full, [C(0)]);
        let (screened, out, toy) = run(PREDICTED);
        assert_eq!(screened, full);
        // c2 and c3 (predicted −150, −60) fitted and refused, then c0 from the reserve; c1
        // (predicted −1) is left screened out.
        assert_eq!(out, [1]);
        assert_eq!(toy.screened, [(1, 1)]);
        assert_eq!(toy.fits, 3);
    }

    /// Under a shortlist (the static diagnosis: only the `size` best by fitted ΔBIC are gated),
    /// a reserve fitted after the shortlisted ones were refused is gated as the full search
    /// would gate it: when it ranks into the shortlist (c0 at −50, above the refused c3's −30)
    /// it is gated and adopted, as by the full search; when it ranks below the refused ones (c0
    /// at −20) it is not gated, and the round adopts nothing, as the full search does.
    #[test]
    fn a_reserve_fit_is_gated_as_the_full_search_gates_it() {
        let policy = Policy {
            rounds: 1,
            max_adopted: 1,
            rank: Rank::FittedBic,
            screen: Screen::Shortlist {
                bic_threshold: 10.0,
                size: 2,
            },
        };
        let run = |screen: FitScreen, c0: f64| {
            let mut toy = Toy::new(&[], screen, &[]);
            toy.gain[0] = c0;
            toy.refused = vec![2, 3];
            let v = select(&mut toy, &policy, 0.0, ()).unwrap();
            let gated: Vec<usize> = v.rounds[0]
                .attempts
                .iter()
                .filter(|a| a.gate.is_some())
                .map(|a| a.candidate.0)
                .collect();
            (v.adopted(), gated, toy.fits)
        };
        for (c0, adopted, gated) in [(-50.0, vec![C(0)], vec![0, 2]), (-20.0, vec![], vec![2, 3])] {
            let (full, full_gated, full_fits) = run(FitScreen::Off, c0);
            let (screened, screened_gated, fits) = run(PREDICTED, c0);
            assert_eq!(full, adopted, "c0 at {c0}: the full search");
            assert_eq!(screened, full, "c0 at {c0}: the screen");
            assert_eq!(full_gated, gated, "c0 at {c0}");
            assert_eq!(full_fits, 4);
            // c2 and c3, then c0 from the reserve; c1 (predicted −1) is never fitted.
            assert_eq!(fits, 3, "c0 at {c0}");
            if c0 < -30.0 {
                assert_eq!(screened_gated, [0, 2, 3]);
            } else {
                assert_eq!(screened_gated, gated);
            }
        }
    }

    /// A candidate whose fit diverges is not a finding, but it was tried: the engine itself (no
    /// mark set by hand) lists it in every round's attempts as not fitted, with the fit's own
    /// reason, never gated and never adopted; the others are selected as without it.
    #[test]
    fn a_fit_that_diverges_is_listed_as_not_fitted_in_each_round() {
        let mut toy = Toy::new(&[], FitScreen::Off, &[2]);
        let policy = Policy {
            rounds: 5,
            max_adopted: 4,
            rank: Rank::FittedBic,
            screen: Screen::All,
        };
        let v = select(&mut toy, &policy, 0.0, ()).unwrap();
        assert_eq!(v.adopted(), [C(0), C(3)]);
        assert!(!v.rounds.is_empty());
        for (r, round) in v.rounds.iter().enumerate() {
            let a = round
                .attempts
                .iter()
                .find(|a| a.candidate == C(2))
                .unwrap_or_else(|| panic!("round {r}: the diverged c2 is not among the attempts"));
            assert_eq!(a.not_fitted.as_deref(), Some("c2 diverged"), "round {r}");
            assert!(a.gate.is_none() && a.score.is_none(), "round {r}");
        }
    }

    /// Fits done ahead, side by side, leave the verdict and the order of every record as fits
    /// one after the other: each is recorded when the engine reaches it, and a round never takes
    /// another round's fit.
    #[test]
    fn fits_done_ahead_give_the_verdict_and_records_of_fits_in_turn() {
        let policy = Policy {
            rounds: 5,
            max_adopted: 4,
            rank: Rank::FittedBic,
            screen: Screen::All,
        };
        for (fails, screen, diverges) in [
            (vec![], FitScreen::Off, vec![]),
            (vec![], FitScreen::Off, vec![3]),
            (vec![2, 3], FitScreen::Off, vec![1]),
            (vec![2, 3], PREDICTED, vec![]),
        ] {
            let mut in_turn = Toy::new(&fails, screen, &diverges);
            let v = select(&mut in_turn, &policy, 0.0, ()).unwrap();
            let mut ahead = Toy::new(&fails, screen, &diverges);
            ahead.ahead = Some(Ahead::default());
            let w = select(&mut ahead, &policy, 0.0, ()).unwrap();
            assert_eq!(w.adopted(), v.adopted(), "{fails:?} {screen:?}");
            assert_eq!(ahead.events, in_turn.events, "{fails:?} {screen:?}");
            assert_eq!(ahead.fits, in_turn.fits);
            let scores = |v: &Verdict<Toy>| -> Vec<Option<f64>> {
                let r = v.rounds.iter().flat_map(|r| &r.attempts);
                r.map(|a| a.score.map(|s| s.chi2)).collect()
            };
            assert_eq!(scores(&w), scores(&v));
        }
    }

    /// A candidate that depends on another of its batch is fitted after it and handed its
    /// result; the others are fitted together; the results come back in the batch's order.
    #[test]
    fn fit_ahead_waits_for_what_a_fit_starts_from() {
        let batch = [C(0), C(1), C(2), C(3)];
        // c1 starts from c0's fit (as a power law from the Newtonian fit it nests), c3 from c1's.
        let waits = |c: C, e: C| (c.0, e.0) == (1, 0) || (c.0, e.0) == (3, 1);
        let seen = std::sync::Mutex::new(Vec::new());
        let out = fit_ahead(&batch, waits, |c, earlier: &[(C, &(usize, usize))]| {
            seen.lock().unwrap().push(c.0);
            let from: usize = earlier.iter().map(|(_, t)| 10 * t.0 + t.1).sum();
            (c.0 + 1, from)
        });
        assert_eq!(out, [(1, 0), (2, 10), (3, 0), (4, 30)]);
        let seen = seen.into_inner().unwrap();
        let at = |c: usize| seen.iter().position(|&s| s == c).unwrap();
        assert!(at(0) < at(1) && at(1) < at(3), "{seen:?}");
        assert_eq!(seen.len(), 4);
    }

    /// A fit that waits for another starts when that one is done, not when every fit started
    /// beside it is: on two threads c2, which cannot finish before c1 has (it waits for c1's
    /// signal, at most 20 s), finishes at once; in waves c1 would wait for c2 and c2 time out.
    #[test]
    fn a_nested_fit_starts_when_its_own_dependency_is_done() {
        use std::sync::{Condvar, Mutex};
        use std::time::Duration;
        let batch = [C(0), C(1), C(2)];
        let waits = |c: C, e: C| (c.0, e.0) == (1, 0);
        let signal = (Mutex::new(false), Condvar::new());
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let out = pool.install(|| {
            fit_ahead(&batch, waits, |c, _earlier: &[(C, &bool)]| match c.0 {
                1 => {
                    *signal.0.lock().unwrap() = true;
                    signal.1.notify_all();
                    true
                }
                2 => {
                    let seen = signal
                        .1
                        .wait_timeout_while(
                            signal.0.lock().unwrap(),
                            Duration::from_secs(20),
                            |s| !*s,
                        )
                        .unwrap();
                    *seen.0
                }
                _ => true,
            })
        });
        assert_eq!(out, [true, true, true], "c2 timed out waiting for c1");
    }

    /// The motion and runs rooms log this line before a batch; the words are the ones their
    /// logs carried when each room wrote it out itself, labels in the batch's order.
    #[test]
    fn the_side_by_side_line_names_the_round_and_the_batch_in_order() {
        assert_eq!(
            side_by_side_line(3, &[C(2), C(0)]),
            "round 3: fitting c2, c0 side by side (the lines of each follow in turn)"
        );
    }
}
