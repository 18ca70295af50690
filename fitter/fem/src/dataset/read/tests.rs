//! Every bad-input case of the dataset format, each checking that the message names the file,
//! the line and the field (or, for mesh geometry, the element).

use crate::dataset::StaticDataset;
use crate::mesh::boxmesh::box_mesh;
use crate::mesh::gmsh::write_msh;
use crate::mesh::Mesh;
use std::path::Path;

const TOML: &str =
    "name = \"tiny\"\ndescription = \"a 10 x 10 x 5 cm box, two pokes\"\nunits = \"SI\"\n\
mesh = \"mesh.msh\"\nfixed_group = \"bottom\"\nprobe_radius = 0.02\nmarker_noise = 1e-4\n";
const MARKERS: &str =
    "marker,x,y,z\nm1,0.03,0.04,0.05\nm2,0.07,0.06,0.05\n# a comment\nm3,0.1,0.05,0.02\n";
const MEASUREMENTS: &str =
    "measurement,marker,x,y,z\np1,m1,0.03,0.04,0.049\np1,m2,0.07,0.06,0.0495\n\
p2,m1,0.03,0.04,0.0498\np2,m3,0.1,0.05,0.0199\n";
const CONTACTS: &str = "measurement,x,y,z,fx,fy,fz,radius\np1,0.05,0.05,0.05,0,0,-1.5,0.02\np2,0.05,0.05,0.05,0,0,-0.5\n";

/// 10 × 10 × 5 cm box, 25 mm cells (median surface edge 25 mm, embedding tolerance 25 mm),
/// plus an empty group "nothing".
fn mesh() -> Mesh {
    let mut m = box_mesh([0.1, 0.1, 0.05], [4, 4, 2]);
    m.node_groups.insert("nothing".into(), vec![]);
    m
}

fn write_dataset(dir: &Path, files: &[(&str, &str)], mesh: &Mesh) {
    write_msh(mesh, dir.join("mesh.msh")).unwrap();
    let defaults = [
        ("dataset.toml", TOML),
        ("markers.csv", MARKERS),
        ("measurements.csv", MEASUREMENTS),
        ("contacts.csv", CONTACTS),
    ];
    for (name, text) in defaults {
        let text = files
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, t)| *t)
            .unwrap_or(text);
        std::fs::write(dir.join(name), text).unwrap();
    }
}

/// Reads the default dataset with `files` replaced; returns the error message.
fn error_with(files: &[(&str, &str)]) -> String {
    error_with_mesh(files, &mesh())
}

fn error_with_mesh(files: &[(&str, &str)], mesh: &Mesh) -> String {
    let dir = tempfile::tempdir().unwrap();
    write_dataset(dir.path(), files, mesh);
    StaticDataset::read(dir.path()).unwrap_err().to_string()
}

/// Reads the default dataset with `file` replaced by `text` and asserts that the error message
/// names every one of `parts`.
#[track_caller]
fn rejects(file: &str, text: &str, parts: &[&str]) {
    assert_has(&error_with(&[(file, text)]), parts);
}

#[track_caller]
fn assert_has(msg: &str, parts: &[&str]) {
    for p in parts {
        assert!(msg.contains(p), "message {msg:?} lacks {p:?}");
    }
}

