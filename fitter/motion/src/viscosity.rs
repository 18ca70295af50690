//! Power-law viscosity (Real2Sim eq. 17): σ = ν γ̇^(h−1) (∇v + ∇vᵀ), γ̇ = √½ ‖∇v + ∇vᵀ‖_F.
//!
//! h = 1 is Newtonian, h < 1 shear thinning, h > 1 shear thickening. Two readings of ∇v
//! ([`Form`]):
//! - **Rest gradient** (the default): ∇v is taken with the rest shape-function gradients
//!   (Ḟ = Σ_a v_a ∇φ_aᵀ) as in the paper's public code, so the viscous force depends on the
//!   velocities only (its position derivative is zero) and the stress acts like a first
//!   Piola–Kirchhoff stress: f_a = −V σ ∇φ_a. It is not objective: an element already turned by
//!   θ and turning at θ̇ has Ḟ + Ḟᵀ ≈ 2θθ̇ W² ≠ 0, so a cantilever hanging at its static slope
//!   is damped for swinging as a rigid body.
//! - **Objective**: the same law on the Green–Lagrange strain rate Ė = ½(FᵀḞ + ḞᵀF), the second
//!   Piola–Kirchhoff stress S = ν γ̇^(h−1) 2Ė with γ̇ = √½ ‖2Ė‖_F, and P = F S (the finite-strain
//!   Kelvin–Voigt solid; Holzapfel, *Nonlinear Solid Mechanics*, §6.10): a rigid motion of any
//!   element dissipates nothing, and at small strain it is the rest-gradient law. Its force
//!   depends on the positions too, and [`element_stiffness`] is that derivative.
//!
//! Elements whose ‖Ḟ‖_F ≤ f64::MIN_POSITIVE are skipped, as the paper does (the shear-thinning
//! stress is undefined there but tends to 0), and so, under the objective form, are rigidly
//! moving elements (γ̇ = 0). The power γ̇^(h−1) is read in Carreau's form (γ̇² + γ̇₀²)^((h−1)/2)
//! with γ̇₀ = [`CARREAU_RATE`]: the power law above γ̇₀, a Newtonian plateau at ν γ̇₀^(h−1) below
//! it, smooth between, so that an element at rest does not get an unbounded viscosity from its
//! round-off rate and Newton's iteration does not meet a kink in the tangent.
//!
//! In the closed forms below p = (γ̇² + γ̇₀²)^((h−1)/2) is that power ([`Rate::power`], γ̇^(h−1)
//! of the pure law) and p′ = (h−1) p / (γ̇² + γ̇₀²) its slope factor ((h−1) γ̇^(h−3) of the pure
//! law): dp = p′ γ̇ dγ̇.

/// How ∇v of eq. 17 is read (see the module's documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Form {
    /// Ḟ through the rest gradients, as Real2Sim's public code: not objective.
    #[default]
    RestGradient,
    /// The Green–Lagrange strain rate, P = F S: objective.
    Objective,
}

impl Form {
    /// Its name in dataset.toml and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::RestGradient => "rest-gradient",
            Self::Objective => "objective",
        }
    }

    /// Parses [`Self::name`].
    pub fn parse(s: &str) -> Option<Self> {
        [Self::RestGradient, Self::Objective]
            .into_iter()
            .find(|f| f.name() == s)
    }
}

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
    /// Under the objective form, F and Ḟ (E is then FᵀḞ + ḞᵀF and the stress F S).
    pub at: Option<(Matrix3<f64>, Matrix3<f64>)>,
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
            at: None,
        })
    }

    /// Under the objective form: from the deformation gradient F, the velocity gradient Ḟ and h;
    /// `None` where the element moves rigidly (γ̇ = 0) or not at all.
    pub fn objective(f: &Matrix3<f64>, l: &Matrix3<f64>, h: f64) -> Option<Self> {
        if l.norm() <= f64::MIN_POSITIVE {
            return None;
        }
        let ftl = f.transpose() * l;
        let e = ftl + ftl.transpose();
        let gamma = (0.5f64).sqrt() * e.norm();
        if gamma <= f64::MIN_POSITIVE {
            return None;
        }
        Some(Self {
            e,
            gamma,
            h,
            power: rate_power(gamma, h),
            at: Some((*f, *l)),
        })
    }

    /// In the form `form`, from F, Ḟ and h.
    pub fn of(form: Form, f: &Matrix3<f64>, l: &Matrix3<f64>, h: f64) -> Option<Self> {
        match form {
            Form::RestGradient => Self::new(l, h),
            Form::Objective => Self::objective(f, l, h),
        }
    }

    /// `scale` p′ with p′ = (h−1) p / (γ̇² + γ̇₀²) (see the module): the power's change
    /// dp = p′ (E : dE / 2) per change of E, the tangents' second term.
    fn power_slope(&self, scale: f64) -> f64 {
        scale * (self.h - 1.0) * self.power / carreau_square(self.gamma)
    }

    /// The first Piola–Kirchhoff form of a stress `s` of this rate's form: F s under the
    /// objective form (s a second Piola–Kirchhoff stress), s itself otherwise.
    fn pk1(&self, s: Matrix3<f64>) -> Matrix3<f64> {
        match &self.at {
            Some((f, _)) => f * s,
            None => s,
        }
    }
}

