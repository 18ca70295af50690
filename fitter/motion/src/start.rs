//! A starting stiffness estimated from the data, for a fit whose dataset gives no `[initial]`.
//!
//! An LBFGS fit in log parameters starts anywhere in principle, but a motion fit must first
//! simulate its start: a 20 cm silicone cantilever fitted from a generic 10 kPa guess hangs
//! straight down, and every step of the optimiser is spent walking two decades back. The data
//! usually says the scale at once: the markers' first frame against their rest positions is the
//! body's sag under its own weight and known loads, and in linear elasticity that sag scales as
//! 1/μ at a fixed Poisson's ratio. The estimate is the μ whose elastostatic start
//! ([`crate::sim::equilibrium`], the non-linear solve the fit itself uses) reproduces the
//! observed first-frame displacement in the least-squares sense along it, found by the
//! fixed point μ ← μ · s with s = u_simᵀu_obs / u_obsᵀu_obs (exact in the linear regime, a
//! contraction beyond it because the sag grows monotonically as μ falls).
//!
//! The viscosity needs a start on the right scale too: the fit works in log parameters, and
//! the gradient with respect to log ν is ν ∂Φ/∂ν, which vanishes when ν starts decades below
//! where it damps anything — LBFGS then never moves it. The sag gives the first mode's angular
//! frequency ω by Rayleigh's quotient with the static deflection u as the mode shape,
//! ω² ≈ uᵀK u / uᵀM u = uᵀf / uᵀM u (f the load that made u), and the Newtonian power law
//! (h = 1; stress 2ν ε̇ against the elastic 2μ ε) damps that mode with ratio ζ = ων/(2μ). The
//! start is ν = 2ζμ/ω at [`ASSUMED_DAMPING_RATIO`].

use crate::model::{Material, Model, Observations, Param, ParamKind};
use crate::sim::equilibrium;
use crate::MotionError;

/// Poisson's ratio assumed by the estimate when the caller holds none: the soft solids this
/// fits (silicones, gels, foams with closed cells) are nearly incompressible; the fit frees it.
pub const ASSUMED_POISSON: f64 = 0.45;

/// Damping ratio of the first mode assumed by the viscosity start: elastomers and gels ring
/// down with a few per cent.
pub const ASSUMED_DAMPING_RATIO: f64 = 0.02;

/// The estimated start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StartEstimate {
    /// Shear modulus μ (Pa).
    pub mu: f64,
    /// Lamé's λ (Pa) at the assumed Poisson's ratio.
    pub lambda: f64,
    /// The Poisson's ratio used.
    pub poisson: f64,
    /// Observed static displacement, RMS over markers (m).
    pub observed_rms_m: f64,
    /// What the start at the estimate leaves of it, RMS over markers (m).
    pub misfit_rms_m: f64,
    /// Static solves spent.
    pub solves: usize,
    /// First-mode angular frequency by Rayleigh's quotient of the sag (rad/s).
    pub omega_rad_s: f64,
    /// Newtonian viscosity (h = 1) damping that mode at [`ASSUMED_DAMPING_RATIO`] (Pa·s).
    pub viscosity: f64,
}

impl StartEstimate {
    /// Young's modulus E = 2μ(1 + ν) (Pa).
    pub fn young_modulus_pa(&self) -> f64 {
        2.0 * self.mu * (1.0 + self.poisson)
    }
}

/// Why no estimate was made.
#[derive(Debug, Clone, PartialEq)]
pub enum NoEstimate {
    /// The observed static state is within three noise RMS of the rest positions: the sag does
    /// not show.
    SagBelowNoise {
        /// Observed RMS displacement (m).
        observed_rms_m: f64,
        /// Three times the marker noise (m).
        floor_m: f64,
    },
    /// No marker is observed where the static state is read.
    NoEarlyFrame,
    /// The model's sag points away from the observed one (gravity or loads declared wrongly).
    OppositeSag,
    /// The static start did not converge at any stiffness tried.
    NoStart(String),
}

impl std::fmt::Display for NoEstimate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::SagBelowNoise {
                observed_rms_m,
                floor_m,
            } => write!(
                f,
                "the observed static state is {:.3} mm (RMS) from the rest positions, within \
                 the noise floor {:.3} mm: the sag does not show",
                1e3 * observed_rms_m,
                1e3 * floor_m
            ),
            Self::NoEarlyFrame => write!(
                f,
                "no marker is observed in the first 5 steps (elastostatic start) or the last \
                 0.5 s (a run from the rest shape)"
            ),
            Self::OppositeSag => write!(
                f,
                "the simulated sag points away from the observed one (check `gravity` and the \
                 `[[loads]]`)"
            ),
            Self::NoStart(e) => write!(f, "the static start did not converge: {e}"),
        }
    }
}

