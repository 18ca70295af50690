//! A material's shear modulus from scans of the object at rest under its weight, clamped, held
//! in a moved grip (twisted, bent) or loaded: μ (at a held Poisson's ratio) fitted by
//! Gauss–Newton in ln μ to the scanned points' signed distances to the deformed surface
//! ([`crate::surface`]), every state's scan at once, through the Neo-Hookean static solver on linear
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
//! - **Two materials**: with [`LoadedObject::regions`] each element belongs to one of two parts,
//!   each with its own μ (same ν); the sensitivity to each part's ln μ is then a forward
//!   difference (h = 1e-3) of the equilibrium, the solver's analytic one being for a uniform
//!   material ([`crate::regions`] searches for such a split).
//! - **Uncertainty**: the Gauss–Newton covariance (JᵀΩJ)⁻¹ scaled by the weighted residual's
//!   variance Σ wᵢ rᵢ² / (n − k), n the points with weight, k the moduli fitted.
//! - **Steps**: the Gauss–Newton step, at most 0.5 in ln μ (per modulus); one over 1 % is halved (up to ten
//!   times) until it does not raise the iteration's weighted cost. Done when the step is below
//!   1e-4 in ln μ.

use nalgebra::{DMatrix, DVector, Vector3};
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
/// The forward-difference step in ln μ of a part's modulus: the equilibrium's truncation error
/// is ~h/2 of its curvature in ln μ (a twentieth of a per cent of the Jacobian), far above the
/// solver's tolerance over h.
const REGION_STEP: f64 = 1e-3;

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

/// The object in one state: its rest mesh, what holds it (clamped nodes, a grip moved to a
/// prescribed place), what loads it (its weight, dead loads on nodes), and how it is
/// discretised — any [`StaticProblem`] of one or two materials at a held Poisson's ratio.
#[derive(Debug, Clone)]
pub struct LoadedObject<'a> {
    /// The linear rest mesh (m).
    pub mesh: &'a Mesh,
    /// Fixed nodes of the linear mesh (for P2, the edge nodes between two of them too).
    pub fixed: Vec<usize>,
    /// Each fixed node's displacement (m, same order as `fixed`: a held grip's rigid motion),
    /// or empty: all held at rest.
    pub fixed_displacement: Vec<[f64; 3]>,
    /// Dead loads on nodes of the linear mesh (node, force in N).
    pub forces: Vec<(usize, [f64; 3])>,
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
    /// Load increments of the static solve (≥ 1; a large twist needs more).
    pub load_steps: usize,
    /// Each element's part, 0 or 1, each part with its own μ; empty: one material.
    pub regions: Vec<usize>,
    /// Added to every equilibrium's positions, per node of the design (m); empty: nothing. A
    /// correction held through a fit: the discretisation error of this mesh measured against
    /// the mesh refined once (the approximation-error approach of the static diagnosis).
    pub offset: Vec<[f64; 3]>,
}

/// The object's equilibrium at its moduli, on its design's nodes.
#[derive(Debug, Clone)]
pub struct Equilibrium {
    /// Shear modulus of each part (Pa): one for a uniform material.
    pub mu: Vec<f64>,
    /// Rest positions of the design's nodes (for P2 the quadratic mesh's: corners first).
    pub rest: Vec<[f64; 3]>,
    /// Deformed positions of the same nodes.
    pub positions: Vec<[f64; 3]>,
    /// ∂x/∂ln μₖ at fixed ν, one per part, when asked for (empty otherwise).
    pub dln_mu: Vec<Vec<[f64; 3]>>,
    /// The surface as flat triangles over these nodes, outward-wound.
    pub surface: Vec<[usize; 3]>,
}

impl<'a> LoadedObject<'a> {
    /// The object hanging under its weight from its `fixed` nodes, one material, no dead load,
    /// ten load increments.
    pub fn hanging(
        mesh: &'a Mesh,
        fixed: Vec<usize>,
        density: f64,
        gravity: [f64; 3],
        poisson: f64,
        design: Design,
        tol: f64,
    ) -> Self {
        Self {
            mesh,
            fixed,
            fixed_displacement: Vec::new(),
            forces: Vec::new(),
            density,
            gravity,
            poisson,
            design,
            tol,
            load_steps: 10,
            regions: Vec::new(),
            offset: Vec::new(),
        }
    }
}

