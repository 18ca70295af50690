//! The mesh's own null: would a candidate pass on data that hold no effect but the dataset
//! mesh's discretisation error?
//!
//! Linear tetrahedra at a dataset's resolution are too stiff, most where the strain varies
//! fastest (at a clamp, in bending), and a fit on that mesh leaves a residual shaped by it. A
//! candidate that can bend the coarse model towards a finer one — a second material at the clamp,
//! a strain stiffening, a constant offset per marker for the static sag the coarse mesh gets
//! wrong — lowers that residual and passes the gate on data that hold no such effect (on the
//! independent generator's cylinders: marker offsets, a stiffer region at the clamp and a
//! stiffening adopted on data whose only effect was a viscous damping).
//!
//! Before a passing candidate is adopted it is therefore fitted a second time, on the null: the
//! current model simulated on the mesh refined once ([`palpate_motion::model::Model::refined`]), observed at the same
//! markers and steps without noise. On
//! the null the current model is refitted first, from its moduli scaled to the softer refined
//! object (a golden-section search over one scale of the moduli), then the candidate on top of
//! it, exactly as on the data. The χ² it removes there, fitted (Δχ²₀) and held out (Δχ²₀,h), is what the mesh's own error lets it
//! remove. On the data it must remove more: with χ²₀ the current fit's and χ²₁ the candidate's,
//!
//!   ΔBIC beyond the null = n ln((χ²₁ + Δχ²₀)/χ²₀) + Δk ln n < −threshold,
//!   held-out RMS beyond the null = √((χ²₁,h + Δχ²₀,h)/χ²₀,h) − 1 ≤ −min_holdout_gain,
//!
//! the adoption rule's own thresholds on what the candidate explains beyond the mesh. The null
//! holds no noise: what a candidate removes of noise by chance it removes on the data too, and
//! the rule's k ln n already charges it. It stands for a truth finer than
//! the dataset's mesh — what a real object is; on data simulated on the dataset's mesh itself
//! (a test of the library's confusions, `palpate-lab motion-confusion`) there is no mesh error
//! to guard against and the check is off. Where the data's own truth is coarser than the refined
//! mesh, the null holds more mesh error than the data do and the check errs on the side of
//! refusing. Clamp forces are left out of the null (the density candidate, identifiable only
//! with them, is not fitted there: nothing is handed back from its gain). A dissipative
//! candidate is not checked ([`super::candidates::MotionEffect::mimics_mesh_error`]).

use palpate_motion::dataset::MotionDataset;
use palpate_motion::golden_section::{golden_section, Stop};
use palpate_motion::model::{Material, ParamKind};
use palpate_motion::optimize::precision;
use palpate_motion::refine::marker_paths;
use serde::Serialize;
use std::convert::Infallible;

use super::candidates::Candidate;
use super::engine::MotionModel;
use super::fit::{fit_model, fit_with_offsets, fitted_part, run_trajectory, FittedModel, Split};
use super::mesh::Refined;
use super::MotionOptions;
use crate::select::{bic, Outcome};

/// A candidate checked against the mesh's own null.
#[derive(Debug, Clone, Serialize)]
pub struct NullCheck {
    /// Tetrahedra of the refined mesh that made the null.
    pub refined_tets: usize,
    /// The data's declared noise floor σ√3 (m), when declared.
    pub noise_floor: Option<f64>,
    /// RMS of the current model refitted on the null, fitted steps (m).
    pub base_rms_fit: f64,
    /// The scale of the current moduli the refit on the null started from: how much softer
    /// the refined mesh is.
    pub modulus_scale: f64,
    /// The candidate's fitted ΔBIC on the null (0 when it could not be fitted there). The null
    /// holds no noise, so this log ratio of small χ² runs large; the decision reads the χ²
    /// removed instead.
    pub delta_bic: f64,
    /// The candidate's relative held-out RMS change on the null.
    pub heldout_gain: f64,
    /// Its fitted ΔBIC on the data with the χ² it removes on the null handed back.
    pub excess_delta_bic: f64,
    /// Its held-out RMS change on the data with the held-out χ² it removes on the null handed
    /// back.
    pub excess_heldout_gain: f64,
    /// Refused: it explains no more than the mesh's own error.
    pub refused: bool,
    /// Simulations the check ran (the null, the refit of the current model, the candidate's).
    pub evaluations: usize,
    /// What was found, in words for the report.
    pub statement: String,
    /// The candidate's fitted values on the null, when it was fitted there: once it is adopted,
    /// where a refit of the model it makes on a null of the mesh starts
    /// ([`MotionModel::mesh_floor`]).
    #[serde(skip)]
    pub(super) on_null_values: Option<Vec<f64>>,
}

