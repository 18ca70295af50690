//! ARCHITECTURE.md checked against the code: its code map must state each workspace crate's own
//! dependencies exactly as `cargo metadata` reads them from the manifests, no crate may reach
//! (directly or through others) a crate its row says it must not depend on, and every path the
//! page names must exist. A map that a newcomer trusts has to fail the build when it drifts.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ has a parent")
        .to_path_buf()
}

/// Workspace members and their normal (not dev, not build) dependencies on other members, as
/// cargo resolves the manifests.
fn cargo_graph(root: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .args([
            "metadata",
            "--format-version",
            "1",
            "--no-deps",
            "--offline",
        ])
        .current_dir(root)
        .output()
        .expect("cargo metadata runs");
    assert!(
        out.status.success(),
        "cargo metadata failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta: serde_json::Value =
        serde_json::from_slice(&out.stdout).expect("cargo metadata is JSON");
    let packages = meta["packages"].as_array().expect("packages");
    let members: BTreeSet<String> = packages
        .iter()
        .map(|p| p["name"].as_str().expect("name").to_owned())
        .collect();
    packages
        .iter()
        .map(|p| {
            let deps = p["dependencies"]
                .as_array()
                .expect("dependencies")
                .iter()
                .filter(|d| d["kind"].is_null())
                .map(|d| d["name"].as_str().expect("dependency name").to_owned())
                .filter(|n| members.contains(n) && n != p["name"].as_str().unwrap())
                .collect();
            (p["name"].as_str().unwrap().to_owned(), deps)
        })
        .collect()
}

/// The cells of a Markdown table row; `\|` inside a cell is a literal bar, not a separator.
fn cells(row: &str) -> Vec<String> {
    let inner = row.trim().trim_start_matches('|').trim_end_matches('|');
    let mut out = vec![String::new()];
    let mut prev = ' ';
    for c in inner.chars() {
        if c == '|' && prev != '\\' {
            out.push(String::new());
        } else {
            out.last_mut().unwrap().push(c);
        }
        prev = c;
    }
    out.into_iter().map(|c| c.trim().to_owned()).collect()
}

/// The `backticked` words of a cell.
fn ticked(cell: &str) -> Vec<String> {
    cell.split('`')
        .skip(1)
        .step_by(2)
        .map(str::to_owned)
        .collect()
}

struct Row {
    krate: String,
    depends_on: BTreeSet<String>,
    must_not: BTreeSet<String>,
}

/// The code map: the table whose header starts `| folder | crate |`.
fn code_map(page: &str) -> Vec<Row> {
    let mut lines = page
        .lines()
        .skip_while(|l| !l.starts_with("| folder | crate |"));
    let header = cells(lines.next().expect("ARCHITECTURE.md has a code map table"));
    let col = |name: &str| {
        header
            .iter()
            .position(|h| h == name)
            .unwrap_or_else(|| panic!("code map has no column `{name}`: {header:?}"))
    };
    let (c_crate, c_deps, c_not) = (col("crate"), col("depends on"), col("must not depend on"));
    lines
        .skip(1) // the |---| line
        .take_while(|l| l.starts_with('|'))
        .map(|l| {
            let c = cells(l);
            let krate = ticked(&c[c_crate])
                .into_iter()
                .next()
                .expect("crate cell names the crate");
            let names = |cell: &str| {
                ticked(cell)
                    .into_iter()
                    .filter(|n| n.starts_with("palpate"))
                    .collect()
            };
            Row {
                krate,
                depends_on: names(&c[c_deps]),
                must_not: names(&c[c_not]),
            }
        })
        .collect()
}

fn closure(graph: &BTreeMap<String, BTreeSet<String>>, from: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut stack: Vec<&str> = graph[from].iter().map(String::as_str).collect();
    while let Some(n) = stack.pop() {
        if seen.insert(n.to_owned()) {
            stack.extend(graph[n].iter().map(String::as_str));
        }
    }
    seen
}

#[test]
fn the_code_map_states_every_crate_and_its_dependencies_as_the_manifests_do() {
    let root = workspace_root();
    let page = std::fs::read_to_string(root.join("ARCHITECTURE.md")).expect("ARCHITECTURE.md");
    let graph = cargo_graph(&root);
    let rows = code_map(&page);

    let mapped: BTreeSet<&str> = rows.iter().map(|r| r.krate.as_str()).collect();
    let members: BTreeSet<&str> = graph.keys().map(String::as_str).collect();
    assert_eq!(
        mapped, members,
        "the code map's crates differ from the workspace members"
    );

    let mut wrong = Vec::new();
    for r in &rows {
        let actual = &graph[&r.krate];
        if &r.depends_on != actual {
            wrong.push(format!(
                "{}: ARCHITECTURE.md says it depends on {:?}, its Cargo.toml on {:?}",
                r.krate, r.depends_on, actual
            ));
        }
        let reach = closure(&graph, &r.krate);
        for banned in &r.must_not {
            assert!(
                members.contains(banned.as_str()),
                "{}: `{banned}` in \"must not depend on\" is no crate",
                r.krate
            );
            if reach.contains(banned) {
                wrong.push(format!(
                    "{}: must not depend on {banned}, but reaches it",
                    r.krate
                ));
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "ARCHITECTURE.md's code map is not the crate graph:\n{}",
        wrong.join("\n")
    );
}

#[test]
fn every_path_the_architecture_page_names_exists() {
    let root = workspace_root();
    let page = std::fs::read_to_string(root.join("ARCHITECTURE.md")).expect("ARCHITECTURE.md");
    // A backticked word with a slash and no spaces is a repository path (`fitter/fem/src/mesh/`,
    // `runtime/src/tick.rs`); Rust paths use `::` and are not checked here.
    let missing: Vec<String> = ticked(&page)
        .into_iter()
        .filter(|t| t.contains('/') && !t.contains(' ') && !t.contains("::"))
        // `*` and `<kind>` mark a pattern or a template, not one path.
        .filter(|t| !t.contains('*') && !t.contains('<'))
        .filter(|t| !root.join(t.trim_end_matches('/')).exists())
        .collect();
    assert!(
        missing.is_empty(),
        "ARCHITECTURE.md names paths that do not exist: {missing:?}"
    );
}

#[test]
fn the_table_reader_finds_a_wrong_dependency() {
    // The check above must be able to fail: a row claiming a dependency the manifests lack.
    let page =
        "| folder | crate | what | depends on | must not depend on |\n|---|---|---|---|---|\n\
                | `a/` | `palpate-a` | x \\| y | `palpate-b` | `palpate-c` |\n";
    let rows = code_map(page);
    assert_eq!(rows.len(), 1);
    assert_eq!(rows[0].krate, "palpate-a");
    assert_eq!(rows[0].depends_on, BTreeSet::from(["palpate-b".to_owned()]));
    assert_eq!(rows[0].must_not, BTreeSet::from(["palpate-c".to_owned()]));
    let graph = BTreeMap::from([
        (
            "palpate-a".to_owned(),
            BTreeSet::from(["palpate-c".to_owned()]),
        ),
        ("palpate-c".to_owned(), BTreeSet::new()),
    ]);
    assert!(closure(&graph, "palpate-a").contains("palpate-c"));
}

/// The production crates a test file names (`palpate_motion::…` → `palpate-motion`), leaving out
/// the test helpers (`palpate_tests`) and the stand-in objects (`palpate_specimen`), and
/// counting the offline layer `palpate_fem` only where the file builds a runtime model with it
/// (its exporter, directly or through `palpate_tests::model`): a mesh or a dataset made by fem is
/// a test object, not a crate under test.
fn crates_under_test(source: &str) -> BTreeSet<String> {
    let mut found = BTreeSet::new();
    for (i, _) in source.match_indices("palpate_") {
        if i > 0 {
            let before = source.as_bytes()[i - 1];
            if before.is_ascii_alphanumeric() || before == b'_' {
                continue;
            }
        }
        let name: String = source[i..]
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect();
        found.insert(name.replace('_', "-"));
    }
    found.remove("palpate-tests");
    found.remove("palpate-specimen");
    let builds_models =
        source.contains("palpate_fem::export") || source.contains("palpate_tests::model");
    if !builds_models {
        found.remove("palpate-fem");
    }
    found
}

#[test]
fn the_cross_crate_tests_each_cross_crates() {
    // A test of one crate belongs in that crate's `tests/` folder, where `cargo test -p` that
    // crate runs it (ARCHITECTURE.md, "Tests").
    let dir = workspace_root().join("tests/tests/cross_crate");
    let mut single = Vec::new();
    for entry in std::fs::read_dir(&dir).expect("tests/tests/cross_crate") {
        let path = entry.expect("a directory entry").path();
        if path.file_name().is_some_and(|n| n == "main.rs") {
            continue;
        }
        let source = std::fs::read_to_string(&path).expect("a test file");
        let crates = crates_under_test(&source);
        if crates.len() < 2 {
            single.push(format!("{}: {crates:?}", path.display()));
        }
    }
    assert!(
        single.is_empty(),
        "test files in tests/tests/cross_crate/ that test one crate (move them to that crate's \
         tests/ folder):\n{}",
        single.join("\n")
    );
}

#[test]
fn the_crate_reader_tells_a_crossing_test_from_a_single_crate_one() {
    let one = "use palpate_diagnose::run;\nuse palpate_fem::mesh::Mesh;\nuse palpate_specimen::generate;\n";
    assert_eq!(
        crates_under_test(one),
        BTreeSet::from(["palpate-diagnose".to_owned()])
    );
    let two = "use palpate_fem::export::ModelBuffers;\nuse palpate_runtime::Runtime;\nlet x = my_palpate_link;\n";
    assert_eq!(
        crates_under_test(two),
        BTreeSet::from(["palpate-fem".to_owned(), "palpate-runtime".to_owned()])
    );
}