impl LoadedObject<'_> {
    /// The moduli fitted: 1, or 2 with [`Self::regions`].
    pub fn materials(&self) -> usize {
        if self.regions.is_empty() {
            1
        } else {
            2
        }
    }

    /// The same object on `fine`, the mesh refined once (`refine_with_midpoints`, whose
    /// midpoint of each coarse edge is `mid`): a midpoint of two fixed nodes is fixed, moved by
    /// the mean of their moves (a grip's motion is rigid, so exactly its own); the dead loads
    /// stay on their nodes (coarse nodes keep their indices); element e's part is its eight
    /// children's (8e..8e + 8); no offset.
    pub fn refined<'b>(
        &self,
        fine: &'b Mesh,
        mid: &std::collections::HashMap<(usize, usize), usize>,
    ) -> LoadedObject<'b> {
        let at: std::collections::HashMap<usize, usize> = self
            .fixed
            .iter()
            .enumerate()
            .map(|(k, &n)| (n, k))
            .collect();
        let mut fixed = self.fixed.clone();
        let mut moved = self.fixed_displacement.clone();
        let mut edges: Vec<(&(usize, usize), &usize)> = mid.iter().collect();
        edges.sort_unstable();
        for (&(a, b), &m) in edges {
            if let (Some(&ka), Some(&kb)) = (at.get(&a), at.get(&b)) {
                fixed.push(m);
                if !moved.is_empty() {
                    let (da, db) = (moved[ka], moved[kb]);
                    moved.push([0, 1, 2].map(|k| 0.5 * (da[k] + db[k])));
                }
            }
        }
        LoadedObject {
            mesh: fine,
            fixed,
            fixed_displacement: moved,
            forces: self.forces.clone(),
            density: self.density,
            gravity: self.gravity,
            poisson: self.poisson,
            design: self.design,
            tol: self.tol,
            load_steps: self.load_steps,
            regions: self
                .regions
                .iter()
                .flat_map(|&r| std::iter::repeat_n(r, 8))
                .collect(),
            offset: Vec::new(),
        }
    }

    fn problem(&self, mu: &[f64]) -> StaticProblem<'_> {
        let mut p = StaticProblem::new(self.mesh, lame(mu[0], self.poisson), self.fixed.clone());
        if !self.regions.is_empty() {
            p.material = self
                .regions
                .iter()
                .map(|&r| lame(mu[r], self.poisson))
                .collect();
        }
        p.fixed_displacement = self.fixed_displacement.clone();
        p.forces = self.forces.clone();
        p.density = self.density;
        p.gravity = self.gravity;
        p.tol = self.tol;
        p.load_steps = self.load_steps.max(1);
        p
    }

    /// The equilibrium at a uniform shear modulus `mu` (Pa, every part), with ∂x/∂ln μ of each
    /// part if `sensitivity`.
    pub fn equilibrium(&self, mu: f64, sensitivity: bool) -> Result<Equilibrium, ScanError> {
        self.equilibrium_at(&vec![mu; self.materials()], sensitivity)
    }

    /// The equilibrium at each part's shear modulus `mu` (Pa), with ∂x/∂ln μₖ if
    /// `sensitivity`: the solver's analytic one for one material, a forward difference per
    /// part for two.
    pub fn equilibrium_at(&self, mu: &[f64], sensitivity: bool) -> Result<Equilibrium, ScanError> {
        if mu.len() != self.materials() {
            return Err(ScanError::Invalid(format!(
                "{} moduli given for an object of {} material(s)",
                mu.len(),
                self.materials()
            )));
        }
        let uniform = self.materials() == 1;
        let (rest, mut positions, surface, analytic) = self.solve(mu, sensitivity && uniform)?;
        let dln_mu = if !sensitivity {
            Vec::new()
        } else if let Some(d) = analytic {
            vec![d]
        } else {
            (0..mu.len())
                .map(|k| {
                    let mut moved = mu.to_vec();
                    moved[k] *= REGION_STEP.exp();
                    let (_, x, _, _) = self.solve(&moved, false)?;
                    Ok(x.iter()
                        .zip(&positions)
                        .map(|(a, b)| [0, 1, 2].map(|i| (a[i] - b[i]) / REGION_STEP))
                        .collect())
                })
                .collect::<Result<_, ScanError>>()?
        };
        if !self.offset.is_empty() {
            if self.offset.len() != positions.len() {
                return Err(ScanError::Invalid(format!(
                    "an offset of {} nodes for an equilibrium of {}",
                    self.offset.len(),
                    positions.len()
                )));
            }
            for (x, o) in positions.iter_mut().zip(&self.offset) {
                *x = [0, 1, 2].map(|k| x[k] + o[k]);
            }
        }
        Ok(Equilibrium {
            mu: mu.to_vec(),
            rest,
            positions,
            dln_mu,
            surface,
        })
    }

    /// Rest and deformed nodes, the surface, and (uniform only) the analytic ∂x/∂ln μ.
    #[allow(clippy::type_complexity)]
    fn solve(
        &self,
        mu: &[f64],
        sensitivity: bool,
    ) -> Result<
        (
            Vec<[f64; 3]>,
            Vec<[f64; 3]>,
            Vec<[usize; 3]>,
            Option<Vec<[f64; 3]>>,
        ),
        ScanError,
    > {
        let p = self.problem(mu);
        let material = lame(mu[0], self.poisson);
        let solve = |e: palpate_motion::MotionError| ScanError::Solve {
            what: format!(
                "{} static solve at μ = {} Pa, ν = {}",
                self.design.name(),
                mu.iter()
                    .map(|m| format!("{m:.1}"))
                    .collect::<Vec<_>>()
                    .join(" / "),
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
        Ok((rest, positions, surface, dln_mu))
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

/// An iteration's weighted least-squares problem for one scan, linearised at one set of
/// moduli: Φ(θ) = ½ Σᵢ ωᵢ dᵢ(θ)² with θ = ln μ (one per part) and ωᵢ = wᵢ/sᵢ² (Tukey weight
/// over the squared noise) held.
#[derive(Debug, Clone)]
pub struct Linearisation {
    /// The equilibrium linearised at.
    pub equilibrium: Equilibrium,
    /// The points' residuals there.
    pub residuals: Vec<PointResidual>,
    /// Φ at the equilibrium.
    pub cost: f64,
    /// dΦ/dθₖ = Σ ωᵢ dᵢ Jᵢₖ (Jᵀr), one per part.
    pub gradient: Vec<f64>,
    /// Gauss–Newton's Σ ωᵢ Jᵢₖ Jᵢₗ (JᵀJ), k × k by rows.
    pub hessian: Vec<f64>,
}

/// Each state's ωᵢ at its linearisation ([`Linearisation::omegas`]): the weights a Gauss–Newton
/// step's line search holds while it tries shorter steps.
pub fn state_omegas(lins: &[Linearisation], states: &[ScanState<'_>]) -> Vec<Vec<f64>> {
    lins.iter()
        .zip(states)
        .map(|(l, s)| l.omegas(s.scan.points.len()))
        .collect()
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

    /// Σ wᵢ (dᵢ/sᵢ)² over the points, and how many have a weight.
    pub fn weighted_chi2(&self) -> (f64, usize) {
        let chi2 = self
            .residuals
            .iter()
            .map(|r| r.weight * r.scaled() * r.scaled())
            .sum();
        let used = self.residuals.iter().filter(|r| r.weight > 0.0).count();
        (chi2, used)
    }

    /// The RMS signed distance (m) of the points with a weight.
    pub fn rms_distance(&self) -> f64 {
        let d: Vec<f64> = self
            .residuals
            .iter()
            .filter(|r| r.weight > 0.0)
            .map(|r| r.correspondence.distance)
            .collect();
        (d.iter().map(|v| v * v).sum::<f64>() / d.len().max(1) as f64).sqrt()
    }
}

/// Solves at μ = e^θ (one θ per part) with its sensitivity and linearises the scan cost there.
pub fn linearise(
    object: &LoadedObject<'_>,
    scan: &ScanPoints,
    ln_mu: &[f64],
    max_distance: f64,
) -> Result<Linearisation, ScanError> {
    let mu: Vec<f64> = ln_mu.iter().map(|t| t.exp()).collect();
    let eq = object.equilibrium_at(&mu, true)?;
    let res = residuals(&eq, scan, max_distance);
    let k = mu.len();
    let (mut cost, mut gradient, mut hessian) = (0.0, vec![0.0; k], vec![0.0; k * k]);
    let mut j = vec![0.0; k];
    for r in &res {
        let c = &r.correspondence;
        for (jk, dx) in j.iter_mut().zip(&eq.dln_mu) {
            *jk = c
                .jacobian()
                .iter()
                .map(|(n, d)| d.dot(&Vector3::from(dx[*n])))
                .sum();
        }
        let omega = r.weight / (r.sigma * r.sigma);
        cost += 0.5 * omega * c.distance * c.distance;
        for a in 0..k {
            gradient[a] += omega * c.distance * j[a];
            for b in 0..k {
                hessian[a * k + b] += omega * j[a] * j[b];
            }
        }
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
    object: &LoadedObject<'_>,
    scan: &ScanPoints,
    omegas: &[f64],
    ln_mu: &[f64],
    max_distance: f64,
) -> Result<f64, ScanError> {
    let mu: Vec<f64> = ln_mu.iter().map(|t| t.exp()).collect();
    let eq = object.equilibrium_at(&mu, false)?;
    Ok(cost_at(&eq, scan, omegas, max_distance))
}

/// Φ of the equilibrium `eq` against `scan` with the weights `omegas` held ([`weighted_cost`]).
pub fn cost_at(eq: &Equilibrium, scan: &ScanPoints, omegas: &[f64], max_distance: f64) -> f64 {
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
    /// Trial shear moduli (Pa), each for every part; the fit starts from the one nearest the
    /// scans (a single trial is taken without solving for it).
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

/// One observed state: the object as it was held and loaded, and its scan.
#[derive(Debug, Clone)]
pub struct ScanState<'a> {
    /// Its name in reports.
    pub name: String,
    /// The object in that state.
    pub object: LoadedObject<'a>,
    /// What was scanned of it.
    pub scan: ScanPoints,
}

/// Moduli fitted to every state's scan at once.
#[derive(Debug, Clone)]
pub struct JointFit {
    /// μ of each part (Pa).
    pub mu: Vec<f64>,
    /// Poisson's ratio, held.
    pub poisson: f64,
    /// Covariance of ln μ (k × k by rows): (JᵀΩJ)⁻¹ × Σ wᵢrᵢ² / (n − k).
    pub covariance: Vec<f64>,
    /// Gauss–Newton iterations.
    pub iterations: usize,
    /// Each state's last linearisation (at μ), in the states' order.
    pub states: Vec<Linearisation>,
}

impl JointFit {
    /// Young's modulus 2μ(1 + ν) of part `k` (Pa).
    pub fn young_modulus(&self, k: usize) -> f64 {
        young(self.mu[k], self.poisson)
    }

    /// The standard deviation of ln μₖ (relative σ of μₖ and Eₖ).
    pub fn sigma_ln_mu(&self, k: usize) -> f64 {
        let n = self.mu.len();
        self.covariance[k * n + k].max(0.0).sqrt()
    }

    /// Σ wᵢ (dᵢ/sᵢ)² over all states, and the points with a weight.
    pub fn weighted_chi2(&self) -> (f64, usize) {
        self.states
            .iter()
            .map(Linearisation::weighted_chi2)
            .fold((0.0, 0), |(a, b), (c, d)| (a + c, b + d))
    }
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

/// Fits μ of `object` to `scan`: [`fit_states`] on one state.
pub fn fit_scan(
    object: &LoadedObject<'_>,
    scan: &ScanPoints,
    settings: &FitSettings,
) -> Result<ScanFit, ScanError> {
    let state = ScanState {
        name: "scan".into(),
        object: object.clone(),
        scan: scan.clone(),
    };
    let mut fit = fit_states(std::slice::from_ref(&state), settings)?;
    Ok(ScanFit {
        mu: fit.mu[0],
        young_modulus: fit.young_modulus(0),
        iterations: fit.iterations,
        at_fit: fit.states.remove(0),
    })
}

fn linearise_all(
    states: &[ScanState<'_>],
    theta: &[f64],
    max_distance: f64,
) -> Result<Vec<Linearisation>, ScanError> {
    states
        .iter()
        .map(|s| linearise(&s.object, &s.scan, theta, max_distance))
        .collect()
}

fn e_kpa(theta: &[f64], poisson: f64) -> String {
    theta
        .iter()
        .map(|t| format!("{:.1}", young(t.exp(), poisson) / 1e3))
        .collect::<Vec<_>>()
        .join(" / ")
}

/// Fits the moduli of the states' object (one, or two with [`LoadedObject::regions`]; every
/// state's object the same but for how it is held and loaded) to all their scans at once.
pub fn fit_states(states: &[ScanState<'_>], settings: &FitSettings) -> Result<JointFit, ScanError> {
    let k = check_states(states)?;
    let first = &states[0];
    let poisson = first.object.poisson;
    let design = first.object.design.name();
    let start = if let [mu] = settings.starts[..] {
        Some(mu.ln())
    } else {
        let mut best = (f64::INFINITY, None);
        for &mu in &settings.starts {
            let mut cost = 0.0;
            for s in states {
                // A trial far too soft may find no equilibrium (elements inverted): it is no
                // start, not the end of the fit.
                match s.object.equilibrium(mu, false) {
                    Ok(eq) => cost += median_distance(&eq, &s.scan, settings.max_distance),
                    Err(e) => {
                        log::info!(
                            "{design} start E {:.1} kPa, state {:?}: {e}",
                            young(mu, poisson) / 1e3,
                            s.name
                        );
                        cost = f64::INFINITY;
                        break;
                    }
                }
            }
            log::info!(
                "{design} start E {:.1} kPa: median distance {:.3} mm (summed over {} state(s))",
                young(mu, poisson) / 1e3,
                1e3 * cost,
                states.len()
            );
            if cost < best.0 {
                best = (cost, Some(mu.ln()));
            }
        }
        best.1
    };
    let Some(start) = start else {
        return Err(ScanError::Invalid(
            "scan fit: no trial modulus to start from".into(),
        ));
    };
    fit_states_from(states, settings, &vec![start; k])
}

/// Fits the moduli of the states' object from ln μ = `theta` (one per part): [`fit_states`]
/// after its start is chosen — a refit from where an earlier fit of the same parts ended (the
/// scans corrected by a nuisance, a split's two moduli).
pub fn fit_states_from(
    states: &[ScanState<'_>],
    settings: &FitSettings,
    theta: &[f64],
) -> Result<JointFit, ScanError> {
    let k = check_states(states)?;
    let poisson = states[0].object.poisson;
    let design = states[0].object.design.name();
    if theta.len() != k || theta.iter().any(|t| !t.is_finite()) {
        return Err(ScanError::Invalid(format!(
            "scan fit: start ln μ {theta:?}, expected {k} finite value(s)"
        )));
    }
    let mut theta = theta.to_vec();
    let mut lins = linearise_all(states, &theta, settings.max_distance)?;
    for it in 1..=settings.max_iter {
        let (g, h, points) = sums(&lins, k);
        let step = DMatrix::from_row_slice(k, k, &h)
            .cholesky()
            .filter(|_| points >= 10 && h.iter().all(|v| v.is_finite()))
            .map(|c| -c.solve(&DVector::from_column_slice(&g)));
        let Some(mut step) = step else {
            return Err(ScanError::Invalid(format!(
                "scan fit, iteration {it}: {points} points near the surface, JᵀJ = {h:?} at E = {} kPa: \
                 the scans do not see the object move with its modulus",
                e_kpa(&theta, poisson)
            )));
        };
        let largest = step.amax();
        if largest > 0.5 {
            step *= 0.5 / largest;
        }
        let omegas = state_omegas(&lins, states);
        let cost: f64 = lins.iter().map(|l| l.cost).sum();
        // A step under 1 % is taken as it is: Gauss–Newton converges there, and what it gains
        // (½ JᵀJ step²) falls below the jumps of the cost where closest points switch between
        // triangles of different normals. With every step line-searched, the strip's P1 fits
        // stopped 0.04–0.3 % short of where plain Gauss–Newton settles, no halving of their
        // last step lowering the cost.
        let mut accepted = step.amax() < SMALL_STEP;
        for _ in 0..if accepted { 0 } else { 10 } {
            let trial_theta: Vec<f64> = theta.iter().zip(step.iter()).map(|(t, s)| t + s).collect();
            let mut trial = 0.0;
            for (s, w) in states.iter().zip(&omegas) {
                trial += weighted_cost(&s.object, &s.scan, w, &trial_theta, settings.max_distance)?;
            }
            if trial <= cost {
                accepted = true;
                break;
            }
            step *= 0.5;
        }
        if !accepted {
            log::warn!(
                "scan fit, iteration {it}: no step down to {:.1e} in ln μ lowers the cost; stopped at E {} kPa",
                step.amax(),
                e_kpa(&theta, poisson)
            );
            return Ok(finish(theta, poisson, it, lins));
        }
        for (t, s) in theta.iter_mut().zip(step.iter()) {
            *t += s;
        }
        lins = linearise_all(states, &theta, settings.max_distance)?;
        log::info!(
            "{design} iteration {it}: E {} kPa, {} points, step {:.2e}",
            e_kpa(&theta, poisson),
            lins.iter().map(|l| l.residuals.len()).sum::<usize>(),
            step.amax()
        );
        // 1e-4 in ln μ: a hundredth of a per cent, below what the correspondences' switching
        // between triangles lets the steps settle to.
        if step.amax() < 1e-4 {
            return Ok(finish(theta, poisson, it, lins));
        }
    }
    Err(ScanError::Invalid(format!(
        "scan fit: Gauss–Newton did not settle in {} iterations (E {} kPa)",
        settings.max_iter,
        e_kpa(&theta, poisson)
    )))
}

/// The moduli the states fit (1 or 2); refused when there is no state, a scan's noise values are
/// not one per point, or the states' objects differ in their parts.
fn check_states(states: &[ScanState<'_>]) -> Result<usize, ScanError> {
    let Some(first) = states.first() else {
        return Err(ScanError::Invalid("scan fit: no state to fit".into()));
    };
    let k = first.object.materials();
    for s in states {
        if s.scan.points.len() != s.scan.sigma.len() {
            return Err(ScanError::Invalid(format!(
                "state {:?}: {} points but {} noise values, expected one per point",
                s.name,
                s.scan.points.len(),
                s.scan.sigma.len()
            )));
        }
        if s.object.materials() != k {
            return Err(ScanError::Invalid(format!(
                "state {:?}: {} material(s), the first state has {k}",
                s.name,
                s.object.materials()
            )));
        }
    }
    Ok(k)
}

/// The states' gradients and Gauss–Newton matrices summed, and the points near the surface.
fn sums(lins: &[Linearisation], k: usize) -> (Vec<f64>, Vec<f64>, usize) {
    let mut g = vec![0.0; k];
    let mut h = vec![0.0; k * k];
    let mut points = 0;
    for l in lins {
        g.iter_mut().zip(&l.gradient).for_each(|(a, b)| *a += b);
        h.iter_mut().zip(&l.hessian).for_each(|(a, b)| *a += b);
        points += l.residuals.len();
    }
    (g, h, points)
}

fn finish(
    theta: Vec<f64>,
    poisson: f64,
    iterations: usize,
    states: Vec<Linearisation>,
) -> JointFit {
    let k = theta.len();
    let (_, h, _) = sums(&states, k);
    let (chi2, used) = states
        .iter()
        .map(Linearisation::weighted_chi2)
        .fold((0.0, 0), |(a, b), (c, d)| (a + c, b + d));
    let scale = chi2 / (used.saturating_sub(k)).max(1) as f64;
    let covariance = DMatrix::from_row_slice(k, k, &h)
        .try_inverse()
        .map(|m| (m * scale).transpose().as_slice().to_vec())
        .unwrap_or_else(|| vec![f64::INFINITY; k * k]);
    JointFit {
        mu: theta.iter().map(|t| t.exp()).collect(),
        poisson,
        covariance,
        iterations,
        states,
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

    fn strip(mesh: &Mesh, design: Design) -> LoadedObject<'_> {
        LoadedObject::hanging(
            mesh,
            (0..mesh.nodes.len())
                .filter(|&n| mesh.nodes[n][0] < 1e-9)
                .collect(),
            1100.0,
            [0.0, 0.0, -9.81],
            0.45,
            design,
            1e-9,
        )
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
    fn scan_of(object: &LoadedObject<'_>) -> ScanPoints {
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
            let lin = linearise(&object, &scan, &[theta], 2e-2).unwrap();
            let omegas = lin.omegas(scan.points.len());
            let h = 1e-4;
            let at = |t: f64| weighted_cost(&object, &scan, &omegas, &[t], 2e-2).unwrap();
            let fd = (at(theta + h) - at(theta - h)) / (2.0 * h);
            assert!(
                (fd - lin.gradient[0]).abs() < 1e-3 * fd.abs(),
                "{}: Jᵀr {} against finite differences {fd}",
                design.name(),
                lin.gradient[0]
            );
            // The cost at θ is the linearisation's own.
            assert!((at(theta) - lin.cost).abs() <= 1e-9 * lin.cost);
        }
    }
}
