//! A simulation and its step observer on two threads: while the observer works on step n (the
//! direct method's sensitivity solves, the objective's terms), the simulation already solves
//! step n + 1.
//!
//! With [`StepSolve::Fresh`] nothing the observer computes flows back into the simulation: each
//! step's Newton iterations start from the previous step's own factor, which the simulation
//! made itself, and the observer only reads the converged step. So the two can run side by
//! side, with the same arithmetic in the same order as one after the other — the same results
//! to the last bit. On a single run the second core is otherwise idle for most of a step (only
//! the element passes split their halves onto it); where both cores are busy already (several
//! runs or candidates side by side) the two threads share them and little is lost. Other solves
//! ([`StepSolve::Kept`]: a solve may refactorise S and hand that factor back to Newton) and
//! small meshes, where a step costs about as much as handing it over, run one after the other
//! as [`simulate_solving`] does; so does everything when rayon's pool has one thread.

use super::forces::SPLIT_ASSEMBLY_ELEMENTS;
use super::model::{Material, Model};
use super::relaxation::{Relaxation, StepBranch};
use super::sim::{simulate_solving, SimStats, StepSolve, StepSolver, StepView};
use super::sparse::Factor;
use super::MotionError;
use std::sync::mpsc;

/// Converged steps the simulation may run ahead of its observer: enough to ride out a step that
/// needs more Newton iterations than its neighbours, few enough that the copies stay in cache.
const AHEAD: usize = 2;

/// A converged step, owned: what [`StepView`] lends, copied for the observer's thread.
struct OwnedStep {
    n: usize,
    x: Vec<f64>,
    v: Vec<f64>,
    prev: [Vec<f64>; 4],
    force_state: [Vec<f64>; 2],
    inertia_base: Vec<f64>,
    factor: Option<Factor>,
    solver: Option<StepSolver>,
    k: Vec<f64>,
    d: Vec<f64>,
    relaxation: Option<(StepBranch, Relaxation)>,
}

impl OwnedStep {
    fn of(s: &StepView<'_>) -> Self {
        Self {
            n: s.n,
            x: s.x.to_vec(),
            v: s.v.to_vec(),
            prev: s.prev.map(<[f64]>::to_vec),
            force_state: s.force_state.map(<[f64]>::to_vec),
            inertia_base: s.inertia_base.to_vec(),
            factor: s.factor.cloned(),
            solver: s.solver.cloned(),
            k: s.k.to_vec(),
            d: s.d.to_vec(),
            relaxation: s.relaxation.map(|(b, r)| (b.clone(), r.clone())),
        }
    }

    fn view(&self) -> StepView<'_> {
        StepView {
            n: self.n,
            x: &self.x,
            v: &self.v,
            prev: [&self.prev[0], &self.prev[1], &self.prev[2], &self.prev[3]],
            force_state: [&self.force_state[0], &self.force_state[1]],
            inertia_base: &self.inertia_base,
            factor: self.factor.as_ref(),
            solver: self.solver.as_ref(),
            k: &self.k,
            d: &self.d,
            relaxation: self.relaxation.as_ref().map(|(b, r)| (b, r)),
        }
    }
}

/// Why the simulation stopped handing steps over: the observer failed on an earlier step (its
/// error is the one reported).
fn observer_gone() -> MotionError {
    MotionError::Invalid("the step observer stopped".into())
}

