//! The runtime's model matched to the converged material.
//!
//! The runtime replays a warped linear model on linear tetrahedra (P1) in fixed memory; a motion
//! fit's modulus is the P1 mesh's effective one, which near incompressibility is locked in
//! bending ([`crate::convergence`]). The material itself is the modulus on quadratic tetrahedra
//! (P2), which do not lock. What the runtime should replay is the material, so the export fits the
//! runtime mesh's parameters to what the converged model does under a set of probe loads — seed
//! 000's displacement-based inverse (§5.3, eqs. 5.61–5.92, through
//! [`palpate_static_fit::fit_static`]) fed with measurements the converged model synthesises —
//! and reports the runtime model's error against the converged one on probes it was not fitted
//! to. (The force-based inverse of §5.2, which complete data would allow, is not used: the P2
//! field at the corners is not one a locked P1 element can take without large volumetric forces,
//! and fitting those forces drives λ down to a soft, compressible material: on the silicone beam
//! its one pair came out at E = 68 kPa, ν = −0.21, and predicted the held-out presses 177 % off.)
//!
//! - **Probes**: [`MatchOptions::probes`] contact points on the free boundary, spread by
//!   farthest-point sampling from the node farthest from the clamp, each pressing along the
//!   inward surface normal with the runtime's contact rule over [`MatchOptions::radius_edges`]
//!   mean boundary edges. Every other probe is held out. Each force is scaled so that the
//!   exported model's largest displacement under it is [`MatchOptions::displacement_fraction`]
//!   of the object's bounding-box diagonal: presses of a haptic probe, not the object's
//!   large-strain range (the runtime's model is linear in its rotated frames).
//! - **The converged model**: Neo-Hookean at the record's P2 shear modulus and Poisson's ratio,
//!   solved on the quadratic lift of the runtime mesh ([`palpate_motion::quadratic_statics`]),
//!   the clamp held, no gravity (the runtime's rest shape is the mesh), each press loaded as the
//!   traction its lumped forces stand for
//!   ([`palpate_motion::quadratic_statics::consistent_traction_load`]: on the corners alone a
//!   quadratic mesh would see point loads, and dimple under them). Its corner nodes are the
//!   runtime mesh's nodes, so each probe gives every boundary node's deformed position.
//! - **Designs**: the export as fitted (the motion fit's P1 moduli at rest), one (λ, α) pair
//!   fitted to the fitting probes' markers (one on every free boundary node), and one pair per
//!   element with the thesis' spatial smoothness L_s (§5.2.1), its weight γ chosen on the
//!   L-curve (§5.1). The design with the smallest error on the fitting probes is exported — a
//!   richer one only where it cuts the simpler one's by a tenth ([`RICHER_GAIN`]) — unless it
//!   predicts the held-out probes worse than the fit's own moduli (the held-out gate); the
//!   held-out probes report how far the runtime is from the material.
//! - **Error**: per probe set, the RMS over the free nodes of the runtime's displacement minus
//!   the converged model's, relative to the RMS of the converged displacement, and the largest
//!   node error (m); the runtime's displacement is the f64 forward model's warped solve, the
//!   runtime's element maths.

use crate::Error;
use palpate_fem::dataset::Marker;
use palpate_fem::forward::{Contact, Load, Material, SolveOptions, StaticProblem};
use palpate_fem::mesh::Mesh;
use palpate_motion::fitted::ConvergedModulus;
use palpate_motion::quadratic_statics::{consistent_traction_load, solve_static_quadratic_loaded};
use palpate_motion::rest_fit::lame;
use palpate_motion::statics::StaticProblem as HyperProblem;
use palpate_runtime::material::LambdaAlpha;
use palpate_static_fit::{fit_static, FitInput, FitMeasurement, FitOptions, Layout, Method, Sets};
use rayon::prelude::*;
use serde::Serialize;
use std::fmt::Write as _;

