//! The progress line of long commands: drawn only on a terminal. Run with stderr piped (as in a
//! log file or CI), a command that shows one writes its messages and no cursor control codes.

use crate::common;

use common::{assert_succeeded, palpate, repo, text};

#[test]
fn without_a_terminal_diagnose_writes_messages_and_no_bar_control_codes() {
    let dir = tempfile::tempdir().unwrap();
    let o = palpate()
        .arg("diagnose")
        .arg(repo().join("models/motion-example"))
        .arg("-o")
        .arg(dir.path().join("d"))
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    assert_succeeded(&o);
    let err = text(&o.stderr);
    // The stages still reach the log, one per line.
    assert!(err.contains("round 1"), "{err}");
    assert!(
        !err.contains('\u{1b}') && !err.contains('\r'),
        "control codes on a stderr that is not a terminal: {err:?}"
    );
}
