//! Power-law viscosity of eq. 17: ν (Pa·s^h) and the index h free (2 parameters). Newtonian
//! damping is this law at h = 1: fitted in the same round, the power law starts from that fit with
//! h = 1 (the room's `fit_with`), else like the damping from the measured ring-downs. The two laws
//! exclude each other.

use palpate_motion::model::{Material, ParamKind};

use super::damping::{predict_damping, start_viscosity, viscosity_values};
use super::RunsEffect;
use crate::runs::fit::RunsModel;
use crate::runs::screen::ScreenPoint;
use crate::runs::{RunsError, RunsFit};
use crate::select::{ParamValue, Prediction};

/// See the module.
pub struct DampingPowerLaw;

impl RunsEffect for DampingPowerLaw {
    fn name(&self) -> &'static str {
        "damping-power-law"
    }

    fn kinds(&self) -> &'static [ParamKind] {
        &[ParamKind::Nu, ParamKind::PowerH]
    }

    fn start(&self, room: &RunsModel, round: usize, cur: &RunsFit, start: &mut Material) {
        start_viscosity(self, room, round, cur, start);
    }

    fn predict(&self, _room: &mut RunsModel, at: &ScreenPoint) -> Result<Prediction, RunsError> {
        Ok(predict_damping(self, at))
    }

    fn values(&self, material: &Material) -> Vec<ParamValue> {
        viscosity_values(material, false)
    }
}
