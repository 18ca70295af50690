//! What `--model` names: a runtime model (`.palp`) or a fitted motion model (`fit.json`), told
//! apart by content (the `PALP` magic, a JSON object), never by the file's name. A command that
//! plays a model in the runtime (`simulate`, `haptic`) takes both: a fit is exported for the
//! runtime in memory, on the mesh of a run it was fitted on, by the export path
//! `fit-motion --export` writes files with (matched to the material where the fit recorded its
//! modulus as the mesh's). A command that needs the fit itself (`validate`)
//! refuses a `.palp`: it holds the runtime's linear material only, not the fit's viscosity,
//! density or loads. Which kind was read is logged.

use std::path::{Path, PathBuf};

use anyhow::Context;
use palpate_fem::export::ProvenanceInfo;
use palpate_motion::fitted::FittedModel;

use super::input_kind::{self, Kind};

/// A `--model` file, read as the kind its content shows.
pub enum ModelFile {
    /// A runtime model: its bytes, decoded by the caller.
    Palp {
        /// The file.
        path: PathBuf,
        /// Its content.
        bytes: Vec<u8>,
    },
    /// A fitted motion model.
    Fit {
        /// The file.
        path: PathBuf,
        /// The fit it holds.
        fit: Box<FittedModel>,
    },
}

impl ModelFile {
    /// Reads `path` as the kind its content shows and logs which. `command` is the command and
    /// flag being run (`simulate --model`), named in errors.
    pub fn read(path: &Path, command: &str) -> anyhow::Result<Self> {
        // A dataset, a capture or a mesh is refused naming what it is and where it goes.
        input_kind::expect_one_of(path, &[Kind::Palp, Kind::FitJson], command)?;
        let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
        let text_start = bytes
            .strip_prefix("\u{feff}".as_bytes())
            .unwrap_or(&bytes)
            .iter()
            .find(|b| !b.is_ascii_whitespace());
        let file = if bytes.starts_with(b"PALP") {
            Self::Palp {
                path: path.into(),
                bytes,
            }
        } else if text_start == Some(&b'{') {
            Self::Fit {
                path: path.into(),
                fit: Box::new(read_fit(path, &bytes)?),
            }
        } else {
            anyhow::bail!(
                "{}: `palpate {command}` takes {} or {}, and this is neither (no `PALP` magic, \
                 not a JSON object)",
                path.display(),
                Kind::Palp,
                Kind::FitJson
            );
        };
        log::info!("{command} {}: read as {}", path.display(), file.kind());
        Ok(file)
    }

    fn kind(&self) -> Kind {
        match self {
            Self::Palp { .. } => Kind::Palp,
            Self::Fit { .. } => Kind::FitJson,
        }
    }

    /// The fitted motion model; a `.palp` is refused, naming the file, what it is and what the
    /// command needs.
    pub fn into_fit(self, command: &str) -> anyhow::Result<FittedModel> {
        match self {
            Self::Fit { fit, .. } => Ok(*fit),
            Self::Palp { path, .. } => anyhow::bail!(
                "{} is {}, but `palpate {command}` needs {}: a .palp holds the runtime's linear \
                 material only, not the motion fit's viscosity, density and loads; give the \
                 fit.json that `palpate fit-motion -o` or `palpate diagnose` wrote",
                path.display(),
                Kind::Palp,
                Kind::FitJson
            ),
        }
    }

