//! Sensor saturation at high force: the conductance levels off, g/(1 + F/F_sat) (one parameter
//! F_sat, N, fitted in its logarithm, starting at the largest force or a fifth of it). FSR data
//! only. The residual over the top of the force range points to it.

use super::{CurveEffect, Values};
use crate::curve::model::{Model, Param};
use crate::curve::read::Group;
use crate::curve::signature::Variable;

/// See the module.
pub struct Saturation;

impl CurveEffect for Saturation {
    fn name(&self) -> String {
        "saturation".into()
    }

    fn words(&self) -> &'static str {
        "sensor saturation at high force"
    }

    fn available(&self, m: &Model, _groups: usize, _rate_info: bool) -> bool {
        !m.family.mechanical() && !m.saturation
    }

    fn add_to(&self, m: &mut Model) {
        m.saturation = true;
    }

    fn describe(&self, m: &Model) -> Option<String> {
        m.saturation.then(|| "saturation".into())
    }

    fn params(&self, m: &Model, out: &mut Vec<Param>) {
        if m.saturation {
            let start = m.scale.x_max.max(1e-9);
            out.push(Param::new("F_sat", "N", true, false, start));
        }
    }

    fn alternatives(&self, p: &Param, m: &Model) -> Option<Vec<f64>> {
        let x = m.scale.x_max.max(1e-9);
        (p.name == "F_sat").then(|| vec![x, x / 5.0])
    }

    fn evidence(&self) -> &'static [Variable] {
        &[Variable::Top, Variable::Magnitude]
    }

    fn respond(&self, _m: &Model, val: &Values<'_>, g: &Group, s: &mut [f64]) {
        if let Some(fs) = val("F_sat") {
            for (s, &f) in s.iter_mut().zip(&g.x) {
                *s /= 1.0 + f.max(0.0) / fs;
            }
        }
    }
}
