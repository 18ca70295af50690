//! The runtime (f32, matrix-free PCG, fixed memory) against independent references: a dense f64
//! direct solve, an f64 equilibrium check of the warped solution, and the patch test.

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_fem::mesh::Mesh;
use palpate_runtime::contact_rule::{contact_weights, lumped_surface_areas};
use palpate_runtime::element::{element_stiffness, tet_geometry};
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::rotation::warp_rotation_svd;
use palpate_runtime::{Runtime, RuntimeConfig, SolveStatus};
use palpate_tests::model::{self, Storage};

const E: f64 = 10_000.0;
const NU: f64 = 0.3;

fn sponge(cells: [usize; 3]) -> (Mesh, Vec<usize>) {
    let m = box_mesh([0.1, 0.1, 0.05], cells);
    let fixed = m.group("bottom").unwrap().to_vec();
    (m, fixed)
}

/// Nodal forces of the shared contact rule, in f64.
fn contact_forces(
    m: &Mesh,
    fixed: &[usize],
    c: [f64; 3],
    force: [f64; 3],
    radius: f64,
) -> Vec<f64> {
    let mut areas = vec![0.0; m.nodes.len()];
    lumped_surface_areas(|i| m.nodes[i], m.boundary_triangles(), &mut areas);
    let mut f = vec![0.0; 3 * m.nodes.len()];
    contact_weights(
        c,
        radius,
        |i| m.nodes[i],
        &areas,
        |i| fixed.contains(&i),
        |i, w| {
            for k in 0..3 {
                f[3 * i + k] = w * force[k];
            }
        },
    )
    .unwrap();
    f
}

/// Dense global K (f64) for given per-element rotations (None = no warping).
fn dense_k(m: &Mesh, p: LambdaAlpha, rot: Option<&[Matrix3<f64>]>) -> DMatrix<f64> {
    let n = m.nodes.len();
    let mut k = DMatrix::zeros(3 * n, 3 * n);
    for (e, t) in m.tets.iter().enumerate() {
        let g = tet_geometry(&t.map(|i| Vector3::from(m.nodes[i]))).unwrap();
        let ke = element_stiffness(&g, p.lambda, p.alpha);
        let r = rot.map(|r| r[e]).unwrap_or_else(Matrix3::identity);
        for a in 0..4 {
            for b in 0..4 {
                let blk = r * ke.fixed_view::<3, 3>(3 * a, 3 * b) * r.transpose();
                let (ia, ib) = (3 * t[a], 3 * t[b]);
                for i in 0..3 {
                    for j in 0..3 {
                        k[(ia + i, ib + j)] += blk[(i, j)];
                    }
                }
            }
        }
    }
    k
}

/// Ticks until the full load is applied and the rotation fixed point has settled: the step is
/// below 1e-6 of the largest displacement (f32 resolves about 1e-7 of it).
fn run_to_rest(rt: &mut Runtime<'_>, max_ticks: usize) -> usize {
    let mut last = 0.0;
    for tick in 0..max_ticks {
        let rep = rt.tick();
        assert_ne!(rep.status, SolveStatus::Rejected);
        let umax = rt
            .displacements()
            .iter()
            .fold(0.0f32, |a, v| a.max(v.abs()));
        last = rep.step / umax.max(1e-30);
        if rep.load_fraction >= 1.0
            && rep.step <= 1e-6 * umax
            && rep.status == SolveStatus::Converged
        {
            return tick + 1;
        }
    }
    panic!("did not settle in {max_ticks} ticks (last relative step {last:e})");
}

