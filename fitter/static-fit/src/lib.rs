//! Static material fits of seed 000 chapter 5 (and the blending data of §6.2):
//!
//! - [`force`]: the force-based linear least squares A(x̄)p = f̄ with spatial (L_s) and
//!   cross-measurement (L_m) smoothness (eqs. 5.15–5.60), with and without warping;
//! - [`completion`]: the deformed positions of unobserved nodes that the force-based fit needs
//!   (the observed markers are imposed as constraints on the current-parameter equilibrium);
//! - [`displacement`]: the displacement-based non-linear least squares on the observed markers
//!   (eqs. 5.61–5.92), Gauss–Newton/Levenberg–Marquardt with adjoint/direct Jacobian products;
//! - [`regularisation`]: L_s, L_m and the automatic choice of γ by the L-curve;
//! - [`blend`]: RBF weights over fitted deformations (eqs. 6.2–6.5) and per-element strain-space
//!   weights (eqs. 6.7–6.11);
//! - [`synthetic`]: synthetic datasets with known parameters for tests and evidence;
//! - [`loo`]: leave-one-out validation.
//!
//! Every fit returns a [`FitResult`] with residuals per marker and per measurement (and the
//! iteration history), which the report and the residual diagnosis reason with.

// Index loops over nodes/elements/coordinates mirror the equations' subscripts (x_{n,d},
// R_e); the iterator forms clippy suggests would obscure them.
#![allow(clippy::needless_range_loop)]
// Result tuples of (per-measurement, per-node) vectors are used once, at their call sites.
#![allow(clippy::type_complexity)]

pub mod blend;
pub mod completion;
pub mod displacement;
pub mod evidence;
pub mod force;
pub mod input;
pub mod loo;
pub mod param;
pub mod regularisation;
pub mod report;
pub mod run;
pub mod synthetic;

pub use input::{FitInput, FitMeasurement};
pub use run::{fit_static, FitOptions};

use palpate_fem::forward::{ForwardError, Material};

/// Every error of this crate (the fits, the synthetic datasets, the reports and evidence runs):
/// one flat enum; each message names what and where.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FitError {
    /// The forward model failed.
    #[error(transparent)]
    Forward(#[from] ForwardError),
    /// Input is inconsistent.
    #[error("{0}")]
    Input(String),
    /// The data cannot determine the parameters (zero forces, markers that do not move, fewer
    /// observations than parameters): refused before fitting.
    #[error("the data cannot be fitted:\n{0}")]
    Refused(palpate_fem::sanity::Refused),
    /// The least-squares system is rank deficient.
    #[error("the least-squares system is singular: {0}")]
    Singular(String),
    /// A fit produced non-finite or non-physical values.
    #[error("the fit diverged: {0}")]
    Diverged(String),
    /// A mesh could not be read.
    #[error(transparent)]
    Mesh(#[from] palpate_fem::mesh::gmsh::MeshError),
    /// A dataset could not be written.
    #[error(transparent)]
    Dataset(#[from] palpate_fem::dataset::read::DatasetError),
    /// A VTK file could not be written.
    #[error(transparent)]
    Vtk(#[from] palpate_fem::mesh::vtk::VtkError),
    /// A figure could not be drawn or written.
    #[error(transparent)]
    Plot(#[from] palpate_plot::PlotError),
    /// A report file could not be serialised or written.
    #[error("writing {file}: {message}")]
    Write {
        /// The file.
        file: std::path::PathBuf,
        /// What went wrong.
        message: String,
    },
}

/// Writes `bytes` to `file` atomically, the error naming the file.
pub(crate) fn write_file(file: &std::path::Path, bytes: &[u8]) -> Result<(), FitError> {
    palpate_fem::io::atomic::write_atomic(file, bytes).map_err(|e| FitError::Write {
        file: file.into(),
        message: format!("{e:#}"),
    })
}

/// Pretty JSON of `v`, the error naming the file it was meant for.
pub(crate) fn to_json(
    file: &std::path::Path,
    v: &impl serde::Serialize,
) -> Result<String, FitError> {
    serde_json::to_string_pretty(v).map_err(|e| FitError::Write {
        file: file.into(),
        message: e.to_string(),
    })
}

impl From<palpate_fem::sanity::Refused> for FitError {
    fn from(r: palpate_fem::sanity::Refused) -> Self {
        Self::Refused(r)
    }
}

/// One (λ, α) pair for all elements, or one per element (§3.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Layout {
    /// Homogeneous isotropic (one pair per set).
    Homogeneous,
    /// Inhomogeneous (one pair per element per set).
    Inhomogeneous,
}

/// One parameter set for every measurement (linear material) or one per measurement (non-linear
/// material, blended at run time, §5.2.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Sets {
    /// One set fitted to all measurements.
    Single,
    /// One set per measurement, tied by the cross-measurement smoothness L_m.
    PerMeasurement,
}

/// Which inverse.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Method {
    /// Force-based linear least squares (§5.2).
    Force,
    /// Displacement-based non-linear least squares (§5.3).
    Displacement,
}

impl std::fmt::Display for Layout {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Layout::Homogeneous => "homogeneous",
            Layout::Inhomogeneous => "inhomogeneous (one pair per element)",
        })
    }
}

