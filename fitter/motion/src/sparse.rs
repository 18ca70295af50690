//! Sparse system matrices on the free degrees of freedom and their faer Cholesky factorisation.
//!
//! The pattern (node pairs sharing a tetrahedron, free dofs only) is built once per model; each
//! element's 12 × 12 block has a precomputed scatter map into the value array, and the symbolic
//! Cholesky analysis (fill-reducing ordering + elimination tree) is done once and reused for
//! every numeric factorisation of every Newton iteration, time step and simulation.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky,
    SymmetricOrdering,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Side};
use std::sync::Arc;

/// Sparsity pattern of the free-dof system with element scatter maps.
///
/// The matrices are symmetric and stored as their lower triangle in the fill-reducing (AMD)
/// order: numbering the unknowns that way once lets faer's numeric Cholesky read the values as
/// they are (with its own ordering it copied and permuted the whole matrix at every
/// factorisation, 5 % of a motion fit), and half the triangle is half the scatter work. The
/// methods take and return vectors in the caller's free-dof numbering.
#[derive(Debug, Clone)]
pub struct Pattern {
    /// Number of free dofs (matrix order).
    pub n: usize,
    /// The lower triangle, sorted rows, in the internal (fill-reducing) numbering.
    lower: SymbolicSparseColMat<usize>,
    /// Per stored entry, its row and column in the caller's numbering (for products).
    row_free: Vec<usize>,
    col_free: Vec<usize>,
    /// Value index of the diagonal entry of each free dof (caller's numbering).
    diag: Vec<usize>,
    /// Element scatter lists: element e's entries are `elem_entries[elem_ptr[e]..elem_ptr[e + 1]]`,
    /// each (local index `r * 12 + c` with r ≤ c, value index) — one per unordered pair of free
    /// dofs, since the element blocks are symmetric and one stored entry holds both mirrors.
    /// Eight bytes an entry (a `usize` index made it sixteen): the scatter of every tangent
    /// assembly streams this list, 56k entries on the 716-tet beam.
    elem_ptr: Vec<usize>,
    elem_entries: Vec<(u16, u32)>,
    /// Internal position i holds the caller's free dof `order[i]`.
    order: Arc<Vec<usize>>,
    symbolic: Arc<SymbolicCholesky<usize>>,
    factor_len: usize,
}

/// A numeric Cholesky factor S = L Lᵀ of a matrix on [`Pattern`]. Cloning shares the values
/// (the adjoint tape keeps the factor of every step that the simulation already made).
#[derive(Debug, Clone)]
pub struct Factor {
    symbolic: Arc<SymbolicCholesky<usize>>,
    order: Arc<Vec<usize>>,
    values: Arc<Vec<f64>>,
}

impl Factor {
    /// Whether `self` and `other` are clones of one factorisation.
    pub fn shares_values(&self, other: &Factor) -> bool {
        Arc::ptr_eq(&self.values, &other.values)
    }

    /// Solves S x = b in place (`b` in the caller's free-dof numbering).
    pub fn solve_in_place(&self, b: &mut [f64]) {
        self.solve_columns_in_place(b, 1);
    }

    /// Solves S X = B in place for `m` right-hand sides stored column after column (each of
    /// length n, the caller's free-dof numbering): one pass of the supernodal triangular solves
    /// for all of them (the direct sensitivities of a step: one column per parameter).
    pub fn solve_columns_in_place(&self, b: &mut [f64], m: usize) {
        if m == 0 {
            return;
        }
        let n = b.len() / m;
        let mut y = vec![0.0; n * m];
        for j in 0..m {
            for (i, &d) in self.order.iter().enumerate() {
                y[j * n + i] = b[j * n + d];
            }
        }
        let par = faer::get_global_parallelism();
        let mut buf = MemBuffer::new(self.symbolic.solve_in_place_scratch::<f64>(m, par));
        LltRef::new(&self.symbolic, &self.values).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut y, n, m),
            par,
            MemStack::new(&mut buf),
        );
        for j in 0..m {
            for (i, &d) in self.order.iter().enumerate() {
                b[j * n + d] = y[j * n + i];
            }
        }
    }
}

