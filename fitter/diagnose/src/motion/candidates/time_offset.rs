//! The markers are recorded out of step with the clamps' record (1 parameter: an integer number
//! of simulation steps, [`palpate_motion::time_offset`]): two capture streams on two clocks, or a
//! start instant misread. Scanned on the fitted steps within ±3 capture frames (widened to ±12
//! while the best lies at the edge) with the current material, the material refitted where one
//! Gauss–Newton step predicts the scan's offset or a neighbour best ([`refit_first`]), scanned
//! again (refitted once more if it moved), then the neighbouring offsets refitted while χ² falls
//! and one Gauss–Newton step there predicts it to (a scan at 0 has both ±1 predicted and fitted,
//! [`fit_step_off`]); the held-out steps are forecast at the same offset.

use palpate_motion::dataset::MotionDataset;
use palpate_motion::model::{Material, ParamKind};
use palpate_motion::time_offset;
use rayon::prelude::*;

use super::{Candidate, MotionEffect};
use crate::motion::engine::MotionModel;
use crate::motion::fit::{self, with_offsets, FittedModel};
use crate::motion::screen::{self, Screening};
use crate::motion::{MotionDiagnoseError, MotionOptions, Value};
use crate::select::{Outcome, Prediction};

/// Steps the candidate moves from its scanned offset, each way, while a refit there lowers χ²
/// ([`fit_timed`]).
const OFFSET_NEIGHBOURS: usize = 3;

/// See the module.
pub struct TimeOffset;

impl MotionEffect for TimeOffset {
    fn name(&self) -> &'static str {
        "time-offset"
    }

    fn extra_params(&self, _markers: usize) -> usize {
        1
    }

    /// With a time offset every fit runs on the data re-timed to the simulation's clock and is
    /// read back on the data's own rows.
    fn fit(
        &self,
        m: &MotionModel<'_>,
        c: Candidate,
        cur: &FittedModel,
    ) -> Result<Outcome<FittedModel>, MotionDiagnoseError> {
        let (r, tried) = match scan(m.ds, m.split, &cur.material, cur.offsets.as_deref()) {
            Ok(t) => t,
            Err(e) => return Ok(Outcome::NotFitted(format!("scan failed: {e}"))),
        };
        if r == 0 {
            return fit_step_off(m, c, cur, &tried);
        }
        let (r, predictions) = refit_first(m, cur, r, &tried);
        Ok(match fit_timed(m, c, cur, r) {
            Ok(mut f) => {
                f.evaluations += predictions;
                Outcome::Fitted(f)
            }
            Err(e) => Outcome::NotFitted(format!("fit failed: {e}")),
        })
    }

    /// By its scan at the current material, χ² in proportion to the scan's own at offset 0 (the
    /// material not refitted). A scan at 0 is not predicted here: the fit then predicts a step
    /// either way with the material refitted by one Gauss–Newton step ([`fit_step_off`]), which
    /// the scan at the current material cannot see.
    fn predict(&self, s: &Screening<'_, '_>) -> Result<Prediction, MotionDiagnoseError> {
        let m = s.model;
        let (best, tried) = match scan(m.ds, m.split, &s.cur.material, s.cur.offsets.as_deref()) {
            Ok(t) => t,
            Err(e) => return Ok(Prediction::none(&format!("scan failed: {e}"))),
        };
        s.count(1);
        let at = |o: i64| tried.iter().find(|t| t.0 == o).map(|t| t.1);
        match (best, at(best), at(0)) {
            (0, ..) => Ok(Prediction::none(
                "the scan says 0: a step either way is predicted by a Gauss–Newton step of the \
                 material there, and fitted where that promises a better fit",
            )),
            (_, Some(b), Some(z)) if z > 0.0 => Ok(Prediction {
                delta_bic: Some(s.delta_bic(s.cur.scores.chi2_fit * b / z, 1)),
                how: format!(
                    "the offset scanned ({:+.1} ms), the material not refitted",
                    1e3 * best as f64 * m.ds.model.dt
                ),
            }),
            _ => Ok(Prediction::none("the scan has no χ² at 0")),
        }
    }

    /// The offset in seconds (from steps of `dt`), when the model has one.
    fn values(&self, fitted: &FittedModel, model: &palpate_motion::model::Model) -> Vec<Value> {
        fitted
            .time_offset
            .map(|r| Value {
                name: "time offset of the markers (s)".into(),
                value: r as f64 * model.dt,
                sigma: None,
            })
            .into_iter()
            .collect()
    }
}

