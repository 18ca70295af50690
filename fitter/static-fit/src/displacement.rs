//! Displacement-based inverse (seed 000 §5.3): minimise over the parameters
//!
//! Σ_i ‖(M x_i(p) − x̄_i)/σ‖² + ‖L q‖²   (eqs. 5.66–5.67, 5.80, 5.85, 5.90)
//!
//! on the *observed markers only* (M interpolates node positions to markers), with
//! x_i(p) = K'(p)⁻¹(f̄_i + K''(p)x₀) (eq. 5.65) the warped forward model and q the physical
//! parameterisation of [`super::param`]. Residuals are divided by σ (the marker noise, or 0.1 mm
//! when not declared) so the γ's are dimensionless.
//!
//! **Jacobian products (eqs. 5.71–5.73), never a dense inverse.** With the rotations held at those
//! of the converged state (as the thesis does), differentiating K'x = f + K''x₀ gives
//! ∂x/∂λ_e = −K'⁻¹ s_e(x), ∂x/∂α_e = −K'⁻¹ t_e(x), with s_e, t_e the force-based element vectors
//! (eqs. 5.18–5.19) at the current state. Hence, per measurement, with ONE sparse Cholesky
//! factorisation of K' (the one from the last forward solve):
//! - direct: J v = −M K'⁻¹ (Σ_e v_λe s_e + v_αe t_e) / σ (one solve);
//! - adjoint: Jᵀ w = −[s_eᵀ y, t_eᵀ y]_e / σ with y = K'⁻¹ Mᵀ w (one solve).
//!
//! The step solves (JᵀJ + LᵀL + μI) δ = −(Jᵀr + LᵀLq): densely (J formed column by column with the
//! direct method) when there are few parameters, otherwise matrix-free by conjugate gradients
//! (two solves per measurement per CG iteration). Levenberg–Marquardt damping μ adapts to
//! accepted/rejected steps.

use std::time::Instant;

use nalgebra::{DMatrix, DVector, SVector};

use palpate_fem::forward::{Factorised, Material, SolveOptions};

use super::force::element_vectors;
use super::param::{from_q, to_q};
use super::regularisation::spatial_pairs;
use super::{FitError, FitInput, Gammas, IterationRecord, Layout, Sets};

/// Options of the displacement-based fit.
#[derive(Debug, Clone, PartialEq)]
pub struct DisplacementOptions {
    /// Homogeneous or inhomogeneous.
    pub layout: Layout,
    /// One set or one per measurement.
    pub sets: Sets,
    /// Regularisation weights (dimensionless; act on q = (log E, s)).
    pub gammas: Gammas,
    /// Forward-solver options (warping, increments, fixed-point tolerance).
    pub solve: SolveOptions,
    /// Residual scale σ (m).
    pub sigma: f64,
    /// Starting material (homogeneous guess broadcast to every slot).
    pub initial: palpate_runtime::material::LambdaAlpha,
    /// Maximum Gauss–Newton/LM iterations.
    pub max_iterations: usize,
    /// Stop when the relative objective decrease of an accepted step is below this.
    pub tolerance: f64,
    /// Use the dense normal equations up to this many parameters, CG beyond.
    pub dense_limit: usize,
    /// CG iterations per step (matrix-free path).
    pub cg_iterations: usize,
}

impl DisplacementOptions {
    /// Reasonable defaults for `layout`/`sets`.
    pub fn new(layout: Layout, sets: Sets) -> Self {
        Self {
            layout,
            sets,
            gammas: Gammas::uniform(1.0),
            solve: SolveOptions {
                increments: 4,
                tolerance: 1e-10,
                ..Default::default()
            },
            sigma: 1e-4,
            initial: palpate_runtime::material::LambdaAlpha::from_young_poisson(1e4, 0.3),
            max_iterations: 30,
            tolerance: 1e-7,
            dense_limit: 64,
            cg_iterations: 40,
        }
    }
}

