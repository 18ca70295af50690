//! The static diagnosis loop ([`run_diagnosis`]): the data gate, the simplest fit, the mesh it is
//! solved on, where the inclusion and layer candidates start, the selection rounds, the noise
//! tests, the verdict and the power statement.

use std::time::Instant;

use palpate_fem::dataset::StaticDataset;

use super::approx_error::{self, refresh, Correction};
use super::fit::Fitted;
use super::fit::{fit, initial_theta};
use super::holdout::{errors, holdout, marker_norms, stats, Held};
use super::model::{self, poisson_of, Candidate, Context, Model};
use super::noise::{self, estimate_noise, NoiseFinding};
use super::params::{base_params, effect_params, identifiability};
use super::rest_noise::{estimate_rest_noise, RestNoiseFinding};
use super::select::{static_steps, StaticModel};
use super::{power, power_check, sensitivity, signature};
use super::{
    DiagnoseError, DiagnoseOptions, Diagnosed, DiagnosisReport, Errors, Kept, MeshChoice,
    MeshErrorSummary, ResidualCheck, SolvedOn, Step, MESH_ERROR_MAX_TETS,
};
use crate::select::{self, Policy, Rank, Screen};

/// Which mesh to solve on ([`MeshChoice::Auto`] resolved), and why (in words for the report).
pub(super) fn mesh_decision(
    o: &DiagnoseOptions,
    tets: usize,
    mesh_error: Option<&MeshErrorSummary>,
    floor: f64,
) -> Result<(MeshChoice, String), DiagnoseError> {
    match (o.mesh, mesh_error) {
        (MeshChoice::Dataset, _) => Ok((MeshChoice::Dataset, "the dataset mesh (as asked)".into())),
        (c @ (MeshChoice::Refined | MeshChoice::Corrected), Some(e)) => Ok((
            c,
            format!(
                "the dataset mesh {} the mesh refined once, {} tetrahedra (as asked)",
                if c == MeshChoice::Refined { "replaced by" } else { "corrected by" },
                e.refined_tets
            ),
        )),
        (MeshChoice::Refined | MeshChoice::Corrected, None) => Err(DiagnoseError::Input(format!(
            "the refined mesh was asked for but could not be built or solved ({} tetrahedra → {}; limit {MESH_ERROR_MAX_TETS})",
            tets,
            8 * tets
        ))),
        (MeshChoice::Auto, None) => Ok((
            MeshChoice::Dataset,
            "the dataset mesh (its discretisation error could not be estimated)".into(),
        )),
        (MeshChoice::Auto, Some(e)) => {
            let big = e.rms > o.refine_above * floor;
            let fits = e.refined_tets <= o.refine_max_tets;
            let why = format!(
                "the dataset mesh's discretisation error at the markers is {:.1} µm RMS, {:.0}% of the noise floor {:.1} µm (correct above {:.0}%, up to {} tetrahedra)",
                1e6 * e.rms,
                100.0 * e.rms / floor,
                1e6 * floor,
                100.0 * o.refine_above,
                o.refine_max_tets
            );
            Ok(match (big, fits) {
                (true, true) => (
                    MeshChoice::Corrected,
                    format!("the dataset mesh with the approximation-error correction from the mesh refined once ({} tetrahedra): {why}", e.refined_tets),
                ),
                (true, false) => (
                    MeshChoice::Dataset,
                    format!("the dataset mesh, although {why}: the refined mesh ({} tetrahedra) is over the limit", e.refined_tets),
                ),
                _ => (MeshChoice::Dataset, format!("the dataset mesh: {why}")),
            })
        }
    }
}

/// Runs the diagnosis loop on a dataset.
pub fn run_diagnosis(
    ds: &StaticDataset,
    o: &DiagnoseOptions,
) -> Result<DiagnosisReport, DiagnoseError> {
    run_diagnosis_with(ds, o, |_| {})
}

