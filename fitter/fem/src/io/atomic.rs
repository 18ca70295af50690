//! Atomic output: write to a temporary file (or folder) beside the target, then rename over it,
//! so a reader never sees a half-written file and a failed run leaves the old one intact.

use std::io::Write;
use std::path::{Path, PathBuf};

/// Why [`write_atomic`] or [`write_atomic_with`] did not write a file: the file, the step that
/// failed with the file or directory it was done to ("creating directory …", "writing …",
/// "renaming … to …"), and the operating-system error. The target is then unchanged and no
/// temporary file is left behind.
#[derive(Debug, thiserror::Error)]
#[error("{what}: {source}")]
#[non_exhaustive]
pub struct AtomicWriteError {
    /// The file that was to be written.
    pub path: PathBuf,
    /// The step that failed, naming what it was done to.
    pub what: String,
    /// The operating-system error (or the error of the content's writer).
    pub source: std::io::Error,
}

impl AtomicWriteError {
    fn new(path: &Path, what: String, source: std::io::Error) -> Self {
        Self {
            path: path.to_path_buf(),
            what,
            source,
        }
    }
}

/// Writes `bytes` to `path` atomically (temporary file in the same directory + rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), AtomicWriteError> {
    write_atomic_with(path, |w| w.write_all(bytes))
}

