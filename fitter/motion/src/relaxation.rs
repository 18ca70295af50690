//! Creep: one branch of a generalised-Maxwell (Prony) series on the elastic stress, as in linear
//! viscoelasticity at finite strain (Simo 1987; Simo & Hughes, *Computational Inelasticity*,
//! §10.3).
//!
//! **What it models.** The elastic law (Neo-Hookean or the splines) is the *long-term*, relaxed
//! response: what a static fit measures and where a body comes to rest. On top of it one branch
//! with relaxed fraction g ([`ParamKind::CreepFraction`]) and time τ
//! ([`ParamKind::CreepTime`]) makes the short-time stress (1 + g) times the law's, decaying
//! towards the law's own in τ: a load applied suddenly first meets the stiffer (1 + g) body and
//! the body then creeps on (for a small strain the standard linear solid, creep time
//! τ_c = (1 + g) τ). The static start is fully relaxed (internal variable 0).
//!
//! **Formulation (Simo's, on the second Piola–Kirchhoff stress).** Per element an internal
//! stress H (symmetric, in the reference configuration) with the exact exponential update over
//! a step of Δt (Simo & Hughes eq. 10.3.13, midpoint for the change of the elastic stress):
//!
//! H_{n+1} = a H_n + g b (S⁰_{n+1} − S⁰_n),   a = e^{−Δt/τ}, b = e^{−Δt/(2τ)},
//!
//! with S⁰ = F⁻¹P⁰ the elastic law's second Piola–Kirchhoff stress, and the total first
//! Piola–Kirchhoff stress P = P⁰ + F H. The reference-configuration form is frame-indifferent:
//! a rigid rotation changes F but neither S⁰ nor H, so a cantilever that swings through an
//! angle keeps its creep stress with it. (A branch on the nodal forces, the simpler choice,
//! would keep world-frame forces while the element turns: spurious forces ∝ g θ.)
//!
//! Within step n+1 everything of step n is fixed, so with C_n = a H_n − g b S⁰_n
//! ([`StepBranch`]) the step's stress is P = (1 + g b) P⁰(F) + F C_n: the elastic forces scaled
//! by 1 + g b plus a term linear in the positions, and the step's tangent is
//! K = (1 + g b) K⁰ + V (∇φ_a · C_n ∇φ_b) I₃ (symmetric: C_n is). The step remains the minimum
//! of an incremental potential, so the Newton line search holds as it is.
//!
//! **Under every scheme.** The branch lives where the scheme evaluates its forces: S⁰_n and H_n
//! are taken at step n's force state x_f (BDF2: x^n; the midpoint rule: x^{n−½};
//! generalised-α: Σ β_j x^{n−2+j}, [`super::timestep::TwoStep`]), not at the end of the step.
//! Those states are Δt apart in time like the steps, so the update above is the same
//! exponential midpoint rule on the same convolution H(t) = ∫ g e^{−(t−s)/τ} dS⁰/ds ds, second
//! order, and the step's stress (1 + g b) P⁰(F(x_f)) + F(x_f) C_n is the total stress at the
//! time the scheme's forces stand for: the scheme stays second order. Taking S⁰ at x^n instead
//! would mix two times in one update (x^n is half a step after the midpoint force state, and
//! on a stiff, barely damped body it alternates about it), an O(Δt) error. With BDF2 x_f = x^n
//! and nothing changes. Cost when absent: none — a material without a relaxed fraction
//! ([`Material::has_creep`]) never builds a [`Relaxation`].

use super::elastic::ElasticState;
use super::hyperelastic::{self as he, FParts, RestTet};
use super::model::{Material, Model, ParamKind};
use super::MotionError;
use nalgebra::Matrix3;

/// a = e^{−Δt/τ} and g b = g e^{−Δt/(2τ)} of one element's branch over a step of `dt`.
pub fn coefficients(g: f64, tau: f64, dt: f64) -> (f64, f64) {
    ((-dt / tau).exp(), g * (-0.5 * dt / tau).exp())
}

