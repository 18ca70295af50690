//! Global internal forces f(x, v) (eqs. 16–17), their tangents K = −∂f/∂x and D = −∂f/∂v on the
//! free pattern, and the parameter derivatives ∂F/∂q of the step residual's force terms.

use super::elastic::ElasticState;
use super::hyperelastic::{self as he, FParts};
use super::model::{Material, Model, ParamKind};
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
    let t = &model.rest[e];
    let s = ElasticState::new(mat, e, he::deformation_gradient(t, &model.gather(e, x)))?;
    let mut fe = [0.0; 12];
    he::add_stress_forces(t, &s.pk1(), 1.0, &mut fe);
    if let Some(r) = visc::Rate::new(&visc::velocity_gradient(t, &model.gather(e, v))) {
        let sig = visc::stress(&r, mat.get(ParamKind::Nu, e), mat.get(ParamKind::PowerH, e));
        he::add_stress_forces(t, &sig, 1.0, &mut fe);
    }
    Ok(fe)
}

/// Assembles f (full dofs, overwritten) and optionally K, D values on the free pattern
/// (overwritten). Fails on an inverted element or non-finite force.
pub fn assemble(
    model: &Model,
    mat: &Material,
    x: &[f64],
    v: &[f64],
    f: &mut [f64],
    mut kvals: Option<&mut [f64]>,
    mut dvals: Option<&mut [f64]>,
) -> Result<(), MotionError> {
    f.iter_mut().for_each(|z| *z = 0.0);
    if let Some(k) = kvals.as_deref_mut() {
        k.iter_mut().for_each(|z| *z = 0.0);
    }
    if let Some(d) = dvals.as_deref_mut() {
        d.iter_mut().for_each(|z| *z = 0.0);
    }
    for (e, tet) in model.tets.iter().enumerate() {
        let t = &model.rest[e];
        let s = ElasticState::new(mat, e, he::deformation_gradient(t, &model.gather(e, x)))?;
        let mut fe = [0.0; 12];
        he::add_stress_forces(t, &s.pk1(), 1.0, &mut fe);
        if let Some(k) = kvals.as_deref_mut() {
            model.pattern.add_element(e, &s.tangent(t), 1.0, k);
        }
        if let Some(r) = visc::Rate::new(&visc::velocity_gradient(t, &model.gather(e, v))) {
            let (nu, h) = (mat.get(ParamKind::Nu, e), mat.get(ParamKind::PowerH, e));
            he::add_stress_forces(t, &visc::stress(&r, nu, h), 1.0, &mut fe);
            if let Some(d) = dvals.as_deref_mut() {
                model
                    .pattern
                    .add_element(e, &visc::element_damping(t, &r, nu, h), 1.0, d);
            }
        }
        for a in 0..4 {
            for i in 0..3 {
                f[3 * tet[a] + i] += fe[3 * a + i];
            }
        }
    }
    if f.iter().any(|z| !z.is_finite()) {
        return Err(MotionError::NonFinite("internal force".into()));
    }
    Ok(())
}

/// Calls `sink(e, slot, ∂F_e/∂q_slot)` for every element and every derivative slot with
/// `slots[slot]` set (slots: the five material kinds, then the spline control values, see
/// [`super::model::Param::slot`]), where
/// F = f(x, v) + f_ext − c M (v − b) is the force part of the BDF2 residual (eq. 2) and
/// `inertia = Some((c, v − b))` (full dofs) includes the density's mass term; `None` drops it
/// (elastostatic initial condition, eq. 14). `elems` restricts the pass to some elements.
pub fn param_derivatives(
    model: &Model,
    mat: &Material,
    kinds: &[bool],
    x: &[f64],
    v: &[f64],
    inertia: Option<(f64, &[f64])>,
    elems: Option<&[usize]>,
    mut sink: impl FnMut(usize, usize, &[f64; 12]),
) -> Result<(), MotionError> {
    let nf = mat.spline.as_ref().map_or(0, |s| s.len(Response::F));
    let any_spline = kinds.iter().skip(5).any(|&b| b);
    let all: Vec<usize>;
    let list = match elems {
        Some(l) => l,
        None => {
            all = (0..model.tets.len()).collect();
            &all
        }
    };
    for &e in list {
        let t = &model.rest[e];
        let fgrad = he::deformation_gradient(t, &model.gather(e, x));
        if kinds[ParamKind::Lambda as usize] || kinds[ParamKind::Mu as usize] {
            let s = FParts::new(fgrad).ok_or(MotionError::Inverted { element: e })?;
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
                        Response::F => 5 + i,
                        Response::H => 5 + nf + i,
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
            let r = visc::Rate::new(&visc::velocity_gradient(t, &model.gather(e, v)));
            let (nu, h) = (mat.get(ParamKind::Nu, e), mat.get(ParamKind::PowerH, e));
            if kinds[ParamKind::Nu as usize] {
                let mut g = [0.0; 12];
                if let Some(r) = &r {
                    he::add_stress_forces(t, &visc::stress_dnu(r, h), 1.0, &mut g);
                }
                sink(e, ParamKind::Nu as usize, &g);
            }
            if kinds[ParamKind::PowerH as usize] {
                let mut g = [0.0; 12];
                if let Some(r) = &r {
                    he::add_stress_forces(t, &visc::stress_dh(r, nu, h), 1.0, &mut g);
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
    }
    Ok(())
}
