//! The spline material of seed 001 §4.2 (eqs. 18–20): stress and tangent against finite
//! differences of the energy, the Neo-Hookean initialisation (eq. 19) against eq. 16, and the
//! direct/adjoint gradients with respect to spline control values against finite differences.

use crate::support::{assert_gradients_agree, bar};
use nalgebra::{Matrix3, Rotation3, Vector3};
use palpate_motion::elastic::ElasticState;
use palpate_motion::hyperelastic::{self as he, RestTet};
use palpate_motion::model::{Material, Param, ParamKind};
use palpate_motion::scenario::record;
use palpate_motion::spline::{Response, Spline, SplineMaterial};

const LAMBDA: f64 = 1.0e4;
const MU: f64 = 2.0e4;

fn knots() -> (Vec<f64>, Vec<f64>) {
    (
        Spline::uniform_knots(0.5, 1.7, 9),
        Spline::uniform_knots(0.6, 1.5, 7),
    )
}

/// Neo-Hookean initialisation, then a non-Neo-Hookean perturbation of every control value
/// (stiffening f′, softer h′) so the checks do not only see the quadratic special case.
fn perturbed() -> SplineMaterial {
    let (kf, kh) = knots();
    let mut m = SplineMaterial::neo_hookean(LAMBDA, MU, kf, kh).unwrap();
    for (x, v) in m.f.knots.iter().zip(m.f.values.iter_mut()) {
        *v += 0.4 * MU * (x - 1.0).powi(3) + 0.1 * MU * (3.0 * x).sin();
    }
    for (x, v) in m.h.knots.iter().zip(m.h.values.iter_mut()) {
        *v += 0.2 * LAMBDA * (x - 1.0).powi(2) * (2.0 * x).cos();
    }
    m
}

/// Deformation gradients with distinct, pairwise-equal and all-equal principal stretches
/// (the SVD derivative's singular cases), each rotated on both sides.
fn gradients() -> Vec<Matrix3<f64>> {
    let r1 = Rotation3::from_scaled_axis(Vector3::new(0.3, -0.5, 0.2)).into_inner();
    let r2 = Rotation3::from_scaled_axis(Vector3::new(-0.1, 0.4, 0.7)).into_inner();
    let mut v = Vec::new();
    for d in [
        [1.15, 0.93, 0.82],
        [1.1, 1.1, 0.88],
        [1.0, 1.0, 1.0],
        [0.97, 0.97, 0.97],
        [1.3, 0.75, 1.02],
    ] {
        v.push(r1 * Matrix3::from_diagonal(&Vector3::from(d)) * r2);
    }
    // A general F with shear.
    v.push(Matrix3::new(
        1.1, 0.08, -0.05, 0.03, 0.92, 0.11, -0.04, 0.06, 1.04,
    ));
    v
}

/// P = ∂Ψ/∂F by central differences of Ψ (step 1e-6: the energy integral is accurate to
/// ~1e-15 relative, so the FD error is ~1e-8 of |P|; asserted at 1e-6 of max |P| + 1e-3 Pa for
/// the zero-stress rest state), and dP[dF] against central differences of P (step 1e-6,
/// asserted at 1e-6 relative to the tangent scale μ).
#[test]
fn spline_stress_and_tangent_match_finite_differences() {
    let m = perturbed();
    for f in gradients() {
        let st = m.state(&f).unwrap();
        let p = SplineMaterial::pk1(&st);
        let pmax = p.amax();
        let h = 1e-6;
        for i in 0..3 {
            for j in 0..3 {
                let mut fp = f;
                let mut fm = f;
                fp[(i, j)] += h;
                fm[(i, j)] -= h;
                let fd =
                    (m.energy_density(&fp).unwrap() - m.energy_density(&fm).unwrap()) / (2.0 * h);
                assert!(
                    (p[(i, j)] - fd).abs() <= 1e-6 * pmax + 1e-3,
                    "F {f}: P[{i}{j}] {} vs FD {fd}",
                    p[(i, j)]
                );
                let mut df = Matrix3::zeros();
                df[(i, j)] = 1.0;
                let dp = m.dpk1(&st, &df);
                let pp = SplineMaterial::pk1(&m.state(&fp).unwrap());
                let pm = SplineMaterial::pk1(&m.state(&fm).unwrap());
                let fd = (pp - pm) / (2.0 * h);
                let err = (dp - fd).amax();
                assert!(
                    err <= 1e-6 * MU,
                    "F {f}: dP/dF[{i}{j}] off by {err}: {dp} vs {fd}"
                );
            }
        }
    }
}

fn tet() -> (RestTet, [Vector3<f64>; 4]) {
    RestTet::sample()
}

