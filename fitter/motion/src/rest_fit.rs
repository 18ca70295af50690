//! The shear modulus from rest states: a motion dataset's settled end (the markers' mean over its
//! last stretch, where the ring-down has died out) is a quasi-static equilibrium under gravity,
//! the dead loads and the clamps' final poses, so μ at a fixed Poisson's ratio can be fitted by
//! Gauss–Newton in ln μ through the quasi-static solver on linear ([`super::statics`]) or
//! quadratic ([`super::quadratic_statics`]) tetrahedra — the same data seen through two
//! discretisations, which is what a mesh-convergence study of the fitted modulus needs.
//!
//! The markers are taken as the dataset embeds them (element and barycentric coordinates on the
//! linear mesh, extrapolated a little outside it for stand-offs) with no registration or offset
//! fitted at rest: what is left is reported as the RMS.

use super::dataset::MotionDataset;
use super::hyperelastic::HyperParams;
use super::model::Model;
use super::quadratic_statics::{quadratic_sensitivity, solve_static_quadratic, value_at};
use super::statics::{solve_static, static_sensitivity, StaticProblem};
use super::MotionError;
use nalgebra::{Matrix3, Vector3};
use palpate_fem::mesh::Mesh;
use rayon::prelude::*;

/// The element design a rest state is solved with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Design {
    /// Linear 4-node tetrahedra (P1).
    Linear,
    /// Quadratic 10-node tetrahedra on the same corners (P2).
    Quadratic,
}

impl Design {
    /// "P1" or "P2".
    pub fn name(self) -> &'static str {
        match self {
            Self::Linear => "P1",
            Self::Quadratic => "P2",
        }
    }
}

/// How a marker that sits off the body (on a stand-off post, up to centimetres out) follows it.
/// The dataset embeds every marker by barycentric coordinates in one element, extrapolated
/// outside it for a stand-off: an affine map on linear elements, a quadratic one on quadratic
/// elements, whose curvature an extrapolation several millimetres out amplifies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum StandOff {
    /// The element's own interpolation, extrapolated: x_f + F·d on linear elements (the post
    /// stretches and shears with the element).
    #[default]
    Extrapolated,
    /// A rigid post: the marker is at x_f + R·d, where x_f is the post's foot (the marker's
    /// barycentric coordinates clamped into its element), d the foot-to-marker vector at rest and
    /// R the rotation of the deformation gradient at the foot (F = R U, the polar decomposition).
    /// A marker inside its element is its own foot.
    RigidPost,
}

impl StandOff {
    /// "extrapolated" or "rigid-post".
    pub fn name(self) -> &'static str {
        match self {
            Self::Extrapolated => "extrapolated",
            Self::RigidPost => "rigid-post",
        }
    }
}

/// One run's rest state: the static problem's data and the markers' settled positions.
#[derive(Debug, Clone)]
pub struct RestState {
    /// The linear mesh.
    pub mesh: Mesh,
    /// Density (kg/m³) and gravity (m/s²).
    pub density: f64,
    /// Gravity (m/s²).
    pub gravity: [f64; 3],
    /// Clamped nodes and their displacement at the end of the capture.
    pub fixed: Vec<usize>,
    /// Displacement of each clamped node (same order as `fixed`).
    pub fixed_displacement: Vec<[f64; 3]>,
    /// Dead loads acting at the end of the capture, per node (N).
    pub forces: Vec<(usize, [f64; 3])>,
    /// Each marker's element of the linear mesh and barycentric coordinates in it.
    pub markers: Vec<(usize, [f64; 4])>,
    /// Each marker's mean observed position over the window (m).
    pub observed: Vec<[f64; 3]>,
    /// Observed frames averaged per marker (fewest over the markers).
    pub frames: usize,
    /// How the markers on stand-offs follow the body.
    pub stand_off: StandOff,
}