/// Relative change of a parameter under one refinement above which the fitted value is the mesh's
/// and not the material's: the 5 % a converged parameter is held to across two discretisations
/// ([`crate::convergence::TOLERANCE`]).
pub const BIAS_TOLERANCE: f64 = crate::convergence::TOLERANCE;

/// What the mesh's own null says of the fitted parameters, where no rest state can: the current
/// model of a round simulated on the mesh refined once and read back on the dataset's mesh. A
/// parameter this mesh reads at r times its value on the refined mesh's motion reads the data at
/// r times the refined mesh's reading too, to first order; the refined mesh would read the data
/// at about value / r. Measured at the first null a diagnosis makes (usually the first round's,
/// at the simplest fit, at no cost beyond the checks); where no check made one and the capture
/// has no rest state to check the modulus on, the first round's null is made for it
/// (`MotionModel::first_null_bias`).
#[derive(Debug, Clone, Serialize)]
pub struct MeshBias {
    /// The round whose current model the null was made at.
    pub round: usize,
    /// Tetrahedra of the refined mesh.
    pub refined_tets: usize,
    /// Each fitted positive parameter of that model.
    pub parameters: Vec<BiasedValue>,
    /// Whether every one moves by at most [`BIAS_TOLERANCE`] in the refinement.
    pub converged: bool,
    /// What it means, in words for the report.
    pub statement: String,
}

/// One parameter read through the dataset mesh and through the mesh refined once.
#[derive(Debug, Clone, Serialize)]
pub struct BiasedValue {
    /// The parameter ([`ParamKind::name`]).
    pub name: String,
    /// Its value in the round's current model: the data read on the dataset mesh (SI).
    pub fitted: f64,
    /// What the dataset mesh reads from that model's motion on the mesh refined once.
    pub on_null: f64,
    /// The first-order estimate of the data read on the refined mesh: fitted² / on_null.
    pub refined_estimate: f64,
    /// The SI unit of the three values.
    pub unit: &'static str,
}

/// The parameters of `kinds` with their values `fitted` and their readings `on_null` (the same
/// order), those positive in both, and whether each stays within [`BIAS_TOLERANCE`].
pub fn biased_values(
    kinds: &[ParamKind],
    fitted: &[f64],
    on_null: &[f64],
) -> (Vec<BiasedValue>, bool) {
    let values: Vec<BiasedValue> = kinds
        .iter()
        .zip(fitted.iter().zip(on_null))
        .filter(|(_, (a, b))| **a > 0.0 && **b > 0.0 && a.is_finite() && b.is_finite())
        .map(|(k, (&a, &b))| BiasedValue {
            name: k.name().to_string(),
            fitted: a,
            on_null: b,
            refined_estimate: a * a / b,
            unit: match k {
                ParamKind::Lambda | ParamKind::Mu | ParamKind::Stiffening => "Pa",
                ParamKind::Nu => "Pa·s^h",
                ParamKind::Density => "kg/m³",
                ParamKind::CreepTime => "s",
                _ => "",
            },
        })
        .collect();
    let converged = values
        .iter()
        .all(|v| (v.on_null / v.fitted - 1.0).abs() <= BIAS_TOLERANCE);
    (values, converged)
}

impl MeshBias {
    /// The bias the null of round `round` (the current model `cur` refitted there as `base`, on
    /// `refined_tets` tetrahedra) shows; `None` when no parameter of `cur` is positive in both.
    fn of(
        round: usize,
        refined_tets: usize,
        cur: &FittedModel,
        base: &FittedModel,
    ) -> Option<Self> {
        if base.kinds != cur.kinds {
            return None;
        }
        let n = cur.kinds.len();
        let (parameters, converged) =
            biased_values(&cur.kinds, &cur.values[..n], &base.values[..n]);
        if parameters.is_empty() {
            return None;
        }
        let list = |f: &dyn Fn(&BiasedValue) -> String| {
            parameters.iter().map(f).collect::<Vec<_>>().join(", ")
        };
        let read = list(&|v| format!("{} × {:.3}", v.name, v.on_null / v.fitted));
        let statement = if converged {
            format!(
                "round {round}'s model simulated on the mesh refined once ({refined_tets} \
                 tetrahedra) is read back on this mesh at {read}: every parameter within {:.0} % \
                 of its value under one refinement",
                100.0 * BIAS_TOLERANCE
            )
        } else {
            format!(
                "round {round}'s model simulated on the mesh refined once ({refined_tets} \
                 tetrahedra) is read back on this mesh at {read}: NOT converged — the fitted \
                 values move by more than {:.0} % in one refinement and are this mesh's; read on \
                 the mesh refined once, the same data would give about {} (first order: value² \
                 / its reading on the null; that mesh is not converged either)",
                100.0 * BIAS_TOLERANCE,
                list(&|v| format!(
                    "{} {}",
                    v.name,
                    palpate_fem::numbers::quantity(v.refined_estimate, v.unit)
                ))
            )
        };
        Some(Self {
            round,
            refined_tets,
            parameters,
            converged,
            statement,
        })
    }
}

