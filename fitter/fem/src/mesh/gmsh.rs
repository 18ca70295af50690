//! Gmsh MSH input (4.1 ASCII and binary, 2.2 ASCII) and MSH 4.1 output.
//!
//! [`read_msh`] reads tetrahedral meshes written by Gmsh or by other tools (meshio, older
//! pipelines) into a [`Mesh`] of linear tetrahedra: 4-node tetrahedra (element type 4), and
//! 10-node ones (type 11, `gmsh -order 2`) as their four corners. The version and file type on the `$MeshFormat` line
//! choose the parser:
//!
//! - **MSH 4.1 ASCII** files are parsed here, line by line, so that every error names the file,
//!   the line, what was expected and what was found. (mshio drops the node tags of densely
//!   numbered files, and palpate's CSV files name nodes by their Gmsh tags, so tags must survive
//!   exactly.)
//! - **MSH 4.1 binary** files are parsed by `mshio`; its errors are wrapped with the file name and
//!   the byte offset (and the line, counted in the ASCII header part). mshio keeps node tags only
//!   when they are sparse; for densely numbered files the tags are rebuilt as
//!   `min_tag + position`, block by block in file order, which is how Gmsh numbers the nodes it
//!   writes.
//! - **MSH 2.2 ASCII** (and 2.1, 2.0, whose ASCII grammar is the same for what is read here:
//!   `gmsh -format msh22`, meshio's `gmsh22`) is parsed here too, with the same line-precise
//!   errors. MSH 2 binary (`-bin`) is rewritten as the ASCII it stands for and read the same way
//!   (`binary22`; its errors name the byte). Other versions are rejected naming the version found.
//!
//! What is read:
//! - Node tags are kept in [`Mesh::node_tags`]. Nodes used by no tetrahedron are dropped (they would
//!   make the stiffness matrix singular) and counted in [`MshReport::dropped_nodes`].
//! - Every tetrahedron is oriented to positive volume: one listed with negative orientation has two
//!   nodes swapped and is counted in [`MshReport::reoriented`]. An element whose volume is zero
//!   (|V| ≤ [`ZERO_VOLUME_RATIO`] · ℓ³, ℓ its longest edge) is an error. An element is *inverted*
//!   when, after orientation, it lies on the same side of a face it shares with a neighbour (the mesh
//!   folds over itself): also an error, naming both element tags.
//! - A 10-node tetrahedron's edge nodes are set aside ([`MshReport::edge_nodes`]): palpate's
//!   linear models use the corners, and its quadratic ones (`mesh::quadratic`) put edge nodes
//!   back at the midpoints. How far the file's edge nodes stood off those midpoints is measured
//!   ([`MshReport::largest_edge_bow`]) and logged, as a warning above [`CURVED_EDGE`]: a curved
//!   boundary is then read with straight edges.
//! - Other volume element types (hexahedra, prisms, pyramids, …) are rejected; lower-dimensional
//!   elements (points, lines, triangles, quads, of either order) only feed the physical groups.
//! - Physical groups of dimension 0–3 become [`Mesh::node_groups`]: all nodes of all elements (and
//!   all nodes classified) on every entity of the group, by name (`$PhysicalNames`); a group without
//!   a name is called `group-<tag>`. Groups of the same name in different dimensions are merged.
//! - In MSH 2.2 the physical tag is written on each element (its first tag; 0 = none) and nodes are
//!   not classified on entities, so a group is all nodes of the elements that carry its tag, with
//!   the same naming and merging. Gmsh writes an element of several groups once per group; those
//!   repeats are read as one element in all of its groups.
//!
//! [`write_msh`] writes MSH 4.1 ASCII that [`read_msh`] and Gmsh read back; its layout is described
//! there.

mod ascii;
mod ascii22;
mod assemble;
mod binary;
mod binary22;
mod write;

pub use write::write_msh;

use super::Mesh;
use std::path::{Path, PathBuf};

/// Elements with |V| ≤ `ZERO_VOLUME_RATIO` · ℓ_max³ count as zero volume: a regular tetrahedron
/// has V/ℓ³ ≈ 0.118, so this only catches elements whose stiffness would be singular to working
/// precision, not merely poor ones.
pub const ZERO_VOLUME_RATIO: f64 = 1e-10;

