//! Preconditioned conjugate gradients on a constrained (projected) space, in caller buffers.
//!
//! Why a free function over traits: the solver is the part of a tick most worth testing on its
//! own and most likely to be tuned; with the operator, the preconditioner and the constraint
//! filter behind [`LinearOperator`], [`Preconditioner`] and [`Projection`] it can be (a small
//! dense matrix in the tests, K' = Σ R_e K_e R_eᵀ in the runtime). The shape follows faer's
//! `conjugate_gradient` (an operator, a preconditioner, caller storage, a typed result), without
//! allocation and for one right-hand side.
//!
//! Constraints are filters on the CG vectors (modified PCG, Baraff & Witkin 1998): the system is
//! S A S x = S b for the projection S; r = S(b − A x) drives the iteration while
//! `r_full` = b − A x is tracked unfiltered beside it, because at constrained nodes it is the
//! reaction (the force the runtime renders).

use crate::error::RuntimeError;
use crate::storage::{Carver, Dims, RoomLayout};

/// ‖v‖₂ (accumulated in f64 with independent partial sums, see
/// [`crate::kernel::norm2_lanes`]).
pub fn norm(v: &[f32]) -> f32 {
    libm::sqrt(crate::kernel::norm2_lanes(v)) as f32
}

/// a · b (independent partial sums, see [`crate::kernel::dot_lanes`]).
pub fn dot(a: &[f32], b: &[f32]) -> f32 {
    crate::kernel::dot_lanes(a, b)
}

/// dst ← src over the common length (a length mismatch truncates instead of panicking).
#[inline(always)]
fn copy(dst: &mut [f32], src: &[f32]) {
    let k = dst.len().min(src.len());
    dst[..k].copy_from_slice(&src[..k]);
}

/// A symmetric operator A, applied without being stored.
pub trait LinearOperator {
    /// y = A x. `&mut self`: an operator may sum through its own scratch (the runtime's goes
    /// through an element-force buffer).
    fn apply(&mut self, x: &[f32], y: &mut [f32]);
}

/// The constraint filter S: an orthogonal projection onto the free directions, block diagonal in
/// nodes of 3 values (each node is constrained on its own), so [`pcg`] can apply it node by node
/// inside its update pass.
pub trait Projection {
    /// (S v)_i of node `i`, whose values are `v`.
    fn project_node(&self, i: usize, v: [f32; 3]) -> [f32; 3];

    /// v ← S v, node by node.
    fn project(&self, v: &mut [f32]) {
        for (i, c) in v.chunks_exact_mut(3).enumerate() {
            let o = self.project_node(i, [c[0], c[1], c[2]]);
            c.copy_from_slice(&o);
        }
    }
}

/// No constraints: S = I.
impl Projection for () {
    fn project_node(&self, _i: usize, v: [f32; 3]) -> [f32; 3] {
        v
    }

    fn project(&self, _v: &mut [f32]) {}
}

/// A symmetric positive-definite approximation M⁻¹ of A⁻¹ on the projected space, split into a
/// block-diagonal part (node blocks of 3, applied by [`pcg`] inside its update pass, where it
/// costs nothing beside the residual's reduction) and a global remainder.
pub trait Preconditioner {
    /// The block-diagonal part of M⁻¹ for node `i`, whose residual is `r`.
    fn apply_node(&self, i: usize, r: [f32; 3]) -> [f32; 3];

    /// Completes z = S M⁻¹ r, given z = the block-diagonal part: adds the global part and
    /// projects, so the search directions stay in range(S).
    fn finish(&mut self, r: &[f32], z: &mut [f32]);

    /// z = S M⁻¹ r.
    fn apply(&mut self, r: &[f32], z: &mut [f32]) {
        for (i, (ri, zi)) in r.chunks_exact(3).zip(z.chunks_exact_mut(3)).enumerate() {
            let o = self.apply_node(i, [ri[0], ri[1], ri[2]]);
            zi.copy_from_slice(&o);
        }
        self.finish(r, z);
    }
}

