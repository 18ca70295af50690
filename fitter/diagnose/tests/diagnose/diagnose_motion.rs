//! `palpate diagnose` on motion datasets (on top of the motion fitter): a viscous
//! specimen must be diagnosed as viscous and forecast to the noise floor; an elastic one must come
//! back clean; one whose markers were recorded out of step with its base's record must be given
//! its time offset; `palpate diagnose <dir>` must recognise a motion dataset on disk.
//!
//! Specimens: the example dataset's set-up (a 2 × 8 × 2 cm bar of 24 tets standing on a base
//! moved by two sinusoids, 45 steps at 180 Hz, nine markers, density declared) simulated by the
//! motion fitter's own forward model (Neo-Hookean eq. 16 + viscosity eq. 17, BDF2) with marker
//! noise σ = 0.1 mm. The noise floor of the RMS marker error is σ√3 = 173.2 µm.

use crate::support::{bar, record_late, DT, SIZE};
use palpate_diagnose::motion::{diagnose, MotionDiagnosis, MotionOptions};
use palpate_motion::dataset::{
    write_dataset as write_dataset_files, ClampRows, DatasetToml, Decimals, Initial, MotionDataset,
    MotionDatasetFiles, StepRow,
};
use palpate_motion::model::{Material, Model};
use palpate_motion::scenario::{nine_markers, record, two_sinusoids};
use palpate_specimen::motion::{motion_specimen, MotionEffect, MotionTruth};

const SIGMA: f64 = 1e-4;
const STEPS: usize = 45;

fn truth(model: &Model, nu: f64) -> Material {
    Material::uniform(model.tets.len(), 1.0e4, 2.0e4, nu, 1.0, 47.0)
}

/// Truth λ = 1e4, μ = 2e4 Pa, h = 1, ρ = 47 kg/m³ and viscosity `nu` (Pa s).
fn specimen(nu: f64, seed: u64) -> MotionDataset {
    let (mesh, model) = bar([1, 4, 1], STEPS);
    let mut obs = record(&model, &truth(&model, nu), SIGMA, seed).unwrap();
    // Markers only, like the example dataset (no load cell).
    obs.forces
        .iter_mut()
        .for_each(|r| r.iter_mut().for_each(|f| *f = None));
    MotionDataset {
        config: DatasetToml {
            name: None,
            description: None,
            units: None,
            marker_noise: Some(SIGMA),
            mesh: "mesh.msh".into(),
            dt: DT,
            steps: Some(STEPS),
            // The specimen is simulated at the capture step (a test of the diagnosis, not of
            // the time discretisation).
            substeps: Some(1),
            scheme: None,
            viscosity_form: None,
            density: Some(47.0),
            gravity: Some([0.0, -9.81, 0.0]),
            clamps: vec!["front".into()],
            mass: None,
            static_start: None,
            marker_weight: None,
            force_weight: None,
            initial: Initial {
                lambda: 2.0e4,
                mu: 1.0e4,
                nu: 6.0,
                h: 1.3,
            },
            loads: Vec::new(),
            initial_declared: true,
        },
        mesh,
        model,
        obs,
        timestep: palpate_motion::timestep::TimeStep::capture_rate(DT),
    }
}

/// [`specimen`] whose markers were recorded `late` steps behind the base's record (negative:
/// ahead), [`crate::support::record_late`].
fn late_specimen(nu: f64, seed: u64, late: i64) -> MotionDataset {
    let mut ds = specimen(nu, seed);
    ds.obs = record_late(&ds.model, &truth(&ds.model, nu), SIGMA, seed, late, 2).unwrap();
    // Markers only, as `specimen`.
    ds.obs
        .forces
        .iter_mut()
        .for_each(|r| r.iter_mut().for_each(|f| *f = None));
    ds
}

/// The drawn specimen of `effect` and `seed` (`palpate_specimen::motion`, on the example bar),
/// diagnosed.
fn drawn(effect: MotionEffect, seed: u64) -> (MotionDiagnosis, MotionTruth) {
    let base = crate::diagnose_runs::example();
    let (ds, truth) = motion_specimen(&base, effect, seed).unwrap();
    eprintln!("{}", truth.detail);
    (run(&ds, effect.name()), truth)
}

