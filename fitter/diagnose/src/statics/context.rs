//! Everything fixed about a static dataset once it is prepared for the diagnosis ([`Context`]):
//! the forward problem, markers, measurements, the depth maps the layer candidate reads and where
//! the inclusion candidate starts.

use nalgebra::Vector3;
use rayon::prelude::*;
use serde::Serialize;

use super::DiagnoseError;
use palpate_fem::dataset::embed::closest_point_on_triangle;
use palpate_fem::dataset::{Marker, StaticDataset};
use palpate_fem::forward::{SolveOptions, StaticProblem};

/// One measurement as the model sees it.
#[derive(Debug, Clone)]
pub struct MeasData {
    /// Id.
    pub id: String,
    /// Contact point (m).
    pub point: [f64; 3],
    /// Reported force (N).
    pub force: [f64; 3],
    /// Probe radius (m).
    pub radius: f64,
    /// Observed markers.
    pub observed: Vec<(usize, [f64; 3])>,
}

/// The best blob of the adjoint sensitivity scan ([`super::sensitivity::scan_blobs`]): where the
/// inclusion candidate starts. Defined here, beside the context that holds it, so the model does
/// not depend on the scan that fills it (the scan depends on fits of the model).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlobScan {
    /// Centre (m).
    pub centre: [f64; 3],
    /// Radius (m).
    pub radius: f64,
    /// Gauss–Newton contrast a (log E change at the centre).
    pub contrast: f64,
    /// Predicted χ² reduction (units of σ²).
    pub reduction: f64,
}

/// Everything fixed about a dataset: forward problem, markers, measurements, reference points.
#[derive(Debug, Clone)]
pub struct Context {
    /// The forward problem on the mesh solved on (the dataset's, or it refined once).
    pub problem: StaticProblem,
    /// The same problem with its supported face on an elastic foundation
    /// ([`super::candidates::Candidate::Support`]); `None` when no boundary triangle lies on the fixed nodes.
    pub foundation: Option<StaticProblem>,
    /// Markers.
    pub markers: Vec<Marker>,
    /// Measurements.
    pub meas: Vec<MeasData>,
    /// Residual scale σ (m): the declared marker noise, or 0.1 mm.
    pub sigma: f64,
    /// Whether σ was declared by the dataset.
    pub sigma_declared: bool,
    /// The pivots and scales the effects are measured against.
    pub frame: Frame,
    /// Tangent basis perpendicular to the mean reported force.
    pub tangents: [[f64; 3]; 2],
    /// Trilinear weights of each element centroid on the inhomogeneity grid: (grid node, weight).
    pub grid_weights: Vec<Vec<(usize, f64)>>,
    /// Inhomogeneity grid size.
    pub grid: [usize; 3],
    /// Forward-solver options.
    pub solve: SolveOptions,
    /// Rest position of each marker on the model (interpolated from the mesh).
    pub marker_rest: Vec<[f64; 3]>,
    /// Element centroids (m).
    pub centroids: Vec<[f64; 3]>,
    /// The layer candidate's depth maps.
    pub layer: LayerDepth,
    /// Where the inclusion candidate starts.
    pub inclusion: InclusionStart,
    /// Node tags of the mesh solved on (for the export).
    pub node_tags: Vec<u64>,
    /// Approximation-error correction δ added to every predicted marker (per measurement, aligned
    /// with its observed markers; [`super::approx_error`]); `None` = the plain dataset-mesh model.
    pub correction: Option<Vec<Vec<[f64; 3]>>>,
}

/// The pivots and scales the effects are measured against.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Largest reported force magnitude (N), the calibration reference.
    pub f_ref: f64,
    /// Mesh bounding-box centre (registration pivot).
    pub centre: [f64; 3],
    /// Centroid of the fixed nodes (support pivot).
    pub base: [f64; 3],
    /// Half the smaller horizontal box width (m).
    pub half: f64,
    /// Gravity vector used by the gravity candidate (m/s²).
    pub gravity: [f64; 3],
    /// Lumped volume per node (m³).
    pub node_volume: Vec<f64>,
}

