//! `palpate-lab bench fit`: the displacement-based non-linear inhomogeneous fit (one (λ_e, α_e) per
//! element and measurement, eqs. 5.85–5.87) of 4 measurements on a ~2,000-tet block with ~200
//! markers, timed; and the cost of the same fit with finite-difference Jacobians, extrapolated
//! from a timed subset of FD columns (one warm-started forward solve per parameter and
//! measurement, as a finite-difference Gauss–Newton would need every iteration).

use std::time::Instant;

use palpate_fem::forward::SolveOptions;
use palpate_static_fit::synthetic::{synthesise, SyntheticSpec};
use palpate_static_fit::{fit_static, FitOptions, Gammas, Layout, Method, Sets};

/// Arguments of `palpate-lab bench fit`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Approximate number of tetrahedra.
    #[arg(long, default_value_t = 2000)]
    pub tets: usize,
    /// Number of markers.
    #[arg(long, default_value_t = 200)]
    pub markers: usize,
    /// Maximum LM iterations.
    #[arg(long, default_value_t = 10)]
    pub max_iterations: usize,
    /// FD columns timed for the extrapolation.
    #[arg(long, default_value_t = 20)]
    pub fd_columns: usize,
    /// Instead of the benchmark, run the evidence: the §5.1 trade-off (marker error and roughness
    /// vs γ_s for the stiff-inclusion case) with plots and JSON into this folder.
    #[arg(long)]
    pub evidence: Option<std::path::PathBuf>,
    /// Instead of the benchmark, write the synthetic example dataset of the bundled sponge into
    /// this folder (ground truth in `truth.toml`).
    #[arg(long)]
    pub sponge_dataset: Option<std::path::PathBuf>,
    /// Mesh of the sponge dataset.
    #[arg(long, default_value = "models/sponge/sponge.msh")]
    pub sponge_mesh: std::path::PathBuf,
}

/// Runs the benchmark.
pub fn run(args: Args) -> anyhow::Result<()> {
    if let Some(dir) = &args.sponge_dataset {
        palpate_static_fit::evidence::write_sponge_dataset(&args.sponge_mesh, dir)?;
        log::info!("wrote {}", dir.display());
        return Ok(());
    }
    if let Some(dir) = &args.evidence {
        let rows = palpate_static_fit::evidence::tradeoff(dir, [5, 5, 3])?;
        log::info!(
            "wrote {}/tradeoff_error.svg, tradeoff_roughness.svg, tradeoff.json",
            dir.display()
        );
        println!(
            "{}",
            serde_json::json!({"schema_version": 1, "bench": "fit-evidence", "tradeoff": rows})
        );
        return Ok(());
    }
    let size = [0.1, 0.1, 0.05];
    let cells = palpate_fem::mesh::boxmesh::cells_for_target(size, args.tets);
    let mut spec = SyntheticSpec::block(cells);
    spec.markers = args.markers;
    spec.noise = 1e-4;
    spec.inclusion = Some(([0.05, 0.05, 0.03], 0.025, 60_000.0));
    let syn = synthesise(&spec)?;
    let input = &syn.input;
    let tets = input.problem.element_count();
    let mut o = FitOptions::new(
        Method::Displacement,
        Layout::Inhomogeneous,
        Sets::PerMeasurement,
    );
    o.gammas = Some(Gammas::new(3.0, 3.0));
    o.max_iterations = args.max_iterations;
    o.solve = SolveOptions {
        increments: 4,
        tolerance: 1e-9,
        ..Default::default()
    };
    let started = Instant::now();
    let fit = fit_static(input, &o, |_, _| {})?;
    let seconds = started.elapsed().as_secs_f64();
    let iterations = fit.history.len().saturating_sub(1);
    let params = 2 * tets * input.measurements.len();
    let cg: usize = fit.history.iter().map(|h| h.cg_iterations).sum();
    // FD: time `fd_columns` perturbed forward solves (warm-started from the fitted state, as a FD
    // Jacobian would be), per measurement 2·t columns; FD Gauss–Newton needs them each iteration.
    let solve = SolveOptions {
        warp: true,
        ..o.solve
    };
    let m0 = &input.measurements[0];
    let base = &fit.params[0];
    let t0 = Instant::now();
    let k = args.fd_columns.max(1);
    for j in 0..k {
        let mut m = base.clone();
        let e = j % tets;
        m.lambda[e] *= 1.0 + 1e-6;
        input
            .problem
            .solve_forces(&m, &m0.force, Some(&fit.deformed[0]), &solve)?;
    }
    let per_column = t0.elapsed().as_secs_f64() / k as f64;
    let fd_seconds = per_column * params as f64 * iterations.max(1) as f64;
    println!("| quantity | value |\n|---|---|");
    println!(
        "| tets | {tets} |\n| nodes | {} |\n| measurements | {} |\n| markers | {} |",
        input.problem.node_count(),
        input.measurements.len(),
        input.markers.len()
    );
    println!("| parameters | {params} |\n| LM iterations | {iterations} |\n| CG iterations (total) | {cg} |");
    println!(
        "| seconds (adjoint/direct) | {seconds:.3} |\n| RMS marker error (mm) | {:.4} |",
        fit.rms() * 1e3
    );
    println!("| FD column (s, timed over {k}) | {per_column:.4e} |\n| FD fit (s, extrapolated: params × iterations × column) | {fd_seconds:.1} |");
    println!("| speed-up | {:.0}× |", fd_seconds / seconds);
    println!(
        "{}",
        serde_json::json!({
            "schema_version": 1,
            "bench": "fit",
            "tets": tets,
            "params": params,
            "markers": input.markers.len(),
            "measurements": input.measurements.len(),
            "seconds": seconds,
            "iterations": iterations,
            "cg_iterations": cg,
            "rms_m": fit.rms(),
            "fd_seconds": fd_seconds,
            "fd_method": format!("extrapolated from {k} timed warm-started forward solves × {params} params × {iterations} iterations"),
            "speedup": fd_seconds / seconds,
        })
    );
    Ok(())
}
