//! Hardware-in-the-loop harness: the firmware library (simulated ADC) writes frames into one
//! end of a real pseudo-terminal pair, the host link reads them from the other end.

use palpate_link::faults::{FaultCounts, FaultPlan, FaultyWriter};
use palpate_link::sender::{run_sender, SenderOptions, SenderReport};
use palpate_link::FrameReader;
use palpate_probe::sim::{Profile, SimProbe};
use palpate_protocol::link::{Config, ForceSample, Frame, LinkStats};

use serialport::{SerialPort, TTYPort};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Close the host end after this many delivered samples, stay unplugged for `away`, reopen.
#[derive(Debug, Clone, Copy)]
pub struct Unplug {
    /// Delivered samples before the unplug.
    pub after_samples: usize,
    /// Time unplugged.
    pub away: Duration,
}

/// Everything one run produced.
#[derive(Debug)]
pub struct HilRun {
    /// The sender's account.
    pub sent: SenderReport,
    /// Delivered samples with host arrival instants.
    pub delivered: Vec<(ForceSample, Instant)>,
    /// Delivered frames other than samples.
    pub other: Vec<Frame>,
    /// Receiver counters.
    pub stats: LinkStats,
    /// Injected faults.
    pub faults: FaultCounts,
    /// Peer version seen in rejected frames.
    pub peer_version: Option<u8>,
    /// Wall instant of simulated time 0.
    pub base: Instant,
    /// Samples delivered after the reopen (when unplugged).
    pub delivered_after_reopen: usize,
    /// When the host end was closed and when it was open again (when unplugged).
    pub unplugged: Option<(Instant, Instant)>,
}

/// Runs `profile` through the simulated probe for `opts.seconds` over a fresh pty pair, with
/// `plan` faults on the wire and an optional unplug of the host end. `on_batch` gets the
/// samples of each read as they arrive (the host side's live hook, e.g. the runtime).
// Each argument is one independent knob of a test scenario; a builder would only rename them.
#[allow(clippy::too_many_arguments)]
pub fn run_link(
    config: Config,
    profile: Profile,
    noise: i16,
    opts: SenderOptions,
    plan: FaultPlan,
    seed: u64,
    unplug: Option<Unplug>,
    mut on_batch: impl FnMut(&[ForceSample]),
) -> HilRun {
    let (mut master, mut slave) = TTYPort::pair().expect("pty pair");
    master.set_timeout(Duration::from_millis(500)).unwrap();
    slave.set_timeout(Duration::from_millis(20)).unwrap();
    let path = slave.name().expect("slave has a path");
    let sim = SimProbe::new(config, profile, noise).expect("sim probe");
    let base = Instant::now();
    let stop = Arc::new(AtomicBool::new(false));
    let done = Arc::new(AtomicBool::new(false));
    let (stop2, done2) = (stop.clone(), done.clone());
    let sender = std::thread::spawn(move || {
        let sink = FaultyWriter::new(master, plan, seed);
        let (rep, sink) = run_sender(sink, sim, &opts, base, &stop2);
        done2.store(true, Ordering::SeqCst);
        (rep, sink.counts(), sink)
    });
    let mut reader = FrameReader::new(slave);
    let mut delivered = Vec::new();
    let mut other = Vec::new();
    let mut quiet_since = None;
    let mut unplugged = unplug;
    let mut reopen_at_len = None;
    let mut away = None;
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let mut batch = Vec::new();
        let n = reader
            .poll(|f, at| match f {
                Frame::Sample(s) => {
                    delivered.push((s, at));
                    batch.push(s);
                }
                f => other.push(f),
            })
            .unwrap_or(0);
        if !batch.is_empty() {
            on_batch(&batch);
        }
        if let Some(u) = unplugged {
            if delivered.len() >= u.after_samples {
                unplugged = None;
                // Unplug: close the host end for a while, then open the device path again.
                let closed_at = Instant::now();
                let old = reader.replace_source(TTYPort::pair().expect("placeholder").1);
                drop(old);
                std::thread::sleep(u.away);
                let mut port = serialport::new(&path, 1_000_000)
                    .timeout(Duration::from_millis(20))
                    .open_native()
                    .expect("reopen");
                port.set_timeout(Duration::from_millis(20)).unwrap();
                reader.replace_source(port);
                reopen_at_len = Some(delivered.len());
                away = Some((closed_at, Instant::now()));
            }
        }
        if n == 0 && done.load(Ordering::SeqCst) {
            let t = *quiet_since.get_or_insert_with(Instant::now);
            if t.elapsed() > Duration::from_millis(100) {
                break;
            }
        } else {
            quiet_since = None;
        }
        if Instant::now() > deadline {
            stop.store(true, Ordering::SeqCst);
        }
    }
    let (sent, faults, _sink) = sender.join().expect("sender thread");
    let delivered_after_reopen = reopen_at_len.map_or(0, |k| delivered.len() - k);
    let stats = *reader.stats();
    let peer_version = reader.receiver_mut().peer_version();
    HilRun {
        sent,
        delivered,
        other,
        stats,
        faults,
        peer_version,
        base,
        delivered_after_reopen,
        unplugged: away,
    }
}

/// Checks the invariants every run must keep, whatever the faults: each delivered sample is
/// bit-for-bit the one the probe sent under that number, numbers strictly increase, and every
/// sample not delivered is counted as missing (requires the first and last samples to arrive:
/// the fault plans keep the first and last frames clean).
pub fn assert_link_invariants(run: &HilRun) {
    let mut last = None;
    for (s, _) in &run.delivered {
        let sent = run
            .sent
            .samples
            .iter()
            .find(|x| x.seq == s.seq)
            .unwrap_or_else(|| panic!("delivered seq {} was never sent", s.seq));
        assert_eq!(
            s, sent,
            "delivered sample differs from the one sent: corrupted frame delivered"
        );
        if let Some(l) = last {
            assert!(s.seq > l, "out of order: {} after {l}", s.seq);
        }
        last = Some(s.seq);
    }
    let first = run.delivered.first().expect("something delivered").0.seq;
    assert_eq!(
        first, run.sent.samples[0].seq,
        "first sample lost: the plans keep it clean"
    );
    let last = last.unwrap();
    assert_eq!(
        last,
        run.sent.samples.last().unwrap().seq,
        "last sample lost: the plans keep the tail clean"
    );
    // Numbers consumed by the probe (including stalled / skipped slots) = delivered + missing.
    assert_eq!(
        run.stats.samples + run.stats.missing_samples,
        u64::from(last - first) + 1,
        "{:?}",
        run.stats
    );
    assert_eq!(run.stats.samples as usize, run.delivered.len());
}
