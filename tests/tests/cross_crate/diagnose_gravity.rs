//! Issue 6, the gravity candidate (`diagnose::model`, "the rest scan was taken under gravity"):
//! markers are re-located at the material point X with X + u_g(X) = their scanned (sagged) rest
//! position. On a gravity specimen (ρ = 1000 kg/m³, rest scan under gravity) with the true material,
//! the re-located markers must predict the measurements better than the dataset's nearest-point
//! embedding, which on the side faces sits at a sag-shifted material point.

use palpate_diagnose::model::{s_of, Candidate, Context, Model};
use palpate_specimen::Effect;
use palpate_tests::diagnose::specimen_with;

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

/// Measured: 205.1 µm RMS with the re-located markers vs 274.5 µm with the dataset's embedding
/// (true E, ν, ρ, uncorrected dataset mesh: the rest is marker noise and the mesh's own error;
/// asserted a 5 % drop at least); side markers move up by up to 322.6 µm (asserted > 50 µm, never
/// down), top markers — whose sag is normal to their face — only sideways, by up to 96.9 µm
/// (the block's bulge; asserted below the side markers' largest move).
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
    assert!(with < 0.95 * without, "{with:e} vs {without:e}");
    let top = ctx.problem.x0.iter().map(|p| p[2]).fold(f64::MIN, f64::max);
    let (mut side_up, mut top_side) = (0.0f64, 0.0f64);
    for (k, &(t, b)) in embedding.iter().enumerate() {
        let p: [f64; 3] =
            std::array::from_fn(|d| (0..3).map(|i| b[i] * ctx.problem.x0[t[i]][d]).sum());
        let old = ctx.marker_rest[k];
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
        side_up > 5e-5,
        "largest upward move of a side marker {side_up:e} m"
    );
    assert!(
        top_side < side_up,
        "top {top_side:e} m vs side {side_up:e} m"
    );
}
