//! A scan dataset fitted: its scans registered when it asks for it ([`Register`],
//! [`fit_fixed_part_registered`]), μ (E = 2μ(1 + ν)) of one material to every state's scan at
//! once ([`crate::fit::fit_states`]), then a second material searched for
//! ([`crate::regions`]), and
//! what a person reads of it: the moduli with their σ, each state's residual against its scan's
//! noise, the rest scan's registration, as JSON ([`DatasetFit::to_json`]) and Markdown
//! ([`DatasetFit::report_markdown`]).

use std::fmt::Write as _;

use nalgebra::Vector3;

use crate::dataset::{Register, ScanDataset};
use crate::fit::{fit_states, Design, FitSettings, JointFit, Linearisation, ScanFit, ScanState};
use crate::regions::{search_regions, RegionSearch, ADOPT_DELTA_BIC, MIN_PART_ELEMENTS, MIN_RATIO};
use crate::registration::{register, Registration, RegistrationSettings};
use crate::surface::correspond;
use crate::ScanError;

/// Rounds of the fixed part's registration at most: each registers every scan onto its fixed
/// part at the fitted equilibrium, then fits the modulus again.
pub const REGISTRATION_ROUNDS: usize = 8;
/// The registration has settled when a round moves no node of the object by more than this
/// (m): a hundredth of a millimetre, far below a depth camera's noise.
const REGISTRATION_SETTLED_M: f64 = 1e-5;

/// Each state's scan registered onto its fixed part, alternated with the fit of the modulus:
/// first onto `parts` (each state's fixed part placed as at rest, [`crate::registration::fixed_part_surface`]),
/// then, each round, onto the same triangles at the fitted equilibrium — a band near a clamp
/// bends a little with the load (a hanging strip's top face there tilts by degrees), and a
/// registration onto its rest shape would take that tilt for the camera's — then the modulus
/// fitted again from where it was. Done when a round moves no node of the object by more than
/// 0.01 mm ([`REGISTRATION_ROUNDS`] at most). Returns the states with their scans registered,
/// the fit, each state's registration (the motion from the scan as given) and the rounds.
pub fn fit_fixed_part_registered<'a>(
    states: &[ScanState<'a>],
    parts: &[(Vec<[f64; 3]>, Vec<[usize; 3]>)],
    settings: &FitSettings,
    icp: &RegistrationSettings,
    names: &[String],
) -> Result<(Vec<ScanState<'a>>, JointFit, Vec<Registration>, usize), ScanError> {
    let mut regs = Vec::with_capacity(states.len());
    for ((s, (nodes, tris)), what) in states.iter().zip(parts).zip(names) {
        regs.push(register(&s.scan, nodes, tris, icp, what)?);
    }
    let moved = |regs: &[Registration]| -> Vec<ScanState<'a>> {
        states
            .iter()
            .zip(regs)
            .map(|(s, r)| ScanState {
                scan: r.transform.move_scan(&s.scan),
                ..s.clone()
            })
            .collect()
    };
    let mut registered = moved(&regs);
    let mut fit = fit_states(&registered, settings)?;
    let mut rounds = 0;
    while rounds < REGISTRATION_ROUNDS {
        rounds += 1;
        let mut largest: f64 = 0.0;
        for (i, ((s, (_, tris)), what)) in registered.iter().zip(parts).zip(names).enumerate() {
            let eq = &fit.states[i].equilibrium;
            // The design's nodes begin with the linear mesh's, the triangles' corners.
            let r = register(&s.scan, &eq.positions, tris, icp, what)?;
            let object: Vec<Vector3<f64>> =
                eq.positions.iter().map(|p| Vector3::from(*p)).collect();
            largest = largest.max(r.transform.largest_move(&object));
            regs[i] = Registration {
                transform: r.transform.after(&regs[i].transform),
                ..r
            };
        }
        registered = moved(&regs);
        fit = fit_states(
            &registered,
            &FitSettings {
                starts: vec![fit.mu[0]],
                ..settings.clone()
            },
        )?;
        log::info!(
            "fixed-part registration, round {rounds}: E {:.1} kPa, the scans moved by {:.3} mm at most",
            fit.young_modulus(0) / 1e3,
            1e3 * largest
        );
        if largest < REGISTRATION_SETTLED_M {
            break;
        }
    }
    Ok((registered, fit, regs, rounds))
}

