//! Where a second material would sit ("find where, then what"): the misfit's
//! sensitivity to each element's own shear modulus, from the fit's adjoint — one simulation and
//! one adjoint pass for every element at once (Real2Sim eqs. 8–12 with a per-element μ_e).
//!
//! At a fitted global μ the per-element sensitivities sum to zero (∂Φ/∂ln μ = Σ_e ∂Φ/∂ln μ_e = 0
//! at the optimum), so a one-material body that fits leaves only noise in the map, while a body
//! of two materials leaves one sign where the fitted μ is too soft and the other where it is too
//! stiff. The map is taken per unit volume (a large element weighs more by its size alone),
//! smoothed over elements sharing a node (the adjoint's per-element values are noisy where the
//! markers see little), and cut into candidate regions (below); the chosen region's μ is then
//! fitted as a parameter of its own, the rest keeps the global μ, and λ stays one value.
//!
//! The sign split is where a *first-order* change of μ helps, not where the second material
//! ends: at the one-material fit the map's zero crossing sits wherever the fitted μ happens to
//! equal the local truth's average, and a strong contrast moves it by a whole element layer
//! (random two-material bars, `palpate-lab motion-confusion`: the sign split took 10 elements
//! where the true region had 6 or 8, and its refits stayed 16–25× above the noise floor where the
//! truth's partition came within 2× of it, both measured before λ reached a region's elements).
//! So the candidate regions are the map's nested level sets —
//! the elements ordered by their map value, cut at [`LEVEL_FRACTIONS`] of the volume — beside the
//! sign split, and the two-material candidate screens them by short fits, then every cut between the
//! best one's coarse neighbours (up to [`FINE_LEVELS`]): the map says *in what order* elements
//! join the region, the data say *where the boundary is*.

use super::fit::{fitted_part, retimed, with_offsets, FittedModel, Split};
use palpate_motion::dataset::MotionDataset;
use palpate_motion::gradient::{evaluate, Method};
use palpate_motion::model::{Model, Param, ParamKind};
use palpate_motion::MotionError;

/// Smoothing passes over node-sharing neighbours.
const SMOOTHING_PASSES: usize = 2;

/// Volume fractions at which the map's level sets are cut into the coarse candidate regions
/// ([`Family::coarse`]; the sign split is tried beside them).
pub const LEVEL_FRACTIONS: [f64; 9] = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9];

/// Most cuts screened between the best coarse cut's neighbours ([`Family::between`]).
pub const FINE_LEVELS: usize = 6;

/// The fewest elements a second material's region may hold. A coarse mesh's own error
/// concentrates in a few elements where the stress does (a cantilever's root at its clamp), and
/// one element made several times stiffer there mimics the refinement the mesh lacks: a region
/// that small is a symptom of the mesh, not a material, and the sensitivity map — smoothed over
/// node-sharing neighbourhoods — cannot place it anyway.
pub const MIN_REGION_ELEMENTS: usize = 4;

/// The smallest share of the body's volume a second material's region may hold, for the same
/// reason as [`MIN_REGION_ELEMENTS`] on a fine mesh, where four elements are a speck.
pub const MIN_REGION_VOLUME: f64 = 0.01;

/// Whether a region of `elements` elements and `volume` of the body's `total` volume is large
/// enough to be a material ([`MIN_REGION_ELEMENTS`], [`MIN_REGION_VOLUME`]).
pub fn plausible(elements: usize, volume: f64, total: f64) -> bool {
    elements >= MIN_REGION_ELEMENTS && volume >= MIN_REGION_VOLUME * total
}

/// The share of a region's volume in a clamp's element layer from which it is refused
/// ([`at_clamp_layer`]): two thirds, so that a region mostly in the layer, reaching less than
/// half a layer beyond it, is refused, while one with as much volume beyond the layer as in it
/// (the half of a bar next to its clamp, two element layers deep) is kept.
pub const CLAMP_LAYER_SHARE: f64 = 2.0 / 3.0;

