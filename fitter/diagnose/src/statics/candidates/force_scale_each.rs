//! A force sensor whose gain differs from measurement to measurement (a drifting amplifier, a
//! probe re-seated on its load cell): measurement i's force is s_i times the reported one.
//! Profiled, not in θ: in the warped linear model the displacement scales with the force, so s_i
//! is the least-squares scale of the simulated marker displacements onto the measured ones, and
//! the s_i of the fitted measurements are divided by their geometric mean (a common gain is
//! Young's modulus's to fit). 1 parameter per measurement (dimensionless; one fewer when fitted
//! together), counted by BIC and the held-out gate. The probe, not the object: not in the
//! runtime model.

use super::{PowerPoint, ProfiledKind, StaticEffect};
use crate::statics::context::Context;
use crate::statics::power::measurement_columns;
use crate::statics::signature::{EvidencePoints, Residual};
use crate::statics::DiagnoseError;

/// See the module.
pub struct ForceScaleEach;

impl StaticEffect for ForceScaleEach {
    fn name(&self) -> &'static str {
        "force-scale-each"
    }

    fn relative_note(&self, _ctx: &Context) -> Option<String> {
        Some(
            "Young's modulus is relative to the geometric mean of the fitted measurements' force \
             gains: each measurement's gain is fitted, and a gain common to all of them cannot \
             be told from E"
                .into(),
        )
    }

    fn profiled(&self, measurements: usize) -> usize {
        measurements
    }

    fn affects_solve(&self) -> bool {
        false
    }

    fn evidence(&self, r: &Residual) -> EvidencePoints {
        r.scale_by_measurement()
    }

    /// One column per measurement: its markers' displacement (a scale 1 + s moves them by s
    /// times it).
    fn profiled_columns(&self, p: &PowerPoint) -> Option<Result<Vec<ProfiledKind>, DiagnoseError>> {
        let ctx = p.at.ctx;
        let cols = measurement_columns(ctx, p.subset, &p.sim.markers, &|k, p, _| {
            let rest = ctx.marker_rest[k];
            [0, 1, 2].map(|d| p[d] - rest[d])
        });
        Some(Ok(vec![("force scale s", "", cols)]))
    }

    /// Each measurement's simulated displacements (from the markers' rest places) scaled by the
    /// s_i that fits its measured ones best, the s_i of several measurements divided by their
    /// geometric mean. A measurement whose markers do not move, or whose best scale is not
    /// positive, keeps s_i = 1.
    fn scale_responses(&self, ctx: &Context, subset: &[usize], sims: &mut [Vec<[f64; 3]>]) {
        let scales: Vec<f64> = subset
            .iter()
            .zip(sims.iter())
            .map(|(&i, sim)| {
                let mut sums = (0.0, 0.0);
                ctx.add_scale_terms(i, sim, &mut sums);
                match sums.0 / sums.1 {
                    s if s.is_finite() && s > 0.0 => s,
                    _ => 1.0,
                }
            })
            .collect();
        let mean_log = if scales.len() > 1 {
            scales.iter().map(|s| s.ln()).sum::<f64>() / scales.len() as f64
        } else {
            0.0
        };
        for ((&i, sim), s) in subset.iter().zip(sims.iter_mut()).zip(&scales) {
            let s = s / mean_log.exp();
            for (&(k, _), p) in ctx.meas[i].observed.iter().zip(sim.iter_mut()) {
                let rest = ctx.marker_rest[k];
                for d in 0..3 {
                    p[d] = rest[d] + s * (p[d] - rest[d]);
                }
            }
        }
    }
}
