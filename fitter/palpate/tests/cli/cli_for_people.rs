//! The `palpate` program as a person reads it: one vocabulary (the viscosity is `viscosity`, the
//! thesis' pair is never "λ" next to E and ν), results on stdout and everything else on stderr
//! with `-q`/`-v`/RUST_LOG, JSON documents with a schema version and units in their field names,
//! and figures in the format asked for.

use crate::common;

use common::{
    assert_exit_and_stderr, assert_fit_written, assert_succeeded, fit_sponge, last_json, palpate,
    repo, text,
};
use std::path::Path;
use std::process::{Command, Output};

/// Runs `c` and asserts that it succeeded (its stderr shown if not).
#[track_caller]
fn succeeds(c: &mut Command) {
    assert_succeeded(&c.output().unwrap());
}

/// The JSON document in the file at `path`.
fn json_file(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// `palpate -q fit-motion <example> --params mu --max-iterations 2 -o <fit>`: a short motion fit
/// (μ alone, two iterations) whose files the tests then read; the caller checks the outcome.
fn quick_fit_motion(example: &Path, fit: &Path) -> Output {
    palpate()
        .args(["-q", "fit-motion"])
        .arg(example)
        .args(["--params", "mu", "--max-iterations", "2", "-o"])
        .arg(fit)
        .output()
        .unwrap()
}

/// `fit-motion --params mu,nu` (the old name of the viscosity) still fits, says on stderr that
/// the name is now `viscosity`, and writes `viscosity` in fit.json's list of fitted parameters;
/// the table names Lamé's λ, μ, E and ν and the thesis pair under its own name, with the
/// sentence that says what it is, and prints plain numbers with their units.
#[test]
fn fit_motion_reads_the_old_nu_with_a_warning_and_names_things_once() {
    let dir = tempfile::tempdir().unwrap();
    let fit = dir.path().join("fit.json");
    let o = palpate()
        .arg("fit-motion")
        .arg(repo().join("models/motion-example"))
        .args(["--params", "mu,nu", "--initial", "nu=8"])
        .args(["--max-iterations", "3", "-o"])
        .arg(&fit)
        .output()
        .unwrap();
    let (out, err) = (text(&o.stdout), text(&o.stderr));
    // 3 iterations stop at the cap: written, with that warning (exit 2).
    assert!(matches!(o.status.code(), Some(0 | 2)), "{out}{err}");
    for flag in ["--params", "--initial"] {
        assert!(
            err.contains(&format!("{flag}: `nu` is now called `viscosity`")),
            "{flag}: {err}"
        );
    }
    let record = json_file(&fit);
    assert_eq!(record["schema_version"], 2);
    assert_eq!(record["format"], "palpate-motion-fit/2");
    assert_eq!(record["fitted"], serde_json::json!(["mu", "viscosity"]));
    for k in [
        "lame_lambda_pa",
        "shear_modulus_pa",
        "viscosity_pa_s_h",
        "power_law_index",
        "density_kg_m3",
        "thesis_lambda_f_alpha_g_pa",
    ] {
        assert!(record[k].is_array(), "{k} missing: {record}");
    }
    assert!(record.get("lambda").is_none() && record.get("nu").is_none());
    for words in [
        "| Lamé λ (",
        "| shear modulus μ (",
        "| viscosity (",
        "Young's modulus E, Poisson's ratio ν",
        "thesis coefficients (λ_F, α_G)",
        "not Lamé's (λ, μ)",
    ] {
        assert!(out.contains(words), "{words:?} not in:\n{out}");
    }
    // Plain numbers in the unit each figure reads best in (`20.00 kPa`, `5.312 Pa·s^h`), never
    // exponent notation (`2.000000e4`).
    assert!(out.contains(" kPa") && out.contains(" Pa·s^h"), "{out}");
    let exponent = |l: &str| {
        l.as_bytes().windows(3).any(|w| {
            w[0].is_ascii_digit() && w[1] == b'e' && (w[2].is_ascii_digit() || w[2] == b'-')
        })
    };
    assert!(
        !out.lines().any(|l| l.starts_with('|') && exponent(l)),
        "exponent notation in:\n{out}"
    );
    assert!(!out.contains("| λ (Pa)") && !out.contains("runtime (thesis) λ"));
    // The new name needs no warning.
    let o = palpate()
        .arg("fit-motion")
        .arg(repo().join("models/motion-example"))
        .args(["--params", "mu,viscosity", "--max-iterations", "1", "-q"])
        .output()
        .unwrap();
    assert!(
        !text(&o.stderr).contains("is now called"),
        "{}",
        text(&o.stderr)
    );
    // An unknown name is an error that lists the names.
    let o = palpate()
        .arg("fit-motion")
        .arg(repo().join("models/motion-example"))
        .args(["--params", "mu,damping"])
        .output()
        .unwrap();
    assert_exit_and_stderr(
        &o,
        1,
        "\"damping\" (lambda, mu, viscosity, h, density, stiffening)",
    );
}

/// A motion dataset whose `[initial]` table still says `nu` is read (as the viscosity) with a
/// warning naming the new key.
#[test]
fn a_dataset_with_initial_nu_is_read_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dir.path().join("example");
    std::fs::create_dir_all(&ds).unwrap();
    for e in std::fs::read_dir(repo().join("models/motion-example")).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), ds.join(e.file_name())).unwrap();
    }
    let toml = std::fs::read_to_string(ds.join("dataset.toml")).unwrap();
    assert!(toml.contains("\nviscosity = 6.0"));
    std::fs::write(
        ds.join("dataset.toml"),
        toml.replace("\nviscosity = 6.0", "\nnu = 6.0"),
    )
    .unwrap();
    let o = palpate().arg("info").arg(&ds).output().unwrap();
    assert_exit_and_stderr(&o, 0, "[initial] nu is now called viscosity");
    let d = palpate_motion::dataset::load(&ds).unwrap();
    assert_eq!(d.config.initial.nu, 6.0);
}

