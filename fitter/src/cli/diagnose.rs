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
    /// Static or motion dataset directory, or measured curves (CSV file or directory).
    pub dataset: PathBuf,
    /// Report directory (diagnosis.md, diagnosis.json, evidence plots, model.palp for the runtime).
    #[arg(short, long, default_value = "diagnosis")]
    pub output: PathBuf,
    /// Candidates to try (default: all).
    #[arg(long, value_delimiter = ',')]
    pub candidates: Vec<String>,
    /// Most effects to adopt.
    #[arg(long, default_value_t = 3)]
    pub max_effects: usize,
    /// Gauge length L0 (mm) of tension-test CSVs (stretch λ = 1 + Δ/L0); fitted if not given.
    #[arg(long)]
    pub gauge_length: Option<f64>,
}

/// Runs the diagnosis.
pub fn run(args: Args) -> anyhow::Result<()> {
    // A CSV file or a directory of CSVs without dataset.toml: measured curves (diagnose::curve).
    if crate::diagnose::curve::read::is_curve_input(&args.dataset) {
        return crate::diagnose::curve::cli::run(
            &args.dataset,
            &args.output,
            &args.candidates,
            args.max_effects,
            args.gauge_length,
        );
    }
    if !args.dataset.exists() {
        anyhow::bail!("{}: no such file or directory", args.dataset.display());
    }
    if args.dataset.is_dir() && !args.dataset.join("dataset.toml").exists() {
        anyhow::bail!(
            "{}: not a static dataset (no dataset.toml), not a motion dataset (no dataset.toml \
             with `dt`, plus trajectories.csv) and not measured curves (no CSV file with a \
             recognised header); see docs/dataset.md, docs/motion-dataset.md and docs/diagnose.md",
            args.dataset.display()
        );
    }
    // dataset.toml with `dt`/`clamps`: a motion dataset (docs/motion-dataset.md).
    if args.dataset.is_dir() && crate::diagnose::motion::is_motion_dataset(&args.dataset) {
        return crate::diagnose::motion::cli::run(
            &args.dataset,
            &args.output,
            &args.candidates,
            args.max_effects,
        );
    }
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
    let mut files = write_report(&r, &args.output)?;
    let model_path = args.output.join("model.palp");
    let buffers = crate::diagnose::export::diagnosed_model(
        &r,
        &ds,
        &format!("palpate {} diagnose", env!("CARGO_PKG_VERSION")),
        &format!("{} ({})", ds.name, args.dataset.display()),
    )?;
    buffers
        .write(&model_path)
        .with_context(|| format!("writing {}", model_path.display()))?;
    files.push(model_path);
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
