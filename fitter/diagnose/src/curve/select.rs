//! The loop: fit the simplest model, look at the residual, refit every candidate augmentation,
//! score it by BIC and by held-out RMS, adopt the best one that passes both gates, repeat.
//!
//! Held-out scheme: with ≥ 3 files/runs, leave whole files/runs out (merged round-robin into at
//! most 10 folds), so an effect must predict a rate, a stretch level or a run not used in the fit.
//! With fewer, 5 contiguous blocks of samples of each file (the last block is an extrapolation in
//! x for a monotone pull). Time-series models are always integrated over the whole record; only
//! the residuals of held-out samples are left out of the fit.

use super::fit::{fit, residuals, Fit, Mask};
use super::model::{Candidate, Model};
use super::read::Group;
use super::signature::{directions, holds, rates, signature, Signature, Variable};
use super::CurveOptions;

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

/// A fitted parameter with its 1σ uncertainty from the Gauss–Newton covariance.
#[derive(Debug, Clone, serde::Serialize)]
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
    let n = f.n as f64;
    n * (f.rss / n).max(f64::MIN_POSITIVE).ln() + f.theta.len() as f64 * n.ln()
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
    let wanted: &[Variable] = match c {
        Candidate::Viscosity => &[Variable::Direction, Variable::Rate, Variable::HoldTime],
        Candidate::Saturation => &[Variable::Top, Variable::Magnitude],
        Candidate::Drift => &[Variable::Group],
        Candidate::Slack => &[Variable::Direction, Variable::Magnitude],
        _ => &[Variable::Magnitude],
    };
    sig.signals
        .iter()
        .find(|s| wanted.contains(&s.variable))
        .map_or(wanted[0], |s| s.variable)
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
    let mut cur = fit(&start, groups, None, None, o.max_iterations)?;
    let mut cur_held = cross_validate(&cur, groups, &folds, o)?;
    let mut cur_err = errors(&cur, groups, &cur_held);
    log(&format!(
        "{}: RMS {:.4e} fitted, {:.4e} held out",
        cur.model.describe(),
        cur_err.fitted_rms,
        cur_err.heldout_rms
    ));
    let mut sel = Selection {
        holdout,
        steps: vec![],
        fits: vec![cur.clone()],
        heldout: vec![cur_held.clone()],
        errors: vec![cur_err],
    };
    for round in 1..=o.max_effects + 1 {
        let sig = signature(groups, &resid_of(&cur, groups), time_series);
        let cur_bic = bic(&cur);
        let mut tried = Vec::new();
        let mut fits = Vec::new();
        let cands: Vec<Candidate> = cur
            .model
            .candidates(groups.len(), rate_info)
            .into_iter()
            .filter(|c| o.candidates.as_ref().is_none_or(|l| l.contains(&c.name())))
            .collect();
        for c in cands {
            let m = cur.model.with(c);
            let Some(f) = fit(
                &m,
                groups,
                None,
                Some((&cur.model, &cur.theta)),
                o.max_iterations,
            ) else {
                log(&format!("  {}: fit failed", c.name()));
                continue;
            };
            let held = cross_validate(&f, groups, &folds, o);
            let e = held.as_ref().map(|h| errors(&f, groups, h));
            let hr = e.map_or(f64::INFINITY, |e| e.heldout_rms);
            let db = bic(&f) - cur_bic;
            let gain = 1.0 - hr / cur_err.heldout_rms;
            let passed = db < -o.bic_threshold && gain >= o.min_holdout_gain;
            log(&format!(
                "  {:<28} ΔBIC {:>10.1}  held-out RMS {:.4e} (gain {:+.1} %){}",
                c.name(),
                db,
                hr,
                100.0 * gain,
                if passed { "  passes" } else { "" }
            ));
            tried.push(Tried {
                candidate: c.name(),
                extra_params: f.theta.len() as i64 - cur.theta.len() as i64,
                rms: (f.rss / f.n as f64).sqrt(),
                delta_bic: db,
                heldout_rms: hr,
                gain,
                passed,
            });
            fits.push((c, f, held, e));
        }
        let mut order: Vec<usize> = (0..tried.len()).collect();
        order.sort_by(|&a, &b| tried[a].heldout_rms.total_cmp(&tried[b].heldout_rms));
        let best = order.iter().copied().find(|&i| tried[i].passed);
        let tried_sorted: Vec<Tried> = order.iter().map(|&i| tried[i].clone()).collect();
        let model_name = cur.model.describe();
        let before = cur_err;
        match best {
            Some(i) if round <= o.max_effects => {
                let (c, f, held, e) = fits.swap_remove(i);
                let (held, e) = (held.expect("passed implies held-out"), e.expect("passed"));
                let reason = format!(
                    "{} lowers the held-out RMS by {:.1} % (≥ {:.0} %) and BIC by {:.1} (> {:.0}); best held-out of {} passing",
                    c.name(),
                    100.0 * tried[i].gain,
                    100.0 * o.min_holdout_gain,
                    -tried[i].delta_bic,
                    o.bic_threshold,
                    tried.iter().filter(|t| t.passed).count()
                );
                log(&format!("round {round}: adopt {}", c.name()));
                sel.steps.push(Step {
                    round,
                    model: model_name,
                    evidence: Some(evidence_variable(c, &sig)),
                    signature: sig,
                    tried: tried_sorted,
                    adopted: Some(c),
                    reason,
                    before,
                    after: Some(e),
                });
                cur = f;
                cur_held = held;
                cur_err = e;
                sel.fits.push(cur.clone());
                sel.heldout.push(cur_held.clone());
                sel.errors.push(cur_err);
            }
            other => {
                let reason = if other.is_some() {
                    format!(
                        "a candidate passes, but the limit of {} effects is reached",
                        o.max_effects
                    )
                } else if tried.is_empty() {
                    "no candidate left to try".into()
                } else {
                    format!(
                        "no candidate lowers the held-out RMS by ≥ {:.0} % with ΔBIC < −{:.0}: nothing significant is left",
                        100.0 * o.min_holdout_gain,
                        o.bic_threshold
                    )
                };
                log(&format!("round {round}: {reason}"));
                sel.steps.push(Step {
                    round,
                    model: model_name,
                    signature: sig,
                    tried: tried_sorted,
                    adopted: None,
                    reason,
                    before,
                    after: None,
                    evidence: None,
                });
                break;
            }
        }
    }
    Some(sel)
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
