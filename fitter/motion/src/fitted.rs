//! The record `palpate fit-motion -o fit.json` writes and `palpate validate --model fit.json`
//! reads: the fitted material per element, what was fitted and what was held, and per fitted run
//! its load and where it came to rest (the points of the linear baseline of
//! [`super::predict::linear_baseline`]).

use serde::{Deserialize, Serialize};

use super::model::{Material, Model, ParamKind};

/// Gives every load of `model` declared as a mass the inertia of that mass (`on`), or none.
pub fn set_hanging_inertia(model: &mut Model, on: bool) {
    for l in &mut model.loads {
        l.inertia = on && l.mass.is_some() && l.from_step == 0;
    }
}

/// The format tag of [`FittedModel`].
pub const FORMAT: &str = "palpate-motion-fit/2";

/// The `schema_version` written with a [`FittedModel`] ([`FittedModel::to_json`]).
pub const SCHEMA_VERSION: u32 = 2;

/// The format tags a reader accepts: version 1 had the same numbers under names without units
/// (`lambda`, `mu`, `viscosity`, `h`, `density`, `runtime_lambda_alpha`), still read.
pub const READABLE_FORMATS: [&str; 2] = ["palpate-motion-fit/1", FORMAT];

/// A motion fit, as written to JSON (`fit.json`). Field names carry their units; the Rust names
/// follow the papers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FittedModel {
    /// [`FORMAT`].
    pub format: String,
    /// The fitted datasets (directories as given).
    pub datasets: Vec<String>,
    /// Nodes of the mesh the material belongs to.
    pub nodes: usize,
    /// Tetrahedra of that mesh (one value per element in each array below, or one for all).
    pub tets: usize,
    /// Lamé's λ per element (Pa).
    #[serde(rename = "lame_lambda_pa", alias = "lambda")]
    pub lambda: Vec<f64>,
    /// Shear modulus μ per element (Pa).
    #[serde(rename = "shear_modulus_pa", alias = "mu")]
    pub mu: Vec<f64>,
    /// Viscosity coefficient of the power law (Pa·s^h) per element (the paper's ν; not Poisson's ratio).
    #[serde(rename = "viscosity_pa_s_h", alias = "viscosity")]
    pub viscosity: Vec<f64>,
    /// Power-law index h per element.
    #[serde(rename = "power_law_index", alias = "h")]
    pub h: Vec<f64>,
    /// Density per element (kg/m³).
    #[serde(rename = "density_kg_m3", alias = "density")]
    pub density: Vec<f64>,
    /// Strain-stiffening coefficient c per element (Pa; the c (Ī₁ − 3)² term,
    /// [`super::model::ParamKind::Stiffening`]); absent in older records and when not fitted,
    /// which reads as 0 (the paper's eq. 16).
    #[serde(
        rename = "stiffening_pa",
        default,
        skip_serializing_if = "Vec::is_empty"
    )]
    pub stiffening: Vec<f64>,
    /// The creep branch ([`super::relaxation`]), absent without one (and in older records).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub creep: Option<CreepRecord>,
    /// How the viscosity read the velocity gradient ([`crate::viscosity::Form`]): absent in
    /// records of the rest-gradient law, the only one before the objective form.
    #[serde(default, skip_serializing_if = "is_rest_gradient")]
    pub viscosity_form: crate::viscosity::Form,
    /// Poisson's ratio, when it was held fixed (λ followed μ).
    #[serde(rename = "poisson_ratio_fixed", alias = "poisson_fixed")]
    pub poisson_fixed: Option<f64>,
    /// Whether hanging masses moved with their nodes (inertia) in the fit; a prediction applies
    /// the same to the loads of the run it predicts.
    #[serde(default)]
    pub hanging_inertia: bool,
    /// Whether each run's markers were offset in time against the simulation
    /// ([`super::time_offset`]); a prediction then scans the offset of the run it predicts (a
    /// new capture has its own release instant) and reports it.
    #[serde(default)]
    pub time_offset: bool,
    /// How far beyond their nodes the hanging weights acted along the body's long axis (m;
    /// [`super::load_point`]), absent when they acted on their nodes; a prediction moves the
    /// hanging weights of the run it predicts by the same lever.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub load_lever_m: Option<f64>,
    /// The gravity's turn from its declared direction, (tan toward e_a, tan toward e_b) of
    /// [`super::model::Model::gravity_axes`] ([`ParamKind::GRAVITY`]); absent when it acted as
    /// declared. A prediction turns the gravity of the run it predicts by the same.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gravity_turn: Option<[f64; 2]>,
    /// The fitted parameter kinds (the others were held at their dataset values).
    pub fitted: Vec<String>,
    /// The thesis coefficients (λ_F, α_G) of each element as exported to the runtime (Pa; not
    /// Lamé's λ: `palpate_fem::names::THESIS_PAIR_NOTE`).
    #[serde(rename = "thesis_lambda_f_alpha_g_pa", alias = "runtime_lambda_alpha")]
    pub runtime_lambda_alpha: Vec<[f64; 2]>,
    /// RMS marker error over all runs at the fitted parameters (m).
    pub rms_marker_m: f64,
    /// RMS clamp-force error over all runs (N).
    pub rms_force_n: f64,
    /// Simulations the fit ran.
    pub evaluations: usize,
    /// Per fitted run.
    pub runs: Vec<FittedRun>,
    /// The shear modulus of the fitted runs' rest states on elements that do not lock, beside
    /// the one on this mesh's linear elements (the mesh-convergence check); absent when the check
    /// was not made. With it a prediction can carry the material to another mesh
    /// ([`super::transfer`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub converged: Option<ConvergedModulus>,
}

