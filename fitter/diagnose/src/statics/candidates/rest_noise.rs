//! Noise in the declared rest positions (the rest scan is a measurement too). Like
//! [`super::noise`] not a model candidate: it changes no prediction, only the covariance the
//! final residual is judged with. Adopted after the structural loop by the persistent-nugget
//! test of [`crate::statics::rest_noise`]. 0 params.

use super::StaticEffect;
use crate::statics::signature::{EvidencePoints, Residual};

/// See the module.
pub struct RestNoise;

impl StaticEffect for RestNoise {
    fn name(&self) -> &'static str {
        "rest-noise"
    }

    /// The marker error against distance from the contact shows it spread evenly (the rest
    /// scan's report plots its per-marker means, `rest.svg`).
    fn evidence(&self, r: &Residual) -> EvidencePoints {
        r.error_against_distance()
    }
}
