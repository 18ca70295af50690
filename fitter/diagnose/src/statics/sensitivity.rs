//! Where the residual asks for a stiffer or softer material: the gradient of χ² with respect to
//! every element's log E (one adjoint solve per measurement), and a matched-filter scan that
//! turns it into the inclusion candidate's start — find where, then what.
//!
//! The warped equilibrium of measurement i is F(x, p) = Σ_e R_e K_e ũ_e − f = 0 with
//! ũ_e = R_eᵀ x_e − X_e (eq. 3.53). K_e is proportional to the element's E at a fixed Poisson's
//! ratio, so ∂F/∂log E_e = R_e K_e ũ_e =: q_e, the element's internal force. With the adjoint
//! K' λ = ∂χ²/∂x (K' = Σ R_e K_e R_eᵀ, the rotations' own derivative neglected — a map needs
//! the direction, not the last per cent) the gradient is dχ²/d log E_e = −λ_eᵀ q_e.
//!
//! The raw gradient is largest wherever the data are most sensitive — under the probes, next to
//! the markers — whatever the truth; an inclusion elsewhere shows only after normalising by that
//! sensitivity. For a blob φ_p(e) = exp(−½ ‖c_e − p‖²/r²) added to log E with contrast a, the
//! Gauss–Newton model of χ² along a predicts the reduction (gᵀφ)² / (4 ‖Jφ‖²) at the step
//! a = −gᵀφ / (2 ‖Jφ‖²), where Jφ (the markers' response to the blob, in units of σ) costs one
//! back-substitution per measurement with the factor already made for the adjoint. The scan
//! evaluates it on a grid of centres and two radii and returns the best.
//!
//! The fit that follows refits the homogeneous (λ, α) beside the blob, so the scan scores each
//! blob as that joint fit would — profiled (the Schur complement of the Gauss–Newton model):
//! Jφ and gᵀφ with their parts along the uniform log λ and log α directions taken out. Without
//! it a broad blob, much of whose response a global modulus change already gives, is scored as
//! if that part had to be paid for again, and the scan prefers a small blob at the surface to
//! a large soft core (the independent generator's cylinder 6005: a ×0.13 core of radius 10 mm
//! was scored below a stiffer 8 mm blob 26 mm away).

use nalgebra::{Matrix3, SVector};
use palpate_fem::forward::{rotate_vec, Factorised, StaticProblem};
use rayon::prelude::*;

use super::fit::Fitted;
use super::model::{Context, Model};
use super::DiagnoseError;

/// Per measurement: the factor of K', and each element's internal force q_e = R_e K_e ũ_e.
struct Linearised {
    factor: Factorised,
    q: Vec<SVector<f64, 12>>,
    /// (∂χ²/∂x solved) λ on every node (zero on fixed nodes).
    lambda: Vec<[f64; 3]>,
}

/// The gradient map and the pieces the scan reuses.
pub struct Sensitivity {
    /// dχ²/d log E_e per element (χ² in units of σ²).
    pub gradient: Vec<f64>,
    per_measurement: Vec<(usize, Linearised)>,
    /// The uniform log λ and log α directions, orthonormalised: each an observed-marker
    /// response (units of σ, stacked in the scan's order) with its gradient component carried
    /// through the same Gram–Schmidt steps.
    uniform: Vec<(Vec<f64>, f64)>,
    /// The model linearised (its problem: fixed supports or the foundation's).
    model: Model,
}

/// One measurement's marker responses and gradient components along the uniform log λ and log α
/// directions, before they are stacked and orthonormalised.
type UniformParts = [(Vec<f64>, f64); 2];

/// Removes from (j, g) its parts along the orthonormal directions `basis` (Gram–Schmidt with
/// the gradient component carried along: for u = Σ c_k b_k, gᵤ = Σ c_k g_k).
fn profile(basis: &[(Vec<f64>, f64)], j: &mut [f64], g: &mut f64) {
    for (u, gu) in basis {
        let c: f64 = j.iter().zip(u).map(|(a, b)| a * b).sum();
        j.iter_mut().zip(u).for_each(|(a, b)| *a -= c * b);
        *g -= c * gu;
    }
}

/// Full-node vector from a free-dof vector (zero on fixed nodes).
fn nodal(problem: &StaticProblem, free: &[f64]) -> Vec<[f64; 3]> {
    let x0 = problem.positions_from_free(&vec![0.0; free.len()]);
    problem
        .positions_from_free(free)
        .iter()
        .zip(&x0)
        .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
        .collect()
}

