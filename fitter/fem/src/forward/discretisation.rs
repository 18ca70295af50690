//! Discretisations of the displacement field beside the linear tetrahedron of the runtime, for
//! the f64 forward model: quadratic (10-node) tetrahedra and linear tetrahedra with the
//! volumetric strain averaged over each node's patch ("average nodal pressure"). Linear
//! tetrahedra lock in bending as Poisson's ratio nears ½ (each element's volume is held
//! constant, and the bending modes of a coarse mesh all change some element's volume), so the
//! Young's modulus fitted with them grows as the mesh coarsens; both designs here remove the
//! constraint count that causes it (see `docs/results/discretisation/README.md`).
//!
//! A [`DiscretisedModel`] is the small-strain stiffness of one design over a problem's mesh,
//! with its sparsity pattern and symbolic Cholesky factorisation computed once, like the linear
//! model's. The linear mesh's nodes come first in every design, so fixed nodes, loads and
//! marker positions named on the linear mesh keep their meaning.

use faer::sparse::{SparseColMat, SparseColMatRef};
use faer::MatMut;
use nalgebra::{DMatrix, Vector3};

use super::cholesky::{Llt, Symbolic};
use super::{ForwardError, Material, StaticProblem};
use crate::mesh::quadratic::QuadraticMesh;

use super::nodal_pressure::NodalPressure;
use super::quadratic::Quadratic;

/// How the displacement field is discretised over the mesh's tetrahedra.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Discretisation {
    /// Linear 4-node tetrahedra (P1): the runtime's element and the default.
    #[default]
    Linear,
    /// Quadratic 10-node tetrahedra (P2) on the same corners, a node added at each edge's
    /// midpoint, integrated with the 4-point rule (exact for straight-sided elements).
    Quadratic,
    /// Linear tetrahedra whose volumetric strain is averaged over each node's patch (average
    /// nodal pressure, Bonet & Burton 1998): the deviatoric energy per element, the volumetric
    /// energy per node.
    NodalPressure,
}

impl Discretisation {
    /// Short name for tables and messages.
    pub fn name(self) -> &'static str {
        match self {
            Self::Linear => "P1",
            Self::Quadratic => "P2",
            Self::NodalPressure => "ANP",
        }
    }
}

/// Dense blocks over node lists: block b couples the nodes `nodes[offsets[b]..offsets[b + 1]]`.
#[derive(Debug, Clone, Default)]
pub(super) struct Blocks {
    pub(super) nodes: Vec<usize>,
    pub(super) offsets: Vec<usize>,
}

impl Blocks {
    pub(super) fn push(&mut self, nodes: &[usize]) {
        if self.offsets.is_empty() {
            self.offsets.push(0);
        }
        self.nodes.extend_from_slice(nodes);
        self.offsets.push(self.nodes.len());
    }
    pub(super) fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }
    pub(super) fn get(&self, b: usize) -> &[usize] {
        &self.nodes[self.offsets[b]..self.offsets[b + 1]]
    }
}

/// The sparsity pattern over the free dofs of a sum of dense blocks, where each block entry
/// lands, and the symbolic Cholesky factorisation, all computed once.
#[derive(Debug, Clone)]
struct BlockPattern {
    matrix: SparseColMat<usize, f64>,
    /// Value index of every block entry (row-major per block), `u32::MAX` for a fixed dof.
    scatter: Vec<u32>,
    /// Start of block b's entries in `scatter`.
    starts: Vec<usize>,
    symbolic: Symbolic,
}

impl BlockPattern {
    fn new(blocks: &Blocks, free_index: &[usize], free_count: usize) -> Result<Self, ForwardError> {
        let (matrix, scatter, starts) = super::assembly::block_pattern(
            (0..blocks.len()).map(|b| blocks.get(b)),
            free_index,
            free_count,
        )?;
        let symbolic = Symbolic::new(matrix.symbolic())?;
        Ok(Self {
            matrix,
            scatter,
            starts,
            symbolic,
        })
    }
}

