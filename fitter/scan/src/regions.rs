//! A second material found: an object declared as one material, searched for a split into two
//! parts of different moduli (two silicones cast into one mould).
//!
//! - **Candidates**: planes normal to the rest mesh's longest principal axis at a tenth, two
//!   tenths, … nine tenths of its extent, and the halves along each other principal axis; an
//!   element belongs to the part its centroid lies in. A candidate whose smaller part holds
//!   fewer than [`MIN_PART_ELEMENTS`] elements is not tried: one element's modulus is the
//!   mesh's freedom, not a material. Nor is one with a part that has [`CLAMP_LAYER_SHARE`] or
//!   more of its volume in the layer of elements touching a held node (a clamp or a grip): a
//!   coarse mesh's error concentrates where the stress does, at a cantilever's root, and a
//!   stiffer layer there mimics the refinement the mesh lacks — a material that thin at a clamp
//!   cannot be told from the mesh's error (the rule of `palpate diagnose`, docs/diagnose.md).
//! - **Screening**: at the one-material fit, each candidate's two-modulus Gauss–Newton step is
//!   predicted from the fit's own linearisation (∂r/∂ln μ₁ + ∂r/∂ln μ₂ = ∂r/∂ln μ, so one
//!   forward difference per candidate and state gives both columns): the predicted fall of the
//!   cost ½ gᵀH⁻¹g. The [`FITTED`] best are fitted in full.
//! - **Adoption**: BIC = n ln(RSS/n) + k ln n, n the scans' points, RSS the weighted squared
//!   residual Σ ωᵢdᵢ² with the one-material fit's weights held for both models (a weight the
//!   split gives back to a point would otherwise count as a better fit). The split is adopted
//!   when ΔBIC < −10 and the two moduli differ by more than [`MIN_RATIO`]: with thousands of
//!   points, a coarse mesh's own discretisation error is found "significant" by BIC, and a part
//!   a few per cent stiffer near a clamp takes it up (a homogeneous strip on 768 P2 tets: a
//!   split at 10 % of its length, ratio 1.06, ΔBIC −34) — two silicones differ by more.

use nalgebra::{DMatrix, DVector, SymmetricEigen, Vector3};
use palpate_fem::mesh::Mesh;

use crate::fit::{cost_at, fit_states, FitSettings, JointFit, ScanState};
use crate::ScanError;

/// The share of a part's volume in the held nodes' element layer from which it is refused.
pub const CLAMP_LAYER_SHARE: f64 = 2.0 / 3.0;
/// The least ratio of the two parts' moduli (or its inverse) that is adopted as a second
/// material.
pub const MIN_RATIO: f64 = 1.2;
/// The fewest elements a part may hold.
pub const MIN_PART_ELEMENTS: usize = 8;
/// ΔBIC a split must reach to be adopted.
pub const ADOPT_DELTA_BIC: f64 = -10.0;
/// Candidates fitted in full after screening.
pub const FITTED: usize = 2;
/// The forward-difference step in ln μ₂ of the screening.
const SCREEN_STEP: f64 = 1e-3;

/// A split of the mesh into two parts by a plane.
#[derive(Debug, Clone)]
pub struct Split {
    /// How it reads: "plane ⟂ axis 1 at 40 % of its extent".
    pub label: String,
    /// The plane's unit normal, a principal axis of the rest mesh (part 2 on its positive side).
    pub normal: [f64; 3],
    /// A point of the plane (m).
    pub point: [f64; 3],
    /// Where along the axis, as a fraction of the mesh's extent along it.
    pub fraction: f64,
    /// Each element's part, 0 or 1.
    pub regions: Vec<usize>,
    /// Elements in each part.
    pub elements: [usize; 2],
    /// Part 2's bounding box (m): lowest and highest corner of its elements' nodes.
    pub second_bounds: ([f64; 3], [f64; 3]),
}

/// The rest mesh's principal axes, longest first, each turned so its largest component is
/// positive; with the node centroid.
pub fn principal_axes(mesh: &Mesh) -> ([Vector3<f64>; 3], Vector3<f64>) {
    let n = mesh.nodes.len().max(1) as f64;
    let c = mesh
        .nodes
        .iter()
        .map(|p| Vector3::from(*p))
        .sum::<Vector3<f64>>()
        / n;
    let mut cov = nalgebra::Matrix3::zeros();
    for p in &mesh.nodes {
        let d = Vector3::from(*p) - c;
        cov += d * d.transpose();
    }
    let e = SymmetricEigen::new(cov);
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| e.eigenvalues[b].total_cmp(&e.eigenvalues[a]));
    let axes = order.map(|k| {
        let v: Vector3<f64> = e.eigenvectors.column(k).into();
        let big = v
            .iter()
            .copied()
            .fold(0.0f64, |m, x| if x.abs() > m.abs() { x } else { m });
        if big < 0.0 {
            -v
        } else {
            v
        }
    });
    (axes, c)
}

