use super::*;
use crate::mesh::boxmesh::box_mesh;

pub(super) fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("src/mesh/gmsh/testdata")
        .join(name)
}

/// Every tet's signed volume, in mesh order.
fn volumes(m: &Mesh) -> Vec<f64> {
    m.tets
        .iter()
        .map(|t| assemble::signed_volume(&t.map(|i| m.nodes[i])))
        .collect()
}

fn total_volume(m: &Mesh) -> f64 {
    volumes(m).iter().sum()
}

/// Two tetrahedra sharing face (1, 2, 3); `node5` is the apex of the second, `tet2` its node list.
fn tiny(node5: &str, tet2: &str) -> String {
    format!(
        "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$PhysicalNames\n1\n2 7 \"base\"\n$EndPhysicalNames\n\
         $Entities\n0 0 1 1\n1 0 0 0 1 1 0 1 7 0\n1 0 0 -1 1 1 1 0 0\n$EndEntities\n\
         $Nodes\n1 5 1 5\n3 1 0 5\n1\n2\n3\n4\n5\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n{node5}\n$EndNodes\n\
         $Elements\n2 3 1 3\n3 1 4 2\n1 1 2 3 4\n{tet2}\n2 1 2 1\n3 1 2 3\n$EndElements\n"
    )
}

pub(super) fn read_text(text: &str) -> Result<(Mesh, MshReport), MeshError> {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("t.msh");
    std::fs::write(&p, text).unwrap();
    read_msh_with_report(&p)
}

pub(super) fn err_text(text: &str) -> String {
    read_text(text).unwrap_err().to_string()
}

#[test]
fn reads_gmsh_ascii_fixture_with_groups_and_unit_volume() {
    let (m, r) = read_msh_with_report(fixture("cube-ascii.msh")).unwrap();
    // Counts printed by Gmsh itself when it wrote the fixture (make_cube.py).
    assert_eq!(m.tets.len(), 100);
    assert_eq!(m.nodes.len(), 45);
    assert_eq!(m.node_groups["bottom"].len(), 12);
    assert_eq!(m.node_groups["body"].len(), 45);
    // The unnamed point group (tag 3) on the corner (0, 0, 1).
    let corner = &m.node_groups["group-3"];
    assert_eq!(corner.len(), 1);
    assert_eq!(m.nodes[corner[0]], [0.0, 0.0, 1.0]);
    assert!(m.node_groups["bottom"]
        .iter()
        .all(|&i| m.nodes[i][2].abs() < 1e-12));
    assert_eq!(
        r.reoriented, 0,
        "Gmsh writes positively oriented tetrahedra"
    );
    assert!(!r.binary);
    // Unit cube: volumes sum to 1 up to round-off of ~100 terms.
    assert!((total_volume(&m) - 1.0).abs() < 1e-12);
}

#[test]
fn binary_fixture_matches_ascii_fixture() {
    let (a, _) = read_msh_with_report(fixture("cube-ascii.msh")).unwrap();
    let (b, rb) = read_msh_with_report(fixture("cube-binary.msh")).unwrap();
    assert!(rb.binary);
    assert_eq!(a.node_tags, b.node_tags);
    // Gmsh prints 16 significant digits in ASCII; binary holds the exact doubles.
    for (p, q) in a.nodes.iter().zip(&b.nodes) {
        for k in 0..3 {
            assert!((p[k] - q[k]).abs() <= 1e-15, "{p:?} vs {q:?}");
        }
    }
    assert_eq!(a.tets, b.tets);
    assert_eq!(a.node_groups, b.node_groups);
}

