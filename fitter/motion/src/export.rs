//! Export of a motion fit to the haptic runtime's model (`.palp`): the fitted elastic
//! parameters, converted from Lamé (λ_L, μ) to the thesis (λ, α) of seed 000 (eqs. 3.36–3.38;
//! α = λ_L, λ = 2μ + 2λ_L, see `palpate_runtime::material::LambdaAlpha::from_lame`), written
//! through the same record builder as the static fit ([`palpate_fem::export::ModelBuffers::build`]).
//!
//! The runtime is a quasi-static warped linear FEM, so the export keeps only the small-strain
//! elastic moduli. What is lost is stated in the model's provenance ([`lost_in_export`]):
//! viscosity ν and the power-law index h (eq. 17), density (no inertia in the runtime), the
//! large-strain Neo-Hookean response (eq. 16) — replaced by its linearisation at rest plus
//! stiffness warping, which agree for small strains and arbitrary rotations — and, for the spline
//! material of §4.2, everything beyond its rest tangent. Clamp motion is lost too: the runtime
//! holds the clamp groups fixed at their rest positions.

use super::model::{Material, Model, ParamKind};
use palpate_fem::export::{ExportError, ModelBuffers, ProvenanceInfo};
use palpate_fem::forward::Material as ThesisMaterial;
use palpate_fem::mesh::Mesh;
use palpate_runtime::material::LambdaAlpha;

/// Small-strain Lamé constants (λ_L, μ) of element `e`: the fitted Neo-Hookean values, or the
/// rest tangent of the spline material when it is active.
pub fn lame_at_rest(mat: &Material, e: usize) -> (f64, f64) {
    match &mat.spline {
        Some(s) => s.lame_at_rest(),
        None => (mat.get(ParamKind::Lambda, e), mat.get(ParamKind::Mu, e)),
    }
}

/// Per-element thesis parameters (λ_e, α_e) of a fitted motion material; a single global pair
/// when every element has the same values.
pub fn runtime_parameters(mat: &Material) -> ThesisMaterial {
    let ne = mat.values[0].len();
    let all: Vec<LambdaAlpha> = (0..ne)
        .map(|e| {
            let (l, m) = lame_at_rest(mat, e);
            LambdaAlpha::from_lame(l, m)
        })
        .collect();
    if all.iter().all(|p| *p == all[0]) {
        ThesisMaterial::homogeneous(all[0])
    } else {
        ThesisMaterial::per_element(&all)
    }
}

/// The sentence stored in the provenance notes and printed by `fit-motion --export`.
pub fn lost_in_export(mat: &Material) -> String {
    let mean = |k: ParamKind| {
        let v = &mat.values[k as usize];
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    let elastic = match &mat.spline {
        Some(sp) => format!(
            "the spline (principal-stretch, seed 001 §4.2) material's large-strain response: only \
             its rest tangent (small-strain Lame constants) is kept, and its stress at rest \
             f'(1) + h'(1) = {:.4e} Pa is dropped",
            sp.rest_stress()
        ),
        None => "the large-strain Neo-Hookean response (seed 001 eq. 16): the runtime uses its \
                 rest linearisation with stiffness warping (equal for small strains, any rotation)"
            .to_string(),
    };
    format!(
        "motion fit exported to the static runtime; lost: viscosity = {:.4e} Pa s^h and \
         power-law index h = {:.4} (eq. 17; the runtime is quasi-static), density {:.4e} kg/m^3 \
         (no inertia), {elastic}; clamp motion (clamp groups are held fixed at rest)",
        mean(ParamKind::Nu),
        mean(ParamKind::PowerH),
        mean(ParamKind::Density)
    )
}

/// Fixed nodes of the runtime model: every node of every clamp group, ascending.
pub fn clamp_nodes(model: &Model) -> Vec<usize> {
    let mut v: Vec<usize> = model
        .clamps
        .iter()
        .flat_map(|c| c.nodes.iter().copied())
        .collect();
    v.sort_unstable();
    v.dedup();
    v
}

/// Builds the runtime model of a motion fit. `prov.notes` is extended by [`lost_in_export`].
pub fn model_buffers(
    mesh: &Mesh,
    model: &Model,
    mat: &Material,
    prov: &ProvenanceInfo,
) -> Result<ModelBuffers, ExportError> {
    model_buffers_with(mesh, model, mat, &runtime_parameters(mat), None, prov)
}

/// [`model_buffers`] with the runtime's parameters given (`params`: thesis (λ, α), one pair or
/// one per element) instead of the fit's own at rest — the runtime matched to the converged
/// material, whose provenance `matched` says (appended to the notes).
pub fn model_buffers_with(
    mesh: &Mesh,
    model: &Model,
    mat: &Material,
    params: &ThesisMaterial,
    matched: Option<&str>,
    prov: &ProvenanceInfo,
) -> Result<ModelBuffers, ExportError> {
    for (e, (&lambda, &alpha)) in params.lambda.iter().zip(&params.alpha).enumerate() {
        if !(LambdaAlpha { lambda, alpha }).is_physical() {
            return Err(ExportError::Sets(format!(
                "element {e}: fitted (lambda, alpha) = ({lambda:e}, {alpha:e}) Pa is not a \
                 physical linear material (needs E > 0, -1 < Poisson < 0.5)"
            )));
        }
    }
    let mut p = prov.clone();
    let mut notes: Vec<String> = [p.notes.clone(), lost_in_export(mat)]
        .into_iter()
        .filter(|s| !s.is_empty())
        .collect();
    notes.extend(matched.map(str::to_string));
    p.notes = notes.join("; ");
    ModelBuffers::from_mesh(mesh, &clamp_nodes(model), params, &p)
}
