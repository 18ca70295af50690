//! Dead loads in motion datasets (a weight hung from an edge), runs fitted together with a fixed
//! Poisson's ratio, and the prediction of a run from a fitted material — on the bundled 24-tet
//! example bar (front face clamped and shaken, gravity along −y).

use crate::support::{copy_example, example};
use palpate_motion::dataset::load;
use palpate_motion::gradient::Method;
use palpate_motion::model::{DeadLoad, Material, Model, Observations, Param, ParamKind};
use palpate_motion::optimize::{evaluate_runs, fit_runs, FitSettings, Run};
use palpate_motion::predict::{linear_baseline, predict};
use palpate_motion::scenario::record;
use palpate_motion::sim::{equilibrium, simulate_states};

/// A copy of the example with `extra` appended to its dataset.toml, loaded (or its error).
fn with_toml(extra: &str) -> Result<palpate_motion::dataset::MotionDataset, String> {
    edited_toml(|t| format!("{t}\n{extra}"))
}

/// A copy of the example with its dataset.toml rewritten by `edit`, loaded (or its error).
fn edited_toml(
    edit: impl Fn(&str) -> String,
) -> Result<palpate_motion::dataset::MotionDataset, String> {
    let dir = tempfile::tempdir().unwrap();
    copy_example(dir.path());
    let t = std::fs::read_to_string(dir.path().join("dataset.toml")).unwrap();
    std::fs::write(dir.path().join("dataset.toml"), edit(&t)).unwrap();
    load(dir.path()).map_err(|e| e.to_string())
}

#[test]
fn a_hanging_weight_is_read_on_the_groups_edge_and_switched_on_at_its_time() {
    let ds =
        with_toml("[[loads]]\ngroup = \"back\"\nedge = [0, 0, 1]\nmass = 0.01\nfrom_t = 0.1\n")
            .unwrap();
    let l = &ds.model.loads[0];
    let back = ds.mesh.group("back").unwrap();
    let ztop = back
        .iter()
        .map(|&n| ds.mesh.nodes[n][2])
        .fold(f64::NEG_INFINITY, f64::max);
    assert!(!l.nodes.is_empty() && l.nodes.len() < back.len());
    assert!(l.nodes.iter().all(|&n| ds.mesh.nodes[n][2] == ztop));
    assert_eq!(
        l.nodes.len(),
        back.iter()
            .filter(|&&n| ds.mesh.nodes[n][2] == ztop)
            .count()
    );
    assert_eq!(l.force, [0.0, -0.0981, 0.0]);
    assert_eq!(l.from_step, 18, "0.1 s on the 1/180 s grid");
    assert_eq!(l.name, "back");
}

#[test]
fn bad_loads_are_refused_naming_the_field() {
    for (extra, want) in [
        (
            "group = \"back\"\nmass = 0.01\nforce = [0, 1, 0]",
            "not both",
        ),
        ("group = \"back\"", "force = [fx, fy, fz]"),
        ("group = \"back\"\nmass = -1", "field mass"),
        ("group = \"nosuch\"\nmass = 0.01", "nosuch"),
        ("group = \"front\"\nmass = 0.01", "clamped"),
        (
            "group = \"back\"\nmass = 0.01\nedge = [0, 0, 0]",
            "field edge",
        ),
        ("group = \"back\"\nmass = 0.01\nfrom_t = -1", "field from_t"),
    ] {
        let e = with_toml(&format!("[[loads]]\n{extra}\n")).unwrap_err();
        assert!(
            e.contains("dataset.toml") && e.contains("loads[0]") && e.contains(want),
            "{extra:?}: {e}"
        );
    }
}

fn example_material(ds: &palpate_motion::dataset::MotionDataset) -> Material {
    let i = &ds.config.initial;
    Material::uniform(
        ds.model.tets.len(),
        i.lambda,
        i.mu,
        i.nu,
        i.h,
        ds.config.density.unwrap(),
    )
}

fn trajectory(model: &Model, mat: &Material) -> Vec<Vec<f64>> {
    let mut out = Vec::new();
    simulate_states(model, mat, |s| {
        out.push(s.x.to_vec());
        Ok(())
    })
    .unwrap();
    out
}

