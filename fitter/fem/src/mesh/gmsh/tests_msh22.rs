//! MSH 2.2 ASCII: the same meshes as from MSH 4.1, files written by Gmsh's and meshio's own
//! writers, and errors that name the line.

use super::tests::{err_text, fixture, read_text};
use super::*;

/// Two tetrahedra sharing face (1, 2, 3), in MSH 2.2 as Gmsh writes it: the triangle on that face
/// in physical surface "fixed", the tetrahedra in physical volumes "body" and "soft", so each is
/// listed twice (once per group, new element tag each time). Element 4 carries partition tags
/// (ntags = 4), which say nothing about groups. The same mesh in MSH 4.1 is [`TWO_TETS_41`].
pub(super) const TWO_TETS_22: &str = "$MeshFormat
2.2 0 8
$EndMeshFormat
$Comments
written by hand for palpate's tests: two tetrahedra sharing face 1 2 3
$EndComments
$PhysicalNames
3
2 7 \"fixed\"
3 8 \"body\"
3 9 \"soft\"
$EndPhysicalNames
$Nodes
5
1 0 0 0
2 1 0 0
3 0 1 0
4 0 0 1
5 0 0 -1
$EndNodes
$Elements
5
1 2 2 7 1 1 2 3
2 4 2 8 1 1 2 3 4
3 4 2 9 1 1 2 3 4
4 4 4 8 1 1 2 1 3 2 5
5 4 4 9 1 1 2 1 3 2 5
$EndElements
";

/// [`TWO_TETS_22`] in MSH 4.1: the groups sit on the entities (surface 1: 7; volume 1: 8 and 9).
const TWO_TETS_41: &str = "$MeshFormat
4.1 0 8
$EndMeshFormat
$PhysicalNames
3
2 7 \"fixed\"
3 8 \"body\"
3 9 \"soft\"
$EndPhysicalNames
$Entities
0 0 1 1
1 0 0 0 1 1 0 1 7 0
1 0 0 -1 1 1 1 2 8 9 0
$EndEntities
$Nodes
1 5 1 5
3 1 0 5
1
2
3
4
5
0 0 0
1 0 0
0 1 0
0 0 1
0 0 -1
$EndNodes
$Elements
2 3 1 3
2 1 2 1
1 1 2 3
3 1 4 2
2 1 2 3 4
3 1 3 2 5
$EndElements
";

#[track_caller]
fn assert_same_mesh(a: &Mesh, b: &Mesh) {
    assert_eq!(a.nodes, b.nodes);
    assert_eq!(a.node_tags, b.node_tags);
    assert_eq!(a.tets, b.tets);
    assert_eq!(a.node_groups, b.node_groups);
}

#[test]
fn msh22_reads_as_the_same_mesh_as_msh41() {
    let (m22, r22) = read_text(TWO_TETS_22).unwrap();
    let (m41, r41) = read_text(TWO_TETS_41).unwrap();
    assert_same_mesh(&m22, &m41);
    assert_eq!(
        m22.tets.len(),
        2,
        "the per-group repeats are one element each"
    );
    assert_eq!(m22.node_groups["fixed"], vec![0, 1, 2]);
    assert_eq!(m22.node_groups["body"], vec![0, 1, 2, 3, 4]);
    assert_eq!(m22.node_groups["soft"], vec![0, 1, 2, 3, 4]);
    assert_eq!(r22, r41);
    assert_eq!(r22.boundary_elements, 1);
    assert!(!r22.binary);
}

#[test]
fn msh20_and_msh21_headers_are_read_as_msh22() {
    let (m22, _) = read_text(TWO_TETS_22).unwrap();
    for version in ["2.0", "2.1"] {
        let text = TWO_TETS_22.replace("2.2 0 8", &format!("{version} 0 8"));
        let (m, _) = read_text(&text).unwrap();
        assert_same_mesh(&m, &m22);
    }
}

/// In MSH 2 the physical tag belongs to the element: two triangles of one elementary surface
/// can be in different groups, physical tag 0 (or no tags) is no group, and a row with a single
/// tag has a physical tag but no elementary one.
#[test]
fn msh22_groups_follow_each_element_physical_tag() {
    let text = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n\
                $PhysicalNames\n2\n2 7 \"a\"\n2 8 \"b\"\n$EndPhysicalNames\n\
                $Nodes\n5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 0 0 -1\n$EndNodes\n\
                $Elements\n5\n\
                1 4 2 0 1 1 2 3 4\n\
                2 4 0 1 3 2 5\n\
                3 2 2 7 1 1 2 3\n\
                4 2 2 8 1 1 2 4\n\
                5 1 1 9 4 5\n\
                $EndElements\n";
    let (m, r) = read_text(text).unwrap();
    assert_eq!(
        m.node_groups.keys().collect::<Vec<_>>(),
        ["a", "b", "group-9"]
    );
    assert_eq!(m.node_groups["a"], vec![0, 1, 2]);
    assert_eq!(m.node_groups["b"], vec![0, 1, 3]);
    assert_eq!(m.node_groups["group-9"], vec![3, 4]);
    assert_eq!(r.boundary_elements, 3);
}

