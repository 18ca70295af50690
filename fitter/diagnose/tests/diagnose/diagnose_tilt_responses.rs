//! The per-measurement tilt's marker responses (two more solves per measurement in every
//! simulation of a model that holds `tilt-each`) started near a base simulation — where a
//! Jacobian column or a Levenberg–Marquardt trial starts them — against the same responses
//! solved from the untilted state: the same fixed point, to the solves' tolerance.

use crate::support::specimen_seeded;
use palpate_diagnose::fit::initial_theta;
use palpate_diagnose::model::{Candidate, Context, Model};

/// Largest entry-wise difference of two sets of responses (m per unit coefficient).
fn largest_difference(a: &[[Vec<[f64; 3]>; 2]], b: &[[Vec<[f64; 3]>; 2]]) -> f64 {
    let mut worst = 0.0f64;
    for (p, q) in a.iter().zip(b) {
        for j in 0..2 {
            assert_eq!(p[j].len(), q[j].len());
            for (u, v) in p[j].iter().zip(&q[j]) {
                for d in 0..3 {
                    worst = worst.max((u[d] - v[d]).abs());
                }
            }
        }
    }
    worst
}

#[test]
fn tilt_responses_started_near_a_base_are_those_solved_from_the_untilted_state() {
    let s = specimen_seeded(5);
    let ctx = Context::new(&s.dataset, [3, 3, 2]).unwrap();
    let all: Vec<usize> = (0..ctx.meas.len()).collect();
    let (theta, sim0) = initial_theta(&ctx, &all).unwrap();
    let model = Model::base().with(Candidate::TiltEach);
    let base = model.simulate(&ctx, &theta, &all, Some(&sim0.x)).unwrap();
    let tilted = base
        .tilted
        .as_ref()
        .expect("tilt-each keeps its solves' states");
    assert_eq!(tilted.len(), all.len());
    // A step in ln E of 1 %, a hundred times a Jacobian column's: the responses move with it.
    let mut moved = theta.clone();
    moved[0] += 0.01;
    let near = model.simulate_near(&ctx, &moved, &all, &base).unwrap();
    let own = model.simulate(&ctx, &moved, &all, Some(&base.x)).unwrap();
    let (near_t, own_t, base_t) = (
        near.tilt.as_ref().unwrap(),
        own.tilt.as_ref().unwrap(),
        base.tilt.as_ref().unwrap(),
    );
    let scale = base_t
        .iter()
        .flat_map(|r| r.iter().flatten())
        .flat_map(|p| p.iter())
        .fold(0.0f64, |m, v| m.max(v.abs()));
    let moved_by = largest_difference(own_t, base_t);
    let apart = largest_difference(near_t, own_t);
    eprintln!(
        "responses up to {scale:.3e} m; moved by {moved_by:.3e} m with ln E + 0.01; \
         started near the base against from the untilted state: {apart:.3e} m"
    );
    assert!(scale > 1e-4, "the tilted load moves the markers: {scale:e}");
    assert!(
        moved_by > 1e-3 * scale,
        "the step in E should move the responses ({moved_by:e} of {scale:e})"
    );
    // Each solve stops within 10⁻⁹ m (node move) of its fixed point; a response is a difference
    // of two solves over the probe's coefficient 0.1.
    assert!(
        apart < 1e-8,
        "the two starts should reach the same fixed point: {apart:e} m apart"
    );
    let markers_apart = near
        .markers
        .iter()
        .zip(&own.markers)
        .flat_map(|(a, b)| a.iter().zip(b))
        .flat_map(|(p, q)| (0..3).map(move |d| (p[d] - q[d]).abs()))
        .fold(0.0f64, f64::max);
    assert!(
        markers_apart < 1e-8,
        "profiled markers {markers_apart:e} m apart"
    );
}
