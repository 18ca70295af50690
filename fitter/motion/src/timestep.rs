//! How finely to integrate a capture: the simulation step is the capture interval divided by a
//! number of substeps chosen so that BDF2 resolves the motion the capture shows.
//!
//! BDF2 (eq. 2) is A-stable but not free of error on an oscillation: resolved by N steps per
//! period, an undamped mode comes out with a longer period and decays every cycle. From the
//! scheme's characteristic polynomial for ẍ = −ω²x ([`bdf2_oscillator_error`]):
//!
//! | steps per period N | 13 | 20 | 26 | 32 | 40 | 52 |
//! |---|---|---|---|---|---|---|
//! | period × | 1.065 | 1.030 | 1.018 | 1.012 | 1.008 | 1.005 |
//! | amplitude per cycle | 0.887 | 0.960 | 0.980 | 0.990 | 0.994 | 0.997 |
//!
//! A 100 Hz capture of a beam ringing at 7.7 Hz is 13 frames per period: stepping at the capture
//! rate makes the simulated ring-down 6.5 % too slow and damped by 11 % per cycle before any
//! material damping — errors a fit then absorbs into the stiffness and the viscosity. The rule
//! here asks for [`STEPS_PER_PERIOD`] steps per period of the fastest oscillation the capture
//! shows (its ring-down, [`capture_period`]): the period error stays near 1 % and the numerical
//! damping near 1 % per cycle, below what the captures here can see. A body shaken at its clamp
//! rings in higher modes too, which that period does not see: the loader then measures the
//! chosen step's own error on the capture and makes it finer where the declared noise would see
//! it ([`crate::step_error`]).

use crate::model::{Model, Observations};
use crate::step_error::StepError;
use nalgebra::Complex;

/// The time integration scheme of a simulation's steps.
///
/// Both solve each step by Newton on the free velocities v^n with a system matrix
/// S = c M + a_x K + a_v D ([`Scheme::coefficients`]), so they share the solver, the modified
/// Newton and the gradients' structure; they differ in their error on an oscillation
/// ([`Scheme::oscillator_error`]):
///
/// | steps per period N | 13 | 15 | 16 | 20 | 26 | 32 |
/// |---|---|---|---|---|---|---|
/// | BDF2: period × | 1.065 | 1.051 | 1.045 | 1.030 | 1.018 | 1.012 |
/// | BDF2: amplitude per cycle | 0.887 | 0.919 | 0.931 | 0.961 | 0.981 | 0.989 |
/// | implicit midpoint: period × | 1.019 | 1.014 | 1.013 | 1.008 | 1.005 | 1.003 |
/// | implicit midpoint: amplitude per cycle | 1 | 1 | 1 | 1 | 1 | 1 |
/// | generalised-α, ρ∞ = 0.8: period × | 1.020 | 1.015 | 1.013 | 1.009 | 1.005 | 1.003 |
/// | generalised-α, ρ∞ = 0.8: amplitude per cycle | 1.000 | 1.000 | 1.000 | 1.000 | 1.000 | 1.000 |
///
/// The midpoint rule reaches BDF2's period error with half the steps and adds no numerical
/// damping, so a fitted viscosity is the material's and not partly the integrator's. Its highest
/// modes are not damped by the scheme either (|z| = 1 at any ωΔt); the material viscosity damps
/// them (D enters S and the residual at full weight), and an undamped model of a released body
/// can blow up with it: a model that asks for the midpoint rule integrates a material without
/// viscosity by BDF2 ([`Model::scheme_for`](crate::model::Model::scheme_for)).
///
/// The generalised-α scheme ([`Scheme::Alpha`], ρ∞ = [`ALPHA_RHO_INF`]) sits between the two:
/// second order, a period error near the midpoint rule's, little damping in the resolved band,
/// and every unresolved mode damped by ρ∞ per step ([`Scheme::two_step`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Scheme {
    /// BDF2 (Real2Sim eq. 2): x^n = (4x^{n−1} − x^{n−2})/3 + (2Δt/3) v^n,
    /// M (3v^n − 4v^{n−1} + v^{n−2})/(2Δt) = f(x^n, v^n) + f_ext. A-stable and L-stable: damps.
    #[default]
    Bdf2,
    /// Implicit midpoint: x^n = x^{n−1} + (Δt/2)(v^{n−1} + v^n),
    /// M (v^n − v^{n−1})/Δt = f(x^{n−½}, v^{n−½}) + f_ext with x^{n−½} = (x^{n−1} + x^n)/2 and
    /// v^{n−½} = (x^n − x^{n−1})/Δt. Second order, symplectic, no numerical damping (on a
    /// linear system identical to the trapezoidal rule, Newmark's average acceleration).
    Midpoint,
    /// Generalised-α (Jansen, Whiting & Hulbert 2000, the first-order form of Chung & Hulbert
    /// 1993) on the system in (x, v), written as the two-step one-leg method it is for a linear
    /// system: with ρ = ρ∞ = [`ALPHA_RHO_INF`],
    /// Σ α_j x^{n−2+j} = Δt Σ β_j v^{n−2+j}, M Σ α_j v^{n−2+j} / Δt = f(Σ β_j x^{n−2+j},
    /// Σ β_j v^{n−2+j}) + f_ext, with β(ζ) = (ζ + ρ)²/(1 + ρ)² (the double root −ρ is the
    /// amplification of every mode as ωΔt → ∞) and α(ζ) the second-order α for that β
    /// ([`Scheme::two_step`]). ρ = 0 is BDF2, ρ = 1 the trapezoidal rule. A-stable, second
    /// order, and its one-leg form is G-stable (Dahlquist), so its stability carries over to the
    /// nonlinear forces.
    Alpha,
}

