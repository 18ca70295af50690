//! The scan room's model fitted: the moduli (one material, or two on a split) through
//! [`palpate_scan::fit`], with the nuisances of the scans — each scan's rigid motion (a camera
//! moved between scans) and the depth camera's bias along its rays — fitted together with them,
//! its evidence on the points held out, and the mesh's own discretisation error held as a
//! correction.
//!
//! - **Held out**: each scan's points are split by a checkerboard of cubes of a sixth of the
//!   object's longest side ([`BLOCKS`]) in the mesh's frame: the fit sees the points of the even
//!   cubes, the odd ones are predicted. A cube is larger than what a nuisance or a split can
//!   bend locally (an element or two), so a candidate that only fits the points it saw gains
//!   nothing on the others.
//! - **Nuisances**: a depth bias b moves each point along its camera ray, p ↦ p − b u with u =
//!   (p − c)/z (c the camera's centre, z the point's depth: b is in depth units); a camera moved
//!   is a small turn ω about the scan's centre and a shift t per scan, p ↦ p + t + ω × (p −
//!   centre). Both enter one Gauss–Newton with ln μ ([`Problem::fit`]): the moduli's columns of J from
//!   the solver's sensitivity, the nuisances' from the points' motion along the normal at their
//!   closest points, JᵀΩJ with the fit's Tukey weights held per iteration, a step over 1 % in ln
//!   μ line-searched on the weighted cost. It stops when a step is a tenth of a standard
//!   deviation in the joint metric (δᵀJᵀΩJδ over the residual's variance below 0.01). The
//!   moduli's covariance is the joint one's block: a scan free to turn about its clamp takes up
//!   part of the sag, and the modulus' σ says so. A registration onto the clamped part alone
//!   (what `register = "fixed-part"` starts from) rests on the few points near a clamp: on a
//!   strip's scans it moved them by a quarter of a millimetre where the camera had not moved.
//! - **The mesh's own error** ([`Problem::mesh_error`]): each state solved again on the mesh
//!   refined once; the difference at the design's nodes is added to every later equilibrium,
//!   measured again when a second material is adopted.
//! - **Score**: χ² = Σ min(rᵢ², [`CAP`]²) over the points with a surface within the search
//!   radius, rᵢ the signed distance over the noise along the normal: a truncated square, so that
//!   the background (the clamp, the table) counts the same under every model and the fit's own
//!   Tukey weights (which differ between models) do not enter the comparison.

use nalgebra::{DMatrix, DVector, Vector3};
use palpate_scan::dataset::ScanDataset;
use palpate_scan::fit::{
    fit_states, fit_states_from, linearise, residuals, state_omegas, weighted_cost, Design,
    FitSettings, JointFit, Linearisation, ScanPoints, ScanState,
};
use palpate_scan::regions::Split;
use palpate_scan::registration::{register, RegistrationSettings, RigidTransform};
use palpate_scan::ScanError;

use super::Effect;

/// A cube of the held-out checkerboard is this fraction of the object's longest side.
pub const BLOCKS: f64 = 1.0 / 6.0;
/// A step that moves no point by more than this (m), with one below 1e-4 in ln μ, ends the fit.
const SETTLED_M: f64 = 1e-5;
/// A step below this in ln μ, with the nuisances moving no point by more than [`SMALL_MOVE_M`],
/// is taken without a line search: Gauss–Newton converges there, and what it gains falls below
/// the jumps of the cost where closest points switch triangles (as in `palpate_scan::fit`).
const SMALL_STEP: f64 = 1e-2;
/// See [`SMALL_STEP`] (m).
const SMALL_MOVE_M: f64 = 2e-5;
/// The truncation of the score's square, in noise σ.
pub const CAP: f64 = 5.0;

/// One state's points, fitted and held out, with what fits them.
#[derive(Debug, Clone)]
pub struct Problem<'a> {
    /// The dataset.
    pub dataset: &'a ScanDataset,
    /// Each state with its fitted points (the even cubes), as the dataset registers them.
    pub states: Vec<ScanState<'a>>,
    /// Each state's held-out points (the odd cubes).
    pub held: Vec<ScanPoints>,
    /// Each state's clamped and held part at rest (nodes, triangles), for a camera moved; `None`
    /// when a state's part has no surface triangle.
    pub parts: Option<Vec<(Vec<[f64; 3]>, Vec<[usize; 3]>)>>,
    /// The modulus fit's settings.
    pub settings: FitSettings,
    /// The registration's.
    pub icp: RegistrationSettings,
    /// Each state's correction for the mesh's own discretisation error ([`Self::mesh_error`]),
    /// held in every fit once set, and measured again when an adopted effect changes the
    /// object's field (a second material).
    pub correction: std::cell::RefCell<Option<Vec<Vec<[f64; 3]>>>>,
}

