//! Neo-Hookean element kernel (Real2Sim eq. 16) with an optional strain-stiffening term.
//!
//! Ψ(F) = λ/2 ((J² − 1)/2 − ln J) + μ/2 (tr(FᵀF) − 3 − 2 ln J) + c (Ī₁ − 3)²,
//! I₁ = tr(FᵀF), Ī₁ = J^(−2/3) I₁.
//!
//! The last term is palpate's addition (c = 0 gives the paper's model), the second-order term of
//! Yeoh's model on the isochoric invariant: it stiffens the response to distortion at large strain
//! without changing the small-strain moduli (Ī₁ − 3 is second order in the strain, so its stress
//! and tangent vanish at F = I), which is what the specimen generator needs to make a visibly
//! non-linear object. (The first version used I₁ itself: I₁ − 3 ≈ 2 tr ε is first order for a
//! compressible material, so c (I₁ − 3)² added 8c to λ at small strain — with c = 20 μ it made a
//! ν = 0.35 block nearly incompressible instead of non-linear, a change a fitted E and ν absorb.)
//! Element forces are f_a = −V_e P ∇φ_a (P = ∂Ψ/∂F, ∇φ_a the rest shape-function gradients) and
//! the tangent is K_e = −∂f/∂x. This file is the one implementation used by the dynamic motion
//! simulator and the quasi-static solver [`super::statics`].

use super::MotionError;
use nalgebra::{Matrix3, Vector3};
use palpate_fem::mesh::Mesh;

/// Material constants of one element for the hyperelastic kernel (Pa).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HyperParams {
    /// Lamé's first parameter λ.
    pub lambda: f64,
    /// Shear modulus μ.
    pub mu: f64,
    /// Strain-stiffening coefficient c of the c (Ī₁ − 3)² term (0 = pure Neo-Hookean).
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

impl RestTet {
    /// The rest geometry of every tetrahedron of `mesh` (the runtime's element maths); a
    /// degenerate one is [`MotionError::BadElement`].
    pub fn of_mesh(mesh: &Mesh) -> Result<Vec<Self>, MotionError> {
        mesh.tets
            .iter()
            .enumerate()
            .map(|(e, t)| {
                let x = t.map(|n| Vector3::from(mesh.nodes[n]));
                let g = palpate_runtime::element::tet_geometry(&x).map_err(|d| {
                    MotionError::BadElement {
                        element: e,
                        why: format!("{d:?}"),
                    }
                })?;
                Ok(Self {
                    grad: g.grad,
                    volume: g.volume,
                })
            })
            .collect()
    }

    /// A 1 cm tetrahedron of no special shape, and its rest corners: the fixture of the
    /// element tests here, in `viscosity` and in the cross-crate spline tests (public so that
    /// they share one element rather than copies of its corners).
    pub fn sample() -> (Self, [Vector3<f64>; 4]) {
        let x = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(0.01, 0.0, 0.0),
            Vector3::new(0.002, 0.012, 0.0),
            Vector3::new(0.001, 0.003, 0.011),
        ];
        let g = palpate_runtime::element::tet_geometry(&x).expect("the sample tet is regular");
        (
            Self {
                grad: g.grad,
                volume: g.volume,
            },
            x,
        )
    }
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
    let bar = j.powf(-2.0 / 3.0) * i1 - 3.0;
    Some(
        0.5 * p.lambda * ((j * j - 1.0) / 2.0 - lnj)
            + 0.5 * p.mu * (i1 - 3.0 - 2.0 * lnj)
            + p.stiffening * bar * bar,
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
        // F⁻ᵀ = cof(F)/J, the cofactor matrix's columns being the cross products of F's
        // other two columns: one pass for J and F⁻ᵀ (a general inverse and a transpose were 5 %
        // of a motion fit).
        let (c0, c1, c2) = (f.column(0), f.column(1), f.column(2));
        let cof = Matrix3::from_columns(&[c1.cross(&c2), c2.cross(&c0), c0.cross(&c1)]);
        let j = c0.dot(&cof.column(0));
        if j.is_nan() || j <= 0.0 {
            return None;
        }
        let f_inv_t = cof / j;
        if !f_inv_t.iter().all(|z| z.is_finite()) {
            return None;
        }
        Some(Self {
            f,
            f_inv_t,
            j,
            i1: f.norm_squared(),
        })
    }

    /// J^(−2/3), by cbrt (a third of pow's cost). Only the stiffening term needs it, so it is
    /// evaluated there and not for every element of every Neo-Hookean assembly, where the cbrt
    /// alone was 7 % of a motion fit's time.
    pub fn j23(&self) -> f64 {
        let c = self.j.cbrt();
        1.0 / (c * c)
    }

    /// Ī₁ − 3 with Ī₁ = J^(−2/3) I₁.
    fn bar(&self) -> f64 {
        self.j23() * self.i1 - 3.0
    }

    /// ∂Ī₁/∂F = J^(−2/3) (2F − ⅔ I₁ F⁻ᵀ).
    fn dbar(&self) -> Matrix3<f64> {
        (self.f * 2.0 - self.f_inv_t * (2.0 / 3.0 * self.i1)) * self.j23()
    }
}

