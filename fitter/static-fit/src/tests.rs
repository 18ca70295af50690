//! Static-fit checks: exactness on noise-free data, Jacobian products against finite differences,
//! recovery under marker noise.

use super::displacement::{DisplacementOptions, Objective};
use super::force::{fit_force, ForceOptions};
use super::synthetic::{synthesise, SyntheticSpec};
use super::*;
use palpate_fem::forward::SolveOptions;
use palpate_runtime::material::LambdaAlpha;

fn rel(a: f64, b: f64) -> f64 {
    ((a - b) / b).abs()
}

/// The default block of `cells` seen through `markers` markers with Gaussian marker noise
/// σ = `noise` (m) drawn from `seed`.
fn noisy_block(cells: [usize; 3], markers: usize, noise: f64, seed: u64) -> SyntheticSpec {
    SyntheticSpec {
        markers,
        noise,
        seed,
        ..SyntheticSpec::block(cells)
    }
}

/// Noise-free synthetic data with every node known: the homogeneous force-based fit is exact
/// (the true (λ, α) solve A(x̄)p = f̄ exactly); the tolerance is the fixed-point tolerance of the
/// data generation (1e-10 m on ~1 mm displacements).
#[test]
fn force_fit_is_exact_on_noise_free_data() {
    let spec = SyntheticSpec::block([4, 4, 2]);
    let syn = synthesise(&spec).unwrap();
    let forces: Vec<Vec<f64>> = syn
        .input
        .measurements
        .iter()
        .map(|m| m.force.clone())
        .collect();
    for (warp, sets) in [(true, Sets::Single), (true, Sets::PerMeasurement)] {
        let opts = ForceOptions {
            layout: Layout::Homogeneous,
            sets,
            warp,
            gammas: Gammas::uniform(0.0),
        };
        let fit = fit_force(&syn.input.problem, &syn.exact, &forces, &opts).unwrap();
        for m in &fit.params {
            assert!(
                rel(m.lambda[0], syn.truth.lambda[0]) < 1e-6,
                "λ {} vs {}",
                m.lambda[0],
                syn.truth.lambda[0]
            );
            assert!(
                rel(m.alpha[0], syn.truth.alpha[0]) < 1e-6,
                "α {} vs {}",
                m.alpha[0],
                syn.truth.alpha[0]
            );
        }
        let fmax = forces[0].iter().fold(0.0f64, |a, v| a.max(v.abs()));
        assert!(
            fit.force_residuals.iter().all(|r| *r < 1e-5 * fmax),
            "{:?}",
            fit.force_residuals
        );
    }
    // Without warping the warped data is not reproduced exactly: the linear fit is biased.
    let opts = ForceOptions {
        layout: Layout::Homogeneous,
        sets: Sets::Single,
        warp: false,
        gammas: Gammas::uniform(0.0),
    };
    let fit = fit_force(&syn.input.problem, &syn.exact, &forces, &opts).unwrap();
    assert!(fit.force_residuals[0] > 1e-5 * forces[0].iter().fold(0.0f64, |a, v| a.max(v.abs())));
}

/// Inhomogeneous force-based fit with full noise-free data and light smoothing reproduces the
/// observed forces and marker positions closely (the system is underdetermined, so the parameters
/// themselves are not unique; the forward model with them must still match the data).
#[test]
fn force_fit_with_completion_matches_markers() {
    let mut spec = SyntheticSpec::block([4, 4, 2]);
    spec.contacts.truncate(2);
    let syn = synthesise(&spec).unwrap();
    let mut o = FitOptions::new(Method::Force, Layout::Homogeneous, Sets::Single);
    o.max_iterations = 20;
    let r = fit_static(&syn.input, &o, |_, _| {}).unwrap();
    // Markers on every free surface node, interior completed by alternation: converges to truth.
    assert!(
        rel(r.params[0].lambda[0], syn.truth.lambda[0]) < 1e-3,
        "λ {}",
        r.params[0].lambda[0]
    );
    assert!(r.rms() < 1e-7, "rms {}", r.rms());
}

