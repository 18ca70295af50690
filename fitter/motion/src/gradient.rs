//! Objective and gradient: direct sensitivities (eqs. 5–6) and the adjoint method (eqs. 8–12)
//! with the elastostatic initial-condition term (eq. 14).
//!
//! Both are the exact derivatives of the *discrete* scheme (BDF2, the implicit midpoint rule or
//! generalised-α, [`Scheme`]): differentiating the step's equations (eq. 2 for BDF2) gives eq. 6 (direct), and
//! transposing that linear recurrence step by step gives the backward recurrence of eq. 12
//! (adjoint), so the two agree to round-off and match finite differences up to the Newton
//! tolerance. Density enters M and f_ext; its terms (§4.3) are included.
//!
//! Both schemes evaluate a step's forces at a state affine in the step's velocities v^n:
//! s_xf = s_xa + a_x s_v^n, s_vf = s_va + a_v s_v^n, with the inertia base's sensitivity s_b,
//! so the sensitivity step is S s_v^n = G + c M s_b − K s_xa − D s_va (G = ∂F/∂q at the force
//! state with the density's inertia term). BDF2: s_xa = (4s_x^{n−1} − s_x^{n−2})/3, s_va = 0,
//! s_b = (4s_v^{n−1} − s_v^{n−2})/3, s_x^n = s_xa + a_x s_v^n. Midpoint: s_xa = s_x^{n−1} +
//! (Δt/4) s_v^{n−1}, s_va = s_v^{n−1}/2, s_b = s_v^{n−1}, s_x^n = s_x^{n−1} + (Δt/2)(s_v^{n−1} +
//! s_v^n). Generalised-α ([`crate::timestep::TwoStep`], A_j, E its force history):
//! s_xa = A_1 s_x^{n−1} + A_0 s_x^{n−2} + E s_va, s_va = β_1 s_v^{n−1} + β_0 s_v^{n−2},
//! s_b = −(α_1 s_v^{n−1} + α_0 s_v^{n−2})/α_2, s_x^n = (Δt Σ β_j s_v − α_1 s_x^{n−1} −
//! α_0 s_x^{n−2})/α_2.

use super::forces::{param_derivatives, weight_derivatives, ViscousSkew, SPLIT_ASSEMBLY_ELEMENTS};
use super::model::{Material, Model, Observations, Param, Tie};
use super::objective::{clamp_force_derivatives, step_term, StepTerm};
use super::pipeline::simulate_pipelined;
use super::predict::Simulated;
use super::relaxation::Sensitivities as CreepSensitivities;
use super::sim::{simulate_solving, simulate_states, SimStats, StepSolve, StepSolver, StepView};
use super::sparse::Factor;
use super::timestep::Scheme;
use super::viscosity::Form;
use super::MotionError;

/// How the gradients solve with each converged step's S. Factorising every step afresh stays
/// the default. On the beam's gravity run (716 tets, BDF2 at 3 substeps) CG preconditioned with
/// Newton's kept factor to 10⁻¹⁰ cuts the factorisations from 1302 to 91 but takes 5.8
/// iterations a step (each a triangular solve and a product per column, where one
/// factorisation costs 0.7 ms) and leaves Newton without the converged factors it carries:
/// 1.44× the CPU of a direct-gradient evaluation. Loosened to 10⁻², with S refactorised after a
/// solve of more than one iteration and Newton carrying that factor, it takes 0.81× the CPU with
/// the Jacobian's columns within 2·10⁻⁴ (`palpate-lab bench motion-step`); an option
/// ([`KeptSolve`](super::sim::KeptSolve)), not the default: the adjoint method's solves run after
/// the forward run, where Newton cannot reuse them, and the direct and adjoint gradients would no
/// longer agree to round-off.
pub const DEFAULT_STEP_SOLVE: StepSolve = StepSolve::Fresh;

/// The process's step solve (see [`set_step_solve`]).
static STEP_SOLVE: std::sync::RwLock<StepSolve> = std::sync::RwLock::new(DEFAULT_STEP_SOLVE);

/// Sets how every gradient evaluation of this process that names no [`StepSolve`] solves the
/// step systems ([`evaluate`], [`evaluate_gauss_newton`] and the fits through them): a whole fit
/// can then be run under another solve without a setting threaded through the optimiser.
/// [`StepSolve::None`] restores [`DEFAULT_STEP_SOLVE`].
pub fn set_step_solve(solve: StepSolve) {
    let solve = match solve {
        StepSolve::None => step_solve(),
        other => other,
    };
    // A poisoned lock only means a panic elsewhere while it was held; the value is a plain copy.
    *STEP_SOLVE.write().unwrap_or_else(|e| e.into_inner()) = solve;
}

/// The step solve gradient evaluations use when their caller names none ([`set_step_solve`]).
pub fn step_solve() -> StepSolve {
    *STEP_SOLVE.read().unwrap_or_else(|e| e.into_inner())
}

/// How to compute the gradient.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// Direct sensitivity analysis (eqs. 5–6): one extra solve per step and parameter.
    Direct,
    /// Adjoint method (eqs. 8–12, 14): one backward solve per step; stores every step.
    Adjoint,
}

/// Result of one simulation (with or without gradient).
#[derive(Debug, Clone)]
pub struct Evaluation {
    /// Φ.
    pub phi: f64,
    /// dΦ/dq (linear parameters), when asked for.
    pub grad: Option<Vec<f64>>,
    /// RMS marker error √(Σ‖e‖²/count) = √(2Φ_m/(NT)) for complete data (m).
    pub rms_marker: f64,
    /// RMS force error over observed clamp forces (N).
    pub rms_force: f64,
    /// Newton counters.
    pub stats: SimStats,
    /// Bytes the gradient method kept (adjoint tape, or the direct method's sensitivities).
    pub stored_bytes: usize,
    /// Observed marker positions the RMS is over.
    pub marker_count: usize,
    /// Observed clamp forces the RMS is over.
    pub force_count: usize,
    /// The simulation's markers at every step and its last state: the run's readings without
    /// simulating it again ([`crate::predict::assess`]). `None` for evaluations combined over
    /// runs.
    pub simulated: Option<Simulated>,
}

impl Evaluation {
    /// The evaluation of several runs sharing one material: Φ and gradients add, the RMS errors
    /// are over all observations of all runs.
    pub fn combine(parts: &[Evaluation]) -> Evaluation {
        let pool = |rms: fn(&Evaluation) -> (f64, usize)| {
            let (sq, n) = parts
                .iter()
                .map(rms)
                .fold((0.0, 0), |(s, c), (r, n)| (s + r * r * n as f64, c + n));
            if n == 0 {
                0.0
            } else {
                (sq / n as f64).sqrt()
            }
        };
        let grad =
            parts
                .iter()
                .map(|p| p.grad.clone())
                .try_fold(Vec::<f64>::new(), |mut acc, g| {
                    let g = g?;
                    acc.resize(g.len(), 0.0);
                    acc.iter_mut().zip(&g).for_each(|(a, b)| *a += b);
                    Some(acc)
                });
        Evaluation {
            phi: parts.iter().map(|p| p.phi).sum(),
            grad: grad.filter(|_| !parts.is_empty()),
            rms_marker: pool(|p| (p.rms_marker, p.marker_count)),
            rms_force: pool(|p| (p.rms_force, p.force_count)),
            stats: SimStats {
                newton_iterations: parts.iter().map(|p| p.stats.newton_iterations).sum(),
                unconverged_steps: parts.iter().map(|p| p.stats.unconverged_steps).sum(),
                max_residual: parts
                    .iter()
                    .map(|p| p.stats.max_residual)
                    .fold(0.0, f64::max),
                factorisations: parts.iter().map(|p| p.stats.factorisations).sum(),
                cg_iterations: parts.iter().map(|p| p.stats.cg_iterations).sum(),
            },
            stored_bytes: parts.iter().map(|p| p.stored_bytes).max().unwrap_or(0),
            marker_count: parts.iter().map(|p| p.marker_count).sum(),
            force_count: parts.iter().map(|p| p.force_count).sum(),
            simulated: None,
        }
    }
}

