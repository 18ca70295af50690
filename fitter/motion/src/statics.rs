//! Quasi-static hyperelastic solver: equilibrium of the Neo-Hookean (+ optional stiffening)
//! material of [`super::hyperelastic`] on a [`Mesh`] with fixed nodes, nodal forces and gravity.
//!
//! Public API for the specimen generator. Method: the load (forces, gravity and the
//! prescribed displacement of fixed nodes) is applied in `load_steps` equal increments; each
//! increment is solved by Newton on the total potential energy
//! E(x) = Σ_e V_e Ψ(F_e) − s f_extᵀ (x − X), with a faer sparse Cholesky of the tangent
//! (symbolic analysis done once), a diagonal shift when the tangent is indefinite, and a
//! backtracking (Armijo) line search on E that also backs off from inverted elements.

use super::hyperelastic::{self as he, FParts, HyperParams, RestTet};
use super::sparse::Pattern;
use super::MotionError;
use nalgebra::Vector3;
use palpate_fem::mesh::Mesh;

/// A quasi-static problem.
#[derive(Debug, Clone)]
pub struct StaticProblem<'a> {
    /// The mesh (rest positions).
    pub mesh: &'a Mesh,
    /// Material per element (length = number of tets) or one entry for all.
    pub material: Vec<HyperParams>,
    /// Density (kg/m³) for gravity; 0 = no weight.
    pub density: f64,
    /// Gravity (m/s²).
    pub gravity: [f64; 3],
    /// Fixed nodes (all three dofs).
    pub fixed: Vec<usize>,
    /// Final displacement of each fixed node (same order as `fixed`), or empty = held at rest.
    pub fixed_displacement: Vec<[f64; 3]>,
    /// External nodal forces (node, force in N) at full load.
    pub forces: Vec<(usize, [f64; 3])>,
    /// Number of load increments (≥ 1).
    pub load_steps: usize,
    /// Newton tolerance on the free-dof residual norm (N).
    pub tol: f64,
    /// Newton iteration cap per increment.
    pub max_iter: usize,
}

impl<'a> StaticProblem<'a> {
    /// A problem with uniform material, no gravity, 10 load steps, tol 1e-9 N, 50 iterations.
    pub fn new(mesh: &'a Mesh, material: HyperParams, fixed: Vec<usize>) -> Self {
        Self {
            mesh,
            material: vec![material],
            density: 0.0,
            gravity: [0.0; 3],
            fixed,
            fixed_displacement: Vec::new(),
            forces: Vec::new(),
            load_steps: 10,
            tol: 1e-9,
            max_iter: 50,
        }
    }
}

/// The equilibrium found.
#[derive(Debug, Clone)]
pub struct StaticSolution {
    /// Deformed node positions (m).
    pub positions: Vec<[f64; 3]>,
    /// Newton iterations over all increments.
    pub iterations: usize,
    /// Final residual norm (N).
    pub residual: f64,
}

struct Ctx<'a> {
    p: &'a StaticProblem<'a>,
    rest: Vec<RestTet>,
    free: Vec<usize>,
    nfree: usize,
    pattern: Pattern,
}

impl Ctx<'_> {
    fn mat(&self, e: usize) -> &HyperParams {
        if self.p.material.len() == 1 {
            &self.p.material[0]
        } else {
            &self.p.material[e]
        }
    }
    fn gather(&self, e: usize, x: &[f64]) -> [Vector3<f64>; 4] {
        self.p.mesh.tets[e].map(|n| Vector3::new(x[3 * n], x[3 * n + 1], x[3 * n + 2]))
    }
    /// Internal energy; `None` if an element is inverted.
    fn energy(&self, x: &[f64]) -> Option<f64> {
        let mut e_tot = 0.0;
        for e in 0..self.rest.len() {
            let f = he::deformation_gradient(&self.rest[e], &self.gather(e, x));
            e_tot += self.rest[e].volume * he::energy_density(&f, self.mat(e))?;
        }
        Some(e_tot)
    }
    /// Internal forces (full) and optionally K on the free pattern.
    fn forces(&self, x: &[f64], mut k: Option<&mut [f64]>) -> Option<Vec<f64>> {
        let mut f = vec![0.0; x.len()];
        if let Some(k) = k.as_deref_mut() {
            k.iter_mut().for_each(|v| *v = 0.0);
        }
        for e in 0..self.rest.len() {
            let s = FParts::new(he::deformation_gradient(&self.rest[e], &self.gather(e, x)))?;
            let mut fe = [0.0; 12];
            he::add_stress_forces(&self.rest[e], &he::pk1(&s, self.mat(e)), 1.0, &mut fe);
            for (a, &n) in self.p.mesh.tets[e].iter().enumerate() {
                for i in 0..3 {
                    f[3 * n + i] += fe[3 * a + i];
                }
            }
            if let Some(k) = k.as_deref_mut() {
                self.pattern.add_element(
                    e,
                    &he::element_tangent(&self.rest[e], &s, self.mat(e)),
                    1.0,
                    k,
                );
            }
        }
        Some(f)
    }
}

