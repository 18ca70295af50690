//! The f64 forward model of seed 000 §3.3 and §6.1: warped-stiffness linear FEM solved with a
//! sparse direct solver (faer). This is "what the runtime computes", in double precision: the
//! runtime (f32, PCG) is checked against it, the static fitter differentiates it, and the
//! specimen generator uses it to synthesise data.
//!
//! - [`StaticProblem`]: mesh, fixed (Dirichlet) nodes, surface, per-element C_e and D_e (from the
//!   shared `palpate_runtime::element` kernels), and the sparsity pattern of K' over free dofs with
//!   its symbolic Cholesky factorisation (computed once, reused for every numeric factorisation).
//! - [`Material`]: one (λ, α) pair or one per element (eqs. 3.36–3.38, 3.61).
//! - [`Load`]: force-driven contacts spread with the runtime's contact rule
//!   (`palpate_runtime::contact_rule`) plus explicit nodal forces.
//! - [`StaticProblem::solve`]: incremental loading with rotations recomputed from the current state
//!   each increment, then fixed-point iterations at full load until the rotation update moves x by
//!   less than a tolerance (§6.1).

// Index loops over nodes/elements/coordinates mirror the equations' subscripts (x_{n,d},
// R_e); the iterator forms clippy suggests would obscure them.
#![allow(clippy::needless_range_loop)]
// Result tuples of (per-measurement, per-node) vectors are used once, at their call sites.
#![allow(clippy::type_complexity)]

mod assembly;
pub mod cantilever;
mod cholesky;
mod discretisation;
mod load;
mod nodal_pressure;
mod polar_lanes;
mod quadratic;
mod solve;

pub use assembly::{rotate_sandwich, rotate_vec, rotate_vec_t, Factorised};
pub use discretisation::{Discretisation, DiscretisedFactor, DiscretisedModel};
pub use load::{Contact, Load};
pub use solve::{Solution, SolveOptions, SolvedWithFactor};

use nalgebra::Matrix3;
use palpate_runtime::element::{
    element_cd, tet_geometry, ElementDefect, ElementMatrix, TetGeometry,
};
use palpate_runtime::material::LambdaAlpha;

use crate::mesh::Mesh;