/// Per element, the parameter index of each derivative slot (`usize::MAX` = not a parameter),
/// and which slots are active. Spline control values are global: every element maps them.
fn param_table(
    model: &Model,
    mat: &Material,
    params: &[Param],
) -> Result<(Vec<Vec<usize>>, Vec<bool>), MotionError> {
    mat.check_params(params)?;
    let ns = mat.slots();
    let mut t = vec![vec![usize::MAX; ns]; model.tets.len()];
    let mut kinds = vec![false; ns];
    // As `Material::set` writes them: a global material parameter in the elements outside the
    // regions that have that kind of their own, then the regions' and elements' own values.
    for global in [true, false] {
        for (p, par) in params.iter().enumerate() {
            if par.is_global() != global {
                continue;
            }
            let slot = par.slot(mat);
            kinds[slot] = true;
            match (par.element, par.region) {
                (Some(e), _) if !par.kind.is_spline() => t[e][slot] = p,
                (None, Some(r)) => mat.regions[r].iter().for_each(|&e| t[e][slot] = p),
                _ if par.kind.is_spline() => t.iter_mut().for_each(|r| r[slot] = p),
                _ => t
                    .iter_mut()
                    .zip(&mat.overridden(params, par.kind))
                    .filter(|(_, &i)| !i)
                    .for_each(|(r, _)| r[slot] = p),
            }
        }
    }
    Ok((t, kinds))
}

fn reduce(acc: &[Vec<f64>], table: &[Vec<usize>], grad: &mut [f64]) {
    for (e, row) in table.iter().enumerate() {
        for k in 0..row.len() {
            if row[k] != usize::MAX && !acc[k].is_empty() {
                grad[row[k]] += acc[k][e];
            }
        }
    }
}

fn finish(terms: &StepTerm, stats: SimStats, grad: Option<Vec<f64>>, stored: usize) -> Evaluation {
    let rms = |sq: f64, n: usize| if n == 0 { 0.0 } else { (sq / n as f64).sqrt() };
    Evaluation {
        phi: terms.phi,
        grad,
        rms_marker: rms(terms.marker_sq, terms.marker_count),
        rms_force: rms(terms.force_sq, terms.force_count),
        stats,
        stored_bytes: stored,
        marker_count: terms.marker_count,
        force_count: terms.force_count,
        simulated: None,
    }
}

fn add(t: &mut StepTerm, s: StepTerm) {
    t.phi += s.phi;
    t.marker_sq += s.marker_sq;
    t.marker_count += s.marker_count;
    t.force_sq += s.force_sq;
    t.force_count += s.force_count;
}

/// Adds step `s`'s term of Φ to `total` and its explicit parameter derivatives to `acc`;
/// returns ∂φ_n/∂x^n and ∂φ_n/∂v^n (free dofs).
fn observe_step(
    model: &Model,
    mat: &Material,
    obs: &Observations,
    s: &StepView<'_>,
    kinds: &[bool],
    total: &mut StepTerm,
    acc: &mut [Vec<f64>],
) -> Result<(Vec<f64>, Vec<f64>), MotionError> {
    let mut gx = vec![0.0; model.nfree];
    let mut gv = vec![0.0; model.nfree];
    add(
        total,
        step_term(
            model,
            mat,
            obs,
            s.n,
            s.x,
            s.v,
            kinds,
            Some((&mut gx, &mut gv, acc)),
        )?,
    );
    Ok((gx, gv))
}

/// Per-marker sums for the closed-form marker offsets of [`Observations::free_marker_offsets`]
/// (variable projection, Golub & Pereyra 1973): over each marker's observed steps the count N_i,
/// the residual sum s_i = Σ_n e_in and, where the sensitivities are carried, S_i = Σ_n J_in (a
/// 3-vector per parameter). With the offsets at their optimum ē_i = s_i / N_i,
/// Φ = Φ_raw − ½ w Σ_i ‖s_i‖²/N_i, ∇Φ = ∇Φ_raw − w Σ_i S_iᵀ ē_i and the Gauss–Newton matrix
/// H = H_raw − w Σ_i S_iᵀ S_i / N_i (w the marker term's weight times the observation
/// interval): the exact reduced problem, so a fit of the parameters alone reaches the joint
/// minimum over parameters and offsets.
struct MarkerMeans {
    count: Vec<usize>,
    e: Vec<[f64; 3]>,
    j: Vec<Vec<[f64; 3]>>,
}

impl MarkerMeans {
    fn new(markers: usize, np: usize) -> Self {
        Self {
            count: vec![0; markers],
            e: vec![[0.0; 3]; markers],
            j: vec![vec![[0.0; 3]; np]; markers],
        }
    }

    /// Adds the residuals e = x̄ − x* of step `n`'s observed markers at positions `x`.
    fn add_residuals(&mut self, model: &Model, obs: &Observations, n: usize, x: &[f64]) {
        let Some(row) = obs.markers.get(n - 1) else {
            return;
        };
        for (i, target) in row.iter().enumerate() {
            let Some(t) = target else { continue };
            let p = model.marker_position(&model.markers[i], x);
            self.count[i] += 1;
            for k in 0..3 {
                self.e[i][k] += p[k] - t[k];
            }
        }
    }

    /// Marker i's mean residual ē_i (`None` when it was never observed).
    fn mean(&self, i: usize) -> Option<[f64; 3]> {
        let n = self.count[i];
        (n > 0).then(|| self.e[i].map(|v| v / n as f64))
    }

    /// Φ and the marker sums of `total` with the offsets' part removed (weight `w`).
    fn project_terms(&self, total: &mut StepTerm, w: f64) {
        for (i, &n) in self.count.iter().enumerate() {
            if n > 0 {
                let sq = self.e[i].iter().map(|v| v * v).sum::<f64>() / n as f64;
                total.marker_sq -= sq;
                total.phi -= 0.5 * w * sq;
            }
        }
        // Round-off must not leave a negative sum of squares.
        total.marker_sq = total.marker_sq.max(0.0);
        total.phi = total.phi.max(0.0);
    }

    /// ∇Φ −= w Σ_i S_iᵀ ē_i.
    fn project_gradient(&self, grad: &mut [f64], w: f64) {
        for i in 0..self.count.len() {
            let Some(m) = self.mean(i) else { continue };
            for (g, j) in grad.iter_mut().zip(&self.j[i]) {
                *g -= w * (0..3).map(|k| j[k] * m[k]).sum::<f64>();
            }
        }
    }

    /// H −= w Σ_i S_iᵀ S_i / N_i (row-major, np × np).
    fn project_gauss_newton(&self, h: &mut [f64], w: f64) {
        for (i, &n) in self.count.iter().enumerate() {
            if n > 0 {
                add_outer(h, &self.j[i], -w / n as f64);
            }
        }
    }

