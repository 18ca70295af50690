//! One haptic tick: incremental loading (seed 000 §6.1) with warped stiffness and a
//! preconditioned conjugate-gradient solve under a fixed budget.
//!
//! Per tick, following the synthesis loop of §6.1:
//! 1. the applied load f_k moves toward the commanded load by at most ∆f (and the probe by at
//!    most its step);
//! 2. R_e is recomputed from the current state x_k (eqs. 3.55–3.58, warm-started iteration);
//! 3. non-linear materials re-blend (λ_e, α_e) (eqs. 6.2–6.11);
//! 4. the system K' x_{k+1} = f_{k+1} + K'' x₀ (eq. 3.52) is solved in increment form:
//!    K' δ = f_{k+1} − f_int(x_k) with f_int(x) = Σ R_e K_e (R_eᵀ x_e − x₀_e), which is the same
//!    equation because K' x_k − K'' x₀ = f_int(x_k) for the frozen rotations; δ starts at the
//!    energy-optimal multiple of the previous tick's increment (the predictor, `predict`:
//!    a probe sliding at constant speed makes the same increment every tick), so the solve is
//!    warm-started from the previous tick's solution extrapolated along its motion.
//!
//! Constraints are filters on the CG vectors (modified PCG, Baraff & Witkin 1998): fixed nodes
//! have no free direction; probe-held nodes keep their two tangential directions (frictionless).

use crate::blend::blend_parameters;
use crate::config::{Kernel, Preconditioner};
use crate::kernel::{
    diagonal_blocks_lanes, gradient_of_lanes, rotate_gradients_lanes, rotated_apply_lanes,
    warped_apply_packed, warped_internal_force, warped_internal_force_from_h_lanes, LANES, M3,
};
use crate::rotation::warp_rotation_fast_lanes;
use crate::runtime::{blk, norm, Probe, Runtime, SolveStatus, TickReport, FIXED, FREE, PROBED};

#[inline(always)]
fn gather(v: &[f32], ids: &[usize; 4]) -> [[f32; 3]; 4] {
    let mut o = [[0.0f32; 3]; 4];
    for a in 0..4 {
        let i = 3 * ids[a];
        o[a] = [v[i], v[i + 1], v[i + 2]];
    }
    o
}

#[inline(always)]
fn scatter_add(v: &mut [f32], ids: &[usize; 4], f: &[[f32; 3]; 4]) {
    for a in 0..4 {
        let i = 3 * ids[a];
        v[i] += f[a][0];
        v[i + 1] += f[a][1];
        v[i + 2] += f[a][2];
    }
}

fn dot(a: &[f32], b: &[f32]) -> f32 {
    crate::kernel::dot_lanes(a, b)
}

/// Block `b` of a LANES-blocked per-element array of `W` values per element (see `blk`): one
/// contiguous run of `W · LANES` values.
#[inline(always)]
fn block<const W: usize>(arr: &[f32], b: usize) -> [[f32; LANES]; W] {
    let mut o = [[0.0f32; LANES]; W];
    let base = b * W * LANES;
    for (k, ok) in o.iter_mut().enumerate() {
        ok.copy_from_slice(&arr[base + k * LANES..base + (k + 1) * LANES]);
    }
    o
}

/// Writes block `b` of a LANES-blocked array (inverse of [`block`]).
#[inline(always)]
fn store_block<const W: usize>(arr: &mut [f32], b: usize, v: &[[f32; LANES]; W]) {
    let base = b * W * LANES;
    for (k, vk) in v.iter().enumerate() {
        arr[base + k * LANES..base + (k + 1) * LANES].copy_from_slice(vk);
    }
}

