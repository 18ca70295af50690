//! The viscosity effect: a stand-in for a rate-dependent elastomer strip in a tensile tester,
//! written as tension-test curves in the column format of the real VHB 4910 records
//! (`time_s,displacement_mm,force_N`), one file per stretch rate, so `palpate diagnose` sees it
//! exactly as it would see a new measured record.
//!
//! The truth is the motion fitter's forward model (Real2Sim): a Neo-Hookean strip (eq. 16) with
//! Newtonian viscosity (power law eq. 17 with h = 1) integrated by BDF2, one end clamped, the other
//! driven up to the peak stretch and back at a constant grip speed; the observable is the reaction
//! force on the driven clamp with Gaussian load-cell noise. The magnitude knob is the viscous time
//! τ = ν/μ (s): at stretch rate ε̇ the viscous stress is about 2 τ ε̇ μ, so τ = 2 s makes it ≈ 20 %
//! of the elastic stress at 0.05 1/s and ≈ 4 % at 0.01 1/s — a visible loading/unloading loop that
//! grows with rate, as in the VHB records.

use std::path::Path;

use serde::Serialize;

use super::{rng, to_json, write_file, SpecimenError};
use palpate_motion::model::Material;
use palpate_motion::scenario::{record, tension_bar};

/// Options of a viscous tension specimen.
#[derive(Debug, Clone, Serialize)]
pub struct ViscousOptions {
    /// Viscous time τ = ν/μ (s); 0 makes a purely elastic (Neo-Hookean) strip.
    pub tau: f64,
    /// Shear modulus μ (Pa).
    pub mu: f64,
    /// Poisson ratio of the small-strain limit (sets λ).
    pub poisson: f64,
    /// Strip size (m): width, gauge length (pull axis), thickness.
    pub size: [f64; 3],
    /// Peak nominal stretch of every test.
    pub stretch: f64,
    /// Nominal stretch rates (1/s), one file each.
    pub rates: Vec<f64>,
    /// Time steps per test.
    pub steps: usize,
    /// Load-cell noise, as a fraction of the largest force of the fastest test.
    pub noise: f64,
    /// Random seed of the noise.
    pub seed: u64,
}

impl Default for ViscousOptions {
    fn default() -> Self {
        Self {
            tau: 2.0,
            mu: 3.0e4,
            poisson: 0.45,
            size: [0.01, 0.08, 0.002],
            stretch: 1.5,
            rates: vec![0.05, 0.01],
            steps: 200,
            noise: 0.005,
            seed: 1,
        }
    }
}

/// One test record.
#[derive(Debug, Clone, Serialize)]
pub struct CurveFile {
    /// File name.
    pub name: String,
    /// Stretch rate (1/s).
    pub rate: f64,
    /// Rows (time s, grip displacement mm, force N), noise included.
    pub rows: Vec<[f64; 3]>,
    /// Noise-free forces (N), one per row (t = 0, Δt, …, 2 × peak time).
    pub true_force: Vec<f64>,
}

/// A viscous specimen: the curve files and the options that made them (the truth).
#[derive(Debug, Clone, Serialize)]
pub struct ViscousSpecimen {
    /// Options (the ground truth).
    pub options: ViscousOptions,
    /// Test records.
    pub files: Vec<CurveFile>,
}

impl ViscousOptions {
    fn check(&self) -> Result<(), SpecimenError> {
        let bad = |s: String| Err(SpecimenError::Options(s));
        if !(self.tau.is_finite() && self.tau >= 0.0) {
            return bad(format!("viscosity: τ must be ≥ 0 s, found {}", self.tau));
        }
        if !(self.stretch > 1.0 && self.stretch < 4.0) {
            return bad(format!(
                "viscosity: peak stretch must be in (1, 4), found {}",
                self.stretch
            ));
        }
        if self.rates.is_empty() || self.rates.iter().any(|r| !(r.is_finite() && *r > 0.0)) {
            return bad(format!(
                "viscosity: rates must be > 0 1/s, found {:?}",
                self.rates
            ));
        }
        if self.steps < 20 {
            return bad(format!(
                "viscosity: at least 20 steps per test, found {}",
                self.steps
            ));
        }
        Ok(())
    }
}

/// Half-width (in units of the half period) of the rounded turn at the peak.
const TURN: f64 = 0.05;

