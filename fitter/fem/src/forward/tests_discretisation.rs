//! The quadratic and average-nodal-pressure designs against independent references: the
//! runtime's element, the patch test, Timoshenko's beam and a converged reference.

use super::cantilever::Cantilever;
use super::discretisation::add_isotropic;
use super::*;
use crate::mesh::boxmesh::box_mesh;
use nalgebra::{DMatrix, Matrix3, Vector3};

/// The index form of the isotropic stiffness (`add_isotropic`, used by both designs) on a
/// linear element's gradients against the runtime's V_e B_eᵀ (λ_F F + α_G G) B_e (eqs. 3.33,
/// 3.63, a Voigt-matrix form written separately), with the thesis pair mapped to Lamé's: the
/// same matrix, so round-off.
#[test]
fn isotropic_block_is_the_runtime_element() {
    let x = [
        Vector3::new(0.0, 0.0, 0.0),
        Vector3::new(0.03, 0.002, -0.001),
        Vector3::new(0.004, 0.025, 0.003),
        Vector3::new(-0.002, 0.005, 0.02),
    ];
    let g = palpate_runtime::element::tet_geometry(&x).unwrap();
    let p = LambdaAlpha::from_young_poisson(150e3, 0.49);
    let reference = palpate_runtime::element::element_stiffness(&g, p.lambda, p.alpha);
    let mut k = DMatrix::zeros(12, 12);
    add_isotropic(&mut k, &g.grad, g.volume, p.alpha, 0.5 * p.lambda - p.alpha);
    let scale = reference.amax();
    for a in 0..12 {
        for b in 0..12 {
            assert!(
                (k[(a, b)] - reference[(a, b)]).abs() <= 1e-12 * scale,
                "({a}, {b}): index form {} vs runtime {}",
                k[(a, b)],
                reference[(a, b)]
            );
        }
    }
}

/// A box with its interior nodes moved off the grid by up to an eighth of a cell (deterministic), so
/// that no element is a scaled copy of another.
fn distorted_box() -> Mesh {
    let cells = [4, 3, 3];
    let size = [0.1, 0.04, 0.03];
    let mut m = box_mesh(size, cells);
    let on_face =
        |p: &[f64; 3]| (0..3).any(|d| p[d].abs() < 1e-12 || (p[d] - size[d]).abs() < 1e-12);
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    for p in m.nodes.iter_mut() {
        if !on_face(p) {
            for d in 0..3 {
                p[d] += 0.25 * next() * size[d] / cells[d] as f64;
            }
        }
    }
    m
}

/// The patch test with boundary loads only: the linear field u = x a (zero on the clamped face
/// x = 0) has the uniform stress σ = λ tr ε I + 2μ ε; its tractions σ n on the other five faces,
/// spread as each design's consistent nodal loads, and no interior force must give back u at
/// every node — corners and, for P2, edge nodes — on a distorted mesh at ν = 0.49. A solve of
/// a consistent, convergent design reproduces a linear field exactly, so the margin is
/// round-off of a system with κ/μ = 50.
fn patch_test(design: Discretisation) {
    let m = distorted_box();
    let fixed = m.node_groups["left"].clone();
    let surface = m.boundary_triangles();
    let (young, nu) = (150e3, 0.49);
    let material = Material::from_young_poisson(young, nu);
    let lame = young * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
    let mu = young / (2.0 * (1.0 + nu));
    let a: Vector3<f64> = Vector3::new(1e-3, 4e-4, -3e-4);
    // ∇u = a e_xᵀ.
    let grad_u = a * Vector3::x().transpose();
    let eps = 0.5 * (grad_u + grad_u.transpose());
    let sigma = Matrix3::identity() * (lame * eps.trace()) + eps * (2.0 * mu);
    let faces: [(&str, Vector3<f64>); 5] = [
        ("right", Vector3::x()),
        ("front", -Vector3::y()),
        ("back", Vector3::y()),
        ("bottom", -Vector3::z()),
        ("top", Vector3::z()),
    ];
    {
        let p = StaticProblem::new(&m, &fixed, &surface)
            .unwrap()
            .with_discretisation(design)
            .unwrap();
        let model = p.discretised().unwrap();
        let mut f = vec![0.0; 3 * model.nodes().len()];
        for (group, n) in faces {
            let mut on = vec![false; m.nodes.len()];
            for &i in &m.node_groups[group] {
                on[i] = true;
            }
            let tris: Vec<[usize; 3]> = surface
                .iter()
                .filter(|t| t.iter().all(|&i| on[i]))
                .copied()
                .collect();
            let t = sigma * n;
            for (fi, gi) in f
                .iter_mut()
                .zip(model.traction_load(&tris, [t.x, t.y, t.z]))
            {
                *fi += gi;
            }
        }
        let factor = model.factorise(&material).unwrap();
        let u = model.displacement(&factor, &f).unwrap();
        let scale = a.amax() * 0.1;
        for (i, (got, x)) in u.iter().zip(model.nodes()).enumerate() {
            let want = a * x[0];
            for d in 0..3 {
                assert!(
                    (got[d] - want[d]).abs() <= 1e-9 * scale,
                    "{}: node {i} at {x:?}, u[{d}] = {} expected {}",
                    design.name(),
                    got[d],
                    want[d]
                );
            }
        }
    }
}