/// The candidate splits of `mesh` (module doc), those with both parts large enough and
/// neither mostly in the layer of elements touching a node of `held` (clamped or gripped).
pub fn candidate_splits(mesh: &Mesh, held: &[usize]) -> Vec<Split> {
    let (axes, _) = principal_axes(mesh);
    let is_held: std::collections::HashSet<usize> = held.iter().copied().collect();
    let volume: Vec<f64> = mesh
        .tets
        .iter()
        .map(|t| palpate_fem::mesh::signed_volume(t.map(|n| mesh.nodes[n])).abs())
        .collect();
    let in_layer: Vec<bool> = mesh
        .tets
        .iter()
        .map(|t| t.iter().any(|n| is_held.contains(n)))
        .collect();
    let centroids: Vec<Vector3<f64>> = mesh
        .tets
        .iter()
        .map(|t| {
            t.iter()
                .map(|&n| Vector3::from(mesh.nodes[n]))
                .sum::<Vector3<f64>>()
                / 4.0
        })
        .collect();
    let mut out = Vec::new();
    let planes = (1..10)
        .map(|k| (0, k as f64 / 10.0))
        .chain([(1, 0.5), (2, 0.5)]);
    for (a, fraction) in planes {
        let axis = axes[a];
        let proj: Vec<f64> = mesh
            .nodes
            .iter()
            .map(|p| axis.dot(&Vector3::from(*p)))
            .collect();
        let lo = proj.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = proj.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let at = lo + fraction * (hi - lo);
        let regions: Vec<usize> = centroids
            .iter()
            .map(|c| usize::from(axis.dot(c) > at))
            .collect();
        let second = regions.iter().filter(|&&r| r == 1).count();
        let elements = [regions.len() - second, second];
        if elements.iter().any(|&e| e < MIN_PART_ELEMENTS) {
            continue;
        }
        let at_clamp = (0..2).any(|part| {
            let (mut all, mut layer) = (0.0, 0.0);
            for e in (0..regions.len()).filter(|&e| regions[e] == part) {
                all += volume[e];
                if in_layer[e] {
                    layer += volume[e];
                }
            }
            layer >= CLAMP_LAYER_SHARE * all
        });
        if at_clamp {
            log::debug!(
                "axis {} at {:.0} %: a part lies mostly in the held nodes' element layer",
                a + 1,
                100.0 * fraction
            );
            continue;
        }
        let mut blo = [f64::INFINITY; 3];
        let mut bhi = [f64::NEG_INFINITY; 3];
        for (t, _) in mesh.tets.iter().zip(&regions).filter(|(_, r)| **r == 1) {
            for &n in t {
                for k in 0..3 {
                    blo[k] = blo[k].min(mesh.nodes[n][k]);
                    bhi[k] = bhi[k].max(mesh.nodes[n][k]);
                }
            }
        }
        // A point of the plane: the nodes' centroid moved onto it along the axis.
        let (_, c) = principal_axes(mesh);
        let point = c + axis * (at - axis.dot(&c));
        out.push(Split {
            label: format!(
                "plane ⟂ principal axis {} at {:.0} % of its extent",
                a + 1,
                100.0 * fraction
            ),
            normal: axis.into(),
            point: point.into(),
            fraction,
            regions,
            elements,
            second_bounds: (blo, bhi),
        });
    }
    out
}

/// A two-material fit on one split, against the one-material fit.
#[derive(Debug, Clone)]
pub struct SplitFit {
    /// The split.
    pub split: Split,
    /// The two moduli fitted.
    pub fit: JointFit,
    /// BIC of the one-material fit.
    pub bic_single: f64,
    /// BIC of this split's fit.
    pub bic_split: f64,
    /// μ₂/μ₁.
    pub ratio: f64,
    /// Its standard deviation, from the fit's covariance.
    pub ratio_sigma: f64,
}

impl SplitFit {
    /// BIC of the split minus the one-material fit's.
    pub fn delta_bic(&self) -> f64 {
        self.bic_split - self.bic_single
    }
}

/// What the search found.
#[derive(Debug, Clone)]
pub struct RegionSearch {
    /// Each candidate screened with its predicted fall of the cost, best first.
    pub screened: Vec<(String, f64)>,
    /// The best split fitted (lowest BIC), if any candidate could be fitted.
    pub best: Option<SplitFit>,
    /// Whether it is adopted (ΔBIC < −10, both parts large enough, the moduli [`MIN_RATIO`]
    /// apart).
    pub adopted: bool,
    /// Points in all the scans (the n of BIC).
    pub points: usize,
}

fn bic(rss: f64, n: usize, k: usize) -> f64 {
    let n = n as f64;
    n * (rss / n).ln() + k as f64 * n.ln()
}