/// The gradient of the fitted model's χ² with respect to each element's log E.
pub fn log_modulus_gradient(ctx: &Context, f: &Fitted) -> Result<Sensitivity, DiagnoseError> {
    let material = f.model.field_material(ctx, &f.theta)?;
    let problem = f.model.problem(ctx);
    let ne = problem.element_count();
    let nn = problem.node_count();
    let s2 = ctx.sigma * ctx.sigma;
    let per: Vec<(usize, Linearised, UniformParts)> = f
        .subset
        .par_iter()
        .enumerate()
        .map(
            |(k, &i)| -> Result<(usize, Linearised, UniformParts), DiagnoseError> {
                let x = &f.sim.x[k];
                let rot: Vec<Matrix3<f64>> = problem.rotations(x, ctx.solve.warp);
                let factor = problem
                    .factorise(&material, &rot)
                    .map_err(|e| DiagnoseError::Diverged(format!("sensitivity: {e}")))?;
                // q_e and its λ part R_e λ_e C_e ũ_e (the α part is the difference): the uniform
                // log λ and log α directions' forces.
                let (q, q_lambda): (Vec<SVector<f64, 12>>, Vec<SVector<f64, 12>>) = (0..ne)
                    .map(|e| {
                        let u = problem.unrotated_displacement(e, &rot[e], x);
                        let (l, _) = material.at(e);
                        (
                            rotate_vec(&rot[e], &(problem.element_stiffness(e, &material) * u)),
                            rotate_vec(&rot[e], &(problem.c[e] * l * u)),
                        )
                    })
                    .unzip();
                // ∂χ²/∂x: 2 (sim − measured)/σ² spread on each marker's triangle.
                let mut dx = vec![0.0; 3 * nn];
                for (&(m, meas), p) in ctx.meas[i].observed.iter().zip(&f.sim.markers[k]) {
                    let mk = &ctx.markers[m];
                    for (t, &n) in mk.triangle.iter().enumerate() {
                        for d in 0..3 {
                            dx[3 * n + d] += 2.0 * mk.barycentric[t] * (p[d] - meas[d]) / s2;
                        }
                    }
                }
                let mut rhs = problem.gather_free(&dx);
                factor.solve_in_place(&mut rhs);
                let lambda = nodal(problem, &rhs);
                let q_alpha: Vec<SVector<f64, 12>> =
                    q.iter().zip(&q_lambda).map(|(a, b)| a - b).collect();
                let uniform = [&q_lambda, &q_alpha].map(|qs| {
                    let phi = vec![1.0; ne];
                    let j = marker_response(ctx, problem, &factor, qs, &phi, i);
                    let g: f64 = -(0..ne)
                        .map(|e| {
                            (0..12)
                                .map(|a| lambda[problem.tets[e][a / 3]][a % 3] * qs[e][a])
                                .sum::<f64>()
                        })
                        .sum::<f64>();
                    (j, g)
                });
                Ok((i, Linearised { factor, q, lambda }, uniform))
            },
        )
        .collect::<Result<_, _>>()?;
    // The two uniform directions stacked over the measurements, then orthonormalised.
    let mut uniform: Vec<(Vec<f64>, f64)> = Vec::new();
    for k in 0..2 {
        let mut j: Vec<f64> = per.iter().flat_map(|(_, _, u)| u[k].0.clone()).collect();
        let mut g: f64 = per.iter().map(|(_, _, u)| u[k].1).sum();
        profile(&uniform, &mut j, &mut g);
        let norm = j.iter().map(|v| v * v).sum::<f64>().sqrt();
        if norm > 0.0 {
            uniform.push((j.iter().map(|v| v / norm).collect(), g / norm));
        }
    }
    let per: Vec<(usize, Linearised)> = per.into_iter().map(|(i, l, _)| (i, l)).collect();
    let tets = &problem.tets;
    let mut gradient = vec![0.0; ne];
    for (_, l) in &per {
        for (e, g) in gradient.iter_mut().enumerate() {
            let t = &tets[e];
            *g -= (0..12)
                .map(|a| l.lambda[t[a / 3]][a % 3] * l.q[e][a])
                .sum::<f64>();
        }
    }
    Ok(Sensitivity {
        gradient,
        per_measurement: per,
        uniform,
        model: f.model.clone(),
    })
}

/// The best blob of the scan (a model's inclusion start, so it is defined beside it).
pub use super::model::BlobScan;

/// Centres of the scan: a `n × n × m` grid over the elements' bounding box, each snapped to the
/// nearest element centroid (so every centre lies in the body, whatever its shape), duplicates
/// removed.
fn scan_centres(ctx: &Context, n: usize, m: usize) -> Vec<[f64; 3]> {
    let c = &ctx.centroids;
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in c {
        for d in 0..3 {
            lo[d] = lo[d].min(p[d]);
            hi[d] = hi[d].max(p[d]);
        }
    }
    let mut out: Vec<usize> = Vec::new();
    let steps = [n, n, m];
    for i in 0..n {
        for j in 0..n {
            for k in 0..m {
                let idx = [i, j, k];
                let p: [f64; 3] = std::array::from_fn(|d| {
                    lo[d] + (hi[d] - lo[d]) * (idx[d] as f64 + 0.5) / steps[d] as f64
                });
                let near = c
                    .iter()
                    .enumerate()
                    .map(|(e, q)| (e, (0..3).map(|d| (q[d] - p[d]).powi(2)).sum::<f64>()))
                    .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a })
                    .0;
                if !out.contains(&near) {
                    out.push(near);
                }
            }
        }
    }
    out.into_iter().map(|e| c[e]).collect()
}

