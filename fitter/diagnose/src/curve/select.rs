//! The loop: fit the simplest model, look at the residual, refit every candidate augmentation,
//! score it by BIC and by held-out RMS, adopt the best one that passes both gates, repeat.
//!
//! Held-out scheme: with ≥ 3 files/runs, leave whole files/runs out (merged round-robin into at
//! most 10 folds), so an effect must predict a rate, a stretch level or a run not used in the fit.
//! With fewer, 5 contiguous blocks of samples of each file (the last block is an extrapolation in
//! x for a monotone pull). Time-series models are always integrated over the whole record; only
//! the residuals of held-out samples are left out of the fit.

use super::candidates::Candidate;
use super::fit::{fit, residuals, Fit, Mask};
use super::model::Model;
use super::read::Group;
use super::signature::{directions, holds, rates, signature, Signature, Variable};
use super::CurveOptions;
use crate::select::{
    self as engine, CandidateModel, Current, Gate, HeldoutGate, Outcome, Policy, Rank, Score,
    Screen, Verdict,
};

/// Error figures in the response's unit.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Errors {
    /// RMS on the fitted data.
    pub fitted_rms: f64,
    /// Largest |error| on the fitted data.
    pub fitted_max: f64,
    /// RMS on held-out data (each sample predicted by the fit that left it out).
    pub heldout_rms: f64,
    /// Largest held-out |error|.
    pub heldout_max: f64,
}

/// A fitted parameter with its 1σ uncertainty (one type with the static diagnosis).
pub use crate::select::ParamValue;

/// A candidate tried in a round.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Tried {
    /// Candidate.
    pub candidate: String,
    /// Parameters of the augmented model minus those of the current one.
    pub extra_params: i64,
    /// Fitted RMS.
    pub rms: f64,
    /// ΔBIC against the current model.
    pub delta_bic: f64,
    /// Held-out RMS.
    pub heldout_rms: f64,
    /// Held-out gain 1 − held-out RMS / current held-out RMS.
    pub gain: f64,
    /// Passed both gates.
    pub passed: bool,
}

/// One round.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Step {
    /// Round (1-based).
    pub round: usize,
    /// Model at the start of the round.
    pub model: String,
    /// Its residual signature.
    pub signature: Signature,
    /// Candidates tried, best held-out first.
    pub tried: Vec<Tried>,
    /// Adopted candidate.
    pub adopted: Option<Candidate>,
    /// Why (or why not).
    pub reason: String,
    /// Errors at the start of the round.
    pub before: Errors,
    /// Errors after adoption.
    pub after: Option<Errors>,
    /// The variable that gave the adopted effect away.
    pub evidence: Option<Variable>,
}

/// Result of the loop.
#[derive(Debug, Clone)]
pub struct Selection {
    /// Held-out scheme in words.
    pub holdout: String,
    /// Rounds.
    pub steps: Vec<Step>,
    /// Fits: the simplest model, then one per adopted effect.
    pub fits: Vec<Fit>,
    /// Held-out predictions of each fit, per group.
    pub heldout: Vec<Vec<Vec<f64>>>,
    /// Errors of each fit.
    pub errors: Vec<Errors>,
}

/// Held-out folds: masks with `true` = held out.
pub fn folds(groups: &[Group]) -> (String, Vec<Mask>) {
    if groups.len() >= 3 {
        let k = groups.len().min(10);
        let masks = (0..k)
            .map(|f| {
                groups
                    .iter()
                    .enumerate()
                    .map(|(gi, g)| vec![gi % k == f; g.x.len()])
                    .collect()
            })
            .collect();
        let what = if k == groups.len() {
            format!("leave one file/run out ({k} folds)")
        } else {
            format!(
                "leave files/runs out, {} files in {k} round-robin folds",
                groups.len()
            )
        };
        (what, masks)
    } else {
        let k = groups.iter().map(|g| g.x.len()).min().unwrap_or(0).min(5);
        let masks = (0..k)
            .map(|f| {
                groups
                    .iter()
                    .map(|g| {
                        let n = g.x.len();
                        (0..n).map(|i| i * k / n == f).collect()
                    })
                    .collect()
            })
            .collect();
        (
            format!("{k} contiguous blocks of samples per file, each held out in turn"),
            masks,
        )
    }
}

