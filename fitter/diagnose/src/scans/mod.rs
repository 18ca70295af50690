//! The scan room: a scan dataset (`docs/scan-dataset.md`: an object hanging, held or twisted,
//! seen by a depth camera or a scanner) diagnosed — the simplest model (one material, the scans
//! where they were declared) fitted, the residual on the surface, the effects it lacks tried,
//! those that earn their parameters on points the fit did not see adopted, before/after.
//!
//! | effect | parameters | what it is |
//! |---|---|---|
//! | `second-material` | μ₂ and a split | two materials declared as one ([`palpate_scan::regions`]: the best split by a linearised screen, its two moduli fitted) |
//! | `camera-moved` | 6 per scan | a camera bumped between scans, or a pose declared by hand: each scan registered onto its clamped and held part at the fitted equilibrium |
//! | `depth-bias` | 1 | the depth camera's offset along its rays, one sensor for every scan |
//! | `depth-scale` | 1 | the depth camera's scale error along its rays (a depth read (1 + s) × too far), one sensor |
//!
//! The held-out data are each scan's points in the odd cubes of a checkerboard
//! ([`fit::BLOCKS`]); the gate is the shared held-out gate ([`crate::select::HeldoutGate`]): ΔBIC
//! on the fitted points below −10, held-out ΔBIC below 0, held-out RMS down by 2 %; a second
//! material must also be plausible — both parts of at least [`MIN_PART_ELEMENTS`] elements,
//! their moduli more than [`MIN_RATIO`] apart (a mesh's own error near a clamp fits as a few per
//! cent of stiffness next to it).
//!
//! The verdict is honest: "explained" only when the residual, fitted and held out, is within
//! [`EXPLAINED`] × its noise floor.

pub mod fit;
pub mod report;
mod room;
pub mod run;

pub use palpate_scan::fit::Design;
pub use palpate_scan::regions::{MIN_PART_ELEMENTS, MIN_RATIO};

use crate::select::{select, CandidateEffect, GateDetail, Policy, Rank, Screen, Stop};
use crate::Error;
use fit::{Evidence, Problem, ScanModel};

/// The residual within this many times its noise floor, fitted and held out, is explained.
pub const EXPLAINED: f64 = 1.2;

/// An effect the simplest scan model lacks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Effect {
    /// Two materials declared as one.
    SecondMaterial,
    /// A scan's camera not where it was declared.
    CameraMoved,
    /// The depth camera's offset along its rays.
    DepthBias,
    /// The depth camera's scale error along its rays.
    DepthScale,
}

impl CandidateEffect for Effect {
    const LIBRARY: &'static str = "scan candidate";

    fn library() -> Vec<Self> {
        vec![
            Self::SecondMaterial,
            Self::CameraMoved,
            Self::DepthBias,
            Self::DepthScale,
        ]
    }

    fn label(self) -> String {
        match self {
            Self::SecondMaterial => "second-material",
            Self::CameraMoved => "camera-moved",
            Self::DepthBias => "depth-bias",
            Self::DepthScale => "depth-scale",
        }
        .into()
    }
}

/// How a scan dataset is diagnosed.
#[derive(Debug, Clone)]
pub struct ScanOptions {
    /// P2 (the default: linear tetrahedra lock in bending near incompressibility) or P1.
    pub design: Design,
    /// Candidates tried (empty: the whole library).
    pub candidates: Vec<Effect>,
    /// Most effects adopted.
    pub max_effects: usize,
    /// Trial Young's moduli (Pa) of the first fit.
    pub start_young: Vec<f64>,
    /// Gauss–Newton iterations at most per fit.
    pub max_iter: usize,
    /// ΔBIC on the fitted points must be below −this.
    pub bic_threshold: f64,
    /// The held-out RMS must fall by at least this fraction.
    pub min_holdout_gain: f64,
    /// Correct every fit for the mesh's own discretisation error, measured against the mesh
    /// refined once at the simplest model's fit ([`fit::Problem::mesh_error`]).
    pub mesh_error: bool,
}

impl Default for ScanOptions {
    fn default() -> Self {
        let fit = palpate_scan::dataset_fit::DatasetFitOptions::default();
        Self {
            design: fit.design,
            candidates: Vec::new(),
            max_effects: crate::run::DEFAULT_MAX_EFFECTS,
            start_young: fit.start_young,
            max_iter: fit.max_iter,
            bic_threshold: 10.0,
            min_holdout_gain: 0.02,
            mesh_error: true,
        }
    }
}

/// One candidate tried in a round, as the report keeps it.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Tried {
    /// The candidate.
    pub effect: Effect,
    /// Why it was not fitted, if it was not.
    pub not_fitted: Option<String>,
    /// Its fitted ΔBIC against the round's model.
    pub delta_bic: Option<f64>,
    /// Young's moduli fitted with it (Pa).
    pub young_pa: Vec<f64>,
    /// Its depth bias (m), if it has one.
    pub bias_m: Option<f64>,
    /// Its depth scale error (relative), if it has one.
    pub scale: Option<f64>,
    /// The largest move of a scan's registration (m), if it has them.
    pub largest_move_m: Option<f64>,
    /// The split's label and its moduli's ratio, for a second material.
    pub split: Option<(String, f64)>,
    /// The fitted points' RMS over their noise.
    pub fitted_ratio: Option<f64>,
    /// The held-out points' RMS over their noise.
    pub heldout_ratio: Option<f64>,
    /// The gate's figures and words, when gated.
    pub gate: Option<GateDetail>,
    /// Adopted in its round.
    pub adopted: bool,
    /// Passes the gate with a fitted ΔBIC within [`TOLD_APART`] of the adopted one's: these
    /// scans do not tell it from the effect adopted (a depth bias and a depth scale, seen from
    /// one distance).
    pub not_told_apart: bool,
}

