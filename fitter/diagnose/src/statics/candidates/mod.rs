//! The static room's library of candidate effects, one file per candidate. Each file says what
//! its effect models (parameters and units), where its parameters start, how the report names
//! them, what in the residual points to it, how large it must be to be detected, and its part of
//! the forward model — all through [`StaticEffect`], which the rest of the room calls instead of
//! naming candidates.
//!
//! A new candidate is a new file here implementing [`StaticEffect`], plus its line in
//! [`Candidate`] (the serialisable identity), in [`Candidate::effect`] and, if it is fitted, in
//! [`ALL_CANDIDATES`].
//!
//! The forward model ([`super::model::Model`]) calls the hooks of the effects it holds in library
//! order ([`ALL_CANDIDATES`]'s), whatever order they were adopted in: a load, a field or a marker
//! transform of two effects is composed the same way in every model.

use std::sync::Arc;

use palpate_fem::dataset::Marker;
use palpate_fem::forward::{Factorised, Material, StaticProblem};
use serde::Serialize;

use super::context::{Context, MeasData};
use super::model::{Model, Simulated};
use super::signature::{EvidencePoints, Residual};
use super::DiagnoseError;

mod boundary;
mod calibration;
mod contact_radius;
mod force_scale_each;
mod gravity;
mod inclusion;
mod inhomogeneity;
mod layer;
mod noise;
mod registration;
mod registration_each;
mod rest_noise;
mod stiffening;
mod support;
mod tilt;
mod tilt_each;

pub(in crate::statics) use tilt_each::responses as tilt_each_responses;
pub use tilt_each::TILT_PROBE;

/// A candidate effect of the library (each an augmented model with extra parameters). The
/// identity the reports serialise; what each is lives in its file, reached by
/// [`Candidate::effect`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Candidate {
    /// Force-sensor calibration curve (`calibration.rs`).
    Calibration,
    /// Tilted probe / tangential friction (`tilt.rs`).
    Tilt,
    /// Compliant support, moving rigidly (`boundary.rs`).
    Boundary,
    /// Elastic foundation under the supported face (`support.rs`).
    Support,
    /// One marker registration offset (`registration.rs`).
    Registration,
    /// A tangential force that differs from measurement to measurement (`tilt_each.rs`).
    TiltEach,
    /// A contact patch of another radius than declared (`contact_radius.rs`).
    ContactRadius,
    /// A registration offset in every measurement (`registration_each.rs`).
    RegistrationEach,
    /// A force-sensor gain in every measurement (`force_scale_each.rs`).
    ForceScaleEach,
    /// Gravity preload (`gravity.rs`).
    Gravity,
    /// A smooth log-modulus field over the bounding box (`inhomogeneity.rs`).
    Inhomogeneity,
    /// A modulus that varies with depth (`layer.rs`).
    Layer,
    /// A stiff or soft inclusion (`inclusion.rs`).
    Inclusion,
    /// Strain stiffening (`stiffening.rs`).
    Stiffening,
    /// Marker noise above the declared level; not a model candidate (`noise.rs`).
    Noise,
    /// Noise in the declared rest positions; not a model candidate (`rest_noise.rs`).
    RestNoise,
}

/// Every candidate, in the order they are tried.
pub const ALL_CANDIDATES: [Candidate; 14] = [
    Candidate::Calibration,
    Candidate::Tilt,
    Candidate::TiltEach,
    Candidate::ContactRadius,
    Candidate::Boundary,
    Candidate::Support,
    Candidate::Registration,
    Candidate::RegistrationEach,
    Candidate::ForceScaleEach,
    Candidate::Gravity,
    Candidate::Inhomogeneity,
    Candidate::Layer,
    Candidate::Inclusion,
    Candidate::Stiffening,
];

