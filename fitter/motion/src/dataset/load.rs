//! The reader: `dataset.toml` and its checks, the markers, the clamp poses on the step grid, the
//! observations, then the time step chosen for the simulation.

use super::{
    bad, check_marker_scale, check_markers_near_mesh, check_trajectories_near_rest, csv, dead_load,
    num, read, read_series, step_of, DatasetError, DatasetToml, MotionDataset, CLAMP_FORCES,
    DEFAULT_GRAVITY, MARKER_POSITIONS, MAX_DECLARED_SUBSTEPS, MAX_STEPS, MAX_STEPS_PAST_DATA,
};
use crate::model::{Clamp, MassKind, Model, Observations, Pose};
use palpate_fem::mesh::Mesh;
use std::collections::HashMap;
use std::path::Path;

/// A CSV file's rows after the header: (line, fields in the header alternative's order).
type Rows = Vec<(usize, Vec<String>)>;

/// A CSV file that may be absent: which header alternative it has, and its rows.
type OptionalCsv = Option<(usize, Rows)>;

/// The markers' names and rest places, in file order.
type MarkerPlaces = Vec<(String, [f64; 3])>;

/// One clamp's pose samples: (t, translation, quaternion w, x, y, z).
type PoseSamples = Vec<(f64, [f64; 3], [f64; 4])>;

/// Loads a motion dataset directory.
pub fn load(dir: &Path) -> Result<MotionDataset, DatasetError> {
    let tf = dir.join("dataset.toml");
    let config = read_config(&tf)?;
    let (gravity, mass) = check_config(&tf, &config)?;
    let mf = dir.join(&config.mesh);
    let mesh = palpate_fem::mesh::gmsh::read_msh(&mf).map_err(|e| bad(&mf, 0, e.to_string()))?;
    let dt = config.dt;
    let kf = dir.join("markers.csv");
    let (marker_pts, marker_index) = read_markers(&kf, &mesh)?;
    // Trajectories, clamps, forces.
    let jf = dir.join("trajectories.csv");
    let traj = csv(&jf, &[&["t", "marker", "x", "y", "z"]])?;
    let cf = dir.join("clamps.csv");
    let clamps_csv = csv(
        &cf,
        &[
            &["t", "clamp", "tx", "ty", "tz", "qw", "qx", "qy", "qz"],
            &["t", "clamp", "ux", "uy", "uz"],
        ],
    )?;
    let ff = dir.join("forces.csv");
    let forces = csv(&ff, &[&["t", "clamp", "fx", "fy", "fz"]])?;
    let clamp_index: HashMap<&str, usize> = config
        .clamps
        .iter()
        .enumerate()
        .map(|(i, c)| (c.as_str(), i))
        .collect();
    let steps = count_steps(&tf, &config, [(&jf, &traj), (&ff, &forces)])?;
    let samples = read_clamp_samples(&cf, &clamps_csv, &config, &clamp_index)?;
    let mut clamps = Vec::new();
    for (c, name) in config.clamps.iter().enumerate() {
        let nodes = mesh
            .group(name)
            .map_err(|e| bad(&tf, 0, format!("field clamps: {e}")))?
            .to_vec();
        clamps.push(Clamp {
            name: name.clone(),
            nodes,
            poses: clamp_poses(&samples[c], steps, dt),
        });
    }
    let mut model = Model::new(&mesh, clamps, Vec::new(), dt, steps, gravity, mass)
        .map_err(|e| bad(&tf, 0, e.to_string()))?;
    configure_model(&tf, &config, &mesh, &marker_pts, &mut model)?;
    let mut obs = Observations {
        markers: vec![vec![None; marker_pts.len()]; steps],
        forces: vec![vec![None; config.clamps.len()]; steps],
        marker_weight: config.marker_weight.unwrap_or(1.0),
        force_weight: config.force_weight.unwrap_or(1.0),
        free_marker_offsets: false,
        phi_precision: 0.0,
    };
    if let Some((_, rows)) = &traj {
        read_series(&jf, rows, dt, &MARKER_POSITIONS, &mut obs.markers, |name| {
            marker_index.get(name).copied()
        })?;
        check_trajectories_near_rest(&jf, rows, &marker_pts, &marker_index, &mesh)?;
    }
    if let Some((_, rows)) = &forces {
        read_series(&ff, rows, dt, &CLAMP_FORCES, &mut obs.forces, |name| {
            clamp_index.get(name).copied()
        })?;
    }
    if traj.is_none() && forces.is_none() {
        return Err(bad(
            dir,
            0,
            "neither trajectories.csv nor forces.csv present: nothing to fit",
        ));
    }
    check_weights(&tf, &obs, traj.is_some(), forces.is_some())?;
    check_substeps(&tf, &config, model.steps)?;
    let timestep = crate::timestep::choose(&model, &obs, config.substeps);
    let (fine, fine_obs) = model.resampled(&obs, timestep.substeps);
    let ds = MotionDataset {
        config,
        mesh,
        model: fine,
        obs: fine_obs,
        timestep,
    };
    Ok(if ds.timestep.declared {
        ds
    } else {
        checked_step(ds, &model, &obs)
    })
}

