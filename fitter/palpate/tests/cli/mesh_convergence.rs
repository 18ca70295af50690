//! The runs diagnosis' mesh-convergence check on the measured beam: its two fitted captures,
//! imported as a user does, fitted at rest with linear and quadratic elements on the coarse mesh.
//! Linear tetrahedra lock at ν = 0.49, so the check must find the modulus not converged, with the
//! figures `docs/results/beam/convergence.md` measured (E 133.3 kPa P1, 256.3 kPa P2); and a run
//! whose markers move more in the window than the fit's error allows has no rest state to fit.
//! `palpate fit-motion --mesh-convergence` prints the same verdict. With it recorded,
//! `palpate validate` carries the fitted material to the beam's finer mesh.

use crate::common::{self, assert_succeeded};
use palpate_diagnose::convergence::{check, MeshConvergence};

#[test]
fn the_beams_modulus_on_linear_tets_is_the_meshs_and_carries_to_a_finer_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let mut fit = Vec::new();
    for (run, hang) in [
        ("gravity_V2_a", None),
        ("load52_V2_a", Some("0.052@free_end")),
    ] {
        let out = dir.path().join(run);
        let mut c = common::import_beam(&format!("beam_{run}.c3d"));
        if let Some(h) = hang {
            c.args(["--hang", h]);
        }
        assert_succeeded(&c.arg("-o").arg(&out).output().unwrap());
        fit.push((
            run.to_string(),
            palpate_motion::dataset::load(&out).unwrap(),
        ));
    }
    let fit: Vec<(&str, &palpate_motion::dataset::MotionDataset)> =
        fit.iter().map(|(n, d)| (n.as_str(), d)).collect();
    let nu = 0.49;
    let mu = 133e3 / (2.0 * (1.0 + nu));
    // The markers settle to ≈ 0.1 mm of scatter; a fit 1 µm off would call them moving.
    let strict = check(&fit, nu, mu, 1e-6, &|_| {});
    match &strict {
        MeshConvergence::Skipped { reason } => assert!(reason.contains("still move"), "{reason}"),
        c => panic!("checked against a 1 µm fit: {c:?}"),
    }
    let c = check(&fit, nu, mu, 0.5e-3, &|l| eprintln!("{l}"));
    let MeshConvergence::Checked {
        linear, quadratic, ..
    } = &c
    else {
        panic!("not checked: {c:?}");
    };
    eprintln!(
        "E P1 {:.1} kPa, P2 {:.1} kPa",
        linear.young_pa / 1e3,
        quadratic.young_pa / 1e3
    );
    assert!((linear.young_pa / 133.3e3 - 1.0).abs() < 0.03, "{linear:?}");
    assert!(
        (quadratic.young_pa / 256.3e3 - 1.0).abs() < 0.03,
        "{quadratic:?}"
    );
    assert_eq!(c.converged(), Some(false));
    assert!(c.difference().unwrap() > 0.5, "{c:?}");
    // The same check from the command line, after an equilibria fit of the two runs.
    let out = common::palpate()
        .args(["fit-motion"])
        .arg(dir.path().join("gravity_V2_a"))
        .arg(dir.path().join("load52_V2_a"))
        .args(["--equilibria", "--poisson", "0.49", "--mesh-convergence"])
        .output()
        .unwrap();
    assert_succeeded(&out);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let line = stdout
        .lines()
        .find(|l| l.starts_with("mesh convergence: E"))
        .unwrap_or_else(|| panic!("no convergence line in {stdout}"));
    assert!(line.contains("not converged"), "{line}");

    // A model without the converged modulus is refused on another mesh, and says how to get it.
    let beam = common::repo().join("models/silicone-beam");
    let fine = dir.path().join("gravity_V2_b-fine");
    let mut import = common::palpate();
    import
        .args(["import", "c3d"])
        .arg(beam.join("beam_gravity_V2_b.c3d"))
        .arg("--mesh")
        .arg(beam.join("beam.msh"))
        .arg("--places")
        .arg(beam.join("marker-places.csv"))
        .args([
            "--clamps",
            "clamp",
            "--gravity=-9.81,0,0",
            "--density",
            "1070",
            "-o",
        ])
        .arg(&fine);
    assert_succeeded(&import.output().unwrap());
    let shipped = beam.join("fit.json");
    let out = common::palpate()
        .args(["-q", "validate", "--model"])
        .arg(&shipped)
        .arg(&fine)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--mesh-convergence"), "{err}");
    // With the check's outcome recorded (what `diagnose` and `fit-motion --mesh-convergence`
    // write), the shipped model on the 716-tet mesh predicts the run on the 2,600-tet one:
    // measured 0.25 mm RMS at rest (0.51 mm over the trajectory), where its moduli taken as
    // they are leave 0.88 mm (1.20 mm).
    let mut record: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&shipped).unwrap()).unwrap();
    record["converged"] = serde_json::to_value(c.converged_modulus().unwrap()).unwrap();
    let with = dir.path().join("fit-converged.json");
    std::fs::write(&with, record.to_string()).unwrap();
    let out = common::palpate()
        .args(["-q", "validate", "--model"])
        .arg(&with)
        .arg(&fine)
        .output()
        .unwrap();
    assert_succeeded(&out);
    let v = common::last_json(&out);
    let scale = v["carried"]["scale"].as_f64().expect("carried");
    // The finer mesh locks less: its linear modulus of the same material is larger.
    assert!((1.05..1.35).contains(&scale), "{v}");
    let rest = v["final_rms_m"].as_f64().unwrap();
    assert!(rest < 0.4e-3, "rest RMS {rest} m: {v}");
}

/// `fit-motion --mesh-convergence` on the example bar (shaken at its base, so no rest state to
/// check the modulus on, said so) refits the motion on quadratic elements and prints every fitted
/// parameter beside the linear one with a verdict. The example's data were made on its own
/// coarse linear mesh, so the quadratic modulus must come out well above the linear one.
#[test]
fn fit_motion_refits_the_motion_on_quadratic_elements() {
    let out = common::palpate()
        .arg("fit-motion")
        .arg(common::repo().join("models/motion-example"))
        .args(["--params", "mu,viscosity", "--poisson", "0.1667"])
        .args(["--max-iterations", "10", "--mesh-convergence"])
        .output()
        .unwrap();
    assert_succeeded(&out);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let section = stdout
        .split("## Mesh convergence of the motion")
        .nth(1)
        .unwrap_or_else(|| panic!("no motion convergence section in {stdout}"));
    assert!(stdout.contains("mesh convergence not checked"), "{stdout}");
    let row = section
        .lines()
        .find(|l| l.starts_with("| mu |"))
        .unwrap_or_else(|| panic!("no μ row in {section}"));
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    let number = |s: &str| s.split_whitespace().next().unwrap().parse::<f64>().unwrap();
    let (linear, quadratic) = (number(cells[2]), number(cells[3]));
    assert!(quadratic > 1.5 * linear, "{row}");
    assert!(section.contains("| viscosity |"), "{section}");
    assert!(
        section.contains("**Not converged**") || section.contains("**Not determined**"),
        "{section}"
    );
}
