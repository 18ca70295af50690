//! `palpate specimen`: simulate a stand-in object with undeclared effects and write it as a static
//! dataset (plus `truth.json`, which the fitter and diagnose never read).

use std::path::PathBuf;

use anyhow::Context as _;

use palpate_specimen::{generate, Effect, EffectSpec, SpecimenOptions};

/// Options.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Effects to inject, comma-separated (stiffening, inclusion, soft-layer, calibration,
    /// boundary, registration, gravity, tilt, contact-radius, noise, occlusion, rest-noise), or
    /// `none`; or `viscosity` alone (magnitude: viscous time τ = ν/μ in s, default 2), which writes
    /// tension-test curves at two stretch rates in the VHB records' format instead of a static
    /// dataset.
    #[arg(long, value_delimiter = ',', default_value = "none")]
    pub effect: Vec<String>,
    /// Magnitudes, one per effect in the same order (default: each effect's realistic default).
    #[arg(long, value_delimiter = ',')]
    pub magnitude: Vec<f64>,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Declared marker noise σ (m).
    #[arg(long, default_value_t = 1e-4)]
    pub noise: f64,
    /// Number of probe measurements.
    #[arg(long, default_value_t = 8)]
    pub measurements: usize,
    /// Largest probe force (N).
    #[arg(long, default_value_t = 1.5)]
    pub max_force: f64,
    /// Output dataset directory.
    #[arg(short, long)]
    pub output: PathBuf,
}

/// Parses effect names and magnitudes.
pub fn parse_effects(names: &[String], magnitudes: &[f64]) -> anyhow::Result<Vec<EffectSpec>> {
    let names: Vec<&str> = names
        .iter()
        .map(|s| s.trim())
        .filter(|s| !s.is_empty() && *s != "none")
        .collect();
    if !magnitudes.is_empty() && magnitudes.len() != names.len() {
        anyhow::bail!(
            "--magnitude has {} values but --effect names {} effects",
            magnitudes.len(),
            names.len()
        );
    }
    names
        .iter()
        .enumerate()
        .map(|(k, n)| {
            let effect = Effect::parse(n)?;
            Ok(EffectSpec {
                effect,
                magnitude: magnitudes
                    .get(k)
                    .copied()
                    .unwrap_or(effect.default_magnitude()),
            })
        })
        .collect()
}

/// Runs the generator.
pub fn run(args: Args) -> anyhow::Result<()> {
    if args.effect.iter().any(|e| e.trim() == "viscosity") {
        return run_viscous(&args);
    }
    let effects = parse_effects(&args.effect, &args.magnitude)?;
    let o = SpecimenOptions {
        seed: args.seed,
        noise: args.noise,
        measurements: args.measurements,
        max_force: args.max_force,
        effects,
        ..Default::default()
    };
    let s = generate(&o)?;
    s.write(&args.output)
        .with_context(|| format!("writing {}", args.output.display()))?;
    println!(
        "specimen written to {} ({} measurements, {} markers, truth mesh {} nodes / {} tets; ground truth in truth.json)",
        args.output.display(),
        s.dataset.measurements.len(),
        s.dataset.markers.len(),
        s.truth.truth_mesh[0],
        s.truth.truth_mesh[1]
    );
    Ok(())
}

/// `--effect viscosity`: tension-test curves of a visco-elastic strip (see
/// [`palpate_specimen::viscous`]).
fn run_viscous(args: &Args) -> anyhow::Result<()> {
    use palpate_specimen::viscous::{generate_viscous, ViscousOptions};
    let others: Vec<&String> = args
        .effect
        .iter()
        .filter(|e| !matches!(e.trim(), "viscosity" | "none" | ""))
        .collect();
    if !others.is_empty() {
        anyhow::bail!(
            "viscosity writes tension-test curves, not a static contact dataset; it cannot be combined with {:?}",
            others
        );
    }
    if args.magnitude.len() > 1 {
        anyhow::bail!(
            "--magnitude has {} values but --effect names 1 effect",
            args.magnitude.len()
        );
    }
    let mut o = ViscousOptions {
        seed: args.seed,
        ..Default::default()
    };
    if let Some(&m) = args.magnitude.first() {
        o.tau = m;
    }
    let s = generate_viscous(&o)?;
    s.write(&args.output)
        .with_context(|| format!("writing {}", args.output.display()))?;
    println!(
        "viscous specimen written to {}: {} tension tests (rates {:?} 1/s, peak stretch {}, τ = {} s); ground truth in truth.json",
        args.output.display(),
        s.files.len(),
        o.rates,
        o.stretch,
        o.tau
    );
    Ok(())
}
