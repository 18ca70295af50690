//! Two checks of the runtime's inputs and state: `Runtime::new` rejects a model with an orphan
//! free node (the protocol's node-coverage check), and strain-space blending follows the strain
//! also when warping is off (the linear strain sym(H), R = I).

use nalgebra::Vector3;
use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_protocol::model::{validate_node_coverage, Invalid, ModelError};
use palpate_runtime::element::tet_geometry;
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::{RuntimeConfig, RuntimeError};
use palpate_tests::model;
use palpate_tests::model::Storage;

#[test]
fn runtime_new_rejects_an_orphan_free_node() {
    let mut m = box_mesh([0.1, 0.1, 0.05], [2, 2, 1]);
    let fixed = m.group("bottom").unwrap().to_vec();
    // A free node that no tetrahedron uses: it would have no stiffness (singular K').
    let orphan = m.nodes.len();
    m.nodes.push([0.2, 0.2, 0.2]);
    m.node_tags.push(orphan as u64 + 1);
    let p = LambdaAlpha::from_young_poisson(10_000.0, 0.3);
    let buf = model::homogeneous(&m, &fixed, p.lambda, p.alpha);
    let expected = ModelError::InvalidContent {
        what: Invalid::OrphanNode {
            node: orphan as u32,
        },
    };
    // The protocol's own check names the node …
    let mut scratch = vec![0u8; m.nodes.len()];
    assert_eq!(
        validate_node_coverage(&buf.record(), &mut scratch),
        Err(expected)
    );
    // … and the runtime reports the same error instead of building a singular system.
    let cfg = RuntimeConfig::default();
    let mut storage = Storage::for_model(&buf.record(), &cfg);
    match storage.runtime(buf.record(), cfg) {
        Err(e) => assert_eq!(e, RuntimeError::InvalidModel(expected)),
        Ok(_) => panic!("a model with an orphan free node was accepted"),
    }
}

/// Engineering strain (xx, yy, zz, xy, yz, zx) of the constant displacement gradient `h`.
fn linear_strain(h: &[[f64; 3]; 3]) -> [f64; 6] {
    [
        h[0][0],
        h[1][1],
        h[2][2],
        h[0][1] + h[1][0],
        h[1][2] + h[2][1],
        h[2][0] + h[0][2],
    ]
}

#[test]
fn strain_blending_without_warping_follows_the_linear_strain() {
    let m = box_mesh([0.1, 0.1, 0.05], [3, 3, 2]);
    let fixed = m.group("bottom").unwrap().to_vec();
    let (n, t) = (m.nodes.len(), m.tets.len());
    // Two parameter sets: set 0 fitted at zero strain, set 1 at the strain of the field
    // u = A x below (A has only a z column, so u vanishes on the fixed bottom).
    let a = [[0.0, 0.0, 0.01], [0.0, 0.0, -0.004], [0.0, 0.0, -0.02]];
    let eps = linear_strain(&a);
    let dist = eps.iter().map(|v| v * v).sum::<f64>().sqrt();
    let p0 = LambdaAlpha::from_young_poisson(10_000.0, 0.3);
    let p1 = LambdaAlpha::from_young_poisson(30_000.0, 0.3);
    // Each element's metric uses only itself (one neighbour, weight 1), so the distance of
    // its strain to the two centres is exactly 0 and ‖ε_A‖ at the centres. With φ(r) = r the
    // RBF interpolant through (0 → v0, ‖ε_A‖ → v1) has weights w0 = v1/D, w1 = v0/D.
    let buf = model::strain_blend(&m, &fixed, [p0, p1], eps, |v0, v1| [v1 / dist, v0 / dist]);
    let cfg = model::linear_config(1e-7, 2000);
    let mut storage = Storage::for_model(&buf.record(), &cfg);
    let mut rt = storage.runtime(buf.record(), cfg).unwrap();

    let u: Vec<f32> = (0..n)
        .flat_map(|i| {
            let x = m.nodes[i];
            (0..3).map(move |r| (a[r][0] * x[0] + a[r][1] * x[1] + a[r][2] * x[2]) as f32)
        })
        .collect();
    rt.set_displacements(&u).unwrap();
    for e in 0..t {
        let s = rt.element_strain(e).unwrap();
        for c in 0..6 {
            // f32 displacements of ~1e-3 m over 1.7 cm elements: strain good to ~1e-6.
            assert!(
                (s[c] as f64 - eps[c]).abs() < 1e-5,
                "element {e}: strain {s:?} vs {eps:?}"
            );
        }
        // The blend sees that strain: set 1 is reproduced at its centre (2e-3: f32 RBF sums).
        let (l, al) = rt.element_parameters(e).unwrap();
        assert!(
            (l as f64 - p1.lambda).abs() < 2e-3 * p1.lambda,
            "element {e}: λ {l} vs set 1 {}",
            p1.lambda
        );
        assert!(
            (al as f64 - p1.alpha).abs() < 2e-3 * p1.alpha,
            "element {e}: α {al} vs set 1 {}",
            p1.alpha
        );
    }

    // The tick keeps it current too: each tick takes the strain of the state it starts from
    // (before its solve), so after a loaded tick every element's strain is the linear strain
    // of the displacements the tick started from (computed here in f64).
    rt.set_displacements(&vec![0.0; 3 * n]).unwrap();
    rt.set_contact_force([0.05, 0.05, 0.05], [0.0, 0.0, -0.3], 0.03)
        .unwrap();
    for _ in 0..4 {
        rt.tick();
    }
    let ud = rt.displacements().to_vec();
    rt.tick();
    let mut largest = 0.0f64;
    for (e, tet) in m.tets.iter().enumerate() {
        let g = tet_geometry(&tet.map(|i| Vector3::from(m.nodes[i]))).unwrap();
        let mut h = [[0.0f64; 3]; 3];
        for (a_, &node) in tet.iter().enumerate() {
            for (r, hr) in h.iter_mut().enumerate() {
                for (c, hrc) in hr.iter_mut().enumerate() {
                    *hrc += ud[3 * node + r] as f64 * g.grad[a_][c];
                }
            }
        }
        let want = linear_strain(&h);
        let got = rt.element_strain(e).unwrap();
        for c in 0..6 {
            largest = largest.max(want[c].abs());
            // f32 gradients of ~1e-3 m displacements: good to ~1e-7 of strains of ~1e-2.
            assert!(
                (got[c] as f64 - want[c]).abs() < 1e-6 + 1e-4 * want[c].abs(),
                "element {e} component {c}: runtime {} vs f64 {}",
                got[c],
                want[c]
            );
        }
    }
    assert!(
        largest > 1e-3,
        "the load should strain the block (max {largest:e})"
    );
}
