//! What the diagnosis tests share: static specimens, the summary line of a report, and the
//! motion example bar.

use std::path::{Path, PathBuf};

use palpate_diagnose::DiagnosisReport;
use palpate_fem::mesh::Mesh;
use palpate_motion::model::Model;
use palpate_motion::scenario::{example_bar, EXAMPLE_BAR_SIZE, EXAMPLE_DT};
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

/// The bundled motion dataset (`models/motion-example`: a 24-tet bar, front face clamped and
/// shaken, gravity along −y).
pub fn example() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/motion-example")
}

/// The bar: 2 × 8 × 2 cm.
pub const SIZE: [f64; 3] = EXAMPLE_BAR_SIZE;
/// The time step: 180 Hz.
pub const DT: f64 = EXAMPLE_DT;

/// The example bar ([`example_bar`]) in `cells` hexahedra for `steps` steps.
pub fn bar(cells: [usize; 3], steps: usize) -> (Mesh, Model) {
    example_bar(cells, steps).unwrap()
}

/// The recording of a run observed out of step with its base, shared with the motion specimens.
pub use palpate_specimen::motion::record_late;
