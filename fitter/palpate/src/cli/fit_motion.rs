//! `palpate fit-motion <dataset>`: fit visco-elastic parameters to a motion dataset
//! (docs/motion-dataset.md) with log-parameter LBFGS and adjoint (or direct) gradients.

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use palpate_fem::export::ProvenanceInfo;
use palpate_motion::gradient::Method;
use palpate_motion::model::{Material, Param, ParamKind};
use palpate_motion::optimize::{fit, FitSettings};
use palpate_runtime::material::LambdaAlpha;
use std::path::PathBuf;

/// Options.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset directory (dataset.toml, mesh.msh, markers.csv, …).
    pub dataset: PathBuf,
    /// Global parameters to fit, comma-separated from lambda,mu,nu,h,density.
    #[arg(long, default_value = "lambda,mu,nu,h", value_delimiter = ',')]
    pub params: Vec<String>,
    /// Per-element parameters to fit (lambda,mu,density), with neighbour smoothness.
    #[arg(long, value_delimiter = ',')]
    pub per_element: Vec<String>,
    /// Neighbour-smoothness weight for per-element parameters (default: automatic).
    #[arg(long)]
    pub smoothness: Option<f64>,
    /// Use direct sensitivities instead of the adjoint method.
    #[arg(long)]
    pub direct: bool,
    /// LBFGS iteration cap.
    #[arg(long, default_value_t = 150)]
    pub max_iters: u64,
    /// Write the fitted parameters (JSON) here.
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Export the fit as a runtime model (.palp): Lamé → thesis (λ, α) per element, clamp groups
    /// fixed; viscosity, density and the large-strain response are not kept (stated in the
    /// model's provenance).
    #[arg(long)]
    pub export: Option<PathBuf>,
}

