//! A scan registered to a surface by a rigid motion: robust point-to-plane ICP (Chen and
//! Medioni's, linearised in a small rotation), to bring a scan whose camera pose is known only
//! roughly into the mesh's frame.
//!
//! - **Target**: the surface whose place is known in the scan's state — the rest mesh's whole
//!   surface for a scan of the object at rest; for a loaded state, the part that does not move
//!   with the material: the surface within a band of the clamped nodes at rest and of the held
//!   nodes moved with their grip ([`fixed_part_surface`]).
//! - **Residual**: each point's signed distance dᵢ = n·(T pᵢ − qᵢ) to its closest point qᵢ
//!   ([`crate::surface`]), over its noise σᵢ. A small motion δ = (ω, v) about the matched
//!   points' centroid c moves T pᵢ = yᵢ by ω × (yᵢ − c) + v, so ∂dᵢ/∂δ = ((yᵢ − c) × n, n).
//! - **Weights**: Tukey's biweight at 4 robust scales (1.4826 × the median |dᵢ/σᵢ|, never
//!   below 1), as the scan residual's; points with no surface within the search radius (the
//!   background, the moving part of the object) are trimmed, and so are points whose closest
//!   point lies on the target's open border (past the band's end: Turk and Levoy's rule) or
//!   off its triangle's edge by more than 3σ (a clamp's face beside the object), which
//!   point-to-plane would otherwise pull along.
//! - **Directions the target does not pin**: a prism's side faces do not say where along its
//!   axis the scan sits. The Gauss–Newton matrix is solved in its eigenbasis, rotations scaled
//!   by the matched points' RMS radius; directions whose eigenvalue is below [`PINNED`] of the
//!   largest are left as declared, and counted in [`Registration::pinned`].
//! - **Done** when a step moves no matched point by more than 1 µm (far below a depth camera's
//!   noise), or when a step undoes the one before (a point's match flipping at each iteration):
//!   then half of it is taken, the pose between the two; or, past 30 iterations, when a step
//!   moves no point by more than a twentieth of the scan's median noise (a longer cycle of
//!   switching matches); otherwise an error after the iterations allowed.

use std::collections::{HashMap, HashSet};

use nalgebra::{Matrix3, Matrix6, Rotation3, SymmetricEigen, Vector3, Vector6};
use palpate_fem::mesh::Mesh;

use crate::fit::ScanPoints;
use crate::surface::{RobustLoss, SurfaceGrid};
use crate::ScanError;

/// Tukey's window, in robust scales of the residuals.
const TUKEY: f64 = 4.0;
/// A direction of the scaled Gauss–Newton matrix with an eigenvalue below this fraction of the
/// largest is not pinned by the target and is left as declared.
pub const PINNED: f64 = 1e-2;
/// A step that moves no matched point by more than this (m) ends the iterations.
const SETTLED_M: f64 = 1e-6;

/// A rigid motion x ↦ R x + t.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidTransform {
    /// The rotation R.
    pub rotation: Matrix3<f64>,
    /// The translation t (m).
    pub translation: Vector3<f64>,
}

impl RigidTransform {
    /// No motion.
    pub fn identity() -> Self {
        Self {
            rotation: Matrix3::identity(),
            translation: Vector3::zeros(),
        }
    }

    /// The rotation by `angle` (rad) about the unit-less `axis` through `about`, then `shift`.
    pub fn about(axis: Vector3<f64>, angle: f64, about: Vector3<f64>, shift: Vector3<f64>) -> Self {
        let r = if angle == 0.0 || axis.norm() == 0.0 {
            Matrix3::identity()
        } else {
            Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle).into_inner()
        };
        Self {
            rotation: r,
            translation: about - r * about + shift,
        }
    }

    /// Where the motion takes `p`.
    pub fn apply(&self, p: Vector3<f64>) -> Vector3<f64> {
        self.rotation * p + self.translation
    }

    /// `self` after `first`: x ↦ self(first(x)).
    pub fn after(&self, first: &Self) -> Self {
        Self {
            rotation: self.rotation * first.rotation,
            translation: self.rotation * first.translation + self.translation,
        }
    }

    /// The inverse motion.
    pub fn inverse(&self) -> Self {
        let rt = self.rotation.transpose();
        Self {
            rotation: rt,
            translation: -(rt * self.translation),
        }
    }

    /// The rotation's angle (degrees).
    pub fn angle_deg(&self) -> f64 {
        Rotation3::from_matrix_unchecked(self.rotation)
            .angle()
            .to_degrees()
    }

    /// The largest distance the motion moves a point of `points` (m).
    pub fn largest_move(&self, points: &[Vector3<f64>]) -> f64 {
        points
            .iter()
            .map(|p| (self.apply(*p) - p).norm())
            .fold(0.0, f64::max)
    }

    /// `scan` moved by the motion, its camera with it (so that each point's noise keeps its
    /// direction along the camera's ray).
    pub fn move_scan(&self, scan: &ScanPoints) -> ScanPoints {
        ScanPoints {
            points: scan.points.iter().map(|p| self.apply(*p)).collect(),
            sigma: scan.sigma.clone(),
            camera: scan.camera.map(|mut c| {
                c.pose.rotation = self.rotation * c.pose.rotation;
                c.pose.translation = self.apply(c.pose.translation);
                c
            }),
        }
    }
}

