//! The effects a specimen can carry, each with one magnitude knob (documented units) and a
//! realistic default.

use serde::Serialize;

use super::SpecimenError;

/// An effect the fitted model does not declare.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Effect {
    /// Strain stiffening beyond Neo-Hookean: c (Ī₁ − 3)² (Yeoh's second-order term on the isochoric invariant Ī₁ = J^(−2/3) I₁) with c = magnitude × μ.
    Stiffening,
    /// A spherical inclusion under the top face: E_inclusion = (1 + magnitude) E, stiff for a
    /// positive magnitude, soft for one in (−1, 0).
    Inclusion,
    /// A soft top layer (a quarter of the height): E_layer = E / (1 + magnitude).
    SoftLayer,
    /// Force sensor non-linearity: reported f = true f · (|true f| / f_max)^magnitude.
    Calibration,
    /// Compliant support: the "fixed" face moves rigidly, translation = magnitude (m/N) × total
    /// force, rotation = magnitude × moment / (half width)² (rad per N m).
    Boundary,
    /// Marker registration offset: one rigid transform on every measured position, translation
    /// of length magnitude (m) and rotation magnitude / (half width) (rad), random axes.
    Registration,
    /// The rest scan was taken under gravity (−z), density = magnitude × 1000 kg/m³.
    Gravity,
    /// Tilted probe / tangential friction: true force = reported + magnitude · |f| · t with one
    /// fixed random horizontal unit vector t.
    Tilt,
    /// The probe's contact patch is wider (or narrower) than the declared probe: the true load
    /// is spread over the nodes within (1 + magnitude) × the declared radius (a soft object
    /// wrapping around a rounded probe).
    ContactRadius,
    /// Marker noise beyond the declared σ: actual σ = (1 + magnitude) × declared σ.
    Noise,
    /// Occlusions: each marker row is dropped with probability magnitude.
    Occlusion,
    /// A noisy rest scan: every declared rest position is off its true place by white noise of
    /// magnitude × declared σ per axis (a rest scan averaged over n frames has 1/√n), the same
    /// error in every measurement.
    RestNoise,
}

/// Every effect, in the order the CLI lists them.
pub const ALL_EFFECTS: [Effect; 12] = [
    Effect::Stiffening,
    Effect::Inclusion,
    Effect::SoftLayer,
    Effect::Calibration,
    Effect::Boundary,
    Effect::Registration,
    Effect::Gravity,
    Effect::Tilt,
    Effect::ContactRadius,
    Effect::Noise,
    Effect::Occlusion,
    Effect::RestNoise,
];

impl Effect {
    /// Command-line name.
    pub fn name(self) -> &'static str {
        match self {
            Effect::Stiffening => "stiffening",
            Effect::Inclusion => "inclusion",
            Effect::SoftLayer => "soft-layer",
            Effect::Calibration => "calibration",
            Effect::Boundary => "boundary",
            Effect::Registration => "registration",
            Effect::Gravity => "gravity",
            Effect::Tilt => "tilt",
            Effect::ContactRadius => "contact-radius",
            Effect::Noise => "noise",
            Effect::Occlusion => "occlusion",
            Effect::RestNoise => "rest-noise",
        }
    }

    /// A realistic default magnitude (units in the variant docs).
    pub fn default_magnitude(self) -> f64 {
        match self {
            Effect::Stiffening => 20.0,
            Effect::Inclusion => 9.0,
            Effect::SoftLayer => 3.0,
            Effect::Calibration => 0.3,
            Effect::Boundary => 4e-4,
            Effect::Registration => 4e-4,
            Effect::Gravity => 1.0,
            Effect::Tilt => 0.3,
            Effect::ContactRadius => 0.6,
            Effect::Noise => 1.0,
            Effect::Occlusion => 0.2,
            Effect::RestNoise => 0.5,
        }
    }

    /// Parses a command-line name.
    pub fn parse(name: &str) -> Result<Self, SpecimenError> {
        ALL_EFFECTS
            .iter()
            .copied()
            .find(|e| e.name() == name.trim())
            .ok_or_else(|| SpecimenError::UnknownEffect {
                name: name.to_string(),
                known: ALL_EFFECTS
                    .iter()
                    .map(|e| e.name())
                    .collect::<Vec<_>>()
                    .join(", "),
            })
    }

    /// Checks a magnitude.
    pub fn check(self, m: f64) -> Result<(), SpecimenError> {
        let bad = |why| {
            Err(SpecimenError::Magnitude {
                effect: self.name(),
                value: m,
                why,
            })
        };
        if !m.is_finite() {
            return bad("not finite");
        }
        match self {
            Effect::Occlusion if !(0.0..0.9).contains(&m) => bad("a drop probability in [0, 0.9)"),
            Effect::Calibration if !(-0.9..=2.0).contains(&m) => {
                bad("a power-law exponent in [-0.9, 2]")
            }
            Effect::ContactRadius if m <= -0.5 => {
                bad("> −0.5 (patch radius = (1 + magnitude) × the declared probe radius)")
            }
            Effect::Inclusion if m <= -1.0 => {
                bad("> −1 (E_inclusion = (1 + magnitude) E: −1 < m < 0 a soft inclusion)")
            }
            Effect::SoftLayer
            | Effect::Stiffening
            | Effect::Gravity
            | Effect::Noise
            | Effect::RestNoise
                if m < 0.0 =>
            {
                bad("must be ≥ 0")
            }
            _ => Ok(()),
        }
    }
}

/// One effect with its magnitude.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct EffectSpec {
    /// Which effect.
    pub effect: Effect,
    /// Its magnitude (units in [`Effect`]).
    pub magnitude: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_bad_names_list_the_known_ones() {
        for e in ALL_EFFECTS {
            assert_eq!(Effect::parse(e.name()).unwrap(), e);
            e.check(e.default_magnitude()).unwrap();
        }
        let msg = Effect::parse("viscosity").unwrap_err().to_string();
        assert!(
            msg.contains("viscosity") && msg.contains("soft-layer"),
            "{msg}"
        );
        assert!(Effect::Occlusion
            .check(0.95)
            .unwrap_err()
            .to_string()
            .contains("occlusion"));
    }
}
