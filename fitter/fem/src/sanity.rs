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

/// A fit that ended on its starting values (nothing in the data moved it: every marker off by the
/// same large amount, observations in other units) or whose residual is not a number is no
/// result; one whose residual is far above the declared marker noise is a warning. `start` is
/// the starting material of every set, `rms` the fit's RMS marker error (m), `noise` the
/// declared σ per axis (m).
pub fn check_fit_result(
    start: &Material,
    result: &[Material],
    rms: f64,
    noise: Option<f64>,
) -> Findings {
    let mut f = Findings::default();
    let finite = result
        .iter()
        .all(|m| m.lambda.iter().chain(&m.alpha).all(|v| v.is_finite()));
    if !(finite && rms.is_finite()) {
        f.error(
            "non-finite-fit",
            format!(
                "the fit ended at infinity or NaN (RMS marker error {rms:.3e} m): an observed \
                 position is not a number the model can reach (check measurements.csv for huge \
                 values or other units)"
            ),
        );
        return f;
    }
    let same = |a: &[f64], b: &[f64]| a.iter().zip(b.iter().cycle()).all(|(x, y)| x == y);
    let unmoved = !result.is_empty()
        && result
            .iter()
            .all(|m| same(&m.lambda, &start.lambda) && same(&m.alpha, &start.alpha));
    if unmoved {
        f.error(
            "fit-did-not-move",
            format!(
                "the fit ended where it started (λ = {:.4e} Pa, α = {:.4e} Pa, RMS marker error \
                 {:.3} mm): the data did not move it, so the result is the starting guess, not a \
                 measurement (check that measured and rest positions share units and frame)",
                start.lambda[0],
                start.alpha[0],
                1e3 * rms
            ),
        );
    }
    if let Some(sigma) = noise.filter(|s| *s > 0.0) {
        // σ per axis: a marker's error norm is about σ√3 at the noise floor.
        let floor = sigma * 3f64.sqrt();
        if rms > RESIDUAL_NOISE_FACTOR * floor {
            f.warn(
                "residual-above-noise",
                format!(
                    "the RMS marker error {:.3} mm is {:.0} × the declared noise floor {:.3} mm \
                     (marker_noise σ√3): the model does not explain the data (displacements in \
                     other units, a wrong fixed group, or effects the model lacks — try \
                     `palpate diagnose`)",
                    1e3 * rms,
                    rms / floor,
                    1e3 * floor
                ),
            );
        }
    }
    f
}

/// How many times the declared noise floor a fit's RMS marker error may be before it is warned
/// about (a fit that explains its data lands within a few times the floor).
pub const RESIDUAL_NOISE_FACTOR: f64 = 20.0;

/// The largest gravity a dataset or command may declare (m/s²): ten g. Beyond it the number is
/// almost surely in other units (9810 is g in mm/s²).
pub const MAX_GRAVITY_M_S2: f64 = 10.0 * 9.81;

/// The densest material a soft object could be (kg/m³), above osmium's 22 590: beyond it the
/// number is in other units (g/m³, kg/cm³ inverted).
pub const MAX_DENSITY_KG_M3: f64 = 25_000.0;

/// A number as a user wrote it, but short: `1e300` stays `1e300`, not three hundred digits.
pub fn show(v: f64) -> String {
    let plain = v.to_string();
    if plain.len() <= 12 {
        plain
    } else {
        format!("{v:e}")
    }
}

/// Checks a gravity vector: finite and at most [`MAX_GRAVITY_M_S2`]. The message says what was
/// expected and found; the caller adds file, line and field.
pub fn check_gravity(g: [f64; 3]) -> Result<(), String> {
    if !g.iter().all(|v| v.is_finite()) {
        return Err(format!("expected three finite numbers (m/s²), found {g:?}"));
    }
    // Scaled, so that 1e308 is reported as 1e308 and not as an overflowed infinity.
    let big = g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let norm = if big > 0.0 {
        big * g.iter().map(|v| (v / big).powi(2)).sum::<f64>().sqrt()
    } else {
        0.0
    };
    if norm > MAX_GRAVITY_M_S2 {
        return Err(format!(
            "|g| = {norm:.4e} m/s² is more than {MAX_GRAVITY_M_S2:.1} m/s² (10 g); gravity is \
             9.81 m/s² on Earth — {norm:.0} looks like mm/s² or cm/s², give it in m/s²"
        ));
    }
    Ok(())
}

