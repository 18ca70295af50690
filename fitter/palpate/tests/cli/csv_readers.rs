//! Every dataset CSV is read by its header names: columns in any order, quoted fields unquoted
//! (`"m0"` is the marker m0), as spreadsheet programs write them. A dataset rewritten so reads
//! exactly as the original: `palpate info` says the same of both.

use crate::common;

use common::{assert_succeeded, copy_dir, palpate, repo, text};
use std::path::Path;

/// Rewrites the CSV `file` with its columns in the order `order` (header names) and every value
/// of column `quoted` in double quotes.
fn reorder_and_quote(file: &Path, order: &[&str], quoted: &str) {
    let t = std::fs::read_to_string(file).unwrap();
    let mut lines = t.lines().filter(|l| !l.trim().is_empty());
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(head.len(), order.len(), "{}", file.display());
    let at: Vec<usize> = order
        .iter()
        .map(|n| head.iter().position(|h| h == n).unwrap())
        .collect();
    let mut out = format!("{}\n", order.join(","));
    for l in lines {
        let f: Vec<&str> = l.split(',').collect();
        // A row may leave out trailing optional fields: they stay left out.
        let row: Vec<String> = at
            .iter()
            .filter_map(|&p| {
                let v = f.get(p)?;
                Some(if head[p] == quoted {
                    format!("\"{v}\"")
                } else {
                    v.to_string()
                })
            })
            .collect();
        out.push_str(&row.join(","));
        out.push('\n');
    }
    std::fs::write(file, out).unwrap();
}

/// `palpate info DIR` with DIR's path left out of what it prints.
fn info(dir: &Path) -> String {
    let o = palpate().arg("info").arg(dir).output().unwrap();
    assert_succeeded(&o);
    text(&o.stdout).replace(&dir.display().to_string(), "DIR")
}

#[test]
fn static_dataset_csvs_read_by_header_names_with_quoted_ids() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let src = repo().join("models/dataset-example");
    // The example's mesh is a sibling folder: name it absolutely in both copies.
    let mesh = format!(
        "{:?}",
        src.join("../sponge/sponge.msh").display().to_string()
    );
    for d in [&a, &b] {
        copy_dir(&src, d);
        let toml = d.join("dataset.toml");
        let t = std::fs::read_to_string(&toml).unwrap();
        std::fs::write(&toml, t.replace("\"../sponge/sponge.msh\"", &mesh)).unwrap();
    }
    reorder_and_quote(&b.join("markers.csv"), &["z", "marker", "y", "x"], "marker");
    reorder_and_quote(
        &b.join("measurements.csv"),
        &["marker", "x", "measurement", "z", "y"],
        "measurement",
    );
    // The optional `radius` is missing from a row: only the ids are quoted.
    reorder_and_quote(
        &b.join("contacts.csv"),
        &["measurement", "x", "y", "z", "fx", "fy", "fz", "radius"],
        "measurement",
    );
    assert!(std::fs::read_to_string(b.join("markers.csv"))
        .unwrap()
        .contains("\"m1\""));
    assert_eq!(info(&b), info(&a));
}

#[test]
fn motion_dataset_csvs_read_by_header_names_with_quoted_ids() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let src = repo().join("models/motion-example");
    copy_dir(&src, &a);
    copy_dir(&src, &b);
    reorder_and_quote(&b.join("markers.csv"), &["y", "x", "z", "marker"], "marker");
    reorder_and_quote(
        &b.join("trajectories.csv"),
        &["marker", "z", "t", "y", "x"],
        "marker",
    );
    reorder_and_quote(
        &b.join("clamps.csv"),
        &["clamp", "t", "uz", "uy", "ux"],
        "clamp",
    );
    assert_eq!(info(&b), info(&a));
}

/// The file `name` a command wrote into the folder `out` of `tmp`.
fn written(tmp: &Path, out: &str, name: &str) -> String {
    std::fs::read_to_string(tmp.join(out).join(name)).unwrap()
}

