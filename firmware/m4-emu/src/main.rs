//! palpate's runtime and probe firmware on an emulated Cortex-M4F (QEMU `mps2-an386`).
//!
//! Plays each bundled `.palp` model (in flash, `include_bytes!`) through a scripted probe press in
//! a fixed static pool no larger than an nRF52840 leaves, then runs the probe firmware's
//! sampling, calibration and framing path on the library's scripted converter (a simulated
//! ADS1015 on a pretend I²C bus). Everything goes out over semihosting as `m4 …` lines — the
//! probe's positions, the reaction forces and the final displacement hash as f32 bits, the link
//! frames as hex, and the SysTick counts of each tick — which `palpate-lab m4-emu compare`
//! replays on the host and checks bit for bit. The exit status is the run's (semihosting exit).
//!
//! Counting: under `qemu-system-arm -icount shift=0` the virtual clock advances 1 ns per
//! instruction executed, and SysTick on the processor clock (25 MHz on this board) counts one per
//! 40 ns, so one SysTick count is 40 instructions. The run calibrates that against a loop of a
//! known instruction count and prints both. QEMU models no cycle counter (DWT CYCCNT reads 0).
#![no_std]
#![no_main]

use core::fmt::Write as _;
use cortex_m::peripheral::{syst::SystClkSource, SYST};
use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hio};
use palpate_probe::sim::{default_config, Profile, SimProbe};
use palpate_probe::tx::FrameWriter;
use palpate_protocol::link::{Frame, MAX_FRAME_ENCODED};
use palpate_runtime::{Probe, Runtime, RuntimeConfig, StorageRequirement};

mod state_hash;
use state_hash::fnv1a;

/// The bundled models, by name (`palpate-lab m4-emu models` writes them).
const MODELS: &[(&str, &[u8])] = &[
    ("block-6", include_bytes!("../models/block-6.palp")),
    ("block-24", include_bytes!("../models/block-24.palp")),
    ("block-192", include_bytes!("../models/block-192.palp")),
];

/// Runtime storage: 224 KiB of the nRF52840's 256 KiB, the rest for the stack (the runtime's
/// 8-lane kernels keep a few KiB of lane arrays on it) and the probe's state.
const POOL_WORDS: usize = 224 * 1024 / 4;

/// The scripted press, what a force-feedback device drives: a rigid sphere of `SPHERE_RADIUS`
/// (the runtime bench's) above the top centre of the 10 × 10 × 5 cm block, moved in by a
/// raised-cosine ramp from `START_DEPTH` (clear of the surface) to `PEAK_DEPTH` over `RAMP`
/// ticks, held, and withdrawn by a raised-cosine release: a hand's smooth press at 1 kHz.
const SPHERE_RADIUS: f32 = 0.01;
const START_DEPTH: f32 = -0.0005;
const PEAK_DEPTH: f32 = 0.002;
const TOP: [f32; 3] = [0.05, 0.05, 0.05];
const RAMP: u32 = 150;
const HOLD: u32 = 50;
const RELEASE: u32 = 100;

/// SysTick counts one per this many instructions under `-icount shift=0` (25 MHz core clock:
/// 40 ns per count, 1 ns per instruction).
const INSTRUCTIONS_PER_COUNT: u32 = 40;

/// The probe script: `Profile::Press` of this peak and period, ±`NOISE` counts of dither,
/// sampled at the board config's 1 kHz for `PROBE_US`.
const PROBE_PEAK_N: f32 = 5.0;
const PROBE_PERIOD_S: f32 = 0.25;
const PROBE_NOISE: i16 = 2;
const PROBE_US: u64 = 300_000;

type Line = heapless::String<256>;

fn emit(line: &Line) {
    if let Ok(mut out) = hio::hstdout() {
        let _ = out.write_all(line.as_bytes());
        let _ = out.write_all(b"\n");
    }
}

macro_rules! line {
    ($($arg:tt)*) => {{
        let mut l = Line::new();
        let _ = write!(l, $($arg)*);
        emit(&l);
    }};
}

