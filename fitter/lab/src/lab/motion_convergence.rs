//! `palpate-lab motion-convergence`: the motion's material — modulus and viscosity — fitted on
//! linear and on quadratic tetrahedra, on each of several meshes of one object, by one method
//! (Levenberg–Marquardt on forward differences, `palpate_motion::difference_fit`) and one
//! objective: how converged a fitted material is (docs/results/beam/convergence.md).
//!
//! Each mesh is a folder holding the same runs imported on it (`palpate import c3d … --mesh`).
//! The runs named by `--fit` are fitted together; those named by `--held-out` are then
//! predicted at the fitted material. The linear and quadratic fits on the first mesh start at
//! `--initial` and `--initial-quadratic`; on each later mesh a design starts where it ended on
//! the mesh before.

use anyhow::Context as _;
use palpate_motion::dataset::MotionDataset;
use palpate_motion::difference_fit::{
    fit_by_differences, marker_residual, marker_rms, DifferenceRun, Forward, GlobalParam,
};
use palpate_motion::fitted::set_hanging_inertia;
use palpate_motion::model::{Material, ParamKind};
use palpate_motion::quadratic_motion::QuadraticMotion;
use palpate_motion::refine::marker_paths;
use palpate_motion::rest_fit::StandOff;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `palpate-lab motion-convergence`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Folders, one per mesh (coarsest first), each holding the runs imported on that mesh.
    #[arg(long, value_delimiter = ',', required = true)]
    pub meshes: Vec<PathBuf>,
    /// The runs fitted together (folder names inside each mesh's folder).
    #[arg(long, value_delimiter = ',', required = true)]
    pub fit: Vec<String>,
    /// Runs predicted at the fitted material.
    #[arg(long, value_delimiter = ',')]
    pub held_out: Vec<String>,
    /// Designs: P1 (linear tetrahedra), P2 (quadratic).
    #[arg(long, value_delimiter = ',', default_values_t = ["P1".to_string(), "P2".to_string()])]
    pub designs: Vec<String>,
    /// The fitted parameters: mu (λ follows at --poisson, or is fitted as lambda), viscosity,
    /// h, stiffening.
    #[arg(long, value_delimiter = ',', default_values_t = ["mu".to_string(), "viscosity".to_string(), "h".to_string()])]
    pub params: Vec<String>,
    /// Poisson's ratio held fixed (none: lambda among --params).
    #[arg(long)]
    pub poisson: Option<f64>,
    /// The linear fit's start on the first mesh: name=value pairs of every parameter.
    #[arg(long, value_delimiter = ',', required = true)]
    pub initial: Vec<String>,
    /// The quadratic fit's start on the first mesh (default: --initial).
    #[arg(long, value_delimiter = ',')]
    pub initial_quadratic: Vec<String>,
    /// The hanging weights carry their mass (the diagnosis' hanging-inertia effect).
    #[arg(long)]
    pub hanging_inertia: bool,
    /// How the quadratic model's markers off the body follow it: extrapolated (the element's
    /// field) or rigid-post (`palpate_motion::rest_fit::StandOff`); linear elements extrapolate.
    #[arg(long, default_value = "extrapolated", value_parser = ["extrapolated", "rigid-post"])]
    pub stand_off: String,
    /// Levenberg–Marquardt iterations per fit.
    #[arg(long, default_value_t = 12)]
    pub max_iterations: usize,
}

/// One fit of one design on one mesh.
#[derive(Debug, Serialize)]
struct Row {
    mesh: String,
    design: String,
    tets: usize,
    free_dofs: usize,
    values: Vec<(String, f64, f64)>,
    young_modulus_pa: f64,
    poisson: f64,
    fitted_rms_mm: Vec<(String, f64)>,
    held_out_rms_mm: Vec<(String, f64)>,
    simulations: usize,
    iterations: usize,
    converged: bool,
    seconds: f64,
}