/// The scheme a dataset is integrated with when it names none (its `scheme` key), and what
/// `palpate import c3d` writes: the implicit midpoint rule. Data from another simulator or a
/// capture carry no numerical damping, and BDF2's, at the capture's own rate, is a loss and a
/// period error the fit must explain with something: with it, the motion diagnosis of the
/// independent generator's cylinders named the injected effect first in 31 of 46 draws, under the
/// midpoint rule in 38 of 48, and effect-free draws lost stiffenings and marker offsets that had
/// taken up BDF2's error (docs/motion-dataset.md, "The simulation step").
/// [`Scheme::default`] stays Real2Sim's BDF2 for a model built in code.
pub const DATASET_DEFAULT: Scheme = Scheme::Midpoint;

/// The spectral radius at infinity of [`Scheme::Alpha`]: every mode with ωΔt ≫ 1 loses 1 − ρ∞ =
/// 20 % of its amplitude per step, while a mode resolved by 13 steps per period loses 0.02 % per
/// cycle ([`Scheme::oscillator_error`]).
pub const ALPHA_RHO_INF: f64 = 0.8;

/// A two-step one-leg method's coefficients, oldest first: Σ_j α_j x^{n−2+j} = Δt Σ_j β_j
/// v^{n−2+j} and M Σ_j α_j v^{n−2+j} / Δt = f(Σ_j β_j x^{n−2+j}, Σ_j β_j v^{n−2+j}) + f_ext.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TwoStep {
    /// α_0, α_1, α_2 (Σ α = 0, Σ j α_j = 1: consistent).
    pub alpha: [f64; 3],
    /// β_0, β_1, β_2 (Σ β = 1).
    pub beta: [f64; 3],
}

impl TwoStep {
    /// Generalised-α with spectral radius at infinity `rho` (0 ≤ ρ ≤ 1): β(ζ) = (ζ + ρ)²/(1 +
    /// ρ)², α from the order conditions Σ α_j = 0, Σ j α_j = Σ β_j, Σ j² α_j = 2 Σ j β_j.
    pub fn generalised_alpha(rho: f64) -> Self {
        let q = 1.0 + rho;
        Self {
            alpha: [
                (1.0 - 3.0 * rho) / (2.0 * q),
                -2.0 * (1.0 - rho) / q,
                (3.0 - rho) / (2.0 * q),
            ],
            beta: [rho * rho / (q * q), 2.0 * rho / (q * q), 1.0 / (q * q)],
        }
    }

    /// The step's (c, a_x, a_v) ([`Scheme::coefficients`]): c = α_2/Δt, a_x = Δt β_2²/α_2,
    /// a_v = β_2.
    pub fn coefficients(&self, dt: f64) -> (f64, f64, f64) {
        let (a2, b2) = (self.alpha[2], self.beta[2]);
        (a2 / dt, dt * b2 * b2 / a2, b2)
    }

    /// The force state's history part x_a = A_1 x^{n−1} + A_0 x^{n−2} + E (β_1 v^{n−1} + β_0
    /// v^{n−2}): (A_0, A_1, E) with A_j = β_j − β_2 α_j/α_2, E = Δt β_2/α_2.
    pub fn force_history(&self, dt: f64) -> (f64, f64, f64) {
        let (a, b) = (self.alpha, self.beta);
        (
            b[0] - b[2] * a[0] / a[2],
            b[1] - b[2] * a[1] / a[2],
            dt * b[2] / a[2],
        )
    }

    /// x^n = (Δt Σ_j β_j v^{n−2+j} − α_1 x^{n−1} − α_0 x^{n−2}) / α_2.
    pub fn position(&self, dt: f64, x: [f64; 2], v: [f64; 3]) -> f64 {
        let (a, b) = (self.alpha, self.beta);
        (dt * (b[0] * v[0] + b[1] * v[1] + b[2] * v[2]) - a[1] * x[1] - a[0] * x[0]) / a[2]
    }
}

