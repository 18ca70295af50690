//! Assembly of K' = Σ R_e K_e R_eᵀ (eq. 3.53) over the free dofs, the right-hand side
//! f + K'' x₀ (K'' = Σ R_e K_e, eq. 3.54) with the fixed nodes eliminated, element force vectors,
//! and the sparse Cholesky factorisation (symbolic part computed once per problem).

use faer::sparse::{SparseColMat, SparseColMatRef, Triplet};
use faer::MatMut;
use nalgebra::{Matrix3, SVector, Vector3};
use palpate_runtime::element::{deformation_gradient, warped_strain, ElementMatrix};

use super::cholesky::{Llt, Symbolic};
use super::polar_lanes::polar_rotations;
use super::{ForwardError, Material, StaticProblem};

/// The sparsity pattern over the free dofs of a sum of dense element blocks (each block the 3
/// dofs of each of its nodes, in order), with zero values; where each block entry (a, c) lands in
/// the value array, row-major per block (`u32::MAX` when either dof is fixed); and where each
/// block's entries start. The element stiffnesses and the discretisation-error blocks share it.
pub(super) fn block_pattern<'a>(
    blocks: impl Iterator<Item = &'a [usize]> + Clone,
    free_index: &[usize],
    free_count: usize,
) -> Result<(SparseColMat<usize, f64>, Vec<u32>, Vec<usize>), ForwardError> {
    let nd = 3 * free_count;
    let dof = |nodes: &[usize], a: usize| -> Option<usize> {
        let f = free_index[nodes[a / 3]];
        (f != usize::MAX).then(|| 3 * f + a % 3)
    };
    let entries: usize = blocks.clone().map(|n| 9 * n.len() * n.len()).sum();
    let mut trip = Vec::with_capacity(entries);
    for nodes in blocks.clone() {
        for a in 0..3 * nodes.len() {
            for c in 0..3 * nodes.len() {
                if let (Some(i), Some(j)) = (dof(nodes, a), dof(nodes, c)) {
                    trip.push(Triplet::new(i, j, 0.0));
                }
            }
        }
    }
    let matrix = SparseColMat::<usize, f64>::try_new_from_triplets(nd, nd, &trip)
        .map_err(|e| ForwardError::Sparse(format!("{e:?}")))?;
    drop(trip);
    let (cp, ri) = (matrix.symbolic().col_ptr(), matrix.symbolic().row_idx());
    let mut scatter = Vec::with_capacity(entries);
    let mut starts = Vec::new();
    for nodes in blocks {
        starts.push(scatter.len());
        for a in 0..3 * nodes.len() {
            for c in 0..3 * nodes.len() {
                scatter.push(match (dof(nodes, a), dof(nodes, c)) {
                    (Some(i), Some(j)) => {
                        let k = ri[cp[j]..cp[j + 1]]
                            .binary_search(&i)
                            .expect("entry is in the pattern by construction");
                        (cp[j] + k) as u32
                    }
                    _ => u32::MAX,
                });
            }
        }
    }
    Ok((matrix, scatter, starts))
}

/// The fixed sparsity pattern of K' (both triangles) and where each element entry lands.
#[derive(Debug, Clone)]
pub(super) struct Pattern {
    /// Pattern with zero values (the values are supplied per assembly).
    matrix: SparseColMat<usize, f64>,
    /// For element e, local entry (a, b) (a, b in 0..12): index into the value array, or
    /// `u32::MAX` when either dof is fixed. 144 entries per element.
    scatter: Vec<u32>,
    /// Symbolic Cholesky of the pattern (lower triangle), reused by every factorisation.
    symbolic: Symbolic,
}

impl Pattern {
    pub(super) fn new(
        tets: &[[usize; 4]],
        free_index: &[usize],
        free_count: usize,
    ) -> Result<Self, ForwardError> {
        let (matrix, scatter, _) =
            block_pattern(tets.iter().map(|t| t.as_slice()), free_index, free_count)?;
        let symbolic = Symbolic::new(matrix.symbolic())?;
        Ok(Self {
            matrix,
            scatter,
            symbolic,
        })
    }