impl RestState {
    /// The rest state of `ds`: the markers' mean positions over the last `window` seconds of
    /// the capture, with the loads and clamp poses of its last step. A marker with no frame in
    /// the window, or whose weights name no element, is an error naming it.
    pub fn of_dataset(ds: &MotionDataset, window: f64) -> Result<Self, MotionError> {
        let model = &ds.model;
        let density = ds.config.density.ok_or_else(|| {
            MotionError::Invalid(
                "dataset.toml: field density is missing (a rest state needs the weight)".into(),
            )
        })?;
        let end = model.steps;
        let first = end.saturating_sub((window / model.dt).round() as usize);
        let located = model.marker_elements()?;
        let mut markers = Vec::with_capacity(model.markers.len());
        let mut observed = Vec::with_capacity(model.markers.len());
        let mut frames = usize::MAX;
        for (i, m) in model.markers.iter().enumerate() {
            let (e, bary) = located[i];
            // Steps first+1..=end are observation rows first..end.
            let seen: Vec<[f64; 3]> = model_rows(&ds.obs.markers, first, end, i);
            if seen.is_empty() {
                return Err(MotionError::Invalid(format!(
                    "marker {:?}: no observed frame in the last {window} s",
                    m.name
                )));
            }
            frames = frames.min(seen.len());
            let k = seen.len() as f64;
            observed.push([0, 1, 2].map(|d| seen.iter().map(|p| p[d]).sum::<f64>() / k));
            markers.push((e, bary));
        }
        let ndof = 3 * ds.mesh.nodes.len();
        let forces = dead_load_forces(model);
        let mut x = vec![0.0; ndof];
        model.apply_clamps(end, &mut x);
        let fixed: Vec<usize> = model
            .clamps
            .iter()
            .flat_map(|c| c.nodes.iter().copied())
            .collect();
        let fixed_displacement = fixed
            .iter()
            .map(|&n| [0, 1, 2].map(|d| x[3 * n + d] - ds.mesh.nodes[n][d]))
            .collect();
        Ok(Self {
            mesh: ds.mesh.clone(),
            density,
            gravity: model.gravity,
            fixed,
            fixed_displacement,
            forces,
            markers,
            observed,
            frames: if frames == usize::MAX { 0 } else { frames },
            stand_off: StandOff::default(),
        })
    }

    /// This rest state under `model`'s dead loads at its last step (the same run's model with
    /// its hanging weights moved, say: [`crate::load_point`]).
    pub fn with_loads_of(&self, model: &Model) -> Self {
        Self {
            forces: dead_load_forces(model),
            ..self.clone()
        }
    }

    /// The static problem of this rest state for `material`.
    fn problem(&self, material: HyperParams, solve: &RestSolve) -> StaticProblem<'_> {
        let mut p = StaticProblem::new(&self.mesh, material, self.fixed.clone());
        p.density = self.density;
        p.gravity = self.gravity;
        p.fixed_displacement = self.fixed_displacement.clone();
        p.forces = self.forces.clone();
        p.load_steps = solve.load_steps;
        p.tol = solve.tol;
        p
    }
}

/// The nodal forces of `model`'s dead loads at its last step, on the nodes they load.
fn dead_load_forces(model: &Model) -> Vec<(usize, [f64; 3])> {
    let mut f = vec![0.0; 3 * model.nodes.len()];
    model.add_dead_loads(model.steps, &mut f);
    (0..model.nodes.len())
        .filter(|&n| f[3 * n..3 * n + 3].iter().any(|v| *v != 0.0))
        .map(|n| (n, [f[3 * n], f[3 * n + 1], f[3 * n + 2]]))
        .collect()
}

/// How each rest state is solved: load increments and Newton tolerance on the residual (N).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RestSolve {
    /// Load increments (≥ 1).
    pub load_steps: usize,
    /// Newton tolerance (N). Near incompressibility the residual's round-off floor rises with λ
    /// (≈ 2e-8 N for the beam at ν = 0.499 on linear tetrahedra), so it must sit above it.
    pub tol: f64,
}

