//! Is the fitted motion's material — its modulus and its viscosity — the material's or the
//! mesh's? [`super::convergence`] answers for the modulus from where the runs came to rest; this
//! check refits the motion itself on quadratic 10-node tetrahedra of the same mesh
//! ([`palpate_motion::quadratic_motion`], which do not lock in bending) by the same objective,
//! and sets every fitted parameter beside the linear fit's. On the silicone beam the linear
//! elements' modulus is half the material's and their viscosity 12 % low
//! (docs/results/beam/convergence.md).
//!
//! The quadratic model has no sensitivities of its own: it is fitted by Levenberg–Marquardt on
//! forward differences ([`palpate_motion::difference_fit`]), from the linear fit's values with
//! the moduli scaled by the rest states' quadratic-to-linear ratio when that is known. What it
//! does not carry (the spline material, per-element or per-region values, a parameter it cannot
//! refit) is not checked, and the report says which.

use palpate_fem::numbers;
use palpate_motion::difference_fit::{fit_by_differences, DifferenceRun, Forward, GlobalParam};
use palpate_motion::model::{Material, Model, Observations, ParamKind};
use palpate_motion::quadratic_motion::QuadraticMotion;
use serde::Serialize;
use std::fmt::Write as _;

/// Relative difference of a parameter on linear and quadratic elements above which it is the
/// mesh's: the 5 % of [`super::convergence::TOLERANCE`].
pub use super::convergence::TOLERANCE;

/// Levenberg–Marquardt iterations of the quadratic fit at most: it starts near its optimum.
const MAX_ITERATIONS: usize = 10;

/// One parameter on both discretisations.
#[derive(Debug, Clone, Serialize)]
pub struct Parameter {
    /// Its name ([`ParamKind::name`]).
    pub name: &'static str,
    /// The linear fit's value (this mesh's).
    pub linear: f64,
    /// The quadratic fit's value.
    pub quadratic: f64,
    /// The quadratic value's 1σ from its Gauss–Newton matrix.
    pub quadratic_sigma: f64,
}

/// A quadratic value whose 1σ exceeds this fraction of it is not determined by the data: the
/// fit may land anywhere along a valley (the viscosity against its index, λ against μ in
/// bending), and its difference from the linear value says nothing of the mesh.
pub const UNDETERMINED: f64 = 0.2;

/// How one parameter compares across the two discretisations.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Agreement {
    /// Within [`TOLERANCE`], or within two of the quadratic value's σ.
    Converged,
    /// Further apart than both.
    NotConverged,
    /// The quadratic value's 1σ is above [`UNDETERMINED`] of it.
    Undetermined,
}

impl Parameter {
    /// quadratic / linear − 1.
    pub fn difference(&self) -> f64 {
        self.quadratic / self.linear - 1.0
    }

    /// Whether the two values agree, beyond the tolerance and the quadratic fit's uncertainty.
    pub fn agreement(&self) -> Agreement {
        let sigma = self.quadratic_sigma.abs();
        if !sigma.is_finite() || sigma > UNDETERMINED * self.quadratic.abs() {
            Agreement::Undetermined
        } else if self.difference().abs() <= TOLERANCE
            || (self.quadratic - self.linear).abs() <= 2.0 * sigma
        {
            Agreement::Converged
        } else {
            Agreement::NotConverged
        }
    }
}

/// The check's outcome.
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "outcome", rename_all = "kebab-case")]
pub enum MotionConvergence {
    /// Refitted on quadratic elements.
    Checked {
        /// Every fitted parameter.
        parameters: Vec<Parameter>,
        /// The linear fit's marker RMS (m).
        linear_rms_m: f64,
        /// The quadratic fit's marker RMS (m).
        quadratic_rms_m: f64,
        /// Simulations of one run on quadratic elements.
        simulations: usize,
    },
    /// Not checked, and why.
    Skipped {
        /// Why.
        reason: String,
    },
}