    /// Index of entry (row `i`, column `j`) in the value array, if it is in the pattern.
    pub(super) fn slot(&self, i: usize, j: usize) -> Option<usize> {
        let (cp, ri) = (
            self.matrix.symbolic().col_ptr(),
            self.matrix.symbolic().row_idx(),
        );
        let col = ri.get(*cp.get(j)?..*cp.get(j + 1)?)?;
        col.binary_search(&i).ok().map(|k| cp[j] + k)
    }
}

/// A numerically factorised K' (sparse Cholesky LLᵀ over the free dofs) together with the
/// assembled values, so that one factorisation serves the solve and any number of Jacobian
/// products (§5.3, eq. 5.71).
pub struct Factorised {
    llt: Llt,
    values: Vec<f64>,
    n: usize,
}

impl std::fmt::Debug for Factorised {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Factorised")
            .field("free_dofs", &self.n)
            .field("nonzeros", &self.values.len())
            .finish_non_exhaustive()
    }
}

impl Factorised {
    /// Solves K' y = b in place (b over the free dofs).
    pub fn solve_in_place(&self, b: &mut [f64]) {
        debug_assert_eq!(b.len(), self.n);
        self.llt
            .solve_in_place(MatMut::from_column_major_slice_mut(b, self.n, 1));
    }
    /// Solves K' Y = B in place for several right-hand sides (columns of `b`).
    pub fn solve_in_place_mat(&self, b: MatMut<'_, f64>) {
        self.llt.solve_in_place(b);
    }
    /// The assembled K' values (same pattern as every assembly of this problem).
    pub fn values(&self) -> &[f64] {
        &self.values
    }
    /// Number of free dofs.
    pub fn dim(&self) -> usize {
        self.n
    }
}

/// Adds the element forces `pe`, rotated by R_e, into the full force vector at the nodes `t`.
fn add_rotated(f: &mut [f64], t: &[usize; 4], r: &Matrix3<f64>, pe: &[Vector3<f64>; 4]) {
    for (k, &n) in t.iter().enumerate() {
        let q = r * pe[k];
        for dd in 0..3 {
            f[3 * n + dd] += q[dd];
        }
    }
}

/// 12 × 12 block-diagonal rotation of one element applied as R M Rᵀ.
pub fn rotate_sandwich(m: &ElementMatrix<f64>, r: &Matrix3<f64>) -> ElementMatrix<f64> {
    let mut out = ElementMatrix::<f64>::zeros();
    let rt = r.transpose();
    for a in 0..4 {
        for b in 0..4 {
            let blk: Matrix3<f64> = m.fixed_view::<3, 3>(3 * a, 3 * b).into_owned();
            out.fixed_view_mut::<3, 3>(3 * a, 3 * b)
                .copy_from(&(r * blk * rt));
        }
    }
    out
}

/// R v for a 12-vector (block-diagonal R).
pub fn rotate_vec(r: &Matrix3<f64>, v: &SVector<f64, 12>) -> SVector<f64, 12> {
    let mut out = SVector::<f64, 12>::zeros();
    for a in 0..4 {
        let p = r * v.fixed_rows::<3>(3 * a);
        out.fixed_rows_mut::<3>(3 * a).copy_from(&p);
    }
    out
}

/// Rᵀ v for a 12-vector.
pub fn rotate_vec_t(r: &Matrix3<f64>, v: &SVector<f64, 12>) -> SVector<f64, 12> {
    rotate_vec(&r.transpose(), v)
}

impl StaticProblem {
    /// K_e = λ_e C_e + α_e D_e (eq. 3.63).
    pub fn element_stiffness(&self, e: usize, material: &Material) -> ElementMatrix<f64> {
        let (l, a) = material.at(e);
        self.c[e] * l + self.d[e] * a
    }

