//! Forward simulation: elastostatic start (§3.4) and time steps solved by Newton — BDF2 (eq. 2),
//! the implicit midpoint rule or generalised-α ([`Scheme`]).
//!
//! Unknowns per step are the free velocities v^{n}; positions follow from them:
//! BDF2 x^{n} = (4x^{n−1} − x^{n−2})/3 + (2Δt/3) v^{n}, midpoint x^{n} = x^{n−1} +
//! (Δt/2)(v^{n−1} + v^{n}). Clamped dofs are prescribed: their positions come from the clamp pose
//! and their velocities from BDF2's difference of those positions (second order, and without
//! the step-to-step alternation the trapezoidal velocity rule shows on a noisy capture). Before
//! t = 0 the body rests (v(t ≤ 0) = 0, x^{−1} = x^{0}).

use super::forces::{assemble, assemble_relaxing, assemble_tangents};
use super::model::{Material, Model};
use super::relaxation::{Relaxation, StepBranch};
use super::sparse::{Factor, Pattern};
use super::timestep::{Scheme, TwoStep};
use super::MotionError;
use std::cell::{Cell, RefCell};

/// How a run solves with each converged step's S = c M + a_x K + a_v D (what the gradients
/// need).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum StepSolve {
    /// No solves: the forward run alone.
    #[default]
    None,
    /// Every converged step is factorised afresh at its own state ([`StepView::factor`]).
    Fresh,
    /// Solves by conjugate gradients on the exact S, preconditioned with the factor Newton
    /// kept (from an earlier iteration or step), to the accuracy [`KeptSolve`] asks; S is
    /// factorised afresh when that does not converge (or, by its policy, needed many
    /// iterations), and the fresh factor then preconditions the next steps' solves in its place
    /// ([`StepSolver::refreshed`]).
    Kept(KeptSolve),
}

/// The settings of [`StepSolve::Kept`].
///
/// The gradients' consumers need far less than a direct solve's accuracy: Levenberg–Marquardt
/// evaluates its residual exactly and uses J only for the step, where a relative error ε of J
/// changes the step (and the covariance) by O(ε).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeptSolve {
    /// Relative residual ‖b − S x‖ ≤ tol ‖b‖ (per column) the solves reach.
    pub tolerance: f64,
    /// Preconditioned-CG iterations before S is factorised afresh.
    pub max_iterations: usize,
    /// A solve that converged but needed more than this many iterations also factorises S, so
    /// that the next steps are preconditioned with a factor of their own neighbourhood
    /// (`usize::MAX`: only when CG fails).
    pub refresh_above: usize,
    /// Newton's next step starts from a factor the solves made (S's own at the converged
    /// state, as with [`StepSolve::Fresh`]); otherwise Newton goes on with its own factor and
    /// the forward run is the same to the last bit as without solves.
    pub newton_reuses: bool,
}

impl KeptSolve {
    /// Solves to a relative residual of 10⁻¹⁰ in at most [`KEPT_FACTOR_ITERATIONS`]: far below
    /// the Newton tolerance's effect on the gradients, so they agree with a direct solve to what
    /// finite differences can tell. S is factorised only when CG fails, and Newton keeps its
    /// own factors.
    pub const EXACT: KeptSolve = KeptSolve {
        tolerance: KEPT_FACTOR_TOLERANCE,
        max_iterations: KEPT_FACTOR_ITERATIONS,
        refresh_above: usize::MAX,
        newton_reuses: false,
    };

    /// [`Self::EXACT`] with the relative residual `tolerance`.
    pub fn with_tolerance(tolerance: f64) -> Self {
        Self {
            tolerance,
            ..Self::EXACT
        }
    }
}

/// Preconditioned-CG iterations a kept factor gets before S is factorised afresh: a factor
/// from a nearby state leaves F⁻¹S within a few per cent of I, where each iteration gains two
/// or more digits.
pub const KEPT_FACTOR_ITERATIONS: usize = 6;

/// Relative residual ‖b − S x‖ ≤ tol ‖b‖ (per column) of [`KeptSolve::EXACT`].
pub const KEPT_FACTOR_TOLERANCE: f64 = 1e-10;

/// Solves with a converged step's S (see [`StepSolve`]). Cloning shares the factors.
#[derive(Debug, Clone)]
pub struct StepSolver {
    /// S values at the converged state (free pattern).
    s: Vec<f64>,
    /// The preconditioner the solver was handed.
    handed: Factor,
    factor: RefCell<Factor>,
    /// Whether `factor` is S's own (then one triangular solve is exact).
    exact: Cell<bool>,
    step: usize,
    settings: KeptSolve,
    refactorisations: Cell<usize>,
    cg_iterations: Cell<usize>,
}

impl StepSolver {
    /// When a solve had to factorise S: (the factor it was handed, S's own factor). A later
    /// solver handed the same stale factor should start from the fresh one
    /// ([`Self::precondition_after`]).
    pub fn refreshed(&self) -> Option<(Factor, Factor)> {
        (self.refactorisations.get() > 0)
            .then(|| (self.handed.clone(), self.factor.borrow().clone()))
    }

    /// Takes the fresh factor of an earlier solver's [`Self::refreshed`] as preconditioner when
    /// this solver was handed the same stale one.
    pub fn precondition_after(&self, refresh: &(Factor, Factor)) {
        if !self.exact.get() && self.factor.borrow().shares_values(&refresh.0) {
            *self.factor.borrow_mut() = refresh.1.clone();
        }
    }

    /// The factor the solver was handed (shared with other steps').
    pub fn preconditioner(&self) -> &Factor {
        &self.handed
    }

    /// Numeric factorisations of S these solves made.
    pub fn refactorisations(&self) -> usize {
        self.refactorisations.get()
    }

    /// Preconditioned-CG iterations these solves took.
    pub fn cg_iterations(&self) -> usize {
        self.cg_iterations.get()
    }

    /// Bytes of S's values this solver keeps (the factor is shared with other steps).
    pub fn value_bytes(&self) -> usize {
        8 * self.s.len()
    }

    /// Solves S X = B in place for `m` right-hand sides stored column after column (the
    /// caller's free-dof numbering); `pattern` is the model's, which S's values are on.
    pub fn solve_columns(
        &self,
        pattern: &Pattern,
        b: &mut [f64],
        m: usize,
    ) -> Result<(), MotionError> {
        if m == 0 {
            return Ok(());
        }
        if !self.exact.get() {
            let set = self.settings;
            let (converged, its) = {
                let f = self.factor.borrow();
                pcg_columns(
                    pattern,
                    &self.s,
                    &f,
                    b,
                    m,
                    set.tolerance,
                    set.max_iterations,
                )
            };
            self.cg_iterations.set(self.cg_iterations.get() + its);
            if converged && its <= set.refresh_above {
                return Ok(());
            }
            let fresh = pattern
                .factor(&self.s)
                .ok_or(MotionError::NotPositiveDefinite { step: self.step })?;
            *self.factor.borrow_mut() = fresh;
            self.exact.set(true);
            self.refactorisations.set(self.refactorisations.get() + 1);
            if converged {
                // Solved to the tolerance already; the factor is for the steps after this one.
                return Ok(());
            }
        }
        self.factor.borrow().solve_columns_in_place(b, m);
        Ok(())
    }
}

