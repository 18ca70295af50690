//! Simulates a specimen: a block on a fixed bottom face, probed on its top face, with markers on
//! the top and side faces. The truth runs on a mesh `refine` times finer than the dataset's own
//! mesh with the Neo-Hookean (+ stiffening) quasi-static solver; the dataset carries only the
//! coarse mesh, the reported forces and the (noisy, possibly occluded) marker positions.

use serde::Serialize;

use super::effect::{Effect, EffectSpec};
use super::{rng, SpecimenError};
use nalgebra::Vector3;
use palpate_fem::dataset::embed::embed_point;
use palpate_fem::dataset::{Marker, Measurement, StaticDataset};
use palpate_fem::forward::{Load, StaticProblem as LinearProblem};
use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_fem::mesh::centroid;
use palpate_fem::rng::SplitMix64;
use palpate_motion::hyperelastic::HyperParams;
use palpate_motion::statics::{solve_static, StaticProblem as HyperProblem};

/// What to simulate.
#[derive(Debug, Clone, Serialize)]
pub struct SpecimenOptions {
    /// Block size (m).
    pub size: [f64; 3],
    /// Cells per axis of the dataset (fitted) mesh.
    pub cells: [usize; 3],
    /// Refinement factor of the truth mesh (≥ 1).
    pub refine: usize,
    /// Young's modulus of the bulk (Pa).
    pub young: f64,
    /// Poisson ratio of the bulk.
    pub poisson: f64,
    /// Number of probe measurements.
    pub measurements: usize,
    /// Largest probe force (N); the others are spread down to a quarter of it.
    pub max_force: f64,
    /// Probe radius (m).
    pub probe_radius: f64,
    /// Declared marker noise σ (m), written to `dataset.toml`.
    pub noise: f64,
    /// Random seed (contact points, noise, effect directions).
    pub seed: u64,
    /// Effects injected (and never declared).
    pub effects: Vec<EffectSpec>,
    /// Reference world for measuring an effect's signal: the force applied is the force the
    /// dataset reports (so a calibration effect changes the reported forces and the truth follows
    /// them). `diagnose-evidence --sweep` compares a specimen's truth with this world's truth to
    /// get what the effect does to the markers beyond what the reported data explain.
    pub apply_reported_force: bool,
    /// Centre of the inclusion effect, as fractions of `size` (default (0.5, 0.5, 0.6): under the
    /// middle of the probed top face).
    pub inclusion_centre: [f64; 3],
    /// Radius of the inclusion effect as a fraction of the x size (default 0.22).
    pub inclusion_radius: f64,
}

impl Default for SpecimenOptions {
    fn default() -> Self {
        Self {
            size: [0.08, 0.08, 0.04],
            cells: [6, 6, 3],
            refine: 2,
            young: 20e3,
            poisson: 0.35,
            measurements: 8,
            max_force: 1.5,
            probe_radius: 0.012,
            noise: 1e-4,
            seed: 1,
            effects: Vec::new(),
            apply_reported_force: false,
            inclusion_centre: [0.5, 0.5, 0.6],
            inclusion_radius: 0.22,
        }
    }
}

impl SpecimenOptions {
    /// The default specimen of `seed` with `effect` (if any) injected at its default magnitude.
    pub fn with_effect(effect: Option<Effect>, seed: u64) -> Self {
        Self {
            seed,
            effects: effect
                .map(|e| {
                    vec![EffectSpec {
                        effect: e,
                        magnitude: e.default_magnitude(),
                    }]
                })
                .unwrap_or_default(),
            ..Default::default()
        }
    }

    /// Magnitude of `e` if injected.
    pub fn magnitude(&self, e: Effect) -> Option<f64> {
        self.effects
            .iter()
            .find(|s| s.effect == e)
            .map(|s| s.magnitude)
    }
}

/// Ground truth of one measurement.
#[derive(Debug, Clone, Serialize)]
pub struct TruthMeasurement {
    /// Measurement id.
    pub id: String,
    /// Force actually applied (N).
    pub true_force: [f64; 3],
    /// Force written to the dataset (N).
    pub reported_force: [f64; 3],
    /// Noise-free, registration-free marker positions (m), every marker.
    pub markers: Vec<[f64; 3]>,
    /// Rigid support translation applied (m).
    pub support_translation: [f64; 3],
}

