//! The runs diagnosis on runs whose truth is known: the bundled example bar (24 tets, shaken at
//! its clamped front face), four runs — two without and two with a weight hung from the top edge
//! of its back face whose mass moves with it — recorded from a damped truth with noise. Fitted on
//! one run of each kind, held out the other two: the diagnosis must name the damping — its
//! simplest model moving the weight with its nodes — and predict the held-out runs far better
//! than the simplest model; asked to find the weight's inertia as a candidate, it must name it
//! too. Without any hanging weight the inertia is neither in the model nor offered. Runs whose markers
//! were recorded a few steps out of step with the simulation's clock (a release instant misread,
//! a marker stream out of sync with the rig) must be found out by the time-offset candidate, each
//! run's offset recovered; runs in step must not be given one. A body that stiffens at larger
//! strains, hung with a light and a heavy weight, must be found out by the stiffening candidate.

use crate::support::record_late;
use palpate_diagnose::runs::{diagnose_runs, Effect, RunsDiagnosis, RunsOptions, ALL_EFFECTS};
use palpate_motion::dataset::{load, MotionDataset};
use palpate_motion::model::Material;

/// The bundled motion example's dataset (its own runs recorded by each test).
pub(crate) fn example() -> MotionDataset {
    load(&crate::support::example()).unwrap()
}

/// The truth: the example's Lamé pair (Poisson's ratio 1/3), Newtonian damping.
fn truth(ds: &MotionDataset) -> Material {
    Material::uniform(ds.model.tets.len(), 2.0e4, 1.0e4, 6.0, 1.0, 47.0)
}

/// A run of the example: with a weight of `mass` kg (moving with its nodes) if given.
fn run(name: &str, mass: Option<f64>, seed: u64) -> (String, MotionDataset) {
    run_late(name, mass, seed, 0)
}

/// [`run`] with its markers (and clamp forces) recorded `late` steps behind the simulation's
/// clock (negative: ahead), [`crate::support::record_late`].
fn run_late(name: &str, mass: Option<f64>, seed: u64, late: i64) -> (String, MotionDataset) {
    run_of(name, mass, seed, late, &|ds| truth(ds))
}

/// [`run_late`] recorded from the material `truth` gives.
pub(crate) fn run_of(
    name: &str,
    mass: Option<f64>,
    seed: u64,
    late: i64,
    truth: &dyn Fn(&MotionDataset) -> Material,
) -> (String, MotionDataset) {
    let mut ds = example();
    if let Some(m) = mass {
        ds.model.loads = vec![palpate_specimen::motion::hung_weight(&ds, m).unwrap()];
    }
    ds.obs = record_late(&ds.model, &truth(&ds), 2e-5, seed, late, 4).unwrap();
    // Declared with its mass, its inertia left to the diagnosis (`RunsOptions::weights_move`).
    for l in &mut ds.model.loads {
        l.inertia = false;
    }
    (name.to_string(), ds)
}

/// The final model predicts the held-out runs at least three times better than the simplest,
/// and recovers μ to 2 % (the truth is in the model class); returns the fitted μ.
fn assert_predicts_and_recovers_mu(d: &RunsDiagnosis) -> f64 {
    assert!(
        d.heldout_rms_m.1 < d.heldout_rms_m.0 / 3.0,
        "{:?}",
        d.heldout_rms_m
    );
    let mu = d.values[1].value;
    assert!((mu / 1.0e4 - 1.0).abs() < 0.02, "μ = {mu}");
    mu
}

fn options() -> RunsOptions {
    RunsOptions {
        poisson: 1.0 / 3.0,
        start_mu: 2.0e4,
        start_viscosity: None,
        ..Default::default()
    }
}

/// [`options`] with the weights' inertia among the candidates: the simplest model holds the
/// weights as forces only.
fn options_asking_the_inertia() -> RunsOptions {
    RunsOptions {
        candidates: ALL_EFFECTS.to_vec(),
        ..options()
    }
}

