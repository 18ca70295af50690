//! The runs diagnosis' mesh-convergence check on the measured beam: its two fitted captures,
//! imported as a user does, fitted at rest with linear and quadratic elements on the coarse mesh.
//! Linear tetrahedra lock at ν = 0.49, so the check must find the modulus not converged, with the
//! figures `docs/results/beam/convergence.md` measured (E 133.3 kPa P1, 256.3 kPa P2); and a run
//! whose markers move more in the window than the fit's error allows has no rest state to fit.
//! `palpate fit-motion --mesh-convergence` prints the same verdict.

use crate::common::{self, assert_succeeded};
use palpate_diagnose::convergence::{check, MeshConvergence};

#[test]
fn the_beams_modulus_on_linear_tets_is_the_meshs() {
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
}
