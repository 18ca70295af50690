//! One scan dataset diagnosed on request: read, diagnose, write the report, and hand back the
//! line the command prints.

use std::path::Path;

use palpate_scan::dataset::ScanDataset;

use super::fit::Problem;
use super::report::{summary_line, write_report};
use super::{diagnose, Design, Effect, ScanOptions};
use crate::error::Error;
use crate::summary::Summary;

/// Runs the scan diagnosis of `dataset` into `output` on `design` (P2 when `None`), corrected
/// for the mesh's error unless `mesh` is [`crate::MeshChoice::Dataset`].
pub fn run(
    dataset: &Path,
    output: &Path,
    candidates: &[String],
    max_effects: usize,
    design: Option<Design>,
    mesh: crate::MeshChoice,
) -> Result<Summary, Error> {
    let ds = ScanDataset::read(dataset)?;
    let mut o = ScanOptions {
        max_effects,
        // `--mesh dataset`: the dataset's mesh as it is, its error not corrected.
        mesh_error: mesh != crate::MeshChoice::Dataset,
        ..ScanOptions::default()
    };
    if let Some(d) = design {
        o.design = d;
    }
    if !candidates.is_empty() {
        o.candidates = crate::select::pick_candidates::<Effect>(candidates)?;
    }
    let mut problem = Problem::new(&ds, o.design, &o.start_young, o.max_iter)?;
    let d = diagnose(&mut problem, &o)?;
    let name = dataset.display().to_string();
    let files = write_report(output, &name, &problem, &d)?;
    Ok(Summary {
        lines: vec![summary_line(&name, &d)],
        files,
    })
}
