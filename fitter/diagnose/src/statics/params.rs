//! A fit's parameters in physical units with their uncertainties: the base material's E and ν and
//! each adopted effect's, as the report and the export state them.

use super::fit::Fitted;
use super::model::{poisson_of, Candidate, Context};
use crate::select::ParamValue;
use serde::Serialize;

/// Physical values of the parameters of `c` in fit `f`.
pub fn effect_params(ctx: &Context, f: &Fitted, c: Candidate) -> Vec<ParamValue> {
    let Some(o) = f.model.offset(c, ctx.grid) else {
        return Vec::new();
    };
    c.param_names(ctx.grid)
        .into_iter()
        .enumerate()
        .map(|(j, (name, unit, scale))| ParamValue {
            name,
            value: f.theta[o + j] * scale,
            sd: f.theta_sd[o + j] * scale,
            unit: unit.into(),
        })
        .collect()
}

/// E and ν of a fit with their uncertainties (delta method).
pub fn base_params(f: &Fitted) -> Vec<ParamValue> {
    let e = f.theta[0].exp();
    let nu = poisson_of(f.theta[1]);
    let dnu = 0.75 * (1.0 - f.theta[1].tanh().powi(2));
    vec![
        ParamValue {
            name: "Young's modulus E".into(),
            value: e,
            sd: e * f.theta_sd[0],
            unit: "Pa".into(),
        },
        ParamValue {
            name: "Poisson ratio ν".into(),
            value: nu,
            sd: dnu * f.theta_sd[1],
            unit: "".into(),
        },
    ]
}

/// Two parameters of the final fit that these data determine only in combination: their
/// correlation in the Gauss–Newton covariance is at least [`DEGENERATE_CORRELATION`] in
/// magnitude, so each alone is known only relative to the other.
#[derive(Debug, Clone, Serialize)]
pub struct Degeneracy {
    /// The two parameters, as the parameter table names them.
    pub parameters: [String; 2],
    /// Their correlation.
    pub correlation: f64,
}

/// |correlation| from which a pair is reported as determined only in combination: at 0.95 the
/// uncertainty of either, the other held, is a third of its marginal one (1/√(1 − r²) ≈ 3.2),
/// so the marginal ±1σ of the table is dominated by the trade-off between the two.
pub const DEGENERATE_CORRELATION: f64 = 0.95;

/// The names of θ's entries, in θ's order: E and ν, then each effect's block.
fn theta_names(ctx: &Context, f: &Fitted) -> Vec<String> {
    let mut names: Vec<String> = base_params(f).into_iter().map(|p| p.name).collect();
    for &c in &f.model.effects {
        names.extend(c.param_names(ctx.grid).into_iter().map(|(n, _, _)| n));
    }
    names
}

/// The pairs of the fit's parameters that are degenerate ([`DEGENERATE_CORRELATION`]).
pub fn degeneracies(ctx: &Context, f: &Fitted) -> Vec<Degeneracy> {
    degenerate_pairs(&theta_names(ctx, f), &f.theta_corr)
}

/// The pairs of `names` (θ's order) whose correlation in `corr` (row-major) is degenerate; none
/// when the two do not describe the same parameters.
fn degenerate_pairs(names: &[String], corr: &[f64]) -> Vec<Degeneracy> {
    let k = names.len();
    if corr.len() != k * k {
        return Vec::new();
    }
    let mut out = Vec::new();
    for i in 0..k {
        for j in i + 1..k {
            let r = corr[i * k + j];
            if r.is_finite() && r.abs() >= DEGENERATE_CORRELATION {
                out.push(Degeneracy {
                    parameters: [names[i].clone(), names[j].clone()],
                    correlation: r,
                });
            }
        }
    }
    out
}

/// What the final fit's parameters are known relative to: degenerate pairs, and the adopted
/// effects' own notes ([`super::candidates::StaticEffect::relative_note`]).
#[derive(Debug, Clone, Default, Serialize)]
pub struct Identifiability {
    /// Pairs determined only in combination.
    pub degenerate: Vec<Degeneracy>,
    /// Figures that are relative to an assumption, in words.
    pub relative: Vec<String>,
}

/// What E is relative to when no adopted effect rescales the reported forces (whose own notes
/// say it then, [`super::candidates::StaticEffect::relative_note`]): the displacements of a
/// force-driven linear model scale with force over stiffness, so the force sensor's gain and E
/// are one direction of the data — a fit of E alone hides it behind an assumed gain of 1, and a
/// sensor off by a gain (or a power law read at another force) moves E by as much, unannounced.
pub const FORCE_GAIN_NOTE: &str = "Young's modulus E is relative to the force gain: in a linear \
     model the displacements scale with force over stiffness, so E/gain is determined, not E — E \
     is stated for a force sensor that reads true (gain 1), and a sensor that reads 20 % high \
     makes E 20 % high";

/// The effects that rescale the reported forces, each stating what E is then relative to.
fn rescales_forces(c: Candidate) -> bool {
    matches!(c, Candidate::Calibration | Candidate::ForceScaleEach)
}

/// The identifiability of fit `f`: the degenerate pairs of its parameters, what E is relative to
/// ([`FORCE_GAIN_NOTE`] unless an adopted effect says it), and the adopted effects' notes.
pub fn identifiability(ctx: &Context, f: &Fitted) -> Identifiability {
    let effects = &f.model.effects;
    let base = (!effects.iter().any(|&c| rescales_forces(c))).then(|| FORCE_GAIN_NOTE.to_string());
    Identifiability {
        degenerate: degeneracies(ctx, f),
        relative: base
            .into_iter()
            .chain(effects.iter().filter_map(|c| c.effect().relative_note(ctx)))
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_pairs_at_the_threshold_are_degenerate() {
        let names: Vec<String> = ["E", "ν", "gain"].iter().map(|s| s.to_string()).collect();
        #[rustfmt::skip]
        let corr = [
            1.0, 0.3, -0.97,
            0.3, 1.0, 0.949,
            -0.97, 0.949, 1.0,
        ];
        let d = degenerate_pairs(&names, &corr);
        assert_eq!(d.len(), 1, "{d:?}");
        assert_eq!(d[0].parameters, ["E".to_string(), "gain".to_string()]);
        assert_eq!(d[0].correlation, -0.97);
        // Names and correlations of different fits: nothing, rather than a wrong pair.
        assert!(degenerate_pairs(&names[..2], &corr).is_empty());
    }
}
