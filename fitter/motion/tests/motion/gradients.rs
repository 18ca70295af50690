//! Motion fitter gradients (Real2Sim eqs. 5–6, 8–12, 14): direct and adjoint agree with each
//! other and with central finite differences for every parameter type, with marker and force
//! observations, from an elastostatic start.

use crate::support::{assert_gradients_agree, bar, truth};
use palpate_motion::gradient::evaluate_gauss_newton;
use palpate_motion::model::{DeadLoad, MassKind, Material, Param, ParamKind};
use palpate_motion::scenario::record;

pub(crate) fn setup(
    mass: MassKind,
) -> (
    palpate_motion::model::Model,
    Material,
    palpate_motion::model::Observations,
) {
    let (_, mut model) = bar([1, 4, 1], 24);
    model.mass = mass;
    // Tight Newton tolerance so the discrete equations hold to round-off: the gradients assume
    // R(v) = 0 exactly, and FD of a loosely converged simulation is noisier than the check.
    model.newton.tol = 1e-11;
    model.newton.max_iter = 50;
    let ne = model.tets.len();
    let obs = record(&model, &truth(&model), 0.0, 1).unwrap();
    // Evaluate away from the truth, with a non-Newtonian index so ∂/∂h is non-trivial, and
    // per-element variation so per-element derivatives differ between elements.
    let mut mat = Material::uniform(ne, 1.6e4, 1.3e4, 7.0, 0.85, 60.0);
    // A stiffening term on, so that ∂/∂c is checked where it acts (and the step 1e-5 c is not 0).
    mat.set_uniform(ParamKind::Stiffening, 4.0e3);
    for e in 0..ne {
        mat.values[ParamKind::Mu as usize][e] *= 1.0 + 0.05 * (e % 3) as f64;
    }
    (model, mat, obs)
}

/// Central FD of Φ with relative step 1e-5 (Φ is smooth; with Newton at 1e-11 N the FD error
/// is ~1e-6 relative), against both analytic gradients.
fn check(params: &[Param], mass: MassKind, use_forces: bool) {
    let (model, mat, mut obs) = setup(mass);
    if !use_forces {
        obs.forces.clear();
    } else {
        obs.force_weight = 1e3; // make the force term comparable to the marker term
    }
    assert_gradients_agree(&model, &mat, params, &obs, |_, q0| 1e-5 * q0);
}

#[test]
fn global_parameters_markers_lumped() {
    let params = Param::globals(&ParamKind::ALL);
    check(&params, MassKind::Lumped, false);
}

#[test]
fn global_parameters_markers_and_forces_consistent_mass() {
    let params = Param::globals(&ParamKind::ALL);
    check(&params, MassKind::Consistent, true);
}

#[test]
fn per_element_lambda_mu_density_stiffening() {
    let mut params = Vec::new();
    for e in [0usize, 7, 13, 22] {
        for kind in [
            ParamKind::Lambda,
            ParamKind::Mu,
            ParamKind::Density,
            ParamKind::Stiffening,
        ] {
            params.push(Param::of_element(kind, e));
        }
    }
    check(&params, MassKind::Lumped, true);
}

/// The stiffening coefficient alone, so the check is relative to its own derivative (beside λ
/// and μ it is the smallest component and a check against the largest would hardly bind).
#[test]
fn stiffening_alone_matches_finite_differences() {
    for (mass, forces) in [(MassKind::Lumped, false), (MassKind::Consistent, true)] {
        let (model, mat, mut obs) = setup(mass);
        if forces {
            obs.force_weight = 1e3;
        } else {
            obs.forces.clear();
        }
        let params = [Param::global(ParamKind::Stiffening)];
        let (g, scale) = assert_gradients_agree(&model, &mat, &params, &obs, |_, q0| 1e-4 * q0);
        assert!(g[0] != 0.0 && scale == g[0].abs(), "∂Φ/∂c = {}", g[0]);
    }
}

