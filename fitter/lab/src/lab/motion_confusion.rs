//! `palpate-lab motion-confusion`: motion specimens with one effect each, drawn at random
//! ([`palpate_specimen::motion`]), through the motion diagnosis; the confusion table of what was
//! adopted against what was injected.

use anyhow::Context;
use palpate_diagnose::motion::{diagnose, MotionOptions};
use palpate_specimen::motion::{motion_specimen, MotionEffect, MotionTruth, SIGMA};
use serde::Serialize;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `palpate-lab motion-confusion`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Random draws per effect (seeds 1..=draws).
    #[arg(long, default_value_t = 5)]
    pub draws: u64,
    /// The base motion dataset (the example bar).
    #[arg(long, default_value = "models/motion-example")]
    pub dataset: PathBuf,
    /// Only these effects (names as in the table), e.g. to look at one row with `--log`.
    #[arg(long, value_delimiter = ',')]
    pub effects: Vec<String>,
    /// Print every diagnosis' progress lines.
    #[arg(long)]
    pub log: bool,
    /// Output directory (`motion-confusion.md`, `motion-confusion.json`).
    #[arg(short, long, default_value = "docs/results/diagnose/confusion")]
    pub output: PathBuf,
}

/// One diagnosed specimen.
#[derive(Debug, Serialize)]
struct Row {
    truth: MotionTruth,
    adopted: Vec<String>,
    verdict: String,
    rms_held_before_m: f64,
    rms_held_after_m: f64,
    seconds: f64,
}

impl Row {
    /// The injected effect named (for `none`: nothing adopted).
    fn named(&self) -> bool {
        match self.truth.effect {
            MotionEffect::None => self.adopted.is_empty(),
            // Any viscosity law names a Newtonian damping.
            MotionEffect::Viscosity => self.adopted.iter().any(|a| {
                a == "viscosity" || a == "viscosity-newtonian" || a == "viscosity-objective"
            }),
            e => self.adopted.iter().any(|a| a == e.name()),
        }
    }
    /// The injected effect named first.
    fn first(&self) -> bool {
        match (self.truth.effect, self.adopted.first()) {
            (MotionEffect::None, None) => true,
            (MotionEffect::Viscosity, Some(a)) => a.starts_with("viscosity"),
            (e, Some(a)) => a == e.name(),
            _ => false,
        }
    }
}

/// Runs it.
pub fn run(args: Args) -> anyhow::Result<()> {
    let base = palpate_motion::dataset::load(&args.dataset)
        .with_context(|| format!("reading {}", args.dataset.display()))?;
    // The draws are simulated on the dataset's own mesh: they hold no discretisation error, and
    // the check of each adoption against the mesh's own null (which stands for a truth finer
    // than the mesh) is off for them. Its effect is measured on data made on finer meshes.
    let options = MotionOptions {
        mesh_null: false,
        ..MotionOptions::default()
    };
    let t0 = Instant::now();
    let mut rows = Vec::new();
    for effect in MotionEffect::ALL {
        if !args.effects.is_empty() && !args.effects.iter().any(|e| e == effect.name()) {
            continue;
        }
        for seed in 1..=args.draws {
            let (ds, truth) = motion_specimen(&base, effect, seed)?;
            let label = format!("{}-{seed}", effect.name());
            let t = Instant::now();
            let log = |m: &str| {
                if args.log {
                    eprintln!("  {m}");
                }
            };
            let d = diagnose(&ds, &label, &options, &log)?;
            let row = Row {
                truth,
                adopted: d.adopted.clone(),
                verdict: d.verdict(),
                rms_held_before_m: d.before.rms_held,
                rms_held_after_m: d.after.rms_held,
                seconds: t.elapsed().as_secs_f64(),
            };
            eprintln!(
                "{label}: adopted [{}] ({}; {:.1} s)",
                row.adopted.join(", "),
                if row.named() { "named" } else { "NOT named" },
                row.seconds
            );
            rows.push(row);
        }
    }
    let md = table(&args, &rows, t0.elapsed().as_secs_f64());
    std::fs::create_dir_all(&args.output)?;
    let md_path = args.output.join("motion-confusion.md");
    std::fs::write(&md_path, &md).with_context(|| format!("writing {}", md_path.display()))?;
    let json_path = args.output.join("motion-confusion.json");
    std::fs::write(&json_path, serde_json::to_string_pretty(&rows)?)
        .with_context(|| format!("writing {}", json_path.display()))?;
    print!("{md}");
    eprintln!("wrote {} and {}", md_path.display(), json_path.display());
    Ok(())
}

/// The report: the summary per effect, then every specimen.
fn table(args: &Args, rows: &[Row], seconds: f64) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Motion diagnosis on randomly drawn specimens\n\n    palpate-lab motion-confusion --draws {} \
         --dataset {} -o {}\n\n{} specimens, one effect each ([`palpate_specimen::motion`]: the example \
         bar hung with a 10–30 g weight, moduli, magnitudes and places drawn per seed, σ = {:.0} µm \
         declared), diagnosed with the default options ({:.0} s in all). \"Named\": the injected \
         effect among the adopted (for `none`: nothing adopted); \"first\": adopted first.\n",
        args.draws,
        args.dataset.display(),
        args.output.display(),
        rows.len(),
        1e6 * SIGMA,
        seconds
    );
    let _ = writeln!(s, "| injected | named | first | also adopted (count) |");
    let _ = writeln!(s, "|---|---|---|---|");
    for effect in MotionEffect::ALL {
        let of: Vec<&Row> = rows.iter().filter(|r| r.truth.effect == effect).collect();
        let named = of.iter().filter(|r| r.named()).count();
        let first = of.iter().filter(|r| r.first()).count();
        let mut others: Vec<(String, usize)> = Vec::new();
        for r in &of {
            for a in &r.adopted {
                let own = match effect {
                    MotionEffect::Viscosity => a.starts_with("viscosity"),
                    e => a == e.name(),
                };
                if own {
                    continue;
                }
                match others.iter_mut().find(|(n, _)| n == a) {
                    Some((_, c)) => *c += 1,
                    None => others.push((a.clone(), 1)),
                }
            }
        }
        let others = others
            .iter()
            .map(|(n, c)| format!("{n} ({c})"))
            .collect::<Vec<_>>()
            .join(", ");
        let _ = writeln!(
            s,
            "| {} | {named}/{} | {first}/{} | {} |",
            effect.name(),
            of.len(),
            of.len(),
            if others.is_empty() { "–" } else { &others }
        );
    }
    let _ = writeln!(
        s,
        "\n| specimen | drawn | adopted | held-out RMS before → after (µm) | verdict | s |\n|---|---|---|---|---|---|"
    );
    for r in rows {
        let _ = writeln!(
            s,
            "| {}-{} | μ {:.1} kPa, {:.0} g{}{} | {} | {:.1} → {:.1} | {} | {:.1} |",
            r.truth.effect.name(),
            r.truth.seed,
            1e-3 * r.truth.mu,
            1e3 * r.truth.mass,
            if r.truth.detail.is_empty() { "" } else { "; " },
            r.truth.detail,
            if r.adopted.is_empty() {
                "–".to_string()
            } else {
                r.adopted.join(", ")
            },
            1e6 * r.rms_held_before_m,
            1e6 * r.rms_held_after_m,
            r.verdict.replace('|', "/"),
            r.seconds
        );
    }
    s
}