/// [`run_diagnosis`] with a progress callback (one line per stage).
pub fn run_diagnosis_with(
    ds: &StaticDataset,
    o: &DiagnoseOptions,
    mut progress: impl FnMut(&str),
) -> Result<DiagnosisReport, DiagnoseError> {
    let started = Instant::now();
    let (coarse, coarse_fit) = fit_simplest(ds, o, &mut progress)?;
    let refined = if 8 * ds.mesh.tets.len() <= MESH_ERROR_MAX_TETS {
        palpate_fem::dataset::refine::refine_dataset(ds).ok()
    } else {
        None
    };
    let (mesh_error, first_delta) =
        estimate_mesh_error(refined.as_ref(), &coarse, &coarse_fit, o, &mut progress);
    let floor = coarse.sigma * 3f64.sqrt();
    let (choice, reason) = mesh_decision(o, ds.mesh.tets.len(), mesh_error.as_ref(), floor)?;
    let dataset_mesh_rms = stats(&marker_norms(&coarse, &coarse_fit)).0;
    let (mut ctx, current, mut correction) = solve_on_chosen_mesh(
        choice,
        refined,
        first_delta,
        coarse,
        coarse_fit,
        o,
        &mut progress,
    )?;
    locate_candidates(&mut ctx, correction.as_mut(), &current, o, &mut progress);
    let mut solved_on = SolvedOn {
        tets: ctx.problem.element_count(),
        choice,
        correction_rms: None,
        dataset_mesh_rms,
        reason,
    };
    let current_held = holdout(&ctx, &current, o.holdout_iterations)?;
    let first = errors(&ctx, &current, &current_held);
    let (ctx, current, current_held, steps) =
        select_effects(ctx, correction, current, current_held, o, &mut progress)?;
    let after = errors(&ctx, &current, &current_held);
    solved_on.correction_rms = ctx.correction.as_deref().map(approx_error::delta_rms);
    let noise = test_noise(&ctx, &current, o, &mut progress);
    let (adopted, residual_check) = judge_residual(&ctx, &current, &noise, &after);
    let detectable = power_statement(&ctx, &current, &residual_check, o, &mut progress)?;
    let mut final_params = base_params(&current);
    for &c in &current.model.effects {
        final_params.extend(effect_params(&ctx, &current, c));
    }
    let identifiability = identifiability(&ctx, &current);
    Ok(DiagnosisReport {
        input: Diagnosed {
            dataset: ds.name.clone(),
            criterion: criterion(o),
            sigma: ctx.sigma,
            sigma_declared: ctx.sigma_declared,
        },
        noise_floor: ctx.sigma * 3f64.sqrt(),
        options: o.clone(),
        adopted,
        noise: noise.noise,
        rest_noise: noise.rest_noise,
        noise_evidence: noise.evidence,
        steps,
        before: first,
        mesh_error,
        solved_on,
        after,
        residual_check,
        detectable,
        young_poisson: (current.theta[0].exp(), poisson_of(current.theta[1])),
        final_params,
        identifiability,
        seconds: started.elapsed().as_secs_f64(),
        kept: Kept {
            final_fit: Some(current),
            context: Some(ctx),
        },
    })
}

/// The approximation-error correction and the δ it computed at the simplest fit, kept for the
/// correction's first refresh.
type FirstDelta = (Correction, Vec<Vec<[f64; 3]>>);

