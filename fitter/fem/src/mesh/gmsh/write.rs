//! MSH 4.1 ASCII output.

use super::MeshError;
use crate::io::atomic::write_atomic_with;
use crate::mesh::Mesh;
use std::collections::BTreeSet;
use std::io::Write;
use std::path::Path;

/// Writes `mesh` as Gmsh MSH 4.1 ASCII, atomically.
///
/// Layout (chosen so that both [`super::read_msh`] and Gmsh read back exactly the same node groups):
/// - one volume entity (tag 1) holding all nodes, in mesh order with their
///   [`Mesh::node_tags`] (1, 2, … if the mesh has none), and all tetrahedra, tagged 1…n;
/// - for the k-th node group (k = 1, 2, … in name order): a surface entity of tag k carrying the
///   boundary triangles whose three nodes all belong to the group, in the physical surface group
///   (dim 2, tag k) with the group's name; every group node not on such a triangle gets its own
///   point entity with one point element, in the physical point group (dim 0, tag k) of the same
///   name. Reading merges both by name, so every group comes back node for node.
/// - a group holding every node of the mesh is written as a physical volume group (dim 3, tag k)
///   on the volume entity instead.
pub fn write_msh(mesh: &Mesh, path: impl AsRef<Path>) -> Result<(), MeshError> {
    let path = path.as_ref();
    let invalid = |message: String| MeshError::InvalidMesh {
        file: path.to_path_buf(),
        message,
    };
    let tags = checked_tags(mesh).map_err(invalid)?;
    let layout = Layout::new(mesh, tags);
    write_atomic_with(path, |w| {
        writeln!(w, "$MeshFormat\n4.1 0 8\n$EndMeshFormat")?;
        layout.physical_names(w)?;
        let point_entities = layout.entities(w)?;
        layout.nodes(w)?;
        layout.elements(w, &point_entities)
    })
    .map_err(|e| MeshError::Write {
        file: path.to_path_buf(),
        message: format!("{e:#}"),
    })
}

/// The node tags to write (1, 2, … if the mesh has none), after checking that they are distinct
/// and non-zero, that the tetrahedra and groups refer to nodes of the mesh, and that every group
/// name can be quoted.
fn checked_tags(mesh: &Mesh) -> Result<Vec<u64>, String> {
    let n = mesh.nodes.len();
    let tags: Vec<u64> = if mesh.node_tags.is_empty() {
        (1..=n as u64).collect()
    } else {
        mesh.node_tags.clone()
    };
    if tags.len() != n {
        return Err(format!("{} node tags for {} nodes", tags.len(), n));
    }
    let mut distinct = BTreeSet::new();
    for &t in &tags {
        if t == 0 || !distinct.insert(t) {
            return Err(format!("node tag {t} is zero or repeated"));
        }
    }
    if let Some(t) = mesh.tets.iter().find(|t| t.iter().any(|&i| i >= n)) {
        return Err(format!("tetrahedron {t:?} refers to a node index ≥ {n}"));
    }
    for (name, members) in &mesh.node_groups {
        if name.contains('"') || name.contains('\n') {
            return Err(format!("group name {name:?} holds a quote or newline"));
        }
        if let Some(i) = members.iter().find(|&&i| i >= n) {
            return Err(format!("group {name:?} refers to node index {i} ≥ {n}"));
        }
    }
    Ok(tags)
}

/// One node group as written: its name, the boundary triangles inside it, and its nodes on
/// none of them.
struct GroupLayout<'a> {
    name: &'a String,
    tris: Vec<[usize; 3]>,
    rest: Vec<usize>,
    /// The group holds every node of the mesh: a physical volume group.
    whole: bool,
}

/// What the file holds beyond the mesh itself: the node tags and each group's entities.
struct Layout<'a> {
    mesh: &'a Mesh,
    tags: Vec<u64>,
    groups: Vec<GroupLayout<'a>>,
}

impl<'a> Layout<'a> {
    fn new(mesh: &'a Mesh, tags: Vec<u64>) -> Self {
        let n = mesh.nodes.len();
        let boundary = mesh.boundary_triangles();
        let groups = mesh
            .node_groups
            .iter()
            .map(|(name, members)| {
                let whole = members.len() >= n
                    && members.iter().copied().collect::<BTreeSet<usize>>().len() == n;
                let inside: BTreeSet<usize> = members.iter().copied().collect();
                if inside.len() == n {
                    // The whole mesh: a physical volume group, no surface or point entities.
                    return GroupLayout {
                        name,
                        tris: Vec::new(),
                        rest: Vec::new(),
                        whole,
                    };
                }
                let tris: Vec<[usize; 3]> = boundary
                    .iter()
                    .filter(|t| t.iter().all(|i| inside.contains(i)))
                    .copied()
                    .collect();
                let covered: BTreeSet<usize> = tris.iter().flatten().copied().collect();
                let rest = inside.difference(&covered).copied().collect();
                GroupLayout {
                    name,
                    tris,
                    rest,
                    whole,
                }
            })
            .collect();
        Self { mesh, tags, groups }
    }

    /// The bounding box of the nodes `idx`.
    fn bbox(&self, idx: &mut dyn Iterator<Item = usize>) -> ([f64; 3], [f64; 3]) {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for i in idx {
            for d in 0..3 {
                lo[d] = lo[d].min(self.mesh.nodes[i][d]);
                hi[d] = hi[d].max(self.mesh.nodes[i][d]);
            }
        }
        (lo, hi)
    }

