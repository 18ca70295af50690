//! Where a second material would sit (issue 14, "find where, then what"): the misfit's
//! sensitivity to each element's own shear modulus, from the fit's adjoint — one simulation and
//! one adjoint pass for every element at once (Real2Sim eqs. 8–12 with a per-element μ_e).
//!
//! At a fitted global μ the per-element sensitivities sum to zero (∂Φ/∂ln μ = Σ_e ∂Φ/∂ln μ_e = 0
//! at the optimum), so a one-material body that fits leaves only noise in the map, while a body
//! of two materials leaves one sign where the fitted μ is too soft and the other where it is too
//! stiff. The map is taken per unit volume (a large element weighs more by its size alone),
//! smoothed over elements sharing a node (the adjoint's per-element values are noisy where the
//! markers see little), and split by sign; the smaller part by volume is the candidate region:
//! its μ is then fitted as a parameter of its own, the rest keeps the global μ.

use super::fit::{fitted_part, retimed, with_offsets, FittedModel, Split};
use palpate_motion::dataset::MotionDataset;
use palpate_motion::gradient::{evaluate, Method};
use palpate_motion::model::{Model, Param, ParamKind};
use palpate_motion::MotionError;

/// Smoothing passes over node-sharing neighbours.
const SMOOTHING_PASSES: usize = 2;

/// The located region.
#[derive(Debug, Clone)]
pub struct Region {
    /// Elements of the region.
    pub elements: Vec<usize>,
    /// True when a stiffer material there lowers the misfit (the map is negative there: the
    /// fitted μ was too soft).
    pub stiffer: bool,
}

/// One line for a report: how large a region is, where, and which way its material differs
/// from the rest's (`stiffer`).
pub fn describe(model: &Model, elements: &[usize], stiffer: bool) -> String {
    let (fraction, centre) = extent(model, elements);
    format!(
        "{} elements, {:.0} % of the volume, centred at ({:.1}, {:.1}, {:.1}) mm, {} than the rest",
        elements.len(),
        100.0 * fraction,
        1e3 * centre[0],
        1e3 * centre[1],
        1e3 * centre[2],
        if stiffer { "stiffer" } else { "softer" }
    )
}

/// A region's share of the body's volume and its volume-weighted centroid (m).
fn extent(model: &Model, elements: &[usize]) -> (f64, [f64; 3]) {
    let total: f64 = model.rest.iter().map(|r| r.volume).sum();
    let v: f64 = elements.iter().map(|&e| model.rest[e].volume).sum();
    let mut centre = [0.0; 3];
    for &e in elements {
        let w = model.rest[e].volume / v;
        for &n in &model.tets[e] {
            for k in 0..3 {
                centre[k] += 0.25 * w * model.nodes[n][k];
            }
        }
    }
    (v / total, centre)
}

/// The sign split of the per-element μ sensitivity at the current fit `cur`, on the data it was
/// fitted to (its marker offsets and time offset applied); `None` when the map has one sign
/// everywhere (nothing to split).
pub fn locate(
    ds: &MotionDataset,
    split: Split,
    cur: &FittedModel,
) -> Result<Option<Region>, MotionError> {
    let grad = sensitivity(ds, split, cur)?;
    let model = &ds.model;
    let ne = model.tets.len();
    let raw: Vec<f64> = (0..ne)
        .map(|e| grad[e] * cur.material.get(ParamKind::Mu, e) / model.rest[e].volume)
        .collect();
    let map = smooth(model, &raw, SMOOTHING_PASSES);
    Ok(split_by_sign(model, &map))
}

/// Volume-weighted means over each element and the elements sharing a node with it, `passes`
/// times.
fn smooth(model: &Model, values: &[f64], passes: usize) -> Vec<f64> {
    let mut around: Vec<Vec<usize>> = vec![Vec::new(); model.nodes.len()];
    for (e, t) in model.tets.iter().enumerate() {
        t.iter().for_each(|&n| around[n].push(e));
    }
    // Each element's neighbourhood (itself and every element sharing a node), once.
    let neighbourhoods: Vec<Vec<usize>> = model
        .tets
        .iter()
        .map(|t| {
            let mut seen: Vec<usize> = t.iter().flat_map(|&n| around[n].iter().copied()).collect();
            seen.sort_unstable();
            seen.dedup();
            seen
        })
        .collect();
    let mut v = values.to_vec();
    for _ in 0..passes {
        v = neighbourhoods
            .iter()
            .map(|seen| {
                let (s, w) = seen.iter().fold((0.0, 0.0), |(s, w), &f| {
                    let vol = model.rest[f].volume;
                    (s + vol * v[f], w + vol)
                });
                s / w
            })
            .collect();
    }
    v
}

