//! A hanging strip's modulus from one depth image: the scan fit ([`palpate_scan::fit`]) end to
//! end on data whose truth is known.
//!
//! A silicone-like strip (80 × 20 × 10 mm, clamped over its end face, sagging under its own
//! weight) is solved at the true modulus, rendered by a depth camera looking at it from the side
//! and above ([`palpate_scan::render`]) with depth noise σ = 0.2 mm + 1 mm⁻¹·z² and pixels
//! dropped at random, and back-projected into points; μ is fitted on the coarse mesh with the
//! chosen element design (`--design p1|p2`). Three truths: the fit's own mesh and design (what
//! the residual and the fit can recover at all); linear tetrahedra on a mesh refined twice per
//! axis; quadratic tetrahedra on that refined mesh — the converged reference, what a real strip
//! of that modulus does.

use anyhow::{bail, Context as _};
use clap::Parser;
use nalgebra::Vector3;
use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_fem::mesh::Mesh;
use palpate_fem::rng::SplitMix64;
use palpate_scan::camera::{Camera, Intrinsics, Pose};
use palpate_scan::fit::{fit_scan, young, Design, FitSettings, LoadedObject, ScanPoints};
use palpate_scan::render::{noisy_scan, DepthNoise};
use palpate_scan::residual_vtu::write_fit_residual;

/// Arguments.
#[derive(Debug, Parser)]
pub struct Args {
    /// Cells of the fit's mesh along the strip, across it and through its thickness.
    #[arg(long, value_delimiter = ',', default_value = "16,4,2")]
    pub cells: Vec<usize>,
    /// Seed of the depth noise and the dropped pixels.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// The fit's element design: p1 (linear tetrahedra) or p2 (quadratic).
    #[arg(long, default_value = "p1")]
    pub design: String,
    /// The truths fitted: own (the fit's mesh and design), p1-fine, p2-fine (the mesh refined
    /// twice per axis, linear or quadratic tetrahedra).
    #[arg(long, value_delimiter = ',', default_value = "own,p1-fine,p2-fine")]
    pub truths: Vec<String>,
    /// A folder to write each fit's residual into as VTU (`<design>-<truth>-points.vtu`,
    /// `<design>-<truth>-surface.vtu`); nothing is written without it.
    #[arg(long)]
    pub vtu: Option<std::path::PathBuf>,
}

const SIZE: [f64; 3] = [0.08, 0.02, 0.01];
const E_TRUE: f64 = 300e3;
const NU: f64 = 0.45;
const SIGMA_A: f64 = 2e-4;
const SIGMA_B: f64 = 1e-3;
const DROPPED: f64 = 0.1;

fn design(name: &str) -> anyhow::Result<Design> {
    match name.to_ascii_lowercase().as_str() {
        "p1" => Ok(Design::Linear),
        "p2" => Ok(Design::Quadratic),
        _ => bail!("--design: expected p1 or p2, found {name:?}"),
    }
}

/// The strip on `mesh`, clamped over its end face x = 0.
fn strip(mesh: &Mesh, design: Design) -> LoadedObject<'_> {
    LoadedObject::hanging(
        mesh,
        (0..mesh.nodes.len())
            .filter(|&n| mesh.nodes[n][0] < 1e-9)
            .collect(),
        1100.0,
        [0.0, 0.0, -9.81],
        NU,
        design,
        // 1e-7 N against the strip's 0.17 N weight: below that Newton meets round-off.
        1e-7,
    )
}

/// The camera: beside the strip and above it, looking at its middle.
fn camera() -> Camera {
    Camera {
        intrinsics: Intrinsics {
            fx: 420.0,
            fy: 420.0,
            cx: 159.5,
            cy: 119.5,
        },
        pose: Pose::looking_at(
            Vector3::new(0.05, -0.16, 0.08),
            Vector3::new(0.04, 0.01, -0.01),
            Vector3::new(0.0, 0.0, 1.0),
        ),
    }
}

/// A depth image of the truth's surface, with the sensor's noise and dropped pixels,
/// back-projected, each point's depth σ beside it.
fn scan(positions: &[[f64; 3]], surface: &[[usize; 3]], seed: u64) -> ScanPoints {
    noisy_scan(
        &camera(),
        (320, 240),
        positions,
        surface,
        &DepthNoise {
            sigma_m: SIGMA_A,
            sigma_per_m: SIGMA_B,
            dropped: DROPPED,
        },
        &mut SplitMix64::new(seed),
    )
}

