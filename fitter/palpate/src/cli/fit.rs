//! `palpate fit <dataset> --material … --method … [--gamma-s …] [--gamma-m …] -o model.palp`:
//! fit a static dataset (seed 000 chapter 5), export the model and write the report beside it.

use std::path::PathBuf;

use anyhow::Context;
use clap::ValueEnum;
use indicatif::ProgressStyle;

use palpate_fem::dataset::StaticDataset;
use palpate_fem::export::{ModelBuffers, ProvenanceInfo};

use palpate_static_fit::loo::leave_one_out;
use palpate_static_fit::{fit_static, FitInput, FitOptions, Gammas, Layout, Method, Sets};

/// Material class (docs/method.md, "The static model").
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum MaterialClass {
    /// One material (E, ν) for the whole object.
    LinearHomogeneous,
    /// One material (E, ν) per element.
    LinearInhomogeneous,
    /// One material per measurement, blended by radial basis functions over deformations.
    NonlinearHomogeneous,
    /// One material per element and measurement, blended in strain space.
    NonlinearInhomogeneous,
}

/// Inverse method.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum MethodArg {
    /// Force-based: linear least squares on the measured positions (fast; docs/method.md).
    Force,
    /// Displacement-based: non-linear least squares on the marker errors (docs/method.md).
    Displacement,
}

/// Arguments of `palpate fit`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset folder (dataset.toml, mesh, markers.csv, measurements.csv, contacts.csv).
    pub dataset: PathBuf,
    /// Material class.
    #[arg(long, value_enum, default_value = "linear-homogeneous")]
    pub material: MaterialClass,
    /// Inverse method.
    #[arg(long, value_enum, default_value = "displacement")]
    pub method: MethodArg,
    /// Spatial smoothness γ_s (both parameter types); chosen on the L-curve when omitted.
    #[arg(long, value_parser = super::output::non_negative, allow_hyphen_values = true)]
    pub gamma_s: Option<f64>,
    /// Cross-measurement smoothness γ_m (both types); defaults to γ_s.
    #[arg(long, value_parser = super::output::non_negative, allow_hyphen_values = true)]
    pub gamma_m: Option<f64>,
    /// Fit without stiffness warping (R_e = I).
    #[arg(long)]
    pub no_warp: bool,
    /// Maximum iterations.
    #[arg(long, default_value_t = 30)]
    pub max_iterations: usize,
    /// Also run leave-one-out validation (one extra fit per measurement).
    #[arg(long)]
    pub leave_one_out: bool,
    /// Output: the model file written; the report goes to `<model>.report/`.
    #[arg(
        short = 'o',
        long = "output",
        visible_alias = "out",
        value_name = "MODEL",
        default_value = "model.palp"
    )]
    pub out: PathBuf,
    /// Figure format.
    #[command(flatten)]
    pub plots: super::output::PlotArgs,
}

/// Runs `palpate fit`.
pub fn run(args: Args) -> anyhow::Result<()> {
    args.plots.apply();
    let command = std::env::args().collect::<Vec<_>>().join(" ");
    super::input_kind::expect(&args.dataset, super::input_kind::Kind::StaticDataset, "fit")?;
    super::output::check_writable(&args.out)?;
    let ds = StaticDataset::read(&args.dataset)
        .with_context(|| format!("reading dataset {}", args.dataset.display()))?;
    let input = FitInput::from_dataset(&ds)?;
    let (layout, sets) = match args.material {
        MaterialClass::LinearHomogeneous => (Layout::Homogeneous, Sets::Single),
        MaterialClass::LinearInhomogeneous => (Layout::Inhomogeneous, Sets::Single),
        MaterialClass::NonlinearHomogeneous => (Layout::Homogeneous, Sets::PerMeasurement),
        MaterialClass::NonlinearInhomogeneous => (Layout::Inhomogeneous, Sets::PerMeasurement),
    };
    let method = match args.method {
        MethodArg::Force => Method::Force,
        MethodArg::Displacement => Method::Displacement,
    };
    let mut o = FitOptions::new(method, layout, sets);
    o.warp = !args.no_warp;
    o.max_iterations = args.max_iterations;
    o.gammas = args
        .gamma_s
        .map(|s| Gammas::new(s, args.gamma_m.unwrap_or(s)));
    if args.gamma_s.is_none() && args.gamma_m.is_some() {
        anyhow::bail!("--gamma-m needs --gamma-s (or omit both to choose γ on the L-curve)");
    }
    let bar = super::logging::bar(None);
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {msg}")
            .expect("static template"),
    );
    let fit = fit_static(&input, &o, |stage, rec| {
        bar.set_message(format!(
            "{stage}: iteration {} objective {:.4e} rms {:.4} mm",
            rec.iteration,
            rec.objective,
            rec.rms_m * 1e3
        ));
        bar.tick();
    })?;
    bar.finish_with_message(format!(
        "fitted in {:.1} s, RMS marker error {:.4} mm",
        fit.seconds,
        fit.rms() * 1e3
    ));
    if fit.findings.has_errors() {
        anyhow::bail!(
            "the fit is not a result, nothing was written:\n{}",
            fit.findings
                .0
                .iter()
                .map(|f| f.to_string())
                .collect::<Vec<_>>()
                .join("\n")
        );
    }
    let blend =
        palpate_static_fit::blend::for_fit(&input.problem, layout, &fit.params, &fit.deformed)?;
    let prov = ProvenanceInfo {
        tool: format!("palpate {} {}", env!("CARGO_PKG_VERSION"), command),
        source: format!("{} ({})", ds.name, args.dataset.display()),
        notes: format!(
            "{} fit, {} material, {}; RMS marker error {:.6e} m; regularisation γ_s {:.3e}, γ_m {:.3e}",
            method,
            layout,
            sets,
            fit.rms(),
            fit.gammas.s_lambda,
            fit.gammas.m_lambda
        ),
    };
    let buffers = ModelBuffers::new(
        &input.problem,
        &ds.mesh.node_tags,
        &fit.params,
        &blend,
        &prov,
    )?;
    let loo = if args.leave_one_out {
        Some(leave_one_out(&input, &o)?)
    } else {
        None
    };
    // The report is written beside its place and swapped in right after the model, so a run
    // killed part-way never leaves a new model next to half of an old report.
    let dir = args.out.with_extension("report");
    let staged = super::output::Staged::new(&dir)?;
    let files = palpate_static_fit::report::static_report::write_report(
        &staged.path,
        &ds.name,
        &command,
        &ds.mesh,
        &input,
        &fit,
        loo.as_deref(),
    )?;
    let bytes = buffers.write(&args.out)?;
    let files = staged.commit(files)?;
    println!(
        "{}",
        palpate_static_fit::report::static_report::markdown(
            &ds.name,
            &command,
            &fit,
            loo.as_deref()
        )
    );
    log::info!("wrote {} ({bytes} bytes): the model", args.out.display());
    for f in files {
        log::info!("wrote {}", f.display());
    }
    let warnings = fit.findings.warnings().count();
    if warnings > 0 {
        for w in fit.findings.warnings() {
            log::warn!("{w}");
        }
        return Err(super::WrittenWithWarnings(warnings).into());
    }
    Ok(())
}
