//! Linear tetrahedron kernels (seed 000 §3.1.5–3.1.6, §3.4): shape-function gradients, B_e, V_e,
//! C_e = V_e B_eᵀ F B_e and D_e = V_e B_eᵀ G B_e, and K_e = λ_e C_e + α_e D_e.
//!
//! This module is the one implementation of the element maths: the runtime calls it in `f32`, the
//! fitter in `f64`. Everything here is generic over nalgebra's [`RealField`] and allocation-free.
//!
//! Conventions: the 12-vector of an element stacks its four nodes' (x, y, z); strain is the
//! 6-vector (ε_xx, ε_yy, ε_zz, γ_xy, γ_yz, γ_zx) of eq. 3.3 with engineering shear strains.

use nalgebra::{Matrix3, RealField, SMatrix, SVector, Vector3};

/// Number of entries of a packed symmetric 12 × 12 matrix (upper triangle, row by row).
pub const PACKED_LEN: usize = 78;

/// 6 × 12 strain-displacement matrix B_e (eq. 3.17).
pub type StrainMatrix<T> = SMatrix<T, 6, 12>;
/// 12 × 12 element matrix.
pub type ElementMatrix<T> = SMatrix<T, 12, 12>;

/// Why an element cannot be used.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ElementDefect {
    /// Signed volume is not finite.
    NonFinite,
    /// |V_e| is below the tolerance relative to the element's edge length cubed (a flat sliver).
    ZeroVolume,
    /// Signed volume is negative: node order gives an inverted tetrahedron.
    Inverted,
}

/// Shape-function gradients ∇φ_i (eqs. 3.11–3.12) and rest volume V_e of one linear tetrahedron.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TetGeometry<T: RealField + Copy> {
    /// ∇φ_i for the four nodes; they sum to zero.
    pub grad: [Vector3<T>; 4],
    /// Rest volume V_e > 0.
    pub volume: T,
}

/// Signed volume of a tetrahedron, positive when (x1−x0, x2−x0, x3−x0) is right-handed.
pub fn signed_volume<T: RealField + Copy>(x: &[Vector3<T>; 4]) -> T {
    let dm = Matrix3::from_columns(&[x[1] - x[0], x[2] - x[0], x[3] - x[0]]);
    dm.determinant() / T::from_f64(6.0).unwrap()
}

/// Shape-function gradients and volume of the rest tetrahedron `x` (eqs. 3.11–3.12).
///
/// φ_i(x) = a_i x + b_i y + c_i z + d_i with φ_i(x_j) = δ_ij; the gradients (a_i, b_i, c_i) are the
/// rows of D_m⁻¹ (D_m = [x1−x0, x2−x0, x3−x0]) for nodes 1..3, and ∇φ_0 = −Σ ∇φ_i.
/// Rejects inverted, non-finite and flat elements (|V| < 1e-9 · ℓ³, ℓ the longest edge).
pub fn tet_geometry<T: RealField + Copy>(
    x: &[Vector3<T>; 4],
) -> Result<TetGeometry<T>, ElementDefect> {
    let dm = Matrix3::from_columns(&[x[1] - x[0], x[2] - x[0], x[3] - x[0]]);
    let six_v = dm.determinant();
    if !six_v.is_finite() {
        return Err(ElementDefect::NonFinite);
    }
    let mut longest = T::zero();
    for i in 0..4 {
        for j in (i + 1)..4 {
            longest = longest.max((x[j] - x[i]).norm());
        }
    }
    let tol = T::from_f64(6e-9).unwrap() * longest * longest * longest;
    if six_v.abs() <= tol {
        return Err(ElementDefect::ZeroVolume);
    }
    if six_v < T::zero() {
        return Err(ElementDefect::Inverted);
    }
    let inv = dm.try_inverse().ok_or(ElementDefect::ZeroVolume)?;
    let g1 = inv.row(0).transpose();
    let g2 = inv.row(1).transpose();
    let g3 = inv.row(2).transpose();
    let g0 = -(g1 + g2 + g3);
    Ok(TetGeometry {
        grad: [g0, g1, g2, g3],
        volume: six_v / T::from_f64(6.0).unwrap(),
    })
}

/// B_e (eq. 3.17): rows (ε_xx, ε_yy, ε_zz, γ_xy, γ_yz, γ_zx), columns (u0x, u0y, u0z, u1x, …).
pub fn strain_matrix<T: RealField + Copy>(g: &TetGeometry<T>) -> StrainMatrix<T> {
    let mut b = StrainMatrix::<T>::zeros();
    for (a, grad) in g.grad.iter().enumerate() {
        let (bx, by, bz) = (grad.x, grad.y, grad.z);
        let c = 3 * a;
        b[(0, c)] = bx;
        b[(1, c + 1)] = by;
        b[(2, c + 2)] = bz;
        b[(3, c)] = by;
        b[(3, c + 1)] = bx;
        b[(4, c + 1)] = bz;
        b[(4, c + 2)] = by;
        b[(5, c)] = bz;
        b[(5, c + 2)] = bx;
    }
    b
}

