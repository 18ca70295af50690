//! Motion specimens with one undeclared effect each, drawn at random ("generality as a
//! test, not a hope", the motion half): the diagnosis is run on many of them and its adoptions
//! scored against what was injected (`palpate-lab motion-confusion`).
//!
//! Every specimen is the bundled example bar (`models/motion-example`: a 2 × 8 × 2 cm bar of 24
//! tets whose front face is shaken) hung with a weight at its far end's top edge, so it bends well
//! past the small strains of the bare bar, recorded by the motion fitter's own forward model
//! (Neo-Hookean eq. 16, eq. 17 viscosity, BDF2) with marker noise σ = 20 µm, declared. What is
//! drawn per specimen: the moduli (λ = 2μ, μ log-uniform in 7–14 kPa), the weight (10–30 g; it
//! moves with its nodes, and the dataset says so: the single-run diagnosis has no inertia
//! candidate), and the effect's magnitude and place:
//!
//! | effect | drawn |
//! |---|---|
//! | none | — |
//! | viscosity | Newtonian, viscous time ν/μ log-uniform in 0.5–3 Δt |
//! | stiffening | c (Ī₁ − 3)², c log-uniform in 2–8 μ |
//! | two-material | the bar cut across its length at 30–70 %, one side 2–4× stiffer or softer (μ) |
//! | marker-offsets | every marker 0.2–0.6 mm off its declared place, in a random direction |
//! | time-offset | the markers recorded 1–3 steps late or early against the base's record |
//! | clamp-compliance | the elements at the shaken face softened as a whole (λ and μ) to 0.15–0.5× |
//! | gravity-direction | the gravity turned by 2–6° (log-uniform) toward a random direction across it, the declared one kept |
//!
//! The truth is palpate's own simulator: this tests the diagnosis' search and selection, not
//! the model class (the independent generators of `tests/generators/` do that).

use palpate_fem::rng::SplitMix64;
use palpate_motion::dataset::MotionDataset;
use palpate_motion::model::{DeadLoad, Material, Model, Observations, ParamKind};
use palpate_motion::scenario::{record, Gauss};
use palpate_motion::MotionError;
use serde::Serialize;

/// Marker noise of every motion specimen (m per coordinate).
pub const SIGMA: f64 = 2e-5;

/// An effect injected into a motion specimen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum MotionEffect {
    /// Nothing beyond the simplest model (Neo-Hookean, no viscosity).
    None,
    /// Newtonian viscosity.
    Viscosity,
    /// A Yeoh-type stiffening term.
    Stiffening,
    /// Two materials on either side of a cut across the bar.
    TwoMaterial,
    /// Markers off their declared places.
    MarkerOffsets,
    /// Markers recorded out of step with the base.
    TimeOffset,
    /// The clamp gives: the elements at the clamped face softer, both moduli by one factor.
    ClampCompliance,
    /// The gravity acts along another direction than the declared one.
    GravityDirection,
}

impl MotionEffect {
    /// Every effect, in table order.
    pub const ALL: [MotionEffect; 8] = [
        Self::None,
        Self::Viscosity,
        Self::Stiffening,
        Self::TwoMaterial,
        Self::MarkerOffsets,
        Self::TimeOffset,
        Self::ClampCompliance,
        Self::GravityDirection,
    ];

    /// The name of the diagnosis' candidate that is this effect (`None`: nothing to name).
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Viscosity => "viscosity",
            Self::Stiffening => "stiffening",
            Self::TwoMaterial => "two-material",
            Self::MarkerOffsets => "marker-offsets",
            Self::TimeOffset => "time-offset",
            Self::ClampCompliance => "clamp-compliance",
            Self::GravityDirection => "gravity-direction",
        }
    }
}

/// What was injected, for scoring (the diagnosis never reads it).
#[derive(Debug, Clone, Serialize)]
pub struct MotionTruth {
    /// The effect.
    pub effect: MotionEffect,
    /// The seed it was drawn from.
    pub seed: u64,
    /// Shear modulus μ outside any second material (Pa); λ = 2μ.
    pub mu: f64,
    /// The hung weight (kg).
    pub mass: f64,
    /// The effect's magnitude and place in words.
    pub detail: String,
}

