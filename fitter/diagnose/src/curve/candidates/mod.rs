//! The curve room's library of candidate effects, one file per candidate. Each file says what
//! its effect adds to the model (the parameters it frees, with their units and starts, and the
//! alternative starts of the non-linear ones), when the data can show it at all, its part of the
//! prediction (through the stage hooks the model calls in library order), which residual
//! signals point to it and what the report says of it — all through [`CurveEffect`], which the
//! rest of the room calls instead of naming candidates. Every candidate is fitted the same way:
//! the shared Levenberg–Marquardt fit of [`super::fit`], started from the current model's values
//! and the candidate's alternatives.
//!
//! A new candidate is a new file here implementing [`CurveEffect`], plus its line in
//! [`Candidate`] (the serialisable identity), in [`Candidate::effect`] and in
//! [`ALL_CANDIDATES`]; a new state of the model it switches on is a field of
//! [`super::model::Model`].

use serde::Serialize;

use super::model::{Model, Param};
use super::read::Group;
use super::signature::Variable;

mod drift;
pub mod hyperelastic;
mod offset;
mod power_law;
mod saturation;
mod slack;
mod threshold;
mod viscosity;

pub use hyperelastic::{Law, HYPERELASTIC};

/// A candidate effect: what an augmented model adds to the current one. The identity the reports
/// serialise; what each is lives in its file, reached by [`Candidate::effect`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Candidate {
    /// Replace the elastic law by a hyperelastic one (non-linearity; `hyperelastic.rs`).
    Hyperelastic(Law),
    /// One more viscous (Maxwell) branch: hysteresis, rate dependence, relaxation
    /// (`viscosity.rs`).
    Viscosity,
    /// A zero offset of the response (load-cell zero; `offset.rs`).
    Offset,
    /// The specimen cannot carry compression (tension only; `slack.rs`).
    Slack,
    /// Power-law sensor response (`power_law.rs`).
    PowerLaw,
    /// Sensor conductance saturation (`saturation.rs`).
    Saturation,
    /// Sensor turn-on threshold (`threshold.rs`).
    Threshold,
    /// Sensitivity drift from run to run (`drift.rs`).
    Drift,
}

/// Every candidate, in the order they are tried (and their hooks called): the hyperelastic laws,
/// then the effects.
pub const ALL_CANDIDATES: [Candidate; 12] = [
    Candidate::Hyperelastic(Law::NeoHookean),
    Candidate::Hyperelastic(Law::MooneyRivlin),
    Candidate::Hyperelastic(Law::Ogden),
    Candidate::Hyperelastic(Law::Yeoh),
    Candidate::Hyperelastic(Law::Ogden2),
    Candidate::Viscosity,
    Candidate::Offset,
    Candidate::Slack,
    Candidate::PowerLaw,
    Candidate::Saturation,
    Candidate::Threshold,
    Candidate::Drift,
];

/// The physical value of a model's parameter by name, `None` if the model has no such parameter.
pub type Values<'a> = dyn Fn(&str) -> Option<f64> + 'a;

/// What a candidate effect of the curve room is: its parameters and starts, when the data can
/// show it, its part of the prediction, the signals that point to it, and its report words.
///
/// The prediction hooks are called for every candidate in [`ALL_CANDIDATES`] order, whether the
/// model holds it or not: each acts only when the model holds it (reading its own field of
/// [`Model`] or the presence of its parameters), so every hook but the ones an effect uses keeps
/// the default, which changes nothing.
pub trait CurveEffect: Sync {
    /// Name used on the command line and in reports.
    fn name(&self) -> String;

    /// The physical effect in words (the report's "Effect:" line).
    fn words(&self) -> &'static str;

    /// Whether it can augment `m` given the data (`groups`: how many files/runs; `rate_info`:
    /// whether the record can tell viscosity from elasticity at all,
    /// [`super::select::has_rate_information`]).
    fn available(&self, m: &Model, groups: usize, rate_info: bool) -> bool;

    /// Adds it to `m`.
    fn add_to(&self, m: &mut Model);

    /// Its part of the model's short description, when `m` holds it.
    fn describe(&self, _m: &Model) -> Option<String> {
        None
    }

    /// Appends its parameters, in θ order, when `m` holds it.
    fn params(&self, _m: &Model, _out: &mut Vec<Param>) {}

