//! Density free (1 parameter, started at the current density). Only identifiable with measured
//! clamp forces: with prescribed clamps the motion depends on λ/ρ, μ/ρ, ν/ρ only.

use palpate_motion::model::ParamKind;

use super::{Candidate, MotionEffect};
use crate::motion::engine::MotionModel;
use crate::motion::fit::FittedModel;
use crate::motion::screen::Screening;
use crate::motion::MotionDiagnoseError;
use crate::select::{Outcome, Prediction};

/// See the module.
pub struct Density;

impl MotionEffect for Density {
    fn name(&self) -> &'static str {
        "density"
    }

    fn kinds(&self) -> &'static [ParamKind] {
        &[ParamKind::Density]
    }

    /// Linearised at the current density.
    fn screened_params(&self) -> &'static [(ParamKind, Option<f64>)] {
        &[(ParamKind::Density, None)]
    }

    /// Without clamp forces it is not fitted (nothing to predict); with them, linearised.
    fn predict(&self, s: &Screening<'_, '_>) -> Result<Prediction, MotionDiagnoseError> {
        if !s.model.has_forces {
            return Ok(Prediction::none("not identifiable without clamp forces"));
        }
        Ok(s.linearised(
            &[ParamKind::Density],
            1,
            "one Gauss–Newton step from the current density",
        ))
    }

    fn new_starts(&self, cur: &FittedModel, _dt: f64) -> Vec<Vec<f64>> {
        vec![vec![cur.material.get(ParamKind::Density, 0)]]
    }

    fn fit(
        &self,
        m: &MotionModel<'_>,
        c: Candidate,
        cur: &FittedModel,
    ) -> Result<Outcome<FittedModel>, MotionDiagnoseError> {
        if !m.has_forces {
            return Ok(Outcome::NotFitted(
                "not identifiable from markers alone: with prescribed clamps the motion \
                 depends on λ/ρ, μ/ρ, ν/ρ only (M a = f_int + M g), so ρ needs measured \
                 clamp forces (forces.csv)"
                    .into(),
            ));
        }
        Ok(match m.fit_from(cur, c) {
            Ok(f) => Outcome::Fitted(f),
            Err(e) => Outcome::NotFitted(format!("fit failed: {e}")),
        })
    }
}
