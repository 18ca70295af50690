//! The pinhole camera of a depth sensor: intrinsics (focal lengths and principal point in
//! pixels) and the pose that carries camera coordinates into the mesh's frame. Camera axes are
//! the usual ones of depth sensors (OpenCV, RealSense, Azure Kinect): x right, y down, z along the
//! optical axis; a depth value is the z coordinate of the point, not its distance to the centre.

use nalgebra::{Matrix3, Vector3};

use crate::depth::DepthImage;
use crate::ScanError;

/// Intrinsics of a pinhole camera without distortion (a depth sensor's images are usually
/// delivered undistorted).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    /// Focal length along x, in pixels.
    pub fx: f64,
    /// Focal length along y, in pixels.
    pub fy: f64,
    /// Principal point x, in pixels (the centre of pixel (0, 0) is at 0).
    pub cx: f64,
    /// Principal point y, in pixels.
    pub cy: f64,
}

/// A rigid motion from camera coordinates into the mesh's frame: p_mesh = R p_cam + t.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Rotation R (orthonormal, det +1).
    pub rotation: Matrix3<f64>,
    /// Translation t (m): the camera centre in the mesh's frame.
    pub translation: Vector3<f64>,
}

impl Pose {
    /// The camera at the origin looking along +z.
    pub fn identity() -> Self {
        Self {
            rotation: Matrix3::identity(),
            translation: Vector3::zeros(),
        }
    }

    /// A camera at `eye` looking at `target`, with image "up" (−y of the camera) as close to `up`
    /// as the view direction allows.
    pub fn looking_at(eye: Vector3<f64>, target: Vector3<f64>, up: Vector3<f64>) -> Self {
        let z = (target - eye).normalize();
        let x = z.cross(&up).normalize();
        let y = z.cross(&x);
        Self {
            rotation: Matrix3::from_columns(&[x, y, z]),
            translation: eye,
        }
    }

    /// A point in camera coordinates carried into the mesh's frame.
    pub fn to_mesh(&self, p: Vector3<f64>) -> Vector3<f64> {
        self.rotation * p + self.translation
    }

    /// A point in the mesh's frame carried into camera coordinates.
    pub fn to_camera(&self, p: Vector3<f64>) -> Vector3<f64> {
        self.rotation.transpose() * (p - self.translation)
    }
}

/// A calibrated depth camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Its intrinsics.
    pub intrinsics: Intrinsics,
    /// Its pose in the mesh's frame.
    pub pose: Pose,
}

impl Camera {
    /// Checks that the intrinsics describe a camera (positive, finite focal lengths, a finite
    /// principal point) and that the rotation is one (orthonormal to 1e-6, det +1).
    pub fn validate(&self) -> Result<(), ScanError> {
        let k = &self.intrinsics;
        if !(k.fx.is_finite() && k.fx > 0.0 && k.fy.is_finite() && k.fy > 0.0) {
            return Err(ScanError::Invalid(format!(
                "camera focal lengths must be positive pixels, found fx = {}, fy = {}",
                k.fx, k.fy
            )));
        }
        if !(k.cx.is_finite() && k.cy.is_finite()) {
            return Err(ScanError::Invalid(format!(
                "camera principal point must be finite, found ({}, {})",
                k.cx, k.cy
            )));
        }
        let r = &self.pose.rotation;
        let off = (r.transpose() * r - Matrix3::identity()).abs().max();
        let rotation = off < 1e-6 && (r.determinant() - 1.0).abs() < 1e-6;
        if !rotation || !self.pose.translation.iter().all(|v| v.is_finite()) {
            return Err(ScanError::Invalid(format!(
                "camera pose: the rotation must be orthonormal with det +1 (|RᵀR − I| = {off:.1e}, det = {:.6}) and the translation finite",
                r.determinant()
            )));
        }
        Ok(())
    }