/// Each state's scan registered as `dataset` asks ([`Register`]); empty for
/// [`Register::None`].
pub fn register_scans(
    dataset: &ScanDataset,
    max_distance: f64,
) -> Result<Vec<Registration>, ScanError> {
    let icp = RegistrationSettings {
        max_distance,
        ..RegistrationSettings::default()
    };
    match dataset.register {
        Register::None => Ok(Vec::new()),
        Register::Rest => {
            let rest = dataset.rest.as_ref().ok_or_else(|| {
                ScanError::Invalid("register = \"rest\" without a rest scan".into())
            })?;
            let what = format!("the rest scan ({})", rest.record.source);
            let r = register(
                &rest.points,
                &dataset.mesh.nodes,
                &dataset.mesh.boundary_triangles(),
                &icp,
                &what,
            )?;
            Ok(vec![r; dataset.states.len()])
        }
        Register::FixedPart => {
            let (parts, names) = fixed_parts(dataset)?;
            parts
                .iter()
                .zip(&names)
                .zip(&dataset.states)
                .map(|(((nodes, tris), what), s)| register(&s.scan.points, nodes, tris, &icp, what))
                .collect()
        }
    }
}

/// Each state's fixed part ([`ScanDataset::fixed_part`]) and its name in errors; refused when
/// a state has none.
#[allow(clippy::type_complexity)]
fn fixed_parts(
    dataset: &ScanDataset,
) -> Result<(Vec<(Vec<[f64; 3]>, Vec<[usize; 3]>)>, Vec<String>), ScanError> {
    let mut parts = Vec::new();
    let mut names = Vec::new();
    for (i, s) in dataset.states.iter().enumerate() {
        let what = format!("states[{i}] ({:?}, {})", s.name, s.scan_dir.display());
        let (nodes, tris) = dataset.fixed_part(i);
        if tris.is_empty() {
            return Err(ScanError::Invalid(format!(
                "registering {what}: no surface triangle lies within register_band_m = {} m of its clamped or held nodes; expected some: widen the band",
                dataset.register_band_m
            )));
        }
        parts.push((nodes, tris));
        names.push(what);
    }
    Ok((parts, names))
}

/// How a dataset is fitted.
#[derive(Debug, Clone)]
pub struct DatasetFitOptions {
    /// P2 (the default: linear tetrahedra lock in bending near incompressibility) or P1.
    pub design: Design,
    /// Search for a second material.
    pub regions: bool,
    /// Trial Young's moduli (Pa); the fit starts from the one nearest the scans.
    pub start_young: Vec<f64>,
    /// Gauss–Newton iterations at most.
    pub max_iter: usize,
}

impl Default for DatasetFitOptions {
    fn default() -> Self {
        Self {
            design: Design::Quadratic,
            regions: true,
            // Silicones span about 10 kPa to 3 MPa: trials a factor 2 apart over that range, so
            // one lies within √2 of any modulus there. From a start 3× off, the closest points
            // pair the scan's faces with the wrong faces of the model and Gauss–Newton settles
            // where they lead (a strip of 300 kPa started at 1 MPa: 683 kPa).
            start_young: (0..9).map(|k| 1e4 * 2f64.powi(k)).collect(),
            max_iter: 30,
        }
    }
}

/// One state's residual at the fit.
#[derive(Debug, Clone)]
pub struct StateSummary {
    /// Its name.
    pub name: String,
    /// Points in its scan.
    pub points: usize,
    /// Points with a robust weight.
    pub used: usize,
    /// RMS signed distance of those points to the fitted surface (m).
    pub rms_m: f64,
    /// The scan's noise floor: RMS of those points' σ along their normals (m).
    pub noise_m: f64,
}

impl StateSummary {
    fn of(name: &str, points: usize, l: &Linearisation) -> Self {
        let used: Vec<_> = l.residuals.iter().filter(|r| r.weight > 0.0).collect();
        let noise =
            (used.iter().map(|r| r.sigma * r.sigma).sum::<f64>() / used.len().max(1) as f64).sqrt();
        Self {
            name: name.into(),
            points,
            used: used.len(),
            rms_m: l.rms_distance(),
            noise_m: noise,
        }
    }

    /// RMS residual over the noise floor: near 1 when the model explains the scan.
    pub fn ratio(&self) -> f64 {
        self.rms_m / self.noise_m
    }
}

/// The rest scan against the rest mesh: how well the scans are registered to the mesh.
#[derive(Debug, Clone, Copy)]
pub struct RestCheck {
    /// Points in the rest scan.
    pub points: usize,
    /// Points within the search radius of the rest surface.
    pub matched: usize,
    /// Their median |distance| (m).
    pub median_m: f64,
    /// The scan's median σ (m).
    pub noise_m: f64,
}

