//! The specimen generator: a stand-in for a real object, simulated at higher fidelity
//! than the model the fitter uses (a finer mesh, Neo-Hookean with optional strain stiffening via
//! [`palpate_motion::statics::solve_static`], so large strains are non-linear), with physical effects
//! nobody declared, written as a STATIC dataset ([`palpate_fem::dataset::StaticDataset::write`]).
//!
//! The ground truth (material, effects with magnitudes, noise-free marker positions) is written to
//! `truth.json` next to the dataset. The fitter and `palpate diagnose` never read it: it exists so
//! evidence runs can score what diagnose names against what was injected.
//!
//! - [`effect`]: the effect library ([`Effect`]) with magnitude knobs and their defaults;
//! - [`generate`](mod@generate): the simulation ([`generate::generate`]);
//! - [`motion`]: motion specimens (the example bar with one effect each, drawn at random).

pub mod effect;
pub mod generate;
pub mod motion;
pub mod signal;
pub mod viscous;

pub use effect::{Effect, EffectSpec};
pub use generate::{generate, Specimen, SpecimenOptions, Truth};
pub use signal::signal_rms;

use serde::Serialize;

/// Every error of this crate (generating and writing specimens): one flat enum; each message
/// names what and where.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SpecimenError {
    /// An effect name was not recognised.
    #[error("unknown effect {name:?}; known effects: {known}")]
    UnknownEffect {
        /// What was given.
        name: String,
        /// Comma-separated known names.
        known: String,
    },
    /// A magnitude is not finite or out of its range.
    #[error("effect {effect}: magnitude {value} is not allowed ({why})")]
    Magnitude {
        /// Effect name.
        effect: &'static str,
        /// Given magnitude.
        value: f64,
        /// Why.
        why: &'static str,
    },
    /// Options are inconsistent.
    #[error("{0}")]
    Options(String),
    /// The linear forward model (used for the contact rule on the fine mesh) failed.
    #[error("contact load on the truth mesh: {0}")]
    Forward(#[from] palpate_fem::forward::ForwardError),
    /// The hyperelastic solve failed.
    #[error("Neo-Hookean truth solve of measurement {measurement}: {message}")]
    Truth {
        /// Measurement index.
        measurement: usize,
        /// Solver message.
        message: String,
    },
    /// A marker could not be embedded.
    #[error("marker {marker} at {point:?} could not be embedded in the {mesh} mesh surface")]
    Embed {
        /// Marker index.
        marker: usize,
        /// Its rest position.
        point: [f64; 3],
        /// Which mesh.
        mesh: &'static str,
    },
    /// The dataset could not be written.
    #[error(transparent)]
    Dataset(#[from] palpate_fem::dataset::read::DatasetError),
    /// A file could not be written.
    #[error("writing {file}: {message}")]
    Write {
        /// The file.
        file: std::path::PathBuf,
        /// What went wrong.
        message: String,
    },
}

/// Writes `bytes` to `file` atomically, the error naming the file.
fn write_file(file: &std::path::Path, bytes: &[u8]) -> Result<(), SpecimenError> {
    palpate_fem::io::atomic::write_atomic(file, bytes).map_err(|e| SpecimenError::Write {
        file: file.into(),
        message: format!("{e:#}"),
    })
}

/// Pretty JSON of `v`, the error naming the file it was meant for.
fn to_json(file: &std::path::Path, v: &impl Serialize) -> Result<String, SpecimenError> {
    serde_json::to_string_pretty(v).map_err(|e| SpecimenError::Write {
        file: file.into(),
        message: e.to_string(),
    })
}

/// The specimen stream ([`palpate_fem::rng::study_stream`]), shared with the diagnosis's
/// noise studies.
pub use palpate_fem::rng::study_stream as rng;