/// Jacobian products by the direct and adjoint method against central finite differences of the
/// forward model with the rotations frozen (the model the Jacobian differentiates, eqs.
/// 5.71–5.73), and the adjoint identity uᵀ(Jv) = (Jᵀu)ᵀv.
#[test]
fn jacobian_products_match_finite_differences() {
    let mut spec = SyntheticSpec::block([4, 4, 2]);
    spec.contacts.truncate(2);
    spec.markers = 20;
    spec.inclusion = Some(([0.05, 0.05, 0.03], 0.03, 60_000.0));
    let syn = synthesise(&spec).unwrap();
    let mut o = DisplacementOptions::new(Layout::Inhomogeneous, Sets::PerMeasurement);
    o.solve = SolveOptions {
        tolerance: 1e-13,
        ..Default::default()
    };
    let obj = Objective::new(&syn.input, &o);
    let n = obj.lay.len();
    let mut q = obj.initial_q();
    for (k, v) in q.iter_mut().enumerate() {
        *v += 0.2 * ((k as f64 * 0.77).sin());
    }
    let (mats, jacs) = obj.materials(&q);
    let states = obj.states(&mats, None).unwrap();
    let v: Vec<f64> = (0..n).map(|k| ((k as f64) * 1.3).cos()).collect();
    let p = &syn.input.problem;
    for (i, s) in states.iter().enumerate() {
        let jac = &jacs[obj.lay.set_of(i)];
        let jv = obj.jv(i, s, jac, &v);
        // Frozen-rotation forward model at q ± h v.
        let h = 1e-6;
        let rot = p.rotations(&s.x, true);
        let eval = |sign: f64| -> Vec<f64> {
            let qq: Vec<f64> = q.iter().zip(&v).map(|(a, b)| a + sign * h * b).collect();
            let (m, _) = obj.materials(&qq);
            let mat = &m[obj.lay.set_of(i)];
            let rot_used = &rot;
            let mut b = p.rhs(mat, rot_used, &syn.input.measurements[i].force);
            p.factorise(mat, rot_used).unwrap().solve_in_place(&mut b);
            let x = p.positions_from_free(&b);
            syn.input
                .marker_errors(i, &x)
                .iter()
                .flat_map(|(_, e)| e.map(|c| c / o.sigma))
                .collect()
        };
        let (rp, rm) = (eval(1.0), eval(-1.0));
        let fd: Vec<f64> = rp
            .iter()
            .zip(&rm)
            .map(|(a, b)| (a - b) / (2.0 * h))
            .collect();
        let scale = fd.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        assert!(scale > 1e-3, "perturbation should move markers");
        for (a, b) in jv.iter().zip(&fd) {
            // Central differences with h = 1e-6: truncation ~h² and round-off ~1e-16/h ≈ 1e-10
            // relative to the residual; 1e-5 of the largest entry is a safe bound.
            assert!((a - b).abs() <= 1e-5 * scale, "J v {a} vs FD {b}");
        }
        // Adjoint identity.
        let u: Vec<f64> = (0..jv.len()).map(|k| ((k as f64) * 0.31).sin()).collect();
        let mut jtu = vec![0.0; n];
        obj.jtu(i, s, jac, &u, &mut jtu);
        let lhs: f64 = u.iter().zip(&jv).map(|(a, b)| a * b).sum();
        let rhs: f64 = jtu.iter().zip(&v).map(|(a, b)| a * b).sum();
        assert!(
            (lhs - rhs).abs() <= 1e-10 * lhs.abs().max(rhs.abs()),
            "uᵀJv {lhs} vs (Jᵀu)ᵀv {rhs}"
        );
    }
}

/// Homogeneous E and ν recovered within 1% from 0.1 mm marker noise on a 10 cm block
/// (displacement-based, warped, 4 contacts, 120 markers). With ~1–3 mm displacements and
/// 1440 noisy coordinates, the statistical error of E is ~0.1–0.3%: 1% is the bar.
#[test]
fn homogeneous_recovered_within_one_percent_at_tenth_mm_noise() {
    let syn = synthesise(&noisy_block([5, 5, 3], 120, 1e-4, 7)).unwrap();
    let mut o = FitOptions::new(Method::Displacement, Layout::Homogeneous, Sets::Single);
    o.initial = LambdaAlpha::from_young_poisson(8_000.0, 0.1);
    let r = fit_static(&syn.input, &o, |_, _| {}).unwrap();
    let fitted = LambdaAlpha {
        lambda: r.params[0].lambda[0],
        alpha: r.params[0].alpha[0],
    };
    let truth = LambdaAlpha {
        lambda: syn.truth.lambda[0],
        alpha: syn.truth.alpha[0],
    };
    assert!(
        rel(fitted.young(), truth.young()) < 0.01,
        "E {} vs {}",
        fitted.young(),
        truth.young()
    );
    assert!(
        rel(fitted.poisson(), truth.poisson()) < 0.01,
        "ν {} vs {}",
        fitted.poisson(),
        truth.poisson()
    );
    // The fit error reaches the noise floor: RMS of 3-D errors ≈ σ√3 when the model is right.
    let floor = 1e-4 * 3f64.sqrt();
    assert!(
        r.rms() < 1.1 * floor && r.rms() > 0.8 * floor,
        "rms {} vs floor {floor}",
        r.rms()
    );
}

