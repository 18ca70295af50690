//! The motion of [`crate::sim`] on quadratic (10-node) tetrahedra: the same step (BDF2, eq. 2,
//! the implicit midpoint rule or generalised-α, [`crate::timestep::Scheme`], as
//! [`Model::scheme_for`] chooses it, through [`crate::sim`]'s own scheme terms) with the same
//! residual c M (v − b) = f(x_f, v_f) + f_ext, on the quadratic lift of a model's linear mesh.
//!
//! Linear tetrahedra lock in bending as Poisson's ratio nears ½ (docs/results/discretisation),
//! so a modulus and a viscosity fitted through them belong to the mesh: a cantilever of them
//! rings too fast, and the fit softens the material to bring the period back. Quadratic
//! tetrahedra converge at the meshes a capture comes with; this model is what a fitted
//! material is checked against (docs/results/beam/convergence.md).
//!
//! What is the linear model's, and what is new here:
//! - Nodes, clamps, dead loads and markers keep their linear indices and meaning: corner nodes
//!   are the linear mesh's; an edge node is clamped when both its corners are and sits at their
//!   prescribed positions' mean (exact under a clamp's rigid pose); dead loads act on their
//!   corner nodes as in the linear model, and a load's carried mass sits on them too; a marker's
//!   barycentric coordinates in its element are read through the ten shape functions. A load
//!   on nodes along one edge is read as the line load its equal shares stand for
//!   (`load_shares`).
//! - The elastic law ([`ElasticState`]: Neo-Hookean with its stiffening, or the splines) and the
//!   power-law viscosity ([`visc`], in either reading of ∇v) are evaluated at the four points of
//!   the degree-2 rule, with the same kernels. Their 30 × 30 tangents are written at each
//!   point as rows of 30-vectors: Neo-Hookean's closed form, every other term from its moduli
//!   V ∂P/∂F or V ∂P/∂Ḟ ([`visc::Moduli`]); the element's sum goes into the tangent's pattern,
//!   built on its ten 4-node blocks (`BLOCKS`), once per stored entry, as the quadratic statics'
//!   does.
//! - The mass is consistent, M_ab = ∫ ρ N_a N_b dV integrated exactly ([`mass_table`]): the
//!   row sums of the quadratic element's mass are negative at its corners, so it has no
//!   positive lumped form by row sums.
//! - Newton keeps its factor across iterations and steps while the residual contracts
//!   (`REFACTOR_CONTRACTION`, as [`crate::sim`]); an update that raises the residual or
//!   inverts an element is made again with a fresh tangent, or halved when it was exact.
//!
//! - The creep branch ([`crate::relaxation`]) is held at every quadrature point instead of every
//!   element, with the same update.
//!
//! Not carried: clamp reaction forces.

use super::elastic::ElasticState;
use super::hyperelastic::{self as he, HyperParams};
use super::model::{DeadLoad, Material, Model, ParamKind};
use super::quadratic_statics::{
    add_moduli_rows, add_symmetric_rows, block_tets, element_points, shape_functions, share,
    solve_static_quadratic_loaded, ElementScatter, QuadPoint, BLOCKS,
};
use super::relaxation::{element_coefficients, StepBranch};
use super::rest_fit::{Post, StandOff};
use super::sim::{shifted_factor, SchemeTerms};
use super::sparse::{Factor, Pattern};
use super::statics::StaticProblem;
use super::viscosity as visc;
use super::MotionError;
use nalgebra::{Matrix3, Vector3};
use palpate_fem::mesh::quadratic::{QuadraticMesh, QUADRATIC_EDGES};
use palpate_fem::mesh::Mesh;
use std::collections::HashMap;

/// Largest residual ratio ‖r_k‖/‖r_{k−1}‖ an iteration with a kept factor may show before the
/// tangent is assembled and factorised afresh ([`crate::sim`]'s rule).
const REFACTOR_CONTRACTION: f64 = 0.25;

/// Halvings of a Newton update that inverted an element before the step gives up.
const HALVINGS: usize = 12;

/// (1/V) ∫ N_a N_b dV over a straight-sided quadratic tetrahedron, exactly: each N is a
/// polynomial in the barycentric coordinates (N_a = 2L_a² − L_a, N_ab = 4 L_a L_b) and
/// ∫ L₀^i L₁^j L₂^k L₃^l dV = 6V i! j! k! l! / (i + j + k + l + 3)!.
pub fn mass_table() -> [[f64; 10]; 10] {
    fn poly(k: usize) -> Vec<([u32; 4], f64)> {
        let unit = |a: usize, p: u32| {
            let mut e = [0; 4];
            e[a] = p;
            e
        };
        if k < 4 {
            vec![(unit(k, 2), 2.0), (unit(k, 1), -1.0)]
        } else {
            let [a, b] = QUADRATIC_EDGES[k - 4];
            let mut e = [0; 4];
            e[a] = 1;
            e[b] = 1;
            vec![(e, 4.0)]
        }
    }
    fn factorial(n: u32) -> f64 {
        (1..=n).map(f64::from).product()
    }
    let integral = |e: [u32; 4]| {
        6.0 * e.iter().map(|&p| factorial(p)).product::<f64>()
            / factorial(e.iter().sum::<u32>() + 3)
    };
    std::array::from_fn(|a| {
        std::array::from_fn(|b| {
            let mut s = 0.0;
            for (ea, ca) in poly(a) {
                for (eb, cb) in poly(b) {
                    s += ca * cb * integral(std::array::from_fn(|i| ea[i] + eb[i]));
                }
            }
            s
        })
    })
}

/// What a run on quadratic tetrahedra gives back.
#[derive(Debug, Clone, Default)]
pub struct QuadraticRun {
    /// Every marker's simulated position at steps 1..=steps (index 0 = step 1).
    pub markers: Vec<Vec<[f64; 3]>>,
    /// Newton iterations over the run.
    pub newton_iterations: usize,
    /// Numeric factorisations over the run.
    pub factorisations: usize,
    /// Steps that ended at the iteration cap above the tolerance.
    pub unconverged_steps: usize,
    /// Largest final residual of a step (N).
    pub max_residual: f64,
}

