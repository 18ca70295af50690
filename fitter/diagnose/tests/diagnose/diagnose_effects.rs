//! `diagnose` on specimens (Neo-Hookean truth on a 2× finer mesh, linear warped model on
//! the dataset's 6 × 6 × 3 box). A clean specimen must come back clean; injected effects must be
//! named, with the RMS marker error after adoption within 1.5× the declared noise floor σ√3
//! (σ = 100 µm declared → floor 173.2 µm; the tolerance is the issue's own 1.5×). Measured on
//! the committed code: clean 201.8 µm (1.17×), registration 201.5 µm (1.16×), boundary 201.7 µm
//! (seed 1, 1.16×). Each diagnosis (one adoption round) takes 15–40 s in release on a quiet 2-core
//! machine, more than the few seconds the team rules ask for: these are the loop's end-to-end
//! checks and cannot be made smaller without making the specimens too coarse to mean anything.

use crate::support::drawn;
use crate::support::summary;
use palpate_diagnose::export::runtime_fit;
use palpate_diagnose::model::{Candidate, Context};
use palpate_diagnose::{run_diagnosis, DiagnoseOptions, MeshChoice};
use palpate_fem::dataset::StaticDataset;
use palpate_specimen::{Effect, SpecimenOptions};

fn diagnose(effect: Option<Effect>, seed: u64) -> palpate_diagnose::DiagnosisReport {
    // One adoption round is what these tests assert on (the first effect named and the error
    // after it); the second round would re-try all remaining candidates and double the time.
    // The full loop runs in `palpate-lab diagnose-evidence` (docs/results/diagnose/confusion/confusion.md).
    // On the dataset's own mesh: these check the selection loop, whose decisions the refined
    // mesh only sharpens (`diagnose_refined_mesh_reaches_the_noise_floor` checks the refinement),
    // at an eighth of the cost.
    let s = drawn(&SpecimenOptions::with_effect(effect, seed)).expect("specimen");
    let r = one_round(&s.dataset);
    eprintln!(
        "{effect:?} seed {seed}: {}; {:.1} s",
        summary(&r),
        r.seconds
    );
    r
}

/// One adoption round on the dataset's own mesh (why: [`diagnose`]).
fn one_round(dataset: &StaticDataset) -> palpate_diagnose::DiagnosisReport {
    let o = DiagnoseOptions {
        max_effects: 1,
        mesh: MeshChoice::Dataset,
        ..Default::default()
    };
    run_diagnosis(dataset, &o).expect("diagnosis")
}

#[test]
fn diagnose_clean_specimen_adopts_nothing() {
    let r = diagnose(None, 1);
    assert!(r.adopted.is_empty(), "adopted {:?}", r.adopted);
    // diagnosis.json: a schema version, units in the field names, the base material as Lamé's
    // λ, μ and E, ν.
    let json: serde_json::Value =
        serde_json::from_str(&palpate_diagnose::report::json_text(&r).unwrap()).unwrap();
    assert_eq!(json["schema_version"], 1);
    assert_eq!(json["kind"], "static-diagnosis");
    assert!(
        json["after"]["fitted_rms_m"].as_f64().unwrap() > 0.0,
        "{json}"
    );
    assert!(json["after"].get("fitted_rms").is_none());
    assert!(json["noise_floor_m"].as_f64().unwrap() > 0.0);
    for k in [
        "lame_lambda_pa",
        "shear_modulus_pa",
        "young_modulus_pa",
        "poisson_ratio",
    ] {
        assert!(json["elastic"][k].as_f64().unwrap() > 0.0, "{k}: {json}");
    }
    assert!(
        r.after.fitted_rms <= 1.5 * r.noise_floor,
        "clean residual {:e} vs floor {:e}",
        r.after.fitted_rms,
        r.noise_floor
    );
    // A force-driven fit determines E over the force sensor's gain: the report says so in its
    // text and its JSON, though no effect was adopted.
    let relative = json["identifiability"]["relative"].as_array().unwrap();
    assert!(
        relative.iter().any(|w| w
            .as_str()
            .is_some_and(|w| w.contains("E/gain is determined, not E"))),
        "{relative:?}"
    );
    let md = palpate_diagnose::report::markdown(&r, &[]);
    assert!(
        md.contains("Young's modulus E is relative to the force gain"),
        "{md}"
    );
}