/// The stiff inclusion (3× stiffer sphere) is found: the fitted log E map correlates with the
/// truth, and the fit error reaches the noise floor σ√3. Measured on this 5×5×3-cell block at
/// σ = 0.1 mm, γ_s = 3 (the trade-off scan of `palpate-lab bench fit --evidence` gives correlation
/// 0.68 at γ_s = 1, 0.69 at 3, 0.55 at 10; RMS 0.163, 0.171, 0.181 mm against the floor 0.173 mm):
/// measured 0.69 and 0.171 mm. Bounds: correlation > 0.6, RMS within 0.9–1.05 × floor.
#[test]
fn inclusion_map_correlates_with_truth_at_noise_floor() {
    let (syn, fit) = evidence::inclusion_case([5, 5, 3], 1e-4, 3.0).unwrap();
    let f = evidence::inclusion_figures(&syn, &fit);
    eprintln!("inclusion: {f:?}");
    assert!(f.correlation > 0.6, "correlation {}", f.correlation);
    assert!(
        f.rms_m < 1.05 * f.floor_m && f.rms_m > 0.9 * f.floor_m,
        "rms {} vs floor {}",
        f.rms_m,
        f.floor_m
    );
}

/// Blending reproduces each fitted set at its own centre (RBF interpolation, eqs. 6.2–6.5 and
/// 6.9–6.10): exact up to the LU solve's round-off (1e-9 relative), and clamps outside the range.
#[test]
fn blends_reproduce_each_set_at_its_centre() {
    let mut spec = SyntheticSpec::block([3, 3, 2]);
    spec.contacts = vec![
        palpate_fem::forward::Contact {
            point: [0.05, 0.05, 0.05],
            force: [0.0, 0.0, -1.0],
            radius: 0.04,
        },
        palpate_fem::forward::Contact {
            point: [0.05, 0.05, 0.05],
            force: [0.0, 0.0, -3.0],
            radius: 0.04,
        },
        palpate_fem::forward::Contact {
            point: [0.05, 0.05, 0.05],
            force: [1.0, 0.0, -2.0],
            radius: 0.04,
        },
    ];
    let syn = synthesise(&spec).unwrap();
    let p = &syn.input.problem;
    let t = p.element_count();
    let sets: Vec<palpate_fem::forward::Material> = (0..3)
        .map(|i| {
            let e = 20_000.0 * (1.0 + 0.3 * i as f64);
            let per: Vec<LambdaAlpha> = (0..t)
                .map(|k| {
                    LambdaAlpha::from_young_poisson(
                        e * (1.0 + 0.01 * k as f64),
                        0.3 - 0.02 * i as f64,
                    )
                })
                .collect();
            palpate_fem::forward::Material::per_element(&per)
        })
        .collect();
    let homog: Vec<palpate_fem::forward::Material> = sets
        .iter()
        .map(|m| palpate_fem::forward::Material {
            lambda: vec![m.lambda[0]],
            alpha: vec![m.alpha[0]],
            foundation: None,
        })
        .collect();
    let bd = blend::deformation_blend(&homog, &syn.exact).unwrap();
    for (i, x) in syn.exact.iter().enumerate() {
        let (l, a) = blend::eval_deformation(&bd, &homog, x).unwrap();
        assert!(
            rel(l, homog[i].lambda[0]) < 1e-9 && rel(a, homog[i].alpha[0]) < 1e-9,
            "set {i}: {l} {a}"
        );
    }
    let bs = blend::strain_blend(p, &sets, &syn.exact, 8).unwrap();
    for (i, x) in syn.exact.iter().enumerate() {
        let strains = p.strains(x, &p.rotations(x, true));
        let m = blend::eval_strain(&bs, &sets, &strains).unwrap();
        for e in 0..t {
            assert!(
                rel(m.lambda[e], sets[i].lambda[e]) < 1e-9,
                "set {i} element {e}: λ {} vs {}",
                m.lambda[e],
                sets[i].lambda[e]
            );
            assert!(
                rel(m.alpha[e], sets[i].alpha[e]) < 1e-9,
                "set {i} element {e}: α"
            );
        }
    }
    // Far outside the fitted deformations the blend is clamped to the fitted range.
    let far: Vec<[f64; 3]> = syn.exact[1]
        .iter()
        .zip(&p.x0)
        .map(|(x, x0)| {
            [0; 3]
                .map(|_| 0.0)
                .iter()
                .enumerate()
                .map(|(d, _)| x0[d] + 10.0 * (x[d] - x0[d]))
                .collect::<Vec<_>>()
                .try_into()
                .unwrap()
        })
        .collect();
    let (l, _) = blend::eval_deformation(&bd, &homog, &far).unwrap();
    let (lo, hi) = homog.iter().fold((f64::INFINITY, 0.0f64), |(a, b), m| {
        (a.min(m.lambda[0]), b.max(m.lambda[0]))
    });
    assert!(l >= lo && l <= hi, "clamped λ {l} in [{lo}, {hi}]");
}