/// After the semihosting exit (QEMU has stopped by then; a debugger would not).
fn halt() -> ! {
    loop {
        cortex_m::asm::wfi();
    }
}

fn fail(what: &str) -> ! {
    line!("m4 error {what}");
    debug::exit(debug::EXIT_FAILURE);
    halt()
}

/// Timer counts elapsed since `start` (SysTick counts down through 24 bits).
fn counts_since(start: u32) -> u32 {
    start.wrapping_sub(SYST::get_current()) & 0x00FF_FFFF
}

fn depth_at(k: u32) -> f32 {
    let pi = core::f32::consts::PI;
    let shape = if k < RAMP {
        0.5 * (1.0 - libm::cosf(pi * k as f32 / RAMP as f32))
    } else if k < RAMP + HOLD {
        1.0
    } else {
        0.5 * (1.0 + libm::cosf(pi * (k - RAMP - HOLD) as f32 / RELEASE as f32))
    };
    START_DEPTH + (PEAK_DEPTH - START_DEPTH) * shape
}

fn play(name: &str, bytes: &[u8], pool: &mut [u32]) {
    let record = match palpate_protocol::model::decode(bytes) {
        Ok(r) => r,
        Err(e) => {
            line!("m4 error {name}: {e}");
            fail("model");
        }
    };
    let cfg = RuntimeConfig::default();
    let need = StorageRequirement::for_model(&record, &cfg);
    if need.u32s + need.f32s > pool.len() {
        line!(
            "m4 error {name}: needs {} B of runtime storage, the pool holds {} B",
            need.bytes(),
            4 * pool.len()
        );
        fail("storage");
    }
    let (u, rest) = pool.split_at_mut(need.u32s);
    let f: &mut [f32] = bytemuck::cast_slice_mut(&mut rest[..need.f32s]);
    let mut rt = match Runtime::new(record, f, u, cfg) {
        Ok(rt) => rt,
        Err(e) => {
            line!("m4 error {name}: {e:?}");
            fail("runtime");
        }
    };
    line!(
        "m4 model {name} {} {} {}",
        rt.node_count(),
        rt.element_count(),
        need.bytes()
    );
    line!("m4 press {name} {:08x}", SPHERE_RADIUS.to_bits());
    for k in 0..RAMP + HOLD + RELEASE {
        let center = [TOP[0], TOP[1], TOP[2] + SPHERE_RADIUS - depth_at(k)];
        let start = SYST::get_current();
        let probe = Probe::Sphere {
            center,
            radius: SPHERE_RADIUS,
        };
        if let Err(e) = rt.set_probe(probe) {
            line!("m4 error {name}: tick {k}: {e:?}");
            fail("probe");
        }
        let report = rt.tick();
        let counts = counts_since(start);
        line!(
            "m4 tick {name} {k} {:08x} {:08x} {:08x} {:08x} {:08x} {:08x} {}/{}",
            center[0].to_bits(),
            center[1].to_bits(),
            center[2].to_bits(),
            report.reaction[0].to_bits(),
            report.reaction[1].to_bits(),
            report.reaction[2].to_bits(),
            report.iterations,
            counts
        );
    }
    line!("m4 state {name} {:016x}", fnv1a(rt.displacements()));
}

/// One frame's bytes, for printing as hex.
struct FrameSink {
    buf: [u8; MAX_FRAME_ENCODED],
    len: usize,
}

impl embedded_io::ErrorType for FrameSink {
    type Error = embedded_io::ErrorKind;
}