/// Result of the displacement-based fit.
#[derive(Debug, Clone)]
pub struct DisplacementFit {
    /// Fitted sets.
    pub params: Vec<Material>,
    /// History (one record per accepted iteration, plus the start).
    pub history: Vec<IterationRecord>,
    /// Final simulated deformations per measurement.
    pub deformed: Vec<Vec<[f64; 3]>>,
    /// Number of accepted iterations.
    pub iterations: usize,
    /// Whether the relative decrease fell below the tolerance, or no damped step could decrease
    /// the objective any more (a stationary point to round-off) — not stopped by the cap.
    pub converged: bool,
}

/// Parameter layout: column of (type, set, slot), type 0 = log E, 1 = s.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Layouting {
    pub slots: usize,
    pub sets: usize,
}

impl Layouting {
    pub fn len(&self) -> usize {
        2 * self.slots * self.sets
    }
    #[inline]
    pub fn col(&self, ty: usize, set: usize, slot: usize) -> usize {
        ty * self.slots * self.sets + set * self.slots + slot
    }
    pub fn set_of(&self, i: usize) -> usize {
        if self.sets == 1 {
            0
        } else {
            i
        }
    }
    pub fn slot_of(&self, e: usize) -> usize {
        if self.slots == 1 {
            0
        } else {
            e
        }
    }
}

/// Forward state of one measurement at the current parameters.
pub(crate) struct MeasurementState {
    pub x: Vec<[f64; 3]>,
    pub factor: std::sync::Arc<Factorised>,
    pub st: Vec<(SVector<f64, 12>, SVector<f64, 12>)>,
    /// Residual vector (3 per observed marker), already divided by σ.
    pub r: Vec<f64>,
}

/// The displacement-based objective and its derivative products.
pub(crate) struct Objective<'a> {
    pub input: &'a FitInput,
    pub lay: Layouting,
    pub opts: &'a DisplacementOptions,
    pairs: Vec<(usize, usize)>,
}

impl<'a> Objective<'a> {
    pub fn new(input: &'a FitInput, opts: &'a DisplacementOptions) -> Self {
        let slots = match opts.layout {
            Layout::Homogeneous => 1,
            Layout::Inhomogeneous => input.problem.element_count(),
        };
        let sets = match opts.sets {
            Sets::Single => 1,
            Sets::PerMeasurement => input.measurements.len(),
        };
        let pairs = if slots > 1 {
            spatial_pairs(&input.problem.tets)
        } else {
            Vec::new()
        };
        Self {
            input,
            lay: Layouting { slots, sets },
            opts,
            pairs,
        }
    }

    /// Materials and dp/dq blocks of every set.
    pub fn materials(&self, q: &[f64]) -> (Vec<Material>, Vec<Vec<[[f64; 2]; 2]>>) {
        let mut mats = Vec::with_capacity(self.lay.sets);
        let mut jacs = Vec::with_capacity(self.lay.sets);
        for set in 0..self.lay.sets {
            let mut m = Material {
                lambda: Vec::with_capacity(self.lay.slots),
                alpha: Vec::with_capacity(self.lay.slots),
                foundation: None,
            };
            let mut j = Vec::with_capacity(self.lay.slots);
            for slot in 0..self.lay.slots {
                let (p, d) = from_q([q[self.lay.col(0, set, slot)], q[self.lay.col(1, set, slot)]]);
                m.lambda.push(p.lambda);
                m.alpha.push(p.alpha);
                j.push(d);
            }
            mats.push(m);
            jacs.push(j);
        }
        (mats, jacs)
    }

    /// Initial q from a homogeneous guess.
    pub fn initial_q(&self) -> Vec<f64> {
        let q0 = to_q(self.opts.initial);
        let mut q = vec![0.0; self.lay.len()];
        for set in 0..self.lay.sets {
            for slot in 0..self.lay.slots {
                q[self.lay.col(0, set, slot)] = q0[0];
                q[self.lay.col(1, set, slot)] = q0[1];
            }
        }
        q
    }