/// Where the layer candidate's depth is measured from.
#[derive(Debug, Clone)]
pub struct LayerDepth {
    /// Depth of each element centroid in the layer candidate's stack, as a fraction (0 at the
    /// surface the layers start from): one of [`LayerDepth::maps`], by default
    /// [`LayerAxis::Push`]'s.
    pub depth: Vec<f64>,
    /// The axis [`LayerDepth::depth`] is measured along.
    pub axis: LayerAxis,
    /// Every layer axis's depth map and the length (m) its unit fraction stands for (the
    /// sensitivity scan picks one, [`Context::set_layer_axis`]).
    pub maps: Vec<(LayerAxis, Vec<f64>, f64)>,
    /// Edge of a regular tetrahedron of the mean element volume (m): the layer scan's step width.
    pub element_size: f64,
    /// The sensitivity scan's best layer on the current axis, (Gauss–Newton log contrast,
    /// thickness as a fraction of the depth range), where the layer candidate starts (`None`:
    /// the default start, [`super::candidates::Candidate::start`]).
    pub seed: Option<[f64; 2]>,
}

impl LayerDepth {
    /// Width of the layer's edge as a fraction of the current axis' depth range: the logistic
    /// step 1 / (1 + e^{−(t − d)/w}) rises from 10 to 90 % over about one element (a quarter of
    /// the element size each side), so the field is smooth in the thickness t at the mesh's
    /// own resolution; the sensitivity scan steps with the same width.
    pub fn edge_width(&self) -> f64 {
        let range = self
            .maps
            .iter()
            .find(|(a, _, _)| *a == self.axis)
            .map_or(1.0, |(_, _, r)| *r);
        0.25 * self.element_size / range
    }

    /// The layer candidate's least thickness as a fraction of the current axis' depth range:
    /// half an element. A thinner layer only softens the surface row of elements in part, and
    /// that is what the mesh's own error under a probe looks like (an effect-free independent
    /// dome fitted one 0.02 of its depth thick, its thickness undetermined, and adopted it).
    pub fn least_thickness(&self) -> f64 {
        (2.0 * self.edge_width()).min(0.5)
    }

    /// The thickness (fraction of the depth range) of the layer candidate's parameter θ_t:
    /// t = t₀ + (1 − t₀) / (1 + e^{−θ_t}), t₀ the [least thickness](Self::least_thickness).
    pub fn thickness(&self, theta_t: f64) -> f64 {
        let least = self.least_thickness();
        least + (1.0 - least) / (1.0 + (-theta_t.clamp(-20.0, 20.0)).exp())
    }

    /// The θ_t of thickness `t` (the inverse of [`Self::thickness`]), `t` kept within 2 % of
    /// the free range from either end.
    pub fn theta_of_thickness(&self, t: f64) -> f64 {
        let least = self.least_thickness();
        let u = ((t - least) / (1.0 - least)).clamp(0.02, 0.98);
        (u / (1.0 - u)).ln()
    }
}

/// Where the inclusion candidate starts.
#[derive(Debug, Clone)]
pub struct InclusionStart {
    /// Starting centre of the inclusion candidate.
    pub centre: [f64; 3],
    /// Starting θ of the inclusion candidate from the sensitivity scan (`None`: the default
    /// start, [`super::candidates::Candidate::start`]).
    pub seed: Option<[f64; 5]>,
    /// The scan's best blob, for the report.
    pub scan: Option<BlobScan>,
}

impl Context {
    /// Measures the layer candidate's depth along `axis` from now on.
    pub fn set_layer_axis(&mut self, axis: LayerAxis) {
        if let Some((_, d, _)) = self.layer.maps.iter().find(|(a, _, _)| *a == axis) {
            self.layer.depth = d.clone();
            self.layer.axis = axis;
        }
    }

