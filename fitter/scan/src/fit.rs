//! A material's shear modulus from a scan of the object at rest under its weight: μ (at a held
//! Poisson's ratio) fitted by Gauss–Newton in ln μ to the scanned points' signed distances to
//! the deformed surface ([`crate::surface`]), through the Neo-Hookean static solver on linear
//! (P1, [`palpate_motion::statics`]) or quadratic (P2, [`palpate_motion::quadratic_statics`])
//! tetrahedra, with the solver's analytic sensitivity ∂x/∂ln μ = λ ∂x/∂λ + μ ∂x/∂μ (λ ∝ μ at
//! fixed ν).
//!
//! - **Residual**: rᵢ = dᵢ/sᵢ, dᵢ the point's signed distance along the normal at its closest
//!   point, sᵢ its noise along that normal (a depth camera's noise lies along its ray,
//!   [`crate::camera::Camera::noise_along`]; without a camera the σ given is taken in every
//!   direction). Its derivative is Jᵢ = Σₙ (−bₙ n)·∂xₙ/∂ln μ over the triangle's nodes.
//! - **Weights**: Tukey's biweight at 4 robust scales of the residuals (1.4826 × their median
//!   absolute value, never below 1), so points of the background, the clamp or flying pixels
//!   get none. Weights, scales and the correspondence search are iteratively reweighted: held
//!   within an iteration, found again at the next.
//! - **The P2 surface**: each quadratic boundary triangle is split into four flat triangles
//!   through its mid-edge nodes. Every vertex of that surface is a node of the quadratic mesh,
//!   so the closest-point search and its Jacobian −bₙ n are those of the linear surface, applied
//!   to the P2 solution's own nodes and sensitivities; the flat pieces depart from the curved
//!   triangle by the sagitta of a half edge, about h²κ/32 (h an edge, κ the surface's
//!   curvature): 11 µm on a 5 mm edge bent to a 7 cm radius (a 80 mm strip sagging 20 mm, at
//!   its clamp), far below a depth camera's noise (0.2 mm and more). The exact closest point
//!   on a curved triangle would need a Newton search per point and iteration for that.
//! - **Start**: far from the fit, closest points pair the scan's top face with the model's side
//!   and Gauss–Newton can walk away; the fit starts from the caller's trial modulus whose
//!   surface is nearest the scan by the median distance (an unmatched point counting the
//!   search radius): robust to up to half the points being the background or a part the trial
//!   bends wrongly, where a cost truncated at a few σ counts little but the points a trial
//!   happens to pass through.
//! - **Steps**: the Gauss–Newton step, at most 0.5 in ln μ; one over 1 % is halved (up to ten
//!   times) until it does not raise the iteration's weighted cost. Done when the step is below
//!   1e-4 in ln μ.

use nalgebra::Vector3;
use palpate_fem::mesh::quadratic::QuadraticMesh;
use palpate_fem::mesh::Mesh;
use palpate_motion::quadratic_statics::{quadratic_sensitivity, solve_static_quadratic};
use palpate_motion::rest_fit::lame;
pub use palpate_motion::rest_fit::Design;
use palpate_motion::statics::{solve_static, static_sensitivity, StaticProblem};

use crate::camera::Camera;
use crate::surface::{correspond, Correspondence, RobustLoss};
use crate::ScanError;

/// Tukey's window, in robust scales of the residuals.
const TUKEY: f64 = 4.0;
/// Steps in ln μ below this are taken without a line search.
const SMALL_STEP: f64 = 1e-2;

/// The scanned points and what is known of their noise.
#[derive(Debug, Clone)]
pub struct ScanPoints {
    /// The points in the mesh's frame (m).
    pub points: Vec<Vector3<f64>>,
    /// Each point's standard deviation (m): along its camera ray when [`Self::camera`] is set,
    /// in every direction otherwise.
    pub sigma: Vec<f64>,
    /// The depth camera that saw them, when known.
    pub camera: Option<Camera>,
}

impl ScanPoints {
    /// The noise of point `i` along the unit `normal` (m), never below 1 nm.
    pub fn noise_along(&self, i: usize, normal: Vector3<f64>) -> f64 {
        let s = match &self.camera {
            Some(c) => c.noise_along(self.points[i], normal, self.sigma[i]),
            None => self.sigma[i],
        };
        s.max(1e-9)
    }
}