/// When [`pcg`] stops.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CgParams {
    /// Converged when ‖S r‖₂ ≤ this (absolute; the caller scales it).
    pub tolerance: f32,
    /// Iterations allowed (the budget).
    pub max_iterations: u32,
}

/// A converged solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CgInfo {
    /// Iterations used (0 when the initial iterate already met the tolerance).
    pub iterations: u32,
    /// ‖S r‖₂ at exit.
    pub residual: f32,
}

/// A solve that did not converge. In every case `x` and `r_full` are consistent (r_full =
/// b − A x up to round-off); after [`CgError::NoConvergence`] the iterate is the last one, the
/// best the budget allowed, and usable.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CgError {
    /// The budget ran out with ‖S r‖₂ above the tolerance.
    NoConvergence {
        /// Iterations used (the budget).
        iterations: u32,
        /// ‖S r‖₂ at exit.
        residual: f32,
    },
    /// pᵀ A p was not positive and finite: A is not positive definite on range(S), or a value
    /// became non-finite. Nothing was updated in that iteration.
    Breakdown {
        /// Iterations completed before.
        iterations: u32,
        /// ‖S r‖₂ before the failed iteration.
        residual: f32,
    },
    /// The residual became non-finite.
    NonFinite {
        /// Iterations completed (including the one that failed).
        iterations: u32,
        /// The non-finite ‖S r‖₂.
        residual: f32,
    },
}

/// The PCG's vectors, as long as the system (3 per node in the runtime): carved once, reused by
/// every solve.
pub struct PcgWork<'a> {
    /// Projected residual S(b − A x).
    pub r: &'a mut [f32],
    /// Preconditioned residual S M⁻¹ r.
    pub z: &'a mut [f32],
    /// Search direction.
    pub p: &'a mut [f32],
    /// A p.
    pub q: &'a mut [f32],
}

impl<'a> PcgWork<'a> {
    /// The room's arrays in the runtime, in carving order (see [`crate::storage::Layout`]).
    pub(crate) const fn layout(d: &Dims) -> RoomLayout<4, 0> {
        let v = 3 * d.nodes;
        RoomLayout {
            f32s: [v, v, v, v],
            u32s: [],
        }
    }

    /// Cuts the room from the pools (zeroed).
    pub(crate) fn carve(
        layout: RoomLayout<4, 0>,
        f: &mut Carver<'a, f32>,
        u: &mut Carver<'a, u32>,
    ) -> Result<Self, RuntimeError> {
        let ([r, z, p, q], []) = layout.carve(f, u)?;
        Ok(Self { r, z, p, q })
    }
}

/// The predictor: x ← c d with c = (dᵀ r)/(dᵀ A d) for the filtered direction d = S `direction`,
/// the energy-optimal multiple of d (a one-dimensional Galerkin projection, so the error in the
/// energy norm never grows). In the runtime d is the previous tick's increment: a probe sliding
/// at constant speed makes the same increment every tick, so this removes most of the residual
/// for one A product; after an abrupt change c ≈ 0 and nothing is lost but that product.
///
/// Expects x = 0, `r_full` = b and `work.r` = S b; updates x and `r_full` (r_full −= c A d) and
/// returns whether it did (false when d is zero or dᵀ A d is not positive, or c not finite).
/// `work.p` and `work.q` are overwritten; `work.r` is left for [`pcg`] to recompute.
pub fn predict<A: LinearOperator + ?Sized, S: Projection + ?Sized>(
    a: &mut A,
    s: &S,
    direction: &[f32],
    x: &mut [f32],
    r_full: &mut [f32],
    work: &mut PcgWork<'_>,
) -> bool {
    copy(work.p, direction);
    s.project(work.p);
    if dot(work.p, work.p) == 0.0 {
        return false;
    }
    a.apply(work.p, work.q);
    let pq = dot(work.p, work.q);
    // p is filtered, so p·r_full = p·r.
    let c = dot(work.p, work.r) / pq;
    if !(pq > 0.0 && c.is_finite()) {
        return false;
    }
    for (d, p) in x.iter_mut().zip(work.p.iter()) {
        *d = c * p;
    }
    for (r, q) in r_full.iter_mut().zip(work.q.iter()) {
        *r -= c * q;
    }
    true
}