impl embedded_io::Write for FrameSink {
    fn write(&mut self, data: &[u8]) -> Result<usize, Self::Error> {
        let room = self.buf.len() - self.len;
        let n = data.len().min(room);
        if n == 0 && !data.is_empty() {
            return Err(embedded_io::ErrorKind::OutOfMemory);
        }
        self.buf[self.len..self.len + n].copy_from_slice(&data[..n]);
        self.len += n;
        Ok(n)
    }

    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

fn emit_frame(tx: &mut FrameWriter<FrameSink>, counts: u32) {
    let sink = tx.inner_mut();
    let mut l = Line::new();
    let _ = l.push_str("m4 frame ");
    for b in &sink.buf[..sink.len] {
        let _ = write!(l, "{b:02x}");
    }
    let _ = write!(l, " {counts}");
    emit(&l);
    sink.len = 0;
}

fn send(tx: &mut FrameWriter<FrameSink>, frame: &Frame) {
    if tx.send(frame).is_err() {
        fail("probe frame did not encode");
    }
}

fn probe_run() {
    line!(
        "m4 probe {:08x} {:08x} {PROBE_NOISE} {PROBE_US}",
        PROBE_PEAK_N.to_bits(),
        PROBE_PERIOD_S.to_bits()
    );
    let profile = Profile::Press {
        peak: PROBE_PEAK_N,
        period_s: PROBE_PERIOD_S,
    };
    let mut sim = match SimProbe::new(default_config(), profile, PROBE_NOISE) {
        Ok(s) => s,
        Err(_) => fail("probe start"),
    };
    let mut tx = FrameWriter::new(FrameSink {
        buf: [0; MAX_FRAME_ENCODED],
        len: 0,
    });
    let hello = sim.probe.hello();
    send(&mut tx, &hello);
    emit_frame(&mut tx, 0);
    let config = *sim.probe.config();
    send(&mut tx, &Frame::Config(config));
    emit_frame(&mut tx, 0);
    let mut now = 0u64;
    while now <= PROBE_US {
        // The scripted force reaches the simulated converter outside the count: on the board
        // it is the FSR's physics, not the firmware's work.
        let f = sim.scripted_force(now);
        let cal = sim.probe.config().calibration;
        sim.probe.adc_mut().bus_mut().press(&cal, f);
        let start = SYST::get_current();
        if let Some(s) = sim.probe.poll(now) {
            send(&mut tx, &Frame::Sample(s));
            let counts = counts_since(start);
            emit_frame(&mut tx, counts);
            if let Some(o) = sim.probe.take_overrun() {
                send(&mut tx, &o);
                emit_frame(&mut tx, 0);
            }
        }
        now += 1000;
    }
}

#[entry]
fn main() -> ! {
    static mut POOL: [u32; POOL_WORDS] = [0; POOL_WORDS];
    let Some(mut cp) = cortex_m::Peripherals::take() else {
        fail("peripherals taken twice");
    };
    cp.SYST.set_clock_source(SystClkSource::Core);
    cp.SYST.set_reload(0x00FF_FFFF);
    cp.SYST.clear_current();
    cp.SYST.enable_counter();

    // Calibration: `asm::delay(n)` is n + 1 iterations of `subs; bne`.
    let n = 999_999;
    let start = SYST::get_current();
    cortex_m::asm::delay(n);
    let counts = counts_since(start);
    line!("m4 timer {INSTRUCTIONS_PER_COUNT} systick");
    line!("m4 calibrate {} {counts}", 2 * (n + 1));
    cp.DCB.enable_trace();
    cp.DWT.enable_cycle_counter();
    let c0 = cortex_m::peripheral::DWT::cycle_count();
    cortex_m::asm::delay(n);
    let c1 = cortex_m::peripheral::DWT::cycle_count();
    line!("m4 note dwt_cyccnt_delta {}", c1.wrapping_sub(c0));

    // The runtime accumulates its dot products and norms in f64 (kernel::dot_lanes,
    // norm2_lanes): on a single-precision FPU each of those is a software routine.
    let v = [0.5f32; 1024];
    let start = SYST::get_current();
    let n2 = palpate_runtime::kernel::norm2_lanes(core::hint::black_box(&v));
    let counts = counts_since(start);
    core::hint::black_box(n2);
    line!("m4 kernel norm2_lanes {} {counts}", v.len());

    for (name, bytes) in MODELS {
        play(name, bytes, &mut POOL[..]);
    }
    probe_run();
    line!("m4 done");
    debug::exit(debug::EXIT_SUCCESS);
    halt()
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    let mut l = Line::new();
    let _ = write!(l, "m4 error panic: {info}");
    emit(&l);
    debug::exit(debug::EXIT_FAILURE);
    halt()
}
