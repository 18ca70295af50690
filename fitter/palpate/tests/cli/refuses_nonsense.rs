//! The `palpate` program as a user runs it, on inputs that must not give a confident answer:
//! degenerate static data, absurd loads, a probe nowhere near the object, out-of-range options.
//! Each must exit non-zero, name what is wrong, and write nothing.

use crate::common;

use common::{
    assert_exit_and_stderr, assert_succeeded, fit_sponge, last_json, palpate, refused, repo,
};
use std::path::{Path, PathBuf};

/// A copy of the bundled sponge dataset with `edit` applied to each CSV row of `file` (the header
/// is kept).
fn sponge_with(
    dir: &Path,
    file: &str,
    edit: impl Fn(usize, Vec<String>) -> Vec<String>,
) -> PathBuf {
    let dst = dir.join("dataset");
    common::copy_dir(&repo().join("models/sponge/dataset"), &dst);
    let text = std::fs::read_to_string(dst.join(file)).unwrap();
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        if i == 0 || line.trim().is_empty() || line.starts_with('#') {
            out.push(line.to_string());
            continue;
        }
        let fields = line.split(',').map(String::from).collect();
        out.push(edit(i, fields).join(","));
    }
    std::fs::write(dst.join(file), out.join("\n") + "\n").unwrap();
    dst
}

/// Runs `palpate fit` and returns (exit code, stderr); asserts nothing was written.
fn fit_refused(dataset: &Path, extra: &[&str]) -> (i32, String) {
    let out = dataset.parent().unwrap().join("out");
    let model = out.join("model.palp");
    let o = palpate()
        .args(["fit"])
        .arg(dataset)
        .args(extra)
        .arg("-o")
        .arg(&model)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(!model.exists(), "a model was written: {err}");
    assert!(
        !out.join("model.report").exists(),
        "a report was written: {err}"
    );
    (o.status.code().unwrap_or(-1), err)
}

/// `palpate fit` on the sponge with `edit` applied to `file` (as [`sponge_with`]) exits 1, writes
/// nothing and names every one of `parts` on stderr.
#[track_caller]
fn fit_on_edited_sponge_refuses(
    file: &str,
    edit: impl Fn(usize, Vec<String>) -> Vec<String>,
    parts: &[&str],
) {
    let tmp = tempfile::tempdir().unwrap();
    let ds = sponge_with(tmp.path(), file, edit);
    let (code, err) = fit_refused(&ds, &[]);
    assert_eq!(code, 1, "{err}");
    assert!(parts.iter().all(|p| err.contains(p)), "{err}");
}

#[test]
fn fit_refuses_zero_forces() {
    fit_on_edited_sponge_refuses(
        "contacts.csv",
        |_, mut f| {
            f[4] = "0".into();
            f[5] = "0".into();
            f[6] = "0".into();
            f
        },
        &["zero-forces", "zero probe force"],
    );
}

#[test]
fn fit_refuses_markers_that_never_move() {
    let markers =
        std::fs::read_to_string(repo().join("models/sponge/dataset/markers.csv")).unwrap();
    let rest: std::collections::HashMap<String, Vec<String>> = markers
        .lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let f: Vec<String> = l.split(',').map(String::from).collect();
            (f[0].clone(), f[1..4].to_vec())
        })
        .collect();
    fit_on_edited_sponge_refuses(
        "measurements.csv",
        |_, f| {
            let mut g = f[..2].to_vec();
            g.extend(rest[&f[1]].iter().cloned());
            g
        },
        &["markers-still"],
    );
}

#[test]
fn fit_refuses_a_parameter_at_its_bound() {
    // A meganewton on one contact of a sponge: the (λ, α) fit runs into ν = −1.
    fit_on_edited_sponge_refuses(
        "contacts.csv",
        |i, mut f| {
            if i == 1 {
                f[6] = "-1e6".into();
            }
            f
        },
        &["parameter-at-bound", "ν"],
    );
}

#[test]
fn fit_refuses_nonsense_regularisation() {
    let ds = repo().join("models/sponge/dataset");
    for g in ["NaN", "inf", "-1"] {
        let o = palpate()
            .args(["fit"])
            .arg(&ds)
            .args(["--gamma-s", g, "-o", "/nonexistent-palpate/m.palp"])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "--gamma-s {g}: {err}"); // clap's usage error
        assert!(
            err.contains("--gamma-s") && err.contains("finite number ≥ 0"),
            "{err}"
        );
    }
}

