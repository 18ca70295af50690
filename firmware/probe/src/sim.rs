//! A simulated probe for the host: an ADS1x15 that answers on a pretend I²C bus with the
//! divider voltage of an FSR pressed by a scripted force profile. The real [`Probe`] code runs
//! on top of it unchanged — the stand-in behind `palpate probe-sim` and the HIL tests.

use crate::ads1x15::register::{config, pointer};
use crate::ads1x15::{Ads1x15, Channel, FullScale, Variant};
use crate::frontend::FrontEndLimits;
use crate::probe::{variant_for_rate, Probe, ProbeSettings};
use crate::Error;
use embedded_hal::i2c::{ErrorKind, ErrorType, I2c, NoAcknowledgeSource, Operation};
use palpate_protocol::link::{Calibration, Config, Divider, ForceCurve, ForceSample};

/// A scripted force profile, force magnitude in N as a function of time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Profile {
    /// Constant force.
    Constant(f32),
    /// `mean + amplitude · sin(2π hz t)`, clamped at 0.
    Sine {
        /// Mean force, N.
        mean: f32,
        /// Amplitude, N.
        amplitude: f32,
        /// Frequency, Hz.
        hz: f32,
    },
    /// Repeated presses `peak · (1 − cos(2π t / period)) / 2`: smooth touch and release.
    Press {
        /// Peak force, N.
        peak: f32,
        /// Press period, s.
        period_s: f32,
    },
}

impl Profile {
    /// Force at time `t_s`.
    pub fn force_at(&self, t_s: f64) -> f32 {
        use core::f64::consts::PI;
        match *self {
            Profile::Constant(f) => f,
            Profile::Sine {
                mean,
                amplitude,
                hz,
            } => (f64::from(mean)
                + f64::from(amplitude) * libm::sin(2.0 * PI * f64::from(hz) * t_s))
            .max(0.0) as f32,
            Profile::Press { peak, period_s } => {
                (f64::from(peak) * 0.5 * (1.0 - libm::cos(2.0 * PI * t_s / f64::from(period_s))))
                    as f32
            }
        }
    }
}

/// The simulated converter. Set [`volts`](Self::volts) (or use [`press`](Self::press)) before
/// each conversion read.
#[derive(Debug, Clone)]
pub struct SimAds1x15 {
    /// Bus address it answers on.
    pub address: u8,
    /// Which part it pretends to be.
    pub variant: Variant,
    /// Voltage at its input.
    pub volts: f32,
    /// Peak dither in counts added to every conversion (real converters show ±1–3 counts).
    pub noise_counts: i16,
    /// The next this-many transactions fail with a NACK.
    pub fail_next: u32,
    /// When set, every conversion returns this register value (a frozen converter).
    pub frozen: Option<u16>,
    config: u16,
    pointer: u8,
    rng: u32,
}

impl SimAds1x15 {
    /// A converter at `address`, input at 0 V, with ±`noise_counts` dither.
    pub fn new(address: u8, variant: Variant, noise_counts: i16) -> Self {
        Self {
            address,
            variant,
            volts: 0.0,
            noise_counts,
            fail_next: 0,
            frozen: None,
            config: config::RESET,
            pointer: 0,
            rng: 0x9E37_79B9,
        }
    }

    /// Sets the input to the divider voltage of an FSR pressed with `force_n` under `cal`.
    pub fn press(&mut self, cal: &Calibration, force_n: f32) {
        self.volts = cal.divider.voltage(cal.curve.conductance_us(force_n));
    }

    fn full_scale(&self) -> f32 {
        match (self.config >> 9) & 0b111 {
            0 => 6.144,
            1 => 4.096,
            2 => 2.048,
            3 => 1.024,
            4 => 0.512,
            _ => 0.256,
        }
    }

    fn conversion(&mut self) -> u16 {
        if let Some(r) = self.frozen {
            return r;
        }
        // xorshift32: deterministic dither, uniform in ±noise_counts.
        self.rng ^= self.rng << 13;
        self.rng ^= self.rng >> 17;
        self.rng ^= self.rng << 5;
        let span = 2 * i32::from(self.noise_counts) + 1;
        let dither = (self.rng % span as u32) as i32 - i32::from(self.noise_counts);
        let full = i32::from(self.variant.full_count());
        let counts =
            libm::roundf(self.volts / self.full_scale() * (full + 1) as f32) as i32 + dither;
        let counts = counts.clamp(-full - 1, full) as i16;
        match self.variant {
            Variant::Ads1015 => (counts << 4) as u16,
            Variant::Ads1115 => counts as u16,
        }
    }
}

