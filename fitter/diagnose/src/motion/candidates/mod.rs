//! The motion room's library of candidate effects, one file per candidate. Each file says what
//! its effect models (the parameters it frees and how many the rule charges), where its new
//! parameters start, how it is fitted — the default refit of [`MotionEffect::fit`] through the
//! room's fitter, or a search of its own (the time offset's scan, the second material's region)
//! — and what the report says of it, all through [`MotionEffect`], which the rest of the room
//! calls instead of naming candidates.
//!
//! A new candidate is a new file here implementing [`MotionEffect`], plus its line in
//! [`Candidate`] (the serialisable identity), in [`Candidate::effect`], in [`ALL_CANDIDATES`]
//! and in [`REPORT_ORDER`].

use palpate_motion::model::{Model, ParamKind};
use serde::Serialize;

use super::engine::MotionModel;
use super::fit::FittedModel;
use super::screen::Screening;
use super::{MotionDiagnoseError, Value};
use crate::select::{Outcome, Prediction};

pub(crate) mod clamp_compliance;
mod density;
mod gravity_direction;
mod marker_offsets;
mod stiffening;
mod time_offset;
pub(in crate::motion) mod two_material;
mod viscosity;
mod viscosity_newtonian;
mod viscosity_objective;

/// A candidate effect the simplest motion model lacks. The identity the reports serialise; what
/// each is lives in its file, reached by [`Candidate::effect`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Candidate {
    /// Power-law viscosity of eq. 17, ν and h free (`viscosity.rs`).
    Viscosity,
    /// Newtonian viscosity, ν free and h = 1 (`viscosity_newtonian.rs`).
    ViscosityNewtonian,
    /// The power law on the Green–Lagrange strain rate, ν and h free (`viscosity_objective.rs`).
    ViscosityObjective,
    /// Density free, identifiable only with measured clamp forces (`density.rs`).
    Density,
    /// A constant offset of each marker from its declared place (`marker_offsets.rs`).
    MarkerOffsets,
    /// The markers recorded out of step with the clamps' record (`time_offset.rs`).
    TimeOffset,
    /// A Yeoh-type stiffening term beside Neo-Hookean (`stiffening.rs`).
    Stiffening,
    /// A body of two materials (`two_material.rs`).
    TwoMaterial,
    /// A clamp that gives: the layer at the clamps softened as a whole (`clamp_compliance.rs`).
    ClampCompliance,
    /// Gravity along another direction than the declared one (`gravity_direction.rs`).
    GravityDirection,
}

/// Every candidate, in the order they are tried.
pub const ALL_CANDIDATES: [Candidate; 10] = [
    Candidate::Viscosity,
    Candidate::ViscosityNewtonian,
    Candidate::ViscosityObjective,
    Candidate::Density,
    Candidate::MarkerOffsets,
    Candidate::TimeOffset,
    Candidate::Stiffening,
    Candidate::TwoMaterial,
    Candidate::ClampCompliance,
    Candidate::GravityDirection,
];

/// The order in which a fitted model's effect values are listed after the material's
/// ([`MotionEffect::values`], [`MotionEffect::summary_values`]): a second material's μ is a
/// material value and sits beside the global ones; the offsets, which read the data rather than
/// the body, come last.
pub const REPORT_ORDER: [Candidate; 10] = [
    Candidate::Viscosity,
    Candidate::ViscosityNewtonian,
    Candidate::ViscosityObjective,
    Candidate::Density,
    Candidate::Stiffening,
    Candidate::TwoMaterial,
    Candidate::ClampCompliance,
    Candidate::GravityDirection,
    Candidate::TimeOffset,
    Candidate::MarkerOffsets,
];

/// What a candidate effect is: the parameters it frees and charges, where they start, how it is
/// fitted on top of the current model and adopted, and what the report lists of it. Every
/// method but the name has the default of an effect that frees no material parameter and is
/// fitted by the room's plain refit.
pub trait MotionEffect: Sync {
    /// Name used on the command line and in reports.
    fn name(&self) -> &'static str;

