//! `palpate validate --model fit.json <dataset>`: predict a run the model was not fitted to —
//! simulate it from the fitted material without refitting, solve where it should come to rest —
//! and report the marker errors against the capture, next to the naive linear baseline. The last
//! line printed is one JSON object (`final_rms_m`, `trajectory_rms_m`, …) for scripts.

use std::path::PathBuf;

use palpate_motion::validation::validate;

/// Options.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The fitted model: the `fit.json` that `palpate fit-motion -o` or `palpate diagnose` wrote
    /// (a `.palp` is refused: it holds the runtime's linear material only).
    #[arg(long)]
    pub model: PathBuf,
    /// The motion dataset to predict (e.g. from `palpate import c3d`), on the model's mesh.
    pub dataset: PathBuf,
    /// Output: also write the prediction here, a folder with `prediction.csv` (simulated and observed
    /// markers per step) and `tip.svg`/`tip.png` (the markers' displacement along gravity).
    /// The result is printed; nothing is written without it.
    #[arg(
        short = 'o',
        long = "output",
        visible_alias = "out",
        value_name = "DIR"
    )]
    pub output: Option<PathBuf>,
    /// Figure format.
    #[command(flatten)]
    pub plots: super::output::PlotArgs,
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    args.plots.apply();
    let fit = super::model_file::ModelFile::read(&args.model, "validate --model")?
        .into_fit("validate --model")?;
    super::input_kind::expect(
        &args.dataset,
        super::input_kind::Kind::MotionDataset,
        "validate",
    )?;
    // Where the folder will be made is checked now; the folder itself only once there is a
    // prediction to put in it.
    if let Some(out) = &args.output {
        super::output::check_writable(out)?;
    }
    let v = validate(&fit, &args.model, &args.dataset)?;
    print!("{v}");
    if let Some(out) = &args.output {
        for f in v.write(out)? {
            log::info!("wrote {}", f.display());
        }
    }
    println!("{}", v.json());
    Ok(())
}