/// A scan dataset fitted.
#[derive(Debug, Clone)]
pub struct DatasetFit {
    /// The element design.
    pub design: Design,
    /// Poisson's ratio held.
    pub poisson: f64,
    /// Whether it was declared (else the silicone default).
    pub poisson_declared: bool,
    /// The one-material fit.
    pub single: JointFit,
    /// The search for a second material, if asked for.
    pub search: Option<RegionSearch>,
    /// Each state's residual at the fit reported (the split's when adopted).
    pub states: Vec<StateSummary>,
    /// The rest scan's check, if there is one.
    pub rest: Option<RestCheck>,
    /// Elements in the mesh.
    pub elements: usize,
    /// How the scans were registered, unless they were declared in the mesh's frame.
    pub registration: Option<DatasetRegistration>,
}

/// Fits `dataset` (module doc); progress goes to the log.
pub fn fit_dataset(
    dataset: &ScanDataset,
    options: &DatasetFitOptions,
) -> Result<DatasetFit, ScanError> {
    let (lo, hi) = dataset.mesh.bounds();
    let diagonal = Vector3::from(hi) - Vector3::from(lo);
    let settings = FitSettings {
        starts: options
            .start_young
            .iter()
            .map(|e| e / (2.0 * (1.0 + dataset.poisson)))
            .collect(),
        // A quarter of the object's size: beyond a start's misfit, short of its other side.
        max_distance: 0.25 * diagonal.norm(),
        max_iter: options.max_iter,
    };
    // A millionth of the object's weight: far below what a scan resolves, above round-off.
    let tol = 1e-6 * dataset.weight().max(1e-9);
    let mut states = dataset.scan_states(options.design, tol);
    log::info!(
        "fitting E on {} ({} tets) to {} state(s), ν = {}{}",
        options.design.name(),
        dataset.mesh.tets.len(),
        states.len(),
        dataset.poisson,
        if dataset.poisson_declared {
            ""
        } else {
            " (not declared: a silicone's)"
        }
    );
    let icp = RegistrationSettings {
        max_distance: settings.max_distance,
        ..RegistrationSettings::default()
    };
    let (single, registrations, rounds) = match dataset.register {
        Register::FixedPart => {
            let (parts, names) = fixed_parts(dataset)?;
            let (registered, fit, regs, rounds) =
                fit_fixed_part_registered(&states, &parts, &settings, &icp, &names)?;
            states = registered;
            (fit, regs, rounds)
        }
        _ => {
            let regs = register_scans(dataset, settings.max_distance)?;
            for (s, r) in states.iter_mut().zip(&regs) {
                s.scan = r.transform.move_scan(&s.scan);
            }
            (fit_states(&states, &settings)?, regs, 0)
        }
    };
    for (r, d) in registrations.iter().zip(&dataset.states) {
        log::info!(
            "{}: registered ({}) by {:.3}°, RMS {:.3} mm on {} of {} points, {} of 6 directions pinned",
            d.scan_dir.display(),
            dataset.register.name(),
            r.transform.angle_deg(),
            1e3 * r.rms_m,
            r.used,
            r.points,
            r.pinned
        );
    }
    log::info!(
        "one material: E {:.1} kPa ± {:.2} %",
        single.young_modulus(0) / 1e3,
        100.0 * single.sigma_ln_mu(0)
    );
    let search = if options.regions {
        log::info!("searching for a second material");
        Some(search_regions(&states, &single, &settings)?)
    } else {
        None
    };
    let reported = match &search {
        Some(s) if s.adopted => &s.best.as_ref().expect("adopted implies a best").fit,
        _ => &single,
    };
    let summaries = reported
        .states
        .iter()
        .zip(&states)
        .map(|(l, s)| StateSummary::of(&s.name, s.scan.points.len(), l))
        .collect();
    let rest = dataset.rest.as_ref().map(|scan| {
        let tris = dataset.mesh.boundary_triangles();
        let points = match (dataset.register, registrations.first()) {
            (Register::Rest, Some(r)) => r.transform.move_scan(&scan.points).points,
            _ => scan.points.points.clone(),
        };
        let (found, _) = correspond(&dataset.mesh.nodes, &tris, &points, settings.max_distance);
        let mut d: Vec<f64> = found.iter().map(|c| c.distance.abs()).collect();
        let mut s = scan.points.sigma.clone();
        RestCheck {
            points: scan.points.points.len(),
            matched: d.len(),
            median_m: median(&mut d),
            noise_m: median(&mut s),
        }
    });
    Ok(DatasetFit {
        design: options.design,
        poisson: dataset.poisson,
        poisson_declared: dataset.poisson_declared,
        single,
        search,
        states: summaries,
        rest,
        elements: dataset.mesh.tets.len(),
        registration: (dataset.register != Register::None).then(|| {
            let nodes: Vec<Vector3<f64>> = dataset
                .mesh
                .nodes
                .iter()
                .map(|p| Vector3::from(*p))
                .collect();
            DatasetRegistration {
                mode: dataset.register,
                band_m: dataset.register_band_m,
                states: registrations
                    .iter()
                    .map(|r| StateRegistration {
                        registration: *r,
                        largest_move_m: r.transform.largest_move(&nodes),
                    })
                    .collect(),
                rounds,
            }
        }),
    })
}

