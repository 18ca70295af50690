//! `palpate validate --model fit.json <dataset>`: predict a run the model was not fitted to —
//! simulate it from the fitted material without refitting, solve where it should come to rest —
//! and report the marker errors against the capture, next to the naive linear baseline. The last
//! line printed is one JSON object (`final_rms_m`, `trajectory_rms_m`, …) for scripts.

use std::path::PathBuf;

use anyhow::Context;
use palpate_motion::predict;

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
    let mut ds = palpate_motion::dataset::load(&args.dataset)?;
    if fit.hanging_inertia {
        palpate_motion::fitted::set_hanging_inertia(&mut ds.model, true);
    }
    anyhow::ensure!(
        ds.mesh.nodes.len() == fit.nodes && ds.mesh.tets.len() == fit.tets,
        "{}: its mesh has {} nodes and {} tets, the model's {} and {}: a model predicts runs on \
         the mesh it was fitted on",
        args.dataset.display(),
        ds.mesh.nodes.len(),
        ds.mesh.tets.len(),
        fit.nodes,
        fit.tets
    );
    let mat = fit
        .material()
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.model.display()))?;
    // A model fitted with per-run time offsets predicts a new capture at its own offset (its
    // release instant is its own), scanned with the fitted material — never refitted.
    let offset = if fit.time_offset {
        palpate_motion::time_offset::scan(&ds.model, &mat, &ds.obs)
            .with_context(|| format!("scanning the time offset of {}", args.dataset.display()))?
            .0
    } else {
        0
    };
    let p = predict::predict_offset(&ds.model, &mat, &ds.obs, offset)
        .with_context(|| format!("simulating {}", args.dataset.display()))?;
    if fit.time_offset {
        println!(
            "time offset of this run (the model was fitted with one per run): {:+.1} ms, scanned over ±{} capture frames (±{} at most)",
            1e3 * offset as f64 * ds.model.dt,
            palpate_motion::time_offset::SCAN_FRAMES,
            palpate_motion::time_offset::MAX_SCAN_FRAMES
        );
    }
    let load = predict::load_along_gravity(&ds.model);
    // The baseline by marker name: the fitted runs may list the markers in another order.
    let names: Vec<String> = ds.model.markers.iter().map(|m| m.name.clone()).collect();
    let fitted_runs: Vec<(f64, Vec<Option<[f64; 3]>>)> = fit
        .runs
        .iter()
        .map(|r| {
            let by_name = names
                .iter()
                .map(|n| {
                    r.markers
                        .iter()
                        .position(|m| m == n)
                        .and_then(|i| r.final_displacement_m.get(i).copied().flatten())
                })
                .collect();
            (r.load_n, by_name)
        })
        .collect();
    let baseline_final_rms_m = predict::baseline_rest_rms(&fitted_runs, &ds.model, &ds.obs);
    println!(
        "validate {} with {} (fitted on {}): {} steps of {} s, {} markers, dead load {:.4} N along gravity",
        args.dataset.display(),
        args.model.display(),
        fit.datasets.join(", "),
        ds.model.steps,
        ds.model.dt,
        names.len(),
        load
    );
    println!("| marker | trajectory RMS (mm) | final rest error (mm) |\n|---|---|---|");
    for m in &p.markers {
        println!(
            "| {} | {:.3} | {} |",
            m.name,
            1e3 * m.trajectory_rms_m,
            m.final_m
                .map(|e| format!("{:.3}", 1e3 * e))
                .unwrap_or_else(|| "unseen".into())
        );
    }
    println!(
        "| all | {:.3} (max {:.3}) | {:.3} (max {:.3}) |",
        1e3 * p.trajectory_rms_m,
        1e3 * p.trajectory_max_m,
        1e3 * p.final_rms_m,
        1e3 * p.final_max_m
    );
    match baseline_final_rms_m {
        Some(b) => println!(
            "baseline (final displacements linear in the load through the {} fitted runs): final RMS {:.3} mm",
            fit.runs.len(),
            1e3 * b
        ),
        None => println!(
            "baseline: not available (the fitted runs do not span two different loads)"
        ),
    }
    if let Some(out) = &args.output {
        write_outputs(out, &ds, &p)?;
    }
    // Read by scripts (and an external checker): `final_rms_m` and `trajectory_rms_m` keep
    // their names.
    let json = serde_json::json!({
        "schema_version": 1,
        "kind": "validation",
        "dataset": args.dataset.display().to_string(),
        "model": args.model.display().to_string(),
        "final_rms_m": p.final_rms_m,
        "final_max_m": p.final_max_m,
        "trajectory_rms_m": p.trajectory_rms_m,
        "trajectory_max_m": p.trajectory_max_m,
        "baseline_final_rms_m": baseline_final_rms_m,
        "load_n": load,
        "steps": ds.model.steps,
        "dt_s": ds.model.dt,
        "time_offset_s": offset as f64 * ds.model.dt,
    });
    println!("{json}");
    Ok(())
}

