//! `palpate fit-motion <dataset>`: fit visco-elastic parameters to a motion dataset
//! (docs/motion-dataset.md): log-parameter Levenberg–Marquardt on the Gauss–Newton matrix for
//! global parameters, the paper's LBFGS with adjoint (or direct) gradients for per-element ones
//! (or on request).

use anyhow::Context;
use indicatif::ProgressStyle;
use palpate_diagnose::runtime_match::export_parameters;
use palpate_motion::gradient::Method;
use palpate_motion::model::ParamKind;
use palpate_motion::optimize::{FitSettings, Optimizer};
use palpate_motion::request::{self, FitRequest, NamedRun};
use std::path::PathBuf;

/// Options.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset directories (dataset.toml, mesh.msh, markers.csv, …): one, or several runs of one
    /// object on one mesh (other loads, repeats) fitted together with one material.
    #[arg(required = true, num_args = 1..)]
    pub datasets: Vec<PathBuf>,
    /// Global parameters to fit, comma-separated from lambda, mu (Lamé's λ and the shear
    /// modulus μ, Pa), viscosity (the power-law viscosity coefficient, Pa·s^h; formerly `nu`),
    /// h (its power-law index), density (kg/m³) and stiffening (the c of a c (Ī₁ − 3)² term
    /// beside Neo-Hookean, Pa; starts at μ unless `--initial stiffening=…`).
    #[arg(long, default_value = "lambda,mu,viscosity,h", value_delimiter = ',')]
    pub params: Vec<String>,
    /// Per-element parameters to fit (lambda,mu,density), with neighbour smoothness.
    #[arg(long, value_delimiter = ',')]
    pub per_element: Vec<String>,
    /// Neighbour-smoothness weight for per-element parameters (default: automatic).
    #[arg(long)]
    pub smoothness: Option<f64>,
    /// Use direct sensitivities instead of the adjoint method (LBFGS).
    #[arg(long)]
    pub direct: bool,
    /// Optimiser: `auto` (Levenberg–Marquardt on the Gauss–Newton matrix for global parameters,
    /// LBFGS for per-element ones), `lm`, or `lbfgs` (Real2Sim's optimiser, docs/method.md).
    #[arg(long, default_value = "auto", value_parser = ["auto", "lm", "lbfgs"])]
    pub optimizer: String,
    /// Hold Poisson's ratio fixed at this value (λ follows μ; give `mu` and not `lambda` in
    /// --params). For a nearly incompressible material seen through a few markers.
    #[arg(long)]
    pub poisson: Option<f64>,
    /// Starting values overriding the first dataset's `[initial]` table, e.g.
    /// `mu=8e4,viscosity=5` (lambda, mu in Pa; viscosity in Pa·s^h; h; stiffening in Pa).
    #[arg(long, value_delimiter = ',', value_name = "KIND=VALUE")]
    pub initial: Vec<String>,
    /// Hanging weights (`[[loads]]` with a mass) also add their inertia, lumped on their nodes.
    #[arg(long)]
    pub hanging_inertia: bool,
    /// How the viscosity reads the velocity gradient, overriding each dataset's
    /// `viscosity_form`: `rest-gradient` (Real2Sim's public code; damps a turned element that
    /// swings rigidly) or `objective` (the Green–Lagrange strain rate: a rigid motion dissipates
    /// nothing). docs/motion-dataset.md.
    #[arg(long, value_parser = ["rest-gradient", "objective"])]
    pub viscosity_form: Option<String>,
    /// Fit only μ (Poisson's ratio held by --poisson) to where the runs came to rest — their
    /// equilibria under their loads, no dynamics — and print E with its 1σ.
    #[arg(long, requires = "poisson")]
    pub equilibria: bool,
    /// After the fit, fit the runs' rest states on linear and on quadratic elements of the same
    /// mesh and say whether the fitted modulus is the material's or the mesh's (linear tetrahedra
    /// lock in bending near incompressibility; docs/diagnose.md, "Mesh convergence"); then refit
    /// the motion itself on quadratic elements and set every fitted parameter beside the linear
    /// one. The output's `converged` then lets `palpate validate` carry the material to another
    /// mesh, and `--export` fits the runtime's parameters to that material.
    #[arg(long)]
    pub mesh_convergence: bool,
    /// Optimiser iteration cap.
    #[arg(
        long = "max-iterations",
        visible_alias = "max-iters",
        default_value_t = 150
    )]
    pub max_iters: u64,
    /// Output: the fitted parameters (fit.json) written; the result is printed, and nothing is
    /// written without it.
    #[arg(
        short = 'o',
        long = "output",
        visible_alias = "out",
        value_name = "FILE"
    )]
    pub output: Option<PathBuf>,
    /// Export the fit as a runtime model (.palp): Lamé's (λ, μ) → the coefficients
    /// (λ_F, α_G) the runtime stores, per element, clamp groups fixed; viscosity, density and the
    /// large-strain response are not kept (stated in the model's provenance). With
    /// --mesh-convergence, the runtime's parameters are instead fitted to the material on
    /// quadratic elements under probe presses, and the runtime's error against it is printed.
    #[arg(long)]
    pub export: Option<PathBuf>,
}