    /// Adds measurement `i`'s terms of the least-squares scale of simulated onto measured
    /// displacements (both from the markers' rest places) to `sums`: Σ u_sim·u_meas to the
    /// first, Σ u_sim·u_sim to the second. The best scale is their ratio; the callers decide what
    /// a degenerate one becomes.
    pub(crate) fn add_scale_terms(&self, i: usize, sim: &[[f64; 3]], sums: &mut (f64, f64)) {
        let (num, den) = sums;
        for (&(k, meas), p) in self.meas[i].observed.iter().zip(sim) {
            let rest = self.marker_rest[k];
            for d in 0..3 {
                let us = p[d] - rest[d];
                *num += us * (meas[d] - rest[d]);
                *den += us * us;
            }
        }
    }

    /// Prepares a dataset.
    pub fn new(ds: &StaticDataset, grid: [usize; 3]) -> Result<Self, DiagnoseError> {
        if ds.measurements.len() < 2 {
            return Err(DiagnoseError::Input(format!(
                "dataset {:?} has {} measurements; diagnosis needs at least 2 (one is held out)",
                ds.name,
                ds.measurements.len()
            )));
        }
        if grid.contains(&0) {
            return Err(DiagnoseError::Input(
                "inhomogeneity grid needs ≥ 1 node per axis".into(),
            ));
        }
        let problem = StaticProblem::new(&ds.mesh, &ds.fixed_nodes, &ds.surface)?;
        let foundation = match StaticProblem::on_foundation(&ds.mesh, &ds.fixed_nodes, &ds.surface)
        {
            Ok(p) => Some(p),
            Err(palpate_fem::forward::ForwardError::NoFoundationFace) => None,
            Err(e) => return Err(e.into()),
        };
        let (meas, f_ref) = measurements(ds)?;
        let (lo, hi) = ds.mesh.bounds();
        let centre = [0, 1, 2].map(|d| 0.5 * (lo[d] + hi[d]));
        let base = fixed_centroid(ds);
        let half = 0.5 * (hi[0] - lo[0]).min(hi[1] - lo[1]).max(1e-9);
        let [nz, t1, t2] = frame_along(mean_direction(&meas), 1e-9);
        let gravity = ds.gravity.unwrap_or([0.0, 0.0, -9.81]);
        let node_volume = node_volumes(ds, &problem);
        let centroids = palpate_static_fit::blend::centroids(&problem);
        let grid_weights = centroids
            .iter()
            .map(|&c| trilinear(c, lo, hi, grid))
            .collect();
        let (depth_maps, top, span) = layer_depth_maps(ds, &centroids, nz, gravity);
        let depth = depth_maps[0].1.clone();
        let mean_volume = problem.geometry.iter().map(|g| g.volume).sum::<f64>()
            / problem.geometry.len().max(1) as f64;
        let element_size = (6.0 * 2f64.sqrt() * mean_volume).cbrt();
        let inclusion_start = inclusion_start(&meas, nz, top, span);
        let marker_rest = ds
            .markers
            .iter()
            .map(|m| m.interpolate(|n| ds.mesh.nodes[n]))
            .collect();
        Ok(Self {
            problem,
            foundation,
            markers: ds.markers.clone(),
            meas,
            sigma: ds.marker_noise.unwrap_or(1e-4),
            sigma_declared: ds.marker_noise.is_some(),
            frame: Frame {
                f_ref,
                centre,
                base,
                half,
                gravity,
                node_volume,
            },
            tangents: [t1, t2],
            grid_weights,
            grid,
            solve: SolveOptions {
                increments: 3,
                warp: true,
                tolerance: 1e-9,
                max_fixed_point: 40,
                reuse_factor: true,
            },
            marker_rest,
            centroids,
            layer: LayerDepth {
                depth,
                axis: LayerAxis::Push,
                maps: depth_maps,
                element_size,
                seed: None,
            },
            inclusion: InclusionStart {
                centre: inclusion_start,
                seed: None,
                scan: None,
            },
            node_tags: ds.mesh.node_tags.clone(),
            correction: None,
        })
    }

    /// Number of residual entries of the measurements `subset`.
    pub fn residual_len(&self, subset: &[usize]) -> usize {
        subset
            .iter()
            .map(|&i| 3 * self.meas[i].observed.len())
            .sum()
    }
}

