//! Power-law viscosity (Real2Sim eq. 17): σ = ν γ̇^(h−1) (∇v + ∇vᵀ), γ̇ = √½ ‖∇v + ∇vᵀ‖_F.
//!
//! h = 1 is Newtonian, h < 1 shear thinning, h > 1 shear thickening. ∇v is taken with the rest
//! shape-function gradients (Ḟ = Σ_a v_a ∇φ_aᵀ) as in the paper's public code, so the viscous
//! force depends on the velocities only (its position derivative is zero) and the stress acts
//! like a first Piola–Kirchhoff stress: f_a = −V σ ∇φ_a. Elements whose ‖∇v‖_F ≤ f64::MIN_POSITIVE
//! are skipped, as the paper does (the shear-thinning stress is undefined there but tends to 0).

use super::hyperelastic::RestTet;
use nalgebra::{Matrix3, Vector3};

/// Velocity gradient Ḟ = Σ_a v_a ∇φ_aᵀ.
pub fn velocity_gradient(t: &RestTet, v: &[Vector3<f64>; 4]) -> Matrix3<f64> {
    let mut l = Matrix3::zeros();
    for a in 0..4 {
        l += v[a] * t.grad[a].transpose();
    }
    l
}

/// Viscous stress state of one element under the power law of index h; `None` when the element
/// is skipped (‖Ḟ‖ ≤ MIN_POSITIVE).
#[derive(Debug, Clone, Copy)]
pub struct Rate {
    /// E = Ḟ + Ḟᵀ.
    pub e: Matrix3<f64>,
    /// γ̇ = √½ ‖E‖_F.
    pub gamma: f64,
    /// The power-law index h.
    pub h: f64,
    /// γ̇^(h−1), evaluated once here: the stress, the damping tangent and the parameter
    /// derivatives of one element all need it, and pow was a tenth of a simulation's time.
    pub power: f64,
}

impl Rate {
    /// From the velocity gradient and the power-law index h.
    pub fn new(l: &Matrix3<f64>, h: f64) -> Option<Self> {
        if l.norm() <= f64::MIN_POSITIVE {
            return None;
        }
        let e = l + l.transpose();
        let gamma = (0.5f64).sqrt() * e.norm();
        if gamma <= f64::MIN_POSITIVE {
            return None; // purely skew Ḟ (rigid rotation rate): no viscous stress
        }
        Some(Self {
            e,
            gamma,
            h,
            power: rate_power(gamma, h),
        })
    }
}

/// γ̇^(h−1), exactly 1 for the Newtonian h = 1 without calling pow (a tenth of a motion
/// simulation's time went to pow(γ̇, 0) in every element of every assembly).
fn rate_power(gamma: f64, h: f64) -> f64 {
    if h == 1.0 {
        1.0
    } else {
        gamma.powf(h - 1.0)
    }
}

/// σ = ν γ̇^(h−1) E.
pub fn stress(r: &Rate, nu: f64) -> Matrix3<f64> {
    r.e * (nu * r.power)
}

/// ∂σ/∂ν = γ̇^(h−1) E.
pub fn stress_dnu(r: &Rate) -> Matrix3<f64> {
    r.e * r.power
}

/// ∂σ/∂h = ν ln γ̇ γ̇^(h−1) E.
pub fn stress_dh(r: &Rate, nu: f64) -> Matrix3<f64> {
    r.e * (nu * r.gamma.ln() * r.power)
}

/// Damping tangent D_e = −∂f_e/∂v_e (12 × 12, row-major).
///
/// dσ = ν [ (h−1) γ̇^(h−2) dγ̇ E + γ̇^(h−1) dE ], dE = dḞ + dḞᵀ, dγ̇ = E : dE / (2γ̇). With
/// dḞ = e_j ∇φ_bᵀ, w_b = E ∇φ_b and g_ab = ∇φ_a·∇φ_b this is, in closed form,
/// D\[3a+i\]\[3b+j\] = V ν [ (h−1) γ̇^(h−3) w_a,i w_b,j + γ̇^(h−1) (δ_ij g_ab + ∇φ_b,i ∇φ_a,j) ].
pub fn element_damping(t: &RestTet, r: &Rate, nu: f64) -> [[f64; 12]; 12] {
    let mut d = [[0.0; 12]; 12];
    let (gh1, h) = (r.power, r.h);
    let c1 = t.volume * nu * (h - 1.0) * gh1 / (r.gamma * r.gamma);
    let c2 = t.volume * nu * gh1;
    let w: [Vector3<f64>; 4] = std::array::from_fn(|a| r.e * t.grad[a]);
    // Symmetric: the upper triangle is evaluated and mirrored.
    for a in 0..4 {
        for b in a..4 {
            let gab = t.grad[a].dot(&t.grad[b]);
            for i in 0..3 {
                for j in if a == b { i..3 } else { 0..3 } {
                    let mut val = c1 * w[a][i] * w[b][j] + c2 * t.grad[b][i] * t.grad[a][j];
                    if i == j {
                        val += c2 * gab;
                    }
                    d[3 * a + i][3 * b + j] = val;
                    d[3 * b + j][3 * a + i] = val;
                }
            }
        }
    }
    d
}

#[cfg(test)]
mod tests {
    use super::super::hyperelastic::add_stress_forces;
    use super::super::hyperelastic::tests::{central_pair, tet};
    use super::*;

    /// The damping tangent is minus the Jacobian of the viscous forces (central differences,
    /// h = 1e-9 m/s on velocities of ~0.1 m/s: truncation ~1e-12 relative, round-off ~1e-7).
    #[test]
    fn damping_tangent_matches_finite_differences_shear_thinning_and_thickening() {
        let (t, _) = tet();
        let v0 = [
            Vector3::new(0.1, -0.05, 0.02),
            Vector3::new(-0.03, 0.08, 0.0),
            Vector3::new(0.0, 0.01, -0.07),
            Vector3::new(0.05, 0.0, 0.04),
        ];
        for (nu, h) in [(8.0, 0.8), (12.0, 1.0), (5.0, 1.4)] {
            let force = |v: &[Vector3<f64>; 4]| {
                let mut f = [0.0; 12];
                if let Some(r) = Rate::new(&velocity_gradient(&t, v), h) {
                    add_stress_forces(&t, &stress(&r, nu), 1.0, &mut f);
                }
                f
            };
            let r = Rate::new(&velocity_gradient(&t, &v0), h).unwrap();
            let d = element_damping(&t, &r, nu);
            let eps = 1e-9;
            for c in 0..12 {
                let (vp, vm) = central_pair(&v0, c, eps);
                let (fp, fm) = (force(&vp), force(&vm));
                for row in 0..12 {
                    let fd = -(fp[row] - fm[row]) / (2.0 * eps);
                    assert!(
                        (d[row][c] - fd).abs() < 1e-5 * (d[row][c].abs() + 1e-3),
                        "h={h} D[{row}][{c}]"
                    );
                }
            }
        }
    }
}
