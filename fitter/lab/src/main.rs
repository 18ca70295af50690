//! `palpate-lab`: the project's lab tool — benchmarks that print a table and, as their last line,
//! one JSON object (figures in BENCHMARKS.md with their commands), and the evidence runs whose
//! tables and figures live in `docs/results/`. Not part of the user's `palpate` command list.
use clap::Parser;

mod lab;

fn main() {
    let cli = lab::Cli::parse();
    if let Err(e) = lab::run(cli) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