/// Why a region is not taken for a second material because of where it sits, or `None`: at
/// least [`CLAMP_LAYER_SHARE`] of its volume lies in the layer of elements that touch a clamp's
/// nodes. The size floor ([`plausible`]) keeps out one element; this keeps out the next symptom
/// of the same cause — a coarse mesh's error at a Dirichlet boundary sits in exactly that layer
/// (a cantilever's root, where the stress is largest and linear tets are too stiff), and another
/// material there, hardly thicker than one element, mimics the refinement the mesh lacks. A
/// material that thin at a clamp cannot be told from the mesh's error there.
pub fn at_clamp_layer(model: &Model, elements: &[usize]) -> Option<String> {
    let volumes: Vec<f64> = model.rest.iter().map(|r| r.volume).collect();
    let clamps: Vec<(&str, &[usize])> = model
        .clamps
        .iter()
        .map(|c| (c.name.as_str(), c.nodes.as_slice()))
        .collect();
    clamp_layer_refusal(&model.tets, &volumes, &clamps, elements)
}

/// [`at_clamp_layer`] on the mesh's `tets`, their `volumes` and the `clamps`' (name, nodes).
fn clamp_layer_refusal(
    tets: &[[usize; 4]],
    volumes: &[f64],
    clamps: &[(&str, &[usize])],
    elements: &[usize],
) -> Option<String> {
    let region: f64 = elements.iter().map(|&e| volumes[e]).sum();
    let total: f64 = volumes.iter().sum();
    clamps.iter().find_map(|&(name, nodes)| {
        let clamped: std::collections::HashSet<usize> = nodes.iter().copied().collect();
        let touches = |e: usize| tets[e].iter().any(|n| clamped.contains(n));
        let layer: Vec<usize> = (0..tets.len()).filter(|&e| touches(e)).collect();
        let inside: Vec<usize> = elements.iter().copied().filter(|&e| touches(e)).collect();
        let inside_volume: f64 = inside.iter().map(|&e| volumes[e]).sum();
        (region > 0.0 && inside_volume >= CLAMP_LAYER_SHARE * region).then(|| {
            format!(
                "a region of {} element{} ({:.1} % of the volume), {} of them ({:.0} % of its \
                 volume) in the layer of {} elements at clamp `{name}` — discretisation error \
                 at a boundary is not a material",
                elements.len(),
                if elements.len() == 1 { "" } else { "s" },
                100.0 * region / total,
                inside.len(),
                100.0 * inside_volume / region,
                layer.len()
            )
        })
    })
}

/// Iterations of each region's screening fit: the region's μ and the global ones from the
/// current model, a ranking, not an answer (the random bars' screens converged in 5–6; the
/// chosen region is then fitted in full).
pub const SCREEN_ITERS: u64 = 5;

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
        "{} elements, {:.0} % of the volume, centred at ({:.1}, {:.1}, {:.1}) mm, {} than the \
         rest{}",
        elements.len(),
        100.0 * fraction,
        1e3 * centre[0],
        1e3 * centre[1],
        1e3 * centre[2],
        if stiffer { "stiffer" } else { "softer" },
        at_clamps(model, elements)
    )
}