impl Scheme {
    /// The name in dataset files and reports (`"bdf2"`, `"midpoint"`).
    pub const fn name(self) -> &'static str {
        match self {
            Scheme::Bdf2 => "bdf2",
            Scheme::Midpoint => "midpoint",
            Scheme::Alpha => "alpha",
        }
    }

    /// The scheme named `name` ([`Scheme::name`]), if any.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "bdf2" => Some(Scheme::Bdf2),
            "midpoint" => Some(Scheme::Midpoint),
            "alpha" => Some(Scheme::Alpha),
            _ => None,
        }
    }

    /// Steps per period of the capture's oscillation asked for by the substep rule
    /// ([`substeps_for_scheme`]): BDF2 32 (period +1.2 %, amplitude ×0.990 per cycle), midpoint
    /// 15 (period +1.4 %, no numerical damping), generalised-α [`ALPHA_STEPS_PER_PERIOD`].
    pub fn steps_per_period(self) -> f64 {
        match self {
            Scheme::Bdf2 => STEPS_PER_PERIOD,
            Scheme::Midpoint => MIDPOINT_STEPS_PER_PERIOD,
            Scheme::Alpha => ALPHA_STEPS_PER_PERIOD,
        }
    }

    /// The scheme as a two-step one-leg method ([`TwoStep`]): BDF2 α = (1/2, −2, 3/2), β = (0,
    /// 0, 1); midpoint α = (0, −1, 1), β = (0, 1/2, 1/2); generalised-α
    /// [`TwoStep::generalised_alpha`] at [`ALPHA_RHO_INF`].
    pub fn two_step(self) -> TwoStep {
        match self {
            Scheme::Bdf2 => TwoStep {
                alpha: [0.5, -2.0, 1.5],
                beta: [0.0, 0.0, 1.0],
            },
            Scheme::Midpoint => TwoStep {
                alpha: [0.0, -1.0, 1.0],
                beta: [0.0, 0.5, 0.5],
            },
            Scheme::Alpha => TwoStep::generalised_alpha(ALPHA_RHO_INF),
        }
    }

    /// (numerical period / true period, amplitude ratio per numerical period) of the undamped
    /// oscillator ẍ = −ω²x resolved by `n` steps per period.
    pub fn oscillator_error(self, n: f64) -> (f64, f64) {
        match self {
            Scheme::Bdf2 => bdf2_oscillator_error(n),
            Scheme::Midpoint => midpoint_oscillator_error(n),
            Scheme::Alpha => damped_oscillator_error(self, n, 0.0),
        }
    }

    /// (c, a_x, a_v) of a step of length `dt`: the step's residual is
    /// r(v) = f(x_f, v_f) + f_ext − c M (v − b) with the force state x_f = x_a + a_x v,
    /// v_f = v_a + a_v v affine in the step's velocities v, so −∂r/∂v = S = c M + a_x K + a_v D.
    /// BDF2: (3/(2Δt), 2Δt/3, 1); midpoint: (1/Δt, Δt/4, 1/2); generalised-α
    /// [`TwoStep::coefficients`].
    pub fn coefficients(self, dt: f64) -> (f64, f64, f64) {
        match self {
            Scheme::Bdf2 => (1.5 / dt, 2.0 * dt / 3.0, 1.0),
            Scheme::Midpoint => (1.0 / dt, 0.25 * dt, 0.5),
            Scheme::Alpha => self.two_step().coefficients(dt),
        }
    }
}

