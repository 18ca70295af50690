//! Driving a runtime to rest: the loop every export-replay test needs.

use palpate_runtime::{Runtime, SolveStatus};

/// Ticks `rt` until a tick converges with the whole commanded load applied (incremental loading
/// may spread a large change over ticks) and its last step is at most `rel_step` of the largest
/// displacement component (f32 resolves about 1e-7 of a position, so 1e-5…1e-6 is settled), or
/// `max_ticks` pass. Returns whether it settled.
pub fn settle(rt: &mut Runtime<'_>, max_ticks: usize, rel_step: f32) -> bool {
    for _ in 0..max_ticks {
        let rep = rt.tick();
        let umax = rt
            .displacements()
            .iter()
            .fold(0.0f32, |a, v| a.max(v.abs()));
        if rep.status == SolveStatus::Converged
            && rep.load_remaining == 0.0
            && rep.step <= rel_step * umax
        {
            return true;
        }
    }
    false
}