fn kind_of(name: &str) -> anyhow::Result<GlobalParam> {
    let (kind, log) = match name {
        "mu" => (ParamKind::Mu, true),
        "lambda" => (ParamKind::Lambda, true),
        "viscosity" => (ParamKind::Nu, true),
        "h" => (ParamKind::PowerH, false),
        "stiffening" => (ParamKind::Stiffening, true),
        other => {
            anyhow::bail!(
                "--params: unknown parameter {other:?} (mu, lambda, viscosity, h, stiffening)"
            )
        }
    };
    Ok(GlobalParam { kind, log })
}

fn starts(pairs: &[String], names: &[String]) -> anyhow::Result<Vec<f64>> {
    names
        .iter()
        .map(|n| {
            let v = pairs
                .iter()
                .find_map(|p| p.strip_prefix(&format!("{n}=")))
                .with_context(|| format!("no start for {n} (give {n}=value)"))?;
            v.parse::<f64>()
                .with_context(|| format!("the start of {n}: {v:?} is not a number"))
        })
        .collect()
}

fn load(mesh: &Path, run: &str, inertia: bool) -> anyhow::Result<MotionDataset> {
    let dir = mesh.join(run);
    let mut ds = palpate_motion::dataset::load(&dir)
        .with_context(|| format!("reading {}", dir.display()))?;
    set_hanging_inertia(&mut ds.model, inertia);
    Ok(ds)
}

/// The material every fit starts from: the dataset's density, no creep, Newtonian.
fn base(ds: &MotionDataset) -> Material {
    let n = ds.model.tets.len();
    Material::uniform(n, 0.0, 0.0, 0.0, 1.0, ds.config.density.unwrap_or(1000.0))
}

