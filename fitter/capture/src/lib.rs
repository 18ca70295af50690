//! Motion-capture import: what a capture rig (Qualisys, Vicon, OptiTrack, Motion Analysis) writes,
//! read into marker trajectories palpate can fit, and registered to the mesh's frame.
//!
//! - [`c3d`]: C3D files (the standard capture format) through the `c3dio` crate, with the header
//!   checked against the file's size before anything is allocated, units from `POINT:UNITS`,
//!   missing samples (negative residual) as `None`, and errors that name the file and what is wrong;
//!   empty parameters (a zero dimension, as Vicon Nexus writes them), which `c3dio` refuses, are
//!   left out of the parameter section first (`c3d_parameters`).
//! - [`register`]: Horn's closed-form absolute orientation (quaternion method, Horn 1987), the rigid
//!   transform from the capture frame to the mesh frame from labelled markers (thesis §4.2), with
//!   the residual of every marker.
//! - [`Capture::release_frame`]: the last frame at rest before the object is released.
//!
//! What it must not depend on: the fitters, the diagnosis, the CLI.

pub mod c3d;
mod c3d_parameters;
pub mod import;
pub mod register;

pub use c3d::{read_c3d, Capture, CaptureError};
pub use register::{absolute_orientation, RegistrationError, RigidTransform};