/// The constant matrix F of eq. 3.33.
pub fn material_f<T: RealField + Copy>() -> SMatrix<T, 6, 6> {
    let h = T::from_f64(0.5).unwrap();
    SMatrix::<T, 6, 6>::from_diagonal(&SVector::<T, 6>::from([
        T::one(),
        T::one(),
        T::one(),
        h,
        h,
        h,
    ]))
}

/// The constant matrix G of eq. 3.34.
pub fn material_g<T: RealField + Copy>() -> SMatrix<T, 6, 6> {
    let mut g = SMatrix::<T, 6, 6>::zeros();
    for i in 0..3 {
        for j in 0..3 {
            g[(i, j)] = if i == j { -T::one() } else { T::one() };
        }
        g[(i + 3, i + 3)] = -T::one();
    }
    g
}

/// C_e = V_e B_eᵀ F B_e and D_e = V_e B_eᵀ G B_e (eq. 3.63).
pub fn element_cd<T: RealField + Copy>(g: &TetGeometry<T>) -> (ElementMatrix<T>, ElementMatrix<T>) {
    let b = strain_matrix(g);
    let bt = b.transpose();
    let c = (bt * material_f::<T>() * b) * g.volume;
    let d = (bt * material_g::<T>() * b) * g.volume;
    (c, d)
}

/// K_e = λ_e C_e + α_e D_e (eq. 3.63).
pub fn element_stiffness<T: RealField + Copy>(
    g: &TetGeometry<T>,
    lambda: T,
    alpha: T,
) -> ElementMatrix<T> {
    let (c, d) = element_cd(g);
    c * lambda + d * alpha
}

/// Index of (i, j) in the packed upper triangle of a symmetric 12 × 12 matrix.
#[inline]
pub const fn packed_index(i: usize, j: usize) -> usize {
    let (r, c) = if i <= j { (i, j) } else { (j, i) };
    // Row r starts after rows 0..r, which hold 12, 11, …, 13 − r entries.
    r * 12 - (r * r.saturating_sub(1)) / 2 + (c - r)
}

/// Packs the upper triangle of a symmetric 12 × 12 matrix row by row into 78 values.
pub fn pack_symmetric<T: RealField + Copy>(m: &ElementMatrix<T>, out: &mut [T; PACKED_LEN]) {
    let mut k = 0;
    for i in 0..12 {
        for j in i..12 {
            out[k] = m[(i, j)];
            k += 1;
        }
    }
}

/// Inverse of [`pack_symmetric`].
pub fn unpack_symmetric<T: RealField + Copy>(p: &[T; PACKED_LEN]) -> ElementMatrix<T> {
    let mut m = ElementMatrix::<T>::zeros();
    let mut k = 0;
    for i in 0..12 {
        for j in i..12 {
            m[(i, j)] = p[k];
            m[(j, i)] = p[k];
            k += 1;
        }
    }
    m
}

/// Deformation gradient F = Σ_a x_a ∇φ_aᵀ of a linear tetrahedron at positions `x`.
///
/// Always inlined: the fitters' element passes call it once per element, and the compiler's own
/// choice can leave it out of line, where it cost 6 % of a static diagnosis.
#[inline(always)]
pub fn deformation_gradient<T: RealField + Copy>(
    g: &TetGeometry<T>,
    x: &[Vector3<T>; 4],
) -> Matrix3<T> {
    let mut f = Matrix3::<T>::zeros();
    for (xa, ga) in x.iter().zip(g.grad.iter()) {
        f += xa * ga.transpose();
    }
    f
}

