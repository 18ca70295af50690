//! Every dataset CSV is read by its header names: columns in any order, quoted fields unquoted
//! (`"m0"` is the marker m0), as spreadsheet programs write them. A dataset rewritten so reads
//! exactly as the original: `palpate info` says the same of both.

mod common;

use common::{assert_succeeded, palpate, repo, text};
use std::path::Path;

/// Copies the dataset folder `src` to `dst`.
fn copy_dir(src: &Path, dst: &Path) {
    std::fs::create_dir_all(dst).unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), dst.join(e.file_name())).unwrap();
    }
}

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