/// The observed markers' response (units of σ) of measurement `i` to the log-E field `phi`
/// acting through the element forces `q`: dx = −K'⁻¹ Σ_e φ_e q_e, one back-substitution.
fn marker_response(
    ctx: &Context,
    problem: &StaticProblem,
    factor: &Factorised,
    q: &[SVector<f64, 12>],
    phi: &[f64],
    i: usize,
) -> Vec<f64> {
    let tets = &problem.tets;
    let mut rhs = vec![0.0; 3 * problem.node_count()];
    for (e, w) in phi.iter().enumerate() {
        if w.abs() < 1e-6 {
            continue;
        }
        for a in 0..12 {
            rhs[3 * tets[e][a / 3] + a % 3] -= w * q[e][a];
        }
    }
    let mut free = problem.gather_free(&rhs);
    factor.solve_in_place(&mut free);
    let dx = nodal(problem, &free);
    ctx.meas[i]
        .observed
        .iter()
        .flat_map(|&(m, _)| ctx.markers[m].interpolate(|n| dx[n]).map(|v| v / ctx.sigma))
        .collect()
}

/// The Gauss–Newton model of χ² along a log-E field `phi` (per element) added with contrast a,
/// profiled over the homogeneous (λ, α) the fit refits beside it: (gᵀφ, ‖Jφ‖²) with both
/// parts along the uniform directions removed, Jφ the observed markers' response in units of
/// σ. `None` when no marker responds outside those directions.
fn gauss_newton_along(ctx: &Context, s: &Sensitivity, phi: &[f64]) -> Option<(f64, f64)> {
    let mut g: f64 = s.gradient.iter().zip(phi).map(|(a, b)| a * b).sum();
    let mut j: Vec<f64> = s
        .per_measurement
        .iter()
        .flat_map(|(i, l)| marker_response(ctx, s.model.problem(ctx), &l.factor, &l.q, phi, *i))
        .collect();
    let jj0: f64 = j.iter().map(|v| v * v).sum();
    profile(&s.uniform, &mut j, &mut g);
    let jj: f64 = j.iter().map(|v| v * v).sum();
    // A field the uniform directions already give (φ ≡ 1) leaves round-off only.
    (jj > 1e-9 * jj0 && jj > 0.0).then_some((g, jj))
}

/// Matched-filter scan of Gaussian blobs of log E over the body (radii as fractions of the half
/// width `ctx.frame.half`): the blob whose Gauss–Newton step predicts the largest χ² reduction.
pub fn scan_blobs(ctx: &Context, s: &Sensitivity, radii: &[f64]) -> Option<BlobScan> {
    let centres = scan_centres(ctx, 6, 4);
    let trials: Vec<(f64, [f64; 3])> = radii
        .iter()
        .flat_map(|&r| centres.iter().map(move |&p| (r * ctx.frame.half, p)))
        .collect();
    trials
        .par_iter()
        .filter_map(|&(r, p)| {
            let phi: Vec<f64> = ctx
                .centroids
                .iter()
                .map(|c| {
                    let d2: f64 = (0..3).map(|d| (c[d] - p[d]).powi(2)).sum();
                    (-0.5 * d2 / (r * r)).exp()
                })
                .collect();
            let (g, jj) = gauss_newton_along(ctx, s, &phi)?;
            Some(BlobScan {
                centre: p,
                radius: r,
                contrast: -g / (2.0 * jj),
                reduction: g * g / (4.0 * jj),
            })
        })
        .max_by(|a, b| a.reduction.total_cmp(&b.reduction))
}

/// The best layer of the scan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LayerScan {
    /// Thickness as a fraction of the depth map's range.
    pub thickness: f64,
    /// Gauss–Newton contrast a (log E change in the layer).
    pub contrast: f64,
    /// Predicted χ² reduction (units of σ²).
    pub reduction: f64,
}

/// Matched-filter scan of layers of `thicknesses` (fractions) over the element depths `depth`:
/// the step 1 / (1 + e^{−(t − d)/w}) in log E whose Gauss–Newton step predicts the largest χ²
/// reduction.
pub fn scan_layers(
    ctx: &Context,
    s: &Sensitivity,
    depth: &[f64],
    thicknesses: &[f64],
    width: f64,
) -> Option<LayerScan> {
    thicknesses
        .par_iter()
        .filter_map(|&t| {
            let phi: Vec<f64> = depth
                .iter()
                .map(|&d| 1.0 / (1.0 + (-(t - d) / width).exp()))
                .collect();
            let (g, jj) = gauss_newton_along(ctx, s, &phi)?;
            Some(LayerScan {
                thickness: t,
                contrast: -g / (2.0 * jj),
                reduction: g * g / (4.0 * jj),
            })
        })
        .max_by(|a, b| a.reduction.total_cmp(&b.reduction))
}