/// Preconditioned conjugate gradients for S X = B (`m` columns, each with its own step
/// lengths) with `f` ≈ S as preconditioner, from X = 0. On success `b` holds X with
/// ‖B − S X‖ ≤ `tol` ‖B‖ per column (the recurrence's residual) and the result is `(true,
/// iterations)`; otherwise `b` is left as it came.
fn pcg_columns(
    pattern: &Pattern,
    s: &[f64],
    f: &Factor,
    b: &mut [f64],
    m: usize,
    tol: f64,
    max_iter: usize,
) -> (bool, usize) {
    let n = b.len() / m;
    let dot = |a: &[f64], c: &[f64]| a.iter().zip(c).map(|(p, q)| p * q).sum::<f64>();
    let goal: Vec<f64> = b
        .chunks_exact(n)
        .map(|col| tol * dot(col, col).sqrt())
        .collect();
    let mut x = vec![0.0; n * m];
    let mut r = b.to_vec();
    let mut z = r.clone();
    f.solve_columns_in_place(&mut z, m);
    let mut p = z.clone();
    let mut rz: Vec<f64> = (0..m)
        .map(|j| dot(&r[j * n..(j + 1) * n], &z[j * n..(j + 1) * n]))
        .collect();
    let mut q = vec![0.0; n * m];
    let done =
        |r: &[f64], j: usize| dot(&r[j * n..(j + 1) * n], &r[j * n..(j + 1) * n]).sqrt() <= goal[j];
    let mut active: Vec<bool> = (0..m).map(|j| !done(&r, j)).collect();
    let mut its = 0;
    while active.iter().any(|&a| a) {
        if its == max_iter {
            return (false, its);
        }
        its += 1;
        q.iter_mut().for_each(|v| *v = 0.0);
        for j in (0..m).filter(|&j| active[j]) {
            let cols = j * n..(j + 1) * n;
            pattern.mul_add(s, &p[cols.clone()], &mut q[cols]);
        }
        for j in 0..m {
            if !active[j] {
                continue;
            }
            let cols = j * n..(j + 1) * n;
            let pq = dot(&p[cols.clone()], &q[cols.clone()]);
            if pq.is_nan() || pq <= 0.0 {
                // S is not positive definite along p (or the iteration broke down).
                return (false, its);
            }
            let alpha = rz[j] / pq;
            for i in cols {
                x[i] += alpha * p[i];
                r[i] -= alpha * q[i];
            }
            active[j] = !done(&r, j);
        }
        z.copy_from_slice(&r);
        f.solve_columns_in_place(&mut z, m);
        for j in (0..m).filter(|&j| active[j]) {
            let cols = j * n..(j + 1) * n;
            let rz_new = dot(&r[cols.clone()], &z[cols.clone()]);
            let beta = rz_new / rz[j];
            rz[j] = rz_new;
            for i in cols {
                p[i] = z[i] + beta * p[i];
            }
        }
    }
    b.copy_from_slice(&x);
    (true, its)
}

/// Converged end-of-step data handed to a step observer.
pub struct StepView<'a> {
    /// Step index n ≥ 1.
    pub n: usize,
    /// Positions x^n (full dofs).
    pub x: &'a [f64],
    /// Velocities v^n (full dofs).
    pub v: &'a [f64],
    /// x^{n−1}, x^{n−2}, v^{n−1}, v^{n−2} (full dofs).
    pub prev: [&'a [f64]; 4],
    /// The state (positions, velocities; full dofs) where the step's forces and tangents are
    /// evaluated: x^n, v^n for BDF2, x^{n−½}, v^{n−½} for the midpoint rule, Σ β_j x^{n−2+j},
    /// Σ β_j v^{n−2+j} for generalised-α ([`crate::timestep::TwoStep`]).
    pub force_state: [&'a [f64]; 2],
    /// b of the step's inertia term c M (v^n − b) (full dofs): (4v^{n−1} − v^{n−2})/3 for BDF2,
    /// v^{n−1} for the midpoint rule, −(α_1 v^{n−1} + α_0 v^{n−2})/α_2 for generalised-α.
    pub inertia_base: &'a [f64],
    /// Cholesky factor of S = c M + a_x K + a_v D ([`Scheme::coefficients`]) at the converged
    /// state (present when the caller asked for [`StepSolve::Fresh`]).
    pub factor: Option<&'a Factor>,
    /// Solves with S at the converged state (present unless the run was [`StepSolve::None`]).
    pub solver: Option<&'a StepSolver>,
    /// K values at the converged force state (free pattern) when the caller asked for solves;
    /// otherwise those of the step's last tangent assembly.
    pub k: &'a [f64],
    /// D values, as `k`.
    pub d: &'a [f64],
    /// With a creep branch ([`super::relaxation`]): what the step took from the history, and
    /// the branch's state at its end.
    pub relaxation: Option<(&'a StepBranch, &'a Relaxation)>,
}

/// Counters of one forward run.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SimStats {
    /// Newton iterations over all steps (linear solves).
    pub newton_iterations: usize,
    /// Steps that hit the iteration cap without reaching the tolerance.
    pub unconverged_steps: usize,
    /// Largest final residual norm over steps (N).
    pub max_residual: f64,
    /// Numeric factorisations of S (fresh tangents; the rest of the iterations reused a kept
    /// factor).
    pub factorisations: usize,
    /// Preconditioned-CG iterations of the [`StepSolve::Kept`] solves.
    pub cg_iterations: usize,
}

/// Elastostatic equilibrium f(x, 0) + f_ext = 0 with clamps at their step-0 pose (§3.4).
/// Returns x⁰ and the factor of K₀ at x⁰ (needed by eq. 14 and the direct method's s_x⁰).
pub fn static_start(model: &Model, mat: &Material) -> Result<(Vec<f64>, Factor), MotionError> {
    equilibrium(model, mat, 0)
}

/// Elastostatic equilibrium under the clamp poses and external loads of step `n`, by Newton
/// from the rest shape: where a run that has rung down should come to rest (the prediction a
/// validation compares with the capture's last frames).
pub fn equilibrium(
    model: &Model,
    mat: &Material,
    n: usize,
) -> Result<(Vec<f64>, Factor), MotionError> {
    let mut x: Vec<f64> = model.nodes.iter().flatten().copied().collect();
    model.apply_clamps(n, &mut x);
    equilibrium_from(model, mat, n, x)
}