/// A two-material body: μ and λ of a region of its own beside the global ones (the global ones
/// reach the elements outside it), with a region stiffening too — every derivative matches.
#[test]
fn region_parameters_match_finite_differences() {
    let (model, mut mat, obs) = setup(MassKind::Lumped);
    mat.regions = vec![(8..16).collect()];
    let params = [
        Param::global(ParamKind::Mu),
        Param::in_region(ParamKind::Mu, 0),
        Param::global(ParamKind::Lambda),
        Param::in_region(ParamKind::Lambda, 0),
        Param::in_region(ParamKind::Stiffening, 0),
    ];
    // The region holds its own μ: the global μ set beside it leaves the region's elements to
    // it; a global λ set without a region λ is the one λ of both materials and reaches them.
    let mu_only = [params[0], params[1], Param::global(ParamKind::Lambda)];
    mat.set(&mu_only, &[1.7e4, 2.9e4, 3.1e4]);
    for (e, &a) in mat.values[ParamKind::Mu as usize].iter().enumerate() {
        assert_eq!(
            a,
            if (8..16).contains(&e) { 2.9e4 } else { 1.7e4 },
            "element {e}"
        );
    }
    assert!(mat.values[ParamKind::Lambda as usize]
        .iter()
        .all(|&l| l == 3.1e4));
    // The point of the check is one the parameters describe (one value per material).
    let q = mat.read(&params);
    mat.set(&params, &q);
    let (g, _) = assert_gradients_agree(&model, &mat, &params, &obs, |_, q0| 1e-5 * q0);
    assert!(g.iter().all(|&x| x != 0.0), "{g:?}");
    // The two-material candidate's parameters: the region's own μ, one λ for both.
    let shared = [
        Param::global(ParamKind::Lambda),
        Param::global(ParamKind::Mu),
        Param::in_region(ParamKind::Mu, 0),
    ];
    let q = mat.read(&shared);
    mat.set(&shared, &q);
    let (g, _) = assert_gradients_agree(&model, &mat, &shared, &obs, |_, q0| 1e-5 * q0);
    assert!(g.iter().all(|&x| x != 0.0), "{g:?}");
    // An unknown region is refused, not ignored.
    let bad = [Param::in_region(ParamKind::Mu, 1)];
    assert!(mat.check_params(&bad).is_err());
    assert!(palpate_motion::gradient::evaluate(
        &model,
        &mat,
        &bad,
        &obs,
        Some(palpate_motion::gradient::Method::Adjoint)
    )
    .is_err());
}