/// The scheme on the damped oscillator ẍ + 2ζωẋ + ω²x = 0 resolved by `n` steps per undamped
/// period: (numerical period / true damped period, numerical amplitude ratio per numerical
/// period / the true one, exp(−2πζ/√(1−ζ²))). The step is linear in its history, so its
/// amplification matrix is assembled column by column from unit histories and its complex
/// eigenvalue of largest modulus is the physical mode. At ζ = 0 it is
/// [`Scheme::oscillator_error`].
pub fn damped_oscillator_error(scheme: Scheme, n: f64, zeta: f64) -> (f64, f64) {
    let tau = 2.0 * std::f64::consts::PI;
    let (w, h) = (tau, 1.0 / n);
    let (c, ax, av) = scheme.coefficients(h);
    // One step from the history `s` (BDF2: x¹, x², v¹, v²; midpoint: x¹, v¹, 0, 0): the new
    // history. The residual −ω²x_f − 2ζω v_f − c(v − b) = 0 with x_f = x_a + a_x v,
    // v_f = v_a + a_v v, solved for v.
    let ts = scheme.two_step();
    let (a0, a1, e) = ts.force_history(h);
    let step = |s: [f64; 4]| -> [f64; 4] {
        let (xa, va, b) = match scheme {
            Scheme::Bdf2 => ((4.0 * s[0] - s[1]) / 3.0, 0.0, (4.0 * s[2] - s[3]) / 3.0),
            Scheme::Midpoint => (s[0] + ax * s[1], av * s[1], s[1]),
            Scheme::Alpha => {
                let hist_v = ts.beta[1] * s[2] + ts.beta[0] * s[3];
                (
                    a1 * s[0] + a0 * s[1] + e * hist_v,
                    hist_v,
                    -(ts.alpha[1] * s[2] + ts.alpha[0] * s[3]) / ts.alpha[2],
                )
            }
        };
        let v = (c * b - w * w * xa - 2.0 * zeta * w * va) / (c + ax * w * w + 2.0 * zeta * w * av);
        match scheme {
            Scheme::Bdf2 => [xa + ax * v, s[0], v, s[2]],
            Scheme::Midpoint => [s[0] + 0.5 * h * (s[1] + v), v, 0.0, 0.0],
            Scheme::Alpha => [ts.position(h, [s[1], s[0]], [s[3], s[2], v]), s[0], v, s[2]],
        }
    };
    let dim = match scheme {
        Scheme::Bdf2 | Scheme::Alpha => 4,
        Scheme::Midpoint => 2,
    };
    let a = nalgebra::DMatrix::from_fn(dim, dim, |r, col| {
        let mut e = [0.0; 4];
        e[col] = 1.0;
        step(e)[r]
    });
    let z = a
        .complex_eigenvalues()
        .iter()
        .copied()
        .filter(|z| z.im.abs() > 1e-12)
        .max_by(|p, q| p.norm().total_cmp(&q.norm()))
        .expect("an oscillating mode");
    let steps = tau / z.arg().abs();
    let damped = (1.0 - zeta * zeta).sqrt();
    let true_period = n / damped;
    let true_decay = (-tau * zeta / damped).exp();
    (steps / true_period, z.norm().powf(steps) / true_decay)
}

/// Generalised-α steps per period of the capture's oscillation asked for: at ρ∞ = 0.8, period
/// +1.5 % and amplitude ×0.9998 per cycle, the midpoint rule's rule.
pub const ALPHA_STEPS_PER_PERIOD: f64 = 15.0;

/// Midpoint steps per period of the capture's oscillation asked for (period error ≈ 1.4 %, no
/// numerical damping).
pub const MIDPOINT_STEPS_PER_PERIOD: f64 = 15.0;

/// The implicit midpoint rule on ẍ = −ω²x resolved by `n` steps per period: (numerical period /
/// true period, amplitude ratio per numerical period). The step's amplification in (x, v) has
/// the eigenvalues z = (1 ± iθ/2)/(1 ∓ iθ/2), θ = ωΔt: |z| = 1 and arg z = 2 atan(θ/2).
pub fn midpoint_oscillator_error(n: f64) -> (f64, f64) {
    let theta = 2.0 * std::f64::consts::PI / n;
    let i = Complex::new(0.0, 1.0);
    let z =
        (Complex::new(1.0, 0.0) + i * (0.5 * theta)) / (Complex::new(1.0, 0.0) - i * (0.5 * theta));
    let steps = 2.0 * std::f64::consts::PI / z.arg().abs();
    (steps / n, z.norm().powf(steps))
}

/// BDF2 steps per period of the capture's oscillation asked for (period error ≈ 1.2 %,
/// numerical damping ≈ 1 % per cycle).
pub const STEPS_PER_PERIOD: f64 = 32.0;

/// Most substeps chosen automatically (a dataset may declare more): time and the adjoint's tape
/// grow with the step count.
pub const MAX_SUBSTEPS: usize = 8;

/// How a dataset's simulation step was chosen.
#[derive(Debug, Clone, PartialEq)]
pub struct TimeStep {
    /// Simulation steps per capture interval.
    pub substeps: usize,
    /// The capture interval (s).
    pub capture_dt: f64,
    /// The period of the capture's dominant oscillation (s), when one was found.
    pub period_s: Option<f64>,
    /// Whether `substeps` was declared in `dataset.toml` (else chosen here).
    pub declared: bool,
    /// The integration scheme the step was chosen for.
    pub scheme: Scheme,
    /// The step's own error measured on the capture ([`crate::step_error`]) when the step was
    /// chosen, not declared; `Err` says why it could not be.
    pub step_error: Option<Result<StepError, String>>,
}

impl TimeStep {
    /// Integration at the capture rate, declared (a dataset made by a simulation at that step).
    pub fn capture_rate(capture_dt: f64) -> Self {
        Self {
            substeps: 1,
            capture_dt,
            period_s: None,
            declared: true,
            scheme: Scheme::Bdf2,
            step_error: None,
        }
    }