/// First Piola–Kirchhoff stress P = λ/2 (J² − 1) F⁻ᵀ + μ (F − F⁻ᵀ) + 2c (Ī₁ − 3) ∂Ī₁/∂F.
pub fn pk1(s: &FParts, p: &HyperParams) -> Matrix3<f64> {
    let mut out = s.f_inv_t * (0.5 * p.lambda * (s.j * s.j - 1.0)) + (s.f - s.f_inv_t) * p.mu;
    if p.stiffening != 0.0 {
        out += s.dbar() * (2.0 * p.stiffening * s.bar());
    }
    out
}

/// ∂P/∂λ = ½ (J² − 1) F⁻ᵀ.
pub fn pk1_dlambda(s: &FParts) -> Matrix3<f64> {
    s.f_inv_t * (0.5 * (s.j * s.j - 1.0))
}

/// ∂P/∂μ = F − F⁻ᵀ.
pub fn pk1_dmu(s: &FParts) -> Matrix3<f64> {
    s.f - s.f_inv_t
}

/// ∂P/∂c = 2 (Ī₁ − 3) ∂Ī₁/∂F (the stiffening coefficient's).
pub fn pk1_dstiffening(s: &FParts) -> Matrix3<f64> {
    s.dbar() * (2.0 * s.bar())
}

