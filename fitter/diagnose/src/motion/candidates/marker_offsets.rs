//! Each marker sits at a constant offset from its declared place (3 parameters per marker): a
//! marker glued a millimetre from where `markers.csv` says, a marker's centre above the surface,
//! a capture registered with a small shift. Eliminated in closed form (each marker's mean
//! residual on the fitted steps, [`fit_with_offsets`](crate::motion::fit::fit_with_offsets));
//! the held-out steps use the offsets fitted on the fitted steps.

use palpate_motion::model::ParamKind;

use super::{Candidate, MotionEffect};
use crate::motion::fit::{self, FittedModel};
use crate::motion::screen::Screening;
use crate::motion::{MotionDiagnoseError, Value};
use crate::select::Prediction;

/// See the module.
pub struct MarkerOffsets;

impl MotionEffect for MarkerOffsets {
    fn name(&self) -> &'static str {
        "marker-offsets"
    }

    fn extra_params(&self, markers: usize) -> usize {
        3 * markers
    }

    fn frees_marker_offsets(&self) -> bool {
        true
    }

    /// A turned gravity's static part is a constant offset of each marker: with the offsets
    /// free, the turn is left only the motion's second-order share and wanders (on the
    /// independent cylinder turned 3°, to 24° with ν 0.48 → 0.29), so it is held where the data
    /// put it before the offsets.
    fn holds(&self) -> &'static [ParamKind] {
        &ParamKind::GRAVITY
    }

    /// For the same reason a turn is not fitted on top of the offsets: it would be fitted on the
    /// motion's second-order share alone.
    fn conflicts(&self, other: Candidate) -> bool {
        other == Candidate::GravityDirection
    }

    /// In closed form at the current material: each marker's mean residual on the fitted steps
    /// removed (the gain of the offsets alone, the material not refitted).
    fn predict(&self, s: &Screening<'_, '_>) -> Result<Prediction, MotionDiagnoseError> {
        let markers = s.model.ds.model.markers.len();
        let mut traj = s.cur.traj.clone();
        fit::remove_marker_means(&mut traj, s.model.split, markers);
        let chi2 = fit::scores(&traj, s.model.split).chi2_fit;
        Ok(Prediction {
            delta_bic: Some(s.delta_bic(chi2, self.extra_params(markers))),
            how: "each marker's mean residual removed, the material not refitted".into(),
        })
    }

    /// The largest offset, when the model has them.
    fn summary_values(&self, fitted: &FittedModel) -> Vec<Value> {
        let Some(off) = &fitted.offsets else {
            return Vec::new();
        };
        let largest = off
            .iter()
            .map(|c| (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt())
            .fold(0.0, f64::max);
        vec![Value {
            name: format!("marker offsets ({} markers): largest |c| (m)", off.len()),
            value: largest,
            sigma: None,
        }]
    }
}
