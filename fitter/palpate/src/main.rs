//! `palpate`: fit, diagnose, simulate and play back soft objects from contact measurements.
//!
//! A thin shell: every command parses its arguments and calls the library crates
//! (`ARCHITECTURE.md`). Benchmarks and evidence runs live in the lab tool (`palpate-lab`).
use clap::Parser;

mod cli;

fn main() {
    restore_sigpipe();
    let cli = cli::Cli::parse();
    // Exit status: 0 a clean result, 1 an error (nothing written), 2 a result written with
    // warnings the user must read.
    if let Err(e) = cli::run(cli) {
        if let Some(w) = e.downcast_ref::<cli::WrittenWithWarnings>() {
            eprintln!("warning: {w}");
            std::process::exit(2);
        }
        eprintln!("error: {}", chain_message(&e));
        std::process::exit(1);
    }
}

/// The error and its causes joined by ": ", leaving out a cause whose text the message already
/// holds (library errors that name their cause in their own message, as the dataset readers'
/// do, would otherwise print it twice).
fn chain_message(e: &anyhow::Error) -> String {
    let mut msg = e.to_string();
    for cause in e.chain().skip(1) {
        let c = cause.to_string();
        if !msg.contains(&c) {
            msg.push_str(": ");
            msg.push_str(&c);
        }
    }
    msg
}

/// A reader that stops early (`palpate info x | head`) closes the pipe; a Unix filter then ends
/// quietly on SIGPIPE. Rust starts programs with SIGPIPE ignored, so every later `println!` would
/// panic on the broken pipe instead: the default disposition is restored before anything is
/// printed. The binary's one `unsafe`: `signal` with a constant handler has no precondition to
/// break.
#[cfg(unix)]
#[allow(unsafe_code)]
fn restore_sigpipe() {
    // SAFETY: SIG_DFL is a valid disposition for SIGPIPE; no handler code runs.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

#[cfg(not(unix))]
fn restore_sigpipe() {}
