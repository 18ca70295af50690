//! What the README states about the build is what `Cargo.toml` says: every dependency of the
//! workspace has a row in the README's dependency table, every crate in the table is a
//! dependency, and the features the table names are the ones the manifest enables (postcard
//! without `use-crc`, the crates built without their default features). A dependency added to
//! `Cargo.toml` without a line saying why it is there fails here.

use crate::common;

use std::path::Path;

/// A dependency's specification in a manifest: `"1.0"` or `{ version, features, … }`.
#[derive(Debug)]
struct Spec {
    default_features: bool,
    features: Vec<String>,
}

fn spec_of(value: &toml::Value) -> Spec {
    let table = value.as_table();
    let default_features = table
        .and_then(|t| t.get("default-features"))
        .and_then(toml::Value::as_bool)
        .unwrap_or(true);
    let features = table
        .and_then(|t| t.get("features"))
        .and_then(toml::Value::as_array)
        .map(|a| {
            a.iter()
                .filter_map(|f| f.as_str().map(str::to_string))
                .collect()
        })
        .unwrap_or_default();
    Spec {
        default_features,
        features,
    }
}

fn is_path(value: &toml::Value) -> bool {
    value.as_table().is_some_and(|t| t.contains_key("path"))
}

fn read_toml(path: &Path) -> toml::Table {
    let text = std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("{}: cannot read: {e}", path.display()));
    text.parse()
        .unwrap_or_else(|e| panic!("{}: not TOML: {e}", path.display()))
}

/// The external (non-path) dependencies of the root's `[workspace.dependencies]`, in order.
fn workspace_dependencies(root: &toml::Table) -> Vec<(String, Spec)> {
    root["workspace"]["dependencies"]
        .as_table()
        .expect("Cargo.toml: [workspace.dependencies] is a table")
        .iter()
        .filter(|(_, v)| !is_path(v))
        .map(|(k, v)| (k.clone(), spec_of(v)))
        .collect()
}

/// The external dependencies a member manifest declares itself (not `workspace = true`), from
/// `[dependencies]`, `[dev-dependencies]` and every `[target.….dependencies]`.
fn own_dependencies(manifest: &toml::Table) -> Vec<(String, Spec)> {
    let mut tables: Vec<&toml::Table> = Vec::new();
    for key in ["dependencies", "dev-dependencies", "build-dependencies"] {
        tables.extend(manifest.get(key).and_then(toml::Value::as_table));
    }
    if let Some(targets) = manifest.get("target").and_then(toml::Value::as_table) {
        for t in targets.values().filter_map(toml::Value::as_table) {
            for key in ["dependencies", "dev-dependencies"] {
                tables.extend(t.get(key).and_then(toml::Value::as_table));
            }
        }
    }
    tables
        .into_iter()
        .flat_map(|t| t.iter())
        .filter(|(_, v)| {
            !is_path(v)
                && !v.as_table().is_some_and(|t| {
                    t.get("workspace").and_then(toml::Value::as_bool) == Some(true)
                })
        })
        .map(|(k, v)| (k.clone(), spec_of(v)))
        .collect()
}

/// One row of the README's table: the crates it names and what its parentheses say.
#[derive(Debug)]
struct Row {
    line: usize,
    crates: Vec<String>,
    details: String,
}

/// The rows of the table under the README's `## Dependencies` heading: first cell
/// `crate[, crate…] [(details)]`.
fn dependency_rows(readme: &str) -> Vec<Row> {
    let mut rows = Vec::new();
    let mut in_section = false;
    for (i, line) in readme.lines().enumerate() {
        if line.starts_with("## ") {
            in_section = line.starts_with("## Dependencies");
            continue;
        }
        if !in_section || !line.starts_with('|') || line.starts_with("|---") {
            continue;
        }
        let cell = line
            .trim_start_matches('|')
            .split('|')
            .next()
            .unwrap_or("")
            .trim();
        if cell == "crate" {
            continue;
        }
        let (names, details) = match cell.find('(') {
            Some(open) => (
                &cell[..open],
                cell[open + 1..].trim_end_matches(')').to_string(),
            ),
            None => (cell, String::new()),
        };
        rows.push(Row {
            line: i + 1,
            crates: names
                .split(',')
                .map(|n| n.trim().to_string())
                .filter(|n| !n.is_empty())
                .collect(),
            details,
        });
    }
    rows
}

/// The features a row's details name, split into enabled (`` `f` ``) and refused (`` not `f` ``).
fn named_features(details: &str) -> (Vec<String>, Vec<String>) {
    let mut on = Vec::new();
    let mut off = Vec::new();
    let mut rest = details;
    while let Some(start) = rest.find('`') {
        let Some(len) = rest[start + 1..].find('`') else {
            break;
        };
        let name = rest[start + 1..start + 1 + len].to_string();
        if rest[..start].trim_end().ends_with("not") {
            off.push(name);
        } else {
            on.push(name);
        }
        rest = &rest[start + len + 2..];
    }
    (on, off)
}

