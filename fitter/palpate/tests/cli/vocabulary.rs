//! One name per thing on the command line and in files: the clamped face is `clamps`, a flag whose
//! unit is not SI says its unit, help texts cite documents a user can open, `-o` is what a command
//! writes, `--model` takes a runtime model or a fit and says which it read. Old spellings are
//! still read, with a warning that names the new one.

use crate::common;

use common::{assert_exit_and_stderr, assert_succeeded, palpate, refused, repo, text};
use std::path::Path;

/// `simulate --mesh … --clamps GROUP`, or the older `--fixed GROUP` with a warning.
#[test]
fn simulate_reads_clamps_and_the_older_fixed_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let run = |flag: &str| {
        palpate()
            .arg("simulate")
            .arg("--mesh")
            .arg(repo().join("models/motion-example/mesh.msh"))
            .args(["--young", "50000", "--poisson", "0.3", flag, "bottom"])
            .args(["--contact", "0.01,0.04,0.02", "--force", "0,0,-0.1"])
            .arg("-o")
            .arg(dir.path().join(flag.trim_start_matches('-')))
            .env_remove("RUST_LOG")
            .output()
            .unwrap()
    };
    let new = run("--clamps");
    assert_succeeded(&new);
    assert!(
        !text(&new.stderr).contains("older name"),
        "{}",
        text(&new.stderr)
    );
    let old = run("--fixed");
    assert_succeeded(&old);
    let err = text(&old.stderr);
    assert!(
        err.contains("warning: --fixed is the older name of --clamps"),
        "{err}"
    );
}

/// A static dataset's `fixed_group = "…"` is read as `clamps = ["…"]`, with a warning naming the
/// file and line.
#[test]
fn a_static_dataset_with_fixed_group_is_read_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let src = repo().join("models/dataset-example");
    common::copy_dir(&src, dir.path());
    let toml = dir.path().join("dataset.toml");
    let t = std::fs::read_to_string(&toml).unwrap();
    assert!(t.contains("clamps = [\"bottom\"]"), "{t}");
    let mesh = src.join("../sponge/sponge.msh");
    let t = t
        .replace("clamps = [\"bottom\"]", "fixed_group = \"bottom\"")
        .replace(
            "\"../sponge/sponge.msh\"",
            &format!("{:?}", mesh.display().to_string()),
        );
    std::fs::write(&toml, t).unwrap();
    let o = palpate()
        .arg("info")
        .arg(dir.path())
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    assert_succeeded(&o);
    let err = text(&o.stderr);
    assert!(
        err.contains("dataset.toml:7: `fixed_group` is the older name of `clamps = [\"bottom\"]`"),
        "{err}"
    );
}

/// `--gauge-length-mm` says its unit; `--gauge-length` is still read, with a warning, and a bad
/// value is refused in the unit of the flag.
#[test]
fn gauge_length_says_millimetres() {
    let o = palpate()
        .arg("diagnose")
        .arg(repo().join("models/motion-example"))
        .args(["--gauge-length", "0"])
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    assert_exit_and_stderr(
        &o,
        1,
        "--gauge-length-mm 0: expected a finite length > 0 mm",
    );
    assert!(
        text(&o.stderr).contains("--gauge-length is the older name of --gauge-length-mm"),
        "{}",
        text(&o.stderr)
    );
}

/// probe-sim's dither is in ADC counts, and its flag says so; `--noise` is still read.
#[test]
fn probe_sim_dither_says_counts() {
    let help = palpate().args(["probe-sim", "--help"]).output().unwrap();
    let h = text(&help.stdout);
    assert!(h.contains("--adc-dither-counts"), "{h}");
    assert!(
        !h.lines().any(|l| l.trim_start().starts_with("--noise")),
        "{h}"
    );
    let o = palpate()
        .args(["probe-sim", "--noise", "2", "--profile", "bogus:1"])
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    assert_exit_and_stderr(&o, 1, "unknown kind \"bogus\"");
    assert!(
        text(&o.stderr).contains("--noise is the older name of --adc-dither-counts"),
        "{}",
        text(&o.stderr)
    );
}

/// Help texts cite documents a user can open (docs/method.md), not sections of the papers.
#[test]
fn help_cites_no_paper_sections() {
    let commands = common::commands();
    assert!(commands.len() > 10, "{commands:?}");
    for c in std::iter::once(String::new()).chain(commands) {
        let o = palpate().args([c.as_str(), "--help"]).output().unwrap();
        let h = text(&o.stdout);
        for bad in ["§", "seed 00", "thesis"] {
            assert!(!h.contains(bad), "`palpate {c} --help` cites {bad:?}:\n{h}");
        }
    }
}

