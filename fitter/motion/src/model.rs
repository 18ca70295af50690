//! The simulation model: rest geometry, clamps, markers, observations, per-element material and
//! the parameter vector the optimiser sees.

use super::hyperelastic::RestTet;
use super::sparse::Pattern;
use super::spline::{Response, SplineMaterial};
use super::MotionError;
use nalgebra::{Matrix3, Vector3};
use palpate_fem::mesh::Mesh;

/// Which mass matrix to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MassKind {
    /// Row-sum lumped: ρV/4 per node of each element.
    Lumped,
    /// Consistent linear-tet mass: ρV/20 (1 + δ_ab) I₃.
    Consistent,
}

/// A material quantity that can be a parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ParamKind {
    /// Lamé's first parameter λ (Pa).
    Lambda = 0,
    /// Shear modulus μ (Pa).
    Mu = 1,
    /// Viscosity coefficient ν of eq. 17 (Pa s^h).
    Nu = 2,
    /// Power-law index h of eq. 17.
    PowerH = 3,
    /// Density ρ (kg/m³).
    Density = 4,
    /// Strain-stiffening coefficient c of the c (Ī₁ − 3)² term added to Neo-Hookean (Pa; a
    /// Yeoh-type second-order term, Ī₁ = J^(−2/3) I₁, see [`super::hyperelastic`]); 0 is the
    /// paper's eq. 16.
    Stiffening = 5,
    /// Relaxed fraction g of the creep branch (dimensionless; [`super::relaxation`]): the
    /// elastic stress is (1 + g) times the elastic law's at short times and relaxes to the
    /// law's own (the fitted, long-term stiffness); 0 is no branch.
    CreepFraction = 6,
    /// Relaxation time τ of the creep branch (s; [`super::relaxation`]).
    CreepTime = 7,
    /// Gravity turned from its declared direction toward the first axis across it
    /// ([`Model::gravity_axes`]): the value q carries the tangent of the turn as ln q, so that
    /// the fitter's z = ln q is the turn itself, of either sign, and q = 1 is the declared
    /// gravity ([`Model::gravity_of`]). Global only; not a property of the material, but of
    /// where the material sits, carried beside it so that a fit can free it like one.
    GravityTiltA = 8,
    /// The same toward the second axis across the declared gravity.
    GravityTiltB = 9,
    /// A control value of the spline f′ of §4.2 (Pa); `Param::element` holds the control index.
    SplineF = 10,
    /// A control value J·h′(J) of the spline h′ of §4.2 (Pa); `Param::element` holds the
    /// control index.
    SplineH = 11,
}

/// Number of per-element kinds ([`ParamKind::EVERY`]): the derivative slots before the spline
/// control values.
pub const MATERIAL_KINDS: usize = 10;

impl ParamKind {
    /// The elastic, viscous and inertial kinds of Real2Sim's model (eqs. 16–17) in index order,
    /// the stiffening included: what a fit frees by default and a report lists. The creep
    /// branch's kinds ([`Self::CREEP`]) are not among them: at g = 0 the branch is absent and
    /// its time has no effect, so a fit of "every kind" would have no gradient there.
    pub const ALL: [ParamKind; 6] = [
        Self::Lambda,
        Self::Mu,
        Self::Nu,
        Self::PowerH,
        Self::Density,
        Self::Stiffening,
    ];
    /// The creep branch's kinds ([`super::relaxation`]).
    pub const CREEP: [ParamKind; 2] = [Self::CreepFraction, Self::CreepTime];
    /// The gravity's turn across its declared direction ([`Model::gravity_of`]).
    pub const GRAVITY: [ParamKind; 2] = [Self::GravityTiltA, Self::GravityTiltB];
    /// Every per-element kind in index order (the spline kinds are separate: their parameters
    /// are control points, see [`Param`]): [`Self::ALL`], then [`Self::CREEP`], then
    /// [`Self::GRAVITY`], joined here so that a kind added to any is in it.
    pub const EVERY: [ParamKind; MATERIAL_KINDS] = {
        // A kind added to a group without MATERIAL_KINDS following stops the build here.
        assert!(Self::ALL.len() + Self::CREEP.len() + Self::GRAVITY.len() == MATERIAL_KINDS);
        let mut every = [Self::Lambda; MATERIAL_KINDS];
        let mut i = 0;
        while i < Self::ALL.len() {
            every[i] = Self::ALL[i];
            i += 1;
        }
        while i < Self::ALL.len() + Self::CREEP.len() {
            every[i] = Self::CREEP[i - Self::ALL.len()];
            i += 1;
        }
        while i < MATERIAL_KINDS {
            every[i] = Self::GRAVITY[i - Self::ALL.len() - Self::CREEP.len()];
            i += 1;
        }
        every
    };
    /// Short name as used on the command line and in reports. The viscosity coefficient is
    /// `viscosity` (the paper's ν; ν is Poisson's ratio everywhere else in palpate).
    pub fn name(self) -> &'static str {
        match self {
            Self::Lambda => "lambda",
            Self::Mu => "mu",
            Self::Nu => "viscosity",
            Self::PowerH => "h",
            Self::Density => "density",
            Self::Stiffening => "stiffening",
            Self::CreepFraction => "creep_fraction",
            Self::CreepTime => "creep_time",
            Self::GravityTiltA => "gravity_tilt_a",
            Self::GravityTiltB => "gravity_tilt_b",
            Self::SplineF => "spline_f",
            Self::SplineH => "spline_h",
        }
    }
    /// What a report calls it, with its unit.
    pub fn label(self) -> &'static str {
        match self {
            Self::Lambda => "Lamé λ (Pa)",
            Self::Mu => "shear modulus μ (Pa)",
            Self::Nu => "viscosity (Pa·s^h)",
            Self::PowerH => "power-law index h",
            Self::Density => "density (kg/m³)",
            Self::Stiffening => "strain-stiffening c (Pa)",
            Self::CreepFraction => "creep: relaxed fraction g",
            Self::CreepTime => "creep: relaxation time τ (s)",
            Self::GravityTiltA => "gravity turned toward its first cross axis (exp of the tangent)",
            Self::GravityTiltB => {
                "gravity turned toward its second cross axis (exp of the tangent)"
            }
            Self::SplineF => "spline f′ control value (Pa)",
            Self::SplineH => "spline J·h′ control value (Pa)",
        }
    }
    /// True for the spline control-value kinds (optimised linearly, not in log space).
    pub fn is_spline(self) -> bool {
        matches!(self, Self::SplineF | Self::SplineH)
    }
    /// The spline response a spline kind refers to.
    pub fn response(self) -> Option<Response> {
        match self {
            Self::SplineF => Some(Response::F),
            Self::SplineH => Some(Response::H),
            _ => None,
        }
    }
    /// Parses a command-line name.
    pub fn parse(s: &str) -> Option<Self> {
        Self::EVERY.into_iter().find(|k| k.name() == s)
    }
    /// The name a kind had before, if `s` is one (`nu`, the viscosity's until the names followed
    /// the rest of palpate): callers accept it and warn with [`ParamKind::name`].
    pub fn old_name(s: &str) -> Option<Self> {
        match s {
            "nu" => Some(Self::Nu),
            _ => None,
        }
    }
}

