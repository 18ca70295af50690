//! A time offset of each run's markers against the simulation's clock: one integer number of
//! steps per run ([`palpate_motion::time_offset`]; the release instant an import reads off the
//! capture is uncertain by a frame or two). Found by a scan, not a descent (the misfit of a
//! ring-down has a minimum every period): each fitted run's offset is scanned with the current
//! material, the material refitted with the offsets held, the offsets scanned again and, if one
//! moved, the material refitted once more ([`RunsModel::fit_retimed`]). A held-out run gets its
//! own offset, scanned with the candidate's material, and the held-out gate counts those offsets
//! as parameters. The fit screen predicts it by its scan at the current material, without the
//! material's refit; its fit starts from that scan.

use palpate_motion::fitted::FittedModel;
use palpate_motion::model::Material;
use palpate_motion::time_offset;

use super::{Effect, RunsEffect};
use crate::runs::fit::{fitted, RunsModel};
use crate::runs::screen::ScreenPoint;
use crate::runs::{RunsDiagnosis, RunsError, RunsFit};
use crate::select::{Outcome, Prediction};

/// See the module.
pub struct TimeOffset;

impl RunsEffect for TimeOffset {
    fn name(&self) -> &'static str {
        "time-offset"
    }

    fn parameters(&self, runs: usize) -> usize {
        runs
    }

    fn retimes(&self) -> bool {
        true
    }

    fn fit(
        &self,
        room: &mut RunsModel,
        round: usize,
        _cur: &RunsFit,
        effects: &[Effect],
        start: &Material,
        budget: u64,
    ) -> Result<Outcome<RunsFit>, RunsError> {
        let scanned = match room.scanned.take() {
            Some((r, o)) if r == round => o,
            _ => {
                room.count(room.fit.len(), false);
                room.scan_offsets(room.fit, effects, start)?
            }
        };
        (room.log)(&format!(
            "round {round}: time offsets scanned (±{} frames, widened to ±{} at an edge): {}",
            time_offset::SCAN_FRAMES,
            time_offset::MAX_SCAN_FRAMES,
            RunsModel::describe_offsets(room.fit, &scanned)
        ));
        if scanned.iter().all(|&r| r == 0) {
            let why = "the scan puts every run in step with the simulation (offsets 0)";
            return Ok(Outcome::NotFitted(why.into()));
        }
        Ok(fitted(
            room.fit_retimed(round, effects, start, scanned, budget),
        ))
    }

    fn predict(&self, room: &mut RunsModel, at: &ScreenPoint) -> Result<Prediction, RunsError> {
        let mut effects = at.cur.effects.clone();
        effects.push(Effect::TimeOffset);
        let models = room.models(room.fit, &effects);
        use rayon::prelude::*;
        let scans: Vec<(i64, Vec<(i64, f64)>)> = room
            .fit
            .par_iter()
            .zip(models.par_iter())
            .map(|((_, d), m)| time_offset::scan(m, &at.cur.material, &d.obs))
            .collect::<Result<_, _>>()?;
        // Each run's χ² in proportion to the scan's own at offset 0 (the scan's window of steps
        // may differ from the fit's).
        let chi2: f64 = scans
            .iter()
            .zip(&at.cur.fitted)
            .map(|((best, tried), r)| {
                let chi2_at = |o: i64| tried.iter().find(|t| t.0 == o).map(|t| t.1);
                match (chi2_at(*best), chi2_at(0)) {
                    (Some(b), Some(z)) if z > 0.0 => r.chi2 * b / z,
                    _ => r.chi2,
                }
            })
            .sum();
        room.count(room.fit.len(), false);
        room.scanned = Some((at.round, scans.iter().map(|s| s.0).collect()));
        Ok(Prediction {
            delta_bic: Some(at.delta_bic(chi2, self.parameters(at.runs))),
            how: "the offsets scanned, the material not refitted".into(),
        })
    }

    fn record(&self, model: &mut FittedModel) {
        model.time_offset = true;
    }

    fn report(&self, r: &RunsDiagnosis) -> Option<String> {
        Some(format!(
            "\nTime offsets (each run's markers compared with the simulation this much later; \
             a held-out run's own, scanned with the final material): {}.",
            r.after
                .0
                .iter()
                .chain(&r.after.1)
                .map(|a| format!("{} {:+.1} ms", a.run, 1e3 * a.time_offset_s))
                .collect::<Vec<_>>()
                .join(", ")
        ))
    }
}
