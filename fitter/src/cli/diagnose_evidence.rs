//! `palpate diagnose-evidence`: every specimen effect (and none) × seeds through `diagnose`;
//! writes the confusion table (effect injected × effect named) to
//! `docs/results/diagnose/confusion.md` and the per-run figures to `confusion.json`.

use std::fmt::Write as _;
use std::path::PathBuf;

use serde::Serialize;

use crate::diagnose::model::{Candidate, ALL_CANDIDATES};
use crate::diagnose::{run_diagnosis, DiagnoseOptions};
use crate::io::atomic::write_atomic;
use crate::specimen::effect::ALL_EFFECTS;
use crate::specimen::{generate, Effect, EffectSpec, SpecimenOptions};

/// Options.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Seeds per effect.
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    pub seeds: Vec<u64>,
    /// Output directory.
    #[arg(short, long, default_value = "docs/results/diagnose")]
    pub output: PathBuf,
}

/// The candidates that correctly explain an injected effect, the specific one first (empty:
/// nothing should be adopted — noise and occlusions change no mean behaviour). The issue names
/// "inhomogeneity (a stiff inclusion, a soft layer)" as one effect, so the general
/// inhomogeneity field counts as naming either.
pub fn expected(e: Option<Effect>) -> Vec<Candidate> {
    match e {
        None => Vec::new(),
        Some(e) => match e {
            Effect::Stiffening => vec![Candidate::Stiffening],
            Effect::Inclusion => vec![Candidate::Inclusion, Candidate::Inhomogeneity],
            Effect::SoftLayer => vec![Candidate::Layer, Candidate::Inhomogeneity],
            Effect::Calibration => vec![Candidate::Calibration],
            Effect::Boundary => vec![Candidate::Boundary],
            Effect::Registration => vec![Candidate::Registration],
            Effect::Gravity => vec![Candidate::Gravity],
            Effect::Tilt => vec![Candidate::Tilt],
            Effect::Noise | Effect::Occlusion => Vec::new(),
        },
    }
}

/// Whether a first adopted candidate (None = clean) is a correct answer for `e`.
fn is_correct(e: Option<Effect>, first: Option<Candidate>) -> bool {
    let want = expected(e);
    match first {
        None => want.is_empty(),
        Some(c) => want.contains(&c),
    }
}

#[derive(Debug, Serialize)]
struct Run {
    injected: String,
    magnitude: f64,
    seed: u64,
    adopted: Vec<Candidate>,
    correct: bool,
    rms_before_um: f64,
    rms_after_um: f64,
    heldout_before_um: f64,
    heldout_after_um: f64,
    floor_um: f64,
    within_1_5_floor: bool,
    seconds: f64,
}

/// Runs the evidence.
pub fn run(args: Args) -> anyhow::Result<()> {
    let mut runs = Vec::new();
    let mut failures: Vec<String> = Vec::new();
    let injected: Vec<Option<Effect>> = std::iter::once(None)
        .chain(ALL_EFFECTS.iter().copied().map(Some))
        .collect();
    for &e in &injected {
        for &seed in &args.seeds {
            let effects = e
                .map(|e| {
                    vec![EffectSpec {
                        effect: e,
                        magnitude: e.default_magnitude(),
                    }]
                })
                .unwrap_or_default();
            let outcome = generate(&SpecimenOptions {
                seed,
                effects,
                ..Default::default()
            })
            .map_err(anyhow::Error::from)
            .and_then(|s| {
                run_diagnosis(&s.dataset, &DiagnoseOptions::default()).map_err(anyhow::Error::from)
            });
            let r = match outcome {
                Ok(r) => r,
                Err(err) => {
                    println!(
                        "{:<13} seed {seed}: FAILED: {err:#}",
                        e.map_or("none", |e| e.name())
                    );
                    failures.push(format!(
                        "{} seed {seed}: {err:#}",
                        e.map_or("none", |e| e.name())
                    ));
                    continue;
                }
            };
            let run = Run {
                injected: e.map_or("none", |e| e.name()).into(),
                magnitude: e.map_or(0.0, |e| e.default_magnitude()),
                seed,
                correct: is_correct(e, r.adopted.first().copied()),
                adopted: r.adopted.clone(),
                rms_before_um: 1e6 * r.before.fitted_rms,
                rms_after_um: 1e6 * r.after.fitted_rms,
                heldout_before_um: 1e6 * r.before.heldout_rms,
                heldout_after_um: 1e6 * r.after.heldout_rms,
                floor_um: 1e6 * r.noise_floor,
                within_1_5_floor: r.after.fitted_rms <= 1.5 * r.noise_floor,
                seconds: r.seconds,
            };
            println!(
                "{:<13} seed {seed}: adopted {:<40} RMS {:7.1} → {:7.1} µm, held out {:7.1} → {:7.1} µm, floor {:.1} µm ({:.1} s)",
                run.injected,
                format!("{:?}", run.adopted.iter().map(|c| c.name()).collect::<Vec<_>>()),
                run.rms_before_um,
                run.rms_after_um,
                run.heldout_before_um,
                run.heldout_after_um,
                run.floor_um,
                run.seconds
            );
            runs.push(run);
            write_tables(&args, &injected, &runs, &failures)?;
        }
    }
    write_tables(&args, &injected, &runs, &failures)?;
    let correct = runs.iter().filter(|r| r.correct).count();
    println!(
        "{correct}/{} correct; wrote {}",
        runs.len(),
        args.output.join("confusion.md").display()
    );
    Ok(())
}