/// Initialised by eq. 19 the spline material is Neo-Hookean (eq. 16): element forces and
/// tangents agree to 1e-8 relative for every deformation inside the knot range (the splines
/// reproduce f′ = μx and J h′ = −μ + λ(J² − 1)/2 exactly; what remains is SVD round-off), and
/// the rest tangent gives back λ and μ to 1e-12.
#[test]
fn neo_hookean_initialisation_matches_eq16_forces() {
    let (kf, kh) = knots();
    let sp = SplineMaterial::neo_hookean(LAMBDA, MU, kf, kh).unwrap();
    let (l, m) = sp.lame_at_rest();
    assert!((l - LAMBDA).abs() <= 1e-12 * LAMBDA && (m - MU).abs() <= 1e-12 * MU);
    let nh = Material::uniform(1, LAMBDA, MU, 0.0, 1.0, 1000.0);
    let mut spm = nh.clone();
    spm.spline = Some(sp);
    let (t, x0) = tet();
    for f in gradients() {
        let x = x0.map(|p| f * p);
        let fg = he::deformation_gradient(&t, &x);
        let a = ElasticState::new(&nh, 0, fg).unwrap();
        let b = ElasticState::new(&spm, 0, fg).unwrap();
        let (pa, pb) = (a.pk1(), b.pk1());
        let scale = pa.amax().max(1e-3 * MU); // at rest P = 0: compare on the modulus scale
        assert!(
            (pa - pb).amax() <= 1e-8 * scale,
            "F {f}: P Neo-Hookean {pa} vs spline {pb}"
        );
        let mut fa = [0.0; 12];
        let mut fb = [0.0; 12];
        he::add_stress_forces(&t, &pa, 1.0, &mut fa);
        he::add_stress_forces(&t, &pb, 1.0, &mut fb);
        let fmax = fa.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for k in 0..12 {
            assert!((fa[k] - fb[k]).abs() <= 1e-8 * fmax.max(1e-3 * MU * t.volume / 0.01));
        }
        let (ka, kb) = (a.tangent(&t), b.tangent(&t));
        let kmax = ka.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
        for r in 0..12 {
            for c in 0..12 {
                assert!(
                    (ka[r][c] - kb[r][c]).abs() <= 1e-8 * kmax,
                    "F {f}: K[{r}][{c}] {} vs {}",
                    ka[r][c],
                    kb[r][c]
                );
            }
        }
    }
}

/// The slope penalty's gradient against central differences (it is piecewise quadratic in the
/// control values; step 1e-4 of μ away from the kinks), on a material with negative slopes.
#[test]
fn slope_penalty_gradient_matches_finite_differences() {
    let mut m = perturbed();
    m.f.values[3] -= 0.5 * MU; // a dip: negative f″ on both sides
    m.h.values[2] += 0.6 * LAMBDA; // a bump: negative h″ after it
    let nf = m.f.values.len();
    let mut g = vec![0.0; nf + m.h.values.len()];
    let r0 = m.slope_penalty(&mut g);
    assert!(r0 > 0.0);
    let h = 1e-4 * MU;
    for c in 0..g.len() {
        let at = |d: f64| {
            let mut q = m.clone();
            if c < nf {
                q.f.values[c] += d;
            } else {
                q.h.values[c - nf] += d;
            }
            q.slope_penalty(&mut vec![0.0; g.len()])
        };
        let fd = (at(h) - at(-h)) / (2.0 * h);
        assert!(
            (g[c] - fd).abs() <= 1e-6 * (g[c].abs() + fd.abs()) + 1e-9 * r0 / MU,
            "control {c}: {} vs FD {fd}",
            g[c]
        );
    }
}

/// dΦ/dc for every control value of both splines: adjoint = direct to 1e-8 and both = central
/// FD (step 1e-5·μ, Newton at 1e-11 N) to 1e-4 of the largest component — the same tolerances
/// as the Neo-Hookean parameters in motion_gradients.rs. Markers and clamp forces, elastostatic
/// start, from a perturbed (non-Neo-Hookean) spline against Neo-Hookean data.
#[test]
fn control_value_gradients_direct_adjoint_and_fd_agree() {
    let (_, mut model) = bar([1, 4, 1], 24);
    model.newton.tol = 1e-11;
    model.newton.max_iter = 50;
    let ne = model.tets.len();
    let truth = Material::uniform(ne, LAMBDA, MU, 12.0, 1.0, 47.0);
    let mut obs = record(&model, &truth, 0.0, 1).unwrap();
    obs.force_weight = 1e3;
    let mut mat = Material::uniform(ne, LAMBDA, MU, 7.0, 0.85, 60.0);
    let (kf, kh) = knots();
    let mut sp = SplineMaterial::neo_hookean(1.3 * LAMBDA, 0.7 * MU, kf, kh).unwrap();
    for (x, v) in sp.f.knots.iter().zip(sp.f.values.iter_mut()) {
        *v += 0.3 * MU * (x - 1.0).powi(2);
    }
    mat.spline = Some(sp.clone());
    let mut params: Vec<Param> = (0..sp.len(Response::F))
        .map(|i| Param::of_element(ParamKind::SplineF, i))
        .collect();
    params.extend((0..sp.len(Response::H)).map(|i| Param::of_element(ParamKind::SplineH, i)));
    params.push(Param::global(ParamKind::Nu));
    let step = |par: &Param, q0: f64| {
        if par.kind.is_spline() {
            1e-5 * MU
        } else {
            1e-5 * q0
        }
    };
    let (ga, scale) = assert_gradients_agree(&model, &mat, &params, &obs, step);
    assert!(scale > 0.0);
    let nonzero = ga.iter().filter(|g| g.abs() > 1e-3 * scale).count();
    // The motion stays near rest, so only controls near stretch 1 and J = 1 matter; at least
    // the control values next to 1 on each spline must carry gradient.
    assert!(nonzero >= 4, "only {nonzero} control values carry gradient");
}
