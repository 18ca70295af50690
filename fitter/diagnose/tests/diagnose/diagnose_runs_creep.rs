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
    diagnose_with(&truth(g), g, RunsOptions::default())
}

/// [`diagnose`] of runs recorded from `t` (relaxed fraction `g`, for the log) with `options`'
/// screen.
fn diagnose_with(t: &dyn Fn(&MotionDataset) -> Material, g: f64, o: RunsOptions) -> RunsDiagnosis {
    diagnose_logged(t, g, o).0
}

/// [`diagnose_with`], with the diagnosis' log lines.
fn diagnose_logged(
    t: &dyn Fn(&MotionDataset) -> Material,
    g: f64,
    o: RunsOptions,
) -> (RunsDiagnosis, Vec<String>) {
    let fit = vec![run("creep-a", 1, t), run("creep-b", 2, t)];
    let held = vec![run("creep-c", 3, t), run("creep-d", 4, t)];
    let options = RunsOptions {
        poisson: 1.0 / 3.0,
        start_mu: 2.0e4,
        candidates: vec![Effect::Damping, Effect::HangingInertia, Effect::Creep],
        ..o
    };
    let lines = std::sync::Mutex::new(Vec::new());
    let d = diagnose_runs(&fit, &held, &options, &|m| {
        eprintln!("{m}");
        lines.lock().unwrap().push(m.to_string());
    })
    .unwrap();
    eprintln!(
        "g = {g}: adopted {:?}; held-out RMS {:.2e} -> {:.2e} m; creep {:?}",
        d.adopted, d.heldout_rms_m.0, d.heldout_rms_m.1, d.model.creep
    );
    (d, lines.into_inner().unwrap())
}

/// The relaxed fraction g each creep fit started from, and whether it was the fit screen's step.
fn creep_starts(lines: &[String]) -> Vec<(f64, bool)> {
    lines
        .iter()
        .filter_map(|l| {
            let rest = l.split("creep starts at g = ").nth(1)?;
            let g = rest.split_whitespace().next()?.parse().ok()?;
            Some((g, rest.contains("(the fit screen's step)")))
        })
        .collect()
}

