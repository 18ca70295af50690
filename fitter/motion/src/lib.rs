//! Motion fitter (seed 001, Real2Sim, Hahn et al. 2019): visco-elastic material parameters from
//! dynamic motion.
//!
//! - [`hyperelastic`], [`viscosity`]: element kernels (eqs. 16–17);
//! - [`model`], [`forces`], [`sparse`]: the FEM model, global forces/tangents, faer Cholesky with
//!   the symbolic analysis reused across Newton iterations, steps and simulations;
//! - [`sim`]: elastostatic start (§3.4) and BDF2 + Newton (eq. 2);
//! - [`objective`], [`gradient`]: eq. 15 and its force analogue; direct (eqs. 5–6) and adjoint
//!   (eqs. 8–12, 14) gradients;
//! - [`optimize`]: log-parameter LBFGS (§4.3) with a Wolfe line search (argmin);
//! - [`statics`]: a reusable quasi-static hyperelastic solver (the specimen generator's);
//! - [`quadratic_statics`]: the same on quadratic (10-node) tetrahedra, which do not lock;
//! - [`rest_fit`]: the shear modulus fitted to datasets' rest states through either design;
//! - [`scenario`]: synthetic set-ups (bars with moving clamps) shared by bench, evidence, tests;
//! - [`dataset`]: the motion dataset reader (docs/motion-dataset.md);
//! - [`spline`], [`elastic`]: the principal-stretch spline material of §4.2 (eqs. 18–20) and the
//!   per-element switch between it and Neo-Hookean;
//! - [`export`]: a motion fit as a runtime model (Lamé → thesis (λ, α));
//! - [`golden_section`]: a one-parameter search without gradients;
//! - [`line_minimum`]: a one-coordinate minimum from values alone (a bracket, then Brent's method);
//! - [`predict`], [`validation`]: a run predicted from a fitted material and its linear
//!   baseline; a fitted model validated on a run, its table, JSON line and files.

pub mod dataset;
pub mod difference_fit;
pub mod elastic;
pub mod export;
pub mod fitted;
mod force_lanes;
pub mod forces;
pub mod golden_section;
pub mod gradient;
pub mod hyperelastic;
pub mod line_minimum;
pub mod load_point;
pub mod model;
pub mod objective;
pub mod optimize;
mod pipeline;
pub mod predict;
pub mod quadratic_motion;
pub mod quadratic_statics;
pub mod refine;
pub mod relaxation;
pub mod request;
pub mod rest_fit;
pub mod scenario;
pub mod settling;
pub mod sim;
pub mod sparse;
pub mod spline;
pub mod start;
mod static_newton;
pub mod statics;
pub mod step_error;
pub mod time_offset;
pub mod timestep;
pub mod transfer;
pub mod validation;
pub mod viscosity;

/// Errors of the motion simulator, gradients and optimiser.
#[derive(Debug, Clone, thiserror::Error)]
pub enum MotionError {
    /// An element is degenerate at rest.
    #[error("element {element}: unusable rest geometry ({why})")]
    BadElement {
        /// Element index.
        element: usize,
        /// Defect.
        why: String,
    },
    /// An element turned inside out (J ≤ 0): the simulation is unstable for these parameters.
    #[error(
        "element {element} inverted (det F <= 0): the simulation is unstable for these parameters"
    )]
    Inverted {
        /// Element index.
        element: usize,
    },
    /// The Newton system matrix was not positive definite.
    #[error("step {step}: system matrix not positive definite (unstable material or time step)")]
    NotPositiveDefinite {
        /// Time step (0 = elastostatic start).
        step: usize,
    },
    /// Newton did not converge (only fatal for the elastostatic start and statics).
    #[error("step {step}: Newton did not converge (residual {residual:.3e} N)")]
    NoConvergence {
        /// Time step (0 = elastostatic start) or load step.
        step: usize,
        /// Final residual norm.
        residual: f64,
    },
    /// A force or residual became NaN/∞.
    #[error("non-finite {0}")]
    NonFinite(String),
    /// Inconsistent model input.
    #[error("{0}")]
    Invalid(String),
}