/// The ground truth (`truth.json`). Never read by the fitter or by diagnose.
#[derive(Debug, Clone, Serialize)]
pub struct Truth {
    /// Note to readers.
    pub note: &'static str,
    /// Options used (effects and magnitudes included).
    pub options: SpecimenOptions,
    /// Truth mesh: nodes and tets.
    pub truth_mesh: [usize; 2],
    /// Tilt direction (unit, horizontal) if tilt is injected.
    pub tilt_direction: Option<[f64; 3]>,
    /// Registration: rotation vector (rad) and translation (m), applied about the block centre.
    pub registration: Option<([f64; 3], [f64; 3])>,
    /// Actual marker noise σ (m).
    pub actual_noise: f64,
    /// Per measurement.
    pub measurements: Vec<TruthMeasurement>,
}

/// A generated specimen.
#[derive(Debug, Clone)]
pub struct Specimen {
    /// The dataset (what a user would have).
    pub dataset: StaticDataset,
    /// The ground truth.
    pub truth: Truth,
}

impl Specimen {
    /// Writes the dataset and `truth.json` into `dir`.
    pub fn write(&self, dir: &std::path::Path) -> Result<(), SpecimenError> {
        self.dataset.write(dir)?;
        let file = dir.join("truth.json");
        let json = super::to_json(&file, &self.truth)?;
        super::write_file(&file, json.as_bytes())
    }
}

fn hyper(young: f64, nu: f64) -> HyperParams {
    HyperParams {
        lambda: young * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
        mu: young / (2.0 * (1.0 + nu)),
        stiffening: 0.0,
    }
}

/// Rodrigues rotation, shared with the diagnosis (which must rotate markers the same way).
pub use palpate_fem::geometry::rotate;

/// Markers: an 8 × 8 grid on the top face and two rows of five on each side face (inset from
/// the edges so every marker sits inside one face).
fn marker_points(size: [f64; 3]) -> Vec<[f64; 3]> {
    let mut pts = Vec::new();
    for j in 0..8 {
        for i in 0..8 {
            pts.push([
                size[0] * (0.06 + 0.88 * i as f64 / 7.0),
                size[1] * (0.06 + 0.88 * j as f64 / 7.0),
                size[2],
            ]);
        }
    }
    for &zf in &[0.45, 0.85] {
        for k in 0..5 {
            let s = 0.1 + 0.8 * k as f64 / 4.0;
            let z = size[2] * zf;
            pts.push([size[0] * s, 0.0, z]);
            pts.push([size[0] * s, size[1], z]);
            pts.push([0.0, size[1] * s, z]);
            pts.push([size[0], size[1] * s, z]);
        }
    }
    pts
}