/// The element maths of one design: the dense blocks it assembles.
#[derive(Debug, Clone)]
pub(super) enum Design {
    Quadratic(Quadratic),
    NodalPressure(NodalPressure),
}

/// The small-strain stiffness of one [`Discretisation`] over a problem's mesh.
#[derive(Debug, Clone)]
pub struct DiscretisedModel {
    kind: Discretisation,
    nodes: Vec<[f64; 3]>,
    vertex_count: usize,
    fixed: Vec<bool>,
    free_index: Vec<usize>,
    free_count: usize,
    blocks: Blocks,
    design: Design,
    pattern: BlockPattern,
}

/// One numeric factorisation of a [`DiscretisedModel`]'s stiffness for one material.
pub struct DiscretisedFactor {
    llt: Llt,
    n: usize,
}

impl std::fmt::Debug for DiscretisedFactor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DiscretisedFactor")
            .field("free_dofs", &self.n)
            .finish_non_exhaustive()
    }
}

impl DiscretisedModel {
    /// Builds `kind` over the linear problem `p` (its mesh, fixed nodes and elements). An edge
    /// node of the quadratic design is fixed when both its corners are.
    pub fn new(p: &StaticProblem, kind: Discretisation) -> Result<Self, ForwardError> {
        let (nodes, fixed, blocks, design) = match kind {
            Discretisation::Linear => {
                return Err(ForwardError::Discretisation {
                    discretisation: kind.name(),
                    reason: "is the problem's own: it needs no separate model",
                })
            }
            Discretisation::Quadratic => {
                let mesh = crate::mesh::Mesh {
                    nodes: p.x0.clone(),
                    tets: p.tets.clone(),
                    ..Default::default()
                };
                let q = QuadraticMesh::from_linear(&mesh);
                let fixed = q.lift_flags(&p.fixed);
                let mut blocks = Blocks::default();
                for t in &q.tets {
                    blocks.push(t);
                }
                let design = Design::Quadratic(Quadratic::new(&p.geometry));
                (q.nodes, fixed, blocks, design)
            }
            Discretisation::NodalPressure => {
                let (np, blocks) = NodalPressure::new(&p.tets, &p.geometry, p.x0.len());
                (
                    p.x0.clone(),
                    p.fixed.clone(),
                    blocks,
                    Design::NodalPressure(np),
                )
            }
        };
        let mut free_index = vec![usize::MAX; nodes.len()];
        let mut free_count = 0;
        for (i, f) in fixed.iter().enumerate() {
            if !f {
                free_index[i] = free_count;
                free_count += 1;
            }
        }
        let pattern = BlockPattern::new(&blocks, &free_index, free_count)?;
        Ok(Self {
            kind,
            nodes,
            vertex_count: p.x0.len(),
            fixed,
            free_index,
            free_count,
            blocks,
            design,
            pattern,
        })
    }

    /// Which design this is.
    pub fn kind(&self) -> Discretisation {
        self.kind
    }
    /// Rest positions of all of its nodes (the linear mesh's first).
    pub fn nodes(&self) -> &[[f64; 3]] {
        &self.nodes
    }
    /// Number of the linear mesh's nodes (the first of [`DiscretisedModel::nodes`]).
    pub fn vertex_count(&self) -> usize {
        self.vertex_count
    }
    /// Number of free dofs.
    pub fn free_dofs(&self) -> usize {
        3 * self.free_count
    }
    /// Whether node i is held at its rest position.
    pub fn is_fixed(&self, i: usize) -> bool {
        self.fixed[i]
    }
    /// Nonzeros of the stiffness pattern over the free dofs (both triangles).
    pub fn nonzeros(&self) -> usize {
        self.pattern.matrix.symbolic().row_idx().len()
    }