/// Runs the study.
pub fn run(a: Args) -> anyhow::Result<()> {
    let params: Vec<GlobalParam> = a
        .params
        .iter()
        .map(|n| kind_of(n))
        .collect::<Result<_, _>>()?;
    if a.poisson.is_none() && !params.iter().any(|p| p.kind == ParamKind::Lambda) {
        anyhow::bail!("give --poisson, or fit lambda (--params lambda,mu,…)");
    }
    let mut start_linear = starts(&a.initial, &a.params)?;
    let mut start_quadratic = if a.initial_quadratic.is_empty() {
        start_linear.clone()
    } else {
        starts(&a.initial_quadratic, &a.params)?
    };
    let stand_off = if a.stand_off == "rigid-post" {
        StandOff::RigidPost
    } else {
        StandOff::Extrapolated
    };
    let mut rows = Vec::new();
    println!(
        "| mesh | design | tets | free dofs | {} | E (kPa) | ν | fitted RMS (mm) | held-out RMS (mm) | simulations | time (s) |",
        a.params.join(" | ")
    );
    println!("|{}", "---|".repeat(10 + a.params.len()));
    for mesh in &a.meshes {
        let fitted: Vec<MotionDataset> = a
            .fit
            .iter()
            .map(|r| load(mesh, r, a.hanging_inertia))
            .collect::<Result<_, _>>()?;
        let held: Vec<MotionDataset> = a
            .held_out
            .iter()
            .map(|r| load(mesh, r, a.hanging_inertia))
            .collect::<Result<_, _>>()?;
        let base = base(&fitted[0]);
        for design in &a.designs {
            let quadratic = match design.as_str() {
                "P1" => false,
                "P2" => true,
                other => anyhow::bail!("--designs: unknown design {other:?} (P1, P2)"),
            };
            let lifted: Vec<QuadraticMotion<'_>> = if quadratic {
                fitted
                    .iter()
                    .chain(&held)
                    .map(|d| QuadraticMotion::new(&d.model).map(|q| q.with_stand_off(stand_off)))
                    .collect::<Result<_, _>>()?
            } else {
                Vec::new()
            };
            let forwards: Vec<Box<Forward<'_>>> = fitted
                .iter()
                .chain(&held)
                .enumerate()
                .map(|(k, d)| -> Box<Forward<'_>> {
                    if quadratic {
                        let q = &lifted[k];
                        Box::new(move |m: &Material| Ok(q.simulate(m)?.markers))
                    } else {
                        let model = &d.model;
                        Box::new(move |m: &Material| marker_paths(model, m))
                    }
                })
                .collect();
            let runs: Vec<DifferenceRun<'_>> = fitted
                .iter()
                .zip(&forwards)
                .map(|(d, f)| DifferenceRun {
                    obs: &d.obs,
                    forward: f.as_ref(),
                })
                .collect();
            let start = if quadratic {
                &mut start_quadratic
            } else {
                &mut start_linear
            };
            let label = format!("{} {design}", mesh.display());
            let t0 = Instant::now();
            let fit = fit_by_differences(
                &runs,
                &base,
                &params,
                start,
                a.poisson,
                a.max_iterations,
                &|it, rms| {
                    eprintln!(
                        "[{label}] iteration {it}: RMS {:.4} mm ({:.0} s)",
                        1e3 * rms,
                        t0.elapsed().as_secs_f64()
                    )
                },
            )
            .with_context(|| format!("fitting {label}"))?;
            let seconds = t0.elapsed().as_secs_f64();
            let mut mat = base.clone();
            for (p, &v) in params.iter().zip(&fit.values) {
                mat.set_uniform(p.kind, v);
            }
            let mu = mat.get(ParamKind::Mu, 0);
            if let Some(nu) = a.poisson {
                mat.set_uniform(ParamKind::Lambda, mu * 2.0 * nu / (1.0 - 2.0 * nu));
            }
            let lambda = mat.get(ParamKind::Lambda, 0);
            let poisson = lambda / (2.0 * (lambda + mu));
            let held_out_rms_mm = held
                .iter()
                .zip(&forwards[fitted.len()..])
                .zip(&a.held_out)
                .map(|((d, f), name)| {
                    let r = marker_residual(&d.obs, &f(&mat)?);
                    Ok((name.clone(), 1e3 * marker_rms(&r)))
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            let row = Row {
                mesh: mesh.display().to_string(),
                design: design.clone(),
                tets: fitted[0].model.tets.len(),
                free_dofs: if quadratic {
                    lifted[0].free_dofs()
                } else {
                    fitted[0].model.nfree
                },
                values: a
                    .params
                    .iter()
                    .zip(fit.values.iter().zip(&fit.std))
                    .map(|(n, (&v, &s))| (n.clone(), v, s))
                    .collect(),
                young_modulus_pa: 2.0 * mu * (1.0 + poisson),
                poisson,
                fitted_rms_mm: a
                    .fit
                    .iter()
                    .zip(&fit.run_rms)
                    .map(|(n, &r)| (n.clone(), 1e3 * r))
                    .collect(),
                held_out_rms_mm,
                simulations: fit.simulations,
                iterations: fit.iterations,
                converged: fit.converged,
                seconds,
            };
            let cell = |v: &[(String, f64)]| {
                v.iter()
                    .map(|(n, r)| format!("{n} {r:.3}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            println!(
                "| {} | {} | {} | {} | {} | {:.1} | {:.3} | {} | {} | {} | {:.0} |",
                row.mesh,
                row.design,
                row.tets,
                row.free_dofs,
                row.values
                    .iter()
                    .map(|(_, v, s)| format!("{v:.4} ± {s:.2}"))
                    .collect::<Vec<_>>()
                    .join(" | "),
                row.young_modulus_pa / 1e3,
                row.poisson,
                cell(&row.fitted_rms_mm),
                cell(&row.held_out_rms_mm),
                row.simulations,
                row.seconds
            );
            start.clone_from(&fit.values);
            rows.push(row);
        }
    }
    println!("{}", serde_json::to_string(&rows)?);
    Ok(())
}