/// Under the objective form, −∂f_e/∂x_e of the viscous forces at fixed velocities (12 × 12,
/// row-major); `None` under the rest-gradient form, whose viscous force does not depend on the
/// positions.
///
/// dP = dF S + F dS with dE = dFᵀḞ + ḞᵀdF. With dF = e_j ∇φ_bᵀ, g_a = ∇φ_a, g_ab = g_a·g_b,
/// u_a = F g_a, z_a = F E g_a, q_a = Ḟ g_a, y_a = Ḟ E g_a and C = F Ḟᵀ this is, in closed form,
/// K\[3a+i\]\[3b+j\] = V ν [ p (δ_ij g_a·E g_b + u_b,i q_a,j + C_ij g_ab) + p′ z_a,i y_b,j ]
/// — not symmetric (p and p′: the module's notation).
pub fn element_stiffness(t: &RestTet, r: &Rate, nu: f64) -> Option<[[f64; 12]; 12]> {
    let (f, l) = r.at?;
    let g = &t.grad;
    let c1 = r.power_slope(t.volume * nu);
    let c2 = t.volume * nu * r.power;
    let w: [Vector3<f64>; 4] = std::array::from_fn(|a| r.e * g[a]);
    let u: [Vector3<f64>; 4] = std::array::from_fn(|a| f * g[a]);
    let z: [Vector3<f64>; 4] = std::array::from_fn(|a| f * w[a]);
    let q: [Vector3<f64>; 4] = std::array::from_fn(|a| l * g[a]);
    let y: [Vector3<f64>; 4] = std::array::from_fn(|a| l * w[a]);
    let c = f * l.transpose();
    let mut k = [[0.0; 12]; 12];
    for a in 0..4 {
        for b in 0..4 {
            let gab = g[a].dot(&g[b]);
            let sab = c2 * g[a].dot(&w[b]);
            for i in 0..3 {
                for j in 0..3 {
                    let mut val =
                        c1 * z[a][i] * y[b][j] + c2 * (u[b][i] * q[a][j] + c[(i, j)] * gab);
                    if i == j {
                        val += sab;
                    }
                    k[3 * a + i][3 * b + j] = val;
                }
            }
        }
    }
    Some(k)
}

/// The symmetric part ½(K + Kᵀ) of [`element_stiffness`]: what a symmetric system matrix can
/// hold of it.
pub fn element_stiffness_symmetric(t: &RestTet, r: &Rate, nu: f64) -> Option<[[f64; 12]; 12]> {
    let k = element_stiffness(t, r, nu)?;
    Some(std::array::from_fn(|i| {
        std::array::from_fn(|j| 0.5 * (k[i][j] + k[j][i]))
    }))
}

/// A tangent's moduli at one point: `A[3i + k][3j + l]` holds V ∂P_ik/∂G_jl, G the variable
/// (F for a stiffness, Ḟ for a damping) and V the point's volume, so that the tangent's entry of
/// node a's dof i and node b's dof j is Σ_kl ∇φ_a,k A\[3i+k\]\[3j+l\] ∇φ_b,l for any number of
/// nodes: how a quadratic element builds its 30 × 30 tangents (`add_moduli_rows` of the
/// quadratic statics).
pub type Moduli = [[f64; 9]; 9];

