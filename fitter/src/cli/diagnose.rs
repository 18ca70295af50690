//! `palpate diagnose <dataset>`: fit the simplest model, trace the residual to the effects the
//! model lacks, adopt those that earn their parameters, and report before/after.

use std::path::PathBuf;

use anyhow::Context as _;

use crate::dataset::StaticDataset;
use crate::diagnose::model::{Candidate, ALL_CANDIDATES};
use crate::diagnose::report::write_report;
use crate::diagnose::{run_diagnosis_with, DiagnoseOptions};

/// Options.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Static dataset directory.
    pub dataset: PathBuf,
    /// Report directory (diagnosis.md, diagnosis.json, evidence plots).
    #[arg(short, long, default_value = "diagnosis")]
    pub output: PathBuf,
    /// Candidates to try (default: all).
    #[arg(long, value_delimiter = ',')]
    pub candidates: Vec<String>,
    /// Most effects to adopt.
    #[arg(long, default_value_t = 3)]
    pub max_effects: usize,
}

/// Runs the diagnosis.
pub fn run(args: Args) -> anyhow::Result<()> {
    let ds = StaticDataset::read(&args.dataset)
        .with_context(|| format!("reading {}", args.dataset.display()))?;
    let mut o = DiagnoseOptions {
        max_effects: args.max_effects,
        ..Default::default()
    };
    if !args.candidates.is_empty() {
        o.candidates = args
            .candidates
            .iter()
            .map(|n| {
                ALL_CANDIDATES
                    .iter()
                    .copied()
                    .find(|c| c.name() == n.trim())
                    .ok_or_else(|| {
                        anyhow::anyhow!(
                            "unknown candidate {n:?}; known: {}",
                            ALL_CANDIDATES
                                .iter()
                                .map(|c| c.name())
                                .collect::<Vec<_>>()
                                .join(", ")
                        )
                    })
            })
            .collect::<anyhow::Result<Vec<Candidate>>>()?;
    }
    let r = run_diagnosis_with(&ds, &o, |msg| eprintln!("{msg}"))?;
    let files = write_report(&r, &args.output)?;
    println!(
        "{}: {}; RMS marker error {:.1} → {:.1} µm fitted, {:.1} → {:.1} µm held out (noise floor {:.1} µm)",
        r.dataset,
        if r.adopted.is_empty() { "clean (no effect adopted)".to_string() } else { format!("adopted {}", r.adopted.iter().map(|c| c.name()).collect::<Vec<_>>().join(", ")) },
        1e6 * r.before.fitted_rms,
        1e6 * r.after.fitted_rms,
        1e6 * r.before.heldout_rms,
        1e6 * r.after.heldout_rms,
        1e6 * r.noise_floor
    );
    for f in files {
        println!("wrote {}", f.display());
    }
    Ok(())
}
