//! Every kind of `.vtu` the `palpate` program writes, read the way another program would: with a
//! plain XML parser (roxmltree) and the VTK XML format's own rules for decoding inline binary
//! arrays, not with vtkio, the library that wrote them (a reader shares its writer's mistakes).
//!
//! The rules checked are the ones meshio and VTK apply: a `VTKFile` of type `UnstructuredGrid`
//! with an XML-format version (meshio refuses the legacy "4.1"), counts that match the mesh, and
//! the convention ParaView users expect: points at the rest positions plus a `displacement`
//! vector, so Warp By Vector shows the deformation once.

use crate::common;

use common::{assert_fit_written, assert_succeeded, fit_sponge, palpate, repo};
use std::collections::HashMap;
use std::path::Path;

use palpate_fem::mesh::{gmsh::read_msh, vtk, Mesh};

/// One decoded `DataArray`.
struct Array {
    components: usize,
    values: Vec<f64>,
}

/// A `.vtu` file's structure and arrays, decoded from the XML alone.
struct Vtu {
    version: String,
    points: usize,
    cells: usize,
    /// `(section, name)` → array, for the sections `Points`, `Cells`, `PointData`, `CellData`
    /// (the `Points` array under the name "").
    arrays: HashMap<(String, String), Array>,
}

impl Vtu {
    fn array(&self, section: &str, name: &str) -> &Array {
        self.arrays
            .get(&(section.to_string(), name.to_string()))
            .unwrap_or_else(|| panic!("no DataArray {name:?} in {section}"))
    }
}

/// Reads `path` as VTK XML: inline arrays, `ascii` or `binary` (base64 of a byte-count header of
/// `header_type`, UInt32 if absent, then the values in `byte_order`). Panics naming the file on
/// anything a VTK reader would refuse, including compressed or appended data (palpate writes
/// neither).
fn read_vtu(path: &Path) -> Vtu {
    let file = path.display();
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{file}: cannot read: {e}"));
    let doc = roxmltree::Document::parse(&text).unwrap_or_else(|e| panic!("{file}: not XML: {e}"));
    let root = doc.root_element();
    assert_eq!(root.tag_name().name(), "VTKFile", "{file}");
    assert_eq!(root.attribute("type"), Some("UnstructuredGrid"), "{file}");
    assert_eq!(root.attribute("compressor"), None, "{file}");
    let version = root.attribute("version").unwrap_or("").to_string();
    let big = match root.attribute("byte_order") {
        Some("BigEndian") => true,
        Some("LittleEndian") => false,
        b => panic!("{file}: byte_order {b:?}"),
    };
    let header = match root.attribute("header_type") {
        Some("UInt64") => 8,
        None | Some("UInt32") => 4,
        h => panic!("{file}: header_type {h:?}"),
    };
    let word = |b: &[u8]| -> u64 {
        let mut v = 0u64;
        for k in 0..b.len() {
            let byte = if big { b[k] } else { b[b.len() - 1 - k] };
            v = (v << 8) | u64::from(byte);
        }
        v
    };
    let grid = root
        .children()
        .find(|n| n.has_tag_name("UnstructuredGrid"))
        .unwrap_or_else(|| panic!("{file}: no UnstructuredGrid element"));
    let pieces: Vec<_> = grid
        .children()
        .filter(|n| n.has_tag_name("Piece"))
        .collect();
    assert_eq!(pieces.len(), 1, "{file}: one Piece");
    let piece = pieces[0];
    let count = |attr: &str| -> usize {
        piece
            .attribute(attr)
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("{file}: Piece {attr}"))
    };
    let mut arrays = HashMap::new();
    for section in piece.children().filter(|n| n.is_element()) {
        let sname = section.tag_name().name().to_string();
        for a in section.children().filter(|n| n.has_tag_name("DataArray")) {
            let name = a.attribute("Name").unwrap_or("").to_string();
            let what = format!("{file}: {sname}/{name:?}");
            let components: usize = a
                .attribute("NumberOfComponents")
                .unwrap_or("1")
                .parse()
                .unwrap_or_else(|e| panic!("{what}: NumberOfComponents: {e}"));
            let body = a.text().unwrap_or("").trim();
            let ty = a
                .attribute("type")
                .unwrap_or_else(|| panic!("{what}: no type"));
            let values: Vec<f64> = match a.attribute("format") {
                Some("ascii") => body
                    .split_whitespace()
                    .map(|v| v.parse().unwrap_or_else(|e| panic!("{what}: {v:?}: {e}")))
                    .collect(),
                Some("binary") => {
                    let bytes =
                        base64::decode(body).unwrap_or_else(|e| panic!("{what}: base64: {e}"));
                    let n = word(&bytes[..header]) as usize;
                    assert_eq!(bytes.len(), header + n, "{what}: byte count");
                    let size = match ty {
                        "Float64" | "Int64" | "UInt64" => 8,
                        "Float32" | "Int32" | "UInt32" => 4,
                        "Int16" | "UInt16" => 2,
                        "Int8" | "UInt8" => 1,
                        t => panic!("{what}: type {t}"),
                    };
                    assert_eq!(n % size, 0, "{what}: {n} bytes of {ty}");
                    bytes[header..]
                        .chunks(size)
                        .map(|c| {
                            let w = word(c);
                            match ty {
                                "Float64" => f64::from_bits(w),
                                "Float32" => f64::from(f32::from_bits(w as u32)),
                                // Signed integers: sign-extend from the value's width.
                                t if t.starts_with("Int") => {
                                    let shift = 64 - 8 * size as u32;
                                    (((w << shift) as i64) >> shift) as f64
                                }
                                _ => w as f64,
                            }
                        })
                        .collect()
                }
                f => panic!("{what}: format {f:?} (palpate writes inline arrays)"),
            };
            arrays.insert((sname.clone(), name), Array { components, values });
        }
    }
    Vtu {
        version,
        points: count("NumberOfPoints"),
        cells: count("NumberOfCells"),
        arrays,
    }
}

