//! What the `palpate` program's test modules share: the program, the repository root, the check
//! that a fit was written, and the bundled data copied or imported as the README does.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

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

/// The commands `palpate --help` lists (without `help`).
pub fn commands() -> Vec<String> {
    let top = text(&palpate().arg("--help").output().unwrap().stdout);
    top.lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.split_whitespace().next().map(String::from))
        .filter(|c| c != "help")
        .collect()
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

/// Asserts that the program exited 0, its stderr shown if not.
#[track_caller]
pub fn assert_succeeded(o: &Output) {
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stderr));
}

/// Asserts that the program exited with `code` and said `part` on stderr (shown if not).
#[track_caller]
pub fn assert_exit_and_stderr(o: &Output, code: i32, part: &str) {
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(code), "{err}");
    assert!(err.contains(part), "{err}");
}

/// Asserts that the program failed (any status but 0) and returns its stderr, for the caller to
/// check that it names what was wrong.
#[track_caller]
pub fn refused(o: &Output) -> String {
    let err = text(&o.stderr);
    assert_ne!(o.status.code(), Some(0), "{err}");
    err
}

/// The last line the program wrote to stdout, as JSON (its stdout and stderr shown if that is
/// not JSON).
pub fn last_json(o: &Output) -> serde_json::Value {
    let out = text(&o.stdout);
    let line = out.lines().last().unwrap_or_default();
    serde_json::from_str(line).unwrap_or_else(|e| panic!("{e}: {out}{}", text(&o.stderr)))
}

/// Runs `cmd` with its stdout and stderr captured, killing it after `secs`: a hang is a failure
/// that names the command and shows its stderr, not a stuck test run. Both pipes are drained
/// while it runs, so a program that writes a lot cannot block on a full pipe and pass for a hang.
pub fn run_within(mut cmd: Command, secs: u64) -> Output {
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let drain = |mut pipe: Box<dyn Read + Send>| {
        std::thread::spawn(move || {
            let mut bytes = Vec::new();
            let _ = pipe.read_to_end(&mut bytes);
            bytes
        })
    };
    let stdout = drain(Box::new(child.stdout.take().unwrap()));
    let stderr = drain(Box::new(child.stderr.take().unwrap()));
    let t0 = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if t0.elapsed() > Duration::from_secs(secs) {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "still running after {secs} s: {:?}\nstderr: {}",
                cmd.get_args().collect::<Vec<_>>(),
                text(&stderr.join().unwrap())
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    Output {
        status,
        stdout: stdout.join().unwrap(),
        stderr: stderr.join().unwrap(),
    }
}

/// Copies the files (not the subfolders) of `src` into `dst`, made if needed.
pub fn copy_dir(src: &Path, dst: &Path) {
    std::fs::create_dir_all(dst).unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let e = e.unwrap();
        if e.path().is_file() {
            std::fs::copy(e.path(), dst.join(e.file_name())).unwrap();
        }
    }
}

/// `palpate import c3d` of the bundled beam capture `capture` (e.g. `beam_gravity_V2_a.c3d`)
/// onto the coarse beam mesh, as the README does it (the bundled places, clamps, gravity,
/// density); the caller adds the output and any other flag.
pub fn import_beam(capture: &str) -> Command {
    import_beam_with_places(
        capture,
        &repo().join("models/silicone-beam/marker-places.csv"),
    )
}

/// [`import_beam`] with the marker places of `places`.
pub fn import_beam_with_places(capture: &str, places: &Path) -> Command {
    let beam = repo().join("models/silicone-beam");
    let mut c = palpate();
    c.args(["import", "c3d"])
        .arg(beam.join(capture))
        .arg("--mesh")
        .arg(beam.join("beam-coarse.msh"))
        .arg("--places")
        .arg(places)
        .args([
            "--clamps",
            "clamp",
            "--gravity=-9.81,0,0",
            "--density",
            "1070",
        ]);
    c
}