/// A region scaled as a whole (`Material::scaled_regions`, a layer at the body's Poisson's
/// ratio): its λ = μ_r λ_b/μ_b follows the region's μ and the body's two moduli, against central
/// differences of Φ with the tie in place (adjoint and direct), and the global λ does not reach
/// the region otherwise. The Gauss–Newton matrix over (global μ, region μ, global λ) is the one
/// over the four Lamé values with the region's λ folded by hand.
#[test]
fn a_region_scaled_as_a_whole_matches_finite_differences() {
    let (model, mut mat, obs) = setup(MassKind::Lumped);
    mat.regions = vec![(8..16).collect()];
    mat.scaled_regions = vec![0];
    let ratio = 3.1e4 / 1.7e4;
    let params = [
        Param::global(ParamKind::Mu),
        Param::in_region(ParamKind::Mu, 0),
        Param::global(ParamKind::Lambda),
    ];
    mat.set(&params, &[1.7e4, 0.6e4, 3.1e4]);
    for (e, (&l, &m)) in mat.values[ParamKind::Lambda as usize]
        .iter()
        .zip(&mat.values[ParamKind::Mu as usize])
        .enumerate()
    {
        let expected = if (8..16).contains(&e) {
            (ratio * 0.6e4, 0.6e4)
        } else {
            (3.1e4, 1.7e4)
        };
        assert!(
            (l - expected.0).abs() <= 1e-12 * l && m == expected.1,
            "element {e}: {:?}",
            (l, m)
        );
    }
    let (g, _) = assert_gradients_agree(&model, &mat, &params, &obs, |_, q0| 1e-5 * q0);
    assert!(g.iter().all(|&x| x != 0.0), "{g:?}");
    // The region's λ is no parameter of its own.
    let twice = [Param::in_region(ParamKind::Lambda, 0)];
    assert!(mat.ties(&twice).is_err());
    // The folded Gauss–Newton matrix against the untied one folded here.
    let (tied_ev, tied) = evaluate_gauss_newton(&model, &mat, &params, &obs).unwrap();
    let mut free = mat.clone();
    free.scaled_regions.clear();
    let four = [
        params[0],
        params[1],
        params[2],
        Param::in_region(ParamKind::Lambda, 0),
    ];
    let (free_ev, h4) = evaluate_gauss_newton(&model, &free, &four, &obs).unwrap();
    assert_eq!(tied_ev.phi, free_ev.phi);
    let (mb, mr) = (1.7e4, 0.6e4);
    let t = |i: usize, a: usize| match (i, a) {
        (3, 0) => -mr * ratio / mb,
        (3, 1) => ratio,
        (3, 2) => mr / mb,
        _ if i == a => 1.0,
        _ => 0.0,
    };
    for a in 0..3 {
        for b in 0..3 {
            let mut want = 0.0;
            for i in 0..4 {
                for j in 0..4 {
                    want += t(i, a) * h4[i * 4 + j] * t(j, b);
                }
            }
            let got = tied[a * 3 + b];
            assert!(
                (got - want).abs() <= 1e-12 * want.abs().max(tied[a * 3 + a].abs()),
                "H[{a}][{b}]: {got:e} folded, {want:e} by hand"
            );
        }
    }
    let (gt, gf) = (tied_ev.grad.unwrap(), free_ev.grad.unwrap());
    let want = [
        gf[0] - mr * ratio / mb * gf[3],
        gf[1] + ratio * gf[3],
        gf[2] + mr / mb * gf[3],
    ];
    for (a, b) in gt.iter().zip(want) {
        assert!((a - b).abs() <= 1e-12 * b.abs(), "{gt:?} vs {want:?}");
    }
}

/// The gravity turned across its declared direction (`ParamKind::GRAVITY`), from the static
/// start on: both gradients match central differences, at the declared gravity and at a turned
/// one, with clamp forces (which hold internal forces only) and without, and with a hanging
/// weight whose force turns with it; the turn keeps the magnitude.
#[test]
fn the_gravity_turned_matches_finite_differences() {
    let turned = [0.1f64.exp(), (-0.05f64).exp()];
    for (turn, forces, weight) in [
        ([1.0, 1.0], false, false),
        (turned, true, false),
        (turned, false, true),
    ] {
        let (mut model, mut mat, mut obs) = setup(MassKind::Lumped);
        assert!(model.static_start);
        if weight {
            // A 5 g weight hung at the far end, moving with its nodes: its force turns too.
            let ymax = model.nodes.iter().map(|p| p[1]).fold(f64::MIN, f64::max);
            let nodes: Vec<usize> = (0..model.nodes.len())
                .filter(|&n| model.nodes[n][1] == ymax)
                .collect();
            model.loads.push(DeadLoad {
                name: "weight".into(),
                nodes,
                force: model.gravity.map(|g| 0.005 * g),
                from_step: 0,
                mass: Some(0.005),
                inertia: true,
                lever: None,
            });
            assert!(!model.turned_weights().is_empty());
        }
        if forces {
            obs.force_weight = 1e3;
        } else {
            obs.forces.clear();
        }
        let params = [
            Param::global(ParamKind::GravityTiltA),
            Param::global(ParamKind::GravityTiltB),
            Param::global(ParamKind::Mu),
        ];
        mat.set(&params[..2], &turn);
        let g = model.gravity_of(&mat);
        let norm = |v: [f64; 3]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
        assert!((norm(g) - norm(model.gravity)).abs() <= 1e-12 * norm(model.gravity));
        let (grad, _) = assert_gradients_agree(&model, &mat, &params, &obs, |_, q0| 1e-5 * q0);
        assert!(grad[0] != 0.0 && grad[1] != 0.0, "{grad:?}");
    }
}
