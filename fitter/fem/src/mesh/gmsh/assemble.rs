//! From the file's raw blocks to a validated [`Mesh`]: node numbering, tetrahedron orientation
//! and validity, physical groups.

use super::{element_type_name, MeshError, MshReport, RawMsh, ZERO_VOLUME_RATIO};
use crate::mesh::quadratic::QUADRATIC_EDGES;
use crate::mesh::Mesh;
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::Path;

/// Gmsh's element type of the 10-node (quadratic) tetrahedron.
const QUADRATIC_TET: i32 = 11;

pub(super) fn assemble(file: &Path, raw: RawMsh) -> Result<(Mesh, MshReport), MeshError> {
    let f = || file.to_path_buf();
    let mut report = MshReport::default();

    // All nodes by tag, in file order.
    let mut index_of: HashMap<u64, usize> = HashMap::new();
    let mut file_nodes: Vec<(u64, [f64; 3])> = Vec::new();
    for (_, _, block) in &raw.node_blocks {
        for &(tag, x) in block {
            if !x.iter().all(|v| v.is_finite()) {
                return Err(MeshError::NonFiniteNode {
                    file: f(),
                    node_tag: tag,
                    coords: x,
                });
            }
            if index_of.insert(tag, file_nodes.len()).is_some() {
                return Err(MeshError::DuplicateNode {
                    file: f(),
                    node_tag: tag,
                });
            }
            file_nodes.push((tag, x));
        }
    }
    let lookup = |element_tag: u64, node_tag: u64| {
        index_of
            .get(&node_tag)
            .copied()
            .ok_or(MeshError::UnknownNode {
                file: f(),
                element_tag,
                node_tag,
            })
    };

    // Tetrahedra (file node indices) and their tags; reject other volume elements. A 10-node
    // tetrahedron is read as its four corners (Gmsh lists them first), its edge nodes set
    // aside: palpate's linear models are built on the corners, and its quadratic ones lift the
    // corners' mesh with straight edges (`mesh::quadratic`), so how far an edge node stands off
    // its edge's midpoint is measured and reported — the curvature that straight edges drop.
    let mut tets: Vec<[usize; 4]> = Vec::new();
    let mut tet_tags: Vec<u64> = Vec::new();
    let mut edge_nodes: BTreeSet<usize> = BTreeSet::new();
    for b in &raw.element_blocks {
        if b.type_id == 4 || b.type_id == QUADRATIC_TET {
            for (tag, nodes) in &b.elements {
                let mut t = [0; 4];
                for (k, &n) in nodes.iter().enumerate().take(4) {
                    t[k] = lookup(*tag, n)?;
                }
                if b.type_id == QUADRATIC_TET {
                    report.quadratic_tets += 1;
                    for (k, &n) in nodes.iter().enumerate().skip(4).take(6) {
                        let m = lookup(*tag, n)?;
                        edge_nodes.insert(m);
                        let [a, c] = QUADRATIC_EDGES[k - 4].map(|v| file_nodes[t[v]].1);
                        let mid = [0, 1, 2].map(|d| 0.5 * (a[d] + c[d]));
                        let bow = dist(file_nodes[m].1, mid) / dist(a, c).max(f64::MIN_POSITIVE);
                        report.largest_edge_bow = report.largest_edge_bow.max(bow);
                    }
                }
                tets.push(t);
                tet_tags.push(*tag);
            }
        } else if b.dim == 3 {
            let element_tag = b.elements.first().map(|e| e.0).unwrap_or(0);
            return Err(MeshError::UnsupportedElement {
                file: f(),
                element_tag,
                type_id: b.type_id,
                type_name: element_type_name(b.type_id),
            });
        } else {
            report.boundary_elements += b.elements.len();
        }
    }
    if tets.is_empty() {
        return Err(MeshError::NoTetrahedra { file: f() });
    }

    // Orientation and zero volume.
    let mut reoriented = vec![false; tets.len()];
    for (e, t) in tets.iter_mut().enumerate() {
        let p = t.map(|i| file_nodes[i].1);
        let v = signed_volume(&p);
        let longest = (0..4)
            .flat_map(|a| (a + 1..4).map(move |b| (a, b)))
            .map(|(a, b)| dist(p[a], p[b]))
            .fold(0.0, f64::max);
        let limit = ZERO_VOLUME_RATIO * longest.powi(3);
        if v.abs() <= limit {
            return Err(MeshError::ZeroVolume {
                file: f(),
                element_tag: tet_tags[e],
                volume: v,
                limit,
            });
        }
        if v < 0.0 {
            t.swap(2, 3);
            reoriented[e] = true;
            report.reoriented += 1;
        }
    }
    check_folds(file, &tets, &tet_tags, &reoriented, &file_nodes)?;

    // Keep only nodes used by tetrahedra, in file order.
    let mut used = vec![false; file_nodes.len()];
    tets.iter().flatten().for_each(|&i| used[i] = true);
    let mut new_index = vec![usize::MAX; file_nodes.len()];
    let mut nodes = Vec::new();
    let mut node_tags = Vec::new();
    for (i, &(tag, x)) in file_nodes.iter().enumerate() {
        if used[i] {
            new_index[i] = nodes.len();
            nodes.push(x);
            node_tags.push(tag);
        }
    }
    report.edge_nodes = edge_nodes.iter().filter(|&&i| !used[i]).count();
    report.dropped_nodes = file_nodes.len() - nodes.len() - report.edge_nodes;
    let tets = tets.into_iter().map(|t| t.map(|i| new_index[i])).collect();

    // Physical groups → node sets by name.
    let names: HashMap<(i32, i32), &str> = raw
        .physical_names
        .iter()
        .map(|(d, t, n)| ((*d, *t), n.as_str()))
        .collect();
    let group_name = |dim: i32, tag: i32| {
        names
            .get(&(dim, tag))
            .map(|s| s.to_string())
            .unwrap_or(format!("group-{tag}"))
    };
    let mut sets: BTreeMap<String, BTreeSet<usize>> = BTreeMap::new();
    // Named groups exist even when no entity carries them (then they are empty).
    for (d, t, _) in &raw.physical_names {
        sets.entry(group_name(*d, *t)).or_default();
    }
    let mut add = |dim: i32, entity: i32, file_idx: &mut dyn Iterator<Item = usize>| {
        let Some((_, phys)) = raw
            .entity_physicals
            .iter()
            .find(|(k, _)| *k == (dim, entity))
        else {
            return;
        };
        let members: Vec<usize> = file_idx
            .filter(|&i| used[i])
            .map(|i| new_index[i])
            .collect();
        for &p in phys {
            sets.entry(group_name(dim, p.abs()))
                .or_default()
                .extend(members.iter().copied());
        }
    };
    for b in &raw.element_blocks {
        let mut it = b
            .elements
            .iter()
            .flat_map(|(_, ns)| ns.iter().filter_map(|n| index_of.get(n).copied()));
        add(b.dim, b.entity, &mut it);
    }
    for (dim, entity, block) in &raw.node_blocks {
        let mut it = block.iter().map(|(tag, _)| index_of[tag]);
        add(*dim, *entity, &mut it);
    }
    let node_groups = sets
        .into_iter()
        .map(|(k, v)| (k, v.into_iter().collect()))
        .collect();
    Ok((
        Mesh {
            nodes,
            node_tags,
            tets,
            node_groups,
        },
        report,
    ))
}