#[test]
fn pcg_matches_dense_direct_solve_without_warping() {
    let (m, fixed) = sponge([4, 4, 2]);
    let p = LambdaAlpha::from_young_poisson(E, NU);
    let buf = model::homogeneous(&m, &fixed, p.lambda, p.alpha);
    let cfg = model::linear_config(1e-7, 5000);
    let mut storage = Storage::for_model(&buf.record(), &cfg);
    let mut rt = storage.runtime(buf.record(), cfg).unwrap();
    let (c, force, radius) = ([0.05, 0.05, 0.05], [0.1, -0.05, -0.5], 0.03);
    rt.set_contact_force([0.05, 0.05, 0.05], [0.1, -0.05, -0.5], 0.03)
        .unwrap();
    let rep = rt.tick();
    assert_eq!(rep.status, SolveStatus::Converged);

    // Reference: dense LU of the reduced K u = f.
    let k = dense_k(&m, p, None);
    let f = contact_forces(&m, &fixed, c, force, radius);
    let free: Vec<usize> = (0..3 * m.nodes.len())
        .filter(|d| !fixed.contains(&(d / 3)))
        .collect();
    let kr = DMatrix::from_fn(free.len(), free.len(), |i, j| k[(free[i], free[j])]);
    let fr = DVector::from_fn(free.len(), |i, _| f[free[i]]);
    let ur = kr.lu().solve(&fr).unwrap();
    let umax = ur.amax();
    let mut err: f64 = 0.0;
    for (i, &d) in free.iter().enumerate() {
        err = err.max((rt.displacements()[d] as f64 - ur[i]).abs());
    }
    // f32 storage and a 1e-7 CG tolerance: agreement to 1e-4 of the largest displacement.
    assert!(
        err < 1e-4 * umax,
        "max error {err:e} vs max displacement {umax:e}"
    );
    for &n in &fixed {
        assert_eq!(&rt.displacements()[3 * n..3 * n + 3], &[0.0, 0.0, 0.0]);
    }
}

#[test]
fn warped_solution_satisfies_f64_equilibrium() {
    let (m, fixed) = sponge([6, 6, 3]);
    let p = LambdaAlpha::from_young_poisson(E, NU);
    let buf = model::homogeneous(&m, &fixed, p.lambda, p.alpha);
    let cfg = RuntimeConfig {
        tolerance: 1e-6,
        max_iterations: 2000,
        load_step: 0.25,
        rotation_iterations: 10,
        ..Default::default()
    };
    let mut storage = Storage::for_model(&buf.record(), &cfg);
    let mut rt = storage.runtime(buf.record(), cfg).unwrap();
    // A large load: 3 N on a 10 kPa sponge pushes the top in by ~1 cm with visible rotations.
    let (c, force, radius) = ([0.05, 0.05, 0.05], [0.8, 0.0, -3.0], 0.02);
    rt.set_contact_force([0.05, 0.05, 0.05], [0.8, 0.0, -3.0], 0.02)
        .unwrap();
    run_to_rest(&mut rt, 400);
    let u: Vec<f64> = rt.displacements().iter().map(|v| *v as f64).collect();
    let umax = u.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    assert!(
        umax > 5e-3,
        "test load should deform visibly, max |u| = {umax}"
    );

    // Independent f64 evaluation of f_int(x) = Σ R_e K_e (R_eᵀ x_e − x₀_e), R from SVD.
    let f_ext = contact_forces(&m, &fixed, c, force, radius);
    let mut f_int = vec![0.0; u.len()];
    for t in &m.tets {
        let x0 = t.map(|i| Vector3::from(m.nodes[i]));
        let g = tet_geometry(&x0).unwrap();
        let x = t.map(|i| {
            Vector3::from(m.nodes[i]) + Vector3::new(u[3 * i], u[3 * i + 1], u[3 * i + 2])
        });
        let f = palpate_runtime::element::deformation_gradient(&g, &x);
        let r = warp_rotation_svd(&f);
        let ke = element_stiffness(&g, p.lambda, p.alpha);
        let mut d = nalgebra::SVector::<f64, 12>::zeros();
        for a in 0..4 {
            let v = r.transpose() * x[a] - x0[a];
            d.fixed_rows_mut::<3>(3 * a).copy_from(&v);
        }
        let fe = ke * d;
        for a in 0..4 {
            let fa = r * fe.fixed_rows::<3>(3 * a);
            for k in 0..3 {
                f_int[3 * t[a] + k] += fa[k];
            }
        }
    }
    let mut res2 = 0.0;
    let mut ext2 = 0.0;
    for d in 0..u.len() {
        if fixed.contains(&(d / 3)) {
            continue;
        }
        res2 += (f_ext[d] - f_int[d]).powi(2);
        ext2 += f_ext[d].powi(2);
    }
    let rel = (res2 / ext2).sqrt();
    // The runtime converges the rotation fixed point in f32; 1e-3 of the load is f32 round-off on
    // forces that cancel between neighbouring elements.
    assert!(rel < 1e-3, "relative equilibrium residual {rel:e}");
}

