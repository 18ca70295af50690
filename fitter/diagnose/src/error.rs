//! The one error of the crate: every diagnosis (static, motion, runs, curve) and the request that
//! dispatches them ([`crate::run::run`]) fail with [`Error`], whose variants say what failed and
//! where.

use std::path::PathBuf;

/// Why a diagnosis request failed. Every variant names the input or file it is about.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The input cannot be diagnosed (what and why, naming the dataset, run or curve).
    #[error("{0}")]
    Input(String),
    /// Writing a report failed (the file and the reason).
    #[error("writing the report: {0}")]
    Write(String),
    /// The static forward model failed.
    #[error(transparent)]
    Forward(#[from] palpate_fem::forward::ForwardError),
    /// A static fit left the physical range, or its law found no equilibrium under a load.
    #[error("the fit diverged: {0}")]
    Diverged(String),
    /// A curve file or directory cannot be read.
    #[error("{path}: {message}")]
    Io {
        /// Path.
        path: String,
        /// OS error.
        message: String,
    },
    /// A curve file's content is malformed.
    #[error("{file}:{line}: {message}")]
    Format {
        /// File.
        file: String,
        /// 1-based line.
        line: usize,
        /// What was expected and found.
        message: String,
    },
    /// The simplest curve model could not be fitted (the dataset named).
    #[error("{0}: the fit failed (no finite prediction)")]
    Fit(String),
    /// A motion dataset given as a value was malformed.
    #[error(transparent)]
    MotionData(#[from] palpate_motion::dataset::DatasetError),
    /// The motion simulator or optimiser failed (motion and runs diagnoses).
    #[error(transparent)]
    Motion(#[from] palpate_motion::MotionError),
    /// A scan dataset could not be read, or a scan fit failed (the file, the state, the solve).
    #[error(transparent)]
    Scan(#[from] palpate_scan::ScanError),
    /// A static dataset could not be read.
    #[error("reading {}: {source}", path.display())]
    StaticDataset {
        /// The dataset directory.
        path: PathBuf,
        /// What was wrong, naming file, line and field.
        source: Box<palpate_fem::dataset::read::DatasetError>,
    },
    /// A motion dataset could not be read.
    #[error("reading motion dataset {}: {source}", path.display())]
    MotionDataset {
        /// The dataset directory.
        path: PathBuf,
        /// What was wrong, naming file, line and field.
        source: Box<palpate_motion::dataset::DatasetError>,
    },
    /// The diagnosed model could not be written.
    #[error("writing {}: {source}", path.display())]
    WriteModel {
        /// The `.palp` file.
        path: PathBuf,
        /// What was wrong with the model or the write.
        source: palpate_fem::export::ExportError,
    },
    /// A directory could not be listed.
    #[error("listing {}: {source}", path.display())]
    ListDirectory {
        /// The directory.
        path: PathBuf,
        /// The operating-system error.
        source: std::io::Error,
    },
    /// A requested candidate is not in the library of the input's diagnosis.
    #[error(
        "unknown {what} {name:?}; known{}: {}",
        input.map(|i| format!(" for {i}")).unwrap_or_default(),
        known.join(", ")
    )]
    UnknownCandidate {
        /// "candidate" or "motion candidate".
        what: String,
        /// The name given.
        name: String,
        /// The kind of input whose library was searched, when the message names it ("curves").
        input: Option<&'static str>,
        /// Every name the library knows.
        known: Vec<String>,
    },
    /// A mesh choice that is not one of [`crate::MeshChoice`]'s names.
    #[error("unknown mesh {found:?}; expected one of: {}", crate::MeshChoice::NAMES.join(", "))]
    UnknownMesh {
        /// The name given.
        found: String,
    },
    /// The gauge length of tension-test curves is not a positive length.
    #[error("--gauge-length must be > 0 mm, found {found}")]
    GaugeLength {
        /// The value given (mm).
        found: f64,
    },
    /// The input does not exist.
    #[error("{}: no such file or directory", path.display())]
    NotFound {
        /// The path given.
        path: PathBuf,
    },
    /// A directory that is none of the inputs `diagnose` reads, and holds none as a subdirectory.
    #[error(
        "{}: not a static dataset (no dataset.toml), not a motion dataset (no dataset.toml \
         with `dt`, plus trajectories.csv) and not measured curves (no CSV file with a \
         recognised header), and no subdirectory is any of these; see docs/dataset.md, \
         docs/motion-dataset.md and docs/diagnose.md",
        path.display()
    )]
    NotDiagnosable {
        /// The directory.
        path: PathBuf,
    },
    /// Some subdirectories of a folder of inputs failed (each error was printed as it happened;
    /// the others were diagnosed and reported).
    #[error(
        "{} of {total} subdirectories could not be diagnosed: {}",
        failed.len(),
        failed.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
    )]
    Subdirectories {
        /// The subdirectories that failed.
        failed: Vec<PathBuf>,
        /// How many subdirectories were diagnosed.
        total: usize,
    },
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::MeshChoice;

    #[test]
    fn mesh_choice_names_parse_and_display_round_trip() {
        assert_eq!(MeshChoice::ALL.map(MeshChoice::name), MeshChoice::NAMES);
        for m in MeshChoice::ALL {
            assert_eq!(m.to_string().parse::<MeshChoice>().unwrap(), m);
            assert_eq!(
                serde_json::to_string(&m).unwrap(),
                format!("\"{}\"", m.name())
            );
        }
        let e = "fine".parse::<MeshChoice>().unwrap_err().to_string();
        assert!(e.contains("\"fine\"") && e.contains("corrected"), "{e}");
    }

    #[test]
    fn unknown_candidate_names_the_library() {
        let e = Error::UnknownCandidate {
            what: "candidate".into(),
            name: "x".into(),
            input: Some("curves"),
            known: vec!["a".into(), "b".into()],
        };
        assert_eq!(
            e.to_string(),
            "unknown candidate \"x\"; known for curves: a, b"
        );
    }
}
