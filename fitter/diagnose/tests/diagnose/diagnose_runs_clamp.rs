//! The runs diagnosis' clamp-compliance candidate on the example bar hung with a light and a
//! heavy weight: runs recorded from a body held by a clamp that gives (the elements at the clamp
//! softened as a whole to 0.3× the body's moduli) must be found out by it, the layer's give
//! recovered; runs recorded from the same body clamped rigidly must not be given one.

use crate::diagnose_runs::run_of;
use palpate_diagnose::runs::{diagnose_runs, Effect, RunsDiagnosis, RunsOptions};
use palpate_motion::dataset::MotionDataset;
use palpate_motion::model::{Material, Param, ParamKind};

/// The truth of the runs test (Lamé pair at Poisson's ratio 1/3, Newtonian damping), its clamp
/// layer at `give` times the body's moduli (1: a rigid clamp).
fn truth(give: f64) -> impl Fn(&MotionDataset) -> Material {
    move |ds| {
        let mut m = Material::uniform(ds.model.tets.len(), 2.0e4, 1.0e4, 6.0, 1.0, 47.0);
        if give != 1.0 {
            m.regions.push(ds.model.clamp_layer());
            m.scaled_regions.push(0);
            m.set(&[Param::in_region(ParamKind::Mu, 0)], &[give * 1.0e4]);
        }
        m
    }
}

/// Two fitted runs (a light and a heavy weight) and two held out (the same weights, other noise),
/// diagnosed with the candidates a soft root could be mistaken for: a stiffer or softer body
/// under the heavier weight (stiffening) beside the damping and the weights' inertia.
fn diagnose(give: f64) -> RunsDiagnosis {
    let t = truth(give);
    let fit = vec![
        run_of("light-a", Some(0.002), 1, 0, &t),
        run_of("heavy-a", Some(0.006), 2, 0, &t),
    ];
    let held = vec![
        run_of("light-b", Some(0.002), 3, 0, &t),
        run_of("heavy-b", Some(0.006), 4, 0, &t),
    ];
    let options = RunsOptions {
        poisson: 1.0 / 3.0,
        start_mu: 2.0e4,
        candidates: vec![
            Effect::Damping,
            Effect::HangingInertia,
            Effect::Stiffening,
            Effect::ClampCompliance,
        ],
        ..Default::default()
    };
    let d = diagnose_runs(&fit, &held, &options, &|m| eprintln!("{m}")).unwrap();
    eprintln!(
        "give {give}: adopted {:?}; held-out RMS {:.2e} -> {:.2e} m; layer {:?}",
        d.adopted, d.heldout_rms_m.0, d.heldout_rms_m.1, d.clamp_layer
    );
    d
}

#[test]
fn names_a_clamp_that_gives() {
    let d = diagnose(0.3);
    assert!(
        d.adopted.contains(&Effect::ClampCompliance),
        "{:?}",
        d.adopted
    );
    assert!(!d.adopted.contains(&Effect::Stiffening), "{:?}", d.adopted);
    let layer = d
        .clamp_layer
        .as_ref()
        .expect("the report carries the layer");
    let give = layer.mu / layer.body_mu;
    assert!((give / 0.3 - 1.0).abs() < 0.05, "give {give}");
    assert!(
        (layer.body_mu / 1.0e4 - 1.0).abs() < 0.02,
        "μ {}",
        layer.body_mu
    );
    // The record `palpate validate` reads carries the softened layer element by element.
    let back = d.model.material().unwrap();
    let soft = back.values[ParamKind::Mu as usize]
        .iter()
        .filter(|&&m| m < 0.5e4)
        .count();
    assert_eq!(soft, layer.elements);
    let md = palpate_diagnose::runs::report::markdown(&d);
    assert!(md.contains("**The clamp gives.**"), "{md}");
}

#[test]
fn gives_no_clamp_compliance_to_a_rigid_clamp() {
    let d = diagnose(1.0);
    assert!(
        !d.adopted.contains(&Effect::ClampCompliance),
        "{:?}",
        d.adopted
    );
    assert!(d.clamp_layer.is_none());
}
