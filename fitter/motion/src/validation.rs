//! A fitted model's prediction of a run it was not fitted to (`palpate validate`): the run
//! simulated from the fitted material without refitting, its rest state solved ([`predict`]),
//! both compared with the capture and with the naive linear baseline through the fitted runs;
//! the table a person reads ([`Validation`]'s `Display`), the JSON line scripts read
//! ([`Validation::json`]) and the one writer of the prediction's files ([`Validation::write`]).

use std::fmt;
use std::path::{Path, PathBuf};

use crate::dataset::{DatasetError, MotionDataset};
use crate::fitted::FittedModel;
use crate::predict::{self, Prediction};
use crate::settling::{self, Settling};
use crate::transfer::{self, Carried};
use crate::{time_offset, MotionError};

/// Why a run could not be predicted, or its prediction not written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ValidationError {
    /// The dataset could not be read.
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    /// The run is on another mesh than the model's.
    #[error(
        "{}: its mesh has {nodes} nodes and {tets} tets, the model's {model_nodes} and \
         {model_tets}, and the model records no converged modulus to carry its material to \
         another mesh: fit it with `--mesh-convergence` (or `palpate diagnose`, which checks it)",
        dataset.display()
    )]
    OtherMesh {
        /// The dataset.
        dataset: PathBuf,
        /// The dataset's nodes.
        nodes: usize,
        /// The dataset's tetrahedra.
        tets: usize,
        /// The model's nodes.
        model_nodes: usize,
        /// The model's tetrahedra.
        model_tets: usize,
    },
    /// The model's material could not be carried to the run's mesh.
    #[error("{}: carrying the model's material to its mesh: {message}", dataset.display())]
    Carry {
        /// The dataset.
        dataset: PathBuf,
        /// Why.
        message: String,
    },
    /// The model's material fields are inconsistent.
    #[error("{}: {message}", model.display())]
    Material {
        /// The model file.
        model: PathBuf,
        /// What is wrong with which field.
        message: String,
    },
    /// The run's time offset could not be scanned.
    #[error("scanning the time offset of {}", dataset.display())]
    TimeOffset {
        /// The dataset.
        dataset: PathBuf,
        /// The simulator's error.
        source: MotionError,
    },
    /// The model's lever of the hanging weights could not be put on the run's loads.
    #[error("moving the hanging weights of {} by the model's lever", dataset.display())]
    Lever {
        /// The dataset.
        dataset: PathBuf,
        /// Why.
        source: MotionError,
    },
    /// The run could not be simulated with the model's material.
    #[error("simulating {}", dataset.display())]
    Simulate {
        /// The dataset.
        dataset: PathBuf,
        /// The simulator's error.
        source: MotionError,
    },
    /// The output folder could not be made.
    #[error("creating {}", dir.display())]
    CreateDir {
        /// The folder.
        dir: PathBuf,
        /// The file system's error.
        source: std::io::Error,
    },
    /// `prediction.csv` could not be written.
    #[error(transparent)]
    Write(#[from] palpate_fem::io::atomic::AtomicWriteError),
    /// The figure could not be written.
    #[error(transparent)]
    Plot(#[from] palpate_plot::PlotError),
}

/// A run predicted by a fitted model, with its errors and the baseline's.
pub struct Validation {
    /// The dataset as the user named it.
    pub dataset: PathBuf,
    /// The model file as the user named it.
    pub model: PathBuf,
    /// The runs the model was fitted on.
    pub fitted_on: Vec<String>,
    /// How many runs the baseline goes through.
    pub fitted_runs: usize,
    /// The run's own time offset (steps), scanned when the model was fitted with one per run.
    pub time_offset: Option<i64>,
    /// The run's dead load along gravity (N), [`predict::load_along_gravity`].
    pub load_n: f64,
    /// The prediction and its errors.
    pub prediction: Prediction,
    /// The linear baseline's rest-state RMS (m), [`predict::fitted_baseline_rms`].
    pub baseline_final_rms_m: Option<f64>,
    /// The run (loaded with the model's hanging inertia).
    pub run: MotionDataset,
    /// How the prediction settles after the ring-down against the capture
    /// ([`settling::settling`]).
    pub settling: Option<Settling>,
    /// The rest error's RMS along gravity and across it (m), [`settling::rest_error_directions`].
    pub rest_directions: Option<(f64, f64)>,
    /// How the material was carried to the run's mesh, when it is not the model's
    /// ([`transfer::carry`]).
    pub carried: Option<Carried>,
}

/// Reads the motion dataset at `dataset` and predicts it with `fit` (read from `model`): at the
/// run's own time offset when the model was fitted with one per run (scanned with the fitted
/// material, never refitted), on the mesh the model was fitted on.
pub fn validate(
    fit: &FittedModel,
    model: &Path,
    dataset: &Path,
) -> Result<Validation, ValidationError> {
    let mut ds = crate::dataset::load(dataset)?;
    if fit.hanging_inertia {
        crate::fitted::set_hanging_inertia(&mut ds.model, true);
    }
    if let Some(d) = fit.load_lever_m {
        ds.model
            .set_load_lever(d)
            .map_err(|source| ValidationError::Lever {
                dataset: dataset.into(),
                source,
            })?;
    }
    let mut carried = None;
    let carried_fit;
    let fit = if ds.mesh.nodes.len() != fit.nodes || ds.mesh.tets.len() != fit.tets {
        if fit.converged.is_none() {
            return Err(ValidationError::OtherMesh {
                dataset: dataset.into(),
                nodes: ds.mesh.nodes.len(),
                tets: ds.mesh.tets.len(),
                model_nodes: fit.nodes,
                model_tets: fit.tets,
            });
        }
        let (f, c) = transfer::carry(fit, &ds).map_err(|message| ValidationError::Carry {
            dataset: dataset.into(),
            message,
        })?;
        carried = Some(c);
        carried_fit = f;
        &carried_fit
    } else {
        fit
    };
    let mat = fit
        .material()
        .map_err(|message| ValidationError::Material {
            model: model.into(),
            message,
        })?;
    let time_offset = if fit.time_offset {
        let (offset, _) = time_offset::scan(&ds.model, &mat, &ds.obs).map_err(|source| {
            ValidationError::TimeOffset {
                dataset: dataset.into(),
                source,
            }
        })?;
        Some(offset)
    } else {
        None
    };
    let prediction = predict::predict_offset(&ds.model, &mat, &ds.obs, time_offset.unwrap_or(0))
        .map_err(|source| ValidationError::Simulate {
            dataset: dataset.into(),
            source,
        })?;
    let settling = settling::settling(&ds.model, &ds.obs, &prediction.simulated);
    let rest_directions =
        settling::rest_error_directions(&ds.model, &ds.obs, &prediction.equilibrium);
    Ok(Validation {
        carried,
        settling,
        rest_directions,
        dataset: dataset.into(),
        model: model.into(),
        fitted_on: fit.datasets.clone(),
        fitted_runs: fit.runs.len(),
        time_offset,
        load_n: predict::load_along_gravity(&ds.model),
        baseline_final_rms_m: predict::fitted_baseline_rms(fit, &ds.model, &ds.obs),
        prediction,
        run: ds,
    })
}

impl Validation {
    /// The JSON line for scripts (`docs/json-outputs.md`). Read by scripts and an external
    /// checker: `final_rms_m` and `trajectory_rms_m` keep their names.
    pub fn json(&self) -> serde_json::Value {
        let (p, m) = (&self.prediction, &self.run.model);
        serde_json::json!({
            "schema_version": 1,
            "kind": "validation",
            "dataset": self.dataset.display().to_string(),
            "model": self.model.display().to_string(),
            "final_rms_m": p.final_rms_m,
            "final_max_m": p.final_max_m,
            "trajectory_rms_m": p.trajectory_rms_m,
            "trajectory_max_m": p.trajectory_max_m,
            "baseline_final_rms_m": self.baseline_final_rms_m,
            "load_n": self.load_n,
            "steps": m.steps,
            "dt_s": m.dt,
            "time_offset_s": self.time_offset.unwrap_or(0) as f64 * m.dt,
            "carried": self.carried.as_ref().map(|c| serde_json::json!({
                "converged_shear_modulus_pa": c.converged_mu_pa,
                "fit_mesh_shear_modulus_pa": c.fit_mesh_mu_pa,
                "new_mesh_shear_modulus_pa": c.new_mesh_mu_pa,
                "scale": c.scale,
                "match_rms_m": c.match_rms_m,
                "largest_displacement_m": c.largest_displacement_m,
            })),
            "rest_along_gravity_rms_m": self.rest_directions.map(|d| d.0),
            "rest_across_gravity_rms_m": self.rest_directions.map(|d| d.1),
            "settling": self.settling.as_ref().map(|s| serde_json::json!({
                "from_s": s.from_s,
                "markers": s.markers.iter().map(|&i| m.markers[i].name.clone()).collect::<Vec<_>>(),
                "max_abs_error_m": s.max_abs_error_m(),
                "measured_drift_m": s.measured_drift_m(),
                "simulated_drift_m": s.simulated_drift_m(),
                "windows": s.windows.iter().map(|w| serde_json::json!({
                    "t_s": w.0, "measured_m": w.1, "simulated_m": w.2,
                })).collect::<Vec<_>>(),
            })),
        })
    }

    /// Writes the prediction into the folder `dir` (made if missing): `prediction.csv`
    /// (simulated and observed markers per step) and `tip.svg`/`tip.png` as the plot format
    /// says (the displacement along gravity of the marker that moves most). Returns the files
    /// written, in order.
    pub fn write(&self, dir: &Path) -> Result<Vec<PathBuf>, ValidationError> {
        std::fs::create_dir_all(dir).map_err(|source| ValidationError::CreateDir {
            dir: dir.into(),
            source,
        })?;
        let file = dir.join("prediction.csv");
        palpate_fem::io::atomic::write_atomic(&file, self.csv().as_bytes())?;
        let mut written = vec![file];
        written.extend(self.tip_plot(&dir.join("tip.svg"))?);
        Ok(written)
    }

    /// `prediction.csv`: per step and marker, the simulated and the observed position (empty
    /// where the marker was not seen).
    fn csv(&self) -> String {
        let (p, ds) = (&self.prediction, &self.run);
        let mut csv = String::from("t,marker,sim_x,sim_y,sim_z,obs_x,obs_y,obs_z\n");
        for (n, row) in p.simulated.iter().enumerate() {
            for (i, m) in ds.model.markers.iter().enumerate() {
                let s = row[i];
                let o = ds.obs.markers[n][i];
                let o = o
                    .map(|o| format!("{},{},{}", o[0], o[1], o[2]))
                    .unwrap_or_else(|| ",,".into());
                csv.push_str(&format!(
                    "{},{},{},{},{},{o}\n",
                    (n + 1) as f64 * ds.model.dt,
                    m.name,
                    s[0],
                    s[1],
                    s[2]
                ));
            }
        }
        csv
    }

    /// The displacement along gravity of the marker that moves most (the tip), measured,
    /// simulated and at the predicted rest state.
    fn tip_plot(&self, svg: &Path) -> Result<Vec<PathBuf>, ValidationError> {
        let (p, ds) = (&self.prediction, &self.run);
        let g = ds.model.gravity;
        let gn = g.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
        let rest = predict::rest_markers(&ds.model);
        let along =
            |p: &[f64; 3], i: usize| (0..3).map(|k| (p[k] - rest[i][k]) * g[k] / gn).sum::<f64>();
        let tip = (0..rest.len())
            .max_by(|&a, &b| {
                let d = |i: usize| {
                    p.equilibrium
                        .get(i)
                        .map(|q| along(q, i).abs())
                        .unwrap_or(0.0)
                };
                d(a).total_cmp(&d(b))
            })
            .unwrap_or(0);
        let sim: Vec<(f64, f64)> = p
            .simulated
            .iter()
            .enumerate()
            .map(|(n, r)| ((n + 1) as f64 * ds.model.dt, 1e3 * along(&r[tip], tip)))
            .collect();
        let obs: Vec<(f64, f64)> = ds
            .obs
            .markers
            .iter()
            .enumerate()
            .filter_map(|(n, r)| {
                r[tip].map(|o| ((n + 1) as f64 * ds.model.dt, 1e3 * along(&o, tip)))
            })
            .collect();
        let eq = [
            (0.0, 1e3 * along(&p.equilibrium[tip], tip)),
            (
                ds.model.steps as f64 * ds.model.dt,
                1e3 * along(&p.equilibrium[tip], tip),
            ),
        ];
        let name = &ds.model.markers[tip].name;
        Ok(palpate_plot::lines(
            svg,
            &format!("Marker {name}: displacement along gravity"),
            "time after release (s)",
            "displacement along gravity (mm)",
            &[
                palpate_plot::Series::new("measured", &obs, palpate_plot::Style::Points),
                palpate_plot::Series::new("simulated", &sim, palpate_plot::Style::Line),
                palpate_plot::Series::new("predicted rest", &eq, palpate_plot::Style::Line),
            ],
        )?)
    }
}

/// The table a person reads: the run's time offset (when scanned), what was predicted with
/// what, the marker errors (mm) and the baseline's.
impl fmt::Display for Validation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (p, m) = (&self.prediction, &self.run.model);
        if let Some(offset) = self.time_offset {
            writeln!(
                f,
                "time offset of this run (the model was fitted with one per run): {:+.1} ms, scanned over ±{} capture frames (±{} at most)",
                1e3 * offset as f64 * m.dt,
                time_offset::SCAN_FRAMES,
                time_offset::MAX_SCAN_FRAMES
            )?;
        }
        if let Some(c) = &self.carried {
            writeln!(
                f,
                "the material carried to this mesh ({} tets): μ {} on quadratic tetrahedra (the material's) is μ {} on the fit's linear mesh and {} on this one under this run's loads (match RMS {:.3} mm of a {:.1} mm displacement), so the moduli, the viscosity and the stiffening are scaled by {:.4} (the viscosity's own factor is smaller where the locking is volumetric, near ν = ½: on a silicone beam refined from 716 to 2,600 tets the fitted viscosity grew by 1.085 where μ grew by 1.196)",
                m.tets.len(),
                palpate_fem::numbers::quantity(c.converged_mu_pa, "Pa"),
                palpate_fem::numbers::quantity(c.fit_mesh_mu_pa, "Pa"),
                palpate_fem::numbers::quantity(c.new_mesh_mu_pa, "Pa"),
                1e3 * c.match_rms_m,
                1e3 * c.largest_displacement_m,
                c.scale
            )?;
        }
        writeln!(
            f,
            "validate {} with {} (fitted on {}): {} steps of {} s, {} markers, dead load {:.4} N along gravity",
            self.dataset.display(),
            self.model.display(),
            self.fitted_on.join(", "),
            m.steps,
            m.dt,
            m.markers.len(),
            self.load_n
        )?;
        writeln!(
            f,
            "| marker | trajectory RMS (mm) | final rest error (mm) |\n|---|---|---|"
        )?;
        for e in &p.markers {
            writeln!(
                f,
                "| {} | {:.3} | {} |",
                e.name,
                1e3 * e.trajectory_rms_m,
                e.final_m
                    .map(|e| format!("{:.3}", 1e3 * e))
                    .unwrap_or_else(|| "unseen".into())
            )?;
        }
        writeln!(
            f,
            "| all | {:.3} (max {:.3}) | {:.3} (max {:.3}) |",
            1e3 * p.trajectory_rms_m,
            1e3 * p.trajectory_max_m,
            1e3 * p.final_rms_m,
            1e3 * p.final_max_m
        )?;
        if let Some((along, across)) = self.rest_directions {
            writeln!(
                f,
                "rest error by direction (RMS over the markers): {:.3} mm along gravity, {:.3} mm across it",
                1e3 * along,
                1e3 * across
            )?;
        }
        if let Some(s) = &self.settling {
            let names: Vec<&str> = s
                .markers
                .iter()
                .map(|&i| m.markers[i].name.as_str())
                .collect();
            writeln!(
                f,
                "settling from {:.2} s (the measured swing below {:.0} % of its largest), mean of {} along gravity in {:.1} s windows: simulated − measured within {:.3} mm; the capture drifts {:+.3} mm over it, the simulation {:+.3} mm",
                s.from_s,
                100.0 * settling::SETTLED_FRACTION,
                names.join(", "),
                settling::WINDOW_S,
                1e3 * s.max_abs_error_m(),
                1e3 * s.measured_drift_m(),
                1e3 * s.simulated_drift_m()
            )?;
        }
        match self.baseline_final_rms_m {
            Some(b) => writeln!(
                f,
                "baseline (final displacements linear in the load through the {} fitted runs): final RMS {:.3} mm",
                self.fitted_runs,
                1e3 * b
            ),
            None => writeln!(
                f,
                "baseline: not available (the fitted runs do not span two different loads)"
            ),
        }
    }
}
