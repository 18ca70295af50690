//! Motion fitter gradients (Real2Sim eqs. 5–6, 8–12, 14): direct and adjoint agree with each
//! other and with central finite differences for every parameter type, with marker and force
//! observations, from an elastostatic start.

use palpate_motion::gradient::{evaluate, Method};
use palpate_motion::model::{MassKind, Material, Param, ParamKind};
use palpate_motion::scenario::{bar_model, nine_markers, record};

fn setup(
    mass: MassKind,
) -> (
    palpate_motion::model::Model,
    Material,
    palpate_motion::model::Observations,
) {
    let size = [0.02, 0.08, 0.02];
    let (_, mut model) = bar_model(
        size,
        [1, 4, 1],
        1.0 / 180.0,
        24,
        &|t| palpate_motion::scenario::two_sinusoids(t),
        &nine_markers(size),
    )
    .unwrap();
    model.mass = mass;
    // Tight Newton tolerance so the discrete equations hold to round-off: the gradients assume
    // R(v) = 0 exactly, and FD of a loosely converged simulation is noisier than the check.
    model.newton.tol = 1e-11;
    model.newton.max_iter = 50;
    let ne = model.tets.len();
    let truth = Material::uniform(ne, 1.0e4, 2.0e4, 12.0, 1.0, 47.0);
    let obs = record(&model, &truth, 0.0, 1).unwrap();
    // Evaluate away from the truth, with a non-Newtonian index so ∂/∂h is non-trivial, and
    // per-element variation so per-element derivatives differ between elements.
    let mut mat = Material::uniform(ne, 1.6e4, 1.3e4, 7.0, 0.85, 60.0);
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
    let ad = evaluate(&model, &mat, params, &obs, Some(Method::Adjoint)).unwrap();
    let di = evaluate(&model, &mat, params, &obs, Some(Method::Direct)).unwrap();
    let (ga, gd) = (ad.grad.unwrap(), di.grad.unwrap());
    assert!((ad.phi - di.phi).abs() <= 1e-14 * ad.phi.abs());
    let scale = ga.iter().fold(0.0f64, |m, g| m.max(g.abs()));
    for (p, par) in params.iter().enumerate() {
        let q0 = mat.read(&[*par])[0];
        let h = 1e-5 * q0;
        let phi = |q: f64| {
            let mut m = mat.clone();
            m.set(&[*par], &[q]);
            evaluate(&model, &m, params, &obs, None).unwrap().phi
        };
        let fd = (phi(q0 + h) - phi(q0 - h)) / (2.0 * h);
        // Adjoint vs direct: same discrete derivative, different order of operations.
        assert!(
            (ga[p] - gd[p]).abs() <= 1e-8 * scale.max(ga[p].abs()),
            "{par:?}: adjoint {} direct {}",
            ga[p],
            gd[p]
        );
        // Analytic vs FD: relative 1e-4 of the largest component (FD truncation + Newton noise).
        assert!(
            (ga[p] - fd).abs() <= 1e-4 * scale.max(fd.abs()),
            "{par:?}: adjoint {} vs finite difference {fd} (scale {scale})",
            ga[p]
        );
    }
}

#[test]
fn global_parameters_markers_lumped() {
    let params: Vec<Param> = ParamKind::ALL
        .iter()
        .map(|&kind| Param {
            kind,
            element: None,
        })
        .collect();
    check(&params, MassKind::Lumped, false);
}

#[test]
fn global_parameters_markers_and_forces_consistent_mass() {
    let params: Vec<Param> = ParamKind::ALL
        .iter()
        .map(|&kind| Param {
            kind,
            element: None,
        })
        .collect();
    check(&params, MassKind::Consistent, true);
}

#[test]
fn per_element_lambda_mu_density() {
    let mut params = Vec::new();
    for e in [0usize, 7, 13, 22] {
        for kind in [ParamKind::Lambda, ParamKind::Mu, ParamKind::Density] {
            params.push(Param {
                kind,
                element: Some(e),
            });
        }
    }
    check(&params, MassKind::Lumped, true);
}