impl MotionConvergence {
    /// Whether every determined parameter agrees on both discretisations
    /// ([`Parameter::agreement`]); `None` when not checked or when none is determined.
    pub fn converged(&self) -> Option<bool> {
        match self {
            Self::Checked { parameters, .. } => {
                let determined: Vec<Agreement> = parameters
                    .iter()
                    .map(Parameter::agreement)
                    .filter(|a| *a != Agreement::Undetermined)
                    .collect();
                (!determined.is_empty())
                    .then(|| determined.iter().all(|a| *a == Agreement::Converged))
            }
            Self::Skipped { .. } => None,
        }
    }

    /// A table and the verdict, for a terminal or a report.
    pub fn markdown(&self) -> String {
        let mut md = String::from("\n## Mesh convergence of the motion\n\n");
        let Self::Checked {
            parameters,
            linear_rms_m,
            quadratic_rms_m,
            simulations,
        } = self
        else {
            if let Self::Skipped { reason } = self {
                let _ = writeln!(md, "Not checked: {reason}.\n");
            }
            return md;
        };
        let _ = writeln!(
            md,
            "The fitted runs refitted on quadratic 10-node elements of this mesh (which do not \
             lock in bending), by forward differences ({simulations} simulations):\n\n\
             | parameter | linear (this mesh's) | quadratic | difference |\n|---|---|---|---|"
        );
        for p in parameters {
            let (quadratic, sigma) = numbers::value_and_sd(p.quadratic, p.quadratic_sigma, "");
            let _ = writeln!(
                md,
                "| {} | {} | {quadratic} ± {sigma} | {:+.1} %{} |",
                p.name,
                numbers::plain(p.linear),
                100.0 * p.difference(),
                match p.agreement() {
                    Agreement::Converged => "",
                    Agreement::NotConverged => " (not converged)",
                    Agreement::Undetermined => " (not determined by the data)",
                }
            );
        }
        let _ = writeln!(
            md,
            "| marker RMS (mm) | {:.3} | {:.3} | |\n",
            1e3 * linear_rms_m,
            1e3 * quadratic_rms_m
        );
        let tol = 100.0 * TOLERANCE;
        let undetermined = 100.0 * UNDETERMINED;
        let _ = if self.converged() == Some(true) {
            writeln!(
                md,
                "**Converged**: every parameter the data determine within {tol:.0} % (or two of \
                 its σ) on both discretisations: the fitted material is the object's, not this \
                 mesh's.\n"
            )
        } else if self.converged().is_none() {
            writeln!(
                md,
                "**Not determined**: on quadratic elements every parameter's 1σ is above \
                 {undetermined:.0} % of it; the data do not say whether the material is this \
                 mesh's. Hold what bending cannot tell (Poisson's ratio, the viscosity's index) \
                 and check again.\n"
            )
        } else {
            writeln!(
                md,
                "**Not converged**: the parameters marked differ by more than {tol:.0} % and two \
                 of their σ. The \
                 linear fit's are this mesh's effective values (right on this mesh, what the \
                 runtime replays); the quadratic ones are the material's, to carry to another \
                 mesh or object.\n"
            )
        };
        md
    }
}

/// The fitted kinds the quadratic model refits, and whether each is fitted in its logarithm.
fn refittable(kind: ParamKind) -> Option<GlobalParam> {
    let log = match kind {
        ParamKind::Lambda
        | ParamKind::Mu
        | ParamKind::Nu
        | ParamKind::Stiffening
        | ParamKind::CreepFraction
        | ParamKind::CreepTime => true,
        ParamKind::PowerH => false,
        _ => return None,
    };
    Some(GlobalParam { kind, log })
}

/// A fitted run: its name, model and observations.
pub type FittedRun<'a> = (&'a str, &'a Model, &'a Observations);