#[test]
fn patch_test_quadratic() {
    patch_test(Discretisation::Quadratic);
}

#[test]
fn patch_test_nodal_pressure() {
    patch_test(Discretisation::NodalPressure);
}

/// The 10 cm beam of the evidence (1 × 1 cm, E = 150 kPa, 1 mN at the end): L/h = 10.
fn beam(cells: usize, poisson: f64) -> Cantilever {
    Cantilever {
        size: [0.1, 0.01, 0.01],
        cells: [cells, cells / 10, cells / 10],
        young: 150e3,
        poisson,
        load: 1e-3,
    }
}

/// Timoshenko's end-loaded cantilever, written here from Timoshenko & Goodier (bending) and
/// Cowper 1966 (κ of a rectangle) rather than taken from `Cantilever::timoshenko`.
fn timoshenko(c: &Cantilever) -> f64 {
    let [l, b, h] = c.size;
    let (e, nu, p) = (c.young, c.poisson, c.load);
    let bending = p * l * l * l / (3.0 * e * (b * h * h * h / 12.0));
    let shear = p * l * 2.0 * (1.0 + nu) / (e * b * h) * (12.0 + 11.0 * nu) / (10.0 * (1.0 + nu));
    bending + shear
}

/// Bending at ν = 0.45, 0.49 and 0.499, errors against a converged reference (P2 on 40 × 4 × 4
/// cells). Margins are the figures measured by `palpate-lab bench discretisation`
/// (docs/results/discretisation, there against P2 on 60 × 6 × 6) with about half again:
///
/// - the reference is Timoshenko's beam less what a fully clamped end adds to the stiffness
///   (measured −2.0, −2.7, −3.1 %; bound (−4.5 %, 0]: discretisation and clamp both stiffen);
/// - P2 on 20 × 2 × 2 is within 4 % of it (measured −1.1, −2.0, −2.6 %) and its error falls
///   more than 3× per halving of h from 10 × 1 × 1 (measured 5.1, 4.7, 4.3×: second order);
/// - P1 on 20 × 2 × 2 is far too stiff (measured −70, −89, −98 %: locking);
/// - ANP on 40 × 4 × 4 hardly changes with ν (measured −13.6 % at 0.45, −16.1 % at 0.499),
///   where P1 on the same mesh goes from −39 % to −95 %: the volumetric locking is gone, the
///   linear element's slow bending is not.
#[test]
fn cantilever_does_not_lock_with_the_new_designs() {
    let mut anp = Vec::new();
    let mut p1_fine = Vec::new();
    for nu in [0.45, 0.49, 0.499] {
        let reference = beam(40, nu)
            .tip_deflection(Discretisation::Quadratic)
            .unwrap()
            .deflection;
        let timo = timoshenko(&beam(40, nu));
        let err = |d: f64| (d - reference) / reference;
        let vs_timo = (reference - timo) / timo;
        assert!(
            vs_timo > -0.045 && vs_timo <= 0.0,
            "ν = {nu}: reference {reference:e} m vs Timoshenko {timo:e} m ({:.2} %)",
            100.0 * vs_timo
        );
        let tip = |cells, d| beam(cells, nu).tip_deflection(d).unwrap().deflection;
        let p1 = err(tip(20, Discretisation::Linear));
        let p2_coarse = err(tip(10, Discretisation::Quadratic));
        let p2 = err(tip(20, Discretisation::Quadratic));
        assert!(p2.abs() < 0.04, "ν = {nu}: P2 error {:.2} %", 100.0 * p2);
        assert!(
            p2_coarse.abs() > 3.0 * p2.abs(),
            "ν = {nu}: P2 errors {:.3} % → {:.3} % under halving h",
            100.0 * p2_coarse,
            100.0 * p2
        );
        assert!(
            p1 < -0.6,
            "ν = {nu}: P1 error {:.2} % (locking expected)",
            100.0 * p1
        );
        if nu != 0.49 {
            anp.push(err(tip(40, Discretisation::NodalPressure)));
            p1_fine.push(err(tip(40, Discretisation::Linear)));
        }
    }
    assert!(
        (anp[1] - anp[0]).abs() < 0.05 && anp[1] > -0.25,
        "ANP error {:.2} % at ν 0.45, {:.2} % at 0.499",
        100.0 * anp[0],
        100.0 * anp[1]
    );
    assert!(
        p1_fine[0] - p1_fine[1] > 0.4,
        "P1 error {:.2} % at ν 0.45, {:.2} % at 0.499 (locking expected)",
        100.0 * p1_fine[0],
        100.0 * p1_fine[1]
    );
}