/// A name, unit and scale of one parameter for reports: the physical value is θ_j × scale.
pub type ParamName = (String, &'static str, f64);

/// The power statement's block of a candidate whose first parameter is a log contrast and whose
/// others (where it is, how thick or how large) are invisible at zero contrast: its start with
/// the contrast at zero, the others where the statement assumes them.
fn at_zero_contrast(mut start: Vec<f64>) -> Option<Vec<f64>> {
    start[0] = 0.0;
    Some(start)
}

/// Measurement-to-measurement responses of a profiled candidate (per measurement, its markers'
/// response to each of its directions).
pub type Responses = Vec<[Vec<[f64; 3]>; 2]>;

/// The node positions of the solves a profiled candidate's [`Responses`] were read from (per
/// measurement and direction): the start of the same solves at a nearby parameter point.
pub type ResponseStates = Vec<[Vec<[f64; 3]>; 2]>;

/// A nearby simulation's node positions and its [`ResponseStates`] (per measurement of the
/// same subset): where a Jacobian column's or a trial's response solves start.
pub type ResponsesNear<'a> = (&'a [Vec<[f64; 3]>], &'a [[Vec<[f64; 3]>; 2]]);

/// A kind of profiled parameter for the power statement: (name, unit, its residual columns in
/// units of σ, one per measurement and direction).
pub type ProfiledKind = (&'static str, &'static str, Vec<Vec<f64>>);

/// A model at a parameter point: what the hooks that solve need.
#[derive(Clone, Copy)]
pub struct At<'a> {
    /// The model.
    pub model: &'a Model,
    /// The dataset.
    pub ctx: &'a Context,
    /// Its parameters.
    pub theta: &'a [f64],
    /// The material fields' log-E offsets at `theta` (`None` without any).
    pub log_e: Option<&'a [f64]>,
}

/// The power statement's linearisation point: the final model with every θ candidate at zero
/// effect, simulated.
pub struct PowerPoint<'a> {
    /// The augmented model at `theta`.
    pub at: At<'a>,
    /// The measurements fitted.
    pub subset: &'a [usize],
    /// Its simulation.
    pub sim: &'a Simulated,
}

/// What a candidate effect is: its parameters, its report words, its residual signature, its
/// power statement and its part of the forward model. Every method but the name and the
/// signature has the default of an effect that does not take part there.
pub trait StaticEffect: Sync {
    /// Name (as in reports and the serialised [`Candidate`]).
    fn name(&self) -> &'static str;

    /// Number of parameters the effect adds to θ.
    fn params(&self, _grid: [usize; 3]) -> usize {
        0
    }

    /// Parameters fitted in closed form for each of `measurements` measurements rather than in θ
    /// (counted by BIC and the held-out gate all the same).
    fn profiled(&self, _measurements: usize) -> usize {
        0
    }

    /// Starting values of its block when it is added to a fitted model (zero: the effect absent).
    fn start(&self, grid: [usize; 3]) -> Vec<f64> {
        vec![0.0; self.params(grid)]
    }

    /// Starting values of its block in the selection loop, where the dataset's scans may place it.
    fn fit_start(&self, _ctx: &Context, grid: [usize; 3]) -> Vec<f64> {
        self.start(grid)
    }

    /// Whether [`StaticEffect::fit_start`] is where the diagnosis' sensitivity scan of the data
    /// places it (else it starts at zero effect, or at a fixed start).
    fn placed_by_scan(&self) -> bool {
        false
    }

    /// Whether the dataset can hold the effect at all.
    fn available(&self, _ctx: &Context) -> bool {
        true
    }

    /// Whether its parameters change the FEM solve (else they act on the solved markers only).
    fn affects_solve(&self) -> bool {
        true
    }

    /// Names and physical units of its θ parameters (after scaling), for reports.
    fn param_names(&self, _grid: [usize; 3]) -> Vec<ParamName> {
        Vec::new()
    }

    /// Whether the runtime model carries it (a property of the object, not of the measurement).
    fn in_runtime_model(&self) -> bool {
        false
    }

    /// What its adoption leaves known only relative to an assumption, in words for the report
    /// (`None`: nothing): a sensor gain that E absorbs, for one.
    fn relative_note(&self, _ctx: &Context) -> Option<String> {
        None
    }

    /// The variable that gives the effect away and the residual measure plotted against it.
    fn evidence(&self, r: &Residual) -> EvidencePoints;

    /// Its θ block at zero effect for the power statement (`None`: no θ statement).
    fn power_start(&self, grid: [usize; 3]) -> Option<Vec<f64>> {
        (self.params(grid) > 0).then(|| self.start(grid))
    }

