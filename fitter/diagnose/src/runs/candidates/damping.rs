//! Newtonian viscosity: the viscous stress of eq. 17 at h = 1, ν free (1 parameter, Pa·s). A
//! ring-down that decays faster than the simplest model's (which has no viscosity) points to it.
//! Its fit starts from the viscosity the measured ring-downs show
//! ([`crate::runs::viscosity_from_ring_down`]) unless the options give one.

use palpate_motion::model::{Material, Param, ParamKind};

use super::RunsEffect;
use crate::runs::fit::RunsModel;
use crate::runs::screen::ScreenPoint;
use crate::runs::{viscosity_from_ring_down, RunsError, RunsFit};
use crate::select::{ParamValue, Prediction};

/// See the module.
pub struct Damping;

impl RunsEffect for Damping {
    fn name(&self) -> &'static str {
        "damping"
    }

    fn kinds(&self) -> &'static [ParamKind] {
        &[ParamKind::Nu]
    }

    fn start(&self, room: &RunsModel, round: usize, cur: &RunsFit, start: &mut Material) {
        start_viscosity(self, room, round, cur, start);
    }

    fn predict(&self, _room: &mut RunsModel, at: &ScreenPoint) -> Result<Prediction, RunsError> {
        Ok(predict_damping(self, at))
    }

    fn values(&self, material: &Material) -> Vec<ParamValue> {
        viscosity_values(material, true)
    }
}

/// Starts a damping law's viscosity where `start` has none (a law that nests one fitted this
/// round starts from that fit's): the option, else the ring-down estimate of the current model's
/// runs, else 10 Pa·s.
pub(super) fn start_viscosity(
    effect: &dyn RunsEffect,
    room: &RunsModel,
    round: usize,
    cur: &RunsFit,
    start: &mut Material,
) {
    if start.get(ParamKind::Nu, 0) <= 0.0 {
        let (nu, source) = start_of(room, cur);
        (room.log)(&format!(
            "round {round}: {} starts at viscosity {nu:.3e} Pa·s ({source})",
            effect.name()
        ));
        start.set(&[Param::global(ParamKind::Nu)], &[nu]);
    }
}

/// Where a damping law's viscosity starts on top of `cur`, and whence: the option, else the
/// ring-down estimate of the current model's runs, else 10 Pa·s.
pub(in crate::runs) fn start_of(room: &RunsModel, cur: &RunsFit) -> (f64, &'static str) {
    match room.o.start_viscosity {
        Some(v) => (v, "given"),
        None => match viscosity_from_ring_down(&cur.fitted, cur.material.body_moduli().1) {
            Some(v) => (v, "from the measured ring-downs"),
            None => (10.0, "no run rings down: the default"),
        },
    }
}

/// A damping law's prediction at `at`: one Gauss–Newton step from no viscosity, or one from its
/// fit's start where that gains more ([`ScreenPoint::started`]).
pub(super) fn predict_damping(effect: &dyn RunsEffect, at: &ScreenPoint) -> Prediction {
    let k = effect.parameters(at.runs);
    at.started(at.stepped(effect.kinds(), k), effect.kinds(), k)
}

/// The viscosity and the power-law index of the final material, as the report lists them for
/// either damping law: `newtonian`, the law that holds h at 1, its viscosity in Pa·s and its
/// index said to be held (the names before the parenthesis are the same for both laws).
pub(super) fn viscosity_values(material: &Material, newtonian: bool) -> Vec<ParamValue> {
    let (law, unit, index) = if newtonian {
        (
            "viscosity (Newtonian)",
            "Pa·s",
            "power-law index h (held: Newtonian)",
        )
    } else {
        ("viscosity (power law)", "Pa·s^h", "power-law index h")
    };
    vec![
        ParamValue {
            name: law.into(),
            value: material.get(ParamKind::Nu, 0),
            sd: f64::NAN,
            unit: unit.into(),
        },
        ParamValue {
            name: index.into(),
            value: material.get(ParamKind::PowerH, 0),
            sd: f64::NAN,
            unit: "".into(),
        },
    ]
}
