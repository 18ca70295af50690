//! A scan on disk, as `palpate import depth|cloud` writes it and the fits read it: a folder with
//!
//! - `points.ply`: ASCII PLY, one `vertex` per point with `double` properties `x`, `y`, `z`
//!   (metres, in the mesh's frame) and `sigma` (the point's noise σ in metres: along its camera
//!   ray when `scan.toml` names a camera, in every direction otherwise);
//! - `scan.toml`: where the points came from — [`ScanRecord`]: the source file and its kind, the
//!   source's unit, the camera (intrinsics and pose) for a depth image, and the noise model,
//!   declared or estimated from the points' local scatter ([`crate::noise`]).
//!
//! A camera is described by a TOML file ([`CameraToml`]):
//!
//! ```toml
//! fx = 420.0            # focal lengths and principal point, pixels
//! fy = 420.0
//! cx = 159.5
//! cy = 119.5
//! depth_unit_m = 0.001  # metres per integer unit of the 16-bit PNG or PGM
//! sigma_m = 0.0002      # optional depth noise σ = sigma_m + sigma_per_m · z² (m);
//! sigma_per_m = 0.001   # without them σ is estimated from the points' local scatter
//! [pose]                # camera → mesh frame; either eye, target and up (m) …
//! eye = [0.05, -0.16, 0.08]
//! target = [0.04, 0.01, -0.01]
//! up = [0.0, 0.0, 1.0]
//! # … or rotation = [[r00, r01, r02], [r10, …], […]] (rows) and translation = [tx, ty, tz];
//! # no [pose]: the camera's frame is the mesh's.
//! ```

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use crate::camera::{Camera, Intrinsics, Pose};
use crate::depth::DepthImage;
use crate::fit::ScanPoints;
use crate::ScanError;

/// The `schema_version` of `scan.toml`.
pub const SCHEMA_VERSION: u32 = 1;
/// The points' file in a scan folder.
pub const POINTS_FILE: &str = "points.ply";
/// The provenance file in a scan folder.
pub const RECORD_FILE: &str = "scan.toml";

/// A camera's pose in TOML: eye/target/up or rotation rows and translation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseToml {
    /// The camera centre (m), with `target` and `up`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub eye: Option<[f64; 3]>,
    /// The point looked at (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target: Option<[f64; 3]>,
    /// The image's up direction.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub up: Option<[f64; 3]>,
    /// Rotation camera → mesh, by rows.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotation: Option<[[f64; 3]; 3]>,
    /// The camera centre in the mesh's frame (m), with `rotation`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub translation: Option<[f64; 3]>,
}

impl PoseToml {
    /// The pose it describes, or what is missing.
    pub fn pose(&self) -> Result<Pose, String> {
        match (
            self.eye,
            self.target,
            self.up,
            self.rotation,
            self.translation,
        ) {
            (Some(e), Some(t), Some(u), None, None) => Ok(Pose::looking_at(
                Vector3::from(e),
                Vector3::from(t),
                Vector3::from(u),
            )),
            (None, None, None, Some(r), Some(t)) => Ok(Pose {
                rotation: Matrix3::from_fn(|i, j| r[i][j]),
                translation: Vector3::from(t),
            }),
            _ => Err(
                "[pose]: expected either eye, target and up, or rotation and translation".into(),
            ),
        }
    }

    /// The rotation-and-translation form of `pose`.
    pub fn of(pose: &Pose) -> Self {
        let r = pose.rotation;
        Self {
            eye: None,
            target: None,
            up: None,
            rotation: Some([0, 1, 2].map(|i| [0, 1, 2].map(|j| r[(i, j)]))),
            translation: Some(pose.translation.into()),
        }
    }
}

/// A depth camera as a TOML file describes it (module doc).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraToml {
    /// Focal length x (px).
    pub fx: f64,
    /// Focal length y (px).
    pub fy: f64,
    /// Principal point x (px).
    pub cx: f64,
    /// Principal point y (px).
    pub cy: f64,
    /// Metres per integer unit of a depth image.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_unit_m: Option<f64>,
    /// Depth noise at zero depth (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma_m: Option<f64>,
    /// Depth noise's growth with depth squared (1/m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma_per_m: Option<f64>,
    /// Camera → mesh frame; none: the identity.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose: Option<PoseToml>,
}

impl CameraToml {
    /// Reads and checks a camera file; errors name the file, and the line and field.
    pub fn read(path: &Path) -> Result<Self, ScanError> {
        let text = std::fs::read_to_string(path).map_err(|e| ScanError::io(path, e))?;
        let c: Self = toml::from_str(&text)
            .map_err(|e| ScanError::format(path, format!("camera TOML: {e}")))?;
        c.camera().map_err(|e| ScanError::format(path, e))?;
        for (name, v) in [("sigma_m", c.sigma_m), ("sigma_per_m", c.sigma_per_m)] {
            if v.is_some_and(|v| !(v.is_finite() && v >= 0.0)) {
                return Err(ScanError::format(
                    path,
                    format!("field {name}: expected a finite number ≥ 0, found {v:?}"),
                ));
            }
        }
        Ok(c)
    }