/// Observed positions of marker `i` at observation rows `first..end`.
fn model_rows(rows: &[Vec<Option<[f64; 3]>>], first: usize, end: usize, i: usize) -> Vec<[f64; 3]> {
    rows[first.min(rows.len())..end.min(rows.len())]
        .iter()
        .filter_map(|r| r.get(i).copied().flatten())
        .collect()
}

/// A solved rest state: the markers' predicted positions and, if asked, their derivative with
/// respect to ln μ at fixed Poisson's ratio.
#[derive(Debug, Clone)]
pub struct RestPrediction {
    /// Predicted marker positions (m).
    pub markers: Vec<[f64; 3]>,
    /// ∂marker/∂ln μ at fixed ν (m), when asked for.
    pub dmarkers: Option<Vec<[f64; 3]>>,
    /// Newton iterations of the solve.
    pub newton_iterations: usize,
}

impl RestPrediction {
    /// RMS of the 3-D marker error against `state`'s observed rest positions (m).
    pub fn rms(&self, state: &RestState) -> f64 {
        let s: f64 = self
            .markers
            .iter()
            .zip(&state.observed)
            .map(|(p, o)| (0..3).map(|d| (p[d] - o[d]).powi(2)).sum::<f64>())
            .sum();
        (s / self.markers.len().max(1) as f64).sqrt()
    }
}

/// Lamé parameters of shear modulus `mu` at Poisson's ratio `poisson`.
pub fn lame(mu: f64, poisson: f64) -> HyperParams {
    HyperParams {
        lambda: 2.0 * mu * poisson / (1.0 - 2.0 * poisson),
        mu,
        stiffening: 0.0,
    }
}

/// Solves `state` with `design` at (μ, ν); with `sensitivity`, also ∂markers/∂ln μ at fixed ν,
/// μ ∂x/∂μ + λ ∂x/∂λ (λ is proportional to μ at fixed ν).
pub fn predict_rest(
    state: &RestState,
    design: Design,
    mu: f64,
    poisson: f64,
    solve: &RestSolve,
    sensitivity: bool,
) -> Result<RestPrediction, MotionError> {
    let material = lame(mu, poisson);
    let p = state.problem(material, solve);
    let linear_at = |v: &[[f64; 3]], e: usize, l: &[f64; 4]| -> [f64; 3] {
        let t = state.mesh.tets[e];
        [0, 1, 2].map(|d| (0..4).map(|a| l[a] * v[t[a]][d]).sum())
    };
    let (solution, sens, quadratic) = match design {
        Design::Linear => {
            let s = solve_static(&p)?;
            let d = sensitivity
                .then(|| static_sensitivity(&p, &s))
                .transpose()?;
            (s, d, None)
        }
        Design::Quadratic => {
            let s = solve_static_quadratic(&p)?;
            let d = sensitivity
                .then(|| quadratic_sensitivity(&p, &s))
                .transpose()?;
            (s.solution, d, Some(s.mesh))
        }
    };
    let at = |v: &[[f64; 3]], e: usize, l: &[f64; 4]| match &quadratic {
        Some(q) => value_at(q, v, e, l),
        None => linear_at(v, e, l),
    };
    let posts = state.posts();
    let marker_at = |v: &[[f64; 3]], i: usize| -> Result<[f64; 3], MotionError> {
        let (e, l) = &state.markers[i];
        match &posts[i] {
            Some(post) => post.position(&|l: &[f64; 4]| at(v, *e, l)).ok_or_else(|| {
                MotionError::NonFinite(format!(
                    "the rotation at the foot of marker {i}'s post (element {e})"
                ))
            }),
            None => Ok(at(v, *e, l)),
        }
    };
    let n = state.markers.len();
    let markers: Vec<[f64; 3]> = (0..n)
        .map(|i| marker_at(&solution.positions, i))
        .collect::<Result<_, _>>()?;
    let dmarkers = sens
        .map(|ds| -> Result<Vec<[f64; 3]>, MotionError> {
            // ∂x/∂ln μ at fixed ν of every node, then of each marker: the interpolation's own where
            // it is linear in the nodes, a central difference along that nodal field for a rigid
            // post (R depends on the positions; the difference of a smooth map, no solve).
            let dx: Vec<[f64; 3]> = ds
                .dlambda
                .iter()
                .zip(&ds.dmu)
                .map(|(dl, dm)| [0, 1, 2].map(|d| material.lambda * dl[d] + material.mu * dm[d]))
                .collect();
            let h = 1e-4;
            let moved = |sign: f64| -> Vec<[f64; 3]> {
                solution
                    .positions
                    .iter()
                    .zip(&dx)
                    .map(|(x, d)| [0, 1, 2].map(|k| x[k] + sign * h * d[k]))
                    .collect()
            };
            let (plus, minus) = (moved(1.0), moved(-1.0));
            (0..n)
                .map(|i| {
                    let (e, l) = &state.markers[i];
                    match posts[i] {
                        Some(_) => {
                            let (a, b) = (marker_at(&plus, i)?, marker_at(&minus, i)?);
                            Ok([0, 1, 2].map(|k| (a[k] - b[k]) / (2.0 * h)))
                        }
                        None => Ok(at(&dx, *e, l)),
                    }
                })
                .collect()
        })
        .transpose()?;
    Ok(RestPrediction {
        markers,
        dmarkers,
        newton_iterations: solution.iterations,
    })
}