fn rms_max(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut s, mut m, mut n) = (0.0, 0.0f64, 0usize);
    for e in v {
        s += e * e;
        m = m.max(e.abs());
        n += 1;
    }
    ((s / n.max(1) as f64).sqrt(), m)
}

/// Held-out predictions of `full`'s model (refitted per fold, warm-started from `full`).
fn cross_validate(
    full: &Fit,
    groups: &[Group],
    folds: &[Mask],
    o: &CurveOptions,
) -> Option<Vec<Vec<f64>>> {
    let mut out: Vec<Vec<f64>> = groups.iter().map(|g| vec![f64::NAN; g.x.len()]).collect();
    for held in folds {
        let train: Mask = held
            .iter()
            .map(|m| m.iter().map(|b| !b).collect())
            .collect();
        let f = fit(
            &full.model,
            groups,
            Some(&train),
            Some((&full.model, &full.theta)),
            o.holdout_iterations,
        )?;
        for (gi, g) in groups.iter().enumerate() {
            if held[gi].iter().any(|&b| b) {
                let p = full.model.predict(&f.theta, g)?;
                for i in 0..g.x.len() {
                    if held[gi][i] {
                        out[gi][i] = p[i];
                    }
                }
            }
        }
    }
    Some(out)
}

fn errors(f: &Fit, groups: &[Group], held: &[Vec<f64>]) -> Errors {
    let r = residuals(&f.model, &f.theta, groups, None).unwrap_or_default();
    let (fitted_rms, fitted_max) = rms_max(r.into_iter());
    let (heldout_rms, heldout_max) = rms_max(
        groups
            .iter()
            .zip(held)
            .flat_map(|(g, h)| g.y.iter().zip(h).map(|(y, p)| p - y)),
    );
    Errors {
        fitted_rms,
        fitted_max,
        heldout_rms,
        heldout_max,
    }
}

/// Whether a time-series record can separate viscosity from elasticity: it has unloading, a
/// hold at non-zero load, or loading rates differing by more than 1.5× between files. A single
/// monotone pull at one rate cannot: any viscous branch is then just another shape function of x.
pub fn has_rate_information(groups: &[Group]) -> bool {
    let dirs = directions(groups);
    if dirs.iter().flatten().any(|&d| d < 0) || !holds(groups, &dirs).is_empty() {
        return true;
    }
    let mean_rates: Vec<f64> = groups
        .iter()
        .zip(&dirs)
        .filter_map(|(g, d)| {
            let r = rates(g);
            let v: Vec<f64> = (0..r.len()).filter(|&i| d[i] > 0).map(|i| r[i]).collect();
            (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
        })
        .collect();
    let lo = mean_rates.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = mean_rates.iter().copied().fold(0.0, f64::max);
    lo > 0.0 && hi / lo > 1.5
}

/// BIC with unknown noise variance: n ln(RSS/n) + k ln n.
pub fn bic(f: &Fit) -> f64 {
    crate::select::bic(f.rss, f.n, f.theta.len())
}

/// Measured − model per group.
pub fn resid_of(f: &Fit, groups: &[Group]) -> Vec<Vec<f64>> {
    groups
        .iter()
        .map(|g| match f.model.predict(&f.theta, g) {
            Some(p) => g.y.iter().zip(p).map(|(y, p)| y - p).collect(),
            None => vec![f64::NAN; g.x.len()],
        })
        .collect()
}

/// The variable that best shows what `c` explains, from the signature of the model it augments.
pub fn evidence_variable(c: Candidate, sig: &Signature) -> Variable {
    let wanted = c.effect().evidence();
    sig.signals
        .iter()
        .find(|s| wanted.contains(&s.variable))
        .map_or(wanted[0], |s| s.variable)
}

/// The curve diagnosis as the selection engine sees it.
struct CurveModel<'a> {
    groups: &'a [Group],
    folds: Vec<Mask>,
    time_series: bool,
    /// Whether viscous candidates can be told from elastic ones ([`has_rate_information`]).
    rate_info: bool,
    o: &'a CurveOptions,
    log: &'a mut dyn FnMut(&str),
}

/// Held-out predictions of a fit and its errors; `None` when a fold's refit failed (the
/// candidate then cannot pass: its held-out RMS counts as infinite).
type CurveHeld = Option<(Vec<Vec<f64>>, Errors)>;

/// The curve gate's figures of one candidate: held-out RMS and gain.
struct CurveGate {
    heldout_rms: f64,
    gain: f64,
}

