//! What the `palpate` program's test files share: the program, the repository root, and the
//! check that a fit was written.

// Each test file uses its own part of this module.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The `palpate` program this package builds.
pub fn palpate() -> Command {
    Command::new(env!("CARGO_BIN_EXE_palpate"))
}

/// The repository root (the bundled models are under `models/`).
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Runs `palpate <before…> fit <the bundled sponge dataset> <options…> -o <model>`.
pub fn fit_sponge(before: &[&str], options: &[&str], model: &Path) -> Output {
    palpate()
        .args(before)
        .arg("fit")
        .arg(repo().join("models/sponge/dataset"))
        .args(options)
        .arg("-o")
        .arg(model)
        .output()
        .unwrap()
}

/// Bytes a program wrote, as text.
pub fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).to_string()
}

/// Asserts that a fit was written: exit status 0, or 2 when it stopped at its iteration cap
/// (written, with the warning); its stderr shown if not.
#[track_caller]
pub fn assert_fit_written(o: &Output) {
    assert!(
        matches!(o.status.code(), Some(0 | 2)),
        "{}",
        text(&o.stderr)
    );
}