/// An output that cannot be written is refused before any work: before the fit, and before the
/// dataset is even read — a dataset folder that does not exist is not what the error names.
#[test]
fn fit_checks_its_output_before_fitting() {
    let o = fit_sponge(
        &[],
        &[],
        Path::new("/proc/palpate-cannot-write-here/model.palp"),
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("output") && err.contains("model.palp"),
        "{err}"
    );
    let o = palpate()
        .args(["fit", "/nonexistent-palpate-dataset", "-o"])
        .arg("/proc/palpate-cannot-write-here/model.palp")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("model.palp") && !err.contains("nonexistent-palpate-dataset"),
        "the output must be checked before the dataset is read: {err}"
    );
}

fn simulate(extra: &[&str], out: &Path) -> (i32, String) {
    let o = palpate()
        .args(["simulate", "--mesh"])
        .arg(repo().join("models/sponge/sponge.msh"))
        .args(["--young", "2e4", "--poisson", "0.3", "--fixed", "bottom"])
        .args(extra)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).to_string(),
    )
}

#[test]
fn simulate_refuses_loads_beyond_the_model() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("sim");
    let (code, err) = simulate(
        &["--contact", "0.05,0.05,0.05", "--force", "0,0,-1e6"],
        &out,
    );
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("displacement-beyond-size"), "{err}");
    assert!(!out.exists(), "nothing written");
    // It stops early, not at the tick cap: the not-settled finding says after how many ticks
    // ("within N ticks (cap M)").
    let count = |after: &str| -> usize {
        let rest = &err[err
            .find(after)
            .unwrap_or_else(|| panic!("{after:?} not in: {err}"))
            + after.len()..];
        rest.split(|c: char| !c.is_ascii_digit())
            .next()
            .and_then(|d| d.parse().ok())
            .unwrap_or_else(|| panic!("no count after {after:?} in: {err}"))
    };
    let (ticks, cap) = (count("within "), count("ticks (cap "));
    assert!(ticks < cap, "ran to the cap: {ticks} of {cap} ticks: {err}");
    // A probe nowhere near the object.
    let (code, err) = simulate(&["--probe", "5,5,5"], &out);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("no-contact") && err.contains("bounding box"),
        "{err}"
    );
    // Increments are bounded.
    let (code, err) = simulate(
        &[
            "--contact",
            "0.05,0.05,0.05",
            "--force",
            "0,0,-1",
            "--increments",
            "1000000000",
        ],
        &out,
    );
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--increments"), "{err}");
    // And an ordinary press still works.
    let (code, err) = simulate(&["--contact", "0.05,0.05,0.05", "--force", "0,0,-1"], &out);
    assert_eq!(code, 0, "{err}");
    assert!(out.join("displacements.csv").exists());
}

/// `palpate probe` on a port where nothing streams is an error, not "0 samples" and exit 0.
#[test]
fn probe_with_no_data_is_an_error() {
    use serialport::SerialPort;
    let (master, slave) = serialport::TTYPort::pair().expect("a pseudo-terminal pair");
    let path = slave.name().expect("the slave end has a path");
    let o = palpate()
        .args(["probe", "--port", &path, "--seconds", "0.5"])
        .output()
        .unwrap();
    drop(master);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("no force sample received") && err.contains(&path),
        "{err}"
    );
}

/// A fit stopped by its iteration cap is written but said loudly: exit status 2, the warning on
/// stderr and "NOT CONVERGED" in the report.
#[test]
fn fit_at_its_iteration_cap_exits_2_with_the_warning_in_the_report() {
    let tmp = tempfile::tempdir().unwrap();
    let model = tmp.path().join("model.palp");
    let o = fit_sponge(&[], &["--max-iterations", "1"], &model);
    assert_exit_and_stderr(&o, 2, "iteration-cap");
    assert!(model.exists());
    let report = std::fs::read_to_string(tmp.path().join("model.report/report.md")).unwrap();
    assert!(
        report.contains("NOT CONVERGED") && report.contains("iteration-cap"),
        "{report}"
    );
}