/// `ds` on a step whose own error is within tolerance ([`crate::step_error`]): measured at the
/// data's start estimate, and `ds` resampled finer from the capture's `model` and `obs` when it
/// is not.
fn checked_step(mut ds: MotionDataset, model: &Model, obs: &Observations) -> MotionDataset {
    let mat = crate::start::initial_values(&ds, None).material(&ds);
    let measured = crate::step_error::measure(
        model,
        obs,
        ds.timestep.substeps,
        ds.config.marker_noise,
        &mat,
    );
    if let Ok(e) = &measured {
        if e.substeps > e.from_substeps {
            (ds.model, ds.obs) = model.resampled(obs, e.substeps);
            ds.timestep.substeps = e.substeps;
        }
    }
    ds.timestep.step_error = Some(measured);
    ds
}

/// What `dataset.toml` says of the model beyond its clamps: a static start or not, the time
/// scheme, the dead loads; and the markers, embedded in the mesh.
fn configure_model(
    tf: &Path,
    config: &DatasetToml,
    mesh: &Mesh,
    marker_pts: &MarkerPlaces,
    model: &mut Model,
) -> Result<(), DatasetError> {
    model.static_start = config.static_start.unwrap_or(true);
    model.scheme = crate::timestep::DATASET_DEFAULT;
    if let Some(name) = config.scheme.as_deref() {
        model.scheme = crate::timestep::Scheme::from_name(name).ok_or_else(|| {
            bad(
                tf,
                0,
                format!(
                    "field scheme: expected \"bdf2\", \"midpoint\" or \"alpha\", found {name:?}"
                ),
            )
        })?;
    }
    if let Some(name) = config.viscosity_form.as_deref() {
        model.viscous_form = crate::viscosity::Form::parse(name).ok_or_else(|| {
            bad(
                tf,
                0,
                format!(
                    "field viscosity_form: expected \"rest-gradient\" or \"objective\", found \
                     {name:?}"
                ),
            )
        })?;
    }
    model.loads = config
        .loads
        .iter()
        .enumerate()
        .map(|(i, l)| dead_load(tf, i, l, mesh, model))
        .collect::<Result<_, _>>()?;
    for (i, l) in config.loads.iter().enumerate() {
        if let Some(d) = l.lever_m.filter(|d| *d != 0.0) {
            let lever = crate::load_point::lever(model, &model.loads[i], d).map_err(|e| {
                bad(
                    tf,
                    0,
                    format!("loads[{i}] (group {:?}): field lever_m: {e}", l.group),
                )
            })?;
            model.loads[i].lever = Some(lever);
        }
    }
    model.markers = marker_pts
        .iter()
        .map(|(n, p)| model.marker_at(n, *p))
        .collect();
    Ok(())
}

