//! The inertia of hanging weights: a weight hung with a declared mass from the release moves with
//! its nodes, the mass lumped on them (no new parameter: the declared mass). Tried only when
//! named among the candidates: the simplest model then treats the weights as forces only, and a
//! ring-down period it gets wrong points to the mass ([`crate::runs::RunsOptions::weights_move`];
//! by default the simplest model moves them). Offered only when some run, fitted or held out,
//! hangs such a weight.

use palpate_motion::fitted::{set_hanging_inertia, FittedModel};
use palpate_motion::model::Model;

use super::RunsEffect;
use crate::runs::fit::RunsModel;
use crate::runs::screen::ScreenPoint;
use crate::runs::RunsError;
use crate::select::Prediction;

/// See the module.
pub struct HangingInertia;

impl RunsEffect for HangingInertia {
    fn name(&self) -> &'static str {
        "hanging-inertia"
    }

    fn available(&self, room: &RunsModel) -> bool {
        crate::runs::hangs_a_weight(room.fit.iter().chain(room.held))
    }

    fn unavailable_because(&self) -> &'static str {
        "no run hangs a weight from its start"
    }

    fn change_model(&self, _room: &RunsModel, model: &mut Model) {
        set_hanging_inertia(model, true);
    }

    // A switch has no neutral value to linearise about: switched on, a weight that moves with
    // its nodes changes the period, and one Gauss–Newton step from the current material cannot
    // follow (a run whose timing was adopted was predicted +7,233 where its fit was adopted). It
    // is always fitted.
    fn predict(&self, _room: &mut RunsModel, _at: &ScreenPoint) -> Result<Prediction, RunsError> {
        Ok(Prediction {
            delta_bic: None,
            how: "a switch: always fitted".into(),
        })
    }

    fn record(&self, model: &mut FittedModel) {
        model.hanging_inertia = true;
    }
}