fn named(effect: Effect, candidate: Candidate) {
    for seed in [1, 2] {
        let r = diagnose(Some(effect), seed);
        assert_eq!(
            r.adopted.first(),
            Some(&candidate),
            "seed {seed}: adopted {:?}",
            r.adopted
        );
        assert!(
            r.after.fitted_rms <= 1.5 * r.noise_floor,
            "seed {seed}: residual after {:e} vs floor {:e}",
            r.after.fitted_rms,
            r.noise_floor
        );
        assert!(
            r.after.heldout_rms < r.before.heldout_rms,
            "seed {seed}: held-out error did not drop"
        );
    }
}

#[test]
fn diagnose_names_registration_offset() {
    named(Effect::Registration, Candidate::Registration);
}

#[test]
fn diagnose_names_compliant_boundary() {
    named(Effect::Boundary, Candidate::Boundary);
}

/// `--mesh auto` on the clean specimen: the dataset mesh's discretisation error is 114 µm RMS,
/// 66 % of the 173.2 µm floor, and the residual is corrected by the approximation error from the
/// mesh refined once (5,184 tets). With it the simplest model's
/// residual is down to the marker noise (measured on the refined mesh itself: 168.3 µm vs
/// 201.8 µm uncorrected; asserted ≤ 1.02 × floor, as the RMS of 3 × 8 × ~95 noise samples scatters
/// by ≈ 1.5 %) and E is the truth's within 5 % (20.76 kPa vs 20 kPa refined; the rest is
/// Neo-Hookean vs linear at these strains). One candidate only (gravity) keeps it short; nothing
/// may be adopted.
#[test]
fn diagnose_corrected_mesh_reaches_the_noise_floor() {
    let s = drawn(&SpecimenOptions::default()).expect("specimen");
    let o = DiagnoseOptions {
        candidates: vec![Candidate::Gravity],
        max_effects: 1,
        ..Default::default()
    };
    let r = run_diagnosis(&s.dataset, &o).expect("diagnosis");
    assert_eq!(
        r.solved_on.choice,
        MeshChoice::Corrected,
        "{}",
        r.solved_on.reason
    );
    let delta = r.solved_on.correction_rms.expect("a correction");
    assert!(delta > 50e-6, "correction δ {delta:e} m RMS");
    assert!(r.adopted.is_empty(), "adopted {:?}", r.adopted);
    assert!(
        r.before.fitted_rms <= 1.02 * r.noise_floor,
        "corrected residual {:e} vs floor {:e}",
        r.before.fitted_rms,
        r.noise_floor
    );
    assert!(
        r.solved_on.dataset_mesh_rms > 1.1 * r.before.fitted_rms,
        "the dataset mesh's residual {:e} should be well above the corrected one {:e}",
        r.solved_on.dataset_mesh_rms,
        r.before.fitted_rms
    );
    assert!(
        (r.young_poisson.0 / 20e3 - 1.0).abs() < 0.05,
        "E = {}",
        r.young_poisson.0
    );
    // The runtime runs the dataset mesh: the exported model is the final model refitted there
    // without the correction. Its residual is the uncorrected fit's (201.8 µm; 1e-3 relative: the
    // same least-squares problem from another start), and here its E is the object's within 2 %
    // (measured 20.87 vs 20.85 kPa): this mesh's error is a local shape error under the probe,
    // not a global stiffness bias, so the physical E is also the right one to play back.
    let (ctx, f) = runtime_fit(&r).expect("runtime fit");
    assert!(ctx.correction.is_none());
    let e = f.theta[0].exp();
    assert!(
        (e / r.young_poisson.0 - 1.0).abs() < 0.02,
        "exported E {e} vs {}",
        r.young_poisson.0
    );
    let rms = (3.0 * f.chi2 / f.n as f64).sqrt() * ctx.sigma;
    assert!(
        (rms / r.solved_on.dataset_mesh_rms - 1.0).abs() < 1e-3,
        "exported model's residual {rms:e} vs the dataset mesh's {:e}",
        r.solved_on.dataset_mesh_rms
    );
}