/// Errors of the forward model.
#[derive(Debug, thiserror::Error)]
pub enum ForwardError {
    /// A tetrahedron names a node that does not exist.
    #[error("element {element} names node {node}, but the mesh has {count} nodes")]
    NodeOutOfRange {
        /// Element index.
        element: usize,
        /// Offending node index.
        node: usize,
        /// Number of nodes.
        count: usize,
    },
    /// A rest tetrahedron cannot be used.
    #[error("element {element} (nodes {nodes:?}) is {defect}")]
    BadElement {
        /// Element index.
        element: usize,
        /// Its node indices.
        nodes: [usize; 4],
        /// What is wrong with it.
        defect: &'static str,
    },
    /// A fixed node index is out of range.
    #[error("fixed node {node} is out of range (the mesh has {count} nodes)")]
    FixedOutOfRange {
        /// Offending index.
        node: usize,
        /// Number of nodes.
        count: usize,
    },
    /// No node is fixed: K' is singular (six rigid motions).
    #[error("no fixed nodes: the stiffness matrix is singular (rigid-body motions are free)")]
    NoFixedNodes,
    /// Every node is fixed: nothing to solve.
    #[error("every node is fixed: there is nothing to solve")]
    NoFreeNodes,
    /// An elastic foundation was asked for, but no boundary triangle has all three nodes among
    /// the fixed nodes: there is no supported face to spread it over.
    #[error("no boundary triangle lies on the fixed nodes: an elastic foundation needs a supported face")]
    NoFoundationFace,
    /// The problem rests on an elastic foundation and the material gives it no (positive,
    /// finite) stiffness, or the problem has none and the material gives one.
    #[error("foundation stiffness: {0}")]
    FoundationStiffness(String),
    /// A surface triangle names a node that does not exist.
    #[error("surface triangle {triangle} names node {node}, but the mesh has {count} nodes")]
    SurfaceOutOfRange {
        /// Triangle index.
        triangle: usize,
        /// Offending node index.
        node: usize,
        /// Number of nodes.
        count: usize,
    },
    /// The material has the wrong number of values.
    #[error(
        "material has {found} pairs of thesis coefficients (λ_F: {lambda}, α_G: {alpha}); expected 1 or {elements}"
    )]
    MaterialLength {
        /// Number of λ values.
        lambda: usize,
        /// Number of α values.
        alpha: usize,
        /// min of both.
        found: usize,
        /// Number of elements.
        elements: usize,
    },
    /// Non-physical parameters.
    #[error("element {element}: thesis coefficients λ_F = {lambda}, α_G = {alpha} are not physical (need E > 0 and −1 < ν < 0.5)")]
    NonPhysical {
        /// Element index (0 for a homogeneous material).
        element: usize,
        /// λ (Pa).
        lambda: f64,
        /// α (Pa).
        alpha: f64,
    },
    /// A contact could not be spread over the surface.
    #[error("contact {index} at {point:?} (radius {radius} m): {reason}")]
    Contact {
        /// Index in the load's contact list.
        index: usize,
        /// Contact point (m).
        point: [f64; 3],
        /// Probe radius (m).
        radius: f64,
        /// Why.
        reason: String,
    },
    /// A nodal force names a node that does not exist, or is not finite.
    #[error("nodal force {index} on node {node}: {reason}")]
    NodalForce {
        /// Index in the load's nodal-force list.
        index: usize,
        /// Node index.
        node: usize,
        /// Why.
        reason: &'static str,
    },
    /// A position or force vector has the wrong length.
    #[error("{what} has {found} entries, expected {expected}")]
    Length {
        /// Which vector.
        what: &'static str,
        /// Found length.
        found: usize,
        /// Expected length.
        expected: usize,
    },
    /// The numeric Cholesky factorisation failed.
    #[error(
        "the stiffness matrix could not be factorised, so the object has no equilibrium: it is \
         not positive definite (a material with E ≤ 0 or Poisson's ratio outside (−1, 0.5), a \
         flat element, or no fixed node holding the body still) — solver: {0}"
    )]
    Factorisation(String),
    /// Building the sparsity pattern failed.
    #[error("building the sparse matrix failed: {0}")]
    Sparse(String),
    /// A discretisation other than linear tetrahedra was asked for something it does not serve.
    #[error("the {discretisation} discretisation {reason}")]
    Discretisation {
        /// Which ([`Discretisation::name`]).
        discretisation: &'static str,
        /// What it does not serve.
        reason: &'static str,
    },
    /// The solution contains NaN or infinity.
    #[error("the solve produced a non-finite position (at increment {increment})")]
    NonFinite {
        /// Load increment (or fixed-point iteration counted after the increments).
        increment: usize,
    },
}

/// Material parameters: one (λ, α) pair for the whole object or one per element
/// (thesis parameters of E = λF + αG, eqs. 3.36–3.38 and 3.61), and the stiffness of the
/// elastic foundation of a problem built on one ([`StaticProblem::on_foundation`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Material {
    /// λ values (Pa): 1 or one per element.
    pub lambda: Vec<f64>,
    /// α values (Pa): same length as `lambda`.
    pub alpha: Vec<f64>,
    /// The foundation's stiffness per unit area; `None` for a problem with fixed supports only.
    pub foundation: Option<Foundation>,
}

/// Stiffness per unit area (Pa/m) of an elastic (Winkler) foundation: the supported face rests
/// on independent springs, `normal` along the face's normal and `tangential` in its plane. A
/// soft mat under the object, a suction cup, a base glued to a compliant plate: the support
/// gives way in proportion to the local traction instead of holding its nodes fixed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Foundation {
    /// k_n (Pa/m).
    pub normal: f64,
    /// k_t (Pa/m).
    pub tangential: f64,
}

/// A node that rests on the foundation: its lumped area on the supported face, the face's unit
/// outward normal there, and where its 3 × 3 diagonal block sits in K'.
#[derive(Debug, Clone)]
pub struct FoundationNode {
    /// Node index.
    pub node: usize,
    /// Lumped area A_i (a third of each supported triangle at the node), m².
    pub area: f64,
    /// Area-weighted unit normal n_i of the supported triangles at the node.
    pub normal: [f64; 3],
    /// Indices of the node's diagonal block (row-major 3 × 3) in the K' values.
    slots: [usize; 9],
}