/// Most directions [`predict_subspace`] combines.
pub const MAX_DIRECTIONS: usize = 3;

/// The predictor on a subspace: x ← Σ c_j S d_j with the c that minimise the energy
/// ½ xᵀ A x − xᵀ b over the span of the filtered directions (a Galerkin projection of up to
/// [`MAX_DIRECTIONS`] dimensions, one A product each, so the error in the energy norm never
/// grows) — [`predict`] for several directions at once. Directions that are zero after the
/// filter are skipped; a combination the small system cannot determine (dependent directions)
/// drops the dependent ones.
///
/// Expects x = 0, `r_full` = b and `r` = S b; `scratch` holds two vectors per direction (the
/// filtered direction and its product). Updates x and `r_full` and returns whether it moved x.
pub fn predict_subspace<A: LinearOperator + ?Sized, S: Projection + ?Sized>(
    a: &mut A,
    s: &S,
    directions: &[&[f32]],
    x: &mut [f32],
    r_full: &mut [f32],
    r: &[f32],
    scratch: &mut [&mut [f32]],
) -> bool {
    let (sd, kd) = scratch.split_at_mut(scratch.len() / 2);
    let mut k = 0;
    for d in directions.iter().take(MAX_DIRECTIONS.min(sd.len())) {
        copy(sd[k], d);
        s.project(sd[k]);
        if dot(sd[k], sd[k]) > 0.0 {
            a.apply(sd[k], kd[k]);
            k += 1;
        }
    }
    if k == 0 {
        return false;
    }
    // G c = g with G_ij = d_iᵀ A d_j, g_j = d_jᵀ b (d filtered, so d·r_full = d·r).
    let mut g = [0.0f32; MAX_DIRECTIONS * MAX_DIRECTIONS];
    let mut c = [0.0f32; MAX_DIRECTIONS];
    for i in 0..k {
        for j in 0..=i {
            let v = dot(sd[i], kd[j]);
            g[i * k + j] = v;
            g[j * k + i] = v;
        }
        c[i] = dot(sd[i], r);
    }
    crate::dense::cholesky_in_place(&mut g[..k * k], k);
    crate::dense::cholesky_solve(&g[..k * k], k, &mut c[..k]);
    if !c[..k].iter().all(|v| v.is_finite()) || c[..k].iter().all(|v| *v == 0.0) {
        return false;
    }
    x.iter_mut().for_each(|v| *v = 0.0);
    for j in 0..k {
        for ((xd, d), (r, q)) in x
            .iter_mut()
            .zip(sd[j].iter())
            .zip(r_full.iter_mut().zip(kd[j].iter()))
        {
            *xd += c[j] * d;
            *r -= c[j] * q;
        }
    }
    true
}

/// Preconditioned CG for S A S x = S b from the iterate `x`, where on entry `r_full` = b − A x
/// (unfiltered). Updates `x` and `r_full` in place; `work` is scratch. Stops when ‖S r‖₂ ≤
/// `params.tolerance` ([`CgInfo`]), when the budget runs out ([`CgError::NoConvergence`], the
/// iterate kept), or on breakdown. The vectors hold nodes of 3 values. Never allocates, never
/// panics (mismatched lengths are truncated to the shortest whole number of nodes).
pub fn pcg<A, M, S>(
    a: &mut A,
    m: &mut M,
    s: &S,
    x: &mut [f32],
    r_full: &mut [f32],
    work: &mut PcgWork<'_>,
    params: CgParams,
) -> Result<CgInfo, CgError>
where
    A: LinearOperator + ?Sized,
    M: Preconditioner + ?Sized,
    S: Projection + ?Sized,
{
    let mut carry = pcg_start(m, s, r_full, work, params.tolerance);
    pcg_iterate(a, m, s, x, r_full, work, &mut carry, params)
}

