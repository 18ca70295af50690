//! A fit's residual as a flat map of the deformed surface: each surface triangle projected along
//! a view axis, with the mean signed distance of the scan points whose closest point lies on it,
//! in painter's order (farthest from the viewer first), for a figure a person reads beside the
//! report.
//!
//! The view axis is the rest mesh's smallest principal axis (the direction in which the object
//! is thinnest, so the projection shows most of its surface), looked along from the side the
//! scan's points face: the sign that makes the mean outward normal at the points' closest points
//! point at the viewer. A scan dataset does not carry one camera direction (a scan may be a
//! point cloud, or fused from several views), so the geometry decides.

use std::collections::HashMap;

use nalgebra::{Matrix3, SymmetricEigen, Vector3};

use crate::fit::{PointResidual, ScanFit};

/// The surface projected for a figure.
#[derive(Debug, Clone)]
pub struct ResidualMap {
    /// Unit screen axes in the mesh's frame: x (right) and y (up); the viewer looks along
    /// −(x × y).
    pub axes: [[f64; 3]; 2],
    /// Each triangle's corners on the screen (m), in drawing order: farthest first.
    pub triangles: Vec<[(f64, f64); 3]>,
    /// Each triangle's mean signed distance (m) of the points nearest it, in the same order;
    /// NaN where no point's closest point lies on it.
    pub mean_m: Vec<f64>,
    /// How many points lie nearest each triangle, in the same order.
    pub points: Vec<usize>,
}

/// The mean signed distance of the points whose closest point lies on each of `surface`'s
/// triangles (NaN where none does), and their count.
pub fn triangle_mean_residual(
    surface: &[[usize; 3]],
    residuals: &[PointResidual],
) -> (Vec<f64>, Vec<usize>) {
    let key = |t: &[usize; 3]| {
        let mut k = *t;
        k.sort_unstable();
        k
    };
    let index: HashMap<[usize; 3], usize> = surface
        .iter()
        .enumerate()
        .map(|(i, t)| (key(t), i))
        .collect();
    let mut sum = vec![0.0; surface.len()];
    let mut count = vec![0usize; surface.len()];
    for r in residuals {
        let c = &r.correspondence;
        if let Some(&i) = index.get(&key(&c.triangle)) {
            if c.distance.is_finite() {
                sum[i] += c.distance;
                count[i] += 1;
            }
        }
    }
    let mean = sum
        .iter()
        .zip(&count)
        .map(|(s, &n)| if n > 0 { s / n as f64 } else { f64::NAN })
        .collect();
    (mean, count)
}

/// The covariance of `points` about their centroid, each offset projected onto the plane across
/// the unit vector `across` when it is given (zero for no points).
fn covariance(points: &[[f64; 3]], across: Option<&Vector3<f64>>) -> Matrix3<f64> {
    let n = points.len().max(1) as f64;
    let centre = points
        .iter()
        .fold(Vector3::zeros(), |a, p| a + Vector3::from(*p))
        / n;
    points.iter().fold(Matrix3::zeros(), |a, p| {
        let d = Vector3::from(*p) - centre;
        let d = across.map_or(d, |v| d - v * v.dot(&d));
        a + d * d.transpose()
    }) / n
}

/// The direction from the object to the viewer: the smallest principal axis of `rest`'s points
/// (the surface nodes at rest), signed so that the residuals' outward normals face it on the
/// whole (+ when they balance). `None` for fewer than three points.
pub fn view_axis(rest: &[[f64; 3]], residuals: &[PointResidual]) -> Option<Vector3<f64>> {
    if rest.len() < 3 {
        return None;
    }
    let eig = SymmetricEigen::new(covariance(rest, None));
    let k = eig.eigenvalues.imin();
    let axis = eig.eigenvectors.column(k).into_owned();
    let facing: f64 = residuals
        .iter()
        .map(|r| r.correspondence.normal.dot(&axis))
        .sum();
    Some(if facing < 0.0 { -axis } else { axis })
}

/// Projects `surface` at `positions` along `view` (from the object to the viewer): the screen's
/// x is the rest shape's largest principal axis across `view` when `rest` is given, else any
/// axis across it; y = view × x. Triangles come out sorted by their centroid's height along
/// `view`, lowest (farthest) first, each with its `values` entry.
pub fn project(
    positions: &[[f64; 3]],
    surface: &[[usize; 3]],
    values: &[f64],
    counts: &[usize],
    view: Vector3<f64>,
    rest: &[[f64; 3]],
) -> ResidualMap {
    let v = view.normalize();
    // The widest direction across the view: the largest eigenvector of the rest shape's
    // covariance projected onto the screen plane.
    let x = {
        let eig = SymmetricEigen::new(covariance(rest, Some(&v)));
        let e = eig.eigenvectors.column(eig.eigenvalues.imax()).into_owned();
        let e = e - v * v.dot(&e);
        if e.norm() > 1e-9 {
            // Sign: the axis' largest component positive, so a mesh along +x reads left to right.
            let e = e.normalize();
            if e[e.iamax()] < 0.0 {
                -e
            } else {
                e
            }
        } else {
            let helper = if v.x.abs() < 0.9 {
                Vector3::x()
            } else {
                Vector3::y()
            };
            (helper - v * v.dot(&helper)).normalize()
        }
    };
    let y = v.cross(&x);
    let at = |i: usize| Vector3::from(positions[i]);
    let mut order: Vec<(f64, usize)> = surface
        .iter()
        .enumerate()
        .map(|(k, t)| ((at(t[0]) + at(t[1]) + at(t[2])).dot(&v) / 3.0, k))
        .collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0));
    let screen = |i: usize| (at(i).dot(&x), at(i).dot(&y));
    ResidualMap {
        axes: [[x.x, x.y, x.z], [y.x, y.y, y.z]],
        triangles: order.iter().map(|&(_, k)| surface[k].map(screen)).collect(),
        mean_m: order.iter().map(|&(_, k)| values[k]).collect(),
        points: order.iter().map(|&(_, k)| counts[k]).collect(),
    }
}

