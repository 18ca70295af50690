//! One haptic tick: incremental loading (seed 000 §6.1) with warped stiffness and a
//! preconditioned conjugate-gradient solve under a fixed budget. This module only orchestrates;
//! the work is done by the rooms (see [`crate::runtime`]) and [`crate::pcg`].
//!
//! Per tick, following the synthesis loop of §6.1 (the probe first moves by at most its step and
//! the contact set is updated), steps 1–5 run once per load increment:
//! 1. the applied load f_k moves toward the commanded load by one increment ∆f, chosen from the
//!    load change ([`crate::RuntimeConfig::load_increment`]): one increment for the small changes
//!    of a sliding or pressing probe, several for a step — sized, once a load is applied, by the
//!    rotation change the load change is predicted to cause
//!    ([`crate::RuntimeConfig::rotation_increment`]), so a load redistributed at small strain (a
//!    node crossing a lumped probe's rim) is one increment; the increments share the tick's PCG
//!    budget, and a tick that runs out of budget or increments
//!    ([`crate::RuntimeConfig::max_load_increments`]) stops with the load partly applied and says
//!    so ([`TickReport::load_remaining`]);
//! 2. R_e is recomputed from the current state x_k (eqs. 3.55–3.58, warm-started iteration;
//!    an element whose step turns it by less than the PCG's tolerance stops there,
//!    [`crate::RuntimeConfig::rotation_tolerance`]);
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
//! **The energy line search.** Step 4 with the rotations frozen is the lagged-rotation fixed
//! point: it has no geometric stiffness, and at large rotations it cycles instead of converging
//! (the 10 cm cantilever of the runtime evidence at twice the load that bends it by a third of its
//! length). With R_e the polar rotation, f_int is the gradient of the corotational energy
//! Π(x) = Σ ½ (R_eᵀx_e − x₀e)ᵀ K_e (R_eᵀx_e − x₀e) − f·u, and the solve's step δ is a descent
//! direction of Π (K' is positive definite). The next residual pass — the next increment's or the
//! next tick's, which recomputes rotations and f_int at x + δ anyway — gives the slope of Π along δ
//! at its end, s(1) = −(f − f_int(x + δ))·δ at the load δ was solved for (the load applied since is
//! taken out: f changed by ∆f adds ∆f·δ). When s(1) > 0 the step overshot the minimum along δ and
//! is cut to the root of the slope's secant, t = s(0)/(s(0) − s(1)), and the pass repeated at
//! x + tδ. So the check costs nothing while steps do not overshoot (every haptic steady tick), one
//! residual pass when they do. The offline solver does the same (`palpate_fem::forward::solve`).
//!
//! **The quiet tick.** Steps 2–3 are a pass over every element, most of the cost of a tick that
//! solves nothing. When the last pass was made at the same u and applied load, its rotations had
//! settled — none turned by more than the rotation tolerance, where the extraction itself stops
//! ([`crate::RuntimeConfig::rotation_tolerance`]) — and no preconditioner refresh is due, another
//! pass would only turn them by less and leave a residual the solve cannot tell from the one it
//! has, so the tick reuses that residual ([`TickReport::passes`] 0). Such ticks are the still
//! ticks of a sliding lumped probe between its rim crossings and every tick of a load held still.
//! A blended material's parameters move with its blend, so it always gets its pass.
//!
//! Constraints are filters on the CG vectors (modified PCG, Baraff & Witkin 1998): fixed nodes
//! have no free direction; probe-held nodes keep their two tangential directions (frictionless).

use crate::anticipate::Fired;
use crate::blend::blend_parameters;
use crate::pcg::{dot, norm, pcg, predict, predict_subspace, CgError, CgParams, Projection};
use crate::runtime::Runtime;
use crate::stiffness::{residual_pass, KeepRotations, Stiffness};
use crate::two_level::TwoLevelApply;
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
    /// ‖f_commanded − f_applied‖ after the tick (N): how much of the commanded load this tick
    /// could not reach (its increments or PCG budget ran out); 0 when it is all applied.
    pub load_remaining: f32,
    /// Load increments the tick took (each a rotation update and a PCG solve).
    pub increments: u32,
    /// The smallest step factor the line search applied this tick (1: no step was cut).
    pub line_search: f32,
    /// Nodes held by the probe.
    pub contact_nodes: u32,
    /// Force the object exerts on the probe (N), what a force-feedback device renders.
    pub reaction: [f32; 3],
    /// ‖δu‖_∞ of the step (m).
    pub step: f32,
    /// The tick started from anticipated solves ([`crate::anticipate`]): a planned rim crossing
    /// of a lumped probe happened in it, or it took the correction of one that happened in the
    /// tick before.
    pub anticipated: bool,
    /// PCG iterations (a residual recomputed counting as one) the tick spent after its own solve
    /// on the planned crossings ([`crate::RuntimeConfig::anticipation_iterations`]).
    pub iterations_ahead: u32,
    /// Passes over the elements that formed the residual (rotations and internal forces): one
    /// per load increment and line-search cut, none in a quiet tick that reused the last pass's
    /// (module docs, "The quiet tick").
    pub passes: u32,
}

