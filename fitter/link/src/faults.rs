//! A writer that damages what passes through it — byte corruption, dropped bytes, bursts of
//! garbage — with a seeded generator and exact counts, for the fault tests and demos.

use palpate_fem::rng::XorShift64Star;
use std::io::Write;

/// What to inject.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FaultPlan {
    /// Probability that a byte is replaced by a random different byte.
    pub corrupt: f64,
    /// Probability that a byte is dropped.
    pub drop: f64,
    /// Every this many writes, a burst of random bytes goes out first (0 = never).
    pub burst_every: u32,
    /// Length of each garbage burst.
    pub burst_len: usize,
    /// Faults start after this many clean writes (the link is up first).
    pub start_after: u64,
    /// Faults stop after this many writes (0 = never): the link recovers and the tail is clean.
    pub stop_after: u64,
}

/// What was injected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FaultCounts {
    /// Writes (frames) that passed.
    pub writes: u64,
    /// Writes with at least one damaged or dropped byte.
    pub writes_damaged: u64,
    /// Bytes corrupted.
    pub corrupted: u64,
    /// Bytes dropped.
    pub dropped: u64,
    /// Garbage bursts sent.
    pub bursts: u64,
}

/// The damaging writer.
#[derive(Debug)]
pub struct FaultyWriter<W> {
    inner: W,
    plan: FaultPlan,
    rng: XorShift64Star,
    counts: FaultCounts,
    scratch: Vec<u8>,
}

impl<W: Write> FaultyWriter<W> {
    /// Wraps `inner`; `seed` makes runs repeatable.
    pub fn new(inner: W, plan: FaultPlan, seed: u64) -> Self {
        Self {
            inner,
            plan,
            rng: XorShift64Star::new(seed | 1),
            counts: FaultCounts::default(),
            scratch: Vec::new(),
        }
    }

    /// What was injected so far.
    pub fn counts(&self) -> FaultCounts {
        self.counts
    }

    /// The wrapped writer.
    pub fn inner_mut(&mut self) -> &mut W {
        &mut self.inner
    }

    fn next(&mut self) -> u64 {
        self.rng.next_u64()
    }

    fn chance(&mut self, p: f64) -> bool {
        p > 0.0 && ((self.next() >> 11) as f64) / ((1u64 << 53) as f64) < p
    }
}

impl<W: Write> Write for FaultyWriter<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.counts.writes += 1;
        let w = self.counts.writes;
        if w <= self.plan.start_after || (self.plan.stop_after > 0 && w > self.plan.stop_after) {
            self.inner.write_all(buf)?;
            return Ok(buf.len());
        }
        self.scratch.clear();
        if self.plan.burst_every > 0
            && self
                .counts
                .writes
                .is_multiple_of(u64::from(self.plan.burst_every))
        {
            self.counts.bursts += 1;
            for _ in 0..self.plan.burst_len {
                let b = self.next() as u8;
                self.scratch.push(b);
            }
        }
        let mut damaged = false;
        for &b in buf {
            if self.chance(self.plan.drop) {
                self.counts.dropped += 1;
                damaged = true;
                continue;
            }
            if self.chance(self.plan.corrupt) {
                let x = (self.next() as u8).max(1);
                self.scratch.push(b ^ x);
                self.counts.corrupted += 1;
                damaged = true;
            } else {
                self.scratch.push(b);
            }
        }
        self.counts.writes_damaged += u64::from(damaged);
        self.inner.write_all(&self.scratch)?;
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}
