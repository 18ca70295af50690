//! `palpate demo`: the whole loop on the bundled data — fit, diagnose, export, and a short haptic
//! replay driven by the simulated probe over a real pseudo-terminal — then the before/after table.

use anyhow::Context;
use palpate_diagnose::{run_diagnosis_with, DiagnoseOptions};
use palpate_fem::dataset::StaticDataset;
use palpate_fem::export::{ModelBuffers, ProvenanceInfo};
use palpate_runtime::RuntimeConfig;
use palpate_static_fit::blend::BlendData;
use palpate_static_fit::FitResult;
use palpate_static_fit::{fit_static, FitInput, FitOptions, Layout, Method, Sets};
use std::path::{Path, PathBuf};

use super::demo_readme::{figures_in, DemoReadme, Part, Table};
use super::logging::Stage;
use std::time::Instant;

/// Arguments of `palpate demo`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The static dataset to run the loop on.
    #[arg(long, default_value = "models/sponge-specimen")]
    pub dataset: PathBuf,
    /// Output: the folder written (README.md, models, reports).
    #[arg(
        short = 'o',
        long = "output",
        visible_alias = "out",
        value_name = "DIR",
        default_value = "out/demo"
    )]
    pub out: PathBuf,
    /// Seconds of haptic replay over the pseudo-terminal.
    #[arg(long, default_value_t = 2.0)]
    pub haptic_seconds: f64,
    /// Skip the measured-beam loop (models/silicone-beam) and run only the synthetic specimen.
    #[arg(long)]
    pub no_beam: bool,
    /// Figure format.
    #[command(flatten)]
    pub plots: super::output::PlotArgs,
}

fn mm(v: f64) -> String {
    format!("{:.3}", v * 1e3)
}

/// Runs the demo.
pub fn run(args: Args) -> anyhow::Result<()> {
    args.plots.apply();
    check_bundled_data(&args)?;
    let t0 = Instant::now();
    let progress = super::logging::Progress::start("palpate demo");
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    // First the loop on measured data (a real capture), then the synthetic specimen whose
    // injected effects are known.
    let parts = if args.no_beam { 1 } else { 2 };
    let beam = if args.no_beam {
        None
    } else {
        progress.stage(&Stage {
            step: Some((1, parts)),
            text: "the measured silicone beam".into(),
            ..Stage::default()
        });
        log::info!("palpate demo, part 1: the measured silicone beam (models/silicone-beam, C3D)");
        Some(super::demo_beam::run(&args.out)?)
    };
    progress.stage(&Stage {
        step: Some((parts, parts)),
        text: "the synthetic specimen".into(),
        ..Stage::default()
    });
    if beam.is_some() {
        log::info!("palpate demo, part 2: the synthetic specimen (effects known)");
    }
    let specimen = specimen_loop(&args)?;
    drop(progress);
    // The tables: printed, and written with the figures into the folder's README.
    let part = specimen_part(&specimen.report, &specimen.diag_files, &args.out);
    let replay = &specimen.replay.replay;
    let haptic = format!(
        "Haptic replay of the diagnosed model over a pseudo-terminal: {} samples solved ({} lost); \
         latency from frame written to solved p50 {:.0} µs, p99 {:.0} µs; mean PCG iterations \
         {:.1}; runtime memory {} bytes.",
        replay.solved,
        replay.lost,
        replay.p50_us,
        replay.p99_us,
        replay.mean_iterations,
        specimen.replay.footprint_bytes
    );
    for t in &part.tables {
        println!("\n{}", t.markdown());
    }
    println!("{haptic}");
    if replay.non_monotonic > 0 {
        log::warn!(
            "{} latency pairs were out of clock order and are excluded from the figures",
            replay.non_monotonic
        );
    }
    let mut parts = Vec::new();
    if let Some(b) = &beam {
        let part = super::demo_beam::part(b, &args.out);
        super::demo_beam::print_table(&part);
        parts.push(part);
    }
    parts.push(part);
    let readme = DemoReadme {
        command: "palpate demo".into(),
        parts,
        notes: vec![
            haptic,
            format!(
                "Models: `{}` (the simplest) and `{}` (the diagnosed one); `palpate info` says \
                 what each holds.",
                "model-simplest.palp", "model.palp"
            ),
            format!("The demo ran for {:.0} s.", t0.elapsed().as_secs_f64()),
        ],
    };
    let readme_path = super::demo_readme::write(&args.out, &readme)?;
    println!(
        "\nthe results, tables and figures: {}",
        readme_path.display()
    );
    log::info!("demo finished in {:.1} s", t0.elapsed().as_secs_f64());
    if let Some(b) = &beam {
        super::demo_beam::check_expected(b)?;
        log::info!("the beam's decisions and held-out errors are the expected ones");
    }
    Ok(())
}

