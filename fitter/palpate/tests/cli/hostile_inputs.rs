//! The `palpate` program on hostile inputs as a new user gives them: corrupt captures, absurd
//! flags, data in other units, the wrong kind of file. Each must end promptly with a clear error
//! (no panic, no abort, no hang), write nothing, and destroy nothing that was there before.

use crate::common;

use common::{copy_dir, palpate, repo, run_within, text};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Asserts a clean refusal: exit status 1 (not a signal: no abort), no panic, and every one of
/// `parts` on stderr, which is returned.
#[track_caller]
fn refused_with(o: &Output, parts: &[&str]) -> String {
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "status {:?}: {err}", o.status);
    assert!(!err.contains("panicked"), "{err}");
    for p in parts {
        assert!(err.contains(p), "stderr lacks {p:?}: {err}");
    }
    err
}

fn cmd(args: &[&str]) -> Command {
    let mut c = palpate();
    c.args(args);
    c
}

/// A copy of the bundled beam capture with `patch` bytes written over it.
fn beam_c3d_with(dir: &Path, patch: &[(usize, u8)]) -> PathBuf {
    let mut b = std::fs::read(repo().join("models/silicone-beam/beam_gravity_V2_a.c3d")).unwrap();
    for &(i, v) in patch {
        b[i] = v;
    }
    let p = dir.join("a.c3d");
    std::fs::write(&p, b).unwrap();
    p
}

#[test]
fn a_c3d_whose_first_byte_is_zero_is_a_header_error_not_a_panic() {
    let tmp = tempfile::tempdir().unwrap();
    let c3d = beam_c3d_with(tmp.path(), &[(0, 0)]);
    let o = run_within(
        {
            let mut c = cmd(&["info"]);
            c.arg(&c3d);
            c
        },
        60,
    );
    refused_with(&o, &["a.c3d", "parameter section start"]);
    let o = run_within(import_beam(&c3d, &tmp.path().join("D"), &[]), 60);
    refused_with(&o, &["a.c3d", "parameter section start"]);
}

#[test]
fn a_c3d_whose_data_start_is_zero_is_a_header_error_not_a_panic() {
    let tmp = tempfile::tempdir().unwrap();
    let c3d = beam_c3d_with(tmp.path(), &[(16, 0), (17, 0)]);
    let mut c = cmd(&["info"]);
    c.arg(&c3d);
    refused_with(&run_within(c, 60), &["a.c3d", "data section start"]);
}

#[test]
fn a_block_of_a_hundred_billion_tets_is_refused_not_an_allocation_abort() {
    let o = run_within(
        cmd(&[
            "haptic",
            "--block-tets",
            "100000000000",
            "--port",
            "/dev/ttyNOSUCH0",
        ]),
        60,
    );
    refused_with(&o, &["--block-tets 100000000000", "1000000"]);
}

#[test]
fn a_billion_specimen_measurements_are_refused_before_any_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("s");
    let mut c = cmd(&["specimen", "--measurements", "1000000000", "-o"]);
    c.arg(&out);
    refused_with(&run_within(c, 60), &["--measurements 1000000000", "1000"]);
    assert!(!out.exists());
}

#[test]
fn an_inclusion_1e300_times_stiffer_returns_promptly() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("s");
    let mut c = cmd(&[
        "specimen",
        "--effect",
        "inclusion",
        "--magnitude",
        "1e300",
        "-o",
    ]);
    c.arg(&out);
    refused_with(&run_within(c, 120), &["--magnitude"]);
    assert!(!out.exists());
}

#[test]
fn ten_metres_of_noise_on_an_8_cm_block_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("s");
    let mut c = cmd(&["specimen", "--noise", "10", "-o"]);
    c.arg(&out);
    refused_with(&run_within(c, 60), &["--noise 10", "smallest side"]);
    assert!(!out.exists());
}

