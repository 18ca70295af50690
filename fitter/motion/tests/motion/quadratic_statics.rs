//! The quasi-static Neo-Hookean solver on quadratic tetrahedra: the patch test at large strain,
//! agreement with the independent small-strain P2 model of `palpate_fem` at a small load (and
//! the linear elements' locking beside it), and the λ/μ sensitivities against finite
//! differences.

use palpate_fem::forward::cantilever::Cantilever;
use palpate_fem::forward::{
    Discretisation, DiscretisedModel, Material, StaticProblem as SmallStrainProblem,
};
use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_motion::hyperelastic::HyperParams;
use palpate_motion::quadratic_statics::{quadratic_sensitivity, solve_static_quadratic};
use palpate_motion::statics::{solve_static, static_sensitivity, StaticProblem};

fn lame(young: f64, poisson: f64) -> HyperParams {
    let mu = young / (2.0 * (1.0 + poisson));
    HyperParams {
        lambda: 2.0 * mu * poisson / (1.0 - 2.0 * poisson),
        mu,
        stiffening: 0.0,
    }
}

/// Every boundary node of a 2 × 2 × 2-cell block moved by a large affine map (stretches of
/// −10 % to +20 %, shears of 10 %): the solution inside — the interior corner and every interior
/// edge node — is the same map to round-off, since a homogeneous F is in equilibrium whatever
/// the quadrature.
#[test]
fn quadratic_patch_test_at_large_strain() {
    let mesh = box_mesh([0.03, 0.02, 0.02], [2, 2, 2]);
    let mut boundary = vec![false; mesh.nodes.len()];
    for t in mesh.boundary_triangles() {
        t.iter().for_each(|&n| boundary[n] = true);
    }
    let fixed: Vec<usize> = (0..mesh.nodes.len()).filter(|&n| boundary[n]).collect();
    assert!(
        fixed.len() < mesh.nodes.len(),
        "the block has an interior node"
    );
    let a = [[1.2, 0.1, 0.0], [0.05, 0.9, 0.1], [0.0, -0.1, 1.1]];
    let c = [0.001, -0.002, 0.0005];
    let map = |x: [f64; 3]| -> [f64; 3] {
        std::array::from_fn(|i| (0..3).map(|j| a[i][j] * x[j]).sum::<f64>() + c[i])
    };
    let mut p = StaticProblem::new(&mesh, lame(150e3, 0.49), fixed.clone());
    p.fixed_displacement = fixed
        .iter()
        .map(|&n| {
            let (x, y) = (mesh.nodes[n], map(mesh.nodes[n]));
            std::array::from_fn(|d| y[d] - x[d])
        })
        .collect();
    p.tol = 1e-10;
    let s = solve_static_quadratic(&p).unwrap();
    let on_boundary = s.mesh.lift_flags(&boundary);
    let mut checked = 0;
    for (n, x) in s.mesh.nodes.iter().enumerate() {
        let want = map(*x);
        let err = (0..3)
            .map(|d| (s.solution.positions[n][d] - want[d]).abs())
            .fold(0.0, f64::max);
        assert!(err < 1e-10, "node {n}: error {err:.3e} m");
        checked += usize::from(!on_boundary[n]);
    }
    assert!(checked > 1, "only {checked} free nodes were checked");
}

