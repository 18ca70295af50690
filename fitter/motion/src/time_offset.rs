//! A time offset between a capture's markers and the simulation's clock.
//!
//! An imported run puts t = 0 where the importer saw the motion begin (the beam's release: the
//! frame before the tip has moved 0.5 mm); the true instant lies a frame or so either side, and a
//! marker stream recorded beside a rig can run out of step with the rig's clock in the same way.
//! Neither is a property of the material, yet a fit that cannot move the observations in time
//! pays for the misalignment with its material parameters (a ring-down one frame late looks
//! like a longer period). Here the offset is a parameter of each run, on the simulation's step
//! grid: with offset r (steps), the observation recorded at step n is compared with the
//! simulated state of step n − r.
//!
//! - r > 0 (the motion began r steps after the import's t = 0): the observations of steps ≤ r
//!   saw the object before it began to move, and are compared with the simulation's initial
//!   state; a fit leaves them out of Φ (they do not depend on the parameters when the run starts
//!   from its rest shape).
//! - r < 0 (the motion began earlier): the simulation runs |r| steps longer, the clamps held at
//!   their last pose, and its first |r| steps were not seen.
//!
//! One simulation serves every offset of a scan: the offsets move the observations, not the
//! simulation ([`Trajectory::chi2`]).

use super::model::{Material, Model, Observations};
use super::sim::simulate;
use super::MotionError;

/// Capture frames a scan first moves a run either way ([`scan`]): the release detection of an
/// import is off by a frame or two.
pub const SCAN_FRAMES: i64 = 3;

/// The widest scan ([`scan`]): a best offset at the edge of the first scan widens it, doubling, up
/// to this many frames either way — two capture streams can be out of step by more than an
/// import's misread release; further than this it is not a timing error but another experiment.
pub const MAX_SCAN_FRAMES: i64 = 12;

/// The model with its horizon `steps − offset` (at least one step): truncated, or extended with
/// the clamps held at their last pose.
pub fn shifted_model(model: &Model, offset: i64) -> Result<Model, MotionError> {
    let steps = model.steps as i64 - offset;
    if steps < 1 {
        return Err(MotionError::Invalid(format!(
            "a time offset of {offset} steps leaves nothing of a {}-step run to simulate",
            model.steps
        )));
    }
    let steps = steps as usize;
    let mut m = model.clone();
    m.steps = steps;
    for cl in &mut m.clamps {
        let last = *cl
            .poses
            .last()
            .ok_or_else(|| MotionError::Invalid(format!("clamp {:?} has no poses", cl.name)))?;
        cl.poses.resize(steps + 1, last);
    }
    Ok(m)
}

/// The run re-timed by `offset` steps: the model of [`shifted_model`] and the observations on
/// its clock (row m holds what was recorded at step m + 1 + offset); the observations made
/// before the simulation starts are dropped (see the module's note on r > 0).
pub fn shifted(
    model: &Model,
    obs: &Observations,
    offset: i64,
) -> Result<(Model, Observations), MotionError> {
    let m = shifted_model(model, offset)?;
    let take = |rows: &Vec<Vec<Option<[f64; 3]>>>, width: usize| -> Vec<Vec<Option<[f64; 3]>>> {
        (0..m.steps as i64)
            .map(|row| {
                usize::try_from(row + offset)
                    .ok()
                    .and_then(|n| rows.get(n).cloned())
                    .unwrap_or_else(|| vec![None; width])
            })
            .collect()
    };
    let o = Observations {
        markers: take(&obs.markers, model.markers.len()),
        forces: take(&obs.forces, model.clamps.len()),
        ..obs.clone()
    };
    Ok((m, o))
}

/// Simulated marker positions (and velocities) on the simulation's clock: the initial state
/// (step 0, at rest) and every step after it.
#[derive(Debug, Clone)]
pub struct Trajectory {
    /// Markers at step 0 (the rest shape, or the elastostatic start).
    pub initial: Vec<[f64; 3]>,
    /// Markers at steps 1..=steps.
    pub rows: Vec<Vec<[f64; 3]>>,
    /// Marker velocities at steps 1..=steps (m/s).
    pub velocities: Vec<Vec<[f64; 3]>>,
    /// Full-dof positions at the last step (a start for the equilibrium after the run).
    pub last: Vec<f64>,
}

