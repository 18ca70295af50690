//! Runs of one object diagnosed on request: load the runs fitted and those held out, diagnose them
//! together, write the report, and hand back the summary the command prints.

use std::path::PathBuf;

use crate::error::Error;
use crate::summary::Summary;

/// Runs the runs diagnosis: `fitted` fitted together, `held_out` predicted, the report into
/// `output`; `max_effects` and `poisson` override [`super::RunsOptions`]'s defaults, and
/// `full_search` turns its fit screen off.
pub fn run(
    fitted: &[PathBuf],
    held_out: &[PathBuf],
    output: &std::path::Path,
    candidates: &[String],
    max_effects: Option<usize>,
    poisson: Option<f64>,
    motion_convergence: bool,
    full_search: bool,
) -> Result<Summary, Error> {
    let load = |p: &PathBuf| -> Result<(String, palpate_motion::dataset::MotionDataset), Error> {
        let ds = palpate_motion::dataset::load(p).map_err(|source| Error::MotionDataset {
            path: p.clone(),
            source: Box::new(source),
        })?;
        Ok((p.display().to_string(), ds))
    };
    // Each run's reading checks its own simulation step (two simulations): side by side, and the
    // first failing run in the order given is the one reported.
    use rayon::prelude::*;
    let paths: Vec<&PathBuf> = fitted.iter().chain(held_out).collect();
    let mut loaded: Vec<_> = paths
        .par_iter()
        .map(|p| load(p))
        .collect::<Vec<_>>()
        .into_iter()
        .collect::<Result<Vec<_>, _>>()?;
    let held = loaded.split_off(fitted.len());
    let fit = loaded;
    let mut o = super::RunsOptions::default();
    if let Some(n) = max_effects {
        o.max_effects = n;
    }
    if let Some(nu) = poisson {
        o.poisson = nu;
    }
    o.motion_convergence = motion_convergence;
    o.screen = !full_search;
    if !candidates.is_empty() {
        o.candidates = crate::select::pick_candidates::<super::Effect>(candidates)?;
    }
    let r = super::diagnose_runs(&fit, &held, &o, &|m| log::info!("{m}"))?;
    let files = super::report::write_report(&r, output, fit[0].1.model.dt)?;
    Ok(Summary {
        lines: vec![super::report::summary_line(&r)],
        files,
    })
}