/// A copy of the bundled sponge specimen with each data row of `file` edited.
fn specimen_with(dir: &Path, file: &str, edit: impl Fn(Vec<String>) -> Vec<String>) -> PathBuf {
    let dst = dir.join("dataset");
    copy_dir(&repo().join("models/sponge-specimen"), &dst);
    let t = std::fs::read_to_string(dst.join(file)).unwrap();
    let mut out = Vec::new();
    for (i, line) in t.lines().enumerate() {
        if i == 0 || line.trim().is_empty() {
            out.push(line.to_string());
        } else {
            out.push(edit(line.split(',').map(String::from).collect()).join(","));
        }
    }
    std::fs::write(dst.join(file), out.join("\n") + "\n").unwrap();
    dst
}

/// `palpate fit` on `ds`: refused with `parts`, and no model written.
#[track_caller]
fn fit_refused_with(ds: &Path, parts: &[&str]) -> String {
    let model = ds.parent().unwrap().join("m.palp");
    let mut c = cmd(&["fit"]);
    c.arg(ds).arg("-o").arg(&model);
    let err = refused_with(&run_within(c, 300), parts);
    assert!(!model.exists(), "a model was written: {err}");
    err
}

fn scaled(f: Vec<String>, from: usize, k: f64) -> Vec<String> {
    f.into_iter()
        .enumerate()
        .map(|(i, v)| {
            if i >= from {
                (v.parse::<f64>().unwrap() * k).to_string()
            } else {
                v
            }
        })
        .collect()
}

#[test]
fn fit_refuses_measured_positions_in_millimetres() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = specimen_with(tmp.path(), "measurements.csv", |f| scaled(f, 2, 1e3));
    fit_refused_with(&ds, &["measurements.csv:2", "millimetres"]);
}

#[test]
fn fit_refuses_a_measured_coordinate_of_1e308() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = specimen_with(tmp.path(), "measurements.csv", |mut f| {
        if f[0] == "c3" && f[1] == "m5" {
            f[3] = "1e308".into();
        }
        f
    });
    fit_refused_with(&ds, &["measurements.csv:", "field `x,y,z`"]);
}

#[test]
fn fit_refuses_displacements_a_hundred_times_too_large() {
    let tmp = tempfile::tempdir().unwrap();
    let rest: std::collections::HashMap<String, Vec<f64>> =
        std::fs::read_to_string(repo().join("models/sponge-specimen/markers.csv"))
            .unwrap()
            .lines()
            .skip(1)
            .map(|l| {
                let f: Vec<&str> = l.split(',').collect();
                (
                    f[0].to_string(),
                    f[1..].iter().map(|v| v.parse().unwrap()).collect(),
                )
            })
            .collect();
    let ds = specimen_with(tmp.path(), "measurements.csv", move |mut f| {
        let r = &rest[&f[1]];
        for k in 0..3 {
            let v: f64 = f[2 + k].parse().unwrap();
            f[2 + k] = (r[k] + 100.0 * (v - r[k])).to_string();
        }
        f
    });
    fit_refused_with(&ds, &["measurements.csv:", "displacements scaled up"]);
}

#[test]
fn fit_refuses_a_contact_radius_of_1e308() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = specimen_with(tmp.path(), "contacts.csv", |mut f| {
        if f[0] == "c1" {
            f[7] = "1e308".into();
        }
        f
    });
    fit_refused_with(&ds, &["contacts.csv:3", "field `radius`"]);
}

/// A copy of the bundled motion example with `dataset.toml` edited by `edit`.
fn motion_with(dir: &Path, edit: impl Fn(String) -> String) -> PathBuf {
    let dst = dir.join("motion");
    copy_dir(&repo().join("models/motion-example"), &dst);
    let t = std::fs::read_to_string(dst.join("dataset.toml")).unwrap();
    std::fs::write(dst.join("dataset.toml"), edit(t)).unwrap();
    dst
}

#[track_caller]
fn fit_motion_refused_with(ds: &Path, parts: &[&str]) {
    let out = ds.parent().unwrap().join("fit.json");
    let mut c = cmd(&["fit-motion"]);
    c.arg(ds).arg("-o").arg(&out);
    let err = refused_with(&run_within(c, 300), parts);
    assert!(!out.exists(), "a fit was written: {err}");
}