/// The time offset of the fitted steps under `mat` with the marker offsets `offsets`, scanned
/// ([`time_offset::scan`]; the held-out steps are a forecast and take no part).
pub(in crate::motion) fn scan_offset(
    m: &MotionModel<'_>,
    mat: &Material,
    offsets: Option<&[[f64; 3]]>,
) -> Result<i64, MotionDiagnoseError> {
    Ok(scan(m.ds, m.split, mat, offsets)?.0)
}

/// [`scan_offset`] with every offset tried and its χ² on the fitted steps.
pub(in crate::motion) fn scan(
    ds: &MotionDataset,
    split: fit::Split,
    mat: &Material,
    offsets: Option<&[[f64; 3]]>,
) -> Result<(i64, Vec<(i64, f64)>), MotionDiagnoseError> {
    let ds = offsets.map_or_else(|| ds.clone(), |o| with_offsets(ds, o));
    let (model, obs) = fit::fitted_part(&ds, split);
    Ok(time_offset::scan(&model, mat, &obs)?)
}

/// Where the candidate is fitted first: of the scanned offset `r` and its two neighbours, the one
/// one Gauss–Newton step of the current parameters there predicts the lowest χ² for (the scan's
/// χ² at the current material times the step's relative gain, [`refit_gain`]; the three steps
/// side by side). The scan runs at a material fitted without the offset, which has absorbed
/// part of one, and its best offset is then a step short of where the refitted material puts
/// it; a neighbour whose prediction fails, or that the scan did not try, is not chosen.
/// Returns the offset and the simulations the predictions took.
fn refit_first(
    m: &MotionModel<'_>,
    cur: &FittedModel,
    r: i64,
    tried: &[(i64, f64)],
) -> (i64, usize) {
    let at = |o: i64| tried.iter().find(|t| t.0 == o).map(|t| t.1);
    let scanned: Vec<(i64, f64)> = [r - 1, r, r + 1]
        .into_iter()
        .filter_map(|o| Some((o, at(o)?)))
        .collect();
    let predicted: Vec<(i64, f64)> = scanned
        .par_iter()
        .filter_map(|&(o, chi2)| Some((o, chi2 * refit_gain(m, cur, o).ok()?)))
        .collect();
    let best = predicted
        .iter()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map_or(r, |p| p.0);
    if best != r {
        (m.log)(&format!(
            "  time-offset: one Gauss–Newton step of the material predicts {:+.1} ms better than \
             the scan's {:+.1} ms: fitted there first",
            1e3 * best as f64 * m.ds.model.dt,
            1e3 * r as f64 * m.ds.model.dt
        ));
    }
    (best, scanned.len())
}