/// Leave-one-out on homogeneous data: the held-out contact is predicted to the noise floor
/// (the model class is right, so generalisation error ≈ marker noise σ√3 = 0.173 mm; bound 1.2×).
#[test]
fn leave_one_out_predicts_held_out_contact_at_noise_floor() {
    let mut spec = noisy_block([4, 4, 2], 60, 1e-4, 1);
    spec.contacts.truncate(3);
    let syn = synthesise(&spec).unwrap();
    let mut o = FitOptions::new(Method::Displacement, Layout::Homogeneous, Sets::Single);
    o.initial = LambdaAlpha::from_young_poisson(10_000.0, 0.2);
    let loo = loo::leave_one_out(&syn.input, &o).unwrap();
    assert_eq!(loo.len(), 3);
    for h in &loo {
        assert!(
            h.residual.rms < 1.2 * 1e-4 * 3f64.sqrt(),
            "held out {}: rms {}",
            h.residual.id,
            h.residual.rms
        );
    }
}

/// Force-based inhomogeneous per-measurement fit with γ on the L-curve (noise-free, every node
/// observed through markers on the free surface + completion): runs through the automatic γ
/// choice and reproduces the markers of the noise-free data (measured 4e-10 m; bound 1e-6 m,
/// i.e. 1e-3 of the ~1 mm displacements).
#[test]
fn force_inhomogeneous_with_l_curve_fits_markers() {
    let mut spec = SyntheticSpec::block([3, 3, 2]);
    spec.contacts.truncate(2);
    for c in spec.contacts.iter_mut() {
        c.radius = 0.04;
    }
    let syn = synthesise(&spec).unwrap();
    let mut o = FitOptions::new(Method::Force, Layout::Inhomogeneous, Sets::PerMeasurement);
    o.max_iterations = 5;
    o.l_curve_points = 5;
    let r = fit_static(&syn.input, &o, |_, _| {}).unwrap();
    assert!(matches!(r.gamma_choice, GammaChoice::LCurve { .. }));
    eprintln!("force inhomogeneous: rms {} m, γ {:?}", r.rms(), r.gammas);
    assert!(r.rms() < 1e-6, "rms {}", r.rms());
}

/// Three contacts at one point, 1, 2 and 3 N, on a material that stiffens with the load (each
/// made with its own Young's modulus, 20, 30 and 40 kPa: what per-measurement sets model), with
/// 0.02 mm marker noise.
fn stiffening_by_load() -> FitInput {
    let mut inputs = Vec::new();
    for (k, young) in [20_000.0, 30_000.0, 40_000.0].into_iter().enumerate() {
        let mut spec = noisy_block([4, 4, 2], 40, 2e-5, 1);
        spec.young = young;
        spec.contacts.truncate(1);
        spec.contacts[0].force = [0.0, 0.0, -1.0 - k as f64];
        let mut syn = synthesise(&spec).unwrap();
        syn.input.measurements[0].id = format!("f{}", k + 1);
        inputs.push(syn.input);
    }
    let mut input = inputs[0].clone();
    for other in &inputs[1..] {
        assert_eq!(other.markers.len(), input.markers.len());
        input.measurements.push(other.measurements[0].clone());
    }
    input
}