/// One optimisation parameter: a material kind, global (all elements) or of one element.
///
/// For the spline kinds ([`ParamKind::SplineF`], [`ParamKind::SplineH`]) the material is global
/// and `element` is `Some(i)`: control point i of that spline.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Param {
    /// Which quantity.
    pub kind: ParamKind,
    /// `None` = the same value in every element; `Some(e)` = element e only (control point e for
    /// the spline kinds).
    pub element: Option<usize>,
    /// `Some(r)` = the elements of the material's region r ([`Material::regions`]; `element` is
    /// then `None`): one value there — the second material of a two-material body. A global
    /// parameter reaches the elements outside every region.
    pub region: Option<usize>,
}

impl Param {
    /// A global parameter (the same value in every element).
    pub fn global(kind: ParamKind) -> Self {
        Self {
            kind,
            element: None,
            region: None,
        }
    }

    /// One element's own value of `kind`.
    pub fn of_element(kind: ParamKind, e: usize) -> Self {
        Self {
            kind,
            element: Some(e),
            region: None,
        }
    }

    /// One value of `kind` in the elements of region `r` ([`Material::regions`]).
    pub fn in_region(kind: ParamKind, r: usize) -> Self {
        Self {
            kind,
            element: None,
            region: Some(r),
        }
    }

    /// True for a parameter that covers every element not overridden by another (a global
    /// material quantity or a spline control value).
    pub fn is_global(&self) -> bool {
        self.region.is_none() && (self.element.is_none() || self.kind.is_spline())
    }

    /// Global parameters of `kinds`, in order.
    pub fn globals(kinds: &[ParamKind]) -> Vec<Self> {
        kinds.iter().map(|&k| Self::global(k)).collect()
    }

    /// The derivative slot of this parameter: the kind index for material kinds,
    /// [`MATERIAL_KINDS`] + i for f′ control i, [`MATERIAL_KINDS`] + (f′ count) + i for h′
    /// control i. Gradient passes accumulate per element and slot.
    pub fn slot(&self, mat: &Material) -> usize {
        let nf = mat.spline.as_ref().map_or(0, |s| s.len(Response::F));
        match (self.kind, self.element) {
            (ParamKind::SplineF, Some(i)) => MATERIAL_KINDS + i,
            (ParamKind::SplineH, Some(i)) => MATERIAL_KINDS + nf + i,
            (k, _) => k as usize,
        }
    }
}

/// Per-element material values.
#[derive(Debug, Clone, PartialEq)]
pub struct Material {
    /// Values indexed `[kind as usize][element]` ([`ParamKind::EVERY`]; the stiffening and the
    /// creep fraction are 0 unless set: the paper's eq. 16, no creep branch).
    pub values: [Vec<f64>; MATERIAL_KINDS],
    /// The principal-stretch material of §4.2; when present it replaces Neo-Hookean (λ, μ and
    /// the stiffening unused).
    pub spline: Option<SplineMaterial>,
    /// Element sets that a region parameter ([`Param::in_region`]) gives one value of its own:
    /// the second material of a two-material body. Empty for one material.
    pub regions: Vec<Vec<usize>>,
    /// Regions scaled as a whole: the body's Lamé moduli times one factor, the region's μ over
    /// the body's, so that the region keeps the body's Poisson's ratio (a compliant layer at a
    /// clamp): λ_r = μ_r λ_b/μ_b, with λ_b and μ_b the values outside every region. Setting
    /// values ([`Self::set`]) sets the region's λ; the parameters its λ depends on carry its
    /// derivative by the chain rule ([`Self::ties`]), and it is no parameter of its own.
    pub scaled_regions: Vec<usize>,
    /// How the viscosity reads the velocity gradient ([`crate::viscosity::Form`]): a property
    /// of the law, as the spline's choice is.
    pub viscous_form: crate::viscosity::Form,
}

/// A region's λ that follows parameters ([`Material::scaled_regions`]): dλ = Σ w dq\[i\] over
/// `weights` (i, w) ([`Material::ties`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Tie {
    /// The λ that follows (a region's).
    pub lambda: Param,
    /// (index in the parameter list, ∂λ/∂q) of each parameter it depends on.
    pub weights: Vec<(usize, f64)>,
}