#[test]
fn write_then_read_is_exact() {
    let mut m = box_mesh([0.1, 0.07, 0.05], [3, 2, 2]);
    // Sparse, shuffled tags and a group that is not a surface patch (two loose nodes).
    m.node_tags = (0..m.nodes.len() as u64).map(|i| 1000 - 7 * i).collect();
    m.node_groups.insert("probe points".into(), vec![0, 17]);
    m.node_groups.insert("empty".into(), vec![]);
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.msh");
    write_msh(&m, &p).unwrap();
    let back = read_msh(&p).unwrap();
    assert_eq!(
        back.nodes, m.nodes,
        "coordinates are printed with round-trip precision"
    );
    assert_eq!(back.node_tags, m.node_tags);
    assert_eq!(back.tets, m.tets);
    assert_eq!(back.node_groups, m.node_groups);
}

#[test]
fn tiny_mesh_reads() {
    let (m, r) = read_text(&tiny("0 0 -1", "2 1 3 2 5")).unwrap();
    assert_eq!(m.tets.len(), 2);
    assert_eq!(r.reoriented, 0);
    assert_eq!(r.boundary_elements, 1);
    assert_eq!(m.node_groups["base"], vec![0, 1, 2]);
}

#[test]
fn negatively_listed_tetrahedra_are_reoriented_and_counted() {
    // Second tet listed as 1 2 3 5 (negative volume, same geometry).
    let (m, r) = read_text(&tiny("0 0 -1", "2 1 2 3 5")).unwrap();
    assert_eq!(r.reoriented, 1);
    assert!((total_volume(&m) - 2.0 / 6.0).abs() < 1e-15);
}

#[test]
fn folded_element_is_reported_as_inverted() {
    // Apex 5 moved to the same side as apex 4: element 2 overlaps element 1.
    let e = err_text(&tiny("0.2 0.2 0.5", "2 1 3 2 5"));
    assert!(
        e.contains("t.msh") && e.contains("element 2 is inverted") && e.contains("element 1"),
        "{e}"
    );
}

#[test]
fn zero_volume_element_names_its_tag() {
    let e = err_text(&tiny("0.5 0.5 0", "2 1 3 2 5"));
    assert!(
        e.contains("t.msh") && e.contains("element 2 has zero volume"),
        "{e}"
    );
}

#[test]
fn malformed_number_names_line_and_token() {
    let e = err_text(&tiny("0 0 -1x", "2 1 3 2 5"));
    // Line 25 holds the coordinates of node 5.
    assert!(
        e.contains("t.msh:25: expected node z (a number), found \"-1x\""),
        "{e}"
    );
}

#[test]
fn non_finite_coordinate_is_rejected() {
    let e = err_text(&tiny("0 NaN -1", "2 1 3 2 5"));
    assert!(e.contains("node 5 has a non-finite coordinate"), "{e}");
}

#[test]
fn unknown_and_duplicate_nodes_are_rejected() {
    let e = err_text(&tiny("0 0 -1", "2 1 3 2 9"));
    assert!(e.contains("element 2 refers to node 9"), "{e}");
    let dup = tiny("0 0 -1", "2 1 3 2 5").replace("4\n5\n0 0 0", "4\n4\n0 0 0");
    let e = err_text(&dup);
    assert!(e.contains("node tag 4 appears twice"), "{e}");
}

#[test]
fn other_volume_elements_and_versions_are_rejected() {
    let hex = tiny("0 0 -1", "2 1 3 2 5").replace("3 1 4 2\n", "3 1 5 2\n");
    let e = err_text(&hex);
    assert!(
        e.contains("element 1 has Gmsh type 5 (8-node hexahedron)"),
        "{e}"
    );
    // MSH 2.2 ASCII is read now (more in `tests_msh22`); a version between 2.2 and 4.1 is not.
    let (msh22, _) = read_text(super::tests_msh22::TWO_TETS_22).unwrap();
    assert_eq!(msh22.tets.len(), 2);
    let unsupported = tiny("0 0 -1", "2 1 3 2 5").replace("4.1 0 8", "3.0 0 8");
    let e = err_text(&unsupported);
    assert!(
        e.contains("t.msh:2: expected MSH format version 4.1") && e.contains("found \"3.0\""),
        "{e}"
    );
    let short = tiny("0 0 -1", "2 1 3 2");
    let e = err_text(&short);
    assert!(
        e.contains("t.msh:31: expected 4 node tags for element 2 of type 4, found \"3 node tags\""),
        "{e}"
    );
}

