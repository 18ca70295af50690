//! The motion room's fit screen ([`crate::select::FitScreen`], [`super::MotionOptions::screen`]):
//! before a round's fits, one simulation with direct sensitivities at the current fit gives the
//! misfit's gradient and Gauss–Newton matrix over the current parameters and the union of the
//! open candidates' new ones, each at its neutral value (ν = 0, c = 0: the current model; the
//! density at its current value) — [`crate::screen`]. A candidate's predicted gain is the χ²
//! drop of one Gauss–Newton step over the current parameters and its own (the score statistic),
//! charged its parameters as BIC charges them (nothing but that charge where the step holds
//! every new parameter at its neutral value: the candidate is then the current model,
//! [`screen::held_at_neutral`]). The candidates without such a column say how they are
//! predicted in their files ([`super::MotionEffect::predict`]): the marker offsets in closed form
//! at the current material, the time offset by its scan, the second material not at all (its
//! region search is a screen of its own: always fitted). The best predicted are fitted in full;
//! the rest are reported with their predicted ΔBIC and fitted after all if nothing fitted
//! passes the gate.
//!
//! Every step over the current parameters and a candidate's holds the current parameters' own
//! step, which at a fit stopped at its minimum should gain nothing. Where the misfit is far from
//! quadratic over it (a residual the mesh's own error makes large) the Gauss–Newton model of
//! that step promises a gain no refit finds, and each candidate's prediction carries it. The
//! screen simulates that step once a round where it promises more than the gate's threshold
//! (`Screening::new`); where it realises less than a quarter of its promise (`POOR_STEP`),
//! each candidate is predicted by its gain beyond it (`Screening::predicted`), the score
//! statistic's increment over the current parameters' own.

use std::cell::Cell;
use std::sync::Arc;

use palpate_motion::gradient::{evaluate, evaluate_gauss_newton};
use palpate_motion::model::{Material, Model, Observations, Param, ParamKind};

use super::candidates::two_material::RegionSearch;
use super::candidates::Candidate;
use super::engine::MotionModel;
use super::fit::{self, FittedModel};
use super::MotionDiagnoseError;
use crate::screen::{self, Normal};
use crate::select::{self, Prediction};

/// The current fit linearised once for a round's predictions.
pub struct Screening<'m, 'a> {
    /// The room's fitter.
    pub(in crate::motion) model: &'m MotionModel<'a>,
    /// The current fit.
    pub(in crate::motion) cur: &'m FittedModel,
    /// Φ, gradient and Gauss–Newton matrix over `kinds`, then each region's μ (`None`: no
    /// candidate is linearised).
    normal: Option<Normal>,
    /// χ² of the linearisation's own simulation (m²).
    chi2_sim: f64,
    /// The global parameters linearised: the current model's, then the candidates'.
    kinds: Vec<ParamKind>,
    /// Their values at the linearisation (the candidates' at their neutral values).
    at: Vec<f64>,
    /// Where the predictions' Gauss–Newton steps took the candidates' new parameters.
    stepped: std::cell::RefCell<Vec<(ParamKind, f64)>>,
    /// The χ² drop (m²) the current parameters' own Gauss–Newton step promises and does not
    /// realise, taken off every linearised candidate's gain (0: the step realises it, or
    /// promises nothing worth checking).
    unrealised: f64,
    /// What the check of the current parameters' own step found, for the round's log.
    own_step: Option<String>,
    /// Simulations run for the round's predictions.
    simulations: Cell<usize>,
    /// The second material's region search the prediction ran, for the round's fit.
    region_search: std::cell::RefCell<Option<Arc<RegionSearch>>>,
    /// The fitted steps as the current fit sees them ([`as_seen`]), made once a round.
    seen: std::cell::OnceCell<(Model, Observations)>,
}

impl<'m, 'a> Screening<'m, 'a> {
    /// The linearisation at `cur` for the candidates `open`: one simulation with direct
    /// sensitivities, on the data as the current model sees them (its time offset, its marker
    /// offsets eliminated in closed form).
    pub(in crate::motion) fn new(
        model: &'m MotionModel<'a>,
        cur: &'m FittedModel,
        open: &[Candidate],
    ) -> Result<Self, MotionDiagnoseError> {
        Self::linearised_at(model, cur, open, None)
    }

