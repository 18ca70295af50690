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

/// The 10 cm cantilever of the runtime evidence (20 × 2 × 2 cells, E = 1 MPa, ν = 0.3, clamped at
/// x = 0) under a downward tip load `load` (N) shared by the tip-face nodes.
fn cantilever(load: f64) -> (StaticProblem, Vec<f64>, Vec<usize>, Mesh) {
    let m = box_mesh([0.1, 0.01, 0.01], [20, 2, 2]);
    let fixed = m.node_groups["left"].clone();
    let tip = m.node_groups["right"].clone();
    let p = StaticProblem::new(&m, &fixed, &m.boundary_triangles()).unwrap();
    let mut f = vec![0.0; 3 * m.nodes.len()];
    for &i in &tip {
        f[3 * i + 2] = -load / tip.len() as f64;
    }
    (p, f, tip, m)
}

/// The cantilever's runtime model (linear material, no blend).
fn cantilever_buffers(p: &StaticProblem, m: &Mesh, mat: &Material) -> crate::export::ModelBuffers {
    use crate::export::{BlendData, ModelBuffers, ProvenanceInfo};
    let prov = ProvenanceInfo {
        tool: "test".into(),
        source: "cantilever".into(),
        notes: String::new(),
    };
    ModelBuffers::new(
        p,
        &m.node_tags,
        std::slice::from_ref(mat),
        &BlendData::None,
        &prov,
    )
    .unwrap()
}

/// The load at which the lagged-rotation fixed point stopped converging (twice the 0.25 N of the
/// runtime evidence, four times) converges with the energy line search, to the same answer for 10
/// and 40 increments, and that answer is an equilibrium. Before the line search, 0.5 N cycled with
/// a largest node move of 0.179 m per iteration and 1 N with 0.728 m (at 10 and 100 increments
/// alike), and 0.25 N took 53 solves (47 with it).
#[test]
fn warped_solve_converges_at_twice_and_four_times_the_load() {
    let mat = Material::from_young_poisson(1e6, 0.3);
    let mut deflection = Vec::new();
    for load in [0.25, 0.5, 1.0] {
        let (p, f, tip, _) = cantilever(load);
        let mut tips = Vec::new();
        for increments in [10, 40] {
            let o = SolveOptions {
                increments,
                max_fixed_point: 300,
                tolerance: 1e-9,
                warp: true,
                reuse_factor: false,
            };
            let s = p.solve_forces(&mat, &f, None, &o).unwrap().solution;
            // Keeping a factorisation reaches the same fixed point at these loads too.
            let kept = SolveOptions {
                reuse_factor: true,
                ..o
            };
            let sk = p.solve_forces(&mat, &f, None, &kept).unwrap().solution;
            assert!(
                sk.converged,
                "{load} N, kept factor: {:e} m",
                sk.last_change
            );
            let gap =
                s.x.iter()
                    .zip(&sk.x)
                    .flat_map(|(a, b)| (0..3).map(move |k| (a[k] - b[k]).abs()))
                    .fold(0.0, f64::max);
            assert!(gap < 1e-7, "{load} N: kept factor {gap:e} m off");
            assert!(
                s.converged,
                "{load} N, {increments} increments: last move {:e} m after {} solves",
                s.last_change, s.iterations
            );
            // Equilibrium with the rotations of the converged state itself.
            let rot = p.rotations(&s.x, true);
            let fi = p.internal_forces(&mat, &rot, &s.x);
            let res = p
                .gather_free(&f.iter().zip(&fi).map(|(a, b)| a - b).collect::<Vec<_>>())
                .iter()
                .map(|v| v * v)
                .sum::<f64>()
                .sqrt();
            assert!(
                res < 1e-6 * load,
                "{load} N: equilibrium residual {res:e} N"
            );
            let z = tip.iter().map(|&i| s.x[i][2]).sum::<f64>() / tip.len() as f64;
            tips.push(z);
            eprintln!(
                "{load} N, {increments} increments: {} solves, tip z {z:.6} m, residual {res:e} N",
                s.iterations
            );
        }
        assert!((tips[0] - tips[1]).abs() < 1e-7, "{load} N: {tips:?}");
        deflection.push(0.005 - tips[0]);
    }
    // A stiffening response (the beam swings under the load): more load, more deflection, less
    // per newton. Measured 41.6, 61.2, 76.0 mm.
    assert!(
        deflection
            .windows(2)
            .all(|w| w[1] > w[0] && w[1] < 2.0 * w[0]),
        "{deflection:?}"
    );
}

