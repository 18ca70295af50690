//! The load-increment Newton solver shared by the quasi-static designs ([`super::statics`] on
//! linear tetrahedra, [`super::quadratic_statics`] on quadratic ones): the problem's checks, the
//! free-dof numbering, the external load applied in increments with Newton on the total potential
//! energy, and the parameter sensitivities of an equilibrium. A design supplies its energy, forces
//! and tangent ([`Discretised`]); everything else is the same for every element.

use super::hyperelastic::HyperParams;
use super::sparse::Pattern;
use super::statics::{StaticProblem, StaticSensitivity, StaticSolution};
use super::MotionError;

/// What a design of the quasi-static model computes on its own dofs (3 per node, node-major).
pub(crate) trait Discretised {
    /// Internal energy Σ ∫ Ψ(F) dV; `None` when an element (or a quadrature point) is inverted.
    fn energy(&self, x: &[f64]) -> Option<f64>;
    /// Internal forces (every dof) and, if asked, the tangent K = −∂f/∂x on the free pattern.
    fn forces(&self, x: &[f64], k: Option<(&Pattern, &mut [f64])>) -> Option<Vec<f64>>;
    /// ∂f/∂λ and ∂f/∂μ (every dof) of a uniform material.
    fn parameter_forces(&self, x: &[f64]) -> Option<[Vec<f64>; 2]>;
}

/// The free-dof numbering and pattern of a design.
#[derive(Clone)]
pub(crate) struct Dofs {
    /// dof → free index, `usize::MAX` for a fixed dof.
    pub free: Vec<usize>,
    /// Number of free dofs.
    pub nfree: usize,
    /// The tangent's pattern on the free dofs.
    pub pattern: Pattern,
}

impl Dofs {
    /// Numbers the dofs of the nodes not flagged in `fixed`; `tets` are the (possibly
    /// pseudo-) tetrahedra whose node pairs make the pattern.
    pub fn new(fixed: &[bool], tets: &[[usize; 4]]) -> Result<Self, MotionError> {
        let mut free = vec![usize::MAX; 3 * fixed.len()];
        let mut nfree = 0;
        for (n, &f) in fixed.iter().enumerate() {
            if !f {
                for i in 0..3 {
                    free[3 * n + i] = nfree;
                    nfree += 1;
                }
            }
        }
        let pattern =
            Pattern::new(tets, &free, nfree).map_err(|e| MotionError::Invalid(e.to_string()))?;
        Ok(Self {
            free,
            nfree,
            pattern,
        })
    }
}

/// Checks a problem against its linear mesh: material count, fixed displacements, node indices
/// of fixed nodes and forces; returns the per-node fixed flags of the linear mesh.
pub(crate) fn check_problem(p: &StaticProblem<'_>) -> Result<Vec<bool>, MotionError> {
    let (nn, ne) = (p.mesh.nodes.len(), p.mesh.tets.len());
    if p.material.len() != 1 && p.material.len() != ne {
        return Err(MotionError::Invalid(format!(
            "material has {} entries for {ne} elements (expected 1 or {ne})",
            p.material.len()
        )));
    }
    if !p.fixed_displacement.is_empty() && p.fixed_displacement.len() != p.fixed.len() {
        return Err(MotionError::Invalid(format!(
            "{} fixed displacements for {} fixed nodes",
            p.fixed_displacement.len(),
            p.fixed.len()
        )));
    }
    let mut is_fixed = vec![false; nn];
    for &n in &p.fixed {
        if n >= nn {
            return Err(MotionError::Invalid(format!(
                "fixed node {n} out of range (mesh has {nn} nodes)"
            )));
        }
        is_fixed[n] = true;
    }
    if let Some(&(n, _)) = p.forces.iter().find(|(n, _)| *n >= nn) {
        return Err(MotionError::Invalid(format!(
            "force on node {n} out of range (mesh has {nn} nodes)"
        )));
    }
    Ok(is_fixed)
}

/// The one material of a problem whose sensitivities are asked for.
fn uniform_material(p: &StaticProblem<'_>) -> Result<HyperParams, MotionError> {
    match p.material.as_slice() {
        [m] => Ok(*m),
        _ => Err(MotionError::Invalid(format!(
            "sensitivities to λ and μ need one material for all elements, found {} entries",
            p.material.len()
        ))),
    }
}