/// How the scans were brought into the mesh's frame.
#[derive(Debug, Clone)]
pub struct DatasetRegistration {
    /// As `scans.toml` asks.
    pub mode: Register,
    /// The fixed part's band (m).
    pub band_m: f64,
    /// Each state's.
    pub states: Vec<StateRegistration>,
    /// Rounds of the fixed part's registration alternated with the fit (0 for the rest's).
    pub rounds: usize,
}

/// One state's registration.
#[derive(Debug, Clone, Copy)]
pub struct StateRegistration {
    /// Onto the fixed part (or the rest mesh).
    pub registration: Registration,
    /// The largest distance the registration moves a node of the rest mesh (m).
    pub largest_move_m: f64,
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mid = v.len() / 2;
    v.select_nth_unstable_by(mid, f64::total_cmp);
    v[mid]
}

impl DatasetFit {
    /// The fit reported: the adopted split's, else the one material's.
    pub fn reported(&self) -> &JointFit {
        match &self.search {
            Some(s) if s.adopted => &s.best.as_ref().expect("adopted implies a best").fit,
            _ => &self.single,
        }
    }

    /// State `i`'s residual at the reported fit, in the shape the residual's VTU writer takes.
    pub fn state_fit(&self, i: usize) -> ScanFit {
        let f = self.reported();
        ScanFit {
            mu: f.mu[0],
            young_modulus: f.young_modulus(0),
            iterations: f.iterations,
            at_fit: f.states[i].clone(),
        }
    }

    /// The noise floor over every state: RMS of the used points' σ (m).
    pub fn noise_m(&self) -> f64 {
        let (s2, n) = self.states.iter().fold((0.0, 0), |(a, b), s| {
            (a + s.noise_m * s.noise_m * s.used as f64, b + s.used)
        });
        (s2 / n.max(1) as f64).sqrt()
    }

    /// The RMS residual over every state (m).
    pub fn rms_m(&self) -> f64 {
        let (s2, n) = self.states.iter().fold((0.0, 0), |(a, b), s| {
            (a + s.rms_m * s.rms_m * s.used as f64, b + s.used)
        });
        (s2 / n.max(1) as f64).sqrt()
    }