impl Material {
    /// The same values in every one of `n` elements.
    pub fn uniform(n: usize, lambda: f64, mu: f64, nu: f64, h: f64, density: f64) -> Self {
        Self {
            values: [
                vec![lambda; n],
                vec![mu; n],
                vec![nu; n],
                vec![h; n],
                vec![density; n],
                vec![0.0; n],
                vec![0.0; n],
                // Any positive time: without a relaxed fraction it has no effect.
                vec![1.0; n],
                // The declared gravity: no turn (ln 1 = 0).
                vec![1.0; n],
                vec![1.0; n],
            ],
            spline: None,
            regions: Vec::new(),
            scaled_regions: Vec::new(),
            viscous_form: crate::viscosity::Form::RestGradient,
        }
    }
    /// The body's (λ, μ): the values outside every region (the means there).
    pub fn body_moduli(&self) -> (f64, f64) {
        let v = self.read(&[
            Param::global(ParamKind::Lambda),
            Param::global(ParamKind::Mu),
        ]);
        (v[0], v[1])
    }
    /// The λ of each scaled region ([`Self::scaled_regions`]) as it follows `params`:
    /// λ_r = μ_r λ_b/μ_b, so ∂λ_r/∂μ_r = λ_b/μ_b, ∂λ_r/∂λ_b = μ_r/μ_b and
    /// ∂λ_r/∂μ_b = −μ_r λ_b/μ_b², each where that value is a parameter. A scaled region's λ
    /// among `params` is refused: it is no parameter of its own.
    pub fn ties(&self, params: &[Param]) -> Result<Vec<Tie>, MotionError> {
        if self.scaled_regions.is_empty() {
            return Ok(Vec::new());
        }
        if let Some((i, p)) = params.iter().enumerate().find(|(_, p)| {
            p.kind == ParamKind::Lambda
                && p.region.is_some_and(|r| self.scaled_regions.contains(&r))
        }) {
            return Err(MotionError::Invalid(format!(
                "parameter {i}: region {}'s λ follows its μ at the body's Poisson's ratio and is \
                 no parameter of its own",
                p.region.unwrap_or_default()
            )));
        }
        let (lb, mb) = self.body_moduli();
        let at = |p: Param| params.iter().position(|q| *q == p);
        Ok(self
            .scaled_regions
            .iter()
            .map(|&r| {
                let mr = self.read(&[Param::in_region(ParamKind::Mu, r)])[0];
                let weights = [
                    (at(Param::in_region(ParamKind::Mu, r)), lb / mb),
                    (at(Param::global(ParamKind::Lambda)), mr / mb),
                    (at(Param::global(ParamKind::Mu)), -mr * lb / (mb * mb)),
                ]
                .into_iter()
                .filter_map(|(i, w)| Some((i?, w)))
                .collect();
                Tie {
                    lambda: Param::in_region(ParamKind::Lambda, r),
                    weights,
                }
            })
            .filter(|t| !t.weights.is_empty())
            .collect())
    }
    /// Whether any element has a creep branch (a relaxed fraction other than 0,
    /// [`super::relaxation`]).
    pub fn has_creep(&self) -> bool {
        self.values[ParamKind::CreepFraction as usize]
            .iter()
            .any(|&g| g != 0.0)
    }
    /// Whether the material damps a fast motion: a power-law viscosity (eq. 17) in some element.
    /// A creep branch alone does not: its relaxation is slow, and to a mode much faster than its
    /// time it is a stiffness.
    pub fn damps(&self) -> bool {
        self.values[ParamKind::Nu as usize].iter().any(|&v| v > 0.0)
    }
    /// Sets `kind` to `value` in every element.
    pub fn set_uniform(&mut self, kind: ParamKind, value: f64) {
        self.values[kind as usize].fill(value);
    }
    /// Derivative slots (see [`Param::slot`]): the material kinds plus the spline controls.
    pub fn slots(&self) -> usize {
        MATERIAL_KINDS
            + self
                .spline
                .as_ref()
                .map_or(0, |s| s.len(Response::F) + s.len(Response::H))
    }
    /// Checks that every parameter refers to something this material has.
    pub fn check_params(&self, params: &[Param]) -> Result<(), MotionError> {
        for &r in &self.scaled_regions {
            if r >= self.regions.len() {
                return Err(MotionError::Invalid(format!(
                    "region {r} is scaled as a whole, but the material has {} region(s)",
                    self.regions.len()
                )));
            }
        }
        for (i, p) in params.iter().enumerate() {
            if let Some(r) = p.region {
                let Some(elements) = self.regions.get(r) else {
                    return Err(MotionError::Invalid(format!(
                        "parameter {i}: {} in region {r}, but the material has {} region(s)",
                        p.kind.name(),
                        self.regions.len()
                    )));
                };
                if p.kind.is_spline() || p.element.is_some() {
                    return Err(MotionError::Invalid(format!(
                        "parameter {i}: a region parameter is a material quantity of no single \
                         element, found {} with element {:?}",
                        p.kind.name(),
                        p.element
                    )));
                }
                if let Some(&e) = elements.iter().find(|&&e| e >= self.values[0].len()) {
                    return Err(MotionError::Invalid(format!(
                        "region {r}: element {e} out of range ({} elements)",
                        self.values[0].len()
                    )));
                }
            }
            match (p.kind.response(), &self.spline) {
                (Some(r), Some(s)) => match p.element {
                    Some(c) if c < s.len(r) => {}
                    _ => {
                        return Err(MotionError::Invalid(format!(
                            "parameter {i}: {} needs a control index below {}, found {:?}",
                            p.kind.name(),
                            s.len(r),
                            p.element
                        )))
                    }
                },
                (Some(_), None) => {
                    return Err(MotionError::Invalid(format!(
                        "parameter {i}: {} but the material has no response splines",
                        p.kind.name()
                    )))
                }
                (None, Some(_))
                    if matches!(
                        p.kind,
                        ParamKind::Lambda | ParamKind::Mu | ParamKind::Stiffening
                    ) =>
                {
                    return Err(MotionError::Invalid(format!(
                        "parameter {i}: {} has no effect with the spline material (fit its \
                         control values instead)",
                        p.kind.name()
                    )))
                }
                (None, _) => {
                    if let Some(e) = p.element {
                        if e >= self.values[0].len() {
                            return Err(MotionError::Invalid(format!(
                                "parameter {i}: element {e} out of range ({} elements)",
                                self.values[0].len()
                            )));
                        }
                    }
                }
            }
        }
        Ok(())
    }
    /// Value of `kind` in element `e`.
    pub fn get(&self, kind: ParamKind, e: usize) -> f64 {
        self.values[kind as usize][e]
    }
    /// Which elements lie in a region ([`Self::regions`]).
    pub fn in_region(&self) -> Vec<bool> {
        let mut inside = vec![false; self.values[0].len()];
        self.regions
            .iter()
            .flatten()
            .for_each(|&e| inside[e] = true);
        inside
    }

    /// Which elements a global parameter of `kind` in `params` does not reach: those of the
    /// regions that `params` gives a value of `kind` of their own. A region is a second material
    /// for the kinds it has a parameter of, and the same material for the others: the
    /// two-material candidate's region has its own μ but shares the one λ (before, a global λ
    /// reached no region element, so the region kept the λ it was created with while the rest's
    /// was fitted — random two-material bars refitted on their true partition stayed 6.7× above
    /// the noise floor).
    pub fn overridden(&self, params: &[Param], kind: ParamKind) -> Vec<bool> {
        let mut inside = vec![false; self.values[0].len()];
        if kind == ParamKind::Lambda {
            // A region whose λ follows its μ is never reached by the global λ.
            for &r in &self.scaled_regions {
                if let Some(elements) = self.regions.get(r) {
                    elements.iter().for_each(|&e| inside[e] = true);
                }
            }
        }
        for p in params {
            if let (Some(r), None) = (p.region, p.element) {
                if p.kind == kind {
                    if let Some(elements) = self.regions.get(r) {
                        elements.iter().for_each(|&e| inside[e] = true);
                    }
                }
            }
        }
        inside
    }

