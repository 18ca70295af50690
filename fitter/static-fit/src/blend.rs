//! Blending data for non-linear materials (seed 000 §6.2.3–6.2.4).
//!
//! - Homogeneous (eqs. 6.2–6.5): biharmonic RBF φ(r) = r over whole deformations; centres are the
//!   fitted deformed node positions x̄_i; weights solve Φw = [λ^i] and Φw = [α^i] with
//!   Φ_ij = ‖x̄_i − x̄_j‖ (invertible for distinct centres, Micchelli).
//! - Inhomogeneous (eqs. 6.7–6.11, in the form `protocol::model::Blend::Strain` documents): per
//!   element e, ‖e − ē_l‖_e² = Σ_{e'∈N(e)} w_{e,e'} ‖ε_{e'} − ε̄^l_{e'}‖² over the k nearest element
//!   centroids N(e) (including e) with w_{e,e'} = exp(−c ‖c_e − c_{e'}‖²); per element weights solve
//!   Φ_e w_e = b_e with Φ_{e,p,q} = φ(‖ē_p − ē_q‖_e).
//!
//! **Outside the fitted range.** An RBF interpolant with φ(r) = r grows linearly away from its
//! centres, so a deformation beyond the fitted ones extrapolates λ, α without bound and can turn
//! them non-physical (the thesis warns of this). The guard, applied by [`clamp_to_fitted`] here and
//! by the runtime: blended λ and α are clamped to the per-element [min, max] over the fitted sets,
//! so the blend never leaves the convex range of what was measured, and the result is then
//! checked physical (α is also clamped to keep ν = α/λ inside the fitted ν range).

use nalgebra::{DMatrix, DVector};
use palpate_fem::forward::{Material, StaticProblem};
use palpate_fem::mesh::centroid;

use super::FitError;

pub use palpate_fem::export::BlendData;

fn solve_rbf(phi: DMatrix<f64>, b: &[f64]) -> Result<Vec<f64>, FitError> {
    let n = b.len();
    let rhs = DVector::from_column_slice(b);
    // φ(r) = r gives an indefinite but invertible Φ: LU, with a relative ridge if the centres
    // nearly coincide (then the sets are blended rather than interpolated exactly).
    let scale = phi.amax().max(1e-300);
    if let Some(w) = phi.clone().lu().solve(&rhs) {
        if w.iter().all(|v| v.is_finite()) {
            return Ok(w.iter().copied().collect());
        }
    }
    let mut p = phi;
    for k in 0..n {
        p[(k, k)] += 1e-9 * scale;
    }
    p.lu()
        .solve(&rhs)
        .map(|w| w.iter().copied().collect())
        .ok_or_else(|| FitError::Singular("RBF system is singular (identical centres)".into()))
}

/// Refuses sets without exactly one fitted deformation each (or no sets at all).
fn one_deformation_per_set(sets: usize, deformations: usize) -> Result<(), FitError> {
    if sets != deformations || sets == 0 {
        return Err(FitError::Input(
            "blending needs one fitted deformation per set".into(),
        ));
    }
    Ok(())
}

/// The RBF weights of the λ and α values `bl`, `ba` of the sets (eq. 6.4) on the distance
/// matrix `phi`; a single set is its own weight.
fn rbf_weights(
    phi: DMatrix<f64>,
    bl: Vec<f64>,
    ba: Vec<f64>,
) -> Result<(Vec<f64>, Vec<f64>), FitError> {
    if bl.len() == 1 {
        Ok((bl, ba))
    } else {
        Ok((solve_rbf(phi.clone(), &bl)?, solve_rbf(phi, &ba)?))
    }
}

