//! `palpate import depth|cloud` and `palpate info` on the scan folder: the points where the
//! pinhole model and the declared units put them (derived here by hand), the noise as declared,
//! and each format's bad input refused with the file and what was wrong named.

use std::path::Path;

use crate::common;

use common::{assert_succeeded, last_json, palpate, refused};
use palpate_scan::depth::DepthImage;

/// A 4 × 3 depth frame at 500 mm everywhere but pixel (0, 0), which saw nothing.
fn frame(path: &Path) {
    let mut image = DepthImage::empty(4, 3);
    image.depth.iter_mut().for_each(|z| *z = 0.5);
    image.depth[0] = 0.0;
    image.write_png(path, 1e-3).unwrap();
}

/// `palpate import depth FRAME --camera CAMERA -o OUT`, which must succeed.
fn import_depth(frame: &Path, camera: &Path, out: &Path) {
    let o = palpate()
        .args(["import", "depth"])
        .arg(frame)
        .arg("--camera")
        .arg(camera)
        .arg("-o")
        .arg(out)
        .output()
        .unwrap();
    assert_succeeded(&o);
}

const CAMERA: &str = "fx = 100.0\nfy = 200.0\ncx = 1.5\ncy = 1.0\ndepth_unit_m = 0.001\n\
                      sigma_m = 0.001\nsigma_per_m = 0.004\n\
                      [pose]\nrotation = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]\n\
                      translation = [0.0, 0.0, 1.0]\n";

/// The frame's 11 points, back-projected by hand: x = (u − 1.5)·0.5/100 for u = 0…3 (−7.5 to
/// +7.5 mm), y = (v − 1)·0.5/200 for v = 0…2 (−2.5 to +2.5 mm), z = 0.5 + 1 (the pose's
/// translation); each point's σ = 1 mm + 4 m⁻¹ · (0.5 m)² = 2 mm. `palpate info` says so. The
/// same frame saved as a PGM gives the same points.
#[test]
fn a_depth_frame_lands_where_the_pinhole_puts_it() {
    let tmp = tempfile::tempdir().unwrap();
    let png = tmp.path().join("frame.png");
    frame(&png);
    let camera = tmp.path().join("camera.toml");
    std::fs::write(&camera, CAMERA).unwrap();
    let out = tmp.path().join("scan");
    import_depth(&png, &camera, &out);
    let (points, sigma) =
        palpate_scan::cloud::read_ply_with(&out.join("points.ply"), "sigma").unwrap();
    assert_eq!(points.len(), 11);
    assert!(sigma.iter().all(|s| (s - 2e-3).abs() < 1e-15), "{sigma:?}");
    let info = palpate().arg("info").arg(&out).output().unwrap();
    assert_succeeded(&info);
    let j = last_json(&info);
    assert_eq!(j["points"], 11);
    let close = |v: &serde_json::Value, want: [f64; 3]| {
        (0..3).all(|k| (v[k].as_f64().unwrap() - want[k]).abs() < 1e-12)
    };
    assert!(close(&j["bounds_min_m"], [-7.5e-3, -2.5e-3, 1.5]), "{j}");
    assert!(close(&j["bounds_max_m"], [7.5e-3, 2.5e-3, 1.5]), "{j}");
    assert_eq!(j["noise"]["origin"], "declared");
    assert_eq!(j["camera"]["fy_px"], 200.0);

    // The same frame as a 16-bit binary PGM, written here by hand (header, then big-endian
    // samples in millimetres): the same points.
    let pgm = tmp.path().join("frame.pgm");
    let mut bytes = b"P5\n4 3\n65535\n".to_vec();
    for k in 0..12u16 {
        bytes.extend(if k == 0 { 0u16 } else { 500 }.to_be_bytes());
    }
    std::fs::write(&pgm, bytes).unwrap();
    let from_pgm = tmp.path().join("scan-pgm");
    import_depth(&pgm, &camera, &from_pgm);
    let (again, _) =
        palpate_scan::cloud::read_ply_with(&from_pgm.join("points.ply"), "sigma").unwrap();
    assert_eq!(again, points);
}

/// `palpate import cloud CLOUD --units mm --sigma 0.0005 -o OUT`, which must succeed.
fn import_cloud_mm(cloud: &Path, out: &Path) {
    let o = palpate()
        .args(["import", "cloud"])
        .arg(cloud)
        .args(["--units", "mm", "--sigma", "0.0005", "-o"])
        .arg(out)
        .output()
        .unwrap();
    assert_succeeded(&o);
}

/// A cloud in millimetres lands in metres; the σ given is kept. The same points as PCL's
/// binary PCD (with a colour field, and a NaN point that is no point) land in the same place.
#[test]
fn a_cloud_in_millimetres_lands_in_metres() {
    let tmp = tempfile::tempdir().unwrap();
    let xyz = tmp.path().join("cloud.xyz");
    std::fs::write(&xyz, "x y z\n1 2 3\n-4 5 6\n10,20,-30\n").unwrap();
    let pcd = tmp.path().join("cloud.pcd");
    let mut bytes = b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F U\n\
                      COUNT 1 1 1 1\nWIDTH 4\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 4\n\
                      DATA binary\n"
        .to_vec();
    for p in [
        [1f32, 2., 3.],
        [-4., 5., 6.],
        [f32::NAN; 3],
        [10., 20., -30.],
    ] {
        p.iter().for_each(|v| bytes.extend(v.to_le_bytes()));
        bytes.extend(0u32.to_le_bytes());
    }
    std::fs::write(&pcd, bytes).unwrap();
    let from_pcd = tmp.path().join("scan-pcd");
    import_cloud_mm(&pcd, &from_pcd);
    let (from_pcd, _) =
        palpate_scan::cloud::read_ply_with(&from_pcd.join("points.ply"), "sigma").unwrap();
    let out = tmp.path().join("scan");
    import_cloud_mm(&xyz, &out);
    let info = palpate()
        .arg("info")
        .arg(out.join("scan.toml"))
        .output()
        .unwrap();
    assert_succeeded(&info);
    let j = last_json(&info);
    assert_eq!(j["points"], 3);
    assert_eq!(j["bounds_min_m"][0], -4e-3);
    assert_eq!(j["bounds_max_m"][1], 20e-3);
    assert_eq!(j["bounds_min_m"][2], -30e-3);
    assert_eq!(j["noise"]["sigma_m"], 5e-4);
    assert!(j["camera"].is_null(), "{j}");
    let (from_xyz, _) =
        palpate_scan::cloud::read_ply_with(&out.join("points.ply"), "sigma").unwrap();
    assert_eq!(from_pcd, from_xyz);
}