    /// [`Self::new`] with the current parameters' unrealised drop already known (`Some`: from
    /// the round's own screening, for a candidate linearised at the current model read another
    /// way), or checked here (`None`).
    pub(in crate::motion) fn linearised_at(
        model: &'m MotionModel<'a>,
        cur: &'m FittedModel,
        open: &[Candidate],
        unrealised: Option<f64>,
    ) -> Result<Self, MotionDiagnoseError> {
        let mut kinds = cur.kinds.clone();
        let mut mat = cur.material.clone();
        for c in open {
            for &(k, neutral) in c.effect().screened_params() {
                if kinds.contains(&k) {
                    continue;
                }
                kinds.push(k);
                if let Some(v) = neutral {
                    mat.set(&[Param::global(k)], &[v]);
                }
            }
        }
        let at = mat.read(&Param::globals(&kinds));
        let mut screening = Self {
            model,
            cur,
            normal: None,
            chi2_sim: 0.0,
            kinds,
            at,
            stepped: Default::default(),
            unrealised: unrealised.unwrap_or(0.0),
            own_step: None,
            simulations: Cell::new(0),
            region_search: Default::default(),
            seen: Default::default(),
        };
        if screening.kinds.len() == cur.kinds.len() {
            return Ok(screening);
        }
        let params = fit::params_for(&screening.kinds, &mat);
        let (normal, chi2_sim) = screening.linearise(&mat, &params)?;
        screening.chi2_sim = chi2_sim;
        if unrealised.is_none() {
            (screening.unrealised, screening.own_step) =
                screening.own_step_unrealised(screening.seen()?, &normal, &mat, &params)?;
        }
        screening.normal = Some(normal);
        Ok(screening)
    }

    /// The χ² drop the current parameters' own Gauss–Newton step promises and does not realise:
    /// the step (over the current parameters alone, the candidates' at their neutral values) is
    /// simulated where it promises a ΔBIC beyond the gate's threshold, and again at half its
    /// length where it simulates but realises less than [`POOR_STEP`] of its promise; where the
    /// better of the two still does, its whole promise is unrealised. A step that does not
    /// simulate realises nothing.
    fn own_step_unrealised(
        &self,
        seen: &(Model, Observations),
        normal: &Normal,
        mat: &Material,
        params: &[Param],
    ) -> Result<(f64, Option<String>), MotionDiagnoseError> {
        let own = self.cur.kinds.len();
        let globals = self.kinds.len();
        let cols: Vec<usize> = (0..own).chain(globals..normal.len()).collect();
        let parts = std::slice::from_ref(normal);
        let delta = screen::step(parts, &cols);
        let change = screen::change(parts, &cols, &delta)[0];
        let chi2_fit = self.cur.scores.chi2_fit;
        let promised = chi2_fit - stepped_chi2(self.cur, normal, self.chi2_sim, change);
        let promised_bic = self.delta_bic(chi2_fit - promised, 0);
        if promised_bic.is_nan() || promised_bic >= -self.model.o.bic_threshold {
            return Ok((0.0, None));
        }
        let at = mat.read(params);
        let mut realised = f64::NEG_INFINITY;
        let mut failed = None;
        for t in [1.0, 0.5] {
            let mut q = at.clone();
            for (&col, d) in cols.iter().zip(&delta) {
                q[col] += t * d;
            }
            self.count(1);
            match simulated_phi(seen, mat, params, &q) {
                Ok(phi) => {
                    let chi2 = stepped_chi2(self.cur, normal, self.chi2_sim, phi - normal.phi);
                    realised = realised.max(chi2_fit - chi2);
                }
                // A material the simulation refuses is one no fit reaches: its half is not
                // tried (on the confusion plan's draw 002 the refusal is Newton's at the first
                // step, about a second each).
                Err(e) => {
                    failed = Some(e);
                    break;
                }
            }
            if realised >= POOR_STEP * promised {
                break;
            }
        }
        let realises = match (realised.is_finite(), failed) {
            (true, _) => format!("realises {:.0} % of it", 100.0 * realised / promised),
            (false, Some(e)) => format!("does not simulate ({e})"),
            (false, None) => "realises nothing".into(),
        };
        let unrealised = realised < POOR_STEP * promised || !realised.is_finite();
        let note = format!(
            "the current parameters' own Gauss–Newton step promises ΔBIC {promised_bic:.1} and \
             {realises}{}",
            if unrealised {
                ": each candidate is predicted by its gain beyond that step"
            } else {
                ""
            }
        );
        Ok((if unrealised { promised } else { 0.0 }, Some(note)))
    }

