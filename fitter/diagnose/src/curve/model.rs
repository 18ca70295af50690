//! The 1-D model library: an elastic law (linear, or hyperelastic in uniaxial form), optional
//! viscous branches integrated over the recorded time series, a zero offset, slack (tension only:
//! F = max(F_model, 0), the specimen buckles instead of carrying compression); for FSRs a divider
//! model with optional power-law response, conductance saturation, turn-on threshold and drift.
//!
//! Mechanical (tension: F in N against grip displacement Δ; stress–strain: nominal stress P against
//! engineering strain ε), uniaxial incompressible forms with stretch λ = 1 + Δ/L0 (= 1 + ε):
//! - linear: F = k Δ (P = E ε);
//! - Neo-Hookean: P = μ (λ − λ⁻²);
//! - Mooney–Rivlin: P = 2 (λ − λ⁻²)(C10 + C01/λ);
//! - Yeoh: P = 2 (λ − λ⁻²)(C10 + 2 C20 (I₁ − 3) + 3 C30 (I₁ − 3)²), I₁ = λ² + 2/λ;
//! - Ogden (one term): P = (2μ/α)(λ^(α−1) − λ^(−α/2−1)) (α = 2 is Neo-Hookean);
//! - Ogden (two terms): the sum of two such terms (μ1, α1, μ2, α2).
//!
//! For tension data the cross-section is unknown, so the moduli are *effective*: force scales
//! A0·μ in N. L0 is given (`--gauge-length`) or, if not, fitted as a parameter.
//!
//! Viscosity is Fung's quasi-linear viscoelasticity, i.e. a generalised Maxwell model on the
//! elastic response: P(t) = P_e(λ(t)) + Σ_i h_i(t) with ḣ_i = −h_i/τ_i + β_i dP_e/dt, integrated
//! exactly for P_e piecewise linear in time: h_i(t_k) = e^{−Δt/τ_i} h_i(t_{k−1}) +
//! β_i e^{−Δt/(2τ_i)} (P_e(t_k) − P_e(t_{k−1})). One model gives loading, unloading, every rate and
//! relaxation at constant displacement. P_e is the long-term (equilibrium) response; the
//! instantaneous one is (1 + Σβ_i) P_e.
//!
//! FSR (balance): u = R_pd G = a g(F) e^{δ (r − r̄)} (dimensionless divider conductance), counts =
//! N u / (1 + u) with N = 2^bits − 1. Base: g(F) = F (conductance ∝ force). Effects: power law
//! g = F_+^b, saturation g = F/(1 + F/F_sat), threshold F_+ = max(F − F0, 0), drift δ per run.
//! FSR (datasheet points): ln R = −ln(a g(F)) (R in Ω, a in S/N), same g.

use super::read::{Format, Group};

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
    fn moduli(self) -> &'static [&'static str] {
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

/// A candidate effect: what an augmented model adds to the current one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Candidate {
    /// Replace the elastic law by a hyperelastic one (non-linearity).
    Hyperelastic(Law),
    /// One more viscous (Maxwell) branch: hysteresis, rate dependence, relaxation.
    Viscosity,
    /// A zero offset of the response (load-cell zero).
    Offset,
    /// The specimen cannot carry compression: a membrane or strip slackens (buckles) when the
    /// model force would turn negative, so the measured force stays at zero (tension only).
    Slack,
    /// Power-law sensor response.
    PowerLaw,
    /// Sensor conductance saturation.
    Saturation,
    /// Sensor turn-on threshold.
    Threshold,
    /// Sensitivity drift from run to run.
    Drift,
}

impl Candidate {
    /// Name used on the command line and in reports.
    pub fn name(self) -> String {
        match self {
            Candidate::Hyperelastic(l) => format!("hyperelastic-{}", l.name()),
            Candidate::Viscosity => "viscosity".into(),
            Candidate::Offset => "offset".into(),
            Candidate::Slack => "slack".into(),
            Candidate::PowerLaw => "power-law-response".into(),
            Candidate::Saturation => "saturation".into(),
            Candidate::Threshold => "turn-on-threshold".into(),
            Candidate::Drift => "drift".into(),
        }
    }
    /// The physical effect in words.
    pub fn effect(self) -> &'static str {
        match self {
            Candidate::Hyperelastic(_) => {
                "material non-linearity (hyperelastic stiffening/softening)"
            }
            Candidate::Viscosity => "viscosity (hysteresis, rate dependence, relaxation)",
            Candidate::Offset => "zero offset of the load cell",
            Candidate::Slack => "slack: the specimen buckles instead of carrying compression",
            Candidate::PowerLaw => "non-linear (power-law) sensor response",
            Candidate::Saturation => "sensor saturation at high force",
            Candidate::Threshold => "sensor turn-on threshold",
            Candidate::Drift => "sensor drift from run to run",
        }
    }
}