/// A linear [`Model`] lifted to quadratic tetrahedra, ready to simulate any material.
pub struct QuadraticMotion<'a> {
    model: &'a Model,
    linear: Mesh,
    mesh: QuadraticMesh,
    points: Vec<[QuadPoint; 4]>,
    volumes: Vec<f64>,
    table: [[f64; 10]; 10],
    free: Vec<usize>,
    nfree: usize,
    pattern: Pattern,
    /// Where the element matrices go in `pattern`.
    scatter: ElementScatter,
    /// Each marker's element and the ten shape functions at its barycentric coordinates.
    markers: Vec<(usize, [f64; 10])>,
    /// Each marker's element and barycentric coordinates ([`Model::marker_elements`]).
    located: Vec<(usize, [f64; 4])>,
    /// Under [`StandOff::RigidPost`], the post of each marker outside its element.
    posts: Vec<Option<Post>>,
    /// Every clamped node of the quadratic mesh, with its corners (the same node twice for a
    /// corner).
    clamped: Vec<(usize, [usize; 2])>,
    /// Each dead load's shares of its force on the quadratic mesh's nodes ([`load_shares`]).
    load_shares: Vec<Vec<(usize, f64)>>,
}

impl<'a> QuadraticMotion<'a> {
    /// Lifts `model`; refused when its mesh cannot be lifted.
    pub fn new(model: &'a Model) -> Result<Self, MotionError> {
        let linear = Mesh {
            nodes: model.nodes.clone(),
            node_tags: (1..=model.nodes.len() as u64).collect(),
            tets: model.tets.clone(),
            node_groups: Default::default(),
        };
        let mesh = QuadraticMesh::from_linear(&linear);
        let points = element_points(&model.rest);
        let volumes = model.rest.iter().map(|r| r.volume).collect();
        let corner_clamped: Vec<bool> = (0..model.nodes.len())
            .map(|n| model.free[3 * n] == usize::MAX)
            .collect();
        let flags = mesh.lift_flags(&corner_clamped);
        let mut free = vec![usize::MAX; 3 * mesh.nodes.len()];
        let mut nfree = 0;
        let mut clamped = Vec::new();
        for (n, &fixed) in flags.iter().enumerate() {
            if fixed {
                let corners = if n < mesh.vertex_count {
                    [n, n]
                } else {
                    mesh.edges[n - mesh.vertex_count]
                };
                clamped.push((n, corners));
                continue;
            }
            for i in 0..3 {
                free[3 * n + i] = nfree;
                nfree += 1;
            }
        }
        let pattern = Pattern::new(&block_tets(&mesh), &free, nfree)
            .map_err(|e| MotionError::Invalid(e.to_string()))?;
        let scatter = ElementScatter::new(&pattern, mesh.tets.len());
        let located = model.marker_elements()?;
        let markers = located
            .iter()
            .map(|(e, l)| (*e, shape_functions(l)))
            .collect();
        let load_shares = model.loads.iter().map(|l| load_shares(&mesh, l)).collect();
        Ok(Self {
            load_shares,
            model,
            linear,
            mesh,
            points,
            volumes,
            table: mass_table(),
            free,
            nfree,
            pattern,
            scatter,
            markers,
            posts: located.iter().map(|_| None).collect(),
            located,
            clamped,
        })
    }

    /// Free dofs of the quadratic model.
    pub fn free_dofs(&self) -> usize {
        self.nfree
    }

    /// The quadratic mesh simulated on.
    pub fn mesh(&self) -> &QuadraticMesh {
        &self.mesh
    }

    /// How markers off the body follow it ([`StandOff`]; extrapolated by default): under
    /// [`StandOff::RigidPost`] a marker outside its element rides a rigid post from the
    /// nearest point of the element, turned by the rotation of F there, instead of the quadratic
    /// field extrapolated millimetres out with its curvature.
    pub fn with_stand_off(mut self, stand_off: StandOff) -> Self {
        self.posts = match stand_off {
            StandOff::Extrapolated => self.markers.iter().map(|_| None).collect(),
            StandOff::RigidPost => self
                .located
                .iter()
                .map(|(e, l)| Post::of_marker(&self.model.nodes, self.model.tets[*e], l))
                .collect(),
        };
        self
    }

    /// Marker positions in the nodal positions `x` (every dof of the quadratic mesh).
    pub fn marker_positions(&self, x: &[f64]) -> Vec<[f64; 3]> {
        self.markers
            .iter()
            .zip(&self.posts)
            .map(|((e, n), post)| {
                let nodes = &self.mesh.tets[*e];
                let at = |n: &[f64; 10]| {
                    let mut p = [0.0; 3];
                    for (a, &node) in nodes.iter().enumerate() {
                        for d in 0..3 {
                            p[d] += n[a] * x[3 * node + d];
                        }
                    }
                    p
                };
                post.as_ref()
                    .and_then(|p| p.position(&|l: &[f64; 4]| at(&shape_functions(l))))
                    .unwrap_or_else(|| at(n))
            })
            .collect()
    }

    /// Writes the clamped nodes' positions at step `n` into `x` (every dof); `corners` is a
    /// scratch vector of the linear mesh's dofs.
    fn apply_clamps(&self, n: usize, corners: &mut Vec<f64>, x: &mut [f64]) {
        corners.clear();
        corners.extend(self.model.nodes.iter().flatten());
        self.model.apply_clamps(n, corners);
        for &(node, [a, b]) in &self.clamped {
            for d in 0..3 {
                x[3 * node + d] = 0.5 * (corners[3 * a + d] + corners[3 * b + d]);
            }
        }
    }