/// How the probes are made and the per-element fit regularised.
#[derive(Debug, Clone, PartialEq)]
pub struct MatchOptions {
    /// Probe contacts (half fitted, half held out).
    pub probes: usize,
    /// The largest displacement under each probe, as a fraction of the bounding-box diagonal.
    pub displacement_fraction: f64,
    /// The contact radius in mean boundary edge lengths.
    pub radius_edges: f64,
    /// Levenberg–Marquardt iterations of each fit at most. On the beam the per-element fit
    /// reaches 20 with 0.7 % error left on the fitting presses; 40 leave its held-out error
    /// where it was (3.9 % against 3.6 %) at 1.5× the time.
    pub max_iterations: usize,
    /// Points of the per-element fit's L-curve in γ.
    pub l_curve_points: usize,
}

impl Default for MatchOptions {
    fn default() -> Self {
        Self {
            probes: 16,
            displacement_fraction: 0.02,
            radius_edges: 1.5,
            max_iterations: 20,
            l_curve_points: 5,
        }
    }
}

/// One design of the runtime's parameters, against the converged model.
#[derive(Debug, Clone, Serialize)]
pub struct DesignError {
    /// "as fitted", "one pair", "per element".
    pub design: String,
    /// Relative displacement RMS on the fitting probes.
    pub fitted_relative: f64,
    /// Relative displacement RMS on the held-out probes.
    pub held_out_relative: f64,
    /// The largest node error over the held-out probes (m).
    pub held_out_max_m: f64,
    /// Young's modulus of the design (Pa): the mean over elements.
    pub mean_young_pa: f64,
    /// Poisson's ratio of the design: the mean over elements.
    pub mean_poisson: f64,
}

/// The match: the parameters to export and every design's errors.
#[derive(Debug, Clone)]
pub struct RuntimeMatch {
    /// The chosen design's parameters (thesis λ, α).
    pub material: Material,
    /// The chosen design's name.
    pub chosen: String,
    /// Every design tried, the export as fitted first.
    pub designs: Vec<DesignError>,
    /// The probes' force magnitudes (N), in probe order.
    pub probe_forces_n: Vec<f64>,
    /// The probes' contact radius (m).
    pub radius_m: f64,
    /// The converged model's largest displacement over all probes (m).
    pub largest_displacement_m: f64,
    /// The converged modulus matched.
    pub converged: ConvergedModulus,
}

/// One probe: its load and the converged model's deformed node positions.
struct Probe {
    force: Vec<f64>,
    converged: Vec<[f64; 3]>,
}

/// The fraction of the simpler design's error on the fitting presses a design with more
/// parameters must come below to be chosen: the presses are noise-free, so any freedom lowers
/// that error a little, and a per-element model that barely beats one pair carries its
/// smoothing's artefacts for nothing.
pub const RICHER_GAIN: f64 = 0.9;

/// The warped solve of the runtime's model (the f64 forward model, the runtime's element maths).
const RUNTIME_SOLVE: SolveOptions = SolveOptions {
    increments: 4,
    warp: true,
    tolerance: 1e-10,
    max_fixed_point: 100,
    reuse_factor: true,
};

