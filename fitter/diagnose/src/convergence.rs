//! Is the fitted modulus the material's or the mesh's? Linear tetrahedra lock in bending near
//! incompressibility, so the μ a motion fit reads through them changes with the mesh
//! (`docs/results/beam/convergence.md`: 133 kPa on one mesh of the beam, 159 on a finer one,
//! while quadratic elements give 256 and 262). The check: the fitted runs' **rest states** (the
//! markers settled at the end of each capture, [`palpate_motion::rest_fit`]) fitted for μ at the
//! diagnosis' Poisson's ratio twice on the dataset's mesh — linear (P1, what the motion fit
//! uses) and quadratic 10-node elements on the same corners (P2, converged within a few per cent
//! where P1 is off by half). When the two moduli differ by more than [`TOLERANCE`], the report
//! says the motion fit's modulus is the mesh's, and which figure is the material's.
//!
//! A run whose markers still move in the window (their scatter about its mean above the final
//! model's fitted RMS) has no rest state to fit: the check is skipped and says so.

use palpate_fem::numbers;
use palpate_motion::dataset::MotionDataset;
use palpate_motion::fitted::ConvergedModulus;
use palpate_motion::rest_fit::{fit_shear_modulus, Design, RestSolve, RestState};
use serde::Serialize;
use std::fmt::Write as _;

/// The last stretch of each capture taken as its rest state (s).
pub const WINDOW_S: f64 = 0.5;

/// Relative difference of the P1 and P2 moduli above which the fitted modulus is the mesh's:
/// the 5 % a converged parameter is held to across two discretisations.
pub const TOLERANCE: f64 = 0.05;

/// The rest states' solve: four load increments (a beam sags by centimetres), Newton to 1 µN.
const SOLVE: RestSolve = RestSolve {
    load_steps: 4,
    tol: 1e-6,
};

/// Gauss–Newton iterations in ln μ at most (each one solve and one sensitivity per run).
const MAX_ITER: usize = 12;

/// One design's rest-state fit.
#[derive(Debug, Clone, Serialize)]
pub struct RestModulus {
    /// "P1" or "P2".
    pub design: &'static str,
    /// Young's modulus E = 2μ(1 + ν) (Pa).
    pub young_pa: f64,
    /// Each fitted run's rest-state marker RMS at that modulus (m).
    pub rest_rms_m: Vec<f64>,
    /// Gauss–Newton iterations.
    pub iterations: usize,
}

/// The check's outcome.
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "outcome", rename_all = "kebab-case")]
pub enum MeshConvergence {
    /// Both designs fitted.
    Checked {
        /// The window of each capture taken as its rest state (s).
        window_s: f64,
        /// Poisson's ratio held (the diagnosis').
        poisson: f64,
        /// Linear elements (the motion fit's).
        linear: RestModulus,
        /// Quadratic elements on the same mesh.
        quadratic: RestModulus,
    },
    /// Not checked, and why.
    Skipped {
        /// Why.
        reason: String,
    },
}

impl MeshConvergence {
    /// What `fit.json` records of a checked outcome: both shear moduli at the held Poisson's
    /// ratio.
    pub fn converged_modulus(&self) -> Option<ConvergedModulus> {
        match self {
            Self::Checked {
                poisson,
                linear,
                quadratic,
                ..
            } => {
                let mu = |e: f64| e / (2.0 * (1.0 + poisson));
                Some(ConvergedModulus {
                    design: quadratic.design.into(),
                    poisson: *poisson,
                    shear_modulus_pa: mu(quadratic.young_pa),
                    mesh_shear_modulus_pa: mu(linear.young_pa),
                })
            }
            Self::Skipped { .. } => None,
        }
    }

    /// P2's modulus over P1's, minus one, when checked.
    pub fn difference(&self) -> Option<f64> {
        match self {
            Self::Checked {
                linear, quadratic, ..
            } => Some(quadratic.young_pa / linear.young_pa - 1.0),
            Self::Skipped { .. } => None,
        }
    }

    /// Whether the modulus is converged on this mesh (P1 and P2 within [`TOLERANCE`]); `None`
    /// when not checked.
    pub fn converged(&self) -> Option<bool> {
        self.difference().map(|d| d.abs() <= TOLERANCE)
    }

