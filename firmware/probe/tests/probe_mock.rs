//! The probe pipeline (counts → force, flags, schedule, frames) on a mock I²C bus.

use embedded_hal::i2c::ErrorKind;
use embedded_hal_mock::eh1::i2c::{Mock, Transaction as T};
use palpate_probe::ads1x15::{Ads1x15, Channel, FullScale, Variant};
use palpate_probe::filter::LowPass;
use palpate_probe::frontend::FrontEndLimits;
use palpate_probe::schedule::Schedule;
use palpate_probe::tx::FrameWriter;
use palpate_probe::{Probe, ProbeSettings};
use palpate_protocol::link::{
    status, Calibration, Config, Divider, ForceCurve, ForceSample, Frame,
};

const A: u8 = 0x48;

fn cal() -> Calibration {
    Calibration {
        divider: Divider {
            r_pulldown_ohm: 10_000.0,
            v_supply_v: 3.3,
        },
        curve: ForceCurve::PowerLaw {
            gain: 0.01,
            exponent: 1.0,
        },
        usable_min_n: 0.2,
        usable_max_n: 50.0,
    }
}

fn settings(stuck_window: u32) -> ProbeSettings {
    ProbeSettings {
        channel: Channel::A0,
        range: FullScale::V4_096,
        device_id: 1,
        stuck_window,
        limits: FrontEndLimits::default(),
    }
}

fn start() -> Vec<T> {
    vec![
        T::write(A, vec![0x01, 0x42, 0x83]),
        T::write_read(A, vec![0x01], vec![0xC2, 0x83]),
    ]
}

fn conv(counts: i16) -> T {
    T::write_read(A, vec![0x00], ((counts << 4) as u16).to_be_bytes().to_vec())
}

/// 1 kHz, no filter, the calibration of [`cal`].
fn config() -> Config {
    Config {
        rate_hz: 1000,
        filter_cutoff_hz: 0.0,
        calibration: cal(),
    }
}

/// A probe on a mock bus that expects `exp`, started at t = 0 with [`config`].
fn probe(exp: &[T], stuck_window: u32) -> Probe<Mock> {
    Probe::new(
        Ads1x15::new(Mock::new(exp), A, Variant::Ads1015),
        settings(stuck_window),
        config(),
        0,
    )
    .unwrap()
}

#[test]
fn counts_become_force_and_faults_are_flagged() {
    let mut exp = start();
    exp.extend([conv(1000), conv(2047), conv(0)]);
    exp.push(T::write_read(A, vec![0x00], vec![0, 0]).with_error(ErrorKind::Other));
    let mut p = probe(&exp, 0);

    // 1000 counts · 2 mV = 2.0 V; G = V / (R (Vs − V)) = 2 / (1e4 · 1.3) S = 153.846 µS; F = 0.01 · G.
    let s = p.poll(0).unwrap();
    assert_eq!(
        (s.seq, s.timestamp_us, s.raw_counts, s.status),
        (0, 0, 1000, status::OK)
    );
    assert!((s.force_n - 1.538_46).abs() < 1e-4, "{s:?}");
    // Full scale (4.094 V > 0.99 · 3.3 V): saturated, force at the saturation point (a lower bound).
    let s = p.poll(1000).unwrap();
    assert_eq!(s.status & status::SATURATED, status::SATURATED);
    assert!(
        (s.force_n - 0.01 * 3.267 / (1e4 * 0.033) * 1e6).abs() < 0.05,
        "{s:?}"
    );
    // No conduction: force exactly 0.
    let s = p.poll(2000).unwrap();
    assert_eq!((s.status, s.force_n), (status::OPEN_CIRCUIT, 0.0));
    // Bus error: repeat the last value, flagged.
    let s = p.poll(3000).unwrap();
    assert_eq!(
        (s.status, s.raw_counts, s.force_n, s.seq),
        (status::ADC_ERROR, 0, 0.0, 3)
    );
    p.adc_mut().bus_mut().done();
}

