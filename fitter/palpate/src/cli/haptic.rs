//! `palpate haptic --model <m> --port <dev> --contact x,y,z`: drive the runtime with the live force
//! stream — each sample a force-driven contact at the given point, one solve per sample — and
//! report per-sample latency from frame arrival to solved state.

use palpate_fem::io::parse_vec3;
use palpate_link::haptic::Contact;
use palpate_link::model_source::{haptic_config, ModelSource};
use palpate_link::session::{run_session, SessionOptions};
use serde_json::json;
use std::path::PathBuf;

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
    let r = run_session(
        rec,
        haptic_config(),
        &SessionOptions {
            port: args.port.clone(),
            baud: args.baud,
            seconds: args.seconds,
            contact: Contact {
                point: args.contact,
                direction: args.direction,
                radius: args.radius,
            },
            hold: args.hold,
        },
    )?;
    let (p, it, st) = (r.latency_us, r.iterations, r.stats);
    println!(
        "haptic loop: {} nodes, {} tets, contact {:?} r = {} m",
        r.nodes, r.tets, args.contact, args.radius
    );
    println!(
        "{:<40} {:>12}",
        "solves / superseded samples",
        format!("{}/{}", p.n, r.superseded)
    );
    println!(
        "{:<40} {:>12}",
        "fed / held / released",
        format!("{}/{}/{}", r.fed, r.held, r.released)
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
    println!("{:<40} {:>12}", "unconverged ticks", r.unconverged);
    println!(
        "{:<40} {:>12.1}",
        "host CPU (loop thread) [%]",
        r.cpu_fraction.unwrap_or(f64::NAN) * 100.0
    );
    println!(
        "{}",
        json!({"schema_version": 1, "kind": "haptic", "samples": p.n, "fed": r.fed, "held": r.held, "released": r.released, "missing": st.missing_samples,
               "rejected": st.rejected(), "superseded": r.superseded, "latency_us": p, "iterations": it, "worst_rel_residual": r.worst_rel_residual,
               "unconverged": r.unconverged, "cpu_fraction": r.cpu_fraction})
    );
    Ok(())
}
