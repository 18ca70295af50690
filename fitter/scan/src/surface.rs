//! The scan residual: each scanned point's signed distance to the deformed mesh surface, along
//! the normal of the triangle that holds its closest point (point-to-plane, as in ICP; positive
//! outside). With the correspondence held, its Jacobian in the node positions is −bᵢ n for the
//! triangle's three nodes (b the closest point's barycentric coordinates) — and it is the exact
//! derivative of the distance where the closest point lies inside a triangle, since moving the
//! triangle within its own plane, or turning its normal, changes the distance only at second
//! order. Correspondences are found again as the surface moves (between iterations of a fit).
//!
//! A depth camera's points are not equally trustworthy nor equally spread: pixels of the
//! background, the clamp or the table, and "flying pixels" at depth edges lie far from the
//! object (a robust loss gives them a small or no weight, [`RobustLoss`]); a surface facing the
//! camera is sampled far more densely than one seen at a grazing angle ([`density_weights`]
//! gives each point the share of the surface it stands for, so a dense patch does not drown the
//! rest).

use nalgebra::Vector3;
use palpate_fem::dataset::embed::closest_point_on_triangle;

/// One point's closest place on the surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correspondence {
    /// Index of the point in the scan.
    pub point: usize,
    /// The triangle's node indices.
    pub triangle: [usize; 3],
    /// Barycentric coordinates of the closest point on it.
    pub barycentric: [f64; 3],
    /// The triangle's unit normal (outward for an outward-wound surface).
    pub normal: Vector3<f64>,
    /// Signed distance n·(p − q) (m), q the closest point.
    pub distance: f64,
}

impl Correspondence {
    /// ∂(distance)/∂x for each of the triangle's nodes, the correspondence held: −bᵢ n.
    pub fn jacobian(&self) -> [(usize, Vector3<f64>); 3] {
        [0, 1, 2].map(|i| (self.triangle[i], -self.barycentric[i] * self.normal))
    }
}

/// A uniform grid over a surface's triangles: each cell lists the triangles whose bounding box
/// meets it, so a closest-point query looks only at the cells within its search radius.
pub struct SurfaceGrid<'a> {
    nodes: &'a [[f64; 3]],
    triangles: &'a [[usize; 3]],
    origin: Vector3<f64>,
    cell: f64,
    dims: [usize; 3],
    cells: Vec<Vec<u32>>,
}

impl<'a> SurfaceGrid<'a> {
    /// A grid of cubic cells of side `cell` (m) over the triangles of `triangles` placed at
    /// `nodes`. The cell count is capped at 2²¹; the cells grow to keep to it.
    pub fn new(nodes: &'a [[f64; 3]], triangles: &'a [[usize; 3]], cell: f64) -> Self {
        let mut lo = Vector3::repeat(f64::INFINITY);
        let mut hi = Vector3::repeat(f64::NEG_INFINITY);
        for t in triangles {
            for &n in t {
                let p = Vector3::from(nodes[n]);
                lo = lo.inf(&p);
                hi = hi.sup(&p);
            }
        }
        if triangles.is_empty() {
            lo = Vector3::zeros();
            hi = Vector3::zeros();
        }
        let extent = hi - lo;
        let mut cell = if cell.is_finite() && cell > 0.0 {
            cell
        } else {
            extent.max().max(1e-9)
        };
        let dims_for = |c: f64| extent.map(|e| (e / c).floor() as usize + 1);
        while dims_for(cell).iter().product::<usize>() > 1 << 21 {
            cell *= 2.0;
        }
        let d = dims_for(cell);
        let dims = [d.x, d.y, d.z];
        let mut cells = vec![Vec::new(); dims[0] * dims[1] * dims[2]];
        let grid = Self {
            nodes,
            triangles,
            origin: lo,
            cell,
            dims,
            cells: Vec::new(),
        };
        for (k, t) in triangles.iter().enumerate() {
            let mut a = Vector3::repeat(f64::INFINITY);
            let mut b = Vector3::repeat(f64::NEG_INFINITY);
            for &n in t {
                let p = Vector3::from(nodes[n]);
                a = a.inf(&p);
                b = b.sup(&p);
            }
            let (ia, ib) = (grid.index(a), grid.index(b));
            for x in ia[0]..=ib[0] {
                for y in ia[1]..=ib[1] {
                    for z in ia[2]..=ib[2] {
                        cells[(x * dims[1] + y) * dims[2] + z].push(k as u32);
                    }
                }
            }
        }
        Self { cells, ..grid }
    }

