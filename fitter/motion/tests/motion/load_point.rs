//! Where a hanging weight acts, read from rest states
//! ([`palpate_motion::load_point::fit_lever`]): the example bar turned into a horizontal
//! cantilever (gravity across it, its clamp held still), one run under its own weight and one
//! with a 2 g weight on the top edge of its free end, each run's markers at the static
//! equilibrium the truth comes to, with 20 µm of noise per coordinate. A weight whose truth acts
//! 8 mm beyond its nodes is found there, clear of zero; a weight on its nodes is found within 2σ
//! of them.

use crate::support::example;
use palpate_fem::rng::SplitMix64;
use palpate_motion::dataset::{load, MotionDataset};
use palpate_motion::load_point::fit_lever;
use palpate_motion::model::DeadLoad;
use palpate_motion::rest_fit::{predict_rest, Design, RestSolve, RestState};

const POISSON: f64 = 1.0 / 3.0;
const MU: f64 = 1.0e4;

/// A run at rest: the cantilever with a weight of `mass` kg (none: its own weight only) acting
/// `lever` m beyond its nodes; the markers of every frame the truth's equilibrium with noise.
/// The dataset, as a user would give it, declares the weight on its nodes.
fn at_rest(mass: Option<f64>, lever: f64, seed: u64) -> MotionDataset {
    let mut ds = load(&example()).unwrap();
    ds.model.gravity = [0.0, 0.0, -9.81];
    for c in &mut ds.model.clamps {
        let still = c.poses[0];
        c.poses.iter_mut().for_each(|p| *p = still);
    }
    if let Some(m) = mass {
        let back = ds.mesh.group("back").unwrap().to_vec();
        let top = back
            .iter()
            .map(|&n| ds.mesh.nodes[n][2])
            .fold(f64::NEG_INFINITY, f64::max);
        ds.model.loads = vec![DeadLoad {
            name: "weight".into(),
            nodes: back
                .into_iter()
                .filter(|&n| ds.mesh.nodes[n][2] == top)
                .collect(),
            force: [0.0, 0.0, -9.81 * m],
            from_step: 0,
            mass: Some(m),
            inertia: false,
            lever: None,
        }];
        ds.model.set_load_lever(lever).unwrap();
    }
    let state = RestState::of_dataset(&ds, 0.5).unwrap();
    let solve = RestSolve {
        load_steps: 4,
        tol: 1e-9,
    };
    let rest = predict_rest(&state, Design::Linear, MU, POISSON, &solve, false).unwrap();
    let mut rng = SplitMix64::new(seed);
    for row in &mut ds.obs.markers {
        for (seen, p) in row.iter_mut().zip(&rest.markers) {
            *seen = Some(p.map(|v| v + 20e-6 * rng.normal()));
        }
    }
    for l in &mut ds.model.loads {
        l.lever = None;
    }
    ds
}

fn read(lever: f64) -> palpate_motion::load_point::LeverFit {
    let plain = at_rest(None, 0.0, 1);
    let weight = at_rest(Some(0.002), lever, 2);
    let l = fit_lever(&[&plain, &weight], Design::Linear, POISSON, 2.0 * MU, 0.5).unwrap();
    eprintln!(
        "truth {:.1} mm: read {:.2} ± {:.2} mm, μ {:.1} Pa, RMS {:.1} → {:.1} µm ({} offsets)",
        1e3 * lever,
        1e3 * l.offset_m,
        1e3 * l.sigma_m,
        l.mu,
        1e6 * l.rms_on_nodes_m,
        1e6 * l.rms_m,
        l.evaluations
    );
    l
}

#[test]
fn a_weight_acting_beyond_its_nodes_is_found_there() {
    let l = read(0.008);
    assert!((l.offset_m - 0.008).abs() < 0.1 * 0.008, "{l:?}");
    assert!(l.offset_m.abs() > 2.0 * l.sigma_m, "{l:?}");
    assert!((l.mu / MU - 1.0).abs() < 0.02, "{l:?}");
    assert!(l.rms_m < 0.5 * l.rms_on_nodes_m, "{l:?}");
}

#[test]
fn a_weight_on_its_nodes_is_left_there() {
    let l = read(0.0);
    assert!(l.offset_m.abs() < 2.0 * l.sigma_m, "{l:?}");
    assert!((l.mu / MU - 1.0).abs() < 0.02, "{l:?}");
}

/// `lever_m` of a `[[loads]]` table puts the lever on the load as read: the example turned into
/// a cantilever, a 2 g weight on its free end's top edge 8 mm beyond its nodes.
#[test]
fn a_datasets_lever_is_read_onto_its_load() {
    let dir = tempfile::tempdir().unwrap();
    crate::support::copy_example(dir.path());
    let toml = dir.path().join("dataset.toml");
    let text = std::fs::read_to_string(&toml)
        .unwrap()
        .replace("gravity = [0.0, -9.81, 0.0]", "gravity = [0.0, 0.0, -9.81]");
    let table = "\n[[loads]]\ngroup = \"back\"\nedge = [0, 0, 1]\nmass = 0.002\nlever_m = 0.008\n";
    std::fs::write(&toml, text + table).unwrap();
    let ds = load(dir.path()).unwrap();
    assert_eq!(ds.model.load_lever(), 0.008);
    let lever = ds.model.loads[0].lever.as_ref().unwrap();
    assert!((lever.shares.iter().map(|s| s.1).sum::<f64>() - 1.0).abs() < 1e-12);
    assert!(lever.axis[1] > 0.99, "{:?}", lever.axis);
}