/// [`coefficients`] of element `e`'s branch, its g ≥ 0 and τ > 0 checked.
pub fn element_coefficients(mat: &Material, e: usize, dt: f64) -> Result<(f64, f64), MotionError> {
    let (g, tau) = (
        mat.get(ParamKind::CreepFraction, e),
        mat.get(ParamKind::CreepTime, e),
    );
    if !(g >= 0.0 && g.is_finite() && tau > 0.0 && tau.is_finite()) {
        return Err(MotionError::Invalid(format!(
            "element {e}: the creep branch needs a relaxed fraction g ≥ 0 and a time τ > 0 (s), \
             found g = {g}, τ = {tau}"
        )));
    }
    Ok(coefficients(g, tau, dt))
}

/// ∂(a, g b)/∂g and ∂(a, g b)/∂τ (see [`coefficients`]).
pub fn coefficient_derivatives(g: f64, tau: f64, dt: f64) -> [(f64, f64); 2] {
    let (a, gb) = coefficients(g, tau, dt);
    let b = (-0.5 * dt / tau).exp();
    let t2 = tau * tau;
    [(0.0, b), (a * dt / t2, gb * 0.5 * dt / t2)]
}

/// What step n+1 takes from the branch's history: per element C_n = a H_n − g b S⁰_n and the
/// gain g b (the step's stress is (1 + g b) P⁰ + F C_n).
#[derive(Debug, Clone, PartialEq)]
pub struct StepBranch {
    /// C_n per element.
    pub c: Vec<Matrix3<f64>>,
    /// g b per element.
    pub gain: Vec<f64>,
}

impl StepBranch {
    /// Element `e`'s total first Piola–Kirchhoff stress from its elastic one `p0` at `f`.
    pub fn stress(&self, e: usize, f: &Matrix3<f64>, p0: &Matrix3<f64>) -> Matrix3<f64> {
        p0 * (1.0 + self.gain[e]) + f * self.c[e]
    }

    /// Element `e`'s tangent from its elastic one `k0`: (1 + g b) K⁰ + V (∇φ_a · C ∇φ_b) I₃.
    pub fn tangent(&self, e: usize, t: &RestTet, k0: &[[f64; 12]; 12]) -> [[f64; 12]; 12] {
        let s = 1.0 + self.gain[e];
        let mut k = k0.map(|row| row.map(|v| v * s));
        let c = &self.c[e];
        for a in 0..4 {
            let ca = c * t.grad[a];
            for b in 0..4 {
                let w = t.volume * t.grad[b].dot(&ca);
                for i in 0..3 {
                    k[3 * a + i][3 * b + i] += w;
                }
            }
        }
        k
    }
}

/// The branch's state after a converged step: H and S⁰ per element, and the coefficients
/// (a, g b) of every step (Δt is the model's).
#[derive(Debug, Clone, PartialEq)]
pub struct Relaxation {
    /// H_n per element.
    pub h: Vec<Matrix3<f64>>,
    /// S⁰_n per element.
    pub s0: Vec<Matrix3<f64>>,
    /// a per element.
    pub decay: Vec<f64>,
    /// g b per element.
    pub gain: Vec<f64>,
}

/// The elastic second Piola–Kirchhoff stress S⁰ = F⁻¹P⁰ of element `e` at positions `x`, with F
/// and its elastic state.
pub fn elastic_pk2<'a>(
    model: &Model,
    mat: &'a Material,
    e: usize,
    x: &[f64],
) -> Result<(Matrix3<f64>, Matrix3<f64>, ElasticState<'a>), MotionError> {
    let (f, s) = elastic_state(model, mat, e, x)?;
    // The Neo-Hookean state holds F⁻ᵀ already.
    let finv = match &s {
        ElasticState::NeoHookean(parts, _) => parts.f_inv_t.transpose(),
        ElasticState::Spline(..) => f
            .try_inverse()
            .ok_or(MotionError::Inverted { element: e })?,
    };
    Ok((finv * s.pk1(), f, s))
}

