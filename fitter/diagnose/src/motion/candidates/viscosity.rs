//! Power-law viscosity of eq. 17: the viscous stress ν γ̇^(h−1)(∇v + ∇vᵀ) with ν and h free
//! (2 parameters). Excludes the Newtonian law.

use palpate_motion::model::ParamKind;

use super::{Candidate, MotionEffect};
use crate::motion::fit::FittedModel;
use crate::motion::screen::Screening;
use crate::motion::MotionDiagnoseError;
use crate::select::Prediction;

/// See the module.
pub struct Viscosity;

/// Starting viscosities on top of `cur`: the viscous time τ = ν/μ over three decades around the
/// step, 0.03, 0.3 and 3 Δt (shared by both laws).
pub(super) fn viscosity_starts(cur: &FittedModel, dt: f64) -> [f64; 3] {
    let mu = cur
        .material
        .read(&[palpate_motion::model::Param::global(ParamKind::Mu)])[0];
    [0.03, 0.3, 3.0].map(|f| mu * f * dt)
}

/// The viscosity the screen's Gauss–Newton step from ν = 0 reached, when positive: the
/// Newtonian fit's one start in place of [`viscosity_starts`]' three. The step knows which way
/// the misfit falls; the three starts, three decades apart, were each fitted for 15 iterations to
/// find the same basin (on the independent 1,267-tetrahedron cylinder, 48 simulations of a 62 s
/// round). A step to ν ≤ 0 says nothing of where the viscosity is, and the three starts stay.
/// The power law keeps its three: started at this ν (h = 1) on that cylinder it ran on to
/// h = 0.005, a lower χ² (ΔBIC −483.6 against −478.3 at h = 0.13) where every simulation carries
/// a nearly rate-independent dashpot, and the diagnosis took 124 s instead of 75 s.
pub(super) fn screened_viscosity(stepped: &dyn Fn(ParamKind) -> Option<f64>) -> Option<f64> {
    stepped(ParamKind::Nu).filter(|nu| nu.is_finite() && *nu > 0.0)
}

impl MotionEffect for Viscosity {
    fn name(&self) -> &'static str {
        "viscosity"
    }

    fn kinds(&self) -> &'static [ParamKind] {
        &[ParamKind::Nu, ParamKind::PowerH]
    }

    fn conflicts(&self, other: Candidate) -> bool {
        matches!(
            other,
            Candidate::ViscosityNewtonian | Candidate::ViscosityObjective
        )
    }

    /// A loss of energy: the mesh's error cannot make one. Refining the mesh changes an elastic
    /// body's stiffness, not its energy balance (the coarse and the refined elastic models both
    /// conserve energy up to the integrator's own damping, the same scheme on both).
    fn mimics_mesh_error(&self) -> bool {
        false
    }

    fn screened_params(&self) -> &'static [(ParamKind, Option<f64>)] {
        &[(ParamKind::Nu, Some(0.0))]
    }

    /// The power-law index has no effect at ν = 0: the law is predicted as Newtonian damping,
    /// charged its two parameters.
    fn predict(&self, s: &Screening<'_, '_>) -> Result<Prediction, MotionDiagnoseError> {
        Ok(s.linearised(
            &[ParamKind::Nu],
            2,
            "one Gauss–Newton step from ν = 0, as Newtonian (h has no effect there)",
        ))
    }

    /// Each viscosity start with h = 1 (Newtonian).
    fn new_starts(&self, cur: &FittedModel, dt: f64) -> Vec<Vec<f64>> {
        viscosity_starts(cur, dt)
            .iter()
            .map(|&nu| vec![nu, 1.0])
            .collect()
    }
}
