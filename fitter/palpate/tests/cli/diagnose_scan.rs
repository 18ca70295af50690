//! `palpate diagnose` on a scan dataset, as a user runs it: a strip whose depth frames read 0.6 mm
//! too far (a sensor's bias `scans.toml` does not declare), diagnosed into a report with the bias
//! named and measured, the residual drawn on each state's surface before and after; and a
//! candidate of another room refused naming the scan room's library.

use palpate_scan::fit::Design;
use palpate_scan::synthetic::{write_strip_dataset, Injected, StripCase};

use crate::common::{assert_succeeded, palpate, refused, text};

#[test]
fn a_depth_bias_is_named_in_the_report_with_the_residual_before_and_after() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("strip");
    let case = StripCase {
        design: Design::Linear,
        injected: Injected::DepthBias(0.6e-3),
        ..StripCase::default()
    };
    write_strip_dataset(&dir, &case).unwrap();
    let out = tmp.path().join("report");
    let o = palpate()
        .arg("diagnose")
        .arg(&dir)
        // The truth is the dataset's own mesh and design: no mesh error to correct.
        .args(["--design", "p1", "--mesh", "dataset"])
        // A depth scale is not told apart from a bias seen from one distance: left out, so
        // that the bias is the one measured.
        .args([
            "--candidates",
            "second-material,camera-moved,depth-bias",
            "-o",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert_succeeded(&o);
    let line = text(&o.stdout);
    assert!(line.contains("adopted depth-bias; explained"), "{line}");
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("diagnosis.json")).unwrap())
            .unwrap();
    assert_eq!(j["kind"], "scan diagnosis");
    assert_eq!(j["adopted"], serde_json::json!(["depth-bias"]));
    let b = j["after"]["depth_bias_m"].as_f64().unwrap();
    assert!((b - 0.6e-3).abs() < 0.05e-3, "bias {b}");
    assert!(j["mesh_error"].is_null());
    assert!(text(&o.stdout).contains("E "));
    let md = std::fs::read_to_string(out.join("diagnosis.md")).unwrap();
    assert!(md.contains("depth-bias **adopted**"), "{md}");
    assert!(md.contains("was not measured (`--mesh dataset`)"), "{md}");
    for state in ["hanging", "twisted"] {
        for vtu in ["points", "surface"] {
            let f = out.join(format!("{state}-{vtu}.vtu"));
            assert!(f.is_file(), "{} missing", f.display());
        }
        for when in ["before", "after"] {
            for ext in ["svg", "png"] {
                let f = out.join(format!("{state}-residual-{when}.{ext}"));
                assert!(f.is_file(), "{} missing", f.display());
            }
        }
    }
}

#[test]
fn a_candidate_of_another_room_is_refused_with_the_scan_library() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("strip");
    let case = StripCase {
        cells: [4, 1, 1],
        design: Design::Linear,
        ..StripCase::default()
    };
    write_strip_dataset(&dir, &case).unwrap();
    let o = palpate()
        .arg("diagnose")
        .arg(&dir)
        .args(["--candidates", "viscosity", "-o"])
        .arg(tmp.path().join("out"))
        .output()
        .unwrap();
    let err = refused(&o);
    assert!(
        err.contains("unknown scan candidate \"viscosity\"")
            && err.contains("second-material")
            && err.contains("depth-bias"),
        "{err}"
    );
    assert!(!tmp.path().join("out").join("diagnosis.json").exists());
}