#[test]
fn truncated_file_says_end_of_file() {
    let text = tiny("0 0 -1", "2 1 3 2 5");
    let cut = &text[..text.find("$EndNodes").unwrap() - 8];
    let e = err_text(cut);
    assert!(e.contains("found end of file"), "{e}");
}

#[test]
fn corrupt_binary_is_wrapped_with_file_and_offset() {
    let mut bytes = std::fs::read(fixture("cube-binary.msh")).unwrap();
    let at = bytes.windows(6).position(|w| w == b"$Nodes").unwrap();
    bytes.truncate(at + 40);
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bad.msh");
    std::fs::write(&p, &bytes).unwrap();
    let e = read_msh(&p).unwrap_err().to_string();
    assert!(e.contains("bad.msh: binary MSH parse error at byte"), "{e}");
}

/// The mesh `models/<rel>`, read; asserts its (nodes, tets) and that no element needed turning.
#[track_caller]
fn bundled(rel: &str, counts: (usize, usize)) -> Mesh {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../models")
        .join(rel);
    let (m, r) = read_msh_with_report(path).unwrap();
    assert_eq!((m.nodes.len(), m.tets.len()), counts);
    assert_eq!(r.reoriented, 0);
    m
}

/// Whether every node of group `g` satisfies `f`.
fn all_on(m: &Mesh, g: &str, f: &dyn Fn([f64; 3]) -> bool) -> bool {
    m.node_groups[g].iter().all(|&i| f(m.nodes[i]))
}

#[test]
fn bundled_sponge_mesh_reads() {
    // Counts printed by Gmsh when make_mesh.py wrote the file.
    let m = bundled("sponge/sponge.msh", (1089, 4379));
    for g in ["bottom", "top", "sides", "sponge"] {
        assert!(!m.node_groups[g].is_empty(), "{g}");
    }
    assert_eq!(m.node_groups["sponge"].len(), 1089);
    let on = |g: &str, f: &dyn Fn([f64; 3]) -> bool| all_on(&m, g, f);
    assert!(on("bottom", &|p| p[2].abs() < 1e-12));
    assert!(on("top", &|p| (p[2] - 0.05).abs() < 1e-12));
    assert!(on("sides", &|p| {
        p[0].abs() < 1e-12
            || (p[0] - 0.1).abs() < 1e-12
            || p[1].abs() < 1e-12
            || (p[1] - 0.1).abs() < 1e-12
    }));
    let vols = volumes(&m);
    assert!(vols.iter().all(|&v| v > 0.0));
    // 10 × 10 × 5 cm = 5e-4 m³; Gmsh prints 16 digits, so the sum is exact to ~1e-15 relative.
    assert!((vols.iter().sum::<f64>() - 5e-4).abs() < 1e-9);
}

#[test]
fn whole_mesh_group_round_trips_as_a_volume_group() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/sponge/sponge.msh");
    let m = read_msh(path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("sponge.msh");
    write_msh(&m, &p).unwrap();
    let text = std::fs::read_to_string(&p).unwrap();
    assert!(
        text.contains("3 3 \"sponge\""),
        "the all-node group becomes a physical volume"
    );
    let back = read_msh(&p).unwrap();
    assert_eq!(back.node_groups, m.node_groups);
    assert_eq!(back.tets, m.tets);
    assert_eq!(back.node_tags, m.node_tags);
}

#[test]
fn absurd_counts_fail_cleanly() {
    let text = tiny("0 0 -1", "2 1 3 2 5").replace("3 1 0 5\n", "3 1 0 99999999999999\n");
    let e = err_text(&text);
    assert!(e.contains("t.msh:"), "{e}");
}

