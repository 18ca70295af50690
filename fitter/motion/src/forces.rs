//! Global internal forces f(x, v) (eqs. 16–17), their tangents K = −∂f/∂x and D = −∂f/∂v on the
//! free pattern, and the parameter derivatives ∂F/∂q of the step residual's force terms.

use super::elastic::ElasticState;
use super::force_lanes;
use super::hyperelastic::{self as he, FParts};
use super::model::{Material, Model, ParamKind, MATERIAL_KINDS};
use super::relaxation::StepBranch;
use super::spline::{Response, SplineMaterial};
use super::viscosity as visc;
use super::MotionError;

/// What to assemble besides the force vector.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Want {
    /// Assemble K.
    pub k: bool,
    /// Assemble D.
    pub d: bool,
}

/// Internal forces of element `e` (elastic + viscous), or an inverted-element error.
pub fn element_internal(
    model: &Model,
    mat: &Material,
    e: usize,
    x: &[f64],
    v: &[f64],
) -> Result<[f64; 12], MotionError> {
    element_internal_relaxing(model, mat, None, e, x, v)
}

/// [`element_internal`] with a creep branch's step history (the elastic stress becomes
/// [`StepBranch::stress`]); `None` is [`element_internal`] itself.
fn element_internal_relaxing(
    model: &Model,
    mat: &Material,
    branch: Option<&StepBranch>,
    e: usize,
    x: &[f64],
    v: &[f64],
) -> Result<[f64; 12], MotionError> {
    let t = &model.rest[e];
    let fgrad = he::deformation_gradient(t, &model.gather(e, x));
    let s = ElasticState::new(mat, e, fgrad)?;
    // Both stresses act through the same rest gradients: summed first, mapped to forces once.
    let mut p = s.pk1();
    if let Some(b) = branch {
        p = b.stress(e, &fgrad, &p);
    }
    if let Some(r) = rate(model, mat, e, &fgrad, v) {
        p += visc::stress(&r, mat.get(ParamKind::Nu, e));
    }
    let mut fe = [0.0; 12];
    he::add_stress_forces(t, &p, 1.0, &mut fe);
    Ok(fe)
}

/// The strain rate of element `e`'s viscous stress, `None` where there is none: no rate (a rest
/// or rigidly turning element), or no viscosity. The models without damping (viscosity held at
/// 0: a diagnosis' simplest model and its first candidates) skip the rate, the stress and the
/// damping tangent, which were zeros: the same forces and tangents to the last bit
/// (`lane_forces_are_the_element_forces_to_the_last_bit`), and about a tenth less time in those
/// simulations (BENCHMARKS.md).
pub(crate) fn rate(
    model: &Model,
    mat: &Material,
    e: usize,
    fgrad: &nalgebra::Matrix3<f64>,
    v: &[f64],
) -> Option<visc::Rate> {
    let nu = mat.get(ParamKind::Nu, e);
    if nu == 0.0 {
        return None;
    }
    let l = visc::velocity_gradient(&model.rest[e], &model.gather(e, v));
    visc::Rate::of(mat.viscous_form, fgrad, &l, mat.get(ParamKind::PowerH, e))
}

/// The antisymmetric part A = ½(K_v − K_vᵀ) of the objective viscosity's position tangent
/// K_v = −∂f_v/∂x at one state ([`visc::element_stiffness`]): the part a symmetric system matrix
/// cannot hold, assembled once on the model's pattern so that the iterations of a step's solve
/// apply it without evaluating it again.
pub struct ViscousSkew {
    values: Vec<f64>,
}

