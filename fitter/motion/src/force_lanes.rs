//! Internal forces (eqs. 16–17) of four Neo-Hookean elements at once, structure of arrays: the
//! force pass of a Newton iteration with a kept factor, the most frequent element pass of a
//! motion simulation (three or more per step against one tangent pass), in 256-bit lanes.
//!
//! The arithmetic is that of the scalar path ([`super::hyperelastic::FParts::new`],
//! [`super::hyperelastic::pk1`], [`super::viscosity::Rate::new`] or, under the objective reading,
//! [`super::viscosity::Rate::objective`], [`super::viscosity::stress`],
//! [`super::hyperelastic::add_stress_forces`]) term by term in nalgebra's order, so the forces
//! are the same to the last bit (Rust does not contract a·b + c into fused multiply-adds); a test
//! holds the two paths to it. A creep branch's step stress (1 + g b) P⁰ + F C_n
//! ([`super::relaxation::StepBranch::stress`]) is added the same way, so a material with the
//! branch keeps the fast pass. Spline materials keep the scalar path.

use super::hyperelastic::RestTet;
use super::model::{Material, Model, ParamKind};
use super::relaxation::StepBranch;
use super::viscosity::{rate_power, Form};
use super::MotionError;

/// Elements per lane group (four f64: one AVX2 register).
pub(crate) const LANES: usize = 4;

type L = [f64; LANES];

/// 3 × 3 per lane, `m[i][j]` row i, column j.
type M = [[L; 3]; 3];

#[inline(always)]
fn lanes(f: impl Fn(usize) -> f64) -> L {
    [f(0), f(1), f(2), f(3)]
}

#[inline(always)]
fn map2(a: &L, b: &L, f: impl Fn(f64, f64) -> f64) -> L {
    lanes(|l| f(a[l], b[l]))
}

/// Σ_a y_a ∇φ_aᵀ (F of positions, Ḟ of velocities), summed a = 0..3 from zero as nalgebra's
/// `f += x_a ∇φ_aᵀ` does.
#[inline(always)]
fn gradient(y: &[[L; 3]; 4], g: &[[L; 3]; 4]) -> M {
    let mut m = [[[0.0; LANES]; 3]; 3];
    for a in 0..4 {
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] = lanes(|l| m[i][j][l] + y[a][i][l] * g[a][j][l]);
            }
        }
    }
    m
}

/// nalgebra's `cross` of columns `p`, `q` (each `[L; 3]`).
#[inline(always)]
fn cross(p: &[L; 3], q: &[L; 3]) -> [L; 3] {
    [
        lanes(|l| p[1][l] * q[2][l] - p[2][l] * q[1][l]),
        lanes(|l| p[2][l] * q[0][l] - p[0][l] * q[2][l]),
        lanes(|l| p[0][l] * q[1][l] - p[1][l] * q[0][l]),
    ]
}

/// Entry (r, c) of A B, or of Aᵀ B when `transpose_a`, summed (a_0 b_0 + a_1 b_1) + a_2 b_2
/// as nalgebra's 3 × 3 product sums it.
#[inline(always)]
fn product(a: &M, b: &M, r: usize, c: usize, transpose_a: bool) -> L {
    let at = |k: usize| if transpose_a { a[k][r] } else { a[r][k] };
    let (a0, a1, a2) = (at(0), at(1), at(2));
    lanes(|l| (a0[l] * b[0][c][l] + a1[l] * b[1][c][l]) + a2[l] * b[2][c][l])
}

/// nalgebra's `norm_squared` of a 3 × 3 matrix: column by column, each (a² + b²) + c².
#[inline(always)]
fn norm_squared(m: &M) -> L {
    let mut s = [0.0; LANES];
    for j in 0..3 {
        s = lanes(|l| {
            s[l] + (m[0][j][l] * m[0][j][l] + m[1][j][l] * m[1][j][l] + m[2][j][l] * m[2][j][l])
        });
    }
    s
}