    /// Material parameters it frees (global, beside the current model's).
    fn kinds(&self) -> &'static [ParamKind] {
        &[]
    }

    /// Parameters it adds to a model of `markers` markers (what BIC and the held-out gate
    /// charge).
    fn extra_params(&self, _markers: usize) -> usize {
        self.kinds().len()
    }

    /// Whether, adopted, it excludes `other`: two laws of one effect, or an effect its own
    /// parameters would leave unidentified.
    fn conflicts(&self, _other: Candidate) -> bool {
        false
    }

    /// Starting values of its [`Self::kinds`] on top of the current fit `cur` (time step `dt`):
    /// one list per start; several are screened and the best continued.
    fn new_starts(&self, _cur: &FittedModel, _dt: f64) -> Vec<Vec<f64>> {
        vec![Vec::new()]
    }

    /// One start of its [`Self::kinds`] from where the round's screen stepped them (`stepped`
    /// of a kind: its value after the prediction's Gauss–Newton step, `None` when not
    /// screened), in place of [`Self::new_starts`]; `None` (the default): the new starts.
    fn screened_start(&self, _stepped: &dyn Fn(ParamKind) -> Option<f64>) -> Option<Vec<f64>> {
        None
    }

    /// Whether its fit frees a constant offset per marker (eliminated in closed form,
    /// [`super::fit::fit_with_offsets`]).
    fn frees_marker_offsets(&self) -> bool {
        false
    }

    /// Parameters of the current model that its fit holds at their values, and every fit after
    /// its adoption: those its own parameters leave unidentified (the default: none).
    fn holds(&self) -> &'static [ParamKind] {
        &[]
    }

    /// Why it is not offered on the dataset of `m`, if it is not (the default: it is): the
    /// default [`Self::predict`] and [`Self::fit`] then say so instead of predicting or fitting.
    fn refusal(&self, _m: &MotionModel<'_>) -> Option<String> {
        None
    }

    /// Fits the candidate `c` (this effect) on top of `cur`. The default refits the current
    /// model's parameters and the effect's own (at the current model's time offset, if any),
    /// unless [`Self::refusal`] says why not; a failed fit is a finding about this candidate,
    /// not the end of the diagnosis.
    fn fit(
        &self,
        m: &MotionModel<'_>,
        c: Candidate,
        cur: &FittedModel,
    ) -> Result<Outcome<FittedModel>, MotionDiagnoseError> {
        Ok(match self.refusal(m) {
            Some(why) => Outcome::NotFitted(why),
            None => refit(m, c, cur),
        })
    }

    /// The parameters through which the fit screen linearises it ([`super::screen`]), each with
    /// its neutral value, where the augmented model is the current one (`None`: the current
    /// model's value). Empty: not linearised.
    fn screened_params(&self) -> &'static [(ParamKind, Option<f64>)] {
        &[]
    }

    /// Its gain predicted before its fit, at the current fit linearised once for the round
    /// (`s`). The default: one Gauss–Newton step over the current parameters and
    /// [`Self::screened_params`], charged [`Self::extra_params`]; not predicted (always fitted)
    /// without such parameters.
    fn predict(&self, s: &Screening<'_, '_>) -> Result<Prediction, MotionDiagnoseError> {
        if let Some(why) = self.refusal(s.model) {
            return Ok(Prediction::none(&why));
        }
        let kinds: Vec<ParamKind> = self.screened_params().iter().map(|p| p.0).collect();
        if kinds.is_empty() {
            return Ok(Prediction::none(
                "no neutral value to linearise at: always fitted",
            ));
        }
        let extra = self.extra_params(s.model.ds.model.markers.len());
        Ok(s.linearised(
            &kinds,
            extra,
            "one Gauss–Newton step from the neutral value",
        ))
    }

    /// Whether the dataset mesh's own discretisation error can pass for this effect, so that a
    /// passing fit is checked against the mesh's null before it is adopted
    /// ([`super::mesh_null`]). The default: it can.
    fn mimics_mesh_error(&self) -> bool {
        true
    }

    /// The gated fit refined on adoption (the default keeps it).
    fn adopt(&self, _m: &MotionModel<'_>, gated: FittedModel) -> FittedModel {
        gated
    }

    /// What a fitted model lists of this effect beside its material values, when the effect is
    /// in `fitted` (the report's parameters; `model` places regions).
    fn values(&self, _fitted: &FittedModel, _model: &Model) -> Vec<Value> {
        Vec::new()
    }

    /// What a trial's summary lists of this effect beyond [`Self::values`].
    fn summary_values(&self, _fitted: &FittedModel) -> Vec<Value> {
        Vec::new()
    }
}

