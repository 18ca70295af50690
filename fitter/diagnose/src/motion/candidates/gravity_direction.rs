//! The gravity acts along another direction than the declared one: the object mounted turned,
//! or the lab's vertical registered wrong (2 parameters: the turn toward the two axes across
//! the declared gravity, [`palpate_motion::model::Model::gravity_axes`]; the magnitude kept).
//!
//! A turn leaves the sag along the declared gravity almost as it was (cos θ) and adds one across
//! it (sin θ) that no material parameter makes, and it rings in the motion like the sag does.
//! Its parameters are [`ParamKind::GRAVITY`]'s: q = exp(tan θ_axis), so that the fitter's
//! ln q is the turn itself, of either sign, and q = 1 the declared gravity.

use palpate_motion::model::{Model, ParamKind};

use super::MotionEffect;
use crate::motion::engine::MotionModel;
use crate::motion::fit::FittedModel;
use crate::motion::Value;

/// The largest turn (degrees) a fit starts from ([`MotionEffect::screened_start`]).
pub const MAX_START_TURN: f64 = 10.0;

/// See the module.
pub struct GravityDirection;

/// Why the candidate is not offered for `model`, if it is not: no gravity declared, or a
/// hanging weight declared as a mass that comes on after the start (a mass hanging from the
/// start turns with the gravity, [`Model::turned_weights`]; one that comes on later is not
/// modelled so).
fn not_offered(model: &Model) -> Option<String> {
    if model.gravity_axes().is_none() {
        return Some("no gravity declared: nothing to turn".into());
    }
    model
        .loads
        .iter()
        .find(|l| l.mass.is_some() && l.from_step > 0)
        .map(|l| {
            format!(
                "the hanging weight {:?} comes on at step {}: its force would turn with the \
                 gravity from then on, which this candidate does not model",
                l.name, l.from_step
            )
        })
}

impl MotionEffect for GravityDirection {
    fn name(&self) -> &'static str {
        "gravity-direction"
    }

    fn kinds(&self) -> &'static [ParamKind] {
        &ParamKind::GRAVITY
    }

    /// Linearised at the declared gravity (q = 1: no turn).
    fn screened_params(&self) -> &'static [(ParamKind, Option<f64>)] {
        &[
            (ParamKind::GravityTiltA, Some(1.0)),
            (ParamKind::GravityTiltB, Some(1.0)),
        ]
    }

    fn refusal(&self, m: &MotionModel<'_>) -> Option<String> {
        not_offered(&m.ds.model)
    }

    /// From the declared gravity.
    fn new_starts(&self, _cur: &FittedModel, _dt: f64) -> Vec<Vec<f64>> {
        vec![vec![1.0, 1.0]]
    }

    /// From where the screen's step turned it: the screen steps q from 1, where dq = d(ln q),
    /// so the step is the turn's tangent itself and the start exp of it (q stays positive). A
    /// step that turns gravity by more than [`MAX_START_TURN`] is shortened to it, its
    /// direction kept: one Gauss–Newton step from the declared gravity is a linearisation, and
    /// where the misfit is the mesh's (on the independent generator's coarse cylinders it
    /// stepped the turn far enough that the start no longer simulated: "system matrix not
    /// positive definite" at the third step) the fit starts where the linearisation still
    /// holds and goes further itself if the data ask for it.
    fn screened_start(&self, stepped: &dyn Fn(ParamKind) -> Option<f64>) -> Option<Vec<f64>> {
        let z: Vec<f64> = ParamKind::GRAVITY
            .iter()
            .map(|&k| stepped(k).map(|q| q - 1.0))
            .collect::<Option<_>>()?;
        let turn = z.iter().map(|v| v * v).sum::<f64>().sqrt();
        let cap = MAX_START_TURN.to_radians().tan();
        let shorten = if turn > cap { cap / turn } else { 1.0 };
        Some(z.iter().map(|v| (shorten * v).exp()).collect())
    }

    /// The turn toward each cross axis (degrees, with its 1σ; "held" where a later effect holds
    /// it) and the gravity acting, where the model turns it.
    fn values(&self, fitted: &FittedModel, model: &Model) -> Vec<Value> {
        let Some((ea, eb)) = model.gravity_axes() else {
            return Vec::new();
        };
        let at = |k: ParamKind| fitted.kinds.iter().position(|&x| x == k);
        let turned = ParamKind::GRAVITY
            .iter()
            .any(|&k| fitted.material.get(k, 0) != 1.0);
        if ParamKind::GRAVITY.iter().all(|&k| at(k).is_none()) && !turned {
            return Vec::new();
        }
        let axis = |e: [f64; 3]| format!("({:.3}, {:.3}, {:.3})", e[0], e[1], e[2]);
        let mut out = Vec::new();
        for (k, e) in ParamKind::GRAVITY.into_iter().zip([ea, eb]) {
            let q = fitted.material.get(k, 0);
            let z = q.ln();
            // dθ/dq = 1/(q (1 + z²)) for θ = atan(ln q).
            let sigma = at(k).and_then(|i| fitted.sigma.as_ref().map(|s| s[i]));
            out.push(Value {
                name: format!(
                    "gravity turned toward {} (degrees{})",
                    axis(e),
                    if at(k).is_some() { "" } else { ", held" }
                ),
                value: z.atan().to_degrees(),
                sigma: sigma.map(|s| (s / (q * (1.0 + z * z))).to_degrees()),
            });
        }
        let g = model.gravity_of(&fitted.material);
        for (i, name) in ["x", "y", "z"].into_iter().enumerate() {
            out.push(Value {
                name: format!("gravity acting, {name} (m/s²)"),
                value: g[i],
                sigma: None,
            });
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The screen's step is the start where it turns gravity by less than the cap; beyond, the
    /// start turns by the cap in the step's direction.
    #[test]
    fn a_screened_turn_starts_at_most_the_cap_away() {
        let start = |za: f64, zb: f64| {
            let stepped = move |k: ParamKind| match k {
                ParamKind::GravityTiltA => Some(1.0 + za),
                ParamKind::GravityTiltB => Some(1.0 + zb),
                _ => None,
            };
            GravityDirection
                .screened_start(&stepped)
                .expect("both turns stepped")
        };
        let small = start(0.03, -0.04);
        assert!((small[0].ln() - 0.03).abs() < 1e-15 && (small[1].ln() + 0.04).abs() < 1e-15);
        let large = start(3.0, -4.0);
        let z = [large[0].ln(), large[1].ln()];
        let turn = z[0].hypot(z[1]).atan().to_degrees();
        assert!((turn - MAX_START_TURN).abs() < 1e-9, "{turn}");
        assert!((z[0] / z[1] + 0.75).abs() < 1e-12, "{z:?}");
    }
}
