//! One motion dataset diagnosed on request: load, diagnose, write the report and `model.palp`,
//! and hand back the summary the command prints.

use super::report::{summary_line, write_report};
use super::{diagnose, Candidate, MotionOptions};
use crate::error::Error;
use crate::summary::Summary;
use palpate_fem::export::ProvenanceInfo;
use std::path::Path;

/// Runs the motion diagnosis of `dataset` into `output` (`full_search`: every open candidate
/// fitted, the fit screen off).
pub fn run(
    dataset: &Path,
    output: &Path,
    candidates: &[String],
    max_effects: usize,
    mesh: crate::MeshChoice,
    motion_convergence: bool,
    full_search: bool,
) -> Result<Summary, Error> {
    if mesh == crate::MeshChoice::Refined {
        return Err(Error::Input(format!(
            "{}: --mesh refined: a motion diagnosis fits on the dataset's mesh (the refined mesh \
             measures its error and checks each adoption against it); expected `auto` or \
             `dataset`",
            dataset.display()
        )));
    }
    let ds = palpate_motion::dataset::load(dataset).map_err(|source| Error::MotionDataset {
        path: dataset.into(),
        source: Box::new(source),
    })?;
    // `--mesh dataset`: nothing on the refined mesh (neither the error's estimate nor the
    // check of each adoption against the mesh's own null).
    let refined = mesh != crate::MeshChoice::Dataset;
    let mut o = MotionOptions {
        max_effects,
        mesh_error: refined,
        mesh_null: refined,
        motion_convergence,
        screen: !full_search,
        ..Default::default()
    };
    if !candidates.is_empty() {
        o.candidates = crate::select::pick_candidates::<Candidate>(candidates)?;
    }
    let label = dataset.display().to_string();
    let r = diagnose(&ds, &label, &o, &|m| log::info!("{m}"))?;
    let mut files = write_report(&r, output)?;
    if let Some(mat) = &r.material {
        let prov = ProvenanceInfo {
            tool: format!("palpate {} diagnose", crate::VERSION),
            source: label.clone(),
            notes: format!(
                "motion diagnosis: adopted [{}]; RMS marker error {:.4e} m fitted, {:.4e} m held out",
                r.adopted.join(", "),
                r.after.rms_fit,
                r.after.rms_held
            ),
        };
        // The runtime replays the material, not the mesh's locked modulus, where the check
        // found them apart (`crate::runtime_match`).
        let converged = r
            .mesh_convergence
            .as_ref()
            .and_then(|c| c.converged_modulus());
        let (params, matched) =
            crate::runtime_match::export_parameters_or_own(&ds, mat, converged.as_ref());
        let how = matched.as_ref().map(|m| m.provenance());
        if let Some(m) = &matched {
            let path = output.join("runtime-match.md");
            palpate_fem::io::atomic::write_atomic(&path, m.report().as_bytes())
                .map_err(|e| Error::Write(format!("{}: {e}", path.display())))?;
            files.push(path);
        }
        let path = output.join("model.palp");
        match palpate_motion::export::model_buffers_with(
            &ds.mesh,
            &ds.model,
            mat,
            &params,
            how.as_deref(),
            &prov,
        ) {
            Ok(b) => {
                b.write(&path).map_err(|source| Error::WriteModel {
                    path: path.clone(),
                    source,
                })?;
                files.push(path);
            }
            Err(e) => log::warn!("model.palp not written: {e}"),
        }
    }
    Ok(Summary {
        lines: vec![summary_line(&r)],
        files,
    })
}
