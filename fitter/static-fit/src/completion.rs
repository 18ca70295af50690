//! Completing unobserved nodes for the force-based fit, which needs every node's deformed
//! position x̄ (eqs. 5.15–5.21) while only surface markers are observed.
//!
//! Given the current parameters p, the completed state is the equilibrium of the current model with
//! the observed markers imposed as constraints: x̄ = argmin E_p(x) subject to M x = x̄_markers,
//! i.e. x̄ = x(p) + K'⁻¹Mᵀ (M K'⁻¹ Mᵀ)⁻¹ (x̄_markers − M x(p)). Unobserved nodes thus take the
//! positions the current model gives them when the observed markers are held where they were
//! measured. The fitter alternates: complete with the current parameters, refit (force-based),
//! repeat until the parameters stop changing. With noise-free data and the true parameters the
//! correction is zero, so the truth is a fixed point of the alternation.

use faer::Mat;
use nalgebra::{DMatrix, DVector};

use palpate_fem::forward::{Material, SolveOptions};

use super::{FitError, FitInput};

/// Completed deformation of measurement `i` with `material`, warm-started from `start`.
pub fn complete(
    input: &FitInput,
    i: usize,
    material: &Material,
    options: &SolveOptions,
    start: Option<&[[f64; 3]]>,
) -> Result<Vec<[f64; 3]>, FitError> {
    let p = &input.problem;
    let m = &input.measurements[i];
    let solved = p.solve_forces(material, &m.force, start, options)?;
    let x = solved.solution.x;
    let nd = p.free_dofs();
    let k = m.observed.len();
    if k == 0 {
        return Ok(x);
    }
    // Columns of Mᵀ over the free dofs (3 per marker).
    let mut z = Mat::<f64>::zeros(nd, 3 * k);
    for (c, &(mk, _)) in m.observed.iter().enumerate() {
        let mkr = &input.markers[mk];
        for (b, &n) in mkr.barycentric.iter().zip(&mkr.triangle) {
            let fi = p.free_index[n];
            if fi != usize::MAX {
                for d in 0..3 {
                    z[(3 * fi + d, 3 * c + d)] += *b;
                }
            }
        }
    }
    // Sparse copy of Mᵀ's columns (at most 3 entries each) before z is overwritten by K'⁻¹Mᵀ.
    let cols: Vec<Vec<(usize, f64)>> = (0..3 * k)
        .map(|a| {
            (0..nd)
                .filter(|&r| z[(r, a)] != 0.0)
                .map(|r| (r, z[(r, a)]))
                .collect()
        })
        .collect();
    solved.factor.solve_in_place_mat(z.as_mut());
    // S = M K'⁻¹ Mᵀ (3k × 3k, symmetric positive semi-definite).
    let mut s = DMatrix::<f64>::zeros(3 * k, 3 * k);
    for (a, col) in cols.iter().enumerate() {
        for b in 0..3 * k {
            s[(a, b)] = col.iter().map(|&(r, v)| v * z[(r, b)]).sum();
        }
    }
    // A tiny ridge keeps markers that sit only on fixed nodes (zero rows) harmless.
    let ridge = 1e-12
        * (0..3 * k)
            .map(|a| s[(a, a)])
            .fold(0.0, f64::max)
            .max(1e-300);
    for a in 0..3 * k {
        s[(a, a)] += ridge;
    }
    let mut r = DVector::<f64>::zeros(3 * k);
    for (c, (_, e)) in input.marker_errors(i, &x).iter().enumerate() {
        for d in 0..3 {
            r[3 * c + d] = -e[d];
        }
    }
    let mu = s.cholesky().map(|ch| ch.solve(&r)).ok_or_else(|| {
        FitError::Singular(format!(
            "measurement {:?}: marker constraint matrix is singular (duplicate markers?)",
            m.id
        ))
    })?;
    let mut out = x;
    for (n, fi) in p.free_index.iter().enumerate() {
        if *fi == usize::MAX {
            continue;
        }
        for d in 0..3 {
            let row = 3 * fi + d;
            let mut v = 0.0;
            for c in 0..3 * k {
                v += z[(row, c)] * mu[c];
            }
            out[n][d] += v;
        }
    }
    Ok(out)
}