/// Which kind of data a model describes.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub enum Family {
    /// Force against displacement; gauge length in mm if known.
    Tension {
        /// L0, mm.
        gauge_mm: Option<f64>,
    },
    /// Nominal stress against engineering strain.
    StressStrain,
    /// ADC counts of a divider against force; full-scale count.
    FsrCounts {
        /// N = 2^bits − 1.
        full_count: f64,
    },
    /// ln resistance against force.
    FsrResistance,
}

impl Family {
    /// The family of a format.
    pub fn of(format: Format, gauge_mm: Option<f64>, adc_bits: u32) -> Family {
        match format {
            Format::Tension => Family::Tension { gauge_mm },
            Format::StressStrain => Family::StressStrain,
            Format::FsrBalance => Family::FsrCounts {
                full_count: f64::from((1u32 << adc_bits.min(31)) - 1),
            },
            Format::FsrDatasheet => Family::FsrResistance,
        }
    }
    fn mechanical(self) -> bool {
        matches!(self, Family::Tension { .. } | Family::StressStrain)
    }
}

/// One parameter of a model.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Param {
    /// Name.
    pub name: String,
    /// Unit of the physical value.
    pub unit: String,
    /// θ = ln(value) (positive quantities), else θ = value.
    pub log: bool,
    /// The prediction is linear in this parameter (jointly with the other linear ones), so its
    /// start value can be solved for by linear least squares.
    pub linear: bool,
    /// Default start value (physical).
    pub start: f64,
}

impl Param {
    /// Physical value of θ.
    pub fn value(&self, theta: f64) -> f64 {
        if self.log {
            theta.exp()
        } else {
            theta
        }
    }
    /// θ of a physical value.
    pub fn theta(&self, value: f64) -> f64 {
        if self.log {
            value.max(1e-300).ln()
        } else {
            value
        }
    }
}

/// A model: the family, the elastic law and the effects adopted so far.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Model {
    /// Data family.
    pub family: Family,
    /// Elastic law (mechanical).
    pub law: Law,
    /// Viscous branches (mechanical).
    pub branches: usize,
    /// Zero offset.
    pub offset: bool,
    /// Tension only (force clipped at zero).
    pub slack: bool,
    /// FSR power-law response.
    pub power: bool,
    /// FSR saturation.
    pub saturation: bool,
    /// FSR threshold.
    pub threshold: bool,
    /// FSR drift.
    pub drift: bool,
    /// Scale of the data (typical |x|, |y|, duration), for start values.
    pub scale: Scale,
}

/// Typical magnitudes of a dataset.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Scale {
    /// Largest |x|.
    pub x_max: f64,
    /// Longest group duration, s.
    pub duration: f64,
    /// Mean run order (drift reference).
    pub order_mean: f64,
}

impl Model {
    /// The simplest model of a family.
    pub fn simplest(family: Family, scale: Scale) -> Model {
        Model {
            family,
            law: Law::Linear,
            branches: 0,
            offset: false,
            slack: false,
            power: false,
            saturation: false,
            threshold: false,
            drift: false,
            scale,
        }
    }

    /// Candidates that can augment this model given the data (`groups`: how many files/runs;
    /// `rate_info`: whether the record can tell viscosity from elasticity at all — it has
    /// unloading, a hold, or several rates; a single monotone pull at one rate cannot).
    pub fn candidates(&self, groups: usize, rate_info: bool) -> Vec<Candidate> {
        let mut v = Vec::new();
        if self.family.mechanical() {
            for l in HYPERELASTIC {
                if l != self.law && l.rank() >= self.law.rank() {
                    v.push(Candidate::Hyperelastic(l));
                }
            }
            if self.branches < 3 && rate_info {
                v.push(Candidate::Viscosity);
            }
            if !self.offset {
                v.push(Candidate::Offset);
            }
            if !self.slack && matches!(self.family, Family::Tension { .. }) {
                v.push(Candidate::Slack);
            }
        } else {
            if !self.power {
                v.push(Candidate::PowerLaw);
            }
            if !self.saturation {
                v.push(Candidate::Saturation);
            }
            if !self.threshold {
                v.push(Candidate::Threshold);
            }
            if !self.drift && groups >= 2 {
                v.push(Candidate::Drift);
            }
        }
        v
    }

