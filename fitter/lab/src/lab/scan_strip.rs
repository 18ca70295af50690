//! A hanging strip's modulus from one depth image: the scan residual
//! ([`palpate_scan::surface`]) closing a fit, end to end on data whose truth is known.
//!
//! A silicone-like strip (80 × 20 × 10 mm, clamped over its end face, sagging under its own
//! weight) is solved with the Neo-Hookean static solver ([`palpate_motion::statics`]) at the true
//! modulus, rendered by a depth camera looking at it from the side and above
//! ([`palpate_scan::render`]) with depth noise σ = 0.2 mm + 1 mm⁻¹·z² and pixels dropped at
//! random, and back-projected into points. From a start chosen on a coarse grid of moduli (a
//! factor 2 apart, not holding the truth), μ is fitted by
//! Gauss–Newton in ln μ (ν held at the truth's) on the points' distances to the deformed
//! surface over the noise along each face's normal, Tukey-weighted, the correspondences found
//! again at every iteration; ∂x/∂ln μ by central differences of the static solve. Two cases:
//! the truth on the fit's own mesh (what the residual and the fit can recover at all), and the
//! truth on a mesh refined twice per axis (what a fit on a coarse mesh makes of a real strip:
//! linear tetrahedra are stiff in bending, so the modulus comes out low).

use anyhow::{bail, Context as _};
use clap::Parser;
use nalgebra::Vector3;
use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_fem::mesh::Mesh;
use palpate_fem::rng::SplitMix64;
use palpate_motion::hyperelastic::HyperParams;
use palpate_motion::statics::{solve_static, StaticProblem};
use palpate_scan::camera::{Camera, Intrinsics, Pose};
use palpate_scan::render::render_depth;
use palpate_scan::surface::{correspond, Correspondence, RobustLoss};

