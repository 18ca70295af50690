//! Newtonian viscosity: the viscous stress of eq. 17 with h = 1, ν free (1 parameter). Excludes
//! the power law.

use palpate_motion::model::ParamKind;

use super::viscosity::{screened_viscosity, viscosity_starts};
use super::{Candidate, MotionEffect};
use crate::motion::fit::FittedModel;

/// See the module.
pub struct ViscosityNewtonian;

impl MotionEffect for ViscosityNewtonian {
    fn name(&self) -> &'static str {
        "viscosity-newtonian"
    }

    fn kinds(&self) -> &'static [ParamKind] {
        &[ParamKind::Nu]
    }

    fn conflicts(&self, other: Candidate) -> bool {
        matches!(other, Candidate::Viscosity | Candidate::ViscosityObjective)
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

    fn screened_start(&self, stepped: &dyn Fn(ParamKind) -> Option<f64>) -> Option<Vec<f64>> {
        screened_viscosity(stepped).map(|nu| vec![nu])
    }

    fn new_starts(&self, cur: &FittedModel, dt: f64) -> Vec<Vec<f64>> {
        viscosity_starts(cur, dt)
            .iter()
            .map(|&nu| vec![nu])
            .collect()
    }
}