#[test]
fn a_dead_load_changes_nothing_before_its_step_and_deflects_linearly_at_small_loads() {
    let ds = load(&example()).unwrap();
    let mat = example_material(&ds);
    let back = ds.mesh.group("back").unwrap().to_vec();
    let loaded = |force: [f64; 3], from_step: usize| {
        let mut m = ds.model.clone();
        m.loads = vec![DeadLoad {
            name: "push".into(),
            nodes: back.clone(),
            force,
            from_step,
            mass: None,
            inertia: false,
            lever: None,
        }];
        m
    };
    let free = trajectory(&ds.model, &mat);
    let pushed = trajectory(&loaded([1e-3, 0.0, 0.0], 10), &mat);
    for n in 0..9 {
        assert_eq!(free[n], pushed[n], "step {} before the load", n + 1);
    }
    assert!(free[10] != pushed[10], "the load acts from step 10");
    // Equilibrium: a small push deflects in proportion to the push (Neo-Hookean at small strain).
    let mut still = ds.model.clone();
    still.gravity = [0.0; 3];
    let mut at = |f: f64| {
        still.loads = vec![DeadLoad {
            name: "push".into(),
            nodes: back.clone(),
            force: [f, 0.0, 0.0],
            from_step: 0,
            mass: None,
            inertia: false,
            lever: None,
        }];
        let (x, _) = equilibrium(&still, &mat, 0).unwrap();
        let rest: Vec<f64> = still.nodes.iter().flatten().copied().collect();
        x.iter()
            .zip(&rest)
            .map(|(a, b)| a - b)
            .collect::<Vec<f64>>()
    };
    let (u1, u2) = (at(1e-4), at(2e-4));
    let norm = |v: &[f64]| v.iter().map(|a| a * a).sum::<f64>().sqrt();
    let diff: Vec<f64> = u2.iter().zip(&u1).map(|(a, b)| a - 2.0 * b).collect();
    assert!(norm(&u1) > 1e-7, "the push deflects the bar");
    assert!(norm(&diff) < 1e-2 * norm(&u2), "linear at small loads");
}

/// Two runs of the example bar, one with a dead load on its back face, and their records from a
/// material with Poisson's ratio `nu`.
fn two_runs(mu: f64, nu: f64) -> (Vec<Model>, Material) {
    let ds = load(&example()).unwrap();
    let mut mat = example_material(&ds);
    mat.set(
        &[
            Param::global(ParamKind::Mu),
            Param::global(ParamKind::Lambda),
        ],
        &[mu, 2.0 * nu / (1.0 - 2.0 * nu) * mu],
    );
    let mut loaded = ds.model.clone();
    loaded.loads = vec![DeadLoad {
        name: "weight".into(),
        nodes: ds.mesh.group("back").unwrap().to_vec(),
        force: [0.0, 0.0, -2e-3],
        from_step: 0,
        // A weight that moves with its nodes: its inertia enters M, and so the adjoint.
        mass: Some(2e-3 / 9.81),
        inertia: true,
        lever: None,
    }];
    (vec![ds.model, loaded], mat)
}

/// Each model's record from `truth` with marker noise `noise` (seed `seed`).
fn record_each(models: &[Model], truth: &Material, noise: f64, seed: u64) -> Vec<Observations> {
    models
        .iter()
        .map(|m| record(m, truth, noise, seed).unwrap())
        .collect()
}

/// The runs of `models` with their observations `obs`, in order.
fn paired<'a>(models: &'a [Model], obs: &'a [Observations]) -> Vec<Run<'a>> {
    models
        .iter()
        .zip(obs)
        .map(|(model, obs)| Run { model, obs })
        .collect()
}

#[test]
fn the_tied_gradient_of_two_runs_matches_finite_differences() {
    let nu = 0.3;
    let ratio = 2.0 * nu / (1.0 - 2.0 * nu);
    let (mut models, truth) = two_runs(1e4, nu);
    // Central differences of Φ divide the simulations' own error by 2h: at the default Newton
    // tolerance (1e-6 N) that error depends on where Newton happens to stop (the predictor) and
    // alone reaches ~2e-4 of the derivative here; solved to 1e-10 N the difference measures the
    // gradient.
    for m in &mut models {
        m.newton.tol = 1e-10;
    }
    let obs = record_each(&models, &truth, 1e-4, 3);
    let runs = paired(&models, &obs);
    let params = [
        Param::global(ParamKind::Mu),
        Param::global(ParamKind::Lambda),
    ];
    let at = |mu: f64| {
        let mut m = truth.clone();
        m.set(&params, &[mu, ratio * mu]);
        m
    };
    let mu = 1.3e4;
    let (e, parts) = evaluate_runs(&runs, &at(mu), &params, Some(Method::Adjoint)).unwrap();
    assert_eq!(parts.len(), 2);
    let g = e.grad.unwrap();
    let tied = g[0] + ratio * g[1];
    let h = 1e-4 * mu;
    let phi = |m: f64| evaluate_runs(&runs, &at(m), &params, None).unwrap().0.phi;
    let fd = (phi(mu + h) - phi(mu - h)) / (2.0 * h);
    assert!(
        (tied - fd).abs() < 1e-4 * fd.abs(),
        "adjoint {tied:e} vs finite differences {fd:e}"
    );
    assert!((e.phi - parts[0].phi - parts[1].phi).abs() < 1e-15 * e.phi.abs().max(1e-30));
}

