//! Marker embedding: each marker is attached to the closest point of the mesh's boundary surface,
//! in barycentric coordinates of a boundary triangle, so that its position can be interpolated
//! from the node positions of any deformed state ([`super::Marker::interpolate`]).
//!
//! The search is brute force over all boundary triangles (O(markers × triangles): 200 markers on a
//! 2,000-triangle surface is 400k point–triangle tests, a few milliseconds).

use crate::mesh::Mesh;
use nalgebra::Vector3;

/// A marker farther from the surface than `EMBED_TOLERANCE_FRACTION` × the median boundary edge
/// length (plus a declared `marker_standoff`) is rejected. A marker off the surface is a material
/// point carried rigidly by its surface patch ([`super::Marker`]): the faceting of a curved scan
/// (a fraction of a millimetre), a glued bead, a short post are all modelled; one edge is still far
/// less than what markers given in the wrong units or frame are off by (centimetres to metres).
pub const EMBED_TOLERANCE_FRACTION: f64 = 1.0;

/// Where a point lands on the surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Embedding {
    /// Node indices of the boundary triangle.
    pub triangle: [usize; 3],
    /// Barycentric coordinates of the closest point (non-negative, sum to 1).
    pub barycentric: [f64; 3],
    /// The closest point itself (m).
    pub point: [f64; 3],
    /// Distance from the query point to it (m).
    pub distance: f64,
}

/// Median length of the boundary edges (each edge counted once), in metres.
pub fn median_surface_edge(mesh: &Mesh, surface: &[[usize; 3]]) -> f64 {
    let mut edges: Vec<(usize, usize)> = surface
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .map(|(a, b)| (a.min(b), a.max(b)))
        .collect();
    edges.sort_unstable();
    edges.dedup();
    let mut len: Vec<f64> = edges
        .iter()
        .map(|&(a, b)| dist(mesh.nodes[a], mesh.nodes[b]))
        .collect();
    if len.is_empty() {
        return 0.0;
    }
    len.sort_by(f64::total_cmp);
    len[len.len() / 2]
}

/// The embedding tolerance of a mesh: [`EMBED_TOLERANCE_FRACTION`] × [`median_surface_edge`].
pub fn embedding_tolerance(mesh: &Mesh, surface: &[[usize; 3]]) -> f64 {
    EMBED_TOLERANCE_FRACTION * median_surface_edge(mesh, surface)
}

/// The closest point to `p` on the surface triangles (ties go to the first triangle), or `None`
/// for an empty surface.
pub fn embed_point(mesh: &Mesh, surface: &[[usize; 3]], p: [f64; 3]) -> Option<Embedding> {
    embed_point_in(&mesh.nodes, surface, p)
}

/// [`embed_point`] on node positions `nodes` (any configuration of the mesh).
pub fn embed_point_in(
    nodes: &[[f64; 3]],
    surface: &[[usize; 3]],
    p: [f64; 3],
) -> Option<Embedding> {
    let mut best: Option<Embedding> = None;
    for &t in surface {
        let (bary, q) = closest_point_on_triangle(p, nodes[t[0]], nodes[t[1]], nodes[t[2]]);
        let d = dist(p, q);
        if best.as_ref().is_none_or(|b| d < b.distance) {
            best = Some(Embedding {
                triangle: t,
                barycentric: bary,
                point: q,
                distance: d,
            });
        }
    }
    best
}

/// Closest point on triangle (a, b, c) to p: barycentric coordinates and the point (Ericson,
/// *Real-Time Collision Detection*, §5.1.5: Voronoi regions of vertices, edges and the face).
pub fn closest_point_on_triangle(
    p: [f64; 3],
    a: [f64; 3],
    b: [f64; 3],
    c: [f64; 3],
) -> ([f64; 3], [f64; 3]) {
    let (p, a, b, c) = (v3(p), v3(a), v3(b), v3(c));
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return ([1.0, 0.0, 0.0], a.into());
    }
    let bp = p - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return ([0.0, 1.0, 0.0], b.into());
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return ([1.0 - v, v, 0.0], (a + ab * v).into());
    }
    let cp = p - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return ([0.0, 0.0, 1.0], c.into());
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return ([1.0 - w, 0.0, w], (a + ac * w).into());
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return ([0.0, 1.0 - w, w], (b + (c - b) * w).into());
    }
    let denom = 1.0 / (va + vb + vc);
    let v = vb * denom;
    let w = vc * denom;
    ([1.0 - v - w, v, w], (a + ab * v + ac * w).into())
}

fn v3(a: [f64; 3]) -> Vector3<f64> {
    Vector3::from(a)
}

/// Distance between two points.
fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    (v3(a) - v3(b)).norm()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::boxmesh::box_mesh;

    /// Brute-force reference: the minimum over a fine barycentric grid (spacing 1/400) must not
    /// beat the analytic closest point, and must come within the grid's resolution of it.
    #[test]
    fn closest_point_matches_dense_sampling_in_every_region() {
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.2, 0.1], [0.3, 0.9, -0.2]);
        let queries = [
            [0.3, 0.3, 0.5],   // face
            [-0.5, -0.5, 0.0], // vertex a
            [2.0, 0.2, 0.0],   // vertex b
            [0.3, 2.0, 0.0],   // vertex c
            [0.6, -0.5, 0.3],  // edge ab
            [1.0, 1.0, 0.0],   // edge bc
            [-0.4, 0.5, 0.0],  // edge ca
        ];
        let n = 400;
        for p in queries {
            let (bary, q) = closest_point_on_triangle(p, a, b, c);
            assert!(
                (bary.iter().sum::<f64>() - 1.0).abs() < 1e-14 && bary.iter().all(|&x| x >= 0.0)
            );
            let interp = [0, 1, 2].map(|d| bary[0] * a[d] + bary[1] * b[d] + bary[2] * c[d]);
            assert!(dist(interp, q) < 1e-14);
            let d = dist(p, q);
            let mut best = f64::INFINITY;
            for i in 0..=n {
                for j in 0..=(n - i) {
                    let (v, w) = (i as f64 / n as f64, j as f64 / n as f64);
                    let s = [0, 1, 2].map(|k| a[k] + v * (b[k] - a[k]) + w * (c[k] - a[k]));
                    best = best.min(dist(p, s));
                }
            }
            assert!(
                d <= best + 1e-12,
                "analytic {d} worse than sampled {best} for {p:?}"
            );
            // Grid spacing ≤ 1.2/400 in this triangle; the sampled minimum is within it.
            assert!(best - d < 3e-3, "sampled {best} vs analytic {d} for {p:?}");
        }
    }

    #[test]
    fn marker_above_top_face_embeds_with_its_height_as_distance() {
        let m = box_mesh([0.1, 0.1, 0.05], [4, 4, 2]);
        let s = m.boundary_triangles();
        let e = embed_point(&m, &s, [0.031, 0.047, 0.0512]).unwrap();
        assert!((e.distance - 0.0012).abs() < 1e-15);
        assert!(e.triangle.iter().all(|&i| m.nodes[i][2] == 0.05));
        assert!((e.point[0] - 0.031).abs() < 1e-15 && (e.point[1] - 0.047).abs() < 1e-15);
        // Median edge of this box: cells are 25 × 25 × 25 mm; face diagonals are longer, so the
        // median is the cell edge.
        assert!((median_surface_edge(&m, &s) - 0.025).abs() < 1e-15);
    }
}
