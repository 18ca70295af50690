//! Simulates a specimen: a block on a fixed bottom face, probed on its top face, with markers on
//! the top and side faces. The truth runs on a mesh `refine` times finer than the dataset's own
//! mesh with the Neo-Hookean (+ stiffening) quasi-static solver; the dataset carries only the
//! coarse mesh, the reported forces and the (noisy, possibly occluded) marker positions.

use serde::Serialize;

use super::effect::{Effect, EffectSpec};
use super::{rng, SpecimenError};
use nalgebra::Vector3;
use palpate_fem::dataset::embed::{embed_point, Embedding};
use palpate_fem::dataset::{Marker, Measurement, StaticDataset};
use palpate_fem::forward::{Load, StaticProblem as LinearProblem};
use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_fem::mesh::{centroid, Mesh};
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

/// Generates a specimen: the truth body, the markers at rest, then one truth solve per probe
/// contact with the effects applied to what the dataset records.
pub fn generate(o: &SpecimenOptions) -> Result<Specimen, SpecimenError> {
    check_options(o)?;
    let size = o.size;
    let mut rng = rng(o.seed);
    let coarse = box_mesh(size, o.cells);
    let fixed_c = coarse
        .node_groups
        .get("bottom")
        .cloned()
        .unwrap_or_default();
    let surf_c = coarse.boundary_triangles();
    let body = TruthBody::new(o)?;
    let rest_positions = body.rest_scan(o)?;
    let mut markers = Vec::with_capacity(rest_positions.len());
    for (k, &p) in rest_positions.iter().enumerate() {
        let e = embed_point(&coarse, &surf_c, p).ok_or(SpecimenError::Embed {
            marker: k,
            point: p,
            mesh: "dataset",
        })?;
        markers.push(Marker::embedded(format!("m{k}"), p, &e, &coarse.nodes));
    }
    let draws = EffectDraws::draw(o, &mut rng);
    let mags = contact_magnitudes(o, &mut rng);
    let mut measurements = Vec::with_capacity(mags.len());
    let mut truth_meas = Vec::with_capacity(mags.len());
    for (i, &fm) in mags.iter().enumerate() {
        let (m, t) = body.measure(o, &draws, i, fm, &mut rng)?;
        measurements.push(m);
        truth_meas.push(t);
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
        truth_mesh: [body.mesh.nodes.len(), body.mesh.tets.len()],
        tilt_direction: o.magnitude(Effect::Tilt).map(|_| draws.tilt_dir),
        registration: draws.registration,
        actual_noise: draws.sigma,
        measurements: truth_meas,
    };
    Ok(Specimen { dataset, truth })
}

/// Refuses options no specimen can be made of: an effect's magnitude out of its range, zero
/// counts, a non-physical material or a non-positive force.
fn check_options(o: &SpecimenOptions) -> Result<(), SpecimenError> {
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
    Ok(())
}

/// The truth: the finer mesh, its material with the material effects (inclusion, soft layer,
/// stiffening), the density of the gravity effect, and the markers' true places embedded in it.
struct TruthBody {
    mesh: Mesh,
    fixed: Vec<usize>,
    linear: LinearProblem,
    base: HyperParams,
    stiff: f64,
    material: Vec<HyperParams>,
    density: f64,
    points: Vec<[f64; 3]>,
    embedded: Vec<Embedding>,
    /// The centre of the clamped bottom face, about which the boundary effect turns.
    base_centre: [f64; 3],
}