/// The observed static displacement of the markers against their rest positions on the mesh,
/// (marker index, displacement), and the step whose equilibrium it is: with an elastostatic
/// start, each marker's first observed position within the first five steps (step 0's
/// equilibrium); a run that starts from the rest shape is compared where it came to rest — the
/// mean over its last [`crate::predict::FINAL_WINDOW_S`] — with the equilibrium of its last step.
fn observed_static(model: &Model, obs: &Observations) -> (Vec<(usize, [f64; 3])>, usize) {
    let rest: Vec<f64> = model.nodes.iter().flatten().copied().collect();
    let (seen, step): (Vec<Option<[f64; 3]>>, usize) = if model.static_start {
        let first = (0..model.markers.len())
            .map(|i| {
                obs.markers
                    .iter()
                    .take(5)
                    .find_map(|frame| frame.get(i).copied().flatten())
            })
            .collect();
        (first, 0)
    } else {
        (crate::predict::final_observed(model, obs), model.steps)
    };
    let u = seen
        .iter()
        .enumerate()
        .filter_map(|(i, p)| {
            p.map(|p| {
                let r = model.marker_position(&model.markers[i], &rest);
                (i, [p[0] - r[0], p[1] - r[1], p[2] - r[2]])
            })
        })
        .collect();
    (u, step)
}