/// The smaller part by volume of the sign split of `map`, or `None` if one part is empty.
fn split_by_sign(model: &Model, map: &[f64]) -> Option<Region> {
    let negative: Vec<usize> = (0..map.len()).filter(|&e| map[e] < 0.0).collect();
    let positive: Vec<usize> = (0..map.len()).filter(|&e| map[e] >= 0.0).collect();
    if negative.is_empty() || positive.is_empty() {
        return None;
    }
    let volume = |es: &[usize]| es.iter().map(|&e| model.rest[e].volume).sum::<f64>();
    let (elements, stiffer) = if volume(&negative) <= volume(&positive) {
        (negative, true)
    } else {
        (positive, false)
    };
    Some(Region { elements, stiffer })
}

/// Calls `f` with the model and observations of `cur`'s fitted steps, its marker offsets and
/// time offset applied.
fn with_fitted_data<T>(
    ds: &MotionDataset,
    split: Split,
    cur: &FittedModel,
    f: impl FnOnce(&Model, &palpate_motion::model::Observations) -> Result<T, MotionError>,
) -> Result<T, MotionError> {
    let moved = cur.offsets.as_deref().map(|o| with_offsets(ds, o));
    let data = moved.as_ref().unwrap_or(ds);
    let timed = match cur.time_offset {
        Some(r) => Some(retimed(data, split, r)?),
        None => None,
    };
    let (data, split) = timed.as_ref().map_or((data, split), |(d, s)| (d, *s));
    let (model, obs) = fitted_part(data, split);
    f(&model, &obs)
}

/// ∂Φ/∂μ_e of every element at the fit `cur`, on the data it was fitted to (its marker offsets
/// and time offset applied): one simulation and one adjoint pass.
pub fn sensitivity(
    ds: &MotionDataset,
    split: Split,
    cur: &FittedModel,
) -> Result<Vec<f64>, MotionError> {
    with_fitted_data(ds, split, cur, |model, obs| {
        let params: Vec<Param> = (0..model.tets.len())
            .map(|e| Param::of_element(ParamKind::Mu, e))
            .collect();
        evaluate(model, &cur.material, &params, obs, Some(Method::Adjoint))?
            .grad
            .ok_or_else(|| MotionError::Invalid("the adjoint pass gave no gradient".into()))
    })
}

/// The elements whose switch to the other material lowers Φ to first order,
/// Δ_e = ∂Φ/∂μ_e (μ_other − μ_e) < 0, most negative Δ_e first; `grad` from [`sensitivity`] at a
/// fit of the two materials (`mu_region` inside `region`, `mu_rest` outside).
pub fn switches(region: &[usize], grad: &[f64], mu_region: f64, mu_rest: f64) -> Vec<usize> {
    let mut inside = vec![false; grad.len()];
    region.iter().for_each(|&e| inside[e] = true);
    let mut gain: Vec<(f64, usize)> = grad
        .iter()
        .enumerate()
        .map(|(e, &g)| {
            let change = if inside[e] {
                mu_rest - mu_region
            } else {
                mu_region - mu_rest
            };
            (g * change, e)
        })
        .filter(|&(d, _)| d < 0.0)
        .collect();
    gain.sort_by(|a, b| a.0.total_cmp(&b.0));
    gain.into_iter().map(|(_, e)| e).collect()
}

/// `region` with the elements `moved` switched to the other material; `None` when that would
/// leave one of the two materials without elements (`elements` in all).
pub fn switched(region: &[usize], moved: &[usize], elements: usize) -> Option<Vec<usize>> {
    let mut inside = vec![false; elements];
    region.iter().for_each(|&e| inside[e] = true);
    moved.iter().for_each(|&e| inside[e] = !inside[e]);
    let next: Vec<usize> = (0..elements).filter(|&e| inside[e]).collect();
    (!next.is_empty() && next.len() < elements).then_some(next)
}
