//! The elastic law of an element: Neo-Hookean (eq. 16, parameters λ, μ) or, when the material
//! carries response splines, the principal-stretch material of §4.2 (eqs. 18–20). Forces,
//! tangents and parameter derivatives of both go through this one switch.

use super::hyperelastic::{self as he, FParts, HyperParams, RestTet};
use super::model::{Material, ParamKind};
use super::spline::{SplineMaterial, StretchState};
use super::viscosity::Moduli;
use super::MotionError;
use nalgebra::Matrix3;

/// Kinematic state of one element under its elastic law.
// The spline state is larger (SVD + basis weights); it lives on the stack per element, never
// in collections, so boxing it would only add an allocation per element evaluation.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy)]
pub enum ElasticState<'a> {
    /// Neo-Hookean (eq. 16).
    NeoHookean(FParts, HyperParams),
    /// Principal-stretch splines (eq. 18).
    Spline(StretchState, &'a SplineMaterial),
}

impl<'a> ElasticState<'a> {
    /// State of element `e` at deformation gradient `f`; an inverted element is an error.
    pub fn new(mat: &'a Material, e: usize, f: Matrix3<f64>) -> Result<Self, MotionError> {
        match &mat.spline {
            Some(sp) => sp
                .state(&f)
                .map(|s| Self::Spline(s, sp))
                .ok_or(MotionError::Inverted { element: e }),
            None => {
                let s = FParts::new(f).ok_or(MotionError::Inverted { element: e })?;
                Ok(Self::NeoHookean(
                    s,
                    HyperParams {
                        lambda: mat.get(ParamKind::Lambda, e),
                        mu: mat.get(ParamKind::Mu, e),
                        stiffening: mat.get(ParamKind::Stiffening, e),
                    },
                ))
            }
        }
    }

    /// First Piola–Kirchhoff stress.
    pub fn pk1(&self) -> Matrix3<f64> {
        match self {
            Self::NeoHookean(s, p) => he::pk1(s, p),
            Self::Spline(s, _) => SplineMaterial::pk1(s),
        }
    }

    /// Directional derivative dP\[dF\] of the first Piola–Kirchhoff stress.
    pub fn dpk1(&self, df: &Matrix3<f64>) -> Matrix3<f64> {
        match self {
            Self::NeoHookean(s, p) => he::dpk1(s, p, df),
            Self::Spline(s, m) => m.dpk1(s, df),
        }
    }

    /// Element tangent K_e = −∂f_e/∂x_e (12 × 12).
    pub fn tangent(&self, t: &RestTet) -> [[f64; 12]; 12] {
        match self {
            Self::NeoHookean(s, p) => he::element_tangent(t, s, p),
            Self::Spline(s, m) => tangent_from(t, |df| m.dpk1(s, df)),
        }
    }

    /// The tangent's moduli V ∂P_ik/∂F_jl at a point of volume `volume` ([`Moduli`]), from
    /// nine directional derivatives: what a quadratic element's point builds its tangent from
    /// when the law has no row form of its own (the splines; Neo-Hookean has one in
    /// [`he`]).
    pub fn moduli(&self, volume: f64) -> Moduli {
        let mut a = [[0.0; 9]; 9];
        for col in 0..9 {
            let mut df = Matrix3::zeros();
            df[(col / 3, col % 3)] = 1.0;
            let dp = self.dpk1(&df);
            for (r, row) in a.iter_mut().enumerate() {
                row[col] = volume * dp[(r / 3, r % 3)];
            }
        }
        a
    }
}

/// K_e from a directional stress derivative dP\[dF\]: column (b, j) is V_e dP\[e_j ∇φ_bᵀ\] ∇φ_a.
pub fn tangent_from(t: &RestTet, dp: impl Fn(&Matrix3<f64>) -> Matrix3<f64>) -> [[f64; 12]; 12] {
    let mut k = [[0.0; 12]; 12];
    for b in 0..4 {
        for j in 0..3 {
            let mut df = Matrix3::zeros();
            for c in 0..3 {
                df[(j, c)] = t.grad[b][c];
            }
            let p = dp(&df);
            for a in 0..4 {
                let col = p * t.grad[a] * t.volume;
                for i in 0..3 {
                    k[3 * a + i][3 * b + j] = col[i];
                }
            }
        }
    }
    k
}
