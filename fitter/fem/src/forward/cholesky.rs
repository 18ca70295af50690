//! The sparse Cholesky factorisation LLᵀ of the static stiffness over the free dofs: faer's
//! supernodal form after an AMD ordering, its analysis made once per pattern.
//!
//! faer's automatic choice (`SymbolicLlt::try_new`) takes the simplicial form for these 3D
//! tetrahedral systems, whose flops per stored entry of L fall below its threshold; the
//! supernodal form factorises them 3.1–3.4× faster at 716 and 1,512 tets
//! (`palpate-lab bench motion-step`, BENCHMARKS.md "A step with sensitivities"). On the
//! specimens' and the blocks' meshes the simplicial factorisation was the largest item of a static
//! diagnosis; on larger meshes faer chooses the supernodal form itself (BENCHMARKS.md "The static
//! solver's factorisation").

use std::sync::Arc;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky,
    SymmetricOrdering,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Side};

use super::ForwardError;

/// The ordering and elimination structure of one pattern (its lower triangle is read), shared
/// by every factorisation of values on that pattern.
#[derive(Debug, Clone)]
pub(super) struct Symbolic(Arc<SymbolicCholesky<usize>>);

impl Symbolic {
    /// The analysis of `pattern` (square, both triangles or the lower one stored).
    pub(super) fn new(pattern: SymbolicSparseColMatRef<'_, usize>) -> Result<Self, ForwardError> {
        factorize_symbolic_cholesky(
            pattern,
            Side::Lower,
            SymmetricOrdering::Amd,
            CholeskySymbolicParams {
                supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
                ..Default::default()
            },
        )
        .map(|s| Self(Arc::new(s)))
        .map_err(|e| ForwardError::Sparse(format!("symbolic Cholesky: {e:?}")))
    }

    /// L of `matrix` (values on the analysed pattern); an error where it is not positive
    /// definite.
    pub(super) fn factor(
        &self,
        matrix: SparseColMatRef<'_, usize, f64>,
    ) -> Result<Llt, ForwardError> {
        let par = faer::get_global_parallelism();
        let mut values = vec![0.0; self.0.len_val()];
        let mut buf = MemBuffer::new(
            self.0
                .factorize_numeric_llt_scratch::<f64>(par, Default::default()),
        );
        self.0
            .factorize_numeric_llt(
                &mut values,
                matrix,
                Side::Lower,
                Default::default(),
                par,
                MemStack::new(&mut buf),
                Default::default(),
            )
            .map_err(|e| ForwardError::Factorisation(format!("{e:?}")))?;
        Ok(Llt {
            symbolic: self.0.clone(),
            values,
        })
    }
}

/// A numeric factor LLᵀ ([`Symbolic::factor`]).
#[derive(Debug, Clone)]
pub(super) struct Llt {
    symbolic: Arc<SymbolicCholesky<usize>>,
    values: Vec<f64>,
}

impl Llt {
    /// Solves A X = B in place (B's columns in the matrix's numbering).
    pub(super) fn solve_in_place(&self, b: MatMut<'_, f64>) {
        let par = faer::get_global_parallelism();
        let mut buf = MemBuffer::new(self.symbolic.solve_in_place_scratch::<f64>(b.ncols(), par));
        LltRef::new(&self.symbolic, &self.values).solve_in_place_with_conj(
            Conj::No,
            b,
            par,
            MemStack::new(&mut buf),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::sparse::linalg::cholesky::SymbolicCholeskyRaw;
    use faer::sparse::{SparseColMat, Triplet};
    use nalgebra::{DMatrix, DVector};

    /// A 7-point Laplacian on an m³ grid plus `shift` on the diagonal, both triangles stored:
    /// the fill of a 3D mesh, small enough for a dense reference.
    fn grid(m: usize, shift: f64) -> (SparseColMat<usize, f64>, DMatrix<f64>) {
        let n = m * m * m;
        let id = |i: usize, j: usize, k: usize| (i * m + j) * m + k;
        let mut dense = DMatrix::<f64>::zeros(n, n);
        for i in 0..m {
            for j in 0..m {
                for k in 0..m {
                    let a = id(i, j, k);
                    dense[(a, a)] = 6.0 + shift;
                    for (di, dj, dk) in [(1, 0, 0), (0, 1, 0), (0, 0, 1)] {
                        let (p, q, r) = (i + di, j + dj, k + dk);
                        if p < m && q < m && r < m {
                            let b = id(p, q, r);
                            dense[(a, b)] = -1.0;
                            dense[(b, a)] = -1.0;
                        }
                    }
                }
            }
        }
        let trip: Vec<_> = (0..n)
            .flat_map(|c| (0..n).map(move |r| (r, c)))
            .filter(|&(r, c)| dense[(r, c)] != 0.0)
            .map(|(r, c)| Triplet::new(r, c, dense[(r, c)]))
            .collect();
        (
            SparseColMat::try_new_from_triplets(n, n, &trip).unwrap(),
            dense,
        )
    }

    /// The supernodal factor (where faer's automatic choice would take the simplicial one)
    /// solves what nalgebra's dense Cholesky solves, for two right-hand sides at once.
    #[test]
    fn the_supernodal_factor_solves_as_a_dense_cholesky_does() {
        let (sparse, dense) = grid(6, 0.01);
        let n = dense.nrows();
        let symbolic = Symbolic::new(sparse.symbolic()).unwrap();
        assert!(matches!(
            symbolic.0.raw(),
            SymbolicCholeskyRaw::Supernodal(_)
        ));
        let automatic = factorize_symbolic_cholesky(
            sparse.symbolic(),
            Side::Lower,
            SymmetricOrdering::Amd,
            Default::default(),
        )
        .unwrap();
        assert!(matches!(
            automatic.raw(),
            SymbolicCholeskyRaw::Simplicial(_)
        ));
        let llt = symbolic.factor(sparse.as_ref()).unwrap();
        let b: Vec<f64> = (0..2 * n).map(|i| ((i * 37) % 11) as f64 - 5.0).collect();
        let mut x = b.clone();
        llt.solve_in_place(MatMut::from_column_major_slice_mut(&mut x, n, 2));
        let reference = dense.clone().cholesky().unwrap();
        for c in 0..2 {
            let want = reference.solve(&DVector::from_column_slice(&b[c * n..(c + 1) * n]));
            let err = (0..n)
                .map(|i| (x[c * n + i] - want[i]).abs())
                .fold(0.0, f64::max);
            assert!(err < 1e-10 * want.amax(), "column {c}: {err:e}");
        }
    }

    /// A matrix that is not positive definite is an error, not a panic or a wrong solve.
    #[test]
    fn an_indefinite_matrix_is_refused() {
        let (sparse, _) = grid(4, -7.0);
        let symbolic = Symbolic::new(sparse.symbolic()).unwrap();
        assert!(matches!(
            symbolic.factor(sparse.as_ref()),
            Err(ForwardError::Factorisation(_))
        ));
    }
}