/// A marker's rigid post ([`StandOff::RigidPost`]): its foot in barycentric coordinates, the
/// foot-to-marker vector at rest and the inverse of its element's rest edge matrix.
#[derive(Debug, Clone)]
pub(crate) struct Post {
    foot: [f64; 4],
    offset: Vector3<f64>,
    dm_inv: Matrix3<f64>,
}

impl Post {
    /// The post of a marker at barycentric `l` of the element with corners `t` of `nodes`
    /// (rest positions), when it sits outside the element; `None` inside it (the interpolation
    /// follows it) or for a degenerate element.
    pub(crate) fn of_marker(nodes: &[[f64; 3]], t: [usize; 4], l: &[f64; 4]) -> Option<Self> {
        if l.iter().all(|w| *w >= 0.0) {
            return None;
        }
        let x = |l: &[f64; 4]| -> Vector3<f64> {
            (0..4).fold(Vector3::zeros(), |acc, a| {
                acc + Vector3::from(nodes[t[a]]) * l[a]
            })
        };
        let clamped = l.map(|w| w.max(0.0));
        let sum: f64 = clamped.iter().sum();
        let foot = clamped.map(|w| w / sum);
        let corner = |a: usize| Vector3::from(nodes[t[a]]);
        let dm = Matrix3::from_columns(&[
            corner(1) - corner(0),
            corner(2) - corner(0),
            corner(3) - corner(0),
        ]);
        let dm_inv = dm.try_inverse()?;
        Some(Post {
            foot,
            offset: x(l) - x(&foot),
            dm_inv,
        })
    }

    /// The marker's position, given the deformed position at any barycentric point of its
    /// element (`at`): the foot's, plus the offset turned by the rotation of F at the foot.
    /// F = ∂x/∂ξ · D⁻¹ with ∂x/∂ξ by central differences of step 10⁻³ in the local coordinates
    /// — exact for interpolations of degree ≤ 2, as the linear and quadratic ones are.
    /// `None` where F is not finite.
    pub(crate) fn position(&self, at: &dyn Fn(&[f64; 4]) -> [f64; 3]) -> Option<[f64; 3]> {
        let h = 1e-3;
        let mut dxi = Matrix3::zeros();
        for k in 1..4 {
            let (mut p, mut m) = (self.foot, self.foot);
            p[k] += h;
            p[0] -= h;
            m[k] -= h;
            m[0] += h;
            let (a, b) = (at(&p), at(&m));
            for d in 0..3 {
                dxi[(d, k - 1)] = (a[d] - b[d]) / (2.0 * h);
            }
        }
        let f = dxi * self.dm_inv;
        if !f.iter().all(|v| v.is_finite()) {
            return None;
        }
        // The warped FEM's own polar rotation (an inverted element: the SVD's nearest rotation).
        let r = palpate_runtime::rotation::warp_rotation_polar(&f);
        let x = at(&self.foot);
        let turned = r * self.offset;
        Some([x[0] + turned[0], x[1] + turned[1], x[2] + turned[2]])
    }
}