    /// The sixteen 3 × 3 blocks (a, b, (R_e K_e R_eᵀ)_ab) of the rotated element stiffness, in
    /// closed form. K_e = λ_e C_e + α_e D_e (eq. 3.63) is the isotropic law with Lamé constants
    /// α_e and λ_e/2 − α_e (the F and G of eq. 3.63, as [`StaticProblem::strain_forces`] reads
    /// them), whose block is V (α g_a g_bᵀ + (λ/2 − α)(g_b g_aᵀ + (g_a·g_b) I)) for the shape
    /// gradients g = ∇φ. Rotating it only turns the gradients, h = R g (R I Rᵀ = I), so
    /// R K_ab Rᵀ = V (α h_a h_bᵀ + (λ/2 − α)(h_b h_aᵀ + (g_a·g_b) I)): a third of the arithmetic
    /// of forming K_e and multiplying each block by R on both sides, and none of C_e's and D_e's
    /// 2.3 kB per element (forming, rotating and scattering them was an eighth of a static
    /// diagnosis' profile).
    pub fn rotated_stiffness_blocks(
        &self,
        e: usize,
        material: &Material,
        r: &Matrix3<f64>,
    ) -> impl Iterator<Item = (usize, usize, Matrix3<f64>)> {
        let geometry = &self.geometry[e];
        let (lambda, alpha) = material.at(e);
        let v = geometry.volume;
        let (first, second) = (v * alpha, v * (0.5 * lambda - alpha));
        let g = geometry.grad;
        let h = g.map(|ga| r * ga);
        (0..16).map(move |k| {
            let (a, b) = (k / 4, k % 4);
            let mut block = h[a] * h[b].transpose() * first + h[b] * h[a].transpose() * second;
            let diagonal = second * g[a].dot(&g[b]);
            for d in 0..3 {
                block[(d, d)] += diagonal;
            }
            (a, b, block)
        })
    }

    /// The 12-vector of positions of element e.
    pub fn element_positions(&self, e: usize, x: &[[f64; 3]]) -> SVector<f64, 12> {
        let t = &self.tets[e];
        SVector::<f64, 12>::from_fn(|k, _| x[t[k / 3]][k % 3])
    }

    /// The element displacement in the unrotated frame, R_eᵀ x_e − x₀e (eq. 3.49's argument).
    pub fn unrotated_displacement(
        &self,
        e: usize,
        r: &Matrix3<f64>,
        x: &[[f64; 3]],
    ) -> SVector<f64, 12> {
        rotate_vec_t(r, &self.element_positions(e, x)) - self.element_positions(e, &self.x0)
    }

    /// Assembles the values of K' = Σ R_e K_e R_eᵀ over the free dofs (eq. 3.53).
    pub fn stiffness_values(&self, material: &Material, rotations: &[Matrix3<f64>]) -> Vec<f64> {
        let mut values = vec![0.0; self.pattern.matrix.symbolic().row_idx().len()];
        for e in 0..self.tets.len() {
            let sc = &self.pattern.scatter[144 * e..144 * e + 144];
            for (a, b, block) in self.rotated_stiffness_blocks(e, material, &rotations[e]) {
                for i in 0..3 {
                    for j in 0..3 {
                        let k = sc[12 * (3 * a + i) + 3 * b + j];
                        if k != u32::MAX {
                            values[k as usize] += block[(i, j)];
                        }
                    }
                }
            }
        }
        if let Some(k) = &material.foundation {
            for s in &self.foundation {
                let ks = s.stiffness(k);
                for (m, &slot) in s.slots.iter().enumerate() {
                    values[slot] += ks[(m / 3, m % 3)];
                }
            }
        }
        values
    }

    /// Adds the foundation's spring forces K_i (x_i − x₀ᵢ) to the internal forces `f` (full 3n).
    fn add_foundation_forces(&self, material: &Material, x: &[[f64; 3]], f: &mut [f64]) {
        let Some(k) = &material.foundation else {
            return;
        };
        for s in &self.foundation {
            let i = s.node;
            let u = Vector3::from(x[i]) - Vector3::from(self.x0[i]);
            let q = s.stiffness(k) * u;
            for d in 0..3 {
                f[3 * i + d] += q[d];
            }
        }
    }

