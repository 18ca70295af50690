//! The clamp gives: the body is held less rigidly than a Dirichlet boundary holds it (rubber
//! jaws, a clamp that rocks on its stand, the held part of the body itself squeezed). Modelled
//! as the layer of elements that touch a clamp's nodes softened as a whole — both Lamé moduli by
//! one factor, so that it keeps the body's Poisson's ratio ([`Material::scaled_regions`]) and
//! yields in tension, compression and shear alike, as an elastic interface does: one parameter,
//! the layer's μ. The fitted layer is reported as the interface it stands for, a stiffness per
//! area k = modulus / thickness along and across the clamp's face, which does not depend on how
//! thick the mesh makes the layer.
//!
//! Only a softer layer is a compliant clamp. A layer that comes out stiffer than the body is the
//! other sign of what a coarse mesh does at a clamp (its linear elements are too stiff where the
//! bending is largest, the fitted body too soft to make up for it elsewhere, and the root then
//! asks for more stiffness): refused, as the second material refuses a region no thicker than
//! that layer ([`crate::motion::region::at_clamp_layer`]). A softer layer that passes is still
//! checked against the mesh's own null before it is adopted ([`crate::motion::mesh_null`]).

use palpate_motion::model::{Material, Model, Param, ParamKind};
use rayon::prelude::*;

use super::{Candidate, MotionEffect};
use crate::motion::engine::MotionModel;
use crate::motion::fit::{self, FittedModel};
use crate::motion::screen::{self as motion_screen, Screening};
use crate::motion::{MotionDiagnoseError, MotionOptions, Value};
use crate::screen;
use crate::select::{Outcome, Prediction};

/// The largest share of the body's volume the clamp layer may hold: on a mesh so coarse that
/// the elements at the clamp are more than a third of the body there is no layer to speak of,
/// and softening it would be a softer body, not a clamp that gives. (A cantilever of four cells,
/// the example bar, has a quarter of its volume at the clamp: the cell that carries the largest
/// bending moment, where a clamp's give and a soft root cannot be told apart.)
const MAX_LAYER_SHARE: f64 = 1.0 / 3.0;

/// The layer's μ at the short fits' starts, as fractions of the body's.
const LAYER_STARTS: [f64; 3] = [1.0, 0.4, 0.15];

/// Iterations of each short fit.
const SHORT_ITERS: u64 = 5;

/// See the module.
pub struct ClampCompliance;

