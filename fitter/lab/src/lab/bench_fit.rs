//! `palpate-lab bench fit`: the displacement-based non-linear inhomogeneous fit (one (λ_e, α_e) per
//! element and measurement, eqs. 5.85–5.87) of 4 measurements on a ~2,000-tet block with ~200
//! markers, timed; and the cost of the same fit with finite-difference Jacobians — **measured** on
//! a small block (`--fd-tets`, 150 by default: every one of its 2·t·4 columns solved, so the FD
//! Jacobian of an iteration is timed whole, in the same run as that block's analytic fit), and on
//! the large block extrapolated from a timed subset of columns (its 15,552 columns would take
//! about half an hour per iteration). An FD column is one forward solve per parameter and
//! measurement, warm-started from the fitted state and from its factorisation, as a
//! finite-difference Gauss–Newton would need every iteration.

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
    /// Approximate tets of the small block whose FD Jacobian is measured whole (0: skip).
    #[arg(long, default_value_t = 150)]
    pub fd_tets: usize,
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
    let small = (args.fd_tets > 0)
        .then(|| measured_fd(args.fd_tets, args.markers.min(60), args.max_iterations))
        .transpose()?;
    let (syn, o, fit, seconds) = analytic_fit(args.tets, args.markers, args.max_iterations)?;
    let input = &syn.input;
    let tets = input.problem.element_count();
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
    println!("| speed-up (extrapolated) | {:.0}× |", fd_seconds / seconds);
    if let Some(m) = &small {
        println!(
            "| small block, measured whole: tets, parameters | {}, {} |\n| small block: analytic fit (s), iterations | {:.3}, {} |\n| small block: one FD Jacobian, all columns (s, measured) | {:.3} |\n| small block: FD / analytic per iteration (measured, same run) | {:.0}× |",
            m.tets, m.params, m.analytic_seconds, m.iterations, m.fd_jacobian_seconds, m.ratio_per_iteration()
        );
    }
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
            "fd_measured_small": small.as_ref().map(|m| serde_json::json!({
                "tets": m.tets,
                "params": m.params,
                "analytic_seconds": m.analytic_seconds,
                "iterations": m.iterations,
                "fd_jacobian_seconds": m.fd_jacobian_seconds,
                "fd_over_analytic_per_iteration": m.ratio_per_iteration(),
            })),
        })
    );
    Ok(())
}

/// The benchmark's synthetic block of about `tets` tets (a stiff inclusion, 4 measurements) and
/// its displacement-based inhomogeneous fit, timed.
fn analytic_fit(
    tets: usize,
    markers: usize,
    max_iterations: usize,
) -> anyhow::Result<(
    palpate_static_fit::synthetic::Synthetic,
    FitOptions,
    palpate_static_fit::FitResult,
    f64,
)> {
    let size = [0.1, 0.1, 0.05];
    let cells = palpate_fem::mesh::boxmesh::cells_for_target(size, tets);
    let mut spec = SyntheticSpec::block(cells);
    spec.markers = markers;
    spec.noise = 1e-4;
    spec.inclusion = Some(([0.05, 0.05, 0.03], 0.025, 60_000.0));
    let syn = synthesise(&spec)?;
    let mut o = FitOptions::new(
        Method::Displacement,
        Layout::Inhomogeneous,
        Sets::PerMeasurement,
    );
    o.gammas = Some(Gammas::new(3.0, 3.0));
    o.max_iterations = max_iterations;
    o.solve = SolveOptions {
        increments: 4,
        tolerance: 1e-9,
        ..Default::default()
    };
    let started = Instant::now();
    let fit = fit_static(&syn.input, &o, |_, _| {})?;
    Ok((syn, o, fit, started.elapsed().as_secs_f64()))
}

/// The small block's figures: its analytic fit and one whole FD Jacobian, timed in one run.
struct MeasuredFd {
    tets: usize,
    params: usize,
    analytic_seconds: f64,
    iterations: usize,
    fd_jacobian_seconds: f64,
}

impl MeasuredFd {
    /// One FD Jacobian against one analytic iteration (the fit's time over its iterations).
    fn ratio_per_iteration(&self) -> f64 {
        self.fd_jacobian_seconds / (self.analytic_seconds / self.iterations.max(1) as f64)
    }
}

/// Fits the small block analytically, then solves every FD column of its Jacobian at the fitted
/// state: per measurement and element, λ_e and α_e perturbed by 1e-6 relative, each a forward
/// solve warm-started from the fitted deformation and its factorisation (the cheapest FD column
/// this solver offers).
fn measured_fd(tets: usize, markers: usize, max_iterations: usize) -> anyhow::Result<MeasuredFd> {
    let (syn, o, fit, analytic_seconds) = analytic_fit(tets, markers, max_iterations)?;
    let input = &syn.input;
    let ne = input.problem.element_count();
    let solve = SolveOptions {
        warp: true,
        reuse_factor: true,
        ..o.solve
    };
    let t0 = Instant::now();
    for (k, m) in input.measurements.iter().enumerate() {
        let base = &fit.params[k.min(fit.params.len() - 1)];
        let start = input
            .problem
            .solve_forces(base, &m.force, Some(&fit.deformed[k]), &solve)?;
        for e in 0..2 * ne {
            let mut p = base.clone();
            if e < ne {
                p.lambda[e] *= 1.0 + 1e-6;
            } else {
                p.alpha[e - ne] *= 1.0 + 1e-6;
            }
            input.problem.solve_forces_with(
                &p,
                &m.force,
                Some(&start.solution.x),
                &solve,
                Some(&start.factor),
            )?;
        }
    }
    Ok(MeasuredFd {
        tets: ne,
        params: 2 * ne * input.measurements.len(),
        analytic_seconds,
        iterations: fit.history.len().saturating_sub(1),
        fd_jacobian_seconds: t0.elapsed().as_secs_f64(),
    })
}
