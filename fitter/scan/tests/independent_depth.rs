//! A depth image palpate did not make: `tests/generators/render_depth.py` casts rays from a
//! pinhole camera at a box on a post analytically, adds depth-dependent noise, drops grazing
//! pixels and mixes depths at edges, and writes the 16-bit PNG by hand. Read back through
//! palpate's PNG reader and camera, the box's pixels must lie on palpate's box mesh within the
//! generator's noise: a wrong axis convention, pixel centre, unit or pose shows as a bias or a
//! scatter far above it.

use std::path::PathBuf;

use nalgebra::{Matrix3, Vector3};
use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_scan::camera::{Camera, Intrinsics, Pose};
use palpate_scan::depth::DepthImage;
use palpate_scan::surface::{correspond, RobustLoss};

fn fixture() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/depth-box")
}

#[test]
fn an_independent_depth_image_lies_on_the_box_within_its_noise() {
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixture().join("camera.json")).unwrap())
            .unwrap();
    let num = |k: &str| {
        meta[k]
            .as_f64()
            .unwrap_or_else(|| panic!("camera.json: {k}"))
    };
    let vec3 = |v: &serde_json::Value| {
        Vector3::from_iterator((0..3).map(|i| v[i].as_f64().expect("a number")))
    };
    let cols = &meta["rotation_columns"];
    let camera = Camera {
        intrinsics: Intrinsics {
            fx: num("fx"),
            fy: num("fy"),
            cx: num("cx"),
            cy: num("cy"),
        },
        pose: Pose {
            rotation: Matrix3::from_columns(&[vec3(&cols[0]), vec3(&cols[1]), vec3(&cols[2])]),
            translation: vec3(&meta["camera_centre"]),
        },
    };
    camera.validate().unwrap();
    let image = DepthImage::read_png(&fixture().join("depth.png"), num("unit_m")).unwrap();
    assert_eq!((image.width, image.height), (160, 120));
    let points = camera.points(&image);

    let (lo, hi) = (vec3(&meta["box_lo"]), vec3(&meta["box_hi"]));
    let mesh = box_mesh((hi - lo).into(), [10, 4, 2]);
    let tris = mesh.boundary_triangles();
    let (found, unmatched) = correspond(&mesh.nodes, &tris, &points, 5e-3);
    let box_pixels = meta["box_pixels"].as_u64().unwrap() as usize;
    // The box's own pixels, and some of the mixed ones at its edges, are found; the post's
    // table, a centimetre below, is not.
    assert!(
        found.len() >= box_pixels * 95 / 100 && found.len() <= box_pixels * 115 / 100,
        "{} matched of {box_pixels} box pixels ({unmatched} unmatched)",
        found.len()
    );

    // Each residual over the generator's declared depth noise at its depth, carried along the
    // face's normal; Tukey's biweight (c = 4) sets the mixed pixels aside.
    let (a, b) = (num("sigma_a_m"), num("sigma_b_per_m"));
    let mut scaled = Vec::new();
    let (mut sw, mut swr2) = (0.0, 0.0);
    for c in &found {
        let z = camera.pose.to_camera(points[c.point]).z;
        let r = c.distance / camera.noise_along(points[c.point], c.normal, a + b * z * z);
        let w = RobustLoss::Tukey(4.0).weight(r);
        sw += w;
        swr2 += w * r * r;
        scaled.push(r);
    }
    scaled.sort_by(f64::total_cmp);
    let median = scaled[scaled.len() / 2];
    let rms = (swr2 / sw).sqrt();
    eprintln!(
        "{} points, {} matched, median residual {median:.3} σ, weighted RMS {rms:.3} σ",
        points.len(),
        found.len()
    );
    // The 0.1 mm rounding adds (0.1/√12)² to σ² ≈ (0.3 mm)²: 1 % of the RMS. Tukey's weights
    // shrink a Gaussian's weighted RMS to about 0.8 σ.
    assert!(
        median.abs() < 0.15,
        "median residual {median} σ: the image is biased"
    );
    assert!((0.65..1.0).contains(&rms), "weighted RMS {rms} σ");
}