impl ViscousSkew {
    /// A at (x, v); `None` under the rest-gradient form (its viscous force does not depend on
    /// the positions) or where no element has a rate.
    pub fn at(
        model: &Model,
        mat: &Material,
        x: &[f64],
        v: &[f64],
    ) -> Result<Option<Self>, MotionError> {
        if mat.viscous_form != visc::Form::Objective {
            return Ok(None);
        }
        let mut values = vec![0.0; model.pattern.nnz()];
        let mut any = false;
        for e in 0..model.tets.len() {
            let t = &model.rest[e];
            let fgrad = he::deformation_gradient(t, &model.gather(e, x));
            let Some(r) = rate(model, mat, e, &fgrad, v) else {
                continue;
            };
            let Some(k) = visc::element_stiffness(t, &r, mat.get(ParamKind::Nu, e)) else {
                continue;
            };
            let tet = &model.tets[e];
            let free: [usize; 12] = std::array::from_fn(|l| model.free[3 * tet[l / 3] + l % 3]);
            let skew = std::array::from_fn(|a| std::array::from_fn(|b| 0.5 * (k[a][b] - k[b][a])));
            model.pattern.add_element_skew(e, &free, &skew, &mut values);
            any = true;
        }
        if values.iter().any(|z| !z.is_finite()) {
            return Err(MotionError::NonFinite("viscous position tangent".into()));
        }
        Ok(any.then_some(Self { values }))
    }

    /// Y += `scale` A X over `np` columns of the free dofs (stored column after column).
    pub fn mul_add(&self, model: &Model, xs: &[f64], np: usize, scale: f64, y: &mut [f64]) {
        model.pattern.mul_add_skew(&self.values, xs, y, np, scale);
    }
}

/// Adds the 12 × 12 matrix `b` into `a`.
pub(crate) fn add_to(a: &mut [[f64; 12]; 12], b: &[[f64; 12]; 12]) {
    for (ra, rb) in a.iter_mut().zip(b) {
        for (x, y) in ra.iter_mut().zip(rb) {
            *x += y;
        }
    }
}

/// Meshes with at least this many elements are assembled in two halves, the second into its own
/// buffers and added afterwards, through `rayon::join`: the second half runs on an idle core when
/// there is one (a single run; or the shorter of a fit's runs, which are simulated side by side,
/// has finished) and on the same thread otherwise. The split depends on the mesh only, so a
/// result is the same to the last bit wherever the halves ran. Below it the extra buffers cost
/// more than a second core saves (an element's forces and tangent take about a microsecond).
pub(crate) const SPLIT_ASSEMBLY_ELEMENTS: usize = 500;

/// Assembles f (full dofs, overwritten) and optionally K, D values on the free pattern
/// (overwritten). Fails on an inverted element (the lowest index) or non-finite force.
pub fn assemble(
    model: &Model,
    mat: &Material,
    x: &[f64],
    v: &[f64],
    f: &mut [f64],
    kvals: Option<&mut [f64]>,
    dvals: Option<&mut [f64]>,
) -> Result<(), MotionError> {
    assemble_parts(model, mat, x, v, None, Some(f), kvals, dvals)
}

/// [`assemble`] with a creep branch's history for the step ([`super::relaxation`]): each
/// element's stress is (1 + g b) P⁰ + F C_n and its tangent gains the branch's terms; `None` is
/// [`assemble`] itself.
#[allow(clippy::too_many_arguments)]
pub fn assemble_relaxing(
    model: &Model,
    mat: &Material,
    x: &[f64],
    v: &[f64],
    branch: Option<&StepBranch>,
    f: &mut [f64],
    kvals: Option<&mut [f64]>,
    dvals: Option<&mut [f64]>,
) -> Result<(), MotionError> {
    assemble_parts(model, mat, x, v, branch, Some(f), kvals, dvals)
}

/// Assembles K and D values on the free pattern (overwritten) without the forces: a Newton
/// step that converged with a kept factor already has its forces, and the gradients need the
/// tangents at that state (one force pass of the three a step makes saved).
pub fn assemble_tangents(
    model: &Model,
    mat: &Material,
    x: &[f64],
    v: &[f64],
    branch: Option<&StepBranch>,
    kvals: &mut [f64],
    dvals: &mut [f64],
) -> Result<(), MotionError> {
    assemble_parts(model, mat, x, v, branch, None, Some(kvals), Some(dvals))
}