/// [`equilibrium`] by Newton from `x` (full dofs, clamped dofs already at their step-`n` pose),
/// e.g. the last state of a simulation that has nearly come to rest.
///
/// Newton is tried under the full load first (cheap when `x` is near the answer). When it fails
/// — a slender body under its own weight, where the first Newton step is the linear answer that
/// stretches the body instead of bending it — the load is followed by continuation: the load
/// factor s grows from 0 to 1 in increments that double after a converged increment and halve
/// after a failed one, each solve starting from the last converged state.
pub fn equilibrium_from(
    model: &Model,
    mat: &Material,
    n: usize,
    x: Vec<f64>,
) -> Result<(Vec<f64>, Factor), MotionError> {
    let fext = model.external_load(mat, n);
    let first = match newton_static(model, mat, n, x.clone(), &fext, 1.0) {
        Ok(r) => return Ok(r),
        Err(e) => e,
    };
    // Smallest increment tried before giving up: a load path that needs more than ~1000
    // increments is not a plausible static state (the body collapses under the load).
    const MIN_INCREMENT: f64 = 1.0 / 1024.0;
    let (mut x, mut s, mut ds) = (x, 0.0f64, 0.25f64);
    let mut last_err = first;
    while s < 1.0 {
        let target = (s + ds).min(1.0);
        match newton_static(model, mat, n, x.clone(), &fext, target) {
            Ok((xs, fac)) => {
                if target >= 1.0 {
                    return Ok((xs, fac));
                }
                x = xs;
                s = target;
                ds = (2.0 * ds).min(1.0);
            }
            Err(e) => {
                last_err = e;
                ds *= 0.5;
                if ds < MIN_INCREMENT {
                    break;
                }
            }
        }
    }
    Err(last_err)
}

/// Newton for f(x, 0) + `scale`·`fext` = 0 from `x`, with an exact line search on the total
/// potential energy.
///
/// The static problem minimises E(x) = Σ_e V_e Ψ(F_e) − (scale·f_ext)ᵀx, whose gradient is −r
/// (r = f + scale·f_ext, the net force). Along the Newton direction dx the energy's slope is
/// g(α) = −dxᵀ r(x + α dx), negative at α = 0 whenever K is positive definite. A merit function
/// on ‖r‖ (what backtracking on the residual norm uses) rejects the steps a bending body needs —
/// the linear step overshoots in stretch, ‖r‖ grows though E falls — and crawls at α ≈ 1e-3;
/// a root of g is the energy minimum along dx and needs only residuals, so it also holds for
/// the spline materials, whose energy is not evaluated anywhere. Steps that would invert an
/// element are halved. When K is not positive definite (a compressed state far from
/// equilibrium), a growing diagonal shift makes dx a descent direction again.
fn newton_static(
    model: &Model,
    mat: &Material,
    n: usize,
    mut x: Vec<f64>,
    fext: &[f64],
    scale: f64,
) -> Result<(Vec<f64>, Factor), MotionError> {
    let ndof = 3 * model.nodes.len();
    let v = vec![0.0; ndof];
    let mut f = vec![0.0; ndof];
    let mut k = vec![0.0; model.pattern.nnz()];
    let resid =
        |x: &[f64], f: &mut [f64], k: Option<&mut [f64]>| -> Result<(Vec<f64>, f64), MotionError> {
            assemble(model, mat, x, &v, f, k, None)?;
            let mut r = vec![0.0; model.nfree];
            for (d, &fr) in model.free.iter().enumerate() {
                if fr != usize::MAX {
                    r[fr] = f[d] + scale * fext[d];
                }
            }
            let nrm = r.iter().map(|z| z * z).sum::<f64>().sqrt();
            Ok((r, nrm))
        };
    let step = |x: &[f64], dx: &[f64], alpha: f64| -> Vec<f64> {
        let mut xt = x.to_vec();
        for (d, &fr) in model.free.iter().enumerate() {
            if fr != usize::MAX {
                xt[d] += alpha * dx[fr];
            }
        }
        xt
    };
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(p, q)| p * q).sum::<f64>();
    // The paper's 1e-6 N, or a relative 1e-12 of the load where the load is so large that
    // rounding in the internal forces alone exceeds it.
    let load = scale * fext.iter().map(|z| z * z).sum::<f64>().sqrt();
    let tol = model.newton.tol.max(1e-12 * load);
    let (mut r, mut nrm) = resid(&x, &mut f, Some(&mut k))?;
    for _ in 0..NEWTON_STATIC_ITERATIONS {
        if nrm < tol {
            let factor = model
                .pattern
                .factor(&k)
                .ok_or(MotionError::NotPositiveDefinite { step: n })?;
            return Ok((x, factor));
        }
        let factor = shifted_factor(&model.pattern, model.nfree, &mut k)
            .ok_or(MotionError::NotPositiveDefinite { step: n })?;
        let mut dx = r.clone();
        factor.solve_in_place(&mut dx);
        let g0 = -dot(&dx, &r);
        // Energy slope at α (None: an element inverts there).
        let slope = |alpha: f64| -> Option<f64> {
            let xt = step(&x, &dx, alpha);
            resid(&xt, &mut f, None).ok().map(|(rt, _)| -dot(&dx, &rt))
        };
        let Some(alpha) = slope_root(g0, slope) else {
            break;
        };
        x = step(&x, &dx, alpha);
        (r, nrm) = resid(&x, &mut f, Some(&mut k))?;
    }
    Err(MotionError::NoConvergence {
        step: n,
        residual: nrm,
    })
}

/// The affine map from a step's velocities v to the state its forces are evaluated at: on free
/// dofs x_f = x_a + a_x v, v_f = v_a + a_v v ([`Scheme::coefficients`]); clamped dofs keep the
/// values the step prescribes them.
pub(crate) struct ForceMap {
    xa: Vec<f64>,
    va: Vec<f64>,
    ax: f64,
    av: f64,
}

impl ForceMap {
    /// Writes the free entries of (`xf`, `vf`) from `v`.
    pub(crate) fn fill(&self, free: &[usize], v: &[f64], xf: &mut [f64], vf: &mut [f64]) {
        for (d, &fr) in free.iter().enumerate() {
            if fr != usize::MAX {
                xf[d] = self.xa[d] + self.ax * v[d];
                vf[d] = self.va[d] + self.av * v[d];
            }
        }
    }
}

/// Line search of a step along the Newton update `dv` (free dofs) from `v0`.
///
/// The step's residual r(v) = f(x_f(v), v_f(v)) + f_ext − c M (v − b) (see [`ForceMap`]) is
/// −∇Π/a_x of the incremental potential Π(v) = (c a_x/2) (v − b)ᵀM(v − b) + W(x_f(v)) −
/// a_x f_extᵀv + (a_x/a_v) times the viscous dissipation potential at v_f (convex for the power
/// law), so — as in the static solve — the root of Π's slope g(α) = −dvᵀ r(v0 + α dv) along dv
/// is the minimum along it. Regula falsi (Illinois) on g from g(0) = `g0` < 0, halving first
/// while the step inverts an element. `xf`, `vf` hold the step's clamped values (their free
/// entries are ignored). Returns α.
#[allow(clippy::too_many_arguments)]
fn line_search_dynamic(
    model: &Model,
    mat: &Material,
    branch: Option<&StepBranch>,
    map: &ForceMap,
    xf: &[f64],
    vf: &[f64],
    v0: &[f64],
    dv: &[f64],
    g0: f64,
    residual: &mut dyn FnMut(&[f64], &[f64]) -> Vec<f64>,
) -> f64 {
    let ndof = v0.len();
    let mut f = vec![0.0; ndof];
    let mut slope = |alpha: f64| -> Option<f64> {
        let mut v = v0.to_vec();
        let (mut x, mut w) = (xf.to_vec(), vf.to_vec());
        for (d, &fr) in model.free.iter().enumerate() {
            if fr != usize::MAX {
                v[d] += alpha * dv[fr];
            }
        }
        map.fill(&model.free, &v, &mut x, &mut w);
        assemble_relaxing(model, mat, &x, &w, branch, &mut f, None, None).ok()?;
        let r = residual(&f, &v);
        Some(-dv.iter().zip(&r).map(|(p, q)| p * q).sum::<f64>())
    };
    slope_root(g0, &mut slope).unwrap_or(0.0)
}

