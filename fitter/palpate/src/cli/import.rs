//! `palpate import c3d <capture.c3d> …`: a motion capture as a palpate motion dataset — the
//! capture frame registered to the mesh frame (Horn) on a frame at rest, the trajectories from
//! the release on, the mesh copied beside them. `palpate import depth|cloud`: a scan
//! (`super::import_scan`).

use std::path::{Path, PathBuf};

use anyhow::Context;
use palpate_capture::import::{import_motion, ImportOptions, Imported};
use palpate_fem::io::parse_vec3_f64;
use palpate_motion::dataset::{DatasetToml, LoadToml, MotionDataset, MotionDatasetFiles};

/// What to import.
#[derive(Debug, clap::Subcommand)]
pub enum ImportCommand {
    /// A C3D file (Qualisys, Vicon, OptiTrack, Motion Analysis export).
    C3d(C3dArgs),
    /// A depth frame (16-bit PNG or PGM) and its camera (TOML), back-projected into a scan folder.
    Depth(super::import_scan::DepthArgs),
    /// A point cloud (PLY, PCD, XYZ, CSV) in the mesh's frame, as a scan folder.
    Cloud(super::import_scan::CloudArgs),
}

/// The time integration `palpate import c3d` writes when `--scheme` is not given: a dataset's
/// own default.
pub const DEFAULT_SCHEME: &str = palpate_motion::timestep::DATASET_DEFAULT.name();

/// Options of `palpate import c3d`.
#[derive(Debug, Clone, clap::Args)]
pub struct C3dArgs {
    /// The capture.
    pub capture: PathBuf,
    /// Tetrahedral mesh of the object in its own frame (Gmsh 4.1; see models/mesh_stl.py).
    #[arg(long)]
    pub mesh: PathBuf,
    /// Marker places in the mesh frame: CSV with the header `marker,x,y,z` (columns in any
    /// order; m), labels as in the capture.
    #[arg(long)]
    pub places: PathBuf,
    /// Clamped physical groups of the mesh (comma-separated).
    #[arg(long, value_delimiter = ',', required = true, value_name = "GROUP,…")]
    pub clamps: Vec<String>,
    /// Gravity in the mesh frame, gx,gy,gz (m/s²).
    #[arg(
        long,
        value_parser = parse_vec3_f64,
        allow_hyphen_values = true,
        value_name = "GX,GY,GZ"
    )]
    pub gravity: [f64; 3],
    /// Density (kg/m³), if known.
    #[arg(long, value_name = "KG_M3")]
    pub density: Option<f64>,
    /// Time integration written into the dataset: `midpoint` (the implicit midpoint rule, the
    /// default: no numerical damping, ≥ 15 steps per period of the capture's ring-down; a model
    /// without viscosity is integrated by BDF2 at that step, since an undamped released body can
    /// blow up under the midpoint rule), `bdf2` (Real2Sim's, ≥ 32 steps per period) or `alpha`
    /// (generalised-α, ρ∞ = 0.8: ≥ 16 steps per period, damps only the unresolved modes);
    /// docs/motion-dataset.md. The midpoint rule is the default because at the capture's own
    /// rate its step error on the measured beam is below BDF2's at twice the steps
    /// (docs/results/beam/README.md, "Converged in time").
    #[arg(long, default_value = DEFAULT_SCHEME, value_parser = ["bdf2", "midpoint", "alpha"])]
    pub scheme: String,
    /// A weight hung from the top edge of a group of the mesh (its nodes furthest against
    /// gravity), as `MASS_KG@GROUP`, e.g. `0.052@free_end`; repeat for several. Written as a
    /// `[[loads]]` table of the dataset (docs/motion-dataset.md).
    #[arg(long = "hang", value_name = "KG@GROUP", value_parser = parse_hang)]
    pub hang: Vec<(f64, String)>,
    /// Frame at rest used for the registration [default: the first frame before the release
    /// that sees every placed marker].
    #[arg(long)]
    pub rest_frame: Option<usize>,
    /// Release: the last frame held still (simulation starts there). Default: detected as the
    /// frame before the registration markers' mean first moves more than `--release-threshold`.
    #[arg(long)]
    pub release_frame: Option<usize>,
    /// Movement (m) that detects the release.
    #[arg(long, default_value_t = 0.5e-3, value_name = "M")]
    pub release_threshold: f64,
    /// Last frame imported (default: the end of the capture).
    #[arg(long)]
    pub last_frame: Option<usize>,
    /// Track only the markers with a declared place (by default the capture's other markers
    /// near the object are located from the rest frame and tracked too).
    #[arg(long)]
    pub declared_only: bool,
    /// Output: the motion dataset folder written (`dataset.toml`, `markers.csv`,
    /// `trajectories.csv` and the mesh).
    #[arg(
        short = 'o',
        long = "output",
        visible_alias = "out",
        value_name = "DIR",
        default_value = "motion-dataset"
    )]
    pub output: PathBuf,
}

