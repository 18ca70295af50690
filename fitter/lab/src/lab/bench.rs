//! `palpate-lab bench …`: benchmark subcommands (figures go to BENCHMARKS.md with their commands).

use clap::Subcommand;

/// Which benchmark to run.
#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Displacement-based non-linear inhomogeneous static fit (adjoint Jacobians) vs finite differences.
    Fit(super::bench_fit::Args),
    /// The haptic tick (runtime) on a generated block, against a per-tick sparse direct solve.
    Runtime(super::bench_runtime::Args),
    /// Motion fitting (Real2Sim) on the MyFEM anchor bar: simulation, gradients, LBFGS.
    Motion(super::bench_motion::Args),
    /// The motion integrators (BDF2, implicit midpoint) on a captured run: steps, Newton work,
    /// CPU time, marker error against the capture and a converged reference.
    MotionSchemes(super::bench_motion::SchemesArgs),
    /// A time step with sensitivities on a captured run: faer's Cholesky variants on its S, the
    /// gradient with fresh factorisations against kept-factor CG at looser tolerances, whole fits.
    MotionStep(super::bench_motion_step::Args),
    /// One simulation on quadratic tetrahedra (the motion's mesh-convergence refit's forward
    /// model) on a captured run: wall and CPU time of whole runs, Newton iterations,
    /// factorisations.
    QuadraticMotion(super::bench_quadratic_motion::Args),
    /// The probe link over a pty: frames/s, written → solved latency at 1 kHz, host CPU.
    Link(super::bench_link::Args),
    /// This core's f32 FMA peak and read bandwidth by working set, against the flops and bytes of
    /// one PCG iteration of the tick on `bench runtime`'s block.
    Roofline(super::roofline::Args),
    /// The end-loaded cantilever with linear, quadratic and average-nodal-pressure tetrahedra at
    /// ν up to 0.499: tip error per mesh against a converged reference and Timoshenko, solve cost.
    Discretisation(super::bench_discretisation::Args),
}

/// Runs a benchmark.
pub fn run(cmd: BenchCommand) -> anyhow::Result<()> {
    match cmd {
        BenchCommand::Fit(a) => super::bench_fit::run(a),
        BenchCommand::Runtime(a) => super::bench_runtime::run(a),
        BenchCommand::Motion(a) => super::bench_motion::run(a),
        BenchCommand::MotionSchemes(a) => super::bench_motion::run_schemes(a),
        BenchCommand::MotionStep(a) => super::bench_motion_step::run(a),
        BenchCommand::QuadraticMotion(a) => super::bench_quadratic_motion::run(a),
        BenchCommand::Link(a) => super::bench_link::run(a),
        BenchCommand::Roofline(a) => super::roofline::run(a),
        BenchCommand::Discretisation(a) => super::bench_discretisation::run(a),
    }
}