/// Draws a specimen of `effect` from `seed` on the example dataset `base` (its mesh, clamps, base
/// motion and markers; its observations are replaced).
pub fn motion_specimen(
    base: &MotionDataset,
    effect: MotionEffect,
    seed: u64,
) -> Result<(MotionDataset, MotionTruth), MotionError> {
    let mut rng = SplitMix64::new(seed.wrapping_mul(0x9E37_79B9).wrapping_add(17));
    let log_uniform = |rng: &mut SplitMix64, lo: f64, hi: f64| {
        (lo.ln() + rng.uniform() * (hi.ln() - lo.ln())).exp()
    };
    let mut ds = base.clone();
    let mu = log_uniform(&mut rng, 7e3, 1.4e4);
    let mass = 0.01 + 0.02 * rng.uniform();
    ds.model.loads = vec![hung_weight(&ds, mass)?];
    let ne = ds.model.tets.len();
    let density = ds.config.density.unwrap_or(1000.0);
    let mut truth = Material::uniform(ne, 2.0 * mu, mu, 0.0, 1.0, density);
    let mut late = 0i64;
    let mut offsets: Vec<[f64; 3]> = Vec::new();
    let detail = match effect {
        MotionEffect::None => String::new(),
        MotionEffect::Viscosity => {
            let tau = log_uniform(&mut rng, 0.5, 3.0);
            truth.set_uniform(ParamKind::Nu, tau * ds.model.dt * mu);
            format!("ν/μ = {tau:.2} Δt (Newtonian)")
        }
        MotionEffect::Stiffening => {
            let k = log_uniform(&mut rng, 2.0, 8.0);
            truth.set_uniform(ParamKind::Stiffening, k * mu);
            format!("c = {k:.2} μ")
        }
        MotionEffect::TwoMaterial => {
            let (axis, lo, hi) = long_axis(&ds.model);
            let cut = lo + (0.3 + 0.4 * rng.uniform()) * (hi - lo);
            let near = rng.uniform() < 0.5;
            let contrast = log_uniform(&mut rng, 2.0, 4.0);
            let factor = if rng.uniform() < 0.5 {
                contrast
            } else {
                1.0 / contrast
            };
            let m = &ds.model;
            for e in 0..ne {
                let c = m.tets[e].iter().map(|&n| m.nodes[n][axis]).sum::<f64>() / 4.0;
                if (c < cut) == near {
                    truth.values[ParamKind::Mu as usize][e] = factor * mu;
                }
            }
            format!(
                "μ × {factor:.2} where {} {:.1} mm (of {:.1}–{:.1})",
                if near { "below" } else { "above" },
                1e3 * cut,
                1e3 * lo,
                1e3 * hi
            )
        }
        MotionEffect::MarkerOffsets => {
            let mut g = Gauss::new(seed + 7);
            offsets = (0..ds.model.markers.len())
                .map(|_| {
                    let d = [g.next(), g.next(), g.next()];
                    let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-12);
                    let r = 2e-4 + 4e-4 * rng.uniform();
                    d.map(|v| r * v / n)
                })
                .collect();
            "0.2–0.6 mm per marker".into()
        }
        MotionEffect::TimeOffset => {
            let steps = 1 + (3.0 * rng.uniform()) as i64;
            late = if rng.uniform() < 0.5 { steps } else { -steps };
            format!("{late:+} steps")
        }
        MotionEffect::ClampCompliance => {
            let factor = log_uniform(&mut rng, 0.15, 0.5);
            let layer = ds.model.clamp_layer();
            for &e in &layer {
                for k in [ParamKind::Lambda, ParamKind::Mu] {
                    truth.values[k as usize][e] *= factor;
                }
            }
            format!(
                "λ and μ × {factor:.2} in the {} elements at the clamp",
                layer.len()
            )
        }
        MotionEffect::GravityDirection => {
            let angle = log_uniform(&mut rng, 2.0, 6.0);
            let toward = std::f64::consts::TAU * rng.uniform();
            let tan = angle.to_radians().tan();
            let turn = [tan * toward.cos(), tan * toward.sin()];
            for (k, z) in ParamKind::GRAVITY.into_iter().zip(turn) {
                truth.set_uniform(k, z.exp());
            }
            let g = ds.model.gravity_of(&truth);
            format!(
                "gravity turned by {angle:.2}° to ({:.3}, {:.3}, {:.3}) m/s²",
                g[0], g[1], g[2]
            )
        }
    };
    ds.obs = record_late(&ds.model, &truth, SIGMA, seed, late, 4)?;
    // Markers only (no load cell), as a capture.
    ds.obs
        .forces
        .iter_mut()
        .for_each(|r| r.iter_mut().for_each(|f| *f = None));
    for row in &mut ds.obs.markers {
        for (p, c) in row.iter_mut().zip(&offsets) {
            if let Some(p) = p {
                for k in 0..3 {
                    p[k] += c[k];
                }
            }
        }
    }
    ds.config.marker_noise = Some(SIGMA);
    Ok((
        ds,
        MotionTruth {
            effect,
            seed,
            mu,
            mass,
            detail,
        },
    ))
}