/// The free-dof pairs (row, column) of a tetrahedron's 12 × 12 block, with the local index
/// `r * 12 + c` of each; pairs with a fixed dof are left out.
fn free_pairs<'a>(
    t: &'a [usize; 4],
    free: &'a [usize],
) -> impl Iterator<Item = (usize, usize, usize)> + 'a {
    (0..144).filter_map(move |local| {
        let (lr, lc) = (local / 12, local % 12);
        let r = free[3 * t[lr / 3] + lr % 3];
        let c = free[3 * t[lc / 3] + lc % 3];
        (r != usize::MAX && c != usize::MAX).then_some((local, r, c))
    })
}

/// Why a [`Pattern`] could not be built.
#[derive(Debug, thiserror::Error)]
pub enum PatternError {
    /// A free degree of freedom lies in no tetrahedron (a node no element uses): the system
    /// would be singular.
    #[error("free degree of freedom {0} lies in no tetrahedron (a node no element uses)")]
    DofInNoElement(usize),
    /// More stored entries than a 32-bit scatter index holds.
    #[error("the system has {0} stored entries, more than the 2³² a scatter index holds")]
    TooLarge(usize),
    /// faer's symbolic analysis failed.
    #[error("sparse analysis failed: {0:?}")]
    Analysis(faer::sparse::FaerError),
}

impl From<faer::sparse::FaerError> for PatternError {
    fn from(e: faer::sparse::FaerError) -> Self {
        Self::Analysis(e)
    }
}

/// Column-compressed arrays (sorted, deduplicated rows) from per-column row lists.
fn compress(mut cols: Vec<Vec<usize>>) -> (Vec<usize>, Vec<usize>) {
    let mut col_ptr = Vec::with_capacity(cols.len() + 1);
    let mut row_idx = Vec::new();
    col_ptr.push(0);
    for c in cols.iter_mut() {
        c.sort_unstable();
        c.dedup();
        row_idx.extend_from_slice(c);
        col_ptr.push(row_idx.len());
    }
    (col_ptr, row_idx)
}

