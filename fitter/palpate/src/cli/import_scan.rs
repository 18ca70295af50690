//! `palpate import depth <frame.png> --camera camera.toml` and `palpate import cloud <points>
//! --units mm`: a scan as palpate's scan folder (`points.ply` in metres in the mesh's frame with
//! each point's noise, `scan.toml` with where it came from; `palpate_scan::record`), and what
//! `palpate info` says of one.

use std::path::{Path, PathBuf};

use palpate_scan::record::{self, Scan};

/// Options of `palpate import depth`.
#[derive(Debug, Clone, clap::Args)]
pub struct DepthArgs {
    /// The depth frame: a 16-bit greyscale PNG or binary PGM (Netpbm P5), 0 where the sensor saw
    /// nothing.
    pub frame: PathBuf,
    /// The camera: a TOML file with fx, fy, cx, cy (pixels), depth_unit_m (metres per
    /// image unit), optionally sigma_m and sigma_per_m (depth noise σ = sigma_m + sigma_per_m·z²;
    /// estimated from the points' local scatter when absent) and a `[pose]` table into the
    /// mesh's frame (eye, target, up; or rotation rows and translation). Format:
    /// fitter/scan/src/record.rs.
    #[arg(long, value_name = "TOML")]
    pub camera: PathBuf,
    /// Output: the scan folder written (`points.ply`, `scan.toml`).
    #[arg(
        short = 'o',
        long = "output",
        visible_alias = "out",
        value_name = "DIR",
        default_value = "scan"
    )]
    pub output: PathBuf,
}

/// Options of `palpate import cloud`.
#[derive(Debug, Clone, clap::Args)]
pub struct CloudArgs {
    /// The point cloud: PLY (ASCII or binary; the vertex element's x, y, z), PCD (ASCII or
    /// binary; the x, y, z fields, NaN points dropped), or XYZ / CSV / TXT
    /// text (three numbers a line), in the mesh's frame.
    pub cloud: PathBuf,
    /// The coordinates' unit: m, cm, mm, um, or a number of metres per unit.
    #[arg(long, value_parser = parse_unit, value_name = "UNIT")]
    pub units: f64,
    /// The points' noise σ in metres, in every direction; estimated from their local scatter
    /// when absent.
    #[arg(long, value_name = "M")]
    pub sigma: Option<f64>,
    /// Output: the scan folder written (`points.ply`, `scan.toml`).
    #[arg(
        short = 'o',
        long = "output",
        visible_alias = "out",
        value_name = "DIR",
        default_value = "scan"
    )]
    pub output: PathBuf,
}

fn parse_unit(s: &str) -> Result<f64, String> {
    let v: f64 = match s.trim() {
        "m" => 1.0,
        "cm" => 1e-2,
        "mm" => 1e-3,
        "um" | "µm" => 1e-6,
        other => other
            .parse()
            .map_err(|_| format!("{s:?}: expected m, cm, mm, um or a number of metres per unit"))?,
    };
    if !(v.is_finite() && v > 0.0) {
        return Err(format!("{s:?}: a unit must be a positive number of metres"));
    }
    Ok(v)
}

/// Runs `palpate import depth`.
pub fn run_depth(a: &DepthArgs) -> anyhow::Result<()> {
    super::output::check_writable(&a.output)?;
    let scan = record::import_depth(&a.frame, &a.camera)?;
    write(&a.output, &scan)
}

/// Runs `palpate import cloud`.
pub fn run_cloud(a: &CloudArgs) -> anyhow::Result<()> {
    super::output::check_writable(&a.output)?;
    let scan = record::import_cloud(&a.cloud, a.units, a.sigma)?;
    write(&a.output, &scan)
}

/// Where a scan's noise acts, for a sentence: "along the camera ray", or "in any direction" for
/// a cloud without a camera.
fn direction(along: &str) -> String {
    if along == "any direction" {
        "in any direction".into()
    } else {
        format!("along the {along}")
    }
}

/// Writes the scan folder through a staging folder, so that a failed write leaves the output as
/// it was.
fn write(output: &Path, scan: &Scan) -> anyhow::Result<()> {
    let staged = super::output::Staged::new(output)?;
    let written = record::write_scan(&staged.path, scan)?;
    let files = staged.commit(written)?;
    log::info!(
        "{}: {} points, noise σ {:.3} mm + {:.3e} m⁻¹·z² {} ({})",
        scan.record.source,
        scan.record.points,
        1e3 * scan.record.noise.sigma_m,
        scan.record.noise.sigma_per_m,
        direction(&scan.record.noise.along),
        scan.record.noise.origin
    );
    for f in files {
        log::info!("wrote {}", f.display());
    }
    Ok(())
}

/// Whether `path` is a scan folder or its `scan.toml`.
pub fn is_scan(path: &Path) -> bool {
    if path.is_dir() {
        path.join(record::RECORD_FILE).is_file()
    } else {
        path.file_name().and_then(|n| n.to_str()) == Some(record::RECORD_FILE)
    }
}

/// `palpate info` of a scan: points, bounding box, units, camera, noise; a last JSON line.
pub fn info(path: &Path) -> anyhow::Result<()> {
    let scan = record::read_scan(path)?;
    let r = &scan.record;
    let (lo, hi) = scan.bounds();
    let camera = match &r.camera {
        Some(c) => {
            let t = scan
                .points
                .camera
                .as_ref()
                .map(|c| c.pose.translation)
                .unwrap_or_default();
            format!(
                "camera fx {} fy {} cx {} cy {} px at ({:.4}, {:.4}, {:.4}) m",
                c.fx, c.fy, c.cx, c.cy, t.x, t.y, t.z
            )
        }
        None => "no camera".into(),
    };
    println!(
        "{}: scan of a {} ({}); {} points in {} in the mesh's frame, from ({:.4}, {:.4}, {:.4}) to ({:.4}, {:.4}, {:.4}) m; source unit {} m; {camera}; noise σ {:.3} mm + {:.3e} m⁻¹·z² {} ({})",
        path.display(),
        r.kind,
        r.source,
        r.points,
        r.units,
        lo[0],
        lo[1],
        lo[2],
        hi[0],
        hi[1],
        hi[2],
        r.source_unit_m,
        1e3 * r.noise.sigma_m,
        r.noise.sigma_per_m,
        direction(&r.noise.along),
        r.noise.origin
    );
    println!(
        "{}",
        serde_json::json!({
            "schema_version": 1, "kind": "scan", "source_kind": r.kind, "source": r.source,
            "points": r.points, "units": r.units, "bounds_min_m": lo, "bounds_max_m": hi,
            "source_unit_m": r.source_unit_m,
            "camera": r.camera.as_ref().map(|c| serde_json::json!({
                "fx_px": c.fx, "fy_px": c.fy, "cx_px": c.cx, "cy_px": c.cy,
                "position_m": scan.points.camera.as_ref().map(|c| [c.pose.translation.x, c.pose.translation.y, c.pose.translation.z]),
            })),
            "noise": { "sigma_m": r.noise.sigma_m, "sigma_per_m": r.noise.sigma_per_m,
                       "along": r.noise.along, "origin": r.noise.origin },
        })
    );
    Ok(())
}