/// A parameter kind by its name; the viscosity's old name `nu` still works, with a warning on
/// stderr that names the new one.
fn param_kind(name: &str, flag: &str) -> Option<ParamKind> {
    let name = name.trim();
    ParamKind::parse(name).or_else(|| {
        let kind = ParamKind::old_name(name)?;
        log::warn!(
            "{flag}: `{name}` is now called `{}` (ν is Poisson's ratio everywhere else); read as {}",
            kind.name(),
            kind.name()
        );
        Some(kind)
    })
}

/// Parses `--initial KIND=VALUE,…` into kinds and finite positive values.
fn initial_values(given: &[String]) -> anyhow::Result<Vec<(ParamKind, f64)>> {
    given
        .iter()
        .map(|kv| {
            let (k, v) = kv
                .split_once('=')
                .with_context(|| format!("--initial: {kv:?} is not KIND=VALUE"))?;
            let v: f64 = v
                .trim()
                .parse()
                .ok()
                .filter(|v: &f64| v.is_finite() && *v > 0.0)
                .with_context(|| {
                    format!("--initial: {kv:?}: the value must be a finite number > 0")
                })?;
            match param_kind(k, "--initial") {
                Some(
                    kind @ (ParamKind::Lambda
                    | ParamKind::Mu
                    | ParamKind::Nu
                    | ParamKind::PowerH
                    | ParamKind::Stiffening),
                ) => Ok((kind, v)),
                _ => anyhow::bail!(
                    "--initial: unknown kind {:?} (lambda, mu, viscosity, h, stiffening)",
                    k.trim()
                ),
            }
        })
        .collect()
}

/// The request the flags describe.
fn request(args: &Args) -> anyhow::Result<FitRequest> {
    let params = args
        .params
        .iter()
        .map(|name| {
            param_kind(name, "--params").with_context(|| {
                format!(
                    "--params: unknown parameter {name:?} (lambda, mu, viscosity, h, density, stiffening)"
                )
            })
        })
        .collect::<anyhow::Result<_>>()?;
    let per_element = args
        .per_element
        .iter()
        .map(|name| {
            param_kind(name, "--per-element")
                .filter(|k| matches!(k, ParamKind::Lambda | ParamKind::Mu | ParamKind::Density))
                .with_context(|| {
                    format!("--per-element: {name:?} is not one of lambda, mu, density")
                })
        })
        .collect::<anyhow::Result<_>>()?;
    Ok(FitRequest {
        params,
        per_element,
        initial: initial_values(&args.initial)?,
        hanging_inertia: args.hanging_inertia,
        settings: FitSettings {
            optimizer: match args.optimizer.as_str() {
                "lm" => Optimizer::LevenbergMarquardt,
                "lbfgs" => Optimizer::Lbfgs,
                _ => Optimizer::Auto,
            },
            method: if args.direct {
                Method::Direct
            } else {
                Method::Adjoint
            },
            max_iters: args.max_iters,
            smoothness: args.smoothness,
            poisson: args.poisson,
            ..Default::default()
        },
    })
}

