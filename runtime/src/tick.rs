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
//!    equation because K' x_k − K'' x₀ = f_int(x_k) for the frozen rotations; δ starts at zero, so
//!    the solve is warm-started from the previous tick's solution.
//!
//! Constraints are filters on the CG vectors (modified PCG, Baraff & Witkin 1998): fixed nodes
//! have no free direction; probe-held nodes keep their two tangential directions (frictionless).

use crate::blend::blend_parameters;
use crate::config::{Kernel, Preconditioner};
use crate::kernel::{
    diagonal_block, warped_apply, warped_apply_lanes, warped_apply_packed, warped_internal_force,
    warped_internal_force_lanes, LANES, M3,
};
use crate::rotation::warp_rotation_fast;
use crate::runtime::{norm, Probe, Runtime, SolveStatus, TickReport, FIXED, FREE, PROBED};
use nalgebra::Matrix3;

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
    let mut s = 0.0f32;
    for (x, y) in a.iter().zip(b) {
        s += x * y;
    }
    s
}

/// `LANES` consecutive elements gathered structure-of-arrays for the batched kernels.
struct Lanes {
    ids: [[usize; LANES]; 4],
    v: [[[f32; LANES]; 3]; 4],
    g: [[f32; LANES]; 9],
    r: [[f32; LANES]; 9],
    vol: [f32; LANES],
    lam: [f32; LANES],
    alp: [f32; LANES],
}

impl<'a> Runtime<'a> {
    /// Gathers elements `e0..e0 + LANES`: node ids, the nodal values of `src` (3 per node), ∇φ,
    /// R, V, λ, α.
    #[inline(always)]
    fn gather_lanes(&self, e0: usize, src: &[f32]) -> Lanes {
        let mut o = Lanes {
            ids: [[0; LANES]; 4],
            v: [[[0.0; LANES]; 3]; 4],
            g: [[0.0; LANES]; 9],
            r: [[0.0; LANES]; 9],
            vol: [0.0; LANES],
            lam: [0.0; LANES],
            alp: [0.0; LANES],
        };
        for l in 0..LANES {
            let e = e0 + l;
            for a in 0..4 {
                let i = self.tets[4 * e + a] as usize;
                o.ids[a][l] = i;
                for k in 0..3 {
                    o.v[a][k][l] = src[3 * i + k];
                }
            }
            for k in 0..9 {
                o.g[k][l] = self.grad[9 * e + k];
                o.r[k][l] = self.rot[9 * e + k];
            }
            o.vol[l] = self.vol[e];
            o.lam[l] = self.lam[e];
            o.alp[l] = self.alp[e];
        }
        o
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
        let mut g = [0.0; 9];
        g.copy_from_slice(&self.grad[9 * e..9 * e + 9]);
        g
    }