    /// The start: the rest shape with the clamps at their step-0 pose, or the elastostatic
    /// equilibrium there under gravity and the loads acting from step 0 (on quadratic elements,
    /// [`solve_static_quadratic`]).
    fn start(&self, mat: &Material) -> Result<Vec<f64>, MotionError> {
        let mut corners = Vec::new();
        if !self.model.static_start {
            let mut x: Vec<f64> = self.mesh.nodes.iter().flatten().copied().collect();
            self.apply_clamps(0, &mut corners, &mut x);
            return Ok(x);
        }
        if mat.spline.is_some() {
            return Err(MotionError::Invalid(
                "an elastostatic start on quadratic elements needs a Neo-Hookean material".into(),
            ));
        }
        let density = mat.get(ParamKind::Density, 0);
        if mat.values[ParamKind::Density as usize]
            .iter()
            .any(|&r| r != density)
        {
            return Err(MotionError::Invalid(
                "an elastostatic start on quadratic elements needs one density".into(),
            ));
        }
        let ne = self.model.tets.len();
        let material = (0..ne)
            .map(|e| HyperParams {
                lambda: mat.get(ParamKind::Lambda, e),
                mu: mat.get(ParamKind::Mu, e),
                stiffening: mat.get(ParamKind::Stiffening, e),
            })
            .collect();
        corners.extend(self.model.nodes.iter().flatten());
        self.model.apply_clamps(0, &mut corners);
        let fixed: Vec<usize> = (0..self.model.nodes.len())
            .filter(|&n| self.model.free[3 * n] == usize::MAX)
            .collect();
        let fixed_displacement = fixed
            .iter()
            .map(|&n| std::array::from_fn(|d| corners[3 * n + d] - self.model.nodes[n][d]))
            .collect();
        let mut loads = vec![0.0; 3 * self.mesh.nodes.len()];
        self.add_dead_loads(0, &mut loads);
        let extra: Vec<(usize, [f64; 3])> = (0..self.mesh.nodes.len())
            .filter(|&n| loads[3 * n..3 * n + 3].iter().any(|&f| f != 0.0))
            .map(|n| (n, [loads[3 * n], loads[3 * n + 1], loads[3 * n + 2]]))
            .collect();
        let p = StaticProblem {
            mesh: &self.linear,
            material,
            density,
            gravity: self.model.gravity_of(mat),
            fixed,
            fixed_displacement,
            forces: Vec::new(),
            load_steps: 10,
            // The linear model's static start's own tolerance ([`crate::sim::static_start`]).
            tol: self.model.newton.tol,
            max_iter: 50,
        };
        Ok(solve_static_quadratic_loaded(&p, &extra)?
            .solution
            .positions
            .iter()
            .flatten()
            .copied()
            .collect())
    }

    /// Internal forces f(x, v) (every dof) and, when asked, K = −∂f/∂x and D = −∂f/∂v on the
    /// free pattern.
    fn assemble(
        &self,
        mat: &Material,
        branch: Option<&StepBranch>,
        x: &[f64],
        v: &[f64],
        f: &mut [f64],
        mut tangents: Option<(&mut [f64], &mut [f64])>,
    ) -> Result<(), MotionError> {
        f.iter_mut().for_each(|z| *z = 0.0);
        if let Some((k, d)) = tangents.as_mut() {
            k.iter_mut().for_each(|z| *z = 0.0);
            d.iter_mut().for_each(|z| *z = 0.0);
        }
        let at = |w: &[f64], n: usize| Vector3::new(w[3 * n], w[3 * n + 1], w[3 * n + 2]);
        // The element's 30 × 30 K and D, their node-block upper triangles summed over the
        // quadrature points in SIMD rows and scattered once, each stored entry they touch once
        // and both in one pass ([`ElementScatter`]), as the quadratic statics do.
        let (mut ke, mut de) = ([[0.0; 30]; 30], [[0.0; 30]; 30]);
        let want = tangents.is_some();
        for (e, (nodes, pts)) in self.mesh.tets.iter().zip(&self.points).enumerate() {
            let xe: [Vector3<f64>; 10] = std::array::from_fn(|a| at(x, nodes[a]));
            let ve: [Vector3<f64>; 10] = std::array::from_fn(|a| at(v, nodes[a]));
            let nu = mat.get(ParamKind::Nu, e);
            let h = mat.get(ParamKind::PowerH, e);
            if want {
                ke = [[0.0; 30]; 30];
                de = [[0.0; 30]; 30];
            }
            let mut damped = false;
            for (q, qp) in pts.iter().enumerate() {
                let fg = point_gradient(&xe, qp);
                let s = ElasticState::new(mat, e, fg)?;
                let mut p = s.pk1();
                if let Some(br) = branch {
                    p = br.stress(4 * e + q, &fg, &p);
                }
                let rate = if nu == 0.0 {
                    None
                } else {
                    let mut l = Matrix3::zeros();
                    for a in 0..10 {
                        l += ve[a] * qp.grad[a].transpose();
                    }
                    // At rest a Newtonian dashpot still has its damping tangent (the power
                    // law's is 0 or unbounded there): Newton's first step from rest needs it
                    // (the rest-gradient one; under the objective form only Newton's matrix
                    // differs, not the force, which is 0 at rest in either form).
                    visc::Rate::of(mat.viscous_form, &fg, &l, h).or((h == 1.0).then_some(
                        visc::Rate {
                            e: Matrix3::zeros(),
                            gamma: 1.0,
                            h,
                            power: 1.0,
                            at: None,
                        },
                    ))
                };
                if let Some(r) = &rate {
                    p += visc::stress(r, nu);
                }
                for (a, &node) in nodes.iter().enumerate() {
                    let fa = p * qp.grad[a] * (-qp.weight);
                    for i in 0..3 {
                        f[3 * node + i] += fa[i];
                    }
                }
                if !want {
                    continue;
                }
                // The creep branch's tangent (1 + g b) K⁰ + V (∇φ_a · C ∇φ_b) I₃
                // ([`StepBranch::tangent`]).
                let elastic_volume = branch.map_or(qp.weight, |br| {
                    let k = 4 * e + q;
                    add_symmetric_rows(&qp.grad, qp.weight, &br.c[k], &mut ke);
                    qp.weight * (1.0 + br.gain[k])
                });
                match &s {
                    ElasticState::NeoHookean(parts, params) => he::quadratic_point_tangent(
                        &qp.grad,
                        elastic_volume,
                        parts,
                        params,
                        &mut ke,
                    ),
                    ElasticState::Spline(..) => {
                        add_moduli_rows(&qp.grad, &s.moduli(elastic_volume), &mut ke)
                    }
                }
                if let Some(r) = &rate {
                    // The objective viscosity's force depends on the positions too; a
                    // symmetric matrix holds the symmetric part of that tangent, as the linear
                    // model's does ([`crate::forces`]), and Newton's residual stays exact.
                    if let Some(a) = r.stiffness_moduli_symmetric(nu, qp.weight) {
                        add_moduli_rows(&qp.grad, &a, &mut ke);
                    }
                    add_moduli_rows(&qp.grad, &r.damping_moduli(nu, qp.weight), &mut de);
                    damped = true;
                }
            }
            if let Some((k, d)) = tangents.as_mut() {
                if damped {
                    self.scatter.add_pair(e, (&ke, k), (&de, d));
                } else {
                    self.scatter.add(e, &ke, k);
                }
            }
        }
        Ok(())
    }

