//! `palpate bench link`: the probe link over a real pseudo-terminal pair, the firmware library
//! (simulated ADS1015) writing on one end, the host link + runtime on the other.
//!
//! Measures: frames/s sustained (sender unthrottled, receiver decoding); at the probe rate in
//! real time, end-to-end latency from frame written to solved state (p50/p99/max), split into
//! write → arrival and arrival → solved; and host CPU use of the receiving loop.

use super::haptic::{haptic_config, parse_vec3, ModelSource};
use crate::link::faults::{FaultPlan, FaultyWriter};
use crate::link::gate::ForceGate;
use crate::link::haptic::{Contact, HapticLoop};
use crate::link::port::FrameReader;
use crate::link::sender::{run_sender, Pacing, SenderOptions, SenderReport};
use crate::link::stats::{process_cpu_seconds, thread_cpu_seconds, Percentiles};
use anyhow::Context;
use palpate_probe::sim::{default_config, Profile, SimProbe};
use palpate_protocol::link::{ForceSample, Frame, LinkStats, LINK_VERSION};
use palpate_runtime::{Runtime, StorageRequirement};
use serde_json::json;
use serialport::{SerialPort, TTYPort};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Arguments.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Real-time seconds of the latency phase.
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
    /// Probe sample rate, Hz.
    #[arg(long, default_value_t = 1000)]
    pub rate: u16,
    /// Simulated seconds pushed through the throughput phase.
    #[arg(long, default_value_t = 60.0)]
    pub throughput_seconds: f64,
    /// Model file; default a generated 10 × 10 × 5 cm block.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Tetrahedra of the generated block.
    #[arg(long, default_value_t = 900)]
    pub block_tets: usize,
    /// Contact point x,y,z (m).
    #[arg(long, default_value = "0.05,0.05,0.05", value_parser = parse_vec3)]
    pub contact: [f32; 3],
    /// Contact radius (m).
    #[arg(long, default_value_t = 0.015)]
    pub radius: f32,
}

struct Phase {
    sent: SenderReport,
    /// (seq, arrival, solved)
    events: Vec<(u32, Instant, Instant)>,
    stats: LinkStats,
    wall_s: f64,
    rx_cpu_s: Option<f64>,
    proc_cpu_s: Option<f64>,
    iterations: Vec<f64>,
    superseded: u64,
}