/// ", N of them at clamp `name`" for each clamp the region's elements touch (share a node
/// with), or nothing: a region at a clamp sits where a coarse mesh's own error is largest, which
/// a reader weighing the region should know.
fn at_clamps(model: &Model, elements: &[usize]) -> String {
    model
        .clamps
        .iter()
        .filter_map(|c| {
            let touching = elements
                .iter()
                .filter(|&&e| model.tets[e].iter().any(|n| c.nodes.contains(n)))
                .count();
            (touching > 0).then(|| format!(", {touching} of them at clamp `{}`", c.name))
        })
        .collect()
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

/// The nested candidate regions of a second material: the elements in ascending order of the
/// smoothed μ sensitivity map (most negative first: where a stiffer μ helps most), cut after
/// the first k of them for k in 1..n. The sign split is the cut at the map's zero.
#[derive(Debug, Clone)]
pub struct Family {
    /// Elements, most negative map value first.
    order: Vec<usize>,
    /// Cumulative volume of the first k elements, k = 0..=n.
    volume: Vec<f64>,
    /// The cut at the map's zero (elements with a negative value).
    sign_cut: usize,
}

impl Family {
    /// The region of the cut after the first `k` elements: the smaller side by volume, sorted,
    /// `stiffer` when it is the low side.
    pub fn region(&self, k: usize) -> Region {
        let total = self.volume[self.order.len()];
        let (mut elements, stiffer) = if self.volume[k] <= 0.5 * total {
            (self.order[..k].to_vec(), true)
        } else {
            (self.order[k..].to_vec(), false)
        };
        elements.sort_unstable();
        Region { elements, stiffer }
    }

    /// Elements in the family's order.
    pub fn len(&self) -> usize {
        self.order.len()
    }

    /// Whether the family has no elements (never: a family splits a map of two signs).
    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }

    /// The elements from the `lo`-th to before the `hi`-th in the family's order, sorted: the
    /// band between two cuts.
    pub fn band(&self, lo: usize, hi: usize) -> Vec<usize> {
        let mut elements = self.order[lo..hi].to_vec();
        elements.sort_unstable();
        elements
    }

    /// Whether the cut after the first `k` elements leaves a region (its smaller side) large
    /// enough to be a material ([`plausible`]).
    fn plausible_cut(&self, k: usize) -> bool {
        let n = self.order.len();
        let total = self.volume[n];
        if self.volume[k] <= 0.5 * total {
            plausible(k, self.volume[k], total)
        } else {
            plausible(n - k, total - self.volume[k], total)
        }
    }

    /// The coarse cuts, ascending: the sign split's and those at [`LEVEL_FRACTIONS`] of the
    /// volume (the first k holding at least that fraction), each leaving a [`plausible`]
    /// region.
    pub fn coarse(&self) -> Vec<usize> {
        let n = self.order.len();
        let total = self.volume[n];
        let mut cuts: Vec<usize> = LEVEL_FRACTIONS
            .iter()
            .map(|&f| (1..=n).find(|&k| self.volume[k] >= f * total).unwrap_or(n))
            .chain(std::iter::once(self.sign_cut))
            .filter(|&k| k > 0 && k < n && self.plausible_cut(k))
            .collect();
        cuts.sort_unstable();
        cuts.dedup();
        cuts
    }

    /// Up to `most` cuts strictly between the coarse neighbours of `best` in `coarse` (or the
    /// family's ends), evenly spaced, each leaving a [`plausible`] region: where the boundary
    /// is, to the element, once the coarse scan has said roughly where.
    pub fn between(&self, coarse: &[usize], best: usize, most: usize) -> Vec<usize> {
        let lo = coarse
            .iter()
            .copied()
            .filter(|&k| k < best)
            .max()
            .unwrap_or(0);
        let hi = coarse
            .iter()
            .copied()
            .filter(|&k| k > best)
            .min()
            .unwrap_or(self.order.len());
        let inner: Vec<usize> = (lo + 1..hi)
            .filter(|&k| k != best && self.plausible_cut(k))
            .collect();
        if inner.len() <= most {
            return inner;
        }
        let mut cuts: Vec<usize> = (0..most)
            .map(|i| inner[(i * (inner.len() - 1)) / (most - 1).max(1)])
            .collect();
        cuts.dedup();
        cuts
    }
}