#[allow(clippy::too_many_arguments)]
fn assemble_parts(
    model: &Model,
    mat: &Material,
    x: &[f64],
    v: &[f64],
    branch: Option<&StepBranch>,
    mut f: Option<&mut [f64]>,
    mut kvals: Option<&mut [f64]>,
    mut dvals: Option<&mut [f64]>,
) -> Result<(), MotionError> {
    let zero = |z: Option<&mut [f64]>| {
        if let Some(z) = z {
            z.iter_mut().for_each(|z| *z = 0.0);
        }
    };
    zero(f.as_deref_mut());
    zero(kvals.as_deref_mut());
    zero(dvals.as_deref_mut());
    let ne = model.tets.len();
    if ne < SPLIT_ASSEMBLY_ELEMENTS {
        assemble_into(
            model,
            mat,
            x,
            v,
            branch,
            0..ne,
            f.as_deref_mut(),
            kvals,
            dvals,
        )?;
    } else {
        let half = ne / 2;
        let (want_k, want_d) = (kvals.is_some(), dvals.is_some());
        let ndof = f.as_deref().map_or(0, <[f64]>::len);
        let second = || -> Result<(Vec<f64>, Vec<f64>, Vec<f64>), MotionError> {
            let nnz = model.pattern.nnz();
            let mut f2 = vec![0.0; ndof];
            let mut k2 = vec![0.0; if want_k { nnz } else { 0 }];
            let mut d2 = vec![0.0; if want_d { nnz } else { 0 }];
            assemble_into(
                model,
                mat,
                x,
                v,
                branch,
                half..ne,
                (ndof > 0).then_some(f2.as_mut_slice()),
                want_k.then_some(k2.as_mut_slice()),
                want_d.then_some(d2.as_mut_slice()),
            )?;
            Ok((f2, k2, d2))
        };
        let (first, second) = rayon::join(
            || {
                assemble_into(
                    model,
                    mat,
                    x,
                    v,
                    branch,
                    0..half,
                    f.as_deref_mut(),
                    kvals.as_deref_mut(),
                    dvals.as_deref_mut(),
                )
            },
            second,
        );
        first?;
        let (f2, k2, d2) = second?;
        let add = |to: &mut [f64], from: &[f64]| to.iter_mut().zip(from).for_each(|(a, b)| *a += b);
        if let Some(f) = f.as_deref_mut() {
            add(f, &f2);
        }
        if let Some(k) = kvals {
            add(k, &k2);
        }
        if let Some(d) = dvals {
            add(d, &d2);
        }
    }
    if f.is_some_and(|f| f.iter().any(|z| !z.is_finite())) {
        return Err(MotionError::NonFinite("internal force".into()));
    }
    Ok(())
}

/// Adds the forces of the elements in `range` into `f` (when asked) and their K, D blocks into
/// `kvals`, `dvals`.
#[allow(clippy::too_many_arguments)]
fn assemble_into(
    model: &Model,
    mat: &Material,
    x: &[f64],
    v: &[f64],
    branch: Option<&StepBranch>,
    range: std::ops::Range<usize>,
    mut f: Option<&mut [f64]>,
    mut kvals: Option<&mut [f64]>,
    mut dvals: Option<&mut [f64]>,
) -> Result<(), MotionError> {
    if let (None, None, None, Some(f)) = (&kvals, &dvals, &mat.spline, f.as_deref_mut()) {
        return forces_in_lanes(model, mat, x, v, branch, range, f);
    }
    for e in range {
        let tet = &model.tets[e];
        let t = &model.rest[e];
        let fgrad = he::deformation_gradient(t, &model.gather(e, x));
        let s = ElasticState::new(mat, e, fgrad)?;
        let nu = mat.get(ParamKind::Nu, e);
        let rate = rate(model, mat, e, &fgrad, v);
        let tangent = || {
            let mut k = match branch {
                Some(b) => b.tangent(e, t, &s.tangent(t)),
                None => s.tangent(t),
            };
            // The objective viscosity's force depends on the positions too.
            if let Some(kv) = rate
                .as_ref()
                .and_then(|r| visc::element_stiffness_symmetric(t, r, nu))
            {
                add_to(&mut k, &kv);
            }
            k
        };
        match (kvals.as_deref_mut(), dvals.as_deref_mut(), &rate) {
            (Some(k), Some(d), Some(r)) => model.pattern.add_element_pair(
                e,
                (&tangent(), k),
                (&visc::element_damping(t, r, nu), d),
            ),
            (k, d, r) => {
                if let Some(k) = k {
                    model.pattern.add_element(e, &tangent(), 1.0, k);
                }
                if let (Some(d), Some(r)) = (d, r) {
                    model
                        .pattern
                        .add_element(e, &visc::element_damping(t, r, nu), 1.0, d);
                }
            }
        }
        let Some(f) = f.as_deref_mut() else {
            continue;
        };
        // Elastic and viscous stresses act through the same rest gradients: summed first, mapped
        // to nodal forces once.
        let mut p = s.pk1();
        if let Some(b) = branch {
            p = b.stress(e, &fgrad, &p);
        }
        if let Some(r) = &rate {
            p += visc::stress(r, nu);
        }
        let mut fe = [0.0; 12];
        he::add_stress_forces(t, &p, 1.0, &mut fe);
        scatter(f, tet, &fe);
    }
    Ok(())
}

