//! `palpate`: fit, diagnose, simulate and play back soft objects from contact measurements.
use clap::Parser;

fn main() {
    let cli = palpate_fitter::cli::Cli::parse();
    if let Err(e) = palpate_fitter::cli::run(cli) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