impl<'a> Runtime<'a> {
    /// Node ids of the elements of block `b` and the nodal values of `src` (3 per node) there.
    #[inline(always)]
    fn gather_nodes(&self, b: usize, src: &[f32]) -> ([[usize; LANES]; 4], [[[f32; LANES]; 3]; 4]) {
        let mut ids = [[0usize; LANES]; 4];
        let mut v = [[[0.0f32; LANES]; 3]; 4];
        let tets = &self.tets[4 * LANES * b..4 * LANES * (b + 1)];
        for l in 0..LANES {
            for a in 0..4 {
                let i = tets[4 * l + a] as usize;
                ids[a][l] = i;
                // One bounds check per node (ids < n by construction).
                if let Some(x) = src.get(3 * i..3 * i + 3) {
                    v[a][0][l] = x[0];
                    v[a][1][l] = x[1];
                    v[a][2][l] = x[2];
                }
            }
        }
        (ids, v)
    }

    #[inline(always)]
    fn element_ids(&self, e: usize) -> [usize; 4] {
        [
            self.tets[4 * e] as usize,
            self.tets[4 * e + 1] as usize,
            self.tets[4 * e + 2] as usize,
            self.tets[4 * e + 3] as usize,
        ]
    }

    #[inline(always)]
    fn element_grad(&self, e: usize) -> [f32; 9] {
        core::array::from_fn(|k| self.grad[blk(e, k, 9)])
    }

    #[inline(always)]
    fn element_rot(&self, e: usize) -> M3 {
        core::array::from_fn(|k| self.rot[blk(e, k, 9)])
    }

    /// Advances the applied load and the probe toward their commands (incremental loading).
    #[inline(never)]
    fn advance_loads(&mut self) -> f32 {
        let step = self.config.load_step;
        let mut diff2 = 0.0f64;
        for (a, c) in self.f_app.iter().zip(self.f_cmd.iter()) {
            diff2 += ((c - a) as f64) * ((c - a) as f64);
        }
        let diff = libm::sqrt(diff2) as f32;
        if diff <= step || !step.is_finite() {
            self.f_app.copy_from_slice(self.f_cmd);
        } else {
            let s = step / diff;
            for (a, c) in self.f_app.iter_mut().zip(self.f_cmd.iter()) {
                *a += s * (c - *a);
            }
        }
        // Probe position.
        let ps = self.config.probe_step;
        self.probe = match (self.probe, self.probe_cmd) {
            (_, Probe::None) => Probe::None,
            (Probe::Sphere { center: c0, .. }, Probe::Sphere { center: c1, radius }) => {
                Probe::Sphere {
                    center: step_toward(c0, c1, ps),
                    radius,
                }
            }
            (
                Probe::Flat { center: c0, .. },
                Probe::Flat {
                    center: c1,
                    axis,
                    radius,
                },
            ) => Probe::Flat {
                center: step_toward(c0, c1, ps),
                axis,
                radius,
            },
            (_, cmd) => cmd,
        };
        if self.f_cmd_norm > 0.0 {
            norm(self.f_app) / self.f_cmd_norm
        } else {
            1.0
        }
    }

    /// R_e from the current state (eqs. 3.55–3.58) and, for strain blending, ε_e (eq. 6.8) —
    /// also without warping (R_e = I), where ε_e is the linear strain sym(H). Runs LANES elements
    /// at a time (SIMD).
    #[inline(never)]
    fn update_rotations(&mut self, iters: usize) {
        let warp = self.config.warp;
        let mut moved = 0.0f32;
        let want_strain = !self.strain.is_empty();
        if !warp && !want_strain {
            return;
        }
        for b in 0..self.tp / LANES {
            let (_, v) = self.gather_nodes(b, self.u);
            let g = block::<9>(self.grad, b);
            // F = I + H
            let mut f = gradient_of_lanes(&v, &g);
            for k in [0, 4, 8] {
                for fl in f[k].iter_mut() {
                    *fl += 1.0;
                }
            }
            let mut r = block::<9>(self.rot, b);
            if warp {
                let mut q = block::<4>(self.quat, b);
                moved = moved.max(warp_rotation_fast_lanes(&f, &mut q, iters, &mut r));
                store_block(self.quat, b, &q);
                store_block(self.rot, b, &r);
                store_block(self.ghat, b, &rotate_gradients_lanes(&g, &r));
            }
            if want_strain {
                // ε = sym(RᵀF) − I, engineering shear (R = I without warping).
                for l in 0..LANES {
                    let e = b * LANES + l;
                    if e >= self.t {
                        break;
                    }
                    let rt_f = |i: usize, j: usize| {
                        r[i][l] * f[j][l] + r[3 + i][l] * f[3 + j][l] + r[6 + i][l] * f[6 + j][l]
                    };
                    let s = &mut self.strain[6 * e..6 * e + 6];
                    s[0] = rt_f(0, 0) - 1.0;
                    s[1] = rt_f(1, 1) - 1.0;
                    s[2] = rt_f(2, 2) - 1.0;
                    s[3] = rt_f(0, 1) + rt_f(1, 0);
                    s[4] = rt_f(1, 2) + rt_f(2, 1);
                    s[5] = rt_f(2, 0) + rt_f(0, 2);
                }
            }
        }
        self.precond_drift += moved;
    }