/// The object: its rest mesh, what holds it, what loads it, and how it is discretised.
#[derive(Debug, Clone)]
pub struct HangingObject<'a> {
    /// The linear rest mesh (m).
    pub mesh: &'a Mesh,
    /// Clamped nodes of the linear mesh (for P2, the edge nodes between two of them too).
    pub fixed: Vec<usize>,
    /// Density (kg/m³).
    pub density: f64,
    /// Gravity (m/s²).
    pub gravity: [f64; 3],
    /// Poisson's ratio, held.
    pub poisson: f64,
    /// P1 or P2.
    pub design: Design,
    /// Newton's force tolerance (N).
    pub tol: f64,
}

/// The object's equilibrium at one μ, on its design's nodes.
#[derive(Debug, Clone)]
pub struct Equilibrium {
    /// Shear modulus (Pa).
    pub mu: f64,
    /// Rest positions of the design's nodes (for P2 the quadratic mesh's: corners first).
    pub rest: Vec<[f64; 3]>,
    /// Deformed positions of the same nodes.
    pub positions: Vec<[f64; 3]>,
    /// ∂x/∂ln μ at fixed ν, when asked for.
    pub dln_mu: Option<Vec<[f64; 3]>>,
    /// The surface as flat triangles over these nodes, outward-wound.
    pub surface: Vec<[usize; 3]>,
}

impl HangingObject<'_> {
    fn problem(&self, mu: f64) -> StaticProblem<'_> {
        let mut p = StaticProblem::new(self.mesh, lame(mu, self.poisson), self.fixed.clone());
        p.density = self.density;
        p.gravity = self.gravity;
        p.tol = self.tol;
        p
    }

    /// The equilibrium at shear modulus `mu` (Pa), with ∂x/∂ln μ if `sensitivity`.
    pub fn equilibrium(&self, mu: f64, sensitivity: bool) -> Result<Equilibrium, ScanError> {
        let p = self.problem(mu);
        let material = lame(mu, self.poisson);
        let solve = |e: palpate_motion::MotionError| ScanError::Solve {
            what: format!(
                "{} static solve at μ = {mu:.1} Pa, ν = {}",
                self.design.name(),
                self.poisson
            ),
            source: e,
        };
        let (rest, positions, sens, surface) = match self.design {
            Design::Linear => {
                let s = solve_static(&p).map_err(solve)?;
                let d = sensitivity
                    .then(|| static_sensitivity(&p, &s))
                    .transpose()
                    .map_err(solve)?;
                (
                    self.mesh.nodes.clone(),
                    s.positions,
                    d,
                    self.mesh.boundary_triangles(),
                )
            }
            Design::Quadratic => {
                let s = solve_static_quadratic(&p).map_err(solve)?;
                let d = sensitivity
                    .then(|| quadratic_sensitivity(&p, &s))
                    .transpose()
                    .map_err(solve)?;
                let surface = split_quadratic_surface(&s.mesh, &self.mesh.boundary_triangles());
                (s.mesh.nodes.clone(), s.solution.positions, d, surface)
            }
        };
        let dln_mu = sens.map(|d| {
            d.dlambda
                .iter()
                .zip(&d.dmu)
                .map(|(dl, dm)| [0, 1, 2].map(|k| material.lambda * dl[k] + material.mu * dm[k]))
                .collect()
        });
        Ok(Equilibrium {
            mu,
            rest,
            positions,
            dln_mu,
            surface,
        })
    }
}

/// The quadratic lift of the linear `surface`, each 6-node triangle split into four flat ones
/// through its mid-edge nodes, wound as the linear triangle is.
pub fn split_quadratic_surface(q: &QuadraticMesh, surface: &[[usize; 3]]) -> Vec<[usize; 3]> {
    q.lift_triangles(surface)
        .iter()
        .flat_map(|&[a, b, c, ab, bc, ca]| [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]])
        .collect()
}

/// One scanned point against the deformed surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointResidual {
    /// Its closest place on the surface, signed distance (m) and normal.
    pub correspondence: Correspondence,
    /// Its noise along the normal (m).
    pub sigma: f64,
    /// Its robust (Tukey) weight, 0–1.
    pub weight: f64,
}

impl PointResidual {
    /// The residual over its noise, d/s.
    pub fn scaled(&self) -> f64 {
        self.correspondence.distance / self.sigma
    }
}

