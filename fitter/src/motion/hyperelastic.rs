//! Neo-Hookean element kernel (Real2Sim eq. 16) with an optional strain-stiffening term.
//!
//! Ψ(F) = λ/2 ((J² − 1)/2 − ln J) + μ/2 (tr(FᵀF) − 3 − 2 ln J) + c (I₁ − 3)²,  I₁ = tr(FᵀF).
//!
//! The last term is palpate's addition (c = 0 gives the paper's model): it stiffens the response
//! at large stretch without changing the small-strain moduli (its stress and tangent vanish at
//! F = I), which is what the specimen generator needs to make a visibly non-linear object.
//! Element forces are f_a = −V_e P ∇φ_a (P = ∂Ψ/∂F, ∇φ_a the rest shape-function gradients) and
//! the tangent is K_e = −∂f/∂x. This file is the one implementation used by the dynamic motion
//! simulator and the quasi-static solver [`super::statics`].

use nalgebra::{Matrix3, Vector3};

/// Material constants of one element for the hyperelastic kernel (Pa).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HyperParams {
    /// Lamé's first parameter λ.
    pub lambda: f64,
    /// Shear modulus μ.
    pub mu: f64,
    /// Strain-stiffening coefficient c of the c (I₁ − 3)² term (0 = pure Neo-Hookean).
    pub stiffening: f64,
}

/// Rest geometry of one tetrahedron: shape-function gradients and volume.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RestTet {
    /// ∇φ_a of the four nodes in the rest configuration.
    pub grad: [Vector3<f64>; 4],
    /// Rest volume V_e.
    pub volume: f64,
}

/// F = Σ_a x_a ∇φ_aᵀ.
pub fn deformation_gradient(t: &RestTet, x: &[Vector3<f64>; 4]) -> Matrix3<f64> {
    let mut f = Matrix3::zeros();
    for a in 0..4 {
        f += x[a] * t.grad[a].transpose();
    }
    f
}

/// Strain energy density Ψ(F); `None` when J ≤ 0 (inverted element: ln J undefined).
pub fn energy_density(f: &Matrix3<f64>, p: &HyperParams) -> Option<f64> {
    let j = f.determinant();
    if j.is_nan() || j <= 0.0 {
        return None;
    }
    let lnj = j.ln();
    let i1 = f.norm_squared();
    Some(
        0.5 * p.lambda * ((j * j - 1.0) / 2.0 - lnj)
            + 0.5 * p.mu * (i1 - 3.0 - 2.0 * lnj)
            + p.stiffening * (i1 - 3.0) * (i1 - 3.0),
    )
}

/// Pieces of F reused by the stress and its derivatives.
#[derive(Debug, Clone, Copy)]
pub struct FParts {
    /// F.
    pub f: Matrix3<f64>,
    /// F⁻ᵀ.
    pub f_inv_t: Matrix3<f64>,
    /// J = det F.
    pub j: f64,
    /// I₁ = tr(FᵀF).
    pub i1: f64,
}

impl FParts {
    /// Splits F; `None` when J ≤ 0 or F is singular.
    pub fn new(f: Matrix3<f64>) -> Option<Self> {
        let j = f.determinant();
        if j.is_nan() || j <= 0.0 {
            return None;
        }
        let f_inv_t = f.try_inverse()?.transpose();
        Some(Self {
            f,
            f_inv_t,
            j,
            i1: f.norm_squared(),
        })
    }
}

/// First Piola–Kirchhoff stress P = λ/2 (J² − 1) F⁻ᵀ + μ (F − F⁻ᵀ) + 4c (I₁ − 3) F.
pub fn pk1(s: &FParts, p: &HyperParams) -> Matrix3<f64> {
    s.f_inv_t * (0.5 * p.lambda * (s.j * s.j - 1.0))
        + (s.f - s.f_inv_t) * p.mu
        + s.f * (4.0 * p.stiffening * (s.i1 - 3.0))
}

/// ∂P/∂λ = ½ (J² − 1) F⁻ᵀ.
pub fn pk1_dlambda(s: &FParts) -> Matrix3<f64> {
    s.f_inv_t * (0.5 * (s.j * s.j - 1.0))
}

/// ∂P/∂μ = F − F⁻ᵀ.
pub fn pk1_dmu(s: &FParts) -> Matrix3<f64> {
    s.f - s.f_inv_t
}

/// Directional derivative dP[dF].
///
/// d(F⁻ᵀ) = −F⁻ᵀ dFᵀ F⁻ᵀ, dJ = J tr(F⁻¹ dF), dI₁ = 2 F : dF.
pub fn dpk1(s: &FParts, p: &HyperParams, df: &Matrix3<f64>) -> Matrix3<f64> {
    let d_finv_t = -(s.f_inv_t * df.transpose() * s.f_inv_t);
    let tr = s.f_inv_t.component_mul(df).sum(); // tr(F⁻¹ dF)
    let dj2 = 2.0 * s.j * s.j * tr;
    let di1 = 2.0 * s.f.component_mul(df).sum();
    s.f_inv_t * (0.5 * p.lambda * dj2)
        + d_finv_t * (0.5 * p.lambda * (s.j * s.j - 1.0))
        + (df - d_finv_t) * p.mu
        + (s.f * di1 + df * (s.i1 - 3.0)) * (4.0 * p.stiffening)
}

/// Nodal forces −V P ∇φ_a of a stress P, added into `out` (12-vector, node-major).
pub fn add_stress_forces(t: &RestTet, p: &Matrix3<f64>, scale: f64, out: &mut [f64; 12]) {
    for a in 0..4 {
        let fa = p * t.grad[a] * (-t.volume * scale);
        for i in 0..3 {
            out[3 * a + i] += fa[i];
        }
    }
}

