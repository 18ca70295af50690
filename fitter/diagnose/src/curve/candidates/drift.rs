//! Sensitivity drift from run to run: the conductance scales by e^{δ (r − r̄)} in run r (one
//! parameter δ, per run, starting at 0). FSR data of at least two runs only. The per-run mean of
//! the residual points to it.

use super::{CurveEffect, Values};
use crate::curve::model::{Model, Param};
use crate::curve::read::Group;
use crate::curve::signature::Variable;

/// See the module.
pub struct Drift;

impl CurveEffect for Drift {
    fn name(&self) -> String {
        "drift".into()
    }

    fn words(&self) -> &'static str {
        "sensor drift from run to run"
    }

    fn available(&self, m: &Model, groups: usize, _rate_info: bool) -> bool {
        !m.family.mechanical() && !m.drift && groups >= 2
    }

    fn add_to(&self, m: &mut Model) {
        m.drift = true;
    }

    fn describe(&self, m: &Model) -> Option<String> {
        m.drift.then(|| "drift".into())
    }

    fn params(&self, m: &Model, out: &mut Vec<Param>) {
        if m.drift {
            out.push(Param::new("delta", "per run", false, false, 0.0));
        }
    }

    fn evidence(&self) -> &'static [Variable] {
        &[Variable::Group]
    }

    fn gain(&self, m: &Model, val: &Values<'_>, g: &Group) -> f64 {
        val("delta").map_or(1.0, |d| (d * (g.order - m.scale.order_mean)).exp())
    }
}
