//! A scan dataset of a strip written to disk as a user's would be — a Gmsh mesh, 16-bit depth
//! frames imported through the camera file, `scans.toml` — with one effect the dataset does not
//! declare put into its frames: the test data of the scan diagnosis.
//!
//! The strip (80 × 20 × 10 mm, Neo-Hookean; the truth on the dataset's mesh or on one refined
//! [`StripCase::refine`] times per axis) hangs from its left face and, in a second
//! state, has its right face held and turned about the long axis. A 160 × 120 depth camera
//! (f = 210 px) sees it from the front and above; depth noise σ = 0.2 mm + 1e-3 m⁻¹·z², a tenth of
//! the pixels dropped, a depth unit of 0.1 mm.
//!
//! | injected | what the frames hold that `scans.toml` does not say |
//! |---|---|
//! | [`Injected::DepthBias`] | every depth read `b` too far |
//! | [`Injected::DepthScale`] | every depth read (1 + s) × too far |
//! | [`Injected::CameraMoved`] | the second state seen by a camera turned and shifted from the declared pose |
//! | [`Injected::SecondMaterial`] | the strip's part beyond a plane across its length `ratio` × stiffer |

use std::path::{Path, PathBuf};

use nalgebra::{Rotation3, Vector3};
use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_fem::mesh::gmsh::write_msh;
use palpate_fem::rng::SplitMix64;

use crate::camera::{Camera, Intrinsics, Pose};
use crate::dataset::HeldToml;
use crate::fit::{Design, LoadedObject};
use crate::record::{import_depth, write_scan};
use crate::render::{add_depth_noise, render_depth, DepthNoise};
use crate::ScanError;

/// What the frames hold that the dataset does not declare.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Injected {
    /// Nothing.
    None,
    /// Every depth read this much too far (m).
    DepthBias(f64),
    /// Every depth read (1 + this) × too far.
    DepthScale(f64),
    /// The second state's camera turned by `angle_deg` about its vertical and shifted by
    /// `shift_m` from its declared pose.
    CameraMoved {
        /// Turn (degrees).
        angle_deg: f64,
        /// Shift (m).
        shift_m: [f64; 3],
    },
    /// The part beyond `fraction` of the length `ratio` × as stiff as the rest.
    SecondMaterial {
        /// Where the plane cuts the length (0–1).
        fraction: f64,
        /// Its modulus over the rest's.
        ratio: f64,
    },
}

/// The strip and its scans.
#[derive(Debug, Clone)]
pub struct StripCase {
    /// Cells of the dataset's mesh along x, y, z.
    pub cells: [usize; 3],
    /// The truth's design.
    pub design: Design,
    /// The truth's mesh is the dataset's with each cell split this many times per axis (1: the
    /// dataset's own mesh; 2: a truth the fit's discretisation does not share).
    pub refine: usize,
    /// Young's modulus (Pa).
    pub young: f64,
    /// Poisson's ratio.
    pub poisson: f64,
    /// The effect put in.
    pub injected: Injected,
    /// The noise's seed.
    pub seed: u64,
}

impl Default for StripCase {
    fn default() -> Self {
        Self {
            cells: [8, 2, 1],
            design: Design::Quadratic,
            refine: 1,
            young: 300e3,
            poisson: 0.45,
            injected: Injected::None,
            seed: 1,
        }
    }
}

const SIZE: [f64; 3] = [0.08, 0.02, 0.01];
const DENSITY: f64 = 1100.0;
const GRAVITY: [f64; 3] = [0.0, 0.0, -9.81];
const DEPTH_UNIT_M: f64 = 1e-4;
const EYE: [f64; 3] = [0.05, -0.16, 0.08];
const TARGET: [f64; 3] = [0.04, 0.01, -0.01];

fn camera() -> Camera {
    Camera {
        intrinsics: Intrinsics {
            fx: 210.0,
            fy: 210.0,
            cx: 79.5,
            cy: 59.5,
        },
        pose: Pose::looking_at(EYE.into(), TARGET.into(), Vector3::z()),
    }
}

fn twist() -> HeldToml {
    HeldToml {
        group: "right".into(),
        axis: Some([1.0, 0.0, 0.0]),
        angle_deg: 30.0,
        about: [SIZE[0], SIZE[1] / 2.0, SIZE[2] / 2.0],
        translation: [0.0; 3],
    }
}