/// What CG carries from one iteration to the next besides its vectors: rᵀz and ‖S r‖₂. With the
/// vectors of a [`PcgWork`] that persists, a solve can be resumed where it stopped
/// ([`pcg_iterate`]), e.g. a few iterations per haptic tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CgCarry {
    /// rᵀ z of the current residual.
    pub rz: f32,
    /// ‖S r‖₂ of the current residual.
    pub rnorm: f32,
}

/// Starts a PCG solve from `r_full` = b − A x: r = S r_full, and — unless ‖r‖ ≤ `tolerance`
/// already, when there is nothing to solve and the preconditioner is skipped ([`pcg_iterate`]
/// then stops at once) — z = S M⁻¹ r and p = z.
pub fn pcg_start<M, S>(
    m: &mut M,
    s: &S,
    r_full: &[f32],
    work: &mut PcgWork<'_>,
    tolerance: f32,
) -> CgCarry
where
    M: Preconditioner + ?Sized,
    S: Projection + ?Sized,
{
    let PcgWork { r, z, p, .. } = work;
    copy(r, r_full);
    s.project(r);
    let rnorm = norm(r);
    if rnorm <= tolerance {
        return CgCarry { rz: 0.0, rnorm };
    }
    m.apply(r, z);
    copy(p, z);
    CgCarry {
        rz: dot(r, z),
        rnorm,
    }
}

