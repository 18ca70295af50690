//! A layer: log E += a s_e, s_e = 1 / (1 + e^{−(t − d_e)/w}) — the material from the surface
//! the depth is measured from ([`LayerDepth::axis`](crate::statics::context::LayerDepth::axis))
//! down to the thickness t differs from the body's below it by the log contrast a. d_e is the
//! element centroid's depth and t the thickness, both as fractions of the axis' depth range; w
//! the edge's width ([`LayerDepth::edge_width`](crate::statics::context::LayerDepth::edge_width),
//! about one element), which keeps the field smooth in t. t = t₀ + (1 − t₀) / (1 + e^{−θ_t})
//! ([`LayerDepth::thickness`](crate::statics::context::LayerDepth::thickness)) is never thinner
//! than half an element, t₀: a thinner one is the mesh's own error at the surface. 2 params (a,
//! θ_t, dimensionless), started where the sensitivity scan puts the best layer. E is the body's
//! below the layer: the part of the object most measurements load. A property of the object:
//! the runtime model carries it per element.

use super::{at_zero_contrast, ParamName, StaticEffect};
use crate::statics::context::Context;
use crate::statics::signature::{EvidencePoints, Residual};

/// Thickness of the default start beyond the least one, as a fraction of the rest of the depth
/// range: a quarter.
const START_THICKNESS: f64 = 0.25;

/// See the module.
pub struct Layer;

impl StaticEffect for Layer {
    fn name(&self) -> &'static str {
        "layer"
    }

    fn params(&self, _grid: [usize; 3]) -> usize {
        2
    }

    /// The thickness is invisible at zero contrast, so the layer starts at a modest (softer)
    /// one, half an element and a quarter of the rest of the depth thick.
    fn start(&self, _grid: [usize; 3]) -> Vec<f64> {
        vec![-0.5, (START_THICKNESS / (1.0 - START_THICKNESS)).ln()]
    }

    /// The sensitivity scan's best layer: its thickness and Gauss–Newton contrast, the
    /// contrast's size kept between 0.3 (the thickness is invisible at zero contrast) and ln 10.
    fn fit_start(&self, ctx: &Context, grid: [usize; 3]) -> Vec<f64> {
        match ctx.layer.seed {
            Some([a, t]) => vec![
                a.signum() * a.abs().clamp(0.3, 10f64.ln()),
                ctx.layer.theta_of_thickness(t),
            ],
            None => self.start(grid),
        }
    }

    fn placed_by_scan(&self) -> bool {
        true
    }

    fn param_names(&self, _grid: [usize; 3]) -> Vec<ParamName> {
        vec![
            ("log contrast a of the layer".into(), "", 1.0),
            (
                "layer thickness θ_t (t = t₀ + (1 − t₀) / (1 + e^−θ_t) of the depth range, t₀ half an element)".into(),
                "",
                1.0,
            ),
        ]
    }

    fn in_runtime_model(&self) -> bool {
        true
    }

    fn evidence(&self, r: &Residual) -> EvidencePoints {
        r.error_against_distance()
    }

    /// At zero contrast, at its starting thickness.
    fn power_start(&self, grid: [usize; 3]) -> Option<Vec<f64>> {
        at_zero_contrast(self.start(grid))
    }

    /// Only the contrast: the thickness is invisible at zero contrast (the contrast is stated
    /// at the starting thickness).
    fn live_columns(&self, _grid: [usize; 3]) -> Vec<usize> {
        vec![0]
    }

    fn power_note(&self) -> Option<&'static str> {
        Some("a layer half an element and a quarter of the rest of the depth thick: its starting thickness")
    }

    fn material_field(&self) -> bool {
        true
    }

    fn add_log_e(&self, ctx: &Context, b: &[f64], out: &mut [f64]) {
        let t = ctx.layer.thickness(b[1]);
        let w = ctx.layer.edge_width();
        for (o, &d) in out.iter_mut().zip(&ctx.layer.depth) {
            *o += b[0] / (1.0 + (-(t - d) / w).exp());
        }
    }
}