/// A weight of `mass` hung on the top edge of the dataset's `back` group, moving with its nodes.
pub fn hung_weight(ds: &MotionDataset, mass: f64) -> Result<DeadLoad, MotionError> {
    let back = ds
        .mesh
        .group("back")
        .map_err(|e| MotionError::Invalid(format!("the specimen's base dataset: {e}")))?;
    let ztop = back
        .iter()
        .map(|&n| ds.mesh.nodes[n][2])
        .fold(f64::NEG_INFINITY, f64::max);
    Ok(DeadLoad {
        name: "weight".into(),
        nodes: back
            .iter()
            .copied()
            .filter(|&n| ds.mesh.nodes[n][2] == ztop)
            .collect(),
        force: ds.model.gravity.map(|g| mass * g),
        from_step: 0,
        mass: Some(mass),
        inertia: true,
        lever: None,
    })
}

/// The axis of the body's longest extent and its range (m).
fn long_axis(model: &Model) -> (usize, f64, f64) {
    let mut best = (0, 0.0, 0.0);
    for axis in 0..3 {
        let (lo, hi) = model
            .nodes
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), p| {
                (l.min(p[axis]), h.max(p[axis]))
            });
        if hi - lo > best.2 - best.1 {
            best = (axis, lo, hi);
        }
    }
    best
}

/// A recording of `model` with `mat` whose markers and clamp forces run `late` steps behind the
/// simulation's clock (negative: ahead), Gaussian marker noise `noise` (m) from `seed`: the truth
/// is simulated over a horizon `reach` ≥ |late| steps longer, its clamps held at their last pose;
/// the capture's row n sees the truth's step n + 1 − late, and a row before the truth starts sees
/// its initial markers (fresh noise each row) and no force. Built with the simulator alone, not
/// with `palpate_motion::time_offset`, which the tests check against it.
pub fn record_late(
    model: &Model,
    mat: &Material,
    noise: f64,
    seed: u64,
    late: i64,
    reach: usize,
) -> Result<Observations, MotionError> {
    let mut long = model.clone();
    long.steps += reach;
    for c in &mut long.clamps {
        if let Some(&last) = c.poses.last() {
            c.poses.resize(long.steps + 1, last);
        }
    }
    let recorded = record(&long, mat, noise, seed)?;
    let mut x0 = Vec::new();
    palpate_motion::sim::simulate(&long, mat, false, |x, _| x0 = x.to_vec(), |_| Ok(()))?;
    let mut rng = Gauss::new(seed + 1000);
    let mut obs = recorded.clone();
    obs.markers = (0..model.steps as i64)
        .map(|n| match usize::try_from(n - late) {
            Ok(i) => recorded.markers[i].clone(),
            Err(_) => long
                .markers
                .iter()
                .map(|m| Some(long.marker_position(m, &x0).map(|v| v + noise * rng.next())))
                .collect(),
        })
        .collect();
    obs.forces = (0..model.steps as i64)
        .map(|n| match usize::try_from(n - late) {
            Ok(i) => recorded.forces[i].clone(),
            Err(_) => vec![None; long.clamps.len()],
        })
        .collect();
    Ok(obs)
}