impl TruthBody {
    fn new(o: &SpecimenOptions) -> Result<Self, SpecimenError> {
        let size = o.size;
        let mesh = box_mesh(size, o.cells.map(|c| c * o.refine));
        let fixed = mesh.node_groups.get("bottom").cloned().unwrap_or_default();
        let surface = mesh.boundary_triangles();
        let linear = LinearProblem::new(&mesh, &fixed, &surface)?;
        let base = hyper(o.young, o.poisson);
        let stiff = o.magnitude(Effect::Stiffening).unwrap_or(0.0) * base.mu;
        let material: Vec<HyperParams> = mesh
            .tets
            .iter()
            .map(|t| {
                let c = centroid(&mesh.nodes, t);
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
        let points = marker_points(size);
        let mut embedded = Vec::with_capacity(points.len());
        for (k, &p) in points.iter().enumerate() {
            embedded.push(embed_point(&mesh, &surface, p).ok_or(SpecimenError::Embed {
                marker: k,
                point: p,
                mesh: "truth",
            })?);
        }
        Ok(Self {
            mesh,
            fixed,
            linear,
            base,
            stiff,
            material,
            density,
            points,
            embedded,
            base_centre: [0.5 * size[0], 0.5 * size[1], 0.0],
        })
    }

    /// Marker `k`'s place on the truth mesh with node positions `x`.
    fn marker(&self, x: &[[f64; 3]], k: usize) -> [f64; 3] {
        let e = &self.embedded[k];
        let mut p = [0.0; 3];
        for (w, &n) in e.barycentric.iter().zip(&e.triangle) {
            for d in 0..3 {
                p[d] += w * x[n][d];
            }
        }
        p
    }

    /// Every marker's place on the truth mesh with node positions `x`.
    fn markers(&self, x: &[[f64; 3]]) -> Vec<[f64; 3]> {
        (0..self.points.len()).map(|k| self.marker(x, k)).collect()
    }

    /// The truth's quasi-static problem under nodal `forces` and support displacements.
    fn problem(
        &self,
        forces: Vec<(usize, [f64; 3])>,
        fixed_displacement: Vec<[f64; 3]>,
    ) -> HyperProblem<'_> {
        let mut p = HyperProblem::new(&self.mesh, self.base, self.fixed.clone());
        p.material = self.material.clone();
        p.density = self.density;
        p.gravity = [0.0, 0.0, -9.81];
        p.forces = forces;
        p.fixed_displacement = fixed_displacement;
        // 1e-7 N on probe forces of 0.4–1.5 N: a relative residual of 1e-7, far below any
        // effect; stiffening needs more increments for Newton to converge.
        p.load_steps = if self.stiff > 0.0 { 16 } else { 8 };
        p.tol = 1e-7;
        p
    }

    /// The rest scan the dataset declares: under gravity when that effect is on, and off the
    /// true places when the rest-noise effect is.
    fn rest_scan(&self, o: &SpecimenOptions) -> Result<Vec<[f64; 3]>, SpecimenError> {
        let rest_positions: Vec<[f64; 3]> = if self.density > 0.0 {
            let s = solve_static(&self.problem(Vec::new(), Vec::new())).map_err(|e| {
                SpecimenError::Truth {
                    measurement: usize::MAX,
                    message: format!("gravity rest scan: {e}"),
                }
            })?;
            self.markers(&s.positions)
        } else {
            self.points.clone()
        };
        // A noisy rest scan declares every marker off its true place (its own random stream, so
        // the contacts and the measurements' noise are the same with and without it).
        Ok(match o.magnitude(Effect::RestNoise) {
            Some(m) => {
                let mut rest_rng = crate::rng(o.seed ^ 0x7e57_5ca0);
                rest_positions
                    .iter()
                    .map(|p| p.map(|v| v + m * o.noise * rest_rng.normal()))
                    .collect()
            }
            None => rest_positions,
        })
    }

    /// Measurement `i`: a contact of magnitude `fm` at a random point of the top face, solved on
    /// the truth, then what the dataset records of it (reported force, noisy and occluded
    /// markers, registration offset) beside the truth's own record.
    fn measure(
        &self,
        o: &SpecimenOptions,
        draws: &EffectDraws,
        i: usize,
        fm: f64,
        rng: &mut SplitMix64,
    ) -> Result<(Measurement, TruthMeasurement), SpecimenError> {
        let size = o.size;
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
            Some(m) => [0, 1, 2].map(|d| applied[d] + m * fm * draws.tilt_dir[d]),
            None => applied,
        };
        // The patch the truth is loaded over: the declared probe's unless the contact-radius
        // effect widens it (the dataset still declares `o.probe_radius`).
        let patch = o.probe_radius * (1.0 + o.magnitude(Effect::ContactRadius).unwrap_or(0.0));
        let fvec = self
            .linear
            .force_vector(&Load::contact(point, true_force, patch))?;
        let forces: Vec<(usize, [f64; 3])> = (0..self.mesh.nodes.len())
            .map(|k| (k, [fvec[3 * k], fvec[3 * k + 1], fvec[3 * k + 2]]))
            .filter(|(_, f)| f.iter().any(|v| *v != 0.0))
            .collect();
        let (support_t, fixed_disp) = match o.magnitude(Effect::Boundary) {
            Some(c) => self.support_motion(c, point, true_force, draws.half),
            None => ([0.0; 3], Vec::new()),
        };
        let sol =
            solve_static(&self.problem(forces, fixed_disp)).map_err(|e| SpecimenError::Truth {
                measurement: i,
                message: e.to_string(),
            })?;
        let clean = self.markers(&sol.positions);
        let mut observed = Vec::with_capacity(clean.len());
        for (k, p) in clean.iter().enumerate() {
            let mut q = *p;
            if let Some((w, t)) = draws.registration {
                let r = rotate(w, [0, 1, 2].map(|d| q[d] - draws.centre[d]));
                q = [0, 1, 2].map(|d| draws.centre[d] + r[d] + t[d]);
            }
            let q = q.map(|v| v + draws.sigma * rng.normal());
            // Draw always (same noise stream with and without occlusion).
            let u = rng.uniform();
            if u >= draws.drop {
                observed.push((k, q));
            }
        }
        let id = format!("c{i}");
        Ok((
            Measurement {
                id: id.clone(),
                contact: point,
                force: reported,
                radius: o.probe_radius,
                observed,
            },
            TruthMeasurement {
                id,
                true_force,
                reported_force: reported,
                markers: clean,
                support_translation: support_t,
            },
        ))
    }