impl Trajectory {
    /// Simulates `model` with `mat`, keeping the markers (and their velocities) of every step.
    pub fn simulate(model: &Model, mat: &Material) -> Result<Self, MotionError> {
        let markers = |x: &[f64]| -> Vec<[f64; 3]> {
            model
                .markers
                .iter()
                .map(|m| model.marker_position(m, x))
                .collect()
        };
        let mut initial = Vec::new();
        let mut rows = Vec::with_capacity(model.steps);
        let mut velocities = Vec::with_capacity(model.steps);
        let mut last = Vec::new();
        simulate(
            model,
            mat,
            false,
            |x0, _| initial = markers(x0),
            |s| {
                rows.push(markers(s.x));
                velocities.push(markers(s.v));
                if s.n == model.steps {
                    last = s.x.to_vec();
                }
                Ok(())
            },
        )?;
        Ok(Self {
            initial,
            rows,
            velocities,
            last,
        })
    }

    /// Markers at step `s` of the simulation's clock: the initial state for s ≤ 0, `None` past
    /// the simulated horizon.
    pub fn at(&self, s: i64) -> Option<&[[f64; 3]]> {
        if s <= 0 {
            Some(&self.initial)
        } else {
            self.rows.get(s as usize - 1).map(|r| r.as_slice())
        }
    }

    /// Marker velocities at step `s` (zero before the start, `None` past the horizon).
    pub fn velocity_at(&self, s: i64) -> Option<Vec<[f64; 3]>> {
        if s <= 0 {
            Some(vec![[0.0; 3]; self.initial.len()])
        } else {
            self.velocities.get(s as usize - 1).cloned()
        }
    }

    /// The simulated markers for each of `steps` recorded steps (row n = step n + 1) of a run
    /// observed with `offset`; `None` past the horizon.
    pub fn recorded(&self, steps: usize, offset: i64) -> Option<Vec<Vec<[f64; 3]>>> {
        (0..steps as i64)
            .map(|n| self.at(n + 1 - offset).map(|r| r.to_vec()))
            .collect()
    }

    /// Σ‖simulated − observed‖² over every observed marker position of `obs` seen with `offset`,
    /// and how many there are; `None` when the offset reaches past the simulated horizon.
    pub fn chi2(&self, obs: &Observations, offset: i64) -> Option<(f64, usize)> {
        let (mut c, mut count) = (0.0, 0);
        for (n, row) in obs.markers.iter().enumerate() {
            if row.iter().all(Option::is_none) {
                continue;
            }
            let sim = self.at(n as i64 + 1 - offset)?;
            for (s, o) in sim.iter().zip(row) {
                if let Some(o) = o {
                    c += (0..3).map(|k| (s[k] - o[k]).powi(2)).sum::<f64>();
                    count += 1;
                }
            }
        }
        Some((c, count))
    }
}

