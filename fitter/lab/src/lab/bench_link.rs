//! `palpate-lab bench link`: the probe link over a real pseudo-terminal pair, the firmware library
//! (simulated ADS1015) writing on one end, the host link + runtime on the other.
//!
//! Measures: frames/s sustained (sender unthrottled, receiver decoding); at the probe rate in
//! real time, end-to-end latency from frame written to solved state (p50/p99/max), split into
//! write → arrival and arrival → solved; and host CPU use of the receiving loop.

use anyhow::Context;
use palpate_fem::io::parse_vec3;
use palpate_fem::runtime_storage::Storage;
use palpate_link::gate::ForceGate;
use palpate_link::haptic::{Contact, HapticLoop};
use palpate_link::model_source::{haptic_config, ModelSource};
use palpate_link::replay::phase;
use palpate_link::sender::{Pacing, SenderOptions};
use palpate_link::stats::Percentiles;
use serde_json::json;
use std::path::PathBuf;

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

/// Runs the benchmark.
pub fn run(args: Args) -> anyhow::Result<()> {
    // Throughput: the sender runs free; the pty's back-pressure paces it to what the receiver takes.
    let opts = SenderOptions::clean(args.throughput_seconds, Pacing::AsFastAsPossible);
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
    let mut storage = Storage::for_model(&rec, &cfg);
    let rt = storage.runtime(rec, cfg).context("building the runtime")?;
    let (nodes, tets) = (rt.node_count(), rt.element_count());
    let contact = Contact {
        point: args.contact,
        direction: [0.0, 0.0, -1.0],
        radius: args.radius,
    };
    let mut hl = HapticLoop::new(rt, ForceGate::new(20, 100.0), contact);
    let opts = SenderOptions::clean(args.seconds, Pacing::RealTime);
    let lp = phase(opts, args.rate, |b| {
        Ok(hl
            .on_batch(b)
            .map_err(palpate_link::LinkHostError::Tick)?
            .map_or(0, |r| r.1.iterations))
    })?;
    let (mut e2e, mut link, mut solve) = (Vec::new(), Vec::new(), Vec::new());
    // Pairs out of order on the one monotonic clock are a measurement fault: counted and
    // reported, never clamped to zero (as `duration_since` would).
    let mut non_monotonic = 0usize;
    for &(seq, arrival, solved) in &lp.events {
        let Some(Some(written)) = lp.sent.written_at.get(seq as usize) else {
            continue;
        };
        match (
            solved.checked_duration_since(*written),
            arrival.checked_duration_since(*written),
            solved.checked_duration_since(arrival),
        ) {
            (Some(a), Some(b), Some(c)) => {
                e2e.push(a.as_secs_f64() * 1e6);
                link.push(b.as_secs_f64() * 1e6);
                solve.push(c.as_secs_f64() * 1e6);
            }
            _ => non_monotonic += 1,
        }
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

    println!("palpate-lab bench link — pty pair, simulated ADS1015 probe (firmware library) → host link → runtime");
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
        "{:<46} {:>12}",
        "latency pairs out of clock order (excluded)", non_monotonic
    );
    println!(
        "{}",
        json!({"schema_version": 1, "bench": "link", "rate_hz": args.rate, "nodes": nodes, "tets": tets,
               "throughput_fps": fps, "bytes_per_frame": bytes_per_frame,
               "written_to_solved_us": e2e, "written_to_arrival_us": link, "arrival_to_solved_us": solve,
               "iterations": it, "superseded": lp.superseded, "non_monotonic_pairs": non_monotonic, "host_cpu_fraction": cpu, "process_cpu_fraction": pcpu,
               "missing": lp.stats.missing_samples + tp.stats.missing_samples,
               "rejected": lp.stats.rejected() + tp.stats.rejected()})
    );
    Ok(())
}
