//! Incremental loading with stiffness warping (seed 000 §6.1): the load is applied in equal
//! increments; before each increment the rotations are recomputed from the current state, K'
//! assembled and factorised and K' x = f_k + K'' x₀ solved. At full load, fixed-point iterations
//! (rotations from the current state, solve) continue until the update moves no node by more than
//! the tolerance. A fixed point satisfies f_int(x) = Σ R_e K_e (R_eᵀx_e − x₀e) = f exactly.
//!
//! **Large loads.** The lagged-rotation iteration x ← K'(R(x))⁻¹ (f + K''(R(x)) x₀) has no
//! geometric stiffness: past a load where the rotations change a lot per solve it cycles instead
//! of converging (a 10 cm cantilever at twice the load that bends it by a third of its length
//! cycles with a 18 cm amplitude, at any number of increments). With R(x) the polar rotation,
//! f_int is the gradient of the corotational energy Π(x) = Σ ½ (R_eᵀx_e − x₀e)ᵀ K_e (R_eᵀx_e − x₀e)
//! − fᵀx, and each solve's step d = K'⁻¹(f − f_int(x)) is a descent direction of Π (K' is
//! positive definite). So every step is checked by the slope of Π along it at its end,
//! s(1) = −(f − f_int(x + d))·d with fresh rotations: when it is positive the step overshot the
//! minimum along d and is cut to the root of the slope's secant, t = s(0) / (s(0) − s(1)) (an exact
//! line search for a quadratic energy). Steps that do not overshoot are taken whole.

use std::sync::Arc;

use nalgebra::Matrix3;

use super::{Factorised, ForwardError, Load, Material, StaticProblem};

/// Solver options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveOptions {
    /// Number of load increments (≥ 1).
    pub increments: usize,
    /// Stiffness warping on (R_e from the current state) or off (R_e = I: linear FEM).
    pub warp: bool,
    /// Fixed-point tolerance: stop when max_i ‖x_i^{k+1} − x_i^k‖ ≤ this (m).
    pub tolerance: f64,
    /// Maximum fixed-point iterations at full load.
    pub max_fixed_point: usize,
    /// Keep a factorisation of K' across increments and fixed-point iterations while it still
    /// serves (see [`StaticProblem::solve_forces_with`]): each such iteration costs an assembly,
    /// a residual and two triangular solves instead of a numeric Cholesky. The fixed point is the
    /// same — the residual of every iteration is the exact one — only the path to it changes,
    /// and the returned factor may be a few rotations stale (fine for preconditioning and warm
    /// starts; the static fitter's adjoint keeps `false` and gets the factor of the final state).
    pub reuse_factor: bool,
}

impl Default for SolveOptions {
    fn default() -> Self {
        Self {
            increments: 10,
            warp: true,
            tolerance: 1e-10,
            max_fixed_point: 100,
            reuse_factor: false,
        }
    }
}

/// A solved static state.
#[derive(Debug, Clone)]
pub struct Solution {
    /// Deformed node positions x (m).
    pub x: Vec<[f64; 3]>,
    /// Element rotations R_e of the last solve (computed from the state before it).
    pub rotations: Vec<Matrix3<f64>>,
    /// Linear solves performed (increments + fixed-point iterations).
    pub iterations: usize,
    /// Largest node move of the last fixed-point iteration (m).
    pub last_change: f64,
    /// Whether the fixed point reached `tolerance` within `max_fixed_point` iterations.
    pub converged: bool,
}

/// A solution together with the factorisation of the last solve (reused for Jacobian products).
pub struct SolvedWithFactor {
    /// The converged solution.
    pub solution: Solution,
    /// The last tangent's factorisation, reused for adjoint solves (shared: a caller may hand it
    /// back to [`StaticProblem::solve_forces_with`] for the next, nearby solve).
    pub factor: Arc<Factorised>,
}

fn max_move(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| {
            ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
        })
        .fold(0.0, f64::max)
}

