//! Golden-section search of a one-parameter misfit on a bracket: the searches that need no
//! gradient (a modulus scale from the rest states, a mesh null's softness), where each
//! evaluation is a simulation and the count of them is the cost.
//!
//! Each section keeps the share 0.618… of the bracket and reuses one interior point, so a
//! section costs one evaluation after the first two (Kiefer 1953).

/// The golden ratio's conjugate, (√5 − 1)/2: the share of a bracket each section keeps.
pub const GOLDEN: f64 = 0.618_033_988_749_895;

/// When a search stops.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Stop {
    /// After this many sections (`n + 2` evaluations).
    Sections(usize),
    /// Once the bracket is no wider than this.
    Width(f64),
}

/// Where a search ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Section {
    /// The last bracket, `a < b`.
    pub a: f64,
    pub b: f64,
    /// Its interior points (`c < d`) and their misfits.
    pub c: f64,
    pub fc: f64,
    pub d: f64,
    pub fd: f64,
    /// The evaluations it took.
    pub evaluations: usize,
}

impl Section {
    /// The better interior point (the lower on a tie).
    pub fn best(&self) -> f64 {
        if self.fc <= self.fd {
            self.c
        } else {
            self.d
        }
    }

    /// The middle of the last bracket.
    pub fn midpoint(&self) -> f64 {
        0.5 * (self.a + self.b)
    }
}

/// Golden sections of `[a, b]` on `f` until `stop`. On a tie of the interior points the lower
/// part of the bracket is kept. The first error of `f` ends the search.
pub fn golden_section<E>(
    mut f: impl FnMut(f64) -> Result<f64, E>,
    a: f64,
    b: f64,
    stop: Stop,
) -> Result<Section, E> {
    let (mut a, mut b) = (a, b);
    let mut c = b - GOLDEN * (b - a);
    let mut d = a + GOLDEN * (b - a);
    let (mut fc, mut fd) = (f(c)?, f(d)?);
    let mut sections = 0;
    while match stop {
        Stop::Sections(n) => sections < n,
        Stop::Width(w) => b - a > w,
    } {
        if fc <= fd {
            (b, d, fd) = (d, c, fc);
            c = b - GOLDEN * (b - a);
            fc = f(c)?;
        } else {
            (a, c, fc) = (c, d, fd);
            d = a + GOLDEN * (b - a);
            fd = f(d)?;
        }
        sections += 1;
    }
    Ok(Section {
        a,
        b,
        c,
        fc,
        d,
        fd,
        evaluations: sections + 2,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::convert::Infallible;

    /// A parabola's minimum, found to the bracket's width, in the evaluations the rule promises.
    #[test]
    fn a_parabola_is_bracketed_at_its_minimum() {
        let f = |x: f64| Ok::<_, Infallible>((x - 0.3).powi(2));
        let Ok(s) = golden_section(f, -2.0, 2.0, Stop::Width(1e-4));
        assert!(s.b - s.a <= 1e-4);
        assert!((s.midpoint() - 0.3).abs() < 1e-4, "{}", s.midpoint());
        // 4 · 0.618ⁿ ≤ 10⁻⁴ first at n = 23.
        assert_eq!(s.evaluations, 25);
        let Ok(s) = golden_section(f, -2.0, 2.0, Stop::Sections(10));
        assert_eq!(s.evaluations, 12);
        assert!((s.b - s.a - 4.0 * GOLDEN.powi(10)).abs() < 1e-12);
        assert!(
            (s.best() - 0.3).abs() < 4.0 * GOLDEN.powi(10),
            "{}",
            s.best()
        );
    }

    /// An error of the misfit ends the search with it.
    #[test]
    fn an_error_ends_the_search() {
        let mut calls = 0;
        let r = golden_section(
            |x: f64| {
                calls += 1;
                if calls == 4 {
                    Err("no")
                } else {
                    Ok(x * x)
                }
            },
            -1.0,
            2.0,
            Stop::Sections(10),
        );
        assert_eq!(r, Err("no"));
        assert_eq!(calls, 4);
    }
}
