//! `palpate export`: a fitted material as a runtime model for a mesh, the runtime's parameters
//! matched to the material on quadratic elements; refused, saying what is missing, for a fit
//! that never measured its material and for a clamp the mesh does not have.

use crate::common::{self, assert_succeeded, refused, text};

/// The beam's diagnosed material (`docs/results/beam/diagnosis/fit.json`, which records its
/// modulus on quadratic elements) exported on the beam's own coarse mesh: the table printed,
/// the per-element design exported, its error on the held-out presses below the fit's own
/// moduli (3.6 % against 9.2 %, measured), and the model readable by `palpate info`.
#[test]
fn a_diagnosed_material_is_exported_matched_to_its_quadratic_modulus() {
    let dir = tempfile::tempdir().unwrap();
    let palp = dir.path().join("beam.palp");
    let repo = common::repo();
    let o = common::palpate()
        .args(["export", "--model"])
        .arg(repo.join("docs/results/beam/diagnosis/fit.json"))
        .arg("--mesh")
        .arg(repo.join("models/silicone-beam/beam-coarse.msh"))
        .args(["--clamps", "clamp", "-o"])
        .arg(&palp)
        .output()
        .unwrap();
    assert_succeeded(&o);
    let out = text(&o.stdout);
    let row = |design: &str| -> Vec<f64> {
        let line = out
            .lines()
            .find(|l| l.starts_with(&format!("| {design}")))
            .unwrap_or_else(|| panic!("no row {design:?} in\n{out}"));
        line.split('|')
            .filter_map(|c| c.trim().trim_end_matches(" %").parse::<f64>().ok())
            .collect()
    };
    // Columns: mean E (kPa), mean ν, fitting, held-out (%), largest held-out error (mm).
    let own = row("as fitted");
    let exported = row("per element (exported)");
    assert!(exported[3] < 0.6 * own[3], "{out}");
    let info = common::palpate().arg("info").arg(&palp).output().unwrap();
    assert_succeeded(&info);
    assert!(
        text(&info.stdout).contains("held-out presses"),
        "{}",
        text(&info.stdout)
    );
}

#[test]
fn export_refuses_a_fit_without_its_material_and_a_clamp_the_mesh_lacks() {
    let dir = tempfile::tempdir().unwrap();
    let repo = common::repo();
    let mesh = repo.join("models/silicone-beam/beam-coarse.msh");
    // The shipped four-run fit records no modulus on quadratic elements.
    let o = common::palpate()
        .args(["export", "--model"])
        .arg(repo.join("models/silicone-beam/fit.json"))
        .arg("--mesh")
        .arg(&mesh)
        .args(["--clamps", "clamp", "-o"])
        .arg(dir.path().join("a.palp"))
        .output()
        .unwrap();
    let err = refused(&o);
    assert!(err.contains("--mesh-convergence"), "{err}");
    let o = common::palpate()
        .args(["export", "--model"])
        .arg(repo.join("docs/results/beam/diagnosis/fit.json"))
        .arg("--mesh")
        .arg(&mesh)
        .args(["--clamps", "wall", "-o"])
        .arg(dir.path().join("b.palp"))
        .output()
        .unwrap();
    let err = refused(&o);
    assert!(err.contains("\"wall\"") && err.contains("clamp"), "{err}");
    assert!(!dir.path().join("a.palp").exists() && !dir.path().join("b.palp").exists());
}
