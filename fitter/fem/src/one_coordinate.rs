//! Least squares in one coordinate: a safeguarded cubic search in a bracket, the form
//! [`crate::lm::minimise_trust_region`] takes when θ has a single coordinate.
//!
//! In one dimension every evaluation gives Φ and Φ' exactly (a simulation's sensitivities), and
//! two of them determine a cubic (Hermite) model of Φ along the whole line; a trust-region
//! iteration with a secant term learns the same curvature one step late and walks the rest on a
//! radius it keeps resizing. Where Φ is not convex — an undamped model out of phase with a
//! ring-down, the simplest model of a motion capture — the difference is large: on the measured
//! beam's simplest model the trust-region iteration takes ten simulations to the minimum, which
//! this search brackets after three and reaches in six. The search is the one of Moré & Thuente
//! (1994) and of Brent's derivative form: interpolate, bracket, and bisect when the
//! interpolation does not shrink the bracket (Nocedal & Wright 2006, §3.5).

use crate::lm::{Normal, TrustOptions, TrustOutcome};

/// One evaluated point: θ, Φ and Φ'.
#[derive(Debug, Clone, Copy)]
struct Point {
    t: f64,
    phi: f64,
    g: f64,
}

/// The far end of a bracket: the minimum lies strictly between the best point and it. A failed
/// evaluation (`None` from the caller) bounds the bracket with no value.
#[derive(Debug, Clone, Copy)]
enum Far {
    Evaluated(Point),
    Failed(f64),
}

impl Far {
    fn t(self) -> f64 {
        match self {
            Far::Evaluated(p) => p.t,
            Far::Failed(t) => t,
        }
    }
}

/// Evaluations after which a bracket that has not halved is bisected: an interpolation that
/// keeps landing beside the best point (one end of the bracket stuck far away) still gets there.
pub const SHRINK_WITHIN: usize = 3;

/// Expansion of an unbracketed step whose cubic has no minimum ahead (Φ concave along the
/// way): a multiple of the last step, at least Gauss–Newton's.
pub const EXPAND: f64 = 4.0;

/// The cubic p(s) = c₀ + c₁ s + c₂ s² + c₃ s³ through `a` (s = 0) and `b` (s = 1) with their
/// values and slopes (in units of s: Φ' · (b − a)).
fn hermite(a: Point, b: Point) -> [f64; 4] {
    let d = b.t - a.t;
    let (ga, gb) = (a.g * d, b.g * d);
    let dphi = b.phi - a.phi;
    [a.phi, ga, 3.0 * dphi - 2.0 * ga - gb, -2.0 * dphi + ga + gb]
}

fn cubic_at(c: [f64; 4], s: f64) -> f64 {
    c[0] + s * (c[1] + s * (c[2] + s * c[3]))
}

/// The local minimum of the cubic `c` (where p' = 0 and p'' > 0), if it has one.
fn cubic_minimum(c: [f64; 4]) -> Option<f64> {
    // p'(s) = c₁ + 2 c₂ s + 3 c₃ s²; at its local minimum p''(s) = 2 c₂ + 6 c₃ s > 0.
    let (a, b, k) = (3.0 * c[3], 2.0 * c[2], c[1]);
    let s = if a.abs() <= 1e-12 * (b.abs() + k.abs()) {
        (b > 0.0).then(|| -k / b)?
    } else {
        let disc = b * b - 4.0 * a * k;
        if disc < 0.0 {
            return None;
        }
        // The root with p'' = 2a s + b = +√disc, in the cancellation-free form.
        let q = -0.5 * (b + b.signum() * disc.sqrt());
        let (r1, r2) = (q / a, if q != 0.0 { k / q } else { f64::NAN });
        [r1, r2]
            .into_iter()
            .find(|&s| s.is_finite() && 2.0 * a * s + b > 0.0)?
    };
    s.is_finite().then_some(s)
}

/// The model's step from `best` toward the minimum of the cubic through `best` and `q`, with
/// the decrease it predicts; `None` where the cubic has no minimum.
fn cubic_step(best: Point, q: Point) -> Option<(f64, f64)> {
    let d = q.t - best.t;
    if d == 0.0 || !q.phi.is_finite() || !q.g.is_finite() {
        return None;
    }
    let c = hermite(best, q);
    let s = cubic_minimum(c)?;
    Some((s * d, best.phi - cubic_at(c, s)))
}

/// The decrease Gauss–Newton's parabola Φ + g s + ½ H s² predicts for the step `s`.
fn parabola_decrease(best: Point, h: f64, s: f64) -> f64 {
    -(best.g * s + 0.5 * h * s * s)
}

