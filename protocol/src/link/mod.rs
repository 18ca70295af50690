//! The probe's wire protocol: typed [`Frame`]s carried as
//! `COBS( version ‖ postcard(frame) ‖ CRC-32C_le ) ‖ 0x00` (see `protocol/LINK-FORMAT.md`).
//!
//! - [`frame`]: the frame types (hello/version, config with the force calibration, force
//!   sample, error report) and their validation.
//! - [`calibration`]: the FSR front end (divider → conductance) and force curve, evaluated
//!   identically by the firmware, the host and the fitter.
//! - [`codec`]: encode one frame into a caller buffer (a slice, or appended to a
//!   `heapless::Vec`); decode one frame in place.
//! - [`receiver`]: a fixed-buffer byte accumulator that resynchronises after garbage, counts
//!   every rejected and missing frame, and never delivers a corrupted one.
//!
//! ```
//! use palpate_protocol::link::{codec, Frame, ForceSample, Receiver, status, MAX_FRAME_ENCODED};
//! let sample = ForceSample { seq: 7, timestamp_us: 7000, raw_counts: 12000, force_n: 1.5, status: status::OK };
//! let mut wire = [0u8; MAX_FRAME_ENCODED];
//! let n = codec::encode(&Frame::Sample(sample), &mut wire).unwrap();
//! let mut rx: Receiver = Receiver::new();
//! let got: Vec<_> = wire[..n].iter().filter_map(|&b| rx.push(b)).collect();
//! assert_eq!(got, [Ok(Frame::Sample(sample))]);
//! ```

pub mod calibration;
pub mod codec;
mod error;
pub mod frame;
pub mod receiver;

pub use calibration::{Calibration, Divider, ForceCurve, MAX_KNOTS};
pub use error::{LinkError, Rejection};
pub use frame::{status, Config, ErrorCode, ErrorReport, ForceSample, Frame, Hello};
pub use receiver::{LinkStats, Receiver, SEQ_WINDOW};

/// Protocol version carried in the first byte of every frame. Bump on any change of the frame
/// layout; only ever append enum variants.
pub const LINK_VERSION: u8 = 1;

/// Upper bound of `postcard(frame)` in bytes, from postcard's `MaxSize` (known at compile time).
pub const MAX_FRAME_POSTCARD: usize =
    <Frame as postcard::experimental::max_size::MaxSize>::POSTCARD_MAX_SIZE;

/// Upper bound of the unencoded frame body: version byte + postcard + 4 CRC bytes.
pub const MAX_FRAME_BODY: usize = 1 + MAX_FRAME_POSTCARD + 4;

/// Upper bound of one frame on the wire: COBS adds at most one byte per 254 plus one, and the
/// `0x00` delimiter adds one.
pub const MAX_FRAME_ENCODED: usize = MAX_FRAME_BODY + MAX_FRAME_BODY / 254 + 1 + 1;

// The firmware keeps one encoded frame on its stack and the receiver one in its buffer:
// fail the build, not the device, if a frame type ever grows past that budget.
const _: () = assert!(
    MAX_FRAME_ENCODED <= 160,
    "link frame outgrew its 160-byte budget"
);

#[cfg(test)]
mod tests;