/// Parses `dataset.toml`: the parser's own message (`missing field `dt``, `unknown field …`) on
/// the line its span starts (a missing field spans the whole document: line 1), without the
/// rendered excerpt; and whether `[initial]` was declared at all.
fn read_config(tf: &Path) -> Result<DatasetToml, DatasetError> {
    let text = read(tf)?;
    let mut config: DatasetToml = toml::from_str(&text).map_err(|e| {
        let line = e
            .span()
            .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1)
            .unwrap_or(1);
        bad(tf, line, e.message().trim())
    })?;
    let table = text.parse::<toml::Table>().ok();
    config.initial_declared = table.as_ref().is_none_or(|t| t.contains_key("initial"));
    if let Some(initial) = table
        .as_ref()
        .and_then(|t| t.get("initial"))
        .and_then(|i| i.as_table())
    {
        if initial.contains_key("nu") {
            log::warn!(
                "{}: [initial] nu is now called viscosity (ν is Poisson's ratio everywhere else); \
                 read as viscosity",
                tf.display()
            );
        }
    }
    Ok(config)
}

/// Checks the scalar fields of `dataset.toml` (step, units, noise, density, start values) and
/// returns its gravity (the default, with a warning, when none is declared) and mass kind.
fn check_config(tf: &Path, config: &DatasetToml) -> Result<([f64; 3], MassKind), DatasetError> {
    if !(config.dt > 0.0 && config.dt.is_finite()) {
        return Err(bad(
            tf,
            0,
            format!("field dt: must be finite and > 0, found {}", config.dt),
        ));
    }
    if let Some(u) = config.units.as_deref().filter(|u| *u != "SI") {
        return Err(bad(
            tf,
            0,
            format!("field units: expected \"SI\" (m, s, N, kg, Pa), found {u:?}"),
        ));
    }
    if let Some(s) = config.marker_noise.filter(|s| !(s.is_finite() && *s > 0.0)) {
        return Err(bad(
            tf,
            0,
            format!("field marker_noise: must be finite and > 0 m, found {s}"),
        ));
    }
    if let Some(d) = config.density {
        palpate_fem::sanity::check_density(d)
            .map_err(|why| bad(tf, 0, format!("field density: {why}")))?;
    }
    let i = &config.initial;
    for (key, v) in [
        ("initial.lambda", i.lambda),
        ("initial.mu", i.mu),
        ("initial.viscosity", i.nu),
        ("initial.h", i.h),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(bad(
                tf,
                0,
                format!("field {key}: expected a finite value > 0, found {v}"),
            ));
        }
    }
    let gravity = match config.gravity {
        Some(g) => {
            palpate_fem::sanity::check_gravity(g)
                .map_err(|why| bad(tf, 0, format!("field gravity: {why}")))?;
            g
        }
        None => {
            log::warn!(
                "{}: no `gravity` declared; using {DEFAULT_GRAVITY:?} m/s² (declare it: a \
                 static dataset without it has none)",
                tf.display()
            );
            DEFAULT_GRAVITY
        }
    };
    let mass = match config.mass.as_deref() {
        None | Some("lumped") => MassKind::Lumped,
        Some("consistent") => MassKind::Consistent,
        Some(o) => {
            return Err(bad(
                tf,
                0,
                format!("field mass: expected \"lumped\" or \"consistent\", found {o:?}"),
            ))
        }
    };
    Ok((gravity, mass))
}