    /// Updates which surface nodes the probe holds and their targets; returns the count.
    #[inline(never)]
    fn update_contact_set(&mut self) -> u32 {
        let mut count = 0;
        for i in 0..self.n {
            if self.flag[i] == FIXED || self.area[i] <= 0.0 {
                continue;
            }
            let x = [
                self.x0[3 * i] + self.u[3 * i],
                self.x0[3 * i + 1] + self.u[3 * i + 1],
                self.x0[3 * i + 2] + self.u[3 * i + 2],
            ];
            let held = self.flag[i] == PROBED;
            // Contact force on the node c_i = −r_full_i; the probe can only push (c·n ≥ 0).
            let pushing = if held {
                let n = [
                    self.normal[3 * i],
                    self.normal[3 * i + 1],
                    self.normal[3 * i + 2],
                ];
                -(self.r_full[3 * i] * n[0]
                    + self.r_full[3 * i + 1] * n[1]
                    + self.r_full[3 * i + 2] * n[2])
                    >= 0.0
            } else {
                true
            };
            let target = match self.probe {
                Probe::None => None,
                Probe::Sphere { center, radius } => {
                    let d = [x[0] - center[0], x[1] - center[1], x[2] - center[2]];
                    let dist = libm::sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
                    if (dist < radius || held) && dist > 1e-12 {
                        let n = [d[0] / dist, d[1] / dist, d[2] / dist];
                        let inside = dist < radius;
                        Some((
                            n,
                            n[0] * center[0] + n[1] * center[1] + n[2] * center[2] + radius,
                            inside,
                        ))
                    } else {
                        None
                    }
                }
                Probe::Flat {
                    center,
                    axis,
                    radius,
                } => {
                    let d = [x[0] - center[0], x[1] - center[1], x[2] - center[2]];
                    let along = d[0] * axis[0] + d[1] * axis[1] + d[2] * axis[2];
                    let radial = [
                        d[0] - along * axis[0],
                        d[1] - along * axis[1],
                        d[2] - along * axis[2],
                    ];
                    let rr = libm::sqrtf(
                        radial[0] * radial[0] + radial[1] * radial[1] + radial[2] * radial[2],
                    );
                    if rr <= radius && (along < 0.0 || held) {
                        let plane = axis[0] * center[0] + axis[1] * center[1] + axis[2] * center[2];
                        Some((axis, plane, along < 0.0))
                    } else {
                        None
                    }
                }
            };
            match target {
                Some((n, plane, inside)) if (!held && inside) || (held && pushing) => {
                    self.flag[i] = PROBED;
                    self.normal[3 * i..3 * i + 3].copy_from_slice(&n);
                    self.prescribed[i] = plane;
                    count += 1;
                }
                _ => {
                    if held {
                        self.flag[i] = FREE;
                    }
                }
            }
        }
        count
    }