/// Like [`write_atomic`], but the content is produced by `fill` writing into a buffered writer
/// (e.g. with `writeln!`); an error of `fill` is reported as "writing `path`".
pub fn write_atomic_with(
    path: &Path,
    fill: impl FnOnce(&mut std::io::BufWriter<std::fs::File>) -> std::io::Result<()>,
) -> Result<(), AtomicWriteError> {
    let err = |what: String| move |e: std::io::Error| AtomicWriteError::new(path, what, e);
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(err(format!("creating directory {}", dir.display())))?;
    let Some(name) = path.file_name() else {
        return Err(AtomicWriteError::new(
            path,
            format!("writing {}", path.display()),
            std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "the path has no file name",
            ),
        ));
    };
    let tmp = dir.join(format!(
        ".{}.{}.tmp",
        name.to_string_lossy(),
        std::process::id()
    ));
    let result = (|| {
        let file =
            std::fs::File::create(&tmp).map_err(err(format!("creating {}", tmp.display())))?;
        let mut w = std::io::BufWriter::new(file);
        fill(&mut w).map_err(err(format!("writing {}", path.display())))?;
        let file = w
            .into_inner()
            .map_err(|e| e.into_error())
            .map_err(err(format!("flushing {}", tmp.display())))?;
        file.sync_all()
            .map_err(err(format!("syncing {}", tmp.display())))?;
        std::fs::rename(&tmp, path).map_err(err(format!(
            "renaming {} to {}",
            tmp.display(),
            path.display()
        )))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// A folder filled beside its final place and swapped in by [`StagedDir::commit`]: a run that
/// fails before the commit (or is dropped) removes its staging folder and leaves whatever was at
/// the target untouched.
#[derive(Debug)]
pub struct StagedDir {
    path: PathBuf,
    target: PathBuf,
    committed: bool,
}

impl StagedDir {
    /// Creates the empty staging folder `.<name>.<pid>.staging` beside `target` (which may
    /// exist, as a folder, and is not touched).
    pub fn new(target: &Path) -> Result<Self, AtomicWriteError> {
        let err = |what: String| move |e: std::io::Error| AtomicWriteError::new(target, what, e);
        let Some(name) = target.file_name() else {
            return Err(AtomicWriteError::new(
                target,
                format!("staging {}", target.display()),
                std::io::Error::new(
                    std::io::ErrorKind::InvalidInput,
                    "the path has no folder name",
                ),
            ));
        };
        if target.exists() && !target.is_dir() {
            return Err(AtomicWriteError::new(
                target,
                format!("staging {}", target.display()),
                std::io::Error::new(
                    std::io::ErrorKind::AlreadyExists,
                    "a file is in the way: the output is a folder",
                ),
            ));
        }
        let path = target.with_file_name(format!(
            ".{}.{}.staging",
            name.to_string_lossy(),
            std::process::id()
        ));
        if path.exists() {
            std::fs::remove_dir_all(&path)
                .map_err(err(format!("removing stale {}", path.display())))?;
        }
        std::fs::create_dir_all(&path).map_err(err(format!("creating {}", path.display())))?;
        Ok(Self {
            path,
            target: target.to_path_buf(),
            committed: false,
        })
    }

    /// Where the files go until the commit.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The folder the staged one replaces.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// `file` (inside the staging folder) at its final place.
    pub fn final_path(&self, file: &Path) -> PathBuf {
        match file.strip_prefix(&self.path) {
            Ok(rel) => self.target.join(rel),
            Err(_) => file.to_path_buf(),
        }
    }

    /// Swaps the staged folder in: the old target is first moved aside, so a failed rename puts
    /// it back and nothing is lost.
    pub fn commit(mut self) -> Result<PathBuf, AtomicWriteError> {
        let target = self.target.clone();
        let err = |what: String| {
            let target = &target;
            move |e: std::io::Error| AtomicWriteError::new(target, what, e)
        };
        let old = self.path.with_extension("old");
        let had_old = self.target.exists();
        if had_old {
            std::fs::rename(&self.target, &old).map_err(err(format!(
                "moving {} aside to {}",
                self.target.display(),
                old.display()
            )))?;
        }
        if let Err(e) = std::fs::rename(&self.path, &self.target) {
            if had_old {
                let _ = std::fs::rename(&old, &self.target);
            }
            return Err(err(format!(
                "renaming {} to {}",
                self.path.display(),
                self.target.display()
            ))(e));
        }
        self.committed = true;
        if had_old {
            std::fs::remove_dir_all(&old)
                .map_err(err(format!("removing the replaced {}", old.display())))?;
        }
        Ok(self.target.clone())
    }
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.path);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failed_write_keeps_old_file_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("out.csv");
        write_atomic(&p, b"old").unwrap();
        let r = write_atomic_with(&p, |w| {
            w.write_all(b"partial")?;
            Err(std::io::Error::other("simulated failure"))
        });
        let e = r.unwrap_err();
        assert_eq!(e.path, p);
        let msg = e.to_string();
        assert!(
            msg.contains("writing") && msg.contains("out.csv") && msg.contains("simulated failure"),
            "{msg}"
        );
        assert_eq!(std::fs::read(&p).unwrap(), b"old");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn unwritable_directory_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let blocker = dir.path().join("file");
        std::fs::write(&blocker, b"x").unwrap();
        let e = write_atomic(&blocker.join("sub").join("out.csv"), b"y").unwrap_err();
        assert!(e.to_string().starts_with("creating directory "), "{e}");
    }

    #[test]
    fn a_staged_folder_replaces_the_old_only_on_commit() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out");
        std::fs::create_dir(&target).unwrap();
        std::fs::write(target.join("old.csv"), b"old").unwrap();
        {
            let staged = StagedDir::new(&target).unwrap();
            std::fs::write(staged.path().join("half.csv"), b"x").unwrap();
            // Dropped without a commit: the run failed.
        }
        assert_eq!(std::fs::read(target.join("old.csv")).unwrap(), b"old");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        let staged = StagedDir::new(&target).unwrap();
        let new = staged.path().join("new.csv");
        std::fs::write(&new, b"new").unwrap();
        assert_eq!(staged.final_path(&new), target.join("new.csv"));
        staged.commit().unwrap();
        assert!(!target.join("old.csv").exists());
        assert_eq!(std::fs::read(target.join("new.csv")).unwrap(), b"new");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn a_file_in_the_way_of_a_folder_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out");
        std::fs::write(&target, b"x").unwrap();
        let e = StagedDir::new(&target).unwrap_err();
        assert!(e.to_string().contains("a file is in the way"), "{e}");
    }
}
