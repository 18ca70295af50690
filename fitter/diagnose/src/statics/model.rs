//! The augmented forward model: the warped linear homogeneous FEM of seed 000 (the simplest model
//! a static dataset can be fitted with) plus any set of candidate effects, each adding a few
//! parameters. Parameters θ are dimensionless (each block has a documented scale) so one finite
//! difference step fits all.
//!
//! Layout: θ₀ = log E (Pa), θ₁ = s with ν = −1/4 + 3/4 · tanh(s) (any real θ is physical), then
//! one block per effect in the order of [`Model::effects`].

use nalgebra::Vector3;
use palpate_runtime::material::LambdaAlpha;
use rayon::prelude::*;
use serde::Serialize;

use super::DiagnoseError;

pub use super::candidate::{Candidate, ALL_CANDIDATES};
pub use super::context::{BlobScan, Context, LayerAxis, MeasData, LAYER_NODES};
use palpate_fem::dataset::Marker;
use palpate_fem::forward::{Factorised, Foundation, Load, Material, SolveOptions, StaticProblem};
use palpate_fem::geometry::rotate;
use std::sync::Arc;

/// Most secant passes of the stiffening fixed point.
const STIFFENING_PASSES: usize = 30;
/// The stiffening fixed point stops when no element's log-modulus moves by more than this.
const STIFFENING_TOLERANCE: f64 = 1e-6;
/// A fixed point that stops converging (or reaches [`STIFFENING_PASSES`]) before its change ever
/// fell below this is not a solution; one that did has converged as far as its passes' solves
/// allow: a log-modulus within 0.1 % of its fixed point moves markers by about a thousandth of
/// their displacement, far below their noise. (The slowest converging fixed points measured, a
/// contraction of ≈ 0.9 per pass, end near 1e-6; with large warped rotations some stall between
/// 1e-4 and 4e-4.)
const STIFFENING_UNCONVERGED: f64 = 1e-3;
/// Passes in a row without a new smallest change that end the fixed point (converged or, above
/// [`STIFFENING_UNCONVERGED`], without a solution); also the passes in a row with an element
/// past its peak stress after which a softening law has no stable equilibrium. Converging
/// passes shrink the change, at worst with one pass of overshoot between two new minima
/// (measured on the independent layer draw: 3,500 converging solves); a softening law loaded
/// past its limit point (the secant stress E ε/(1 + |β| s²) peaks at |β| s² = 1) grows it from
/// the first pass.
const STIFFENING_STALLED_PASSES: usize = 3;
/// The least relaxation of an element's update in the stiffening fixed point (halved at each
/// reversal of its step).
const STIFFENING_MIN_RELAX: f64 = 1.0 / 16.0;

/// The stiffening law's per-element log-modulus offsets at state `x` and their gains
/// ∂T/∂ln‖ε‖. With s = ‖ε_e‖/0.1 the secant modulus is E (1 + β s²) for β ≥ 0 — the leading
/// form of a Yeoh c (Ī₁ − 3)² term over Neo-Hookean (Ī₁ − 3 is quadratic in the strain, so the
/// secant grows with the squared strain) — and
/// E / (1 + |β| s²) for β < 0 (softening), so it stays positive for any β.
fn stiffening_target(ctx: &Context, x: &[[f64; 3]], beta: f64) -> (Vec<f64>, Vec<f64>) {
    let rot = ctx.problem.rotations(x, true);
    ctx.problem
        .strains(x, &rot)
        .iter()
        .map(|st| {
            let q = beta.abs() * st.iter().map(|v| v * v).sum::<f64>() / 0.01;
            let g = 2.0 * q / (1.0 + q);
            if beta >= 0.0 {
                ((1.0 + q).ln(), g)
            } else {
                (-(1.0 + q).ln(), -g)
            }
        })
        .unzip()
}

/// Per-element log-E offsets of the stiffening effect at state `x` (see [`stiffening_target`]).
fn stiffening_log_e(ctx: &Context, x: &[[f64; 3]], beta: f64) -> Vec<f64> {
    stiffening_target(ctx, x, beta).0
}

/// Adds the gravity candidate's lumped body force ρ V_n g (ρ in 1000 kg/m³) to `fvec`.
fn add_gravity(ctx: &Context, rho: f64, fvec: &mut [f64]) {
    let rho = rho * 1000.0;
    for (n, v) in ctx.node_volume.iter().enumerate() {
        for d in 0..3 {
            fvec[3 * n + d] += rho * v * ctx.gravity[d];
        }
    }
}

/// A model: the base material plus an ordered set of effects.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Model {
    /// Adopted effects, in adoption order.
    pub effects: Vec<Candidate>,
}

/// The tangential coefficient of [`Candidate::TiltEach`]'s probing solves: a tilt of ≈ 6°, small
/// enough for the warped response to stay linear in it, large enough to stand above round-off.
pub const TILT_PROBE: f64 = 0.1;

