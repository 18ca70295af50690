//! A haptic replay over a real pseudo-terminal: the simulated probe (firmware library behind a
//! mock ADC) writes frames on one end, the host link and the runtime read and solve on the other.
//! `palpate demo` plays its diagnosed model this way; the link benchmark measures it. Beside it,
//! one model file held under a constant contact force until it settles
//! ([`settle_contact_force`]: the demo's weight at the beam's tip).

use crate::faults::{FaultPlan, FaultyWriter};
use crate::gate::ForceGate;
use crate::haptic::{Contact, HapticLoop};
use crate::port::FrameReader;
use crate::sender::{run_sender, Pacing, SenderOptions, SenderReport};
use crate::stats::{process_cpu_seconds, thread_cpu_seconds, Percentiles};
use crate::LinkHostError;
use palpate_fem::runtime_storage::Storage;
use palpate_probe::sim::{default_config, Profile, SimProbe};
use palpate_protocol::link::{ForceSample, Frame, LinkStats};
use palpate_runtime::{Runtime, RuntimeConfig, SolveStatus};
use serialport::{SerialPort, TTYPort};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// What one pass of simulated probe frames through a pseudo-terminal measured.
pub struct Phase {
    /// sent.
    pub sent: SenderReport,
    /// (seq, arrival, solved)
    /// events.
    pub events: Vec<(u32, Instant, Instant)>,
    /// stats.
    pub stats: LinkStats,
    /// wall s.
    pub wall_s: f64,
    /// rx cpu s.
    pub rx_cpu_s: Option<f64>,
    /// proc cpu s.
    pub proc_cpu_s: Option<f64>,
    /// iterations.
    pub iterations: Vec<f64>,
    /// superseded.
    pub superseded: u64,
}

/// Streams simulated probe frames (the firmware library behind a mock ADC pressing with a
/// 0.5 N, 1 s profile) through a real pseudo-terminal pair and hands every batch that arrives to
/// `on_batch`, which returns its PCG iterations.
pub fn phase(
    opts: SenderOptions,
    rate: u16,
    mut on_batch: impl FnMut(&[ForceSample]) -> Result<u32, LinkHostError>,
) -> Result<Phase, LinkHostError> {
    let (mut master, mut slave) = TTYPort::pair().map_err(LinkHostError::Pty)?;
    master
        .set_timeout(Duration::from_millis(500))
        .map_err(LinkHostError::Pty)?;
    slave
        .set_timeout(Duration::from_millis(20))
        .map_err(LinkHostError::Pty)?;
    let mut cfg = default_config();
    cfg.rate_hz = rate;
    let sim = SimProbe::new(
        cfg,
        Profile::Press {
            peak: 0.5,
            period_s: 1.0,
        },
        2,
    )
    .map_err(|e| LinkHostError::SimProbe(e.to_string()))?;
    let done = Arc::new(AtomicBool::new(false));
    let stop = Arc::new(AtomicBool::new(false));
    let (done2, stop2) = (done.clone(), stop.clone());
    let base = Instant::now();
    let sender = std::thread::spawn(move || {
        let (rep, sink) = run_sender(
            FaultyWriter::new(master, FaultPlan::default(), 1),
            sim,
            &opts,
            base,
            &stop2,
        );
        done2.store(true, Ordering::SeqCst);
        // The master end stays open (inside the join result) until the reader has drained it.
        (rep, sink)
    });
    let mut reader = FrameReader::new(slave);
    let mut events = Vec::new();
    let mut iterations = Vec::new();
    let (cpu0, pcpu0) = (thread_cpu_seconds(), process_cpu_seconds());
    let t0 = Instant::now();
    let mut quiet = None;
    let mut err = None;
    let mut batch: Vec<ForceSample> = Vec::new();
    let mut superseded = 0u64;
    loop {
        batch.clear();
        let mut arrival = None;
        let polled = reader.poll(|f, at| {
            if let Frame::Sample(s) = f {
                batch.push(s);
                arrival = Some(at);
            }
        });
        if let (Some(last), Some(at)) = (batch.last(), arrival) {
            match on_batch(&batch) {
                Ok(it) => {
                    events.push((last.seq, at, Instant::now()));
                    iterations.push(f64::from(it));
                    superseded += batch.len() as u64 - 1;
                }
                Err(e) => err = Some(e),
            }
        }
        let n = match polled {
            Ok(n) => n,
            Err(e) if done.load(Ordering::SeqCst) => {
                let _ = e; // the far end closed after sending everything
                0
            }
            Err(source) => {
                return Err(LinkHostError::Io {
                    what: "reading",
                    path: "the pseudo-terminal".into(),
                    source,
                })
            }
        };
        if let Some(e) = err.take() {
            stop.store(true, Ordering::SeqCst);
            let _ = sender.join();
            return Err(e);
        }
        if n == 0 && done.load(Ordering::SeqCst) {
            if quiet.get_or_insert_with(Instant::now).elapsed() > Duration::from_millis(100) {
                break;
            }
        } else {
            quiet = None;
        }
    }
    let wall_s = events
        .last()
        .map_or(0.0, |e| e.1.duration_since(t0).as_secs_f64());
    let rx_cpu_s = cpu0.zip(thread_cpu_seconds()).map(|(a, b)| b - a);
    let proc_cpu_s = pcpu0.zip(process_cpu_seconds()).map(|(a, b)| b - a);
    let (sent, _master) = sender.join().map_err(|_| LinkHostError::SenderPanicked)?;
    Ok(Phase {
        sent,
        events,
        stats: *reader.stats(),
        wall_s,
        rx_cpu_s,
        proc_cpu_s,
        iterations,
        superseded,
    })
}