    /// One line for a terminal: both moduli and the verdict, or why it was not checked.
    pub fn summary_line(&self) -> String {
        match self {
            Self::Skipped { reason } => format!("mesh convergence not checked: {reason}"),
            Self::Checked {
                linear, quadratic, ..
            } => format!(
                "mesh convergence: E {} on linear elements, {} on quadratic ones ({:+.1} %): {}",
                numbers::pressure(linear.young_pa),
                numbers::pressure(quadratic.young_pa),
                100.0 * self.difference().unwrap_or(f64::NAN),
                if self.converged() == Some(true) {
                    "converged, the modulus is the material's"
                } else {
                    "not converged, the fitted modulus is this mesh's and the quadratic one the \
                     material's"
                }
            ),
        }
    }

    /// The report's section: both moduli, the fitted runs' rest-state errors and the verdict,
    /// or why it was not checked.
    pub fn markdown(&self) -> String {
        let mut md = String::from("\n## Mesh convergence of the modulus\n\n");
        let (window_s, poisson, linear, quadratic) = match self {
            Self::Skipped { reason } => {
                let _ = writeln!(md, "Not checked: {reason}.\n");
                return md;
            }
            Self::Checked {
                window_s,
                poisson,
                linear,
                quadratic,
            } => (window_s, poisson, linear, quadratic),
        };
        let rms = |m: &RestModulus| {
            m.rest_rms_m
                .iter()
                .map(|v| format!("{:.3}", 1e3 * v))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let _ = writeln!(
            md,
            "The fitted runs' rest states (the markers' mean over the last {window_s} s of each) \
             fitted for E at the motion fit's Poisson's ratio ({poisson:.3}) on this mesh, with its linear \
             elements and with quadratic 10-node elements on the same corners (which do not lock in \
             bending):\n\n| elements | E | rest-state RMS per fitted run (mm) |\n|---|---|---|\n\
             | linear (P1, the motion fit's) | {} | {} |\n| quadratic (P2) | {} | {} |\n",
            numbers::pressure(linear.young_pa),
            rms(linear),
            numbers::pressure(quadratic.young_pa),
            rms(quadratic),
        );
        let d = 100.0 * self.difference().unwrap_or(f64::NAN);
        let tol = 100.0 * TOLERANCE;
        let _ = if self.converged() == Some(true) {
            writeln!(
                md,
                "**Converged**: the two differ by {d:+.1} % (within {tol:.0} %): the fitted modulus \
                 is the material's, not this mesh's.\n"
            )
        } else {
            writeln!(
                md,
                "**Not converged**: quadratic elements give {d:+.1} % (more than {tol:.0} %). The \
                 motion fit's modulus is this mesh's: carried to another mesh or object it is wrong by \
                 about that much. The material's modulus is the quadratic figure; the fitted model is \
                 this mesh's effective one, right on this mesh (what the runtime replays).\n"
            )
        };
        md
    }
}

/// Checks the runs `fit` at Poisson's ratio `poisson`, from the motion fit's shear modulus `mu`;
/// `fitted_rms_m` is the final model's fitted marker RMS, the scale below which the markers'
/// scatter in the window counts as at rest. `log` receives progress lines.
pub fn check(
    fit: &[(&str, &MotionDataset)],
    poisson: f64,
    mu: f64,
    fitted_rms_m: f64,
    log: &dyn Fn(&str),
) -> MeshConvergence {
    let skipped = |reason: String| MeshConvergence::Skipped { reason };
    let mut states = Vec::with_capacity(fit.len());
    for &(name, ds) in fit {
        if ds.config.density.is_none() {
            return skipped(format!(
                "{name} declares no density: a rest state needs the body's weight"
            ));
        }
        let state = match RestState::of_dataset(ds, WINDOW_S) {
            Ok(s) => s,
            Err(e) => return skipped(format!("{name}: no rest state: {e}")),
        };
        let scatter = scatter_in_window(ds, WINDOW_S);
        // A NaN fit or scatter is no evidence of rest either.
        let at_rest = scatter <= fitted_rms_m;
        if !at_rest {
            return skipped(format!(
                "{name}'s markers still move in its last {WINDOW_S} s (scatter {:.3} mm about \
                 their mean, above the fitted RMS {:.3} mm): no rest state to fit",
                1e3 * scatter,
                1e3 * fitted_rms_m
            ));
        }
        states.push(state);
    }
    log(&format!(
        "mesh convergence: fitting μ to the rest states of {} run(s) on linear and quadratic \
         elements",
        states.len()
    ));
    let fitted = |design: Design, mu0: f64| {
        fit_shear_modulus(&states, design, poisson, mu0, &SOLVE, MAX_ITER).map(|f| {
            let modulus = RestModulus {
                design: design.name(),
                young_pa: 2.0 * f.mu * (1.0 + poisson),
                rest_rms_m: f
                    .predictions
                    .iter()
                    .zip(&states)
                    .map(|(p, s)| p.rms(s))
                    .collect(),
                iterations: f.iterations,
            };
            (f.mu, modulus)
        })
    };
    let (mu1, linear) = match fitted(Design::Linear, mu) {
        Ok(f) => f,
        Err(e) => return skipped(format!("the linear rest-state fit failed: {e}")),
    };
    let quadratic = match fitted(Design::Quadratic, mu1) {
        Ok((_, m)) => m,
        Err(e) => return skipped(format!("the quadratic rest-state fit failed: {e}")),
    };
    log(&format!(
        "mesh convergence: E {:.4} kPa (P1), {:.4} kPa (P2)",
        linear.young_pa / 1e3,
        quadratic.young_pa / 1e3
    ));
    MeshConvergence::Checked {
        window_s: WINDOW_S,
        poisson,
        linear,
        quadratic,
    }
}

/// RMS over the markers of their scatter about their own mean in the last `window` seconds of
/// `ds` (m): ≈ the noise where the body is at rest.
pub(crate) fn scatter_in_window(ds: &MotionDataset, window: f64) -> f64 {
    let rows = &ds.obs.markers;
    let end = ds.model.steps.min(rows.len());
    let first = end.saturating_sub((window / ds.model.dt).round() as usize);
    let (mut sum, mut count) = (0.0, 0usize);
    for i in 0..ds.model.markers.len() {
        let seen: Vec<[f64; 3]> = rows[first..end]
            .iter()
            .filter_map(|r| r.get(i).copied().flatten())
            .collect();
        if seen.len() < 2 {
            continue;
        }
        let k = seen.len() as f64;
        let mean = [0, 1, 2].map(|d| seen.iter().map(|p| p[d]).sum::<f64>() / k);
        for p in &seen {
            sum += (0..3).map(|d| (p[d] - mean[d]).powi(2)).sum::<f64>();
        }
        count += seen.len();
    }
    if count == 0 {
        f64::INFINITY
    } else {
        (sum / count as f64).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn checked(p1: f64, p2: f64) -> MeshConvergence {
        let m = |design, young_pa| RestModulus {
            design,
            young_pa,
            rest_rms_m: vec![4e-4, 7e-4],
            iterations: 3,
        };
        MeshConvergence::Checked {
            window_s: WINDOW_S,
            poisson: 0.49,
            linear: m("P1", p1),
            quadratic: m("P2", p2),
        }
    }

    #[test]
    fn the_verdict_turns_at_the_tolerance() {
        let locked = checked(133.3e3, 256.3e3);
        assert_eq!(locked.converged(), Some(false));
        let md = locked.markdown();
        assert!(
            md.contains("**Not converged**") && md.contains("+92.3 %"),
            "{md}"
        );
        assert!(md.contains("0.400, 0.700"), "{md}");
        let line = locked.summary_line();
        assert!(
            line.contains("+92.3 %") && line.contains("not converged"),
            "{line}"
        );
        let close = checked(250e3, 250e3 * (1.0 + 0.9 * TOLERANCE));
        assert_eq!(close.converged(), Some(true));
        assert!(close.markdown().contains("**Converged**"));
        assert_eq!(
            checked(250e3, 250e3 * (1.0 - 1.1 * TOLERANCE)).converged(),
            Some(false)
        );
        let skipped = MeshConvergence::Skipped {
            reason: "no density".into(),
        };
        assert_eq!(skipped.converged(), None);
        assert!(skipped.markdown().contains("Not checked: no density."));
    }
}