/// Writes the dataset of `case` into `dir` (made if missing): `mesh.msh`, `camera.toml`, the
/// frames `hanging.png` and `twisted.png`, their scan folders, `scans.toml`. Returns the files.
pub fn write_strip_dataset(dir: &Path, case: &StripCase) -> Result<Vec<PathBuf>, ScanError> {
    std::fs::create_dir_all(dir).map_err(|e| ScanError::io(dir, e))?;
    let dataset_mesh = box_mesh(SIZE, case.cells);
    let mesh = box_mesh(SIZE, case.cells.map(|c| c * case.refine.max(1)));
    let msh = dir.join("mesh.msh");
    write_msh(&dataset_mesh, &msh)
        .map_err(|e| ScanError::Invalid(format!("{}: {e}", msh.display())))?;
    let declared = camera();
    let camera_file = dir.join("camera.toml");
    let camera_toml = format!(
        "fx = 210.0\nfy = 210.0\ncx = 79.5\ncy = 59.5\ndepth_unit_m = {DEPTH_UNIT_M}\n\
         sigma_m = 0.0002\nsigma_per_m = 0.001\n[pose]\neye = {EYE:?}\ntarget = {TARGET:?}\n\
         up = [0.0, 0.0, 1.0]\n"
    );
    std::fs::write(&camera_file, camera_toml).map_err(|e| ScanError::io(&camera_file, e))?;
    let mut files = vec![msh, camera_file.clone()];
    let noise = DepthNoise {
        sigma_m: 2e-4,
        sigma_per_m: 1e-3,
        dropped: 0.1,
    };
    let mut rng = SplitMix64::new(case.seed);
    let mu = case.young / (2.0 * (1.0 + case.poisson));
    let held = twist();
    for (name, twisted) in [("hanging", false), ("twisted", true)] {
        let mut o = LoadedObject::hanging(
            &mesh,
            mesh.node_groups["left"].clone(),
            DENSITY,
            GRAVITY,
            case.poisson,
            case.design,
            // Newton's tolerance: a hundred-thousandth of the strip's weight (17 mN).
            1e-7,
        );
        if twisted {
            o.fixed_displacement = vec![[0.0; 3]; o.fixed.len()];
            for &n in &mesh.node_groups["right"] {
                let y = held.apply(mesh.nodes[n]);
                o.fixed.push(n);
                o.fixed_displacement
                    .push([0, 1, 2].map(|k| y[k] - mesh.nodes[n][k]));
            }
            o.load_steps = 20;
        }
        let moduli = match case.injected {
            Injected::SecondMaterial { fraction, ratio } => {
                o.regions = mesh
                    .tets
                    .iter()
                    .map(|t| {
                        let x = t.iter().map(|&n| mesh.nodes[n][0]).sum::<f64>() / 4.0;
                        usize::from(x > fraction * SIZE[0])
                    })
                    .collect();
                vec![mu, ratio * mu]
            }
            _ => vec![mu],
        };
        let eq = o.equilibrium_at(&moduli, false)?;
        let mut seen = declared;
        if let (Injected::CameraMoved { angle_deg, shift_m }, true) = (case.injected, twisted) {
            let turn = Rotation3::from_axis_angle(&Vector3::z_axis(), angle_deg.to_radians());
            seen.pose.rotation = turn * seen.pose.rotation;
            seen.pose.translation += Vector3::from(shift_m);
        }
        let mut image = render_depth(&seen, 160, 120, &eq.positions, &eq.surface);
        for z in image.depth.iter_mut().filter(|z| **z > 0.0) {
            match case.injected {
                Injected::DepthBias(b) => *z += b,
                Injected::DepthScale(s) => *z *= 1.0 + s,
                _ => {}
            }
        }
        add_depth_noise(&mut image, &noise, &mut rng);
        let png = dir.join(format!("{name}.png"));
        image.write_png(&png, DEPTH_UNIT_M)?;
        let scan = import_depth(&png, &camera_file)?;
        files.push(png);
        files.extend(write_scan(&dir.join(name), &scan)?);
    }
    let toml = dir.join(crate::dataset::DATASET_FILE);
    std::fs::write(
        &toml,
        format!(
            "mesh = \"mesh.msh\"\npoisson = {}\ndensity = {DENSITY}\ngravity = {GRAVITY:?}\n\n\
             [[states]]\nname = \"hanging\"\nscan = \"hanging\"\nclamped = [\"left\"]\n\n\
             [[states]]\nname = \"twisted\"\nscan = \"twisted\"\nclamped = [\"left\"]\n\
             [states.held]\ngroup = \"right\"\naxis = [1.0, 0.0, 0.0]\nangle_deg = {}\n\
             about = {:?}\n",
            case.poisson, held.angle_deg, held.about
        ),
    )
    .map_err(|e| ScanError::io(&toml, e))?;
    files.push(toml);
    Ok(files)
}