    /// Adds the dead loads acting at step `n` to `f` (every dof of the quadratic mesh).
    fn add_dead_loads(&self, n: usize, f: &mut [f64]) {
        for (l, shares) in self.model.loads.iter().zip(&self.load_shares) {
            if n < l.from_step {
                continue;
            }
            for &(node, w) in shares {
                for i in 0..3 {
                    f[3 * node + i] += w * l.force[i];
                }
            }
        }
    }

    /// The elastic second Piola–Kirchhoff stress S⁰ = F⁻¹P⁰ at every quadrature point.
    fn point_pk2(&self, mat: &Material, x: &[f64]) -> Result<Vec<Matrix3<f64>>, MotionError> {
        let at = |n: usize| Vector3::new(x[3 * n], x[3 * n + 1], x[3 * n + 2]);
        let mut out = Vec::with_capacity(4 * self.points.len());
        for (e, (nodes, pts)) in self.mesh.tets.iter().zip(&self.points).enumerate() {
            let xe: [Vector3<f64>; 10] = std::array::from_fn(|a| at(nodes[a]));
            for qp in pts {
                let f = point_gradient(&xe, qp);
                let p0 = ElasticState::new(mat, e, f)?.pk1();
                let finv = f
                    .try_inverse()
                    .ok_or(MotionError::Inverted { element: e })?;
                out.push(finv * p0);
            }
        }
        Ok(out)
    }

    /// The fully relaxed branch (H = 0) at the start `x0`; `None` without creep.
    fn relaxation(
        &self,
        mat: &Material,
        x0: &[f64],
    ) -> Result<Option<PointRelaxation>, MotionError> {
        if !mat.has_creep() {
            return Ok(None);
        }
        let ne = self.points.len();
        let (mut decay, mut gain) = (Vec::with_capacity(4 * ne), Vec::with_capacity(4 * ne));
        for e in 0..ne {
            let (a, gb) = element_coefficients(mat, e, self.model.dt)?;
            decay.extend([a; 4]);
            gain.extend([gb; 4]);
        }
        Ok(Some(PointRelaxation {
            h: vec![Matrix3::zeros(); 4 * ne],
            s0: self.point_pk2(mat, x0)?,
            decay,
            gain,
        }))
    }

    /// y += M w over every dof: the consistent element masses, and each load's carried mass
    /// on its corner nodes.
    fn mass_mul(&self, mat: &Material, w: &[f64], y: &mut [f64]) {
        for l in &self.model.loads {
            let m = l.mass_per_node();
            if m > 0.0 {
                for &n in &l.nodes {
                    for i in 0..3 {
                        y[3 * n + i] += m * w[3 * n + i];
                    }
                }
            }
        }
        for (e, nodes) in self.mesh.tets.iter().enumerate() {
            let m = mat.get(ParamKind::Density, e) * self.volumes[e];
            for (a, &na) in nodes.iter().enumerate() {
                let mut s = [0.0; 3];
                for (b, &nb) in nodes.iter().enumerate() {
                    let t = self.table[a][b];
                    for i in 0..3 {
                        s[i] += t * w[3 * nb + i];
                    }
                }
                for i in 0..3 {
                    y[3 * na + i] += m * s[i];
                }
            }
        }
    }

    /// M on the free pattern.
    fn mass_values(&self, mat: &Material) -> Vec<f64> {
        let mut values = vec![0.0; self.pattern.nnz()];
        for e in 0..self.mesh.tets.len() {
            let m = mat.get(ParamKind::Density, e) * self.volumes[e];
            for (b, local) in BLOCKS.iter().enumerate() {
                let mut mb = [[0.0; 12]; 12];
                for (i, &a) in local.iter().enumerate() {
                    for (j, &c) in local.iter().enumerate() {
                        for d in 0..3 {
                            mb[3 * i + d][3 * j + d] = m * self.table[a][c];
                        }
                    }
                }
                share(&mut mb);
                self.pattern
                    .add_element(BLOCKS.len() * e + b, &mb, 1.0, &mut values);
            }
        }
        self.model
            .add_load_masses(&self.free, &self.pattern, &mut values);
        values
    }

    /// Gravity's consistent load ∫ ρ g N_a dV (every dof).
    fn gravity_load(&self, mat: &Material) -> Vec<f64> {
        let sums: [f64; 10] = std::array::from_fn(|a| self.table[a].iter().sum());
        let g = self.model.gravity_of(mat);
        let mut f = vec![0.0; 3 * self.mesh.nodes.len()];
        for (e, nodes) in self.mesh.tets.iter().enumerate() {
            let m = mat.get(ParamKind::Density, e) * self.volumes[e];
            for (a, &n) in nodes.iter().enumerate() {
                for i in 0..3 {
                    f[3 * n + i] += m * sums[a] * g[i];
                }
            }
        }
        f
    }

    /// Simulates the model's run with `mat` and returns its markers at every step.
    pub fn simulate(&self, mat: &Material) -> Result<QuadraticRun, MotionError> {
        self.simulate_states(mat, |_, _| {})
    }

