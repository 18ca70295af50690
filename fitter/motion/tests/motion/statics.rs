//! The quasi-static hyperelastic solver (`motion::statics`) against independent references.

use nalgebra::Vector3;
use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_motion::hyperelastic::{element_forces, HyperParams, RestTet};
use palpate_motion::statics::{solve_static, StaticProblem};

/// Uniaxial stretch of a Neo-Hookean bar with the lateral faces free: the end reaction at
/// stretch s must equal the analytic homogeneous solution. The exact homogeneous state
/// F = diag(t, s, t) comes from a 1-D root search on the lateral stretch t (zero lateral stress;
/// an independent computation, no FEM). Homogeneous deformation is represented exactly by linear
/// tets, so the FEM must land every node on it (1e-9 m) and its end reaction must be
/// P₂₂(s, t)·A₀ (1e-6 relative). The positions alone would not see a stress wrong by a common
/// factor (the same equilibrium); the reaction does.
#[test]
fn uniaxial_neo_hookean_bar_matches_homogeneous_solution() {
    let (l, w) = (0.04, 0.01);
    let mesh = box_mesh([w, l, w], [2, 4, 2]);
    let p = HyperParams {
        lambda: 4.0e4,
        mu: 2.0e4,
        stiffening: 3.0e3,
    };
    let s = 1.3;
    // Roller-free ends would need sliding supports; instead prescribe the exact homogeneous
    // motion on both end faces (including the lateral contraction t) and check that the
    // interior nodes land on the homogeneous field and the solver reports equilibrium.
    let t = lateral_stretch(&p, s);
    let mut fixed = Vec::new();
    let mut disp = Vec::new();
    for (n, x) in mesh.nodes.iter().enumerate() {
        if x[1] == 0.0 || (x[1] - l).abs() < 1e-12 {
            fixed.push(n);
            disp.push([(t - 1.0) * x[0], (s - 1.0) * x[1], (t - 1.0) * x[2]]);
        }
    }
    let mut prob = StaticProblem::new(&mesh, p, fixed);
    prob.fixed_displacement = disp;
    prob.load_steps = 4;
    let sol = solve_static(&prob).unwrap();
    for (n, x) in mesh.nodes.iter().enumerate() {
        let want = [t * x[0], s * x[1], t * x[2]];
        for k in 0..3 {
            assert!(
                (sol.positions[n][k] - want[k]).abs() < 1e-9,
                "node {n} axis {k}: {} vs {}",
                sol.positions[n][k],
                want[k]
            );
        }
    }
    // The reaction on the y = l end: what the support holds against the elements' forces on
    // its nodes, summed.
    let rest = RestTet::of_mesh(&mesh).unwrap();
    let end = |n: usize| (mesh.nodes[n][1] - l).abs() < 1e-12;
    let mut reaction = 0.0;
    for (tet, r) in mesh.tets.iter().zip(&rest) {
        let x = tet.map(|n| Vector3::from(sol.positions[n]));
        let f = element_forces(r, &x, &p).unwrap();
        for (a, &n) in tet.iter().enumerate() {
            if end(n) {
                reaction -= f[3 * a + 1];
            }
        }
    }
    let want = axial_stress(&p, s, t) * w * w;
    assert!(
        (reaction / want - 1.0).abs() < 1e-6,
        "end reaction {reaction:e} N, analytic P₂₂·A₀ = {want:e} N"
    );
}

/// P₂₂ of F = diag(t, s, t) (the stretched axis y): the same derivative as the lateral P₁₁ of
/// [`lateral_stretch`] with s and t exchanged in the direction of stretch,
/// λ/2 (J² − 1)/s + μ (s − 1/s) + 2c (Ī₁ − 3) J^(−2/3) (2s − ⅔ I₁/s).
fn axial_stress(p: &HyperParams, s: f64, t: f64) -> f64 {
    let j = s * t * t;
    let i1 = s * s + 2.0 * t * t;
    let j23 = j.powf(-2.0 / 3.0);
    0.5 * p.lambda * (j * j - 1.0) / s
        + p.mu * (s - 1.0 / s)
        + 2.0 * p.stiffening * (j23 * i1 - 3.0) * j23 * (2.0 * s - 2.0 / 3.0 * i1 / s)
}

/// Lateral stretch t of the uniaxial state F = diag(t, s, t) with zero lateral stress:
/// P₁₁ = λ/2 (J² − 1)/t + μ (t − 1/t) + 2c (Ī₁ − 3) J^(−2/3) (2t − ⅔ I₁/t) = 0, J = s t²,
/// I₁ = s² + 2t², Ī₁ = J^(−2/3) I₁.
fn lateral_stretch(p: &HyperParams, s: f64) -> f64 {
    let f = |t: f64| {
        let j = s * t * t;
        let i1 = s * s + 2.0 * t * t;
        let j23 = j.powf(-2.0 / 3.0);
        0.5 * p.lambda * (j * j - 1.0) / t
            + p.mu * (t - 1.0 / t)
            + 2.0 * p.stiffening * (j23 * i1 - 3.0) * j23 * (2.0 * t - 2.0 / 3.0 * i1 / t)
    };
    let (mut a, mut b) = (0.3, 1.0);
    for _ in 0..200 {
        let m = 0.5 * (a + b);
        if f(a) * f(m) <= 0.0 {
            b = m;
        } else {
            a = m;
        }
    }
    0.5 * (a + b)
}

/// A cantilever under its own weight and a tip load: equilibrium residual below tolerance,
/// the tip moves down, and the stiffening term makes the same load deflect less.
#[test]
fn cantilever_with_gravity_and_tip_load_converges_and_stiffening_stiffens() {
    let mesh = box_mesh([0.1, 0.01, 0.01], [10, 1, 1]);
    let fixed = mesh.group("left").unwrap().to_vec();
    let tip: Vec<usize> = mesh.group("right").unwrap().to_vec();
    let run = |c: f64| {
        let mut prob = StaticProblem::new(
            &mesh,
            HyperParams {
                lambda: 2.0e5,
                mu: 1.0e5,
                stiffening: c,
            },
            fixed.clone(),
        );
        prob.density = 1000.0;
        prob.gravity = [0.0, 0.0, -9.81];
        prob.forces = tip
            .iter()
            .map(|&n| (n, [0.0, 0.0, -0.05 / tip.len() as f64]))
            .collect();
        prob.load_steps = 5;
        let sol = solve_static(&prob).unwrap();
        assert!(sol.residual < 1e-9);
        tip.iter()
            .map(|&n| sol.positions[n][2] - mesh.nodes[n][2])
            .sum::<f64>()
            / tip.len() as f64
    };
    let soft = run(0.0);
    let stiff = run(2.0e5);
    assert!(
        soft < -0.005,
        "tip deflection {soft} m should be clearly downward"
    );
    assert!(stiff > soft && stiff < 0.0, "stiffening: {stiff} vs {soft}");
}
