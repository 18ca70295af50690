//! Newtonian viscosity: the viscous stress of eq. 17 with h = 1, ν free (1 parameter). Excludes
//! the power law.

use palpate_motion::model::ParamKind;

use super::viscosity::viscosity_starts;
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
        other == Candidate::Viscosity
    }

    fn screened_params(&self) -> &'static [(ParamKind, Option<f64>)] {
        &[(ParamKind::Nu, Some(0.0))]
    }

    fn new_starts(&self, cur: &FittedModel, dt: f64) -> Vec<Vec<f64>> {
        viscosity_starts(cur, dt)
            .iter()
            .map(|&nu| vec![nu])
            .collect()
    }
}