/// What the dataset mesh's own error leaves in the final model's residual: the final model
/// simulated on the mesh refined once and refitted on the dataset's mesh there, noise-free (its
/// null), leaves an RMS no parameter of the model can take away, and the verdict's floor is
/// widened by it in quadrature ([`crate::ResidualCheck::with_discretisation`]), as the static
/// diagnosis widens its floor by what its approximation-error correction leaves. Without it a
/// residual of the mesh's own making reads as an effect the library lacks.
///
/// It is the refined mesh's difference, not extrapolated to the material (Richardson's (4/3)
/// for an O(h²) error would): against a material the dataset mesh errs by more, so the floor is
/// widened by less than the mesh may leave and the verdict errs on the side of "not explained".
/// On data made on a mesh coarser than the refined one (the independent generator's truth) the
/// extrapolation overshoots: on its committed 312-tet cylinders the residual stood 3σ below a
/// floor widened by 4/3 of the null's RMS.
#[derive(Debug, Clone, Serialize)]
pub struct MeshFloor {
    /// Tetrahedra of the refined mesh that made the null.
    pub refined_tets: usize,
    /// RMS of the final model refitted on its null, fitted steps (m): the widening of the
    /// fitted check's floor.
    pub null_rms_fit: f64,
    /// The same on the held-out steps, the refit's parameters kept (m): the widening of the
    /// held-out check's floor.
    pub null_rms_held: f64,
    /// Simulations it took (none when the last round's null was made at the final model).
    pub evaluations: usize,
}

/// A round's null: the data the current model makes on the refined mesh, and the current model
/// refitted on them.
pub(super) struct NullRound {
    data: MotionDataset,
    base: FittedModel,
    refined_tets: usize,
    /// The scale of the moduli the refit started from ([`modulus_scale`]).
    scale: f64,
    /// Simulations of the null and of its refit not yet charged to a check.
    uncharged: usize,
}

/// The null data of `cur` on the refined model `fine`: its simulated marker places wherever
/// `ds` observed a marker, without noise (the simulation the mesh's note made when `cur` is the
/// simplest fit). The data's noise is not added: a candidate fitted to noise removes about σ²
/// per parameter by chance, on the data as on a noisy null, and the rule charges that once
/// already (k ln n); the null is to measure what the mesh's error alone lets a candidate remove.
/// With the data, the simulations it took (0 or 1).
fn null_data(
    ds: &MotionDataset,
    fine: &Refined,
    cur: &FittedModel,
) -> Result<(MotionDataset, usize), String> {
    let made;
    let (paths, simulations) = if cur.material == fine.material {
        (&fine.paths, 0)
    } else {
        made = marker_paths(&fine.model, &cur.material.refined()).map_err(|e| e.to_string())?;
        (&made, 1)
    };
    let mut null = ds.clone();
    for (row, sim) in null.obs.markers.iter_mut().zip(paths) {
        for (p, s) in row.iter_mut().zip(sim) {
            if let Some(p) = p {
                *p = *s;
            }
        }
    }
    for row in &mut null.obs.forces {
        row.iter_mut().for_each(|f| *f = None);
    }
    // The null's fits are held to the precision of the data's (a tenth of one residual's share
    // of the current fit's Φ = ½ w Δt χ²), not to their own Φ's, which is the mesh's error
    // alone and a small fraction of it: a candidate's gain on the null is set against the data's
    // χ², where a finer gain cannot move a verdict.
    let s = &cur.scores;
    let weight = ds.obs.marker_weight * ds.model.observation_interval();
    null.obs.phi_precision = precision(s.n_fit) * 0.5 * weight * s.chi2_fit;
    Ok((null, simulations))
}