/// The bundled data are found relative to the working directory: outside the repository the
/// demo says so before it makes any folder.
fn check_bundled_data(args: &Args) -> anyhow::Result<()> {
    let mut needed = vec![args.dataset.clone()];
    if !args.no_beam {
        needed.push(PathBuf::from(super::demo_beam::BEAM_DIR));
    }
    for p in &needed {
        if !p.exists() {
            anyhow::bail!(
                "{}: not found. The demo runs on the data bundled with palpate's repository: run \
                 it from the repository's root folder (the one holding README.md and models/), \
                 or give --dataset DIR{}",
                p.display(),
                if args.no_beam { "" } else { " --no-beam" }
            );
        }
    }
    Ok(())
}

/// What the synthetic specimen's loop made: the diagnosis, its report's files, the replay of
/// the diagnosed model.
struct SpecimenLoop {
    report: palpate_diagnose::DiagnosisReport,
    diag_files: Vec<PathBuf>,
    replay: palpate_link::replay::ModelReplay,
}

/// The loop on the static dataset: fit the simplest model, diagnose, export both models, replay
/// the diagnosed one over a pseudo-terminal. Each step is one library call.
fn specimen_loop(args: &Args) -> anyhow::Result<SpecimenLoop> {
    let ds = StaticDataset::read(&args.dataset)
        .with_context(|| format!("reading dataset {}", args.dataset.display()))?;
    log::info!(
        "palpate demo on {:?}: {} nodes, {} tets, {} markers, {} measurements",
        ds.name,
        ds.mesh.nodes.len(),
        ds.mesh.tets.len(),
        ds.markers.len(),
        ds.measurements.len()
    );
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;

    let (input, fit) = fit_simplest(&ds)?;

    // 2. Diagnose: residual signatures, candidate effects scored on held-out data.
    log::info!("[2/4] diagnose: residual signatures, candidate effects, held-out scoring");
    let report = run_diagnosis_with(&ds, &DiagnoseOptions::default(), |msg| {
        log::info!("  {msg}")
    })?;
    let diag_dir = args.out.join("diagnosis");
    let diag_files = palpate_diagnose::report::write_report(&report, &diag_dir)?;
    log::info!(
        "      report: {} files in {}",
        diag_files.len(),
        diag_dir.display()
    );

    let model_path = export_models(args, &ds, &input, &fit, &report)?;

    // 4. Haptic replay: the simulated probe streams forces over a pseudo-terminal; the runtime
    //    solves one warped tick per sample.
    log::info!(
        "[4/4] haptic replay over a pseudo-terminal ({} s at 1 kHz)",
        args.haptic_seconds
    );
    let cfg = RuntimeConfig {
        max_iterations: 100,
        ..Default::default()
    };
    let (lo, hi) = ds.mesh.bounds();
    let contact = [
        (lo[0] + hi[0]) as f32 / 2.0,
        (lo[1] + hi[1]) as f32 / 2.0,
        hi[2] as f32,
    ];
    let replay = palpate_link::replay::replay_model_file(
        &model_path,
        cfg,
        contact,
        ds.probe_radius as f32,
        args.haptic_seconds,
    )?;
    Ok(SpecimenLoop {
        report,
        diag_files,
        replay,
    })
}

