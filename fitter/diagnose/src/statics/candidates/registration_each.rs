//! A different registration offset in every measurement (the markers re-tracked, the object
//! re-seated between probes): each measurement's simulated markers are moved by the rigid
//! transform that best maps them onto its measured ones (Horn's closed form, weighted to the
//! markers the load barely moves: w = 1/(1 + (|u|/3σ)²) with u the simulated displacement).
//! Profiled, not in θ: 6 parameters per measurement (rotation in rad, translation in m), counted
//! by BIC and the held-out gate. The tracker, not the object: not in the runtime model.

use nalgebra::Vector3;

use super::{PowerPoint, ProfiledKind, StaticEffect};
use crate::statics::context::Context;
use crate::statics::power::measurement_columns;
use crate::statics::signature::{EvidencePoints, Residual};
use crate::statics::DiagnoseError;

/// See the module.
pub struct RegistrationEach;

impl StaticEffect for RegistrationEach {
    fn name(&self) -> &'static str {
        "registration-each"
    }

    fn profiled(&self, measurements: usize) -> usize {
        6 * measurements
    }

    fn affects_solve(&self) -> bool {
        false
    }

    fn evidence(&self, r: &Residual) -> EvidencePoints {
        r.rigid_part_against_force()
    }

    /// A translation column per measurement and axis, and a rotation column per measurement and
    /// axis (about its markers' centroid).
    fn profiled_columns(&self, p: &PowerPoint) -> Option<Result<Vec<ProfiledKind>, DiagnoseError>> {
        let (ctx, subset, sims) = (p.at.ctx, p.subset, &p.sim.markers);
        let mut t = Vec::new();
        let mut r = Vec::new();
        for axis in 0..3 {
            t.extend(measurement_columns(ctx, subset, sims, &|_, _, _| {
                let mut e = [0.0; 3];
                e[axis] = 1.0;
                e
            }));
            r.extend(measurement_columns(ctx, subset, sims, &|_, p, centre| {
                let v = [0, 1, 2].map(|d| p[d] - centre[d]);
                // e_axis × v
                match axis {
                    0 => [0.0, -v[2], v[1]],
                    1 => [v[2], 0.0, -v[0]],
                    _ => [-v[1], v[0], 0.0],
                }
            }));
        }
        Some(Ok(vec![
            ("translation per axis", "m", t),
            ("rotation per axis", "rad", r),
        ]))
    }

    /// `sim` moved by the weighted rigid transform that best maps it onto the measured markers
    /// (unchanged when that is degenerate).
    fn profile(
        &self,
        ctx: &Context,
        i: usize,
        sim: Vec<[f64; 3]>,
        _responses: Option<&[Vec<[f64; 3]>; 2]>,
    ) -> Vec<[f64; 3]> {
        let m = &ctx.meas[i];
        let measured: Vec<[f64; 3]> = m.observed.iter().map(|&(_, q)| q).collect();
        let scale = 3.0 * ctx.sigma;
        let w: Vec<f64> = m
            .observed
            .iter()
            .zip(&sim)
            .map(|(&(k, _), p)| {
                let u = (0..3)
                    .map(|d| (p[d] - ctx.marker_rest[k][d]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                1.0 / (1.0 + (u / scale).powi(2))
            })
            .collect();
        match palpate_capture::register::weighted_orientation(&sim, &measured, &w) {
            Some((r, t)) => sim
                .iter()
                .map(|p| {
                    let q = r * Vector3::from(*p) + t;
                    [q.x, q.y, q.z]
                })
                .collect(),
            None => sim,
        }
    }
}