/// Homogeneous blending (eqs. 6.2–6.5) from per-measurement homogeneous sets and their fitted
/// deformations.
pub fn deformation_blend(
    sets: &[Material],
    deformed: &[Vec<[f64; 3]>],
) -> Result<BlendData, FitError> {
    let n = sets.len();
    one_deformation_per_set(n, deformed.len())?;
    let dist = |a: &[[f64; 3]], b: &[[f64; 3]]| -> f64 {
        a.iter()
            .zip(b)
            .map(|(p, q)| (0..3).map(|d| (p[d] - q[d]).powi(2)).sum::<f64>())
            .sum::<f64>()
            .sqrt()
    };
    let phi = DMatrix::from_fn(n, n, |i, j| dist(&deformed[i], &deformed[j]));
    let bl: Vec<f64> = sets.iter().map(|m| m.lambda[0]).collect();
    let ba: Vec<f64> = sets.iter().map(|m| m.alpha[0]).collect();
    let (weights_lambda, weights_alpha) = rbf_weights(phi, bl, ba)?;
    let centres = flat_centres(deformed);
    Ok(BlendData::Deformation {
        centres,
        weights_lambda,
        weights_alpha,
    })
}

/// The RBF centres as the model format stores them: every fitted state's values in order, state
/// after state (deformations: nodes × 3; strains: elements × 6).
fn flat_centres<const N: usize>(states: &[Vec<[f64; N]>]) -> Vec<f64> {
    states
        .iter()
        .flat_map(|x| x.iter().flat_map(|v| v.iter().copied()))
        .collect()
}

/// Element centroids of the rest mesh.
pub fn centroids(problem: &StaticProblem) -> Vec<[f64; 3]> {
    problem
        .tets
        .iter()
        .map(|t| centroid(&problem.x0, t))
        .collect()
}

/// Inhomogeneous strain-space blending (eqs. 6.7–6.11) with `k` nearest neighbours; the decay c
/// is chosen so that the median distance to the k-th neighbour gets weight e⁻² (c = 2/d_k²).
pub fn strain_blend(
    problem: &StaticProblem,
    sets: &[Material],
    deformed: &[Vec<[f64; 3]>],
    k: usize,
) -> Result<BlendData, FitError> {
    let n = sets.len();
    let t = problem.element_count();
    one_deformation_per_set(n, deformed.len())?;
    let k = k.clamp(1, t);
    let cen = centroids(problem);
    // k nearest centroids by brute force over a uniform grid would be faster; t is small (≤ 1e4)
    // and this runs once per export.
    let mut neighbour_index = Vec::with_capacity(t * k);
    let mut dk = Vec::with_capacity(t);
    let mut dists = Vec::with_capacity(t * k);
    for e in 0..t {
        let mut d: Vec<(f64, usize)> = (0..t)
            .map(|f| {
                (
                    (0..3).map(|a| (cen[e][a] - cen[f][a]).powi(2)).sum::<f64>(),
                    f,
                )
            })
            .collect();
        d.select_nth_unstable_by(k - 1, |a, b| a.0.total_cmp(&b.0));
        let mut near: Vec<(f64, usize)> = d[..k].to_vec();
        near.sort_by(|a, b| a.0.total_cmp(&b.0));
        dk.push(near[k - 1].0);
        for (d2, f) in near {
            neighbour_index.push(f as u32);
            dists.push(d2);
        }
    }
    let mut sorted = dk.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2].max(1e-300);
    let decay = 2.0 / median;
    let neighbour_weight: Vec<f64> = dists.iter().map(|d2| (-decay * d2).exp()).collect();
    // Strain centres (eq. 6.8) with the rotations of each fitted state.
    let strains: Vec<Vec<[f64; 6]>> = deformed
        .iter()
        .map(|x| problem.strains(x, &problem.rotations(x, true)))
        .collect();
    let mut weights_lambda = vec![0.0; t * n];
    let mut weights_alpha = vec![0.0; t * n];
    for e in 0..t {
        let nb = &neighbour_index[e * k..e * k + k];
        let wt = &neighbour_weight[e * k..e * k + k];
        let phi = DMatrix::from_fn(n, n, |p, q| {
            nb.iter()
                .zip(wt)
                .map(|(&f, &w)| {
                    w * (0..6)
                        .map(|c| (strains[p][f as usize][c] - strains[q][f as usize][c]).powi(2))
                        .sum::<f64>()
                })
                .sum::<f64>()
                .sqrt()
        });
        let bl: Vec<f64> = sets.iter().map(|m| m.at(e).0).collect();
        let ba: Vec<f64> = sets.iter().map(|m| m.at(e).1).collect();
        let (wl, wa) = rbf_weights(phi, bl, ba)?;
        weights_lambda[e * n..e * n + n].copy_from_slice(&wl);
        weights_alpha[e * n..e * n + n].copy_from_slice(&wa);
    }
    let centres = flat_centres(&strains);
    Ok(BlendData::Strain {
        decay,
        neighbours: k,
        neighbour_index,
        neighbour_weight,
        centres,
        weights_lambda,
        weights_alpha,
    })
}

