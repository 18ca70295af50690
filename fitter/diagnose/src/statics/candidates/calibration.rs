//! Force-sensor calibration curve: f_model = f_reported · (|f_reported| / f_ref)^p, f_ref the
//! largest reported magnitude. 1 param (p, dimensionless). A global scale is not separable from
//! E in a linear model, so only the power is fitted. A property of the probe's calibration, not
//! of the object: not in the runtime model.

use super::{ParamName, StaticEffect};
use crate::statics::context::Context;
use crate::statics::signature::{EvidencePoints, Residual};

/// See the module.
pub struct Calibration;

impl StaticEffect for Calibration {
    fn name(&self) -> &'static str {
        "calibration"
    }

    fn params(&self, _grid: [usize; 3]) -> usize {
        1
    }

    fn param_names(&self, _grid: [usize; 3]) -> Vec<ParamName> {
        vec![("power p".into(), "", 1.0)]
    }

    fn relative_note(&self, ctx: &Context) -> Option<String> {
        Some(format!(
            "Young's modulus is relative to the force sensor reading true at its largest force \
             ({} N): in a linear model the displacements scale with force over stiffness, so a \
             sensor gain cannot be told from E — only the calibration curve's power is fitted, \
             and E moves with whatever gain the sensor really has",
            palpate_fem::numbers::plain(ctx.frame.f_ref)
        ))
    }

    /// A curved calibration makes the displacement scale drift with the load.
    fn evidence(&self, r: &Residual) -> EvidencePoints {
        r.scale_against_force()
    }

    fn force(&self, ctx: &Context, b: &[f64], reported: f64, force: [f64; 3]) -> [f64; 3] {
        let k = if reported > 0.0 {
            (reported / ctx.frame.f_ref).powf(b[0])
        } else {
            1.0
        };
        force.map(|v| v * k)
    }
}
