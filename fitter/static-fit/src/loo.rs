//! Leave-one-out validation (the validation the thesis names as missing): fit on all measurements
//! but one, synthesise the held-out contact with the forward model, report its marker error.
//!
//! With one set for all measurements the held-out contact uses that set. With one set per
//! measurement (the non-linear classes, thesis §8 names this validation as missing) there is no
//! fitted set for the held-out contact: it is played through the blend exported with the
//! remaining sets ([`crate::blend::for_fit`]: deformation-space RBF for homogeneous sets,
//! strain-space RBF for inhomogeneous ones), re-blended at the state as the runtime does
//! ([`crate::blend::solve_blended`]) — the playback the exported model gives.

use palpate_fem::forward::SolveOptions;

use super::blend::{for_fit, solve_blended, BlendData};
use super::run::{fit_static, FitOptions};
use super::{FitError, FitInput, MeasurementResidual};

/// One held-out measurement's outcome.
#[derive(Debug, Clone, serde::Serialize)]
pub struct HeldOut {
    /// Residuals of the held-out measurement under the model fitted without it.
    pub residual: MeasurementResidual,
    /// RMS marker error of the fit on the remaining measurements (m).
    pub training_rms: f64,
    /// Played through the blend of the remaining sets (the non-linear classes).
    pub blended: bool,
    /// Whether the blended parameters settled at the held-out state (always true for one set).
    pub blend_settled: bool,
}

/// Re-blend rounds at full load of a held-out blended solve.
pub const MAX_BLEND_ROUNDS: usize = 30;

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
        let blend = for_fit(&input.problem, fit.layout, &fit.params, &fit.deformed)?;
        let (x, settled) = solve_blended(
            &input.problem,
            &fit.params,
            &blend,
            &held.force,
            &solve,
            MAX_BLEND_ROUNDS,
        )?;
        let residual =
            MeasurementResidual::new(held.id.clone(), 0, input.marker_errors(j, &x), None);
        out.push(HeldOut {
            residual,
            training_rms: fit.rms(),
            blended: !matches!(blend, BlendData::None),
            blend_settled: settled,
        });
    }
    Ok(out)
}
