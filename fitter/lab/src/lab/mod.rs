//! The lab tool's commands: one file per command, each with its `Args` and `run`.

use clap::{Parser, Subcommand};

pub mod beam_convergence;
pub mod beam_load_point;
pub mod bench;
pub mod bench_discretisation;
pub mod bench_fit;
pub mod bench_link;
pub mod bench_motion;
pub mod bench_motion_step;
pub mod bench_quadratic_motion;
pub mod bench_runtime;
pub mod diagnose_evidence;
pub mod m4_emu;
pub mod model_form;
pub mod motion_confusion;
pub mod motion_convergence;
pub mod motion_evidence;
pub mod motion_evidence_spline;
pub mod nonlinear_evidence;
pub mod peer_export;
pub mod reduced_basis;
pub mod roofline;
pub mod scan_confusion;
pub mod scan_strip;

/// palpate-lab: benchmarks and evidence runs of the palpate project.
#[derive(Debug, Parser)]
#[command(name = "palpate-lab", version, about, long_about = None)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Benchmarks that print a table and, as their last line, one JSON object.
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// Motion-fitter evidence runs (coarsening, recover, vhb, bimaterial) into docs/results/motion.
    MotionEvidence(motion_evidence::Args),
    /// Every specimen effect × seeds through diagnose: the confusion table (docs/results/diagnose/confusion).
    DiagnoseEvidence(diagnose_evidence::Args),
    /// Motion specimens with one effect each, drawn at random, through the motion diagnosis: the
    /// motion confusion table (docs/results/diagnose/confusion).
    MotionConfusion(motion_confusion::Args),
    /// The non-linear chain end to end (incremental loading, blends on non-linear data, the γ_m
    /// sweep) into docs/results/nonlinear.
    NonlinearEvidence(nonlinear_evidence::Args),
    /// Whether a static dataset's residual is the warped linear model's form: its (E, ν) fit
    /// against the Neo-Hookean quasi-static solver's best fit on the same mesh and loads.
    ModelForm(model_form::Args),
    /// The beam's shear modulus fitted to imported rest states with linear and quadratic
    /// tetrahedra on two meshes: how converged the fitted material is
    /// (docs/results/beam/convergence.md).
    BeamConvergence(beam_convergence::Args),
    /// Where a hanging weight acts: the beam's modulus fitted to its rest states with each loaded
    /// run's force moved to a point off its nodes (a hook's lever), per run and jointly.
    BeamLoadPoint(beam_load_point::Args),
    /// The runtime and probe firmware on an emulated Cortex-M4F: the bundled models, the
    /// comparison with the host and the board's cost model (firmware/m4-emu).
    M4Emu(m4_emu::Args),
    /// A hanging strip's modulus fitted to one rendered depth image (the scan residual end to
    /// end) with linear or quadratic tetrahedra, against truths on its own mesh and on a finer one.
    ScanStrip(scan_strip::Args),
    /// The scan diagnosis on strips with one undeclared effect each (a depth bias, a camera
    /// moved, a second material, or none): what it adopts, before and after.
    ScanConfusion(scan_confusion::Args),
    /// How well a small subspace (vibration modes, with static load shapes, or the run's own
    /// principal components) holds a motion run: the first gate of a reduced-order motion model.
    ReducedBasis(reduced_basis::Args),
    /// The motion's modulus and viscosity fitted on linear and quadratic tetrahedra on several
    /// meshes of one object, by one method: how converged a fitted material is
    /// (docs/results/beam/convergence.md).
    MotionConvergence(motion_convergence::Args),
}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Bench(b) => bench::run(b),
        Command::MotionEvidence(a) => motion_evidence::run(a),
        Command::DiagnoseEvidence(a) => diagnose_evidence::run(a),
        Command::MotionConfusion(a) => motion_confusion::run(a),
        Command::NonlinearEvidence(a) => nonlinear_evidence::run(a),
        Command::ModelForm(a) => model_form::run(a),
        Command::BeamConvergence(a) => beam_convergence::run(a),
        Command::BeamLoadPoint(a) => beam_load_point::run(a),
        Command::M4Emu(a) => m4_emu::run(a),
        Command::ScanStrip(a) => scan_strip::run(a),
        Command::ScanConfusion(a) => scan_confusion::run(a),
        Command::ReducedBasis(a) => reduced_basis::run(a),
        Command::MotionConvergence(a) => motion_convergence::run(a),
    }
}
