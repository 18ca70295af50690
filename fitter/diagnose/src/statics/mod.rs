//! The static diagnosis: fit the simplest model (warped linear homogeneous,
//! displacement-based), look at the residual ([`signature`](mod@signature)), hold every candidate effect of the
//! library ([`model::Candidate`]) against it by refitting the augmented model ([`fit`](mod@fit)), adopt the
//! best one if it earns its parameters, repeat until nothing significant is left, and report
//! ([`report`]).
//!
//! Selection (stated in every report): candidates are ranked by the Bayesian information criterion
//! with unknown noise variance, BIC = n ln(χ²/n) + k ln n (n residual entries, k parameters). The
//! best [`DiagnoseOptions::cv_candidates`] are shortlisted; a candidate passes only if (a) ΔBIC <
//! −[`DiagnoseOptions::bic_threshold`] and (b) leave-one-
//! measurement-out cross-validation confirms it: every measurement is refitted without and predicted;
//! the same criterion on the held-out predictions, n ln(χ²_new/χ²_old) + k ln n, must be negative,
//! and the held-out error in excess of the noise floor, √(RMS² − 3σ²), must drop by at least
//! [`DiagnoseOptions::min_holdout_gain`]; the first in fitted-BIC order that passes is adopted, and a
//! later shortlisted one that also passes with a lower held-out ΔBIC is reported as an ambiguity
//! ([`Step::ambiguous_with`]). (a) alone over-adopts when the residual is dominated by
//! model-form error of the coarse linear model (n is large, so any extra parameter that absorbs a
//! little of it passes); (b) makes the parameter pay for itself on data it was not fitted to, and
//! explain a real part of what the noise does not. The held-out ΔBIC alone is not enough: on a clean
//! specimen the 7-parameter inhomogeneity field absorbs part of the coarse mesh's discretisation
//! error (held-out ΔBIC −58, but only 7 % of the excess error); measuring the gain against the
//! excess rather than the whole RMS (the first version) no longer hides effects whose gain is small
//! next to the marker noise but large next to what the model gets wrong.
//!
//! After the structural loop, the white-noise level of the final residual is estimated apart from
//! smooth model-form error ([`noise`]: a local nugget estimator with a bootstrap interval over
//! measurements). Marker noise significantly above the declared σ is reported as the effect
//! `noise` ([`model::Candidate::Noise`]): no parameter of the model changes, the finding is that
//! the declared noise level is wrong, and the noise floor is recomputed with σ̂. The declared rest
//! positions are tested for noise of their own ([`rest_noise`]: the same nugget on each marker's
//! mean residual over its measurements); a significant τ̂ is reported as `rest-noise`
//! ([`model::Candidate::RestNoise`]) and the final residual is judged under the covariance both
//! noises give ([`ResidualCheck::with_rest_noise`]). A noisy rest scan makes the noise test fire
//! too; when the measurements' own (within-marker) noise is as declared, `rest-noise` replaces
//! `noise`, and when it is above, both are adopted (judged under σ̂_w²I + τ̂²11ᵀ).

pub mod approx_error;
pub mod candidates;
mod context;
mod diagnose;
mod diagnosis;
pub mod export;
pub mod fit;
mod holdout;
pub mod model;
pub mod noise;
mod options;
mod params;
pub mod power;
pub mod power_check;
pub mod report;
pub mod rest_noise;
pub mod run;
mod screen;
mod select;
pub mod sensitivity;
pub mod signature;
mod verdict;

pub use diagnose::{run_diagnosis, run_diagnosis_with};
pub use diagnosis::{
    Diagnosed, DiagnosisReport, Errors, Evidence, Kept, MeshErrorSummary, SolvedOn, Step, Tried,
    MESH_ERROR_MAX_TETS,
};
pub use options::{DiagnoseOptions, MeshChoice};
pub use params::{base_params, effect_params};
pub use verdict::ResidualCheck;

use crate::json;
use crate::Error;

/// The static diagnosis's errors: the crate's one [`Error`] (the name kept for its callers).
pub type DiagnoseError = Error;
