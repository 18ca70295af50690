//! What a diagnosis request hands back per input: the lines `palpate diagnose` prints and the
//! files written. Every room's `run.rs` makes one.

use std::path::PathBuf;

/// What one diagnosed input hands back: the summary lines the command prints (one per input, and
/// for a static dataset the magnitudes it would have detected) and the files written.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Summary {
    /// The lines of the summary, without line ends.
    pub lines: Vec<String>,
    /// The report files and the model written.
    pub files: Vec<PathBuf>,
}

impl std::fmt::Display for Summary {
    /// The summary lines, each ended by a newline (what the command prints).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.lines.iter().try_for_each(|l| writeln!(f, "{l}"))
    }
}