/// The map of `fit`'s residual on its deformed surface, seen along the rest surface's smallest
/// principal axis. `None` for a surface of fewer than three nodes.
pub fn residual_map(fit: &ScanFit) -> Option<ResidualMap> {
    let eq = &fit.at_fit.equilibrium;
    let mut on_surface = vec![false; eq.rest.len()];
    for t in &eq.surface {
        for &i in t {
            on_surface[i] = true;
        }
    }
    let rest: Vec<[f64; 3]> = eq
        .rest
        .iter()
        .zip(&on_surface)
        .filter(|(_, s)| **s)
        .map(|(p, _)| *p)
        .collect();
    let view = view_axis(&rest, &fit.at_fit.residuals)?;
    let (mean, count) = triangle_mean_residual(&eq.surface, &fit.at_fit.residuals);
    Some(project(
        &eq.positions,
        &eq.surface,
        &mean,
        &count,
        view,
        &rest,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::surface::Correspondence;

    fn residual(triangle: [usize; 3], normal: Vector3<f64>, d: f64) -> PointResidual {
        PointResidual {
            correspondence: Correspondence {
                point: 0,
                triangle,
                barycentric: [1.0 / 3.0; 3],
                normal,
                distance: d,
            },
            sigma: 1e-3,
            weight: 1.0,
        }
    }

    /// Three points on triangle 0 (listed in another rotation of its nodes) at +1, +2, +3 mm
    /// average +2 mm; triangle 1 has none (NaN, count 0).
    #[test]
    fn each_triangle_gets_the_mean_of_its_points() {
        let surface = [[0, 1, 2], [1, 3, 2]];
        let r: Vec<_> = [1e-3, 2e-3, 3e-3]
            .iter()
            .map(|&d| residual([2, 0, 1], Vector3::z(), d))
            .collect();
        let (mean, count) = triangle_mean_residual(&surface, &r);
        assert!((mean[0] - 2e-3).abs() < 1e-15, "{mean:?}");
        assert_eq!(count, vec![3, 0]);
        assert!(mean[1].is_nan());
    }

    /// A flat 40 × 10 × 2 mm slab: the view axis is z, from the side the points face; the
    /// screen's x runs along the slab's length; of two triangles one above the other, the
    /// lower (farther) one is drawn first whichever way round they are listed, and flipping the
    /// points' normals flips the view, and with it the order.
    #[test]
    fn the_view_is_along_the_thin_axis_and_far_triangles_come_first() {
        let mut rest = Vec::new();
        for &x in &[0.0, 0.04] {
            for &y in &[0.0, 0.01] {
                for &z in &[0.0, 0.002] {
                    rest.push([x, y, z]);
                }
            }
        }
        let up = [residual([0, 1, 2], Vector3::z(), 0.0)];
        let v = view_axis(&rest, &up).unwrap();
        assert!((v - Vector3::z()).norm() < 1e-12, "{v}");
        let down = [residual([0, 1, 2], -Vector3::z(), 0.0)];
        assert!((view_axis(&rest, &down).unwrap() + Vector3::z()).norm() < 1e-12);

        // Triangle 0 at z = 0.002 (near from +z), triangle 1 at z = 0 (far).
        let positions = [
            [0.0, 0.0, 0.002],
            [0.01, 0.0, 0.002],
            [0.0, 0.01, 0.002],
            [0.0, 0.0, 0.0],
            [0.01, 0.0, 0.0],
            [0.0, 0.01, 0.0],
        ];
        let surface = [[0, 1, 2], [3, 4, 5]];
        let values = [1e-3, -1e-3];
        let m = project(&positions, &surface, &values, &[1, 1], v, &rest);
        assert_eq!(m.mean_m, vec![-1e-3, 1e-3], "far (z = 0) first");
        let ax = m.axes[0];
        assert!((ax[0] - 1.0).abs() < 1e-12, "x along the length: {ax:?}");
        // Right-handed: x × y is the view axis, so the picture is not mirrored.
        let (x, y) = (Vector3::from(m.axes[0]), Vector3::from(m.axes[1]));
        assert!((x.cross(&y) - v).norm() < 1e-12);
        assert_eq!(m.triangles[1][1], (0.01, 0.0));
        let m = project(&positions, &surface, &values, &[1, 1], -v, &rest);
        assert_eq!(m.mean_m, vec![1e-3, -1e-3], "seen from below");
    }
}
