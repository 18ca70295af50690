//! A capture as a palpate motion dataset (`docs/motion-dataset.md`): the markers registered from
//! the capture frame to the mesh frame on a frame at rest, their trajectories from the release
//! on, written as `markers.csv` and `trajectories.csv` beside a `dataset.toml`.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::{absolute_orientation, Capture, CaptureError, RegistrationError, RigidTransform};

/// What the import needs besides the capture.
#[derive(Debug, Clone)]
pub struct ImportOptions {
    /// Marker places in the mesh frame (m), by label: the markers used for the registration.
    pub places: Vec<(String, [f64; 3])>,
    /// The frame at rest on which the registration is computed (default 0: held before release).
    pub rest_frame: usize,
    /// The first simulated frame (the release); trajectories start one step after it.
    pub release_frame: usize,
    /// The last frame imported (inclusive); `None`: to the end.
    pub last_frame: Option<usize>,
    /// `dataset.toml` lines written as given (mesh, clamps, gravity, density, …).
    pub toml: String,
    /// Also track the capture's markers whose places are not declared, located from the rest
    /// frame through the registration (those far from the declared ones are left out).
    pub locate_undeclared: bool,
}

/// Errors of the import.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ImportError {
    /// The capture itself.
    #[error(transparent)]
    Capture(#[from] CaptureError),
    /// The registration.
    #[error("{path}: {source}")]
    Registration {
        /// The capture file.
        path: PathBuf,
        /// Why.
        source: RegistrationError,
    },
    /// A marker used for the registration is missing in the rest frame, or the frames are out of
    /// range.
    #[error("{path}: {what}")]
    Frames {
        /// The capture file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// Writing the dataset failed.
    #[error("writing {path}: {source}")]
    Write {
        /// The file.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
}

/// What the import did: the registration and its per-marker residuals.
#[derive(Debug, Clone)]
pub struct Imported {
    /// Capture frame → mesh frame.
    pub transform: RigidTransform,
    /// Labels in the order of `transform.residuals`.
    pub labels: Vec<String>,
    /// Simulated steps written.
    pub steps: usize,
    /// Files written.
    pub files: Vec<PathBuf>,
    /// Markers without a declared place, located from the rest frame.
    pub located: Vec<String>,
    /// Markers without a declared place left out: missing in the rest frame, or farther from the
    /// declared markers than half their spread (on the rig, not on the object).
    pub ignored: Vec<String>,
}

/// Registers `capture` on `o.rest_frame` and writes a motion dataset into `out`.
pub fn import_motion_dataset(
    capture: &Capture,
    o: &ImportOptions,
    out: &Path,
) -> Result<Imported, ImportError> {
    let path = capture.source.clone();
    let frames = capture.positions.len();
    let last = o.last_frame.unwrap_or(frames.saturating_sub(1));
    if o.rest_frame >= frames || o.release_frame >= last || last >= frames {
        return Err(ImportError::Frames {
            path,
            what: format!(
                "rest frame {}, release frame {}, last frame {last}: the capture has frames 0–{}",
                o.rest_frame,
                o.release_frame,
                frames.saturating_sub(1)
            ),
        });
    }
    let mut from = Vec::new();
    let mut to = Vec::new();
    let mut labels = Vec::new();
    for (label, place) in &o.places {
        let k = capture.marker(label)?;
        let p = capture.positions[o.rest_frame][k].ok_or_else(|| ImportError::Frames {
            path: path.clone(),
            what: format!(
                "marker {label:?} is missing in the rest frame {}",
                o.rest_frame
            ),
        })?;
        from.push(p);
        to.push(*place);
        labels.push(label.clone());
    }
    let transform =
        absolute_orientation(&from, &to).map_err(|source| ImportError::Registration {
            path: path.clone(),
            source,
        })?;
    let write = |name: &str, text: &str| -> Result<PathBuf, ImportError> {
        let p = out.join(name);
        std::fs::write(&p, text).map_err(|source| ImportError::Write {
            path: p.clone(),
            source,
        })?;
        Ok(p)
    };
    std::fs::create_dir_all(out).map_err(|source| ImportError::Write {
        path: out.into(),
        source,
    })?;
    // Markers without a declared place: located where the registration puts them on the rest
    // frame, if they sit near the declared ones (a marker on the rig or the table is not a point
    // of the object).
    let (mut located, mut ignored) = (Vec::new(), Vec::new());
    let mut tracked: Vec<(String, [f64; 3])> =
        labels.iter().cloned().zip(from.iter().copied()).collect();
    if o.locate_undeclared {
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for q in &to {
            for d in 0..3 {
                lo[d] = lo[d].min(q[d]);
                hi[d] = hi[d].max(q[d]);
            }
        }
        let reach = 0.5 * (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
        for (k, label) in capture.labels.iter().enumerate() {
            if labels.contains(label) {
                continue;
            }
            let Some(p) = capture.positions[o.rest_frame][k] else {
                ignored.push(label.clone());
                continue;
            };
            let q = transform.apply(p);
            let outside = (0..3)
                .map(|d| (lo[d] - q[d]).max(q[d] - hi[d]).max(0.0).powi(2))
                .sum::<f64>()
                .sqrt();
            if outside <= reach {
                located.push(label.clone());
                tracked.push((label.clone(), p));
            } else {
                ignored.push(label.clone());
            }
        }
    }
    // The markers' rest places: where the registration puts them on the rest frame (the declared
    // places themselves may be rounded; the registered capture is what the trajectories share).
    let mut markers = String::from("marker,x,y,z\n");
    for (label, p) in tracked.iter().map(|(l, p)| (l, p)) {
        let q = transform.apply(*p);
        let _ = writeln!(markers, "{label},{:.7},{:.7},{:.7}", q[0], q[1], q[2]);
    }
    let dt = 1.0 / capture.rate_hz;
    let mut traj = String::from("t,marker,x,y,z\n");
    let mut steps = 0;
    for f in o.release_frame + 1..=last {
        let n = f - o.release_frame;
        steps = n;
        for (label, _) in &tracked {
            let k = capture.marker(label)?;
            if let Some(p) = capture.positions[f][k] {
                let q = transform.apply(p);
                let _ = writeln!(
                    traj,
                    "{:.6},{label},{:.7},{:.7},{:.7}",
                    n as f64 * dt,
                    q[0],
                    q[1],
                    q[2]
                );
            }
        }
    }
    let toml = format!(
        "# Imported from {} (frames {}–{last} at {} Hz; registered on frame {}: RMS {:.3} mm).\n\
         dt = {dt}\nstatic_start = false\n{}\n",
        path.display(),
        o.release_frame,
        capture.rate_hz,
        o.rest_frame,
        1e3 * transform.rms(),
        o.toml.trim()
    );
    let files = vec![
        write("markers.csv", &markers)?,
        write("trajectories.csv", &traj)?,
        write("dataset.toml", &toml)?,
    ];
    Ok(Imported {
        transform,
        labels,
        steps,
        files,
        located,
        ignored,
    })
}
