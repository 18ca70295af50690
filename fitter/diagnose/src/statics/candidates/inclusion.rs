//! A stiff or soft inclusion: log E += a exp(−½ ‖x_e − p‖² / r²), a Gaussian blob with contrast
//! a, centre p = p₀ + h θ (h the half width, p₀ = [`InclusionStart::centre`](crate::statics::context::InclusionStart::centre), below the mean
//! contact point at a quarter of the depth) and radius r = ½ h exp(θ_r). 5 params (a, p/h, θ_r,
//! dimensionless). A property of the object: the runtime model carries it per element.

use super::{at_zero_contrast, ParamName, StaticEffect};
use crate::statics::context::Context;
use crate::statics::signature::{EvidencePoints, Residual};

/// See the module.
pub struct Inclusion;

impl StaticEffect for Inclusion {
    fn name(&self) -> &'static str {
        "inclusion"
    }

    fn params(&self, _grid: [usize; 3]) -> usize {
        5
    }

    /// Position and size are invisible at zero contrast, so the blob starts at a modest one.
    fn start(&self, _grid: [usize; 3]) -> Vec<f64> {
        vec![0.5, 0.0, 0.0, 0.0, 0.0]
    }

    /// The sensitivity scan's blob: its centre is the start's centre, so the offsets start at
    /// zero; contrast and radius from its Gauss–Newton step.
    fn fit_start(&self, ctx: &Context, grid: [usize; 3]) -> Vec<f64> {
        match ctx.inclusion.seed {
            Some(seed) => seed.to_vec(),
            None => self.start(grid),
        }
    }

    fn placed_by_scan(&self) -> bool {
        true
    }

    fn param_names(&self, _grid: [usize; 3]) -> Vec<ParamName> {
        let v = |n: &str| (n.to_string(), "", 1.0);
        vec![
            v("log contrast a"),
            v("centre offset x / h"),
            v("centre offset y / h"),
            v("centre offset z / h"),
            v("log radius θ_r (r = h/2 e^θ_r)"),
        ]
    }

    fn in_runtime_model(&self) -> bool {
        true
    }

    fn evidence(&self, r: &Residual) -> EvidencePoints {
        r.error_against_distance()
    }

    /// At zero contrast: its starting place.
    fn power_start(&self, grid: [usize; 3]) -> Option<Vec<f64>> {
        at_zero_contrast(self.start(grid))
    }

    /// Only the contrast: the position and radius are invisible at zero contrast (the contrast
    /// is stated at the candidate's starting place).
    fn live_columns(&self, _grid: [usize; 3]) -> Vec<usize> {
        vec![0]
    }

    fn power_note(&self) -> Option<&'static str> {
        Some("r = h/2, centred a quarter deep below the mean contact point: its starting place")
    }

    fn material_field(&self) -> bool {
        true
    }

    fn add_log_e(&self, ctx: &Context, b: &[f64], out: &mut [f64]) {
        let p = [0, 1, 2].map(|d| ctx.inclusion.centre[d] + ctx.frame.half * b[1 + d]);
        let r = 0.5 * ctx.frame.half * b[4].clamp(-5.0, 5.0).exp();
        for (o, c) in out.iter_mut().zip(&ctx.centroids) {
            let d2: f64 = (0..3).map(|d| (c[d] - p[d]).powi(2)).sum();
            *o += b[0] * (-0.5 * d2 / (r * r)).exp();
        }
    }
}
