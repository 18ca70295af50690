//! A body of two materials: the second material's shear modulus, and its region's shape charged
//! as [`REGION_SHAPE_PARAMS`] more parameters. Where it sits is found first, from the misfit's
//! sensitivity to each element's own μ at the current fit ([`region`]): of the map's level sets,
//! the region whose short fit is best, of the few that one linearisation ranks first
//! ([`region_rank`]); its μ is then fitted, the rest keeps the global μ (λ
//! stays one value: Poisson's ratio differs between the two), and its boundary is refined on
//! adoption ([`refine_boundary`]). A region no thicker than the element layer at a clamp is
//! refused ([`region::at_clamp_layer`]): there a coarse mesh's own error looks like a material.

use palpate_motion::model::{Model, Param, ParamKind};
use rayon::prelude::*;

use super::{Candidate, MotionEffect};
use crate::motion::engine::MotionModel;
use crate::motion::fit::{FittedModel, REGION_SHAPE_PARAMS};
use crate::motion::screen::Screening;
use crate::motion::{region, region_rank, MotionDiagnoseError, MotionOptions, Value};
use crate::select::{Outcome, Prediction};

/// Cuts fitted short after the ranking by one linearisation ([`region_rank`]): the
/// linearisation at the one-material fit ranks a strong contrast's cuts roughly, and the short
/// fits of the few best say which is best. Over the 80 region searches of 48 drawn bars
/// (`palpate-lab motion-confusion --draws 8`) the best of four short fits was the first ranked
/// cut in 73, the second in 4, the third in 3; on the bar whose near half is three times as
/// stiff (`diagnose_motion::a_bar_of_two_materials_is_given_its_second_material`) the truth's
/// cut is ranked third, its prediction within 1.3 % of the second's, and two short fits miss it.
const RANKED_SHORT_FITS: usize = 4;

/// Refits that move the region's boundary on adoption ([`refine_boundary`]).
const REGION_REFITS: usize = 4;

/// See the module.
pub struct TwoMaterial;

impl MotionEffect for TwoMaterial {
    fn name(&self) -> &'static str {
        "two-material"
    }

    fn extra_params(&self, _markers: usize) -> usize {
        1 + REGION_SHAPE_PARAMS
    }

    /// One region effect at a time ([`super::clamp_compliance`]).
    fn conflicts(&self, other: Candidate) -> bool {
        other == Candidate::ClampCompliance
    }

    fn fit(
        &self,
        m: &MotionModel<'_>,
        c: Candidate,
        cur: &FittedModel,
    ) -> Result<Outcome<FittedModel>, MotionDiagnoseError> {
        fit_two_material(m, c, cur)
    }

    /// The best ranked level set's prediction ([`region_rank`]): one Gauss–Newton step over
    /// the current parameters and a second material on each of the map's cuts, the best one's
    /// χ² charged the region's parameters. The best of many cuts is an optimistic prediction,
    /// which a screen can afford: it fits the candidate where the best cut promises a gain.
    /// The search it ran is kept for the round's fit ([`MotionModel::region_search`]). Where
    /// the cuts are not ranked (a region is already adopted, or μ is not fitted) the short fits
    /// are the search: always fitted.
    fn predict(&self, s: &Screening<'_, '_>) -> Result<Prediction, MotionDiagnoseError> {
        let extra = self.extra_params(0);
        let located = search(s.model, s.cur);
        // The map's simulation with its adjoint when it was made, and the ranking's.
        s.count(match &located {
            Located::Failed(_) => 0,
            Located::Nothing(_) => 1,
            Located::Found(r) => 1 + usize::from(r.ranked.is_ok()),
        });
        let found = match located {
            Located::Nothing(why) => {
                return Ok(Prediction {
                    delta_bic: Some(s.delta_bic(s.cur.scores.chi2_fit, extra)),
                    how: why,
                })
            }
            Located::Failed(why) => return Ok(Prediction::none(&why)),
            Located::Found(found) => found,
        };
        let prediction = match &found.ranked {
            Ok(ranked) => match ranked.first() {
                Some(&(cut, chi2)) => s.predicted(
                    chi2,
                    extra,
                    &format!(
                        "one Gauss–Newton step with a second material on the best of {} level \
                         sets of the sensitivity map (cut {cut})",
                        ranked.len()
                    ),
                ),
                None => Prediction::none("no cut ranked: always fitted"),
            },
            Err(why) => Prediction::none(&format!(
                "{why}: its region is searched by short fits of its own, always fitted"
            )),
        };
        s.keep_region_search(found);
        Ok(prediction)
    }

    fn adopt(&self, m: &MotionModel<'_>, gated: FittedModel) -> FittedModel {
        refine_boundary(m, gated)
    }

    /// The shear modulus of each second material's region, named with where the region is (a
    /// clamp layer is the clamp's give, [`super::clamp_compliance`]).
    fn values(&self, fitted: &FittedModel, model: &Model) -> Vec<Value> {
        let first = fitted.values.len() - fitted.material.regions.len();
        let mu_rest = fitted.material.read(&[Param::global(ParamKind::Mu)])[0];
        fitted
            .material
            .regions
            .iter()
            .enumerate()
            .filter(|&(r, _)| !super::clamp_compliance::is_layer(&fitted.material, r))
            .map(|(r, elements)| Value {
                name: format!(
                    "mu of the second material ({})",
                    region::describe(model, elements, fitted.values[first + r] > mu_rest)
                ),
                value: fitted.values[first + r],
                sigma: fitted.sigma.as_ref().map(|s| s[first + r]),
            })
            .collect()
    }
}