fn parse_hang(s: &str) -> Result<(f64, String), String> {
    let (m, g) = s
        .split_once('@')
        .ok_or_else(|| format!("{s:?}: expected MASS_KG@GROUP, e.g. 0.052@free_end"))?;
    let m: f64 = m
        .trim()
        .parse()
        .map_err(|_| format!("{s:?}: the mass {m:?} is not a number (kg)"))?;
    if !(m.is_finite() && m > 0.0) {
        return Err(format!("{s:?}: the mass must be finite and > 0 kg"));
    }
    if g.trim().is_empty() {
        return Err(format!("{s:?}: no group after '@'"));
    }
    Ok((m, g.trim().to_string()))
}

/// The marker places: CSV `marker,x,y,z` (m), its header naming the columns in any order,
/// read by the dataset readers' CSV layer (quoted labels, `#` comments, errors naming the
/// file, line and column).
fn read_places(path: &Path) -> anyhow::Result<Vec<(String, [f64; 3])>> {
    let table = palpate_fem::io::csv::Table::read(path.to_path_buf())?;
    table
        .rows(&["marker", "x", "y", "z"], 0)?
        .iter()
        .map(|row| Ok((row.id(0)?.to_string(), row.vec3(1)?)))
        .collect()
}

/// Runs the command.
pub fn run(cmd: ImportCommand) -> anyhow::Result<()> {
    match cmd {
        ImportCommand::C3d(a) => import_c3d(&a).map(|_| ()),
        ImportCommand::Depth(a) => super::import_scan::run_depth(&a),
        ImportCommand::Cloud(a) => super::import_scan::run_cloud(&a),
    }
}

/// Checks the flags before the capture is read and before any folder is made.
fn check_args(a: &C3dArgs) -> anyhow::Result<()> {
    palpate_fem::sanity::check_gravity(a.gravity)
        .map_err(|why| anyhow::anyhow!("--gravity: {why}"))?;
    if let Some(d) = a.density {
        palpate_fem::sanity::check_density(d).map_err(|why| anyhow::anyhow!("--density: {why}"))?;
    }
    // Zero or less would find the release at the first frame that differs by a rounding error.
    if !(a.release_threshold.is_finite() && a.release_threshold > 0.0 && a.release_threshold <= 1.0)
    {
        anyhow::bail!(
            "--release-threshold {}: expected a movement in (0, 1] m (the default 0.0005 m is \
             half a millimetre)",
            palpate_fem::sanity::show(a.release_threshold)
        );
    }
    if a.clamps.iter().any(|c| c.trim().is_empty()) {
        anyhow::bail!("--clamps: an empty group name in {:?}", a.clamps);
    }
    super::input_kind::expect(&a.capture, super::input_kind::Kind::C3d, "import c3d")?;
    super::input_kind::expect(&a.mesh, super::input_kind::Kind::Gmsh, "import c3d --mesh")?;
    super::output::check_writable(&a.output)?;
    Ok(())
}