/// Fits the runtime mesh's parameters to the converged material (module note). `mesh` is the
/// runtime's, `fixed` its clamp nodes, `as_fitted` the export of the motion fit's own moduli.
pub fn match_runtime(
    mesh: &Mesh,
    fixed: &[usize],
    as_fitted: &Material,
    converged: &ConvergedModulus,
    o: &MatchOptions,
) -> Result<RuntimeMatch, Error> {
    let (mu, nu) = (converged.shear_modulus_pa, converged.poisson);
    if !(mu.is_finite() && mu > 0.0 && nu > -1.0 && nu < 0.5) {
        return Err(Error::Input(format!(
            "the converged material is not one: shear modulus {mu:e} Pa (expected > 0), \
             Poisson's ratio {nu} (expected between -1 and 0.5)"
        )));
    }
    if o.probes < 2 {
        return Err(Error::Input(format!(
            "the runtime match needs at least 2 probes (one fitted, one held out), found {}",
            o.probes
        )));
    }
    let surface = mesh.boundary_triangles();
    let problem = StaticProblem::new(mesh, fixed, &surface)?;
    let (contacts, radius) = probe_contacts(mesh, fixed, &surface, as_fitted, &problem, o)?;
    let probe_forces_n: Vec<f64> = contacts
        .iter()
        .map(|c| c.force.iter().map(|f| f * f).sum::<f64>().sqrt())
        .collect();
    let t0 = std::time::Instant::now();
    let probes = contacts
        .par_iter()
        .enumerate()
        .map(|(k, c)| {
            let force = problem.force_vector(&Load::contact(c.point, c.force, c.radius))?;
            let converged = converged_state(mesh, fixed, &surface, &force, converged)
                .map_err(|e| Error::Fit(format!("runtime match, probe {k}: {e}")))?;
            Ok(Probe { force, converged })
        })
        .collect::<Result<Vec<_>, Error>>()?;
    log::debug!(
        "runtime match: {} presses on the converged model in {:.2} s",
        probes.len(),
        t0.elapsed().as_secs_f64()
    );
    let largest_displacement_m = probes
        .iter()
        .flat_map(|p| p.converged.iter().zip(&mesh.nodes).map(|(x, r)| dist(x, r)))
        .fold(0.0, f64::max);
    let fit: Vec<&Probe> = probes.iter().step_by(2).collect();
    let held: Vec<&Probe> = probes.iter().skip(1).step_by(2).collect();

    let mut candidates: Vec<(String, Material)> = vec![("as fitted".into(), as_fitted.clone())];
    let input = fit_input(mesh, &problem, &contacts, &probes);
    let pair = |m: &Material| {
        let (lambda, alpha) = m.at(0);
        LambdaAlpha { lambda, alpha }
    };
    let mut start = pair(as_fitted);
    for (name, layout) in [
        ("one pair", Layout::Homogeneous),
        ("per element", Layout::Inhomogeneous),
    ] {
        let mut fo = FitOptions::new(Method::Displacement, layout, Sets::Single);
        // The per-element fit starts from the fitted pair, the nearest homogeneous material.
        fo.initial = start;
        fo.solve = RUNTIME_SOLVE;
        fo.max_iterations = o.max_iterations;
        fo.l_curve_points = o.l_curve_points;
        let t = std::time::Instant::now();
        match fit_static(&input, &fo, |_, _| {}) {
            Ok(r) if r.params[0].check(mesh.tets.len()).is_ok() => {
                log::debug!(
                    "runtime match, {name}: {} iterations, {:.1} s",
                    r.history.len(),
                    t.elapsed().as_secs_f64()
                );
                if layout == Layout::Homogeneous {
                    start = pair(&r.params[0]);
                }
                candidates.push((name.into(), r.params[0].clone()));
            }
            Ok(_) => log::warn!("runtime match, {name}: not a physical material; not offered"),
            Err(e) => log::warn!("runtime match, {name}: {e}; not offered"),
        }
    }

    let mut designs = Vec::with_capacity(candidates.len());
    for (name, m) in &candidates {
        let (fitted_relative, _) = relative_error(&problem, m, &fit)?;
        let (held_out_relative, held_out_max_m) = relative_error(&problem, m, &held)?;
        designs.push(DesignError {
            design: name.clone(),
            fitted_relative,
            held_out_relative,
            held_out_max_m,
            mean_young_pa: m.mean(LambdaAlpha::young),
            mean_poisson: m.mean(LambdaAlpha::poisson),
        });
    }
    // The fitting probes choose, the designs in order of their parameters: a richer one is
    // taken where it cuts the simpler one's error by RICHER_GAIN. The held-out ones are the
    // gate: a design that predicts them worse than the fit's own moduli is not exported.
    let mut chosen = 0;
    for (i, d) in designs.iter().enumerate().skip(1) {
        if d.held_out_relative <= designs[0].held_out_relative
            && d.fitted_relative < RICHER_GAIN * designs[chosen].fitted_relative
        {
            chosen = i;
        }
    }
    Ok(RuntimeMatch {
        material: candidates[chosen].1.clone(),
        chosen: candidates[chosen].0.clone(),
        designs,
        probe_forces_n,
        radius_m: radius,
        largest_displacement_m,
        converged: converged.clone(),
    })
}