    /// Moves probe-held nodes onto the probe (their prescribed normal position).
    fn apply_prescribed(&mut self) {
        for i in 0..self.n {
            if self.flag[i] == PROBED {
                let n = [
                    self.normal[3 * i],
                    self.normal[3 * i + 1],
                    self.normal[3 * i + 2],
                ];
                let x = [
                    self.x0[3 * i] + self.u[3 * i],
                    self.x0[3 * i + 1] + self.u[3 * i + 1],
                    self.x0[3 * i + 2] + self.u[3 * i + 2],
                ];
                let gap = self.prescribed[i] - (n[0] * x[0] + n[1] * x[1] + n[2] * x[2]);
                for (u, nk) in self.u[3 * i..3 * i + 3].iter_mut().zip(n) {
                    *u += gap * nk;
                }
            }
        }
    }

    /// Whether the preconditioner blocks must be rebuilt this tick (see
    /// [`crate::RuntimeConfig::precond_refresh_angle`]).
    fn precond_due(&self) -> bool {
        !self.precond_valid
            || self.precond_drift > self.config.precond_refresh_angle
            || !matches!(self.record.blend, palpate_protocol::model::Blend::None)
    }

    /// One pass over the elements, LANES at a time (SIMD; padding elements contribute zero):
    /// r_full = f_app − f_int(u); with `rotate = Some(iterations)` first R_e (and R∇φ) from the
    /// current state, fused here so u and ∇φ are gathered once; with `diag` the 3 × 3 node
    /// blocks of K' for the preconditioner, inverted in place.
    #[inline(never)]
    fn element_pass(&mut self, rotate: Option<usize>, diag: bool) {
        if diag {
            self.precond.iter_mut().for_each(|v| *v = 0.0);
            self.precond_valid = true;
            self.precond_drift = 0.0;
        }
        let mut moved = 0.0f32;
        for b in 0..self.tp / LANES {
            let (ids, v) = self.gather_nodes(b, self.u);
            let g = block::<9>(self.grad, b);
            let mut r = block::<9>(self.rot, b);
            let e0 = b * LANES;
            let mut vol = [0.0f32; LANES];
            let mut lam = [0.0f32; LANES];
            let mut alp = [0.0f32; LANES];
            vol.copy_from_slice(&self.vol[e0..e0 + LANES]);
            lam.copy_from_slice(&self.lam[e0..e0 + LANES]);
            alp.copy_from_slice(&self.alp[e0..e0 + LANES]);
            let h = gradient_of_lanes(&v, &g);
            if let Some(iters) = rotate {
                let mut f = h;
                for k in [0, 4, 8] {
                    for fl in f[k].iter_mut() {
                        *fl += 1.0;
                    }
                }
                let mut q = block::<4>(self.quat, b);
                moved = moved.max(warp_rotation_fast_lanes(&f, &mut q, iters, &mut r));
                store_block(self.quat, b, &q);
                store_block(self.rot, b, &r);
                store_block(self.ghat, b, &rotate_gradients_lanes(&g, &r));
            }
            let f = warped_internal_force_from_h_lanes(&h, &g, &r, &vol, &lam, &alp);
            self.store_element_forces(b, &f);
            if diag {
                let d = diagonal_blocks_lanes(&g, &r, &vol, &lam, &alp);
                for l in 0..LANES {
                    for a in 0..4 {
                        if let Some(x) = self.precond.get_mut(6 * ids[a][l]..6 * ids[a][l] + 6) {
                            for j in 0..6 {
                                x[j] += d[a][j][l];
                            }
                        }
                    }
                }
            }
        }
        for i in 0..self.n {
            let fi = self.node_force(i);
            let rows = self.r_full[3 * i..3 * i + 3].iter_mut();
            for ((r, a), f) in rows.zip(&self.f_app[3 * i..3 * i + 3]).zip(fi) {
                *r = a - f;
            }
        }
        self.precond_drift += moved;
        if diag {
            self.invert_precond();
        }
    }