    /// The prediction of a candidate that adds `extra` parameters, whose step over the current
    /// parameters and its own leaves χ² = `chi2` on the fitted steps ([`stepped_chi2`]), made as
    /// `how` says: where the current parameters' own step does not realise, its gain beyond that
    /// step (the unrealised drop added back, no worse than the current fit), and `how` says so.
    pub(in crate::motion) fn predicted(&self, chi2: f64, extra: usize, how: &str) -> Prediction {
        let (chi2, how) = if self.unrealised > 0.0 {
            (
                (chi2 + self.unrealised).min(self.cur.scores.chi2_fit),
                format!(
                    "{how}; its gain beyond the current parameters' own step, which does not \
                     realise"
                ),
            )
        } else {
            (chi2, how.to_string())
        };
        Prediction {
            delta_bic: Some(self.delta_bic(chi2, extra)),
            how,
        }
    }

    /// The current parameters' unrealised drop, for a linearisation of the same round made at
    /// the current model read another way ([`Self::linearised_at`]).
    pub(in crate::motion) fn unrealised(&self) -> f64 {
        self.unrealised
    }

    /// Counts `n` more simulations run for the predictions (a candidate's own scan).
    pub(in crate::motion) fn count(&self, n: usize) {
        self.simulations.set(self.simulations.get() + n);
    }

    /// Keeps the second material's region search for the round's fit.
    pub(in crate::motion) fn keep_region_search(&self, search: RegionSearch) {
        *self.region_search.borrow_mut() = Some(Arc::new(search));
    }

    /// ΔBIC of a model with χ² = `chi2` on the fitted steps and `extra` more parameters than the
    /// current one.
    pub(in crate::motion) fn delta_bic(&self, chi2: f64, extra: usize) -> f64 {
        let s = &self.cur.scores;
        select::heldout_delta_bic(s.chi2_fit, chi2, s.n_fit, extra)
    }

    /// The fitted steps as the current fit sees them ([`as_seen`]), made on first use.
    fn seen(&self) -> Result<&(Model, Observations), MotionDiagnoseError> {
        match self.seen.get() {
            Some(seen) => Ok(seen),
            None => {
                let seen = as_seen(self.model, self.cur)?;
                Ok(self.seen.get_or_init(|| seen))
            }
        }
    }

    /// One simulation with the direct sensitivities of `params` at `mat` on the data as the
    /// current fit sees them, counted among the round's ([`linearise`]).
    pub(in crate::motion) fn linearise(
        &self,
        mat: &Material,
        params: &[Param],
    ) -> Result<(Normal, f64), MotionDiagnoseError> {
        let seen = self.seen()?;
        self.count(1);
        linearise_seen(seen, mat, params)
    }

