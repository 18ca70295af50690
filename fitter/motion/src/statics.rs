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
use super::static_newton::{check_problem, Discretised, Dofs, Prepared};
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

impl StaticProblem<'_> {
    /// The material of element `e` (the one entry when there is one for all).
    pub(crate) fn material_of(&self, e: usize) -> &HyperParams {
        &self.material[if self.material.len() == 1 { 0 } else { e }]
    }
}

/// The equilibrium found (for quadratic tetrahedra, on the nodes of the quadratic mesh).
#[derive(Debug, Clone)]
pub struct StaticSolution {
    /// Deformed node positions (m).
    pub positions: Vec<[f64; 3]>,
    /// Newton iterations over all increments.
    pub iterations: usize,
    /// Final residual norm (N).
    pub residual: f64,
}

/// The sensitivities of an equilibrium to a uniform material's Lamé parameters, per node (m/Pa;
/// zero at fixed nodes): ∂x/∂q = K⁻¹ ∂f/∂q at equilibrium, K = −∂f/∂x the tangent.
#[derive(Debug, Clone)]
pub struct StaticSensitivity {
    /// ∂x/∂λ per node.
    pub dlambda: Vec<[f64; 3]>,
    /// ∂x/∂μ per node.
    pub dmu: Vec<[f64; 3]>,
}

struct Ctx<'a> {
    p: &'a StaticProblem<'a>,
    rest: Vec<RestTet>,
}

impl Ctx<'_> {
    fn mat(&self, e: usize) -> &HyperParams {
        self.p.material_of(e)
    }
    fn gather(&self, e: usize, x: &[f64]) -> [Vector3<f64>; 4] {
        self.p.mesh.tets[e].map(|n| Vector3::new(x[3 * n], x[3 * n + 1], x[3 * n + 2]))
    }
    /// Adds an element's 12 forces into the global vector.
    fn scatter(&self, e: usize, fe: &[f64; 12], f: &mut [f64]) {
        for (a, &n) in self.p.mesh.tets[e].iter().enumerate() {
            for i in 0..3 {
                f[3 * n + i] += fe[3 * a + i];
            }
        }
    }
}

impl Discretised for Ctx<'_> {
    fn energy(&self, x: &[f64]) -> Option<f64> {
        let mut e_tot = 0.0;
        for e in 0..self.rest.len() {
            let f = he::deformation_gradient(&self.rest[e], &self.gather(e, x));
            e_tot += self.rest[e].volume * he::energy_density(&f, self.mat(e))?;
        }
        Some(e_tot)
    }
    fn forces(&self, x: &[f64], mut k: Option<(&Pattern, &mut [f64])>) -> Option<Vec<f64>> {
        let mut f = vec![0.0; x.len()];
        if let Some((_, k)) = k.as_mut() {
            k.iter_mut().for_each(|v| *v = 0.0);
        }
        for e in 0..self.rest.len() {
            let s = FParts::new(he::deformation_gradient(&self.rest[e], &self.gather(e, x)))?;
            let mut fe = [0.0; 12];
            he::add_stress_forces(&self.rest[e], &he::pk1(&s, self.mat(e)), 1.0, &mut fe);
            self.scatter(e, &fe, &mut f);
            if let Some((pattern, k)) = k.as_mut() {
                pattern.add_element(
                    e,
                    &he::element_tangent(&self.rest[e], &s, self.mat(e)),
                    1.0,
                    k,
                );
            }
        }
        Some(f)
    }
    fn parameter_forces(&self, x: &[f64]) -> Option<[Vec<f64>; 2]> {
        let mut out = [vec![0.0; x.len()], vec![0.0; x.len()]];
        for e in 0..self.rest.len() {
            let s = FParts::new(he::deformation_gradient(&self.rest[e], &self.gather(e, x)))?;
            for (o, dp) in out.iter_mut().zip([he::pk1_dlambda(&s), he::pk1_dmu(&s)]) {
                let mut fe = [0.0; 12];
                he::add_stress_forces(&self.rest[e], &dp, 1.0, &mut fe);
                self.scatter(e, &fe, o);
            }
        }
        Some(out)
    }
}

/// The linear design's context, dofs and loading.
fn setup<'a>(p: &'a StaticProblem<'a>) -> Result<(Ctx<'a>, Prepared<'static>), MotionError> {
    let mesh = p.mesh;
    let is_fixed = check_problem(p)?;
    let rest = RestTet::of_mesh(mesh)?;
    let dofs = Dofs::new(&is_fixed, &mesh.tets)?;
    // Full external load: nodal forces + gravity (ρ V g / 4 per node of each element).
    let mut fext = vec![0.0; 3 * mesh.nodes.len()];
    for &(n, f) in &p.forces {
        for i in 0..3 {
            fext[3 * n + i] += f[i];
        }
    }
    for (e, t) in mesh.tets.iter().enumerate() {
        for &n in t {
            for i in 0..3 {
                fext[3 * n + i] += p.density * rest[e].volume / 4.0 * p.gravity[i];
            }
        }
    }
    let moved = p
        .fixed
        .iter()
        .zip(&p.fixed_displacement)
        .flat_map(|(&n, u)| (0..3).map(move |d| (3 * n + d, u[d])))
        .collect();
    let prepared = Prepared {
        dofs: std::borrow::Cow::Owned(dofs),
        fext,
        rest: mesh.nodes.iter().flatten().copied().collect(),
        moved,
    };
    Ok((Ctx { p, rest }, prepared))
}

/// Solves the quasi-static problem; positions are returned for every node.
pub fn solve_static(p: &StaticProblem<'_>) -> Result<StaticSolution, MotionError> {
    let (ctx, prepared) = setup(p)?;
    prepared.solve(&ctx, p)
}

/// The sensitivities of an equilibrium found by [`solve_static`] to the (uniform) material's λ
/// and μ, for a Gauss–Newton fit of the Lamé parameters.
pub fn static_sensitivity(
    p: &StaticProblem<'_>,
    solution: &StaticSolution,
) -> Result<StaticSensitivity, MotionError> {
    let (ctx, prepared) = setup(p)?;
    prepared.sensitivity(&ctx, p, &solution.positions)
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