/// How a registration searches.
#[derive(Debug, Clone, Copy)]
pub struct RegistrationSettings {
    /// A point farther than this from the target (m) has no correspondence.
    pub max_distance: f64,
    /// ICP iterations at most.
    pub max_iter: usize,
    /// Points with a weight needed at least.
    pub min_points: usize,
    /// The largest rotation accepted (degrees): a declared pose is off by a few degrees, and a
    /// registration that turns the scan further has paired the wrong faces.
    pub max_angle_deg: f64,
}

impl Default for RegistrationSettings {
    fn default() -> Self {
        Self {
            max_distance: 0.01,
            max_iter: 200,
            min_points: 50,
            max_angle_deg: 10.0,
        }
    }
}

/// A scan registered to a target surface.
#[derive(Debug, Clone, Copy)]
pub struct Registration {
    /// The motion that carries the scan onto the target.
    pub transform: RigidTransform,
    /// RMS signed distance of the points with a weight, after the motion (m).
    pub rms_m: f64,
    /// Points with a weight at the end.
    pub used: usize,
    /// Points in the scan.
    pub points: usize,
    /// ICP iterations.
    pub iterations: usize,
    /// Directions (of 6) the target pins.
    pub pinned: usize,
}

/// Registers `scan` onto the surface `triangles` over `nodes` (module doc). `what` names the
/// scan in errors (its folder).
pub fn register(
    scan: &ScanPoints,
    nodes: &[[f64; 3]],
    triangles: &[[usize; 3]],
    settings: &RegistrationSettings,
    what: &str,
) -> Result<Registration, ScanError> {
    let n = scan.points.len();
    let grid = SurfaceGrid::new(nodes, triangles, settings.max_distance.max(1e-6));
    let open = open_edges(triangles);
    let mut t = RigidTransform::identity();
    let mut last = (0, f64::NAN, 6);
    let mut previous: Option<Vector6<f64>> = None;
    let median_sigma = {
        let mut s = scan.sigma.clone();
        s.sort_by(f64::total_cmp);
        s.get(s.len() / 2).copied().unwrap_or(0.0)
    };
    for it in 1..=settings.max_iter {
        let moved: Vec<Vector3<f64>> = scan.points.iter().map(|p| t.apply(*p)).collect();
        let found: Vec<(usize, Vector3<f64>, f64)> = moved
            .iter()
            .enumerate()
            .filter_map(|(i, y)| {
                let c = grid.closest(*y, settings.max_distance)?;
                if on_open_edge(&c.triangle, &c.barycentric, &open) {
                    return None;
                }
                // A point off its closest triangle's edge by more than its noise (a clamp's
                // face beside the object) is not on the target.
                let q: Vector3<f64> = (0..3)
                    .map(|k| c.barycentric[k] * Vector3::from(nodes[c.triangle[k]]))
                    .sum();
                let off = ((y - q).norm_squared() - c.distance * c.distance).max(0.0);
                let s = 3.0 * scan.sigma[i].max(1e-9);
                (off <= s * s).then_some((i, c.normal, c.distance))
            })
            .collect();
        let mut abs: Vec<f64> = found
            .iter()
            .map(|(i, _, d)| (d / scan.sigma[*i].max(1e-9)).abs())
            .collect();
        abs.sort_by(f64::total_cmp);
        let scale = (1.4826 * abs.get(abs.len() / 2).copied().unwrap_or(1.0)).max(1.0);
        let weighted: Vec<(usize, Vector3<f64>, f64, f64)> = found
            .iter()
            .map(|&(i, nrm, d)| {
                let s = scan.sigma[i].max(1e-9);
                (
                    i,
                    nrm,
                    d,
                    RobustLoss::Tukey(TUKEY).weight(d / s / scale) / (s * s),
                )
            })
            .filter(|x| x.3 > 0.0)
            .collect();
        let used = weighted.len();
        let rms = (weighted.iter().map(|x| x.2 * x.2).sum::<f64>() / used.max(1) as f64).sqrt();
        if used < settings.min_points {
            return Err(ScanError::Invalid(format!(
                "registering {what}: {used} of {n} points lie within {:.1} mm of the target surface ({} triangles), expected at least {}: the scan does not see that part, or its declared pose is farther off than the search radius",
                1e3 * settings.max_distance,
                triangles.len(),
                settings.min_points
            )));
        }
        let wsum: f64 = weighted.iter().map(|x| x.3).sum();
        let c: Vector3<f64> = weighted
            .iter()
            .map(|x| moved[x.0] * x.3)
            .sum::<Vector3<f64>>()
            / wsum;
        let radius = (weighted
            .iter()
            .map(|x| x.3 * (moved[x.0] - c).norm_squared())
            .sum::<f64>()
            / wsum)
            .sqrt()
            .max(1e-6);
        // Rotations scaled by the radius: each column of J in metres.
        let mut h = Matrix6::<f64>::zeros();
        let mut g = Vector6::<f64>::zeros();
        for &(i, nrm, d, w) in &weighted {
            let arm = (moved[i] - c).cross(&nrm) / radius;
            let j = Vector6::new(arm.x, arm.y, arm.z, nrm.x, nrm.y, nrm.z);
            h += j * j.transpose() * w;
            g += j * (w * d);
        }
        let eig = SymmetricEigen::new(h);
        let top = eig.eigenvalues.amax();
        let mut step = Vector6::zeros();
        let mut pinned = 0;
        for k in 0..6 {
            let l = eig.eigenvalues[k];
            if l > PINNED * top && top > 0.0 {
                let u = eig.eigenvectors.column(k);
                step -= u * (u.dot(&g) / l);
                pinned += 1;
            }
        }
        // A step moves a point by at most a quarter of the search radius: far from the fit
        // the correspondences are wrong, and a full step on them can leave the target.
        let reach = step.norm() * 3f64.sqrt();
        if reach > 0.25 * settings.max_distance {
            step *= 0.25 * settings.max_distance / reach;
        }
        // A point whose match or weight flips at each iteration makes the steps alternate
        // between two poses: the pose between them is taken, and the iterations end.
        let cycling = previous.is_some_and(|p: Vector6<f64>| (step + p).norm() < 0.1 * step.norm());
        if cycling {
            step *= 0.5;
        }
        previous = Some(step);
        let omega = Vector3::new(step[0], step[1], step[2]) / radius;
        let v = Vector3::new(step[3], step[4], step[5]);
        let dt = RigidTransform::about(omega, omega.norm(), c, v);
        t = dt.after(&t);
        last = (used, rms, pinned);
        let moves = omega.norm() * 3.0 * radius + v.norm();
        log::debug!(
            "registering {what}, iteration {it}: {used} points, RMS {:.3} mm, step {:.2e} m, {pinned} directions pinned",
            1e3 * rms,
            moves
        );
        // Past 30 iterations, points switching between triangles can keep the pose wobbling
        // in a longer cycle; a wobble under a twentieth of the noise is settled.
        let wobble = it >= 30 && moves < 0.05 * median_sigma;
        if moves < SETTLED_M || cycling || wobble {
            if t.angle_deg() > settings.max_angle_deg {
                return Err(ScanError::Invalid(format!(
                    "registering {what}: ICP settled with the scan turned by {:.1}°, more than the {}° a declared pose may be off ({used} of {n} points used, {pinned} of 6 directions pinned): the target does not hold the scan; declare the pose more closely or widen the target",
                    t.angle_deg(),
                    settings.max_angle_deg
                )));
            }
            return Ok(Registration {
                transform: t,
                rms_m: rms,
                used,
                points: n,
                iterations: it,
                pinned,
            });
        }
    }
    Err(ScanError::Invalid(format!(
        "registering {what}: ICP did not settle in {} iterations ({} of {n} points used, RMS {:.3} mm, {} directions pinned)",
        settings.max_iter,
        last.0,
        1e3 * last.1,
        last.2
    )))
}

