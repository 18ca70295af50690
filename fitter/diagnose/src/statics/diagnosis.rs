//! What a static diagnosis finds: its rounds ([`Step`], [`Tried`]), the error figures of each
//! model ([`Errors`]), the mesh it solved on, and the whole [`DiagnosisReport`] (serialised as
//! `diagnosis.json`, `docs/json-outputs.md`).

use serde::Serialize;

use super::fit::Fitted;
use super::model::{Candidate, Context};
use super::noise::NoiseFinding;
use super::params::Identifiability;
use super::power;
use super::rest_noise::RestNoiseFinding;
use super::signature::Signature;
use super::{DiagnoseOptions, MeshChoice, ResidualCheck};
use crate::select::ParamValue;

/// Error figures of a model (m for markers, N for forces).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Errors {
    /// RMS marker error on the fitted data.
    pub fitted_rms: f64,
    /// Largest marker error on the fitted data.
    pub fitted_max: f64,
    /// RMS marker error on held-out measurements (leave-one-out).
    pub heldout_rms: f64,
    /// Largest held-out marker error.
    pub heldout_max: f64,
    /// RMS implied-force error on the fitted data: |s_i − 1| |f_i| with s_i the best scale of the
    /// simulated displacement onto the measured one (the force error the markers imply).
    pub force_rms: f64,
    /// Largest implied-force error on the fitted data.
    pub force_max: f64,
    /// RMS implied-force error on held-out measurements.
    pub heldout_force_rms: f64,
}

/// One candidate tried in a round.
#[derive(Debug, Clone, Serialize)]
pub struct Tried {
    /// Candidate.
    pub candidate: Candidate,
    /// Extra parameters.
    pub extra_params: usize,
    /// RMS marker error of the refit (m).
    pub rms: f64,
    /// ΔBIC against the current model (negative = better).
    pub delta_bic: f64,
    /// Held-out RMS (m), computed for the best-ranked candidates only.
    pub heldout_rms: Option<f64>,
    /// Paired t statistic of the held-out χ² reductions (cross-validated candidates only).
    pub heldout_t: Option<f64>,
    /// ΔBIC on the held-out predictions (cross-validated candidates only; must be < 0).
    pub heldout_delta_bic: Option<f64>,
    /// Held-out RMS implied-force error (N; cross-validated candidates only).
    pub heldout_force_rms: Option<f64>,
    /// Why it has no figures, when it could not be fitted (e.g. its law found no equilibrium
    /// under one of the loads): `rms` and `delta_bic` are then NaN.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub not_fitted: Option<String>,
    /// ΔBIC the fit screen predicted before any fit (`None`: not predicted, or the screen off).
    pub predicted_delta_bic: Option<f64>,
    /// Left unfitted by the fit screen (its prediction ranked it out).
    pub screened_out: bool,
}

/// Evidence plot data of an adopted effect: x label, y label, points before and after adoption.
pub type Evidence = (String, String, Vec<(f64, f64)>, Vec<(f64, f64)>);

/// One round of the loop.
#[derive(Debug, Clone, Serialize)]
pub struct Step {
    /// Round number (1-based).
    pub round: usize,
    /// Effects in the model at the start of the round.
    pub model: Vec<Candidate>,
    /// Residual signature of that model.
    pub signature: Signature,
    /// Candidates tried, best first.
    pub tried: Vec<Tried>,
    /// Adopted effect, if any.
    pub adopted: Option<Candidate>,
    /// Why (or why not).
    pub reason: String,
    /// Shortlisted candidates that also pass the held-out test and predict the held-out data
    /// better than the adopted one (held-out ΔBIC): alternatives the data cannot rule out.
    pub ambiguous_with: Vec<Candidate>,
    /// Errors of the model at the start of the round.
    pub before: Errors,
    /// Errors after adopting (if adopted).
    pub after: Option<Errors>,
    /// Fitted values of the adopted effect's parameters.
    pub new_params: Vec<ParamValue>,
    /// Evidence plot data: x label, y label, points before and after adoption.
    pub evidence: Option<Evidence>,
}

