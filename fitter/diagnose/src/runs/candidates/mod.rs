//! The runs room's library of candidate effects, one file per candidate. Each file says what its
//! effect adds to the simplest model (material parameters, or a change of the runs' models or of
//! their clock), where its fit starts and how it is fitted, how the fit screen predicts it, and
//! what the report and the fitted-model record say of it — all through [`RunsEffect`], which the
//! room's driver calls instead of naming candidates.
//!
//! A new candidate is a new file here implementing [`RunsEffect`], plus its line in [`Effect`]
//! (the serialisable identity), in [`Effect::effect`] and in [`ALL_EFFECTS`].

use palpate_motion::fitted::FittedModel;
use palpate_motion::model::{Material, Model, ParamKind};
use serde::Serialize;

use super::fit::{fitted, RunsModel};
use super::screen::ScreenPoint;
use super::{RunsDiagnosis, RunsError, RunsFit};
use crate::select::{Outcome, ParamValue, Prediction};

pub(in crate::runs) mod clamp_compliance;
pub(in crate::runs) mod creep;
pub(in crate::runs) mod damping;
mod damping_power_law;
mod hanging_inertia;
mod load_point;
mod stiffening;
mod time_offset;

/// A candidate effect the simplest model of the runs lacks. The identity the reports serialise;
/// what each is lives in its file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Effect {
    /// Newtonian viscosity: ν free, h = 1 (1 parameter; `damping.rs`).
    Damping,
    /// Power-law viscosity of eq. 17: ν and h free (2 parameters; `damping_power_law.rs`).
    DampingPowerLaw,
    /// Hanging weights move with their nodes (0 parameters: the declared mass;
    /// `hanging_inertia.rs`).
    HangingInertia,
    /// Each run's markers are offset in time against the simulation (1 integer parameter per
    /// run: its offset in steps, scanned; `time_offset.rs`).
    TimeOffset,
    /// The material stiffens (or holds its stiffness) at larger strains beyond Neo-Hookean: a
    /// Yeoh-type c (Ī₁ − 3)² term beside eq. 16 (1 parameter, c ≥ 0; `stiffening.rs`).
    Stiffening,
    /// The elastic stress relaxes: one generalised-Maxwell branch, relaxed fraction g and time
    /// τ free (2 parameters; `creep.rs`).
    Creep,
    /// The hanging weights act at a point beyond their nodes, a hook's lever read from the rest
    /// states (1 parameter; `load_point.rs`).
    LoadPoint,
    /// The clamp gives: the layer of elements at the clamps softened as a whole (1 parameter,
    /// its μ; `clamp_compliance.rs`).
    ClampCompliance,
}

/// Every effect, in the order tried: the names `--candidates` accepts.
pub const ALL_EFFECTS: [Effect; 8] = [
    Effect::Damping,
    Effect::DampingPowerLaw,
    Effect::HangingInertia,
    Effect::TimeOffset,
    Effect::Stiffening,
    Effect::Creep,
    Effect::LoadPoint,
    Effect::ClampCompliance,
];

/// The effects a diagnosis tries by default: [`ALL_EFFECTS`] but the hanging weights' inertia,
/// which the simplest model holds ([`super::RunsOptions::weights_move`]).
pub fn default_effects() -> Vec<Effect> {
    ALL_EFFECTS
        .into_iter()
        .filter(|e| *e != Effect::HangingInertia)
        .collect()
}

/// What a candidate effect of the runs is: its parameters, its part of the runs' models and of
/// their fit, its prediction by the fit screen, and its report words. Every method but the name
/// has the default of an effect that does not take part there.
pub(in crate::runs) trait RunsEffect: Sync {
    /// Name (on the command line, in reports and the serialised [`Effect`]).
    fn name(&self) -> &'static str;

    /// Material parameters it frees (global, fitted together with μ).
    fn kinds(&self) -> &'static [ParamKind] {
        &[]
    }

    /// Parameters it adds to a model of `runs` runs.
    fn parameters(&self, _runs: usize) -> usize {
        self.kinds().len()
    }

    /// Whether the runs can show it at all.
    fn available(&self, _room: &RunsModel) -> bool {
        true
    }

    /// Why it is not [`Self::available`], as the log says when a requested candidate is left out.
    fn unavailable_because(&self) -> &'static str {
        "the runs cannot show it"
    }

    /// Whether it offsets each run's markers in time against the simulation: then every fit of a
    /// model that holds it scans the offsets again after refitting the material
    /// ([`RunsModel::fit_retimed`]), and each held-out run is given its own.
    fn retimes(&self) -> bool {
        false
    }

    /// Changes a run's model from the simplest one's,
    /// with what the room has read from the runs (`room`).
    fn change_model(&self, _room: &RunsModel, _model: &mut Model) {}

    /// Sets the start of its material parameters in `start` (the current model's material, or
    /// the fit of a candidate nested in it this round) before its fit on top of `cur`.
    fn start(&self, _room: &RunsModel, _round: usize, _cur: &RunsFit, _start: &mut Material) {}

    /// Fits `effects` (the current model's and this one) from `start` within `budget`
    /// iterations: by default the material refitted with the current model's time offsets.
    fn fit(
        &self,
        room: &mut RunsModel,
        round: usize,
        cur: &RunsFit,
        effects: &[Effect],
        start: &Material,
        budget: u64,
    ) -> Result<Outcome<RunsFit>, RunsError> {
        Ok(fitted(room.fit_effects(
            round,
            effects,
            start,
            &cur.offsets,
            budget,
        )))
    }

    /// Its gain as the fit screen predicts it at `at`: by default one Gauss–Newton step over the
    /// current parameters and its own from their neutral values (a continuous effect).
    fn predict(&self, _room: &mut RunsModel, at: &ScreenPoint) -> Result<Prediction, RunsError> {
        Ok(at.stepped(self.kinds(), self.parameters(at.runs)))
    }

    /// Its parameters in the final model's `material`, as the report lists them.
    fn values(&self, _material: &Material) -> Vec<ParamValue> {
        Vec::new()
    }

    /// Marks itself in the record `palpate validate` reads.
    fn record(&self, _model: &mut FittedModel) {}

    /// Its paragraph of the report, after the per-run table, when adopted.
    fn report(&self, _r: &RunsDiagnosis) -> Option<String> {
        None
    }
}

