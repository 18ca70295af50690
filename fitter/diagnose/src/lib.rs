//! The closed loop of palpate: fit the simplest model, trace the residual to the effects it lacks,
//! adopt the candidates that earn their parameters, and report before/after — for five kinds of
//! data, each in a room of the same shape.
//!
//! | room | data | candidates | fit | signature | report |
//! |---|---|---|---|---|---|
//! | [`statics`] | static contact datasets (`docs/dataset.md`) | [`statics::candidates`] | [`statics::fit`] | [`statics::signature`] | [`statics::report`] |
//! | [`motion`] | one motion dataset (`docs/motion-dataset.md`) | [`motion::Candidate`] | [`motion::fit`] | [`motion::signature`] | [`motion::report`] |
//! | [`runs`] | several runs of one object, some held out | [`runs::Effect`] | [`runs`] | [`runs::RunResidual`] | [`runs::report`] |
//! | [`curve`] | measured curves (tension tests, CSV) | [`curve::candidates`] | [`curve::fit`] | [`curve::signature`] | [`curve::report`] |
//! | [`scans`] | scan datasets (`docs/scan-dataset.md`) | [`scans::Effect`] | [`scans::fit`] | the residual on the surface ([`scans::report`]) | [`scans::report`] |
//!
//! Each room has a `run.rs` that diagnoses one input on request and hands back a
//! [`run::Summary`]. Shared above the rooms: the selection engine every room drives
//! ([`select`]: ranking, the held-out gate, adoption, the verdict's rounds), the request that
//! recognises an input and dispatches it to its room ([`run`]), the `diagnosis.json` layer
//! (`json`) and the crate's one error ([`Error`]).
//!
//! ```no_run
//! use palpate_diagnose::{run_diagnosis, DiagnoseOptions};
//! let ds = palpate_fem::dataset::StaticDataset::read("models/sponge-specimen")?;
//! let report = run_diagnosis(&ds, &DiagnoseOptions::default())?;
//! println!("{}", palpate_diagnose::report::summary_lines(&report).join("\n"));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

/// The version the reports and exported models name as their tool.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");

pub mod convergence;
pub mod curve;
mod error;
mod json;
pub mod motion;
pub mod motion_convergence;
pub mod run;
pub mod runs;
pub mod runtime_match;
pub mod scans;
pub mod screen;
pub mod select;
pub mod statics;
mod summary;

pub use error::Error;

/// A fitted parameter with its uncertainty (1 σ from the Gauss–Newton covariance), in physical
/// units; one type for every room.
pub use select::ParamValue;

// The static room's modules and items under the paths the other crates use.
pub use statics::{
    approx_error, export, fit, model, noise, power, power_check, report, rest_noise, sensitivity,
    signature,
};
pub use statics::{
    base_params, effect_params, run_diagnosis, run_diagnosis_with, DiagnoseError, DiagnoseOptions,
    DiagnosisReport, Errors, Evidence, MeshChoice, MeshErrorSummary, ResidualCheck, SolvedOn, Step,
    Tried, MESH_ERROR_MAX_TETS,
};