impl ErrorType for SimAds1x15 {
    type Error = ErrorKind;
}

impl I2c for SimAds1x15 {
    fn transaction(
        &mut self,
        address: u8,
        operations: &mut [Operation<'_>],
    ) -> Result<(), Self::Error> {
        if address != self.address {
            return Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address));
        }
        if self.fail_next > 0 {
            self.fail_next -= 1;
            return Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Data));
        }
        for op in operations {
            match op {
                Operation::Write(bytes) => match bytes {
                    [p] => self.pointer = *p,
                    [p, hi, lo] if *p == pointer::CONFIG => {
                        self.pointer = *p;
                        self.config = u16::from_be_bytes([*hi, *lo]) & config::READBACK_MASK;
                    }
                    _ => return Err(ErrorKind::Other),
                },
                Operation::Read(buf) => {
                    let v = match self.pointer {
                        pointer::CONFIG => self.config | config::OS,
                        pointer::CONVERSION => self.conversion(),
                        _ => 0,
                    };
                    let b = v.to_be_bytes();
                    for (i, x) in buf.iter_mut().enumerate() {
                        *x = b[i % 2];
                    }
                }
            }
        }
        Ok(())
    }
}

/// The calibration the simulator presses with by default: the power law fitted to the
/// Interlink FSR 402 datasheet points by `palpate calibrate-fsr` (F = 1.708e-3 · G^1.292,
/// G in µS), on the nRF52840 board's 10 kΩ / 3.3 V divider.
pub fn default_calibration() -> Calibration {
    Calibration {
        divider: Divider {
            r_pulldown_ohm: 10_000.0,
            v_supply_v: 3.3,
        },
        curve: ForceCurve::PowerLaw {
            gain: 1.708e-3,
            exponent: 1.292,
        },
        usable_min_n: 0.2,
        usable_max_n: 100.0,
    }
}

/// The board's default sampling config: 1 kHz, 100 Hz low-pass, [`default_calibration`].
pub fn default_config() -> Config {
    Config {
        rate_hz: 1000,
        filter_cutoff_hz: 100.0,
        calibration: default_calibration(),
    }
}

/// Probe settings for the simulator: A0, ±4.096 V, stuck after 200 identical readings.
pub fn sim_settings() -> ProbeSettings {
    ProbeSettings {
        channel: Channel::A0,
        range: FullScale::V4_096,
        device_id: 0x51_4D_50_52,
        stuck_window: 200,
        limits: FrontEndLimits::default(),
    }
}

/// The firmware's probe on a simulated converter pressed by a profile.
#[derive(Debug)]
pub struct SimProbe {
    /// The probe (real firmware code).
    pub probe: Probe<SimAds1x15>,
    /// The force script.
    pub profile: Profile,
}

impl SimProbe {
    /// Builds the probe on a simulated converter with ±`noise_counts` dither.
    pub fn new(
        config: Config,
        profile: Profile,
        noise_counts: i16,
    ) -> Result<Self, Error<ErrorKind>> {
        let adc = Ads1x15::new(
            SimAds1x15::new(0x48, variant_for_rate(config.rate_hz), noise_counts),
            0x48,
            variant_for_rate(config.rate_hz),
        );
        Ok(Self {
            probe: Probe::new(adc, sim_settings(), config, 0)?,
            profile,
        })
    }

    /// The scripted force at `now_us`.
    pub fn scripted_force(&self, now_us: u64) -> f32 {
        self.profile.force_at(now_us as f64 * 1e-6)
    }

    /// Presses the simulated sensor with the scripted force at `now_us` and takes the sample
    /// that is due, if any.
    pub fn step(&mut self, now_us: u64) -> Option<ForceSample> {
        let f = self.scripted_force(now_us);
        let cal = self.probe.config().calibration;
        self.probe.adc_mut().bus_mut().press(&cal, f);
        self.probe.poll(now_us)
    }
}
