//! Levenberg–Marquardt (the shared [`palpate_fem::lm::minimise`]) on the augmented model with a forward-difference Jacobian (the models
//! have at most a few dozen parameters, so k + 1 warm-started solves per measurement per
//! iteration is cheap on a small mesh), and the Gauss–Newton covariance s² (JᵀJ)⁻¹ for the
//! parameter uncertainties.

use nalgebra::DMatrix;
use palpate_fem::lm::{minimise, LmOptions};
use rayon::prelude::*;

use super::model::{s_of, Context, Model, Simulated};
use super::DiagnoseError;

/// Forward-difference step on the dimensionless θ. The fixed-point tolerance is 1e-10 m, so the
/// solver noise in a residual column is ≈ 1e-10 / (σ h) ≈ 1e-2 (for σ = 100 µm) against columns of
/// order u/σ ≈ 10–100: negligible; the truncation error is O(h) relative.
pub(super) const FD_STEP: f64 = 1e-4;

/// A fitted model.
#[derive(Debug, Clone)]
pub struct Fitted {
    /// The model.
    pub model: Model,
    /// Parameters (dimensionless, see [`super::model`]).
    pub theta: Vec<f64>,
    /// χ² = Σ ((simulated − measured)/σ)².
    pub chi2: f64,
    /// Number of residual entries.
    pub n: usize,
    /// Standard deviation of each θ from the Gauss–Newton covariance s² (JᵀJ)⁻¹ with
    /// s² = max(1, χ²/(n − k)) (inflated when the residual exceeds the declared noise).
    pub theta_sd: Vec<f64>,
    /// Correlations of θ from the same covariance, row-major k × k (NaN where JᵀJ is singular):
    /// a pair near ±1 is determined only in combination (the report lists such pairs).
    pub theta_corr: Vec<f64>,
    /// LM iterations.
    pub iterations: usize,
    /// The simulation at θ.
    pub sim: Simulated,
    /// Measurements fitted.
    pub subset: Vec<usize>,
}

/// How far (in noise standard deviations) the measured displacements may point against the
/// simulated ones — their projection on the unit simulated pattern — before the data are called
/// reversed: pure noise projects as N(0, σ²).
const REVERSED_Z: f64 = 3.0;

/// Starting θ for the base model: E from the best displacement scale of a 10 kPa solve.
///
/// The same projection tells a reversed force convention from a stiffness: every linear model
/// moves the markers along its loads, so measured displacements that project significantly
/// *against* a solve of the reported forces are not a stiff object but forces that point the
/// other way (a pull where palpate reads a push). That is refused, naming the measurements; one
/// measurement that does so while the others agree is a warning naming it (its force row).
pub fn initial_theta(
    ctx: &Context,
    subset: &[usize],
) -> Result<(Vec<f64>, Simulated), DiagnoseError> {
    let model = Model::base();
    let e0: f64 = 1e4;
    let theta = vec![e0.ln(), s_of(0.3)];
    let sim = model.simulate(ctx, &theta, subset, None)?;
    let per: Vec<(f64, f64)> = subset
        .iter()
        .zip(&sim.markers)
        .map(|(&i, ms)| {
            let mut sums = (0.0, 0.0);
            ctx.add_scale_terms(i, ms, &mut sums);
            sums
        })
        .collect();
    // z of measured-on-simulated: the projection ⟨u_meas, u_sim⟩/‖u_sim‖ over σ.
    let z = |(num, den): (f64, f64)| {
        if den > 0.0 {
            num / (den.sqrt() * ctx.sigma)
        } else {
            0.0
        }
    };
    let against: Vec<&str> = subset
        .iter()
        .zip(&per)
        .filter(|(_, &s)| z(s) < -REVERSED_Z)
        .map(|(&i, _)| ctx.meas[i].id.as_str())
        .collect();
    let (num, den) = per
        .iter()
        .fold((0.0, 0.0), |(a, b), &(n, d)| (a + n, b + d));
    if z((num, den)) < -REVERSED_Z {
        return Err(DiagnoseError::Input(format!(
            "the measured marker displacements point against the reported forces: projected on \
             a linear solve of those forces they move the other way, {:.1} noise standard \
             deviations over all measurements (in {} of {}: {}). palpate reads fx,fy,fz in \
             contacts.csv as the force the probe applies to the object (into it at a push); \
             check their sign convention",
            -z((num, den)),
            against.len(),
            subset.len(),
            against.join(", ")
        )));
    }
    for id in &against {
        log::warn!(
            "measurement {id:?}: its markers move against its reported force (projected on a \
             linear solve of that force, more than {REVERSED_Z} noise standard deviations the \
             other way) while the other measurements move with theirs — check its row in \
             contacts.csv (the force's sign or its measurement id)"
        );
    }
    let a = if num > 0.0 && den > 0.0 {
        num / den
    } else {
        1.0
    };
    Ok((vec![(e0 / a).ln(), s_of(0.3)], sim))
}

