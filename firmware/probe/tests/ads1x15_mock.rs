//! The ADS1x15 driver against a mock I²C bus that fails on any unexpected transaction.
//! Register values are taken from the datasheets (TI SBAS444D Table 8 for the ADS1115,
//! SBAS473 Table 8 for the ADS1015), written out as literals here — not from the crate.

use embedded_hal::i2c::ErrorKind;
use embedded_hal_mock::eh1::i2c::{Mock, Transaction as T};
use palpate_probe::ads1x15::{AdcError, Ads1x15, Channel, FullScale, Variant};

const ADDR_GND: u8 = 0x48; // ADDR pin to GND (Table 4)

#[test]
fn ads1015_continuous_1600sps_ain0_4v096_then_reads_left_justified_results() {
    // 0x4283 = MUX 100 (AIN0/GND) | PGA 001 (±4.096 V) | MODE 0 (continuous) | DR 100 (1600 SPS)
    //          | COMP_QUE 11 (comparator off). Read-back has OS = 1 (idle).
    let exp = [
        T::write(ADDR_GND, vec![0x01, 0x42, 0x83]),
        T::write_read(ADDR_GND, vec![0x01], vec![0xC2, 0x83]),
        T::write_read(ADDR_GND, vec![0x00], vec![0x7F, 0xF0]), // +full scale = 2047
        T::write_read(ADDR_GND, vec![0x00], vec![0x80, 0x00]), // −full scale = −2048
        T::write_read(ADDR_GND, vec![0x00], vec![0x00, 0x10]), // 1 LSB
    ];
    let mut adc = Ads1x15::new(Mock::new(&exp), ADDR_GND, Variant::Ads1015);
    assert_eq!(
        adc.start_continuous(Channel::A0, FullScale::V4_096, 1000),
        Ok(1600)
    );
    assert_eq!(adc.read_counts(), Ok(2047));
    assert_eq!(adc.read_counts(), Ok(-2048));
    assert_eq!(adc.read_counts(), Ok(1));
    // 12 bits over ±4.096 V: 2 mV per count (datasheet Table 3).
    assert_eq!(adc.volts_per_count(), 0.002);
    adc.destroy().done();
}

#[test]
fn ads1115_picks_860sps_for_500hz_and_reads_16bit_results() {
    // 0x52E3 = MUX 101 (AIN1/GND) | PGA 001 | continuous | DR 111 (860 SPS) | COMP_QUE 11.
    let exp = [
        T::write(0x49, vec![0x01, 0x52, 0xE3]),
        T::write_read(0x49, vec![0x01], vec![0xD2, 0xE3]),
        T::write_read(0x49, vec![0x00], vec![0x7F, 0xFF]),
        T::write_read(0x49, vec![0x00], vec![0xFF, 0xFF]),
    ];
    let mut adc = Ads1x15::new(Mock::new(&exp), 0x49, Variant::Ads1115);
    assert_eq!(
        adc.start_continuous(Channel::A1, FullScale::V4_096, 500),
        Ok(860)
    );
    assert_eq!(adc.read_counts(), Ok(32767));
    assert_eq!(adc.read_counts(), Ok(-1));
    assert_eq!(adc.volts_per_count(), 0.000125); // 125 µV LSB at ±4.096 V
    adc.destroy().done();
}

#[test]
fn too_fast_for_the_ads1115_is_refused_without_touching_the_bus() {
    let mut adc = Ads1x15::new(Mock::new(&[]), ADDR_GND, Variant::Ads1115);
    assert_eq!(
        adc.start_continuous(Channel::A0, FullScale::V4_096, 1000),
        Err(AdcError::RateUnsupported {
            rate_hz: 1000,
            max_hz: 860
        })
    );
    adc.destroy().done();
}

#[test]
fn wrong_readback_and_nack_are_reported() {
    // A chip that keeps its reset config 0x8583 (e.g. a different part at this address).
    let exp = [
        T::write(ADDR_GND, vec![0x01, 0x42, 0x83]),
        T::write_read(ADDR_GND, vec![0x01], vec![0x85, 0x83]),
        T::write(ADDR_GND, vec![0x01, 0x42, 0x83]).with_error(ErrorKind::Other),
    ];
    let mut adc = Ads1x15::new(Mock::new(&exp), ADDR_GND, Variant::Ads1015);
    assert_eq!(
        adc.start_continuous(Channel::A0, FullScale::V4_096, 1000),
        Err(AdcError::ConfigReadback {
            wrote: 0x4283,
            read: 0x0583
        })
    );
    assert_eq!(
        adc.start_continuous(Channel::A0, FullScale::V4_096, 1000),
        Err(AdcError::Bus(ErrorKind::Other))
    );
    adc.destroy().done();
}