/// Checks a density: finite, > 0 and at most [`MAX_DENSITY_KG_M3`].
pub fn check_density(d: f64) -> Result<(), String> {
    if !(d.is_finite() && d > 0.0) {
        return Err(format!(
            "expected a density > 0 kg/m³ (a foam ~50, silicone ~1100), found {}",
            show(d)
        ));
    }
    if d > MAX_DENSITY_KG_M3 {
        return Err(format!(
            "{d:.4e} kg/m³ is denser than any material (at most {MAX_DENSITY_KG_M3} kg/m³): \
             give it in kg/m³"
        ));
    }
    Ok(())
}

/// Checks the weights of an objective's terms: each finite and ≥ 0, and not all zero (a fit
/// with no weighted term has nothing to match and returns its start). `names` and `weights`
/// are parallel.
pub fn check_weights(names: &[&str], weights: &[f64]) -> Result<(), String> {
    for (n, w) in names.iter().zip(weights) {
        if !(w.is_finite() && *w >= 0.0) {
            return Err(format!(
                "{n}: expected a finite weight ≥ 0, found {}",
                show(*w)
            ));
        }
    }
    if weights.iter().all(|w| *w == 0.0) {
        return Err(if names.len() > 1 {
            format!(
                "{} are all 0: the fit would have nothing to match; give one a weight > 0",
                names.join(" and ")
            )
        } else {
            format!(
                "{} is 0: the fit would have nothing to match; give it a weight > 0",
                names.join("")
            )
        });
    }
    Ok(())
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

    #[test]
    fn a_fit_that_never_moved_or_ran_to_infinity_is_refused() {
        let start = Material::homogeneous(LambdaAlpha {
            lambda: 5e3,
            alpha: 2e3,
        });
        let same = check_fit_result(&start, std::slice::from_ref(&start), 0.077, Some(1e-4));
        assert!(
            same.0.iter().any(|f| f.code == "fit-did-not-move"),
            "{same:?}"
        );
        let mut moved = start.clone();
        moved.lambda[0] *= 1.01;
        let ok = check_fit_result(&start, &[moved.clone()], 2e-4, Some(1e-4));
        assert!(ok.0.is_empty(), "{ok:?}");
        let inf = check_fit_result(&start, &[moved.clone()], f64::INFINITY, None);
        assert!(inf.0.iter().any(|f| f.code == "non-finite-fit"), "{inf:?}");
        let far = check_fit_result(&start, &[moved], 0.053, Some(1e-4));
        assert!(
            far.0.iter().any(|f| f.code == "residual-above-noise"),
            "{far:?}"
        );
    }

    #[test]
    fn bounds_name_the_likely_unit() {
        assert!(check_gravity([0.0, -9.81, 0.0]).is_ok());
        assert!(check_gravity([0.0, -9810.0, 0.0])
            .unwrap_err()
            .contains("mm/s²"));
        assert!(check_gravity([1e308, 1e308, 0.0])
            .unwrap_err()
            .contains("1.4142e308"));
        assert!(check_gravity([f64::NAN, 0.0, 0.0]).is_err());
        assert!(check_density(47.0).is_ok());
        assert!(check_density(0.0).is_err());
        assert!(check_density(-47.0).is_err());
        assert!(check_density(1e6).is_err());
        assert!(check_weights(&["a", "b"], &[1.0, 0.0]).is_ok());
        assert!(check_weights(&["a", "b"], &[-1.0, 1.0]).is_err());
        assert!(check_weights(&["a"], &[0.0]).is_err());
    }
}
