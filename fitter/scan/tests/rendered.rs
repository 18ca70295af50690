//! Scan fits on rendered data: a strip solved at a known modulus on quadratic tetrahedra over a
//! mesh refined twice per axis (the converged truth), seen by a depth camera with noise, dropped
//! pixels and a floor behind it ([`palpate_scan::render`]), back-projected, and fitted on the
//! coarse mesh with the library a user's `palpate fit-scan` runs.
//!
//! The fit's mesh is 10 × 2 × 1 cells (120 tetrahedra, P2), the truth's twice as fine per axis:
//! tens of seconds a test, and the coarse P2 mesh's own discretisation error is then several per
//! cent (measured: −5.9 % hanging, −9.3 % twisted; a two-material ratio of 4.1 for 3), so these
//! tolerances are the coarse mesh's. `PALPATE_SCAN_CELLS=16,4,2` fits on the mesh of
//! `docs/results/scans/README.md` (768 tetrahedra, minutes a test) and asserts the tolerances a
//! user is promised: E within 2 % hanging and 5 % twisted, the ratio within 10 %.

use nalgebra::Vector3;
use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_fem::mesh::Mesh;
use palpate_fem::rng::SplitMix64;
use palpate_scan::camera::{Camera, Intrinsics, Pose};
use palpate_scan::dataset::HeldToml;
use palpate_scan::fit::{fit_states, Design, FitSettings, LoadedObject, ScanPoints, ScanState};
use palpate_scan::regions::search_regions;
use palpate_scan::render::render_depth;

const SIZE: [f64; 3] = [0.08, 0.02, 0.01];
fn coarse_cells() -> [usize; 3] {
    let cells = std::env::var("PALPATE_SCAN_CELLS").unwrap_or_else(|_| "10,2,1".into());
    let v: Vec<usize> = cells
        .split(',')
        .map(|x| x.trim().parse().expect("PALPATE_SCAN_CELLS: three counts"))
        .collect();
    [v[0], v[1], v[2]]
}
const NU: f64 = 0.45;
const E_TRUE: f64 = 300e3;
const SIGMA_A: f64 = 2e-4;
const SIGMA_B: f64 = 1e-3;

/// The tolerance: `promised` on the 16 × 4 × 2 mesh or finer, `coarse` on a coarser one.
fn tolerance(promised: f64, coarse: f64) -> f64 {
    if coarse_cells()[0] >= 16 {
        promised
    } else {
        coarse
    }
}

fn mu_of(e: f64) -> f64 {
    e / (2.0 * (1.0 + NU))
}

/// The strip clamped over its end face x = 0, hanging; with `held`, its far face x = L moved
/// by that rigid motion.
fn strip<'a>(mesh: &'a Mesh, design: Design, held: Option<&HeldToml>) -> LoadedObject<'a> {
    let mut o = LoadedObject::hanging(
        mesh,
        mesh.node_groups["left"].clone(),
        1100.0,
        [0.0, 0.0, -9.81],
        NU,
        design,
        1e-7,
    );
    if let Some(h) = held {
        let right = &mesh.node_groups["right"];
        o.fixed_displacement = vec![[0.0; 3]; o.fixed.len()];
        for &n in right {
            let y = h.apply(mesh.nodes[n]);
            o.fixed.push(n);
            o.fixed_displacement
                .push([0, 1, 2].map(|k| y[k] - mesh.nodes[n][k]));
        }
        o.load_steps = 20;
    }
    o
}

fn camera() -> Camera {
    Camera {
        intrinsics: Intrinsics {
            fx: 210.0,
            fy: 210.0,
            cx: 79.5,
            cy: 59.5,
        },
        pose: Pose::looking_at(
            Vector3::new(0.05, -0.16, 0.08),
            Vector3::new(0.04, 0.01, -0.01),
            Vector3::new(0.0, 0.0, 1.0),
        ),
    }
}