/// The runtime reaches the same answer as the f64 solver at 1×, 2× and 4× the load with its
/// defaults (incremental loading, energy line search), to 0.2 % of the tip deflection (f32, PCG to
/// 1e-6); the line search is what makes it converge at the larger loads, and the first tick with
/// incremental loading is closer to the answer than one step.
#[test]
fn runtime_agrees_with_the_f64_solve_at_large_loads() {
    use crate::runtime_storage::Storage;
    use palpate_runtime::{RuntimeConfig, SolveStatus};
    let mat = Material::from_young_poisson(1e6, 0.3);
    for load in [0.25, 0.5, 1.0] {
        let (p, f, tip, m) = cantilever(load);
        let o = SolveOptions {
            increments: 20,
            max_fixed_point: 300,
            tolerance: 1e-10,
            warp: true,
            reuse_factor: false,
        };
        let reference = p.solve_forces(&mat, &f, None, &o).unwrap().solution;
        let ref_tip =
            |k: usize| tip.iter().map(|&i| reference.x[i][k]).sum::<f64>() / tip.len() as f64;
        let deflection = 0.005 - ref_tip(2);
        let buf = cantilever_buffers(&p, &m, &mat);
        // (line search, load increment): the defaults, one step without the line search.
        let mut results = Vec::new();
        for (line_search, load_increment) in
            [(true, 0.25), (false, f32::INFINITY), (true, f32::INFINITY)]
        {
            let cfg = RuntimeConfig {
                tolerance: 1e-6,
                max_iterations: 5000,
                rotation_iterations: 4,
                line_search,
                load_increment,
                ..Default::default()
            };
            let mut st = Storage::for_model(&buf.record(), &cfg);
            let mut rt = st.runtime(buf.record(), cfg).unwrap();
            for &i in &tip {
                rt.add_nodal_force(i, [0.0, 0.0, -(load / tip.len() as f64) as f32])
                    .unwrap();
            }
            let tip_err = |rt: &palpate_runtime::Runtime<'_>| {
                let u = rt.displacements();
                let z = tip
                    .iter()
                    .map(|&i| m.nodes[i][2] + u[3 * i + 2] as f64)
                    .sum::<f64>()
                    / tip.len() as f64;
                let x = tip
                    .iter()
                    .map(|&i| m.nodes[i][0] + u[3 * i] as f64)
                    .sum::<f64>()
                    / tip.len() as f64;
                ((z - ref_tip(2)).powi(2) + (x - ref_tip(0)).powi(2)).sqrt()
            };
            let first = rt.tick();
            assert_ne!(first.status, SolveStatus::Rejected);
            let first_err = tip_err(&rt);
            let mut ticks = 1;
            let mut settled = false;
            while ticks < 400 {
                let r = rt.tick();
                ticks += 1;
                assert_ne!(r.status, SolveStatus::Rejected);
                if r.load_remaining == 0.0 && (r.step as f64) < 1e-5 * deflection {
                    settled = true;
                    break;
                }
            }
            let err = tip_err(&rt);
            eprintln!(
                "{load} N, line search {line_search}, increment {load_increment}: first tick {} increments, tip error {:.3e} m; settled {settled} after {ticks} ticks, error {err:.3e} m (deflection {deflection:.4} m)",
                first.increments, first_err
            );
            results.push((settled, first_err, err));
        }
        let (inc, one_plain, one_ls) = (results[0], results[1], results[2]);
        for (name, r) in [("incremental", inc), ("one step + line search", one_ls)] {
            assert!(r.0, "{load} N, {name}: did not settle");
            assert!(
                r.2 < 2e-3 * deflection,
                "{load} N, {name}: tip error {:e} m",
                r.2
            );
        }
        // The first tick's answer: increments bring it closer to the reference than one step.
        assert!(
            inc.1 < one_ls.1,
            "{load} N: first tick {inc:?} vs one step {one_ls:?}"
        );
        if load > 0.25 {
            // Without the line search the lagged-rotation iteration does not find the answer.
            assert!(
                !one_plain.0 || one_plain.2 > 1e-2 * deflection,
                "{load} N: {one_plain:?}"
            );
        }
    }
}

