//! Creep: one branch of a generalised-Maxwell (Prony) series on the elastic stress
//! ([`palpate_motion::relaxation`]): relaxed fraction g (dimensionless) and relaxation time τ
//! (s) free (2 parameters, fitted in ln g and ln τ). The fitted elastic law stays the long-term
//! one; just after a change of strain the stress is (1 + g) times it, relaxing in τ. A body
//! whose markers go on sinking after the ring-down, and a model that settles short of where the
//! capture ends, point to it.
//!
//! Its fit starts at g = 0.05 and τ a quarter of the shortest fitted run (creep slower than the
//! ring-down but seen within the capture). At g = 0 the branch is absent and τ has no effect,
//! so there is no slope to linearise about: the fit screen does not predict it, it is always
//! fitted.

use palpate_motion::fitted::FittedModel;
use palpate_motion::model::{Material, ParamKind};

use super::RunsEffect;
use crate::runs::fit::RunsModel;
use crate::runs::screen::ScreenPoint;
use crate::runs::{RunsDiagnosis, RunsError, RunsFit};
use crate::select::{ParamValue, Prediction};

/// The relaxed fraction the fit starts from: a small branch, so that the start is the current
/// model nearly unchanged.
const START_FRACTION: f64 = 0.05;

/// See the module.
pub struct Creep;

impl RunsEffect for Creep {
    fn name(&self) -> &'static str {
        "creep"
    }

    fn kinds(&self) -> &'static [ParamKind] {
        &ParamKind::CREEP
    }

    fn start(&self, room: &RunsModel, round: usize, _cur: &RunsFit, start: &mut Material) {
        if start.has_creep() {
            return;
        }
        let shortest = room
            .fit
            .iter()
            .map(|(_, d)| d.model.steps as f64 * d.model.dt)
            .fold(f64::INFINITY, f64::min);
        let tau = if shortest.is_finite() && shortest > 0.0 {
            0.25 * shortest
        } else {
            1.0
        };
        (room.log)(&format!(
            "round {round}: creep starts at g = {START_FRACTION}, τ = {tau:.3} s (a quarter of \
             the shortest fitted run)"
        ));
        start.set_uniform(ParamKind::CreepFraction, START_FRACTION);
        start.set_uniform(ParamKind::CreepTime, tau);
    }

    fn predict(&self, _room: &mut RunsModel, _at: &ScreenPoint) -> Result<Prediction, RunsError> {
        Ok(Prediction {
            delta_bic: None,
            how: "no slope at g = 0: always fitted".into(),
        })
    }

    fn values(&self, material: &Material) -> Vec<ParamValue> {
        vec![
            ParamValue {
                name: "creep: relaxed fraction g".into(),
                value: material.get(ParamKind::CreepFraction, 0),
                sd: f64::NAN,
                unit: "".into(),
            },
            ParamValue {
                name: "creep: relaxation time τ".into(),
                value: material.get(ParamKind::CreepTime, 0),
                sd: f64::NAN,
                unit: "s".into(),
            },
        ]
    }

    fn record(&self, _model: &mut FittedModel) {
        // The material carries the branch: `FittedModel::creep` is written from it.
    }

    fn report(&self, r: &RunsDiagnosis) -> Option<String> {
        let c = r.model.creep.as_ref()?;
        let (g, tau) = (*c.fraction.first()?, *c.time_s.first()?);
        Some(format!(
            "\n**Creep.** Just after a change of strain the elastic stress is {:.3} times the fitted \
             law's (relaxed fraction g = {g:.3}), relaxing to it in τ = {tau:.3} s: under a \
             constant load the body creeps on by g/(1 + g) = {:.1} % of its deflection, with \
             creep time (1 + g) τ = {:.3} s (the standard linear solid at small strain).",
            1.0 + g,
            100.0 * g / (1.0 + g),
            (1.0 + g) * tau
        ))
    }
}
