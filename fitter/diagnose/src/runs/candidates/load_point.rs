//! Where the hanging weights act: a weight hung from a hook that stands off the end acts at the
//! hook's point, a lever d beyond its nodes, and adds a moment in proportion to the weight that
//! the simplest model (the force shared by the loaded nodes) lacks. Its sign in the data: runs
//! under different weights fit different moduli, the heavier one softer. d is read from where the
//! fitted runs came to rest, before the rounds ([`palpate_motion::load_point::fit_lever`]: a
//! profile over d with μ refitted on the runs' rest states, the dataset's linear elements and
//! the held Poisson's ratio); the candidate moves every run's hanging weights by it and refits
//! the material on the motion, so its gain is judged on the held-out runs like any other
//! (1 parameter). Offered only when some fitted run hangs a weight and the rest states put d at
//! least 2σ from 0.

use palpate_motion::model::Model;

use super::RunsEffect;
use crate::runs::fit::RunsModel;
use crate::runs::screen::ScreenPoint;
use crate::runs::{RunsDiagnosis, RunsError};
use crate::select::Prediction;

/// See the module.
pub struct LoadPoint;

impl RunsEffect for LoadPoint {
    fn name(&self) -> &'static str {
        "load-point"
    }

    fn parameters(&self, _runs: usize) -> usize {
        1
    }

    // A value read from the rest states is worth a fit only where they determine it: d at least
    // twice its 1σ from 0 (the weights on their nodes).
    fn available(&self, room: &RunsModel) -> bool {
        room.lever
            .as_ref()
            .is_some_and(|l| l.offset_m.abs() >= 2.0 * l.sigma_m)
    }

    fn unavailable_because(&self) -> &'static str {
        "the fitted runs' rest states put no hanging weight's point off its nodes (by 2σ or more)"
    }

    fn change_model(&self, room: &RunsModel, model: &mut Model) {
        if let Some(l) = &room.lever {
            // The lever was built on the fitted runs' mesh, which every run shares
            // (`check_runs`): it cannot fail here but for a load of another shape.
            if let Err(e) = model.set_load_lever(l.offset_m) {
                log::warn!("load-point: {e}: that run's weights stay on their nodes");
            }
        }
    }

    // A structural change whose value is read from the rest states, not linearised about: it is
    // always fitted.
    fn predict(&self, _room: &mut RunsModel, _at: &ScreenPoint) -> Result<Prediction, RunsError> {
        Ok(Prediction {
            delta_bic: None,
            how: "read from the rest states: always fitted".into(),
        })
    }

    fn report(&self, r: &RunsDiagnosis) -> Option<String> {
        let l = r.load_lever.as_ref()?;
        Some(format!(
            "The hanging weights act {:.1} mm ± {:.1} mm beyond their nodes along the body's long axis \
             (read from the fitted runs' rest states: their marker RMS {:.3} → {:.3} mm with μ refitted, \
             {} offsets tried); every run's weights, held-out ones included, are moved by it.",
            1e3 * l.offset_m,
            1e3 * l.sigma_m,
            1e3 * l.rms_on_nodes_m,
            1e3 * l.rms_m,
            l.evaluations
        ))
    }
}