/// The body's μ within 2 % of the drawn truth's and the forecast under 1.2× the specimens'
/// noise floor σ√3.
fn assert_body_and_floor(r: &MotionDiagnosis, truth: &MotionTruth) {
    let mu = final_value(r, "mu");
    assert!(
        (mu / truth.mu - 1.0).abs() < 0.02,
        "μ {mu} for {}",
        truth.mu
    );
    let floor = palpate_specimen::motion::SIGMA * 3f64.sqrt();
    assert!(r.after.rms_held < 1.2 * floor, "{:?}", r.after);
}

/// The final model's value whose name starts with `start`.
fn final_value(r: &MotionDiagnosis, start: &str) -> f64 {
    r.after_values
        .iter()
        .find(|v| v.name.starts_with(start))
        .unwrap_or_else(|| panic!("{start}: {:?}", r.after_values))
        .value
}

fn run(ds: &MotionDataset, label: &str) -> MotionDiagnosis {
    // The specimens are simulated on the dataset's own mesh, so they hold no discretisation
    // error: the check against the mesh's own null (a truth finer than the mesh) is off, as in
    // `palpate-lab motion-confusion`; `diagnose_mesh_null` tests it on refined-mesh data.
    let o = MotionOptions {
        mesh_null: false,
        ..MotionOptions::default()
    };
    let r = diagnose(ds, label, &o, &|m| eprintln!("{m}")).unwrap();
    eprintln!(
        "{label}: adopted {:?}; RMS fitted {:.1} -> {:.1} µm, held out {:.1} -> {:.1} µm",
        r.adopted,
        1e6 * r.before.rms_fit,
        1e6 * r.after.rms_fit,
        1e6 * r.before.rms_held,
        1e6 * r.after.rms_held
    );
    for rd in &r.rounds {
        let s = &rd.signature;
        eprintln!(
            "  round {} signature: {} (drift {:.2}, speed bins {:?})",
            rd.round,
            s.reading,
            s.drift_ratio,
            s.speed_bins
                .iter()
                .map(|b| (
                    format!("{:.1} mm/s", 1e3 * b.0),
                    format!("{:.1} µm", 1e6 * b.1)
                ))
                .collect::<Vec<_>>()
        );
    }
    r
}

/// ν = 400 Pa s (viscous time ν/μ = 20 ms = 3.6 steps) on seeds 1 and 2: viscosity is named
/// first, the held-out forecast error comes down to the noise floor and ν is recovered.
/// Measured: seed 1 held out 208.2 → 174.4 µm, ν = 428; seed 2 204.1 → 179.5 µm, ν = 388.
/// Tolerances: held-out RMS ≤ 1.5 σ√3 (the bar; measured ≤ 1.04×); ν within 20 %
/// (measured 7 % and 3 %; the rest of the 20 % covers the λ–μ–ν correlation of this nearly
/// rigid, weakly excited bar, whose λ is itself only known to ±100 %).
#[test]
fn viscous_specimen_is_diagnosed_viscous_and_forecast_to_the_noise_floor() {
    let floor = SIGMA * 3f64.sqrt();
    for seed in [1, 2] {
        let r = run(&specimen(400.0, seed), &format!("viscous seed {seed}"));
        assert!(
            r.verdict().contains("the residual is then"),
            "{}",
            r.verdict()
        );
        assert!(
            r.adopted
                .first()
                .is_some_and(|a| a.starts_with("viscosity")),
            "seed {seed}: adopted {:?}",
            r.adopted
        );
        assert!(
            r.after.rms_held <= 1.5 * floor,
            "seed {seed}: held-out RMS {:.1} µm > 1.5 × {:.1} µm",
            1e6 * r.after.rms_held,
            1e6 * floor
        );
        assert!(r.after.rms_held < r.before.rms_held);
        // The residual of the elastic fit is a significant lag along the marker velocity
        // (measured ΔBIC −56.9 / −32.2 for the 1-parameter regression e ≈ c·u_rel; threshold
        // −10 as for the adoption rule), and none is left after viscosity (+5.6 / +6.6).
        assert!(r.rounds[0].signature.speed_dbic < -10.0, "seed {seed}");
        assert!(r.final_signature.speed_dbic > -10.0, "seed {seed}");
        let nu = r
            .after_values
            .iter()
            .find(|v| v.name == "viscosity")
            .unwrap();
        assert!(
            (nu.value / 400.0 - 1.0).abs() < 0.2,
            "seed {seed}: nu = {}",
            nu.value
        );
        assert!(nu.sigma.is_some_and(|s| s > 0.0 && s.is_finite()));
    }
}