    /// Assembles and factorises K' (numeric Cholesky reusing the symbolic factorisation).
    pub fn factorise(
        &self,
        material: &Material,
        rotations: &[Matrix3<f64>],
    ) -> Result<Factorised, ForwardError> {
        let values = self.stiffness_values(material, rotations);
        let m = SparseColMatRef::new(self.pattern.matrix.symbolic(), &values);
        let llt = self.pattern.symbolic.factor(m)?;
        Ok(Factorised {
            llt,
            values,
            n: self.free_dofs(),
        })
    }

    /// y = K' v over the free dofs, with K' given by its assembled `values`.
    pub fn stiffness_mul(&self, values: &[f64], v: &[f64]) -> Vec<f64> {
        let sym = self.pattern.matrix.symbolic();
        let (cp, ri) = (sym.col_ptr(), sym.row_idx());
        let mut y = vec![0.0; v.len()];
        for j in 0..v.len() {
            let vj = v[j];
            for k in cp[j]..cp[j + 1] {
                y[ri[k]] += values[k] * vj;
            }
        }
        y
    }

    /// Internal elastic forces f_int(x) = Σ_e R_e K_e (R_eᵀ x_e − x₀e) (eq. 3.50), full 3n vector.
    pub fn internal_forces(
        &self,
        material: &Material,
        rotations: &[Matrix3<f64>],
        x: &[[f64; 3]],
    ) -> Vec<f64> {
        let mut f = vec![0.0; 3 * self.x0.len()];
        for (e, t) in self.tets.iter().enumerate() {
            let r = &rotations[e];
            // R_eᵀ x_e − x₀e, node by node (eq. 3.49's argument).
            let u = t.map(|n| r.tr_mul(&Vector3::from(x[n])) - Vector3::from(self.x0[n]));
            add_rotated(&mut f, t, r, &self.stiffness_times(e, material, &u));
        }
        self.add_foundation_forces(material, x, &mut f);
        f
    }

    /// The warp rotations of `x` (as [`StaticProblem::rotations`]) and the internal forces with
    /// them (as [`StaticProblem::internal_forces`]) in one pass over the elements: the
    /// deformation gradient F_e both need is formed once, and the unrotated strain is read off
    /// it, B_e(R_eᵀx_e − x₀e) = sym(R_eᵀF_e) − I (runtime's `warped_strain`). Every iteration of a
    /// warped solve's line search asks for both at its trial point.
    pub fn rotations_and_forces(
        &self,
        material: &Material,
        x: &[[f64; 3]],
        warp: bool,
    ) -> (Vec<Matrix3<f64>>, Vec<f64>) {
        let mut f = vec![0.0; 3 * self.x0.len()];
        let gradients = self.deformation_gradients(x);
        let rotations = if warp {
            polar_rotations(&gradients)
        } else {
            vec![Matrix3::identity(); self.tets.len()]
        };
        for (e, ((t, fe), r)) in self.tets.iter().zip(&gradients).zip(&rotations).enumerate() {
            let s = warped_strain(r, fe);
            let pe = self.strain_forces(e, material, &[s[0], s[1], s[2], s[3], s[4], s[5]]);
            add_rotated(&mut f, t, r, &pe);
        }
        self.add_foundation_forces(material, x, &mut f);
        (rotations, f)
    }

    /// K_e w for a nodal vector w of element e, without forming K_e (see
    /// [`StaticProblem::strain_forces`]).
    pub fn stiffness_times(
        &self,
        e: usize,
        material: &Material,
        w: &[Vector3<f64>; 4],
    ) -> [Vector3<f64>; 4] {
        // ∇w = Σ_k w_k ∇φ_kᵀ (the deformation gradient's sum, applied to w); ε in B's Voigt order
        // with engineering shears.
        let h = deformation_gradient(&self.geometry[e], w);
        let eps = [
            h[(0, 0)],
            h[(1, 1)],
            h[(2, 2)],
            h[(0, 1)] + h[(1, 0)],
            h[(1, 2)] + h[(2, 1)],
            h[(0, 2)] + h[(2, 0)],
        ];
        self.strain_forces(e, material, &eps)
    }