#[test]
fn good_dataset_reads_embeds_and_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    write_dataset(dir.path(), &[], &mesh());
    let d = StaticDataset::read(dir.path()).unwrap();
    assert_eq!(d.name, "tiny");
    assert_eq!(d.markers.len(), 3);
    assert_eq!(d.measurements.len(), 2);
    assert_eq!(d.fixed_nodes.len(), 25);
    assert_eq!(d.marker_noise, Some(1e-4));
    // p2 has no radius column: the default probe radius applies.
    assert_eq!(d.measurements[1].radius, 0.02);
    // p2 observed m1 and m3 (m2 occluded), sorted by marker index.
    assert_eq!(
        d.measurements[1]
            .observed
            .iter()
            .map(|o| o.0)
            .collect::<Vec<_>>(),
        vec![0, 2]
    );
    // Markers on the surface embed at distance 0 and interpolate back to their rest position
    // (exactly up to round-off of a 3-term barycentric sum).
    for m in &d.markers {
        assert!(m.distance < 1e-15, "{m:?}");
        let p = m.interpolate(|i| d.mesh.nodes[i]);
        for (a, b) in p.iter().zip(&m.rest) {
            assert!((a - b).abs() < 1e-15);
        }
    }
    // Round trip through StaticDataset::write.
    let out = tempfile::tempdir().unwrap();
    d.write(out.path()).unwrap();
    let e = StaticDataset::read(out.path()).unwrap();
    assert_eq!(e.markers, d.markers);
    assert_eq!(e.measurements, d.measurements);
    assert_eq!(e.mesh.nodes, d.mesh.nodes);
    assert_eq!(e.mesh.tets, d.mesh.tets);
    assert_eq!(
        (e.probe_radius, e.marker_noise, e.gravity),
        (d.probe_radius, d.marker_noise, d.gravity)
    );
    assert_eq!(e.description, d.description);
}

#[test]
fn units_other_than_si_are_rejected() {
    let toml = TOML.replace("units = \"SI\"", "units = \"mm\"");
    rejects(
        "dataset.toml",
        &toml,
        &[
            "dataset.toml:3:",
            "field `units`",
            "expected \"SI\"",
            "found \"mm\"",
        ],
    );
}

#[test]
fn unknown_or_missing_toml_keys_are_named() {
    let toml = TOML.replace("probe_radius", "probe_radios");
    rejects("dataset.toml", &toml, &["dataset.toml:6:", "probe_radios"]);
    let toml = TOML.replace("fixed_group = \"bottom\"\n", "");
    rejects("dataset.toml", &toml, &["dataset.toml:", "fixed_group"]);
}

#[test]
fn malformed_number_names_file_line_field() {
    let markers = MARKERS.replace("m2,0.07,0.06", "m2,0.07,0.06x");
    rejects(
        "markers.csv",
        &markers,
        &[
            "markers.csv:3:",
            "field `y`",
            "expected a number",
            "found \"0.06x\"",
        ],
    );
}

#[test]
fn nan_and_infinity_are_rejected() {
    let meas = MEASUREMENTS.replace("p2,m3,0.1,0.05,0.0199", "p2,m3,0.1,NaN,0.0199");
    rejects(
        "measurements.csv",
        &meas,
        &[
            "measurements.csv:5:",
            "field `y`",
            "finite number",
            "found \"NaN\"",
        ],
    );
    let contacts = CONTACTS.replace("0,0,-1.5", "0,0,-inf");
    rejects(
        "contacts.csv",
        &contacts,
        &[
            "contacts.csv:2:",
            "field `fz`",
            "finite number",
            "found \"-inf\"",
        ],
    );
}

#[test]
fn unknown_marker_is_rejected() {
    let meas = MEASUREMENTS.replace("p2,m3", "p2,m9");
    rejects(
        "measurements.csv",
        &meas,
        &[
            "measurements.csv:5:",
            "field `marker`",
            "unknown marker \"m9\"",
        ],
    );
}

#[test]
fn duplicate_ids_are_rejected() {
    let markers = MARKERS.replace("m3,", "m1,");
    rejects(
        "markers.csv",
        &markers,
        &[
            "markers.csv:5:",
            "field `marker`",
            "\"m1\" appears twice (first on line 2)",
        ],
    );
    let contacts = CONTACTS.replace("p2,", "p1,");
    rejects(
        "contacts.csv",
        &contacts,
        &[
            "contacts.csv:3:",
            "field `measurement`",
            "\"p1\" appears twice",
        ],
    );
    let meas = format!("{MEASUREMENTS}p1,m1,0.03,0.04,0.049\n");
    rejects(
        "measurements.csv",
        &meas,
        &[
            "measurements.csv:6:",
            "field `marker`",
            "\"p1/m1\" appears twice (first on line 2)",
        ],
    );
}

