#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]
//! palpate's probe firmware as a host-testable `no_std`, allocation-free library: the FSR front
//! end of the thesis' contact probe (seed 000 §4.1–4.2) made concrete.
//!
//! An FSR in a pull-down divider is read by an ADS1015/ADS1115 over embedded-hal 1.0 I²C
//! ([`ads1x15`]); counts become divider voltage, sensor conductance and force through the
//! calibration curve ([`frontend`], curve in `palpate_protocol::link::calibration`), sampled on a
//! fixed schedule with timestamps ([`schedule`]), low-pass filtered ([`filter`]), checked for
//! saturation, open circuit and stuck readings ([`frontend`], [`detect`]), and sent as link
//! frames through an `embedded-io` writer ([`tx`]). [`sim`] puts the same code behind a
//! simulated converter for the host. `defmt` logging only with the `defmt` feature.
//!
//! ```
//! use palpate_probe::sim::{default_config, Profile, SimProbe};
//! let mut p = SimProbe::new(default_config(), Profile::Constant(5.0), 1).unwrap();
//! let s = (0..100u64).filter_map(|k| p.step(k * 1000)).last().unwrap();
//! assert!((s.force_n - 5.0).abs() < 0.1, "{s:?}");
//! ```

pub mod ads1x15;
pub mod detect;
pub mod filter;
mod fmt;
pub mod frontend;
pub mod probe;
pub mod schedule;
pub mod sim;
pub mod tx;

pub use probe::{Probe, ProbeSettings};

/// Errors of the probe library.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Error<E> {
    /// The I²C bus failed talking to the converter.
    Bus(E),
    /// The converter's config register read back differently from what was written.
    AdcReadback {
        /// Written (without OS bit).
        wrote: u16,
        /// Read (without OS bit).
        read: u16,
    },
    /// The converter cannot sample this fast (ADS1115 ≤ 860 SPS; use the ADS1015 above).
    RateUnsupported {
        /// Requested rate, Hz.
        rate_hz: u16,
        /// The part's fastest rate, Hz.
        max_hz: u16,
    },
    /// A configuration value is out of range (names which).
    InvalidConfig(&'static str),
}

impl<E: core::fmt::Debug> core::fmt::Display for Error<E> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Error::Bus(e) => write!(f, "I2C bus error talking to the ADC: {e:?}"),
            Error::AdcReadback { wrote, read } => {
                write!(
                    f,
                    "ADC config read back {read:#06x}, wrote {wrote:#06x} (wrong or faulty chip?)"
                )
            }
            Error::RateUnsupported { rate_hz, max_hz } => {
                write!(f, "ADC cannot sample at {rate_hz} Hz (max {max_hz} SPS)")
            }
            Error::InvalidConfig(what) => write!(f, "invalid probe config: {what}"),
        }
    }
}

impl<E: core::fmt::Debug> core::error::Error for Error<E> {}