    /// Writes the parameter values `q` (linear, not log) into the material: a global parameter
    /// into every element but those of the regions `params` gives that kind of their own
    /// ([`Self::overridden`]), then the regions' and the elements' own values; last, each scaled
    /// region's λ from its μ at the body's ratio ([`Self::scaled_regions`]).
    pub fn set(&mut self, params: &[Param], q: &[f64]) {
        self.set_values(params, q);
        if self.scaled_regions.is_empty() {
            return;
        }
        let (lb, mb) = self.body_moduli();
        for &r in &self.scaled_regions {
            let Some(elements) = self.regions.get(r) else {
                continue;
            };
            for &e in elements {
                self.values[ParamKind::Lambda as usize][e] =
                    self.values[ParamKind::Mu as usize][e] * lb / mb;
            }
        }
    }
    fn set_values(&mut self, params: &[Param], q: &[f64]) {
        for global in [true, false] {
            for (p, &v) in params.iter().zip(q) {
                if p.is_global() != global {
                    continue;
                }
                if let Some(r) = p.kind.response() {
                    if let (Some(s), Some(i)) = (self.spline.as_mut(), p.element) {
                        s.set_value(r, i, v);
                    }
                    continue;
                }
                let values = &mut self.values[p.kind as usize];
                match (p.element, p.region) {
                    (Some(e), _) => values[e] = v,
                    (None, Some(r)) => self.regions[r].iter().for_each(|&e| values[e] = v),
                    (None, None) => {
                        let inside = self.overridden(params, p.kind);
                        self.values[p.kind as usize]
                            .iter_mut()
                            .zip(&inside)
                            .filter(|(_, &i)| !i)
                            .for_each(|(x, _)| *x = v)
                    }
                }
            }
        }
    }
    /// Reads the parameter values: for a global parameter the mean over the elements outside
    /// every region (over all when there is none), for a region's the mean over its elements.
    pub fn read(&self, params: &[Param]) -> Vec<f64> {
        let mean = |v: &[f64], elements: &mut dyn Iterator<Item = usize>| {
            let (sum, n) = elements.fold((0.0, 0usize), |(s, n), e| (s + v[e], n + 1));
            if n == 0 {
                f64::NAN
            } else {
                sum / n as f64
            }
        };
        params
            .iter()
            .map(|p| match (p.element, p.region) {
                _ if p.kind.is_spline() => match (p.kind.response(), &self.spline, p.element) {
                    (Some(r), Some(s), Some(i)) => s.value(r, i),
                    _ => f64::NAN,
                },
                (Some(e), _) => self.values[p.kind as usize][e],
                (None, Some(r)) => mean(
                    &self.values[p.kind as usize],
                    &mut self.regions[r].iter().copied(),
                ),
                (None, None) => {
                    let v = &self.values[p.kind as usize];
                    let inside = self.in_region();
                    match mean(v, &mut (0..v.len()).filter(|&e| !inside[e])) {
                        m if m.is_nan() => mean(v, &mut (0..v.len())),
                        m => m,
                    }
                }
            })
            .collect()
    }
}

/// A rigid pose x = R X + t.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Rotation R.
    pub r: Matrix3<f64>,
    /// Translation t (m).
    pub t: Vector3<f64>,
}

impl Pose {
    /// The identity pose.
    pub fn identity() -> Self {
        Self {
            r: Matrix3::identity(),
            t: Vector3::zeros(),
        }
    }
    /// A pure translation.
    pub fn translation(t: [f64; 3]) -> Self {
        Self {
            r: Matrix3::identity(),
            t: Vector3::from(t),
        }
    }
    /// From a translation and a unit quaternion (w, x, y, z); the quaternion is normalised.
    pub fn from_quaternion(t: [f64; 3], q: [f64; 4]) -> Self {
        let uq = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            q[0], q[1], q[2], q[3],
        ));
        Self {
            r: *uq.to_rotation_matrix().matrix(),
            t: Vector3::from(t),
        }
    }
    /// The pose a fraction `w` ∈ [0, 1] of the way to `other`: translation linear, rotation by
    /// normalised quaternion blend in one hemisphere (what the dataset reader does between
    /// samples).
    pub fn blend(&self, other: &Pose, w: f64) -> Pose {
        let qa = nalgebra::UnitQuaternion::from_matrix(&self.r);
        let qb = nalgebra::UnitQuaternion::from_matrix(&other.r);
        let sign = if qa.coords.dot(&qb.coords) < 0.0 {
            -1.0
        } else {
            1.0
        };
        let q = qa.coords * (1.0 - w) + qb.coords * (sign * w);
        let uq = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::from(q));
        Pose {
            r: *uq.to_rotation_matrix().matrix(),
            t: self.t * (1.0 - w) + other.t * w,
        }
    }

    /// Applies the pose to a rest point.
    pub fn apply(&self, x: &[f64; 3]) -> [f64; 3] {
        let p = self.r * Vector3::from(*x) + self.t;
        [p[0], p[1], p[2]]
    }
}

/// A clamped node group moving rigidly (a moving Dirichlet boundary).
#[derive(Debug, Clone)]
pub struct Clamp {
    /// Group name (mesh physical group).
    pub name: String,
    /// Node indices.
    pub nodes: Vec<usize>,
    /// Pose at each time step 0..=steps.
    pub poses: Vec<Pose>,
}

/// A virtual marker: a fixed linear combination of node positions (barycentric in a tet).
#[derive(Debug, Clone, PartialEq)]
pub struct Marker {
    /// Name from markers.csv.
    pub name: String,
    /// (node, weight) pairs; weights sum to 1.
    pub weights: Vec<(usize, f64)>,
}

/// Observed data per time step, aligned with the simulation steps 1..=steps (index 0 = step 1).
#[derive(Debug, Clone, Default)]
pub struct Observations {
    /// `markers[n][i]`: target position of marker i at step n+1, `None` for a dropped frame.
    pub markers: Vec<Vec<Option<[f64; 3]>>>,
    /// `forces[n][c]`: measured reaction force on clamp c at step n+1.
    pub forces: Vec<Vec<Option<[f64; 3]>>>,
    /// Weight of the marker term (eq. 15), default 1.
    pub marker_weight: f64,
    /// Weight of the force term (½ Σ dt ‖F − F*‖²), default 1.
    pub force_weight: f64,
    /// Each marker carries an unknown constant offset from its simulated place (a marker glued a
    /// millimetre from where it is declared, a marker's centre above the surface): the offsets
    /// are eliminated in closed form — at any parameters the best offset of marker i is its mean
    /// residual over its observed steps — so Φ, its gradient and the Gauss–Newton matrix are
    /// those of the residuals with each marker's mean removed ([`super::gradient`]).
    pub free_marker_offsets: bool,
    /// Φ's absolute precision: a Levenberg–Marquardt fit to these observations also stops
    /// where its steps gain less than this (0: its own Φ's relative precision alone,
    /// [`super::optimize::precision`]). For data made without noise that stand in for measured
    /// ones (the mesh's own null of a diagnosis), the measured data's precision: held to the
    /// relative precision of their own small Φ, their fits run on for gains a hundredth of what
    /// the measured data can tell apart.
    pub phi_precision: f64,
}

/// Newton settings (paper §4.3: residual < 1e-6 N or 20 iterations).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewtonSettings {
    /// Stop when ‖r‖₂ < tol (N).
    pub tol: f64,
    /// Iteration cap per step.
    pub max_iter: usize,
}

impl Default for NewtonSettings {
    fn default() -> Self {
        Self {
            tol: 1e-6,
            max_iter: 20,
        }
    }
}