    /// The columns of its block that carry its magnitude at zero effect.
    fn live_columns(&self, grid: [usize; 3]) -> Vec<usize> {
        (0..self.params(grid)).collect()
    }

    /// What its power statement assumes beyond the linearisation.
    fn power_note(&self) -> Option<&'static str> {
        None
    }

    /// The largest |θ| of a live parameter at which the effect is still a plausible one of its
    /// kind (`None`: no limit); a power statement beyond it is not checked by injection
    /// ([`crate::statics::power_check`]). A field of log E: a factor 10 from the body's modulus.
    fn plausible_magnitude(&self) -> Option<f64> {
        self.material_field().then_some(std::f64::consts::LN_10)
    }

    /// A profiled candidate's residual columns by kind at the power statement's point (`None`:
    /// not profiled).
    fn profiled_columns(
        &self,
        _p: &PowerPoint,
    ) -> Option<Result<Vec<ProfiledKind>, DiagnoseError>> {
        None
    }

    /// The force the model applies, given the one before it (`force`) and the reported
    /// magnitude `reported`.
    fn force(&self, _ctx: &Context, _b: &[f64], _reported: f64, force: [f64; 3]) -> [f64; 3] {
        force
    }

    /// Changes the probe's nodal load `f` of measurement `m` carrying `force`.
    fn load_change(
        &self,
        _problem: &StaticProblem,
        _m: &MeasData,
        _b: &[f64],
        _force: [f64; 3],
        _f: &mut [f64],
    ) -> Result<(), DiagnoseError> {
        Ok(())
    }

    /// Adds a load that acts in every measurement besides the probe's to `fvec`.
    fn body_force(&self, _ctx: &Context, _b: &[f64], _fvec: &mut [f64]) {}

    /// Whether it is a spatial field of log E ([`StaticEffect::add_log_e`]).
    fn material_field(&self) -> bool {
        false
    }

    /// Adds its per-element log-E offsets to `out`.
    fn add_log_e(&self, _ctx: &Context, _b: &[f64], _out: &mut [f64]) {}

    /// Changes the solve's material (e.g. the support under the body).
    fn material(&self, _ctx: &Context, _theta: &[f64], _b: &[f64], _m: &mut Material) {}

    /// Whether the body is solved on [`Context::foundation`]'s problem.
    fn on_foundation(&self) -> bool {
        false
    }

    /// Whether its material depends on the solved state (a secant fixed point).
    fn state_dependent(&self) -> bool {
        false
    }

    /// Per-element log-E offsets at the solved state `x` (state-dependent effects).
    fn secant_log_e(&self, _ctx: &Context, _x: &[[f64; 3]], _b: &[f64]) -> Option<Vec<f64>> {
        None
    }

    /// The state-dependent equilibrium under `load` (force vector, measurement id) from the
    /// linear state `start` and the warm log-modulus offsets `m0`.
    fn equilibrium(
        &self,
        _at: At,
        _b: &[f64],
        _load: (&[f64], &str),
        _m0: Option<Vec<f64>>,
        start: (Vec<[f64; 3]>, Arc<Factorised>),
    ) -> Result<(Vec<[f64; 3]>, Arc<Factorised>), DiagnoseError> {
        Ok(start)
    }

    /// The markers re-embedded where the effect puts them on the unloaded body (`None`: the
    /// dataset's embedding).
    fn marker_embedding(&self, _at: At, _b: &[f64]) -> Option<Result<Vec<Marker>, DiagnoseError>> {
        None
    }

    /// Moves one simulated marker `p` of measurement `m` (model force `force`).
    fn move_marker(
        &self,
        _ctx: &Context,
        _b: &[f64],
        _m: &MeasData,
        _force: [f64; 3],
        p: [f64; 3],
    ) -> [f64; 3] {
        p
    }

    /// Extra marker responses its profile needs, solved at `xs` (per measurement of `subset`;
    /// started from `near`'s states moved with xs where given), and the states they were read
    /// from.
    fn responses(
        &self,
        _at: At,
        _subset: &[usize],
        _sim: (&[Vec<[f64; 3]>], &[Arc<Factorised>], Option<&[Marker]>),
        _near: Option<ResponsesNear>,
    ) -> Option<Result<(Responses, ResponseStates), DiagnoseError>> {
        None
    }

    /// Rescales the simulated markers `sims` of `subset` together (a profile over measurements).
    fn scale_responses(&self, _ctx: &Context, _subset: &[usize], _sims: &mut [Vec<[f64; 3]>]) {}

    /// Its closed-form profile on measurement `i`'s simulated markers (`responses`: its own
    /// responses for that measurement, when solved).
    fn profile(
        &self,
        _ctx: &Context,
        _i: usize,
        sim: Vec<[f64; 3]>,
        _responses: Option<&[Vec<[f64; 3]>; 2]>,
    ) -> Vec<[f64; 3]> {
        sim
    }
}

