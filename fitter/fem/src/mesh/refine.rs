//! Uniform refinement of a tetrahedral mesh: every tetrahedron into eight (Bey's "red" refinement),
//! new nodes at edge midpoints. Used to measure how much of a residual the dataset's own mesh
//! causes (the discretisation error of a fitted model: solve again at h/2 and compare).
//!
//! The refined mesh has the same geometry (faces are split in their planes), the same boundary
//! (each boundary triangle becomes four), and node groups carried over: a midpoint belongs to a
//! group when both ends of its edge do, so a fixed face stays a fixed face.

use std::collections::HashMap;

use super::{signed_volume, Mesh};

/// The mesh with every tetrahedron split into eight. New node tags continue after the largest
/// existing tag.
pub fn refine(mesh: &Mesh) -> Mesh {
    refine_with_midpoints(mesh).0
}

/// [`refine`], also returning the midpoint node of every coarse edge ((a, b) with a < b → node).
/// Coarse nodes keep their indices.
pub fn refine_with_midpoints(mesh: &Mesh) -> (Mesh, HashMap<(usize, usize), usize>) {
    let mut nodes = mesh.nodes.clone();
    let mut tags = mesh.node_tags.clone();
    let mut next_tag = tags.iter().copied().max().unwrap_or(0) + 1;
    let mut mid: HashMap<(usize, usize), usize> = HashMap::new();
    let mut midpoint = |a: usize, b: usize, nodes: &mut Vec<[f64; 3]>| -> usize {
        let key = (a.min(b), a.max(b));
        *mid.entry(key).or_insert_with(|| {
            let (p, q) = (nodes[a], nodes[b]);
            nodes.push([
                0.5 * (p[0] + q[0]),
                0.5 * (p[1] + q[1]),
                0.5 * (p[2] + q[2]),
            ]);
            tags.push(next_tag);
            next_tag += 1;
            nodes.len() - 1
        })
    };
    let mut tets = Vec::with_capacity(8 * mesh.tets.len());
    for t in &mesh.tets {
        let [x0, x1, x2, x3] = *t;
        let m01 = midpoint(x0, x1, &mut nodes);
        let m02 = midpoint(x0, x2, &mut nodes);
        let m03 = midpoint(x0, x3, &mut nodes);
        let m12 = midpoint(x1, x2, &mut nodes);
        let m13 = midpoint(x1, x3, &mut nodes);
        let m23 = midpoint(x2, x3, &mut nodes);
        // Four corner tetrahedra and the inner octahedron cut along the diagonal m02–m13.
        for mut c in [
            [x0, m01, m02, m03],
            [m01, x1, m12, m13],
            [m02, m12, x2, m23],
            [m03, m13, m23, x3],
            [m01, m02, m03, m13],
            [m01, m12, m02, m13],
            [m02, m03, m13, m23],
            [m02, m13, m12, m23],
        ] {
            if signed_volume(c.map(|i| nodes[i])) < 0.0 {
                c.swap(2, 3);
            }
            tets.push(c);
        }
    }
    let mut node_groups = mesh.node_groups.clone();
    for members in node_groups.values_mut() {
        let set: std::collections::HashSet<usize> = members.iter().copied().collect();
        for (&(a, b), &m) in &mid {
            if set.contains(&a) && set.contains(&b) {
                members.push(m);
            }
        }
        members.sort_unstable();
        members.dedup();
    }
    (
        Mesh {
            nodes,
            node_tags: tags,
            tets,
            node_groups,
        },
        mid,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::boxmesh::box_mesh;

    /// Volume is preserved (1e-12 relative), every child is positively oriented with a volume of
    /// 1/8 of its parent's in total, node count = nodes + edges, boundary triangles × 4, a node
    /// group (the bottom face) gains exactly the midpoints of its own edges and stays planar.
    #[test]
    fn refinement_preserves_geometry_and_groups() {
        let m = box_mesh([0.08, 0.06, 0.04], [3, 2, 2]);
        let r = refine(&m);
        let vol = |mesh: &Mesh| -> f64 {
            mesh.tets
                .iter()
                .map(|t| signed_volume(t.map(|i| mesh.nodes[i])))
                .sum()
        };
        assert!((vol(&r) - vol(&m)).abs() < 1e-12 * vol(&m));
        assert!(r
            .tets
            .iter()
            .all(|t| signed_volume(t.map(|i| r.nodes[i])) > 0.0));
        assert_eq!(r.tets.len(), 8 * m.tets.len());
        // Bey's red refinement: the eight children of a tetrahedron have equal volumes (a
        // wrong octahedron split would give overlapping children of unequal volume).
        for (t, kids) in m.tets.iter().zip(r.tets.chunks(8)) {
            let parent = signed_volume(t.map(|i| m.nodes[i]));
            for k in kids {
                let v = signed_volume(k.map(|i| r.nodes[i]));
                assert!(
                    (v - parent / 8.0).abs() < 1e-12 * parent,
                    "{v} vs {parent}/8"
                );
            }
        }
        let mut edges = std::collections::HashSet::new();
        for t in &m.tets {
            for a in 0..4 {
                for b in a + 1..4 {
                    edges.insert((t[a].min(t[b]), t[a].max(t[b])));
                }
            }
        }
        assert_eq!(r.nodes.len(), m.nodes.len() + edges.len());
        assert_eq!(
            r.boundary_triangles().len(),
            4 * m.boundary_triangles().len()
        );
        let bottom = r.group("bottom").unwrap();
        assert!(bottom.iter().all(|&i| r.nodes[i][2].abs() < 1e-15));
        let on_bottom = r.nodes.iter().filter(|p| p[2].abs() < 1e-15).count();
        assert_eq!(bottom.len(), on_bottom);
        let mut tags = r.node_tags.clone();
        tags.sort_unstable();
        tags.dedup();
        assert_eq!(tags.len(), r.nodes.len(), "node tags must stay unique");
    }
}
