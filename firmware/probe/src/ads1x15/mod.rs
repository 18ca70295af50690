//! A small driver for the TI ADS1015 (12-bit, ≤ 3300 SPS) and ADS1115 (16-bit, ≤ 860 SPS)
//! over embedded-hal 1.0 [`I2c`], written against the datasheet's register map.
//!
//! Why our own and not `ads1x1x` 0.3: the probe needs exactly one mode (continuous, one
//! single-ended channel, chosen range and rate) plus a read-back check of the config register
//! that tells an absent or wrong chip apart at start-up; the driver is ~150 lines, has no `nb`
//! layer, and its register constants are checked against the datasheet in the mock-bus tests.

pub mod register;

use embedded_hal::i2c::I2c;
use register::{config, pointer};

/// Which member of the family.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Variant {
    /// 12-bit, 128 … 3300 SPS (needed for 1 kHz sampling).
    Ads1015,
    /// 16-bit, 8 … 860 SPS.
    Ads1115,
}

/// Input range of the programmable-gain amplifier.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FullScale {
    /// ±6.144 V (inputs still limited to VDD + 0.3 V).
    V6_144,
    /// ±4.096 V: a 3.3 V divider fits with headroom.
    V4_096,
    /// ±2.048 V.
    V2_048,
}

impl FullScale {
    /// Full-scale voltage in volts.
    pub fn volts(self) -> f32 {
        match self {
            FullScale::V6_144 => 6.144,
            FullScale::V4_096 => 4.096,
            FullScale::V2_048 => 2.048,
        }
    }
    fn bits(self) -> u16 {
        match self {
            FullScale::V6_144 => config::PGA_6_144,
            FullScale::V4_096 => config::PGA_4_096,
            FullScale::V2_048 => config::PGA_2_048,
        }
    }
}

/// Single-ended input channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Channel {
    /// AIN0 against GND.
    A0,
    /// AIN1 against GND.
    A1,
    /// AIN2 against GND.
    A2,
    /// AIN3 against GND.
    A3,
}

impl Channel {
    fn bits(self) -> u16 {
        match self {
            Channel::A0 => config::MUX_AIN0_GND,
            Channel::A1 => config::MUX_AIN1_GND,
            Channel::A2 => config::MUX_AIN2_GND,
            Channel::A3 => config::MUX_AIN3_GND,
        }
    }
}

impl Variant {
    /// Largest positive conversion result (2047 or 32767).
    pub fn full_count(self) -> i16 {
        match self {
            Variant::Ads1015 => 2047,
            Variant::Ads1115 => 32767,
        }
    }
    /// Data rates by DR code.
    pub fn rates(self) -> &'static [u16; 8] {
        match self {
            Variant::Ads1015 => &register::ADS1015_RATES,
            Variant::Ads1115 => &register::ADS1115_RATES,
        }
    }
    /// The slowest DR code whose rate is at least `rate_hz` (so every sample period sees a
    /// fresh conversion), with its rate; `None` when the part is too slow.
    pub fn data_rate_for(self, rate_hz: u16) -> Option<(u16, u16)> {
        self.rates()
            .iter()
            .enumerate()
            .find(|(_, &r)| r >= rate_hz)
            .map(|(code, &r)| (code as u16, r))
    }
}

/// Driver errors.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AdcError<E> {
    /// The bus transaction failed (no device, NACK, arbitration loss …).
    Bus(E),
    /// The config register read back differs from what was written (wrong or faulty chip).
    ConfigReadback {
        /// Value written (without OS).
        wrote: u16,
        /// Value read (without OS).
        read: u16,
    },
    /// The part cannot convert this fast.
    RateUnsupported {
        /// Requested rate in Hz.
        rate_hz: u16,
        /// The part's fastest rate.
        max_hz: u16,
    },
}

/// An ADS1015/ADS1115 on an I²C bus.
#[derive(Debug)]
pub struct Ads1x15<I2C> {
    i2c: I2C,
    address: u8,
    variant: Variant,
    range: FullScale,
}

impl<I2C: I2c> Ads1x15<I2C> {
    /// Takes the bus; nothing is sent until [`start_continuous`](Self::start_continuous).
    pub fn new(i2c: I2C, address: u8, variant: Variant) -> Self {
        Self {
            i2c,
            address,
            variant,
            range: FullScale::V2_048,
        }
    }

    /// Gives the bus back.
    pub fn destroy(self) -> I2C {
        self.i2c
    }

    /// The bus, e.g. to steer a simulated converter.
    pub fn bus_mut(&mut self) -> &mut I2C {
        &mut self.i2c
    }

    /// The part.
    pub fn variant(&self) -> Variant {
        self.variant
    }

    /// Volts per count at the configured range.
    pub fn volts_per_count(&self) -> f32 {
        self.range.volts() / (f32::from(self.variant.full_count()) + 1.0)
    }

    /// The config word for continuous conversion of `channel` at `range` and DR code `dr`,
    /// comparator off.
    pub fn config_word(channel: Channel, range: FullScale, dr: u16) -> u16 {
        channel.bits()
            | range.bits()
            | config::MODE_CONTINUOUS
            | (dr << config::DR_SHIFT)
            | config::COMP_QUE_DISABLE
    }

    /// Starts continuous conversion at the slowest data rate ≥ `rate_hz`, then reads the config
    /// register back to make sure the chip took it. Returns the converter's data rate.
    pub fn start_continuous(
        &mut self,
        channel: Channel,
        range: FullScale,
        rate_hz: u16,
    ) -> Result<u16, AdcError<I2C::Error>> {
        let max_hz = self.variant.rates()[7];
        let (dr, sps) = self
            .variant
            .data_rate_for(rate_hz)
            .ok_or(AdcError::RateUnsupported { rate_hz, max_hz })?;
        let word = Self::config_word(channel, range, dr);
        let [hi, lo] = word.to_be_bytes();
        self.i2c
            .write(self.address, &[pointer::CONFIG, hi, lo])
            .map_err(AdcError::Bus)?;
        let read = self.read_register(pointer::CONFIG)?;
        if read & config::READBACK_MASK != word & config::READBACK_MASK {
            return Err(AdcError::ConfigReadback {
                wrote: word & config::READBACK_MASK,
                read: read & config::READBACK_MASK,
            });
        }
        self.range = range;
        Ok(sps)
    }

    /// Reads the latest conversion result in counts (12-bit results shifted down).
    pub fn read_counts(&mut self) -> Result<i16, AdcError<I2C::Error>> {
        let raw = self.read_register(pointer::CONVERSION)? as i16;
        Ok(match self.variant {
            Variant::Ads1015 => raw >> 4,
            Variant::Ads1115 => raw,
        })
    }

    fn read_register(&mut self, reg: u8) -> Result<u16, AdcError<I2C::Error>> {
        let mut b = [0u8; 2];
        self.i2c
            .write_read(self.address, &[reg], &mut b)
            .map_err(AdcError::Bus)?;
        Ok(u16::from_be_bytes(b))
    }
}