    /// Simulation steps per period of the capture's oscillation.
    pub fn steps_per_period(&self) -> Option<f64> {
        self.period_s
            .map(|p| p / (self.capture_dt / self.substeps as f64))
    }

    /// One sentence for reports: the step, why, and the scheme's error at it.
    pub fn describe(&self) -> String {
        let step_ms = 1e3 * self.capture_dt / self.substeps as f64;
        let raised = match &self.step_error {
            Some(Ok(e)) if e.substeps > e.from_substeps => Some(e.from_substeps),
            _ => None,
        };
        let why = if self.declared {
            "as declared (`substeps`)".to_string()
        } else if let Some(k) = raised {
            format!("raised from the period rule's {k} by the step's measured error")
        } else {
            match self.period_s {
                Some(_) => format!(
                    "≥ {:.0} {} steps per period of the capture's oscillation",
                    self.scheme.steps_per_period(),
                    self.scheme.name()
                ),
                None => "no oscillation found in the capture: its own rate".into(),
            }
        };
        let error = match (self.period_s, self.steps_per_period()) {
            (Some(p), Some(n)) => {
                let (ratio, amp) = self.scheme.oscillator_error(n);
                format!(
                    "; the capture oscillates with period {:.3} s, {n:.0} steps per period: \
                     numerical period +{:.1} %, amplitude ×{amp:.3} per cycle",
                    p,
                    100.0 * (ratio - 1.0)
                )
            }
            _ => String::new(),
        };
        let checked = match &self.step_error {
            Some(Ok(e)) => format!("; {}", e.describe()),
            Some(Err(why)) => format!("; the step's own error not measured: {why}"),
            None => String::new(),
        };
        let undamped = if self.scheme == Scheme::Midpoint {
            "; a model without viscosity (a diagnosis' simplest) is integrated by BDF2 at this \
             step, whose numerical damping is then part of its figures (docs/motion-dataset.md)"
        } else {
            ""
        };
        format!(
            "simulated every {step_ms:.3} ms ({} substep{} of the {:.3} ms capture interval, {why}){error}{checked}{undamped}",
            self.substeps,
            if self.substeps == 1 { "" } else { "s" },
            1e3 * self.capture_dt
        )
    }
}

/// BDF2 on the undamped oscillator ẍ = −ω²x resolved by `n` steps per period: (numerical period
/// / true period, amplitude ratio per numerical period). From the characteristic equation of the
/// scheme in (x, v): ((3z² − 4z + 1)/2)² + (ωΔt)² z⁴ = 0, whose growing roots are
/// z = (2 ± √(1 + 2iωΔt)) / (3 − 2iωΔt) and its conjugate; the root of largest modulus is the
/// physical mode.
pub fn bdf2_oscillator_error(n: f64) -> (f64, f64) {
    let w = 2.0 * std::f64::consts::PI / n;
    let i = Complex::new(0.0, 1.0);
    let root = (Complex::new(1.0, 0.0) + i * (2.0 * w)).sqrt();
    let den = Complex::new(3.0, 0.0) - i * (2.0 * w);
    let z = [(2.0 + root) / den, (2.0 - root) / den]
        .into_iter()
        .max_by(|a, b| a.norm().total_cmp(&b.norm()))
        .expect("two roots");
    let steps = 2.0 * std::f64::consts::PI / z.arg().abs();
    (steps / n, z.norm().powf(steps))
}

/// Period and amplitude ratio per cycle of a ring-down `s` (sampled every `dt`; NaN = not
/// observed) about its final value (the mean of its last fifth): from the crossings of that value
/// and the extremes between them, over the half-cycles whose extreme exceeds 5 % of the first
/// one.
pub fn ring_down(s: &[f64], dt: f64) -> (Option<f64>, Option<f64>) {
    let v: Vec<(usize, f64)> = s
        .iter()
        .copied()
        .enumerate()
        .filter(|(_, x)| x.is_finite())
        .collect();
    if v.len() < 10 {
        return (None, None);
    }
    let tail = &v[v.len() - v.len() / 5..];
    let rest = tail.iter().map(|p| p.1).sum::<f64>() / tail.len() as f64;
    // Crossing times (linear interpolation) and the extreme of each half-cycle.
    let mut crossings = Vec::new();
    let mut extremes = Vec::new();
    let mut peak = 0.0f64;
    for w in v.windows(2) {
        let (a, b) = (w[0].1 - rest, w[1].1 - rest);
        if a.abs() > peak.abs() {
            peak = a;
        }
        if a != 0.0 && a.signum() != b.signum() {
            let t = (w[0].0 as f64 + a / (a - b) * (w[1].0 - w[0].0) as f64) * dt;
            crossings.push(t);
            extremes.push(peak.abs());
            peak = 0.0;
        }
    }
    // Half-cycles between crossings; keep those above 5 % of the largest (noise crossings later).
    let first = extremes.iter().copied().fold(0.0, f64::max);
    let keep = extremes
        .iter()
        .skip(1)
        .take_while(|e| **e > 0.05 * first)
        .count();
    if keep < 2 {
        return (None, None);
    }
    let half: Vec<f64> = crossings
        .windows(2)
        .take(keep)
        .map(|w| w[1] - w[0])
        .collect();
    let period = 2.0 * half.iter().sum::<f64>() / half.len() as f64;
    // Extremes of the same sign one cycle apart.
    let ex = &extremes[1..=keep];
    let ratios: Vec<f64> = ex.windows(3).map(|w| w[2] / w[0]).collect();
    let decay = (!ratios.is_empty())
        .then(|| (ratios.iter().map(|r| r.ln()).sum::<f64>() / ratios.len() as f64).exp());
    (Some(period), decay)
}

