//! `palpate fit-motion <dataset>`: fit visco-elastic parameters to a motion dataset
//! (docs/motion-dataset.md): log-parameter Levenberg–Marquardt on the Gauss–Newton matrix for
//! global parameters, the paper's LBFGS with adjoint (or direct) gradients for per-element ones
//! (or on request).

use anyhow::Context;
use indicatif::ProgressStyle;
use palpate_fem::export::ProvenanceInfo;
use palpate_motion::fitted::{FittedModel, FittedRun};
use palpate_motion::gradient::Method;
use palpate_motion::model::{Material, Param, ParamKind};
use palpate_motion::optimize::{fit_runs, FitSettings, Optimizer, Run};
use palpate_motion::predict;
use palpate_runtime::material::LambdaAlpha;
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
    /// LBFGS for per-element ones), `lm`, or `lbfgs` (the paper's, §4.3).
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
    /// Fit only μ (Poisson's ratio held by --poisson) to where the runs came to rest — their
    /// equilibria under their loads, no dynamics — and print E with its 1σ.
    #[arg(long, requires = "poisson")]
    pub equilibria: bool,
    /// Optimiser iteration cap.
    #[arg(
        long = "max-iterations",
        visible_alias = "max-iters",
        default_value_t = 150
    )]
    pub max_iters: u64,
    /// Write the fitted parameters (JSON) here.
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Export the fit as a runtime model (.palp): Lamé's (λ, μ) → the thesis coefficients
    /// (λ_F, α_G) the runtime stores, per element, clamp groups fixed; viscosity, density and the large-strain response are not kept (stated in the
    /// model's provenance).
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

