//! The minimum of a misfit along one coordinate from its values alone: bracketed from a start by
//! steps that grow by the golden ratio, then closed in by the parabola through the bracket,
//! guarded by golden sections (successive parabolic interpolation in the manner of Brent 1973,
//! ch. 5), until the parabola predicts less gain than the caller's precision.
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

/// Minimises `f` along one coordinate from `t0`: first a step of `step`, then steps of the
/// golden ratio times the last, downhill (the other way when the first step rises), until the
/// value rises — a bracket — then the vertex of the parabola through the bracket's three points
/// until it predicts a gain of at most `least_gain`, at most `max_evaluations` values in all. A
/// value that is not finite counts as far above every other. The first error of `f` ends the
/// search with it.
pub fn line_minimum<E>(
    mut f: impl FnMut(f64) -> Result<f64, E>,
    t0: f64,
    step: f64,
    least_gain: f64,
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
    let mut best = last;
    let mut converged = false;
    loop {
        if evaluations.get() >= cap {
            break;
        }
        let next = value(last.t + (last.t - prev.t) / GOLDEN)?;
        if next.f <= last.f {
            (prev, last) = (last, next);
            best = next;
            continue;
        }
        // The bracket (a, x, b) in ascending t, x the least.
        let (mut a, mut x, mut b) = if prev.t < next.t {
            (prev, last, next)
        } else {
            (next, last, prev)
        };
        let mut width_at = (b.t - a.t, 0usize);
        let mut iteration = 0;
        while evaluations.get() < cap {
            iteration += 1;
            let (u, predicted) = vertex(a, x, b);
            if predicted <= least_gain {
                converged = true;
                break;
            }
            let width = b.t - a.t;
            let stuck = iteration - width_at.1 > SHRINK_WITHIN && width > 0.5 * width_at.0;
            let tiny = 1e-12 * x.t.abs().max(1.0);
            let u = if stuck || !(u > a.t + tiny && u < b.t - tiny) || (u - x.t).abs() < tiny {
                // A golden section of the larger part.
                if x.t - a.t > b.t - x.t {
                    x.t - (1.0 - GOLDEN) * (x.t - a.t)
                } else {
                    x.t + (1.0 - GOLDEN) * (b.t - x.t)
                }
            } else {
                u
            };
            if (b.t - a.t) <= 4.0 * tiny {
                converged = true;
                break;
            }
            let p = value(u)?;
            if p.f < x.f {
                // The new least: the bracket closes on it from the side it left.
                if p.t < x.t {
                    (b, x) = (x, p);
                } else {
                    (a, x) = (x, p);
                }
            } else if p.t < x.t {
                a = p;
            } else {
                b = p;
            }
            if b.t - a.t <= 0.5 * width_at.0 {
                width_at = (b.t - a.t, iteration);
            }
        }
        best = x;
        break;
    }
    Ok(LineMinimum {
        t: best.t,
        value: best.f,
        evaluations: evaluations.get(),
        converged,
    })
}

/// The vertex of the parabola through `a`, `x`, `b` (x the least, a < x < b) and the gain it
/// predicts below `x`: (x, 0) where the three lie on a line.
fn vertex(a: Point, x: Point, b: Point) -> (f64, f64) {
    let (da, db) = (a.t - x.t, b.t - x.t);
    let (fa, fb) = (a.f - x.f, b.f - x.f);
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

    /// A looser precision stops sooner, within what it asked for.
    #[test]
    fn the_precision_asked_for_ends_the_search() {
        let f = |t: f64| 4.0e-4 + 0.0073 * (t - 0.107).powi(2) + 0.01 * (t - 0.107).powi(4);
        let Ok(tight) = line_minimum(|t| Ok::<_, Infallible>(f(t)), 0.0, 0.1, 1e-14, 60);
        let Ok(loose) = line_minimum(|t| Ok::<_, Infallible>(f(t)), 0.0, 0.1, 2e-9, 60);
        assert!(loose.converged && tight.converged);
        assert!(loose.evaluations < tight.evaluations, "{loose:?} {tight:?}");
        assert!(loose.value - 4.0e-4 < 2e-8, "{loose:?}");
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
