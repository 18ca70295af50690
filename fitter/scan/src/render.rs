//! Depth images of a mesh's surface from a virtual camera: what a depth sensor would see of a
//! simulated object, to make scans whose truth is known. A z-buffer: each triangle in front of
//! the camera is rasterised at the pixel centres it covers, its depth interpolated in 1/z
//! (perspective-correct, so a back-projected pixel lies on its triangle's plane), the nearest
//! kept. A sensor's faults — depth noise growing with depth and pixels dropped at random —
//! are added by [`add_depth_noise`]; a background is the caller's to put in the scene.

use nalgebra::Vector3;
use palpate_fem::rng::SplitMix64;

use crate::camera::Camera;
use crate::depth::DepthImage;
use crate::fit::ScanPoints;

/// Depths nearer than this (m) are clipped: a triangle reaching behind it is skipped whole.
const NEAR: f64 = 1e-3;

/// The depth image of `triangles` (node indices into `nodes`) seen by `camera` at
/// `width` × `height` pixels; 0 where no triangle is seen.
pub fn render_depth(
    camera: &Camera,
    width: usize,
    height: usize,
    nodes: &[[f64; 3]],
    triangles: &[[usize; 3]],
) -> DepthImage {
    let mut image = DepthImage::empty(width, height);
    for t in triangles {
        let cam = t.map(|n| camera.pose.to_camera(Vector3::from(nodes[n])));
        if cam.iter().any(|c| c.z < NEAR) {
            continue;
        }
        let k = &camera.intrinsics;
        let uv = cam.map(|c| (k.fx * c.x / c.z + k.cx, k.fy * c.y / c.z + k.cy));
        // Twice the signed area in pixels; a triangle seen edge-on covers no pixel centre.
        let area =
            (uv[1].0 - uv[0].0) * (uv[2].1 - uv[0].1) - (uv[2].0 - uv[0].0) * (uv[1].1 - uv[0].1);
        if area.abs() < 1e-12 {
            continue;
        }
        let (u0, u1) = span(uv.map(|p| p.0), width);
        let (v0, v1) = span(uv.map(|p| p.1), height);
        for v in v0..v1 {
            for u in u0..u1 {
                let (x, y) = (u as f64, v as f64);
                // Screen-space barycentric coordinates of the pixel centre.
                let edge = |a: (f64, f64), b: (f64, f64)| {
                    (b.0 - a.0) * (y - a.1) - (x - a.0) * (b.1 - a.1)
                };
                let l = [
                    edge(uv[1], uv[2]) / area,
                    edge(uv[2], uv[0]) / area,
                    edge(uv[0], uv[1]) / area,
                ];
                if l.iter().any(|w| *w < 0.0) {
                    continue;
                }
                let z = 1.0 / (l[0] / cam[0].z + l[1] / cam[1].z + l[2] / cam[2].z);
                let d = &mut image.depth[v * width + u];
                if *d == 0.0 || z < *d {
                    *d = z;
                }
            }
        }
    }
    image
}

/// A depth sensor's faults: depth noise σ(z) = `sigma_m` + `sigma_per_m`·z² (a structured-light
/// or stereo camera's noise grows with the square of the depth) and a share of the pixels
/// returning nothing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthNoise {
    /// σ at zero depth (m).
    pub sigma_m: f64,
    /// Growth of σ with the squared depth (m⁻¹).
    pub sigma_per_m: f64,
    /// The share of valid pixels dropped (0–1).
    pub dropped: f64,
}

impl DepthNoise {
    /// σ at depth `z` (m).
    pub fn sigma(&self, z: f64) -> f64 {
        self.sigma_m + self.sigma_per_m * z * z
    }
}

/// Adds `noise` to every valid pixel of `image`: each dropped with probability
/// [`DepthNoise::dropped`], else its depth moved by a normal draw of σ(z).
pub fn add_depth_noise(image: &mut DepthImage, noise: &DepthNoise, rng: &mut SplitMix64) {
    for z in image.depth.iter_mut().filter(|z| **z > 0.0) {
        *z = if rng.uniform() < noise.dropped {
            0.0
        } else {
            *z + noise.sigma(*z) * rng.normal()
        };
    }
}

