//! `palpate`: fit, diagnose, simulate and play back soft objects from contact measurements.
//!
//! A thin shell: every command parses its arguments and calls the library crates
//! (`ARCHITECTURE.md`). Benchmarks and evidence runs live in the lab tool (`palpate-lab`).
use clap::Parser;

mod cli;

fn main() {
    let cli = cli::Cli::parse();
    // Exit status: 0 a clean result, 1 an error (nothing written), 2 a result written with
    // warnings the user must read.
    if let Err(e) = cli::run(cli) {
        if let Some(w) = e.downcast_ref::<cli::WrittenWithWarnings>() {
            eprintln!("warning: {w}");
            std::process::exit(2);
        }
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