/// The offset of one run: every step within ±[`SCAN_FRAMES`] capture frames, each scored by the
/// marker χ² of a simulation of `mat` run that much longer; while the best offset lies at the
/// edge of the scan, the scan is doubled up to ±[`MAX_SCAN_FRAMES`]. Returns the best offset and
/// the χ² of every offset of the last scan. The objective is a sum over a ring-down and has a
/// minimum every period apart, hence a scan of the grid rather than a descent, and the widening
/// in stages: a nearer minimum is preferred to a lower one a period away.
///
/// One simulation, as long as the widest scan needs, serves every stage: a step's state depends
/// only on the steps before it, so the first `steps + r` steps of the longest run are those of
/// the run extended by r, to the bit (`the_longest_scan_serves_the_shorter_ones`); a widened scan
/// used to cost one more, longer simulation per stage.
pub fn scan(
    model: &Model,
    mat: &Material,
    obs: &Observations,
) -> Result<(i64, Vec<(i64, f64)>), MotionError> {
    let per_frame = model.substeps.max(1) as i64;
    let traj = Trajectory::simulate(&shifted_model(model, -MAX_SCAN_FRAMES * per_frame)?, mat)?;
    let mut frames = SCAN_FRAMES;
    loop {
        let reach = frames * per_frame;
        let tried: Vec<(i64, f64)> = (-reach..=reach)
            .filter_map(|r| traj.chi2(obs, r).map(|(c, _)| (r, c)))
            .collect();
        let best = tried
            .iter()
            .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.abs().cmp(&b.0.abs())))
            .map_or(0, |t| t.0);
        if best.abs() < reach || frames >= MAX_SCAN_FRAMES {
            return Ok((best, tried));
        }
        frames = (2 * frames).min(MAX_SCAN_FRAMES);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Material, Observations};
    use crate::scenario::{bar_model, nine_markers, two_sinusoids};

    /// A 2 × 6 × 2 cm bar of three cells, its base shaken for `steps` steps of 10 ms,
    /// nine markers, starting from rest.
    fn shaken_bar(steps: usize) -> Model {
        let size = [0.02, 0.06, 0.02];
        let (_, mut model) = bar_model(
            size,
            [1, 3, 1],
            0.01,
            steps,
            &two_sinusoids,
            &nine_markers(size),
        )
        .unwrap();
        model.static_start = false;
        model
    }

    /// The prefix property [`scan`] rests on: the run extended by r steps is, step for step and
    /// to the bit, the start of the run extended by more, so every offset within ±r scores the
    /// same χ² on either; with a clamp that moves and a dead load that switches on mid-run.
    #[test]
    fn the_longest_scan_serves_the_shorter_ones() {
        let mut model = shaken_bar(30);
        let free_node = (0..model.nodes.len())
            .find(|&a| model.free[3 * a] != usize::MAX)
            .unwrap();
        model.loads.push(crate::model::DeadLoad {
            name: "weight".into(),
            nodes: vec![free_node],
            force: [0.0, 0.0, -0.05],
            from_step: 10,
            mass: None,
            inertia: false,
            lever: None,
        });
        let mat = Material::uniform(model.tets.len(), 2.0e4, 1.0e4, 3.0, 1.0, 47.0);
        let long = Trajectory::simulate(&shifted_model(&model, -12).unwrap(), &mat).unwrap();
        let obs = Observations {
            markers: long
                .recorded(model.steps, 2)
                .unwrap()
                .iter()
                .map(|row| {
                    row.iter()
                        .map(|p| Some([p[0] + 1e-4, p[1], p[2]]))
                        .collect()
                })
                .collect(),
            forces: vec![vec![None; model.clamps.len()]; model.steps],
            marker_weight: 1.0,
            force_weight: 1.0,
            free_marker_offsets: false,
            phi_precision: 0.0,
        };
        for reach in [0i64, 3, 6] {
            let short =
                Trajectory::simulate(&shifted_model(&model, -reach).unwrap(), &mat).unwrap();
            assert_eq!(short.rows.len() as i64, model.steps as i64 + reach);
            for (a, b) in short.rows.iter().zip(&long.rows) {
                assert_eq!(a, b, "reach {reach}");
            }
            for r in -reach..=reach {
                assert_eq!(short.chi2(&obs, r), long.chi2(&obs, r), "offset {r}");
            }
        }
    }

    /// A recording delayed by r steps against its simulation is found at r by the scan, and
    /// [`shifted`] puts every recorded row where the simulation of the re-timed model reproduces
    /// it exactly — for an early start (r < 0) and a late one (r > 0).
    #[test]
    fn a_delayed_recording_is_found_and_realigned() {
        let model = shaken_bar(40);
        let mat = Material::uniform(model.tets.len(), 2.0e4, 1.0e4, 3.0, 1.0, 47.0);
        // The truth runs 12 steps longer; the "capture" sees it from various instants (7 and −9
        // lie beyond the first scan's ±3 frames: found by the widened scan).
        let long = shifted_model(&model, -12).unwrap();
        let truth = Trajectory::simulate(&long, &mat).unwrap();
        for r in [-3i64, -1, 0, 2, 3, 7, -9] {
            let rows = truth.recorded(model.steps, r).unwrap();
            let obs = Observations {
                markers: rows
                    .iter()
                    .map(|row| row.iter().map(|p| Some(*p)).collect())
                    .collect(),
                forces: vec![vec![None; model.clamps.len()]; model.steps],
                marker_weight: 1.0,
                force_weight: 1.0,
                free_marker_offsets: false,
                phi_precision: 0.0,
            };
            let (best, tried) = scan(&model, &mat, &obs).unwrap();
            assert_eq!(best, r, "{tried:?}");
            let zero = tried.iter().find(|t| t.0 == r).unwrap().1;
            assert!(zero < 1e-20, "χ² at the true offset {zero}");
            let (m, o) = shifted(&model, &obs, r).unwrap();
            assert_eq!(m.steps as i64, model.steps as i64 - r);
            let sim = Trajectory::simulate(&m, &mat).unwrap();
            let (c, n) = sim.chi2(&o, 0).unwrap();
            assert!(c < 1e-20, "r = {r}: χ² {c}");
            // Rows seen before the start (r > 0) are dropped, none is lost otherwise.
            assert_eq!(n, model.markers.len() * (model.steps - r.max(0) as usize));
        }
    }
}
