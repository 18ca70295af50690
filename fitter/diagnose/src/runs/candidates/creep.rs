//! Creep: one branch of a generalised-Maxwell (Prony) series on the elastic stress
//! ([`palpate_motion::relaxation`]): relaxed fraction g (dimensionless) and relaxation time τ
//! (s) free (2 parameters, fitted in ln g and ln τ). The fitted elastic law stays the long-term
//! one; just after a change of strain the stress is (1 + g) times it, relaxing in τ. A body
//! whose markers go on sinking after the ring-down, and a model that settles short of where the
//! capture ends, point to it.
//!
//! τ is held above the longest ring-down period measured in the fitted runs (the room's
//! `creep_floor`; the fit's coordinate is ln(τ − floor)): a branch that relaxes within a period
//! acts on the ring-down as a dashpot of viscosity ≈ gμτ, which is what the damping candidates are,
//! and a report that called it creep would name the wrong effect. Its fit starts with τ a quarter
//! of the shortest fitted run, or twice the floor where that is longer (creep slower than the
//! ring-down but seen within the capture). The fit screen predicts it by one Gauss–Newton step in g
//! itself from g = 0 with τ held at that start (at g = 0, τ has no effect: there is no slope in τ,
//! nor in ln g, the fit's coordinate), and the fit starts at the g that step reaches — the branch's
//! stress is linear in g at a fixed τ, so the step's g is the data's own estimate of the branch's
//! size, up to g = 1 — or at g = 0.05, a small branch, where the step gives less (on the measured
//! beam: g = 0.38 in round 1, its fit 5 simulations instead of 12 from 0.05; 0.14 in round 2, where
//! the fit ends at 0.129). Stiffening's c, also linear in its stress, keeps its start c = μ: from
//! the screen's step its fit took 9 simulations on the measured beam against 7. A step with τ held
//! can only under-state the gain of the fit, which frees τ; the screen's own rule then decides
//! (fitted when among the best predicted or within its margin of the best, or as a fall-back when
//! nothing fitted passes and it is predicted to pay). Runs that weigh the clamp's reaction force,
//! which a model with the branch cannot predict, are not offered it.

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

/// The largest relaxed fraction a fit starts from at the fit screen's step: a branch as stiff as
/// the relaxed law.
const MAX_SCREENED_FRACTION: f64 = 1.0;

/// The relaxed fraction the fit screen linearises at ([`ScreenPoint`]): at g = 0 the branch is
/// absent and carries no sensitivity, while here the runs differ from the current model's by
/// about this fraction of the branch's effect and dr/dg is its slope at g = 0 to the same
/// fraction — far below anything the screen's rule turns on.
pub(in crate::runs) const SCREEN_FRACTION: f64 = 1e-6;

/// The relaxation time the fit starts from (s): a quarter of the shortest fitted run (1 s when
/// the runs have no length), or twice the floor ([`RunsModel::creep_floor`]) where that is longer.
pub(in crate::runs) fn start_time(room: &RunsModel) -> f64 {
    let floor = room.creep_floor.map_or(0.0, |f| 2.0 * f);
    quarter_run(room).max(floor)
}

/// A quarter of the shortest fitted run (s; 1 s when the runs have no length).
fn quarter_run(room: &RunsModel) -> f64 {
    let shortest = room
        .fit
        .iter()
        .map(|(_, d)| d.model.steps as f64 * d.model.dt)
        .fold(f64::INFINITY, f64::min);
    if shortest.is_finite() && shortest > 0.0 {
        0.25 * shortest
    } else {
        1.0
    }
}

/// See the module.
pub struct Creep;

impl RunsEffect for Creep {
    fn name(&self) -> &'static str {
        "creep"
    }

    fn kinds(&self) -> &'static [ParamKind] {
        &ParamKind::CREEP
    }

    /// Not where a run weighs its clamp's reaction force: the reaction sums the elements'
    /// elastic and viscous forces, not the branch's stress, so no model with the branch can be
    /// evaluated on those runs ([`palpate_motion::gradient`] refuses it).
    fn available(&self, room: &RunsModel) -> bool {
        room.fit.iter().chain(room.held).all(|(_, d)| {
            d.obs.force_weight == 0.0 || d.obs.forces.iter().flatten().all(Option::is_none)
        })
    }

    fn unavailable_because(&self) -> &'static str {
        "a run records the clamp's reaction force, which a model with the branch cannot \
         predict (give the forces weight 0 to fit the markers alone)"
    }

    fn start(&self, room: &RunsModel, round: usize, _cur: &RunsFit, start: &mut Material) {
        if start.has_creep() {
            return;
        }
        let tau = start_time(room);
        let why = if tau > quarter_run(room) {
            "twice its floor"
        } else {
            "a quarter of the shortest fitted run"
        };
        let floor = room.creep_floor.map_or(String::new(), |f| {
            format!("; τ held above {f:.3} s, the longest measured ring-down period")
        });
        // Where the fit screen's step took g (τ at this start), when that is above the small
        // branch of the default start: the data's own pointer to the branch's size. A step
        // beyond a branch as stiff as the relaxed law is a linearisation at g = 0 taken far out
        // of its range: the start stops there.
        let (g, from) = match room.landing(round, ParamKind::CreepFraction) {
            Some(g) if g > MAX_SCREENED_FRACTION => {
                (MAX_SCREENED_FRACTION, "the fit screen's step, at most 1")
            }
            Some(g) if g > START_FRACTION => (g, "the fit screen's step"),
            _ => (START_FRACTION, "a small branch"),
        };
        (room.log)(&format!(
            "round {round}: creep starts at g = {g:.3} ({from}), τ = {tau:.3} s ({why}){floor}"
        ));
        start.set_uniform(ParamKind::CreepFraction, g);
        start.set_uniform(ParamKind::CreepTime, tau);
    }

    fn predict(&self, room: &mut RunsModel, at: &ScreenPoint) -> Result<Prediction, RunsError> {
        if !at.creep_slope {
            return Ok(Prediction::none(
                "no slope in g to step along: always fitted",
            ));
        }
        let how = format!(
            "one Gauss–Newton step in g from 0, τ held at {:.3} s",
            start_time(room)
        );
        let kind = ParamKind::CreepFraction;
        let (prediction, landing) = at.stepped_to(
            &[kind],
            self.parameters(at.runs),
            &how,
            Some((kind, SCREEN_FRACTION)),
        );
        if let Some(g) = landing {
            room.landed.push((at.round, kind, g));
        }
        Ok(prediction)
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
        let floor = match r.creep_floor_s {
            Some(f) if tau <= f * (1.0 + 1e-9) => format!(
                " τ sits on its floor, the longest ring-down period measured ({f:.3} s): the \
                 data ask for a faster branch, which would act on the ring-down as damping."
            ),
            Some(f) => format!(
                " τ was held above the longest ring-down period measured ({f:.3} s), below \
                 which a branch acts on the ring-down as damping."
            ),
            None => String::new(),
        };
        Some(format!(
            "\n**Creep.** Just after a change of strain the elastic stress is {:.3} times the fitted \
             law's (relaxed fraction g = {g:.3}), relaxing to it in τ = {tau:.3} s: under a \
             constant load the body creeps on by g/(1 + g) = {:.1} % of its deflection, with \
             creep time (1 + g) τ = {:.3} s (the standard linear solid at small strain).{floor}",
            1.0 + g,
            100.0 * g / (1.0 + g),
            (1.0 + g) * tau
        ))
    }
}