/// [`Candidate::TiltEach`] on measurement `i`: the coefficients (a, b) of the responses `cols`
/// that best explain the measured markers' misfit (2 × 2 normal equations), added to `sim`.
fn tilt_each(
    ctx: &Context,
    i: usize,
    sim: Vec<[f64; 3]>,
    cols: &[Vec<[f64; 3]>; 2],
) -> Vec<[f64; 3]> {
    let m = &ctx.meas[i];
    let (mut a11, mut a12, mut a22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (j, (&(_, q), p)) in m.observed.iter().zip(&sim).enumerate() {
        for d in 0..3 {
            let (u, v, r) = (cols[0][j][d], cols[1][j][d], q[d] - p[d]);
            a11 += u * u;
            a12 += u * v;
            a22 += v * v;
            b1 += u * r;
            b2 += v * r;
        }
    }
    let det = a11 * a22 - a12 * a12;
    // A degenerate or non-finite system (a measurement without force, markers that do not
    // respond) leaves the markers as they are.
    let well_posed = det > 1e-12 * (a11 * a22).max(f64::MIN_POSITIVE);
    if !well_posed || !det.is_finite() {
        return sim;
    }
    let (a, b) = ((b1 * a22 - b2 * a12) / det, (a11 * b2 - a12 * b1) / det);
    sim.iter()
        .enumerate()
        .map(|(j, p)| [0, 1, 2].map(|d| p[d] + a * cols[0][j][d] + b * cols[1][j][d]))
        .collect()
}

/// [`Candidate::ForceScaleEach`] on the measurements `subset` (their simulated markers `sims`):
/// each measurement's simulated displacements (from the markers' rest places) scaled by the s_i
/// that fits its measured ones best, the s_i of several measurements divided by their geometric
/// mean. A measurement whose markers do not move, or whose best scale is not positive, keeps
/// s_i = 1.
fn force_scale_each(ctx: &Context, subset: &[usize], sims: &mut [Vec<[f64; 3]>]) {
    let scales: Vec<f64> = subset
        .iter()
        .zip(sims.iter())
        .map(|(&i, sim)| {
            let mut sums = (0.0, 0.0);
            ctx.add_scale_terms(i, sim, &mut sums);
            match sums.0 / sums.1 {
                s if s.is_finite() && s > 0.0 => s,
                _ => 1.0,
            }
        })
        .collect();
    let mean_log = if scales.len() > 1 {
        scales.iter().map(|s| s.ln()).sum::<f64>() / scales.len() as f64
    } else {
        0.0
    };
    for ((&i, sim), s) in subset.iter().zip(sims.iter_mut()).zip(&scales) {
        let s = s / mean_log.exp();
        for (&(k, _), p) in ctx.meas[i].observed.iter().zip(sim.iter_mut()) {
            let rest = ctx.marker_rest[k];
            for d in 0..3 {
                p[d] = rest[d] + s * (p[d] - rest[d]);
            }
        }
    }
}

/// ν from θ₁.
pub fn poisson_of(s: f64) -> f64 {
    -0.25 + 0.75 * s.tanh()
}

/// θ₁ from ν.
pub fn s_of(nu: f64) -> f64 {
    ((nu + 0.25) / 0.75).clamp(-0.999_999, 0.999_999).atanh()
}

/// Simulated positions of a measurement: node positions and the observed markers' positions.
#[derive(Debug, Clone)]
pub struct Simulated {
    /// Node positions per simulated measurement.
    pub x: Vec<Vec<[f64; 3]>>,
    /// Simulated marker positions (per measurement, aligned with `observed`).
    pub markers: Vec<Vec<[f64; 3]>>,
    /// The markers re-embedded at the gravity candidate's rest-scan material points, one per
    /// marker (`None`: the dataset's own embedding).
    pub embedding: Option<Vec<Marker>>,
    /// [`Candidate::TiltEach`]: per measurement, the simulated markers' response to a unit
    /// tangential coefficient along t₁ and t₂ (m per unit of |f|).
    pub tilt: Option<Vec<[Vec<[f64; 3]>; 2]>>,
    /// The factorisation of K' each measurement's solve ended with (start of nearby solves).
    pub factors: Vec<Arc<Factorised>>,
}

impl Model {
    /// The base model.
    pub fn base() -> Self {
        Self {
            effects: Vec::new(),
        }
    }

    /// With one more effect.
    pub fn with(&self, c: Candidate) -> Self {
        let mut m = self.clone();
        m.effects.push(c);
        m
    }

    /// Total parameter count.
    pub fn param_count(&self, grid: [usize; 3]) -> usize {
        2 + self.effects.iter().map(|c| c.params(grid)).sum::<usize>()
    }

    /// Offset of effect `c`'s block in θ.
    pub fn offset(&self, c: Candidate, grid: [usize; 3]) -> Option<usize> {
        let mut o = 2;
        for &e in &self.effects {
            if e == c {
                return Some(o);
            }
            o += e.params(grid);
        }
        None
    }

    /// Whether θ_j changes the FEM solve.
    pub fn affects_solve(&self, j: usize, grid: [usize; 3]) -> bool {
        if j < 2 {
            return true;
        }
        let mut o = 2;
        for &e in &self.effects {
            let k = e.params(grid);
            if j < o + k {
                return e.affects_solve();
            }
            o += k;
        }
        false
    }

    fn block<'a>(&self, c: Candidate, theta: &'a [f64], grid: [usize; 3]) -> Option<&'a [f64]> {
        self.offset(c, grid).map(|o| &theta[o..o + c.params(grid)])
    }

    /// The force the model applies for measurement `i`.
    pub fn model_force(&self, ctx: &Context, theta: &[f64], i: usize) -> [f64; 3] {
        let f = ctx.meas[i].force;
        let fm = Vector3::from(f).norm();
        let mut out = f;
        if let Some(p) = self.block(Candidate::Calibration, theta, ctx.grid) {
            let k = if fm > 0.0 {
                (fm / ctx.f_ref).powf(p[0])
            } else {
                1.0
            };
            out = out.map(|v| v * k);
        }
        if let Some(t) = self.block(Candidate::Tilt, theta, ctx.grid) {
            let [t1, t2] = ctx.tangents;
            out = [0, 1, 2].map(|d| out[d] + fm * (t[0] * t1[d] + t[1] * t2[d]));
        }
        out
    }

    /// The nodal force vector of measurement `i`'s probe carrying `force`: the dataset's contact
    /// rule (lumped onto the free surface nodes within the declared radius r), and with
    /// [`Candidate::ContactRadius`] the change a patch of radius s·r makes, as the difference of
    /// two consistently integrated uniform pressures, f_cons(s·r) − f_cons(r).
    ///
    /// Why a difference rather than f_cons(s·r) alone: the approximation-error correction δ is
    /// the refined mesh's answer minus the dataset mesh's under the lumped rule, and on a coarse
    /// mesh much of δ near the probe *is* the lumping (one or two nodes within a small radius
    /// carry the whole force). The refined mesh's lumped and consistent loads agree, so the
    /// lumped rule plus δ already stands for the refined, consistent answer at s = 1; replacing
    /// the lumped load by f_cons(s·r) under that δ would count the lumping error twice (measured
    /// on an independent draw: the candidate gained 2 µm of 31 µm in excess of the floor). The
    /// difference is continuous in s (its Jacobian column is a finite difference like any
    /// other's) and nests the model without it exactly at ln s = 0.
    pub fn load_vector(
        &self,
        ctx: &Context,
        theta: &[f64],
        i: usize,
        force: [f64; 3],
    ) -> Result<Vec<f64>, DiagnoseError> {
        let m = &ctx.meas[i];
        let bad = |e: String| DiagnoseError::Input(format!("measurement {:?}: {e}", m.id));
        let mut f = self
            .problem(ctx)
            .force_vector(&Load::contact(m.point, force, m.radius))
            .map_err(|e| bad(e.to_string()))?;
        let Some(b) = self.block(Candidate::ContactRadius, theta, ctx.grid) else {
            return Ok(f);
        };
        if b[0] == 0.0 {
            return Ok(f);
        }
        let p = self.problem(ctx);
        for (radius, sign) in [(m.radius * b[0].exp(), 1.0), (m.radius, -1.0)] {
            palpate_runtime::contact_rule::contact_weights_consistent(
                m.point,
                radius,
                p.x0.len(),
                |n| p.x0[n],
                p.surface.len(),
                |t| p.surface[t],
                |n| p.fixed[n],
                |n, w| {
                    for d in 0..3 {
                        f[3 * n + d] += sign * w * force[d];
                    }
                },
            )
            .map_err(|e| {
                bad(format!(
                    "contact-radius: no free surface within {radius:.3e} m of the contact point ({e:?})"
                ))
            })?;
        }
        Ok(f)
    }

    /// The material of the solve at `theta` without the stiffening fixed point: the field
    /// candidates' log E on the base E (what [`crate::sensitivity`] differentiates).
    pub fn field_material(&self, ctx: &Context, theta: &[f64]) -> Result<Material, DiagnoseError> {
        let log_e = self.log_e_field(ctx, theta);
        self.material(ctx, theta, log_e.as_deref(), None)
    }

    /// Per-element log-E offsets of the spatial material effects (inhomogeneity, layer,
    /// inclusion); `None` without any.
    fn log_e_field(&self, ctx: &Context, theta: &[f64]) -> Option<Vec<f64>> {
        let grid = self.block(Candidate::Inhomogeneity, theta, ctx.grid);
        let layer = self.block(Candidate::Layer, theta, ctx.grid);
        let blob = self.block(Candidate::Inclusion, theta, ctx.grid);
        if grid.is_none() && layer.is_none() && blob.is_none() {
            return None;
        }
        let mut out = vec![0.0; ctx.centroids.len()];
        if let Some(b) = grid {
            for (o, ws) in out.iter_mut().zip(&ctx.grid_weights) {
                *o += ws
                    .iter()
                    .map(|&(k, w)| if k == 0 { 0.0 } else { w * b[k - 1] })
                    .sum::<f64>();
            }
        }
        if let Some(b) = layer {
            // Nodes at depth k/(L−1); the deepest (k = L−1) is the reference.
            let last = (LAYER_NODES - 1) as f64;
            for (o, &d) in out.iter_mut().zip(&ctx.depth) {
                let t = (d.clamp(0.0, 1.0) * last).min(last - 1e-12);
                let k = t.floor() as usize;
                let w = t - k as f64;
                let at = |j: usize| if j < LAYER_NODES - 1 { b[j] } else { 0.0 };
                *o += (1.0 - w) * at(k) + w * at(k + 1);
            }
        }
        if let Some(b) = blob {
            let p = [0, 1, 2].map(|d| ctx.inclusion_start[d] + ctx.half * b[1 + d]);
            let r = 0.5 * ctx.half * b[4].clamp(-5.0, 5.0).exp();
            for (o, c) in out.iter_mut().zip(&ctx.centroids) {
                let d2: f64 = (0..3).map(|d| (c[d] - p[d]).powi(2)).sum();
                *o += b[0] * (-0.5 * d2 / (r * r)).exp();
            }
        }
        Some(out)
    }

    /// The stiffening law's secant material at equilibrium under the force vector `fvec`
    /// (measurement `id`), from the linear state `(x, factor)` and the log-modulus offsets `m0`
    /// (a warm start's, or none).
    ///
    /// The secant material is a fixed point m = T(ε(x(m))); it is solved by Newton on each
    /// element's log-modulus offset, with the local estimate ∂ln‖ε‖/∂m ≈ −1 (strain inversely
    /// proportional to the local modulus) — plain substitution diverges once the stiffening
    /// doubles the modulus (its gain reaches 2). Each pass is one linear solve with the rotations
    /// and the material of the current state (a joint fixed point); the rotations are converged
    /// to the forward model's own tolerance by the final solve.
    ///
    /// It is an error (an optimiser's trial counts it as rejected) where the law has no stable
    /// equilibrium: a softening law that loads an element past its peak stress (the secant
    /// stress E ε/(1 + |β| s²) peaks at |β| s² = 1, where the gain ∂T/∂ln s reaches −1) for
    /// [`STIFFENING_STALLED_PASSES`] passes in a row, or a fixed point that stops converging,
    /// or reaches the pass limit, before its change ever fell below [`STIFFENING_UNCONVERGED`].
    fn stiffening_equilibrium(
        &self,
        ctx: &Context,
        theta: &[f64],
        log_e: Option<&[f64]>,
        beta: f64,
        (fvec, id): (&[f64], &str),
        m0: Option<Vec<f64>>,
        (mut x, mut factor): (Vec<[f64; 3]>, Arc<Factorised>),
    ) -> Result<(Vec<[f64; 3]>, Arc<Factorised>), DiagnoseError> {
        let mut m = m0.unwrap_or_else(|| vec![0.0; ctx.problem.element_count()]);
        let pass = SolveOptions {
            max_fixed_point: 0,
            ..ctx.solve
        };
        // The smallest change so far and the passes since it was set: a fixed point that stops
        // shrinking has no solution, and its last iterate is not one (it used to be returned
        // after 30 passes — a quarter of a layer draw's solves, three quarters of its time — for
        // an optimiser trial to score).
        let (mut least, mut stalled, mut past_peak) = (f64::INFINITY, 0, 0);
        // Per element, a step that reverses the previous one halves that element's relaxation:
        // the local estimate ∂ln‖ε‖/∂m ≈ −1 overshoots where neighbours hold the strain (then the
        // true derivative is nearer 0), and with a softening gain near its limit the Newton
        // divisor 1 − g magnifies that overshoot.
        let n_el = m.len();
        let (mut relax, mut last_step) = (vec![1.0f64; n_el], vec![0.0f64; n_el]);
        for k in 0..=STIFFENING_PASSES {
            let (target, gain) = stiffening_target(ctx, &x, beta);
            let mut change = 0.0f64;
            for e in 0..n_el {
                let step = (target[e] - m[e]) / (1.0 + gain[e]).max(0.25);
                change = change.max(step.abs());
                if step * last_step[e] < 0.0 {
                    relax[e] = (0.5 * relax[e]).max(STIFFENING_MIN_RELAX);
                }
                last_step[e] = step;
                m[e] += relax[e] * step;
            }
            if change < least {
                (least, stalled) = (change, 0);
            } else {
                stalled += 1;
            }
            // Past the peak an element's stress falls as it strains: a fixed point may still
            // exist there (its neighbours hold it; measured on specimen seed 3 at β = −0.1, gain
            // −1.10, converging by 0.81 per pass) but it is not a stable equilibrium of the law.
            let peak = gain.iter().fold(0.0f64, |a, &g| a.min(g));
            past_peak = if peak <= -1.0 { past_peak + 1 } else { 0 };
            if past_peak >= STIFFENING_STALLED_PASSES {
                return Err(DiagnoseError::Diverged(format!(
                    "the stiffening law (β = {beta:.3e}) found no equilibrium under measurement \
                     {id:?}: it loads an element past its peak stress (|β| s² ≥ 1, gain \
                     {peak:.2}) for {past_peak} passes — a softening law at or past its limit load"
                )));
            }
            // A fixed point whose change stops shrinking once it is below STIFFENING_UNCONVERGED
            // has converged as far as its passes' own solves (with the warped rotations they
            // update) allow, and ends there; so does one at the pass limit. Measured on the
            // independent layer draw, where no element is near its peak: β = −1.2e-4 reached
            // 3.8e-5 and then wandered at 1.3e-4, β = −1.6e-3 stalled at 2.7e-4, and β = −1.3e-3
            // was still shrinking at 4.2e-4 at pass 31 — each called "no equilibrium" by the
            // first version of this rule (a 1e-4 bound).
            let stuck = stalled >= STIFFENING_STALLED_PASSES;
            let end = stuck || k == STIFFENING_PASSES;
            if !change.is_finite() || (end && least >= STIFFENING_UNCONVERGED) {
                let why = if stuck {
                    "stopped converging"
                } else {
                    "did not converge"
                };
                return Err(DiagnoseError::Diverged(format!(
                    "the stiffening law (β = {beta:.3e}) found no equilibrium under measurement \
                     {id:?}: its secant fixed point {why} and still moved a log-modulus by \
                     {change:.2e} after {} passes (least {least:.2e})",
                    k + 1
                )));
            }
            let last = change < STIFFENING_TOLERANCE || end;
            let mat = self.material(ctx, theta, log_e, Some(&m))?;
            let problem = self.problem(ctx);
            // A pass is one exact linear solve (its own factorisation: a stale one would make it
            // a stationary step and move the joint fixed point's path); the last, converged
            // solve starts from the previous pass's factor.
            let solved = if last {
                problem.solve_forces_with(&mat, fvec, Some(&x), &ctx.solve, Some(&factor))?
            } else {
                problem.solve_forces(&mat, fvec, Some(&x), &pass)?
            };
            (x, factor) = (solved.solution.x, solved.factor);
            if last {
                break;
            }
        }
        Ok((x, factor))
    }

    fn material(
        &self,
        ctx: &Context,
        theta: &[f64],
        log_e: Option<&[f64]>,
        extra: Option<&[f64]>,
    ) -> Result<Material, DiagnoseError> {
        let mut m = self.bulk_material(theta, log_e, extra)?;
        if let Some(b) = self.block(Candidate::Support, theta, ctx.grid) {
            // k_n = E / ℓ_n with ℓ_n = h e^{θ₀}; the exponents clamped so that a wandering
            // optimiser trial stays finite (e^{±30}: far beyond any support a dataset can show).
            let normal = theta[0].exp() / (ctx.half * b[0].clamp(-30.0, 30.0).exp());
            m.foundation = Some(Foundation {
                normal,
                tangential: normal * b[1].clamp(-30.0, 30.0).exp(),
            });
        }
        Ok(m)
    }

    /// The problem the model solves: the foundation's when it holds [`Candidate::Support`].
    pub fn problem<'a>(&self, ctx: &'a Context) -> &'a StaticProblem {
        match (&ctx.foundation, self.effects.contains(&Candidate::Support)) {
            (Some(p), true) => p,
            _ => &ctx.problem,
        }
    }

    /// (λ, α) per element (or one pair) at `theta`.
    fn bulk_material(
        &self,
        theta: &[f64],
        log_e: Option<&[f64]>,
        extra: Option<&[f64]>,
    ) -> Result<Material, DiagnoseError> {
        let nu = poisson_of(theta[1]);
        let check = |e: f64| {
            if e.is_finite() && e > 0.0 && e < 1e15 {
                Ok(LambdaAlpha::from_young_poisson(e, nu))
            } else {
                Err(DiagnoseError::Diverged(format!(
                    "Young's modulus {e:e} Pa left the physical range"
                )))
            }
        };
        match (log_e, extra) {
            (None, None) => Ok(Material::homogeneous(check(theta[0].exp())?)),
            _ => {
                let n = log_e
                    .map(|v| v.len())
                    .or(extra.map(|v| v.len()))
                    .unwrap_or(0);
                let ps: Result<Vec<_>, _> = (0..n)
                    .map(|e| {
                        check(
                            (theta[0] + log_e.map_or(0.0, |v| v[e]) + extra.map_or(0.0, |v| v[e]))
                                .exp(),
                        )
                    })
                    .collect();
                Ok(Material::per_element(&ps?))
            }
        }
    }

    /// Solves the measurements in `subset` (warm-started from `warm` if given: one x per
    /// measurement in `subset` order) and returns node and marker positions.
    pub fn simulate(
        &self,
        ctx: &Context,
        theta: &[f64],
        subset: &[usize],
        warm: Option<&[Vec<[f64; 3]>]>,
    ) -> Result<Simulated, DiagnoseError> {
        self.simulate_with(ctx, theta, subset, warm, None)
    }

    /// [`Model::simulate`] near `base` (a Jacobian column, a Levenberg–Marquardt trial):
    /// warm-started from its states and starting from its factorisations of K', which serve the
    /// nearby solves as long as they contract ([`StaticProblem::solve_forces_with`]).
    pub fn simulate_near(
        &self,
        ctx: &Context,
        theta: &[f64],
        subset: &[usize],
        base: &Simulated,
    ) -> Result<Simulated, DiagnoseError> {
        let hints = (base.factors.len() == subset.len()).then_some(base.factors.as_slice());
        self.simulate_with(ctx, theta, subset, Some(&base.x), hints)
    }

    fn simulate_with(
        &self,
        ctx: &Context,
        theta: &[f64],
        subset: &[usize],
        warm: Option<&[Vec<[f64; 3]>]>,
        hints: Option<&[Arc<Factorised>]>,
    ) -> Result<Simulated, DiagnoseError> {
        let log_e = self.log_e_field(ctx, theta);
        // Measurements are independent solves: one per core (the refined mesh of the
        // approximation-error correction spends most of its time here).
        let solve_one =
            |k: usize, i: usize| -> Result<(Vec<[f64; 3]>, Arc<Factorised>), DiagnoseError> {
                let m = &ctx.meas[i];
                let f = self.model_force(ctx, theta, i);
                let mut fvec = self.load_vector(ctx, theta, i, f)?;
                if let Some(rho) = self.block(Candidate::Gravity, theta, ctx.grid) {
                    add_gravity(ctx, rho[0], &mut fvec);
                }
                let start = warm.map(|w| w[k].as_slice());
                let stiffening = self.block(Candidate::Stiffening, theta, ctx.grid);
                // Warm-started (a Jacobian column, an LM trial, a held-out refit): the secant moduli
                // at the warm state are already close to the fixed point, so start there rather than
                // from the linear material (measured: a stiffening-only diagnosis of a 648-tet
                // specimen takes 14.8 s of CPU instead of 28 s, with identical scores).
                let m0 = match (stiffening, start) {
                    (Some(b), Some(w)) => Some(stiffening_log_e(ctx, w, b[0])),
                    _ => None,
                };
                let mat = self.material(ctx, theta, log_e.as_deref(), m0.as_deref())?;
                let hint = hints.and_then(|h| h.get(k));
                let solved = self
                    .problem(ctx)
                    .solve_forces_with(&mat, &fvec, start, &ctx.solve, hint)?;
                let (mut x, mut factor) = (solved.solution.x, solved.factor);
                if let Some(beta) = stiffening {
                    (x, factor) = self.stiffening_equilibrium(
                        ctx,
                        theta,
                        log_e.as_deref(),
                        beta[0],
                        (&fvec, &m.id),
                        m0,
                        (x, factor),
                    )?;
                }
                Ok((x, factor))
            };
        let (xs, factors): (Vec<Vec<[f64; 3]>>, Vec<Arc<Factorised>>) = subset
            .par_iter()
            .enumerate()
            .map(|(k, &i)| solve_one(k, i))
            .collect::<Result<Vec<_>, _>>()?
            .into_iter()
            .unzip();
        let embedding = match self.block(Candidate::Gravity, theta, ctx.grid) {
            Some(rho) => Some(self.rest_scan_embedding(ctx, theta, log_e.as_deref(), rho[0])?),
            None => None,
        };
        let tilt = if self.effects.contains(&Candidate::TiltEach) {
            Some(self.tilt_columns(
                ctx,
                theta,
                subset,
                &xs,
                &factors,
                log_e.as_deref(),
                embedding.as_deref(),
            )?)
        } else {
            None
        };
        Ok(Simulated {
            markers: self.markers_from(
                ctx,
                theta,
                subset,
                &xs,
                embedding.as_deref(),
                tilt.as_deref(),
            ),
            x: xs,
            factors,
            embedding,
            tilt,
        })
    }

    /// [`Candidate::TiltEach`]'s marker responses at a simulation `sim` of this model (whether or
    /// not the model holds the candidate): what the power statement of a clean verdict needs.
    pub fn tilt_responses(
        &self,
        ctx: &Context,
        theta: &[f64],
        subset: &[usize],
        sim: &Simulated,
    ) -> Result<Vec<[Vec<[f64; 3]>; 2]>, DiagnoseError> {
        let log_e = self.log_e_field(ctx, theta);
        self.tilt_columns(
            ctx,
            theta,
            subset,
            &sim.x,
            &sim.factors,
            log_e.as_deref(),
            sim.embedding.as_deref(),
        )
    }

    /// The marker responses of [`Candidate::TiltEach`]: for each measurement, two more solves with
    /// the force tilted by [`TILT_PROBE`]·|f| along t₁ and t₂ (warm-started from `xs` and from the
    /// factorisation of K' that measurement's own solve ended with: the tilted load changes the
    /// rotations by a tenth of the load's, so the kept factor serves and no new factorisation is
    /// made), their markers minus the untilted ones, per unit coefficient. Measurements in parallel.
    #[allow(clippy::too_many_arguments)]
    fn tilt_columns(
        &self,
        ctx: &Context,
        theta: &[f64],
        subset: &[usize],
        xs: &[Vec<[f64; 3]>],
        factors: &[Arc<Factorised>],
        log_e: Option<&[f64]>,
        embedding: Option<&[Marker]>,
    ) -> Result<Vec<[Vec<[f64; 3]>; 2]>, DiagnoseError> {
        let mat = self.material(ctx, theta, log_e, None)?;
        subset
            .par_iter()
            .zip(xs)
            .enumerate()
            .map(|(k, (&i, x))| {
                let m = &ctx.meas[i];
                let f = self.model_force(ctx, theta, i);
                let fm = Vector3::from(m.force).norm();
                let base = self.physical_markers(ctx, theta, i, x, embedding);
                let mut cols: [Vec<[f64; 3]>; 2] = [Vec::new(), Vec::new()];
                for (j, t) in ctx.tangents.iter().enumerate() {
                    if fm == 0.0 {
                        cols[j] = vec![[0.0; 3]; base.len()];
                        continue;
                    }
                    let ft = [0, 1, 2].map(|d| f[d] + TILT_PROBE * fm * t[d]);
                    let mut fvec = self.load_vector(ctx, theta, i, ft)?;
                    if let Some(rho) = self.block(Candidate::Gravity, theta, ctx.grid) {
                        add_gravity(ctx, rho[0], &mut fvec);
                    }
                    let xt = self
                        .problem(ctx)
                        .solve_forces_with(&mat, &fvec, Some(x), &ctx.solve, factors.get(k))?
                        .solution
                        .x;
                    let tilted = self.physical_markers(ctx, theta, i, &xt, embedding);
                    cols[j] = tilted
                        .iter()
                        .zip(&base)
                        .map(|(a, b)| [0, 1, 2].map(|d| (a[d] - b[d]) / TILT_PROBE))
                        .collect();
                }
                Ok(cols)
            })
            .collect()
    }

    /// Where the markers sit on the unloaded object when the rest scan was taken under gravity
    /// (the gravity candidate: "the rest scan was taken under gravity"). The dataset embeds each
    /// marker's scanned position at the nearest surface point; under a preload that scan is the
    /// sagged position, so on a side face the nearest point is a material point shifted by the
    /// sag, and the model would apply the sag twice. The material point X of marker k solves
    /// X + u_g(X) = rest_k with u_g the gravity-only displacement at θ: one fixed-point step
    /// from the dataset's embedding (u_g varies slowly over the surface; the sag is a fraction of
    /// an element), re-embedded there with X's own offset from the surface. (The sag is taken at
    /// the surface point, without the marker's offset: the dataset's offset of a scan under
    /// gravity *is* the sag's normal part, and carrying it beside u_g(X) applied that part twice —
    /// a signal no such data hold, which made the candidate's power statement claim ρ ≥ 65 kg/m³
    /// on a specimen whose ρ = 1,000 kg/m³ was not there to be seen.)
    fn rest_scan_embedding(
        &self,
        ctx: &Context,
        theta: &[f64],
        log_e: Option<&[f64]>,
        rho: f64,
    ) -> Result<Vec<Marker>, DiagnoseError> {
        let mut fvec = vec![0.0; 3 * ctx.node_volume.len()];
        add_gravity(ctx, rho, &mut fvec);
        let mat = self.material(ctx, theta, log_e, None)?;
        let xg = self
            .problem(ctx)
            .solve_forces(&mat, &fvec, None, &ctx.solve)?
            .solution
            .x;
        Ok(ctx
            .markers
            .iter()
            .map(|m| {
                let (sagged, unloaded) = (
                    m.surface_point(|n| xg[n]),
                    m.surface_point(|n| ctx.problem.x0[n]),
                );
                let q = [0, 1, 2].map(|d| m.rest[d] - (sagged[d] - unloaded[d]));
                match palpate_fem::dataset::embed::embed_point_in(
                    &ctx.problem.x0,
                    &ctx.problem.surface,
                    q,
                ) {
                    Some(e) => Marker::embedded(m.id.clone(), q, &e, &ctx.problem.x0),
                    None => m.clone(),
                }
            })
            .collect())
    }

    /// The material the model uses at the solved state `x` (the secant moduli of the stiffening
    /// effect evaluated at x's strains): what the runtime export blends between.
    pub fn material_at(
        &self,
        ctx: &Context,
        theta: &[f64],
        x: &[[f64; 3]],
    ) -> Result<Material, DiagnoseError> {
        let log_e = self.log_e_field(ctx, theta);
        let extra = self
            .block(Candidate::Stiffening, theta, ctx.grid)
            .map(|b| stiffening_log_e(ctx, x, b[0]));
        self.material(ctx, theta, log_e.as_deref(), extra.as_deref())
    }

    /// Marker positions from solved node positions: support motion and registration applied,
    /// then the profiled per-measurement effects (the tangential force of
    /// [`Candidate::TiltEach`] from its responses `tilt`, the rigid transform of
    /// [`Candidate::RegistrationEach`]).
    pub fn markers_from(
        &self,
        ctx: &Context,
        theta: &[f64],
        subset: &[usize],
        xs: &[Vec<[f64; 3]>],
        embedding: Option<&[Marker]>,
        tilt: Option<&[[Vec<[f64; 3]>; 2]]>,
    ) -> Vec<Vec<[f64; 3]>> {
        let mut sims: Vec<Vec<[f64; 3]>> = subset
            .iter()
            .zip(xs)
            .map(|(&i, x)| self.physical_markers(ctx, theta, i, x, embedding))
            .collect();
        if self.effects.contains(&Candidate::ForceScaleEach) {
            force_scale_each(ctx, subset, &mut sims);
        }
        sims.into_iter()
            .zip(subset)
            .enumerate()
            .map(|(k, (mut sim, &i))| {
                if let Some(cols) = tilt.and_then(|t| t.get(k)) {
                    sim = tilt_each(ctx, i, sim, cols);
                }
                if self.effects.contains(&Candidate::RegistrationEach) {
                    sim = self.register_each(ctx, i, sim);
                }
                sim
            })
            .collect()
    }

    /// Measurement `i`'s observed markers on the solved positions `x`, with the support motion,
    /// the mesh correction and the global registration (the effects with parameters in θ).
    fn physical_markers(
        &self,
        ctx: &Context,
        theta: &[f64],
        i: usize,
        x: &[[f64; 3]],
        embedding: Option<&[Marker]>,
    ) -> Vec<[f64; 3]> {
        let boundary = self.block(Candidate::Boundary, theta, ctx.grid);
        let reg = self.block(Candidate::Registration, theta, ctx.grid);
        let m = &ctx.meas[i];
        let f = self.model_force(ctx, theta, i);
        let support = boundary.map(|b| {
            let t = f.map(|v| v * b[0] * 1e-4);
            let arm = [0, 1, 2].map(|d| m.point[d] - ctx.base[d]);
            let w = <[f64; 3]>::from(Vector3::from(arm).cross(&Vector3::from(f)))
                .map(|v| v * b[1] * 1e-4 / (ctx.half * ctx.half));
            (t, w)
        });
        let delta = ctx.correction.as_ref().map(|c| &c[i]);
        m.observed
            .iter()
            .enumerate()
            .map(|(j, &(k, _))| {
                let marker = embedding.map_or(&ctx.markers[k], |e| &e[k]);
                let mut p = marker.interpolate(|n| x[n]);
                if let Some(d) = delta {
                    p = [0, 1, 2].map(|a| p[a] + d[j][a]);
                }
                if let Some((t, w)) = support {
                    let r = [0, 1, 2].map(|d| p[d] - ctx.base[d]);
                    let wr = Vector3::from(w).cross(&Vector3::from(r));
                    p = [0, 1, 2].map(|d| p[d] + t[d] + wr[d]);
                }
                if let Some(g) = reg {
                    let w = [g[0], g[1], g[2]].map(|v| v * 1e-3);
                    let r = rotate(w, [0, 1, 2].map(|d| p[d] - ctx.centre[d]));
                    p = [0, 1, 2].map(|d| ctx.centre[d] + r[d] + g[3 + d] * 1e-4);
                }
                p
            })
            .collect()
    }

    /// [`Candidate::RegistrationEach`] on measurement `i`: `sim` moved by the weighted rigid
    /// transform that best maps it onto the measured markers (unchanged when that is degenerate).
    fn register_each(&self, ctx: &Context, i: usize, sim: Vec<[f64; 3]>) -> Vec<[f64; 3]> {
        let m = &ctx.meas[i];
        let measured: Vec<[f64; 3]> = m.observed.iter().map(|&(_, q)| q).collect();
        let scale = 3.0 * ctx.sigma;
        let w: Vec<f64> = m
            .observed
            .iter()
            .zip(&sim)
            .map(|(&(k, _), p)| {
                let u = (0..3)
                    .map(|d| (p[d] - ctx.marker_rest[k][d]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                1.0 / (1.0 + (u / scale).powi(2))
            })
            .collect();
        match palpate_capture::register::weighted_orientation(&sim, &measured, &w) {
            Some((r, t)) => sim
                .iter()
                .map(|p| {
                    let q = r * Vector3::from(*p) + t;
                    [q.x, q.y, q.z]
                })
                .collect(),
            None => sim,
        }
    }

    /// Scaled residuals (simulated − measured)/σ of `subset`, stacked.
    pub fn residuals(
        &self,
        ctx: &Context,
        subset: &[usize],
        markers: &[Vec<[f64; 3]>],
    ) -> Vec<f64> {
        let mut r = Vec::with_capacity(ctx.residual_len(subset));
        for (&i, sim) in subset.iter().zip(markers) {
            for (&(_, meas), p) in ctx.meas[i].observed.iter().zip(sim) {
                for d in 0..3 {
                    r.push((p[d] - meas[d]) / ctx.sigma);
                }
            }
        }
        r
    }
}