/// `palpate validate` predicts a run from a fitted model and ends with one JSON line; a file that
/// is not a fitted model, or a model of another mesh, is refused with the reason.
#[test]
fn validate_predicts_from_a_fit_and_refuses_other_models() {
    let dir = tempfile::tempdir().unwrap();
    let example = repo().join("models/motion-example");
    let fit = dir.path().join("fit.json");
    let o = palpate()
        .args(["fit-motion"])
        .arg(&example)
        .args(["--params", "mu", "--max-iters", "60", "-o"])
        .arg(&fit)
        .output()
        .unwrap();
    assert!(fit.exists(), "{}", String::from_utf8_lossy(&o.stderr));
    let validate = |model: &Path| {
        palpate()
            .args(["validate", "--model"])
            .arg(model)
            .arg(&example)
            .output()
            .unwrap()
    };
    let o = validate(&fit);
    assert_succeeded(&o);
    let last = last_json(&o);
    for key in ["final_rms_m", "trajectory_rms_m"] {
        let v = last[key].as_f64().unwrap();
        assert!(v.is_finite() && v >= 0.0, "{key} = {v}");
    }
    // The fit predicts its own run to the dataset's noise floor: σ = 0.2 mm per axis
    // (`models/motion-example/truth.toml`), σ√3 = 0.346 mm over the three; measured 0.348 mm
    // (release build, 60 iterations). 1.15 × the floor leaves room for the optimiser's stopping
    // point; a misfit of the material shows as millimetres.
    let floor = 0.2e-3 * 3f64.sqrt();
    assert!(
        last["trajectory_rms_m"].as_f64().unwrap() < 1.15 * floor,
        "{last}"
    );
    assert_eq!(last["time_offset_s"], 0.0);

    // A model fitted with per-run time offsets scans the run's own: this run is in step with its
    // simulation, so the scan finds 0 and the prediction is the same.
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&fit).unwrap()).unwrap();
    v["time_offset"] = serde_json::json!(true);
    let timed = dir.path().join("timed.json");
    std::fs::write(&timed, v.to_string()).unwrap();
    let o = validate(&timed);
    assert_succeeded(&o);
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("time offset of this run"),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    let timed_last = last_json(&o);
    assert_eq!(timed_last["time_offset_s"], 0.0, "{timed_last}");
    assert_eq!(timed_last["trajectory_rms_m"], last["trajectory_rms_m"]);

    let not_a_model = dir.path().join("other.json");
    std::fs::write(&not_a_model, "{\"lambda\": [1.0]}").unwrap();
    let e = refused(&validate(&not_a_model));
    assert!(e.contains("not a fitted motion model"), "{e}");

    let text = std::fs::read_to_string(&fit).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["tets"] = serde_json::json!(25);
    let other_mesh = dir.path().join("other-mesh.json");
    std::fs::write(&other_mesh, v.to_string()).unwrap();
    let e = refused(&validate(&other_mesh));
    assert!(e.contains("mesh") && e.contains("25"), "{e}");
}

/// `palpate import c3d --hang` on a real capture writes the weight as a dead load on the top edge
/// of the free end; a group the mesh lacks is refused and nothing stays written.
#[test]
fn import_c3d_declares_a_hanging_weight_and_refuses_an_unknown_group() {
    let dir = tempfile::tempdir().unwrap();
    let import = |hang: &str, out: &Path| {
        common::import_beam("beam_load52_V2_a.c3d")
            .args(["--hang", hang, "-o"])
            .arg(out)
            .output()
            .unwrap()
    };
    let good = dir.path().join("good");
    assert_succeeded(&import("0.052@free_end", &good));
    let ds = palpate_motion::dataset::load(&good).unwrap();
    let l = &ds.model.loads[0];
    assert!((l.force[0] + 0.052 * 9.81).abs() < 1e-12 && l.force[1] == 0.0 && l.force[2] == 0.0);
    assert_eq!(l.mass, Some(0.052));
    // The top edge of the free end: z = 0 and x = 30 mm (gravity is −x in the mesh frame).
    assert!(!l.nodes.is_empty());
    for &n in &l.nodes {
        let p = ds.mesh.nodes[n];
        assert!(p[2].abs() < 1e-9 && (p[0] - 0.03).abs() < 1e-9, "{p:?}");
    }
    let bad = dir.path().join("bad");
    let e = refused(&import("0.052@nosuch", &bad));
    assert!(e.contains("nosuch") && e.contains("nothing written"), "{e}");
    assert!(!bad.join("dataset.toml").exists() && !bad.join("trajectories.csv").exists());
}

