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

use std::cell::Cell;
use std::sync::Arc;

use palpate_motion::gradient::evaluate_gauss_newton;
use palpate_motion::model::{Material, Param, ParamKind};

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
    /// Simulations run for the round's predictions.
    simulations: Cell<usize>,
    /// The second material's region search the prediction ran, for the round's fit.
    region_search: std::cell::RefCell<Option<Arc<RegionSearch>>>,
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
            simulations: Cell::new(0),
            region_search: Default::default(),
        };
        if screening.kinds.len() == cur.kinds.len() {
            return Ok(screening);
        }
        let params = fit::params_for(&screening.kinds, &mat);
        let (normal, chi2_sim) = linearise(model, cur, &mat, &params)?;
        screening.count(1);
        screening.chi2_sim = chi2_sim;
        screening.normal = Some(normal);
        Ok(screening)
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
        let chi2 = stepped_chi2(self.cur, normal, self.chi2_sim, change);
        Prediction {
            delta_bic: Some(self.delta_bic(chi2, extra)),
            how,
        }
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
    let mut ds = model.ds.clone();
    ds.obs.free_marker_offsets = cur.offsets.is_some();
    let (ds, split) = match cur.time_offset {
        Some(r) => fit::retimed(&ds, model.split, r)?,
        None => (ds, model.split),
    };
    let (m, obs) = fit::fitted_part(&ds, split);
    let (ev, gn) = evaluate_gauss_newton(&m, mat, params, &obs)?;
    let chi2_sim = ev.rms_marker * ev.rms_marker * ev.marker_count as f64;
    let normal = Normal {
        phi: ev.phi,
        grad: ev.grad.unwrap_or_default(),
        gn,
    };
    Ok((normal, chi2_sim))
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