impl Rate {
    /// [`element_damping`]'s moduli at a point of volume `volume`, read off its closed forms:
    /// rest gradient V ν [p′ E_ik E_jl + p (δ_ij δ_kl + δ_il δ_jk)]; objective
    /// V ν [p′ (FE)_ik (FE)_jl + p ((FFᵀ)_ij δ_kl + F_il F_jk)]. Symmetric, as D is.
    pub fn damping_moduli(&self, nu: f64, volume: f64) -> Moduli {
        let c1 = self.power_slope(volume * nu);
        let c2 = volume * nu * self.power;
        let mut a = [[0.0; 9]; 9];
        let delta = |i: usize, j: usize| f64::from(u8::from(i == j));
        match &self.at {
            None => {
                let e = &self.e;
                for (r, row) in a.iter_mut().enumerate() {
                    let (i, k) = (r / 3, r % 3);
                    for (col, v) in row.iter_mut().enumerate() {
                        let (j, l) = (col / 3, col % 3);
                        *v = c1 * e[(i, k)] * e[(j, l)]
                            + c2 * (delta(i, j) * delta(k, l) + delta(i, l) * delta(j, k));
                    }
                }
            }
            Some((f, _)) => {
                let (m, b) = (f * self.e, f * f.transpose());
                for (r, row) in a.iter_mut().enumerate() {
                    let (i, k) = (r / 3, r % 3);
                    for (col, v) in row.iter_mut().enumerate() {
                        let (j, l) = (col / 3, col % 3);
                        *v = c1 * m[(i, k)] * m[(j, l)]
                            + c2 * (b[(i, j)] * delta(k, l) + f[(i, l)] * f[(j, k)]);
                    }
                }
            }
        }
        a
    }

    /// [`element_stiffness_symmetric`]'s moduli at a point of volume `volume`: the symmetric
    /// part ½(A + Aᵀ) of [`element_stiffness`]'s,
    /// V ν [p (δ_ij E_kl + F_il Ḟ_jk + (FḞᵀ)_ij δ_kl) + p′ (FE)_ik (ḞE)_jl]; `None` under the
    /// rest-gradient form.
    pub fn stiffness_moduli_symmetric(&self, nu: f64, volume: f64) -> Option<Moduli> {
        let (f, l) = self.at?;
        let c1 = self.power_slope(volume * nu);
        let c2 = volume * nu * self.power;
        let (m, y, c) = (f * self.e, l * self.e, f * l.transpose());
        let delta = |i: usize, j: usize| f64::from(u8::from(i == j));
        let entry = |r: usize, col: usize| {
            let (i, k, j, l_) = (r / 3, r % 3, col / 3, col % 3);
            c2 * (delta(i, j) * self.e[(k, l_)] + f[(i, l_)] * l[(j, k)] + c[(i, j)] * delta(k, l_))
                + c1 * m[(i, k)] * y[(j, l_)]
        };
        Some(std::array::from_fn(|r| {
            std::array::from_fn(|col| 0.5 * (entry(r, col) + entry(col, r)))
        }))
    }
}

/// The strain rate γ̇₀ (1/s) of the Carreau form of the power law (Carreau 1972; Bird,
/// Armstrong & Hassager, *Dynamics of Polymeric Liquids* vol. 1, ch. 4): the viscosity is
/// ν (γ̇² + γ̇₀²)^((h−1)/2), the power law ν γ̇^(h−1) well above γ̇₀ and a Newtonian plateau
/// ν γ̇₀^(h−1) below it.
///
/// The pure shear-thinning law's viscosity grows without bound as γ̇ → 0, and every element's
/// rate passes through zero at each turn of an oscillation: near rest at γ̇ its damping tangent
/// outweighs a neighbour's moving at γ̇₁ by (γ̇₁/γ̇)^(1−h), and at a strongly thinning index (h ≈ 0.15) a
/// step's Newton iteration, meeting that kink, needs a factorisation for nearly every iteration
/// and leaves steps unconverged. Near γ̇₀ the plateau still holds that kink's cost: Newton's
/// steps overshoot the elements whose rate should come to rest and are cut back by the line
/// search, an iteration at a time. 10⁻³/s is two to three decades below the rates at which the
/// law is read (a ring-down's 0.1–1/s) — a decimetre body strained at it moves 0.1 mm a second.
/// On a 1,300-tet cylinder's capture at h = 0.1–0.156 the markers move by 2.9–4.4 µm RMS
/// against γ̇₀ = 10⁻⁴/s (1–2 % of the capture's noise; its fitted h moves by a twentieth of its
/// 1σ) with 37–39 % of the factorisations, and a diagnosis that adopts the law takes 35–56 % less
/// time (BENCHMARKS.md, "The power law at a small index").
pub const CARREAU_RATE: f64 = 1e-3;

