//! The gate between the link and the runtime: which force the simulation gets for a sample.
//!
//! Only samples the probe vouches for drive the contact. `SATURATED`, `STUCK` and `ADC_ERROR`
//! (and anything non-finite, negative or above the plausibility limit) are untrusted: the
//! last trusted force is held for at most `hold_limit` samples — a short glitch does not jolt
//! the haptic device — and after that the contact is released (force 0), the fail-safe for a
//! sensor that stays broken. `OPEN_CIRCUIT` is a trusted zero (nothing presses the sensor, or
//! its lead is open: both mean "apply no force").

use palpate_protocol::link::{status, ForceSample};

/// What the gate did with a sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GateDecision {
    /// The sample's own force.
    Feed(f32),
    /// Untrusted sample: the last trusted force, held.
    Hold(f32),
    /// Untrusted for longer than the hold limit: no force.
    Release,
}

impl GateDecision {
    /// The force to apply.
    pub fn force_n(&self) -> f32 {
        match *self {
            GateDecision::Feed(f) | GateDecision::Hold(f) => f,
            GateDecision::Release => 0.0,
        }
    }
}

/// The gate's state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceGate {
    /// Untrusted samples in a row that still hold the last force.
    pub hold_limit: u32,
    /// Forces above this (N) are implausible for the probe and treated as untrusted.
    pub max_force_n: f32,
    held: u32,
    last: f32,
}

impl ForceGate {
    /// A gate with a hold limit (samples) and a plausibility limit (N).
    pub fn new(hold_limit: u32, max_force_n: f32) -> Self {
        Self {
            hold_limit,
            max_force_n,
            held: 0,
            last: 0.0,
        }
    }

    /// Whether a sample's force may drive the runtime.
    pub fn trusted(&self, s: &ForceSample) -> bool {
        s.status & status::UNTRUSTED == 0
            && s.force_n.is_finite()
            && (0.0..=self.max_force_n).contains(&s.force_n)
    }

    /// Decides the force for one sample.
    pub fn admit(&mut self, s: &ForceSample) -> GateDecision {
        if self.trusted(s) {
            self.held = 0;
            self.last = s.force_n;
            GateDecision::Feed(s.force_n)
        } else if self.held < self.hold_limit {
            self.held += 1;
            GateDecision::Hold(self.last)
        } else {
            self.last = 0.0;
            GateDecision::Release
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(force_n: f32, st: u8) -> ForceSample {
        ForceSample {
            seq: 0,
            timestamp_us: 0,
            raw_counts: 0,
            force_n,
            status: st,
        }
    }

    #[test]
    fn untrusted_samples_hold_then_release() {
        let mut g = ForceGate::new(2, 50.0);
        assert_eq!(g.admit(&s(3.0, status::OK)), GateDecision::Feed(3.0));
        assert_eq!(
            g.admit(&s(99.0, status::SATURATED)),
            GateDecision::Hold(3.0)
        );
        assert_eq!(g.admit(&s(f32::NAN, status::OK)), GateDecision::Hold(3.0));
        assert_eq!(g.admit(&s(3.1, status::STUCK)), GateDecision::Release);
        assert_eq!(g.admit(&s(60.0, status::OK)), GateDecision::Release); // implausible
        assert_eq!(
            g.admit(&s(0.0, status::OPEN_CIRCUIT)),
            GateDecision::Feed(0.0)
        );
        assert_eq!(
            g.admit(&s(2.0, status::OUT_OF_RANGE)),
            GateDecision::Feed(2.0)
        );
        assert_eq!(g.admit(&s(-1.0, status::OK)), GateDecision::Hold(2.0));
    }
}