impl RestState {
    /// Each marker's rigid post under [`StandOff::RigidPost`] when it sits outside its element
    /// (`None`: followed by the interpolation).
    fn posts(&self) -> Vec<Option<Post>> {
        self.markers
            .iter()
            .map(|(e, l)| {
                if self.stand_off != StandOff::RigidPost {
                    return None;
                }
                Post::of_marker(&self.mesh.nodes, self.mesh.tets[*e], l)
            })
            .collect()
    }
}

/// A fitted shear modulus.
#[derive(Debug, Clone)]
pub struct ShearFit {
    /// μ (Pa).
    pub mu: f64,
    /// Gauss–Newton iterations (each one solve and one sensitivity per run).
    pub iterations: usize,
    /// Newton iterations over every solve of the fit.
    pub newton_iterations: usize,
    /// The fitted runs' predictions at μ.
    pub predictions: Vec<RestPrediction>,
}

/// The Gauss–Newton step `gn` in ln μ, taken in the compliance 1/μ instead. A rest state is loaded
/// by forces alone (gravity, hung weights) against a fixed clamp, so at a fixed Poisson's ratio a
/// linear response displaces every marker in proportion to 1/μ: there the step in 1/μ is exact,
/// where the one in ln μ falls short — markers displaced c times the measured amount ask for ln c,
/// and ln μ's linearisation gives (c − 1)/c (0.48 for c = 1.93, the beam's quadratic-to-linear
/// ratio, in place of 0.66). The two agree to first order near the minimum. Beyond gn = 0.9 (the
/// markers displaced ten times too far) the step in ln μ is kept: the step in 1/μ grows without
/// bound there, and the fit's halving guards either.
pub fn compliance_step(gn: f64) -> f64 {
    if gn < 0.9 {
        -(-gn).ln_1p()
    } else {
        gn
    }
}

