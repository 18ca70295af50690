//! Synthetic static datasets with known parameters, made with the forward model: a homogeneous
//! block, or a block with a stiff spherical inclusion; markers on the free surface; Gaussian
//! marker noise from a seeded generator (reproducible).

use palpate_fem::dataset::{Marker, Measurement, StaticDataset};
use palpate_fem::forward::{Contact, Load, Material, SolveOptions, StaticProblem};
use palpate_fem::mesh::boxmesh::box_mesh;
use palpate_fem::mesh::{centroid, Mesh};
use palpate_fem::rng::SplitMix64;

use super::{FitError, FitInput, FitMeasurement};

/// What to synthesise.
#[derive(Debug, Clone)]
pub struct SyntheticSpec {
    /// Block size (m).
    pub size: [f64; 3],
    /// Cells per axis of the box mesh.
    pub cells: [usize; 3],
    /// Background Young's modulus (Pa) and Poisson ratio.
    pub young: f64,
    /// Background Poisson ratio.
    pub poisson: f64,
    /// Optional stiff inclusion: (centre, radius, Young's modulus) — elements whose centroid lies
    /// inside get that modulus.
    pub inclusion: Option<([f64; 3], f64, f64)>,
    /// Probe contacts (on the top face) with their forces.
    pub contacts: Vec<Contact>,
    /// Number of markers (placed on free boundary triangles; 0 = one on every free surface node).
    pub markers: usize,
    /// Marker noise σ (m), Gaussian per coordinate.
    pub noise: f64,
    /// Seed.
    pub seed: u64,
    /// Forward-solver options used to make the data.
    pub solve: SolveOptions,
}

impl SyntheticSpec {
    /// A 10 × 10 × 5 cm block (bottom fixed), E = 20 kPa, ν = 0.3, four contacts on the top face.
    pub fn block(cells: [usize; 3]) -> Self {
        let top = 0.05;
        let c = |x: f64, y: f64, fx: f64, fy: f64, fz: f64| Contact {
            point: [x, y, top],
            force: [fx, fy, fz],
            radius: 0.02,
        };
        Self {
            size: [0.1, 0.1, 0.05],
            cells,
            young: 20_000.0,
            poisson: 0.3,
            inclusion: None,
            contacts: vec![
                c(0.05, 0.05, 0.0, 0.0, -2.0),
                c(0.03, 0.07, 0.5, 0.0, -1.5),
                c(0.07, 0.03, 0.0, -0.5, -2.5),
                c(0.07, 0.07, -0.3, 0.3, -1.0),
            ],
            markers: 0,
            noise: 0.0,
            seed: 1,
            solve: SolveOptions::default(),
        }
    }
}

/// A synthetic dataset and its ground truth.
#[derive(Debug, Clone)]
pub struct Synthetic {
    /// The mesh.
    pub mesh: Mesh,
    /// Fixed nodes (the `bottom` group).
    pub fixed: Vec<usize>,
    /// The fit input (noisy observed markers).
    pub input: FitInput,
    /// True material.
    pub truth: Material,
    /// Noise-free deformed positions of every node, per measurement.
    pub exact: Vec<Vec<[f64; 3]>>,
}

/// Makes a synthetic dataset.
pub fn synthesise(spec: &SyntheticSpec) -> Result<Synthetic, FitError> {
    let mesh = box_mesh(spec.size, spec.cells);
    let fixed = mesh.node_groups.get("bottom").cloned().unwrap_or_default();
    synthesise_on(mesh, fixed, spec)
}