/// The period of the dominant oscillation the capture shows (s): the ring-down of the marker that
/// moves most, along the direction it moves most (its trajectory's principal axis).
pub fn capture_period(model: &Model, obs: &Observations) -> Option<f64> {
    let nm = model.markers.len();
    let mut best: Option<(f64, Vec<f64>)> = None;
    for i in 0..nm {
        let pts: Vec<(usize, [f64; 3])> = obs
            .markers
            .iter()
            .enumerate()
            .filter_map(|(n, row)| row.get(i).copied().flatten().map(|p| (n, p)))
            .collect();
        if pts.len() < 10 {
            continue;
        }
        let c = pts.len() as f64;
        let mean = [0, 1, 2].map(|k| pts.iter().map(|p| p.1[k]).sum::<f64>() / c);
        let cov = nalgebra::Matrix3::from_fn(|a, b| {
            pts.iter()
                .map(|p| (p.1[a] - mean[a]) * (p.1[b] - mean[b]))
                .sum::<f64>()
                / c
        });
        let eig = cov.symmetric_eigen();
        let (j, var) = eig
            .eigenvalues
            .iter()
            .copied()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(&b.1))?;
        if best.as_ref().is_some_and(|b| b.0 >= var) {
            continue;
        }
        let axis = eig.eigenvectors.column(j).into_owned();
        let mut s = vec![f64::NAN; obs.markers.len()];
        for (n, p) in &pts {
            s[*n] = (0..3).map(|k| (p[k] - mean[k]) * axis[k]).sum();
        }
        best = Some((var, s));
    }
    let (_, s) = best?;
    ring_down(&s, model.dt).0
}

/// Substeps that give `scheme`'s [`Scheme::steps_per_period`] steps per `period_s` at the
/// capture interval `capture_dt` (1 without a period; at most [`MAX_SUBSTEPS`]).
pub fn substeps_for_scheme(scheme: Scheme, capture_dt: f64, period_s: Option<f64>) -> usize {
    match period_s {
        Some(p) if p > 0.0 && capture_dt > 0.0 => {
            let k = (scheme.steps_per_period() * capture_dt / p).ceil();
            (k.max(1.0) as usize).min(MAX_SUBSTEPS)
        }
        _ => 1,
    }
}

/// BDF2's substeps: [`substeps_for_scheme`] with [`Scheme::Bdf2`].
///
/// Substeps that give [`STEPS_PER_PERIOD`] steps per `period_s` at the capture interval
/// `capture_dt` (1 without a period; at most [`MAX_SUBSTEPS`]).
pub fn substeps_for(capture_dt: f64, period_s: Option<f64>) -> usize {
    substeps_for_scheme(Scheme::Bdf2, capture_dt, period_s)
}