impl MotionEffect for ClampCompliance {
    fn name(&self) -> &'static str {
        "clamp-compliance"
    }

    /// The layer's μ; its place is the clamps', not chosen from the data.
    fn extra_params(&self, _markers: usize) -> usize {
        1
    }

    /// Both place a material of their own in part of the body; one region effect at a time.
    fn conflicts(&self, other: Candidate) -> bool {
        other == Candidate::TwoMaterial
    }

    fn fit(
        &self,
        m: &MotionModel<'_>,
        c: Candidate,
        cur: &FittedModel,
    ) -> Result<Outcome<FittedModel>, MotionDiagnoseError> {
        let (start, r) = match with_layer(&m.ds.model, cur) {
            Ok(s) => s,
            Err(why) => return Ok(Outcome::NotFitted(why)),
        };
        // The layer's μ from the body's (the current model) and from two softer starts, each
        // fitted short beside the others; the best continued. A clamp that gives much (the
        // layer at a fifth of the body's moduli) is not reached from the body's μ in a fit's
        // iterations: the misfit is flat there until the layer is soft enough to matter.
        let short = MotionOptions {
            max_iters: m.o.screen_iters.min(SHORT_ITERS),
            ..m.o.clone()
        };
        let screener = m.with_options(&short);
        let fits: Vec<Result<FittedModel, MotionDiagnoseError>> = LAYER_STARTS
            .par_iter()
            .map(|&k| screener.fit_from(&scaled(&start, r, k), c))
            .collect();
        let mut evaluations = 0;
        let mut best: Option<FittedModel> = None;
        let mut failures = Vec::new();
        for f in fits {
            match f {
                Ok(f) => {
                    evaluations += f.evaluations;
                    if best
                        .as_ref()
                        .is_none_or(|b| f.scores.chi2_fit < b.scores.chi2_fit)
                    {
                        best = Some(f);
                    }
                }
                Err(e) => failures.push(e.to_string()),
            }
        }
        let Some(best) = best else {
            return Ok(Outcome::NotFitted(format!(
                "fit failed from every start: {}",
                failures.join("; ")
            )));
        };
        // The best of the short fits, from the body's μ and from softer layers, already stiffer
        // than the body: the data pull the layer up from every start, and the fit continued from
        // there is refused below for the same reason — it is not run.
        if let Some(ratio) = stiffer(&best) {
            return Ok(Outcome::NotFitted(format!(
                "the layer at the clamp came out {ratio:.2}× as stiff as the body in the best of \
                 {} short fits from its start at the body's μ and softer ones: {STIFFER_ROOT}",
                LAYER_STARTS.len()
            )));
        }
        let mut f = match m.fit_from(&best, c) {
            Ok(f) => f,
            Err(e) => return Ok(Outcome::NotFitted(format!("fit failed: {e}"))),
        };
        f.evaluations += evaluations;
        if layer_of(&f).is_none() {
            return Ok(Outcome::NotFitted("the fit lost the clamp layer".into()));
        }
        if let Some(ratio) = stiffer(&f) {
            return Ok(Outcome::NotFitted(format!(
                "the layer at the clamp came out {ratio:.2}× as stiff as the body: {STIFFER_ROOT}"
            )));
        }
        Ok(Outcome::Fitted(f))
    }

    /// One Gauss–Newton step over the current parameters and the layer's μ, from the layer at
    /// the body's μ (the current model): a simulation with sensitivities of its own. A step that
    /// stiffens the layer predicts no gain (the candidate's charge alone): a refit of the current
    /// parameters, which the step also holds, is no gain of the clamp's give.
    fn predict(&self, s: &Screening<'_, '_>) -> Result<Prediction, MotionDiagnoseError> {
        let (start, _) = match with_layer(&s.model.ds.model, s.cur) {
            Ok(start) => start,
            Err(why) => return Ok(Prediction::none(&why)),
        };
        let params = fit::params_for(&start.kinds, &start.material);
        let (normal, chi2_sim) = match s.linearise(&start.material, &params) {
            Ok(l) => l,
            Err(e) => {
                return Ok(Prediction::none(&format!(
                    "its linearisation did not simulate ({e}): always fitted"
                )))
            }
        };
        let parts = std::slice::from_ref(&normal);
        let layer_col = params.len() - 1;
        let cols: Vec<usize> = (0..params.len()).collect();
        let delta = screen::step(parts, &cols);
        let extra = self.extra_params(0);
        if delta[layer_col] >= 0.0 {
            // Held at the body's μ the layer adds nothing; what a refit of the current
            // parameters alone would gain is no gain of this candidate's.
            return Ok(Prediction {
                delta_bic: Some(s.delta_bic(s.cur.scores.chi2_fit, extra)),
                how: "one Gauss–Newton step from the layer at the body's μ stiffens the layer: \
                      no clamp that gives is predicted"
                    .into(),
            });
        }
        let change = screen::change(parts, &cols, &delta)[0];
        Ok(s.predicted(
            motion_screen::stepped_chi2(s.cur, &normal, chi2_sim, change),
            extra,
            "one Gauss–Newton step from the layer at the body's μ",
        ))
    }

    /// The layer's μ, its thickness, and the interface it stands for.
    fn values(&self, fitted: &FittedModel, model: &Model) -> Vec<Value> {
        let Some(layer) = layer_of(fitted) else {
            return Vec::new();
        };
        let rel = layer.sigma.map(|s| s / layer.mu);
        let thickness = layer_thickness(model, &fitted.material.regions[layer.region]);
        let lambda = layer.ratio * layer.mu;
        let mut out = vec![Value {
            name: format!(
                "mu of the layer at the clamps ({} elements, {:.2}× the body's; λ follows at \
                 the body's Poisson's ratio)",
                fitted.material.regions[layer.region].len(),
                layer.mu / layer.body_mu
            ),
            value: layer.mu,
            sigma: layer.sigma,
        }];
        if let Some(t) = thickness {
            out.push(Value {
                name: "clamp layer's mean thickness (m)".into(),
                value: t,
                sigma: None,
            });
            for (name, k) in [
                (
                    "clamp compliance: stiffness per area across the clamp face, (λ + 2μ)/t (Pa/m)",
                    (lambda + 2.0 * layer.mu) / t,
                ),
                (
                    "clamp compliance: stiffness per area along the clamp face, μ/t (Pa/m)",
                    layer.mu / t,
                ),
            ] {
                out.push(Value {
                    name: name.into(),
                    value: k,
                    sigma: rel.map(|r| r * k),
                });
            }
        }
        out
    }
}