impl Pattern {
    /// Builds the pattern of a tetrahedral mesh; `free[dof]` is the free index or `usize::MAX`.
    pub fn new(tets: &[[usize; 4]], free: &[usize], n: usize) -> Result<Self, PatternError> {
        // The fill-reducing order, from the full pattern in the caller's numbering.
        let mut cols: Vec<Vec<usize>> = vec![Vec::new(); n];
        for t in tets {
            for (_, r, c) in free_pairs(t, free) {
                cols[c].push(r);
            }
        }
        let (col_ptr, row_idx) = compress(cols);
        let full = SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx);
        let amd = factorize_symbolic_cholesky(
            full,
            Side::Lower,
            SymmetricOrdering::Amd,
            Default::default(),
        )?;
        let order: Vec<usize> = match amd.perm() {
            Some(p) => p.arrays().0.to_vec(),
            None => (0..n).collect(),
        };
        let mut internal = vec![0; n];
        for (i, &d) in order.iter().enumerate() {
            internal[d] = i;
        }
        // The same pattern renumbered: full (for the symbolic analysis, which reads the
        // pattern as given when no ordering is asked for) and its lower triangle (the values).
        let mut full_cols: Vec<Vec<usize>> = vec![Vec::new(); n];
        let mut lower_cols: Vec<Vec<usize>> = vec![Vec::new(); n];
        for c in 0..n {
            for &r in &row_idx[col_ptr[c]..col_ptr[c + 1]] {
                let (ri, ci) = (internal[r], internal[c]);
                full_cols[ci].push(ri);
                if ri >= ci {
                    lower_cols[ci].push(ri);
                }
            }
        }
        let (fcp, fri) = compress(full_cols);
        let (lcp, lri) = compress(lower_cols);
        // Supernodal: 3.1–3.4× faster than faer's automatic choice (simplicial) on these 3D
        // tetrahedral systems at 716 and 1,512 tets, and LDLᵀ no faster than LLᵀ
        // (`palpate-lab bench motion-step`, BENCHMARKS.md "A step with sensitivities").
        let symbolic = factorize_symbolic_cholesky(
            SymbolicSparseColMatRef::new_checked(n, n, &fcp, None, &fri),
            Side::Lower,
            SymmetricOrdering::Identity,
            CholeskySymbolicParams {
                supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
                ..Default::default()
            },
        )?;
        let factor_len = symbolic.len_val();
        let mut row_free = Vec::with_capacity(lri.len());
        let mut col_free = Vec::with_capacity(lri.len());
        let mut diag = vec![usize::MAX; n];
        for ci in 0..n {
            for (k, &ri) in lri.iter().enumerate().take(lcp[ci + 1]).skip(lcp[ci]) {
                row_free.push(order[ri]);
                col_free.push(order[ci]);
                if ri == ci {
                    diag[order[ci]] = k;
                }
            }
        }
        if let Some(d) = diag.iter().position(|&k| k == usize::MAX) {
            return Err(PatternError::DofInNoElement(d));
        }
        let find = |ri: usize, ci: usize| -> usize {
            let s = &lri[lcp[ci]..lcp[ci + 1]];
            lcp[ci] + s.binary_search(&ri).expect("entry in pattern")
        };
        let mut elem_ptr = Vec::with_capacity(tets.len() + 1);
        let mut elem_entries = Vec::with_capacity(78 * tets.len());
        elem_ptr.push(0);
        for t in tets {
            for (local, r, c) in free_pairs(t, free) {
                if local / 12 <= local % 12 {
                    let (ri, ci) = (internal[r], internal[c]);
                    let idx = find(ri.max(ci), ri.min(ci));
                    let idx = u32::try_from(idx).map_err(|_| PatternError::TooLarge(idx))?;
                    elem_entries.push((local as u16, idx));
                }
            }
            elem_ptr.push(elem_entries.len());
        }
        let lower = SymbolicSparseColMat::new_checked(n, n, lcp, None, lri);
        Ok(Self {
            n,
            lower,
            row_free,
            col_free,
            diag,
            elem_ptr,
            elem_entries,
            order: Arc::new(order),
            symbolic: Arc::new(symbolic),
            factor_len,
        })
    }

    /// Each stored entry's (row, column) in the caller's free-dof numbering, in the order of a
    /// value array (one entry per unordered pair: the matrices are symmetric).
    pub fn entries(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.row_free
            .iter()
            .copied()
            .zip(self.col_free.iter().copied())
    }

    /// Number of stored entries (the lower triangle): the length of a value array.
    pub fn nnz(&self) -> usize {
        self.row_free.len()
    }

    /// Adds `scale · k` (a symmetric element block, row-major; only its upper triangle r ≤ c is
    /// read) into `values`.
    pub fn add_element(&self, e: usize, k: &[[f64; 12]; 12], scale: f64, values: &mut [f64]) {
        let k = k.as_flattened();
        for &(local, idx) in self.element_entries(e) {
            values[idx as usize] += scale * k[local as usize];
        }
    }

    /// Element `e`'s scatter list: (local index 12 r + c with r ≤ c, value index) of each of its
    /// block's stored entries.
    pub fn element_entries(&self, e: usize) -> &[(u16, u32)] {
        &self.elem_entries[self.elem_ptr[e]..self.elem_ptr[e + 1]]
    }

    /// Adds two symmetric element blocks into two value arrays in one pass over the element's
    /// scatter list (K and D of one element: the list is read once, not twice).
    pub fn add_element_pair(
        &self,
        e: usize,
        (k, kvalues): (&[[f64; 12]; 12], &mut [f64]),
        (d, dvalues): (&[[f64; 12]; 12], &mut [f64]),
    ) {
        let (k, d) = (k.as_flattened(), d.as_flattened());
        for &(local, idx) in &self.elem_entries[self.elem_ptr[e]..self.elem_ptr[e + 1]] {
            kvalues[idx as usize] += k[local as usize];
            dvalues[idx as usize] += d[local as usize];
        }
    }

    /// Adds an antisymmetric element block A = −Aᵀ of element `e` (its dofs' free indices
    /// `free`, `usize::MAX` where clamped) into `values`: each stored entry holds A at its own
    /// (row, column) in the caller's numbering, the mirror being its negative
    /// ([`Self::mul_add_skew`]).
    pub fn add_element_skew(
        &self,
        e: usize,
        free: &[usize; 12],
        a: &[[f64; 12]; 12],
        values: &mut [f64],
    ) {
        for &(local, idx) in &self.elem_entries[self.elem_ptr[e]..self.elem_ptr[e + 1]] {
            let (lr, lc) = (local as usize / 12, local as usize % 12);
            if lr == lc {
                continue;
            }
            let idx = idx as usize;
            values[idx] += if self.row_free[idx] == free[lr] {
                a[lr][lc]
            } else {
                a[lc][lr]
            };
        }
    }

    /// Y += `scale` A X for the antisymmetric A that [`Self::add_element_skew`] stored in
    /// `values`, over `m` columns stored column after column (row-major copies of up to eight
    /// columns at a time, as [`Self::mul_add_difference`] does, for the same reason: each Y entry
    /// receives the same terms in the same order as a column-by-column pass).
    pub fn mul_add_skew(&self, values: &[f64], x: &[f64], y: &mut [f64], m: usize, scale: f64) {
        let n = self.n;
        for first in (0..m).step_by(8) {
            let w = (m - first).min(8);
            let cols = first * n..(first + w) * n;
            let rows = |v: &[f64]| row_major(&v[cols.clone()], n, w);
            let (xt, mut yt) = (rows(x), rows(y));
            match w {
                1 => self.skew_rows::<1>(values, scale, &xt, &mut yt),
                2 => self.skew_rows::<2>(values, scale, &xt, &mut yt),
                3 => self.skew_rows::<3>(values, scale, &xt, &mut yt),
                4 => self.skew_rows::<4>(values, scale, &xt, &mut yt),
                5 => self.skew_rows::<5>(values, scale, &xt, &mut yt),
                6 => self.skew_rows::<6>(values, scale, &xt, &mut yt),
                7 => self.skew_rows::<7>(values, scale, &xt, &mut yt),
                _ => self.skew_rows::<8>(values, scale, &xt, &mut yt),
            }
            column_major(&yt, w, &mut y[cols]);
        }
    }

    /// The entries' pass of [`Self::mul_add_skew`] on a group of `M` row-major columns.
    fn skew_rows<const M: usize>(&self, values: &[f64], scale: f64, xt: &[f64], yt: &mut [f64]) {
        let row = |r: usize| -> [f64; M] {
            let mut out = [0.0; M];
            out.copy_from_slice(&xt[r * M..(r + 1) * M]);
            out
        };
        for ((&v, &r), &c) in values.iter().zip(&self.row_free).zip(&self.col_free) {
            if r == c || v == 0.0 {
                continue;
            }
            let v = scale * v;
            let (xc, xr) = (row(c), row(r));
            for j in 0..M {
                yt[r * M + j] += v * xc[j];
            }
            for j in 0..M {
                yt[c * M + j] -= v * xr[j];
            }
        }
    }

    /// Adds a diagonal entry (lumped mass) at free dof `r`.
    pub fn add_diagonal(&self, r: usize, v: f64, values: &mut [f64]) {
        values[self.diag[r]] += v;
    }

    /// The diagonal entry at free dof `r`.
    pub fn diagonal(&self, r: usize, values: &[f64]) -> f64 {
        values[self.diag[r]]
    }

    /// y += A x for the symmetric matrix with `values` on this pattern.
    pub fn mul_add(&self, values: &[f64], x: &[f64], y: &mut [f64]) {
        for ((&v, &r), &c) in values.iter().zip(&self.row_free).zip(&self.col_free) {
            y[r] += v * x[c];
            if r != c {
                y[c] += v * x[r];
            }
        }
    }

    /// Y += a A X − B Z for the symmetric matrices A, B with values `a_values`, `b_values` on
    /// this pattern and `m` columns X, Z, Y stored column after column: the history term
    /// c M s_b − K s_a of every parameter's BDF2 sensitivity step in one pass over the entries.
    pub fn mul_add_difference(
        &self,
        (a, a_values, x): (f64, &[f64], &[f64]),
        (b_values, z): (&[f64], &[f64]),
        y: &mut [f64],
        m: usize,
    ) {
        let n = self.n;
        // Row-major copies (entry (r, j) at r w + j) of up to eight columns at a time: an
        // entry's columns are then adjacent, one cache line instead of w lines n apart, and the
        // group's width a constant, so an entry's update is a short vector operation without
        // index checks. Each Y entry receives the same terms in the same order as a
        // column-by-column pass, so the result is the same to the last bit.
        for first in (0..m).step_by(8) {
            let w = (m - first).min(8);
            let cols = first * n..(first + w) * n;
            let rows = |v: &[f64]| row_major(&v[cols.clone()], n, w);
            let (xt, zt, mut yt) = (rows(x), rows(z), rows(y));
            let pass = (a, a_values, b_values, (&xt[..], &zt[..]));
            match w {
                1 => self.difference_rows::<1>(pass, &mut yt),
                2 => self.difference_rows::<2>(pass, &mut yt),
                3 => self.difference_rows::<3>(pass, &mut yt),
                4 => self.difference_rows::<4>(pass, &mut yt),
                5 => self.difference_rows::<5>(pass, &mut yt),
                6 => self.difference_rows::<6>(pass, &mut yt),
                7 => self.difference_rows::<7>(pass, &mut yt),
                _ => self.difference_rows::<8>(pass, &mut yt),
            }
            column_major(&yt, w, &mut y[cols]);
        }
    }

    /// The entries' pass of [`Self::mul_add_difference`] on a group of `M` row-major columns.
    fn difference_rows<const M: usize>(
        &self,
        (a, a_values, b_values, (xt, zt)): (f64, &[f64], &[f64], (&[f64], &[f64])),
        yt: &mut [f64],
    ) {
        let row = |v: &[f64], r: usize| -> [f64; M] {
            let mut out = [0.0; M];
            out.copy_from_slice(&v[r * M..(r + 1) * M]);
            out
        };
        for (((&av, &bv), &r), &c) in a_values
            .iter()
            .zip(b_values)
            .zip(&self.row_free)
            .zip(&self.col_free)
        {
            let av = a * av;
            let (xc, zc) = (row(xt, c), row(zt, c));
            let yr = &mut yt[r * M..(r + 1) * M];
            for j in 0..M {
                yr[j] += av * xc[j] - bv * zc[j];
            }
            if r != c {
                let (xr, zr) = (row(xt, r), row(zt, r));
                let yc = &mut yt[c * M..(c + 1) * M];
                for j in 0..M {
                    yc[j] += av * xr[j] - bv * zr[j];
                }
            }
        }
    }

    /// Numeric Cholesky factorisation reusing the symbolic analysis; `None` if the matrix is not
    /// positive definite.
    pub fn factor(&self, values: &[f64]) -> Option<Factor> {
        if values.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let mat = SparseColMatRef::new(self.lower.as_ref(), values);
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
            order: self.order.clone(),
            values: Arc::new(out),
        })
    }

    /// Bytes of one numeric factor (L's stored values; the adjoint tape keeps one per step).
    pub fn factor_bytes(&self) -> usize {
        self.factor_len * std::mem::size_of::<f64>()
    }
}

