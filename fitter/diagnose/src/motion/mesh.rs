//! The dataset mesh's own discretisation error in a motion diagnosis, measured and stated.
//!
//! Linear tetrahedra are too stiff at a dataset's resolution, and stiffest where the strain
//! varies fastest: at a clamp, in bending. A fit on the dataset mesh absorbs that stiffness into
//! the material (the fitted E is this mesh's, not the object's), and a candidate may absorb the
//! rest: a soft "second material" of a few elements at the clamp lowers the residual of a mesh
//! that is merely too coarse there. The report therefore says how far the markers would move if
//! the simplest fitted model were simulated on the mesh refined once
//! ([`palpate_motion::refine`]): δ = x_h − x_{h/2} at every marker and step.
//!
//! It is a statement, not a correction of the data as in the static diagnosis (what guards the
//! adoptions against this error is [`super::mesh_null`]): in a motion the
//! coarse mesh's error is mostly a shift of the body's frequencies, so δ(t) is a phase drift that
//! changes with every parameter, and data corrected by a δ made at one fit mislead the next
//! (on an independent 1,267-tetrahedron cylinder, corrected data were fitted at 939 µm RMS
//! against 402 µm uncorrected, δ moving from 3.2 to 4.0 mm between the two fits).

use super::fit::FittedModel;
use super::MotionOptions;
use palpate_motion::dataset::MotionDataset;
use palpate_motion::model::{Material, Model};
use palpate_motion::refine::mesh_error;
use serde::Serialize;

/// The dataset mesh's discretisation error at the simplest fit.
#[derive(Debug, Clone, Serialize)]
pub struct MeshNote {
    /// RMS of δ over every marker and step (m); `None` when not estimated.
    pub rms: Option<f64>,
    /// Largest |δ| (m).
    pub max: Option<f64>,
    /// Tetrahedra of the refined mesh.
    pub refined_tets: usize,
    /// What it means, in words for the report.
    pub statement: String,
}

/// The dataset's model on the mesh refined once, built for the note and kept for the checks
/// against the mesh's own null ([`super::mesh_null`]), with what the simplest model does on it.
pub(super) struct Refined {
    /// The model on the refined mesh.
    pub model: Model,
    /// The material simulated on it (the simplest fit's, on the dataset mesh's elements).
    pub material: Material,
    /// Its markers' places at every step ([`palpate_motion::refine::MeshError::refined`]): the
    /// first round's null, made at the simplest fit.
    pub paths: Vec<Vec<[f64; 3]>>,
}

/// Measures δ at the simplest fit's material (two simulations: the dataset mesh's and the
/// refined mesh's) and says what it means against the noise floor σ√3 (`floor`, NaN when not
/// declared); with it the refined model and its simulation, when they could be made.
pub(super) fn estimate(
    ds: &MotionDataset,
    simplest: &FittedModel,
    floor: f64,
    o: &MotionOptions,
    log: &(dyn Fn(&str) + Sync),
) -> (MeshNote, Option<Refined>) {
    let refined_tets = 8 * ds.model.tets.len();
    let note = |rms, max, statement| MeshNote {
        rms,
        max,
        refined_tets,
        statement,
    };
    if !o.mesh_error {
        return (note(None, None, "not estimated (as asked)".into()), None);
    }
    if refined_tets > o.refine_max_tets {
        return (
            note(
                None,
                None,
                format!(
                    "not estimated: the mesh refined once would have {refined_tets} tetrahedra \
                     (limit {})",
                    o.refine_max_tets
                ),
            ),
            None,
        );
    }
    log(&format!(
        "estimating the mesh's discretisation error: the simplest model on the mesh refined once \
         ({refined_tets} tets)"
    ));
    let (fine, e) = match ds.model.refined().and_then(|fine| {
        let e = mesh_error(&ds.model, &fine, &simplest.material)?;
        Ok((fine, e))
    }) {
        Ok(r) => r,
        Err(err) => {
            let s = format!(
                "not estimated: the simplest model did not simulate on the mesh refined once \
                 ({err})"
            );
            log(&s);
            return (note(None, None, s), None);
        }
    };
    let size = format!(
        "at the simplest fit's material the mesh refined once ({refined_tets} tetrahedra) moves \
         the markers by {:.1} µm RMS ({:.1} µm at most)",
        1e6 * e.rms,
        1e6 * e.max
    );
    let statement = if !floor.is_finite() {
        format!("{size}; no noise floor is declared to compare it with")
    } else if e.rms > floor {
        format!(
            "{size}, {:.1}× the noise floor: the fitted stiffness is this mesh's, not the \
             material's, and a residual of this size may be the mesh's own error, not an effect \
             ({})",
            e.rms / floor,
            if o.mesh_null {
                "each adoption is checked against the mesh's own null"
            } else {
                "compare an adopted effect on a finer mesh"
            }
        )
    } else {
        format!(
            "{size}, {:.0} % of the noise floor: the mesh is fine enough for the effects this \
             diagnosis can see",
            100.0 * e.rms / floor
        )
    };
    log(&statement);
    let refined = Refined {
        model: fine,
        material: simplest.material.clone(),
        paths: e.refined,
    };
    (note(Some(e.rms), Some(e.max), statement), Some(refined))
}
