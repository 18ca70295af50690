//! Residual signatures: the ways an engineer looks at a residual field (per measurement and its
//! scale factor against load magnitude, against distance from the contact, its rigid-body part,
//! its persistent per-marker part over space) and the (x, y) points that show a given effect.

use nalgebra::{Matrix6, Vector3, Vector6};
use palpate_static_fit::evidence::centred_products;
use serde::Serialize;

use super::fit::Fitted;
use super::model::{Candidate, Context};

/// Residual signature of one measurement.
#[derive(Debug, Clone, Serialize)]
pub struct MeasurementSignature {
    /// Measurement id.
    pub id: String,
    /// Reported force magnitude (N).
    pub force: f64,
    /// RMS marker error (m).
    pub rms: f64,
    /// Largest marker error (m).
    pub max: f64,
    /// Best scale s of the simulated displacement onto the measured one (1 = right load level).
    pub scale: f64,
    /// Rigid part of the residual: translation (m) and rotation vector (rad) about the mesh centre.
    pub rigid: ([f64; 3], [f64; 3]),
    /// Mean residual vector (m).
    pub mean: [f64; 3],
}

/// The whole signature.
#[derive(Debug, Clone, Serialize)]
pub struct Signature {
    /// Per measurement.
    pub per_measurement: Vec<MeasurementSignature>,
    /// Pearson correlation of the scale factors with the force magnitude.
    pub scale_vs_force: f64,
    /// RMS residual (m) in distance-from-contact bins of one probe radius: (upper edge m, rms, count).
    pub vs_distance: Vec<(f64, f64, usize)>,
    /// Fraction of the residual energy explained by one rigid transform for all measurements.
    pub rigid_fraction: f64,
    /// Fraction of the residual energy that is the same at each marker in every measurement.
    pub persistent_fraction: f64,
    /// Markers with the largest RMS residual: (id, rms m).
    pub worst_markers: Vec<(String, f64)>,
}

/// Residual vectors (simulated − measured, m) with their marker index, per fitted measurement.
pub fn residual_vectors(ctx: &Context, f: &Fitted) -> Vec<Vec<(usize, [f64; 3])>> {
    f.subset
        .iter()
        .zip(&f.sim.markers)
        .map(|(&i, sim)| {
            ctx.meas[i]
                .observed
                .iter()
                .zip(sim)
                .map(|(&(k, m), p)| (k, [0, 1, 2].map(|d| p[d] - m[d])))
                .collect()
        })
        .collect()
}

/// Least-squares rigid part e ≈ t + ω × (p − c) of residuals `e` at points `p`.
fn rigid_fit(points: &[[f64; 3]], e: &[[f64; 3]], c: [f64; 3]) -> ([f64; 3], [f64; 3], f64) {
    let mut a = Matrix6::zeros();
    let mut b = Vector6::zeros();
    for (p, r) in points.iter().zip(e) {
        let q = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
        // rows: e_d = t_d + (ω × q)_d ; ω × q = [ω1 q2 − ω2 q1, ω2 q0 − ω0 q2, ω0 q1 − ω1 q0]
        let rows = [
            [1.0, 0.0, 0.0, 0.0, q[2], -q[1]],
            [0.0, 1.0, 0.0, -q[2], 0.0, q[0]],
            [0.0, 0.0, 1.0, q[1], -q[0], 0.0],
        ];
        for d in 0..3 {
            let row = Vector6::from_row_slice(&rows[d]);
            a += row * row.transpose();
            b += row * r[d];
        }
    }
    let x = (a + Matrix6::identity() * 1e-18)
        .cholesky()
        .map(|ch| ch.solve(&b))
        .unwrap_or_else(Vector6::zeros);
    let total: f64 = e.iter().map(|r| r.iter().map(|v| v * v).sum::<f64>()).sum();
    let mut left = 0.0;
    for (p, r) in points.iter().zip(e) {
        let q = Vector3::from(*p) - Vector3::from(c);
        let wq = Vector3::new(x[3], x[4], x[5]).cross(&q);
        left += (0..3).map(|d| (r[d] - x[d] - wq[d]).powi(2)).sum::<f64>();
    }
    (
        [x[0], x[1], x[2]],
        [x[3], x[4], x[5]],
        if total > 0.0 { 1.0 - left / total } else { 0.0 },
    )
}

fn pearson(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    if a.len() < 3 {
        return 0.0;
    }
    let (sab, saa, sbb) = centred_products(a, b, n);
    if saa > 0.0 && sbb > 0.0 {
        sab / (saa * sbb).sqrt()
    } else {
        0.0
    }
}

