//! An unreported tangential force that differs from measurement to measurement (friction at the
//! tip, a probe held at another tilt each time): f = f_reported + |f|(a_i t₁ + b_i t₂), t₁, t₂
//! [`Context::tangents`]. Profiled, not in θ: each measurement's marker response to the two
//! tangential directions ([`TiltEach::responses`]: two more solves, warm-started) and the
//! (a_i, b_i) of least squares in closed form ([`TiltEach::profile`]). 2 parameters per
//! measurement (dimensionless), counted by BIC and the held-out gate. The probe, not the object:
//! not in the runtime model.

use std::sync::Arc;

use nalgebra::Vector3;
use palpate_fem::dataset::Marker;
use palpate_fem::forward::Factorised;
use rayon::prelude::*;

use super::{At, PowerPoint, ProfiledKind, ResponseStates, Responses, ResponsesNear, StaticEffect};
use crate::statics::context::Context;
use crate::statics::power::row_offsets;
use crate::statics::signature::{EvidencePoints, Residual};
use crate::statics::DiagnoseError;

/// The tangential coefficient of the probing solves: a tilt of ≈ 6°, small enough for the warped
/// response to stay linear in it, large enough to stand above round-off.
pub const TILT_PROBE: f64 = 0.1;

/// See the module.
pub struct TiltEach;

impl StaticEffect for TiltEach {
    fn name(&self) -> &'static str {
        "tilt-each"
    }

    fn profiled(&self, measurements: usize) -> usize {
        2 * measurements
    }

    fn evidence(&self, r: &Residual) -> EvidencePoints {
        r.horizontal_mean_against_force()
    }

    /// Its columns are the probing solves' responses (two more solves per measurement, made only
    /// for the statement).
    fn profiled_columns(&self, p: &PowerPoint) -> Option<Result<Vec<ProfiledKind>, DiagnoseError>> {
        let tilt =
            p.at.model
                .tilt_responses(p.at.ctx, p.at.theta, p.subset, p.sim);
        Some(tilt.map(|tilt| {
            vec![(
                "tangential coefficient per direction",
                "",
                response_columns(p.at.ctx, p.subset, &tilt),
            )]
        }))
    }

    fn responses(
        &self,
        at: At,
        subset: &[usize],
        sim: (&[Vec<[f64; 3]>], &[Arc<Factorised>], Option<&[Marker]>),
        near: Option<ResponsesNear>,
    ) -> Option<Result<(Responses, ResponseStates), DiagnoseError>> {
        Some(responses(at, subset, sim, near))
    }

    fn profile(
        &self,
        ctx: &Context,
        i: usize,
        sim: Vec<[f64; 3]>,
        responses: Option<&[Vec<[f64; 3]>; 2]>,
    ) -> Vec<[f64; 3]> {
        match responses {
            Some(cols) => tilt_each(ctx, i, sim, cols),
            None => sim,
        }
    }
}

/// The marker responses: for each measurement, two more solves with the force tilted by
/// [`TILT_PROBE`]·|f| along t₁ and t₂ (from the factorisation of K' that measurement's own
/// solve ended with: the tilted load changes the rotations by a tenth of the load's, so the
/// kept factor serves and no new factorisation is made), their markers minus the untilted ones,
/// per unit coefficient, and the tilted states. Measurements in parallel.
///
/// Each tilted solve starts from `xs` moved by the tilt's displacement at `near` (a Jacobian
/// column's or a trial's base simulation), x + (x_t − x)_near, which is within the parameter
/// step of its fixed point; without `near` it starts from `xs`, a tenth of the load away. The
/// fixed point is the same either way (the solve's tolerance, 10⁻⁹ m, is what separates them).
pub(in crate::statics) fn responses(
    at: At,
    subset: &[usize],
    (xs, factors, embedding): (&[Vec<[f64; 3]>], &[Arc<Factorised>], Option<&[Marker]>),
    near: Option<ResponsesNear>,
) -> Result<(Responses, ResponseStates), DiagnoseError> {
    let (ctx, model, theta) = (at.ctx, at.model, at.theta);
    let mat = model.material(ctx, theta, at.log_e, None)?;
    subset
        .par_iter()
        .zip(xs)
        .enumerate()
        .map(|(k, (&i, x))| {
            let m = &ctx.meas[i];
            let f = model.model_force(ctx, theta, i);
            let fm = Vector3::from(m.force).norm();
            let base = model.physical_markers(ctx, theta, i, x, embedding);
            let mut cols: [Vec<[f64; 3]>; 2] = [Vec::new(), Vec::new()];
            let mut states: [Vec<[f64; 3]>; 2] = [Vec::new(), Vec::new()];
            for (j, t) in ctx.tangents.iter().enumerate() {
                if fm == 0.0 {
                    cols[j] = vec![[0.0; 3]; base.len()];
                    states[j] = x.clone();
                    continue;
                }
                let ft = [0, 1, 2].map(|d| f[d] + TILT_PROBE * fm * t[d]);
                let fvec = model.full_load(ctx, theta, i, ft)?;
                let moved: Option<Vec<[f64; 3]>> = match near {
                    Some((x_near, tilted_near))
                        if x_near.get(k).is_some_and(|v| v.len() == x.len())
                            && tilted_near.get(k).is_some_and(|v| v[j].len() == x.len()) =>
                    {
                        Some(
                            x.iter()
                                .zip(&x_near[k])
                                .zip(&tilted_near[k][j])
                                .map(|((p, q), r)| [0, 1, 2].map(|d| p[d] + (r[d] - q[d])))
                                .collect(),
                        )
                    }
                    _ => None,
                };
                let start = moved.as_deref().unwrap_or(x);
                let xt = model
                    .problem(ctx)
                    .solve_forces_with(&mat, &fvec, Some(start), &ctx.solve, factors.get(k))?
                    .solution
                    .x;
                let tilted = model.physical_markers(ctx, theta, i, &xt, embedding);
                cols[j] = tilted
                    .iter()
                    .zip(&base)
                    .map(|(a, b)| [0, 1, 2].map(|d| (a[d] - b[d]) / TILT_PROBE))
                    .collect();
                states[j] = xt;
            }
            Ok((cols, states))
        })
        .collect::<Result<Vec<_>, DiagnoseError>>()
        .map(|v| v.into_iter().unzip())
}

/// The profile on measurement `i`: the coefficients (a, b) of the responses `cols` that best
/// explain the measured markers' misfit (2 × 2 normal equations), added to `sim`.
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

/// The residual columns (units of σ, in [`Model::residuals`]'s order) of the responses: per
/// measurement and tangent direction, its markers' response to a unit tangential coefficient
/// (× |f|).
///
/// [`Model::residuals`]: crate::statics::model::Model::residuals
fn response_columns(ctx: &Context, subset: &[usize], tilt: &[[Vec<[f64; 3]>; 2]]) -> Vec<Vec<f64>> {
    let (offset, n) = row_offsets(ctx, subset);
    let mut out = Vec::with_capacity(2 * subset.len());
    for (a, responses) in tilt.iter().enumerate() {
        for resp in responses {
            let mut col = vec![0.0; n];
            for (j, p) in resp.iter().enumerate() {
                for d in 0..3 {
                    col[offset[a] + 3 * j + d] = p[d] / ctx.sigma;
                }
            }
            out.push(col);
        }
    }
    out
}
