//! The motion diagnosis on data it did not make: small motion datasets from the independent
//! generator (`tests/generators/independent_motion.py`: a clamped foam cylinder shaken at its
//! clamp, with its own Neo-Hookean truth, Kelvin–Voigt damping, BDF2 integrator and meshes; no
//! palpate code), committed with their `truth.json` under `tests/data/independent-motion/` (the
//! README there gives each one's command). One is as the generator made it; in the other the
//! clamp's record lags the markers by two capture frames
//! (`tests/generators/record_clamps_late.py`), an effect the time-offset candidate is for. Each
//! is diagnosed as `palpate diagnose <dir>` does with its defaults, and what the truth supports
//! is asserted.

use palpate_diagnose::motion::{diagnose, MotionDiagnosis, MotionOptions};
use std::path::PathBuf;

fn folder(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("data/independent-motion")
        .join(name)
}

fn truth(name: &str) -> serde_json::Value {
    let path = folder(name).join("truth.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn run(name: &str) -> MotionDiagnosis {
    let dir = folder(name);
    let ds =
        palpate_motion::dataset::load(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    let r =
        diagnose(&ds, name, &MotionOptions::default(), &|m| eprintln!("{m}")).expect("diagnosis");
    eprintln!(
        "{name}: {}; adopted {:?}; RMS fitted {:.1} -> {:.1} µm, held out {:.1} -> {:.1} µm; \
         values {:?}",
        r.verdict(),
        r.adopted,
        1e6 * r.before.rms_fit,
        1e6 * r.after.rms_fit,
        1e6 * r.before.rms_held,
        1e6 * r.after.rms_held,
        r.after_values
    );
    r
}

/// The noise floor of the RMS marker error: σ√3 with the generator's σ per axis.
fn floor(t: &serde_json::Value) -> f64 {
    t["marker_noise_m"].as_f64().expect("marker_noise_m") * 3f64.sqrt()
}

/// What the dataset mesh leaves, asserted as the mesh's: the residual stays well above the
/// noise floor alone (the dataset's 312 tetrahedra are stiff in bending: the fits land μ at
/// 371–481 kPa against the truth's 533 kPa, λ anywhere from 0 to 515 kPa against 827 kPa), and
/// the final model refitted on its own null (the mesh refined once, noise-free) leaves as much:
/// the verdict widens its floor by that share, says how far above the noise alone the residual
/// stands, and that effects smaller than the mesh's error cannot be told from it. Measured with
/// the objective viscosity adopted (the truth's Kelvin–Voigt law): 1.22× the noise floor alone
/// fitted, 1.26× held out; the null's 144.5 µm fitted, 246.0 µm held out; against the widened
/// floor 1.01× (+0.6σ) fitted and 0.82× (−5.3σ) held out: the null's forecast of its last 22
/// steps drifts further than the data's (246.0 µm against the 164 µm the data hold above the
/// noise), so the held-out share over-states what the data leave — the widened held-out floor
/// errs towards "explained" here, and the verdict's wording (the ratio to the noise alone, and
/// that smaller effects cannot be told from the mesh's) is what stays true. Asserted: above 1.2× the floor alone (the margin a forecast at
/// the floor keeps in `palpate_diagnose`'s own motion tests), the mesh's share measured and
/// below the data's own residual, both checks within 1.1× of the widened floor, and the fitted
/// one not 3σ below it.
fn assert_the_mesh_leaves_the_rest(r: &MotionDiagnosis, floor: f64) {
    let verdict = r.verdict();
    assert!(
        r.after.rms_held > 1.2 * floor,
        "held out {:.1} µm against a floor of {:.1} µm: the mesh's share is gone, update this test",
        1e6 * r.after.rms_held,
        1e6 * floor
    );
    let share = r
        .mesh_floor
        .as_ref()
        .expect("the mesh's share of the residual measured");
    assert!(
        share.null_rms_fit > 0.0 && share.null_rms_fit < r.after.rms_fit,
        "{share:?} against {:.1} µm fitted",
        1e6 * r.after.rms_fit
    );
    for c in [&r.residual_check, &r.heldout_check] {
        assert!(
            c.discretisation_m > 0.0 && c.ratio < 1.1,
            "{verdict}: {c:?}"
        );
        assert!(c.ratio_noise > 1.2, "{verdict}: {c:?}");
    }
    // Not far below the widened floor on the fitted steps either: a share over-stated (the
    // refined mesh's difference extrapolated by Richardson's 4/3 put the check 3.1σ below it).
    let c = &r.residual_check;
    assert!(c.z > -3.0, "{verdict}: {c:?}");
    assert!(
        verdict.contains("widened by the mesh's remaining discretisation error")
            && verdict.contains("cannot be told from the mesh's"),
        "{verdict}"
    );
    assert!(!verdict.starts_with("clean"), "{verdict}");
}

/// The screen keeps its promises: each candidate fitted that the screen predicted to gain at
/// least the gate's threshold gains at least half the ΔBIC predicted, or comes within twice the
/// threshold of it. At the simplest fit of the late clamp record the current parameters' own
/// Gauss–Newton step promises ΔBIC −330.5 and does not simulate; with that promise in every
/// candidate's, the stiffening was predicted −706.9 for a fit that gains −200.7, and is now
/// predicted by its gain beyond that step, −293.3.
fn assert_the_screen_keeps_its_promises(r: &MotionDiagnosis) {
    let threshold = MotionOptions::default().bic_threshold;
    for round in &r.rounds {
        for t in round.trials.iter().filter(|t| t.fitted) {
            let Some(p) = t.predicted_delta_bic.filter(|p| *p < -threshold) else {
                continue;
            };
            assert!(
                t.delta_bic <= 0.5 * p || t.delta_bic <= p + 2.0 * threshold,
                "round {}: {} predicted ΔBIC {p:.1}, its fit gains {:.1}",
                round.round,
                t.candidate,
                t.delta_bic
            );
        }
    }
}

/// The clamp's record two capture frames (40 ms) late: the time offset is adopted first and
/// recovered to the step (measured −40.0 ms, asserted within half a capture frame of the
/// injected −40 ms), the forecast improves tenfold (measured 3,450.8 → 350.4 µm held out,
/// asserted below a fifth), viscosity follows (the truth is damped), and the residual left is
/// what the mesh leaves ([`assert_the_mesh_leaves_the_rest`]). The offset is fitted once: the
/// neighbours are predicted by one Gauss–Newton step each and not fitted (measured: 9 simulations
/// for the candidate; fitting each neighbour in full takes 25).
#[test]
fn independent_clamp_recorded_late_is_given_its_time_offset() {
    let name = "cylinder-s2-clamps-late-2";
    let t = truth(name);
    let r = run(name);
    let injected = t["injected"]["time_offset_s"].as_f64().expect("injected");
    let dt = t["dt"].as_f64().expect("dt");
    assert_eq!(
        r.adopted.first().map(String::as_str),
        Some("time-offset"),
        "{:?}",
        r.adopted
    );
    let offset = r
        .after_values
        .iter()
        .find(|v| v.name.starts_with("time offset"))
        .expect("a time offset in the values");
    assert!(
        (offset.value - injected).abs() <= 0.5 * dt,
        "fitted {} s, injected {injected} s",
        offset.value
    );
    assert!(
        r.after.rms_held < 0.2 * r.before.rms_held,
        "held out {:e} -> {:e} m",
        r.before.rms_held,
        r.after.rms_held
    );
    assert!(
        r.adopted.iter().any(|a| a.starts_with("viscosity")),
        "{:?}",
        r.adopted
    );
    let fitted = r.rounds[0]
        .trials
        .iter()
        .find(|t| t.candidate == "time-offset")
        .expect("the time offset tried in the first round");
    assert!(
        fitted.evaluations <= 12,
        "{} simulations for the time offset",
        fitted.evaluations
    );
    assert_the_mesh_leaves_the_rest(&r, floor(&t));
    assert_the_screen_keeps_its_promises(&r);
}

/// The same draw as generated: no time offset (the scan finds none), viscosity adopted (the
/// truth is damped at a 3.7 % ratio; measured: the objective law, 850.7 → 268.1 µm held out,
/// where the rest-gradient power law reaches 338.5 µm), and the rest the mesh's
/// ([`assert_the_mesh_leaves_the_rest`]).
#[test]
fn independent_cylinder_as_generated_is_given_its_damping_and_no_offset() {
    let name = "cylinder-s2";
    let t = truth(name);
    let r = run(name);
    assert!(
        !r.adopted.iter().any(|a| a == "time-offset"),
        "{:?}",
        r.adopted
    );
    assert!(
        r.adopted.iter().any(|a| a.starts_with("viscosity")),
        "{:?}",
        r.adopted
    );
    assert_the_mesh_leaves_the_rest(&r, floor(&t));
    assert_the_screen_keeps_its_promises(&r);
}

/// The step `ds` is simulated at, against one 4 times finer from the data's start estimate:
/// the markers' RMS difference at the capture's frames (m), and the step check's tolerance.
fn step_error_against_4x_finer(ds: &palpate_motion::dataset::MotionDataset) -> (f64, f64) {
    let e = ds
        .timestep
        .step_error
        .clone()
        .expect("measured")
        .expect("measured");
    let tol = e.tolerance_m.expect("marker_noise is declared");
    let mat = palpate_motion::start::initial_values(ds, None).material(ds);
    let (finer, _) = ds.model.resampled(&ds.obs, 4);
    let at = palpate_motion::refine::marker_paths(&ds.model, &mat).unwrap();
    let reference = palpate_motion::refine::marker_paths(&finer, &mat).unwrap();
    let k = ds.model.substeps;
    let (mut d2, mut n) = (0.0, 0);
    for s in 1..=ds.capture_steps() {
        for (p, q) in at[s * k - 1].iter().zip(&reference[4 * s * k - 1]) {
            d2 += (0..3).map(|j| (p[j] - q[j]).powi(2)).sum::<f64>();
            n += 1;
        }
    }
    ((d2 / n as f64).sqrt(), tol)
}

/// The generator's cylinder rings in modes its dominant period does not show. Under BDF2 the
/// period rule's 3 substeps leave a step error its declared noise would see, the loader takes
/// more, and the chosen step's error against one 4 times finer is within the tolerance. Read as
/// generated (no `scheme` key: the midpoint rule), the rule's 2 substeps are within it already:
/// the same check passes without raising the step.
#[test]
fn the_generators_cylinder_is_stepped_finer_than_its_period_asks() {
    use palpate_motion::timestep::Scheme;
    let src = folder("cylinder-s2");
    let dir = tempfile::tempdir().unwrap();
    for f in std::fs::read_dir(&src).unwrap() {
        let f = f.unwrap().path();
        std::fs::copy(&f, dir.path().join(f.file_name().unwrap())).unwrap();
    }
    let toml = dir.path().join("dataset.toml");
    let text = std::fs::read_to_string(&toml).unwrap();
    assert!(!text.contains("scheme"), "the generator names no scheme");
    std::fs::write(&toml, format!("scheme = \"bdf2\"\n{text}")).unwrap();
    let bdf2 = palpate_motion::dataset::load(dir.path()).unwrap();
    eprintln!("{}", bdf2.timestep.describe());
    let e = bdf2.timestep.step_error.clone().unwrap().unwrap();
    let tol = e.tolerance_m.expect("marker_noise is declared");
    assert!(e.first_error_m > tol && e.substeps > e.from_substeps);
    assert_eq!(bdf2.model.substeps, e.substeps);
    assert!(bdf2
        .timestep
        .describe()
        .contains("raised from the period rule's"));
    let (error, tol) = step_error_against_4x_finer(&bdf2);
    assert!(
        error <= tol,
        "BDF2: {error:e} m against 4× finer > {tol:e} m"
    );

    let midpoint =
        palpate_motion::dataset::load(&src).unwrap_or_else(|e| panic!("{}: {e}", src.display()));
    eprintln!("{}", midpoint.timestep.describe());
    assert_eq!(midpoint.model.scheme, Scheme::Midpoint);
    let e = midpoint.timestep.step_error.clone().unwrap().unwrap();
    assert_eq!(e.substeps, e.from_substeps, "not raised");
    assert!(midpoint.model.substeps < bdf2.model.substeps);
    let (error, tol) = step_error_against_4x_finer(&midpoint);
    assert!(
        error <= tol,
        "midpoint: {error:e} m against 4× finer > {tol:e} m"
    );
}