    /// Consistent nodal loads (full 3 × node-count vector) of a uniform traction `traction`
    /// (Pa) over the linear mesh's boundary triangles `triangles`: ∫ N_i t dA, which is A/3 at
    /// each corner for linear triangles and A/3 at each edge node (none at the corners) for
    /// quadratic ones.
    pub fn traction_load(&self, triangles: &[[usize; 3]], traction: [f64; 3]) -> Vec<f64> {
        let mut f = vec![0.0; 3 * self.nodes.len()];
        let index: std::collections::HashMap<[usize; 2], usize> = match &self.design {
            Design::Quadratic(_) => self
                .blocks
                .nodes
                .chunks(10)
                .flat_map(|t| {
                    crate::mesh::quadratic::QUADRATIC_EDGES
                        .iter()
                        .enumerate()
                        .map(move |(k, [a, b])| ([t[*a].min(t[*b]), t[*a].max(t[*b])], t[4 + k]))
                })
                .collect(),
            Design::NodalPressure(_) => Default::default(),
        };
        for &[a, b, c] in triangles {
            let [pa, pb, pc] = [a, b, c].map(|i| Vector3::from(self.nodes[i]));
            let area = 0.5 * (pb - pa).cross(&(pc - pa)).norm();
            let targets: Vec<usize> = match &self.design {
                Design::Quadratic(_) => [(a, b), (b, c), (c, a)]
                    .iter()
                    .map(|&(i, j)| index[&[i.min(j), i.max(j)]])
                    .collect(),
                Design::NodalPressure(_) => vec![a, b, c],
            };
            for i in targets {
                for d in 0..3 {
                    f[3 * i + d] += area / 3.0 * traction[d];
                }
            }
        }
        f
    }

    /// Assembles the stiffness over the free dofs for `material` and factorises it (numeric
    /// Cholesky reusing the symbolic factorisation).
    pub fn factorise(&self, material: &Material) -> Result<DiscretisedFactor, ForwardError> {
        let mut values = vec![0.0; self.nonzeros()];
        let mut k = DMatrix::<f64>::zeros(0, 0);
        for b in 0..self.blocks.len() {
            let m = 3 * self.blocks.get(b).len();
            if k.nrows() != m {
                k = DMatrix::zeros(m, m);
            } else {
                k.fill(0.0);
            }
            match &self.design {
                Design::Quadratic(q) => q.add_element(b, material, &mut k),
                Design::NodalPressure(np) => np.add_block(b, material, &mut k),
            }
            let sc = &self.pattern.scatter[self.pattern.starts[b]..self.pattern.starts[b] + m * m];
            for a in 0..m {
                for c in 0..m {
                    let s = sc[m * a + c];
                    if s != u32::MAX {
                        values[s as usize] += k[(a, c)];
                    }
                }
            }
        }
        let mref = SparseColMatRef::new(self.pattern.matrix.symbolic(), &values);
        let llt = self.pattern.symbolic.factor(mref)?;
        Ok(DiscretisedFactor {
            llt,
            n: self.free_dofs(),
        })
    }

    /// Small-strain displacements of all nodes (fixed ones zero) under the nodal forces `f`
    /// (3 × node count), with a factorisation from [`DiscretisedModel::factorise`].
    pub fn displacement(
        &self,
        factor: &DiscretisedFactor,
        f: &[f64],
    ) -> Result<Vec<[f64; 3]>, ForwardError> {
        if f.len() != 3 * self.nodes.len() {
            return Err(ForwardError::Length {
                what: "force vector of the discretised model",
                found: f.len(),
                expected: 3 * self.nodes.len(),
            });
        }
        let mut b = vec![0.0; factor.n];
        for (i, &fi) in self.free_index.iter().enumerate() {
            if fi != usize::MAX {
                b[3 * fi..3 * fi + 3].copy_from_slice(&f[3 * i..3 * i + 3]);
            }
        }
        factor
            .llt
            .solve_in_place(MatMut::from_column_major_slice_mut(&mut b, factor.n, 1));
        if !b.iter().all(|v| v.is_finite()) {
            return Err(ForwardError::NonFinite { increment: 1 });
        }
        Ok(self
            .free_index
            .iter()
            .map(|&fi| {
                if fi == usize::MAX {
                    [0.0; 3]
                } else {
                    [b[3 * fi], b[3 * fi + 1], b[3 * fi + 2]]
                }
            })
            .collect())
    }
}