/// Best scale of simulated displacements onto measured ones for measurement `i`.
fn scale(ctx: &Context, i: usize, sim: &[[f64; 3]]) -> f64 {
    let mut sums = (0.0, 0.0);
    ctx.add_scale_terms(i, sim, &mut sums);
    let (num, den) = sums;
    if den > 0.0 {
        num / den
    } else {
        1.0
    }
}

/// Computes the signature of a fit.
pub fn signature(ctx: &Context, f: &Fitted) -> Signature {
    let res = residual_vectors(ctx, f);
    let mut per = Vec::new();
    let (mut all_p, mut all_e) = (Vec::new(), Vec::new());
    let nm = ctx.markers.len();
    let (mut sum, mut sumsq, mut count) = (vec![[0.0; 3]; nm], vec![0.0; nm], vec![0usize; nm]);
    let bin = ctx
        .meas
        .iter()
        .map(|m| m.radius)
        .fold(0.0, f64::max)
        .max(1e-6);
    let mut bins: Vec<(f64, usize)> = vec![(0.0, 0); 12];
    for ((&i, r), sim) in f.subset.iter().zip(&res).zip(&f.sim.markers) {
        let m = &ctx.meas[i];
        let pts: Vec<[f64; 3]> = r.iter().map(|&(k, _)| ctx.marker_rest[k]).collect();
        let es: Vec<[f64; 3]> = r.iter().map(|&(_, e)| e).collect();
        let norms: Vec<f64> = es.iter().map(|&e| Vector3::from(e).norm()).collect();
        let (t, w, _) = rigid_fit(&pts, &es, ctx.frame.centre);
        let mut mean = [0.0; 3];
        for e in &es {
            for d in 0..3 {
                mean[d] += e[d] / es.len() as f64;
            }
        }
        per.push(MeasurementSignature {
            id: m.id.clone(),
            force: Vector3::from(m.force).norm(),
            rms: (norms.iter().map(|v| v * v).sum::<f64>() / norms.len().max(1) as f64).sqrt(),
            max: norms.iter().copied().fold(0.0, f64::max),
            scale: scale(ctx, i, sim),
            rigid: (t, w),
            mean,
        });
        for (&(k, e), p) in r.iter().zip(&pts) {
            for d in 0..3 {
                sum[k][d] += e[d];
            }
            sumsq[k] += e.iter().map(|v| v * v).sum::<f64>();
            count[k] += 1;
            let dist = (Vector3::from(*p) - Vector3::from(m.point)).norm();
            let b = ((dist / bin) as usize).min(bins.len() - 1);
            bins[b].0 += e.iter().map(|v| v * v).sum::<f64>();
            bins[b].1 += 1;
        }
        all_p.extend(pts);
        all_e.extend(es);
    }
    let (_, _, rigid_fraction) = rigid_fit(&all_p, &all_e, ctx.frame.centre);
    let total: f64 = sumsq.iter().sum();
    let persistent: f64 = (0..nm)
        .filter(|&k| count[k] > 0)
        .map(|k| sum[k].iter().map(|v| v * v).sum::<f64>() / count[k] as f64)
        .sum();
    let mut worst: Vec<(String, f64)> = (0..nm)
        .filter(|&k| count[k] > 0)
        .map(|k| {
            (
                ctx.markers[k].id.clone(),
                (sumsq[k] / count[k] as f64).sqrt(),
            )
        })
        .collect();
    worst.sort_by(|a, b| b.1.total_cmp(&a.1));
    worst.truncate(5);
    let forces: Vec<f64> = per.iter().map(|p| p.force).collect();
    let scales: Vec<f64> = per.iter().map(|p| p.scale).collect();
    Signature {
        scale_vs_force: pearson(&forces, &scales),
        per_measurement: per,
        vs_distance: bins
            .iter()
            .enumerate()
            .filter(|(_, b)| b.1 > 0)
            .map(|(j, b)| ((j + 1) as f64 * bin, (b.0 / b.1 as f64).sqrt(), b.1))
            .collect(),
        rigid_fraction,
        persistent_fraction: if total > 0.0 { persistent / total } else { 0.0 },
        worst_markers: worst,
    }
}

/// The variable that gives an effect away and the residual measure plotted against it:
/// (x label, y label, points).
pub type EvidencePoints = (&'static str, &'static str, Vec<(f64, f64)>);