/// The time step of a capture: `declared` substeps, or chosen from the capture's own
/// oscillation ([`capture_period`], [`substeps_for`]). `model` and `obs` are at the capture rate.
pub fn choose(model: &Model, obs: &Observations, declared: Option<usize>) -> TimeStep {
    let period_s = capture_period(model, obs);
    let (substeps, declared) = match declared {
        Some(k) => (k.max(1), true),
        None => (substeps_for_scheme(model.scheme, model.dt, period_s), false),
    };
    TimeStep {
        substeps,
        capture_dt: model.dt,
        period_s,
        declared,
        scheme: model.scheme,
        step_error: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The error table of the module documentation, and a check of the formula against a direct
    /// BDF2 integration of the oscillator.
    #[test]
    fn bdf2_error_matches_a_direct_integration() {
        let (r13, a13) = bdf2_oscillator_error(13.0);
        assert!(
            (r13 - 1.065).abs() < 1e-3 && (a13 - 0.887).abs() < 1e-3,
            "{r13} {a13}"
        );
        let (r32, a32) = bdf2_oscillator_error(32.0);
        assert!(
            (r32 - 1.012).abs() < 1e-3 && (a32 - 0.990).abs() < 1e-3,
            "{r32} {a32}"
        );
        // Direct: x'' = −ω²x with ω = 2π (period 1), 13 steps per period, BDF2 in (x, v) from
        // x = 1 at rest; the amplitude after 20 cycles against a13^20 (in numerical periods).
        let n = 13.0;
        let (w, dt) = (2.0 * std::f64::consts::PI, 1.0 / n);
        let (mut x1, mut x2, mut v1, mut v2) = (1.0f64, 1.0f64, 0.0f64, 0.0f64);
        let mut xs = vec![1.0];
        for _ in 0..(40.0 * n) as usize {
            // Solve the 2×2 step: x = (4x1 − x2)/3 + 2dt/3 v, (3v − 4v1 + v2)/(2dt) = −w²x.
            let a = (4.0 * x1 - x2) / 3.0;
            let b = (4.0 * v1 - v2) / 3.0;
            let c = 2.0 * dt / 3.0;
            let v = (b - c * w * w * a) / (1.0 + c * c * w * w);
            let x = a + c * v;
            (x2, x1, v2, v1) = (x1, x, v1, v);
            xs.push(x);
        }
        let (period, decay) = ring_down(&xs, dt);
        let (period, decay) = (period.unwrap(), decay.unwrap());
        assert!((period - r13).abs() < 0.01, "period {period} vs {r13}");
        assert!((decay - a13).abs() < 0.01, "decay {decay} vs {a13}");
    }

    /// The scheme table of [`Scheme`]'s documentation, from the characteristic polynomials.
    #[test]
    fn scheme_table_matches_the_polynomials() {
        let table = [
            (
                Scheme::Bdf2,
                [1.065, 1.051, 1.045, 1.030, 1.018, 1.012],
                [0.887, 0.919, 0.931, 0.961, 0.981, 0.989],
            ),
            (
                Scheme::Midpoint,
                [1.019, 1.014, 1.013, 1.008, 1.005, 1.003],
                [1.0; 6],
            ),
            (
                Scheme::Alpha,
                [1.020, 1.015, 1.013, 1.009, 1.005, 1.003],
                [1.0; 6],
            ),
        ];
        for (scheme, period, amp) in table {
            for (i, n) in [13.0, 15.0, 16.0, 20.0, 26.0, 32.0].into_iter().enumerate() {
                let (r, a) = scheme.oscillator_error(n);
                assert!(
                    (r - period[i]).abs() < 1e-3 && (a - amp[i]).abs() < 1e-3,
                    "{scheme:?} at {n}: period ×{r:.4} amplitude ×{a:.4}"
                );
            }
        }
        // The midpoint rule's rule: ≈ 1.4 % period error and no numerical damping.
        let (r, a) = Scheme::Midpoint.oscillator_error(MIDPOINT_STEPS_PER_PERIOD);
        assert!(
            (r - 1.0144).abs() < 1e-3 && (a - 1.0).abs() < 1e-12,
            "{r} {a}"
        );
    }

    /// Undamped, the amplification matrix gives the closed forms.
    #[test]
    fn damped_error_reduces_to_the_closed_forms() {
        for scheme in [Scheme::Bdf2, Scheme::Midpoint, Scheme::Alpha] {
            for n in [13.0, 32.0] {
                let (r, a) = scheme.oscillator_error(n);
                let (rd, ad) = damped_oscillator_error(scheme, n, 0.0);
                assert!(
                    (r - rd).abs() < 1e-10 && (a - ad).abs() < 1e-10,
                    "{scheme:?} {n}"
                );
            }
        }
    }

    /// Generalised-α as written here is the first-order generalised-α of Jansen, Whiting &
    /// Hulbert on the oscillator's (x, v): the physical eigenvalue of that scheme's
    /// amplification (state y, ẏ) equals the two-step method's largest root, at every ωΔt and
    /// damping, and both lose ρ∞ per step as ωΔt → ∞.
    #[test]
    fn alpha_is_jansen_whiting_hulbert_generalised_alpha() {
        use nalgebra::{DMatrix, Matrix2};
        for rho in [0.0, 0.5, ALPHA_RHO_INF, 0.9] {
            let two = TwoStep::generalised_alpha(rho);
            let (am, af) = (0.5 * (3.0 - rho) / (1.0 + rho), 1.0 / (1.0 + rho));
            let gamma = 0.5 + am - af;
            for (wh, zeta) in [
                (0.05, 0.0),
                (0.4, 0.0),
                (0.4, 0.05),
                (3.0, 0.02),
                (1e4, 0.0),
            ] {
                let a = Matrix2::new(0.0, 1.0, -wh * wh, -2.0 * zeta * wh);
                // (αm/γ I − αf A) y' = (αm/γ I + (1 − αf) A) y + (αm(1 − γ)/γ − (1 − αm)) ẏ,
                // ẏ' = (y' − y − (1 − γ) ẏ)/γ, with Δt = 1.
                let lhs = Matrix2::identity() * (am / gamma) - a * af;
                let inv = lhs.try_inverse().expect("invertible");
                let py = inv * (Matrix2::identity() * (am / gamma) + a * (1.0 - af));
                let pd = inv * (am * (1.0 - gamma) / gamma - (1.0 - am));
                let qy = (py - Matrix2::identity()) / gamma;
                let qd = pd / gamma - Matrix2::identity() * ((1.0 - gamma) / gamma);
                let amp = DMatrix::from_fn(4, 4, |r, c| match (r < 2, c < 2) {
                    (true, true) => py[(r, c)],
                    (true, false) => pd[(r, c - 2)],
                    (false, true) => qy[(r - 2, c)],
                    (false, false) => qd[(r - 2, c - 2)],
                });
                let jwh = amp
                    .complex_eigenvalues()
                    .iter()
                    .copied()
                    .max_by(|p, q| p.norm().total_cmp(&q.norm()))
                    .expect("four eigenvalues");
                // The two-step method on y' = λ y, λ the oscillator's eigenvalue.
                let lam = Complex::new(-zeta * wh, wh * (1.0 - zeta * zeta).sqrt());
                let (al, be) = (two.alpha, two.beta);
                let p2 = lam * (-be[2]) + al[2];
                let p1 = lam * (-be[1]) + al[1];
                let p0 = lam * (-be[0]) + al[0];
                let disc = (p1 * p1 - p2 * p0 * 4.0).sqrt();
                let roots = [(-p1 + disc) / (p2 * 2.0), (-p1 - disc) / (p2 * 2.0)];
                let lmm = roots
                    .into_iter()
                    .max_by(|p, q| p.norm().total_cmp(&q.norm()))
                    .expect("two roots");
                assert!(
                    (jwh.norm() - lmm.norm()).abs() < 1e-7
                        && (jwh.arg().abs() - lmm.arg().abs()).abs() < 1e-7,
                    "ρ∞ {rho}, ωΔt {wh}, ζ {zeta}: JWH {jwh} two-step {lmm}"
                );
                if wh > 1e3 {
                    assert!((lmm.norm() - rho).abs() < 2e-2, "ρ∞ {rho}: {lmm}");
                }
            }
        }
    }

    /// BDF2's and the midpoint rule's two-step coefficients give their own step constants, and
    /// generalised-α meets the order conditions.
    #[test]
    fn two_step_coefficients_are_consistent() {
        for scheme in [Scheme::Bdf2, Scheme::Midpoint] {
            let (c, ax, av) = scheme.coefficients(0.01);
            let (c2, ax2, av2) = scheme.two_step().coefficients(0.01);
            assert!(
                (c - c2).abs() < 1e-9 && (ax - ax2).abs() < 1e-15 && (av - av2).abs() < 1e-15,
                "{scheme:?}"
            );
        }
        let t = TwoStep::generalised_alpha(ALPHA_RHO_INF);
        let sum = |w: [f64; 3], p: i32| (0..3).map(|j| w[j] * (j as f64).powi(p)).sum::<f64>();
        assert!(sum(t.alpha, 0).abs() < 1e-14);
        assert!((sum(t.alpha, 1) - sum(t.beta, 0)).abs() < 1e-14);
        assert!((sum(t.beta, 0) - 1.0).abs() < 1e-14);
        assert!((sum(t.alpha, 2) - 2.0 * sum(t.beta, 1)).abs() < 1e-14);
    }

    #[test]
    fn midpoint_substeps_follow_the_rule() {
        // The beam's gravity runs (0.130 s) and 52 g runs (0.231 s) at 100 Hz.
        assert_eq!(substeps_for_scheme(Scheme::Midpoint, 0.01, Some(0.13)), 2);
        assert_eq!(substeps_for_scheme(Scheme::Midpoint, 0.01, Some(0.231)), 1);
        assert_eq!(substeps_for_scheme(Scheme::Bdf2, 0.01, Some(0.13)), 3);
        assert_eq!(substeps_for_scheme(Scheme::Alpha, 0.01, Some(0.13)), 2);
        assert_eq!(substeps_for_scheme(Scheme::Alpha, 0.01, Some(0.231)), 1);
    }

    #[test]
    fn substeps_follow_the_rule() {
        assert_eq!(substeps_for(0.01, Some(0.13)), 3);
        assert_eq!(substeps_for(0.01, Some(0.23)), 2);
        assert_eq!(substeps_for(0.01, Some(2.0)), 1);
        assert_eq!(substeps_for(0.01, None), 1);
        assert_eq!(substeps_for(0.01, Some(1e-4)), MAX_SUBSTEPS);
    }
}