impl Relaxation {
    /// The fully relaxed branch (H = 0) at the start positions `x0` (the body rests before the
    /// first step, so `x0` is also the force state before it); `None` when the material has no
    /// creep branch.
    pub fn start(model: &Model, mat: &Material, x0: &[f64]) -> Result<Option<Self>, MotionError> {
        if !mat.has_creep() {
            return Ok(None);
        }
        let ne = model.tets.len();
        let mut s0 = Vec::with_capacity(ne);
        let (mut decay, mut gain) = (Vec::with_capacity(ne), Vec::with_capacity(ne));
        for e in 0..ne {
            let (a, gb) = element_coefficients(mat, e, model.dt)?;
            decay.push(a);
            gain.push(gb);
            s0.push(elastic_pk2(model, mat, e, x0)?.0);
        }
        Ok(Some(Self {
            h: vec![Matrix3::zeros(); ne],
            s0,
            decay,
            gain,
        }))
    }

    /// What the next step takes from this state.
    pub fn step_branch(&self) -> StepBranch {
        StepBranch {
            c: (0..self.h.len())
                .map(|e| self.h[e] * self.decay[e] - self.s0[e] * self.gain[e])
                .collect(),
            gain: self.gain.clone(),
        }
    }

    /// The state after the step that took `branch` and converged with the force state at
    /// positions `xf` (the step's x_f, see the module doc): S⁰_{n+1} at `xf`,
    /// H_{n+1} = C_n + g b S⁰_{n+1}.
    pub fn advance(
        &mut self,
        model: &Model,
        mat: &Material,
        branch: &StepBranch,
        xf: &[f64],
    ) -> Result<(), MotionError> {
        for e in 0..self.h.len() {
            let s0 = elastic_pk2(model, mat, e, xf)?.0;
            self.h[e] = branch.c[e] + s0 * self.gain[e];
            self.s0[e] = s0;
        }
        Ok(())
    }
}

/// ∂P⁰/∂q of the Neo-Hookean kinds at a state (λ, μ, stiffening; `None` for the others, and
/// for every kind of the spline material, whose creep sensitivities are not carried).
pub fn pk1_dkind(s: &FParts, kind: ParamKind) -> Option<Matrix3<f64>> {
    match kind {
        ParamKind::Lambda => Some(he::pk1_dlambda(s)),
        ParamKind::Mu => Some(he::pk1_dmu(s)),
        ParamKind::Stiffening => Some(he::pk1_dstiffening(s)),
        _ => None,
    }
}

/// dS⁰ = F⁻¹ (dP⁰ − dF S⁰): the change of the elastic second Piola–Kirchhoff stress for a change
/// dF of the deformation gradient and dP0 = dP⁰\[dF\] + ∂P⁰/∂q dq of the first.
pub fn pk2_change(
    finv: &Matrix3<f64>,
    s0: &Matrix3<f64>,
    df: &Matrix3<f64>,
    dp0: &Matrix3<f64>,
) -> Matrix3<f64> {
    finv * (dp0 - df * s0)
}

/// The direct method's part of the branch ([`super::gradient`]): per element and parameter the
/// total derivatives dH_n/dq and dS⁰_n/dq, carried step to step, and the history term each step's
/// sensitivity system gains.
///
/// Differentiating the step's stress P = (1 + g b) P⁰(F; q) + F C_n at fixed x gives the
/// explicit part g b ∂P⁰/∂q + ∂(g b)/∂q P⁰ + F dC_n/dq, with
/// dC_n/dq = ∂a/∂q H_n + a dH_n/dq − ∂(g b)/∂q S⁰_n − g b dS⁰_n/dq (history: known before the
/// step's solve); the state's part goes through the step's tangent, which already holds the
/// branch. After the solve, dS⁰_{n+1} = F⁻¹(dP⁰ − dF S⁰) with dF from the force state's
/// sensitivity s_xf = s_xa + a_x s_v^{n+1} (the branch lives at the force state; for BDF2 that
/// is s_x^{n+1}), and dH_{n+1} = dC_n + ∂(g b)/∂q S⁰_{n+1} + g b dS⁰_{n+1}.
///
/// What a step asks of every element is computed once per simulation or once per step: the
/// coefficients (a, g b) and their derivatives per parameter hold for the whole simulation (the
/// material and Δt do not change in it), and the elastic state at the step's force state serves
/// both the history term before the solve and the advance after it (F⁻¹ from its own F⁻ᵀ).
pub(crate) struct Sensitivities<'a> {
    /// H_n and S⁰_n per element (the state before the coming step).
    h: Vec<Matrix3<f64>>,
    s0: Vec<Matrix3<f64>>,
    /// dH_n/dq, dS⁰_n/dq per element, then parameter.
    dh: Vec<Vec<Matrix3<f64>>>,
    ds0: Vec<Vec<Matrix3<f64>>>,
    /// dC_n/dq of the step under way.
    dc: Vec<Vec<Matrix3<f64>>>,
    /// a per element, and ∂(a, g b)/∂q per element, then parameter.
    decay: Vec<f64>,
    dcoef: Vec<Vec<(f64, f64)>>,
    /// The elastic state of every element at the step's force state ([`Self::add_history`]'s,
    /// which [`Self::advance`] takes up).
    at_force: Vec<ElasticState<'a>>,
}