/// `cur` with the clamp layer as a region of its own at the body's moduli (scaled as a whole),
/// its μ a parameter — the start of the candidate's fit, where it is the current model — and
/// the layer's index among the regions. `Err`: why there is no layer to soften.
fn with_layer(model: &Model, cur: &FittedModel) -> Result<(FittedModel, usize), String> {
    if layer_of(cur).is_some() {
        return Err("the clamp layer is already in the model".into());
    }
    let layer = softenable_layer(model)?;
    if layer
        .iter()
        .any(|e| cur.material.regions.iter().flatten().any(|r| r == e))
    {
        return Err("the clamp layer overlaps a region already in the model".into());
    }
    let body_mu = cur.material.body_moduli().1;
    let mut start = cur.clone();
    let r = start.material.regions.len();
    start.material.regions.push(layer);
    start.material.scaled_regions.push(r);
    start
        .material
        .set(&[Param::in_region(ParamKind::Mu, r)], &[body_mu]);
    start.values.push(body_mu);
    if let Some(s) = start.sigma.as_mut() {
        s.push(f64::NAN);
    }
    Ok((start, r))
}

/// The layer of elements at the clamps ([`Model::clamp_layer`]) when there is one to soften:
/// `Err` says why not (no element at a clamp, or a mesh so coarse there that the layer is more
/// than [`MAX_LAYER_SHARE`] of the body). The runs room's candidate asks the same of its mesh.
pub(crate) fn softenable_layer(model: &Model) -> Result<Vec<usize>, String> {
    let layer = model.clamp_layer();
    if layer.is_empty() {
        return Err("no element touches a clamp: no clamp to give".into());
    }
    let volume =
        |es: &mut dyn Iterator<Item = usize>| es.map(|e| model.rest[e].volume).sum::<f64>();
    let share = volume(&mut layer.iter().copied()) / volume(&mut (0..model.tets.len()));
    if share > MAX_LAYER_SHARE {
        return Err(format!(
            "the elements at the clamps hold {:.0} % of the volume (at most {:.0} %): the mesh is \
             too coarse at the clamps to soften a layer there",
            100.0 * share,
            100.0 * MAX_LAYER_SHARE
        ));
    }
    Ok(layer)
}

/// `start` with its clamp layer, region `r`, at `k` times the body's μ (and so λ).
fn scaled(start: &FittedModel, r: usize, k: f64) -> FittedModel {
    let mut s = start.clone();
    let mu = k * s.material.body_moduli().1;
    s.material.set(&[Param::in_region(ParamKind::Mu, r)], &[mu]);
    let first = s.values.len() - s.material.regions.len();
    s.values[first + r] = mu;
    s
}

/// The clamp layer of a fitted model.
struct Layer {
    /// Its index among the material's regions.
    region: usize,
    /// Its μ (Pa) and 1σ.
    mu: f64,
    sigma: Option<f64>,
    /// λ/μ it keeps: the body's.
    ratio: f64,
    /// The body's μ (Pa).
    body_mu: f64,
}

/// Why a layer stiffer than the body is refused (see the module).
const STIFFER_ROOT: &str =
    "a root stiffer than the body is a coarse mesh's own error at a clamp, not a clamp that gives";

/// The layer's μ over the body's where it is at least 1: a layer no softer than the body.
fn stiffer(f: &FittedModel) -> Option<f64> {
    let layer = layer_of(f)?;
    let ratio = layer.mu / layer.body_mu;
    (ratio >= 1.0).then_some(ratio)
}

/// The clamp layer of `f`: the region scaled as a whole (the only kind of region this candidate
/// makes; the second material's shares the body's λ).
fn layer_of(f: &FittedModel) -> Option<Layer> {
    let &region = f.material.scaled_regions.first()?;
    let first = f.values.len() - f.material.regions.len();
    let (lambda, body_mu) = f.material.body_moduli();
    Some(Layer {
        region,
        mu: f.values[first + region],
        sigma: f.sigma.as_ref().map(|s| s[first + region]),
        ratio: lambda / body_mu,
        body_mu,
    })
}

/// Whether region `r` of `mat` is a clamp layer (not a second material).
pub fn is_layer(mat: &Material, r: usize) -> bool {
    mat.scaled_regions.contains(&r)
}

/// The layer's volume over the area of its faces on the clamps (the faces whose three nodes are
/// all clamped): its mean thickness. `None` when no face lies on a clamp.
pub(crate) fn layer_thickness(model: &Model, layer: &[usize]) -> Option<f64> {
    let clamped = |n: usize| model.node_clamp[n] != usize::MAX;
    let mut area = 0.0;
    let mut volume = 0.0;
    for &e in layer {
        let t = model.tets[e];
        volume += model.rest[e].volume;
        for skip in 0..4 {
            let face: Vec<usize> = (0..4).filter(|&i| i != skip).map(|i| t[i]).collect();
            if face.iter().all(|&n| clamped(n)) {
                let p = |i: usize| nalgebra::Vector3::from(model.nodes[face[i]]);
                area += 0.5 * (p(1) - p(0)).cross(&(p(2) - p(0))).norm();
            }
        }
    }
    (area > 0.0).then(|| volume / area)
}