/// Runs the fit and prints the report.
pub fn run(args: Args) -> anyhow::Result<()> {
    for out in [&args.output, &args.export].into_iter().flatten() {
        super::output::check_writable(out)?;
    }
    let ds = palpate_motion::dataset::load(&args.dataset)?;
    let ne = ds.model.tets.len();
    let init = &ds.config.initial;
    let density = ds.config.density.unwrap_or(1000.0);
    let base = Material::uniform(ne, init.lambda, init.mu, init.nu, init.h, density);
    let mut params = Vec::new();
    for name in &args.params {
        let kind = ParamKind::parse(name).with_context(|| {
            format!("--params: unknown parameter {name:?} (lambda, mu, nu, h, density)")
        })?;
        params.push(Param::global(kind));
    }
    for name in &args.per_element {
        let kind = ParamKind::parse(name)
            .filter(|k| matches!(k, ParamKind::Lambda | ParamKind::Mu | ParamKind::Density));
        let kind = kind.with_context(|| {
            format!("--per-element: {name:?} is not one of lambda, mu, density")
        })?;
        anyhow::ensure!(
            !params.iter().any(|p| p.kind == kind),
            "{name} is both global and per-element"
        );
        params.extend((0..ne).map(|e| Param {
            kind,
            element: Some(e),
        }));
    }
    anyhow::ensure!(!params.is_empty(), "no parameters to fit");
    if ds.config.density.is_none() && !params.iter().any(|p| p.kind == ParamKind::Density) {
        eprintln!("note: density not given in dataset.toml; using 1000 kg/m³");
    }
    let q0 = base.read(&params);
    let bar = ProgressBar::new(args.max_iters * 2);
    bar.set_style(
        ProgressStyle::with_template("{spinner} {pos} simulations, {msg} [{elapsed}]")
            .unwrap_or(ProgressStyle::default_spinner()),
    );
    let pb = bar.clone();
    let progress = move |n: usize, phi: f64| {
        pb.set_position(n as u64);
        pb.set_message(format!("Φ = {phi:.5e}"));
    };
    let settings = FitSettings {
        method: if args.direct {
            Method::Direct
        } else {
            Method::Adjoint
        },
        max_iters: args.max_iters,
        smoothness: args.smoothness,
        ..Default::default()
    };
    let r = fit(
        &ds.model,
        &base,
        &params,
        &q0,
        &ds.obs,
        &settings,
        &ds.mesh.face_neighbours(),
        &progress,
    )?;
    bar.finish_and_clear();
    let mut fitted = base.clone();
    fitted.set(&params, &r.q);
    println!(
        "fit-motion {}: {} tets, {} steps of {} s, {} markers",
        args.dataset.display(),
        ne,
        ds.model.steps,
        ds.model.dt,
        ds.model.markers.len()
    );
    println!("| quantity | value |\n|---|---|");
    println!(
        "| RMS marker error √(2Φ/(NT)) | {:.4} mm |",
        r.eval.rms_marker * 1e3
    );
    println!("| RMS force error | {:.4e} N |", r.eval.rms_force);
    println!(
        "| simulations / LBFGS iterations | {} / {} |",
        r.evaluations, r.iterations
    );
    for k in ParamKind::ALL {
        let v = &fitted.values[k as usize];
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                (a.min(*x), b.max(*x))
            });
        let tag = if params.iter().any(|p| p.kind == k) {
            "fitted"
        } else {
            "fixed"
        };
        println!(
            "| {} ({tag}) | mean {mean:.6e} (min {lo:.4e}, max {hi:.4e}) |",
            k.name()
        );
    }
    let la = LambdaAlpha::from_lame(
        fitted.get(ParamKind::Lambda, 0),
        fitted.get(ParamKind::Mu, 0),
    );
    println!(
        "| runtime (thesis) λ, α of element 0 | {:.4e}, {:.4e} (E = {:.4e} Pa, Poisson {:.3}) |",
        la.lambda,
        la.alpha,
        la.young(),
        la.poisson()
    );
    for f in &r.failures {
        println!("note: {f}");
    }
    // The result's gates: elastic parameters at the bounds of what a soft object can be refuse
    // the export; Newton steps that never met their tolerance and an LBFGS run stopped by its cap
    // are said loudly (stderr, exit status 2).
    let elastic: Vec<palpate_fem::forward::Material> =
        (0..fitted.values[0].len().max(fitted.values[1].len()))
            .map(|e| {
                let at = |k: usize| fitted.values[k][e.min(fitted.values[k].len() - 1)];
                palpate_fem::forward::Material::homogeneous(LambdaAlpha::from_lame(at(0), at(1)))
            })
            .collect();
    let mut findings = palpate_fem::sanity::Findings::default();
    for (e, m) in elastic.iter().enumerate() {
        for mut f in palpate_fem::sanity::check_material(std::slice::from_ref(m)).0 {
            if elastic.len() > 1 {
                f.message = format!("element {e}: {}", f.message);
            }
            findings.0.push(f);
        }
    }
    let stats = r.eval.stats;
    if stats.unconverged_steps > 0 {
        findings.warn(
            "newton-not-converged",
            format!(
                "{} of {} time steps of the fitted simulation did not meet the Newton tolerance \
                 (largest residual {:.3e} N): the fitted trajectory is not an accurate solution",
                stats.unconverged_steps, ds.model.steps, stats.max_residual
            ),
        );
    }
    findings.extend(palpate_fem::sanity::check_iterations(
        "LBFGS",
        r.iterations as usize,
        args.max_iters as usize,
        r.iterations < args.max_iters,
    ));
    let findings = findings.into_result()?;
    if let Some(out) = &args.output {
        let json = serde_json::json!({
            "dataset": args.dataset.display().to_string(),
            "lambda": fitted.values[0], "mu": fitted.values[1], "nu": fitted.values[2], "h": fitted.values[3], "density": fitted.values[4],
            "runtime_lambda_alpha": fitted.values[0].iter().zip(&fitted.values[1]).map(|(l, m)| { let a = LambdaAlpha::from_lame(*l, *m); [a.lambda, a.alpha] }).collect::<Vec<_>>(),
            "rms_marker_m": r.eval.rms_marker, "rms_force_n": r.eval.rms_force, "evaluations": r.evaluations,
        });
        palpate_fem::io::atomic::write_atomic(
            out,
            serde_json::to_string_pretty(&json)?.as_bytes(),
        )?;
        println!(
            "wrote {} (fitted parameters; viscosity is not used by the static runtime)",
            out.display()
        );
    }
    if let Some(path) = &args.export {
        let prov = ProvenanceInfo {
            tool: format!(
                "palpate {} {}",
                env!("CARGO_PKG_VERSION"),
                std::env::args().collect::<Vec<_>>().join(" ")
            ),
            source: args.dataset.display().to_string(),
            notes: format!(
                "fit-motion: RMS marker {:.4e} m, RMS force {:.4e} N, {} simulations",
                r.eval.rms_marker, r.eval.rms_force, r.evaluations
            ),
        };
        let buffers = palpate_motion::export::model_buffers(&ds.mesh, &ds.model, &fitted, &prov)
            .with_context(|| format!("exporting {}", path.display()))?;
        let n = buffers.write(path)?;
        println!(
            "wrote {} ({n} bytes): runtime model; {}",
            path.display(),
            palpate_motion::export::lost_in_export(&fitted)
        );
    }
    let warnings = findings.warnings().count();
    if warnings > 0 {
        for w in findings.warnings() {
            eprintln!("{w}");
        }
        return Err(super::WrittenWithWarnings(warnings).into());
    }
    Ok(())
}