/// The runtime's rotation rule for load increments (`RuntimeConfig::rotation_increment`): a load
/// raised by half takes one increment where the cantilever barely rotates (0.01 N) and the load
/// rule's two where it is bent (0.5 N, a third of its length), and one increment reaches the same
/// settled answer as two (f32, PCG to 1e-6).
#[test]
fn load_increments_follow_the_predicted_rotation() {
    use crate::runtime_storage::Storage;
    use palpate_runtime::{Runtime, RuntimeConfig};
    let mat = Material::from_young_poisson(1e6, 0.3);
    for (load, rotates) in [(0.01, false), (0.5, true)] {
        let (p, _, tip, m) = cantilever(load);
        let buf = cantilever_buffers(&p, &m, &mat);
        let push = |rt: &mut Runtime<'_>, total: f64| {
            for &i in &tip {
                rt.add_nodal_force(i, [0.0, 0.0, -(total / tip.len() as f64) as f32])
                    .unwrap();
            }
        };
        let settle = |rt: &mut Runtime<'_>| {
            for _ in 0..400 {
                let r = rt.tick();
                let size = rt
                    .displacements()
                    .iter()
                    .fold(0.0f32, |a, v| a.max(v.abs()));
                if r.load_remaining == 0.0 && r.step < 1e-5 * size {
                    return;
                }
            }
            panic!("{load} N: did not settle");
        };
        // (first tick's increments after the raise, settled displacements, θ_max before it)
        let mut runs = Vec::new();
        for rotation_increment in [RuntimeConfig::default().rotation_increment, 0.0] {
            let cfg = RuntimeConfig {
                tolerance: 1e-6,
                max_iterations: 5000,
                rotation_iterations: 4,
                rotation_increment,
                ..Default::default()
            };
            let mut st = Storage::for_model(&buf.record(), &cfg);
            let mut rt = st.runtime(buf.record(), cfg).unwrap();
            push(&mut rt, load);
            settle(&mut rt);
            let theta = rt.largest_rotation();
            // The angle the rule reads is the largest element rotation, read here from each
            // R_e's trace (cos θ = (tr R − 1)/2) rather than from the quaternions it scans.
            let from_trace = (0..rt.element_count())
                .filter_map(|e| rt.element_rotation(e))
                .map(|r| {
                    (0.5 * ((r[0] + r[4] + r[8]) as f64 - 1.0))
                        .clamp(-1.0, 1.0)
                        .acos()
                })
                .fold(0.0f64, f64::max);
            assert!(
                (theta as f64 - from_trace).abs() <= 1e-3 * from_trace.max(1e-3),
                "{load} N: θ_max {theta} rad, from the rotations' traces {from_trace} rad"
            );
            push(&mut rt, 0.5 * load);
            let first = rt.tick().increments;
            settle(&mut rt);
            runs.push((first, rt.displacements().to_vec(), theta));
        }
        let (with_rule, off) = (&runs[0], &runs[1]);
        assert_eq!(
            off.0, 2,
            "{load} N: the load rule splits a raise by half in two"
        );
        let expected = if rotates { 2 } else { 1 };
        assert_eq!(
            with_rule.0, expected,
            "{load} N: θ_max {} rad before the raise",
            with_rule.2
        );
        let scale = off.1.iter().fold(0.0f32, |a, v| a.max(v.abs()));
        let diff = with_rule
            .1
            .iter()
            .zip(&off.1)
            .fold(0.0f32, |a, (x, y)| a.max((x - y).abs()));
        assert!(
            diff < 1e-4 * scale,
            "{load} N: settled answers differ by {diff} m of {scale} m"
        );
    }
}

/// K_e w through the strain (`stiffness_times`) against the formed 12 × 12 product λ_e C_e w +
/// α_e D_e w, on every element of a block with per-element coefficients and arbitrary nodal
/// vectors: the same matrix, so agreement to round-off.
#[test]
fn stiffness_times_matches_the_formed_element_matrix() {
    let (mesh, fixed, surface) = block();
    let p = StaticProblem::new(&mesh, &fixed, &surface).unwrap();
    let ne = mesh.tets.len();
    let mat = Material {
        lambda: (0..ne)
            .map(|e| 1.0e4 * (1.0 + (0.37 * e as f64) % 3.0))
            .collect(),
        alpha: (0..ne)
            .map(|e| -2.0e3 * (1.0 + (0.11 * e as f64) % 2.0))
            .collect(),
        foundation: None,
    };
    for e in 0..ne {
        let w: [nalgebra::Vector3<f64>; 4] = std::array::from_fn(|k| {
            let s = (e * 4 + k) as f64;
            nalgebra::Vector3::new((0.7 * s).sin(), (1.3 * s).cos(), (0.3 * s + 1.0).sin()) * 1e-3
        });
        let got = p.stiffness_times(e, &mat, &w);
        let wv = nalgebra::SVector::<f64, 12>::from_fn(|i, _| w[i / 3][i % 3]);
        let want = p.element_stiffness(e, &mat) * wv;
        let scale = want.amax();
        for i in 0..12 {
            assert!(
                (got[i / 3][i % 3] - want[i]).abs() <= 1e-12 * scale,
                "element {e}, entry {i}: {} vs {}",
                got[i / 3][i % 3],
                want[i]
            );
        }
    }
}