/// Every interior face must separate its two tetrahedra. With both oriented positive, the face
/// wound outward from one must appear with the opposite winding from the other; the same winding
/// means both lie on one side: the mesh folds (an inverted element).
fn check_folds(
    file: &Path,
    tets: &[[usize; 4]],
    tags: &[u64],
    reoriented: &[bool],
    nodes: &[(u64, [f64; 3])],
) -> Result<(), MeshError> {
    // Face opposite node k, wound outward for a positively oriented tetrahedron.
    const FACES: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];
    let mut seen: HashMap<[usize; 3], (usize, bool, u8)> = HashMap::new();
    let tag_face = |key: [usize; 3]| key.map(|i| nodes[i].0);
    for (e, t) in tets.iter().enumerate() {
        for f in FACES {
            let tri = [t[f[0]], t[f[1]], t[f[2]]];
            let mut key = tri;
            key.sort_unstable();
            let parity = is_even_permutation(tri, key);
            match seen.get_mut(&key) {
                None => {
                    seen.insert(key, (e, parity, 1));
                }
                Some((other, other_parity, count)) => {
                    *count += 1;
                    if *count > 2 {
                        return Err(MeshError::NonManifold {
                            file: file.to_path_buf(),
                            face: tag_face(key),
                            tags: vec![tags[*other], tags[e]],
                        });
                    }
                    if *other_parity == parity {
                        // Blame the one that was listed with the minority (re-oriented) sign.
                        let (bad, good) = if reoriented[e] && !reoriented[*other] {
                            (e, *other)
                        } else {
                            (*other, e)
                        };
                        let note = if reoriented[bad] != reoriented[good] {
                            format!(" (element {} was listed with the opposite orientation to its neighbour)", tags[bad])
                        } else {
                            String::new()
                        };
                        return Err(MeshError::Inverted {
                            file: file.to_path_buf(),
                            element_tag: tags[bad],
                            neighbour_tag: tags[good],
                            face: tag_face(key),
                            note,
                        });
                    }
                }
            }
        }
    }
    Ok(())
}

/// Whether `tri` is an even permutation (same cyclic order) of the sorted `key`.
fn is_even_permutation(tri: [usize; 3], key: [usize; 3]) -> bool {
    let pos = tri.map(|v| key.iter().position(|&k| k == v).unwrap_or(0));
    matches!(pos, [0, 1, 2] | [1, 2, 0] | [2, 0, 1])
}

pub(crate) fn signed_volume(p: &[[f64; 3]; 4]) -> f64 {
    crate::mesh::signed_volume(*p)
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}
