//! Isotropic material parameters and their conversions (seed 000 §3.2, eqs. 3.36–3.42).
//!
//! The thesis parameterises E = λF + αG with λ = E/((1+ν)(1−2ν)) and α = λν, which is linear in
//! the parameters. In Lamé terms α is Lamé's first constant and the shear modulus is μ = λ/2 − α.

/// Thesis parameters (λ, α) of E = λF + αG.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LambdaAlpha {
    /// λ = E/((1+ν)(1−2ν)) (eq. 3.36), Pa.
    pub lambda: f64,
    /// α = λν (eq. 3.37): Lamé's first constant, Pa.
    pub alpha: f64,
}

impl LambdaAlpha {
    /// From Young's modulus E (Pa) and Poisson ratio ν (eqs. 3.41–3.42).
    pub fn from_young_poisson(young: f64, poisson: f64) -> Self {
        let lambda = young / ((1.0 + poisson) * (1.0 - 2.0 * poisson));
        Self {
            lambda,
            alpha: lambda * poisson,
        }
    }
    /// From the Lamé constants (λ_L, μ): α = λ_L and λ = 2μ + 2λ_L.
    pub fn from_lame(lame_lambda: f64, mu: f64) -> Self {
        Self {
            lambda: 2.0 * mu + 2.0 * lame_lambda,
            alpha: lame_lambda,
        }
    }
    /// Poisson ratio ν = α/λ (eq. 3.39).
    pub fn poisson(&self) -> f64 {
        self.alpha / self.lambda
    }
    /// Young's modulus E = λ(1+ν)(1−2ν) (eq. 3.40).
    pub fn young(&self) -> f64 {
        let nu = self.poisson();
        self.lambda * (1.0 + nu) * (1.0 - 2.0 * nu)
    }
    /// Shear modulus μ = λ/2 − α.
    pub fn shear_modulus(&self) -> f64 {
        0.5 * self.lambda - self.alpha
    }
    /// True when E > 0 and −1 < ν < 0.5, i.e. the element matrix is positive definite on
    /// non-rigid motions.
    pub fn is_physical(&self) -> bool {
        let nu = self.poisson();
        self.lambda.is_finite()
            && self.alpha.is_finite()
            && self.lambda > 0.0
            && nu > -1.0
            && nu < 0.5
    }
}

/// Shear modulus μ = λ/2 − α of thesis parameters (f32, for the runtime's hot loop).
#[inline]
pub fn shear_modulus_f32(lambda: f32, alpha: f32) -> f32 {
    0.5 * lambda - alpha
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_young_poisson() {
        let p = LambdaAlpha::from_young_poisson(12_000.0, 0.3);
        assert!((p.young() - 12_000.0).abs() < 1e-9 * 12_000.0);
        assert!((p.poisson() - 0.3).abs() < 1e-12);
        // μ = E / (2(1+ν))
        assert!((p.shear_modulus() - 12_000.0 / 2.6).abs() < 1e-9 * 12_000.0);
        let lame = 12_000.0 * 0.3 / (1.3 * 0.4);
        let q = LambdaAlpha::from_lame(lame, 12_000.0 / 2.6);
        assert!((q.lambda - p.lambda).abs() < 1e-9 * p.lambda);
        assert!((q.alpha - p.alpha).abs() < 1e-9 * p.alpha);
    }
}