/// Reads the `.vtu` at `path` and the mesh it was written from (`msh`) and checks what every
/// `.vtu` palpate writes must satisfy: an XML version, the counts, the points at the rest
/// positions (to `rel`), the cells as the mesh's tetrahedra (VTK type 10) with offsets 4, 8, …,
/// and the Gmsh node tags.
fn read_checked_grid(path: &Path, msh: &Path, rel: f64) -> (Vtu, Mesh) {
    let v = read_vtu(path);
    let mesh = read_msh(msh).unwrap();
    let file = path.display();
    assert!(
        ["0.1", "1.0", "2.2"].contains(&v.version.as_str()),
        "{file}: version {:?} is not a VTK XML version",
        v.version
    );
    let (np, nc) = (mesh.nodes.len(), mesh.tets.len());
    assert_eq!((v.points, v.cells), (np, nc), "{file}: points, cells");
    let pts = v.array("Points", "");
    assert_eq!((pts.components, pts.values.len()), (3, 3 * np), "{file}");
    for (i, (p, r)) in pts.values.chunks(3).zip(&mesh.nodes).enumerate() {
        for k in 0..3 {
            assert!(
                (p[k] - r[k]).abs() <= rel * r[k].abs() + 1e-12,
                "{file}: point {i} is {p:?}, the rest position is {r:?}"
            );
        }
    }
    let conn = &v.array("Cells", "connectivity").values;
    let offsets = &v.array("Cells", "offsets").values;
    let types = &v.array("Cells", "types").values;
    assert_eq!(
        (conn.len(), offsets.len(), types.len()),
        (4 * nc, nc, nc),
        "{file}"
    );
    assert!(types.iter().all(|&t| t == 10.0), "{file}: VTK_TETRA");
    assert!(
        offsets
            .iter()
            .enumerate()
            .all(|(k, &o)| o == (4 * (k + 1)) as f64),
        "{file}: offsets"
    );
    let tets: Vec<f64> = mesh.tets.iter().flatten().map(|&i| i as f64).collect();
    assert_eq!(*conn, tets, "{file}: connectivity");
    let tags = v.array("PointData", vtk::NODE_TAG);
    assert_eq!(tags.components, 1, "{file}");
    assert_eq!(
        tags.values,
        mesh.node_tags.iter().map(|&t| t as f64).collect::<Vec<_>>(),
        "{file}: node tags"
    );
    (v, mesh)
}