/// The fitting probes as the static fitter's input: a marker on every free boundary node,
/// observed where the converged model puts it.
fn fit_input(
    mesh: &Mesh,
    problem: &StaticProblem,
    contacts: &[Contact],
    probes: &[Probe],
) -> FitInput {
    let mut on: Vec<Option<[usize; 3]>> = vec![None; mesh.nodes.len()];
    for t in &problem.surface {
        for (k, &i) in t.iter().enumerate() {
            if !problem.fixed[i] && on[i].is_none() {
                // The triangle rotated so that the node is its first corner.
                on[i] = Some([t[k], t[(k + 1) % 3], t[(k + 2) % 3]]);
            }
        }
    }
    let nodes: Vec<(usize, [usize; 3])> = on
        .iter()
        .enumerate()
        .filter_map(|(i, t)| t.map(|t| (i, t)))
        .collect();
    let markers = nodes
        .iter()
        .map(|&(i, triangle)| Marker {
            id: format!(
                "node {}",
                mesh.node_tags.get(i).copied().unwrap_or(i as u64)
            ),
            rest: mesh.nodes[i],
            triangle,
            barycentric: [1.0, 0.0, 0.0],
            distance: 0.0,
            offset_local: [0.0; 3],
        })
        .collect();
    let measurements = contacts
        .iter()
        .zip(probes)
        .step_by(2)
        .enumerate()
        .map(|(k, (c, p))| FitMeasurement {
            id: format!("probe {}", 2 * k),
            contact: *c,
            force: p.force.clone(),
            observed: nodes
                .iter()
                .enumerate()
                .map(|(m, &(i, _))| (m, p.converged[i]))
                .collect(),
        })
        .collect();
    FitInput {
        problem: problem.clone(),
        markers,
        measurements,
        marker_noise: None,
    }
}

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (0..3).map(|d| (a[d] - b[d]).powi(2)).sum::<f64>().sqrt()
}

/// The converged model's deformed node positions (the runtime mesh's nodes: the quadratic lift's
/// corners) under the press whose lumped nodal forces are `force` (3n), loaded on the quadratic
/// lift as the traction it stands for.
fn converged_state(
    mesh: &Mesh,
    fixed: &[usize],
    surface: &[[usize; 3]],
    force: &[f64],
    c: &ConvergedModulus,
) -> Result<Vec<[f64; 3]>, palpate_motion::MotionError> {
    let load = consistent_traction_load(mesh, surface, force);
    let total = load
        .iter()
        .map(|(_, f)| f.iter().map(|v| v * v).sum::<f64>().sqrt())
        .sum::<f64>();
    let mut p = HyperProblem::new(mesh, lame(c.shear_modulus_pa, c.poisson), fixed.to_vec());
    p.load_steps = 2;
    // A millionth of the probe's force: far below what moves a node by a micrometre here.
    p.tol = 1e-6 * total;
    p.max_iter = 50;
    let s = solve_static_quadratic_loaded(&p, &load)?;
    Ok(s.solution.positions[..mesh.nodes.len()].to_vec())
}

/// The runtime's displacement error against the converged model over `probes`: the relative RMS
/// over the free nodes and the largest node error (m).
fn relative_error(
    problem: &StaticProblem,
    m: &Material,
    probes: &[&Probe],
) -> Result<(f64, f64), Error> {
    let (mut err2, mut ref2, mut largest) = (0.0, 0.0, 0.0f64);
    for p in probes {
        let x = problem
            .solve_forces(m, &p.force, None, &RUNTIME_SOLVE)?
            .solution
            .x;
        for i in (0..x.len()).filter(|&i| !problem.fixed[i]) {
            let e = dist(&x[i], &p.converged[i]);
            err2 += e * e;
            ref2 += dist(&p.converged[i], &problem.x0[i]).powi(2);
            largest = largest.max(e);
        }
    }
    Ok(((err2 / ref2.max(f64::MIN_POSITIVE)).sqrt(), largest))
}

