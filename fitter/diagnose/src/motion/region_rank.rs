//! A second material's candidate regions ranked by one linearisation: the score test of the fit
//! screen ([`super::screen`]), cut by cut.
//!
//! Every cut of the sensitivity map's level sets ([`Family`]) splits the body's elements, in
//! the map's order, into two sides, so the bands between consecutive cuts span every candidate
//! region: a cut's region μ moves the bands on one side, the rest's μ the bands on the other.
//! One simulation with the direct sensitivities of the current parameters (the global μ
//! excepted) and of each band's own μ — every band at the current μ, so the model is the current
//! one — gives Φ's gradient and Gauss–Newton matrix over them. Folded onto a cut's two sides
//! ([`Normal::combine`]), one Gauss–Newton step over the current parameters and the two μ
//! predicts the χ² of that cut's fit. The short fits that place the region then run on the best
//! predicted cuts only, instead of on every cut.

use palpate_motion::model::{Param, ParamKind};

use super::engine::MotionModel;
use super::fit::FittedModel;
use super::region::Family;
use super::screen::{linearise, stepped_chi2};
use super::MotionDiagnoseError;
use crate::screen;

/// The χ² on the fitted steps after one Gauss–Newton step from `cur` with a second material on
/// each of `cuts` (in their order), from one simulation; `None` where the ranking does not
/// apply: the current model already has a region (a band would cut across it), or its μ is not
/// fitted (the rest's μ would not move).
pub(in crate::motion) fn predicted_chi2(
    m: &MotionModel<'_>,
    cur: &FittedModel,
    family: &Family,
    cuts: &[usize],
) -> Result<Option<Vec<f64>>, MotionDiagnoseError> {
    if !cur.material.regions.is_empty() || !cur.kinds.contains(&ParamKind::Mu) {
        return Ok(None);
    }
    let mut bounds: Vec<usize> = cuts.to_vec();
    bounds.extend([0, family.len()]);
    bounds.sort_unstable();
    bounds.dedup();
    let mut mat = cur.material.clone();
    mat.regions = bounds.windows(2).map(|w| family.band(w[0], w[1])).collect();
    let others: Vec<ParamKind> = cur
        .kinds
        .iter()
        .copied()
        .filter(|&k| k != ParamKind::Mu)
        .collect();
    let bands = mat.regions.len();
    let mut params = Param::globals(&others);
    params.extend((0..bands).map(|b| Param::in_region(ParamKind::Mu, b)));
    let (normal, chi2_sim) = linearise(m, cur, &mat, &params)?;
    let n = params.len();
    let no = others.len();
    let predicted = cuts
        .iter()
        .map(|&cut| {
            // Band b lies below the cut when its upper bound is at or below it.
            let below = bounds.iter().skip(1).take_while(|&&hi| hi <= cut).count();
            let mut t: Vec<Vec<f64>> = (0..no)
                .map(|k| {
                    let mut col = vec![0.0; n];
                    col[k] = 1.0;
                    col
                })
                .collect();
            let side = |range: std::ops::Range<usize>| {
                let mut col = vec![0.0; n];
                range.for_each(|b| col[no + b] = 1.0);
                col
            };
            t.push(side(0..below));
            t.push(side(below..bands));
            let folded = [normal.combine(&t)];
            let cols: Vec<usize> = (0..t.len()).collect();
            let delta = screen::step(&folded, &cols);
            let change = screen::change(&folded, &cols, &delta)[0];
            stepped_chi2(cur, &normal, chi2_sim, change)
        })
        .collect();
    Ok(Some(predicted))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::fit::fitted_specimen;
    use crate::motion::region::locate;
    use crate::motion::MotionOptions;
    use palpate_specimen::motion::MotionEffect;

    /// The prediction of a cut folded from the bands is the one the cut's own region gives:
    /// the one-material fit of a drawn two-material bar, linearised once with every band's μ
    /// and once with the cut's region alone (its μ and the rest's), each followed by one
    /// Gauss–Newton step. The two simulations are different (70-odd parameters against four),
    /// so the agreement checks the folding, not a shared computation.
    #[test]
    fn a_cut_folded_from_the_bands_is_predicted_as_its_own_region() {
        let (ds, split, cur) = fitted_specimen(MotionEffect::TwoMaterial, 2);
        let kinds = cur.kinds.clone();
        let family = locate(&ds, split, &cur)
            .unwrap()
            .expect("a map of two signs");
        let o = MotionOptions::default();
        let log = |_: &str| {};
        let m = MotionModel::new(&ds, split, &o, &log);
        let cuts = family.coarse();
        assert!(cuts.len() >= 3, "{cuts:?}");
        let folded = predicted_chi2(&m, &cur, &family, &cuts).unwrap().unwrap();
        for (&cut, &chi2) in cuts.iter().zip(&folded) {
            // The cut's region on its own: λ, the rest's μ and the region's μ.
            let mut one = cur.material.clone();
            one.regions = vec![family.band(0, cut)];
            let mut params = Param::globals(&kinds);
            params.push(Param::in_region(ParamKind::Mu, 0));
            let (normal, chi2_sim) = linearise(&m, &cur, &one, &params).unwrap();
            let cols: Vec<usize> = (0..params.len()).collect();
            let parts = std::slice::from_ref(&normal);
            let delta = screen::step(parts, &cols);
            let change = screen::change(parts, &cols, &delta)[0];
            let own = stepped_chi2(&cur, &normal, chi2_sim, change);
            assert!(
                (chi2 / own - 1.0).abs() < 1e-6,
                "cut {cut}: folded {chi2:.9e}, own region {own:.9e}"
            );
            assert!(chi2 <= cur.scores.chi2_fit * (1.0 + 1e-9), "cut {cut}");
        }
        // The cuts differ: the ranking has something to rank.
        let (lo, hi) = folded
            .iter()
            .fold((f64::INFINITY, 0.0f64), |(a, b), &c| (a.min(c), b.max(c)));
        assert!(hi > 1.5 * lo, "{folded:?}");
    }
}