/// Step 1: fits the simplest model the method offers, linear homogeneous and
/// displacement-based.
fn fit_simplest(ds: &StaticDataset) -> anyhow::Result<(FitInput, FitResult)> {
    // 1. Fit the simplest model the method offers: linear homogeneous, displacement-based.
    log::info!(
        "[1/4] fit: linear homogeneous material, displacement-based inverse (docs/method.md)"
    );
    let input = FitInput::from_dataset(ds)?;
    let o = FitOptions::new(Method::Displacement, Layout::Homogeneous, Sets::Single);
    let fit = fit_static(&input, &o, |_, _| {})?;
    let p = palpate_runtime::material::LambdaAlpha {
        lambda: fit.params[0].lambda[0],
        alpha: fit.params[0].alpha[0],
    };
    log::info!(
        "      E = {:.0} Pa, ν = {:.3}, RMS marker error {} mm ({:.1} s)",
        p.young(),
        p.poisson(),
        mm(fit.rms()),
        fit.seconds
    );
    Ok((input, fit))
}

/// Step 3: exports the simplest and the diagnosed model for the runtime; returns the
/// diagnosed model's path.
fn export_models(
    args: &Args,
    ds: &StaticDataset,
    input: &FitInput,
    fit: &FitResult,
    report: &palpate_diagnose::DiagnosisReport,
) -> anyhow::Result<PathBuf> {
    // 3. Export the fitted model for the runtime.
    log::info!("[3/4] export");
    let prov = ProvenanceInfo {
        tool: format!("palpate {} demo", env!("CARGO_PKG_VERSION")),
        source: format!("{} ({})", ds.name, args.dataset.display()),
        notes: format!(
            "linear homogeneous displacement fit, RMS {:.3e} m",
            fit.rms()
        ),
    };
    let simplest_path = args.out.join("model-simplest.palp");
    let buffers = ModelBuffers::new(
        &input.problem,
        &ds.mesh.node_tags,
        &fit.params,
        &BlendData::None,
        &prov,
    )?;
    let bytes = buffers.write(&simplest_path)?;
    log::info!(
        "      {} ({} bytes): the simplest model",
        simplest_path.display(),
        bytes
    );
    let model_path = args.out.join("model.palp");
    let diagnosed = palpate_diagnose::export::diagnosed_model(report, &prov.tool, &prov.source)?;
    let bytes = diagnosed.write(&model_path)?;
    log::info!(
        "      {} ({} bytes): the diagnosed model (replayed below)",
        model_path.display(),
        bytes
    );
    Ok(model_path)
}

/// The synthetic specimen's part of the README: verdict, before/after table, figures. `root` is
/// the README's folder.
fn specimen_part(
    report: &palpate_diagnose::DiagnosisReport,
    files: &[PathBuf],
    root: &Path,
) -> Part {
    let adopted = palpate_diagnose::model::Candidate::names(&report.adopted, ", ", "");
    let row = |label: String, e: &palpate_diagnose::Errors| {
        vec![
            label,
            mm(e.fitted_rms),
            mm(e.fitted_max),
            mm(e.heldout_rms),
            mm(e.heldout_max),
            format!("{:.4}", e.force_rms),
        ]
    };
    let table = Table {
        caption: format!(
            "Before / after (marker errors in mm; noise floor {} mm)",
            mm(report.noise_floor)
        ),
        header: [
            "model",
            "fitted RMS",
            "fitted max",
            "held-out RMS",
            "held-out max",
            "implied force RMS (N)",
        ]
        .map(String::from)
        .to_vec(),
        rows: vec![
            row("simplest (linear homogeneous)".into(), &report.before),
            row(
                format!(
                    "after diagnosis (+ {})",
                    if adopted.is_empty() {
                        "nothing"
                    } else {
                        &adopted
                    }
                ),
                &report.after,
            ),
        ],
    };
    Part {
        title: format!(
            "A synthetic specimen with known effects ({})",
            report.input.dataset
        ),
        verdict: format!(
            "{}.",
            report
                .residual_check
                .verdict(&palpate_diagnose::model::Candidate::names(
                    &report.adopted,
                    " → ",
                    ""
                ))
        ),
        tables: vec![table],
        notes: Vec::new(),
        report: super::demo_beam::markdown_report(root, files),
        figures: figures_in(root, files),
    }
}
