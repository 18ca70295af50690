//! Output paths of the commands: checked before any long work, and replaced as a whole at the end.
//!
//! Why: a fit that runs for minutes and then finds its output directory unwritable wastes the
//! user's time; a fit killed half-way must not leave a new model beside half of an old report.

use std::path::{Path, PathBuf};

use anyhow::Context;

/// Checks that files can be created where `path` will be written (creating its parent directory
/// if needed), by creating and removing a probe file — before the work starts.
pub fn check_writable(path: &Path) -> anyhow::Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).with_context(|| {
        format!(
            "output {}: cannot create directory {}",
            path.display(),
            dir.display()
        )
    })?;
    if path.is_dir() && path.extension().is_some() {
        anyhow::bail!("output {}: is a directory, expected a file", path.display());
    }
    let probe = dir.join(format!(".palpate-write-check.{}", std::process::id()));
    std::fs::write(&probe, b"").with_context(|| {
        format!(
            "output {}: cannot write in {}",
            path.display(),
            dir.display()
        )
    })?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// A directory to write a report or dataset into beside its final place; [`Staged::commit`]
/// swaps it in, and a run that fails before that leaves the old one as it was.
pub struct Staged {
    /// Where the files go now.
    pub path: PathBuf,
    inner: palpate_fem::io::atomic::StagedDir,
}

impl Staged {
    /// Stages `target` (a directory that may already exist).
    pub fn new(target: &Path) -> anyhow::Result<Self> {
        let inner = palpate_fem::io::atomic::StagedDir::new(target)?;
        Ok(Self {
            path: inner.path().to_path_buf(),
            inner,
        })
    }

    /// Replaces the target directory by the staged one; `files` written into the staging
    /// directory are returned at their final paths.
    pub fn commit(self, files: Vec<PathBuf>) -> anyhow::Result<Vec<PathBuf>> {
        let files = files.iter().map(|f| self.inner.final_path(f)).collect();
        self.inner.commit()?;
        Ok(files)
    }
}

/// A finite, non-negative number (clap value parser for regularisation weights and the like).
pub fn non_negative(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        Ok(v) => Err(format!("{v} is not a finite number ≥ 0")),
        Err(_) => Err(format!("{s:?} is not a number")),
    }
}

/// `--plot-format` of the commands that write figures.
#[derive(Debug, Clone, clap::Args)]
pub struct PlotArgs {
    /// Figures as png, svg or both (the Markdown reports link to the SVG when there is one).
    #[arg(long, default_value = "both", value_parser = plot_format())]
    pub plot_format: palpate_plot::PlotFormat,
}

impl PlotArgs {
    /// Makes every figure this run writes use the chosen format.
    pub fn apply(&self) {
        palpate_plot::set_format(self.plot_format);
    }
}

fn plot_format() -> impl clap::builder::TypedValueParser<Value = palpate_plot::PlotFormat> {
    use clap::builder::TypedValueParser as _;
    clap::builder::PossibleValuesParser::new(palpate_plot::PlotFormat::NAMES).map(|s| {
        s.parse::<palpate_plot::PlotFormat>()
            .expect("PossibleValuesParser passes only PlotFormat::NAMES")
    })
}