/// The range [`modulus_scale`] searches.
const SCALE_BOUNDS: (f64, f64) = (0.05, 2.0);

/// The moduli that scale with the mesh's stiffness: λ, μ (a region's μ too) and the
/// stiffening c.
const SCALED: [ParamKind; 3] = [ParamKind::Lambda, ParamKind::Mu, ParamKind::Stiffening];

/// `m` with its [`SCALED`] moduli times `s`.
fn scaled(m: &Material, s: f64) -> Material {
    let mut m = m.clone();
    for k in SCALED {
        m.values[k as usize].iter_mut().for_each(|v| *v *= s);
    }
    m
}

/// The half-width in ln s of the bracket [`modulus_scale`] searches about an earlier null's
/// scale: the refined mesh's softness is the mesh's, and moves little with the model fitted on
/// it (by 0.6–1.7 % from one round's null to the next on draws 001, 002 and 007 of the motion
/// confusion plan, about × 0.8).
const PRIOR_BRACKET: f64 = 0.1;

/// Golden sections of the bracket about an earlier null's scale: its width 0.2 falls to
/// 0.2 · 0.618⁴ ≈ 0.03 in ln s, where [`SEARCHES`] leave the whole range's 3.7.
const PRIOR_SEARCHES: usize = 4;

/// Golden sections of the whole range [`SCALE_BOUNDS`].
const SEARCHES: usize = 10;