#[test]
fn two_runs_with_a_fixed_poisson_ratio_recover_the_shear_modulus_and_predict() {
    let nu = 0.3;
    let (models, truth) = two_runs(1e4, nu);
    let obs = record_each(&models, &truth, 0.0, 1);
    let runs = paired(&models, &obs);
    let settings = FitSettings {
        poisson: Some(nu),
        max_iters: 40,
        ..Default::default()
    };
    let r = fit_runs(
        &runs,
        &truth,
        &[Param::global(ParamKind::Mu)],
        &[2e4],
        &settings,
        &[],
        &|_, _| {},
    )
    .unwrap();
    assert!((r.q[0] / 1e4 - 1.0).abs() < 1e-4, "μ = {}", r.q[0]);
    assert_eq!(r.runs.len(), 2);
    assert!(r.eval.rms_marker < 1e-7, "{}", r.eval.rms_marker);
    // λ tied to μ cannot be a parameter at the same time.
    let both = fit_runs(
        &runs,
        &truth,
        &[
            Param::global(ParamKind::Mu),
            Param::global(ParamKind::Lambda),
        ],
        &[2e4, 2e4],
        &settings,
        &[],
        &|_, _| {},
    );
    assert!(both.unwrap_err().to_string().contains("Poisson"));
    // The truth predicts its own runs exactly.
    let p = predict(&models[1], &truth, &obs[1]).unwrap();
    assert!(p.trajectory_rms_m < 1e-12, "{}", p.trajectory_rms_m);
    assert_eq!(p.simulated.len(), models[1].steps);
    // A straight line through two loads is exact for a third on the line.
    let b = linear_baseline(
        &[
            (0.0, vec![Some([0.0, 0.0, 0.0])]),
            (1.0, vec![Some([0.0, -1.0, 0.0])]),
        ],
        2.5,
    );
    assert_eq!(b[0], Some([0.0, -2.5, 0.0]));
}

/// The static fit from the ends of runs recovers μ from equilibria it did not make: two "runs" of
/// the example bar (with and without a dead load) whose markers sit at the truth's equilibrium.
#[test]
fn the_equilibria_fit_recovers_the_shear_modulus_of_rest_states() {
    let nu = 0.3;
    let (models, truth) = two_runs(1e4, nu);
    let obs: Vec<palpate_motion::model::Observations> = models
        .iter()
        .map(|m| {
            let (x, _) = equilibrium(m, &truth, m.steps).unwrap();
            let at_rest: Vec<Option<[f64; 3]>> = m
                .markers
                .iter()
                .map(|k| Some(m.marker_position(k, &x)))
                .collect();
            palpate_motion::model::Observations {
                markers: vec![at_rest; m.steps],
                marker_weight: 1.0,
                force_weight: 1.0,
                ..Default::default()
            }
        })
        .collect();
    let runs: Vec<_> = models.iter().zip(&obs).collect();
    let (mu, rms, sd) = palpate_motion::predict::fit_equilibria(&runs, &truth, nu, 2.0e4).unwrap();
    assert!((mu / 1e4 - 1.0).abs() < 1e-3, "μ = {mu}");
    assert!(rms < 1e-6, "rest-state RMS {rms}");
    assert!(sd.is_finite() && sd < 1e-2 * mu, "1σ {sd}");
}

/// One schema with the static datasets: a motion dataset takes `name`, `description`, `units`
/// (SI only) and `marker_noise`; a static dataset takes `clamps = ["group"]` for its fixed group.
#[test]
fn shared_dataset_keys_mean_the_same_in_both_formats() {
    let ds = edited_toml(|t| {
        format!("name = \"bar\"\ndescription = \"the example\"\nunits = \"SI\"\nmarker_noise = 1e-4\n{t}")
    })
    .unwrap();
    assert_eq!(ds.config.name.as_deref(), Some("bar"));
    assert_eq!(ds.config.marker_noise, Some(1e-4));
    for (key, want) in [
        ("units = \"mm\"", "field units"),
        ("marker_noise = -1.0", "field marker_noise"),
    ] {
        let e = edited_toml(|t| format!("{key}\n{t}")).unwrap_err();
        assert!(e.contains("dataset.toml") && e.contains(want), "{key}: {e}");
    }
    // The static reader: `clamps` for `fixed_group`, one group only, not both.
    let src = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/sponge/dataset");
    let read = |edit: &dyn Fn(&str) -> String| {
        let dir = tempfile::tempdir().unwrap();
        for e in std::fs::read_dir(&src).unwrap() {
            let e = e.unwrap();
            std::fs::copy(e.path(), dir.path().join(e.file_name())).unwrap();
        }
        let t = std::fs::read_to_string(dir.path().join("dataset.toml")).unwrap();
        std::fs::write(dir.path().join("dataset.toml"), edit(&t)).unwrap();
        palpate_fem::dataset::StaticDataset::read(dir.path()).map_err(|e| e.to_string())
    };
    // The bundled dataset says `clamps`; the older `fixed_group` is the alias under test.
    let plain = read(&|t| t.replace("clamps = [\"bottom\"]", "fixed_group = \"bottom\"")).unwrap();
    let aliased = read(&|t| t.to_string()).unwrap();
    assert_eq!(plain.fixed_nodes, aliased.fixed_nodes);
    let two = read(&|t| t.replace("clamps = [\"bottom\"]", "clamps = [\"bottom\", \"top\"]"))
        .unwrap_err();
    assert!(two.contains("exactly one"), "{two}");
    let both = read(&|t| {
        t.replace(
            "clamps = [\"bottom\"]",
            "fixed_group = \"bottom\"\nclamps = [\"bottom\"]",
        )
    })
    .unwrap_err();
    assert!(both.contains("give one"), "{both}");
}