/// By default the simplest model moves a declared weight with its nodes: the diagnosis names
/// the damping alone, offers no inertia candidate, records the inertia for `palpate validate`,
/// predicts the held-out runs and recovers μ.
#[test]
fn the_simplest_model_moves_a_declared_weight() {
    let fit = vec![run("plain-a", None, 1), run("weight-a", Some(0.002), 2)];
    let held = vec![run("plain-b", None, 3), run("weight-b", Some(0.002), 4)];
    let d = diagnose_runs(&fit, &held, &options(), &|m| eprintln!("{m}")).unwrap();
    assert_eq!(d.adopted, vec![Effect::Damping], "{:?}", d.adopted);
    assert!(d.trials.iter().all(|t| t.effect != Effect::HangingInertia));
    assert!(d.model.hanging_inertia);
    let md = palpate_diagnose::runs::report::markdown(&d);
    assert!(
        md.contains("each hung weight moving with its nodes"),
        "{md}"
    );
    // The Newtonian law's viscosity in its own unit, its index held, not called a power law.
    assert!(
        md.contains("| viscosity (Newtonian) |") && md.contains(" Pa·s |"),
        "{md}"
    );
    assert!(!md.contains("viscosity (power law)"), "{md}");
    assert_predicts_and_recovers_mu(&d);
    // The final model's residuals are read from the fit's own simulations: each is the run
    // simulated afresh at the final material, run by run in order. To 10⁻⁴, not to the bit: a
    // simulation with sensitivities reaches each step's tolerance along other Newton iterates
    // (6·10⁻⁶ apart here); a run read as another, or a step late, is off by its whole size.
    let mat = d.model.material().unwrap();
    for ((name, ds), read) in fit
        .iter()
        .chain(&held)
        .zip(d.after.0.iter().chain(&d.after.1))
    {
        let mut ds = ds.clone();
        palpate_motion::fitted::set_hanging_inertia(&mut ds.model, true);
        let fresh = palpate_diagnose::runs::residual(name, &ds, &mat).unwrap();
        assert_eq!(read.run, fresh.run);
        assert!(
            (read.rms_m / fresh.rms_m - 1.0).abs() < 1e-4,
            "{name}: {} read, {} fresh",
            read.rms_m,
            fresh.rms_m
        );
        assert!((read.final_rms_m / fresh.final_rms_m - 1.0).abs() < 1e-4);
    }
}