/// The dataset mesh's discretisation error at a fitted model: each state's equilibrium on the
/// mesh refined once, against the mesh's own.
#[derive(Debug, Clone)]
pub struct MeshError {
    /// Per state and design node, the refined equilibrium's position minus the mesh's (m).
    pub offsets: Vec<Vec<[f64; 3]>>,
    /// RMS change of the weighted points' signed distances it makes (m).
    pub rms_m: f64,
    /// Their noise floor (m).
    pub noise_m: f64,
    /// Elements of the refined mesh.
    pub elements: usize,
}

/// The scans' nuisances.
#[derive(Debug, Clone, PartialEq)]
pub struct Nuisance {
    /// Each state's scan moved by this (identity unless a camera moved is in the model).
    pub rigid: Vec<RigidTransform>,
    /// Depth bias (m, along each ray in depth units; 0 unless in the model).
    pub bias_m: f64,
    /// Depth scale error (relative: a depth read (1 + s) × too far; 0 unless in the model).
    pub scale: f64,
}

/// A fitted model of the scans.
#[derive(Debug, Clone)]
pub struct ScanModel {
    /// Effects in it, in the order adopted.
    pub effects: Vec<Effect>,
    /// The split of a second material.
    pub split: Option<Split>,
    /// The moduli at the fitted points, the scans corrected by [`Self::nuisance`].
    pub fit: JointFit,
    /// The nuisances fitted.
    pub nuisance: Nuisance,
    /// σ of the depth bias (m), from the joint Gauss–Newton covariance.
    pub bias_sd_m: f64,
    /// σ of the depth scale (relative), from the same.
    pub scale_sd: f64,
    /// Gauss–Newton iterations of the moduli with the nuisances (0 without nuisances).
    pub iterations: usize,
    /// The fitted points' score.
    pub score: Evidence,
}

/// The score of a model on a set of points ([`CAP`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Evidence {
    /// Σ min(r², CAP²) over the points with a surface near.
    pub chi2: f64,
    /// Those points.
    pub n: usize,
    /// RMS signed distance (m) of the points the robust weights keep (as `fit-scan` reports).
    pub rms_m: f64,
    /// RMS noise along the normal (m) of the same points.
    pub noise_m: f64,
}

impl Evidence {
    /// RMS over the noise floor: near 1 when the model explains the points.
    pub fn ratio(&self) -> f64 {
        self.rms_m / self.noise_m
    }

    /// √(χ²/n): the truncated residual's RMS in noise σ.
    pub fn scaled_rms(&self) -> f64 {
        (self.chi2 / self.n.max(1) as f64).sqrt()
    }

    fn add(self, o: Self) -> Self {
        let used = |e: &Self| e.n as f64;
        let w = (used(&self) + used(&o)).max(1.0);
        Self {
            chi2: self.chi2 + o.chi2,
            n: self.n + o.n,
            rms_m: ((self.rms_m.powi(2) * used(&self) + o.rms_m.powi(2) * used(&o)) / w).sqrt(),
            noise_m: ((self.noise_m.powi(2) * used(&self) + o.noise_m.powi(2) * used(&o)) / w)
                .sqrt(),
        }
    }

    fn empty() -> Self {
        Self {
            chi2: 0.0,
            n: 0,
            rms_m: 0.0,
            noise_m: 0.0,
        }
    }
}

fn subset(scan: &ScanPoints, keep: &[bool], want: bool) -> ScanPoints {
    let pick = |i: &usize| keep[*i] == want;
    ScanPoints {
        points: (0..scan.points.len())
            .filter(pick)
            .map(|i| scan.points[i])
            .collect(),
        sigma: (0..scan.points.len())
            .filter(pick)
            .map(|i| scan.sigma[i])
            .collect(),
        camera: scan.camera,
    }
}