/// The probes' contacts and their radius (module note).
fn probe_contacts(
    mesh: &Mesh,
    fixed: &[usize],
    surface: &[[usize; 3]],
    as_fitted: &Material,
    problem: &StaticProblem,
    o: &MatchOptions,
) -> Result<(Vec<Contact>, f64), Error> {
    let n = mesh.nodes.len();
    let v = |i: usize| nalgebra::Vector3::from(mesh.nodes[i]);
    let mut normal = vec![nalgebra::Vector3::<f64>::zeros(); n];
    let (mut edges, mut edge_sum) = (0usize, 0.0);
    for t in surface {
        // (b − a) × (c − a): twice the area along the outward normal.
        let w = (v(t[1]) - v(t[0])).cross(&(v(t[2]) - v(t[0])));
        for &i in t {
            normal[i] += w;
        }
        for k in 0..3 {
            edge_sum += (v(t[k]) - v(t[(k + 1) % 3])).norm();
            edges += 1;
        }
    }
    let radius = o.radius_edges * edge_sum / edges.max(1) as f64;
    let mut is_fixed = vec![false; n];
    fixed.iter().for_each(|&i| is_fixed[i] = true);
    let candidates: Vec<usize> = (0..n)
        .filter(|&i| !is_fixed[i] && normal[i].norm() > 0.0)
        .collect();
    if candidates.len() < o.probes {
        return Err(Error::Input(format!(
            "the runtime match needs {} free boundary nodes to press, the mesh has {}",
            o.probes,
            candidates.len()
        )));
    }
    let clamp = fixed
        .iter()
        .map(|&i| v(i))
        .fold(nalgebra::Vector3::zeros(), |a, b| a + b)
        / fixed.len().max(1) as f64;
    // Farthest-point sampling from the node farthest from the clamp.
    let first = *candidates
        .iter()
        .max_by(|&&a, &&b| (v(a) - clamp).norm().total_cmp(&(v(b) - clamp).norm()))
        .unwrap_or(&candidates[0]);
    let mut chosen = vec![first];
    let mut nearest: Vec<f64> = candidates
        .iter()
        .map(|&i| (v(i) - v(first)).norm())
        .collect();
    while chosen.len() < o.probes {
        let (k, _) = nearest
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .unwrap_or((0, &0.0));
        let next = candidates[k];
        chosen.push(next);
        for (d, &i) in nearest.iter_mut().zip(&candidates) {
            *d = d.min((v(i) - v(next)).norm());
        }
    }
    let (lo, hi) = mesh.bounds();
    let diagonal = dist(&lo, &hi);
    let linear = SolveOptions {
        increments: 1,
        warp: false,
        ..RUNTIME_SOLVE
    };
    chosen
        .into_iter()
        .map(|i| {
            let inward = -normal[i].normalize();
            let unit = Contact {
                point: mesh.nodes[i],
                force: inward.into(),
                radius,
            };
            // The linear response scales with the force: one solve at 1 N sets the magnitude.
            let f = problem.force_vector(&Load::contact(unit.point, unit.force, radius))?;
            let x = problem
                .solve_forces(as_fitted, &f, None, &linear)?
                .solution
                .x;
            let largest = x
                .iter()
                .zip(&mesh.nodes)
                .map(|(x, r)| dist(x, r))
                .fold(0.0, f64::max);
            let scale = o.displacement_fraction * diagonal / largest.max(f64::MIN_POSITIVE);
            Ok(Contact {
                force: (inward * scale).into(),
                ..unit
            })
        })
        .collect::<Result<Vec<_>, Error>>()
        .map(|c| (c, radius))
}

/// [`match_runtime`] for a motion fit: the runtime mesh and clamps of `ds` (the dataset the fit
/// is exported on), the fit's own moduli at rest as the design "as fitted".
pub fn match_motion_fit(
    ds: &palpate_motion::dataset::MotionDataset,
    mat: &palpate_motion::model::Material,
    converged: &ConvergedModulus,
    o: &MatchOptions,
) -> Result<RuntimeMatch, Error> {
    match_runtime(
        &ds.mesh,
        &palpate_motion::export::clamp_nodes(&ds.model),
        &palpate_motion::export::runtime_parameters(mat),
        converged,
        o,
    )
}