/// Imports one capture as `palpate import c3d` does (also the demo's first step), and returns the
/// dataset as it read back from what was written (its step checked), so that a caller need not
/// read it again.
pub fn import_c3d(a: &C3dArgs) -> anyhow::Result<MotionDataset> {
    check_args(a)?;
    let capture = palpate_capture::read_c3d(&a.capture)?;
    let places = read_places(&a.places)?;
    let ids: Vec<usize> = places
        .iter()
        .map(|(l, _)| capture.marker(l))
        .collect::<Result<_, _>>()?;
    let release_frame = match a.release_frame {
        Some(f) => f,
        None => capture
            .release_frame(&ids, a.release_threshold)
            .map(|f| f - 1)
            .with_context(|| {
                format!(
                    "{}: no release found (the placed markers seen never move {} m, on average, \
                     from where each was first seen); give --release-frame",
                    a.capture.display(),
                    a.release_threshold
                )
            })?,
    };
    let rest_frame = match a.rest_frame {
        Some(f) => f,
        None => capture
            .first_frame_seeing_all(&ids, release_frame)
            .with_context(|| {
                let lost: Vec<&str> = ids
                    .iter()
                    .zip(&places)
                    .filter(|(&k, _)| {
                        (0..=release_frame.min(capture.positions.len().saturating_sub(1)))
                            .all(|f| capture.positions[f][k].is_none())
                    })
                    .map(|(_, (l, _))| l.as_str())
                    .collect();
                format!(
                    "{}: no frame up to the release (frame {release_frame}) sees every placed \
                     marker (never seen there: {lost:?}); give --rest-frame, or leave those \
                     markers out of the places",
                    a.capture.display()
                )
            })?,
    };
    // The dataset is written beside its place and swapped in only once it reads back: a failing
    // import leaves the previous dataset at the output whole.
    let had_output = a.output.exists();
    let staged = super::output::Staged::new(&a.output)?;
    let out = staged.path.clone();
    std::fs::copy(&a.mesh, out.join("mesh.msh"))
        .with_context(|| format!("copying {}", a.mesh.display()))?;
    let r = import_motion(
        &capture,
        &ImportOptions {
            places,
            rest_frame,
            release_frame,
            last_frame: a.last_frame,
            locate_undeclared: !a.declared_only,
        },
    )?;
    let written = palpate_motion::dataset::write_files(&out, &dataset_files(a, &r))?;
    // The dataset must read back as palpate reads it (a `--hang` group the mesh lacks, a load on
    // the clamp, a mesh in other units than the places): otherwise the staging folder is
    // dropped and the output keeps what it had.
    let ds = match palpate_motion::dataset::load(&out) {
        Ok(ds) => ds,
        Err(e) => {
            // The reader names the staging folder; the user knows the output's name.
            let what = e
                .to_string()
                .replace(&out.display().to_string(), &a.output.display().to_string());
            return Err(anyhow::anyhow!(what).context(if had_output {
                format!(
                    "the imported dataset does not read back; {} left as it was",
                    a.output.display()
                )
            } else {
                format!(
                    "the imported dataset does not read back; nothing written to {}",
                    a.output.display()
                )
            }));
        }
    };
    let files = staged.commit(written)?;
    // What import did is a note beside the dataset it wrote (stderr; `palpate info` reads the
    // dataset back).
    log::info!(
        "{}: {} markers at {} Hz, registered on frame {} (RMS {:.2} mm; per marker: {}); release at frame {release_frame}; {}",
        a.capture.display(),
        capture.labels.len(),
        capture.rate_hz,
        rest_frame,
        1e3 * r.transform.rms(),
        r.labels
            .iter()
            .zip(&r.transform.residuals)
            .map(|(l, e)| format!("{l} {:.2} mm", 1e3 * e))
            .collect::<Vec<_>>()
            .join(", "),
        ds.steps_sentence()
    );
    if !r.located.is_empty() {
        log::info!(
            "located from frame {} (no declared place): {}",
            rest_frame,
            r.located.join(", ")
        );
    }
    if !r.ignored.is_empty() {
        log::warn!(
            "left out (missing at rest, or far from the object): {}",
            r.ignored.join(", ")
        );
    }
    for f in files {
        log::info!("wrote {}", f.display());
    }
    Ok(ds)
}

/// The imported capture as the files of a motion dataset: the flags' clamps, gravity, density
/// and hung weights in `dataset.toml`, the capture's markers and trajectories at its precision.
fn dataset_files(a: &C3dArgs, r: &Imported) -> MotionDatasetFiles {
    let mut config = DatasetToml::new(r.dt, a.clamps.clone());
    // The capture starts from the held shape, not from a static sag.
    config.static_start = Some(false);
    config.gravity = Some(a.gravity);
    config.density = a.density;
    // Written even at its default, so that the dataset says how it is integrated.
    config.scheme = Some(a.scheme.clone());
    config.loads = a
        .hang
        .iter()
        .map(|(m, g)| LoadToml {
            name: Some(format!("{m} kg hung from {g}")),
            group: g.clone(),
            edge: Some(a.gravity.map(|v| -v)),
            force: None,
            mass: Some(*m),
            from_t: 0.0,
            inertia: false,
            lever_m: None,
        })
        .collect();
    MotionDatasetFiles::captured(
        config,
        vec![r.source_note.clone()],
        r.markers.clone(),
        &r.trajectories,
    )
}