/// The material's modulus as elements that do not lock see it, and the same rest states'
/// modulus on the fit's own linear mesh: their ratio is how much that mesh's locking stiffens
/// it (`fit.json`'s `converged`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConvergedModulus {
    /// The discretisation of the material's modulus ("P2": quadratic tetrahedra).
    pub design: String,
    /// Poisson's ratio held in both fits.
    pub poisson: f64,
    /// μ fitted to the rest states with `design` (Pa): the material's.
    pub shear_modulus_pa: f64,
    /// μ fitted to the same rest states on the fit's linear mesh (Pa): the mesh's.
    pub mesh_shear_modulus_pa: f64,
}

/// The creep branch of a fit ([`super::relaxation`]): one value for every element or one per
/// element.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CreepRecord {
    /// Relaxed fraction g ([`ParamKind::CreepFraction`]): the short-time elastic stress is
    /// (1 + g) times the long-term law's.
    pub fraction: Vec<f64>,
    /// Relaxation time τ (s, [`ParamKind::CreepTime`]).
    pub time_s: Vec<f64>,
}

impl CreepRecord {
    /// The record of `mat`'s branch, `None` without one.
    pub fn of(mat: &Material) -> Option<Self> {
        mat.has_creep().then(|| Self {
            fraction: mat.values[ParamKind::CreepFraction as usize].clone(),
            time_s: mat.values[ParamKind::CreepTime as usize].clone(),
        })
    }
}

/// Whether `f` is the rest-gradient law (not written to a record).
fn is_rest_gradient(f: &crate::viscosity::Form) -> bool {
    *f == crate::viscosity::Form::RestGradient
}

impl FittedModel {
    /// The fitted material on its `tets` elements: each field holds one value (the same in
    /// every element) or one per element; the stiffening may be absent (0). The error names
    /// the field, what it holds and what was expected.
    pub fn material(&self) -> Result<Material, String> {
        let ne = self.tets;
        let per_element = |name: &str, v: &[f64], absent: Option<f64>| match (v.len(), absent) {
            (0, Some(a)) => Ok(vec![a; ne]),
            (1, _) => Ok(vec![v[0]; ne]),
            (n, _) if n == ne => Ok(v.to_vec()),
            (n, _) => Err(format!("field {name}: {n} values, expected 1 or {ne}")),
        };
        let mut mat = Material::uniform(ne, 1.0, 1.0, 1.0, 1.0, 1.0);
        mat.viscous_form = self.viscosity_form;
        mat.values = [
            per_element("lame_lambda_pa", &self.lambda, None)?,
            per_element("shear_modulus_pa", &self.mu, None)?,
            per_element("viscosity_pa_s_h", &self.viscosity, None)?,
            per_element("power_law_index", &self.h, None)?,
            per_element("density_kg_m3", &self.density, None)?,
            per_element("stiffening_pa", &self.stiffening, Some(0.0))?,
            per_element(
                "creep.fraction",
                self.creep.as_ref().map_or(&[][..], |c| &c.fraction),
                Some(0.0),
            )?,
            per_element(
                "creep.time_s",
                self.creep.as_ref().map_or(&[][..], |c| &c.time_s),
                Some(1.0),
            )?,
            vec![self.gravity_turn.map_or(1.0, |t| t[0].exp()); ne],
            vec![self.gravity_turn.map_or(1.0, |t| t[1].exp()); ne],
        ];
        // A tangent of 100 is a turn of 89.4°: beyond it the record is not a turn of gravity
        // (and exp of it, the value carried, would overflow).
        if let Some(t) = self
            .gravity_turn
            .filter(|t| !t.iter().all(|z| z.is_finite() && z.abs() <= 100.0))
        {
            return Err(format!(
                "field gravity_turn: {t:?}, expected two finite tangents of at most 100 in size"
            ));
        }
        // A hand-edited or corrupt record must not be simulated: each value within what it
        // means (moduli and density > 0, the stiffening ≥ 0).
        // λ may be negative (an auxetic material) and h is any exponent: those only finite.
        for (k, (name, sign)) in [
            ("lame_lambda_pa", ""),
            ("shear_modulus_pa", "> 0"),
            ("viscosity_pa_s_h", "≥ 0"),
            ("power_law_index", ""),
            ("density_kg_m3", "> 0"),
            ("stiffening_pa", "≥ 0"),
            ("creep.fraction", "≥ 0"),
            ("creep.time_s", "> 0"),
        ]
        .into_iter()
        .enumerate()
        {
            for (e, &v) in mat.values[k].iter().enumerate() {
                let ok = v.is_finite()
                    && match sign {
                        "> 0" => v > 0.0,
                        "≥ 0" => v >= 0.0,
                        _ => true,
                    };
                if !ok {
                    return Err(format!(
                        "field {name}: element {e} holds {v}, expected a finite value {sign}"
                    ));
                }
            }
            if name == "density_kg_m3" {
                if let Some(v) = mat.values[k]
                    .iter()
                    .find(|v| **v > palpate_fem::sanity::MAX_DENSITY_KG_M3)
                {
                    return Err(format!(
                        "field {name}: {v} kg/m³ is denser than any material (at most {} kg/m³)",
                        palpate_fem::sanity::MAX_DENSITY_KG_M3
                    ));
                }
            }
        }
        Ok(mat)
    }

