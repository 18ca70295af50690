//! Quadratic (10-node) tetrahedra built from a linear mesh: one node at the midpoint of every
//! edge. The linear mesh's nodes keep their indices (they come first), so marker embeddings,
//! clamped groups and contact loads named on the linear mesh name the same points here.

use std::collections::HashMap;

use super::Mesh;

/// The six edges of a tetrahedron in Gmsh's order for its 10-node tetrahedron (element type 11):
/// local node 4 + k sits on the edge `QUADRATIC_EDGES[k]`.
pub const QUADRATIC_EDGES: [[usize; 2]; 6] = [[0, 1], [1, 2], [2, 0], [0, 3], [2, 3], [1, 3]];

/// A mesh of 10-node tetrahedra whose first `vertex_count` nodes are the corners of a linear
/// mesh (same indices) and whose other nodes are the midpoints of its edges.
#[derive(Debug, Clone)]
pub struct QuadraticMesh {
    /// Rest positions (m): the linear mesh's nodes, then one per edge.
    pub nodes: Vec<[f64; 3]>,
    /// Elements: four corners (as in the linear mesh), then the edge nodes in
    /// [`QUADRATIC_EDGES`] order.
    pub tets: Vec<[usize; 10]>,
    /// Number of corner nodes (the linear mesh's node count).
    pub vertex_count: usize,
    /// The two corners of edge node `vertex_count + k`.
    pub edges: Vec<[usize; 2]>,
}

impl QuadraticMesh {
    /// Adds a midpoint node on every edge of `mesh` (straight-sided elements).
    pub fn from_linear(mesh: &Mesh) -> Self {
        let n = mesh.nodes.len();
        let mut nodes = mesh.nodes.clone();
        let mut edges: Vec<[usize; 2]> = Vec::new();
        let mut index: HashMap<[usize; 2], usize> = HashMap::new();
        let tets = mesh
            .tets
            .iter()
            .map(|t| {
                let mut q = [0usize; 10];
                q[..4].copy_from_slice(t);
                for (k, [a, b]) in QUADRATIC_EDGES.iter().enumerate() {
                    let key = [t[*a].min(t[*b]), t[*a].max(t[*b])];
                    q[4 + k] = *index.entry(key).or_insert_with(|| {
                        let [p, r] = [mesh.nodes[key[0]], mesh.nodes[key[1]]];
                        nodes.push([0, 1, 2].map(|d| 0.5 * (p[d] + r[d])));
                        edges.push(key);
                        n + edges.len() - 1
                    });
                }
                q
            })
            .collect();
        Self {
            nodes,
            tets,
            vertex_count: n,
            edges,
        }
    }

    /// Per node of this mesh, whether it lies on a set of corner nodes: a corner when it is in
    /// `on`, an edge node when both its corners are (the edge of a clamped face is clamped).
    pub fn lift_flags(&self, on: &[bool]) -> Vec<bool> {
        let mut out = Vec::with_capacity(self.nodes.len());
        out.extend_from_slice(&on[..self.vertex_count]);
        out.extend(self.edges.iter().map(|[a, b]| on[*a] && on[*b]));
        out
    }

    /// The boundary triangles of the linear mesh as 6-node triangles: three corners, then the
    /// edge nodes of (0, 1), (1, 2), (2, 0).
    pub fn lift_triangles(&self, surface: &[[usize; 3]]) -> Vec<[usize; 6]> {
        let index: HashMap<[usize; 2], usize> = self
            .edges
            .iter()
            .enumerate()
            .map(|(k, e)| (*e, self.vertex_count + k))
            .collect();
        let mid = |a: usize, b: usize| index[&[a.min(b), a.max(b)]];
        surface
            .iter()
            .map(|&[a, b, c]| [a, b, c, mid(a, b), mid(b, c), mid(c, a)])
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::boxmesh::box_mesh;

    /// Euler's count on a structured box: a grid of nx × ny × nz Kuhn cells has one edge per
    /// grid-line segment (3 axis directions), one diagonal per face of the grid (3 face
    /// directions) and one body diagonal per cell, so the midpoints are counted independently
    /// of the edge map; every edge node is the midpoint of its two corners.
    #[test]
    fn one_midpoint_per_edge() {
        let (nx, ny, nz) = (3usize, 2usize, 2usize);
        let m = box_mesh([0.3, 0.2, 0.1], [nx, ny, nz]);
        let q = QuadraticMesh::from_linear(&m);
        let axis = nx * (ny + 1) * (nz + 1) + (nx + 1) * ny * (nz + 1) + (nx + 1) * (ny + 1) * nz;
        let face = nx * ny * (nz + 1) + nx * (ny + 1) * nz + (nx + 1) * ny * nz;
        let body = nx * ny * nz;
        assert_eq!(q.edges.len(), axis + face + body);
        assert_eq!(q.vertex_count, m.nodes.len());
        for t in &q.tets {
            for (k, [a, b]) in QUADRATIC_EDGES.iter().enumerate() {
                let (p, r, s) = (q.nodes[t[*a]], q.nodes[t[*b]], q.nodes[t[4 + k]]);
                for d in 0..3 {
                    assert!((s[d] - 0.5 * (p[d] + r[d])).abs() < 1e-15);
                }
            }
        }
    }
}
