//! Tetrahedral meshes: the in-memory mesh every fitter part shares, a built-in box mesher for
//! tests and benchmarks, Gmsh 4.1 input and VTK output.

pub mod boxmesh;
pub mod gmsh;
pub mod quadratic;
pub mod refine;
pub mod vtk;

use std::collections::{BTreeMap, HashMap};

use nalgebra::Vector3;

/// Signed volume of a tetrahedron: positive when its corners are ordered right-handed
/// ((p1 − p0) · ((p2 − p0) × (p3 − p0)) / 6).
pub fn signed_volume(p: [[f64; 3]; 4]) -> f64 {
    let [a, b, c, d] = p.map(Vector3::from);
    (b - a).dot(&(c - a).cross(&(d - a))) / 6.0
}

/// Centroid of tetrahedron `tet` of the points `nodes`: the mean of its four corners.
pub fn centroid(nodes: &[[f64; 3]], tet: &[usize; 4]) -> [f64; 3] {
    let mut c = [0.0; 3];
    for &n in tet {
        for d in 0..3 {
            c[d] += 0.25 * nodes[n][d];
        }
    }
    c
}

/// A linear tetrahedral mesh with named node groups (Gmsh physical groups).
#[derive(Debug, Clone, Default)]
pub struct Mesh {
    /// Rest positions in metres.
    pub nodes: Vec<[f64; 3]>,
    /// The mesh file's node tag of each node (Gmsh tags; 1-based sequence for generated meshes).
    /// Every CSV palpate writes names nodes by these tags.
    pub node_tags: Vec<u64>,
    /// Tetrahedra as node indices, oriented to positive volume.
    pub tets: Vec<[usize; 4]>,
    /// Physical group name → sorted, de-duplicated node indices.
    pub node_groups: BTreeMap<String, Vec<usize>>,
}

impl Mesh {
    /// Boundary triangles (faces used by exactly one tetrahedron), wound outward.
    pub fn boundary_triangles(&self) -> Vec<[usize; 3]> {
        // Face opposite node k of tet (a,b,c,d) with positive volume, wound so that its normal
        // points away from node k.
        const FACES: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];
        let mut count: HashMap<[usize; 3], (usize, [usize; 3])> = HashMap::new();
        for t in &self.tets {
            for f in FACES {
                let tri = [t[f[0]], t[f[1]], t[f[2]]];
                let mut key = tri;
                key.sort_unstable();
                count
                    .entry(key)
                    .and_modify(|e| e.0 += 1)
                    .or_insert((1, tri));
            }
        }
        let mut out: Vec<[usize; 3]> = count
            .into_values()
            .filter(|(n, _)| *n == 1)
            .map(|(_, t)| t)
            .collect();
        out.sort_unstable();
        out
    }

    /// Node indices of a physical group, or an error naming the group and the groups present.
    pub fn group(&self, name: &str) -> Result<&[usize], gmsh::MeshError> {
        self.node_groups
            .get(name)
            .map(|v| v.as_slice())
            .ok_or_else(|| gmsh::MeshError::NoGroup {
                name: name.to_string(),
                present: self
                    .node_groups
                    .keys()
                    .cloned()
                    .collect::<Vec<_>>()
                    .join(", "),
            })
    }

    /// Axis-aligned bounding box (min, max).
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in &self.nodes {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        (lo, hi)
    }

    /// Pairs of elements sharing a face (the neighbourhood of the spatial smoothness L_s, eq. 5.25).
    pub fn face_neighbours(&self) -> Vec<(usize, usize)> {
        let mut owner: HashMap<[usize; 3], usize> = HashMap::new();
        let mut pairs = Vec::new();
        for (e, t) in self.tets.iter().enumerate() {
            for skip in 0..4 {
                let mut key = [0usize; 3];
                let mut k = 0;
                for (i, &n) in t.iter().enumerate() {
                    if i != skip {
                        key[k] = n;
                        k += 1;
                    }
                }
                key.sort_unstable();
                if let Some(&o) = owner.get(&key) {
                    pairs.push((o, e));
                } else {
                    owner.insert(key, e);
                }
            }
        }
        pairs.sort_unstable();
        pairs
    }
}