/// Results on stdout, progress and the files written on stderr; `-q` leaves only the result,
/// `RUST_LOG=warn` does the same without the flag, and `-v` adds debug lines.
#[test]
fn progress_goes_to_stderr_and_quiet_silences_it() {
    let dir = tempfile::tempdir().unwrap();
    let run = |extra: &[&str], env: Option<(&str, &str)>| -> Output {
        let mut c = palpate();
        c.args(extra)
            .arg("diagnose")
            .arg(repo().join("models/motion-example"))
            .arg("-o")
            .arg(dir.path().join("d"))
            .env_remove("RUST_LOG");
        if let Some((k, v)) = env {
            c.env(k, v);
        }
        c.output().unwrap()
    };
    let plain = run(&[], None);
    assert_succeeded(&plain);
    let (out, err) = (text(&plain.stdout), text(&plain.stderr));
    // The verdict is the result: stdout, one line.
    assert_eq!(out.lines().count(), 1, "{out}");
    assert!(out.contains("RMS marker error"), "{out}");
    assert!(err.contains("round 1") && err.contains("wrote "), "{err}");
    assert!(!out.contains("wrote "));
    let quiet = run(&["-q"], None);
    assert_succeeded(&quiet);
    assert_eq!(text(&quiet.stdout), out, "-q changes only stderr");
    assert_eq!(
        text(&quiet.stderr),
        "",
        "-q leaves warnings and errors only"
    );
    let env_quiet = run(&[], Some(("RUST_LOG", "warn")));
    assert_eq!(text(&env_quiet.stderr), "");
    // A flag beats RUST_LOG.
    let flag_wins = run(&["-q"], Some(("RUST_LOG", "debug")));
    assert_eq!(text(&flag_wins.stderr), "");
    // -q and -v together is a usage error, not a guess.
    let both = run(&["-q", "-v"], None);
    assert_exit_and_stderr(&both, 2, "cannot be used with");
    // Errors are shown under -q too.
    let o = palpate()
        .args(["-q", "info"])
        .arg(repo().join("README.md"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(
        text(&o.stderr).starts_with("error: "),
        "{}",
        text(&o.stderr)
    );
}

/// Every JSON document of the user's commands carries `schema_version`: fit.json (above), the
/// diagnosis (here: a motion dataset's), validate's and info's last lines, the static fit's
/// report.json, simulate's summary.json; validate's line keeps `final_rms_m` and
/// `trajectory_rms_m` (an external checker reads them).
#[test]
fn every_json_document_has_a_schema_version_and_units_in_its_names() {
    let dir = tempfile::tempdir().unwrap();
    let example = repo().join("models/motion-example");
    // The motion diagnosis (0.5 s).
    let d = dir.path().join("diagnosis");
    succeeds(
        palpate()
            .args(["-q", "diagnose"])
            .arg(&example)
            .arg("-o")
            .arg(&d),
    );
    let doc = json_file(&d.join("diagnosis.json"));
    assert_eq!(doc["schema_version"], 1);
    assert_eq!(doc["kind"], "motion-diagnosis");
    assert!(doc["before"]["rms_fit_m"].as_f64().is_some(), "{doc}");
    assert!(doc["size"]["dt_s"].as_f64().is_some());
    assert!(doc["elastic"]["poisson_ratio"].as_f64().is_some());
    // The example does not come to rest, so the parameters under one refinement come from the
    // mesh's own null, made for them when no check made one.
    let bias = &doc["mesh_bias"];
    assert!(
        bias["parameters"].as_array().is_some_and(|p| !p.is_empty())
            && bias["converged"].is_boolean(),
        "{bias}"
    );
    let names: Vec<&str> = doc["after_values"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|v| v["name"].as_str())
        .collect();
    assert!(
        names.iter().any(|n| n.starts_with("viscosity")),
        "{names:?}"
    );
    assert!(!names.iter().any(|n| n.starts_with("nu")), "{names:?}");
    let md = std::fs::read_to_string(d.join("diagnosis.md")).unwrap();
    assert!(md.contains("viscosity = 0 held fixed") && md.contains("Young's modulus E ="));

    // fit-motion → validate's last line.
    let fit = dir.path().join("fit.json");
    let o = quick_fit_motion(&example, &fit);
    assert!(fit.exists(), "{}", text(&o.stderr));
    let o = palpate()
        .args(["-q", "validate", "--model"])
        .arg(&fit)
        .arg(&example)
        .output()
        .unwrap();
    let v = last_json(&o);
    assert_eq!(v["schema_version"], 1);
    for k in ["final_rms_m", "trajectory_rms_m", "load_n", "dt_s"] {
        assert!(v[k].as_f64().is_some(), "{k}: {v}");
    }
    // The rest error split along gravity and across it is the whole rest error.
    let (along, across, whole) = (
        v["rest_along_gravity_rms_m"]
            .as_f64()
            .expect("the example has gravity"),
        v["rest_across_gravity_rms_m"].as_f64().unwrap(),
        v["final_rms_m"].as_f64().unwrap(),
    );
    assert!(
        (along.hypot(across) - whole).abs() <= 1e-9 * whole.max(1e-12),
        "{along} ⊕ {across} against {whole}"
    );
    // info on the fit, the dataset and a model.
    for arg in [fit.clone(), example.clone()] {
        let o = palpate().arg("info").arg(&arg).output().unwrap();
        let v = last_json(&o);
        assert_eq!(v["schema_version"], 1, "{v}");
    }
    let o = palpate()
        .arg("info")
        .arg(repo().join("models/silicone-beam/fit.json"))
        .output()
        .unwrap();
    let v = last_json(&o);
    for k in [
        "young_modulus_pa",
        "poisson_ratio",
        "lame_lambda_pa",
        "shear_modulus_pa",
        "viscosity_pa_s_h",
    ] {
        assert!(v[k].as_f64().is_some(), "{k}: {v}");
    }
    // simulate's summary.json, then info on a .palp made by fit (the static report.json).
    let sim = dir.path().join("sim");
    succeeds(
        palpate()
            .args(["-q", "simulate", "--mesh"])
            .arg(repo().join("models/sponge/sponge.msh"))
            .args(["--young", "2e4", "--poisson", "0.3", "--fixed", "bottom"])
            .args(["--contact", "0.05,0.05,0.05", "--force", "0,0,-0.5", "-o"])
            .arg(&sim),
    );
    let s = json_file(&sim.join("summary.json"));
    assert_eq!(s["schema_version"], 1);
    let model = dir.path().join("m.palp");
    let o = fit_sponge(&["-q"], &["--plot-format", "png"], &model);
    assert_fit_written(&o);
    let report = dir.path().join("m.report");
    let r = json_file(&report.join("report.json"));
    assert_eq!(r["schema_version"], 1);
    let row = &r["rows"][0];
    for k in [
        "young_modulus_pa",
        "poisson_ratio",
        "lame_lambda_pa",
        "shear_modulus_pa",
        "thesis_lambda_f_pa",
        "thesis_alpha_g_pa",
        "rms_m",
    ] {
        assert!(row[k].as_f64().is_some(), "{k}: {row}");
    }
    assert!(row.get("lambda").is_none() && row.get("alpha").is_none());
    assert!(r["fit"]["per_measurement"][0]["rms_m"].as_f64().is_some());
    let md = std::fs::read_to_string(report.join("report.md")).unwrap();
    assert!(
        md.contains("| E (kPa) | ν | Lamé λ (kPa) | μ (kPa) |"),
        "{md}"
    );
    assert!(
        md.contains("Thesis coefficients (λ_F, α_G)") && md.contains("| λ_F (kPa) | α_G (kPa) |")
    );
    assert!(!md.contains("| λ (kPa) |") && !md.contains("| α (kPa) |"));
    // The report reads as words and shows its figures: no Rust type names, the figure embedded
    // as the PNG that --plot-format png wrote.
    for type_name in ["Homogeneous", "Single", "Displacement", "Converged"] {
        assert!(!md.contains(type_name), "{type_name} in {md}");
    }
    assert!(md.contains("](marker_error.png)"), "{md}");
    // --plot-format png: every figure as PNG, no SVG.
    let figures: Vec<String> = std::fs::read_dir(&report)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .collect();
    assert!(
        figures.iter().any(|f| f == "marker_error.png"),
        "{figures:?}"
    );
    assert!(!figures.iter().any(|f| f.ends_with(".svg")), "{figures:?}");
    // One material: no histogram of one value (E and ν are in the table).
    assert!(!figures.iter().any(|f| f.contains("_hist")), "{figures:?}");
    let o = palpate().arg("info").arg(&model).output().unwrap();
    let v = last_json(&o);
    assert_eq!(v["schema_version"], 1);
    assert!(v["lame_lambda_min_pa"].as_f64().is_some(), "{v}");
    assert!(text(&o.stdout).contains("Lamé λ"));
}

/// `--plot-format svg` writes the SVG only, and the default writes both.
#[test]
fn plot_format_chooses_the_files() {
    let dir = tempfile::tempdir().unwrap();
    let example = repo().join("models/motion-example");
    let fit = dir.path().join("fit.json");
    quick_fit_motion(&example, &fit);
    for (format, svg, png) in [("svg", true, false), ("both", true, true)] {
        let out = dir.path().join(format);
        succeeds(
            palpate()
                .args(["-q", "validate", "--model"])
                .arg(&fit)
                .arg(&example)
                .args(["--plot-format", format, "-o"])
                .arg(&out),
        );
        assert_eq!(out.join("tip.svg").exists(), svg, "{format}");
        assert_eq!(out.join("tip.png").exists(), png, "{format}");
    }
    let o = palpate()
        .args(["validate", "--model"])
        .arg(&fit)
        .arg(&example)
        .args(["--plot-format", "pdf"])
        .output()
        .unwrap();
    assert_exit_and_stderr(&o, 2, "png, svg, both");
}

/// `palpate info` on a motion capture says what `palpate import c3d` will read: markers, rate,
/// frames and each marker's gaps and travel — the bundled beam capture (6 markers at 100 Hz; the
/// tip moves centimetres, the base markers near the clamp under a few millimetres).
#[test]
fn info_reads_a_c3d_capture() {
    let c3d = repo().join("models/silicone-beam/beam_gravity_V2_a.c3d");
    let o = palpate().arg("info").arg(&c3d).output().unwrap();
    assert_succeeded(&o);
    let out = text(&o.stdout);
    assert!(
        out.contains("C3D motion capture; 6 markers at 100 Hz"),
        "{out}"
    );
    let j = last_json(&o);
    assert_eq!(j["kind"], "capture");
    assert_eq!(j["markers"], 6);
    let per: Vec<(String, f64)> = j["per_marker"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| {
            (
                m["label"].as_str().unwrap().to_string(),
                m["max_travel_m"].as_f64().unwrap(),
            )
        })
        .collect();
    let travel = |prefix: &str| {
        per.iter()
            .filter(|(l, _)| l.starts_with(prefix))
            .map(|(_, t)| *t)
            .fold(0.0, f64::max)
    };
    assert!(travel("Tip") > 0.01, "{per:?}");
    assert!(travel("Base") < 0.005, "{per:?}");
}

/// A reader that closes the pipe early (`palpate info x | head -1`) ends palpate quietly, as it
/// ends any Unix filter, never with a panic on the broken pipe. The read end is closed before
/// palpate has read its capture, so its first line meets a closed pipe.
#[cfg(unix)]
#[test]
fn a_closed_stdout_ends_quietly() {
    use std::process::Stdio;
    let c3d = repo().join("models/silicone-beam/beam_gravity_V2_a.c3d");
    let mut child = palpate()
        .arg("info")
        .arg(&c3d)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    let err = text(&o.stderr);
    assert!(!err.contains("panicked"), "{err}");
}

/// `palpate info` on a Gmsh mesh: its size, extent, volume and physical groups — the bundled beam
/// mesh is the 30 × 30 × 100 mm beam (volume 9 × 10⁻⁵ m³) with its `clamp` and `free_end` faces.
#[test]
fn info_reads_a_gmsh_mesh() {
    let msh = repo().join("models/silicone-beam/beam-coarse.msh");
    let o = palpate().arg("info").arg(&msh).output().unwrap();
    assert_succeeded(&o);
    let j = last_json(&o);
    assert_eq!(j["kind"], "mesh");
    assert_eq!(j["tets"], 716);
    assert!(
        (j["volume_m3"].as_f64().unwrap() - 9e-5).abs() < 1e-12,
        "{j}"
    );
    let extent: Vec<f64> = j["extent_m"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    for (e, want) in extent.iter().zip([0.03, 0.03, 0.1]) {
        assert!((e - want).abs() < 1e-9, "{extent:?}");
    }
    assert!(j["groups"]["clamp"].as_u64().unwrap() > 0, "{j}");
    assert!(j["groups"]["free_end"].as_u64().unwrap() > 0, "{j}");
}