/// The second material's candidate regions at a current fit: the sensitivity map's level sets
/// ([`region::locate`]) and, where one linearisation ranks them ([`region_rank`]), every cut
/// the coarse-then-fine scan could reach in the order of its predicted χ². Made by the round's
/// screen for its prediction and read by the round's fit ([`MotionModel::region_search`]).
#[derive(Debug)]
pub(in crate::motion) struct RegionSearch {
    /// The map's level sets.
    family: region::Family,
    /// Cuts, best predicted first, each with its predicted χ² on the fitted steps (m²); or why
    /// the linearisation does not rank them (the short fits then search them).
    ranked: Result<Vec<(usize, f64)>, String>,
}

/// What the search for a second material's region found at a current fit.
enum Located {
    /// No region to place, and why.
    Nothing(String),
    /// The map could not be made, and why.
    Failed(String),
    /// The map's level sets.
    Found(RegionSearch),
}

/// The search at `cur`: the map's level sets ([`region::locate`]), and their cuts ranked by one
/// linearisation ([`region_rank`]) where that applies.
fn search(m: &MotionModel<'_>, cur: &FittedModel) -> Located {
    let family = match region::locate(m.ds, m.split, cur) {
        Ok(Some(f)) => f,
        Ok(None) => {
            return Located::Nothing(
                "the misfit's sensitivity to each element's μ has one sign everywhere: no \
                 second material to place"
                    .into(),
            )
        }
        Err(e) => return Located::Failed(format!("locating it failed: {e}")),
    };
    let coarse = family.coarse();
    if coarse.is_empty() {
        return Located::Nothing(format!(
            "no level set of the sensitivity map leaves a region of at least {} elements and \
             {:.0} % of the volume on both sides",
            region::MIN_REGION_ELEMENTS,
            100.0 * region::MIN_REGION_VOLUME
        ));
    }
    let mut cuts: Vec<usize> = coarse
        .iter()
        .flat_map(|&k| family.between(&coarse, k, region::FINE_LEVELS))
        .chain(coarse.iter().copied())
        .collect();
    cuts.sort_unstable();
    cuts.dedup();
    let ranked = match region_rank::predicted_chi2(m, cur, &family, &cuts) {
        Ok(Some(chi2)) => {
            let mut ranked: Vec<(usize, f64)> = cuts.into_iter().zip(chi2).collect();
            ranked.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
            Ok(ranked)
        }
        Ok(None) => Err("the cuts are not ranked with a region adopted or μ held".to_string()),
        Err(e) => Err(format!("ranking the cuts failed ({e})")),
    };
    Located::Found(RegionSearch { family, ranked })
}