    /// Forward-solves every measurement (warm-started from `prev` when given).
    pub fn states(
        &self,
        mats: &[Material],
        prev: Option<&[MeasurementState]>,
    ) -> Result<Vec<MeasurementState>, FitError> {
        let p = &self.input.problem;
        let mut out = Vec::with_capacity(self.input.measurements.len());
        for (i, m) in self.input.measurements.iter().enumerate() {
            let start = prev.map(|s| s[i].x.as_slice());
            let solved =
                p.solve_forces(&mats[self.lay.set_of(i)], &m.force, start, &self.opts.solve)?;
            let x = solved.solution.x;
            let st = element_vectors(p, &x, &solved.solution.rotations);
            let r: Vec<f64> = self
                .input
                .marker_errors(i, &x)
                .iter()
                .flat_map(|(_, e)| e.map(|v| v / self.opts.sigma))
                .collect();
            out.push(MeasurementState {
                x,
                factor: solved.factor,
                st,
                r,
            });
        }
        Ok(out)
    }

    /// ‖L q‖² (regularisation term).
    pub fn reg(&self, q: &[f64]) -> f64 {
        let v = self.lq(q);
        v.iter().map(|x| x * x).sum()
    }

    /// L q (rows: spatial pairs per set per type, then consecutive sets per slot per type).
    fn lq(&self, q: &[f64]) -> Vec<f64> {
        let g = self.opts.gammas;
        let mut out = Vec::new();
        for (ty, gs) in [(0, g.s_lambda), (1, g.s_alpha)] {
            for set in 0..self.lay.sets {
                for &(a, b) in &self.pairs {
                    out.push(gs * (q[self.lay.col(ty, set, a)] - q[self.lay.col(ty, set, b)]));
                }
            }
        }
        for (ty, gm) in [(0, g.m_lambda), (1, g.m_alpha)] {
            for set in 0..self.lay.sets.saturating_sub(1) {
                for slot in 0..self.lay.slots {
                    out.push(
                        gm * (q[self.lay.col(ty, set, slot)] - q[self.lay.col(ty, set + 1, slot)]),
                    );
                }
            }
        }
        out
    }

    /// Lᵀ L v.
    fn ltl(&self, v: &[f64]) -> Vec<f64> {
        let g = self.opts.gammas;
        let mut out = vec![0.0; v.len()];
        for (ty, gs) in [(0, g.s_lambda), (1, g.s_alpha)] {
            let w = gs * gs;
            for set in 0..self.lay.sets {
                for &(a, b) in &self.pairs {
                    let (ca, cb) = (self.lay.col(ty, set, a), self.lay.col(ty, set, b));
                    let d = w * (v[ca] - v[cb]);
                    out[ca] += d;
                    out[cb] -= d;
                }
            }
        }
        for (ty, gm) in [(0, g.m_lambda), (1, g.m_alpha)] {
            let w = gm * gm;
            for set in 0..self.lay.sets.saturating_sub(1) {
                for slot in 0..self.lay.slots {
                    let (ca, cb) = (self.lay.col(ty, set, slot), self.lay.col(ty, set + 1, slot));
                    let d = w * (v[ca] - v[cb]);
                    out[ca] += d;
                    out[cb] -= d;
                }
            }
        }
        out
    }