/// Forces of the Neo-Hookean elements `es` (full dofs, element-major 12 per lane), or the
/// lowest-indexed inverted element's error, as [`super::forces::element_internal`] gives them
/// (with a creep branch's step history `branch`, as the element-by-element assembly does).
pub(crate) fn element_forces(
    model: &Model,
    mat: &Material,
    branch: Option<&StepBranch>,
    es: [usize; LANES],
    x: &[f64],
    v: &[f64],
) -> Result<[[f64; 12]; LANES], MotionError> {
    let rest: [&RestTet; LANES] = es.map(|e| &model.rest[e]);
    let tets = es.map(|e| model.tets[e]);
    let node = |y: &[f64]| -> [[L; 3]; 4] {
        std::array::from_fn(|a| std::array::from_fn(|i| lanes(|l| y[3 * tets[l][a] + i])))
    };
    let g: [[L; 3]; 4] =
        std::array::from_fn(|a| std::array::from_fn(|j| lanes(|l| rest[l].grad[a][j])));
    let param = |k: ParamKind| lanes(|l| mat.get(k, es[l]));
    let (lambda, mu, stiffening) = (
        param(ParamKind::Lambda),
        param(ParamKind::Mu),
        param(ParamKind::Stiffening),
    );
    let (nu, h) = (param(ParamKind::Nu), param(ParamKind::PowerH));

    // FParts::new: F⁻ᵀ = cof(F)/J, the cofactor's columns the cross products of F's columns.
    let f = gradient(&node(x), &g);
    let col = |m: &M, j: usize| -> [L; 3] { [m[0][j], m[1][j], m[2][j]] };
    let (c0, c1, c2) = (col(&f, 0), col(&f, 1), col(&f, 2));
    let cof_cols = [cross(&c1, &c2), cross(&c2, &c0), cross(&c0, &c1)];
    let j = lanes(|l| {
        c0[0][l] * cof_cols[0][0][l] + c0[1][l] * cof_cols[0][1][l] + c0[2][l] * cof_cols[0][2][l]
    });
    let f_inv_t: M =
        std::array::from_fn(|r| std::array::from_fn(|c| lanes(|l| cof_cols[c][r][l] / j[l])));
    for l in 0..LANES {
        let finite = f_inv_t.iter().flatten().all(|z| z[l].is_finite());
        if j[l].is_nan() || j[l] <= 0.0 || !finite {
            return Err(MotionError::Inverted { element: es[l] });
        }
    }
    let i1 = norm_squared(&f);

    // pk1: F⁻ᵀ · (½ λ (J² − 1)) + (F − F⁻ᵀ) · μ.
    let vol_coef = lanes(|l| 0.5 * lambda[l] * (j[l] * j[l] - 1.0));
    let mut p: M = std::array::from_fn(|r| {
        std::array::from_fn(|c| {
            lanes(|l| f_inv_t[r][c][l] * vol_coef[l] + (f[r][c][l] - f_inv_t[r][c][l]) * mu[l])
        })
    });
    for l in 0..LANES {
        if stiffening[l] != 0.0 {
            add_stiffening(&mut p, l, &f, &f_inv_t, j[l], i1[l], stiffening[l]);
        }
    }
    if let Some(b) = branch {
        add_branch(&mut p, &f, b, es);
    }

    // The power-law viscous stress (Rate::new, stress): skipped where ‖Ḟ‖ or γ̇ or the
    // viscosity vanish (as `forces::rate` skips it).
    let ld = gradient(&node(v), &g);
    let l_norm = norm_squared(&ld).map(f64::sqrt);
    // E = Ḟ + Ḟᵀ, or under the objective form FᵀḞ + ḞᵀF (Rate::objective).
    let objective = mat.viscous_form == Form::Objective;
    let rate = if objective {
        std::array::from_fn(|r| std::array::from_fn(|c| product(&f, &ld, r, c, true)))
    } else {
        ld
    };
    let e: M = std::array::from_fn(|r| {
        std::array::from_fn(|c| map2(&rate[r][c], &rate[c][r], |a, b| a + b))
    });
    let gamma = norm_squared(&e).map(|s| 0.5f64.sqrt() * s.sqrt());
    for l in 0..LANES {
        if nu[l] == 0.0 || l_norm[l] <= f64::MIN_POSITIVE || gamma[l] <= f64::MIN_POSITIVE {
            continue;
        }
        let power = rate_power(gamma[l], h[l]);
        let s = nu[l] * power;
        if objective {
            // P = F S, S = ν γ̇^(h−1) E, as nalgebra's product sums it.
            for r in 0..3 {
                for c in 0..3 {
                    let fs = (f[r][0][l] * (e[0][c][l] * s) + f[r][1][l] * (e[1][c][l] * s))
                        + f[r][2][l] * (e[2][c][l] * s);
                    p[r][c][l] += fs;
                }
            }
            continue;
        }
        for r in 0..3 {
            for c in 0..3 {
                p[r][c][l] += e[r][c][l] * s;
            }
        }
    }

    // add_stress_forces: f_a = (P ∇φ_a) · (−V), P ∇φ_a as nalgebra's product sums it.
    let minus_v = lanes(|l| -rest[l].volume);
    let mut out = [[0.0; 12]; LANES];
    for a in 0..4 {
        for i in 0..3 {
            let pg = lanes(|l| {
                p[i][0][l] * g[a][0][l] + p[i][1][l] * g[a][1][l] + p[i][2][l] * g[a][2][l]
            });
            for l in 0..LANES {
                out[l][3 * a + i] = pg[l] * minus_v[l];
            }
        }
    }
    Ok(out)
}

