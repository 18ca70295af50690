//! Shared pieces of the static-diagnosis tests: specimens and the summary line.

use palpate_diagnose::DiagnosisReport;
use palpate_specimen::{generate, Effect, EffectSpec, Specimen, SpecimenOptions};

/// The default specimen with the one effect `effect` injected at `magnitude`.
pub fn specimen_with(effect: Effect, magnitude: f64) -> Specimen {
    generate(&SpecimenOptions {
        effects: vec![EffectSpec { effect, magnitude }],
        ..Default::default()
    })
    .expect("specimen")
}

/// The default specimen (no effect) drawn with `seed`.
pub fn specimen_seeded(seed: u64) -> Specimen {
    generate(&SpecimenOptions {
        seed,
        ..Default::default()
    })
    .expect("specimen")
}

/// The line the diagnosis tests print for a report: what was adopted, the fitted and held-out
/// RMS marker error before → after (µm) and the noise floor (µm). Each test adds its own label
/// before it and figures after it.
pub fn summary(r: &DiagnosisReport) -> String {
    format!(
        "adopted {:?}; RMS {:.1} → {:.1} µm (held out {:.1} → {:.1}); floor {:.1} µm",
        r.adopted,
        1e6 * r.before.fitted_rms,
        1e6 * r.after.fitted_rms,
        1e6 * r.before.heldout_rms,
        1e6 * r.after.heldout_rms,
        1e6 * r.noise_floor,
    )
}
