//! The clamp gives: the body is held less rigidly than a Dirichlet boundary holds it (rubber
//! jaws, a clamp that rocks on its stand, the held part of the body squeezed). As in the single
//! run's candidate ([`crate::motion::candidates::clamp_compliance`]): the layer of elements that
//! touch a clamp's nodes, softened as a whole — both Lamé moduli by one factor, so that it keeps
//! the body's Poisson's ratio and yields in tension, compression and shear alike, as an elastic
//! interface does (1 parameter, the layer's μ, fitted in ln μ with the material). Runs under
//! different weights tell it from a softer body: the give turns the whole body about its root,
//! so a heavier weight moves the free end by more than the body's bending alone, and the end
//! turns further.
//!
//! Only a softer layer is a clamp that gives; a layer fitted stiffer than the body is refused —
//! the sign of linear elements' own error where the bending is largest, or of jaws that hold
//! more of the body than the clamped nodes (on the measured beam, fitted from half the body's
//! moduli, the layer comes out 1.9–3.3× stiffer in every round). The fit screen
//! predicts it from the layer's own column in the round's one Gauss–Newton evaluation (the layer
//! held at the body's moduli there: the current model); a step that stiffens the layer predicts
//! nothing of it.

use palpate_motion::fitted::FittedModel;
use palpate_motion::model::{Material, Model, Param, ParamKind};

use super::{Effect, RunsEffect};
use crate::motion::candidates::clamp_compliance::{layer_thickness, softenable_layer};
use crate::runs::fit::{fitted, RunsModel};
use crate::runs::screen::ScreenPoint;
use crate::runs::{RunsDiagnosis, RunsError, RunsFit};
use crate::select::{Outcome, ParamValue, Prediction};

/// The layer's μ at the fit's start, as a fraction of the body's: softer than the body, where
/// the misfit has a slope (at the body's own μ a small give is flat in χ²), and within a few
/// Levenberg–Marquardt steps in ln μ of a layer ten times softer or as stiff as the body.
const START_FRACTION: f64 = 0.5;

/// See the module.
pub struct ClampCompliance;

/// The clamp layer a model of the runs could soften: the fitted runs' mesh's (every run shares
/// it), not already a region of `material`. `Err`: why there is none.
pub(in crate::runs) fn open_layer(
    room: &RunsModel,
    material: &Material,
) -> Result<Vec<usize>, String> {
    let (_, d) = room.fit.first().ok_or("no fitted run")?;
    if !material.scaled_regions.is_empty() {
        return Err("the clamp layer is already in the model".into());
    }
    softenable_layer(&d.model)
}

/// The clamp layer of `material` (its one region scaled as a whole): (region, μ, the body's μ).
fn layer_of(material: &Material) -> Option<(usize, f64, f64)> {
    let &r = material.scaled_regions.first()?;
    let mu = material.read(&[Param::in_region(ParamKind::Mu, r)])[0];
    Some((r, mu, material.body_moduli().1))
}