/// The scan `camera` makes of `image`: its valid pixels back-projected, each with the depth σ
/// of `noise` at its depth, the camera kept for the noise's direction.
pub fn scan_points(camera: &Camera, image: &DepthImage, noise: &DepthNoise) -> ScanPoints {
    let points = camera.points(image);
    let sigma = points
        .iter()
        .map(|p| noise.sigma(camera.pose.to_camera(*p).z))
        .collect();
    ScanPoints {
        points,
        sigma,
        camera: Some(*camera),
    }
}

/// A noisy scan of `triangles` over `nodes` seen by `camera` at `width` × `height` pixels:
/// [`render_depth`], [`add_depth_noise`] drawn from `rng`, then [`scan_points`].
pub fn noisy_scan(
    camera: &Camera,
    (width, height): (usize, usize),
    nodes: &[[f64; 3]],
    triangles: &[[usize; 3]],
    noise: &DepthNoise,
    rng: &mut SplitMix64,
) -> ScanPoints {
    let mut image = render_depth(camera, width, height, nodes, triangles);
    add_depth_noise(&mut image, noise, rng);
    scan_points(camera, &image, noise)
}

/// The pixel centres (a half-open index range, clamped to the image) between the smallest and
/// largest of three coordinates.
fn span(c: [f64; 3], size: usize) -> (usize, usize) {
    let lo = c
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min)
        .ceil()
        .max(0.0);
    let hi = c.iter().copied().fold(f64::NEG_INFINITY, f64::max).floor() + 1.0;
    let hi = hi.clamp(0.0, size as f64);
    ((lo as usize).min(size), hi as usize)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Intrinsics, Pose};
    use crate::surface::correspond;
    use palpate_fem::mesh::boxmesh::box_mesh;

    /// A box seen obliquely: every back-projected pixel lies on the box's surface (to 1e-9 m:
    /// the depth is exact, not sampled), it sees three faces, and the nearest depth is that of
    /// the box's nearest corner or farther.
    #[test]
    fn a_rendered_box_back_projects_onto_its_surface() {
        let mesh = box_mesh([0.10, 0.04, 0.02], [10, 4, 2]);
        let tris = mesh.boundary_triangles();
        let camera = Camera {
            intrinsics: Intrinsics {
                fx: 300.0,
                fy: 300.0,
                cx: 79.5,
                cy: 59.5,
            },
            pose: Pose::looking_at(
                Vector3::new(0.25, 0.2, 0.3),
                Vector3::new(0.05, 0.02, 0.01),
                Vector3::new(0.0, 0.0, 1.0),
            ),
        };
        let image = render_depth(&camera, 160, 120, &mesh.nodes, &tris);
        let points = camera.points(&image);
        assert!(points.len() > 500, "{} pixels", points.len());
        let (found, unmatched) = correspond(&mesh.nodes, &tris, &points, 1e-3);
        assert_eq!(unmatched, 0);
        let worst = found.iter().map(|c| c.distance.abs()).fold(0.0, f64::max);
        assert!(worst < 1e-9, "worst distance {worst}");
        let mut faces: Vec<[i64; 3]> = found
            .iter()
            .map(|c| c.normal.map(|v| v.round() as i64).into())
            .collect();
        faces.sort_unstable();
        faces.dedup();
        assert_eq!(
            faces,
            vec![[0, 0, 1], [0, 1, 0], [1, 0, 0]],
            "the faces facing the camera"
        );
        let nearest = mesh
            .nodes
            .iter()
            .map(|p| camera.pose.to_camera(Vector3::from(*p)).z)
            .fold(f64::INFINITY, f64::min);
        let seen = image
            .depth
            .iter()
            .copied()
            .filter(|z| *z > 0.0)
            .fold(f64::INFINITY, f64::min);
        assert!(seen >= nearest - 1e-12, "{seen} < {nearest}");
    }
}
