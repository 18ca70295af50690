//! Two-level preconditioner: a coarse space of rigid-body modes on spatial aggregates of nodes,
//! added to the block-Jacobi smoother (additive two-level Schwarz).
//!
//! Why: block Jacobi only removes local error. When the probe's loaded node set changes by one
//! node the residual is a *local* force whose response is *global* and smooth, and block-Jacobi
//! CG needs ~80 iterations to reach 1e-4 on 5k tets. Six rigid modes (three translations, three
//! rotations) per aggregate span exactly that smooth response, so a small dense coarse solve
//! removes it in one step.
//!
//! The coarse matrix A_c = Pᵀ K₀ P is built once from the rest stiffness (R_e = I) with the first
//! parameter set and factorised by dense Cholesky in the caller's storage; it is not rebuilt per
//! tick (rotations change K' = Σ R_e K_e R_eᵀ slowly, and a preconditioner only needs to be
//! close). Modes whose pivot vanishes (aggregates of one node, or of fixed nodes only) are
//! dropped.

use crate::kernel::warped_apply;

/// Coarse-space sizes for `n` nodes and a requested aggregate count.
pub fn aggregate_capacity(requested: u32, nodes: usize) -> usize {
    (requested as usize).min(nodes / 8)
}

/// f32 values the coarse space needs for `m` aggregates: centroids and scales (4m), the coarse
/// vector (6m) and the dense factor ((6m)²).
pub const fn coarse_f32s(m: usize) -> usize {
    4 * m + 6 * m + 36 * m * m
}

/// Mode `k` (0..6) of aggregate with centroid `c` and scale `s` at a node at `x`.
#[inline(always)]
fn mode(k: usize, x: [f32; 3], c: &[f32], s: f32) -> [f32; 3] {
    if k < 3 {
        let mut v = [0.0; 3];
        v[k] = 1.0;
        v
    } else {
        let d = [(x[0] - c[0]) / s, (x[1] - c[1]) / s, (x[2] - c[2]) / s];
        // e_j × d
        match k - 3 {
            0 => [0.0, -d[2], d[1]],
            1 => [d[2], 0.0, -d[0]],
            _ => [-d[1], d[0], 0.0],
        }
    }
}

/// The coarse space, borrowing the runtime's storage.
pub struct Coarse<'a> {
    /// Number of aggregates in use.
    pub m: usize,
    /// Aggregate of each node (`u32::MAX` for fixed nodes).
    pub agg: &'a mut [u32],
    /// Centroid (3) and inverse scale 1/s (1) per aggregate (s while building).
    pub geo: &'a mut [f32],
    /// Coarse vector (6m).
    pub g: &'a mut [f32],
    /// Dense lower Cholesky factor, row-major (6m × 6m).
    pub l: &'a mut [f32],
}

impl<'a> Coarse<'a> {
    /// Cuts the coarse space's arrays from `storage` (`coarse_f32s(capacity)` values) and `agg`
    /// (one per node); [`Coarse::build`] fills them.
    pub fn new(capacity: usize, agg: &'a mut [u32], storage: &'a mut [f32]) -> Self {
        let (geo, rest) = storage.split_at_mut((4 * capacity).min(storage.len()));
        let (g, l) = rest.split_at_mut((6 * capacity).min(rest.len()));
        Coarse {
            m: 0,
            agg,
            geo,
            g,
            l,
        }
    }