/// Unrotated element strain ε_e = B_e (R_eᵀ x_e − x_0e) (eq. 3.49), as a 6-vector with engineering
/// shear. Computed from F as sym(RᵀF) − I, which equals eq. 3.49 because B_e applied to the rest
/// positions gives the identity gradient.
#[inline]
pub fn warped_strain<T: RealField + Copy>(r: &Matrix3<T>, f: &Matrix3<T>) -> SVector<T, 6> {
    let h = r.transpose() * f;
    let one = T::one();
    SVector::<T, 6>::from([
        h[(0, 0)] - one,
        h[(1, 1)] - one,
        h[(2, 2)] - one,
        h[(0, 1)] + h[(1, 0)],
        h[(1, 2)] + h[(2, 1)],
        h[(2, 0)] + h[(0, 2)],
    ])
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::SymmetricEigen;

    fn reference_tet() -> [Vector3<f64>; 4] {
        [
            Vector3::new(0.01, -0.02, 0.0),
            Vector3::new(0.05, 0.0, 0.01),
            Vector3::new(0.0, 0.04, 0.005),
            Vector3::new(0.015, 0.01, 0.045),
        ]
    }

    /// The textbook isotropic element stiffness, written without this module's B_e, F, G or
    /// `tet_geometry`: the shape functions from the inverse of the 4 × 4 matrix [1 x y z] of the
    /// corners, and K_(ai)(bj) = V (λ_L ∂_iφ_a ∂_jφ_b + μ ∂_jφ_a ∂_iφ_b + μ δ_ij ∇φ_a·∇φ_b),
    /// the component form of V BᵀDB for Hooke's law σ = λ_L tr(ε) I + 2με, with Lamé's λ_L and
    /// μ from E and ν by the textbook formulas.
    fn textbook_stiffness(x: &[Vector3<f64>; 4], young: f64, nu: f64) -> ElementMatrix<f64> {
        let lame = young * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
        let mu = young / (2.0 * (1.0 + nu));
        let mut a = nalgebra::Matrix4::<f64>::zeros();
        for (r, p) in x.iter().enumerate() {
            a[(r, 0)] = 1.0;
            a[(r, 1)] = p.x;
            a[(r, 2)] = p.y;
            a[(r, 3)] = p.z;
        }
        let volume = a.determinant().abs() / 6.0;
        // φ_b(x) = Σ_k coef[(k, b)] [1 x y z]_k: column b of A⁻¹ holds φ_b's coefficients.
        let coef = a.try_inverse().expect("non-degenerate test tetrahedron");
        let grad = |b: usize, i: usize| coef[(i + 1, b)];
        let mut k = ElementMatrix::<f64>::zeros();
        for a_ in 0..4 {
            for b in 0..4 {
                let dot: f64 = (0..3).map(|m| grad(a_, m) * grad(b, m)).sum();
                for i in 0..3 {
                    for j in 0..3 {
                        let delta = if i == j { 1.0 } else { 0.0 };
                        k[(3 * a_ + i, 3 * b + j)] = volume
                            * (lame * grad(a_, i) * grad(b, j)
                                + mu * grad(a_, j) * grad(b, i)
                                + mu * delta * dot);
                    }
                }
            }
        }
        k
    }

    /// K_e = λC_e + αD_e (eqs. 3.33–3.34, 3.63, with λ, α from E, ν by eqs. 3.41–3.42) is the
    /// isotropic linear-elastic element stiffness of the textbook, computed independently above:
    /// a wrong entry of F or G, a wrong shear factor in B_e or a wrong volume shows here (and not
    /// in a finite-difference check of an energy built from the same B_e, F, G and V).
    #[test]
    fn stiffness_equals_textbook_isotropic_btdb() {
        let x = reference_tet();
        let g = tet_geometry(&x).unwrap();
        for (young, nu) in [(20e3, 0.35), (1e5, 0.0), (5e3, 0.49), (3e4, -0.3)] {
            let lambda = young / ((1.0 + nu) * (1.0 - 2.0 * nu));
            let k = element_stiffness(&g, lambda, lambda * nu);
            let reference = textbook_stiffness(&x, young, nu);
            // Both are sums of a few products of the same magnitudes: round-off is ~1e-15 of
            // the largest entry; 1e-12 leaves room and still sees any wrong coefficient.
            let worst = (k - reference).amax() / reference.amax();
            assert!(
                worst < 1e-12,
                "E = {young}, ν = {nu}: relative mismatch {worst:e}"
            );
        }
    }

    #[test]
    fn c_and_d_are_symmetric_with_rigid_modes_in_null_space() {
        let g = tet_geometry(&reference_tet()).unwrap();
        let (c, d) = element_cd(&g);
        for m in [&c, &d] {
            assert!((m - m.transpose()).amax() < 1e-12 * m.amax());
        }
        // Rigid modes: three translations and three infinitesimal rotations ω × x.
        let x = reference_tet();
        let mut modes = [[0.0f64; 12]; 6];
        for a in 0..4 {
            for k in 0..3 {
                modes[k][3 * a + k] = 1.0;
            }
            for (r, axis) in [Vector3::x(), Vector3::y(), Vector3::z()]
                .iter()
                .enumerate()
            {
                let v = axis.cross(&x[a]);
                for k in 0..3 {
                    modes[3 + r][3 * a + k] = v[k];
                }
            }
        }
        for m in [&c, &d] {
            for mode in &modes {
                let v = SVector::<f64, 12>::from_column_slice(mode);
                assert!(
                    (m * v).amax() < 1e-10 * m.amax(),
                    "rigid mode not in null space"
                );
            }
        }
        // C is positive semi-definite (F is positive definite): 6 zero and 6 positive eigenvalues.
        let ev = SymmetricEigen::new(c).eigenvalues;
        let mut ev: Vec<f64> = ev.iter().copied().collect();
        ev.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let top = ev[11];
        assert!(ev[..6].iter().all(|v| v.abs() < 1e-10 * top), "{ev:?}");
        assert!(ev[6..].iter().all(|v| *v > 1e-6 * top), "{ev:?}");
        // K = λC + αD is positive semi-definite for physical parameters (E > 0, −1 < ν < 0.5).
        for nu in [-0.9, 0.0, 0.3, 0.49] {
            let lambda = 1.0 / ((1.0 + nu) * (1.0 - 2.0 * nu));
            let k = c * lambda + d * (lambda * nu);
            let ev = SymmetricEigen::new(k).eigenvalues;
            assert!(ev.iter().all(|v| *v > -1e-9 * ev.amax()), "ν = {nu}: {ev}");
        }
    }

    #[test]
    fn shape_gradients_reproduce_linear_fields_and_reject_bad_elements() {
        let x = reference_tet();
        let g = tet_geometry(&x).unwrap();
        // ∇φ of a linear interpolant of φ(x) = a·x + b is a.
        let a = Vector3::new(0.3, -1.2, 2.0);
        let grad: Vector3<f64> = (0..4).map(|i| g.grad[i] * (a.dot(&x[i]) + 0.7)).sum();
        assert!((grad - a).norm() < 1e-12);
        let mut inv = x;
        inv.swap(1, 2);
        assert_eq!(tet_geometry(&inv), Err(ElementDefect::Inverted));
        let flat = [x[0], x[1], x[2], (x[0] + x[1]) * 0.5];
        assert_eq!(tet_geometry(&flat), Err(ElementDefect::ZeroVolume));
        let mut nan = x;
        nan[3].x = f64::NAN;
        assert_eq!(tet_geometry(&nan), Err(ElementDefect::NonFinite));
    }

    #[test]
    fn gradient_kernel_equals_packed_c_d_kernel() {
        // The runtime's matrix-free σ∇φ kernel must be the same operator as λC_e + αD_e.
        let x = reference_tet();
        let g = tet_geometry(&x).unwrap();
        let (lambda, alpha) = (14_000.0, 4_000.0);
        let k = element_stiffness(&g, lambda, alpha);
        let grad32: [f32; 9] = core::array::from_fn(|i| g.grad[1 + i / 3][i % 3] as f32);
        let r = [1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        let v: [[f32; 3]; 4] =
            core::array::from_fn(|a| core::array::from_fn(|k| ((3 * a + k) as f32 * 0.37).sin()));
        let y = crate::kernel::warped_apply(
            &v,
            &grad32,
            &r,
            g.volume as f32,
            lambda as f32,
            alpha as f32,
        );
        let mut vv = SVector::<f64, 12>::zeros();
        for i in 0..12 {
            vv[i] = v[i / 3][i % 3] as f64;
        }
        let yr = k * vv;
        for i in 0..12 {
            assert!(
                (y[i / 3][i % 3] as f64 - yr[i]).abs() < 1e-5 * yr.amax(),
                "{i}: {} vs {}",
                y[i / 3][i % 3],
                yr[i]
            );
        }
        let mut cp = [0.0f64; PACKED_LEN];
        let mut dp = [0.0f64; PACKED_LEN];
        let (c, d) = element_cd(&g);
        pack_symmetric(&c, &mut cp);
        pack_symmetric(&d, &mut dp);
        let c32 = cp.map(|v| v as f32);
        let d32 = dp.map(|v| v as f32);
        let yp =
            crate::kernel::warped_apply_packed(&v, &c32, &d32, &r, lambda as f32, alpha as f32);
        for i in 0..12 {
            assert!((yp[i / 3][i % 3] as f64 - yr[i]).abs() < 1e-5 * yr.amax());
        }
    }

    #[test]
    fn packed_index_matches_pack_order() {
        let mut k = 0;
        for i in 0..12 {
            for j in i..12 {
                assert_eq!(packed_index(i, j), k);
                assert_eq!(packed_index(j, i), k);
                k += 1;
            }
        }
        assert_eq!(k, PACKED_LEN);
    }
}