    /// Alternative start values (physical) of its parameter `p` when that parameter is new to the
    /// model being fitted (`None`: not its parameter; a parameter no candidate claims starts at
    /// its [`Param::start`] only).
    fn alternatives(&self, _p: &Param, _m: &Model) -> Option<Vec<f64>> {
        None
    }

    /// The residual signals that point to it, the most telling first
    /// ([`super::select::evidence_variable`]).
    fn evidence(&self) -> &'static [Variable] {
        &[Variable::Magnitude]
    }

    /// Mechanical: the equilibrium (elastic) response `pe` of the model's law at the load
    /// variable `g.x` (`gauge`: L0 in mm if known, 1 for strains). Only the model's own law
    /// fills it; `None` leaves the model's domain.
    fn elastic(
        &self,
        _m: &Model,
        _val: &Values<'_>,
        _gauge: Option<f64>,
        _g: &Group,
        _pe: &mut Vec<f64>,
    ) -> Option<()> {
        Some(())
    }

    /// Mechanical: adds its history-dependent part to `out` (which starts as the elastic
    /// response `pe`); `None` leaves the model's domain.
    fn viscous(
        &self,
        _m: &Model,
        _val: &Values<'_>,
        _g: &Group,
        _pe: &[f64],
        _out: &mut [f64],
    ) -> Option<()> {
        Some(())
    }

    /// Mechanical: limits what the specimen can carry (after every viscous branch).
    fn clip(&self, _m: &Model, _out: &mut [f64]) {}

    /// Mechanical: shifts the reading (last, after the clip: an instrument's zero).
    fn zero(&self, _m: &Model, _val: &Values<'_>, _out: &mut [f64]) {}

    /// Sensor: changes the force the sensor responds to (`force` starts as the applied force and
    /// is clipped at zero afterwards).
    fn sensed_force(&self, _m: &Model, _val: &Values<'_>, _force: &mut [f64]) {}

    /// Sensor: shapes the response `s` (which starts as the sensed force) at the applied forces
    /// `g.x`.
    fn respond(&self, _m: &Model, _val: &Values<'_>, _g: &Group, _s: &mut [f64]) {}

    /// Sensor: the sensitivity factor of the run `g`.
    fn gain(&self, _m: &Model, _val: &Values<'_>, _g: &Group) -> f64 {
        1.0
    }
}

impl Candidate {
    /// What the candidate is.
    pub fn effect(self) -> &'static dyn CurveEffect {
        match self {
            Candidate::Hyperelastic(l) => hyperelastic::of(l),
            Candidate::Viscosity => &viscosity::Viscosity,
            Candidate::Offset => &offset::Offset,
            Candidate::Slack => &slack::Slack,
            Candidate::PowerLaw => &power_law::PowerLaw,
            Candidate::Saturation => &saturation::Saturation,
            Candidate::Threshold => &threshold::Threshold,
            Candidate::Drift => &drift::Drift,
        }
    }
    /// Name used on the command line and in reports.
    pub fn name(self) -> String {
        self.effect().name()
    }
    /// The physical effect in words.
    pub fn words(self) -> &'static str {
        self.effect().words()
    }
}

/// Every candidate's effect, in library order (the order the model calls the hooks).
pub fn effects() -> impl Iterator<Item = &'static dyn CurveEffect> {
    ALL_CANDIDATES.iter().map(|c| c.effect())
}

impl crate::select::CandidateEffect for Candidate {
    const LIBRARY: &'static str = "candidate";
    /// The hyperelastic laws, then the effects.
    fn library() -> Vec<Self> {
        ALL_CANDIDATES.to_vec()
    }
    fn label(self) -> String {
        self.name()
    }
}

#[cfg(test)]
mod tests {
    use super::{Candidate, ALL_CANDIDATES};

    /// The serialised identity keeps the shape the reports have always had (the law inside the
    /// hyperelastic variant), and every candidate has a distinct name.
    #[test]
    fn identities_and_names_are_distinct() {
        let json = serde_json::to_string(&Candidate::Hyperelastic(super::Law::Ogden2)).unwrap();
        assert_eq!(json, r#"{"Hyperelastic":"Ogden2"}"#);
        assert_eq!(
            serde_json::to_string(&Candidate::Slack).unwrap(),
            r#""Slack""#
        );
        let names: Vec<String> = ALL_CANDIDATES.iter().map(|c| c.name()).collect();
        for (i, a) in names.iter().enumerate() {
            assert!(!names[i + 1..].contains(a), "{a} twice");
        }
    }
}