impl FoundationNode {
    /// The node's spring matrix K_i = A_i (k_t I + (k_n − k_t) n_i n_iᵀ).
    pub fn stiffness(&self, k: &Foundation) -> Matrix3<f64> {
        let n = nalgebra::Vector3::from(self.normal);
        (Matrix3::identity() * k.tangential + n * n.transpose() * (k.normal - k.tangential))
            * self.area
    }
}

impl Material {
    /// A homogeneous material.
    pub fn homogeneous(p: LambdaAlpha) -> Self {
        Self {
            lambda: vec![p.lambda],
            alpha: vec![p.alpha],
            foundation: None,
        }
    }
    /// A homogeneous material from Young's modulus (Pa) and Poisson ratio.
    pub fn from_young_poisson(young: f64, poisson: f64) -> Self {
        Self::homogeneous(LambdaAlpha::from_young_poisson(young, poisson))
    }
    /// Per-element parameters.
    pub fn per_element(params: &[LambdaAlpha]) -> Self {
        Self {
            lambda: params.iter().map(|p| p.lambda).collect(),
            alpha: params.iter().map(|p| p.alpha).collect(),
            foundation: None,
        }
    }
    /// True when one pair serves every element.
    pub fn is_homogeneous(&self) -> bool {
        self.lambda.len() == 1
    }
    /// (λ_e, α_e) of element `e`.
    #[inline]
    pub fn at(&self, e: usize) -> (f64, f64) {
        if self.lambda.len() == 1 {
            (self.lambda[0], self.alpha[0])
        } else {
            (self.lambda[e], self.alpha[e])
        }
    }
    /// The mean over the stored pairs of a property of each (Young's modulus, Poisson's ratio):
    /// the value itself for a homogeneous material.
    pub fn mean(&self, f: impl Fn(&LambdaAlpha) -> f64) -> f64 {
        self.lambda
            .iter()
            .zip(&self.alpha)
            .map(|(&lambda, &alpha)| f(&LambdaAlpha { lambda, alpha }))
            .sum::<f64>()
            / self.lambda.len().max(1) as f64
    }
    /// Checks the length against `elements` and that every pair is physical.
    pub fn check(&self, elements: usize) -> Result<(), ForwardError> {
        let (nl, na) = (self.lambda.len(), self.alpha.len());
        if nl != na || !(nl == 1 || nl == elements) {
            return Err(ForwardError::MaterialLength {
                lambda: nl,
                alpha: na,
                found: nl.min(na),
                elements,
            });
        }
        for (e, (&lambda, &alpha)) in self.lambda.iter().zip(&self.alpha).enumerate() {
            if !(LambdaAlpha { lambda, alpha }).is_physical() {
                return Err(ForwardError::NonPhysical {
                    element: e,
                    lambda,
                    alpha,
                });
            }
        }
        Ok(())
    }
}

/// A static FEM problem: rest mesh, Dirichlet nodes, surface, element matrices and the K'
/// sparsity pattern over the free dofs.
#[derive(Debug, Clone)]
pub struct StaticProblem {
    /// Rest positions x₀ (m).
    pub x0: Vec<[f64; 3]>,
    /// Tetrahedra (node indices, positive volume).
    pub tets: Vec<[usize; 4]>,
    /// Boundary triangles (node indices).
    pub surface: Vec<[usize; 3]>,
    /// `fixed[i]`: node i is held at its rest position.
    pub fixed: Vec<bool>,
    /// Free-dof block of each node (`usize::MAX` for fixed nodes): dofs 3k..3k+3.
    pub free_index: Vec<usize>,
    /// Number of free nodes (free dofs = 3 × this).
    pub free_count: usize,
    /// Rest geometry of each element.
    pub geometry: Vec<TetGeometry<f64>>,
    /// C_e = V_e B_eᵀ F B_e (eq. 3.63).
    pub c: Vec<ElementMatrix<f64>>,
    /// D_e = V_e B_eᵀ G B_e (eq. 3.63).
    pub d: Vec<ElementMatrix<f64>>,
    /// Lumped surface area of each node (contact rule).
    pub areas: Vec<f64>,
    /// Nodes on an elastic foundation instead of fixed (empty unless built by
    /// [`StaticProblem::on_foundation`]).
    pub foundation: Vec<FoundationNode>,
    pattern: assembly::Pattern,
    /// The model of another discretisation that [`StaticProblem::solve`] uses instead of the
    /// linear tetrahedra ([`StaticProblem::with_discretisation`]).
    discretised: Option<std::sync::Arc<DiscretisedModel>>,
}