/// The markers' rest places from `markers.csv` (required), in file order, and each name's index;
/// a name listed twice, a marker far from the mesh or a mesh in other units is refused.
fn read_markers(
    kf: &Path,
    mesh: &Mesh,
) -> Result<(MarkerPlaces, HashMap<String, usize>), DatasetError> {
    let (_, krows) =
        csv(kf, &[&["marker", "x", "y", "z"]])?.ok_or_else(|| bad(kf, 0, "missing (required)"))?;
    let mut marker_pts = Vec::new();
    let mut marker_index = HashMap::new();
    for (line, f) in &krows {
        if marker_index
            .insert(f[0].clone(), marker_pts.len())
            .is_some()
        {
            return Err(bad(kf, *line, format!("marker {:?} listed twice", f[0])));
        }
        marker_pts.push((
            f[0].clone(),
            [
                num(kf, *line, "x", &f[1])?,
                num(kf, *line, "y", &f[2])?,
                num(kf, *line, "z", &f[3])?,
            ],
        ));
    }
    check_markers_near_mesh(kf, &krows, &marker_pts, mesh)?;
    check_marker_scale(kf, &marker_pts, mesh)?;
    Ok((marker_pts, marker_index))
}

/// The steps to simulate: `steps` if declared, else the last observed step of the series files;
/// refused beyond [`MAX_STEPS`], beyond [`MAX_STEPS_PAST_DATA`] times the data, or at zero.
fn count_steps(
    tf: &Path,
    config: &DatasetToml,
    series: [(&Path, &OptionalCsv); 2],
) -> Result<usize, DatasetError> {
    let dt = config.dt;
    let mut last_step = 0;
    for (file, rows) in series {
        if let Some((_, rows)) = rows {
            for (line, f) in rows {
                last_step = last_step.max(step_of(file, *line, num(file, *line, "t", &f[0])?, dt)?);
            }
        }
    }
    let steps = config.steps.unwrap_or(last_step);
    if steps > MAX_STEPS {
        return Err(bad(
            tf,
            0,
            format!("field steps: {steps}, at most {MAX_STEPS} steps are supported"),
        ));
    }
    if last_step > 0 && steps > MAX_STEPS_PAST_DATA * last_step {
        return Err(bad(
            tf,
            0,
            format!(
                "field steps: {steps}, but the last observation is step {last_step} (t = {} s); \
                 steps past {MAX_STEPS_PAST_DATA}× the data carry no information — declare \
                 steps ≤ {} or leave it out",
                last_step as f64 * dt,
                MAX_STEPS_PAST_DATA * last_step
            ),
        ));
    }
    if steps == 0 {
        return Err(bad(
            tf,
            0,
            "no observations after t = 0 and no `steps` given: nothing to simulate",
        ));
    }
    Ok(steps)
}

/// The pose samples of each clamp from `clamps.csv` (poses, or translations only), in time
/// order: an unknown clamp, a quaternion off unit norm or a time not after the previous one is
/// refused.
fn read_clamp_samples(
    cf: &Path,
    clamps_csv: &OptionalCsv,
    config: &DatasetToml,
    clamp_index: &HashMap<&str, usize>,
) -> Result<Vec<PoseSamples>, DatasetError> {
    let mut samples: Vec<PoseSamples> = vec![Vec::new(); config.clamps.len()];
    let Some((kind, rows)) = clamps_csv else {
        return Ok(samples);
    };
    for (line, f) in rows {
        let c = *clamp_index.get(f[1].as_str()).ok_or_else(|| {
            bad(
                cf,
                *line,
                format!(
                    "field clamp: {:?} is not in dataset.toml clamps {:?}",
                    f[1], config.clamps
                ),
            )
        })?;
        let t = num(cf, *line, "t", &f[0])?;
        let names = if *kind == 0 {
            ["tx", "ty", "tz"]
        } else {
            ["ux", "uy", "uz"]
        };
        let tr = [
            num(cf, *line, names[0], &f[2])?,
            num(cf, *line, names[1], &f[3])?,
            num(cf, *line, names[2], &f[4])?,
        ];
        let q = if *kind == 0 {
            let q = [
                num(cf, *line, "qw", &f[5])?,
                num(cf, *line, "qx", &f[6])?,
                num(cf, *line, "qy", &f[7])?,
                num(cf, *line, "qz", &f[8])?,
            ];
            let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
            if (n - 1.0).abs() > 1e-3 {
                return Err(bad(
                    cf,
                    *line,
                    format!("quaternion norm {n:.4}, expected 1"),
                ));
            }
            q
        } else {
            [1.0, 0.0, 0.0, 0.0]
        };
        if let Some(prev) = samples[c].last() {
            if t <= prev.0 {
                return Err(bad(
                    cf,
                    *line,
                    format!(
                        "field t: {t} not after previous time {} for clamp {:?}",
                        prev.0, f[1]
                    ),
                ));
            }
        }
        samples[c].push((t, tr, q));
    }
    Ok(samples)
}