    /// The prediction of a candidate whose new parameters are `kinds` (columns of the
    /// linearisation) and that adds `extra` parameters: χ² after one Gauss–Newton step over the
    /// current parameters and `kinds`, in proportion to the current fit's χ² (so that the
    /// linearisation's own simulation does not count as a gain).
    pub(in crate::motion) fn linearised(
        &self,
        kinds: &[ParamKind],
        extra: usize,
        how: &str,
    ) -> Prediction {
        let Some(normal) = &self.normal else {
            return Prediction::none("not linearised: always fitted");
        };
        let globals = self.kinds.len();
        let own = self.cur.kinds.len();
        let mut cols: Vec<usize> = (0..own).chain(globals..normal.len()).collect();
        cols.extend(
            kinds
                .iter()
                .filter_map(|k| self.kinds.iter().position(|j| j == k))
                .filter(|i| *i >= own),
        );
        let parts = std::slice::from_ref(normal);
        // A viscosity or a stiffening coefficient cannot go below 0: a step that takes one there
        // is taken again with it held at 0, where the candidate does best.
        let (delta, held) = screen::step_within_bounds(parts, &mut cols, |col| {
            (col >= own && col < globals).then(|| self.kinds[col])
        });
        let how = if held.is_empty() {
            how.to_string()
        } else {
            format!("{how}; {} stepped below 0, held there", held.join(", "))
        };
        if !cols.iter().any(|&c| c >= own && c < globals) {
            return Prediction {
                delta_bic: Some(self.delta_bic(self.cur.scores.chi2_fit, extra)),
                how: screen::held_at_neutral(&how),
            };
        }
        let mut stepped = self.stepped.borrow_mut();
        for (&col, d) in cols.iter().zip(&delta) {
            if col >= own && col < globals && !stepped.iter().any(|(k, _)| *k == self.kinds[col]) {
                stepped.push((self.kinds[col], self.at[col] + d));
            }
        }
        let change = screen::change(parts, &cols, &delta)[0];
        self.predicted(
            stepped_chi2(self.cur, normal, self.chi2_sim, change),
            extra,
            &how,
        )
    }
}

/// One simulation with the direct sensitivities of `params` at `mat`, on the data as the current
/// fit `cur` sees them (its time offset, its marker offsets eliminated in closed form): Φ, its
/// gradient and Gauss–Newton matrix, and the simulation's own χ² (m²).
pub(in crate::motion) fn linearise(
    model: &MotionModel<'_>,
    cur: &FittedModel,
    mat: &Material,
    params: &[Param],
) -> Result<(Normal, f64), MotionDiagnoseError> {
    linearise_seen(&as_seen(model, cur)?, mat, params)
}

/// [`linearise`] on the fitted steps' model and observations `seen` as the current fit sees them
/// ([`as_seen`]).
fn linearise_seen(
    (m, obs): &(Model, Observations),
    mat: &Material,
    params: &[Param],
) -> Result<(Normal, f64), MotionDiagnoseError> {
    let (ev, gn) = evaluate_gauss_newton(m, mat, params, obs)?;
    let chi2_sim = ev.rms_marker * ev.rms_marker * ev.marker_count as f64;
    let normal = Normal {
        phi: ev.phi,
        grad: ev.grad.unwrap_or_default(),
        gn,
    };
    Ok((normal, chi2_sim))
}

/// The share of its promised χ² drop below which the current parameters' own Gauss–Newton step
/// is taken not to be realised ([`Screening::predicted`]): the trust region's ratio for a poor
/// step.
const POOR_STEP: f64 = 0.25;

/// The fitted steps' model and observations as the current fit `cur` sees them: its time
/// offset, its marker offsets eliminated in closed form.
fn as_seen(
    model: &MotionModel<'_>,
    cur: &FittedModel,
) -> Result<(Model, Observations), MotionDiagnoseError> {
    let mut ds = model.ds.clone();
    ds.obs.free_marker_offsets = cur.offsets.is_some();
    let (ds, split) = match cur.time_offset {
        Some(r) => fit::retimed(&ds, model.split, r)?,
        None => (ds, model.split),
    };
    Ok(fit::fitted_part(&ds, split))
}

/// Φ simulated with `params` at `q` on `mat`, on the fitted steps' model and observations `seen`
/// as the current fit sees them ([`as_seen`]): one simulation, no sensitivities.
fn simulated_phi(
    (m, obs): &(Model, Observations),
    mat: &Material,
    params: &[Param],
    q: &[f64],
) -> Result<f64, MotionDiagnoseError> {
    let mut mat = mat.clone();
    mat.set(params, q);
    Ok(evaluate(m, &mat, params, obs, None)?.phi)
}