/// Fits μ at fixed `poisson` to the rest states `states` by Gauss–Newton in ln μ from `mu0`,
/// each step taken in the compliance ([`compliance_step`]), until the step is below `1e-4` in
/// ln μ (0.01 %) or after `max_iter` iterations; a step that does not lower the summed squared
/// marker error is halved (up to ten times).
pub fn fit_shear_modulus(
    states: &[RestState],
    design: Design,
    poisson: f64,
    mu0: f64,
    settings: &RestSolve,
    max_iter: usize,
) -> Result<ShearFit, MotionError> {
    let mut newton = 0usize;
    let mut solve = |mu: f64, sens: bool| -> Result<Vec<RestPrediction>, MotionError> {
        // Each run's rest state is its own solve: side by side.
        let out: Vec<RestPrediction> = states
            .par_iter()
            .map(|s| predict_rest(s, design, mu, poisson, settings, sens))
            .collect::<Result<_, _>>()?;
        newton += out.iter().map(|p| p.newton_iterations).sum::<usize>();
        Ok(out)
    };
    let cost = |preds: &[RestPrediction]| -> f64 {
        preds
            .iter()
            .zip(states)
            .map(|(p, s)| p.rms(s).powi(2) * p.markers.len() as f64)
            .sum()
    };
    let mut theta = mu0.ln();
    let mut preds = solve(mu0, true)?;
    let mut iterations = 0;
    for _ in 0..max_iter {
        iterations += 1;
        let (mut jtr, mut jtj) = (0.0, 0.0);
        for (p, s) in preds.iter().zip(states) {
            let dm = p.dmarkers.as_ref().expect("sensitivities were asked for");
            for ((x, o), j) in p.markers.iter().zip(&s.observed).zip(dm) {
                for d in 0..3 {
                    jtr += j[d] * (x[d] - o[d]);
                    jtj += j[d] * j[d];
                }
            }
        }
        if jtj <= 0.0 || !jtj.is_finite() {
            return Err(MotionError::NonFinite(format!(
                "Gauss–Newton normal equation JᵀJ = {jtj:e} at μ = {:.1} Pa",
                theta.exp()
            )));
        }
        let mut step = compliance_step(-jtr / jtj);
        let before = cost(&preds);
        let mut accepted = None;
        for _ in 0..10 {
            let trial = solve((theta + step).exp(), true)?;
            if cost(&trial) <= before {
                accepted = Some(trial);
                break;
            }
            step *= 0.5;
        }
        let Some(trial) = accepted else {
            break;
        };
        theta += step;
        preds = trial;
        log::info!(
            "{} ν {poisson}: GN {iterations}: μ = {:.1} Pa (step {step:+.2e} in ln μ)",
            design.name(),
            theta.exp()
        );
        if step.abs() < 1e-4 {
            break;
        }
    }
    Ok(ShearFit {
        mu: theta.exp(),
        iterations,
        newton_iterations: newton,
        predictions: preds,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_fem::mesh::boxmesh::box_mesh;

    /// Markers displaced c times the measured amount by a linear response ask for ln c in ln μ:
    /// the step in the compliance gives it exactly, where ln μ's own linearisation, (c − 1)/c,
    /// falls short; near the minimum the two differ by a term of second order in the step.
    #[test]
    fn the_compliance_step_is_exact_for_a_linear_response() {
        for c in [0.2, 0.7, 1.3, 1.93, 5.0] {
            let gn: f64 = 1.0 - 1.0 / c;
            let step = compliance_step(gn);
            assert!(
                (step - c.ln()).abs() < 1e-12,
                "c {c}: {step} for {}",
                c.ln()
            );
        }
        let gn = 1e-3;
        assert!((compliance_step(gn) - gn).abs() < gn * gn);
        // Ten times too far and beyond: ln μ's own step.
        assert_eq!(compliance_step(0.95), 0.95);
    }

    /// One element and a post standing out of it: the foot-to-marker vector is turned by the
    /// rotation of F and not stretched, where the extrapolated interpolation stretches it.
    #[test]
    fn a_rigid_post_turns_with_its_element_and_does_not_stretch() {
        let corners = [
            [0.0; 3],
            [0.01, 0.0, 0.0],
            [0.0, 0.01, 0.0],
            [0.0, 0.0, 0.01],
        ];
        // A marker 2.9 mm beyond the face x + y + z = 0.01, over its centre.
        let l = [-0.5, 0.5, 0.5, 0.5];
        let (post, rest) = {
            let mesh = Mesh {
                nodes: corners.to_vec(),
                tets: vec![[0, 1, 2, 3]],
                ..Default::default()
            };
            let state = RestState {
                mesh,
                density: 0.0,
                gravity: [0.0; 3],
                fixed: Vec::new(),
                fixed_displacement: Vec::new(),
                forces: Vec::new(),
                markers: vec![(0, l)],
                observed: vec![[0.0; 3]],
                frames: 1,
                stand_off: StandOff::RigidPost,
            };
            (
                state.posts().remove(0).expect("the marker is outside"),
                state,
            )
        };
        let x_rest = |l: &[f64; 4]| {
            [0, 1, 2].map(|d| (0..4).map(|a| l[a] * rest.mesh.nodes[a][d]).sum::<f64>())
        };
        // F = R₀ diag(1.3, 0.9, 1.1) and a shift: the deformed corners.
        let r0 = nalgebra::Rotation3::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vector3::new(1.0, 2.0, -0.5)),
            0.7,
        )
        .into_inner();
        let f = r0 * Matrix3::from_diagonal(&Vector3::new(1.3, 0.9, 1.1));
        let shift = Vector3::new(0.002, -0.001, 0.003);
        let moved: Vec<Vector3<f64>> = corners
            .iter()
            .map(|c| f * Vector3::from(*c) + shift)
            .collect();
        let at = |l: &[f64; 4]| -> [f64; 3] {
            let p = (0..4).fold(Vector3::zeros(), |acc, a| acc + moved[a] * l[a]);
            [p[0], p[1], p[2]]
        };
        let got = Vector3::from(post.position(&at).expect("a rotation"));
        let foot = Vector3::from(at(&post.foot));
        let d = Vector3::from(x_rest(&l)) - Vector3::from(x_rest(&post.foot));
        assert!((post.offset - d).norm() < 1e-15);
        assert!(d.norm() > 2.8e-3, "the post is {} m", d.norm());
        let expected = foot + r0 * d;
        assert!((got - expected).norm() < 1e-9, "{got} against {expected}");
        // The extrapolation stretches it: x_f + F·d.
        let extrapolated = Vector3::from(at(&l));
        assert!((extrapolated - (foot + f * d)).norm() < 1e-12);
        assert!((extrapolated - expected).norm() > 5e-4);
        // A state that is not finite has no rotation: no position, where the caller says so.
        assert!(post.position(&|_| [f64::NAN; 3]).is_none());
    }

    /// The rest states of a cantilever with markers on 6 mm posts, made under rigid posts on
    /// quadratic elements at a known μ: the fit under rigid posts returns that μ from a start
    /// 30 % off (its ∂marker/∂ln μ, a difference along the solved sensitivity, is right), and
    /// the extrapolated posts read another.
    #[test]
    fn the_shear_modulus_is_read_back_through_rigid_posts() {
        let mesh = box_mesh([0.03, 0.10, 0.02], [2, 6, 2]);
        let fixed = mesh.node_groups["front"].clone();
        // Markers 6 mm above the top face and beyond the free end.
        let points = [
            [0.015, 0.1, 0.026],
            [0.015, 0.106, 0.01],
            [0.005, 0.06, 0.026],
        ];
        let markers: Vec<(usize, [f64; 4])> = points
            .iter()
            .map(|p| {
                let x = Vector3::from(*p);
                (0..mesh.tets.len())
                    .map(|e| {
                        let c = mesh.tets[e].map(|n| Vector3::from(mesh.nodes[n]));
                        let m = Matrix3::from_columns(&[c[1] - c[0], c[2] - c[0], c[3] - c[0]]);
                        let l = m.try_inverse().unwrap() * (x - c[0]);
                        let l = [1.0 - l.sum(), l[0], l[1], l[2]];
                        (e, l, l.iter().fold(0.0f64, |m, v| m.min(*v)))
                    })
                    .max_by(|a, b| a.2.total_cmp(&b.2))
                    .map(|(e, l, _)| (e, l))
                    .unwrap()
            })
            .collect();
        assert!(markers.iter().all(|(_, l)| l.iter().any(|v| *v < -0.1)));
        let mut state = RestState {
            mesh,
            density: 1100.0,
            gravity: [0.0, 0.0, -9.81],
            fixed_displacement: vec![[0.0; 3]; fixed.len()],
            fixed,
            forces: Vec::new(),
            observed: vec![[0.0; 3]; markers.len()],
            markers,
            frames: 1,
            stand_off: StandOff::RigidPost,
        };
        let solve = RestSolve {
            load_steps: 2,
            tol: 1e-9,
        };
        let mu = 1.5e4;
        let truth = predict_rest(&state, Design::Quadratic, mu, 0.45, &solve, false).unwrap();
        state.observed = truth.markers;
        let back = fit_shear_modulus(
            std::slice::from_ref(&state),
            Design::Quadratic,
            0.45,
            1.3 * mu,
            &solve,
            20,
        )
        .unwrap();
        assert!((back.mu / mu - 1.0).abs() < 1e-4, "μ {} for {mu}", back.mu);
        assert!(back.predictions[0].rms(&state) < 1e-8);
        state.stand_off = StandOff::Extrapolated;
        let other = fit_shear_modulus(
            std::slice::from_ref(&state),
            Design::Quadratic,
            0.45,
            mu,
            &solve,
            20,
        )
        .unwrap();
        assert!(other.predictions[0].rms(&state) > 1e-6, "{other:?}");
    }
}