    #[inline(always)]
    fn element_rot(&self, e: usize) -> M3 {
        let mut r = [0.0; 9];
        r.copy_from_slice(&self.rot[9 * e..9 * e + 9]);
        r
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

    /// R_e from the current state (eqs. 3.55–3.58) and, for strain blending, ε_e (eq. 6.8).
    #[inline(never)]
    fn update_rotations(&mut self, iters: usize) {
        if !self.config.warp {
            return;
        }
        let want_strain = !self.strain.is_empty();
        for e in 0..self.t {
            let ids = self.element_ids(e);
            let g = self.element_grad(e);
            let u = gather(self.u, &ids);
            let h = crate::kernel::gradient_of(&u, &g);
            let fm = [
                1.0 + h[0],
                h[1],
                h[2],
                h[3],
                1.0 + h[4],
                h[5],
                h[6],
                h[7],
                1.0 + h[8],
            ];
            let mut q = [
                self.quat[4 * e],
                self.quat[4 * e + 1],
                self.quat[4 * e + 2],
                self.quat[4 * e + 3],
            ];
            let mut ro = [0.0f32; 9];
            warp_rotation_fast(&fm, &mut q, iters, &mut ro);
            self.quat[4 * e..4 * e + 4].copy_from_slice(&q);
            self.rot[9 * e..9 * e + 9].copy_from_slice(&ro);
            let f = Matrix3::from_row_slice(&fm);
            let r = Matrix3::from_row_slice(&ro);
            if want_strain {
                let rt_f = r.transpose() * f;
                let s = &mut self.strain[6 * e..6 * e + 6];
                s[0] = rt_f[(0, 0)] - 1.0;
                s[1] = rt_f[(1, 1)] - 1.0;
                s[2] = rt_f[(2, 2)] - 1.0;
                s[3] = rt_f[(0, 1)] + rt_f[(1, 0)];
                s[4] = rt_f[(1, 2)] + rt_f[(2, 1)];
                s[5] = rt_f[(2, 0)] + rt_f[(0, 2)];
            }
        }
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
                for k in 0..3 {
                    self.u[3 * i + k] += gap * n[k];
                }
            }
        }
    }

    /// r_full = f_app − f_int(u) and the preconditioner blocks (inverted in place).
    #[inline(never)]
    fn residual_and_preconditioner(&mut self) {
        self.r_full.copy_from_slice(self.f_app);
        self.precond.iter_mut().for_each(|v| *v = 0.0);
        // Internal forces LANES elements at a time (SIMD), the remainder one by one below.
        let batched = self.t / LANES * LANES;
        let mut e0 = 0;
        while e0 < batched {
            let Lanes {
                ids,
                v,
                g,
                r,
                vol,
                lam,
                alp,
            } = self.gather_lanes(e0, self.u);
            let f = warped_internal_force_lanes(&v, &g, &r, &vol, &lam, &alp);
            for l in 0..LANES {
                let e = e0 + l;
                let ge = self.element_grad(e);
                let re = self.element_rot(e);
                for a in 0..4 {
                    let i = ids[a][l];
                    self.r_full[3 * i] -= f[a][0][l];
                    self.r_full[3 * i + 1] -= f[a][1][l];
                    self.r_full[3 * i + 2] -= f[a][2][l];
                    let b = diagonal_block(a, &ge, &re, vol[l], lam[l], alp[l]);
                    for j in 0..6 {
                        self.precond[6 * i + j] += b[j];
                    }
                }
            }
            e0 += LANES;
        }
        for e in batched..self.t {
            let ids = self.element_ids(e);
            let g = self.element_grad(e);
            let r = self.element_rot(e);
            let (v, l, a) = (self.vol[e], self.lam[e], self.alp[e]);
            let u = gather(self.u, &ids);
            let (mut f, _) = warped_internal_force(&u, &g, &r, v, l, a);
            for fa in f.iter_mut() {
                for c in fa.iter_mut() {
                    *c = -*c;
                }
            }
            scatter_add(self.r_full, &ids, &f);
            for (k, &node) in ids.iter().enumerate() {
                let b = diagonal_block(k, &g, &r, v, l, a);
                for j in 0..6 {
                    self.precond[6 * node + j] += b[j];
                }
            }
        }
        let block = self.config.preconditioner == Preconditioner::BlockJacobi;
        for i in 0..self.n {
            let b = &mut self.precond[6 * i..6 * i + 6];
            if block {
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
                for k in 0..3 {
                    b[k] = if b[k] > 0.0 { 1.0 / b[k] } else { 0.0 };
                }
                for k in 3..6 {
                    b[k] = 0.0;
                }
            }
        }
    }

    /// q = K' p (matrix-free, all elements). The gradient kernel runs [`LANES`] elements at a time
    /// (structure-of-arrays, SIMD); the remainder and the packed kernel run element by element.
    #[inline(never)]
    fn apply_stiffness(&mut self) {
        self.q.iter_mut().for_each(|v| *v = 0.0);
        let packed = self.config.kernel == Kernel::Packed;
        let batched = if packed { 0 } else { self.t / LANES * LANES };
        let mut e0 = 0;
        while e0 < batched {
            let Lanes {
                ids,
                v,
                g,
                r,
                vol,
                lam,
                alp,
            } = self.gather_lanes(e0, self.p);
            let f = warped_apply_lanes(&v, &g, &r, &vol, &lam, &alp);
            for l in 0..LANES {
                for a in 0..4 {
                    let i = 3 * ids[a][l];
                    self.q[i] += f[a][0][l];
                    self.q[i + 1] += f[a][1][l];
                    self.q[i + 2] += f[a][2][l];
                }
            }
            e0 += LANES;
        }
        for e in batched..self.t {
            let ids = self.element_ids(e);
            let r = self.element_rot(e);
            let v = gather(self.p, &ids);
            let f = if packed {
                let base = 2 * 78 * e;
                let c: &[f32; 78] = self.cd[base..base + 78].try_into().unwrap_or(&[0.0; 78]);
                let d: &[f32; 78] = self.cd[base + 78..base + 156]
                    .try_into()
                    .unwrap_or(&[0.0; 78]);
                warped_apply_packed(&v, c, d, &r, self.lam[e], self.alp[e])
            } else {
                let g = self.element_grad(e);
                warped_apply(&v, &g, &r, self.vol[e], self.lam[e], self.alp[e])
            };
            scatter_add(self.q, &ids, &f);
        }
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

    /// Preconditioned CG for K' δ = r_full on the filtered space. Returns (iterations, ‖r‖, status).
    #[inline(never)]
    fn pcg(&mut self, scale: f32) -> (u32, f32, SolveStatus) {
        let tol = self.config.tolerance * scale + self.config.absolute_tolerance;
        self.delta.iter_mut().for_each(|v| *v = 0.0);
        self.r.copy_from_slice(self.r_full);
        Self::filter(self.flag, self.normal, self.r);
        self.precondition();
        self.p.copy_from_slice(self.z);
        let mut rz = dot(self.r, self.z);
        let mut rnorm = norm(self.r);
        let mut it = 0;
        while it < self.config.max_iterations {
            if rnorm <= tol {
                return (it, rnorm, SolveStatus::Converged);
            }
            self.apply_stiffness();
            // r_full tracks the unfiltered residual (reactions at held nodes); q is then filtered.
            // p is filtered, so p·(S q) = p·q.
            let pq = dot(self.p, self.q);
            if !(pq > 0.0) || !pq.is_finite() {
                return (it, rnorm, SolveStatus::Rejected);
            }
            let alpha = rz / pq;
            for k in 0..3 * self.n {
                self.delta[k] += alpha * self.p[k];
                self.r_full[k] -= alpha * self.q[k];
            }
            Self::filter(self.flag, self.normal, self.q);
            for k in 0..3 * self.n {
                self.r[k] -= alpha * self.q[k];
            }
            self.precondition();
            let rz_new = dot(self.r, self.z);
            let beta = rz_new / rz;
            rz = rz_new;
            for k in 0..3 * self.n {
                self.p[k] = self.z[k] + beta * self.p[k];
            }
            rnorm = norm(self.r);
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
        // A jump to an arbitrary state needs more than the per-tick warm-started iterations.
        self.update_rotations(50);
        blend_parameters(self);
    }

    /// Runs one tick. Never allocates; never panics on any state.
    pub fn tick(&mut self) -> TickReport {
        self.u_good.copy_from_slice(self.u);
        let load_fraction = self.advance_loads();
        self.update_rotations(self.config.rotation_iterations as usize);
        if self.tick_count % self.config.blend_every.max(1) as u64 == 0 {
            blend_parameters(self);
        }
        let contact_nodes = self.update_contact_set();
        self.apply_prescribed();
        self.residual_and_preconditioner();
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
            step = 0.0;
        }
        // Force on the probe: Σ over held nodes of r_full (= −contact force on the node).
        let mut reaction = [0.0f32; 3];
        for i in 0..self.n {
            if self.flag[i] == PROBED {
                for k in 0..3 {
                    reaction[k] += self.r_full[3 * i + k];
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