    /// Builds aggregates by binning the free nodes' rest positions on a grid of about
    /// `capacity` cells, then assembles and factorises A_c. `fixed(i)` tells fixed nodes,
    /// `grad_of(e)` element e's ∇φ₁..₃; `vol` has one value per element.
    #[allow(clippy::too_many_arguments)]
    pub fn build(
        &mut self,
        capacity: usize,
        x0: &[f32],
        fixed: impl Fn(usize) -> bool,
        tets: &[u32],
        grad_of: impl Fn(usize) -> [f32; 9],
        vol: &[f32],
        lam: &[f32],
        alp: &[f32],
    ) {
        let n = x0.len() / 3;
        let c = self;
        c.m = 0;
        if capacity == 0 || c.l.len() < 36 * capacity {
            c.agg.iter_mut().for_each(|a| *a = u32::MAX);
            return;
        }
        // Grid over the bounding box with about `capacity` cells, proportioned to the extents.
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for i in 0..n {
            for k in 0..3 {
                lo[k] = lo[k].min(x0[3 * i + k]);
                hi[k] = hi[k].max(x0[3 * i + k]);
            }
        }
        let ext = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
        let vol_box = ext.iter().map(|e| e.max(1e-12)).product::<f32>();
        let h = libm::cbrtf(vol_box / capacity as f32);
        let mut dims = ext.map(|e| ((e / h) as usize).max(1));
        while dims[0] * dims[1] * dims[2] > capacity {
            let k = (0..3).max_by_key(|&k| dims[k]).unwrap_or(0);
            dims[k] = (dims[k] - 1).max(1);
        }
        let cell = |i: usize| -> usize {
            let mut id = 0;
            for k in (0..3).rev() {
                let t = if ext[k] > 0.0 {
                    (x0[3 * i + k] - lo[k]) / ext[k]
                } else {
                    0.0
                };
                let b = ((t * dims[k] as f32) as usize).min(dims[k] - 1);
                id = id * dims[k] + b;
            }
            id
        };
        // Compact the used cells to aggregate ids (cells ≤ capacity, so ids fit); the scratch for
        // the cell → id map is the g buffer region (6·capacity ≥ cells).
        let cells = dims[0] * dims[1] * dims[2];
        for v in c.g.iter_mut() {
            *v = -1.0;
        }
        for i in 0..n {
            if fixed(i) {
                c.agg[i] = u32::MAX;
                continue;
            }
            let cl = cell(i);
            if cl >= cells {
                c.agg[i] = u32::MAX;
                continue;
            }
            if c.g[cl] < 0.0 {
                c.g[cl] = c.m as f32;
                c.m += 1;
            }
            c.agg[i] = c.g[cl] as u32;
        }
        let m = c.m;
        // Centroids and scales.
        c.geo.iter_mut().for_each(|v| *v = 0.0);
        for i in 0..n {
            let a = c.agg[i];
            if a == u32::MAX {
                continue;
            }
            let a = a as usize;
            for k in 0..3 {
                c.geo[4 * a + k] += x0[3 * i + k];
            }
            c.geo[4 * a + 3] += 1.0;
        }
        for a in 0..m {
            let cnt = c.geo[4 * a + 3].max(1.0);
            for k in 0..3 {
                c.geo[4 * a + k] /= cnt;
            }
            c.geo[4 * a + 3] = 0.0;
        }
        for i in 0..n {
            let a = c.agg[i];
            if a == u32::MAX {
                continue;
            }
            let a = a as usize;
            let d2: f32 = (0..3)
                .map(|k| (x0[3 * i + k] - c.geo[4 * a + k]) * (x0[3 * i + k] - c.geo[4 * a + k]))
                .sum();
            c.geo[4 * a + 3] = c.geo[4 * a + 3].max(libm::sqrtf(d2));
        }
        for a in 0..m {
            if c.geo[4 * a + 3] <= 0.0 {
                c.geo[4 * a + 3] = 1.0;
            }
        }
        // A_c = Pᵀ K₀ P, element by element (rest rotations).
        let dim = 6 * m;
        c.l[..dim * dim].iter_mut().for_each(|v| *v = 0.0);
        let ident = [1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        for e in 0..vol.len() {
            let ids = [
                tets[4 * e] as usize,
                tets[4 * e + 1] as usize,
                tets[4 * e + 2] as usize,
                tets[4 * e + 3] as usize,
            ];
            let ge = grad_of(e);
            let aggs = ids.map(|i| c.agg[i]);
            for (j0, &a) in aggs.iter().enumerate() {
                if a == u32::MAX || aggs[..j0].contains(&a) {
                    continue;
                }
                let au = a as usize;
                let ca = [c.geo[4 * au], c.geo[4 * au + 1], c.geo[4 * au + 2]];
                let sa = c.geo[4 * au + 3];
                for k in 0..6 {
                    let mut v = [[0.0f32; 3]; 4];
                    for j in 0..4 {
                        if aggs[j] == a {
                            let x = [x0[3 * ids[j]], x0[3 * ids[j] + 1], x0[3 * ids[j] + 2]];
                            v[j] = mode(k, x, &ca, sa);
                        }
                    }
                    let y = warped_apply(&v, &ge, &ident, vol[e], lam[e], alp[e]);
                    for j in 0..4 {
                        let b = aggs[j];
                        if b == u32::MAX {
                            continue;
                        }
                        let bu = b as usize;
                        let cb = [c.geo[4 * bu], c.geo[4 * bu + 1], c.geo[4 * bu + 2]];
                        let sb = c.geo[4 * bu + 3];
                        let x = [x0[3 * ids[j]], x0[3 * ids[j] + 1], x0[3 * ids[j] + 2]];
                        for lmode in 0..6 {
                            let p = mode(lmode, x, &cb, sb);
                            let val = p[0] * y[j][0] + p[1] * y[j][1] + p[2] * y[j][2];
                            c.l[(6 * bu + lmode) * dim + 6 * au + k] += val;
                        }
                    }
                }
            }
        }
        crate::dense::cholesky_in_place(c.l, dim);
        // From here on the apply multiplies by 1/s (a division per node and mode was most of
        // the restriction and prolongation cost).
        for a in 0..m {
            c.geo[4 * a + 3] = 1.0 / c.geo[4 * a + 3];
        }
    }

    /// z += P A_c⁻¹ Pᵀ r.
    pub fn apply(&mut self, x0: &[f32], r: &[f32], z: &mut [f32]) {
        let m = self.m;
        if m == 0 {
            return;
        }
        let dim = 6 * m;
        let n = x0.len() / 3;
        self.g[..dim].iter_mut().for_each(|v| *v = 0.0);
        for i in 0..n {
            let a = self.agg[i];
            if a == u32::MAX {
                continue;
            }
            let a = a as usize;
            let ri = [r[3 * i], r[3 * i + 1], r[3 * i + 2]];
            let inv_s = self.geo[4 * a + 3];
            let d = [
                (x0[3 * i] - self.geo[4 * a]) * inv_s,
                (x0[3 * i + 1] - self.geo[4 * a + 1]) * inv_s,
                (x0[3 * i + 2] - self.geo[4 * a + 2]) * inv_s,
            ];
            let g = &mut self.g[6 * a..6 * a + 6];
            g[0] += ri[0];
            g[1] += ri[1];
            g[2] += ri[2];
            // (e_j × d)·r = e_j·(d × r)
            g[3] += d[1] * ri[2] - d[2] * ri[1];
            g[4] += d[2] * ri[0] - d[0] * ri[2];
            g[5] += d[0] * ri[1] - d[1] * ri[0];
        }
        crate::dense::cholesky_solve(self.l, dim, self.g);
        for i in 0..n {
            let a = self.agg[i];
            if a == u32::MAX {
                continue;
            }
            let a = a as usize;
            let inv_s = self.geo[4 * a + 3];
            let d = [
                (x0[3 * i] - self.geo[4 * a]) * inv_s,
                (x0[3 * i + 1] - self.geo[4 * a + 1]) * inv_s,
                (x0[3 * i + 2] - self.geo[4 * a + 2]) * inv_s,
            ];
            let y = &self.g[6 * a..6 * a + 6];
            // translation + ω × d
            z[3 * i] += y[0] + (y[4] * d[2] - y[5] * d[1]);
            z[3 * i + 1] += y[1] + (y[5] * d[0] - y[3] * d[2]);
            z[3 * i + 2] += y[2] + (y[3] * d[1] - y[4] * d[0]);
        }
    }
}