/// The scale of the current model's moduli at which the dataset mesh best fits the null, and
/// the simulations it took: a golden-section search in ln s on the fitted steps' χ², forward
/// simulations only, over a bracket about `prior` (an earlier round's null's scale) where
/// there is one and the search does not end at the bracket's edge, otherwise over
/// [`SCALE_BOUNDS`]. The refined mesh is softer than the dataset's, by as much as locking makes
/// it (× 0.81 and × 0.72 at the current fits of the independent generator's 1,267- and
/// 1,412-tet cylinders): the refit of the current model on the null starts there instead of
/// crawling from the dataset mesh's moduli. The markers' means stay in the χ² even where the
/// model frees their offsets (the null has none): the static sag is what pins the scale, and
/// with it removed the search ran to its bound of 1/20 on seven of the independent generator's
/// 24 cylinders with offsets adopted (a body too soft to swing leaves less than one swinging out
/// of phase).
fn modulus_scale(
    null: &MotionDataset,
    split: Split,
    cur: &FittedModel,
    prior: Option<f64>,
) -> (f64, usize) {
    let (model, obs) = fitted_part(null, split);
    let chi2 = |ln_s: f64| -> Result<f64, Infallible> {
        let Ok(t) = run_trajectory(&model, &scaled(&cur.material, ln_s.exp()), &obs) else {
            return Ok(f64::INFINITY);
        };
        Ok(t.res
            .iter()
            .flatten()
            .flatten()
            .map(|e| e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
            .sum())
    };
    let search = |a, b, n| {
        let Ok(s) = golden_section(&chi2, a, b, Stop::Sections(n));
        s
    };
    let (lo, hi) = (SCALE_BOUNDS.0.ln(), SCALE_BOUNDS.1.ln());
    let mut simulations = 0;
    if let Some(p) = prior.filter(|p| p.ln() - PRIOR_BRACKET > lo && p.ln() + PRIOR_BRACKET < hi) {
        let (a, b) = (p.ln() - PRIOR_BRACKET, p.ln() + PRIOR_BRACKET);
        let s = search(a, b, PRIOR_SEARCHES);
        simulations += s.evaluations;
        // Ended within its last section of an edge: the minimum may lie outside the bracket.
        let (ln_s, last) = (s.best(), s.b - s.a);
        if ln_s - a > last && b - ln_s > last {
            return (ln_s.exp(), simulations);
        }
    }
    let s = search(lo, hi, SEARCHES);
    (s.best().exp(), simulations + s.evaluations)
}

/// The null at the current model `cur` on the refined model `fine`, and the current model
/// refitted on it ([`NullRound`]); `Err` says why there is none. It reads only the data and the
/// current model, so a round can make it beside its candidates' fits
/// ([`MotionModel::wants_null`]).
pub(super) fn make_null(
    ds: &MotionDataset,
    split: Split,
    o: &MotionOptions,
    fine: &Refined,
    cur: &FittedModel,
    prior_scale: Option<f64>,
    warm: Option<(f64, &[f64])>,
) -> Result<NullRound, String> {
    let refined_tets = fine.model.tets.len();
    let (data, made) = null_data(ds, fine, cur)
        .map_err(|e| format!("the current model did not simulate on the refined mesh: {e}"))?;
    // On the null the markers are in step with the simulation and carry no offset: the
    // current model is refitted as it stands, its offsets (if adopted) free again, from its
    // moduli scaled to the softer refined object — or, `warm`, from values fitted on a null of
    // the same mesh already, at the scale that null's search found.
    let (scale, scans) = match warm {
        Some((scale, _)) => (scale, 0),
        None => modulus_scale(&data, split, cur, prior_scale),
    };
    log::debug!(
        "mesh null: the moduli × {scale:.4} ({scans} simulations; the last null's × {})",
        prior_scale.map_or("none".into(), |p| format!("{p:.4}"))
    );
    let material = scaled(&cur.material, scale);
    let start: Vec<f64> = match warm {
        Some((_, values)) => values.to_vec(),
        None => cur
            .values
            .iter()
            .enumerate()
            .map(|(i, &v)| match cur.kinds.get(i) {
                Some(k) if !SCALED.contains(k) => v,
                _ => v * scale,
            })
            .collect(),
    };
    let base = if cur.offsets.is_some() {
        fit_with_offsets(&data, split, &material, &cur.kinds, &start, o.max_iters)
    } else {
        fit_model(
            &data,
            split,
            &material,
            &cur.kinds,
            &[start],
            o.max_iters,
            o.screen_iters,
        )
    }
    .map_err(|e| format!("the current model did not refit on the null: {e}"))?;
    let uncharged = made + scans + base.evaluations;
    Ok(NullRound {
        data,
        base,
        refined_tets,
        scale,
        uncharged,
    })
}

impl MotionModel<'_> {
    /// Whether a round fitting `batch` is likely to check a candidate against the null, so
    /// that the null is worth making beside the fits: the check is on, the refined model was
    /// made, and the screen predicted a candidate of the batch that the mesh's error can mimic
    /// to pass. Elsewhere the null is made only when a candidate passes (on the independent
    /// 1,267-tetrahedron cylinder, made beside every round's fits it gained 11 s in the first
    /// round and lost 10 s in the two after, where nothing was checked).
    pub(super) fn wants_null(&self, round: usize, batch: &[Candidate]) -> bool {
        let (screened, promising) = &self.promising;
        self.o.mesh_error
            && self.o.mesh_null
            && self.fine.is_ok()
            && self.null.as_ref().is_none_or(|(r, _)| *r != round)
            && *screened == round
            && batch
                .iter()
                .any(|c| c.effect().mimics_mesh_error() && promising.contains(c))
    }

    /// The modulus scale of the last null made, where one was made: where the next null's
    /// search starts ([`modulus_scale`]).
    pub(super) fn null_scale(&self) -> Option<f64> {
        match &self.null {
            Some((_, Ok(n))) => Some(n.scale),
            _ => None,
        }
    }

    /// Keeps round `round`'s null (made at the current model `cur`) and, from the first one made,
    /// what it says of the fitted parameters ([`MeshBias`]).
    pub(super) fn keep_null(
        &mut self,
        round: usize,
        cur: &FittedModel,
        made: Result<NullRound, String>,
    ) {
        if let (None, Ok(n)) = (&self.mesh_bias, &made) {
            self.mesh_bias = MeshBias::of(round, n.refined_tets, cur, &n.base);
        }
        self.null = Some((round, made));
    }

    /// Makes the first round's null at the simplest fit `simplest` when no null was made and the
    /// refined model exists, for [`MeshBias`] alone (its reason logged when it cannot be made).
    pub(super) fn first_null_bias(&mut self, simplest: &FittedModel) {
        if self.mesh_bias.is_some() || self.fine.is_err() {
            return;
        }
        (self.log)("the parameters under one refinement: the first round's null, made for them");
        if let Err(why) = self.null_round(1, simplest, None) {
            (self.log)(&format!(
                "no null for the parameters under one refinement: {why}"
            ));
        }
    }

    /// The null of round `round` at the current model `cur`, made and refitted once per round
    /// (the refit from `warm` when given, [`make_null`]); `Err` says why there is none.
    fn null_round(
        &mut self,
        round: usize,
        cur: &FittedModel,
        warm: Option<(f64, &[f64])>,
    ) -> Result<&mut NullRound, String> {
        if self.null.as_ref().is_none_or(|(r, _)| *r != round) {
            let made = match &self.fine {
                Ok(fine) => make_null(
                    self.ds,
                    self.split,
                    self.o,
                    fine,
                    cur,
                    self.null_scale(),
                    warm,
                ),
                Err(why) => Err(format!("the mesh's error was not estimated: {why}")),
            };
            self.keep_null(round, cur, made);
        }
        match self.null.as_mut() {
            Some((_, Ok(n))) => Ok(n),
            Some((_, Err(why))) => Err(why.clone()),
            None => Err("no null".into()),
        }
    }

    /// [`MeshFloor`] of the final model `cur`, the current model of round `round` (its null made
    /// unless that round made it already); `None`, its reason logged, when there is no null.
    /// `last` is the last adoption, its round and candidate: where its check fitted it on that
    /// round's null, the final model's refit on its own null starts from those values, at that
    /// null's modulus scale — the same null and the same refit, from a start near its end,
    /// instead of the scale's search and a refit from the moduli scaled (on the independent
    /// generator's cylinders 11–113 simulations, a tenth to a third of a diagnosis).
    pub(super) fn mesh_floor(
        &mut self,
        round: usize,
        cur: &FittedModel,
        last: Option<(usize, Candidate)>,
    ) -> Option<MeshFloor> {
        let log = self.log;
        let made_here = matches!(&self.null, Some((r, _)) if *r == round);
        let warm = last.and_then(|(k, c)| {
            self.null_checks
                .iter()
                .find(|(r, d, _)| (*r, *d) == (k, c))
                .and_then(|(_, _, check)| {
                    let values = check.on_null_values.as_ref()?;
                    (values.len() == cur.values.len())
                        .then(|| (check.modulus_scale, values.clone()))
                })
        });
        if let (false, Some(_), Some((k, _))) = (made_here, &warm, last) {
            log(&format!(
                "the final model's null: its refit starts where the last adoption's check left \
                 it on round {k}'s null"
            ));
        }
        let warm = warm
            .as_ref()
            .map(|(scale, values)| (*scale, values.as_slice()));
        let measured = self.null_round(round, cur, warm).and_then(|n| {
            let (fit, held) = (n.base.scores.rms_fit, n.base.scores.rms_held);
            // A refit that ended on the scale search's bound found no softer object that fits,
            // and a noise-free null left with more than the data's own residual (which holds the
            // noise and the mesh's error and any effect) is a refit that failed: neither
            // measures the mesh's share, and the floor stays the noise's. (Ten golden sections
            // leave the search within e^0.03 of where it ends.)
            let (lo, hi) = SCALE_BOUNDS;
            if n.scale <= lo * 1.06 || n.scale >= hi / 1.06 {
                return Err(format!(
                    "the refit on the null started from the moduli × {:.3}, the scale search's \
                     bound",
                    n.scale
                ));
            }
            if fit > cur.scores.rms_fit {
                return Err(format!(
                    "the final model refitted on its null leaves {:.1} µm, more than the data's \
                     own {:.1} µm",
                    1e6 * fit,
                    1e6 * cur.scores.rms_fit
                ));
            }
            Ok(MeshFloor {
                refined_tets: n.refined_tets,
                null_rms_fit: fit,
                null_rms_held: held,
                evaluations: std::mem::take(&mut n.uncharged),
            })
        });
        measured
            .map_err(|why| {
                log(&format!(
                    "the final residual's floor is not widened by the mesh's own error: {why}"
                ))
            })
            .ok()
    }

    /// Checks candidate `c`, fitted on the data as `fitted` on top of `cur` with fitted ΔBIC
    /// `delta_bic`, against the mesh's own null ([`NullCheck`]); `None` when it is not checked
    /// (the reason logged when there is no null).
    pub(super) fn null_check(
        &mut self,
        round: usize,
        cur: &FittedModel,
        c: Candidate,
        fitted: &FittedModel,
        delta_bic: f64,
    ) -> Option<NullCheck> {
        if !self.o.mesh_error || !self.o.mesh_null || !c.effect().mimics_mesh_error() {
            return None;
        }
        let log = self.log;
        let (split, o) = (self.split, self.o);
        let noise_floor = super::noise_floor(self.ds);
        let null = match self.null_round(round, cur, None) {
            Ok(n) => n,
            Err(why) => {
                log(&format!(
                    "round {round}: {}: not checked against the mesh's own null: {why}",
                    c.name()
                ));
                return None;
            }
        };
        let quiet = |_: &str| {};
        let fitter = MotionModel::new(&null.data, split, o, &quiet);
        let outcome = c.effect().fit(&fitter, c, &null.base);
        let base = &null.base;
        let score = |m: &FittedModel| bic(m.scores.chi2_fit, m.scores.n_fit, m.parameter_count());
        // What the candidate removes of χ² on the null, fitted and held-out steps (none when
        // it could not be fitted there, or made the null worse).
        let (on_null, how) = match outcome {
            Ok(Outcome::Fitted(f)) => {
                let how = format!(
                    "the candidate takes it to {:.1} µm, held out {:.1} → {:.1} µm",
                    1e6 * f.scores.rms_fit,
                    1e6 * base.scores.rms_held,
                    1e6 * f.scores.rms_held
                );
                (Some(f), how)
            }
            Ok(Outcome::NotFitted(why)) => {
                (None, format!("the candidate is not fitted there: {why}"))
            }
            Ok(Outcome::Dropped) => (None, "the candidate is not fitted there".into()),
            Err(e) => (None, format!("the candidate's fit failed there: {e}")),
        };
        let on_null_values = on_null.as_ref().map(|f| f.values.clone());
        let (null_bic, null_gain, removed, removed_held, fitted_evals) = match &on_null {
            Some(f) => (
                score(f) - score(base),
                f.scores.rms_held / base.scores.rms_held - 1.0,
                (base.scores.chi2_fit - f.scores.chi2_fit).max(0.0),
                (base.scores.chi2_held - f.scores.chi2_held).max(0.0),
                f.evaluations,
            ),
            None => (0.0, 0.0, 0.0, 0.0, 0),
        };
        // The candidate's fit on the data with the null's removal handed back: the χ² it
        // lowers beyond what the mesh's own error lets it lower, charged the same parameters.
        let (s0, s1) = (&cur.scores, &fitted.scores);
        let n = s1.n_fit.max(1) as f64;
        let charge = delta_bic - n * (s1.chi2_fit / s0.chi2_fit).ln();
        let excess_bic = n * ((s1.chi2_fit + removed) / s0.chi2_fit).ln() + charge;
        let excess_gain = ((s1.chi2_held + removed_held) / s0.chi2_held).sqrt() - 1.0;
        let refused = !(excess_bic < -o.bic_threshold && excess_gain <= -o.min_holdout_gain);
        let verdict = if refused {
            format!(
                "refused: it explains no more than the mesh's own error (beyond the null ΔBIC \
                 {excess_bic:.1}, held-out RMS {:+.1} %; needs < −{} and ≤ −{:.0} %)",
                100.0 * excess_gain,
                o.bic_threshold,
                100.0 * o.min_holdout_gain
            )
        } else {
            format!(
                "beyond the null ΔBIC {excess_bic:.1}, held-out RMS {:+.1} %: more than the \
                 mesh's own error",
                100.0 * excess_gain
            )
        };
        let statement = format!(
            "on the mesh's own null (the current model on the mesh refined once, {} tets, \
             noise-free, refitted there from the moduli × {:.3} to {:.1} µm; {how}): {verdict}",
            null.refined_tets,
            null.scale,
            1e6 * base.scores.rms_fit,
        );
        log(&format!("round {round}: {}: {statement}", c.name()));
        Some(NullCheck {
            refined_tets: null.refined_tets,
            noise_floor,
            base_rms_fit: base.scores.rms_fit,
            modulus_scale: null.scale,
            delta_bic: null_bic,
            heldout_gain: null_gain,
            excess_delta_bic: excess_bic,
            excess_heldout_gain: excess_gain,
            refused,
            evaluations: std::mem::take(&mut null.uncharged) + fitted_evals,
            statement,
            on_null_values,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::MotionOptions;
    use super::*;
    use palpate_motion::dataset::{DatasetToml, Initial};
    use palpate_motion::scenario::{example_bar, record, EXAMPLE_DT};

    /// The parameters under one refinement: each value's reading on the null, the first-order
    /// estimate value² / reading, non-positive values left out, and "converged" only when every
    /// one stays within 5 %.
    #[test]
    fn the_bias_of_each_parameter_is_read_from_the_null() {
        let kinds = [ParamKind::Lambda, ParamKind::Mu, ParamKind::Stiffening];
        let (v, converged) = biased_values(&kinds, &[2.0e6, 1.0e6, 0.0], &[1.8e6, 0.8e6, 0.0]);
        assert!(!converged);
        assert_eq!(v.len(), 2, "{v:?}");
        assert_eq!((v[1].name.as_str(), v[1].unit), ("mu", "Pa"));
        assert!((v[1].refined_estimate - 1.25e6).abs() < 1e-6);
        assert!((v[0].refined_estimate - 2.0e6 * 2.0e6 / 1.8e6).abs() < 1e-6);
        let (_, converged) = biased_values(&kinds[..2], &[2.0e6, 1.0e6], &[1.95e6, 1.04e6]);
        assert!(converged);
        let (_, converged) = biased_values(&kinds[..2], &[2.0e6, 1.0e6], &[1.95e6, 1.06e6]);
        assert!(!converged);
    }

    /// The bar of [`the_modulus_scale_is_found_where_the_data_were_made`] with `steps` steps,
    /// its data made at `data` times the current moduli, and the current model.
    fn bar(steps: usize, data: f64) -> (MotionDataset, FittedModel) {
        let (mesh, model) = example_bar([1, 4, 1], steps).unwrap();
        let ne = model.tets.len();
        let current = Material::uniform(ne, 4.0e4, 2.0e4, 0.0, 1.0, 47.0);
        let obs = record(&model, &scaled(&current, data), 0.0, 1).unwrap();
        let ds = MotionDataset {
            config: DatasetToml {
                steps: Some(steps),
                substeps: Some(1),
                density: Some(47.0),
                gravity: Some(model.gravity),
                initial: Initial {
                    lambda: 4.0e4,
                    mu: 2.0e4,
                    nu: 0.0,
                    h: 1.0,
                },
                initial_declared: true,
                ..DatasetToml::new(EXAMPLE_DT, vec!["front".into()])
            },
            mesh,
            model,
            obs,
            timestep: palpate_motion::timestep::TimeStep::capture_rate(EXAMPLE_DT),
        };
        (ds, FittedModel::elastic(current, [4.0e4, 2.0e4]))
    }

    /// The final model's null refitted from values a null of the same mesh was fitted to
    /// already (the last adoption's check) ends where the refit from the scale's search does,
    /// without the search and in fewer simulations: the same null, a nearer start.
    #[test]
    fn a_null_refit_started_warm_ends_where_the_searched_one_does() {
        let (ds, cur) = bar(30, 1.0);
        let split = Split {
            fit_steps: 20,
            steps: 30,
        };
        let model = ds.model.refined().unwrap();
        let paths = marker_paths(&model, &cur.material.refined()).unwrap();
        let fine = Refined {
            model,
            material: cur.material.clone(),
            paths,
        };
        let o = MotionOptions::default();
        let cold = make_null(&ds, split, &o, &fine, &cur, None, None).unwrap();
        // A start near the cold refit's end, as a check's refit on the last round's null is.
        let near: Vec<f64> = cold.base.values.iter().map(|v| 1.02 * v).collect();
        let warm = make_null(&ds, split, &o, &fine, &cur, None, Some((cold.scale, &near))).unwrap();
        assert_eq!(warm.scale, cold.scale);
        let (c, w) = (cold.base.scores.rms_fit, warm.base.scores.rms_fit);
        assert!((w / c - 1.0).abs() < 0.01, "warm {w:e}, cold {c:e}");
        assert!(
            warm.uncharged < cold.uncharged,
            "warm {} simulations, cold {}",
            warm.uncharged,
            cold.uncharged
        );
    }

    /// Data made by the bar at half the current moduli: the search finds the half.
    #[test]
    fn the_modulus_scale_is_found_where_the_data_were_made() {
        let (ds, cur) = bar(30, 0.5);
        let split = Split {
            fit_steps: 20,
            steps: 30,
        };
        let (s, simulations) = modulus_scale(&ds, split, &cur, None);
        assert!((s / 0.5 - 1.0).abs() < 0.03, "scale {s}");
        assert_eq!(simulations, 12);
        // About an earlier null's scale near the half: the half again, in half the simulations.
        let (near, simulations) = modulus_scale(&ds, split, &cur, Some(0.53));
        assert!((near / 0.5 - 1.0).abs() < 0.03, "scale {near} from 0.53");
        assert_eq!(simulations, 6);
        // About a scale whose bracket misses the half: the search ends at its edge and the whole
        // range is searched after it.
        let (far, simulations) = modulus_scale(&ds, split, &cur, Some(0.8));
        assert!((far / 0.5 - 1.0).abs() < 0.03, "scale {far} from 0.8");
        assert_eq!(simulations, 18);
    }
}