/// Directional derivative dP\[dF\].
///
/// d(F⁻ᵀ) = −F⁻ᵀ dFᵀ F⁻ᵀ, dJ = J tr(F⁻¹ dF), dI₁ = 2 F : dF, and for the stiffening term
/// d(∂Ī₁/∂F) = J^(−2/3) [−⅔ (F⁻ᵀ:dF)(2F − ⅔ I₁ F⁻ᵀ) + 2 dF − ⅔ dI₁ F⁻ᵀ − ⅔ I₁ d(F⁻ᵀ)].
pub fn dpk1(s: &FParts, p: &HyperParams, df: &Matrix3<f64>) -> Matrix3<f64> {
    let d_finv_t = -(s.f_inv_t * df.transpose() * s.f_inv_t);
    let tr = s.f_inv_t.component_mul(df).sum(); // tr(F⁻¹ dF)
    let dj2 = 2.0 * s.j * s.j * tr;
    let mut out = s.f_inv_t * (0.5 * p.lambda * dj2)
        + d_finv_t * (0.5 * p.lambda * (s.j * s.j - 1.0))
        + (df - d_finv_t) * p.mu;
    if p.stiffening != 0.0 {
        let g = s.dbar();
        let di1 = 2.0 * s.f.component_mul(df).sum();
        let dg = ((s.f * 2.0 - s.f_inv_t * (2.0 / 3.0 * s.i1)) * (-2.0 / 3.0 * tr) + df * 2.0
            - s.f_inv_t * (2.0 / 3.0 * di1)
            - d_finv_t * (2.0 / 3.0 * s.i1))
            * s.j23();
        out += g * (2.0 * p.stiffening * g.component_mul(df).sum())
            + dg * (2.0 * p.stiffening * s.bar());
    }
    out
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
/// K\[3a+i\]\[3b+j\] = V [ μ δ_ij g_ab + λJ² h_a,i h_b,j − c h_b,i h_a,j
///                     + 2c_s G_a,i G_b,j + 2c_s (Ī₁ − 3) J^(−2/3) (2 δ_ij g_ab
///                       − ⁴⁄₃ (f_a,i h_b,j + h_a,i f_b,j) + ⁴⁄₉ I₁ h_a,i h_b,j + ⅔ I₁ h_b,i h_a,j) ]
/// with G_a = (∂Ī₁/∂F) ∇φ_a.
/// (The per-direction evaluation through `dpk1` was the motion simulator's hottest loop.)
pub fn element_tangent(t: &RestTet, s: &FParts, p: &HyperParams) -> [[f64; 12]; 12] {
    // Without the stiffening term (the paper's model, and every fit that has not adopted it) its
    // four products per entry are zero; a copy of the loop compiled without them is the one the
    // simpler models run.
    if p.stiffening == 0.0 {
        tangent_entries::<false>(t, s, p)
    } else {
        tangent_entries::<true>(t, s, p)
    }
}

/// [`element_tangent`]'s entries, with the stiffening terms when `STIFFENING`.
#[inline(always)]
fn tangent_entries<const STIFFENING: bool>(
    t: &RestTet,
    s: &FParts,
    p: &HyperParams,
) -> [[f64; 12]; 12] {
    let h: [Vector3<f64>; 4] = std::array::from_fn(|a| s.f_inv_t * t.grad[a]);
    let j2 = s.j * s.j;
    let c = 0.5 * p.lambda * (j2 - 1.0) - p.mu;
    let lj2 = p.lambda * j2;
    let (fg, gs, ks, kb) = if STIFFENING {
        let g = s.dbar();
        let ks = 2.0 * p.stiffening;
        (
            std::array::from_fn(|a| s.f * t.grad[a]),
            std::array::from_fn(|a| g * t.grad[a]),
            ks,
            ks * s.bar() * s.j23(),
        )
    } else {
        ([Vector3::zeros(); 4], [Vector3::zeros(); 4], 0.0, 0.0)
    };
    let diag = p.mu + 2.0 * kb;
    let v = t.volume;
    let mut k = [[0.0; 12]; 12];
    // K_e is symmetric: the upper triangle is evaluated and mirrored (half the arithmetic of
    // the hottest loop of a motion fit, and exactly symmetric).
    for a in 0..4 {
        for b in a..4 {
            let gab = t.grad[a].dot(&t.grad[b]);
            for i in 0..3 {
                for jj in if a == b { i..3 } else { 0..3 } {
                    let mut val = lj2 * h[a][i] * h[b][jj] - c * h[b][i] * h[a][jj];
                    if STIFFENING {
                        val += ks * gs[a][i] * gs[b][jj]
                            + kb * (-4.0 / 3.0 * (fg[a][i] * h[b][jj] + h[a][i] * fg[b][jj])
                                + 4.0 / 9.0 * s.i1 * h[a][i] * h[b][jj]
                                + 2.0 / 3.0 * s.i1 * h[b][i] * h[a][jj]);
                    }
                    if i == jj {
                        val += diag * gab;
                    }
                    k[3 * a + i][3 * b + jj] = v * val;
                    k[3 * b + jj][3 * a + i] = v * val;
                }
            }
        }
    }
    k
}

/// [`element_tangent`]'s closed form at one quadrature point of a quadratic (10-node) element,
/// ∇φ_a the ten shape-function gradients there and V the point's weight, added into the 30 × 30
/// `k` (row-major, node-major dofs) where b ≥ a: the node-block upper triangle, which holds the
/// symmetric matrix (the entries below it are left as they are). Each row (a, i) is
///
///   K\[3a+i\]\[3b+j\] += s_ai h_b,j + g_ai G_b,j + t_ai f_b,j + e (h_b,i h_a,j) + δ_ij V d g_ab
///
/// with s_ai = V((λJ² + ⁴⁄₉ k I₁) h_a,i − ⁴⁄₃ k f_a,i), g_ai = 2V c_s G_a,i, t_ai = −⁴⁄₃ V k h_a,i,
/// e = V(⅔ k I₁ − c), d = μ + 2k and k = 2c_s (Ī₁ − 3) J^(−2/3) ([`element_tangent`]'s terms
/// grouped by column): every row is a sum of 30-vectors from column 3a on, so the loops run over
/// contiguous columns in SIMD lanes — cheaper this way than the upper triangle entry by entry.
pub(crate) fn quadratic_point_tangent(
    grad: &[Vector3<f64>; 10],
    volume: f64,
    s: &FParts,
    p: &HyperParams,
    k: &mut [[f64; 30]; 30],
) {
    if p.stiffening == 0.0 {
        point_tangent_rows::<false>(grad, volume, s, p, k)
    } else {
        point_tangent_rows::<true>(grad, volume, s, p, k)
    }
}

/// [`quadratic_point_tangent`]'s rows, with the stiffening terms when `STIFFENING`.
#[inline(always)]
fn point_tangent_rows<const STIFFENING: bool>(
    grad: &[Vector3<f64>; 10],
    v: f64,
    s: &FParts,
    p: &HyperParams,
    k: &mut [[f64; 30]; 30],
) {
    // Node-major 30-vectors of h_b = F⁻ᵀ ∇φ_b, f_b = F ∇φ_b and G_b = (∂Ī₁/∂F) ∇φ_b, and for
    // each direction i the vector (h_b,i) repeated over j.
    let flat = |m: &Matrix3<f64>| -> [f64; 30] {
        let mut out = [0.0; 30];
        for (b, g) in grad.iter().enumerate() {
            let w = m * g;
            out[3 * b..3 * b + 3].copy_from_slice(w.as_slice());
        }
        out
    };
    let h = flat(&s.f_inv_t);
    let hi: [[f64; 30]; 3] =
        std::array::from_fn(|i| std::array::from_fn(|col| h[3 * (col / 3) + i]));
    let j2 = s.j * s.j;
    let c = 0.5 * p.lambda * (j2 - 1.0) - p.mu;
    let (fg, gs, ks, kb) = if STIFFENING {
        let ks = 2.0 * p.stiffening;
        (flat(&s.f), flat(&s.dbar()), ks, ks * s.bar() * s.j23())
    } else {
        ([0.0; 30], [0.0; 30], 0.0, 0.0)
    };
    let sh = v * (p.lambda * j2 + 4.0 / 9.0 * kb * s.i1);
    let e = v * (2.0 / 3.0 * kb * s.i1 - c);
    let d = v * (p.mu + 2.0 * kb);
    for a in 0..10 {
        // (h_a,j) repeated over b.
        let ha: [f64; 30] = std::array::from_fn(|col| h[3 * a + col % 3]);
        for i in 0..3 {
            let row = &mut k[3 * a + i];
            let sa = sh * h[3 * a + i];
            if STIFFENING {
                let sa = sa - v * 4.0 / 3.0 * kb * fg[3 * a + i];
                let ga = v * ks * gs[3 * a + i];
                let ta = -v * 4.0 / 3.0 * kb * h[3 * a + i];
                for col in 3 * a..30 {
                    row[col] +=
                        sa * h[col] + ga * gs[col] + ta * fg[col] + e * hi[i][col] * ha[col];
                }
            } else {
                for col in 3 * a..30 {
                    row[col] += sa * h[col] + e * hi[i][col] * ha[col];
                }
            }
            for (b, gb) in grad.iter().enumerate().skip(a) {
                row[3 * b + i] += d * grad[a].dot(gb);
            }
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A 1 cm tetrahedron of no special shape, and its corners ([`RestTet::sample`]).
    pub(crate) fn tet() -> (RestTet, [Vector3<f64>; 4]) {
        RestTet::sample()
    }

    /// The corners moved by ±`h` along coordinate `c` (node c / 3, axis c % 3): the two points
    /// of a central difference.
    pub(crate) fn central_pair(
        x: &[Vector3<f64>; 4],
        c: usize,
        h: f64,
    ) -> ([Vector3<f64>; 4], [Vector3<f64>; 4]) {
        let (mut xp, mut xm) = (*x, *x);
        xp[c / 3][c % 3] += h;
        xm[c / 3][c % 3] -= h;
        (xp, xm)
    }

    /// The test material (λ = 3e4 Pa, μ = 1e4 Pa, soft-tissue order) with stiffening `c`.
    fn material(stiffening: f64) -> HyperParams {
        HyperParams {
            lambda: 3e4,
            mu: 1e4,
            stiffening,
        }
    }

    /// Forces are minus the energy gradient and the tangent is minus the force Jacobian; central
    /// differences with h = 1e-8 m on a 1 cm element are accurate to ~1e-6 relative.
    #[test]
    fn forces_and_tangent_match_finite_differences() {
        let (t, x0) = tet();
        let p = material(5e3);
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
            let (xp, xm) = central_pair(&x, c, h);
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
        let p = material(5e3);
        let f = element_forces(&t, &x, &p).unwrap();
        assert!(f.iter().all(|v| v.abs() < 1e-12));
        let mut xi = x;
        xi[3][2] = -0.011;
        assert!(element_forces(&t, &xi, &p).is_none());
    }

    /// dP[dF] against central differences of P (h = 1e-7 on a deformation of order 0.2; accurate
    /// to ~1e-7 relative, asserted 1e-6) for a general dF, with the stiffening term on.
    #[test]
    fn dpk1_matches_finite_differences() {
        let p = material(5e4);
        let f = Matrix3::new(1.1, 0.2, -0.05, 0.03, 0.92, 0.1, -0.08, 0.05, 1.15);
        let df = Matrix3::new(0.3, -0.1, 0.2, 0.05, 0.4, -0.25, 0.1, 0.15, -0.2);
        let s = FParts::new(f).unwrap();
        let h = 1e-7;
        let pp = pk1(&FParts::new(f + df * h).unwrap(), &p);
        let pm = pk1(&FParts::new(f - df * h).unwrap(), &p);
        let fd = (pp - pm) / (2.0 * h);
        let an = dpk1(&s, &p, &df);
        assert!(
            (an - fd).norm() < 1e-6 * fd.norm(),
            "dP {an} vs finite differences {fd}"
        );
    }

    /// The stiffening term leaves the small-strain moduli alone: at F = I the tangent with c = 5 μ
    /// equals the Neo-Hookean one (to round-off, 1e-9 relative); at 30 % simple shear it is
    /// stiffer (the secant shear stress P₁₂ grows by more than 10 %).
    #[test]
    fn stiffening_changes_large_strains_only() {
        let (t, x) = tet();
        let (plain, stiff) = (material(0.0), material(5e4));
        let s = FParts::new(deformation_gradient(&t, &x)).unwrap();
        let (k0, k1) = (
            element_tangent(&t, &s, &plain),
            element_tangent(&t, &s, &stiff),
        );
        let scale = k0.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
        for r in 0..12 {
            for c in 0..12 {
                assert!((k0[r][c] - k1[r][c]).abs() < 1e-9 * scale, "K[{r}][{c}]");
            }
        }
        let shear = FParts::new(Matrix3::new(1.0, 0.3, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)).unwrap();
        let (p0, p1) = (pk1(&shear, &plain)[(0, 1)], pk1(&shear, &stiff)[(0, 1)]);
        assert!(p1 > 1.1 * p0, "shear stress {p1} vs Neo-Hookean {p0}");
    }
}