/// ν = 0: nothing is adopted on seeds 1 and 2 (measured: the viscosity candidates have fitted
/// ΔBIC +6.9 … +15.1 and change the held-out RMS by −0.1 % / 0.0 %).
#[test]
fn elastic_specimen_comes_back_clean() {
    for seed in [1, 2] {
        let r = run(&specimen(0.0, seed), &format!("elastic seed {seed}"));
        assert!(r.adopted.is_empty(), "seed {seed}: adopted {:?}", r.adopted);
        assert_eq!(r.before.rms_held, r.after.rms_held);
        // Clean because the residual is the declared noise's, fitted and forecast.
        assert!(r.verdict().starts_with("clean"), "{}", r.verdict());
        // No lag along the velocity in the residual (measured ΔBIC +6.8 / +6.1).
        assert!(r.rounds[0].signature.speed_dbic > -10.0, "seed {seed}");
        // The elastic fit itself is at the noise floor (within 10 %: 34 × 9 markers give the
        // RMS a relative sampling error of ≈ 2.3 %, plus the bias of fitting 2 parameters).
        assert!((r.before.rms_fit / (SIGMA * 3f64.sqrt()) - 1.0).abs() < 0.1);
        // Markers only, no load: the moduli are those of the declared density, and the
        // report says so.
        assert!(
            r.relative.len() == 1
                && r.relative[0].contains("relative to the density ρ = 47")
                && r.relative[0].contains("kg/m³ (declared)")
                && r.relative[0].contains("μ/ρ is determined, not μ"),
            "{:?}",
            r.relative
        );
        let md = palpate_diagnose::motion::report::markdown(&r);
        assert!(md.contains("**Relative figures**: the moduli"), "{md}");
        // The fit lands λ where the data put it, not on its floor, and no value is marked.
        assert!(r.on_floor.is_empty(), "seed {seed}: {:?}", r.on_floor);
        assert!(!md.contains("on its floor"), "{md}");
    }
}

/// The elastic specimen with its markers 2 steps (11 ms) late, and 2 steps early: the time
/// offset is named (nothing else), recovered to the step, and the forecast comes down to the
/// noise floor.
#[test]
fn markers_out_of_step_with_the_base_are_given_their_time_offset() {
    let floor = SIGMA * 3f64.sqrt();
    for late in [2i64, -2] {
        let r = run(&late_specimen(0.0, 1, late), &format!("late {late}"));
        assert_eq!(r.adopted, vec!["time-offset".to_string()], "late {late}");
        let offset = r
            .after_values
            .iter()
            .find(|v| v.name.starts_with("time offset"))
            .unwrap();
        assert_eq!((offset.value / DT).round() as i64, late, "{offset:?}");
        assert!(
            r.after.rms_held <= 1.5 * floor,
            "late {late}: held-out RMS {:.1} µm",
            1e6 * r.after.rms_held
        );
        assert!(
            r.before.rms_held > 2.0 * floor,
            "late {late}: the offset shows"
        );
    }
}

