//! palpate probe on an nRF52840: an FSR divider (10 kΩ to GND, 3.3 V) on AIN0 of an ADS1015 at
//! I²C address 0x48 on TWIM0 (SCL P0.27, SDA P0.26, 400 kHz); frames out on UARTE0 (TX P0.06,
//! RX P0.08, 1 Mbaud — a 1 kHz sample stream needs ~310 kbit/s). All logic lives in the tested
//! `palpate-probe` library; this file only wires it to the board. It cannot be flashed here.
#![no_std]
#![no_main]

use defmt_rtt as _;
use embedded_io::{Read, ReadReady};
use nrf52840_hal::{
    gpio::{p0, Level},
    pac,
    timer::Timer,
    twim::{self, Twim},
    uarte::{self, Baudrate, Parity, Uarte},
};
use palpate_probe::ads1x15::{register::address, Ads1x15, Channel, FullScale, Variant};
use palpate_probe::frontend::FrontEndLimits;
use palpate_probe::sim::default_config;
use palpate_probe::tx::FrameWriter;
use palpate_probe::{Probe, ProbeSettings};
use palpate_protocol::link::{ErrorCode, ErrorReport, Frame, Receiver};
use panic_probe as _;

/// A 1 MHz free-running timer widened to 64 bits (TIMER0 wraps every 71.6 minutes).
struct Clock<T: nrf52840_hal::timer::Instance> {
    timer: Timer<T, nrf52840_hal::timer::Periodic>,
    last: u32,
    high: u64,
}

impl<T: nrf52840_hal::timer::Instance> Clock<T> {
    fn now_us(&mut self) -> u64 {
        let t = self.timer.read();
        if t < self.last {
            self.high += 1 << 32;
        }
        self.last = t;
        self.high | u64::from(t)
    }
}

#[cortex_m_rt::entry]
fn main() -> ! {
    let p = pac::Peripherals::take().unwrap();
    let port0 = p0::Parts::new(p.P0);
    let mut timer = Timer::periodic(p.TIMER0);
    timer.start(u32::MAX);
    let mut clock = Clock { timer, last: 0, high: 0 };

    let i2c = Twim::new(
        p.TWIM0,
        twim::Pins { scl: port0.p0_27.into_floating_input().degrade(), sda: port0.p0_26.into_floating_input().degrade() },
        twim::Frequency::K400,
    );
    let uart = Uarte::new(
        p.UARTE0,
        uarte::Pins {
            txd: port0.p0_06.into_push_pull_output(Level::High).degrade(),
            rxd: port0.p0_08.into_floating_input().degrade(),
            cts: None,
            rts: None,
        },
        Parity::EXCLUDED,
        Baudrate::BAUD1M,
    );
    let tx_buf = cortex_m::singleton!(: [u8; 160] = [0; 160]).unwrap();
    let rx_buf = cortex_m::singleton!(: [u8; 1] = [0; 1]).unwrap();
    let (uart_tx, mut uart_rx) = uart.split(tx_buf, rx_buf).unwrap();
    let mut tx = FrameWriter::new(uart_tx);
    let _ = tx.flush_line();

    let settings = ProbeSettings {
        channel: Channel::A0,
        range: FullScale::V4_096,
        device_id: unsafe { (*pac::FICR::ptr()).deviceid[0].read().bits() },
        stuck_window: 200,
        limits: FrontEndLimits::default(),
    };
    let mut adc = Ads1x15::new(i2c, address::GND, Variant::Ads1015);
    let config = default_config();
    // Until the converter answers (and reads its config back), report the bus error once a
    // second and retry; the probe never streams forces from a converter it could not set up.
    while let Err(e) = adc.start_continuous(settings.channel, settings.range, config.rate_hz) {
        defmt::error!("ADC start failed: {}", defmt::Debug2Format(&e));
        let _ = tx.send(&Frame::Error(ErrorReport { code: ErrorCode::AdcBus, detail: 0 }));
        let t0 = clock.now_us();
        while clock.now_us() - t0 < 1_000_000 {}
    }
    let mut probe = match Probe::new(adc, settings, config, clock.now_us()) {
        Ok(p) => p,
        Err(e) => defmt::panic!("probe start failed after the ADC answered: {}", defmt::Debug2Format(&e)),
    };
    let _ = tx.send(&probe.hello());
    let _ = tx.send(&Frame::Config(*probe.config()));
    defmt::info!("probe running at {} Hz", probe.config().rate_hz);

    let mut rx: Receiver = Receiver::new();
    let mut dropped = 0u32;
    loop {
        let now = clock.now_us();
        if let Some(s) = probe.poll(now) {
            if tx.send(&Frame::Sample(s)).is_err() {
                dropped += 1;
            }
            if let Some(f) = probe.take_overrun() {
                let _ = tx.send(&f);
            }
            if dropped > 0 && tx.send(&Frame::Error(ErrorReport { code: ErrorCode::TxDropped, detail: dropped })).is_ok() {
                dropped = 0;
            }
        }
        // Host → probe: a config frame changes rate, filter and calibration.
        if let Ok(true) = uart_rx.read_ready() {
            let mut b = [0u8; 1];
            if let Ok(1) = uart_rx.read(&mut b) {
                if let Some(Ok(f)) = rx.push(b[0]) {
                    if let Some(reply) = probe.handle(&f, clock.now_us()) {
                        let _ = tx.send(&reply);
                    }
                }
            }
        }
    }
}