/// Step length along a descent direction from the slope g(α) of the potential it descends
/// (g(0) = `g0` < 0; `slope` is `None` where the step inverts an element).
///
/// The full step is halved until it is admissible; it is kept when the potential still falls
/// there or the slope has dropped to half its size, otherwise the root of g in [0, α] is found
/// by regula falsi (Illinois), to half the initial slope. `None` when no admissible step was
/// found in 40 halvings.
fn slope_root(g0: f64, mut slope: impl FnMut(f64) -> Option<f64>) -> Option<f64> {
    let mut hi = 1.0;
    let mut g_hi = None;
    for _ in 0..40 {
        if let Some(g) = slope(hi) {
            g_hi = Some(g);
            break;
        }
        hi *= 0.5;
    }
    let g_hi = g_hi?;
    if g_hi <= 0.0 || g_hi.abs() <= 0.5 * g0.abs() {
        return Some(hi);
    }
    let (mut a, mut ga, mut b, mut gb) = (0.0, g0, hi, g_hi);
    let mut c = hi;
    for side in 0..12 {
        c = (a * gb - b * ga) / (gb - ga);
        let Some(gc) = slope(c) else {
            b = c;
            continue;
        };
        if gc.abs() <= 0.5 * g0.abs() {
            break;
        }
        if gc < 0.0 {
            a = c;
            ga = gc;
            if side > 0 {
                gb *= 0.5;
            }
        } else {
            b = c;
            gb = gc;
            ga *= 0.5;
        }
    }
    Some(c)
}

/// Newton iterations of one static solve (one load level).
const NEWTON_STATIC_ITERATIONS: usize = 60;

/// Cholesky factor of K, or of K + τ I with τ growing tenfold from 1e-8 of the mean diagonal when
/// K is not positive definite (the values in `k` are left shifted).
pub(crate) fn shifted_factor(pattern: &Pattern, nf: usize, k: &mut [f64]) -> Option<Factor> {
    if let Some(f) = pattern.factor(k) {
        return Some(f);
    }
    let mean = (0..nf).map(|r| pattern.diagonal(r, k).abs()).sum::<f64>() / nf.max(1) as f64;
    let mut tau = 1e-8 * mean;
    let mut added = 0.0;
    for _ in 0..12 {
        for r in 0..nf {
            pattern.add_diagonal(r, tau - added, k);
        }
        added = tau;
        if let Some(f) = pattern.factor(k) {
            return Some(f);
        }
        tau *= 10.0;
    }
    None
}