    /// The adjoint's source term ∂Φ/∂x^n loses each observed marker's mean part:
    /// −w ē_i spread on the marker's nodes (free dofs).
    fn project_source(&self, model: &Model, obs: &Observations, n: usize, w: f64, gx: &mut [f64]) {
        let Some(row) = obs.markers.get(n - 1) else {
            return;
        };
        for (i, target) in row.iter().enumerate() {
            if target.is_none() {
                continue;
            }
            let Some(m) = self.mean(i) else { continue };
            for &(node, wa) in &model.markers[i].weights {
                for k in 0..3 {
                    let fr = model.free[3 * node + k];
                    if fr != usize::MAX {
                        gx[fr] -= w * m[k] * wa;
                    }
                }
            }
        }
    }
}

/// v^n − b (full dofs): the velocity term of the step's inertia c M (v^n − b).
fn inertia_velocity(s: &StepView<'_>) -> Vec<f64> {
    (0..s.v.len()).map(|d| s.v[d] - s.inertia_base[d]).collect()
}

/// Refuses observed clamp forces (with a weight) beside a creep branch: the clamp's reaction
/// ([`super::objective::clamp_force`]) sums the elements' elastic and viscous forces, and the
/// branch's stress is not among them.
fn refuse_creep_forces(mat: &Material, obs: &Observations) -> Result<(), MotionError> {
    if mat.has_creep()
        && obs.force_weight != 0.0
        && obs.forces.iter().flatten().any(Option::is_some)
    {
        return Err(MotionError::Invalid(
            "observed clamp forces with a creep branch: the reaction force does not carry the \
             branch's stress; fit the markers alone (force weight 0) or the model without creep"
                .into(),
        ));
    }
    Ok(())
}

/// Simulates with material `mat` (parameters already applied) and evaluates Φ and, if
/// `method` is given, dΦ/dq for `params`.
pub fn evaluate(
    model: &Model,
    mat: &Material,
    params: &[Param],
    obs: &Observations,
    method: Option<Method>,
) -> Result<Evaluation, MotionError> {
    let (all, ties) = with_ties(mat, params)?;
    let mut ev = in_pool(|| evaluate_here(model, mat, &all, obs, method))?;
    if let Some(g) = ev.grad.as_mut() {
        fold_gradient(g, params.len(), &ties);
    }
    Ok(ev)
}

/// The parameters evaluated for `params` on `mat`: its own, then each λ that follows some of
/// them ([`Material::ties`]), whose derivative is folded into theirs by the chain rule,
/// dΦ/dq|tied = ∂Φ/∂q + (∂λ/∂q) ∂Φ/∂λ ([`fold_gradient`], [`fold_gauss_newton`]).
fn with_ties(mat: &Material, params: &[Param]) -> Result<(Vec<Param>, Vec<Tie>), MotionError> {
    let ties = mat.ties(params)?;
    let all = params
        .iter()
        .copied()
        .chain(ties.iter().map(|t| t.lambda))
        .collect();
    Ok((all, ties))
}

/// The gradient over `params` and their tied λs folded onto the first `np` ([`with_ties`]).
fn fold_gradient(g: &mut Vec<f64>, np: usize, ties: &[Tie]) {
    for (t, dl) in ties.iter().zip(g.split_off(np)) {
        for &(i, w) in &t.weights {
            g[i] += w * dl;
        }
    }
}

/// The Gauss–Newton matrix over `params` and their tied λs (row-major, `np + ties.len()`
/// square) folded onto the first `np`: Tᵀ H T, T the identity on the parameters with each
/// tied λ's row carrying its weights.
fn fold_gauss_newton(h: &[f64], np: usize, ties: &[Tie]) -> Vec<f64> {
    if ties.is_empty() {
        return h.to_vec();
    }
    let na = np + ties.len();
    // The evaluated index i reaches the fitted indices `into(i)` with their weights T[i][a].
    let own: Vec<Vec<(usize, f64)>> = (0..np).map(|i| vec![(i, 1.0)]).collect();
    let into = |i: usize| -> &[(usize, f64)] {
        match i.checked_sub(np) {
            None => &own[i],
            Some(k) => &ties[k].weights,
        }
    };
    let mut out = vec![0.0; np * np];
    for i in 0..na {
        for &(a, wa) in into(i) {
            for j in 0..na {
                for &(b, wb) in into(j) {
                    out[a * np + b] += wa * h[i * na + j] * wb;
                }
            }
        }
    }
    out
}

/// Runs `op` on a worker of rayon's pool (at once when called from one): the element passes
/// split their halves with `rayon::join`, which from a thread outside the pool hands both halves
/// to the pool and blocks on a lock — a wake-up per pass, hundreds per simulation — while inside
/// it the second half is merely offered to the other worker.
fn in_pool<R: Send>(op: impl FnOnce() -> R + Send) -> R {
    if rayon::current_thread_index().is_some() {
        op()
    } else {
        rayon::scope(|_| op())
    }
}

fn evaluate_here(
    model: &Model,
    mat: &Material,
    params: &[Param],
    obs: &Observations,
    method: Option<Method>,
) -> Result<Evaluation, MotionError> {
    refuse_creep_forces(mat, obs)?;
    match method {
        None => {
            let mut total = StepTerm::default();
            let mut means = obs
                .free_marker_offsets
                .then(|| MarkerMeans::new(model.markers.len(), 0));
            let mut simulated = Simulated::default();
            let stats = simulate_states(model, mat, |s| {
                add(
                    &mut total,
                    step_term(model, mat, obs, s.n, s.x, s.v, &[], None)?,
                );
                if let Some(m) = means.as_mut() {
                    m.add_residuals(model, obs, s.n, s.x);
                }
                simulated.record(model, s.n, s.x);
                Ok(())
            })?;
            if let Some(m) = &means {
                m.project_terms(&mut total, obs.marker_weight * model.observation_interval());
            }
            Ok(Evaluation {
                simulated: Some(simulated),
                ..finish(&total, stats, None, 0)
            })
        }
        Some(Method::Direct) => {
            direct(model, mat, params, obs, false, step_solve()).map(|(e, _)| e)
        }
        Some(Method::Adjoint) => adjoint(model, mat, params, obs, step_solve()),
    }
}

/// Φ, dΦ/dq and the Gauss–Newton matrix H = Σ_n Δt w_m Σ_i J_inᵀ J_in of the marker term
/// (row-major, `params.len()`²), J_in = ∂x̄_i(x^n)/∂q the marker's sensitivity — from the
/// direct sensitivities (eqs. 5–6), which carry every state derivative the step needs anyway.
/// H is the exact Hessian of Φ without its second-order residual terms, so Levenberg–Marquardt
/// on it takes Newton-like steps on a least-squares fit ([`super::optimize`]). The clamp-force
/// term is not in H: a caller with observed forces uses the gradient alone (LBFGS).
pub fn evaluate_gauss_newton(
    model: &Model,
    mat: &Material,
    params: &[Param],
    obs: &Observations,
) -> Result<(Evaluation, Vec<f64>), MotionError> {
    evaluate_gauss_newton_with(model, mat, params, obs, step_solve())
}