/// The candidate fitted at the scanned time offset `r`: the fit on the re-timed data, its
/// trajectory and scores read back on the data's rows; the offset is scanned again with the
/// refitted material and, if it moved, the material refitted once more; then the neighbouring
/// offsets are refitted while that lowers χ² on the fitted steps (at most [`OFFSET_NEIGHBOURS`]
/// steps each way): the scan runs at a material fitted without the offset, and on a strongly
/// loaded run it can settle a step off (−2 for −3 on drawn specimens, the fit then far above the
/// floor). Each offset is fitted once, and a neighbour only where one Gauss–Newton step of the
/// best fit's parameters there predicts a lower χ² than the best's ([`predicted_refit`]): on the
/// independent generator's cylinder recorded two frames late, fitting the walk's last, worse,
/// neighbour in full takes 25 simulations with sensitivities; predicting it, one.
fn fit_timed(
    m: &MotionModel<'_>,
    c: Candidate,
    cur: &FittedModel,
    mut r: i64,
) -> Result<FittedModel, MotionDiagnoseError> {
    let kinds: &[ParamKind] = &cur.kinds;
    let mut evaluations = 0;
    // Every fit starts from `cur`, so an offset fitted once is not fitted again: the first
    // scan's offset, which a rescan moved by a step, is the new offset's neighbour.
    let mut fits: Vec<FittedModel> = Vec::new();
    let fit_at = |fits: &mut Vec<FittedModel>,
                  r: i64,
                  evaluations: &mut usize|
     -> Result<FittedModel, MotionDiagnoseError> {
        if let Some(f) = fits.iter().find(|f| f.time_offset == Some(r)) {
            return Ok(f.clone());
        }
        let f = m.fit_at(cur, c, kinds, r, evaluations)?;
        fits.push(f.clone());
        Ok(f)
    };
    let mut rescanned = false;
    let mut best = loop {
        let f = fit_at(&mut fits, r, &mut evaluations)?;
        if rescanned {
            break f;
        }
        let again = scan_offset(m, &f.material, f.offsets.as_deref())?;
        if again == r {
            break f;
        }
        (r, rescanned) = (again, true);
    };
    for dir in [-1, 1] {
        for _ in 0..OFFSET_NEIGHBOURS {
            let next = best.time_offset.unwrap_or(r) + dir;
            // A neighbour not fitted yet is fitted only where one Gauss–Newton step of the best
            // fit's parameters there, from one simulation with sensitivities, predicts a lower
            // χ² than the best's (as `fit_step_off` judges the steps off a scan at 0).
            if !fits.iter().any(|f| f.time_offset == Some(next)) {
                evaluations += 1;
                match predicted_refit(m, &best, next) {
                    Ok(chi2) if chi2 >= best.scores.chi2_fit => {
                        (m.log)(&format!(
                            "  time-offset: one Gauss–Newton step at {:+.1} ms predicts χ² \
                             {:.4}× the fit's at {:+.1} ms: not fitted",
                            1e3 * next as f64 * m.ds.model.dt,
                            chi2 / best.scores.chi2_fit,
                            1e3 * best.time_offset.unwrap_or(r) as f64 * m.ds.model.dt,
                        ));
                        break;
                    }
                    _ => {}
                }
            }
            match fit_at(&mut fits, next, &mut evaluations) {
                Ok(n) if n.scores.chi2_fit < best.scores.chi2_fit => best = n,
                _ => break,
            }
        }
    }
    best.evaluations = evaluations;
    Ok(best)
}

/// χ² on the fitted steps after one Gauss–Newton step of `from`'s parameters with the markers
/// `r` steps off the clamps' record ([`refit_step`]): the χ² of `from` there times the step's
/// relative gain.
fn predicted_refit(
    m: &MotionModel<'_>,
    from: &FittedModel,
    r: i64,
) -> Result<f64, MotionDiagnoseError> {
    let (chi2, gain) = refit_step(m, from, r)?;
    Ok(chi2 * gain)
}