/// The box cantilever of docs/results/discretisation (100 × 10 × 10 mm, 10 × 1 × 1 cells,
/// E = 150 kPa, clamped at x = 0) with 10 µN shared among the end face's corners: deflections
/// of 2e-4 of the length, where the Neo-Hookean model is the small-strain one to ~1e-4. Its
/// quadratic solve must match `palpate_fem`'s small-strain P2 (an independent assembly) to 1e-3
/// relative at ν = 0.45, 0.49, 0.499; the linear solve on the same mesh deflects less than half
/// as much (locking).
#[test]
fn quadratic_matches_small_strain_p2_and_linear_locks() {
    for poisson in [0.45, 0.49, 0.499] {
        let beam = Cantilever {
            size: [0.1, 0.01, 0.01],
            cells: [10, 1, 1],
            young: 150e3,
            poisson,
            load: 1e-5,
        };
        let (mesh, fixed, _) = beam.mesh();
        let end = mesh.node_groups["right"].clone();
        let force = [0.0, 0.0, -beam.load / end.len() as f64];
        let mut p = StaticProblem::new(&mesh, lame(beam.young, poisson), fixed.clone());
        p.forces = end.iter().map(|&n| (n, force)).collect();
        p.load_steps = 1;
        p.tol = 1e-10;
        let quadratic = solve_static_quadratic(&p).unwrap();
        let small = SmallStrainProblem::new(&mesh, &fixed, &mesh.boundary_triangles()).unwrap();
        let model = DiscretisedModel::new(&small, Discretisation::Quadratic).unwrap();
        assert_eq!(model.nodes(), &quadratic.mesh.nodes[..], "the same lift");
        let mut f = vec![0.0; 3 * model.nodes().len()];
        for &n in &end {
            f[3 * n + 2] = force[2];
        }
        let factor = model
            .factorise(&Material::from_young_poisson(beam.young, poisson))
            .unwrap();
        let u_ref = model.displacement(&factor, &f).unwrap();
        let (mut diff, mut norm) = (0.0, 0.0);
        for (n, u) in u_ref.iter().enumerate() {
            for d in 0..3 {
                let mine = quadratic.solution.positions[n][d] - quadratic.mesh.nodes[n][d];
                diff += (mine - u[d]).powi(2);
                norm += u[d] * u[d];
            }
        }
        let rel = (diff / norm).sqrt();
        assert!(rel < 1e-3, "ν = {poisson}: P2 vs small-strain P2 {rel:.2e}");
        let tip = |x: &[[f64; 3]], rest: &[[f64; 3]]| {
            end.iter().map(|&n| rest[n][2] - x[n][2]).sum::<f64>() / end.len() as f64
        };
        // The locked linear model at 100 times the load (still far below 1e-3 of the length):
        // at 10 µN its energy changes drown in round-off before the residual reaches 1e-10 N.
        let mut p1 = p.clone();
        p1.forces.iter_mut().for_each(|(_, f)| f[2] *= 100.0);
        p1.tol = 1e-9;
        let linear = solve_static(&p1).unwrap();
        let (c1, c2) = (
            tip(&linear.positions, &mesh.nodes) / (100.0 * beam.load),
            tip(&quadratic.solution.positions, &quadratic.mesh.nodes) / beam.load,
        );
        assert!(
            c1 < 0.5 * c2,
            "ν = {poisson}: tip compliance P1 {c1:.3e} m/N, P2 {c2:.3e} m/N"
        );
    }
}

/// A 60 mm cantilever at ν = 0.49 sagging under its weight and a 20 mN tip load (P2 by about a
/// fifth of its length, the locked P1 by a few percent): ∂x/∂λ and ∂x/∂μ of both designs against central differences of the solves (relative
/// step 1e-3; agreement to 1e-4 of the sensitivity's norm).
#[test]
fn sensitivities_match_finite_differences() {
    let mesh = box_mesh([0.06, 0.01, 0.01], [4, 1, 1]);
    let fixed = mesh.node_groups["left"].clone();
    let end = mesh.node_groups["right"].clone();
    let problem = |m: HyperParams| {
        let mut p = StaticProblem::new(&mesh, m, fixed.clone());
        p.density = 1070.0;
        p.gravity = [0.0, 0.0, -9.81];
        p.forces = end.iter().map(|&n| (n, [0.0, 0.0, -0.02 / 4.0])).collect();
        p.load_steps = 3;
        p.tol = 1e-8;
        p
    };
    let base = lame(150e3, 0.49);
    type Solve = fn(&StaticProblem<'_>) -> (Vec<[f64; 3]>, [Vec<[f64; 3]>; 2]);
    let p1: Solve = |p| {
        let s = solve_static(p).unwrap();
        let d = static_sensitivity(p, &s).unwrap();
        (s.positions, [d.dlambda, d.dmu])
    };
    let p2: Solve = |p| {
        let s = solve_static_quadratic(p).unwrap();
        let d = quadratic_sensitivity(p, &s).unwrap();
        (s.solution.positions, [d.dlambda, d.dmu])
    };
    for (name, solve) in [("P1", p1), ("P2", p2)] {
        let (x, sens) = solve(&problem(base));
        let sag = end.iter().map(|&n| mesh.nodes[n][2] - x[n][2]).sum::<f64>() / 4.0;
        assert!(
            sag > 0.001,
            "{name}: sag {sag:.4} m is not a large deflection"
        );
        for (k, analytic) in sens.iter().enumerate() {
            let mut up = base;
            let mut down = base;
            let h = 1e-3 * if k == 0 { base.lambda } else { base.mu };
            if k == 0 {
                up.lambda += h;
                down.lambda -= h;
            } else {
                up.mu += h;
                down.mu -= h;
            }
            let (xp, xm) = (solve(&problem(up)).0, solve(&problem(down)).0);
            let (mut diff, mut norm) = (0.0, 0.0);
            for n in 0..x.len() {
                for d in 0..3 {
                    let fd = (xp[n][d] - xm[n][d]) / (2.0 * h);
                    diff += (fd - analytic[n][d]).powi(2);
                    norm += analytic[n][d].powi(2);
                }
            }
            let rel = (diff / norm).sqrt();
            assert!(rel < 1e-4, "{name} ∂x/∂{}: {rel:.2e}", ["λ", "μ"][k]);
        }
    }
}