impl std::fmt::Display for Sets {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Sets::Single => "one parameter set (linear)",
            Sets::PerMeasurement => "one parameter set per measurement (non-linear, blended)",
        })
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Method::Force => "force-based",
            Method::Displacement => "displacement-based",
        })
    }
}

/// The four regularisation weights (eqs. 5.50–5.52): spatial (s) and cross-measurement (m), for the
/// λ-type and α-type parameters.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Gammas {
    /// γ_s^λ: spatial smoothness of the thesis coefficient λ_F.
    #[serde(rename = "spatial_lambda_f")]
    pub s_lambda: f64,
    /// γ_s^α: spatial smoothness of α_G.
    #[serde(rename = "spatial_alpha_g")]
    pub s_alpha: f64,
    /// γ_m^λ: smoothness of λ_F across measurements.
    #[serde(rename = "across_measurements_lambda_f")]
    pub m_lambda: f64,
    /// γ_m^α: smoothness of α_G across measurements.
    #[serde(rename = "across_measurements_alpha_g")]
    pub m_alpha: f64,
}

impl Gammas {
    /// All four equal.
    pub fn uniform(g: f64) -> Self {
        Self {
            s_lambda: g,
            s_alpha: g,
            m_lambda: g,
            m_alpha: g,
        }
    }
    /// Spatial and cross-measurement weights.
    pub fn new(s: f64, m: f64) -> Self {
        Self {
            s_lambda: s,
            s_alpha: s,
            m_lambda: m,
            m_alpha: m,
        }
    }
    /// Multiplies the spatial pair by `k` (the L-curve scans this factor).
    pub fn scale_spatial(self, k: f64) -> Self {
        Self {
            s_lambda: self.s_lambda * k,
            s_alpha: self.s_alpha * k,
            ..self
        }
    }
}

/// How the γ's were chosen.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub enum GammaChoice {
    /// Given by the user.
    User,
    /// Not needed (homogeneous single set: overdetermined, no regularisation).
    NotNeeded,
    /// Chosen at the corner (largest curvature) of the L-curve over the listed grid.
    LCurve {
        /// (γ, data residual norm, roughness ‖L p‖ at γ = 1) per grid point.
        grid: Vec<(f64, f64, f64)>,
        /// Index of the chosen point.
        chosen: usize,
    },
}

/// Residuals of one measurement: every observed marker's error vector (simulated − measured, m)
/// and summary figures.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MeasurementResidual {
    /// Measurement id.
    pub id: String,
    /// Which fitted parameter set it uses.
    pub set: usize,
    /// (marker index, simulated − measured position) per observed marker (m).
    #[serde(rename = "marker_errors_m")]
    pub marker_errors: Vec<(usize, [f64; 3])>,
    /// Root-mean-square marker error (m).
    #[serde(rename = "rms_m")]
    pub rms: f64,
    /// Smallest marker error norm (m).
    #[serde(rename = "min_m")]
    pub min: f64,
    /// Mean marker error norm (m).
    #[serde(rename = "mean_m")]
    pub mean: f64,
    /// Largest marker error norm (m).
    #[serde(rename = "max_m")]
    pub max: f64,
    /// ‖A(x̄)p − f̄‖ over the free dofs (N) at the fitted/completed deformation, for the
    /// force-based method; `None` for the displacement-based one.
    #[serde(rename = "force_residual_n")]
    pub force_residual: Option<f64>,
}