/// Where first: the round's [`RegionSearch`], or the search made here ([`search`]); the
/// [`RANKED_SHORT_FITS`] best ranked cuts fitted beside the global parameters from the current
/// model for [`region::SCREEN_ITERS`] iterations; the region whose short fit has the lowest χ²
/// on the fitted steps is fitted in full. Where the ranking does not apply (a region already
/// adopted) every coarse cut is fitted short, then the cuts between the best one's neighbours.
/// The held-out steps choose nothing.
fn fit_two_material(
    m: &MotionModel<'_>,
    c: Candidate,
    cur: &FittedModel,
) -> Result<Outcome<FittedModel>, MotionDiagnoseError> {
    let made;
    let found = match &m.region_search {
        Some(kept) => kept.as_ref(),
        None => {
            made = search(m, cur);
            match &made {
                Located::Nothing(why) | Located::Failed(why) => {
                    return Ok(Outcome::NotFitted(why.clone()))
                }
                Located::Found(found) => found,
            }
        }
    };
    let family = &found.family;
    // Each region starts at the current μ: the fit starts from the current model (its χ²),
    // where the map says which way the region's μ goes, and can only improve on it. (A start
    // 1.5× off that way, and a 5 × 5 grid of starting contrasts with the rest's λ moving with
    // its μ, were tried: the first ended worse than the current model on the independent
    // cylinder with marker offsets adopted, the second never beat the one-material point on
    // the two-material test bar — neither kept. Starts 2× and 4× off on the random bars
    // ended where the current μ's start did: the region, not the start, was what was wrong.)
    let mu = cur.material.read(&[Param::global(ParamKind::Mu)])[0];
    let screen = MotionOptions {
        max_iters: m.o.screen_iters.min(region::SCREEN_ITERS),
        ..m.o.clone()
    };
    let screener = m.with_options(&screen);
    let mut best: Option<(FittedModel, usize)> = None;
    let (mut screened, mut evaluations) = (0, 0);
    let mut failures = Vec::new();
    // The screens are independent fits: one per core.
    let mut scan = |cuts: &[usize], best: &mut Option<(FittedModel, usize)>| {
        let fits: Vec<(usize, Result<FittedModel, MotionDiagnoseError>)> = cuts
            .par_iter()
            .map(|&k| {
                let mut start = cur.clone();
                start.material.regions.push(family.region(k).elements);
                start.values.push(mu);
                (k, screener.fit_from(&start, c))
            })
            .collect();
        for (k, fit) in fits {
            screened += 1;
            match fit {
                Ok(f) => {
                    log::debug!(
                        "two-material: cut {k}: short fit χ² {:.6e} m² ({} evaluations)",
                        f.scores.chi2_fit,
                        f.evaluations
                    );
                    evaluations += f.evaluations;
                    if best
                        .as_ref()
                        .is_none_or(|(b, _)| f.scores.chi2_fit < b.scores.chi2_fit)
                    {
                        *best = Some((f, k));
                    }
                }
                Err(e) => failures.push(format!("cut {k}: {e}")),
            }
        }
    };
    // The level sets the search chose among: every ranked cut, or every cut fitted short.
    let offered = match &found.ranked {
        Ok(ranked) => {
            for (rank, (k, chi2)) in ranked.iter().enumerate() {
                log::debug!("two-material: rank {rank}: cut {k}: predicted χ² {chi2:.6e} m²");
            }
            let top: Vec<usize> = ranked.iter().take(RANKED_SHORT_FITS).map(|r| r.0).collect();
            scan(&top, &mut best);
            ranked.len()
        }
        Err(why) => {
            (m.log)(&format!("  two-material: {why}; every cut is fitted short"));
            let coarse = family.coarse();
            scan(&coarse, &mut best);
            if let Some(k) = best.as_ref().map(|b| b.1) {
                scan(&family.between(&coarse, k, region::FINE_LEVELS), &mut best);
            }
            screened
        }
    };
    let Some((start, k)) = best else {
        return Ok(Outcome::NotFitted(format!(
            "fit failed on all {screened} candidate regions: {}",
            failures.join("; ")
        )));
    };
    let region = family.region(k);
    // The best region is judged where it sits, not replaced by the best of the rest: a clamp's
    // element layer that fits better than every region elsewhere says the misfit the map sees
    // is the mesh's at the boundary, which a region elsewhere would only absorb in part.
    if let Some(why) = region::at_clamp_layer(&m.ds.model, &region.elements) {
        (m.log)(&format!(
            "  two-material: the best of {screened} short fits of {offered} level sets of the \
             sensitivity map is refused: {why}"
        ));
        return Ok(Outcome::NotFitted(format!("refused: {why}")));
    }
    (m.log)(&format!(
        "  two-material: region of {} (the best of {screened} short fits of {offered} level sets \
         of the sensitivity map)",
        region::describe(&m.ds.model, &region.elements, region.stiffer),
    ));
    let mut best = match m.fit_from(&start, c) {
        Ok(f) => f,
        Err(e) => return Ok(Outcome::NotFitted(format!("fit failed: {e}"))),
    };
    // The short fits' evaluations (the search's own simulations are the screen's, or the
    // ranking's one when it ran here).
    let ranked_here = m.region_search.is_none() && found.ranked.is_ok();
    best.evaluations += evaluations + usize::from(ranked_here);
    Ok(Outcome::Fitted(best))
}

