//! Leave-one-out validation (the validation the thesis names as missing): fit on all measurements
//! but one, synthesise the held-out contact with the forward model, report its marker error.
//!
//! With one set for all measurements the held-out contact uses that set. With one set per
//! measurement (non-linear classes) there is no fitted set for the held-out contact: it uses the
//! set of the remaining measurement whose contact is nearest (contact point distance + force
//! difference scaled by the probe radius per newton), which is what a lookup-style playback would
//! do; the run-time blend is evaluated by the runtime, not here.

use palpate_fem::forward::SolveOptions;

use super::run::{fit_static, FitOptions};
use super::{FitError, FitInput, MeasurementResidual};

/// One held-out measurement's outcome.
#[derive(Debug, Clone, serde::Serialize)]
pub struct HeldOut {
    /// Residuals of the held-out measurement under the model fitted without it.
    pub residual: MeasurementResidual,
    /// RMS marker error of the fit on the remaining measurements (m).
    pub training_rms: f64,
}

/// Runs leave-one-out over every measurement.
pub fn leave_one_out(input: &FitInput, options: &FitOptions) -> Result<Vec<HeldOut>, FitError> {
    let n = input.measurements.len();
    if n < 2 {
        return Err(FitError::Input(
            "leave-one-out needs at least two measurements".into(),
        ));
    }
    let solve = SolveOptions {
        warp: options.warp,
        ..options.solve
    };
    let mut out = Vec::with_capacity(n);
    for j in 0..n {
        let mut train = input.clone();
        let held = train.measurements.remove(j);
        let fit = fit_static(&train, options, |_, _| {})?;
        let set = if fit.params.len() == 1 {
            0
        } else {
            let score = |k: usize| {
                let m = &train.measurements[k];
                let dp: f64 = (0..3)
                    .map(|d| (m.contact.point[d] - held.contact.point[d]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                let df: f64 = (0..3)
                    .map(|d| (m.contact.force[d] - held.contact.force[d]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                dp + held.contact.radius * df
            };
            (0..train.measurements.len())
                .min_by(|&a, &b| score(a).total_cmp(&score(b)))
                .unwrap_or(0)
        };
        let sol = input
            .problem
            .solve_forces(&fit.params[set], &held.force, None, &solve)?
            .solution;
        let residual =
            MeasurementResidual::new(held.id.clone(), set, input.marker_errors(j, &sol.x), None);
        out.push(HeldOut {
            residual,
            training_rms: fit.rms(),
        });
    }
    Ok(out)
}
