//! VTK output for ParaView and other readers (meshio, VTK itself): an unstructured grid of linear
//! tetrahedra with per-node and per-element data.
//!
//! The points are always the mesh's **rest** positions; a deformation goes in as a point-data
//! vector named [`DISPLACEMENT`]. That is what ParaView users expect: *Warp By Vector* adds the
//! vector to the points, so deformed points plus a displacement would show the deformation twice.
//!
//! The format follows the file extension: `.vtu` writes VTK XML version 1.0 (what ParaView
//! prefers), `.vtk` writes the legacy binary format 4.1 (big-endian, as the legacy format
//! requires). Both go through [`crate::io::atomic`]; the tests re-read both with `vtkio` and the
//! `.vtu` with a plain XML parser as well.
//!
//! Every file also carries the Gmsh node tag ([`NODE_TAG`]), so a value seen in ParaView can be
//! traced back to the mesh file and to palpate's CSV files. Arrays that more than one writer
//! produces take their names from the constants here, so one quantity has one name in every file.

use super::Mesh;
use crate::io::atomic::write_atomic_with;
use std::path::{Path, PathBuf};
use vtkio::model::{
    Attribute, Attributes, ByteOrder, CellType, Cells, DataArray, DataSet, UnstructuredGridPiece,
    Version, VertexNumbers, Vtk,
};

/// Point-data vector: displacement from the rest position, m.
pub const DISPLACEMENT: &str = "displacement";
/// Cell-data scalar: Young's modulus E, Pa.
pub const YOUNG_MODULUS: &str = "young_modulus_pa";
/// Cell-data scalar: Poisson's ratio ν (dimensionless).
pub const POISSON_RATIO: &str = "poisson_ratio";
/// Point-data scalar added to every file: the node's Gmsh tag (1-based index if the mesh has none).
pub const NODE_TAG: &str = "node_tag";

/// Values of one data array: one per node (point data) or one per tetrahedron (cell data).
#[derive(Debug, Clone, Copy)]
pub enum Values<'a> {
    /// One number each (e.g. E, ν, error norm).
    Scalar(&'a [f64]),
    /// One 3-vector each (e.g. displacement).
    Vector(&'a [[f64; 3]]),
}

impl Values<'_> {
    fn len(&self) -> usize {
        match self {
            Values::Scalar(v) => v.len(),
            Values::Vector(v) => v.len(),
        }
    }
}

/// A named data array.
#[derive(Debug, Clone, Copy)]
pub struct Field<'a> {
    /// Array name as ParaView shows it.
    pub name: &'a str,
    /// The values.
    pub values: Values<'a>,
}

impl<'a> Field<'a> {
    /// A scalar array.
    pub fn scalar(name: &'a str, values: &'a [f64]) -> Self {
        Field {
            name,
            values: Values::Scalar(values),
        }
    }
    /// A 3-vector array.
    pub fn vector(name: &'a str, values: &'a [[f64; 3]]) -> Self {
        Field {
            name,
            values: Values::Vector(values),
        }
    }
}

/// Why a VTK file was not written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum VtkError {
    /// The extension is neither `.vtu` nor `.vtk`.
    #[error("{file}: unknown VTK extension: expected .vtu (XML) or .vtk (legacy)")]
    Extension {
        /// The file.
        file: PathBuf,
    },
    /// An array has the wrong number of entries.
    #[error("{file}: array {name:?} ({kind}) has {found} entries, expected {expected}")]
    Length {
        /// The file.
        file: PathBuf,
        /// Array name.
        name: String,
        /// "point data" or "cell data".
        kind: &'static str,
        /// Entries needed.
        expected: usize,
        /// Entries given.
        found: usize,
    },
    /// Writing failed.
    #[error("{file}: cannot write: {message}")]
    Write {
        /// The file.
        file: PathBuf,
        /// The underlying error chain.
        message: String,
    },
}