/// Runs `palpate import <args…> -o <tmp>/scan` and returns its stderr, asserting it failed and
/// wrote nothing.
fn import_refused(tmp: &Path, args: &[&std::ffi::OsStr]) -> String {
    let out = tmp.join("scan");
    let o = palpate()
        .arg("import")
        .args(args)
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    let err = refused(&o);
    assert!(!out.exists(), "a refused import wrote {}", out.display());
    err
}

/// Depth frames: an 8-bit PNG, a PNG cut short, a camera without fy and one without the depth
/// unit — each named with its file and what was expected.
#[test]
fn bad_depth_frames_and_cameras_are_refused_by_name() {
    let tmp = tempfile::tempdir().unwrap();
    let camera = tmp.path().join("camera.toml");
    std::fs::write(&camera, CAMERA).unwrap();
    let good = tmp.path().join("frame.png");
    frame(&good);

    let eight = tmp.path().join("eight.png");
    {
        let f = std::fs::File::create(&eight).unwrap();
        let mut e = png::Encoder::new(std::io::BufWriter::new(f), 4, 3);
        e.set_color(png::ColorType::Grayscale);
        e.set_depth(png::BitDepth::Eight);
        e.write_header()
            .unwrap()
            .write_image_data(&[7; 12])
            .unwrap();
    }
    let err = import_refused(
        tmp.path(),
        &[
            "depth".as_ref(),
            eight.as_os_str(),
            "--camera".as_ref(),
            camera.as_os_str(),
        ],
    );
    assert!(err.contains("eight.png") && err.contains("16-bit"), "{err}");

    let cut = tmp.path().join("cut.png");
    let bytes = std::fs::read(&good).unwrap();
    std::fs::write(&cut, &bytes[..bytes.len() - 20]).unwrap();
    let err = import_refused(
        tmp.path(),
        &[
            "depth".as_ref(),
            cut.as_os_str(),
            "--camera".as_ref(),
            camera.as_os_str(),
        ],
    );
    assert!(err.contains("cut.png"), "{err}");

    let no_fy = tmp.path().join("no-fy.toml");
    std::fs::write(&no_fy, CAMERA.replace("fy = 200.0\n", "")).unwrap();
    let err = import_refused(
        tmp.path(),
        &[
            "depth".as_ref(),
            good.as_os_str(),
            "--camera".as_ref(),
            no_fy.as_os_str(),
        ],
    );
    assert!(err.contains("no-fy.toml") && err.contains("fy"), "{err}");

    let no_unit = tmp.path().join("no-unit.toml");
    std::fs::write(&no_unit, CAMERA.replace("depth_unit_m = 0.001\n", "")).unwrap();
    let err = import_refused(
        tmp.path(),
        &[
            "depth".as_ref(),
            good.as_os_str(),
            "--camera".as_ref(),
            no_unit.as_os_str(),
        ],
    );
    assert!(
        err.contains("no-unit.toml") && err.contains("depth_unit_m"),
        "{err}"
    );
}

/// Clouds: a PLY whose header promises more vertices than it holds (ASCII), one whose binary
/// header promises 10¹⁵ (refused, not an allocation of petabytes), an XYZ line with a word
/// for a number, and a cloud without its unit.
#[test]
fn bad_clouds_are_refused_by_name() {
    let tmp = tempfile::tempdir().unwrap();
    let mm = ["--units".as_ref(), "mm".as_ref()];

    let lying = tmp.path().join("lying.ply");
    std::fs::write(
        &lying,
        "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n",
    )
    .unwrap();
    let err = import_refused(
        tmp.path(),
        &[&["cloud".as_ref(), lying.as_os_str()], &mm[..]].concat(),
    );
    assert!(
        err.contains("lying.ply") && err.contains("instance 3 of 5"),
        "{err}"
    );

    let huge = tmp.path().join("huge.ply");
    let mut bytes = b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n".to_vec();
    bytes.extend_from_slice(&[0; 24]);
    std::fs::write(&huge, bytes).unwrap();
    let err = import_refused(
        tmp.path(),
        &[&["cloud".as_ref(), huge.as_os_str()], &mm[..]].concat(),
    );
    assert!(
        err.contains("huge.ply") && err.contains("instance 2 of 1000000000000000"),
        "{err}"
    );

    let xyz = tmp.path().join("bad.xyz");
    std::fs::write(&xyz, "1 2 3\n4 five 6\n").unwrap();
    let err = import_refused(
        tmp.path(),
        &[&["cloud".as_ref(), xyz.as_os_str()], &mm[..]].concat(),
    );
    assert!(
        err.contains("bad.xyz") && err.contains("line 2") && err.contains("five"),
        "{err}"
    );

    let o = palpate()
        .args(["import", "cloud"])
        .arg(&xyz)
        .output()
        .unwrap();
    let err = refused(&o);
    assert!(err.contains("--units"), "{err}");
}