#[test]
fn names_damping_and_the_hanging_weights_inertia_on_held_out_runs() {
    // The bar weighs 47 kg/m³ × its volume; the weight is comparable to it.
    let fit = vec![run("plain-a", None, 1), run("weight-a", Some(0.002), 2)];
    let held = vec![run("plain-b", None, 3), run("weight-b", Some(0.002), 4)];
    let o = options_asking_the_inertia();
    let d = diagnose_runs(&fit, &held, &o, &|m| eprintln!("{m}")).unwrap();
    eprintln!(
        "adopted {:?}; held-out RMS {:.2e} -> {:.2e} m",
        d.adopted, d.heldout_rms_m.0, d.heldout_rms_m.1
    );
    assert!(
        d.adopted.contains(&Effect::HangingInertia),
        "{:?}",
        d.adopted
    );
    assert!(d.adopted.contains(&Effect::Damping), "{:?}", d.adopted);
    // Held out at the fitted loads only, and the report says what that does not test.
    assert!(d.held_out_loads_beyond_fitted().is_empty());
    let md = palpate_diagnose::runs::report::markdown(&d);
    assert!(md.contains("not extrapolation to other loads"), "{md}");
    assert!(md.contains("hanging weights as forces only"), "{md}");
    // The parameters in plain numbers with their units (`shear modulus μ = 10.02 kPa`), never in
    // exponent notation (`1.00200e4 Pa`).
    let exponent = |l: &str| {
        l.as_bytes().windows(3).any(|w| {
            w[0].is_ascii_digit() && w[1] == b'e' && (w[2].is_ascii_digit() || w[2] == b'-')
        })
    };
    let parameters: Vec<&str> = md
        .lines()
        .skip_while(|l| !l.starts_with("## Parameters of the final model"))
        .filter(|l| l.starts_with('|') || l.starts_with("Elastic constants"))
        .collect();
    assert!(
        parameters.iter().any(|l| l.contains(" kPa")) && !parameters.iter().any(|l| exponent(l)),
        "{parameters:#?}"
    );
    // A Neo-Hookean truth: no stiffening, and none recorded.
    assert!(!d.adopted.contains(&Effect::Stiffening), "{:?}", d.adopted);
    assert!(d.model.stiffening.is_empty());
    // In step with the simulation: no run is given a time offset.
    assert!(!d.adopted.contains(&Effect::TimeOffset), "{:?}", d.adopted);
    assert!(!d.model.time_offset);
    let mu = assert_predicts_and_recovers_mu(&d);
    // The record `palpate validate` reads carries the adopted inertia.
    assert!(d.model.hanging_inertia);
    assert_eq!(d.model.runs.len(), 2);
    // fit.json and diagnosis.json: schema versions, units in the names, Lamé λ, μ and E, ν.
    let fit: serde_json::Value = serde_json::from_str(&d.model.to_json().unwrap()).unwrap();
    assert_eq!(fit["schema_version"], 2);
    assert!(fit["shear_modulus_pa"][0].as_f64().unwrap() > 0.0, "{fit}");
    assert!(fit.get("mu").is_none() && fit.get("runtime_lambda_alpha").is_none());
    let back: palpate_motion::fitted::FittedModel = serde_json::from_value(fit).unwrap();
    assert_eq!(back, d.model);
    let json: serde_json::Value =
        serde_json::from_str(&palpate_diagnose::runs::report::json_text(&d).unwrap()).unwrap();
    assert_eq!(json["schema_version"], 1);
    assert!((json["elastic"]["shear_modulus_pa"].as_f64().unwrap() / mu - 1.0).abs() < 1e-9);
    assert!(json["before"][1][0]["chi2_m2"].as_f64().is_some(), "{json}");
}

#[test]
fn without_a_hanging_weight_the_inertia_candidate_is_not_offered() {
    let fit = vec![run("plain-a", None, 1)];
    let held = vec![run("plain-b", None, 3)];
    let d = diagnose_runs(&fit, &held, &options_asking_the_inertia(), &|_| {}).unwrap();
    assert!(d.trials.iter().all(|t| t.effect != Effect::HangingInertia));
    assert!(!d.model.hanging_inertia);
    // Nor is it recorded where the simplest model would move a weight: there is none.
    let d = diagnose_runs(&fit, &held, &options(), &|_| {}).unwrap();
    assert!(!d.model.hanging_inertia);
    let md = palpate_diagnose::runs::report::markdown(&d);
    assert!(!md.contains("hung weight"), "{md}");
    // Runs on different meshes are refused.
    let mut other = run("other", None, 5);
    other.1.mesh.nodes[0][0] += 1e-3;
    let e = diagnose_runs(&fit, &[other], &options(), &|_| {}).unwrap_err();
    assert!(e.to_string().contains("mesh differs"), "{e}");
}