/// Two passing candidates whose fitted ΔBIC differ by less than this are not told apart.
pub const TOLD_APART: f64 = 10.0;

/// One round.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RoundRecord {
    /// Round (1-based).
    pub round: usize,
    /// Effects in the model at its start.
    pub model: Vec<Effect>,
    /// Candidates tried.
    pub tried: Vec<Tried>,
}

/// A scan dataset diagnosed.
#[derive(Debug, Clone)]
pub struct ScanDiagnosis {
    /// The simplest model, fitted.
    pub before: ScanModel,
    /// Its held-out score.
    pub before_held: Evidence,
    /// The model diagnosed.
    pub after: ScanModel,
    /// Its held-out score.
    pub after_held: Evidence,
    /// The rounds.
    pub rounds: Vec<RoundRecord>,
    /// Why the search ended.
    pub stop: Stop,
    /// Points fitted and held out.
    pub points: (usize, usize),
    /// The element design.
    pub design: Design,
    /// Elements in the mesh.
    pub elements: usize,
    /// Poisson's ratio held, and whether it was declared.
    pub poisson: (f64, bool),
    /// The states' names.
    pub states: Vec<String>,
    /// The mesh's discretisation error at the simplest model's first fit, when measured: its
    /// RMS at the weighted points (m), their noise (m), the refined mesh's elements, and the
    /// modulus fitted without the correction (Pa).
    pub mesh_error: Option<(f64, f64, usize, f64)>,
    /// The mesh's error measured again at an adoption that changes the field: the effect, its
    /// RMS at the weighted points and their noise (m).
    pub mesh_error_again: Vec<(Effect, f64, f64)>,
}

impl ScanDiagnosis {
    /// Whether the model diagnosed explains the scans: fitted and held-out residuals within
    /// [`EXPLAINED`] × their noise floors.
    pub fn explained(&self) -> bool {
        self.after.score.ratio() <= EXPLAINED && self.after_held.ratio() <= EXPLAINED
    }
}

/// Diagnoses the scans of `problem` (module doc: [`Problem::new`] reads them into fitted and
/// held-out points); progress goes to the log.
pub fn diagnose(problem: &mut Problem<'_>, options: &ScanOptions) -> Result<ScanDiagnosis, Error> {
    let dataset = problem.dataset;
    let fitted: usize = problem.states.iter().map(|s| s.scan.points.len()).sum();
    let held: usize = problem.held.iter().map(|s| s.points.len()).sum();
    log::info!(
        "scan diagnosis on {} ({} tets), {} state(s): {fitted} points fitted, {held} held out",
        options.design.name(),
        dataset.mesh.tets.len(),
        problem.states.len()
    );
    // A dataset that registers its scans onto their fixed parts has a moved camera declared:
    // the simplest model has it.
    let base: Vec<Effect> = if dataset.register == palpate_scan::dataset::Register::FixedPart {
        vec![Effect::CameraMoved]
    } else {
        Vec::new()
    };
    let mut start = problem.fit(&base, None, None)?;
    // The mesh's own error, measured once at the simplest model and held: without it, a coarse
    // mesh's stiffness is fitted by whatever candidate can bend the scans (a camera turned
    // about the clamp reads as the sag the mesh cannot make).
    let mut mesh_error = None;
    if options.mesh_error {
        let e = problem.mesh_error(&start)?;
        log::info!(
            "mesh error against the mesh refined once ({} tets): {:.4} mm RMS at the points, \
             {:.2}× their noise; every fit corrected by it",
            e.elements,
            1e3 * e.rms_m,
            e.rms_m / e.noise_m
        );
        mesh_error = Some((e.rms_m, e.noise_m, e.elements, start.fit.young_modulus(0)));
        *problem.correction.borrow_mut() = Some(e.offsets);
        let theta: Vec<f64> = start.fit.mu.iter().map(|m| m.ln()).collect();
        start = problem.fit(&base, None, Some((&theta, &start.nuisance.clone())))?;
    }
    let problem = &*problem;
    let start_held = problem.held_out(&start);
    let mut room = room::ScanRoom::new(problem, options);
    let policy = Policy {
        rounds: options.max_effects + 1,
        max_adopted: options.max_effects,
        rank: Rank::FittedBic,
        screen: Screen::All,
    };
    let verdict = select(&mut room, &policy, start.clone(), start_held)?;
    let (after, after_held) = verdict
        .path
        .last()
        .cloned()
        .expect("the path starts with the simplest model");
    Ok(ScanDiagnosis {
        rounds: room::records(&verdict),
        stop: verdict.stop,
        before: start,
        before_held: start_held,
        after,
        after_held,
        points: (fitted, held),
        design: options.design,
        elements: dataset.mesh.tets.len(),
        poisson: (dataset.poisson, dataset.poisson_declared),
        states: problem.states.iter().map(|s| s.name.clone()).collect(),
        mesh_error,
        mesh_error_again: room.remeasured,
    })
}