/// Searches `states` (one material, fitted as `single`) for a second material (module doc).
pub fn search_regions(
    states: &[ScanState<'_>],
    single: &JointFit,
    settings: &FitSettings,
) -> Result<RegionSearch, ScanError> {
    let Some(first) = states.first() else {
        return Err(ScanError::Invalid("region search: no state".into()));
    };
    let mesh = first.object.mesh;
    let mu = single.mu[0];
    let n: usize = states.iter().map(|s| s.scan.points.len()).sum();
    let omegas: Vec<Vec<f64>> = single
        .states
        .iter()
        .zip(states)
        .map(|(l, s)| l.omegas(s.scan.points.len()))
        .collect();
    let rss_single: f64 = 2.0 * single.states.iter().map(|l| l.cost).sum::<f64>();
    let bic_single = bic(rss_single, n, 1);
    let mut screened = Vec::new();
    let held: Vec<usize> = states
        .iter()
        .flat_map(|s| s.object.fixed.iter().copied())
        .collect();
    let candidates = candidate_splits(mesh, &held);
    for split in &candidates {
        let (mut g, mut h) = (DVector::<f64>::zeros(2), DMatrix::<f64>::zeros(2, 2));
        for (s, lin) in states.iter().zip(&single.states) {
            let mut o = s.object.clone();
            o.regions = split.regions.clone();
            let moved = o.equilibrium_at(&[mu, mu * SCREEN_STEP.exp()], false)?;
            let base = &lin.equilibrium;
            let total = &base.dln_mu[0];
            for r in &lin.residuals {
                let c = &r.correspondence;
                let (mut j_total, mut j_second) = (0.0, 0.0);
                for (node, d) in c.jacobian() {
                    let dx2 =
                        Vector3::from(moved.positions[node]) - Vector3::from(base.positions[node]);
                    j_second += d.dot(&dx2) / SCREEN_STEP;
                    j_total += d.dot(&Vector3::from(total[node]));
                }
                let j = nalgebra::Vector2::new(j_total - j_second, j_second);
                let omega = r.weight / (r.sigma * r.sigma);
                g += j * (omega * c.distance);
                h += j * j.transpose() * omega;
            }
        }
        let gain = h
            .clone()
            .cholesky()
            .map(|c| 0.5 * g.dot(&c.solve(&g)))
            .unwrap_or(0.0);
        log::debug!("{}: predicted fall of the cost {gain:.3e}", split.label);
        screened.push((split.label.clone(), gain));
    }
    let mut order: Vec<usize> = (0..candidates.len()).collect();
    order.sort_by(|&a, &b| screened[b].1.total_cmp(&screened[a].1));
    let screened_sorted: Vec<(String, f64)> = order.iter().map(|&i| screened[i].clone()).collect();
    let mut best: Option<SplitFit> = None;
    for &i in order.iter().take(FITTED) {
        let split = &candidates[i];
        log::info!("fitting two materials split by the {}", split.label);
        let two: Vec<ScanState<'_>> = states
            .iter()
            .map(|s| {
                let mut s = s.clone();
                s.object.regions = split.regions.clone();
                s
            })
            .collect();
        let fit = match fit_states(
            &two,
            &FitSettings {
                starts: vec![mu],
                ..settings.clone()
            },
        ) {
            Ok(f) => f,
            Err(e) => {
                log::warn!("two materials split by the {}: no fit: {e}", split.label);
                continue;
            }
        };
        let rss: f64 = 2.0
            * fit
                .states
                .iter()
                .zip(&two)
                .zip(&omegas)
                .map(|((l, s), w)| cost_at(&l.equilibrium, &s.scan, w, settings.max_distance))
                .sum::<f64>();
        let c = &fit.covariance;
        let var = c[0] + c[3] - 2.0 * c[1];
        let ratio = fit.mu[1] / fit.mu[0];
        let candidate = SplitFit {
            split: split.clone(),
            bic_single,
            bic_split: bic(rss, n, 2),
            ratio,
            ratio_sigma: ratio * var.max(0.0).sqrt(),
            fit,
        };
        log::info!(
            "{}: E {:.1} / {:.1} kPa, ratio {:.3}, ΔBIC {:.1}",
            split.label,
            candidate.fit.young_modulus(0) / 1e3,
            candidate.fit.young_modulus(1) / 1e3,
            ratio,
            candidate.delta_bic()
        );
        if best
            .as_ref()
            .is_none_or(|b| candidate.bic_split < b.bic_split)
        {
            best = Some(candidate);
        }
    }
    let adopted = best.as_ref().is_some_and(|b| {
        b.delta_bic() < ADOPT_DELTA_BIC
            && b.split.elements.iter().all(|&e| e >= MIN_PART_ELEMENTS)
            && b.ratio.ln().abs() > MIN_RATIO.ln()
    });
    Ok(RegionSearch {
        screened: screened_sorted,
        best,
        adopted,
        points: n,
    })
}
