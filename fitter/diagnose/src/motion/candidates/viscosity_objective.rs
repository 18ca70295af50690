//! The power-law viscosity of eq. 17 read objectively: on the Green–Lagrange strain rate, the
//! stress F S with S = ν γ̇^(h−1) 2Ė ([`palpate_motion::viscosity::Form::Objective`]), ν and h
//! free (2 parameters). Excludes the other two laws.
//!
//! The rest-gradient law of Real2Sim's public code, which the other two candidates fit, damps
//! an element that swings rigidly once it is turned: a cantilever hanging at its static slope
//! θ and swinging at θ̇ sees a spurious rate of about 2θθ̇, many times the bending's own strain
//! rate in a slender body. A body whose dissipation is objective (a finite-strain Kelvin–Voigt
//! solid, the independent generator's truth) is then fitted with a viscosity a sixteenth to a
//! twenty-first of its own and a power-law index of 0.14–0.85 for its Newtonian 1
//! (docs/results/diagnose/motion-independent, "The viscosity's two readings"); this candidate
//! lets the data say which reading they hold, on the same footing as the other two laws.

use palpate_motion::model::ParamKind;
use palpate_motion::viscosity::Form;

use super::viscosity::viscosity_starts;
use super::{Candidate, MotionEffect};
use crate::motion::engine::MotionModel;
use crate::motion::fit::FittedModel;
use crate::motion::screen::Screening;
use crate::motion::MotionDiagnoseError;
use crate::select::{Outcome, Prediction};

/// See the module.
pub struct ViscosityObjective;

impl MotionEffect for ViscosityObjective {
    fn name(&self) -> &'static str {
        "viscosity-objective"
    }

    fn kinds(&self) -> &'static [ParamKind] {
        &[ParamKind::Nu, ParamKind::PowerH]
    }

    fn conflicts(&self, other: Candidate) -> bool {
        matches!(other, Candidate::Viscosity | Candidate::ViscosityNewtonian)
    }

    /// A loss of energy, as the other laws: the mesh's error cannot make one.
    fn mimics_mesh_error(&self) -> bool {
        false
    }

    /// Where the dataset declares the objective law, the other two candidates fit it already.
    fn refusal(&self, m: &MotionModel<'_>) -> Option<String> {
        (m.ds.model.viscous_form == Form::Objective).then(|| {
            "the dataset declares the objective viscosity (viscosity_form): the viscosity \
             candidates fit it"
                .into()
        })
    }

    /// The current model with its viscosity read objectively, refitted with ν and h free.
    fn fit(
        &self,
        m: &MotionModel<'_>,
        c: Candidate,
        cur: &FittedModel,
    ) -> Result<Outcome<FittedModel>, MotionDiagnoseError> {
        if let Some(why) = self.refusal(m) {
            return Ok(Outcome::NotFitted(why));
        }
        let mut base = cur.clone();
        base.material.viscous_form = Form::Objective;
        Ok(super::refit(m, c, &base))
    }

    fn screened_params(&self) -> &'static [(ParamKind, Option<f64>)] {
        &[(ParamKind::Nu, Some(0.0))]
    }

    /// At ν = 0 both readings simulate the same motion, but their slopes in ν differ (the
    /// objective rate FᵀḞ + ḞᵀF against Ḟ + Ḟᵀ): the law is linearised on its own, one more
    /// simulation with sensitivities at the current model read objectively, and predicted as
    /// Newtonian damping charged its two parameters.
    fn predict(&self, s: &Screening<'_, '_>) -> Result<Prediction, MotionDiagnoseError> {
        let mut cur = s.cur.clone();
        cur.material.viscous_form = Form::Objective;
        let own = Screening::linearised_at(
            s.model,
            &cur,
            &[Candidate::ViscosityObjective],
            Some(s.unrealised()),
        )?;
        s.count(1);
        Ok(own.linearised(
            &[ParamKind::Nu],
            2,
            "one Gauss–Newton step from ν = 0 of the objective law, as Newtonian (h has no \
             effect there)",
        ))
    }

    /// Each viscosity start with h = 1 (Newtonian), as the rest-gradient power law's.
    fn new_starts(&self, cur: &FittedModel, dt: f64) -> Vec<Vec<f64>> {
        viscosity_starts(cur, dt)
            .iter()
            .map(|&nu| vec![nu, 1.0])
            .collect()
    }
}