#[test]
fn fit_motion_refuses_a_negative_or_zero_marker_weight() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = motion_with(tmp.path(), |t| {
        t.replace(
            "clamps = [\"front\"]",
            "clamps = [\"front\"]\nmarker_weight = -1.0",
        )
    });
    fit_motion_refused_with(&ds, &["dataset.toml", "marker_weight", "-1"]);
    let tmp = tempfile::tempdir().unwrap();
    let ds = motion_with(tmp.path(), |t| {
        t.replace(
            "clamps = [\"front\"]",
            "clamps = [\"front\"]\nmarker_weight = 0.0",
        )
    });
    fit_motion_refused_with(&ds, &["dataset.toml", "marker_weight", "nothing to match"]);
}

#[test]
fn fit_motion_refuses_a_zero_density_and_gravity_in_millimetres() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = motion_with(tmp.path(), |t| t.replace("density = 47.0", "density = 0.0"));
    fit_motion_refused_with(&ds, &["dataset.toml", "field density"]);
    let tmp = tempfile::tempdir().unwrap();
    let ds = motion_with(tmp.path(), |t| {
        t.replace("gravity = [0.0, -9.81, 0.0]", "gravity = [0, -9810, 0]")
    });
    fit_motion_refused_with(&ds, &["dataset.toml", "field gravity", "mm/s²"]);
}

#[test]
fn fit_motion_names_a_bad_start_in_words() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = motion_with(tmp.path(), |t| t.replace("mu = 10000.0", "mu = -1.0"));
    let out = tmp.path().join("fit.json");
    let mut c = cmd(&["fit-motion"]);
    c.arg(&ds).arg("-o").arg(&out);
    let err = refused_with(&run_within(c, 300), &["initial.mu"]);
    assert!(!err.contains("Param {"), "{err}");
}

/// `palpate import c3d <capture> --mesh beam-coarse --places … --clamps clamp --gravity=-9.81,0,0
/// -o <out>` with `extra` flags.
fn import_beam(capture: &Path, out: &Path, extra: &[&str]) -> Command {
    let beam = repo().join("models/silicone-beam");
    let mut c = cmd(&["import", "c3d"]);
    c.arg(capture)
        .arg("--mesh")
        .arg(beam.join("beam-coarse.msh"))
        .arg("--places")
        .arg(beam.join("marker-places.csv"))
        .args(["--clamps", "clamp", "--gravity=-9.81,0,0"])
        .args(extra)
        .arg("-o")
        .arg(out);
    c
}

fn beam_capture() -> PathBuf {
    repo().join("models/silicone-beam/beam_gravity_V2_a.c3d")
}

#[test]
fn import_refuses_a_negative_density_and_a_non_positive_release_threshold() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("D");
    for (flag, part) in [
        ("--density=-1", "--density"),
        ("--release-threshold=0", "--release-threshold"),
        ("--release-threshold=-1", "--release-threshold"),
    ] {
        let o = run_within(import_beam(&beam_capture(), &out, &[flag]), 120);
        refused_with(&o, &[part]);
        assert!(!out.exists(), "{flag}: an output folder was made");
    }
}

