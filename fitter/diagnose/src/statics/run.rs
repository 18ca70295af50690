//! One static dataset diagnosed on request: read, diagnose, write the report and the diagnosed
//! `model.palp`, and hand back the summary the command prints.

use std::path::Path;

use palpate_fem::dataset::StaticDataset;

use super::model::Candidate;
use super::report::write_report;
use super::{run_diagnosis_with, DiagnoseOptions, MeshChoice};
use crate::error::Error;
use crate::select::pick_candidates;
use crate::summary::Summary;

/// Runs the static diagnosis of the dataset at `path` into `output` (`full_search`: every open
/// candidate fitted, the fit screen off).
pub fn run(
    path: &Path,
    output: &Path,
    candidates: &[String],
    max_effects: usize,
    mesh: MeshChoice,
    full_search: bool,
) -> Result<Summary, Error> {
    let ds = StaticDataset::read(path).map_err(|source| Error::StaticDataset {
        path: path.into(),
        source: Box::new(source),
    })?;
    let mut o = DiagnoseOptions {
        max_effects,
        mesh,
        screen: !full_search,
        ..Default::default()
    };
    if !candidates.is_empty() {
        o.candidates = pick_candidates::<Candidate>(candidates)?;
    }
    let r = run_diagnosis_with(&ds, &o, |msg| log::info!("{msg}"))?;
    let mut files = write_report(&r, output)?;
    let model_path = output.join("model.palp");
    let buffers = super::export::diagnosed_model(
        &r,
        &format!("palpate {} diagnose", crate::VERSION),
        &format!("{} ({})", ds.name, path.display()),
    )?;
    buffers
        .write(&model_path)
        .map_err(|source| Error::WriteModel {
            path: model_path.clone(),
            source,
        })?;
    files.push(model_path);
    Ok(Summary {
        lines: super::report::summary_lines(&r),
        files,
    })
}