/// `palpate info` names what a file is (a model, a fitted motion model, a dataset) and ends with
/// one JSON line; a file that is none of them is an error naming it.
#[test]
fn info_reads_models_fits_and_datasets_and_refuses_the_rest() {
    let info = |arg: &Path| -> serde_json::Value {
        let o = palpate().arg("info").arg(arg).output().unwrap();
        assert_succeeded(&o);
        last_json(&o)
    };
    let fit = info(&repo().join("models/silicone-beam/fit.json"));
    assert_eq!(fit["kind"], "motion-fit");
    assert_eq!(fit["tets"], 716);
    assert_eq!(fit["hanging_inertia"], true);
    let ds = info(&repo().join("models/motion-example"));
    assert_eq!(
        (ds["kind"].as_str(), ds["tets"].as_u64()),
        (Some("motion-dataset"), Some(24))
    );
    let st = info(&repo().join("models/sponge-specimen"));
    assert_eq!(st["kind"], "static-dataset");
    let o = palpate()
        .arg("info")
        .arg(repo().join("README.md"))
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1));
    assert!(e.contains("README.md") && e.contains("PALP"), "{e}");
}

/// Help is written for users: no command's `--help` shows rustdoc link syntax (a backtick inside
/// square brackets, "[`Type`]") or a bare paper section ("§5.3") without words around it.
#[test]
fn help_texts_have_no_rustdoc_links() {
    let commands = common::commands();
    assert!(commands.len() >= 10, "{commands:?}");
    for c in std::iter::once(String::new()).chain(commands) {
        let mut cmd = palpate();
        if !c.is_empty() {
            cmd.arg(&c);
        }
        let help = String::from_utf8_lossy(&cmd.arg("--help").output().unwrap().stdout).to_string();
        assert!(
            !help.contains("[`"),
            "palpate {c} --help shows rustdoc links:\n{help}"
        );
        if c == "import" {
            let sub = palpate()
                .args(["import", "c3d", "--help"])
                .output()
                .unwrap();
            assert!(!String::from_utf8_lossy(&sub.stdout).contains("[`"));
        }
    }
}

/// Forces given with the opposite sign convention (the object pulling the probe, or a load cell
/// read the other way round) are not a stiff object: `palpate diagnose` refuses them, says why
/// and names the measurements, and writes no report.
#[test]
fn diagnose_refuses_forces_of_the_wrong_sign() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = sponge_with(tmp.path(), "contacts.csv", |_, mut f| {
        for v in &mut f[4..7] {
            let x: f64 = v.parse().unwrap();
            *v = format!("{}", -x);
        }
        f
    });
    let out = tmp.path().join("report");
    let o = palpate()
        .args(["diagnose"])
        .arg(&ds)
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    for part in [
        "point against the reported forces",
        "sign convention",
        "c0",
        "c1",
    ] {
        assert!(err.contains(part), "{part:?} not in: {err}");
    }
    assert!(
        !out.join("diagnosis.md").exists(),
        "a report was written: {err}"
    );
}

/// One contact row that reports no force while its markers move is named (the fit goes on: the
/// other measurements determine the material).
#[test]
fn fit_names_a_zero_force_measurement_whose_markers_move() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = sponge_with(tmp.path(), "contacts.csv", |i, mut f| {
        if i == 2 {
            for v in &mut f[4..7] {
                *v = "0".into();
            }
        }
        f
    });
    let model = tmp.path().join("model.palp");
    let o = palpate()
        .args(["fit"])
        .arg(&ds)
        .arg("-o")
        .arg(&model)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("zero-force-moves") && err.contains("\"c1\""),
        "{err}"
    );
    // The fit goes on: a model is written (exit 0 or 2, written with or without warnings; the
    // named row is a logged warning, measured exit 0).
    assert!(matches!(o.status.code(), Some(0 | 2)), "{err}");
    assert!(model.exists(), "no model written: {err}");
}