/// Runs the fit and prints the report.
pub fn run(args: Args) -> anyhow::Result<()> {
    for d in &args.datasets {
        super::input_kind::expect(d, super::input_kind::Kind::MotionDataset, "fit-motion")?;
    }
    for out in [&args.output, &args.export].into_iter().flatten() {
        super::output::check_writable(out)?;
    }
    let mut all: Vec<palpate_motion::dataset::MotionDataset> = args
        .datasets
        .iter()
        .map(|d| palpate_motion::dataset::load(d))
        .collect::<Result<_, _>>()?;
    if args.hanging_inertia {
        for d in &mut all {
            palpate_motion::fitted::set_hanging_inertia(&mut d.model, true);
        }
    }
    let ds = &all[0];
    for (d, other) in args.datasets.iter().zip(&all).skip(1) {
        anyhow::ensure!(
            other.mesh.nodes == ds.mesh.nodes && other.mesh.tets == ds.mesh.tets,
            "{}: its mesh differs from {}'s: the runs of one fit share one mesh and material",
            d.display(),
            args.datasets[0].display()
        );
    }
    let ne = ds.model.tets.len();
    if args.equilibria {
        let nu = args.poisson.unwrap_or(0.49);
        let init = &ds.config.initial;
        let mut mu0 = init.mu;
        for kv in &args.initial {
            if let Some(v) = kv.strip_prefix("mu=") {
                mu0 = v.trim().parse().context("--initial mu: not a number")?;
            }
        }
        let base = Material::uniform(
            ne,
            init.lambda,
            mu0,
            0.0,
            1.0,
            ds.config.density.unwrap_or(1000.0),
        );
        let runs: Vec<_> = all.iter().map(|d| (&d.model, &d.obs)).collect();
        let (mu, rms, sd) = predict::fit_equilibria(&runs, &base, nu, mu0)?;
        println!(
            "equilibria of {} runs: μ = {mu:.5e} Pa ± {sd:.2e} (1σ, independent residuals), E = {:.5e} Pa ± {:.2e} at Poisson's ratio {nu} (held); rest-state RMS {:.3} mm",
            all.len(),
            2.0 * (1.0 + nu) * mu,
            2.0 * (1.0 + nu) * sd,
            1e3 * rms
        );
        return Ok(());
    }
    let mut init = ds.config.initial.clone();
    if args.initial.is_empty() {
        let start = palpate_motion::start::initial_values(ds, args.poisson);
        log::info!("{}", start.note);
        (init.lambda, init.mu, init.nu, init.h) =
            (start.lambda, start.mu, start.viscosity, start.h);
    }
    let mut stiffening: Option<f64> = None;
    for kv in &args.initial {
        let (k, v) = kv
            .split_once('=')
            .with_context(|| format!("--initial: {kv:?} is not KIND=VALUE"))?;
        let v: f64 = v
            .trim()
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite() && *v > 0.0)
            .with_context(|| format!("--initial: {kv:?}: the value must be a finite number > 0"))?;
        match param_kind(k, "--initial") {
            Some(ParamKind::Lambda) => init.lambda = v,
            Some(ParamKind::Mu) => init.mu = v,
            Some(ParamKind::Nu) => init.nu = v,
            Some(ParamKind::PowerH) => init.h = v,
            Some(ParamKind::Stiffening) => stiffening = Some(v),
            _ => anyhow::bail!(
                "--initial: unknown kind {:?} (lambda, mu, viscosity, h, stiffening)",
                k.trim()
            ),
        }
    }
    let density = ds.config.density.unwrap_or(1000.0);
    let mut base = Material::uniform(ne, init.lambda, init.mu, init.nu, init.h, density);
    // The stiffening is 0 (eq. 16) unless given or fitted; fitted in ln c, it needs a start
    // above 0: c = μ unless given (at 10 % strain that adds about 6 % to the Neo-Hookean energy).
    let fits_stiffening = args
        .params
        .iter()
        .any(|n| n.trim() == ParamKind::Stiffening.name());
    if let Some(c) = stiffening.or(fits_stiffening.then_some(init.mu)) {
        base.set_uniform(ParamKind::Stiffening, c);
    }
    let mut params = Vec::new();
    for name in &args.params {
        let kind = param_kind(name, "--params").with_context(|| {
            format!(
                "--params: unknown parameter {name:?} (lambda, mu, viscosity, h, density, stiffening)"
            )
        })?;
        params.push(Param::global(kind));
    }
    for name in &args.per_element {
        let kind = param_kind(name, "--per-element")
            .filter(|k| matches!(k, ParamKind::Lambda | ParamKind::Mu | ParamKind::Density));
        let kind = kind.with_context(|| {
            format!("--per-element: {name:?} is not one of lambda, mu, density")
        })?;
        anyhow::ensure!(
            !params.iter().any(|p| p.kind == kind),
            "{name} is both global and per-element"
        );
        params.extend((0..ne).map(|e| Param::of_element(kind, e)));
    }
    anyhow::ensure!(!params.is_empty(), "no parameters to fit");
    if ds.config.density.is_none() && !params.iter().any(|p| p.kind == ParamKind::Density) {
        log::info!("note: density not given in dataset.toml; using 1000 kg/m³");
    }
    let q0 = base.read(&params);
    let bar = super::logging::bar(Some(args.max_iters * 2));
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
    };
    let runs: Vec<Run> = all
        .iter()
        .map(|d| Run {
            model: &d.model,
            obs: &d.obs,
        })
        .collect();
    let r = fit_runs(
        &runs,
        &base,
        &params,
        &q0,
        &settings,
        &ds.mesh.face_neighbours(),
        &progress,
    )?;
    bar.finish_and_clear();
    let mut fitted = base.clone();
    fitted.set(&params, &r.q);
    if let (Some(nu), Some(mu)) = (
        args.poisson,
        params.iter().position(|p| p.kind == ParamKind::Mu),
    ) {
        fitted.set(
            &[Param::global(ParamKind::Lambda)],
            &[2.0 * nu / (1.0 - 2.0 * nu) * r.q[mu]],
        );
    }
    let names: Vec<String> = args
        .datasets
        .iter()
        .map(|d| d.display().to_string())
        .collect();
    println!(
        "fit-motion {}: {} tets, {} steps of {} s, {} markers",
        names.join(" + "),
        ne,
        all.iter()
            .map(|d| d.model.steps.to_string())
            .collect::<Vec<_>>()
            .join(" + "),
        ds.model.dt,
        ds.model.markers.len()
    );
    println!("| quantity | value |\n|---|---|");
    println!(
        "| RMS marker error √(2Φ/(NT)) | {:.4} mm |",
        r.eval.rms_marker * 1e3
    );
    println!("| RMS force error | {:.4e} N |", r.eval.rms_force);
    if all.len() > 1 {
        for (name, e) in names.iter().zip(&r.runs) {
            println!(
                "| RMS marker error, {name} | {:.4} mm |",
                e.rms_marker * 1e3
            );
        }
    }
    println!(
        "| simulations / {} iterations | {} / {} |",
        optimizer_name(r.optimizer),
        r.evaluations,
        r.iterations
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
        } else if k == ParamKind::Lambda && args.poisson.is_some() {
            "from μ at the fixed Poisson's ratio"
        } else {
            "fixed"
        };
        println!(
            "| {} ({tag}) | mean {mean:.6e} (min {lo:.4e}, max {hi:.4e}) |",
            k.label()
        );
    }
    let la = LambdaAlpha::from_lame(
        fitted.get(ParamKind::Lambda, 0),
        fitted.get(ParamKind::Mu, 0),
    );
    println!(
        "| Young's modulus E, Poisson's ratio ν (element 0) | {:.4e} Pa, {:.4} |",
        la.young(),
        la.poisson()
    );
    println!(
        "| {} of element 0, as exported | {:.4e} Pa, {:.4e} Pa |",
        palpate_fem::names::THESIS_PAIR,
        la.lambda,
        la.alpha
    );
    println!("\n{}", palpate_fem::names::THESIS_PAIR_NOTE);
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
        optimizer_name(r.optimizer),
        r.iterations as usize,
        args.max_iters as usize,
        r.iterations < args.max_iters,
    ));
    // A fit that never left its start (nothing in the data pulled on it) or ended at infinity
    // is no result.
    if r.q == q0 {
        findings.error(
            "fit-did-not-move",
            format!(
                "the fit ended on its starting values after {} simulation(s): the data did not \
                 move it, so writing it would pass the start off as a measurement (check the \
                 weights, units and frame of the dataset)",
                r.evaluations
            ),
        );
    }
    if !(r.q.iter().all(|v| v.is_finite())
        && r.eval.rms_marker.is_finite()
        && r.eval.rms_force.is_finite())
    {
        findings.error(
            "non-finite-fit",
            format!(
                "the fit ended at infinity or NaN (RMS marker error {:.3e} m, force {:.3e} N)",
                r.eval.rms_marker, r.eval.rms_force
            ),
        );
    }
    let findings = findings.into_result()?;
    if let Some(out) = &args.output {
        let record = FittedModel {
            format: palpate_motion::fitted::FORMAT.into(),
            datasets: names.clone(),
            nodes: ds.mesh.nodes.len(),
            tets: ne,
            lambda: fitted.values[0].clone(),
            mu: fitted.values[1].clone(),
            viscosity: fitted.values[2].clone(),
            h: fitted.values[3].clone(),
            density: fitted.values[4].clone(),
            stiffening: palpate_motion::fitted::FittedModel::stiffening_of(&fitted),
            poisson_fixed: args.poisson,
            hanging_inertia: args.hanging_inertia
                || all.iter().any(|d| d.model.loads.iter().any(|l| l.inertia)),
            time_offset: false,
            fitted: params
                .iter()
                .map(|p| p.kind.name().to_string())
                .collect::<std::collections::BTreeSet<_>>()
                .into_iter()
                .collect(),
            runtime_lambda_alpha: fitted.values[0]
                .iter()
                .zip(&fitted.values[1])
                .map(|(l, m)| {
                    let a = LambdaAlpha::from_lame(*l, *m);
                    [a.lambda, a.alpha]
                })
                .collect(),
            rms_marker_m: r.eval.rms_marker,
            rms_force_n: r.eval.rms_force,
            evaluations: r.evaluations,
            runs: all
                .iter()
                .zip(&names)
                .zip(&r.runs)
                .map(|((d, name), e)| {
                    let rest = predict::rest_markers(&d.model);
                    FittedRun {
                        dataset: name.clone(),
                        load_n: predict::load_along_gravity(&d.model),
                        rms_marker_m: e.rms_marker,
                        time_offset_s: 0.0,
                        markers: d.model.markers.iter().map(|m| m.name.clone()).collect(),
                        final_displacement_m: predict::final_observed(&d.model, &d.obs)
                            .iter()
                            .zip(&rest)
                            .map(|(f, r0)| f.map(|p| [0, 1, 2].map(|k| p[k] - r0[k])))
                            .collect(),
                    }
                })
                .collect(),
        };
        palpate_fem::io::atomic::write_atomic(out, record.to_json()?.as_bytes())?;
        log::info!(
            "wrote {} (fitted parameters; `palpate validate --model {}` predicts other runs)",
            out.display(),
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
            source: names.join(" + "),
            notes: format!(
                "fit-motion: RMS marker {:.4e} m, RMS force {:.4e} N, {} simulations",
                r.eval.rms_marker, r.eval.rms_force, r.evaluations
            ),
        };
        let buffers = palpate_motion::export::model_buffers(&ds.mesh, &ds.model, &fitted, &prov)
            .with_context(|| format!("exporting {}", path.display()))?;
        let n = buffers.write(path)?;
        log::info!(
            "wrote {} ({n} bytes): runtime model; {}",
            path.display(),
            palpate_motion::export::lost_in_export(&fitted)
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

/// The optimiser's name in reports.
fn optimizer_name(o: Optimizer) -> &'static str {
    match o {
        Optimizer::Lbfgs => "LBFGS",
        _ => "Levenberg–Marquardt",
    }
}
