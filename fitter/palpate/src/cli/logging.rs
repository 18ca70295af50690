//! Where palpate's messages go: results the user asked for (tables, summaries, the last JSON line)
//! are printed on stdout by each command; everything else — progress, notes, the files written,
//! warnings — goes through the `log` facade to stderr, so `palpate … > result.txt` keeps only the
//! result and `-q` keeps only what must be read.
//!
//! Levels: default `info` (progress and notes); `-q` warnings and errors only; `-v` adds `debug`,
//! `-vv` `trace`. Without `-q`/`-v`, `RUST_LOG` is honoured (`RUST_LOG=warn`,
//! `RUST_LOG=palpate_diagnose=debug`, …, on top of the `info` default); with them, the flag wins.

use std::io::Write as _;

use log::{Level, LevelFilter};

/// The level `-q`/`-v` ask for, `None` when neither was given.
pub fn flag_level(quiet: bool, verbose: u8) -> Option<LevelFilter> {
    match (quiet, verbose) {
        (true, _) => Some(LevelFilter::Warn),
        (false, 0) => None,
        (false, 1) => Some(LevelFilter::Debug),
        (false, _) => Some(LevelFilter::Trace),
    }
}

/// Installs the logger for the whole process (once; a second call does nothing).
pub fn init(quiet: bool, verbose: u8) {
    let mut b = env_logger::Builder::new();
    b.filter_level(LevelFilter::Info);
    match flag_level(quiet, verbose) {
        Some(level) => {
            b.filter_level(level);
        }
        None => {
            if let Ok(spec) = std::env::var("RUST_LOG") {
                b.parse_filters(&spec);
            }
        }
    }
    b.target(env_logger::Target::Stderr);
    b.format(|buf, record| {
        let text = record.args().to_string();
        match record.level() {
            // Messages that already say what they are ("warning [code]: …" of the sanity
            // gates) are not prefixed twice.
            Level::Error if !text.starts_with("error") => writeln!(buf, "error: {text}"),
            Level::Warn if !text.starts_with("warning") => writeln!(buf, "warning: {text}"),
            Level::Error | Level::Warn | Level::Info => writeln!(buf, "{text}"),
            Level::Debug | Level::Trace => writeln!(
                buf,
                "{} [{}] {text}",
                record.level().as_str().to_lowercase(),
                record.target()
            ),
        }
    });
    let _ = b.try_init();
}

/// Whether progress (info-level messages, progress bars) is shown.
pub fn progress_shown() -> bool {
    log::log_enabled!(Level::Info)
}

/// A progress bar on stderr that `-q` (or `RUST_LOG=warn`) hides.
pub fn bar(len: Option<u64>) -> indicatif::ProgressBar {
    let bar = match len {
        Some(n) => indicatif::ProgressBar::new(n),
        None => indicatif::ProgressBar::new_spinner(),
    };
    if !progress_shown() {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    bar
}
