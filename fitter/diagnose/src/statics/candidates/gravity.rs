//! Gravity preload: body force ρ g (ρ in 1000 kg/m³, g the declared gravity or 9.81 m/s² along
//! −z, [`Frame::gravity`](crate::statics::context::Frame::gravity)) acting in every measurement, with the rest scan taken under it
//! ([`Gravity::marker_embedding`]). 1 param. The rest scan's state, not the object: not in the
//! runtime model.

use palpate_fem::dataset::Marker;

use super::{At, ParamName, StaticEffect};
use crate::statics::context::Context;
use crate::statics::signature::{EvidencePoints, Residual};
use crate::statics::DiagnoseError;

/// See the module.
pub struct Gravity;

/// Adds the lumped body force ρ V_n g (ρ in 1000 kg/m³) to `fvec`.
fn add_gravity(ctx: &Context, rho: f64, fvec: &mut [f64]) {
    let rho = rho * 1000.0;
    for (n, v) in ctx.frame.node_volume.iter().enumerate() {
        for d in 0..3 {
            fvec[3 * n + d] += rho * v * ctx.frame.gravity[d];
        }
    }
}

impl StaticEffect for Gravity {
    fn name(&self) -> &'static str {
        "gravity"
    }

    fn params(&self, _grid: [usize; 3]) -> usize {
        1
    }

    fn param_names(&self, _grid: [usize; 3]) -> Vec<ParamName> {
        vec![("density ρ".into(), "kg/m³", 1000.0)]
    }

    /// The sag under the object's own weight scales with ρ g over E, the contacts' displacements
    /// with force over E: ρ is fixed through E, and is as relative as E is.
    fn relative_note(&self, _ctx: &Context) -> Option<String> {
        Some(
            "the density ρ is relative to E as the sag fixes it: the object's own weight \
             displaces it by ρ g over E, so ρ/E is determined and ρ moves with E (and with \
             whatever force gain E is relative to)"
                .into(),
        )
    }

    fn evidence(&self, r: &Residual) -> EvidencePoints {
        r.vertical_against_height()
    }

    /// The rest scan shares the preload, so the statement is about what the probe loads change
    /// of the sag, not the sag itself.
    fn power_note(&self) -> Option<&'static str> {
        Some("the rest scan taken under the same weight: only what the weight changes of the probes' displacements is seen")
    }

    fn body_force(&self, ctx: &Context, b: &[f64], fvec: &mut [f64]) {
        add_gravity(ctx, b[0], fvec);
    }

    /// Where the markers sit on the unloaded object when the rest scan was taken under gravity
    /// ("the rest scan was taken under gravity"). The dataset embeds each marker's scanned
    /// position at the nearest surface point; under a preload that scan is the sagged position,
    /// so on a side face the nearest point is a material point shifted by the sag, and the model
    /// would apply the sag twice. The material point X of marker k solves X + u_g(X) = rest_k
    /// with u_g the gravity-only displacement at θ: one fixed-point step from the dataset's
    /// embedding (u_g varies slowly over the surface; the sag is a fraction of an element),
    /// re-embedded there with X's own offset from the surface. (The sag is taken at the surface
    /// point, without the marker's offset: the dataset's offset of a scan under gravity *is* the
    /// sag's normal part, and carrying it beside u_g(X) applied that part twice — a signal no
    /// such data hold, which made the candidate's power statement claim ρ ≥ 65 kg/m³ on a
    /// specimen whose ρ = 1,000 kg/m³ was not there to be seen.)
    fn marker_embedding(&self, at: At, b: &[f64]) -> Option<Result<Vec<Marker>, DiagnoseError>> {
        Some(rest_scan_embedding(at, b[0]))
    }
}

/// [`Gravity::marker_embedding`] at density `rho` (1000 kg/m³).
fn rest_scan_embedding(at: At, rho: f64) -> Result<Vec<Marker>, DiagnoseError> {
    let ctx = at.ctx;
    let mut fvec = vec![0.0; 3 * ctx.frame.node_volume.len()];
    add_gravity(ctx, rho, &mut fvec);
    let mat = at.model.material(ctx, at.theta, at.log_e, None)?;
    let xg = at
        .model
        .problem(ctx)
        .solve_forces(&mat, &fvec, None, &ctx.solve)?
        .solution
        .x;
    Ok(ctx
        .markers
        .iter()
        .map(|m| {
            let (sagged, unloaded) = (
                m.surface_point(|n| xg[n]),
                m.surface_point(|n| ctx.problem.x0[n]),
            );
            let q = [0, 1, 2].map(|d| m.rest[d] - (sagged[d] - unloaded[d]));
            match palpate_fem::dataset::embed::embed_point_in(
                &ctx.problem.x0,
                &ctx.problem.surface,
                q,
            ) {
                Some(e) => Marker::embedded(m.id.clone(), q, &e, &ctx.problem.x0),
                None => m.clone(),
            }
        })
        .collect())
}