/// `-o` means one thing everywhere: `-o, --output` (also `--out`), what the command writes, with
/// its default shown or, for a command whose result is printed, the words that nothing is written
/// without it.
#[test]
fn every_output_flag_is_o_output_with_its_default_or_none() {
    let top = text(&palpate().arg("--help").output().unwrap().stdout);
    assert!(top.contains("-o/--output"), "{top}");
    let mut seen = 0;
    for c in [
        "demo",
        "fit",
        "simulate",
        "specimen",
        "diagnose",
        "fit-motion",
        "validate",
        "calibrate-fsr",
        "import c3d",
    ] {
        let h = text(
            &palpate()
                .args(c.split(' '))
                .arg("--help")
                .output()
                .unwrap()
                .stdout,
        );
        let at = h
            .find("-o, --output <")
            .unwrap_or_else(|| panic!("`palpate {c} --help` has no `-o, --output`:\n{h}"));
        // The flag's entry: up to the next flag.
        let entry = &h[at..];
        let entry = &entry[..entry[3..].find("\n  -").map_or(entry.len(), |e| e + 3)];
        assert!(entry.contains("Output: "), "{c}: {entry}");
        assert!(
            entry.contains("aliases: --out") || entry.contains("alias: --out"),
            "{c}: {entry}"
        );
        assert!(
            entry.contains("[default: ") || entry.contains("nothing is written without it"),
            "{c}: {entry}"
        );
        seen += 1;
    }
    assert_eq!(seen, 9);
}

/// The nodal displacements `simulate` wrote (`displacements.csv`: node,ux,uy,uz), by row.
fn displacements(dir: &Path) -> Vec<[f64; 3]> {
    let t = std::fs::read_to_string(dir.join("displacements.csv")).unwrap();
    t.lines()
        .skip(1)
        .map(|l| {
            let f: Vec<f64> = l.split(',').skip(1).map(|v| v.parse().unwrap()).collect();
            [f[0], f[1], f[2]]
        })
        .collect()
}

/// A `fit.json` of the motion example's mesh, homogeneous E = 50 kPa, ν = 0.3, naming `runs` as
/// the datasets it was fitted on.
fn example_fit(runs: &[&Path]) -> String {
    let ds = palpate_motion::dataset::load(&repo().join("models/motion-example")).unwrap();
    let (e, nu) = (50e3, 0.3);
    serde_json::json!({
        "format": palpate_motion::fitted::FORMAT,
        "datasets": runs.iter().map(|r| r.display().to_string()).collect::<Vec<_>>(),
        "nodes": ds.mesh.nodes.len(),
        "tets": ds.mesh.tets.len(),
        "lame_lambda_pa": [e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))],
        "shear_modulus_pa": [e / (2.0 * (1.0 + nu))],
        "viscosity_pa_s_h": [6.0],
        "power_law_index": [1.3],
        "density_kg_m3": [47.0],
        "poisson_ratio_fixed": nu,
        "fitted": ["mu"],
        "thesis_lambda_f_alpha_g_pa": [],
        "rms_marker_m": 0.0,
        "rms_force_n": 0.0,
        "evaluations": 0,
        "runs": [],
    })
    .to_string()
}

