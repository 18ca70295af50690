//! One diagnosis request, whatever the input: a static dataset, a motion dataset, a scan dataset,
//! measured curves, or a folder of these — recognised, dispatched to its diagnosis, reported, and (for
//! static and motion datasets) exported as the diagnosed model. Each input diagnosed hands back a
//! [`Summary`]; `palpate diagnose` is a thin shell over [`run_with`] that prints them.

use std::path::{Path, PathBuf};

use crate::error::Error;
use crate::MeshChoice;

/// What to diagnose and how.
#[derive(Debug, Clone)]
pub struct Request {
    /// Static or motion dataset directory, measured curves (CSV file or directory), or a folder
    /// holding such inputs.
    pub dataset: PathBuf,
    /// Report directory.
    pub output: PathBuf,
    /// Candidates to try by name (empty: all).
    pub candidates: Vec<String>,
    /// Most effects to adopt; `None`: [`DEFAULT_MAX_EFFECTS`], or for runs of one object
    /// [`crate::runs::RunsOptions`]'s default (its library holds four effects that combine).
    pub max_effects: Option<usize>,
    /// Mesh of static datasets' models.
    pub mesh: MeshChoice,
    /// Gauge length L0 (mm) of tension-test CSVs; fitted if `None`.
    pub gauge_length: Option<f64>,
    /// More motion datasets fitted together with `dataset` (runs of one object).
    pub more_runs: Vec<PathBuf>,
    /// Motion datasets held out: predicted, never fitted. Given (or `more_runs` given), the runs
    /// diagnosis ([`crate::runs`]) is run.
    pub held_out: Vec<PathBuf>,
    /// Poisson's ratio the runs diagnosis holds fixed (default 0.49).
    pub poisson: Option<f64>,
    /// Element design of scan datasets' fits (P2 when `None`).
    pub design: Option<crate::scans::Design>,
    /// Runs of one object: refit the final model on quadratic elements too
    /// ([`crate::motion_convergence`]).
    pub motion_convergence: bool,
    /// Fit every open candidate in every round (static, motion and runs diagnoses): the fit
    /// screen off, for a check of what it left unfitted.
    pub full_search: bool,
}

pub use crate::summary::Summary;

/// Whether `path` is something `diagnose` reads directly: measured curves, or a directory with a
/// `dataset.toml` (static or motion dataset).
fn diagnosable(path: &Path) -> bool {
    crate::curve::read::is_curve_input(path)
        || (path.is_dir() && path.join("dataset.toml").exists())
        || (path.is_dir() && palpate_scan::dataset::is_scan_dataset(path))
}

/// Runs the diagnosis and returns the summaries of every input diagnosed, in order.
pub fn run(args: &Request) -> Result<Vec<Summary>, Error> {
    let mut out = Vec::new();
    run_with(args, &mut |s| out.push(s))?;
    Ok(out)
}

/// Runs the diagnosis, handing each input's [`Summary`] to `done` as soon as it is written (a
/// folder of inputs takes minutes per input). A directory that is not itself a dataset or a set
/// of curves but holds such subdirectories (e.g. a data folder with one folder per instrument) is
/// diagnosed one subdirectory at a time, each into `<output>/<name>`; the summaries of those that
/// succeeded are handed over before the error that names those that failed.
pub fn run_with(args: &Request, done: &mut dyn FnMut(Summary)) -> Result<(), Error> {
    if !args.more_runs.is_empty() || !args.held_out.is_empty() {
        done(run_runs(args)?);
        return Ok(());
    }
    if args.dataset.is_dir() && !diagnosable(&args.dataset) {
        let mut subs: Vec<PathBuf> = std::fs::read_dir(&args.dataset)
            .map_err(|source| Error::ListDirectory {
                path: args.dataset.clone(),
                source,
            })?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_dir() && diagnosable(p))
            .collect();
        subs.sort();
        if !subs.is_empty() {
            let mut failed = Vec::new();
            for sub in &subs {
                let name = sub
                    .file_name()
                    .map(|n| n.to_os_string())
                    .unwrap_or_default();
                log::info!("== {}", sub.display());
                match diagnose_one(args, sub, &args.output.join(name)) {
                    Ok(summaries) => summaries.into_iter().for_each(&mut *done),
                    Err(e) => {
                        log::error!("{}: {e:#}", sub.display());
                        failed.push(sub.clone());
                    }
                }
            }
            if !failed.is_empty() {
                return Err(Error::Subdirectories {
                    failed,
                    total: subs.len(),
                });
            }
            return Ok(());
        }
    }
    diagnose_one(args, &args.dataset, &args.output)?
        .into_iter()
        .for_each(done);
    Ok(())
}