/// Solves the quasi-static problem; positions are returned for every node.
pub fn solve_static(p: &StaticProblem<'_>) -> Result<StaticSolution, MotionError> {
    let mesh = p.mesh;
    let nn = mesh.nodes.len();
    if p.material.len() != 1 && p.material.len() != mesh.tets.len() {
        return Err(MotionError::Invalid(format!(
            "material has {} entries for {} elements (expected 1 or {})",
            p.material.len(),
            mesh.tets.len(),
            mesh.tets.len()
        )));
    }
    if !p.fixed_displacement.is_empty() && p.fixed_displacement.len() != p.fixed.len() {
        return Err(MotionError::Invalid(format!(
            "{} fixed displacements for {} fixed nodes",
            p.fixed_displacement.len(),
            p.fixed.len()
        )));
    }
    let rest = RestTet::of_mesh(mesh)?;
    let mut is_fixed = vec![false; nn];
    for &n in &p.fixed {
        if n >= nn {
            return Err(MotionError::Invalid(format!(
                "fixed node {n} out of range (mesh has {nn} nodes)"
            )));
        }
        is_fixed[n] = true;
    }
    let mut free = vec![usize::MAX; 3 * nn];
    let mut nfree = 0;
    for n in 0..nn {
        if !is_fixed[n] {
            for i in 0..3 {
                free[3 * n + i] = nfree;
                nfree += 1;
            }
        }
    }
    let pattern =
        Pattern::new(&mesh.tets, &free, nfree).map_err(|e| MotionError::Invalid(e.to_string()))?;
    let ctx = Ctx {
        p,
        rest,
        free,
        nfree,
        pattern,
    };
    // Full external load: nodal forces + gravity (ρ V g / 4 per node of each element).
    let mut fext = vec![0.0; 3 * nn];
    for &(n, f) in &p.forces {
        if n >= nn {
            return Err(MotionError::Invalid(format!(
                "force on node {n} out of range (mesh has {nn} nodes)"
            )));
        }
        for i in 0..3 {
            fext[3 * n + i] += f[i];
        }
    }
    for (e, t) in mesh.tets.iter().enumerate() {
        for &n in t {
            for i in 0..3 {
                fext[3 * n + i] += p.density * ctx.rest[e].volume / 4.0 * p.gravity[i];
            }
        }
    }
    let rest_x: Vec<f64> = mesh.nodes.iter().flatten().copied().collect();
    let mut x = rest_x.clone();
    let mut k = vec![0.0; ctx.pattern.nnz()];
    let mut iterations = 0;
    let mut residual = 0.0;
    let steps = p.load_steps.max(1);
    for step in 1..=steps {
        let s = step as f64 / steps as f64;
        for (i, &n) in p.fixed.iter().enumerate() {
            let u = p.fixed_displacement.get(i).copied().unwrap_or([0.0; 3]);
            for d in 0..3 {
                x[3 * n + d] = rest_x[3 * n + d] + s * u[d];
            }
        }
        let total_energy = |x: &[f64]| -> Option<f64> {
            let w: f64 = (0..x.len())
                .filter(|&d| ctx.free[d] != usize::MAX)
                .map(|d| s * fext[d] * (x[d] - rest_x[d]))
                .sum();
            Some(ctx.energy(x)? - w)
        };
        let mut converged = false;
        for _ in 0..p.max_iter {
            let f = ctx
                .forces(&x, Some(&mut k))
                .ok_or(MotionError::NoConvergence {
                    step,
                    residual: f64::INFINITY,
                })?;
            let mut r = vec![0.0; ctx.nfree];
            for (d, &fr) in ctx.free.iter().enumerate() {
                if fr != usize::MAX {
                    r[fr] = f[d] + s * fext[d];
                }
            }
            residual = r.iter().map(|v| v * v).sum::<f64>().sqrt();
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
                    for i in 0..ctx.nfree {
                        ctx.pattern.add_diagonal(i, tau, &mut kk);
                    }
                }
                if let Some(f) = ctx.pattern.factor(&kk) {
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
                for (d, &fr) in ctx.free.iter().enumerate() {
                    if fr != usize::MAX {
                        xt[d] += alpha * dx[fr];
                    }
                }
                // Armijo on the energy; near convergence energy differences drown in round-off,
                // so a step that does not increase the energy beyond 1e-12 relative is taken.
                let ok = match total_energy(&xt) {
                    Some(e1) => {
                        e1 <= e0 + 1e-4 * alpha * slope
                            || (e1 - e0).abs() <= 1e-12 * e0.abs().max(1e-30)
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
    Ok(StaticSolution {
        positions: x.chunks(3).map(|c| [c[0], c[1], c[2]]).collect(),
        iterations,
        residual,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_fem::mesh::boxmesh::box_mesh;
    use std::sync::mpsc;
    use std::time::Duration;

    /// A block with one element 1e300 times stiffer than the rest (the specimen generator's
    /// inclusion at an absurd magnitude): the tangent's diagonal overflows, and the shift loop
    /// used to multiply an infinite τ by ten for ever. It must return an error, and promptly.
    #[test]
    fn an_overflowing_tangent_is_an_error_not_a_hang() {
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let mesh = box_mesh([0.08, 0.08, 0.04], [2, 2, 1]);
            let soft = HyperParams {
                lambda: 4e4,
                mu: 3e3,
                stiffening: 0.0,
            };
            let hard = HyperParams {
                lambda: 4e4 * 1e300,
                mu: 3e3 * 1e300,
                stiffening: 0.0,
            };
            let mut material = vec![soft; mesh.tets.len()];
            material[0] = hard;
            let fixed: Vec<usize> = (0..mesh.nodes.len())
                .filter(|&n| mesh.nodes[n][2] == 0.0)
                .collect();
            let top = (0..mesh.nodes.len())
                .find(|&n| mesh.nodes[n][2] > 0.03)
                .unwrap();
            let mut p = StaticProblem::new(&mesh, soft, fixed);
            p.material = material;
            p.forces = vec![(top, [0.0, 0.0, -1.0])];
            let _ = tx.send(solve_static(&p).map(|s| s.iterations));
        });
        let got = rx
            .recv_timeout(Duration::from_secs(60))
            .expect("the static solve did not return within 60 s");
        assert!(got.is_err(), "an overflowing material solved: {got:?}");
    }
}