impl StaticProblem {
    /// The material gives the foundation a positive, finite stiffness exactly when the problem
    /// rests on one.
    pub fn check_foundation(&self, material: &Material) -> Result<(), ForwardError> {
        match (&material.foundation, self.foundation.is_empty()) {
            (None, true) => Ok(()),
            (Some(_), true) => Err(ForwardError::FoundationStiffness(
                "the material gives a foundation stiffness, but this problem's supports are fixed"
                    .into(),
            )),
            (None, false) => Err(ForwardError::FoundationStiffness(format!(
                "the problem rests {} nodes on an elastic foundation, and the material gives it no stiffness",
                self.foundation.len()
            ))),
            (Some(k), false) => {
                if k.normal.is_finite() && k.tangential.is_finite() && k.normal > 0.0 && k.tangential > 0.0 {
                    Ok(())
                } else {
                    Err(ForwardError::FoundationStiffness(format!(
                        "k_n = {:e}, k_t = {:e} Pa/m: both must be positive and finite",
                        k.normal, k.tangential
                    )))
                }
            }
        }
    }

    /// Slope −(f − f_int)·d of the corotational energy along `d`, over the free dofs, from the
    /// load `fk` and the internal forces `fint` at the point where it is taken.
    fn energy_slope(&self, fk: &[f64], fint: &[f64], d: &[[f64; 3]]) -> f64 {
        let mut s = 0.0;
        for (n, &free) in self.free_index.iter().enumerate() {
            if free == usize::MAX {
                continue;
            }
            for k in 0..3 {
                s -= (fk[3 * n + k] - fint[3 * n + k]) * d[n][k];
            }
        }
        s
    }

    /// Solves the static problem for `load` with incremental loading and warping (§6.1).
    pub fn solve(
        &self,
        material: &Material,
        load: &Load,
        options: &SolveOptions,
    ) -> Result<Solution, ForwardError> {
        let f = self.force_vector(load)?;
        if let Some(model) = &self.discretised {
            let x = self.solve_discretised(model, material, &f, options.warp)?;
            return Ok(Solution {
                x,
                rotations: vec![Matrix3::identity(); self.tets.len()],
                iterations: 1,
                last_change: 0.0,
                converged: true,
            });
        }
        Ok(self.solve_forces(material, &f, None, options)?.solution)
    }

    /// Like [`StaticProblem::solve`] for a full 3n force vector, optionally warm-started from
    /// `start` (then the full load is applied at once and only fixed-point iterations run).
    pub fn solve_forces(
        &self,
        material: &Material,
        f_ext: &[f64],
        start: Option<&[[f64; 3]]>,
        options: &SolveOptions,
    ) -> Result<SolvedWithFactor, ForwardError> {
        self.solve_forces_with(material, f_ext, start, options, None)
    }