/// [`simulate_solving`] with `on_step` on a thread of its own, following the simulation (module
/// doc). The same calls in the same order, so the same results; an error is the earliest step's,
/// whichever side met it.
pub fn simulate_pipelined(
    model: &Model,
    mat: &Material,
    solve: StepSolve,
    on_start: impl FnMut(&[f64], Option<&Factor>),
    mut on_step: impl FnMut(&StepView<'_>) -> Result<(), MotionError> + Send,
) -> Result<SimStats, MotionError> {
    // One thread of rayon's pool (`RAYON_NUM_THREADS=1`) asks for everything one after the
    // other: the observer too.
    if solve != StepSolve::Fresh
        || model.tets.len() < SPLIT_ASSEMBLY_ELEMENTS
        || rayon::current_num_threads() < 2
    {
        return simulate_solving(model, mat, solve, on_start, on_step);
    }
    std::thread::scope(|scope| {
        let (to_observer, steps) = mpsc::sync_channel::<OwnedStep>(AHEAD);
        let observer = scope.spawn(move || -> Result<(), MotionError> {
            for step in steps {
                on_step(&step.view())?;
            }
            Ok(())
        });
        let simulated = simulate_solving(model, mat, solve, on_start, |s| {
            to_observer
                .send(OwnedStep::of(s))
                .map_err(|_| observer_gone())
        });
        // Closing the channel ends the observer's loop once it has seen every step sent.
        drop(to_observer);
        let observed = observer
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
        // The observer's error comes from a step the simulation had finished, so it is the
        // earlier one; otherwise the simulation's own.
        observed?;
        simulated
    })
}

#[cfg(test)]
mod tests {
    use super::super::gradient::{evaluate, Method};
    use super::super::model::{Param, ParamKind};
    use super::super::scenario::{example_bar, example_truth, record};
    use super::*;

    /// The example bar in 648 elements (above the size that is pipelined), shaken at its base
    /// for `steps` steps, with a material away from the recorded one's.
    fn bar(steps: usize) -> (Model, Material, Material) {
        let (_, model) = example_bar([3, 12, 3], steps).unwrap();
        assert!(model.tets.len() >= SPLIT_ASSEMBLY_ELEMENTS);
        let truth = example_truth(&model);
        let mut at = truth.clone();
        at.set(
            &Param::globals(&[ParamKind::Mu, ParamKind::Nu]),
            &[1.7e4, 9.0],
        );
        (model, truth, at)
    }

    /// What an observer sees of a step, to the bit: its index, positions, velocities, K and D,
    /// and the converged factor's solve of a fixed right-hand side.
    fn fingerprint(s: &StepView<'_>, nfree: usize) -> Vec<u64> {
        let mut out = vec![s.n as u64];
        if let Some(f) = s.factor {
            let mut rhs: Vec<f64> = (0..nfree).map(|i| 1.0 + (i % 7) as f64).collect();
            f.solve_in_place(&mut rhs);
            out.extend(rhs.iter().map(|v| v.to_bits()));
        }
        for part in [s.x, s.v, s.k, s.d, s.force_state[0], s.inertia_base] {
            out.extend(part.iter().map(|v| v.to_bits()));
        }
        out
    }

    /// The observer on its own thread sees every step exactly as it sees it on the simulation's.
    #[test]
    fn the_observer_on_its_own_thread_sees_the_same_steps_to_the_bit() {
        let (model, _, at) = bar(12);
        let mut serial = Vec::new();
        simulate_solving(
            &model,
            &at,
            StepSolve::Fresh,
            |_, _| {},
            |s| {
                serial.push(fingerprint(s, model.nfree));
                Ok(())
            },
        )
        .unwrap();
        let mut piped = Vec::new();
        let mut elsewhere = true;
        // The simulation's thread, as its start sees it.
        let simulating = std::sync::Mutex::new(None);
        // A pool of two threads whatever the machine: with one the observer would run in turn.
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        pool.install(|| {
            simulate_pipelined(
                &model,
                &at,
                StepSolve::Fresh,
                |_, _| *simulating.lock().unwrap() = Some(std::thread::current().id()),
                |s| {
                    elsewhere &= *simulating.lock().unwrap() != Some(std::thread::current().id());
                    piped.push(fingerprint(s, model.nfree));
                    Ok(())
                },
            )
        })
        .unwrap();
        assert!(elsewhere, "the observer ran on the simulation's thread");
        assert_eq!(serial.len(), model.steps);
        assert!(serial == piped, "a step differs between the two threads");
    }

    /// An observer's error is the run's, at the step it failed, and no later step reaches it.
    #[test]
    fn an_observer_error_stops_the_run_at_its_step() {
        let (model, _, at) = bar(12);
        let mut seen = Vec::new();
        let err = simulate_pipelined(
            &model,
            &at,
            StepSolve::Fresh,
            |_, _| {},
            |s| {
                seen.push(s.n);
                if s.n == 4 {
                    return Err(MotionError::Invalid("step 4 refused".into()));
                }
                Ok(())
            },
        )
        .unwrap_err();
        assert!(err.to_string().contains("step 4 refused"), "{err}");
        assert_eq!(seen, vec![1, 2, 3, 4]);
    }

    /// The direct method's gradient, now observed on its own thread, is the adjoint method's
    /// (which records the steps on the simulation's thread) to round-off.
    #[test]
    fn the_pipelined_direct_gradient_is_the_adjoint_one() {
        let (model, truth, at) = bar(20);
        let obs = record(&model, &truth, 1e-4, 5).unwrap();
        let params = Param::globals(&[ParamKind::Mu, ParamKind::Nu]);
        let direct = evaluate(&model, &at, &params, &obs, Some(Method::Direct)).unwrap();
        let adjoint = evaluate(&model, &at, &params, &obs, Some(Method::Adjoint)).unwrap();
        assert_eq!(direct.phi.to_bits(), adjoint.phi.to_bits());
        let (gd, ga) = (direct.grad.unwrap(), adjoint.grad.unwrap());
        let scale = ga.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (d, a) in gd.iter().zip(&ga) {
            assert!(
                (d - a).abs() <= 1e-9 * scale,
                "direct {gd:?} adjoint {ga:?}"
            );
        }
    }
}
