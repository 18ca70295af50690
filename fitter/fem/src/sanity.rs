//! Sanity gates shared by every command that fits or simulates (`fit`, `fit-motion`, `diagnose`,
//! `simulate`): data that cannot determine a stiffness, parameters at the edge of what is
//! physical, displacements larger than the object, solvers that stopped at their caps.
//!
//! Why a gate and not a check inside each solver: a solver that "succeeds" on degenerate data
//! returns its starting guess or a bound (E = 10 kPa after 0 iterations on zero forces, ν = −1 on
//! a meganewton), and a command that exports that model gives the user a confident wrong answer.
//! Every finding has a severity: an [`Severity::Error`] stops the command before anything is
//! written; a [`Severity::Warning`] is printed, written into the report, and leaves the exit code
//! non-zero only if the command is asked to be strict.

use std::fmt;

use palpate_runtime::material::LambdaAlpha;

use crate::dataset::StaticDataset;
use crate::forward::Material;

/// How bad a finding is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Severity {
    /// The result is still a result, but the user must know this.
    Warning,
    /// The result is not a result: nothing is exported.
    Error,
}

/// One thing a gate found.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Finding {
    /// How bad.
    pub severity: Severity,
    /// A stable short name (`zero-forces`, `markers-still`, `poisson-at-bound`, …) for scripts.
    pub code: &'static str,
    /// What was found, with the numbers, and what to do.
    pub message: String,
}

impl fmt::Display for Finding {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = match self.severity {
            Severity::Warning => "warning",
            Severity::Error => "error",
        };
        write!(f, "{s} [{}]: {}", self.code, self.message)
    }
}

/// The findings of one or more gates.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct Findings(pub Vec<Finding>);

/// A gate refused the input or the result.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}", .0.iter().filter(|f| f.severity == Severity::Error).map(|f| format!("[{}] {}", f.code, f.message)).collect::<Vec<_>>().join("\n"))]
pub struct Refused(pub Vec<Finding>);

impl Findings {
    /// Adds an error.
    pub fn error(&mut self, code: &'static str, message: impl Into<String>) {
        self.0.push(Finding {
            severity: Severity::Error,
            code,
            message: message.into(),
        });
    }
    /// Adds a warning.
    pub fn warn(&mut self, code: &'static str, message: impl Into<String>) {
        self.0.push(Finding {
            severity: Severity::Warning,
            code,
            message: message.into(),
        });
    }
    /// Appends another gate's findings.
    pub fn extend(&mut self, other: Findings) {
        self.0.extend(other.0);
    }
    /// Whether any finding is an error.
    pub fn has_errors(&self) -> bool {
        self.0.iter().any(|f| f.severity == Severity::Error)
    }
    /// The warnings.
    pub fn warnings(&self) -> impl Iterator<Item = &Finding> {
        self.0.iter().filter(|f| f.severity == Severity::Warning)
    }
    /// `Err` with every finding when any is an error, else the findings (warnings only).
    pub fn into_result(self) -> Result<Findings, Refused> {
        if self.has_errors() {
            Err(Refused(self.0))
        } else {
            Ok(self)
        }
    }
}

/// Poisson's ratio this close to −1 is a fit that ran into the bound of the (λ, α)
/// parameterisation (E = λ(1+ν)(1−2ν) → 0), not a measured auxetic.
pub const POISSON_LOWER_LIMIT: f64 = -0.99;
/// Young's moduli outside [1 Pa, 1 GPa] are not a soft object: below, the object would not hold
/// its shape; above, its markers could not have moved under a hand-held probe.
pub const YOUNG_RANGE_PA: (f64, f64) = (1.0, 1e9);

