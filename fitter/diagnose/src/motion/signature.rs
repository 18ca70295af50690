//! The residual signature of a motion fit, read the way an engineer would: against marker speed
//! (viscous forces scale with the velocity gradient, so a missing dashpot leaves a phase lag,
//! e ≈ c·u), against acceleration (a wrong mass/density leaves e ≈ c·a), over time (drift of a
//! forecast) and per marker.

use super::fit::{FittedModel, Split};
use nalgebra::Vector3;
use palpate_motion::dataset::MotionDataset;
use serde::Serialize;

/// Residual signature of one model.
#[derive(Debug, Clone, Serialize)]
pub struct Signature {
    /// e ≈ c_u · u_rel by least squares over all observed (marker, step) pairs: c_u (s), a lag
    /// (u_rel = marker velocity minus the first clamp's rigid velocity at the marker's rest point).
    pub speed_coef_s: f64,
    /// Share of the residual energy Σ‖e‖² that c_u·u_rel explains.
    pub speed_share: f64,
    /// e ≈ c_a · a (a = simulated marker acceleration, backward difference): c_a (s²).
    pub accel_coef_s2: f64,
    /// Share of the residual energy c_a·a explains.
    pub accel_share: f64,
    /// Significance of the lag: ΔBIC of the 1-parameter regression e ≈ c_u·u_rel against e ≈ 0,
    /// n ln(1 − share) + ln n over the n scalar residuals (< −10: a real structure, not noise —
    /// the share itself is small when white marker noise dominates the residual energy).
    pub speed_dbic: f64,
    /// Same for the acceleration regression.
    pub accel_dbic: f64,
    /// RMS residual (m) in 8 equal time bins: (bin centre t (s), RMS).
    pub time_bins: Vec<(f64, f64)>,
    /// RMS of the last time bin over the first (drift of the forecast).
    pub drift_ratio: f64,
    /// RMS residual per marker (name, m).
    pub per_marker: Vec<(String, f64)>,
    /// Largest per-marker RMS over the median per-marker RMS.
    pub worst_marker_ratio: f64,
    /// RMS residual (m) in 8 quantile bins of |u_rel|: (mean |u_rel| (m/s), RMS).
    pub speed_bins: Vec<(f64, f64)>,
    /// One sentence on what the signature points at.
    pub reading: String,
}

/// Velocity of the first clamp's rigid motion at rest point `p`, step n (1-based), by backward
/// difference of the clamp poses (zero without clamps).
fn clamp_velocity(ds: &MotionDataset, p: [f64; 3], n: usize) -> [f64; 3] {
    let Some(c) = ds.model.clamps.first() else {
        return [0.0; 3];
    };
    let a = c.poses[n].apply(&p);
    let b = c.poses[n - 1].apply(&p);
    [0, 1, 2].map(|i| (a[i] - b[i]) / ds.model.dt)
}

/// Rest position of marker i (barycentric weights applied to the rest nodes).
fn rest_point(ds: &MotionDataset, i: usize) -> [f64; 3] {
    let mut p = [0.0; 3];
    for &(n, w) in &ds.model.markers[i].weights {
        for (pk, xk) in p.iter_mut().zip(&ds.model.nodes[n]) {
            *pk += w * xk;
        }
    }
    p
}

/// Scalar least squares e ≈ c·x over pairs: (c, share of Σ‖e‖² explained).
fn scalar_fit(pairs: &[([f64; 3], [f64; 3])]) -> (f64, f64) {
    let (mut ex, mut xx, mut ee) = (0.0, 0.0, 0.0);
    for (e, x) in pairs {
        let (e, x) = (Vector3::from(*e), Vector3::from(*x));
        ex += e.dot(&x);
        xx += x.norm_squared();
        ee += e.norm_squared();
    }
    if xx <= 0.0 || ee <= 0.0 {
        return (0.0, 0.0);
    }
    (ex / xx, ex * ex / (xx * ee))
}