/// Clamps a blended (λ, α) of element e to the per-element range of the fitted sets — the guard
/// against RBF extrapolation described in the module docs.
pub fn clamp_to_fitted(sets: &[Material], e: usize, lambda: f64, alpha: f64) -> (f64, f64) {
    let (mut lo, mut hi) = (
        (f64::INFINITY, f64::INFINITY),
        (f64::NEG_INFINITY, f64::NEG_INFINITY),
    );
    for m in sets {
        let (l, a) = m.at(e);
        lo = (lo.0.min(l), lo.1.min(a));
        hi = (hi.0.max(l), hi.1.max(a));
    }
    let l = lambda.clamp(lo.0, hi.0);
    // The physical band the runtime keeps too (runtime/src/blend.rs).
    (l, alpha.clamp(lo.1, hi.1).clamp(-0.999 * l, 0.499 * l))
}

/// Evaluates the homogeneous blend at deformation `x` (eqs. 6.2–6.3), clamped to the fitted range.
pub fn eval_deformation(
    blend: &BlendData,
    sets: &[Material],
    x: &[[f64; 3]],
) -> Option<(f64, f64)> {
    let BlendData::Deformation {
        centres,
        weights_lambda,
        weights_alpha,
    } = blend
    else {
        return None;
    };
    let m = 3 * x.len();
    let (mut l, mut a) = (0.0, 0.0);
    for i in 0..weights_lambda.len() {
        let c = &centres[i * m..i * m + m];
        let r = x
            .iter()
            .flat_map(|p| p.iter())
            .zip(c)
            .map(|(p, q)| (p - q).powi(2))
            .sum::<f64>()
            .sqrt();
        let r = if weights_lambda.len() == 1 { 1.0 } else { r };
        l += weights_lambda[i] * r;
        a += weights_alpha[i] * r;
    }
    Some(clamp_to_fitted(sets, 0, l, a))
}

/// Evaluates the strain blend for current element strains (eqs. 6.9–6.11), clamped.
pub fn eval_strain(blend: &BlendData, sets: &[Material], strains: &[[f64; 6]]) -> Option<Material> {
    let BlendData::Strain {
        neighbours: k,
        neighbour_index,
        neighbour_weight,
        centres,
        weights_lambda,
        weights_alpha,
        ..
    } = blend
    else {
        return None;
    };
    let t = strains.len();
    let n = sets.len();
    let mut out = Material {
        lambda: vec![0.0; t],
        alpha: vec![0.0; t],
        foundation: None,
    };
    for e in 0..t {
        let (mut l, mut a) = (0.0, 0.0);
        for i in 0..n {
            let mut d2 = 0.0;
            for j in 0..*k {
                let f = neighbour_index[e * k + j] as usize;
                let c = &centres[(i * t + f) * 6..(i * t + f) * 6 + 6];
                d2 += neighbour_weight[e * k + j]
                    * (0..6).map(|q| (strains[f][q] - c[q]).powi(2)).sum::<f64>();
            }
            let r = if n == 1 { 1.0 } else { d2.sqrt() };
            l += weights_lambda[e * n + i] * r;
            a += weights_alpha[e * n + i] * r;
        }
        let (l, a) = clamp_to_fitted(sets, e, l, a);
        out.lambda[e] = l;
        out.alpha[e] = a;
    }
    Some(out)
}

/// Neighbours per element of the strain-space blend (eqs. 6.9–6.11) that `palpate fit` exports.
pub const STRAIN_NEIGHBOURS: usize = 8;