/// The border of a surface: the edges only one of its triangles has, and their ends.
struct Border {
    edges: HashSet<(usize, usize)>,
    vertices: HashSet<usize>,
}

/// The border of `triangles` (empty for a closed surface).
fn open_edges(triangles: &[[usize; 3]]) -> Border {
    let mut count: HashMap<(usize, usize), usize> = HashMap::new();
    for t in triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *count.entry((a.min(b), a.max(b))).or_insert(0) += 1;
        }
    }
    let edges: HashSet<(usize, usize)> = count
        .into_iter()
        .filter(|(_, c)| *c == 1)
        .map(|(e, _)| e)
        .collect();
    let vertices = edges.iter().flat_map(|&(a, b)| [a, b]).collect();
    Border { edges, vertices }
}

/// Whether a closest point (`barycentric` on `triangle`) lies on an open edge or one of its
/// ends: a point matched there lies beyond the target's border.
fn on_open_edge(triangle: &[usize; 3], barycentric: &[f64; 3], open: &Border) -> bool {
    if open.edges.is_empty() {
        return false;
    }
    let edge = |a: usize, b: usize| open.edges.contains(&(a.min(b), a.max(b)));
    let zeros: Vec<usize> = (0..3).filter(|&k| barycentric[k] == 0.0).collect();
    match zeros[..] {
        [k] => edge(triangle[(k + 1) % 3], triangle[(k + 2) % 3]),
        [_, _] => {
            let v = triangle[(0..3).find(|k| barycentric[*k] != 0.0).unwrap_or(0)];
            open.vertices.contains(&v)
        }
        _ => false,
    }
}

