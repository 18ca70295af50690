//! `palpate`: fit, diagnose, simulate and play back soft objects from contact measurements.
//!
//! A thin shell: every command parses its arguments and calls the library crates
//! (`ARCHITECTURE.md`). Benchmarks and evidence runs live in the lab tool (`palpate-lab`).
use clap::Parser;

mod cli;

fn main() {
    let cli = cli::Cli::parse();
    if let Err(e) = cli::run(cli) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