/// The time offset when the scan says 0. The scan runs at a material fitted without an
/// offset, which has absorbed part of one: a step off is what it can miss (random bars: 2 of
/// 8 draws with ±1 step were scanned to 0 and another effect adopted, 25–34× the floor).
/// First one Gauss–Newton step of the material at each neighbour, from one simulation with
/// sensitivities there ([`refit_gain`]), predicts the neighbour's refit: χ² the scan's at that
/// offset times the step's relative gain. A neighbour predicted no better than offset 0 is not
/// fitted. The others are fitted for [`MotionOptions::screen_iters`] iterations; the better, if
/// it lowers χ² on the fitted steps below the current model's, is fitted in full and its own
/// neighbours that way while χ² falls ([`fit_timed`]), and gated as any other fit.
fn fit_step_off(
    m: &MotionModel<'_>,
    c: Candidate,
    cur: &FittedModel,
    tried: &[(i64, f64)],
) -> Result<Outcome<FittedModel>, MotionDiagnoseError> {
    let at = |o: i64| tried.iter().find(|t| t.0 == o).map(|t| t.1);
    let predicted: Vec<(i64, Option<f64>)> = [-1i64, 1]
        .par_iter()
        .map(|&r| {
            let relative = match (refit_gain(m, cur, r), at(r), at(0)) {
                (Ok(gain), Some(chi2), Some(zero)) if zero > 0.0 => Some(chi2 * gain / zero),
                _ => None,
            };
            (r, relative)
        })
        .collect();
    let mut evaluations = predicted.len();
    for &(r, rel) in &predicted {
        if let Some(rel) = rel {
            (m.log)(&format!(
                "  time-offset: one Gauss–Newton step of the material at {:+.1} ms predicts χ² \
                 {:.4}× offset 0's",
                1e3 * r as f64 * m.ds.model.dt,
                rel
            ));
        }
    }
    // An offset whose prediction failed is fitted, as one predicted better.
    let open: Vec<i64> = predicted
        .iter()
        .filter(|p| p.1.is_none_or(|rel| rel < 1.0))
        .map(|p| p.0)
        .collect();
    if open.is_empty() {
        return Ok(Outcome::NotFitted(
            "the scan puts the markers in step with the simulation (offset 0), and one \
             Gauss–Newton step of the material a step either way predicts no better fit"
                .into(),
        ));
    }
    let screen = MotionOptions {
        max_iters: m.o.screen_iters,
        ..m.o.clone()
    };
    let screener = m.with_options(&screen);
    // The open neighbours are independent fits: one per core.
    let fits: Vec<(i64, usize, Option<FittedModel>)> = open
        .par_iter()
        .map(|&r| {
            let mut evaluations = 0;
            let f = screener.fit_at(cur, c, &cur.kinds, r, &mut evaluations);
            (r, evaluations, f.ok())
        })
        .collect();
    evaluations += fits.iter().map(|f| f.1).sum::<usize>();
    let mut best: Option<(FittedModel, i64)> = None;
    for (r, _, f) in fits {
        if let Some(f) = f {
            if best
                .as_ref()
                .is_none_or(|(b, _)| f.scores.chi2_fit < b.scores.chi2_fit)
            {
                best = Some((f, r));
            }
        }
    }
    let r = match best {
        Some((f, r)) if f.scores.chi2_fit < cur.scores.chi2_fit => r,
        _ => {
            return Ok(Outcome::NotFitted(
                "the scan puts the markers in step with the simulation (offset 0), and a \
                 step either way fits no better"
                    .into(),
            ))
        }
    };
    Ok(match fit_timed(m, c, cur, r) {
        Ok(mut f) => {
            f.evaluations += evaluations;
            Outcome::Fitted(f)
        }
        Err(e) => Outcome::NotFitted(format!("fit failed: {e}")),
    })
}

/// The relative χ² gain of one Gauss–Newton step of the current parameters with the markers
/// `r` steps off the clamps' record: (χ² after the step) / (χ² before) ([`refit_step`]).
fn refit_gain(m: &MotionModel<'_>, cur: &FittedModel, r: i64) -> Result<f64, MotionDiagnoseError> {
    Ok(refit_step(m, cur, r)?.1)
}

/// One Gauss–Newton step of `from`'s parameters with the markers `r` steps off the clamps'
/// record, from one simulation with sensitivities at `from`'s material on the data re-timed by
/// `r`: χ² on the fitted steps there before the step, and (χ² after) / (χ² before) — 1 where
/// the misfit is already 0.
fn refit_step(
    m: &MotionModel<'_>,
    from: &FittedModel,
    r: i64,
) -> Result<(f64, f64), MotionDiagnoseError> {
    let mut at = from.clone();
    at.time_offset = Some(r);
    let params = fit::params_for(&from.kinds, &from.material);
    let (normal, chi2) = screen::linearise(m, &at, &from.material, &params)?;
    if normal.phi <= 0.0 {
        return Ok((chi2, 1.0));
    }
    let cols: Vec<usize> = (0..normal.len()).collect();
    let parts = std::slice::from_ref(&normal);
    let delta = crate::screen::step(parts, &cols);
    let change = crate::screen::change(parts, &cols, &delta)[0];
    Ok((chi2, ((normal.phi + change) / normal.phi).max(0.0)))
}