/// How large viscosity's signal is in this set-up: the RMS over markers and steps of the
/// noise-free trajectory with ν minus the one with ν = 0 (same λ, μ). The example dataset's
/// ν = 12 Pa s is far below its own noise floor (0.2 mm · √3 = 346 µm); ν = 400 is above this
/// test's floor. Measured: 12.8 µm (3.7 % of the example's floor) and 88.3 µm (51 % of this
/// test's floor — detected because the lag is coherent over 306 marker samples while the noise is
/// not). Tolerances: < 5 % and > 30 % of the respective floors, margins of 1.35× and 1.7× on the
/// measured values for solver-level changes.
#[test]
fn viscosity_signal_against_the_noise_floor() {
    let (_, model) = bar([1, 4, 1], STEPS);
    let clean = |nu: f64| record(&model, &truth(&model, nu), 0.0, 1).unwrap();
    let base = clean(0.0);
    let signal = |nu: f64| {
        let o = clean(nu);
        let (mut s, mut c) = (0.0, 0usize);
        for (a, b) in o
            .markers
            .iter()
            .flatten()
            .zip(base.markers.iter().flatten())
        {
            let (a, b) = (a.unwrap(), b.unwrap());
            s += (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>();
            c += 1;
        }
        (s / c as f64).sqrt()
    };
    let (s12, s400) = (signal(12.0), signal(400.0));
    eprintln!(
        "viscosity signal: nu 12 -> {:.2} µm, nu 400 -> {:.2} µm",
        1e6 * s12,
        1e6 * s400
    );
    assert!(s12 < 0.05 * 2e-4 * 3f64.sqrt(), "nu 12 signal {s12}");
    assert!(s400 > 0.3 * SIGMA * 3f64.sqrt(), "nu 400 signal {s400}");
}

/// Writes a motion dataset directory (docs/motion-dataset.md) for `ds`: its mesh, markers and
/// trajectories, the base's motion, and a header that leaves the time step and the noise to the
/// reader (as a user's dataset would).
fn write_dataset(ds: &MotionDataset, dir: &std::path::Path) {
    let mut config = DatasetToml::new(DT, vec!["front".into()]);
    config.density = Some(47.0);
    config.gravity = Some([0.0, -9.81, 0.0]);
    config.initial = ds.config.initial.clone();
    config.initial_declared = true;
    let markers: Vec<(String, [f64; 3])> = nine_markers(SIZE)
        .into_iter()
        .enumerate()
        .map(|(i, p)| (format!("m{i}"), p))
        .collect();
    let mut trajectories = Vec::new();
    for (n, row) in ds.obs.markers.iter().enumerate() {
        for (i, p) in row.iter().enumerate() {
            trajectories.push(StepRow {
                step: n + 1,
                name: format!("m{i}"),
                value: p.unwrap(),
            });
        }
    }
    let clamps = (0..=STEPS)
        .map(|n| StepRow {
            step: n,
            name: "front".into(),
            value: two_sinusoids(n as f64 * DT),
        })
        .collect();
    let files = MotionDatasetFiles {
        comments: Vec::new(),
        config,
        markers,
        trajectories,
        clamps: Some(ClampRows::Displacements(clamps)),
        forces: Vec::new(),
        decimals: Decimals::default(),
    };
    write_dataset_files(dir, &ds.mesh, &files).unwrap();
}

fn cli_args(dataset: &std::path::Path, out: &std::path::Path) -> palpate_diagnose::run::Request {
    palpate_diagnose::run::Request {
        dataset: dataset.to_path_buf(),
        output: out.to_path_buf(),
        candidates: Vec::new(),
        max_effects: Some(2),
        mesh: palpate_diagnose::MeshChoice::Auto,
        gauge_length: None,
        more_runs: Vec::new(),
        held_out: Vec::new(),
        poisson: None,
        design: None,
        motion_convergence: false,
        full_search: false,
    }
}

/// `palpate diagnose <dir>` recognises a motion dataset written to disk, names viscosity and
/// writes the report, the plot and the runtime model; a directory that is none of the known
/// inputs gets an error naming what was looked for.
#[test]
fn cli_recognises_a_motion_dataset_on_disk() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("viscous");
    std::fs::create_dir_all(&dir).unwrap();
    write_dataset(&specimen(400.0, 1), &dir);
    let out = tmp.path().join("report");
    palpate_diagnose::run::run(&cli_args(&dir, &out)).unwrap();
    for f in [
        "diagnosis.md",
        "diagnosis.json",
        "residual-vs-speed.svg",
        "model.palp",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let md = std::fs::read_to_string(out.join("diagnosis.md")).unwrap();
    assert!(md.contains("**Result**: adopted viscosity"), "{md}");
    let json = std::fs::read_to_string(out.join("diagnosis.json")).unwrap();
    let doc: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(doc["schema_version"], 1);
    assert!(doc["after"]["rms_fit_m"].as_f64().is_some(), "{doc}");
    assert!(doc["elastic"]["young_modulus_pa"].as_f64().unwrap() > 0.0);
    assert!(doc["after_values"][0]["unit"].is_string());
    let top = json
        .rfind("\"adopted\": [")
        .expect("top-level adopted list");
    assert!(json[top..]
        .trim_start_matches("\"adopted\": [")
        .trim_start()
        .starts_with("\"viscosity"));

    let empty = tmp.path().join("nothing");
    std::fs::create_dir_all(&empty).unwrap();
    std::fs::write(empty.join("readme.txt"), "not data").unwrap();
    let e = palpate_diagnose::run::run(&cli_args(&empty, &out))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("not a motion dataset") && e.contains("trajectories.csv"),
        "{e}"
    );
}