    /// `$PhysicalNames`: surface and point groups share the group's name and number.
    fn physical_names(&self, w: &mut impl Write) -> std::io::Result<()> {
        let mut names = Vec::new();
        for (k, g) in self.groups.iter().enumerate() {
            if !g.tris.is_empty() {
                names.push(format!("2 {} \"{}\"", k + 1, g.name));
            }
            if g.whole {
                names.push(format!("3 {} \"{}\"", k + 1, g.name));
            } else if !g.rest.is_empty() || g.tris.is_empty() {
                names.push(format!("0 {} \"{}\"", k + 1, g.name));
            }
        }
        writeln!(w, "$PhysicalNames\n{}", names.len())?;
        for l in &names {
            writeln!(w, "{l}")?;
        }
        writeln!(w, "$EndPhysicalNames")
    }

    /// `$Entities`: a point per leftover group node, a surface per group with triangles, the
    /// volume. Returns the point entities' (tag, node index).
    fn entities(&self, w: &mut impl Write) -> std::io::Result<Vec<(usize, usize)>> {
        let n_points: usize = self.groups.iter().map(|g| g.rest.len()).sum();
        let n_surfaces = self.groups.iter().filter(|g| !g.tris.is_empty()).count();
        writeln!(w, "$Entities\n{} 0 {} 1", n_points, n_surfaces)?;
        let mut point_tag = 0;
        let mut point_entities = Vec::new();
        for (k, g) in self.groups.iter().enumerate() {
            for &i in &g.rest {
                point_tag += 1;
                let p = self.mesh.nodes[i];
                writeln!(
                    w,
                    "{} {:e} {:e} {:e} 1 {}",
                    point_tag,
                    p[0],
                    p[1],
                    p[2],
                    k + 1
                )?;
                point_entities.push((point_tag, i));
            }
        }
        for (k, g) in self.groups.iter().enumerate() {
            if !g.tris.is_empty() {
                let (lo, hi) = self.bbox(&mut g.tris.iter().flatten().copied());
                writeln!(
                    w,
                    "{} {:e} {:e} {:e} {:e} {:e} {:e} 1 {} 0",
                    k + 1,
                    lo[0],
                    lo[1],
                    lo[2],
                    hi[0],
                    hi[1],
                    hi[2],
                    k + 1
                )?;
            }
        }
        let volume_groups: Vec<String> = (0..self.groups.len())
            .filter(|&k| self.groups[k].whole)
            .map(|k| (k + 1).to_string())
            .collect();
        let volume_physicals = std::iter::once(volume_groups.len().to_string())
            .chain(volume_groups.iter().cloned())
            .collect::<Vec<_>>()
            .join(" ");
        let (lo, hi) = self.bbox(&mut (0..self.mesh.nodes.len()));
        writeln!(
            w,
            "1 {:e} {:e} {:e} {:e} {:e} {:e} {} 0",
            lo[0], lo[1], lo[2], hi[0], hi[1], hi[2], volume_physicals
        )?;
        writeln!(w, "$EndEntities")?;
        Ok(point_entities)
    }

    /// `$Nodes`: one block on the volume.
    fn nodes(&self, w: &mut impl Write) -> std::io::Result<()> {
        let n = self.mesh.nodes.len();
        let min_tag = self.tags.iter().copied().min().unwrap_or(0);
        let max_tag = self.tags.iter().copied().max().unwrap_or(0);
        writeln!(w, "$Nodes\n1 {n} {min_tag} {max_tag}\n3 1 0 {n}")?;
        for t in &self.tags {
            writeln!(w, "{t}")?;
        }
        for p in &self.mesh.nodes {
            // `{:?}` prints the shortest text that parses back to the same f64.
            writeln!(w, "{:?} {:?} {:?}", p[0], p[1], p[2])?;
        }
        writeln!(w, "$EndNodes")
    }

    /// `$Elements`: tetrahedra, then group triangles, then group points.
    fn elements(
        &self,
        w: &mut impl Write,
        point_entities: &[(usize, usize)],
    ) -> std::io::Result<()> {
        let tags = &self.tags;
        let n_tris: usize = self.groups.iter().map(|g| g.tris.len()).sum();
        let n_surfaces = self.groups.iter().filter(|g| !g.tris.is_empty()).count();
        let n_points = point_entities.len();
        let total = self.mesh.tets.len() + n_tris + n_points;
        let blocks = 1 + n_surfaces + n_points;
        writeln!(w, "$Elements\n{blocks} {total} 1 {total}")?;
        writeln!(w, "3 1 4 {}", self.mesh.tets.len())?;
        let mut etag = 0usize;
        for t in &self.mesh.tets {
            etag += 1;
            writeln!(
                w,
                "{} {} {} {} {}",
                etag, tags[t[0]], tags[t[1]], tags[t[2]], tags[t[3]]
            )?;
        }
        for (k, g) in self.groups.iter().enumerate() {
            if !g.tris.is_empty() {
                writeln!(w, "2 {} 2 {}", k + 1, g.tris.len())?;
                for t in &g.tris {
                    etag += 1;
                    writeln!(w, "{} {} {} {}", etag, tags[t[0]], tags[t[1]], tags[t[2]])?;
                }
            }
        }
        for &(ptag, i) in point_entities {
            etag += 1;
            writeln!(w, "0 {ptag} 15 1\n{etag} {}", tags[i])?;
        }
        writeln!(w, "$EndElements")
    }
}