/// A design's dofs and loading, ready to solve: the full external load, the rest positions and
/// the final displacement of each fixed dof that moves (every dof of the design's mesh).
pub(crate) struct Prepared<'a> {
    /// The free-dof numbering and pattern: the design's own, or one kept for many solves.
    pub dofs: std::borrow::Cow<'a, Dofs>,
    /// External forces at full load.
    pub fext: Vec<f64>,
    /// Rest positions.
    pub rest: Vec<f64>,
    /// (dof, final displacement) of every fixed dof that moves.
    pub moved: Vec<(usize, f64)>,
}

impl Prepared<'_> {
    /// Solves `p` with design `d` ([`solve_increments`]).
    pub fn solve(
        &self,
        d: &impl Discretised,
        p: &StaticProblem<'_>,
    ) -> Result<StaticSolution, MotionError> {
        let (x, iterations, residual) = solve_increments(d, self, p)?;
        Ok(StaticSolution {
            positions: nodes(&x),
            iterations,
            residual,
        })
    }

    /// The sensitivities of the equilibrium `positions` of a uniform material ([`sensitivities`]).
    pub fn sensitivity(
        &self,
        d: &impl Discretised,
        p: &StaticProblem<'_>,
        positions: &[[f64; 3]],
    ) -> Result<StaticSensitivity, MotionError> {
        uniform_material(p)?;
        let x: Vec<f64> = positions.iter().flatten().copied().collect();
        let [dl, dm] = sensitivities(d, &self.dofs, &x)?;
        Ok(StaticSensitivity {
            dlambda: nodes(&dl),
            dmu: nodes(&dm),
        })
    }
}

/// A dof vector as node triples.
fn nodes(x: &[f64]) -> Vec<[f64; 3]> {
    x.chunks(3).map(|c| [c[0], c[1], c[2]]).collect()
}

/// The equilibrium reached: positions (every dof), Newton iterations, final residual norm.
type Reached = (Vec<f64>, usize, f64);