/// The power (γ̇² + γ̇₀²)^((h−1)/2) (γ̇^(h−1) above γ̇₀ = [`CARREAU_RATE`]), exactly 1 for the
/// Newtonian h = 1 without calling pow (a tenth of a motion simulation's time went to pow(γ̇, 0) in every
/// element of every assembly).
pub(crate) fn rate_power(gamma: f64, h: f64) -> f64 {
    if h == 1.0 {
        1.0
    } else {
        carreau_square(gamma).powf(0.5 * (h - 1.0))
    }
}

/// γ̇² + γ̇₀² of Carreau's form ([`CARREAU_RATE`]).
fn carreau_square(gamma: f64) -> f64 {
    gamma * gamma + CARREAU_RATE * CARREAU_RATE
}

/// σ = ν γ̇^(h−1) E (under the objective form P = F S, S = ν γ̇^(h−1) E).
pub fn stress(r: &Rate, nu: f64) -> Matrix3<f64> {
    r.pk1(r.e * (nu * r.power))
}

/// ∂σ/∂ν = γ̇^(h−1) E.
pub fn stress_dnu(r: &Rate) -> Matrix3<f64> {
    r.pk1(r.e * r.power)
}

/// ∂σ/∂h = ν ½ ln(γ̇² + γ̇₀²) (γ̇² + γ̇₀²)^((h−1)/2) E (ν ln γ̇ γ̇^(h−1) E above γ̇₀).
pub fn stress_dh(r: &Rate, nu: f64) -> Matrix3<f64> {
    r.pk1(r.e * (nu * 0.5 * carreau_square(r.gamma).ln() * r.power))
}