    /// `fit.json` (docs/scan-dataset.md).
    pub fn to_json(&self) -> serde_json::Value {
        let s = &self.single;
        let states: Vec<_> = self
            .states
            .iter()
            .map(|st| {
                serde_json::json!({
                    "name": st.name, "points": st.points, "used": st.used,
                    "rms_m": st.rms_m, "noise_m": st.noise_m, "rms_over_noise": st.ratio(),
                })
            })
            .collect();
        let second = self.search.as_ref().map(|r| {
            let best = r.best.as_ref().map(|b| {
                serde_json::json!({
                    "split": b.split.label, "plane_normal": b.split.normal,
                    "plane_point_m": b.split.point, "fraction": b.split.fraction,
                    "elements": b.split.elements,
                    "second_part_bounds_m": [b.split.second_bounds.0, b.split.second_bounds.1],
                    "young_modulus_pa": [b.fit.young_modulus(0), b.fit.young_modulus(1)],
                    "sigma_young_modulus_pa": [
                        b.fit.young_modulus(0) * b.fit.sigma_ln_mu(0),
                        b.fit.young_modulus(1) * b.fit.sigma_ln_mu(1)
                    ],
                    "ratio": b.ratio, "sigma_ratio": b.ratio_sigma,
                    "bic_one_material": b.bic_single, "bic_two_materials": b.bic_split,
                    "delta_bic": b.delta_bic(),
                })
            });
            serde_json::json!({
                "adopted": r.adopted, "points": r.points,
                "rule": format!("ΔBIC < {ADOPT_DELTA_BIC}, ≥ {MIN_PART_ELEMENTS} elements per part, E₂/E₁ beyond {MIN_RATIO} or its inverse"),
                "best": best,
                "screened": r.screened.iter().map(|(l, g)| serde_json::json!({"split": l, "predicted_cost_fall": g})).collect::<Vec<_>>(),
            })
        });
        serde_json::json!({
            "schema_version": 1,
            "kind": "scan fit",
            "design": self.design.name(),
            "elements": self.elements,
            "poisson": self.poisson,
            "poisson_declared": self.poisson_declared,
            "young_modulus_pa": s.young_modulus(0),
            "mu_pa": s.mu[0],
            "sigma_young_modulus_pa": s.young_modulus(0) * s.sigma_ln_mu(0),
            "iterations": s.iterations,
            "second_material": second,
            "states": states,
            "rms_m": self.rms_m(),
            "noise_m": self.noise_m(),
            "rms_over_noise": self.rms_m() / self.noise_m(),
            "registration": self.registration.as_ref().map(|r| r.to_json(&self.states)),
            "rest_scan": self.rest.map(|r| serde_json::json!({
                "points": r.points, "matched": r.matched, "median_distance_m": r.median_m,
                "median_sigma_m": r.noise_m,
            })),
        })
    }

    /// `report.md`: what a person reads; `figure` is the residual histogram's file name, `maps`
    /// each state's residual map's (`None` where it was not drawn).
    pub fn report_markdown(&self, dataset: &str, figure: &str, maps: &[Option<String>]) -> String {
        let s = &self.single;
        let mut o = String::new();
        let _ = writeln!(o, "# Scan fit: {dataset}\n");
        let _ = writeln!(
            o,
            "One material, {} tetrahedra ({} elements), ν = {}{} held, every state at once:\n",
            self.design.name(),
            self.elements,
            self.poisson,
            if self.poisson_declared {
                ""
            } else {
                " (not declared: a silicone's default)"
            }
        );
        let _ = writeln!(
            o,
            "- **E = {:.1} kPa ± {:.1} kPa** (1σ, Gauss–Newton covariance scaled by the residual; μ = {:.1} kPa), {} iterations",
            s.young_modulus(0) / 1e3,
            s.young_modulus(0) * s.sigma_ln_mu(0) / 1e3,
            s.mu[0] / 1e3,
            s.iterations
        );
        match &self.search {
            None => {
                let _ = writeln!(o, "- A second material was not searched for.");
            }
            Some(r) => match &r.best {
                None => {
                    let _ = writeln!(o, "- No split into two parts could be fitted.");
                }
                Some(b) => {
                    let (lo, hi) = b.split.second_bounds;
                    let mm = |v: [f64; 3]| {
                        format!("({:.1}, {:.1}, {:.1})", 1e3 * v[0], 1e3 * v[1], 1e3 * v[2])
                    };
                    let _ = writeln!(
                        o,
                        "- Second material: **{}**. Best split: {} ({} / {} elements; part 2 spans {} to {} mm): E {:.1} / {:.1} kPa, ratio E₂/E₁ = {:.3} ± {:.3}, ΔBIC = {:.1} (adopted when < {ADOPT_DELTA_BIC} with ≥ {MIN_PART_ELEMENTS} elements per part and a ratio beyond {MIN_RATIO} or its inverse).",
                        if r.adopted { "found" } else { "not found" },
                        b.split.label,
                        b.split.elements[0],
                        b.split.elements[1],
                        mm(lo),
                        mm(hi),
                        b.fit.young_modulus(0) / 1e3,
                        b.fit.young_modulus(1) / 1e3,
                        b.ratio,
                        b.ratio_sigma,
                        b.delta_bic()
                    );
                }
            },
        }
        let _ = writeln!(
            o,
            "\nThe residual at the {} fit, per state (points with a robust weight; the noise floor is their σ along the normals):\n",
            if self.search.as_ref().is_some_and(|r| r.adopted) {
                "two-material"
            } else {
                "one-material"
            }
        );
        let _ = writeln!(
            o,
            "| state | points | used | RMS (mm) | noise (mm) | RMS / noise |"
        );
        let _ = writeln!(o, "|---|---|---|---|---|---|");
        for st in &self.states {
            let _ = writeln!(
                o,
                "| {} | {} | {} | {:.3} | {:.3} | {:.2} |",
                st.name,
                st.points,
                st.used,
                1e3 * st.rms_m,
                1e3 * st.noise_m,
                st.ratio()
            );
        }
        if let Some(r) = &self.registration {
            r.report_markdown(&mut o, &self.states);
        }
        if let Some(r) = &self.rest {
            let _ = writeln!(
                o,
                "\nRest scan against the rest mesh: {} of {} points within reach, median distance {:.3} mm (median σ {:.3} mm){}.",
                r.matched,
                r.points,
                1e3 * r.median_m,
                1e3 * r.noise_m,
                if r.median_m > 3.0 * r.noise_m {
                    " — well above the noise: check the scans' registration to the mesh"
                } else {
                    ""
                }
            );
        }
        let _ = writeln!(
            o,
            "\nAn RMS near the noise floor means the model explains the scans; well above it, a part of the object the model does not describe (look where in `<state>-surface.vtu`, `mean_residual_m`).\n\n![residual]({figure})"
        );
        let drawn: Vec<_> = self
            .states
            .iter()
            .zip(maps)
            .filter_map(|(st, m)| Some((st, m.as_ref()?)))
            .collect();
        if !drawn.is_empty() {
            let _ = writeln!(
                o,
                "\nWhere on the object the residual sits, per state (the fitted surface seen along the rest mesh's thinnest axis, each triangle coloured by the mean signed distance of the points nearest it; red: the scan lies outside the model):\n"
            );
            for (st, m) in drawn {
                let _ = writeln!(o, "- {}: [{m}]({m})", st.name);
            }
        }
        o
    }