/// `palpate simulate`'s `deformed.vtu`: the rest mesh, a 3-component `displacement` equal to
/// `displacements.csv` (the deformed position minus the rest one) at every node, and
/// `young_modulus_pa` per cell.
#[test]
fn simulate_writes_a_vtu_other_readers_accept() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sim");
    let msh = repo().join("models/sponge/sponge.msh");
    let o = palpate()
        .args(["simulate", "--mesh"])
        .arg(&msh)
        .args(["--young", "2e4", "--poisson", "0.3", "--fixed", "bottom"])
        .args(["--contact", "0.05,0.05,0.05", "--force", "0,0,-0.5", "-o"])
        .arg(&out)
        .output()
        .unwrap();
    assert_succeeded(&o);
    let path = out.join("deformed.vtu");
    // The runtime keeps f32 positions: the points equal the mesh to f32 precision.
    let (v, mesh) = read_checked_grid(&path, &msh, 1e-7);

    let u = v.array("PointData", vtk::DISPLACEMENT);
    assert_eq!((u.components, u.values.len()), (3, 3 * mesh.nodes.len()));
    assert!(
        u.values.iter().any(|d| d.abs() > 1e-6),
        "the load moves the sponge"
    );
    let csv = std::fs::read_to_string(out.join("displacements.csv")).unwrap();
    let index: HashMap<u64, usize> = mesh
        .node_tags
        .iter()
        .enumerate()
        .map(|(i, &t)| (t, i))
        .collect();
    let mut rows = 0;
    for line in csv.lines().skip(1) {
        let f: Vec<f64> = line.split(',').map(|x| x.trim().parse().unwrap()).collect();
        let i = index[&(f[0] as u64)];
        for k in 0..3 {
            let (vtu, csv) = (u.values[3 * i + k], f[1 + k]);
            // Both come from the runtime's f32 displacement: equal to f32 precision.
            assert!(
                (vtu - csv).abs() <= 1e-6 * csv.abs() + 1e-12,
                "node tag {}, component {k}: vtu {vtu}, csv {csv}",
                f[0]
            );
        }
        rows += 1;
    }
    assert_eq!(rows, mesh.nodes.len(), "one CSV row per node");

    let e = v.array("CellData", vtk::YOUNG_MODULUS);
    assert_eq!(e.components, 1);
    assert!(
        e.values.iter().all(|&x| (x - 2e4).abs() < 1.0),
        "E per cell"
    );
}

/// `palpate fit`'s `fit.vtu` (in the report folder): the dataset's rest mesh, E and ν per cell
/// under the same names as everywhere else, the marker error per node. One iteration keeps it
/// quick; the report and its file are written either way (exit status 2 says so).
#[test]
fn fit_writes_a_vtu_other_readers_accept() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("model.palp");
    let ds = repo().join("models/sponge/dataset");
    let o = fit_sponge(&[], &["--max-iterations", "1"], &model);
    assert_fit_written(&o);
    let path = dir.path().join("model.report/fit.vtu");
    let (v, mesh) = read_checked_grid(&path, &ds.join("mesh.msh"), 0.0);

    assert!(
        !v.arrays
            .contains_key(&("PointData".to_string(), vtk::DISPLACEMENT.to_string())),
        "a fit has no displacement of its own"
    );
    let err = v.array("PointData", "marker_error_m");
    assert_eq!(err.components, 1);
    assert!(err.values.iter().all(|&x| x.is_finite() && x >= 0.0));
    let e = v.array("CellData", vtk::YOUNG_MODULUS);
    let nu = v.array("CellData", vtk::POISSON_RATIO);
    assert_eq!((e.components, nu.components), (1, 1));
    assert_eq!(
        (e.values.len(), nu.values.len()),
        (mesh.tets.len(), mesh.tets.len())
    );
    assert!(e.values.iter().all(|&x| x.is_finite() && x > 0.0), "E > 0");
    assert!(
        nu.values.iter().all(|&x| x > -1.0 && x < 0.5),
        "−1 < ν < 0.5"
    );
}

