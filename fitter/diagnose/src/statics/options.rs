//! What a static diagnosis may try and how it decides: [`DiagnoseOptions`] and the mesh it
//! solves on ([`MeshChoice`]).

use serde::Serialize;

use super::model::{Candidate, ALL_CANDIDATES};
use super::noise::NoiseOptions;
use super::rest_noise::RestNoiseOptions;
use crate::Error;

/// Options of [`super::run_diagnosis`].
#[derive(Debug, Clone, Serialize)]
pub struct DiagnoseOptions {
    /// Candidates to try.
    pub candidates: Vec<Candidate>,
    /// Inhomogeneity grid (nodes per axis).
    pub grid: [usize; 3],
    /// Most effects adopted.
    pub max_effects: usize,
    /// LM iterations per fit.
    pub max_iterations: usize,
    /// LM iterations of each leave-one-out refit (warm-started from the full fit).
    pub holdout_iterations: usize,
    /// ΔBIC must be below −this.
    pub bic_threshold: f64,
    /// The held-out error in excess of the noise floor √(RMS² − 3σ²) (σ declared; else the
    /// held-out RMS itself) must drop by at least this fraction.
    pub min_holdout_gain: f64,

    /// How many BIC-ranked candidates are cross-validated per round.
    pub cv_candidates: usize,
    /// Predict every open candidate's gain by one Gauss–Newton step before fitting any (the
    /// static fit screen, `statics/screen.rs`) and fit in full only those ranked first; `false`:
    /// fit every open candidate (the full search).
    pub screen: bool,
    /// With the screen: the fewest candidates fitted per round (when predicted to pay).
    pub screen_least: usize,
    /// With the screen: a candidate is fitted when its predicted ΔBIC is within this fraction of
    /// the best predicted one.
    pub screen_margin: f64,
    /// The marker-noise test run after the structural loop.
    pub noise: NoiseOptions,
    /// The rest-scan noise test run after the marker-noise test.
    pub rest_noise: RestNoiseOptions,
    /// Which mesh the models are solved on.
    pub mesh: MeshChoice,
    /// [`MeshChoice::Auto`] corrects when the dataset mesh's discretisation error (RMS at the
    /// markers) exceeds this fraction of the noise floor σ√3. Default 0: always, when the refined
    /// mesh is affordable — the correction costs a few refined solves per adopted effect and
    /// removes error the model would otherwise blame on an effect; a threshold made the choice
    /// flip between specimens of one kind (the stiff inclusion lowers the fitted E's mesh error
    /// from 116 to under 87 µm, half the floor, on one seed but not the other).
    pub refine_above: f64,
    /// [`MeshChoice::Auto`] never uses a refined mesh of more than this many tetrahedra: each
    /// refresh solves every measurement on it (with stiffening, a fixed point of such solves), and
    /// a dataset mesh of over 6k tets is usually fine enough for its own error to be small.
    pub refine_max_tets: usize,
    /// Place the inclusion candidate where the adjoint sensitivity scan of the simplest fit
    /// finds the best blob ([`super::sensitivity`]); false: under the mean contact point at a quarter
    /// of the depth (the start before the scan existed).
    pub locate_inclusion: bool,
    /// Measure the layer candidate's depth along the axis (the pushing direction, gravity, or
    /// the distance to the free surface) whose best layer the adjoint sensitivity scan predicts
    /// to lower χ² most ([`super::sensitivity::scan_layers`]); false: along the pushing direction.
    pub locate_layer: bool,
}

/// Which mesh the diagnosis solves its models on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum MeshChoice {
    /// The dataset's own mesh.
    Dataset,
    /// The dataset mesh refined once (every tetrahedron into eight): exact, 8× the elements,
    /// ≈ 100× the time of a full diagnosis.
    Refined,
    /// The dataset mesh with the approximation-error correction from the mesh refined once
    /// ([`super::approx_error`]): the refined model's predictions at each adopted fit, the coarse cost.
    Corrected,
    /// [`MeshChoice::Corrected`] when the dataset mesh's own discretisation error is a large part
    /// of the noise floor (see [`DiagnoseOptions::refine_above`]), else the dataset's mesh.
    Auto,
}

impl MeshChoice {
    /// Every choice, in the order of the enum.
    pub const ALL: [MeshChoice; 4] = [
        MeshChoice::Dataset,
        MeshChoice::Refined,
        MeshChoice::Corrected,
        MeshChoice::Auto,
    ];
    /// The names of [`MeshChoice::ALL`], as parsed and displayed (and serialised).
    pub const NAMES: [&'static str; 4] = ["dataset", "refined", "corrected", "auto"];

    /// The name on the command line and in reports (`dataset`, `refined`, `corrected`, `auto`).
    pub fn name(self) -> &'static str {
        match self {
            MeshChoice::Dataset => "dataset",
            MeshChoice::Refined => "refined",
            MeshChoice::Corrected => "corrected",
            MeshChoice::Auto => "auto",
        }
    }
}

impl std::fmt::Display for MeshChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for MeshChoice {
    type Err = Error;

    /// Parses one of [`MeshChoice::NAMES`] (surrounding blanks ignored).
    fn from_str(s: &str) -> Result<Self, Error> {
        Self::ALL
            .into_iter()
            .find(|m| m.name() == s.trim())
            .ok_or_else(|| Error::UnknownMesh { found: s.into() })
    }
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        Self {
            candidates: ALL_CANDIDATES.to_vec(),
            grid: [2, 2, 2],
            max_effects: 3,
            max_iterations: 8,
            holdout_iterations: 3,
            bic_threshold: 10.0,
            min_holdout_gain: 0.10,
            cv_candidates: 2,
            screen: true,
            screen_least: 3,
            screen_margin: 0.5,
            noise: NoiseOptions::default(),
            rest_noise: RestNoiseOptions::default(),
            mesh: MeshChoice::Auto,
            refine_above: 0.0,
            refine_max_tets: 50_000,
            locate_inclusion: true,
            locate_layer: true,
        }
    }
}
