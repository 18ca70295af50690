//! Layered material: log E varies with depth below the probed face ([`LayerDepth::depth`](crate::statics::context::LayerDepth::depth), along
//! [`LayerDepth::axis`](crate::statics::context::LayerDepth::axis)), piecewise linear over [`LAYER_NODES`] equally spaced depths, the
//! deepest node the reference. LAYER_NODES − 1 params, each a dimensionless Δlog E. A property
//! of the object: the runtime model carries it per element.

use super::{ParamName, StaticEffect};
use crate::statics::context::{Context, LAYER_NODES};
use crate::statics::signature::{EvidencePoints, Residual};

/// See the module.
pub struct Layer;

impl StaticEffect for Layer {
    fn name(&self) -> &'static str {
        "layer"
    }

    fn params(&self, _grid: [usize; 3]) -> usize {
        LAYER_NODES - 1
    }

    fn param_names(&self, _grid: [usize; 3]) -> Vec<ParamName> {
        (0..LAYER_NODES - 1)
            .map(|k| (format!("Δlog E at depth {k}/{}", LAYER_NODES - 1), "", 1.0))
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
        // Nodes at depth k/(L−1); the deepest (k = L−1) is the reference.
        let last = (LAYER_NODES - 1) as f64;
        for (o, &d) in out.iter_mut().zip(&ctx.layer.depth) {
            let t = (d.clamp(0.0, 1.0) * last).min(last - 1e-12);
            let k = t.floor() as usize;
            let w = t - k as f64;
            let at = |j: usize| if j < LAYER_NODES - 1 { b[j] } else { 0.0 };
            *o += (1.0 - w) * at(k) + w * at(k + 1);
        }
    }
}
