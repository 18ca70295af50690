//! `out/demo/README.md`: what the demo found, for a person who opens its folder — the before/after
//! tables, the verdicts and the figures, each linked relative to the README so that the folder
//! can be moved or attached as a whole.
//!
//! Plain data in, one file out: the demo fills a [`DemoReadme`] from its results and
//! [`write()`] renders it, so the page can be checked on a small value without running the demo
//! (`tests/cli/demo_readme.rs`).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// A Markdown table: a caption above, a header row, and rows of already formatted cells.
#[derive(Debug, Clone, Default)]
pub struct Table {
    /// What the table shows, with its units.
    pub caption: String,
    /// Column titles.
    pub header: Vec<String>,
    /// Rows of cells, each as long as `header`.
    pub rows: Vec<Vec<String>>,
}

impl Table {
    /// The table as Markdown (the same text the demo prints on stdout).
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        let row = |cells: &[String]| format!("| {} |", cells.join(" | "));
        let _ = writeln!(s, "{}\n", self.caption);
        let _ = writeln!(s, "{}", row(&self.header));
        let _ = writeln!(s, "|{}", "---|".repeat(self.header.len()));
        for r in &self.rows {
            let _ = writeln!(s, "{}", row(r));
        }
        s
    }
}

/// One part of the demo (the measured beam, the synthetic specimen).
#[derive(Debug, Clone, Default)]
pub struct Part {
    /// The part's heading.
    pub title: String,
    /// Its verdict in words.
    pub verdict: String,
    /// Its before/after tables.
    pub tables: Vec<Table>,
    /// Further facts, one paragraph each.
    pub notes: Vec<String>,
    /// Its full report, relative to the README's folder.
    pub report: Option<PathBuf>,
    /// Its figures, relative to the README's folder.
    pub figures: Vec<PathBuf>,
}

/// The whole page.
#[derive(Debug, Clone, Default)]
pub struct DemoReadme {
    /// The command that made the folder.
    pub command: String,
    /// The demo's parts, in the order they ran.
    pub parts: Vec<Part>,
    /// Closing paragraphs (the haptic replay, the run time).
    pub notes: Vec<String>,
}

/// The figures among `files` (written under `dir`), relative to `dir`: one per figure, the SVG
/// when both an SVG and a PNG were drawn (it stays sharp when zoomed), else the PNG.
pub fn figures_in(dir: &Path, files: &[PathBuf]) -> Vec<PathBuf> {
    let ext = |p: &Path| {
        p.extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
    };
    let mut out = Vec::new();
    for f in files {
        let rel = match f.strip_prefix(dir) {
            Ok(rel) => rel.to_path_buf(),
            // A file outside the folder cannot be linked relative to it.
            Err(_) => continue,
        };
        match ext(f).as_deref() {
            Some("svg") => out.push(rel),
            Some("png") if !files.contains(&f.with_extension("svg")) => out.push(rel),
            _ => {}
        }
    }
    out
}

/// A figure's caption from its file name (`round1-stiffening.svg` → "round1 stiffening").
fn caption(p: &Path) -> String {
    p.file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("figure")
        .replace(['-', '_'], " ")
}

/// A path as a Markdown link target (forward slashes, spaces escaped).
fn link(p: &Path) -> String {
    p.components()
        .map(|c| c.as_os_str().to_string_lossy().replace(' ', "%20"))
        .collect::<Vec<_>>()
        .join("/")
}

/// The page's Markdown text.
pub fn markdown(r: &DemoReadme) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# What `{}` found\n", r.command);
    let _ = writeln!(
        s,
        "Each part fits the simplest model, lets the diagnosis add the effects that earn their \
         place on data it did not fit, and compares the two on that held-out data. Marker errors \
         are in millimetres.\n"
    );
    for p in &r.parts {
        let _ = writeln!(s, "## {}\n", p.title);
        let _ = writeln!(s, "**Verdict:** {}\n", p.verdict);
        for t in &p.tables {
            let _ = writeln!(s, "{}", t.markdown());
        }
        for n in &p.notes {
            let _ = writeln!(s, "{n}\n");
        }
        if let Some(rep) = &p.report {
            let _ = writeln!(
                s,
                "The full report, round by round: [{}]({}).\n",
                link(rep),
                link(rep)
            );
        }
        for f in &p.figures {
            let _ = writeln!(s, "![{}]({})\n", caption(f), link(f));
        }
    }
    if !r.notes.is_empty() {
        let _ = writeln!(s, "## Also\n");
        for n in &r.notes {
            let _ = writeln!(s, "{n}\n");
        }
    }
    s
}

/// Writes `dir/README.md` and returns its path.
pub fn write(dir: &Path, r: &DemoReadme) -> anyhow::Result<PathBuf> {
    let path = dir.join("README.md");
    palpate_fem::io::atomic::write_atomic(&path, markdown(r).as_bytes())
        .map_err(|e| anyhow::anyhow!("writing {}: {e}", path.display()))?;
    Ok(path)
}
