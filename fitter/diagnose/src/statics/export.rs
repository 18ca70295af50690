//! The diagnosed model for the runtime: the final model exported.
//!
//! What of the final model the runtime can play back, and how:
//! - the base material (E, ν) → one global (λ, α) set (seed 000 eqs. 3.36–3.38);
//! - inhomogeneity (trilinear log-E field), layer, inclusion → per-element (λ_e, α_e);
//! - strain stiffening (secant E_e = E (1 + β (‖ε_e‖/0.1)²)) → the thesis' non-linear
//!   inhomogeneous material: one per-element set per measurement, at that measurement's fitted
//!   state, blended in strain space (eqs. 6.7–6.11) with the measurement strains as centres.
//!
//! The other effects describe the measurement, not the object — calibration (belongs to the probe's
//! force calibration), tilt (the probe's direction), registration (the tracker), compliant boundary
//! (the rig), gravity preload (the rest scan) — so they are not in the runtime model; the provenance
//! notes list them with their fitted values so the user knows what the rig needs.

use palpate_fem::export::{ModelBuffers, ProvenanceInfo};
use palpate_fem::forward::Material;
use palpate_static_fit::blend::{strain_blend, BlendData};

use super::fit::{fit, Fitted};
use super::model::{Candidate, Context, Model};
use super::{effect_params, DiagnoseError, DiagnosisReport};

/// Neighbours of the strain-space blend (as the static fitter's export).
const BLEND_NEIGHBOURS: usize = 8;

/// The runtime's parameter sets and blend for `model` at `theta`, given its solved states `xs`
/// (one per measurement): one set without stiffening; with it, one per-element set per state,
/// blended in strain space.
pub fn runtime_material(
    ctx: &Context,
    model: &Model,
    theta: &[f64],
    xs: &[Vec<[f64; 3]>],
) -> Result<(Vec<Material>, BlendData), DiagnoseError> {
    if !model.state_dependent() {
        return Ok((
            vec![model.material_at(ctx, theta, &ctx.problem.x0)?],
            BlendData::None,
        ));
    }
    let sets: Vec<Material> = xs
        .iter()
        .map(|x| model.material_at(ctx, theta, x))
        .collect::<Result<_, _>>()?;
    let blend = strain_blend(&ctx.problem, &sets, xs, BLEND_NEIGHBOURS)
        .map_err(|e| DiagnoseError::Input(format!("strain blend of the export: {e}")))?;
    Ok((sets, blend))
}

/// The fit the runtime model is built from, with its context. Without the approximation-error
/// correction that is the final fit. With it, the final fit's parameters describe the object as
/// the refined mesh solves it, but the runtime runs the dataset mesh, which solves the same
/// parameters differently (by δ at the markers). So the final model is refitted without the
/// correction, from the final θ: the parameters that reproduce the measurements best *on the
/// runtime's own mesh* (the report keeps the physical ones). On the clean specimen the two E
/// agree within 0.1 % (the mesh error there is a local shape error under the probe, which no
/// parameter of the coarse model can remove); a mesh error that acts as a stiffness bias would
/// show up as a difference here.
pub fn runtime_fit(r: &DiagnosisReport) -> Result<(Context, Fitted), DiagnoseError> {
    let (Some(f), Some(ctx)) = (&r.kept.final_fit, &r.kept.context) else {
        return Err(DiagnoseError::Input(
            "the diagnosis kept no final fit to export".into(),
        ));
    };
    if ctx.correction.is_none() {
        return Ok((ctx.clone(), f.clone()));
    }
    let mut plain = ctx.clone();
    plain.correction = None;
    let refit = fit(
        &plain,
        &f.model,
        f.theta.clone(),
        &f.subset,
        Some(&f.sim.x),
        r.options.max_iterations,
    )?;
    Ok((plain, refit))
}

/// Builds the runtime model of a diagnosis.
pub fn diagnosed_model(
    r: &DiagnosisReport,
    tool: &str,
    source: &str,
) -> Result<ModelBuffers, DiagnoseError> {
    let (Some(f), Some(ctx)) = (&r.kept.final_fit, &r.kept.context) else {
        return Err(DiagnoseError::Input(
            "the diagnosis kept no final fit to export".into(),
        ));
    };
    // The refit without the correction can leave the physical range where the corrected fit did
    // not (a stiffening model at a corner): the model then carries the corrected fit's own
    // parameters, and its provenance says so.
    let (rctx, rf, diverged) = match runtime_fit(r) {
        Ok((c, g)) => (c, g, None),
        Err(DiagnoseError::Diverged(why)) => {
            let mut plain = ctx.clone();
            plain.correction = None;
            (plain, f.clone(), Some(why))
        }
        Err(e) => return Err(e),
    };
    let (sets, blend) = runtime_material(&rctx, &rf.model, &rf.theta, &rf.sim.x)?;
    let mut notes = vec![format!(
        "palpate diagnose: base E = {:.6e} Pa, nu = {:.4}; adopted: {}",
        r.young_poisson.0,
        r.young_poisson.1,
        Candidate::names(&r.adopted, ", ", "none")
    )];
    if let (Some(d), Some(why)) = (r.solved_on.correction_rms, &diverged) {
        notes.push(format!(
            "diagnosed with the approximation-error correction from the mesh refined once (delta {:.1} um RMS); the refit on the dataset mesh without it diverged ({why}), so this model carries the corrected fit's parameters: E = {:.6e} Pa, nu = {:.4}",
            1e6 * d,
            rf.theta[0].exp(),
            super::model::poisson_of(rf.theta[1]),
        ));
    } else if let Some(d) = r.solved_on.correction_rms {
        let rms = (rf.chi2 / rf.n.max(1) as f64 * 3.0).sqrt() * rctx.sigma;
        notes.push(format!(
            "diagnosed with the approximation-error correction from the mesh refined once (delta {:.1} um RMS); the values above are the object's. This model runs on the dataset mesh, so it was refitted there without the correction: E = {:.6e} Pa, nu = {:.4}, marker RMS {:.1} um",
            1e6 * d,
            rf.theta[0].exp(),
            super::model::poisson_of(rf.theta[1]),
            1e6 * rms
        ));
    }
    for &c in &r.adopted {
        let in_model = c.effect().in_runtime_model();
        let values: Vec<String> = effect_params(ctx, f, c)
            .iter()
            .map(|p| format!("{} = {:.4e} ± {:.1e} {}", p.name, p.value, p.sd, p.unit))
            .collect();
        notes.push(format!(
            "{}: {} [{}]",
            c.name(),
            if in_model {
                "in this model"
            } else {
                "a property of the measurement, not in this model"
            },
            values.join("; ")
        ));
    }
    let prov = ProvenanceInfo {
        tool: tool.to_string(),
        source: source.to_string(),
        notes: notes.join("\n"),
    };
    ModelBuffers::new(&rctx.problem, &rctx.node_tags, &sets, &blend, &prov)
        .map_err(|e| DiagnoseError::Write(e.to_string()))
}
