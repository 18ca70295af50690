//! `out/demo/README.md` checked on a small value: the writer the demo calls, without the demo's
//! minutes of fitting. The page must hold both before/after tables and the verdicts, and every
//! figure or report it links must exist at a path relative to the page.

#[path = "../../src/cli/demo_readme.rs"]
#[allow(dead_code)]
mod writer;

use std::path::{Path, PathBuf};
use writer::{figures_in, write, DemoReadme, Part, Table};

fn table(caption: &str, first: &str, row: &[&str]) -> Table {
    Table {
        caption: caption.into(),
        header: vec![first.into(), "held-out RMS".into()],
        rows: vec![row.iter().map(|c| c.to_string()).collect()],
    }
}

/// Writes empty files at `names` under `root` and returns their paths.
fn touch(root: &Path, names: &[&str]) -> Vec<PathBuf> {
    names
        .iter()
        .map(|n| {
            let p = root.join(n);
            std::fs::create_dir_all(p.parent().unwrap()).unwrap();
            std::fs::write(&p, b"").unwrap();
            p
        })
        .collect()
}

/// The targets of every Markdown link and image on the page.
fn links(md: &str) -> Vec<String> {
    md.split("](")
        .skip(1)
        .map(|rest| rest[..rest.find(')').unwrap()].to_string())
        .collect()
}

#[test]
fn the_demo_readme_holds_both_tables_and_links_only_existing_figures() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    let beam_files = touch(
        root,
        &[
            "beam/diagnosis/diagnosis.md",
            "beam/diagnosis/fit.json",
            "beam/diagnosis/ring-load52_V2_b.svg",
            "beam/diagnosis/ring-load52_V2_b.png",
        ],
    );
    let specimen_files = touch(
        root,
        &[
            "diagnosis/diagnosis.md",
            "diagnosis/round1-stiffening.png",
            "diagnosis/noise.png",
        ],
    );
    let readme = DemoReadme {
        command: "palpate demo".into(),
        parts: vec![
            Part {
                title: "A measured silicone beam".into(),
                verdict: "adopted stiffening; held-out marker RMS 1.200 → 0.600 mm".into(),
                tables: vec![table(
                    "Held-out runs",
                    "held-out run",
                    &["load52_V2_b", "1.200 → 0.600"],
                )],
                notes: vec!["Neo-Hookean E = 131.5 kPa".into()],
                report: Some("beam/diagnosis/diagnosis.md".into()),
                figures: figures_in(root, &beam_files),
            },
            Part {
                title: "A synthetic specimen".into(),
                verdict: "explained by the noise floor".into(),
                tables: vec![table(
                    "Before / after",
                    "model",
                    &["simplest (linear homogeneous)", "0.310"],
                )],
                notes: Vec::new(),
                report: Some("diagnosis/diagnosis.md".into()),
                figures: figures_in(root, &specimen_files),
            },
        ],
        notes: vec!["Haptic replay: 2000 samples solved".into()],
    };
    let path = write(root, &readme).unwrap();
    assert_eq!(path, root.join("README.md"));
    let md = std::fs::read_to_string(&path).unwrap();

    for part in [
        "| held-out run | held-out RMS |",
        "| load52_V2_b | 1.200 → 0.600 |",
        "| model | held-out RMS |",
        "| simplest (linear homogeneous) | 0.310 |",
        "adopted stiffening",
        "explained by the noise floor",
        "E = 131.5 kPa",
        "Haptic replay",
    ] {
        assert!(md.contains(part), "README lacks {part:?}:\n{md}");
    }
    let targets = links(&md);
    // Three figures (the ring as SVG only, the two PNG-only figures) and the two reports.
    let figures: Vec<_> = targets
        .iter()
        .filter(|t| t.ends_with(".svg") || t.ends_with(".png"))
        .collect();
    assert_eq!(figures.len(), 3, "{md}");
    assert!(!md.contains("ring-load52_V2_b.png"), "{md}");
    assert!(
        targets.iter().any(|t| t == "diagnosis/diagnosis.md"),
        "{md}"
    );
    for t in &targets {
        let p = Path::new(t);
        assert!(p.is_relative(), "link {t} is not relative to the README");
        assert!(root.join(p).is_file(), "link {t} points at nothing");
    }
}
