//! The record `palpate fit-motion -o fit.json` writes and `palpate validate --model fit.json`
//! reads: the fitted material per element, what was fitted and what was held, and per fitted run
//! its load and where it came to rest (the points of the linear baseline of
//! [`super::predict::linear_baseline`]).

use serde::{Deserialize, Serialize};

use super::model::Model;

/// Gives every load of `model` declared as a mass the inertia of that mass (`on`), or none.
pub fn set_hanging_inertia(model: &mut Model, on: bool) {
    for l in &mut model.loads {
        l.inertia = on && l.mass.is_some() && l.from_step == 0;
    }
}

/// The format tag of [`FittedModel`].
pub const FORMAT: &str = "palpate-motion-fit/1";

/// A motion fit, as written to JSON.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FittedModel {
    /// [`FORMAT`].
    pub format: String,
    /// The fitted datasets (directories as given).
    pub datasets: Vec<String>,
    /// Nodes of the mesh the material belongs to.
    pub nodes: usize,
    /// Tetrahedra of that mesh (one value per element in each array below, or one for all).
    pub tets: usize,
    /// Lamé's λ per element (Pa).
    pub lambda: Vec<f64>,
    /// Shear modulus μ per element (Pa).
    pub mu: Vec<f64>,
    /// Viscosity coefficient of the power law (Pa·s^h) per element (the paper's ν; not Poisson's ratio).
    pub viscosity: Vec<f64>,
    /// Power-law index h per element.
    pub h: Vec<f64>,
    /// Density per element (kg/m³).
    pub density: Vec<f64>,
    /// Poisson's ratio, when it was held fixed (λ followed μ).
    pub poisson_fixed: Option<f64>,
    /// Whether hanging masses moved with their nodes (inertia) in the fit; a prediction applies
    /// the same to the loads of the run it predicts.
    #[serde(default)]
    pub hanging_inertia: bool,
    /// The fitted parameter kinds (the others were held at their dataset values).
    pub fitted: Vec<String>,
    /// The thesis' (λ, α) pair of each element, as exported to the runtime.
    pub runtime_lambda_alpha: Vec<[f64; 2]>,
    /// RMS marker error over all runs at the fitted parameters (m).
    pub rms_marker_m: f64,
    /// RMS clamp-force error over all runs (N).
    pub rms_force_n: f64,
    /// Simulations the fit ran.
    pub evaluations: usize,
    /// Per fitted run.
    pub runs: Vec<FittedRun>,
}

/// One fitted run's summary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FittedRun {
    /// The dataset directory.
    pub dataset: String,
    /// Dead loads along gravity at the end of the run (N), [`super::predict::load_along_gravity`].
    pub load_n: f64,
    /// RMS marker error of this run at the fitted parameters (m).
    pub rms_marker_m: f64,
    /// The markers, in the order of `final_displacement_m`.
    pub markers: Vec<String>,
    /// Each marker's observed rest state minus its rest position (m), `None` if unseen.
    pub final_displacement_m: Vec<Option<[f64; 3]>>,
}