/// The capture import's marker places are read by header names too: columns in any order, quoted
/// labels unquoted (a label holds spaces: `Tip - 1`), imported to the very same trajectories; a
/// bad field is named by file, line and column.
#[test]
fn import_places_read_by_header_names_and_a_bad_field_named() {
    let tmp = tempfile::tempdir().unwrap();
    let src = repo().join("models/silicone-beam/marker-places.csv");
    let places = tmp.path().join("places.csv");
    let body: String = std::fs::read_to_string(&src)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(&places, body).unwrap();
    reorder_and_quote(&places, &["z", "x", "marker", "y"], "marker");
    let t = std::fs::read_to_string(&places).unwrap();
    assert!(t.contains("\"Tip - 1\""), "{t}");
    let import = |places: &Path, out: &str| {
        common::import_beam_with_places("beam_gravity_V2_a.c3d", places)
            .arg("-o")
            .arg(tmp.path().join(out))
            .output()
            .unwrap()
    };
    assert_succeeded(&import(&src, "a"));
    assert_succeeded(&import(&places, "b"));
    let trajectories = |d: &str| written(tmp.path(), d, "trajectories.csv");
    assert_eq!(trajectories("b"), trajectories("a"));

    // A comment above the header: the broken row, the table's second, is the file's line 4.
    let mut lines: Vec<String> = t.lines().map(String::from).collect();
    let mut row: Vec<String> = lines[2].split(',').map(String::from).collect();
    row[3] = "0.0x15".into();
    lines[2] = row.join(",");
    let bad = tmp.path().join("bad.csv");
    std::fs::write(&bad, format!("# places\n{}\n", lines.join("\n"))).unwrap();
    let o = import(&bad, "c");
    let err = common::refused(&o);
    assert!(
        err.contains(&format!(
            "{}:4: field `y`: expected a number, found \"0.0x15\"",
            bad.display()
        )),
        "{err}"
    );
}

/// `simulate --node-forces` reads its CSV by header names (any order, quoted fields) and names a
/// bad field by file, line and column.
#[test]
fn node_forces_read_by_header_names_and_a_bad_field_named() {
    let tmp = tempfile::tempdir().unwrap();
    let mesh_file = repo().join("models/motion-example/mesh.msh");
    let mesh = palpate_fem::mesh::gmsh::read_msh(&mesh_file).unwrap();
    let clamped = mesh.group("front").unwrap().to_vec();
    let free: Vec<u64> = (0..mesh.nodes.len())
        .filter(|n| !clamped.contains(n))
        .map(|n| mesh.node_tags[n])
        .take(3)
        .collect();
    let plain = tmp.path().join("plain.csv");
    let rows: String = free.iter().map(|t| format!("{t},0,0,-0.02\n")).collect();
    std::fs::write(&plain, format!("node,fx,fy,fz\n{rows}")).unwrap();
    let shuffled = tmp.path().join("shuffled.csv");
    std::fs::copy(&plain, &shuffled).unwrap();
    reorder_and_quote(&shuffled, &["fz", "node", "fx", "fy"], "node");
    let simulate = |forces: &Path, out: &str| {
        palpate()
            .arg("simulate")
            .arg("--mesh")
            .arg(&mesh_file)
            .args(["--young", "50000", "--poisson", "0.3", "--clamps", "front"])
            .arg("--node-forces")
            .arg(forces)
            .arg("-o")
            .arg(tmp.path().join(out))
            .output()
            .unwrap()
    };
    assert_succeeded(&simulate(&plain, "a"));
    assert_succeeded(&simulate(&shuffled, "b"));
    let u = |d: &str| written(tmp.path(), d, "displacements.csv");
    assert_eq!(u("b"), u("a"));

    let bad = tmp.path().join("bad.csv");
    std::fs::write(
        &bad,
        format!("node,fx,fy,fz\n{},0,0,-0.02\n\"12x\",0,0,-0.02\n", free[0]),
    )
    .unwrap();
    let err = common::refused(&simulate(&bad, "c"));
    assert!(
        err.contains(&format!(
            "{}:3: field `node`: expected a whole number >= 0, found \"12x\"",
            bad.display()
        )),
        "{err}"
    );
}