/// Refits the runs `fit` on quadratic elements: `material` is the linear fit's, `kinds` its
/// fitted global parameters, `poisson` the held ratio (λ then follows μ), `modulus_scale` the
/// rest states' quadratic-to-linear modulus ratio (1 when unknown) and `linear_rms_m` the
/// linear fit's marker RMS. `log` receives progress lines.
pub fn check(
    fit: &[FittedRun<'_>],
    material: &Material,
    kinds: &[ParamKind],
    poisson: Option<f64>,
    modulus_scale: f64,
    linear_rms_m: f64,
    log: &dyn Fn(&str),
) -> MotionConvergence {
    let skipped = |reason: String| MotionConvergence::Skipped { reason };
    if material.spline.is_some() || !material.regions.is_empty() {
        return skipped("quadratic elements refit one Neo-Hookean material only".into());
    }
    if let Some(k) = material
        .values
        .iter()
        .position(|v| v.iter().any(|&x| x != v[0]))
    {
        return skipped(format!(
            "{} varies over the elements; quadratic elements refit uniform values only",
            ParamKind::EVERY[k].name()
        ));
    }
    let mut params = Vec::new();
    for &kind in kinds {
        match refittable(kind) {
            Some(p) => params.push(p),
            None => {
                return skipped(format!(
                    "{} is fitted, which the quadratic refit does not carry",
                    kind.name()
                ))
            }
        }
    }
    if params.is_empty() {
        return skipped("no material parameter was fitted".into());
    }
    let lifted: Vec<QuadraticMotion<'_>> = match fit
        .iter()
        .map(|(_, m, _)| QuadraticMotion::new(m))
        .collect()
    {
        Ok(l) => l,
        Err(e) => return skipped(format!("the quadratic model could not be made: {e}")),
    };
    let forwards: Vec<Box<Forward<'_>>> = lifted
        .iter()
        .map(|q| -> Box<Forward<'_>> { Box::new(move |m: &Material| Ok(q.simulate(m)?.markers)) })
        .collect();
    let runs: Vec<DifferenceRun<'_>> = fit
        .iter()
        .zip(&forwards)
        .map(|((_, _, obs), f)| DifferenceRun {
            obs,
            forward: f.as_ref(),
        })
        .collect();
    let linear: Vec<f64> = params.iter().map(|p| material.get(p.kind, 0)).collect();
    let start: Vec<f64> = params
        .iter()
        .zip(&linear)
        .map(|(p, &v)| match p.kind {
            ParamKind::Lambda | ParamKind::Mu | ParamKind::Stiffening => v * modulus_scale,
            _ => v,
        })
        .collect();
    log(&format!(
        "motion mesh convergence: refitting {} on quadratic elements ({} free dofs)",
        params
            .iter()
            .map(|p| p.kind.name())
            .collect::<Vec<_>>()
            .join(", "),
        lifted.first().map_or(0, QuadraticMotion::free_dofs)
    ));
    let progress = |it: usize, rms: f64| {
        log(&format!(
            "motion mesh convergence: iteration {it}, marker RMS {:.4} mm",
            1e3 * rms
        ))
    };
    let out = match fit_by_differences(
        &runs,
        material,
        &params,
        &start,
        poisson,
        MAX_ITERATIONS,
        &progress,
    ) {
        Ok(o) => o,
        Err(e) => return skipped(format!("the quadratic fit failed: {e}")),
    };
    MotionConvergence::Checked {
        parameters: params
            .iter()
            .zip(linear.iter().zip(out.values.iter().zip(&out.std)))
            .map(|(p, (&l, (&q, &s)))| Parameter {
                name: p.kind.name(),
                linear: l,
                quadratic: q,
                quadratic_sigma: s,
            })
            .collect(),
        linear_rms_m,
        quadratic_rms_m: out.rms,
        simulations: out.simulations,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_motion::scenario::{example_bar, observed};
    use palpate_motion::viscosity::Form;

    fn checked(d_mu: f64, d_visc: f64) -> MotionConvergence {
        MotionConvergence::Checked {
            parameters: vec![
                Parameter {
                    name: "mu",
                    linear: 46e3,
                    quadratic: 46e3 * (1.0 + d_mu),
                    quadratic_sigma: 60.0,
                },
                Parameter {
                    name: "viscosity",
                    linear: 200.0,
                    quadratic: 200.0 * (1.0 + d_visc),
                    quadratic_sigma: 2.0,
                },
            ],
            linear_rms_m: 4.9e-4,
            quadratic_rms_m: 5.6e-4,
            simulations: 50,
        }
    }

    #[test]
    fn every_parameter_must_be_within_the_tolerance() {
        let locked = checked(0.92, 0.14);
        assert_eq!(locked.converged(), Some(false));
        let md = locked.markdown();
        assert!(md.contains("+92.0 % (not converged)"), "{md}");
        assert!(md.contains("**Not converged**"), "{md}");
        let close = checked(0.9 * TOLERANCE, -0.9 * TOLERANCE);
        assert_eq!(close.converged(), Some(true));
        assert!(close.markdown().contains("**Converged**"));
        assert_eq!(checked(0.0, 1.1 * TOLERANCE).converged(), Some(false));
        // Within two σ is within the fit's own uncertainty; a σ above a fifth of the value is
        // not determined, and with nothing determined there is no verdict.
        let mut wide = checked(0.0, 0.3);
        if let MotionConvergence::Checked { parameters, .. } = &mut wide {
            parameters[1].quadratic_sigma = 40.0;
            assert_eq!(parameters[1].agreement(), Agreement::Converged);
            parameters[1].quadratic_sigma = 60.0;
            assert_eq!(parameters[1].agreement(), Agreement::Undetermined);
            parameters[0].quadratic_sigma = 30e3;
        }
        assert_eq!(wide.converged(), None);
        let md = wide.markdown();
        assert!(md.contains("(not determined by the data)") && md.contains("**Not determined**"));
        let skipped = MotionConvergence::Skipped {
            reason: "density is fitted".into(),
        };
        assert_eq!(skipped.converged(), None);
        assert!(skipped
            .markdown()
            .contains("Not checked: density is fitted."));
    }

    /// A bar shaken at its base whose data were made on quadratic elements, and a "linear fit"
    /// of it at the locked modulus: the refit finds the truth and says the linear modulus is
    /// the mesh's, under either reading of the viscosity. A fitted density is refused with its
    /// reason.
    #[test]
    fn the_refit_finds_the_quadratic_truth_and_calls_the_locked_modulus_the_meshs() {
        for form in [Form::RestGradient, Form::Objective] {
            refit_finds_the_quadratic_truth(form);
        }
    }

    fn refit_finds_the_quadratic_truth(form: Form) {
        let (_, mut model) = example_bar([2, 8, 2], 60).unwrap();
        model.static_start = false;
        let nu = 0.49;
        let ratio = 2.0 * nu / (1.0 - 2.0 * nu);
        let mut truth =
            Material::uniform(model.tets.len(), 2.0e4 * ratio, 2.0e4, 12.0, 1.0, 1000.0);
        truth.viscous_form = form;
        let run = QuadraticMotion::new(&model)
            .unwrap()
            .simulate(&truth)
            .unwrap();
        let obs = observed(&run.markers);
        let mut locked = truth.clone();
        locked.set_uniform(ParamKind::Mu, 1.0e4);
        locked.set_uniform(ParamKind::Lambda, 1.0e4 * ratio);
        let runs = [("bar", &model, &obs)];
        let kinds = [ParamKind::Mu, ParamKind::Nu];
        let c = check(&runs, &locked, &kinds, Some(nu), 1.5, 1e-4, &|_| {});
        let MotionConvergence::Checked { parameters, .. } = &c else {
            panic!("{form:?}: {c:?}");
        };
        assert!(
            (parameters[0].quadratic / 2.0e4 - 1.0).abs() < 1e-3,
            "{form:?}: {parameters:?}"
        );
        assert!(
            (parameters[1].quadratic / 12.0 - 1.0).abs() < 1e-2,
            "{form:?}: {parameters:?}"
        );
        assert_eq!(c.converged(), Some(false));
        let refused = check(
            &runs,
            &locked,
            &[ParamKind::Mu, ParamKind::Density],
            Some(nu),
            1.5,
            1e-4,
            &|_| {},
        );
        assert!(
            matches!(&refused, MotionConvergence::Skipped { reason } if reason.contains("density")),
            "{refused:?}"
        );
    }
}
