//! The PCG's preconditioner: the 3 × 3 node blocks of K' (block Jacobi, or their diagonal for
//! Jacobi) plus the coarse correction of rigid modes on aggregates ([`crate::coarse`]), an
//! additive two-level Schwarz preconditioner M⁻¹, filtered by the constraints: z = S M⁻¹ r.
//!
//! This room changes when the preconditioner or its refresh policy changes.

use crate::coarse::Coarse;
use crate::config::Preconditioner as Kind;
use crate::contact_set::ContactSet;
use crate::error::RuntimeError;
use crate::pcg::{Preconditioner, Projection};
use crate::storage::{Carver, Dims, RoomLayout};

/// Node blocks and coarse space.
pub(crate) struct TwoLevel<'a> {
    /// The inverted node blocks (xx, yy, zz, xy, yz, zx), 6 per node.
    pub blocks: &'a mut [f32],
    /// Whether `blocks` holds the (inverted) blocks of some recent K'.
    pub valid: bool,
    /// Upper bound of how far K' moved since `blocks` was built, relative: the rotations' angle
    /// (rad) plus, for blended materials, the parameters' relative change
    /// ([`crate::blend::blend_parameters`]).
    pub drift: f32,
    /// The coarse space (sized for [`Dims::aggregates`]).
    pub coarse: Coarse<'a>,
}

impl<'a> TwoLevel<'a> {
    /// The room's arrays, in carving order (see [`crate::storage::Layout`]).
    pub(crate) const fn layout(d: &Dims) -> RoomLayout<2, 1> {
        RoomLayout {
            f32s: [6 * d.nodes, crate::coarse::coarse_f32s(d.aggregates)],
            u32s: [d.nodes],
        }
    }

    /// Cuts the room from the pools (zeroed; [`Coarse::build`] fills the coarse space).
    pub(crate) fn carve(
        layout: RoomLayout<2, 1>,
        d: &Dims,
        f: &mut Carver<'a, f32>,
        u: &mut Carver<'a, u32>,
    ) -> Result<Self, RuntimeError> {
        let ([blocks, coarse], [agg]) = layout.carve(f, u)?;
        Ok(Self {
            blocks,
            valid: false,
            drift: 0.0,
            coarse: Coarse::new(d.aggregates, agg, coarse),
        })
    }

    /// Whether the node blocks must be rebuilt this tick: never built, or K' moved by more than
    /// `refresh_angle` since (see [`crate::RuntimeConfig::precond_refresh_angle`]): rotations
    /// by that angle, or a blended material's λ_e, α_e by that fraction of λ_e. A stale block
    /// only costs PCG iterations — the solve's residual is K' of the tick's own state — so a
    /// slowly sliding probe on a blended model no longer rebuilds it every tick.
    ///
    /// After a tick that ran PCG iterations (`busy`) a refresh that is due waits for a tick after
    /// a quiet one (its solve starts from the blocks it has), unless K' moved by more than
    /// [`DEFER_LIMIT`] times the angle. A lumped probe's crossing moves the state in three
    /// ticks; the third, where the rotations settle, is the slowest of a 10k block's ticks, and
    /// the refresh then falls in the quiet ticks after it instead.
    pub(crate) fn due(&self, refresh_angle: f32, busy: bool) -> bool {
        let limit = if busy && refresh_angle > 0.0 {
            DEFER_LIMIT * refresh_angle
        } else {
            refresh_angle
        };
        !self.valid || self.drift > limit
    }

    /// Zeroes the node blocks before an assembly pass adds the element blocks into them.
    pub(crate) fn begin_assembly(&mut self) {
        self.blocks.iter_mut().for_each(|v| *v = 0.0);
        self.valid = true;
        self.drift = 0.0;
    }

    /// Inverts the assembled 3 × 3 node blocks in place (or keeps their inverted diagonal for
    /// Jacobi).
    pub(crate) fn invert(&mut self, kind: Kind) {
        let block_jacobi = kind == Kind::BlockJacobi;
        for b in self.blocks.chunks_exact_mut(6) {
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
}

/// How far past its refresh angle K' may move while the refresh waits for a quiet tick
/// ([`TwoLevel::due`]).
pub(crate) const DEFER_LIMIT: f32 = 4.0;

/// z = S M⁻¹ r: the two-level preconditioner with the rest positions its coarse modes need and
/// the constraint filter, borrowed for one solve.
pub(crate) struct TwoLevelApply<'r, 'a> {
    /// The preconditioner.
    pub precond: &'r mut TwoLevel<'a>,
    /// Rest positions (the coarse rotation modes are about aggregate centroids).
    pub x0: &'r [f32],
    /// The filter S.
    pub contact: &'r ContactSet<'a>,
}

impl Preconditioner for TwoLevelApply<'_, '_> {
    /// The node block: z_i = B_i⁻¹ r_i (B_i symmetric, stored xx, yy, zz, xy, yz, zx).
    #[inline(always)]
    fn apply_node(&self, i: usize, r: [f32; 3]) -> [f32; 3] {
        match self.precond.blocks.get(6 * i..6 * i + 6) {
            Some(m) => [
                m[0] * r[0] + m[3] * r[1] + m[5] * r[2],
                m[3] * r[0] + m[1] * r[1] + m[4] * r[2],
                m[5] * r[0] + m[4] * r[1] + m[2] * r[2],
            ],
            None => [0.0; 3],
        }
    }

    /// Two-level: adds the coarse correction P A_c⁻¹ Pᵀ r (r is already filtered), then filters.
    #[inline(never)]
    fn finish(&mut self, r: &[f32], z: &mut [f32]) {
        self.precond.coarse.apply(self.x0, r, z);
        self.contact.project(z);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A due refresh waits after a busy tick while K' moved by at most `DEFER_LIMIT` times the
    /// angle; never-built blocks, a quiet tick before, a larger move, or an angle of 0 (refresh
    /// every tick) do not wait.
    #[test]
    fn a_due_refresh_waits_for_a_quiet_tick_within_its_limit() {
        let (mut blocks, mut agg, mut coarse) = ([0.0f32; 6], [0u32; 1], [0.0f32; 16]);
        let mut p = TwoLevel {
            blocks: &mut blocks,
            valid: false,
            drift: 0.0,
            coarse: Coarse::new(1, &mut agg, &mut coarse),
        };
        let angle = 0.05;
        assert!(p.due(angle, true), "never built");
        p.valid = true;
        p.drift = 0.5 * angle;
        assert!(!p.due(angle, false) && !p.due(angle, true), "not due");
        p.drift = 2.0 * angle;
        assert!(p.due(angle, false), "due after a quiet tick");
        assert!(!p.due(angle, true), "due, but waits after a busy one");
        assert!(p.due(0.0, true), "an angle of 0 refreshes every tick");
        p.drift = 1.01 * DEFER_LIMIT * angle;
        assert!(p.due(angle, true), "past the limit it does not wait");
    }
}
