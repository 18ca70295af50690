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
    /// Output: the dataset folder written.
    #[arg(
        short = 'o',
        long = "output",
        visible_alias = "out",
        value_name = "DIR",
        default_value = "specimen"
    )]
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

/// The most probe measurements of one specimen: each is a non-linear static solve of the truth
/// mesh, so a million of them never returns, and the diagnosis is tested on 8 to a few dozen.
pub const MAX_MEASUREMENTS: usize = 1000;

/// The largest magnitude of an effect: beyond it the truth material or load overflows the
/// solver (an inclusion 1e300 times stiffer than its block) instead of making a specimen.
pub const MAX_MAGNITUDE: f64 = 1000.0;

/// The largest declared noise, as a fraction of the block's smallest side: noise that large is
/// not noise on this object any more.
pub const MAX_NOISE_FRACTION: f64 = 0.1;

/// Checks the flags before any work and before the output folder is made.
fn check_args(args: &Args) -> anyhow::Result<()> {
    if !(1..=MAX_MEASUREMENTS).contains(&args.measurements) {
        anyhow::bail!(
            "--measurements {}: expected 1 to {MAX_MEASUREMENTS} (each is a non-linear static \
             solve of the truth mesh)",
            args.measurements
        );
    }
    let size = SpecimenOptions::default().size;
    let smallest = size.iter().copied().fold(f64::INFINITY, f64::min);
    let max_noise = MAX_NOISE_FRACTION * smallest;
    if !(args.noise.is_finite() && args.noise >= 0.0 && args.noise <= max_noise) {
        anyhow::bail!(
            "--noise {}: expected a marker noise σ from 0 to {max_noise} m ({MAX_NOISE_FRACTION} \
             × the specimen's smallest side {smallest} m; the block is {} × {} × {} m)",
            palpate_fem::sanity::show(args.noise),
            size[0],
            size[1],
            size[2]
        );
    }
    if !(args.max_force.is_finite() && args.max_force > 0.0 && args.max_force <= 1e3) {
        anyhow::bail!(
            "--max-force {}: expected a probe force in (0, 1000] N",
            palpate_fem::sanity::show(args.max_force)
        );
    }
    for m in &args.magnitude {
        if !(m.is_finite() && m.abs() <= MAX_MAGNITUDE) {
            anyhow::bail!(
                "--magnitude {}: expected a finite magnitude of at most {MAX_MAGNITUDE} in size \
                 (the effects' units are in `palpate specimen --help`)",
                palpate_fem::sanity::show(*m)
            );
        }
    }
    // The staging folder goes beside the output: that is where files must be creatable.
    super::output::check_writable(&args.output)?;
    Ok(())
}

/// Runs the generator.
pub fn run(args: Args) -> anyhow::Result<()> {
    check_args(&args)?;
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
    // Written beside its place and swapped in: a failure leaves the previous folder whole.
    let staged = super::output::Staged::new(&args.output)?;
    s.write(&staged.path)
        .with_context(|| format!("writing {}", args.output.display()))?;
    staged.commit(Vec::new())?;
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
    if !(o.tau.is_finite() && o.tau > 0.0) {
        anyhow::bail!(
            "--magnitude {}: the viscous time τ must be finite and > 0 s",
            o.tau
        );
    }
    let s = generate_viscous(&o)?;
    let staged = super::output::Staged::new(&args.output)?;
    s.write(&staged.path)
        .with_context(|| format!("writing {}", args.output.display()))?;
    staged.commit(Vec::new())?;
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