/// Runs the fit and prints the report.
pub fn run(args: Args) -> anyhow::Result<()> {
    for d in &args.datasets {
        super::input_kind::expect(d, super::input_kind::Kind::MotionDataset, "fit-motion")?;
    }
    for out in [&args.output, &args.export].into_iter().flatten() {
        super::output::check_writable(out)?;
    }
    let req = request(&args)?;
    let mut runs = args
        .datasets
        .iter()
        .map(|d| NamedRun::load(d))
        .collect::<Result<Vec<_>, _>>()?;
    for r in &runs {
        log::info!("{}: {}", r.name, r.dataset.timestep.describe());
    }
    if let Some(form) = args
        .viscosity_form
        .as_deref()
        .and_then(palpate_motion::viscosity::Form::parse)
    {
        for r in &mut runs {
            r.dataset.model.viscous_form = form;
        }
    }
    if args.equilibria {
        let eq = request::fit_equilibria(&runs, &req)?;
        println!("{eq}");
        if args.mesh_convergence {
            print_convergence(&runs, eq.poisson, eq.mu.0, eq.rms_m);
        }
        return Ok(());
    }
    let bar = progress_bar(args.max_iters);
    let pb = bar.clone();
    let progress = move |n: usize, phi: f64| {
        pb.set_position(n as u64);
        pb.set_message(format!("Φ = {}", palpate_fem::numbers::plain(phi)));
    };
    let mut outcome = request::fit(&mut runs, &req, &progress)?;
    bar.finish_and_clear();
    println!("{outcome}");
    if args.mesh_convergence {
        let r = &outcome.record;
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let (lambda, mu) = (mean(&r.lambda), mean(&r.mu));
        let poisson = r.poisson_fixed.unwrap_or(lambda / (2.0 * (lambda + mu)));
        let (held_poisson, rms_m) = (r.poisson_fixed, r.rms_marker_m);
        let c = print_convergence(&runs, poisson, mu, rms_m);
        // fit.json carries the converged modulus: `palpate validate` can then take the material
        // to another mesh.
        outcome.record.converged = c.converged_modulus();
        // The motion itself refitted on quadratic elements, from the rest states' modulus.
        let scale = c
            .converged_modulus()
            .map_or(1.0, |m| m.shear_modulus_pa / m.mesh_shear_modulus_pa);
        let named: Vec<palpate_diagnose::motion_convergence::FittedRun<'_>> = runs
            .iter()
            .map(|r| (r.name.as_str(), &r.dataset.model, &r.dataset.obs))
            .collect();
        let kinds: Vec<ParamKind> = outcome.params.iter().map(|p| p.kind).collect();
        let m = palpate_diagnose::motion_convergence::check(
            &named,
            &outcome.fitted,
            &kinds,
            held_poisson,
            scale,
            rms_m,
            &|l| log::info!("{l}"),
        );
        print!("{}", m.markdown());
    }
    let findings = outcome.findings.clone().into_result()?;
    if let Some(out) = &args.output {
        palpate_fem::io::atomic::write_atomic(out, outcome.record.to_json()?.as_bytes())?;
        log::info!(
            "wrote {} (fitted parameters; `palpate validate --model {}` predicts other runs)",
            out.display(),
            out.display()
        );
    }
    if let Some(path) = &args.export {
        let tool = format!(
            "palpate {} {}",
            env!("CARGO_PKG_VERSION"),
            std::env::args().collect::<Vec<_>>().join(" ")
        );
        // With the mesh-convergence check's modulus, the runtime replays the material: its
        // parameters fitted to it under probe presses (`palpate_diagnose::runtime_match`).
        let (params, matched) = export_parameters(
            &runs[0].dataset,
            &outcome.fitted,
            outcome.record.converged.as_ref(),
        )
        .context("matching the runtime's model to the converged material")?;
        if let Some(m) = &matched {
            println!("{}", m.markdown());
        }
        let how = matched.as_ref().map(|m| m.provenance());
        let n = outcome
            .runtime_model(&runs[0].dataset, tool, how.as_deref().map(|h| (&params, h)))
            .with_context(|| format!("exporting {}", path.display()))?
            .write(path)?;
        log::info!(
            "wrote {} ({n} bytes): runtime model; {}",
            path.display(),
            palpate_motion::export::lost_in_export(&outcome.fitted)
        );
    }
    let warnings = findings.warnings().count();
    if warnings > 0 {
        for w in findings.warnings() {
            log::warn!("{w}");
        }
        return Err(super::WrittenWithWarnings(warnings).into());
    }
    Ok(())
}

/// Prints whether the modulus `mu` fitted at Poisson's ratio `poisson` (marker RMS `rms_m`) is
/// the material's or the mesh's ([`palpate_diagnose::convergence`]), and returns the check.
fn print_convergence(
    runs: &[NamedRun],
    poisson: f64,
    mu: f64,
    rms_m: f64,
) -> palpate_diagnose::convergence::MeshConvergence {
    let named: Vec<(&str, &palpate_motion::dataset::MotionDataset)> =
        runs.iter().map(|r| (r.name.as_str(), &r.dataset)).collect();
    let c =
        palpate_diagnose::convergence::check(&named, poisson, mu, rms_m, &|l| log::info!("{l}"));
    println!("{}", c.summary_line());
    c
}

/// The spinner that counts the fit's simulations and shows Φ (on stderr; hidden by `-q`).
fn progress_bar(max_iters: u64) -> indicatif::ProgressBar {
    let bar = super::logging::bar(Some(max_iters * 2));
    bar.set_style(
        ProgressStyle::with_template("{spinner} {pos} simulations, {msg} [{elapsed}]")
            .unwrap_or(ProgressStyle::default_spinner()),
    );
    bar
}