/// Replaces byte `at` (modulo the length) of `bytes` by `byte`, cuts them after `cut` bytes and
/// reads them as the file `name`: an error or a mesh is fine, a panic is not.
fn read_corrupted(mut bytes: Vec<u8>, (at, byte): (usize, u8), cut: usize, name: &str) {
    let n = bytes.len();
    bytes[at % n] = byte;
    bytes.truncate(cut.min(n));
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join(name);
    std::fs::write(&p, &bytes).unwrap();
    let _ = read_msh(&p);
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(256))]
    /// Any corruption of a valid file (a byte replaced, the file cut) is an error or a mesh,
    /// never a panic.
    #[test]
    fn corrupted_ascii_never_panics(at in 0usize..600, byte in proptest::prelude::any::<u8>(), cut in 0usize..700) {
        let bytes = tiny("0 0 -1", "2 1 3 2 5").into_bytes();
        read_corrupted(bytes, (at, byte), cut.max(1), "t.msh");
    }
}

/// Every byte in place of a binary file's data size (the width of its size_t on the
/// `$MeshFormat` line): mshio reads only a few widths and panicked on the others (a 7 found by
/// the corruption test below); every byte but Gmsh's 8 and 4 is now refused on line 2, naming
/// the field, and 4 (a size_t the file was not written with) is an error or a mesh, never a panic.
#[test]
fn every_binary_data_size_is_read_or_refused() {
    let original = std::fs::read(fixture("cube-binary.msh")).unwrap();
    let at = original.windows(6).position(|w| w == b"4.1 1 ").unwrap() + 6;
    assert_eq!(original[at], b'8');
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("size.msh");
    for byte in 0..=255u8 {
        let mut bytes = original.clone();
        bytes[at] = byte;
        std::fs::write(&p, &bytes).unwrap();
        let read = read_msh(&p);
        match byte {
            b'8' => assert!(read.is_ok(), "{read:?}"),
            b'4' => {}
            _ => match read {
                Err(MeshError::Syntax {
                    line: 2, expected, ..
                }) => {
                    assert!(expected.contains("data size"), "{byte}: {expected}")
                }
                other => panic!("byte {byte}: {other:?}"),
            },
        }
    }
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(256))]
    /// The same for binary files (parsed by mshio).
    #[test]
    fn corrupted_binary_never_panics(at in 0usize..9000, byte in proptest::prelude::any::<u8>(), cut in 0usize..9000) {
        let bytes = std::fs::read(fixture("cube-binary.msh")).unwrap();
        read_corrupted(bytes, (at, byte), cut.max(40), "b.msh");
    }
}

/// The silicone beam meshed from its STL (`models/mesh_stl.py`, STL in mm scaled to metres): the
/// counts Gmsh printed, the clamp and free-end groups on their planes, positive volumes summing
/// to the beam's 30 × 30 × 100 mm.
#[test]
fn bundled_beam_mesh_reads() {
    let m = bundled("silicone-beam/beam.msh", (733, 2600));
    let on = |g: &str, f: &dyn Fn([f64; 3]) -> bool| all_on(&m, g, f);
    assert!(on("clamp", &|p| (p[2] - 0.1).abs() < 1e-9));
    assert!(on("free_end", &|p| p[2].abs() < 1e-9));
    assert!(m.node_groups["clamp"].len() > 10);
    let vols = volumes(&m);
    assert!(vols.iter().all(|&v| v > 0.0));
    assert!(
        (vols.iter().sum::<f64>() - 9e-5).abs() < 1e-10,
        "{}",
        vols.iter().sum::<f64>()
    );
}

