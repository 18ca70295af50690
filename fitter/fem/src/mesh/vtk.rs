//! VTK output for ParaView: an unstructured grid of linear tetrahedra at given (e.g. deformed)
//! node positions, with per-node and per-element data.
//!
//! The format follows the file extension: `.vtu` writes VTK XML (what ParaView prefers),
//! `.vtk` writes the legacy binary format (big-endian, as the legacy format requires). Both go
//! through [`crate::io::atomic`] and both are re-read by `vtkio` in the tests.
//!
//! Every point-data array also comes with the Gmsh node tag (`node_tag`), so a value seen in
//! ParaView can be traced back to the mesh file and to palpate's CSV files.

use super::Mesh;
use crate::io::atomic::write_atomic_with;
use std::path::{Path, PathBuf};
use vtkio::model::{
    Attribute, Attributes, ByteOrder, CellType, Cells, DataArray, DataSet, UnstructuredGridPiece,
    Version, VertexNumbers, Vtk,
};

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
        /// Array name ("positions" for the node positions).
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

/// Writes `mesh`'s tetrahedra at node `positions` (one per node, e.g. rest + displacement) with
/// `point_data` (one value per node) and `cell_data` (one value per tetrahedron).
pub fn write_vtk(
    path: impl AsRef<Path>,
    mesh: &Mesh,
    positions: &[[f64; 3]],
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
    check("positions", "point data", n, positions.len())?;
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
        DataArray::scalars("node_tag", 1).with_data(tags),
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
        // legacy `.vtk` one, and meshio refuses it in a `.vtu`.
        version: if xml {
            Version::new((1, 0))
        } else {
            Version::new((4, 1))
        },
        title: "palpate".to_string(),
        byte_order: ByteOrder::BigEndian,
        file_path: None,
        data: DataSet::inline(UnstructuredGridPiece {
            points: positions
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

    /// Writes a deformed box with a displacement vector, a per-node scalar and per-element E, ν,
    /// re-reads it with vtkio and compares every array exactly (both formats store f64).
    fn round_trip(ext: &str) {
        let m = box_mesh([0.1, 0.1, 0.05], [2, 2, 1]);
        let u: Vec<[f64; 3]> = m
            .nodes
            .iter()
            .map(|p| [0.01 * p[2], 0.0, -0.1 * p[0] * p[1]])
            .collect();
        let x: Vec<[f64; 3]> = m
            .nodes
            .iter()
            .zip(&u)
            .map(|(p, d)| [p[0] + d[0], p[1] + d[1], p[2] + d[2]])
            .collect();
        let err: Vec<f64> = (0..m.nodes.len()).map(|i| i as f64 * 1e-4).collect();
        let young: Vec<f64> = (0..m.tets.len()).map(|e| 1e4 + e as f64).collect();
        let nu: Vec<f64> = (0..m.tets.len()).map(|e| 0.3 + 1e-3 * e as f64).collect();
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join(format!("out.{ext}"));
        write_vtk(
            &p,
            &m,
            &x,
            &[
                Field::vector("displacement", &u),
                Field::scalar("error", &err),
            ],
            &[Field::scalar("E", &young), Field::scalar("nu", &nu)],
        )
        .unwrap();
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
        assert_eq!(pts, x.iter().flatten().copied().collect::<Vec<_>>());
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
            array(&piece.data.point, "displacement"),
            u.iter().flatten().copied().collect::<Vec<_>>()
        );
        assert_eq!(array(&piece.data.point, "error"), err);
        assert_eq!(
            array(&piece.data.point, "node_tag"),
            m.node_tags.iter().map(|&t| t as f64).collect::<Vec<_>>()
        );
        assert_eq!(array(&piece.data.cell, "E"), young);
        assert_eq!(array(&piece.data.cell, "nu"), nu);
    }

    #[test]
    fn vtu_round_trips_through_vtkio() {
        round_trip("vtu");
    }

    #[test]
    fn legacy_vtk_round_trips_through_vtkio() {
        round_trip("vtk");
    }

    #[test]
    fn wrong_lengths_and_extensions_are_named() {
        let m = box_mesh([1.0, 1.0, 1.0], [1, 1, 1]);
        let short = vec![0.0; 3];
        let e = write_vtk(
            "/tmp/x.vtu",
            &m,
            &m.nodes,
            &[],
            &[Field::scalar("E", &short)],
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("\"E\" (cell data) has 3 entries, expected 6"),
            "{e}"
        );
        let e = write_vtk("/tmp/x.txt", &m, &m.nodes, &[], &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("x.txt: unknown VTK extension"), "{e}");
    }
}
