//! A lumped probe's rim crossings solved ahead (`palpate_runtime::anticipate`): the same answers
//! as without, and the crossings that were planned cost what a still tick costs.

use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::{ContactRule, RuntimeConfig, TickReport};
use palpate_tests::model::{self, Storage};

/// One lumped probe sliding 6 cm across the top of a 10 × 10 × 5 cm block (0.5 N, radius
/// 1.5 cm, 60 µm per tick) with `anticipation` iterations per still tick: the reports and the
/// displacements after every tick.
fn slide(anticipation: u32) -> Vec<(TickReport, Vec<f32>)> {
    let m = box_mesh([0.1, 0.1, 0.05], [10, 10, 5]);
    let fixed = m.group("bottom").unwrap().to_vec();
    let p = LambdaAlpha::from_young_poisson(10_000.0, 0.3);
    let buf = model::homogeneous(&m, &fixed, p.lambda, p.alpha);
    let cfg = RuntimeConfig {
        contact_rule: ContactRule::Lumped,
        anticipation_iterations: anticipation,
        ..Default::default()
    };
    let mut storage = Storage::for_model(&buf.record(), &cfg);
    let mut rt = storage.runtime(buf.record(), cfg).unwrap();
    let ticks = 1000;
    let point = |k: usize| [0.02 + 0.06 * k as f32 / ticks as f32, 0.05, 0.05];
    rt.set_contact_force(point(0), [0.0, 0.0, -0.5], 0.015)
        .unwrap();
    for _ in 0..20 {
        rt.tick();
    }
    (0..ticks)
        .map(|k| {
            rt.set_contact_force(point(k), [0.0, 0.0, -0.5], 0.015)
                .unwrap();
            let rep = rt.tick();
            (rep, rt.displacements().to_vec())
        })
        .collect()
}

fn rel_diff(a: &[f32], b: &[f32]) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (x, y) in a.iter().zip(b) {
        num += ((x - y) as f64).powi(2);
        den += (*y as f64).powi(2);
    }
    (num / den.max(f64::MIN_POSITIVE)).sqrt()
}

#[test]
fn planned_crossings_cost_a_still_tick_and_change_no_answer() {
    let off = slide(0);
    let on = slide(RuntimeConfig::default().anticipation_iterations);
    // The crossings: the ticks that cost the solve without anticipation most (a still tick
    // solves nothing, its follow-ups a few iterations).
    let crossings: Vec<usize> = (0..off.len())
        .filter(|&k| off[k].0.iterations >= 12)
        .collect();
    assert!(crossings.len() >= 10, "{} crossings", crossings.len());
    let mut worst = 0.0f64;
    for ((a, ua), (b, ub)) in on.iter().zip(&off) {
        // Both converged to the tick's tolerance: their answers agree to it.
        assert_eq!(a.status, palpate_runtime::SolveStatus::Converged);
        assert!(a.rel_residual <= 1e-4 && b.rel_residual <= 1e-4);
        worst = worst.max(rel_diff(ua, ub));
    }
    assert!(worst < 1e-3, "displacements differ by {worst:.2e}");
    // The still ticks did the work ahead, and most crossings were planned.
    let ahead: u32 = on.iter().map(|(r, _)| r.iterations_ahead).sum();
    assert!(ahead > 0);
    let planned = crossings.iter().filter(|&&k| on[k].0.anticipated).count();
    assert!(
        4 * planned >= 3 * crossings.len(),
        "{planned} of {} crossings planned",
        crossings.len()
    );
    // A planned crossing needs at most the last iterations of a solve made to the tick's own
    // tolerance (15–16 without); the worst tick of the run costs at most half the worst tick
    // without anticipation.
    // A planned crossing needs at most the last iterations of solves made to the tick's own
    // tolerance (15–16 without) — all but the nodes planned to cross together that cross a tick
    // apart (the second then solves under the first's rotations, 8 here); with the two ticks
    // after each (the rotations following the step) the crossings cost less than 40 % of what
    // they cost without, and the worst tick of the run at most 60 % of the worst without.
    let mut planned_iterations: Vec<u32> = crossings
        .iter()
        .filter(|&&k| on[k].0.anticipated)
        .map(|&k| on[k].0.iterations)
        .collect();
    planned_iterations.sort_unstable();
    let quick = planned_iterations.iter().filter(|&&i| i <= 2).count();
    assert!(
        5 * quick >= 4 * planned_iterations.len() && *planned_iterations.last().unwrap() <= 10,
        "{planned_iterations:?}"
    );
    let around = |run: &[(TickReport, Vec<f32>)]| -> u32 {
        crossings
            .iter()
            .flat_map(|&k| k..(k + 3).min(run.len()))
            .map(|k| run[k].0.iterations)
            .sum()
    };
    assert!(
        10 * around(&on) <= 4 * around(&off),
        "{} against {} iterations",
        around(&on),
        around(&off)
    );
    let max = |run: &[(TickReport, Vec<f32>)]| run.iter().map(|(r, _)| r.iterations).max();
    assert!(
        10 * max(&on).unwrap() <= 6 * max(&off).unwrap(),
        "{:?} vs {:?}",
        max(&on),
        max(&off)
    );
}

#[test]
fn anticipation_stays_out_of_the_consistent_rule_and_a_still_probe() {
    let m = box_mesh([0.1, 0.1, 0.05], [6, 6, 3]);
    let fixed = m.group("bottom").unwrap().to_vec();
    let p = LambdaAlpha::from_young_poisson(10_000.0, 0.3);
    let buf = model::homogeneous(&m, &fixed, p.lambda, p.alpha);
    for (rule, moving) in [
        (ContactRule::Consistent, true),
        (ContactRule::Lumped, false),
    ] {
        let cfg = RuntimeConfig {
            contact_rule: rule,
            ..Default::default()
        };
        let mut storage = Storage::for_model(&buf.record(), &cfg);
        let mut rt = storage.runtime(buf.record(), cfg).unwrap();
        for k in 0..200 {
            let x = if moving {
                0.03 + 0.0002 * k as f32
            } else {
                0.05
            };
            rt.set_contact_force([x, 0.05, 0.05], [0.0, 0.0, -0.5], 0.015)
                .unwrap();
            let rep = rt.tick();
            assert_eq!(rep.iterations_ahead, 0, "{rule:?}, tick {k}");
            assert!(!rep.anticipated);
        }
    }
}