/// Adds an element's forces into the full force vector.
fn scatter(f: &mut [f64], tet: &[usize; 4], fe: &[f64; 12]) {
    for a in 0..4 {
        for i in 0..3 {
            f[3 * tet[a] + i] += fe[3 * a + i];
        }
    }
}

/// [`assemble_into`]'s forces-only pass (a Newton iteration with a kept factor, a line search)
/// for Neo-Hookean materials, with or without a creep branch: four elements at a time
/// ([`force_lanes`]), the remainder one by one, added in element order — the same forces to the
/// last bit as the element-by-element loop.
fn forces_in_lanes(
    model: &Model,
    mat: &Material,
    x: &[f64],
    v: &[f64],
    branch: Option<&StepBranch>,
    range: std::ops::Range<usize>,
    f: &mut [f64],
) -> Result<(), MotionError> {
    let mut e = range.start;
    while e + force_lanes::LANES <= range.end {
        let fe = force_lanes::element_forces(model, mat, branch, [e, e + 1, e + 2, e + 3], x, v)?;
        for (l, fe) in fe.iter().enumerate() {
            scatter(f, &model.tets[e + l], fe);
        }
        e += force_lanes::LANES;
    }
    for e in e..range.end {
        let fe = element_internal_relaxing(model, mat, branch, e, x, v)?;
        scatter(f, &model.tets[e], &fe);
    }
    Ok(())
}

/// The hanging weights' part of ∂F/∂q for the gravity's turn ([`ParamKind::GRAVITY`] set in
/// `kinds`): `sink(slot, node, d)` with d = m ∂g/∂q for each node of a hanging mass that turns
/// with gravity ([`Model::turned_weights`]). Nodal, not of an element: the passes that call
/// [`param_derivatives`] add it once beside it.
pub fn weight_derivatives(
    model: &Model,
    mat: &Material,
    kinds: &[bool],
    mut sink: impl FnMut(usize, usize, [f64; 3]),
) {
    for kind in ParamKind::GRAVITY {
        if !kinds[kind as usize] {
            continue;
        }
        let dg = model.gravity_derivative(mat, kind);
        for (node, m) in model.turned_weights() {
            sink(kind as usize, node, dg.map(|d| m * d));
        }
    }
}

