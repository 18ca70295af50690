//! `palpate-lab`: the project's lab tool — benchmarks that print a table and, as their last line,
//! one JSON object (figures in BENCHMARKS.md with their commands), and the evidence runs whose
//! tables and figures live in `docs/results/`. Not part of the user's `palpate` command list.
use clap::Parser;

mod lab;

fn main() {
    // The libraries' progress and notes (the `log` facade) on stderr, `info` unless RUST_LOG says
    // otherwise; tables and the last JSON line stay on stdout.
    env_logger::Builder::new()
        .filter_level(log::LevelFilter::Info)
        .parse_default_env()
        .format(|buf, r| {
            use std::io::Write as _;
            writeln!(buf, "{}", r.args())
        })
        .init();
    let cli = lab::Cli::parse();
    if let Err(e) = lab::run(cli) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
