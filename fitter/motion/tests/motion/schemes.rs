//! The integration schemes ([`Scheme`]): each against the analytic damped oscillator to the
//! period error its characteristic polynomial predicts, and the midpoint rule's and
//! generalised-α's direct and adjoint gradients against each other and against central finite
//! differences, as BDF2's are in `gradients.rs`.

use std::collections::BTreeMap;

use crate::gradients::setup;
use crate::support::assert_gradients_agree;
use palpate_fem::mesh::Mesh;
use palpate_motion::model::{Clamp, MassKind, Material, Model, Param, ParamKind, Pose};
use palpate_motion::sim::simulate_states;
use palpate_motion::timestep::{damped_oscillator_error, ring_down, Scheme};

/// Edge of the corner tetrahedron (m), shear modulus (Pa), density (kg/m³), damping ratio.
const EDGE: f64 = 0.1;
const MU: f64 = 1.0e4;
const RHO: f64 = 1000.0;
const ZETA: f64 = 0.02;

/// A single-dof damped oscillator made of one element: the corner tetrahedron
/// (0, e_x, e_y, e_z)·`EDGE` with its first three nodes clamped. With λ = 0 the linearised
/// neo-Hookean stiffness of the free node is K = Vμ/L² (I + e_z e_zᵀ) and the Newtonian
/// viscosity's D = (ν/μ) K, so a push along x excites one mode, ẍ + 2ζω ẋ + ω² x = 0 with
/// ω² = 4μ/(ρL²) (lumped mass ρV/4) and ζ = νω/(2μ). A small gravity along x, switched on at
/// t = 0 from the rest shape, starts the ring-down about the sagged equilibrium (strain 2.5e-4,
/// where the material is linear to ~1e-4).
fn one_element_oscillator(
    scheme: Scheme,
    steps_per_period: f64,
    cycles: f64,
) -> (Model, Material, f64) {
    let omega = (4.0 * MU / (RHO * EDGE * EDGE)).sqrt();
    let dt = 2.0 * std::f64::consts::PI / omega / steps_per_period;
    let steps = (cycles * steps_per_period) as usize;
    let mesh = Mesh {
        nodes: vec![
            [0.0; 3],
            [EDGE, 0.0, 0.0],
            [0.0, EDGE, 0.0],
            [0.0, 0.0, EDGE],
        ],
        node_tags: vec![1, 2, 3, 4],
        tets: vec![[0, 1, 2, 3]],
        node_groups: BTreeMap::new(),
    };
    let clamps = vec![Clamp {
        name: "base".into(),
        nodes: vec![0, 1, 2],
        poses: vec![Pose::identity(); steps + 1],
    }];
    let mut model = Model::new(
        &mesh,
        clamps,
        Vec::new(),
        dt,
        steps,
        [0.1, 0.0, 0.0],
        MassKind::Lumped,
    )
    .unwrap();
    model.static_start = false;
    model.scheme = scheme;
    // The forces are ~4e-3 N: the default 1e-6 N would leave a visible Newton error.
    model.newton.tol = 1e-13;
    model.newton.max_iter = 50;
    let nu = 2.0 * ZETA * MU / omega;
    let mat = Material::uniform(1, 0.0, MU, nu, 1.0, RHO);
    (model, mat, omega)
}

/// The free node's x displacement at every step, from 0 (rest shape) on.
fn ring(model: &Model, mat: &Material) -> Vec<f64> {
    let mut xs = vec![0.0];
    simulate_states(model, mat, |s| {
        xs.push(s.x[9]);
        Ok(())
    })
    .unwrap();
    xs
}

/// Each scheme at 13 and 26 steps per period (13: the beam's 100 Hz capture of its 7.7 Hz ring)
/// against the analytic damped oscillator: the simulated period and amplitude per cycle are the
/// analytic ones times the errors the scheme's amplification predicts
/// ([`damped_oscillator_error`]), to 0.3 % and 0.5 %. The midpoint rule adds no damping of its
/// own; BDF2 takes 10 % more amplitude per cycle than the material at 13 steps, generalised-α
/// 0.5 % less than the material (ζ = 0.02 at 13 steps).
#[test]
fn each_scheme_matches_the_damped_oscillator_to_its_predicted_error() {
    let damped = (1.0 - ZETA * ZETA).sqrt();
    for scheme in [Scheme::Bdf2, Scheme::Midpoint, Scheme::Alpha] {
        for n in [13.0, 26.0] {
            let (model, mat, omega) = one_element_oscillator(scheme, n, 12.0);
            let xs = ring(&model, &mat);
            let (period, decay) = ring_down(&xs, model.dt);
            let (period, decay) = (period.unwrap(), decay.unwrap());
            let t_damped = 2.0 * std::f64::consts::PI / (omega * damped);
            let analytic_decay = (-2.0 * std::f64::consts::PI * ZETA / damped).exp();
            let (ratio, amp) = damped_oscillator_error(scheme, n, ZETA);
            assert!(
                (period / t_damped - ratio).abs() < 3e-3,
                "{scheme:?} at {n} steps per period: period ×{:.4}, predicted ×{ratio:.4}",
                period / t_damped
            );
            assert!(
                (decay / analytic_decay - amp).abs() < 5e-3,
                "{scheme:?} at {n} steps per period: amplitude ×{:.4} of the analytic per cycle, \
                 predicted ×{amp:.4}",
                decay / analytic_decay
            );
        }
    }
}

