//! Where the residual asks for a stiffer or softer material: the gradient of χ² with respect to
//! every element's log E (one adjoint solve per measurement), and a matched-filter scan that
//! turns it into the inclusion candidate's start — find where, then what (issue 14).
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

use nalgebra::{Matrix3, SVector};
use palpate_fem::forward::{rotate_vec, Factorised};
use rayon::prelude::*;

use super::fit::Fitted;
use super::model::Context;
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
}

/// Full-node vector from a free-dof vector (zero on fixed nodes).
fn nodal(ctx: &Context, free: &[f64]) -> Vec<[f64; 3]> {
    let x0 = ctx.problem.positions_from_free(&vec![0.0; free.len()]);
    ctx.problem
        .positions_from_free(free)
        .iter()
        .zip(&x0)
        .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
        .collect()
}

/// The gradient of the fitted model's χ² with respect to each element's log E.
pub fn log_modulus_gradient(ctx: &Context, f: &Fitted) -> Result<Sensitivity, DiagnoseError> {
    let material = f.model.field_material(ctx, &f.theta)?;
    let ne = ctx.problem.element_count();
    let nn = ctx.problem.node_count();
    let s2 = ctx.sigma * ctx.sigma;
    let per: Vec<(usize, Linearised)> = f
        .subset
        .par_iter()
        .enumerate()
        .map(|(k, &i)| -> Result<(usize, Linearised), DiagnoseError> {
            let x = &f.sim.x[k];
            let rot: Vec<Matrix3<f64>> = ctx.problem.rotations(x, ctx.solve.warp);
            let factor = ctx
                .problem
                .factorise(&material, &rot)
                .map_err(|e| DiagnoseError::Diverged(format!("sensitivity: {e}")))?;
            let q = (0..ne)
                .map(|e| {
                    let u = ctx.problem.unrotated_displacement(e, &rot[e], x);
                    rotate_vec(&rot[e], &(ctx.problem.element_stiffness(e, &material) * u))
                })
                .collect();
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
            let mut rhs = ctx.problem.gather_free(&dx);
            factor.solve_in_place(&mut rhs);
            let lambda = nodal(ctx, &rhs);
            Ok((i, Linearised { factor, q, lambda }))
        })
        .collect::<Result<_, _>>()?;
    let tets = &ctx.problem.tets;
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
    })
}

/// The best blob of the scan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlobScan {
    /// Centre (m).
    pub centre: [f64; 3],
    /// Radius (m).
    pub radius: f64,
    /// Gauss–Newton contrast a (log E change at the centre).
    pub contrast: f64,
    /// Predicted χ² reduction (units of σ²).
    pub reduction: f64,
}

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

/// The Gauss–Newton model of χ² along a log-E field `phi` (per element) added with contrast a:
/// (gᵀφ, ‖Jφ‖²), with Jφ the observed markers' response in units of σ — one back-substitution
/// per measurement with the factor already made for the adjoint. `None` when no marker responds.
fn gauss_newton_along(ctx: &Context, s: &Sensitivity, phi: &[f64]) -> Option<(f64, f64)> {
    let tets = &ctx.problem.tets;
    let nn = ctx.problem.node_count();
    let g: f64 = s.gradient.iter().zip(phi).map(|(a, b)| a * b).sum();
    let mut jj = 0.0;
    for (i, l) in &s.per_measurement {
        // dx = −K'⁻¹ Σ_e φ_e q_e.
        let mut rhs = vec![0.0; 3 * nn];
        for (e, w) in phi.iter().enumerate() {
            if w.abs() < 1e-6 {
                continue;
            }
            for a in 0..12 {
                rhs[3 * tets[e][a / 3] + a % 3] -= w * l.q[e][a];
            }
        }
        let mut free = ctx.problem.gather_free(&rhs);
        l.factor.solve_in_place(&mut free);
        let dx = nodal(ctx, &free);
        for &(m, _) in &ctx.meas[*i].observed {
            let p = ctx.markers[m].interpolate(|n| dx[n]);
            jj += (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) / (ctx.sigma * ctx.sigma);
        }
    }
    (jj > 0.0).then_some((g, jj))
}

/// Matched-filter scan of Gaussian blobs of log E over the body (radii as fractions of the half
/// width `ctx.half`): the blob whose Gauss–Newton step predicts the largest χ² reduction.
pub fn scan_blobs(ctx: &Context, s: &Sensitivity, radii: &[f64]) -> Option<BlobScan> {
    let centres = scan_centres(ctx, 6, 4);
    let trials: Vec<(f64, [f64; 3])> = radii
        .iter()
        .flat_map(|&r| centres.iter().map(move |&p| (r * ctx.half, p)))
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
