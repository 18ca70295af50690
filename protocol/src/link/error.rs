//! The link's error types: [`LinkError`] for encoding, [`Rejection`] for frames the receiver
//! throws away (each one is counted in [`LinkStats`](super::LinkStats)).

use core::fmt;

/// Why a frame could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum LinkError {
    /// The output buffer is smaller than the encoded frame needs.
    BufferTooSmall {
        /// Bytes the frame needs (upper bound).
        needed: usize,
        /// Bytes the caller gave.
        got: usize,
    },
    /// postcard could not serialise the frame (only possible with a buffer below the bound).
    Serialize,
    /// The frame's content is invalid (e.g. non-finite force, unsorted calibration knots).
    Invalid(&'static str),
}

impl fmt::Display for LinkError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LinkError::BufferTooSmall { needed, got } => {
                write!(f, "frame buffer too small: needs {needed} bytes, got {got}")
            }
            LinkError::Serialize => write!(f, "postcard serialisation failed"),
            LinkError::Invalid(what) => write!(f, "invalid frame content: {what}"),
        }
    }
}

impl core::error::Error for LinkError {}

/// Why the receiver rejected the bytes between two delimiters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Rejection {
    /// More bytes than any valid frame arrived before a delimiter (garbage or a lost delimiter).
    Overflow,
    /// The bytes are not valid COBS.
    Cobs,
    /// The decoded body is shorter than version + CRC.
    TooShort {
        /// Decoded length in bytes.
        len: usize,
    },
    /// The CRC-32C over version and payload does not match the trailer.
    Crc {
        /// CRC computed over the received bytes.
        computed: u32,
        /// CRC carried in the frame.
        received: u32,
    },
    /// The peer speaks another protocol version (frame intact, content not understood).
    Version {
        /// Version byte the peer sent.
        found: u8,
    },
    /// The payload is not a postcard-encoded frame, or has bytes left over.
    Decode,
    /// The frame decoded but its content is invalid (non-finite force, bad calibration …).
    Invalid(&'static str),
    /// A sample repeated the previous sequence number.
    Duplicate {
        /// The repeated sequence number.
        seq: u32,
    },
    /// An intact [`Hello`](super::Hello) claims a protocol version other than the frame's
    /// version byte (e.g. a hello saying 2 inside a version-1 frame): the peer's identity is
    /// inconsistent, so the hello is refused rather than restarting the sequence.
    HelloVersionMismatch {
        /// The frame's version byte (the version this receiver speaks).
        frame_version: u8,
        /// The `protocol_version` the hello claims.
        hello_version: u16,
    },
}

impl fmt::Display for Rejection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Rejection::Overflow => write!(
                f,
                "frame longer than the {}-byte bound",
                super::MAX_FRAME_ENCODED
            ),
            Rejection::Cobs => write!(f, "invalid COBS encoding"),
            Rejection::TooShort { len } => {
                write!(f, "frame body of {len} bytes is shorter than version + CRC")
            }
            Rejection::Crc { computed, received } => {
                write!(
                    f,
                    "CRC mismatch: computed {computed:#010x}, frame carries {received:#010x}"
                )
            }
            Rejection::Version { found } => {
                write!(
                    f,
                    "protocol version mismatch: expected {}, found {found}",
                    super::LINK_VERSION
                )
            }
            Rejection::Decode => write!(f, "payload is not a valid postcard frame"),
            Rejection::Invalid(what) => write!(f, "invalid frame content: {what}"),
            Rejection::Duplicate { seq } => write!(f, "duplicate sample sequence number {seq}"),
            Rejection::HelloVersionMismatch {
                frame_version,
                hello_version,
            } => write!(
                f,
                "hello claims protocol version {hello_version} inside a version-{frame_version} frame"
            ),
        }
    }
}

impl core::error::Error for Rejection {}
