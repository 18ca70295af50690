//! Marker noise above the declared level. Not a model candidate (not in
//! [`super::ALL_CANDIDATES`], never part of a [`crate::statics::model::Model`]): it changes no
//! prediction, only how large the residual floor is. Adopted after the structural loop by the
//! nugget test of [`crate::statics::noise`]. 0 params.

use super::StaticEffect;
use crate::statics::signature::{EvidencePoints, Residual};

/// See the module.
pub struct Noise;

impl StaticEffect for Noise {
    fn name(&self) -> &'static str {
        "noise"
    }

    /// The marker error against distance from the contact shows it spread evenly (the noise
    /// report plots the nugget itself, see [`crate::statics::noise`]).
    fn evidence(&self, r: &Residual) -> EvidencePoints {
        r.error_against_distance()
    }
}