/// The points' residuals at `eq`, their Tukey weights from the residuals' robust scale.
/// Points without a surface within `max_distance` (m) are left out.
pub fn residuals(eq: &Equilibrium, scan: &ScanPoints, max_distance: f64) -> Vec<PointResidual> {
    let (found, _) = correspond(&eq.positions, &eq.surface, &scan.points, max_distance);
    let mut out: Vec<PointResidual> = found
        .into_iter()
        .map(|c| PointResidual {
            correspondence: c,
            sigma: scan.noise_along(c.point, c.normal),
            weight: 1.0,
        })
        .collect();
    let mut abs: Vec<f64> = out.iter().map(|r| r.scaled().abs()).collect();
    abs.sort_by(f64::total_cmp);
    // Never narrower than 4 σ: far from the fit the whole misfit is "outlying" for a window of
    // 4 σ, and the points that would pull the fit there would get no weight.
    let scale = (1.4826 * abs.get(abs.len() / 2).copied().unwrap_or(1.0)).max(1.0);
    for r in &mut out {
        r.weight = RobustLoss::Tukey(TUKEY).weight(r.scaled() / scale);
    }
    out
}

/// An iteration's weighted least-squares problem, linearised at one μ: Φ(θ) = ½ Σᵢ ωᵢ dᵢ(θ)²
/// with θ = ln μ and ωᵢ = wᵢ/sᵢ² (Tukey weight over the squared noise) held.
#[derive(Debug, Clone)]
pub struct Linearisation {
    /// The equilibrium linearised at.
    pub equilibrium: Equilibrium,
    /// The points' residuals there.
    pub residuals: Vec<PointResidual>,
    /// Φ at the equilibrium.
    pub cost: f64,
    /// dΦ/dθ = Σ ωᵢ dᵢ Jᵢ (Jᵀr).
    pub gradient: f64,
    /// Gauss–Newton's Σ ωᵢ Jᵢ² (JᵀJ).
    pub hessian: f64,
}

impl Linearisation {
    /// Each point's ωᵢ, by point index (0 for a point without a closest point).
    pub fn omegas(&self, count: usize) -> Vec<f64> {
        let mut w = vec![0.0; count];
        for r in &self.residuals {
            w[r.correspondence.point] = r.weight / (r.sigma * r.sigma);
        }
        w
    }
}

/// Solves at μ = e^θ with its sensitivity and linearises the scan cost there.
pub fn linearise(
    object: &HangingObject<'_>,
    scan: &ScanPoints,
    ln_mu: f64,
    max_distance: f64,
) -> Result<Linearisation, ScanError> {
    let eq = object.equilibrium(ln_mu.exp(), true)?;
    let res = residuals(&eq, scan, max_distance);
    let dx = eq.dln_mu.as_ref().expect("the sensitivity was asked for");
    let (mut cost, mut gradient, mut hessian) = (0.0, 0.0, 0.0);
    for r in &res {
        let c = &r.correspondence;
        let j: f64 = c
            .jacobian()
            .iter()
            .map(|(n, d)| d.dot(&Vector3::from(dx[*n])))
            .sum();
        let omega = r.weight / (r.sigma * r.sigma);
        cost += 0.5 * omega * c.distance * c.distance;
        gradient += omega * c.distance * j;
        hessian += omega * j * j;
    }
    Ok(Linearisation {
        equilibrium: eq,
        residuals: res,
        cost,
        gradient,
        hessian,
    })
}

/// Φ(θ) = ½ Σᵢ ωᵢ dᵢ(θ)² with the weights `omegas` (by point index) held and the closest points
/// found again at μ = e^θ; a weighted point with no surface within `max_distance` counts as at
/// that distance.
pub fn weighted_cost(
    object: &HangingObject<'_>,
    scan: &ScanPoints,
    omegas: &[f64],
    ln_mu: f64,
    max_distance: f64,
) -> Result<f64, ScanError> {
    let eq = object.equilibrium(ln_mu.exp(), false)?;
    Ok(cost_at(&eq, scan, omegas, max_distance))
}

fn cost_at(eq: &Equilibrium, scan: &ScanPoints, omegas: &[f64], max_distance: f64) -> f64 {
    let (found, _) = correspond(&eq.positions, &eq.surface, &scan.points, max_distance);
    let mut d2: Vec<f64> = vec![max_distance * max_distance; scan.points.len()];
    for c in &found {
        d2[c.point] = c.distance * c.distance;
    }
    0.5 * omegas.iter().zip(&d2).map(|(w, d)| w * d).sum::<f64>()
}