impl<'a> Problem<'a> {
    /// The dataset's states on `design`, their scans registered as `scans.toml` asks (a
    /// fixed-part registration is the model's [`Effect::CameraMoved`] instead) and split into
    /// fitted and held-out points; `start_young` the trial moduli (Pa).
    pub fn new(
        dataset: &'a ScanDataset,
        design: Design,
        start_young: &[f64],
        max_iter: usize,
    ) -> Result<Self, ScanError> {
        let (lo, hi) = dataset.mesh.bounds();
        let extent = Vector3::from(hi) - Vector3::from(lo);
        let settings = FitSettings {
            starts: start_young
                .iter()
                .map(|e| e / (2.0 * (1.0 + dataset.poisson)))
                .collect(),
            max_distance: 0.25 * extent.norm(),
            max_iter,
        };
        let icp = RegistrationSettings {
            max_distance: settings.max_distance,
            ..RegistrationSettings::default()
        };
        let tol = 1e-6 * dataset.weight().max(1e-9);
        let mut states = dataset.scan_states(design, tol);
        if dataset.register == palpate_scan::dataset::Register::Rest {
            let regs = palpate_scan::dataset_fit::register_scans(dataset, settings.max_distance)?;
            for (s, r) in states.iter_mut().zip(&regs) {
                s.scan = r.transform.move_scan(&s.scan);
            }
        }
        let cube = BLOCKS * extent.max();
        let mut held = Vec::with_capacity(states.len());
        for s in &mut states {
            let odd: Vec<bool> = s
                .scan
                .points
                .iter()
                .map(|p| {
                    let c = (p - Vector3::from(lo)) / cube;
                    (c.x.floor() + c.y.floor() + c.z.floor()).rem_euclid(2.0) == 1.0
                })
                .collect();
            held.push(subset(&s.scan, &odd, true));
            s.scan = subset(&s.scan, &odd, false);
        }
        let parts: Vec<_> = (0..states.len()).map(|i| dataset.fixed_part(i)).collect();
        let parts = parts.iter().all(|(_, t)| !t.is_empty()).then_some(parts);
        Ok(Self {
            dataset,
            states,
            held,
            parts,
            settings,
            icp,
            correction: std::cell::RefCell::new(None),
        })
    }

    /// The mesh's discretisation error at `model` (which must have been fitted without a
    /// correction): every state solved again on the mesh refined once, its design nodes found
    /// among the refined design's by their rest places (a P2 design's nodes are the corners and
    /// edge midpoints, the refined mesh's corners), and the change it makes to the distances of
    /// the points the fit weighs. The offsets estimate the error of the mesh against the
    /// refined one, ≈ 3/4 of its error against the converged solution when the displacements
    /// converge as O(h²).
    pub fn mesh_error(&self, model: &ScanModel) -> Result<MeshError, ScanError> {
        let (fine, mid) = palpate_fem::mesh::refine::refine_with_midpoints(&self.dataset.mesh);
        let states = self.states_with(model.split.as_ref(), &model.nuisance);
        let mut offsets = Vec::with_capacity(states.len());
        let (mut sum, mut count, mut noise) = (0.0, 0usize, 0.0);
        for (i, s) in states.iter().enumerate() {
            let mut coarse = s.object.clone();
            coarse.offset.clear();
            let eq = coarse.equilibrium_at(&model.fit.mu, false)?;
            let refined = coarse.refined(&fine, &mid);
            let eq_fine = refined.equilibrium_at(&model.fit.mu, false)?;
            let key = |p: &[f64; 3]| p.map(|v| (v * 1e9).round() as i64);
            let place: std::collections::HashMap<[i64; 3], usize> = eq_fine
                .rest
                .iter()
                .enumerate()
                .map(|(k, p)| (key(p), k))
                .collect();
            let offset: Vec<[f64; 3]> = eq
                .rest
                .iter()
                .zip(&eq.positions)
                .map(|(r, x)| {
                    place.get(&key(r)).map_or(
                        Err(ScanError::Invalid(format!(
                            "mesh error, state {:?}: the design node at {r:?} is not a node of \
                             the refined design",
                            s.name
                        ))),
                        |&k| Ok([0, 1, 2].map(|a| eq_fine.positions[k][a] - x[a])),
                    )
                })
                .collect::<Result<_, _>>()?;
            let moved: Vec<[f64; 3]> = eq
                .positions
                .iter()
                .zip(&offset)
                .map(|(x, o)| [0, 1, 2].map(|a| x[a] + o[a]))
                .collect();
            let lin = &model.fit.states[i];
            let weighted: Vec<usize> = lin
                .residuals
                .iter()
                .filter(|r| r.weight > 0.0)
                .map(|r| r.correspondence.point)
                .collect();
            let points: Vec<Vector3<f64>> = weighted.iter().map(|&j| s.scan.points[j]).collect();
            let max = self.settings.max_distance;
            let (before, _) =
                palpate_scan::surface::correspond(&eq.positions, &eq.surface, &points, max);
            let (after, _) = palpate_scan::surface::correspond(&moved, &eq.surface, &points, max);
            let mut d = vec![None; points.len()];
            for c in before {
                d[c.point] = Some(c.distance);
            }
            for c in after {
                if let Some(b) = d[c.point] {
                    sum += (c.distance - b).powi(2);
                    count += 1;
                }
            }
            noise += lin
                .residuals
                .iter()
                .filter(|r| r.weight > 0.0)
                .map(|r| r.sigma * r.sigma)
                .sum::<f64>();
            offsets.push(offset);
        }
        let used: usize = model
            .fit
            .states
            .iter()
            .map(|l| l.residuals.iter().filter(|r| r.weight > 0.0).count())
            .sum();
        Ok(MeshError {
            offsets,
            rms_m: (sum / count.max(1) as f64).sqrt(),
            noise_m: (noise / used.max(1) as f64).sqrt(),
            elements: fine.tets.len(),
        })
    }