/// A different registration offset in every measurement (0.5° about a random axis, 0.5 mm, as
/// the independent generator injects it), applied to a clean specimen's measured markers: the
/// global registration cannot explain it, `registration-each` must, down to the noise floor.
#[test]
fn diagnose_names_a_registration_that_differs_per_measurement() {
    use palpate_fem::rng::SplitMix64 as Rng;
    let mut s = drawn(&SpecimenOptions::with_effect(None, 3)).expect("specimen");
    let (lo, hi) = s.dataset.mesh.bounds();
    let centre = [0, 1, 2].map(|d| 0.5 * (lo[d] + hi[d]));
    let mut rng = Rng::new(11);
    for m in &mut s.dataset.measurements {
        let axis = nalgebra::Unit::new_normalize(nalgebra::Vector3::new(
            rng.normal(),
            rng.normal(),
            rng.normal(),
        ));
        let r = nalgebra::Rotation3::from_axis_angle(&axis, 0.5f64.to_radians());
        let t = nalgebra::Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize() * 5e-4;
        for (_, p) in &mut m.observed {
            let q = r * (nalgebra::Vector3::from(*p) - nalgebra::Vector3::from(centre))
                + nalgebra::Vector3::from(centre)
                + t;
            *p = [q.x, q.y, q.z];
        }
    }
    let r = names_per_measurement(
        "per-measurement registration",
        &s.dataset,
        Candidate::RegistrationEach,
    );
    assert!(r.before.fitted_rms > 2.0 * r.noise_floor);
}

/// An unreported tangential force of 0.3·|f| in a direction that changes from measurement to
/// measurement (friction at the tip; the independent generator's case): the reported forces of a
/// clean specimen lose that component. One global tilt cannot explain it; `tilt-each` must.
#[test]
fn diagnose_names_a_tangential_force_that_differs_per_measurement() {
    use palpate_fem::rng::SplitMix64 as Rng;
    let mut s = drawn(&SpecimenOptions::with_effect(None, 4)).expect("specimen");
    let mut rng = Rng::new(5);
    for m in &mut s.dataset.measurements {
        let f = nalgebra::Vector3::from(m.force);
        let n = f.normalize();
        let any = if n.x.abs() < 0.9 {
            nalgebra::Vector3::x()
        } else {
            nalgebra::Vector3::y()
        };
        let t1 = n.cross(&any).normalize();
        let t2 = n.cross(&t1);
        let phi = 2.0 * std::f64::consts::PI * rng.uniform();
        let t = t1 * phi.cos() + t2 * phi.sin();
        let reported = f - t * (0.3 * f.norm());
        m.force = [reported.x, reported.y, reported.z];
    }
    names_per_measurement(
        "per-measurement tangential force",
        &s.dataset,
        Candidate::TiltEach,
    );
}

/// One adoption round on a specimen with a per-measurement effect (`label`): `candidate` must be
/// the first adopted, and the held-out error after it within 1.5× the noise floor.
fn names_per_measurement(
    label: &str,
    dataset: &StaticDataset,
    candidate: Candidate,
) -> palpate_diagnose::DiagnosisReport {
    let r = one_round(dataset);
    eprintln!(
        "{label}: {}; {}",
        summary(&r),
        r.residual_check.verdict("…")
    );
    assert_eq!(r.adopted.first(), Some(&candidate), "{:?}", r.adopted);
    assert!(
        r.after.heldout_rms <= 1.5 * r.noise_floor,
        "{}",
        r.after.heldout_rms
    );
    r
}

