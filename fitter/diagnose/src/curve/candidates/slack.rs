//! Slack: the specimen cannot carry compression. A membrane or strip slackens (buckles) when the
//! model force would turn negative, so the measured force stays at zero: F = max(F_model, 0),
//! after every viscous branch and before the zero offset. No parameter; tension data only.
//! Hysteresis and the load magnitude point to it (the unloading branch flattens at zero).

use super::CurveEffect;
use crate::curve::model::{Family, Model};
use crate::curve::signature::Variable;

/// See the module.
pub struct Slack;

impl CurveEffect for Slack {
    fn name(&self) -> String {
        "slack".into()
    }

    fn words(&self) -> &'static str {
        "slack: the specimen buckles instead of carrying compression"
    }

    fn available(&self, m: &Model, _groups: usize, _rate_info: bool) -> bool {
        !m.slack && matches!(m.family, Family::Tension { .. })
    }

    fn add_to(&self, m: &mut Model) {
        m.slack = true;
    }

    fn describe(&self, m: &Model) -> Option<String> {
        m.slack.then(|| "slack".into())
    }

    fn evidence(&self) -> &'static [Variable] {
        &[Variable::Direction, Variable::Magnitude]
    }

    fn clip(&self, m: &Model, out: &mut [f64]) {
        if m.slack {
            out.iter_mut().for_each(|v| *v = v.max(0.0));
        }
    }
}