/// Everything fixed during an optimisation.
#[derive(Debug, Clone)]
pub struct Model {
    /// Rest node positions.
    pub nodes: Vec<[f64; 3]>,
    /// Tetrahedra.
    pub tets: Vec<[usize; 4]>,
    /// Rest geometry per tet.
    pub rest: Vec<RestTet>,
    /// dof → free index, `usize::MAX` for clamped dofs.
    pub free: Vec<usize>,
    /// Number of free dofs.
    pub nfree: usize,
    /// Free-dof sparsity pattern with reused symbolic Cholesky.
    pub pattern: Pattern,
    /// Moving clamps.
    pub clamps: Vec<Clamp>,
    /// Elements touching each clamp (for reaction forces).
    pub clamp_elems: Vec<Vec<usize>>,
    /// clamp index of each node (`usize::MAX` = none).
    pub node_clamp: Vec<usize>,
    /// Gravity (m/s²).
    pub gravity: [f64; 3],
    /// Mass matrix kind.
    pub mass: MassKind,
    /// Time step (s).
    pub dt: f64,
    /// Number of steps simulated after t = 0.
    pub steps: usize,
    /// Simulation steps per capture interval (≥ 1): the capture's frames are every
    /// `substeps`-th step ([`Model::resampled`]); each observation weighs the capture interval
    /// `substeps · dt` in Φ, so Φ does not depend on how finely the motion is integrated.
    pub substeps: usize,
    /// Newton settings.
    pub newton: NewtonSettings,
    /// Virtual markers.
    pub markers: Vec<Marker>,
    /// Start from elastostatic equilibrium (§3.4) instead of the rest shape.
    pub static_start: bool,
    /// Known dead loads besides gravity (hanging weights); none by default.
    pub loads: Vec<DeadLoad>,
    /// Time integration scheme (default BDF2, eq. 2).
    pub scheme: crate::timestep::Scheme,
    /// The viscosity law a fit of this model's data starts from (`viscosity_form` in
    /// dataset.toml): what is simulated is the material's own ([`Material::viscous_form`]).
    pub viscous_form: crate::viscosity::Form,
}

/// A known dead load: a constant total force shared equally by `nodes`, acting from step
/// `from_step` on (a weight hung from an edge, a tared push). It does not depend on any fitted
/// parameter, so it adds to the external force of every step and to nothing in the gradients.
#[derive(Debug, Clone, PartialEq)]
pub struct DeadLoad {
    /// Name in reports.
    pub name: String,
    /// Free nodes that carry the load.
    pub nodes: Vec<usize>,
    /// Total force (N).
    pub force: [f64; 3],
    /// First step at which the load acts (0: already in the static start).
    pub from_step: usize,
    /// The hanging mass behind the force (kg), when the load was declared as a mass.
    pub mass: Option<f64>,
    /// Whether that mass also adds inertia: lumped equally on the load's nodes, as if the weight
    /// moved with its attachment (a weight on a taut string follows the vertical motion; its
    /// pendulum swing across is not modelled).
    pub inertia: bool,
    /// Where the force acts when not on its nodes: a hook's lever ([`crate::load_point`]); its
    /// nodal shares replace the equal ones.
    pub lever: Option<crate::load_point::Lever>,
}

impl DeadLoad {
    /// Each node's share of the force: its lever's shares, or equal.
    pub fn shares(&self) -> Vec<(usize, f64)> {
        match &self.lever {
            Some(lever) => lever.shares.clone(),
            None => {
                let share = 1.0 / self.nodes.len().max(1) as f64;
                self.nodes.iter().map(|&n| (n, share)).collect()
            }
        }
    }

    /// The mass each of the load's nodes carries (kg): 0 without inertia.
    pub fn mass_per_node(&self) -> f64 {
        match (self.inertia, self.mass) {
            (true, Some(m)) if !self.nodes.is_empty() => m / self.nodes.len() as f64,
            _ => 0.0,
        }
    }
}

impl Model {
    /// The scheme a simulation of `mat` integrates with: the model's own, except that a
    /// material without viscosity ([`Material::damps`]) is integrated by BDF2 where
    /// the model asks for the implicit midpoint rule. The midpoint rule damps no mode, and on a
    /// nonlinear elastic body with no viscosity the energy of the modes it cannot
    /// resolve can grow until an element inverts (Simo & Tarnow 1992): the measured beam's
    /// undamped model, released under gravity at the midpoint rule's step, inverts an element
    /// within the run. An undamped model is a diagnosis' baseline, never its answer; BDF2's
    /// damping of the unresolved modes keeps it simulating.
    pub fn scheme_for(&self, mat: &Material) -> crate::timestep::Scheme {
        use crate::timestep::Scheme;
        match self.scheme {
            Scheme::Midpoint if !mat.damps() => Scheme::Bdf2,
            scheme => scheme,
        }
    }

    /// Builds a model; clamps must not share nodes and each must have `steps + 1` poses.
    pub fn new(
        mesh: &Mesh,
        clamps: Vec<Clamp>,
        markers: Vec<Marker>,
        dt: f64,
        steps: usize,
        gravity: [f64; 3],
        mass: MassKind,
    ) -> Result<Self, MotionError> {
        let rest = RestTet::of_mesh(mesh)?;
        let nn = mesh.nodes.len();
        let mut node_clamp = vec![usize::MAX; nn];
        for (c, cl) in clamps.iter().enumerate() {
            if cl.poses.len() != steps + 1 {
                return Err(MotionError::Invalid(format!(
                    "clamp {:?}: {} poses for {} steps (expected {})",
                    cl.name,
                    cl.poses.len(),
                    steps,
                    steps + 1
                )));
            }
            for &n in &cl.nodes {
                if n >= nn {
                    return Err(MotionError::Invalid(format!(
                        "clamp {:?}: node index {n} out of range",
                        cl.name
                    )));
                }
                if node_clamp[n] != usize::MAX && node_clamp[n] != c {
                    return Err(MotionError::Invalid(format!(
                        "node {n} is in clamps {:?} and {:?}",
                        clamps[node_clamp[n]].name, cl.name
                    )));
                }
                node_clamp[n] = c;
            }
        }
        let mut free = vec![usize::MAX; 3 * nn];
        let mut nfree = 0;
        for n in 0..nn {
            if node_clamp[n] == usize::MAX {
                for i in 0..3 {
                    free[3 * n + i] = nfree;
                    nfree += 1;
                }
            }
        }
        if nfree == 0 {
            return Err(MotionError::Invalid(
                "every node is clamped: nothing to simulate".into(),
            ));
        }
        let mut clamp_elems = vec![Vec::new(); clamps.len()];
        for (e, t) in mesh.tets.iter().enumerate() {
            let mut seen = Vec::new();
            for &n in t {
                let c = node_clamp[n];
                if c != usize::MAX && !seen.contains(&c) {
                    seen.push(c);
                    clamp_elems[c].push(e);
                }
            }
        }
        let pattern = Pattern::new(&mesh.tets, &free, nfree)
            .map_err(|e| MotionError::Invalid(e.to_string()))?;
        Ok(Self {
            nodes: mesh.nodes.clone(),
            tets: mesh.tets.clone(),
            rest,
            free,
            nfree,
            pattern,
            clamps,
            clamp_elems,
            node_clamp,
            gravity,
            mass,
            dt,
            steps,
            substeps: 1,
            newton: NewtonSettings::default(),
            markers,
            static_start: true,
            loads: Vec::new(),
            scheme: crate::timestep::Scheme::Bdf2,
            viscous_form: crate::viscosity::Form::RestGradient,
        })
    }

