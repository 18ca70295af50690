//! `palpate-lab scan-confusion`: the scan diagnosis on strips with one undeclared effect each
//! (`palpate_scan::synthetic`): nothing, a depth bias, a camera moved between the scans, a second
//! material — what it adopts, the moduli, the residual before and after, fitted and held out, as
//! a Markdown table and one JSON line per case.

use std::fmt::Write as _;
use std::path::PathBuf;

use palpate_diagnose::scans::fit::Problem;
use palpate_diagnose::scans::report::{to_json, verdict};
use palpate_diagnose::scans::{diagnose, ScanOptions};
use palpate_scan::dataset::ScanDataset;
use palpate_scan::fit::Design;
use palpate_scan::synthetic::{write_strip_dataset, Injected, StripCase};

/// Options.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Cases: none, depth-bias, depth-scale, camera-moved, second-material.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "none,depth-bias,depth-scale,camera-moved,second-material"
    )]
    pub cases: Vec<String>,
    /// Noise seeds, one dataset per case and seed.
    #[arg(long, value_delimiter = ',', default_value = "1")]
    pub seeds: Vec<u64>,
    /// Cells of the strip's mesh (the truth's and the fit's).
    #[arg(long, value_delimiter = ',', default_value = "8,2,1")]
    pub cells: Vec<usize>,
    /// Element design of the truth and of the fit: p1 or p2.
    #[arg(long, default_value = "p2")]
    pub design: String,
    /// The truth's mesh: the dataset's with each cell split this many times per axis.
    #[arg(long, default_value_t = 1)]
    pub refine: usize,
    /// The mesh's own error: `auto` measures it on the mesh refined once and corrects every
    /// fit; `dataset` does not (for a truth on the dataset's own mesh, which has none).
    #[arg(long, default_value = "auto", value_parser = ["auto", "dataset"])]
    pub mesh: String,
    /// The folder the datasets and reports go into; the table is `confusion.md` in it.
    #[arg(short = 'o', long, default_value = "scan-confusion")]
    pub output: PathBuf,
}

fn injected(name: &str) -> anyhow::Result<Injected> {
    Ok(match name {
        "none" => Injected::None,
        // Three times the depth noise at the strip: well above what the fit resolves.
        "depth-bias" => Injected::DepthBias(0.6e-3),
        // 0.3 %: 0.6 mm at the strip, 0.19–0.23 m from the camera.
        "depth-scale" => Injected::DepthScale(3e-3),
        // A camera on a tripod nudged: a degree and two millimetres.
        "camera-moved" => Injected::CameraMoved {
            angle_deg: 1.0,
            shift_m: [0.002, 0.0, 0.001],
        },
        "second-material" => Injected::SecondMaterial {
            fraction: 0.5,
            ratio: 3.0,
        },
        other => anyhow::bail!(
            "--cases: unknown case {other:?}; expected none, depth-bias, depth-scale, camera-moved or second-material"
        ),
    })
}

/// Runs the cases.
pub fn run(args: Args) -> anyhow::Result<()> {
    let design = match args.design.as_str() {
        "p1" => Design::Linear,
        "p2" => Design::Quadratic,
        other => anyhow::bail!("--design: expected p1 or p2, found {other:?}"),
    };
    let [x, y, z] = args.cells[..] else {
        anyhow::bail!("--cells: expected three counts, found {:?}", args.cells);
    };
    let mut table = String::new();
    let _ = writeln!(
        table,
        "| case | seed | adopted | verdict | E before → after (kPa) | fitted / noise | held out / noise | wall (s) |"
    );
    let _ = writeln!(table, "|---|---|---|---|---|---|---|---|");
    for case in &args.cases {
        let inject = injected(case)?;
        for &seed in &args.seeds {
            let dir = args.output.join(format!("{case}-{seed}"));
            let strip = StripCase {
                cells: [x, y, z],
                design,
                refine: args.refine,
                injected: inject,
                seed,
                ..StripCase::default()
            };
            write_strip_dataset(&dir.join("dataset"), &strip)?;
            let ds = ScanDataset::read(&dir.join("dataset"))?;
            let o = ScanOptions {
                design,
                mesh_error: args.mesh == "auto",
                ..ScanOptions::default()
            };
            let t = std::time::Instant::now();
            let mut problem = Problem::new(&ds, o.design, &o.start_young, o.max_iter)?;
            let d = diagnose(&mut problem, &o)?;
            let wall = t.elapsed().as_secs_f64();
            let name = format!("{case}-{seed}");
            palpate_diagnose::scans::report::write_report(
                &dir.join("diagnosis"),
                &name,
                &problem,
                &d,
            )?;
            let e = |m: &palpate_diagnose::scans::fit::ScanModel| {
                (0..m.fit.mu.len())
                    .map(|k| format!("{:.1}", m.fit.young_modulus(k) / 1e3))
                    .collect::<Vec<_>>()
                    .join(" / ")
            };
            let mut j = to_json(&name, &d);
            j["wall_s"] = wall.into();
            j["case"] = case.clone().into();
            println!("{j}");
            let _ = writeln!(
                table,
                "| {case} | {seed} | {} | {} | {} → {} | {:.2} → {:.2} | {:.2} → {:.2} | {wall:.0} |",
                j["adopted"]
                    .as_array()
                    .map(|a| a
                        .iter()
                        .filter_map(|v| v.as_str())
                        .collect::<Vec<_>>()
                        .join(", "))
                    .filter(|s| !s.is_empty())
                    .unwrap_or_else(|| "—".into()),
                verdict(&d),
                e(&d.before),
                e(&d.after),
                d.before.score.ratio(),
                d.after.score.ratio(),
                d.before_held.ratio(),
                d.after_held.ratio(),
            );
        }
    }
    std::fs::create_dir_all(&args.output)?;
    std::fs::write(args.output.join("confusion.md"), &table)?;
    print!("{table}");
    Ok(())
}
