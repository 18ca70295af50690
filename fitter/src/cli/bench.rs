//! `palpate bench …`: benchmark subcommands (figures go to BENCHMARKS.md with their commands).

use clap::Subcommand;

/// Which benchmark to run.
#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// The haptic tick (runtime) on a generated block, against a per-tick sparse direct solve.
    Runtime(super::bench_runtime::Args),
}

/// Runs a benchmark.
pub fn run(cmd: BenchCommand) -> anyhow::Result<()> {
    match cmd {
        BenchCommand::Runtime(a) => super::bench_runtime::run(a),
    }
}