    /// The stiffening field to record for `mat`: empty where it is 0 everywhere (eq. 16), so
    /// records of Neo-Hookean fits stay as they were.
    pub fn stiffening_of(mat: &Material) -> Vec<f64> {
        let c = &mat.values[ParamKind::Stiffening as usize];
        if c.iter().all(|&v| v == 0.0) {
            Vec::new()
        } else {
            c.clone()
        }
    }

    /// The gravity turn to record for `mat` ([`Self::gravity_turn`]): `None` where it acts as
    /// declared.
    pub fn gravity_turn_of(mat: &Material) -> Option<[f64; 2]> {
        if mat.values[0].is_empty() {
            return None;
        }
        let t = ParamKind::GRAVITY.map(|k| mat.get(k, 0).ln());
        (t != [0.0; 2]).then_some(t)
    }

    /// The JSON text of `fit.json`: `schema_version` first, then the record.
    pub fn to_json(&self) -> Result<String, serde_json::Error> {
        serde_json::to_string_pretty(&palpate_fem::io::json::Versioned::new(SCHEMA_VERSION, self))
    }
}

/// One fitted run's summary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FittedRun {
    /// The dataset directory.
    pub dataset: String,
    /// Dead loads along gravity at the end of the run (N), [`super::predict::load_along_gravity`].
    pub load_n: f64,
    /// RMS marker error of this run at the fitted parameters (m).
    pub rms_marker_m: f64,
    /// The run's time offset: its markers compared with the simulation this much later (s).
    #[serde(default)]
    pub time_offset_s: f64,
    /// The markers, in the order of `final_displacement_m`.
    pub markers: Vec<String>,
    /// Each marker's observed rest state minus its rest position (m), `None` if unseen.
    pub final_displacement_m: Vec<Option<[f64; 3]>>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::viscosity::Form;

    /// A `fit.json` of format 1 (names without units) still reads, into the same record that
    /// format 2 writes with units in its names and `schema_version` first.
    #[test]
    fn format_1_still_reads_and_format_2_names_its_units() {
        let old = r#"{"format": "palpate-motion-fit/1", "datasets": ["a"], "nodes": 4, "tets": 1,
            "lambda": [1e4], "mu": [2e4], "viscosity": [3.0], "h": [1.0], "density": [47.0],
            "poisson_fixed": null, "hanging_inertia": false, "fitted": ["mu", "nu"],
            "runtime_lambda_alpha": [[6e4, 1e4]], "rms_marker_m": 1e-4, "rms_force_n": 0.0,
            "evaluations": 3, "runs": []}"#;
        let f: FittedModel = serde_json::from_str(old).unwrap();
        assert!(READABLE_FORMATS.contains(&f.format.as_str()));
        assert_eq!((f.lambda[0], f.mu[0], f.viscosity[0]), (1e4, 2e4, 3.0));
        let text = f.to_json().unwrap();
        assert!(text.starts_with("{\n  \"schema_version\": 2,"), "{text}");
        for name in [
            "\"lame_lambda_pa\"",
            "\"shear_modulus_pa\"",
            "\"viscosity_pa_s_h\"",
            "\"power_law_index\"",
            "\"density_kg_m3\"",
            "\"thesis_lambda_f_alpha_g_pa\"",
        ] {
            assert!(text.contains(name), "{name} in {text}");
        }
        let back: FittedModel = serde_json::from_str(&text).unwrap();
        assert_eq!(back, f);
    }

    /// A gravity turn reads back into the material as exp of its tangents; one that is no turn
    /// (not finite, or beyond 89.4°) is refused with its field.
    #[test]
    fn a_gravity_turn_reads_back_and_a_wild_one_is_refused() {
        let text = r#"{"format": "palpate-motion-fit/1", "datasets": ["a"], "nodes": 4, "tets": 1,
            "lambda": [1e4], "mu": [2e4], "viscosity": [3.0], "h": [1.0], "density": [47.0],
            "poisson_fixed": null, "hanging_inertia": false, "fitted": ["mu"],
            "runtime_lambda_alpha": [[6e4, 1e4]], "rms_marker_m": 1e-4, "rms_force_n": 0.0,
            "evaluations": 3, "runs": [], "gravity_turn": [0.05, -0.02]}"#;
        let f: FittedModel = serde_json::from_str(text).unwrap();
        let mat = f.material().unwrap();
        let back = FittedModel::gravity_turn_of(&mat).unwrap();
        assert!((back[0] - 0.05).abs() < 1e-15 && (back[1] + 0.02).abs() < 1e-15);
        for bad in [[1e3, 0.0], [0.0, f64::NAN]] {
            let mut g = f.clone();
            g.gravity_turn = Some(bad);
            let e = g.material().unwrap_err();
            assert!(e.contains("field gravity_turn: "), "{e}");
        }
    }

    /// The viscosity law reads back into the material, is written only when it is the
    /// objective one, and an unknown name is refused.
    #[test]
    fn the_viscosity_form_reads_back_and_is_written_only_when_objective() {
        let text = r#"{"format": "palpate-motion-fit/1", "datasets": ["a"], "nodes": 4, "tets": 1,
            "lambda": [1e4], "mu": [2e4], "viscosity": [3.0], "h": [1.0], "density": [47.0],
            "poisson_fixed": null, "hanging_inertia": false, "fitted": ["mu"],
            "runtime_lambda_alpha": [[6e4, 1e4]], "rms_marker_m": 1e-4, "rms_force_n": 0.0,
            "evaluations": 3, "runs": []}"#;
        let mut f: FittedModel = serde_json::from_str(text).unwrap();
        assert_eq!(f.material().unwrap().viscous_form, Form::RestGradient);
        assert!(!serde_json::to_string(&f)
            .unwrap()
            .contains("viscosity_form"));
        f.viscosity_form = Form::Objective;
        let written = serde_json::to_string(&f).unwrap();
        assert!(
            written.contains(r#""viscosity_form":"objective""#),
            "{written}"
        );
        let back: FittedModel = serde_json::from_str(&written).unwrap();
        assert_eq!(back.material().unwrap().viscous_form, Form::Objective);
        let wrong = written.replace(r#""objective""#, r#""spatial""#);
        assert!(serde_json::from_str::<FittedModel>(&wrong).is_err());
    }

    #[test]
    fn a_negative_density_or_modulus_is_refused_with_its_field() {
        let good = r#"{"format": "palpate-motion-fit/1", "datasets": ["a"], "nodes": 4, "tets": 1,
            "lambda": [1e4], "mu": [2e4], "viscosity": [3.0], "h": [1.0], "density": [47.0],
            "poisson_fixed": null, "hanging_inertia": false, "fitted": ["mu", "nu"],
            "runtime_lambda_alpha": [[6e4, 1e4]], "rms_marker_m": 1e-4, "rms_force_n": 0.0,
            "evaluations": 3, "runs": []}"#;
        let f: FittedModel = serde_json::from_str(good).unwrap();
        assert!(f.material().is_ok());
        for (field, bad) in [
            ("density_kg_m3", -47.0),
            ("shear_modulus_pa", 0.0),
            ("viscosity_pa_s_h", -1.0),
            ("density_kg_m3", 1e9),
        ] {
            let mut f = f.clone();
            match field {
                "density_kg_m3" => f.density = vec![bad],
                "shear_modulus_pa" => f.mu = vec![bad],
                _ => f.viscosity = vec![bad],
            }
            let e = f.material().unwrap_err();
            assert!(e.contains(&format!("field {field}: ")), "{e}");
        }
    }
}