impl StaticProblem {
    /// Builds the problem: element matrices from the shared kernels, the free-dof numbering and the
    /// sparsity pattern of K' with its symbolic factorisation.
    pub fn new(mesh: &Mesh, fixed: &[usize], surface: &[[usize; 3]]) -> Result<Self, ForwardError> {
        Self::build(mesh, fixed, surface, false)
    }

    /// The problem with its supported face on an elastic (Winkler) foundation instead of fixed:
    /// the fixed nodes of the boundary triangles whose three nodes are all fixed rest on springs
    /// (area-lumped, along the face's normal and in its plane, stiffness from
    /// [`Material::foundation`]); fixed nodes on no such triangle stay fixed. The springs add
    /// K_s = Σ_i A_i (k_t I + (k_n − k_t) n_i n_iᵀ) to K' and K_s x₀ to the right-hand side: a
    /// linear support anchored at the rest shape, which the fixed problem is the stiff limit of.
    pub fn on_foundation(
        mesh: &Mesh,
        fixed: &[usize],
        surface: &[[usize; 3]],
    ) -> Result<Self, ForwardError> {
        Self::build(mesh, fixed, surface, true)
    }

    fn build(
        mesh: &Mesh,
        fixed: &[usize],
        surface: &[[usize; 3]],
        on_foundation: bool,
    ) -> Result<Self, ForwardError> {
        let n = mesh.nodes.len();
        let mut geometry = Vec::with_capacity(mesh.tets.len());
        let mut c = Vec::with_capacity(mesh.tets.len());
        let mut d = Vec::with_capacity(mesh.tets.len());
        for (e, t) in mesh.tets.iter().enumerate() {
            if let Some(&node) = t.iter().find(|&&i| i >= n) {
                return Err(ForwardError::NodeOutOfRange {
                    element: e,
                    node,
                    count: n,
                });
            }
            let x = t.map(|i| nalgebra::Vector3::from(mesh.nodes[i]));
            let g = tet_geometry(&x).map_err(|defect| ForwardError::BadElement {
                element: e,
                nodes: *t,
                defect: match defect {
                    ElementDefect::NonFinite => "not finite",
                    ElementDefect::ZeroVolume => "flat (zero volume)",
                    ElementDefect::Inverted => "inverted (negative volume)",
                },
            })?;
            let (ce, de) = element_cd(&g);
            geometry.push(g);
            c.push(ce);
            d.push(de);
        }
        let mut is_fixed = vec![false; n];
        for &i in fixed {
            *is_fixed
                .get_mut(i)
                .ok_or(ForwardError::FixedOutOfRange { node: i, count: n })? = true;
        }
        if fixed.is_empty() {
            return Err(ForwardError::NoFixedNodes);
        }
        for (k, t) in surface.iter().enumerate() {
            if let Some(&node) = t.iter().find(|&&i| i >= n) {
                return Err(ForwardError::SurfaceOutOfRange {
                    triangle: k,
                    node,
                    count: n,
                });
            }
        }
        // The supported face: boundary triangles on fixed nodes only. Their nodes leave the
        // fixed set and rest on the foundation.
        let mut support_area = vec![0.0; n];
        let mut support_normal = vec![nalgebra::Vector3::<f64>::zeros(); n];
        if on_foundation {
            for t in surface.iter().filter(|t| t.iter().all(|&i| is_fixed[i])) {
                let [a, b, c] = t.map(|i| nalgebra::Vector3::from(mesh.nodes[i]));
                // (b − a) × (c − a) = 2 A n for an outward-wound triangle.
                let twice = (b - a).cross(&(c - a));
                for &i in t {
                    support_area[i] += twice.norm() / 6.0;
                    support_normal[i] += twice;
                }
            }
            if support_area.iter().all(|&a| a == 0.0) {
                return Err(ForwardError::NoFoundationFace);
            }
            for i in 0..n {
                if support_area[i] > 0.0 {
                    is_fixed[i] = false;
                }
            }
        }
        let mut free_index = vec![usize::MAX; n];
        let mut free_count = 0;
        for i in 0..n {
            if !is_fixed[i] {
                free_index[i] = free_count;
                free_count += 1;
            }
        }
        if free_count == 0 {
            return Err(ForwardError::NoFreeNodes);
        }
        let mut areas = vec![0.0; n];
        palpate_runtime::contact_rule::lumped_surface_areas(
            |i| mesh.nodes[i],
            surface.iter().copied(),
            &mut areas,
        );
        let pattern = assembly::Pattern::new(&mesh.tets, &free_index, free_count)?;
        let foundation = (0..n)
            .filter(|&i| support_area[i] > 0.0)
            .map(|i| {
                let fi = free_index[i];
                let mut slots = [0usize; 9];
                for (k, slot) in slots.iter_mut().enumerate() {
                    *slot = pattern
                        .slot(3 * fi + k / 3, 3 * fi + k % 3)
                        .ok_or_else(|| {
                            ForwardError::Sparse(format!(
                                "node {i} rests on the foundation but belongs to no element"
                            ))
                        })?;
                }
                Ok(FoundationNode {
                    node: i,
                    area: support_area[i],
                    normal: support_normal[i].normalize().into(),
                    slots,
                })
            })
            .collect::<Result<Vec<_>, ForwardError>>()?;
        Ok(Self {
            x0: mesh.nodes.clone(),
            tets: mesh.tets.clone(),
            surface: surface.to_vec(),
            fixed: is_fixed,
            free_index,
            free_count,
            geometry,
            c,
            d,
            areas,
            foundation,
            pattern,
            discretised: None,
        })
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.x0.len()
    }
    /// Number of elements.
    pub fn element_count(&self) -> usize {
        self.tets.len()
    }
    /// Number of free dofs (3 × free nodes).
    pub fn free_dofs(&self) -> usize {
        3 * self.free_count
    }