    /// Why `effect` cannot be fitted to these scans, if it cannot.
    pub fn not_identifiable(&self, effect: Effect) -> Option<String> {
        match effect {
            Effect::SecondMaterial => None,
            Effect::CameraMoved => self.parts.is_none().then(|| {
                format!(
                    "not identifiable: a state's clamped or held part has no surface within \
                     register_band_m = {} m to register its scan on",
                    self.dataset.register_band_m
                )
            }),
            Effect::DepthBias | Effect::DepthScale => {
                self.states
                    .iter()
                    .find(|s| s.scan.camera.is_none())
                    .map(|s| {
                        format!(
                        "not identifiable: the scan of state {:?} has no camera (a point cloud); \
                         a depth {} lies along a camera's rays",
                        s.name,
                        if effect == Effect::DepthBias { "bias" } else { "scale" }
                    )
                    })
            }
        }
    }

    /// State `i`'s `scan` corrected by `nz`: debiased along its rays, then moved.
    fn corrected(&self, i: usize, scan: &ScanPoints, nz: &Nuisance) -> ScanPoints {
        let mut s = scan.clone();
        if nz.bias_m != 0.0 || nz.scale != 0.0 {
            if let Some(c) = &scan.camera {
                for p in &mut s.points {
                    // A depth read b too far, or (1 + s) × too far: the point lies b u, or
                    // s (p − c), beyond where it is along its ray.
                    *p -= nz.bias_m * ray(c, *p) + nz.scale * (*p - c.pose.translation);
                }
            }
        }
        nz.rigid[i].move_scan(&s)
    }

