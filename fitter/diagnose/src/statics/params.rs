//! A fit's parameters in physical units with their uncertainties: the base material's E and ν and
//! each adopted effect's, as the report and the export state them.

use super::fit::Fitted;
use super::model::{poisson_of, Candidate, Context};
use crate::select::ParamValue;

/// Physical values of the parameters of `c` in fit `f`.
pub fn effect_params(ctx: &Context, f: &Fitted, c: Candidate) -> Vec<ParamValue> {
    let Some(o) = f.model.offset(c, ctx.grid) else {
        return Vec::new();
    };
    c.param_names(ctx.grid)
        .into_iter()
        .enumerate()
        .map(|(j, (name, unit, scale))| ParamValue {
            name,
            value: f.theta[o + j] * scale,
            sd: f.theta_sd[o + j] * scale,
            unit: unit.into(),
        })
        .collect()
}

/// E and ν of a fit with their uncertainties (delta method).
pub fn base_params(f: &Fitted) -> Vec<ParamValue> {
    let e = f.theta[0].exp();
    let nu = poisson_of(f.theta[1]);
    let dnu = 0.75 * (1.0 - f.theta[1].tanh().powi(2));
    vec![
        ParamValue {
            name: "Young's modulus E".into(),
            value: e,
            sd: e * f.theta_sd[0],
            unit: "Pa".into(),
        },
        ParamValue {
            name: "Poisson ratio ν".into(),
            value: nu,
            sd: dnu * f.theta_sd[1],
            unit: "".into(),
        },
    ]
}
