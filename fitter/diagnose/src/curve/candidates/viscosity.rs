//! One more viscous branch: Fung's quasi-linear viscoelasticity, a generalised Maxwell model on
//! the elastic response, P(t) = P_e(λ(t)) + Σ_i h_i(t) with ḣ_i = −h_i/τ_i + β_i dP_e/dt,
//! integrated exactly for P_e piecewise linear in time: h_i(t_k) = e^{−Δt/τ_i} h_i(t_{k−1}) +
//! β_i e^{−Δt/(2τ_i)} (P_e(t_k) − P_e(t_{k−1})). One model gives loading, unloading, every rate
//! and relaxation at constant displacement; P_e is the long-term (equilibrium) response, the
//! instantaneous one (1 + Σβ_i) P_e.
//!
//! Each branch frees β_i (1) and τ_i (s), both fitted in logarithms; at most three branches, and
//! only on a record that can tell viscosity from elasticity (unloading, a hold, or several
//! rates). Hysteresis (loading vs unloading), rate dependence and relaxation during holds point
//! to it.

use super::{CurveEffect, Values};
use crate::curve::model::{Model, Param};
use crate::curve::read::Group;
use crate::curve::signature::Variable;

/// See the module.
pub struct Viscosity;

impl CurveEffect for Viscosity {
    fn name(&self) -> String {
        "viscosity".into()
    }

    fn words(&self) -> &'static str {
        "viscosity (hysteresis, rate dependence, relaxation)"
    }

    fn available(&self, m: &Model, _groups: usize, rate_info: bool) -> bool {
        m.family.mechanical() && m.branches < 3 && rate_info
    }

    fn add_to(&self, m: &mut Model) {
        m.branches += 1;
    }

    fn describe(&self, m: &Model) -> Option<String> {
        (m.branches > 0).then(|| {
            format!(
                "{} viscous branch{}",
                m.branches,
                if m.branches > 1 { "es" } else { "" }
            )
        })
    }

    fn params(&self, m: &Model, out: &mut Vec<Param>) {
        for i in 0..m.branches {
            // Spread the start time constants over the record: τ = duration/300, /30, /3.
            let tau = m.scale.duration.max(1e-6) * 10f64.powi(i as i32) / 300.0;
            out.push(Param::new(&format!("beta{}", i + 1), "1", true, false, 0.5));
            out.push(Param::new(&format!("tau{}", i + 1), "s", true, false, tau));
        }
    }

    fn alternatives(&self, p: &Param, m: &Model) -> Option<Vec<f64>> {
        let d = m.scale.duration.max(1e-6);
        p.name
            .starts_with("tau")
            .then(|| vec![d / 300.0, d / 30.0, d / 3.0])
    }

    fn evidence(&self) -> &'static [Variable] {
        &[Variable::Direction, Variable::Rate, Variable::HoldTime]
    }

    fn viscous(
        &self,
        m: &Model,
        val: &Values<'_>,
        g: &Group,
        pe: &[f64],
        out: &mut [f64],
    ) -> Option<()> {
        for i in 0..m.branches {
            let beta = val(&format!("beta{}", i + 1))?;
            let tau = val(&format!("tau{}", i + 1))?;
            let mut h = 0.0;
            for k in 1..pe.len() {
                let dt = (g.t[k] - g.t[k - 1]).max(0.0);
                h = (-dt / tau).exp() * h + beta * (-dt / (2.0 * tau)).exp() * (pe[k] - pe[k - 1]);
                out[k] += h;
            }
        }
        Some(())
    }
}