/// The one-pass rotations and forces (the line search's) against the two passes they replace,
/// at a deformed state with rotations of a few degrees: the same to round-off.
#[test]
fn rotations_and_forces_match_the_separate_passes() {
    let (mesh, fixed, surface) = block();
    let p = StaticProblem::new(&mesh, &fixed, &surface).unwrap();
    let mat = Material::from_young_poisson(20_000.0, 0.3);
    let x: Vec<[f64; 3]> = mesh
        .nodes
        .iter()
        .map(|q| {
            // A bend about y (≈ 3° at the top) and a little stretch.
            let a = 0.6 * q[2];
            [
                q[0] * a.cos() + q[2] * a.sin() + 1e-3 * q[1],
                1.002 * q[1],
                -q[0] * a.sin() + q[2] * a.cos(),
            ]
        })
        .collect();
    for warp in [true, false] {
        let rot = p.rotations(&x, warp);
        let f = p.internal_forces(&mat, &rot, &x);
        let (rot1, f1) = p.rotations_and_forces(&mat, &x, warp);
        let scale = f.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(scale > 1.0, "the state should load the block, got {scale}");
        for (a, b) in rot.iter().zip(&rot1) {
            assert!((a - b).amax() <= 1e-15, "warp {warp}: {a} vs {b}");
        }
        for (i, (a, b)) in f.iter().zip(&f1).enumerate() {
            assert!(
                (a - b).abs() <= 1e-10 * scale,
                "warp {warp}, dof {i}: {a} vs {b}"
            );
        }
    }
}

/// A column on an elastic foundation under a uniform pressure p on its top face, ν = 0: the
/// stress is uniaxial and uniform (linear tetrahedra hold it exactly, and lumped areas are the
/// consistent loads of a uniform traction), so the top sinks by p/k_n (the springs) plus p H / E
/// (the column), nothing moves sideways — with or without warping (no element rotates).
#[test]
fn a_column_on_a_foundation_sinks_by_the_springs_and_the_column() {
    let (h, e, p, kn) = (0.05, 20_000.0, 400.0, 2.0e6);
    let mesh = box_mesh([0.1, 0.1, h], [3, 3, 2]);
    let fixed = mesh.node_groups["bottom"].clone();
    let surface = mesh.boundary_triangles();
    let prob = StaticProblem::on_foundation(&mesh, &fixed, &surface).unwrap();
    assert_eq!(
        prob.foundation.len(),
        fixed.len(),
        "every bottom node rests on springs"
    );
    assert!(prob.fixed.iter().all(|&f| !f), "no node stays fixed");
    let area: f64 = prob.foundation.iter().map(|s| s.area).sum();
    assert!(
        (area - 0.01).abs() < 1e-12,
        "supported area {area} m², expected 0.01"
    );
    for s in &prob.foundation {
        assert!(
            (s.normal[2] + 1.0).abs() < 1e-12,
            "bottom normal {:?}",
            s.normal
        );
    }
    // The top face's uniform pressure as nodal forces: p × each node's third of its triangles.
    let top: std::collections::HashSet<usize> = mesh.node_groups["top"].iter().copied().collect();
    let mut nodal = std::collections::HashMap::<usize, f64>::new();
    for t in surface.iter().filter(|t| t.iter().all(|i| top.contains(i))) {
        let [a, b, c] = t.map(|i| nalgebra::Vector3::from(mesh.nodes[i]));
        for &i in t {
            *nodal.entry(i).or_default() += (b - a).cross(&(c - a)).norm() / 6.0;
        }
    }
    let load = Load {
        contacts: Vec::new(),
        nodal: nodal
            .iter()
            .map(|(&i, &a)| (i, [0.0, 0.0, -p * a]))
            .collect(),
    };
    let mut mat = Material::from_young_poisson(e, 0.0);
    mat.foundation = Some(Foundation {
        normal: kn,
        tangential: 0.3 * kn,
    });
    for warp in [false, true] {
        let opts = SolveOptions {
            warp,
            ..Default::default()
        };
        let sol = prob.solve(&mat, &load, &opts).unwrap();
        for (i, (x, x0)) in sol.x.iter().zip(&mesh.nodes).enumerate() {
            let expected = -p / kn - p * x0[2] / e;
            assert!(
                (x[2] - x0[2] - expected).abs() < 1e-9 * (p / kn + p * h / e),
                "warp {warp}, node {i} at z {}: u_z {:e}, expected {expected:e}",
                x0[2],
                x[2] - x0[2]
            );
            assert!((x[0] - x0[0]).abs() < 1e-12 && (x[1] - x0[1]).abs() < 1e-12);
        }
    }
    // The material and the problem must agree on whether there is a foundation.
    let fixed_problem = StaticProblem::new(&mesh, &fixed, &surface).unwrap();
    assert!(matches!(
        fixed_problem.solve(&mat, &load, &SolveOptions::default()),
        Err(ForwardError::FoundationStiffness(_))
    ));
    mat.foundation = None;
    assert!(matches!(
        prob.solve(&mat, &load, &SolveOptions::default()),
        Err(ForwardError::FoundationStiffness(_))
    ));
}

