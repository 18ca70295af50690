//! The static room's library of candidate effects: what each is called, how many parameters it
//! adds and where they start, and how the report names them. A candidate's forward model is
//! [`super::model::Model`]'s, what in the residual points to it is [`super::signature`]'s, its
//! detectable magnitude [`super::power`]'s.

use serde::Serialize;

use super::context::LAYER_NODES;

/// A candidate effect of the library (each an augmented model with extra parameters).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Candidate {
    /// Force-sensor calibration curve: f_model = f_reported · (|f_reported| / f_ref)^p. 1 param
    /// (p). A global scale is not separable from E in a linear model, so only the power is fitted.
    Calibration,
    /// Tilted probe / tangential friction: f_model = f_reported + |f_reported| (a t₁ + b t₂) with
    /// t₁, t₂ perpendicular to the mean reported direction. 2 params (a, b).
    Tilt,
    /// Compliant support, rigid: the fixed face moves rigidly by c_t F (translation, c_t in 1e-4 m/N)
    /// and rotates by c_r (r × F) / h² (c_r in 1e-4 rad m/N·m, h the half width). 2 params.
    Boundary,
    /// Elastic foundation (Winkler support): the supported face — the boundary triangles on the
    /// declared fixed nodes — rests on springs instead of being held, k_n = E / ℓ_n along the
    /// face's normal and k_t = k_n e^{θ₁} in its plane, with ℓ_n = h e^{θ₀} an equivalent
    /// thickness (h the half width, E the fitted modulus, so the support scales with the body).
    /// Unlike [`Candidate::Boundary`]'s rigid motion of the base, the base deforms with the load
    /// under it (an object on a soft mat, a base glued to a compliant plate). 2 params (θ₀, θ₁);
    /// the fixed support is its stiff limit θ₀ → −∞.
    Support,
    /// Marker registration offset: one rigid transform (rotation vector in 1e-3 rad, translation
    /// in 1e-4 m) about the mesh centre on every simulated marker. 6 params.
    Registration,
    /// An unreported tangential force that differs from measurement to measurement (friction
    /// at the tip, a probe held at another tilt each time): f = f_reported + |f|(a_i t₁ + b_i t₂).
    /// Profiled, not in θ: each measurement's marker response to the two tangential directions
    /// (two more solves, warm-started) and the (a_i, b_i) of least squares in closed form.
    /// 2 parameters per measurement, counted by BIC and the held-out gate.
    TiltEach,
    /// The probe's contact patch is not the declared disc: the force is a uniform pressure over
    /// the rest surface within radius r = s · r_declared (ln s in θ; the change from the declared
    /// patch integrated consistently, [`palpate_runtime::contact_rule::contact_weights_consistent`]). A soft object wraps around a rounded probe
    /// (the patch of a sphere grows with the indentation), and on a coarse mesh the lumped rule
    /// puts the whole force on the one or two nodes within a small radius: either leaves a
    /// residual concentrated within a probe radius or two of the contact. 1 param (ln s), the
    /// model without it at ln s = 0 ([`super::model::Model::load_vector`]: the lumped load plus the change the
    /// wider or narrower patch makes).
    ContactRadius,
    /// A different registration offset in every measurement (the markers re-tracked, the object
    /// re-seated between probes): each measurement's simulated markers are moved by the rigid
    /// transform that best maps them onto its measured ones (Horn's closed form, weighted to the
    /// markers the load barely moves: w = 1/(1 + (|u|/3σ)²) with u the simulated displacement).
    /// Profiled, not in θ: 6 parameters per measurement, counted by BIC and the held-out gate.
    RegistrationEach,
    /// A force sensor whose gain differs from measurement to measurement (a drifting amplifier,
    /// a probe re-seated on its load cell): measurement i's force is s_i times the reported one.
    /// Profiled, not in θ: in the warped linear model the displacement scales with the force, so
    /// s_i is the least-squares scale of the simulated marker displacements onto the measured
    /// ones, and the s_i of the fitted measurements are divided by their geometric mean (a common
    /// gain is Young's modulus's to fit). 1 parameter per measurement (one fewer when fitted
    /// together), counted by BIC and the held-out gate.
    ForceScaleEach,
    /// Gravity preload: body force ρ g (ρ in 1000 kg/m³, g = the declared gravity or 9.81 m/s²
    /// along −z) acting in every measurement. 1 param.
    Gravity,
    /// Inhomogeneity: log E varies over the bounding box as a trilinear field on a coarse grid
    /// (default 3 × 3 × 2 nodes; the first node is the reference, so grid − 1 params).
    Inhomogeneity,
    /// Layered material: log E varies with depth below the probed face (along the mean reported
    /// force direction), piecewise linear over [`LAYER_NODES`] equally spaced depths, the deepest
    /// node the reference. LAYER_NODES − 1 params.
    Layer,
    /// A stiff or soft inclusion: log E += a exp(−½ ‖x_e − p‖² / r²), a Gaussian blob with
    /// contrast a, centre p = p₀ + h θ (h the half width, p₀ below the mean contact point at a
    /// quarter of the depth) and radius r = ½ h exp(θ_r). 5 params (a, p, θ_r).
    Inclusion,
    /// Strain stiffening (non-linear material): secant modulus E_e = E (1 + β (‖ε_e‖ / 0.1)²)
    /// from the element's warped strain (E / (1 + |β| …) for β < 0), solved to its fixed point.
    /// 1 param (β).
    Stiffening,
    /// Marker noise above the declared level. Not a model candidate (not in [`ALL_CANDIDATES`],
    /// never part of a [`super::model::Model`]): it changes no prediction, only how large the residual floor
    /// is. Adopted after the structural loop by the nugget test of [`super::noise`]. 0 params.
    Noise,
    /// Noise in the declared rest positions (the rest scan is a measurement too). Like `noise`
    /// not a model candidate: it changes no prediction, only the covariance the final residual is
    /// judged with. Adopted after the structural loop by the persistent-nugget test of
    /// [`super::rest_noise`]. 0 params.
    RestNoise,
}