    /// [`Self::simulate`], handing every converged step's positions (every dof) to `on_step`.
    pub fn simulate_states(
        &self,
        mat: &Material,
        mut on_step: impl FnMut(usize, &[f64]),
    ) -> Result<QuadraticRun, MotionError> {
        let model = self.model;
        let ndof = 3 * self.mesh.nodes.len();
        let terms = SchemeTerms::new(model, mat);
        let (c, ax, av) = terms.coefficients();
        let fgrav = self.gravity_load(mat);
        let mut fext = fgrav.clone();
        let mvals = self.mass_values(mat);
        let x0 = self.start(mat)?;
        // The creep branch starts fully relaxed at x⁰ ([`crate::relaxation`]).
        let mut relax = self.relaxation(mat, &x0)?;
        let (mut xm2, mut xm1) = (x0.clone(), x0);
        let mut vm: [Vec<f64>; 4] = std::array::from_fn(|_| vec![0.0; ndof]);
        let mut f = vec![0.0; ndof];
        let (mut kv, mut dv) = (vec![0.0; self.pattern.nnz()], vec![0.0; self.pattern.nnz()]);
        let mut sv = vec![0.0; self.pattern.nnz()];
        let mut mw = vec![0.0; ndof];
        let mut r = vec![0.0; self.nfree];
        let mut corners = Vec::new();
        let mut run = QuadraticRun::default();
        let mut carried: Option<Factor> = None;
        let tol = model.newton.tol;
        for n in 1..=model.steps {
            fext.copy_from_slice(&fgrav);
            self.add_dead_loads(n, &mut fext);
            let mut x = vec![0.0; ndof];
            self.apply_clamps(n, &mut corners, &mut x);
            // Newton's start: the linear model's predictor, the clamped dofs' velocities those
            // of their prescribed positions and their force state the scheme's own there.
            let (map, b) = terms.step_map([&xm1, &xm2], [&vm[0], &vm[1]]);
            let (mut xf, mut vf) = (vec![0.0; ndof], vec![0.0; ndof]);
            let mut v = terms.predictor(
                &self.free,
                &x,
                [&xm1, &xm2],
                [&vm[0], &vm[1], &vm[2], &vm[3]],
                &mut xf,
                &mut vf,
            );
            let free = &self.free;
            let force_state = |v: &[f64], xf: &mut [f64], vf: &mut [f64]| map.fill(free, v, xf, vf);
            force_state(&v, &mut xf, &mut vf);
            let step_branch = relax.as_ref().map(PointRelaxation::step_branch);
            let branch = step_branch.as_ref();
            let mut fresh = carried.is_none();
            let mut prev_nrm = f64::INFINITY;
            let mut iter = 0;
            // The last update: where it started, its direction (free dofs), and whether its
            // factor was made at its start (an exact Newton step) or kept from before.
            let mut last: Option<(Vec<f64>, Vec<f64>, bool)> = None;
            let mut halvings = 0;
            loop {
                let assembled = if fresh {
                    self.assemble(mat, branch, &xf, &vf, &mut f, Some((&mut kv, &mut dv)))
                } else {
                    self.assemble(mat, branch, &xf, &vf, &mut f, None)
                };
                let nrm = match assembled {
                    Ok(()) => {
                        let vb: Vec<f64> = (0..ndof).map(|d| v[d] - b[d]).collect();
                        mw.iter_mut().for_each(|z| *z = 0.0);
                        self.mass_mul(mat, &vb, &mut mw);
                        for (d, &fr) in self.free.iter().enumerate() {
                            if fr != usize::MAX {
                                r[fr] = f[d] + fext[d] - c * mw[d];
                            }
                        }
                        r.iter().map(|z| z * z).sum::<f64>().sqrt()
                    }
                    Err(MotionError::Inverted { .. }) if last.is_some() => f64::INFINITY,
                    Err(e) => return Err(e),
                };
                if nrm.is_nan() {
                    return Err(MotionError::NonFinite(format!(
                        "residual at step {n} (quadratic elements)"
                    )));
                }
                // An update that raised the residual (or inverted an element) is not kept: one
                // made with a kept factor is taken back and made again with the tangent where
                // it started; an exact Newton step is halved (its direction descends ½‖r‖²).
                if nrm > prev_nrm {
                    let Some((v0, step, exact)) = last.as_mut() else {
                        return Err(MotionError::NoConvergence {
                            step: n,
                            residual: nrm,
                        });
                    };
                    if !*exact {
                        v.copy_from_slice(v0);
                        last = None;
                        fresh = true;
                    } else if halvings < HALVINGS {
                        halvings += 1;
                        step.iter_mut().for_each(|s| *s *= 0.5);
                        v.copy_from_slice(v0);
                        for (d, &fr) in self.free.iter().enumerate() {
                            if fr != usize::MAX {
                                v[d] += step[fr];
                            }
                        }
                        fresh = false;
                    } else {
                        // No part of the update lowers the residual: round-off's floor. The
                        // step ends where the update started, unconverged if above tol.
                        v.copy_from_slice(v0);
                        force_state(&v, &mut xf, &mut vf);
                        self.assemble(mat, branch, &xf, &vf, &mut f, None)?;
                        run.max_residual = run.max_residual.max(prev_nrm);
                        if prev_nrm >= tol {
                            run.unconverged_steps += 1;
                        }
                        break;
                    }
                    force_state(&v, &mut xf, &mut vf);
                    continue;
                }
                if nrm < tol || iter >= model.newton.max_iter {
                    run.max_residual = run.max_residual.max(nrm);
                    if nrm >= tol {
                        run.unconverged_steps += 1;
                    }
                    break;
                }
                if !fresh && nrm > REFACTOR_CONTRACTION * prev_nrm {
                    // The kept factor no longer contracts: the tangent here, factorised.
                    self.assemble(mat, branch, &xf, &vf, &mut f, Some((&mut kv, &mut dv)))?;
                    fresh = true;
                }
                if fresh {
                    for i in 0..sv.len() {
                        sv[i] = c * mvals[i] + ax * kv[i] + av * dv[i];
                    }
                    // Far from the step's answer an element may be compressed past where S
                    // is definite; a shift keeps the update a descent direction.
                    carried = Some(
                        shifted_factor(&self.pattern, self.nfree, &mut sv)
                            .ok_or(MotionError::NotPositiveDefinite { step: n })?,
                    );
                    run.factorisations += 1;
                }
                let Some(fac) = carried.as_ref() else {
                    fresh = true;
                    continue;
                };
                let mut step = r.clone();
                fac.solve_in_place(&mut step);
                let v0 = v.clone();
                for (d, &fr) in self.free.iter().enumerate() {
                    if fr != usize::MAX {
                        v[d] += step[fr];
                    }
                }
                force_state(&v, &mut xf, &mut vf);
                last = Some((v0, step, fresh));
                halvings = 0;
                prev_nrm = nrm;
                fresh = false;
                iter += 1;
                run.newton_iterations += 1;
            }
            if let (Some(r), Some(b)) = (relax.as_mut(), branch) {
                r.advance(self, mat, b, &xf)?;
            }
            terms.end_positions(&self.free, &xf, &v, [&xm1, &xm2], [&vm[0], &vm[1]], &mut x);
            on_step(n, &x);
            run.markers.push(self.marker_positions(&x));
            xm2 = std::mem::replace(&mut xm1, x);
            vm.rotate_right(1);
            vm[0] = v;
        }
        log::debug!(
            "quadratic run: {} steps, {} Newton iterations, {} factorisations, {} steps unconverged (largest residual {:.1e} N)",
            model.steps,
            run.newton_iterations,
            run.factorisations,
            run.unconverged_steps,
            run.max_residual
        );
        Ok(run)
    }
}

