//! `palpate haptic --model <m> --port <dev> --contact x,y,z`: drive the runtime with the live force
//! stream — each sample a force-driven contact at the given point, one solve per sample — and
//! report per-sample latency from frame arrival to solved state.

use anyhow::Context;
use palpate_fem::io::parse_vec3;
use palpate_fem::runtime_storage::Storage;
use palpate_link::gate::ForceGate;
use palpate_link::haptic::{Contact, HapticLoop};
use palpate_link::model_source::{haptic_config, ModelSource};
use palpate_link::port::{open, FrameReader};
use palpate_link::stats::{thread_cpu_seconds, Percentiles};
use palpate_link::{GateDecision, LinkHostError};
use palpate_protocol::link::Frame;
use palpate_runtime::SolveStatus;
use serde_json::json;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Arguments.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Model file: a runtime model (`.palp`), or a `fit.json` of `fit-motion` or `diagnose`
    /// (exported for the runtime on the mesh of a run it was fitted on); told apart by content.
    /// Without it: a generated 10 × 10 × 5 cm block, E = 10 kPa, ν = 0.3.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Tetrahedra of the generated block (when no --model).
    #[arg(long, default_value_t = 900)]
    pub block_tets: usize,
    /// Serial device of the probe.
    #[arg(long)]
    pub port: String,
    /// Contact point x,y,z in model coordinates (m).
    #[arg(long, default_value = "0.05,0.05,0.05", value_parser = parse_vec3)]
    pub contact: [f32; 3],
    /// Direction of the pressing force x,y,z.
    #[arg(long, default_value = "0,0,-1", value_parser = parse_vec3)]
    pub direction: [f32; 3],
    /// Radius over which the force spreads (m).
    #[arg(long, default_value_t = 0.015)]
    pub radius: f32,
    /// Seconds to run.
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
    /// Untrusted samples in a row that hold the last force before releasing.
    #[arg(long, default_value_t = 20)]
    pub hold: u32,
    /// Baud rate.
    #[arg(long, default_value_t = 1_000_000)]
    pub baud: u32,
}

/// The largest generated block: its model and runtime take about 1 KB per tetrahedron (peak
/// resident memory of this command measured at 20 000 and 80 000 tets), so a million tets is
/// about a gigabyte, and far more than one haptic tick can solve.
pub const MAX_BLOCK_TETS: usize = 1_000_000;

