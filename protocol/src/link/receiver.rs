//! The receiving end of the link: a fixed-size accumulator fed byte by byte.
//!
//! Bytes collect until a `0x00` delimiter; the collected bytes are then decoded with
//! [`codec::decode`](super::codec::decode). Anything that fails — bad COBS, bad CRC, foreign
//! version, bad layout, invalid content, more bytes than any frame can have — is counted and
//! dropped, and the receiver is back in sync at the next delimiter. Sample sequence numbers
//! are tracked so every frame lost on the way (including ones whose bytes never arrived at all)
//! shows up in [`LinkStats::missing_samples`]. Nothing is ever delivered that did not pass the
//! CRC and validation.

use super::{codec, Frame, Rejection, MAX_FRAME_ENCODED};

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
    /// Samples known lost: gaps in the sequence numbers of delivered samples.
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
    /// Times the sample sequence restarted (a hello, or a sequence number going backwards:
    /// the probe was reset).
    pub restarts: u64,
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
        }
    }
}

/// Frame accumulator with an `N`-byte buffer (default: the compile-time frame bound).
#[derive(Debug, Clone)]
pub struct Receiver<const N: usize = MAX_FRAME_ENCODED> {
    buf: [u8; N],
    len: usize,
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
            buf: [0; N],
            len: 0,
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
                restarts: 0,
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
        self.stats.bytes_discarded += self.len as u64;
        self.len = 0;
        self.overflowed = false;
    }

    /// Feeds one byte. Returns `Some` when the byte completed a frame: the frame, or why it
    /// was rejected (already counted). Empty frames (repeated delimiters, used to flush the
    /// line) return `None`.
    pub fn push(&mut self, byte: u8) -> Option<Result<Frame, Rejection>> {
        self.stats.bytes += 1;
        if byte != 0 {
            if self.len < N {
                self.buf[self.len] = byte;
                self.len += 1;
            } else {
                self.overflowed = true;
                self.stats.bytes_discarded += 1;
            }
            return None;
        }
        let len = core::mem::replace(&mut self.len, 0);
        if core::mem::replace(&mut self.overflowed, false) {
            return Some(Err(self.reject(Rejection::Overflow, len)));
        }
        if len == 0 {
            return None;
        }
        let result = codec::decode(&mut self.buf[..len]).and_then(|f| self.sequence(f));
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

    /// Sequence bookkeeping: a hello means the probe (re)started and numbers from 0 again; a
    /// jump forward counts the skipped numbers as missing; a number going backwards (other than
    /// a repeat of the last one) means the probe was reset without our seeing its hello.
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
                match self.next_seq {
                    Some(next) if s.seq >= next => {
                        self.stats.missing_samples += u64::from(s.seq - next)
                    }
                    Some(_) => self.stats.restarts += 1,
                    None => {}
                }
                self.last_seq = Some(s.seq);
                self.next_seq = s.seq.checked_add(1);
                self.stats.samples += 1;
            }
            Frame::Config(_) | Frame::Error(_) => {}
        }
        Ok(f)
    }
}