    /// Every state's scaled residual d/σ of the points with a weight, at the reported fit.
    pub fn scaled_residuals(&self) -> Vec<f64> {
        self.reported()
            .states
            .iter()
            .flat_map(|l| {
                l.residuals
                    .iter()
                    .filter(|r| r.weight > 0.0)
                    .map(|r| r.scaled())
            })
            .collect()
    }
}

fn mm(v: Vector3<f64>) -> [f64; 3] {
    [1e3 * v.x, 1e3 * v.y, 1e3 * v.z]
}

impl DatasetRegistration {
    /// `registration` of `fit.json` (docs/scan-dataset.md).
    fn to_json(&self, states: &[StateSummary]) -> serde_json::Value {
        let per_state: Vec<_> = self
            .states
            .iter()
            .zip(states)
            .map(|(r, st)| {
                let t = &r.registration;
                serde_json::json!({
                    "name": st.name,
                    "angle_deg": t.transform.angle_deg(),
                    "translation_mm": mm(t.transform.translation),
                    "largest_move_mm": 1e3 * r.largest_move_m,
                    "rms_m": t.rms_m, "used": t.used, "points": t.points,
                    "pinned_directions": t.pinned, "iterations": t.iterations,
                })
            })
            .collect();
        serde_json::json!({
            "mode": self.mode.name(),
            "band_m": self.band_m,
            "rounds": self.rounds,
            "states": per_state,
        })
    }

    /// The registration's section of `report.md`.
    fn report_markdown(&self, o: &mut String, states: &[StateSummary]) {
        let _ = writeln!(
            o,
            "\nThe scans were registered to the mesh ({}); per state, the motion found (its angle, how far it moves a node of the rest mesh at most), the RMS distance to the target of the points used, and the directions of the six the target pins (the others left as declared):\n",
            match self.mode {
                Register::Rest => "the rest scan onto the rest mesh, its motion applied to every scan".to_string(),
                _ => format!(
                    "each scan onto the surface within {:.1} mm of its clamped and held nodes, at the fitted equilibrium, alternated with the fit: {} round(s)",
                    1e3 * self.band_m,
                    self.rounds
                ),
            }
        );
        let _ = writeln!(
            o,
            "| state | angle (°) | largest move (mm) | RMS (mm) | points used | directions pinned |"
        );
        let _ = writeln!(o, "|---|---|---|---|---|---|");
        for (r, st) in self.states.iter().zip(states) {
            let _ = writeln!(
                o,
                "| {} | {:.3} | {:.3} | {:.3} | {} of {} | {} |",
                st.name,
                r.registration.transform.angle_deg(),
                1e3 * r.largest_move_m,
                1e3 * r.registration.rms_m,
                r.registration.used,
                r.registration.points,
                r.registration.pinned
            );
        }
    }
}