/// [`simulate`] without factors and without looking at the start: `on_step` sees each converged
/// step (predictions, recordings, the objective without gradient).
pub fn simulate_states(
    model: &Model,
    mat: &Material,
    on_step: impl FnMut(&StepView<'_>) -> Result<(), MotionError>,
) -> Result<SimStats, MotionError> {
    simulate_solving(model, mat, StepSolve::None, |_, _| {}, on_step)
}

/// Runs the forward simulation from the rest shape or the elastostatic start.
///
/// `on_start(x⁰, K₀ factor)` is called once (factor `None` for a rest-shape start), then
/// `on_step` after every converged step. With `factors = true` each step's S is factorised at
/// the converged state (one extra factorisation per step) and handed to `on_step`
/// ([`StepSolve::Fresh`]).
pub fn simulate(
    model: &Model,
    mat: &Material,
    factors: bool,
    on_start: impl FnMut(&[f64], Option<&Factor>),
    on_step: impl FnMut(&StepView<'_>) -> Result<(), MotionError>,
) -> Result<SimStats, MotionError> {
    let solve = if factors {
        StepSolve::Fresh
    } else {
        StepSolve::None
    };
    simulate_solving(model, mat, solve, on_start, on_step)
}

/// The elastostatic start x⁰ with the factor of K₀ there ([`static_start`]), or the rest shape
/// with the clamps at their step-0 pose (no factor).
fn start_state(model: &Model, mat: &Material) -> Result<(Vec<f64>, Option<Factor>), MotionError> {
    if model.static_start {
        let (x, f) = static_start(model, mat)?;
        return Ok((x, Some(f)));
    }
    let mut x: Vec<f64> = model.nodes.iter().flatten().copied().collect();
    model.apply_clamps(0, &mut x);
    Ok((x, None))
}

/// A scheme's constants over a run: S = c M + a_x K + a_v D ([`Scheme::coefficients`]) and
/// generalised-α's two-step weights with their force-state history coefficients.
pub(crate) struct SchemeTerms {
    scheme: Scheme,
    dt: f64,
    c: f64,
    ax: f64,
    av: f64,
    two: TwoStep,
    hist: (f64, f64, f64),
}

impl SchemeTerms {
    pub(crate) fn new(model: &Model, mat: &Material) -> Self {
        let scheme = model.scheme_for(mat);
        let (c, ax, av) = scheme.coefficients(model.dt);
        let two = scheme.two_step();
        let hist = two.force_history(model.dt);
        Self {
            scheme,
            dt: model.dt,
            c,
            ax,
            av,
            two,
            hist,
        }
    }

    /// The step's (c, a_x, a_v) ([`Scheme::coefficients`]).
    pub(crate) fn coefficients(&self) -> (f64, f64, f64) {
        (self.c, self.ax, self.av)
    }

    /// BDF2's extrapolated position (4x^{n−1} − x^{n−2})/3 of dof `d`.
    fn bdf2_xa(xm1: &[f64], xm2: &[f64], d: usize) -> f64 {
        (4.0 * xm1[d] - xm2[d]) / 3.0
    }

    /// The step's force state as a function of v ([`ForceMap`]) and its inertia base b, from
    /// the two steps before it.
    pub(crate) fn step_map(&self, xm: [&[f64]; 2], vm: [&[f64]; 2]) -> (ForceMap, Vec<f64>) {
        let ([xm1, xm2], [vm1, vm2]) = (xm, vm);
        let (ax, av, two) = (self.ax, self.av, &self.two);
        let (hist_a0, hist_a1, hist_e) = self.hist;
        let ndof = xm1.len();
        match self.scheme {
            Scheme::Bdf2 => (
                ForceMap {
                    xa: (0..ndof).map(|d| Self::bdf2_xa(xm1, xm2, d)).collect(),
                    va: vec![0.0; ndof],
                    ax,
                    av,
                },
                (0..ndof)
                    .map(|d| (4.0 * vm1[d] - vm2[d]) / 3.0)
                    .collect::<Vec<f64>>(),
            ),
            Scheme::Midpoint => (
                ForceMap {
                    xa: (0..ndof).map(|d| xm1[d] + ax * vm1[d]).collect(),
                    va: (0..ndof).map(|d| av * vm1[d]).collect(),
                    ax,
                    av,
                },
                vm1.to_vec(),
            ),
            Scheme::Alpha => {
                let hist_v = |d: usize| two.beta[1] * vm1[d] + two.beta[0] * vm2[d];
                (
                    ForceMap {
                        xa: (0..ndof)
                            .map(|d| hist_a1 * xm1[d] + hist_a0 * xm2[d] + hist_e * hist_v(d))
                            .collect(),
                        va: (0..ndof).map(hist_v).collect(),
                        ax,
                        av,
                    },
                    (0..ndof)
                        .map(|d| -(two.alpha[1] * vm1[d] + two.alpha[0] * vm2[d]) / two.alpha[2])
                        .collect(),
                )
            }
        }
    }

    /// Newton's start for step n: the velocity extrapolated quadratically from the last steps
    /// (second-order like the schemes, so Newton starts O(Δt³) from the answer instead of
    /// O(Δt)), and on the clamped dofs the velocities of their prescribed positions `x` with
    /// the force state (`xf`, `vf`) the scheme evaluates there.
    ///
    /// The midpoint rule maps a mode it does not resolve, or one damped stiffly, to z → −1: its
    /// end-of-step velocities alternate in sign from step to step, and extrapolating them
    /// quadratically multiplies that alternation by 7. Its step means u^n = (v^{n−1} + v^n)/2 =
    /// (x^n − x^{n−1})/Δt carry no alternation, so they are what is extrapolated, quadratically,
    /// and v^n = 2u^n − v^{n−1}: v = 2v^{n−1} − 2v^{n−3} + v^{n−4}, exact on the alternation and
    /// O(Δt³) on a smooth motion. `free` maps each dof to its free index, or `usize::MAX` where
    /// it is clamped.
    pub(crate) fn predictor(
        &self,
        free: &[usize],
        x: &[f64],
        xm: [&[f64]; 2],
        vm: [&[f64]; 4],
        xf: &mut [f64],
        vf: &mut [f64],
    ) -> Vec<f64> {
        let ([xm1, xm2], [vm1, vm2, vm3, vm4]) = (xm, vm);
        let (dt, two) = (self.dt, &self.two);
        let a2 = 2.0 * dt / 3.0;
        let mut v: Vec<f64> = match self.scheme {
            Scheme::Midpoint => (0..x.len())
                .map(|d| 2.0 * vm1[d] - 2.0 * vm3[d] + vm4[d])
                .collect(),
            Scheme::Bdf2 | Scheme::Alpha => (0..x.len())
                .map(|d| 3.0 * vm1[d] - 3.0 * vm2[d] + vm3[d])
                .collect(),
        };
        for d in 0..x.len() {
            if free[d] == usize::MAX {
                v[d] = (x[d] - Self::bdf2_xa(xm1, xm2, d)) / a2;
                (xf[d], vf[d]) = match self.scheme {
                    Scheme::Bdf2 => (x[d], v[d]),
                    Scheme::Midpoint => (0.5 * (x[d] + xm1[d]), (x[d] - xm1[d]) / dt),
                    // The scheme's own mean velocity Σ β_j v_j = Σ α_j x_j / Δt of the pose.
                    Scheme::Alpha => (
                        two.beta[2] * x[d] + two.beta[1] * xm1[d] + two.beta[0] * xm2[d],
                        (two.alpha[2] * x[d] + two.alpha[1] * xm1[d] + two.alpha[0] * xm2[d]) / dt,
                    ),
                };
            }
        }
        v
    }

    /// Writes the free dofs' end-of-step positions into `x` from the converged velocities `v`
    /// and force state `xf` (`free` as in [`Self::predictor`]).
    pub(crate) fn end_positions(
        &self,
        free: &[usize],
        xf: &[f64],
        v: &[f64],
        xm: [&[f64]; 2],
        vm: [&[f64]; 2],
        x: &mut [f64],
    ) {
        let ([xm1, xm2], [vm1, vm2]) = (xm, vm);
        for (d, &fr) in free.iter().enumerate() {
            if fr != usize::MAX {
                x[d] = match self.scheme {
                    Scheme::Bdf2 => xf[d],
                    Scheme::Midpoint => xm1[d] + 0.5 * self.dt * (vm1[d] + v[d]),
                    Scheme::Alpha => {
                        self.two
                            .position(self.dt, [xm2[d], xm1[d]], [vm2[d], vm1[d], v[d]])
                    }
                };
            }
        }
    }
}

impl SimStats {
    /// Counts a converged (or capped) step whose final residual norm is `nrm` against the
    /// tolerance `tol`.
    fn finish_step(&mut self, nrm: f64, tol: f64) {
        self.max_residual = self.max_residual.max(nrm);
        if nrm >= tol {
            self.unconverged_steps += 1;
        }
    }
}

impl StepSolver {
    /// The solver of step `n` with S (values `sv`) from Newton's factor `fac` — S's own when
    /// `exact` — preconditioned after the run's last refactorisation `refresh`.
    fn for_step(
        n: usize,
        (fac, exact): (Factor, bool),
        sv: &[f64],
        settings: KeptSolve,
        refresh: Option<&(Factor, Factor)>,
    ) -> Self {
        let solver = StepSolver {
            // An exact factor never needs S's values.
            s: if exact { Vec::new() } else { sv.to_vec() },
            handed: fac.clone(),
            factor: RefCell::new(fac),
            exact: Cell::new(exact),
            step: n,
            settings,
            refactorisations: Cell::new(0),
            cg_iterations: Cell::new(0),
        };
        if let Some(r) = refresh {
            solver.precondition_after(r);
        }
        solver
    }
}

/// [`simulate`] with the converged steps' S solved as `solve` says ([`StepView::solver`]).
pub fn simulate_solving(
    model: &Model,
    mat: &Material,
    solve: StepSolve,
    mut on_start: impl FnMut(&[f64], Option<&Factor>),
    mut on_step: impl FnMut(&StepView<'_>) -> Result<(), MotionError>,
) -> Result<SimStats, MotionError> {
    let ndof = 3 * model.nodes.len();
    let (x0, k0) = start_state(model, mat)?;
    on_start(&x0, k0.as_ref());
    drop(k0);
    // The creep branch starts fully relaxed at x⁰ ([`super::relaxation`]).
    let mut relax = Relaxation::start(model, mat, &x0)?;
    let terms = SchemeTerms::new(model, mat);
    let (c, ax, av) = (terms.c, terms.ax, terms.av);
    // Gravity once; the dead loads switch on at their step.
    let fgrav = model.gravity_load(mat);
    let mut fext = fgrav.clone();
    let mvals = model.mass_values(mat);
    let (mut xm2, mut xm1) = (x0.clone(), x0);
    let (mut vm2, mut vm1) = (vec![0.0; ndof], vec![0.0; ndof]);
    let (mut vm3, mut vm4) = (vec![0.0; ndof], vec![0.0; ndof]);
    let mut f = vec![0.0; ndof];
    let mut kv = vec![0.0; model.pattern.nnz()];
    let mut dv = vec![0.0; model.pattern.nnz()];
    let mut sv = vec![0.0; model.pattern.nnz()];
    let mut mw = vec![0.0; ndof];
    let lumped = model.lumped_mass_diagonal(mat);
    let mut stats = SimStats::default();
    // Modified Newton: the factor of S = c M + a_x K + a_v D is kept across iterations and
    // steps while the residual contracts by at least `REFACTOR_CONTRACTION` per iteration; S
    // changes little from one step to the next of a smooth motion, and an iteration with a
    // kept factor costs one force assembly and two triangular solves instead of the tangent
    // assembly and a numeric factorisation. A converged step whose factor the caller asked
    // for (`StepSolve::Fresh`) is factorised afresh at its own state; `StepSolve::Kept` solves
    // with S there by CG preconditioned with the kept factor.
    let factors = solve != StepSolve::None;
    let mut carried: Option<Factor> = None;
    // StepSolve::Kept: the last solve's refactorisation, (stale factor, fresh factor).
    let mut refresh: Option<(Factor, Factor)> = None;
    // ‖r‖ after / before the last iteration solved with a factor made at its own iterate: what a
    // fresh factor buys here ([`refactor_pays`]); 0 until one has been measured.
    let mut fresh_contraction = 0.0_f64;
    for n in 1..=model.steps {
        if !model.loads.is_empty() {
            fext.copy_from_slice(&fgrav);
            model.add_dead_loads(n, &mut fext);
        }
        // End-of-step positions of the clamped dofs.
        let mut x = vec![0.0; ndof];
        model.apply_clamps(n, &mut x);
        let (map, b) = terms.step_map([&xm1, &xm2], [&vm1, &vm2]);
        let (mut xf, mut vf) = (vec![0.0; ndof], vec![0.0; ndof]);
        let branch = relax.as_ref().map(Relaxation::step_branch);
        let mut v = terms.predictor(
            &model.free,
            &x,
            [&xm1, &xm2],
            [&vm1, &vm2, &vm3, &vm4],
            &mut xf,
            &mut vf,
        );
        map.fill(&model.free, &v, &mut xf, &mut vf);
        let mut iter = 0;
        let last_factor: Option<Factor>;
        // The factor the step's solver starts from, and whether it is S's own.
        let mut kept: Option<(Factor, bool)> = None;
        // The last Newton update: the velocities it started from, its direction (free dofs) and
        // the incremental potential's slope there (see `line_search_dynamic`).
        let mut last_step: Option<(Vec<f64>, Vec<f64>, f64)> = None;
        // Whether this iteration assembles K and D (and factorises S) at its own state.
        let mut fresh = carried.is_none();
        // Whether the last update was solved with a factor made at its own iterate.
        let mut solved_fresh = false;
        let mut prev_nrm = f64::INFINITY;
        loop {
            let assembled = if fresh {
                assemble_relaxing(
                    model,
                    mat,
                    &xf,
                    &vf,
                    branch.as_ref(),
                    &mut f,
                    Some(&mut kv),
                    Some(&mut dv),
                )
            } else {
                assemble_relaxing(model, mat, &xf, &vf, branch.as_ref(), &mut f, None, None)
            };
            // The full step is kept unless it inverts an element or overshoots the minimum of
            // the step's incremental potential by more than half its initial slope; then it is
            // replaced by a line search from where it started (never on the first iteration,
            // whose state is the predictor, not a step).
            let residual = |f: &[f64], v: &[f64], mw: &mut Vec<f64>| -> Vec<f64> {
                let mut r = vec![0.0; model.nfree];
                if let Some(m) = &lumped {
                    for (d, &fr) in model.free.iter().enumerate() {
                        if fr != usize::MAX {
                            r[fr] = f[d] + fext[d] - c * (m[d] * (v[d] - b[d]));
                        }
                    }
                    return r;
                }
                let vb: Vec<f64> = (0..ndof).map(|d| v[d] - b[d]).collect();
                mw.iter_mut().for_each(|z| *z = 0.0);
                model.mass_mul(mat, &vb, mw);
                for (d, &fr) in model.free.iter().enumerate() {
                    if fr != usize::MAX {
                        r[fr] = f[d] + fext[d] - c * mw[d];
                    }
                }
                r
            };
            // The residual the check reads is this iteration's: kept for it.
            let mut checked = None;
            let overshoot = match (&assembled, &last_step) {
                (Err(MotionError::Inverted { .. }), Some(_)) => true,
                (Err(_), _) => false,
                (Ok(()), Some((_, dvec, g0))) => {
                    let r = residual(&f, &v, &mut mw);
                    let g1 = -dvec.iter().zip(&r).map(|(p, q)| p * q).sum::<f64>();
                    checked = Some(r);
                    g1 > 0.5 * g0.abs()
                }
                (Ok(()), None) => false,
            };
            if !overshoot {
                assembled?;
            } else if let Some((v0, dvec, g0)) = last_step.take() {
                let alpha = line_search_dynamic(
                    model,
                    mat,
                    branch.as_ref(),
                    &map,
                    &xf,
                    &vf,
                    &v0,
                    &dvec,
                    g0,
                    &mut |f, v| residual(f, v, &mut mw),
                );
                v.copy_from_slice(&v0);
                for (d, &fr) in model.free.iter().enumerate() {
                    if fr != usize::MAX {
                        v[d] += alpha * dvec[fr];
                    }
                }
                map.fill(&model.free, &v, &mut xf, &mut vf);
                continue;
            }
            let mut r = checked.unwrap_or_else(|| residual(&f, &v, &mut mw));
            let nrm = r.iter().map(|z| z * z).sum::<f64>().sqrt();
            if !nrm.is_finite() {
                return Err(MotionError::NonFinite(format!("residual at step {n}")));
            }
            if solved_fresh {
                fresh_contraction = nrm / prev_nrm;
            }
            let done = nrm < model.newton.tol || iter >= model.newton.max_iter;
            if done && !factors {
                stats.finish_step(nrm, model.newton.tol);
                last_factor = None;
                break;
            }
            if !fresh && done {
                // Converged with a kept factor; the gradients need K, D and S at this state.
                // Its forces are already assembled: the tangents alone.
                assemble_tangents(model, mat, &xf, &vf, branch.as_ref(), &mut kv, &mut dv)?;
            } else if !fresh
                && refactor_pays(
                    nrm / prev_nrm,
                    fresh_contraction,
                    model.newton.max_iter - iter,
                    nrm / model.newton.tol,
                )
            {
                // The kept factor no longer contracts: assemble the tangent here and factorise.
                // This state's forces and residual are already at hand (the same to the last bit
                // as the tangent pass would give them again): the tangents alone.
                assemble_tangents(model, mat, &xf, &vf, branch.as_ref(), &mut kv, &mut dv)?;
                fresh = true;
                last_step = None;
            }
            // S is factorised (afresh, or at the converged state) or handed on only here; an
            // iteration with a kept factor does not read it.
            if done || fresh {
                for i in 0..sv.len() {
                    sv[i] = c * mvals[i] + ax * kv[i] + av * dv[i];
                }
            }
            if let (true, StepSolve::Kept(_)) = (done, solve) {
                stats.finish_step(nrm, model.newton.tol);
                kept = Some(match carried.clone() {
                    Some(fac) => (fac, false),
                    None => {
                        stats.factorisations += 1;
                        let fac = model
                            .pattern
                            .factor(&sv)
                            .ok_or(MotionError::NotPositiveDefinite { step: n })?;
                        (fac, true)
                    }
                });
                last_factor = None;
                break;
            }
            if done {
                // The converged S is what the gradients solve with: no shift here.
                let fac = model
                    .pattern
                    .factor(&sv)
                    .ok_or(MotionError::NotPositiveDefinite { step: n })?;
                stats.factorisations += 1;
                stats.finish_step(nrm, model.newton.tol);
                kept = Some((fac.clone(), true));
                last_factor = Some(fac);
                break;
            }
            if fresh {
                // During the iterations S may be indefinite (an element compressed far from
                // the step's answer); a shift keeps the update a descent direction.
                carried = Some(
                    shifted_factor(&model.pattern, model.nfree, &mut sv)
                        .ok_or(MotionError::NotPositiveDefinite { step: n })?,
                );
                stats.factorisations += 1;
            }
            let Some(fac) = carried.as_ref() else {
                // Unreachable: a fresh iteration has just stored its factor.
                fresh = true;
                continue;
            };
            let r0 = r.clone();
            fac.solve_in_place(&mut r);
            let g0 = -r.iter().zip(&r0).map(|(p, q)| p * q).sum::<f64>();
            let v_before = v.clone();
            for (d, &fr) in model.free.iter().enumerate() {
                if fr != usize::MAX {
                    v[d] += r[fr];
                }
            }
            map.fill(&model.free, &v, &mut xf, &mut vf);
            last_step = Some((v_before, r, g0));
            prev_nrm = nrm;
            solved_fresh = fresh;
            fresh = false;
            iter += 1;
            stats.newton_iterations += 1;
        }
        terms.end_positions(&model.free, &xf, &v, [&xm1, &xm2], [&vm1, &vm2], &mut x);
        // Fresh solves are exact: the settings only steer CG on a kept factor.
        let settings = match solve {
            StepSolve::Kept(k) => k,
            _ => KeptSolve::EXACT,
        };
        let solver = kept.map(|fac| StepSolver::for_step(n, fac, &sv, settings, refresh.as_ref()));
        if let (Some(r), Some(b)) = (relax.as_mut(), &branch) {
            // At the force state, where the step's stress stood ([`super::relaxation`]).
            r.advance(model, mat, b, &xf)?;
        }
        on_step(&StepView {
            n,
            x: &x,
            v: &v,
            prev: [&xm1, &xm2, &vm1, &vm2],
            force_state: [&xf, &vf],
            inertia_base: &b,
            factor: last_factor.as_ref(),
            solver: solver.as_ref(),
            k: &kv,
            d: &dv,
            relaxation: branch.as_ref().zip(relax.as_ref()),
        })?;
        if let Some(sol) = &solver {
            stats.factorisations += sol.refactorisations();
            stats.cg_iterations += sol.cg_iterations();
            if let Some(r) = sol.refreshed() {
                if settings.newton_reuses {
                    // S's own factor at this step's converged state: what `Fresh` carries.
                    carried = Some(r.1.clone());
                }
                refresh = Some(r);
            }
        }
        if last_factor.is_some() {
            // The converged step's own factor is the best Newton matrix for the next step.
            carried = last_factor;
        }
        xm2 = std::mem::replace(&mut xm1, x);
        vm4 = std::mem::replace(
            &mut vm3,
            std::mem::replace(&mut vm2, std::mem::replace(&mut vm1, v)),
        );
    }
    log::debug!(
        "forward run: {} steps, {} Newton iterations, {} factorisations, {} steps unconverged (largest residual {:.1e} N)",
        model.steps,
        stats.newton_iterations,
        stats.factorisations,
        stats.unconverged_steps,
        stats.max_residual
    );
    Ok(stats)
}

/// Residual ratio ‖r_k‖/‖r_{k−1}‖ up to which an iteration with a kept factor always goes on with
/// it.
const REFACTOR_CONTRACTION: f64 = 0.25;

/// A fresh factor's cost in iterations with a kept one: the tangent pass and the numeric
/// factorisation against a force pass and two triangular solves.
const FACTORISATION_COST: f64 = 4.0;

/// Whether factorising S afresh pays after an iteration with a kept factor contracted the
/// residual by `kept` (‖r_k‖/‖r_{k−1}‖), where the last fresh factor contracted it by `fresh`,
/// with `left` iterations left and the residual `to_go` times the tolerance. Per unit of work a
/// kept iteration gains ln(1/kept), one with a fresh factor ln(1/fresh) / (1 + the factorisation's
/// cost): where the law is nearly linear a fresh factor contracts by 10⁻² or less and any kept
/// rate above `REFACTOR_CONTRACTION` loses; where a fresh factor itself contracts only by 0.5 (a
/// shear-thinning law near its floor), refactorising after every slow iteration buys little.
/// A kept factor is replaced all the same where its rate would need more than half the
/// iterations left to reach the tolerance: a rate measured once may worsen (without that margin
/// a soft cantilever's swing left a step unconverged).
fn refactor_pays(kept: f64, fresh: f64, left: usize, to_go: f64) -> bool {
    if kept <= REFACTOR_CONTRACTION {
        return false;
    }
    if kept >= 1.0 || 2.0 * to_go.ln() > left as f64 * (1.0 / kept).ln() {
        return true;
    }
    kept > fresh.powf(1.0 / (1.0 + FACTORISATION_COST))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The midpoint rule's predictor extrapolates its step means: exact on a quadratic motion
    /// with an alternation from step to step on top (z = −1: what the rule makes of a mode it
    /// does not resolve), where extrapolating the end-of-step velocities as BDF2's predictor
    /// does misses by 8 times the alternation.
    #[test]
    fn the_midpoint_predictor_is_exact_on_an_alternation() {
        use crate::model::{Clamp, MassKind, Pose};
        use crate::timestep::Scheme;
        let mesh = palpate_fem::mesh::boxmesh::box_mesh([0.1, 0.02, 0.02], [2, 1, 1]);
        let clamped: Vec<usize> = (0..mesh.nodes.len())
            .filter(|&i| mesh.nodes[i][0] < 1e-9)
            .collect();
        let clamp = Clamp {
            name: "clamp".into(),
            nodes: clamped,
            poses: vec![Pose::identity(); 3],
        };
        let mut model = Model::new(
            &mesh,
            vec![clamp],
            Vec::new(),
            0.01,
            2,
            [0.0, 0.0, -9.81],
            MassKind::Lumped,
        )
        .unwrap();
        model.scheme = Scheme::Midpoint;
        let mat = Material::uniform(mesh.tets.len(), 1e4, 1e4, 1.0, 1.0, 1000.0);
        let terms = SchemeTerms::new(&model, &mat);
        let (ndof, h) = (3 * mesh.nodes.len(), model.dt);
        let smooth = |t: f64| 0.3 + 2.0 * t - 40.0 * t * t;
        let alternation = |i: usize| if i.is_multiple_of(2) { 0.05 } else { -0.05 };
        let past: Vec<Vec<f64>> = (1..=4)
            .map(|i| vec![smooth(-(i as f64) * h) + alternation(i); ndof])
            .collect();
        let x: Vec<f64> = model.nodes.iter().flatten().copied().collect();
        let (mut xf, mut vf) = (vec![0.0; ndof], vec![0.0; ndof]);
        let v = terms.predictor(
            &model.free,
            &x,
            [&x, &x],
            [&past[0], &past[1], &past[2], &past[3]],
            &mut xf,
            &mut vf,
        );
        let d = model.free.iter().position(|&f| f != usize::MAX).unwrap();
        let next = smooth(0.0) + alternation(0);
        assert!((v[d] - next).abs() < 1e-12, "{} against {next}", v[d]);
        let ends = 3.0 * past[0][d] - 3.0 * past[1][d] + past[2][d];
        assert!((ends - next).abs() > 0.39, "{ends} against {next}");
    }

    /// Two tetrahedra sharing a face, node 0 clamped (12 free dofs), with symmetric positive
    /// definite element blocks Bᵀ B + I; `scale[e]` multiplies element e's block.
    fn matrix(scale: [f64; 2]) -> (Pattern, Vec<f64>) {
        let tets = vec![[0, 1, 2, 3], [1, 2, 3, 4]];
        let mut free = vec![usize::MAX; 15];
        for (k, d) in (3..15).enumerate() {
            free[d] = k;
        }
        let p = Pattern::new(&tets, &free, 12).unwrap();
        let mut values = vec![0.0; p.nnz()];
        for (e, &sc) in scale.iter().enumerate() {
            let b = |r: usize, c: usize| ((r * 7 + c * 3 + e * 5) % 11) as f64 / 11.0 - 0.4;
            let mut k = [[0.0; 12]; 12];
            for (r, row) in k.iter_mut().enumerate() {
                for (c, v) in row.iter_mut().enumerate() {
                    *v = (0..12).map(|i| b(i, r) * b(i, c)).sum::<f64>()
                        + if r == c { 1.0 } else { 0.0 };
                }
            }
            p.add_element(e, &k, sc, &mut values);
        }
        (p, values)
    }

    fn solver(s: Vec<f64>, handed: Factor) -> StepSolver {
        StepSolver {
            s,
            handed: handed.clone(),
            factor: RefCell::new(handed),
            exact: Cell::new(false),
            step: 1,
            settings: KeptSolve::EXACT,
            refactorisations: Cell::new(0),
            cg_iterations: Cell::new(0),
        }
    }

    /// Largest relative residual ‖b − S x‖/‖b‖ over the columns, by the pattern's product.
    fn relative_residual(p: &Pattern, s: &[f64], x: &[f64], b: &[f64], m: usize) -> f64 {
        let n = b.len() / m;
        (0..m)
            .map(|j| {
                let cols = j * n..(j + 1) * n;
                let mut sx = vec![0.0; n];
                p.mul_add(s, &x[cols.clone()], &mut sx);
                let r: f64 = sx
                    .iter()
                    .zip(&b[cols.clone()])
                    .map(|(a, c)| (c - a).powi(2))
                    .sum();
                let bb: f64 = b[cols].iter().map(|c| c * c).sum();
                (r / bb).sqrt()
            })
            .fold(0.0, f64::max)
    }

    fn columns(m: usize) -> Vec<f64> {
        (0..12 * m).map(|i| (i as f64 * 0.37).sin() + 0.1).collect()
    }

    /// A factor of a matrix 5 % off in one element preconditions CG to the tolerance in a few
    /// iterations, with no factorisation of S.
    #[test]
    fn a_nearby_factor_solves_to_the_tolerance_without_refactorising() {
        let (p, s) = matrix([1.0, 1.0]);
        let (_, near) = matrix([1.05, 1.0]);
        let sol = solver(s.clone(), p.factor(&near).unwrap());
        let b = columns(3);
        let mut x = b.clone();
        sol.solve_columns(&p, &mut x, 3).unwrap();
        let res = relative_residual(&p, &s, &x, &b, 3);
        assert!(res <= 1e-10, "relative residual {res:.1e}");
        assert_eq!(sol.refactorisations(), 0);
        assert!((1..=KEPT_FACTOR_ITERATIONS).contains(&sol.cg_iterations()));
        assert!(sol.refreshed().is_none());
    }

    /// A factor far from S does not converge in the allowed iterations: S is factorised, the
    /// answer is S's own, and a later solver handed the same stale factor starts from the fresh
    /// one (no factorisation, at most one CG iteration).
    #[test]
    fn a_far_factor_is_replaced_by_s_own_and_handed_on() {
        let (p, s) = matrix([1.0, 1.0]);
        let (_, far) = matrix([1.0, 1e4]);
        let stale = p.factor(&far).unwrap();
        let sol = solver(s.clone(), stale.clone());
        let b = columns(2);
        let mut x = b.clone();
        sol.solve_columns(&p, &mut x, 2).unwrap();
        let res = relative_residual(&p, &s, &x, &b, 2);
        assert!(res <= 1e-10, "relative residual {res:.1e}");
        assert_eq!(sol.refactorisations(), 1);
        let refresh = sol.refreshed().expect("refactorised");
        assert!(refresh.0.shares_values(&stale));
        let next = solver(s.clone(), stale);
        next.precondition_after(&refresh);
        let mut y = b.clone();
        next.solve_columns(&p, &mut y, 2).unwrap();
        assert_eq!(next.refactorisations(), 0);
        assert!(
            next.cg_iterations() <= 1,
            "{} iterations",
            next.cg_iterations()
        );
        assert!(relative_residual(&p, &s, &y, &b, 2) <= 1e-10);
    }

    /// The refactorisation rule: a kept factor that contracts by 4 or more always goes on; one
    /// that does not is replaced where a fresh factor contracts far better (a nearly linear step),
    /// kept where a fresh factor contracts little better (a shear-thinning law near its floor),
    /// and replaced whatever the rates where the residual grows or its rate cannot reach the
    /// tolerance in half the iterations left.
    #[test]
    fn a_kept_factor_is_replaced_where_a_fresh_one_pays_for_itself() {
        let left = 20;
        assert!(!refactor_pays(0.2, 1e-3, left, 1e2));
        assert!(!refactor_pays(0.2, 0.5, left, 1e2));
        // 10⁻³ ^ (1/5) = 0.25: a kept rate of 0.4 gains ln 2.5 per iteration's work where a
        // fresh factor gains ln 10³ / 5.
        assert!(refactor_pays(0.4, 1e-3, left, 1e2));
        // 0.5 ^ (1/5) = 0.87.
        assert!(!refactor_pays(0.6, 0.5, left, 2.0));
        assert!(refactor_pays(0.9, 0.5, left, 2.0));
        // 0.6 takes ln 10² / ln(1/0.6) = 9.0 iterations to gain 10²: at most half of 20 left,
        // more than half of 16.
        assert!(!refactor_pays(0.6, 0.5, 20, 1e2));
        assert!(refactor_pays(0.6, 0.5, 16, 1e2));
        assert!(refactor_pays(1.2, 0.9, left, 2.0));
        // Before any fresh factor has been measured, the rule is the fixed ratio's.
        assert!(refactor_pays(0.3, 0.0, left, 1e2));
    }
}
