//! A zero offset of the response (the load cell's zero): one parameter added to every reading,
//! N for tension data, MPa for stress–strain (linear in the prediction, solved at each start).
//! Mechanical data only.

use super::{CurveEffect, Values};
use crate::curve::model::{Family, Model, Param};

/// See the module.
pub struct Offset;

impl CurveEffect for Offset {
    fn name(&self) -> String {
        "offset".into()
    }

    fn words(&self) -> &'static str {
        "zero offset of the load cell"
    }

    fn available(&self, m: &Model, _groups: usize, _rate_info: bool) -> bool {
        m.family.mechanical() && !m.offset
    }

    fn add_to(&self, m: &mut Model) {
        m.offset = true;
    }

    fn describe(&self, m: &Model) -> Option<String> {
        m.offset.then(|| "offset".into())
    }

    fn params(&self, m: &Model, out: &mut Vec<Param>) {
        if m.offset {
            let unit = if matches!(m.family, Family::Tension { .. }) {
                "N"
            } else {
                "MPa"
            };
            out.push(Param::new("offset", unit, false, true, 0.0));
        }
    }

    fn zero(&self, _m: &Model, val: &Values<'_>, out: &mut [f64]) {
        if let Some(o) = val("offset") {
            out.iter_mut().for_each(|v| *v += o);
        }
    }
}