/// The report of [`super::run_diagnosis`].
#[derive(Debug, Clone, Serialize)]
pub struct DiagnosisReport {
    /// What was diagnosed and by which rule (serialised in its place, field by field).
    #[serde(flatten)]
    pub input: Diagnosed,
    /// Noise floor of the RMS marker error, σ √3 (m).
    pub noise_floor: f64,
    /// Options.
    pub options: DiagnoseOptions,
    /// The loop, round by round.
    pub steps: Vec<Step>,
    /// Effects adopted, in order (the structural effects of the final model, then `noise` if
    /// the marker noise exceeds the declared level).
    pub adopted: Vec<Candidate>,
    /// The marker-noise finding on the final model's residual (`None` if no marker has enough
    /// neighbours to estimate it).
    pub noise: Option<NoiseFinding>,
    /// The rest-scan finding on the final model's residual (`None` when σ is not declared or too
    /// few markers were seen twice).
    pub rest_noise: Option<RestNoiseFinding>,
    /// Evidence plot of the noise finding: (distance from the contact m, normalised nugget error
    /// m) per marker neighbourhood.
    pub noise_evidence: Vec<(f64, f64)>,
    /// Errors of the simplest model.
    pub before: Errors,
    /// The dataset mesh's own discretisation error under the simplest model (`None` when the
    /// refined mesh would exceed [`MESH_ERROR_MAX_TETS`] or a refined solve failed).
    pub mesh_error: Option<MeshErrorSummary>,
    /// The mesh the models were solved on, and why.
    pub solved_on: SolvedOn,
    /// Errors of the final model.
    pub after: Errors,
    /// Whether the final residual is explained by the noise floor ([`ResidualCheck`]).
    pub residual_check: ResidualCheck,
    /// For a residual the noise explains: the smallest magnitude of every candidate the final
    /// model does not hold that this dataset would have detected ([`power::detectable`]); empty
    /// when the residual is not explained (then something is missing, and the verdict says so).
    pub detectable: Vec<power::Detectable>,
    /// Every parameter of the final model.
    pub final_params: Vec<ParamValue>,
    /// What those parameters are known only relative to: degenerate pairs and assumptions.
    pub identifiability: Identifiability,
    /// Young's modulus (Pa) and Poisson ratio of the final model's base material.
    pub young_poisson: (f64, f64),
    /// Wall-clock seconds.
    pub seconds: f64,
    /// The final fit and its context, kept for the export (not serialised).
    #[serde(skip)]
    pub kept: Kept,
}

/// What a diagnosis was run on and by which rule.
#[derive(Debug, Clone, Serialize)]
pub struct Diagnosed {
    /// Dataset name.
    pub dataset: String,
    /// Selection rule in words.
    pub criterion: String,
    /// σ (m) used to scale residuals.
    pub sigma: f64,
    /// Whether σ was declared.
    pub sigma_declared: bool,
}

/// The final fit and its context, kept for the export.
#[derive(Debug, Clone, Default)]
pub struct Kept {
    /// The final fit (parameters, simulation).
    pub final_fit: Option<Fitted>,
    /// The prepared context.
    pub context: Option<Context>,
}

/// The simplest model solved again on the dataset mesh refined once
/// ([`palpate_fem::dataset::mesh_error`]): u_h − u_{h/2} at the observed markers. Reported, not yet used
/// by the selection rule: a residual structure of this size can be the mesh rather than a missing
/// effect (e.g. a "layer" of softer material compensating linear tetrahedra that are too stiff
/// under the probe).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct MeshErrorSummary {
    /// RMS over the observed markers (m).
    pub rms: f64,
    /// Largest marker difference (m).
    pub max: f64,
    /// Tetrahedra of the refined mesh.
    pub refined_tets: usize,
}

/// The mesh the diagnosis solved on.
#[derive(Debug, Clone, Serialize)]
pub struct SolvedOn {
    /// Tetrahedra of that mesh.
    pub tets: usize,
    /// The choice made (never [`MeshChoice::Auto`]).
    pub choice: MeshChoice,
    /// RMS of the final approximation-error correction (m), when corrected.
    pub correction_rms: Option<f64>,
    /// Fitted RMS marker error (m) of the simplest model on the dataset's own mesh.
    pub dataset_mesh_rms: f64,
    /// Why this mesh.
    pub reason: String,
}

/// The mesh-error estimate is skipped when the refined mesh would have more tetrahedra than this
/// (its direct solves would dominate the diagnosis).
pub const MESH_ERROR_MAX_TETS: usize = 200_000;
