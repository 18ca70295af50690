//! Material non-linearity: the elastic law replaced by a hyperelastic one, in uniaxial
//! incompressible form with stretch λ = 1 + Δ/L0 (= 1 + ε), nominal stress P:
//! - Neo-Hookean: P = μ (λ − λ⁻²);
//! - Mooney–Rivlin: P = 2 (λ − λ⁻²)(C10 + C01/λ);
//! - Yeoh: P = 2 (λ − λ⁻²)(C10 + 2 C20 (I₁ − 3) + 3 C30 (I₁ − 3)²), I₁ = λ² + 2/λ;
//! - Ogden (one term): P = (2μ/α)(λ^(α−1) − λ^(−α/2−1)) (α = 2 is Neo-Hookean);
//! - Ogden (two terms): the sum of two such terms (μ1, α1, μ2, α2).
//!
//! Its parameters are the law's moduli (linear in the prediction: MPa, or for tension data, whose
//! cross-section is unknown, effective force scales A0·μ in N), the Ogden exponents, and L0 (mm)
//! when the gauge length is not given. A law replaces the current one only if its complexity
//! rank is at least as high. The residual against the load magnitude (curvature) points to it.

use super::{CurveEffect, Values};
use crate::curve::model::{Family, Model, Param};
use crate::curve::read::Group;

/// The elastic law of a mechanical model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Law {
    /// Force ∝ displacement (stress ∝ strain).
    Linear,
    /// Neo-Hookean.
    NeoHookean,
    /// Two-parameter Mooney–Rivlin.
    MooneyRivlin,
    /// One-term Ogden.
    Ogden,
    /// Three-term Yeoh.
    Yeoh,
    /// Two-term Ogden.
    Ogden2,
}

impl Law {
    /// Name.
    pub fn name(self) -> &'static str {
        match self {
            Law::Linear => "linear",
            Law::NeoHookean => "neo-hookean",
            Law::MooneyRivlin => "mooney-rivlin",
            Law::Ogden => "ogden",
            Law::Yeoh => "yeoh",
            Law::Ogden2 => "ogden-2",
        }
    }
    /// Complexity rank: a law replaces the current one only if its rank is at least as high.
    pub fn rank(self) -> usize {
        match self {
            Law::Linear => 0,
            Law::NeoHookean => 1,
            Law::MooneyRivlin | Law::Ogden => 2,
            Law::Yeoh => 3,
            Law::Ogden2 => 4,
        }
    }
    /// Names of the moduli (the parameters the stress is linear in).
    pub fn moduli(self) -> &'static [&'static str] {
        match self {
            Law::Linear => &["k"],
            Law::NeoHookean => &["mu"],
            Law::MooneyRivlin => &["C10", "C01"],
            Law::Ogden => &["mu"],
            Law::Yeoh => &["C10", "C20", "C30"],
            Law::Ogden2 => &["mu1", "mu2"],
        }
    }
}

/// Every hyperelastic law of the library.
pub const HYPERELASTIC: [Law; 5] = [
    Law::NeoHookean,
    Law::MooneyRivlin,
    Law::Ogden,
    Law::Yeoh,
    Law::Ogden2,
];

/// Nominal (first Piola) uniaxial stress of an incompressible hyperelastic law at stretch λ,
/// with moduli `c` (see the module list).
pub fn elastic(law: Law, c: &[f64], alpha: [f64; 2], lam: f64) -> f64 {
    let d = lam - lam.powi(-2);
    match law {
        Law::Linear => c[0] * (lam - 1.0),
        Law::NeoHookean => c[0] * d,
        Law::MooneyRivlin => 2.0 * d * (c[0] + c[1] / lam),
        Law::Yeoh => {
            let i1 = lam * lam + 2.0 / lam - 3.0;
            2.0 * d * (c[0] + 2.0 * c[1] * i1 + 3.0 * c[2] * i1 * i1)
        }
        Law::Ogden => ogden_term(c[0], alpha[0], lam),
        Law::Ogden2 => ogden_term(c[0], alpha[0], lam) + ogden_term(c[1], alpha[1], lam),
    }
}