/// The `w` columns of length `n` stored one after the other in `cols`, row-major: entry (r, j)
/// at r w + j.
fn row_major(cols: &[f64], n: usize, w: usize) -> Vec<f64> {
    let mut t = vec![0.0; n * w];
    for (j, col) in cols.chunks_exact(n).enumerate() {
        for (r, &val) in col.iter().enumerate() {
            t[r * w + j] = val;
        }
    }
    t
}

/// [`row_major`] undone: the `w` row-major columns `rows` stored column after column in `cols`.
fn column_major(rows: &[f64], w: usize, cols: &mut [f64]) {
    let n = rows.len() / w;
    for (j, col) in cols.chunks_exact_mut(n).enumerate() {
        for (r, val) in col.iter_mut().enumerate() {
            *val = rows[r * w + j];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two tetrahedra sharing a face, node 0 clamped: 12 free dofs.
    fn two_tets() -> (Vec<[usize; 4]>, Vec<usize>, usize) {
        let tets = vec![[0, 1, 2, 3], [1, 2, 3, 4]];
        let mut free = vec![usize::MAX; 15];
        for (k, d) in (3..15).enumerate() {
            free[d] = k;
        }
        (tets, free, 12)
    }

    /// A symmetric positive definite "element block": Bᵀ B + I with B fixed and element-dependent.
    fn block(e: usize) -> [[f64; 12]; 12] {
        let b = |r: usize, c: usize| ((r * 7 + c * 3 + e * 5) % 11) as f64 / 11.0 - 0.4;
        let mut k = [[0.0; 12]; 12];
        for r in 0..12 {
            for c in 0..12 {
                k[r][c] = (0..12).map(|i| b(i, r) * b(i, c)).sum::<f64>()
                    + if r == c { 1.0 } else { 0.0 };
            }
        }
        k
    }

    /// The stored lower triangle in the fill-reducing order against a dense assembly in the
    /// caller's numbering: products agree, and the factor solves the dense system (residual
    /// checked with the dense matrix, an independent reference).
    #[test]
    fn permuted_lower_triangle_matches_a_dense_assembly() {
        let (tets, free, n) = two_tets();
        let p = Pattern::new(&tets, &free, n).unwrap();
        let mut dense = vec![vec![0.0; n]; n];
        let mut values = vec![0.0; p.nnz()];
        for (e, t) in tets.iter().enumerate() {
            let k = block(e);
            p.add_element(e, &k, 2.0, &mut values);
            for r in 0..12 {
                for c in 0..12 {
                    let (fr, fc) = (free[3 * t[r / 3] + r % 3], free[3 * t[c / 3] + c % 3]);
                    if fr != usize::MAX && fc != usize::MAX {
                        dense[fr][fc] += 2.0 * k[r][c];
                    }
                }
            }
        }
        p.add_diagonal(5, 0.5, &mut values);
        dense[5][5] += 0.5;
        assert!((p.diagonal(5, &values) - dense[5][5]).abs() < 1e-12);
        let x: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin()).collect();
        let mut y = vec![0.0; n];
        p.mul_add(&values, &x, &mut y);
        for r in 0..n {
            let yd: f64 = (0..n).map(|c| dense[r][c] * x[c]).sum();
            assert!(
                (y[r] - yd).abs() < 1e-12 * (1.0 + yd.abs()),
                "row {r}: {} vs {yd}",
                y[r]
            );
        }
        let mut b = y.clone();
        p.factor(&values)
            .expect("positive definite")
            .solve_in_place(&mut b);
        for i in 0..n {
            assert!((b[i] - x[i]).abs() < 1e-10, "x[{i}] {} vs {}", b[i], x[i]);
        }
    }

    /// Y += a A X − B Z over several columns (the sensitivities' history term) against dense
    /// products in the caller's numbering, column by column.
    #[test]
    fn multi_column_difference_matches_dense_products() {
        let (tets, free, n) = two_tets();
        let p = Pattern::new(&tets, &free, n).unwrap();
        let (mut av, mut bv) = (vec![0.0; p.nnz()], vec![0.0; p.nnz()]);
        let (mut ad, mut bd) = (vec![vec![0.0; n]; n], vec![vec![0.0; n]; n]);
        for (e, t) in tets.iter().enumerate() {
            let (ka, kb) = (block(e), block(e + 3));
            p.add_element(e, &ka, 1.0, &mut av);
            p.add_element(e, &kb, 1.0, &mut bv);
            for r in 0..12 {
                for c in 0..12 {
                    let (fr, fc) = (free[3 * t[r / 3] + r % 3], free[3 * t[c / 3] + c % 3]);
                    if fr != usize::MAX && fc != usize::MAX {
                        ad[fr][fc] += ka[r][c];
                        bd[fr][fc] += kb[r][c];
                    }
                }
            }
        }
        // Three columns, and eleven: a group of eight and one of three.
        for m in [3, 11] {
            let col = |s: f64| -> Vec<f64> { (0..n * m).map(|i| (i as f64 * s).sin()).collect() };
            let (x, z, y0) = (col(0.37), col(0.61), col(0.13));
            let mut y = y0.clone();
            p.mul_add_difference((1.5, &av, &x), (&bv, &z), &mut y, m);
            // The column-by-column pass over the entries, the order the claim of equality to
            // the last bit is about.
            let mut by_column = y0.clone();
            for (((&a, &b), &r), &c) in av.iter().zip(&bv).zip(&p.row_free).zip(&p.col_free) {
                for j in 0..m {
                    let o = j * n;
                    by_column[o + r] += 1.5 * a * x[o + c] - b * z[o + c];
                    if r != c {
                        by_column[o + c] += 1.5 * a * x[o + r] - b * z[o + r];
                    }
                }
            }
            assert_eq!(y, by_column, "{m} columns: not the column-by-column sums");
            for j in 0..m {
                for r in 0..n {
                    let o = j * n;
                    let want = y0[o + r]
                        + (0..n)
                            .map(|c| 1.5 * ad[r][c] * x[o + c] - bd[r][c] * z[o + c])
                            .sum::<f64>();
                    assert!(
                        (y[o + r] - want).abs() < 1e-12 * (1.0 + want.abs()),
                        "{m} columns, column {j} row {r}: {} vs {want}",
                        y[o + r]
                    );
                }
            }
        }
    }

    /// Y += s A X for the antisymmetric parts A of non-symmetric element blocks, stored by
    /// `add_element_skew`, against the dense product in the caller's numbering, over several
    /// columns; and the same to the last bit as the column-by-column pass over the entries.
    #[test]
    fn skew_products_match_dense_products() {
        let (tets, free, n) = two_tets();
        let p = Pattern::new(&tets, &free, n).unwrap();
        let mut values = vec![0.0; p.nnz()];
        let mut ad = vec![vec![0.0; n]; n];
        for (e, t) in tets.iter().enumerate() {
            // A non-symmetric block, its antisymmetric part ½(K − Kᵀ).
            let k: [[f64; 12]; 12] = std::array::from_fn(|r| {
                std::array::from_fn(|c| ((r * 5 + c * 11 + e * 3) % 13) as f64 / 13.0 - 0.5)
            });
            let skew: [[f64; 12]; 12] =
                std::array::from_fn(|r| std::array::from_fn(|c| 0.5 * (k[r][c] - k[c][r])));
            let fr: [usize; 12] = std::array::from_fn(|l| free[3 * t[l / 3] + l % 3]);
            p.add_element_skew(e, &fr, &skew, &mut values);
            for r in 0..12 {
                for c in 0..12 {
                    if fr[r] != usize::MAX && fr[c] != usize::MAX {
                        ad[fr[r]][fr[c]] += skew[r][c];
                    }
                }
            }
        }
        for m in [3, 11] {
            let col = |s: f64| -> Vec<f64> { (0..n * m).map(|i| (i as f64 * s).sin()).collect() };
            let (x, y0) = (col(0.37), col(0.13));
            let mut y = y0.clone();
            p.mul_add_skew(&values, &x, &mut y, m, -0.7);
            let mut by_column = y0.clone();
            for ((&v, &r), &c) in values.iter().zip(&p.row_free).zip(&p.col_free) {
                if r == c || v == 0.0 {
                    continue;
                }
                for j in 0..m {
                    let o = j * n;
                    by_column[o + r] += -0.7 * v * x[o + c];
                    by_column[o + c] -= -0.7 * v * x[o + r];
                }
            }
            assert_eq!(y, by_column, "{m} columns: not the column-by-column sums");
            for j in 0..m {
                for r in 0..n {
                    let o = j * n;
                    let want = y0[o + r] - 0.7 * (0..n).map(|c| ad[r][c] * x[o + c]).sum::<f64>();
                    assert!(
                        (y[o + r] - want).abs() < 1e-12 * (1.0 + want.abs()),
                        "{m} columns, column {j} row {r}: {} vs {want}",
                        y[o + r]
                    );
                }
            }
        }
    }

    #[test]
    fn a_free_node_in_no_element_is_refused_by_name() {
        let (tets, mut free, _) = two_tets();
        free.extend([12, 13, 14]); // node 5, used by no tetrahedron
        let err = Pattern::new(&tets, &free, 15).unwrap_err();
        assert!(matches!(err, PatternError::DofInNoElement(12)), "{err}");
        assert!(err.to_string().contains("no tetrahedron"));
    }
}
