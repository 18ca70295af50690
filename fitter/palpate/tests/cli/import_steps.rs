//! `palpate import c3d` and `palpate info` on the dataset it wrote say the same thing about its
//! length in time: the capture intervals and `dt` that `dataset.toml` and `trajectories.csv`
//! hold, and, where the simulation takes several steps per interval, those too.

use crate::common;

use common::{assert_succeeded, palpate, text};

/// The bundled beam capture (100 Hz, 500 frames) imported as the README does, with `-v` so the
/// import's note is on stderr; then `palpate info` on the result. The reference is the dataset's
/// own files: `dt` from `dataset.toml` and the last time in `trajectories.csv`, whose ratio is the
/// number of capture intervals (frames after the release).
#[test]
fn import_and_info_count_the_same_steps_of_the_same_dt() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("beam");
    let import = common::import_beam("beam_gravity_V2_a.c3d")
        .arg("-v")
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    assert_succeeded(&import);
    let toml = std::fs::read_to_string(out.join("dataset.toml")).unwrap();
    let dt: f64 = toml
        .lines()
        .find_map(|l| l.strip_prefix("dt = "))
        .expect("dt in dataset.toml")
        .parse()
        .unwrap();
    let trajectories = std::fs::read_to_string(out.join("trajectories.csv")).unwrap();
    let last_t: f64 = trajectories
        .lines()
        .last()
        .and_then(|l| l.split(',').next())
        .unwrap()
        .parse()
        .unwrap();
    let intervals = (last_t / dt).round() as usize;
    // 500 frames at 100 Hz, the release detected at frame 71 (models/silicone-beam/README.md).
    assert_eq!((dt, intervals), (0.01, 428));
    let said = format!("{intervals} steps of {dt} s");
    let err = text(&import.stderr);
    assert!(err.contains(&said), "import says: {err}");
    let info = palpate().arg("info").arg(&out).output().unwrap();
    assert_succeeded(&info);
    let stdout = text(&info.stdout);
    assert!(stdout.contains(&said), "info says: {stdout}");
    let doc = common::last_json(&info);
    assert_eq!(doc["steps"].as_u64(), Some(intervals as u64), "{doc}");
    assert_eq!(doc["dt_s"].as_f64(), Some(dt), "{doc}");
}