/// The iterations of [`pcg`] from a started (or earlier interrupted) solve whose vectors are in
/// `work` and scalars in `carry`, at most `params.max_iterations` of them; `carry` is updated so a
/// later call goes on where this one stopped. The outcomes are [`pcg`]'s.
#[allow(clippy::too_many_arguments)]
pub fn pcg_iterate<A, M, S>(
    a: &mut A,
    m: &mut M,
    s: &S,
    x: &mut [f32],
    r_full: &mut [f32],
    work: &mut PcgWork<'_>,
    carry: &mut CgCarry,
    params: CgParams,
) -> Result<CgInfo, CgError>
where
    A: LinearOperator + ?Sized,
    M: Preconditioner + ?Sized,
    S: Projection + ?Sized,
{
    let tol = params.tolerance;
    let PcgWork { r, z, p, q } = work;
    let CgCarry { mut rz, mut rnorm } = *carry;
    let mut it = 0;
    while it < params.max_iterations {
        if rnorm <= tol {
            return Ok(CgInfo {
                iterations: it,
                residual: rnorm,
            });
        }
        a.apply(p, q);
        // p is filtered, so p·(S q) = p·q.
        let pq = dot(p, q);
        if pq.is_nan() || pq <= 0.0 || !pq.is_finite() {
            return Err(CgError::Breakdown {
                iterations: it,
                residual: rnorm,
            });
        }
        let alpha = rz / pq;
        // One pass, node by node: x += αp, r_full −= αq (unfiltered: reactions at constrained
        // nodes), r −= α S q, the block-diagonal part of z, and ‖r‖² on the way (f64, in index
        // order); the stores hide under the reduction's dependency chain.
        let mut rr = 0.0f64;
        let nodes = x
            .chunks_exact_mut(3)
            .zip(p.chunks_exact(3))
            .zip(r_full.chunks_exact_mut(3))
            .zip(q.chunks_exact(3))
            .zip(r.chunks_exact_mut(3).zip(z.chunks_exact_mut(3)));
        for (i, ((((xi, pi), rfi), qi), (ri, zi))) in nodes.enumerate() {
            for (d, p) in xi.iter_mut().zip(pi) {
                *d += alpha * p;
            }
            let qi = [qi[0], qi[1], qi[2]];
            for (r, q) in rfi.iter_mut().zip(qi) {
                *r -= alpha * q;
            }
            let sq = s.project_node(i, qi);
            let mut rn = [0.0f32; 3];
            for k in 0..3 {
                rn[k] = ri[k] - alpha * sq[k];
                ri[k] = rn[k];
                rr += (rn[k] as f64) * (rn[k] as f64);
            }
            zi.copy_from_slice(&m.apply_node(i, rn));
        }
        // The global part of the preconditioner (r is filtered), then z is filtered.
        m.finish(r, z);
        let rz_new = dot(r, z);
        let beta = rz_new / rz;
        rz = rz_new;
        for (pk, zk) in p.iter_mut().zip(z.iter()) {
            *pk = zk + beta * *pk;
        }
        rnorm = libm::sqrt(rr) as f32;
        it += 1;
        *carry = CgCarry { rz, rnorm };
        if !rnorm.is_finite() {
            return Err(CgError::NonFinite {
                iterations: it,
                residual: rnorm,
            });
        }
    }
    if rnorm <= tol {
        Ok(CgInfo {
            iterations: it,
            residual: rnorm,
        })
    } else {
        Err(CgError::NoConvergence {
            iterations: it,
            residual: rnorm,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dense symmetric matrix, row-major.
    struct Dense<'m> {
        n: usize,
        a: &'m [f32],
    }

    impl LinearOperator for Dense<'_> {
        fn apply(&mut self, x: &[f32], y: &mut [f32]) {
            for (i, yi) in y.iter_mut().enumerate().take(self.n) {
                *yi = (0..self.n).map(|j| self.a[i * self.n + j] * x[j]).sum();
            }
        }
    }

    /// Jacobi, optionally zeroing one constrained component.
    struct Diag<'m> {
        n: usize,
        a: &'m [f32],
        fixed: Option<usize>,
    }

    impl Preconditioner for Diag<'_> {
        fn apply_node(&self, i: usize, r: [f32; 3]) -> [f32; 3] {
            core::array::from_fn(|k| r[k] / self.a[(3 * i + k) * self.n + 3 * i + k])
        }

        fn finish(&mut self, _r: &[f32], z: &mut [f32]) {
            if let Some(k) = self.fixed {
                Fix(k).project(z);
            }
        }
    }

    /// Unknown `.0` fixed.
    struct Fix(usize);

    impl Projection for Fix {
        fn project_node(&self, i: usize, mut v: [f32; 3]) -> [f32; 3] {
            if self.0 / 3 == i {
                v[self.0 % 3] = 0.0;
            }
            v
        }
    }

    /// The four work vectors of one solve, zeroed; `work` lends them to [`pcg`] / [`predict`].
    struct Buffers {
        r: std::vec::Vec<f32>,
        z: std::vec::Vec<f32>,
        p: std::vec::Vec<f32>,
        q: std::vec::Vec<f32>,
    }

    impl Buffers {
        fn new(n: usize) -> Self {
            Self {
                r: std::vec![0.0f32; n],
                z: std::vec![0.0f32; n],
                p: std::vec![0.0f32; n],
                q: std::vec![0.0f32; n],
            }
        }

        fn work(&mut self) -> PcgWork<'_> {
            PcgWork {
                r: &mut self.r,
                z: &mut self.z,
                p: &mut self.p,
                q: &mut self.q,
            }
        }
    }

    /// A 1-D Laplacian plus identity (SPD, well conditioned).
    fn laplacian(n: usize) -> std::vec::Vec<f32> {
        let mut a = std::vec![0.0f32; n * n];
        for i in 0..n {
            a[i * n + i] = 3.0;
            if i > 0 {
                a[i * n + i - 1] = -1.0;
            }
            if i + 1 < n {
                a[i * n + i + 1] = -1.0;
            }
        }
        a
    }

    fn solve(
        a: &[f32],
        b: &[f32],
        fixed: Option<usize>,
        max_iterations: u32,
    ) -> (
        std::vec::Vec<f32>,
        std::vec::Vec<f32>,
        Result<CgInfo, CgError>,
    ) {
        let n = b.len();
        let mut x = std::vec![0.0f32; n];
        let mut r_full = b.to_vec();
        let mut buffers = Buffers::new(n);
        let mut work = buffers.work();
        let params = CgParams {
            tolerance: 1e-5,
            max_iterations,
        };
        let mut op = Dense { n, a };
        let mut m = Diag { n, a, fixed };
        let res = match fixed {
            Some(k) => pcg(
                &mut op,
                &mut m,
                &Fix(k),
                &mut x,
                &mut r_full,
                &mut work,
                params,
            ),
            None => pcg(&mut op, &mut m, &(), &mut x, &mut r_full, &mut work, params),
        };
        (x, r_full, res)
    }

    fn residual(a: &[f32], b: &[f32], x: &[f32]) -> std::vec::Vec<f32> {
        let n = b.len();
        (0..n)
            .map(|i| b[i] - (0..n).map(|j| a[i * n + j] * x[j]).sum::<f32>())
            .collect()
    }

    #[test]
    fn converges_and_tracks_the_residual() {
        let n = 12;
        let a = laplacian(n);
        let b: std::vec::Vec<f32> = (0..n).map(|i| 1.0 + i as f32 * 0.25).collect();
        let (x, r_full, res) = solve(&a, &b, None, 50);
        let info = res.expect("converges");
        assert!(info.iterations > 0 && info.iterations <= n as u32);
        assert!(info.residual <= 1e-5);
        for (t, r) in residual(&a, &b, &x).iter().zip(&r_full) {
            assert!((t - r).abs() < 1e-4, "{t} vs {r}");
        }
    }

    #[test]
    fn budget_exhausted_keeps_a_usable_iterate() {
        let n = 12;
        let a = laplacian(n);
        let b = std::vec![1.0f32; n];
        let (x, r_full, res) = solve(&a, &b, None, 2);
        match res {
            Err(CgError::NoConvergence {
                iterations,
                residual,
            }) => {
                assert_eq!(iterations, 2);
                assert!(residual > 1e-5 && residual < norm(&b));
            }
            other => panic!("expected NoConvergence, got {other:?}"),
        }
        assert!(norm(&residual(&a, &b, &x)) < norm(&b));
        assert!(norm(&r_full) < norm(&b));
    }

    #[test]
    fn projection_keeps_the_constrained_component_and_reports_its_reaction() {
        let n = 9;
        let a = laplacian(n);
        let b = std::vec![1.0f32; n];
        let (x, r_full, res) = solve(&a, &b, Some(3), 50);
        assert!(res.is_ok());
        assert_eq!(x[3], 0.0);
        // Free rows are solved; the fixed row keeps its reaction b − A x.
        let t = residual(&a, &b, &x);
        for i in 0..n {
            if i != 3 {
                assert!(t[i].abs() < 1e-4);
            }
            assert!((t[i] - r_full[i]).abs() < 1e-4);
        }
        assert!(r_full[3].abs() > 0.1);
    }

    #[test]
    fn indefinite_operator_breaks_down() {
        let n = 6;
        let mut a = laplacian(n);
        a[0] = -3.0;
        let b = std::vec![1.0f32, 0.0, 0.0, 0.0, 0.0, 0.0];
        // A positive preconditioner (the Laplacian's diagonal), so the breakdown is A's.
        let lap = laplacian(n);
        let mut x = std::vec![0.0f32; n];
        let mut r_full = b.clone();
        let mut buffers = Buffers::new(n);
        let mut work = buffers.work();
        let res = pcg(
            &mut Dense { n, a: &a },
            &mut Diag {
                n,
                a: &lap,
                fixed: None,
            },
            &(),
            &mut x,
            &mut r_full,
            &mut work,
            CgParams {
                tolerance: 1e-6,
                max_iterations: 10,
            },
        );
        assert!(matches!(res, Err(CgError::Breakdown { iterations: 0, .. })));
        assert_eq!(x, std::vec![0.0f32; n]);
    }

    #[test]
    fn subspace_predictor_is_exact_when_the_solution_is_in_the_span() {
        let n = 6;
        let a = laplacian(n);
        // The solution is 2 e₁ − 0.5 (1, …, 1): in the span of e₁ and the ones, not of either.
        let xs: std::vec::Vec<f32> = (0..n).map(|i| if i == 1 { 1.5 } else { -0.5 }).collect();
        let b: std::vec::Vec<f32> = (0..n)
            .map(|i| (0..n).map(|j| a[i * n + j] * xs[j]).sum())
            .collect();
        let e1: std::vec::Vec<f32> = (0..n).map(|i| if i == 1 { 3.0 } else { 0.0 }).collect();
        let ones = std::vec![1.0f32; n];
        let zero = std::vec![0.0f32; n];
        let mut x = std::vec![0.0f32; n];
        let mut r_full = b.clone();
        let mut s: std::vec::Vec<std::vec::Vec<f32>> =
            (0..6).map(|_| std::vec![0.0f32; n]).collect();
        let mut scratch: std::vec::Vec<&mut [f32]> =
            s.iter_mut().map(|v| v.as_mut_slice()).collect();
        let mut op = Dense { n, a: &a };
        // A zero direction is skipped.
        let dirs: [&[f32]; 3] = [&zero, &e1, &ones];
        assert!(predict_subspace(
            &mut op,
            &(),
            &dirs,
            &mut x,
            &mut r_full,
            &b,
            &mut scratch
        ));
        for (xi, si) in x.iter().zip(&xs) {
            assert!((xi - si).abs() < 1e-5, "{x:?}");
        }
        assert!(norm(&r_full) < 1e-4);
        // One direction alone is the 1-D predictor.
        let (mut x1, mut r1) = (std::vec![0.0f32; n], b.clone());
        let (mut x2, mut r2) = (std::vec![0.0f32; n], b.clone());
        assert!(predict_subspace(
            &mut op,
            &(),
            &[&ones],
            &mut x1,
            &mut r1,
            &b,
            &mut scratch
        ));
        let mut buffers = Buffers::new(n);
        buffers.r.copy_from_slice(&b);
        let mut work = buffers.work();
        assert!(predict(&mut op, &(), &ones, &mut x2, &mut r2, &mut work));
        for ((p, q), (u, v)) in x1.iter().zip(&x2).zip(r1.iter().zip(&r2)) {
            assert!((p - q).abs() < 1e-6 && (u - v).abs() < 1e-5);
        }
        // With only zero directions nothing moves.
        let mut x3 = std::vec![0.0f32; n];
        let dirs: [&[f32]; 1] = [&zero];
        assert!(!predict_subspace(
            &mut op,
            &(),
            &dirs,
            &mut x3,
            &mut r1,
            &b,
            &mut scratch
        ));
        assert!(x3.iter().all(|v| *v == 0.0));
    }

    #[test]
    fn predictor_is_exact_along_the_solution() {
        let n = 6;
        let a = laplacian(n);
        let xs: std::vec::Vec<f32> = (0..n).map(|i| (i as f32 - 2.0) * 0.5).collect();
        let b: std::vec::Vec<f32> = (0..n)
            .map(|i| (0..n).map(|j| a[i * n + j] * xs[j]).sum())
            .collect();
        let mut x = std::vec![0.0f32; n];
        let mut r_full = b.clone();
        let mut buffers = Buffers::new(n);
        buffers.r.copy_from_slice(&b);
        let mut work = buffers.work();
        let dir: std::vec::Vec<f32> = xs.iter().map(|v| 2.0 * v).collect();
        assert!(predict(
            &mut Dense { n, a: &a },
            &(),
            &dir,
            &mut x,
            &mut r_full,
            &mut work
        ));
        for (xi, si) in x.iter().zip(&xs) {
            assert!((xi - si).abs() < 1e-5);
        }
        assert!(norm(&r_full) < 1e-4);
        assert!(!predict(
            &mut Dense { n, a: &a },
            &(),
            &std::vec![0.0f32; n],
            &mut x,
            &mut r_full,
            &mut work
        ));
    }
}