/// A tick at the state and load of a settled residual pass reuses that residual (no pass over
/// the elements), and what it reuses is what a pass made anew finds: rotations within the
/// rotation tolerance of the polar ones (f64, SVD) and a residual the solve cannot see (no PCG
/// iteration). A change of load or of state passes again. At the default rotation tolerance and
/// at one a hundred times tighter, where the last pass's own settling decides.
#[test]
fn a_quiet_tick_reuses_a_settled_pass_and_a_change_passes_again() {
    for rotation_tolerance in [1.0, 0.01] {
        quiet_tick_case(RuntimeConfig {
            rotation_tolerance,
            ..Default::default()
        });
    }
}

fn quiet_tick_case(cfg: RuntimeConfig) {
    let (m, fixed) = sponge([6, 6, 3]);
    let p = LambdaAlpha::from_young_poisson(E, NU);
    let buf = model::homogeneous(&m, &fixed, p.lambda, p.alpha);
    let mut storage = Storage::for_model(&buf.record(), &cfg);
    let mut rt = storage.runtime(buf.record(), cfg).unwrap();
    // The load of the equilibrium test: rotations that take several ticks to settle.
    rt.set_contact_force([0.05, 0.05, 0.05], [0.8, 0.0, -3.0], 0.02)
        .unwrap();
    let quiet_after = |rt: &mut Runtime<'_>| {
        (1..=200)
            .find(|_| rt.tick().passes == 0)
            .expect("no quiet tick in 200 ticks of a load held still")
    };
    let settled_in = quiet_after(&mut rt);
    assert!(settled_in > 1, "the first tick after a load is never quiet");
    let u = rt.displacements().to_vec();
    let mut off = 0.0f64;
    for (e, t) in m.tets.iter().enumerate() {
        let x0 = t.map(|i| Vector3::from(m.nodes[i]));
        let g = tet_geometry(&x0).unwrap();
        let x = t.map(|i| {
            let d = Vector3::new(u[3 * i], u[3 * i + 1], u[3 * i + 2]).cast::<f64>();
            Vector3::from(m.nodes[i]) + d
        });
        let polar = warp_rotation_svd(&palpate_runtime::element::deformation_gradient(&g, &x));
        let kept = Matrix3::from_row_slice(&rt.element_rotation(e).unwrap().map(|v| v as f64));
        // The axial vector of the small rotation between them (the trace's arccos loses such
        // angles to f32 round-off).
        let d = kept.transpose() * polar;
        let w = Vector3::new(
            d[(2, 1)] - d[(1, 2)],
            d[(0, 2)] - d[(2, 0)],
            d[(1, 0)] - d[(0, 1)],
        );
        off = off.max(0.5 * w.norm());
    }
    let settled = cfg.rotation_tolerance * cfg.tolerance;
    assert!(
        off <= settled as f64,
        "a quiet tick kept rotations {off:e} rad from the polar ones (settled: {settled:e})"
    );
    let quiet = rt.tick();
    assert_eq!(quiet.passes, 0);
    assert_eq!((quiet.iterations, quiet.step), (0, 0.0));
    assert_eq!(rt.displacements(), &u[..]);

    // A pass made anew at the same state (a new budget clears the settled pass).
    rt.set_budget(cfg.max_iterations, cfg.tolerance);
    let fresh = rt.tick();
    assert_eq!(fresh.passes, 1);
    assert_eq!(
        fresh.iterations, 0,
        "the reused residual hid one the solve can see (relative {:e})",
        fresh.rel_residual
    );
    assert!(fresh.rel_residual <= cfg.tolerance);

    // A load change passes again, and so does a state set from outside.
    let node = (0..m.nodes.len()).find(|i| !fixed.contains(i)).unwrap();
    rt.add_nodal_force(node, [0.0, 0.0, -0.05]).unwrap();
    assert!(
        rt.tick().passes >= 1,
        "a load change reused the old residual"
    );
    quiet_after(&mut rt);
    let u = rt.displacements().to_vec();
    rt.set_displacements(&u).unwrap();
    assert!(
        rt.tick().passes >= 1,
        "a state set from outside reused the old residual"
    );
}