/// Minimises Φ(θ) over one coordinate from θ₀ (evaluated: `first`), θ ≥ `lower`.
///
/// The first step is Gauss–Newton's, −Φ'/JᵀJ, within [`TrustOptions::initial_radius`]. Each
/// later one goes to the minimum of the cubic through the best point and the last one evaluated
/// beside it (the Hermite cubic of their values and slopes); before the minimum is bracketed, a
/// step whose cubic has no minimum ahead is [`EXPAND`] times the last (Φ concave along the
/// way), and no step is longer than [`TrustOptions::max_radius`]. The bracket is the best point and the nearest point seen on
/// the far side of the minimum: one where Φ rose, or the last best when Φ' changed sign. Inside
/// it a step that leaves it, or a bracket that has not halved in [`SHRINK_WITHIN`]
/// evaluations, bisects instead. A failed evaluation bounds the bracket where it was tried.
///
/// Stopped as [`crate::lm::minimise_trust_region`] stops: converged when a model that predicted
/// the last accepted step to 25 % (or whose last accepted step gained less than the tolerance)
/// predicts less than [`TrustOptions::rel_tolerance`] of Φ (or the absolute tolerance); when a
/// trusted model's step predicted below the noise tolerance gains nothing; when the step or the
/// bracket is shorter than 10⁻⁸; on the bound with Φ' pointing below it; or at the iteration
/// limit (not converged).
pub fn minimise_one_coordinate(
    theta0: f64,
    first: Normal,
    mut eval: impl FnMut(&[f64]) -> Option<Normal>,
    o: &TrustOptions,
    lower: f64,
) -> TrustOutcome {
    let point = |t: f64, n: &Normal| Point {
        t,
        phi: n.phi,
        g: n.grad[0],
    };
    let mut best = point(theta0, &first);
    let mut best_normal = first;
    // The last point evaluated other than the best (the cubic's second point).
    let mut other: Option<Point> = None;
    let mut far: Option<Far> = None;
    let mut width_at = (f64::INFINITY, 0usize);
    let mut trusted = false;
    let mut gained = f64::INFINITY;
    let mut iterations = 0;
    let mut converged = false;
    let mut last_step = 0.0f64;
    while iterations < o.max_iterations {
        let (phi, g) = (best.phi, best.g);
        let tolerance = o.least_gain(o.rel_tolerance, phi);
        if g == 0.0 || g.is_nan() || (best.t <= lower && g > 0.0) {
            // At a stationary point, or held on the bound with Φ' pointing below it.
            converged = true;
            break;
        }
        let descent = -g.signum();
        let h = best_normal.gn[0];
        // The model's step: the cubic through the best point and the other, where it has a
        // minimum on the descent side; else Gauss–Newton's parabola, or an expansion.
        let modelled = other
            .and_then(|q| cubic_step(best, q))
            .filter(|&(s, p)| s * descent > 0.0 && p > 0.0);
        let (mut step, mut predicted) = match modelled {
            Some(sp) => sp,
            None if other.is_none() && h > 0.0 => {
                let s = (-g / h).clamp(-o.initial_radius, o.initial_radius);
                (s, parabola_decrease(best, h, s))
            }
            None => {
                let gn = if h > 0.0 { (g / h).abs() } else { 0.0 };
                let len = (EXPAND * last_step.abs()).max(gn).max(if last_step == 0.0 {
                    o.initial_radius
                } else {
                    0.0
                });
                let s = descent * len;
                (s, -g * s)
            }
        };
        if step.abs() > o.max_radius {
            step = step.signum() * o.max_radius;
            predicted = predicted.min(-g * step);
        }
        if let Some(f) = far {
            let span = f.t() - best.t;
            let inside = step / span;
            let (width, since) = width_at;
            let stuck = iterations - since >= SHRINK_WITHIN && span.abs() > 0.5 * width;
            if !(inside > 0.0 && inside < 1.0) || stuck {
                step = 0.5 * span;
                predicted = match f {
                    Far::Evaluated(q) if q.phi.is_finite() && q.g.is_finite() => {
                        best.phi - cubic_at(hermite(best, q), 0.5)
                    }
                    _ => -g * step,
                };
            }
            if span.abs() < 1e-8 {
                converged = true;
                break;
            }
        }
        let mut hit = false;
        if best.t + step < lower {
            step = lower - best.t;
            predicted = predicted.min(-g * step);
            hit = true;
        }
        let small = !hit && predicted.partial_cmp(&tolerance) != Some(std::cmp::Ordering::Greater);
        if ((trusted || gained <= tolerance) && small) || step.abs() < 1e-8 {
            converged = true;
            break;
        }
        iterations += 1;
        log::debug!(
            "one-coordinate search {iterations}: Φ {phi:.6e}, Φ' {g:.3e}, predicted decrease {predicted:.3e}, step {step:.6e}{}",
            if far.is_some() { ", bracketed" } else { "" }
        );
        let t = if hit { lower } else { best.t + step };
        last_step = step;
        match eval(&[t]) {
            Some(next) if next.phi < phi => {
                let p = point(t, &next);
                let actual = phi - p.phi;
                trusted = (actual / predicted - 1.0).abs() < 0.25;
                gained = actual;
                if p.g.signum() != best.g.signum() {
                    far = Some(Far::Evaluated(best));
                }
                other = Some(best);
                best = p;
                best_normal = next;
            }
            result => {
                if let (Some(_), true) = (&result, trusted) {
                    if predicted < o.least_gain(o.noise_tolerance, phi) {
                        converged = true;
                        break;
                    }
                }
                far = Some(match result {
                    Some(n) => {
                        let p = point(t, &n);
                        other = Some(p);
                        Far::Evaluated(p)
                    }
                    None => Far::Failed(t),
                });
            }
        }
        if let Some(f) = far {
            let width = (f.t() - best.t).abs();
            if width <= 0.5 * width_at.0 {
                width_at = (width, iterations);
            }
        }
    }
    TrustOutcome {
        theta: vec![best.t],
        normal: best_normal,
        iterations,
        converged,
        linearised_at: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn options(rel_tolerance: f64) -> TrustOptions {
        TrustOptions {
            max_iterations: 100,
            rel_tolerance,
            noise_tolerance: 0.0,
            abs_tolerance: 0.0,
            initial_radius: 1.0,
            max_radius: 3.0,
            probe_bounds: 0,
        }
    }

    /// Φ = ½ r² with r(θ) given with its derivative: the Normal of one residual.
    fn normal(r: f64, dr: f64) -> Normal {
        Normal {
            phi: 0.5 * r * r,
            grad: vec![r * dr],
            gn: vec![dr * dr],
        }
    }

    /// The cubic through two points holds their values and slopes, and a cubic that is a
    /// parabola in disguise has the parabola's minimum.
    #[test]
    fn the_hermite_cubic_holds_its_two_points() {
        let a = Point {
            t: 1.0,
            phi: 2.0,
            g: -3.0,
        };
        let b = Point {
            t: 3.0,
            phi: 1.5,
            g: 0.7,
        };
        let c = hermite(a, b);
        let d = b.t - a.t;
        assert!((cubic_at(c, 0.0) - a.phi).abs() < 1e-14);
        assert!((cubic_at(c, 1.0) - b.phi).abs() < 1e-14);
        assert!((c[1] / d - a.g).abs() < 1e-14);
        assert!(((c[1] + 2.0 * c[2] + 3.0 * c[3]) / d - b.g).abs() < 1e-14);
        // Φ = (θ − 2)²: the cubic through θ = 0 and θ = 5 is Φ itself.
        let q = |t: f64| Point {
            t,
            phi: (t - 2.0) * (t - 2.0),
            g: 2.0 * (t - 2.0),
        };
        let (s, p) = cubic_step(q(0.0), q(5.0)).unwrap();
        assert!(
            (s - 2.0).abs() < 1e-12 && (p - 4.0).abs() < 1e-12,
            "{s} {p}"
        );
    }

    /// A residual whose slope grows away from its root, r = sinh(θ − 2): from θ = 0 to the
    /// minimum at 2 in a handful of evaluations; with a floor below the start and the minimum
    /// the same minimum, and with a floor above the minimum (from θ = 3) on the floor.
    #[test]
    fn a_stiff_start_reaches_the_minimum_and_a_floor_holds_it() {
        let evals = std::cell::Cell::new(0);
        let eval = |t: &[f64]| {
            evals.set(evals.get() + 1);
            Some(normal((t[0] - 2.0).sinh(), (t[0] - 2.0).cosh()))
        };
        let start = 0.0;
        let o = options(1e-14);
        let out =
            minimise_one_coordinate(start, eval(&[start]).unwrap(), eval, &o, f64::NEG_INFINITY);
        assert!(out.converged, "{out:?}");
        assert!((out.theta[0] - 2.0).abs() < 1e-7, "{out:?}");
        assert!(evals.get() <= 10, "{} evaluations", evals.get());
        let floored = minimise_one_coordinate(start, eval(&[start]).unwrap(), eval, &o, -1.0);
        assert!((floored.theta[0] - 2.0).abs() < 1e-7, "{floored:?}");
        let high = minimise_one_coordinate(3.0, eval(&[3.0]).unwrap(), eval, &o, 2.5);
        assert!(high.converged && high.theta[0] == 2.5, "{high:?}");
    }

    /// Failed evaluations beyond θ = 1 (a simulation that inverts an element): the bracket
    /// closes on them, and the search ends at the best point below them, not on a failure.
    #[test]
    fn failed_evaluations_bound_the_bracket() {
        let eval = |t: &[f64]| (t[0] < 1.0).then(|| normal(t[0] - 2.0, 1.0));
        let o = options(1e-12);
        let out = minimise_one_coordinate(0.0, eval(&[0.0]).unwrap(), eval, &o, f64::NEG_INFINITY);
        assert!(out.theta[0] < 1.0 && out.theta[0] > 0.99, "{out:?}");
    }
}