/// Markers glued off their declared places — an effect no option declares: each of the nine
/// markers sits a constant 0.3–0.6 mm (3–6 σ) from where `markers.csv` says, on the elastic
/// specimen. Without the marker-offsets candidate the diagnosis must not say "clean" (nothing
/// in its library explains the residual, which stands far above the floor); with it the
/// offsets are named and the forecast comes back to the floor.
#[test]
fn markers_off_their_declared_places_are_named_not_called_clean() {
    use palpate_diagnose::motion::{Candidate, ALL_CANDIDATES};
    let mut ds = specimen(0.0, 3);
    let offsets: Vec<[f64; 3]> = (0..9)
        .map(|i| {
            let a = 0.7 * i as f64;
            let r = 3e-4 + 3e-4 * (i % 4) as f64 / 3.0;
            [r * a.cos(), r * a.sin() * 0.6, r * 0.8 * (1.3 * a).sin()]
        })
        .collect();
    for row in &mut ds.obs.markers {
        for (p, c) in row.iter_mut().zip(&offsets) {
            if let Some(p) = p {
                for k in 0..3 {
                    p[k] += c[k];
                }
            }
        }
    }
    let floor = SIGMA * 3f64.sqrt();
    let without = MotionOptions {
        candidates: ALL_CANDIDATES
            .iter()
            .copied()
            .filter(|c| *c != Candidate::MarkerOffsets)
            .collect(),
        ..MotionOptions::default()
    };
    let r = diagnose(&ds, "offsets, no candidate", &without, &|m| {
        eprintln!("{m}")
    })
    .unwrap();
    eprintln!("without the candidate: {}", r.verdict());
    assert!(
        r.verdict().contains("NOT clean") || r.verdict().contains("still"),
        "{}",
        r.verdict()
    );
    assert!(r.after.rms_held > 2.0 * floor);
    let r = run(&ds, "offsets");
    eprintln!("with it: {}", r.verdict());
    assert!(
        r.adopted.iter().any(|a| a == "marker-offsets"),
        "adopted {:?}",
        r.adopted
    );
    assert!(
        r.after.rms_held < 1.2 * floor,
        "held-out RMS {:.1} µm against the floor {:.1} µm",
        1e6 * r.after.rms_held,
        1e6 * floor
    );
    assert!(!r.verdict().contains("NOT clean"), "{}", r.verdict());
}

/// One run of the runs diagnosis' example bar, hung with a heavy weight, of a material that
/// stiffens at larger strains (a Yeoh-type c (Ī₁ − 3)² beside Neo-Hookean, c = 5 μ): strained
/// far more than this file's bar (whose strains are too small for any c to show: at c = 200 μ
/// its elastic fit stays at the noise floor), it rings down from large to small amplitude, and
/// only a stiffening law fits both. The stiffening is named and c recovered.
#[test]
fn a_stiffening_bar_is_given_its_stiffening() {
    let (_, mut ds) = crate::diagnose_runs::stiffening_run("heavy", 0.03, 2);
    // The weight's inertia as recorded (this diagnosis has no candidate for it).
    for l in &mut ds.model.loads {
        l.inertia = true;
    }
    let r = run(&ds, "stiffening");
    // Named first (the truth's Newtonian damping after it), c recovered within 2 %.
    assert_eq!(
        r.adopted.first().map(String::as_str),
        Some("stiffening"),
        "{:?}",
        r.adopted
    );
    let c = r
        .after_values
        .iter()
        .find(|v| v.name == "stiffening")
        .unwrap();
    assert!((c.value / 5.0e4 - 1.0).abs() < 0.02, "{c:?}");
    // The forecast at the noise floor of this recording (σ = 20 µm per coordinate).
    let floor = 2e-5 * 3f64.sqrt();
    assert!(
        r.after.rms_held < 1.2 * floor,
        "{:.1} µm",
        1e6 * r.after.rms_held
    );
    assert!(r.before.rms_held > 10.0 * floor);
}