impl Effect {
    /// What the candidate is.
    pub(in crate::runs) fn effect(self) -> &'static dyn RunsEffect {
        match self {
            Effect::Damping => &damping::Damping,
            Effect::DampingPowerLaw => &damping_power_law::DampingPowerLaw,
            Effect::HangingInertia => &hanging_inertia::HangingInertia,
            Effect::TimeOffset => &time_offset::TimeOffset,
            Effect::Stiffening => &stiffening::Stiffening,
            Effect::Creep => &creep::Creep,
            Effect::LoadPoint => &load_point::LoadPoint,
            Effect::ClampCompliance => &clamp_compliance::ClampCompliance,
        }
    }
    /// Name on the command line and in reports.
    pub fn name(self) -> &'static str {
        self.effect().name()
    }
    /// Material parameters it frees.
    pub fn kinds(self) -> &'static [ParamKind] {
        self.effect().kinds()
    }
    /// Whether `self` is `other` with some of `other`'s material parameters held at their neutral
    /// values (Newtonian damping is the power law at h = 1). Switches (no parameters) nest nothing.
    pub fn nested_in(self, other: Effect) -> bool {
        let (a, b) = (self.kinds(), other.kinds());
        !a.is_empty() && a.len() < b.len() && a.iter().all(|k| b.contains(k))
    }
    /// Parameters it adds to a model of `runs` runs.
    pub(in crate::runs) fn parameters(self, runs: usize) -> usize {
        self.effect().parameters(runs)
    }
    /// Whether one model cannot hold both: two laws of one material parameter (the damping's).
    pub(in crate::runs) fn conflicts(self, other: Effect) -> bool {
        self != other && self.kinds().iter().any(|k| other.kinds().contains(k))
    }
    /// Whether any of `effects` offsets the runs in time ([`RunsEffect::retimes`]).
    pub(in crate::runs) fn retimed(effects: &[Effect]) -> bool {
        effects.iter().any(|e| e.effect().retimes())
    }
}

impl crate::select::CandidateEffect for Effect {
    const LIBRARY: &'static str = "runs candidate";
    fn library() -> Vec<Self> {
        ALL_EFFECTS.to_vec()
    }
    fn label(self) -> String {
        self.name().into()
    }
}

#[cfg(test)]
mod tests {
    use super::{Effect, ALL_EFFECTS};

    /// Only Newtonian damping nests in another candidate (the power law at h = 1); switches and
    /// the time offset nest nothing, and nothing nests in itself.
    #[test]
    fn only_newtonian_damping_nests_in_the_power_law() {
        for a in ALL_EFFECTS {
            for b in ALL_EFFECTS {
                let expected = a == Effect::Damping && b == Effect::DampingPowerLaw;
                assert_eq!(a.nested_in(b), expected, "{a:?} in {b:?}");
            }
        }
    }

    /// Only the two damping laws exclude each other; nothing excludes itself (a candidate already
    /// adopted is not offered again for another reason).
    #[test]
    fn only_the_two_damping_laws_conflict() {
        for a in ALL_EFFECTS {
            for b in ALL_EFFECTS {
                let expected = matches!(
                    (a, b),
                    (Effect::Damping, Effect::DampingPowerLaw)
                        | (Effect::DampingPowerLaw, Effect::Damping)
                );
                assert_eq!(a.conflicts(b), expected, "{a:?} with {b:?}");
            }
        }
    }

    /// The serialised identity and the effect's report name are one name, and only the time
    /// offset counts a parameter per run.
    #[test]
    fn every_effect_serialises_as_its_name() {
        for e in ALL_EFFECTS {
            let json = serde_json::to_string(&e).unwrap();
            assert_eq!(json, format!("\"{}\"", e.name()));
            let per_run = e.parameters(3) - e.parameters(2);
            assert_eq!(per_run, usize::from(e == Effect::TimeOffset), "{e:?}");
        }
    }
}
