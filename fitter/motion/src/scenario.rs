//! Synthetic set-ups shared by the benchmark, the evidence runs and the tests: a box-meshed bar
//! whose base is clamped and moved, virtual markers, and recorded (optionally noisy) observations.

use super::model::{Clamp, MassKind, Material, Model, Observations, Pose};
use super::sim::simulate_states;
use super::MotionError;
use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_fem::mesh::Mesh;
/// The recordings' noise generator (xorshift64* + Box–Muller), shared from `palpate_fem::rng`.
pub use palpate_fem::rng::Gauss;

/// The anchor's base motion: 1.5 cm·(1 − cos 6πt) in x and 0.5 cm·(1 − cos 10πt) in z.
pub fn two_sinusoids(t: f64) -> [f64; 3] {
    use std::f64::consts::PI;
    [
        0.015 * (1.0 - (6.0 * PI * t).cos()),
        0.0,
        0.005 * (1.0 - (10.0 * PI * t).cos()),
    ]
}

/// A bar of `size` (long axis y) meshed with `cells`, its `front` face (y = 0) clamped and
/// translated by `motion(t)`, gravity −y·9.81 (the bar stands on its moving base), `markers`
/// rest points, lumped mass.
pub fn bar_model(
    size: [f64; 3],
    cells: [usize; 3],
    dt: f64,
    steps: usize,
    motion: &dyn Fn(f64) -> [f64; 3],
    markers: &[[f64; 3]],
) -> Result<(Mesh, Model), MotionError> {
    let mesh = box_mesh(size, cells);
    let base = mesh.node_groups.get("front").cloned().unwrap_or_default();
    let poses = (0..=steps)
        .map(|n| Pose::translation(motion(n as f64 * dt)))
        .collect();
    let clamps = vec![Clamp {
        name: "front".into(),
        nodes: base,
        poses,
    }];
    let mut model = Model::new(
        &mesh,
        clamps,
        Vec::new(),
        dt,
        steps,
        [0.0, -9.81, 0.0],
        MassKind::Lumped,
    )?;
    model.markers = markers
        .iter()
        .enumerate()
        .map(|(i, p)| model.marker_at(&format!("m{i}"), *p))
        .collect();
    Ok((mesh, model))
}

/// A tensile test: a bar of `size` (long axis y) meshed with `cells`, its `front` face (y = 0)
/// fixed and its `back` face pulled along y by `elongation(t)` (m); no gravity (a tared load
/// cell), lumped mass, no markers. The observable is the reaction force of clamp 1 (`back`).
pub fn tension_bar(
    size: [f64; 3],
    cells: [usize; 3],
    dt: f64,
    steps: usize,
    elongation: &dyn Fn(f64) -> f64,
) -> Result<(Mesh, Model), MotionError> {
    let mesh = box_mesh(size, cells);
    let group = |g: &str| mesh.node_groups.get(g).cloned().unwrap_or_default();
    let clamps = vec![
        Clamp {
            name: "front".into(),
            nodes: group("front"),
            poses: vec![Pose::identity(); steps + 1],
        },
        Clamp {
            name: "back".into(),
            nodes: group("back"),
            poses: (0..=steps)
                .map(|n| Pose::translation([0.0, elongation(n as f64 * dt), 0.0]))
                .collect(),
        },
    ];
    let model = Model::new(
        &mesh,
        clamps,
        Vec::new(),
        dt,
        steps,
        [0.0; 3],
        MassKind::Lumped,
    )?;
    Ok((mesh, model))
}

/// Nine surface markers at ⅓, ⅔ and the top of a bar of `size` (three per height).
pub fn nine_markers(size: [f64; 3]) -> Vec<[f64; 3]> {
    let mut m = Vec::new();
    for k in 1..=3 {
        let y = size[1] * k as f64 / 3.0;
        m.push([0.0, y, size[2] / 2.0]);
        m.push([size[0], y, size[2] / 2.0]);
        m.push([size[0] / 2.0, y, size[2]]);
    }
    m
}

/// Simulates `model` with `mat` and records every marker at every step (and every clamp's
/// reaction force), with Gaussian noise of standard deviation `noise` (m) on the markers from a
/// fixed-seed generator (reproducible runs).
pub fn record(
    model: &Model,
    mat: &Material,
    noise: f64,
    seed: u64,
) -> Result<Observations, MotionError> {
    let mut rng = Gauss::new(seed);
    let mut obs = Observations {
        marker_weight: 1.0,
        force_weight: 1.0,
        ..Default::default()
    };
    simulate_states(model, mat, |s| {
        obs.markers.push(
            model
                .markers
                .iter()
                .map(|m| {
                    let p = model.marker_position(m, s.x);
                    Some([
                        p[0] + noise * rng.next(),
                        p[1] + noise * rng.next(),
                        p[2] + noise * rng.next(),
                    ])
                })
                .collect(),
        );
        let mut f = Vec::new();
        for c in 0..model.clamps.len() {
            f.push(Some(super::objective::clamp_force(
                model, mat, c, s.x, s.v,
            )?));
        }
        obs.forces.push(f);
        Ok(())
    })?;
    Ok(obs)
}

/// The example bar of the tests, benches and `models/motion-example`: 2 × 8 × 2 cm.
pub const EXAMPLE_BAR_SIZE: [f64; 3] = [0.02, 0.08, 0.02];
/// The example bar's time step: 180 Hz, a motion-capture rate.
pub const EXAMPLE_DT: f64 = 1.0 / 180.0;

/// The example bar in `cells` hexahedra, its base moving by [`two_sinusoids`] for `steps` steps
/// of [`EXAMPLE_DT`], watched by the [`nine_markers`].
pub fn example_bar(cells: [usize; 3], steps: usize) -> Result<(Mesh, Model), MotionError> {
    bar_model(
        EXAMPLE_BAR_SIZE,
        cells,
        EXAMPLE_DT,
        steps,
        &two_sinusoids,
        &nine_markers(EXAMPLE_BAR_SIZE),
    )
}

/// Noise-free observations of simulated marker paths (`paths[n][i]`: marker i at step n + 1), on
/// any discretisation: data a fit should give its truth back from.
pub fn observed(paths: &[Vec<[f64; 3]>]) -> Observations {
    Observations {
        markers: paths
            .iter()
            .map(|row| row.iter().map(|p| Some(*p)).collect())
            .collect(),
        marker_weight: 1.0,
        force_weight: 1.0,
        ..Default::default()
    }
}

/// The example bar's material, the truth of `models/motion-example`: λ = 10 kPa, μ = 20 kPa,
/// viscosity 12 Pa·s^h, h = 1, ρ = 47 kg/m³ in every element of `model`.
pub fn example_truth(model: &Model) -> Material {
    Material::uniform(model.tets.len(), 1.0e4, 2.0e4, 12.0, 1.0, 47.0)
}
