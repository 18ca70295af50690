//! Where palpate's messages go: results the user asked for (tables, summaries, the last JSON line)
//! are printed on stdout by each command; everything else — progress, notes, the files written,
//! warnings — goes through the `log` facade to stderr, so `palpate … > result.txt` keeps only the
//! result and `-q` keeps only what must be read.
//!
//! Levels: default `info` (progress and notes); `-q` warnings and errors only; `-v` adds `debug`,
//! `-vv` `trace`. Without `-q`/`-v`, `RUST_LOG` is honoured (`RUST_LOG=warn`,
//! `RUST_LOG=palpate_diagnose=debug`, …, on top of the `info` default); with them, the flag wins.
//!
//! Long commands show a [`Progress`] line (elapsed time, the stage, and i/n with an ETA where a
//! count is known) under the messages; it is hidden under `-q` and when stderr is not a terminal,
//! so a log file holds the messages and no cursor control codes.

use std::io::{IsTerminal as _, Write as _};
use std::sync::Mutex;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
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
    let inner = b.build();
    let max = inner.filter();
    if log::set_boxed_logger(Box::new(BarAwareLogger(inner))).is_ok() {
        log::set_max_level(max);
    }
}

/// The progress line on screen, if any: messages are printed above it rather than through it.
static ACTIVE: Mutex<Option<ProgressBar>> = Mutex::new(None);

/// env_logger's filtering and format, printed around the active progress line; each
/// info-level message that names a diagnosis round also moves that line on.
struct BarAwareLogger(env_logger::Logger);

impl log::Log for BarAwareLogger {
    fn enabled(&self, metadata: &log::Metadata) -> bool {
        self.0.enabled(metadata)
    }

    fn log(&self, record: &log::Record) {
        if !self.0.matches(record) {
            return;
        }
        // The bar is cloned out so that the lock is not held while printing.
        let active = ACTIVE.lock().ok().and_then(|a| a.clone());
        match active {
            Some(bar) => {
                if record.level() == Level::Info {
                    show_stage(&bar, &Stage::from_line(&record.args().to_string()));
                }
                bar.suspend(|| self.0.log(record));
            }
            None => self.0.log(record),
        }
    }

    fn flush(&self) {
        self.0.flush()
    }
}

/// Where a long command is: the round of a diagnosis and, when known, the step out of how many
/// (the candidate being fitted in a round, the part of the demo).
///
/// Today the diagnosis reports its stages as log lines, and [`Stage::from_line`] reads the round
/// from them; a structured progress event of the diagnosis (round, candidate i of n) maps onto
/// this type (its candidate i of n as `step`) and is shown with [`Progress::stage`], which then draws i/n and an
/// ETA.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Stage {
    /// The diagnosis round (1 = the first candidates tried on the simplest model).
    pub round: Option<usize>,
    /// The step and how many there are (1-based).
    pub step: Option<(u64, u64)>,
    /// The stage in words.
    pub text: String,
}

impl Stage {
    /// The stage a library's log line names: `round 2: trying stiffening` gives round 2.
    pub fn from_line(line: &str) -> Self {
        let text = line.trim();
        let round = text
            .strip_prefix("round ")
            .map(|r| {
                r.chars()
                    .take_while(char::is_ascii_digit)
                    .collect::<String>()
            })
            .and_then(|d| d.parse().ok());
        Self {
            round,
            step: None,
            text: text.chars().take(70).collect(),
        }
    }
}

/// Moves `bar` to `stage`: the count and ETA when the step is known, else the words only.
fn show_stage(bar: &ProgressBar, stage: &Stage) {
    if let Some((i, n)) = stage.step {
        if bar.length() != Some(n) {
            bar.set_length(n);
            bar.reset_eta();
            bar.set_style(counted_style());
        }
        bar.set_position(i.saturating_sub(1));
    }
    bar.set_message(stage.text.clone());
}

fn counted_style() -> ProgressStyle {
    ProgressStyle::with_template("{spinner} [{elapsed_precise}] {pos}/{len} ETA {eta} {wide_msg}")
        .expect("the template's keys are indicatif's")
}

/// A progress line for a command that can take more than a few seconds: a spinner with the
/// elapsed time and the current stage (the last message logged), i/n and an ETA once a count is
/// known. Messages logged while it lives are printed above it; dropping it clears it.
pub struct Progress {
    bar: ProgressBar,
}

impl Progress {
    /// Starts the line with `what` as its first stage.
    pub fn start(what: &str) -> Self {
        let bar = bar(None);
        bar.set_style(
            ProgressStyle::with_template("{spinner} [{elapsed_precise}] {wide_msg}")
                .expect("the template's keys are indicatif's"),
        );
        bar.set_message(what.to_string());
        // The spinner and clock move between messages too: a round can take minutes.
        bar.enable_steady_tick(Duration::from_millis(200));
        if let Ok(mut a) = ACTIVE.lock() {
            *a = Some(bar.clone());
        }
        Self { bar }
    }

    /// Runs `f` (which prints on stdout) with the line cleared, and draws it again after.
    pub fn suspend<R>(&self, f: impl FnOnce() -> R) -> R {
        self.bar.suspend(f)
    }

    /// Shows a stage reported other than by a log line.
    pub fn stage(&self, stage: &Stage) {
        show_stage(&self.bar, stage);
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        if let Ok(mut a) = ACTIVE.lock() {
            *a = None;
        }
        self.bar.finish_and_clear();
    }
}

/// Whether progress (info-level messages, progress bars) is shown.
pub fn progress_shown() -> bool {
    log::log_enabled!(Level::Info)
}

/// A progress bar on stderr that `-q` (or `RUST_LOG=warn`) hides, and that is not drawn when
/// stderr is not a terminal (a log file or a pipe gets no cursor control codes).
pub fn bar(len: Option<u64>) -> ProgressBar {
    let bar = match len {
        Some(n) => ProgressBar::new(n),
        None => ProgressBar::new_spinner(),
    };
    if !progress_shown() || !std::io::stderr().is_terminal() {
        bar.set_draw_target(ProgressDrawTarget::hidden());
    }
    bar
}