/// [`evaluate_gauss_newton`] with the sensitivity systems solved as `solve` says
/// ([`StepSolve::Fresh`] or [`StepSolve::Kept`]; [`StepSolve::None`] is taken as
/// [`step_solve`]).
pub fn evaluate_gauss_newton_with(
    model: &Model,
    mat: &Material,
    params: &[Param],
    obs: &Observations,
    solve: StepSolve,
) -> Result<(Evaluation, Vec<f64>), MotionError> {
    let (all, ties) = with_ties(mat, params)?;
    let (mut ev, h) = in_pool(|| direct(model, mat, &all, obs, true, solve))?;
    if let Some(g) = ev.grad.as_mut() {
        fold_gradient(g, params.len(), &ties);
    }
    let h = h.map_or_else(Vec::new, |h| fold_gauss_newton(&h, params.len(), &ties));
    Ok((ev, h))
}

fn zeros_acc(kinds: &[bool], ne: usize) -> Vec<Vec<f64>> {
    kinds
        .iter()
        .map(|&k| if k { vec![0.0; ne] } else { Vec::new() })
        .collect()
}

/// A lock that a panic on the other thread does not poison for this one (that panic is resumed
/// where the threads join).
fn lock<T>(m: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The two halves of an element pass side by side on rayon's pool, or one after the other on a
/// thread outside it (the step observer of [`simulate_pipelined`], whose pass would otherwise
/// wait, idle, for a worker of the pool to take it). The same sums either way.
fn join_halves<A: Send, B: Send>(
    a: impl FnOnce() -> A + Send,
    b: impl FnOnce() -> B + Send,
) -> (A, B) {
    if rayon::current_thread_index().is_some() {
        rayon::join(a, b)
    } else {
        (a(), b())
    }
}

/// The split point of an element pass: meshes of at least
/// [`forces::SPLIT_ASSEMBLY_ELEMENTS`](super::forces) elements run it in two halves side by side
/// (`rayon::join`), as the force assembly does; below that, one pass (the split index is the
/// element count).
fn element_split(model: &Model) -> usize {
    let ne = model.tets.len();
    if ne >= SPLIT_ASSEMBLY_ELEMENTS {
        ne / 2
    } else {
        ne
    }
}

/// Largest number of GMRES iterations of [`solve_with_skew`] per column.
const SKEW_ITERATIONS: usize = 80;

/// The relative residual at which [`solve_with_skew`] stops: far below what the Newton
/// tolerance leaves in the sensitivities (finite differences agree with them to 10⁻⁷).
const SKEW_TOLERANCE: f64 = 1e-10;

/// Fixed-point iterations [`solve_with_skew`] tries on all columns at once before GMRES.
const SKEW_FIXED_POINT: usize = 8;

/// Solves (S + a_x A) Y = B in place for `np` columns, where S (the step's symmetric system
/// matrix, `solver`) holds the symmetric part of the objective viscosity's position tangent and
/// A = ½(K_v − K_vᵀ) the rest ([`ViscousSkew`]), on the left-preconditioned system
/// (I + a_x S⁻¹A) Y = S⁻¹B from Y = S⁻¹B. Where a_x S⁻¹A is small (a stiff step matrix) the
/// fixed-point iteration Y ← S⁻¹(B − a_x A Y) ends in two or three multi-column solves; where
/// it does not converge in [`SKEW_FIXED_POINT`] (a soft material, a viscous stiffness a large
/// part of the step's matrix) GMRES (Saad & Schultz 1986) takes each column from there, one
/// product with A and one solve with S's factor an iteration, to a relative residual of
/// [`SKEW_TOLERANCE`]. One that does not reach it is an error, not a silent approximation.
fn solve_with_skew(
    model: &Model,
    skew: &ViscousSkew,
    ax: f64,
    solver: &StepSolver,
    b: &mut [f64],
    np: usize,
) -> Result<(), MotionError> {
    let n = model.nfree;
    solver.solve_columns(&model.pattern, b, np)?;
    let pre = b.to_vec();
    let norm = |v: &[f64]| v.iter().map(|z| z * z).sum::<f64>().sqrt();
    let mut last_change = f64::INFINITY;
    for _ in 0..SKEW_FIXED_POINT {
        let mut w = vec![0.0; n * np];
        skew.mul_add(model, b, np, ax, &mut w);
        solver.solve_columns(&model.pattern, &mut w, np)?;
        let next: Vec<f64> = pre.iter().zip(&w).map(|(p, c)| p - c).collect();
        let change = next
            .iter()
            .zip(b.iter())
            .map(|(a, c)| (a - c) * (a - c))
            .sum::<f64>()
            .sqrt();
        let size = norm(&next);
        let finite = next.iter().all(|z| z.is_finite());
        if finite {
            b.copy_from_slice(&next);
        }
        // A contraction by ρ leaves at most ρ/(1 − ρ) times the last change in the iterate
        // (ρ estimated by the ratio of the last two changes): one solve less than waiting for
        // the change itself to fall below the tolerance.
        let rho = change / last_change;
        let left = if rho < 0.5 {
            change * rho / (1.0 - rho)
        } else {
            change
        };
        if finite && left <= SKEW_TOLERANCE * size {
            return Ok(());
        }
        last_change = change;
        if !finite || change > size {
            // Diverging: a_x S⁻¹A is not small here.
            break;
        }
    }
    let apply = |v: &[f64]| -> Result<Vec<f64>, MotionError> {
        let mut w = vec![0.0; n];
        skew.mul_add(model, v, 1, ax, &mut w);
        solver.solve_columns(&model.pattern, &mut w, 1)?;
        Ok(v.iter().zip(&w).map(|(a, c)| a + c).collect())
    };
    for (col, rhs) in b.chunks_exact_mut(n).zip(pre.chunks_exact(n)).take(np) {
        let start = if col.iter().all(|z| z.is_finite()) {
            col.to_vec()
        } else {
            rhs.to_vec()
        };
        let y = gmres(&apply, rhs, start)?;
        col.copy_from_slice(&y);
    }
    Ok(())
}

/// GMRES for T y = `rhs` from `x0`, T applied by `apply`, without restarts, to a residual of
/// [`SKEW_TOLERANCE`] ‖rhs‖ in at most [`SKEW_ITERATIONS`] iterations (Givens rotations on the
/// Hessenberg matrix, modified Gram–Schmidt).
fn gmres(
    apply: &dyn Fn(&[f64]) -> Result<Vec<f64>, MotionError>,
    rhs: &[f64],
    x0: Vec<f64>,
) -> Result<Vec<f64>, MotionError> {
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let norm = |a: &[f64]| dot(a, a).sqrt();
    let target = SKEW_TOLERANCE * norm(rhs).max(f64::MIN_POSITIVE);
    let t0 = apply(&x0)?;
    let r0: Vec<f64> = rhs.iter().zip(&t0).map(|(a, c)| a - c).collect();
    let beta = norm(&r0);
    if beta <= target {
        return Ok(x0);
    }
    let m = SKEW_ITERATIONS;
    let mut basis = vec![r0.iter().map(|z| z / beta).collect::<Vec<f64>>()];
    let mut h = vec![vec![0.0; m]; m + 1];
    let (mut cs, mut sn) = (vec![0.0; m], vec![0.0; m]);
    let mut g = vec![0.0; m + 1];
    g[0] = beta;
    let mut k = 0;
    while k < m {
        let j = k;
        let mut w = apply(&basis[j])?;
        for (i, v) in basis.iter().enumerate() {
            h[i][j] = dot(&w, v);
            w.iter_mut().zip(v).for_each(|(a, c)| *a -= h[i][j] * c);
        }
        let next = norm(&w);
        h[j + 1][j] = next;
        for i in 0..j {
            let t = cs[i] * h[i][j] + sn[i] * h[i + 1][j];
            h[i + 1][j] = -sn[i] * h[i][j] + cs[i] * h[i + 1][j];
            h[i][j] = t;
        }
        let r = h[j][j].hypot(h[j + 1][j]);
        if r == 0.0 || !r.is_finite() {
            break;
        }
        (cs[j], sn[j]) = (h[j][j] / r, h[j + 1][j] / r);
        h[j][j] = r;
        h[j + 1][j] = 0.0;
        g[j + 1] = -sn[j] * g[j];
        g[j] *= cs[j];
        k = j + 1;
        if g[k].abs() <= target || next == 0.0 {
            break;
        }
        basis.push(w.iter().map(|z| z / next).collect());
    }
    if g[k].abs().is_nan() || g[k].abs() > target {
        return Err(MotionError::Invalid(format!(
            "the sensitivities under the objective viscosity did not converge in {k} GMRES \
             iterations (residual {:.1e} of the right-hand side's)",
            g[k].abs() / (target / SKEW_TOLERANCE)
        )));
    }
    let mut y = vec![0.0; k];
    for i in (0..k).rev() {
        let s: f64 = (i + 1..k).map(|l| h[i][l] * y[l]).sum();
        y[i] = (g[i] - s) / h[i][i];
    }
    let mut x = x0;
    for (yi, v) in y.iter().zip(&basis) {
        x.iter_mut().zip(v).for_each(|(a, c)| *a += yi * c);
    }
    Ok(x)
}

/// G_p (free dofs) for every parameter at a state: ∂F/∂q of the residual's force part. The two
/// halves of the elements ([`element_split`]) scatter into their own columns, added afterwards:
/// the split depends on the mesh only, so the result is the same wherever the halves ran.
fn g_columns(
    model: &Model,
    mat: &Material,
    table: &[Vec<usize>],
    kinds: &[bool],
    np: usize,
    x: &[f64],
    v: &[f64],
    inertia: Option<(f64, &[f64])>,
) -> Result<Vec<Vec<f64>>, MotionError> {
    let part = |range: std::ops::Range<usize>| -> Result<Vec<Vec<f64>>, MotionError> {
        let mut g = vec![vec![0.0; model.nfree]; np];
        param_derivatives(model, mat, kinds, x, v, inertia, range, |e, kind, ge| {
            let p = table[e][kind];
            if p == usize::MAX {
                return;
            }
            for (a, &node) in model.tets[e].iter().enumerate() {
                for i in 0..3 {
                    let fr = model.free[3 * node + i];
                    if fr != usize::MAX {
                        g[p][fr] += ge[3 * a + i];
                    }
                }
            }
        })?;
        Ok(g)
    };
    let (ne, half) = (model.tets.len(), element_split(model));
    let mut g = if half == ne {
        part(0..ne)?
    } else {
        let (first, second) = join_halves(|| part(0..half), || part(half..ne));
        let (mut g, g2) = (first?, second?);
        for (col, col2) in g.iter_mut().zip(&g2) {
            col.iter_mut().zip(col2).for_each(|(a, b)| *a += b);
        }
        g
    };
    // The hanging weights' share of the gravity's turn, at their nodes (a global parameter:
    // any element's entry of the table names it).
    weight_derivatives(model, mat, kinds, |kind, node, d| {
        let p = table.first().map_or(usize::MAX, |row| row[kind]);
        if p == usize::MAX {
            return;
        }
        for (i, di) in d.iter().enumerate() {
            let fr = model.free[3 * node + i];
            if fr != usize::MAX {
                g[p][fr] += di;
            }
        }
    });
    Ok(g)
}

/// acc\[kind\]\[e\] += λ_eᵀ ∂F_e/∂q_kind for every element at a state (λ a full-dof vector): the
/// adjoint's parameter terms. The two halves of the elements ([`element_split`]) run side by
/// side, each writing only its own elements' entries, so every sum is the same to the last bit
/// wherever the halves ran; an inverted element of the first half is the error reported.
fn add_param_dots(
    model: &Model,
    mat: &Material,
    kinds: &[bool],
    x: &[f64],
    v: &[f64],
    inertia: Option<(f64, &[f64])>,
    lambda: &[f64],
    acc: &mut [Vec<f64>],
) -> Result<(), MotionError> {
    let (ne, half) = (model.tets.len(), element_split(model));
    let (first, second): (Vec<&mut [f64]>, Vec<&mut [f64]>) = acc
        .iter_mut()
        .map(|a| {
            if a.is_empty() {
                (&mut [] as &mut [f64], &mut [] as &mut [f64])
            } else {
                a.split_at_mut(half)
            }
        })
        .unzip();
    let pass = |range: std::ops::Range<usize>, mut part: Vec<&mut [f64]>| {
        let start = range.start;
        param_derivatives(model, mat, kinds, x, v, inertia, range, |e, kind, g| {
            part[kind][e - start] += element_dot(model, e, lambda, g)
        })
    };
    if half == ne {
        pass(0..ne, first)?;
    } else {
        let (a, b) = join_halves(|| pass(0..half, first), || pass(half..ne, second));
        a.and(b)?;
    }
    // The hanging weights' share of the gravity's turn, on element 0's entry: the turn is a
    // global parameter, whose gradient sums every element's.
    weight_derivatives(model, mat, kinds, |kind, node, d| {
        if let Some(first) = acc[kind].first_mut() {
            *first += (0..3).map(|i| lambda[3 * node + i] * d[i]).sum::<f64>();
        }
    });
    Ok(())
}

/// What both gradient methods start from: the parameter table, the sizes, the scheme's
/// constants (c, a_x, a_v) ([`Scheme::coefficients`]), and M on the free pattern.
struct Setup {
    table: Vec<Vec<usize>>,
    kinds: Vec<bool>,
    np: usize,
    nf: usize,
    ndof: usize,
    c: f64,
    ax: f64,
    av: f64,
    mvals: Vec<f64>,
}

impl Setup {
    fn new(model: &Model, mat: &Material, params: &[Param]) -> Result<Self, MotionError> {
        let (table, kinds) = param_table(model, mat, params)?;
        let (c, ax, av) = model.scheme_for(mat).coefficients(model.dt);
        Ok(Self {
            table,
            kinds,
            np: params.len(),
            nf: model.nfree,
            ndof: 3 * model.nodes.len(),
            c,
            ax,
            av,
            mvals: model.mass_values(mat),
        })
    }
}

/// λ_eᵀ g: a full-dof vector restricted to element `e`'s nodes, dotted with a 12-vector.
fn element_dot(model: &Model, e: usize, full: &[f64], g: &[f64; 12]) -> f64 {
    let mut s = 0.0;
    for (a, &node) in model.tets[e].iter().enumerate() {
        for k in 0..3 {
            s += full[3 * node + k] * g[3 * a + k];
        }
    }
    s
}

/// h += w Σ_k j_p[k] j_q[k] for the residual rows `j` (one 3-vector per parameter).
fn add_outer(h: &mut [f64], j: &[[f64; 3]], w: f64) {
    let np = j.len();
    for p in 0..np {
        for q in 0..=p {
            let d = w * (0..3).map(|k| j[p][k] * j[q][k]).sum::<f64>();
            h[p * np + q] += d;
            if q != p {
                h[q * np + p] += d;
            }
        }
    }
}

/// dF_c/dq of clamp `c`'s reaction force (see [`super::objective::clamp_force`]) along the
/// state sensitivities s_x, s_v (free dofs, one per parameter): ∂F/∂x s_x + ∂F/∂v s_v + ∂F/∂q,
/// with ∂F_c/∂x = K_e and ∂F_c/∂v = D_e on the clamp's rows, as the objective's own gradient.
#[allow(clippy::too_many_arguments)]
fn clamp_force_jacobian(
    model: &Model,
    mat: &Material,
    table: &[Vec<usize>],
    kinds: &[bool],
    np: usize,
    c: usize,
    s: &StepView<'_>,
    sx: &[Vec<f64>],
    sv: &[Vec<f64>],
) -> Result<Vec<[f64; 3]>, MotionError> {
    let mut j = vec![[0.0; 3]; np];
    let mut explicit = vec![[0.0; 3]; np];
    clamp_force_derivatives(
        model,
        mat,
        kinds,
        c,
        s.x,
        s.v,
        |i, fr, k, d| {
            for (p, jp) in j.iter_mut().enumerate() {
                jp[i] += k * sx[p][fr] + d * sv[p][fr];
            }
        },
        |el, kind, i, g| {
            let p = table[el][kind];
            if p != usize::MAX {
                explicit[p][i] += g;
            }
        },
    )?;
    for (jp, ep) in j.iter_mut().zip(&explicit) {
        for i in 0..3 {
            jp[i] += ep[i];
        }
    }
    Ok(j)
}

/// The direct method; with `gauss_newton` it also sums the marker term's Gauss–Newton matrix
/// (see [`evaluate_gauss_newton`]).
fn direct(
    model: &Model,
    mat: &Material,
    params: &[Param],
    obs: &Observations,
    gauss_newton: bool,
    solve: StepSolve,
) -> Result<(Evaluation, Option<Vec<f64>>), MotionError> {
    let Setup {
        table,
        kinds,
        np,
        nf,
        ndof,
        c,
        ax,
        av,
        mvals,
    } = Setup::new(model, mat, params)?;
    let (scheme, dt) = (model.scheme_for(mat), model.dt);
    let two = scheme.two_step();
    let (hist_a0, hist_a1, hist_e) = two.force_history(dt);
    // s_x⁰ from the elastostatic start (§3.4): K₀ s_x⁰ = ∂f₀/∂q; zero for a rest-shape start.
    // Shared by the start (on the simulation's thread) and the steps (on the observer's,
    // `simulate_pipelined`): a lock, taken once at each end.
    let init: std::sync::Mutex<Option<Result<Vec<Vec<f64>>, MotionError>>> =
        std::sync::Mutex::new(None);
    let mut state: Option<(Vec<Vec<f64>>, Vec<Vec<f64>>, Vec<Vec<f64>>, Vec<Vec<f64>>)> = None;
    let mut total = StepTerm::default();
    let mut grad = vec![0.0; np];
    let mut acc = zeros_acc(&kinds, model.tets.len());
    let mut h = gauss_newton.then(|| vec![0.0; np * np]);
    if mat.has_creep() {
        CreepSensitivities::check(mat)?;
        refuse_creep_forces(mat, obs)?;
    }
    // The start positions, kept for the creep branch's start (its S⁰ and dS⁰ at x⁰).
    let creep_x0: std::sync::Mutex<Option<Vec<f64>>> = std::sync::Mutex::new(None);
    let mut creep: Option<CreepSensitivities> = None;
    let mut means = obs
        .free_marker_offsets
        .then(|| MarkerMeans::new(model.markers.len(), np));
    let wdt = obs.marker_weight * model.observation_interval();
    let wf = obs.force_weight * model.observation_interval();
    let mut simulated = Simulated::default();
    let solve = match solve {
        StepSolve::None => step_solve(),
        other => other,
    };
    let stats = simulate_pipelined(
        model,
        mat,
        solve,
        |x0, k0| {
            if mat.has_creep() {
                *lock(&creep_x0) = Some(x0.to_vec());
            }
            let r = match k0 {
                Some(k0) => g_columns(model, mat, &table, &kinds, np, x0, &vec![0.0; ndof], None)
                    .map(|g| {
                        g.into_iter()
                            .map(|mut col| {
                                k0.solve_in_place(&mut col);
                                col
                            })
                            .collect()
                    }),
                None => Ok(vec![vec![0.0; nf]; np]),
            };
            *lock(&init) = Some(r);
        },
        |s| {
            if state.is_none() {
                let sx0 = lock(&init)
                    .take()
                    .unwrap_or_else(|| Ok(vec![vec![0.0; nf]; np]))?;
                if let Some(x0) = lock(&creep_x0).take() {
                    creep = Some(CreepSensitivities::start(model, mat, &table, &x0, &sx0)?);
                }
                state = Some((
                    sx0.clone(),
                    sx0,
                    vec![vec![0.0; nf]; np],
                    vec![vec![0.0; nf]; np],
                ));
            }
            let (sxm1, sxm2, svm1, svm2) = state.as_mut().expect("initialised");
            let vb = inertia_velocity(s);
            let [xf, vf] = s.force_state;
            let g = g_columns(model, mat, &table, &kinds, np, xf, vf, Some((c, &vb)))?;
            let solver = s.solver.expect("solves requested");
            let (gx, gv) = observe_step(model, mat, obs, s, &kinds, &mut total, &mut acc)?;
            simulated.record(model, s.n, s.x);
            // Every parameter's sensitivity step at once, column after column: the history
            // parts s_xa, s_b (and the midpoint's s_va), then S s_v = g + c M s_b − K s_xa
            // (− D s_va) in one pass over the pattern and one multi-column solve, then s_x.
            let mut sa = vec![0.0; nf * np];
            let mut sb = vec![0.0; nf * np];
            let mut sva = match scheme {
                Scheme::Bdf2 => Vec::new(),
                Scheme::Midpoint | Scheme::Alpha => vec![0.0; nf * np],
            };
            let mut rhs = vec![0.0; nf * np];
            for p in 0..np {
                let o = p * nf;
                for i in 0..nf {
                    match scheme {
                        Scheme::Bdf2 => {
                            sa[o + i] = (4.0 * sxm1[p][i] - sxm2[p][i]) / 3.0;
                            sb[o + i] = (4.0 * svm1[p][i] - svm2[p][i]) / 3.0;
                        }
                        Scheme::Midpoint => {
                            sa[o + i] = sxm1[p][i] + ax * svm1[p][i];
                            sb[o + i] = svm1[p][i];
                            sva[o + i] = av * svm1[p][i];
                        }
                        Scheme::Alpha => {
                            let hist_v = two.beta[1] * svm1[p][i] + two.beta[0] * svm2[p][i];
                            sa[o + i] =
                                hist_a1 * sxm1[p][i] + hist_a0 * sxm2[p][i] + hist_e * hist_v;
                            sb[o + i] = -(two.alpha[1] * svm1[p][i] + two.alpha[0] * svm2[p][i])
                                / two.alpha[2];
                            sva[o + i] = hist_v;
                        }
                    }
                }
                rhs[o..o + nf].copy_from_slice(&g[p]);
            }
            model
                .pattern
                .mul_add_difference((c, &mvals, &sb), (s.k, &sa), &mut rhs, np);
            if !sva.is_empty() {
                model
                    .pattern
                    .mul_add_difference((0.0, &mvals, &sva), (s.d, &sva), &mut rhs, np);
            }
            if let (Some(cs), Some((branch, _))) = (creep.as_mut(), s.relaxation) {
                cs.add_history(model, mat, &table, branch, xf, np, &mut rhs)?;
            }
            // K's antisymmetric part under the objective viscosity, which S's symmetric values
            // do not hold: in the history term, and in S itself by `solve_with_skew`.
            match ViscousSkew::at(model, mat, xf, vf)? {
                Some(skew) => {
                    skew.mul_add(model, &sa, np, -1.0, &mut rhs);
                    solve_with_skew(model, &skew, ax, solver, &mut rhs, np)?;
                }
                None => solver.solve_columns(&model.pattern, &mut rhs, np)?,
            }
            // The creep branch advances at the force state: its sensitivity s_xa + a_x s_v.
            let sxf: Vec<Vec<f64>> = match &creep {
                None => Vec::new(),
                Some(_) => (0..np)
                    .map(|p| {
                        (0..nf)
                            .map(|i| sa[p * nf + i] + ax * rhs[p * nf + i])
                            .collect()
                    })
                    .collect(),
            };
            for p in 0..np {
                let o = p * nf;
                let sv = &rhs[o..o + nf];
                let sxn: Vec<f64> = match scheme {
                    Scheme::Bdf2 => (0..nf).map(|i| sa[o + i] + ax * sv[i]).collect(),
                    Scheme::Midpoint => (0..nf)
                        .map(|i| sxm1[p][i] + 0.5 * dt * (svm1[p][i] + sv[i]))
                        .collect(),
                    Scheme::Alpha => (0..nf)
                        .map(|i| {
                            two.position(
                                dt,
                                [sxm2[p][i], sxm1[p][i]],
                                [svm2[p][i], svm1[p][i], sv[i]],
                            )
                        })
                        .collect(),
                };
                grad[p] += (0..nf).map(|i| gx[i] * sxn[i] + gv[i] * sv[i]).sum::<f64>();
                sxm2[p] = std::mem::replace(&mut sxm1[p], sxn);
                let mut svn = std::mem::take(&mut svm2[p]);
                svn.copy_from_slice(sv);
                svm2[p] = std::mem::replace(&mut svm1[p], svn);
            }
            if let (Some(cs), Some((branch, after))) = (creep.as_mut(), s.relaxation) {
                cs.advance(model, &table, branch, after, &sxf);
            }
            if let Some(m) = means.as_mut() {
                m.add_residuals(model, obs, s.n, s.x);
            }
            let wants_j = h.is_some() || means.is_some();
            if let (true, Some(row)) = (wants_j, obs.markers.get(s.n - 1)) {
                // J_in = Σ_a w_a s_x(node a) for each observed marker (clamped dofs: zero).
                let mut js = vec![[0.0; 3]; np];
                for (i, target) in row.iter().enumerate() {
                    if target.is_none() {
                        continue;
                    }
                    for (p, j) in js.iter_mut().enumerate() {
                        *j = [0.0; 3];
                        for &(node, w) in &model.markers[i].weights {
                            for (k, jk) in j.iter_mut().enumerate() {
                                let fr = model.free[3 * node + k];
                                if fr != usize::MAX {
                                    *jk += w * sxm1[p][fr];
                                }
                            }
                        }
                    }
                    if let Some(h) = h.as_mut() {
                        add_outer(h, &js, wdt);
                    }
                    if let Some(m) = means.as_mut() {
                        for (acc, j) in m.j[i].iter_mut().zip(&js) {
                            for k in 0..3 {
                                acc[k] += j[k];
                            }
                        }
                    }
                }
            }
            if let (Some(h), Some(row)) = (h.as_mut(), obs.forces.get(s.n - 1)) {
                for (c, target) in row.iter().enumerate() {
                    if target.is_some() {
                        let jf = clamp_force_jacobian(
                            model,
                            mat,
                            &table,
                            &kinds,
                            np,
                            c,
                            s,
                            &sxm1[..],
                            &svm1[..],
                        )?;
                        add_outer(h, &jf, wf);
                    }
                }
            }
            Ok(())
        },
    )?;
    reduce(&acc, &table, &mut grad);
    if let Some(m) = &means {
        m.project_terms(&mut total, wdt);
        m.project_gradient(&mut grad, wdt);
        if let Some(h) = h.as_mut() {
            m.project_gauss_newton(h, wdt);
        }
    }
    let ev = Evaluation {
        simulated: Some(simulated),
        ..finish(&total, stats, Some(grad), 4 * np * nf * 8)
    };
    Ok((ev, h))
}

struct TapeStep {
    /// Solves with the step's S (symmetric: the backward solve of eq. 12 is the same).
    solver: StepSolver,
    k: Vec<f64>,
    /// D values (the midpoint rule's history term; empty for BDF2).
    d: Vec<f64>,
    /// The force state (x_f, v_f) and the inertia velocity v^n − b (full dofs).
    x: Vec<f64>,
    v: Vec<f64>,
    vb: Vec<f64>,
    gx: Vec<f64>,
    gv: Vec<f64>,
}

fn adjoint(
    model: &Model,
    mat: &Material,
    params: &[Param],
    obs: &Observations,
    solve: StepSolve,
) -> Result<Evaluation, MotionError> {
    if mat.viscous_form == Form::Objective {
        return Err(MotionError::Invalid(
            "the adjoint gradient solves with S's symmetric values, which do not hold the \
             objective viscosity's position tangent: use the direct method \
             (Levenberg–Marquardt's, or --gradient direct)"
                .into(),
        ));
    }
    if mat.has_creep() {
        return Err(MotionError::Invalid(
            "the adjoint gradient does not carry the creep branch's internal variables: use the \
             direct method (Levenberg–Marquardt's, or --gradient direct)"
                .into(),
        ));
    }
    let solve = match solve {
        StepSolve::None => step_solve(),
        other => other,
    };
    let Setup {
        table,
        kinds,
        np,
        nf,
        ndof,
        c,
        ax,
        av,
        mvals,
    } = Setup::new(model, mat, params)?;
    let (scheme, dt) = (model.scheme_for(mat), model.dt);
    let two = scheme.two_step();
    let (hist_a0, hist_a1, hist_e) = two.force_history(dt);
    let mut acc = zeros_acc(&kinds, model.tets.len());
    let mut total = StepTerm::default();
    let mut start: Option<(Vec<f64>, Option<Factor>)> = None;
    let mut tape: Vec<TapeStep> = Vec::with_capacity(model.steps);
    let mut simulated = Simulated::default();
    let mut means = obs
        .free_marker_offsets
        .then(|| MarkerMeans::new(model.markers.len(), 0));
    let mut stats = simulate_solving(
        model,
        mat,
        solve,
        |x0, k0| start = Some((x0.to_vec(), k0.cloned())),
        |s| {
            let (gx, gv) = observe_step(model, mat, obs, s, &kinds, &mut total, &mut acc)?;
            if let Some(m) = means.as_mut() {
                m.add_residuals(model, obs, s.n, s.x);
            }
            simulated.record(model, s.n, s.x);
            let vb = inertia_velocity(s);
            tape.push(TapeStep {
                solver: s.solver.expect("solves requested").clone(),
                k: s.k.to_vec(),
                d: match scheme {
                    Scheme::Bdf2 => Vec::new(),
                    Scheme::Midpoint | Scheme::Alpha => s.d.to_vec(),
                },
                x: s.force_state[0].to_vec(),
                v: s.force_state[1].to_vec(),
                vb,
                gx,
                gv,
            });
            Ok(())
        },
    )?;
    // Steps share their preconditioning factors: count each once.
    let mut factors: Vec<&Factor> = Vec::new();
    for t in &tape {
        let f = t.solver.preconditioner();
        if !factors.iter().any(|g| g.shares_values(f)) {
            factors.push(f);
        }
    }
    let stored = tape.len() * 8 * (model.pattern.nnz() + 3 * ndof + 2 * nf)
        + tape
            .iter()
            .map(|t| 8 * t.d.len() + t.solver.value_bytes())
            .sum::<usize>()
        + (factors.len() + 1) * model.pattern.factor_bytes();
    drop(factors);
    // Backward pass. X[n], V[n] accumulate dΦ/ds_x^n, dΦ/ds_v^n (index shift +1 for n = −1).
    let nsteps = tape.len();
    let mut xs = vec![vec![0.0; nf]; nsteps + 2];
    let mut vs = vec![vec![0.0; nf]; nsteps + 2];
    let wdt = obs.marker_weight * model.observation_interval();
    for (i, t) in tape.iter().enumerate() {
        xs[i + 2].copy_from_slice(&t.gx);
        vs[i + 2].copy_from_slice(&t.gv);
        if let Some(m) = &means {
            m.project_source(model, obs, i + 1, wdt, &mut xs[i + 2]);
        }
    }
    if let Some(m) = &means {
        m.project_terms(&mut total, wdt);
    }
    // A backward solve that had to factorise S hands its fresh factor on to the earlier steps
    // that were handed the same stale one, as the forward solves do.
    let mut refresh: Option<(Factor, Factor)> = None;
    for n in (1..=nsteps).rev() {
        let t = &tape[n - 1];
        let j = n + 1; // storage index of step n
                       // s_x^n's dependence on s_v^n: a_x (BDF2), Δt/2 (midpoint), Δt β_2/α_2.
        let ex = match scheme {
            Scheme::Bdf2 => ax,
            Scheme::Midpoint => 0.5 * dt,
            Scheme::Alpha => hist_e,
        };
        for i in 0..nf {
            vs[j][i] += ex * xs[j][i];
        }
        let mut rbar = vs[j].clone();
        if let Some(r) = &refresh {
            t.solver.precondition_after(r);
        }
        t.solver.solve_columns(&model.pattern, &mut rbar, 1)?; // λ_v (eq. 12): S is symmetric
        stats.factorisations += t.solver.refactorisations();
        stats.cg_iterations += t.solver.cg_iterations();
        if let Some(r) = t.solver.refreshed() {
            refresh = Some(r);
        }
        let rfull = model.expand(&rbar);
        add_param_dots(
            model,
            mat,
            &kinds,
            &t.x,
            &t.v,
            Some((c, &t.vb)),
            &rfull,
            &mut acc,
        )?;
        let mut kr = vec![0.0; nf];
        model.pattern.mul_add(&t.k, &rbar, &mut kr);
        let mut mr = vec![0.0; nf];
        model.pattern.mul_add(&mvals, &rbar, &mut mr);
        match scheme {
            Scheme::Bdf2 => {
                for i in 0..nf {
                    let abar = xs[j][i] - kr[i];
                    let bbar = c * mr[i];
                    xs[j - 1][i] += 4.0 / 3.0 * abar;
                    xs[j - 2][i] -= abar / 3.0;
                    vs[j - 1][i] += 4.0 / 3.0 * bbar;
                    vs[j - 2][i] -= bbar / 3.0;
                }
            }
            Scheme::Midpoint => {
                let mut dr = vec![0.0; nf];
                model.pattern.mul_add(&t.d, &rbar, &mut dr);
                for i in 0..nf {
                    let xbar = xs[j][i];
                    xs[j - 1][i] += xbar - kr[i];
                    vs[j - 1][i] += 0.5 * dt * xbar + c * mr[i] - ax * kr[i] - av * dr[i];
                }
            }
            Scheme::Alpha => {
                // The transpose of the direct step: s_x^n = (Δt Σ β_j s_v − α_1 s_x^{n−1} −
                // α_0 s_x^{n−2})/α_2 and S s_v^n = G + c M s_b − K s_xa − D s_va.
                let mut dr = vec![0.0; nf];
                model.pattern.mul_add(&t.d, &rbar, &mut dr);
                let (a, b) = (two.alpha, two.beta);
                for i in 0..nf {
                    let xbar = xs[j][i];
                    xs[j - 1][i] += -a[1] / a[2] * xbar - hist_a1 * kr[i];
                    xs[j - 2][i] += -a[0] / a[2] * xbar - hist_a0 * kr[i];
                    for (back, k) in [(1, 1), (2, 0)] {
                        vs[j - back][i] += dt * b[k] / a[2] * xbar
                            - c * a[k] / a[2] * mr[i]
                            - b[k] * (hist_e * kr[i] + dr[i]);
                    }
                }
            }
        }
    }
    // Initial condition (eq. 14): s_x⁰ = s_x⁻¹ = K₀⁻¹ G₀, s_v⁰ = s_v⁻¹ = 0.
    if let Some((x0, Some(k0))) = &start {
        let mut lam: Vec<f64> = (0..nf).map(|i| xs[1][i] + xs[0][i]).collect();
        k0.solve_in_place(&mut lam);
        let lfull = model.expand(&lam);
        add_param_dots(
            model,
            mat,
            &kinds,
            x0,
            &vec![0.0; ndof],
            None,
            &lfull,
            &mut acc,
        )?;
    }
    let mut grad = vec![0.0; np];
    reduce(&acc, &table, &mut grad);
    Ok(Evaluation {
        simulated: Some(simulated),
        ..finish(&total, stats, Some(grad), stored)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// GMRES solves a nonsymmetric system far from the identity (T = I + K with ‖K‖_F > 1, where
    /// the fixed-point iteration is not assured to converge) to the direct solution.
    #[test]
    fn gmres_solves_what_the_fixed_point_iteration_cannot() {
        let n = 12;
        let mut rng = palpate_fem::rng::SplitMix64::new(7);
        let k: Vec<f64> = (0..n * n).map(|_| 1.5 * (rng.uniform() - 0.5)).collect();
        let t = nalgebra::DMatrix::from_fn(n, n, |i, j| f64::from(u8::from(i == j)) + k[i * n + j]);
        let spectral = (t.clone() - nalgebra::DMatrix::identity(n, n)).norm();
        assert!(
            spectral > 1.0,
            "‖K‖_F {spectral}: the fixed point would converge"
        );
        let rhs: Vec<f64> = (0..n).map(|i| (i as f64 * 0.7).sin()).collect();
        let apply = |v: &[f64]| -> Result<Vec<f64>, MotionError> {
            Ok((t.clone() * nalgebra::DVector::from_column_slice(v))
                .as_slice()
                .to_vec())
        };
        let y = gmres(&apply, &rhs, rhs.clone()).unwrap();
        let direct = t
            .clone()
            .lu()
            .solve(&nalgebra::DVector::from_column_slice(&rhs))
            .unwrap();
        let err = (nalgebra::DVector::from_column_slice(&y) - &direct).norm() / direct.norm();
        assert!(err < 1e-8, "relative error {err}");
    }
}
