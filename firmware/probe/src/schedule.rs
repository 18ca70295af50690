//! The fixed-rate sample schedule: deadlines at `t0 + k · period` (no drift), each with its
//! sequence number `k`. A caller that comes late skips the missed slots, and their numbers are
//! consumed so the host counts them as missing.

/// A due sample slot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Slot {
    /// Sequence number of this slot.
    pub seq: u32,
    /// Slots skipped before this one because the caller was late.
    pub missed: u32,
}

/// The schedule.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Schedule {
    period_us: u64,
    next_us: u64,
    seq: u32,
}

impl Schedule {
    /// Period from a rate in Hz (clamped to ≥ 1 Hz), first slot at `start_us`.
    pub fn new(rate_hz: u16, start_us: u64) -> Self {
        Self {
            period_us: 1_000_000 / u64::from(rate_hz.max(1)),
            next_us: start_us,
            seq: 0,
        }
    }

    /// Sampling period in µs.
    pub fn period_us(&self) -> u64 {
        self.period_us
    }

    /// When the next slot is due.
    pub fn next_due_us(&self) -> u64 {
        self.next_us
    }

    /// The slot due at `now_us`, if any.
    pub fn poll(&mut self, now_us: u64) -> Option<Slot> {
        if now_us < self.next_us {
            return None;
        }
        let late = (now_us - self.next_us) / self.period_us;
        let missed = u32::try_from(late).unwrap_or(u32::MAX);
        let seq = self.seq.wrapping_add(missed);
        self.seq = seq.wrapping_add(1);
        self.next_us += (late + 1) * self.period_us;
        Some(Slot { seq, missed })
    }
}