/// A dead load's shares of its force on the quadratic mesh's nodes. A load on nodes that lie on
/// one straight line joined by mesh edges (a weight hung from an edge: `--hang …@group` with the
/// group's top edge) is read as the line load its equal nodal shares stand for: the density
/// q_i = (1/n)/L_i at each node (L_i half its segments' lengths), linear over each segment of
/// length ℓ and integrated against the quadratic shape functions — ℓ q_a/6 to each corner and
/// ℓ (q_a + q_b)/3 to the edge node. Its total is the force. Left on the corners, the quadratic
/// mesh would see point loads,
/// whose local dent grows without bound as the mesh is refined, next to the markers of a
/// loaded end. Any other load (a lever's shares, nodes not on one line) keeps its nodal shares.
fn load_shares(mesh: &QuadraticMesh, l: &DeadLoad) -> Vec<(usize, f64)> {
    if let Some(lever) = &l.lever {
        return lever.shares.clone();
    }
    let equal = || {
        let w = 1.0 / l.nodes.len().max(1) as f64;
        l.nodes.iter().map(|&n| (n, w)).collect::<Vec<_>>()
    };
    let Some(line) = on_one_line(mesh, &l.nodes) else {
        return equal();
    };
    let edge_node: HashMap<[usize; 2], usize> = mesh
        .edges
        .iter()
        .enumerate()
        .map(|(k, &e)| (e, mesh.vertex_count + k))
        .collect();
    let mut segments = Vec::with_capacity(line.len().saturating_sub(1));
    for w in line.windows(2) {
        let key = [w[0].min(w[1]), w[0].max(w[1])];
        let Some(&mid) = edge_node.get(&key) else {
            return equal();
        };
        let (p, q) = (mesh.nodes[w[0]], mesh.nodes[w[1]]);
        let len = (0..3).map(|d| (p[d] - q[d]).powi(2)).sum::<f64>().sqrt();
        segments.push((w[0], w[1], mid, len));
    }
    let mut half = vec![0.0; line.len()];
    for (k, s) in segments.iter().enumerate() {
        half[k] += 0.5 * s.3;
        half[k + 1] += 0.5 * s.3;
    }
    let share = 1.0 / line.len() as f64;
    let density: Vec<f64> = half.iter().map(|&h| share / h).collect();
    let mut out = Vec::with_capacity(2 * line.len());
    for (k, &(a, b, mid, len)) in segments.iter().enumerate() {
        out.push((a, len * density[k] / 6.0));
        out.push((b, len * density[k + 1] / 6.0));
        out.push((mid, len * (density[k] + density[k + 1]) / 3.0));
    }
    out
}

/// The nodes in order along the straight line they lie on (to 10⁻⁶ of its length), or `None`
/// when there are fewer than two or they are not on one line.
fn on_one_line(mesh: &QuadraticMesh, nodes: &[usize]) -> Option<Vec<usize>> {
    let p = |n: usize| Vector3::from(mesh.nodes[n]);
    let (&first, rest) = nodes.split_first()?;
    let far = *rest.iter().max_by(|&&a, &&b| {
        (p(a) - p(first))
            .norm()
            .total_cmp(&(p(b) - p(first)).norm())
    })?;
    let axis = p(far) - p(first);
    let length = axis.norm();
    if length <= 0.0 {
        return None;
    }
    let dir = axis / length;
    let mut along = Vec::with_capacity(nodes.len());
    for &n in nodes {
        let d = p(n) - p(first);
        let t = d.dot(&dir);
        if (d - dir * t).norm() > 1e-6 * length {
            return None;
        }
        along.push((t, n));
    }
    along.sort_by(|a, b| a.0.total_cmp(&b.0));
    Some(along.into_iter().map(|(_, n)| n).collect())
}

/// F = Σ_a x_a ∇N_aᵀ at a quadrature point.
fn point_gradient(xe: &[Vector3<f64>; 10], qp: &QuadPoint) -> Matrix3<f64> {
    let mut f = Matrix3::zeros();
    for a in 0..10 {
        f += xe[a] * qp.grad[a].transpose();
    }
    f
}

/// The creep branch of [`crate::relaxation`] held at every quadrature point (index 4e + q)
/// instead of every element: the same exponential update of H per point, the same
/// [`StepBranch`] for the step's stress and tangent.
struct PointRelaxation {
    h: Vec<Matrix3<f64>>,
    s0: Vec<Matrix3<f64>>,
    decay: Vec<f64>,
    gain: Vec<f64>,
}

impl PointRelaxation {
    fn step_branch(&self) -> StepBranch {
        StepBranch {
            c: (0..self.h.len())
                .map(|k| self.h[k] * self.decay[k] - self.s0[k] * self.gain[k])
                .collect(),
            gain: self.gain.clone(),
        }
    }

