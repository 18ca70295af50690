//! The probe: ADC → front end → filter → fault flags → [`ForceSample`], on a fixed schedule.

use crate::ads1x15::{AdcError, Ads1x15, Channel, FullScale, Variant};
use crate::detect::StuckDetector;
use crate::filter::LowPass;
use crate::frontend::{FrontEnd, FrontEndLimits};
use crate::schedule::Schedule;
use crate::{fmt, Error};
use embedded_hal::i2c::I2c;
use palpate_protocol::link::{
    status, Config, ErrorCode, ErrorReport, ForceSample, Frame, Hello, LINK_VERSION,
};

/// Firmware version reported in the hello (`major << 8 | minor`).
pub const FIRMWARE_VERSION: u16 = 0x0100;

/// Static settings of a probe build.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProbeSettings {
    /// ADC input the divider is wired to.
    pub channel: Channel,
    /// ADC range (must cover the divider supply).
    pub range: FullScale,
    /// Device identifier for the hello.
    pub device_id: u32,
    /// Identical readings in a row that count as stuck (0 = off).
    pub stuck_window: u32,
    /// Front-end thresholds.
    pub limits: FrontEndLimits,
}

/// A probe reading one FSR through an ADS1x15.
#[derive(Debug)]
pub struct Probe<I2C> {
    adc: Ads1x15<I2C>,
    settings: ProbeSettings,
    config: Config,
    front: FrontEnd,
    filter: LowPass,
    stuck: StuckDetector,
    schedule: Schedule,
    last_counts: i16,
    last_force: f32,
    overrun_pending: u32,
}

impl<I2C: I2c> Probe<I2C> {
    /// Validates `config`, starts the converter at a rate that covers it, and schedules the
    /// first sample at `now_us`.
    pub fn new(
        adc: Ads1x15<I2C>,
        settings: ProbeSettings,
        config: Config,
        now_us: u64,
    ) -> Result<Self, Error<I2C::Error>> {
        let mut p = Self {
            front: FrontEnd {
                calibration: config.calibration,
                volts_per_count: adc.volts_per_count(),
                full_count: adc.variant().full_count(),
                limits: settings.limits,
            },
            adc,
            settings,
            config,
            filter: LowPass::new(0.0, 1.0),
            stuck: StuckDetector::new(settings.stuck_window),
            schedule: Schedule::new(config.rate_hz, now_us),
            last_counts: 0,
            last_force: 0.0,
            overrun_pending: 0,
        };
        p.apply_config(config, now_us)?;
        Ok(p)
    }

    /// Applies a new configuration (rate, filter, calibration). On error the old one stays.
    pub fn apply_config(&mut self, config: Config, now_us: u64) -> Result<(), Error<I2C::Error>> {
        Frame::Config(config)
            .validate()
            .map_err(Error::InvalidConfig)?;
        if config.calibration.divider.v_supply_v > self.settings.range.volts() {
            return Err(Error::InvalidConfig("divider supply exceeds the ADC range"));
        }
        let sps = self
            .adc
            .start_continuous(self.settings.channel, self.settings.range, config.rate_hz)
            .map_err(Error::from_adc)?;
        fmt::log_info!(
            "adc continuous at {} SPS for {} Hz sampling",
            sps,
            config.rate_hz
        );
        self.front.calibration = config.calibration;
        self.front.volts_per_count = self.adc.volts_per_count();
        self.filter = LowPass::new(config.filter_cutoff_hz, f32::from(config.rate_hz));
        self.schedule = Schedule::new(config.rate_hz, now_us);
        self.config = config;
        Ok(())
    }

    /// The configuration in force.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// The converter, e.g. to reach a simulated bus.
    pub fn adc_mut(&mut self) -> &mut Ads1x15<I2C> {
        &mut self.adc
    }

    /// The front end in force (for hosts that recompute forces from raw counts).
    pub fn front_end(&self) -> &FrontEnd {
        &self.front
    }