    /// Inverts the assembled 3 × 3 node blocks in place (or keeps their diagonal for Jacobi).
    fn invert_precond(&mut self) {
        let block_jacobi = self.config.preconditioner == Preconditioner::BlockJacobi;
        for i in 0..self.n {
            let b = &mut self.precond[6 * i..6 * i + 6];
            if block_jacobi {
                // Invert the symmetric 3 × 3 block (xx, yy, zz, xy, yz, zx) by cofactors.
                let (a, d, f, bb, e, c) = (b[0], b[1], b[2], b[3], b[4], b[5]);
                let c00 = d * f - e * e;
                let c01 = c * e - bb * f;
                let c02 = bb * e - c * d;
                let det = a * c00 + bb * c01 + c * c02;
                if det.abs() > 0.0 && det.is_finite() {
                    let inv = 1.0 / det;
                    let c11 = a * f - c * c;
                    let c12 = bb * c - a * e;
                    let c22 = a * d - bb * bb;
                    b.copy_from_slice(&[
                        c00 * inv,
                        c11 * inv,
                        c22 * inv,
                        c01 * inv,
                        c12 * inv,
                        c02 * inv,
                    ]);
                } else {
                    b.copy_from_slice(&[0.0; 6]);
                }
            } else {
                for v in b[..3].iter_mut() {
                    *v = if *v > 0.0 { 1.0 / *v } else { 0.0 };
                }
                b[3..].fill(0.0);
            }
        }
    }

    /// q = K' p (matrix-free, all elements). The gradient kernel runs [`LANES`] elements at a time
    /// (structure-of-arrays, SIMD); the packed kernel runs element by element.
    #[inline(never)]
    fn apply_stiffness(&mut self) {
        if self.config.kernel == Kernel::Packed {
            self.q.iter_mut().for_each(|v| *v = 0.0);
            for e in 0..self.t {
                let ids = self.element_ids(e);
                let r = self.element_rot(e);
                let v = gather(self.p, &ids);
                let base = 2 * 78 * e;
                let c: &[f32; 78] = self.cd[base..base + 78].try_into().unwrap_or(&[0.0; 78]);
                let d: &[f32; 78] = self.cd[base + 78..base + 156]
                    .try_into()
                    .unwrap_or(&[0.0; 78]);
                let f = warped_apply_packed(&v, c, d, &r, self.lam[e], self.alp[e]);
                scatter_add(self.q, &ids, &f);
            }
            return;
        }
        for b in 0..self.tp / LANES {
            let (_, v) = self.gather_nodes(b, self.p);
            let gh = block::<9>(self.ghat, b);
            let e0 = b * LANES;
            let mut vol = [0.0f32; LANES];
            let mut lam = [0.0f32; LANES];
            let mut alp = [0.0f32; LANES];
            vol.copy_from_slice(&self.vol[e0..e0 + LANES]);
            lam.copy_from_slice(&self.lam[e0..e0 + LANES]);
            alp.copy_from_slice(&self.alp[e0..e0 + LANES]);
            let f = rotated_apply_lanes(&v, &gh, &vol, &lam, &alp);
            // Element forces go to a buffer with plain vector stores; the node pass below sums
            // them. Scattering them instead costs 96 dependent read-modify-writes per block.
            self.store_element_forces(b, &f);
        }
        for i in 0..self.n {
            let acc = self.node_force(i);
            self.q[3 * i..3 * i + 3].copy_from_slice(&acc);
        }
    }

    /// Stores block `b`'s element forces in `ef` (plain vector stores; see [`Self::node_force`]).
    #[inline(always)]
    fn store_element_forces(&mut self, b: usize, f: &[[[f32; LANES]; 3]; 4]) {
        let ef = &mut self.ef[12 * LANES * b..12 * LANES * (b + 1)];
        for a in 0..4 {
            for k in 0..3 {
                ef[(3 * a + k) * LANES..(3 * a + k + 1) * LANES].copy_from_slice(&f[a][k]);
            }
        }
    }

    /// Σ of the stored element forces on node `i` over its incidences: a gather with
    /// independent sums, instead of a scatter whose read-modify-writes to shared nodes form
    /// store-to-load dependency chains.
    #[inline(always)]
    fn node_force(&self, i: usize) -> [f32; 3] {
        let (s, e) = (self.inc_start[i] as usize, self.inc_start[i + 1] as usize);
        let mut acc = [0.0f32; 3];
        for &pos in &self.inc[s..e] {
            let p = pos as usize;
            if let Some(x) = self.ef.get(p..p + 2 * LANES + 1) {
                acc[0] += x[0];
                acc[1] += x[LANES];
                acc[2] += x[2 * LANES];
            }
        }
        acc
    }