/// A fit's residual as the candidates' evidence reads it: its signature and its vectors.
pub struct Residual<'a> {
    /// The dataset.
    pub ctx: &'a Context,
    /// The fit.
    pub fit: &'a Fitted,
    /// Its signature.
    pub signature: Signature,
    /// Its residual vectors ([`residual_vectors`]).
    pub vectors: Vec<Vec<(usize, [f64; 3])>>,
}

impl<'a> Residual<'a> {
    /// The residual of fit `f`.
    pub fn of(ctx: &'a Context, f: &'a Fitted) -> Self {
        Self {
            ctx,
            fit: f,
            signature: signature(ctx, f),
            vectors: residual_vectors(ctx, f),
        }
    }

    /// Each measurement's displacement scale against its reported force (a load-dependent
    /// response: a calibration curve, a modulus that changes with the strain).
    pub fn scale_against_force(&self) -> EvidencePoints {
        (
            "reported force |f| (N)",
            "displacement scale factor (measured / simulated)",
            self.signature
                .per_measurement
                .iter()
                .map(|p| (p.force, p.scale))
                .collect(),
        )
    }

    /// Each measurement's displacement scale in file order (a gain that changes from measurement
    /// to measurement).
    pub fn scale_by_measurement(&self) -> EvidencePoints {
        (
            "measurement (in file order)",
            "displacement scale factor (measured / simulated)",
            self.signature
                .per_measurement
                .iter()
                .enumerate()
                .map(|(i, p)| ((i + 1) as f64, p.scale))
                .collect(),
        )
    }

    /// Each measurement's horizontal mean residual against its reported force (a tangential
    /// force).
    pub fn horizontal_mean_against_force(&self) -> EvidencePoints {
        (
            "reported force |f| (N)",
            "horizontal mean residual (mm)",
            self.signature
                .per_measurement
                .iter()
                .map(|p| {
                    (
                        p.force,
                        1e3 * (p.mean[0].powi(2) + p.mean[1].powi(2)).sqrt(),
                    )
                })
                .collect(),
        )
    }

    /// Each measurement's rigid translation of the residual against its reported force.
    pub fn rigid_translation_against_force(&self) -> EvidencePoints {
        (
            "reported force |f| (N)",
            "rigid translation of the residual (mm)",
            self.signature
                .per_measurement
                .iter()
                .map(|p| (p.force, 1e3 * Vector3::from(p.rigid.0).norm()))
                .collect(),
        )
    }

    /// Each measurement's rigid part of the residual, |t| + h|ω|, against its reported force.
    pub fn rigid_part_against_force(&self) -> EvidencePoints {
        let half = self.ctx.frame.half;
        (
            "reported force |f| (N)",
            "rigid part of the residual: |t| + h|ω| (mm)",
            self.signature
                .per_measurement
                .iter()
                .map(|p| {
                    (
                        p.force,
                        1e3 * (Vector3::from(p.rigid.0).norm()
                            + half * Vector3::from(p.rigid.1).norm()),
                    )
                })
                .collect(),
        )
    }

    /// Each marker's mean vertical residual against its height.
    pub fn vertical_against_height(&self) -> EvidencePoints {
        let ctx = self.ctx;
        let nm = ctx.markers.len();
        let (mut s, mut n) = (vec![0.0; nm], vec![0usize; nm]);
        for r in &self.vectors {
            for &(k, e) in r {
                s[k] += e[2];
                n[k] += 1;
            }
        }
        (
            "marker height z (m)",
            "mean vertical residual (mm)",
            (0..nm)
                .filter(|&k| n[k] > 0)
                .map(|k| (ctx.marker_rest[k][2], 1e3 * s[k] / n[k] as f64))
                .collect(),
        )
    }

    /// Every marker error against its distance from the contact (concentrated near it, or
    /// spread evenly).
    pub fn error_against_distance(&self) -> EvidencePoints {
        let ctx = self.ctx;
        let mut pts = Vec::new();
        for (&i, r) in self.fit.subset.iter().zip(&self.vectors) {
            let c = ctx.meas[i].point;
            for &(k, e) in r {
                let p = ctx.marker_rest[k];
                pts.push((
                    (Vector3::from(p) - Vector3::from(c)).norm(),
                    1e3 * Vector3::from(e).norm(),
                ));
            }
        }
        ("distance from the contact (m)", "marker error (mm)", pts)
    }
}

/// The variable that gives effect `c` away, and the residual measure plotted against it:
/// (x label, y label, points).
pub fn evidence_points(c: Candidate, ctx: &Context, f: &Fitted) -> EvidencePoints {
    c.effect().evidence(&Residual::of(ctx, f))
}