/// What went wrong reading or writing a Gmsh file. Every variant names the file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MeshError {
    /// The file could not be read.
    #[error("{file}: cannot read: {source}")]
    Io {
        /// The file.
        file: PathBuf,
        /// The operating-system error.
        source: std::io::Error,
    },
    /// The ASCII text does not follow the MSH grammar (4.1 or 2.2), or its version or file type
    /// is not read.
    #[error("{file}:{line}: expected {expected}, found {found}")]
    Syntax {
        /// The file.
        file: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What the grammar expects there.
        expected: String,
        /// What the file holds there.
        found: String,
    },
    /// mshio rejected a binary file.
    #[error("{file}: binary MSH parse error at byte {offset} (line {line} counting newlines): {message}")]
    Binary {
        /// The file.
        file: PathBuf,
        /// Byte offset of the failure.
        offset: usize,
        /// Line number counted by newline bytes (meaningful in the ASCII parts of the file).
        line: usize,
        /// mshio's error chain.
        message: String,
    },
    /// A volume element of a type other than the 4- or 10-node tetrahedron.
    #[error(
        "{file}: element {element_tag} has Gmsh type {type_id} ({type_name}) in a volume; only tetrahedra are supported (type 4, or type 11 read as its corners)"
    )]
    UnsupportedElement {
        /// The file.
        file: PathBuf,
        /// Tag of the first offending element.
        element_tag: u64,
        /// Gmsh element type number.
        type_id: i32,
        /// Its name.
        type_name: &'static str,
    },
    /// The file holds no tetrahedra.
    #[error("{file}: no tetrahedra (type 4 or 11) in the file")]
    NoTetrahedra {
        /// The file.
        file: PathBuf,
    },
    /// Two nodes share a tag.
    #[error("{file}: node tag {node_tag} appears twice")]
    DuplicateNode {
        /// The file.
        file: PathBuf,
        /// The repeated tag.
        node_tag: u64,
    },
    /// A node coordinate is NaN or infinite.
    #[error("{file}: node {node_tag} has a non-finite coordinate {coords:?}")]
    NonFiniteNode {
        /// The file.
        file: PathBuf,
        /// The node's tag.
        node_tag: u64,
        /// Its coordinates as read.
        coords: [f64; 3],
    },
    /// An element refers to a node tag that no node block defines.
    #[error(
        "{file}: element {element_tag} refers to node {node_tag}, which is not defined in $Nodes"
    )]
    UnknownNode {
        /// The file.
        file: PathBuf,
        /// The element's tag.
        element_tag: u64,
        /// The undefined node tag.
        node_tag: u64,
    },
    /// A tetrahedron has (numerically) zero volume.
    #[error(
        "{file}: element {element_tag} has zero volume ({volume:.3e} m³; limit {limit:.3e} m³ = {ratio:e} × longest edge³)",
        ratio = ZERO_VOLUME_RATIO
    )]
    ZeroVolume {
        /// The file.
        file: PathBuf,
        /// The element's tag.
        element_tag: u64,
        /// Its signed volume as listed.
        volume: f64,
        /// The zero-volume limit for this element.
        limit: f64,
    },
    /// Two tetrahedra lie on the same side of their shared face: the mesh folds over itself.
    #[error(
        "{file}: element {element_tag} is inverted: it lies on the same side of face (nodes {face:?}) as element {neighbour_tag}{note}"
    )]
    Inverted {
        /// The file.
        file: PathBuf,
        /// The element judged inverted (the one listed with the minority orientation, if known).
        element_tag: u64,
        /// The neighbour it overlaps.
        neighbour_tag: u64,
        /// Node tags of the shared face.
        face: [u64; 3],
        /// Extra explanation.
        note: String,
    },
    /// More than two tetrahedra share one face.
    #[error("{file}: face (nodes {face:?}) is shared by more than two elements (e.g. {tags:?}): the mesh is not a manifold")]
    NonManifold {
        /// The file.
        file: PathBuf,
        /// Node tags of the face.
        face: [u64; 3],
        /// Element tags sharing it.
        tags: Vec<u64>,
    },
    /// The mesh handed to [`write_msh`] is inconsistent.
    #[error("{file}: cannot write mesh: {message}")]
    InvalidMesh {
        /// The file.
        file: PathBuf,
        /// Why.
        message: String,
    },
    /// Writing failed.
    #[error("{file}: cannot write: {message}")]
    Write {
        /// The file.
        file: PathBuf,
        /// The underlying error chain.
        message: String,
    },
    /// A physical group the caller needs is not in the mesh.
    #[error("no physical group named {name:?} in the mesh (groups present: {present})")]
    NoGroup {
        /// The group asked for.
        name: String,
        /// Comma-separated groups the mesh has.
        present: String,
    },
}

/// The edge bow ([`MshReport::largest_edge_bow`]) above which a 10-node mesh's edges are curved
/// enough for a warning: a per-cent of an edge's length is about what a tenth of a millimetre
/// is to a 1 cm element, the size of a capture's marker noise.
pub const CURVED_EDGE: f64 = 0.01;

