//! Measured curves diagnosed on request (a CSV file or a directory of CSV files): runs the curve
//! diagnosis, writes one report per dataset and hands back one summary per dataset.

use super::candidates::Candidate;
use super::report::{summary_line, write_report};
use super::{diagnose_path, CurveOptions};
use crate::error::Error;
use crate::select::CandidateEffect as _;
use crate::summary::Summary;
use std::path::Path;

/// Every candidate name the curve library knows.
pub fn candidate_names() -> Vec<String> {
    Candidate::library()
        .into_iter()
        .map(|c| c.label())
        .collect()
}

/// Runs the diagnosis of `path`, writing reports under `output` (one sub-directory per dataset
/// when the path holds several).
pub fn run(
    path: &Path,
    output: &Path,
    candidates: &[String],
    max_effects: usize,
    gauge_mm: Option<f64>,
) -> Result<Vec<Summary>, Error> {
    let known = candidate_names();
    for c in candidates {
        if !known.contains(&c.trim().to_string()) {
            return Err(Error::UnknownCandidate {
                what: "candidate".into(),
                name: c.clone(),
                input: Some("curves"),
                known,
            });
        }
    }
    if let Some(l) = gauge_mm {
        if !(l > 0.0 && l.is_finite()) {
            return Err(Error::GaugeLength { found: l });
        }
    }
    let o = CurveOptions {
        gauge_mm,
        max_effects,
        candidates: (!candidates.is_empty())
            .then(|| candidates.iter().map(|c| c.trim().to_string()).collect()),
        ..Default::default()
    };
    let ds = diagnose_path(path, &o, &mut |m| log::info!("{m}"))?;
    ds.iter()
        .map(|d| {
            let dir = if ds.len() == 1 {
                output.to_path_buf()
            } else {
                output.join(&d.name)
            };
            Ok(Summary {
                lines: vec![summary_line(d)],
                files: write_report(d, &dir)?,
            })
        })
        .collect()
}