/// Estimates μ (and λ at `poisson`) from the first frame's sag; `base` gives the density, the
/// stiffening and everything else held. `noise_m` is the marker noise σ (per axis).
pub fn from_rest_sag(
    model: &Model,
    obs: &Observations,
    base: &Material,
    poisson: f64,
    noise_m: f64,
) -> Result<StartEstimate, NoEstimate> {
    let (u_obs, step) = observed_static(model, obs);
    if u_obs.is_empty() {
        return Err(NoEstimate::NoEarlyFrame);
    }
    let n = u_obs.len() as f64;
    let oo: f64 = u_obs.iter().flat_map(|(_, u)| u).map(|v| v * v).sum();
    let observed_rms_m = (oo / n).sqrt();
    // The RMS of 3-D noise is σ√3; the sag must stand three times above it.
    let floor_m = 3.0 * noise_m * 3f64.sqrt();
    if observed_rms_m < floor_m {
        return Err(NoEstimate::SagBelowNoise {
            observed_rms_m,
            floor_m,
        });
    }
    let lambda_of = |mu: f64| 2.0 * mu * poisson / (1.0 - 2.0 * poisson);
    let simulate = |mu: f64| -> Result<(Vec<[f64; 3]>, f64), MotionError> {
        let mut mat = base.clone();
        mat.set(
            &Param::globals(&[ParamKind::Mu, ParamKind::Lambda]),
            &[mu, lambda_of(mu)],
        );
        let (x, _) = equilibrium(model, &mat, step)?;
        let rest: Vec<f64> = model.nodes.iter().flatten().copied().collect();
        // Rayleigh's quotient on the free dofs (the clamps' own motion is not the mode).
        let mut u: Vec<f64> = x.iter().zip(&rest).map(|(a, b)| a - b).collect();
        for (d, &fr) in model.free.iter().enumerate() {
            if fr == usize::MAX {
                u[d] = 0.0;
            }
        }
        let mut mu_ = vec![0.0; u.len()];
        model.mass_mul(&mat, &u, &mut mu_);
        let fext = model.external_load(&mat, step);
        let (uf, umu) = (
            u.iter().zip(&fext).map(|(a, b)| a * b).sum::<f64>(),
            u.iter().zip(&mu_).map(|(a, b)| a * b).sum::<f64>(),
        );
        let omega = if uf > 0.0 && umu > 0.0 {
            (uf / umu).sqrt()
        } else {
            f64::NAN
        };
        let markers = u_obs
            .iter()
            .map(|(i, _)| {
                let m = &model.markers[*i];
                let (p, r) = (
                    model.marker_position(m, &x),
                    model.marker_position(m, &rest),
                );
                [p[0] - r[0], p[1] - r[1], p[2] - r[2]]
            })
            .collect();
        Ok((markers, omega))
    };
    let mut mu = base.get(ParamKind::Mu, 0).max(1.0);
    let mut last = None;
    for solves in 1..=20 {
        let (u_sim, omega) = match simulate(mu) {
            Ok(u) => u,
            Err(e) => {
                // Too soft to stand: ten times stiffer and again.
                last = Some(e.to_string());
                mu *= 10.0;
                continue;
            }
        };
        let so: f64 = u_sim
            .iter()
            .zip(&u_obs)
            .map(|(a, (_, b))| a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
            .sum();
        if so <= 0.0 {
            return Err(NoEstimate::OppositeSag);
        }
        let s = so / oo;
        let misfit: f64 = u_sim
            .iter()
            .zip(&u_obs)
            .map(|(a, (_, b))| (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>())
            .sum();
        if (s - 1.0).abs() < 1e-3 {
            return Ok(StartEstimate {
                mu,
                lambda: lambda_of(mu),
                poisson,
                observed_rms_m,
                misfit_rms_m: (misfit / n).sqrt(),
                solves,
                omega_rad_s: omega,
                viscosity: 2.0 * ASSUMED_DAMPING_RATIO * mu / omega,
            });
        }
        // At most a decade per step: far from the answer the sag is not linear in 1/μ.
        mu *= s.clamp(0.1, 10.0);
    }
    Err(NoEstimate::NoStart(last.unwrap_or_else(|| {
        "the estimate did not settle in 20 static solves".into()
    })))
}

/// Where a fit of a dataset starts.
#[derive(Debug, Clone, PartialEq)]
pub struct StartValues {
    /// Lamé's λ (Pa).
    pub lambda: f64,
    /// Shear modulus μ (Pa).
    pub mu: f64,
    /// Viscosity coefficient (Pa·s^h) and exponent h.
    pub viscosity: f64,
    /// Power-law exponent h.
    pub h: f64,
    /// Where these came from, for the user's log.
    pub note: String,
}

impl StartValues {
    /// These values on every element of `ds`, at its declared density (1000 kg/m³ without
    /// one) and with its viscosity's form.
    pub fn material(&self, ds: &crate::dataset::MotionDataset) -> Material {
        let mut m = Material::uniform(
            ds.model.tets.len(),
            self.lambda,
            self.mu,
            self.viscosity,
            self.h,
            ds.config.density.unwrap_or(crate::request::DEFAULT_DENSITY),
        );
        m.viscous_form = ds.model.viscous_form;
        m
    }
}

/// The start of a fit of `ds`: its `[initial]` table when it has one; otherwise the rest-sag
/// estimate at `poisson` (default [`ASSUMED_POISSON`]) with the viscosity on the scale of the
/// first mode (h = 1), or the format's defaults when the data do not show the scale.
pub fn initial_values(ds: &crate::dataset::MotionDataset, poisson: Option<f64>) -> StartValues {
    let init = &ds.config.initial;
    let declared = StartValues {
        lambda: init.lambda,
        mu: init.mu,
        viscosity: init.nu,
        h: init.h,
        note: "starting values from [initial]".into(),
    };
    if ds.config.initial_declared {
        return declared;
    }
    let nu = poisson.unwrap_or(ASSUMED_POISSON);
    let base = declared.material(ds);
    let noise = ds.config.marker_noise.unwrap_or(1e-4);
    match from_rest_sag(&ds.model, &ds.obs, &base, nu, noise) {
        Ok(e) if e.viscosity.is_finite() && e.viscosity > 0.0 => StartValues {
            lambda: e.lambda,
            mu: e.mu,
            viscosity: e.viscosity,
            h: 1.0,
            note: format!(
                "no [initial] in dataset.toml: starting from the static sag ({:.2} mm RMS): E = {:.4e} Pa at Poisson's ratio {nu} (μ = {:.4e} Pa, Lamé λ = {:.4e} \
                 Pa; {} static solves, {:.3} mm left); viscosity {:.3e} Pa·s (h = 1), a {:.0} % \
                 damping ratio at the first mode's {:.2} Hz",
                1e3 * e.observed_rms_m,
                e.young_modulus_pa(),
                e.mu,
                e.lambda,
                e.solves,
                1e3 * e.misfit_rms_m,
                e.viscosity,
                100.0 * ASSUMED_DAMPING_RATIO,
                e.omega_rad_s / (2.0 * std::f64::consts::PI)
            ),
        },
        Ok(_) => StartValues {
            note: "no [initial] in dataset.toml and the sag gives no mode frequency: starting \
                   from the format's defaults — give [initial] if the fit cannot start"
                .into(),
            ..declared
        },
        Err(why) => StartValues {
            note: format!(
                "no [initial] in dataset.toml and no estimate from the data ({why}): starting \
                 from λ = {:.3e} Pa, μ = {:.3e} Pa — give [initial] if the fit cannot start",
                init.lambda, init.mu
            ),
            ..declared
        },
    }
}
