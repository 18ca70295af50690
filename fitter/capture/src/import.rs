//! A capture as the data of a palpate motion dataset (`docs/motion-dataset.md`): the markers
//! registered from the capture frame to the mesh frame on a frame at rest, their trajectories
//! from the release on. The import returns them as plain data ([`Imported`]); the motion
//! dataset's one writer (`palpate_motion::dataset::write_dataset`, called by `palpate import
//! c3d`) writes them, so this crate needs nothing of the fitters.

use std::path::PathBuf;

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
}

/// What the import made: the markers and their trajectories in the mesh frame, on the capture's
/// step grid from the release on, and the registration that put them there.
#[derive(Debug, Clone)]
pub struct Imported {
    /// Capture frame → mesh frame.
    pub transform: RigidTransform,
    /// Labels in the order of `transform.residuals`.
    pub labels: Vec<String>,
    /// The capture period (s): the dataset's `dt`.
    pub dt: f64,
    /// Capture intervals from the release to the last frame imported.
    pub steps: usize,
    /// Where the data come from, in one line: the file, the frames, the rate, the registration.
    pub source_note: String,
    /// Every tracked marker's rest place in the mesh frame (m): where the registration puts it on
    /// the rest frame (the declared places themselves may be rounded; the registered capture is
    /// what the trajectories share).
    pub markers: Vec<(String, [f64; 3])>,
    /// Tracked positions in the mesh frame (m): (step after the release, marker, position), a
    /// step's markers in the order of `markers`; a marker missing from a frame has no row.
    pub trajectories: Vec<(usize, String, [f64; 3])>,
    /// Markers without a declared place, located from the rest frame.
    pub located: Vec<String>,
    /// Markers without a declared place left out: missing in the rest frame, or farther from the
    /// declared markers than half their spread (on the rig, not on the object).
    pub ignored: Vec<String>,
}

/// Registers `capture` on `o.rest_frame` and returns its markers and trajectories in the mesh
/// frame, from the release on.
pub fn import_motion(capture: &Capture, o: &ImportOptions) -> Result<Imported, ImportError> {
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
    let markers = tracked
        .iter()
        .map(|(label, p)| (label.clone(), transform.apply(*p)))
        .collect();
    let dt = 1.0 / capture.rate_hz;
    let mut trajectories = Vec::new();
    for f in o.release_frame + 1..=last {
        let n = f - o.release_frame;
        for (label, _) in &tracked {
            let k = capture.marker(label)?;
            if let Some(p) = capture.positions[f][k] {
                trajectories.push((n, label.clone(), transform.apply(p)));
            }
        }
    }
    let source_note = format!(
        "Imported from {} (frames {}–{last} at {} Hz; registered on frame {}: RMS {:.3} mm).",
        path.display(),
        o.release_frame,
        capture.rate_hz,
        o.rest_frame,
        1e3 * transform.rms(),
    );
    Ok(Imported {
        transform,
        labels,
        dt,
        steps: last - o.release_frame,
        source_note,
        markers,
        trajectories,
        located,
        ignored,
    })
}
