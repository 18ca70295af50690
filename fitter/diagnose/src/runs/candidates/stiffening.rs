//! Strain stiffening: the material stiffens (or holds its stiffness) at larger strains beyond
//! Neo-Hookean, a Yeoh-type c (Ī₁ − 3)² term beside eq. 16 (1 parameter, c ≥ 0, Pa, fitted in
//! ln c from c = μ: at 10 % strain that adds about 6 % to the Neo-Hookean energy). What tells it
//! from a stiffer μ is the load: runs under different weights strain the body differently.

use palpate_motion::model::{Material, ParamKind};

use super::RunsEffect;
use crate::runs::fit::RunsModel;
use crate::runs::RunsFit;
use crate::select::ParamValue;

/// See the module.
pub struct Stiffening;

impl RunsEffect for Stiffening {
    fn name(&self) -> &'static str {
        "stiffening"
    }

    fn kinds(&self) -> &'static [ParamKind] {
        &[ParamKind::Stiffening]
    }

    fn start(&self, room: &RunsModel, round: usize, _cur: &RunsFit, start: &mut Material) {
        if start.get(ParamKind::Stiffening, 0) <= 0.0 {
            let mu = start.body_moduli().1;
            (room.log)(&format!(
                "round {round}: stiffening starts at c = μ = {mu:.3e} Pa"
            ));
            start.set_uniform(ParamKind::Stiffening, mu);
        }
    }

    fn values(&self, material: &Material) -> Vec<ParamValue> {
        vec![ParamValue {
            name: "strain-stiffening c of c (Ī₁ − 3)²".into(),
            value: material.get(ParamKind::Stiffening, 0),
            sd: f64::NAN,
            unit: "Pa".into(),
        }]
    }
}