impl CandidateModel for CurveModel<'_> {
    type Candidate = Candidate;
    type Fitted = Fit;
    type Held = CurveHeld;
    type Observed = Signature;
    type Summary = ();
    type Detail = CurveGate;
    type Adoption = ();
    type Error = std::convert::Infallible;

    fn observe(&mut self, _round: usize, f: &Fit, _held: &CurveHeld) -> Signature {
        signature(self.groups, &resid_of(f, self.groups), self.time_series)
    }

    fn candidates(&mut self, cur: &Fit, _adopted: &[Candidate]) -> Vec<Candidate> {
        // The model knows which candidates it can still take (and which exclude each other).
        let wanted = |c: &Candidate| {
            self.o
                .candidates
                .as_ref()
                .is_none_or(|l| l.contains(&c.name()))
        };
        cur.model
            .candidates(self.groups.len(), self.rate_info)
            .into_iter()
            .filter(wanted)
            .collect()
    }

    fn fit_with(
        &mut self,
        _round: usize,
        cur: &Fit,
        c: Candidate,
    ) -> Result<Outcome<Fit>, Self::Error> {
        let m = cur.model.with(c);
        let warm = Some((&cur.model, cur.theta.as_slice()));
        Ok(
            match fit(&m, self.groups, None, warm, self.o.max_iterations) {
                Some(f) => Outcome::Fitted(f),
                None => {
                    (self.log)(&format!("  {}: fit failed", c.name()));
                    Outcome::Dropped
                }
            },
        )
    }

    fn score(&self, f: &Fit) -> Score {
        Score {
            chi2: f.rss,
            n: f.n,
            k: f.theta.len(),
        }
    }

    fn summarise(&self, _f: &Fit) {}

    fn heldout(&mut self, _round: usize, _c: Candidate, f: &Fit) -> Result<CurveHeld, Self::Error> {
        let held = cross_validate(f, self.groups, &self.folds, self.o);
        Ok(held.map(|h| {
            let e = errors(f, self.groups, &h);
            (h, e)
        }))
    }

    fn gate(
        &mut self,
        cur: &Current<'_, Self>,
        cand: &engine::Candidate<'_, Self>,
    ) -> Gate<CurveGate> {
        let o = self.o;
        let cur_rms = cur.held.as_ref().map_or(f64::NAN, |h| h.1.heldout_rms);
        let hr = cand
            .held
            .as_ref()
            .map_or(f64::INFINITY, |h| h.1.heldout_rms);
        let db = cand.delta_bic;
        let gain = 1.0 - hr / cur_rms;
        // No held-out ΔBIC: the curve diagnosis ranks by the held-out RMS instead.
        let gate = HeldoutGate {
            bic_threshold: o.bic_threshold,
            min_holdout_gain: o.min_holdout_gain,
        };
        let passes = gate.passes(db, None, -gain);
        (self.log)(&format!(
            "  {:<28} ΔBIC {:>10.1}  held-out RMS {:.4e} (gain {:+.1} %){}",
            cand.candidate.name(),
            db,
            hr,
            100.0 * gain,
            if passes { "  passes" } else { "" }
        ));
        Gate {
            passes,
            // Ambiguities are not reported by the curve diagnosis.
            heldout_delta_bic: f64::NAN,
            heldout_rank: hr,
            detail: CurveGate {
                heldout_rms: hr,
                gain,
            },
        }
    }

    fn adopt(
        &mut self,
        cur: &Current<'_, Self>,
        c: Candidate,
        f: Fit,
        held: CurveHeld,
    ) -> Result<(Fit, CurveHeld, ()), Self::Error> {
        (self.log)(&format!("round {}: adopt {}", cur.round, c.name()));
        Ok((f, held, ()))
    }
}