/// Centroid of the fixed nodes (the compliant support's pivot).
fn fixed_centroid(ds: &StaticDataset) -> [f64; 3] {
    let mut base = [0.0; 3];
    for &n in &ds.fixed_nodes {
        for d in 0..3 {
            base[d] += ds.mesh.nodes[n][d] / ds.fixed_nodes.len() as f64;
        }
    }
    base
}

/// The sum of the measurements' unit reported force directions (the mean pushing direction,
/// unnormalised).
fn mean_direction(meas: &[MeasData]) -> Vector3<f64> {
    let mut mean = [0.0; 3];
    for m in meas {
        let n = Vector3::from(m.force).norm().max(1e-300);
        for d in 0..3 {
            mean[d] += m.force[d] / n;
        }
    }
    Vector3::from(mean)
}

/// Lumped volume per node (m³): a quarter of each tetrahedron's on each of its nodes.
fn node_volumes(ds: &StaticDataset, problem: &StaticProblem) -> Vec<f64> {
    let mut node_volume = vec![0.0; ds.mesh.nodes.len()];
    for (t, g) in ds.mesh.tets.iter().zip(&problem.geometry) {
        for &n in t {
            node_volume[n] += 0.25 * g.volume;
        }
    }
    node_volume
}

/// Every layer axis's depth map of the element `centroids` with the length its unit fraction
/// stands for, [`LayerAxis::Push`]'s first; and the push axis's probed face `top` and `span`
/// along the mean pushing direction `nz` (from the probed face: smallest x·nz).
fn layer_depth_maps(
    ds: &StaticDataset,
    centroids: &[[f64; 3]],
    nz: [f64; 3],
    gravity: [f64; 3],
) -> (Vec<(LayerAxis, Vec<f64>, f64)>, f64, f64) {
    let along = |x: &[f64; 3]| x[0] * nz[0] + x[1] * nz[1] + x[2] * nz[2];
    let (top, bottom) = extent_along(&ds.mesh, nz);
    let span = (bottom - top).max(1e-12);
    let depth: Vec<f64> = centroids.iter().map(|c| (along(c) - top) / span).collect();
    let (vertical, vertical_span) = vertical_depth(&ds.mesh, centroids, gravity);
    let (skin, skin_span) = skin_depth(&ds.mesh, &ds.fixed_nodes, centroids);
    let maps = vec![
        (LayerAxis::Push, depth, span),
        (LayerAxis::Vertical, vertical, vertical_span),
        (LayerAxis::Skin, skin, skin_span),
    ];
    (maps, top, span)
}

/// The inclusion candidate's starting centre: below the mean contact point at a quarter of the
/// depth `span` along `nz` from the probed face `top`.
fn inclusion_start(meas: &[MeasData], nz: [f64; 3], top: f64, span: f64) -> [f64; 3] {
    let along = |x: &[f64; 3]| x[0] * nz[0] + x[1] * nz[1] + x[2] * nz[2];
    let mut contact_mean = [0.0; 3];
    for m in meas {
        for d in 0..3 {
            contact_mean[d] += m.point[d] / meas.len() as f64;
        }
    }
    let shift = 0.25 * span - (along(&contact_mean) - top);
    [0, 1, 2].map(|d| contact_mean[d] + shift * nz[d])
}

/// The dataset's measurements as the diagnosis reads them, and the largest force (N), the
/// reference the load-dependent candidates scale by; a measurement without an observed marker
/// or a dataset whose every force is zero cannot be diagnosed.
fn measurements(ds: &StaticDataset) -> Result<(Vec<MeasData>, f64), DiagnoseError> {
    let meas: Vec<MeasData> = ds
        .measurements
        .iter()
        .map(|m| MeasData {
            id: m.id.clone(),
            point: m.contact,
            force: m.force,
            radius: m.radius,
            observed: m.observed.clone(),
        })
        .collect();
    for m in &meas {
        if m.observed.is_empty() {
            return Err(DiagnoseError::Input(format!(
                "measurement {:?} has no observed marker",
                m.id
            )));
        }
    }
    let f_ref = meas
        .iter()
        .map(|m| Vector3::from(m.force).norm())
        .fold(0.0, f64::max);
    if f_ref <= 0.0 {
        return Err(DiagnoseError::Input("every reported force is zero".into()));
    }
    Ok((meas, f_ref))
}

