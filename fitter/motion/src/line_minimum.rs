//! The minimum of a misfit along one coordinate from its values alone: bracketed from a start by
//! steps that grow by the golden ratio, then closed in by the parabola through the three least
//! values, guarded by golden sections (Brent 1973, ch. 5), until a parabola that has just gained
//! what it predicted predicts less gain than the caller's precision.
//!
//! Where each value is a simulation, one without sensitivities costs a fraction of one with
//! them, and in one coordinate the sensitivities buy only the slope. Brent's own rule (argmin's
//! `BrentOpt`) stops on the width of the bracket, so its last values are spent probing either
//! side of the minimum at that width; this search stops where its model says another value
//! would gain less than the data can tell, as the gradient searches do
//! ([`crate::optimize::precision`]).

/// Where a search ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineMinimum {
    /// The coordinate of the least value found.
    pub t: f64,
    /// That value.
    pub value: f64,
    /// Evaluations made.
    pub evaluations: usize,
    /// Whether the search stopped on its precision (else on the evaluation cap, or on a bracket
    /// that never closed).
    pub converged: bool,
}

/// The value a failed evaluation stands for: far above any misfit, small enough that a parabola
/// through it stays finite.
const FAILED: f64 = 1e150;

/// The golden ratio's conjugate: the bracket's steps grow by its inverse.
const GOLDEN: f64 = crate::golden_section::GOLDEN;

/// Iterations within which the bracket must halve; else the next point is a golden section of its
/// larger part (a parabola that keeps landing beside the best point, one end stuck far away).
const SHRINK_WITHIN: usize = 2;

/// A value of the misfit.
#[derive(Debug, Clone, Copy)]
struct Point {
    t: f64,
    f: f64,
}

/// Minimises `f` (a misfit, ≥ 0) along one coordinate from `t0`: first a step of `step`, then
/// steps of the golden ratio times the last, downhill (the other way when the first step
/// rises), until the value rises — a bracket — then the vertex of the parabola through the three
/// least values (Brent's x, w and v), or a golden section of the bracket's larger part where that
/// vertex falls outside it, next to the least point or into a bracket that has not halved. It
/// stops where the parabola predicts a gain of at most `precision` times the least value and is
/// to be trusted there: its last step gained what it predicted to a quarter, or less than that
/// gain. At most `max_evaluations` values in all. A value that is not finite counts as far above
/// every other. The first error of `f` ends the search with it.
pub fn line_minimum<E>(
    mut f: impl FnMut(f64) -> Result<f64, E>,
    t0: f64,
    step: f64,
    precision: f64,
    max_evaluations: usize,
) -> Result<LineMinimum, E> {
    let cap = max_evaluations.max(3);
    let evaluations = std::cell::Cell::new(0usize);
    let mut value = |t: f64| -> Result<Point, E> {
        evaluations.set(evaluations.get() + 1);
        let v = f(t)?;
        Ok(Point {
            t,
            f: if v.is_finite() { v.min(FAILED) } else { FAILED },
        })
    };
    let (p0, p1) = (value(t0)?, value(t0 + step)?);
    // Uphill, the chain runs the other way: from the step's end through the start.
    let (mut prev, mut last) = if p1.f > p0.f { (p1, p0) } else { (p0, p1) };
    let next = loop {
        if evaluations.get() >= cap {
            return Ok(LineMinimum {
                t: last.t,
                value: last.f,
                evaluations: evaluations.get(),
                converged: false,
            });
        }
        let next = value(last.t + (last.t - prev.t) / GOLDEN)?;
        if next.f > last.f {
            break next;
        }
        (prev, last) = (last, next);
    };
    // The bracket [a, b] holds the least point x; w and v are the next least (Brent's names).
    let (mut a, mut b) = (prev.t.min(next.t), prev.t.max(next.t));
    let (mut x, mut w, mut v) = (last, prev, next);
    let mut width_at = (b - a, 0usize);
    // Whether the last step was a parabola's that gained what it predicted, and what it gained.
    let (mut trusted, mut gained) = (false, f64::INFINITY);
    let mut converged = false;
    let mut iteration = 0;
    while evaluations.get() < cap {
        iteration += 1;
        let least = precision * x.f;
        let (vertex_t, predicted) = vertex(x, w, v);
        if predicted <= least && (trusted || gained <= least) {
            converged = true;
            break;
        }
        let tiny = 1e-12 * x.t.abs().max(1.0);
        if b - a <= 4.0 * tiny {
            converged = true;
            break;
        }
        let stuck = iteration - width_at.1 > SHRINK_WITHIN && b - a > 0.5 * width_at.0;
        let parabolic = predicted > 0.0
            && !stuck
            && vertex_t > a + tiny
            && vertex_t < b - tiny
            && (vertex_t - x.t).abs() > tiny;
        let u = if parabolic {
            vertex_t
        } else if x.t - a > b - x.t {
            // A golden section of the larger part.
            x.t - (1.0 - GOLDEN) * (x.t - a)
        } else {
            x.t + (1.0 - GOLDEN) * (b - x.t)
        };
        let p = value(u)?;
        let actual = x.f - p.f;
        trusted = parabolic && actual > 0.0 && (actual / predicted - 1.0).abs() < 0.25;
        gained = actual.max(0.0);
        if p.f < x.f {
            // The new least: the bracket closes on it from the side it left.
            if p.t < x.t {
                b = x.t;
            } else {
                a = x.t;
            }
            (v, w, x) = (w, x, p);
        } else {
            if p.t < x.t {
                a = p.t;
            } else {
                b = p.t;
            }
            if p.f <= w.f || w.t == x.t {
                (v, w) = (w, p);
            } else if p.f <= v.f || v.t == x.t || v.t == w.t {
                v = p;
            }
        }
        if b - a <= 0.5 * width_at.0 {
            width_at = (b - a, iteration);
        }
    }
    Ok(LineMinimum {
        t: x.t,
        value: x.f,
        evaluations: evaluations.get(),
        converged,
    })
}

