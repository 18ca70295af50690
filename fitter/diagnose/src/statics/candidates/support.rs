//! Elastic foundation (Winkler support): the supported face — the boundary triangles on the
//! declared fixed nodes — rests on springs instead of being held, k_n = E / ℓ_n along the face's
//! normal and k_t = k_n e^{θ₁} in its plane, with ℓ_n = h e^{θ₀} an equivalent thickness (h the
//! half width, E the fitted modulus, so the support scales with the body). Unlike
//! [`super::boundary`]'s rigid motion of the base, the base deforms with the load under it (an
//! object on a soft mat, a base glued to a compliant plate). 2 params (θ₀, θ₁, dimensionless);
//! the fixed support is its stiff limit θ₀ → −∞. Solved on [`Context::foundation`]'s problem;
//! the rig, not the object: not in the runtime model.

use palpate_fem::forward::{Foundation, Material};

use super::{ParamName, StaticEffect};
use crate::statics::context::Context;
use crate::statics::signature::{EvidencePoints, Residual};

/// The starting equivalent thickness ℓ_n / h.
const SUPPORT_START: f64 = 0.1;

/// See the module.
pub struct Support;

impl StaticEffect for Support {
    fn name(&self) -> &'static str {
        "support"
    }

    fn params(&self, _grid: [usize; 3]) -> usize {
        2
    }

    /// The fixed support is the limit ℓ_n → 0, where the effect's gradient vanishes too: start
    /// where a support would add a tenth of the body's compliance, ℓ_n = 0.1 h, k_t = k_n.
    fn start(&self, _grid: [usize; 3]) -> Vec<f64> {
        vec![SUPPORT_START.ln(), 0.0]
    }

    /// An elastic foundation needs a supported face (boundary triangles on fixed nodes).
    fn available(&self, ctx: &Context) -> bool {
        ctx.foundation.is_some()
    }

    fn param_names(&self, _grid: [usize; 3]) -> Vec<ParamName> {
        vec![
            (
                "foundation ln(ℓ_n/h) (k_n = E/ℓ_n, h the half width)".into(),
                "",
                1.0,
            ),
            ("foundation ln(k_t/k_n)".into(), "", 1.0),
        ]
    }

    fn evidence(&self, r: &Residual) -> EvidencePoints {
        r.rigid_translation_against_force()
    }

    /// The fixed support is the foundation's limit ℓ_n → 0, not a point of its θ, and its
    /// response vanishes there: no finite column states its power.
    fn power_start(&self, _grid: [usize; 3]) -> Option<Vec<f64>> {
        None
    }

    fn material(&self, ctx: &Context, theta: &[f64], b: &[f64], m: &mut Material) {
        // k_n = E / ℓ_n with ℓ_n = h e^{θ₀}; the exponents clamped so that a wandering
        // optimiser trial stays finite (e^{±30}: far beyond any support a dataset can show).
        let normal = theta[0].exp() / (ctx.frame.half * b[0].clamp(-30.0, 30.0).exp());
        m.foundation = Some(Foundation {
            normal,
            tangential: normal * b[1].clamp(-30.0, 30.0).exp(),
        });
    }

    fn on_foundation(&self) -> bool {
        true
    }
}
