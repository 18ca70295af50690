//! What the report says of a fitted parameter that ended on its floor.
//!
//! The motion fitter holds two global parameters above a floor below which the model means
//! another effect or no longer changes ([`palpate_motion::optimize::LAMBDA_FLOOR_RATIO`],
//! [`palpate_motion::optimize::POWER_INDEX_FLOOR`]). A fit that ends there reports the floor
//! with the Gauss–Newton σ of that point. That pair reads as a measurement, and is not one: the
//! data pushed the parameter further than the model lets it go, and the σ is the curvature at
//! the floor, not an interval about a minimum. On the independent generator's 36 cylinders of
//! the motion confusion tables (truth ν 0.30–0.49, Kelvin–Voigt damping: h = 1) the final λ
//! ended on its floor in 8 draws and h on its floor in 10, each reported as "Poisson's ratio
//! ν = 0.0005" or "h 0.1000 ± 0.037" without a word.

use super::Value;
use palpate_fem::names::Elastic;
use palpate_motion::model::ParamKind;
use palpate_motion::optimize::{LAMBDA_FLOOR_RATIO, POWER_INDEX_FLOOR};
use serde::Serialize;

/// A value within this fraction above its floor is on it: the fitter stops a step on the floor
/// exactly, and a value kept there moves only by round-off.
const ON_FLOOR: f64 = 1e-6;

/// A fitted parameter that ended on its floor, and what that means.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct OnFloor {
    /// The parameter's name ([`ParamKind::name`]), as the value tables list it.
    pub parameter: String,
    /// What the value on the floor means, in words for the report.
    pub statement: String,
}

/// The final model's fitted global parameters on their floors: `lambda` and `h` are `Some`
/// when fitted (a held one is the user's, not the data's), `mu` is the global shear modulus the
/// floor of λ is reckoned against.
pub fn on_floors(lambda: Option<f64>, mu: f64, h: Option<f64>) -> Vec<OnFloor> {
    let mut notes = Vec::new();
    if let Some(l) = lambda.filter(|&l| mu > 0.0 && l <= LAMBDA_FLOOR_RATIO * mu * (1.0 + ON_FLOOR))
    {
        notes.push(OnFloor {
            parameter: ParamKind::Lambda.name().into(),
            statement: format!(
                "Lamé λ ended on its floor, λ = {LAMBDA_FLOOR_RATIO:e} μ (Poisson's ratio \
                 {:.4}): the data would have lowered it further, where the model no longer \
                 changes. Poisson's ratio is not measured here, and λ's 1σ is the misfit's \
                 curvature at the floor, not an interval. Linear elements that lock in bending \
                 are fitted best with no volume stiffness whatever the material's, so the floor \
                 may be this mesh's: the sections on the mesh below say how far the fitted \
                 values are from converged",
                Elastic::from_lame(l, mu).poisson_ratio
            ),
        });
    }
    if let Some(h) = h.filter(|&h| h <= POWER_INDEX_FLOOR * (1.0 + ON_FLOOR)) {
        notes.push(OnFloor {
            parameter: ParamKind::PowerH.name().into(),
            statement: format!(
                "the power-law index h ended on its floor, h = {h:.4}: the loss the data ask \
                 for is more rate-independent than any power-law dashpot the model holds — a \
                 friction-like (hysteretic) loss, or what the fit takes from the mesh's own \
                 error. h and the viscosity are not a measured shear-thinning law, and h's 1σ \
                 is the misfit's curvature at the floor, not an interval"
            ),
        });
    }
    notes
}

/// The parameters of a value table (a model's [`Value`]s) on their floors: λ and h when fitted
/// (listed without "(fixed)"), against the global μ, fitted or held.
pub fn of_values(vals: &[Value]) -> Vec<OnFloor> {
    let find = |kind: ParamKind, fitted_only: bool| {
        vals.iter()
            .find(|v| {
                v.name == kind.name()
                    || (!fitted_only && v.name.strip_suffix(" (fixed)") == Some(kind.name()))
            })
            .map(|v| v.value)
    };
    on_floors(
        find(ParamKind::Lambda, true),
        find(ParamKind::Mu, false).unwrap_or(0.0),
        find(ParamKind::PowerH, true),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fitted_lambda_on_its_floor_is_stated_and_one_above_it_is_not() {
        let mu = 1.25e6;
        let on = on_floors(Some(LAMBDA_FLOOR_RATIO * mu), mu, None);
        assert_eq!(on.len(), 1);
        assert_eq!(on[0].parameter, "lambda");
        assert!(
            on[0].statement.contains("Poisson's ratio 0.0005")
                && on[0].statement.contains("not measured here"),
            "{}",
            on[0].statement
        );
        // A hundredth of a per cent above the floor is a value the data set.
        assert!(on_floors(Some(1.0001 * LAMBDA_FLOOR_RATIO * mu), mu, None).is_empty());
        // Held (not fitted): the user's value, whatever it is.
        assert!(on_floors(None, mu, None).is_empty());
        // No global μ to reckon the floor against: nothing is claimed.
        assert!(on_floors(Some(0.0), 0.0, None).is_empty());
    }

    #[test]
    fn a_fitted_index_on_its_floor_is_stated_and_one_above_it_is_not() {
        let on = on_floors(None, 1e6, Some(POWER_INDEX_FLOOR));
        assert_eq!(on.len(), 1);
        assert_eq!(on[0].parameter, "h");
        assert!(
            on[0].statement.contains("h = 0.1000"),
            "{}",
            on[0].statement
        );
        assert!(on_floors(None, 1e6, Some(0.1001)).is_empty());
        assert!(on_floors(None, 1e6, Some(1.0)).is_empty());
        // Both at once, λ first as the value table lists them.
        let both = on_floors(Some(1e3), 1e6, Some(POWER_INDEX_FLOOR));
        let names: Vec<&str> = both.iter().map(|n| n.parameter.as_str()).collect();
        assert_eq!(names, ["lambda", "h"]);
    }

    /// A value table's names: λ and h fitted are read, held ones ("(fixed)") are not; μ is
    /// read either way.
    #[test]
    fn a_value_table_is_read_by_its_names() {
        let value = |name: &str, value: f64| Value {
            name: name.into(),
            value,
            sigma: None,
        };
        let fitted = [
            value("lambda", 1.255e3),
            value("mu", 1.255e6),
            value("h", 0.1),
        ];
        let names: Vec<String> = of_values(&fitted)
            .into_iter()
            .map(|n| n.parameter)
            .collect();
        assert_eq!(names, ["lambda", "h"]);
        let held = [
            value("lambda (fixed)", 1.255e3),
            value("mu (fixed)", 1.255e6),
            value("h (fixed)", 0.1),
        ];
        assert!(of_values(&held).is_empty());
        let mu_held = [value("lambda", 1.255e3), value("mu (fixed)", 1.255e6)];
        assert_eq!(of_values(&mu_held).len(), 1);
    }
}
