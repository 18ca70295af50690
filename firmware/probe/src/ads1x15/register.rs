//! ADS1015/ADS1115 register map (TI SBAS444D / SBAS473, §9.6 "Register Map"). The two parts
//! share the map; they differ in resolution (16 vs 12 bits, the 12-bit result left-justified)
//! and in the data-rate codes.

/// 7-bit I²C addresses selected by the ADDR pin (Table 4): GND, VDD, SDA, SCL.
pub mod address {
    /// ADDR tied to GND.
    pub const GND: u8 = 0b100_1000;
    /// ADDR tied to VDD.
    pub const VDD: u8 = 0b100_1001;
    /// ADDR tied to SDA.
    pub const SDA: u8 = 0b100_1010;
    /// ADDR tied to SCL.
    pub const SCL: u8 = 0b100_1011;
}

/// Address-pointer register values (Table 6).
pub mod pointer {
    /// Conversion register (read-only, result).
    pub const CONVERSION: u8 = 0x00;
    /// Config register.
    pub const CONFIG: u8 = 0x01;
    /// Lo_thresh register.
    pub const LO_THRESH: u8 = 0x02;
    /// Hi_thresh register.
    pub const HI_THRESH: u8 = 0x03;
}

/// Config register fields (Table 8). Reset value 0x8583.
pub mod config {
    /// Config register reset value.
    pub const RESET: u16 = 0x8583;
    /// OS (bit 15): write 1 starts a single conversion; reads 1 when no conversion is running.
    pub const OS: u16 = 1 << 15;
    /// MUX (bits 14:12) = 100: AIN0 against GND.
    pub const MUX_AIN0_GND: u16 = 0b100 << 12;
    /// MUX = 101: AIN1 against GND.
    pub const MUX_AIN1_GND: u16 = 0b101 << 12;
    /// MUX = 110: AIN2 against GND.
    pub const MUX_AIN2_GND: u16 = 0b110 << 12;
    /// MUX = 111: AIN3 against GND.
    pub const MUX_AIN3_GND: u16 = 0b111 << 12;
    /// PGA (bits 11:9) = 000: full scale ±6.144 V.
    pub const PGA_6_144: u16 = 0b000 << 9;
    /// PGA = 001: full scale ±4.096 V.
    pub const PGA_4_096: u16 = 0b001 << 9;
    /// PGA = 010: full scale ±2.048 V (reset).
    pub const PGA_2_048: u16 = 0b010 << 9;
    /// MODE (bit 8) = 0: continuous conversion.
    pub const MODE_CONTINUOUS: u16 = 0;
    /// MODE = 1: single-shot / power-down (reset).
    pub const MODE_SINGLE: u16 = 1 << 8;
    /// DR field position (bits 7:5).
    pub const DR_SHIFT: u16 = 5;
    /// COMP_QUE (bits 1:0) = 11: comparator disabled, ALERT/RDY high-impedance (reset).
    pub const COMP_QUE_DISABLE: u16 = 0b11;
    /// Every bit except OS (which reads back the conversion state, not what was written).
    pub const READBACK_MASK: u16 = !OS;
}

/// ADS1115 data rates in samples/s for DR codes 000 … 111 (Table 8).
pub const ADS1115_RATES: [u16; 8] = [8, 16, 32, 64, 128, 250, 475, 860];
/// ADS1015 data rates in samples/s for DR codes 000 … 111 (SBAS473 Table 8; 110 and 111 are both 3300).
pub const ADS1015_RATES: [u16; 8] = [128, 250, 490, 920, 1600, 2400, 3300, 3300];
