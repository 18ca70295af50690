//! The haptic loop on the host: each delivered force sample passes the [`ForceGate`] and, as a
//! force-driven contact at a fixed point, drives a runtime tick — one solve per sample at the
//! probe's rate. When the host falls behind and several samples arrive in one read, all of them
//! pass the gate in order but only the newest drives the solve (the older ones are superseded:
//! solving stale forces would only add latency to the one that matters).

use super::gate::{ForceGate, GateDecision};
use heapless::HistoryBuf;
use palpate_protocol::link::ForceSample;
use palpate_runtime::{Runtime, RuntimeError, TickReport};

/// Where and how the probe's force acts on the model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Contact {
    /// Contact point (model coordinates, m).
    pub point: [f32; 3],
    /// Unit direction of the pressing force.
    pub direction: [f32; 3],
    /// Radius over which the force spreads (m), by the shared contact rule.
    pub radius: f32,
}

/// Solves remembered in [`HapticLoop::commanded`]: 16 s at 1 kHz (128 KiB).
pub const COMMAND_HISTORY: usize = 16_384;

/// Gate + runtime.
pub struct HapticLoop<'a> {
    /// The runtime.
    pub runtime: Runtime<'a>,
    /// The gate.
    pub gate: ForceGate,
    /// The contact.
    pub contact: Contact,
    /// `(seq, force N)` of the last [`COMMAND_HISTORY`] solves, oldest first via
    /// `oldest_ordered()`: exactly what the runtime was fed. A fixed ring, because a haptic
    /// session runs for hours and its memory must not grow with it.
    pub commanded: Box<HistoryBuf<(u32, f32), COMMAND_HISTORY>>,
    /// Solves since the start (the ring keeps only the most recent).
    pub solves: u64,
    /// Samples gated but superseded by a newer one in the same batch.
    pub superseded: u64,
}

impl<'a> HapticLoop<'a> {
    /// A loop over `runtime` with `contact`; the direction is normalised.
    pub fn new(runtime: Runtime<'a>, gate: ForceGate, mut contact: Contact) -> Self {
        let d = contact.direction;
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        if n > 0.0 {
            contact.direction = d.map(|x| x / n);
        }
        Self {
            runtime,
            gate,
            contact,
            commanded: Box::new(HistoryBuf::new()),
            solves: 0,
            superseded: 0,
        }
    }

    /// Gates one sample, commands its force and solves one tick.
    pub fn on_sample(
        &mut self,
        s: &ForceSample,
    ) -> Result<(GateDecision, TickReport), RuntimeError> {
        let decision = self.gate.admit(s);
        self.solve(s.seq, decision)
    }

    /// Gates every sample of a batch in order and solves once for the newest; `None` for an
    /// empty batch.
    pub fn on_batch(
        &mut self,
        batch: &[ForceSample],
    ) -> Result<Option<(GateDecision, TickReport)>, RuntimeError> {
        let Some(last) = batch.last() else {
            return Ok(None);
        };
        let mut decision = GateDecision::Release;
        for s in batch {
            decision = self.gate.admit(s);
        }
        self.superseded += batch.len() as u64 - 1;
        self.solve(last.seq, decision).map(Some)
    }

    fn solve(
        &mut self,
        seq: u32,
        decision: GateDecision,
    ) -> Result<(GateDecision, TickReport), RuntimeError> {
        let f = decision.force_n();
        let c = self.contact;
        self.runtime
            .set_contact_force(c.point, c.direction.map(|d| d * f), c.radius)?;
        self.commanded.write((seq, f));
        self.solves += 1;
        Ok((decision, self.runtime.tick()))
    }
}