/// The depth image of `surface` over `positions` and of the clamp's block behind its fixed end
/// (the background: 20 × 40 × 40 mm at x < 0), noise σ = 0.2 mm + 1e-3 m⁻¹·z², 10 % of the
/// pixels dropped, back-projected.
fn scan(positions: &[[f64; 3]], surface: &[[usize; 3]], seed: u64) -> ScanPoints {
    let cam = camera();
    let mut nodes = positions.to_vec();
    let mut tris = surface.to_vec();
    let block = box_mesh([0.02, 0.04, 0.04], [1, 1, 1]);
    let b = nodes.len();
    nodes.extend(
        block
            .nodes
            .iter()
            .map(|p| [p[0] - 0.0205, p[1] - 0.01, p[2] - 0.015]),
    );
    tris.extend(block.boundary_triangles().iter().map(|t| t.map(|n| n + b)));
    let mut image = render_depth(&cam, 160, 120, &nodes, &tris);
    let mut rng = SplitMix64::new(seed);
    for z in image.depth.iter_mut().filter(|z| **z > 0.0) {
        *z = if rng.uniform() < 0.1 {
            0.0
        } else {
            *z + (SIGMA_A + SIGMA_B * *z * *z) * rng.normal()
        };
    }
    let points = cam.points(&image);
    let sigma = points
        .iter()
        .map(|p| {
            let z = cam.pose.to_camera(*p).z;
            SIGMA_A + SIGMA_B * z * z
        })
        .collect();
    ScanPoints {
        points,
        sigma,
        camera: Some(cam),
    }
}

fn settings() -> FitSettings {
    FitSettings {
        // A factor 2 apart around 1.7 × the truth: a grid that does not hold it.
        starts: (-2..=1)
            .map(|k| mu_of(1.7 * E_TRUE * 2f64.powi(k)))
            .collect(),
        max_distance: 2e-2,
        max_iter: 30,
    }
}

fn fine() -> Mesh {
    box_mesh(SIZE, coarse_cells().map(|c| 2 * c))
}

/// (a) A homogeneous hanging strip: E within 2 % of the truth's, and no second material
/// adopted (ΔBIC of the best split above −10).
#[test]
fn a_homogeneous_hanging_strip_has_one_material() {
    let t0 = std::time::Instant::now();
    let fine = fine();
    let truth = strip(&fine, Design::Quadratic, None)
        .equilibrium(mu_of(E_TRUE), false)
        .unwrap();
    eprintln!("truth solved in {:.1} s", t0.elapsed().as_secs_f64());
    let coarse = box_mesh(SIZE, coarse_cells());
    let states = vec![ScanState {
        name: "hanging".into(),
        object: strip(&coarse, Design::Quadratic, None),
        scan: scan(&truth.positions, &truth.surface, 1),
    }];
    let fit = fit_states(&states, &settings()).unwrap();
    eprintln!("fitted at {:.1} s", t0.elapsed().as_secs_f64());
    let err = fit.young_modulus(0) / E_TRUE - 1.0;
    let search = search_regions(&states, &fit, &settings()).unwrap();
    eprintln!("fitted at {:.1} s", t0.elapsed().as_secs_f64());
    let best = search.best.as_ref().unwrap();
    eprintln!(
        "{} points; homogeneous: E {:.1} kPa ({:+.2} %), σ {:.2} %; best split {} ratio {:.3}, ΔBIC {:.1}",
        states[0].scan.points.len(),
        fit.young_modulus(0) / 1e3,
        100.0 * err,
        100.0 * fit.sigma_ln_mu(0),
        best.split.label,
        best.ratio,
        best.delta_bic()
    );
    assert!(
        err.abs() < tolerance(0.02, 0.07),
        "E off by {:.2} %",
        100.0 * err
    );
    assert!(
        !search.adopted,
        "a second material adopted: {}, ΔBIC {}",
        best.split.label,
        best.delta_bic()
    );
}

