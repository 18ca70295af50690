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

/// A known miss, asserted as one: the residual left is well above the noise floor, and the
/// verdict says so instead of calling the data explained. Palpate's library has no candidate for
/// what is left: the truth's Kelvin–Voigt damping acts on the Green-strain rate (palpate's
/// viscosity: a power law on the velocity gradient), and the dataset's 312 tetrahedra are stiff
/// in bending (the fits land μ at 387–481 kPa against the truth's 533 kPa, λ anywhere from 0 to
/// 414 kPa against 827 kPa). Measured on both datasets: held out 1.59–1.65× the floor, the
/// verdict "more is missing than the library explains" on the held-out forecast; asserted above
/// 1.2× the floor (the margin a forecast at the floor keeps in `palpate_diagnose`'s own motion
/// tests).
fn assert_honest_known_miss(r: &MotionDiagnosis, floor: f64) {
    let verdict = r.verdict();
    assert!(
        r.after.rms_held > 1.2 * floor,
        "held out {:.1} µm against a floor of {:.1} µm: the miss is gone, update this test",
        1e6 * r.after.rms_held,
        1e6 * floor
    );
    assert!(
        r.heldout_check.judged && !r.heldout_check.explained,
        "{verdict}: {:?}",
        r.heldout_check
    );
    assert!(!verdict.starts_with("clean"), "{verdict}");
}

/// The clamp's record two capture frames (40 ms) late: the time offset is adopted first and
/// recovered to the step (measured −40.0 ms, asserted within half a capture frame of the
/// injected −40 ms), the forecast improves tenfold (measured 3,450.8 → 350.4 µm held out,
/// asserted below a fifth), viscosity follows (the truth is damped), and the residual left is
/// the known miss of [`assert_honest_known_miss`] (measured 1.65× the 212.8 µm floor).
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
    assert_honest_known_miss(&r, floor(&t));
}

/// The same draw as generated: no time offset (the scan finds none), viscosity adopted (the
/// truth is damped at a 3.7 % ratio; measured 850.7 → 338.5 µm held out), and the same known
/// miss (measured 1.59× the floor).
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
    assert_honest_known_miss(&r, floor(&t));
}