#[test]
fn import_refuses_a_mesh_in_millimetres_with_places_in_metres() {
    let tmp = tempfile::tempdir().unwrap();
    let mut mesh =
        palpate_fem::mesh::gmsh::read_msh(repo().join("models/silicone-beam/beam-coarse.msh"))
            .unwrap();
    for p in &mut mesh.nodes {
        for v in p.iter_mut() {
            *v *= 1e3;
        }
    }
    let mm = tmp.path().join("beam-mm.msh");
    palpate_fem::mesh::gmsh::write_msh(&mesh, &mm).unwrap();
    let out = tmp.path().join("D");
    let beam = repo().join("models/silicone-beam");
    let mut c = cmd(&["import", "c3d"]);
    c.arg(beam_capture())
        .arg("--mesh")
        .arg(&mm)
        .arg("--places")
        .arg(beam.join("marker-places.csv"))
        .args(["--clamps", "clamp", "--gravity=-9.81,0,0", "-o"])
        .arg(&out);
    let o = run_within(c, 120);
    let err = text(&o.stderr);
    assert_ne!(o.status.code(), Some(0), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(err.contains("millimetres"), "{err}");
    assert!(!out.exists(), "{err}");
}

#[test]
fn a_failing_import_leaves_the_previous_dataset_whole() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("D");
    let o = run_within(import_beam(&beam_capture(), &out, &[]), 120);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stderr));
    let before = std::fs::read(out.join("dataset.toml")).unwrap();
    let mut c = cmd(&["import", "c3d"]);
    let beam = repo().join("models/silicone-beam");
    c.arg(beam_capture())
        .arg("--mesh")
        .arg(beam.join("beam-coarse.msh"))
        .arg("--places")
        .arg(beam.join("marker-places.csv"))
        .args(["--clamps", "nosuch", "--gravity=-9.81,0,0", "-o"])
        .arg(&out);
    let o = run_within(c, 120);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    assert_eq!(std::fs::read(out.join("dataset.toml")).unwrap(), before);
    assert!(out.join("trajectories.csv").exists());
    assert!(out.join("mesh.msh").exists());
    let mut c = cmd(&["import", "c3d"]);
    c.arg(beam_capture())
        .arg("--mesh")
        .arg(beam.join("beam-coarse.msh"))
        .arg("--places")
        .arg(beam.join("marker-places.csv"))
        .args(["--clamps", "clamp", "--gravity=1e308,0,0", "-o"])
        .arg(&out);
    let o = run_within(c, 120);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    assert_eq!(std::fs::read(out.join("dataset.toml")).unwrap(), before);
    // No staging folder left behind beside it.
    let names: Vec<String> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["D"]);
}

#[test]
fn validate_refuses_a_fit_with_a_negative_density() {
    let tmp = tempfile::tempdir().unwrap();
    let t = std::fs::read_to_string(repo().join("models/silicone-beam/fit.json")).unwrap();
    let v: serde_json::Value = serde_json::from_str(&t).unwrap();
    let mut v = v;
    v["density_kg_m3"] = serde_json::json!([-47.0]);
    let fit = tmp.path().join("fit.json");
    std::fs::write(&fit, serde_json::to_string(&v).unwrap()).unwrap();
    // The beam's own dataset is made by import; the mesh check comes after the material's.
    let ds = tmp.path().join("D");
    let o = run_within(import_beam(&beam_capture(), &ds, &[]), 120);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stderr));
    let out = tmp.path().join("pred");
    let mut c = cmd(&["validate", "--model"]);
    c.arg(&fit).arg(&ds).arg("-o").arg(&out);
    refused_with(&run_within(c, 300), &["fit.json", "density_kg_m3", "-47"]);
    assert!(!out.exists());
}

/// A `.palp` of the sponge (fitted once per test binary run: a few seconds).
fn sponge_model(dir: &Path) -> PathBuf {
    let m = dir.join("sponge.palp");
    let o = common::fit_sponge(&["-q"], &[], &m);
    common::assert_fit_written(&o);
    m
}

#[test]
fn simulate_refuses_node_forces_that_load_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let model = sponge_model(tmp.path());
    let mesh =
        palpate_fem::mesh::gmsh::read_msh(repo().join("models/sponge/dataset/mesh.msh")).unwrap();
    let bottom = mesh.group("bottom").unwrap().to_vec();
    let clamped: String = bottom
        .iter()
        .map(|&n| format!("{},0,0,-1\n", mesh.node_tags[n]))
        .collect();
    for (name, content, part) in [
        ("empty.csv", String::new(), "no force rows"),
        ("header.csv", "node,fx,fy,fz\n".to_string(), "no force rows"),
        (
            "clamped.csv",
            format!("node,fx,fy,fz\n{clamped}"),
            "none puts a non-zero force on a free node",
        ),
    ] {
        let f = tmp.path().join(name);
        std::fs::write(&f, content).unwrap();
        let out = tmp.path().join(format!("sim-{name}"));
        let mut c = cmd(&["simulate", "--model"]);
        c.arg(&model)
            .arg("--node-forces")
            .arg(&f)
            .arg("-o")
            .arg(&out);
        refused_with(&run_within(c, 120), &[name, part]);
    }
}