/// The midpoint rule's gradients, as BDF2's in `gradients.rs`: every global parameter with
/// marker observations (lumped mass), with marker and clamp-force observations (consistent mass,
/// whose off-diagonal couples the clamped velocities into the free rows), and per-element λ, μ,
/// density and stiffening — direct = adjoint to 1e-8 and both = central finite differences.
#[test]
fn midpoint_gradients_match_finite_differences() {
    gradients_match_finite_differences(Scheme::Midpoint);
}

/// Generalised-α's gradients, as the midpoint rule's: its two-step history (x^{n−2} and
/// v^{n−2} enter the force state and the inertia base) is differentiated in both methods.
#[test]
fn alpha_gradients_match_finite_differences() {
    gradients_match_finite_differences(Scheme::Alpha);
}

fn gradients_match_finite_differences(scheme: Scheme) {
    let cases: [(MassKind, bool, Vec<Param>); 3] = [
        (MassKind::Lumped, false, Param::globals(&ParamKind::ALL)),
        (MassKind::Consistent, true, Param::globals(&ParamKind::ALL)),
        (
            MassKind::Lumped,
            true,
            [0usize, 7, 13, 22]
                .iter()
                .flat_map(|&e| {
                    [
                        ParamKind::Lambda,
                        ParamKind::Mu,
                        ParamKind::Density,
                        ParamKind::Stiffening,
                    ]
                    .map(|k| Param::of_element(k, e))
                })
                .collect(),
        ),
    ];
    for (mass, forces, params) in cases {
        let (mut model, mat, _) = setup(mass);
        model.scheme = scheme;
        // The observations of the scheme's own truth, so Φ is a fit's, not a mismatch of
        // schemes.
        let mut obs =
            palpate_motion::scenario::record(&model, &crate::support::truth(&model), 0.0, 1)
                .unwrap();
        if forces {
            obs.force_weight = 1e3;
        } else {
            obs.forces.clear();
        }
        assert_gradients_agree(&model, &mat, &params, &obs, |_, q0| 1e-5 * q0);
    }
}

/// A model that asks for the midpoint rule integrates a material without viscosity by
/// BDF2 ([`Model::scheme_for`]): its states are BDF2's to the last bit, and the same material
/// with a viscosity is integrated by the midpoint rule (no numerical damping: it rings longer
/// than under BDF2 at 13 steps per period, 0.89 of the amplitude per cycle).
#[test]
fn the_midpoint_rule_leaves_an_undamped_material_to_bdf2() {
    let (midpoint, mut mat, _) = one_element_oscillator(Scheme::Midpoint, 13.0, 6.0);
    let (bdf2, _, _) = one_element_oscillator(Scheme::Bdf2, 13.0, 6.0);
    mat.set_uniform(ParamKind::Nu, 0.0);
    assert!(!mat.damps());
    assert_eq!(midpoint.scheme_for(&mat), Scheme::Bdf2);
    assert_eq!(ring(&midpoint, &mat), ring(&bdf2, &mat));

    mat.set_uniform(ParamKind::Nu, 1e-3);
    assert!(mat.damps());
    assert_eq!(midpoint.scheme_for(&mat), Scheme::Midpoint);
    let (under_midpoint, under_bdf2) = (ring(&midpoint, &mat), ring(&bdf2, &mat));
    let (_, decay_midpoint) = ring_down(&under_midpoint, midpoint.dt);
    let (_, decay_bdf2) = ring_down(&under_bdf2, bdf2.dt);
    assert!(
        decay_midpoint.unwrap() > decay_bdf2.unwrap() + 0.05,
        "midpoint {decay_midpoint:?}, BDF2 {decay_bdf2:?}"
    );
}
