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

/// Viscous stress state of one element; `None` when the element is skipped (‖Ḟ‖ ≤ MIN_POSITIVE).
#[derive(Debug, Clone, Copy)]
pub struct Rate {
    /// E = Ḟ + Ḟᵀ.
    pub e: Matrix3<f64>,
    /// γ̇ = √½ ‖E‖_F.
    pub gamma: f64,
}

impl Rate {
    /// From the velocity gradient.
    pub fn new(l: &Matrix3<f64>) -> Option<Self> {
        if l.norm() <= f64::MIN_POSITIVE {
            return None;
        }
        let e = l + l.transpose();
        let gamma = (0.5f64).sqrt() * e.norm();
        if gamma <= f64::MIN_POSITIVE {
            return None; // purely skew Ḟ (rigid rotation rate): no viscous stress
        }
        Some(Self { e, gamma })
    }
}

/// σ = ν γ̇^(h−1) E.
pub fn stress(r: &Rate, nu: f64, h: f64) -> Matrix3<f64> {
    r.e * (nu * r.gamma.powf(h - 1.0))
}

/// ∂σ/∂ν = γ̇^(h−1) E.
pub fn stress_dnu(r: &Rate, h: f64) -> Matrix3<f64> {
    r.e * r.gamma.powf(h - 1.0)
}

/// ∂σ/∂h = ν ln γ̇ γ̇^(h−1) E.
pub fn stress_dh(r: &Rate, nu: f64, h: f64) -> Matrix3<f64> {
    r.e * (nu * r.gamma.ln() * r.gamma.powf(h - 1.0))
}

/// Damping tangent D_e = −∂f_e/∂v_e (12 × 12, row-major).
///
/// dσ = ν [ (h−1) γ̇^(h−2) dγ̇ E + γ̇^(h−1) dE ], dE = dḞ + dḞᵀ, dγ̇ = E : dE / (2γ̇).
pub fn element_damping(t: &RestTet, r: &Rate, nu: f64, h: f64) -> [[f64; 12]; 12] {
    let mut d = [[0.0; 12]; 12];
    let gh1 = r.gamma.powf(h - 1.0);
    for b in 0..4 {
        for j in 0..3 {
            let mut ej = Vector3::zeros();
            ej[j] = 1.0;
            let dl = ej * t.grad[b].transpose();
            let de = dl + dl.transpose();
            let dg = r.e.component_mul(&de).sum() / (2.0 * r.gamma);
            let ds = r.e * (nu * (h - 1.0) * gh1 / r.gamma * dg) + de * (nu * gh1);
            for a in 0..4 {
                let col = ds * t.grad[a] * t.volume;
                for i in 0..3 {
                    d[3 * a + i][3 * b + j] = col[i];
                }
            }
        }
    }
    d
}

#[cfg(test)]
mod tests {
    use super::super::hyperelastic::add_stress_forces;
    use super::*;

    /// The damping tangent is minus the Jacobian of the viscous forces (central differences,
    /// h = 1e-9 m/s on velocities of ~0.1 m/s: truncation ~1e-12 relative, round-off ~1e-7).
    #[test]
    fn damping_tangent_matches_finite_differences_shear_thinning_and_thickening() {
        let x = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(0.01, 0.0, 0.0),
            Vector3::new(0.002, 0.012, 0.0),
            Vector3::new(0.001, 0.003, 0.011),
        ];
        let g = palpate_runtime::element::tet_geometry(&x).unwrap();
        let t = RestTet {
            grad: g.grad,
            volume: g.volume,
        };
        let v0 = [
            Vector3::new(0.1, -0.05, 0.02),
            Vector3::new(-0.03, 0.08, 0.0),
            Vector3::new(0.0, 0.01, -0.07),
            Vector3::new(0.05, 0.0, 0.04),
        ];
        for (nu, h) in [(8.0, 0.8), (12.0, 1.0), (5.0, 1.4)] {
            let force = |v: &[Vector3<f64>; 4]| {
                let mut f = [0.0; 12];
                if let Some(r) = Rate::new(&velocity_gradient(&t, v)) {
                    add_stress_forces(&t, &stress(&r, nu, h), 1.0, &mut f);
                }
                f
            };
            let r = Rate::new(&velocity_gradient(&t, &v0)).unwrap();
            let d = element_damping(&t, &r, nu, h);
            let eps = 1e-9;
            for c in 0..12 {
                let mut vp = v0;
                let mut vm = v0;
                vp[c / 3][c % 3] += eps;
                vm[c / 3][c % 3] -= eps;
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