/// The signature of `m`'s residual over all observed steps (fitted and held out).
pub fn signature(ds: &MotionDataset, split: Split, m: &FittedModel) -> Signature {
    let t = &m.traj;
    let dt = ds.model.dt;
    let nm = ds.model.markers.len();
    let rest: Vec<[f64; 3]> = (0..nm).map(|i| rest_point(ds, i)).collect();
    let mut speed_pairs = Vec::new();
    let mut accel_pairs = Vec::new();
    let mut speed_sq = Vec::new();
    let mut per_marker = vec![(0.0, 0usize); nm];
    let bins = 8usize;
    let mut tb = vec![(0.0, 0usize); bins];
    for (n, row) in t.res.iter().enumerate() {
        for (i, e) in row.iter().enumerate() {
            let Some(e) = e else { continue };
            let u = t.vel[n][i];
            let uc = clamp_velocity(ds, rest[i], n + 1);
            let ur = Vector3::from(u) - Vector3::from(uc);
            let up = if n == 0 { [0.0; 3] } else { t.vel[n - 1][i] };
            let a = [0, 1, 2].map(|k| (u[k] - up[k]) / dt);
            speed_pairs.push((*e, ur.into()));
            accel_pairs.push((*e, a));
            let e2 = Vector3::from(*e).norm_squared();
            speed_sq.push((ur.norm(), e2));
            per_marker[i].0 += e2;
            per_marker[i].1 += 1;
            let b = (n * bins / split.steps.max(1)).min(bins - 1);
            tb[b].0 += e2;
            tb[b].1 += 1;
        }
    }
    let (speed_coef_s, speed_share) = scalar_fit(&speed_pairs);
    let (accel_coef_s2, accel_share) = scalar_fit(&accel_pairs);
    let nn = (3 * speed_pairs.len()).max(1) as f64;
    let dbic = |share: f64| nn * (1.0 - share).max(f64::MIN_POSITIVE).ln() + nn.ln();
    let (speed_dbic, accel_dbic) = (dbic(speed_share), dbic(accel_share));
    let rms = |(s, c): (f64, usize)| if c == 0 { 0.0 } else { (s / c as f64).sqrt() };
    let time_bins: Vec<(f64, f64)> = tb
        .iter()
        .enumerate()
        .map(|(b, &v)| {
            (
                (b as f64 + 0.5) * split.steps as f64 * dt / bins as f64,
                rms(v),
            )
        })
        .collect();
    let drift_ratio = match (time_bins.first(), time_bins.last()) {
        (Some(f), Some(l)) if f.1 > 0.0 => l.1 / f.1,
        _ => 0.0,
    };
    let per_marker: Vec<(String, f64)> = per_marker
        .iter()
        .enumerate()
        .map(|(i, &v)| (ds.model.markers[i].name.clone(), rms(v)))
        .collect();
    let mut sorted: Vec<f64> = per_marker.iter().map(|p| p.1).collect();
    sorted.sort_by(f64::total_cmp);
    let worst_marker_ratio = match (sorted.get(sorted.len() / 2), sorted.last()) {
        (Some(&med), Some(&worst)) if med > 0.0 => worst / med,
        _ => 0.0,
    };
    let speed_bins = quantile_bins(&mut speed_sq, bins);
    let reading = if speed_dbic <= accel_dbic && speed_dbic < -10.0 {
        format!(
            "a lag along the marker velocity (e ≈ {:.2e} s · u_rel; {:.1} % of the residual \
             energy, ΔBIC {:.1}): what a missing rate-dependent (viscous) force leaves",
            speed_coef_s,
            100.0 * speed_share,
            speed_dbic
        )
    } else if accel_dbic < -10.0 {
        format!(
            "the residual follows the acceleration (e ≈ {:.2e} s² · a; {:.1} % of the residual \
             energy, ΔBIC {:.1}): inertia (mass/density) is off",
            accel_coef_s2,
            100.0 * accel_share,
            accel_dbic
        )
    } else {
        format!(
            "no significant structure: velocity explains {:.1} % (ΔBIC {:.1}), acceleration \
             {:.1} % (ΔBIC {:.1}) of the residual energy; last/first time-bin RMS {:.2}",
            100.0 * speed_share,
            speed_dbic,
            100.0 * accel_share,
            accel_dbic,
            drift_ratio
        )
    };
    Signature {
        speed_coef_s,
        speed_share,
        accel_coef_s2,
        accel_share,
        speed_dbic,
        accel_dbic,
        time_bins,
        drift_ratio,
        per_marker,
        worst_marker_ratio,
        speed_bins,
        reading,
    }
}

/// RMS of the second value in `bins` quantile bins of the first: (mean x, RMS).
pub fn quantile_bins(v: &mut [(f64, f64)], bins: usize) -> Vec<(f64, f64)> {
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    let n = v.len();
    (0..bins)
        .filter_map(|b| {
            let s = &v[b * n / bins..(b + 1) * n / bins];
            (!s.is_empty()).then(|| {
                let x = s.iter().map(|p| p.0).sum::<f64>() / s.len() as f64;
                let y = (s.iter().map(|p| p.1).sum::<f64>() / s.len() as f64).sqrt();
                (x, y)
            })
        })
        .collect()
}