    /// The camera, checked ([`Camera::validate`]).
    pub fn camera(&self) -> Result<Camera, String> {
        let pose = match &self.pose {
            Some(p) => p.pose()?,
            None => Pose::identity(),
        };
        let c = Camera {
            intrinsics: Intrinsics {
                fx: self.fx,
                fy: self.fy,
                cx: self.cx,
                cy: self.cy,
            },
            pose,
        };
        c.validate().map_err(|e| e.to_string())?;
        Ok(c)
    }
}

/// The noise model of a scan's points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoiseToml {
    /// σ = sigma_m + sigma_per_m · z² (m), z the depth (0 for a cloud).
    pub sigma_m: f64,
    /// Growth with depth squared (1/m).
    pub sigma_per_m: f64,
    /// "camera ray" or "any direction".
    pub along: String,
    /// "declared" or "estimated from local scatter".
    pub origin: String,
}

/// `scan.toml`: where a scan's points came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScanRecord {
    /// [`SCHEMA_VERSION`].
    pub schema_version: u32,
    /// "depth image" or "point cloud".
    pub kind: String,
    /// The imported file.
    pub source: String,
    /// Metres per unit of the source (a PNG's integer unit, a cloud's coordinate unit).
    pub source_unit_m: f64,
    /// Points in [`POINTS_FILE`].
    pub points: usize,
    /// The points' unit: always "m", in the mesh's frame.
    pub units: String,
    /// The points' noise.
    pub noise: NoiseToml,
    /// The depth camera, for a depth image.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraToml>,
}

/// A scan: its points and their provenance.
#[derive(Debug, Clone)]
pub struct Scan {
    /// Points, σ and camera, ready to fit.
    pub points: ScanPoints,
    /// Where they came from.
    pub record: ScanRecord,
}

/// The per-point σ of `points` under the noise model (depth along `camera`'s axis).
fn sigmas(points: &[Vector3<f64>], camera: Option<&Camera>, a: f64, b: f64) -> Vec<f64> {
    points
        .iter()
        .map(|p| {
            let z = camera.map_or(0.0, |c| c.pose.to_camera(*p).z);
            a + b * z * z
        })
        .collect()
}

/// The noise model from what was declared, or estimated from the points.
fn noise(
    points: &[Vector3<f64>],
    declared: Option<(f64, f64)>,
    along: &str,
) -> Result<NoiseToml, ScanError> {
    let (sigma_m, sigma_per_m, origin) = match declared {
        Some((a, b)) => (a, b, "declared"),
        None => {
            let s = crate::noise::local_scatter(points).ok_or_else(|| {
                ScanError::Invalid(format!(
                    "the noise cannot be estimated from {} points (too few with neighbours); declare it",
                    points.len()
                ))
            })?;
            (s, 0.0, "estimated from local scatter")
        }
    };
    Ok(NoiseToml {
        sigma_m,
        sigma_per_m,
        along: along.into(),
        origin: origin.into(),
    })
}

/// A depth image (16-bit PNG or binary PGM, [`DepthImage::read`]) seen by the camera of
/// `camera_file`, back-projected into the mesh's frame. The image's unit comes from the camera
/// file's `depth_unit_m`.
pub fn import_depth(png: &Path, camera_file: &Path) -> Result<Scan, ScanError> {
    let toml = CameraToml::read(camera_file)?;
    let unit = toml.depth_unit_m.ok_or_else(|| {
        ScanError::format(
            camera_file,
            "field depth_unit_m is missing (metres per integer unit of the depth image, 0.001 for millimetres)",
        )
    })?;
    let camera = toml
        .camera()
        .map_err(|e| ScanError::format(camera_file, e))?;
    let image = DepthImage::read(png, unit)?;
    let points = camera.points(&image);
    if points.is_empty() {
        return Err(ScanError::format(png, "no pixel has a depth (all 0)"));
    }
    let declared = match (toml.sigma_m, toml.sigma_per_m) {
        (None, None) => None,
        (a, b) => Some((a.unwrap_or(0.0), b.unwrap_or(0.0))),
    };
    let noise = noise(&points, declared, "camera ray")?;
    let sigma = sigmas(&points, Some(&camera), noise.sigma_m, noise.sigma_per_m);
    let record = ScanRecord {
        schema_version: SCHEMA_VERSION,
        kind: "depth image".into(),
        source: png.display().to_string(),
        source_unit_m: unit,
        points: points.len(),
        units: "m".into(),
        noise,
        camera: Some(CameraToml {
            pose: Some(PoseToml::of(&camera.pose)),
            ..toml
        }),
    };
    Ok(Scan {
        points: ScanPoints {
            points,
            sigma,
            camera: Some(camera),
        },
        record,
    })
}

