//! Frames out through an `embedded-io` writer, encoded on the stack into a fixed-capacity
//! `heapless::Vec` of one frame's bound.

use palpate_protocol::link::{codec, Frame, LinkError, MAX_FRAME_ENCODED};

/// Why a frame was not sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TxError<E> {
    /// The frame could not be encoded.
    Encode(LinkError),
    /// The writer failed.
    Write(E),
}

/// Writes frames to `W`.
#[derive(Debug)]
pub struct FrameWriter<W> {
    w: W,
    version: u8,
    sent: u32,
}

impl<W: embedded_io::Write> FrameWriter<W> {
    /// A writer speaking the current protocol version.
    pub fn new(w: W) -> Self {
        Self {
            w,
            version: palpate_protocol::link::LINK_VERSION,
            sent: 0,
        }
    }

    /// A writer that stamps another version byte (for version-mismatch tests).
    pub fn with_version(w: W, version: u8) -> Self {
        Self {
            w,
            version,
            sent: 0,
        }
    }

    /// Sends a lone delimiter so the peer drops any partial frame it holds (after reset or
    /// reopen).
    pub fn flush_line(&mut self) -> Result<(), TxError<W::Error>> {
        self.w.write_all(&[0]).map_err(TxError::Write)
    }

    /// Encodes and writes one frame.
    pub fn send(&mut self, frame: &Frame) -> Result<(), TxError<W::Error>> {
        let mut buf = heapless::Vec::<u8, MAX_FRAME_ENCODED>::new();
        codec::encode_into_with_version(self.version, frame, &mut buf).map_err(TxError::Encode)?;
        self.w.write_all(&buf).map_err(TxError::Write)?;
        self.sent = self.sent.wrapping_add(1);
        Ok(())
    }

    /// Flushes the writer.
    pub fn flush(&mut self) -> Result<(), TxError<W::Error>> {
        self.w.flush().map_err(TxError::Write)
    }

    /// Frames sent so far.
    pub fn sent(&self) -> u32 {
        self.sent
    }

    /// The writer.
    pub fn inner_mut(&mut self) -> &mut W {
        &mut self.w
    }

    /// Gives the writer back.
    pub fn into_inner(self) -> W {
        self.w
    }
}