    /// Applies the constraint filter S to a vector in place.
    fn filter(flag: &[u32], normal: &[f32], v: &mut [f32]) {
        for (i, fl) in flag.iter().enumerate() {
            match *fl {
                FIXED => {
                    v[3 * i] = 0.0;
                    v[3 * i + 1] = 0.0;
                    v[3 * i + 2] = 0.0;
                }
                PROBED => {
                    let n = [normal[3 * i], normal[3 * i + 1], normal[3 * i + 2]];
                    let d = v[3 * i] * n[0] + v[3 * i + 1] * n[1] + v[3 * i + 2] * n[2];
                    for k in 0..3 {
                        v[3 * i + k] -= d * n[k];
                    }
                }
                _ => {}
            }
        }
    }

    /// z = S M⁻¹ r.
    #[inline(never)]
    fn precondition(&mut self) {
        for i in 0..self.n {
            let m = &self.precond[6 * i..6 * i + 6];
            let r = [self.r[3 * i], self.r[3 * i + 1], self.r[3 * i + 2]];
            self.z[3 * i] = m[0] * r[0] + m[3] * r[1] + m[5] * r[2];
            self.z[3 * i + 1] = m[3] * r[0] + m[1] * r[1] + m[4] * r[2];
            self.z[3 * i + 2] = m[5] * r[0] + m[4] * r[1] + m[2] * r[2];
        }
        // Two-level: add the coarse correction P A_c⁻¹ Pᵀ r (r is already filtered).
        self.coarse.apply(self.x0, self.r, self.z);
        Self::filter(self.flag, self.normal, self.z);
    }

    /// The predictor: δ₀ = c δ_prev with c = (δ_prevᵀ r)/(δ_prevᵀ K' δ_prev), the energy-optimal
    /// multiple of the previous tick's increment (a one-dimensional Galerkin projection, so the
    /// error in the energy norm never grows). A probe sliding at constant speed makes the same
    /// increment every tick, so this removes most of the residual for one K' product; after an
    /// abrupt change c ≈ 0 and nothing is lost but that product. Updates δ, r_full and r and
    /// returns the new ‖r‖, or None when there is no usable previous increment.
    fn predict(&mut self) -> Option<f32> {
        self.p.copy_from_slice(self.delta_prev);
        Self::filter(self.flag, self.normal, self.p);
        if dot(self.p, self.p) == 0.0 {
            return None;
        }
        self.apply_stiffness();
        let pq = dot(self.p, self.q);
        // p is filtered, so p·r_full = p·r.
        let c = dot(self.p, self.r) / pq;
        if !(pq > 0.0 && c.is_finite()) {
            return None;
        }
        for (d, p) in self.delta.iter_mut().zip(self.p.iter()) {
            *d = c * p;
        }
        for (r, q) in self.r_full.iter_mut().zip(self.q.iter()) {
            *r -= c * q;
        }
        self.r.copy_from_slice(self.r_full);
        Self::filter(self.flag, self.normal, self.r);
        Some(norm(self.r))
    }

