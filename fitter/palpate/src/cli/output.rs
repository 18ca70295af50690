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

/// A directory to write a report into beside its final place; [`Staged::commit`] swaps it in.
pub struct Staged {
    /// Where the files go now.
    pub path: PathBuf,
    target: PathBuf,
}

impl Staged {
    /// Stages `target` (a directory that may already exist).
    pub fn new(target: &Path) -> anyhow::Result<Self> {
        let name = target
            .file_name()
            .with_context(|| format!("{} has no name", target.display()))?;
        let path = target.with_file_name(format!(
            ".{}.{}.staging",
            name.to_string_lossy(),
            std::process::id()
        ));
        if path.exists() {
            std::fs::remove_dir_all(&path)
                .with_context(|| format!("removing stale {}", path.display()))?;
        }
        std::fs::create_dir_all(&path).with_context(|| format!("creating {}", path.display()))?;
        Ok(Self {
            path,
            target: target.to_path_buf(),
        })
    }

    /// Replaces the target directory by the staged one; `files` written into the staging
    /// directory are returned at their final paths.
    pub fn commit(self, files: Vec<PathBuf>) -> anyhow::Result<Vec<PathBuf>> {
        if self.target.exists() {
            std::fs::remove_dir_all(&self.target)
                .with_context(|| format!("replacing {}", self.target.display()))?;
        }
        std::fs::rename(&self.path, &self.target).with_context(|| {
            format!(
                "renaming {} to {}",
                self.path.display(),
                self.target.display()
            )
        })?;
        Ok(files
            .into_iter()
            .map(|f| match f.strip_prefix(&self.path) {
                Ok(rel) => self.target.join(rel),
                Err(_) => f,
            })
            .collect())
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