/// Static data that can determine a stiffness: some force, some marker motion above the noise,
/// at least as many observed coordinates as parameters (`parameters`).
pub fn check_static_data(ds: &StaticDataset, parameters: usize) -> Findings {
    let mut f = Findings::default();
    let max_force = ds
        .measurements
        .iter()
        .map(|m| norm(m.force))
        .fold(0.0, f64::max);
    if max_force.is_nan() || max_force <= 0.0 {
        f.error(
            "zero-forces",
            format!(
                "every measurement reports a zero probe force ({} measurements): the data hold \
                 no information on stiffness",
                ds.measurements.len()
            ),
        );
    }
    let mut max_move: f64 = 0.0;
    let mut observed = 0usize;
    for m in &ds.measurements {
        for (k, p) in &m.observed {
            if let Some(rest) = ds.markers.get(*k) {
                max_move = max_move.max(norm(sub(*p, rest.rest)));
                observed += 3;
            }
        }
    }
    let noise = ds.marker_noise.unwrap_or(0.0).max(0.0);
    if max_move <= noise {
        f.error(
            "markers-still",
            format!(
                "no marker moves more than the declared noise (largest move {:.3e} m, marker \
                 noise {:.3e} m): the stiffness is not determined by these data",
                max_move, noise
            ),
        );
    }
    // A measurement that reports no force while its markers move is a row gone wrong (a force
    // not recorded, a tare taken under load): the linear model predicts no motion for it, and
    // the fit can only take its motion for noise or a per-measurement effect.
    for m in &ds.measurements {
        if norm(m.force) > 0.0 || max_force <= 0.0 {
            continue;
        }
        let moved = m
            .observed
            .iter()
            .filter_map(|(k, p)| ds.markers.get(*k).map(|r| norm(sub(*p, r.rest))))
            .fold(0.0, f64::max);
        if moved > 3.0 * noise {
            f.warn(
                "zero-force-moves",
                format!(
                    "measurement {:?} reports a zero probe force but its markers move up to \
                     {moved:.3e} m (marker noise {noise:.3e} m): check its row in contacts.csv",
                    m.id
                ),
            );
        }
    }
    if observed < parameters {
        f.error(
            "too-few-observations",
            format!(
                "{observed} observed marker coordinates for {parameters} parameters: fewer \
                 observations than unknowns"
            ),
        );
    }
    f
}

/// Fitted elastic parameters: every set and element physical, none at the parameterisation's
/// bounds. Sets are named by their index in messages.
pub fn check_material(sets: &[Material]) -> Findings {
    let mut f = Findings::default();
    for (s, m) in sets.iter().enumerate() {
        let mut bad = Vec::new();
        let mut at_lower = 0usize;
        for (e, (&lambda, &alpha)) in m.lambda.iter().zip(&m.alpha).enumerate() {
            let p = LambdaAlpha { lambda, alpha };
            let (young, nu) = (p.young(), p.poisson());
            if !(young.is_finite() && nu.is_finite()) || young <= 0.0 || nu <= -1.0 || nu >= 0.5 {
                bad.push((e, young, nu));
            } else if nu <= POISSON_LOWER_LIMIT
                || young < YOUNG_RANGE_PA.0
                || young > YOUNG_RANGE_PA.1
            {
                at_lower += 1;
                if at_lower == 1 && m.lambda.len() == 1 {
                    f.error(
                        "parameter-at-bound",
                        format!(
                            "set {s}{}: E = {young:.4e} Pa, ν = {nu:.4} — at the edge of what a \
                             soft object can be (ν > {POISSON_LOWER_LIMIT}, E in [{:.0e}, {:.0e}] \
                             Pa); the data do not determine these parameters (check the force \
                             units and sign, the marker motion and the fixed boundary)",
                            if m.lambda.len() > 1 {
                                format!(" element {e}")
                            } else {
                                String::new()
                            },
                            YOUNG_RANGE_PA.0,
                            YOUNG_RANGE_PA.1
                        ),
                    );
                }
            }
        }
        if m.lambda.len() > 1 && at_lower > 0 {
            // Per-element parameters far from every marker are held only by the regularisation:
            // a few at a bound is a weakly determined region, reported, not a refused fit.
            f.warn(
                "parameter-at-bound",
                format!(
                    "set {s}: {at_lower} of {} elements at the edge of what a soft object can be \
                     (ν ≤ {POISSON_LOWER_LIMIT} or E outside [{:.0e}, {:.0e}] Pa): those \
                     elements are not determined by the data (raise γ_s, or add markers near \
                     them)",
                    m.lambda.len(),
                    YOUNG_RANGE_PA.0,
                    YOUNG_RANGE_PA.1
                ),
            );
        }
        if let Some(&(e, young, nu)) = bad.first() {
            f.error(
                "non-physical",
                format!(
                    "set {s}: {} element(s) non-physical, first element {e}: E = {young:.4e} Pa, \
                     ν = {nu:.4}",
                    bad.len()
                ),
            );
        }
    }
    f
}