/// Makes a synthetic dataset on a given mesh with the given fixed nodes (`size`/`cells` of the
/// spec are ignored).
pub fn synthesise_on(
    mesh: Mesh,
    fixed: Vec<usize>,
    spec: &SyntheticSpec,
) -> Result<Synthetic, FitError> {
    let surface = mesh.boundary_triangles();
    let problem = StaticProblem::new(&mesh, &fixed, &surface)?;
    let truth = match spec.inclusion {
        None => Material::from_young_poisson(spec.young, spec.poisson),
        Some((centre, radius, young)) => {
            let params: Vec<_> = mesh
                .tets
                .iter()
                .map(|t| {
                    let c = centroid(&mesh.nodes, t);
                    let r2: f64 = (0..3).map(|d| (c[d] - centre[d]).powi(2)).sum();
                    let e = if r2 <= radius * radius {
                        young
                    } else {
                        spec.young
                    };
                    palpate_runtime::material::LambdaAlpha::from_young_poisson(e, spec.poisson)
                })
                .collect();
            Material::per_element(&params)
        }
    };
    let mut rng = SplitMix64::new(spec.seed);
    // Markers: free boundary triangles (no fixed node), either every free surface node or random
    // points on random triangles.
    let free_tris: Vec<[usize; 3]> = surface
        .iter()
        .copied()
        .filter(|t| t.iter().all(|&n| !problem.fixed[n]))
        .collect();
    let mut markers = Vec::new();
    if spec.markers == 0 {
        let mut seen = vec![false; mesh.nodes.len()];
        for t in &free_tris {
            for (k, &n) in t.iter().enumerate() {
                if !seen[n] {
                    seen[n] = true;
                    let mut b = [0.0; 3];
                    b[k] = 1.0;
                    markers.push(Marker {
                        id: format!("m{}", markers.len()),
                        rest: mesh.nodes[n],
                        triangle: *t,
                        barycentric: b,
                        distance: 0.0,
                        offset_local: [0.0; 3],
                    });
                }
            }
        }
    } else {
        for k in 0..spec.markers {
            let t = free_tris[(rng.uniform() * free_tris.len() as f64) as usize % free_tris.len()];
            let (mut a, mut b) = (rng.uniform(), rng.uniform());
            if a + b > 1.0 {
                a = 1.0 - a;
                b = 1.0 - b;
            }
            let bc = [1.0 - a - b, a, b];
            let mut rest = [0.0; 3];
            for (w, &n) in bc.iter().zip(&t) {
                for d in 0..3 {
                    rest[d] += w * mesh.nodes[n][d];
                }
            }
            markers.push(Marker {
                id: format!("m{k}"),
                rest,
                triangle: t,
                barycentric: bc,
                distance: 0.0,
                offset_local: [0.0; 3],
            });
        }
    }
    let mut measurements = Vec::new();
    let mut exact = Vec::new();
    for (i, c) in spec.contacts.iter().enumerate() {
        let load = Load {
            contacts: vec![*c],
            nodal: vec![],
        };
        let force = problem.force_vector(&load)?;
        let sol = problem
            .solve_forces(&truth, &force, None, &spec.solve)?
            .solution;
        let observed = markers
            .iter()
            .enumerate()
            .map(|(k, m)| {
                let p = m.interpolate(|n| sol.x[n]);
                (k, [0, 1, 2].map(|d| p[d] + spec.noise * rng.normal()))
            })
            .collect();
        measurements.push(FitMeasurement {
            id: format!("c{i}"),
            contact: *c,
            force,
            observed,
        });
        exact.push(sol.x);
    }
    let input = FitInput {
        problem,
        markers,
        measurements,
        marker_noise: (spec.noise > 0.0).then_some(spec.noise),
    };
    Ok(Synthetic {
        mesh,
        fixed,
        input,
        truth,
        exact,
    })
}

impl Synthetic {
    /// The synthetic data as a [`StaticDataset`] (for writing example datasets).
    pub fn to_dataset(&self, name: &str, description: &str, probe_radius: f64) -> StaticDataset {
        StaticDataset {
            marker_standoff: None,
            name: name.into(),
            description: description.into(),
            mesh: self.mesh.clone(),
            fixed_group: "bottom".into(),
            fixed_nodes: self.fixed.clone(),
            surface: self.input.problem.surface.clone(),
            probe_radius,
            marker_noise: self.input.marker_noise,
            gravity: None,
            markers: self.input.markers.clone(),
            measurements: self
                .input
                .measurements
                .iter()
                .map(|m| Measurement {
                    id: m.id.clone(),
                    contact: m.contact.point,
                    force: m.contact.force,
                    radius: m.contact.radius,
                    observed: m.observed.clone(),
                })
                .collect(),
        }
    }
}