    /// H_{n+1} = C_n + g b S⁰_{n+1} at the converged positions `x`.
    fn advance(
        &mut self,
        q: &QuadraticMotion<'_>,
        mat: &Material,
        branch: &StepBranch,
        x: &[f64],
    ) -> Result<(), MotionError> {
        let s0 = q.point_pk2(mat, x)?;
        for (k, s) in s0.into_iter().enumerate() {
            self.h[k] = branch.c[k] + s * self.gain[k];
            self.s0[k] = s;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The exact mass table against closed forms it was not built from: ∫ N_a dV / V is −1/20
    /// at a corner and 1/5 at an edge node, and the quadratic interpolant of L₀ (1 at corner 0,
    /// ½ on its edges) carries ∫ L₀² dV / V = 1/10.
    #[test]
    fn the_mass_table_integrates_what_it_should() {
        let t = mass_table();
        for a in 0..10 {
            let row: f64 = t[a].iter().sum();
            let want = if a < 4 { -1.0 / 20.0 } else { 1.0 / 5.0 };
            assert!((row - want).abs() < 1e-15, "row {a}: {row}");
            for b in 0..10 {
                assert_eq!(t[a][b], t[b][a]);
            }
        }
        let u: [f64; 10] = std::array::from_fn(|k| {
            if k < 4 {
                f64::from(u8::from(k == 0))
            } else if QUADRATIC_EDGES[k - 4].contains(&0) {
                0.5
            } else {
                0.0
            }
        });
        let utu: f64 = (0..10)
            .flat_map(|a| (0..10).map(move |b| (a, b)))
            .map(|(a, b)| u[a] * t[a][b] * u[b])
            .sum();
        assert!((utu - 0.1).abs() < 1e-15, "{utu}");
    }

    /// K and D of the assembly against central differences of its forces on a 3-element bar
    /// lifted to 30-node quadratics, bent, stretched and moving: uᵀ D w against the forces'
    /// change with the velocities along w, and uᵀ K w against the symmetric part of their change
    /// with the positions (what a symmetric K holds of the objective viscosity's), for random u
    /// and w on the free dofs. Three materials, each term at a size of its own: Neo-Hookean with
    /// its stiffening, a creep branch and the objective shear-thinning viscosity; the splines'
    /// law with the rest-gradient thickening one; Neo-Hookean with a Newtonian dashpot at rest
    /// (the tangent kept there). Against |u| |w| times the largest row sum of |K| or |D| the
    /// central differences (step 1e-7) differ by at most 1e-10 here; asserted to 1e-8.
    #[test]
    fn the_row_tangents_are_the_forces_derivatives() {
        use crate::relaxation::StepBranch;
        use crate::spline::{Spline, SplineMaterial};
        let (_, model) =
            crate::scenario::bar_model([0.01, 0.03, 0.01], [1, 3, 1], 0.01, 1, &|_| [0.0; 3], &[])
                .unwrap();
        let q = QuadraticMotion::new(&model).unwrap();
        let ndof = 3 * q.mesh.nodes.len();
        let ne = model.tets.len();
        let mut seed = 7u64;
        let mut rnd = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let (lambda, mu) = (4e5, 1e5);
        let bent: Vec<f64> = q
            .mesh
            .nodes
            .iter()
            .flat_map(|p| {
                [
                    1.05 * p[0],
                    p[1] + 3.0 * p[1] * p[1],
                    p[2] - 2.0 * p[1] * p[1],
                ]
            })
            .collect();
        let moving: Vec<f64> = (0..ndof).map(|_| 0.2 * rnd()).collect();
        let mut stiffened = Material::uniform(ne, lambda, mu, 60.0, 0.7, 1100.0);
        stiffened.set_uniform(ParamKind::Stiffening, 0.5 * mu);
        stiffened.viscous_form = visc::Form::Objective;
        let branch = StepBranch {
            c: (0..4 * ne)
                .map(|_| {
                    let m = Matrix3::from_fn(|_, _| 0.3 * mu * rnd());
                    m + m.transpose()
                })
                .collect(),
            gain: (0..4 * ne).map(|_| 0.5 + 0.2 * rnd()).collect(),
        };
        let mut splines = Material::uniform(ne, lambda, mu, 40.0, 1.4, 1100.0);
        let knots = Spline::uniform_knots(0.5, 1.5, 8);
        splines.spline =
            Some(SplineMaterial::neo_hookean(lambda, mu, knots.clone(), knots).unwrap());
        let newtonian = Material::uniform(ne, lambda, mu, 60.0, 1.0, 1100.0);
        let resting = vec![0.0; ndof];
        let cases = [
            (
                &stiffened,
                Some(&branch),
                &moving,
                "Neo-Hookean, stiffening, creep, objective",
            ),
            (&splines, None, &moving, "splines, rest gradient"),
            (&newtonian, None, &resting, "Newtonian at rest"),
        ];
        let forces = |mat: &Material, br: Option<&StepBranch>, x: &[f64], v: &[f64]| {
            let mut f = vec![0.0; ndof];
            q.assemble(mat, br, x, v, &mut f, None).unwrap();
            f
        };
        // A free-dof vector on every dof (0 on the clamped ones).
        let spread = |w: &[f64]| -> Vec<f64> {
            q.free
                .iter()
                .map(|&fr| if fr == usize::MAX { 0.0 } else { w[fr] })
                .collect()
        };
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        for (mat, br, v, what) in cases {
            let nnz = q.pattern.nnz();
            let (mut kv, mut dv) = (vec![0.0; nnz], vec![0.0; nnz]);
            let mut f = vec![0.0; ndof];
            q.assemble(mat, br, &bent, v, &mut f, Some((&mut kv, &mut dv)))
                .unwrap();
            let row_scale = |values: &[f64]| {
                let ones = vec![1.0; q.nfree];
                let mut y = vec![0.0; q.nfree];
                q.pattern.mul_add(
                    &values.iter().map(|z| z.abs()).collect::<Vec<_>>(),
                    &ones,
                    &mut y,
                );
                y.iter().fold(0.0f64, |m, z| m.max(*z))
            };
            let (kscale, dscale) = (row_scale(&kv), row_scale(&dv));
            assert!(kscale > 0.0 && dscale > 0.0, "{what}");
            let eps = 1e-7;
            for _ in 0..4 {
                let (u, w): (Vec<f64>, Vec<f64>) = (
                    (0..q.nfree).map(|_| rnd()).collect(),
                    (0..q.nfree).map(|_| rnd()).collect(),
                );
                let (uf, wf) = (spread(&u), spread(&w));
                let norms = dot(&u, &u).sqrt() * dot(&w, &w).sqrt();
                // J z = −(f(· + εz) − f(· − εz)) / 2ε, on every dof.
                let along_x = |z: &[f64]| -> Vec<f64> {
                    let shifted = |s: f64| -> Vec<f64> {
                        bent.iter().zip(z).map(|(a, b)| a + s * eps * b).collect()
                    };
                    let (fp, fm) = (
                        forces(mat, br, &shifted(1.0), v),
                        forces(mat, br, &shifted(-1.0), v),
                    );
                    fp.iter()
                        .zip(&fm)
                        .map(|(p, m)| -(p - m) / (2.0 * eps))
                        .collect()
                };
                let along_v = |z: &[f64]| -> Vec<f64> {
                    let shifted = |s: f64| -> Vec<f64> {
                        v.iter().zip(z).map(|(a, b)| a + s * eps * b).collect()
                    };
                    let (fp, fm) = (
                        forces(mat, br, &bent, &shifted(1.0)),
                        forces(mat, br, &bent, &shifted(-1.0)),
                    );
                    fp.iter()
                        .zip(&fm)
                        .map(|(p, m)| -(p - m) / (2.0 * eps))
                        .collect()
                };
                let bilinear = |values: &[f64]| {
                    let mut y = vec![0.0; q.nfree];
                    q.pattern.mul_add(values, &w, &mut y);
                    dot(&u, &y)
                };
                let k_fd = 0.5 * (dot(&uf, &along_x(&wf)) + dot(&wf, &along_x(&uf)));
                let k = bilinear(&kv);
                assert!(
                    (k - k_fd).abs() < 1e-8 * kscale * norms,
                    "{what}: uᵀKw {k} against {k_fd}"
                );
                let d_fd = dot(&uf, &along_v(&wf));
                let d = bilinear(&dv);
                assert!(
                    (d - d_fd).abs() < 1e-8 * dscale * norms,
                    "{what}: uᵀDw {d} against {d_fd}"
                );
            }
        }
    }

    /// A marker 5 mm off a bar's side: under a rigid rotation both the extrapolated field and
    /// the rigid post carry it rigidly; under a bent field (z += c x²) the extrapolated marker
    /// follows the bent map out to where it sits, the post does not.
    #[test]
    fn a_rigid_post_moves_rigidly_and_does_not_stretch() {
        let (_, model) = crate::scenario::bar_model(
            [0.01, 0.04, 0.01],
            [1, 4, 1],
            0.01,
            1,
            &|_| [0.0; 3],
            &[[0.015, 0.03, 0.005]],
        )
        .unwrap();
        let rest = [0.015, 0.03, 0.005];
        let extrapolated = QuadraticMotion::new(&model).unwrap();
        let posted = QuadraticMotion::new(&model)
            .unwrap()
            .with_stand_off(StandOff::RigidPost);
        let (c, s) = (0.3f64.cos(), 0.3f64.sin());
        let turn = |p: [f64; 3]| [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2] + 0.01];
        let turned: Vec<f64> = extrapolated
            .mesh
            .nodes
            .iter()
            .flat_map(|&p| turn(p))
            .collect();
        let want = turn(rest);
        for q in [&extrapolated, &posted] {
            let got = q.marker_positions(&turned)[0];
            for d in 0..3 {
                assert!((got[d] - want[d]).abs() < 1e-12, "{got:?} against {want:?}");
            }
        }
        let bent: Vec<f64> = extrapolated
            .mesh
            .nodes
            .iter()
            .flat_map(|&p| [p[0], p[1], p[2] + 20.0 * p[0] * p[0]])
            .collect();
        let (e, p) = (
            extrapolated.marker_positions(&bent)[0],
            posted.marker_positions(&bent)[0],
        );
        // The extrapolated field is the bent map itself at the marker: z + 20 x².
        assert!(
            (e[2] - (rest[2] + 20.0 * rest[0] * rest[0])).abs() < 1e-12,
            "{e:?}"
        );
        assert!((p[2] - e[2]).abs() > 1e-5, "{p:?} against {e:?}");
    }

    /// Equal shares on four evenly spaced nodes of an edge are the line load of density 1/(2ℓ)
    /// at the ends and 1/(4ℓ) inside: 1/12 at every corner, 1/4, 1/6, 1/4 at the three edge
    /// nodes (total 1). Nodes off one line keep their equal shares.
    #[test]
    fn a_load_along_an_edge_is_shared_as_its_line_load() {
        let mesh = palpate_fem::mesh::boxmesh::box_mesh([0.03, 0.01, 0.01], [3, 1, 1]);
        let q = QuadraticMesh::from_linear(&mesh);
        let edge: Vec<usize> = (0..mesh.nodes.len())
            .filter(|&n| mesh.nodes[n][1] == 0.0 && mesh.nodes[n][2] == 0.0)
            .collect();
        assert_eq!(edge.len(), 4);
        let load = |nodes: Vec<usize>| DeadLoad {
            name: "w".into(),
            nodes,
            force: [0.0, 0.0, -1.0],
            from_step: 0,
            mass: None,
            inertia: false,
            lever: None,
        };
        let shares = load_shares(&q, &load(edge.clone()));
        let total: f64 = shares.iter().map(|s| s.1).sum();
        assert!((total - 1.0).abs() < 1e-14, "{total}");
        let of = |n: usize| shares.iter().filter(|s| s.0 == n).map(|s| s.1).sum::<f64>();
        for &n in &edge {
            assert!((of(n) - 1.0 / 12.0).abs() < 1e-14, "corner {n}: {}", of(n));
        }
        let mut mids: Vec<(f64, f64)> = shares
            .iter()
            .filter(|s| s.0 >= q.vertex_count)
            .map(|s| (q.nodes[s.0][0], s.1))
            .collect();
        mids.sort_by(|a, b| a.0.total_cmp(&b.0));
        for (got, want) in mids.iter().zip([0.25, 1.0 / 6.0, 0.25]) {
            assert!((got.1 - want).abs() < 1e-14, "{mids:?}");
        }
        let top = mesh.node_groups["top"][0];
        let off_line = load_shares(&q, &load(vec![edge[0], edge[1], top]));
        assert!(off_line.iter().all(|s| (s.1 - 1.0 / 3.0).abs() < 1e-15));
    }
}
