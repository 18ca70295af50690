//! The specimen generator of issue 6: a stand-in for a real object, simulated at higher fidelity
//! than the model the fitter uses (a finer mesh, Neo-Hookean with optional strain stiffening via
//! [`palpate_motion::statics::solve_static`], so large strains are non-linear), with physical effects
//! nobody declared, written as a STATIC dataset ([`palpate_fem::dataset::StaticDataset::write`]).
//!
//! The ground truth (material, effects with magnitudes, noise-free marker positions) is written to
//! `truth.json` next to the dataset. The fitter and `palpate diagnose` never read it: it exists so
//! evidence runs can score what diagnose names against what was injected.
//!
//! - [`effect`]: the effect library ([`Effect`]) with magnitude knobs and their defaults;
//! - [`generate`]: the simulation ([`generate::generate`]).

pub mod effect;
pub mod generate;
pub mod signal;
pub mod viscous;

pub use effect::{Effect, EffectSpec};
pub use generate::{generate, Specimen, SpecimenOptions, Truth};
pub use signal::signal_rms;

/// Errors of the specimen generator.
#[derive(Debug, thiserror::Error)]
pub enum SpecimenError {
    /// An effect name was not recognised.
    #[error("unknown effect {name:?}; known effects: {known}")]
    UnknownEffect {
        /// What was given.
        name: String,
        /// Comma-separated known names.
        known: String,
    },
    /// A magnitude is not finite or out of its range.
    #[error("effect {effect}: magnitude {value} is not allowed ({why})")]
    Magnitude {
        /// Effect name.
        effect: &'static str,
        /// Given magnitude.
        value: f64,
        /// Why.
        why: &'static str,
    },
    /// Options are inconsistent.
    #[error("{0}")]
    Options(String),
    /// The linear forward model (used for the contact rule on the fine mesh) failed.
    #[error("contact load on the truth mesh: {0}")]
    Forward(#[from] palpate_fem::forward::ForwardError),
    /// The hyperelastic solve failed.
    #[error("Neo-Hookean truth solve of measurement {measurement}: {message}")]
    Truth {
        /// Measurement index.
        measurement: usize,
        /// Solver message.
        message: String,
    },
    /// A marker could not be embedded.
    #[error("marker {marker} at {point:?} could not be embedded in the {mesh} mesh surface")]
    Embed {
        /// Marker index.
        marker: usize,
        /// Its rest position.
        point: [f64; 3],
        /// Which mesh.
        mesh: &'static str,
    },
}

/// A small deterministic generator (SplitMix64) with Gaussian samples (Box–Muller); own copy so
/// the specimen stream stays fixed whatever other modules do with theirs.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// Seeded generator.
    pub fn new(seed: u64) -> Self {
        Self(seed ^ 0x5EED_0006_D1A6_0005)
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Standard normal sample.
    pub fn normal(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}
