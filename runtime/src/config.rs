//! Runtime configuration: solver budget, incremental-loading step, kernel and preconditioner.

/// Which matrix-free element kernel applies K' = Σ R_e K_e R_eᵀ.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kernel {
    /// Shape-function-gradient form (σ ∇φ), ~150 flops and 100 B per element: the default.
    Gradient,
    /// The model's packed C_e, D_e (eq. 3.63), ~400 flops and 624 B per element.
    Packed,
}

/// Preconditioner of the conjugate-gradient solve.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Preconditioner {
    /// Diagonal (Jacobi).
    Jacobi,
    /// 3 × 3 node blocks of K' (block Jacobi), exact for the rotated element blocks.
    BlockJacobi,
}

/// Settings of a [`crate::Runtime`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RuntimeConfig {
    /// PCG stops when ‖r‖ ≤ tolerance · scale (scale: applied load and probe reaction).
    pub tolerance: f32,
    /// PCG iterations allowed per tick (the tick's budget).
    pub max_iterations: u32,
    /// A cap on how far the applied load moves toward the commanded load in one tick (N), for
    /// callers that want a commanded change spread over many ticks (`palpate simulate`'s load
    /// ramp). `f32::INFINITY` (the default): each tick goes as far as its increments reach.
    pub load_step: f32,
    /// Incremental loading (seed 000 §6.1), the runtime's way to reach a commanded load: within a
    /// tick the applied load moves toward the commanded one in n equal increments, with
    /// n = ⌈‖f_cmd − f_app‖ / (load_increment · max(‖f_cmd‖, ‖f_app‖))⌉, each one a rotation
    /// update and a PCG solve. The increment is thus chosen from the load change: a probe that
    /// slides or presses a little harder changes the load by a small fraction and takes one
    /// increment (the haptic steady state costs nothing more), a step from rest to a load takes
    /// 1 / load_increment increments (0.25: four, as the fitter's default solve). The linear
    /// model (`warp` off) takes one increment (its answer does not depend on the path).
    pub load_increment: f32,
    /// Incremental loading exists to keep each linearised solve's rotation change small (the
    /// rotations are frozen during a solve). When the load rule above would split a load change
    /// and a load is already applied, the split is sized by the rotation change predicted
    /// instead: the rotations in force scale with the applied load (linear response), so a change
    /// of ‖∆f‖ turns elements by about θ_max ‖∆f‖ / ‖f_app‖ (θ_max the largest element rotation,
    /// [`crate::Runtime::largest_rotation`]), and the change takes ⌈that / rotation_increment⌉
    /// increments — never more than the load rule's. A probe whose lumped load jumps as a node
    /// crosses its rim (the load redistributed, a large vector change at small strain) then takes
    /// one increment instead of two; a step from rest (nothing applied: nothing to scale) keeps
    /// the load rule's. Radians; 0 turns the rotation rule off.
    pub rotation_increment: f32,
    /// Increments one tick may take (≥ 1). They share the tick's PCG budget (`max_iterations`):
    /// a tick stops incrementing when either runs out and reports how far the applied load got
    /// ([`crate::TickReport::load_remaining`]); the next tick goes on from there.
    pub max_load_increments: u32,
    /// The energy line search of the warped solve (`runtime/src/tick.rs`): a step whose end shows
    /// the corotational energy rising along it is cut back to the slope's root. Without it the
    /// lagged-rotation iteration cycles at large rotations instead of converging.
    pub line_search: bool,
    /// Position-driven probe: the probe moves toward its commanded position by at most this many
    /// metres per tick.
    pub probe_step: f32,
    /// Stiffness warping on (eqs. 3.53–3.54) or off (R_e = I, the linear model).
    pub warp: bool,
    /// Iterations of the warm-started rotation extraction per tick (at most).
    pub rotation_iterations: u32,
    /// The rotation extraction of an element stops early once a step turns its rotation by less
    /// than this multiple of `tolerance` (rad): a rotation off by δθ changes the element's force
    /// by about δθ of itself, so a rotation within the PCG's relative tolerance of the polar one
    /// leaves a residual the solve cannot see. Away from the probe an element turns by far less
    /// than that per tick, so one step leaves its rotation within the tolerance of the polar
    /// one, and the second of `rotation_iterations` would move it by less than that step did
    /// (test `the_rotation_tolerance_stops_only_converged_lanes`); the elements the load turns
    /// keep iterating. 0 runs every iteration.
    pub rotation_tolerance: f32,
    /// Element kernel.
    pub kernel: Kernel,
    /// Preconditioner.
    pub preconditioner: Preconditioner,
    /// Non-linear materials: re-blend parameters every this many ticks (≥ 1).
    pub blend_every: u32,
    /// Absolute residual floor (N) below which a solve counts as converged whatever the scale.
    pub absolute_tolerance: f32,
    /// Aggregates of the two-level preconditioner's coarse space (rigid modes per aggregate;
    /// 0 = block/point Jacobi only). Capped at nodes / 8.
    pub coarse_aggregates: u32,
    /// The block-Jacobi preconditioner (the 3 × 3 node blocks of K' = Σ R_e K_e R_eᵀ) is rebuilt
    /// only when K' has moved by more than this since it was last built (an upper bound summed
    /// over ticks): the rotations by this angle (rad), or a non-linear material's blended λ_e,
    /// α_e by this fraction of λ_e. A preconditioner only needs to be close: this changes
    /// iteration counts, never the solution. After a tick that ran PCG iterations a due rebuild
    /// waits for a tick after a quiet one, up to four times this move. 0 rebuilds it every tick.
    pub precond_refresh_angle: f32,
    /// Start each solve from the energy-optimal multiple of the previous tick's increment
    /// (a one-dimensional Galerkin predictor, one extra K' product; see `tick.rs`).
    pub predictor: bool,
    /// How [`crate::Runtime::set_contact_force`] spreads a force: the lumped rule static fits
    /// use (default), or the consistent rule whose loads are continuous in the contact point
    /// (a sliding probe; see [`crate::contact_rule`]).
    pub contact_rule: crate::contact_rule::ContactRule,
    /// Under the lumped rule, PCG iterations a tick may spend solving the load change of the
    /// probe's next predicted rim crossing ahead of time ([`crate::anticipate`]), after its own
    /// solve has converged and while that crossing is not solved yet; the crossing tick then
    /// starts from that solution. 0 turns anticipation off (and carves none of its memory).
    pub anticipation_iterations: u32,
}

impl Default for RuntimeConfig {
    fn default() -> Self {
        Self {
            tolerance: 1e-4,
            max_iterations: 200,
            load_step: f32::INFINITY,
            load_increment: 0.25,
            rotation_increment: 0.05,
            max_load_increments: 8,
            line_search: true,
            probe_step: f32::INFINITY,
            warp: true,
            rotation_iterations: 2,
            rotation_tolerance: 1.0,
            kernel: Kernel::Gradient,
            preconditioner: Preconditioner::BlockJacobi,
            blend_every: 1,
            absolute_tolerance: 1e-9,
            coarse_aggregates: 64,
            precond_refresh_angle: 0.05,
            predictor: true,
            contact_rule: crate::contact_rule::ContactRule::Lumped,
            anticipation_iterations: 3,
        }
    }
}
