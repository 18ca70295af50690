//! Tilted probe / tangential friction: f_model = f_reported + |f_reported| (a t₁ + b t₂) with
//! t₁, t₂ perpendicular to the mean reported direction ([`Context::tangents`]). 2 params (a, b,
//! dimensionless). The probe's direction, not the object: not in the runtime model.

use super::{ParamName, StaticEffect};
use crate::statics::context::Context;
use crate::statics::signature::{EvidencePoints, Residual};

/// See the module.
pub struct Tilt;

impl StaticEffect for Tilt {
    fn name(&self) -> &'static str {
        "tilt"
    }

    fn params(&self, _grid: [usize; 3]) -> usize {
        2
    }

    fn param_names(&self, _grid: [usize; 3]) -> Vec<ParamName> {
        vec![
            ("tangential a".into(), "", 1.0),
            ("tangential b".into(), "", 1.0),
        ]
    }

    fn evidence(&self, r: &Residual) -> EvidencePoints {
        r.horizontal_mean_against_force()
    }

    fn force(&self, ctx: &Context, b: &[f64], reported: f64, force: [f64; 3]) -> [f64; 3] {
        let [t1, t2] = ctx.tangents;
        [0, 1, 2].map(|d| force[d] + reported * (b[0] * t1[d] + b[1] * t2[d]))
    }
}