    /// Direct method: J_i v for measurement i (3 values per observed marker).
    pub fn jv(&self, i: usize, s: &MeasurementState, jac: &[[[f64; 2]; 2]], v: &[f64]) -> Vec<f64> {
        let p = &self.input.problem;
        let set = self.lay.set_of(i);
        let mut w = vec![0.0; p.free_dofs()];
        for e in 0..p.element_count() {
            let slot = self.lay.slot_of(e);
            let (v0, v1) = (v[self.lay.col(0, set, slot)], v[self.lay.col(1, set, slot)]);
            if v0 == 0.0 && v1 == 0.0 {
                continue;
            }
            let d = jac[slot];
            let dl = d[0][0] * v0 + d[0][1] * v1;
            let da = d[1][0] * v0 + d[1][1] * v1;
            let (se, te) = &s.st[e];
            for (k, &node) in p.tets[e].iter().enumerate() {
                let fi = p.free_index[node];
                if fi != usize::MAX {
                    for dd in 0..3 {
                        w[3 * fi + dd] += dl * se[3 * k + dd] + da * te[3 * k + dd];
                    }
                }
            }
        }
        s.factor.solve_in_place(&mut w);
        let sc = -1.0 / self.opts.sigma;
        let mut out = Vec::with_capacity(s.r.len());
        for &(mk, _) in &self.input.measurements[i].observed {
            let mkr = &self.input.markers[mk];
            let mut pos = [0.0; 3];
            for (b, &n) in mkr.barycentric.iter().zip(&mkr.triangle) {
                let fi = p.free_index[n];
                if fi != usize::MAX {
                    for dd in 0..3 {
                        pos[dd] += b * w[3 * fi + dd];
                    }
                }
            }
            out.extend(pos.map(|v| sc * v));
        }
        out
    }

    /// Adjoint method: accumulates J_iᵀ u into `out` (all parameters).
    pub fn jtu(
        &self,
        i: usize,
        s: &MeasurementState,
        jac: &[[[f64; 2]; 2]],
        u: &[f64],
        out: &mut [f64],
    ) {
        let p = &self.input.problem;
        let set = self.lay.set_of(i);
        let mut y = vec![0.0; p.free_dofs()];
        for (k, &(mk, _)) in self.input.measurements[i].observed.iter().enumerate() {
            let mkr = &self.input.markers[mk];
            for (b, &n) in mkr.barycentric.iter().zip(&mkr.triangle) {
                let fi = p.free_index[n];
                if fi != usize::MAX {
                    for dd in 0..3 {
                        y[3 * fi + dd] += b * u[3 * k + dd];
                    }
                }
            }
        }
        s.factor.solve_in_place(&mut y);
        let sc = -1.0 / self.opts.sigma;
        for e in 0..p.element_count() {
            let (se, te) = &s.st[e];
            let (mut gl, mut ga) = (0.0, 0.0);
            for (k, &node) in p.tets[e].iter().enumerate() {
                let fi = p.free_index[node];
                if fi != usize::MAX {
                    for dd in 0..3 {
                        gl += se[3 * k + dd] * y[3 * fi + dd];
                        ga += te[3 * k + dd] * y[3 * fi + dd];
                    }
                }
            }
            let slot = self.lay.slot_of(e);
            let d = jac[slot];
            out[self.lay.col(0, set, slot)] += sc * (d[0][0] * gl + d[1][0] * ga);
            out[self.lay.col(1, set, slot)] += sc * (d[0][1] * gl + d[1][1] * ga);
        }
    }

    /// (JᵀJ + LᵀL) v over all measurements.
    fn normal_mul(
        &self,
        states: &[MeasurementState],
        jacs: &[Vec<[[f64; 2]; 2]>],
        v: &[f64],
    ) -> Vec<f64> {
        let mut out = self.ltl(v);
        for (i, s) in states.iter().enumerate() {
            let jac = &jacs[self.lay.set_of(i)];
            let u = self.jv(i, s, jac, v);
            self.jtu(i, s, jac, &u, &mut out);
        }
        out
    }

    /// Gradient (half): Jᵀ r + LᵀL q.
    fn gradient(
        &self,
        states: &[MeasurementState],
        jacs: &[Vec<[[f64; 2]; 2]>],
        q: &[f64],
    ) -> Vec<f64> {
        let mut g = self.ltl(q);
        for (i, s) in states.iter().enumerate() {
            self.jtu(i, s, &jacs[self.lay.set_of(i)], &s.r, &mut g);
        }
        g
    }

