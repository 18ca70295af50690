//! The receiving end of the link: a fixed-size accumulator fed byte by byte.
//!
//! Bytes collect until a `0x00` delimiter; the collected bytes are then decoded with
//! [`super::codec::decode`]. Anything that fails — bad COBS, bad CRC, foreign
//! version, bad layout, invalid content, more bytes than any frame can have — is counted and
//! dropped, and the receiver is back in sync at the next delimiter. Sample sequence numbers
//! are tracked so every frame lost on the way (including ones whose bytes never arrived at all)
//! shows up in [`LinkStats::missing_samples`]. Nothing is ever delivered that did not pass the
//! CRC and validation.
//!
//! Sequence numbers are compared with serial-number arithmetic (RFC 1982, on `u32`): the step
//! from the expected number to the received one is `seq − expected mod 2³²`, so the wrap from
//! `u32::MAX` to 0 is an ordinary step of one. Only a step of at most [`SEQ_WINDOW`] counts its
//! skipped numbers as missing; a larger step forward is an implausible jump (a forged or
//! misdirected frame, or an outage far longer than any the host would bridge) and only
//! resynchronises ([`LinkStats::seq_jumps`]); a step backwards is a probe reset
//! ([`LinkStats::seq_backwards`], also in [`LinkStats::restarts`]).

use super::{codec, Frame, Rejection, MAX_FRAME_ENCODED};

/// The highest sample rate a [`Config`](super::Config) allows, in Hz.
const MAX_RATE_HZ: u32 = 3300;

/// The largest forward step of a sample's sequence number that is taken at face value: 5 s of
/// samples at the highest rate (3300 Hz), i.e. 16 500 periods (16.5 s at the board's 1 kHz).
/// The skipped numbers of a step up to this size are counted in
/// [`LinkStats::missing_samples`]; a larger step counts once in [`LinkStats::seq_jumps`] and
/// adds nothing to `missing_samples` (one forged `seq = 4e9` must not report billions of lost
/// samples), and tracking resynchronises to the new number.
pub const SEQ_WINDOW: u32 = 5 * MAX_RATE_HZ;

/// How a received sequence number relates to the expected one (serial-number arithmetic).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SeqStep {
    /// At or up to [`SEQ_WINDOW`] ahead of the expected number: this many were skipped.
    Ahead(u32),
    /// More than [`SEQ_WINDOW`] ahead (in the forward half of the number circle).
    Jump,
    /// Behind the expected number (the backward half of the circle, 2³¹ included).
    Behind,
}

impl SeqStep {
    fn of(expected: u32, seq: u32) -> Self {
        let step = seq.wrapping_sub(expected);
        if step <= SEQ_WINDOW {
            SeqStep::Ahead(step)
        } else if step < 1 << 31 {
            SeqStep::Jump
        } else {
            SeqStep::Behind
        }
    }
}

/// Counters of everything the receiver has seen. `missing_samples` is the authoritative count
/// of samples not delivered (a sample whose frame was damaged counts there *and* under its
/// rejection reason).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkStats {
    /// Bytes fed in.
    pub bytes: u64,
    /// Frames delivered (all kinds).
    pub frames: u64,
    /// Sample frames delivered.
    pub samples: u64,
    /// Samples known lost: gaps in the sequence numbers of delivered samples (steps of at most
    /// [`SEQ_WINDOW`]; larger ones count in [`seq_jumps`](Self::seq_jumps)).
    pub missing_samples: u64,
    /// Frames dropped because they outgrew the buffer before a delimiter.
    pub rejected_overflow: u64,
    /// Frames dropped for invalid COBS.
    pub rejected_cobs: u64,
    /// Frames dropped for being too short.
    pub rejected_short: u64,
    /// Frames dropped for a CRC mismatch.
    pub rejected_crc: u64,
    /// Intact frames dropped because the peer speaks another protocol version.
    pub rejected_version: u64,
    /// Frames dropped because the payload is not a valid postcard frame.
    pub rejected_decode: u64,
    /// Frames dropped for invalid content.
    pub rejected_invalid: u64,
    /// Samples dropped for repeating the previous sequence number.
    pub rejected_duplicate: u64,
    /// Intact hellos dropped because their `protocol_version` differs from the frame's version
    /// byte ([`Rejection::HelloVersionMismatch`]).
    pub rejected_hello_version: u64,
    /// Times the sample sequence restarted (a hello, or a sequence number going backwards:
    /// the probe was reset). Includes every [`seq_backwards`](Self::seq_backwards).
    pub restarts: u64,
    /// Samples whose sequence number went backwards (serial-number arithmetic; not a repeat of
    /// the last one): delivered, counted as a restart, tracking continues from them.
    pub seq_backwards: u64,
    /// Samples whose sequence number jumped forward by more than [`SEQ_WINDOW`]: delivered,
    /// tracking resynchronises to them, and the skipped numbers are *not* counted as missing.
    pub seq_jumps: u64,
    /// Bytes thrown away with rejected frames.
    pub bytes_discarded: u64,
}

impl LinkStats {
    /// All rejected frames, whatever the reason.
    pub fn rejected(&self) -> u64 {
        self.rejected_overflow
            + self.rejected_cobs
            + self.rejected_short
            + self.rejected_crc
            + self.rejected_version
            + self.rejected_decode
            + self.rejected_invalid
            + self.rejected_duplicate
            + self.rejected_hello_version
    }