/// An effect whose residual sits below the noise floor (widened by the mesh's remaining error)
/// is still named when the held-out data support it strongly: the default stiffening of seed 1
/// leaves the simplest model at 171.3 µm against the 173.2 µm floor, so the held-out gain in
/// excess of the floor is 0/0 — which used to veto it (verdict "clean", with stiffening at
/// ΔBIC −35.2 and held-out ΔBIC −24.9); there the held-out ΔBIC must clear −10 instead. With
/// the approximation-error correction (the default), where the widened floor applies.
#[test]
fn an_effect_below_the_floor_is_named_on_held_out_evidence() {
    let s = drawn(&SpecimenOptions::with_effect(Some(Effect::Stiffening), 1)).expect("specimen");
    let o = DiagnoseOptions {
        max_effects: 1,
        ..Default::default()
    };
    let r = run_diagnosis(&s.dataset, &o).expect("diagnosis");
    eprintln!("stiffening seed 1 (corrected mesh): {}", summary(&r));
    assert!(
        r.before.heldout_rms < r.noise_floor,
        "the case needs a residual below the floor: {}",
        summary(&r)
    );
    assert_eq!(r.adopted, vec![Candidate::Stiffening], "{}", summary(&r));
    assert!(
        r.after.heldout_rms < r.before.heldout_rms,
        "{}",
        summary(&r)
    );
}

/// An elastic (Winkler) foundation under the supported face: the clean specimen's markers moved
/// by what springs of ℓ_n = 0.3 h (k_n = E/ℓ_n, h the half width) and k_t = k_n / 2 under the
/// bottom add to each measurement — the difference between the warped linear solves on springs
/// and on the fixed face at the truth's E and ν (the Neo-Hookean truth keeps the rest of the
/// signal). The rigid `boundary` motion cannot bend the base; `support` must be named first, with
/// ℓ_n within a fifth of the truth's, and the held-out error within 1.1× the floor. Measured:
/// adopted first, 214.6 → 171.9 µm (held out 216.3 → 172.8; floor 173.2), ℓ_n/h = 0.319 for 0.3.
#[test]
fn diagnose_names_an_elastic_foundation() {
    use palpate_fem::forward::{Foundation, Load, Material, SolveOptions, StaticProblem};
    let mut s = drawn(&SpecimenOptions::with_effect(None, 6)).expect("specimen");
    let ds = &s.dataset;
    let (lo, hi) = ds.mesh.bounds();
    let half = 0.5 * (hi[0] - lo[0]).min(hi[1] - lo[1]);
    let (e, nu) = (s.truth.options.young, s.truth.options.poisson);
    let held = StaticProblem::new(&ds.mesh, &ds.fixed_nodes, &ds.surface).unwrap();
    let springs = StaticProblem::on_foundation(&ds.mesh, &ds.fixed_nodes, &ds.surface).unwrap();
    let fixed_mat = Material::from_young_poisson(e, nu);
    let mut spring_mat = fixed_mat.clone();
    let l_n = 0.3 * half;
    spring_mat.foundation = Some(Foundation {
        normal: e / l_n,
        tangential: 0.5 * e / l_n,
    });
    let opts = SolveOptions::default();
    let markers = ds.markers.clone();
    let mut largest: f64 = 0.0;
    for m in &mut s.dataset.measurements {
        let load = Load::contact(m.contact, m.force, m.radius);
        let a = held.solve(&fixed_mat, &load, &opts).unwrap().x;
        let b = springs.solve(&spring_mat, &load, &opts).unwrap().x;
        for (k, p) in &mut m.observed {
            let (pa, pb) = (
                markers[*k].interpolate(|n| a[n]),
                markers[*k].interpolate(|n| b[n]),
            );
            for d in 0..3 {
                p[d] += pb[d] - pa[d];
                largest = largest.max((pb[d] - pa[d]).abs());
            }
        }
    }
    eprintln!(
        "elastic foundation: largest marker shift {:.1} µm",
        1e6 * largest
    );
    // On the mesh the diagnosis chooses (the dataset mesh with the approximation-error correction):
    // on the 648 tets alone the mesh's own error is what the candidates compete for, and `layer`
    // ranks first (measured: support fifth, 196.4 µm against layer's 190.8).
    let o = DiagnoseOptions {
        max_effects: 1,
        ..Default::default()
    };
    let r = run_diagnosis(&s.dataset, &o).expect("diagnosis");
    eprintln!(
        "elastic foundation: {}; {}; {:.1} s",
        summary(&r),
        r.residual_check.verdict("…"),
        r.seconds
    );
    assert_eq!(
        r.adopted.first(),
        Some(&Candidate::Support),
        "{:?}",
        r.adopted
    );
    assert!(
        r.after.heldout_rms <= 1.1 * r.noise_floor,
        "held out {:e} vs floor {:e}",
        r.after.heldout_rms,
        r.noise_floor
    );
    let fitted = r
        .final_params
        .iter()
        .find(|p| p.name.starts_with("foundation ln(ℓ_n/h)"))
        .expect("the foundation's thickness in the final parameters")
        .value
        .exp();
    eprintln!("ℓ_n/h fitted {fitted:.3}, truth 0.3");
    assert!((fitted / 0.3 - 1.0).abs() < 0.2, "ℓ_n/h = {fitted}");
    assert!(r.before.heldout_rms > 1.2 * r.noise_floor);
}