#[test]
fn a_frozen_converter_is_flagged_stuck_after_the_window() {
    let mut exp = start();
    exp.extend((0..12).map(|_| conv(900)));
    let mut p = probe(&exp, 10);
    let flags: Vec<u8> = (0..12u64)
        .map(|k| p.poll(k * 1000).unwrap().status & status::STUCK)
        .collect();
    // Readings 1..9 can still be a quiet sensor; the 10th identical one in a row is stuck.
    assert_eq!(flags, [0, 0, 0, 0, 0, 0, 0, 0, 0, 4, 4, 4]);
    p.adc_mut().bus_mut().done();
}

#[test]
fn late_polls_skip_slots_and_report_an_overrun() {
    let mut exp = start();
    exp.extend([conv(500), conv(500)]);
    let mut p = probe(&exp, 0);
    assert_eq!(p.poll(0).unwrap().seq, 0);
    assert!(p.poll(999).is_none());
    // 3.5 periods late: slots 1, 2, 3 are gone, this is slot 4, next due at 5 ms.
    assert_eq!(p.poll(4500).unwrap().seq, 4);
    assert_eq!(p.next_due_us(), 5000);
    assert_eq!(
        p.take_overrun(),
        Some(Frame::Error(palpate_protocol::link::ErrorReport {
            code: palpate_protocol::link::ErrorCode::Overrun,
            detail: 3
        }))
    );
    assert_eq!(p.take_overrun(), None);
    p.adc_mut().bus_mut().done();
}

#[test]
fn config_out_of_range_is_refused_and_the_old_one_stays() {
    let exp = start();
    let mut p = probe(&exp, 0);
    let cfg = config();
    let mut bad = cfg;
    bad.calibration.divider.v_supply_v = 5.0; // above the ±4.096 V range
    let reply = p.handle(&Frame::Config(bad), 0).unwrap();
    assert!(matches!(reply, Frame::Error(_)), "{reply:?}");
    assert_eq!(*p.config(), cfg);
    p.adc_mut().bus_mut().done();
}

#[test]
fn low_pass_step_response_is_the_analytic_one() {
    // α = 1 − exp(−2π · 100 / 1000) = 0.466 512; step response y_k = 1 − (1 − α)^k.
    let mut f = LowPass::new(100.0, 1000.0);
    assert!((f.alpha() - 0.466_512).abs() < 1e-5);
    f.update(0.0);
    for k in 1..20 {
        let y = f.update(1.0);
        let want = 1.0 - (1.0f32 - 0.466_512).powi(k);
        assert!((y - want).abs() < 1e-5, "k={k}: {y} vs {want}");
    }
    assert_eq!(LowPass::new(0.0, 1000.0).alpha(), 1.0);
}

#[test]
fn schedule_has_no_drift() {
    let mut s = Schedule::new(1000, 10);
    let mut seqs = Vec::new();
    for now in (0..10_000u64).step_by(7) {
        if let Some(slot) = s.poll(now) {
            seqs.push(slot.seq);
        }
    }
    // Deadlines at 10 + k · 1000 µs: k = 0 ..= 9 within 10 ms, none skipped.
    assert_eq!(seqs, (0..10).collect::<Vec<_>>());
}

struct Sink(Vec<u8>);
impl embedded_io::ErrorType for Sink {
    type Error = core::convert::Infallible;
}
impl embedded_io::Write for Sink {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.0.extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

#[test]
fn frames_leave_through_embedded_io_with_the_spec_bytes() {
    let mut w = FrameWriter::new(Sink(Vec::new()));
    let s = ForceSample {
        seq: 1000,
        timestamp_us: 1_000_000,
        raw_counts: 12_345,
        force_n: 2.5,
        status: 0,
    };
    w.flush_line().unwrap();
    w.send(&Frame::Sample(s)).unwrap();
    // The example of protocol/LINK-FORMAT.md, after the leading flush delimiter.
    let spec = [
        0x00, 0x0B, 0x01, 0x02, 0xE8, 0x07, 0xC0, 0x84, 0x3D, 0xF2, 0xC0, 0x01, 0x01, 0x03, 0x20,
        0x40, 0x05, 0x25, 0xE2, 0xC6, 0x10, 0x00,
    ];
    assert_eq!(w.into_inner().0, spec);
}