/// A solver that stopped at its iteration cap: a result, but not a converged one — written, and
/// said loudly (a warning in the report and a non-zero exit status of the command).
pub fn check_iterations(what: &str, used: usize, cap: usize, converged: bool) -> Findings {
    let mut f = Findings::default();
    if !converged {
        f.warn(
            "iteration-cap",
            format!(
                "{what} stopped after {used} of at most {cap} iterations without meeting its \
                 tolerance (raise the iteration limit, or check the data)"
            ),
        );
    }
    f
}

/// Displacements no larger than the object: a linear solve under an absurd load answers with
/// metres of motion of a centimetre block, and that is not a deformation.
pub fn check_displacements(rest: &[[f64; 3]], displacement: &[[f64; 3]]) -> Findings {
    let mut f = Findings::default();
    let diagonal = bounding_diagonal(rest);
    let (mut worst, mut at) = (0.0f64, 0usize);
    for (i, u) in displacement.iter().enumerate() {
        let n = norm(*u);
        if !n.is_finite() {
            f.error(
                "non-finite-displacement",
                format!("node {i}: displacement is not finite"),
            );
            return f;
        }
        if n > worst {
            worst = n;
            at = i;
        }
    }
    if worst > diagonal {
        f.error(
            "displacement-beyond-size",
            format!(
                "node {at} moves {worst:.4e} m, more than the object's own size ({diagonal:.4e} m \
                 bounding-box diagonal): the load is far outside what the model can represent"
            ),
        );
    } else if worst > 0.5 * diagonal {
        f.warn(
            "large-displacement",
            format!(
                "node {at} moves {worst:.4e} m, more than half the object's size ({diagonal:.4e} \
                 m): far beyond the small-strain range a warped linear model was fitted in"
            ),
        );
    }
    f
}

/// The diagonal of the points' axis-aligned bounding box (m).
pub fn bounding_diagonal(points: &[[f64; 3]]) -> f64 {
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for p in points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    if points.is_empty() {
        return 0.0;
    }
    norm(sub(hi, lo))
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn norm(a: [f64; 3]) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn material_bounds_are_named() {
        // The reproducer: λ = 1.56e11, α = −1.56e11 is E = 0, ν = −1.
        let f = check_material(&[Material {
            lambda: vec![1.56e11],
            alpha: vec![-1.56e11],
            foundation: None,
        }]);
        assert!(f.has_errors(), "{f:?}");
        let soft = check_material(&[Material::from_young_poisson(20e3, 0.3)]);
        assert!(soft.0.is_empty(), "{soft:?}");
        let stiff = check_material(&[Material::from_young_poisson(1.6e12, 0.3)]);
        assert!(stiff.has_errors());
        assert!(stiff.0[0].message.contains("E = 1.6"), "{}", stiff.0[0]);
        let auxetic = check_material(&[Material::from_young_poisson(1e4, -0.995)]);
        assert_eq!(auxetic.0[0].code, "parameter-at-bound");
    }

    #[test]
    fn displacements_beyond_the_object_are_refused() {
        let rest = [[0.0, 0.0, 0.0], [0.1, 0.1, 0.05]];
        assert!(check_displacements(&rest, &[[0.0; 3], [0.0, 0.0, -0.01]])
            .0
            .is_empty());
        let big = check_displacements(&rest, &[[0.0; 3], [0.0, 0.0, -7966.0]]);
        assert!(
            big.has_errors() && big.0[0].message.contains("node 1"),
            "{big:?}"
        );
        let nan = check_displacements(&rest, &[[f64::NAN; 3], [0.0; 3]]);
        assert!(nan.has_errors());
    }
}