/// (b) A strip of two materials split at 40 % of its length (the far part 3 × stiffer),
/// declared as one: the split found within one element layer of the truth's plane and the
/// ratio within 10 %.
#[test]
fn a_second_material_is_found_where_it_is() {
    let t0 = std::time::Instant::now();
    let fine = fine();
    let mut t = strip(&fine, Design::Quadratic, None);
    t.regions = fine
        .tets
        .iter()
        .map(|tet| {
            let x = tet.iter().map(|&n| fine.nodes[n][0]).sum::<f64>() / 4.0;
            usize::from(x > 0.4 * SIZE[0])
        })
        .collect();
    let truth = t
        .equilibrium_at(&[mu_of(E_TRUE / 3.0), mu_of(E_TRUE)], false)
        .unwrap();
    eprintln!("truth solved in {:.1} s", t0.elapsed().as_secs_f64());
    let coarse = box_mesh(SIZE, coarse_cells());
    let states = vec![ScanState {
        name: "hanging".into(),
        object: strip(&coarse, Design::Quadratic, None),
        scan: scan(&truth.positions, &truth.surface, 2),
    }];
    let fit = fit_states(&states, &settings()).unwrap();
    eprintln!("fitted at {:.1} s", t0.elapsed().as_secs_f64());
    let search = search_regions(&states, &fit, &settings()).unwrap();
    eprintln!("fitted at {:.1} s", t0.elapsed().as_secs_f64());
    let best = search.best.as_ref().unwrap();
    eprintln!(
        "two materials: one-material E {:.1} kPa; best split {} (normal {:?}), E {:.1} / {:.1} kPa, ratio {:.3} ± {:.3}, ΔBIC {:.1}; screened {:?}",
        fit.young_modulus(0) / 1e3,
        best.split.label,
        best.split.normal,
        best.fit.young_modulus(0) / 1e3,
        best.fit.young_modulus(1) / 1e3,
        best.ratio,
        best.ratio_sigma,
        best.delta_bic(),
        search.screened
    );
    assert!(
        search.adopted,
        "no second material adopted: {}, ΔBIC {}",
        best.split.label,
        best.delta_bic()
    );
    assert!(best.split.normal[0] > 0.99, "{:?}", best.split.normal);
    // One element layer of the coarse mesh is a tenth of the length.
    assert!(
        (best.split.fraction - 0.4).abs() <= 0.1 + 1e-9,
        "split at {}",
        best.split.fraction
    );
    assert!(
        (best.ratio / 3.0 - 1.0).abs() < tolerance(0.1, 0.4),
        "ratio {}",
        best.ratio
    );
}

/// (c) A strip clamped at one end, its other end held and turned 45° about the long axis, fitted
/// with a scan of it hanging (as `palpate fit-scan` fits every state of a dataset): E within 5 %
/// of the truth's on the 16 × 4 × 2 mesh. The twisted scan alone says little of E — a
/// prescribed twist's shape depends on ν, not on the modulus, but for the sag between the grips —
/// and fitted alone it takes up the mesh's error in torsion (measured −11.5 % on 16 × 4 × 2,
/// −9.3 % on 10 × 2 × 1).
#[test]
fn a_twisted_strip_gives_its_modulus() {
    let held = HeldToml {
        group: "right".into(),
        axis: Some([1.0, 0.0, 0.0]),
        angle_deg: 45.0,
        about: [SIZE[0], SIZE[1] / 2.0, SIZE[2] / 2.0],
        translation: [0.0; 3],
    };
    let t0 = std::time::Instant::now();
    let fine = fine();
    let truth = strip(&fine, Design::Quadratic, Some(&held))
        .equilibrium(mu_of(E_TRUE), false)
        .unwrap();
    eprintln!("truth solved in {:.1} s", t0.elapsed().as_secs_f64());
    let coarse = box_mesh(SIZE, coarse_cells());
    let hanging = strip(&fine, Design::Quadratic, None)
        .equilibrium(mu_of(E_TRUE), false)
        .unwrap();
    let states = vec![
        ScanState {
            name: "twisted".into(),
            object: strip(&coarse, Design::Quadratic, Some(&held)),
            scan: scan(&truth.positions, &truth.surface, 3),
        },
        ScanState {
            name: "hanging".into(),
            object: strip(&coarse, Design::Quadratic, None),
            scan: scan(&hanging.positions, &hanging.surface, 4),
        },
    ];
    let fit = fit_states(&states, &settings()).unwrap();
    eprintln!("fitted at {:.1} s", t0.elapsed().as_secs_f64());
    let err = fit.young_modulus(0) / E_TRUE - 1.0;
    eprintln!(
        "twisted 45° and hanging: E {:.1} kPa ({:+.2} %), σ {:.2} %, {} iterations",
        fit.young_modulus(0) / 1e3,
        100.0 * err,
        100.0 * fit.sigma_ln_mu(0),
        fit.iterations
    );
    assert!(
        err.abs() < tolerance(0.05, 0.12),
        "E off by {:.2} %",
        100.0 * err
    );
}