/// A mesh raised to 10-node tetrahedra by Gmsh (`make_order2.py`: the same cylinder written at
/// order 1 and at order 2) reads as the order-1 mesh, corner for corner and group for group, in each
/// format Gmsh writes it; the report counts the 10-node tetrahedra and their edge nodes, and
/// measures the curved surface's edge nodes off their edges' midpoints (Gmsh's script printed
/// 0.158148 of an edge's length).
#[test]
fn ten_node_tetrahedra_are_read_as_their_corners() {
    let (linear, r1) = read_msh_with_report(fixture("cyl-order1.msh")).unwrap();
    assert_eq!(linear.tets.len(), 99);
    assert_eq!((r1.quadratic_tets, r1.edge_nodes), (0, 0));
    assert_eq!(r1.largest_edge_bow, 0.0);
    for name in [
        "cyl-order2.msh",
        "cyl-order2-binary.msh",
        "cyl-order2-22.msh",
    ] {
        let (m, r) = read_msh_with_report(fixture(name)).unwrap();
        // The same corners in the same order (Gmsh gives them new tags as it raises the order),
        // to the last digit an ASCII file keeps against the binary file's exact doubles.
        assert_eq!(m.nodes.len(), linear.nodes.len(), "{name}");
        for (a, b) in m.nodes.iter().flatten().zip(linear.nodes.iter().flatten()) {
            assert!(
                (a - b).abs() <= 1e-15 * b.abs().max(1e-3),
                "{name}: {a} against {b}"
            );
        }
        assert_eq!(m.tets, linear.tets, "{name}");
        assert_eq!(m.node_groups, linear.node_groups, "{name}");
        assert_eq!(r.quadratic_tets, 99, "{name}");
        // Gmsh's script: 242 nodes in all, so 242 − corners on edges; no other node dropped.
        assert_eq!(r.edge_nodes, 242 - linear.nodes.len(), "{name}");
        assert_eq!(r.dropped_nodes, r1.dropped_nodes, "{name}");
        assert!(
            (r.largest_edge_bow - 0.158148).abs() < 1e-5,
            "{name}: {}",
            r.largest_edge_bow
        );
        assert!(r.largest_edge_bow > CURVED_EDGE);
    }
}

/// One 10-node tetrahedron with its edge nodes at the midpoints: straight edges, bow 0 to
/// round-off; one edge node moved off its edge is measured; a line one node short is an error
/// that names what it expected.
#[test]
fn a_ten_node_tetrahedron_is_measured_and_checked() {
    let text = |edge4: &str, count: usize, nodes: &str| {
        format!(
            "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n\
             $Nodes\n1 10 1 10\n3 1 0 10\n1\n2\n3\n4\n5\n6\n7\n8\n9\n10\n\
             0 0 0\n1 0 0\n0 1 0\n0 0 1\n{edge4}\n0.5 0.5 0\n0 0.5 0\n0 0 0.5\n0 0.5 0.5\n\
             0.5 0 0.5\n$EndNodes\n$Elements\n1 {count} 1 {count}\n3 1 11 {count}\n{nodes}\n\
             $EndElements\n"
        )
    };
    let (m, r) = read_text(&text("0.5 0 0", 1, "1 1 2 3 4 5 6 7 8 9 10")).unwrap();
    assert_eq!((m.nodes.len(), m.tets.len()), (4, 1));
    assert_eq!((r.quadratic_tets, r.edge_nodes, r.dropped_nodes), (1, 6, 0));
    assert!(r.largest_edge_bow < 1e-15, "{}", r.largest_edge_bow);
    // Node 5 sits on edge (1, 2) of length 1: moved 0.05 off, it bows 5 % of the edge.
    let (_, r) = read_text(&text("0.5 0.05 0", 1, "1 1 2 3 4 5 6 7 8 9 10")).unwrap();
    assert!(
        (r.largest_edge_bow - 0.05).abs() < 1e-12,
        "{}",
        r.largest_edge_bow
    );
    let e = err_text(&text("0.5 0 0", 1, "1 1 2 3 4 5 6 7 8 9"));
    assert!(
        e.contains("expected 10 node tags for element 1 of type 11, found \"9 node tags\""),
        "{e}"
    );
}