/// The candidate regions of a second material at the current fit `cur` ([`Family`]), from the
/// per-element μ sensitivity on the data it was fitted to (its marker offsets and time offset
/// applied); `None` when the map has one sign everywhere (the global μ is not at its optimum:
/// nothing to split).
pub fn locate(
    ds: &MotionDataset,
    split: Split,
    cur: &FittedModel,
) -> Result<Option<Family>, MotionError> {
    let grad = sensitivity(ds, split, cur)?;
    let model = &ds.model;
    let ne = model.tets.len();
    let raw: Vec<f64> = (0..ne)
        .map(|e| grad[e] * cur.material.get(ParamKind::Mu, e) / model.rest[e].volume)
        .collect();
    let map = smooth(model, &raw, SMOOTHING_PASSES);
    let volumes: Vec<f64> = model.rest.iter().map(|r| r.volume).collect();
    Ok(family(&volumes, &map))
}

/// [`Family`] of `map` over elements of `volumes`, or `None` when it has one sign everywhere.
fn family(volumes: &[f64], map: &[f64]) -> Option<Family> {
    let sign_cut = map.iter().filter(|&&v| v < 0.0).count();
    if sign_cut == 0 || sign_cut == map.len() {
        return None;
    }
    let mut order: Vec<usize> = (0..map.len()).collect();
    order.sort_by(|&a, &b| map[a].total_cmp(&map[b]).then(a.cmp(&b)));
    let mut volume = vec![0.0];
    for &e in &order {
        volume.push(volume[volume.len() - 1] + volumes[e]);
    }
    Some(Family {
        order,
        volume,
        sign_cut,
    })
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
/// leave either material a region too small to be one ([`plausible`]); `volumes` of every
/// element.
pub fn switched(region: &[usize], moved: &[usize], volumes: &[f64]) -> Option<Vec<usize>> {
    let mut inside = vec![false; volumes.len()];
    region.iter().for_each(|&e| inside[e] = true);
    moved.iter().for_each(|&e| inside[e] = !inside[e]);
    let next: Vec<usize> = (0..volumes.len()).filter(|&e| inside[e]).collect();
    let total: f64 = volumes.iter().sum();
    let v: f64 = next.iter().map(|&e| volumes[e]).sum();
    let both =
        plausible(next.len(), v, total) && plausible(volumes.len() - next.len(), total - v, total);
    both.then_some(next)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 24 equal elements along a bar whose map falls linearly from one end: the family is the
    /// bar cut at every element, the coarse cuts at tenths of its volume and the map's zero, and
    /// the fine cuts every element between the best coarse cut's neighbours — so a boundary
    /// between two coarse cuts (the 16 / 8 split of a random two-material bar) is reached.
    #[test]
    fn level_sets_reach_every_cut_near_the_best_coarse_one() {
        let n = 24;
        let volumes = vec![1.0; n];
        // Elements 0..10 negative (a stiffer μ helps there), the rest positive.
        let map: Vec<f64> = (0..n).map(|e| e as f64 - 9.5).collect();
        let f = family(&volumes, &map).unwrap();
        let coarse = f.coarse();
        // The tenths at 3 and 22 leave three and two elements: too few to be a material.
        assert_eq!(coarse, vec![5, 8, 10, 12, 15, 17, 20]);
        assert!(!coarse.contains(&16));
        let fine = f.between(&coarse, 15, FINE_LEVELS);
        assert_eq!(fine, vec![13, 14, 16]);
        // The region of a cut is its smaller side, labelled by the side it is.
        let low = f.region(8);
        assert_eq!(low.elements, (0..8).collect::<Vec<_>>());
        assert!(low.stiffer);
        let high = f.region(16);
        assert_eq!(high.elements, (16..24).collect::<Vec<_>>());
        assert!(!high.stiffer);
        // Many cuts between the neighbours: at most FINE_LEVELS of them, spread out.
        let big = family(
            &vec![1.0; 1000],
            &(0..1000).map(|e| e as f64 - 500.0).collect::<Vec<_>>(),
        )
        .unwrap();
        let c = big.coarse();
        let fine = big.between(&c, 500, FINE_LEVELS);
        assert_eq!(fine.len(), FINE_LEVELS);
        assert!(
            fine.iter().all(|&k| k > 400 && k < 600 && k != 500),
            "{fine:?}"
        );
        // Below the best coarse cut the fine cuts stop where the region would be a speck.
        let fine = f.between(&coarse, 5, FINE_LEVELS);
        assert_eq!(fine, vec![4, 6, 7]);
        // One sign everywhere: nothing to split.
        assert!(family(&volumes, &vec![1.0; n]).is_none());
    }

    /// A region of one or a few elements — where a coarse mesh's own error sits at a clamp —
    /// is never a candidate, whether cut from the map or reached by moving the boundary, and
    /// neither is a split that leaves the rest that small.
    #[test]
    fn a_region_smaller_than_a_few_elements_is_not_a_material() {
        let n = 200;
        let volumes = vec![1.0; n];
        // The map's most negative element alone: the first fine cut would be that one element.
        let map: Vec<f64> = (0..n).map(|e| e as f64 - 0.5).collect();
        let f = family(&volumes, &map).unwrap();
        let coarse = f.coarse();
        let fine = f.between(&coarse, coarse[0], FINE_LEVELS);
        for k in coarse.iter().chain(&fine) {
            let r = f.region(*k);
            assert!(
                r.elements.len() >= MIN_REGION_ELEMENTS,
                "cut {k}: {} elements",
                r.elements.len()
            );
        }
        // The sign split here is one element: dropped, not screened.
        assert!(!coarse.contains(&1), "{coarse:?}");
        // Moving the boundary may not shrink a region below the limit, nor grow it to leave
        // the rest below it.
        let region: Vec<usize> = (0..6).collect();
        assert!(switched(&region, &[0, 1, 2], &volumes).is_none());
        assert_eq!(switched(&region, &[0, 1], &volumes), Some(vec![2, 3, 4, 5]));
        let most: Vec<usize> = (6..n - 2).collect();
        assert!(switched(&region, &most, &volumes).is_none());
        // 1 % of the volume: four elements of 1000 are a speck.
        assert!(!plausible(4, 4.0, 1000.0));
        assert!(plausible(10, 10.0, 1000.0));
    }

    /// A bar of six element layers (four elements each) clamped at its first plane of nodes: a
    /// region mostly in the clamp's element layer is refused, whatever its size; one reaching as
    /// far beyond the layer as into it (half the bar), or away from the clamp, is kept.
    #[test]
    fn a_region_in_the_clamps_element_layer_is_not_a_material() {
        // Plane j holds nodes 4j..4j+3; element (j, i) joins planes j and j + 1.
        let tets: Vec<[usize; 4]> = (0..6)
            .flat_map(|j| {
                (0..4).map(move |i| {
                    let (a, b) = (4 * j + i, 4 * j + (i + 1) % 4);
                    [a, b, a + 4, b + 4]
                })
            })
            .collect();
        let volumes = vec![1.0; tets.len()];
        let clamp: Vec<usize> = (0..4).collect();
        let clamps = [("front", clamp.as_slice())];
        let refused = |elements: &[usize]| clamp_layer_refusal(&tets, &volumes, &clamps, elements);
        let one = refused(&[2]).expect("one element at the clamp");
        assert!(
            one.starts_with("a region of 1 element (4.2 % of the volume)")
                && one.contains("at clamp `front`")
                && one.contains("discretisation error at a boundary is not a material"),
            "{one}"
        );
        assert!(refused(&[0, 1, 2, 3]).is_some(), "the whole layer");
        // The layer and one element beyond it: four fifths in the layer.
        assert!(refused(&[0, 1, 2, 3, 4]).is_some());
        // Three quarters of a layer beyond it: kept.
        assert!(refused(&[0, 1, 2, 3, 4, 5, 6]).is_none());
        // Half the bar next to its clamp: a material three element layers deep.
        assert!(refused(&(0..12).collect::<Vec<_>>()).is_none());
        // Away from the clamp.
        assert!(refused(&[8, 9, 10, 11]).is_none());
        // No clamp: nothing to refuse.
        assert!(clamp_layer_refusal(&tets, &volumes, &[], &[0]).is_none());
    }
}
