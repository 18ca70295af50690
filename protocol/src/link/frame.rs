//! The frames of the probe link. postcard is not self-describing: only ever append variants
//! and bump [`LINK_VERSION`](super::LINK_VERSION) on any other change.

use super::calibration::Calibration;
use postcard::experimental::max_size::MaxSize;
use serde::{Deserialize, Serialize};

/// Status flags of a [`ForceSample`] (bit set = condition present).
pub mod status {
    /// No condition: the force is a calibrated reading inside the usable range.
    pub const OK: u8 = 0;
    /// The divider is at (or within a few counts of) the supply or the ADC full scale: the
    /// sensor's resistance is too low to resolve force; the reported force is a lower bound.
    pub const SATURATED: u8 = 1 << 0;
    /// The sensor does not conduct (conductance below the calibration's floor): either nothing
    /// presses it or a lead is open — a pull-down divider cannot tell these apart. Force is 0.
    pub const OPEN_CIRCUIT: u8 = 1 << 1;
    /// The raw reading has not changed for longer than the stuck window: a live FSR behind a
    /// 16-bit converter always shows noise, so the converter or bus is frozen.
    pub const STUCK: u8 = 1 << 2;
    /// The force lies outside the calibration's usable range (extrapolated).
    pub const OUT_OF_RANGE: u8 = 1 << 3;
    /// The ADC could not be read this period; `raw_counts` and the force repeat the last value.
    pub const ADC_ERROR: u8 = 1 << 4;
    /// Every flag this protocol version defines.
    pub const ALL: u8 = SATURATED | OPEN_CIRCUIT | STUCK | OUT_OF_RANGE | ADC_ERROR;
    /// Flags after which the force must not drive a simulation.
    pub const UNTRUSTED: u8 = SATURATED | STUCK | ADC_ERROR;
}

/// Sent by the probe after reset and on request: who it is and what it speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Hello {
    /// Protocol version (equal to the frame header's version byte, widened for the future).
    pub protocol_version: u16,
    /// Firmware version, `major << 8 | minor`.
    pub firmware_version: u16,
    /// Device identifier (e.g. the low word of the MCU's unique id).
    pub device_id: u32,
    /// Current sample rate in Hz.
    pub rate_hz: u16,
}

/// Sampling configuration: host → probe to set, probe → host to confirm.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config {
    /// Sample (and frame) rate in Hz, 1 ..= 3300.
    pub rate_hz: u16,
    /// Cut-off of the first-order low-pass applied to conductance, in Hz (0 = no filter).
    pub filter_cutoff_hz: f32,
    /// Divider and force curve.
    pub calibration: Calibration,
}

/// One force reading.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ForceSample {
    /// Sample slot number since start, +1 per period. A period the probe could not sample or
    /// send still consumes its number, so the host sees every loss as a gap.
    pub seq: u32,
    /// Time of the conversion read, µs since start, from the probe's clock.
    pub timestamp_us: u64,
    /// The ADC's raw conversion result.
    pub raw_counts: i16,
    /// Filtered, calibrated force magnitude in N.
    pub force_n: f32,
    /// [`status`] flags.
    pub status: u8,
}

/// What went wrong on the probe.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ErrorCode {
    /// The ADC did not answer on the bus.
    AdcBus,
    /// A config frame was rejected (value out of range); `detail` is the rejected rate.
    ConfigRejected,
    /// The sampler missed `detail` periods (they appear as sequence gaps).
    Overrun,
    /// The UART could not take a frame; `detail` frames were dropped.
    TxDropped,
}

/// An error report from the probe.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ErrorReport {
    /// What happened.
    pub code: ErrorCode,
    /// Code-specific detail (see [`ErrorCode`]).
    pub detail: u32,
}

/// Every frame of the link.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Frame {
    /// Identity and version.
    Hello(Hello),
    /// Sampling configuration and calibration.
    Config(Config),
    /// A force reading.
    Sample(ForceSample),
    /// An error report.
    Error(ErrorReport),
}

impl Frame {
    /// Checks the content a CRC cannot vouch for: finite numbers, valid calibration, known
    /// status flags. Names the first problem.
    pub fn validate(&self) -> Result<(), &'static str> {
        match self {
            Frame::Hello(_) | Frame::Error(_) => Ok(()),
            Frame::Config(c) => {
                if !(1..=3300).contains(&c.rate_hz) {
                    return Err("config rate must be 1 ..= 3300 Hz");
                }
                if !(c.filter_cutoff_hz.is_finite() && c.filter_cutoff_hz >= 0.0) {
                    return Err("config filter cut-off must be finite and >= 0 Hz");
                }
                c.calibration.validate()
            }
            Frame::Sample(s) => {
                if !s.force_n.is_finite() {
                    return Err("sample force is not finite");
                }
                if s.status & !status::ALL != 0 {
                    return Err("sample carries unknown status flags");
                }
                Ok(())
            }
        }
    }
}