/// Every round's trial of candidate `name`, in round order.
fn trials_of<'r>(r: &'r MotionDiagnosis, name: &str) -> Vec<&'r palpate_diagnose::motion::Trial> {
    r.rounds
        .iter()
        .flat_map(|rd| &rd.trials)
        .filter(|t| t.candidate == name)
        .collect()
}

/// The bar of [`a_bar_of_two_materials_is_given_its_second_material`] with only the elements
/// that touch its clamp nine times as stiff (μ 90 kPa against 10 kPa): what a coarse mesh's own
/// error at a cantilever's root looks like to the sensitivity map. The two-material candidate
/// must not be adopted, and its row must say why: the region it found lies in the clamp's element
/// layer, where a material cannot be told from the mesh's error at a boundary.
#[test]
fn a_stiff_element_layer_at_the_clamp_is_refused_as_a_second_material() {
    use palpate_motion::model::ParamKind;
    let layer = |m: &Model| -> Vec<bool> {
        let clamped: Vec<usize> = m.clamps.iter().flat_map(|c| c.nodes.clone()).collect();
        m.tets
            .iter()
            .map(|t| t.iter().any(|n| clamped.contains(n)))
            .collect()
    };
    let stiff_root = |ds: &MotionDataset| {
        let mut t = Material::uniform(ds.model.tets.len(), 2.0e4, 1.0e4, 6.0, 1.0, 47.0);
        for (e, at) in layer(&ds.model).into_iter().enumerate() {
            if at {
                t.values[ParamKind::Mu as usize][e] = 9.0e4;
            }
        }
        t
    };
    let (_, mut ds) = crate::diagnose_runs::run_of("stiff-root", Some(0.03), 6, 0, &stiff_root);
    for l in &mut ds.model.loads {
        l.inertia = true;
    }
    let r = run(&ds, "stiff-root");
    // The hung weight is a known force: the moduli are absolute.
    assert!(r.relative.is_empty(), "{:?}", r.relative);
    assert!(
        !r.adopted.iter().any(|a| a == "two-material"),
        "{:?}",
        r.adopted
    );
    let tried = trials_of(&r, "two-material");
    assert!(!tried.is_empty(), "two-material never tried");
    for t in tried {
        assert!(
            !t.fitted
                && t.reason.contains("refused: a region of")
                && t.reason
                    .contains("discretisation error at a boundary is not a material"),
            "{}",
            t.reason
        );
    }
    // Nor is the root taken for a clamp that gives. The screen steps the layer stiffer and does
    // not fit it; fitted all the same (the screen off), its short fits from the body's μ and
    // softer layers end stiffer than the body, and the fit is not continued.
    let o = MotionOptions {
        mesh_null: false,
        screen: false,
        candidates: vec![palpate_diagnose::motion::Candidate::ClampCompliance],
        ..MotionOptions::default()
    };
    let r = diagnose(&ds, "stiff-root", &o, &|m| eprintln!("{m}")).unwrap();
    assert!(r.adopted.is_empty(), "{:?}", r.adopted);
    let fitted = trials_of(&r, "clamp-compliance");
    assert!(!fitted.is_empty(), "clamp-compliance never tried");
    for t in fitted {
        assert!(
            !t.fitted
                && t.reason
                    .contains("as stiff as the body in the best of 3 short fits")
                && t.reason.contains("not a clamp that gives"),
            "{}",
            t.reason
        );
    }
}