    /// The capture interval: what one observation weighs in Φ (s).
    pub fn observation_interval(&self) -> f64 {
        self.dt * self.substeps.max(1) as f64
    }

    /// The same model integrated with `k` times more steps of dt/k — the capture's frames every
    /// k-th step — together with its observations moved onto the finer grid; clamp poses are
    /// interpolated between the capture's (translation linear, rotation by normalised quaternion
    /// blend, as the reader does), loads start at the same time.
    ///
    /// Why: BDF2 lengthens the period of an oscillation resolved by N steps per period and damps
    /// it (N = 13: period +6.5 %, amplitude ×0.89 per cycle, see [`crate::timestep`]); a capture
    /// at 100 Hz of a 7.7 Hz ring-down is 13 frames per period, so stepping at the capture rate
    /// puts a numerical error into every fit that the material parameters would then absorb.
    pub fn resampled(&self, obs: &Observations, k: usize) -> (Model, Observations) {
        let k = k.max(1);
        let mut m = self.clone();
        if k == 1 {
            return (m, obs.clone());
        }
        let k0 = self.substeps.max(1);
        m.dt = self.dt / k as f64;
        m.steps = self.steps * k;
        m.substeps = k0 * k;
        for (cl, old) in m.clamps.iter_mut().zip(&self.clamps) {
            cl.poses = (0..=m.steps)
                .map(|n| {
                    let (j, r) = (n / k, n % k);
                    if r == 0 || j + 1 >= old.poses.len() {
                        old.poses[j.min(old.poses.len() - 1)]
                    } else {
                        old.poses[j].blend(&old.poses[j + 1], r as f64 / k as f64)
                    }
                })
                .collect();
        }
        for l in &mut m.loads {
            l.from_step *= k;
        }
        let mut o = Observations {
            markers: vec![vec![None; self.markers.len()]; m.steps],
            forces: vec![vec![None; self.clamps.len()]; m.steps],
            ..obs.clone()
        };
        // Row n holds step n + 1: capture step s = n + 1 is fine step s·k, row s·k − 1.
        for (n, row) in obs.markers.iter().enumerate() {
            o.markers[(n + 1) * k - 1] = row.clone();
        }
        for (n, row) in obs.forces.iter().enumerate() {
            o.forces[(n + 1) * k - 1] = row.clone();
        }
        (m, o)
    }

    /// Prescribed positions of all clamped dofs at step `n` written into `x` (full dofs).
    pub fn apply_clamps(&self, n: usize, x: &mut [f64]) {
        for cl in &self.clamps {
            for &node in &cl.nodes {
                let p = cl.poses[n].apply(&self.nodes[node]);
                x[3 * node..3 * node + 3].copy_from_slice(&p);
            }
        }
    }

    /// Marker position from full-dof positions `x`.
    pub fn marker_position(&self, m: &Marker, x: &[f64]) -> [f64; 3] {
        let mut p = [0.0; 3];
        for &(n, w) in &m.weights {
            for i in 0..3 {
                p[i] += w * x[3 * n + i];
            }
        }
        p
    }

    /// The elements that touch a clamp's nodes and have a free node (an element held at all four
    /// does not deform), once each, in ascending order: the layer through which a clamp holds
    /// the body.
    pub fn clamp_layer(&self) -> Vec<usize> {
        let free = |e: usize| {
            self.tets[e]
                .iter()
                .any(|&n| self.node_clamp[n] == usize::MAX)
        };
        let mut layer: Vec<usize> = self
            .clamp_elems
            .iter()
            .flatten()
            .copied()
            .filter(|&e| free(e))
            .collect();
        layer.sort_unstable();
        layer.dedup();
        layer
    }
    /// Each marker's element and its barycentric coordinates there (in the element's node
    /// order): what a field other than the linear one (quadratic elements' shape functions) is
    /// read at. A marker whose four weights are not one element's corners is refused.
    pub fn marker_elements(&self) -> Result<Vec<(usize, [f64; 4])>, MotionError> {
        let element: std::collections::HashMap<[usize; 4], usize> = self
            .tets
            .iter()
            .enumerate()
            .map(|(e, t)| {
                let mut k = *t;
                k.sort_unstable();
                (k, e)
            })
            .collect();
        self.markers
            .iter()
            .map(|m| {
                if m.weights.len() != 4 {
                    return Err(MotionError::Invalid(format!(
                        "marker {:?}: {} weights, expected 4 (one tetrahedron)",
                        m.name,
                        m.weights.len()
                    )));
                }
                let mut key: [usize; 4] = std::array::from_fn(|k| m.weights[k].0);
                key.sort_unstable();
                let e = *element.get(&key).ok_or_else(|| {
                    MotionError::Invalid(format!(
                        "marker {:?}: its nodes {key:?} are no element of the mesh",
                        m.name
                    ))
                })?;
                let bary = self.tets[e].map(|n| {
                    m.weights
                        .iter()
                        .find(|(w, _)| *w == n)
                        .map_or(0.0, |(_, w)| *w)
                });
                Ok((e, bary))
            })
            .collect()
    }

    /// Barycentric marker at rest point `p`: the containing tet (or, outside the mesh, the tet
    /// whose smallest barycentric coordinate is largest — linear extrapolation a hair outside).
    pub fn marker_at(&self, name: &str, p: [f64; 3]) -> Marker {
        let mut best = (f64::NEG_INFINITY, 0usize, [0.0; 4]);
        for (e, t) in self.tets.iter().enumerate() {
            let r = &self.rest[e];
            let x0 = Vector3::from(self.nodes[t[0]]);
            let d = Vector3::from(p) - x0;
            let mut w = [0.0; 4];
            for a in 1..4 {
                w[a] = r.grad[a].dot(&d);
            }
            w[0] = 1.0 - w[1] - w[2] - w[3];
            let m = w.iter().cloned().fold(f64::INFINITY, f64::min);
            if m > best.0 {
                best = (m, e, w);
            }
        }
        let t = self.tets[best.1];
        Marker {
            name: name.to_string(),
            weights: (0..4).map(|a| (t[a], best.2[a])).collect(),
        }
    }

    /// Element mass matrix (12 × 12) for ρV = `m`.
    pub fn element_mass(&self, m: f64) -> [[f64; 12]; 12] {
        let mut me = [[0.0; 12]; 12];
        for a in 0..4 {
            for b in 0..4 {
                let w = match self.mass {
                    MassKind::Lumped => {
                        if a == b {
                            m / 4.0
                        } else {
                            0.0
                        }
                    }
                    MassKind::Consistent => m / 20.0 * if a == b { 2.0 } else { 1.0 },
                };
                for i in 0..3 {
                    me[3 * a + i][3 * b + i] = w;
                }
            }
        }
        me
    }

