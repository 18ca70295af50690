//! The objective: the marker term of eq. 15 and its force analogue, per time step, with the
//! partial derivatives ∂φ/∂x, ∂φ/∂v and ∂φ/∂q the gradient methods need.
//!
//! Φ = Σ_n Δt [ w_m ½ Σ_i ‖x̄_i(x^n) − x_i*(t_n)‖² + w_f ½ Σ_c ‖F_c(x^n, v^n) − F_c*(t_n)‖² ],
//! the rectangle-rule discretisation of eq. 15's time integral. F_c = −Σ_{a ∈ clamp c} f_a is the
//! force the clamp exerts on the body through its nodes' internal (elastic + viscous) forces: what
//! a load cell in the clamp reads, without the clamp nodes' own weight and inertia (tared).

use super::elastic::ElasticState;
use super::forces::param_derivatives;
use super::hyperelastic as he;
use super::model::{Material, Model, Observations, ParamKind};
use super::viscosity as visc;
use super::MotionError;

/// One step's objective contribution and partial derivatives.
#[derive(Debug, Clone, Default)]
pub struct StepTerm {
    /// φ_n Δt.
    pub phi: f64,
    /// Σ‖x̄ − x*‖² over observed markers.
    pub marker_sq: f64,
    /// Number of observed markers.
    pub marker_count: usize,
    /// Σ‖F − F*‖² over observed clamp forces.
    pub force_sq: f64,
    /// Number of observed clamp forces.
    pub force_count: usize,
}

/// Reaction force F_c of clamp `c` at state (x, v).
pub fn clamp_force(
    model: &Model,
    mat: &Material,
    c: usize,
    x: &[f64],
    v: &[f64],
) -> Result<[f64; 3], MotionError> {
    let mut out = [0.0; 3];
    for &e in &model.clamp_elems[c] {
        let fe = super::forces::element_internal(model, mat, e, x, v)?;
        for (a, &node) in model.tets[e].iter().enumerate() {
            if model.node_clamp[node] == c {
                for i in 0..3 {
                    out[i] -= fe[3 * a + i];
                }
            }
        }
    }
    Ok(out)
}

/// The derivatives of clamp `c`'s reaction force F_c at (x, v), for the objective's gradient and
/// the Gauss–Newton matrix alike: `dx(i, fr, k, d)` for every component i of F_c and free dof fr,
/// with k = ∂F_c,i/∂x_fr and d = ∂F_c,i/∂v_fr (the element tangents K_e and D_e on the clamp's
/// rows); `dq(el, slot, i, g)` with g = ∂F_c,i/∂q of element `el`'s derivative slot, for the
/// slots set in `kinds` (density excluded: F_c holds internal forces only).
#[allow(clippy::too_many_arguments)]
pub fn clamp_force_derivatives(
    model: &Model,
    mat: &Material,
    kinds: &[bool],
    c: usize,
    x: &[f64],
    v: &[f64],
    mut dx: impl FnMut(usize, usize, f64, f64),
    mut dq: impl FnMut(usize, usize, usize, f64),
) -> Result<(), MotionError> {
    for &el in &model.clamp_elems[c] {
        let tet = model.tets[el];
        let rt = &model.rest[el];
        let fgrad = he::deformation_gradient(rt, &model.gather(el, x));
        let s = ElasticState::new(mat, el, fgrad)?;
        let mut ke = s.tangent(rt);
        let nu = mat.get(ParamKind::Nu, el);
        let rate = visc::Rate::of(
            mat.viscous_form,
            &fgrad,
            &visc::velocity_gradient(rt, &model.gather(el, v)),
            mat.get(ParamKind::PowerH, el),
        );
        if let Some(kv) = rate
            .as_ref()
            .and_then(|r| visc::element_stiffness(rt, r, nu))
        {
            super::forces::add_to(&mut ke, &kv);
        }
        let de = rate.map(|r| visc::element_damping(rt, &r, nu));
        for a in 0..4 {
            if model.node_clamp[tet[a]] != c {
                continue;
            }
            for col in 0..12 {
                let fr = model.free[3 * tet[col / 3] + col % 3];
                if fr == usize::MAX {
                    continue;
                }
                for i in 0..3 {
                    dx(
                        i,
                        fr,
                        ke[3 * a + i][col],
                        de.as_ref().map_or(0.0, |d| d[3 * a + i][col]),
                    );
                }
            }
        }
    }
    let mut k2 = kinds.to_vec();
    // F_c holds internal forces only: the weight's parameters do not reach it directly.
    k2[ParamKind::Density as usize] = false;
    for k in ParamKind::GRAVITY {
        k2[k as usize] = false;
    }
    param_derivatives(
        model,
        mat,
        &k2,
        x,
        v,
        None,
        model.clamp_elems[c].iter().copied(),
        |el, kind, g| {
            let tet = model.tets[el];
            for a in 0..4 {
                if model.node_clamp[tet[a]] == c {
                    for i in 0..3 {
                        dq(el, kind, i, -g[3 * a + i]);
                    }
                }
            }
        },
    )
}

/// Evaluates step `n` (1-based). With `grad = Some((gx, gv, acc))` it adds ∂(φΔt)/∂x and ∂/∂v
/// (free dofs) and ∂/∂(per-element slot) into `acc[slot][e]` for slots set in `kinds` (see
/// [`super::model::Param::slot`]).
#[allow(clippy::type_complexity)]
pub fn step_term(
    model: &Model,
    mat: &Material,
    obs: &Observations,
    n: usize,
    x: &[f64],
    v: &[f64],
    kinds: &[bool],
    grad: Option<(&mut [f64], &mut [f64], &mut [Vec<f64>])>,
) -> Result<StepTerm, MotionError> {
    // Each observation weighs the capture interval, however finely the motion is integrated.
    let dt = model.observation_interval();
    let mut term = StepTerm::default();
    let mut grad = grad;
    if let Some(row) = obs.markers.get(n - 1) {
        for (i, target) in row.iter().enumerate() {
            let Some(t) = target else { continue };
            let m = &model.markers[i];
            let p = model.marker_position(m, x);
            let e = [p[0] - t[0], p[1] - t[1], p[2] - t[2]];
            let sq = e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
            term.marker_sq += sq;
            term.marker_count += 1;
            term.phi += 0.5 * obs.marker_weight * dt * sq;
            if let Some((gx, _, _)) = grad.as_mut() {
                for &(node, w) in &m.weights {
                    for k in 0..3 {
                        let fr = model.free[3 * node + k];
                        if fr != usize::MAX {
                            gx[fr] += obs.marker_weight * dt * e[k] * w;
                        }
                    }
                }
            }
        }
    }
    if let Some(row) = obs.forces.get(n - 1) {
        for (c, target) in row.iter().enumerate() {
            let Some(t) = target else { continue };
            let fc = clamp_force(model, mat, c, x, v)?;
            let e = [fc[0] - t[0], fc[1] - t[1], fc[2] - t[2]];
            let sq = e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
            term.force_sq += sq;
            term.force_count += 1;
            term.phi += 0.5 * obs.force_weight * dt * sq;
            let Some((gx, gv, acc)) = grad.as_mut() else {
                continue;
            };
            let w = obs.force_weight * dt;
            clamp_force_derivatives(
                model,
                mat,
                kinds,
                c,
                x,
                v,
                |i, fr, k, d| {
                    gx[fr] += w * e[i] * k;
                    gv[fr] += w * e[i] * d;
                },
                |el, kind, i, g| acc[kind][el] += w * e[i] * g,
            )?;
        }
    }
    Ok(term)
}
