//! The viscosity effect: the specimen generator's visco-elastic strip (Real2Sim forward
//! model — Neo-Hookean + Newtonian viscosity, BDF2 — in a simulated tensile tester) is written as
//! tension-test curves in the real VHB records' format; `palpate diagnose` reads them as a user's
//! record would be read and must name viscosity first. The same strip without viscosity (τ = 0)
//! must not adopt viscosity: its loading and unloading curves coincide.

use palpate_diagnose::curve::{diagnose_path, CurveOptions};
use palpate_specimen::viscous::{generate_viscous, ViscousOptions};

fn diagnose(tau: f64, seed: u64) -> Vec<String> {
    let s = generate_viscous(&ViscousOptions {
        tau,
        seed,
        ..Default::default()
    })
    .expect("specimen");
    let dir = std::env::temp_dir().join(format!(
        "palpate-viscous-{}-{tau}-{seed}",
        std::process::id()
    ));
    s.write(&dir).expect("write");
    let mut d = diagnose_path(&dir, &CurveOptions::default(), &mut |_| {}).expect("diagnose");
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(d.len(), 1, "the two rates are one dataset");
    let d = d.remove(0);
    eprintln!(
        "τ = {tau} s, seed {seed}: adopted {:?}; RMS {:.4} → {:.4} N fitted, held out {:.4} → {:.4} N",
        d.adopted, d.before.fitted_rms, d.after.fitted_rms, d.before.heldout_rms, d.after.heldout_rms
    );
    // Whatever is adopted must have lowered the held-out error.
    assert!(d.after.heldout_rms <= d.before.heldout_rms);
    d.adopted
}

#[test]
fn viscous_specimen_is_diagnosed_as_viscous() {
    for seed in [1, 2] {
        let adopted = diagnose(2.0, seed);
        assert_eq!(
            adopted.first().map(String::as_str),
            Some("viscosity"),
            "seed {seed}: adopted {adopted:?}"
        );
    }
}

#[test]
fn elastic_strip_adopts_no_viscosity() {
    let adopted = diagnose(0.0, 1);
    assert!(
        !adopted.iter().any(|a| a == "viscosity"),
        "adopted {adopted:?}"
    );
}