/// A model file replayed by [`replay`], and the memory its runtime used.
#[derive(Debug, Clone, Copy)]
pub struct ModelReplay {
    /// What the replay measured.
    pub replay: Replay,
    /// The runtime's memory (bytes), sized once from the model.
    pub footprint_bytes: usize,
}

/// Reads the runtime model (`.palp`) at `path`, builds its runtime under `config` in memory
/// sized for it, and hands it to `play`; an unreadable model, or one the runtime refuses, is a
/// [`LinkHostError::Model`] naming the file.
fn with_model_file<T>(
    path: &Path,
    config: RuntimeConfig,
    play: impl FnOnce(Runtime<'_>) -> Result<T, LinkHostError>,
) -> Result<T, LinkHostError> {
    let model = |message: String| LinkHostError::Model {
        file: path.into(),
        message,
    };
    let file = std::fs::read(path).map_err(|e| model(e.to_string()))?;
    let record = palpate_protocol::model::decode(&file).map_err(|e| model(e.to_string()))?;
    let mut storage = Storage::for_model(&record, &config);
    let runtime = storage
        .runtime(record, config)
        .map_err(|e| model(e.to_string()))?;
    play(runtime)
}

/// Reads the runtime model (`.palp`) at `path`, builds its runtime under `config` in memory
/// sized for it, and replays it as [`replay`] does.
pub fn replay_model_file(
    path: &Path,
    config: RuntimeConfig,
    point: [f32; 3],
    radius: f32,
    seconds: f64,
) -> Result<ModelReplay, LinkHostError> {
    with_model_file(path, config, |runtime| {
        let footprint_bytes = runtime.footprint_bytes();
        Ok(ModelReplay {
            replay: replay(runtime, point, radius, seconds)?,
            footprint_bytes,
        })
    })
}

/// Reads the runtime model (`.palp`) at `path`, builds its runtime under `config` in memory
/// sized for it, holds `force` (N) on the surface at `point` as a contact force of `radius` (m)
/// and ticks until a converged tick moves the displacements by at most 10⁻⁶ of their largest,
/// for at most `max_ticks`: the settled displacements (m, three per node), or `None` when the
/// runtime never settled.
pub fn settle_contact_force(
    path: &Path,
    config: RuntimeConfig,
    point: [f32; 3],
    force: [f32; 3],
    radius: f32,
    max_ticks: usize,
) -> Result<Option<Vec<f32>>, LinkHostError> {
    with_model_file(path, config, |mut rt| {
        rt.set_contact_force(point, force, radius)
            .map_err(|e| LinkHostError::Model {
                file: path.into(),
                message: format!("contact force at {point:?}: {e}"),
            })?;
        for _ in 0..max_ticks {
            let rep = rt.tick();
            let umax = rt
                .displacements()
                .iter()
                .fold(0.0f32, |a, v| a.max(v.abs()));
            if rep.status == SolveStatus::Converged && rep.step <= 1e-6 * umax {
                return Ok(Some(rt.displacements().to_vec()));
            }
        }
        Ok(None)
    })
}

/// What a haptic replay measured.
#[derive(Debug, Clone, Copy)]
pub struct Replay {
    /// Samples that led to a solve.
    pub solved: usize,
    /// Frame written → solved state, median (µs).
    pub p50_us: f64,
    /// Frame written → solved state, 99th percentile (µs).
    pub p99_us: f64,
    /// Mean PCG iterations per solve.
    pub mean_iterations: f64,
    /// Samples missing or frames rejected by the receiver.
    pub lost: u64,
    /// Latency pairs whose "solved" instant preceded "written" (excluded from the percentiles;
    /// should be 0 — a non-zero count means the figures are not to be trusted).
    pub non_monotonic: usize,
}

/// A haptic replay for `palpate demo`: the simulated probe (firmware library behind a mock ADC)
/// presses with a scripted profile, its frames cross a real pseudo-terminal pair at 1 kHz in real
/// time, and `runtime` solves a force-driven contact at `point` for every sample.
pub fn replay(
    runtime: Runtime<'_>,
    point: [f32; 3],
    radius: f32,
    seconds: f64,
) -> Result<Replay, LinkHostError> {
    let contact = Contact {
        point,
        direction: [0.0, 0.0, -1.0],
        radius,
    };
    let mut hl = HapticLoop::new(runtime, ForceGate::new(20, 100.0), contact);
    let opts = SenderOptions::clean(seconds, Pacing::RealTime);
    let lp = phase(opts, 1000, |b| {
        Ok(hl
            .on_batch(b)
            .map_err(LinkHostError::Tick)?
            .map_or(0, |r| r.1.iterations))
    })?;
    let mut e2e = Vec::new();
    let mut non_monotonic = 0;
    for &(seq, _arrival, solved) in &lp.events {
        if let Some(Some(written)) = lp.sent.written_at.get(seq as usize) {
            // Both instants come from one monotonic clock and "written" is taken before the
            // write, so a pair out of order is a measurement fault: counted, never clamped to 0.
            match solved.checked_duration_since(*written) {
                Some(d) => e2e.push(d.as_secs_f64() * 1e6),
                None => non_monotonic += 1,
            }
        }
    }
    let e2e = Percentiles::of(&mut e2e);
    let mean_iterations = lp.iterations.iter().sum::<f64>() / lp.iterations.len().max(1) as f64;
    Ok(Replay {
        solved: e2e.n,
        p50_us: e2e.p50,
        p99_us: e2e.p99,
        mean_iterations,
        lost: lp.stats.missing_samples + lp.stats.rejected(),
        non_monotonic,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_fem::block_model::BlockModel;
    use palpate_fem::export::{ModelBuffers, ProvenanceInfo};
    use palpate_fem::forward::Material;
    use palpate_fem::simulate::{simulate, Request};
    use palpate_runtime::material::LambdaAlpha;

    /// A 1 N press (2 cm radius: the block's top nodes are 1.4 cm apart) on the top of the
    /// generated block, held until the runtime settles, lands where `palpate_fem::simulate` — its
    /// own loop, incremental loading to a 10⁻⁶ tolerance and 20 000 PCG iterations — puts the same
    /// contact: measured 4.7·10⁻⁵ of the largest displacement (1.43 mm) apart; 10⁻³ leaves room
    /// for the two loops' tolerances, and a force 10 % off is 0.10 apart. No tick is no settled
    /// state.
    #[test]
    fn a_held_contact_force_settles_where_the_static_simulation_does() {
        let p = LambdaAlpha::from_young_poisson(10e3, 0.3);
        let block = BlockModel::block(300, p).unwrap();
        let prov = ProvenanceInfo {
            tool: "test".into(),
            source: "generated block".into(),
            notes: String::new(),
        };
        let buffers =
            ModelBuffers::from_mesh(&block.mesh, &block.fixed, &Material::homogeneous(p), &prov)
                .unwrap();
        let path = std::env::temp_dir().join(format!("settle-{}.palp", std::process::id()));
        buffers.write(&path).unwrap();
        let cfg = RuntimeConfig {
            max_iterations: 200,
            ..Default::default()
        };
        let (point, force) = ([0.05f32, 0.05, 0.05], [0.0f32, 0.0, -1.0]);
        let u = settle_contact_force(&path, cfg, point, force, 0.02, 2000)
            .unwrap()
            .expect("settled");
        let never = settle_contact_force(&path, cfg, point, force, 0.02, 0).unwrap();
        std::fs::remove_file(&path).unwrap();
        assert!(never.is_none());
        let reference = simulate(
            buffers.record(),
            &Request {
                contact: Some(([0.05, 0.05, 0.05], [0.0, 0.0, -1.0], 0.02)),
                contact_rule: cfg.contact_rule,
                node_forces: None,
                probe: None,
                warp: cfg.warp,
                increments: 1,
            },
        )
        .unwrap();
        let umax = reference
            .displacements
            .iter()
            .fold(0.0f32, |a, v| a.max(v.abs()));
        let diff = u
            .iter()
            .zip(&reference.displacements)
            .fold(0.0f32, |a, (x, y)| a.max((x - y).abs()));
        assert!(umax > 1e-4, "the press moves the block: {umax} m");
        assert!(diff <= 1e-3 * umax, "{diff} m apart, largest {umax} m");
    }
}