/// Writes `mesh`'s tetrahedra at their rest positions with `point_data` (one value per node, e.g.
/// a [`DISPLACEMENT`] vector) and `cell_data` (one value per tetrahedron).
pub fn write_vtk(
    path: impl AsRef<Path>,
    mesh: &Mesh,
    point_data: &[Field],
    cell_data: &[Field],
) -> Result<(), VtkError> {
    let path = path.as_ref();
    let file = || path.to_path_buf();
    let xml = match path.extension().and_then(|e| e.to_str()) {
        Some("vtu") => true,
        Some("vtk") => false,
        _ => return Err(VtkError::Extension { file: file() }),
    };
    let (n, ne) = (mesh.nodes.len(), mesh.tets.len());
    let check = |name: &str, kind: &'static str, expected: usize, found: usize| {
        if expected == found {
            Ok(())
        } else {
            Err(VtkError::Length {
                file: file(),
                name: name.to_string(),
                kind,
                expected,
                found,
            })
        }
    };
    for f in point_data {
        check(f.name, "point data", n, f.values.len())?;
    }
    for f in cell_data {
        check(f.name, "cell data", ne, f.values.len())?;
    }

    let to_attr = |f: &Field| match f.values {
        Values::Scalar(v) => {
            Attribute::DataArray(DataArray::scalars(f.name, 1).with_data(v.to_vec()))
        }
        Values::Vector(v) => Attribute::DataArray(
            DataArray::vectors(f.name).with_data(v.iter().flatten().copied().collect::<Vec<f64>>()),
        ),
    };
    let mut point: Vec<Attribute> = point_data.iter().map(to_attr).collect();
    let tags: Vec<f64> = if mesh.node_tags.len() == n {
        mesh.node_tags.iter().map(|&t| t as f64).collect()
    } else {
        (1..=n).map(|t| t as f64).collect()
    };
    point.push(Attribute::DataArray(
        DataArray::scalars(NODE_TAG, 1).with_data(tags),
    ));
    let cell: Vec<Attribute> = cell_data.iter().map(to_attr).collect();

    let cell_verts = if xml {
        VertexNumbers::XML {
            connectivity: mesh.tets.iter().flatten().map(|&i| i as u64).collect(),
            offsets: (1..=ne as u64).map(|k| 4 * k).collect(),
        }
    } else {
        VertexNumbers::Legacy {
            num_cells: ne as u32,
            vertices: mesh
                .tets
                .iter()
                .flat_map(|t| [4, t[0] as u32, t[1] as u32, t[2] as u32, t[3] as u32])
                .collect(),
        }
    };
    let vtk = Vtk {
        // The XML formats have their own version numbers ("0.1", "1.0", "2.2"): "4.1" is the
        // legacy `.vtk` one, and meshio refuses it in a `.vtu`. 1.0 rather than 0.1 because
        // vtkio writes `header_type="UInt64"` (64-bit byte counts before each binary array),
        // which came with XML version 1.0; 0.1 readers assume 32-bit counts.
        version: if xml {
            Version::new((1, 0))
        } else {
            Version::new((4, 1))
        },
        title: "palpate".to_string(),
        byte_order: ByteOrder::BigEndian,
        file_path: None,
        data: DataSet::inline(UnstructuredGridPiece {
            points: mesh
                .nodes
                .iter()
                .flatten()
                .copied()
                .collect::<Vec<f64>>()
                .into(),
            cells: Cells {
                cell_verts,
                types: vec![CellType::Tetra; ne],
            },
            data: Attributes { point, cell },
        }),
    };
    write_atomic_with(path, |w| {
        if xml {
            vtk.write_xml(w)
        } else {
            vtk.write_legacy(w)
        }
        .map_err(std::io::Error::other)
    })
    .map_err(|e| VtkError::Write {
        file: file(),
        message: format!("{e:#}"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::boxmesh::box_mesh;
    use vtkio::model::IOBuffer;

    /// A box, a displacement of it, a per-node scalar and per-element E, ν.
    struct Sample {
        mesh: Mesh,
        u: Vec<[f64; 3]>,
        err: Vec<f64>,
        young: Vec<f64>,
        nu: Vec<f64>,
    }

    fn sample() -> Sample {
        let mesh = box_mesh([0.1, 0.1, 0.05], [2, 2, 1]);
        let u = mesh
            .nodes
            .iter()
            .map(|p| [0.01 * p[2], 0.0, -0.1 * p[0] * p[1]])
            .collect();
        let err = (0..mesh.nodes.len()).map(|i| i as f64 * 1e-4).collect();
        let young = (0..mesh.tets.len()).map(|e| 1e4 + e as f64).collect();
        let nu = (0..mesh.tets.len())
            .map(|e| 0.3 + 1e-3 * e as f64)
            .collect();
        Sample {
            mesh,
            u,
            err,
            young,
            nu,
        }
    }

    fn write(s: &Sample, path: &Path) {
        write_vtk(
            path,
            &s.mesh,
            &[
                Field::vector(DISPLACEMENT, &s.u),
                Field::scalar("error", &s.err),
            ],
            &[
                Field::scalar(YOUNG_MODULUS, &s.young),
                Field::scalar(POISSON_RATIO, &s.nu),
            ],
        )
        .unwrap();
    }

    /// Writes the sample, re-reads it with vtkio and compares every array exactly (both formats
    /// store f64): the points are the rest positions, the displacement is its own array.
    fn round_trip(ext: &str) {
        let s = sample();
        let m = &s.mesh;
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join(format!("out.{ext}"));
        write(&s, &p);
        assert!(std::fs::metadata(&p).unwrap().len() > 1000);

        let vtk = Vtk::import(&p).unwrap();
        let DataSet::UnstructuredGrid { pieces, .. } = vtk.data else {
            panic!("not an unstructured grid")
        };
        let piece = pieces
            .into_iter()
            .next()
            .unwrap()
            .into_loaded_piece_data(None)
            .unwrap();
        let pts: Vec<f64> = piece.points.cast_into().unwrap();
        assert_eq!(pts, m.nodes.iter().flatten().copied().collect::<Vec<_>>());
        let (conn, _) = piece.cells.cell_verts.into_xml();
        assert_eq!(
            conn,
            m.tets
                .iter()
                .flatten()
                .map(|&i| i as u64)
                .collect::<Vec<_>>()
        );
        assert!(
            piece.cells.types.iter().all(|t| *t == CellType::Tetra)
                && piece.cells.types.len() == m.tets.len()
        );
        let array = |attrs: &[Attribute], name: &str| -> Vec<f64> {
            attrs
                .iter()
                .find_map(|a| match a {
                    Attribute::DataArray(d) if d.name == name => Some(d.data.clone()),
                    _ => None,
                })
                .map(|b: IOBuffer| b.cast_into().unwrap())
                .unwrap_or_else(|| panic!("no array {name}"))
        };
        assert_eq!(
            array(&piece.data.point, DISPLACEMENT),
            s.u.iter().flatten().copied().collect::<Vec<_>>()
        );
        assert_eq!(array(&piece.data.point, "error"), s.err);
        assert_eq!(
            array(&piece.data.point, NODE_TAG),
            m.node_tags.iter().map(|&t| t as f64).collect::<Vec<_>>()
        );
        assert_eq!(array(&piece.data.cell, YOUNG_MODULUS), s.young);
        assert_eq!(array(&piece.data.cell, POISSON_RATIO), s.nu);
    }

    #[test]
    fn vtu_round_trips_through_vtkio() {
        round_trip("vtu");
    }

    #[test]
    fn legacy_vtk_round_trips_through_vtkio() {
        round_trip("vtk");
    }

    /// The `.vtu` as a plain XML parser sees it (what meshio and VTK check before reading any
    /// value): an XML-format version, not the legacy 4.1; counts matching the mesh; every array
    /// named, typed and with the number of components readers use to shape it. The values
    /// themselves are decoded in the CLI's test of `palpate simulate`'s file.
    #[test]
    fn vtu_declares_an_xml_version_and_shapes_every_array() {
        let s = sample();
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("out.vtu");
        write(&s, &p);
        let text = std::fs::read_to_string(&p).unwrap();
        let doc = roxmltree::Document::parse(&text).unwrap();
        let root = doc.root_element();
        assert_eq!(root.tag_name().name(), "VTKFile");
        assert_eq!(root.attribute("type"), Some("UnstructuredGrid"));
        assert_eq!(root.attribute("version"), Some("1.0"));
        // A version-1.0 reader takes the byte-count width from here (UInt32 if absent).
        assert!(matches!(
            root.attribute("header_type"),
            Some("UInt32" | "UInt64")
        ));
        let piece = root
            .descendants()
            .find(|n| n.has_tag_name("Piece"))
            .unwrap();
        assert_eq!(
            piece.attribute("NumberOfPoints"),
            Some(s.mesh.nodes.len().to_string().as_str())
        );
        assert_eq!(
            piece.attribute("NumberOfCells"),
            Some(s.mesh.tets.len().to_string().as_str())
        );
        let arrays = |section: &str| -> Vec<(String, String)> {
            piece
                .children()
                .find(|n| n.has_tag_name(section))
                .unwrap_or_else(|| panic!("no {section}"))
                .children()
                .filter(|n| n.has_tag_name("DataArray"))
                .map(|a| {
                    (
                        a.attribute("Name").unwrap_or("").to_string(),
                        a.attribute("NumberOfComponents").unwrap_or("1").to_string(),
                    )
                })
                .collect()
        };
        let named = |v: &[(&str, &str)]| -> Vec<(String, String)> {
            v.iter()
                .map(|(a, b)| (a.to_string(), b.to_string()))
                .collect()
        };
        assert_eq!(
            arrays("PointData"),
            named(&[(DISPLACEMENT, "3"), ("error", "1"), (NODE_TAG, "1")])
        );
        assert_eq!(
            arrays("CellData"),
            named(&[(YOUNG_MODULUS, "1"), (POISSON_RATIO, "1")])
        );
        assert_eq!(arrays("Points").len(), 1);
        assert_eq!(
            arrays("Points")[0].1,
            "3",
            "points are 3-vectors: {:?}",
            arrays("Points")
        );
        let cells: Vec<String> = arrays("Cells").into_iter().map(|(n, _)| n).collect();
        assert_eq!(cells, ["connectivity", "offsets", "types"]);
    }

    #[test]
    fn wrong_lengths_and_extensions_are_named() {
        let m = box_mesh([1.0, 1.0, 1.0], [1, 1, 1]);
        let short = vec![0.0; 3];
        let e = write_vtk("/tmp/x.vtu", &m, &[], &[Field::scalar("E", &short)])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("/tmp/x.vtu: array \"E\" (cell data) has 3 entries, expected 6"),
            "{e}"
        );
        let e = write_vtk("/tmp/x.txt", &m, &[], &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("x.txt: unknown VTK extension"), "{e}");
    }
}
