//! Sparse system matrices on the free degrees of freedom and their faer Cholesky factorisation.
//!
//! The pattern (node pairs sharing a tetrahedron, free dofs only) is built once per model; each
//! element's 12 × 12 block has a precomputed scatter map into the value array, and the symbolic
//! Cholesky analysis (fill-reducing ordering + elimination tree) is done once and reused for
//! every numeric factorisation of every Newton iteration, time step and simulation.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Side};
use std::sync::Arc;

/// Sparsity pattern of the free-dof system with element scatter maps.
#[derive(Debug, Clone)]
pub struct Pattern {
    /// Number of free dofs (matrix order).
    pub n: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    /// Per element: value index of local entry (r, c) at `r * 12 + c`, or `usize::MAX` if either
    /// dof is fixed.
    elem_map: Vec<[usize; 144]>,
    symbolic: Arc<SymbolicCholesky<usize>>,
    factor_len: usize,
}

/// A numeric Cholesky factor S = L Lᵀ of a matrix on [`Pattern`].
#[derive(Debug, Clone)]
pub struct Factor {
    symbolic: Arc<SymbolicCholesky<usize>>,
    values: Vec<f64>,
}

impl Factor {
    /// Solves S x = b in place.
    pub fn solve_in_place(&self, b: &mut [f64]) {
        let n = b.len();
        let par = faer::get_global_parallelism();
        let mut buf = MemBuffer::new(self.symbolic.solve_in_place_scratch::<f64>(1, par));
        LltRef::new(&self.symbolic, &self.values).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(b, n, 1),
            par,
            MemStack::new(&mut buf),
        );
    }
}

impl Pattern {
    /// Builds the pattern of a tetrahedral mesh; `free[dof]` is the free index or `usize::MAX`.
    pub fn new(
        tets: &[[usize; 4]],
        free: &[usize],
        n: usize,
    ) -> Result<Self, faer::sparse::FaerError> {
        let mut cols: Vec<Vec<usize>> = vec![Vec::new(); n];
        for t in tets {
            for &a in t {
                for &b in t {
                    for i in 0..3 {
                        for j in 0..3 {
                            let (r, c) = (free[3 * a + i], free[3 * b + j]);
                            if r != usize::MAX && c != usize::MAX {
                                cols[c].push(r);
                            }
                        }
                    }
                }
            }
        }
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        col_ptr.push(0);
        for c in cols.iter_mut() {
            c.sort_unstable();
            c.dedup();
            row_idx.extend_from_slice(c);
            col_ptr.push(row_idx.len());
        }
        let find = |r: usize, c: usize| -> usize {
            let s = &row_idx[col_ptr[c]..col_ptr[c + 1]];
            col_ptr[c] + s.binary_search(&r).expect("entry in pattern")
        };
        let mut elem_map = Vec::with_capacity(tets.len());
        for t in tets {
            let mut m = [usize::MAX; 144];
            for a in 0..4 {
                for i in 0..3 {
                    for b in 0..4 {
                        for j in 0..3 {
                            let (r, c) = (free[3 * t[a] + i], free[3 * t[b] + j]);
                            if r != usize::MAX && c != usize::MAX {
                                m[(3 * a + i) * 12 + 3 * b + j] = find(r, c);
                            }
                        }
                    }
                }
            }
            elem_map.push(m);
        }
        let sym = SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx);
        // Supernodal: measured faster than faer's automatic choice (simplicial) on these 3D
        // tetrahedral systems (bench motion, see docs/results/motion/bench.md).
        let symbolic = factorize_symbolic_cholesky(
            sym,
            Side::Lower,
            Default::default(),
            CholeskySymbolicParams {
                supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
                ..Default::default()
            },
        )?;
        let factor_len = symbolic.len_val();
        Ok(Self {
            n,
            col_ptr,
            row_idx,
            elem_map,
            symbolic: Arc::new(symbolic),
            factor_len,
        })
    }

    /// Number of stored entries (full symmetric pattern).
    pub fn nnz(&self) -> usize {
        self.row_idx.len()
    }

    /// Adds `scale · k` (an element block, row-major) into `values`.
    pub fn add_element(&self, e: usize, k: &[[f64; 12]; 12], scale: f64, values: &mut [f64]) {
        let m = &self.elem_map[e];
        for r in 0..12 {
            for c in 0..12 {
                let idx = m[r * 12 + c];
                if idx != usize::MAX {
                    values[idx] += scale * k[r][c];
                }
            }
        }
    }

    /// Adds a diagonal entry (lumped mass) at free dof `r`.
    pub fn add_diagonal(&self, r: usize, v: f64, values: &mut [f64]) {
        let s = &self.row_idx[self.col_ptr[r]..self.col_ptr[r + 1]];
        let idx = self.col_ptr[r] + s.binary_search(&r).expect("diagonal in pattern");
        values[idx] += v;
    }

    /// The diagonal entry at free dof `r`.
    pub fn diagonal(&self, r: usize, values: &[f64]) -> f64 {
        let s = &self.row_idx[self.col_ptr[r]..self.col_ptr[r + 1]];
        s.binary_search(&r)
            .map(|i| values[self.col_ptr[r] + i])
            .unwrap_or(0.0)
    }

    /// y += A x for the matrix with `values` on this pattern.
    pub fn mul_add(&self, values: &[f64], x: &[f64], y: &mut [f64]) {
        for c in 0..self.n {
            let xc = x[c];
            if xc == 0.0 {
                continue;
            }
            for k in self.col_ptr[c]..self.col_ptr[c + 1] {
                y[self.row_idx[k]] += values[k] * xc;
            }
        }
    }

    /// Numeric Cholesky factorisation reusing the symbolic analysis; `None` if the matrix is not
    /// positive definite.
    pub fn factor(&self, values: &[f64]) -> Option<Factor> {
        if values.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let sym = SymbolicSparseColMatRef::new_checked(
            self.n,
            self.n,
            &self.col_ptr,
            None,
            &self.row_idx,
        );
        let mat = SparseColMatRef::new(sym, values);
        let par = faer::get_global_parallelism();
        let mut out = vec![0.0; self.factor_len];
        let mut buf = MemBuffer::new(
            self.symbolic
                .factorize_numeric_llt_scratch::<f64>(par, Default::default()),
        );
        self.symbolic
            .factorize_numeric_llt(
                &mut out,
                mat,
                Side::Lower,
                Default::default(),
                par,
                MemStack::new(&mut buf),
                Default::default(),
            )
            .ok()?;
        Some(Factor {
            symbolic: self.symbolic.clone(),
            values: out,
        })
    }

    /// Bytes of one numeric factor (L's stored values; the adjoint tape keeps one per step).
    pub fn factor_bytes(&self) -> usize {
        self.factor_len * std::mem::size_of::<f64>()
    }
}
