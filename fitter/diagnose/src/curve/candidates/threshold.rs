//! Sensor turn-on threshold: the sensor responds to F_+ = max(F − F0, 0) (one parameter F0, N,
//! starting at 0 or 5 % of the largest force). FSR data only.

use super::{CurveEffect, Values};
use crate::curve::model::{Model, Param};

/// See the module.
pub struct Threshold;

impl CurveEffect for Threshold {
    fn name(&self) -> String {
        "turn-on-threshold".into()
    }

    fn words(&self) -> &'static str {
        "sensor turn-on threshold"
    }

    fn available(&self, m: &Model, _groups: usize, _rate_info: bool) -> bool {
        !m.family.mechanical() && !m.threshold
    }

    fn add_to(&self, m: &mut Model) {
        m.threshold = true;
    }

    fn describe(&self, m: &Model) -> Option<String> {
        m.threshold.then(|| "threshold".into())
    }

    fn params(&self, m: &Model, out: &mut Vec<Param>) {
        if m.threshold {
            out.push(Param::new("F0", "N", false, false, 0.0));
        }
    }

    fn alternatives(&self, p: &Param, m: &Model) -> Option<Vec<f64>> {
        let x = m.scale.x_max.max(1e-9);
        (p.name == "F0").then(|| vec![0.0, 0.05 * x])
    }

    fn sensed_force(&self, _m: &Model, val: &Values<'_>, force: &mut [f64]) {
        if let Some(f0) = val("F0") {
            force.iter_mut().for_each(|f| *f -= f0);
        }
    }
}