    /// When the next sample is due, in µs.
    pub fn next_due_us(&self) -> u64 {
        self.schedule.next_due_us()
    }

    /// The hello frame.
    pub fn hello(&self) -> Frame {
        Frame::Hello(Hello {
            protocol_version: u16::from(LINK_VERSION),
            firmware_version: FIRMWARE_VERSION,
            device_id: self.settings.device_id,
            rate_hz: self.config.rate_hz,
        })
    }

    /// Takes the sample that is due at `now_us`, if one is. Missed slots are skipped (their
    /// sequence numbers consumed) and reported by [`take_overrun`](Self::take_overrun).
    pub fn poll(&mut self, now_us: u64) -> Option<ForceSample> {
        let slot = self.schedule.poll(now_us)?;
        if slot.missed > 0 {
            fmt::log_warn!("sampler overrun: {} slots missed", slot.missed);
            self.overrun_pending = self.overrun_pending.saturating_add(slot.missed);
        }
        Some(self.sample(slot.seq, now_us))
    }

    /// An `Overrun` error report for slots missed since the last call, if any.
    pub fn take_overrun(&mut self) -> Option<Frame> {
        let n = core::mem::take(&mut self.overrun_pending);
        (n > 0).then_some(Frame::Error(ErrorReport {
            code: ErrorCode::Overrun,
            detail: n,
        }))
    }

    /// Reads the converter and builds sample `seq` stamped `now_us`.
    pub fn sample(&mut self, seq: u32, now_us: u64) -> ForceSample {
        let counts = match self.adc.read_counts() {
            Ok(c) => c,
            Err(_) => {
                fmt::log_warn!("adc read failed at seq {}", seq);
                return ForceSample {
                    seq,
                    timestamp_us: now_us,
                    raw_counts: self.last_counts,
                    force_n: self.last_force,
                    status: status::ADC_ERROR,
                };
            }
        };
        let r = self.front.convert(counts);
        let mut flags = r.flags;
        if self.stuck.update(counts, r.flags != status::OK) {
            flags |= status::STUCK;
        }
        let force = if flags & status::OPEN_CIRCUIT != 0 {
            // No conduction: the force is zero, and the filter restarts from the next press
            // instead of decaying slowly from the last one.
            self.filter.reset();
            0.0
        } else {
            self.front.force_n(self.filter.update(r.conductance_us))
        };
        flags |= self.front.range_flag(force);
        self.last_counts = counts;
        self.last_force = force;
        ForceSample {
            seq,
            timestamp_us: now_us,
            raw_counts: counts,
            force_n: force,
            status: flags,
        }
    }

    /// Handles a frame from the host; returns the reply to send.
    pub fn handle(&mut self, frame: &Frame, now_us: u64) -> Option<Frame> {
        match frame {
            Frame::Config(c) => Some(match self.apply_config(*c, now_us) {
                Ok(()) => Frame::Config(self.config),
                Err(_) => Frame::Error(ErrorReport {
                    code: ErrorCode::ConfigRejected,
                    detail: u32::from(c.rate_hz),
                }),
            }),
            Frame::Hello(_) => Some(self.hello()),
            Frame::Sample(_) | Frame::Error(_) => None,
        }
    }
}

impl<E> Error<E> {
    fn from_adc(e: AdcError<E>) -> Self {
        match e {
            AdcError::Bus(e) => Error::Bus(e),
            AdcError::ConfigReadback { wrote, read } => Error::AdcReadback { wrote, read },
            AdcError::RateUnsupported { rate_hz, max_hz } => {
                Error::RateUnsupported { rate_hz, max_hz }
            }
        }
    }
}

/// The part a rate needs: the ADS1115 up to 860 Hz, the ADS1015 above.
pub fn variant_for_rate(rate_hz: u16) -> Variant {
    if rate_hz <= 860 {
        Variant::Ads1115
    } else {
        Variant::Ads1015
    }
}