fn phase(
    opts: SenderOptions,
    rate: u16,
    mut on_batch: impl FnMut(&[ForceSample]) -> anyhow::Result<u32>,
) -> anyhow::Result<Phase> {
    let (mut master, mut slave) = TTYPort::pair().context("creating a pseudo-terminal pair")?;
    master.set_timeout(Duration::from_millis(500))?;
    slave.set_timeout(Duration::from_millis(20))?;
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
    .map_err(|e| anyhow::anyhow!("sim probe: {e}"))?;
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
            Err(e) => return Err(e.into()),
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
    let (sent, _master) = sender
        .join()
        .map_err(|_| anyhow::anyhow!("sender thread panicked"))?;
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

/// Runs the benchmark.
pub fn run(args: Args) -> anyhow::Result<()> {
    // Throughput: the sender runs free; the pty's back-pressure paces it to what the receiver takes.
    let opts = SenderOptions {
        seconds: args.throughput_seconds,
        pacing: Pacing::AsFastAsPossible,
        version: LINK_VERSION,
        stall: None,
        adc_fault: None,
    };
    let mut decoded = 0u64;
    let tp = phase(opts, args.rate, |b| {
        decoded += b.len() as u64;
        Ok(0)
    })?;
    let (first, last) = (
        tp.events.first().context("no frames delivered")?.1,
        tp.events.last().unwrap().1,
    );
    let fps = decoded as f64 / last.duration_since(first).as_secs_f64();
    let bytes_per_frame = tp.stats.bytes as f64 / tp.stats.frames.max(1) as f64;

    // Latency at the probe rate, runtime in the loop.
    let src = ModelSource::load(args.model.as_deref(), args.block_tets)?;
    let rec = src.record()?;
    let cfg = haptic_config();
    let need = StorageRequirement::for_model(&rec, &cfg);
    let (mut f, mut u) = (vec![0f32; need.f32s], vec![0u32; need.u32s]);
    let rt = Runtime::new(rec, &mut f, &mut u, cfg).context("building the runtime")?;
    let (nodes, tets) = (rt.node_count(), rt.element_count());
    let contact = Contact {
        point: args.contact,
        direction: [0.0, 0.0, -1.0],
        radius: args.radius,
    };
    let mut hl = HapticLoop::new(rt, ForceGate::new(20, 100.0), contact);
    let opts = SenderOptions {
        seconds: args.seconds,
        pacing: Pacing::RealTime,
        version: LINK_VERSION,
        stall: None,
        adc_fault: None,
    };
    let lp = phase(opts, args.rate, |b| {
        Ok(hl
            .on_batch(b)
            .context("runtime tick")?
            .map_or(0, |r| r.1.iterations))
    })?;
    let (mut e2e, mut link, mut solve) = (Vec::new(), Vec::new(), Vec::new());
    for &(seq, arrival, solved) in &lp.events {
        let Some(Some(written)) = lp.sent.written_at.get(seq as usize) else {
            continue;
        };
        e2e.push(solved.duration_since(*written).as_secs_f64() * 1e6);
        link.push(arrival.duration_since(*written).as_secs_f64() * 1e6);
        solve.push(solved.duration_since(arrival).as_secs_f64() * 1e6);
    }
    let (e2e, link, solve) = (
        Percentiles::of(&mut e2e),
        Percentiles::of(&mut link),
        Percentiles::of(&mut solve),
    );
    let mut it = lp.iterations.clone();
    let it = Percentiles::of(&mut it);
    let cpu = lp.rx_cpu_s.map(|c| c / lp.wall_s);
    let pcpu = lp.proc_cpu_s.map(|c| c / lp.wall_s);

    println!("palpate bench link — pty pair, simulated ADS1015 probe (firmware library) → host link → runtime");
    println!(
        "model: {nodes} nodes, {tets} tets; contact {:?}, r = {} m; probe {} Hz",
        args.contact, args.radius, args.rate
    );
    println!("{:<46} {:>12}", "measure", "value");
    println!(
        "{:<46} {:>12.0}",
        "throughput, frames/s (unthrottled, decode only)", fps
    );
    println!("{:<46} {:>12.1}", "bytes per sample frame", bytes_per_frame);
    println!(
        "{:<46} {:>12}",
        "throughput phase missing / rejected",
        format!("{}/{}", tp.stats.missing_samples, tp.stats.rejected())
    );
    println!(
        "{:<46} {:>12}",
        "latency phase solves / superseded samples",
        format!("{}/{}", e2e.n, lp.superseded)
    );
    println!("{:<46} {:>12.1}", "written → solved p50 [µs]", e2e.p50);
    println!("{:<46} {:>12.1}", "written → solved p99 [µs]", e2e.p99);
    println!("{:<46} {:>12.1}", "written → solved max [µs]", e2e.max);
    println!(
        "{:<46} {:>12.1}",
        "  written → arrival p50 / p99 [µs]", link.p50
    );
    println!("{:<46} {:>12.1}", "", link.p99);
    println!(
        "{:<46} {:>12.1}",
        "  arrival → solved p50 / p99 [µs]", solve.p50
    );
    println!("{:<46} {:>12.1}", "", solve.p99);
    println!(
        "{:<46} {:>12.1}",
        "PCG iterations per sample (mean)", it.mean
    );
    println!(
        "{:<46} {:>12.1}",
        "host CPU, receive+solve thread [% of a core]",
        cpu.unwrap_or(f64::NAN) * 100.0
    );
    println!(
        "{:<46} {:>12.1}",
        "process CPU incl. simulated probe [% of a core]",
        pcpu.unwrap_or(f64::NAN) * 100.0
    );
    println!(
        "{:<46} {:>12}",
        "latency phase missing / rejected",
        format!("{}/{}", lp.stats.missing_samples, lp.stats.rejected())
    );
    println!(
        "{}",
        json!({"bench": "link", "rate_hz": args.rate, "nodes": nodes, "tets": tets,
               "throughput_fps": fps, "bytes_per_frame": bytes_per_frame,
               "written_to_solved_us": e2e, "written_to_arrival_us": link, "arrival_to_solved_us": solve,
               "iterations": it, "superseded": lp.superseded, "host_cpu_fraction": cpu, "process_cpu_fraction": pcpu,
               "missing": lp.stats.missing_samples + tp.stats.missing_samples,
               "rejected": lp.stats.rejected() + tp.stats.rejected()})
    );
    Ok(())
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
}

/// A haptic replay for `palpate demo`: the simulated probe (firmware library behind a mock ADC)
/// presses with a scripted profile, its frames cross a real pseudo-terminal pair at 1 kHz in real
/// time, and `runtime` solves a force-driven contact at `point` for every sample.
pub fn replay(
    runtime: Runtime<'_>,
    point: [f32; 3],
    radius: f32,
    seconds: f64,
) -> anyhow::Result<Replay> {
    let contact = Contact {
        point,
        direction: [0.0, 0.0, -1.0],
        radius,
    };
    let mut hl = HapticLoop::new(runtime, ForceGate::new(20, 100.0), contact);
    let opts = SenderOptions {
        seconds,
        pacing: Pacing::RealTime,
        version: LINK_VERSION,
        stall: None,
        adc_fault: None,
    };
    let lp = phase(opts, 1000, |b| {
        Ok(hl
            .on_batch(b)
            .context("runtime tick")?
            .map_or(0, |r| r.1.iterations))
    })?;
    let mut e2e = Vec::new();
    for &(seq, _arrival, solved) in &lp.events {
        if let Some(Some(written)) = lp.sent.written_at.get(seq as usize) {
            e2e.push(solved.duration_since(*written).as_secs_f64() * 1e6);
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
    })
}