/// Trilinear weights of point `c` on a grid of `g` nodes spanning [lo, hi].
fn trilinear(c: [f64; 3], lo: [f64; 3], hi: [f64; 3], g: [usize; 3]) -> Vec<(usize, f64)> {
    let mut axis = [(0usize, 0usize, 1.0f64); 3];
    for d in 0..3 {
        if g[d] == 1 {
            axis[d] = (0, 0, 1.0);
            continue;
        }
        let t = ((c[d] - lo[d]) / (hi[d] - lo[d]).max(1e-300)).clamp(0.0, 1.0) * (g[d] - 1) as f64;
        let i = (t.floor() as usize).min(g[d] - 2);
        axis[d] = (i, i + 1, 1.0 - (t - i as f64));
    }
    let mut out = Vec::with_capacity(8);
    for corner in 0..8 {
        let mut idx = [0usize; 3];
        let mut w = 1.0;
        for d in 0..3 {
            let hi_side = corner >> d & 1 == 1;
            idx[d] = if hi_side { axis[d].1 } else { axis[d].0 };
            w *= if hi_side { 1.0 - axis[d].2 } else { axis[d].2 };
        }
        if w > 0.0 {
            out.push(((idx[2] * g[1] + idx[1]) * g[0] + idx[0], w));
        }
    }
    out
}

/// The direction a layered body's layers are stacked along: which surface the layer candidate's
/// depth is measured from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum LayerAxis {
    /// Along the mean pushing direction, from the plane through the first surface point it meets:
    /// layers parallel to a flat probed face.
    Push,
    /// Along gravity (declared, else −z), from the surface above each point: a top layer that
    /// follows a curved top, whatever side the probes push on.
    Vertical,
    /// The distance to the nearest free boundary face: a skin all round the body.
    Skin,
}

impl LayerAxis {
    /// Name (as in reports).
    pub fn name(self) -> &'static str {
        match self {
            LayerAxis::Push => "along the mean pushing direction",
            LayerAxis::Vertical => "below the top surface (along gravity)",
            LayerAxis::Skin => "below the nearest free surface (a skin)",
        }
    }
}

/// The unit vector along `v` (−z when |v| ≤ `tiny`) and two unit vectors across it: the frame
/// depths are measured in.
fn frame_along(v: Vector3<f64>, tiny: f64) -> [[f64; 3]; 3] {
    let n = if v.norm() > tiny {
        v / v.norm()
    } else {
        Vector3::new(0.0, 0.0, -1.0)
    };
    let helper = if n[0].abs() < 0.9 {
        Vector3::new(1.0, 0.0, 0.0)
    } else {
        Vector3::new(0.0, 1.0, 0.0)
    };
    let t1 = n.cross(&helper);
    let t1 = t1 / t1.norm();
    let t2 = n.cross(&t1);
    [n.into(), t1.into(), t2.into()]
}

/// The smallest and largest x · `dir` over the mesh's nodes.
fn extent_along(mesh: &palpate_fem::mesh::Mesh, dir: [f64; 3]) -> (f64, f64) {
    mesh.nodes
        .iter()
        .map(|x| x[0] * dir[0] + x[1] * dir[1] + x[2] * dir[2])
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), d| {
            (lo.min(d), hi.max(d))
        })
}

/// Depth of `points` below the surface above them along `gravity`, as a fraction of the body's
/// vertical extent ([`surface_depth`]), and that extent (m).
fn vertical_depth(
    mesh: &palpate_fem::mesh::Mesh,
    points: &[[f64; 3]],
    gravity: [f64; 3],
) -> (Vec<f64>, f64) {
    let frame = frame_along(Vector3::from(gravity), 0.0);
    let (top, bottom) = extent_along(mesh, frame[0]);
    let span = (bottom - top).max(1e-12);
    (surface_depth(mesh, points, frame, top, span), span)
}

