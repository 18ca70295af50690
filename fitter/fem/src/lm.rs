//! The dense Levenberg–Marquardt of the offline tools, in two forms for small problems:
//!
//! - [`minimise`] (Marquardt's diagonal scaling: the damped normal matrix is
//!   JᵀJ + μ·diag(max(JᵀJ_dd, 1e-12))), on residuals and a Jacobian made at accepted points: the
//!   diagnosis' augmented static model (`palpate-diagnose` `fit`) and its measured-curve laws
//!   (`curve::lm`). The callers choose the constants ([`LmOptions`]) and how the Jacobian and
//!   residuals are made; a state `S` travels with the accepted θ (a warm start for the next solve).
//! - [`minimise_trust_region`] (Moré's trust-region form, with a structured secant term as in
//!   NL2SOL), on Φ = ½‖r‖², ∇Φ = Jᵀr and JᵀJ delivered together by every evaluation ([`Normal`]):
//!   the motion fitter, whose simulation gives all three at once from its direct sensitivities
//!   (`palpate-motion` `optimize`), where a residual vector of every marker at every step is
//!   never formed, and where Φ of a model out of phase with an oscillation is not convex.
//!
//! Not used by the displacement-based static inverse (`palpate-static-fit` `displacement`): that
//! one damps with μI on a Hessian that may be matrix-free (adjoint products and CG on large
//! per-element layouts), so it is a different method, kept where it is.

use nalgebra::{DMatrix, DVector};

/// The constants of one use of [`minimise`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmOptions {
    /// Outer iterations (one Jacobian each).
    pub max_iterations: usize,
    /// Damped solves tried per iteration before giving up.
    pub tries: usize,
    /// μ at the start.
    pub initial_damping: f64,
    /// Lower bound of μ after an accepted step (μ ← max(μ/3, this)).
    pub min_damping: f64,
    /// μ ← μ × this after a trial that did not lower the cost (×10 after a singular system).
    pub reject_factor: f64,
    /// Stop when an accepted step lowers the cost by less than this fraction.
    pub rel_tolerance: f64,
    /// Floor of the cost in that fraction's denominator.
    pub cost_floor: f64,
}

/// Where [`minimise`] stopped.
#[derive(Debug, Clone)]
pub struct LmOutcome<S> {
    /// Parameters.
    pub theta: Vec<f64>,
    /// Residuals at θ.
    pub residuals: Vec<f64>,
    /// ‖r‖² at θ.
    pub cost: f64,
    /// The state that came with θ.
    pub state: S,
    /// Outer iterations run.
    pub iterations: usize,
    /// Whether the relative-decrease test stopped it (not the iteration limit or a failed
    /// iteration).
    pub converged: bool,
    /// JᵀJ of the last Jacobian evaluated (zeros if none was).
    pub jtj: DMatrix<f64>,
}

fn sum_of_squares(r: &[f64]) -> f64 {
    r.iter().map(|v| v * v).sum()
}

/// Minimises ‖r(θ)‖² from θ₀ (with residuals `r0` and state `state0` there). `jacobian(θ, state,
/// r)` gives J at an accepted point (its error aborts); `eval(θ)` gives a trial's residuals and
/// state, `None` where the model is undefined (the trial counts as rejected).
pub fn minimise<S, E>(
    theta0: Vec<f64>,
    r0: Vec<f64>,
    state0: S,
    mut jacobian: impl FnMut(&[f64], &S, &[f64]) -> Result<DMatrix<f64>, E>,
    mut eval: impl FnMut(&[f64], &S) -> Option<(Vec<f64>, S)>,
    o: &LmOptions,
) -> Result<LmOutcome<S>, E> {
    let p = theta0.len();
    let mut theta = theta0;
    let mut r = r0;
    let mut state = state0;
    let mut cost = sum_of_squares(&r);
    let mut mu = o.initial_damping;
    let mut jtj = DMatrix::zeros(p, p);
    let mut iterations = 0;
    // A start whose cost is below rel_tolerance × cost_floor has converged: no step can lower
    // it by more than that (the cost is ≥ 0), so no Jacobian is spent to find it out. Data a
    // model holds exactly, refitted from where they were made, start there.
    let mut converged = cost <= o.rel_tolerance * o.cost_floor;
    while iterations < o.max_iterations && !converged {
        iterations += 1;
        let j = jacobian(&theta, &state, &r)?;
        jtj = j.transpose() * &j;
        let g = j.transpose() * DVector::from_column_slice(&r);
        let mut accepted = false;
        for _ in 0..o.tries {
            let mut a = jtj.clone();
            for d in 0..p {
                a[(d, d)] += mu * jtj[(d, d)].max(1e-12);
            }
            let Some(ch) = a.cholesky() else {
                mu *= 10.0;
                continue;
            };
            let step = ch.solve(&(-&g));
            let trial: Vec<f64> = theta.iter().zip(step.iter()).map(|(t, s)| t + s).collect();
            if let Some((rt, st)) = eval(&trial, &state) {
                let ct = sum_of_squares(&rt);
                if ct.is_finite() && ct < cost {
                    let rel = (cost - ct) / cost.max(o.cost_floor);
                    theta = trial;
                    r = rt;
                    state = st;
                    cost = ct;
                    mu = (mu / 3.0).max(o.min_damping);
                    accepted = true;
                    converged = rel < o.rel_tolerance;
                    break;
                }
            }
            mu *= o.reject_factor;
        }
        if !accepted || converged {
            break;
        }
    }
    Ok(LmOutcome {
        theta,
        residuals: r,
        cost,
        state,
        iterations,
        converged,
        jtj,
    })
}

/// What one evaluation of a least-squares objective gives [`minimise_trust_region`].
#[derive(Debug, Clone, PartialEq)]
pub struct Normal {
    /// Φ = ½ ‖r‖².
    pub phi: f64,
    /// ∇Φ = Jᵀ r.
    pub grad: Vec<f64>,
    /// The Gauss–Newton matrix JᵀJ, row-major p × p.
    pub gn: Vec<f64>,
}

/// The constants of one use of [`minimise_trust_region`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrustOptions {
    /// Iterations (one evaluation each).
    pub max_iterations: usize,
    /// Converged when a model that predicted its last accepted step to 25 %, or whose last
    /// accepted step gained less than this fraction of Φ, predicts a decrease below it.
    pub rel_tolerance: f64,
    /// Converged too when such a model's step, predicted to gain less than this fraction of Φ,
    /// gains nothing: Φ's own noise (an iterative solve's tolerance) is reached.
    pub noise_tolerance: f64,
    /// Φ's absolute precision: a decrease below it counts as none, whatever fraction of Φ it
    /// is (0: the relative tolerances alone). For a Φ whose size says nothing of the precision
    /// asked of it, such as noise-free data standing in for measured ones.
    pub abs_tolerance: f64,
    /// Trust radius at the start (Euclidean, in θ).
    pub initial_radius: f64,
    /// Largest trust radius.
    pub max_radius: f64,
    /// The coordinates tried on their lower bound when they run to it, bit k for coordinate k
    /// (k < 64; 0: none): those whose effect fades toward the bound, such as a log-parameter
    /// ([`minimise_trust_region`], [`RUN_SHARE`]).
    pub probe_bounds: u64,
}

impl TrustOptions {
    /// The smallest decrease of Φ that counts at Φ = `phi` for a tolerance of `fraction` of Φ:
    /// that fraction, or Φ's absolute precision where it is larger.
    pub(crate) fn least_gain(&self, fraction: f64, phi: f64) -> f64 {
        (fraction * phi).max(self.abs_tolerance)
    }
}

/// Where [`minimise_trust_region`] stopped.
#[derive(Debug, Clone)]
pub struct TrustOutcome {
    /// Parameters.
    pub theta: Vec<f64>,
    /// The evaluation at θ.
    pub normal: Normal,
    /// Iterations run.
    pub iterations: usize,
    /// Whether a convergence test stopped it (not the iteration limit).
    pub converged: bool,
    /// Where the iteration ended on a step confirmed by Φ alone ([`CONFIRM_BELOW`]): the θ
    /// last evaluated in full, whose ∇Φ and Gauss–Newton matrix `normal` carries to θ by the
    /// model (`None`: `normal` is θ's own evaluation).
    pub linearised_at: Option<Vec<f64>>,
}

