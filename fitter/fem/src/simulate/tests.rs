use super::*;
use crate::block_model::BlockModel;

fn block() -> BlockModel {
    BlockModel::block(400, LambdaAlpha::from_young_poisson(20e3, 0.35)).unwrap()
}

fn request() -> Request {
    Request {
        contact: None,
        contact_rule: ContactRule::Lumped,
        node_forces: None,
        probe: None,
        warp: true,
        increments: 10,
    }
}

#[test]
fn a_request_without_loads_is_refused() {
    let b = block();
    let e = simulate(b.record(), &request()).unwrap_err();
    assert!(matches!(e, SimulateError::NothingToSimulate), "{e}");
}

#[test]
fn a_downward_contact_settles_with_the_top_pressed_down_and_writes_its_files() {
    let b = block();
    // The middle of the 10 × 10 × 5 cm block's top face.
    let r = Request {
        contact: Some(([0.05, 0.05, 0.05], [0.0, 0.0, -1.0], 0.015)),
        ..request()
    };
    let sim = simulate(b.record(), &r).unwrap();
    let u = sim.displacement_vectors();
    let top = (0..u.len())
        .filter(|&i| (sim.mesh.nodes[i][2] - 0.05).abs() < 1e-9)
        .min_by(|&i, &j| {
            let d = |k: usize| {
                let p = sim.mesh.nodes[k];
                (p[0] - 0.05).powi(2) + (p[1] - 0.05).powi(2)
            };
            d(i).total_cmp(&d(j))
        })
        .unwrap();
    assert!(
        u[top][2] < 0.0,
        "the node under the contact moves {:?}",
        u[top]
    );
    assert_eq!(sim.last.status, SolveStatus::Converged);
    let dir = tempfile::tempdir().unwrap();
    let files = sim.write(dir.path()).unwrap();
    assert_eq!(files.len(), 3);
    let csv = std::fs::read_to_string(dir.path().join("displacements.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + sim.mesh.nodes.len());
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary["ticks"], sim.ticks);
    assert!(
        (summary["max_displacement_m"].as_f64().unwrap() - sim.max_displacement()).abs() < 1e-15
    );
}

#[test]
fn node_forces_only_on_fixed_nodes_are_refused_by_name() {
    let b = block();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("forces.csv");
    let tag = b.record().node_tags.get(b.fixed[0]).unwrap();
    std::fs::write(&file, format!("node,fx,fy,fz\n{tag},0,0,-1\n")).unwrap();
    let r = Request {
        node_forces: Some(file.clone()),
        ..request()
    };
    let e = simulate(b.record(), &r).unwrap_err();
    match e {
        SimulateError::NothingLoaded { file: f, rows, .. } => {
            assert_eq!((f, rows), (file, 1));
        }
        other => panic!("expected NothingLoaded, found {other}"),
    }
}