#[test]
fn names_creep_in_a_body_whose_stress_relaxes() {
    let (d, lines) = diagnose_logged(&truth(0.5), 0.5, RunsOptions::default());
    // The fit that adopts the branch starts where the screen's Gauss–Newton step in g took it,
    // not at the default small branch (g = 0.05): a linearisation at g = 0 that points at the
    // truth's g = 0.5 within a factor of two.
    let starts = creep_starts(&lines);
    assert!(
        starts
            .iter()
            .any(|&(g, screened)| screened && (0.25..1.0).contains(&g)),
        "creep's starts (g, from the screen): {starts:?}"
    );
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

/// The creep trials of a diagnosis: (round, predicted ΔBIC, fitted ΔBIC, screened out).
fn creep_trials(d: &RunsDiagnosis) -> Vec<(usize, Option<f64>, f64, bool)> {
    d.trials
        .iter()
        .filter(|t| t.effect == Effect::Creep)
        .map(|t| (t.round, t.predicted_delta_bic, t.delta_bic, t.screened_out))
        .collect()
}

/// A small branch (g = 0.05) whose time is the one creep's fit starts from (a quarter of the
/// run), so that the screen's step in g with τ held is the linearisation of the truth: every
/// prediction is finite, and where creep gains most the prediction is a lower bound of the
/// fitted gain within 25 % of it (measured: −7,343 predicted, −8,837 fitted, in the round it is
/// adopted; what is left is the curvature in g and μ's refit).
#[test]
fn screen_predicts_a_small_creep_branch() {
    let g = 0.05;
    let t = move |ds: &MotionDataset| {
        let mut m = truth(g)(ds);
        let tau = 0.25 * ds.model.steps as f64 * ds.model.dt;
        m.set_uniform(ParamKind::CreepTime, tau);
        m
    };
    let d = diagnose_with(&t, g, RunsOptions::default());
    let trials = creep_trials(&d);
    eprintln!("creep trials (round, predicted, fitted, screened out): {trials:?}");
    assert!(
        trials.iter().all(|t| t.1.is_some_and(f64::is_finite)),
        "{trials:?}"
    );
    let best = trials
        .iter()
        .filter(|t| !t.3)
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .expect("creep fitted");
    let (predicted, fitted) = (best.1.unwrap(), best.2);
    let ratio = predicted / fitted;
    assert!(
        fitted < -10.0 && (0.75..1.0).contains(&ratio),
        "round {}: predicted ΔBIC {predicted}, fitted {fitted}",
        best.0
    );
}

/// Runs without creep: every creep prediction is finite, and once damping and the weight's
/// inertia are in the model (the last round creep is tried) the screen predicts that creep does
/// not pay for its two parameters (measured: +14.3 predicted; fitted, it came to +12.1), so it
/// is not fitted there. Before damping is adopted a relaxing stress is a loss too and creep is
/// predicted to pay (−4,278): there it is fitted, as it should be.
#[test]
fn screen_predicts_no_gain_from_creep_where_there_is_none() {
    let o = RunsOptions {
        screen_least: 1,
        ..Default::default()
    };
    let d = diagnose_with(&truth(0.0), 0.0, o);
    let trials = creep_trials(&d);
    eprintln!("creep trials (round, predicted, fitted, screened out): {trials:?}");
    assert!(!d.adopted.contains(&Effect::Creep), "{:?}", d.adopted);
    assert!(
        trials.iter().all(|t| t.1.is_some_and(f64::is_finite)),
        "{trials:?}"
    );
    let last = trials.last().expect("creep tried");
    assert!(
        last.1.is_some_and(|p| p > -10.0) && (last.3 || last.2 > -10.0),
        "{trials:?}"
    );
    assert!(
        trials.iter().any(|t| !t.3 && t.2 < -10.0),
        "creep is never fitted where it is predicted to pay: {trials:?}"
    );
}

/// Runs that weigh the clamp's reaction force beside the markers: a model with the branch cannot
/// predict that force (its evaluation is refused), so creep is not offered, the log says why, and
/// the diagnosis ends with a verdict on the others.
#[test]
fn runs_that_weigh_clamp_forces_are_not_offered_creep() {
    let t = truth(0.0);
    let fit = vec![run_of("forces-a", Some(0.005), 1, 0, &t)];
    let held = vec![run_of("forces-b", Some(0.005), 2, 0, &t)];
    assert!(fit[0].1.obs.forces.iter().flatten().any(Option::is_some));
    let options = RunsOptions {
        poisson: 1.0 / 3.0,
        start_mu: 2.0e4,
        candidates: vec![Effect::Damping, Effect::HangingInertia, Effect::Creep],
        ..Default::default()
    };
    let lines = std::cell::RefCell::new(Vec::<String>::new());
    let d = diagnose_runs(&fit, &held, &options, &|m| {
        eprintln!("{m}");
        lines.borrow_mut().push(m.to_string());
    })
    .unwrap();
    assert!(creep_trials(&d).is_empty(), "{:?}", creep_trials(&d));
    assert!(
        lines
            .borrow()
            .iter()
            .any(|l| l.starts_with("creep not offered") && l.contains("reaction force")),
        "the log does not say why creep is left out"
    );
    assert!(
        d.adopted.contains(&Effect::HangingInertia),
        "{:?}",
        d.adopted
    );
}

/// A body that rings, lightly damped (Newtonian viscosity 0.1 Pa·s, no branch): the creep fit is
/// held above the longest ring-down period measured in the fitted runs (the diagnosis records
/// it, the log says so), where a branch is relaxation slower than the ring-down and not a second
/// name for its damping; the damping is what is named.
#[test]
fn creep_is_held_above_the_ring_down_period() {
    let t = |ds: &MotionDataset| {
        let mut m = truth(0.0)(ds);
        m.set_uniform(ParamKind::Nu, 0.1);
        m
    };
    // Six times the example's length, so that the weight's swing rings down within the run.
    let ring = |name: &str, seed: u64| {
        let mut ds = crate::diagnose_runs::example();
        ds.model.steps *= 6;
        for cl in &mut ds.model.clamps {
            // Held where the example leaves them.
            let last = cl.poses[cl.poses.len() - 1];
            cl.poses.resize(ds.model.steps + 1, last);
        }
        ds.model.loads = vec![palpate_specimen::motion::hung_weight(&ds, 0.005).unwrap()];
        ds.obs = crate::support::record_late(&ds.model, &t(&ds), 2e-5, seed, 0, 4).unwrap();
        ds.obs.forces.clear();
        for l in &mut ds.model.loads {
            l.inertia = false;
        }
        (name.to_string(), ds)
    };
    let fit = vec![ring("ring-a", 1), ring("ring-b", 2)];
    let held = vec![ring("ring-c", 3), ring("ring-d", 4)];
    let options = RunsOptions {
        poisson: 1.0 / 3.0,
        start_mu: 2.0e4,
        candidates: vec![Effect::Damping, Effect::HangingInertia, Effect::Creep],
        ..RunsOptions::default()
    };
    let lines = std::cell::RefCell::new(Vec::new());
    let log = |m: &str| {
        eprintln!("{m}");
        lines.borrow_mut().push(m.to_string());
    };
    let d = diagnose_runs(&fit, &held, &options, &log).unwrap();
    let period = d
        .before
        .0
        .iter()
        .filter_map(|r| r.period_s.0)
        .reduce(f64::max)
        .expect("the runs ring");
    assert_eq!(d.creep_floor_s, Some(period));
    let held_above = format!("τ held above {period:.3} s");
    assert!(
        lines.borrow().iter().any(|l| l.contains(&held_above)),
        "no line says {held_above}"
    );
    assert!(d.adopted.contains(&Effect::Damping), "{:?}", d.adopted);
    assert!(!d.adopted.contains(&Effect::Creep), "{:?}", d.adopted);
}
