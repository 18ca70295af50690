//! The gravity candidate (`diagnose::model`, "the rest scan was taken under gravity"):
//! markers are re-located at the material point X with X + u_g(X) = their scanned (sagged) rest
//! position. On a gravity specimen (ρ = 1000 kg/m³, rest scan under gravity) with the true material,
//! the re-located markers must predict the measurements better than the dataset's nearest-point
//! embedding, which on the side faces sits at a sag-shifted material point.

use crate::support::specimen_with;
use palpate_diagnose::model::{s_of, Candidate, Context, Model};
use palpate_specimen::Effect;

fn rms(ctx: &Context, markers: &[Vec<[f64; 3]>]) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for (m, sim) in ctx.meas.iter().zip(markers) {
        for (&(_, obs), p) in m.observed.iter().zip(sim) {
            s += (0..3).map(|d| (p[d] - obs[d]).powi(2)).sum::<f64>();
            n += 1;
        }
    }
    (s / n as f64).sqrt()
}

/// Measured: 204.8 µm RMS with the re-located markers vs 379.8 µm with the dataset's embedding
/// (true E, ν, ρ, uncorrected dataset mesh: the rest is marker noise and the mesh's own error),
/// a ratio of 0.54, asserted below 0.6; side markers move up by up to 322.6 µm (asserted within
/// 10 %, never down), top markers — whose sag is normal to their face — only sideways, by up to
/// 96.9 µm (the block's bulge; asserted below the side markers' largest move). The figures are
/// this test's own output (release build); every step is deterministic, so the margins only
/// admit a change of solver tolerance.
#[test]
fn rest_scan_under_gravity_relocates_side_markers() {
    let s = specimen_with(Effect::Gravity, 1.0);
    let ctx = Context::new(&s.dataset, [2, 2, 2]).expect("context");
    let model = Model::base().with(Candidate::Gravity);
    let theta = vec![20e3f64.ln(), s_of(0.35), 1.0];
    let all: Vec<usize> = (0..ctx.meas.len()).collect();
    let sim = model.simulate(&ctx, &theta, &all, None).expect("simulate");
    let embedding = sim
        .embedding
        .as_deref()
        .expect("gravity re-locates the markers");
    let plain = model.markers_from(&ctx, &theta, &all, &sim.x, None, None);
    let (with, without) = (rms(&ctx, &sim.markers), rms(&ctx, &plain));
    eprintln!(
        "re-located {:.1} µm, dataset embedding {:.1} µm",
        1e6 * with,
        1e6 * without
    );
    assert!(
        with < 0.6 * without,
        "{with:e} vs {without:e} m: ratio {:.3}, measured 0.539",
        with / without
    );
    let top = ctx.problem.x0.iter().map(|p| p[2]).fold(f64::MIN, f64::max);
    let (mut side_up, mut top_side) = (0.0f64, 0.0f64);
    for (k, m) in embedding.iter().enumerate() {
        let p = m.surface_point(|n| ctx.problem.x0[n]);
        let old = ctx.markers[k].surface_point(|n| ctx.problem.x0[n]);
        let dz = p[2] - old[2];
        if (old[2] - top).abs() < 1e-9 {
            let dh = ((p[0] - old[0]).powi(2) + (p[1] - old[1]).powi(2)).sqrt();
            top_side = top_side.max(dh);
        } else {
            assert!(dz > -1e-9, "side marker {k} moved down {dz:e} m");
            side_up = side_up.max(dz);
        }
    }
    eprintln!(
        "largest move: side markers up {:.1} µm, top markers sideways {:.1} µm",
        1e6 * side_up,
        1e6 * top_side
    );
    assert!(
        (side_up / 322.6e-6 - 1.0).abs() < 0.1,
        "largest upward move of a side marker {side_up:e} m, measured 322.6 µm"
    );
    assert!(
        top_side < side_up,
        "top {top_side:e} m vs side {side_up:e} m"
    );
}

/// Unloaded, at the true ρ, the gravity candidate must put every marker back where the rest scan
/// saw it: the re-embedded marker is the material point X with X + u_g(X) = its scanned position,
/// carrying only X's own offset from the surface. (The dataset keeps each marker's offset from
/// the surface point it rides on; under a rest scan taken under gravity that offset *is* the
/// sag's normal part, and the candidate used to carry it beside u_g(X): a top marker came out
/// sagged twice, a signal no such data hold — the power statement then claimed ρ ≥ 65 kg/m³ would
/// be seen on a specimen whose ρ = 1,000 kg/m³ left no trace.) The specimen's measurements are
/// replayed with a nanonewton, so the simulated markers are the predicted rest scan.
#[test]
fn gravity_candidate_reproduces_the_rest_scan_unloaded() {
    let mut s = specimen_with(Effect::Gravity, 1.0);
    // (A nanonewton, not zero: a dataset whose every force is zero is refused.)
    for m in &mut s.dataset.measurements {
        m.force = [0.0, 0.0, -1e-9];
    }
    let ctx = Context::new(&s.dataset, [2, 2, 2]).expect("context");
    let all: Vec<usize> = (0..ctx.meas.len()).collect();
    let model = Model::base().with(Candidate::Gravity);
    let theta = vec![20e3f64.ln(), s_of(0.35), 1.0];
    let sim = model.simulate(&ctx, &theta, &all, None).expect("simulate");
    let (mut worst, mut sag) = (0.0f64, 0.0f64);
    for (m, markers) in ctx.meas.iter().zip(&sim.markers) {
        for (&(k, _), p) in m.observed.iter().zip(markers) {
            let rest = ctx.markers[k].rest;
            let d = (0..3).map(|a| (p[a] - rest[a]).powi(2)).sum::<f64>().sqrt();
            worst = worst.max(d);
        }
    }
    for (k, x) in sim.x[0].iter().enumerate() {
        let u = (0..3)
            .map(|a| (x[a] - ctx.problem.x0[k][a]).powi(2))
            .sum::<f64>()
            .sqrt();
        sag = sag.max(u);
    }
    eprintln!(
        "unloaded: largest marker distance from its scan {:.1} µm; largest sag {:.1} µm",
        1e6 * worst,
        1e6 * sag
    );
    assert!(sag > 1e-4, "the specimen must sag visibly: {sag:e} m");
    assert!(
        worst < 0.1 * sag,
        "a marker sits {worst:e} m from its rest scan (largest sag {sag:e} m)"
    );
}
