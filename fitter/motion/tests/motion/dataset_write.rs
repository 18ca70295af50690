//! The motion dataset writer against the reader: what is written reads back as it was given,
//! every key of `dataset.toml` and every row of the CSV files, and a failed write leaves the
//! folder that was there whole.

use palpate_motion::dataset::{
    dataset_toml, load, write_dataset, ClampRows, DatasetToml, Decimals, Initial, LoadToml,
    MotionDatasetFiles, StepRow,
};
use palpate_motion::model::Pose;
use palpate_motion::scenario::{example_bar, nine_markers, EXAMPLE_BAR_SIZE, EXAMPLE_DT};

const STEPS: usize = 4;

/// A dataset with every optional key of `dataset.toml` set to a value other than its default,
/// strings that need quoting, numbers that need an exponent, two loads of the two kinds, and
/// all four CSV files (clamp poses with a rotation, a dropped frame, forces).
fn everything() -> (palpate_fem::mesh::Mesh, MotionDatasetFiles) {
    let (mesh, _) = example_bar([1, 4, 1], STEPS).unwrap();
    let dt = EXAMPLE_DT;
    let mut c = DatasetToml::new(dt, vec!["front".into()]);
    c.name = Some("bar \"shaken\"".into());
    c.description = Some("every key set\nover two lines".into());
    c.units = Some("SI".into());
    c.marker_noise = Some(3e-6);
    c.steps = Some(STEPS);
    c.substeps = Some(2);
    c.scheme = Some("midpoint".into());
    c.viscosity_form = Some("objective".into());
    c.static_start = Some(false);
    c.density = Some(47.5);
    c.gravity = Some([0.0, -9.81, 1e-20]);
    c.mass = Some("consistent".into());
    c.marker_weight = Some(0.5);
    c.force_weight = Some(2.0e-3);
    c.initial = Initial {
        lambda: 2.5e4,
        mu: 1.25e4,
        nu: 6.0,
        h: 1.3,
    };
    c.initial_declared = true;
    c.loads = vec![
        LoadToml {
            name: Some("52 g".into()),
            group: "back".into(),
            edge: Some([0.0, 1.0, 0.0]),
            force: None,
            mass: Some(0.052),
            from_t: 0.0,
            inertia: true,
            lever_m: None,
        },
        LoadToml {
            name: None,
            group: "back".into(),
            edge: None,
            force: Some([0.0, 0.0, -0.01]),
            mass: None,
            from_t: 2.0 * dt,
            inertia: false,
            lever_m: None,
        },
    ];
    let markers: Vec<(String, [f64; 3])> = nine_markers(EXAMPLE_BAR_SIZE)
        .into_iter()
        .enumerate()
        .map(|(i, p)| (format!("m{i}"), p))
        .collect();
    let mut trajectories = Vec::new();
    for step in 1..=STEPS {
        for (i, (name, p)) in markers.iter().enumerate() {
            // Marker 3 is not seen at step 2: a dropped frame has no row.
            if (step, i) == (2, 3) {
                continue;
            }
            let d = 1e-4 * (step * 10 + i) as f64 / 3.0;
            trajectories.push(StepRow {
                step,
                name: name.clone(),
                value: [p[0] + d, p[1] - d, p[2] + 0.5 * d],
            });
        }
    }
    let half = std::f64::consts::FRAC_1_SQRT_2;
    let poses = (0..=STEPS)
        .map(|step| {
            let a = 0.01 * step as f64;
            let q = [(a / 2.0).cos(), 0.0, (a / 2.0).sin(), 0.0];
            (
                StepRow {
                    step,
                    name: "front".into(),
                    value: [1e-3 * step as f64 / 7.0, 0.0, -2e-4 * half * step as f64],
                },
                q,
            )
        })
        .collect();
    let forces = (1..=STEPS)
        .map(|step| StepRow {
            step,
            name: "front".into(),
            value: [0.1 / step as f64, -0.2, 0.3 * step as f64],
        })
        .collect();
    let files = MotionDatasetFiles {
        comments: vec!["written by the round-trip test".into()],
        config: c,
        markers,
        trajectories,
        clamps: Some(ClampRows::Poses(poses)),
        forces,
        decimals: Decimals::default(),
    };
    (mesh, files)
}