/// The kinds whose explicit ∂P⁰/∂q the branch scales.
const ELASTIC_KINDS: [ParamKind; 3] = [ParamKind::Lambda, ParamKind::Mu, ParamKind::Stiffening];

/// dF = Σ_a s_a ∇φ_aᵀ of element `e` for a free-dof sensitivity `sx` (clamped dofs: 0).
fn gradient_change(model: &Model, e: usize, sx: &[f64]) -> Matrix3<f64> {
    let t = &model.rest[e];
    let mut df = Matrix3::zeros();
    for (a, &node) in model.tets[e].iter().enumerate() {
        for i in 0..3 {
            let fr = model.free[3 * node + i];
            if fr != usize::MAX {
                for j in 0..3 {
                    df[(i, j)] += sx[fr] * t.grad[a][j];
                }
            }
        }
    }
    df
}

impl<'a> Sensitivities<'a> {
    /// Refuses what the direct method does not carry through the branch: the spline material.
    pub(crate) fn check(mat: &Material) -> Result<(), MotionError> {
        if mat.spline.is_some() {
            return Err(MotionError::Invalid(
                "the creep branch's sensitivities are carried for the Neo-Hookean material only, \
                 the material here is the spline one"
                    .into(),
            ));
        }
        Ok(())
    }

    /// The fully relaxed start at `x0` with the state sensitivities `sx0` (free dofs, one per
    /// parameter): H = 0, dH = 0, S⁰ and dS⁰ at x⁰.
    pub(crate) fn start(
        model: &Model,
        mat: &'a Material,
        table: &[Vec<usize>],
        x0: &[f64],
        sx0: &[Vec<f64>],
    ) -> Result<Self, MotionError> {
        let ne = model.tets.len();
        let np = sx0.len();
        let mut out = Self {
            h: vec![Matrix3::zeros(); ne],
            s0: Vec::with_capacity(ne),
            dh: vec![vec![Matrix3::zeros(); np]; ne],
            ds0: Vec::with_capacity(ne),
            dc: vec![vec![Matrix3::zeros(); np]; ne],
            decay: Vec::with_capacity(ne),
            dcoef: Vec::with_capacity(ne),
            at_force: Vec::with_capacity(ne),
        };
        for e in 0..ne {
            let (_, st) = elastic_state(model, mat, e, x0)?;
            let (s0, ds0) = Self::pk2_sensitivity(model, table, e, &st, sx0);
            out.s0.push(s0);
            out.ds0.push(ds0);
            out.decay.push(branch_decay(model, mat, e));
            out.dcoef.push(
                (0..np)
                    .map(|p| coefficient_change(model, mat, table, e, p))
                    .collect(),
            );
            out.at_force.push(st);
        }
        Ok(out)
    }

    /// S⁰ of element `e` at the state `st` and its total derivative per parameter along `sx`.
    fn pk2_sensitivity(
        model: &Model,
        table: &[Vec<usize>],
        e: usize,
        st: &ElasticState,
        sx: &[Vec<f64>],
    ) -> (Matrix3<f64>, Vec<Matrix3<f64>>) {
        let parts = neo_hookean(st);
        let finv = parts.f_inv_t.transpose();
        let s0 = finv * st.pk1();
        let ds0 = (0..sx.len())
            .map(|p| {
                let df = gradient_change(model, e, &sx[p]);
                let mut dp0 = st.dpk1(&df);
                for k in ELASTIC_KINDS {
                    if table[e][k as usize] == p {
                        dp0 += pk1_dkind(parts, k).unwrap_or_else(Matrix3::zeros);
                    }
                }
                pk2_change(&finv, &s0, &df, &dp0)
            })
            .collect();
        (s0, ds0)
    }