/// The problem with a discretisation keeps the linear mesh's nodes and answers `solve` with
/// them; the warped solve and the adjoint's factor are refused by name.
#[test]
fn a_discretised_problem_solves_small_strains_and_refuses_the_rest() {
    let c = beam(20, 0.49);
    let (m, fixed, _) = c.mesh();
    let p = StaticProblem::new(&m, &fixed, &m.boundary_triangles())
        .unwrap()
        .with_discretisation(Discretisation::Quadratic)
        .unwrap();
    assert_eq!(p.discretisation(), Discretisation::Quadratic);
    let material = Material::from_young_poisson(c.young, c.poisson);
    let tip = m.node_groups["right"].clone();
    let load = Load {
        contacts: Vec::new(),
        nodal: tip
            .iter()
            .map(|&i| (i, [0.0, 0.0, -c.load / tip.len() as f64]))
            .collect(),
    };
    let linear = SolveOptions {
        warp: false,
        increments: 1,
        ..Default::default()
    };
    let sol = p.solve(&material, &load, &linear).unwrap();
    assert_eq!(sol.x.len(), m.nodes.len());
    // Point loads at the end nodes against the consistent traction: the same resultant, so the
    // tip moves by the same amount to within the load's local effect (a few per cent), and
    // much further than P1 on this mesh (which locks).
    let mean_tip = -tip
        .iter()
        .map(|&i| sol.x[i][2] - m.nodes[i][2])
        .sum::<f64>()
        / tip.len() as f64;
    let consistent = c
        .tip_deflection(Discretisation::Quadratic)
        .unwrap()
        .deflection;
    assert!(
        (mean_tip - consistent).abs() < 0.05 * consistent,
        "mean tip {mean_tip:e} vs consistent {consistent:e}"
    );
    let e = p
        .solve(&material, &load, &SolveOptions::default())
        .unwrap_err();
    assert!(e.to_string().contains("small-strain"), "{e}");
    let f = p.force_vector(&load).unwrap();
    let Err(e) = p.solve_forces(&material, &f, None, &linear) else {
        panic!("the discretised problem handed back the linear model's factor");
    };
    assert!(e.to_string().contains("P2"), "{e}");
}
