//! `palpate-lab bench quadratic-motion`: what one simulation on quadratic tetrahedra costs
//! (`palpate_motion::quadratic_motion`, the forward model of the motion's mesh-convergence
//! refit, which runs it once per parameter and iteration): wall and CPU time of whole runs, one
//! after the other on one thread, with the run's Newton iterations and factorisations.

use super::bench_motion_step::{quantile, thread_cpu};
use palpate_motion::fitted::FittedModel;
use palpate_motion::quadratic_motion::QuadraticMotion;
use std::time::Instant;

/// Options of `bench quadratic-motion`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A motion dataset folder (e.g. the beam's gravity run imported as
    /// `docs/results/beam/time-convergence.sh` imports it), simulated as imported.
    pub dataset: std::path::PathBuf,
    /// The material to simulate: a fitted model's JSON on the dataset's mesh (`palpate
    /// fit-motion`'s, or a diagnosis' `fit.json`).
    #[arg(long, default_value = "models/silicone-beam/fit.json")]
    pub material: std::path::PathBuf,
    /// Timed runs (the first, which also warms the caches, is timed too and reported apart).
    #[arg(long, default_value_t = 5)]
    pub rounds: usize,
}

/// Runs the benchmark and prints its JSON.
pub fn run(args: Args) -> anyhow::Result<()> {
    anyhow::ensure!(args.rounds >= 1, "--rounds: at least 1, found 0");
    let ds = palpate_motion::dataset::load(&args.dataset)?;
    let fitted: FittedModel = serde_json::from_str(&std::fs::read_to_string(&args.material)?)
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.material.display()))?;
    let mat = fitted
        .material()
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.material.display()))?;
    let model = &ds.model;
    anyhow::ensure!(
        mat.values[0].len() == model.tets.len(),
        "{}: {} elements, the dataset's mesh has {}",
        args.material.display(),
        mat.values[0].len(),
        model.tets.len()
    );
    let load_start = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    let lift_start = Instant::now();
    let q = QuadraticMotion::new(model)?;
    let lift_s = lift_start.elapsed().as_secs_f64();
    let (mut wall, mut cpu) = (Vec::new(), Vec::new());
    let mut stats = None;
    for round in 0..=args.rounds {
        let (t0, c0) = (Instant::now(), thread_cpu());
        let r = q.simulate(&mat)?;
        let (w, c) = (t0.elapsed().as_secs_f64(), thread_cpu() - c0);
        eprintln!("round {round}: {w:.3} s wall, {c:.3} s CPU");
        if round == 0 {
            stats = Some((w, c, r.newton_iterations, r.factorisations, r.max_residual));
        } else {
            wall.push(w);
            cpu.push(c);
        }
    }
    let (first_wall, first_cpu, newton, factorisations, max_residual) = stats.expect("round 0 ran");
    let load_end = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    let json = serde_json::json!({
        "bench": "quadratic-motion",
        "dataset": args.dataset.display().to_string(),
        "material": args.material.display().to_string(),
        "tets": model.tets.len(),
        "free_dofs": q.free_dofs(),
        "steps": model.steps,
        "scheme": model.scheme.name(),
        "newton_iterations": newton,
        "factorisations": factorisations,
        "max_residual_n": max_residual,
        "lift_s": lift_s,
        "first_run": { "wall_s": first_wall, "cpu_s": first_cpu },
        "rounds": args.rounds,
        "wall_s": { "median": quantile(&wall, 0.5), "p99": quantile(&wall, 0.99), "min": quantile(&wall, 0.0) },
        "cpu_s": { "median": quantile(&cpu, 0.5), "p99": quantile(&cpu, 0.99), "min": quantile(&cpu, 0.0) },
        "loadavg_at_start": load_start.trim(),
        "loadavg_at_end": load_end.trim(),
    });
    println!("{}", serde_json::to_string_pretty(&json)?);
    Ok(())
}