impl Candidate {
    /// What the candidate is.
    pub fn effect(self) -> &'static dyn StaticEffect {
        match self {
            Candidate::Calibration => &calibration::Calibration,
            Candidate::Tilt => &tilt::Tilt,
            Candidate::Boundary => &boundary::Boundary,
            Candidate::Support => &support::Support,
            Candidate::Registration => &registration::Registration,
            Candidate::TiltEach => &tilt_each::TiltEach,
            Candidate::ContactRadius => &contact_radius::ContactRadius,
            Candidate::RegistrationEach => &registration_each::RegistrationEach,
            Candidate::ForceScaleEach => &force_scale_each::ForceScaleEach,
            Candidate::Gravity => &gravity::Gravity,
            Candidate::Inhomogeneity => &inhomogeneity::Inhomogeneity,
            Candidate::Layer => &layer::Layer,
            Candidate::Inclusion => &inclusion::Inclusion,
            Candidate::Stiffening => &stiffening::Stiffening,
            Candidate::Noise => &noise::Noise,
            Candidate::RestNoise => &rest_noise::RestNoise,
        }
    }

    /// The names of `list` joined by `separator`, or `none` for an empty list.
    pub fn names(list: &[Candidate], separator: &str, none: &str) -> String {
        if list.is_empty() {
            none.to_string()
        } else {
            list.iter()
                .map(|c| c.name())
                .collect::<Vec<_>>()
                .join(separator)
        }
    }

    /// Name (as in reports).
    pub fn name(self) -> &'static str {
        self.effect().name()
    }

    /// Number of parameters the effect adds.
    pub fn params(self, grid: [usize; 3]) -> usize {
        self.effect().params(grid)
    }

    /// Parameters fitted in closed form for each of `measurements` measurements rather than in θ
    /// (counted by BIC and the held-out gate all the same).
    pub fn profiled(self, measurements: usize) -> usize {
        self.effect().profiled(measurements)
    }

    /// Every parameter the effect adds over `measurements` measurements: θ's and the profiled.
    pub fn all_params(self, grid: [usize; 3], measurements: usize) -> usize {
        self.params(grid) + self.profiled(measurements)
    }

    /// Starting values of its block when it is added to a fitted model.
    pub fn start(self, grid: [usize; 3]) -> Vec<f64> {
        self.effect().start(grid)
    }

    /// Whether its parameters change the FEM solve (else they act on the solved markers only).
    pub(super) fn affects_solve(self) -> bool {
        self.effect().affects_solve()
    }

    /// Names and physical units of its parameters (after scaling), for reports.
    pub fn param_names(self, grid: [usize; 3]) -> Vec<ParamName> {
        self.effect().param_names(grid)
    }
}

impl crate::select::CandidateEffect for Candidate {
    const LIBRARY: &'static str = "candidate";
    fn library() -> Vec<Self> {
        ALL_CANDIDATES.to_vec()
    }
    fn label(self) -> String {
        self.name().into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The serialised identity and the effect's report name are one name.
    #[test]
    fn every_candidate_serialises_as_its_effect_name() {
        for c in ALL_CANDIDATES
            .iter()
            .chain(&[Candidate::Noise, Candidate::RestNoise])
        {
            let json = serde_json::to_string(c).unwrap();
            assert_eq!(json, format!("\"{}\"", c.name()));
        }
    }
}
