//! `palpate-lab model-form`: is a static dataset's residual the warped linear model's *form*?
//!
//! The static diagnosis fits the thesis' warped linear FEM (seed 000) plus candidate effects. A
//! soft solid is hyperelastic: where a residual is left that no candidate explains (an
//! effect-free draw of the independent generator judged "NOT clean", or one that adopted a
//! preload no one applied), the first question is whether the material law itself is the
//! missing effect. This command answers it on one dataset: it fits the warped linear model's
//! (E, ν) to every measurement, then solves the same loads with the Neo-Hookean quasi-static
//! solver (`palpate_motion::statics`, load stepping and Newton on the energy) on the same mesh
//! and markers and searches (ln E, ν) for that model's smallest marker RMS. If the Neo-Hookean
//! fit is not clearly below the warped linear one, a material-law candidate cannot explain the
//! residual and the search for the effect goes elsewhere.

use anyhow::Context as _;
use palpate_diagnose::fit::{fit, initial_theta};
use palpate_diagnose::model::{poisson_of, Context, Model};
use palpate_fem::dataset::StaticDataset;
use palpate_motion::hyperelastic::HyperParams;
use palpate_motion::statics::{solve_static, StaticProblem};
use rayon::prelude::*;
use serde::Serialize;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `palpate-lab model-form`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A static dataset folder (`dataset.toml`, mesh, markers, measurements).
    pub dataset: PathBuf,
    /// Solve on the dataset mesh refined once (every tetrahedron into eight), as the diagnosis's
    /// approximation-error correction does: the dataset mesh's own discretisation error can
    /// hide a material-law difference.
    #[arg(long)]
    pub refine: bool,
    /// Load increments of each Neo-Hookean solve.
    #[arg(long, default_value_t = 4)]
    pub load_steps: usize,
}

/// The figures printed as the last line.
#[derive(Debug, Serialize)]
struct Summary {
    dataset: String,
    tets: usize,
    residual_entries: usize,
    sigma_m: f64,
    warped_linear: Law,
    neo_hookean: Law,
    neo_hookean_solves: usize,
    seconds: f64,
}

#[derive(Debug, Serialize)]
struct Law {
    young_pa: f64,
    poisson: f64,
    rms_marker_m: f64,
}

/// Runs the comparison.
pub fn run(a: Args) -> anyhow::Result<()> {
    let started = Instant::now();
    let ds = StaticDataset::read(&a.dataset)
        .with_context(|| format!("reading the dataset {}", a.dataset.display()))?;
    let ds = if a.refine {
        palpate_fem::dataset::refine::refine_dataset(&ds)
            .map_err(|e| anyhow::anyhow!("refining the dataset mesh: {e}"))?
    } else {
        ds
    };
    let ctx = Context::new(&ds, [3, 3, 2])?;
    let all: Vec<usize> = (0..ctx.meas.len()).collect();
    let model = Model::base();
    let (theta0, start) = initial_theta(&ctx, &all)?;
    let linear = fit(&ctx, &model, theta0, &all, Some(&start.x), 40)?;
    let theta = linear.theta.clone();
    // RMS of the 3-D marker error over every observed (measurement, marker) entry.
    let rms = |markers: &[Vec<[f64; 3]>]| -> f64 {
        let r = model.residuals(&ctx, &all, markers);
        ctx.sigma * (r.iter().map(|v| v * v).sum::<f64>() / (r.len() as f64 / 3.0)).sqrt()
    };
    let rms_linear = rms(&linear.sim.markers);
    eprintln!(
        "{} tets; warped linear fit: E = {:.1} Pa, ν = {:.3}, RMS {:.2} µm",
        ds.mesh.tets.len(),
        theta[0].exp(),
        poisson_of(theta[1]),
        rms_linear * 1e6
    );
    // The same nodal loads as the warped model's (the declared probe patch, lumped).
    let loads: Vec<Vec<(usize, [f64; 3])>> = all
        .iter()
        .map(|&i| {
            let f = model.model_force(&ctx, &theta, i);
            let v = model.load_vector(&ctx, &theta, i, f)?;
            Ok((0..v.len() / 3)
                .filter(|&n| v[3 * n..3 * n + 3].iter().any(|x| *x != 0.0))
                .map(|n| (n, [v[3 * n], v[3 * n + 1], v[3 * n + 2]]))
                .collect())
        })
        .collect::<Result<_, palpate_diagnose::Error>>()?;
    let mut solves = 0usize;
    let mut neo_hookean = |log_e: f64, nu: f64| -> anyhow::Result<f64> {
        let e = log_e.exp();
        let material = HyperParams {
            lambda: e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
            mu: e / (2.0 * (1.0 + nu)),
            stiffening: 0.0,
        };
        let xs: Vec<Vec<[f64; 3]>> = loads
            .par_iter()
            .map(|forces| {
                let p = StaticProblem {
                    mesh: &ds.mesh,
                    material: vec![material],
                    density: 0.0,
                    gravity: [0.0; 3],
                    fixed: ds.fixed_nodes.clone(),
                    fixed_displacement: Vec::new(),
                    forces: forces.clone(),
                    load_steps: a.load_steps.max(1),
                    tol: 1e-9,
                    max_iter: 50,
                };
                solve_static(&p).map(|s| s.positions)
            })
            .collect::<Result<_, _>>()?;
        solves += xs.len();
        Ok(rms(&model.markers_from(&ctx, &theta, &all, &xs, None, None)))
    };
    // Coordinate search on (ln E, ν) from the linear fit, halving the steps: the objective is
    // smooth and its minimum near the linear fit's (the laws agree at small strain).
    let (mut best_le, mut best_nu) = (theta[0], poisson_of(theta[1]));
    let mut best = neo_hookean(best_le, best_nu)?;
    let (mut step_e, mut step_nu) = (0.08f64, 0.04f64);
    while step_e > 0.004 {
        let mut moved = false;
        for (de, dn) in [
            (step_e, 0.0),
            (-step_e, 0.0),
            (0.0, step_nu),
            (0.0, -step_nu),
        ] {
            let nu = (best_nu + dn).clamp(0.0, 0.499);
            let v = neo_hookean(best_le + de, nu)?;
            if v < best {
                (best, best_le, best_nu, moved) = (v, best_le + de, nu, true);
            }
        }
        if !moved {
            step_e *= 0.5;
            step_nu *= 0.5;
        }
    }
    println!("| law | E (Pa) | ν | marker RMS (µm) |");
    println!("|---|---|---|---|");
    println!(
        "| warped linear (seed 000) | {:.1} | {:.3} | {:.2} |",
        theta[0].exp(),
        poisson_of(theta[1]),
        rms_linear * 1e6
    );
    println!(
        "| Neo-Hookean (its own best fit) | {:.1} | {:.3} | {:.2} |",
        best_le.exp(),
        best_nu,
        best * 1e6
    );
    let summary = Summary {
        dataset: a.dataset.display().to_string(),
        tets: ds.mesh.tets.len(),
        residual_entries: model.residuals(&ctx, &all, &linear.sim.markers).len(),
        sigma_m: ctx.sigma,
        warped_linear: Law {
            young_pa: theta[0].exp(),
            poisson: poisson_of(theta[1]),
            rms_marker_m: rms_linear,
        },
        neo_hookean: Law {
            young_pa: best_le.exp(),
            poisson: best_nu,
            rms_marker_m: best,
        },
        neo_hookean_solves: solves,
        seconds: started.elapsed().as_secs_f64(),
    };
    println!("{}", serde_json::to_string(&summary)?);
    Ok(())
}