/// Checks the flags before any model is built or port opened.
fn check_args(args: &Args) -> anyhow::Result<()> {
    if args.model.is_none() && !(1..=MAX_BLOCK_TETS).contains(&args.block_tets) {
        anyhow::bail!(
            "--block-tets {}: expected 1 to {MAX_BLOCK_TETS} (the generated block takes about \
             1 KB of memory per tetrahedron)",
            args.block_tets
        );
    }
    if !(args.radius.is_finite() && args.radius > 0.0 && args.radius <= 1.0) {
        anyhow::bail!(
            "--radius {}: expected a contact radius in (0, 1] m (a fingertip is about 0.01 m)",
            args.radius
        );
    }
    if !(args.seconds.is_finite() && args.seconds > 0.0) {
        anyhow::bail!(
            "--seconds {}: expected a finite duration > 0 s",
            args.seconds
        );
    }
    if args.contact.iter().any(|v| !v.is_finite()) {
        anyhow::bail!(
            "--contact {:?}: expected three finite numbers (m)",
            args.contact
        );
    }
    let d = args.direction;
    if !(d.iter().all(|v| v.is_finite()) && d.iter().any(|v| *v != 0.0)) {
        anyhow::bail!("--direction {d:?}: expected a non-zero finite direction");
    }
    Ok(())
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    check_args(&args)?;
    let src = match &args.model {
        Some(m) => {
            let (path, bytes) = super::model_file::ModelFile::read(m, "haptic --model")?
                .into_runtime_bytes("haptic --model")?;
            ModelSource::File(path, bytes)
        }
        None => ModelSource::load(None, args.block_tets)?,
    };
    let rec = src.record()?;
    let cfg = haptic_config();
    let mut storage = Storage::for_model(&rec, &cfg);
    let rt = storage.runtime(rec, cfg).context("building the runtime")?;
    let contact = Contact {
        point: args.contact,
        direction: args.direction,
        radius: args.radius,
    };
    let mut hl = HapticLoop::new(rt, ForceGate::new(args.hold, 100.0), contact);
    let mut reader = FrameReader::new(open(&args.port, args.baud, Duration::from_millis(50))?);
    let (mut lat, mut iters) = (Vec::new(), Vec::new());
    let (mut fed, mut held, mut released, mut unconverged) = (0u64, 0u64, 0u64, 0u64);
    let mut worst_res = 0.0f32;
    let mut err = None;
    let t0 = Instant::now();
    let cpu0 = thread_cpu_seconds();
    let mut batch = Vec::new();
    while t0.elapsed().as_secs_f64() < args.seconds && err.is_none() {
        batch.clear();
        let mut arrival = None;
        reader
            .poll(|fr, at| {
                if let Frame::Sample(s) = fr {
                    batch.push(s);
                    arrival = Some(at);
                }
            })
            .map_err(|source| LinkHostError::Io {
                what: "reading",
                path: args.port.clone(),
                source,
            })?;
        if let Some(at) = arrival {
            // Several samples in one read (the host fell behind): all pass the gate, the newest
            // drives the solve.
            match hl.on_batch(&batch) {
                Ok(Some((d, rep))) => {
                    lat.push(at.elapsed().as_secs_f64() * 1e6);
                    iters.push(f64::from(rep.iterations));
                    worst_res = worst_res.max(rep.rel_residual);
                    unconverged += u64::from(rep.status != SolveStatus::Converged);
                    match d {
                        GateDecision::Feed(_) => fed += 1,
                        GateDecision::Hold(_) => held += 1,
                        GateDecision::Release => released += 1,
                    }
                }
                Ok(None) => {}
                Err(e) => err = Some(e),
            }
        }
        if lat.is_empty() && t0.elapsed() > Duration::from_secs(2) {
            if let Some(e) = reader.version_mismatch(&args.port) {
                return Err(e.into());
            }
        }
    }
    if let Some(e) = err {
        anyhow::bail!("runtime refused the contact at {:?}: {e}", args.contact);
    }
    let wall = t0.elapsed().as_secs_f64();
    let cpu = cpu0.zip(thread_cpu_seconds()).map(|(a, b)| (b - a) / wall);
    let p = Percentiles::of(&mut lat);
    let it = Percentiles::of(&mut iters);
    let st = *reader.stats();
    println!(
        "haptic loop: {} nodes, {} tets, contact {:?} r = {} m",
        hl.runtime.node_count(),
        hl.runtime.element_count(),
        args.contact,
        args.radius
    );
    println!(
        "{:<40} {:>12}",
        "solves / superseded samples",
        format!("{}/{}", p.n, hl.superseded)
    );
    println!(
        "{:<40} {:>12}",
        "fed / held / released",
        format!("{fed}/{held}/{released}")
    );
    println!(
        "{:<40} {:>12}",
        "missing / rejected frames",
        format!("{}/{}", st.missing_samples, st.rejected())
    );
    println!("{:<40} {:>12.1}", "arrival → solved p50 [µs]", p.p50);
    println!("{:<40} {:>12.1}", "arrival → solved p99 [µs]", p.p99);
    println!("{:<40} {:>12.1}", "arrival → solved max [µs]", p.max);
    println!("{:<40} {:>12.1}", "PCG iterations mean / p99", it.mean);
    println!("{:<40} {:>12}", "unconverged ticks", unconverged);
    println!(
        "{:<40} {:>12.1}",
        "host CPU (loop thread) [%]",
        cpu.unwrap_or(f64::NAN) * 100.0
    );
    println!(
        "{}",
        json!({"schema_version": 1, "kind": "haptic", "samples": p.n, "fed": fed, "held": held, "released": released, "missing": st.missing_samples,
               "rejected": st.rejected(), "superseded": hl.superseded, "latency_us": p, "iterations": it, "worst_rel_residual": worst_res,
               "unconverged": unconverged, "cpu_fraction": cpu})
    );
    Ok(())
}