/// P of lane `l` += 2c (Ī₁ − 3) ∂Ī₁/∂F, ∂Ī₁/∂F = J^(−2/3) (2F − ⅔ I₁ F⁻ᵀ), as
/// [`super::hyperelastic::pk1`] adds it (only for a lane whose c is not zero).
fn add_stiffening(p: &mut M, l: usize, f: &M, f_inv_t: &M, j: f64, i1: f64, c: f64) {
    let cb = j.cbrt();
    let j23 = 1.0 / (cb * cb);
    let bar = j23 * i1 - 3.0;
    let k = 2.0 * c * bar;
    for r in 0..3 {
        for q in 0..3 {
            let dbar = (f[r][q][l] * 2.0 - f_inv_t[r][q][l] * (2.0 / 3.0 * i1)) * j23;
            p[r][q][l] += dbar * k;
        }
    }
}

/// P ← (1 + g b) P + F C_n per lane, as [`StepBranch::stress`] computes it: the scaled
/// matrix plus nalgebra's product F C, whose entry (r, c) it sums as
/// (F_r0 C_0c + F_r1 C_1c) + F_r2 C_2c.
fn add_branch(p: &mut M, f: &M, b: &StepBranch, es: [usize; LANES]) {
    let scale = lanes(|l| 1.0 + b.gain[es[l]]);
    let c = es.map(|e| &b.c[e]);
    for r in 0..3 {
        for q in 0..3 {
            p[r][q] = lanes(|l| {
                let fc = f[r][0][l] * c[l][(0, q)]
                    + f[r][1][l] * c[l][(1, q)]
                    + f[r][2][l] * c[l][(2, q)];
                p[r][q][l] * scale[l] + fc
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::forces::{assemble, element_internal};
    use super::super::scenario::{bar_model, Gauss};
    use super::*;
    use palpate_fem::mesh::Mesh;

    /// A 2 × 10 × 2 cm bar in 144 elements, at rest.
    fn bar() -> (Mesh, Model) {
        bar_model(
            [0.02, 0.1, 0.02],
            [2, 6, 2],
            1.0 / 180.0,
            1,
            &|_| [0.0; 3],
            &[],
        )
        .unwrap()
    }

    /// The mesh's nodes moved at random by 0.5 mm (no element of [`bar`] inverts).
    fn jiggled(mesh: &Mesh, rng: &mut Gauss) -> Vec<f64> {
        mesh.nodes
            .iter()
            .flatten()
            .map(|&p| p + 5e-4 * rng.next())
            .collect()
    }

    /// An element's forces with the viscous stress always added (`forces::rate` skips it where
    /// the viscosity is 0).
    fn forces_with_every_rate(
        model: &Model,
        mat: &Material,
        e: usize,
        x: &[f64],
        v: &[f64],
    ) -> [f64; 12] {
        use super::super::elastic::ElasticState;
        use super::super::hyperelastic as he;
        use super::super::viscosity as visc;
        let t = &model.rest[e];
        let s =
            ElasticState::new(mat, e, he::deformation_gradient(t, &model.gather(e, x))).unwrap();
        let mut p = s.pk1();
        let l = visc::velocity_gradient(t, &model.gather(e, v));
        let fgrad = he::deformation_gradient(t, &model.gather(e, x));
        if let Some(r) = visc::Rate::of(mat.viscous_form, &fgrad, &l, mat.get(ParamKind::PowerH, e))
        {
            p += visc::stress(&r, mat.get(ParamKind::Nu, e));
        }
        let mut fe = [0.0; 12];
        he::add_stress_forces(t, &p, 1.0, &mut fe);
        fe
    }

    /// A 144-element bar, deformed and moving at random (no element inverted), with per-element
    /// λ, μ, ν, h and a stiffening term on every third element, some elements at rest and every
    /// fifth without viscosity: the lanes' forces equal the element-by-element ones to the last
    /// bit, one by one and assembled, and skipping the viscous stress where the viscosity is 0
    /// changes no bit either; under both readings of the viscosity.
    #[test]
    fn lane_forces_are_the_element_forces_to_the_last_bit() {
        for form in [Form::RestGradient, Form::Objective] {
            lane_forces_match(form);
        }
    }

    fn lane_forces_match(form: Form) {
        let (mesh, model) = bar();
        let ne = model.tets.len();
        let mut mat = Material::uniform(ne, 3e5, 2e4, 15.0, 0.8, 1100.0);
        mat.viscous_form = form;
        for e in 0..ne {
            let s = 1.0 + 0.01 * e as f64;
            mat.values[ParamKind::Lambda as usize][e] *= s;
            mat.values[ParamKind::Mu as usize][e] /= s;
            mat.values[ParamKind::Nu as usize][e] *= if e % 5 == 0 { 0.0 } else { s };
            mat.values[ParamKind::PowerH as usize][e] = if e % 2 == 0 { 1.0 } else { 0.8 };
            mat.values[ParamKind::Stiffening as usize][e] = if e % 3 == 0 { 4e4 } else { 0.0 };
        }
        let mut rng = Gauss::new(7);
        let x = jiggled(&mesh, &mut rng);
        // Nodes with y < 2 cm at rest: the elements there have no viscous stress.
        let v: Vec<f64> = mesh
            .nodes
            .iter()
            .flat_map(|p| {
                let moving = p[1] >= 0.02;
                [0; 3].map(|_| if moving { 0.05 * rng.next() } else { 0.0 })
            })
            .collect();
        let mut reference = vec![0.0; x.len()];
        let mut at_rest = 0;
        for e in 0..ne {
            let fe = element_internal(&model, &mat, e, &x, &v).unwrap();
            let every_rate = forces_with_every_rate(&model, &mat, e, &x, &v);
            assert!(
                fe.iter()
                    .zip(&every_rate)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "element {e}"
            );
            for a in 0..4 {
                for i in 0..3 {
                    reference[3 * model.tets[e][a] + i] += fe[3 * a + i];
                }
            }
            if model.tets[e].iter().all(|&n| mesh.nodes[n][1] < 0.02) {
                at_rest += 1;
            }
            if e % LANES == 0 && e + LANES <= ne {
                let lanes =
                    element_forces(&model, &mat, None, [e, e + 1, e + 2, e + 3], &x, &v).unwrap();
                for (l, got) in lanes.iter().enumerate() {
                    let want = element_internal(&model, &mat, e + l, &x, &v).unwrap();
                    assert_eq!(got, &want, "{form:?}: element {}", e + l);
                }
            }
        }
        assert!(
            at_rest > 0 && at_rest < ne,
            "{at_rest} of {ne} elements at rest"
        );
        let mut f = vec![0.0; x.len()];
        assemble(&model, &mat, &x, &v, &mut f, None, None).unwrap();
        assert!(f
            .iter()
            .zip(&reference)
            .all(|(a, b)| a.to_bits() == b.to_bits()));
    }

    /// With a creep branch (per-element gain g b and history C_n, as after some steps) on a bar
    /// whose element count leaves a remainder past the last group of four, the forces-only pass
    /// (lanes, then the remainder one by one) equals the element-by-element assembly to the last
    /// bit, and each lane equals (1 + g b) P⁰ + F C_n plus the viscous stress mapped to forces;
    /// under both readings of the viscosity.
    #[test]
    fn lane_forces_with_a_creep_branch_are_the_element_forces_to_the_last_bit() {
        for form in [Form::RestGradient, Form::Objective] {
            lane_forces_with_branch_match(form);
        }
    }

    fn lane_forces_with_branch_match(form: Form) {
        use super::super::elastic::ElasticState;
        use super::super::forces::assemble_relaxing;
        use super::super::hyperelastic as he;
        use super::super::viscosity as visc;
        use nalgebra::Matrix3;
        let (mesh, model) = bar_model(
            [0.02, 0.1, 0.02],
            [3, 5, 1],
            1.0 / 180.0,
            1,
            &|_| [0.0; 3],
            &[],
        )
        .unwrap();
        let ne = model.tets.len();
        assert_ne!(ne % LANES, 0, "{ne} elements leave no remainder");
        let mut mat = Material::uniform(ne, 3e5, 2e4, 15.0, 0.8, 1100.0);
        for e in 0..ne {
            mat.values[ParamKind::Nu as usize][e] *= if e % 5 == 0 { 0.0 } else { 1.0 };
            mat.values[ParamKind::Stiffening as usize][e] = if e % 3 == 0 { 4e4 } else { 0.0 };
        }
        mat.viscous_form = form;
        let mut rng = Gauss::new(13);
        let x = jiggled(&mesh, &mut rng);
        let v: Vec<f64> = x.iter().map(|_| 0.05 * rng.next()).collect();
        // C_n of the size of the stresses here (kPa), symmetric as the branch's is.
        let branch = StepBranch {
            c: (0..ne)
                .map(|_| {
                    let m = Matrix3::from_fn(|_, _| 2e3 * rng.next());
                    m + m.transpose()
                })
                .collect(),
            gain: (0..ne).map(|_| 0.3 * rng.next().abs()).collect(),
        };
        for e in (0..ne - ne % LANES).step_by(LANES) {
            let es = [e, e + 1, e + 2, e + 3];
            let got = element_forces(&model, &mat, Some(&branch), es, &x, &v).unwrap();
            for (l, got) in got.iter().enumerate() {
                let e = es[l];
                let t = &model.rest[e];
                let fgrad = he::deformation_gradient(t, &model.gather(e, &x));
                let s = ElasticState::new(&mat, e, fgrad).unwrap();
                let mut p = branch.stress(e, &fgrad, &s.pk1());
                let rate = visc::Rate::of(
                    form,
                    &fgrad,
                    &visc::velocity_gradient(t, &model.gather(e, &v)),
                    mat.get(ParamKind::PowerH, e),
                );
                if let (Some(r), true) = (rate, mat.get(ParamKind::Nu, e) != 0.0) {
                    p += visc::stress(&r, mat.get(ParamKind::Nu, e));
                }
                let mut want = [0.0; 12];
                he::add_stress_forces(t, &p, 1.0, &mut want);
                assert_eq!(got, &want, "{form:?}: element {e}");
            }
        }
        // The element-by-element loop (it runs when K is asked for) against the forces-only pass.
        let (mut by_element, mut fast) = (vec![0.0; x.len()], vec![0.0; x.len()]);
        let mut k = vec![0.0; model.pattern.nnz()];
        assemble_relaxing(
            &model,
            &mat,
            &x,
            &v,
            Some(&branch),
            &mut by_element,
            Some(&mut k),
            None,
        )
        .unwrap();
        assemble_relaxing(&model, &mat, &x, &v, Some(&branch), &mut fast, None, None).unwrap();
        assert!(fast
            .iter()
            .zip(&by_element)
            .all(|(a, b)| a.to_bits() == b.to_bits()));
        // The branch is in them: without it the forces differ.
        let mut plain = vec![0.0; x.len()];
        assemble(&model, &mat, &x, &v, &mut plain, None, None).unwrap();
        assert!(plain.iter().zip(&fast).any(|(a, b)| a != b));
    }

    /// Without viscosity the damping tangent D is zero, as it was when it was assembled from
    /// the zero viscosity, and K is the same to the last bit as with a viscosity.
    #[test]
    fn no_viscosity_assembles_no_damping_tangent() {
        let (mesh, model) = bar();
        let ne = model.tets.len();
        let mut rng = Gauss::new(11);
        let x = jiggled(&mesh, &mut rng);
        let v: Vec<f64> = x.iter().map(|_| 0.05 * rng.next()).collect();
        let nnz = model.pattern.nnz();
        let tangents = |nu: f64| {
            let mat = Material::uniform(ne, 3e5, 2e4, nu, 0.8, 1100.0);
            let (mut f, mut k, mut d) = (vec![0.0; x.len()], vec![0.0; nnz], vec![0.0; nnz]);
            assemble(&model, &mat, &x, &v, &mut f, Some(&mut k), Some(&mut d)).unwrap();
            (k, d)
        };
        let (k0, d0) = tangents(0.0);
        let (k1, d1) = tangents(15.0);
        assert!(d0.iter().all(|&z| z == 0.0));
        assert!(d1.iter().any(|&z| z != 0.0));
        assert!(k0.iter().zip(&k1).all(|(a, b)| a.to_bits() == b.to_bits()));
    }

    /// An inverted element is named as the element-by-element pass names it: the lowest index.
    #[test]
    fn lanes_name_the_first_inverted_element() {
        let (mesh, model) = bar();
        let mat = Material::uniform(model.tets.len(), 3e5, 2e4, 15.0, 1.0, 1100.0);
        let mut x: Vec<f64> = mesh.nodes.iter().flatten().copied().collect();
        let v = vec![0.0; x.len()];
        // Push the last node of element 6 through its opposite face (inverts 6 and others).
        let n = model.tets[6][3];
        let centroid: Vec<f64> = (0..3)
            .map(|i| {
                model.tets[6][..3]
                    .iter()
                    .map(|&m| x[3 * m + i])
                    .sum::<f64>()
                    / 3.0
            })
            .collect();
        for i in 0..3 {
            x[3 * n + i] = 2.0 * centroid[i] - x[3 * n + i];
        }
        let first = (0..model.tets.len())
            .find(|&e| element_internal(&model, &mat, e, &x, &v).is_err())
            .unwrap();
        let mut f = vec![0.0; x.len()];
        match assemble(&model, &mat, &x, &v, &mut f, None, None) {
            Err(MotionError::Inverted { element }) => assert_eq!(element, first),
            other => panic!("expected element {first} inverted, got {other:?}"),
        }
    }
}