/// The surface of `mesh` that does not move with the material in a state: its boundary
/// triangles whose three nodes each lie within `band` (m) of a fixed node, each such node
/// placed as its nearest fixed node's group moves it — `motion(k, x)` takes rest point x with
/// the k-th fixed node's group (at rest for a clamp, the grip's rigid motion for a held group).
/// Returns the nodes (every mesh node; those outside the band at rest, unused) and the
/// triangles.
pub fn fixed_part_surface(
    mesh: &Mesh,
    fixed: &[usize],
    band: f64,
    motion: impl Fn(usize, [f64; 3]) -> [f64; 3],
) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
    let mut nodes = mesh.nodes.clone();
    let mut inside = vec![false; nodes.len()];
    for (n, x) in mesh.nodes.iter().enumerate() {
        let p = Vector3::from(*x);
        let nearest = fixed
            .iter()
            .enumerate()
            .map(|(k, &f)| (k, (Vector3::from(mesh.nodes[f]) - p).norm()))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((k, d)) = nearest {
            if d <= band {
                inside[n] = true;
                nodes[n] = motion(k, *x);
            }
        }
    }
    let triangles = mesh
        .boundary_triangles()
        .into_iter()
        .filter(|t| t.iter().all(|&n| inside[n]))
        .collect();
    (nodes, triangles)
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_fem::mesh::boxmesh::box_mesh;
    use palpate_fem::rng::SplitMix64;

    /// Points spread over every face of a box, with noise along z.
    fn box_points(mesh: &Mesh, rng: &mut SplitMix64, sigma: f64) -> Vec<Vector3<f64>> {
        let tris = mesh.boundary_triangles();
        (0..3000)
            .map(|k| {
                let t = tris[k % tris.len()];
                let (a, b) = (rng.uniform(), rng.uniform());
                let (a, b) = if a + b > 1.0 {
                    (1.0 - a, 1.0 - b)
                } else {
                    (a, b)
                };
                let [p, q, r] = t.map(|n| Vector3::from(mesh.nodes[n]));
                p + (q - p) * a + (r - p) * b + Vector3::new(0.0, 0.0, sigma * rng.normal())
            })
            .collect()
    }

    /// A box's surface points moved by 3° and 4 mm are brought back: the motion found is the
    /// inverse of the one applied to within 0.05° and 0.05 mm (σ 0.1 mm, 3,000 points), and
    /// the RMS is the noise's.
    #[test]
    fn icp_undoes_a_rigid_motion() {
        let mesh = box_mesh([0.08, 0.04, 0.03], [4, 2, 2]);
        let mut rng = SplitMix64::new(4);
        let truth = box_points(&mesh, &mut rng, 1e-4);
        let off = RigidTransform::about(
            Vector3::new(0.3, -1.0, 0.5),
            3f64.to_radians(),
            Vector3::new(0.04, 0.02, 0.015),
            Vector3::new(0.003, -0.002, 0.0025),
        );
        let scan = ScanPoints {
            points: truth.iter().map(|p| off.apply(*p)).collect(),
            sigma: vec![1e-4; truth.len()],
            camera: None,
        };
        let r = register(
            &scan,
            &mesh.nodes,
            &mesh.boundary_triangles(),
            &RegistrationSettings::default(),
            "box",
        )
        .unwrap();
        let left = r.transform.after(&off);
        assert!(left.angle_deg() < 0.05, "{} deg left", left.angle_deg());
        assert!(
            left.largest_move(&truth) < 5e-5,
            "{} m left",
            left.largest_move(&truth)
        );
        assert_eq!(r.pinned, 6);
        assert!(r.rms_m < 1.3e-4 && r.used > 2900, "{r:?}");
    }

    /// Two faces of a box (a prism's sides) do not pin the motion along their common edge: that
    /// direction is left as it was, the other five are found.
    #[test]
    fn a_direction_the_target_does_not_pin_is_left_alone() {
        let mesh = box_mesh([0.08, 0.04, 0.03], [4, 2, 2]);
        let tris: Vec<[usize; 3]> = mesh
            .boundary_triangles()
            .into_iter()
            .filter(|t| {
                let on = |k: usize, v: f64| t.iter().all(|&n| (mesh.nodes[n][k] - v).abs() < 1e-12);
                on(1, 0.0) || on(2, 0.03)
            })
            .collect();
        let mut rng = SplitMix64::new(8);
        let truth: Vec<Vector3<f64>> = (0..2000)
            .map(|k| {
                let x = 0.08 * rng.uniform();
                if k % 2 == 0 {
                    Vector3::new(x, 0.0, 0.03 * rng.uniform())
                } else {
                    Vector3::new(x, 0.04 * rng.uniform(), 0.03)
                }
            })
            .collect();
        let shift = Vector3::new(0.002, 0.001, -0.001);
        let scan = ScanPoints {
            points: truth.iter().map(|p| p + shift).collect(),
            sigma: vec![1e-4; truth.len()],
            camera: None,
        };
        let r = register(
            &scan,
            &mesh.nodes,
            &tris,
            &RegistrationSettings::default(),
            "prism",
        )
        .unwrap();
        assert_eq!(r.pinned, 5);
        let t = r.transform.translation;
        assert!(
            (t.y + 0.001).abs() < 1e-7 && (t.z - 0.001).abs() < 1e-7,
            "{t}"
        );
        assert!(t.x.abs() < 1e-7, "moved along the edge by {}", t.x);
    }

    /// ∂dᵢ/∂δ = ((yᵢ − c) × n, n) against central differences of the distance with the
    /// closest triangle held, for points over a tilted triangle, about a centre c off them.
    #[test]
    fn the_jacobian_of_the_distance_in_a_small_motion() {
        let nodes = [[0.0, 0.0, 0.0], [0.05, 0.01, 0.004], [0.01, 0.04, -0.006]];
        let (a, b, c) = (
            Vector3::from(nodes[0]),
            Vector3::from(nodes[1]),
            Vector3::from(nodes[2]),
        );
        let n = (b - a).cross(&(c - a)).normalize();
        let centre = Vector3::new(0.02, -0.01, 0.03);
        let mut rng = SplitMix64::new(3);
        for _ in 0..20 {
            let (u, v) = (0.3 * rng.uniform(), 0.3 * rng.uniform());
            let y = a + (b - a) * u + (c - a) * v + n * (2e-3 * (rng.uniform() - 0.5));
            let arm = (y - centre).cross(&n);
            let jac = [arm.x, arm.y, arm.z, n.x, n.y, n.z];
            for k in 0..6 {
                let h = 1e-6;
                let at = |s: f64| {
                    let mut d = [0.0; 6];
                    d[k] = s;
                    let w = Vector3::new(d[0], d[1], d[2]);
                    let t =
                        RigidTransform::about(w, w.norm(), centre, Vector3::new(d[3], d[4], d[5]));
                    n.dot(&(t.apply(y) - a))
                };
                let fd = (at(h) - at(-h)) / (2.0 * h);
                assert!(
                    (fd - jac[k]).abs() < 1e-8,
                    "direction {k}: fd {fd} vs {}",
                    jac[k]
                );
            }
        }
    }

    /// Too few points near the target: refused, naming the scan and the counts.
    #[test]
    fn too_few_points_on_the_target_are_refused_by_name() {
        let mesh = box_mesh([0.08, 0.04, 0.03], [4, 2, 2]);
        let scan = ScanPoints {
            points: vec![Vector3::new(0.5, 0.5, 0.5); 100],
            sigma: vec![1e-4; 100],
            camera: None,
        };
        let e = register(
            &scan,
            &mesh.nodes,
            &mesh.boundary_triangles(),
            &RegistrationSettings::default(),
            "scans/hang",
        )
        .unwrap_err()
        .to_string();
        for w in ["scans/hang", "0 of 100 points", "at least 50"] {
            assert!(e.contains(w), "{w:?} not in {e}");
        }
    }
}