/// What [`read_msh_with_report`] did besides reading.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MshReport {
    /// Tetrahedra listed with negative orientation and re-oriented (two nodes swapped).
    pub reoriented: usize,
    /// Nodes used by no tetrahedron, dropped (a 10-node tetrahedron's edge nodes apart).
    pub dropped_nodes: usize,
    /// 10-node tetrahedra (Gmsh type 11) read as their four corners.
    pub quadratic_tets: usize,
    /// Their edge nodes, set aside (no linear tetrahedron uses them).
    pub edge_nodes: usize,
    /// The largest distance of an edge node from its edge's midpoint, over the edge's length:
    /// 0 for straight edges; what reading the corners with straight edges drops.
    pub largest_edge_bow: f64,
    /// Lower-dimensional elements (points, lines, surface elements) read for the groups.
    pub boundary_elements: usize,
    /// Whether the file was binary.
    pub binary: bool,
}

/// Reads a Gmsh mesh of tetrahedra (4-node; 10-node as their corners): MSH 4.1 or MSH 2.2 (also
/// 2.1 and 2.0), ASCII or binary, told apart by the `$MeshFormat` line. Other versions are errors
/// that name the version found. See the module docs for what is read and how groups are formed.
pub fn read_msh(path: impl AsRef<Path>) -> Result<Mesh, MeshError> {
    read_msh_with_report(path).map(|(m, _)| m)
}

/// Like [`read_msh`], also saying what was re-oriented or dropped.
pub fn read_msh_with_report(path: impl AsRef<Path>) -> Result<(Mesh, MshReport), MeshError> {
    let file = path.as_ref().to_path_buf();
    let bytes = std::fs::read(&file).map_err(|source| MeshError::Io {
        file: file.clone(),
        source,
    })?;
    let format = ascii::mesh_format(&file, &bytes)?;
    let raw = match format {
        ascii::MshFormat::V41Ascii => ascii::parse(&file, &bytes)?,
        ascii::MshFormat::V41Binary => binary::parse(&file, &bytes)?,
        ascii::MshFormat::V2Ascii => ascii22::parse(&file, &bytes)?,
        ascii::MshFormat::V2Binary => {
            ascii22::parse(&file, binary22::to_ascii(&file, &bytes)?.as_bytes())?
        }
    };
    let (mesh, mut report) = assemble::assemble(&file, raw)?;
    report.binary = matches!(
        format,
        ascii::MshFormat::V41Binary | ascii::MshFormat::V2Binary
    );
    if report.quadratic_tets > 0 {
        let read = format!(
            "{}: {} 10-node tetrahedra read as their corners ({} edge nodes set aside)",
            file.display(),
            report.quadratic_tets,
            report.edge_nodes
        );
        if report.largest_edge_bow > CURVED_EDGE {
            log::warn!(
                "{read}; their edges are curved, an edge node up to {:.1} % of its edge's length \
                 off the midpoint, and palpate takes them straight: the boundary's curvature \
                 between corners is lost (a finer mesh keeps more of it in its corners)",
                100.0 * report.largest_edge_bow
            );
        } else {
            log::info!(
                "{read}; their edges are straight (edge nodes within {:.2e} of an edge's length \
                 of its midpoint)",
                report.largest_edge_bow
            );
        }
    }
    Ok((mesh, report))
}

/// The file's content before it becomes a [`Mesh`]: shared by the ASCII (4.1 and 2.2) and the
/// binary parser.
#[derive(Debug, Default)]
struct RawMsh {
    /// (dimension, physical tag, name).
    physical_names: Vec<(i32, i32, String)>,
    /// (dimension, entity tag) → physical tags.
    entity_physicals: Vec<((i32, i32), Vec<i32>)>,
    /// Node blocks: (dimension, entity tag, [(node tag, xyz)]).
    node_blocks: Vec<NodeBlock>,
    /// Element blocks.
    element_blocks: Vec<RawElements>,
}

/// (dimension, entity tag, [(node tag, xyz)]).
type NodeBlock = (i32, i32, Vec<(u64, [f64; 3])>);

#[derive(Debug)]
struct RawElements {
    dim: i32,
    entity: i32,
    type_id: i32,
    /// (element tag, node tags).
    elements: Vec<(u64, Vec<u64>)>,
}

/// Gmsh's name for an element type (the common ones; others print as "other").
fn element_type_name(type_id: i32) -> &'static str {
    match type_id {
        1 => "2-node line",
        2 => "3-node triangle",
        3 => "4-node quadrangle",
        4 => "4-node tetrahedron",
        5 => "8-node hexahedron",
        6 => "6-node prism",
        7 => "5-node pyramid",
        8 => "3-node line",
        9 => "6-node triangle",
        10 => "9-node quadrangle",
        11 => "10-node tetrahedron",
        12 => "27-node hexahedron",
        13 => "18-node prism",
        14 => "14-node pyramid",
        15 => "1-node point",
        16 => "8-node quadrangle",
        17 => "20-node hexahedron",
        18 => "15-node prism",
        19 => "13-node pyramid",
        29 => "20-node tetrahedron",
        _ => "other",
    }
}

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_msh22;