    /// The nodal forces V_e B_eᵀ σ of element e's strain ε (Voigt, engineering shears), σ =
    /// (λ_e F + α_e G) ε (eqs. 3.33, 3.34): K_e w = V_e B_eᵀ (λ_e F + α_e G) B_e w (eq. 3.63)
    /// without forming K_e. About a third of the arithmetic of the 12 × 12 product and none of
    /// its 2.3 kB of C_e, D_e per element: forming λ_e C_e + α_e D_e alone was a fifth of a static
    /// diagnosis, in the warped solves' force evaluations.
    pub fn strain_forces(
        &self,
        e: usize,
        material: &Material,
        eps: &[f64; 6],
    ) -> [Vector3<f64>; 4] {
        let g = &self.geometry[e];
        let (l, a) = material.at(e);
        let v = g.volume;
        // F = diag(1, 1, 1, ½, ½, ½); G: −1 on the normal diagonal, +1 off it, −1 on the shears.
        let s = [
            v * (l * eps[0] + a * (eps[1] + eps[2] - eps[0])),
            v * (l * eps[1] + a * (eps[0] + eps[2] - eps[1])),
            v * (l * eps[2] + a * (eps[0] + eps[1] - eps[2])),
            v * (0.5 * l - a) * eps[3],
            v * (0.5 * l - a) * eps[4],
            v * (0.5 * l - a) * eps[5],
        ];
        g.grad.map(|b| {
            Vector3::new(
                b.x * s[0] + b.y * s[3] + b.z * s[5],
                b.y * s[1] + b.x * s[3] + b.z * s[4],
                b.z * s[2] + b.y * s[4] + b.x * s[5],
            )
        })
    }

    /// Right-hand side over the free dofs for the rotations `rotations`: f + K'' x₀ with the
    /// fixed nodes (held at x₀) moved to the right: f_f + (K''x₀)_f − K'_{f,c} x₀,c.
    pub fn rhs(&self, material: &Material, rotations: &[Matrix3<f64>], f_ext: &[f64]) -> Vec<f64> {
        let mut b = self.gather_free(f_ext);
        for e in 0..self.tets.len() {
            let t = &self.tets[e];
            if t.iter().all(|&i| self.fixed[i]) {
                continue;
            }
            let r = &rotations[e];
            // K_e (x₀e − R_eᵀ x_c), x_c the element's fixed nodes at x₀ (zero elsewhere).
            let w = t.map(|n| {
                let x0 = Vector3::from(self.x0[n]);
                if self.fixed[n] {
                    x0 - r.tr_mul(&x0)
                } else {
                    x0
                }
            });
            let fe = self.stiffness_times(e, material, &w);
            for (k, &n) in t.iter().enumerate() {
                let fi = self.free_index[n];
                if fi != usize::MAX {
                    let g = r * fe[k];
                    for dd in 0..3 {
                        b[3 * fi + dd] += g[dd];
                    }
                }
            }
        }
        // The springs are anchored at the rest shape: K_s x = K_s x₀ + f_s moves K_s x₀ right.
        if let Some(k) = &material.foundation {
            for s in &self.foundation {
                let fi = self.free_index[s.node];
                let q = s.stiffness(k) * Vector3::from(self.x0[s.node]);
                for dd in 0..3 {
                    b[3 * fi + dd] += q[dd];
                }
            }
        }
        b
    }

    /// Restricts a full 3n vector to the free dofs.
    pub fn gather_free(&self, full: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; self.free_dofs()];
        for (n, &fi) in self.free_index.iter().enumerate() {
            if fi != usize::MAX {
                out[3 * fi..3 * fi + 3].copy_from_slice(&full[3 * n..3 * n + 3]);
            }
        }
        out
    }

    /// Positions from free-dof values (fixed nodes at x₀).
    pub fn positions_from_free(&self, free: &[f64]) -> Vec<[f64; 3]> {
        self.x0
            .iter()
            .enumerate()
            .map(|(n, p)| {
                let fi = self.free_index[n];
                if fi == usize::MAX {
                    *p
                } else {
                    [free[3 * fi], free[3 * fi + 1], free[3 * fi + 2]]
                }
            })
            .collect()
    }
}