/// `prediction.csv` and the displacement-along-gravity plots.
fn write_outputs(
    out: &std::path::Path,
    ds: &palpate_motion::dataset::MotionDataset,
    p: &predict::Prediction,
) -> anyhow::Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let mut csv = String::from("t,marker,sim_x,sim_y,sim_z,obs_x,obs_y,obs_z\n");
    for (n, row) in p.simulated.iter().enumerate() {
        for (i, m) in ds.model.markers.iter().enumerate() {
            let s = row[i];
            let o = ds.obs.markers[n][i];
            let o = o
                .map(|o| format!("{},{},{}", o[0], o[1], o[2]))
                .unwrap_or_else(|| ",,".into());
            csv.push_str(&format!(
                "{},{},{},{},{},{o}\n",
                (n + 1) as f64 * ds.model.dt,
                m.name,
                s[0],
                s[1],
                s[2]
            ));
        }
    }
    let file = out.join("prediction.csv");
    palpate_fem::io::atomic::write_atomic(&file, csv.as_bytes())?;
    log::info!("wrote {}", file.display());
    // Displacement along gravity of the marker that moves most (the tip), measured and simulated.
    let g = ds.model.gravity;
    let gn = g.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
    let rest = predict::rest_markers(&ds.model);
    let along =
        |p: &[f64; 3], i: usize| (0..3).map(|k| (p[k] - rest[i][k]) * g[k] / gn).sum::<f64>();
    let tip = (0..rest.len())
        .max_by(|&a, &b| {
            let d = |i: usize| {
                p.equilibrium
                    .get(i)
                    .map(|q| along(q, i).abs())
                    .unwrap_or(0.0)
            };
            d(a).total_cmp(&d(b))
        })
        .unwrap_or(0);
    let sim: Vec<(f64, f64)> = p
        .simulated
        .iter()
        .enumerate()
        .map(|(n, r)| ((n + 1) as f64 * ds.model.dt, 1e3 * along(&r[tip], tip)))
        .collect();
    let obs: Vec<(f64, f64)> = ds
        .obs
        .markers
        .iter()
        .enumerate()
        .filter_map(|(n, r)| r[tip].map(|o| ((n + 1) as f64 * ds.model.dt, 1e3 * along(&o, tip))))
        .collect();
    let eq = [
        (0.0, 1e3 * along(&p.equilibrium[tip], tip)),
        (
            ds.model.steps as f64 * ds.model.dt,
            1e3 * along(&p.equilibrium[tip], tip),
        ),
    ];
    let name = &ds.model.markers[tip].name;
    let title = format!("Marker {name}: displacement along gravity");
    // `tip.svg` and `tip.png`, as --plot-format says.
    {
        let written = palpate_plot::lines(
            out.join("tip.svg"),
            &title,
            "time after release (s)",
            "displacement along gravity (mm)",
            &[
                palpate_plot::Series::new("measured", &obs, palpate_plot::Style::Points),
                palpate_plot::Series::new("simulated", &sim, palpate_plot::Style::Line),
                palpate_plot::Series::new("predicted rest", &eq, palpate_plot::Style::Line),
            ],
        )?;
        for f in written {
            log::info!("wrote {}", f.display());
        }
    }
    Ok(())
}