/// Consistent nodal loads of the uniform stress σ = λ_L tr(ε) I + 2μ ε (Hooke's law, written
/// here from E and ν) on the boundary faces: each outward triangle's traction σn, constant over
/// the triangle, shared equally by its three corners (exact for linear shape functions). No
/// interior node is loaded. Independent of the element stiffness.
fn boundary_loads_of_uniform_stress(m: &Mesh, eps: Matrix3<f64>) -> Vec<f64> {
    let lame = E * NU / ((1.0 + NU) * (1.0 - 2.0 * NU));
    let mu = E / (2.0 * (1.0 + NU));
    let sigma = Matrix3::identity() * (lame * eps.trace()) + eps * (2.0 * mu);
    let (lo, hi) = m.bounds();
    let centre = Vector3::from([0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k])));
    let mut f = vec![0.0; 3 * m.nodes.len()];
    for tri in m.boundary_triangles() {
        let [a, b, c] = tri.map(|i| Vector3::from(m.nodes[i]));
        // Area-weighted normal, turned away from the box's centre (the box is convex).
        let mut n = (b - a).cross(&(c - a)) * 0.5;
        if n.dot(&((a + b + c) / 3.0 - centre)) < 0.0 {
            n = -n;
        }
        let t = sigma * n;
        for &i in &tri {
            for k in 0..3 {
                f[3 * i + k] += t[k] / 3.0;
            }
        }
    }
    f
}

/// The patch test (Irons; Zienkiewicz & Taylor vol. 1, §10.3): a linear displacement field
/// u = (a z, b z, c z), which vanishes on the fixed bottom face, has a uniform stress; loaded only
/// by the consistent nodal loads of that stress's traction on the other boundary faces (no force
/// on any interior node), the mesh must reproduce the field exactly. The loads come from Hooke's
/// law and the face areas, not from K, so a wrong stiffness (a wrong volume, shear factor or
/// modulus in the shared element maths) fails here, where f = K·u_lin would pass with any K.
#[test]
fn patch_test_linear_field_is_reproduced() {
    let (m, fixed) = sponge([5, 4, 3]);
    let p = LambdaAlpha::from_young_poisson(E, NU);
    let buf = model::homogeneous(&m, &fixed, p.lambda, p.alpha);
    let (lo, hi) = m.bounds();
    let interior = |x: &[f64; 3]| (0..3).all(|k| x[k] > lo[k] + 1e-9 && x[k] < hi[k] - 1e-9);
    assert!(
        m.nodes.iter().any(interior),
        "the patch needs interior nodes"
    );
    // Warped: the corotational model differs from the linear one by O(θ) for rotations θ of the
    // field, so it passes the patch test only for small fields; at 1e-3 of the amplitude the
    // rotation effect (≈ 4e-5 rad) is below 1e-3 of the field.
    for (warp, amp) in [(false, 1.0), (true, 1e-3)] {
        let h = [2e-3 * amp / 0.05, -1e-3 * amp / 0.05, -3e-3 * amp / 0.05];
        let lin = |x: [f64; 3]| h.map(|hk| hk * x[2]);
        // ε = sym(∇u) of u = h z: ∂u_k/∂z = h_k.
        let grad = Matrix3::new(0.0, 0.0, h[0], 0.0, 0.0, h[1], 0.0, 0.0, h[2]);
        let eps = (grad + grad.transpose()) * 0.5;
        let f = boundary_loads_of_uniform_stress(&m, eps);
        let cfg = RuntimeConfig {
            warp,
            tolerance: 1e-7,
            max_iterations: 5000,
            rotation_iterations: 10,
            ..Default::default()
        };
        let mut storage = Storage::for_model(&buf.record(), &cfg);
        let mut rt = storage.runtime(buf.record(), cfg).unwrap();
        for (i, x) in m.nodes.iter().enumerate() {
            let fi = [f[3 * i], f[3 * i + 1], f[3 * i + 2]];
            if interior(x) {
                assert_eq!(fi, [0.0; 3], "interior node {i} loaded");
            }
            if !fixed.contains(&i) {
                rt.add_nodal_force(i, fi.map(|v| v as f32)).unwrap();
            }
        }
        if warp {
            // Rotations are ~1e-5 rad: a few fixed-point ticks settle them to f32 resolution.
            for _ in 0..10 {
                assert_ne!(rt.tick().status, SolveStatus::Rejected);
            }
        } else {
            assert_eq!(rt.tick().status, SolveStatus::Converged);
        }
        let mut err: f64 = 0.0;
        for (i, x) in m.nodes.iter().enumerate() {
            let want = lin(*x);
            for k in 0..3 {
                err = err.max((rt.displacements()[3 * i + k] as f64 - want[k]).abs());
            }
        }
        // Without warping the field is exact to f32 round-off (1e-5 of 3 mm); with warping (small
        // field) to 1e-3 of its amplitude.
        let tol = if warp { 3e-9 } else { 3e-8 };
        assert!(
            err < tol,
            "warp = {warp}: max deviation from the linear field {err:e} m"
        );
    }
}