/// Calls `sink(e, slot, ∂F_e/∂q_slot)` for every element and every derivative slot with
/// `slots[slot]` set (slots: the material kinds, then the spline control values, see
/// [`super::model::Param::slot`]), where
/// F = f(x, v) + f_ext − c M (v − b) is the force part of the BDF2 residual (eq. 2) and
/// `inertia = Some((c, v − b))` (full dofs) includes the density's mass term; `None` drops it
/// (elastostatic initial condition, eq. 14). `elems` are the elements of the pass, in order (all
/// of them: `0..model.tets.len()`).
pub fn param_derivatives(
    model: &Model,
    mat: &Material,
    kinds: &[bool],
    x: &[f64],
    v: &[f64],
    inertia: Option<(f64, &[f64])>,
    elems: impl IntoIterator<Item = usize>,
    mut sink: impl FnMut(usize, usize, &[f64; 12]),
) -> Result<(), MotionError> {
    let nf = mat.spline.as_ref().map_or(0, |s| s.len(Response::F));
    let any_spline = kinds.iter().skip(MATERIAL_KINDS).any(|&b| b);
    // ∂g/∂q of the gravity's turns, the same in every element ([`Model::gravity_derivative`]).
    let turns = ParamKind::GRAVITY.map(|kind| {
        (
            kind,
            kinds[kind as usize].then(|| model.gravity_derivative(mat, kind)),
        )
    });
    for e in elems {
        let t = &model.rest[e];
        let fgrad = he::deformation_gradient(t, &model.gather(e, x));
        let neo_hookean = [ParamKind::Lambda, ParamKind::Mu, ParamKind::Stiffening];
        if neo_hookean.iter().any(|&k| kinds[k as usize]) {
            let s = FParts::new(fgrad).ok_or(MotionError::Inverted { element: e })?;
            if kinds[ParamKind::Stiffening as usize] {
                let mut g = [0.0; 12];
                he::add_stress_forces(t, &he::pk1_dstiffening(&s), 1.0, &mut g);
                sink(e, ParamKind::Stiffening as usize, &g);
            }
            if kinds[ParamKind::Lambda as usize] {
                let mut g = [0.0; 12];
                he::add_stress_forces(t, &he::pk1_dlambda(&s), 1.0, &mut g);
                sink(e, ParamKind::Lambda as usize, &g);
            }
            if kinds[ParamKind::Mu as usize] {
                let mut g = [0.0; 12];
                he::add_stress_forces(t, &he::pk1_dmu(&s), 1.0, &mut g);
                sink(e, ParamKind::Mu as usize, &g);
            }
        }
        if any_spline {
            if let Some(sp) = &mat.spline {
                let st = sp
                    .state(&fgrad)
                    .ok_or(MotionError::Inverted { element: e })?;
                SplineMaterial::pk1_dcontrols(&st, |r, i, dp| {
                    let slot = match r {
                        Response::F => MATERIAL_KINDS + i,
                        Response::H => MATERIAL_KINDS + nf + i,
                    };
                    if kinds.get(slot).copied().unwrap_or(false) {
                        let mut g = [0.0; 12];
                        he::add_stress_forces(t, dp, 1.0, &mut g);
                        sink(e, slot, &g);
                    }
                });
            }
        }
        if kinds[ParamKind::Nu as usize] || kinds[ParamKind::PowerH as usize] {
            let (nu, h) = (mat.get(ParamKind::Nu, e), mat.get(ParamKind::PowerH, e));
            let fgrad = he::deformation_gradient(t, &model.gather(e, x));
            let r = visc::Rate::of(
                mat.viscous_form,
                &fgrad,
                &visc::velocity_gradient(t, &model.gather(e, v)),
                h,
            );
            if kinds[ParamKind::Nu as usize] {
                let mut g = [0.0; 12];
                if let Some(r) = &r {
                    he::add_stress_forces(t, &visc::stress_dnu(r), 1.0, &mut g);
                }
                sink(e, ParamKind::Nu as usize, &g);
            }
            if kinds[ParamKind::PowerH as usize] {
                let mut g = [0.0; 12];
                if let Some(r) = &r {
                    he::add_stress_forces(t, &visc::stress_dh(r, nu), 1.0, &mut g);
                }
                sink(e, ParamKind::PowerH as usize, &g);
            }
        }
        if kinds[ParamKind::Density as usize] {
            // ∂/∂ρ_e of f_ext − c M (v − b): V g / 4 per node minus c (M_e/ρ_e)(v − b)_e.
            let vol = t.volume;
            let mut g = [0.0; 12];
            for a in 0..4 {
                for i in 0..3 {
                    g[3 * a + i] = vol / 4.0 * model.gravity[i];
                }
            }
            if let Some((c, vb)) = inertia {
                let me = model.element_mass(vol);
                let w = model.gather(e, vb);
                for r in 0..12 {
                    let mut acc = 0.0;
                    for col in 0..12 {
                        acc += me[r][col] * w[col / 3][col % 3];
                    }
                    g[r] -= c * acc;
                }
            }
            sink(e, ParamKind::Density as usize, &g);
        }
        for (kind, dg) in turns {
            if let Some(dg) = dg {
                // ∂/∂q of f_ext: ρ_e V_e/4 ∂g/∂q per node.
                let m = mat.get(ParamKind::Density, e) * t.volume / 4.0;
                let mut g = [0.0; 12];
                for a in 0..4 {
                    for i in 0..3 {
                        g[3 * a + i] = m * dg[i];
                    }
                }
                sink(e, kind as usize, &g);
            }
        }
    }
    Ok(())
}