/// A repeat with the same physical tag is not Gmsh's per-group listing but a duplicated element:
/// it is kept, and the mesh is rejected as it would be in MSH 4.1.
#[test]
fn msh22_element_repeated_in_the_same_group_is_not_merged() {
    let text = TWO_TETS_22.replace("3 4 2 9 1 1 2 3 4", "3 4 2 8 1 1 2 3 4");
    let e = err_text(&text);
    assert!(
        e.contains("t.msh: element 2 is inverted") && e.contains("as element 3"),
        "{e}"
    );
}

/// `make_box22.py` in `testdata/` wrote one Gmsh mesh three times: MSH 4.1 and MSH 2.2 with
/// Gmsh 4.15.2's writers, and MSH 2.2 with meshio 5.3.5's writer (from the 4.1 file). The counts
/// are the ones Gmsh printed.
#[test]
fn gmsh_and_meshio_msh22_files_read_as_the_gmsh_msh41_file() {
    let (m41, r41) = read_msh_with_report(fixture("box-41.msh")).unwrap();
    let (gmsh22, rg) = read_msh_with_report(fixture("box-22-gmsh.msh")).unwrap();
    let (meshio22, rm) = read_msh_with_report(fixture("box-22-meshio.msh")).unwrap();
    assert_eq!((m41.nodes.len(), m41.tets.len()), (24, 42));
    let sizes: Vec<(&str, usize)> = m41
        .node_groups
        .iter()
        .map(|(k, v)| (k.as_str(), v.len()))
        .collect();
    assert_eq!(
        sizes,
        [
            ("body", 24),
            ("fixed", 8),
            ("group-5", 1),
            ("silicone", 24),
            ("top", 8)
        ]
    );
    assert!(m41.node_groups["fixed"]
        .iter()
        .all(|&i| m41.nodes[i][2] == 0.0));
    assert_eq!(m41.nodes[m41.node_groups["group-5"][0]], [0.0, 0.0, 0.04]);

    // Gmsh's 2.2 file lists each tetrahedron twice ("body" and "silicone"): read once each.
    assert_same_mesh(&gmsh22, &m41);
    assert_eq!(rg, r41);

    // meshio prints 17 significant digits, so the coordinates are the same doubles; it keeps
    // one physical tag per element, so "silicone" (the second group of the volume) is empty.
    assert_eq!(meshio22.nodes, m41.nodes);
    assert_eq!(meshio22.node_tags, m41.node_tags);
    assert_eq!(meshio22.tets, m41.tets);
    let mut expected_groups = m41.node_groups.clone();
    expected_groups.insert("silicone".into(), vec![]);
    assert_eq!(meshio22.node_groups, expected_groups);
    assert_eq!(rm, r41);
    assert_eq!(r41.reoriented, 0);
    assert_eq!(r41.boundary_elements, 13, "one point and twelve triangles");
}

#[test]
fn msh22_truncated_elements_name_the_count_line_and_end_of_file() {
    let cut = &TWO_TETS_22[..TWO_TETS_22.find("4 4 4 8").unwrap()];
    let e = err_text(cut);
    assert!(
        e.contains("t.msh:25: expected element 4 of 5 (counted on line 22), found end of file"),
        "{e}"
    );
}

#[test]
fn msh22_node_count_mismatch_names_the_line() {
    let more = TWO_TETS_22.replace("$Nodes\n5\n", "$Nodes\n6\n");
    let e = err_text(&more);
    assert!(
        e.contains("t.msh:20: expected node 6 of 6 (counted on line 14), found \"$EndNodes\""),
        "{e}"
    );
    let fewer = TWO_TETS_22.replace("$Nodes\n5\n", "$Nodes\n4\n");
    let e = err_text(&fewer);
    assert!(
        e.contains(
            "t.msh:19: expected \"$EndNodes\" after the 4 nodes counted on line 14, found \"5\""
        ),
        "{e}"
    );
    let word = TWO_TETS_22.replace("$Nodes\n5\n", "$Nodes\nfive\n");
    let e = err_text(&word);
    assert!(
        e.contains("t.msh:14: expected number of nodes (a count), found \"five\""),
        "{e}"
    );
}

#[test]
fn msh22_unknown_element_type_names_the_line() {
    let text = TWO_TETS_22.replace("1 2 2 7 1 1 2 3", "1 99 2 7 1 1 2 3");
    let e = err_text(&text);
    assert!(
        e.contains(
            "t.msh:23: expected type of element 1 (a Gmsh element type 1–31, 92 or 93), found \"99\""
        ),
        "{e}"
    );
}