#[test]
fn finds_each_runs_time_offset_and_predicts_the_held_out_runs_at_theirs() {
    let late = [
        ("plain-a", 2i64),
        ("weight-a", -2),
        ("plain-b", 1),
        ("weight-b", -3),
    ];
    let mass = |name: &str| name.starts_with("weight").then_some(0.002);
    let make = |i: usize| run_late(late[i].0, mass(late[i].0), i as u64 + 1, late[i].1);
    let fit = vec![make(0), make(1)];
    let held = vec![make(2), make(3)];
    let d = diagnose_runs(&fit, &held, &options(), &|m| eprintln!("{m}")).unwrap();
    eprintln!(
        "adopted {:?}; held-out RMS {:.2e} -> {:.2e} m",
        d.adopted, d.heldout_rms_m.0, d.heldout_rms_m.1
    );
    assert!(d.adopted.contains(&Effect::TimeOffset), "{:?}", d.adopted);
    assert!(d.model.time_offset);
    // Every run's offset recovered to the step: the fitted runs' in the fit, the held-out runs'
    // by their own scan with the fitted material.
    let dt = fit[0].1.model.dt;
    for (r, (name, truth)) in d.after.0.iter().chain(&d.after.1).zip(late) {
        assert_eq!(r.run, name);
        assert_eq!(
            (r.time_offset_s / dt).round() as i64,
            truth,
            "{name}: {r:?}"
        );
    }
    for (f, (_, truth)) in d.model.runs.iter().zip(late) {
        assert_eq!((f.time_offset_s / dt).round() as i64, truth);
    }
    assert_predicts_and_recovers_mu(&d);
}

/// A run of the example hung with a weight of `mass` kg, recorded from [`truth`] with a
/// stiffening term c (Ī₁ − 3)² of c = 5 μ.
pub(crate) fn stiffening_run(name: &str, mass: f64, seed: u64) -> (String, MotionDataset) {
    let stiff = |ds: &MotionDataset| {
        let mut m = truth(ds);
        m.set_uniform(palpate_motion::model::ParamKind::Stiffening, 5.0e4);
        m
    };
    run_of(name, Some(mass), seed, 0, &stiff)
}

/// A body that stiffens at larger strains (a Yeoh-type c (Ī₁ − 3)² beside Neo-Hookean, c = 5 μ),
/// hung with a light and a heavy weight: the light run strains it little, the heavy one much, so
/// no single μ fits both. The diagnosis must name the stiffening and predict the held-out
/// repeats better with it.
#[test]
fn names_a_stiffening_material_from_runs_under_different_weights() {
    let make = stiffening_run;
    let fit = vec![make("light-a", 0.002, 1), make("heavy-a", 0.03, 2)];
    // The held-out repeats, and one run at a load no fitted run carries (15 g): extrapolation.
    let held = vec![
        make("light-b", 0.002, 3),
        make("heavy-b", 0.03, 4),
        make("middle-b", 0.015, 5),
    ];
    let d = diagnose_runs(&fit, &held, &options(), &|m| eprintln!("{m}")).unwrap();
    eprintln!(
        "adopted {:?}; held-out RMS {:.2e} -> {:.2e} m; c = {:?}",
        d.adopted,
        d.heldout_rms_m.0,
        d.heldout_rms_m.1,
        d.model.stiffening.first()
    );
    assert!(d.adopted.contains(&Effect::Stiffening), "{:?}", d.adopted);
    assert!(d.model.hanging_inertia);
    // c and μ recovered; the held-out repeats predicted at the noise (σ = 20 µm per coordinate:
    // 35 µm per marker position) — without the stiffening the same runs stay above 0.1 mm.
    let c = d.model.stiffening[0];
    assert!((c / 5.0e4 - 1.0).abs() < 0.02, "c = {c}");
    let mu = d.values[1].value;
    assert!((mu / 1.0e4 - 1.0).abs() < 0.02, "μ = {mu}");
    assert!(d.heldout_rms_m.1 < 45e-6, "{:?}", d.heldout_rms_m);
    // The report says which held-out load tests extrapolation: the 15 g run's alone.
    let beyond = d.held_out_loads_beyond_fitted();
    assert_eq!(beyond.len(), 1, "{beyond:?}");
    assert!(
        (beyond[0] / (0.015 * 9.81) - 1.0).abs() < 1e-9,
        "{beyond:?}"
    );
    let md = palpate_diagnose::runs::report::markdown(&d);
    assert!(md.contains("extrapolation in load"), "{md}");
    // fit.json carries c, and `palpate validate` reads it back into the material.
    let back = d.model.material().unwrap();
    assert_eq!(back.get(palpate_motion::model::ParamKind::Stiffening, 0), c);
}