/// Leave-one-out of a non-linear class goes through the blend of the remaining sets: the middle
/// contact (2 N), held out, is played with the deformation-space blend of the 1 N and 3 N sets and
/// predicted better than by either of those sets alone (the nearest-contact rule this replaced).
/// Measured: blend 0.041 mm, 1 N set 0.244 mm, 3 N set 0.125 mm (0.02 mm marker noise).
#[test]
fn leave_one_out_plays_the_non_linear_class_through_the_blend() {
    let input = stiffening_by_load();
    let mut o = FitOptions::new(
        Method::Displacement,
        Layout::Homogeneous,
        Sets::PerMeasurement,
    );
    o.gammas = Some(Gammas::new(0.0, 1e-3));
    o.initial = LambdaAlpha::from_young_poisson(25_000.0, 0.3);
    let loo = loo::leave_one_out(&input, &o).unwrap();
    let held = &loo[1];
    assert!(held.blended && held.blend_settled, "{held:?}");
    // The 2 N contact with each remaining set alone.
    let mut train = input.clone();
    train.measurements.remove(1);
    let fit = fit_static(&train, &o, |_, _| {}).unwrap();
    let solve = SolveOptions {
        warp: true,
        ..o.solve
    };
    let alone: Vec<f64> = fit
        .params
        .iter()
        .map(|m| {
            let x = input
                .problem
                .solve_forces(m, &input.measurements[1].force, None, &solve)
                .unwrap()
                .solution
                .x;
            MeasurementResidual::new(String::new(), 0, input.marker_errors(1, &x), None).rms
        })
        .collect();
    let young: Vec<f64> = fit
        .params
        .iter()
        .map(|m| {
            LambdaAlpha {
                lambda: m.lambda[0],
                alpha: m.alpha[0],
            }
            .young()
        })
        .collect();
    eprintln!(
        "held-out 2 N: blend {:.3e} m, sets alone {alone:?} m (E {young:?})",
        held.residual.rms
    );
    assert!(
        alone.iter().all(|&a| held.residual.rms < 0.5 * a),
        "blend {} vs sets alone {alone:?}",
        held.residual.rms
    );
}

/// The force-based inverse on sparse noisy markers (40 markers on the free surface of a 4 × 4 × 2
/// block, σ = 0.1 mm on ~1–3 mm displacements, four contacts) is refused with a message that names
/// the measurement, the counts and the way out (without the refusal its completion/rescale
/// alternation diverged here to λ = 100 Pa, α = −134 Pa); the displacement-based inverse it points to
/// recovers the material from the same data (measured E within 0.16 %; bound 3 %).
#[test]
fn force_inverse_refuses_sparse_noisy_markers() {
    let syn = synthesise(&noisy_block([4, 4, 2], 40, 1e-4, 3)).unwrap();
    let truth = LambdaAlpha {
        lambda: syn.truth.lambda[0],
        alpha: syn.truth.alpha[0],
    };
    let mut o = FitOptions::new(Method::Force, Layout::Homogeneous, Sets::Single);
    o.initial = LambdaAlpha::from_young_poisson(10_000.0, 0.2);
    let err = fit_static(&syn.input, &o, |_, _| {}).unwrap_err();
    let msg = err.to_string();
    assert!(matches!(err, FitError::Refused(_)), "{msg}");
    assert!(
        msg.contains("\"c0\"")
            && msg.contains("observes 40 markers")
            && msg.contains("--method displacement"),
        "{msg}"
    );
    o.method = Method::Displacement;
    let r = fit_static(&syn.input, &o, |_, _| {}).unwrap();
    let p = LambdaAlpha {
        lambda: r.params[0].lambda[0],
        alpha: r.params[0].alpha[0],
    };
    let e = rel(p.young(), truth.young());
    eprintln!(
        "displacement on the same data: E {:.1} Pa (truth {:.1}), rel {e:.4}",
        p.young(),
        truth.young()
    );
    assert!(e < 0.03, "E rel {e}");
}
