//! One haptic tick: incremental loading (seed 000 §6.1) with warped stiffness and a
//! preconditioned conjugate-gradient solve under a fixed budget. This module only orchestrates;
//! the work is done by the rooms (see [`crate::runtime`]) and [`crate::pcg`].
//!
//! Per tick, following the synthesis loop of §6.1:
//! 1. the applied load f_k moves toward the commanded load by at most ∆f (and the probe by at
//!    most its step);
//! 2. R_e is recomputed from the current state x_k (eqs. 3.55–3.58, warm-started iteration);
//! 3. non-linear materials re-blend (λ_e, α_e) (eqs. 6.2–6.11);
//! 4. the system K' x_{k+1} = f_{k+1} + K'' x₀ (eq. 3.52) is solved in increment form:
//!    K' δ = f_{k+1} − f_int(x_k) with f_int(x) = Σ R_e K_e (R_eᵀ x_e − x₀_e), which is the same
//!    equation because K' x_k − K'' x₀ = f_int(x_k) for the frozen rotations; δ starts at the
//!    energy-optimal multiple of the previous tick's increment (the predictor,
//!    [`crate::pcg::predict`]: a probe sliding at constant speed makes the same increment every
//!    tick), so the solve is warm-started from the previous tick's solution extrapolated along
//!    its motion;
//! 5. the step is taken (or a non-finite / indefinite solve rejected) and the reaction on the
//!    probe reported.
//!
//! Constraints are filters on the CG vectors (modified PCG, Baraff & Witkin 1998): fixed nodes
//! have no free direction; probe-held nodes keep their two tangential directions (frictionless).

use crate::blend::blend_parameters;
use crate::pcg::{norm, pcg, predict, CgError, CgParams, Projection};
use crate::precond::TwoLevelApply;
use crate::runtime::Runtime;
use crate::stiffness::{residual_pass, Stiffness};
use palpate_protocol::model::Blend;

/// Outcome of one PCG solve.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SolveStatus {
    /// ‖r‖ ≤ tolerance · scale.
    Converged,
    /// The iteration budget ran out; the iterate was kept (it is usable) and the residual reported.
    BudgetExhausted,
    /// The solve produced a non-finite value or lost positive definiteness; the last good state
    /// was kept.
    Rejected,
}

/// What one tick did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickReport {
    /// PCG iterations used.
    pub iterations: u32,
    /// ‖r‖ / scale at exit.
    pub rel_residual: f32,
    /// Solve outcome.
    pub status: SolveStatus,
    /// ‖f_applied‖ / ‖f_commanded‖ (1 when nothing is commanded).
    pub load_fraction: f32,
    /// Nodes held by the probe.
    pub contact_nodes: u32,
    /// Force the object exerts on the probe (N), what a force-feedback device renders.
    pub reaction: [f32; 3],
    /// ‖δu‖_∞ of the step (m).
    pub step: f32,
}