/// Φ alone at θ (`None` where the model is undefined there), for a caller whose full evaluation
/// costs much more than Φ: a simulation with its parameters' sensitivities against one without.
pub type Value<'a, 'f> = &'a mut (dyn FnMut(&[f64]) -> Option<f64> + 'f);

/// A step whose model is trusted (it predicted the last accepted step to 25 %) and that is the
/// model's own minimum (cut by neither the radius nor a bound) is evaluated by Φ alone when it is
/// predicted to gain at most this multiple of the precision asked; if it then gains what it
/// predicted to 25 %, the iteration ends there. For a quadratic Φ whose curvature the model
/// misjudges by a factor c (a gain ratio ρ = 2 − c), the gain left after the model's step is
/// (1 − c)²/c of the prediction: at most 1/12 for ρ within 25 % of 1, so within the precision.
/// The step's own ∇Φ and Gauss–Newton matrix, which Φ alone does not give, are the model's:
/// so the step must also be short, at most [`CONFIRM_STEP`] in every coordinate.
pub const CONFIRM_BELOW: f64 = 12.0;

/// The longest step in any coordinate that [`CONFIRM_BELOW`] confirms. The Gauss–Newton matrix
/// the result takes from the point before it changes with the step at first order, in the
/// log-parameters a fit runs in by about the step's share, so the 1σ read off it by as much. A
/// gain below the precision is no bound on the step where Φ is flat: on the example bar with
/// noise, a last step predicted to gain 3·10⁻¹¹ moved ln λ by 0.13 and the viscosity's log by
/// 0.25, and the 1σ of λ read off the matrix before it was 13 % off the differenced one.
pub const CONFIRM_STEP: f64 = 0.025;