/// Runs the three cases and prints a table and one JSON line.
pub fn run(a: Args) -> anyhow::Result<()> {
    let [nx, ny, nz] = a.cells[..] else {
        bail!("--cells takes three counts, found {:?}", a.cells);
    };
    let fit_design = design(&a.design)?;
    if let Some(t) = a
        .truths
        .iter()
        .find(|t| !["own", "p1-fine", "p2-fine"].contains(&t.as_str()))
    {
        bail!("--truths: expected own, p1-fine or p2-fine, found {t:?}");
    }
    let mesh = box_mesh(SIZE, [nx, ny, nz]);
    let fine = box_mesh(SIZE, [2 * nx, 2 * ny, 2 * nz]);
    let mu_true = E_TRUE / (2.0 * (1.0 + NU));
    let object = strip(&mesh, fit_design);
    // Moduli a factor 2 apart around 1.7 × the truth: a grid that does not hold the truth.
    let settings = FitSettings {
        starts: (-3..=2).map(|k| 1.7 * mu_true * 2f64.powi(k)).collect(),
        // Far enough that the start's misfit (millimetres at the tip) keeps its points.
        max_distance: 2e-2,
        max_iter: 30,
    };
    let mut rows = Vec::new();
    for (case, key, truth) in [
        (
            "truth: the fit's mesh and design",
            "own",
            strip(&mesh, fit_design),
        ),
        (
            "truth: P1 on the mesh refined 2×",
            "p1-fine",
            strip(&fine, Design::Linear),
        ),
        (
            "truth: P2 on the mesh refined 2× (converged)",
            "p2-fine",
            strip(&fine, Design::Quadratic),
        ),
    ]
    .into_iter()
    .filter(|(_, key, _)| a.truths.iter().any(|t| t == key))
    {
        let t0 = std::time::Instant::now();
        let eq = truth
            .equilibrium(mu_true, false)
            .with_context(|| format!("{case}: the truth's equilibrium"))?;
        let tip = eq
            .positions
            .iter()
            .zip(&eq.rest)
            .map(|(x, x0)| x0[2] - x[2])
            .fold(0.0, f64::max);
        let points = scan(&eq.positions, &eq.surface, a.seed);
        log::info!(
            "{case}: tip sag {:.2} mm, {} points",
            1e3 * tip,
            points.points.len()
        );
        let t1 = std::time::Instant::now();
        let fit = match fit_scan(&object, &points, &settings) {
            Ok(f) => f,
            // A design that cannot take the truth's shape may find no modulus: that is a
            // result of the comparison, printed as a row, not the end of the run.
            Err(e) => {
                println!(
                    "| {} fit, {case} | {} tets | tip sag {:.1} mm | {} points | no fit: {e} | | fit {:.1} s |",
                    fit_design.name(),
                    truth.mesh.tets.len(),
                    1e3 * tip,
                    points.points.len(),
                    t1.elapsed().as_secs_f64()
                );
                rows.push(serde_json::json!({
                    "case": key, "truth_design": truth.design.name(), "truth_tets": truth.mesh.tets.len(),
                    "fit_design": fit_design.name(), "fit_tets": mesh.tets.len(),
                    "tip_sag_m": tip, "points": points.points.len(), "error": e.to_string(),
                }));
                continue;
            }
        };
        let used = fit
            .at_fit
            .residuals
            .iter()
            .filter(|r| r.weight > 0.0)
            .count();
        let err = 100.0 * (fit.young_modulus / E_TRUE - 1.0);
        if let Some(dir) = &a.vtu {
            let name = format!("{}-{key}", fit_design.name().to_ascii_lowercase());
            for f in write_fit_residual(dir, &name, &points, &fit)
                .with_context(|| format!("{case}: the residual's VTU"))?
            {
                log::info!("wrote {}", f.display());
            }
        }
        println!(
            "| {} fit, {case} | {} tets | tip sag {:.1} mm | {} points, {used} used | E {:.1} kPa ({err:+.2} %) | {} iterations | fit {:.1} s |",
            fit_design.name(),
            truth.mesh.tets.len(),
            1e3 * tip,
            points.points.len(),
            fit.young_modulus / 1e3,
            fit.iterations,
            t1.elapsed().as_secs_f64()
        );
        log::info!(
            "{case}: {:.1} s with the truth's solve",
            t0.elapsed().as_secs_f64()
        );
        rows.push(serde_json::json!({
            "case": key, "truth_design": truth.design.name(), "truth_tets": truth.mesh.tets.len(),
            "fit_design": fit_design.name(), "fit_tets": mesh.tets.len(),
            "tip_sag_m": tip, "points": points.points.len(), "used": used,
            "e_fitted_pa": fit.young_modulus, "e_error_percent": err, "iterations": fit.iterations,
            "fit_seconds": t1.elapsed().as_secs_f64(),
        }));
    }
    println!(
        "{}",
        serde_json::json!({
            "e_true_pa": young(mu_true, NU), "nu": NU, "seed": a.seed, "cases": rows
        })
    );
    Ok(())
}