/// Every candidate, in the order they are tried.
pub const ALL_CANDIDATES: [Candidate; 14] = [
    Candidate::Calibration,
    Candidate::Tilt,
    Candidate::TiltEach,
    Candidate::ContactRadius,
    Candidate::Boundary,
    Candidate::Support,
    Candidate::Registration,
    Candidate::RegistrationEach,
    Candidate::ForceScaleEach,
    Candidate::Gravity,
    Candidate::Inhomogeneity,
    Candidate::Layer,
    Candidate::Inclusion,
    Candidate::Stiffening,
];

impl Candidate {
    /// The names of `list` joined by `separator`, or `none` for an empty list.
    pub fn names(list: &[Candidate], separator: &str, none: &str) -> String {
        if list.is_empty() {
            none.to_string()
        } else {
            list.iter()
                .map(|c| c.name())
                .collect::<Vec<_>>()
                .join(separator)
        }
    }

    /// Name (as in reports).
    pub fn name(self) -> &'static str {
        match self {
            Candidate::Calibration => "calibration",
            Candidate::Tilt => "tilt",
            Candidate::TiltEach => "tilt-each",
            Candidate::ContactRadius => "contact-radius",
            Candidate::Boundary => "boundary",
            Candidate::Support => "support",
            Candidate::Registration => "registration",
            Candidate::RegistrationEach => "registration-each",
            Candidate::ForceScaleEach => "force-scale-each",
            Candidate::Gravity => "gravity",
            Candidate::Inhomogeneity => "inhomogeneity",
            Candidate::Layer => "layer",
            Candidate::Inclusion => "inclusion",
            Candidate::Stiffening => "stiffening",
            Candidate::Noise => "noise",
            Candidate::RestNoise => "rest-noise",
        }
    }

    /// Number of parameters the effect adds.
    pub fn params(self, grid: [usize; 3]) -> usize {
        match self {
            Candidate::Calibration
            | Candidate::Gravity
            | Candidate::Stiffening
            | Candidate::ContactRadius => 1,
            Candidate::Tilt | Candidate::Boundary | Candidate::Support => 2,
            Candidate::Registration => 6,
            Candidate::Inhomogeneity => grid[0] * grid[1] * grid[2] - 1,
            Candidate::Layer => LAYER_NODES - 1,
            Candidate::Inclusion => 5,
            Candidate::Noise
            | Candidate::RestNoise
            | Candidate::RegistrationEach
            | Candidate::TiltEach
            | Candidate::ForceScaleEach => 0,
        }
    }

    /// Parameters fitted in closed form for each of `measurements` measurements rather than in θ
    /// (counted by BIC and the held-out gate all the same).
    pub fn profiled(self, measurements: usize) -> usize {
        match self {
            Candidate::RegistrationEach => 6 * measurements,
            Candidate::TiltEach => 2 * measurements,
            Candidate::ForceScaleEach => measurements,
            _ => 0,
        }
    }

    /// Every parameter the effect adds over `measurements` measurements: θ's and the profiled.
    pub fn all_params(self, grid: [usize; 3], measurements: usize) -> usize {
        self.params(grid) + self.profiled(measurements)
    }

    /// Starting values of its block when it is added to a fitted model (zero = the effect is
    /// absent, except the inclusion, whose position and size are invisible at zero contrast and
    /// so start at a modest contrast).
    pub fn start(self, grid: [usize; 3]) -> Vec<f64> {
        let mut v = vec![0.0; self.params(grid)];
        if self == Candidate::Inclusion {
            v[0] = 0.5;
        }
        if self == Candidate::Support {
            // The fixed support is the limit ℓ_n → 0, where the effect's gradient vanishes too:
            // start where a support would add a tenth of the body's compliance, ℓ_n = 0.1 h,
            // k_t = k_n.
            v[0] = SUPPORT_START.ln();
        }
        v
    }

    /// Whether its parameters change the FEM solve (else they act on the solved markers only).
    pub(super) fn affects_solve(self) -> bool {
        !matches!(
            self,
            Candidate::Boundary
                | Candidate::Registration
                | Candidate::RegistrationEach
                | Candidate::ForceScaleEach
        )
    }

    /// Names and physical units of its parameters (after scaling), for reports.
    pub fn param_names(self, grid: [usize; 3]) -> Vec<(String, &'static str, f64)> {
        let v = |n: &str, u, s| (n.to_string(), u, s);
        match self {
            Candidate::Calibration => vec![v("power p", "", 1.0)],
            Candidate::Tilt => vec![v("tangential a", "", 1.0), v("tangential b", "", 1.0)],
            Candidate::ContactRadius => vec![v("contact radius ln s (r = s r_declared)", "", 1.0)],
            Candidate::Boundary => vec![
                v("support compliance c_t", "m/N", 1e-4),
                v("support rotation c_r", "m/N", 1e-4),
            ],
            Candidate::Support => vec![
                v(
                    "foundation ln(ℓ_n/h) (k_n = E/ℓ_n, h the half width)",
                    "",
                    1.0,
                ),
                v("foundation ln(k_t/k_n)", "", 1.0),
            ],
            Candidate::Registration => vec![
                v("rotation ωx", "rad", 1e-3),
                v("rotation ωy", "rad", 1e-3),
                v("rotation ωz", "rad", 1e-3),
                v("translation tx", "m", 1e-4),
                v("translation ty", "m", 1e-4),
                v("translation tz", "m", 1e-4),
            ],
            Candidate::Gravity => vec![v("density ρ", "kg/m³", 1000.0)],
            Candidate::Inhomogeneity => (1..grid[0] * grid[1] * grid[2])
                .map(|k| (format!("Δlog E at grid node {k}"), "", 1.0))
                .collect(),
            Candidate::Stiffening => vec![v("stiffening β", "", 1.0)],
            Candidate::Layer => (0..LAYER_NODES - 1)
                .map(|k| (format!("Δlog E at depth {k}/{}", LAYER_NODES - 1), "", 1.0))
                .collect(),
            Candidate::Inclusion => vec![
                v("log contrast a", "", 1.0),
                v("centre offset x / h", "", 1.0),
                v("centre offset y / h", "", 1.0),
                v("centre offset z / h", "", 1.0),
                v("log radius θ_r (r = h/2 e^θ_r)", "", 1.0),
            ],
            Candidate::Noise
            | Candidate::RestNoise
            | Candidate::RegistrationEach
            | Candidate::TiltEach
            | Candidate::ForceScaleEach => Vec::new(),
        }
    }
}

/// [`Candidate::Support`]'s starting equivalent thickness ℓ_n / h.
pub(super) const SUPPORT_START: f64 = 0.1;

impl crate::select::CandidateEffect for Candidate {
    const LIBRARY: &'static str = "candidate";
    fn library() -> Vec<Self> {
        ALL_CANDIDATES.to_vec()
    }
    fn label(self) -> String {
        self.name().into()
    }
}