    /// Gravity load (full dofs): ρ_e V_e g / 4 per node of each element, g the gravity as
    /// `mat` turns it ([`Self::gravity_of`]); where it is turned, the hanging masses acting
    /// from the start turn with it ([`Self::turned_weights`]).
    pub fn gravity_load(&self, mat: &Material) -> Vec<f64> {
        let g = self.gravity_of(mat);
        let mut f = vec![0.0; 3 * self.nodes.len()];
        for (e, t) in self.tets.iter().enumerate() {
            let m = mat.get(ParamKind::Density, e) * self.rest[e].volume / 4.0;
            for &n in t {
                for i in 0..3 {
                    f[3 * n + i] += m * g[i];
                }
            }
        }
        if g != self.gravity {
            let turn: [f64; 3] = std::array::from_fn(|i| g[i] - self.gravity[i]);
            for (node, m) in self.turned_weights() {
                for i in 0..3 {
                    f[3 * node + i] += m * turn[i];
                }
            }
        }
        f
    }

    /// (node, mass) of the hanging masses that act from the start: a declared mass hangs along
    /// the gravity acting, so its force turns with it (m (g − g₀) on its nodes beside the
    /// declared m g₀, [`Self::gravity_load`]). A mass that comes on later is not among them.
    pub fn turned_weights(&self) -> Vec<(usize, f64)> {
        self.loads
            .iter()
            .filter(|l| l.from_step == 0)
            .filter_map(|l| l.mass.map(|m| (l, m)))
            .flat_map(|(l, m)| l.shares().into_iter().map(move |(n, s)| (n, s * m)))
            .collect()
    }

    /// Two unit axes across the declared gravity ĝ: e_a, the coordinate axis least aligned with
    /// ĝ made orthogonal to it, and e_b = ĝ × e_a, so that a gravity along a coordinate axis
    /// turns toward coordinate axes. `None` without gravity.
    pub fn gravity_axes(&self) -> Option<([f64; 3], [f64; 3])> {
        let g = Vector3::from(self.gravity);
        let n = g.norm();
        if n.is_nan() || n <= 0.0 {
            return None;
        }
        let gh = g / n;
        let k = (0..3)
            .min_by(|&i, &j| gh[i].abs().total_cmp(&gh[j].abs()))
            .unwrap_or(0);
        let mut a = Vector3::zeros();
        a[k] = 1.0;
        let ea = (a - gh * a.dot(&gh)).normalize();
        let eb = gh.cross(&ea);
        Some((ea.into(), eb.into()))
    }

    /// The turned gravity's tangents (z_a, z_b) = (ln q_a, ln q_b) of `mat`'s
    /// [`ParamKind::GRAVITY`] values (global: read at element 0).
    fn gravity_tangents(&self, mat: &Material) -> [f64; 2] {
        if mat.values[0].is_empty() {
            return [0.0; 2];
        }
        ParamKind::GRAVITY.map(|k| mat.get(k, 0).ln())
    }

    /// The gravity acting (m/s²): the declared one turned by `mat`'s
    /// [`ParamKind::GRAVITY`] values, its magnitude kept: g = |g₀| u/|u| with
    /// u = ĝ₀ + z_a e_a + z_b e_b ([`Self::gravity_axes`]); the declared one when both are 1.
    pub fn gravity_of(&self, mat: &Material) -> [f64; 3] {
        let [za, zb] = self.gravity_tangents(mat);
        let Some((ea, eb)) = self.gravity_axes() else {
            return self.gravity;
        };
        if za == 0.0 && zb == 0.0 {
            return self.gravity;
        }
        let g = Vector3::from(self.gravity);
        let u = g / g.norm() + za * Vector3::from(ea) + zb * Vector3::from(eb);
        (u * (g.norm() / u.norm())).into()
    }

    /// ∂g/∂q of one of the [`ParamKind::GRAVITY`] kinds at `mat` ([`Self::gravity_of`]):
    /// |g₀|/|u| (e − û (û·e)) / q with e that kind's axis; zero for another kind or without
    /// gravity.
    pub fn gravity_derivative(&self, mat: &Material, kind: ParamKind) -> [f64; 3] {
        let Some((ea, eb)) = self.gravity_axes() else {
            return [0.0; 3];
        };
        let axis = match kind {
            ParamKind::GravityTiltA => ea,
            ParamKind::GravityTiltB => eb,
            _ => return [0.0; 3],
        };
        let [za, zb] = self.gravity_tangents(mat);
        let g = Vector3::from(self.gravity);
        let u = g / g.norm() + za * Vector3::from(ea) + zb * Vector3::from(eb);
        let (un, e) = (u.norm(), Vector3::from(axis));
        let uh = u / un;
        let q = mat.get(kind, 0);
        ((e - uh * uh.dot(&e)) * (g.norm() / un / q)).into()
    }

    /// External load at step `n` (full dofs): gravity plus the dead loads acting at `n`.
    pub fn external_load(&self, mat: &Material, n: usize) -> Vec<f64> {
        let mut f = self.gravity_load(mat);
        self.add_dead_loads(n, &mut f);
        f
    }

    /// Adds the dead loads acting at step `n` to `f` (full dofs): each load's force split
    /// equally over its nodes, or by its lever's shares.
    pub fn add_dead_loads(&self, n: usize, f: &mut [f64]) {
        for l in self.loads.iter().filter(|l| n >= l.from_step) {
            for (node, share) in l.shares() {
                for i in 0..3 {
                    f[3 * node + i] += share * l.force[i];
                }
            }
        }
    }

    /// The lumped mass matrix's diagonal over all dofs — ρV/4 of each element on its nodes and the
    /// loads' carried masses on theirs, summed in [`Self::mass_mul`]'s order — or `None` for the
    /// consistent mass, which couples nodes. A Newton iteration's residual (read twice where the
    /// step checks an update for overshoot) takes M (v − b) from it as one product a dof instead
    /// of a pass over the elements.
    pub fn lumped_mass_diagonal(&self, mat: &Material) -> Option<Vec<f64>> {
        if self.mass != MassKind::Lumped {
            return None;
        }
        let mut diag = vec![0.0; 3 * self.nodes.len()];
        for l in &self.loads {
            let m = l.mass_per_node();
            if m > 0.0 {
                for &n in &l.nodes {
                    for i in 0..3 {
                        diag[3 * n + i] += m;
                    }
                }
            }
        }
        for (e, t) in self.tets.iter().enumerate() {
            let m = mat.get(ParamKind::Density, e) * self.rest[e].volume / 4.0;
            for &n in t {
                for i in 0..3 {
                    diag[3 * n + i] += m;
                }
            }
        }
        Some(diag)
    }

