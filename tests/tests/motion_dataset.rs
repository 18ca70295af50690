//! The motion dataset reader on the bundled example and on broken copies of it.

use palpate_motion::dataset::load;
use std::path::Path;

fn example() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/motion-example")
}

#[test]
fn example_dataset_loads_with_all_observations() {
    let ds = load(&example()).unwrap();
    assert_eq!(ds.model.tets.len(), 24);
    assert_eq!(ds.model.steps, 45);
    assert_eq!(ds.model.markers.len(), 9);
    assert!(ds
        .obs
        .markers
        .iter()
        .all(|row| row.iter().all(|m| m.is_some())));
    // The clamp pose at t = 0.1 s is the two-sinusoid motion (written with 9 decimals).
    let p = ds.model.clamps[0].poses[18].t;
    let t: f64 = 18.0 / 180.0;
    let want = 0.015 * (1.0 - (6.0 * std::f64::consts::PI * t).cos());
    assert!((p[0] - want).abs() < 1e-9);
}

fn broken(edit: impl Fn(&Path)) -> String {
    let dir = tempfile::tempdir().unwrap();
    for f in [
        "dataset.toml",
        "mesh.msh",
        "markers.csv",
        "trajectories.csv",
        "clamps.csv",
    ] {
        std::fs::copy(example().join(f), dir.path().join(f)).unwrap();
    }
    edit(dir.path());
    load(dir.path()).unwrap_err().to_string()
}

#[test]
fn errors_name_file_line_and_field() {
    let e = broken(|d| {
        let t = std::fs::read_to_string(d.join("trajectories.csv")).unwrap();
        let mut lines: Vec<String> = t.lines().map(String::from).collect();
        lines[3] = lines[3].replacen(",m", ",nosuch", 1);
        std::fs::write(d.join("trajectories.csv"), lines.join("\n")).unwrap();
    });
    assert!(
        e.contains("trajectories.csv:4") && e.contains("marker") && e.contains("nosuch"),
        "{e}"
    );
    let e = broken(|d| {
        let t = std::fs::read_to_string(d.join("clamps.csv")).unwrap();
        std::fs::write(
            d.join("clamps.csv"),
            t.replacen("0.005556,front,", "0.005556,front,abc", 1),
        )
        .unwrap();
    });
    assert!(e.contains("clamps.csv:3") && e.contains("field ux"), "{e}");
    let e = broken(|d| {
        let t = std::fs::read_to_string(d.join("trajectories.csv")).unwrap();
        std::fs::write(
            d.join("trajectories.csv"),
            t.replacen("0.005556,", "0.0071,", 1),
        )
        .unwrap();
    });
    assert!(e.contains("not on the step grid"), "{e}");
    let e = broken(|d| {
        let t = std::fs::read_to_string(d.join("dataset.toml")).unwrap();
        std::fs::write(
            d.join("dataset.toml"),
            t.replace("clamps = [\"front\"]", "clamps = [\"base\"]"),
        )
        .unwrap();
    });
    assert!(e.contains("dataset.toml") && e.contains("base"), "{e}");
}