/// A fitted motion model's material matched on another object's `mesh` held at `fixed` (what
/// `palpate export` writes): the fit's moduli taken as they are stand as "as fitted". Refused,
/// with the reason, when the fit records no modulus on quadratic elements (there is then no
/// material to match, only the fit mesh's locking) or its moduli vary between the elements of
/// its own mesh, which another mesh does not have.
pub fn match_fit_on(
    fit: &palpate_motion::fitted::FittedModel,
    mesh: &Mesh,
    fixed: &[usize],
) -> Result<RuntimeMatch, Error> {
    let converged = fit.converged.as_ref().ok_or_else(|| {
        Error::Input(
            "the fit records no converged modulus: fit it with `palpate fit-motion \
             --mesh-convergence` (or `palpate diagnose`, which checks it), so that its material, \
             not its mesh's, is what another mesh is given"
                .into(),
        )
    })?;
    let uniform = |v: &[f64]| palpate_motion::transfer::uniform(v).flatten();
    let (Some(lambda), Some(mu)) = (uniform(&fit.lambda), uniform(&fit.mu)) else {
        return Err(Error::Input(
            "the fit's moduli vary between the elements of its own mesh, which another mesh \
             does not have; only a uniform material is carried"
                .into(),
        ));
    };
    let as_fitted = Material::homogeneous(LambdaAlpha::from_lame(lambda, mu));
    match_runtime(mesh, fixed, &as_fitted, converged, &MatchOptions::default())
}

/// Whether a fit with this record needs the match: its modulus differs from the material's by
/// more than the mesh-convergence check's [`crate::convergence::TOLERANCE`] (where it does not,
/// the fit's own moduli are the material's and are exported as they are).
pub fn needed(c: &ConvergedModulus) -> bool {
    (c.shear_modulus_pa / c.mesh_shear_modulus_pa - 1.0).abs() > crate::convergence::TOLERANCE
}

/// The runtime parameters a motion fit `mat` exports on the mesh and clamps of `ds`: matched to
/// the converged material ([`match_motion_fit`]) when the record says the fit's modulus is the
/// mesh's ([`needed`]), the fit's own moduli at rest otherwise; with the match when one was made.
pub fn export_parameters(
    ds: &palpate_motion::dataset::MotionDataset,
    mat: &palpate_motion::model::Material,
    converged: Option<&ConvergedModulus>,
) -> Result<(Material, Option<RuntimeMatch>), Error> {
    match converged.filter(|c| needed(c)) {
        Some(c) => {
            let m = match_motion_fit(ds, mat, c, &MatchOptions::default())?;
            Ok((m.material.clone(), Some(m)))
        }
        None => Ok((palpate_motion::export::runtime_parameters(mat), None)),
    }
}

/// [`export_parameters`] for an export that is a by-product (a diagnosis' `model.palp`, a fit
/// played in memory): a match that cannot be made is said in a warning, and the fit's own moduli
/// are exported, rather than the work before it lost.
pub fn export_parameters_or_own(
    ds: &palpate_motion::dataset::MotionDataset,
    mat: &palpate_motion::model::Material,
    converged: Option<&ConvergedModulus>,
) -> (Material, Option<RuntimeMatch>) {
    export_parameters(ds, mat, converged).unwrap_or_else(|e| {
        log::warn!(
            "the runtime's model is not matched to the material ({e}); the fit's own moduli are \
             exported"
        );
        (palpate_motion::export::runtime_parameters(mat), None)
    })
}

impl RuntimeMatch {
    /// The match as a page of its own (`runtime-match.md`).
    pub fn report(&self) -> String {
        format!(
            "# The runtime's model matched to the material\n\n{}",
            self.markdown()
        )
    }

    /// The chosen design's errors.
    pub fn chosen_error(&self) -> Option<&DesignError> {
        self.designs.iter().find(|d| d.design == self.chosen)
    }

