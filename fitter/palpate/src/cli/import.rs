//! `palpate import c3d <capture.c3d> …`: a motion capture as a palpate motion dataset — the
//! capture frame registered to the mesh frame (Horn) on a frame at rest, the trajectories from
//! the release on, the mesh copied beside them.

use std::path::PathBuf;

use anyhow::Context;
use palpate_capture::import::{import_motion_dataset, ImportOptions};
use palpate_fem::io::parse_vec3_f64;

/// What to import.
#[derive(Debug, clap::Subcommand)]
pub enum ImportCommand {
    /// A C3D file (Qualisys, Vicon, OptiTrack, Motion Analysis export).
    C3d(C3dArgs),
}

/// Options of `palpate import c3d`.
#[derive(Debug, Clone, clap::Args)]
pub struct C3dArgs {
    /// The capture.
    pub capture: PathBuf,
    /// Tetrahedral mesh of the object in its own frame (Gmsh 4.1; see models/mesh_stl.py).
    #[arg(long)]
    pub mesh: PathBuf,
    /// Marker places in the mesh frame: CSV `marker,x,y,z` (m), labels as in the capture.
    #[arg(long)]
    pub places: PathBuf,
    /// Clamped physical groups of the mesh (comma-separated).
    #[arg(long, value_delimiter = ',', required = true)]
    pub clamps: Vec<String>,
    /// Gravity in the mesh frame, gx,gy,gz (m/s²).
    #[arg(long, value_parser = parse_vec3_f64, allow_hyphen_values = true)]
    pub gravity: [f64; 3],
    /// Density (kg/m³), if known.
    #[arg(long)]
    pub density: Option<f64>,
    /// A weight hung from the top edge of a group of the mesh (its nodes furthest against
    /// gravity), as `MASS_KG@GROUP`, e.g. `0.052@free_end`; repeat for several. Written as a
    /// `[[loads]]` table of the dataset (docs/motion-dataset.md).
    #[arg(long = "hang", value_name = "KG@GROUP", value_parser = parse_hang)]
    pub hang: Vec<(f64, String)>,
    /// Frame at rest used for the registration.
    #[arg(long, default_value_t = 0)]
    pub rest_frame: usize,
    /// Release: the last frame held still (simulation starts there). Default: detected as the
    /// frame before the registration markers' mean first moves more than `--release-threshold`.
    #[arg(long)]
    pub release_frame: Option<usize>,
    /// Movement (m) that detects the release.
    #[arg(long, default_value_t = 0.5e-3)]
    pub release_threshold: f64,
    /// Last frame imported (default: the end of the capture).
    #[arg(long)]
    pub last_frame: Option<usize>,
    /// Track only the markers with a declared place (by default the capture's other markers
    /// near the object are located from the rest frame and tracked too).
    #[arg(long)]
    pub declared_only: bool,
    /// Output dataset folder.
    #[arg(short, long)]
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

/// Runs the command.
pub fn run(cmd: ImportCommand) -> anyhow::Result<()> {
    let ImportCommand::C3d(a) = cmd;
    import_c3d(&a)
}

/// Imports one capture as `palpate import c3d` does (also the demo's first step).
pub fn import_c3d(a: &C3dArgs) -> anyhow::Result<()> {
    let capture = palpate_capture::read_c3d(&a.capture)?;
    let text = std::fs::read_to_string(&a.places)
        .with_context(|| format!("reading {}", a.places.display()))?;
    let mut places = Vec::new();
    // The one CSV tokenizer (1-based lines, `#` comments, a spreadsheet's byte-order mark).
    for (line, l) in palpate_fem::io::csv::records(&text, true) {
        if l.starts_with("marker,") {
            continue;
        }
        let f = palpate_fem::io::csv::fields(l);
        let at = |what: &str| format!("{}:{line}: {what}", a.places.display());
        if f.len() != 4 {
            anyhow::bail!(
                "{}",
                at(&format!("expected marker,x,y,z, found {} fields", f.len()))
            );
        }
        let mut p = [0.0; 3];
        for k in 0..3 {
            p[k] = palpate_fem::io::csv::finite(f[k + 1])
                .ok()
                .with_context(|| {
                    at(&format!(
                        "field {}: {:?} is not a finite number",
                        ["x", "y", "z"][k],
                        f[k + 1]
                    ))
                })?;
        }
        places.push((f[0].to_string(), p));
    }
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
                    "{}: no release found (the markers never move {} m from frame 0); give --release-frame",
                    a.capture.display(),
                    a.release_threshold
                )
            })?,
    };
    std::fs::create_dir_all(&a.output)
        .with_context(|| format!("creating {}", a.output.display()))?;
    std::fs::copy(&a.mesh, a.output.join("mesh.msh"))
        .with_context(|| format!("copying {}", a.mesh.display()))?;
    let mut toml = format!(
        "mesh = \"mesh.msh\"\nclamps = [{}]\ngravity = [{}, {}, {}]\n",
        a.clamps
            .iter()
            .map(|c| format!("{c:?}"))
            .collect::<Vec<_>>()
            .join(", "),
        a.gravity[0],
        a.gravity[1],
        a.gravity[2]
    );
    if let Some(d) = a.density {
        toml.push_str(&format!("density = {d}\n"));
    }
    // Tables last: every key after a `[[loads]]` header would belong to it.
    for (m, g) in &a.hang {
        toml.push_str(&format!(
            "\n[[loads]]\nname = \"{m} kg hung from {g}\"\ngroup = {g:?}\nedge = [{}, {}, {}]\nmass = {m}\n",
            -a.gravity[0],
            -a.gravity[1],
            -a.gravity[2]
        ));
    }
    let r = import_motion_dataset(
        &capture,
        &ImportOptions {
            places,
            rest_frame: a.rest_frame,
            release_frame,
            last_frame: a.last_frame,
            toml,
            locate_undeclared: !a.declared_only,
        },
        &a.output,
    )?;
    // The dataset must read back as palpate reads it (a `--hang` group the mesh lacks, a load on
    // the clamp): otherwise nothing stays written.
    if let Err(e) = palpate_motion::dataset::load(&a.output) {
        for f in r
            .files
            .iter()
            .chain(std::iter::once(&a.output.join("mesh.msh")))
        {
            let _ = std::fs::remove_file(f);
        }
        return Err(anyhow::anyhow!(e).context(format!(
            "the imported dataset {} does not read back; nothing kept",
            a.output.display()
        )));
    }
    // What import did is a note beside the dataset it wrote (stderr; `palpate info` reads the
    // dataset back).
    log::info!(
        "{}: {} markers at {} Hz, registered on frame {} (RMS {:.2} mm; per marker: {}); release at frame {release_frame}; {} steps",
        a.capture.display(),
        capture.labels.len(),
        capture.rate_hz,
        a.rest_frame,
        1e3 * r.transform.rms(),
        r.labels
            .iter()
            .zip(&r.transform.residuals)
            .map(|(l, e)| format!("{l} {:.2} mm", 1e3 * e))
            .collect::<Vec<_>>()
            .join(", "),
        r.steps
    );
    if !r.located.is_empty() {
        log::info!(
            "located from frame {} (no declared place): {}",
            a.rest_frame,
            r.located.join(", ")
        );
    }
    if !r.ignored.is_empty() {
        log::warn!(
            "left out (missing at rest, or far from the object): {}",
            r.ignored.join(", ")
        );
    }
    for f in r.files {
        log::info!("wrote {}", f.display());
    }
    Ok(())
}
