//! What the diagnosis tests share: static specimens, the independent generator's committed
//! datasets, the summary line of a report, and the motion example bar.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

use palpate_diagnose::DiagnosisReport;
use palpate_fem::dataset::StaticDataset;
use palpate_fem::mesh::Mesh;
use palpate_motion::dataset::{DatasetToml, Initial, MotionDataset};
use palpate_motion::model::{Model, Observations};
use palpate_motion::scenario::{example_bar, EXAMPLE_BAR_SIZE, EXAMPLE_DT};
use palpate_specimen::{generate, Effect, EffectSpec, Specimen, SpecimenError, SpecimenOptions};

/// The specimen `generate(options)` draws, drawn once per test binary: several tests start from
/// the same draw (seed 1 with no effect, seed 3, the gravity specimen), and each draw solves its
/// Neo-Hookean truth on the twice-refined mesh (3.4 s of CPU for the default one). A draw is
/// deterministic in its options, so a copy of the first one is the same dataset; the key is the
/// options' `Debug` text, which prints every field (floats to the last bit).
pub fn drawn(options: &SpecimenOptions) -> Result<Specimen, SpecimenError> {
    static DRAWN: OnceLock<Mutex<HashMap<String, Specimen>>> = OnceLock::new();
    let drawn = DRAWN.get_or_init(Default::default);
    let key = format!("{options:?}");
    if let Some(s) = drawn.lock().expect("specimen cache").get(&key) {
        return Ok(s.clone());
    }
    // Drawn outside the lock, so that tests drawing other specimens do not wait for this one.
    let s = generate(options)?;
    drawn.lock().expect("specimen cache").insert(key, s.clone());
    Ok(s)
}

/// The default specimen with the one effect `effect` injected at `magnitude`.
pub fn specimen_with(effect: Effect, magnitude: f64) -> Specimen {
    drawn(&SpecimenOptions {
        effects: vec![EffectSpec { effect, magnitude }],
        ..Default::default()
    })
    .expect("specimen")
}

/// The default specimen (no effect) drawn with `seed`.
pub fn specimen_seeded(seed: u64) -> Specimen {
    drawn(&SpecimenOptions {
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

/// The independent generator's static dataset `name` under `tests/data/independent/`.
pub fn independent(name: &str) -> StaticDataset {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data/independent")
        .join(name);
    StaticDataset::read(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
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

/// The example bar (`cells` hexahedra, `steps` steps) turned into a cantilever: gravity across
/// its length, starting from its sagged equilibrium, to be shaken at its clamp.
pub fn cantilever(cells: [usize; 3], steps: usize) -> (Mesh, Model) {
    let (mesh, mut model) = bar(cells, steps);
    model.gravity = [0.0, 0.0, -9.81];
    model.static_start = true;
    (mesh, model)
}

/// The motion dataset of a [`cantilever`] observed as `obs` (markers only: the forces are
/// dropped) with marker noise `sigma`, density `density` and the fit's start `initial`.
pub fn cantilever_dataset(
    (mesh, model): (Mesh, Model),
    mut obs: Observations,
    sigma: f64,
    density: f64,
    initial: Initial,
) -> MotionDataset {
    obs.forces
        .iter_mut()
        .for_each(|r| r.iter_mut().for_each(|f| *f = None));
    MotionDataset {
        config: DatasetToml {
            marker_noise: Some(sigma),
            steps: Some(model.steps),
            substeps: Some(1),
            density: Some(density),
            gravity: Some(model.gravity),
            static_start: Some(true),
            initial,
            initial_declared: true,
            ..DatasetToml::new(DT, vec!["front".into()])
        },
        mesh,
        model,
        obs,
        timestep: palpate_motion::timestep::TimeStep::capture_rate(DT),
    }
}

/// The recording of a run observed out of step with its base, shared with the motion specimens.
pub use palpate_specimen::motion::record_late;
