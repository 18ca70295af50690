//! The words every report, table and JSON document of palpate uses for material parameters, so
//! that one symbol means one thing everywhere.
//!
//! - **Lamé's λ and μ** (Pa), **Young's modulus E** (Pa) and **Poisson's ratio ν**: what every
//!   report prints.
//! - **The thesis coefficients (λ_F, α_G)** (Pa): the pair the linear static fit solves for and
//!   the runtime stores (Bächer 2008, eqs. 3.36–3.37, where they are called λ and α). Its first
//!   member is *not* Lamé's λ, so it is never printed as "λ" next to E and ν.
//! - **viscosity** (Pa·s^h): the power-law viscosity coefficient of the motion model (Hahn et al.
//!   2019, eq. 17, where it is called ν — not Poisson's ratio).

use palpate_runtime::material::LambdaAlpha;

/// The heading under which the thesis pair appears in reports.
pub const THESIS_PAIR: &str = "thesis coefficients (λ_F, α_G)";

/// One sentence saying what the thesis pair is, printed wherever it appears.
pub const THESIS_PAIR_NOTE: &str = "λ_F and α_G are the two coefficients of the thesis' element \
    stiffness K = λ_F·F + α_G·G (Bächer 2008, eqs. 3.36–3.37, where they are written λ and α): \
    λ_F = E/((1+ν)(1−2ν)) and α_G = ν·λ_F, which equals Lamé's λ; they are what the linear static \
    fit solves for and the runtime stores, not Lamé's (λ, μ).";

/// Lamé's first parameter λ = α_G of a thesis pair (Pa).
pub fn lame_lambda(p: &LambdaAlpha) -> f64 {
    p.alpha
}

/// Lamé's (λ, μ), E and ν of a thesis pair, the four numbers every report prints.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Elastic {
    /// Lamé's first parameter λ (Pa).
    pub lame_lambda_pa: f64,
    /// Shear modulus μ, Lamé's second parameter (Pa).
    pub shear_modulus_pa: f64,
    /// Young's modulus E (Pa).
    pub young_modulus_pa: f64,
    /// Poisson's ratio ν.
    pub poisson_ratio: f64,
}

impl Elastic {
    /// From the thesis pair.
    pub fn of(p: &LambdaAlpha) -> Self {
        Self {
            lame_lambda_pa: lame_lambda(p),
            shear_modulus_pa: p.shear_modulus(),
            young_modulus_pa: p.young(),
            poisson_ratio: p.poisson(),
        }
    }
    /// From Lamé's (λ, μ).
    pub fn from_lame(lambda: f64, mu: f64) -> Self {
        Self::of(&LambdaAlpha::from_lame(lambda, mu))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lame_of_the_thesis_pair() {
        // E = 12 kPa, ν = 0.3: λ = Eν/((1+ν)(1−2ν)) = 5769.2 Pa, μ = E/(2(1+ν)) = 4615.4 Pa.
        let e = Elastic::of(&LambdaAlpha::from_young_poisson(12_000.0, 0.3));
        assert!((e.lame_lambda_pa - 12_000.0 * 0.3 / (1.3 * 0.4)).abs() < 1e-8);
        assert!((e.shear_modulus_pa - 12_000.0 / 2.6).abs() < 1e-8);
        assert!((e.young_modulus_pa - 12_000.0).abs() < 1e-8);
        assert!((e.poisson_ratio - 0.3).abs() < 1e-12);
        let back = Elastic::from_lame(e.lame_lambda_pa, e.shear_modulus_pa);
        assert!((back.young_modulus_pa - 12_000.0).abs() < 1e-8);
    }
}