/// The vertex of the parabola through `x`, `w`, `v` (three distinct points) and the gain it
/// predicts below `x`: (x, 0) where they lie on a line, coincide or open downward.
fn vertex(x: Point, w: Point, v: Point) -> (f64, f64) {
    let (da, db) = (w.t - x.t, v.t - x.t);
    let (fa, fb) = (w.f - x.f, v.f - x.f);
    // p(t) = x.f + g s + ½ h s², s = t − x.t, through (da, fa) and (db, fb).
    let det = da * db * (db - da);
    if det == 0.0 {
        return (x.t, 0.0);
    }
    let g = (fa * db * db - fb * da * da) / det;
    let h = 2.0 * (fb * da - fa * db) / det;
    if h.is_nan() || h <= 0.0 || !g.is_finite() {
        return (x.t, 0.0);
    }
    let s = -g / h;
    (x.t + s, 0.5 * g * g / h)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::convert::Infallible;

    /// A smooth misfit with its minimum ahead of the start, behind it, and far from it: found to
    /// within the gain asked for, in few values.
    #[test]
    fn a_minimum_is_found_either_side_of_the_start() {
        for (t_star, t0) in [(0.107, 0.0), (-0.45, 0.0), (2.3, 0.1)] {
            // Not a parabola: the parabolas must iterate.
            let f = |t: f64| 1.0 + (t - t_star).powi(2) + 0.3 * (t - t_star).powi(3).abs();
            let Ok(m) = line_minimum(|t| Ok::<_, Infallible>(f(t)), t0, 0.1, 1e-10, 60);
            assert!(m.converged, "{m:?}");
            assert!(m.value - 1.0 < 1e-9, "{t_star}: {m:?}");
            assert!((m.t - t_star).abs() < 1e-4, "{t_star}: {m:?}");
            assert!(m.evaluations <= 16, "{t_star}: {m:?}");
        }
    }

    /// A misfit whose curvature falls away from its minimum on one side (as the measured beam's
    /// undamped model's on its 2,600-tet mesh): the parabola through the first bracket puts its
    /// vertex beside the least point, on the wrong side, predicting almost no gain. The search
    /// goes on until a parabola's step has gained what it predicted.
    #[test]
    fn a_lopsided_minimum_is_not_taken_for_reached() {
        let (t_star, floor) = (0.2895, 4.2185e-4);
        let f = |t: f64| {
            let d: f64 = t - t_star;
            // The curvature 0.014 at the minimum, 0.006 far to its left.
            let c = if d < 0.0 {
                0.007 - 0.004 * (1.0 - (-(d / 0.05).powi(2)).exp())
            } else {
                0.007
            };
            floor + c * d * d
        };
        let precision = 7.9e-6;
        let Ok(m) = line_minimum(|t| Ok::<_, Infallible>(f(t)), 0.0, 0.1, precision, 60);
        assert!(m.converged, "{m:?}");
        assert!(m.value / floor - 1.0 < 2.0 * precision, "{m:?}");
    }

    /// A looser precision stops sooner, within what it asked for.
    #[test]
    fn the_precision_asked_for_ends_the_search() {
        let f = |t: f64| 4.0e-4 + 0.0073 * (t - 0.107).powi(2) + 0.01 * (t - 0.107).powi(4);
        let Ok(tight) = line_minimum(|t| Ok::<_, Infallible>(f(t)), 0.0, 0.1, 1e-12, 60);
        let Ok(loose) = line_minimum(|t| Ok::<_, Infallible>(f(t)), 0.0, 0.1, 1e-5, 60);
        assert!(loose.converged && tight.converged);
        assert!(loose.evaluations < tight.evaluations, "{loose:?} {tight:?}");
        assert!(loose.value / 4.0e-4 - 1.0 < 1e-4, "{loose:?}");
    }

    /// A failed value is far above the rest; an error ends the search with it; the cap holds.
    #[test]
    fn failures_errors_and_the_cap() {
        // Fails (NaN) beyond t = 0.5: the minimum at 0.4 is still found.
        let f = |t: f64| Ok::<_, Infallible>(if t > 0.5 { f64::NAN } else { (t - 0.4).powi(2) });
        let Ok(m) = line_minimum(f, 0.0, 0.1, 1e-12, 60);
        assert!((m.t - 0.4).abs() < 1e-5, "{m:?}");
        let mut calls = 0;
        let r = line_minimum(
            |t: f64| {
                calls += 1;
                if calls == 3 {
                    Err("no")
                } else {
                    Ok(t * t)
                }
            },
            1.0,
            0.1,
            1e-12,
            60,
        );
        assert_eq!(r, Err("no"));
        let Ok(m) = line_minimum(|t: f64| Ok::<_, Infallible>(-t), 0.0, 0.1, 1e-12, 7);
        assert_eq!(m.evaluations, 7);
        assert!(!m.converged);
    }
}