    /// [`StaticProblem::solve_forces`] that may start from a factorisation made for a nearby
    /// problem (`hint`: the same mesh, a slightly different material or state — a Jacobian column,
    /// a line-search trial) when [`SolveOptions::reuse_factor`] is on.
    ///
    /// With a kept factorisation F of K'(R_F), one iteration is the stationary step
    /// x ← x + F⁻¹ (b(R) − K'(R) x) with R the rotations of the current x: where F = K'(R) it is
    /// exactly the fixed-point step x ← K'(R)⁻¹ b(R), and near it the same fixed point is reached
    /// (the residual is exact). F is renewed when the rotations have moved away from R_F by more
    /// than `REFACTOR_ROTATION` (0.05 rad) in some element, or when an iteration at full load contracts
    /// the update by less than `REFACTOR_CONTRACTION` (0.6; a hint made for another material shows
    /// itself this way).
    pub fn solve_forces_with(
        &self,
        material: &Material,
        f_ext: &[f64],
        start: Option<&[[f64; 3]]>,
        options: &SolveOptions,
        hint: Option<&Arc<Factorised>>,
    ) -> Result<SolvedWithFactor, ForwardError> {
        if let Some(model) = &self.discretised {
            return Err(ForwardError::Discretisation {
                discretisation: model.kind().name(),
                reason: "has no factorisation of the linear model's K' to hand back: call `solve`",
            });
        }
        material.check(self.tets.len())?;
        self.check_foundation(material)?;
        if f_ext.len() != 3 * self.x0.len() {
            return Err(ForwardError::Length {
                what: "force vector",
                found: f_ext.len(),
                expected: 3 * self.x0.len(),
            });
        }
        let mut x: Vec<[f64; 3]> = match start {
            Some(s) if s.len() == self.x0.len() => s.to_vec(),
            Some(s) => {
                return Err(ForwardError::Length {
                    what: "start positions",
                    found: s.len(),
                    expected: self.x0.len(),
                })
            }
            None => self.x0.clone(),
        };
        let increments = if start.is_some() {
            1
        } else {
            options.increments.max(1)
        };
        let reuse = options.reuse_factor && options.warp;
        // The kept factorisation and the rotations it was made with (None: made elsewhere).
        let mut kept: Option<(Arc<Factorised>, Option<Vec<Matrix3<f64>>>)> = match hint {
            Some(h) if reuse && start.is_some() && h.dim() == self.free_dofs() => {
                Some((Arc::clone(h), None))
            }
            _ => None,
        };
        let mut iterations = 0;
        // Rotations and internal forces at the current x when already known: the line search
        // takes them at the end of each step, where the next step starts.
        let mut at_x: Option<(Vec<Matrix3<f64>>, Vec<f64>)> = None;
        // One iteration at load `fraction`: returns the new state, the rotations used and the
        // largest node move. `fresh` forces a new factorisation.
        let step = |x: &[[f64; 3]],
                    fraction: f64,
                    fresh: bool,
                    kept: &mut Option<(Arc<Factorised>, Option<Vec<Matrix3<f64>>>)>,
                    at_x: &mut Option<(Vec<Matrix3<f64>>, Vec<f64>)>,
                    iterations: usize|
         -> Result<(Vec<[f64; 3]>, Vec<Matrix3<f64>>, f64), ForwardError> {
            let (rot, fint_x) = match at_x.take() {
                Some((r, f)) => (r, Some(f)),
                None => (self.rotations(x, options.warp), None),
            };
            let fk: Vec<f64> = f_ext.iter().map(|v| v * fraction).collect();
            let usable = reuse
                && !fresh
                && match kept {
                    Some((_, Some(r_f))) => max_rotation_change(r_f, &rot) <= REFACTOR_ROTATION,
                    Some((_, None)) => true,
                    None => false,
                };
            let (b, xn, fint_x) = if usable {
                // b(R) − K'(R) x = f − f_int(x) over the free dofs (eqs. 3.50, 3.53): the
                // residual without assembling K'.
                let (factor, _) = kept.as_ref().expect("usable implies kept");
                let fint = fint_x.unwrap_or_else(|| self.internal_forces(material, &rot, x));
                let r: Vec<f64> = fk.iter().zip(&fint).map(|(a, b)| a - b).collect();
                let mut d = self.gather_free(&r);
                factor.solve_in_place(&mut d);
                let xn: Vec<[f64; 3]> = x
                    .iter()
                    .zip(&self.free_index)
                    .map(|(p, &fi)| {
                        if fi == usize::MAX {
                            *p
                        } else {
                            [0, 1, 2].map(|k| p[k] + d[3 * fi + k])
                        }
                    })
                    .collect();
                (d, xn, Some(fint))
            } else {
                let mut b = self.rhs(material, &rot, &fk);
                let factor = self.factorise(material, &rot)?;
                factor.solve_in_place(&mut b);
                *kept = Some((Arc::new(factor), Some(rot.clone())));
                let xn = self.positions_from_free(&b);
                (b, xn, fint_x)
            };
            if !b.iter().all(|v| v.is_finite()) {
                return Err(ForwardError::NonFinite {
                    increment: iterations,
                });
            }
            // The energy line search of the module docs (warped only: a linear solve is exact).
            let xn = if options.warp {
                let d: Vec<[f64; 3]> = xn
                    .iter()
                    .zip(x)
                    .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
                    .collect();
                let fint_x = fint_x.unwrap_or_else(|| self.internal_forces(material, &rot, x));
                let s0 = self.energy_slope(&fk, &fint_x, &d);
                let (rot_n, fint_n) = self.rotations_and_forces(material, &xn, true);
                let s1 = self.energy_slope(&fk, &fint_n, &d);
                // Cutting only the steps that raised the energy (s1 > −s0) was measured slower
                // (73 solves against 47 at 0.25 N on the cantilever).
                if s0 < 0.0 && s1 > 0.0 {
                    // Root of the slope's secant, kept away from a zero step.
                    let t = (s0 / (s0 - s1)).clamp(0.05, 1.0);
                    x.iter()
                        .zip(&d)
                        .map(|(p, q)| [p[0] + t * q[0], p[1] + t * q[1], p[2] + t * q[2]])
                        .collect()
                } else {
                    *at_x = Some((rot_n, fint_n));
                    xn
                }
            } else {
                xn
            };
            let change = max_move(&xn, x);
            Ok((xn, rot, change))
        };
        let mut last = None;
        for k in 1..=increments {
            iterations += 1;
            let (xn, rot, change) = step(
                &x,
                k as f64 / increments as f64,
                false,
                &mut kept,
                &mut at_x,
                iterations,
            )?;
            x = xn;
            last = Some((rot, change));
        }
        let (mut rot, mut change) = last.expect("at least one increment");
        let mut converged = !options.warp;
        if options.warp {
            // Fixed point at full load; the first iteration always runs because the last
            // increment's rotations came from the state before it.
            let mut previous = f64::INFINITY;
            let mut fresh = false;
            let mut fixed = 0;
            let mut stale_steps = 0;
            // A stale factor's iterations are cheap; they may take more of them than fresh
            // ones would, so they are counted apart from `max_fixed_point`.
            while fixed < options.max_fixed_point {
                iterations += 1;
                let made_before = kept.as_ref().map(|(f, _)| Arc::as_ptr(f));
                let (xn, r, c) = step(&x, 1.0, fresh, &mut kept, &mut at_x, iterations)?;
                let refactored = kept.as_ref().map(|(f, _)| Arc::as_ptr(f)) != made_before;
                if refactored {
                    fixed += 1;
                    stale_steps = 0;
                } else {
                    stale_steps += 1;
                    if stale_steps > 4 * options.max_fixed_point.max(1) {
                        fixed = options.max_fixed_point;
                    }
                }
                x = xn;
                rot = r;
                change = c;
                if change <= options.tolerance {
                    converged = true;
                    break;
                }
                // A stale factor that no longer contracts the update well is renewed.
                fresh = !refactored && change > REFACTOR_CONTRACTION * previous;
                previous = change;
            }
        }
        let factor = match kept {
            Some((f, Some(r_f))) if !reuse || max_rotation_change(&r_f, &rot) == 0.0 => f,
            Some((f, _)) if reuse => f,
            _ => Arc::new(self.factorise(material, &rot)?),
        };
        Ok(SolvedWithFactor {
            solution: Solution {
                x,
                rotations: rot,
                iterations,
                last_change: change,
                converged,
            },
            factor,
        })
    }
}

/// A kept factorisation is renewed once some element's rotation has moved by more than this
/// (‖R_e − R_e^F‖_F, ≈ the angle in radians for small angles) since it was made: the stationary
/// step's contraction factor grows with that angle, and at 0.05 rad (3°) it stays below ≈ 0.1.
pub const REFACTOR_ROTATION: f64 = 0.05;

/// At full load a kept factorisation is renewed when an iteration shrinks the update by less
/// than this factor (a fresh fixed-point iteration of the warped model contracts by ≈ 0.2–0.4 on
/// the specimens here; slower than this means the factor is what limits the rate).
pub const REFACTOR_CONTRACTION: f64 = 0.6;

fn max_rotation_change(a: &[Matrix3<f64>], b: &[Matrix3<f64>]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| (p - q).norm())
        .fold(0.0, f64::max)
}