/// The data gate, then the simplest model (linear homogeneous) fitted on the dataset's own mesh.
fn fit_simplest(
    ds: &StaticDataset,
    o: &DiagnoseOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<(Context, Fitted), DiagnoseError> {
    // The same data gate as `palpate fit` (palpate_fem::sanity): data that cannot determine a
    // stiffness are refused before any model is fitted to them.
    let findings = palpate_fem::sanity::check_static_data(ds, 2)
        .into_result()
        .map_err(|r| DiagnoseError::Input(r.to_string()))?;
    for w in findings.warnings() {
        log::warn!("[{}] {}", w.code, w.message);
    }
    let coarse = Context::new(ds, o.grid)?;
    let all: Vec<usize> = (0..coarse.meas.len()).collect();
    let (theta0, sim0) = initial_theta(&coarse, &all)?;
    progress("fitting the simplest model (linear homogeneous, displacement-based)");
    let coarse_fit = fit(
        &coarse,
        &Model::base(),
        theta0,
        &all,
        Some(&sim0.x),
        o.max_iterations,
    )?;
    Ok((coarse, coarse_fit))
}

/// The dataset mesh's own discretisation error: the approximation-error correction at the
/// simplest fit, δ = x_{h/2}(θ*) − x_h(θ*) at the markers (`None` without a refined mesh, or
/// when a refined solve fails). One set of refined solves serves both the estimate and, when the
/// correction is chosen, its first refresh.
fn estimate_mesh_error(
    refined: Option<&StaticDataset>,
    coarse: &Context,
    coarse_fit: &Fitted,
    o: &DiagnoseOptions,
    progress: &mut dyn FnMut(&str),
) -> (Option<MeshErrorSummary>, Option<FirstDelta>) {
    let mut first_delta = None;
    let mesh_error = match refined {
        Some(fine) => {
            progress(
                "estimating the mesh's discretisation error (simplest model on the mesh refined once)",
            );
            Correction::new(fine, o.grid)
                .and_then(|mut corr| {
                    let delta =
                        corr.delta(coarse, &Model::base(), &coarse_fit.theta, &coarse_fit.sim.x)?;
                    Ok((corr, delta))
                })
                .ok()
                .map(|(corr, delta)| {
                    let summary = MeshErrorSummary {
                        rms: approx_error::delta_rms(&delta),
                        max: approx_error::delta_max(&delta),
                        refined_tets: fine.mesh.tets.len(),
                    };
                    first_delta = Some((corr, delta));
                    summary
                })
        }
        None => None,
    };
    (mesh_error, first_delta)
}

/// The simplest model on the mesh chosen ([`mesh_decision`]): refitted on the refined mesh, or
/// with the approximation-error correction (returned, to be refreshed after each adoption), or
/// the dataset mesh's fit as it is.
fn solve_on_chosen_mesh(
    choice: MeshChoice,
    refined: Option<StaticDataset>,
    mut first_delta: Option<FirstDelta>,
    coarse: Context,
    coarse_fit: Fitted,
    o: &DiagnoseOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<(Context, Fitted, Option<Correction>), DiagnoseError> {
    let all: Vec<usize> = (0..coarse.meas.len()).collect();
    let mut correction = None;
    let (ctx, current) = match (choice, refined) {
        (MeshChoice::Refined, Some(fine)) => {
            progress(&format!(
                "refitting the simplest model on the refined mesh ({} tetrahedra)",
                fine.mesh.tets.len()
            ));
            let ctx = Context::new(&fine, o.grid)?;
            let sim = Model::base().simulate(&ctx, &coarse_fit.theta, &all, None)?;
            let f = fit(
                &ctx,
                &Model::base(),
                coarse_fit.theta.clone(),
                &all,
                Some(&sim.x),
                o.max_iterations,
            )?;
            (ctx, f)
        }
        (MeshChoice::Corrected, Some(fine)) => {
            progress(&format!(
                "refitting the simplest model with the approximation-error correction ({} tetrahedra)",
                fine.mesh.tets.len()
            ));
            let (mut corr, delta) = match first_delta.take() {
                Some(d) => d,
                None => {
                    let mut corr = Correction::new(&fine, o.grid)?;
                    let d = corr.delta(
                        &coarse,
                        &Model::base(),
                        &coarse_fit.theta,
                        &coarse_fit.sim.x,
                    )?;
                    (corr, d)
                }
            };
            let mut ctx = coarse;
            // Two refreshes: δ at the dataset-mesh fit (the mesh-error estimate's), then at the
            // corrected fit (E moves by the mesh's stiffness error, a few per cent, and δ with it).
            ctx.correction = Some(delta);
            let mut f = fit(
                &ctx,
                &coarse_fit.model,
                coarse_fit.theta.clone(),
                &coarse_fit.subset,
                Some(&coarse_fit.sim.x),
                o.max_iterations,
            )?;
            f = refresh(&mut ctx, &mut corr, &f, o.max_iterations)?;
            correction = Some(corr);
            (ctx, f)
        }
        _ => (coarse, coarse_fit),
    };
    Ok((ctx, current, correction))
}

/// Find where before what: the sensitivity scan of the simplest fit places the inclusion
/// candidate where the residual asks for a stiffer or softer blob (its default start, under the
/// mean contact point, sees nothing of an inclusion elsewhere), and chooses the surface the layer
/// candidate's depth is measured from.
pub(in crate::statics) fn locate_candidates(
    ctx: &mut Context,
    mut correction: Option<&mut Correction>,
    current: &Fitted,
    o: &DiagnoseOptions,
    progress: &mut dyn FnMut(&str),
) {
    let blob = o.locate_inclusion && o.candidates.contains(&Candidate::Inclusion);
    let layer = o.locate_layer && o.candidates.contains(&Candidate::Layer);
    let gradient = if blob || layer {
        progress(
            "locating where the residual asks for another stiffness (adjoint sensitivity scan)",
        );
        sensitivity::log_modulus_gradient(ctx, current).ok()
    } else {
        None
    };
    if let Some(scan) = gradient
        .as_ref()
        .filter(|_| blob)
        .and_then(|s| sensitivity::scan_blobs(ctx, s, &[0.3, 0.6]))
    {
        progress(&format!(
            "sensitivity scan: a {} blob of radius {:.1} mm at ({:.1}, {:.1}, {:.1}) mm would lower χ² by {:.0}",
            if scan.contrast > 0.0 { "stiffer" } else { "softer" },
            1e3 * scan.radius,
            1e3 * scan.centre[0],
            1e3 * scan.centre[1],
            1e3 * scan.centre[2],
            scan.reduction
        ));
        ctx.inclusion.centre = scan.centre;
        if let Some(c) = correction.as_mut() {
            c.set_inclusion_start(scan.centre);
        }
        // log contrast at least 0.3 in size (the position is invisible at zero contrast),
        // at most ln 10; radius r = ½ h e^θ_r.
        let a = scan.contrast.signum() * scan.contrast.abs().clamp(0.3, 10f64.ln());
        let theta_r = (2.0 * scan.radius / ctx.frame.half).ln();
        ctx.inclusion.seed = Some([a, 0.0, 0.0, 0.0, theta_r]);
        ctx.inclusion.scan = Some(scan);
    }
    if let Some(s) = gradient.as_ref().filter(|_| layer) {
        // Per axis, the best step in log E over thicknesses of 5–70 % of its depth range (the
        // logistic width a quarter of an element: 10–90 % over about one); the layer
        // candidate's depth is the winning axis's.
        let t: Vec<f64> = (0..14).map(|k| 0.05 + 0.05 * k as f64).collect();
        let best = ctx
            .layer.maps
            .iter()
            .filter_map(|(axis, depth, range)| {
                let width = 0.25 * ctx.layer.element_size / range;
                sensitivity::scan_layers(ctx, s, depth, &t, width).map(|l| (*axis, l))
            })
            .inspect(|(axis, l)| {
                progress(&format!(
                    "sensitivity scan: a {} layer {} {:.0} % of the depth thick would lower χ² by {:.0}",
                    if l.contrast > 0.0 { "stiffer" } else { "softer" },
                    axis.name(),
                    100.0 * l.thickness,
                    l.reduction
                ))
            })
            .fold(None, |best: Option<(model::LayerAxis, sensitivity::LayerScan)>, next| {
                // Ties keep the earlier axis (the pushing direction first: a block pushed from
                // above has the same vertical map).
                match best {
                    Some(b) if b.1.reduction >= next.1.reduction => Some(b),
                    _ => Some(next),
                }
            });
        if let Some((axis, scan)) = best {
            ctx.set_layer_axis(axis);
            ctx.layer.seed = Some([scan.contrast, scan.thickness]);
            if let Some(c) = correction.as_mut() {
                c.set_layer_axis(axis);
            }
        }
    }
}

/// The selection rounds ([`crate::select::select`] driven by [`StaticModel`]) from the simplest
/// model: the context (with its last correction), the final fit and its held-out errors, and the
/// report's rounds.
fn select_effects(
    ctx: Context,
    correction: Option<Correction>,
    current: Fitted,
    current_held: Held,
    o: &DiagnoseOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<(Context, Fitted, Held, Vec<Step>), DiagnoseError> {
    let all: Vec<usize> = (0..ctx.meas.len()).collect();
    let policy = Policy {
        // One round more than effects: the last one states that the maximum is reached.
        rounds: o.max_effects + 1,
        max_adopted: o.max_effects,
        rank: Rank::FittedBic,
        // Leave-one-measurement-out costs a refit per measurement: only the BIC shortlist pays it.
        screen: Screen::Shortlist {
            bic_threshold: o.bic_threshold,
            size: o.cv_candidates,
        },
    };
    let mut engine = StaticModel {
        ctx,
        correction,
        all,
        o,
        progress,
        refreshed: None,
    };
    let verdict = select::select(&mut engine, &policy, current, current_held)?;
    let steps = static_steps(&verdict, o, engine.ctx.meas.len());
    let StaticModel { ctx, .. } = engine;
    let (current, current_held) = verdict
        .path
        .into_iter()
        .last()
        .expect("the start is on the path");
    Ok((ctx, current, current_held, steps))
}

/// The noise tests' findings on the final residual.
struct NoiseTests {
    /// The marker-noise finding.
    noise: Option<NoiseFinding>,
    /// The rest-scan finding.
    rest_noise: Option<RestNoiseFinding>,
    /// The noise finding's evidence plot.
    evidence: Vec<(f64, f64)>,
    /// The final residual per measurement: (marker, residual vector m).
    residuals: Vec<Vec<(usize, [f64; 3])>>,
}

/// The white-noise level of the final residual (marker noise, then the rest scan's own noise),
/// each finding's statement saying which of the two the excess is.
fn test_noise(
    ctx: &Context,
    current: &Fitted,
    o: &DiagnoseOptions,
    progress: &mut dyn FnMut(&str),
) -> NoiseTests {
    progress("estimating the marker noise level (local nugget)");
    let residuals = signature::residual_vectors(ctx, current);
    let fields: Vec<noise::Field> = residuals
        .iter()
        .map(|r| r.iter().map(|&(k, e)| (ctx.marker_rest[k], e)).collect())
        .collect();
    let noise = estimate_noise(&fields, ctx.sigma_declared.then_some(ctx.sigma), &o.noise);
    let noise_evidence = noise
        .as_ref()
        .map(|n| {
            n.points
                .iter()
                .map(|&(i, p, e)| {
                    let c = ctx.meas[current.subset[i]].point;
                    let d = (0..3).map(|a| (p[a] - c[a]).powi(2)).sum::<f64>().sqrt();
                    (d, e)
                })
                .collect()
        })
        .unwrap_or_default();
    // The rest scan is a measurement too: tested on the final residual whenever the
    // measurements' noise is declared.
    let rest_noise = if ctx.sigma_declared {
        progress("testing the rest scan for noise of its own (persistent per-marker nugget)");
        estimate_rest_noise(
            &ctx.marker_rest,
            &residuals,
            ctx.sigma,
            &o.noise,
            &o.rest_noise,
        )
    } else {
        None
    };
    // A noisy rest scan is white in every measurement too, so the noise test fires on it (a
    // one-frame rest scan with the measurements' σ gives σ̂ = √2 σ). When the measurements' own
    // noise, the within-marker estimate from which the rest error cancels, is within the noise
    // test's margin of the declared σ and the rest test fires, the excess is the rest scan's.
    let mut noise = noise;
    if let (Some(n), Some(r)) = (noise.as_mut(), rest_noise.as_ref()) {
        let own = r.sigma_within;
        if n.fired && r.fired && own.is_some_and(|w| w <= (1.0 + o.noise.margin) * ctx.sigma) {
            n.fired = false;
            n.statement = format!(
                "{}; but the measurements' own noise, estimated from each marker's deviations from its mean (where a rest-scan error cancels), is {:.1} µm, within {:.2} × the declared σ: the excess white noise is the rest scan's (below), not the measurements'",
                n.statement,
                1e6 * own.unwrap_or(f64::NAN),
                1.0 + o.noise.margin
            );
        }
    }
    // Both can be true at once: measurements noisier than declared *and* a noisy rest scan. The
    // rest test's null is then the measurements' own noise σ̂_w (the within-marker estimate, from
    // which a rest error cancels), so when it fires beside `noise` both are adopted and the
    // residual is judged under σ̂_w² I + τ̂² 11ᵀ per marker; the pooled σ̂ of the noise test holds
    // both noises and would count the rest scan's twice.
    if let (Some(n), Some(r)) = (noise.as_mut(), rest_noise.as_ref()) {
        if let (true, true, Some(own)) = (n.fired, r.fired, r.sigma_within) {
            n.statement = format!(
                "{}; the measurements' own noise, estimated from each marker's deviations from its mean (where a rest-scan error cancels), is {:.1} µm and the rest scan's is stated below: both are adopted",
                n.statement,
                1e6 * own
            );
        }
    }
    NoiseTests {
        noise,
        rest_noise,
        evidence: noise_evidence,
        residuals,
    }
}

/// The effects adopted (the final model's, then `noise` and `rest-noise` as the tests found) and
/// whether the final residual is what the noise leaves ([`ResidualCheck`]).
fn judge_residual(
    ctx: &Context,
    current: &Fitted,
    tests: &NoiseTests,
    after: &Errors,
) -> (Vec<Candidate>, ResidualCheck) {
    let (noise, rest_noise, residuals) = (&tests.noise, &tests.rest_noise, &tests.residuals);
    let noise_adopted = noise.as_ref().filter(|n| n.fired);
    let rest_adopted = rest_noise
        .as_ref()
        .filter(|r| r.fired && (noise_adopted.is_none() || r.sigma_within.is_some()));
    let mut adopted = current.model.effects.clone();
    if noise_adopted.is_some() {
        adopted.push(Candidate::Noise);
    }
    // With `noise` adopted the floor is the re-estimated σ̂√3 (σ̂_w with the rest scan's noise
    // beside it): the final residual is judged against it — a residual whose smooth part the
    // nugget estimate leaves out stays visible.
    let (check_sigma, judged) = match (noise_adopted, rest_adopted) {
        (Some(_), Some(r)) => (r.sigma_within.unwrap_or(ctx.sigma), true),
        (Some(n), None) => (n.estimate, true),
        (None, _) => (ctx.sigma, ctx.sigma_declared),
    };
    let remaining = ctx
        .correction
        .as_deref()
        .map_or(0.0, approx_error::delta_rms)
        / 3.0;
    let residual_check = match rest_adopted {
        Some(r) => {
            adopted.push(Candidate::RestNoise);
            ResidualCheck::with_rest_noise(
                residuals,
                check_sigma,
                remaining,
                r.estimate,
                current.theta.len(),
                judged,
            )
        }
        None => ResidualCheck::with_discretisation(
            after.fitted_rms,
            check_sigma * 3f64.sqrt(),
            remaining,
            ctx.residual_len(&current.subset),
            current.theta.len(),
            judged,
        ),
    };
    (adopted, residual_check)
}

/// "Clean" says little without what the data could have seen: for a residual the noise explains,
/// the smallest magnitude of every candidate the final model does not hold that the dataset would
/// have detected ([`power::detectable`]).
fn power_statement(
    ctx: &Context,
    current: &Fitted,
    residual_check: &ResidualCheck,
    o: &DiagnoseOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<power::Detectable>, DiagnoseError> {
    let detectable = if residual_check.judged && residual_check.explained {
        progress("stating the smallest effects this dataset could have detected");
        match power::detectable(ctx, current, o.bic_threshold) {
            Ok(mut d) => {
                power_check::check_statements(ctx, current, &mut d, o, progress)?;
                d
            }
            // A secant step that leaves the physical range (a stiffening final model) leaves
            // the statement out; the verdict stands without it.
            Err(DiagnoseError::Diverged(why)) => {
                progress(&format!("no power statement: {why}"));
                Vec::new()
            }
            Err(e) => return Err(e),
        }
    } else {
        Vec::new()
    };
    Ok(detectable)
}

/// The selection rule in words, with the options' numbers (stated in every report).
fn criterion(o: &DiagnoseOptions) -> String {
    format!(
        "rank by BIC = n ln(χ²/n) + k ln n; shortlist the best {} with ΔBIC < −{}; a shortlisted candidate passes if on leave-one-measurement-out predictions n ln(χ²_new/χ²_old) + k ln n < 0 AND the held-out error in excess of the noise floor drops by ≥ {:.0} % (when nothing is above the floor before: held-out ΔBIC < −{} instead); adopt the first that passes (fitted-BIC order) and report any later one that also passes with a lower held-out ΔBIC as ambiguous; repeat; then `noise` if the one-sided 95 % lower bound of the nugget estimate σ̂ of the final residual exceeds {:.2} × the declared σ; `rest-noise` if the per-marker persistent residual's nugget sits ≥ {:.1} null standard deviations above what the measurements' noise leaves and τ̂ ≥ {:.2} σ — in place of `noise` when the within-marker estimate of the measurements' own noise is within that margin of the declared σ",
        o.cv_candidates,
        o.bic_threshold,
        100.0 * o.min_holdout_gain,
        o.bic_threshold,
        1.0 + o.noise.margin,
        o.rest_noise.z_limit,
        o.rest_noise.margin
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn estimate(rms: f64, refined_tets: usize) -> MeshErrorSummary {
        MeshErrorSummary {
            rms,
            max: 2.0 * rms,
            refined_tets,
        }
    }

    /// The auto rule corrects exactly when the mesh error is over the threshold fraction of the
    /// floor and the refined mesh is within the limit; a forced choice is obeyed, and a forced
    /// refinement that cannot be made is an error naming the sizes.
    #[test]
    fn mesh_decision_follows_the_rule() {
        let o = DiagnoseOptions {
            refine_above: 0.5,
            ..DiagnoseOptions::default()
        };
        let floor = 173.2e-6;
        let limit = o.refine_max_tets;
        let decide = |e: Option<MeshErrorSummary>| mesh_decision(&o, 648, e.as_ref(), floor);
        let corrected = |e| decide(Some(e)).unwrap().0 == MeshChoice::Corrected;
        assert!(corrected(estimate(0.51 * floor, 5184)));
        assert!(!corrected(estimate(0.49 * floor, 5184)));
        let (c, why) = decide(Some(estimate(0.9 * floor, limit + 1))).unwrap();
        assert!(
            c == MeshChoice::Dataset && why.contains("over the limit"),
            "{why}"
        );
        assert_eq!(decide(None).unwrap().0, MeshChoice::Dataset);
        let always = DiagnoseOptions::default();
        let got = mesh_decision(&always, 648, Some(&estimate(1e-9, 5184)), floor);
        assert_eq!(got.unwrap().0, MeshChoice::Corrected);
        for asked in [MeshChoice::Refined, MeshChoice::Corrected] {
            let forced = DiagnoseOptions {
                mesh: asked,
                ..DiagnoseOptions::default()
            };
            let got = mesh_decision(&forced, 648, Some(&estimate(0.0, 5184)), floor);
            assert_eq!(got.unwrap().0, asked);
            let e = mesh_decision(&forced, 648, None, floor)
                .unwrap_err()
                .to_string();
            assert!(e.contains("648") && e.contains("5184"), "{e}");
        }
        let never = DiagnoseOptions {
            mesh: MeshChoice::Dataset,
            ..DiagnoseOptions::default()
        };
        let got = mesh_decision(&never, 648, Some(&estimate(floor, 5184)), floor);
        assert_eq!(got.unwrap().0, MeshChoice::Dataset);
    }
}
