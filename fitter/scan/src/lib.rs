//! Surface scans as observations of a deforming object: what a depth camera or a scanner records
//! of it, read and brought into the mesh's frame, and compared with the mesh's deformed surface.
//!
//! - [`camera`]: the pinhole camera (intrinsics and pose) that back-projects a depth image into
//!   points and projects points into pixels;
//! - [`depth`]: depth images, 16-bit PNG in and out;
//! - [`cloud`]: point clouds, PLY (ASCII and binary), PCL's PCD (`pcd`) and XYZ/CSV text;
//! - [`surface`]: the scan residual — each point's signed distance to the deformed surface along
//!   the normal at its closest point, with its Jacobian in the node positions, a robust weight
//!   for background and flying pixels and a weight that keeps a dense patch from drowning the
//!   rest;
//! - [`render`]: depth images of a mesh's surface from a virtual camera, to make test data;
//! - [`fit`]: a shear modulus (or two, one per part) fitted to scans of the object hanging under
//!   its weight, held or loaded, through the static solver on linear or quadratic tetrahedra with its analytic sensitivity;
//! - [`dataset`]: a scan dataset on disk — the rest mesh and the scans of the object in several
//!   states (clamped, a grip moved rigidly, dead loads), `scans.toml`;
//! - [`regions`]: a second material searched for, a split of the object into two parts;
//! - [`registration`]: a scan brought onto a surface by a rigid motion (robust point-to-plane
//!   ICP): onto the part of the object that does not move in its state, or the rest mesh;
//! - [`dataset_fit`]: a scan dataset fitted, with the second-material search, as JSON and Markdown;
//! - [`record`]: a scan on disk (points in metres in the mesh's frame with their noise, and
//!   where they came from), imported from a depth image and its camera or from a point cloud;
//! - [`noise`]: a scan's noise estimated from its points' local scatter;
//! - [`residual_vtu`]: a fit's residual on the points and on the deformed surface, for ParaView;
//! - [`synthetic`]: a strip's scan dataset written to disk with an effect it does not declare, to
//!   test the scan diagnosis;
//! - [`residual_map`]: a fit's residual on the deformed surface projected along its thinnest axis,
//!   per triangle in painter's order, for a figure.
//!
//! Units are metres throughout; a depth image's integer unit is declared by the caller.

pub mod camera;
pub mod cloud;
pub mod dataset;
pub mod dataset_fit;
pub mod depth;
pub mod fit;
pub mod noise;
mod pcd;
pub mod record;
pub mod regions;
pub mod registration;
pub mod render;
pub mod residual_map;
pub mod residual_vtu;
pub mod surface;
pub mod synthetic;

/// What goes wrong reading or using a scan. Every message names the file and where in it.
#[derive(Debug, thiserror::Error)]
pub enum ScanError {
    /// The file could not be opened or read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// The file's content is not what its format says.
    #[error("{path}: {what}")]
    Format {
        /// The file.
        path: String,
        /// What was expected and what was found, and where.
        what: String,
    },
    /// A value out of its range (a camera parameter, an image size).
    #[error("{0}")]
    Invalid(String),
    /// The static solver behind a fit failed.
    #[error("{what}: {source}")]
    Solve {
        /// Which solve.
        what: String,
        /// Why.
        source: palpate_motion::MotionError,
    },
}

impl ScanError {
    fn format(path: &std::path::Path, what: impl Into<String>) -> Self {
        Self::Format {
            path: path.display().to_string(),
            what: what.into(),
        }
    }

    fn io(path: &std::path::Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.display().to_string(),
            source,
        }
    }
}
