//! Forward-model checks against independent references.

use super::*;
use crate::mesh::boxmesh::box_mesh;
use nalgebra::{DMatrix, DVector};

fn block() -> (Mesh, Vec<usize>, Vec<[usize; 3]>) {
    let mesh = box_mesh([0.1, 0.1, 0.05], [3, 3, 2]);
    let fixed = mesh.node_groups["bottom"].clone();
    let surface = mesh.boundary_triangles();
    (mesh, fixed, surface)
}

/// Dense reference: K = Σ K_e assembled by hand into a dense matrix, fixed dofs removed, solved
/// with nalgebra's LU. Without warping the sparse solver must agree to round-off.
#[test]
fn linear_solve_matches_dense_reference() {
    let (mesh, fixed, surface) = block();
    let p = StaticProblem::new(&mesh, &fixed, &surface).unwrap();
    let mat = Material::from_young_poisson(20_000.0, 0.3);
    let load = Load::contact([0.05, 0.05, 0.05], [0.3, -0.2, -2.0], 0.03);
    let opts = SolveOptions {
        warp: false,
        increments: 1,
        ..Default::default()
    };
    let sol = p.solve(&mat, &load, &opts).unwrap();

    let n = mesh.nodes.len();
    let mut k = DMatrix::<f64>::zeros(3 * n, 3 * n);
    for (e, t) in mesh.tets.iter().enumerate() {
        let ke = p.element_stiffness(e, &mat);
        for a in 0..12 {
            for b in 0..12 {
                k[(3 * t[a / 3] + a % 3, 3 * t[b / 3] + b % 3)] += ke[(a, b)];
            }
        }
    }
    let f = p.force_vector(&load).unwrap();
    let free: Vec<usize> = (0..3 * n).filter(|&i| !p.fixed[i / 3]).collect();
    let kff = DMatrix::from_fn(free.len(), free.len(), |i, j| k[(free[i], free[j])]);
    let ff = DVector::from_fn(free.len(), |i, _| f[free[i]]);
    let u = kff.lu().solve(&ff).unwrap();
    let umax = u.amax();
    assert!(
        umax > 1e-4,
        "load should deform the block visibly, got {umax}"
    );
    for (i, &dof) in free.iter().enumerate() {
        let got = sol.x[dof / 3][dof % 3] - mesh.nodes[dof / 3][dof % 3];
        // Both are direct solves of the same SPD system: agreement to ~1e-12 relative.
        assert!(
            (got - u[i]).abs() <= 1e-10 * umax,
            "dof {dof}: sparse {got} vs dense {}",
            u[i]
        );
    }
}

/// The warped fixed point is an equilibrium: f_int(x) = Σ R_e K_e (R_eᵀ x_e − x₀e) equals the
/// applied force at every free dof (checked with a large load that rotates elements visibly).
#[test]
fn warped_solution_is_in_equilibrium() {
    let (mesh, fixed, surface) = block();
    let p = StaticProblem::new(&mesh, &fixed, &surface).unwrap();
    let mat = Material::from_young_poisson(20_000.0, 0.3);
    let load = Load::contact([0.1, 0.05, 0.05], [6.0, 0.0, -6.0], 0.03);
    let opts = SolveOptions {
        tolerance: 1e-12,
        ..Default::default()
    };
    let sol = p.solve(&mat, &load, &opts).unwrap();
    assert!(
        sol.converged,
        "fixed point did not converge: last change {}",
        sol.last_change
    );
    let umax = sol
        .x
        .iter()
        .zip(&mesh.nodes)
        .map(|(a, b)| (a[0] - b[0]).abs().max((a[2] - b[2]).abs()))
        .fold(0.0, f64::max);
    assert!(
        umax > 5e-3,
        "large load should move the corner by millimetres, got {umax}"
    );
    let rot = p.rotations(&sol.x, true);
    let fint = p.internal_forces(&mat, &rot, &sol.x);
    let f = p.force_vector(&load).unwrap();
    let scale = f.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for i in 0..fint.len() {
        if !p.fixed[i / 3] {
            // Fixed point to 1e-12 m in positions: force residual ≤ 1e-6 of the largest nodal force.
            assert!(
                (fint[i] - f[i]).abs() <= 1e-6 * scale,
                "dof {i}: f_int {} vs f {}",
                fint[i],
                f[i]
            );
        }
    }
    // Warping matters at this load: the linear model gives a visibly different answer.
    let lin = p
        .solve(
            &mat,
            &load,
            &SolveOptions {
                warp: false,
                ..opts
            },
        )
        .unwrap();
    let diff = lin
        .x
        .iter()
        .zip(&sol.x)
        .map(|(a, b)| (a[0] - b[0]).abs())
        .fold(0.0, f64::max);
    assert!(
        diff > 1e-2 * umax,
        "warped and linear should differ at large load ({diff})"
    );
}

