//! Compliant support, rigid: the fixed face moves rigidly by c_t F (translation, c_t in
//! 1e-4 m/N) and rotates by c_r (r × F) / h² (c_r in 1e-4 rad m/N·m, r the contact point's arm
//! about the fixed nodes' centroid, h the half width). 2 params. It acts on the solved markers
//! only; the rig, not the object: not in the runtime model.

use nalgebra::Vector3;

use super::{ParamName, StaticEffect};
use crate::statics::context::{Context, MeasData};
use crate::statics::signature::{EvidencePoints, Residual};

/// See the module.
pub struct Boundary;

impl StaticEffect for Boundary {
    fn name(&self) -> &'static str {
        "boundary"
    }

    fn params(&self, _grid: [usize; 3]) -> usize {
        2
    }

    fn affects_solve(&self) -> bool {
        false
    }

    fn param_names(&self, _grid: [usize; 3]) -> Vec<ParamName> {
        vec![
            ("support compliance c_t".into(), "m/N", 1e-4),
            ("support rotation c_r".into(), "m/N", 1e-4),
        ]
    }

    /// A support that gives way moves the whole body nearly rigidly, in proportion to the force.
    fn evidence(&self, r: &Residual) -> EvidencePoints {
        r.rigid_translation_against_force()
    }

    fn move_marker(
        &self,
        ctx: &Context,
        b: &[f64],
        m: &MeasData,
        force: [f64; 3],
        p: [f64; 3],
    ) -> [f64; 3] {
        let t = force.map(|v| v * b[0] * 1e-4);
        let arm = [0, 1, 2].map(|d| m.point[d] - ctx.frame.base[d]);
        let w = <[f64; 3]>::from(Vector3::from(arm).cross(&Vector3::from(force)))
            .map(|v| v * b[1] * 1e-4 / (ctx.frame.half * ctx.frame.half));
        let r = [0, 1, 2].map(|d| p[d] - ctx.frame.base[d]);
        let wr = Vector3::from(w).cross(&Vector3::from(r));
        [0, 1, 2].map(|d| p[d] + t[d] + wr[d])
    }
}