/// A point cloud (PLY, XYZ, CSV) in the mesh's frame, its coordinates in units of `unit_m`
/// metres, with noise σ (m) declared or, if `None`, estimated from the local scatter.
pub fn import_cloud(path: &Path, unit_m: f64, sigma: Option<f64>) -> Result<Scan, ScanError> {
    if !(unit_m.is_finite() && unit_m > 0.0) {
        return Err(ScanError::Invalid(format!(
            "{}: the unit must be a positive number of metres, found {unit_m}",
            path.display()
        )));
    }
    if let Some(s) = sigma.filter(|s| !(s.is_finite() && *s > 0.0)) {
        return Err(ScanError::Invalid(format!(
            "{}: the noise σ must be a positive number of metres, found {s}",
            path.display()
        )));
    }
    let points: Vec<Vector3<f64>> = crate::cloud::read_points(path)?
        .into_iter()
        .map(|p| p * unit_m)
        .collect();
    if points.is_empty() {
        return Err(ScanError::format(path, "no point"));
    }
    let noise = noise(&points, sigma.map(|s| (s, 0.0)), "any direction")?;
    let record = ScanRecord {
        schema_version: SCHEMA_VERSION,
        kind: "point cloud".into(),
        source: path.display().to_string(),
        source_unit_m: unit_m,
        points: points.len(),
        units: "m".into(),
        noise,
        camera: None,
    };
    Ok(Scan {
        points: ScanPoints {
            sigma: vec![record.noise.sigma_m; points.len()],
            points,
            camera: None,
        },
        record,
    })
}

/// Writes `scan` into the folder `dir` (made if missing): [`POINTS_FILE`] and [`RECORD_FILE`].
/// Returns the files written.
pub fn write_scan(dir: &Path, scan: &Scan) -> Result<Vec<PathBuf>, ScanError> {
    std::fs::create_dir_all(dir).map_err(|e| ScanError::io(dir, e))?;
    let ply = dir.join(POINTS_FILE);
    crate::cloud::write_ply(&ply, &scan.points.points, &scan.points.sigma)?;
    let record = dir.join(RECORD_FILE);
    let text = toml::to_string(&scan.record)
        .map_err(|e| ScanError::Invalid(format!("{}: {e}", record.display())))?;
    let text = format!(
        "# A scan imported by palpate: {POINTS_FILE} holds the points (x, y, z in metres in the \
         mesh's frame, sigma their noise σ in metres).\n{text}"
    );
    palpate_fem::io::atomic::write_atomic(&record, text.as_bytes())
        .map_err(|e| ScanError::Invalid(format!("{}: {e}", record.display())))?;
    Ok(vec![ply, record])
}

/// Reads a scan folder (or its `scan.toml`) written by [`write_scan`]; the point count must be
/// the record's.
pub fn read_scan(path: &Path) -> Result<Scan, ScanError> {
    let dir = if path.is_dir() {
        path
    } else {
        path.parent().unwrap_or(Path::new("."))
    };
    let record_path = dir.join(RECORD_FILE);
    let text = std::fs::read_to_string(&record_path).map_err(|e| ScanError::io(&record_path, e))?;
    let record: ScanRecord =
        toml::from_str(&text).map_err(|e| ScanError::format(&record_path, e.to_string()))?;
    if record.schema_version != SCHEMA_VERSION {
        return Err(ScanError::format(
            &record_path,
            format!(
                "schema_version: expected {SCHEMA_VERSION}, found {}",
                record.schema_version
            ),
        ));
    }
    let camera = record
        .camera
        .as_ref()
        .map(|c| c.camera().map_err(|e| ScanError::format(&record_path, e)))
        .transpose()?;
    let ply = dir.join(POINTS_FILE);
    let (points, sigma) = crate::cloud::read_ply_with(&ply, "sigma")?;
    if points.len() != record.points {
        return Err(ScanError::format(
            &ply,
            format!(
                "{} points, but {} says {}",
                points.len(),
                RECORD_FILE,
                record.points
            ),
        ));
    }
    if let Some(i) = sigma.iter().position(|s| !(s.is_finite() && *s > 0.0)) {
        return Err(ScanError::format(
            &ply,
            format!("vertex {i}: sigma must be > 0 m, found {}", sigma[i]),
        ));
    }
    Ok(Scan {
        points: ScanPoints {
            points,
            sigma,
            camera,
        },
        record,
    })
}

impl Scan {
    /// The points' bounding box (m): lowest and highest corner.
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in &self.points.points {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        (lo, hi)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera file without fy: the error names the file and the field.
    #[test]
    fn a_camera_without_an_intrinsic_is_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("camera.toml");
        std::fs::write(
            &f,
            "fx = 400.0\ncx = 10.0\ncy = 10.0\ndepth_unit_m = 0.001\n",
        )
        .unwrap();
        let e = CameraToml::read(&f).unwrap_err().to_string();
        assert!(e.contains("camera.toml") && e.contains("fy"), "{e}");
    }
}