/// Where a tick's first solve starts besides the last increment: the planned direction of a
/// crossing that happened, the correction due from the tick before (`crate::anticipate`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
struct Start {
    planned: bool,
    pending: bool,
}

impl Runtime<'_> {
    /// r_full = f_app − f_int(u), with R_e first when `rotate` (fused), and the preconditioner's
    /// node blocks when they are due. Returns how far any rotation moved (rad, an upper bound).
    fn assemble(&mut self, rotate: Option<(usize, f32)>) -> f32 {
        let diag = self
            .precond
            .due(self.config.precond_refresh_angle, self.last_solved);
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
            KeepRotations::State,
        );
        self.precond.drift += moved;
        if diag {
            self.precond.invert(self.config.preconditioner);
            self.anticipation.operator_changed();
        }
        moved
    }

    /// Solves K' δ = r_full on the filtered space (δ from zero, or from the predictor: along the
    /// last increment, or — when `start` says so — on the span of a planned crossing's direction
    /// and a correction due, [`crate::anticipate`]), tracking r_full. Returns (iterations, ‖S r‖,
    /// status).
    fn solve(&mut self, scale: f32, max_iterations: u32, start: Start) -> (u32, f32, SolveStatus) {
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
        // The predictor and the PCG track r_full from here: it is no longer the pass's.
        self.pass_settled = false;
        let mut k = Stiffness {
            elements: &self.elements,
            forces: &mut self.forces,
            kernel: self.config.kernel,
            rotated: None,
        };
        if self.config.predictor {
            let a = &mut self.anticipation;
            let mut directions: [&[f32]; 2] = [&[], &[]];
            let mut count = 0;
            for (d, take) in [(&*a.r, start.planned), (&*a.pending, start.pending)] {
                if take {
                    directions[count] = d;
                    count += 1;
                }
            }
            if count == 0 {
                predict(
                    &mut k,
                    contact,
                    nodes.delta_prev,
                    nodes.delta,
                    nodes.r_full,
                    work,
                );
            } else {
                // The anticipated solves' own vectors are the scratch; their solve restarts.
                a.carry = None;
                let mut scratch: [&mut [f32]; 4] =
                    [&mut *a.z, &mut *a.p, &mut *a.r_full, &mut *work.p];
                predict_subspace(
                    &mut k,
                    contact,
                    &directions[..count],
                    nodes.delta,
                    nodes.r_full,
                    work.r,
                    &mut scratch,
                );
            }
        }
        let mut m = TwoLevelApply {
            precond: &mut self.precond,
            x0: nodes.x0,
            contact,
        };
        let params = CgParams {
            tolerance: tol,
            max_iterations,
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

    /// Rotations (and, for non-linear materials, blended parameters) from the current state, then
    /// the residual r_full = f_app − f_int(u) and the preconditioner when due — or nothing in a
    /// quiet tick (module docs, "The quiet tick").
    fn refresh(&mut self) {
        let iters = self.config.rotation_iterations as usize;
        let tolerance = self.config.rotation_tolerance * self.config.tolerance;
        let linear_material = matches!(self.record.blend, Blend::None);
        if linear_material
            && self.pass_settled
            && !self
                .precond
                .due(self.config.precond_refresh_angle, self.last_solved)
            && self.nodes.u == self.nodes.u_pass
        {
            return;
        }
        self.passes += 1;
        // `%` rather than `is_multiple_of`: the workspace's MSRV is 1.85.
        #[allow(clippy::manual_is_multiple_of)]
        let due = self.tick_count % self.config.blend_every.max(1) as u64 == 0;
        let moved = match (self.config.warp, &self.record.blend) {
            // Linear material: rotations and internal forces in one pass.
            (true, Blend::None) => self.assemble(Some((iters, tolerance))),
            // Deformation-space blending reads the node positions only, so it goes first and
            // the rotations stay fused with the forces (one pass over the elements fewer than
            // rotations, blend, forces; the same rotations and parameters).
            (true, Blend::Deformation { .. }) => {
                if due {
                    self.precond.drift +=
                        blend_parameters(&self.record, &self.nodes, &mut self.elements);
                }
                self.assemble(Some((iters, tolerance)))
            }
            _ => {
                // Strain-space blending needs every element's strain before any force.
                let moved = self.elements.update_rotations(
                    self.nodes.u,
                    self.config.warp,
                    iters,
                    tolerance,
                );
                self.precond.drift += moved;
                if due {
                    self.precond.drift +=
                        blend_parameters(&self.record, &self.nodes, &mut self.elements);
                }
                self.assemble(None);
                moved
            }
        };
        // Only a settled pass (of a linear material) is ever reused: only then is u kept for the
        // check.
        self.pass_settled = linear_material && moved <= tolerance;
        if self.pass_settled {
            self.nodes.u_pass.copy_from_slice(self.nodes.u);
        }
    }

    /// The line search's check of the last step δ (`delta_prev`) with r_full just refreshed at its
    /// end: cuts the step back when the energy rises there (module docs). `slope0` is s(0),
    /// `along` the load change since the step times δ. Returns the step factor t (1: kept).
    fn check_last_step(&mut self, slope0: f32, along: f32) -> f32 {
        let nodes = &mut self.nodes;
        let slope1 = along - dot(nodes.r_full, nodes.delta_prev);
        // Cutting only the steps that raised the energy (s(1) > −s(0)) was measured slower: at
        // 0.25 N on the cantilever 46 ticks to settle against 34 with every overshoot cut.
        if !(slope0 < 0.0 && slope1 > 0.0) {
            return 1.0;
        }
        // Root of the slope's secant, kept away from a zero step.
        let t = (slope0 / (slope0 - slope1)).clamp(0.05, 1.0);
        for (u, d) in nodes.u.iter_mut().zip(nodes.delta_prev.iter_mut()) {
            *u -= (1.0 - t) * *d;
            *d *= t;
        }
        self.refresh();
        t
    }

    /// Increments a load change of `gap` newtons needs by the rotation change it is predicted to
    /// cause, θ_max · gap / ‖f_app‖ over [`crate::RuntimeConfig::rotation_increment`] (see there);
    /// infinite when nothing is applied yet or the rule is off (the load rule decides).
    fn rotation_increments(&self, gap: f32) -> f32 {
        let applied = norm(self.nodes.f_app);
        let step = self.config.rotation_increment;
        if !(applied > 0.0 && step > 0.0) {
            return f32::INFINITY;
        }
        let predicted = self.elements.largest_rotation() * gap / applied;
        if predicted.is_finite() {
            libm::ceilf(predicted / step).max(1.0)
        } else {
            f32::INFINITY
        }
    }

    /// Runs one tick. Never allocates; never panics on any state.
    pub fn tick(&mut self) -> TickReport {
        self.passes = 0;
        self.nodes.u_good.copy_from_slice(self.nodes.u);
        self.contact.advance_probe(self.config.probe_step);
        // The contact set and the probe-held positions use u and last tick's reactions only, so
        // they come first: rotations and forces are then those of the state being solved from.
        let contact_nodes = self.contact.update(&self.nodes);
        self.contact.apply_prescribed(self.nodes.x0, self.nodes.u);
        let weight = &*self.contact.weight;
        let fired = self
            .anticipation
            .fired(|i| weight.get(i).is_some_and(|w| *w != 0.0));
        let planned = match fired {
            Fired::Planned(mask) => self.anticipation.planned_direction(mask),
            _ => false,
        };
        let correction_due = self.anticipation.pending_ready;
        // The line search compares energies along the last step at one load: a probe that holds
        // nodes moves them between ticks and changes the problem, so its check is dropped.
        let mut pending = self.pending_slope.take().filter(|_| contact_nodes == 0);
        let warped = self.config.warp;
        let budget = self.config.max_iterations;
        let max_increments = if warped {
            self.config.max_load_increments.max(1)
        } else {
            1
        };
        let mut allowance = self.config.load_step;
        let mut iterations = 0u32;
        let mut increments = 0u32;
        let mut step = 0.0f32;
        let mut cut = 1.0f32;
        let (status, rnorm, scale) = loop {
            // 1. One load increment, chosen from the load change.
            let gap = self.nodes.load_gap();
            let along = if gap > 0.0 && allowance > 0.0 {
                let reach =
                    self.config.load_increment * self.nodes.f_cmd_norm.max(norm(self.nodes.f_app));
                let left = max_increments.saturating_sub(increments).max(1) as f32;
                let n = if warped && reach > 0.0 && reach.is_finite() {
                    let by_load = libm::ceilf(gap / reach);
                    if by_load > 1.0 {
                        by_load.min(self.rotation_increments(gap)).clamp(1.0, left)
                    } else {
                        1.0
                    }
                } else {
                    1.0
                };
                let inc = (gap / n).min(allowance);
                allowance -= inc;
                // The pass's residual was for the load before.
                self.pass_settled = false;
                self.nodes.advance_load(inc)
            } else {
                0.0
            };
            // 2–3. Rotations (and blending), the residual and the preconditioner, and the line
            // search's check of the last step.
            self.refresh();
            if let Some(s0) = pending.take() {
                if self.config.line_search && warped {
                    cut = cut.min(self.check_last_step(s0, along));
                }
            }
            // 4. The solve, in what is left of the budget.
            let scale = norm(self.nodes.f_app).max(self.contact.reaction_norm);
            self.nodes.r_start.copy_from_slice(self.nodes.r_full);
            // The tick's first increment starts from the anticipated solves when a planned
            // crossing happened or a crossing's correction is due (`crate::anticipate`).
            let start = Start {
                planned: planned && increments == 0,
                pending: correction_due && increments == 0,
            };
            let (its, rnorm, mut status) =
                self.solve(scale, budget.saturating_sub(iterations), start);
            iterations += its;
            increments += 1;
            // 5. The step.
            let nodes = &mut self.nodes;
            let mut inc_step = 0.0f32;
            if status != SolveStatus::Rejected {
                for (u, d) in nodes.u.iter_mut().zip(nodes.delta.iter()) {
                    inc_step = inc_step.max(d.abs());
                    *u += d;
                }
                if !inc_step.is_finite() || !nodes.u.iter().all(|v| v.is_finite()) {
                    status = SolveStatus::Rejected;
                }
            }
            if status == SolveStatus::Rejected {
                // A non-finite or indefinite solve never replaces the last good state.
                nodes.u.copy_from_slice(nodes.u_good);
                nodes.delta_prev.iter_mut().for_each(|v| *v = 0.0);
                step = 0.0;
                break (status, rnorm, scale);
            }
            step = step.max(inc_step);
            nodes.delta_prev.copy_from_slice(nodes.delta);
            // s(0) = −r₀·δ, the energy's slope at the step's start (δ is filtered, so the
            // unfiltered r₀ gives the same product).
            let slope0 = -dot(nodes.r_start, nodes.delta);
            pending = (its > 0).then_some(slope0);
            let more = nodes.load_gap() > 0.0
                && allowance > 0.0
                && increments < max_increments
                && iterations < budget
                && status == SolveStatus::Converged;
            if !more {
                break (status, rnorm, scale);
            }
        };
        self.pending_slope = pending;
        self.last_solved = iterations > 0;
        let reaction = self.contact.update_reaction(self.nodes.r_full);
        self.tick_count += 1;
        // A crossing that happened hands on its plan; a moved state is a new operator. Only a
        // still tick (nothing solved, nothing moved) has the time and the operator to go on.
        let mut ahead = 0;
        if fired != Fired::Nothing {
            self.anticipation.advance(fired);
        } else {
            self.anticipation.pending_ready = false;
            if step > 0.0 || status != SolveStatus::Converged {
                self.anticipation.operator_changed();
            } else if iterations == 0 {
                ahead = self.anticipate();
            }
        }
        TickReport {
            iterations,
            rel_residual: if scale > 0.0 { rnorm / scale } else { rnorm },
            status,
            load_fraction: self.nodes.load_fraction(),
            load_remaining: self.nodes.load_gap(),
            increments,
            line_search: cut,
            contact_nodes,
            reaction,
            step,
            anticipated: planned || correction_due,
            iterations_ahead: ahead,
            passes: self.passes,
        }
    }
}
