//! Inhomogeneity: log E varies over the bounding box as a trilinear field on a coarse grid
//! ([`Context::grid`], default 3 × 3 × 2 nodes, weights [`Context::grid_weights`]; the first
//! node is the reference, so grid − 1 params, each a dimensionless Δlog E). A property of the
//! object: the runtime model carries it per element.

use super::{ParamName, StaticEffect};
use crate::statics::context::Context;
use crate::statics::signature::{EvidencePoints, Residual};

/// See the module.
pub struct Inhomogeneity;

impl StaticEffect for Inhomogeneity {
    fn name(&self) -> &'static str {
        "inhomogeneity"
    }

    fn params(&self, grid: [usize; 3]) -> usize {
        grid[0] * grid[1] * grid[2] - 1
    }

    fn param_names(&self, grid: [usize; 3]) -> Vec<ParamName> {
        (1..grid[0] * grid[1] * grid[2])
            .map(|k| (format!("Δlog E at grid node {k}"), "", 1.0))
            .collect()
    }

    fn in_runtime_model(&self) -> bool {
        true
    }

    fn evidence(&self, r: &Residual) -> EvidencePoints {
        r.error_against_distance()
    }

    fn material_field(&self) -> bool {
        true
    }

    fn add_log_e(&self, ctx: &Context, b: &[f64], out: &mut [f64]) {
        for (o, ws) in out.iter_mut().zip(&ctx.grid_weights) {
            *o += ws
                .iter()
                .map(|&(k, w)| if k == 0 { 0.0 } else { w * b[k - 1] })
                .sum::<f64>();
        }
    }
}