/// Distance of `points` to the nearest boundary triangle with a node off `fixed` (the free
/// surface), as a fraction of the largest such distance, and that distance (m).
fn skin_depth(
    mesh: &palpate_fem::mesh::Mesh,
    fixed: &[usize],
    points: &[[f64; 3]],
) -> (Vec<f64>, f64) {
    let is_fixed = {
        let mut v = vec![false; mesh.nodes.len()];
        for &n in fixed {
            v[n] = true;
        }
        v
    };
    let tris: Vec<[[f64; 3]; 3]> = mesh
        .boundary_triangles()
        .into_iter()
        .filter(|t| t.iter().any(|&n| !is_fixed[n]))
        .map(|t| t.map(|n| mesh.nodes[n]))
        .collect();
    let d: Vec<f64> = points
        .par_iter()
        .map(|p| {
            tris.iter()
                .map(|t| point_triangle_distance(*p, t))
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    let max = d.iter().copied().fold(0.0, f64::max).max(1e-12);
    (
        d.into_iter()
            .map(|v| if v.is_finite() { v / max } else { 1.0 })
            .collect(),
        max,
    )
}

/// Euclidean distance from `p` to the triangle `t`, by the marker embedding's closest point.
fn point_triangle_distance(p: [f64; 3], t: &[[f64; 3]; 3]) -> f64 {
    let (_, q) = closest_point_on_triangle(p, t[0], t[1], t[2]);
    (Vector3::from(p) - Vector3::from(q)).norm()
}

/// Depth of each of `points` below the probed surface along `frame[0]` (the mean pushing
/// direction nz; `frame[1..]` span the plane across it), as a fraction of `span`: the distance
/// along nz up to the nearest boundary triangle above the point that faces the probe (outward
/// normal against nz), so a layer under a curved top follows it; where no such triangle is above
/// a point, its depth below the plane through the top-most node (`top` = the smallest x·nz).
fn surface_depth(
    mesh: &palpate_fem::mesh::Mesh,
    points: &[[f64; 3]],
    frame: [[f64; 3]; 3],
    top: f64,
    span: f64,
) -> Vec<f64> {
    let dot = |a: &[f64; 3], b: &[f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let [nz, t1, t2] = frame;
    // Facing triangles in (u, v, along) coordinates with their (u, v) bounding boxes.
    let facing: Vec<([[f64; 3]; 3], [f64; 4])> = mesh
        .boundary_triangles()
        .into_iter()
        .filter_map(|t| {
            let p = t.map(|n| mesh.nodes[n]);
            let e1 = Vector3::from(p[1]) - Vector3::from(p[0]);
            let e2 = Vector3::from(p[2]) - Vector3::from(p[0]);
            let normal = e1.cross(&e2);
            let area2 = normal.norm();
            if area2 <= 0.0 || normal.dot(&Vector3::from(nz)) > -0.1 * area2 {
                return None;
            }
            let q = p.map(|x| [dot(&x, &t1), dot(&x, &t2), dot(&x, &nz)]);
            let bbox = [
                q.iter().map(|x| x[0]).fold(f64::INFINITY, f64::min),
                q.iter().map(|x| x[0]).fold(f64::NEG_INFINITY, f64::max),
                q.iter().map(|x| x[1]).fold(f64::INFINITY, f64::min),
                q.iter().map(|x| x[1]).fold(f64::NEG_INFINITY, f64::max),
            ];
            Some((q, bbox))
        })
        .collect();
    points
        .par_iter()
        .map(|c| {
            let (u, v, a) = (dot(c, &t1), dot(c, &t2), dot(c, &nz));
            let mut best = f64::INFINITY;
            for (q, b) in &facing {
                if u < b[0] || u > b[1] || v < b[2] || v > b[3] {
                    continue;
                }
                // Barycentric coordinates of (u, v) in the projected triangle.
                let det = (q[1][0] - q[0][0]) * (q[2][1] - q[0][1])
                    - (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]);
                if det.abs() < 1e-300 {
                    continue;
                }
                let l1 = ((u - q[0][0]) * (q[2][1] - q[0][1])
                    - (q[2][0] - q[0][0]) * (v - q[0][1]))
                    / det;
                let l2 = ((q[1][0] - q[0][0]) * (v - q[0][1])
                    - (u - q[0][0]) * (q[1][1] - q[0][1]))
                    / det;
                let l0 = 1.0 - l1 - l2;
                let eps = -1e-9;
                if l0 < eps || l1 < eps || l2 < eps {
                    continue;
                }
                let hit = l0 * q[0][2] + l1 * q[1][2] + l2 * q[2][2];
                let below = a - hit;
                if below >= -1e-9 * span && below < best {
                    best = below;
                }
            }
            if best.is_finite() {
                best.max(0.0) / span
            } else {
                (a - top) / span
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_fem::mesh::boxmesh::box_mesh;

    fn centroids(m: &palpate_fem::mesh::Mesh) -> Vec<[f64; 3]> {
        m.tets
            .iter()
            .map(|t| [0, 1, 2].map(|d| t.iter().map(|&n| m.nodes[n][d]).sum::<f64>() / 4.0))
            .collect()
    }

    /// The closed form against the nearest of 20,301 points spread over the triangle.
    #[test]
    fn point_triangle_distance_matches_a_dense_sampling() {
        let t = [[0.0, 0.0, 0.0], [1.0, 0.2, 0.1], [0.3, 0.9, -0.2]];
        let tv = t.map(Vector3::from);
        let mut rng = palpate_fem::rng::study_stream(3);
        for _ in 0..200 {
            let p = Vector3::new(
                3.0 * rng.uniform() - 1.0,
                3.0 * rng.uniform() - 1.0,
                2.0 * rng.uniform() - 1.0,
            );
            let n = 200;
            let mut brute = f64::INFINITY;
            for i in 0..=n {
                for j in 0..=n - i {
                    let (u, v) = (i as f64 / n as f64, j as f64 / n as f64);
                    let q = tv[0] + (tv[1] - tv[0]) * u + (tv[2] - tv[0]) * v;
                    brute = brute.min((p - q).norm());
                }
            }
            let d = point_triangle_distance(p.into(), &t);
            // The sampling's spacing is ≈ 0.005: it can only overestimate, by at most that.
            assert!(
                d <= brute + 1e-12 && brute - d < 6e-3,
                "{d} vs {brute} at {p:?}"
            );
        }
    }

    /// A slab sheared so its top and bottom slope (z' = z + 0.3 x): the depth below the top
    /// surface along gravity is H − z exactly, while the plane through the highest node would
    /// give (z'_max − z') — wrong by 0.3 (L − x) everywhere but the high edge.
    #[test]
    fn vertical_depth_follows_a_sloping_top() {
        let (l, h) = (0.08, 0.03);
        let mut m = box_mesh([l, 0.06, h], [8, 6, 3]);
        let before = centroids(&m);
        for p in &mut m.nodes {
            p[2] += 0.3 * p[0];
        }
        let c = centroids(&m);
        let (d, span) = vertical_depth(&m, &c, [0.0, 0.0, -9.81]);
        assert!((span - (h + 0.3 * l)).abs() < 1e-12, "{span}");
        for (e, (&got, b)) in d.iter().zip(&before).enumerate() {
            let want = (h - b[2]) / span;
            assert!((got - want).abs() < 1e-9, "element {e}: {got} vs {want}");
        }
    }

    /// A block fixed at its bottom: the skin depth is the distance to the top or the nearest side.
    #[test]
    fn skin_depth_is_the_distance_to_the_free_surface() {
        let (a, b, h) = (0.08, 0.06, 0.04);
        let m = box_mesh([a, b, h], [8, 6, 4]);
        let fixed = m.node_groups["bottom"].clone();
        let c = centroids(&m);
        let (d, max) = skin_depth(&m, &fixed, &c);
        let want: Vec<f64> = c
            .iter()
            .map(|p| (h - p[2]).min(p[0]).min(a - p[0]).min(p[1]).min(b - p[1]))
            .collect();
        let wmax = want.iter().copied().fold(0.0, f64::max);
        assert!((max - wmax).abs() < 1e-12, "{max} vs {wmax}");
        for (got, w) in d.iter().zip(&want) {
            assert!((got - w / wmax).abs() < 1e-9, "{got} vs {}", w / wmax);
        }
    }
}