/// Most effects adopted by the static, motion and curve diagnoses unless asked otherwise.
pub const DEFAULT_MAX_EFFECTS: usize = 3;

/// Diagnoses one dataset or set of curves at `path` into `output` (a set of curves may hold
/// several datasets: one summary each).
fn diagnose_one(args: &Request, path: &Path, output: &Path) -> Result<Vec<Summary>, Error> {
    // A CSV file or a directory of CSVs without dataset.toml: measured curves (diagnose::curve).
    if crate::curve::read::is_curve_input(path) {
        return crate::curve::run::run(
            path,
            output,
            &args.candidates,
            args.max_effects.unwrap_or(DEFAULT_MAX_EFFECTS),
            args.gauge_length,
        );
    }
    if !path.exists() {
        return Err(Error::NotFound { path: path.into() });
    }
    // scans.toml: a scan dataset (docs/scan-dataset.md).
    if palpate_scan::dataset::is_scan_dataset(path) {
        return Ok(vec![crate::scans::run::run(
            path,
            output,
            &args.candidates,
            args.max_effects.unwrap_or(DEFAULT_MAX_EFFECTS),
            args.design,
            args.mesh,
        )?]);
    }
    if path.is_dir() && !path.join("dataset.toml").exists() {
        return Err(Error::NotDiagnosable { path: path.into() });
    }
    // dataset.toml with `dt`/`clamps`: a motion dataset (docs/motion-dataset.md).
    if path.is_dir() && crate::motion::is_motion_dataset(path) {
        return Ok(vec![crate::motion::run::run(
            path,
            output,
            &args.candidates,
            args.max_effects.unwrap_or(DEFAULT_MAX_EFFECTS),
            args.mesh,
            args.motion_convergence,
            args.full_search,
        )?]);
    }
    Ok(vec![crate::statics::run::run(
        path,
        output,
        &args.candidates,
        args.max_effects.unwrap_or(DEFAULT_MAX_EFFECTS),
        args.mesh,
        args.full_search,
    )?])
}

/// The runs diagnosis: `dataset` and `more_runs` fitted, `held_out` predicted.
fn run_runs(args: &Request) -> Result<Summary, Error> {
    let fitted: Vec<PathBuf> = std::iter::once(&args.dataset)
        .chain(&args.more_runs)
        .cloned()
        .collect();
    crate::runs::run::run(
        &fitted,
        &args.held_out,
        &args.output,
        &args.candidates,
        args.max_effects,
        args.poisson,
        args.motion_convergence,
        args.full_search,
    )
}

#[cfg(test)]
mod tests {
    use crate::select::pick_candidates;

    /// Names are looked up in the library of the room asked for (blanks trimmed), in the order
    /// given; an unknown name is refused naming that library and listing every name it knows.
    #[test]
    fn pick_candidates_looks_names_up_in_the_rooms_library() {
        let names = |v: &[&str]| v.iter().map(|n| n.to_string()).collect::<Vec<_>>();
        let got = pick_candidates::<crate::motion::Candidate>(&names(&[" time-offset", "density"]));
        assert_eq!(
            got.unwrap(),
            [
                crate::motion::Candidate::TimeOffset,
                crate::motion::Candidate::Density
            ]
        );
        let got = pick_candidates::<crate::runs::Effect>(&names(&["stiffening"])).unwrap();
        assert_eq!(got, [crate::runs::Effect::Stiffening]);
        // `layer` is a static candidate, not a motion one.
        let e = pick_candidates::<crate::motion::Candidate>(&names(&["layer"]))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("unknown motion candidate \"layer\"; known: viscosity,")
                && e.contains("time-offset"),
            "{e}"
        );
        let e = pick_candidates::<crate::statics::model::Candidate>(&names(&["viscosity"]))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("unknown candidate \"viscosity\"; known: "),
            "{e}"
        );
        assert!(e.contains("layer") && e.contains("inclusion"), "{e}");
    }
}