    /// y = M w over all dofs (element-wise, so consistent mass couples clamped and free nodes),
    /// with the carried masses of the loads with inertia on their nodes' diagonal.
    pub fn mass_mul(&self, mat: &Material, w: &[f64], y: &mut [f64]) {
        for l in &self.loads {
            let m = l.mass_per_node();
            if m > 0.0 {
                for &n in &l.nodes {
                    for i in 0..3 {
                        y[3 * n + i] += m * w[3 * n + i];
                    }
                }
            }
        }
        for (e, t) in self.tets.iter().enumerate() {
            let m = mat.get(ParamKind::Density, e) * self.rest[e].volume;
            match self.mass {
                MassKind::Lumped => {
                    for &n in t {
                        for i in 0..3 {
                            y[3 * n + i] += m / 4.0 * w[3 * n + i];
                        }
                    }
                }
                MassKind::Consistent => {
                    for &a in t {
                        for &b in t {
                            let s = m / 20.0 * if a == b { 2.0 } else { 1.0 };
                            for i in 0..3 {
                                y[3 * a + i] += s * w[3 * b + i];
                            }
                        }
                    }
                }
            }
        }
    }

    /// Mass matrix values on the free pattern.
    pub fn mass_values(&self, mat: &Material) -> Vec<f64> {
        let mut v = vec![0.0; self.pattern.nnz()];
        for e in 0..self.tets.len() {
            let me = self.element_mass(mat.get(ParamKind::Density, e) * self.rest[e].volume);
            self.pattern.add_element(e, &me, 1.0, &mut v);
        }
        self.add_load_masses(&self.free, &self.pattern, &mut v);
        v
    }

    /// Adds the carried masses of the loads with inertia to the diagonal of a mass matrix on
    /// `pattern`, whose dof numbering is `free` (the loads' nodes keep their indices in it).
    pub fn add_load_masses(&self, free: &[usize], pattern: &Pattern, values: &mut [f64]) {
        for l in &self.loads {
            let m = l.mass_per_node();
            if m > 0.0 {
                for &n in &l.nodes {
                    for i in 0..3 {
                        // Loads sit on free nodes only (the dataset reader refuses clamped ones).
                        let d = free[3 * n + i];
                        if d != usize::MAX {
                            pattern.add_diagonal(d, m, values);
                        }
                    }
                }
            }
        }
    }

    /// Gathers the four nodes' 3-vectors of element `e` from a full-dof vector.
    pub fn gather(&self, e: usize, x: &[f64]) -> [Vector3<f64>; 4] {
        self.tets[e].map(|n| Vector3::new(x[3 * n], x[3 * n + 1], x[3 * n + 2]))
    }

    /// Free-dof restriction of a full vector.
    pub fn restrict(&self, full: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; self.nfree];
        for (d, &f) in self.free.iter().enumerate() {
            if f != usize::MAX {
                out[f] = full[d];
            }
        }
        out
    }

    /// Full vector (zeros on clamped dofs) from a free-dof vector.
    pub fn expand(&self, free_vec: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; self.free.len()];
        for (d, &f) in self.free.iter().enumerate() {
            if f != usize::MAX {
                out[d] = free_vec[f];
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `Material::values` is indexed by `kind as usize` and derivative slots follow `EVERY`: the
    /// joined list must be the discriminants 0..10 in order, each kind once, and the spline
    /// kinds' slots begin after them.
    #[test]
    fn every_kind_is_all_then_creep_then_gravity_in_index_order() {
        assert_eq!(
            ParamKind::EVERY.map(|k| k as usize),
            [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]
        );
        assert_eq!(ParamKind::SplineF as usize, MATERIAL_KINDS);
    }

    /// A model of `mesh` with nothing clamped, gravity down z, lumped mass, one step of 10 ms.
    fn unclamped(mesh: &Mesh) -> Model {
        Model::new(
            mesh,
            Vec::new(),
            Vec::new(),
            0.01,
            1,
            [0.0, 0.0, -9.81],
            MassKind::Lumped,
        )
        .unwrap()
    }

    /// The lumped diagonal is the lumped mass: M w from it agrees with the element pass
    /// [`Model::mass_mul`] (two elements sharing a face, densities that differ, a hung weight
    /// whose inertia rides on two nodes), and the consistent mass has none.
    #[test]
    fn the_lumped_diagonal_is_the_element_passs_mass() {
        let mesh = Mesh {
            nodes: vec![
                [0.0; 3],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
                [1.0, 1.0, 1.0],
            ],
            node_tags: vec![1, 2, 3, 4, 5],
            tets: vec![[0, 1, 2, 3], [1, 2, 3, 4]],
            node_groups: Default::default(),
        };
        let mut model = unclamped(&mesh);
        model.loads.push(DeadLoad {
            name: "weight".into(),
            nodes: vec![3, 4],
            force: [0.0, 0.0, -0.5],
            from_step: 0,
            mass: Some(0.051),
            inertia: true,
            lever: None,
        });
        let mut mat = Material::uniform(2, 1.0, 1.0, 0.0, 1.0, 1100.0);
        mat.set(&[Param::of_element(ParamKind::Density, 1)], &[950.0]);
        let w: Vec<f64> = (0..15).map(|d| 0.3 + 0.17 * d as f64).collect();
        let mut y = vec![0.0; 15];
        model.mass_mul(&mat, &w, &mut y);
        let diag = model.lumped_mass_diagonal(&mat).unwrap();
        for d in 0..15 {
            assert!(
                (diag[d] * w[d] - y[d]).abs() <= 1e-14 * y[d].abs(),
                "dof {d}: {} against {}",
                diag[d] * w[d],
                y[d]
            );
        }
        model.mass = MassKind::Consistent;
        assert!(model.lumped_mass_diagonal(&mat).is_none());
    }

    /// The turned gravity keeps its magnitude, turns toward the axes across the declared one by
    /// the angle whose tangent is ln q, and its derivative is the central difference's.
    #[test]
    fn the_gravity_turns_by_the_tangent_and_keeps_its_size() {
        let mesh = Mesh {
            nodes: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            node_tags: vec![1, 2, 3, 4],
            tets: vec![[0, 1, 2, 3]],
            node_groups: Default::default(),
        };
        let model = unclamped(&mesh);
        let (ea, eb) = model.gravity_axes().unwrap();
        assert_eq!((ea, eb), ([1.0, 0.0, 0.0], [0.0, -1.0, 0.0]));
        let mut mat = Material::uniform(1, 1.0, 1.0, 0.0, 1.0, 1.0);
        let angle = 5f64.to_radians();
        mat.set_uniform(ParamKind::GravityTiltA, angle.tan().exp());
        let g = model.gravity_of(&mat);
        assert!((g[0] - 9.81 * angle.sin()).abs() < 1e-12, "{g:?}");
        assert!((g[2] + 9.81 * angle.cos()).abs() < 1e-12, "{g:?}");
        for kind in ParamKind::GRAVITY {
            let q = mat.get(kind, 0);
            let at = |v: f64| {
                let mut m = mat.clone();
                m.set_uniform(kind, v);
                model.gravity_of(&m)
            };
            let (h, d) = (1e-6 * q, model.gravity_derivative(&mat, kind));
            let (up, down) = (at(q + h), at(q - h));
            for i in 0..3 {
                let fd = (up[i] - down[i]) / (2.0 * h);
                assert!((fd - d[i]).abs() < 1e-6, "{kind:?} {i}: {fd} vs {}", d[i]);
            }
        }
    }
}