    /// The cell holding `p`, clamped into the grid.
    fn index(&self, p: Vector3<f64>) -> [usize; 3] {
        let r = (p - self.origin) / self.cell;
        [0, 1, 2].map(|k| (r[k].floor().max(0.0) as usize).min(self.dims[k] - 1))
    }

    /// The closest point to `p` on the surface within `max_distance` (m), or `None`.
    pub fn closest(&self, p: Vector3<f64>, max_distance: f64) -> Option<Correspondence> {
        if self.triangles.is_empty() {
            return None;
        }
        let lo = self.index(p - Vector3::repeat(max_distance));
        let hi = self.index(p + Vector3::repeat(max_distance));
        // The triangles of the cells within reach, each once: sorted and deduplicated (a hash
        // set per query was about a third of the search).
        let mut candidates: Vec<u32> = Vec::new();
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    candidates
                        .extend_from_slice(&self.cells[(x * self.dims[1] + y) * self.dims[2] + z]);
                }
            }
        }
        candidates.sort_unstable();
        candidates.dedup();
        let mut best: Option<(f64, usize, [f64; 3], [f64; 3])> = None;
        for k in candidates {
            let k = k as usize;
            let t = self.triangles[k];
            let (b, q) = closest_point_on_triangle(
                p.into(),
                self.nodes[t[0]],
                self.nodes[t[1]],
                self.nodes[t[2]],
            );
            let d = (p - Vector3::from(q)).norm();
            // Ties go to the lower triangle index (the candidates are in increasing order).
            if d <= max_distance && best.is_none_or(|(bd, _, _, _)| d < bd) {
                best = Some((d, k, b, q));
            }
        }
        let (_, k, b, q) = best?;
        let t = self.triangles[k];
        let [a, bb, c] = t.map(|n| Vector3::from(self.nodes[n]));
        let normal = (bb - a).cross(&(c - a)).normalize();
        Some(Correspondence {
            point: 0,
            triangle: t,
            barycentric: b,
            normal,
            distance: normal.dot(&(p - Vector3::from(q))),
        })
    }
}

/// Every point's correspondence on the surface (`nodes`, `triangles`) within `max_distance`;
/// points with none (the background, the far side of the room) are left out and counted.
pub fn correspond(
    nodes: &[[f64; 3]],
    triangles: &[[usize; 3]],
    points: &[Vector3<f64>],
    max_distance: f64,
) -> (Vec<Correspondence>, usize) {
    let grid = SurfaceGrid::new(nodes, triangles, max_distance.max(1e-6));
    let mut out = Vec::with_capacity(points.len());
    for (i, p) in points.iter().enumerate() {
        if let Some(c) = grid.closest(*p, max_distance) {
            out.push(Correspondence { point: i, ..c });
        }
    }
    let unmatched = points.len() - out.len();
    (out, unmatched)
}

/// The loss on a residual scaled by the scan's noise, r/σ, as the weight of iteratively
/// reweighted least squares.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RobustLoss {
    /// Quadratic within k, linear beyond: outliers keep a weight k/|r| (a clamp in view).
    Huber(f64),
    /// Tukey's biweight: no weight beyond c (background, flying pixels).
    Tukey(f64),
}

impl RobustLoss {
    /// The weight of a residual of `scaled` = r/σ.
    pub fn weight(self, scaled: f64) -> f64 {
        let a = scaled.abs();
        match self {
            Self::Huber(k) if a <= k => 1.0,
            Self::Huber(k) => k / a,
            Self::Tukey(c) if a < c => (1.0 - (a / c) * (a / c)).powi(2),
            Self::Tukey(_) => 0.0,
        }
    }
}