/// The grip path as a fraction of the peak elongation, s = t/T_half − 1 ∈ [−1, 1]: a triangle
/// whose turn is rounded by a parabola over |s| < TURN (value and slope continuous), as a real
/// crosshead decelerates; an instant reversal would be an infinite acceleration the BDF2 Newton
/// predictor cannot follow on a purely elastic strip.
fn grip_profile(s: f64) -> f64 {
    let a = s.abs();
    let v = if a < TURN {
        1.0 - (a * a + TURN * TURN) / (2.0 * TURN)
    } else {
        1.0 - a
    };
    v.max(0.0)
}

/// File name of a rate, in the VHB records' style (0.05 → `0d05`).
fn rate_tag(r: f64) -> String {
    format!("{r}").replace('.', "d")
}

/// Simulates the tests.
pub fn generate_viscous(o: &ViscousOptions) -> Result<ViscousSpecimen, SpecimenError> {
    o.check()?;
    let lambda = 2.0 * o.mu * o.poisson / (1.0 - 2.0 * o.poisson);
    let l0 = o.size[1];
    let mut files = Vec::new();
    for (k, &rate) in o.rates.iter().enumerate() {
        let half = (o.stretch - 1.0) / rate;
        let dt = 2.0 * half / o.steps as f64;
        let peak = l0 * (o.stretch - 1.0);
        let elongation = move |t: f64| peak * grip_profile(t / half - 1.0);
        let fail = |e: palpate_motion::MotionError| SpecimenError::Truth {
            measurement: k,
            message: e.to_string(),
        };
        let (mesh, model) =
            tension_bar(o.size, [2, 8, 1], dt, o.steps, &elongation).map_err(fail)?;
        let mat = Material::uniform(mesh.tets.len(), lambda, o.mu, o.tau * o.mu, 1.0, 1000.0);
        let obs = record(&model, &mat, 0.0, o.seed).map_err(fail)?;
        // Reaction force on the driven clamp (index 1) along the pull axis; tension positive.
        let fy: Vec<f64> = obs
            .forces
            .iter()
            .map(|f| f.get(1).copied().flatten().map_or(0.0, |v| v[1]))
            .collect();
        let at_peak = fy[fy.len() / 2];
        let sign = if at_peak < 0.0 { -1.0 } else { 1.0 };
        // `record` reports steps 1..=steps; the test starts from rest (zero force) at t = 0.
        let true_force: Vec<f64> = std::iter::once(0.0)
            .chain(fy.iter().map(|v| sign * v))
            .collect();
        files.push(CurveFile {
            name: format!(
                "uniaxial-loading-unloading__{}_specimen.csv",
                rate_tag(rate)
            ),
            rate,
            rows: Vec::new(),
            true_force,
        });
    }
    // Noise relative to the largest force of all tests, from one seeded stream.
    let fmax = files
        .iter()
        .flat_map(|f| f.true_force.iter())
        .fold(0.0f64, |a, v| a.max(v.abs()));
    let mut rng = rng(o.seed);
    for f in &mut files {
        let half = (o.stretch - 1.0) / f.rate;
        let dt = 2.0 * half / o.steps as f64;
        let peak = l0 * (o.stretch - 1.0);
        f.rows = f
            .true_force
            .iter()
            .enumerate()
            .map(|(n, &force)| {
                let t = n as f64 * dt;
                let d = peak * grip_profile(t / half - 1.0);
                [t, 1e3 * d, force + o.noise * fmax * rng.normal()]
            })
            .collect();
    }
    Ok(ViscousSpecimen {
        options: o.clone(),
        files,
    })
}

impl ViscousSpecimen {
    /// Writes the curve files and `truth.json` (which diagnose never reads) into `dir`.
    pub fn write(&self, dir: &Path) -> Result<(), SpecimenError> {
        for f in &self.files {
            let mut s = String::from("time_s,displacement_mm,force_N\n");
            for r in &f.rows {
                s += &format!("{:.4},{:.6},{:.6e}\n", r[0], r[1], r[2]);
            }
            write_file(&dir.join(&f.name), s.as_bytes())?;
        }
        let truth = serde_json::json!({
            "note": "ground truth of a palpate viscous specimen; never read by the fitter or by diagnose",
            "effect": "viscosity",
            "law": "Neo-Hookean (Real2Sim eq. 16) + Newtonian viscosity (eq. 17, h = 1), BDF2",
            "options": self.options,
            "viscosity_pa_s": self.options.tau * self.options.mu,
            "gauge_length_mm": 1e3 * self.options.size[1],
            "files": self.files.iter().map(|f| serde_json::json!({"name": f.name, "rate": f.rate, "true_force_n": f.true_force})).collect::<Vec<_>>(),
        });
        let file = dir.join("truth.json");
        write_file(&file, to_json(&file, &truth)?.as_bytes())
    }
}
