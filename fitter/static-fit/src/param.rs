//! The physical parameterisation of the displacement-based fit: every (λ, α) pair is written as
//! q = (log E, s) with ν = −1/4 + 3/4 · tanh(s), so any real q gives E > 0 and −1 < ν < 1/2 and the
//! optimiser can never leave the physical range. λ = E/((1+ν)(1−2ν)) and α = λν (eqs. 3.36–3.42).
//! Smoothness (L_s, L_m) acts on q: differences of log E (relative stiffness jumps) and of s.

use palpate_runtime::material::LambdaAlpha;

/// q = (log E, s) of a physical (λ, α).
pub fn to_q(p: LambdaAlpha) -> [f64; 2] {
    let nu = p.poisson().clamp(-0.999_999, 0.499_999);
    let e = p.young().max(1e-300);
    [e.ln(), ((nu + 0.25) / 0.75).atanh()]
}

/// (λ, α) and the Jacobian [[∂λ/∂q0, ∂λ/∂q1], [∂α/∂q0, ∂α/∂q1]] at q.
pub fn from_q(q: [f64; 2]) -> (LambdaAlpha, [[f64; 2]; 2]) {
    let e = q[0].exp();
    let th = q[1].tanh();
    let nu = -0.25 + 0.75 * th;
    let dnu = 0.75 * (1.0 - th * th);
    let den = (1.0 + nu) * (1.0 - 2.0 * nu);
    let lambda = e / den;
    let alpha = lambda * nu;
    // dλ/dν = E (1 + 4ν) / ((1+ν)(1−2ν))²
    let dl_dnu = e * (1.0 + 4.0 * nu) / (den * den);
    let da_dnu = dl_dnu * nu + lambda;
    (
        LambdaAlpha { lambda, alpha },
        [[lambda, dl_dnu * dnu], [alpha, da_dnu * dnu]],
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_derivatives_match_finite_differences() {
        for &(e, nu) in &[(1e4, 0.3), (5e5, -0.5), (30.0, 0.49), (2e3, 0.0)] {
            let q = to_q(LambdaAlpha::from_young_poisson(e, nu));
            let (p, jac) = from_q(q);
            assert!((p.young() / e - 1.0).abs() < 1e-9 && (p.poisson() - nu).abs() < 1e-9);
            for k in 0..2 {
                let h = 1e-6;
                let mut qp = q;
                let mut qm = q;
                qp[k] += h;
                qm[k] -= h;
                let (a, b) = (from_q(qp).0, from_q(qm).0);
                let dl = (a.lambda - b.lambda) / (2.0 * h);
                let da = (a.alpha - b.alpha) / (2.0 * h);
                // Central differences: error O(h²) ≈ 1e-12 relative, well inside 1e-6.
                assert!(
                    (dl - jac[0][k]).abs() <= 1e-6 * (jac[0][k].abs() + p.lambda),
                    "dλ/dq{k}"
                );
                assert!(
                    (da - jac[1][k]).abs() <= 1e-6 * (jac[1][k].abs() + p.lambda),
                    "dα/dq{k}"
                );
            }
        }
    }
}
