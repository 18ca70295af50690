//! The 1-D model: the data's family, the simplest model of each (force ∝ displacement, stress ∝
//! strain, FSR conductance ∝ force through the divider) and the state of the candidate effects
//! it holds (one file each in [`super::candidates`]: the hyperelastic laws, viscous branches, a
//! zero offset, slack; the sensor's power-law response, saturation, turn-on threshold, drift).
//! The model asks each candidate for its parameters and calls its hooks, in library order, to
//! predict:
//!
//! - mechanical (tension: F in N against grip displacement Δ; stress–strain: nominal stress P
//!   against engineering strain ε): the elastic response of the law (linear: F = k Δ, P = E ε;
//!   a hyperelastic law in uniaxial incompressible form with stretch λ = 1 + Δ/L0 = 1 + ε), each
//!   viscous branch on it, the clip of a specimen that cannot carry compression, the zero offset.
//!   For tension data the cross-section is unknown, so the moduli are *effective*: force scales
//!   A0·μ in N. L0 is given (`--gauge-length`) or, if not, fitted as a parameter;
//! - FSR (balance): u = R_pd G = a g(F) (dimensionless divider conductance, times the run's
//!   drift factor), counts = N u / (1 + u) with N = 2^bits − 1; base g(F) = F_+ = max(F, 0);
//! - FSR (datasheet points): ln R = −ln(a g(F)) (R in Ω, a in S/N), same g.

use super::candidates::{effects, Candidate, Values, ALL_CANDIDATES};
use super::read::{Format, Group};

pub use super::candidates::hyperelastic::{elastic, Law, HYPERELASTIC};

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
    /// Whether the data are mechanical (tension, stress–strain) rather than a sensor's.
    pub fn mechanical(self) -> bool {
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
    /// A parameter (`log`: fitted as θ = ln value; `linear`: the prediction is linear in it;
    /// `start`: its default start value, physical).
    pub fn new(name: &str, unit: &str, log: bool, linear: bool, start: f64) -> Param {
        Param {
            name: name.into(),
            unit: unit.into(),
            log,
            linear,
            start,
        }
    }
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
        ALL_CANDIDATES
            .into_iter()
            .filter(|c| c.effect().available(self, groups, rate_info))
            .collect()
    }

    /// The model with `c` added.
    pub fn with(&self, c: Candidate) -> Model {
        let mut m = self.clone();
        c.effect().add_to(&mut m);
        m
    }

    /// Short description ("yeoh elastic + 2 viscous branches + offset").
    pub fn describe(&self) -> String {
        let base = if self.family.mechanical() {
            format!("{} elastic", self.law.name())
        } else if matches!(self.family, Family::FsrCounts { .. }) {
            "divider, conductance ∝ force".into()
        } else {
            "conductance ∝ force".into()
        };
        std::iter::once(base)
            .chain(effects().filter_map(|e| e.describe(self)))
            .collect::<Vec<_>>()
            .join(" + ")
    }

    /// Whether L0 is a fitted parameter: tension data without a given gauge length, under a law
    /// that is not linear (the linear law's stiffness is per millimetre of grip travel).
    pub fn gauge_fitted(&self) -> bool {
        matches!(self.family, Family::Tension { gauge_mm: None }) && self.law != Law::Linear
    }

    /// The parameters, in θ order: the simplest model's (the linear stiffness, or the sensor's
    /// conductance scale), then each candidate's the model holds, in library order.
    pub fn params(&self) -> Vec<Param> {
        let mut v = Vec::new();
        match self.family {
            Family::Tension { .. } | Family::StressStrain => {
                if self.law == Law::Linear {
                    let unit = if matches!(self.family, Family::Tension { .. }) {
                        "N/mm"
                    } else {
                        "MPa"
                    };
                    v.push(Param::new("k", unit, false, true, 1.0));
                }
            }
            Family::FsrCounts { .. } | Family::FsrResistance => {
                let unit = if matches!(self.family, Family::FsrCounts { .. }) {
                    "1/N (R_pd·G per newton)"
                } else {
                    "S/N"
                };
                v.push(Param::new("a", unit, true, false, 1.0));
            }
        }
        for e in effects() {
            e.params(self, &mut v);
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
            Family::Tension { gauge_mm } => self.mechanical(g, &val, gauge_mm)?,
            Family::StressStrain => self.mechanical(g, &val, Some(1.0))?,
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

    /// The mechanical response: the law's elastic response, each viscous branch on it, the
    /// clip of a specimen that cannot carry compression, then the instrument's zero.
    fn mechanical(&self, g: &Group, val: &Values<'_>, gauge: Option<f64>) -> Option<Vec<f64>> {
        let mut pe: Vec<f64> = Vec::with_capacity(g.x.len());
        if self.law == Law::Linear {
            let k = val("k")?;
            pe.extend(g.x.iter().map(|&x| k * x));
        }
        for e in effects() {
            e.elastic(self, val, gauge, g, &mut pe)?;
        }
        let mut out = pe.clone();
        for e in effects() {
            e.viscous(self, val, g, &pe, &mut out)?;
        }
        for e in effects() {
            e.clip(self, &mut out);
        }
        for e in effects() {
            e.zero(self, val, &mut out);
        }
        Some(out)
    }

    /// The divider conductance u = a g(F) (drift factor) of one run: the force the sensor
    /// responds to, clipped at zero, shaped by the response effects, scaled by the run's gain.
    fn conductance(&self, g: &Group, val: &Values<'_>) -> Option<Vec<f64>> {
        let a = val("a")?;
        let mut s = g.x.clone();
        for e in effects() {
            e.sensed_force(self, val, &mut s);
        }
        s.iter_mut().for_each(|f| *f = f.max(0.0));
        for e in effects() {
            e.respond(self, val, g, &mut s);
        }
        let mut gain = 1.0;
        for e in effects() {
            gain *= e.gain(self, val, g);
        }
        Some(s.iter().map(|&s| a * s * gain).collect())
    }
}