/// χ² on the fitted steps after a Gauss–Newton step that changes the linearisation's Φ by
/// `change`, in proportion to the current fit's χ² (so that the linearisation's own simulation,
/// whose χ² is `chi2_sim`, does not count as a gain).
pub(in crate::motion) fn stepped_chi2(
    cur: &FittedModel,
    normal: &Normal,
    chi2_sim: f64,
    change: f64,
) -> f64 {
    let scale = if normal.phi > 0.0 {
        chi2_sim / normal.phi
    } else {
        0.0
    };
    let stepped = (chi2_sim + scale * change).max(0.0);
    cur.scores.chi2_fit * stepped / chi2_sim.max(f64::MIN_POSITIVE)
}

/// What a round's screen found besides its predictions, for the round's fits: where the
/// predictions' Gauss–Newton steps took the candidates' new parameters, and the second
/// material's region search.
#[derive(Default)]
pub(in crate::motion) struct Found {
    /// Each stepped parameter's value.
    pub stepped: Vec<(ParamKind, f64)>,
    /// The second material's region search, when the prediction made its map (ranked or not).
    pub region_search: Option<Arc<RegionSearch>>,
}

/// Every open candidate's prediction on top of `cur` (one each, in order), the simulations
/// they took, and what they found for the round's fits.
pub(in crate::motion) fn predict(
    model: &MotionModel<'_>,
    round: usize,
    cur: &FittedModel,
    open: &[Candidate],
) -> Result<(Vec<Prediction>, usize, Found), MotionDiagnoseError> {
    let s = Screening::new(model, cur, open)?;
    if let Some(note) = &s.own_step {
        (model.log)(&format!("round {round}: screen: {note}"));
    }
    let mut out = Vec::with_capacity(open.len());
    for &c in open {
        let p = c.effect().predict(&s)?;
        (model.log)(&format!(
            "round {round}: screen: {} predicted ΔBIC {:.1} ({})",
            c.name(),
            p.delta_bic.unwrap_or(f64::NAN),
            p.how
        ));
        out.push(p);
    }
    let simulations = s.simulations.get();
    let found = Found {
        stepped: s.stepped.into_inner(),
        region_search: s.region_search.into_inner(),
    };
    Ok((out, simulations, found))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::fit::fitted_specimen;
    use crate::motion::MotionOptions;
    use palpate_specimen::motion::MotionEffect;

    /// The simulation that checks the current parameters' own step reads the same Φ as the
    /// linearisation it checks: at the linearisation's own point (a step of length 0) the two
    /// agree, from a simulation without sensitivities and one with them, on the data as the
    /// current fit sees them. A realised share is then a share of the same misfit. They agree to
    /// Newton's tolerance, not to round-off: the simulation without sensitivities keeps its
    /// factorisation across Newton iterations and stops at the same residual by another path
    /// (measured: 4·10⁻⁶ of Φ, a ΔBIC of 0.004; the smallest promise checked is ΔBIC 10).
    #[test]
    fn a_step_of_length_zero_simulates_the_linearisations_misfit() {
        let (ds, split, cur) = fitted_specimen(MotionEffect::Viscosity, 1);
        let o = MotionOptions::default();
        let log = |_: &str| {};
        let m = MotionModel::new(&ds, split, &o, &log);
        let params = fit::params_for(&cur.kinds, &cur.material);
        let (normal, chi2_sim) = linearise(&m, &cur, &cur.material, &params).unwrap();
        let at = cur.material.read(&params);
        let seen = as_seen(&m, &cur).unwrap();
        let phi = simulated_phi(&seen, &cur.material, &params, &at).unwrap();
        assert!(
            (phi / normal.phi - 1.0).abs() < 2e-5,
            "Φ {phi:e} simulated, {:e} linearised",
            normal.phi
        );
        // In ΔBIC, what the screen compares with the gate's threshold of 10: far below it.
        let chi2 = stepped_chi2(&cur, &normal, chi2_sim, phi - normal.phi);
        let s = &cur.scores;
        let bic = select::heldout_delta_bic(s.chi2_fit, chi2, s.n_fit, 0);
        assert!(bic.abs() < 0.05, "ΔBIC {bic}");
    }
}