/// Applies the load in equal increments, each solved by Newton on the total potential energy
/// E(x) = U(x) − s f_extᵀ (x − X) with a diagonal shift when the tangent is indefinite and a
/// backtracking (Armijo) line search on E that also backs off from inverted elements.
fn solve_increments(
    d: &impl Discretised,
    l: &Prepared,
    p: &StaticProblem<'_>,
) -> Result<Reached, MotionError> {
    let dofs = &l.dofs;
    let (free, nfree, pattern, fext, rest_x) =
        (&dofs.free, dofs.nfree, &dofs.pattern, &l.fext, &l.rest);
    let mut x = rest_x.to_vec();
    let mut k = vec![0.0; pattern.nnz()];
    let mut iterations = 0;
    let mut residual = 0.0;
    let steps = p.load_steps.max(1);
    for step in 1..=steps {
        let s = step as f64 / steps as f64;
        for &(dof, u) in &l.moved {
            x[dof] = rest_x[dof] + s * u;
        }
        let total_energy = |x: &[f64]| -> Option<f64> {
            let w: f64 = (0..x.len())
                .filter(|&d| free[d] != usize::MAX)
                .map(|d| s * fext[d] * (x[d] - rest_x[d]))
                .sum();
            Some(d.energy(x)? - w)
        };
        // The free dofs' residual f + s f_ext of the internal forces `f`.
        let free_residual = |f: &[f64]| {
            let mut r = vec![0.0; nfree];
            for (d, &fr) in free.iter().enumerate() {
                if fr != usize::MAX {
                    r[fr] = f[d] + s * fext[d];
                }
            }
            r
        };
        let norm = |r: &[f64]| r.iter().map(|v| v * v).sum::<f64>().sqrt();
        let mut converged = false;
        for _ in 0..p.max_iter {
            let f = d
                .forces(&x, Some((pattern, &mut k)))
                .ok_or(MotionError::NoConvergence {
                    step,
                    residual: f64::INFINITY,
                })?;
            let r = free_residual(&f);
            residual = norm(&r);
            if !residual.is_finite() {
                return Err(MotionError::NonFinite(format!(
                    "force residual at load step {step} (a material or load too large for f64)"
                )));
            }
            if residual < p.tol {
                converged = true;
                break;
            }
            // Newton direction; shift the diagonal until K + τI is positive definite.
            let diag_scale = k.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-30);
            // An overflowed tangent has no finite shift: τ would grow to ∞ and the exit test
            // below, τ > 10³ · ∞, never hold.
            if !diag_scale.is_finite() {
                return Err(MotionError::NonFinite(format!(
                    "tangent stiffness at load step {step} (a material or load too large for f64)"
                )));
            }
            let mut tau = 0.0;
            let factor = loop {
                let mut kk = k.clone();
                if tau > 0.0 {
                    for i in 0..nfree {
                        pattern.add_diagonal(i, tau, &mut kk);
                    }
                }
                if let Some(f) = pattern.factor(&kk) {
                    break f;
                }
                tau = if tau == 0.0 {
                    1e-8 * diag_scale
                } else {
                    tau * 10.0
                };
                if tau > 1e3 * diag_scale {
                    return Err(MotionError::NotPositiveDefinite { step });
                }
            };
            let mut dx = r.clone();
            factor.solve_in_place(&mut dx);
            let e0 = total_energy(&x).ok_or(MotionError::Inverted {
                element: usize::MAX,
            })?;
            let slope: f64 = -dx.iter().zip(&r).map(|(a, b)| a * b).sum::<f64>();
            let mut alpha = 1.0;
            loop {
                let mut xt = x.clone();
                for (d, &fr) in free.iter().enumerate() {
                    if fr != usize::MAX {
                        xt[d] += alpha * dx[fr];
                    }
                }
                // Armijo on the energy; near convergence energy differences drown in round-off,
                // so a step that does not increase the energy beyond 1e-12 relative is taken.
                // The volumetric energy (J² − 1)/2 − ln J is a difference of terms of order
                // J − 1 whose sum is of order (J − 1)², so at small strain its round-off can
                // exceed that test too; there a step that lowers the force residual by Armijo's
                // margin is taken instead (the residual's norm is the merit function whose
                // decrease a Newton step guarantees wherever its tangent is exact).
                let ok = match total_energy(&xt) {
                    Some(e1) => {
                        e1 <= e0 + 1e-4 * alpha * slope
                            || (e1 - e0).abs() <= 1e-12 * e0.abs().max(1e-30)
                            || d.forces(&xt, None).is_some_and(|f| {
                                norm(&free_residual(&f)) <= (1.0 - 1e-4 * alpha) * residual
                            })
                    }
                    None => false,
                };
                if ok {
                    x = xt;
                    break;
                }
                alpha *= 0.5;
                if alpha < 1e-10 {
                    return Err(MotionError::NoConvergence { step, residual });
                }
            }
            iterations += 1;
        }
        if !converged {
            return Err(MotionError::NoConvergence { step, residual });
        }
    }
    Ok((x, iterations, residual))
}

/// The sensitivities ∂x/∂λ and ∂x/∂μ of an equilibrium `x` (every dof, zero on fixed ones):
/// differentiating f(x, q) + f_ext = 0 gives K ∂x/∂q = ∂f/∂q with K = −∂f/∂x.
fn sensitivities(
    d: &impl Discretised,
    dofs: &Dofs,
    x: &[f64],
) -> Result<[Vec<f64>; 2], MotionError> {
    let mut k = vec![0.0; dofs.pattern.nnz()];
    let inverted = || MotionError::Inverted {
        element: usize::MAX,
    };
    d.forces(x, Some((&dofs.pattern, &mut k)))
        .ok_or_else(inverted)?;
    let df = d.parameter_forces(x).ok_or_else(inverted)?;
    // An equilibrium of a stable material has a positive definite tangent; step 0 names it.
    let factor = dofs
        .pattern
        .factor(&k)
        .ok_or(MotionError::NotPositiveDefinite { step: 0 })?;
    let n = dofs.nfree;
    let mut b = vec![0.0; 2 * n];
    for (j, dfj) in df.iter().enumerate() {
        for (dof, &fr) in dofs.free.iter().enumerate() {
            if fr != usize::MAX {
                b[j * n + fr] = dfj[dof];
            }
        }
    }
    factor.solve_columns_in_place(&mut b, 2);
    Ok([0, 1].map(|j| {
        dofs.free
            .iter()
            .map(|&fr| if fr == usize::MAX { 0.0 } else { b[j * n + fr] })
            .collect()
    }))
}
