//! Atomic file output: write to a temporary file beside the target, then rename over it, so a
//! reader never sees a half-written file and a failed run leaves the old file intact.

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
}