    fn count(&mut self, r: &Rejection) {
        match r {
            Rejection::Overflow => self.rejected_overflow += 1,
            Rejection::Cobs => self.rejected_cobs += 1,
            Rejection::TooShort { .. } => self.rejected_short += 1,
            Rejection::Crc { .. } => self.rejected_crc += 1,
            Rejection::Version { .. } => self.rejected_version += 1,
            Rejection::Decode => self.rejected_decode += 1,
            Rejection::Invalid(_) => self.rejected_invalid += 1,
            Rejection::Duplicate { .. } => self.rejected_duplicate += 1,
            Rejection::HelloVersionMismatch { .. } => self.rejected_hello_version += 1,
        }
    }
}

/// Frame accumulator with an `N`-byte buffer (default: the compile-time frame bound).
#[derive(Debug, Clone)]
pub struct Receiver<const N: usize = MAX_FRAME_ENCODED> {
    /// The bytes of the frame in progress; full means the frame outgrew every valid one.
    buf: heapless::Vec<u8, N>,
    overflowed: bool,
    last_seq: Option<u32>,
    next_seq: Option<u32>,
    peer_version: Option<u8>,
    stats: LinkStats,
}

impl<const N: usize> Default for Receiver<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> Receiver<N> {
    /// An empty receiver.
    pub const fn new() -> Self {
        Self {
            buf: heapless::Vec::new(),
            overflowed: false,
            last_seq: None,
            next_seq: None,
            peer_version: None,
            stats: LinkStats {
                bytes: 0,
                frames: 0,
                samples: 0,
                missing_samples: 0,
                rejected_overflow: 0,
                rejected_cobs: 0,
                rejected_short: 0,
                rejected_crc: 0,
                rejected_version: 0,
                rejected_decode: 0,
                rejected_invalid: 0,
                rejected_duplicate: 0,
                rejected_hello_version: 0,
                restarts: 0,
                seq_backwards: 0,
                seq_jumps: 0,
                bytes_discarded: 0,
            },
        }
    }

    /// The counters so far.
    pub fn stats(&self) -> &LinkStats {
        &self.stats
    }

    /// The version byte of the last intact frame in a foreign protocol version, if any.
    pub fn peer_version(&self) -> Option<u8> {
        self.peer_version
    }

    /// Sequence number of the last delivered sample.
    pub fn last_seq(&self) -> Option<u32> {
        self.last_seq
    }

    /// Drops any partial frame (e.g. after the port was closed and reopened); its bytes are
    /// counted as discarded. Sequence tracking continues, so samples lost meanwhile still
    /// count as missing.
    pub fn reset_partial(&mut self) {
        self.stats.bytes_discarded += self.buf.len() as u64;
        self.buf.clear();
        self.overflowed = false;
    }

    /// Feeds one byte. Returns `Some` when the byte completed a frame: the frame, or why it
    /// was rejected (already counted). Empty frames (repeated delimiters, used to flush the
    /// line) return `None`.
    pub fn push(&mut self, byte: u8) -> Option<Result<Frame, Rejection>> {
        self.stats.bytes += 1;
        if byte != 0 {
            if self.buf.push(byte).is_err() {
                self.overflowed = true;
                self.stats.bytes_discarded += 1;
            }
            return None;
        }
        let len = self.buf.len();
        if core::mem::replace(&mut self.overflowed, false) {
            self.buf.clear();
            return Some(Err(self.reject(Rejection::Overflow, len)));
        }
        if len == 0 {
            return None;
        }
        let decoded = codec::decode(&mut self.buf);
        self.buf.clear();
        let result = decoded.and_then(|f| self.sequence(f));
        Some(match result {
            Ok(f) => {
                self.stats.frames += 1;
                Ok(f)
            }
            Err(r) => Err(self.reject(r, len)),
        })
    }

    /// Feeds a slice, handing every delivered frame to `on_frame`. Returns the number of
    /// frames delivered.
    pub fn push_slice(&mut self, bytes: &[u8], mut on_frame: impl FnMut(Frame)) -> usize {
        let mut n = 0;
        for &b in bytes {
            if let Some(Ok(f)) = self.push(b) {
                on_frame(f);
                n += 1;
            }
        }
        n
    }

    fn reject(&mut self, r: Rejection, len: usize) -> Rejection {
        if let Rejection::Version { found } = r {
            self.peer_version = Some(found);
        }
        self.stats.count(&r);
        self.stats.bytes_discarded += len as u64;
        r
    }

    /// Sequence bookkeeping (serial-number arithmetic, see [`SEQ_WINDOW`]): a hello means the
    /// probe (re)started and numbers from 0 again; a step forward within the window counts the
    /// skipped numbers as missing, a larger one only resynchronises; a number going backwards
    /// (other than a repeat of the last one) means the probe was reset without our seeing its
    /// hello.
    fn sequence(&mut self, f: Frame) -> Result<Frame, Rejection> {
        match f {
            Frame::Hello(_) => {
                if self.next_seq.is_some() {
                    self.stats.restarts += 1;
                }
                self.next_seq = Some(0);
                self.last_seq = None;
            }
            Frame::Sample(s) => {
                if self.last_seq == Some(s.seq) {
                    return Err(Rejection::Duplicate { seq: s.seq });
                }
                if let Some(next) = self.next_seq {
                    match SeqStep::of(next, s.seq) {
                        SeqStep::Ahead(skipped) => self.stats.missing_samples += u64::from(skipped),
                        SeqStep::Jump => self.stats.seq_jumps += 1,
                        SeqStep::Behind => {
                            self.stats.seq_backwards += 1;
                            self.stats.restarts += 1;
                        }
                    }
                }
                self.last_seq = Some(s.seq);
                // u32::MAX is followed by 0: the wrap is an ordinary step.
                self.next_seq = Some(s.seq.wrapping_add(1));
                self.stats.samples += 1;
            }
            Frame::Config(_) | Frame::Error(_) => {}
        }
        Ok(f)
    }
}