impl MeasurementResidual {
    /// Builds the summary from the error vectors.
    pub fn new(
        id: String,
        set: usize,
        marker_errors: Vec<(usize, [f64; 3])>,
        force_residual: Option<f64>,
    ) -> Self {
        let norms: Vec<f64> = marker_errors
            .iter()
            .map(|(_, e)| (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt())
            .collect();
        let k = norms.len().max(1) as f64;
        let rms = (norms.iter().map(|v| v * v).sum::<f64>() / k).sqrt();
        let mean = norms.iter().sum::<f64>() / k;
        let min = norms.iter().copied().fold(f64::INFINITY, f64::min);
        let max = norms.iter().copied().fold(0.0, f64::max);
        Self {
            id,
            set,
            marker_errors,
            rms,
            min: if norms.is_empty() { 0.0 } else { min },
            mean,
            max,
            force_residual,
        }
    }
}

/// One iteration of a fit.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct IterationRecord {
    /// Iteration number (0 = start).
    pub iteration: usize,
    /// Objective (data term + regularisation).
    pub objective: f64,
    /// Data term (Σ squared residuals, in the method's units).
    pub data: f64,
    /// RMS marker error over all measurements (m).
    pub rms_m: f64,
    /// Levenberg–Marquardt damping (0 for the linear method).
    pub damping: f64,
    /// CG iterations spent on the step (0 for dense steps).
    pub cg_iterations: usize,
    /// Per-measurement RMS marker error at this iterate (m).
    #[serde(rename = "per_measurement_rms_m")]
    pub per_measurement_rms: Vec<f64>,
}

/// Result of a static fit.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FitResult {
    /// Method used.
    pub method: Method,
    /// Homogeneous or inhomogeneous.
    pub layout: Layout,
    /// One set or one per measurement.
    pub sets: Sets,
    /// Warping on or off.
    pub warp: bool,
    /// Fitted parameter sets (one, or one per measurement in measurement order).
    #[serde(skip)]
    pub params: Vec<Material>,
    /// Residuals per measurement, from the forward model driven with each measured contact.
    pub per_measurement: Vec<MeasurementResidual>,
    /// Iteration history.
    pub history: Vec<IterationRecord>,
    /// Regularisation weights used.
    pub gammas: Gammas,
    /// How they were chosen.
    pub gamma_choice: GammaChoice,
    /// Simulated deformation x_i for every measurement with the fitted parameters (blending
    /// centres, eqs. 6.2 and 6.8).
    #[serde(skip)]
    pub deformed: Vec<Vec<[f64; 3]>>,
    /// Roughness ‖L_s l‖ and ‖L_s a‖ of the thesis coefficients summed over sets (Pa), for the
    /// trade-off plot.
    #[serde(rename = "roughness_pa")]
    pub roughness: [f64; 2],
    /// Wall-clock seconds.
    #[serde(rename = "run_time_s")]
    pub seconds: f64,
    /// Whether the inverse met its tolerance (false: stopped at the iteration cap).
    pub converged: bool,
    /// What the sanity gates found in the result (parameters at bounds, the iteration cap):
    /// a result with an error finding is not exported by the command line.
    pub findings: palpate_fem::sanity::Findings,
}

impl FitResult {
    /// RMS marker error over every observed marker of every measurement (m).
    pub fn rms(&self) -> f64 {
        let (mut s, mut k) = (0.0, 0usize);
        for m in &self.per_measurement {
            for (_, e) in &m.marker_errors {
                s += e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
                k += 1;
            }
        }
        (s / k.max(1) as f64).sqrt()
    }
}

#[cfg(test)]
mod tests;