/// The adopted two-material model with its region's boundary moved while that lowers the
/// fitted misfit: the elements whose switch of material lowers Φ to first order
/// ([`region::switches`]) — all of them, else the better half, quarter, … (a first-order
/// estimate overshoots when many move at once) —, refitted and kept only if χ² on the fitted
/// steps fell; at most [`REGION_REFITS`] refits. Done on adoption only: each refit is a
/// whole fit, and a candidate that does not pass the gate with its located region is not
/// refined into passing.
fn refine_boundary(m: &MotionModel<'_>, gated: FittedModel) -> FittedModel {
    let c = Candidate::TwoMaterial;
    let mut best = gated.clone();
    let volumes: Vec<f64> = m.ds.model.rest.iter().map(|r| r.volume).collect();
    let mut refits = 0;
    'passes: while refits < REGION_REFITS {
        let grad = match region::sensitivity(m.ds, m.split, &best) {
            Ok(g) => g,
            Err(e) => {
                (m.log)(&format!("  two-material: boundary: {e}; region kept"));
                break;
            }
        };
        let mu_in = best.values[best.values.len() - 1];
        let mu_out = best.material.read(&[Param::global(ParamKind::Mu)])[0];
        let region = best.material.regions[0].clone();
        let moves = region::switches(&region, &grad, mu_in, mu_out);
        let mut k = moves.len();
        while k > 0 && refits < REGION_REFITS {
            let Some(next) = region::switched(&region, &moves[..k], &volumes)
                .filter(|next| region::at_clamp_layer(&m.ds.model, next).is_none())
            else {
                k /= 2;
                continue;
            };
            refits += 1;
            let mut start = best.clone();
            start.material.regions[0] = next;
            if let Ok(mut f) = m.fit_from(&start, c) {
                if f.scores.chi2_fit < best.scores.chi2_fit {
                    (m.log)(&format!(
                        "  two-material: boundary: {k} element(s) switched, region of {} \
                         elements, fitted RMS {:.1} → {:.1} µm",
                        f.material.regions[0].len(),
                        1e6 * best.scores.rms_fit,
                        1e6 * f.scores.rms_fit
                    ));
                    f.evaluations += best.evaluations;
                    best = f;
                    continue 'passes;
                }
            }
            k /= 2;
        }
        break;
    }
    if best.material.regions != gated.material.regions {
        (m.log)(&format!(
            "  two-material: boundary refined on adoption: region of {} elements, RMS \
             {:.1}/{:.1} → {:.1}/{:.1} µm fitted/held out",
            best.material.regions[0].len(),
            1e6 * gated.scores.rms_fit,
            1e6 * gated.scores.rms_held,
            1e6 * best.scores.rms_fit,
            1e6 * best.scores.rms_held
        ));
    }
    best
}
