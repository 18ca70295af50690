//! Frames from any byte source (a serial port in practice) with host arrival times, and an
//! `embedded-io` adapter so the firmware's frame writer runs over `std::io::Write`.

use super::LinkHostError;
use palpate_protocol::link::{Frame, LinkStats, Receiver, LINK_VERSION};
use std::io::{ErrorKind, Read};
use std::time::{Duration, Instant};

/// Opens a serial device (8N1, raw) with a read timeout.
pub fn open(
    path: &str,
    baud: u32,
    timeout: Duration,
) -> Result<serialport::TTYPort, LinkHostError> {
    serialport::new(path, baud)
        .timeout(timeout)
        .open_native()
        .map_err(|source| LinkHostError::Open {
            path: path.into(),
            source,
        })
}

/// Reads bytes from `R` into a [`Receiver`]; every delivered frame comes with the instant the
/// read that completed it returned.
#[derive(Debug)]
pub struct FrameReader<R> {
    src: R,
    rx: Receiver,
    buf: Vec<u8>,
}

impl<R: Read> FrameReader<R> {
    /// Wraps a byte source.
    pub fn new(src: R) -> Self {
        Self {
            src,
            rx: Receiver::new(),
            buf: vec![0; 4096],
        }
    }

    /// One read: feeds whatever arrived (nothing on timeout) and hands each delivered frame to
    /// `on_frame` with its arrival instant. Returns the number of bytes read.
    pub fn poll(&mut self, mut on_frame: impl FnMut(Frame, Instant)) -> std::io::Result<usize> {
        let n = match self.src.read(&mut self.buf) {
            Ok(n) => n,
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted
                ) =>
            {
                return Ok(0)
            }
            Err(e) => return Err(e),
        };
        let at = Instant::now();
        for &b in &self.buf[..n] {
            if let Some(Ok(f)) = self.rx.push(b) {
                on_frame(f, at);
            }
        }
        Ok(n)
    }

    /// Link counters.
    pub fn stats(&self) -> &LinkStats {
        self.rx.stats()
    }

    /// [`LinkHostError::Version`] for the probe on `path` if it was heard speaking another link
    /// protocol version.
    pub fn version_mismatch(&self, path: &str) -> Option<LinkHostError> {
        self.rx.peer_version().map(|found| LinkHostError::Version {
            path: path.into(),
            found,
            expected: LINK_VERSION,
        })
    }

    /// The receiver (e.g. to read the peer's version or drop a partial frame).
    pub fn receiver_mut(&mut self) -> &mut Receiver {
        &mut self.rx
    }

    /// Replaces the byte source (after a reopen), dropping any partial frame.
    pub fn replace_source(&mut self, src: R) -> R {
        self.rx.reset_partial();
        std::mem::replace(&mut self.src, src)
    }

    /// The byte source.
    pub fn source_mut(&mut self) -> &mut R {
        &mut self.src
    }
}

/// `embedded_io::Write` over `std::io::Write`.
#[derive(Debug)]
pub struct StdWrite<W>(pub W);

/// An I/O error kind carried through `embedded-io`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StdIoError(pub ErrorKind);

impl std::fmt::Display for StdIoError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "I/O error: {}", self.0)
    }
}

impl std::error::Error for StdIoError {}

impl embedded_io::Error for StdIoError {
    fn kind(&self) -> embedded_io::ErrorKind {
        match self.0 {
            ErrorKind::TimedOut => embedded_io::ErrorKind::TimedOut,
            ErrorKind::Interrupted => embedded_io::ErrorKind::Interrupted,
            ErrorKind::BrokenPipe => embedded_io::ErrorKind::BrokenPipe,
            _ => embedded_io::ErrorKind::Other,
        }
    }
}

impl<W> embedded_io::ErrorType for StdWrite<W> {
    type Error = StdIoError;
}

impl<W: std::io::Write> embedded_io::Write for StdWrite<W> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        loop {
            match self.0.write(buf) {
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                r => return r.map_err(|e| StdIoError(e.kind())),
            }
        }
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        self.0.flush().map_err(|e| StdIoError(e.kind()))
    }
}