#[test]
fn measurement_without_contact_is_rejected() {
    let meas = format!("{MEASUREMENTS}p3,m1,0.03,0.04,0.049\n");
    rejects(
        "measurements.csv",
        &meas,
        &[
            "measurements.csv:6:",
            "field `measurement`",
            "\"p3\" has no contact",
        ],
    );
}

#[test]
fn contact_without_measurement_rows_is_rejected() {
    let contacts = format!("{CONTACTS}p3,0.05,0.05,0.05,0,0,-1\n");
    rejects(
        "contacts.csv",
        &contacts,
        &[
            "contacts.csv:4:",
            "field `measurement`",
            "\"p3\" has no rows in measurements.csv",
        ],
    );
}

#[test]
fn marker_far_from_surface_says_how_far() {
    // 30 mm above the top face; tolerance 1 × 25 mm.
    let markers = MARKERS.replace("m2,0.07,0.06,0.05", "m2,0.07,0.06,0.08");
    rejects(
        "markers.csv",
        &markers,
        &[
            "markers.csv:3:",
            "fields `x,y,z`",
            "\"m2\" is 3.000e-2 m",
            "tolerance is 2.500e-2 m",
            "marker_standoff",
        ],
    );
    // Declared stand-offs widen the tolerance by their height.
    let dir = tempfile::tempdir().unwrap();
    let toml = format!("{TOML}marker_standoff = 0.02\n");
    write_dataset(
        dir.path(),
        &[("markers.csv", &markers), ("dataset.toml", &toml)],
        &mesh(),
    );
    let d = StaticDataset::read(dir.path()).expect("a declared stand-off is accepted");
    assert_eq!(d.marker_standoff, Some(0.02));
}

/// A marker off the surface (here on a 10 mm post above the top face) is a material point carried
/// rigidly by its triangle: at rest it sits where it was declared, and when the whole mesh is
/// rotated rigidly it turns with it — the post's tip moves, not just its foot.
#[test]
fn a_marker_on_a_post_moves_rigidly_with_its_surface_patch() {
    let markers = MARKERS.replace("m2,0.07,0.06,0.05", "m2,0.07,0.06,0.06");
    let dir = tempfile::tempdir().unwrap();
    write_dataset(dir.path(), &[("markers.csv", &markers)], &mesh());
    let d = StaticDataset::read(dir.path()).expect("within one surface edge");
    let m = d.markers.iter().find(|m| m.id == "m2").unwrap();
    assert!((m.distance - 0.01).abs() < 1e-12, "{}", m.distance);
    let at_rest = m.interpolate(|n| d.mesh.nodes[n]);
    assert!(
        (0..3).all(|k| (at_rest[k] - m.rest[k]).abs() < 1e-12),
        "{at_rest:?}"
    );
    // A rigid rotation of 30° about z through the origin, then a shift.
    let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
    let move_rigidly = |p: [f64; 3]| [c * p[0] - s * p[1] + 0.01, s * p[0] + c * p[1], p[2] - 0.02];
    let moved = m.interpolate(|n| move_rigidly(d.mesh.nodes[n]));
    let expected = move_rigidly(m.rest);
    assert!(
        (0..3).all(|k| (moved[k] - expected[k]).abs() < 1e-12),
        "{moved:?} vs {expected:?}"
    );
    // A tilt about x turns the post: its tip moves sideways by the post's height × sin(tilt).
    let (c, s) = (10f64.to_radians().cos(), 10f64.to_radians().sin());
    let tilt = |p: [f64; 3]| [p[0], c * p[1] - s * p[2], s * p[1] + c * p[2]];
    let tilted = m.interpolate(|n| tilt(d.mesh.nodes[n]));
    let expected = tilt(m.rest);
    assert!((0..3).all(|k| (tilted[k] - expected[k]).abs() < 1e-12));
}