    /// Adds the branch's explicit part of the step's ∂F/∂q (see the type's doc) at the step's
    /// force state `x` to `rhs` (free dofs, `np` columns one after the other), and keeps
    /// dC_n/dq for [`Self::advance`].
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn add_history(
        &mut self,
        model: &Model,
        mat: &'a Material,
        table: &[Vec<usize>],
        branch: &StepBranch,
        x: &[f64],
        np: usize,
        rhs: &mut [f64],
    ) -> Result<(), MotionError> {
        let nf = model.nfree;
        for e in 0..model.tets.len() {
            let t = &model.rest[e];
            let (f, st) = elastic_state(model, mat, e, x)?;
            self.at_force[e] = st;
            let p0 = st.pk1();
            let (a, gb) = (self.decay[e], branch.gain[e]);
            for p in 0..np {
                let (da, dgb) = self.dcoef[e][p];
                let dc =
                    self.h[e] * da + self.dh[e][p] * a - self.s0[e] * dgb - self.ds0[e][p] * gb;
                self.dc[e][p] = dc;
                let mut stress = f * dc + p0 * dgb;
                if let ElasticState::NeoHookean(parts, _) = &st {
                    for k in ELASTIC_KINDS {
                        if table[e][k as usize] == p {
                            stress += pk1_dkind(parts, k).unwrap_or_else(Matrix3::zeros) * gb;
                        }
                    }
                }
                let mut ge = [0.0; 12];
                he::add_stress_forces(t, &stress, 1.0, &mut ge);
                for (al, &node) in model.tets[e].iter().enumerate() {
                    for i in 0..3 {
                        let fr = model.free[3 * node + i];
                        if fr != usize::MAX {
                            rhs[p * nf + fr] += ge[3 * al + i];
                        }
                    }
                }
            }
        }
        Ok(())
    }

    /// The state after the step: the branch's own `after` (H_{n+1}, S⁰_{n+1}) and the
    /// derivatives from the sensitivities `sxf` of the step's force state (s_xf, free dofs per
    /// parameter). The elastic states at that force state are [`Self::add_history`]'s of the
    /// same step (the state [`Relaxation::advance`] took).
    pub(crate) fn advance(
        &mut self,
        model: &Model,
        table: &[Vec<usize>],
        branch: &StepBranch,
        after: &Relaxation,
        sxf: &[Vec<f64>],
    ) {
        for e in 0..model.tets.len() {
            let (s0, ds0) = Self::pk2_sensitivity(model, table, e, &self.at_force[e], sxf);
            for p in 0..sxf.len() {
                let (_, dgb) = self.dcoef[e][p];
                self.dh[e][p] = self.dc[e][p] + s0 * dgb + ds0[p] * branch.gain[e];
            }
            self.ds0[e] = ds0;
        }
        self.h.clone_from(&after.h);
        self.s0.clone_from(&after.s0);
    }
}

/// The Neo-Hookean parts of a state the branch's sensitivities carry ([`Sensitivities::check`]
/// refuses the spline material before any is made).
fn neo_hookean<'s>(st: &'s ElasticState) -> &'s FParts {
    match st {
        ElasticState::NeoHookean(parts, _) => parts,
        ElasticState::Spline(..) => {
            unreachable!("`Sensitivities::check` refuses the spline material")
        }
    }
}

/// The deformation gradient and elastic state of element `e` at positions `x`.
fn elastic_state<'a>(
    model: &Model,
    mat: &'a Material,
    e: usize,
    x: &[f64],
) -> Result<(Matrix3<f64>, ElasticState<'a>), MotionError> {
    let f = he::deformation_gradient(&model.rest[e], &model.gather(e, x));
    Ok((f, ElasticState::new(mat, e, f)?))
}