impl RunsEffect for ClampCompliance {
    fn name(&self) -> &'static str {
        "clamp-compliance"
    }

    fn parameters(&self, _runs: usize) -> usize {
        1
    }

    fn available(&self, room: &RunsModel) -> bool {
        room.fit
            .first()
            .is_some_and(|(_, d)| softenable_layer(&d.model).is_ok())
    }

    fn unavailable_because(&self) -> &'static str {
        "no clamp layer to soften: no element touches a clamp, or the elements there hold more \
         than a third of the body"
    }

    fn start(&self, room: &RunsModel, round: usize, _cur: &RunsFit, start: &mut Material) {
        let Ok(layer) = open_layer(room, start) else {
            return;
        };
        let body_mu = start.body_moduli().1;
        let r = start.regions.len();
        (room.log)(&format!(
            "round {round}: clamp-compliance starts with the {} elements at the clamps at {START_FRACTION}× the body's moduli",
            layer.len()
        ));
        start.regions.push(layer);
        start.scaled_regions.push(r);
        start.set(
            &[Param::in_region(ParamKind::Mu, r)],
            &[START_FRACTION * body_mu],
        );
    }

    fn fit(
        &self,
        room: &mut RunsModel,
        round: usize,
        cur: &RunsFit,
        effects: &[Effect],
        start: &Material,
        budget: u64,
    ) -> Result<Outcome<RunsFit>, RunsError> {
        if layer_of(start).is_none() {
            return Ok(Outcome::NotFitted(
                open_layer(room, start).err().unwrap_or_default(),
            ));
        }
        let f = fitted(room.fit_effects(round, effects, start, &cur.offsets, budget));
        if let Outcome::Fitted(f) = &f {
            if let Some((_, mu, body)) = layer_of(&f.material) {
                let ratio = mu / body;
                if ratio >= 1.0 {
                    return Ok(Outcome::NotFitted(format!(
                        "the layer at the clamp came out {ratio:.2}× as stiff as the body: a root \
                         stiffer than the body is not a clamp that gives (linear elements' own \
                         error where the bending is largest, or a clamp that holds more of the \
                         body than its clamped nodes)"
                    )));
                }
            }
        }
        Ok(f)
    }

    fn predict(&self, _room: &mut RunsModel, at: &ScreenPoint) -> Result<Prediction, RunsError> {
        Ok(at.layer_stepped(self.parameters(at.runs)))
    }

    fn values(&self, material: &Material) -> Vec<ParamValue> {
        let Some((r, mu, body)) = layer_of(material) else {
            return Vec::new();
        };
        vec![
            ParamValue {
                name: format!(
                    "μ of the layer at the clamps ({} elements; λ follows at the body's Poisson's ratio)",
                    material.regions[r].len()
                ),
                value: mu,
                sd: f64::NAN,
                unit: "Pa".into(),
            },
            ParamValue {
                name: "the clamp layer's moduli over the body's".into(),
                value: mu / body,
                sd: f64::NAN,
                unit: "".into(),
            },
        ]
    }

    fn record(&self, model: &mut FittedModel) {
        // The per-element moduli carry the layer; the record names the parameter fitted.
        model.fitted.push("mu of the clamp layer".into());
    }

    fn report(&self, r: &RunsDiagnosis) -> Option<String> {
        let layer = r.clamp_layer.as_ref()?;
        let interface = match layer.thickness_m {
            Some(t) => format!(
                " As the interface it stands for (the layer's {:.1} mm mean thickness taken out): \
                 {:.3e} Pa/m across the clamp's face, (λ + 2μ)/t, and {:.3e} Pa/m along it, μ/t.",
                1e3 * t,
                (layer.lambda + 2.0 * layer.mu) / t,
                layer.mu / t
            ),
            None => String::new(),
        };
        Some(format!(
            "\n**The clamp gives.** The {} elements at the clamps are {:.2}× as stiff as the body \
             (μ {:.1} kPa against {:.1} kPa), both Lamé moduli softened together.{interface}",
            layer.elements,
            layer.mu / layer.body_mu,
            layer.mu / 1e3,
            layer.body_mu / 1e3
        ))
    }
}

/// The fitted clamp layer, as the report describes it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ClampLayer {
    /// Elements in the layer.
    pub elements: usize,
    /// The layer's Lamé λ and μ (Pa).
    pub lambda: f64,
    /// See `lambda`.
    pub mu: f64,
    /// The body's μ (Pa).
    pub body_mu: f64,
    /// The layer's volume over its area on the clamps (m); `None` when no face lies on a clamp.
    pub thickness_m: Option<f64>,
}

/// The clamp layer of the final `material` on the runs' mesh `model`, when it has one.
pub(in crate::runs) fn clamp_layer(model: &Model, material: &Material) -> Option<ClampLayer> {
    let (r, mu, body_mu) = layer_of(material)?;
    let elements = &material.regions[r];
    let lambda = material.read(&[Param::in_region(ParamKind::Lambda, r)])[0];
    Some(ClampLayer {
        elements: elements.len(),
        lambda,
        mu,
        body_mu,
        thickness_m: layer_thickness(model, elements),
    })
}