    /// The sentence the exported model's provenance carries.
    pub fn provenance(&self) -> String {
        let as_fitted = self.designs.first();
        match (self.chosen_error(), as_fitted) {
            (Some(c), Some(a)) => format!(
                "runtime parameters: {} fitted to the converged material ({} mu = {:.4e} Pa, \
                 Poisson {:.3}) under {} probe presses; displacement error against it on the \
                 held-out presses {:.1} % (the fit's own moduli: {:.1} %)",
                c.design,
                self.converged.design,
                self.converged.shear_modulus_pa,
                self.converged.poisson,
                self.probe_forces_n.len(),
                100.0 * c.held_out_relative,
                100.0 * a.held_out_relative
            ),
            _ => String::new(),
        }
    }

    /// The report's section: the probes, every design's error and the one exported.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        let forces = &self.probe_forces_n;
        let (lo, hi) = forces
            .iter()
            .fold((f64::INFINITY, 0.0f64), |(l, h), &f| (l.min(f), h.max(f)));
        let _ = writeln!(
            s,
            "The runtime's warped linear model on this mesh, matched to the material on \
             quadratic tetrahedra (Neo-Hookean, μ = {:.1} kPa, ν = {:.3}) under {} probe presses \
             ({} fitted, {} held out; {:.3}–{:.3} N over a {:.1} mm radius, the converged model's \
             largest displacement {:.2} mm). Relative displacement RMS over the free nodes:",
            self.converged.shear_modulus_pa / 1e3,
            self.converged.poisson,
            forces.len(),
            forces.len().div_ceil(2),
            forces.len() / 2,
            lo,
            hi,
            self.radius_m * 1e3,
            self.largest_displacement_m * 1e3
        );
        let _ = writeln!(s);
        let _ = writeln!(
            s,
            "| design | mean E (kPa) | mean ν | fitting probes | held-out probes | held-out largest error (mm) |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|");
        for d in &self.designs {
            let mark = if d.design == self.chosen {
                " (exported)"
            } else {
                ""
            };
            let _ = writeln!(
                s,
                "| {}{} | {:.1} | {:.3} | {:.1} % | {:.1} % | {:.3} |",
                d.design,
                mark,
                d.mean_young_pa / 1e3,
                d.mean_poisson,
                100.0 * d.fitted_relative,
                100.0 * d.held_out_relative,
                d.held_out_max_m * 1e3
            );
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(quadratic: f64, linear: f64) -> ConvergedModulus {
        ConvergedModulus {
            design: "P2".into(),
            poisson: 0.49,
            shear_modulus_pa: quadratic,
            mesh_shear_modulus_pa: linear,
        }
    }

    /// The match is made exactly where the mesh-convergence check calls the modulus the mesh's:
    /// the beam's 86.0 / 44.7 kPa, not a 4 % difference either way.
    #[test]
    fn the_match_is_needed_where_the_check_says_not_converged() {
        assert!(needed(&record(86_004.0, 44_726.0)));
        assert!(!needed(&record(104.0, 100.0)));
        assert!(!needed(&record(96.0, 100.0)));
        assert!(needed(&record(106.0, 100.0)));
    }

    /// A match that cannot be made (here a record whose material is no material: μ < 0 on
    /// quadratic elements) is an error where the export was asked for, and where it is a
    /// by-product the fit's own moduli are exported instead, not the work before it lost.
    #[test]
    fn a_match_that_cannot_be_made_falls_back_to_the_fits_own_moduli() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let ds = palpate_motion::dataset::load(&root.join("models/motion-example"))
            .expect("the example's motion dataset");
        let mat = palpate_motion::model::Material::uniform(
            ds.mesh.tets.len(),
            8_000.0,
            2_000.0,
            0.0,
            1.0,
            1_000.0,
        );
        let bad = record(-4_000.0, 2_000.0);
        assert!(needed(&bad));
        let err = export_parameters(&ds, &mat, Some(&bad))
            .unwrap_err()
            .to_string();
        assert!(err.contains("shear modulus -4e3 Pa"), "{err}");
        let (params, matched) = export_parameters_or_own(&ds, &mat, Some(&bad));
        assert!(matched.is_none());
        assert_eq!(params, palpate_motion::export::runtime_parameters(&mat));
    }
}
