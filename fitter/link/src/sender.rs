//! The simulated probe as a sender: the firmware library ([`SimProbe`]) sampling a scripted
//! force and writing frames through its `embedded-io` frame writer to a byte sink (one end of a
//! pty in the tests, a serial device for `palpate probe-sim`).

use super::port::StdWrite;
use palpate_probe::sim::SimProbe;
use palpate_probe::tx::FrameWriter;
use palpate_protocol::link::{ForceSample, Frame, LINK_VERSION};
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// How simulated time relates to wall time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pacing {
    /// Simulated time is wall time: one frame per period, latency is meaningful.
    RealTime,
    /// Simulated time runs as fast as the link takes frames (the pty's back-pressure paces it).
    AsFastAsPossible,
}

/// A pause of the sender (a hung probe): no sampling, no frames, for `duration_s` of
/// simulated time from `at_s`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stall {
    /// Start, simulated seconds.
    pub at_s: f64,
    /// Length, simulated seconds.
    pub duration_s: f64,
}

/// A converter fault injected for a window of simulated time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdcFault {
    /// Start, simulated seconds.
    pub at_s: f64,
    /// Length, simulated seconds.
    pub duration_s: f64,
    /// What goes wrong.
    pub kind: AdcFaultKind,
}

/// Kinds of converter fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AdcFaultKind {
    /// The conversion register stops changing (mid-scale value): the probe must flag `STUCK`.
    Frozen,
    /// Every read is NACKed: the probe must flag `ADC_ERROR`.
    Nack,
}

/// Sender options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SenderOptions {
    /// Simulated seconds to run.
    pub seconds: f64,
    /// Pacing.
    pub pacing: Pacing,
    /// Version byte to stamp (normally `LINK_VERSION`).
    pub version: u8,
    /// Optional stall.
    pub stall: Option<Stall>,
    /// Optional converter fault.
    pub adc_fault: Option<AdcFault>,
}

impl SenderOptions {
    /// `seconds` of samples at `pacing`, stamped with [`LINK_VERSION`], without stall or fault.
    pub fn clean(seconds: f64, pacing: Pacing) -> Self {
        Self {
            seconds,
            pacing,
            version: LINK_VERSION,
            stall: None,
            adc_fault: None,
        }
    }
}

/// What the sender did.
#[derive(Debug, Clone, Default)]
pub struct SenderReport {
    /// Every sample the probe produced, in order (sent or not).
    pub samples: Vec<ForceSample>,
    /// Wall instant just before each sample's frame was written (`None`: the write failed).
    /// Taken before the write, not after: the receiver may decode and solve the frame before the
    /// writing thread returns from `write`, and a "written" instant after "solved" would make a
    /// latency negative (and `Instant::duration_since` silently saturate it to zero).
    pub written_at: Vec<Option<Instant>>,
    /// Frames of any kind written.
    pub frames_written: u64,
    /// Writes that failed (port closed, timed out); their samples are lost and count as gaps.
    pub write_errors: u64,
}

/// Runs the simulated probe into `sink` until `opts.seconds` of simulated time have passed or
/// `stop` is set. `base` is the wall instant of simulated time 0.
pub fn run_sender<W: Write>(
    sink: W,
    mut sim: SimProbe,
    opts: &SenderOptions,
    base: Instant,
    stop: &AtomicBool,
) -> (SenderReport, W) {
    let mut tx = FrameWriter::with_version(StdWrite(sink), opts.version);
    let mut rep = SenderReport::default();
    let _ = tx.flush_line();
    let hello = sim.probe.hello();
    let config = Frame::Config(*sim.probe.config());
    for f in [hello, config] {
        match tx.send(&f) {
            Ok(()) => rep.frames_written += 1,
            Err(_) => rep.write_errors += 1,
        }
    }
    let end_us = (opts.seconds * 1e6) as u64;
    while !stop.load(Ordering::Relaxed) {
        let mut now_us = sim.probe.next_due_us();
        if now_us >= end_us {
            break;
        }
        if let Some(st) = opts.stall {
            let (a, b) = (
                (st.at_s * 1e6) as u64,
                ((st.at_s + st.duration_s) * 1e6) as u64,
            );
            if now_us >= a && now_us < b {
                now_us = b;
            }
            if now_us >= end_us {
                break;
            }
        }
        if opts.pacing == Pacing::RealTime {
            let due = base + Duration::from_micros(now_us);
            // Sleep most of the wait, then spin the last ~100 µs (sleep overshoots by ~60 µs).
            loop {
                let t = Instant::now();
                if t >= due {
                    break;
                }
                let left = due - t;
                if left > Duration::from_micros(150) {
                    std::thread::sleep(left - Duration::from_micros(100));
                } else {
                    std::hint::spin_loop();
                }
            }
        }
        if let Some(f) = opts.adc_fault {
            let t = now_us as f64 * 1e-6;
            let on = t >= f.at_s && t < f.at_s + f.duration_s;
            let bus = sim.probe.adc_mut().bus_mut();
            bus.frozen = (on && f.kind == AdcFaultKind::Frozen).then_some(0x4000);
            bus.fail_next = u32::from(on && f.kind == AdcFaultKind::Nack);
        }
        let Some(s) = sim.step(now_us) else { continue };
        let mut frames = [Some(Frame::Sample(s)), sim.probe.take_overrun()];
        let before_write = Instant::now();
        // An overrun report goes after the sample whose sequence number shows the gap.
        let mut ok = true;
        for (i, f) in frames.iter_mut().enumerate() {
            let Some(f) = f.take() else { continue };
            match tx.send(&f) {
                Ok(()) => rep.frames_written += 1,
                Err(_) => {
                    rep.write_errors += 1;
                    if i == 0 {
                        ok = false;
                    }
                }
            }
        }
        rep.samples.push(s);
        rep.written_at.push(ok.then_some(before_write));
    }
    let _ = tx.flush();
    (rep, tx.into_inner().0)
}
