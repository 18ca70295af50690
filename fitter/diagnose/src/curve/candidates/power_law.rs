//! Non-linear (power-law) sensor response: the conductance follows g = F_+^b instead of F_+
//! (one parameter b, dimensionless, starting at 1). FSR data only.

use super::{CurveEffect, Values};
use crate::curve::model::{Model, Param};
use crate::curve::read::Group;

/// See the module.
pub struct PowerLaw;

impl CurveEffect for PowerLaw {
    fn name(&self) -> String {
        "power-law-response".into()
    }

    fn words(&self) -> &'static str {
        "non-linear (power-law) sensor response"
    }

    fn available(&self, m: &Model, _groups: usize, _rate_info: bool) -> bool {
        !m.family.mechanical() && !m.power
    }

    fn add_to(&self, m: &mut Model) {
        m.power = true;
    }

    fn describe(&self, m: &Model) -> Option<String> {
        m.power.then(|| "power-law response".into())
    }

    fn params(&self, m: &Model, out: &mut Vec<Param>) {
        if m.power {
            out.push(Param::new("b", "1", false, false, 1.0));
        }
    }

    fn respond(&self, m: &Model, val: &Values<'_>, _g: &Group, s: &mut [f64]) {
        if m.power {
            let b = val("b").unwrap_or(1.0);
            s.iter_mut().for_each(|s| *s = s.powf(b));
        }
    }
}
