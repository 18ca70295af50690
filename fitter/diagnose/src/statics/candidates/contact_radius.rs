//! The probe's contact patch is not the declared disc: the force is a uniform pressure over the
//! rest surface within radius r = s · r_declared (ln s in θ; the change from the declared patch
//! integrated consistently, [`palpate_runtime::contact_rule::contact_weights_consistent`]). A
//! soft object wraps around a rounded probe (the patch of a sphere grows with the indentation),
//! and on a coarse mesh the lumped rule puts the whole force on the one or two nodes within a
//! small radius: either leaves a residual concentrated within a probe radius or two of the
//! contact. 1 param (ln s), the model without it at ln s = 0
//! ([`crate::statics::model::Model::load_vector`]: the lumped load plus the change the wider or
//! narrower patch makes).
//!
//! Why a difference f_cons(s·r) − f_cons(r) rather than f_cons(s·r) alone: the
//! approximation-error correction δ is the refined mesh's answer minus the dataset mesh's under
//! the lumped rule, and on a coarse mesh much of δ near the probe *is* the lumping (one or two
//! nodes within a small radius carry the whole force). The refined mesh's lumped and consistent
//! loads agree, so the lumped rule plus δ already stands for the refined, consistent answer at
//! s = 1; replacing the lumped load by f_cons(s·r) under that δ would count the lumping error
//! twice (measured on an independent draw: the candidate gained 2 µm of 31 µm in excess of the
//! floor). The difference is continuous in s (its Jacobian column is a finite difference like
//! any other's) and nests the model without it exactly at ln s = 0.

use palpate_fem::forward::StaticProblem;

use super::{ParamName, StaticEffect};
use crate::statics::context::MeasData;
use crate::statics::signature::{EvidencePoints, Residual};
use crate::statics::DiagnoseError;

/// See the module.
pub struct ContactRadius;

impl StaticEffect for ContactRadius {
    fn name(&self) -> &'static str {
        "contact-radius"
    }

    fn params(&self, _grid: [usize; 3]) -> usize {
        1
    }

    fn param_names(&self, _grid: [usize; 3]) -> Vec<ParamName> {
        vec![("contact radius ln s (r = s r_declared)".into(), "", 1.0)]
    }

    /// A contact patch of another size: the marker error against distance from the contact
    /// shows it concentrated within a probe radius or two.
    fn evidence(&self, r: &Residual) -> EvidencePoints {
        r.error_against_distance()
    }

    fn load_change(
        &self,
        p: &StaticProblem,
        m: &MeasData,
        b: &[f64],
        force: [f64; 3],
        f: &mut [f64],
    ) -> Result<(), DiagnoseError> {
        if b[0] == 0.0 {
            return Ok(());
        }
        for (radius, sign) in [(m.radius * b[0].exp(), 1.0), (m.radius, -1.0)] {
            palpate_runtime::contact_rule::contact_weights_consistent(
                m.point,
                radius,
                p.x0.len(),
                |n| p.x0[n],
                p.surface.len(),
                |t| p.surface[t],
                |n| p.fixed[n],
                |n, w| {
                    for d in 0..3 {
                        f[3 * n + d] += sign * w * force[d];
                    }
                },
            )
            .map_err(|e| {
                DiagnoseError::Input(format!(
                    "measurement {:?}: contact-radius: no free surface within {radius:.3e} m of the contact point ({e:?})",
                    m.id
                ))
            })?;
        }
        Ok(())
    }
}