/// The default fit of [`MotionEffect::fit`]: the current model's parameters and the candidate's
/// refitted through the room's fitter, a failure a finding about the candidate.
fn refit(m: &MotionModel<'_>, c: Candidate, cur: &FittedModel) -> Outcome<FittedModel> {
    match m.fit_from(cur, c) {
        Ok(f) => Outcome::Fitted(f),
        Err(e) => Outcome::NotFitted(format!("fit failed: {e}")),
    }
}

impl Candidate {
    /// What the candidate is.
    pub fn effect(self) -> &'static dyn MotionEffect {
        match self {
            Candidate::Viscosity => &viscosity::Viscosity,
            Candidate::ViscosityNewtonian => &viscosity_newtonian::ViscosityNewtonian,
            Candidate::ViscosityObjective => &viscosity_objective::ViscosityObjective,
            Candidate::Density => &density::Density,
            Candidate::MarkerOffsets => &marker_offsets::MarkerOffsets,
            Candidate::TimeOffset => &time_offset::TimeOffset,
            Candidate::Stiffening => &stiffening::Stiffening,
            Candidate::TwoMaterial => &two_material::TwoMaterial,
            Candidate::ClampCompliance => &clamp_compliance::ClampCompliance,
            Candidate::GravityDirection => &gravity_direction::GravityDirection,
        }
    }

    /// The candidate of that name ([`Self::name`]), if any.
    pub fn named(name: &str) -> Option<Self> {
        ALL_CANDIDATES.into_iter().find(|c| c.name() == name)
    }

    /// Name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        self.effect().name()
    }

    /// Parameters it adds to a model of `markers` markers.
    pub fn extra_params(self, markers: usize) -> usize {
        self.effect().extra_params(markers)
    }

    /// Parameters it frees.
    pub fn kinds(self) -> &'static [ParamKind] {
        self.effect().kinds()
    }

    /// Effects that exclude each other (the viscosity laws).
    pub fn conflicts(self, other: Candidate) -> bool {
        self.effect().conflicts(other)
    }
}

impl crate::select::CandidateEffect for Candidate {
    const LIBRARY: &'static str = "motion candidate";
    fn library() -> Vec<Self> {
        ALL_CANDIDATES.to_vec()
    }
    fn label(self) -> String {
        self.name().into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every candidate is listed once in the report's order; the three viscosity laws and the two
    /// region effects exclude each other, both ways, and the marker offsets, adopted, exclude a
    /// turned gravity (but not the other way); nothing else is excluded.
    #[test]
    fn the_library_is_listed_once_and_the_viscosity_laws_conflict() {
        for c in ALL_CANDIDATES {
            assert_eq!(REPORT_ORDER.iter().filter(|&&r| r == c).count(), 1, "{c:?}");
            for d in ALL_CANDIDATES {
                let laws = [
                    Candidate::Viscosity,
                    Candidate::ViscosityNewtonian,
                    Candidate::ViscosityObjective,
                ];
                let regions = [Candidate::TwoMaterial, Candidate::ClampCompliance];
                let expected = c != d
                    && ((laws.contains(&c) && laws.contains(&d))
                        || (regions.contains(&c) && regions.contains(&d))
                        || (c, d) == (Candidate::MarkerOffsets, Candidate::GravityDirection));
                assert_eq!(c.conflicts(d), expected, "{c:?} vs {d:?}");
            }
        }
    }
}
