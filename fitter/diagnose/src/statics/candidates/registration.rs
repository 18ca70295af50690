//! Marker registration offset: one rigid transform (rotation vector ω in 1e-3 rad, translation t
//! in 1e-4 m) about the mesh centre on every simulated marker. 6 params. It acts on the solved
//! markers only; the tracker, not the object: not in the runtime model.

use palpate_fem::geometry::rotate;

use super::{ParamName, StaticEffect};
use crate::statics::context::{Context, MeasData};
use crate::statics::signature::{EvidencePoints, Residual};

/// See the module.
pub struct Registration;

impl StaticEffect for Registration {
    fn name(&self) -> &'static str {
        "registration"
    }

    fn params(&self, _grid: [usize; 3]) -> usize {
        6
    }

    fn affects_solve(&self) -> bool {
        false
    }

    fn param_names(&self, _grid: [usize; 3]) -> Vec<ParamName> {
        let v = |n: &str, u, s| (n.to_string(), u, s);
        vec![
            v("rotation ωx", "rad", 1e-3),
            v("rotation ωy", "rad", 1e-3),
            v("rotation ωz", "rad", 1e-3),
            v("translation tx", "m", 1e-4),
            v("translation ty", "m", 1e-4),
            v("translation tz", "m", 1e-4),
        ]
    }

    fn evidence(&self, r: &Residual) -> EvidencePoints {
        r.rigid_part_against_force()
    }

    fn move_marker(
        &self,
        ctx: &Context,
        b: &[f64],
        _m: &MeasData,
        _force: [f64; 3],
        p: [f64; 3],
    ) -> [f64; 3] {
        let w = [b[0], b[1], b[2]].map(|v| v * 1e-3);
        let r = rotate(w, [0, 1, 2].map(|d| p[d] - ctx.frame.centre[d]));
        [0, 1, 2].map(|d| ctx.frame.centre[d] + r[d] + b[3 + d] * 1e-4)
    }
}