/// Generates a specimen.
pub fn generate(o: &SpecimenOptions) -> Result<Specimen, SpecimenError> {
    for s in &o.effects {
        s.effect.check(s.magnitude)?;
    }
    if o.refine == 0 || o.measurements == 0 || o.cells.contains(&0) {
        return Err(SpecimenError::Options(
            "refine, measurements and cells must be ≥ 1".into(),
        ));
    }
    if !(o.noise >= 0.0
        && o.max_force > 0.0
        && o.young > 0.0
        && o.poisson > -1.0
        && o.poisson < 0.5)
    {
        return Err(SpecimenError::Options(format!(
            "need noise ≥ 0, max force > 0, E > 0, −1 < ν < 0.5 (got σ {}, f {}, E {}, ν {})",
            o.noise, o.max_force, o.young, o.poisson
        )));
    }
    let size = o.size;
    let mut rng = rng(o.seed);
    let coarse = box_mesh(size, o.cells);
    let fine = box_mesh(size, o.cells.map(|c| c * o.refine));
    let fixed_c = coarse
        .node_groups
        .get("bottom")
        .cloned()
        .unwrap_or_default();
    let fixed_f = fine.node_groups.get("bottom").cloned().unwrap_or_default();
    let surf_c = coarse.boundary_triangles();
    let surf_f = fine.boundary_triangles();
    let lin_fine = LinearProblem::new(&fine, &fixed_f, &surf_f)?;

    // Material per truth element.
    let base = hyper(o.young, o.poisson);
    let stiff = o.magnitude(Effect::Stiffening).unwrap_or(0.0) * base.mu;
    let material: Vec<HyperParams> = fine
        .tets
        .iter()
        .map(|t| {
            let c = centroid(&fine.nodes, t);
            let mut e = o.young;
            if let Some(m) = o.magnitude(Effect::Inclusion) {
                let centre = [0, 1, 2].map(|d| o.inclusion_centre[d] * size[d]);
                let r = o.inclusion_radius * size[0];
                if (0..3).map(|d| (c[d] - centre[d]).powi(2)).sum::<f64>() <= r * r {
                    e *= 1.0 + m;
                }
            }
            if let Some(m) = o.magnitude(Effect::SoftLayer) {
                if c[2] >= 0.75 * size[2] {
                    e /= 1.0 + m;
                }
            }
            HyperParams {
                stiffening: stiff,
                ..hyper(e, o.poisson)
            }
        })
        .collect();
    let density = 1000.0 * o.magnitude(Effect::Gravity).unwrap_or(0.0);

    // Markers embedded in both meshes.
    let points = marker_points(size);
    let mut emb_f = Vec::with_capacity(points.len());
    for (k, &p) in points.iter().enumerate() {
        emb_f.push(embed_point(&fine, &surf_f, p).ok_or(SpecimenError::Embed {
            marker: k,
            point: p,
            mesh: "truth",
        })?);
    }
    let interp = |x: &[[f64; 3]], k: usize| {
        let e = &emb_f[k];
        let mut p = [0.0; 3];
        for (w, &n) in e.barycentric.iter().zip(&e.triangle) {
            for d in 0..3 {
                p[d] += w * x[n][d];
            }
        }
        p
    };
    let hyper_problem = |forces: Vec<(usize, [f64; 3])>, fixed_disp: Vec<[f64; 3]>| {
        let mut p = HyperProblem::new(&fine, base, fixed_f.clone());
        p.material = material.clone();
        p.density = density;
        p.gravity = [0.0, 0.0, -9.81];
        p.forces = forces;
        p.fixed_displacement = fixed_disp;
        // 1e-7 N on probe forces of 0.4–1.5 N: a relative residual of 1e-7, far below any
        // effect; stiffening needs more increments for Newton to converge.
        p.load_steps = if stiff > 0.0 { 16 } else { 8 };
        p.tol = 1e-7;
        p
    };
    // The rest scan: under gravity when that effect is on.
    let rest_positions: Vec<[f64; 3]> = if density > 0.0 {
        let s = solve_static(&hyper_problem(Vec::new(), Vec::new())).map_err(|e| {
            SpecimenError::Truth {
                measurement: usize::MAX,
                message: format!("gravity rest scan: {e}"),
            }
        })?;
        (0..points.len()).map(|k| interp(&s.positions, k)).collect()
    } else {
        points.clone()
    };
    // A noisy rest scan declares every marker off its true place (its own random stream, so the
    // contacts and the measurements' noise are the same with and without it).
    let rest_positions: Vec<[f64; 3]> = match o.magnitude(Effect::RestNoise) {
        Some(m) => {
            let mut rest_rng = crate::rng(o.seed ^ 0x7e57_5ca0);
            rest_positions
                .iter()
                .map(|p| p.map(|v| v + m * o.noise * rest_rng.normal()))
                .collect()
        }
        None => rest_positions,
    };
    let mut markers = Vec::with_capacity(points.len());
    for (k, &p) in rest_positions.iter().enumerate() {
        let e = embed_point(&coarse, &surf_c, p).ok_or(SpecimenError::Embed {
            marker: k,
            point: p,
            mesh: "dataset",
        })?;
        markers.push(Marker::embedded(format!("m{k}"), p, &e, &coarse.nodes));
    }

    // Effect directions (drawn even when unused so the contact stream is the same for every
    // effect set: a clean and an effected specimen of one seed probe the same points).
    let unit = |rng: &mut SplitMix64| {
        let v = Vector3::new(rng.normal(), rng.normal(), rng.normal());
        let n = v.norm().max(1e-12);
        <[f64; 3]>::from(v / n)
    };
    let reg_axis = unit(&mut rng);
    let reg_dir = unit(&mut rng);
    let phi = std::f64::consts::TAU * rng.uniform();
    let tilt_dir = [phi.cos(), phi.sin(), 0.0];
    let half = 0.5 * size[0].min(size[1]);
    let registration = o
        .magnitude(Effect::Registration)
        .map(|m| (reg_axis.map(|a| a * m / half), reg_dir.map(|a| a * m)));
    let centre = [0.5 * size[0], 0.5 * size[1], 0.5 * size[2]];
    let base_c = [0.5 * size[0], 0.5 * size[1], 0.0];
    let sigma = o.noise * (1.0 + o.magnitude(Effect::Noise).unwrap_or(0.0));
    let drop = o.magnitude(Effect::Occlusion).unwrap_or(0.0);

    // Contact magnitudes spread evenly from f_max/4 to f_max, in shuffled order.
    let n = o.measurements;
    let mut mags: Vec<f64> = (0..n)
        .map(|i| {
            o.max_force
                * (0.25
                    + 0.75
                        * if n == 1 {
                            1.0
                        } else {
                            i as f64 / (n - 1) as f64
                        })
        })
        .collect();
    for i in (1..n).rev() {
        let j = (rng.uniform() * (i + 1) as f64) as usize % (i + 1);
        mags.swap(i, j);
    }
    let mut measurements = Vec::with_capacity(n);
    let mut truth_meas = Vec::with_capacity(n);
    for (i, &fm) in mags.iter().enumerate() {
        let point = [
            size[0] * (0.25 + 0.5 * rng.uniform()),
            size[1] * (0.25 + 0.5 * rng.uniform()),
            size[2],
        ];
        let nominal = [0.0, 0.0, -fm];
        let reported = match o.magnitude(Effect::Calibration) {
            Some(m) => nominal.map(|v| v * (fm / o.max_force).powf(m)),
            None => nominal,
        };
        let applied = if o.apply_reported_force {
            reported
        } else {
            nominal
        };
        let true_force = match o.magnitude(Effect::Tilt) {
            Some(m) => [0, 1, 2].map(|d| applied[d] + m * fm * tilt_dir[d]),
            None => applied,
        };
        // The patch the truth is loaded over: the declared probe's unless the contact-radius
        // effect widens it (the dataset still declares `o.probe_radius`).
        let patch = o.probe_radius * (1.0 + o.magnitude(Effect::ContactRadius).unwrap_or(0.0));
        let fvec = lin_fine.force_vector(&Load::contact(point, true_force, patch))?;
        let forces: Vec<(usize, [f64; 3])> = (0..fine.nodes.len())
            .map(|k| (k, [fvec[3 * k], fvec[3 * k + 1], fvec[3 * k + 2]]))
            .filter(|(_, f)| f.iter().any(|v| *v != 0.0))
            .collect();
        let (support_t, fixed_disp) = match o.magnitude(Effect::Boundary) {
            Some(c) => {
                let t = true_force.map(|f| c * f);
                let arm = [0, 1, 2].map(|d| point[d] - base_c[d]);
                let theta = <[f64; 3]>::from(Vector3::from(arm).cross(&Vector3::from(true_force)))
                    .map(|m| c * m / (half * half));
                let disp = fixed_f
                    .iter()
                    .map(|&k| {
                        let r = [0, 1, 2].map(|d| fine.nodes[k][d] - base_c[d]);
                        let w = Vector3::from(theta).cross(&Vector3::from(r));
                        [0, 1, 2].map(|d| t[d] + w[d])
                    })
                    .collect();
                (t, disp)
            }
            None => ([0.0; 3], Vec::new()),
        };
        let sol =
            solve_static(&hyper_problem(forces, fixed_disp)).map_err(|e| SpecimenError::Truth {
                measurement: i,
                message: e.to_string(),
            })?;
        let clean: Vec<[f64; 3]> = (0..points.len())
            .map(|k| interp(&sol.positions, k))
            .collect();
        let mut observed = Vec::with_capacity(clean.len());
        for (k, p) in clean.iter().enumerate() {
            let mut q = *p;
            if let Some((w, t)) = registration {
                let r = rotate(w, [0, 1, 2].map(|d| q[d] - centre[d]));
                q = [0, 1, 2].map(|d| centre[d] + r[d] + t[d]);
            }
            let q = q.map(|v| v + sigma * rng.normal());
            // Draw always (same noise stream with and without occlusion).
            let u = rng.uniform();
            if u >= drop {
                observed.push((k, q));
            }
        }
        let id = format!("c{i}");
        measurements.push(Measurement {
            id: id.clone(),
            contact: point,
            force: reported,
            radius: o.probe_radius,
            observed,
        });
        truth_meas.push(TruthMeasurement {
            id,
            true_force,
            reported_force: reported,
            markers: clean,
            support_translation: support_t,
        });
    }
    let names: Vec<String> = o
        .effects
        .iter()
        .map(|e| e.effect.name().to_string())
        .collect();
    let dataset = StaticDataset {
        marker_standoff: None,
        name: format!("specimen-seed{}", o.seed),
        description: format!(
            "palpate specimen: {}x{}x{} m block, fitted mesh {:?}; simulated by `palpate specimen` (the injected effects are in truth.json only{})",
            size[0],
            size[1],
            size[2],
            o.cells,
            if names.is_empty() { ", none here" } else { "" }
        ),
        mesh: coarse,
        fixed_group: "bottom".into(),
        fixed_nodes: fixed_c,
        surface: surf_c,
        probe_radius: o.probe_radius,
        marker_noise: (o.noise > 0.0).then_some(o.noise),
        gravity: None,
        markers,
        measurements,
    };
    let truth = Truth {
        note: "ground truth of a palpate specimen; never read by the fitter or by diagnose",
        options: o.clone(),
        truth_mesh: [fine.nodes.len(), fine.tets.len()],
        tilt_direction: o.magnitude(Effect::Tilt).map(|_| tilt_dir),
        registration,
        actual_noise: sigma,
        measurements: truth_meas,
    };
    Ok(Specimen { dataset, truth })
}