/// Damping tangent D_e = −∂f_e/∂v_e (12 × 12, row-major).
///
/// dσ = ν [ p′ γ̇ dγ̇ E + p dE ], dE = dḞ + dḞᵀ, dγ̇ = E : dE / (2γ̇) (p and p′: the module's
/// notation). With dḞ = e_j ∇φ_bᵀ, w_b = E ∇φ_b and g_ab = ∇φ_a·∇φ_b this is, in closed form,
/// D\[3a+i\]\[3b+j\] = V ν [ p′ w_a,i w_b,j + p (δ_ij g_ab + ∇φ_b,i ∇φ_a,j) ].
pub fn element_damping(t: &RestTet, r: &Rate, nu: f64) -> [[f64; 12]; 12] {
    // Under the objective form dE = FᵀdḞ + dḞᵀF and dP = F dS: the same two terms with
    // w_a → z_a = F E ∇φ_a, ∇φ_a → u_a = F ∇φ_a and δ_ij → B_ij = (F Fᵀ)_ij.
    if let Some((f, _)) = r.at {
        return objective_damping(t, r, nu, &f);
    }
    let mut d = [[0.0; 12]; 12];
    let gh1 = r.power;
    let c1 = r.power_slope(t.volume * nu);
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

/// [`element_damping`] under the objective form, in closed form:
/// D\[3a+i\]\[3b+j\] = V ν [ p′ z_a,i z_b,j + p (B_ij g_ab + u_b,i u_a,j) ]
/// with z_a = F E ∇φ_a, u_a = F ∇φ_a, B = F Fᵀ (symmetric, as the rest-gradient form's).
fn objective_damping(t: &RestTet, r: &Rate, nu: f64, f: &Matrix3<f64>) -> [[f64; 12]; 12] {
    let g = &t.grad;
    let c1 = r.power_slope(t.volume * nu);
    let c2 = t.volume * nu * r.power;
    let u: [Vector3<f64>; 4] = std::array::from_fn(|a| f * g[a]);
    let z: [Vector3<f64>; 4] = std::array::from_fn(|a| f * (r.e * g[a]));
    let bb = f * f.transpose();
    let mut d = [[0.0; 12]; 12];
    for a in 0..4 {
        for b in a..4 {
            let gab = g[a].dot(&g[b]);
            for i in 0..3 {
                for j in if a == b { i..3 } else { 0..3 } {
                    let val = c1 * z[a][i] * z[b][j] + c2 * (bb[(i, j)] * gab + u[b][i] * u[a][j]);
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

    /// Deformed corners of the sample element (a stretch, a shear and a turn) and velocities.
    fn deformed() -> (RestTet, [Vector3<f64>; 4], [Vector3<f64>; 4]) {
        let (t, x0) = tet();
        let turn = nalgebra::Rotation3::from_euler_angles(0.3, -0.2, 0.5);
        let stretch = Matrix3::new(1.1, 0.05, 0.0, 0.0, 0.95, 0.08, 0.02, 0.0, 1.03);
        let x = x0.map(|p| turn * (stretch * p));
        let v = [
            Vector3::new(0.1, -0.05, 0.02),
            Vector3::new(-0.03, 0.08, 0.0),
            Vector3::new(0.0, 0.01, -0.07),
            Vector3::new(0.05, 0.0, 0.04),
        ];
        (t, x, v)
    }

    /// The objective form's forces at (x, v).
    fn objective_forces(
        t: &RestTet,
        x: &[Vector3<f64>; 4],
        v: &[Vector3<f64>; 4],
        nu: f64,
        h: f64,
    ) -> [f64; 12] {
        let mut f = [0.0; 12];
        let fgrad = super::super::hyperelastic::deformation_gradient(t, x);
        if let Some(r) = Rate::objective(&fgrad, &velocity_gradient(t, v), h) {
            add_stress_forces(t, &stress(&r, nu), 1.0, &mut f);
        }
        f
    }

    /// Under the objective form both tangents are minus the Jacobians of the viscous forces, in
    /// the velocities (D) and in the positions (K), on an element stretched, sheared and turned
    /// (central differences as above).
    #[test]
    fn objective_tangents_match_finite_differences() {
        let (t, x0, v0) = deformed();
        let fgrad = super::super::hyperelastic::deformation_gradient(&t, &x0);
        for (nu, h) in [(8.0, 0.8), (12.0, 1.0), (5.0, 1.4)] {
            let r = Rate::objective(&fgrad, &velocity_gradient(&t, &v0), h).unwrap();
            let d = element_damping(&t, &r, nu);
            let k = element_stiffness(&t, &r, nu).expect("the objective form depends on x");
            let eps = 1e-9;
            for c in 0..12 {
                let (vp, vm) = central_pair(&v0, c, eps);
                let (xp, xm) = central_pair(&x0, c, eps);
                let (fvp, fvm) = (
                    objective_forces(&t, &x0, &vp, nu, h),
                    objective_forces(&t, &x0, &vm, nu, h),
                );
                let (fxp, fxm) = (
                    objective_forces(&t, &xp, &v0, nu, h),
                    objective_forces(&t, &xm, &v0, nu, h),
                );
                for row in 0..12 {
                    let fd = -(fvp[row] - fvm[row]) / (2.0 * eps);
                    assert!(
                        (d[row][c] - fd).abs() < 1e-5 * (d[row][c].abs() + 1e-3),
                        "h={h} D[{row}][{c}] {} against {fd}",
                        d[row][c]
                    );
                    let fd = -(fxp[row] - fxm[row]) / (2.0 * eps);
                    assert!(
                        (k[row][c] - fd).abs() < 1e-5 * (k[row][c].abs() + 1e-3),
                        "h={h} K[{row}][{c}] {} against {fd}",
                        k[row][c]
                    );
                }
            }
        }
    }

    /// dS for a change dE of E at fixed ν: ν [dp E + p dE] with p = (γ̇² + γ̇₀²)^((h−1)/2),
    /// dp = (h−1) p γ̇ dγ̇ / (γ̇² + γ̇₀²), dγ̇ = E : dE / (2γ̇).
    fn stress_change(r: &Rate, nu: f64, de: &Matrix3<f64>) -> Matrix3<f64> {
        let dgamma = r.e.dot(de) / (2.0 * r.gamma);
        let dpower = (r.h - 1.0) * r.power * r.gamma / carreau_square(r.gamma) * dgamma;
        (r.e * dpower + de * r.power) * nu
    }

    /// M\[3a+i\]\[3b+j\] = V (dP(e_j ∇φ_bᵀ) ∇φ_a)_i of a map dP linear in a change of F or Ḟ
    /// made by node b's dof j: the tangents built from twelve directional derivatives.
    fn directional(t: &RestTet, dp: impl Fn(&Matrix3<f64>) -> Matrix3<f64>) -> [[f64; 12]; 12] {
        let mut m = [[0.0; 12]; 12];
        for b in 0..4 {
            for j in 0..3 {
                let mut dl = Matrix3::zeros();
                for c in 0..3 {
                    dl[(j, c)] = t.grad[b][c];
                }
                let d = dp(&dl);
                for a in 0..4 {
                    let col = d * t.grad[a] * t.volume;
                    for i in 0..3 {
                        m[3 * a + i][3 * b + j] = col[i];
                    }
                }
            }
        }
        m
    }

    /// The closed forms of the objective tangents are the directional derivatives dP = F dS
    /// (velocities) and dP = dF S + F dS (positions), assembled column by column, to round-off.
    #[test]
    fn objective_closed_forms_are_the_directional_derivatives() {
        let (t, x0, v0) = deformed();
        let fgrad = super::super::hyperelastic::deformation_gradient(&t, &x0);
        for (nu, h) in [(8.0, 0.8), (12.0, 1.0), (5.0, 1.4)] {
            let r = Rate::objective(&fgrad, &velocity_gradient(&t, &v0), h).unwrap();
            let (f, l) = r.at.unwrap();
            let s = r.e * (nu * r.power);
            let d_ref = directional(&t, |dl| {
                let ftdl = f.transpose() * dl;
                f * stress_change(&r, nu, &(ftdl + ftdl.transpose()))
            });
            let k_ref = directional(&t, |df| {
                let dftl = df.transpose() * l;
                df * s + f * stress_change(&r, nu, &(dftl + dftl.transpose()))
            });
            let (d, k) = (
                element_damping(&t, &r, nu),
                element_stiffness(&t, &r, nu).unwrap(),
            );
            let scale =
                |m: &[[f64; 12]; 12]| m.iter().flatten().fold(0.0f64, |a, z| a.max(z.abs()));
            for (got, want, name) in [(&d, &d_ref, "D"), (&k, &k_ref, "K")] {
                for (row, (g, w)) in got.iter().zip(want).enumerate() {
                    for c in 0..12 {
                        assert!(
                            (g[c] - w[c]).abs() <= 1e-12 * scale(want),
                            "h={h} {name}[{row}][{c}] {} against {}",
                            g[c],
                            w[c]
                        );
                    }
                }
            }
        }
    }

    /// The Carreau form under both readings: well below γ̇₀ = [`CARREAU_RATE`] the law is
    /// Newtonian at ν γ̇₀^(h−1) (stress and damping tangent), well above it the pure power law,
    /// for a shear-thinning and a shear-thickening index.
    #[test]
    fn the_carreau_form_is_newtonian_below_the_floor_and_the_power_law_above() {
        let (t, x, v_unit) = deformed();
        let fgrad = super::super::hyperelastic::deformation_gradient(&t, &x);
        let nu = 30.0;
        let rate_of = |v: &[Vector3<f64>; 4], form: Form, h: f64| {
            Rate::of(form, &fgrad, &velocity_gradient(&t, v), h).unwrap()
        };
        for form in [Form::RestGradient, Form::Objective] {
            for h in [0.15, 1.4] {
                let g1 = rate_of(&v_unit, form, h).gamma;
                // γ̇ = γ̇₀/100: (1 + 10⁻⁴)^((h−1)/2) off the plateau, a relative 5e-5 at most.
                let v = v_unit.map(|p| p * (0.01 * CARREAU_RATE / g1));
                let r = rate_of(&v, form, h);
                let newtonian = rate_of(&v, form, 1.0);
                let plateau = nu * CARREAU_RATE.powf(h - 1.0);
                let want = stress(&newtonian, plateau);
                assert!(
                    (stress(&r, nu) - want).norm() <= 1e-4 * want.norm(),
                    "{form:?} h={h}: not the plateau"
                );
                let d = element_damping(&t, &r, nu);
                let dn = element_damping(&t, &newtonian, plateau);
                let scale = dn.iter().flatten().fold(0.0f64, |a, z| a.max(z.abs()));
                assert!(
                    d.iter()
                        .flatten()
                        .zip(dn.iter().flatten())
                        .all(|(a, b)| (a - b).abs() <= 1e-3 * scale),
                    "{form:?} h={h}: the damping tangent is not the Newtonian one"
                );
                // γ̇ = 100 γ̇₀: the pure law to the same relative 5e-5.
                let fast = rate_of(&v.map(|p| p * 1e4), form, h);
                let pure = fast.gamma.powf(h - 1.0);
                assert!(
                    (fast.power - pure).abs() <= 1e-4 * pure,
                    "{form:?} h={h}: {} against the power law's {pure}",
                    fast.power
                );
            }
        }
    }

    /// Where the Carreau form bends (γ̇ = 0.3, 1 and 3 γ̇₀) the damping tangent is minus the
    /// Jacobian of the viscous forces and ∂σ/∂h the index's derivative (central differences,
    /// relative steps 1e-6; round-off and truncation ~1e-9 relative, asserted 1e-6).
    #[test]
    fn near_the_floor_the_tangent_and_the_index_derivative_match_finite_differences() {
        let (t, x, v_unit) = deformed();
        let fgrad = super::super::hyperelastic::deformation_gradient(&t, &x);
        let nu = 30.0;
        for form in [Form::RestGradient, Form::Objective] {
            let g1 = Rate::of(form, &fgrad, &velocity_gradient(&t, &v_unit), 0.5)
                .unwrap()
                .gamma;
            for k in [0.3, 1.0, 3.0] {
                let v0 = v_unit.map(|p| p * (k * CARREAU_RATE / g1));
                let forces = |v: &[Vector3<f64>; 4], h: f64| {
                    let mut f = [0.0; 12];
                    let r = Rate::of(form, &fgrad, &velocity_gradient(&t, v), h).unwrap();
                    add_stress_forces(&t, &stress(&r, nu), 1.0, &mut f);
                    f
                };
                let h = 0.15;
                let r = Rate::of(form, &fgrad, &velocity_gradient(&t, &v0), h).unwrap();
                let d = element_damping(&t, &r, nu);
                let scale = d.iter().flatten().fold(0.0f64, |a, z| a.max(z.abs()));
                let speed = v0.iter().map(|p| p.norm()).fold(0.0, f64::max);
                let eps = 1e-6 * speed;
                for c in 0..12 {
                    let (vp, vm) = central_pair(&v0, c, eps);
                    let (fp, fm) = (forces(&vp, h), forces(&vm, h));
                    for row in 0..12 {
                        let fd = -(fp[row] - fm[row]) / (2.0 * eps);
                        assert!(
                            (d[row][c] - fd).abs() <= 1e-6 * scale,
                            "{form:?} γ̇ = {k} γ̇₀: D[{row}][{c}] {} against {fd}",
                            d[row][c]
                        );
                    }
                }
                let mut dh = [0.0; 12];
                add_stress_forces(&t, &stress_dh(&r, nu), 1.0, &mut dh);
                let (fp, fm) = (forces(&v0, h + 1e-6), forces(&v0, h - 1e-6));
                let big = dh.iter().fold(0.0f64, |a, z| a.max(z.abs()));
                for row in 0..12 {
                    let fd = (fp[row] - fm[row]) / 2e-6;
                    assert!(
                        (dh[row] - fd).abs() <= 1e-6 * big,
                        "{form:?} γ̇ = {k} γ̇₀: ∂f/∂h[{row}] {} against {fd}",
                        dh[row]
                    );
                }
            }
        }
    }

    /// The 12 × 12 tangent Σ_kl ∇φ_a,k A\[3i+k\]\[3j+l\] ∇φ_b,l of moduli `a` on a linear
    /// element (the moduli's contract, [`Moduli`]).
    pub(crate) fn from_moduli(t: &RestTet, a: &Moduli) -> [[f64; 12]; 12] {
        std::array::from_fn(|r| {
            std::array::from_fn(|c| {
                let (na, i, nb, j) = (r / 3, r % 3, c / 3, c % 3);
                let mut sum = 0.0;
                for k in 0..3 {
                    for l in 0..3 {
                        sum += t.grad[na][k] * a[3 * i + k][3 * j + l] * t.grad[nb][l];
                    }
                }
                sum
            })
        })
    }

    /// The moduli give the closed-form tangents back on a linear element, under both forms and
    /// for shear thinning, Newtonian and thickening indices, to round-off (1e-12 of the
    /// largest entry).
    #[test]
    fn the_moduli_are_the_closed_form_tangents() {
        let (t, x0, v0) = deformed();
        let fgrad = super::super::hyperelastic::deformation_gradient(&t, &x0);
        let close = |got: &[[f64; 12]; 12], want: &[[f64; 12]; 12], what: &str| {
            let scale = want.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(scale > 0.0, "{what}");
            for r in 0..12 {
                for c in 0..12 {
                    assert!(
                        (got[r][c] - want[r][c]).abs() < 1e-12 * scale,
                        "{what} [{r}][{c}]: {} against {}",
                        got[r][c],
                        want[r][c]
                    );
                }
            }
        };
        for (nu, h) in [(8.0, 0.8), (12.0, 1.0), (5.0, 1.4)] {
            let l = velocity_gradient(&t, &v0);
            let rest = Rate::new(&l, h).unwrap();
            let objective = Rate::objective(&fgrad, &l, h).unwrap();
            for (r, form) in [(&rest, "rest gradient"), (&objective, "objective")] {
                let d = from_moduli(&t, &r.damping_moduli(nu, t.volume));
                close(
                    &d,
                    &element_damping(&t, r, nu),
                    &format!("D, {form}, h={h}"),
                );
            }
            assert!(rest.stiffness_moduli_symmetric(nu, t.volume).is_none());
            let k = from_moduli(
                &t,
                &objective.stiffness_moduli_symmetric(nu, t.volume).unwrap(),
            );
            let want = element_stiffness_symmetric(&t, &objective, nu).unwrap();
            close(&k, &want, &format!("K, h={h}"));
        }
    }

    /// A rigid spin of a deformed element (Ḟ = W F) dissipates nothing under the objective form,
    /// and is damped under the rest-gradient form: the reason the objective form exists.
    #[test]
    fn a_rigid_spin_is_damped_only_by_the_rest_gradient_form() {
        let (t, x, _) = deformed();
        let fgrad = super::super::hyperelastic::deformation_gradient(&t, &x);
        let w = Matrix3::new(0.0, -2.0, 0.5, 2.0, 0.0, -1.0, -0.5, 1.0, 0.0);
        let v = x.map(|p| w * p);
        let l = velocity_gradient(&t, &v);
        assert!((l - w * fgrad).norm() < 1e-12 * l.norm());
        assert!(Rate::objective(&fgrad, &l, 1.0).is_none_or(|r| stress(&r, 1.0).norm() < 1e-12));
        let r = Rate::new(&l, 1.0).expect("the rest-gradient form sees a rate");
        assert!(
            stress(&r, 1.0).norm() > 0.1 * l.norm(),
            "{}",
            stress(&r, 1.0)
        );
        // At rest (F = I) the two forms agree.
        let l = velocity_gradient(
            &t,
            &[
                Vector3::new(0.1, 0.0, 0.02),
                Vector3::zeros(),
                Vector3::new(0.0, -0.04, 0.0),
                Vector3::new(0.01, 0.0, 0.0),
            ],
        );
        let (a, b) = (
            Rate::new(&l, 0.8).unwrap(),
            Rate::objective(&Matrix3::identity(), &l, 0.8).unwrap(),
        );
        assert!((stress(&a, 3.0) - stress(&b, 3.0)).norm() < 1e-14 * stress(&a, 3.0).norm());
    }
}