/// A bar of two materials: the half next to its moving base three times as stiff as the rest
/// (μ 30 kPa against 10 kPa, λ one value), Newtonian damping as the other runs of its kind,
/// hung with a 30 g weight as the stiffening bar (σ = 20 µm). The simplest model's one μ cannot
/// follow it (λ 58 kPa, μ 13.2 kPa: RMS 1,295 µm fitted, 2,284 µm held out). The misfit's
/// per-element μ sensitivity must place the second material where it is — the region must be
/// one of the truth's halves in at least 23 of 24 elements (measured: all 24, the best of 12
/// level sets of the map) —, the candidate must be adopted, both moduli recovered within 5 %
/// (measured 29,999 / 10,000 Pa) and the forecast brought to the noise floor (measured
/// 2,284 → 34.4 µm, floor σ√3 = 34.6 µm, with the damping adopted second).
///
/// Why the bounds are what they are: a region whose elements keep the λ of the one-material fit
/// (a global λ that does not reach the region) stops the refit at 371 µm with μ 19.7 / 12.3 kPa,
/// and a sign split of the map takes one element too many.
#[test]
fn a_bar_of_two_materials_is_given_its_second_material() {
    use palpate_motion::model::ParamKind;
    let centre_y =
        |m: &Model, e: usize| m.tets[e].iter().map(|&n| m.nodes[n][1]).sum::<f64>() / 4.0;
    let near = |m: &Model| -> Vec<bool> {
        (0..m.tets.len())
            .map(|e| centre_y(m, e) < 0.5 * SIZE[1])
            .collect()
    };
    let two = |ds: &MotionDataset| {
        let mut t = Material::uniform(ds.model.tets.len(), 2.0e4, 1.0e4, 6.0, 1.0, 47.0);
        for (e, n) in near(&ds.model).into_iter().enumerate() {
            if n {
                t.values[ParamKind::Mu as usize][e] = 3.0e4;
            }
        }
        t
    };
    let (_, mut ds) = crate::diagnose_runs::run_of("two-material", Some(0.03), 6, 0, &two);
    for l in &mut ds.model.loads {
        l.inertia = true;
    }
    let near = near(&ds.model);
    let r = run(&ds, "two-material");
    assert!(
        r.adopted.iter().any(|a| a == "two-material"),
        "{:?}",
        r.adopted
    );
    let mat = r.material.as_ref().unwrap();
    let region = &mat.regions[0];
    // The region is one of the two halves: its elements the stiff ones or the soft ones.
    let agree = (0..near.len())
        .filter(|&e| region.contains(&e) == near[e])
        .count();
    let agree = agree.max(near.len() - agree);
    assert!(agree + 1 >= near.len(), "{agree} of {}", near.len());
    let mean_mu = |which: bool| {
        let es: Vec<usize> = (0..near.len()).filter(|&e| near[e] == which).collect();
        es.iter().map(|&e| mat.get(ParamKind::Mu, e)).sum::<f64>() / es.len() as f64
    };
    let (stiff, soft) = (mean_mu(true), mean_mu(false));
    eprintln!("μ near the base {stiff:.0} Pa, far {soft:.0} Pa");
    assert!(
        (stiff / 3.0e4 - 1.0).abs() < 0.05 && (soft / 1.0e4 - 1.0).abs() < 0.05,
        "near {stiff} far {soft}"
    );
    // The floor of this recording (σ = 20 µm, `run_of`), not of the module's σ = 100 µm runs:
    // measured 34.4 µm held out against 34.6 µm; 1.2 × the floor (41.5 µm) is the margin the
    // other forecasts at the floor in this file keep.
    let floor = 2e-5 * 3f64.sqrt();
    assert!(
        r.after.rms_held < 1.2 * floor,
        "{:?} -> {:?}",
        r.before,
        r.after
    );
}