    /// The boundary effect: the support yields to the contact force `c` times it, translating
    /// and turning about the bottom face's centre (the moment arm from it to the contact).
    fn support_motion(
        &self,
        c: f64,
        point: [f64; 3],
        true_force: [f64; 3],
        half: f64,
    ) -> ([f64; 3], Vec<[f64; 3]>) {
        let base_c = self.base_centre;
        let t = true_force.map(|f| c * f);
        let arm = [0, 1, 2].map(|d| point[d] - base_c[d]);
        let theta = <[f64; 3]>::from(Vector3::from(arm).cross(&Vector3::from(true_force)))
            .map(|m| c * m / (half * half));
        let disp = self
            .fixed
            .iter()
            .map(|&k| {
                let r = [0, 1, 2].map(|d| self.mesh.nodes[k][d] - base_c[d]);
                let w = Vector3::from(theta).cross(&Vector3::from(r));
                [0, 1, 2].map(|d| t[d] + w[d])
            })
            .collect();
        (t, disp)
    }
}

/// The effects' random directions and the constants of what the dataset records. Drawn even
/// when unused so the contact stream is the same for every effect set: a clean and an effected
/// specimen of one seed probe the same points.
struct EffectDraws {
    tilt_dir: [f64; 3],
    /// The registration effect's small rotation vector and translation.
    registration: Option<([f64; 3], [f64; 3])>,
    /// Half the smaller side of the top face (m).
    half: f64,
    /// The block's centre, about which the registration effect turns.
    centre: [f64; 3],
    /// The marker noise actually added (m).
    sigma: f64,
    /// The chance that a marker is occluded.
    drop: f64,
}

impl EffectDraws {
    fn draw(o: &SpecimenOptions, rng: &mut SplitMix64) -> Self {
        let size = o.size;
        let unit = |rng: &mut SplitMix64| {
            let v = Vector3::new(rng.normal(), rng.normal(), rng.normal());
            let n = v.norm().max(1e-12);
            <[f64; 3]>::from(v / n)
        };
        let reg_axis = unit(rng);
        let reg_dir = unit(rng);
        let phi = std::f64::consts::TAU * rng.uniform();
        let half = 0.5 * size[0].min(size[1]);
        Self {
            tilt_dir: [phi.cos(), phi.sin(), 0.0],
            registration: o
                .magnitude(Effect::Registration)
                .map(|m| (reg_axis.map(|a| a * m / half), reg_dir.map(|a| a * m))),
            half,
            centre: [0.5 * size[0], 0.5 * size[1], 0.5 * size[2]],
            sigma: o.noise * (1.0 + o.magnitude(Effect::Noise).unwrap_or(0.0)),
            drop: o.magnitude(Effect::Occlusion).unwrap_or(0.0),
        }
    }
}

/// Contact magnitudes spread evenly from f_max/4 to f_max, in shuffled order.
fn contact_magnitudes(o: &SpecimenOptions, rng: &mut SplitMix64) -> Vec<f64> {
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
    mags
}