/// Forward-difference columns ∂r/∂θ_j for the parameters `cols` (in that order), with step
/// `step` on the dimensionless θ, from the simulation `base` at θ with residual `r0`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn jacobian_columns(
    ctx: &Context,
    model: &Model,
    theta: &[f64],
    subset: &[usize],
    base: &Simulated,
    r0: &[f64],
    cols: &[usize],
    step: f64,
) -> Result<DMatrix<f64>, DiagnoseError> {
    // The columns are independent solves: one per core (the diagnosis spends most of its time
    // here).
    let columns: Vec<Vec<f64>> = cols
        .par_iter()
        .map(|&c| {
            let mut t = theta.to_vec();
            t[c] += step;
            let markers = if model.affects_solve(c, ctx.grid) {
                model.simulate_near(ctx, &t, subset, base)?.markers
            } else {
                model.markers_from(
                    ctx,
                    &t,
                    subset,
                    &base.x,
                    base.embedding.as_deref(),
                    base.tilt.as_deref(),
                )
            };
            let r = model.residuals(ctx, subset, &markers);
            Ok(r.iter().zip(r0).map(|(a, b)| (a - b) / step).collect())
        })
        .collect::<Result<_, DiagnoseError>>()?;
    let mut j = DMatrix::zeros(r0.len(), cols.len());
    for (c, col) in columns.iter().enumerate() {
        j.column_mut(c).copy_from_slice(col);
    }
    Ok(j)
}

/// Where a fit stops: after `max_iterations`, or when an accepted step lowers χ² by less than
/// `rel_tolerance` of the larger of χ² and `chi2_floor`.
#[derive(Debug, Clone, Copy)]
pub struct Stop {
    /// Levenberg–Marquardt iterations at most.
    pub max_iterations: usize,
    /// The relative gain of a step below which the fit has converged.
    pub rel_tolerance: f64,
    /// The χ² the gain is measured against when χ² is below it (data a model holds exactly drive
    /// χ² toward zero, where every step gains much of what is left).
    pub chi2_floor: f64,
}

impl Stop {
    /// The diagnosis' fits: to 10⁻⁷ of χ².
    pub fn after(max_iterations: usize) -> Self {
        Stop {
            max_iterations,
            rel_tolerance: 1e-7,
            chi2_floor: 1e-300,
        }
    }
}

/// Fits `model` to the measurements `subset` from `theta0` (warm-started from `warm`).
pub fn fit(
    ctx: &Context,
    model: &Model,
    theta0: Vec<f64>,
    subset: &[usize],
    warm: Option<&[Vec<[f64; 3]>]>,
    max_iterations: usize,
) -> Result<Fitted, DiagnoseError> {
    fit_until(
        ctx,
        model,
        theta0,
        subset,
        warm,
        Stop::after(max_iterations),
    )
}

/// [`fit`], stopping where `stop` says.
pub fn fit_until(
    ctx: &Context,
    model: &Model,
    theta0: Vec<f64>,
    subset: &[usize],
    warm: Option<&[Vec<[f64; 3]>]>,
    stop: Stop,
) -> Result<Fitted, DiagnoseError> {
    let sim = model.simulate(ctx, &theta0, subset, warm)?;
    fit_from(ctx, model, theta0, subset, sim, stop)
}

/// [`fit_until`] from `sim`, the simulation of `model` at `theta0` on `ctx` already made.
pub fn fit_from(
    ctx: &Context,
    model: &Model,
    theta0: Vec<f64>,
    subset: &[usize],
    sim: Simulated,
    stop: Stop,
) -> Result<Fitted, DiagnoseError> {
    let r = model.residuals(ctx, subset, &sim.markers);
    let o = LmOptions {
        max_iterations: stop.max_iterations,
        tries: 10,
        initial_damping: 1e-3,
        min_damping: 1e-9,
        reject_factor: 4.0,
        rel_tolerance: stop.rel_tolerance,
        cost_floor: stop.chi2_floor,
    };
    let out = minimise(
        theta0,
        r,
        sim,
        // Every column, at the default step.
        |theta, sim: &Simulated, r| {
            let all: Vec<usize> = (0..theta.len()).collect();
            jacobian_columns(ctx, model, theta, subset, sim, r, &all, FD_STEP)
        },
        |trial, sim| {
            let s = model.simulate_near(ctx, trial, subset, sim).ok()?;
            Some((model.residuals(ctx, subset, &s.markers), s))
        },
        &o,
    )?;
    Ok(finish(
        ctx,
        model,
        out.theta,
        out.cost,
        &out.jtj,
        out.iterations,
        out.state,
        subset,
    ))
}