fn mat_vec(m: &[f64], v: &[f64]) -> Vec<f64> {
    let n = v.len();
    (0..n)
        .map(|i| (0..n).map(|j| m[i * n + j] * v[j]).sum::<f64>())
        .collect()
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// The step of the trust-region subproblem min gᵀs + ½ sᵀBs subject to ‖s‖ ≤ Δ (B symmetric,
/// small and dense): the Newton step when B is positive definite and it fits, else
/// s(λ) = −(B + λI)⁻¹ g with λ > max(0, −λ_min(B)) such that ‖s(λ)‖ = Δ — the
/// Levenberg–Marquardt parameter of Moré (1978), found by bisection on the eigen-decomposition.
pub fn trust_region_step(b: &[f64], g: &[f64], radius: f64) -> Vec<f64> {
    let n = g.len();
    let eig = nalgebra::SymmetricEigen::new(DMatrix::from_row_slice(n, n, b));
    let gq: Vec<f64> = (0..n)
        .map(|i| (0..n).map(|k| eig.eigenvectors[(k, i)] * g[k]).sum::<f64>())
        .collect();
    let lmin = eig
        .eigenvalues
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min);
    let scale = eig
        .eigenvalues
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(1e-300);
    let step_at = |lambda: f64| -> Vec<f64> {
        let c: Vec<f64> = (0..n)
            .map(|i| -gq[i] / (eig.eigenvalues[i] + lambda).max(1e-300 * scale))
            .collect();
        (0..n)
            .map(|k| (0..n).map(|i| eig.eigenvectors[(k, i)] * c[i]).sum::<f64>())
            .collect()
    };
    if lmin > 1e-12 * scale {
        let newton = step_at(0.0);
        if norm(&newton) <= radius {
            return newton;
        }
    }
    // ‖s(λ)‖ falls monotonically for λ > −λ_min: bracket it, then bisect (60 halvings).
    let mut lo = (-lmin).max(0.0) + 1e-12 * scale;
    let mut hi = lo.max(scale);
    while norm(&step_at(hi)) > radius && hi < 1e300 {
        hi *= 4.0;
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if norm(&step_at(mid)) > radius {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    step_at(hi)
}

/// The decrease −(gᵀs + ½ sᵀBs) that the model B predicts for the step s.
fn model_decrease(b: &[f64], g: &[f64], step: &[f64]) -> f64 {
    let bs = mat_vec(b, step);
    -(0..g.len())
        .map(|i| g[i] * step[i] + 0.5 * step[i] * bs[i])
        .sum::<f64>()
}

/// The share of an accepted step's length that one coordinate's downward move must be for the
/// step to count as that coordinate running to its bound ([`TrustOptions::probe_bounds`]).
pub const RUN_SHARE: f64 = 0.9;

/// Accepted steps in a row that must run a coordinate to its bound before it is tried there
/// ([`TrustOptions::probe_bounds`]).
pub const RUN_STEPS: usize = 3;

/// How much higher Φ may be on the bound than where a walk to it stands for [`probe_bound`] to
/// try a Gauss–Newton step of the other coordinates from there. On the independent generator's
/// cylinders the steps that found a lower point started 1.19–1.22 times higher, and those that
/// did not 1.16 and 3–100 times.
const PROBE_FAR: f64 = 1.5;

/// The gain ratio ρ = actual / predicted decrease of an accepted step from which H is taken to
/// over-state the curvature ([`model_step`]'s `concave`): the step gained half as much again as
/// H promised.
const UNDER_PREDICTED: f64 = 1.5;

/// The trust-region step of the model in use (H + S when `augmented`, else H) and whether it is
/// still H + S. Φ = ½‖r‖² ≥ 0, so a model promising a decrease larger than Φ is wrong at that
/// length before it is tried (the secant term has turned indefinite the wrong way): the step is
/// then H's, and no simulation is spent on the other.
///
/// Except where Φ has shown itself concave (`concave`: the last accepted step gained at least
/// [`UNDER_PREDICTED`] times its prediction). There H, which lacks the negative second-order
/// term, over-states the curvature and steps a small fraction of the way (an undamped model out
/// of phase with a ring-down: every step gains twice its prediction, and the fit crawls), while
/// H + S is indefinite and its step runs to the radius. The secant step is then shortened to the
/// length where it promises half of Φ (all of Φ would be a perfect fit) and taken when it still
/// promises more than H's own step. Without that evidence, a secant model's over-promise says
/// only that it is wrong, and H decides: a misfit with several minima (a time offset against an
/// oscillation) keeps Gauss–Newton's local step.
fn model_step(
    h: &[f64],
    with_s: &[f64],
    g: &[f64],
    phi: f64,
    radius: f64,
    augmented: bool,
    concave: bool,
) -> (Vec<f64>, bool) {
    if augmented {
        let step = trust_region_step(with_s, g, radius);
        if model_decrease(with_s, g, &step) <= phi {
            return (step, true);
        }
        if concave {
            let newton = trust_region_step(h, g, radius);
            let promised = model_decrease(h, g, &newton);
            // The promise grows with the radius: bisect it down to half of Φ (no simulation).
            let (mut lo, mut hi) = (0.0, radius);
            for _ in 0..50 {
                let mid = 0.5 * (lo + hi);
                if model_decrease(with_s, g, &trust_region_step(with_s, g, mid)) > 0.5 * phi {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
            let short = trust_region_step(with_s, g, lo);
            if model_decrease(with_s, g, &short) > promised {
                return (short, true);
            }
            return (newton, false);
        }
    }
    (trust_region_step(h, g, radius), false)
}

/// Minimises Φ from θ₀ (evaluated: `first`) by Levenberg–Marquardt in Moré's trust-region form:
/// each iteration minimises the model gᵀs + ½ sᵀBs within the radius Δ ([`trust_region_step`]),
/// evaluates θ + s (`eval` gives `None` where the model is undefined: a rejected step), accepts it
/// when Φ falls, and sets Δ from the gain ratio ρ = ΔΦ / predicted ΔΦ (×2 at ρ > ¾ on the
/// boundary, to ¼ of the step at ρ < ¼ or on a rejection).
///
/// B is the Gauss–Newton matrix H = JᵀJ, or H + S where S, the second-order term Σ r_k ∇²r_k that
/// H lacks, is learnt from the gradients of accepted steps by a symmetric rank-one secant update
/// ((H_new + S_new) s = Δ∇Φ; it may be indefinite, as Φ is where a model oscillates out of phase
/// with its data). As in NL2SOL (Dennis, Gay & Welsch 1981) the iteration starts with H and, after
/// each accepted step, keeps the model whose predicted decrease was nearer the actual one; a
/// rejected step returns to H. With a residual that does not vanish plain Gauss–Newton converges
/// only linearly, or crawls where Φ is not convex; H + S restores a superlinear finish.
///
/// θ is held on or above `lower` (−∞ where free): a step that would take a coordinate below its
/// bound stops it on the bound, and a coordinate on its bound whose gradient points below it is
/// held there (its gradient and its row and column of the model removed) while the others move —
/// a projected Gauss–Newton iteration in the manner of the active-set methods for
/// bound-constrained least squares: the bound becomes active in one step instead of being
/// approached a fraction at a time.
///
/// A coordinate of [`TrustOptions::probe_bounds`] that runs to its bound — [`RUN_STEPS`]
/// accepted steps in a row, each at least [`RUN_SHARE`] of its length that coordinate's and
/// downward — is tried on the bound, the others where they are, then if need be with one
/// Gauss–Newton step of the others from there (`probe_bound`: one or two evaluations, each
/// counted as an iteration; once per coordinate). The point is taken when Φ is lower there than
/// where the walk stands. A log-parameter whose effect fades as it falls (a Lamé λ that a locking
/// mesh asks to vanish) is a Φ that saturates: Gauss–Newton's curvature there falls as the square
/// of the effect and its step runs to the radius, so the iteration walks one radius a step, each
/// gaining less, until the gain is below the precision asked — a dozen simulations or more that
/// the bound, where the walk ends, settles in one or two.
///
/// With one coordinate the search is [`crate::one_coordinate::minimise_one_coordinate`]'s
/// instead: two evaluations determine a cubic model of Φ along the whole line, which the
/// secant term would learn a step late and the radius would walk in steps.
pub fn minimise_trust_region(
    theta0: Vec<f64>,
    first: Normal,
    eval: impl FnMut(&[f64]) -> Option<Normal>,
    o: &TrustOptions,
    lower: &[f64],
) -> TrustOutcome {
    trust_region_confirmed(theta0, first, eval, None, o, lower)
}

/// [`minimise_trust_region`] with Φ alone at hand (`value`): a last step predicted to gain
/// little is confirmed by it instead of a full evaluation ([`CONFIRM_BELOW`]).
fn trust_region_confirmed(
    theta0: Vec<f64>,
    first: Normal,
    eval: impl FnMut(&[f64]) -> Option<Normal>,
    value: Option<Value<'_, '_>>,
    o: &TrustOptions,
    lower: &[f64],
) -> TrustOutcome {
    if let ([t0], [floor]) = (theta0.as_slice(), lower) {
        return crate::one_coordinate::minimise_one_coordinate(*t0, first, eval, o, *floor);
    }
    trust_region_iteration(theta0, first, eval, value, o, lower)
}

/// [`minimise_trust_region`]'s iteration in any number of coordinates.
fn trust_region_iteration(
    theta0: Vec<f64>,
    first: Normal,
    mut eval: impl FnMut(&[f64]) -> Option<Normal>,
    mut value: Option<Value<'_, '_>>,
    o: &TrustOptions,
    lower: &[f64],
) -> TrustOutcome {
    let np = theta0.len();
    let mut theta = theta0;
    let mut cur = first;
    let mut sc = vec![0.0; np * np];
    let mut augmented = false;
    // Whether the model predicted the last accepted step's decrease to 25 %: only then is a
    // small predicted decrease a sign of the minimum (Gauss–Newton alone can predict almost
    // nothing where Φ is not convex, and crawl).
    let mut trusted = false;
    // What the last accepted step gained (∞ before the first): a model that predicts almost
    // nothing after a step that gained almost nothing is at the minimum too, however poorly it
    // predicted that step — a parameter running to its neutral value in log space (each step
    // halves an effect that is no longer there) gains a round-off-sized amount its model cannot
    // predict to 25 %, and would otherwise step on until the iteration limit.
    let mut gained = f64::INFINITY;
    // Whether the last accepted step gained at least UNDER_PREDICTED times its prediction.
    let mut concave = false;
    let mut radius = o.initial_radius;
    let mut iterations = 0;
    let mut converged = false;
    let mut linearised_at = None;
    // Per coordinate: accepted steps in a row that ran it toward its bound, and whether it was
    // tried on the bound.
    let mut running = vec![0usize; np];
    let mut probed = vec![false; np];
    while iterations < o.max_iterations {
        iterations += 1;
        let (g, h, phi) = (&cur.grad, &cur.gn, cur.phi);
        let with_s: Vec<f64> = h.iter().zip(&sc).map(|(a, b)| a + b).collect();
        let held = held_model(&theta, lower, g, [h, &with_s]);
        let (gm, hm, sm) = match &held {
            Some(m) => (&m.g, &m.h, &m.s),
            None => (g, h, &with_s),
        };
        let free_step;
        (free_step, augmented) = model_step(hm, sm, gm, phi, radius, augmented, concave);
        let (step, hit) = within_bounds(&theta, lower, free_step);
        let length = norm(&step);
        let model = if augmented { sm } else { hm };
        let predicted = model_decrease(model, gm, &step);
        let other = model_decrease(if augmented { hm } else { sm }, gm, &step);
        // A NaN prediction (a model that cannot say) counts as no decrease. A step stopped on a
        // bound says nothing of the minimum: the next iteration starts on the bound.
        let tolerance = o.least_gain(o.rel_tolerance, phi);
        let small = hit.is_empty()
            && predicted.partial_cmp(&tolerance) != Some(std::cmp::Ordering::Greater);
        let stalled = gained <= tolerance;
        if ((trusted || stalled) && small) || (length < 1e-8 && hit.is_empty()) || radius < 1e-8 {
            converged = true;
            break;
        }
        log::debug!(
            "trust-region Levenberg–Marquardt {iterations}: Φ {phi:.6e}, predicted decrease {predicted:.3e}, step {step:?}, radius {radius:.2e}, {}",
            if augmented { "H + S" } else { "H" }
        );
        let mut trial: Vec<f64> = theta.iter().zip(&step).map(|(a, b)| a + b).collect();
        for &k in &hit {
            trial[k] = lower[k];
        }
        let own_minimum = hit.is_empty() && length < 0.99 * radius;
        let short = step.iter().all(|s| s.abs() <= CONFIRM_STEP);
        if let Some(value) = value
            .as_mut()
            .filter(|_| trusted && own_minimum && short && predicted <= CONFIRM_BELOW * tolerance)
        {
            let confirmed = value(&trial)
                .filter(|v| v.is_finite() && *v < phi)
                .filter(|v| ((phi - v) / predicted - 1.0).abs() < 0.25);
            if let Some(v) = confirmed {
                log::debug!(
                    "trust-region Levenberg–Marquardt: Φ {v:.6e} alone confirms the step's \
                     predicted decrease to 25 %: converged"
                );
                // ∇Φ at the step by the model it minimised (zero where no coordinate is held).
                let grad: Vec<f64> = mat_vec(if augmented { &with_s } else { h }, &step)
                    .iter()
                    .zip(g)
                    .map(|(bs, g)| g + bs)
                    .collect();
                linearised_at = Some(theta);
                theta = trial;
                cur = Normal {
                    phi: v,
                    grad,
                    gn: cur.gn,
                };
                converged = true;
                break;
            }
        }
        match eval(&trial) {
            Some(next) if next.phi < phi => {
                let actual = phi - next.phi;
                gained = actual;
                let rho = actual / predicted;
                trusted = (rho - 1.0).abs() < 0.25;
                concave = rho >= UNDER_PREDICTED;
                if rho > 0.75 && length > 0.99 * radius {
                    radius = (2.0 * radius).min(o.max_radius);
                } else if rho < 0.25 {
                    radius = 0.25 * length;
                }
                if (actual - other).abs() < (actual - predicted).abs() {
                    augmented = !augmented;
                }
                // The secant update (symmetric rank one), skipped when ill-conditioned.
                let y: Vec<f64> = next.grad.iter().zip(g).map(|(a, b)| a - b).collect();
                let hs = mat_vec(&next.gn, &step);
                let ss = mat_vec(&sc, &step);
                let r: Vec<f64> = (0..np).map(|i| y[i] - hs[i] - ss[i]).collect();
                let rs: f64 = r.iter().zip(&step).map(|(a, b)| a * b).sum();
                if rs.abs() > 1e-8 * norm(&r) * length {
                    for i in 0..np {
                        for j in 0..np {
                            sc[i * np + j] += r[i] * r[j] / rs;
                        }
                    }
                }
                theta = trial;
                cur = next;
                for k in 0..np {
                    let runs = step[k] < -RUN_SHARE * length
                        && lower[k].is_finite()
                        && !on_bound(theta[k], lower[k]);
                    running[k] = if runs { running[k] + 1 } else { 0 };
                }
                let run = (0..np.min(64)).find(|&k| {
                    running[k] >= RUN_STEPS && !probed[k] && o.probe_bounds >> k & 1 == 1
                });
                if let Some(k) = run {
                    probed[k] = true;
                    running[k] = 0;
                    let budget = o.max_iterations - iterations;
                    let (found, used) = probe_bound(&theta, &cur, k, lower, o, &mut eval, budget);
                    iterations += used;
                    if let Some((at, next)) = found {
                        // A jump, not a step of the model: the secant term and the trust in
                        // the model start again from Gauss–Newton's.
                        gained = cur.phi - next.phi;
                        (theta, cur) = (at, next);
                        sc.iter_mut().for_each(|v| *v = 0.0);
                        (augmented, trusted, concave) = (false, false, false);
                    }
                }
            }
            Some(_) if trusted && predicted < o.least_gain(o.noise_tolerance, phi) => {
                converged = true;
                break;
            }
            _ => {
                radius = 0.25 * length;
                augmented = false;
                concave = false;
            }
        }
    }
    TrustOutcome {
        theta,
        normal: cur,
        iterations,
        converged,
        linearised_at,
    }
}

/// Coordinate `k` of θ (evaluated: `cur`) tried on its lower bound, the others where they are;
/// if Φ is not lower there but within [`PROBE_FAR`] of `cur`'s, one Gauss–Newton step of the
/// others from there (k held on the bound while its gradient points below it, [`held_model`]; the
/// radius [`TrustOptions::initial_radius`]): the coordinates a fading one leaves behind move with
/// it, so the bound alone is rarely lower than where the walk stands. Returns the point and its
/// evaluation when Φ is lower there than `cur`'s, and the evaluations spent (at most `budget`).
fn probe_bound(
    theta: &[f64],
    cur: &Normal,
    k: usize,
    lower: &[f64],
    o: &TrustOptions,
    eval: &mut impl FnMut(&[f64]) -> Option<Normal>,
    budget: usize,
) -> (Option<(Vec<f64>, Normal)>, usize) {
    if budget == 0 {
        return (None, 0);
    }
    let mut on = theta.to_vec();
    on[k] = lower[k];
    let there = eval(&on);
    let phi_on = there.as_ref().map_or(f64::NAN, |n| n.phi);
    if let Some(n) = there.as_ref().filter(|n| n.phi < cur.phi) {
        log::debug!(
            "Levenberg–Marquardt: coordinate {k} running to its bound tried on it ({:.4} → {:.4}): Φ {:.6e} → {phi_on:.6e}, taken",
            theta[k],
            lower[k],
            cur.phi
        );
        return (Some((on, n.clone())), 1);
    }
    // Where Φ on the bound is more than PROBE_FAR times the walk's, the bound is not where the
    // walk is going (an interior minimum, the others far from their best): their step is not
    // tried.
    let moved = match (there, budget > 1) {
        (Some(n), true) if n.phi <= PROBE_FAR * cur.phi => {
            let held = held_model(&on, lower, &n.grad, [&n.gn, &n.gn]);
            let (g, h) = held.as_ref().map_or((&n.grad, &n.gn), |m| (&m.g, &m.h));
            let (step, hit) = within_bounds(&on, lower, trust_region_step(h, g, o.initial_radius));
            let mut at: Vec<f64> = on.iter().zip(&step).map(|(a, b)| a + b).collect();
            for &i in &hit {
                at[i] = lower[i];
            }
            let next = eval(&at);
            Some((at, next))
        }
        _ => None,
    };
    let phi_moved = moved
        .as_ref()
        .and_then(|m| m.1.as_ref())
        .map_or(f64::NAN, |n| n.phi);
    let taken = phi_moved < cur.phi;
    log::debug!(
        "Levenberg–Marquardt: coordinate {k} running to its bound tried on it ({:.4} → {:.4}): Φ {:.6e} → {phi_on:.6e}, {phi_moved:.6e} after a Gauss–Newton step of the others, {}",
        theta[k],
        lower[k],
        cur.phi,
        if taken { "taken" } else { "not taken" }
    );
    match moved {
        Some((at, Some(n))) if taken => (Some((at, n)), 2),
        Some(_) => (None, 2),
        None => (None, 1),
    }
}

/// Whether θ_k sits on its lower bound (to rounding).
fn on_bound(theta: f64, lower: f64) -> bool {
    theta <= lower + 1e-12 * lower.abs().max(1.0)
}

/// The model (g, B) with the coordinates held at their lower bounds removed: a coordinate on its
/// bound whose gradient points below it (g_k > 0: Φ falls as θ_k falls) gets g_k = 0 and a unit
/// row and column in B, so every step leaves it where it is. `None` when nothing is held.
fn held_model(theta: &[f64], lower: &[f64], g: &[f64], bs: [&[f64]; 2]) -> Option<HeldModel> {
    let np = theta.len();
    let held: Vec<usize> = (0..np)
        .filter(|&k| on_bound(theta[k], lower[k]) && g[k] > 0.0)
        .collect();
    if held.is_empty() {
        return None;
    }
    let mut g = g.to_vec();
    let [mut h, mut s] = bs.map(<[f64]>::to_vec);
    for &k in &held {
        g[k] = 0.0;
        for b in [&mut h, &mut s] {
            for j in 0..np {
                b[k * np + j] = 0.0;
                b[j * np + k] = 0.0;
            }
            b[k * np + k] = 1.0;
        }
    }
    Some(HeldModel { g, h, s })
}

/// [`held_model`]'s gradient, Gauss–Newton matrix and H + S.
struct HeldModel {
    g: Vec<f64>,
    h: Vec<f64>,
    s: Vec<f64>,
}

/// `step` projected onto the bounds: a coordinate that θ + step would take below `lower` stops on
/// it (the other coordinates keep their step). Returns the step and the coordinates it stopped.
fn within_bounds(theta: &[f64], lower: &[f64], mut step: Vec<f64>) -> (Vec<f64>, Vec<usize>) {
    let mut hit = Vec::new();
    for k in 0..theta.len() {
        if theta[k] + step[k] < lower[k] {
            step[k] = (lower[k] - theta[k]).min(0.0);
            hit.push(k);
        }
    }
    (step, hit)
}

/// [`minimise_trust_region`], started again from where it stopped while a convergence test fired
/// that is not the minimum's. Rejected steps (a simulation that fails, a secant model that
/// misled) shrink the radius until the step is too short to count or the little the model
/// predicts looks converged, far from the minimum. From the point reached, Gauss–Newton's model
/// and a fresh radius ([`TrustOptions::initial_radius`]) decide: while its step promises more
/// than Φ's noise (`noise_tolerance` of Φ) the iteration goes on, and it ends when a restart
/// gains less than the precision asked (`rel_tolerance` of Φ) or the iteration limit, counted
/// over every restart, is reached. θ is held on or above `lower` as in [`minimise_trust_region`].
pub fn minimise_restarting(
    theta0: Vec<f64>,
    first: Normal,
    eval: impl FnMut(&[f64]) -> Option<Normal>,
    o: &TrustOptions,
    lower: &[f64],
) -> TrustOutcome {
    restarting(theta0, first, eval, None, o, lower)
}

/// [`minimise_restarting`] with Φ alone at hand (`value`), for an evaluation whose ∇Φ and
/// Gauss–Newton matrix cost much more than Φ: a last step predicted to gain at most
/// [`CONFIRM_BELOW`] times the precision asked is confirmed by Φ alone, and the iteration ends
/// there ([`TrustOutcome::linearised_at`]) without a restart.
pub fn minimise_restarting_confirmed(
    theta0: Vec<f64>,
    first: Normal,
    eval: impl FnMut(&[f64]) -> Option<Normal>,
    value: Value<'_, '_>,
    o: &TrustOptions,
    lower: &[f64],
) -> TrustOutcome {
    restarting(theta0, first, eval, Some(value), o, lower)
}

/// [`minimise_restarting`]'s iteration, with Φ alone at hand or without it.
fn restarting(
    theta0: Vec<f64>,
    first: Normal,
    mut eval: impl FnMut(&[f64]) -> Option<Normal>,
    mut value: Option<Value<'_, '_>>,
    o: &TrustOptions,
    lower: &[f64],
) -> TrustOutcome {
    let mut out = trust_region_confirmed(theta0, first, &mut eval, value.as_deref_mut(), o, lower);
    let mut iterations = out.iterations;
    while out.converged && out.linearised_at.is_none() && iterations < o.max_iterations {
        let phi = out.normal.phi;
        let (g, h) = (&out.normal.grad, &out.normal.gn);
        let held = held_model(&out.theta, lower, g, [h, h]);
        let (g, h) = match &held {
            Some(m) => (&m.g, &m.h),
            None => (g, h),
        };
        let (step, _) = within_bounds(&out.theta, lower, trust_region_step(h, g, o.initial_radius));
        let promised = model_decrease(h, g, &step);
        if promised.is_nan() || promised <= o.least_gain(o.noise_tolerance, phi) {
            break;
        }
        log::debug!(
            "Levenberg–Marquardt restarted at Φ {phi:.6e}: Gauss–Newton's step promises {promised:.3e}"
        );
        out = trust_region_confirmed(
            out.theta,
            out.normal,
            &mut eval,
            value.as_deref_mut(),
            &TrustOptions {
                max_iterations: o.max_iterations - iterations,
                ..*o
            },
            lower,
        );
        iterations += out.iterations;
        if phi - out.normal.phi <= o.least_gain(o.rel_tolerance, phi) {
            break;
        }
    }
    TrustOutcome { iterations, ..out }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// No bounds on one or two parameters.
    const FREE1: [f64; 1] = [f64::NEG_INFINITY];
    const FREE2: [f64; 2] = [f64::NEG_INFINITY; 2];

    /// Φ, ∇Φ and JᵀJ of residuals `f` with Jacobian `jac` (row-major n × p).
    fn normal(r: &[f64], j: &[f64], p: usize) -> Normal {
        let n = r.len();
        let grad = (0..p)
            .map(|a| (0..n).map(|i| j[i * p + a] * r[i]).sum())
            .collect();
        let gn = (0..p * p)
            .map(|ab| (0..n).map(|i| j[i * p + ab / p] * j[i * p + ab % p]).sum())
            .collect();
        Normal {
            phi: 0.5 * r.iter().map(|v| v * v).sum::<f64>(),
            grad,
            gn,
        }
    }

    /// Data a model holds exactly, refitted from where they were made: the start's cost is below
    /// the tolerance's share of the floor, so no step can gain more than the tolerance, and no
    /// Jacobian is spent to find that out. A start above it is fitted as before.
    #[test]
    fn a_start_below_the_tolerance_of_the_floor_is_converged_without_a_jacobian() {
        // r(θ) = θ − 1: cost (θ − 1)².
        let o = LmOptions {
            max_iterations: 20,
            tries: 10,
            initial_damping: 1e-3,
            min_damping: 1e-9,
            reject_factor: 4.0,
            rel_tolerance: 1e-5,
            cost_floor: 100.0,
        };
        let run = |theta0: f64| {
            let jacobians = std::cell::Cell::new(0);
            let out = minimise(
                vec![theta0],
                vec![theta0 - 1.0],
                (),
                |_, _, _| {
                    jacobians.set(jacobians.get() + 1);
                    Ok::<_, ()>(DMatrix::from_element(1, 1, 1.0))
                },
                |th, _| Some((vec![th[0] - 1.0], ())),
                &o,
            )
            .unwrap();
            (out, jacobians.get())
        };
        // Cost 10⁻⁶ ≤ 10⁻⁵ × 100: converged where it starts.
        let (out, jacobians) = run(1.0 + 1e-3);
        assert!(out.converged && out.iterations == 0 && jacobians == 0);
        assert_eq!(out.theta, vec![1.0 + 1e-3]);
        // Cost 10⁻² > 10⁻³: stepped to the minimum as before.
        let (out, jacobians) = run(1.1);
        assert!(out.converged && jacobians >= 1, "{out:?}");
        assert!((out.theta[0] - 1.0).abs() < 1e-3, "{:?}", out.theta);
    }

    /// Residuals that cannot vanish, r = (θ₀ − 1, θ₁ − 2, θ₀ θ₁ − 1, sin θ₀): Gauss–Newton converges
    /// only linearly there, and its last steps are predicted to gain little.
    fn misfit(t: &[f64]) -> Normal {
        normal(
            &[t[0] - 1.0, t[1] - 2.0, t[0] * t[1] - 1.0, t[0].sin()],
            &[1.0, 0.0, 0.0, 1.0, t[1], t[0], t[0].cos(), 0.0],
            2,
        )
    }

    /// A last step confirmed by Φ alone ([`CONFIRM_BELOW`]) ends where the full evaluations end,
    /// within the precision asked, with fewer of them; a Φ that does not confirm the model's
    /// prediction leaves the iteration as it was.
    #[test]
    fn a_last_step_confirmed_by_phi_alone_ends_within_the_precision() {
        let o = TrustOptions {
            max_iterations: 100,
            rel_tolerance: 1e-9,
            noise_tolerance: 1e-12,
            abs_tolerance: 0.0,
            initial_radius: 1.0,
            max_radius: 10.0,
            probe_bounds: 0,
        };
        let start = [0.2, 0.5];
        let full_evaluations = std::cell::Cell::new(0);
        let eval = |t: &[f64]| {
            full_evaluations.set(full_evaluations.get() + 1);
            Some(misfit(t))
        };
        let full = minimise_restarting(start.to_vec(), misfit(&start), eval, &o, &FREE2);
        let without = full_evaluations.replace(0);
        assert!(full.converged && full.linearised_at.is_none(), "{full:?}");

        let values = std::cell::Cell::new(0);
        let mut phi_alone = |t: &[f64]| {
            values.set(values.get() + 1);
            Some(misfit(t).phi)
        };
        let confirmed = minimise_restarting_confirmed(
            start.to_vec(),
            misfit(&start),
            eval,
            &mut phi_alone,
            &o,
            &FREE2,
        );
        let with = full_evaluations.replace(0);
        assert!(confirmed.converged, "{confirmed:?}");
        let at = confirmed
            .linearised_at
            .clone()
            .expect("ended on a confirmed step");
        assert_eq!(values.get(), 1);
        assert!(with < without, "{with} full evaluations against {without}");
        // Within the precision of the full iteration's minimum, and the point it linearised at
        // was evaluated in full one step before.
        let tolerance = o.rel_tolerance * full.normal.phi;
        assert!(
            confirmed.normal.phi <= full.normal.phi + tolerance,
            "Φ {} against {}",
            confirmed.normal.phi,
            full.normal.phi
        );
        assert!((misfit(&confirmed.theta).phi - confirmed.normal.phi).abs() < 1e-15);
        assert!(misfit(&at).phi > confirmed.normal.phi);

        // Φ alone that disagrees with the model by half its prediction and more never
        // confirms: the full evaluations decide, as without it.
        let mut wrong = |t: &[f64]| Some(misfit(t).phi * (1.0 + 1e-6));
        let unconfirmed = minimise_restarting_confirmed(
            start.to_vec(),
            misfit(&start),
            eval,
            &mut wrong,
            &o,
            &FREE2,
        );
        assert!(unconfirmed.linearised_at.is_none());
        assert_eq!(unconfirmed.theta, full.theta);
        assert_eq!(full_evaluations.get(), without);
    }

    /// Rosenbrock's function as residuals r = (10 (θ₁ − θ₀²), 1 − θ₀), minimum 0 at (1, 1).
    fn rosenbrock(t: &[f64]) -> Normal {
        normal(
            &[10.0 * (t[1] - t[0] * t[0]), 1.0 - t[0]],
            &[-20.0 * t[0], 10.0, -1.0, 0.0],
            2,
        )
    }

    /// The trust-region form on Rosenbrock (a zero residual): the minimum (1, 1).
    #[test]
    fn trust_region_finds_the_rosenbrock_minimum() {
        let eval = rosenbrock;
        let o = TrustOptions {
            max_iterations: 200,
            rel_tolerance: 1e-14,
            noise_tolerance: 0.0,
            abs_tolerance: 0.0,
            initial_radius: 1.0,
            max_radius: 10.0,
            probe_bounds: 0,
        };
        let out = minimise_trust_region(
            vec![-1.2, 1.0],
            eval(&[-1.2, 1.0]),
            |t| Some(eval(t)),
            &o,
            &FREE2,
        );
        assert!(out.converged);
        assert!(
            (out.theta[0] - 1.0).abs() < 1e-6 && (out.theta[1] - 1.0).abs() < 1e-6,
            "{:?}",
            out.theta
        );
    }

    /// A zero-residual Φ (noise-free data standing in for measured ones) whose minimum is
    /// asked only to an absolute precision: the relative tolerance alone runs it to round-off,
    /// the absolute one stops it within that precision of the minimum, in fewer iterations, and
    /// a restart does not step on below it.
    #[test]
    fn an_absolute_tolerance_stops_a_noise_free_fit_at_its_precision() {
        let eval = rosenbrock;
        let run = |abs_tolerance: f64| {
            let o = TrustOptions {
                max_iterations: 200,
                rel_tolerance: 1e-12,
                noise_tolerance: 1e-12,
                abs_tolerance,
                initial_radius: 1.0,
                max_radius: 10.0,
                probe_bounds: 0,
            };
            let start = [-1.2, 1.0];
            minimise_restarting(start.to_vec(), eval(&start), |t| Some(eval(t)), &o, &FREE2)
        };
        let precision = 1e-3;
        let (tight, loose) = (run(0.0), run(precision));
        assert!(tight.converged && loose.converged);
        assert!(tight.normal.phi < 1e-14, "Φ {:e}", tight.normal.phi);
        assert!(
            loose.normal.phi <= precision && loose.normal.phi > tight.normal.phi,
            "Φ {:e}",
            loose.normal.phi
        );
        assert!(
            loose.iterations < tight.iterations,
            "{} iterations with the absolute tolerance, {} without",
            loose.iterations,
            tight.iterations
        );
    }

    /// A parameter running to its neutral value in log space: r = (z₀ − 1, e^{z₁}, 1), whose
    /// minimum in z₁ lies at −∞ (the effect e^{z₁} is not in the data), with the reported Φ
    /// carrying that effect's share twice (a Φ whose own error the model cannot predict, as a
    /// simulated misfit's Newton tolerance). Every step then gains 1.7 times its prediction, so
    /// the model is never trusted to 25 %; without the rule that a step gaining less than the
    /// tolerance ends it, the iteration steps on to its limit, halving an effect no longer there.
    #[test]
    fn a_fit_whose_steps_gain_nothing_stops() {
        let eval = |t: &[f64]| {
            let e = t[1].exp();
            let mut n = normal(&[t[0] - 1.0, e, 1.0], &[1.0, 0.0, 0.0, e, 0.0, 0.0], 2);
            n.phi += 0.5 * e * e;
            n
        };
        let o = TrustOptions {
            max_iterations: 200,
            rel_tolerance: 1e-6,
            noise_tolerance: 1e-7,
            abs_tolerance: 0.0,
            initial_radius: 1.0,
            max_radius: 3.0,
            probe_bounds: 0,
        };
        let out = minimise_trust_region(
            vec![0.0, 0.0],
            eval(&[0.0, 0.0]),
            |t| Some(eval(t)),
            &o,
            &FREE2,
        );
        assert!(out.converged, "{out:?}");
        assert!(out.iterations < 20, "{} iterations", out.iterations);
        assert!((out.theta[0] - 1.0).abs() < 1e-9, "{:?}", out.theta);
        // Stopped where the effect's share is below the tolerance asked, not before.
        let share = out.theta[1].exp().powi(2);
        assert!(share < 2.0 * 1e-6 * out.normal.phi, "e^(2 z₁) {share:e}");
    }

    /// The phase of a sampled sinusoid: r_i = sin(ω t_i) − d_i, d from ω = 2.3 plus a fixed
    /// "noise", sixty samples 0.1 apart; its misfit has a hump at ω ≈ 1.5.
    struct SinusoidPhase {
        t: Vec<f64>,
        d: Vec<f64>,
    }

    impl SinusoidPhase {
        fn new() -> Self {
            let t: Vec<f64> = (0..60).map(|i| 0.1 * i as f64).collect();
            let d = t
                .iter()
                .enumerate()
                .map(|(i, t)| (2.3 * t).sin() + 0.3 * ((7 * i % 11) as f64 / 11.0 - 0.5))
                .collect();
            Self { t, d }
        }

        fn residuals(&self, w: f64) -> Vec<f64> {
            self.t
                .iter()
                .zip(&self.d)
                .map(|(t, d)| (w * t).sin() - d)
                .collect()
        }

        fn jacobian(&self, w: f64) -> Vec<f64> {
            self.t.iter().map(|t| t * (w * t).cos()).collect()
        }

        fn normal(&self, w: f64) -> Normal {
            normal(&self.residuals(w), &self.jacobian(w), 1)
        }
    }

    /// A residual that does not vanish and a Φ that is not convex along the way: the phase of a
    /// sampled sinusoid, r_i = sin(ω t_i) − d_i with d from ω = 2.3 plus a fixed "noise". From
    /// ω = 2.0 the trust-region form reaches the same minimum as the diagonal-scaling form, to
    /// 1e-8 in ω, in fewer evaluations.
    #[test]
    fn trust_region_matches_the_diagonal_form_on_a_large_residual() {
        let phase = SinusoidPhase::new();
        let evals = std::cell::Cell::new(0);
        let eval = |th: &[f64]| {
            evals.set(evals.get() + 1);
            phase.normal(th[0])
        };
        let o = TrustOptions {
            max_iterations: 100,
            rel_tolerance: 1e-12,
            noise_tolerance: 0.0,
            abs_tolerance: 0.0,
            initial_radius: 0.5,
            max_radius: 1.0,
            probe_bounds: 0,
        };
        let tr = minimise_trust_region(vec![2.0], eval(&[2.0]), |th| Some(eval(th)), &o, &FREE1);
        let tr_evals = evals.get();
        let lo = LmOptions {
            max_iterations: 200,
            tries: 30,
            initial_damping: 1e-3,
            min_damping: 1e-12,
            reject_factor: 10.0,
            rel_tolerance: 1e-14,
            cost_floor: f64::MIN_POSITIVE,
        };
        let calls = std::cell::Cell::new(1);
        let diag = minimise(
            vec![2.0],
            phase.residuals(2.0),
            (),
            |th, _, _| {
                Ok::<_, ()>(DMatrix::from_column_slice(
                    phase.t.len(),
                    1,
                    &phase.jacobian(th[0]),
                ))
            },
            |th, _| {
                calls.set(calls.get() + 2); // the trial, and its Jacobian if accepted
                Some((phase.residuals(th[0]), ()))
            },
            &lo,
        )
        .unwrap();
        eprintln!(
            "ω: trust region {} in {tr_evals} evaluations, diagonal {} in {}",
            tr.theta[0],
            diag.theta[0],
            calls.get()
        );
        assert!(tr.converged);
        assert!(
            (tr.theta[0] - diag.theta[0]).abs() < 1e-8,
            "trust region {} diagonal {}",
            tr.theta[0],
            diag.theta[0]
        );
        assert!((tr.theta[0] - 2.3).abs() < 0.05, "{}", tr.theta[0]);
        assert!(
            tr_evals < calls.get(),
            "evaluations: trust region {tr_evals}, diagonal {}",
            calls.get()
        );
    }

    /// A start where every trial fails (a simulation that inverts an element, say) until the
    /// radius has shrunk below what counts as a step: the trust-region iteration stops there,
    /// "converged" at the start's Φ, and the restart, whose fresh radius Gauss–Newton's model
    /// promises a large gain from, goes on to the minimum of r = (θ₀ − 1, 2 (θ₁ + 3)).
    #[test]
    fn a_stop_after_failed_trials_is_restarted_to_the_minimum() {
        let eval = |t: &[f64]| normal(&[t[0] - 1.0, 2.0 * (t[1] + 3.0)], &[1.0, 0.0, 0.0, 2.0], 2);
        let o = TrustOptions {
            max_iterations: 100,
            rel_tolerance: 1e-12,
            noise_tolerance: 1e-10,
            abs_tolerance: 0.0,
            initial_radius: 1.0,
            max_radius: 10.0,
            probe_bounds: 0,
        };
        let calls = std::cell::Cell::new(0);
        let failing_first = |t: &[f64]| {
            calls.set(calls.get() + 1);
            (calls.get() > 20).then(|| eval(t))
        };
        let once =
            minimise_trust_region(vec![0.0, 0.0], eval(&[0.0, 0.0]), failing_first, &o, &FREE2);
        assert!(once.converged && once.theta == [0.0, 0.0], "{once:?}");
        calls.set(0);
        let out = minimise_restarting(vec![0.0, 0.0], eval(&[0.0, 0.0]), failing_first, &o, &FREE2);
        assert!(out.converged, "{out:?}");
        assert!(
            (out.theta[0] - 1.0).abs() < 1e-9 && (out.theta[1] + 3.0).abs() < 1e-9,
            "{:?}",
            out.theta
        );
        assert!(out.iterations > once.iterations, "{out:?}");
    }

    /// Correlated linear residuals r = A θ − b (a₀ and a₁ correlated), whose unconstrained
    /// minimum (1, −3) lies below a floor θ₀ ≥ 2: the bounded fit stops on the floor with θ₁ at
    /// its conditional minimum θ₁ = a₁ᵀ(b − 2 a₀) / a₁ᵀa₁ (the bound-constrained least-squares
    /// solution; the coupling moves θ₁ off −3), in a few iterations instead of crawling toward
    /// the bound. With the floor below the minimum the fit is the unbounded one, to the bit.
    #[test]
    fn a_floor_below_the_minimum_holds_the_fit_on_it() {
        let (c, sn) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
        // Row-major 3 × 2: columns a₀ = (1, 0, 0) and a₁ = (c, s, 1).
        let a = [1.0, c, 0.0, sn, 0.0, 1.0];
        let truth = [1.0, -3.0];
        let b: Vec<f64> = (0..3)
            .map(|i| a[2 * i] * truth[0] + a[2 * i + 1] * truth[1])
            .collect();
        let eval = |t: &[f64]| {
            let r: Vec<f64> = (0..3)
                .map(|i| a[2 * i] * t[0] + a[2 * i + 1] * t[1] - b[i])
                .collect();
            normal(&r, &a, 2)
        };
        let o = TrustOptions {
            max_iterations: 50,
            rel_tolerance: 1e-14,
            noise_tolerance: 0.0,
            abs_tolerance: 0.0,
            initial_radius: 1.0,
            max_radius: 10.0,
            probe_bounds: 0,
        };
        let start = vec![5.0, 0.0];
        let lower = [2.0, f64::NEG_INFINITY];
        let some = |t: &[f64]| Some(eval(t));
        let out = minimise_restarting(start.clone(), eval(&start), some, &o, &lower);
        let a1: Vec<f64> = (0..3).map(|i| a[2 * i + 1]).collect();
        let rest: Vec<f64> = (0..3).map(|i| b[i] - a[2 * i] * 2.0).collect();
        let dot = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(p, q)| p * q).sum::<f64>();
        let theta1 = dot(&a1, &rest) / dot(&a1, &a1);
        assert_eq!(out.theta[0], 2.0, "{out:?}");
        assert!(
            (out.theta[1] - theta1).abs() < 1e-9,
            "{out:?} against {theta1}"
        );
        assert!(
            (theta1 + 3.0).abs() > 0.1,
            "the coupling moves θ₁: {theta1}"
        );
        assert!(out.converged && out.iterations <= 8, "{out:?}");
        // The floor not reached: the same iterates as the unbounded fit.
        let free = minimise_restarting(start.clone(), eval(&start), some, &o, &FREE2);
        let low = [-10.0, f64::NEG_INFINITY];
        let within = minimise_restarting(start.clone(), eval(&start), some, &o, &low);
        assert_eq!(free.theta, within.theta);
        assert_eq!(free.iterations, within.iterations);
        assert!((free.theta[0] - 1.0).abs() < 1e-9 && (free.theta[1] + 3.0).abs() < 1e-9);
    }

    /// A floor b ≥ −8 on the first of two parameters.
    const FLOOR_AT_MINUS_8: [f64; 2] = [-8.0, f64::NEG_INFINITY];

    /// The options of the bound probes' tests, the coordinates `probe_bounds` tried.
    fn probing(probe_bounds: u64) -> TrustOptions {
        TrustOptions {
            max_iterations: 50,
            rel_tolerance: 1e-12,
            noise_tolerance: 0.0,
            abs_tolerance: 0.0,
            initial_radius: 1.0,
            max_radius: 3.0,
            probe_bounds,
        }
    }

    /// A log-parameter whose effect fades as it falls (r₀ = e^b − e^{b*}), with a floor b ≥ −8
    /// and a second, linear parameter (r₁ = c − 1). Where the effect vanishes (b* = −∞) Φ
    /// saturates: Gauss–Newton steps b down one unit an iteration, and the probe puts it on the
    /// floor after [`RUN_STEPS`] such steps, in fewer iterations, at the same minimum. Where the
    /// minimum is inside (b* = −3) the fit with the probe ends there too.
    #[test]
    fn a_coordinate_running_to_its_bound_is_tried_on_it() {
        let (lower, o) = (FLOOR_AT_MINUS_8, probing);
        for target in [f64::NEG_INFINITY, -3.0] {
            let eval = |t: &[f64]| {
                let r = [t[0].exp() - target.exp(), t[1] - 1.0];
                normal(&r, &[t[0].exp(), 0.0, 0.0, 1.0], 2)
            };
            let some = |t: &[f64]| Some(eval(t));
            let start = vec![0.0, 0.0];
            let walked = minimise_restarting(start.clone(), eval(&start), some, &o(0), &lower);
            let probed = minimise_restarting(start.clone(), eval(&start), some, &o(0b01), &lower);
            let minimum = target.max(-8.0);
            for out in [&walked, &probed] {
                assert!((out.theta[0] - minimum).abs() < 1e-6, "{target}: {out:?}");
                assert!((out.theta[1] - 1.0).abs() < 1e-9, "{target}: {out:?}");
            }
            if target == f64::NEG_INFINITY {
                assert_eq!(probed.theta[0], -8.0);
                assert!(walked.iterations >= 8, "{walked:?}");
                // RUN_STEPS steps down, the probe, then c's step and the check of convergence.
                assert!(
                    probed.iterations <= RUN_STEPS + 3,
                    "{probed:?} against {walked:?}"
                );
            }
        }
    }

    /// A fading coordinate that another follows (r₀ = e^b, r₁ = 2 (c − 1 − e^b): the best c
    /// moves with b): on the floor with c where it was Φ is higher than where the walk stands,
    /// and one Gauss–Newton step of c from there finds the lower point. The same minimum as the
    /// walk, in fewer iterations.
    #[test]
    fn a_bound_whose_neighbours_move_is_taken_after_their_step() {
        let (lower, o) = (FLOOR_AT_MINUS_8, probing);
        let eval = |t: &[f64]| {
            let e = t[0].exp();
            normal(&[e, 2.0 * (t[1] - 1.0 - e)], &[e, 0.0, -2.0 * e, 2.0], 2)
        };
        let some = |t: &[f64]| Some(eval(t));
        let start = vec![0.0, 2.0];
        let walked = minimise_restarting(start.clone(), eval(&start), some, &o(0), &lower);
        let probed = minimise_restarting(start.clone(), eval(&start), some, &o(0b01), &lower);
        for out in [&walked, &probed] {
            assert!((out.theta[0] + 8.0).abs() < 1e-6, "{out:?}");
            assert!((out.theta[1] - 1.0 - (-8f64).exp()).abs() < 1e-9, "{out:?}");
        }
        assert!(
            probed.iterations < walked.iterations,
            "{probed:?} against {walked:?}"
        );
        // On the floor with c where it was, Φ is higher than two steps down: the bound alone
        // would not have been taken.
        let two_down = [-2.0, 1.0 + (-2f64).exp()];
        let on_floor = [-8.0, two_down[1]];
        assert!(eval(&on_floor).phi > eval(&two_down).phi);
    }

    /// A secant model that promises more than Φ is not tried: H's step instead. One parameter,
    /// Φ = ½, g = 1, H = 1: H's step is Newton's, −1. H + S = −100 (indefinite) steps to the
    /// radius, −2, and promises 2 + 200 ≫ Φ; H + S = 2 promises 0.25 and keeps its own step.
    #[test]
    fn a_secant_model_promising_more_than_phi_gives_way_to_gauss_newton() {
        let (h, g, phi, radius) = ([1.0], [1.0], 0.5, 2.0);
        let (s, aug) = model_step(&h, &[-100.0], &g, phi, radius, true, false);
        assert!(!aug);
        assert!((s[0] + 1.0).abs() < 1e-12, "{s:?}");
        let (s, aug) = model_step(&h, &[2.0], &g, phi, radius, true, false);
        assert!(aug);
        assert!((s[0] + 0.5).abs() < 1e-12, "{s:?}");
        let (s, aug) = model_step(&h, &[-100.0], &g, phi, radius, false, false);
        assert!(!aug && (s[0] + 1.0).abs() < 1e-12, "{s:?}");
    }

    /// Where Φ has shown itself concave (near the top of a hump of an oscillation's misfit), H
    /// over-states the curvature and its step is a small fraction of the way; the secant model,
    /// indefinite, would run to the radius and promise more than Φ. One parameter, Φ = 1, g = 1,
    /// H = 100 (H's step −0.01, promising 0.005), H + S = −0.01: the secant step shortened to
    /// promise half of Φ, s + 0.005 s² = 0.5, and the secant model kept; without the evidence of
    /// concavity, H's step.
    #[test]
    fn an_over_promising_secant_step_is_shortened_where_phi_is_concave() {
        let (s, aug) = model_step(&[100.0], &[-0.01], &[1.0], 1.0, 1.0, true, true);
        assert!(aug, "{s:?}");
        let want = (-1.0 + (1.0f64 + 0.01).sqrt()) / 0.01;
        assert!((s[0] + want).abs() < 1e-9, "{s:?} against −{want}");
        let (s, aug) = model_step(&[100.0], &[-0.01], &[1.0], 1.0, 1.0, true, false);
        assert!(!aug && (s[0] + 0.01).abs() < 1e-12, "{s:?}");
    }

    /// The same on a whole fit: the phase of a sampled sinusoid (as in
    /// `trust_region_matches_the_diagonal_form_on_a_large_residual`) from ω = 1.505, just past
    /// the top of the misfit's hump at 1.5 where Φ is concave (Φ'' ≈ −260 against JᵀJ ≈ 305), to
    /// the minimum near 2.3: Gauss–Newton's steps there are a few hundredths of the way, each
    /// gaining about twice its prediction (13 evaluations when H's step always replaces an
    /// over-promising secant step).
    #[test]
    fn a_concave_start_does_not_crawl() {
        let phase = SinusoidPhase::new();
        let evals = std::cell::Cell::new(0);
        let eval = |th: &[f64]| {
            evals.set(evals.get() + 1);
            phase.normal(th[0])
        };
        let o = TrustOptions {
            max_iterations: 100,
            rel_tolerance: 1e-10,
            noise_tolerance: 0.0,
            abs_tolerance: 0.0,
            initial_radius: 1.0,
            max_radius: 3.0,
            probe_bounds: 0,
        };
        let out =
            minimise_trust_region(vec![1.505], eval(&[1.505]), |th| Some(eval(th)), &o, &FREE1);
        assert!(out.converged);
        assert!((out.theta[0] - 2.3).abs() < 0.05, "{}", out.theta[0]);
        assert!(evals.get() <= 10, "{} evaluations", evals.get());
    }

    /// One coordinate: the cubic search ([`crate::one_coordinate`]) and the trust-region
    /// iteration reach the same minimum of the sinusoid's phase, from its side of the hump
    /// (ω = 2.0: five evaluations each) and from just past the top of it (1.505, where Φ is
    /// concave: six against eight).
    #[test]
    fn one_coordinate_takes_the_cubic_search() {
        let phase = SinusoidPhase::new();
        let o = TrustOptions {
            max_iterations: 100,
            rel_tolerance: 1e-12,
            noise_tolerance: 0.0,
            abs_tolerance: 0.0,
            initial_radius: 1.0,
            max_radius: 3.0,
            probe_bounds: 0,
        };
        for start in [2.0, 1.505] {
            let evals = std::cell::Cell::new(0);
            let eval = |th: &[f64]| {
                evals.set(evals.get() + 1);
                Some(phase.normal(th[0]))
            };
            let first = phase.normal(start);
            let search = minimise_trust_region(vec![start], first.clone(), eval, &o, &FREE1);
            let searched = evals.replace(0);
            let walk = trust_region_iteration(vec![start], first, eval, None, &o, &FREE1);
            let walked = evals.get();
            eprintln!(
                "from {start}: search ω {} in {searched}, trust region {} in {walked}",
                search.theta[0], walk.theta[0]
            );
            assert!(search.converged && walk.converged);
            assert!(
                (search.theta[0] - walk.theta[0]).abs() < 1e-7,
                "{search:?} against {walk:?}"
            );
            assert!(
                searched < walked || (start == 2.0 && searched == walked),
                "{searched} against {walked} evaluations"
            );
        }
    }

    /// The subproblem: inside the radius the Newton step; on an indefinite B a step of exactly
    /// the radius that decreases the model.
    #[test]
    fn trust_region_step_is_newton_inside_and_on_the_boundary_otherwise() {
        let b = [4.0, 1.0, 1.0, 3.0];
        let g = [1.0, 2.0];
        let s = trust_region_step(&b, &g, 10.0);
        let bs = mat_vec(&b, &s);
        assert!((bs[0] + g[0]).abs() < 1e-12 && (bs[1] + g[1]).abs() < 1e-12);
        let ind = [1.0, 0.0, 0.0, -2.0];
        let s = trust_region_step(&ind, &g, 0.5);
        assert!((norm(&s) - 0.5).abs() < 1e-9, "{}", norm(&s));
        let bs = mat_vec(&ind, &s);
        let m = g[0] * s[0] + g[1] * s[1] + 0.5 * (s[0] * bs[0] + s[1] * bs[1]);
        assert!(m < 0.0, "model change {m}");
    }

    /// Rosenbrock as least squares: r = (10 (y − x²), 1 − x), minimum at (1, 1).
    #[test]
    fn finds_the_rosenbrock_minimum() {
        let f = |t: &[f64]| vec![10.0 * (t[1] - t[0] * t[0]), 1.0 - t[0]];
        let jac = |t: &[f64], _: &(), _: &[f64]| {
            Ok::<_, ()>(DMatrix::from_row_slice(
                2,
                2,
                &[-20.0 * t[0], 10.0, -1.0, 0.0],
            ))
        };
        let o = LmOptions {
            max_iterations: 200,
            tries: 12,
            initial_damping: 1e-3,
            min_damping: 1e-12,
            reject_factor: 10.0,
            rel_tolerance: 1e-12,
            cost_floor: f64::MIN_POSITIVE,
        };
        let out = minimise(
            vec![-1.2, 1.0],
            f(&[-1.2, 1.0]),
            (),
            jac,
            |t, _| Some((f(t), ())),
            &o,
        )
        .unwrap();
        assert!((out.theta[0] - 1.0).abs() < 1e-6 && (out.theta[1] - 1.0).abs() < 1e-6);
    }
}