    /// Per-element warp rotations R_e from the rest state to `x` (eqs. 3.55–3.58: the polar
    /// factor, four elements at a time, `polar_lanes`; the shared reflection-safe
    /// `warp_rotation_svd` where F is inverted or flat), or identities when `warp` is false.
    pub fn rotations(&self, x: &[[f64; 3]], warp: bool) -> Vec<Matrix3<f64>> {
        if !warp {
            return vec![Matrix3::identity(); self.tets.len()];
        }
        polar_lanes::polar_rotations(&self.deformation_gradients(x))
    }

    /// Each element's deformation gradient F_e at `x`.
    fn deformation_gradients(&self, x: &[[f64; 3]]) -> Vec<Matrix3<f64>> {
        self.tets
            .iter()
            .zip(&self.geometry)
            .map(|(t, g)| {
                let xe = t.map(|i| nalgebra::Vector3::from(x[i]));
                palpate_runtime::element::deformation_gradient(g, &xe)
            })
            .collect()
    }

    /// Unrotated element strains ε_e = B_e(R_eᵀ x_e − x₀e) (eqs. 3.49, 6.8), one 6-vector per element.
    pub fn strains(&self, x: &[[f64; 3]], rotations: &[Matrix3<f64>]) -> Vec<[f64; 6]> {
        self.tets
            .iter()
            .zip(&self.geometry)
            .zip(rotations)
            .map(|((t, g), r)| {
                let xe = t.map(|i| nalgebra::Vector3::from(x[i]));
                let f = palpate_runtime::element::deformation_gradient(g, &xe);
                let s = palpate_runtime::element::warped_strain(r, &f);
                [s[0], s[1], s[2], s[3], s[4], s[5]]
            })
            .collect()
    }
}

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_discretisation;