/// `--model` is told by content, not by name: `simulate` and `haptic` play a `.palp` or a
/// `fit.json` (exported in memory on the mesh and clamps of a run it was fitted on), each saying
/// which it read; the fit plays as the same homogeneous material given by `--mesh --young
/// --poisson --clamps`. `validate` needs the fit and refuses a `.palp` naming the file, what it
/// is and what it needs; a fit whose runs are nowhere is refused naming them.
#[test]
fn model_takes_a_palp_or_a_fit_json_and_says_which_it_read() {
    let dir = tempfile::tempdir().unwrap();
    let example = repo().join("models/motion-example");
    // Names that say nothing of the kind: the content decides.
    let fit = dir.path().join("fit.model");
    std::fs::write(&fit, example_fit(&[&example])).unwrap();
    let simulate = |model: &[&dyn AsRef<std::ffi::OsStr>], out: &str| {
        let mut c = palpate();
        c.arg("simulate");
        for a in model {
            c.arg(a);
        }
        c.args(["--contact", "0.01,0.04,0.02", "--force", "0,0,-0.1", "-o"])
            .arg(dir.path().join(out))
            .env_remove("RUST_LOG")
            .output()
            .unwrap()
    };
    let from_fit = simulate(&[&"--model", &fit], "from-fit");
    assert_succeeded(&from_fit);
    let err = text(&from_fit.stderr);
    assert!(
        err.contains("read as a fitted motion model (fit.json)")
            && err.contains("exported for the runtime on the mesh and clamps of"),
        "{err}"
    );
    let mesh = example.join("mesh.msh");
    let from_mesh = simulate(
        &[
            &"--mesh",
            &mesh,
            &"--young",
            &"50000",
            &"--poisson",
            &"0.3",
            &"--clamps",
            &"front",
        ],
        "from-mesh",
    );
    assert_succeeded(&from_mesh);
    let (a, b) = (
        displacements(&dir.path().join("from-fit")),
        displacements(&dir.path().join("from-mesh")),
    );
    assert_eq!(a.len(), b.len());
    let norm = |u: &[f64; 3]| u.iter().map(|v| v * v).sum::<f64>().sqrt();
    let peak = b.iter().map(norm).fold(0.0, f64::max);
    let worst = a
        .iter()
        .zip(&b)
        .map(|(x, y)| norm(&[x[0] - y[0], x[1] - y[1], x[2] - y[2]]))
        .fold(0.0, f64::max);
    // The same material on the same mesh and clamps, up to the runtime's f32 parameters and its
    // CG tolerance (1e-6); another mesh or clamp would differ by the whole field.
    assert!(
        peak > 1e-6 && worst < 1e-4 * peak,
        "peak {peak:e} m, worst difference {worst:e} m"
    );

    // The same fit written as a .palp (named like a JSON file) plays the same and says so.
    let ds = palpate_motion::dataset::load(&example).unwrap();
    let fitted: palpate_motion::fitted::FittedModel =
        serde_json::from_str(&std::fs::read_to_string(&fit).unwrap()).unwrap();
    let palp = dir.path().join("model.json");
    palpate_motion::export::model_buffers(
        &ds.mesh,
        &ds.model,
        &fitted.material().unwrap(),
        &palpate_fem::export::ProvenanceInfo {
            tool: "test".into(),
            source: "test".into(),
            notes: String::new(),
        },
    )
    .unwrap()
    .write(&palp)
    .unwrap();
    let from_palp = simulate(&[&"--model", &palp], "from-palp");
    assert_succeeded(&from_palp);
    let err = text(&from_palp.stderr);
    assert!(
        err.contains("read as a palpate runtime model (.palp)"),
        "{err}"
    );
    assert_eq!(displacements(&dir.path().join("from-palp")), a);

    // haptic reads the fit and exports it before it opens the port.
    let o = palpate()
        .args(["haptic", "--port", "/dev/ttyNOSUCH0", "--model"])
        .arg(&fit)
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    let err = refused(&o);
    assert!(
        err.contains("read as a fitted motion model (fit.json)")
            && err.contains("exported for the runtime")
            && err.contains("ttyNOSUCH0"),
        "{err}"
    );

    // validate needs the fit: it reads it, and refuses the .palp by name.
    let validate = |model: &Path| {
        palpate()
            .args(["validate", "--model"])
            .arg(model)
            .arg(&example)
            .env_remove("RUST_LOG")
            .output()
            .unwrap()
    };
    let o = validate(&fit);
    assert_succeeded(&o);
    assert!(
        text(&o.stderr).contains("read as a fitted motion model (fit.json)"),
        "{}",
        text(&o.stderr)
    );
    let err = refused(&validate(&palp));
    assert!(
        err.contains(&format!(
            "{} is a palpate runtime model (.palp), but `palpate validate --model` needs a \
             fitted motion model (fit.json)",
            palp.display()
        )),
        "{err}"
    );

    // A fit whose runs are nowhere cannot be played: the refusal names the fit and the runs.
    let lost = dir.path().join("lost.json");
    std::fs::write(&lost, example_fit(&[Path::new("no-such-run")])).unwrap();
    let err = refused(&simulate(&[&"--model", &lost], "lost"));
    assert!(
        err.contains(&lost.display().to_string()) && err.contains("no-such-run: not found"),
        "{err}"
    );
    assert!(!dir.path().join("lost").exists());
}

/// `palpate import c3d` writes where `-o`, `--output` or `--out` says, and without it into its
/// default folder, as every command that exists to write files does; its numeric flags name
/// their units in the help.
#[test]
fn import_c3d_takes_the_output_rule_and_names_its_units() {
    let help = text(
        &palpate()
            .args(["import", "c3d", "--help"])
            .output()
            .unwrap()
            .stdout,
    );
    for part in [
        "--density <KG_M3>",
        "--gravity <GX,GY,GZ>",
        "--release-threshold <M>",
        "[default: motion-dataset]",
    ] {
        assert!(help.contains(part), "{part}: {help}");
    }
    let dir = tempfile::tempdir().unwrap();
    let o = common::import_beam("beam_gravity_V2_a.c3d")
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert_succeeded(&o);
    assert!(dir.path().join("motion-dataset/dataset.toml").is_file());
    let o = common::import_beam("beam_gravity_V2_a.c3d")
        .arg("--out")
        .arg(dir.path().join("b"))
        .output()
        .unwrap();
    assert_succeeded(&o);
    assert_eq!(
        std::fs::read_to_string(dir.path().join("b/trajectories.csv")).unwrap(),
        std::fs::read_to_string(dir.path().join("motion-dataset/trajectories.csv")).unwrap()
    );
}