#[allow(clippy::too_many_arguments)]
fn finish(
    ctx: &Context,
    model: &Model,
    theta: Vec<f64>,
    c2: f64,
    h: &DMatrix<f64>,
    iterations: usize,
    sim: Simulated,
    subset: &[usize],
) -> Fitted {
    let n = ctx.residual_len(subset);
    let k = theta.len();
    let s2 = (c2 / (n.saturating_sub(k).max(1)) as f64).max(1.0);
    let inverse = h.clone().try_inverse().filter(|_| h.nrows() == k);
    let theta_sd = match &inverse {
        Some(inv) => (0..k).map(|d| (s2 * inv[(d, d)].max(0.0)).sqrt()).collect(),
        None => vec![f64::NAN; k],
    };
    let theta_corr = if h.nrows() == k {
        correlations(h)
    } else {
        vec![f64::NAN; k * k]
    };
    Fitted {
        model: model.clone(),
        theta,
        chi2: c2,
        n,
        theta_sd,
        theta_corr,
        iterations,
        sim,
        subset: subset.to_vec(),
    }
}

/// The correlations of the Gauss–Newton covariance (JᵀJ)⁻¹ (s² cancels), row-major. A singular
/// JᵀJ — parameters these data cannot tell apart at all — is inverted with a ridge of 10⁻¹⁰ of
/// its mean diagonal, which leaves the determined directions as they are and gives the
/// undetermined ones correlations of ±1: a degeneracy is then reported, not hidden behind NaN.
pub(crate) fn correlations(h: &DMatrix<f64>) -> Vec<f64> {
    let k = h.nrows();
    let inverse = h.clone().try_inverse().or_else(|| {
        let ridge = 1e-10 * h.trace().abs().max(f64::MIN_POSITIVE) / k.max(1) as f64;
        (h + DMatrix::identity(k, k) * ridge).try_inverse()
    });
    let Some(inv) = inverse else {
        return vec![f64::NAN; k * k];
    };
    (0..k * k)
        .map(|ij| {
            let (i, j) = (ij / k, ij % k);
            let d = (inv[(i, i)] * inv[(j, j)]).max(0.0).sqrt();
            if d > 0.0 {
                inv[(i, j)] / d
            } else {
                f64::NAN
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// JᵀJ of a Jacobian with columns `cols` (each of the same length).
    fn normal(cols: &[&[f64]]) -> DMatrix<f64> {
        let n = cols[0].len();
        let j = DMatrix::from_fn(n, cols.len(), |r, c| cols[c][r]);
        j.transpose() * j
    }

    #[test]
    fn correlations_follow_the_covariance() {
        // Orthogonal columns: uncorrelated parameters.
        let c = correlations(&normal(&[&[1.0, 0.0, 1.0], &[0.0, 2.0, 0.0]]));
        assert_eq!(c.len(), 4);
        assert!((c[0] - 1.0).abs() < 1e-12 && (c[3] - 1.0).abs() < 1e-12);
        assert!(c[1].abs() < 1e-12 && c[2].abs() < 1e-12);
        // Two columns that nearly coincide: the covariance of (a, b) is that of a sum known and a
        // difference unknown, so the correlation tends to −1 — computed by hand for
        // J = [1 1; 1 1+ε]: (JᵀJ)⁻¹ ∝ [2+2ε+ε², −(2+ε); −(2+ε), 2], r = −(2+ε)/√(2(2+2ε+ε²)).
        let e = 0.01;
        let c = correlations(&normal(&[&[1.0, 1.0], &[1.0, 1.0 + e]]));
        let want = -(2.0 + e) / (2.0 * (2.0 + 2.0 * e + e * e)).sqrt();
        assert!((c[1] - want).abs() < 1e-9, "{} vs {want}", c[1]);
        // Columns exactly proportional (a gain and a stiffness in a linear model): singular JᵀJ,
        // reported as a correlation of −1, not hidden as NaN.
        let c = correlations(&normal(&[&[1.0, 2.0, 3.0], &[-2.0, -4.0, -6.0]]));
        assert!(c[1] > 0.999, "{c:?}");
        let c = correlations(&normal(&[
            &[1.0, 2.0, 3.0],
            &[2.0, 4.0, 6.0],
            &[0.0, 1.0, 0.0],
        ]));
        assert!(c[1] < -0.999 && c[2].abs() < 0.5, "{c:?}");
    }
}