#[test]
fn the_wrong_kind_of_input_is_named_with_the_command_that_takes_it() {
    let tmp = tempfile::tempdir().unwrap();
    let motion = repo().join("models/motion-example");
    let static_ds = repo().join("models/sponge-specimen");
    let fit_json = repo().join("models/silicone-beam/fit.json");
    let stl = repo().join("models/silicone-beam/beam.stl");
    let palp = sponge_model(tmp.path());
    let cases: Vec<(Command, &[&str])> = vec![
        (
            {
                let mut c = cmd(&["fit"]);
                c.arg(&motion).arg("-o").arg(tmp.path().join("m.palp"));
                c
            },
            &["is a motion dataset", "`palpate fit-motion`"],
        ),
        (
            {
                let mut c = cmd(&["fit-motion"]);
                c.arg(&static_ds).arg("-o").arg(tmp.path().join("f.json"));
                c
            },
            &["is a static contact dataset", "`palpate fit`"],
        ),
        (
            {
                let mut c = cmd(&["simulate", "--model"]);
                c.arg(&fit_json)
                    .args(["--contact", "0.04,0.04,0.04", "--force", "0,0,-1", "-o"])
                    .arg(tmp.path().join("sim"));
                c
            },
            // Played in the runtime on the mesh of a run it was fitted on, which is not here.
            &[
                "is a fitted motion model",
                "out/beam-evidence/gravity_V2_a: not found",
            ],
        ),
        (
            {
                let mut c = cmd(&["validate", "--model"]);
                c.arg(&palp).arg(&motion);
                c
            },
            &["is a palpate runtime model", "needs a fitted motion model"],
        ),
        (
            {
                let mut c = cmd(&["info"]);
                c.arg(&stl);
                c
            },
            &["is an STL surface mesh", "mesh_stl.py"],
        ),
    ];
    for (c, parts) in cases {
        let err = refused_with(&run_within(c, 120), parts);
        assert!(!err.contains("unknown field"), "{err}");
    }
}

#[test]
fn demo_outside_the_repository_says_where_to_run_it() {
    let tmp = tempfile::tempdir().unwrap();
    let mut c = cmd(&["demo"]);
    c.current_dir(tmp.path());
    refused_with(&run_within(c, 60), &["repository's root folder"]);
    assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 0);
}

#[test]
fn diagnose_on_a_missing_dataset_makes_no_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let mut c = cmd(&["diagnose", "nothere"]);
    c.current_dir(tmp.path());
    refused_with(&run_within(c, 60), &["nothere", "no such file or folder"]);
    assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 0);
}

/// An unwritable output is found before the work: a thousand measurements would take minutes.
#[test]
fn specimen_checks_its_output_before_the_work() {
    let tmp = tempfile::tempdir().unwrap();
    let blocker = tmp.path().join("file");
    std::fs::write(&blocker, b"x").unwrap();
    let mut c = cmd(&["specimen", "--measurements", "1000", "-o"]);
    c.arg(blocker.join("s"));
    refused_with(&run_within(c, 30), &["file"]);
}

#[test]
fn probe_checks_its_csv_before_the_port() {
    let tmp = tempfile::tempdir().unwrap();
    let blocker = tmp.path().join("file");
    std::fs::write(&blocker, b"x").unwrap();
    let csv = blocker.join("rec.csv");
    let mut c = cmd(&["probe", "--port", "/dev/ttyNOSUCH0", "--csv"]);
    c.arg(&csv);
    let err = refused_with(&run_within(c, 30), &["rec.csv"]);
    assert!(!err.contains("ttyNOSUCH0"), "{err}");
}

#[test]
fn the_fit_report_names_its_material_in_words() {
    let tmp = tempfile::tempdir().unwrap();
    let model = sponge_model(tmp.path());
    let md = std::fs::read_to_string(model.with_extension("report").join("report.md"))
        .or_else(|_| {
            // The report's file name is the report writer's; read whichever Markdown it wrote.
            let dir = model.with_extension("report");
            let f = std::fs::read_dir(&dir)
                .unwrap()
                .map(|e| e.unwrap().path())
                .find(|p| p.extension().is_some_and(|e| e == "md"))
                .unwrap();
            std::fs::read_to_string(f)
        })
        .unwrap();
    assert!(!md.contains("Homogeneous ×"), "{md}");
    assert!(!md.contains("Displacement,"), "{md}");
    assert!(md.contains("displacement-based"), "{md}");
}
