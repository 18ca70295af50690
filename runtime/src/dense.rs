//! Small dense symmetric solves in caller storage: the coarse space's A_c is factorised by
//! Cholesky once and then applied every PCG iteration.
//!
//! Storage is row-major `dim × dim`; the factor L is kept in the lower triangle (the strict upper
//! triangle is cleared), so every row of L is contiguous and both triangular sweeps read rows.

/// In-place dense Cholesky A = L Lᵀ of the `dim × dim` row-major matrix in `l[..dim²]` (only
/// the lower triangle is read). Accumulates in f64 (the f32 entries of A_c span several orders
/// of magnitude). A pivot below 1e-6 of the largest diagonal entry (a mode the matrix
/// does not control: an aggregate of one node, an unconstrained rigid motion) drops its row and
/// column — the preconditioner then does nothing in that direction instead of amplifying it.
pub fn cholesky_in_place(l: &mut [f32], dim: usize) {
    if l.len() < dim * dim {
        return;
    }
    let mut maxd = 0.0f32;
    for i in 0..dim {
        maxd = maxd.max(l[i * dim + i].abs());
    }
    let floor = 1e-6 * maxd as f64;
    for j in 0..dim {
        let mut d = l[j * dim + j] as f64;
        for k in 0..j {
            d -= l[j * dim + k] as f64 * l[j * dim + k] as f64;
        }
        if d.is_nan() || d <= floor || !d.is_finite() {
            for k in 0..dim {
                l[j * dim + k] = 0.0;
                l[k * dim + j] = 0.0;
            }
            continue;
        }
        let djj = libm::sqrt(d);
        l[j * dim + j] = djj as f32;
        for i in (j + 1)..dim {
            let mut s = l[i * dim + j] as f64;
            for k in 0..j {
                s -= l[i * dim + k] as f64 * l[j * dim + k] as f64;
            }
            l[i * dim + j] = (s / djj) as f32;
        }
    }
    for i in 0..dim {
        for j in (i + 1)..dim {
            l[i * dim + j] = 0.0;
        }
    }
}

/// Solves L Lᵀ y = g in place (`g[..dim]`), with L from [`cholesky_in_place`]; dropped modes
/// (zero pivot) come out zero.
pub fn cholesky_solve(l: &[f32], dim: usize, g: &mut [f32]) {
    if l.len() < dim * dim || g.len() < dim {
        return;
    }
    for i in 0..dim {
        let lii = l[i * dim + i];
        if lii == 0.0 {
            g[i] = 0.0;
            continue;
        }
        let s = g[i] - crate::kernel::dot_lanes(&l[i * dim..i * dim + i], &g[..i]);
        g[i] = s / lii;
    }
    // Lᵀ y = g by column sweeps: row i of L is contiguous, so each step reads one row instead of
    // a strided column (the strided form cost more than the whole element pass).
    for i in (0..dim).rev() {
        let lii = l[i * dim + i];
        if lii == 0.0 {
            g[i] = 0.0;
            continue;
        }
        let yi = g[i] / lii;
        g[i] = yi;
        let row = &l[i * dim..i * dim + i];
        for (gk, lik) in g[..i].iter_mut().zip(row) {
            *gk -= lik * yi;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// x with A x = b for a 3 × 3 A (row-major), through the factorisation in place.
    fn solve3(mut a: [f32; 9], mut b: [f32; 3]) -> [f32; 3] {
        cholesky_in_place(&mut a, 3);
        cholesky_solve(&a, 3, &mut b);
        b
    }

    /// Against a hand-checked 3 × 3 SPD system: A = [[4,2,0],[2,5,1],[0,1,3]], b = (2, 1, 4);
    /// the solution x = (0.625, −0.25, 1.4166…) satisfies A x = b; f32 storage, so 1e-5.
    #[test]
    fn solves_a_small_spd_system() {
        let g = solve3(
            [4.0, 2.0, 0.0, 2.0, 5.0, 1.0, 0.0, 1.0, 3.0],
            [2.0, 1.0, 4.0],
        );
        let a = [[4.0f32, 2.0, 0.0], [2.0, 5.0, 1.0], [0.0, 1.0, 3.0]];
        for (row, b) in a.iter().zip([2.0f32, 1.0, 4.0]) {
            let ax: f32 = row.iter().zip(g).map(|(x, y)| x * y).sum();
            assert!((ax - b).abs() < 1e-5, "A x = {ax}, b = {b}");
        }
    }

    /// A singular direction (zero row/column) is dropped: its component comes out zero and the
    /// rest is solved exactly.
    #[test]
    fn drops_a_vanishing_pivot() {
        let g = solve3(
            [2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 8.0],
            [4.0, 7.0, 16.0],
        );
        assert_eq!(g, [2.0, 0.0, 2.0]);
    }
}