/// The blend a fit is exported with: none for one set, the deformation-space RBF for
/// per-measurement homogeneous sets (eqs. 6.2–6.5), the strain-space RBF with
/// [`STRAIN_NEIGHBOURS`] for per-measurement inhomogeneous sets (eqs. 6.7–6.11). Centres are the
/// fit's simulated deformations.
pub fn for_fit(
    problem: &StaticProblem,
    layout: crate::Layout,
    sets: &[Material],
    deformed: &[Vec<[f64; 3]>],
) -> Result<BlendData, FitError> {
    if sets.len() <= 1 {
        return Ok(BlendData::None);
    }
    match layout {
        crate::Layout::Homogeneous => deformation_blend(sets, deformed),
        crate::Layout::Inhomogeneous => strain_blend(problem, sets, deformed, STRAIN_NEIGHBOURS),
    }
}

/// The blended material at the deformed state `x` (clamped to the fitted range as the runtime
/// does); the single set for [`BlendData::None`].
pub fn blended_material(
    problem: &StaticProblem,
    blend: &BlendData,
    sets: &[Material],
    x: &[[f64; 3]],
) -> Material {
    match blend {
        BlendData::None => sets[0].clone(),
        BlendData::Deformation { .. } => {
            let (l, a) = eval_deformation(blend, sets, x).unwrap_or(sets[0].at(0));
            Material {
                lambda: vec![l],
                alpha: vec![a],
                foundation: None,
            }
        }
        BlendData::Strain { .. } => {
            let strains = problem.strains(x, &problem.rotations(x, true));
            eval_strain(blend, sets, &strains).unwrap_or_else(|| sets[0].clone())
        }
    }
}

/// A blended solve: what the runtime plays, in f64. Incremental loading (`options.increments`
/// equal increments) with the material re-blended at the state each increment starts from (the
/// runtime re-blends every tick), then, at full load, re-blend and solve until the blended
/// parameters change by less than 1e-6 relative (at most `max_blend` rounds; each solve is the
/// warped fixed point of [`StaticProblem::solve_forces`]). The re-blend is relaxed by half: a
/// stiffer blend deforms less, which moves the state toward softer centres, and the undamped
/// iteration can cycle between two states (the runtime's one solve per tick damps it the same
/// way). Returns the state and whether the blend settled.
pub fn solve_blended(
    problem: &StaticProblem,
    sets: &[Material],
    blend: &BlendData,
    f_ext: &[f64],
    options: &palpate_fem::forward::SolveOptions,
    max_blend: usize,
) -> Result<(Vec<[f64; 3]>, bool), FitError> {
    if matches!(blend, BlendData::None) {
        let s = problem
            .solve_forces(&sets[0], f_ext, None, options)?
            .solution;
        return Ok((s.x, s.converged));
    }
    let n = options.increments.max(1);
    let mut x = problem.x0.clone();
    for k in 1..=n {
        let m = blended_material(problem, blend, sets, &x);
        let fk: Vec<f64> = f_ext.iter().map(|v| v * k as f64 / n as f64).collect();
        x = problem.solve_forces(&m, &fk, Some(&x), options)?.solution.x;
    }
    let mut m = blended_material(problem, blend, sets, &x);
    for _ in 0..max_blend {
        x = problem
            .solve_forces(&m, f_ext, Some(&x), options)?
            .solution
            .x;
        let mut next = blended_material(problem, blend, sets, &x);
        for (a, b) in next
            .lambda
            .iter_mut()
            .zip(&m.lambda)
            .chain(next.alpha.iter_mut().zip(&m.alpha))
        {
            *a = 0.5 * (*a + b);
        }
        let change = next
            .lambda
            .iter()
            .zip(&m.lambda)
            .chain(next.alpha.iter().zip(&m.alpha))
            .map(|(a, b)| (a - b).abs() / a.abs().max(1e-300))
            .fold(0.0, f64::max);
        m = next;
        if change < 1e-7 {
            return Ok((x, true));
        }
    }
    Ok((x, false))
}