#[test]
fn missing_or_empty_fixed_group_is_rejected() {
    let toml = TOML.replace("\"bottom\"", "\"floor\"");
    rejects(
        "dataset.toml",
        &toml,
        &[
            "dataset.toml:5:",
            "field `clamps`",
            "no physical group \"floor\"",
            "\"bottom\"",
        ],
    );
    let toml = TOML.replace("\"bottom\"", "\"nothing\"");
    rejects(
        "dataset.toml",
        &toml,
        &[
            "dataset.toml:5:",
            "field `clamps`",
            "\"nothing\" of the mesh holds no node",
        ],
    );
}

#[test]
fn contact_radius_covering_no_node_is_rejected() {
    // Centre of a top cell: the nearest node is √2 × 12.5 mm = 17.68 mm away.
    let contacts = CONTACTS.replace(
        "p1,0.05,0.05,0.05,0,0,-1.5,0.02",
        "p1,0.0125,0.0125,0.05,0,0,-1.5,0.005",
    );
    rejects(
        "contacts.csv",
        &contacts,
        &[
            "contacts.csv:2:",
            "field `radius`",
            "\"p1\" loads no node",
            "5.000e-3 m",
            "nearest at 1.768e-2 m",
        ],
    );
    let contacts = CONTACTS.replace(",0.02\n", ",-0.02\n");
    rejects(
        "contacts.csv",
        &contacts,
        &[
            "contacts.csv:2:",
            "field `radius`",
            "expected a positive number",
        ],
    );
}

#[test]
fn contact_on_fixed_nodes_only_is_rejected() {
    // On the bottom face: the only nodes within 5 mm are fixed, and the rule skips fixed nodes.
    let contacts = CONTACTS.replace(
        "p1,0.05,0.05,0.05,0,0,-1.5,0.02",
        "p1,0.05,0.05,0.0,0,0,1,0.005",
    );
    rejects(
        "contacts.csv",
        &contacts,
        &["contacts.csv:2:", "field `radius`", "loads no node"],
    );
}

#[test]
fn inverted_and_zero_volume_elements_are_rejected() {
    // Node (1,1,1) of the 4 × 4 × 2 grid, index 31, sits at (25, 25, 25) mm.
    let mut m = mesh();
    assert_eq!(m.nodes[31], [0.025, 0.025, 0.025]);
    m.nodes[31][2] = 0.0; // onto the bottom plane: the Kuhn tets below it go flat
    let e = error_with_mesh(&[], &m);
    assert_has(&e, &["mesh.msh", "has zero volume"]);
    let mut m = mesh();
    m.nodes[31] = [0.06, 0.06, 0.025]; // across its neighbours: they fold over
    let e = error_with_mesh(&[], &m);
    assert_has(&e, &["mesh.msh", "is inverted", "element"]);
}

#[test]
fn bad_header_and_short_rows_are_rejected() {
    let markers = MARKERS.replace("marker,x,y,z", "id,x,y,z");
    rejects(
        "markers.csv",
        &markers,
        &[
            "markers.csv:1:",
            "field `header`",
            "\"marker,x,y,z\"",
            "found \"id,x,y,z\"",
        ],
    );
    let meas = MEASUREMENTS.replace("p1,m2,0.07,0.06,0.0495", "p1,m2,0.07,0.06");
    rejects(
        "measurements.csv",
        &meas,
        &[
            "measurements.csv:3:",
            "field `row`",
            "expected 5 comma-separated fields",
        ],
    );
}