/// A clamp's pose at each step 0..=steps, interpolated between its samples (held after the
/// last; the identity without samples).
fn clamp_poses(s: &[(f64, [f64; 3], [f64; 4])], steps: usize, dt: f64) -> Vec<Pose> {
    (0..=steps)
        .map(|n| {
            let t = n as f64 * dt;
            if s.is_empty() {
                return Pose::identity();
            }
            let j = s.iter().rposition(|r| r.0 <= t).unwrap_or(0);
            let (a, b) = (s[j], s[(j + 1).min(s.len() - 1)]);
            let w = if b.0 > a.0 {
                ((t - a.0) / (b.0 - a.0)).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let tr = [0, 1, 2].map(|i| a.1[i] + w * (b.1[i] - a.1[i]));
            // Normalised linear quaternion blend (nlerp) between samples, same hemisphere.
            let sgn = if a.2.iter().zip(&b.2).map(|(x, y)| x * y).sum::<f64>() < 0.0 {
                -1.0
            } else {
                1.0
            };
            let q = [0, 1, 2, 3].map(|i| a.2[i] + w * (sgn * b.2[i] - a.2[i]));
            Pose::from_quaternion(tr, q)
        })
        .collect()
}

/// The weights of the terms with data: only those count, since a zero marker weight on a
/// dataset without forces.csv leaves the fit nothing to match, and it would return its start.
fn check_weights(
    tf: &Path,
    obs: &Observations,
    has_trajectories: bool,
    has_forces: bool,
) -> Result<(), DatasetError> {
    let mut names = Vec::new();
    let mut weights = Vec::new();
    if has_trajectories {
        names.push("field marker_weight (trajectories.csv)");
        weights.push(obs.marker_weight);
    }
    if has_forces {
        names.push("field force_weight (forces.csv)");
        weights.push(obs.force_weight);
    }
    palpate_fem::sanity::check_weights(&names, &weights).map_err(|why| bad(tf, 0, why))?;
    for (key, w) in [
        ("marker_weight", obs.marker_weight),
        ("force_weight", obs.force_weight),
    ] {
        if !(w.is_finite() && w >= 0.0) {
            return Err(bad(
                tf,
                0,
                format!("field {key}: expected a finite weight ≥ 0, found {w}"),
            ));
        }
    }
    Ok(())
}

/// The declared `substeps`: 1 to [`MAX_DECLARED_SUBSTEPS`], and within [`MAX_STEPS`] once
/// multiplied by the model's steps.
fn check_substeps(tf: &Path, config: &DatasetToml, steps: usize) -> Result<(), DatasetError> {
    if config.substeps == Some(0) || config.substeps.is_some_and(|k| k > MAX_DECLARED_SUBSTEPS) {
        return Err(bad(
            tf,
            0,
            format!(
                "field substeps: expected 1 to {MAX_DECLARED_SUBSTEPS}, found {}",
                config.substeps.unwrap_or(0)
            ),
        ));
    }
    if steps.saturating_mul(config.substeps.unwrap_or(1)) > MAX_STEPS {
        return Err(bad(
            tf,
            0,
            format!(
                "field substeps: {} × {} steps is over the {MAX_STEPS} steps supported",
                config.substeps.unwrap_or(1),
                steps
            ),
        ));
    }
    Ok(())
}