    /// Preconditioned CG for K' δ = r_full on the filtered space. Returns (iterations, ‖r‖, status).
    #[inline(never)]
    fn pcg(&mut self, scale: f32) -> (u32, f32, SolveStatus) {
        let tol = self.config.tolerance * scale + self.config.absolute_tolerance;
        self.delta.iter_mut().for_each(|v| *v = 0.0);
        self.r.copy_from_slice(self.r_full);
        Self::filter(self.flag, self.normal, self.r);
        let rnorm0 = norm(self.r);
        if rnorm0 <= tol {
            // Nothing to solve: skip the preconditioner (most steady haptic ticks).
            return (0, rnorm0, SolveStatus::Converged);
        }
        let mut rnorm0 = rnorm0;
        if self.config.predictor {
            if let Some(rn) = self.predict() {
                rnorm0 = rn;
                if rnorm0 <= tol {
                    return (0, rnorm0, SolveStatus::Converged);
                }
            }
        }
        self.precondition();
        self.p.copy_from_slice(self.z);
        let mut rz = dot(self.r, self.z);
        let mut rnorm = rnorm0;
        let mut it = 0;
        while it < self.config.max_iterations {
            if rnorm <= tol {
                return (it, rnorm, SolveStatus::Converged);
            }
            self.apply_stiffness();
            // r_full tracks the unfiltered residual (reactions at held nodes); q is then filtered.
            // p is filtered, so p·(S q) = p·q.
            let pq = dot(self.p, self.q);
            if pq.is_nan() || pq <= 0.0 || !pq.is_finite() {
                return (it, rnorm, SolveStatus::Rejected);
            }
            let alpha = rz / pq;
            // One pass: δ += αp, r_full −= αq, r −= α S q (S applied node by node), and the
            // block-Jacobi part of z with ‖r‖² on the way.
            let mut rr = 0.0f64;
            for i in 0..self.n {
                let mut qi = [self.q[3 * i], self.q[3 * i + 1], self.q[3 * i + 2]];
                let pi = &self.p[3 * i..3 * i + 3];
                for (d, p) in self.delta[3 * i..3 * i + 3].iter_mut().zip(pi) {
                    *d += alpha * p;
                }
                for (r, q) in self.r_full[3 * i..3 * i + 3].iter_mut().zip(qi) {
                    *r -= alpha * q;
                }
                match self.flag[i] {
                    FIXED => qi = [0.0; 3],
                    PROBED => {
                        let n = &self.normal[3 * i..3 * i + 3];
                        let d = qi[0] * n[0] + qi[1] * n[1] + qi[2] * n[2];
                        for (q, nk) in qi.iter_mut().zip(n) {
                            *q -= d * nk;
                        }
                    }
                    _ => {}
                }
                let mut ri = [0.0f32; 3];
                for k in 0..3 {
                    ri[k] = self.r[3 * i + k] - alpha * qi[k];
                    self.r[3 * i + k] = ri[k];
                    rr += (ri[k] as f64) * (ri[k] as f64);
                }
                let m = &self.precond[6 * i..6 * i + 6];
                self.z[3 * i] = m[0] * ri[0] + m[3] * ri[1] + m[5] * ri[2];
                self.z[3 * i + 1] = m[3] * ri[0] + m[1] * ri[1] + m[4] * ri[2];
                self.z[3 * i + 2] = m[5] * ri[0] + m[4] * ri[1] + m[2] * ri[2];
            }
            // Two-level: add the coarse correction P A_c⁻¹ Pᵀ r (r is filtered), then filter z.
            self.coarse.apply(self.x0, self.r, self.z);
            Self::filter(self.flag, self.normal, self.z);
            let rz_new = dot(self.r, self.z);
            let beta = rz_new / rz;
            rz = rz_new;
            for (pk, zk) in self.p.iter_mut().zip(self.z.iter()) {
                *pk = zk + beta * *pk;
            }
            rnorm = libm::sqrt(rr) as f32;
            it += 1;
            if !rnorm.is_finite() {
                return (it, rnorm, SolveStatus::Rejected);
            }
        }
        if rnorm <= tol {
            (it, rnorm, SolveStatus::Converged)
        } else {
            (it, rnorm, SolveStatus::BudgetExhausted)
        }
    }

    /// Internal elastic forces f_int(x) = Σ R_e K_e (R_eᵀ x_e − x₀_e) of the current state with the
    /// current rotations (3 per node, N). `out` must hold 3 values per node.
    pub fn internal_forces(&self, out: &mut [f32]) -> Result<(), crate::RuntimeError> {
        if out.len() != 3 * self.n {
            return Err(crate::RuntimeError::ModelShape {
                what: "internal force buffer",
                expected: 3 * self.n,
                found: out.len(),
            });
        }
        out.iter_mut().for_each(|v| *v = 0.0);
        for e in 0..self.t {
            let ids = self.element_ids(e);
            let g = self.element_grad(e);
            let r = self.element_rot(e);
            let u = gather(self.u, &ids);
            let (f, _) = warped_internal_force(&u, &g, &r, self.vol[e], self.lam[e], self.alp[e]);
            scatter_add(out, &ids, &f);
        }
        Ok(())
    }