    /// The model with `c` added.
    pub fn with(&self, c: Candidate) -> Model {
        let mut m = self.clone();
        match c {
            Candidate::Hyperelastic(l) => m.law = l,
            Candidate::Viscosity => m.branches += 1,
            Candidate::Offset => m.offset = true,
            Candidate::Slack => m.slack = true,
            Candidate::PowerLaw => m.power = true,
            Candidate::Saturation => m.saturation = true,
            Candidate::Threshold => m.threshold = true,
            Candidate::Drift => m.drift = true,
        }
        m
    }

    /// Short description ("yeoh + 2 viscous branches + offset").
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        if self.family.mechanical() {
            parts.push(format!("{} elastic", self.law.name()));
            if self.branches > 0 {
                parts.push(format!(
                    "{} viscous branch{}",
                    self.branches,
                    if self.branches > 1 { "es" } else { "" }
                ));
            }
            if self.offset {
                parts.push("offset".into());
            }
            if self.slack {
                parts.push("slack".into());
            }
        } else {
            parts.push(
                if matches!(self.family, Family::FsrCounts { .. }) {
                    "divider, conductance ∝ force"
                } else {
                    "conductance ∝ force"
                }
                .into(),
            );
            for (on, n) in [
                (self.power, "power-law response"),
                (self.saturation, "saturation"),
                (self.threshold, "threshold"),
                (self.drift, "drift"),
            ] {
                if on {
                    parts.push(n.into());
                }
            }
        }
        parts.join(" + ")
    }

    fn gauge_fitted(&self) -> bool {
        matches!(self.family, Family::Tension { gauge_mm: None }) && self.law != Law::Linear
    }

    /// The parameters, in θ order.
    pub fn params(&self) -> Vec<Param> {
        let p = |name: &str, unit: &str, log: bool, linear: bool, start: f64| Param {
            name: name.into(),
            unit: unit.into(),
            log,
            linear,
            start,
        };
        let mut v = Vec::new();
        match self.family {
            Family::Tension { .. } | Family::StressStrain => {
                let unit = match (self.family, self.law) {
                    (Family::Tension { .. }, Law::Linear) => "N/mm",
                    (Family::Tension { .. }, _) => "N (effective: modulus × unknown area)",
                    (_, _) => "MPa",
                };
                for m in self.law.moduli() {
                    v.push(p(m, unit, false, true, 1.0));
                }
                if self.law == Law::Ogden {
                    v.push(p("alpha", "1", false, false, 2.0));
                }
                if self.law == Law::Ogden2 {
                    v.push(p("alpha1", "1", false, false, 2.0));
                    v.push(p("alpha2", "1", false, false, -2.0));
                }
                if self.gauge_fitted() {
                    v.push(p("L0", "mm", true, false, self.scale.x_max.max(1e-9)));
                }
                for i in 0..self.branches {
                    // Spread the start time constants over the record: τ = duration/300, /30, /3.
                    let tau = self.scale.duration.max(1e-6) * 10f64.powi(i as i32) / 300.0;
                    v.push(p(&format!("beta{}", i + 1), "1", true, false, 0.5));
                    v.push(p(&format!("tau{}", i + 1), "s", true, false, tau));
                }
                if self.offset {
                    let unit = if matches!(self.family, Family::Tension { .. }) {
                        "N"
                    } else {
                        "MPa"
                    };
                    v.push(p("offset", unit, false, true, 0.0));
                }
            }
            Family::FsrCounts { .. } | Family::FsrResistance => {
                let unit = if matches!(self.family, Family::FsrCounts { .. }) {
                    "1/N (R_pd·G per newton)"
                } else {
                    "S/N"
                };
                v.push(p("a", unit, true, false, 1.0));
                if self.power {
                    v.push(p("b", "1", false, false, 1.0));
                }
                if self.saturation {
                    v.push(p("F_sat", "N", true, false, self.scale.x_max.max(1e-9)));
                }
                if self.threshold {
                    v.push(p("F0", "N", false, false, 0.0));
                }
                if self.drift {
                    v.push(p("delta", "per run", false, false, 0.0));
                }
            }
        }
        v
    }

    /// Predicted response of one group, `None` if θ leaves the model's domain.
    pub fn predict(&self, theta: &[f64], g: &Group) -> Option<Vec<f64>> {
        let params = self.params();
        let val = |name: &str| -> Option<f64> {
            params
                .iter()
                .position(|p| p.name == name)
                .map(|i| params[i].value(theta[i]))
        };
        let out = match self.family {
            Family::Tension { gauge_mm } => self.mechanical(theta, g, &val, gauge_mm)?,
            Family::StressStrain => self.mechanical(theta, g, &val, Some(1.0))?,
            Family::FsrCounts { full_count } => {
                let u = self.conductance(g, &val)?;
                u.iter().map(|&u| full_count * u / (1.0 + u)).collect()
            }
            Family::FsrResistance => {
                let u = self.conductance(g, &val)?;
                u.iter()
                    .map(|&u| if u > 0.0 { -u.ln() } else { f64::NAN })
                    .collect()
            }
        };
        out.iter().all(|v: &f64| v.is_finite()).then_some(out)
    }

    fn mechanical(
        &self,
        theta: &[f64],
        g: &Group,
        val: &dyn Fn(&str) -> Option<f64>,
        gauge: Option<f64>,
    ) -> Option<Vec<f64>> {
        let c: Vec<f64> = self
            .law
            .moduli()
            .iter()
            .map(|m| val(m))
            .collect::<Option<_>>()?;
        let l0 = gauge.or_else(|| val("L0")).unwrap_or(1.0);
        let alpha = match self.law {
            Law::Ogden2 => [val("alpha1")?, val("alpha2")?],
            _ => [val("alpha").unwrap_or(2.0), 0.0],
        };
        let mut pe: Vec<f64> = Vec::with_capacity(g.x.len());
        for &x in &g.x {
            let p = if self.law == Law::Linear {
                c[0] * x
            } else {
                let lam = 1.0 + x / l0;
                if lam < 0.05 {
                    return None;
                }
                elastic(self.law, &c, alpha, lam)
            };
            pe.push(p);
        }
        let mut out = pe.clone();
        for i in 0..self.branches {
            let beta = val(&format!("beta{}", i + 1))?;
            let tau = val(&format!("tau{}", i + 1))?;
            let mut h = 0.0;
            for k in 1..pe.len() {
                let dt = (g.t[k] - g.t[k - 1]).max(0.0);
                h = (-dt / tau).exp() * h + beta * (-dt / (2.0 * tau)).exp() * (pe[k] - pe[k - 1]);
                out[k] += h;
            }
        }
        if self.slack {
            out.iter_mut().for_each(|v| *v = v.max(0.0));
        }
        if let Some(o) = val("offset") {
            out.iter_mut().for_each(|v| *v += o);
        }
        let _ = theta;
        Some(out)
    }

    fn conductance(&self, g: &Group, val: &dyn Fn(&str) -> Option<f64>) -> Option<Vec<f64>> {
        let a = val("a")?;
        let b = val("b").unwrap_or(1.0);
        let fsat = val("F_sat");
        let f0 = val("F0").unwrap_or(0.0);
        let drift = val("delta").map_or(1.0, |d| (d * (g.order - self.scale.order_mean)).exp());
        Some(
            g.x.iter()
                .map(|&f| {
                    let fp = (f - f0).max(0.0);
                    let mut s = if self.power { fp.powf(b) } else { fp };
                    if let Some(fs) = fsat {
                        s /= 1.0 + f.max(0.0) / fs;
                    }
                    a * s * drift
                })
                .collect(),
        )
    }
}

/// Nominal (first Piola) uniaxial stress of an incompressible hyperelastic law at stretch λ,
/// with moduli `c` (see the module table).
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

impl crate::select::CandidateEffect for Candidate {
    const LIBRARY: &'static str = "candidate";
    /// The hyperelastic laws, then the effects.
    fn library() -> Vec<Self> {
        let mut v: Vec<Candidate> = HYPERELASTIC
            .iter()
            .map(|&l| Candidate::Hyperelastic(l))
            .collect();
        v.extend([
            Candidate::Viscosity,
            Candidate::Offset,
            Candidate::Slack,
            Candidate::PowerLaw,
            Candidate::Saturation,
            Candidate::Threshold,
            Candidate::Drift,
        ]);
        v
    }
    fn label(self) -> String {
        self.name()
    }
}