    /// The runtime model's bytes: a `.palp` as read, a fit exported on the mesh (and clamps) of
    /// the first of its fitted runs that reads on the model's mesh.
    pub fn into_runtime_bytes(self, command: &str) -> anyhow::Result<(PathBuf, Vec<u8>)> {
        let (path, fit) = match self {
            Self::Palp { path, bytes } => return Ok((path, bytes)),
            Self::Fit { path, fit } => (path, fit),
        };
        let (run, ds) = fitted_run(&path, &fit, command)?;
        let mat = fit
            .material()
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        let prov = ProvenanceInfo {
            tool: format!(
                "palpate {} {}",
                env!("CARGO_PKG_VERSION"),
                std::env::args().collect::<Vec<_>>().join(" ")
            ),
            source: path.display().to_string(),
            notes: format!("exported from the fit on the mesh of {}", run.display()),
        };
        // The material, not the mesh's locked modulus, where the fit recorded them apart.
        let (params, matched) = palpate_diagnose::runtime_match::export_parameters_or_own(
            &ds,
            &mat,
            fit.converged.as_ref(),
        );
        if let Some(m) = &matched {
            log::info!("{}", m.provenance());
        }
        let how = matched.as_ref().map(|m| m.provenance());
        let bytes = palpate_motion::export::model_buffers_with(
            &ds.mesh,
            &ds.model,
            &mat,
            &params,
            how.as_deref(),
            &prov,
        )
        .and_then(|b| b.encode())
        .with_context(|| format!("exporting {} for the runtime", path.display()))?;
        log::info!(
            "{}: exported for the runtime on the mesh and clamps of {} ({} nodes, {} tets); {}",
            path.display(),
            run.display(),
            ds.mesh.nodes.len(),
            ds.mesh.tets.len(),
            palpate_motion::export::lost_in_export(&mat)
        );
        Ok((path, bytes))
    }
}

/// Reads a `fit.json`: a fitted motion model of a format this program reads.
pub fn read_fit(path: &Path, bytes: &[u8]) -> anyhow::Result<FittedModel> {
    let fit: FittedModel = serde_json::from_slice(bytes).with_context(|| {
        format!(
            "{}: not a fitted motion model (the JSON of `palpate fit-motion -o`)",
            path.display()
        )
    })?;
    anyhow::ensure!(
        palpate_motion::fitted::READABLE_FORMATS.contains(&fit.format.as_str()),
        "{}: format {:?}, expected one of {:?}",
        path.display(),
        fit.format,
        palpate_motion::fitted::READABLE_FORMATS
    );
    Ok(fit)
}

/// The first of the fit's runs that reads as a motion dataset on the fit's mesh, looked for as
/// written (relative to the working folder, as `fit-motion` was given it) and beside the
/// `fit.json`. A fit holds its material per element but not the mesh nor the clamps, which the
/// runtime model needs.
fn fitted_run(
    path: &Path,
    fit: &FittedModel,
    command: &str,
) -> anyhow::Result<(PathBuf, palpate_motion::dataset::MotionDataset)> {
    let mut tried = Vec::new();
    for d in &fit.datasets {
        let mut places = vec![PathBuf::from(d)];
        let beside = path
            .parent()
            .filter(|dir| !dir.as_os_str().is_empty() && Path::new(d).is_relative());
        if let Some(dir) = beside {
            places.push(dir.join(d));
        }
        for p in places {
            if !p.join("dataset.toml").is_file() {
                tried.push(format!("{}: not found", p.display()));
                continue;
            }
            match palpate_motion::dataset::load(&p) {
                Ok(ds) if ds.mesh.nodes.len() == fit.nodes && ds.mesh.tets.len() == fit.tets => {
                    return Ok((p, ds))
                }
                Ok(ds) => tried.push(format!(
                    "{}: its mesh has {} nodes and {} tets, the fit's {} and {}",
                    p.display(),
                    ds.mesh.nodes.len(),
                    ds.mesh.tets.len(),
                    fit.nodes,
                    fit.tets
                )),
                Err(e) => tried.push(format!("{}: {e}", p.display())),
            }
        }
    }
    anyhow::bail!(
        "{} is {}; `palpate {command}` plays it in the runtime on the mesh and clamps of a run it \
         was fitted on, which the fit names but does not hold, and none of them reads here ({}). \
         Run from the folder the fit was made in, or write a .palp with \
         `palpate fit-motion … --export model.palp`",
        path.display(),
        Kind::FitJson,
        if tried.is_empty() {
            "it names no run".to_string()
        } else {
            tried.join("; ")
        }
    )
}