impl Runtime<'_> {
    /// r_full = f_app − f_int(u), with R_e first when `rotate` (fused), and the preconditioner's
    /// node blocks when they are due.
    fn assemble(&mut self, rotate: Option<usize>) {
        let linear = matches!(self.record.blend, Blend::None);
        let diag = self.precond.due(self.config.precond_refresh_angle, linear);
        if diag {
            self.precond.begin_assembly();
        }
        let moved = residual_pass(
            &mut self.elements,
            &mut self.forces,
            self.nodes.u,
            self.nodes.f_app,
            self.nodes.r_full,
            rotate,
            if diag {
                Some(&mut *self.precond.blocks)
            } else {
                None
            },
        );
        self.precond.drift += moved;
        if diag {
            self.precond.invert(self.config.preconditioner);
        }
    }

    /// Solves K' δ = r_full on the filtered space (δ from zero, or from the predictor), tracking
    /// r_full. Returns (iterations, ‖S r‖, status).
    fn solve(&mut self, scale: f32) -> (u32, f32, SolveStatus) {
        let tol = self.config.tolerance * scale + self.config.absolute_tolerance;
        let nodes = &mut self.nodes;
        let work = &mut self.work;
        let contact = &self.contact;
        nodes.delta.iter_mut().for_each(|v| *v = 0.0);
        work.r.copy_from_slice(nodes.r_full);
        contact.project(work.r);
        let rnorm0 = norm(work.r);
        if rnorm0 <= tol {
            // Nothing to solve: skip the predictor and the preconditioner (most steady haptic
            // ticks).
            return (0, rnorm0, SolveStatus::Converged);
        }
        let mut k = Stiffness {
            elements: &self.elements,
            forces: &mut self.forces,
            kernel: self.config.kernel,
        };
        if self.config.predictor {
            predict(
                &mut k,
                contact,
                nodes.delta_prev,
                nodes.delta,
                nodes.r_full,
                work,
            );
        }
        let mut m = TwoLevelApply {
            precond: &mut self.precond,
            x0: nodes.x0,
            contact,
        };
        let params = CgParams {
            tolerance: tol,
            max_iterations: self.config.max_iterations,
        };
        match pcg(
            &mut k,
            &mut m,
            contact,
            nodes.delta,
            nodes.r_full,
            work,
            params,
        ) {
            Ok(info) => (info.iterations, info.residual, SolveStatus::Converged),
            Err(CgError::NoConvergence {
                iterations,
                residual,
            }) => (iterations, residual, SolveStatus::BudgetExhausted),
            Err(
                CgError::Breakdown {
                    iterations,
                    residual,
                }
                | CgError::NonFinite {
                    iterations,
                    residual,
                },
            ) => (iterations, residual, SolveStatus::Rejected),
        }
    }

    /// Runs one tick. Never allocates; never panics on any state.
    pub fn tick(&mut self) -> TickReport {
        // 1. Incremental loading.
        self.nodes.u_good.copy_from_slice(self.nodes.u);
        let load_fraction = self.nodes.advance_load(self.config.load_step);
        self.contact.advance_probe(self.config.probe_step);
        // The contact set and the probe-held positions use u and last tick's reactions only, so
        // they come first: rotations and forces are then those of the state being solved from.
        let contact_nodes = self.contact.update(&self.nodes);
        self.contact.apply_prescribed(self.nodes.x0, self.nodes.u);
        // 2–3. Rotations (and blending), then the residual and preconditioner.
        let iters = self.config.rotation_iterations as usize;
        if self.config.warp && matches!(self.record.blend, Blend::None) {
            // Linear material: rotations and internal forces in one pass.
            self.assemble(Some(iters));
        } else {
            // Blending needs every element's strain before any force.
            self.precond.drift +=
                self.elements
                    .update_rotations(self.nodes.u, self.config.warp, iters);
            // `%` rather than `is_multiple_of`: the workspace's MSRV is 1.85.
            #[allow(clippy::manual_is_multiple_of)]
            let due = self.tick_count % self.config.blend_every.max(1) as u64 == 0;
            if due {
                blend_parameters(&self.record, &self.nodes, &mut self.elements);
            }
            self.assemble(None);
        }
        // 4. The solve.
        let scale = norm(self.nodes.f_app).max(self.contact.reaction_norm);
        let (iterations, rnorm, mut status) = self.solve(scale);
        // 5. The step, the reaction.
        let nodes = &mut self.nodes;
        let mut step = 0.0f32;
        if status != SolveStatus::Rejected {
            for (u, d) in nodes.u.iter_mut().zip(nodes.delta.iter()) {
                step = step.max(d.abs());
                *u += d;
            }
            if !step.is_finite() || !nodes.u.iter().all(|v| v.is_finite()) {
                status = SolveStatus::Rejected;
            }
        }
        if status == SolveStatus::Rejected {
            // A non-finite or indefinite solve never replaces the last good state.
            nodes.u.copy_from_slice(nodes.u_good);
            nodes.delta_prev.iter_mut().for_each(|v| *v = 0.0);
            step = 0.0;
        } else {
            nodes.delta_prev.copy_from_slice(nodes.delta);
        }
        let reaction = self.contact.update_reaction(nodes.r_full);
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
