//! The host side of the probe link (`protocol/LINK-FORMAT.md`): reading frames from a serial
//! port with arrival times, writing frames, gating untrusted forces before they reach the
//! runtime, fault injection for the hardware-in-the-loop tests, the simulated probe as a
//! sender, stream statistics, the haptic replay over a pseudo-terminal, and the FSR calibration
//! fit whose result the probe firmware applies.

pub mod faults;
pub mod fsr;
pub mod gate;
pub mod haptic;
pub mod model_source;
pub mod port;
pub mod replay;
pub mod sender;
pub mod session;
pub mod stats;

pub use gate::{ForceGate, GateDecision};
pub use port::{FrameReader, StdWrite};
pub use stats::Percentiles;

/// Every error of this crate (the serial link, the replay over a pseudo-terminal, the model the
/// haptic commands play): one flat enum; each message names what and where. The FSR calibration
/// keeps its own [`fsr::FsrError`] (file, line, field).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LinkHostError {
    /// The serial device could not be opened.
    #[error("opening serial port {path}: {source}")]
    Open {
        /// Device path.
        path: String,
        /// Cause.
        source: serialport::Error,
    },
    /// Reading or writing the device failed.
    #[error("{what} on {path}: {source}")]
    Io {
        /// Operation.
        what: &'static str,
        /// Device path.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// The probe speaks another protocol version.
    #[error("probe on {path} speaks link protocol version {found}, this host speaks {expected}")]
    Version {
        /// Device path.
        path: String,
        /// Peer version.
        found: u8,
        /// Ours.
        expected: u8,
    },
    /// A frame could not be encoded.
    #[error("encoding a frame: {0}")]
    Encode(palpate_protocol::link::LinkError),
    /// A model file could not be read or decoded.
    #[error("model {file}: {message}")]
    Model {
        /// The file.
        file: std::path::PathBuf,
        /// What went wrong.
        message: String,
    },
    /// The generated block model could not be built.
    #[error("generating the block model: {0}")]
    Block(#[source] palpate_fem::export::ExportError),
    /// The pseudo-terminal pair of a replay could not be made or set up.
    #[error("pseudo-terminal: {0}")]
    Pty(#[source] serialport::Error),
    /// The simulated probe could not be configured.
    #[error("sim probe: {0}")]
    SimProbe(String),
    /// The runtime rejected a tick of the haptic loop.
    #[error("runtime tick: {0}")]
    Tick(#[source] palpate_runtime::RuntimeError),
    /// The runtime could not be built for the model.
    #[error("building the runtime: {0}")]
    Runtime(#[source] palpate_runtime::RuntimeError),
    /// The runtime refused the contact a sample commanded.
    #[error("runtime refused the contact at {point:?}: {source}")]
    Contact {
        /// The contact point (model coordinates, m).
        point: [f32; 3],
        /// The runtime's reason.
        source: palpate_runtime::RuntimeError,
    },
    /// The replay's sender thread panicked.
    #[error("sender thread panicked")]
    SenderPanicked,
}