/// ∂(a, g b)/∂q_p of element `e`: nonzero for its own creep fraction and time.
fn coefficient_change(
    model: &Model,
    mat: &Material,
    table: &[Vec<usize>],
    e: usize,
    p: usize,
) -> (f64, f64) {
    let d = coefficient_derivatives(
        mat.get(ParamKind::CreepFraction, e),
        mat.get(ParamKind::CreepTime, e),
        model.dt,
    );
    let mut out = (0.0, 0.0);
    for (k, dk) in ParamKind::CREEP.into_iter().zip(d) {
        if table[e][k as usize] == p {
            out.0 += dk.0;
            out.1 += dk.1;
        }
    }
    out
}

/// a = e^{−Δt/τ} of element `e`'s branch.
fn branch_decay(model: &Model, mat: &Material, e: usize) -> f64 {
    coefficients(
        mat.get(ParamKind::CreepFraction, e),
        mat.get(ParamKind::CreepTime, e),
        model.dt,
    )
    .0
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The coefficients' derivatives against central differences (relative step 1e-6; the
    /// functions are smooth exponentials, so 1e-8 relative is far above round-off).
    #[test]
    fn coefficient_derivatives_match_finite_differences() {
        let (g, tau, dt) = (0.3, 0.7, 0.011);
        let d = coefficient_derivatives(g, tau, dt);
        let fd = |f: &dyn Fn(f64) -> (f64, f64), x: f64| {
            let h = 1e-6 * x;
            let (p, m) = (f(x + h), f(x - h));
            ((p.0 - m.0) / (2.0 * h), (p.1 - m.1) / (2.0 * h))
        };
        let dg = fd(&|x| coefficients(x, tau, dt), g);
        let dtau = fd(&|x| coefficients(g, x, dt), tau);
        for (a, b) in [(d[0], dg), (d[1], dtau)] {
            assert!((a.0 - b.0).abs() <= 1e-8 * (1.0 + b.0.abs()), "{a:?} {b:?}");
            assert!((a.1 - b.1).abs() <= 1e-8 * (1.0 + b.1.abs()), "{a:?} {b:?}");
        }
    }

    /// The branch's tangent is −∂f/∂x of its forces −V P ∇φ_a with P = (1 + g b) P⁰ + F C
    /// (central differences, step 1e-7 m on a unit-size tet; 1e-6 relative to the largest
    /// entry covers the differences' truncation error).
    #[test]
    fn branch_tangent_matches_finite_differences() {
        use super::super::hyperelastic::{self as he, HyperParams};
        let (t, mut x) = RestTet::sample();
        // Away from the rest shape, where P⁰ and so the scaled elastic part are not zero.
        x[1].x += 0.001;
        x[2].y -= 0.0007;
        x[3].z += 0.0012;
        let p = HyperParams {
            lambda: 2.0e4,
            mu: 1.0e4,
            stiffening: 0.0,
        };
        let c = Matrix3::new(300.0, 40.0, -20.0, 40.0, -150.0, 60.0, -20.0, 60.0, 90.0);
        let branch = StepBranch {
            c: vec![c],
            gain: vec![0.4],
        };
        let forces = |x: &[nalgebra::Vector3<f64>; 4]| {
            let f = he::deformation_gradient(&t, x);
            let s = FParts::new(f).unwrap();
            let mut out = [0.0; 12];
            he::add_stress_forces(&t, &branch.stress(0, &f, &he::pk1(&s, &p)), 1.0, &mut out);
            out
        };
        let s = FParts::new(he::deformation_gradient(&t, &x)).unwrap();
        let k = branch.tangent(0, &t, &he::element_tangent(&t, &s, &p));
        let scale = k.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
        let h = 1e-7;
        for b in 0..4 {
            for j in 0..3 {
                let (mut xp, mut xm) = (x, x);
                xp[b][j] += h;
                xm[b][j] -= h;
                let (fp, fm) = (forces(&xp), forces(&xm));
                for r in 0..12 {
                    let fd = -(fp[r] - fm[r]) / (2.0 * h);
                    assert!(
                        (k[r][3 * b + j] - fd).abs() <= 1e-6 * scale,
                        "K[{r}][{}] = {} vs {fd}",
                        3 * b + j,
                        k[r][3 * b + j]
                    );
                }
            }
        }
    }
}