/// How the fit searches.
#[derive(Debug, Clone)]
pub struct FitSettings {
    /// Trial shear moduli (Pa); the fit starts from the one nearest the scan.
    pub starts: Vec<f64>,
    /// Closest points farther than this are no correspondence (m): beyond the start's misfit.
    pub max_distance: f64,
    /// Gauss–Newton iterations at most.
    pub max_iter: usize,
}

/// A fitted shear modulus.
#[derive(Debug, Clone)]
pub struct ScanFit {
    /// μ (Pa).
    pub mu: f64,
    /// Young's modulus 2μ(1 + ν) (Pa).
    pub young_modulus: f64,
    /// Gauss–Newton iterations.
    pub iterations: usize,
    /// The last linearisation (at μ): the equilibrium and each point's residual and weight.
    pub at_fit: Linearisation,
}

/// The median distance of the points to the surface (m), a point without a closest point
/// counting `max_distance`: how well the better half of the scan fits, whatever the other half
/// holds (background, or a part the start bends wrong).
fn median_distance(eq: &Equilibrium, scan: &ScanPoints, max_distance: f64) -> f64 {
    let (found, _) = correspond(&eq.positions, &eq.surface, &scan.points, max_distance);
    let mut d = vec![max_distance; scan.points.len()];
    for c in &found {
        d[c.point] = c.distance.abs();
    }
    let mid = d.len() / 2;
    d.select_nth_unstable_by(mid, f64::total_cmp);
    d[mid]
}

/// Fits μ of `object` to `scan`.
pub fn fit_scan(
    object: &HangingObject<'_>,
    scan: &ScanPoints,
    settings: &FitSettings,
) -> Result<ScanFit, ScanError> {
    if scan.points.len() != scan.sigma.len() {
        return Err(ScanError::Invalid(format!(
            "scan: {} points but {} noise values, expected one per point",
            scan.points.len(),
            scan.sigma.len()
        )));
    }
    let mut best = (f64::INFINITY, None);
    for &mu in &settings.starts {
        let eq = object.equilibrium(mu, false)?;
        let cost = median_distance(&eq, scan, settings.max_distance);
        log::info!(
            "{} start E {:.1} kPa: median distance {:.3} mm",
            object.design.name(),
            young(mu, object.poisson) / 1e3,
            1e3 * cost
        );
        if cost < best.0 {
            best = (cost, Some(mu.ln()));
        }
    }
    let Some(mut theta) = best.1 else {
        return Err(ScanError::Invalid(
            "scan fit: no trial modulus to start from".into(),
        ));
    };
    let mut lin = linearise(object, scan, theta, settings.max_distance)?;
    for it in 1..=settings.max_iter {
        if lin.residuals.len() < 10 || !(lin.hessian.is_finite() && lin.hessian > 0.0) {
            return Err(ScanError::Invalid(format!(
                "scan fit, iteration {it}: {} points near the surface, JᵀJ = {:e} at E = {:.1} kPa: \
                 the scan does not see the object move with its modulus",
                lin.residuals.len(),
                lin.hessian,
                young(theta.exp(), object.poisson) / 1e3
            )));
        }
        let omegas = lin.omegas(scan.points.len());
        let mut step = (-lin.gradient / lin.hessian).clamp(-0.5, 0.5);
        // A step under 1 % is taken as it is: Gauss–Newton converges there, and what it gains
        // (½ JᵀJ step²) falls below the jumps of the cost where closest points switch between
        // triangles of different normals. With every step line-searched, the strip's P1 fits
        // stopped 0.04–0.3 % short of where plain Gauss–Newton settles, no halving of their
        // last step lowering the cost.
        let mut accepted = step.abs() < SMALL_STEP;
        for _ in 0..if accepted { 0 } else { 10 } {
            let trial = weighted_cost(object, scan, &omegas, theta + step, settings.max_distance)?;
            if trial <= lin.cost {
                accepted = true;
                break;
            }
            step *= 0.5;
        }
        if !accepted {
            log::warn!(
                "scan fit, iteration {it}: no step down to {step:+.1e} in ln μ lowers the cost; stopped at E {:.1} kPa",
                young(theta.exp(), object.poisson) / 1e3
            );
            return Ok(finish(object, theta, it, lin));
        }
        theta += step;
        lin = linearise(object, scan, theta, settings.max_distance)?;
        log::info!(
            "{} iteration {it}: E {:.1} kPa, {} points, step {step:+.2e}",
            object.design.name(),
            young(theta.exp(), object.poisson) / 1e3,
            lin.residuals.len()
        );
        // 1e-4 in ln μ: a hundredth of a per cent, below what the correspondences' switching
        // between triangles lets the steps settle to.
        if step.abs() < 1e-4 {
            return Ok(finish(object, theta, it, lin));
        }
    }
    Err(ScanError::Invalid(format!(
        "scan fit: Gauss–Newton did not settle in {} iterations (E {:.1} kPa)",
        settings.max_iter,
        young(theta.exp(), object.poisson) / 1e3
    )))
}