/// Every way the README's table and the manifests disagree, one line each.
fn disagreements(
    readme: &str,
    root: &toml::Table,
    members: &[(String, toml::Table)],
) -> Vec<String> {
    let rows = dependency_rows(readme);
    let workspace = workspace_dependencies(root);
    let mut found = Vec::new();
    if rows.is_empty() {
        found.push("README.md: no table under a `## Dependencies` heading".to_string());
        return found;
    }
    for (name, _) in &workspace {
        if !rows.iter().any(|r| r.crates.contains(name)) {
            found.push(format!(
                "README.md's dependency table has no row for `{name}`, which Cargo.toml's \
                 [workspace.dependencies] declares: say why it is there"
            ));
        }
    }
    // Where each crate's features are set: the workspace's table first, then the manifest that
    // declares the crate itself.
    let mut known: Vec<(String, Spec, String)> = workspace
        .into_iter()
        .map(|(n, s)| (n, s, "Cargo.toml [workspace.dependencies]".to_string()))
        .collect();
    for (path, m) in members {
        for (n, s) in own_dependencies(m) {
            if !known.iter().any(|(k, _, _)| *k == n) {
                known.push((n, s, path.clone()));
            }
        }
    }
    let spec = |name: &str| {
        known
            .iter()
            .find(|(n, _, _)| n == name)
            .map(|(_, s, at)| (s, at.as_str()))
    };
    for row in &rows {
        for name in &row.crates {
            if spec(name).is_none() {
                found.push(format!(
                    "README.md line {}: `{name}` is in the dependency table but no manifest \
                     depends on it",
                    row.line
                ));
            }
        }
        let (on, off) = named_features(&row.details);
        let says_no_default = row.details.contains("no default features");
        if row.crates.len() > 1 {
            for name in &row.crates {
                if let Some((s, at)) = spec(name) {
                    if !s.default_features || !s.features.is_empty() {
                        found.push(format!(
                            "README.md line {}: `{name}` shares a row, but {at} sets its features \
                             (default-features = {}, features = {:?}): give it a row of its own",
                            row.line, s.default_features, s.features
                        ));
                    }
                }
            }
            continue;
        }
        let Some(name) = row.crates.first() else {
            continue;
        };
        let Some((s, at)) = spec(name) else { continue };
        if says_no_default == s.default_features {
            found.push(format!(
                "README.md line {}: `{name}`: the table {} \"no default features\", {at} has \
                 default-features = {}",
                row.line,
                if says_no_default {
                    "says"
                } else {
                    "does not say"
                },
                s.default_features
            ));
        }
        for f in &on {
            if !s.features.contains(f) {
                found.push(format!(
                    "README.md line {}: `{name}`: the table names feature `{f}`, {at} enables \
                     {:?}",
                    row.line, s.features
                ));
            }
        }
        for f in &off {
            if s.features.contains(f) {
                found.push(format!(
                    "README.md line {}: `{name}`: the table says not `{f}`, {at} enables it",
                    row.line
                ));
            }
        }
        for f in &s.features {
            if !on.contains(f) {
                found.push(format!(
                    "README.md line {}: `{name}`: {at} enables feature `{f}`, the table does not \
                     name it",
                    row.line
                ));
            }
        }
    }
    found
}

/// The member manifests (workspace members and the excluded board binary), with their paths.
fn member_manifests(repo: &Path, root: &toml::Table) -> Vec<(String, toml::Table)> {
    let ws = &root["workspace"];
    ["members", "exclude"]
        .iter()
        .filter_map(|k| ws.get(*k).and_then(toml::Value::as_array))
        .flatten()
        .filter_map(toml::Value::as_str)
        .map(|m| {
            let path = format!("{m}/Cargo.toml");
            let t = read_toml(&repo.join(&path));
            (path, t)
        })
        .collect()
}

#[test]
fn the_readme_dependency_table_is_the_manifest() {
    let repo = common::repo();
    let root = read_toml(&repo.join("Cargo.toml"));
    let members = member_manifests(&repo, &root);
    let readme = std::fs::read_to_string(repo.join("README.md")).unwrap();
    let found = disagreements(&readme, &root, &members);
    assert!(found.is_empty(), "{}", found.join("\n"));
}

/// The check itself catches what it is for: a dependency added to Cargo.toml without a row, a
/// feature the table claims that the manifest leaves out, and a row for a crate nobody uses.
#[test]
fn the_check_catches_a_dependency_without_a_row_and_a_wrong_feature() {
    let repo = common::repo();
    let mut root = read_toml(&repo.join("Cargo.toml"));
    let members = member_manifests(&repo, &root);
    let readme = std::fs::read_to_string(repo.join("README.md")).unwrap();
    root["workspace"]["dependencies"]
        .as_table_mut()
        .unwrap()
        .insert("smallvec".into(), toml::Value::String("1".into()));
    let found = disagreements(&readme, &root, &members).join("\n");
    assert!(found.contains("no row for `smallvec`"), "{found}");

    let root = read_toml(&repo.join("Cargo.toml"));
    let claimed = readme.replace("not `use-crc`", "`use-crc`");
    let found = disagreements(&claimed, &root, &members).join("\n");
    assert!(
        found.contains("`postcard`: the table names feature `use-crc`"),
        "{found}"
    );

    let extra = readme.replace("| rayon |", "| rayon, crossbeam |");
    let found = disagreements(&extra, &root, &members).join("\n");
    assert!(
        found.contains("`crossbeam` is in the dependency table but no manifest"),
        "{found}"
    );
}

/// The toolchain the README says is tested is the workspace's `rust-version`.
#[test]
fn the_readme_toolchain_is_the_rust_version() {
    let repo = common::repo();
    let root = read_toml(&repo.join("Cargo.toml"));
    let version = root["workspace"]["package"]["rust-version"]
        .as_str()
        .expect("Cargo.toml: [workspace.package] rust-version");
    let readme = std::fs::read_to_string(repo.join("README.md")).unwrap();
    assert!(
        readme.contains(&format!("Rust {version} (stable)")),
        "README.md does not say \"Rust {version} (stable)\", Cargo.toml's rust-version"
    );
}
