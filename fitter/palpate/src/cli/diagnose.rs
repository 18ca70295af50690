//! `palpate diagnose <dataset>`: fit the simplest model, trace the residual to the effects the
//! model lacks, adopt those that earn their parameters, and report before/after.

use std::path::PathBuf;

use clap::builder::TypedValueParser as _;

use palpate_diagnose::MeshChoice;

/// Options.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Static, motion or scan dataset directory, or measured curves (CSV file or directory).
    pub dataset: PathBuf,
    /// Output: the report folder written (diagnosis.md, diagnosis.json, evidence plots, model.palp
    /// for the runtime).
    #[arg(
        short = 'o',
        long = "output",
        visible_alias = "out",
        value_name = "DIR",
        default_value = "diagnosis"
    )]
    pub output: PathBuf,
    /// Candidates to try (default: all; for runs of one object all but `hanging-inertia`, whose
    /// declared weights the simplest model moves with their nodes — name it to have the diagnosis
    /// find their mass, the simplest model then holding the weights as forces only).
    #[arg(long, value_delimiter = ',')]
    pub candidates: Vec<String>,
    /// Most effects to adopt (default 3; 4 for runs of one object, whose library holds four
    /// effects that combine).
    #[arg(long)]
    pub max_effects: Option<usize>,
    /// Mesh of static datasets' models: `auto` refines the dataset mesh once when its own
    /// discretisation error is a large part of the noise floor; `dataset`, `refined` force one.
    /// Motion datasets: `auto` measures the mesh's error on the mesh refined once and checks
    /// every adoption against it; `dataset` does neither.
    #[arg(long, default_value = "auto", value_parser = mesh_choice())]
    pub mesh: MeshChoice,
    /// Gauge length L0 in mm of tension-test CSVs (stretch λ = 1 + Δ/L0); fitted if not given
    /// (`--gauge-length` is its older name).
    #[arg(long = "gauge-length-mm", alias = "gauge-length", value_name = "MM")]
    pub gauge_length: Option<f64>,
    /// More runs of the same object (motion datasets on one mesh) fitted together with DATASET.
    #[arg(long, value_delimiter = ',')]
    pub with: Vec<PathBuf>,
    /// Runs held out: predicted from the fit, never fitted (the repeats, or another load).
    /// Given, the runs diagnosis compares its candidates on them.
    #[arg(long, value_delimiter = ',')]
    pub held_out: Vec<PathBuf>,
    /// Poisson's ratio the runs diagnosis holds fixed.
    #[arg(long, default_value_t = 0.49)]
    pub poisson: f64,
    /// Element design of a scan dataset's fits: p2 (quadratic tetrahedra on the mesh's corners;
    /// linear ones lock in bending near incompressibility) or p1 (the mesh's own).
    #[arg(long, default_value = "p2", value_parser = ["p1", "p2"])]
    pub design: String,
    /// Motion datasets and runs of one object: after the diagnosis, refit the final model's
    /// material on quadratic elements of the same mesh (which do not lock in bending) and set
    /// every parameter beside the linear one, with a verdict (docs/diagnose.md, "Mesh
    /// convergence of the motion"). About a minute on the beam's coarse mesh, so not by default.
    #[arg(long)]
    pub motion_convergence: bool,
    /// Fit every open candidate in every round. By default a round first predicts each
    /// candidate's gain by one Gauss–Newton step at the current fit and fits in full only those
    /// ranked first (the others are listed as screened out with their prediction); this turns
    /// that screen off, for a check of what it left unfitted (static, motion and runs).
    #[arg(long)]
    pub full_search: bool,
    /// Figure format.
    #[command(flatten)]
    pub plots: super::output::PlotArgs,
}

/// Parses `--mesh`, listing [`MeshChoice`]'s names as the possible values in `--help`.
fn mesh_choice() -> impl clap::builder::TypedValueParser<Value = MeshChoice> {
    clap::builder::PossibleValuesParser::new(MeshChoice::NAMES).map(|s| {
        s.parse::<MeshChoice>()
            .expect("PossibleValuesParser passes only MeshChoice::NAMES")
    })
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    super::renamed::warn_if_used("--gauge-length", "--gauge-length-mm");
    args.plots.apply();
    // Inputs and flags first, so a typo makes no output folder; then the output, before the
    // diagnosis runs (minutes), not after.
    for p in std::iter::once(&args.dataset)
        .chain(&args.with)
        .chain(&args.held_out)
    {
        if !p.exists() {
            anyhow::bail!(
                "{}: no such file or folder (expected a static, motion or scan dataset \
                 folder, a folder of runs, or a measured curve)",
                p.display()
            );
        }
    }
    if !(args.poisson.is_finite() && args.poisson > -1.0 && args.poisson < 0.5) {
        anyhow::bail!(
            "--poisson {}: expected Poisson's ratio in (−1, 0.5)",
            args.poisson
        );
    }
    if let Some(g) = args.gauge_length.filter(|g| !(g.is_finite() && *g > 0.0)) {
        anyhow::bail!("--gauge-length-mm {g}: expected a finite length > 0 mm");
    }
    super::output::check_writable(&args.output)?;
    let request = palpate_diagnose::run::Request {
        dataset: args.dataset,
        output: args.output,
        candidates: args.candidates,
        max_effects: args.max_effects,
        mesh: args.mesh,
        gauge_length: args.gauge_length,
        more_runs: args.with,
        held_out: args.held_out,
        poisson: Some(args.poisson),
        design: Some(if args.design == "p1" {
            palpate_scan::fit::Design::Linear
        } else {
            palpate_scan::fit::Design::Quadratic
        }),
        motion_convergence: args.motion_convergence,
        full_search: args.full_search,
    };
    // Each input's summary is printed as soon as it is written: a folder of inputs takes minutes
    // per input.
    let progress = super::logging::Progress::start("diagnosing");
    palpate_diagnose::run::run_with(&request, &mut |summary| {
        progress.suspend(|| print!("{summary}"));
        for f in &summary.files {
            log::info!("wrote {}", f.display());
        }
    })?;
    Ok(())
}
