//! The `palpate` command line: one file per subcommand, each with its `Args` and `run`.

use clap::{Parser, Subcommand};

pub mod calibrate_fsr;
pub mod demo;
pub mod demo_beam;
pub mod demo_readme;
pub mod diagnose;
pub mod export;
pub mod fit;
pub mod fit_motion;
pub mod fit_scan;
pub mod haptic;
pub mod import;
pub mod import_scan;
pub mod info;
pub mod input_kind;
pub mod logging;
pub mod model_file;
pub mod output;
pub mod probe;
pub mod probe_sim;
pub mod renamed;
pub mod simulate;
pub mod specimen;
pub mod validate;

/// palpate: learn how a soft object deforms when touched, and play it back at haptic rates.
#[derive(Debug, Parser)]
#[command(
    name = "palpate",
    version,
    about,
    long_about = None,
    after_help = "Results (tables, summaries, a last JSON line) go to stdout; progress, notes, the \
                  files written and warnings go to stderr (-q: only warnings and errors).\n\
                  -o/--output (also --out) is what a command writes, a file or a folder: a command \
                  that exists to write files has a default (shown in its help); a command whose \
                  result is printed writes a file only when -o is given."
)]
pub struct Cli {
    /// Quiet: only warnings and errors on stderr (no progress, no notes, no list of files
    /// written); results still go to stdout.
    #[arg(short, long, global = true, conflicts_with = "verbose")]
    pub quiet: bool,
    /// More detail on stderr: -v debug, -vv trace. Without -q/-v, RUST_LOG is honoured
    /// (e.g. RUST_LOG=warn, or RUST_LOG=palpate_diagnose=debug).
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    pub verbose: u8,
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// The whole loop on the bundled data: fit, diagnose, export, haptic replay over a pty.
    Demo(demo::Args),
    /// Import a motion capture (C3D) as a motion dataset, or a scan (depth frame, point cloud).
    #[command(subcommand)]
    Import(import::ImportCommand),
    /// Simulate one static interaction with the runtime; writes displacements CSV and VTK.
    Simulate(simulate::Args),
    /// Fit material parameters to a static contact dataset and export a model.
    Fit(fit::Args),
    /// Fit an FSR calibration (balance readings or datasheet points) and write the probe's calibration.
    CalibrateFsr(calibrate_fsr::Args),
    /// Read the probe's force stream live, record it to CSV, report the link's counters.
    Probe(probe::Args),
    /// Run the probe firmware library on the host behind a simulated ADC, streaming a scripted force.
    ProbeSim(probe_sim::Args),
    /// Drive the runtime with the live force stream (force-driven contact) and report latency.
    Haptic(haptic::Args),
    /// Fit visco-elastic parameters to a motion dataset (Real2Sim).
    FitMotion(fit_motion::Args),
    /// Export a fitted material as a runtime model for any object of it, matched to the material.
    Export(export::Args),
    /// Fit Young's modulus to scans of an object hanging, held or twisted (a scan dataset); find a second material.
    FitScan(fit_scan::Args),
    /// What a model, a fitted motion model or a dataset is and where it came from.
    Info(info::Args),
    /// Predict a motion dataset from a fitted model without refitting; report the marker errors.
    Validate(validate::Args),
    /// Simulate a stand-in specimen with undeclared effects as a static dataset (+ truth.json).
    Specimen(specimen::Args),
    /// Trace a static dataset's residual to missing effects, adopt those that earn their place, report.
    Diagnose(diagnose::Args),
}

/// A command wrote its result but found things the user must know (a fit that stopped at its
/// iteration cap, elements at a parameter bound): `palpate` exits with status 2.
#[derive(Debug)]
pub struct WrittenWithWarnings(pub usize);

impl std::fmt::Display for WrittenWithWarnings {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the result was written with {} warning(s) (above and in the report)",
            self.0
        )
    }
}

impl std::error::Error for WrittenWithWarnings {}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    logging::init(cli.quiet, cli.verbose);
    match cli.command {
        Command::Demo(a) => demo::run(a),
        Command::Import(c) => import::run(c),
        Command::Simulate(a) => simulate::run(a),
        Command::Fit(a) => fit::run(a),
        Command::CalibrateFsr(a) => calibrate_fsr::run(a),
        Command::Probe(a) => probe::run(a),
        Command::ProbeSim(a) => probe_sim::run(a),
        Command::Haptic(a) => haptic::run(a),
        Command::FitMotion(a) => fit_motion::run(a),
        Command::Export(a) => export::run(a),
        Command::FitScan(a) => fit_scan::run(a),
        Command::Validate(a) => validate::run(a),
        Command::Info(a) => info::run(a),
        Command::Specimen(a) => specimen::run(a),
        Command::Diagnose(a) => diagnose::run(a),
    }
}