#[test]
fn msh22_malformed_rows_name_line_and_token() {
    let cases = [
        (
            "5 0 0 -1\n",
            "5 0 0 -1x\n",
            "t.msh:19: expected node z (a number), found \"-1x\"",
        ),
        (
            "5 0 0 -1\n",
            "5 0 0\n",
            "t.msh:19: expected node z (a number), found end of line",
        ),
        (
            "5 0 0 -1\n",
            "5 0 0 -1 7\n",
            "t.msh:19: expected the end of the node row (tag x y z), found \"7\"",
        ),
        (
            "5 4 4 9 1 1 2 1 3 2 5",
            "5 4 4 9 1 1 2 1 3 2",
            "t.msh:27: expected 4 node tags for element 5 of type 4, found \"3 node tags\"",
        ),
        (
            "5 4 4 9 1 1 2 1 3 2 5",
            "5 4 4 9 1 1 2 1 3 2 5 6",
            "t.msh:27: expected 4 node tags for element 5 of type 4, found \"5 node tags\"",
        ),
        (
            "1 2 2 7 1 1 2 3",
            "1 2 2 7",
            "t.msh:23: expected tag 2 of 2 of element 1 (an integer), found end of line",
        ),
    ];
    for (from, to, expected) in cases {
        let e = err_text(&TWO_TETS_22.replace(from, to));
        assert!(e.contains(expected), "{to:?}: {e}");
    }
}

/// Gmsh's MSH 2.2 binary file of the same box reads as its MSH 4.1 file does: every tetrahedron
/// once (Gmsh lists each twice, once per volume group), the coordinates to the ASCII file's 16
/// digits, the same groups.
/// Every prefix of it, and the file with a byte changed, is refused or read, never a crash, and a
/// cut inside the nodes names the byte where they run out.
#[test]
fn gmsh_msh22_binary_reads_as_the_gmsh_msh41_file() {
    let (m41, r41) = read_msh_with_report(fixture("box-41.msh")).unwrap();
    let (bin, rb) = read_msh_with_report(fixture("box-22-binary.msh")).unwrap();
    assert!(rb.binary);
    // Gmsh prints 16 significant digits in ASCII; binary holds the exact doubles.
    assert_eq!(bin.nodes.len(), m41.nodes.len());
    for (a, b) in bin.nodes.iter().zip(&m41.nodes) {
        for k in 0..3 {
            assert!(
                (a[k] - b[k]).abs() <= 1e-15 * b[k].abs() + 1e-18,
                "{a:?} {b:?}"
            );
        }
    }
    assert_eq!(bin.node_tags, m41.node_tags);
    assert_eq!(bin.tets, m41.tets);
    assert_eq!(bin.node_groups, m41.node_groups);
    assert_eq!(
        MshReport {
            binary: false,
            ..rb
        },
        r41
    );
    let bytes = std::fs::read(fixture("box-22-binary.msh")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("cut.msh");
    for cut in 0..bytes.len() {
        std::fs::write(&p, &bytes[..cut]).unwrap();
        let _ = read_msh(&p);
    }
    for at in (0..bytes.len()).step_by(3) {
        let mut bad = bytes.clone();
        bad[at] ^= 0xa5;
        std::fs::write(&p, &bad).unwrap();
        let _ = read_msh(&p);
    }
    let nodes = bytes.windows(7).position(|w| w == b"$Nodes\n").unwrap();
    std::fs::write(&p, &bytes[..nodes + 20]).unwrap();
    let e = read_msh(&p).unwrap_err().to_string();
    assert!(
        e.contains("cut.msh: binary MSH parse error at byte") && e.contains("bytes needed"),
        "{e}"
    );
}

#[test]
fn unsupported_version_is_refused_listing_the_versions_read() {
    for version in ["3.0", "4.0", "1.0"] {
        let text = TWO_TETS_41.replace("4.1 0 8", &format!("{version} 0 8"));
        let e = err_text(&text);
        assert!(
            e.contains(
                "t.msh:2: expected MSH format version 4.1 or 2.2, 2.1, 2.0 (ASCII or binary)"
            ) && e.ends_with(&format!("found \"{version}\"")),
            "{e}"
        );
    }
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(256))]
    /// Any corruption of a valid MSH 2.2 file (a byte replaced, the file cut) is an error or a
    /// mesh, never a panic.
    #[test]
    fn corrupted_msh22_never_panics(at in 0usize..500, byte in proptest::prelude::any::<u8>(), cut in 1usize..500) {
        let mut bytes = TWO_TETS_22.as_bytes().to_vec();
        let n = bytes.len();
        bytes[at % n] = byte;
        bytes.truncate(cut.min(n));
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.msh");
        std::fs::write(&p, &bytes).unwrap();
        let _ = read_msh(&p);
    }
}