/// The curve report's rounds from the engine's verdict (tried best held-out first).
fn curve_steps(v: &Verdict<CurveModel<'_>>, o: &CurveOptions) -> Vec<Step> {
    v.rounds
        .iter()
        .map(|r| {
            let (cur, cur_held) = &v.path[r.round - 1];
            let tried: Vec<Tried> = r
                .ranked()
                .map(|a| {
                    let s = a.score.expect("the curve diagnosis records fitted candidates only");
                    let g = a.gate.as_ref().expect("every fitted candidate is gated");
                    Tried {
                        candidate: a.candidate.name(),
                        extra_params: s.k as i64 - cur.theta.len() as i64,
                        rms: (s.chi2 / s.n as f64).sqrt(),
                        delta_bic: a.delta_bic,
                        heldout_rms: g.detail.heldout_rms,
                        gain: g.detail.gain,
                        passed: g.passes,
                    }
                })
                .collect();
            let before = cur_held.as_ref().expect("the current model has held-out predictions").1;
            let adopted = r.adopted_attempt();
            let reason = match (adopted, r.stop) {
                (Some(a), _) => {
                    let g = a.gate.as_ref().expect("gated");
                    format!(
                        "{} lowers the held-out RMS by {:.1} % (≥ {:.0} %) and BIC by {:.1} (> {:.0}); best held-out of {} passing",
                        a.candidate.name(),
                        100.0 * g.detail.gain,
                        100.0 * o.min_holdout_gain,
                        -a.delta_bic,
                        o.bic_threshold,
                        tried.iter().filter(|t| t.passed).count()
                    )
                }
                (None, Some(engine::Stop::Limit)) => format!(
                    "a candidate passes, but the limit of {} effects is reached",
                    o.max_effects
                ),
                (None, Some(engine::Stop::NothingToTry)) => "no candidate left to try".into(),
                (None, _) => format!(
                    "no candidate lowers the held-out RMS by ≥ {:.0} % with ΔBIC < −{:.0}: nothing significant is left",
                    100.0 * o.min_holdout_gain,
                    o.bic_threshold
                ),
            };
            Step {
                round: r.round,
                model: cur.model.describe(),
                signature: r.observed.clone(),
                tried,
                adopted: adopted.map(|a| a.candidate),
                reason,
                before,
                after: adopted.and_then(|a| a.held.as_ref().and_then(|h| h.as_ref().map(|h| h.1))),
                evidence: adopted.map(|a| evidence_variable(a.candidate, &r.observed)),
            }
        })
        .collect()
}

/// Runs the loop from `start`.
pub fn select(
    start: Model,
    groups: &[Group],
    time_series: bool,
    o: &CurveOptions,
    log: &mut dyn FnMut(&str),
) -> Option<Selection> {
    let (holdout, folds) = folds(groups);
    let rate_info = time_series && has_rate_information(groups);
    let cur = fit(&start, groups, None, None, o.max_iterations)?;
    let cur_held = cross_validate(&cur, groups, &folds, o)?;
    let cur_err = errors(&cur, groups, &cur_held);
    log(&format!(
        "{}: RMS {:.4e} fitted, {:.4e} held out",
        cur.model.describe(),
        cur_err.fitted_rms,
        cur_err.heldout_rms
    ));
    let policy = Policy {
        // One round more than effects: the last one reports a candidate that would still pass.
        rounds: o.max_effects + 1,
        max_adopted: o.max_effects,
        rank: Rank::Heldout,
        screen: Screen::All,
    };
    let mut model = CurveModel {
        groups,
        folds,
        time_series,
        rate_info,
        o,
        log: &mut *log,
    };
    let verdict = match engine::select(&mut model, &policy, cur, Some((cur_held, cur_err))) {
        Ok(v) => v,
        Err(never) => match never {},
    };
    let steps = curve_steps(&verdict, o);
    let (mut fits, mut heldout, mut errors) = (Vec::new(), Vec::new(), Vec::new());
    for (f, h) in verdict.path {
        let (h, e) = h.expect("an adopted model has held-out predictions");
        fits.push(f);
        heldout.push(h);
        errors.push(e);
    }
    // The last round says why the loop stopped (the engine's verdict borrows `log` until here).
    if let Some(st) = steps.last().filter(|st| st.adopted.is_none()) {
        log(&format!("round {}: {}", st.round, st.reason));
    }
    Some(Selection {
        holdout,
        steps,
        fits,
        heldout,
        errors,
    })
}

/// Physical parameter values with 1σ (delta method through θ = ln v for positive parameters).
pub fn param_values(f: &Fit) -> Vec<ParamValue> {
    f.model
        .params()
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let v = p.value(f.theta[i]);
            let sd_t = f
                .cov
                .as_ref()
                .map_or(f64::NAN, |c| c[(i, i)].max(0.0).sqrt());
            ParamValue {
                name: p.name.clone(),
                value: v,
                sd: if p.log { v * sd_t } else { sd_t },
                unit: p.unit.clone(),
            }
        })
        .collect()
}
