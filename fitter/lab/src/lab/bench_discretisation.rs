//! `palpate-lab bench discretisation`: the end-loaded box cantilever (L/h = 10, clamped face)
//! solved with linear tetrahedra (P1), quadratic tetrahedra (P2) and average nodal pressure
//! (ANP) on successive refinements at several Poisson ratios: tip deflection against a
//! converged reference (P2 on a finer mesh) and against Timoshenko's beam, the observed
//! convergence rate, and the cost of one solve (median of `--repeats`). The table behind
//! `docs/results/discretisation/README.md`.

use palpate_fem::forward::cantilever::Cantilever;
use palpate_fem::forward::Discretisation;

/// Arguments of `palpate-lab bench discretisation`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Poisson ratios.
    #[arg(long, value_delimiter = ',', default_values_t = [0.45, 0.49, 0.499])]
    pub poisson: Vec<f64>,
    /// Cells along the beam of each mesh (a tenth of it, at least 1, across each side).
    #[arg(long, value_delimiter = ',', default_values_t = [10, 20, 40])]
    pub cells: Vec<usize>,
    /// Cells along the beam of the reference mesh (solved with P2).
    #[arg(long, default_value_t = 60)]
    pub reference_cells: usize,
    /// Timed solves per row (the median is reported).
    #[arg(long, default_value_t = 3)]
    pub repeats: usize,
}

fn beam(cells: usize, poisson: f64) -> Cantilever {
    let across = (cells / 10).max(1);
    Cantilever {
        size: [0.1, 0.01, 0.01],
        cells: [cells, across, across],
        young: 150e3,
        poisson,
        load: 1e-3,
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Runs the benchmark.
pub fn run(args: Args) -> anyhow::Result<()> {
    let designs = [
        Discretisation::Linear,
        Discretisation::Quadratic,
        Discretisation::NodalPressure,
    ];
    let mut rows = Vec::new();
    println!(
        "{:>6} {:>7} {:>6} {:>8} {:>10} {:>12} {:>10} {:>10} {:>6} {:>9} {:>9}",
        "design",
        "nu",
        "cells",
        "dofs",
        "nnz",
        "tip_m",
        "err_ref",
        "err_timo",
        "rate",
        "setup_s",
        "solve_s"
    );
    for &nu in &args.poisson {
        let reference = beam(args.reference_cells, nu).tip_deflection(Discretisation::Quadratic)?;
        let timoshenko = beam(args.reference_cells, nu).timoshenko();
        log::info!(
            "ν = {nu}: reference (P2, {} cells, {} dofs) {:.6e} m, Timoshenko {:.6e} m",
            args.reference_cells,
            reference.dofs,
            reference.deflection,
            timoshenko
        );
        for design in designs {
            let mut previous: Option<f64> = None;
            for &cells in &args.cells {
                let case = beam(cells, nu);
                let mut times = Vec::new();
                let mut last = None;
                for _ in 0..args.repeats.max(1) {
                    let r = case.tip_deflection(design)?;
                    times.push(r.solve_seconds);
                    last = Some(r);
                }
                let r = last.expect("at least one repeat");
                let err_ref = (r.deflection - reference.deflection) / reference.deflection;
                let err_timo = (r.deflection - timoshenko) / timoshenko;
                // Halving h per step: the rate is log₂ of the error ratio.
                let rate = previous.map(|e: f64| (e.abs() / err_ref.abs()).log2());
                previous = Some(err_ref);
                let solve = median(times);
                println!(
                    "{:>6} {:>7} {:>6} {:>8} {:>10} {:>12.5e} {:>9.2}% {:>9.2}% {:>6} {:>9.4} {:>9.4}",
                    design.name(),
                    nu,
                    cells,
                    r.dofs,
                    r.nonzeros,
                    r.deflection,
                    100.0 * err_ref,
                    100.0 * err_timo,
                    rate.map_or("—".to_string(), |v| format!("{v:.2}")),
                    r.setup_seconds,
                    solve
                );
                rows.push(serde_json::json!({
                    "design": design.name(),
                    "poisson": nu,
                    "cells": case.cells,
                    "dofs": r.dofs,
                    "nonzeros": r.nonzeros,
                    "tip_deflection_m": r.deflection,
                    "error_vs_reference": err_ref,
                    "error_vs_timoshenko": err_timo,
                    "observed_rate": rate,
                    "setup_s": r.setup_seconds,
                    "solve_median_s": solve,
                }));
            }
        }
        rows.push(serde_json::json!({
            "design": "reference",
            "poisson": nu,
            "cells": beam(args.reference_cells, nu).cells,
            "dofs": reference.dofs,
            "tip_deflection_m": reference.deflection,
            "timoshenko_m": timoshenko,
        }));
    }
    println!(
        "{}",
        serde_json::json!({
            "schema_version": 1,
            "bench": "discretisation",
            "beam_m": [0.1, 0.01, 0.01],
            "young_pa": 150e3,
            "load_n": 1e-3,
            "repeats": args.repeats,
            "rows": rows,
        })
    );
    Ok(())
}
