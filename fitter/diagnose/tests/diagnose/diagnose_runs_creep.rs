//! The runs diagnosis' creep candidate on the example bar hung with a weight: runs recorded from a
//! body whose elastic stress relaxes (one generalised-Maxwell branch, g = 0.5, τ = 0.05 s) must
//! be found out by it, the branch recovered; runs recorded from the same body without the branch
//! must not be given one.

use crate::diagnose_runs::run_of;
use palpate_diagnose::runs::{diagnose_runs, Effect, RunsDiagnosis, RunsOptions};
use palpate_motion::dataset::MotionDataset;
use palpate_motion::model::{Material, ParamKind};

/// The truth of the runs test (Lamé pair at Poisson's ratio 1/3, Newtonian damping), with a
/// creep branch of relaxed fraction `g` (none at 0) and time 0.05 s.
fn truth(g: f64) -> impl Fn(&MotionDataset) -> Material {
    move |ds| {
        let mut m = Material::uniform(ds.model.tets.len(), 2.0e4, 1.0e4, 6.0, 1.0, 47.0);
        m.set_uniform(ParamKind::CreepFraction, g);
        m.set_uniform(ParamKind::CreepTime, 0.05);
        m
    }
}

/// A run with a 5 g weight (heavier than the bar), markers only: a capture's data (the
/// branch's stress is not in the clamp's reaction force, so force records are refused with it).
fn run(name: &str, seed: u64, t: &dyn Fn(&MotionDataset) -> Material) -> (String, MotionDataset) {
    let (name, mut ds) = run_of(name, Some(0.005), seed, 0, t);
    ds.obs.forces.clear();
    (name, ds)
}

/// Two fitted and two held-out runs ([`run`]), diagnosed with the candidates that can be in
/// such a body's model: damping, the weight's inertia and creep.
fn diagnose(g: f64) -> RunsDiagnosis {
    let t = truth(g);
    let fit = vec![run("creep-a", 1, &t), run("creep-b", 2, &t)];
    let held = vec![run("creep-c", 3, &t), run("creep-d", 4, &t)];
    let options = RunsOptions {
        poisson: 1.0 / 3.0,
        start_mu: 2.0e4,
        candidates: vec![Effect::Damping, Effect::HangingInertia, Effect::Creep],
        ..Default::default()
    };
    let d = diagnose_runs(&fit, &held, &options, &|m| eprintln!("{m}")).unwrap();
    eprintln!(
        "g = {g}: adopted {:?}; held-out RMS {:.2e} -> {:.2e} m; creep {:?}",
        d.adopted, d.heldout_rms_m.0, d.heldout_rms_m.1, d.model.creep
    );
    d
}

#[test]
fn names_creep_in_a_body_whose_stress_relaxes() {
    let d = diagnose(0.5);
    assert!(d.adopted.contains(&Effect::Creep), "{:?}", d.adopted);
    let c = d
        .model
        .creep
        .as_ref()
        .expect("the record carries the branch");
    // Recovered to 0.3 % (g = 0.5014) and 0.5 % (τ = 0.04976 s) under the 20 µm marker noise
    // (measured); 2 % is the margin.
    let (g, tau) = (c.fraction[0], c.time_s[0]);
    assert!((g / 0.5 - 1.0).abs() < 0.02, "g = {g}");
    assert!((tau / 0.05 - 1.0).abs() < 0.02, "τ = {tau}");
    // The record `palpate validate` reads gives the branch back.
    let back = d.model.material().unwrap();
    assert_eq!(back.get(ParamKind::CreepFraction, 0), g);
    let md = palpate_diagnose::runs::report::markdown(&d);
    assert!(md.contains("**Creep.**"), "{md}");
}

#[test]
fn gives_no_creep_to_a_body_without_it() {
    let d = diagnose(0.0);
    assert!(!d.adopted.contains(&Effect::Creep), "{:?}", d.adopted);
    assert!(d.model.creep.is_none());
}