    fn data(states: &[MeasurementState]) -> f64 {
        states
            .iter()
            .map(|s| s.r.iter().map(|v| v * v).sum::<f64>())
            .sum()
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Runs the Levenberg–Marquardt iteration.
///
/// Kept apart from the shared dense `palpate_fem::lm::minimise` on purpose: the damping here is
/// μI scaled by the mean Hessian diagonal (not Marquardt's per-parameter scaling), the objective
/// carries the regularisation terms and adjoint gradients, and above `dense_limit` parameters the
/// step is matrix-free (CG on Hessian–vector products), which a dense JᵀJ driver cannot do.
pub fn fit_displacement(
    input: &FitInput,
    opts: &DisplacementOptions,
    mut progress: impl FnMut(&IterationRecord),
) -> Result<DisplacementFit, FitError> {
    let obj = Objective::new(input, opts);
    let n = obj.lay.len();
    let mut q = obj.initial_q();
    let (mut mats, mut jacs) = obj.materials(&q);
    let mut states = obj.states(&mats, None)?;
    let mut phi = Objective::data(&states) + obj.reg(&q);
    let mut history = vec![record(input, opts, 0, phi, &states, 0.0, 0)];
    progress(&history[0]);
    let mut mu = 0.0;
    let mut iterations = 0;
    let mut stationary = false;
    let started = Instant::now();
    let _ = started;
    for it in 1..=opts.max_iterations {
        let g = obj.gradient(&states, &jacs, &q);
        // Dense or matrix-free step.
        let dense = if n <= opts.dense_limit {
            Some(dense_normal(&obj, &states, &jacs, n))
        } else {
            None
        };
        if mu == 0.0 {
            let diag_mean = match &dense {
                Some(h) => h.diagonal().mean(),
                None => {
                    // Hutchinson estimate of tr(JᵀJ + LᵀL)/n with one ±1 probe.
                    let v: Vec<f64> = (0..n)
                        .map(|k| if (k * 2654435761) % 7 < 4 { 1.0 } else { -1.0 })
                        .collect();
                    dot(&v, &obj.normal_mul(&states, &jacs, &v)) / n as f64
                }
            };
            mu = 1e-3 * diag_mean.max(1e-300);
        }
        let mut accepted = false;
        let mut cg_used = 0;
        for _retry in 0..10 {
            let (delta, cg) = match &dense {
                Some(h) => {
                    let mut a = h.clone();
                    for k in 0..n {
                        a[(k, k)] += mu;
                    }
                    let rhs = DVector::from_iterator(n, g.iter().map(|v| -v));
                    let sol = a.cholesky().map(|c| c.solve(&rhs)).ok_or_else(|| {
                        FitError::Singular("normal matrix not positive definite".into())
                    })?;
                    (sol.iter().copied().collect::<Vec<f64>>(), 0)
                }
                None => cg_step(&obj, &states, &jacs, &g, mu, opts.cg_iterations),
            };
            cg_used += cg;
            let q_new: Vec<f64> = q.iter().zip(&delta).map(|(a, b)| a + b).collect();
            let (m_new, j_new) = obj.materials(&q_new);
            let trial = obj.states(&m_new, Some(&states));
            if let Ok(st_new) = trial {
                let phi_new = Objective::data(&st_new) + obj.reg(&q_new);
                if phi_new.is_finite() && phi_new < phi {
                    let rel = (phi - phi_new) / phi.max(1e-300);
                    q = q_new;
                    mats = m_new;
                    jacs = j_new;
                    states = st_new;
                    phi = phi_new;
                    mu = (mu / 3.0).max(1e-12 * mu.max(1e-300));
                    accepted = true;
                    iterations = it;
                    let rec = record(input, opts, it, phi, &states, mu, cg_used);
                    progress(&rec);
                    history.push(rec);
                    if rel < opts.tolerance {
                        return Ok(DisplacementFit {
                            params: mats,
                            history,
                            deformed: states.into_iter().map(|s| s.x).collect(),
                            iterations,
                            converged: true,
                        });
                    }
                    break;
                }
            }
            mu *= 4.0;
        }
        if !accepted {
            stationary = true;
            break;
        }
    }
    let _ = &mats;
    Ok(DisplacementFit {
        params: mats,
        history,
        deformed: states.into_iter().map(|s| s.x).collect(),
        iterations,
        converged: stationary,
    })
}

fn record(
    input: &FitInput,
    opts: &DisplacementOptions,
    iteration: usize,
    objective: f64,
    states: &[MeasurementState],
    damping: f64,
    cg: usize,
) -> IterationRecord {
    let data = Objective::data(states);
    let per: Vec<f64> = states
        .iter()
        .map(|s| {
            opts.sigma
                * (s.r.iter().map(|v| v * v).sum::<f64>() / (s.r.len() / 3).max(1) as f64).sqrt()
        })
        .collect();
    let markers: usize = states.iter().map(|s| s.r.len() / 3).sum();
    let _ = input;
    IterationRecord {
        iteration,
        objective,
        data,
        rms_m: opts.sigma * (data / markers.max(1) as f64).sqrt(),
        damping,
        cg_iterations: cg,
        per_measurement_rms: per,
    }
}

/// JᵀJ + LᵀL formed densely, column by column with the direct method.
fn dense_normal(
    obj: &Objective,
    states: &[MeasurementState],
    jacs: &[Vec<[[f64; 2]; 2]>],
    n: usize,
) -> DMatrix<f64> {
    let mut h = DMatrix::<f64>::zeros(n, n);
    let mut jcols: Vec<Vec<Vec<f64>>> = vec![Vec::with_capacity(n); states.len()];
    for k in 0..n {
        let mut e = vec![0.0; n];
        e[k] = 1.0;
        for (i, s) in states.iter().enumerate() {
            jcols[i].push(obj.jv(i, s, &jacs[obj.lay.set_of(i)], &e));
        }
        let l = obj.ltl(&e);
        for r in 0..n {
            h[(r, k)] += l[r];
        }
    }
    for cols in &jcols {
        for a in 0..n {
            for b in a..n {
                let v = dot(&cols[a], &cols[b]);
                h[(a, b)] += v;
                if a != b {
                    h[(b, a)] += v;
                }
            }
        }
    }
    h
}

/// Matrix-free CG on (JᵀJ + LᵀL + μI) δ = −g.
fn cg_step(
    obj: &Objective,
    states: &[MeasurementState],
    jacs: &[Vec<[[f64; 2]; 2]>],
    g: &[f64],
    mu: f64,
    iters: usize,
) -> (Vec<f64>, usize) {
    let n = g.len();
    let mut x = vec![0.0; n];
    let mut r: Vec<f64> = g.iter().map(|v| -v).collect();
    let mut p = r.clone();
    let mut rr = dot(&r, &r);
    let r0 = rr.sqrt();
    let mut used = 0;
    for _ in 0..iters {
        used += 1;
        let mut ap = obj.normal_mul(states, jacs, &p);
        for k in 0..n {
            ap[k] += mu * p[k];
        }
        let pap = dot(&p, &ap);
        if pap <= 0.0 {
            break;
        }
        let a = rr / pap;
        for k in 0..n {
            x[k] += a * p[k];
            r[k] -= a * ap[k];
        }
        let rr_new = dot(&r, &r);
        if rr_new.sqrt() <= 1e-4 * r0 {
            break;
        }
        let beta = rr_new / rr;
        for k in 0..n {
            p[k] = r[k] + beta * p[k];
        }
        rr = rr_new;
    }
    (x, used)
}