/// A very stiff foundation is the fixed support: a probe's warped solve agrees with the fixed
/// problem's to the springs' own compliance.
#[test]
fn a_stiff_foundation_is_the_fixed_support() {
    let (mesh, fixed, surface) = block();
    let fixed_problem = StaticProblem::new(&mesh, &fixed, &surface).unwrap();
    let on_springs = StaticProblem::on_foundation(&mesh, &fixed, &surface).unwrap();
    let load = Load::contact([0.05, 0.05, 0.05], [0.3, -0.2, -2.0], 0.03);
    let mut mat = Material::from_young_poisson(20_000.0, 0.3);
    let a = fixed_problem
        .solve(&mat, &load, &SolveOptions::default())
        .unwrap();
    mat.foundation = Some(Foundation {
        normal: 1e13,
        tangential: 1e13,
    });
    let b = on_springs
        .solve(&mat, &load, &SolveOptions::default())
        .unwrap();
    let umax =
        a.x.iter()
            .zip(&mesh.nodes)
            .map(|(x, x0)| (0..3).map(|d| (x[d] - x0[d]).abs()).fold(0.0, f64::max))
            .fold(0.0, f64::max);
    let diff =
        a.x.iter()
            .zip(&b.x)
            .map(|(p, q)| (0..3).map(|d| (p[d] - q[d]).abs()).fold(0.0, f64::max))
            .fold(0.0, f64::max);
    assert!(
        umax > 1e-4 && diff < 1e-6 * umax,
        "moved {umax:e}, differ by {diff:e}"
    );
}

/// The closed-form rotated element stiffness is R_e (λ_e C_e + α_e D_e) R_eᵀ (eq. 3.63) formed
/// and multiplied out, for per-element (λ, α) — α up to past λ/2, where the shear term turns
/// negative — and rotations through large angles.
#[test]
fn rotated_stiffness_blocks_are_the_sandwich_of_eq_3_63() {
    let (mesh, fixed, surface) = block();
    let p = StaticProblem::new(&mesh, &fixed, &surface).unwrap();
    let ne = mesh.tets.len();
    let lambda: Vec<f64> = (0..ne).map(|e| 1e4 * (1.0 + e as f64 / 7.0)).collect();
    let alpha: Vec<f64> = (0..ne)
        .map(|e| lambda[e] * (0.05 + 0.6 * ((e * 37 % 11) as f64 / 10.0)))
        .collect();
    let mat = Material {
        lambda: lambda.clone(),
        alpha: alpha.clone(),
        ..Material::from_young_poisson(1.0, 0.3)
    };
    for e in 0..ne {
        let axis = nalgebra::Vector3::new(0.3 + e as f64, -1.1, 0.7 * e as f64).normalize();
        let r = nalgebra::Rotation3::from_axis_angle(
            &nalgebra::Unit::new_normalize(axis),
            0.4 * e as f64 + 0.9,
        )
        .into_inner();
        let want = rotate_sandwich(&p.element_stiffness(e, &mat), &r);
        let scale = want.amax();
        let mut seen = 0;
        for (a, b, block) in p.rotated_stiffness_blocks(e, &mat, &r) {
            let off = (block - want.fixed_view::<3, 3>(3 * a, 3 * b)).amax();
            assert!(
                off <= 1e-13 * scale,
                "element {e}, block ({a}, {b}): {off:e} of {scale:e}"
            );
            seen |= 1 << (4 * a + b);
        }
        assert_eq!(seen, 0xffff, "element {e}: every block once");
    }
}