fn finish(
    object: &HangingObject<'_>,
    theta: f64,
    iterations: usize,
    at_fit: Linearisation,
) -> ScanFit {
    ScanFit {
        mu: theta.exp(),
        young_modulus: young(theta.exp(), object.poisson),
        iterations,
        at_fit,
    }
}

/// Young's modulus of shear modulus `mu` at Poisson's ratio `nu`.
pub fn young(mu: f64, nu: f64) -> f64 {
    2.0 * mu * (1.0 + nu)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Intrinsics, Pose};
    use crate::render::render_depth;
    use palpate_fem::mesh::boxmesh::box_mesh;

    const SIZE: [f64; 3] = [0.08, 0.02, 0.01];

    fn strip(mesh: &Mesh, design: Design) -> HangingObject<'_> {
        HangingObject {
            mesh,
            fixed: (0..mesh.nodes.len())
                .filter(|&n| mesh.nodes[n][0] < 1e-9)
                .collect(),
            density: 1100.0,
            gravity: [0.0, 0.0, -9.81],
            poisson: 0.45,
            design,
            tol: 1e-9,
        }
    }

    fn camera() -> Camera {
        Camera {
            intrinsics: Intrinsics {
                fx: 300.0,
                fy: 300.0,
                cx: 79.5,
                cy: 59.5,
            },
            pose: Pose::looking_at(
                Vector3::new(0.05, -0.16, 0.08),
                Vector3::new(0.04, 0.01, -0.01),
                Vector3::new(0.0, 0.0, 1.0),
            ),
        }
    }

    /// A noiseless depth image of the strip at E = 300 kPa on its own design, back-projected,
    /// σ 0.2 mm along each ray.
    fn scan_of(object: &HangingObject<'_>) -> ScanPoints {
        let eq = object.equilibrium(300e3 / 2.9, false).unwrap();
        let cam = camera();
        let image = render_depth(&cam, 160, 120, &eq.positions, &eq.surface);
        let points = cam.points(&image);
        ScanPoints {
            sigma: vec![2e-4; points.len()],
            points,
            camera: Some(cam),
        }
    }

    /// Jᵀr of the analytic sensitivity against central differences of the iteration's cost
    /// (weights held, closest points found again), at a modulus 40 % off the scan's, on P1 and
    /// P2. h = 1e-4 in ln μ with solves to 1e-9 N: the differences' truncation error is
    /// ~h² ≈ 1e-8 relative; points whose closest point crosses an edge between ±h (where the
    /// distance has a kink) leave the rest. Measured: 3.2e-4 relative on P1, 7.1e-6 on P2;
    /// asserted 1e-3. Dropping the λ term of ∂x/∂ln μ makes Jᵀr 30 % low on P1.
    #[test]
    fn the_gradient_is_the_derivative_of_the_cost() {
        let mesh = box_mesh(SIZE, [8, 2, 2]);
        for design in [Design::Linear, Design::Quadratic] {
            let object = strip(&mesh, design);
            let scan = scan_of(&object);
            assert!(scan.points.len() > 1000, "{} points", scan.points.len());
            let theta = (1.4 * 300e3 / 2.9f64).ln();
            let lin = linearise(&object, &scan, theta, 2e-2).unwrap();
            let omegas = lin.omegas(scan.points.len());
            let h = 1e-4;
            let at = |t: f64| weighted_cost(&object, &scan, &omegas, t, 2e-2).unwrap();
            let fd = (at(theta + h) - at(theta - h)) / (2.0 * h);
            assert!(
                (fd - lin.gradient).abs() < 1e-3 * fd.abs(),
                "{}: Jᵀr {} against finite differences {fd}",
                design.name(),
                lin.gradient
            );
            // The cost at θ is the linearisation's own.
            assert!((at(theta) - lin.cost).abs() <= 1e-9 * lin.cost);
        }
    }
}