/// Arguments.
#[derive(Debug, Parser)]
pub struct Args {
    /// Cells of the fit's mesh along the strip, across it and through its thickness.
    #[arg(long, value_delimiter = ',', default_value = "16,4,2")]
    pub cells: Vec<usize>,
    /// Seed of the depth noise and the dropped pixels.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

const SIZE: [f64; 3] = [0.08, 0.02, 0.01];
const E_TRUE: f64 = 300e3;
const NU: f64 = 0.45;
const DENSITY: f64 = 1100.0;
const GRAVITY: [f64; 3] = [0.0, 0.0, -9.81];
const SIGMA_A: f64 = 2e-4;
const SIGMA_B: f64 = 1e-3;
const DROPPED: f64 = 0.1;

fn params(mu: f64) -> HyperParams {
    HyperParams {
        lambda: 2.0 * mu * NU / (1.0 - 2.0 * NU),
        mu,
        stiffening: 0.0,
    }
}

/// The strip's equilibrium under its weight at shear modulus `mu`: node positions.
fn hang(mesh: &Mesh, mu: f64) -> anyhow::Result<Vec<[f64; 3]>> {
    let fixed: Vec<usize> = (0..mesh.nodes.len())
        .filter(|&n| mesh.nodes[n][0] < 1e-9)
        .collect();
    let mut p = StaticProblem::new(mesh, params(mu), fixed);
    p.density = DENSITY;
    p.gravity = GRAVITY;
    // 1e-7 N against the strip's 0.17 N weight: below that Newton meets round-off.
    p.tol = 1e-7;
    Ok(solve_static(&p)
        .with_context(|| format!("the strip's equilibrium at μ = {mu:.1} Pa"))?
        .positions)
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

/// A depth image of the truth, with the sensor's noise and dropped pixels, back-projected.
fn scan(truth: &Mesh, positions: &[[f64; 3]], seed: u64) -> Vec<Vector3<f64>> {
    let cam = camera();
    let mut image = render_depth(&cam, 320, 240, positions, &truth.boundary_triangles());
    let mut rng = SplitMix64::new(seed);
    for z in image.depth.iter_mut().filter(|z| **z > 0.0) {
        *z = if rng.uniform() < DROPPED {
            0.0
        } else {
            *z + (SIGMA_A + SIGMA_B * *z * *z) * rng.normal()
        };
    }
    cam.points(&image)
}

/// Residuals over their noise and their Tukey weights, at the surface `positions`.
fn residuals(
    positions: &[[f64; 3]],
    tris: &[[usize; 3]],
    points: &[Vector3<f64>],
) -> (Vec<Correspondence>, Vec<f64>, Vec<f64>) {
    let cam = camera();
    // Far enough that the start's misfit (millimetres at the tip) keeps its points.
    let (found, _) = correspond(positions, tris, points, 2e-2);
    let r: Vec<f64> = found
        .iter()
        .map(|c| {
            let p = points[c.point];
            let z = cam.pose.to_camera(p).z;
            c.distance
                / cam
                    .noise_along(p, c.normal, SIGMA_A + SIGMA_B * z * z)
                    .max(1e-9)
        })
        .collect();
    // Tukey's window at 4 of the residuals' robust scale (1.4826 × their median absolute
    // value), never narrower than 4 σ: far from the fit the whole misfit is "outlying" for a
    // window of 4 σ, and the points that would pull the fit there get no weight.
    let mut abs: Vec<f64> = r.iter().map(|v| v.abs()).collect();
    abs.sort_by(f64::total_cmp);
    let scale = (1.4826 * abs.get(abs.len() / 2).copied().unwrap_or(1.0)).max(1.0);
    let w = r
        .iter()
        .map(|v| RobustLoss::Tukey(4.0).weight(v / scale))
        .collect();
    (found, r, w)
}

/// One case: the fitted E, the points used, the iterations.
fn fit(mesh: &Mesh, points: &[Vector3<f64>]) -> anyhow::Result<(f64, usize, usize)> {
    let tris = mesh.boundary_triangles();
    let cam = camera();
    // The start: of moduli a factor 2 apart around 1.7 × the truth (a grid that does not hold
    // the truth itself), the one whose surface
    // leaves the fewest points far off (a truncated quadratic, every point beyond 4 σ or
    // unmatched counting 16). Far from the fit, closest points pair a scan's face with the
    // wrong face of the model, and Gauss–Newton from there can walk away from the minimum.
    let start = (1.7 * E_TRUE / (2.0 * (1.0 + NU))).ln();
    let mut best = (f64::INFINITY, start);
    for k in -3..=2 {
        let ln_mu = start + k as f64 * std::f64::consts::LN_2;
        let x = hang(mesh, ln_mu.exp())?;
        let (found, r, _) = residuals(&x, &tris, points);
        let cost = r.iter().map(|v| (v * v).min(16.0)).sum::<f64>()
            + 16.0 * (points.len() - found.len()) as f64;
        log::info!(
            "start E {:.1} kPa: truncated cost {cost:.4e}",
            2.0 * (1.0 + NU) * ln_mu.exp() / 1e3
        );
        if cost < best.0 {
            best = (cost, ln_mu);
        }
    }
    let mut ln_mu = best.1;
    for it in 1..=30 {
        let x = hang(mesh, ln_mu.exp())?;
        let (found, r, w) = residuals(&x, &tris, points);
        if found.len() < 100 {
            bail!(
                "iteration {it}: only {} points near the surface",
                found.len()
            );
        }
        let h = 1e-3;
        let (xp, xm) = (
            hang(mesh, (ln_mu + h).exp())?,
            hang(mesh, (ln_mu - h).exp())?,
        );
        let (mut jtj, mut jtr) = (0.0, 0.0);
        for ((c, r), w) in found.iter().zip(&r).zip(&w) {
            let p = points[c.point];
            let z = cam.pose.to_camera(p).z;
            let s = cam
                .noise_along(p, c.normal, SIGMA_A + SIGMA_B * z * z)
                .max(1e-9);
            let j: f64 = c
                .jacobian()
                .iter()
                .map(|(n, d)| {
                    let dx = (Vector3::from(xp[*n]) - Vector3::from(xm[*n])) / (2.0 * h);
                    d.dot(&dx)
                })
                .sum::<f64>()
                / s;
            jtj += w * j * j;
            jtr += w * j * r;
        }
        let step = (-jtr / jtj).clamp(-0.5, 0.5);
        ln_mu += step;
        log::info!(
            "iteration {it}: E {:.1} kPa, {} points, step {step:+.2e}",
            2.0 * (1.0 + NU) * ln_mu.exp() / 1e3,
            found.len()
        );
        // 1e-4 in ln E: a hundredth of a per cent, below what the correspondences' switching
        // between triangles lets the steps settle to.
        if step.abs() < 1e-4 {
            return Ok((2.0 * (1.0 + NU) * ln_mu.exp(), found.len(), it));
        }
    }
    bail!("Gauss–Newton did not settle in 30 iterations")
}

/// Runs both cases and prints a table and one JSON line.
pub fn run(a: Args) -> anyhow::Result<()> {
    let [nx, ny, nz] = a.cells[..] else {
        bail!("--cells takes three counts, found {:?}", a.cells);
    };
    let mesh = box_mesh(SIZE, [nx, ny, nz]);
    let fine = box_mesh(SIZE, [2 * nx, 2 * ny, 2 * nz]);
    let mu_true = E_TRUE / (2.0 * (1.0 + NU));
    let mut rows = Vec::new();
    for (case, truth) in [
        ("truth on the fit's mesh", &mesh),
        ("truth on the mesh refined 2×", &fine),
    ] {
        let t0 = std::time::Instant::now();
        let x = hang(truth, mu_true)?;
        let tip = x
            .iter()
            .zip(&truth.nodes)
            .map(|(x, x0)| x0[2] - x[2])
            .fold(0.0, f64::max);
        let points = scan(truth, &x, a.seed);
        log::info!(
            "{case}: tip sag {:.2} mm, {} points",
            1e3 * tip,
            points.len()
        );
        let (e, used, iterations) = fit(&mesh, &points)?;
        let err = 100.0 * (e / E_TRUE - 1.0);
        println!(
            "| {case} | {} tets | tip sag {:.1} mm | {} points, {used} used | E {:.1} kPa ({err:+.2} %) | {iterations} iterations | {:.1} s |",
            truth.tets.len(),
            1e3 * tip,
            points.len(),
            e / 1e3,
            t0.elapsed().as_secs_f64()
        );
        rows.push(serde_json::json!({
            "case": case, "truth_tets": truth.tets.len(), "fit_tets": mesh.tets.len(),
            "tip_sag_m": tip, "points": points.len(), "used": used, "e_fitted_pa": e,
            "e_error_percent": err, "iterations": iterations,
        }));
    }
    println!(
        "{}",
        serde_json::json!({ "e_true_pa": E_TRUE, "nu": NU, "seed": a.seed, "cases": rows })
    );
    Ok(())
}