/// At a tiny load, warped and linear FEM coincide (rotations are ~identity).
#[test]
fn small_load_warped_equals_linear() {
    let (mesh, fixed, surface) = block();
    let p = StaticProblem::new(&mesh, &fixed, &surface).unwrap();
    let mat = Material::from_young_poisson(20_000.0, 0.3);
    let load = Load::contact([0.05, 0.05, 0.05], [0.0, 0.0, -1e-4], 0.03);
    let w = p.solve(&mat, &load, &SolveOptions::default()).unwrap();
    let l = p
        .solve(
            &mat,
            &load,
            &SolveOptions {
                warp: false,
                ..Default::default()
            },
        )
        .unwrap();
    let umax =
        l.x.iter()
            .zip(&mesh.nodes)
            .map(|(a, b)| (a[2] - b[2]).abs())
            .fold(0.0, f64::max);
    for (a, b) in w.x.iter().zip(&l.x) {
        for d in 0..3 {
            // Second-order effect: relative difference ~ strain (~1e-6 here).
            assert!((a[d] - b[d]).abs() <= 1e-4 * umax);
        }
    }
}

#[test]
fn bad_inputs_are_named() {
    let (mesh, fixed, surface) = block();
    assert!(matches!(
        StaticProblem::new(&mesh, &[], &surface),
        Err(ForwardError::NoFixedNodes)
    ));
    let p = StaticProblem::new(&mesh, &fixed, &surface).unwrap();
    let e = p
        .force_vector(&Load::contact([0.05, 0.05, 0.2], [0.0, 0.0, -1.0], 0.01))
        .unwrap_err();
    assert!(
        e.to_string()
            .contains("no free surface node within the probe radius"),
        "{e}"
    );
    let bad = Material::from_young_poisson(1000.0, 0.6);
    let e = p
        .solve(&bad, &Load::default(), &SolveOptions::default())
        .unwrap_err();
    assert!(e.to_string().contains("not physical"), "{e}");
}

/// Keeping a factorisation (a stale K' as the iteration matrix) changes the path, not the fixed
/// point: with `reuse_factor` the warped solution agrees with the refactor-every-iteration one to
/// the fixed-point tolerance, from a cold start, from a warm start, and from a factorisation
/// handed over from another material (a Jacobian column's situation, here 30 % stiffer); and it
/// makes fewer factorisations than iterations.
#[test]
fn kept_factorisation_reaches_the_same_fixed_point() {
    let (mesh, fixed, surface) = block();
    let p = StaticProblem::new(&mesh, &fixed, &surface).unwrap();
    let mat = Material::from_young_poisson(20_000.0, 0.3);
    let f = p
        .force_vector(&Load::contact([0.1, 0.05, 0.05], [4.0, 0.0, -4.0], 0.03))
        .unwrap();
    let exact = SolveOptions {
        tolerance: 1e-12,
        ..Default::default()
    };
    let kept = SolveOptions {
        reuse_factor: true,
        ..exact
    };
    let reference = p.solve_forces(&mat, &f, None, &exact).unwrap();
    assert!(reference.solution.converged);
    let max_diff = |a: &[[f64; 3]], b: &[[f64; 3]]| {
        a.iter()
            .zip(b)
            .flat_map(|(p, q)| (0..3).map(move |d| (p[d] - q[d]).abs()))
            .fold(0.0, f64::max)
    };
    let cold = p.solve_forces(&mat, &f, None, &kept).unwrap();
    assert!(cold.solution.converged);
    assert!(max_diff(&cold.solution.x, &reference.solution.x) < 1e-10);
    // A different material's factor as the start of a warm solve.
    let stiffer = Material::from_young_poisson(26_000.0, 0.3);
    let other = p.solve_forces(&stiffer, &f, None, &exact).unwrap();
    let warm = p
        .solve_forces_with(
            &mat,
            &f,
            Some(&other.solution.x),
            &kept,
            Some(&other.factor),
        )
        .unwrap();
    assert!(warm.solution.converged);
    assert!(max_diff(&warm.solution.x, &reference.solution.x) < 1e-10);
    // The stiffer material's solution really is elsewhere (the test would pass trivially if not).
    assert!(max_diff(&other.solution.x, &reference.solution.x) > 1e-4);
    // Without a kept factor every iteration factorises; with it the handed-over factor can serve
    // the whole warm solve, so the returned factor may be that very one.
    let fresh = p
        .solve_forces(&mat, &f, Some(&other.solution.x), &exact)
        .unwrap();
    assert!(fresh.solution.converged);
    assert!(max_diff(&fresh.solution.x, &reference.solution.x) < 1e-10);
}