/// A soft top layer (the specimen's top quarter at a quarter of the body's E, 1 cm of its 4 cm):
/// `layer` is named first, soft, about as thick as it is, and E is the body's below it — on the
/// mesh the diagnosis chooses (the dataset mesh, 648 tets three elements deep, with the
/// approximation-error correction from the mesh refined once). Three elements deep, the layer's
/// edge is an element wide, so thickness and contrast trade against each other (measured:
/// 0.18× E over 0.22 of the depth for the truth's 0.25× over 0.25; E 20.41 kPa for 20; held out
/// 256.1 → 181.0 µm against a 173.2 µm floor). (Seed 2's specimen names `inhomogeneity` first:
/// the confusion table, docs/results/diagnose/confusion/.)
#[test]
fn diagnose_names_a_soft_layer_and_the_body_below_it() {
    let seed = 1;
    let s = drawn(&SpecimenOptions::with_effect(Some(Effect::SoftLayer), seed)).expect("specimen");
    let o = DiagnoseOptions {
        max_effects: 1,
        ..Default::default()
    };
    let r = run_diagnosis(&s.dataset, &o).expect("diagnosis");
    eprintln!(
        "soft layer, seed {seed}: {}; {:.1} s",
        summary(&r),
        r.seconds
    );
    assert_eq!(
        r.adopted.first(),
        Some(&Candidate::Layer),
        "seed {seed}: {:?}",
        r.adopted
    );
    let value = |prefix: &str| {
        r.final_params
            .iter()
            .find(|p| p.name.starts_with(prefix))
            .unwrap_or_else(|| panic!("{prefix} in {:?}", r.final_params))
            .value
    };
    let contrast = value("log contrast a of the layer").exp();
    // The block's push and vertical depth maps are the same: either axis' least thickness.
    let ctx = Context::new(&s.dataset, o.grid).expect("context");
    let thickness = ctx.layer.thickness(value("layer thickness"));
    let young = value("Young's modulus E");
    eprintln!(
            "seed {seed}: contrast {contrast:.3} (truth 0.25), thickness {thickness:.3} of the depth (truth 0.25), E {:.2} kPa (truth 20)",
            1e-3 * young
        );
    assert!(
        contrast > 0.1 && contrast < 0.5,
        "seed {seed}: contrast {contrast}"
    );
    assert!(
        (thickness - 0.25).abs() < 0.1,
        "seed {seed}: thickness {thickness}"
    );
    assert!((young / 20e3 - 1.0).abs() < 0.1, "seed {seed}: E {young}");
    assert!(
        r.after.heldout_rms < 0.8 * r.before.heldout_rms,
        "seed {seed}: held out {:e} from {:e}",
        r.after.heldout_rms,
        r.before.heldout_rms
    );
}