/// Each point's share of the scanned surface, normalised to a mean of 1: the inverse of the
/// number of points in its cubic cell of side `cell` (m). A patch seen face-on by the camera
/// has many points per cell and each counts little; a patch seen at a grazing angle has few.
pub fn density_weights(points: &[Vector3<f64>], cell: f64) -> Vec<f64> {
    let key = |p: &Vector3<f64>| p.map(|v| (v / cell).floor() as i64);
    let mut count = std::collections::HashMap::new();
    for p in points {
        *count.entry(key(p)).or_insert(0usize) += 1;
    }
    let raw: Vec<f64> = points.iter().map(|p| 1.0 / count[&key(p)] as f64).collect();
    let mean = raw.iter().sum::<f64>() / raw.len().max(1) as f64;
    raw.into_iter().map(|w| w / mean).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_fem::dataset::embed::embed_point_in;
    use palpate_fem::mesh::boxmesh::box_mesh;
    use palpate_fem::rng::SplitMix64;

    /// A box's surface, its nodes moved a little at random so that no two triangles share a
    /// plane.
    fn wobbly_box(seed: u64) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
        let mesh = box_mesh([0.10, 0.04, 0.02], [10, 4, 2]);
        let tris = mesh.boundary_triangles();
        let mut rng = SplitMix64::new(seed);
        let nodes = mesh
            .nodes
            .iter()
            .map(|p| p.map(|v| v + 5e-4 * (rng.uniform() - 0.5)))
            .collect();
        (nodes, tris)
    }

    /// The grid finds the same closest point as the brute-force search over every triangle, and
    /// nothing for a point with no triangle within the search radius (its cells 8 mm, the box
    /// 10 × 4 × 2 cm).
    #[test]
    fn the_grid_finds_what_brute_force_finds() {
        let (nodes, tris) = wobbly_box(3);
        let mut rng = SplitMix64::new(9);
        let points: Vec<Vector3<f64>> = (0..600)
            .map(|_| {
                Vector3::new(
                    0.12 * rng.uniform() - 0.01,
                    0.06 * rng.uniform() - 0.01,
                    0.04 * rng.uniform() - 0.01,
                )
            })
            .collect();
        let radius = 0.008;
        let (found, unmatched) = correspond(&nodes, &tris, &points, radius);
        let mut within = 0;
        for (i, p) in points.iter().enumerate() {
            let e = embed_point_in(&nodes, &tris, (*p).into()).unwrap();
            let c = found.iter().find(|c| c.point == i);
            if e.distance > radius {
                assert!(c.is_none(), "point {i} at {} found", e.distance);
                continue;
            }
            within += 1;
            let c = c.unwrap_or_else(|| panic!("point {i} at {} not found", e.distance));
            let q: Vector3<f64> = (0..3)
                .map(|k| c.barycentric[k] * Vector3::from(nodes[c.triangle[k]]))
                .sum();
            let gap = (p - q).norm();
            assert!(
                (gap - e.distance).abs() < 1e-12,
                "point {i}: {gap} vs {}",
                e.distance
            );
            // Along the normal the distance is at most the gap (equal inside a triangle).
            assert!(c.distance.abs() <= gap + 1e-15, "point {i}");
        }
        assert_eq!(unmatched, points.len() - within);
        assert!(
            within > 100 && unmatched > 100,
            "{within} within, {unmatched} beyond"
        );
    }

    /// The Jacobian −bᵢ n against central differences of the distance, its closest point found
    /// again at each perturbed surface, for points whose closest point is inside a triangle.
    #[test]
    fn the_jacobian_is_the_derivative_of_the_distance() {
        let (nodes, tris) = wobbly_box(5);
        let mut rng = SplitMix64::new(11);
        let mut checked = 0;
        for _ in 0..200 {
            let p = Vector3::new(
                0.1 * rng.uniform(),
                0.04 * rng.uniform(),
                0.02 + 0.004 * (rng.uniform() - 0.3),
            );
            let (c, _) = correspond(&nodes, &tris, &[p], 0.05);
            let Some(c) = c.first() else { continue };
            if c.barycentric.iter().any(|b| *b < 0.05) {
                continue;
            }
            for (n, d) in c.jacobian() {
                for k in 0..3 {
                    let h = 1e-7;
                    let at = |s: f64| {
                        let mut moved = nodes.clone();
                        moved[n][k] += s;
                        correspond(&moved, &tris, &[p], 0.05).0[0].distance
                    };
                    let fd = (at(h) - at(-h)) / (2.0 * h);
                    assert!(
                        (fd - d[k]).abs() < 1e-6,
                        "node {n} axis {k}: fd {fd} vs {}",
                        d[k]
                    );
                }
            }
            checked += 1;
        }
        assert!(checked > 20, "only {checked} points inside a triangle");
    }

    #[test]
    fn robust_weights_and_density_weights() {
        assert_eq!(RobustLoss::Huber(2.0).weight(1.0), 1.0);
        assert_eq!(RobustLoss::Huber(2.0).weight(-4.0), 0.5);
        assert_eq!(RobustLoss::Tukey(4.0).weight(4.5), 0.0);
        assert!((RobustLoss::Tukey(4.0).weight(2.0) - 0.5625).abs() < 1e-15);
        // Nine points in one cell and one alone: the lone one stands for as much surface as
        // the nine together.
        let mut pts = vec![Vector3::new(0.0005, 0.0005, 0.0005); 9];
        pts.push(Vector3::new(0.0105, 0.0, 0.0));
        let w = density_weights(&pts, 0.001);
        assert!(
            (w[9] - 9.0 * w[0]).abs() < 1e-12 && (w.iter().sum::<f64>() - 10.0).abs() < 1e-12,
            "{w:?}"
        );
    }
}