/// One Ogden term (2μ/α)(λ^(α−1) − λ^(−α/2−1)), guarded at α → 0 where it tends to
/// 3 μ ln λ / λ.
fn ogden_term(mu: f64, alpha: f64, lam: f64) -> f64 {
    if alpha.abs() < 1e-6 {
        3.0 * mu * lam.ln() / lam
    } else {
        2.0 * mu / alpha * (lam.powf(alpha - 1.0) - lam.powf(-alpha / 2.0 - 1.0))
    }
}

/// See the module: the candidate of one law.
pub struct Hyperelastic(pub Law);

/// The candidate of `law`.
pub(super) fn of(law: Law) -> &'static Hyperelastic {
    match law {
        Law::Linear => &Hyperelastic(Law::Linear),
        Law::NeoHookean => &Hyperelastic(Law::NeoHookean),
        Law::MooneyRivlin => &Hyperelastic(Law::MooneyRivlin),
        Law::Ogden => &Hyperelastic(Law::Ogden),
        Law::Yeoh => &Hyperelastic(Law::Yeoh),
        Law::Ogden2 => &Hyperelastic(Law::Ogden2),
    }
}

impl CurveEffect for Hyperelastic {
    fn name(&self) -> String {
        format!("hyperelastic-{}", self.0.name())
    }

    fn words(&self) -> &'static str {
        "material non-linearity (hyperelastic stiffening/softening)"
    }

    fn available(&self, m: &Model, _groups: usize, _rate_info: bool) -> bool {
        m.family.mechanical() && self.0 != m.law && self.0.rank() >= m.law.rank()
    }

    fn add_to(&self, m: &mut Model) {
        m.law = self.0;
    }

    fn params(&self, m: &Model, out: &mut Vec<Param>) {
        if m.law != self.0 {
            return;
        }
        let tension = matches!(m.family, Family::Tension { .. });
        let unit = if tension {
            "N (effective: modulus × unknown area)"
        } else {
            "MPa"
        };
        for name in self.0.moduli() {
            out.push(Param::new(name, unit, false, true, 1.0));
        }
        if self.0 == Law::Ogden {
            out.push(Param::new("alpha", "1", false, false, 2.0));
        }
        if self.0 == Law::Ogden2 {
            out.push(Param::new("alpha1", "1", false, false, 2.0));
            out.push(Param::new("alpha2", "1", false, false, -2.0));
        }
        if m.gauge_fitted() {
            let start = m.scale.x_max.max(1e-9);
            out.push(Param::new("L0", "mm", true, false, start));
        }
    }

    fn alternatives(&self, p: &Param, m: &Model) -> Option<Vec<f64>> {
        let x = m.scale.x_max.max(1e-9);
        match p.name.as_str() {
            "L0" => Some(vec![x, x / 3.0, 3.0 * x]),
            "alpha" | "alpha1" => Some(vec![2.0, 5.0, -2.0]),
            "alpha2" => Some(vec![-2.0, 8.0, 1.0]),
            _ => None,
        }
    }

    fn elastic(
        &self,
        m: &Model,
        val: &Values<'_>,
        gauge: Option<f64>,
        g: &Group,
        pe: &mut Vec<f64>,
    ) -> Option<()> {
        if m.law != self.0 {
            return Some(());
        }
        let c: Vec<f64> = self
            .0
            .moduli()
            .iter()
            .map(|m| val(m))
            .collect::<Option<_>>()?;
        let l0 = gauge.or_else(|| val("L0")).unwrap_or(1.0);
        let alpha = match self.0 {
            Law::Ogden2 => [val("alpha1")?, val("alpha2")?],
            _ => [val("alpha").unwrap_or(2.0), 0.0],
        };
        for &x in &g.x {
            let lam = 1.0 + x / l0;
            if lam < 0.05 {
                return None;
            }
            pe.push(elastic(self.0, &c, alpha, lam));
        }
        Some(())
    }
}