/// Adds `weight` × the isotropic elasticity block of shape-function gradients `grads` to `k`
/// (3m × 3m, node-major): k_ab,ij += w (λ ∂_i N_a ∂_j N_b + μ ∂_j N_a ∂_i N_b + μ δ_ij ∇N_a·∇N_b),
/// the bilinear form ∫ λ div u div v + 2μ ε(u):ε(v) with Lamé's λ (not the thesis λ_F).
pub(super) fn add_isotropic(
    k: &mut DMatrix<f64>,
    grads: &[Vector3<f64>],
    weight: f64,
    lame: f64,
    mu: f64,
) {
    for (a, ga) in grads.iter().enumerate() {
        for (b, gb) in grads.iter().enumerate() {
            let dot = ga.dot(gb);
            for i in 0..3 {
                for j in 0..3 {
                    let mut v = lame * ga[i] * gb[j] + mu * ga[j] * gb[i];
                    if i == j {
                        v += mu * dot;
                    }
                    k[(3 * a + i, 3 * b + j)] += weight * v;
                }
            }
        }
    }
}

/// Lamé's λ and the shear modulus μ of element e from the thesis pair (λ_F, α_G): the stress
/// σ_xx = λ_F ε_xx + α_G (ε_yy + ε_zz − ε_xx) of eq. 3.33 is Lamé's with λ = α_G and
/// 2μ = λ_F − 2α_G.
pub(super) fn lame(material: &Material, e: usize) -> (f64, f64) {
    let (l, a) = material.at(e);
    (a, 0.5 * l - a)
}

impl StaticProblem {
    /// The problem solved with `kind` instead of linear tetrahedra (see [`Discretisation`]);
    /// `Linear` gives the problem back unchanged. The other designs serve small-strain solves
    /// ([`StaticProblem::solve`] without warping); the warped solve and the factor the static
    /// fitter's adjoint reuses stay the linear model's.
    pub fn with_discretisation(mut self, kind: Discretisation) -> Result<Self, ForwardError> {
        self.discretised = match kind {
            Discretisation::Linear => None,
            _ => Some(std::sync::Arc::new(DiscretisedModel::new(&self, kind)?)),
        };
        Ok(self)
    }

    /// The discretisation [`StaticProblem::solve`] uses.
    pub fn discretisation(&self) -> Discretisation {
        self.discretised
            .as_ref()
            .map_or(Discretisation::Linear, |m| m.kind())
    }

    /// The model of a discretisation other than linear tetrahedra, if one was asked for.
    pub fn discretised(&self) -> Option<&DiscretisedModel> {
        self.discretised.as_deref()
    }

    /// Small-strain solve with the problem's other discretisation: positions of the linear
    /// mesh's nodes.
    pub(super) fn solve_discretised(
        &self,
        model: &DiscretisedModel,
        material: &Material,
        f_ext: &[f64],
        warp: bool,
    ) -> Result<Vec<[f64; 3]>, ForwardError> {
        if warp {
            return Err(ForwardError::Discretisation {
                discretisation: model.kind().name(),
                reason: "serves small-strain solves only: ask for `warp: false`",
            });
        }
        material.check(self.tets.len())?;
        self.check_foundation(material)?;
        if material.foundation.is_some() {
            return Err(ForwardError::Discretisation {
                discretisation: model.kind().name(),
                reason: "has no elastic foundation",
            });
        }
        let mut f = vec![0.0; 3 * model.nodes().len()];
        f[..f_ext.len()].copy_from_slice(f_ext);
        let factor = model.factorise(material)?;
        let u = model.displacement(&factor, &f)?;
        Ok(self
            .x0
            .iter()
            .zip(&u)
            .map(|(p, d)| [p[0] + d[0], p[1] + d[1], p[2] + d[2]])
            .collect())
    }
}
