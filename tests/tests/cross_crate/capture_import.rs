//! A real capture (the silicone beam, Qualisys C3D) imported as a motion dataset and read back by
//! the motion fitter's reader: registered to the mesh frame on the held frame, trajectories from
//! the detected release, the tip sagging along the declared gravity.

use palpate_capture::import::{import_motion_dataset, ImportOptions};
use std::path::Path;

fn beam() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/silicone-beam")
}

#[test]
fn beam_capture_imports_as_a_motion_dataset() {
    let capture = palpate_capture::read_c3d(&beam().join("beam_gravity_V2_a.c3d")).unwrap();
    let text = std::fs::read_to_string(beam().join("marker-places.csv")).unwrap();
    let places: Vec<(String, [f64; 3])> = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("marker,"))
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (
                f[0].to_string(),
                [
                    f[1].parse().unwrap(),
                    f[2].parse().unwrap(),
                    f[3].parse().unwrap(),
                ],
            )
        })
        .collect();
    let ids: Vec<usize> = places
        .iter()
        .map(|(l, _)| capture.marker(l).unwrap())
        .collect();
    let release = capture.release_frame(&ids, 0.5e-3).unwrap() - 1;
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(beam().join("beam.msh"), dir.path().join("mesh.msh")).unwrap();
    let r = import_motion_dataset(
        &capture,
        &ImportOptions {
            places,
            rest_frame: 0,
            release_frame: release,
            last_frame: None,
            toml: "mesh = \"mesh.msh\"\nclamps = [\"clamp\"]\ngravity = [-9.81, 0.0, 0.0]\ndensity = 1070.0".into(),
        },
        dir.path(),
    )
    .unwrap();
    // The declared places are the authors' (rounded, on stand-offs): millimetre residuals.
    assert!(
        r.transform.rms() < 1.5e-3,
        "registration RMS {} m",
        r.transform.rms()
    );
    let ds = palpate_motion::dataset::load(dir.path()).unwrap();
    assert_eq!(ds.model.steps, 500 - 1 - release);
    assert_eq!(ds.model.markers.len(), 6);
    assert!(ds
        .obs
        .markers
        .iter()
        .all(|row| row.iter().all(|m| m.is_some())));
    assert!(
        !ds.model.static_start,
        "the held beam is released from its rest shape"
    );
    // The tip ends lower along −x (gravity) by about the README's 6.4 mm sag.
    let tip = ds
        .model
        .markers
        .iter()
        .position(|m| m.name == "Tip - 1")
        .unwrap();
    let first = ds.obs.markers[0][tip].unwrap();
    let last = ds.obs.markers.last().unwrap()[tip].unwrap();
    let sag = first[0] - last[0];
    assert!(sag > 4e-3 && sag < 8e-3, "tip sag along gravity {sag} m");
}