    /// Recomputes rotations, strains and blended parameters for the current displacements.
    pub(crate) fn refresh_state(&mut self) {
        self.precond_valid = false;
        // After a jump the last increment predicts nothing.
        self.delta_prev.iter_mut().for_each(|v| *v = 0.0);
        // A jump to an arbitrary state needs more than the per-tick warm-started iterations.
        self.update_rotations(50);
        blend_parameters(self);
    }

    /// Runs one tick. Never allocates; never panics on any state.
    pub fn tick(&mut self) -> TickReport {
        self.u_good.copy_from_slice(self.u);
        let load_fraction = self.advance_loads();
        // The contact set and the probe-held positions use u and last tick's reactions only, so
        // they come first: rotations and forces are then those of the state being solved from.
        let contact_nodes = self.update_contact_set();
        self.apply_prescribed();
        let iters = self.config.rotation_iterations as usize;
        if self.config.warp && matches!(self.record.blend, palpate_protocol::model::Blend::None) {
            // Linear material: rotations and internal forces in one pass.
            let diag = self.precond_due();
            self.element_pass(Some(iters), diag);
        } else {
            // Blending needs every element's strain before any force.
            self.update_rotations(iters);
            // `%` rather than `is_multiple_of`: the workspace's MSRV is 1.85.
            #[allow(clippy::manual_is_multiple_of)]
            let due = self.tick_count % self.config.blend_every.max(1) as u64 == 0;
            if due {
                blend_parameters(self);
            }
            let diag = self.precond_due();
            self.element_pass(None, diag);
        }
        let scale = norm(self.f_app).max(self.reaction_norm);
        let (iterations, rnorm, mut status) = self.pcg(scale);
        let mut step = 0.0f32;
        if status != SolveStatus::Rejected {
            for k in 0..3 * self.n {
                let d = self.delta[k];
                step = step.max(d.abs());
                self.u[k] += d;
            }
            if !step.is_finite() || !self.u.iter().all(|v| v.is_finite()) {
                status = SolveStatus::Rejected;
            }
        }
        if status == SolveStatus::Rejected {
            // A non-finite or indefinite solve never replaces the last good state.
            self.u.copy_from_slice(self.u_good);
            self.delta_prev.iter_mut().for_each(|v| *v = 0.0);
            step = 0.0;
        } else {
            self.delta_prev.copy_from_slice(self.delta);
        }
        // Force on the probe: Σ over held nodes of r_full (= −contact force on the node).
        let mut reaction = [0.0f32; 3];
        for i in 0..self.n {
            if self.flag[i] == PROBED {
                for (rk, f) in reaction.iter_mut().zip(&self.r_full[3 * i..3 * i + 3]) {
                    *rk += f;
                }
            }
        }
        self.reaction = reaction;
        self.reaction_norm = libm::sqrtf(
            reaction[0] * reaction[0] + reaction[1] * reaction[1] + reaction[2] * reaction[2],
        );
        self.tick_count += 1;
        TickReport {
            iterations,
            rel_residual: if scale > 0.0 { rnorm / scale } else { rnorm },
            status,
            load_fraction,
            contact_nodes,
            reaction,
            step,
        }
    }
}

fn step_toward(from: [f32; 3], to: [f32; 3], max_step: f32) -> [f32; 3] {
    let d = [to[0] - from[0], to[1] - from[1], to[2] - from[2]];
    let len = libm::sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if len <= max_step || !max_step.is_finite() {
        to
    } else {
        let s = max_step / len;
        [from[0] + s * d[0], from[1] + s * d[1], from[2] + s * d[2]]
    }
}