    /// The point seen at pixel (u, v) with depth z (m), in the mesh's frame.
    pub fn back_project(&self, u: f64, v: f64, z: f64) -> Vector3<f64> {
        let k = &self.intrinsics;
        let p = Vector3::new((u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z);
        self.pose.to_mesh(p)
    }

    /// Where a point of the mesh's frame falls in the image: (u, v, depth), or `None` behind the
    /// camera.
    pub fn project(&self, p: Vector3<f64>) -> Option<(f64, f64, f64)> {
        let c = self.pose.to_camera(p);
        if c.z <= 0.0 {
            return None;
        }
        let k = &self.intrinsics;
        Some((k.fx * c.x / c.z + k.cx, k.fy * c.y / c.z + k.cy, c.z))
    }

    /// The standard deviation, along a surface's unit `normal`, of the point seen at `p` when
    /// its depth has standard deviation `sigma_depth`: depth noise moves the point along its
    /// ray, by d = (p − c)/z per unit of depth (c the camera centre, z the point's depth), so
    /// its distance to the surface moves by |n·d| per unit — less than the depth noise where
    /// the surface is seen obliquely.
    pub fn noise_along(&self, p: Vector3<f64>, normal: Vector3<f64>, sigma_depth: f64) -> f64 {
        let z = self.pose.to_camera(p).z;
        sigma_depth * (normal.dot(&(p - self.pose.translation)) / z).abs()
    }

    /// Every valid pixel of `image` (depth > 0 and finite) back-projected into the mesh's frame.
    pub fn points(&self, image: &DepthImage) -> Vec<Vector3<f64>> {
        let mut out = Vec::new();
        for v in 0..image.height {
            for u in 0..image.width {
                let z = image.depth[v * image.width + u];
                if z.is_finite() && z > 0.0 {
                    out.push(self.back_project(u as f64, v as f64, z));
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Back-projection inverts projection, for a camera that is neither at the origin nor
    /// aligned with the axes.
    #[test]
    fn back_projection_inverts_projection() {
        let cam = Camera {
            intrinsics: Intrinsics {
                fx: 600.0,
                fy: 610.0,
                cx: 319.5,
                cy: 241.0,
            },
            pose: Pose::looking_at(
                Vector3::new(0.3, -0.2, 0.5),
                Vector3::new(0.0, 0.01, 0.02),
                Vector3::new(0.0, 0.0, 1.0),
            ),
        };
        cam.validate().unwrap();
        let p = Vector3::new(0.02, -0.01, 0.03);
        let (u, v, z) = cam.project(p).unwrap();
        assert!((cam.back_project(u, v, z) - p).norm() < 1e-12);
        // The target is on the optical axis: it projects onto the principal point.
        let (u, v, _) = cam.project(Vector3::new(0.0, 0.01, 0.02)).unwrap();
        assert!(
            (u - 319.5).abs() < 1e-9 && (v - 241.0).abs() < 1e-9,
            "{u} {v}"
        );
    }

    /// A surface facing the camera square on sees the whole depth noise along its normal at the
    /// principal point; a pixel off axis sees its ray's tilt; a surface seen edge-on sees none.
    #[test]
    fn depth_noise_along_a_normal() {
        let cam = Camera {
            intrinsics: Intrinsics {
                fx: 500.0,
                fy: 500.0,
                cx: 10.0,
                cy: 10.0,
            },
            pose: Pose::identity(),
        };
        let n = Vector3::new(0.0, 0.0, -1.0);
        assert!((cam.noise_along(Vector3::new(0.0, 0.0, 0.5), n, 1e-3) - 1e-3).abs() < 1e-15);
        // Off axis the ray is longer than its depth, but its normal component is still 1 per
        // unit of depth for a plane facing the camera: the plane z = 0.5 moves by δz.
        assert!((cam.noise_along(Vector3::new(0.2, 0.1, 0.5), n, 1e-3) - 1e-3).abs() < 1e-15);
        let side = Vector3::new(1.0, 0.0, 0.0);
        assert!(
            cam.noise_along(Vector3::new(0.0, 0.0, 0.5), side, 1e-3)
                .abs()
                < 1e-15
        );
        assert!((cam.noise_along(Vector3::new(0.25, 0.0, 0.5), side, 1e-3) - 0.5e-3).abs() < 1e-15);
    }

    #[test]
    fn a_camera_that_is_not_one_is_refused_by_name() {
        let mut cam = Camera {
            intrinsics: Intrinsics {
                fx: 0.0,
                fy: 600.0,
                cx: 0.0,
                cy: 0.0,
            },
            pose: Pose::identity(),
        };
        let e = cam.validate().unwrap_err().to_string();
        assert!(e.contains("fx = 0"), "{e}");
        cam.intrinsics.fx = 600.0;
        cam.pose.rotation[(0, 0)] = 2.0;
        let e = cam.validate().unwrap_err().to_string();
        assert!(e.contains("orthonormal"), "{e}");
    }
}
