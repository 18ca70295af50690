//! Each marker sits at a constant offset from its declared place (3 parameters per marker): a
//! marker glued a millimetre from where `markers.csv` says, a marker's centre above the surface,
//! a capture registered with a small shift. Eliminated in closed form (each marker's mean
//! residual on the fitted steps, [`fit_with_offsets`](crate::motion::fit::fit_with_offsets));
//! the held-out steps use the offsets fitted on the fitted steps.

use super::MotionEffect;
use crate::motion::fit::FittedModel;
use crate::motion::Value;

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