#[test]
fn example_dataset_in_models_reads() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/dataset-example");
    let d = StaticDataset::read(dir).unwrap();
    assert_eq!((d.markers.len(), d.measurements.len()), (9, 2));
    // p1 misses m9 (occluded); p2 sees all nine.
    assert_eq!(d.measurements[0].observed.len(), 8);
    assert_eq!(d.measurements[1].observed.len(), 9);
    assert_eq!(d.measurements[0].radius, 0.01);
    assert_eq!(d.measurements[1].radius, 0.008);
    assert_eq!(d.gravity, Some([0.0, 0.0, -9.81]));
    // The markers lie on the flat top face of the sponge: distance 0 up to round-off.
    assert!(d.markers.iter().all(|m| m.distance < 1e-15));
}

/// What a spreadsheet program writes ("CSV UTF-8": a byte-order mark, CRLF line ends) reads as
/// the same dataset, and a line-numbered error still names the right line.
#[test]
fn spreadsheet_csv_with_byte_order_mark_and_crlf_reads_the_same() {
    let plain = tempfile::tempdir().unwrap();
    write_dataset(plain.path(), &[], &mesh());
    let windows = |t: &str| format!("\u{feff}{}", t.replace('\n', "\r\n"));
    let (markers, measurements, contacts, toml) = (
        windows(MARKERS),
        windows(MEASUREMENTS),
        windows(CONTACTS),
        windows(TOML),
    );
    let excel = tempfile::tempdir().unwrap();
    write_dataset(
        excel.path(),
        &[
            ("markers.csv", &markers),
            ("measurements.csv", &measurements),
            ("contacts.csv", &contacts),
            ("dataset.toml", &toml),
        ],
        &mesh(),
    );
    let a = StaticDataset::read(plain.path()).unwrap();
    let b = StaticDataset::read(excel.path()).unwrap();
    assert_eq!(a.markers, b.markers);
    assert_eq!(a.measurements, b.measurements);
    // The mark does not shift the line numbers: a bad number on line 3 is still line 3.
    let bad = windows(&MARKERS.replace("m2,0.07", "m2,0.0x7"));
    assert_has(
        &error_with(&[("markers.csv", &bad)]),
        &["markers.csv:3", "`x`", "0.0x7"],
    );
}

/// Measured positions in millimetres (or 1e308): a displacement larger than the object is in
/// other units, and the fit would start from it and go nowhere.
#[test]
fn a_displacement_larger_than_the_object_is_refused_with_its_cause() {
    rejects(
        "measurements.csv",
        "measurement,marker,x,y,z\np1,m1,30,40,49\np1,m2,0.07,0.06,0.0495\n\
p2,m1,0.03,0.04,0.0498\np2,m3,0.1,0.05,0.0199\n",
        &["measurements.csv:2", "field `x,y,z`", "millimetres"],
    );
    rejects(
        "measurements.csv",
        "measurement,marker,x,y,z\np1,m1,0.03,0.04,0.049\np1,m2,0.07,0.06,0.0495\n\
p2,m1,0.03,0.04,0.0498\np2,m3,0.1,1e308,0.0199\n",
        &[
            "measurements.csv:5",
            "field `x,y,z`",
            "1.0000e308",
            "no position",
        ],
    );
    // Displacements ×100: 0.3 m on a 10 cm box.
    rejects(
        "measurements.csv",
        "measurement,marker,x,y,z\np1,m1,0.03,0.04,-0.25\np1,m2,0.07,0.06,0.0495\n\
p2,m1,0.03,0.04,0.0498\np2,m3,0.1,0.05,0.0199\n",
        &["measurements.csv:2", "displacements scaled up"],
    );
}

#[test]
fn a_contact_radius_wider_than_the_object_is_refused() {
    rejects(
        "contacts.csv",
        "measurement,x,y,z,fx,fy,fz,radius\np1,0.05,0.05,0.05,0,0,-1.5,1e308\np2,0.05,0.05,0.05,0,0,-0.5\n",
        &["contacts.csv:2", "field `radius`", "mesh's size"],
    );
    rejects(
        "dataset.toml",
        &TOML.replace("probe_radius = 0.02", "probe_radius = 1e308"),
        &["dataset.toml:6", "field `probe_radius`", "mesh's size"],
    );
}