fn write_tables(
    args: &Args,
    injected: &[Option<Effect>],
    runs: &[Run],
    failures: &[String],
) -> anyhow::Result<()> {
    let mut md = String::new();
    let _ = writeln!(md, "# diagnose confusion table\n");
    let _ = writeln!(md, "Produced by `palpate diagnose-evidence --seeds {}` (specimen defaults: 8×8×4 cm block, dataset mesh 6×6×3 cells, Neo-Hookean truth on a 2× finer mesh, E = 20 kPa, ν = 0.35, 8 contacts of 0.375–1.5 N, σ = 100 µm declared → noise floor σ√3 = 173.2 µm). Rows: effect injected (default magnitude); columns: first effect diagnose adopted, counted over seeds.\n",
        args.seeds.iter().map(|s| s.to_string()).collect::<Vec<_>>().join(","));
    let cols: Vec<Option<Candidate>> = std::iter::once(None)
        .chain(ALL_CANDIDATES.iter().copied().map(Some))
        .collect();
    let _ = writeln!(
        md,
        "| injected \\ named | {} |",
        cols.iter()
            .map(|c| c.map_or("none", |c| c.name()))
            .collect::<Vec<_>>()
            .join(" | ")
    );
    let _ = writeln!(md, "|---|{}", "---|".repeat(cols.len()));
    for &e in injected {
        let name = e.map_or("none", |e| e.name());
        let cells: Vec<String> = cols
            .iter()
            .map(|&c| {
                let n = runs
                    .iter()
                    .filter(|r| r.injected == name && r.adopted.first().copied() == c)
                    .count();
                if n == 0 {
                    "·".into()
                } else if is_correct(e, c) {
                    format!("**{n}**")
                } else {
                    n.to_string()
                }
            })
            .collect();
        let _ = writeln!(md, "| {name} | {} |", cells.join(" | "));
    }
    let correct = runs.iter().filter(|r| r.correct).count();
    let _ = writeln!(md, "\nCorrect first choice: {correct}/{} runs (bold = a correct column: the specific candidate, or for inclusion and soft layer also the general inhomogeneity field — the issue's \"inhomogeneity (a stiff inclusion, a soft layer)\"; noise and occlusion are expected to stay clean).\n", runs.len());
    let _ = writeln!(md, "| injected | magnitude | seed | adopted | RMS before µm | RMS after µm | held-out before µm | held-out after µm | after ≤ 1.5 floor | s |\n|---|---|---|---|---|---|---|---|---|---|");
    for r in runs {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {} | {:.1} |",
            r.injected,
            r.magnitude,
            r.seed,
            if r.adopted.is_empty() {
                "none".into()
            } else {
                r.adopted
                    .iter()
                    .map(|c| c.name())
                    .collect::<Vec<_>>()
                    .join(" → ")
            },
            r.rms_before_um,
            r.rms_after_um,
            r.heldout_before_um,
            r.heldout_after_um,
            if r.within_1_5_floor { "yes" } else { "no" },
            r.seconds
        );
    }
    for f in failures {
        let _ = writeln!(md, "\nFailed run: {f}");
    }
    std::fs::create_dir_all(&args.output)?;
    write_atomic(&args.output.join("confusion.md"), md.as_bytes())?;
    write_atomic(
        &args.output.join("confusion.json"),
        serde_json::to_string_pretty(&runs)?.as_bytes(),
    )?;
    println!(
        "{correct}/{} correct; wrote {}",
        runs.len(),
        args.output.join("confusion.md").display()
    );
    Ok(())
}