/// The scan fit's residual files (`palpate_scan::residual_vtu`), for a hand-made fit of two
/// triangles and three points, one of them with no surface near: the point file has one vertex
/// cell per point and the surface file only the four surface nodes and two triangles; each
/// array holds one value per point; the unmatched point's distance is NaN and its weight 0; the
/// node means are those derived by hand (node 0: 1 mm from the point at it; node 3: −2 mm).
#[test]
fn the_scan_residual_files_are_what_a_vtk_reader_expects() {
    use nalgebra::Vector3;
    use palpate_scan::fit::{Equilibrium, Linearisation, PointResidual, ScanFit, ScanPoints};
    use palpate_scan::surface::Correspondence;
    let tmp = tempfile::tempdir().unwrap();
    let at = |point, triangle, barycentric, distance| PointResidual {
        correspondence: Correspondence {
            point,
            triangle,
            barycentric,
            normal: Vector3::z(),
            distance,
        },
        sigma: 1e-3,
        weight: 0.5,
    };
    // Five nodes, node 4 interior (in no triangle): the surface file must leave it out.
    let rest = vec![
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.5, 0.5, -1.0],
    ];
    let positions: Vec<[f64; 3]> = rest.iter().map(|p| [p[0], p[1], p[2] - 0.1]).collect();
    let fit = ScanFit {
        mu: 1e5,
        young_modulus: 2.9e5,
        iterations: 1,
        at_fit: Linearisation {
            equilibrium: Equilibrium {
                mu: vec![1e5],
                rest,
                positions,
                dln_mu: Vec::new(),
                surface: vec![[0, 1, 2], [1, 3, 2]],
            },
            residuals: vec![
                at(0, [0, 1, 2], [1.0, 0.0, 0.0], 1e-3),
                at(2, [1, 3, 2], [0.0, 1.0, 0.0], -2e-3),
            ],
            cost: 0.0,
            gradient: vec![0.0],
            hessian: vec![1.0],
        },
    };
    let scan = ScanPoints {
        points: vec![
            Vector3::new(0.0, 0.0, -0.099),
            Vector3::new(9.0, 9.0, 9.0),
            Vector3::new(1.0, 1.0, -0.102),
        ],
        sigma: vec![1e-3; 3],
        camera: None,
    };
    let files =
        palpate_scan::residual_vtu::write_fit_residual(tmp.path(), "t", &scan, &fit).unwrap();
    let points = read_vtu(&files[0]);
    assert_eq!((points.points, points.cells), (3, 3));
    assert_eq!(points.array("Cells", "offsets").values, [1.0, 2.0, 3.0]);
    assert_eq!(points.array("Cells", "types").values, [1.0; 3]);
    let d = &points.array("PointData", "signed_distance_m").values;
    assert!(d[0] == 1e-3 && d[1].is_nan() && d[2] == -2e-3, "{d:?}");
    assert_eq!(points.array("PointData", "weight").values, [0.5, 0.0, 0.5]);
    let surface = read_vtu(&files[1]);
    assert_eq!((surface.points, surface.cells), (4, 2));
    assert_eq!(surface.array("Cells", "types").values, [5.0; 2]);
    assert_eq!(surface.array("Cells", "offsets").values, [3.0, 6.0]);
    let mean = &surface.array("PointData", "mean_residual_m").values;
    // Renumbered in first-seen order: 0, 1, 2, 3.
    assert!(
        mean[0] == 1e-3 && mean[3] == -2e-3 && mean[1].is_nan(),
        "{mean:?}"
    );
    let u = surface.array("PointData", "displacement");
    assert_eq!(u.components, 3);
    assert!(
        u.values.chunks(3).all(|c| c == [0.0, 0.0, -0.1]),
        "{:?}",
        u.values
    );
}