/// Element forces f_e = −V P ∇φ_a; `None` for an inverted element.
pub fn element_forces(t: &RestTet, x: &[Vector3<f64>; 4], p: &HyperParams) -> Option<[f64; 12]> {
    let s = FParts::new(deformation_gradient(t, x))?;
    let mut out = [0.0; 12];
    add_stress_forces(t, &pk1(&s, p), 1.0, &mut out);
    Some(out)
}

/// Element tangent K_e = −∂f_e/∂x_e (12 × 12, row-major `k[row][col]`), symmetric.
///
/// Closed form of V dP[e_j ∇φ_bᵀ] ∇φ_a (from [`dpk1`] with H = F⁻ᵀ, h_a = H ∇φ_a, f_a = F ∇φ_a,
/// g_ab = ∇φ_a·∇φ_b, c = λ(J² − 1)/2 − μ):
/// K[3a+i][3b+j] = V [ μ δ_ij g_ab + λJ² h_a,i h_b,j − c h_b,i h_a,j
///                     + 4c_s (2 f_a,i f_b,j + (I₁ − 3) δ_ij g_ab) ].
/// (The per-direction evaluation through `dpk1` was the motion simulator's hottest loop.)
pub fn element_tangent(t: &RestTet, s: &FParts, p: &HyperParams) -> [[f64; 12]; 12] {
    let h: [Vector3<f64>; 4] = std::array::from_fn(|a| s.f_inv_t * t.grad[a]);
    let fg: [Vector3<f64>; 4] = std::array::from_fn(|a| s.f * t.grad[a]);
    let j2 = s.j * s.j;
    let c = 0.5 * p.lambda * (j2 - 1.0) - p.mu;
    let lj2 = p.lambda * j2;
    let ks = 4.0 * p.stiffening;
    let diag = p.mu + ks * (s.i1 - 3.0);
    let v = t.volume;
    let mut k = [[0.0; 12]; 12];
    for a in 0..4 {
        for b in 0..4 {
            let gab = t.grad[a].dot(&t.grad[b]);
            for i in 0..3 {
                for jj in 0..3 {
                    let mut val = lj2 * h[a][i] * h[b][jj] - c * h[b][i] * h[a][jj]
                        + 2.0 * ks * fg[a][i] * fg[b][jj];
                    if i == jj {
                        val += diag * gab;
                    }
                    k[3 * a + i][3 * b + jj] = v * val;
                }
            }
        }
    }
    k
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tet() -> (RestTet, [Vector3<f64>; 4]) {
        let x = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(0.01, 0.0, 0.0),
            Vector3::new(0.002, 0.012, 0.0),
            Vector3::new(0.001, 0.003, 0.011),
        ];
        let g = palpate_runtime::element::tet_geometry(&x).unwrap();
        (
            RestTet {
                grad: g.grad,
                volume: g.volume,
            },
            x,
        )
    }

    /// Forces are minus the energy gradient and the tangent is minus the force Jacobian; central
    /// differences with h = 1e-8 m on a 1 cm element are accurate to ~1e-6 relative.
    #[test]
    fn forces_and_tangent_match_finite_differences() {
        let (t, x0) = tet();
        let p = HyperParams {
            lambda: 3e4,
            mu: 1e4,
            stiffening: 5e3,
        };
        let mut x = x0;
        x[1] += Vector3::new(0.002, -0.001, 0.0005);
        x[3] += Vector3::new(-0.001, 0.0015, 0.002);
        let energy = |x: &[Vector3<f64>; 4]| {
            t.volume * energy_density(&deformation_gradient(&t, x), &p).unwrap()
        };
        let f = element_forces(&t, &x, &p).unwrap();
        let s = FParts::new(deformation_gradient(&t, &x)).unwrap();
        let k = element_tangent(&t, &s, &p);
        let h = 1e-8;
        for c in 0..12 {
            let mut xp = x;
            let mut xm = x;
            xp[c / 3][c % 3] += h;
            xm[c / 3][c % 3] -= h;
            let fd_e = (energy(&xp) - energy(&xm)) / (2.0 * h);
            assert!(
                (f[c] + fd_e).abs() < 1e-6 * f.iter().map(|v| v.abs()).fold(0.0, f64::max),
                "force {c}"
            );
            let fp = element_forces(&t, &xp, &p).unwrap();
            let fm = element_forces(&t, &xm, &p).unwrap();
            for r in 0..12 {
                let fd = -(fp[r] - fm[r]) / (2.0 * h);
                assert!(
                    (k[r][c] - fd).abs() < 1e-5 * (k[r][c].abs() + 1.0),
                    "K[{r}][{c}] {} vs {fd}",
                    k[r][c]
                );
            }
        }
        for r in 0..12 {
            for c in 0..12 {
                assert!((k[r][c] - k[c][r]).abs() < 1e-9 * (k[r][c].abs() + 1.0));
            }
        }
    }

    #[test]
    fn rest_state_is_stress_free_and_inverted_is_rejected() {
        let (t, x) = tet();
        let p = HyperParams {
            lambda: 3e4,
            mu: 1e4,
            stiffening: 5e3,
        };
        let f = element_forces(&t, &x, &p).unwrap();
        assert!(f.iter().all(|v| v.abs() < 1e-12));
        let mut xi = x;
        xi[3][2] = -0.011;
        assert!(element_forces(&t, &xi, &p).is_none());
    }
}