    pub(crate) fn states_with(&self, split: Option<&Split>, nz: &Nuisance) -> Vec<ScanState<'a>> {
        self.states
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let mut s = s.clone();
                s.scan = self.corrected(i, &s.scan, nz);
                s.object.regions = split.map(|p| p.regions.clone()).unwrap_or_default();
                if let Some(c) = self.correction.borrow().as_ref() {
                    s.object.offset = c[i].clone();
                }
                s
            })
            .collect()
    }

    /// Fits the model of `effects` (a second material on `split`) from `start`: ln μ and the
    /// nuisances of a fitted model (an effect added to it starts from where it ended: with two
    /// nearly exchangeable nuisances, a depth bias and a camera moved, a start from nothing
    /// settles where the first one fitted takes what the other should), or from the trial
    /// moduli and no nuisance. A dataset that registers onto fixed parts starts each scan
    /// registered onto its part at rest.
    pub fn fit(
        &self,
        effects: &[Effect],
        split: Option<&Split>,
        start: Option<(&[f64], &Nuisance)>,
    ) -> Result<ScanModel, ScanError> {
        let moved = effects.contains(&Effect::CameraMoved);
        let nuisances =
            moved || effects.contains(&Effect::DepthBias) || effects.contains(&Effect::DepthScale);
        let mut nz = start.map_or_else(
            || Nuisance {
                rigid: vec![RigidTransform::identity(); self.states.len()],
                bias_m: 0.0,
                scale: 0.0,
            },
            |(_, n)| n.clone(),
        );
        let theta = start.map(|(t, _)| t);
        // A dataset that registers its scans onto their fixed parts declares a pose known only
        // roughly: each scan starts from its part at rest, as `fit-scan` starts it.
        if moved
            && start.is_none()
            && self.dataset.register == palpate_scan::dataset::Register::FixedPart
        {
            let parts = self.parts.as_ref().ok_or_else(|| {
                ScanError::Invalid(
                    self.not_identifiable(Effect::CameraMoved)
                        .unwrap_or_default(),
                )
            })?;
            for (i, (s, (nodes, tris))) in self.states.iter().zip(parts).enumerate() {
                nz.rigid[i] = register(&s.scan, nodes, tris, &self.icp, &s.name)?.transform;
            }
        }
        let states = self.states_with(split, &nz);
        let (fit, nz, [bias_sd_m, scale_sd], iterations) = if nuisances {
            self.joint(&states, effects, split, theta.map(<[f64]>::to_vec), nz)?
        } else {
            let fit = match theta {
                Some(t) => fit_states_from(&states, &self.settings, t)?,
                None => fit_states(&states, &self.settings)?,
            };
            (fit, nz, [f64::NAN; 2], 0)
        };
        let score = self.evidence(&fit, &nz, |i| &self.states[i].scan);
        Ok(ScanModel {
            effects: effects.to_vec(),
            split: split.cloned(),
            fit,
            nuisance: nz,
            bias_sd_m,
            scale_sd,
            iterations,
            score,
        })
    }

    /// The moduli and the nuisances of `effects` fitted together by Gauss–Newton (module doc),
    /// from ln μ `theta` (the trial moduli's best when `None`) and the nuisances `nz`. Returns
    /// the fit (its covariance the moduli's block of the joint one), the nuisances, σ of the
    /// depth bias and scale, and the iterations.
    fn joint(
        &self,
        states: &[ScanState<'a>],
        effects: &[Effect],
        split: Option<&Split>,
        theta: Option<Vec<f64>>,
        mut nz: Nuisance,
    ) -> Result<(JointFit, Nuisance, [f64; 2], usize), ScanError> {
        let mut theta = match theta {
            Some(t) => t,
            None => fit_states(states, &self.settings)?
                .mu
                .iter()
                .map(|m| m.ln())
                .collect(),
        };
        let k = theta.len();
        let lay = Layout::of(k, effects, states);
        let max = self.settings.max_distance;
        let linearise_all = |theta: &[f64], nz: &Nuisance| -> Result<_, ScanError> {
            self.states_with(split, nz)
                .iter()
                .map(|s| linearise(&s.object, &s.scan, theta, max))
                .collect::<Result<Vec<_>, _>>()
        };
        let mut lins = linearise_all(&theta, &nz)?;
        for it in 1..=self.settings.max_iter {
            let (h, g, used) = self.normal_equations(&lins, &lay, &nz);
            let Some(chol) = h.clone().cholesky() else {
                return Err(ScanError::Invalid(format!(
                    "scan fit with nuisances, iteration {it}: the moduli and the nuisances are                      not told apart by these scans (singular Gauss–Newton matrix)"
                )));
            };
            let mut step = -chol.solve(&g);
            // Settled when the step is a tenth of a standard deviation in the joint metric
            // (δᵀJᵀΩJδ over the residual's variance below 0.01): with a scan free to turn,
            // closest points switching triangles keep Gauss–Newton stepping by 1e-3 in ln μ
            // where the modulus' σ is a few per cent.
            let chi2: f64 = lins.iter().map(|l| l.weighted_chi2().0).sum();
            let variance = chi2 / used.saturating_sub(lay.n).max(1) as f64;
            if step.dot(&(&h * &step)) / variance < 1e-2 {
                return Ok(self.finish(theta, nz, lins, &lay, it));
            }
            let largest = step.rows(0, k).amax();
            if largest > 0.5 {
                step *= 0.5 / largest;
            }
            let omegas = state_omegas(&lins, states);
            let cost: f64 = lins.iter().map(|l| l.cost).sum();
            let mut accepted = false;
            let mut moved = 0.0;
            for _ in 0..10 {
                let (t, n) = lay.apply(&theta, &nz, &step);
                moved = lay.moves(&nz, &n, self, &lins);
                if step.rows(0, k).amax() < SMALL_STEP && moved < SMALL_MOVE_M {
                    (theta, nz, accepted) = (t, n, true);
                    break;
                }
                let eqs_cost: f64 = self
                    .states_with(split, &n)
                    .iter()
                    .zip(&omegas)
                    .map(|(s, w)| weighted_cost(&s.object, &s.scan, w, &t, max))
                    .sum::<Result<f64, _>>()?;
                if eqs_cost <= cost {
                    (theta, nz, accepted) = (t, n, true);
                    break;
                }
                step *= 0.5;
            }
            if !accepted {
                log::warn!(
                    "scan fit with nuisances, iteration {it}: no step lowers the cost; stopped"
                );
                return Ok(self.finish(theta, nz, lins, &lay, it));
            }
            lins = linearise_all(&theta, &nz)?;
            log::info!(
                "with nuisances, iteration {it}: E {} kPa, bias {:.4} mm, step {:.2e} in ln μ,                  nuisances moved {:.4} mm",
                theta
                    .iter()
                    .map(|t| format!("{:.1}", palpate_scan::fit::young(t.exp(), lay.poisson) / 1e3))
                    .collect::<Vec<_>>()
                    .join(" / "),
                1e3 * nz.bias_m,
                step.rows(0, k).amax(),
                1e3 * moved
            );
            if step.rows(0, k).amax() < 1e-4 && moved < SETTLED_M {
                return Ok(self.finish(theta, nz, lins, &lay, it));
            }
        }
        Err(ScanError::Invalid(format!(
            "scan fit with nuisances: Gauss–Newton did not settle in {} iterations",
            self.settings.max_iter
        )))
    }

    /// JᵀΩJ, JᵀΩd and the points with a weight, over the moduli and nuisances of `lay`.
    fn normal_equations(
        &self,
        lins: &[Linearisation],
        lay: &Layout,
        nz: &Nuisance,
    ) -> (DMatrix<f64>, DVector<f64>, usize) {
        let n = lay.n;
        let (mut h, mut g) = (DMatrix::zeros(n, n), DVector::zeros(n));
        let mut used = 0;
        self.rows(lins, lay, nz, |_, d, w, row| {
            used += 1;
            h.ger(w, row, row, 1.0);
            g.axpy(w * d, row, 1.0);
        });
        (h, g, used)
    }

    /// Each weighted point's row of J (∂d over the moduli and nuisances of `lay`), handed to
    /// `each` with its state, its signed distance d and its weight ω = w/σ².
    fn rows(
        &self,
        lins: &[Linearisation],
        lay: &Layout,
        nz: &Nuisance,
        mut each: impl FnMut(usize, f64, f64, &DVector<f64>),
    ) {
        let mut row = DVector::zeros(lay.n);
        for (i, lin) in lins.iter().enumerate() {
            let given = &self.states[i].scan;
            let here = self.corrected(i, given, nz);
            let centre = lay.centres[i];
            for r in &lin.residuals {
                let w = r.weight / (r.sigma * r.sigma);
                if w == 0.0 {
                    continue;
                }
                let c = &r.correspondence;
                row.fill(0.0);
                for (kk, dx) in lin.equilibrium.dln_mu.iter().enumerate() {
                    row[kk] = c
                        .jacobian()
                        .iter()
                        .map(|(node, v)| v.dot(&Vector3::from(dx[*node])))
                        .sum();
                }
                if let (Some(b), Some(camera)) = (lay.bias, given.camera) {
                    let u = nz.rigid[i].rotation * ray(&camera, given.points[c.point]);
                    row[b] = -c.normal.dot(&u);
                }
                if let (Some(sc), Some(camera)) = (lay.scale, given.camera) {
                    let v =
                        nz.rigid[i].rotation * (given.points[c.point] - camera.pose.translation);
                    row[sc] = -c.normal.dot(&v);
                }
                if let Some(base) = lay.rigid {
                    // A small turn ω about the scan's centre and a shift t move the point by
                    // ω × (p − centre) + t: d changes by ω·((p − centre) × n) + t·n.
                    let arm = (here.points[c.point] - centre).cross(&c.normal);
                    let at = base + 6 * i;
                    for a in 0..3 {
                        row[at + a] = arm[a];
                        row[at + 3 + a] = c.normal[a];
                    }
                }
                each(i, c.distance, w, &row);
            }
        }
    }

    fn finish(
        &self,
        theta: Vec<f64>,
        nz: Nuisance,
        lins: Vec<Linearisation>,
        lay: &Layout,
        iterations: usize,
    ) -> (JointFit, Nuisance, [f64; 2], usize) {
        let (h, _, used) = self.normal_equations(&lins, lay, &nz);
        let chi2: f64 = lins.iter().map(|l| l.weighted_chi2().0).sum();
        let scale = chi2 / used.saturating_sub(lay.n).max(1) as f64;
        let k = theta.len();
        let cov = h.try_inverse().map(|c| c * scale);
        let covariance = match &cov {
            Some(c) => c.view((0, 0), (k, k)).transpose().as_slice().to_vec(),
            None => vec![f64::INFINITY; k * k],
        };
        let sd = |at: Option<usize>| match (&cov, at) {
            (Some(c), Some(b)) => c[(b, b)].max(0.0).sqrt(),
            _ => f64::NAN,
        };
        let nuisance_sd = [sd(lay.bias), sd(lay.scale)];
        let fit = JointFit {
            mu: theta.iter().map(|t| t.exp()).collect(),
            poisson: lay.poisson,
            covariance,
            iterations,
            states: lins,
        };
        (fit, nz, nuisance_sd, iterations)
    }

    /// The score of `fit` (with its nuisances `nz`) on the points `points(i)` of each state.
    fn evidence<'s>(
        &'s self,
        fit: &JointFit,
        nz: &Nuisance,
        points: impl Fn(usize) -> &'s ScanPoints,
    ) -> Evidence {
        let mut total = Evidence::empty();
        for i in 0..self.states.len() {
            let eq = &fit.states[i].equilibrium;
            let here = self.corrected(i, points(i), nz);
            let res = residuals(eq, &here, self.settings.max_distance);
            let chi2 = res.iter().map(|r| r.scaled().powi(2).min(CAP * CAP)).sum();
            let kept: Vec<_> = res.iter().filter(|r| r.weight > 0.0).collect();
            let k = kept.len().max(1) as f64;
            total = total.add(Evidence {
                chi2,
                n: res.len(),
                rms_m: (kept
                    .iter()
                    .map(|r| r.correspondence.distance.powi(2))
                    .sum::<f64>()
                    / k)
                    .sqrt(),
                noise_m: (kept.iter().map(|r| r.sigma * r.sigma).sum::<f64>() / k).sqrt(),
            });
        }
        total
    }

    /// The model's score on the held-out points (its nuisances are the scans', fitted on their
    /// other points).
    pub fn held_out(&self, model: &ScanModel) -> Evidence {
        self.evidence(&model.fit, &model.nuisance, |i| &self.held[i])
    }

    /// State `i`'s fitted and held-out points together, corrected by the model's nuisances.
    pub fn all_points(&self, i: usize, model: &ScanModel) -> ScanPoints {
        let mut s = self.corrected(i, &self.states[i].scan, &model.nuisance);
        let h = self.corrected(i, &self.held[i], &model.nuisance);
        s.points.extend(h.points);
        s.sigma.extend(h.sigma);
        s
    }

    /// Free parameters of a model: its moduli and nuisances.
    pub fn parameters(&self, model: &ScanModel) -> usize {
        let mut k = model.fit.mu.len();
        if model.effects.contains(&Effect::DepthBias) {
            k += 1;
        }
        if model.effects.contains(&Effect::DepthScale) {
            k += 1;
        }
        if model.effects.contains(&Effect::CameraMoved) {
            k += 6 * self.states.len();
        }
        k
    }
}