#[test]
fn a_written_dataset_reads_back_as_it_was_given() {
    let (mesh, files) = everything();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ds");
    let written = write_dataset(&out, &mesh, &files).unwrap();
    assert_eq!(written.len(), 6, "{written:?}");
    assert!(written.iter().all(|f| f.starts_with(&out) && f.exists()));
    let ds = load(&out).unwrap();
    // Every key of dataset.toml, the [initial] table and both [[loads]] tables.
    assert_eq!(ds.config, files.config);
    // The CSV rows, exactly (shortest round-trip text), on the simulation's grid of 2 substeps:
    // capture step n is simulation step 2n, observation row 2n − 1.
    let k = 2;
    assert_eq!(ds.model.substeps, k);
    assert_eq!(ds.capture_steps(), STEPS);
    let rest = palpate_motion::predict::rest_markers(&ds.model);
    for ((name, p), (m, q)) in files.markers.iter().zip(ds.model.markers.iter().zip(&rest)) {
        assert_eq!(&m.name, name);
        // Embedded by barycentric weights: the rest place comes back to round-off.
        assert!(
            (0..3).all(|a| (p[a] - q[a]).abs() < 1e-15),
            "{name}: {p:?} vs {q:?}"
        );
    }
    let mut seen = 0;
    for row in &ds.obs.markers {
        seen += row.iter().filter(|m| m.is_some()).count();
    }
    assert_eq!(seen, files.trajectories.len());
    for r in &files.trajectories {
        let i = files
            .markers
            .iter()
            .position(|(n, _)| *n == r.name)
            .unwrap();
        assert_eq!(ds.obs.markers[r.step * k - 1][i], Some(r.value), "{r:?}");
    }
    for r in &files.forces {
        assert_eq!(ds.obs.forces[r.step * k - 1][0], Some(r.value), "{r:?}");
    }
    let Some(ClampRows::Poses(poses)) = &files.clamps else {
        unreachable!()
    };
    for (r, q) in poses {
        let want = Pose::from_quaternion(r.value, *q);
        assert_eq!(ds.model.clamps[0].poses[r.step * k], want, "{r:?}");
    }
}

/// The header `palpate import c3d` writes for the beam hung with a weight, byte for byte as the
/// import wrote it by hand before the writer existed (tables last, `{}` numbers, `-0` kept).
#[test]
fn dataset_toml_has_its_keys_in_the_format_order() {
    let mut c = DatasetToml::new(0.01, vec!["clamp".into()]);
    c.static_start = Some(false);
    c.gravity = Some([-9.81, 0.0, 0.0]);
    c.density = Some(1070.0);
    c.loads = vec![LoadToml {
        name: Some("0.052 kg hung from free_end".into()),
        group: "free_end".into(),
        edge: Some([9.81, -0.0, -0.0]),
        force: None,
        mass: Some(0.052),
        from_t: 0.0,
        inertia: false,
        lever_m: None,
    }];
    let text = dataset_toml(&["Imported from beam.c3d.".into()], &c);
    assert_eq!(
        text,
        "# Imported from beam.c3d.\n\
         dt = 0.01\n\
         static_start = false\n\
         mesh = \"mesh.msh\"\n\
         clamps = [\"clamp\"]\n\
         gravity = [-9.81, 0, 0]\n\
         density = 1070\n\
         \n\
         [[loads]]\n\
         name = \"0.052 kg hung from free_end\"\n\
         group = \"free_end\"\n\
         edge = [9.81, -0, -0]\n\
         mass = 0.052\n"
    );
}

/// A write that fails part-way (the mesh cannot be written: a group name holds a quote, which
/// Gmsh cannot store) leaves the dataset that was at the target as it was, and no staging folder
/// beside it.
#[test]
fn a_failed_write_leaves_the_old_dataset_whole() {
    let (mesh, good) = everything();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ds");
    write_dataset(&out, &mesh, &good).unwrap();
    let before = std::fs::read(out.join("dataset.toml")).unwrap();
    let mut bad = good.clone();
    bad.config.dt = 0.5;
    let mut bad_mesh = mesh.clone();
    bad_mesh
        .node_groups
        .insert("a \"quoted\" group".into(), vec![0]);
    let e = write_dataset(&out, &bad_mesh, &bad)
        .unwrap_err()
        .to_string();
    assert!(e.contains("quote"), "{e}");
    assert_eq!(std::fs::read(out.join("dataset.toml")).unwrap(), before);
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left, vec![std::ffi::OsString::from("ds")]);
}