/// A clamp that gives: the drawn specimen whose elements at the shaken face are softened as a
/// whole (`palpate_specimen::motion`, clamp-compliance, seed 4: λ and μ × 0.17 there). The
/// diagnosis must name the clamp's give first and alone, put the layer within the drawn range
/// (0.15–0.5× the body; measured 0.170×), recover the body's μ within 2 % (measured 7,498.7 Pa
/// for 7,493.0) and forecast at the noise floor (measured 32.0 µm held out, floor σ√3 =
/// 34.6 µm). The simplest model fitted to this bar drives λ down to explain the soft root;
/// before every fit started λ at 1 % of μ or more
/// (`palpate_diagnose::motion::fit::LAMBDA_START_RATIO`) it stayed at 10⁻⁸ Pa in every later
/// fit and the layer's fit stopped at 3.2 mm.
#[test]
fn a_clamp_that_gives_is_named() {
    let (r, truth) = drawn(MotionEffect::ClampCompliance, 4);
    assert_eq!(r.adopted, ["clamp-compliance"]);
    let (mu, layer) = (final_value(&r, "mu"), final_value(&r, "mu of the layer"));
    assert!(
        (0.15..0.5).contains(&(layer / mu)),
        "layer {layer}, body {mu}"
    );
    assert_body_and_floor(&r, &truth);
}

/// A candidate whose screen step holds every new parameter at its neutral value is the current
/// model: its prediction is its BIC charge alone (a whole number of ln n), not the gain the
/// current parameters' own step promises. On the drawn bar whose clamp gives, the simplest fit
/// stops far from its minimum (17.7 mm RMS), where that step promises 61 % of Φ; the stiffening
/// and the objective viscosity are held there in round 1.
#[test]
fn a_candidate_held_at_its_neutral_value_predicts_its_charge_alone() {
    let (r, _) = drawn(MotionEffect::ClampCompliance, 4);
    let ln_n = (r.before.n_fit as f64).ln();
    let mut held: Vec<(&str, f64)> = r
        .rounds
        .iter()
        .flat_map(|rd| &rd.trials)
        .filter(|t| t.reason.contains("the current model, no gain predicted"))
        .map(|t| (t.candidate.as_str(), t.predicted_delta_bic.unwrap()))
        .collect();
    // Round 1's, by name: the two whose step goes below 0 there.
    for name in ["stiffening", "viscosity-objective"] {
        let t = r.rounds[0]
            .trials
            .iter()
            .find(|t| t.candidate == name)
            .unwrap();
        assert!(t.reason.contains("held there"), "{name}: {}", t.reason);
        held.push((name, t.predicted_delta_bic.unwrap()));
    }
    for (c, d) in held {
        let charged = (d / ln_n).round();
        assert!(
            charged >= 1.0 && (d - charged * ln_n).abs() < 1e-9 * d,
            "{c}: predicted {d} is not a charge of whole parameters (ln n = {ln_n})"
        );
    }
}

/// A gravity turned by 2.2° from the declared one (the drawn specimen of seed 4: toward +x) is
/// named first and alone, the turn and the gravity acting read back, and the forecast comes to
/// the noise floor.
#[test]
fn a_turned_gravity_is_named() {
    let (r, truth) = drawn(MotionEffect::GravityDirection, 4);
    assert_eq!(r.adopted, ["gravity-direction"]);
    // The truth's gravity, as the specimen's detail gives it.
    let g_truth = [0.383, -9.803, -0.018];
    assert!(
        truth.detail.contains("(0.383, -9.803, -0.018)"),
        "{}",
        truth.detail
    );
    for (axis, want) in ["x", "y", "z"].into_iter().zip(g_truth) {
        let got = final_value(&r, &format!("gravity acting, {axis}"));
        assert!((got - want).abs() < 0.01, "g_{axis} {got} for {want}");
    }
    assert_body_and_floor(&r, &truth);
}

/// Marker offsets hold a turned gravity's parameters: where a turn passed beside the offsets
/// adopted (the drawn marker-offsets specimen of seed 2), the verdict says it is not ruled out
/// instead of leaving it unmentioned.
#[test]
fn a_turn_the_offsets_hide_is_not_ruled_out() {
    let (r, _) = drawn(MotionEffect::MarkerOffsets, 2);
    assert_eq!(r.adopted, ["marker-offsets"]);
    let v = r.verdict();
    assert!(
        v.contains("gravity-direction passed too in round 1")
            && v.contains("it cannot be told from them: it is not ruled out"),
        "{v}"
    );
}