/// A point's ray direction scaled to unit depth: (p − c)/z, z its depth along the camera's axis.
fn ray(camera: &palpate_scan::camera::Camera, p: Vector3<f64>) -> Vector3<f64> {
    let z = camera.pose.to_camera(p).z;
    if z.abs() < 1e-9 {
        return Vector3::zeros();
    }
    (p - camera.pose.translation) / z
}

/// Where each parameter of a joint fit sits: the moduli first, then the bias, then six per
/// state (a turn, then a shift).
struct Layout {
    bias: Option<usize>,
    scale: Option<usize>,
    rigid: Option<usize>,
    n: usize,
    poisson: f64,
    /// Each state's scan centre, the turns' pivot.
    centres: Vec<Vector3<f64>>,
}

impl Layout {
    fn of(k: usize, effects: &[Effect], states: &[ScanState<'_>]) -> Self {
        let mut n = k;
        let mut next = |take: bool, size: usize| {
            take.then(|| {
                n += size;
                n - size
            })
        };
        let bias = next(effects.contains(&Effect::DepthBias), 1);
        let scale = next(effects.contains(&Effect::DepthScale), 1);
        let rigid = next(effects.contains(&Effect::CameraMoved), 6 * states.len());
        Self {
            bias,
            scale,
            rigid,
            n,
            poisson: states[0].object.poisson,
            centres: states
                .iter()
                .map(|s| {
                    s.scan.points.iter().sum::<Vector3<f64>>() / s.scan.points.len().max(1) as f64
                })
                .collect(),
        }
    }

    /// ln μ and the nuisances after `step`.
    fn apply(&self, theta: &[f64], nz: &Nuisance, step: &DVector<f64>) -> (Vec<f64>, Nuisance) {
        let t = theta.iter().zip(step.iter()).map(|(a, b)| a + b).collect();
        let mut n = nz.clone();
        if let Some(b) = self.bias {
            n.bias_m += step[b];
        }
        if let Some(sc) = self.scale {
            n.scale += step[sc];
        }
        if let Some(base) = self.rigid {
            for (i, r) in n.rigid.iter_mut().enumerate() {
                let at = base + 6 * i;
                let omega = Vector3::new(step[at], step[at + 1], step[at + 2]);
                let shift = Vector3::new(step[at + 3], step[at + 4], step[at + 5]);
                let d = RigidTransform::about(omega, omega.norm(), self.centres[i], shift);
                *r = d.after(r);
            }
        }
        (t, n)
    }

    /// The largest distance (m) a change of nuisances from `a` to `b` moves a scanned point
    /// near the object.
    fn moves(&self, a: &Nuisance, b: &Nuisance, p: &Problem<'_>, lins: &[Linearisation]) -> f64 {
        let mut largest: f64 = 0.0;
        for (i, lin) in lins.iter().enumerate() {
            let given = &p.states[i].scan;
            let (pa, pb) = (p.corrected(i, given, a), p.corrected(i, given, b));
            for r in &lin.residuals {
                let j = r.correspondence.point;
                largest = largest.max((pa.points[j] - pb.points[j]).norm());
            }
        }
        largest
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_scan::synthetic::{write_strip_dataset, Injected, StripCase};

    /// Each column of the joint Jacobian — the modulus, the depth bias, each scan's turn and
    /// shift — against a central difference of the points' signed distances with their
    /// correspondences (triangle, barycentric point, normal) held, at a model away from the
    /// truth (a bias and turns not zero).
    #[test]
    fn the_joint_jacobian_is_the_finite_difference_of_the_distances() {
        let tmp = tempfile::tempdir().unwrap();
        let case = StripCase {
            cells: [6, 2, 1],
            design: Design::Linear,
            injected: Injected::DepthBias(4e-4),
            ..StripCase::default()
        };
        write_strip_dataset(tmp.path(), &case).unwrap();
        let ds = ScanDataset::read(tmp.path()).unwrap();
        let p = Problem::new(&ds, Design::Linear, &[300e3], 10).unwrap();
        let k = 1;
        let lay = Layout::of(
            k,
            &[Effect::DepthBias, Effect::DepthScale, Effect::CameraMoved],
            &p.states,
        );
        let theta = vec![(250e3f64 / 2.9).ln()];
        let nz0 = Nuisance {
            rigid: vec![
                RigidTransform::about(
                    Vector3::new(0.3, -0.2, 1.0),
                    0.01,
                    lay.centres[0],
                    Vector3::new(1e-4, 0.0, -2e-4),
                ),
                RigidTransform::about(
                    Vector3::new(-0.5, 1.0, 0.2),
                    0.02,
                    lay.centres[1],
                    Vector3::new(0.0, 3e-4, 1e-4),
                ),
            ],
            bias_m: 2e-4,
            scale: 3e-3,
        };
        let max = p.settings.max_distance;
        let lins: Vec<Linearisation> = p
            .states_with(None, &nz0)
            .iter()
            .map(|s| linearise(&s.object, &s.scan, &theta, max).unwrap())
            .collect();
        // The equilibria at θ and θ ± h (the modulus' column), per state.
        let h_theta = 1e-4;
        let eqs: Vec<[Vec<[f64; 3]>; 3]> = p
            .states
            .iter()
            .map(|s| {
                [0.0, h_theta, -h_theta].map(|d| {
                    s.object
                        .equilibrium_at(&[(theta[0] + d).exp()], false)
                        .unwrap()
                        .positions
                })
            })
            .collect();
        // The distance of a point to its correspondence's plane, held, at the nodes `x` and
        // the nuisances `nz`.
        let distance =
            |x: &[[f64; 3]], nz: &Nuisance, i: usize, r: &palpate_scan::fit::PointResidual| {
                let c = &r.correspondence;
                let on: Vector3<f64> = (0..3)
                    .map(|a| c.barycentric[a] * Vector3::from(x[c.triangle[a]]))
                    .sum();
                let here = p.corrected(i, &p.states[i].scan, nz);
                c.normal.dot(&(here.points[c.point] - on))
            };
        let mut rows = Vec::new();
        p.rows(&lins, &lay, &nz0, |i, _, _, row| {
            rows.push((i, row.clone()))
        });
        let mut checked = 0;
        for (i, lin) in lins.iter().enumerate() {
            let weighted: Vec<_> = lin.residuals.iter().filter(|r| r.weight > 0.0).collect();
            let state_rows: Vec<_> = rows.iter().filter(|(s, _)| *s == i).collect();
            assert_eq!(weighted.len(), state_rows.len());
            for idx in [0, weighted.len() / 2] {
                let (r, row) = (weighted[idx], &state_rows[idx].1);
                for col in 0..lay.n {
                    let h = if col < k { h_theta } else { 1e-6 };
                    let mut step = DVector::zeros(lay.n);
                    step[col] = h;
                    let (_, np) = lay.apply(&theta, &nz0, &step);
                    step[col] = -h;
                    let (_, nm) = lay.apply(&theta, &nz0, &step);
                    let (xp, xm) = if col < k {
                        (&eqs[i][1], &eqs[i][2])
                    } else {
                        (&eqs[i][0], &eqs[i][0])
                    };
                    let fd = (distance(xp, &np, i, r) - distance(xm, &nm, i, r)) / (2.0 * h);
                    let scale = row.amax().max(1e-3);
                    assert!(
                        (fd - row[col]).abs() < 2e-3 * scale,
                        "state {i}, point {idx}, column {col}: analytic {} vs difference {fd}",
                        row[col]
                    );
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, 4 * lay.n);
    }
}
