//! The material stiffens at larger strains beyond Neo-Hookean: a Yeoh-type c (Ī₁ − 3)² term
//! beside eq. 16 (1 parameter, fitted in ln c).

use palpate_motion::model::{Param, ParamKind};

use super::MotionEffect;
use crate::motion::fit::FittedModel;

/// See the module.
pub struct Stiffening;

impl MotionEffect for Stiffening {
    fn name(&self) -> &'static str {
        "stiffening"
    }

    fn kinds(&self) -> &'static [ParamKind] {
        &[ParamKind::Stiffening]
    }

    fn screened_params(&self) -> &'static [(ParamKind, Option<f64>)] {
        &[(ParamKind::Stiffening, Some(0.0))]
    }

    /// From c = μ: at 10 % strain the term adds about 6 % to the Neo-Hookean energy.
    fn new_starts(&self, cur: &FittedModel, _dt: f64) -> Vec<Vec<f64>> {
        vec![vec![cur.material.read(&[Param::global(ParamKind::Mu)])[0]]]
    }
}
